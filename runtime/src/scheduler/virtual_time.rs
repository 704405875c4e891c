//! Virtual time: a deterministic discrete-event loop.
//!
//! The next activation of every task waits in a priority queue ordered by (time, task index).
//! An activation runs its step at once, at its activation instant (that is the `now` the task
//! sees and stamps its messages with); the step then occupies the task for the cost its timing
//! model gives (its own report, else the per-level figure, else zero), and activation instants
//! that fall inside that cost are skipped exactly as in real time. Nothing depends on the host's
//! speed, so the same config and seed replay the same trace.

use super::{
    ActivationReport, Parts, PhaseGate, Resources, SchedulerError, TaskId, TaskRunner, TaskStats,
};
use crate::bus::Bus;
use crate::clock::{Clock, ClockError, Timestamp, VirtualClock};
use crate::task::MissionHealth;
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::Arc;
use std::time::Duration;

/// One thing that happened, for replay comparison and debugging.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TraceEvent {
    pub time: Timestamp,
    pub task: Arc<str>,
    pub kind: TraceKind,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TraceKind {
    Started,
    /// A step ran, costing `cost` of virtual time.
    Stepped {
        cost: Duration,
    },
    Overrun {
        cost: Duration,
    },
    Skipped {
        count: u64,
    },
    /// An input-triggered task took the newest of its inputs; this many came before it unread.
    DroppedInputs {
        count: u64,
    },
    Failed {
        error: String,
        gave_up: bool,
    },
    Restarted,
    LevelChanged {
        level: usize,
    },
    /// The mission entered a phase the task does not list.
    Suspended,
    /// The mission entered a phase the task lists again.
    Resumed,
    Stopped,
}

/// The virtual-time scheduler. Time moves only in [`VirtualScheduler::run_until`].
pub struct VirtualScheduler {
    clock: VirtualClock,
    runners: Vec<TaskRunner>,
    names: Vec<Arc<str>>,
    /// (due time ns, task index, generation); entries of an older generation are stale.
    queue: BinaryHeap<Reverse<(u64, usize, u64)>>,
    generations: Vec<u64>,
    /// The due time each task has in the queue (of its current generation), if any.
    queued_ns: Vec<Option<u64>>,
    bus: Bus,
    resources: Resources,
    health: MissionHealth,
    trace: Option<Vec<TraceEvent>>,
    started: bool,
    stopped: bool,
}

impl VirtualScheduler {
    pub(crate) fn new(parts: Parts, record_trace: bool) -> Self {
        let names = parts
            .runners
            .iter()
            .map(|runner| Arc::from(runner.name()))
            .collect();
        let count = parts.runners.len();
        VirtualScheduler {
            clock: VirtualClock::new(),
            runners: parts.runners,
            names,
            queue: BinaryHeap::with_capacity(count),
            generations: vec![0; count],
            queued_ns: vec![None; count],
            bus: parts.bus,
            resources: parts.resources,
            health: parts.health,
            trace: record_trace.then(Vec::new),
            started: false,
            stopped: false,
        }
    }

    /// Starts every task (in config order) at the current time; their first activations are
    /// now. [`VirtualScheduler::run_until`] does this itself the first time.
    pub fn start(&mut self) -> Result<(), SchedulerError> {
        if self.stopped {
            return Err(SchedulerError::Stopped);
        }
        if self.started {
            return Err(SchedulerError::AlreadyStarted);
        }
        self.started = true;
        let now = self.clock.now();
        for index in 0..self.runners.len() {
            self.push_trace(now, index, TraceKind::Started);
            if let Some(failure) = self.runners[index].start(now, now) {
                let kind = TraceKind::Failed {
                    error: failure.message,
                    gave_up: failure.gave_up,
                };
                self.push_trace(now, index, kind);
            }
            self.schedule(index);
        }
        Ok(())
    }

    /// Runs every activation due up to and including `until`, then sets the clock to `until`.
    /// Returns how many activations ran.
    pub fn run_until(&mut self, until: Timestamp) -> Result<u64, SchedulerError> {
        if self.stopped {
            return Err(SchedulerError::Stopped);
        }
        let now = self.clock.now();
        if until < now {
            return Err(ClockError::Backwards {
                now,
                requested: until,
            }
            .into());
        }
        if !self.started {
            self.start()?;
        }
        // What was published from outside since the last call (a camera frame, telemetry)
        // arrived by `until`.
        self.poll_triggers(until);
        let mut activations = 0;
        while let Some(&Reverse((due_ns, index, generation))) = self.queue.peek() {
            if due_ns > until.as_nanos() {
                break;
            }
            self.queue.pop();
            if generation != self.generations[index] {
                continue;
            }
            let due = Timestamp::from_nanos(due_ns);
            self.clock.advance_to(due)?;
            self.activate(index, due);
            activations += 1;
        }
        self.clock.advance_to(until)?;
        Ok(activations)
    }

    /// Runs for `duration` of virtual time from now.
    pub fn run_for(&mut self, duration: Duration) -> Result<u64, SchedulerError> {
        let until = self.clock.now().saturating_add(duration);
        self.run_until(until)
    }

    fn activate(&mut self, index: usize, due: Timestamp) {
        let runner = &mut self.runners[index];
        let report = runner.activate(due);
        let cost = runner.modelled_cost(&report);
        let finished = due.saturating_add(cost);
        let completion = runner.record(due, due, finished, &report, None);
        if self.trace.is_some() {
            self.trace_activation(index, due, cost, &report, completion);
        }
        self.schedule(index);
        // What the step published reaches the tasks it triggers when the step ends.
        self.poll_triggers(finished);
    }

    /// Input-triggered tasks whose input has a new message are queued for it, as arrived at
    /// `now` unless noticed before.
    fn poll_triggers(&mut self, now: Timestamp) {
        for index in 0..self.runners.len() {
            let runner = &mut self.runners[index];
            if runner.trigger().is_none() || !runner.is_scheduled() {
                continue;
            }
            runner.notice_input(now);
            let due = runner.next_due_at(now).map(Timestamp::as_nanos);
            if due != self.queued_ns[index] {
                self.generations[index] += 1;
                self.schedule(index);
            }
        }
    }

    fn trace_activation(
        &mut self,
        index: usize,
        due: Timestamp,
        cost: Duration,
        report: &ActivationReport,
        completion: super::cadence::Completion,
    ) {
        if report.restarted {
            self.push_trace(due, index, TraceKind::Restarted);
        }
        if report.stepped {
            self.push_trace(due, index, TraceKind::Stepped { cost });
        }
        if let Some(failure) = &report.failure {
            let kind = TraceKind::Failed {
                error: failure.message.clone(),
                gave_up: failure.gave_up,
            };
            self.push_trace(due, index, kind);
        }
        if completion.overrun && report.stepped {
            self.push_trace(due, index, TraceKind::Overrun { cost });
        }
        if completion.skipped > 0 {
            let kind = TraceKind::Skipped {
                count: completion.skipped,
            };
            self.push_trace(due, index, kind);
        }
        if report.dropped_inputs > 0 {
            let kind = TraceKind::DroppedInputs {
                count: report.dropped_inputs,
            };
            self.push_trace(due, index, kind);
        }
    }

    fn push_trace(&mut self, time: Timestamp, index: usize, kind: TraceKind) {
        if let Some(trace) = self.trace.as_mut() {
            trace.push(TraceEvent {
                time,
                task: self.names[index].clone(),
                kind,
            });
        }
    }

    /// Queues the task's next activation (none once it failed for good, nor for a triggered
    /// task with nothing to run on).
    fn schedule(&mut self, index: usize) {
        self.queued_ns[index] = None;
        let runner = &self.runners[index];
        if !runner.is_scheduled() {
            return;
        }
        if let Some(due) = runner.next_due_at(self.clock.now()) {
            // A due instant already past (an input noticed before a level change re-queued
            // it) is now: the clock never goes back.
            let due_ns = due.max(self.clock.now()).as_nanos();
            self.queue
                .push(Reverse((due_ns, index, self.generations[index])));
            self.queued_ns[index] = Some(due_ns);
        }
    }

    /// Changes `task`'s QoS level now; its next activation is re-computed from the new period
    /// (at most one new period from now).
    pub fn set_level(&mut self, task: TaskId, level: usize) -> Result<(), SchedulerError> {
        let index = self.index_of_id(task)?;
        let runner = &mut self.runners[index];
        if level >= runner.level_count() {
            return Err(crate::task::LevelError::OutOfRange {
                task: runner.name().to_string(),
                level,
                count: runner.level_count(),
            }
            .into());
        }
        if level == runner.level() {
            return Ok(());
        }
        let now = self.clock.now();
        let failure = runner.change_level(level, now);
        self.push_trace(now, index, TraceKind::LevelChanged { level });
        if let Some(failure) = failure {
            let kind = TraceKind::Failed {
                error: failure.message,
                gave_up: failure.gave_up,
            };
            self.push_trace(now, index, kind);
        }
        if self.started {
            // Invalidate the queued activation computed from the old period.
            self.generations[index] += 1;
            self.schedule(index);
        }
        Ok(())
    }

    /// Enters a phase: tasks the gate does not admit are suspended (their queued activation
    /// dropped), the ones it admits again resume with an activation now.
    pub fn set_phase(&mut self, gate: &PhaseGate) {
        let now = self.clock.now();
        for index in 0..self.runners.len() {
            let Some(active) = self.runners[index].apply_gate(gate, now) else {
                continue;
            };
            let kind = if active {
                TraceKind::Resumed
            } else {
                TraceKind::Suspended
            };
            self.push_trace(now, index, kind);
            if self.started {
                self.generations[index] += 1;
                self.schedule(index);
            }
        }
    }

    fn index_of(&self, task: &str) -> Result<usize, SchedulerError> {
        self.names
            .iter()
            .position(|name| &**name == task)
            .ok_or_else(|| SchedulerError::UnknownTask {
                task: task.to_string(),
                known: self.names.join(", "),
            })
    }

    /// The id of the task named `task`, if the scheduler holds it.
    pub fn task_id(&self, task: &str) -> Option<TaskId> {
        self.index_of(task).ok().map(TaskId)
    }

    /// `task`'s index among the runners, or an error naming the tasks there are.
    fn index_of_id(&self, task: TaskId) -> Result<usize, SchedulerError> {
        if task.0 < self.runners.len() {
            Ok(task.0)
        } else {
            Err(SchedulerError::UnknownTaskId {
                id: task,
                known: self.names.join(", "),
            })
        }
    }

    /// `task`'s QoS level; `None` for an id this scheduler did not give.
    pub fn level(&self, task: TaskId) -> Option<usize> {
        let index = self.index_of_id(task).ok()?;
        Some(self.runners[index].level())
    }

    pub fn now(&self) -> Timestamp {
        self.clock.now()
    }

    /// When `task` next takes an input, if it still runs: a periodic task at its next
    /// activation, an input-triggered one as soon as an input arriving now could run it (a
    /// simulator renders a camera frame only when a consumer will look at it).
    pub fn next_activation(&self, task: TaskId) -> Option<Timestamp> {
        let runner = &self.runners[self.index_of_id(task).ok()?];
        (self.started && runner.is_scheduled()).then(|| runner.next_input_take(self.clock.now()))
    }

    /// A handle on the scheduler's clock, for reading (the scheduler advances it; advancing it
    /// from elsewhere makes the next `run_until` fail with a clock error).
    pub fn clock(&self) -> VirtualClock {
        self.clock.clone()
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

    /// The tasks that are down (restarting or failed for good), in config order.
    pub fn failed_tasks(&self) -> Vec<String> {
        self.health.failed_tasks()
    }

    pub fn stats(&self) -> Vec<TaskStats> {
        self.runners.iter().map(TaskRunner::snapshot).collect()
    }

    pub fn task_stats(&self, task: &str) -> Option<TaskStats> {
        let index = self.index_of(task).ok()?;
        Some(self.runners[index].snapshot())
    }

    /// The trace so far (empty unless the builder asked to record one).
    pub fn trace(&self) -> &[TraceEvent] {
        self.trace.as_deref().unwrap_or(&[])
    }

    pub fn take_trace(&mut self) -> Vec<TraceEvent> {
        self.trace.as_mut().map(std::mem::take).unwrap_or_default()
    }

    /// Stops every task (calls their `stop`); the scheduler cannot run again.
    pub fn stop(&mut self) {
        if self.stopped {
            return;
        }
        self.stopped = true;
        let now = self.clock.now();
        for index in 0..self.runners.len() {
            if self.started {
                self.runners[index].shutdown();
                self.push_trace(now, index, TraceKind::Stopped);
            } else {
                self.runners[index].abandon();
            }
        }
        self.queue.clear();
    }
}

impl Drop for VirtualScheduler {
    fn drop(&mut self) {
        self.stop();
    }
}
