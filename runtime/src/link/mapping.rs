//! MAVLink ⇄ runtime types, without I/O.
//!
//! Inbound: ATTITUDE, LOCAL_POSITION_NED, DISTANCE_SENSOR and EXTENDED_SYS_STATE become a
//! [`VehicleState`]; BATTERY_STATUS / SYS_STATUS become [`BatteryTelemetry`]; HEARTBEAT becomes
//! an [`AutopilotStatus`]; COMMAND_ACK becomes a [`CommandAck`]. [`TelemetryState`] accumulates
//! them, because one MAVLink message carries only part of what the runtime needs.
//!
//! Acceleration comes from differencing LOCAL_POSITION_NED velocities over the autopilot's own
//! `time_boot_ms`, not from HIGHRES_IMU: HIGHRES_IMU is body-frame specific force (gravity
//! included) that would need the attitude to rotate and de-gravitate, and PX4 does not stream it
//! by default on the onboard link; the velocity difference is already NED and comes with every
//! position message.
//!
//! Outbound: [`VehicleCommand`] becomes SET_POSITION_TARGET_LOCAL_NED, COMMAND_LONG or
//! LANDING_TARGET ([`command_message`]); the mission sequencer turns the landing logic's
//! [`LandingSetpoint`](crate::topics::LandingSetpoint) into commands.
//!
//! PX4's and ArduCopter's mode numbers are the `autopilot_modes` crate's table, which the
//! simulated autopilot obeys too.

use crate::telemetry::BatteryTelemetry;
use crate::topics::VehicleState;
use algorithms::estimation::camera_mount::camera_attitude_of_gimbal;
use algorithms::estimation::pad_height::PadHeightEstimator;
use algorithms::estimation::projection::Attitude;
use autopilot_modes::{ArduCopterMode, Px4Mode};
use mavlink::dialects::common::{
    GimbalDeviceFlags, MavAutopilot, MavCmd, MavFrame, MavLandedState, MavMessage, MavModeFlag,
    MavResult, MavSensorOrientation, MavState, MavSysStatusSensor, MavType, PositionTargetTypemask,
    ATTITUDE_DATA, BATTERY_STATUS_DATA, COMMAND_LONG_DATA, DISTANCE_SENSOR_DATA,
    GIMBAL_DEVICE_ATTITUDE_STATUS_DATA, HEARTBEAT_DATA, LANDING_TARGET_DATA,
    LOCAL_POSITION_NED_DATA, SET_POSITION_TARGET_LOCAL_NED_DATA, SYS_STATUS_DATA,
};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// MAV_COMP_ID_ONBOARD_COMPUTER: the companion's component id.
pub const ONBOARD_COMPUTER_COMPONENT_ID: u8 = 191;
/// The value of an unused or unmeasured uint16 MAVLink field.
const UINT16_UNKNOWN: u16 = u16::MAX;
/// A rangefinder reading older than this no longer says where the pad is.
pub const RANGEFINDER_STALE_S: f64 = 0.5;
/// A gimbal attitude older than this is not used: a frame is not projected with where the
/// camera pointed half a second ago.
pub const GIMBAL_STALE_S: f64 = 0.5;
/// Velocity samples further apart than this are not differenced (a gap, not a rate).
const MAX_ACCELERATION_DT_S: f64 = 0.5;

/// Which autopilot firmware speaks, from HEARTBEAT.autopilot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AutopilotKind {
    Px4,
    ArduPilot,
    /// Another MAV_AUTOPILOT value; its custom modes are not decoded.
    Other(u32),
}

/// The autopilot's flight mode, in the runtime's words.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AutopilotMode {
    /// PX4 OFFBOARD or ArduPilot GUIDED: the companion's setpoints fly the vehicle.
    Offboard,
    /// PX4 AUTO.LAND or AUTO.PRECLAND, or ArduPilot LAND (precise when PLND_ENABLED).
    Land,
    /// PX4 AUTO.TAKEOFF.
    Takeoff,
    /// PX4 AUTO.LOITER or ArduPilot LOITER: holds position.
    Hold,
    /// PX4 POSCTL: the pilot flies.
    Position,
    /// Any other mode; the raw `custom_mode` says which.
    Other { custom_mode: u32 },
}

/// What one HEARTBEAT says about the autopilot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AutopilotStatus {
    pub kind: AutopilotKind,
    pub mode: AutopilotMode,
    pub armed: bool,
    pub custom_mode: u32,
    /// MAV_STATE as a number (3 standby, 4 active, 5 critical, 6 emergency).
    pub system_status: u32,
}

/// Decodes an autopilot's HEARTBEAT; `None` for heartbeats of things that are not autopilots
/// (MAV_AUTOPILOT_INVALID: ground stations, cameras, other companions).
pub fn decode_heartbeat(heartbeat: &HEARTBEAT_DATA) -> Option<AutopilotStatus> {
    let kind = match heartbeat.autopilot {
        MavAutopilot::MAV_AUTOPILOT_INVALID => return None,
        MavAutopilot::MAV_AUTOPILOT_PX4 => AutopilotKind::Px4,
        MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA => AutopilotKind::ArduPilot,
        other => AutopilotKind::Other(other as u32),
    };
    let custom_mode = heartbeat.custom_mode;
    let custom = heartbeat
        .base_mode
        .contains(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED);
    let mode = if custom {
        decode_custom_mode(kind, custom_mode)
    } else {
        AutopilotMode::Other { custom_mode }
    };
    Some(AutopilotStatus {
        kind,
        mode,
        armed: heartbeat
            .base_mode
            .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
        custom_mode,
        system_status: heartbeat.system_status as u32,
    })
}

/// The runtime's name for an autopilot's `custom_mode`.
pub fn decode_custom_mode(kind: AutopilotKind, custom_mode: u32) -> AutopilotMode {
    match kind {
        AutopilotKind::Px4 => match Px4Mode::from_custom_mode(custom_mode) {
            Some(Px4Mode::Offboard) => AutopilotMode::Offboard,
            Some(Px4Mode::Position) => AutopilotMode::Position,
            Some(Px4Mode::Land | Px4Mode::PrecisionLand) => AutopilotMode::Land,
            Some(Px4Mode::Takeoff) => AutopilotMode::Takeoff,
            Some(Px4Mode::Loiter) => AutopilotMode::Hold,
            None => AutopilotMode::Other { custom_mode },
        },
        AutopilotKind::ArduPilot => match ArduCopterMode::from_number(custom_mode) {
            Some(ArduCopterMode::Guided) => AutopilotMode::Offboard,
            Some(ArduCopterMode::Land) => AutopilotMode::Land,
            Some(ArduCopterMode::Loiter) => AutopilotMode::Hold,
            None => AutopilotMode::Other { custom_mode },
        },
        AutopilotKind::Other(_) => AutopilotMode::Other { custom_mode },
    }
}

/// The pack voltage from BATTERY_STATUS.voltages (mV per cell, UINT16_MAX where there is no
/// cell) and voltages_ext (cells 11–14, 0 where there is none). UINT16_MAX−1 in cell 0 is the
/// spec's overflow form (cell 0 = 65534 mV, cell 1 = the rest), which summing handles.
pub fn pack_voltage_from_cells(cells_mv: &[u16; 10], extension_mv: &[u16; 4]) -> Option<f64> {
    let cells = cells_mv.iter().filter(|&&cell| cell != UINT16_UNKNOWN);
    let extension = extension_mv
        .iter()
        .filter(|&&cell| cell != 0 && cell != UINT16_UNKNOWN);
    let mut total_mv = 0u32;
    let mut any = false;
    for &cell in cells.chain(extension) {
        total_mv += u32::from(cell);
        any = true;
    }
    any.then_some(f64::from(total_mv) / 1000.0)
}

/// BATTERY_STATUS → telemetry. `current_battery` −1, `current_consumed` −1 and
/// `battery_remaining` −1 mean "not measured".
pub fn battery_from_battery_status(status: &BATTERY_STATUS_DATA, time_s: f64) -> BatteryTelemetry {
    BatteryTelemetry {
        time_s,
        voltage_v: pack_voltage_from_cells(&status.voltages, &status.voltages_ext),
        current_a: current_from_centiamps(status.current_battery),
        consumed_mah: (status.current_consumed >= 0).then_some(f64::from(status.current_consumed)),
        remaining_fraction: remaining_from_percent(status.battery_remaining),
    }
}

/// SYS_STATUS → telemetry. `voltage_battery` UINT16_MAX, `current_battery` −1 and
/// `battery_remaining` −1 mean "not measured"; SYS_STATUS has no consumed charge. `None` when
/// the sensor bits say the battery monitor is present but not enabled: its fields then measure
/// nothing (ArduPilot with `BATT_MONITOR = 0` sends 0 V there). An autopilot that leaves the
/// bits empty, as some do, is taken at its fields.
pub fn battery_from_sys_status(status: &SYS_STATUS_DATA, time_s: f64) -> Option<BatteryTelemetry> {
    let battery = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_BATTERY;
    if status.onboard_control_sensors_present.contains(battery)
        && !status.onboard_control_sensors_enabled.contains(battery)
    {
        return None;
    }
    Some(BatteryTelemetry {
        time_s,
        voltage_v: (status.voltage_battery != UINT16_UNKNOWN)
            .then_some(f64::from(status.voltage_battery) / 1000.0),
        current_a: current_from_centiamps(status.current_battery),
        consumed_mah: None,
        remaining_fraction: remaining_from_percent(status.battery_remaining),
    })
}

fn current_from_centiamps(current_ca: i16) -> Option<f64> {
    // −1 cA is MAVLink's sentinel; −100 cA is PX4's own "unknown" (its −1 A scaled to cA, as
    // SIH's battery sends it). Any other negative value is a charging current.
    (current_ca != -1 && current_ca != -100).then_some(f64::from(current_ca) / 100.0)
}

fn remaining_from_percent(remaining_percent: i8) -> Option<f64> {
    (0..=100)
        .contains(&remaining_percent)
        .then_some(f64::from(remaining_percent) / 100.0)
}

/// Height above the surface under the vehicle from a downward (PITCH_270) rangefinder, tilt
/// corrected (the beam runs along the body's down axis); `None` for other orientations and
/// readings outside the sensor's own [min, max) range (out of range arrives as UINT16_MAX,
/// max+1, or, forwarded by PX4, max itself).
pub fn rangefinder_height_m(sensor: &DISTANCE_SENSOR_DATA, attitude: &Attitude) -> Option<f64> {
    if sensor.orientation != MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270 {
        return None;
    }
    let distance_cm = sensor.current_distance;
    if distance_cm == UINT16_UNKNOWN
        || distance_cm < sensor.min_distance
        || distance_cm >= sensor.max_distance
    {
        return None;
    }
    let tilt_cos = attitude.cos_tilt();
    if tilt_cos <= 0.0 {
        return None;
    }
    Some(f64::from(distance_cm) / 100.0 * tilt_cos)
}

/// EXTENDED_SYS_STATE.landed_state → on the ground; `None` when the autopilot does not know.
pub fn landed_from_state(state: MavLandedState) -> Option<bool> {
    match state {
        MavLandedState::MAV_LANDED_STATE_UNDEFINED => None,
        MavLandedState::MAV_LANDED_STATE_ON_GROUND => Some(true),
        _ => Some(false),
    }
}

/// MAV_RESULT of a COMMAND_ACK.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AckResult {
    Accepted,
    InProgress,
    TemporarilyRejected,
    Denied,
    Unsupported,
    Failed,
    /// Any other MAV_RESULT, by number.
    Other(u32),
}

impl AckResult {
    pub fn from_mav(result: MavResult) -> Self {
        match result {
            MavResult::MAV_RESULT_ACCEPTED => Self::Accepted,
            MavResult::MAV_RESULT_IN_PROGRESS => Self::InProgress,
            MavResult::MAV_RESULT_TEMPORARILY_REJECTED => Self::TemporarilyRejected,
            MavResult::MAV_RESULT_DENIED => Self::Denied,
            MavResult::MAV_RESULT_UNSUPPORTED => Self::Unsupported,
            MavResult::MAV_RESULT_FAILED => Self::Failed,
            other => Self::Other(other as u32),
        }
    }

    pub fn is_accepted(self) -> bool {
        matches!(self, Self::Accepted | Self::InProgress)
    }
}

/// The autopilot's answer to one COMMAND_LONG.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandAck {
    /// MAV_CMD id (400 arm/disarm, 22 takeoff, 21 land, 176 set mode).
    pub command_id: u32,
    pub result: AckResult,
}

/// What one message changed in a [`TelemetryState`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Applied {
    pub vehicle_state: bool,
    pub battery: bool,
    pub heartbeat: Option<AutopilotStatus>,
    pub ack: Option<CommandAck>,
}

/// The latest of everything the autopilot reported, assembled into runtime types.
#[derive(Debug, Clone, Default)]
pub struct TelemetryState {
    attitude: Option<Attitude>,
    /// The camera gimbal's attitude, with the runtime time it arrived.
    gimbal_attitude: Option<(Attitude, f64)>,
    position_ned_m: Option<Vector3<f64>>,
    velocity_ned_m_s: Option<Vector3<f64>>,
    acceleration_ned_m_s2: Vector3<f64>,
    last_position_boot_ms: Option<u32>,
    /// Tilt-corrected rangefinder height, with the runtime time it arrived.
    rangefinder: Option<(f64, f64)>,
    /// Tells the pad from the ground beside it in the rangefinder's readings.
    pad_height: PadHeightEstimator,
    landed: bool,
    battery: Option<BatteryTelemetry>,
    /// The home point's altitude above mean sea level (GLOBAL_POSITION_INT alt − relative_alt).
    home_amsl_m: Option<f64>,
    has_battery_status: bool,
    sys_status_voltage_v: Option<f64>,
    autopilot: Option<AutopilotStatus>,
}

impl TelemetryState {
    pub fn new() -> Self {
        Self::default()
    }

    /// Folds one message from the autopilot in; `now_s` is the runtime's clock.
    pub fn apply(&mut self, message: &MavMessage, now_s: f64) -> Applied {
        let mut applied = Applied::default();
        match message {
            MavMessage::HEARTBEAT(heartbeat) => {
                if let Some(status) = decode_heartbeat(heartbeat) {
                    self.autopilot = Some(status);
                    applied.heartbeat = Some(status);
                }
            }
            MavMessage::ATTITUDE(attitude) => {
                self.attitude = Some(attitude_from(attitude));
                applied.vehicle_state = self.position_ned_m.is_some();
            }
            MavMessage::GIMBAL_DEVICE_ATTITUDE_STATUS(status) => {
                // Unknown (NaN) or in the vehicle's frame before its heading is known: none.
                self.gimbal_attitude =
                    gimbal_attitude_from(status, self.attitude.as_ref()).map(|a| (a, now_s));
                applied.vehicle_state = self.attitude.is_some() && self.position_ned_m.is_some();
            }
            MavMessage::LOCAL_POSITION_NED(position) => {
                self.apply_position(position);
                applied.vehicle_state = self.attitude.is_some();
            }
            MavMessage::DISTANCE_SENSOR(sensor) => {
                let attitude = self.attitude.unwrap_or(Attitude::new(0.0, 0.0, 0.0));
                if sensor.orientation == MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270 {
                    // An out-of-range reading clears the old one: the pad may have gone.
                    self.rangefinder =
                        rangefinder_height_m(sensor, &attitude).map(|height| (height, now_s));
                    if let (Some((height_m, _)), Some(position)) =
                        (self.rangefinder, self.position_ned_m)
                    {
                        self.pad_height.update(now_s, height_m, -position.z);
                    }
                    applied.vehicle_state =
                        self.attitude.is_some() && self.position_ned_m.is_some();
                }
            }
            MavMessage::EXTENDED_SYS_STATE(state) => {
                if let Some(landed) = landed_from_state(state.landed_state) {
                    applied.vehicle_state = landed != self.landed
                        && self.attitude.is_some()
                        && self.position_ned_m.is_some();
                    self.landed = landed;
                }
            }
            MavMessage::BATTERY_STATUS(status) => {
                let mut battery = battery_from_battery_status(status, now_s);
                if battery.voltage_v.is_none() {
                    battery.voltage_v = self.sys_status_voltage_v;
                }
                self.has_battery_status = true;
                self.battery = Some(battery);
                applied.battery = true;
            }
            MavMessage::SYS_STATUS(status) => {
                let battery = battery_from_sys_status(status, now_s);
                self.sys_status_voltage_v = battery.and_then(|b| b.voltage_v);
                // BATTERY_STATUS is richer (consumed charge); SYS_STATUS speaks only without it.
                if let Some(battery) = battery.filter(|_| !self.has_battery_status) {
                    self.battery = Some(battery);
                    applied.battery = true;
                }
            }
            MavMessage::GLOBAL_POSITION_INT(global) => {
                self.home_amsl_m = Some(f64::from(global.alt - global.relative_alt) / 1000.0);
            }
            MavMessage::COMMAND_ACK(ack) => {
                applied.ack = Some(CommandAck {
                    command_id: ack.command as u32,
                    result: AckResult::from_mav(ack.result),
                });
            }
            _ => {}
        }
        applied
    }

    fn apply_position(&mut self, position: &LOCAL_POSITION_NED_DATA) {
        let velocity = Vector3::new(
            f64::from(position.vx),
            f64::from(position.vy),
            f64::from(position.vz),
        );
        if let (Some(previous), Some(previous_ms)) =
            (self.velocity_ned_m_s, self.last_position_boot_ms)
        {
            let dt_s = f64::from(position.time_boot_ms.wrapping_sub(previous_ms)) / 1000.0;
            if dt_s > 0.0 && dt_s <= MAX_ACCELERATION_DT_S {
                self.acceleration_ned_m_s2 = (velocity - previous) / dt_s;
            }
        }
        self.velocity_ned_m_s = Some(velocity);
        self.last_position_boot_ms = Some(position.time_boot_ms);
        self.position_ned_m = Some(Vector3::new(
            f64::from(position.x),
            f64::from(position.y),
            f64::from(position.z),
        ));
    }

    /// The vehicle as last reported, once both attitude and position have come in. Height is
    /// above the pad from the rangefinder ([`PadHeightEstimator`]: its latest reading, less the
    /// pad's height when the beam hit the ground beside the pad), else the latest reading when younger
    /// than [`RANGEFINDER_STALE_S`], else −z (height above the home point).
    pub fn vehicle_state(&self, now_s: f64) -> Option<VehicleState> {
        let attitude = self.attitude?;
        let position = self.position_ned_m?;
        let height_above_pad_m = self
            .pad_height
            .height_above_pad_m(-position.z)
            .or(self
                .rangefinder
                .filter(|(_, at_s)| now_s - at_s <= RANGEFINDER_STALE_S)
                .map(|(height_m, _)| height_m))
            .unwrap_or(-position.z);
        Some(VehicleState {
            attitude,
            velocity_ned_m_s: self.velocity_ned_m_s.unwrap_or_else(Vector3::zeros),
            acceleration_ned_m_s2: self.acceleration_ned_m_s2,
            height_above_pad_m,
            position_ned_m: Some(position),
            landed: self.landed,
            gimbal_attitude: self
                .gimbal_attitude
                .filter(|(_, at_s)| now_s - at_s <= GIMBAL_STALE_S)
                .map(|(attitude, _)| attitude),
            offboard: self
                .autopilot
                .is_some_and(|status| status.mode == AutopilotMode::Offboard),
        })
    }

    /// Local NED position, as last reported.
    pub fn position_ned_m(&self) -> Option<Vector3<f64>> {
        self.position_ned_m
    }

    pub fn battery(&self) -> Option<BatteryTelemetry> {
        self.battery
    }

    pub fn autopilot(&self) -> Option<AutopilotStatus> {
        self.autopilot
    }

    pub fn home_amsl_m(&self) -> Option<f64> {
        self.home_amsl_m
    }
}

/// The camera's attitude from GIMBAL_DEVICE_ATTITUDE_STATUS. Its quaternion's yaw is in the
/// earth frame or relative to the vehicle's heading, as its flags say (without either frame
/// flag, as the message's definition keeps for old gimbals: earth with YAW_LOCK, else the
/// vehicle's); a vehicle-frame yaw needs the vehicle's attitude.
fn gimbal_attitude_from(
    status: &GIMBAL_DEVICE_ATTITUDE_STATUS_DATA,
    vehicle: Option<&Attitude>,
) -> Option<Attitude> {
    let flags = status.flags;
    let earth_frame = flags.contains(GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME)
        || (!flags.contains(GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)
            && flags.contains(GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_LOCK));
    let [w, x, y, z] = status.q.map(f64::from);
    let q_earth = if earth_frame {
        [w, x, y, z]
    } else {
        let heading = UnitQuaternion::from_euler_angles(0.0, 0.0, vehicle?.yaw_rad);
        let q = heading * UnitQuaternion::new_unchecked(Quaternion::new(w, x, y, z));
        [q.w, q.i, q.j, q.k]
    };
    camera_attitude_of_gimbal(q_earth)
}

fn attitude_from(attitude: &ATTITUDE_DATA) -> Attitude {
    Attitude::new(
        f64::from(attitude.roll),
        f64::from(attitude.pitch),
        f64::from(attitude.yaw),
    )
}

/// What the runtime asks of the autopilot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum VehicleCommand {
    Arm,
    Disarm,
    /// Take off to this height above the take-off point.
    Takeoff {
        altitude_m: f64,
    },
    Land,
    /// The autopilot's own precision landing on the LANDING_TARGETs it is sent: PX4
    /// AUTO.PRECLAND (landing_target_estimator running), ArduPilot LAND (PLND_ENABLED = 1).
    PrecisionLand,
    /// PX4 OFFBOARD (ArduPilot GUIDED).
    SetOffboard,
    /// PX4 AUTO.LOITER (ArduPilot LOITER).
    SetHold,
    /// An offboard velocity setpoint, NED, with an optional yaw.
    VelocityNed {
        velocity_ned_m_s: Vector3<f64>,
        yaw_rad: Option<f64>,
    },
    /// Ask the autopilot to stream a message at an interval (MAV_CMD_SET_MESSAGE_INTERVAL; it
    /// applies to the link it arrives on).
    SetMessageInterval {
        message_id: u32,
        interval_us: i64,
    },
    /// Where the pad is, as angles off the camera's (body FRD) axis, for the autopilot's own
    /// precision landing.
    LandingTarget {
        angle_x_rad: f64,
        angle_y_rad: f64,
        distance_m: f64,
        size_x_rad: f64,
        size_y_rad: f64,
        time_usec: u64,
    },
}

impl VehicleCommand {
    /// Whether this is a streamed offboard setpoint (stopped while the link is lost).
    pub fn is_offboard_setpoint(&self) -> bool {
        matches!(self, Self::VelocityNed { .. })
    }

    /// The MAV_CMD id a COMMAND_ACK will answer with, for commands sent as COMMAND_LONG.
    pub fn command_id(&self) -> Option<u32> {
        match self {
            Self::Arm | Self::Disarm => Some(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM as u32),
            Self::Takeoff { .. } => Some(MavCmd::MAV_CMD_NAV_TAKEOFF as u32),
            Self::Land => Some(MavCmd::MAV_CMD_NAV_LAND as u32),
            Self::SetOffboard | Self::SetHold | Self::PrecisionLand => {
                Some(MavCmd::MAV_CMD_DO_SET_MODE as u32)
            }
            Self::SetMessageInterval { .. } => Some(MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL as u32),
            Self::VelocityNed { .. } | Self::LandingTarget { .. } => None,
        }
    }
}

/// Who the commands go to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandTarget {
    pub system_id: u8,
    pub component_id: u8,
    /// Decides how modes are encoded; PX4 until a heartbeat says otherwise.
    pub kind: AutopilotKind,
    /// PX4 takes off to an altitude above mean sea level: home's, when known.
    pub home_amsl_m: Option<f64>,
}

/// SET_POSITION_TARGET_LOCAL_NED type_mask for a velocity-only setpoint: position,
/// acceleration and yaw rate ignored; yaw ignored unless given.
pub fn velocity_type_mask(with_yaw: bool) -> PositionTargetTypemask {
    let mut mask = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_X_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Y_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Z_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AX_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AY_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AZ_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE;
    if !with_yaw {
        mask |= PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_IGNORE;
    }
    mask
}

/// The MAVLink message for a command. `time_boot_ms` is the companion's own clock.
pub fn command_message(
    command: &VehicleCommand,
    target: &CommandTarget,
    time_boot_ms: u32,
) -> MavMessage {
    let long = |command: MavCmd, params: [f32; 7]| {
        MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1: params[0],
            param2: params[1],
            param3: params[2],
            param4: params[3],
            param5: params[4],
            param6: params[5],
            param7: params[6],
            command,
            target_system: target.system_id,
            target_component: target.component_id,
            confirmation: 0,
        })
    };
    let custom_mode_flag = f32::from(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits());
    let set_mode = |px4: Px4Mode, arducopter: ArduCopterMode| {
        let (param2, param3) = match target.kind {
            AutopilotKind::ArduPilot => (arducopter.number() as f32, 0.0),
            _ => {
                let (main_mode, sub_mode) = px4.parts();
                (f32::from(main_mode), f32::from(sub_mode))
            }
        };
        long(
            MavCmd::MAV_CMD_DO_SET_MODE,
            [custom_mode_flag, param2, param3, 0.0, 0.0, 0.0, 0.0],
        )
    };
    match *command {
        VehicleCommand::Arm => long(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ),
        VehicleCommand::Disarm => long(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ),
        // NaN: keep current yaw and horizontal position. ArduPilot's altitude is relative to
        // home; PX4's is above mean sea level (NaN: its MIS_TAKEOFF_ALT).
        VehicleCommand::Takeoff { altitude_m } => {
            let param7 = match (target.kind, target.home_amsl_m) {
                (AutopilotKind::ArduPilot, _) => altitude_m as f32,
                (_, Some(home_m)) => (home_m + altitude_m) as f32,
                (_, None) => f32::NAN,
            };
            long(
                MavCmd::MAV_CMD_NAV_TAKEOFF,
                [0.0, 0.0, 0.0, f32::NAN, f32::NAN, f32::NAN, param7],
            )
        }
        VehicleCommand::Land => long(
            MavCmd::MAV_CMD_NAV_LAND,
            [0.0, 0.0, 0.0, f32::NAN, f32::NAN, f32::NAN, f32::NAN],
        ),
        VehicleCommand::PrecisionLand => set_mode(Px4Mode::PrecisionLand, ArduCopterMode::Land),
        VehicleCommand::SetOffboard => set_mode(Px4Mode::Offboard, ArduCopterMode::Guided),
        VehicleCommand::SetMessageInterval {
            message_id,
            interval_us,
        } => long(
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            [
                message_id as f32,
                interval_us as f32,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
        ),
        VehicleCommand::SetHold => set_mode(Px4Mode::Loiter, ArduCopterMode::Loiter),
        VehicleCommand::VelocityNed {
            velocity_ned_m_s,
            yaw_rad,
        } => MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
            time_boot_ms,
            x: 0.0,
            y: 0.0,
            z: 0.0,
            vx: velocity_ned_m_s.x as f32,
            vy: velocity_ned_m_s.y as f32,
            vz: velocity_ned_m_s.z as f32,
            afx: 0.0,
            afy: 0.0,
            afz: 0.0,
            yaw: yaw_rad.unwrap_or(0.0) as f32,
            yaw_rate: 0.0,
            type_mask: velocity_type_mask(yaw_rad.is_some()),
            target_system: target.system_id,
            target_component: target.component_id,
            coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
        }),
        VehicleCommand::LandingTarget {
            angle_x_rad,
            angle_y_rad,
            distance_m,
            size_x_rad,
            size_y_rad,
            time_usec,
        } => MavMessage::LANDING_TARGET(LANDING_TARGET_DATA {
            time_usec,
            angle_x: angle_x_rad as f32,
            angle_y: angle_y_rad as f32,
            distance: distance_m as f32,
            size_x: size_x_rad as f32,
            size_y: size_y_rad as f32,
            target_num: 0,
            frame: MavFrame::MAV_FRAME_BODY_FRD,
            ..Default::default()
        }),
    }
}

/// The companion computer's own HEARTBEAT (sent at 1 Hz so the autopilot sees it alive).
pub fn companion_heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

#[cfg(test)]
mod tests;
