//! Scheduler behaviour, in virtual and real time, with small test-only tasks.

use super::*;
use crate::bus::{Message, QueueSpec, Topic, TopicInfo};
use crate::catalog::{PluginCatalog, PluginInfo, Port, BUILTIN_PLUGINS};
use crate::config::{load_str, Knob, MissionConfig};
use crate::task::{TaskBuild, TaskError};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

const REFERENCE: &str = include_str!("../../../../qos.toml");
const MS: u64 = 1_000_000;

/// What a probe saw at one activation.
#[derive(Debug, Clone, PartialEq)]
struct Seen {
    task: String,
    at: Timestamp,
    level: usize,
    degraded: bool,
    failed: Vec<String>,
}

type Log = Arc<Mutex<Vec<Seen>>>;

#[derive(Debug, Default, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
struct ProbeParams {
    /// Panic at this step of every instance (0 = its first step).
    panic_on_step: Option<u64>,
    /// Return an error at this step of every instance.
    error_on_step: Option<u64>,
    /// Panic once, at this activation of the task across instances.
    panic_once_at: Option<u64>,
    fail_start: bool,
    /// Real time: sleep this long in every step.
    sleep_ms: Option<u64>,
    /// Virtual time: report this step cost.
    report_cost_ms: Option<u64>,
}

/// A test task: logs every activation, and misbehaves as its params say.
struct Probe {
    params: ProbeParams,
    steps: u64,
    log: Log,
    crashes: Arc<AtomicU64>,
    stops: Arc<AtomicU64>,
}

impl Task for Probe {
    fn start(&mut self, _ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        if self.params.fail_start {
            return Err(TaskError::failed("camera not found"));
        }
        Ok(())
    }

    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        self.log.lock().unwrap().push(Seen {
            task: ctx.name().to_string(),
            at: ctx.now(),
            level: ctx.level().index,
            degraded: ctx.is_degraded(),
            failed: ctx.failed_tasks(),
        });
        let step = self.steps;
        self.steps += 1;
        if self.params.panic_on_step == Some(step) {
            panic!("probe panics at step {step}");
        }
        if self.params.error_on_step == Some(step) {
            return Err(TaskError::failed(format!("probe fails at step {step}")));
        }
        if self.params.panic_once_at == Some(ctx.activation())
            && self.crashes.fetch_add(1, Ordering::SeqCst) == 0
        {
            panic!("probe panics once");
        }
        if let Some(sleep_ms) = self.params.sleep_ms {
            std::thread::sleep(Duration::from_millis(sleep_ms));
        }
        if let Some(cost_ms) = self.params.report_cost_ms {
            ctx.report_step_cost(Duration::from_millis(cost_ms));
        }
        Ok(())
    }

    fn stop(&mut self) {
        self.stops.fetch_add(1, Ordering::SeqCst);
    }
}

struct Probes {
    registry: PluginRegistry,
    log: Log,
    stops: Arc<AtomicU64>,
}

/// A task with a trivial step.
struct Idle;

impl Task for Idle {
    fn step(&mut self, _ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        Ok(())
    }
}

/// A registry with the probe under the name "probe", and the idle task under every built-in
/// plugin name (so the reference mission runs with trivial steps).
fn probes() -> Probes {
    let log: Log = Arc::default();
    let stops = Arc::new(AtomicU64::new(0));
    let crashes = Arc::new(AtomicU64::new(0));
    let mut registry = PluginRegistry::new();
    let factory = {
        let (log, stops) = (log.clone(), stops.clone());
        move |build: &TaskBuild<'_>| -> Result<Box<dyn Task>, TaskError> {
            Ok(Box::new(Probe {
                params: build.parse_params()?,
                steps: 0,
                log: log.clone(),
                crashes: crashes.clone(),
                stops: stops.clone(),
            }))
        }
    };
    registry.register("probe", factory).unwrap();
    for info in BUILTIN_PLUGINS {
        registry
            .register_plugin(info.clone(), |_: &TaskBuild<'_>| {
                Ok(Box::new(Idle) as Box<dyn Task>)
            })
            .unwrap();
    }
    Probes {
        registry,
        log,
        stops,
    }
}

fn probe(name: &str, knob: Knob, levels: &[f64], params: &str) -> TaskConfig {
    TaskConfig {
        name: name.into(),
        plugin: "probe".into(),
        resource: Resource::Cpu,
        cores: vec![],
        phases: vec!["tracking".into()],
        weight: 1.0,
        knob,
        utility: (0..levels.len())
            .map(|i| (i + 1) as f64 / levels.len() as f64)
            .collect(),
        levels: levels.to_vec(),
        restart: None,
        params: toml::from_str(params).unwrap(),
        trigger: Default::default(),
        max_idle_ms: None,
        config_dir: None,
        camera: Default::default(),
    }
}

/// Real time without pinning: the tests' tasks run wherever the machine has room.
fn unpinned() -> RealTimeOptions {
    RealTimeOptions {
        pinning: Pinning::Off,
        ..RealTimeOptions::default()
    }
}

fn times_of(log: &Log, task: &str) -> Vec<u64> {
    log.lock()
        .unwrap()
        .iter()
        .filter(|seen| seen.task == task)
        .map(|seen| seen.at.as_nanos())
        .collect()
}

fn reference(catalog: &PluginCatalog) -> MissionConfig {
    load_str(REFERENCE, None, catalog).expect("the reference mission loads")
}

mod failures;
mod phases;
mod rates;
mod replay;
mod setup;
mod timing;
mod triggers;
