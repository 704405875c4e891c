use super::*;
use crate::catalog::PluginCatalog;
use crate::config::load_file;
use crate::energy::load_mission_model;
use power_models::battery::{BatterySpec, EstimatorConfig};
use power_models::planner::{DurationByLevel, PlanPhase, PlanTask, PowerTerm};
use std::fmt;
use std::path::Path;

mod change;
mod planning;
mod scenarios;
mod telemetry;

// ---- missions --------------------------------------------------------------------------

fn reference_model() -> MissionModel {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("reference config");
    load_mission_model(&loaded).expect("reference profiles")
}

fn reference_governor(capacity_wh: Option<f64>) -> Governor {
    capture_logs();
    let model = reference_model();
    let spec = model.battery_spec(capacity_wh).unwrap();
    let estimator = BatteryEstimator::new(spec).unwrap();
    let reserve = model.config.mission.reserve_fraction;
    Governor::new(
        model.plan_problem(),
        estimator,
        reserve,
        GovernorConfig::default(),
    )
    .unwrap()
}

/// A survey mission whose computer is a large share of the power (a GPU board on a small
/// airframe), so that QoS can absorb a drain of 10-15 %. On the reference mission it
/// cannot: all its QoS levels together span 0.65 Wh of a 54 Wh mission. Transit runs a
/// CNN; the survey runs the CNN and a marker detector that share the board (a joint
/// table: they contend); the landing is shorter the faster the detector runs.
fn survey_problem() -> PlanProblem {
    let task = |name: &str, utility: &[f64], weight: f64| PlanTask {
        name: name.into(),
        utility: utility.to_vec(),
        weight,
        allowed_levels: None,
    };
    let cnn_w = [2.0, 8.0, 18.0, 30.0];
    let detector_w = [1.0, 3.0, 6.0, 10.0];
    let mut joint_w = Vec::new();
    for (i, cnn) in cnn_w.iter().enumerate() {
        for (j, detector) in detector_w.iter().enumerate() {
            joint_w.push(cnn + detector + 0.5 * (i * j) as f64);
        }
    }
    let phase = |name: &str, duration_s: f64, flight_power_w: f64| PlanPhase {
        name: name.into(),
        duration_s,
        duration_by_level: None,
        flight_power_w,
        base_power_w: 8.0,
        active_tasks: vec![],
        terms: vec![],
    };
    let transit = PlanPhase {
        active_tasks: vec![0],
        terms: vec![PowerTerm {
            tasks: vec![0],
            power_w: cnn_w.to_vec(),
        }],
        ..phase("transit", 120.0, 150.0)
    };
    let survey = PlanPhase {
        active_tasks: vec![0, 1],
        terms: vec![PowerTerm {
            tasks: vec![0, 1],
            power_w: joint_w,
        }],
        ..phase("survey", 900.0, 120.0)
    };
    let landing = PlanPhase {
        duration_by_level: Some(DurationByLevel {
            task: 1,
            duration_s: vec![100.0, 85.0, 70.0, 60.0],
        }),
        active_tasks: vec![1],
        terms: vec![PowerTerm {
            tasks: vec![1],
            power_w: detector_w.to_vec(),
        }],
        ..phase("landing", 60.0, 130.0)
    };
    PlanProblem {
        tasks: vec![
            task("cnn", &[0.2, 0.5, 0.8, 1.0], 1.0),
            task("detector", &[0.1, 0.4, 0.7, 1.0], 2.0),
        ],
        phases: vec![transit, survey, landing],
    }
}

fn survey_governor(
    capacity_wh: f64,
    estimator: EstimatorConfig,
    config: GovernorConfig,
) -> Governor {
    capture_logs();
    let spec = BatterySpec::from_capacity_wh(capacity_wh, 4, 3.7, 0.025).unwrap();
    let estimator = BatteryEstimator::with_config(spec, estimator).unwrap();
    Governor::new(survey_problem(), estimator, 0.25, config).unwrap()
}

/// The estimator told what a sensor with ±5 % uniform noise is like after the governor's
/// 5 s low-pass (about ±0.04 V per cell with the curve's own spread), and that the pack
/// was charged before take-off (a preflight check) rather than "unknown".
fn noisy_sensor_estimator() -> EstimatorConfig {
    EstimatorConfig {
        voltage_sigma_cell_v: 0.05,
        initial_soc: 1.0,
        initial_soc_sigma: 0.05,
        ..EstimatorConfig::default()
    }
}

// ---- the simulated flight ----------------------------------------------------------------

/// Uniform noise in [-1, 1] (splitmix64), so scenarios are deterministic.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

/// The world of a scenario. The pack is the governor's spec, full at take-off.
struct Scenario<'a> {
    /// True power ÷ the model's power at the levels in force, as a function of time.
    power_factor: &'a dyn Fn(f64) -> f64,
    /// Every voltage and current reading is off by a uniform fraction up to this.
    noise_fraction: f64,
    seed: u64,
    /// False: nobody reads the telemetry and the initial levels are flown throughout.
    governed: bool,
}

impl Scenario<'_> {
    fn constant(power_factor: &dyn Fn(f64) -> f64) -> Scenario<'_> {
        Scenario {
            power_factor,
            noise_fraction: 0.0,
            seed: 1,
            governed: true,
        }
    }
}

const STEP_S: f64 = 1.0;

struct Flight {
    events: Vec<GovernorEvent>,
    /// Usable energy left at the end, rated as the reserve is.
    final_remaining_wh: f64,
    /// The pack reached its cutoff before the mission's end.
    emptied: bool,
}

impl Flight {
    fn changes(&self) -> Vec<&LevelChange> {
        self.events
            .iter()
            .filter_map(|event| match event {
                GovernorEvent::LevelsChanged(change) => Some(change),
                _ => None,
            })
            .collect()
    }

    fn land_now(&self) -> Vec<&LandNow> {
        self.events
            .iter()
            .filter_map(|event| match event {
                GovernorEvent::LandNow(land_now) => Some(land_now),
                _ => None,
            })
            .collect()
    }

    fn downs(&self) -> usize {
        self.changes()
            .iter()
            .filter(|c| c.new_utility < c.old_utility)
            .count()
    }

    fn ups(&self) -> usize {
        self.changes()
            .iter()
            .filter(|c| c.new_utility > c.old_utility)
            .count()
    }
}

/// Flies the whole mission in steps of 1 s: the levels in force set the true power, the
/// Rint pack model gives the terminal voltage and current for it, the governor reads them.
/// A phase ends when its duration at the levels in force has passed.
fn fly(governor: &mut Governor, scenario: &Scenario) -> Flight {
    let spec = governor.estimator().spec().clone();
    let mut noise = Noise(scenario.seed);
    let mut soc = 1.0;
    let mut time_s = 0.0;
    let mut events = Vec::new();
    let mut progress = MissionProgress::start();
    let mut emptied = false;
    let phase_count = governor.problem().phases.len();
    loop {
        let factor = (scenario.power_factor)(time_s);
        let power_w = factor * governor.model_power_w(progress.phase).unwrap();
        let current_a = spec.current_for_power_a(soc, power_w).unwrap();
        let voltage_v = spec.terminal_voltage_v(soc, current_a);
        if voltage_v < spec.cutoff_voltage_v() {
            emptied = true;
            break;
        }
        if scenario.governed {
            let telemetry = BatteryTelemetry {
                time_s,
                voltage_v: Some(voltage_v * (1.0 + scenario.noise_fraction * noise.next())),
                current_a: Some(current_a * (1.0 + scenario.noise_fraction * noise.next())),
                consumed_mah: None,
                remaining_fraction: None,
            };
            events.extend(governor.update(&telemetry, progress).unwrap());
        }
        // The levels now in force draw this step's power.
        let power_w = factor * governor.model_power_w(progress.phase).unwrap();
        let current_a = spec.current_for_power_a(soc, power_w).unwrap();
        soc -= current_a * STEP_S / SECONDS_PER_HOUR / spec.capacity_ah();
        time_s += STEP_S;
        progress.phase_elapsed_s += STEP_S;
        let levels = governor.phase_levels(progress.phase).unwrap();
        let duration_s = governor.problem().phase_duration_s(progress.phase, levels);
        if progress.phase_elapsed_s >= duration_s.unwrap() - 1e-9 {
            if progress.phase + 1 == phase_count {
                break;
            }
            progress = MissionProgress::new(progress.phase + 1, 0.0);
        }
    }
    let final_remaining_wh = spec
        .usable_energy_wh(governor.reserve_rating_power_w(), soc.max(0.0), 0.0)
        .unwrap();
    Flight {
        events,
        final_remaining_wh,
        emptied,
    }
}

fn all_levels(governor: &Governor) -> Vec<Vec<TaskLevel>> {
    (0..governor.problem().phases.len())
        .map(|p| governor.phase_levels(p).unwrap().to_vec())
        .collect()
}

type Logged = (std::thread::ThreadId, tracing::Level, String);

/// The process-wide subscriber of these tests: records every event at INFO and above with
/// its thread, so a test reads its own. It is installed before any governor test reaches a
/// `tracing` call site (see [`capture_logs`]): a scoped subscriber would race with call
/// sites that other test threads register first, whose interest `tracing` caches.
struct Capture(std::sync::Mutex<Vec<Logged>>);

static CAPTURE: std::sync::OnceLock<&'static Capture> = std::sync::OnceLock::new();

/// Installs [`Capture`] as the global subscriber, once.
fn capture_logs() -> &'static Capture {
    CAPTURE.get_or_init(|| {
        let capture: &'static Capture = Box::leak(Box::new(Capture(Default::default())));
        // Only this function installs one; if something else did, the test that reads the
        // log says so.
        let _ = tracing::subscriber::set_global_default(CaptureRef(capture));
        capture
    })
}

struct CaptureRef(&'static Capture);

struct Fields<'a>(&'a mut String);

impl tracing::field::Visit for Fields<'_> {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn fmt::Debug) {
        self.0.push_str(&format!("{}={value:?} ", field.name()));
    }
}

impl tracing::Subscriber for CaptureRef {
    fn enabled(&self, metadata: &tracing::Metadata<'_>) -> bool {
        *metadata.level() <= tracing::Level::INFO
    }
    fn new_span(&self, _: &tracing::span::Attributes<'_>) -> tracing::span::Id {
        tracing::span::Id::from_u64(1)
    }
    fn record(&self, _: &tracing::span::Id, _: &tracing::span::Record<'_>) {}
    fn record_follows_from(&self, _: &tracing::span::Id, _: &tracing::span::Id) {}
    fn event(&self, event: &tracing::Event<'_>) {
        let mut fields = String::new();
        event.record(&mut Fields(&mut fields));
        let logged = (
            std::thread::current().id(),
            *event.metadata().level(),
            fields,
        );
        let mut log = self
            .0
             .0
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        log.push(logged);
    }
    fn enter(&self, _: &tracing::span::Id) {}
    fn exit(&self, _: &tracing::span::Id) {}
}
