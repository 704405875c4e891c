//! The simulated autopilot's vocabulary, shared by the vehicle model and the MAVLink autopilot
//! that speaks for it: what the autopilot can be told, and what it reports.

use algorithms::estimation::projection::Attitude;
use nalgebra::Vector3;

/// The flight modes the simulated autopilot has, after PX4's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlightMode {
    /// Holds position (PX4's Hold / Loiter); also what the failsafe falls back to.
    Hold,
    /// Climbs to the takeoff altitude above the surface it left, then holds.
    Takeoff,
    /// Follows streamed velocity setpoints (PX4's Offboard).
    Offboard,
    /// Descends at the land speed until the landed detector fires, then disarms.
    Land,
}

/// MAVLink's MAV_LANDED_STATE, as EXTENDED_SYS_STATE reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LandedState {
    OnGround,
    InAir,
    Takeoff,
    Landing,
}

/// What the autopilot can be told (decoded from MAVLink by the autopilot server).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AutopilotCommand {
    Arm,
    Disarm,
    /// Take off to this height above the surface the vehicle stands on.
    Takeoff {
        altitude_m: f64,
    },
    Land,
    SetMode(FlightMode),
    /// An offboard velocity setpoint in NED (down positive), with an optional yaw.
    VelocitySetpoint {
        velocity_ned_m_s: Vector3<f64>,
        yaw_rad: Option<f64>,
    },
}

/// Why the autopilot refused a command (MAV_RESULT_DENIED / TEMPORARILY_REJECTED).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommandRejected {
    #[error("not armed")]
    NotArmed,
    #[error("cannot {0} while in the air")]
    InAir(&'static str),
    #[error("offboard needs a velocity setpoint streaming first")]
    NoOffboardSetpoint,
    #[error("invalid command value: {0}")]
    Invalid(String),
}

/// The pack as the autopilot measures it (BATTERY_STATUS / SYS_STATUS).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryReading {
    pub voltage_v: f64,
    /// Discharge current, positive out of the pack.
    pub current_a: f64,
    pub consumed_mah: f64,
    pub remaining_fraction: f64,
}

/// Everything the autopilot reports about the vehicle at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleSnapshot {
    /// Time since the autopilot booted.
    pub time_s: f64,
    /// Local NED position relative to the home point (the take-off spot at ground level).
    pub position_ned_m: Vector3<f64>,
    pub velocity_ned_m_s: Vector3<f64>,
    pub acceleration_ned_m_s2: Vector3<f64>,
    pub attitude: Attitude,
    /// Body rates (roll, pitch, yaw rate).
    pub body_rates_rad_s: Vector3<f64>,
    pub armed: bool,
    pub mode: FlightMode,
    pub landed_state: LandedState,
    /// What the downward rangefinder measures: distance to the surface below (pad or ground)
    /// along the body's down axis; `None` outside its range.
    pub rangefinder_m: Option<f64>,
    pub battery: BatteryReading,
    /// The camera gimbal's attitude (as [`algorithms::estimation::camera_mount`] describes a
    /// camera), when the vehicle carries one; its autopilot then streams
    /// GIMBAL_DEVICE_ATTITUDE_STATUS.
    pub gimbal_attitude: Option<Attitude>,
}
