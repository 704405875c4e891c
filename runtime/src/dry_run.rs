//! A dry run: every configured task built from its plugin and stepped at its QoS rate in real
//! time by the mission runner, the same loop that flies, on synthetic inputs — rendered camera
//! frames of the landing pad through an in-memory camera source, and a hovering vehicle speaking
//! MAVLink over the loopback with battery telemetry from the pack model at the power the
//! governor's model predicts — in observe mode, holding one phase, for a few seconds; then the
//! per-task statistics. It shows what the tasks cost on this computer before anything flies.

use crate::camera::{CapturedFrame, MemorySource};
use crate::config::CameraSettings;
use crate::energy::MissionModel;
use crate::link::{LinkConfig, LinkError, MavlinkLink};
use crate::mission::{MissionPlan, MissionRunner, RunnerError, RunnerOptions};
use crate::registry::PluginRegistry;
use crate::scheduler::stats::Histogram;
use crate::scheduler::{
    DurationSummary, RealTimeOptions, SchedulerBuilder, SchedulerError, TaskStats,
};
use crate::topics::{CameraFrame, VehicleState, LANDING_SETPOINT, RELATIVE_STATE};
use algorithms::camera::{CameraError, CameraPose};
use algorithms::estimation::camera_mount;
use algorithms::estimation::projection::Attitude;
use algorithms::vision::image::GrayImage;
use algorithms::vision::landing_marker::{LandingMarkerError, LandingMarkerLayout};
use algorithms::vision::render::{render, RenderError, RenderOptions, Scene, Texture};
use mavlink::dialects::common::{
    GimbalDeviceFlags, MavAutopilot, MavLandedState, MavMessage, MavModeFlag, MavState, MavType,
    MavVtolState, ATTITUDE_DATA, BATTERY_STATUS_DATA, EXTENDED_SYS_STATE_DATA,
    GIMBAL_DEVICE_ATTITUDE_STATUS_DATA, HEARTBEAT_DATA, LOCAL_POSITION_NED_DATA,
};
use mavlink::{MavHeader, MavlinkVersion};
use nalgebra::Vector3;
use power_models::battery::BatteryError;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::Mutex;
use std::time::{Duration, Instant};

#[derive(Debug, thiserror::Error)]
pub enum DryRunError {
    #[error("unknown phase `{0}`")]
    UnknownPhase(String),
    #[error(transparent)]
    Scheduler(#[from] SchedulerError),
    #[error(transparent)]
    Runner(#[from] RunnerError),
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error("the synthetic vehicle's socket: {0}")]
    Vehicle(#[from] std::io::Error),
    #[error("battery: {0}")]
    Battery(#[source] BatteryError),
    #[error("the link has no local address for the synthetic vehicle to send to")]
    NoLinkAddress,
    #[error("synthetic camera: {0}")]
    Camera(#[source] CameraError),
    #[error("synthetic camera: {0}")]
    Pad(#[source] LandingMarkerError),
    #[error("synthetic camera: {0}")]
    Render(#[source] RenderError),
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
    /// From a frame's publication to the first landing setpoint computed from its fix (the
    /// relative state carrying that fix, then the guidance's step after it), on the bus: what
    /// the scheduler and the tasks add. Empty when no fix reached a setpoint.
    pub frame_to_setpoint: DurationSummary,
}

/// Relative states (stamp, fix capture) and setpoints (stamp) as published, in order.
#[derive(Default)]
struct ChainLog {
    relative: Vec<(f64, Option<f64>)>,
    setpoints: Vec<f64>,
}

impl ChainLog {
    /// For each frame (its stamp), the delay to the first setpoint stamped at or after the
    /// first relative state carrying its fix.
    fn frame_to_setpoint(&self, frame_stamps_s: &[f64]) -> DurationSummary {
        let mut histogram = Histogram::default();
        for &frame_s in frame_stamps_s {
            let answered = self
                .relative
                .iter()
                .find(|(_, fix_s)| fix_s.is_some_and(|f| (f - frame_s).abs() < 1e-6))
                .and_then(|&(relative_s, _)| {
                    self.setpoints.iter().find(|&&s| s >= relative_s).copied()
                });
            if let Some(setpoint_s) = answered {
                histogram.record(((setpoint_s - frame_s).max(0.0) * 1e9) as u64);
            }
        }
        histogram.summary()
    }
}

pub(crate) const FRAME_PERIOD: Duration = Duration::from_millis(100);
const TELEMETRY_PERIOD: Duration = Duration::from_millis(200);
/// The loop's period, as in flight.
const LOOP_PERIOD: Duration = Duration::from_millis(20);

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
    let frames = synthetic_frames(&config.camera_settings())?;
    let pack = model.battery_spec(None).map_err(DryRunError::Battery)?;

    let scheduler = SchedulerBuilder::new(registry)
        .tasks(&config.tasks)
        .build_real_time(RealTimeOptions::default())?;
    let chain = Arc::new(Mutex::new(ChainLog::default()));
    let bus = scheduler.bus();
    let log = chain.clone();
    bus.tap(
        RELATIVE_STATE,
        Box::new(move |m| {
            crate::scheduler::lock(&log)
                .relative
                .push((m.stamp.as_secs_f64(), m.value.last_fix_time_s))
        }),
    )
    .map_err(RunnerError::from)?;
    let log = chain.clone();
    bus.tap(
        LANDING_SETPOINT,
        Box::new(move |m| {
            crate::scheduler::lock(&log)
                .setpoints
                .push(m.stamp.as_secs_f64())
        }),
    )
    .map_err(RunnerError::from)?;
    let mut frame_stamps_s = Vec::new();
    let link = MavlinkLink::bind_local_ephemeral(LinkConfig::default())?;
    let runtime_addr = link.local_addr().ok_or(DryRunError::NoLinkAddress)?;
    let mut vehicle = SyntheticVehicle::new(runtime_addr)?;
    let camera = MemorySource::new();
    let mut plan = MissionPlan::for_mission(config);
    plan.control = false;
    plan.only_phase = Some(phase_index);
    let mut runner = MissionRunner::new(
        model.clone(),
        scheduler,
        link,
        plan,
        Some(Box::new(camera.clone())),
        RunnerOptions::default(),
    )?;

    let started = Instant::now();
    let mut next_frame = Duration::ZERO;
    let mut next_telemetry = Duration::ZERO;
    let mut frame_index = 0u64;
    let (mut soc, mut consumed_mah) = (1.0_f64, 0.0_f64);
    while started.elapsed() < options.duration {
        let now = started.elapsed();
        let now_s = runner.scheduler().now().as_secs_f64();
        if now >= next_frame {
            let image = frames[frame_index as usize % frames.len()].clone();
            camera.push(CapturedFrame {
                frame: CameraFrame {
                    vehicle_at_capture: None,
                    frame_index,
                    image,
                },
                capture_time_s: now_s,
                arrived_s: now_s,
            });
            // Published at its capture, as the runner stamps it.
            frame_stamps_s.push(crate::clock::Timestamp::from_secs_f64(now_s).as_secs_f64());
            frame_index += 1;
            next_frame += FRAME_PERIOD;
        }
        let battery = if now >= next_telemetry {
            // The pack at the power the governor's model predicts for the levels in force.
            let power_w = runner.governor().model_power_w(phase_index).unwrap_or(0.0);
            let current_a = pack.current_for_power_a(soc, power_w).unwrap_or(0.0);
            let dt_s = TELEMETRY_PERIOD.as_secs_f64();
            consumed_mah += current_a * dt_s / 3.6;
            soc -= current_a * dt_s / 3600.0 / pack.capacity_ah();
            next_telemetry += TELEMETRY_PERIOD;
            Some((
                pack.terminal_voltage_v(soc, current_a),
                current_a,
                consumed_mah,
            ))
        } else {
            None
        };
        vehicle.send(now.as_secs_f64(), battery)?;
        runner.step(now_s, None)?;
        std::thread::sleep(LOOP_PERIOD.saturating_sub(started.elapsed() - now));
    }
    let wall_s = started.elapsed().as_secs_f64();
    runner.stop();
    let stats = runner.scheduler().stats();
    let tasks = config
        .tasks
        .iter()
        .filter_map(|task| {
            let stats = stats.iter().find(|s| s.name == task.name)?.clone();
            Some((stats, task.runs_in(&phase_name)))
        })
        .collect();
    let log = runner.log();
    let frame_to_setpoint = crate::scheduler::lock(&chain).frame_to_setpoint(&frame_stamps_s);
    Ok(DryRunReport {
        phase: phase_name,
        tasks,
        frames_published: log.frames,
        telemetry_samples: log.battery.samples,
        governor_events: log.governor.iter().map(|d| d.description.clone()).collect(),
        wall_s,
        frame_to_setpoint,
    })
}

/// The dry run's vehicle: a PX4 hovering at [`HOVER_HEIGHT_M`] in position mode, speaking
/// MAVLink over the loopback as an autopilot does (system 1, component 1).
pub(crate) struct SyntheticVehicle {
    socket: UdpSocket,
    to: SocketAddr,
    sequence: u8,
    sent_heartbeat_s: Option<f64>,
}

impl SyntheticVehicle {
    pub(crate) fn new(to: SocketAddr) -> std::io::Result<Self> {
        Ok(Self {
            socket: UdpSocket::bind("127.0.0.1:0")?,
            to,
            sequence: 0,
            sent_heartbeat_s: None,
        })
    }

    /// Attitude and position every call, the heartbeat once a second, and the battery
    /// (volts, amps, mAh consumed) when given.
    pub(crate) fn send(
        &mut self,
        time_s: f64,
        battery: Option<(f64, f64, f64)>,
    ) -> std::io::Result<()> {
        let state = hovering_vehicle();
        let time_boot_ms = (time_s * 1000.0) as u32;
        if self
            .sent_heartbeat_s
            .is_none_or(|last| time_s - last >= 1.0)
        {
            self.sent_heartbeat_s = Some(time_s);
            self.message(&MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                custom_mode: autopilot_modes::Px4Mode::Position.custom_mode(),
                mavtype: MavType::MAV_TYPE_QUADROTOR,
                autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
                base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                    | MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            }))?;
            self.message(&MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
                vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
                landed_state: MavLandedState::MAV_LANDED_STATE_IN_AIR,
            }))?;
        }
        let attitude = state.attitude;
        self.message(&MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms,
            roll: attitude.roll_rad as f32,
            pitch: attitude.pitch_rad as f32,
            yaw: attitude.yaw_rad as f32,
            ..Default::default()
        }))?;
        if let Some(camera) = state.gimbal_attitude {
            let q = camera_mount::gimbal_quaternion(&camera).map(|c| c as f32);
            self.message(&MavMessage::GIMBAL_DEVICE_ATTITUDE_STATUS(
                GIMBAL_DEVICE_ATTITUDE_STATUS_DATA {
                    time_boot_ms,
                    q,
                    flags: GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME,
                    ..Default::default()
                },
            ))?;
        }
        let position = state.position_ned_m.unwrap_or_else(Vector3::zeros);
        self.message(&MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms,
            x: position.x as f32,
            y: position.y as f32,
            z: position.z as f32,
            ..Default::default()
        }))?;
        if let Some((voltage_v, current_a, consumed_mah)) = battery {
            let mut voltages = [u16::MAX; 10];
            voltages[0] = (voltage_v * 1000.0).round() as u16;
            self.message(&MavMessage::BATTERY_STATUS(BATTERY_STATUS_DATA {
                current_consumed: consumed_mah.round() as i32,
                energy_consumed: -1,
                voltages,
                current_battery: (current_a * 100.0).round() as i16,
                battery_remaining: -1,
                ..Default::default()
            }))?;
        }
        Ok(())
    }

    fn message(&mut self, message: &MavMessage) -> std::io::Result<()> {
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let mut bytes = Vec::with_capacity(64);
        mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, message)
            .map_err(std::io::Error::other)?;
        self.socket.send_to(&bytes, self.to).map(|_| ())
    }
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
        // A gimbal, for a config whose camera is on one, pointing the camera where the
        // synthetic frames were rendered from.
        gimbal_attitude: Some(Attitude::new(roll, pitch, yaw)),
        offboard: true,
    }
}

/// A few frames of the reference pad drifting under the mission's camera at 5 m, rendered once
/// up front so the run measures the tasks, not the renderer (and the tasks project them with
/// the camera that took them).
pub(crate) fn synthetic_frames(
    camera: &CameraSettings,
) -> Result<Vec<Arc<GrayImage>>, DryRunError> {
    let camera = camera.pinhole().map_err(DryRunError::Camera)?;
    let [roll, pitch, yaw] = HOVER_ATTITUDE_RAD;
    let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -HOVER_HEIGHT_M), roll, pitch, yaw);
    (0..5)
        .map(|index| {
            let mut scene = Scene::new(Texture::field(3));
            scene.patches = LandingMarkerLayout::default()
                .patches(0.1 * index as f64, -0.3 + 0.15 * index as f64, 0.0, 0.4)
                .map_err(DryRunError::Pad)?;
            render(&camera, &pose, &scene, &RenderOptions::default())
                .map(Arc::new)
                .map_err(DryRunError::Render)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_is_answered_by_the_first_setpoint_after_the_state_that_carries_its_fix() {
        let chain = ChainLog {
            // The tracker publishes at 0.105 s still on the old fix, at 0.112 s on frame 0.1's.
            relative: vec![(0.105, Some(0.0)), (0.112, Some(0.1)), (0.132, Some(0.1))],
            setpoints: vec![0.106, 0.110, 0.113, 0.133],
        };
        let latency = chain.frame_to_setpoint(&[0.1, 0.2]);
        // Frame 0.2 gave no fix: not counted.
        assert_eq!(latency.count, 1);
        assert!(
            (latency.p50_us - 13_000.0).abs() < 13_000.0 * 0.016,
            "{latency:?}"
        );
    }
}
