//! Running the sweep in the real-time scheduler while the meter is read.

use super::*;

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
pub(super) trait Inputs {
    /// Called whenever due: publish what the tasks read.
    fn publish(&mut self, now: Duration);
    /// The measuring window begins (the warm-up is over).
    fn window_started(&mut self) {}
}

pub(super) struct NoInputs;

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
pub(super) fn measure(
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

/// The scheduler's id of config task `task`, or an error naming the tasks it holds.
fn task_id(
    scheduler: &RealTimeScheduler,
    config: &MissionConfig,
    task: usize,
) -> Result<TaskId, SchedulerError> {
    let name = &config.tasks[task].name;
    scheduler
        .task_id(name)
        .ok_or_else(|| SchedulerError::UnknownTask {
            task: name.clone(),
            known: scheduler
                .stats()
                .into_iter()
                .map(|stats| stats.name)
                .collect::<Vec<_>>()
                .join(", "),
        })
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
    let frames = synthetic_frames(&config.camera_settings()).map_err(SweepError::Frames)?;
    let mut scheduler = SchedulerBuilder::new(registry)
        .tasks(tasks.iter().copied())
        .build_real_time(RealTimeOptions::default())?;
    let camera = scheduler
        .bus()
        .publisher::<CameraFrame>(CAMERA_FRAME)
        .map_err(SweepError::Inputs)?;
    let vehicle = scheduler
        .bus()
        .publisher::<VehicleState>(VEHICLE_STATE)
        .map_err(SweepError::Inputs)?;
    scheduler.start()?;
    for knob in &plan.held {
        let id = task_id(&scheduler, config, knob.task)?;
        scheduler.set_level(id, knob.levels[0])?;
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
            let id = task_id(&scheduler, config, axis.task)?;
            scheduler.set_level(id, axis.levels[i])?;
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
