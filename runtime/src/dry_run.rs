//! A dry run: every configured task built from its plugin and stepped at its QoS rate in real
//! time, on synthetic inputs — rendered camera frames of the landing pad, a hovering vehicle's
//! state and battery telemetry from the pack model at the planned power — with the governor choosing the levels, for a few
//! seconds; then the per-task statistics. It shows what the tasks cost on this computer before
//! anything flies.

use crate::energy::MissionModel;
use crate::governor::Governor;
use crate::registry::PluginRegistry;
use crate::scheduler::{PhaseGate, RealTimeOptions, SchedulerBuilder, SchedulerError, TaskStats};
use crate::telemetry::{BatteryTelemetry, MissionProgress};
use crate::topics::{CameraFrame, VehicleState, CAMERA_FRAME, VEHICLE_STATE};
use algorithms::estimation::projection::Attitude;
use algorithms::vision::camera::{CameraPose, PinholeCamera};
use algorithms::vision::image::GrayImage;
use algorithms::vision::landing_marker::LandingMarkerLayout;
use algorithms::vision::render::{render, RenderOptions, Scene, Texture};
use nalgebra::Vector3;
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum DryRunError {
    #[error("unknown phase `{0}`")]
    UnknownPhase(String),
    #[error(transparent)]
    Scheduler(#[from] SchedulerError),
    #[error("governor: {0}")]
    Governor(String),
    #[error("synthetic camera: {0}")]
    Camera(String),
}

pub struct DryRunOptions {
    pub duration: Duration,
    /// The mission phase to run; default the one with the most tasks.
    pub phase: Option<String>,
}

/// What a dry run measured.
pub struct DryRunReport {
    pub phase: String,
    /// Per task, in config order: its statistics and whether it runs in the phase.
    pub tasks: Vec<(TaskStats, bool)>,
    pub frames_published: u64,
    pub telemetry_samples: u64,
    /// The governor's decisions, described.
    pub governor_events: Vec<String>,
    pub wall_s: f64,
}

pub(crate) const FRAME_PERIOD: Duration = Duration::from_millis(100);
const TELEMETRY_PERIOD: Duration = Duration::from_millis(200);

pub fn dry_run(
    model: &MissionModel,
    registry: &PluginRegistry,
    options: &DryRunOptions,
) -> Result<DryRunReport, DryRunError> {
    let config = &model.config;
    let phase_index = match &options.phase {
        Some(name) => config
            .mission
            .phases
            .iter()
            .position(|p| &p.name == name)
            .ok_or_else(|| DryRunError::UnknownPhase(name.clone()))?,
        None => (0..config.mission.phases.len())
            .max_by_key(|&i| {
                let name = &config.mission.phases[i].name;
                (
                    config.tasks.iter().filter(|t| t.runs_in(name)).count(),
                    usize::MAX - i,
                )
            })
            .unwrap_or(0),
    };
    let phase_name = config.mission.phases[phase_index].name.clone();
    let frames = synthetic_frames()?;
    let mut governor = Governor::from_mission(model, config.governor.clone().unwrap_or_default())
        .map_err(|e| DryRunError::Governor(e.to_string()))?;
    let pack = model.battery_spec(None).map_err(DryRunError::Governor)?;

    // Only the phase's tasks run, as in flight.
    let mut scheduler = SchedulerBuilder::new(registry)
        .tasks(&config.tasks)
        .phase_gate(PhaseGate::Phase(phase_name.clone()))
        .build_real_time(RealTimeOptions::default())?;
    let camera = scheduler
        .bus()
        .publisher::<CameraFrame>(CAMERA_FRAME)
        .map_err(|e| DryRunError::Camera(e.to_string()))?;
    let vehicle = scheduler
        .bus()
        .publisher::<VehicleState>(VEHICLE_STATE)
        .map_err(|e| DryRunError::Camera(e.to_string()))?;
    let hovering = hovering_vehicle();
    apply_levels(&scheduler, model, &governor)?;
    scheduler.start()?;

    let started = Instant::now();
    let (mut frames_published, mut telemetry_samples) = (0u64, 0u64);
    let mut next_frame = Duration::ZERO;
    let mut next_telemetry = Duration::ZERO;
    let (mut soc, mut consumed_mah) = (1.0_f64, 0.0_f64);
    let mut governor_events = Vec::new();
    while started.elapsed() < options.duration {
        let now = started.elapsed();
        if now >= next_frame {
            vehicle.publish(scheduler.now(), hovering);
            let image = frames[frames_published as usize % frames.len()].clone();
            camera.publish(
                scheduler.now(),
                CameraFrame {
                    frame_index: frames_published,
                    image,
                },
            );
            frames_published += 1;
            next_frame += FRAME_PERIOD;
        }
        if now >= next_telemetry {
            // The pack at the power the governor's model predicts for the levels in force.
            let power_w = governor.model_power_w(phase_index).unwrap_or(0.0);
            let current_a = pack.current_for_power_a(soc, power_w).unwrap_or(0.0);
            let dt_s = TELEMETRY_PERIOD.as_secs_f64();
            consumed_mah += current_a * dt_s / 3.6;
            soc -= current_a * dt_s / 3600.0 / pack.capacity_ah();
            let sample = BatteryTelemetry {
                time_s: now.as_secs_f64(),
                voltage_v: Some(pack.terminal_voltage_v(soc, current_a)),
                current_a: Some(current_a),
                consumed_mah: Some(consumed_mah),
                remaining_fraction: None,
            };
            let progress = MissionProgress::new(phase_index, now.as_secs_f64());
            match governor.update(&sample, progress) {
                Ok(events) => {
                    for event in events {
                        governor_events.push(event.describe(&config.tasks));
                    }
                    apply_levels(&scheduler, model, &governor)?;
                }
                Err(error) => governor_events.push(format!("telemetry refused: {error}")),
            }
            telemetry_samples += 1;
            next_telemetry += TELEMETRY_PERIOD;
        }
        let wake = next_frame.min(next_telemetry);
        std::thread::sleep(wake.saturating_sub(started.elapsed()));
    }
    let wall_s = started.elapsed().as_secs_f64();
    scheduler.stop();
    let tasks = config
        .tasks
        .iter()
        .filter_map(|task| {
            let stats = scheduler.task_stats(&task.name)?;
            Some((stats, task.runs_in(&phase_name)))
        })
        .collect();
    Ok(DryRunReport {
        phase: phase_name,
        tasks,
        frames_published,
        telemetry_samples,
        governor_events,
        wall_s,
    })
}

/// Sets each task that runs in the phase to the governor's level.
fn apply_levels(
    scheduler: &crate::scheduler::RealTimeScheduler,
    model: &MissionModel,
    governor: &Governor,
) -> Result<(), DryRunError> {
    for chosen in governor.current_levels() {
        let name = &model.config.tasks[chosen.task].name;
        if scheduler.level(name) != Some(chosen.level) {
            scheduler.set_level(name, chosen.level)?;
        }
    }
    Ok(())
}

/// The synthetic vehicle: hovering 5 m above the pad, slightly tilted.
const HOVER_HEIGHT_M: f64 = 5.0;
const HOVER_ATTITUDE_RAD: [f64; 3] = [0.04, -0.03, 0.2];

/// The synthetic vehicle's state, as its autopilot would report it.
pub(crate) fn hovering_vehicle() -> VehicleState {
    let [roll, pitch, yaw] = HOVER_ATTITUDE_RAD;
    VehicleState {
        attitude: Attitude::new(roll, pitch, yaw),
        velocity_ned_m_s: Vector3::zeros(),
        acceleration_ned_m_s2: Vector3::zeros(),
        height_above_pad_m: HOVER_HEIGHT_M,
        // The pad lies on the ground in the synthetic frames.
        position_ned_m: Some(Vector3::new(0.0, 0.0, -HOVER_HEIGHT_M)),
        landed: false,
    }
}

/// A few frames of the reference pad drifting under a camera at 5 m, rendered once up front so
/// the run measures the tasks, not the renderer.
pub(crate) fn synthetic_frames() -> Result<Vec<Arc<GrayImage>>, DryRunError> {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians())
        .map_err(|e| DryRunError::Camera(e.to_string()))?;
    let [roll, pitch, yaw] = HOVER_ATTITUDE_RAD;
    let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -HOVER_HEIGHT_M), roll, pitch, yaw);
    (0..5)
        .map(|index| {
            let mut scene = Scene::new(Texture::field(3));
            scene.patches = LandingMarkerLayout::default()
                .patches(0.1 * index as f64, -0.3 + 0.15 * index as f64, 0.0, 0.4)
                .map_err(|e| DryRunError::Camera(e.to_string()))?;
            render(&camera, &pose, &scene, &RenderOptions::default())
                .map(Arc::new)
                .map_err(|e| DryRunError::Camera(e.to_string()))
        })
        .collect()
}
