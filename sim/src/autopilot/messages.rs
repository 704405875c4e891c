//! What goes over the link: the vehicle's snapshot as PX4's telemetry messages, and the
//! runtime's setpoints and commands decoded.

use crate::flight::{AutopilotCommand, FlightMode, LandedState, VehicleSnapshot};
use algorithms::estimation::camera_mount::gimbal_quaternion;
use algorithms::estimation::projection::Attitude;
use mavlink::dialects::common::{
    GimbalDeviceFlags, MavAutopilot, MavBatteryFunction, MavBatteryType, MavCmd, MavDistanceSensor,
    MavFrame, MavLandedState, MavMessage, MavModeFlag, MavResult, MavSensorOrientation, MavState,
    MavSysStatusSensor, MavType, MavVtolState, PositionTargetTypemask, ATTITUDE_DATA,
    BATTERY_STATUS_DATA, COMMAND_LONG_DATA, DISTANCE_SENSOR_DATA, EXTENDED_SYS_STATE_DATA,
    GIMBAL_DEVICE_ATTITUDE_STATUS_DATA, GLOBAL_POSITION_INT_DATA, HEARTBEAT_DATA,
    LOCAL_POSITION_NED_DATA, SET_POSITION_TARGET_LOCAL_NED_DATA, SYS_STATUS_DATA,
};
use nalgebra::Vector3;

use super::{flight_mode_of_px4, px4_mode_of, RANGEFINDER_MAX_CM, RANGEFINDER_MIN_CM};
use autopilot_modes::{px4_custom_mode, Px4Mode};

pub(super) fn heartbeat(snapshot: &VehicleSnapshot) -> MavMessage {
    let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        | MavModeFlag::MAV_MODE_FLAG_STABILIZE_ENABLED
        | MavModeFlag::MAV_MODE_FLAG_GUIDED_ENABLED;
    if snapshot.mode != FlightMode::Offboard {
        base_mode |= MavModeFlag::MAV_MODE_FLAG_AUTO_ENABLED;
    }
    if snapshot.armed {
        base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    }
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: px4_mode_of(snapshot.mode).custom_mode(),
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode,
        system_status: if snapshot.armed {
            MavState::MAV_STATE_ACTIVE
        } else {
            MavState::MAV_STATE_STANDBY
        },
        mavlink_version: 3,
    })
}

pub(super) fn attitude(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    MavMessage::ATTITUDE(ATTITUDE_DATA {
        time_boot_ms,
        roll: snapshot.attitude.roll_rad as f32,
        pitch: snapshot.attitude.pitch_rad as f32,
        yaw: snapshot.attitude.yaw_rad as f32,
        rollspeed: snapshot.body_rates_rad_s.x as f32,
        pitchspeed: snapshot.body_rates_rad_s.y as f32,
        yawspeed: snapshot.body_rates_rad_s.z as f32,
    })
}

/// GIMBAL_DEVICE_ATTITUDE_STATUS for the vehicle's gimbal, its quaternion in the earth frame.
pub(super) fn gimbal_attitude(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> Option<MavMessage> {
    snapshot
        .gimbal_attitude
        .map(|camera| gimbal_device_attitude_status(&camera, time_boot_ms))
}

/// GIMBAL_DEVICE_ATTITUDE_STATUS of a gimbal whose camera points as `camera` does, its
/// quaternion in the earth frame: what a MAVLink gimbal device reports.
pub fn gimbal_device_attitude_status(camera: &Attitude, time_boot_ms: u32) -> MavMessage {
    let q = gimbal_quaternion(camera).map(|c| c as f32);
    MavMessage::GIMBAL_DEVICE_ATTITUDE_STATUS(GIMBAL_DEVICE_ATTITUDE_STATUS_DATA {
        time_boot_ms,
        q,
        angular_velocity_x: f32::NAN,
        angular_velocity_y: f32::NAN,
        angular_velocity_z: f32::NAN,
        flags: GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_ROLL_LOCK
            | GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_PITCH_LOCK
            | GimbalDeviceFlags::GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME,
        delta_yaw: f32::NAN,
        delta_yaw_velocity: f32::NAN,
        ..Default::default()
    })
}

pub(super) fn local_position(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
        time_boot_ms,
        x: snapshot.position_ned_m.x as f32,
        y: snapshot.position_ned_m.y as f32,
        z: snapshot.position_ned_m.z as f32,
        vx: snapshot.velocity_ned_m_s.x as f32,
        vy: snapshot.velocity_ned_m_s.y as f32,
        vz: snapshot.velocity_ned_m_s.z as f32,
    })
}

/// The home point's altitude above mean sea level, as PX4's SIH starts (its default location).
pub const HOME_AMSL_M: f64 = 488.0;
/// The home point's latitude and longitude (degrees), SIH's default.
const HOME_LAT_LON_DEG: (f64, f64) = (47.397_742, 8.545_594);
const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// GLOBAL_POSITION_INT: the local position on a flat earth around home; PX4 gives AMSL and
/// relative altitudes in mm, which a companion needs for MAV_CMD_NAV_TAKEOFF (AMSL).
pub(super) fn global_position(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    let position = snapshot.position_ned_m;
    let (lat0, lon0) = HOME_LAT_LON_DEG;
    let lat_deg = lat0 + (position.x / EARTH_RADIUS_M).to_degrees();
    let lon_deg = lon0 + (position.y / (EARTH_RADIUS_M * lat0.to_radians().cos())).to_degrees();
    let height_m = -position.z;
    MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
        time_boot_ms,
        lat: (lat_deg * 1e7).round() as i32,
        lon: (lon_deg * 1e7).round() as i32,
        alt: ((HOME_AMSL_M + height_m) * 1000.0).round() as i32,
        relative_alt: (height_m * 1000.0).round() as i32,
        vx: (snapshot.velocity_ned_m_s.x * 100.0).round() as i16,
        vy: (snapshot.velocity_ned_m_s.y * 100.0).round() as i16,
        vz: (snapshot.velocity_ned_m_s.z * 100.0).round() as i16,
        hdg: u16::MAX,
    })
}

/// Out of range (`None`) is reported as UINT16_MAX, which the runtime reads as "no reading".
pub(super) fn distance_sensor(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    let current_distance = match snapshot.rangefinder_m {
        Some(distance_m) if distance_m.is_finite() => {
            let centimetres = (distance_m * 100.0).round();
            if (f64::from(RANGEFINDER_MIN_CM)..=f64::from(RANGEFINDER_MAX_CM))
                .contains(&centimetres)
            {
                centimetres as u16
            } else {
                u16::MAX
            }
        }
        _ => u16::MAX,
    };
    MavMessage::DISTANCE_SENSOR(DISTANCE_SENSOR_DATA {
        time_boot_ms,
        min_distance: RANGEFINDER_MIN_CM,
        max_distance: RANGEFINDER_MAX_CM,
        current_distance,
        mavtype: MavDistanceSensor::MAV_DISTANCE_SENSOR_LASER,
        id: 0,
        orientation: MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270,
        covariance: u8::MAX,
        ..Default::default()
    })
}

fn clamp_to_i16(value: f64) -> i16 {
    value
        .round()
        .clamp(f64::from(i16::MIN + 1), f64::from(i16::MAX)) as i16
}

fn remaining_percent(fraction: f64) -> i8 {
    (fraction * 100.0).round().clamp(0.0, 100.0) as i8
}

/// The simulator knows only the pack voltage, so it is reported as MAVLink says to when cells
/// are not measured: the total in cell 0, the rest UINT16_MAX (with the 65534 mV overflow form).
pub(super) fn battery_status(snapshot: &VehicleSnapshot) -> MavMessage {
    let battery = snapshot.battery;
    let mut voltages = [u16::MAX; 10];
    let total_mv = (battery.voltage_v * 1000.0)
        .round()
        .clamp(0.0, 2.0 * 65_534.0) as u32;
    if total_mv > 65_534 {
        voltages[0] = 65_534;
        voltages[1] = (total_mv - 65_534) as u16;
    } else {
        voltages[0] = total_mv as u16;
    }
    MavMessage::BATTERY_STATUS(BATTERY_STATUS_DATA {
        current_consumed: battery.consumed_mah.round().clamp(0.0, f64::from(i32::MAX)) as i32,
        energy_consumed: -1,
        temperature: i16::MAX,
        voltages,
        current_battery: clamp_to_i16(battery.current_a * 100.0),
        id: 0,
        battery_function: MavBatteryFunction::MAV_BATTERY_FUNCTION_ALL,
        mavtype: MavBatteryType::MAV_BATTERY_TYPE_LIPO,
        battery_remaining: remaining_percent(battery.remaining_fraction),
        ..Default::default()
    })
}

pub(super) fn sys_status(snapshot: &VehicleSnapshot) -> MavMessage {
    let battery = snapshot.battery;
    MavMessage::SYS_STATUS(SYS_STATUS_DATA {
        onboard_control_sensors_present: MavSysStatusSensor::empty(),
        onboard_control_sensors_enabled: MavSysStatusSensor::empty(),
        onboard_control_sensors_health: MavSysStatusSensor::empty(),
        load: 0,
        voltage_battery: (battery.voltage_v * 1000.0).round().clamp(0.0, 65_534.0) as u16,
        current_battery: clamp_to_i16(battery.current_a * 100.0),
        drop_rate_comm: 0,
        errors_comm: 0,
        errors_count1: 0,
        errors_count2: 0,
        errors_count3: 0,
        errors_count4: 0,
        battery_remaining: remaining_percent(battery.remaining_fraction),
        ..Default::default()
    })
}

pub(super) fn extended_sys_state(snapshot: &VehicleSnapshot) -> MavMessage {
    MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
        vtol_state: MavVtolState::MAV_VTOL_STATE_MC,
        landed_state: match snapshot.landed_state {
            LandedState::OnGround => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
            LandedState::InAir => MavLandedState::MAV_LANDED_STATE_IN_AIR,
            LandedState::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
            LandedState::Landing => MavLandedState::MAV_LANDED_STATE_LANDING,
        },
    })
}

/// A velocity-only setpoint in LOCAL_NED (yaw optional); anything that asks for position or
/// acceleration control is refused, as the simulator flies velocity only.
pub fn decode_velocity_setpoint(
    setpoint: &SET_POSITION_TARGET_LOCAL_NED_DATA,
) -> Result<AutopilotCommand, &'static str> {
    if setpoint.coordinate_frame != MavFrame::MAV_FRAME_LOCAL_NED {
        return Err("only MAV_FRAME_LOCAL_NED setpoints are supported");
    }
    let mask = setpoint.type_mask;
    let position_ignored = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_X_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Y_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Z_IGNORE;
    let velocity_ignored = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VX_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VY_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VZ_IGNORE;
    let acceleration_ignored = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AX_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AY_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AZ_IGNORE;
    if !mask.contains(position_ignored) {
        return Err("position setpoints are not supported (velocity only)");
    }
    if mask.intersects(velocity_ignored) {
        return Err("the velocity must be given on all three axes");
    }
    if !mask.contains(acceleration_ignored) {
        return Err("acceleration setpoints are not supported (velocity only)");
    }
    let velocity = Vector3::new(
        f64::from(setpoint.vx),
        f64::from(setpoint.vy),
        f64::from(setpoint.vz),
    );
    if !velocity.iter().all(|v| v.is_finite()) {
        return Err("the velocity is not finite");
    }
    let yaw_rad = (!mask.contains(PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_IGNORE))
        .then_some(f64::from(setpoint.yaw))
        .filter(|yaw| yaw.is_finite());
    Ok(AutopilotCommand::VelocitySetpoint {
        velocity_ned_m_s: velocity,
        yaw_rad,
    })
}

/// COMMAND_LONG → command; `Err` carries the MAV_RESULT to answer at once (an unsupported
/// command, an unknown mode, or a request needing no action).
pub fn decode_command_long(long: &COMMAND_LONG_DATA) -> Result<AutopilotCommand, MavResult> {
    match long.command {
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => {
            if long.param1 == 1.0 {
                Ok(AutopilotCommand::Arm)
            } else if long.param1 == 0.0 {
                Ok(AutopilotCommand::Disarm)
            } else {
                Err(MavResult::MAV_RESULT_DENIED)
            }
        }
        MavCmd::MAV_CMD_NAV_TAKEOFF => {
            // PX4 reads param7 as altitude above mean sea level; NaN takes MIS_TAKEOFF_ALT.
            let amsl_m = f64::from(long.param7);
            if amsl_m.is_nan() {
                Ok(AutopilotCommand::SetMode(FlightMode::Takeoff))
            } else if amsl_m.is_finite() && amsl_m > HOME_AMSL_M {
                Ok(AutopilotCommand::Takeoff {
                    altitude_m: amsl_m - HOME_AMSL_M,
                })
            } else {
                Err(MavResult::MAV_RESULT_DENIED)
            }
        }
        MavCmd::MAV_CMD_NAV_LAND => Ok(AutopilotCommand::Land),
        // Answered at once: like PX4 it accepts the request, and its fixed streams already
        // run at the rates the runtime asks for.
        MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => Err(MavResult::MAV_RESULT_ACCEPTED),
        MavCmd::MAV_CMD_DO_SET_MODE => {
            let custom_flag = f32::from(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits());
            let base_mode = long.param1;
            if !base_mode.is_finite() || (base_mode as u32) & (custom_flag as u32) == 0 {
                return Err(MavResult::MAV_RESULT_DENIED);
            }
            if !(0.0..=255.0).contains(&long.param2) || !(0.0..=255.0).contains(&long.param3) {
                return Err(MavResult::MAV_RESULT_DENIED);
            }
            let custom_mode = px4_custom_mode(long.param2 as u8, long.param3 as u8);
            Px4Mode::from_custom_mode(custom_mode)
                .and_then(flight_mode_of_px4)
                .map(AutopilotCommand::SetMode)
                .ok_or(MavResult::MAV_RESULT_DENIED)
        }
        _ => Err(MavResult::MAV_RESULT_UNSUPPORTED),
    }
}
