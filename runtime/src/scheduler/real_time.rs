//! Real time: every task on its own worker thread, activated by the wall clock.
//!
//! A worker sleeps until its task's next activation (parked with a timeout, so a level change
//! or a stop wakes it at once; an input-triggered task's worker is also woken by its input's
//! messages), runs the step, measures it and books it with the same cadence
//! logic as virtual time. CPU tasks may be pinned to their configured `cores`; the GPU task's
//! worker holds the GPU lease for as long as the task lives. I/O (the MAVLink link, camera
//! sources) belongs on tokio, outside these workers.

use super::stats::StatsAccum;
use super::{lock, Parts, PhaseGate, Resources, SchedulerError, TaskId, TaskRunner, TaskStats};
use crate::bus::Bus;
use crate::clock::{Clock, Timestamp, WallClock};
use crate::config::Resource;
use crate::task::{LevelError, MissionHealth, TaskHealth};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};

/// Whether workers are pinned to their task's configured `cores`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pinning {
    Off,
    /// Pin where possible; a core this machine lacks is a warning (a mission configured for an
    /// 8-core board still runs on a laptop).
    #[default]
    BestEffort,
    /// A core that cannot be pinned is an error at start.
    Required,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RealTimeOptions {
    pub pinning: Pinning,
    /// Linux: set the workers' timer slack to 1 ns (default 50 µs), so they wake on time.
    pub fine_timer_slack: bool,
}

impl Default for RealTimeOptions {
    fn default() -> Self {
        RealTimeOptions {
            pinning: Pinning::BestEffort,
            fine_timer_slack: true,
        }
    }
}

/// What a worker and the scheduler share.
struct WorkerShared {
    stop: AtomicBool,
    requested_level: AtomicUsize,
    /// The task's phases include the mission's current one.
    active: AtomicBool,
}

enum Command {
    /// Start the task instance, then report.
    Start,
    /// First activation at this instant.
    Go(Timestamp),
    Abort,
}

struct Worker {
    name: String,
    config: crate::config::TaskConfig,
    resource: Resource,
    cores: Vec<usize>,
    level_count: usize,
    shared: Arc<WorkerShared>,
    stats: Arc<Mutex<StatsAccum>>,
    thread: Option<JoinHandle<()>>,
}

enum State {
    Built(Vec<TaskRunner>),
    Running,
    Stopped,
}

/// The real-time scheduler. Build, [`start`](RealTimeScheduler::start), change levels live,
/// read statistics, [`stop`](RealTimeScheduler::stop) (also on drop).
pub struct RealTimeScheduler {
    clock: WallClock,
    workers: Vec<Worker>,
    state: State,
    bus: Bus,
    resources: Resources,
    health: MissionHealth,
    options: RealTimeOptions,
}

impl RealTimeScheduler {
    pub(crate) fn new(parts: Parts, options: RealTimeOptions) -> Self {
        let workers = parts
            .runners
            .iter()
            .map(|runner| Worker {
                name: runner.name().to_string(),
                config: runner.config().clone(),
                resource: runner.config().resource,
                cores: runner.config().cores.clone(),
                level_count: runner.level_count(),
                shared: Arc::new(WorkerShared {
                    stop: AtomicBool::new(false),
                    requested_level: AtomicUsize::new(runner.level()),
                    active: AtomicBool::new(runner.is_active()),
                }),
                stats: runner.stats_handle(),
                thread: None,
            })
            .collect();
        RealTimeScheduler {
            clock: WallClock::new(),
            workers,
            state: State::Built(parts.runners),
            bus: parts.bus,
            resources: parts.resources,
            health: parts.health,
            options,
        }
    }

    /// Spawns the workers, pins them, starts every task and, once all have started, releases
    /// them together: every task's first activation is at the same instant.
    pub fn start(&mut self) -> Result<(), SchedulerError> {
        let runners = match std::mem::replace(&mut self.state, State::Running) {
            State::Built(runners) => runners,
            State::Running => return Err(SchedulerError::AlreadyStarted),
            State::Stopped => {
                self.state = State::Stopped;
                return Err(SchedulerError::Stopped);
            }
        };
        let (report_tx, report_rx) = mpsc::channel::<(usize, Result<(), PinError>)>();
        let mut commands = Vec::with_capacity(runners.len());
        for (index, runner) in runners.into_iter().enumerate() {
            let (command_tx, command_rx) = mpsc::channel();
            let shared = self.workers[index].shared.clone();
            let clock = self.clock;
            let options = self.options;
            let report = report_tx.clone();
            let spawned = thread::Builder::new()
                .name(format!("qosrt-{}", runner.name()))
                .spawn(move || {
                    worker_main(index, runner, shared, clock, options, report, command_rx)
                });
            match spawned {
                Ok(handle) => {
                    self.workers[index].thread = Some(handle);
                    commands.push(command_tx);
                }
                Err(source) => {
                    self.abort(&commands);
                    return Err(SchedulerError::Spawn {
                        task: self.workers[index].name.clone(),
                        source,
                    });
                }
            }
        }
        drop(report_tx);
        // Round 1: pinning.
        let mut pin_error = None;
        for _ in 0..commands.len() {
            match report_rx.recv() {
                Ok((index, Err(reason))) if pin_error.is_none() => {
                    pin_error = Some((index, reason));
                }
                Ok(_) => {}
                Err(_) => break,
            }
        }
        if let Some((index, reason)) = pin_error {
            self.abort(&commands);
            let task = &self.workers[index];
            return Err(SchedulerError::Pinning {
                task: task.name.clone(),
                cores: task.cores.clone(),
                source: reason,
            });
        }
        // Round 2: every task starts (a failing start is the task's failure, not the scheduler's).
        for command in &commands {
            let _ = command.send(Command::Start);
        }
        for _ in 0..commands.len() {
            if report_rx.recv().is_err() {
                break;
            }
        }
        let first_activation = self.clock.now();
        for command in &commands {
            let _ = command.send(Command::Go(first_activation));
        }
        Ok(())
    }

    fn abort(&mut self, commands: &[Sender<Command>]) {
        for command in commands {
            let _ = command.send(Command::Abort);
        }
        self.join_workers();
        self.state = State::Stopped;
    }

    /// Changes `task`'s QoS level; its worker applies it at once (it is woken), and the next
    /// activation is re-computed from the new period: within one new period from now.
    pub fn set_level(&self, task: TaskId, level: usize) -> Result<(), SchedulerError> {
        let worker = self.worker_of_id(task)?;
        if level >= worker.level_count {
            return Err(LevelError::OutOfRange {
                task: worker.name.clone(),
                level,
                count: worker.level_count,
            }
            .into());
        }
        worker
            .shared
            .requested_level
            .store(level, Ordering::Release);
        if let Some(thread) = &worker.thread {
            thread.thread().unpark();
        }
        Ok(())
    }

    /// Enters a phase: workers of tasks the gate does not admit stop stepping (they sleep
    /// until resumed); the ones it admits again are woken and step at once.
    pub fn set_phase(&self, gate: &PhaseGate) {
        for worker in &self.workers {
            let active = gate.admits(&worker.config);
            if worker.shared.active.swap(active, Ordering::AcqRel) != active {
                if let Some(thread) = &worker.thread {
                    thread.thread().unpark();
                }
            }
        }
    }

    /// The level the task's worker runs at; `None` for an id this scheduler did not give.
    pub fn level(&self, task: TaskId) -> Option<usize> {
        let worker = self.worker_of_id(task).ok()?;
        Some(lock(&worker.stats).level)
    }

    /// The id of the task named `task`, if the scheduler holds it.
    pub fn task_id(&self, task: &str) -> Option<TaskId> {
        self.workers
            .iter()
            .position(|worker| worker.name == task)
            .map(TaskId)
    }

    fn worker(&self, task: &str) -> Result<&Worker, SchedulerError> {
        self.workers
            .iter()
            .find(|worker| worker.name == task)
            .ok_or_else(|| SchedulerError::UnknownTask {
                task: task.to_string(),
                known: self.known_tasks(),
            })
    }

    fn worker_of_id(&self, task: TaskId) -> Result<&Worker, SchedulerError> {
        self.workers
            .get(task.0)
            .ok_or_else(|| SchedulerError::UnknownTaskId {
                id: task,
                known: self.known_tasks(),
            })
    }

    /// The tasks' names, for an error.
    fn known_tasks(&self) -> String {
        self.workers
            .iter()
            .map(|worker| worker.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    }

    pub fn now(&self) -> Timestamp {
        self.clock.now()
    }

    pub fn clock(&self) -> WallClock {
        self.clock
    }

    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    pub fn resources(&self) -> &Resources {
        &self.resources
    }

    pub fn health(&self) -> &MissionHealth {
        &self.health
    }

    pub fn failed_tasks(&self) -> Vec<String> {
        self.health.failed_tasks()
    }

    pub fn stats(&self) -> Vec<TaskStats> {
        self.workers
            .iter()
            .map(|worker| self.snapshot(worker))
            .collect()
    }

    pub fn task_stats(&self, task: &str) -> Option<TaskStats> {
        self.worker(task).ok().map(|worker| self.snapshot(worker))
    }

    fn snapshot(&self, worker: &Worker) -> TaskStats {
        let health = self
            .health
            .health_of(&worker.name)
            .unwrap_or(TaskHealth::Running);
        lock(&worker.stats).snapshot(&worker.name, health)
    }

    /// Stops every worker after its current step, calls each task's `stop` and waits for them.
    /// Statistics stay readable.
    pub fn stop(&mut self) {
        if let State::Built(runners) = std::mem::replace(&mut self.state, State::Stopped) {
            for mut runner in runners {
                runner.abandon();
            }
        }
        for worker in &self.workers {
            worker.shared.stop.store(true, Ordering::Release);
            if let Some(thread) = &worker.thread {
                thread.thread().unpark();
            }
        }
        self.join_workers();
    }

    fn join_workers(&mut self) {
        for worker in &mut self.workers {
            if let Some(thread) = worker.thread.take() {
                if thread.join().is_err() {
                    tracing::error!(task = %worker.name, resource = %worker.resource, "worker thread panicked outside its task");
                }
            }
        }
    }
}

impl Drop for RealTimeScheduler {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Why a worker could not be pinned to its cores.
#[derive(Debug, thiserror::Error)]
pub enum PinError {
    #[error("core {core} is beyond the {max} cores the OS can address")]
    BeyondAddressable { core: usize, max: usize },
    #[error("{0} (does this machine have these cores?)")]
    SetAffinity(#[source] std::io::Error),
    #[error("{0}")]
    GetAffinity(#[source] std::io::Error),
    #[error("cores {missing:?} are not available on this machine")]
    Missing { missing: Vec<usize> },
    #[error("pinning is only supported on Linux")]
    Unsupported,
}

fn worker_main(
    index: usize,
    mut runner: TaskRunner,
    shared: Arc<WorkerShared>,
    clock: WallClock,
    options: RealTimeOptions,
    report: Sender<(usize, Result<(), PinError>)>,
    commands: Receiver<Command>,
) {
    if options.fine_timer_slack {
        os::set_fine_timer_slack();
    }
    let cores = runner.config().cores.clone();
    let pinned = match options.pinning {
        Pinning::Off => Ok(()),
        _ if cores.is_empty() => Ok(()),
        Pinning::BestEffort => {
            if let Err(reason) = os::pin_current_thread(&cores) {
                tracing::warn!(task = %runner.name(), ?cores, %reason, "running unpinned");
            }
            Ok(())
        }
        Pinning::Required => os::pin_current_thread(&cores),
    };
    let _ = report.send((index, pinned));
    if !matches!(commands.recv(), Ok(Command::Start)) {
        runner.abandon();
        return;
    }
    runner.start(clock.now(), clock.now());
    let _ = report.send((index, Ok(())));
    let first_activation = match commands.recv() {
        Ok(Command::Go(at)) => at,
        _ => {
            runner.shutdown();
            return;
        }
    };
    runner.reschedule_first(first_activation);
    drop(report);

    // End of the last step: the time from it to the next clock read at the top of the loop
    // (just before sleeping or stepping) is the worker's own bookkeeping per activation.
    let mut last_finished: Option<Timestamp> = None;
    let mut overhead_ns = None;
    // An input-triggered task's worker is woken by its input's every message.
    let input = runner.trigger().map(|trigger| trigger.activity().clone());
    if let Some(input) = &input {
        input.watch(thread::current());
    }
    loop {
        if shared.stop.load(Ordering::Acquire) {
            break;
        }
        let requested = shared.requested_level.load(Ordering::Acquire);
        if requested != runner.level() {
            runner.change_level(requested, clock.now());
        }
        runner.set_active(shared.active.load(Ordering::Acquire), clock.now());
        if !runner.is_active() {
            // Outside the task's phases: sleep until resumed or stopped.
            last_finished = None;
            thread::park();
            continue;
        }
        if !runner.is_scheduled() {
            // Failed for good: wait for the stop.
            thread::park();
            continue;
        }
        let now = clock.now();
        runner.notice_input(now);
        if let Some(finished) = last_finished.take() {
            overhead_ns = Some(now.as_nanos().saturating_sub(finished.as_nanos()));
        }
        let Some(due) = runner.next_due_at(now) else {
            // Input-triggered with nothing to run on: sleep until a message, a level change
            // or the stop.
            thread::park();
            continue;
        };
        if now < due {
            // Woken early by set_level or stop (or spuriously): the loop re-checks both.
            thread::park_timeout(due.saturating_duration_since(now));
            continue;
        }
        let report = runner.activate(now);
        let finished = clock.now();
        runner.record(due, now, finished, &report, overhead_ns.take());
        last_finished = Some(finished);
    }
    if let Some(input) = &input {
        input.unwatch(thread::current().id());
    }
    runner.shutdown();
}

#[cfg(target_os = "linux")]
pub(crate) mod os {
    use super::PinError;

    /// Timer slack lets the kernel coalesce wake-ups up to 50 µs late by default; a periodic
    /// task wants its wake-up on time.
    pub fn set_fine_timer_slack() {
        // SAFETY: PR_SET_TIMERSLACK takes one integer argument and changes only this thread's
        // timer slack; no memory is passed.
        let result = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
        if result != 0 {
            tracing::debug!(error = %std::io::Error::last_os_error(), "could not lower the timer slack");
        }
    }

    /// Lowers the calling thread's scheduling priority (a nice value of `nice`, 1..=19): it
    /// then runs in the time the mission's threads leave, never instead of them.
    pub fn lower_current_thread_priority(nice: i32) {
        // SAFETY: setpriority with PRIO_PROCESS and id 0 acts on the calling thread only (Linux
        // gives each thread its own nice value); no memory is passed.
        let result = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, nice) };
        if result != 0 {
            tracing::debug!(error = %std::io::Error::last_os_error(), "could not lower the thread's priority");
        }
    }

    /// Pins the calling thread to `cores`; an error names the cores this machine lacks.
    pub fn pin_current_thread(cores: &[usize]) -> Result<(), PinError> {
        let max = libc::CPU_SETSIZE as usize;
        if let Some(&core) = cores.iter().find(|&&core| core >= max) {
            return Err(PinError::BeyondAddressable { core, max });
        }
        // SAFETY: cpu_set_t is a plain bit array for which all-zero is the empty set; the CPU_*
        // helpers index within it (cores were checked against CPU_SETSIZE above), and the
        // sched_*affinity calls get its true size and act on the calling thread only (pid 0).
        unsafe {
            let mut wanted: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_ZERO(&mut wanted);
            for &core in cores {
                libc::CPU_SET(core, &mut wanted);
            }
            let size = std::mem::size_of::<libc::cpu_set_t>();
            if libc::sched_setaffinity(0, size, &wanted) != 0 {
                return Err(PinError::SetAffinity(std::io::Error::last_os_error()));
            }
            // The kernel accepts a set of which only some cores exist: check what we got.
            let mut got: libc::cpu_set_t = std::mem::zeroed();
            if libc::sched_getaffinity(0, size, &mut got) != 0 {
                return Err(PinError::GetAffinity(std::io::Error::last_os_error()));
            }
            let missing: Vec<usize> = cores
                .iter()
                .copied()
                .filter(|&core| !libc::CPU_ISSET(core, &got))
                .collect();
            if !missing.is_empty() {
                return Err(PinError::Missing { missing });
            }
        }
        Ok(())
    }
}

#[cfg(not(target_os = "linux"))]
pub(crate) mod os {
    pub fn set_fine_timer_slack() {}

    pub fn lower_current_thread_priority(_nice: i32) {}

    pub fn pin_current_thread(_cores: &[usize]) -> Result<(), super::PinError> {
        Err(super::PinError::Unsupported)
    }
}
