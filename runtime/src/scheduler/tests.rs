//! Scheduler behaviour, in virtual and real time, with small test-only tasks.

use super::*;
use crate::bus::{Message, QueueSpec, Topic, TopicInfo};
use crate::catalog::{PluginCatalog, PluginInfo, Port, BUILTIN_PLUGINS};
use crate::config::{load_str, Knob, MissionConfig};
use crate::task::{TaskBuild, TaskError};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

const REFERENCE: &str = include_str!("../../../qos.toml");
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
        config_dir: None,
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

// ---------------------------------------------------------------------------------------------
// Deterministic replay

#[derive(Debug, Clone, PartialEq)]
struct Observation {
    id: u64,
    from_seq: u64,
}

/// The reference mission's four roles wired over the bus, with random values from the task seed
/// and step costs drawn from measured samples.
struct Stage {
    rng: SplitMix64,
    input: Option<crate::bus::Subscriber<Observation>>,
    output: Option<crate::bus::Publisher<Observation>>,
    commands: Option<crate::bus::QueueSender<Observation>>,
    received: Option<crate::bus::QueueReceiver<Observation>>,
    record: Record,
}

type Record = Arc<Mutex<Vec<(String, Message<Observation>)>>>;

const MARKER: Topic<Observation> = Topic::new("marker", "Observation");
const RELATIVE: Topic<Observation> = Topic::new("relative_state", "Observation");
const SETPOINTS: Topic<Observation> = Topic::new("setpoints", "Observation");

impl Stage {
    /// The stage's ports for its role: (inputs, outputs).
    fn ports(role: &str) -> (&'static [Port], &'static [Port]) {
        match role {
            "landing_marker" => (&[], const { &[Port::of(MARKER)] }),
            "kalman_tracker" => (
                const { &[Port::of(MARKER)] },
                const { &[Port::of(RELATIVE)] },
            ),
            "landing_guidance" => (
                const { &[Port::of(RELATIVE)] },
                const { &[Port::of(SETPOINTS)] },
            ),
            _ => (const { &[Port::of(SETPOINTS)] }, &[]),
        }
    }

    fn new(role: &'static str, record: Record, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        let mut stage = Stage {
            rng: SplitMix64::new(0),
            input: None,
            output: None,
            commands: None,
            received: None,
            record,
        };
        match role {
            "landing_marker" => stage.output = Some(build.output(MARKER)?),
            "kalman_tracker" => {
                stage.input = Some(build.input(MARKER)?);
                stage.output = Some(build.output(RELATIVE)?);
            }
            "landing_guidance" => {
                stage.input = Some(build.input(RELATIVE)?);
                stage.commands = Some(build.queue_output(SETPOINTS, QueueSpec::drop_oldest(4))?);
            }
            _ => stage.received = Some(build.queue_input(SETPOINTS, QueueSpec::drop_oldest(4))?),
        }
        Ok(stage)
    }
}

impl Task for Stage {
    fn start(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        self.rng = SplitMix64::new(ctx.seed());
        Ok(())
    }

    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let from_seq = match self.input.as_mut() {
            Some(input) => match input.take_new() {
                Some(message) => message.seq,
                None => return Ok(()),
            },
            None => 0,
        };
        let value = Observation {
            id: self.rng.next_u64() % 1000,
            from_seq,
        };
        if let Some(output) = &self.output {
            let seq = output.publish(ctx.now(), value.clone());
            self.record.lock().unwrap().push((
                ctx.name().to_string(),
                Message {
                    stamp: ctx.now(),
                    seq,
                    value,
                },
            ));
        } else if let Some(commands) = &self.commands {
            let _ = commands.send(ctx.now(), value);
        } else if let Some(received) = self.received.as_mut() {
            for message in received.drain() {
                self.record
                    .lock()
                    .unwrap()
                    .push((ctx.name().to_string(), message));
            }
        }
        Ok(())
    }
}

type Replay = (
    Vec<TraceEvent>,
    Vec<(String, Message<Observation>)>,
    Vec<TopicInfo>,
    Vec<TaskStats>,
);

fn replay(seed: u64) -> Replay {
    let record: Record = Arc::default();
    let mut registry = PluginRegistry::new();
    for info in BUILTIN_PLUGINS {
        let record = record.clone();
        let role = info.name;
        let (inputs, outputs) = Stage::ports(role);
        let info = PluginInfo {
            inputs,
            outputs,
            ..info.clone()
        };
        registry
            .register_plugin(info, move |build| {
                Ok(Box::new(Stage::new(role, record.clone(), build)?) as Box<dyn Task>)
            })
            .unwrap();
    }
    let mut config = reference(&registry.catalog());
    // Measured step times with a heavy tail, so overruns and skips depend on the draws.
    config.tasks[0].params.insert(
        STEP_COST_PARAM.into(),
        toml::from_str::<toml::Table>(
            "v = [[3.0, 900.0], [3.0, 400.0], [3.0, 250.0], [3.0, 150.0]]",
        )
        .unwrap()["v"]
            .clone(),
    );
    let mut builder = SchedulerBuilder::new(&registry);
    builder.tasks(&config.tasks).seed(seed).record_trace(true);
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.run_until(Timestamp::from_millis(7_000)).unwrap();
    scheduler.set_level("tracking", 0).unwrap();
    scheduler.set_level("hazard", 1).unwrap();
    scheduler.run_until(Timestamp::from_millis(20_000)).unwrap();
    let stats = scheduler.stats();
    let topics = scheduler.bus().topics();
    let trace = scheduler.take_trace();
    drop(scheduler);
    let record = record.lock().unwrap().clone();
    (trace, record, topics, stats)
}

#[test]
fn virtual_replay_is_identical_for_a_seed_and_differs_across_seeds() {
    let first = replay(7);
    let second = replay(7);
    assert!(
        first.0.len() > 1_500,
        "a rich trace: {} events",
        first.0.len()
    );
    assert!(first.1.len() > 250, "many messages: {}", first.1.len());
    assert_eq!(first.0, second.0, "trace of (time, task, event)");
    assert_eq!(
        first.1, second.1,
        "bus messages with stamps and sequence numbers"
    );
    assert_eq!(first.2, second.2, "bus counters");
    assert_eq!(first.3, second.3, "task statistics");
    // The draws matter: the seed changes the messages and the detector's overruns.
    let detection = &first.3[0];
    assert!(
        detection.overruns > 0 && detection.skipped > 0,
        "{detection:?}"
    );
    let other = replay(8);
    assert_ne!(first.0, other.0);
    assert_ne!(first.1, other.1);
    assert!(first
        .0
        .iter()
        .any(|event| event.kind == TraceKind::LevelChanged { level: 0 }
            && event.time == Timestamp::from_millis(7_000)
            && &*event.task == "tracking"));
}

// ---------------------------------------------------------------------------------------------
// Rate changes

#[test]
fn virtual_rate_change_takes_effect_within_one_period() {
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[100.0, 20.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            initial_level: Some(0),
            ..TaskOptions::default()
        },
    );
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.run_until(Timestamp::from_millis(1_050)).unwrap();
    assert_eq!(
        times_of(&probes.log, "tracking"),
        (0..=10).map(|k| k * 100 * MS).collect::<Vec<_>>()
    );
    // Faster: the last activation was at 1000 ms, 1000 + 20 is past, so it runs now.
    scheduler.set_level("tracking", 1).unwrap();
    scheduler.run_until(Timestamp::from_millis(1_200)).unwrap();
    let after: Vec<u64> = times_of(&probes.log, "tracking")
        .into_iter()
        .filter(|&t| t > 1_000 * MS)
        .collect();
    assert_eq!(
        after,
        (0..8).map(|k| (1_050 + 20 * k) * MS).collect::<Vec<_>>()
    );
    assert!(probes.log.lock().unwrap().last().unwrap().level == 1);
    // Slower: the last activation was at 1190 ms; the next is 1190 + 100, within 100 ms of now.
    scheduler.set_level("tracking", 0).unwrap();
    scheduler.run_until(Timestamp::from_millis(1_500)).unwrap();
    let after: Vec<u64> = times_of(&probes.log, "tracking")
        .into_iter()
        .filter(|&t| t > 1_200 * MS)
        .collect();
    assert_eq!(after, vec![1_290 * MS, 1_390 * MS, 1_490 * MS]);
    let stats = scheduler.task_stats("tracking").unwrap();
    assert_eq!((stats.level, stats.period_ms), (0, 100.0));
    assert_eq!(stats.activations, 11 + 8 + 3);
}

#[test]
fn real_time_rate_change_takes_effect_within_one_period() {
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[300.0, 10.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            initial_level: Some(0),
            ..TaskOptions::default()
        },
    );
    let mut scheduler = builder
        .build_real_time(RealTimeOptions {
            pinning: Pinning::Off,
            ..RealTimeOptions::default()
        })
        .unwrap();
    scheduler.start().unwrap();
    std::thread::sleep(Duration::from_millis(60));
    // One activation at start; at 300 ms the next would be 240 ms away.
    assert_eq!(times_of(&probes.log, "tracking").len(), 1);
    let changed_at = scheduler.now();
    scheduler.set_level("tracking", 1).unwrap();
    std::thread::sleep(Duration::from_millis(150));
    scheduler.stop();
    let times = times_of(&probes.log, "tracking");
    let first_after = times[1];
    // Within one new period (10 ms), plus wake-up slack for a loaded 2-core machine.
    let delay_ms = (first_after - changed_at.as_nanos()) as f64 / MS as f64;
    assert!(
        delay_ms < 10.0 + 15.0,
        "first activation {delay_ms} ms after the change"
    );
    let after = times.len() - 1;
    assert!(
        (8..=17).contains(&after),
        "{after} activations in 150 ms at 10 ms"
    );
    assert_eq!(scheduler.level("tracking"), Some(1));
}

// ---------------------------------------------------------------------------------------------
// The GPU

#[test]
fn gpu_is_exclusive_at_build_and_at_run_time() {
    let probes = probes();
    let mut hazard = probe("hazard", Knob::RateFps, &[4.0], "");
    hazard.resource = Resource::Gpu;
    let mut second = probe("hazard2", Knob::RateFps, &[4.0], "");
    second.resource = Resource::Gpu;

    // Two GPU tasks in one scheduler: refused, naming both.
    let error = SchedulerBuilder::new(&probes.registry)
        .task(&hazard)
        .task(&second)
        .build_virtual()
        .err()
        .unwrap();
    assert!(
        matches!(&error, SchedulerError::Resource(ResourceError::Busy { holder, claimant, .. })
            if holder == "hazard" && claimant == "hazard2"),
        "{error:?}"
    );

    // At run time the running GPU task holds the lease: any other claimant is refused.
    let resources = Resources::new();
    let mut running = SchedulerBuilder::new(&probes.registry)
        .task(&hazard)
        .resources(resources.clone())
        .build_real_time(RealTimeOptions::default())
        .unwrap();
    running.start().unwrap();
    assert_eq!(resources.gpu().holder().as_deref(), Some("hazard"));
    assert!(matches!(
        resources.gpu().claim("intruder"),
        Err(ResourceError::Busy { holder, .. }) if holder == "hazard"
    ));
    let refused = SchedulerBuilder::new(&probes.registry)
        .task(&second)
        .resources(resources.clone())
        .build_virtual();
    assert!(matches!(
        refused,
        Err(SchedulerError::Resource(ResourceError::Busy { .. }))
    ));
    running.stop();
    // Released with the task.
    assert_eq!(resources.gpu().holder(), None);
    assert!(resources.gpu().claim("hazard2").is_ok());
}

#[test]
fn a_gpu_task_that_fails_for_good_releases_the_gpu() {
    let probes = probes();
    let mut hazard = probe("hazard", Knob::RateFps, &[4.0], "panic_on_step = 0");
    hazard.resource = Resource::Gpu;
    let resources = Resources::new();
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task_with(
            &hazard,
            TaskOptions {
                restart: RestartPolicy::Never,
                ..TaskOptions::default()
            },
        )
        .resources(resources.clone())
        .build_virtual()
        .unwrap();
    assert_eq!(resources.gpu().holder().as_deref(), Some("hazard"));
    scheduler.run_until(Timestamp::from_millis(1)).unwrap();
    assert_eq!(scheduler.failed_tasks(), vec!["hazard".to_string()]);
    assert_eq!(resources.gpu().holder(), None);
}

// ---------------------------------------------------------------------------------------------
// Failures

#[test]
fn a_panicking_task_is_restarted_per_policy_and_the_others_keep_their_rates() {
    let probes = probes();
    let steady = probe("steady", Knob::PeriodMs, &[20.0], "");
    // Every instance panics at its third step: t = 40, 100, 160 ms (the restart is at the next
    // activation, 20 ms after each failure).
    let crashy = probe("crashy", Knob::PeriodMs, &[20.0], "panic_on_step = 2");
    let once = probe("once", Knob::RateFps, &[50.0], "panic_once_at = 5");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder
        .task(&steady)
        .task_with(
            &crashy,
            TaskOptions {
                restart: RestartPolicy::OnFailure { max_restarts: 2 },
                ..TaskOptions::default()
            },
        )
        .task(&once)
        .record_trace(true);
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.run_until(Timestamp::from_millis(1_000)).unwrap();

    let crashy = scheduler.task_stats("crashy").unwrap();
    assert_eq!((crashy.failures, crashy.restarts), (3, 2), "{crashy:?}");
    assert_eq!(crashy.health, TaskHealth::Failed);
    assert_eq!(crashy.activations, 9, "three instances of three steps");
    assert!(crashy
        .last_error
        .as_deref()
        .unwrap()
        .contains("probe panics at step 2"));
    assert_eq!(
        times_of(&probes.log, "crashy"),
        [0, 20, 40, 60, 80, 100, 120, 140, 160]
            .map(|t| t * MS)
            .to_vec()
    );
    // Its neighbours never missed an activation.
    let steady = scheduler.task_stats("steady").unwrap();
    assert_eq!(steady.activations, 51);
    assert_eq!((steady.failures, steady.skipped), (0, 0));
    assert_eq!(
        times_of(&probes.log, "steady"),
        (0..=50).map(|k| k * 20 * MS).collect::<Vec<_>>()
    );
    // A one-off panic: one restart, then it runs on at its rate.
    let once = scheduler.task_stats("once").unwrap();
    assert_eq!((once.failures, once.restarts), (1, 1));
    assert_eq!(once.health, TaskHealth::Running);
    assert_eq!(once.activations, 51);
    assert_eq!(scheduler.failed_tasks(), vec!["crashy".to_string()]);
    let gave_up = scheduler.trace().iter().find(|event| {
        matches!(&event.kind, TraceKind::Failed { gave_up: true, .. }) && &*event.task == "crashy"
    });
    assert_eq!(gave_up.unwrap().time, Timestamp::from_millis(160));
    // Each failed instance was stopped (3 crashy + 1 once) before it was dropped.
    assert_eq!(probes.stops.load(Ordering::SeqCst), 4);
}

#[test]
fn never_policy_fails_for_good_and_tasks_see_the_degraded_mission() {
    let probes = probes();
    let detection = probe("detection", Knob::PeriodMs, &[50.0], "error_on_step = 1");
    let landing = probe("landing", Knob::PeriodMs, &[20.0], "");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task_with(
            &detection,
            TaskOptions {
                restart: RestartPolicy::Never,
                ..TaskOptions::default()
            },
        )
        .task(&landing)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(200)).unwrap();
    assert_eq!(times_of(&probes.log, "detection"), vec![0, 50 * MS]);
    let detection = scheduler.task_stats("detection").unwrap();
    assert_eq!((detection.failures, detection.restarts), (1, 0));
    assert!(detection
        .last_error
        .unwrap()
        .contains("probe fails at step 1"));
    // The landing task sees the mission healthy until 50 ms, degraded from then on.
    let log = probes.log.lock().unwrap();
    let landing: Vec<&Seen> = log.iter().filter(|seen| seen.task == "landing").collect();
    assert_eq!(landing.len(), 11);
    for seen in landing {
        let expect_degraded = seen.at > Timestamp::from_millis(50);
        assert_eq!(seen.degraded, expect_degraded, "{seen:?}");
        if expect_degraded {
            assert_eq!(seen.failed, vec!["detection".to_string()]);
        }
    }
    assert_eq!(
        scheduler.health().health_of("detection"),
        Some(TaskHealth::Failed)
    );
}

#[test]
fn a_failing_start_is_a_failure_restarted_per_policy() {
    let probes = probes();
    let camera = probe("camera", Knob::PeriodMs, &[10.0], "fail_start = true");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task_with(
            &camera,
            TaskOptions {
                restart: RestartPolicy::OnFailure { max_restarts: 4 },
                ..TaskOptions::default()
            },
        )
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(100)).unwrap();
    let stats = scheduler.task_stats("camera").unwrap();
    // Start fails, then four restarts at 0, 10, 20, 30 ms each fail again; never a step.
    assert_eq!(
        (stats.failures, stats.restarts, stats.activations),
        (5, 4, 0)
    );
    assert_eq!(stats.health, TaskHealth::Failed);
    assert!(stats.last_error.unwrap().contains("camera not found"));
}

#[test]
fn real_time_panicking_task_is_isolated_and_the_others_keep_their_rates() {
    let probes = probes();
    let steady = probe("steady", Knob::PeriodMs, &[10.0], "");
    let crashy = probe("crashy", Knob::PeriodMs, &[10.0], "panic_on_step = 2");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&steady)
        .task_with(
            &crashy,
            TaskOptions {
                restart: RestartPolicy::OnFailure { max_restarts: 2 },
                ..TaskOptions::default()
            },
        )
        .build_real_time(RealTimeOptions {
            pinning: Pinning::Off,
            ..RealTimeOptions::default()
        })
        .unwrap();
    let started = Instant::now();
    scheduler.start().unwrap();
    // A panic can take long (the default hook prints a backtrace when RUST_BACKTRACE is set):
    // wait for the crashy task to give up rather than assume a time.
    while scheduler.health().health_of("crashy") != Some(TaskHealth::Failed) {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "crashy never gave up"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let crashed_ms = started.elapsed().as_secs_f64() * 1e3;
    let during = scheduler.task_stats("steady").unwrap().activations;
    std::thread::sleep(Duration::from_millis(300));
    let after = scheduler.task_stats("steady").unwrap().activations - during;
    scheduler.stop();
    let crashy = scheduler.task_stats("crashy").unwrap();
    assert_eq!((crashy.failures, crashy.restarts), (3, 2), "{crashy:?}");
    assert_eq!(crashy.health, TaskHealth::Failed);
    assert_eq!(crashy.activations, 9);
    let steady = scheduler.task_stats("steady").unwrap();
    assert_eq!(steady.failures, 0);
    // At 10 ms: kept its rate while the other task crashed three times (a loaded machine may
    // skip a few activations, never run extra)…
    let expected_during = crashed_ms / 10.0;
    assert!(
        during as f64 >= 0.7 * expected_during - 2.0 && during as f64 <= expected_during + 2.0,
        "{during} activations in the {crashed_ms:.0} ms of crashes"
    );
    // …and after it.
    assert!((21..=32).contains(&after), "{after} activations in 300 ms");
    assert_eq!(scheduler.failed_tasks(), vec!["crashy".to_string()]);
}

// ---------------------------------------------------------------------------------------------
// Overruns and skips

#[test]
fn virtual_overruns_and_skips_follow_the_timing_model() {
    let probes = probes();
    let slow = probe("slow", Knob::PeriodMs, &[10.0], "step_cost_ms = 25.0");
    let exact = probe("exact", Knob::PeriodMs, &[10.0], "step_cost_ms = 10.0");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&slow)
        .task(&exact)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(1_000)).unwrap();
    // 25 ms steps at 10 ms: each step covers the next two instants; it runs at 0, 30, …, 990.
    let slow = scheduler.task_stats("slow").unwrap();
    assert_eq!(slow.activations, 34);
    assert_eq!(slow.overruns, 34);
    assert_eq!(slow.skipped, 68);
    assert_eq!(
        times_of(&probes.log, "slow")[..4],
        [0, 30 * MS, 60 * MS, 90 * MS]
    );
    assert!((slow.step_time.p50_us - 25_000.0).abs() < 25_000.0 * 0.016);
    assert_eq!(slow.lateness.max_us, 0.0);
    // A step exactly as long as its period is neither.
    let exact = scheduler.task_stats("exact").unwrap();
    assert_eq!(
        (exact.activations, exact.overruns, exact.skipped),
        (101, 0, 0)
    );
}

#[test]
fn a_tasks_own_cost_report_overrides_the_per_level_figure() {
    let probes = probes();
    let config = probe(
        "cnn",
        Knob::PeriodMs,
        &[100.0, 50.0],
        "step_cost_ms = [1.0, 1.0]\nreport_cost_ms = 120",
    );
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(999)).unwrap();
    // 120 ms steps at 50 ms: runs at 0, 150, …, 900; skips two instants each time.
    let stats = scheduler.task_stats("cnn").unwrap();
    assert_eq!(
        (stats.activations, stats.overruns, stats.skipped),
        (7, 7, 14)
    );
}

#[test]
fn timing_model_from_code_and_its_level_count_is_checked() {
    let probes = probes();
    let config = probe("cnn", Knob::RateFps, &[1.0, 4.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            timing: Some(TimingModel::fixed_ms(&[300.0]).unwrap()),
            ..TaskOptions::default()
        },
    );
    assert!(matches!(
        builder.build_virtual(),
        Err(SchedulerError::Timing {
            source: TimingError::WrongLength {
                found: 1,
                levels: 2
            },
            ..
        })
    ));
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            timing: Some(TimingModel::fixed_ms(&[300.0, 300.0]).unwrap()),
            ..TaskOptions::default()
        },
    );
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.run_until(Timestamp::from_millis(1_000)).unwrap();
    // 300 ms steps at 250 ms: runs at 0, 500, 1000, skipping 250, 750 and (after the last
    // step, which ends at 1300) 1250.
    let stats = scheduler.task_stats("cnn").unwrap();
    assert_eq!(
        (stats.activations, stats.overruns, stats.skipped),
        (3, 3, 3)
    );
}

#[test]
fn real_time_overruns_and_skips_are_counted() {
    let probes = probes();
    let slow = probe("slow", Knob::PeriodMs, &[10.0], "sleep_ms = 25");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&slow)
        .build_real_time(RealTimeOptions {
            pinning: Pinning::Off,
            ..RealTimeOptions::default()
        })
        .unwrap();
    scheduler.start().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    scheduler.stop();
    let stats = scheduler.task_stats("slow").unwrap();
    assert!(stats.activations >= 5, "{stats:?}");
    assert_eq!(
        stats.overruns, stats.activations,
        "every 25 ms step overruns 10 ms"
    );
    // Each step covers at least two instants (a late wake-up may cover a third).
    assert!(stats.skipped >= 2 * stats.activations, "{stats:?}");
    assert!(stats.step_time.p50_us >= 25_000.0, "{stats:?}");
}

// ---------------------------------------------------------------------------------------------
// Speed

#[test]
fn virtual_time_runs_much_faster_than_real_time() {
    let probes = probes();
    let config = reference(&probes.registry.catalog());
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .tasks(&config.tasks)
        .build_virtual()
        .unwrap();
    let simulated_s = 600.0;
    let started = Instant::now();
    let activations = scheduler
        .run_until(Timestamp::from_secs_f64(simulated_s))
        .unwrap();
    let wall_s = started.elapsed().as_secs_f64();
    // Top levels: detection 10 fps, tracking 20 ms, landing 20 ms, hazard 4 fps, from t = 0.
    assert_eq!(activations, 6_001 + 30_001 + 30_001 + 2_401);
    let stats = scheduler.stats();
    assert_eq!(stats[3].activations, 2_401);
    assert!(
        simulated_s / wall_s > 100.0,
        "{simulated_s} s simulated in {wall_s:.3} s"
    );
}

// ---------------------------------------------------------------------------------------------
// Bad input

#[test]
fn mistakes_are_named_errors() {
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[100.0, 20.0], "");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_virtual()
        .unwrap();
    assert!(matches!(
        scheduler.set_level("trackin", 0),
        Err(SchedulerError::UnknownTask { task, known }) if task == "trackin" && known == "tracking"
    ));
    assert!(matches!(
        scheduler.set_level("tracking", 2),
        Err(SchedulerError::Level(LevelError::OutOfRange {
            level: 2,
            count: 2,
            ..
        }))
    ));
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(10)),
        Ok(1)
    ));
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(5)),
        Err(SchedulerError::Clock(ClockError::Backwards { .. }))
    ));
    // The clock advanced behind the scheduler's back is refused, not silently jumped.
    scheduler
        .clock()
        .advance_to(Timestamp::from_millis(500))
        .unwrap();
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(600)),
        Err(SchedulerError::Clock(_))
    ));

    let build = |configs: &[&TaskConfig], options: TaskOptions| {
        let mut builder = SchedulerBuilder::new(&probes.registry);
        for config in configs {
            builder.task_with(config, options.clone());
        }
        builder.build_virtual().err()
    };
    assert!(matches!(
        build(&[&config, &config], TaskOptions::default()),
        Some(SchedulerError::DuplicateTask { task }) if task == "tracking"
    ));
    assert!(matches!(
        build(
            &[&config],
            TaskOptions {
                initial_level: Some(5),
                ..TaskOptions::default()
            }
        ),
        Some(SchedulerError::Level(LevelError::OutOfRange {
            level: 5,
            ..
        }))
    ));
    let mut unknown = config.clone();
    unknown.plugin = "prob".into();
    assert!(matches!(
        build(&[&unknown], TaskOptions::default()),
        Some(SchedulerError::Registry(RegistryError::UnknownPlugin { suggestion: Some(s), .. })) if s == "probe"
    ));
    let bad_cost = probe(
        "tracking",
        Knob::PeriodMs,
        &[100.0, 20.0],
        "step_cost_ms = [1.0]",
    );
    let error = build(&[&bad_cost], TaskOptions::default()).unwrap();
    assert!(
        error.to_string().contains("tracking") && error.to_string().contains("step_cost_ms"),
        "{error}"
    );
    let bad_params = probe("tracking", Knob::PeriodMs, &[100.0], "panic_on = 1");
    let error = build(&[&bad_params], TaskOptions::default()).unwrap();
    assert!(error.to_string().contains("panic_on"), "{error}");
    let bad_level = probe("tracking", Knob::RateFps, &[0.0], "");
    assert!(matches!(
        build(&[&bad_level], TaskOptions::default()),
        Some(SchedulerError::Level(LevelError::BadValue { .. }))
    ));
}

#[test]
fn the_timing_param_is_the_schedulers_not_the_plugins() {
    // The probe's params deny unknown keys; step_cost_ms must not reach it.
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[20.0], "step_cost_ms = 5.0");
    assert!(SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_virtual()
        .is_ok());
}

#[test]
fn restart_policy_reads_from_toml() {
    #[derive(serde::Deserialize)]
    struct Holder {
        restart: RestartPolicy,
    }
    let never: Holder = toml::from_str("restart = { policy = \"never\" }").unwrap();
    assert_eq!(never.restart, RestartPolicy::Never);
    let limited: Holder =
        toml::from_str("restart = { policy = \"on_failure\", max_restarts = 5 }").unwrap();
    assert_eq!(
        limited.restart,
        RestartPolicy::OnFailure { max_restarts: 5 }
    );
    assert!(toml::from_str::<Holder>("restart = { policy = \"always\" }").is_err());
}

#[test]
fn stopping_stops_every_task_once() {
    let probes = probes();
    let a = probe("a", Knob::PeriodMs, &[10.0], "");
    let b = probe("b", Knob::PeriodMs, &[10.0], "");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&a)
        .task(&b)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(30)).unwrap();
    scheduler.stop();
    scheduler.stop();
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(40)),
        Err(SchedulerError::Stopped)
    ));
    drop(scheduler);
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
}

#[test]
fn real_time_stop_stops_every_started_task_once() {
    let probes = probes();
    let a = probe("a", Knob::PeriodMs, &[5.0], "");
    let b = probe("b", Knob::PeriodMs, &[5.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task(&a).task(&b);
    let options = RealTimeOptions {
        pinning: Pinning::Off,
        ..RealTimeOptions::default()
    };
    // Built but never started: nothing to stop.
    drop(builder.build_real_time(options).unwrap());
    assert_eq!(probes.stops.load(Ordering::SeqCst), 0);
    let mut scheduler = builder.build_real_time(options).unwrap();
    scheduler.start().unwrap();
    assert!(matches!(
        scheduler.start(),
        Err(SchedulerError::AlreadyStarted)
    ));
    std::thread::sleep(Duration::from_millis(30));
    scheduler.stop();
    let stopped_with = [
        scheduler.task_stats("a").unwrap().activations,
        scheduler.task_stats("b").unwrap().activations,
    ];
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
    std::thread::sleep(Duration::from_millis(20));
    // No activation after the stop; a second stop (and the drop) changes nothing.
    scheduler.stop();
    assert_eq!(
        scheduler.task_stats("a").unwrap().activations,
        stopped_with[0]
    );
    drop(scheduler);
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
    assert!(stopped_with.iter().all(|&n| n >= 2), "{stopped_with:?}");
}

#[cfg(target_os = "linux")]
#[test]
fn pinning_to_a_missing_core_is_an_error_only_when_required() {
    let probes = probes();
    let mut config = probe("pinned", Knob::PeriodMs, &[10.0], "");
    config.cores = vec![1000];
    let options = |pinning| RealTimeOptions {
        pinning,
        ..RealTimeOptions::default()
    };
    let mut required = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_real_time(options(Pinning::Required))
        .unwrap();
    assert!(matches!(
        required.start(),
        Err(SchedulerError::Pinning { task, cores, .. }) if task == "pinned" && cores == vec![1000]
    ));
    // Best effort: a warning, and the task runs.
    let mut best_effort = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_real_time(options(Pinning::BestEffort))
        .unwrap();
    best_effort.start().unwrap();
    std::thread::sleep(Duration::from_millis(30));
    best_effort.stop();
    assert!(best_effort.task_stats("pinned").unwrap().activations >= 1);
    // Core 0 exists everywhere.
    config.cores = vec![0];
    let mut on_core_0 = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_real_time(options(Pinning::Required))
        .unwrap();
    on_core_0.start().unwrap();
    on_core_0.stop();
}

// ---------------------------------------------------------------------------------------------
// Phases: a task runs only in the phases it lists.

/// Two probes: `watch` in transit and tracking, `land` in tracking and landing.
fn phased_probes() -> (Probes, Vec<TaskConfig>) {
    let probes = probes();
    let mut watch = probe("watch", Knob::PeriodMs, &[100.0], "");
    watch.phases = vec!["transit".into(), "tracking".into()];
    let mut land = probe("land", Knob::PeriodMs, &[100.0], "");
    land.phases = vec!["tracking".into(), "landing".into()];
    (probes, vec![watch, land])
}

#[test]
fn virtual_time_steps_a_task_only_in_its_phases() {
    let (probes, tasks) = phased_probes();
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .tasks(&tasks)
        .phase_gate(PhaseGate::NoPhase)
        .record_trace(true)
        .build_virtual()
        .unwrap();
    let ms = Timestamp::from_millis;
    // Before the first phase nothing runs; then each phase for one second.
    scheduler.run_until(ms(1000)).unwrap();
    for (phase, until_ms) in [("transit", 2000), ("tracking", 3000), ("landing", 4000)] {
        scheduler.set_phase(&PhaseGate::Phase(phase.into()));
        scheduler.run_until(ms(until_ms)).unwrap();
    }
    scheduler.set_phase(&PhaseGate::NoPhase);
    scheduler.run_until(ms(5000)).unwrap();
    let watch = times_of(&probes.log, "watch");
    let land = times_of(&probes.log, "land");
    // Every 100 ms while its phases fly (`run_until` includes its end instant, at which the
    // phase still flies): watch from 1 s to 3 s, land from 2 s to 4 s, never outside.
    let every_100_ms = |from_ms: u64, to_ms: u64| -> Vec<u64> {
        (from_ms / 100..=to_ms / 100)
            .map(|k| k * 100 * MS)
            .collect()
    };
    assert_eq!(watch, every_100_ms(1000, 3000));
    assert_eq!(land, every_100_ms(2000, 4000));
    let kinds: Vec<&TraceKind> = scheduler
        .trace()
        .iter()
        .filter(|e| &*e.task == "land")
        .map(|e| &e.kind)
        .filter(|k| matches!(k, TraceKind::Suspended | TraceKind::Resumed))
        .collect();
    assert_eq!(kinds, [&TraceKind::Resumed, &TraceKind::Suspended]);
}

#[test]
fn real_time_suspends_a_task_outside_its_phases() {
    let (probes, tasks) = phased_probes();
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .tasks(&tasks)
        .phase_gate(PhaseGate::Phase("transit".into()))
        .build_real_time(RealTimeOptions {
            pinning: Pinning::Off,
            ..RealTimeOptions::default()
        })
        .unwrap();
    scheduler.start().unwrap();
    std::thread::sleep(Duration::from_millis(250));
    assert!(times_of(&probes.log, "land").is_empty());
    let watch_before = times_of(&probes.log, "watch").len();
    assert!(
        watch_before >= 2,
        "{watch_before} steps in 250 ms at 100 ms"
    );
    // The tasks' threads run while the phase changes, so the switch is
    // bracketed: a step may land between the change and a later clock read.
    let before_switch = scheduler.now().as_nanos();
    scheduler.set_phase(&PhaseGate::Phase("landing".into()));
    let after_switch = scheduler.now().as_nanos();
    std::thread::sleep(Duration::from_millis(250));
    scheduler.stop();
    let watch = times_of(&probes.log, "watch");
    let land = times_of(&probes.log, "land");
    assert!(
        watch.iter().all(|&t| t <= after_switch),
        "watch stepped in landing: {watch:?}"
    );
    assert!(land.len() >= 2, "{land:?}");
    assert!(
        land[0] >= before_switch,
        "land stepped in transit: {land:?}"
    );
    // Resumed at once (within a loaded machine's wake-up slack).
    assert!(
        land[0] - before_switch < 20 * MS,
        "{} ms",
        (land[0] - before_switch) / MS
    );
}
