//! One simulated mission: the world (vehicle, tractor, wind, camera, pack) and the runtime's
//! mission runner (the configured task plugins on the virtual-time scheduler, the governor, the
//! mission sequencer), joined only by MAVLink over UDP on the loopback and by camera frames.
//!
//! Time advances in ticks of [`TICK_S`] (50 Hz, the rate at which PX4 streams attitude and
//! position); physics integrates at [`PHYSICS_DT_S`] inside a tick. Each tick, in lockstep:
//! the autopilot sends its telemetry ending in a TIMESYNC; the runtime's link reads up to that
//! barrier; the camera renders if a consumer will look; the runtime's tasks run up to the
//! tick; the sequencer's commands go back over the link, again up to a barrier; the autopilot
//! applies them; physics moves on. Nothing depends on the host's speed, so the same config and
//! seed fly the same mission.

use crate::hazard_score::HazardScore;
use algorithms::vision::render::SplitMix64;
use nalgebra::Vector3;
use runtime::camera::{CapturedFrame, MemorySource};
use runtime::clock::Timestamp;
use runtime::config::{Mission, PhaseKind};
use runtime::energy::MissionModel;
use runtime::link::{LinkConfig, MavlinkLink};
use runtime::mission::runner::LOCKSTEP_TIMEOUT;
use runtime::mission::{
    LandingBy, MissionEvent, MissionPlan, MissionRunner, RunnerError, RunnerOptions,
};
use runtime::record::{
    ConfigFile, RecordError, Recorder, RecorderOptions, RecordingHeader, RecordingSource,
};
use runtime::registry::PluginRegistry;
use runtime::scheduler::{Pinning, RealTimeOptions, SchedulerBuilder, TaskScheduler};
use runtime::topics::{
    CameraFrame, DepthFrame, HazardReport, RelativeState, CAMERA_FRAME, DEPTH_FRAME, HAZARDS,
    RELATIVE_STATE,
};
use sim::autopilot::MavlinkAutopilot;
use sim::autopilot::StreamRates;
use sim::camera::{PendingFrame, SimCamera, SimCameraConfig};
use sim::estimate::EstimatedTelemetry;
use sim::gimbal::{Gimbal, GimbalError, GimbalParams};
use sim::outcome::{LocalisationAccumulator, QosChange, QosSample, SimOutcome, TrackSample};
use sim::power::{RotorPowerModel, SimBattery, SimPack};
use sim::realism::CameraRealism;
use sim::scene::PadOccluder;
use sim::scene::{HazardField, PadPose, SimScene, TrackScatterConfig, TractorBody};
use sim::stereo_camera::{SimStereoCamera, StereoCameraConfig};
use sim::tractor::{Tractor, TractorParams};
use sim::vehicle::{Multirotor, VehicleParams};
use sim::wind::Wind;
use sim::world::{World, WorldOptions};
use std::time::Instant;

mod autopilot;
mod options;
mod world;

use autopilot::Flyer;
pub use autopilot::{
    AutopilotKind, AutopilotProcess, RealAutopilot, RealVehicle, REAL_AUTOPILOT_READY_S,
};
pub(crate) use autopilot::{CameraGimbal, GimballedVehicle};
pub use options::*;
pub use world::*;

/// Flies one mission.
pub fn simulate(
    model: &MissionModel,
    registry: &PluginRegistry,
    options: &SimOptions,
) -> Result<SimOutcome, SimError> {
    let wall_start = Instant::now();
    // The governor plans for the tracking time actually flown.
    let mut adjusted = model.clone();
    if let Some(tracking_s) = options.tracking_s {
        let kinds = adjusted.config.mission.phase_kinds();
        for (phase, kind) in adjusted.config.mission.phases.iter_mut().zip(kinds) {
            if kind == PhaseKind::Track {
                phase.duration_s = tracking_s;
            }
        }
    }
    let model = &adjusted;
    let config = &model.config;

    // The runtime: every configured task whose plugin this build has.
    let mut skipped_tasks = Vec::new();
    let mut builder = SchedulerBuilder::new(registry);
    builder.seed(options.world.seed);
    for task in &config.tasks {
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

    // The world.
    let pad_height_m = TractorParams::default().pad_height_m;
    let realism = &options.world.realism;
    let seed = options.world.seed;
    let mut world = World::build(&options.world, pad_height_m)?;
    let camera_config = SimCameraConfig {
        exposure_ms: realism.camera.exposure_ms,
        render_threads: options.render_threads,
        ..camera_config(model)
    };
    let camera_period_s = 1.0 / camera_config.rate_fps;
    // Frames reach the runtime after their capture-to-delivery latency, stamped with their
    // capture time, in order.
    // (delivery time, capture time on the runtime's clock, the frame being rendered)
    let mut in_transit: std::collections::VecDeque<(f64, f64, PendingFrame)> =
        std::collections::VecDeque::new();
    let mut latency_rng = SplitMix64::new(seed ^ 0x006c_6174_656e_6379);
    let mut camera = SimCamera::new(camera_config, seed).map_err(setup)?;
    // The hazards stand beside the track the tractor will drive while the CNN watches.
    let watch_s = phases_duration_s(&model.config.mission, |kind| kind == PhaseKind::Track);
    let track = future_track_ne_m(&world.tractor, watch_s).map_err(setup)?;
    let hazards = HazardField::along_track(seed, &track, &track_scatter(&track)).map_err(setup)?;
    let hazards_total = hazards.hazards.len();
    let mut scene = SimScene::new(seed)
        .with_tractor_body(TractorBody::default())
        .map_err(setup)?
        .with_hazards(hazards)
        .with_pad_occluders(pad_occluders(&realism.camera, seed));
    // The world's pack has the config's capacity, cells and resistance.
    let spec = model.battery_spec(None).map_err(setup)?;
    let pack = SimPack::new(
        spec.capacity_mah,
        spec.cell_count,
        spec.internal_resistance_ohm,
    )
    .map_err(setup)?;
    let mut battery = SimBattery::new(pack);
    let hover_power_w = hover_power_w(model)
        .ok_or_else(|| SimError::Setup("[flight] gives no hover_power_w".into()))?;
    let rotors = RotorPowerModel::iris(hover_power_w);
    rotors.validate().map_err(setup)?;

    let gimbal = camera_gimbal(model).map_err(setup)?;
    // The vehicle and who flies it; the runtime's MAVLink to its autopilot, as on a drone.
    let telemetry = &realism.telemetry;
    let (mut flyer, link, _autopilot_process) = match &options.autopilot {
        None if MissionPlan::for_mission(&model.config).landing
            == LandingBy::AutopilotPrecision =>
        {
            return Err(SimError::NoPrecisionLanding);
        }
        None => {
            // MAVLink over the loopback, as with PX4 SITL: the autopilot sends to the
            // runtime's port.
            let link =
                MavlinkLink::bind_local_ephemeral(LinkConfig::default()).map_err(link_error)?;
            let runtime_addr = link
                .local_addr()
                .ok_or_else(|| SimError::Link("the link has no local UDP address".into()))?;
            let autopilot = MavlinkAutopilot::bind_local(runtime_addr, !options.real_time)
                .map_err(link_error)?
                .with_stream_rates(StreamRates {
                    attitude_hz: telemetry.attitude_rate_hz,
                    position_hz: telemetry.position_rate_hz,
                    distance_hz: telemetry.distance_rate_hz,
                });
            let mut vehicle =
                Multirotor::on_ground(VehicleParams::default(), Vector3::zeros()).map_err(setup)?;
            if let Some(gimbal) = gimbal {
                vehicle = vehicle.with_gimbal(gimbal);
            }
            let estimate = EstimatedTelemetry::new(
                realism.estimator,
                realism.rangefinder,
                telemetry.latency_s,
                seed,
            );
            let flyer = Flyer::Builtin {
                vehicle: Box::new(vehicle),
                autopilot: Box::new(autopilot),
                estimate: Box::new(estimate),
            };
            (flyer, link, None)
        }
        Some(real) => {
            let gimbal = gimbal
                .map(|gimbal| CameraGimbal::for_autopilot(gimbal, real))
                .transpose()?;
            let (vehicle, process) = RealVehicle::connect(real, seed)?;
            let link = real.open_link(process.as_ref())?;
            let flyer = Flyer::Real(Box::new(GimballedVehicle::new(vehicle, gimbal)));
            (flyer, link, process)
        }
    };

    let mut plan = mission_plan(model, options.world.meeting_point_ne_m, pad_height_m);
    if options.autopilot.is_some() {
        // A real autopilot refuses to arm until its estimator has converged on the world's
        // sensors (PX4 about 16 s, ArduPilot about 42 s).
        plan.command_timeout_s = plan.command_timeout_s.max(REAL_AUTOPILOT_READY_S);
    }
    let max_time_s = options.max_time_s.unwrap_or_else(|| {
        phases_duration_s(&model.config.mission, |kind| kind != PhaseKind::Transit) + TIME_MARGIN_S
    });
    let bus = scheduler.bus().clone();
    // The camera's frames reach the runtime as a real camera's do: through a frame source.
    let frames = MemorySource::new();
    let mut events: Vec<(f64, String)> = Vec::new();
    let runner_options = RunnerOptions {
        landing_target: model.config.link.as_ref().is_some_and(|l| l.landing_target),
        fixed_levels: options.fixed_levels.clone(),
    };
    let mut runner = MissionRunner::new(
        model.clone(),
        scheduler,
        link,
        plan.clone(),
        Some(Box::new(frames.clone())),
        runner_options.clone(),
    )
    .map_err(|error| match error {
        RunnerError::FixedLevel { task, value, why } => SimError::FixedLevel { task, value, why },
        other => SimError::Setup(other.into()),
    })?;
    if let Some(record) = &options.record {
        let mut header = RecordingHeader::new(
            RecordingSource::Sim,
            seed,
            plan,
            config,
            true,
            record
                .config_files
                .first()
                .map_or_else(String::new, |f| f.path.clone()),
        );
        header.fixed_levels = runner_options.fixed_levels.clone();
        header.landing_target = runner_options.landing_target;
        header.link_peer_known = runner.link().has_peer();
        let recorder = Recorder::start(&record.recorder, &header, &record.config_files)?;
        if let Some(port) = recorder.live_port() {
            events.push((0.0, format!("serving Foxglove's WebSocket on port {port}")));
        }
        runner.record(recorder).map_err(setup)?;
    }
    // The tasks that look at camera frames: a frame is rendered only when one will.
    let camera_consumers: Vec<String> = config
        .tasks
        .iter()
        .filter(|t| registry.reads(t, CAMERA_FRAME.name()))
        .map(|t| t.name.clone())
        .collect();
    // The stereo camera flies only for a task that reads depth: the missions without one are
    // not slowed by it.
    let reads_depth = config
        .tasks
        .iter()
        .any(|t| registry.reads(t, DEPTH_FRAME.name()));
    let mut stereo = if reads_depth {
        let camera = SimStereoCamera::new(options.stereo, seed).map_err(setup)?;
        let publisher = bus.publisher::<DepthFrame>(DEPTH_FRAME).map_err(setup)?;
        Some((camera, publisher))
    } else {
        None
    };
    let mut relative_states = bus
        .subscriber::<RelativeState>(RELATIVE_STATE)
        .map_err(setup)?;
    let mut localisation = LocalisationAccumulator::default();
    let hazard_task = config
        .tasks
        .iter()
        .find(|t| t.plugin == "hazard_cnn" && registry.contains(&t.plugin))
        .map(|t| t.name.clone());
    let mut hazard_reports = bus.subscriber::<HazardReport>(HAZARDS).map_err(setup)?;
    let mut hazard_score = HazardScore::default();
    let mut hazard_backend: Option<&'static str> = None;

    let mut track = Vec::new();
    let mut qos_track = Vec::new();
    let mut landing_started_s: Option<f64> = None;
    let mut tracking_started_s: Option<f64> = None;
    let mut landing_aborts = 0u32;
    let mut last_landing_mode = None;
    let mut next_track_s = 0.0;
    let mut tick = 0u64;
    let mut finished_s = None;
    let phase_count = config.mission.phases.len();
    let phase_kinds = config.mission.phase_kinds();
    let pace_start = Instant::now();
    let mut current_phase: Option<(usize, String)> = None;
    let ticks_per_report = (1.0 / TICK_S).round().max(1.0) as u64;
    loop {
        let time_s = tick as f64 * TICK_S;
        if let Some(progress) = &options.progress {
            if tick.is_multiple_of(ticks_per_report) {
                (progress.0)(&SimProgress {
                    time_s,
                    max_time_s,
                    phase: current_phase.clone(),
                    phase_count,
                    wall_s: pace_start.elapsed().as_secs_f64(),
                });
            }
        }
        let now = Timestamp::from_nanos(MavlinkAutopilot::time_ns(time_s));
        if time_s > max_time_s {
            events.push((
                time_s,
                format!("simulation time limit of {max_time_s:.0} s reached"),
            ));
            break;
        }
        let fault_time = tracking_started_s.map(|start| time_s - start);
        let in_window = |window: Option<(f64, f64)>| matches!((window, fault_time), (Some((from, until)), Some(t)) if t >= from && t < until);
        if let Flyer::Builtin { autopilot, .. } = &mut flyer {
            autopilot.set_link_down(in_window(options.faults.link_loss));
        }

        // The runtime's clock: the world's in lockstep; the real-time scheduler's (the one its
        // tasks stamp messages with) on the wall clock.
        let runtime_now_s = if options.real_time {
            runner.scheduler().now().as_secs_f64()
        } else {
            now.as_secs_f64()
        };
        // The camera renders only what a task will look at before the next frame (in real
        // time the scheduler does not say ahead: every frame).
        if camera.is_due(time_s) {
            let wanted = options.real_time
                || camera_consumers.iter().any(|name| {
                    runner
                        .scheduler()
                        .next_activation(name)
                        .is_some_and(|next| {
                            next.as_secs_f64()
                                < time_s + camera_period_s + realism.camera.latency_max_s
                        })
                });
            if wanted {
                scene
                    .set_pad_pose(pad_pose(&world.tractor))
                    .map_err(setup)?;
                let pose = flyer.camera_pose();
                // Rendered on other threads during the frame's latency; the loop goes on.
                match camera.capture_deferred(time_s, &pose, &scene) {
                    Ok(frame) => {
                        let frame_index = frame.frame_index;
                        let c = &realism.camera;
                        let latency_s = c.latency_min_s
                            + (c.latency_max_s - c.latency_min_s) * latency_rng.next_f64();
                        // Not before the frame ahead of it: a camera delivers in order.
                        let deliver_s = in_transit
                            .back()
                            .map_or(time_s + latency_s, |(s, _, _)| s.max(time_s + latency_s));
                        in_transit.push_back((deliver_s, runtime_now_s, frame));
                        if let Some((stereo, depth_frames)) = stereo.as_mut() {
                            match stereo.capture(
                                frame_index,
                                &pose.position_ned_m,
                                &pose.attitude,
                                &scene,
                            ) {
                                Ok(depth) => {
                                    depth_frames.publish(
                                        now,
                                        DepthFrame {
                                            frame_index: depth.frame_index,
                                            image: depth.image,
                                        },
                                    );
                                }
                                Err(error) => {
                                    events.push((time_s, format!("stereo camera: {error}")))
                                }
                            }
                        }
                    }
                    Err(error) => events.push((time_s, format!("camera: {error}"))),
                }
            }
        }

        while in_transit
            .front()
            .is_some_and(|(deliver_s, _, _)| *deliver_s <= time_s + 1e-9)
        {
            if let Some((_, capture_time_s, frame)) = in_transit.pop_front() {
                match frame.wait() {
                    Ok(frame) => frames.push(CapturedFrame {
                        frame: CameraFrame {
                            vehicle_at_capture: None,
                            frame_index: frame.frame_index,
                            image: frame.image,
                        },
                        capture_time_s,
                        arrived_s: runtime_now_s,
                    }),
                    Err(error) => events.push((time_s, format!("camera: {error}"))),
                }
            }
        }

        // Autopilot → runtime → autopilot: in lockstep, or as the datagrams come. A real
        // autopilot streams on its own; the world and it are in lockstep through its
        // simulator interface.
        let lockstep = match &mut flyer {
            Flyer::Builtin {
                vehicle,
                autopilot,
                estimate,
            } => {
                let snapshot = estimate.report(&vehicle.snapshot(time_s, battery.reading()));
                let t_ns = autopilot.publish(&snapshot).map_err(link_error)?;
                (!options.real_time).then_some(t_ns)
            }
            Flyer::Real(_) => None,
        };
        let step = runner
            .step(runtime_now_s, lockstep)
            .map_err(|error| match error {
                RunnerError::Scheduler(error) => SimError::Scheduler(error),
                other => SimError::Link(other.into()),
            })?;
        if let Flyer::Builtin {
            vehicle, autopilot, ..
        } = &mut flyer
        {
            let received = match lockstep {
                Some(t_ns) => autopilot.receive_lockstep(t_ns, LOCKSTEP_TIMEOUT),
                None => autopilot.receive(),
            }
            .map_err(link_error)?;
            for received in received {
                let result = vehicle.command(received.command, time_s);
                if let Some(pending) = received.ack {
                    autopilot.ack(pending, &result).map_err(link_error)?;
                }
            }
        }

        // Where the runtime thinks the pad is, against the truth, while it tracks it.
        if tracking_started_s.is_some() && flyer.touchdown().is_none() {
            if let Some(message) = relative_states.latest() {
                let relative = &message.value;
                let fresh = runtime_now_s - relative.estimate.time_s <= LOCALISATION_MAX_AGE_S;
                let seen = relative
                    .last_fix_time_s
                    .is_some_and(|fix_s| runtime_now_s - fix_s <= LOCALISATION_MAX_FIX_GAP_S);
                if fresh && seen {
                    let pad = world.pad();
                    let truth = flyer.position_ned_m() - pad.centre_ned_m;
                    localisation.add(
                        &relative.estimate.uav_relative_ned_m,
                        &truth,
                        relative
                            .platform_velocity_ned_m_s
                            .map(|v| (v, pad.velocity_ned_m_s)),
                    );
                }
            }
        }
        if let Some(report) = hazard_reports.take_new() {
            hazard_score.add(scene.hazards(), &report.value);
            hazard_backend = Some(report.value.backend);
        }
        if let Some(setpoint) = step.landing {
            use algorithms::control::landing::LandingMode;
            if setpoint.mode == LandingMode::Reacquire
                && last_landing_mode != Some(LandingMode::Reacquire)
            {
                landing_aborts += 1;
                events.push((time_s, "landing: target lost, climbing to reacquire".into()));
            }
            last_landing_mode = Some(setpoint.mode);
        }
        for event in &step.events {
            if let MissionEvent::PhaseStarted { phase, .. } = event {
                current_phase = config
                    .mission
                    .phases
                    .get(*phase)
                    .map(|p| (*phase, p.name.clone()));
                let kind = phase_kinds.get(*phase).copied();
                if kind == Some(PhaseKind::Land) {
                    landing_started_s = Some(time_s);
                }
                if kind == Some(PhaseKind::Track) && tracking_started_s.is_none() {
                    tracking_started_s = Some(time_s);
                    if let Some((from_s, until_s)) = options.faults.camera_freeze {
                        camera.freeze(time_s + from_s, time_s + until_s);
                    }
                    if let Some((from_s, until_s)) = options.faults.camera_stall {
                        camera.drop_frames(time_s + from_s, time_s + until_s);
                    }
                }
                // The tractor drives off once the vehicle is with it.
                world.tractor_moving |= kind != Some(PhaseKind::Transit);
            }
        }
        let status = runner.status();
        if status.finished && finished_s.is_none() {
            finished_s = Some(time_s);
        }
        if let Some(done_s) = finished_s {
            // Let the vehicle settle on the pad for a moment, then stop.
            if time_s - done_s >= 1.0 {
                break;
            }
        }

        // Physics.
        match &mut flyer {
            Flyer::Builtin { vehicle, .. } => {
                world.step_tick(time_s, TICK_S, PHYSICS_DT_S, vehicle.as_mut(), |_, _| {
                    Ok::<(), SimError>(())
                })?
            }
            Flyer::Real(real) => real.step_until(&mut world, time_s + TICK_S, TICK_S)?,
        }
        let flight_w = flyer.flight_power_w(&mut world.wind, &rotors, time_s);
        // The companion draws what the tasks of the phase in flight cost at their levels.
        let companion_w = runner.companion_power_w();
        if let Err(error) = battery.drain(flight_w, companion_w, TICK_S) {
            events.push((time_s, format!("battery: {error}")));
            break;
        }
        if battery.soc() <= 0.0 {
            events.push((time_s, "battery empty: the vehicle falls".into()));
            break;
        }
        if options.record_track {
            let levels: Vec<(String, usize, f64)> = runner
                .qos_levels()
                .tasks
                .into_iter()
                .map(|(task, l)| (task, l.level, l.value))
                .collect();
            if qos_track
                .last()
                .is_none_or(|last: &QosSample| last.levels != levels)
            {
                qos_track.push(QosSample { time_s, levels });
            }
        }
        if options.record_track && time_s >= next_track_s {
            let position = flyer.position_ned_m();
            let pose = world.tractor.pose();
            track.push(TrackSample {
                time_s,
                vehicle_ne_m: [position.x, position.y],
                altitude_m: -position.z,
                tractor_ne_m: [pose.position_ne_m.x, pose.position_ne_m.y],
                battery_soc: battery.soc(),
            });
            next_track_s += 1.0;
        }
        tick += 1;
        if options.real_time {
            // The world keeps the pace of the wall clock.
            let due = pace_start + std::time::Duration::from_secs_f64(tick as f64 * TICK_S);
            std::thread::sleep(due.saturating_duration_since(Instant::now()));
        }
    }
    let end_s = tick as f64 * TICK_S;
    runner.stop();
    if let Some(summary) = runner.finish_recording().transpose()? {
        events.push((
            end_s,
            format!(
                "recorded {} messages ({:.1} MB){}",
                summary.total_messages(),
                summary.bytes as f64 / 1e6,
                summary
                    .file
                    .map_or_else(String::new, |path| format!(" to {}", path.display()))
            ),
        ));
    }
    let stats = runner.scheduler().stats();
    let failed_tasks = runner
        .scheduler()
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
        .collect();
    let log = runner.log();
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
    // The runtime's log (mission events, refused telemetry, camera faults) beside the world's.
    events.extend(log.events.iter().cloned());
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    let touchdown = flyer.touchdown();
    // How hard and how leaning: the first contact (a bounce's later ones are softer).
    let first_touchdown = flyer.first_touchdown();
    let (flight_energy_wh, companion_energy_wh) = battery.energy_wh();
    let wall_s = wall_start.elapsed().as_secs_f64();
    Ok(SimOutcome {
        seed,
        landed_on_pad: touchdown.is_some_and(|t| t.on_pad),
        touched_down: touchdown.is_some(),
        touchdown_error_m: touchdown.map(|t| t.horizontal_error_m),
        touchdown_tilt_deg: first_touchdown.map(|t| t.tilt_deg),
        touchdown_vertical_speed_m_s: first_touchdown.map(|t| t.vertical_speed_m_s),
        time_to_land_s: match (touchdown, landing_started_s) {
            (Some(t), Some(start)) => Some(t.time_s - start),
            _ => None,
        },
        mission_time_s: end_s,
        flight_energy_wh,
        companion_energy_wh,
        battery_left_fraction: battery.soc(),
        landing_aborts,
        qos_changes,
        events,
        hazards_seen: hazard_task
            .as_ref()
            .filter(|_| hazard_backend.is_some())
            .map(|_| hazard_score.seen()),
        hazards_total,
        hazard_frames: hazard_score.frames,
        hazard_false_detections: hazard_score.false_detections,
        hazard_backend: hazard_backend.map(str::to_string),
        failed_tasks,
        skipped_tasks,
        speedup: end_s / wall_s.max(1e-9),
        localisation: localisation.finish(),
        track,
        qos_track,
        loop_step_p50_us: loop_step.p50_us,
        loop_step_p99_us: loop_step.p99_us,
        capture_to_setpoint_ms: (latency.count > 0)
            .then(|| [latency.p50_us, latency.p99_us, latency.max_us].map(|us| us / 1e3)),
        capture_to_setpoint_fixes: latency.count,
        delivered_to_setpoint_ms: (delivered.count > 0)
            .then(|| [delivered.p50_us, delivered.p99_us, delivered.max_us].map(|us| us / 1e3)),
    })
}

/// The summed duration of the mission's phases whose kind `counts`.
fn phases_duration_s(mission: &Mission, counts: impl Fn(PhaseKind) -> bool) -> f64 {
    mission
        .phases
        .iter()
        .zip(mission.phase_kinds())
        .filter(|&(_, kind)| counts(kind))
        .map(|(phase, _)| phase.duration_s)
        .sum()
}
