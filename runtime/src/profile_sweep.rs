//! The QoS sweep of `qosrt profile`: the configured tasks of one mission phase run in the
//! real-time scheduler on synthetic inputs (the dry run's rendered frames and hovering vehicle)
//! at each chosen combination of their QoS levels, while a [`PowerMeter`] is sampled at a steady
//! rate; the warm-up after each change is discarded, and the board's idle power (no task
//! running) is measured first. The result becomes a [`Profile`], the format `plan` reads.
//!
//! Choosing the combinations ([`plan_sweep`]) and turning readings into a profile
//! ([`summarise`], [`to_profile`]) are pure; [`run_sweep`] does the running and the reading.

use crate::config::MissionConfig;
use crate::dry_run::{hovering_vehicle, synthetic_frames, FRAME_PERIOD};
use crate::power_meter::{MeterError, PowerMeter, PowerReading};
use crate::registry::PluginRegistry;
use crate::scheduler::{RealTimeOptions, RealTimeScheduler, SchedulerBuilder, SchedulerError};
use crate::task::TaskHealth;
use crate::topics::{CameraFrame, VehicleState, CAMERA_FRAME, VEHICLE_STATE};
use power_models::profile::{ChannelStats, Profile, Sample};
use std::str::FromStr;
use std::time::{Duration, Instant};

/// A sweep aborts a point when more of its readings than this fraction fail.
const MAX_FAILED_READ_FRACTION: f64 = 0.1;
/// A meter below this fraction of the requested rate is reported.
const RATE_TOLERANCE: f64 = 0.9;
/// A task below this fraction of its nominal rate is reported (it cannot keep its level).
const TASK_RATE_TOLERANCE: f64 = 0.8;
/// Fewer activations than this in a point's window make its power a poor sample of the level.
const MIN_ACTIVATIONS: f64 = 3.0;
/// The activations per window the warning above asks for.
const FAIR_ACTIVATIONS: f64 = 10.0;

#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("--levels `{text}`: {message}")]
    BadLevels { text: String, message: String },
    #[error("unknown phase `{phase}`; the config's phases are: {known}")]
    UnknownPhase { phase: String, known: String },
    #[error("--levels {knob}: no task that runs in phase `{phase}` has this knob; those tasks' knobs are: {known}")]
    UnknownKnob {
        knob: String,
        phase: String,
        known: String,
    },
    #[error("--levels {knob}={value}: not one of the task's levels [{levels}]")]
    NotALevel {
        knob: String,
        value: f64,
        levels: String,
    },
    #[error("--levels {knob} is given twice")]
    KnobTwice { knob: String },
    #[error("--levels {knob}: task `{task}` cannot run here: its plugin `{plugin}` is not built into this binary")]
    KnobOfSkippedTask {
        knob: String,
        task: String,
        plugin: String,
    },
    #[error("phase `{phase}` has no task this binary can run{skipped}")]
    NothingToRun { phase: String, skipped: String },
    #[error("bad sweep option: {0}")]
    Options(String),
    #[error(transparent)]
    Scheduler(#[from] SchedulerError),
    #[error("synthetic inputs: {0}")]
    Inputs(String),
    #[error("meter {meter}: {failed} of {attempts} readings failed while measuring {point}; the last: {last}")]
    MeterFailed {
        meter: String,
        point: String,
        failed: usize,
        attempts: usize,
        last: Box<MeterError>,
    },
    #[error("meter {meter}: {readings} reading(s) in the {window_s:.2} s window of {point}, at least 2 are needed: lengthen --duration-s or raise --rate-hz")]
    TooFewReadings {
        meter: String,
        point: String,
        readings: usize,
        window_s: f64,
    },
}

/// `--levels task.knob=a,b,…`: the levels of one knob to sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelChoice {
    pub knob: String,
    pub values: Vec<f64>,
}

impl FromStr for LevelChoice {
    type Err = SweepError;

    fn from_str(text: &str) -> Result<Self, SweepError> {
        let bad = |message: &str| SweepError::BadLevels {
            text: text.to_string(),
            message: message.to_string(),
        };
        let (knob, values) = text
            .split_once('=')
            .ok_or_else(|| bad("expected TASK.KNOB=VALUE,VALUE,… e.g. hazard.rate_fps=4,1"))?;
        let knob = knob.trim();
        if !knob.contains('.') {
            return Err(bad("the knob is named TASK.KNOB, e.g. detection.rate_fps"));
        }
        let mut parsed = Vec::new();
        for cell in values.split(',') {
            let cell = cell.trim();
            let value: f64 = cell
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or_else(|| bad(&format!("`{cell}` is not a number")))?;
            if parsed.contains(&value) {
                return Err(bad(&format!("{cell} is given twice")));
            }
            parsed.push(value);
        }
        Ok(LevelChoice {
            knob: knob.to_string(),
            values: parsed,
        })
    }
}

/// One task's knob in the sweep: the levels it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct SweptKnob {
    /// Index of the task in the config.
    pub task: usize,
    /// `task.knob`.
    pub name: String,
    /// Level indices into the task's levels, lowest QoS first.
    pub levels: Vec<usize>,
    /// The knob values of those levels.
    pub values: Vec<f64>,
}

/// A task of the phase that does not run: its plugin is not in this binary.
#[derive(Debug, Clone, PartialEq)]
pub struct SkippedTask {
    pub task: String,
    pub plugin: String,
}

/// What the sweep runs.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    pub phase: String,
    /// Indices of the tasks that run.
    pub tasks: Vec<usize>,
    /// Knobs that take several levels: the profile's axes.
    pub axes: Vec<SweptKnob>,
    /// Knobs held at one level throughout (they are no axis of the profile).
    pub held: Vec<SweptKnob>,
    pub skipped: Vec<SkippedTask>,
}

impl SweepPlan {
    /// Every combination of the axes' levels, as positions into each axis's `levels`; the
    /// first axis changes slowest.
    pub fn combinations(&self) -> Vec<Vec<usize>> {
        let mut out = vec![Vec::new()];
        for axis in &self.axes {
            out = out
                .into_iter()
                .flat_map(|prefix| {
                    (0..axis.levels.len()).map(move |i| {
                        let mut next = prefix.clone();
                        next.push(i);
                        next
                    })
                })
                .collect();
        }
        out
    }

    /// `hazard.rate_fps=4, detection.rate_fps=10` for a combination.
    pub fn label(&self, combination: &[usize]) -> String {
        if self.axes.is_empty() {
            return "the held levels".to_string();
        }
        self.axes
            .iter()
            .zip(combination)
            .map(|(axis, &i)| format!("{}={}", axis.name, axis.values[i]))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Chooses the phase (by name, or the one with the most runnable tasks), its runnable tasks
/// (`can_run(plugin)`) and each knob's levels: those of `--levels`, else all the task's levels.
pub fn plan_sweep(
    config: &MissionConfig,
    can_run: &dyn Fn(&str) -> bool,
    phase: Option<&str>,
    choices: &[LevelChoice],
) -> Result<SweepPlan, SweepError> {
    let phases = &config.mission.phases;
    let phase = match phase {
        Some(name) => phases
            .iter()
            .find(|p| p.name == name)
            .ok_or_else(|| SweepError::UnknownPhase {
                phase: name.to_string(),
                known: phases
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?
            .name
            .clone(),
        None => {
            let runnable = |name: &str| {
                config
                    .tasks
                    .iter()
                    .filter(|t| t.runs_in(name) && can_run(&t.plugin))
                    .count()
            };
            // Most runnable tasks; the earliest phase on a tie.
            let mut best: Option<(&str, usize)> = None;
            for p in phases {
                let n = runnable(&p.name);
                if best.is_none_or(|(_, m)| n > m) {
                    best = Some((&p.name, n));
                }
            }
            best.map(|(name, _)| name.to_string()).unwrap_or_default()
        }
    };
    let in_phase: Vec<usize> = (0..config.tasks.len())
        .filter(|&i| config.tasks[i].runs_in(&phase))
        .collect();
    let (tasks, skipped_idx): (Vec<usize>, Vec<usize>) = in_phase
        .iter()
        .partition(|&&i| can_run(&config.tasks[i].plugin));
    let skipped: Vec<SkippedTask> = skipped_idx
        .iter()
        .map(|&i| SkippedTask {
            task: config.tasks[i].name.clone(),
            plugin: config.tasks[i].plugin.clone(),
        })
        .collect();
    for (n, choice) in choices.iter().enumerate() {
        if choices[..n].iter().any(|c| c.knob == choice.knob) {
            return Err(SweepError::KnobTwice {
                knob: choice.knob.clone(),
            });
        }
        if let Some(&i) = skipped_idx
            .iter()
            .find(|&&i| config.tasks[i].knob_name() == choice.knob)
        {
            return Err(SweepError::KnobOfSkippedTask {
                knob: choice.knob.clone(),
                task: config.tasks[i].name.clone(),
                plugin: config.tasks[i].plugin.clone(),
            });
        }
        if !tasks
            .iter()
            .any(|&i| config.tasks[i].knob_name() == choice.knob)
        {
            return Err(SweepError::UnknownKnob {
                knob: choice.knob.clone(),
                phase: phase.clone(),
                known: tasks
                    .iter()
                    .map(|&i| config.tasks[i].knob_name())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
    }
    if tasks.is_empty() {
        let skipped = if skipped.is_empty() {
            String::new()
        } else {
            format!(
                " (not built in: {})",
                skipped
                    .iter()
                    .map(|s| format!("task `{}` plugin `{}`", s.task, s.plugin))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        return Err(SweepError::NothingToRun { phase, skipped });
    }

    let (mut axes, mut held) = (Vec::new(), Vec::new());
    for &i in &tasks {
        let task = &config.tasks[i];
        let name = task.knob_name();
        let levels: Vec<usize> = match choices.iter().find(|c| c.knob == name) {
            None => (0..task.levels.len()).collect(),
            Some(choice) => {
                let mut levels = Vec::new();
                for &value in &choice.values {
                    let level = task
                        .levels
                        .iter()
                        .position(|&l| (l - value).abs() <= 1e-9 * l.abs().max(1.0))
                        .ok_or_else(|| SweepError::NotALevel {
                            knob: name.clone(),
                            value,
                            levels: task
                                .levels
                                .iter()
                                .map(f64::to_string)
                                .collect::<Vec<_>>()
                                .join(", "),
                        })?;
                    levels.push(level);
                }
                // Lowest QoS first, as the config lists them.
                levels.sort_unstable();
                levels
            }
        };
        let knob = SweptKnob {
            task: i,
            values: levels.iter().map(|&l| task.levels[l]).collect(),
            levels,
            name,
        };
        if knob.levels.len() > 1 {
            axes.push(knob);
        } else {
            held.push(knob);
        }
    }
    Ok(SweepPlan {
        phase,
        tasks,
        axes,
        held,
        skipped,
    })
}

/// How long each point is measured, and how often the meter is read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepOptions {
    /// Readings kept per point.
    pub duration: Duration,
    /// Discarded after each change of levels: the tasks settle, caches and clocks ramp.
    pub warmup: Duration,
    pub rate_hz: f64,
}

impl SweepOptions {
    pub fn check(&self) -> Result<(), SweepError> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 1000.0) {
            return Err(SweepError::Options(format!(
                "the sampling rate must be within (0, 1000] Hz, got {}",
                self.rate_hz
            )));
        }
        if self.duration.is_zero() {
            return Err(SweepError::Options(
                "the measuring time per point must be > 0 s".into(),
            ));
        }
        Ok(())
    }
}

/// What one point's readings came to.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    pub readings: usize,
    /// Length of the measuring window (after the warm-up).
    pub window_s: f64,
    pub total: ChannelStats,
    pub cpu: Option<ChannelStats>,
    pub gpu: Option<ChannelStats>,
    /// Readings per second in the window.
    pub achieved_rate_hz: f64,
    pub failed_reads: usize,
    /// The slowest meter read, in ms.
    pub slowest_read_ms: f64,
}

/// Mean and spread of a window's readings; `None` below 2 readings. The CPU and GPU rails
/// count only where every reading has them.
pub fn summarise(readings: &[PowerReading], window_s: f64) -> Option<Measurement> {
    let total: Vec<f64> = readings.iter().map(|r| r.total_w).collect();
    let rail = |pick: fn(&PowerReading) -> Option<f64>| {
        let values: Option<Vec<f64>> = readings.iter().map(pick).collect();
        values.and_then(|v| ChannelStats::of(&v))
    };
    Some(Measurement {
        readings: readings.len(),
        window_s,
        total: ChannelStats::of(&total)?,
        cpu: rail(|r| r.cpu_w),
        gpu: rail(|r| r.gpu_w),
        achieved_rate_hz: if window_s > 0.0 {
            readings.len() as f64 / window_s
        } else {
            0.0
        },
        failed_reads: 0,
        slowest_read_ms: 0.0,
    })
}

/// How fast a task ran during a point's window.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskRate {
    pub task: String,
    pub nominal_hz: f64,
    pub achieved_hz: f64,
}

/// One measured combination.
#[derive(Debug, Clone, PartialEq)]
pub struct PointResult {
    /// Knob values, in the order of the plan's axes.
    pub values: Vec<f64>,
    pub measurement: Measurement,
    pub task_rates: Vec<TaskRate>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct SweepResult {
    pub idle: Measurement,
    pub points: Vec<PointResult>,
    /// Everything the observer was warned of.
    pub warnings: Vec<String>,
}

/// Follows a sweep (a progress bar, a log). Every method has a do-nothing default.
pub trait SweepObserver {
    /// Step `step` of `steps` begins (step 0 is the idle baseline).
    fn step_started(&mut self, step: usize, steps: usize, label: &str) {
        let _ = (step, steps, label);
    }
    /// Called between readings: how far into the current step, in [0, 1].
    fn progress(&mut self, fraction: f64) {
        let _ = fraction;
    }
    fn step_finished(&mut self, label: &str, measurement: &Measurement) {
        let _ = (label, measurement);
    }
    fn warning(&mut self, message: &str) {
        let _ = message;
    }
}

/// What runs beside the meter during a point.
trait Inputs {
    /// Called whenever due: publish what the tasks read.
    fn publish(&mut self, now: Duration);
    /// The measuring window begins (the warm-up is over).
    fn window_started(&mut self) {}
}

struct NoInputs;

impl Inputs for NoInputs {
    fn publish(&mut self, _now: Duration) {}
}

/// The dry run's synthetic camera and vehicle, published at the camera's rate.
struct SyntheticInputs<'s> {
    scheduler: &'s RealTimeScheduler,
    camera: crate::bus::Publisher<CameraFrame>,
    vehicle: crate::bus::Publisher<VehicleState>,
    frames: Vec<std::sync::Arc<algorithms::vision::image::GrayImage>>,
    published: u64,
    next: Duration,
    /// Activation counts of the tasks when the window began.
    window_start: Vec<u64>,
    task_names: Vec<String>,
}

impl Inputs for SyntheticInputs<'_> {
    fn publish(&mut self, now: Duration) {
        if now < self.next {
            return;
        }
        let at = self.scheduler.now();
        self.vehicle.publish(at, hovering_vehicle());
        let image = self.frames[self.published as usize % self.frames.len()].clone();
        self.camera.publish(
            at,
            CameraFrame {
                vehicle_at_capture: None,
                frame_index: self.published,
                image,
            },
        );
        self.published += 1;
        self.next = now + FRAME_PERIOD;
    }

    fn window_started(&mut self) {
        self.window_start = self.activations();
    }
}

impl SyntheticInputs<'_> {
    fn activations(&self) -> Vec<u64> {
        self.task_names
            .iter()
            .map(|name| {
                self.scheduler
                    .task_stats(name)
                    .map_or(0, |stats| stats.activations)
            })
            .collect()
    }
}

/// Reads the meter at a steady rate for the warm-up and the window, keeping the window's
/// readings, with `inputs` published in between.
fn measure(
    meter: &mut dyn PowerMeter,
    options: &SweepOptions,
    point: &str,
    inputs: &mut dyn Inputs,
    observer: &mut dyn SweepObserver,
    warnings: &mut Vec<String>,
) -> Result<Measurement, SweepError> {
    let period = Duration::from_secs_f64(1.0 / options.rate_hz);
    let total = options.warmup + options.duration;
    let started = Instant::now();
    let mut next_read = Duration::ZERO;
    let mut in_window = false;
    let mut window_started = Duration::ZERO;
    let mut readings = Vec::new();
    let (mut attempts, mut failed) = (0usize, 0usize);
    let mut last_error = None;
    let mut slowest_read = Duration::ZERO;
    let mut read_time = Duration::ZERO;
    loop {
        let now = started.elapsed();
        if now >= total {
            break;
        }
        if !in_window && now >= options.warmup {
            in_window = true;
            window_started = now;
            inputs.window_started();
        }
        inputs.publish(now);
        if now >= next_read {
            let before = Instant::now();
            let reading = meter.read();
            let took = before.elapsed();
            read_time += took;
            slowest_read = slowest_read.max(took);
            if in_window {
                attempts += 1;
                match reading {
                    Ok(reading) => readings.push(reading),
                    Err(error) => {
                        failed += 1;
                        last_error = Some(error);
                    }
                }
            }
            next_read += period;
            // A meter slower than the rate: read again at once, but never in a burst.
            let after = started.elapsed();
            if next_read < after {
                next_read = after;
            }
        }
        observer.progress(now.as_secs_f64() / total.as_secs_f64());
        let wake = next_read.min(total);
        std::thread::sleep(wake.saturating_sub(started.elapsed()).min(FRAME_PERIOD));
    }
    let window_s = (started.elapsed() - window_started).as_secs_f64();
    if let Some(last) = last_error {
        if failed as f64 > MAX_FAILED_READ_FRACTION * attempts as f64 {
            return Err(SweepError::MeterFailed {
                meter: meter.name().to_string(),
                point: point.to_string(),
                failed,
                attempts,
                last: Box::new(last),
            });
        }
        let message = format!(
            "{point}: {failed} of {attempts} readings of meter {} failed and were left out; the last: {last}",
            meter.name()
        );
        observer.warning(&message);
        warnings.push(message);
    }
    let mut measurement =
        summarise(&readings, window_s).ok_or_else(|| SweepError::TooFewReadings {
            meter: meter.name().to_string(),
            point: point.to_string(),
            readings: readings.len(),
            window_s,
        })?;
    measurement.failed_reads = failed;
    measurement.slowest_read_ms = slowest_read.as_secs_f64() * 1e3;
    if measurement.achieved_rate_hz < RATE_TOLERANCE * options.rate_hz {
        let reads = attempts.max(1) as f64;
        let message = format!(
            "{point}: meter {} kept {:.1} of the requested {} readings/s (a read takes {:.1} ms on average, {:.1} ms at most): lower --rate-hz",
            meter.name(),
            measurement.achieved_rate_hz,
            options.rate_hz,
            read_time.as_secs_f64() * 1e3 / reads,
            measurement.slowest_read_ms
        );
        observer.warning(&message);
        warnings.push(message);
    }
    Ok(measurement)
}

/// Runs the plan: the idle baseline first, then every combination, on `meter`.
pub fn run_sweep(
    config: &MissionConfig,
    registry: &PluginRegistry,
    plan: &SweepPlan,
    meter: &mut dyn PowerMeter,
    options: &SweepOptions,
    observer: &mut dyn SweepObserver,
) -> Result<SweepResult, SweepError> {
    options.check()?;
    let combinations = plan.combinations();
    let steps = combinations.len() + 1;
    let mut warnings = Vec::new();

    // Idle: before any task is built, so none of them holds memory, threads or the GPU.
    let idle_label = "idle (no task running)";
    observer.step_started(0, steps, idle_label);
    let idle = measure(
        meter,
        options,
        idle_label,
        &mut NoInputs,
        observer,
        &mut warnings,
    )?;
    observer.step_finished(idle_label, &idle);

    let tasks: Vec<_> = plan.tasks.iter().map(|&i| &config.tasks[i]).collect();
    let task_names: Vec<String> = tasks.iter().map(|t| t.name.clone()).collect();
    let frames = synthetic_frames().map_err(|e| SweepError::Inputs(e.to_string()))?;
    let mut scheduler = SchedulerBuilder::new(registry)
        .tasks(tasks.iter().copied())
        .build_real_time(RealTimeOptions::default())?;
    let camera = scheduler
        .bus()
        .publisher::<CameraFrame>(CAMERA_FRAME)
        .map_err(|e| SweepError::Inputs(e.to_string()))?;
    let vehicle = scheduler
        .bus()
        .publisher::<VehicleState>(VEHICLE_STATE)
        .map_err(|e| SweepError::Inputs(e.to_string()))?;
    scheduler.start()?;
    for knob in &plan.held {
        scheduler.set_level(&config.tasks[knob.task].name, knob.levels[0])?;
    }
    let mut inputs = SyntheticInputs {
        scheduler: &scheduler,
        camera,
        vehicle,
        frames,
        published: 0,
        next: Duration::ZERO,
        window_start: Vec::new(),
        task_names,
    };

    let mut points = Vec::with_capacity(combinations.len());
    for (n, combination) in combinations.iter().enumerate() {
        let label = plan.label(combination);
        observer.step_started(n + 1, steps, &label);
        for (axis, &i) in plan.axes.iter().zip(combination) {
            scheduler.set_level(&config.tasks[axis.task].name, axis.levels[i])?;
        }
        inputs.next = Duration::ZERO;
        let measurement = measure(meter, options, &label, &mut inputs, observer, &mut warnings)?;
        let task_rates = task_rates(&inputs, &measurement, &label, observer, &mut warnings);
        observer.step_finished(&label, &measurement);
        points.push(PointResult {
            values: plan
                .axes
                .iter()
                .zip(combination)
                .map(|(axis, &i)| axis.values[i])
                .collect(),
            measurement,
            task_rates,
        });
    }
    drop(inputs);
    scheduler.stop();
    Ok(SweepResult {
        idle,
        points,
        warnings,
    })
}

/// Each task's rate over the window, with a warning where the task could not keep its level
/// (the power measured is then not that level's), had too few activations to be sampled
/// fairly, or failed.
fn task_rates(
    inputs: &SyntheticInputs<'_>,
    measurement: &Measurement,
    point: &str,
    observer: &mut dyn SweepObserver,
    warnings: &mut Vec<String>,
) -> Vec<TaskRate> {
    let now = inputs.activations();
    let mut rates = Vec::new();
    let mut warn = |message: String| {
        observer.warning(&message);
        warnings.push(message);
    };
    for ((name, after), before) in inputs.task_names.iter().zip(&now).zip(&inputs.window_start) {
        let Some(stats) = inputs.scheduler.task_stats(name) else {
            continue;
        };
        let nominal_hz = 1000.0 / stats.period_ms;
        let achieved_hz = after.saturating_sub(*before) as f64 / measurement.window_s;
        let expected = nominal_hz * measurement.window_s;
        if stats.health != TaskHealth::Running {
            warn(format!(
                "{point}: task `{name}` is {} ({}): the power measured is not that of its level",
                stats.health,
                stats.last_error.as_deref().unwrap_or("no error recorded")
            ));
        } else if expected >= 10.0 && achieved_hz < TASK_RATE_TOLERANCE * nominal_hz {
            warn(format!(
                "{point}: task `{name}` ran at {achieved_hz:.2} of its {nominal_hz:.2} activations/s: this board cannot keep the level"
            ));
        } else if expected < MIN_ACTIVATIONS {
            warn(format!(
                "{point}: task `{name}` at {nominal_hz:.3} activations/s runs only {expected:.1} times in the {:.1} s window: lengthen --duration-s to at least {:.0} s for a fair sample",
                measurement.window_s,
                FAIR_ACTIVATIONS / nominal_hz
            ));
        }
        rates.push(TaskRate {
            task: name.clone(),
            nominal_hz,
            achieved_hz,
        });
    }
    rates
}

/// The sweep as a profile: one sample per combination (knobs in the order of the plan's
/// axes), and the idle baseline. `source` says how it was measured.
pub fn to_profile(
    plan: &SweepPlan,
    result: &SweepResult,
    board: &str,
    meter: &str,
    rate_hz: f64,
    source: String,
) -> Profile {
    Profile {
        board: board.to_string(),
        meter: meter.to_string(),
        sample_rate_hz: Some(rate_hz),
        source: Some(source),
        idle_power_w: Some(result.idle.total.mean_w),
        idle_power_std_w: Some(result.idle.total.std_w),
        knobs: plan.axes.iter().map(|axis| axis.name.clone()).collect(),
        samples: result
            .points
            .iter()
            .map(|point| Sample {
                knobs: point.values.clone(),
                power_w: point.measurement.total.mean_w,
                power_std_w: Some(point.measurement.total.std_w),
                duration_s: Some(point.measurement.window_s),
                cpu_power_w: point.measurement.cpu.map(|c| c.mean_w),
                gpu_power_w: point.measurement.gpu.map(|c| c.mean_w),
            })
            .collect(),
    }
}

/// How the sweep was run, in words, for the profile's `source`.
pub fn describe_method(plan: &SweepPlan, config: &MissionConfig, options: &SweepOptions) -> String {
    let mut text = format!(
        "qosrt profile: phase `{}` of mission `{}`, each point {} s after {} s of warm-up, meter read at {} Hz, tasks on synthetic rendered frames",
        plan.phase,
        config.mission.name,
        options.duration.as_secs_f64(),
        options.warmup.as_secs_f64(),
        options.rate_hz
    );
    if !plan.held.is_empty() {
        let held: Vec<String> = plan
            .held
            .iter()
            .map(|k| format!("{} = {}", k.name, k.values[0]))
            .collect();
        text += &format!("; held: {}", held.join(", "));
    }
    if !plan.skipped.is_empty() {
        let skipped: Vec<String> = plan
            .skipped
            .iter()
            .map(|s| format!("{} (plugin {})", s.task, s.plugin))
            .collect();
        text += &format!("; not run (plugin not built in): {}", skipped.join(", "));
    }
    text
}

#[cfg(test)]
mod tests;
