//! The task plugin interface: what a piece of mission computation (marker detection, tracking,
//! landing guidance, the hazard CNN, or a user's own) implements to be hosted by the scheduler.
//!
//! Lifecycle of one instance:
//! 1. a factory registered under the plugin's name (see [`crate::registry`]) builds it from a
//!    [`TaskBuild`]: its `[task.params]`, its [`TaskConfig`] and its ports on the bus, which the
//!    instance holds from then on (a step cannot run without them);
//! 2. [`Task::set_qos`] gives it its first QoS level, then [`Task::start`] runs once;
//! 3. [`Task::step`] runs at every activation, at the period of the current level;
//!    [`Task::set_qos`] runs again (between steps) whenever the level changes;
//! 4. [`Task::stop`] runs once at shutdown, or after a failure before the instance is dropped.
//!
//! A step that returns an error or panics fails the instance: the scheduler drops it and, per the
//! task's restart policy, builds a fresh one from the factory.

use crate::bus::{
    Bus, BusError, Publisher, QueueReceiver, QueueSender, QueueSpec, Subscriber, Topic,
};
use crate::catalog::PluginInfo;
use crate::clock::Timestamp;
use crate::config::{Knob, TaskConfig};
use serde::de::DeserializeOwned;
use std::fmt;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

/// A task plugin. `Send` because the real-time scheduler moves it onto its worker thread.
pub trait Task: Send {
    /// Runs once before the first step (after the first [`Task::set_qos`]): open devices, warm
    /// up. An error fails the instance like a failed step.
    fn start(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let _ = ctx;
        Ok(())
    }

    /// One activation: read inputs from the bus, compute, publish.
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError>;

    /// Runs once at shutdown, or after a failure before the instance is dropped.
    fn stop(&mut self) {}

    /// The task's QoS level changed (also called once before [`Task::start`]). The scheduler
    /// already changes the activation period; this is for the plugin's own knobs.
    fn set_qos(&mut self, level: &QosLevel) -> Result<(), TaskError> {
        let _ = level;
        Ok(())
    }
}

/// Why a task failed.
#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    #[error("bad [task.params]: {0}")]
    Params(String),
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error("plugin `{plugin}` does not declare {direction} `{topic}` in its catalogue entry")]
    UndeclaredPort {
        plugin: &'static str,
        topic: &'static str,
        direction: &'static str,
    },
    #[error("{0}")]
    Failed(String),
    #[error(transparent)]
    Other(Box<dyn std::error::Error + Send + Sync>),
}

impl TaskError {
    pub fn failed(message: impl Into<String>) -> Self {
        TaskError::Failed(message.into())
    }

    pub fn other(error: impl std::error::Error + Send + Sync + 'static) -> Self {
        TaskError::Other(Box::new(error))
    }
}

/// What a plugin's factory builds a task from: its `[task.params]`, its config, and its ports on
/// the bus. Only the ports its catalogue entry declares can be taken, so the dataflow
/// `qosrt check --graph` draws from the catalogue is the one that runs.
pub struct TaskBuild<'a> {
    params: &'a toml::Table,
    config: &'a TaskConfig,
    plugin: &'a PluginInfo,
    bus: &'a Bus,
}

impl<'a> TaskBuild<'a> {
    /// `params` are the task's `[task.params]` less the scheduler's own keys.
    pub fn new(
        params: &'a toml::Table,
        config: &'a TaskConfig,
        plugin: &'a PluginInfo,
        bus: &'a Bus,
    ) -> Self {
        TaskBuild {
            params,
            config,
            plugin,
            bus,
        }
    }

    pub fn params(&self) -> &'a toml::Table {
        self.params
    }

    pub fn config(&self) -> &'a TaskConfig {
        self.config
    }

    /// Parses the params into the plugin's own settings type.
    pub fn parse_params<P: DeserializeOwned>(&self) -> Result<P, TaskError> {
        parse_params(self.params)
    }

    /// A subscriber to the declared input `topic`.
    pub fn input<T: Send + Sync + 'static>(
        &self,
        topic: Topic<T>,
    ) -> Result<Subscriber<T>, TaskError> {
        self.declared(self.plugin.inputs, topic.name(), "input")?;
        Ok(self.bus.subscriber(topic)?)
    }

    /// A publisher on the declared output `topic`.
    pub fn output<T: Send + Sync + 'static>(
        &self,
        topic: Topic<T>,
    ) -> Result<Publisher<T>, TaskError> {
        self.declared(self.plugin.outputs, topic.name(), "output")?;
        Ok(self.bus.publisher(topic)?)
    }

    /// The receiver of the declared input queue `topic`.
    pub fn queue_input<T: Send + 'static>(
        &self,
        topic: Topic<T>,
        spec: QueueSpec,
    ) -> Result<QueueReceiver<T>, TaskError> {
        self.declared(self.plugin.inputs, topic.name(), "input")?;
        Ok(self.bus.queue_receiver(topic, spec)?)
    }

    /// A sender on the declared output queue `topic`.
    pub fn queue_output<T: Send + 'static>(
        &self,
        topic: Topic<T>,
        spec: QueueSpec,
    ) -> Result<QueueSender<T>, TaskError> {
        self.declared(self.plugin.outputs, topic.name(), "output")?;
        Ok(self.bus.queue_sender(topic, spec)?)
    }

    fn declared(
        &self,
        ports: &[crate::catalog::Port],
        topic: &'static str,
        direction: &'static str,
    ) -> Result<(), TaskError> {
        if ports.iter().any(|port| port.topic == topic) {
            Ok(())
        } else {
            Err(TaskError::UndeclaredPort {
                plugin: self.plugin.name,
                topic,
                direction,
            })
        }
    }
}

/// Parses a plugin's `[task.params]` into its own settings type (with `#[serde(deny_unknown_fields)]`
/// a misspelt key is an error naming it).
pub fn parse_params<P: DeserializeOwned>(params: &toml::Table) -> Result<P, TaskError> {
    params
        .clone()
        .try_into()
        .map_err(|error: toml::de::Error| TaskError::Params(error.message().to_string()))
}

/// A plugin call's own result, or its panic as a [`TaskError::Failed`] naming the panic.
pub(crate) fn panic_as_failure<T>(
    result: std::thread::Result<Result<T, TaskError>>,
) -> Result<T, TaskError> {
    result.unwrap_or_else(|payload| Err(TaskError::Failed(panic_message(payload.as_ref()))))
}

/// The message of a caught panic, for the failure report.
pub(crate) fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(message) = payload.downcast_ref::<&str>() {
        format!("panicked: {message}")
    } else if let Some(message) = payload.downcast_ref::<String>() {
        format!("panicked: {message}")
    } else {
        "panicked".to_string()
    }
}

/// One QoS level of a task: its index (0 = lowest QoS), the knob and its value, and the
/// activation period that follows from it.
#[derive(Debug, Clone, PartialEq)]
pub struct QosLevel {
    pub index: usize,
    pub knob: Knob,
    pub value: f64,
    pub period_ms: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LevelError {
    #[error("task `{task}` has no level {level}; its levels are 0..={}", count.saturating_sub(1))]
    OutOfRange {
        task: String,
        level: usize,
        count: usize,
    },
    #[error("task `{task}` has no QoS levels")]
    NoLevels { task: String },
    #[error("task `{task}` level {index}: {knob} = {value} gives no usable period (need a finite period of at least 1 µs)")]
    BadValue {
        task: String,
        index: usize,
        knob: Knob,
        value: f64,
    },
}

impl QosLevel {
    /// Level `index` of `task`.
    pub fn of_task(task: &TaskConfig, index: usize) -> Result<Self, LevelError> {
        let value = *task
            .levels
            .get(index)
            .ok_or_else(|| LevelError::OutOfRange {
                task: task.name.clone(),
                level: index,
                count: task.levels.len(),
            })?;
        let period_ms = task.knob.period_ms(value);
        // Sub-microsecond or non-finite periods would make the scheduler spin; reject them here
        // even though the config check should have already.
        if !(period_ms.is_finite() && period_ms >= 1e-3) {
            return Err(LevelError::BadValue {
                task: task.name.clone(),
                index,
                knob: task.knob,
                value,
            });
        }
        Ok(QosLevel {
            index,
            knob: task.knob,
            value,
            period_ms,
        })
    }

    /// Every level of `task`, lowest QoS first.
    pub fn all_of_task(task: &TaskConfig) -> Result<Vec<Self>, LevelError> {
        if task.levels.is_empty() {
            return Err(LevelError::NoLevels {
                task: task.name.clone(),
            });
        }
        (0..task.levels.len())
            .map(|index| Self::of_task(task, index))
            .collect()
    }

    pub fn period(&self) -> Duration {
        Duration::from_nanos((self.period_ms * 1e6).round() as u64)
    }
}

/// A task's health as the rest of the mission sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum TaskHealth {
    Running,
    /// Failed; a fresh instance is built at its next activation.
    Restarting,
    /// Failed for good (restart policy `never`, or its restarts are used up).
    Failed,
}

impl fmt::Display for TaskHealth {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            TaskHealth::Running => "running",
            TaskHealth::Restarting => "restarting",
            TaskHealth::Failed => "failed",
        })
    }
}

/// Which tasks are down: the mission is degraded while any is. Shared by the scheduler (which
/// writes it) and every task's context and the landing logic (which read it).
#[derive(Clone)]
pub struct MissionHealth {
    inner: Arc<HealthInner>,
}

struct HealthInner {
    names: Vec<String>,
    states: Mutex<Vec<TaskHealth>>,
    // Kept beside the states so the hot-path question "degraded?" is one atomic load.
    down: AtomicUsize,
}

impl fmt::Debug for MissionHealth {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_map().entries(self.snapshot()).finish()
    }
}

impl MissionHealth {
    /// Every named task running.
    pub fn new(names: Vec<String>) -> Self {
        let states = vec![TaskHealth::Running; names.len()];
        MissionHealth {
            inner: Arc::new(HealthInner {
                names,
                states: Mutex::new(states),
                down: AtomicUsize::new(0),
            }),
        }
    }

    pub(crate) fn set(&self, index: usize, health: TaskHealth) {
        let mut states = self
            .inner
            .states
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let Some(state) = states.get_mut(index) else {
            return;
        };
        let was_down = *state != TaskHealth::Running;
        let is_down = health != TaskHealth::Running;
        *state = health;
        match (was_down, is_down) {
            (false, true) => {
                self.inner.down.fetch_add(1, Ordering::AcqRel);
            }
            (true, false) => {
                self.inner.down.fetch_sub(1, Ordering::AcqRel);
            }
            _ => {}
        }
    }

    /// Whether any task is down (restarting or failed for good).
    pub fn is_degraded(&self) -> bool {
        self.inner.down.load(Ordering::Acquire) > 0
    }

    /// The tasks that are down, in config order.
    pub fn failed_tasks(&self) -> Vec<String> {
        self.snapshot()
            .into_iter()
            .filter(|(_, health)| *health != TaskHealth::Running)
            .map(|(name, _)| name)
            .collect()
    }

    pub fn health_of(&self, task: &str) -> Option<TaskHealth> {
        let index = self.inner.names.iter().position(|name| name == task)?;
        let states = self
            .inner
            .states
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        states.get(index).copied()
    }

    pub fn snapshot(&self) -> Vec<(String, TaskHealth)> {
        let states = self
            .inner
            .states
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        self.inner
            .names
            .iter()
            .cloned()
            .zip(states.iter().copied())
            .collect()
    }
}

/// What a task sees during `start` and `step`.
pub struct TaskContext<'a> {
    name: &'a str,
    now: Timestamp,
    activation: u64,
    level: &'a QosLevel,
    health: &'a MissionHealth,
    seed: u64,
    reported_step_cost: Option<Duration>,
}

impl<'a> TaskContext<'a> {
    /// A context for driving a task by hand (a plugin's unit tests); the scheduler builds its own.
    pub fn new(
        name: &'a str,
        now: Timestamp,
        level: &'a QosLevel,
        health: &'a MissionHealth,
        seed: u64,
    ) -> Self {
        TaskContext {
            name,
            now,
            activation: 0,
            level,
            health,
            seed,
            reported_step_cost: None,
        }
    }

    pub(crate) fn with_activation(mut self, activation: u64) -> Self {
        self.activation = activation;
        self
    }

    /// The task's name in the config.
    pub fn name(&self) -> &str {
        self.name
    }

    /// The activation instant on the scheduler's clock (virtual or wall). Stamp messages with it.
    pub fn now(&self) -> Timestamp {
        self.now
    }

    /// How many activations this task has had before this one (0 during `start` and the first step).
    pub fn activation(&self) -> u64 {
        self.activation
    }

    /// The current QoS level.
    pub fn level(&self) -> &QosLevel {
        self.level
    }

    /// Whether any task of the mission is down: the landing logic switches to its safe mode.
    pub fn is_degraded(&self) -> bool {
        self.health.is_degraded()
    }

    /// The tasks that are down, in config order.
    pub fn failed_tasks(&self) -> Vec<String> {
        self.health.failed_tasks()
    }

    pub fn health(&self) -> &MissionHealth {
        self.health
    }

    /// A seed for the task's own randomness, fixed by the scheduler's seed and the task's place
    /// in the config, so a virtual-time run replays exactly.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// In virtual time, how long this step takes (the task's own timing model); it overrides the
    /// scheduler's per-level figure. Ignored in real time, where the measured time counts.
    pub fn report_step_cost(&mut self, cost: Duration) {
        self.reported_step_cost = Some(cost);
    }

    pub(crate) fn reported_step_cost(&self) -> Option<Duration> {
        self.reported_step_cost
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Resource;

    fn task(knob: Knob, levels: Vec<f64>) -> TaskConfig {
        TaskConfig {
            name: "detection".into(),
            plugin: "landing_marker".into(),
            resource: Resource::Cpu,
            cores: vec![],
            phases: vec!["landing".into()],
            weight: 1.0,
            knob,
            utility: vec![0.5; levels.len()],
            levels,
            restart: None,
            params: toml::Table::new(),
            trigger: Default::default(),
            max_idle_ms: None,
            config_dir: None,
            camera: Default::default(),
        }
    }

    #[test]
    fn levels_carry_knob_value_and_period() {
        let levels = QosLevel::all_of_task(&task(Knob::RateFps, vec![0.5, 10.0])).unwrap();
        assert_eq!(levels[1].index, 1);
        assert_eq!(levels[1].value, 10.0);
        assert_eq!(levels[1].period_ms, 100.0);
        assert_eq!(levels[0].period(), Duration::from_secs(2));
        let by_period = QosLevel::of_task(&task(Knob::PeriodMs, vec![20.0]), 0).unwrap();
        assert_eq!(by_period.period(), Duration::from_millis(20));
    }

    #[test]
    fn bad_levels_are_named_errors() {
        assert!(matches!(
            QosLevel::of_task(&task(Knob::RateFps, vec![1.0]), 3),
            Err(LevelError::OutOfRange {
                level: 3,
                count: 1,
                ..
            })
        ));
        assert!(matches!(
            QosLevel::all_of_task(&task(Knob::RateFps, vec![1.0, 0.0])),
            Err(LevelError::BadValue { index: 1, .. })
        ));
        assert!(matches!(
            QosLevel::all_of_task(&task(Knob::PeriodMs, vec![f64::NAN])),
            Err(LevelError::BadValue { index: 0, .. })
        ));
        assert!(matches!(
            QosLevel::all_of_task(&task(Knob::PeriodMs, vec![])),
            Err(LevelError::NoLevels { .. })
        ));
    }

    #[test]
    fn health_tracks_which_tasks_are_down() {
        let health = MissionHealth::new(vec!["a".into(), "b".into(), "c".into()]);
        assert!(!health.is_degraded());
        health.set(1, TaskHealth::Restarting);
        health.set(2, TaskHealth::Failed);
        assert!(health.is_degraded());
        assert_eq!(
            health.failed_tasks(),
            vec!["b".to_string(), "c".to_string()]
        );
        health.set(1, TaskHealth::Running);
        health.set(2, TaskHealth::Failed); // no double count
        assert_eq!(health.failed_tasks(), vec!["c".to_string()]);
        health.set(2, TaskHealth::Running);
        assert!(!health.is_degraded());
        assert_eq!(health.health_of("b"), Some(TaskHealth::Running));
        assert_eq!(health.health_of("zz"), None);
        health.set(9, TaskHealth::Failed); // out of range: ignored
        assert!(!health.is_degraded());
    }

    #[test]
    fn params_parse_into_the_plugins_type_with_named_errors() {
        #[derive(serde::Deserialize, Debug, PartialEq)]
        #[serde(deny_unknown_fields)]
        struct Params {
            kernel_size_px: u32,
        }
        let good: toml::Table = toml::from_str("kernel_size_px = 13").unwrap();
        assert_eq!(
            parse_params::<Params>(&good).unwrap(),
            Params { kernel_size_px: 13 }
        );
        let bad: toml::Table = toml::from_str("kernel_size = 13").unwrap();
        let message = parse_params::<Params>(&bad).unwrap_err().to_string();
        assert!(message.contains("kernel_size"), "{message}");
    }
}
