//! The harness: the world and the runtime built once, then coupled tick by tick, and the
//! outcome told at the end.

use std::time::Instant;

use runtime::clock::Timestamp;
use runtime::config::PhaseKind;
use runtime::energy::MissionModel;
use runtime::link::MavlinkLink;
use runtime::mission::{
    LandingBy, MissionEvent, MissionObserver, MissionPlan, MissionRunner, RunnerError,
    RunnerOptions, StepReport,
};
use runtime::record::{Recorder, RecordingHeader, RecordingSource};
use runtime::registry::PluginRegistry;
use runtime::ros2::Ros2Node;
use runtime::scheduler::{Pinning, RealTimeOptions, SchedulerBuilder, TaskScheduler};
use sim::autopilot::MavlinkAutopilot;
use sim::camera::SimCameraConfig;
use sim::power::{RotorPowerModel, SimBattery};
use sim::realism::Realism;
use sim::scene::{HazardField, SimScene, TractorBody};
use sim::tractor::TractorParams;
use sim::world::World;

use super::autopilot::AutopilotProcess;
use super::camera_feed::CameraFeed;
use super::flyer::Flyer;
use super::*;
use crate::outcome::{QosChange, SimOutcome};
use crate::score::{FlightScore, TrackTruth};

type Runner = MissionRunner<Box<dyn TaskScheduler>>;

/// One mission's world and runtime, coupled.
pub(super) struct Harness<'a> {
    options: &'a SimOptions,
    /// The configured mission, its tracking time the one flown.
    model: MissionModel,
    runner: Runner,
    flyer: Flyer,
    world: World,
    scene: SimScene,
    camera: CameraFeed,
    battery: SimBattery,
    rotors: RotorPowerModel,
    score: FlightScore,
    phases: PhaseTimes,
    /// The world's events beside the runtime's log.
    events: Vec<(f64, String)>,
    max_time_s: f64,
    skipped_tasks: Vec<String>,
    hazards_total: usize,
    /// Last, so the autopilot qosrt started outlives the link to it.
    _autopilot_process: Option<AutopilotProcess>,
}

/// When the phases that matter to the world began.
#[derive(Default)]
struct PhaseTimes {
    /// The phase in flight (index into the config's phases) and its name.
    current: Option<(usize, String)>,
    /// The first tracking phase's start: the tractor drives, the faults count from here.
    tracking_started_s: Option<f64>,
    landing_started_s: Option<f64>,
}

impl PhaseTimes {
    /// Whether `time_s` lies in `window`, timed from the tracking's start.
    fn in_window(&self, time_s: f64, window: Option<(f64, f64)>) -> bool {
        match (window, self.tracking_started_s) {
            (Some((from_s, until_s)), Some(start_s)) => {
                let t_s = time_s - start_s;
                t_s >= from_s && t_s < until_s
            }
            _ => false,
        }
    }
}

impl<'a> Harness<'a> {
    /// The runtime (every configured task whose plugin this build has), the world, its camera
    /// and pack, and who flies the vehicle, joined by MAVLink as on a drone.
    pub(super) fn build(
        model: &MissionModel,
        registry: &PluginRegistry,
        options: &'a SimOptions,
    ) -> Result<Self, SimError> {
        let model = with_tracking_time(model, options.tracking_s);
        let (scheduler, skipped_tasks) = build_scheduler(&model, registry, options)?;
        let realism = &options.world.realism;
        let seed = options.world.seed;
        let pad_height_m = TractorParams::default().pad_height_m;
        let world = World::build(&options.world, pad_height_m)?;
        // The sequencer flies to the world's meeting point, at cruise height above its pad.
        let plan = mission_plan(&model, options.world.meeting_point_ne_m, pad_height_m);
        let (scene, hazards_total) = build_scene(&model, &world, realism, seed)?;
        let (battery, rotors) = pack_and_rotors(&model).map_err(SimError::Setup)?;
        let camera_config = SimCameraConfig {
            exposure_ms: realism.camera.exposure_ms,
            render_threads: options.render_threads,
            ..camera_config(&model)
        };
        let camera = CameraFeed::new(
            camera_config,
            realism.camera,
            &model.config.tasks,
            registry,
            options.stereo,
            &*scheduler,
            seed,
            options.real_time,
        )?;
        let score = FlightScore::new(scheduler.bus(), options.record_track).map_err(setup)?;
        let gimbal = camera_gimbal(&model).map_err(setup)?;
        let (flyer, link, autopilot_process) = match &options.autopilot {
            None if MissionPlan::for_mission(&model.config).landing
                == LandingBy::AutopilotPrecision =>
            {
                return Err(SimError::NoPrecisionLanding);
            }
            None => Flyer::builtin(gimbal, realism, seed, options.real_time)?,
            Some(real) => Flyer::real(real, gimbal, seed)?,
        };
        let mut events = Vec::new();
        let runner = start_runner(&model, plan, scheduler, link, &camera, options, &mut events)?;
        let max_time_s = options.max_time_s.unwrap_or_else(|| {
            phases_duration_s(&model.config.mission, |kind| kind != PhaseKind::Transit)
                + TIME_MARGIN_S
        });
        Ok(Self {
            options,
            model,
            runner,
            flyer,
            world,
            scene,
            camera,
            battery,
            rotors,
            score,
            phases: PhaseTimes::default(),
            events,
            max_time_s,
            skipped_tasks,
            hazards_total,
            _autopilot_process: autopilot_process,
        })
    }

    /// Each tick, in lockstep: the camera captures and delivers, the autopilot's telemetry
    /// reaches the runtime, its tasks run up to the tick, its commands go back, the flight is
    /// scored, physics moves on. Until the mission is done and the vehicle has settled, the
    /// time limit passes or the pack gives out; returns the simulated end time.
    pub(super) fn fly(&mut self) -> Result<f64, SimError> {
        let pace_start = Instant::now();
        let mut finished_s = None;
        let mut tick = 0u64;
        loop {
            let time_s = tick as f64 * TICK_S;
            self.report_progress(tick, time_s, pace_start);
            if time_s > self.max_time_s {
                let limit = format!("simulation time limit of {:.0} s reached", self.max_time_s);
                self.events.push((time_s, limit));
                break;
            }
            let link_down = self.phases.in_window(time_s, self.options.faults.link_loss);
            self.flyer.set_link_down(link_down);
            let now = Timestamp::from_nanos(MavlinkAutopilot::time_ns(time_s));
            // The runtime's clock: the world's in lockstep; the real-time scheduler's (the one
            // its tasks stamp messages with) on the wall clock.
            let runtime_now_s = if self.options.real_time {
                self.runner.scheduler().now().as_secs_f64()
            } else {
                now.as_secs_f64()
            };
            self.camera.capture(
                time_s,
                now,
                runtime_now_s,
                &**self.runner.scheduler(),
                &self.flyer,
                &self.world.tractor,
                &mut self.scene,
                &mut self.events,
            )?;
            self.camera.deliver(time_s, runtime_now_s, &mut self.events);
            let step = self.exchange(time_s, runtime_now_s)?;
            self.observe(time_s, runtime_now_s, step);
            if self.runner.status().finished && finished_s.is_none() {
                finished_s = Some(time_s);
            }
            // Let the vehicle settle on the pad for a moment, then stop.
            if finished_s.is_some_and(|done_s| time_s - done_s >= 1.0) {
                break;
            }
            if !self.advance(time_s)? {
                break;
            }
            self.sample(time_s);
            tick += 1;
            if self.options.real_time {
                // The world keeps the pace of the wall clock.
                let due = pace_start + std::time::Duration::from_secs_f64(tick as f64 * TICK_S);
                std::thread::sleep(due.saturating_duration_since(Instant::now()));
            }
        }
        Ok(tick as f64 * TICK_S)
    }

    /// Once a simulated second, how far the mission is.
    fn report_progress(&self, tick: u64, time_s: f64, pace_start: Instant) {
        let Some(progress) = &self.options.progress else {
            return;
        };
        let ticks_per_report = (1.0 / TICK_S).round().max(1.0) as u64;
        if tick.is_multiple_of(ticks_per_report) {
            (progress.0)(&SimProgress {
                time_s,
                max_time_s: self.max_time_s,
                phase: self.phases.current.clone(),
                phase_count: self.model.config.mission.phases.len(),
                wall_s: pace_start.elapsed().as_secs_f64(),
            });
        }
    }

    /// Autopilot → runtime → autopilot: in lockstep, or as the datagrams come. A real
    /// autopilot streams on its own; the world and it are in lockstep through its simulator
    /// interface.
    fn exchange(&mut self, time_s: f64, runtime_now_s: f64) -> Result<StepReport, SimError> {
        let battery = self.battery.reading();
        let lockstep = self
            .flyer
            .send_telemetry(time_s, battery, !self.options.real_time)?;
        let step = self
            .runner
            .step(runtime_now_s, lockstep)
            .map_err(|error| match error {
                RunnerError::Scheduler(error) => SimError::Scheduler(error),
                other => SimError::Link(other.into()),
            })?;
        self.flyer.apply_commands(time_s, lockstep)?;
        Ok(step)
    }

    /// The runtime's step against the truth, and the phases it started.
    fn observe(&mut self, time_s: f64, runtime_now_s: f64, step: StepReport) {
        if self.phases.tracking_started_s.is_some() && self.flyer.touchdown().is_none() {
            let vehicle_ned_m = self.flyer.position_ned_m();
            self.score
                .localise(runtime_now_s, &vehicle_ned_m, &self.world.pad());
        }
        self.score.hazards(self.scene.hazards());
        if let Some(setpoint) = &step.landing {
            self.score.landing(time_s, setpoint, &mut self.events);
        }
        for event in &step.events {
            if let MissionEvent::PhaseStarted { phase, .. } = event {
                self.phase_started(time_s, *phase);
            }
        }
    }

    /// What the world does at a phase's start: a tracking phase starts the faults' clock, and
    /// the tractor drives off once the vehicle is with it.
    fn phase_started(&mut self, time_s: f64, phase: usize) {
        let mission = &self.model.config.mission;
        self.phases.current = mission.phases.get(phase).map(|p| (phase, p.name.clone()));
        let kind = mission.phase_kinds().get(phase).copied();
        if kind == Some(PhaseKind::Land) {
            self.phases.landing_started_s = Some(time_s);
        }
        if kind == Some(PhaseKind::Track) && self.phases.tracking_started_s.is_none() {
            self.phases.tracking_started_s = Some(time_s);
            self.camera.inject(&self.options.faults, time_s);
        }
        self.world.tractor_moving |= kind != Some(PhaseKind::Transit);
    }

    /// Physics to the tick's end, and the pack drained by the rotors and the companion; false
    /// when the pack gives out.
    fn advance(&mut self, time_s: f64) -> Result<bool, SimError> {
        self.flyer.step_world(&mut self.world, time_s)?;
        let flight_w = self
            .flyer
            .flight_power_w(&mut self.world.wind, &self.rotors, time_s);
        // The companion draws what the tasks of the phase in flight cost at their levels.
        let companion_w = self.runner.companion_power_w();
        if let Err(error) = self.battery.drain(flight_w, companion_w, TICK_S) {
            self.events.push((time_s, format!("battery: {error}")));
            return Ok(false);
        }
        if self.battery.soc() <= 0.0 {
            self.events
                .push((time_s, "battery empty: the vehicle falls".into()));
            return Ok(false);
        }
        Ok(true)
    }

    /// The track and the levels for the plots.
    fn sample(&mut self, time_s: f64) {
        let (runner, flyer, world, battery) =
            (&self.runner, &self.flyer, &self.world, &self.battery);
        self.score.sample(
            time_s,
            || {
                runner
                    .qos_levels()
                    .tasks
                    .into_iter()
                    .map(|(task, l)| (task, l.level, l.value))
                    .collect()
            },
            || {
                let pose = world.tractor.pose();
                TrackTruth {
                    vehicle_ned_m: flyer.position_ned_m(),
                    tractor_ne_m: [pose.position_ne_m.x, pose.position_ne_m.y],
                    battery_soc: battery.soc(),
                }
            },
        );
    }

    /// Stops the runtime, closes the recording and tells how the mission went.
    pub(super) fn finish(
        mut self,
        end_s: f64,
        wall_start: Instant,
    ) -> Result<SimOutcome, SimError> {
        self.runner.stop();
        if let Some(summary) = self.runner.finish_recording().transpose()? {
            self.events.push((end_s, summary.describe()));
        }
        let failed_tasks = failed_tasks(&**self.runner.scheduler());
        let log = self.runner.log();
        let loop_step = log.loop_step();
        let latency = log.capture_to_setpoint();
        let delivered = log.delivered_to_setpoint();
        let qos_changes = log
            .governor
            .iter()
            .map(|decision| QosChange {
                time_s: decision.time_s,
                description: decision.description.clone(),
            })
            .collect();
        // The runtime's log (mission events, refused telemetry, camera faults) beside the
        // world's.
        let mut events = self.events;
        events.extend(log.events.iter().cloned());
        events.sort_by(|a, b| a.0.total_cmp(&b.0));
        let touchdown = self.flyer.touchdown();
        // How hard and how leaning: the first contact (a bounce's later ones are softer).
        let first_touchdown = self.flyer.first_touchdown();
        let (flight_energy_wh, companion_energy_wh) = self.battery.energy_wh();
        let score = self.score;
        let wall_s = wall_start.elapsed().as_secs_f64();
        Ok(SimOutcome {
            seed: self.options.world.seed,
            landed_on_pad: touchdown.is_some_and(|t| t.on_pad),
            touched_down: touchdown.is_some(),
            touchdown_error_m: touchdown.map(|t| t.horizontal_error_m),
            touchdown_tilt_deg: first_touchdown.map(|t| t.tilt_deg),
            touchdown_vertical_speed_m_s: first_touchdown.map(|t| t.vertical_speed_m_s),
            blind_before_contact_s: first_touchdown.and(score.fix_age_s),
            time_to_land_s: match (touchdown, self.phases.landing_started_s) {
                (Some(t), Some(start)) => Some(t.time_s - start),
                _ => None,
            },
            mission_time_s: end_s,
            flight_energy_wh,
            companion_energy_wh,
            battery_left_fraction: self.battery.soc(),
            landing_aborts: score.landing_aborts,
            qos_changes,
            events,
            // Only a task that declares the hazards topic can publish a report on it.
            hazards_seen: score.hazard_backend.map(|_| score.hazards.seen()),
            hazards_total: self.hazards_total,
            hazard_frames: score.hazards.frames,
            hazard_false_detections: score.hazards.false_detections,
            hazard_backend: score.hazard_backend.map(str::to_string),
            failed_tasks,
            skipped_tasks: self.skipped_tasks,
            speedup: end_s / wall_s.max(1e-9),
            localisation: score.localisation.finish(),
            track: score.track,
            qos_track: score.qos_track,
            loop_step_p50_us: loop_step.p50_us,
            loop_step_p99_us: loop_step.p99_us,
            capture_to_setpoint_ms: (latency.count > 0)
                .then(|| [latency.p50_us, latency.p99_us, latency.max_us].map(|us| us / 1e3)),
            capture_to_setpoint_fixes: latency.count,
            delivered_to_setpoint_ms: (delivered.count > 0)
                .then(|| [delivered.p50_us, delivered.p99_us, delivered.max_us].map(|us| us / 1e3)),
        })
    }
}

/// The mission as configured, its tracking phases lasting `tracking_s` where given: the
/// governor plans for the tracking time actually flown.
fn with_tracking_time(model: &MissionModel, tracking_s: Option<f64>) -> MissionModel {
    let mut adjusted = model.clone();
    if let Some(tracking_s) = tracking_s {
        let kinds = adjusted.config.mission.phase_kinds();
        for (phase, kind) in adjusted.config.mission.phases.iter_mut().zip(kinds) {
            if kind == PhaseKind::Track {
                phase.duration_s = tracking_s;
            }
        }
    }
    adjusted
}

/// The runtime's scheduler with every configured task whose plugin this build has, and the
/// tasks it could not run and why.
fn build_scheduler(
    model: &MissionModel,
    registry: &PluginRegistry,
    options: &SimOptions,
) -> Result<(Box<dyn TaskScheduler>, Vec<String>), SimError> {
    let mut skipped_tasks = Vec::new();
    let mut builder = SchedulerBuilder::new(registry);
    builder.seed(options.world.seed);
    for task in &model.config.tasks {
        if registry.contains(&task.plugin) {
            builder.task(task);
        } else {
            skipped_tasks.push(format!(
                "{} (plugin `{}` is not built into this binary)",
                task.name, task.plugin
            ));
        }
    }
    let scheduler: Box<dyn TaskScheduler> = if options.real_time {
        Box::new(builder.build_real_time(RealTimeOptions {
            pinning: Pinning::Off,
            ..RealTimeOptions::default()
        })?)
    } else {
        Box::new(builder.build_virtual()?)
    };
    Ok((scheduler, skipped_tasks))
}

/// What the camera sees: the tractor's body, and the hazards beside the track it will drive
/// while the CNN watches; and how many hazards there are.
fn build_scene(
    model: &MissionModel,
    world: &World,
    realism: &Realism,
    seed: u64,
) -> Result<(SimScene, usize), SimError> {
    let watch_s = phases_duration_s(&model.config.mission, |kind| kind == PhaseKind::Track);
    let track = future_track_ne_m(&world.tractor, watch_s).map_err(setup)?;
    let hazards = HazardField::along_track(seed, &track, &track_scatter(&track)).map_err(setup)?;
    let hazards_total = hazards.hazards.len();
    let scene = SimScene::new(seed)
        .with_tractor_body(TractorBody::default())
        .map_err(setup)?
        .with_hazards(hazards)
        .with_pad_occluders(pad_occluders(&realism.camera, seed));
    Ok((scene, hazards_total))
}

/// The mission runner flying `plan` on `scheduler` and `link`, reading the camera's frames,
/// recording where asked (the Foxglove port told in `events`).
fn start_runner(
    model: &MissionModel,
    mut plan: MissionPlan,
    scheduler: Box<dyn TaskScheduler>,
    link: MavlinkLink,
    camera: &CameraFeed,
    options: &SimOptions,
    events: &mut Vec<(f64, String)>,
) -> Result<Runner, SimError> {
    if options.autopilot.is_some() {
        // A real autopilot refuses to arm until its estimator has converged on the world's
        // sensors (PX4 about 16 s, ArduPilot about 42 s).
        plan.command_timeout_s = plan.command_timeout_s.max(REAL_AUTOPILOT_READY_S);
    }
    let runner_options = RunnerOptions {
        landing_target: model.config.link.as_ref().is_some_and(|l| l.landing_target),
        fixed_levels: options.fixed_levels.clone(),
    };
    let mut runner = MissionRunner::new(
        model.clone(),
        scheduler,
        link,
        plan.clone(),
        Some(Box::new(camera.source())),
        runner_options.clone(),
    )
    .map_err(|error| match error {
        RunnerError::FixedLevel { task, value, why } => SimError::FixedLevel { task, value, why },
        other => SimError::Setup(other.into()),
    })?;
    if let Some(vehicle) = &options.ros2_vehicle {
        let capacity_ah = model.config.battery.capacity_ah().unwrap_or(f64::NAN);
        let node = Ros2Node::start(vehicle, capacity_ah)?;
        events.push((
            0.0,
            format!("publishing ROS 2 topics under {}", node.namespace()),
        ));
        runner.observe(Box::new(node));
    }
    if !options.plan_changes.is_empty() {
        runner.observe(Box::new(ScheduledPlanRequests::new(&options.plan_changes)));
    }
    let Some(record) = &options.record else {
        return Ok(runner);
    };
    let mut header = RecordingHeader::new(
        RecordingSource::Sim,
        options.world.seed,
        plan,
        &model.config,
        true,
        record
            .config_files
            .first()
            .map_or_else(String::new, |f| f.path.clone()),
    );
    header.fixed_levels = runner_options.fixed_levels;
    header.landing_target = runner_options.landing_target;
    header.link_peer_known = runner.link().has_peer();
    let recorder = Recorder::start(&record.recorder, &header, &record.config_files)?;
    if let Some(port) = recorder.live_port() {
        events.push((0.0, format!("serving Foxglove's WebSocket on port {port}")));
    }
    runner.record(recorder).map_err(setup)?;
    Ok(runner)
}

/// The tasks that failed for good, each with its last error.
fn failed_tasks(scheduler: &dyn TaskScheduler) -> Vec<String> {
    let stats = scheduler.stats();
    scheduler
        .failed_tasks()
        .into_iter()
        .map(|name| {
            let error = stats
                .iter()
                .find(|s| s.name == name)
                .and_then(|s| s.last_error.clone())
                .unwrap_or_default();
            format!("{name}: {error}")
        })
        .collect()
}

/// The plan changes of `--plan-change`, each handed to the runner at the first step at or after
/// its time, numbered in order.
struct ScheduledPlanRequests {
    pending: std::sync::Mutex<std::collections::VecDeque<ScheduledPlanChange>>,
}

impl ScheduledPlanRequests {
    fn new(changes: &[ScheduledPlanChange]) -> Self {
        let mut changes = changes.to_vec();
        changes.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        for (id, change) in changes.iter_mut().enumerate() {
            change.request.id = id as u64 + 1;
        }
        Self {
            pending: std::sync::Mutex::new(changes.into()),
        }
    }
}

impl MissionObserver for ScheduledPlanRequests {
    fn plan_requests(&self, now_s: f64) -> Vec<runtime::mission::PlanRequest> {
        let mut pending = self
            .pending
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut due = Vec::new();
        while pending.front().is_some_and(|change| change.at_s <= now_s) {
            due.extend(pending.pop_front().map(|change| change.request));
        }
        due
    }
}
