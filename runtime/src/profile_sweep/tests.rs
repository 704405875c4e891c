//! The sweep's choices, and a whole sweep on a scripted meter whose power follows what the
//! tasks really do: each step of a test task costs energy, so the meter reads the activation
//! rates the real-time scheduler achieved at each level.

use super::*;
use crate::config::load_str;
use crate::task::{Task, TaskContext, TaskError};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

const CONFIG: &str = r#"
[mission]
name = "sweep-test"
reserve_fraction = 0.2

[[mission.phase]]
name = "cruise"
duration_s = 60.0

[[mission.phase]]
name = "work"
duration_s = 60.0

[battery]
capacity_wh = 50.0
cell_count = 4

[flight]
hover_power_w = 100.0

[power_model]
[[power_model.profile]]
path = "not-yet-measured.toml"
phases = ["cruise", "work"]

[[task]]
name = "a"
plugin = "busy"
resource = "cpu"
phases = ["work"]
weight = 1.0
knob = "rate_fps"
levels = [10.0, 25.0, 40.0]
utility = [0.2, 0.5, 1.0]

[[task]]
name = "b"
plugin = "busy"
resource = "cpu"
phases = ["work", "cruise"]
weight = 1.0
knob = "period_ms"
levels = [50.0, 12.5]
utility = [0.5, 1.0]

[[task]]
name = "c"
plugin = "busy"
resource = "cpu"
phases = ["work"]
weight = 1.0
knob = "rate_fps"
levels = [5.0, 20.0]
utility = [0.5, 1.0]

[[task]]
name = "d"
plugin = "absent_plugin"
resource = "cpu"
phases = ["work"]
weight = 1.0
knob = "rate_fps"
levels = [1.0]
utility = [1.0]
"#;

/// Energy per step of each test task, in J: the scripted meter's model.
const STEP_J: [(&str, f64); 3] = [("a", 0.05), ("b", 0.01), ("c", 0.02)];
const BASE_W: f64 = 1.0;

type Counters = Arc<BTreeMap<String, Arc<AtomicU64>>>;

struct Busy {
    steps: Arc<AtomicU64>,
}

impl Task for Busy {
    fn step(&mut self, _ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        self.steps.fetch_add(1, Ordering::SeqCst);
        Ok(())
    }
}

/// A registry with `busy` (which counts its steps per task) and a catalogue that also knows
/// `absent_plugin`, so the config loads while that plugin stays unbuilt.
fn setup() -> (MissionConfig, PluginRegistry, Counters) {
    let counters: Counters = Arc::new(
        STEP_J
            .iter()
            .map(|(name, _)| (name.to_string(), Arc::new(AtomicU64::new(0))))
            .collect(),
    );
    let mut registry = PluginRegistry::new();
    let for_factory = counters.clone();
    registry
        .register("busy", move |build| {
            Ok(Box::new(Busy {
                steps: for_factory[&build.config().name].clone(),
            }) as Box<dyn Task>)
        })
        .unwrap();
    let mut catalog_registry = PluginRegistry::new();
    for name in ["busy", "absent_plugin"] {
        catalog_registry
            .register(name, |_| Err(TaskError::failed("catalogue only")))
            .unwrap();
    }
    let config = load_str(CONFIG, None, &catalog_registry.catalog()).unwrap_or_else(|d| {
        panic!("{d:#?}");
    });
    (config, registry, counters)
}

/// Power = base + Σ energy per step × steps per second since the previous reading: what a
/// board's meter shows when every activation costs energy.
struct ScriptedMeter {
    counters: Counters,
    previous: Vec<u64>,
    previous_at: Instant,
}

impl ScriptedMeter {
    fn new(counters: Counters) -> Self {
        let previous = counters
            .values()
            .map(|c| c.load(Ordering::SeqCst))
            .collect();
        ScriptedMeter {
            counters,
            previous,
            previous_at: Instant::now(),
        }
    }
}

impl PowerMeter for ScriptedMeter {
    fn name(&self) -> &str {
        "scripted"
    }
    fn describe(&self) -> String {
        "scripted test meter".into()
    }
    fn rails(&self) -> Vec<String> {
        vec!["total".into()]
    }
    fn read(&mut self) -> Result<PowerReading, MeterError> {
        let now = Instant::now();
        let dt_s = (now - self.previous_at).as_secs_f64();
        let counts: Vec<u64> = self
            .counters
            .values()
            .map(|c| c.load(Ordering::SeqCst))
            .collect();
        let joules: f64 = self
            .counters
            .keys()
            .zip(counts.iter().zip(&self.previous))
            .map(|(name, (now, before))| {
                let j = STEP_J.iter().find(|(n, _)| n == name).unwrap().1;
                j * (now - before) as f64
            })
            .sum();
        self.previous = counts;
        self.previous_at = now;
        let total_w = BASE_W + joules / dt_s;
        Ok(PowerReading {
            total_w,
            cpu_w: Some(total_w - BASE_W),
            gpu_w: None,
            rails_w: vec![total_w],
        })
    }
}

#[derive(Default)]
struct Recorder {
    steps: Vec<String>,
    warnings: Vec<String>,
}

impl SweepObserver for Recorder {
    fn step_started(&mut self, step: usize, steps: usize, label: &str) {
        self.steps.push(format!("{step}/{steps} {label}"));
    }
    fn warning(&mut self, message: &str) {
        self.warnings.push(message.to_string());
    }
}

fn choices(args: &[&str]) -> Vec<LevelChoice> {
    args.iter().map(|a| a.parse().unwrap()).collect()
}

#[test]
fn level_choices_parse_or_say_what_is_wrong() {
    let c: LevelChoice = "hazard.rate_fps= 4, 0.25".parse().unwrap();
    assert_eq!(c.knob, "hazard.rate_fps");
    assert_eq!(c.values, [4.0, 0.25]);
    for (text, needle) in [
        ("hazard.rate_fps", "TASK.KNOB=VALUE"),
        ("hazard=4", "TASK.KNOB"),
        ("hazard.rate_fps=4,x", "`x` is not a number"),
        ("hazard.rate_fps=4,", "`` is not a number"),
        ("hazard.rate_fps=4,4.0", "given twice"),
        ("hazard.rate_fps=inf", "not a number"),
    ] {
        let error = text.parse::<LevelChoice>().unwrap_err().to_string();
        assert!(error.contains(needle), "{text}: {error}");
    }
}

#[test]
fn the_plan_picks_the_phase_tasks_and_levels() {
    let (config, registry, _) = setup();
    let can_run = |p: &str| registry.contains(p);
    // Default phase: the one with the most runnable tasks (work: a, b, c; d is not built in).
    let plan = plan_sweep(&config, &can_run, None, &[]).unwrap();
    assert_eq!(plan.phase, "work");
    assert_eq!(plan.tasks, [0, 1, 2]);
    assert_eq!(
        plan.skipped,
        [SkippedTask {
            task: "d".into(),
            plugin: "absent_plugin".into()
        }]
    );
    let names: Vec<&str> = plan.axes.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(names, ["a.rate_fps", "b.period_ms", "c.rate_fps"]);
    assert_eq!(plan.combinations().len(), 3 * 2 * 2);
    // The first axis changes slowest.
    assert_eq!(plan.combinations()[..3], [[0, 0, 0], [0, 0, 1], [0, 1, 0]]);

    // A subset, given in any order, comes out lowest QoS first; one value holds the knob.
    let plan = plan_sweep(
        &config,
        &can_run,
        Some("work"),
        &choices(&["a.rate_fps=40,10", "c.rate_fps=20"]),
    )
    .unwrap();
    assert_eq!(plan.axes[0].levels, [0, 2]);
    assert_eq!(plan.axes[0].values, [10.0, 40.0]);
    assert_eq!(plan.held.len(), 1);
    assert_eq!(
        (plan.held[0].name.as_str(), plan.held[0].levels[0]),
        ("c.rate_fps", 1)
    );
    assert_eq!(plan.label(&[1, 0]), "a.rate_fps=40, b.period_ms=50");

    let plan = plan_sweep(&config, &can_run, Some("cruise"), &[]).unwrap();
    assert_eq!(plan.tasks, [1]);
}

#[test]
fn the_plan_refuses_what_it_cannot_run() {
    let (config, registry, _) = setup();
    let can_run = |p: &str| registry.contains(p);
    let error = |phase: Option<&str>, args: &[&str]| {
        plan_sweep(&config, &can_run, phase, &choices(args))
            .unwrap_err()
            .to_string()
    };
    assert!(error(Some("landing"), &[])
        .contains("unknown phase `landing`; the config's phases are: cruise, work"));
    let e = error(None, &["a.period_ms=10"]);
    assert!(
        e.contains("a.period_ms") && e.contains("a.rate_fps, b.period_ms, c.rate_fps"),
        "{e}"
    );
    let e = error(None, &["a.rate_fps=12"]);
    assert!(
        e.contains("not one of the task's levels [10, 25, 40]"),
        "{e}"
    );
    let e = error(None, &["a.rate_fps=10", "a.rate_fps=40"]);
    assert!(e.contains("given twice"), "{e}");
    let e = error(None, &["d.rate_fps=1"]);
    assert!(
        e.contains("plugin `absent_plugin` is not built into this binary"),
        "{e}"
    );
    // A task outside the phase is not the phase's knob.
    let e = error(Some("cruise"), &["a.rate_fps=10"]);
    assert!(e.contains("phase `cruise`"), "{e}");
    let nothing = |_: &str| false;
    let e = plan_sweep(&config, &nothing, Some("work"), &[])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no task this binary can run") && e.contains("task `a` plugin `busy`"),
        "{e}"
    );
}

#[test]
fn summaries_match_an_independent_computation() {
    let reading = |total_w: f64, cpu_w: Option<f64>| PowerReading {
        total_w,
        cpu_w,
        gpu_w: None,
        rails_w: vec![total_w],
    };
    let readings = [
        reading(3.0, Some(1.0)),
        reading(5.0, Some(2.0)),
        reading(4.0, Some(3.0)),
    ];
    let m = summarise(&readings, 0.3).unwrap();
    assert_eq!(m.readings, 3);
    assert_eq!(m.total.mean_w, 4.0);
    // Deviations −1, 1, 0: sample variance 2/2 = 1.
    assert_eq!(m.total.std_w, 1.0);
    assert_eq!(m.cpu.unwrap().mean_w, 2.0);
    assert_eq!(m.gpu, None);
    assert!((m.achieved_rate_hz - 10.0).abs() < 1e-9);
    // A rail missing from one reading is missing from the summary.
    let mixed = [reading(3.0, Some(1.0)), reading(5.0, None)];
    assert_eq!(summarise(&mixed, 0.2).unwrap().cpu, None);
    assert!(summarise(&readings[..1], 0.1).is_none());
}

#[test]
fn a_sweep_on_a_scripted_meter_reproduces_the_power_of_each_level() {
    let (config, registry, counters) = setup();
    let can_run = |p: &str| registry.contains(p);
    let plan = plan_sweep(
        &config,
        &can_run,
        Some("work"),
        &choices(&["a.rate_fps=10,40", "c.rate_fps=20"]),
    )
    .unwrap();
    let options = SweepOptions {
        duration: Duration::from_millis(600),
        warmup: Duration::from_millis(200),
        rate_hz: 20.0,
    };
    let mut meter = ScriptedMeter::new(counters);
    let mut recorder = Recorder::default();
    let result = run_sweep(
        &config,
        &registry,
        &plan,
        &mut meter,
        &options,
        &mut recorder,
    )
    .unwrap();
    assert_eq!(
        recorder.steps,
        [
            "0/5 idle (no task running)",
            "1/5 a.rate_fps=10, b.period_ms=50",
            "2/5 a.rate_fps=10, b.period_ms=12.5",
            "3/5 a.rate_fps=40, b.period_ms=50",
            "4/5 a.rate_fps=40, b.period_ms=12.5"
        ]
    );
    // Idle: no task has run yet, so exactly the base power, without spread.
    assert_eq!(result.idle.total.mean_w, BASE_W);
    assert_eq!(result.idle.total.std_w, 0.0);

    let profile = to_profile(
        &plan,
        &result,
        "test-board",
        "scripted",
        20.0,
        "test".into(),
    );
    assert_eq!(profile.knobs, ["a.rate_fps", "b.period_ms"]);
    assert_eq!(profile.idle_power_w, Some(BASE_W));
    // The independent expectation: base + Σ J/step × steps/s, c held at 20 fps.
    let expected = |a_fps: f64, b_period_ms: f64| {
        BASE_W + 0.05 * a_fps + 0.01 * (1000.0 / b_period_ms) + 0.02 * 20.0
    };
    let mut seen = Vec::new();
    for sample in &profile.samples {
        let want = expected(sample.knobs[0], sample.knobs[1]);
        // A window of 0.6 s may hold one activation more or less of each task.
        let tolerance = (0.05 + 0.01 + 0.02) / 0.6 + 0.05 * want;
        assert!(
            (sample.power_w - want).abs() < tolerance,
            "{:?}: measured {} W, expected {want} W (warnings: {:#?})",
            sample.knobs,
            sample.power_w,
            recorder.warnings
        );
        assert!((sample.duration_s.unwrap() - 0.6).abs() < 0.1);
        seen.push((sample.knobs.clone(), sample.power_w));
    }
    assert_eq!(seen.len(), 4);
    // The dependence itself: a 30 fps step of `a` costs 1.5 W, b's 60/s cost 0.6 W.
    let at = |k: [f64; 2]| seen.iter().find(|(v, _)| v[..] == k[..]).unwrap().1;
    let a_effect = at([40.0, 50.0]) - at([10.0, 50.0]);
    let b_effect = at([10.0, 12.5]) - at([10.0, 50.0]);
    assert!((a_effect - 1.5).abs() < 0.3, "a: {a_effect}");
    assert!((b_effect - 0.6).abs() < 0.2, "b: {b_effect}");
    // The tasks ran at their levels, and `d` (not built in) is named in the method.
    for point in &result.points {
        let a = point.task_rates.iter().find(|r| r.task == "a").unwrap();
        assert_eq!(a.nominal_hz, point.values[0]);
        assert!(
            (a.achieved_hz - a.nominal_hz).abs() <= 2.0 / 0.6 + 0.1 * a.nominal_hz,
            "{a:?}"
        );
    }
    let method = describe_method(&plan, &config, &options);
    assert!(method.contains("held: c.rate_fps = 20"), "{method}");
    assert!(
        method.contains("not run (plugin not built in): d (plugin absent_plugin)"),
        "{method}"
    );
    // What is written reads back as a profile.
    let text = profile.to_toml_string().unwrap();
    assert_eq!(Profile::from_toml_str(&text).unwrap(), profile);
}

/// A meter that fails now and then, or always.
struct Flaky {
    calls: usize,
    fail_every: usize,
}

impl PowerMeter for Flaky {
    fn name(&self) -> &str {
        "flaky"
    }
    fn describe(&self) -> String {
        "flaky".into()
    }
    fn rails(&self) -> Vec<String> {
        vec![]
    }
    fn read(&mut self) -> Result<PowerReading, MeterError> {
        self.calls += 1;
        if self.calls.is_multiple_of(self.fail_every) {
            return Err(MeterError::NoTimeElapsed {
                what: "flaky".into(),
            });
        }
        Ok(PowerReading {
            total_w: 2.0 + (self.calls % 2) as f64,
            cpu_w: None,
            gpu_w: None,
            rails_w: vec![],
        })
    }
}

/// One point measured on `meter` with no tasks; the warnings go to `warnings`.
fn measure_alone(
    meter: &mut dyn PowerMeter,
    options: &SweepOptions,
    warnings: &mut Vec<String>,
) -> Result<Measurement, SweepError> {
    measure(
        meter,
        options,
        "p",
        &mut NoInputs,
        &mut Recorder::default(),
        warnings,
    )
}

#[test]
fn meter_failures_are_left_out_or_abort() {
    let options = SweepOptions {
        duration: Duration::from_millis(400),
        warmup: Duration::from_millis(50),
        rate_hz: 50.0,
    };
    let mut warnings = Vec::new();
    // One read in 20 fails: left out, with a warning.
    let mut meter = Flaky {
        calls: 0,
        fail_every: 20,
    };
    let m = measure_alone(&mut meter, &options, &mut warnings).unwrap();
    assert!(m.failed_reads >= 1, "{m:?}");
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("failed and were left out")),
        "{warnings:?}"
    );
    // Every other read fails: the point is not measured.
    let mut meter = Flaky {
        calls: 0,
        fail_every: 2,
    };
    let error = measure_alone(&mut meter, &options, &mut warnings)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("readings failed while measuring p"),
        "{error}"
    );
    // Too short a window for two readings.
    let short = SweepOptions {
        duration: Duration::from_millis(30),
        warmup: Duration::ZERO,
        rate_hz: 10.0,
    };
    let mut meter = Flaky {
        calls: 0,
        fail_every: 1000,
    };
    let error = measure_alone(&mut meter, &short, &mut warnings)
        .unwrap_err()
        .to_string();
    assert!(error.contains("at least 2 are needed"), "{error}");
}

/// A meter slower than the requested rate is used at the rate it manages, with a warning.
struct Slow;

impl PowerMeter for Slow {
    fn name(&self) -> &str {
        "slow"
    }
    fn describe(&self) -> String {
        "slow".into()
    }
    fn rails(&self) -> Vec<String> {
        vec![]
    }
    fn read(&mut self) -> Result<PowerReading, MeterError> {
        std::thread::sleep(Duration::from_millis(40));
        Ok(PowerReading {
            total_w: 5.0,
            cpu_w: None,
            gpu_w: None,
            rails_w: vec![],
        })
    }
}

#[test]
fn a_slow_meter_is_reported() {
    let options = SweepOptions {
        duration: Duration::from_millis(400),
        warmup: Duration::ZERO,
        rate_hz: 100.0,
    };
    let mut warnings = Vec::new();
    let mut recorder = Recorder::default();
    let m = measure(
        &mut Slow,
        &options,
        "p",
        &mut NoInputs,
        &mut recorder,
        &mut warnings,
    )
    .unwrap();
    assert!(m.achieved_rate_hz < 30.0, "{m:?}");
    assert!(m.slowest_read_ms >= 40.0);
    assert_eq!(recorder.warnings.len(), 1);
    assert!(
        recorder.warnings[0].contains("requested 100 readings/s"),
        "{:?}",
        recorder.warnings
    );
}

#[test]
fn bad_options_are_refused() {
    for (rate_hz, duration_ms) in [(0.0, 100), (f64::NAN, 100), (5000.0, 100), (10.0, 0)] {
        let options = SweepOptions {
            duration: Duration::from_millis(duration_ms),
            warmup: Duration::ZERO,
            rate_hz,
        };
        assert!(options.check().is_err(), "{rate_hz} {duration_ms}");
    }
}
