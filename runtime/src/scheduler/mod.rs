//! The scheduler: activates each task at the period of its current QoS level, isolates and
//! restarts failing tasks, and counts what happened.
//!
//! One activation logic (`cadence.rs`) and one task runner (start, step, failure, restart, stats)
//! serve two execution modes:
//! - [`RealTimeScheduler`] (wall clock, for flight): each task on its own worker thread, CPU
//!   tasks optionally pinned to their configured `cores`; the GPU task holds the GPU lease.
//! - [`VirtualScheduler`] (virtual clock, for simulation): a deterministic discrete-event loop in
//!   which a step costs what the task's timing model says, so the same config and seed give the
//!   same activations and messages, far faster than real time.
//!
//! Build either from a [`SchedulerBuilder`]:
//!
//! ```
//! use runtime::bus::{Publisher, Topic};
//! use runtime::catalog::{PluginInfo, Port};
//! use runtime::registry::PluginRegistry;
//! use runtime::scheduler::SchedulerBuilder;
//! use runtime::task::{Task, TaskContext, TaskError};
//! # use runtime::config::{Knob, Resource, TaskConfig};
//!
//! const PING: Topic<u64> = Topic::new("ping", "u64");
//!
//! struct Ping {
//!     output: Publisher<u64>,
//! }
//! impl Task for Ping {
//!     fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
//!         self.output.publish(ctx.now(), ctx.activation());
//!         Ok(())
//!     }
//! }
//!
//! let info = PluginInfo { outputs: const { &[Port::of(PING)] }, ..PluginInfo::user("ping") };
//! let mut registry = PluginRegistry::new();
//! registry
//!     .register_plugin(info, |build| Ok(Box::new(Ping { output: build.output(PING)? })))
//!     .unwrap();
//! # let config = TaskConfig { name: "ping".into(), plugin: "ping".into(), resource: Resource::Cpu,
//! #     cores: vec![], phases: vec!["tracking".into()], weight: 1.0, knob: Knob::PeriodMs,
//! #     levels: vec![100.0, 20.0], utility: vec![0.5, 1.0], restart: None, params: Default::default(),
//! #     config_dir: None };
//! let mut scheduler = SchedulerBuilder::new(&registry).task(&config).build_virtual().unwrap();
//! scheduler.run_for(std::time::Duration::from_secs(1)).unwrap();
//! assert_eq!(scheduler.task_stats("ping").unwrap().activations, 51); // t = 0, 20, …, 1000 ms
//! ```

mod cadence;
mod real_time;
mod resources;
pub(crate) mod stats;
mod timing;
mod virtual_time;

#[cfg(test)]
mod tests;

pub use real_time::{Pinning, RealTimeOptions, RealTimeScheduler};
pub use resources::{ExclusiveResource, ResourceError, ResourceLease, Resources};
pub use stats::{DurationSummary, TaskStats};
pub use timing::{StepCost, TimingError, TimingModel, STEP_COST_PARAM};
pub use virtual_time::{TraceEvent, TraceKind, VirtualScheduler};

use crate::bus::Bus;
use crate::clock::{duration_to_nanos, ClockError, Timestamp};
use crate::config::{Resource, TaskConfig};
use crate::registry::{PluginRegistry, RegistryError, TaskFactory};
use crate::task::{
    panic_message, LevelError, MissionHealth, QosLevel, Task, TaskContext, TaskHealth,
};
use cadence::{Cadence, Completion};
use serde::{Deserialize, Serialize};
use stats::StatsAccum;
use std::collections::HashSet;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;
use timing::{task_seed, SplitMix64};

#[derive(Debug, thiserror::Error)]
pub enum SchedulerError {
    #[error(transparent)]
    Registry(#[from] RegistryError),
    #[error(transparent)]
    Level(#[from] LevelError),
    #[error(transparent)]
    Resource(#[from] ResourceError),
    #[error(transparent)]
    Clock(#[from] ClockError),
    #[error("task `{task}`: {source}")]
    Timing {
        task: String,
        #[source]
        source: TimingError,
    },
    #[error("no task named `{task}`; the tasks are: {known}")]
    UnknownTask { task: String, known: String },
    #[error("task `{task}` is defined twice")]
    DuplicateTask { task: String },
    #[error("task `{task}`: could not pin its worker to cores {cores:?}: {reason}")]
    Pinning {
        task: String,
        cores: Vec<usize>,
        reason: String,
    },
    #[error("could not start the worker thread of task `{task}`: {source}")]
    Spawn {
        task: String,
        #[source]
        source: std::io::Error,
    },
    #[error("the scheduler was already started")]
    AlreadyStarted,
    #[error("the scheduler was stopped; build a new one")]
    Stopped,
}

/// What to do when a task fails. In TOML: `{ policy = "never" }` or
/// `{ policy = "on_failure", max_restarts = 3 }`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "policy", rename_all = "snake_case", deny_unknown_fields)]
pub enum RestartPolicy {
    /// The first failure is final.
    Never,
    /// Build a fresh instance at the next activation, at most `max_restarts` times in the run.
    OnFailure { max_restarts: u32 },
}

impl Default for RestartPolicy {
    /// A few restarts ride out a transient fault (a dropped camera frame buffer) without
    /// letting a task that always fails burn CPU forever.
    fn default() -> Self {
        RestartPolicy::OnFailure { max_restarts: 3 }
    }
}

/// Per-task settings beyond the config.
#[derive(Debug, Clone, Default)]
pub struct TaskOptions {
    pub restart: RestartPolicy,
    /// Level to start at; default the highest (the governor lowers it if the battery needs).
    pub initial_level: Option<usize>,
    /// Virtual time's step cost; default `[task.params] step_cost_ms`, or zero.
    pub timing: Option<TimingModel>,
}

/// Collects tasks and settings, and builds a [`VirtualScheduler`] or a [`RealTimeScheduler`].
/// Each build makes fresh task instances (and, unless one is given, a fresh bus and resources),
/// so one builder can produce two identical virtual runs.
pub struct SchedulerBuilder<'r> {
    registry: &'r PluginRegistry,
    tasks: Vec<(TaskConfig, TaskOptions)>,
    seed: u64,
    bus: Option<Bus>,
    resources: Option<Resources>,
    record_trace: bool,
    gate: PhaseGate,
}

impl<'r> SchedulerBuilder<'r> {
    /// The tasks' seed unless [`Self::seed`] sets another.
    pub const DEFAULT_SEED: u64 = 0;

    pub fn new(registry: &'r PluginRegistry) -> Self {
        SchedulerBuilder {
            registry,
            tasks: Vec::new(),
            seed: Self::DEFAULT_SEED,
            bus: None,
            resources: None,
            record_trace: false,
            gate: PhaseGate::AllTasks,
        }
    }

    /// Adds a task with default options.
    /// Adds a task with the restart policy its config names (or the default).
    pub fn task(&mut self, config: &TaskConfig) -> &mut Self {
        let options = TaskOptions {
            restart: config.restart.unwrap_or_default(),
            ..TaskOptions::default()
        };
        self.task_with(config, options)
    }

    pub fn task_with(&mut self, config: &TaskConfig, options: TaskOptions) -> &mut Self {
        self.tasks.push((config.clone(), options));
        self
    }

    /// Adds tasks as [`Self::task`] does, in order (the order breaks ties in virtual time).
    pub fn tasks<'c>(&mut self, configs: impl IntoIterator<Item = &'c TaskConfig>) -> &mut Self {
        for config in configs {
            self.task(config);
        }
        self
    }

    /// The seed of the tasks' randomness ([`TaskContext::seed`]) and of drawn step costs.
    pub fn seed(&mut self, seed: u64) -> &mut Self {
        self.seed = seed;
        self
    }

    /// Use this bus (to share it with the simulator or the MAVLink link).
    pub fn bus(&mut self, bus: Bus) -> &mut Self {
        self.bus = Some(bus);
        self
    }

    /// Use these resources (to share the GPU with other users of the board).
    pub fn resources(&mut self, resources: Resources) -> &mut Self {
        self.resources = Some(resources);
        self
    }

    /// Which tasks run at start (default: all of them; a mission starts with
    /// [`PhaseGate::NoPhase`] and opens each phase as it begins).
    pub fn phase_gate(&mut self, gate: PhaseGate) -> &mut Self {
        self.gate = gate;
        self
    }

    /// Virtual time only: keep a [`TraceEvent`] for everything that happens.
    pub fn record_trace(&mut self, record: bool) -> &mut Self {
        self.record_trace = record;
        self
    }

    pub fn build_virtual(&self) -> Result<VirtualScheduler, SchedulerError> {
        let parts = self.prepare()?;
        Ok(VirtualScheduler::new(parts, self.record_trace))
    }

    pub fn build_real_time(
        &self,
        options: RealTimeOptions,
    ) -> Result<RealTimeScheduler, SchedulerError> {
        let parts = self.prepare()?;
        Ok(RealTimeScheduler::new(parts, options))
    }

    /// Checks everything a user can get wrong, creates the instances and claims the GPU.
    fn prepare(&self) -> Result<Parts, SchedulerError> {
        let mut names = HashSet::new();
        for (config, _) in &self.tasks {
            if !names.insert(config.name.as_str()) {
                return Err(SchedulerError::DuplicateTask {
                    task: config.name.clone(),
                });
            }
        }
        let bus = self.bus.clone().unwrap_or_default();
        let resources = self.resources.clone().unwrap_or_default();
        let health = MissionHealth::new(
            self.tasks
                .iter()
                .map(|(config, _)| config.name.clone())
                .collect(),
        );
        let mut runners = Vec::with_capacity(self.tasks.len());
        for (index, (config, options)) in self.tasks.iter().enumerate() {
            let factory = self.registry.resolve(config)?;
            let levels = QosLevel::all_of_task(config)?;
            let level = match options.initial_level {
                Some(level) if level >= levels.len() => {
                    return Err(LevelError::OutOfRange {
                        task: config.name.clone(),
                        level,
                        count: levels.len(),
                    }
                    .into())
                }
                Some(level) => level,
                None => levels.len() - 1,
            };
            // The timing model belongs to the scheduler: the plugin never sees its key.
            let mut params = config.params.clone();
            let param_timing = params.remove(STEP_COST_PARAM);
            let timing = match (&options.timing, param_timing) {
                (Some(timing), _) => Some(timing.clone()),
                (None, Some(value)) => Some(
                    TimingModel::from_param(&value, levels.len()).map_err(|source| {
                        SchedulerError::Timing {
                            task: config.name.clone(),
                            source,
                        }
                    })?,
                ),
                (None, None) => None,
            };
            if let Some(timing) = &timing {
                if timing.levels() != levels.len() {
                    return Err(SchedulerError::Timing {
                        task: config.name.clone(),
                        source: TimingError::WrongLength {
                            found: timing.levels(),
                            levels: levels.len(),
                        },
                    });
                }
            }
            let lease = match config.resource {
                Resource::Gpu => Some(resources.gpu().claim(&config.name)?),
                Resource::Cpu => None,
            };
            let instance = factory.create(&params, config, &bus)?;
            let seed = task_seed(self.seed, index);
            let period_ms = levels[level].period_ms;
            runners.push(TaskRunner {
                index,
                config: config.clone(),
                params,
                factory,
                instance: Some(instance),
                cadence: Cadence::new(0, duration_to_nanos(levels[level].period())),
                levels,
                level,
                restart: options.restart,
                restarts: 0,
                timing,
                rng: SplitMix64::new(seed ^ 0x5EED),
                seed,
                activations: 0,
                state: TaskHealth::Running,
                stats: Arc::new(Mutex::new(StatsAccum {
                    level,
                    period_ms,
                    ..StatsAccum::default()
                })),
                health: health.clone(),
                bus: bus.clone(),
                lease,
                active: self.gate.admits(config),
            });
        }
        Ok(Parts {
            runners,
            bus,
            resources,
            health,
        })
    }
}

/// What a build hands to an execution mode.
pub(crate) struct Parts {
    pub runners: Vec<TaskRunner>,
    pub bus: Bus,
    pub resources: Resources,
    pub health: MissionHealth,
}

/// What happened in one activation.
#[derive(Debug, Default)]
pub(crate) struct ActivationReport {
    /// A fresh instance was built (and started) before the step.
    pub restarted: bool,
    /// `step` was called.
    pub stepped: bool,
    pub failure: Option<Failure>,
    /// The step's own cost report (virtual time).
    pub reported_cost: Option<Duration>,
}

#[derive(Debug, Clone)]
pub(crate) struct Failure {
    pub message: String,
    pub gave_up: bool,
}

pub(crate) fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    // Stats and worker state stay consistent under a panic (no step runs under these locks).
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

/// One task's instance and bookkeeping; owned by the virtual loop or by the task's worker thread.
pub(crate) struct TaskRunner {
    index: usize,
    config: TaskConfig,
    /// `[task.params]` without the scheduler's keys.
    params: toml::Table,
    factory: TaskFactory,
    instance: Option<Box<dyn Task>>,
    levels: Vec<QosLevel>,
    level: usize,
    cadence: Cadence,
    restart: RestartPolicy,
    restarts: u32,
    timing: Option<TimingModel>,
    rng: SplitMix64,
    seed: u64,
    activations: u64,
    state: TaskHealth,
    stats: Arc<Mutex<StatsAccum>>,
    health: MissionHealth,
    bus: Bus,
    lease: Option<ResourceLease>,
    /// Runs in the current mission phase; a suspended task is never activated.
    active: bool,
}

/// Which tasks run: every task (a scheduler outside a mission), or those that list the phase.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PhaseGate {
    /// No mission: every task runs.
    AllTasks,
    /// Before the first phase and after the last: no task runs.
    NoPhase,
    /// The tasks whose `phases` list this name run; the others are suspended.
    Phase(String),
}

impl PhaseGate {
    /// Whether a task with this config runs under the gate.
    pub fn admits(&self, config: &TaskConfig) -> bool {
        match self {
            Self::AllTasks => true,
            Self::NoPhase => false,
            Self::Phase(name) => config.runs_in(name),
        }
    }
}

impl TaskRunner {
    pub fn name(&self) -> &str {
        &self.config.name
    }

    pub fn config(&self) -> &TaskConfig {
        &self.config
    }

    pub fn level(&self) -> usize {
        self.level
    }

    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    pub fn stats_handle(&self) -> Arc<Mutex<StatsAccum>> {
        self.stats.clone()
    }

    /// Runs in the mission's current phase.
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// Still activated: not failed for good, and not suspended outside its phases.
    pub fn is_scheduled(&self) -> bool {
        self.state != TaskHealth::Failed && self.active
    }

    /// Applies a phase gate at `now`: a task the gate no longer admits is suspended (its
    /// instance kept, never stepped); one it admits again resumes with an activation at `now`.
    /// Returns the change, if any.
    pub fn apply_gate(&mut self, gate: &PhaseGate, now: Timestamp) -> Option<bool> {
        self.set_active(gate.admits(&self.config), now)
    }

    /// Suspends or resumes the task at `now`; returns the change, if any.
    pub fn set_active(&mut self, active: bool, now: Timestamp) -> Option<bool> {
        if active == self.active {
            return None;
        }
        self.active = active;
        if active {
            self.cadence = Cadence::new(now.as_nanos(), self.cadence.period_ns());
        }
        tracing::info!(task = %self.config.name, "task {}", if active { "resumed" } else { "suspended" });
        Some(active)
    }

    pub fn next_due(&self) -> Timestamp {
        Timestamp::from_nanos(self.cadence.next_ns())
    }

    /// Gives the instance its level and starts it; the first activation is at `first_activation`.
    pub fn start(&mut self, now: Timestamp, first_activation: Timestamp) -> Option<Failure> {
        self.cadence = Cadence::new(first_activation.as_nanos(), self.cadence.period_ns());
        let mut instance = self.instance.take()?;
        let result = self.start_instance(instance.as_mut(), now);
        self.instance = Some(instance);
        match result {
            Ok(()) => {
                tracing::info!(task = %self.config.name, level = self.level, period_ms = self.levels[self.level].period_ms, "task started");
                None
            }
            Err(message) => Some(self.fail(message)),
        }
    }

    /// Moves the first activation to `at` (real time: once every worker has started).
    pub fn reschedule_first(&mut self, at: Timestamp) {
        self.cadence = Cadence::new(at.as_nanos(), self.cadence.period_ns());
    }

    /// `set_qos` then `start`, with panics caught.
    fn start_instance(&mut self, instance: &mut dyn Task, now: Timestamp) -> Result<(), String> {
        let level = &self.levels[self.level];
        let mut ctx = TaskContext::new(&self.config.name, now, level, &self.health, self.seed)
            .with_activation(self.activations);
        let result = catch_unwind(AssertUnwindSafe(|| {
            instance.set_qos(level)?;
            instance.start(&mut ctx)
        }));
        flatten(result)
    }

    /// One activation, run at `now`: rebuild the instance if it failed before, then step.
    pub fn activate(&mut self, now: Timestamp) -> ActivationReport {
        let mut report = ActivationReport::default();
        if self.state == TaskHealth::Failed {
            return report;
        }
        if self.instance.is_none() {
            self.restarts += 1;
            lock(&self.stats).restarts += 1;
            report.restarted = true;
            let created = self
                .factory
                .create(&self.params, &self.config, &self.bus)
                .map_err(|error| error.to_string());
            let started = created.and_then(|mut instance| {
                self.start_instance(instance.as_mut(), now)
                    .map(|()| instance)
            });
            match started {
                Ok(instance) => {
                    self.instance = Some(instance);
                    self.set_state(TaskHealth::Running);
                    tracing::warn!(task = %self.config.name, restarts = self.restarts, "task restarted");
                }
                Err(message) => {
                    report.failure = Some(self.fail(message));
                    return report;
                }
            }
        }
        let Some(instance) = self.instance.as_mut() else {
            return report;
        };
        let mut ctx = TaskContext::new(
            &self.config.name,
            now,
            &self.levels[self.level],
            &self.health,
            self.seed,
        )
        .with_activation(self.activations);
        let result = catch_unwind(AssertUnwindSafe(|| instance.step(&mut ctx)));
        report.reported_cost = ctx.reported_step_cost();
        report.stepped = true;
        self.activations += 1;
        if let Err(message) = flatten(result) {
            report.failure = Some(self.fail(message));
        }
        report
    }

    /// Virtual time's cost of the step just run: its own report, else the timing model, else 0.
    pub fn modelled_cost(&mut self, report: &ActivationReport) -> Duration {
        if !report.stepped {
            return Duration::ZERO;
        }
        report
            .reported_cost
            .or_else(|| {
                let level = self.level;
                let rng = &mut self.rng;
                self.timing.as_ref().map(|timing| timing.cost(level, rng))
            })
            .unwrap_or(Duration::ZERO)
    }

    /// Books the activation due at `due` whose work ran from `started` to `finished`, with the
    /// worker's bookkeeping time after the previous activation (real time).
    pub fn record(
        &mut self,
        due: Timestamp,
        started: Timestamp,
        finished: Timestamp,
        report: &ActivationReport,
        overhead_ns: Option<u64>,
    ) -> Completion {
        let completion =
            self.cadence
                .complete(due.as_nanos(), started.as_nanos(), finished.as_nanos());
        let mut stats = lock(&self.stats);
        if report.stepped {
            stats.activations += 1;
            stats
                .step_time
                .record(finished.as_nanos().saturating_sub(started.as_nanos()));
            stats
                .lateness
                .record(started.as_nanos().saturating_sub(due.as_nanos()));
        }
        if completion.overrun && report.stepped {
            stats.overruns += 1;
        }
        stats.skipped += completion.skipped;
        if let Some(overhead_ns) = overhead_ns {
            stats.overhead.record(overhead_ns);
        }
        drop(stats);
        if completion.overrun && report.stepped {
            tracing::debug!(task = %self.config.name, step_ms = finished.saturating_duration_since(started).as_secs_f64() * 1e3, period_ms = self.levels[self.level].period_ms, "overrun");
        }
        completion
    }

    /// Switches to `level` at `now`: the next activation moves to `last + new period` (or now).
    /// The instance hears of it through `set_qos`; if that fails, the task fails.
    pub fn change_level(&mut self, level: usize, now: Timestamp) -> Option<Failure> {
        if level == self.level || level >= self.levels.len() {
            return None;
        }
        let from = self.level;
        self.level = level;
        let new_level = &self.levels[level];
        self.cadence
            .set_period(duration_to_nanos(new_level.period()), now.as_nanos());
        {
            let mut stats = lock(&self.stats);
            stats.level = level;
            stats.period_ms = new_level.period_ms;
        }
        tracing::info!(task = %self.config.name, from, to = level, knob = %new_level.knob, value = new_level.value, period_ms = new_level.period_ms, "QoS level changed");
        let instance = self.instance.as_mut()?;
        let result = catch_unwind(AssertUnwindSafe(|| instance.set_qos(new_level)));
        flatten(result).err().map(|message| self.fail(message))
    }

    /// The instance failed: stop and drop it, then restart later or give up per the policy.
    fn fail(&mut self, message: String) -> Failure {
        {
            let mut stats = lock(&self.stats);
            stats.failures += 1;
            stats.last_error = Some(message.clone());
        }
        self.discard_instance();
        let gave_up = match self.restart {
            RestartPolicy::Never => true,
            RestartPolicy::OnFailure { max_restarts } => self.restarts >= max_restarts,
        };
        if gave_up {
            self.set_state(TaskHealth::Failed);
            // A task that is gone for good must not keep the GPU from a fallback.
            self.lease = None;
            tracing::error!(task = %self.config.name, error = %message, restarts = self.restarts, "task failed for good; the mission continues degraded");
        } else {
            self.set_state(TaskHealth::Restarting);
            tracing::error!(task = %self.config.name, error = %message, restarts = self.restarts, "task failed; restarting at its next activation");
        }
        Failure { message, gave_up }
    }

    fn discard_instance(&mut self) {
        if let Some(mut instance) = self.instance.take() {
            // A failed instance may be inconsistent: its stop and drop may panic too.
            let stopped = catch_unwind(AssertUnwindSafe(move || {
                instance.stop();
                drop(instance);
            }));
            if let Err(payload) = stopped {
                tracing::warn!(task = %self.config.name, error = %panic_message(payload.as_ref()), "task panicked while being stopped");
            }
        }
    }

    fn set_state(&mut self, state: TaskHealth) {
        self.state = state;
        self.health.set(self.index, state);
    }

    /// Drops an instance that was never started, without calling its `stop`.
    pub fn abandon(&mut self) {
        if let Some(instance) = self.instance.take() {
            if let Err(payload) = catch_unwind(AssertUnwindSafe(move || drop(instance))) {
                tracing::warn!(task = %self.config.name, error = %panic_message(payload.as_ref()), "task panicked while being dropped");
            }
        }
        self.lease = None;
    }

    /// Stops the instance for good (scheduler shutdown).
    pub fn shutdown(&mut self) {
        self.discard_instance();
        self.lease = None;
    }

    pub fn snapshot(&self) -> TaskStats {
        lock(&self.stats).snapshot(&self.config.name, self.state)
    }
}

/// What the mission runner needs of a scheduler, whichever clock drives it.
pub trait TaskScheduler {
    /// The scheduler's clock: what its tasks stamp their messages with.
    fn now(&self) -> Timestamp;
    fn bus(&self) -> &Bus;
    fn start(&mut self) -> Result<(), SchedulerError>;
    /// Virtual time: runs every activation due up to `now`. Real time: the workers run by
    /// themselves, so nothing.
    fn run_until(&mut self, now: Timestamp) -> Result<(), SchedulerError>;
    fn level(&self, task: &str) -> Option<usize>;
    fn set_level(&mut self, task: &str, level: usize) -> Result<(), SchedulerError>;
    fn set_phase(&mut self, gate: &PhaseGate);
    /// When `task` next steps, where the scheduler knows ahead (virtual time).
    fn next_activation(&self, task: &str) -> Option<Timestamp>;
    fn stats(&self) -> Vec<TaskStats>;
    fn failed_tasks(&self) -> Vec<String>;
    fn stop(&mut self);
}

impl TaskScheduler for VirtualScheduler {
    fn now(&self) -> Timestamp {
        VirtualScheduler::now(self)
    }
    fn bus(&self) -> &Bus {
        VirtualScheduler::bus(self)
    }
    fn start(&mut self) -> Result<(), SchedulerError> {
        VirtualScheduler::start(self)
    }
    fn run_until(&mut self, now: Timestamp) -> Result<(), SchedulerError> {
        VirtualScheduler::run_until(self, now).map(|_| ())
    }
    fn level(&self, task: &str) -> Option<usize> {
        VirtualScheduler::level(self, task)
    }
    fn set_level(&mut self, task: &str, level: usize) -> Result<(), SchedulerError> {
        VirtualScheduler::set_level(self, task, level)
    }
    fn set_phase(&mut self, gate: &PhaseGate) {
        VirtualScheduler::set_phase(self, gate)
    }
    fn next_activation(&self, task: &str) -> Option<Timestamp> {
        VirtualScheduler::next_activation(self, task)
    }
    fn stats(&self) -> Vec<TaskStats> {
        VirtualScheduler::stats(self)
    }
    fn failed_tasks(&self) -> Vec<String> {
        VirtualScheduler::failed_tasks(self)
    }
    fn stop(&mut self) {
        VirtualScheduler::stop(self)
    }
}

impl TaskScheduler for RealTimeScheduler {
    fn now(&self) -> Timestamp {
        RealTimeScheduler::now(self)
    }
    fn bus(&self) -> &Bus {
        RealTimeScheduler::bus(self)
    }
    fn start(&mut self) -> Result<(), SchedulerError> {
        RealTimeScheduler::start(self)
    }
    fn run_until(&mut self, _now: Timestamp) -> Result<(), SchedulerError> {
        Ok(())
    }
    fn level(&self, task: &str) -> Option<usize> {
        RealTimeScheduler::level(self, task)
    }
    fn set_level(&mut self, task: &str, level: usize) -> Result<(), SchedulerError> {
        RealTimeScheduler::set_level(self, task, level)
    }
    fn set_phase(&mut self, gate: &PhaseGate) {
        RealTimeScheduler::set_phase(self, gate)
    }
    fn next_activation(&self, _task: &str) -> Option<Timestamp> {
        None
    }
    fn stats(&self) -> Vec<TaskStats> {
        RealTimeScheduler::stats(self)
    }
    fn failed_tasks(&self) -> Vec<String> {
        RealTimeScheduler::failed_tasks(self)
    }
    fn stop(&mut self) {
        RealTimeScheduler::stop(self)
    }
}

/// A scheduler chosen at run time (the simulator's harness flies in virtual or in real time).
impl TaskScheduler for Box<dyn TaskScheduler> {
    fn now(&self) -> Timestamp {
        (**self).now()
    }
    fn bus(&self) -> &Bus {
        (**self).bus()
    }
    fn start(&mut self) -> Result<(), SchedulerError> {
        (**self).start()
    }
    fn run_until(&mut self, now: Timestamp) -> Result<(), SchedulerError> {
        (**self).run_until(now)
    }
    fn level(&self, task: &str) -> Option<usize> {
        (**self).level(task)
    }
    fn set_level(&mut self, task: &str, level: usize) -> Result<(), SchedulerError> {
        (**self).set_level(task, level)
    }
    fn set_phase(&mut self, gate: &PhaseGate) {
        (**self).set_phase(gate)
    }
    fn next_activation(&self, task: &str) -> Option<Timestamp> {
        (**self).next_activation(task)
    }
    fn stats(&self) -> Vec<TaskStats> {
        (**self).stats()
    }
    fn failed_tasks(&self) -> Vec<String> {
        (**self).failed_tasks()
    }
    fn stop(&mut self) {
        (**self).stop()
    }
}

fn flatten(result: std::thread::Result<Result<(), crate::task::TaskError>>) -> Result<(), String> {
    match result {
        Ok(Ok(())) => Ok(()),
        Ok(Err(error)) => Err(error.to_string()),
        Err(payload) => Err(panic_message(payload.as_ref())),
    }
}
