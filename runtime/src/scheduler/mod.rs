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
//! #     trigger: Default::default(), max_idle_ms: None,
//! #     config_dir: None, camera: Default::default() };
//! let mut scheduler = SchedulerBuilder::new(&registry).task(&config).build_virtual().unwrap();
//! scheduler.run_for(std::time::Duration::from_secs(1)).unwrap();
//! assert_eq!(scheduler.task_stats("ping").unwrap().activations, 51); // t = 0, 20, …, 1000 ms
//! ```

mod cadence;
mod real_time;
mod resources;
mod runner;
pub(crate) mod stats;
mod task_scheduler;
mod timing;
mod trigger;
mod virtual_time;

#[cfg(test)]
mod tests;

pub(crate) use real_time::os::lower_current_thread_priority;
pub use real_time::{PinError, Pinning, RealTimeOptions, RealTimeScheduler};
pub use resources::{ExclusiveResource, ResourceError, ResourceLease, Resources};
pub use stats::{DurationSummary, TaskStats};
pub use task_scheduler::TaskScheduler;
pub use timing::{StepCost, TimingError, TimingModel, STEP_COST_PARAM};
pub use virtual_time::{TraceEvent, TraceKind, VirtualScheduler};
// A task's restart policy is config, read by the runner.
pub use crate::config::RestartPolicy;

use crate::bus::Bus;
use crate::clock::{duration_to_nanos, ClockError, Timestamp};
use crate::config::{Resource, TaskConfig};
use crate::registry::{PluginRegistry, RegistryError, TaskFactory};
use crate::task::{
    panic_message, LevelError, MissionHealth, QosLevel, Task, TaskContext, TaskHealth,
};
use cadence::Cadence;
use stats::StatsAccum;
use std::collections::HashSet;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

pub(crate) use runner::{lock, ActivationReport, Parts, TaskRunner};
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
    /// A [`TaskId`] this scheduler did not hand out (one of another scheduler's).
    #[error("no task with id {id} in this scheduler (an id of another scheduler?); the tasks are: {known}")]
    UnknownTaskId { id: TaskId, known: String },
    #[error("task `{task}` is defined twice")]
    DuplicateTask { task: String },
    // The cores appear twice, as they always have.
    #[error(
        "task `{task}`: could not pin its worker to cores {cores:?}: cores {cores:?}: {source}"
    )]
    Pinning {
        task: String,
        cores: Vec<usize>,
        #[source]
        source: PinError,
    },
    #[error("could not start the worker thread of task `{task}`: {source}")]
    Spawn {
        task: String,
        #[source]
        source: std::io::Error,
    },
    #[error("task `{task}`: its trigger: {source}")]
    Trigger {
        task: String,
        #[source]
        source: crate::bus::BusError,
    },
    #[error("the scheduler was already started")]
    AlreadyStarted,
    #[error("the scheduler was stopped; build a new one")]
    Stopped,
}

/// A scheduler's handle on one of its tasks: its place in the order the tasks were added to
/// the [`SchedulerBuilder`] (which is not a task's place in a mission config when the config has
/// tasks the scheduler does not hold). Get it once by name with [`TaskScheduler::task_id`]
/// (or the schedulers' own `task_id`), then change and read the task's level, and ask when it
/// next runs, without looking its name up again. Only meaningful to the scheduler that gave it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TaskId(usize);

impl TaskId {
    /// The task's place among the scheduler's tasks (the order of [`TaskScheduler::stats`]).
    pub fn index(self) -> usize {
        self.0
    }
}

impl std::fmt::Display for TaskId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "#{}", self.0)
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
            let trigger = match config.trigger.input() {
                None => None,
                Some(topic) => {
                    let activity =
                        bus.activity(topic)
                            .map_err(|source| SchedulerError::Trigger {
                                task: config.name.clone(),
                                source,
                            })?;
                    let max_idle_ns = config
                        .max_idle_ms
                        .filter(|ms| ms.is_finite() && *ms > 0.0)
                        .map(|ms| duration_to_nanos(Duration::from_secs_f64(ms / 1e3)));
                    Some(trigger::InputTrigger::new(activity, max_idle_ns))
                }
            };
            let seed = task_seed(self.seed, index);
            let period_ms = levels[level].period_ms;
            runners.push(TaskRunner {
                index,
                config: config.clone(),
                params,
                factory,
                instance: Some(instance),
                cadence: Cadence::new(0, duration_to_nanos(levels[level].period())),
                trigger,
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
