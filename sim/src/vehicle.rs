//! The multirotor (Iris class) and its PX4-like autopilot behaviour: translational dynamics with
//! drag and an external (wind) force, first-order attitude tracking with tilt and thrust limits,
//! PX4's cascaded position → velocity → acceleration control, flight modes, arming rules,
//! offboard setpoint timeout, landed detection, and contact with the ground and the moving pad.
//!
//! Conventions: world NED, metres, the ground at down = 0; yaw from north towards east. The
//! vehicle's drag acts on its ground velocity (still air); the wind module supplies what moving
//! air adds (see `crate::wind`). The vehicle's centre sits on the surface when landed (no legs).

use std::f64::consts::{PI, TAU};

use algorithms::estimation::projection::Attitude;
use nalgebra::{Rotation3, Vector2, Vector3};
use thiserror::Error;

use crate::camera::VehiclePose;
use crate::flight::{
    AutopilotCommand, BatteryReading, CommandRejected, FlightMode, LandedState, VehicleSnapshot,
};
use crate::gimbal::Gimbal;
use crate::tractor::PadState;

mod dynamics;
mod params;
pub use params::{Drag, VehicleParams};

const GRAVITY_M_S2: f64 = 9.80665;
/// Integration sub-step: larger steps are split so the dynamics stay stable.
const MAX_SUBSTEP_S: f64 = 0.005;
/// Rangefinder limits.
const RANGEFINDER_MIN_M: f64 = 0.1;
const RANGEFINDER_MAX_M: f64 = 15.0;

/// A vehicle configuration or step input that cannot be used.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum VehicleError {
    #[error("vehicle {name} = {value} must be a finite number > 0")]
    NotPositive { name: &'static str, value: f64 },
    #[error("vehicle {name} = {value} must be a finite number ≥ 0")]
    Negative { name: &'static str, value: f64 },
    #[error("vehicle {name} is not finite")]
    NonFinite { name: &'static str },
    #[error("max_tilt_rad = {0} must lie in (0, 80°)")]
    Tilt(f64),
    #[error("min_thrust_fraction = {0} must lie in [0, 1) and land_detect_thrust_fraction = {1} in (0, 1)")]
    ThrustFraction(f64, f64),
    #[error("max thrust {max_thrust_n} N cannot hold the {weight_n} N vehicle at the tilt limit")]
    TooWeak { max_thrust_n: f64, weight_n: f64 },
}

/// The first contact with a surface after a flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Touchdown {
    pub time_s: f64,
    pub on_pad: bool,
    /// Vehicle centre minus pad centre, in the pad frame (x along the pad's yaw, y right); given
    /// for a miss too.
    pub offset_in_pad_frame_m: Vector2<f64>,
    /// Norm of the offset.
    pub horizontal_error_m: f64,
    /// Down-positive speed at contact.
    pub vertical_speed_m_s: f64,
    /// Horizontal speed relative to the surface touched (the pad's velocity, or the ground).
    pub relative_horizontal_speed_m_s: f64,
    /// The body's tilt from the vertical at contact: a lean at touchdown tips a vehicle over.
    pub tilt_deg: f64,
}

/// The surface a resting vehicle is attached to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Contact {
    Ground,
    /// Where on the pad it sits and its yaw relative to the pad's.
    Pad {
        offset_pad_m: Vector2<f64>,
        yaw_offset_rad: f64,
    },
}

pub(crate) fn wrap_angle(angle_rad: f64) -> f64 {
    (angle_rad + PI).rem_euclid(TAU) - PI
}

fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|c| c.is_finite())
}

/// The vehicle with its autopilot.
#[derive(Debug, Clone, PartialEq)]
pub struct Multirotor {
    params: VehicleParams,
    position_ned_m: Vector3<f64>,
    velocity_ned_m_s: Vector3<f64>,
    acceleration_ned_m_s2: Vector3<f64>,
    attitude: Attitude,
    euler_rates_rad_s: Vector3<f64>,
    thrust_n: f64,
    armed: bool,
    mode: FlightMode,
    landed: bool,
    contact: Option<Contact>,
    low_thrust_since_s: Option<f64>,
    landed_since_s: Option<f64>,
    velocity_integral_m_s2: Vector3<f64>,
    hold_target_ned_m: Vector3<f64>,
    takeoff_target_down_m: f64,
    yaw_setpoint_rad: f64,
    setpoint: Option<(Vector3<f64>, Option<f64>)>,
    setpoint_time_s: Option<f64>,
    touchdowns: Vec<Touchdown>,
    last_pad: Option<PadState>,
    time_s: f64,
    /// The camera's gimbal, when the camera hangs in one (else it is fixed to the body).
    gimbal: Option<Gimbal>,
}

impl Multirotor {
    fn at_rest(
        params: VehicleParams,
        position_ned_m: Vector3<f64>,
        yaw_rad: f64,
        contact: Contact,
        pad: Option<PadState>,
    ) -> Self {
        Self {
            params,
            position_ned_m,
            velocity_ned_m_s: pad.map_or_else(Vector3::zeros, |p| p.velocity_ned_m_s),
            acceleration_ned_m_s2: Vector3::zeros(),
            attitude: Attitude::new(0.0, 0.0, wrap_angle(yaw_rad)),
            euler_rates_rad_s: Vector3::zeros(),
            thrust_n: 0.0,
            armed: false,
            mode: FlightMode::Hold,
            landed: true,
            contact: Some(contact),
            low_thrust_since_s: None,
            landed_since_s: None,
            velocity_integral_m_s2: Vector3::zeros(),
            hold_target_ned_m: position_ned_m,
            takeoff_target_down_m: position_ned_m.z,
            yaw_setpoint_rad: wrap_angle(yaw_rad),
            setpoint: None,
            setpoint_time_s: None,
            touchdowns: Vec::new(),
            last_pad: pad,
            time_s: 0.0,
            gimbal: None,
        }
    }

    /// The vehicle with its camera on `gimbal`: it levels the camera as the vehicle flies, its
    /// autopilot reports it, and [`Self::camera_pose`] is the gimbal's.
    pub fn with_gimbal(mut self, gimbal: Gimbal) -> Self {
        self.gimbal = Some(gimbal);
        self
    }

    /// Where the camera is and points: the body's pose, or the gimbal's on a gimballed vehicle.
    pub fn camera_pose(&self) -> VehiclePose {
        let body = VehiclePose {
            position_ned_m: self.position_ned_m,
            attitude: self.attitude,
            velocity_ned_m_s: self.velocity_ned_m_s,
            body_rates_rad_s: self.body_rates_rad_s(),
        };
        self.gimbal
            .as_ref()
            .map_or(body, |gimbal| gimbal.camera_pose(&body))
    }

    /// Disarmed, landed on the ground at `position_ned_m`'s north and east (its down is ignored:
    /// the ground is at 0), yaw north.
    pub fn on_ground(
        params: VehicleParams,
        position_ned_m: Vector3<f64>,
    ) -> Result<Self, VehicleError> {
        params.validate()?;
        if !finite3(&position_ned_m) {
            return Err(VehicleError::NonFinite {
                name: "position_ned_m",
            });
        }
        let position = Vector3::new(position_ned_m.x, position_ned_m.y, 0.0);
        Ok(Self::at_rest(params, position, 0.0, Contact::Ground, None))
    }

    /// Disarmed, landed on the pad at `offset_pad_m` from its centre (pad frame), aligned with
    /// it: a mission taking off from the moving tractor.
    pub fn on_pad(
        params: VehicleParams,
        pad: &PadState,
        offset_pad_m: Vector2<f64>,
    ) -> Result<Self, VehicleError> {
        params.validate()?;
        if !pad.is_finite() {
            return Err(VehicleError::NonFinite { name: "pad" });
        }
        if !offset_pad_m.iter().all(|v| v.is_finite()) {
            return Err(VehicleError::NonFinite {
                name: "offset_pad_m",
            });
        }
        let ne = pad.from_pad_frame(offset_pad_m);
        let position = Vector3::new(ne.x, ne.y, pad.centre_ned_m.z);
        let contact = Contact::Pad {
            offset_pad_m,
            yaw_offset_rad: 0.0,
        };
        Ok(Self::at_rest(
            params,
            position,
            pad.yaw_rad,
            contact,
            Some(*pad),
        ))
    }

    pub fn params(&self) -> &VehicleParams {
        &self.params
    }
    pub fn position_ned_m(&self) -> Vector3<f64> {
        self.position_ned_m
    }
    pub fn velocity_ned_m_s(&self) -> Vector3<f64> {
        self.velocity_ned_m_s
    }
    pub fn acceleration_ned_m_s2(&self) -> Vector3<f64> {
        self.acceleration_ned_m_s2
    }
    pub fn attitude(&self) -> Attitude {
        self.attitude
    }
    /// Body rates (p, q, r) from the Euler angle rates.
    pub fn body_rates_rad_s(&self) -> Vector3<f64> {
        let (phi, theta) = (self.attitude.roll_rad, self.attitude.pitch_rad);
        let (dphi, dtheta, dpsi) = (
            self.euler_rates_rad_s.x,
            self.euler_rates_rad_s.y,
            self.euler_rates_rad_s.z,
        );
        Vector3::new(
            dphi - dpsi * theta.sin(),
            dtheta * phi.cos() + dpsi * theta.cos() * phi.sin(),
            -dtheta * phi.sin() + dpsi * theta.cos() * phi.cos(),
        )
    }
    /// Tilt of the body's z axis from the vertical.
    pub fn tilt_rad(&self) -> f64 {
        self.attitude.tilt_rad()
    }
    /// Collective thrust being produced.
    pub fn thrust_n(&self) -> f64 {
        self.thrust_n
    }
    pub fn armed(&self) -> bool {
        self.armed
    }
    pub fn mode(&self) -> FlightMode {
        self.mode
    }
    /// Whether the landed detector says landed.
    pub fn is_landed(&self) -> bool {
        self.landed
    }
    /// Whether the vehicle is off every surface.
    pub fn is_flying(&self) -> bool {
        self.contact.is_none()
    }
    /// Whether it rests on the pad (and rides with it).
    pub fn on_pad_now(&self) -> bool {
        matches!(self.contact, Some(Contact::Pad { .. }))
    }
    pub fn landed_state(&self) -> LandedState {
        if self.landed {
            LandedState::OnGround
        } else {
            match self.mode {
                FlightMode::Takeoff => LandedState::Takeoff,
                FlightMode::Land => LandedState::Landing,
                FlightMode::Hold | FlightMode::Offboard => LandedState::InAir,
            }
        }
    }
    /// Every touchdown so far, in order.
    pub fn touchdowns(&self) -> &[Touchdown] {
        &self.touchdowns
    }
    /// The most recent touchdown.
    pub fn touchdown(&self) -> Option<Touchdown> {
        self.touchdowns.last().copied()
    }

    /// What the autopilot reports at `time_s`.
    pub fn snapshot(&self, time_s: f64, battery: BatteryReading) -> VehicleSnapshot {
        VehicleSnapshot {
            time_s,
            position_ned_m: self.position_ned_m,
            velocity_ned_m_s: self.velocity_ned_m_s,
            acceleration_ned_m_s2: self.acceleration_ned_m_s2,
            attitude: self.attitude,
            body_rates_rad_s: self.body_rates_rad_s(),
            armed: self.armed,
            mode: self.mode,
            landed_state: self.landed_state(),
            rangefinder_m: self.rangefinder_m(),
            battery,
            gimbal_attitude: self
                .gimbal
                .as_ref()
                .map(|gimbal| gimbal.camera_attitude(&self.attitude)),
        }
    }

    /// The world direction of the body's down axis.
    fn body_down_ned(&self) -> Vector3<f64> {
        Rotation3::from_euler_angles(
            self.attitude.roll_rad,
            self.attitude.pitch_rad,
            self.attitude.yaw_rad,
        ) * Vector3::z()
    }

    /// Distance along the body's down axis to the pad's top or the ground, whichever is hit
    /// first; `None` outside 0.1–15 m or when pointing at the sky.
    pub fn rangefinder_m(&self) -> Option<f64> {
        range_to_surface_m(
            self.position_ned_m,
            self.body_down_ned(),
            self.last_pad.as_ref(),
        )
    }

    fn setpoint_fresh(&self, time_s: f64) -> bool {
        self.setpoint_time_s
            .is_some_and(|t| time_s - t <= self.params.offboard_timeout_s)
    }

    fn enter_hold(&mut self) {
        self.mode = FlightMode::Hold;
        self.hold_target_ned_m = self.position_ned_m;
    }

    fn start_takeoff(&mut self, altitude_m: f64) -> Result<(), CommandRejected> {
        if !(altitude_m.is_finite() && altitude_m > 0.0) {
            return Err(CommandRejected::Invalid(format!(
                "takeoff altitude {altitude_m} m must be finite and > 0"
            )));
        }
        if !self.armed {
            return Err(CommandRejected::NotArmed);
        }
        if !self.landed {
            return Err(CommandRejected::InAir("take off"));
        }
        self.mode = FlightMode::Takeoff;
        self.takeoff_target_down_m = self.position_ned_m.z - altitude_m;
        self.hold_target_ned_m = self.position_ned_m;
        Ok(())
    }

    fn start_land(&mut self) -> Result<(), CommandRejected> {
        if !self.armed {
            return Err(CommandRejected::NotArmed);
        }
        self.mode = FlightMode::Land;
        self.hold_target_ned_m = self.position_ned_m;
        Ok(())
    }

    /// Applies a command at `time_s`, with PX4's rules; on rejection nothing changes.
    pub fn command(
        &mut self,
        command: AutopilotCommand,
        time_s: f64,
    ) -> Result<(), CommandRejected> {
        if !time_s.is_finite() {
            return Err(CommandRejected::Invalid(format!(
                "command time {time_s} s is not finite"
            )));
        }
        match command {
            AutopilotCommand::Arm => {
                if !self.landed {
                    return Err(CommandRejected::InAir("arm"));
                }
                if !self.armed {
                    self.armed = true;
                    // Arming never starts a landing: a vehicle armed in Land would disarm at once.
                    if self.mode == FlightMode::Land {
                        self.enter_hold();
                    }
                    self.velocity_integral_m_s2 = Vector3::zeros();
                }
                Ok(())
            }
            AutopilotCommand::Disarm => {
                if !self.landed {
                    return Err(CommandRejected::InAir("disarm"));
                }
                self.armed = false;
                Ok(())
            }
            AutopilotCommand::Takeoff { altitude_m } => self.start_takeoff(altitude_m),
            AutopilotCommand::Land => self.start_land(),
            AutopilotCommand::SetMode(FlightMode::Hold) => {
                self.enter_hold();
                Ok(())
            }
            AutopilotCommand::SetMode(FlightMode::Takeoff) => {
                self.start_takeoff(self.params.default_takeoff_altitude_m)
            }
            AutopilotCommand::SetMode(FlightMode::Land) => self.start_land(),
            AutopilotCommand::SetMode(FlightMode::Offboard) => {
                if !self.setpoint_fresh(time_s) {
                    return Err(CommandRejected::NoOffboardSetpoint);
                }
                self.mode = FlightMode::Offboard;
                Ok(())
            }
            AutopilotCommand::VelocitySetpoint {
                velocity_ned_m_s,
                yaw_rad,
            } => {
                if !finite3(&velocity_ned_m_s) || yaw_rad.is_some_and(|y| !y.is_finite()) {
                    return Err(CommandRejected::Invalid(
                        "velocity setpoint must be finite".into(),
                    ));
                }
                self.setpoint = Some((velocity_ned_m_s, yaw_rad));
                self.setpoint_time_s = Some(time_s);
                Ok(())
            }
        }
    }

    /// Advances by `dt_s` to `time_s` (the time at the end of the step), with the wind's force
    /// and the pad's state at the end of the step. On error nothing changes.
    pub fn step(
        &mut self,
        dt_s: f64,
        time_s: f64,
        wind_force_ned_n: Vector3<f64>,
        pad: &PadState,
    ) -> Result<(), VehicleError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(VehicleError::NotPositive {
                name: "dt_s",
                value: dt_s,
            });
        }
        if !time_s.is_finite() {
            return Err(VehicleError::NonFinite { name: "time_s" });
        }
        if !finite3(&wind_force_ned_n) {
            return Err(VehicleError::NonFinite {
                name: "wind_force_ned_n",
            });
        }
        if !(pad.is_finite() && pad.half_size_m >= 0.0) {
            return Err(VehicleError::NonFinite { name: "pad" });
        }
        if self.mode == FlightMode::Offboard && !self.setpoint_fresh(time_s) {
            // PX4's offboard loss failsafe.
            self.enter_hold();
        }
        let substeps = (dt_s / MAX_SUBSTEP_S).ceil().max(1.0) as usize;
        let h = dt_s / substeps as f64;
        let previous_pad = self.last_pad.unwrap_or(*pad);
        for i in 0..substeps {
            let t = time_s - dt_s + (i + 1) as f64 * h;
            self.substep(h, t, wind_force_ned_n, pad, &previous_pad, dt_s);
        }
        self.last_pad = Some(*pad);
        self.time_s = time_s;
        if let Some(gimbal) = self.gimbal.as_mut() {
            gimbal.step(dt_s, &self.attitude);
        }
        Ok(())
    }
}

/// Distance from `position_ned_m` along `direction_ned` (a unit vector) to the pad's top or the
/// ground, whichever is hit first: a downward rangefinder's reading; `None` outside 0.1–15 m or
/// when pointing at the sky.
pub fn range_to_surface_m(
    position_ned_m: Vector3<f64>,
    direction_ned: Vector3<f64>,
    pad: Option<&PadState>,
) -> Option<f64> {
    if direction_ned.z <= 1e-6 {
        return None;
    }
    let p = position_ned_m;
    let mut range = (0.0 - p.z) / direction_ned.z;
    if let Some(pad) = pad {
        let t = (pad.centre_ned_m.z - p.z) / direction_ned.z;
        let hit = p + direction_ned * t;
        if t >= 0.0 && t < range && pad.contains_ne(hit.xy()) {
            range = t;
        }
    }
    (RANGEFINDER_MIN_M..=RANGEFINDER_MAX_M)
        .contains(&range)
        .then_some(range)
}

/// A body that moved from `previous_down_m` to `position_ned_m` in one step: the touchdown, if
/// it crossed the pad's top inside its square or reached the ground. The pad heaves: a top that
/// rose past the body since the last step still counts as crossed from above (it was above the
/// lower of the two tops).
pub(crate) fn touchdown_crossing(
    time_s: f64,
    previous_down_m: f64,
    position_ned_m: Vector3<f64>,
    velocity_ned_m_s: Vector3<f64>,
    tilt_rad: f64,
    pad: &PadState,
    previous_pad: &PadState,
) -> Option<Touchdown> {
    let pad_top = pad.centre_ned_m.z;
    let hits_pad = previous_down_m <= pad_top.max(previous_pad.centre_ned_m.z)
        && position_ned_m.z >= pad_top
        && pad.contains_ne(position_ned_m.xy());
    if !(hits_pad || position_ned_m.z >= 0.0) {
        return None;
    }
    let offset = pad.to_pad_frame(position_ned_m.xy());
    let surface_velocity = if hits_pad {
        pad.velocity_ned_m_s
    } else {
        Vector3::zeros()
    };
    Some(Touchdown {
        time_s,
        on_pad: hits_pad,
        offset_in_pad_frame_m: offset,
        horizontal_error_m: offset.norm(),
        vertical_speed_m_s: velocity_ned_m_s.z,
        relative_horizontal_speed_m_s: (velocity_ned_m_s - surface_velocity).xy().norm(),
        tilt_deg: tilt_rad.to_degrees(),
    })
}

/// Where a body resting on `contact` is, how it moves and its yaw: on the ground it stays put;
/// on the pad it rides with it, with the turn's contribution at its offset.
pub(crate) fn resting_state(
    contact: Contact,
    position_ned_m: Vector3<f64>,
    yaw_rad: f64,
    pad: &PadState,
    previous_pad: &PadState,
    pad_dt_s: f64,
) -> (Vector3<f64>, Vector3<f64>, f64) {
    match contact {
        Contact::Ground => (
            Vector3::new(position_ned_m.x, position_ned_m.y, 0.0),
            Vector3::zeros(),
            yaw_rad,
        ),
        Contact::Pad {
            offset_pad_m,
            yaw_offset_rad,
        } => {
            let ne = pad.from_pad_frame(offset_pad_m);
            let pad_yaw_rate = wrap_angle(pad.yaw_rad - previous_pad.yaw_rad) / pad_dt_s;
            let r = ne - pad.centre_ned_m.xy();
            (
                Vector3::new(ne.x, ne.y, pad.centre_ned_m.z),
                pad.velocity_ned_m_s + Vector3::new(-pad_yaw_rate * r.y, pad_yaw_rate * r.x, 0.0),
                wrap_angle(pad.yaw_rad + yaw_offset_rad),
            )
        }
    }
}

#[cfg(test)]
mod tests;
