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

const GRAVITY_M_S2: f64 = 9.80665;
/// Integration sub-step: larger steps are split so the dynamics stay stable.
const MAX_SUBSTEP_S: f64 = 0.005;
/// Rangefinder limits.
const RANGEFINDER_MIN_M: f64 = 0.1;
const RANGEFINDER_MAX_M: f64 = 15.0;
/// An offboard setpoint climbing faster than this lifts a landed vehicle off (PX4 takes off in
/// offboard when the setpoint asks to climb).
const OFFBOARD_TAKEOFF_CLIMB_M_S: f64 = 0.2;
/// Takeoff is complete within this distance of the target altitude.
const TAKEOFF_DONE_M: f64 = 0.1;
/// Integrator bound (acceleration), a backstop behind the anti-windup.
const MAX_INTEGRAL_M_S2: f64 = 8.0;

/// Vehicle and autopilot parameters; PX4 names in brackets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleParams {
    pub mass_kg: f64,
    pub max_thrust_n: f64,
    /// Idle thrust as a fraction of the maximum [MPC_THR_MIN].
    pub min_thrust_fraction: f64,
    /// [MPC_TILTMAX_AIR]
    pub max_tilt_rad: f64,
    /// Roll and pitch follow their commands as first-order lags with this time constant.
    pub attitude_time_constant_s: f64,
    pub yaw_time_constant_s: f64,
    /// [MPC_YAWRAUTO_MAX]
    pub max_yaw_rate_rad_s: f64,
    /// Horizontal drag −(c1 + c2·|v_h|)·v_h; the quadratic term is the seed's wind coefficient.
    pub drag_linear_horizontal_n_s_per_m: f64,
    pub drag_quadratic_horizontal_n_s2_per_m2: f64,
    pub drag_linear_vertical_n_s_per_m: f64,
    pub drag_quadratic_vertical_n_s2_per_m2: f64,
    /// [MPC_XY_VEL_MAX]
    pub max_horizontal_speed_m_s: f64,
    /// [MPC_XY_CRUISE]: the speed limit of position holding.
    pub hold_max_horizontal_speed_m_s: f64,
    /// [MPC_Z_VEL_MAX_UP]
    pub max_climb_speed_m_s: f64,
    /// [MPC_Z_VEL_MAX_DN]
    pub max_descent_speed_m_s: f64,
    /// [MPC_XY_P], [MPC_Z_P]
    pub position_gain_horizontal_per_s: f64,
    pub position_gain_vertical_per_s: f64,
    /// [MPC_XY_VEL_P_ACC], [MPC_XY_VEL_I_ACC]
    pub velocity_p_horizontal_per_s: f64,
    pub velocity_i_horizontal_per_s2: f64,
    /// [MPC_Z_VEL_P_ACC], [MPC_Z_VEL_I_ACC]
    pub velocity_p_vertical_per_s: f64,
    pub velocity_i_vertical_per_s2: f64,
    /// [MPC_LAND_SPEED]
    pub land_speed_m_s: f64,
    /// [MPC_TKO_SPEED]
    pub takeoff_speed_m_s: f64,
    /// [MIS_TAKEOFF_ALT]: used by `SetMode(Takeoff)`.
    pub default_takeoff_altitude_m: f64,
    /// [COM_OF_LOSS_T]: without a fresh setpoint for this long, offboard fails safe to Hold.
    pub offboard_timeout_s: f64,
    /// Landed detector: on a surface with the commanded thrust below this fraction of hover
    /// thrust [LNDMC_LOW_T_THR, relative]...
    pub land_detect_thrust_fraction: f64,
    /// ... and a vertical speed relative to the surface below this [LNDMC_Z_VEL_MAX] ...
    pub land_detect_max_vertical_speed_m_s: f64,
    /// ... for this long [LNDMC_TRIG_TIME].
    pub land_detect_time_s: f64,
    /// In Land mode, disarm this long after landing is detected [COM_DISARM_LAND].
    pub land_disarm_delay_s: f64,
}

impl Default for VehicleParams {
    fn default() -> Self {
        let mass_kg = 1.5;
        Self {
            mass_kg,
            max_thrust_n: 2.0 * mass_kg * GRAVITY_M_S2,
            min_thrust_fraction: 0.1,
            max_tilt_rad: 45f64.to_radians(),
            attitude_time_constant_s: 0.1,
            yaw_time_constant_s: 0.3,
            max_yaw_rate_rad_s: 45f64.to_radians(),
            drag_linear_horizontal_n_s_per_m: 0.1,
            drag_quadratic_horizontal_n_s2_per_m2: crate::wind::SEED_FORCE_COEFFICIENT_N_S2_PER_M2,
            drag_linear_vertical_n_s_per_m: 0.2,
            drag_quadratic_vertical_n_s2_per_m2: 0.1,
            max_horizontal_speed_m_s: 12.0,
            hold_max_horizontal_speed_m_s: 5.0,
            max_climb_speed_m_s: 3.0,
            max_descent_speed_m_s: 2.0,
            position_gain_horizontal_per_s: 0.95,
            position_gain_vertical_per_s: 1.0,
            velocity_p_horizontal_per_s: 1.8,
            velocity_i_horizontal_per_s2: 0.4,
            velocity_p_vertical_per_s: 4.0,
            velocity_i_vertical_per_s2: 2.0,
            land_speed_m_s: 0.7,
            takeoff_speed_m_s: 1.5,
            default_takeoff_altitude_m: 2.5,
            offboard_timeout_s: 0.5,
            land_detect_thrust_fraction: 0.6,
            land_detect_max_vertical_speed_m_s: 0.25,
            land_detect_time_s: 0.5,
            land_disarm_delay_s: 1.0,
        }
    }
}

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

impl VehicleParams {
    pub fn validate(&self) -> Result<(), VehicleError> {
        for (name, value) in [
            ("mass_kg", self.mass_kg),
            ("max_thrust_n", self.max_thrust_n),
            ("attitude_time_constant_s", self.attitude_time_constant_s),
            ("yaw_time_constant_s", self.yaw_time_constant_s),
            ("max_yaw_rate_rad_s", self.max_yaw_rate_rad_s),
            ("max_horizontal_speed_m_s", self.max_horizontal_speed_m_s),
            (
                "hold_max_horizontal_speed_m_s",
                self.hold_max_horizontal_speed_m_s,
            ),
            ("max_climb_speed_m_s", self.max_climb_speed_m_s),
            ("max_descent_speed_m_s", self.max_descent_speed_m_s),
            (
                "position_gain_horizontal_per_s",
                self.position_gain_horizontal_per_s,
            ),
            (
                "position_gain_vertical_per_s",
                self.position_gain_vertical_per_s,
            ),
            (
                "velocity_p_horizontal_per_s",
                self.velocity_p_horizontal_per_s,
            ),
            ("velocity_p_vertical_per_s", self.velocity_p_vertical_per_s),
            ("land_speed_m_s", self.land_speed_m_s),
            ("takeoff_speed_m_s", self.takeoff_speed_m_s),
            (
                "default_takeoff_altitude_m",
                self.default_takeoff_altitude_m,
            ),
            ("offboard_timeout_s", self.offboard_timeout_s),
            (
                "land_detect_max_vertical_speed_m_s",
                self.land_detect_max_vertical_speed_m_s,
            ),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(VehicleError::NotPositive { name, value });
            }
        }
        for (name, value) in [
            (
                "drag_linear_horizontal_n_s_per_m",
                self.drag_linear_horizontal_n_s_per_m,
            ),
            (
                "drag_quadratic_horizontal_n_s2_per_m2",
                self.drag_quadratic_horizontal_n_s2_per_m2,
            ),
            (
                "drag_linear_vertical_n_s_per_m",
                self.drag_linear_vertical_n_s_per_m,
            ),
            (
                "drag_quadratic_vertical_n_s2_per_m2",
                self.drag_quadratic_vertical_n_s2_per_m2,
            ),
            (
                "velocity_i_horizontal_per_s2",
                self.velocity_i_horizontal_per_s2,
            ),
            (
                "velocity_i_vertical_per_s2",
                self.velocity_i_vertical_per_s2,
            ),
            ("land_detect_time_s", self.land_detect_time_s),
            ("land_disarm_delay_s", self.land_disarm_delay_s),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(VehicleError::Negative { name, value });
            }
        }
        if !(self.max_tilt_rad > 0.0 && self.max_tilt_rad < 80f64.to_radians()) {
            return Err(VehicleError::Tilt(self.max_tilt_rad));
        }
        if !((0.0..1.0).contains(&self.min_thrust_fraction)
            && self.land_detect_thrust_fraction > 0.0
            && self.land_detect_thrust_fraction < 1.0)
        {
            return Err(VehicleError::ThrustFraction(
                self.min_thrust_fraction,
                self.land_detect_thrust_fraction,
            ));
        }
        let weight_n = self.mass_kg * GRAVITY_M_S2;
        if self.max_thrust_n * self.max_tilt_rad.cos() <= weight_n {
            return Err(VehicleError::TooWeak {
                max_thrust_n: self.max_thrust_n,
                weight_n,
            });
        }
        Ok(())
    }

    fn hover_thrust_n(&self) -> f64 {
        self.mass_kg * GRAVITY_M_S2
    }
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
enum Contact {
    Ground,
    /// Where on the pad it sits and its yaw relative to the pad's.
    Pad {
        offset_pad_m: Vector2<f64>,
        yaw_offset_rad: f64,
    },
}

fn wrap_angle(angle_rad: f64) -> f64 {
    (angle_rad + PI).rem_euclid(TAU) - PI
}

fn clamp_norm(v: Vector2<f64>, max_norm: f64) -> Vector2<f64> {
    let norm = v.norm();
    if norm > max_norm {
        v * (max_norm / norm)
    } else {
        v
    }
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
        let down = self.body_down_ned();
        if down.z <= 1e-6 {
            return None;
        }
        let p = self.position_ned_m;
        let mut range = (0.0 - p.z) / down.z;
        if let Some(pad) = &self.last_pad {
            let t = (pad.centre_ned_m.z - p.z) / down.z;
            let hit = p + down * t;
            if t >= 0.0 && t < range && pad.contains_ne(hit.xy()) {
                range = t;
            }
        }
        (RANGEFINDER_MIN_M..=RANGEFINDER_MAX_M)
            .contains(&range)
            .then_some(range)
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

    /// The velocity setpoint the current mode asks for, and the yaw setpoint.
    fn velocity_setpoint(&mut self) -> Vector3<f64> {
        let p = self.params;
        let pos = self.position_ned_m;
        let hold_xy = |target: Vector3<f64>| {
            clamp_norm(
                (target.xy() - pos.xy()) * p.position_gain_horizontal_per_s,
                p.hold_max_horizontal_speed_m_s,
            )
        };
        let vertical_to = |target_down_m: f64, up_limit: f64| {
            ((target_down_m - pos.z) * p.position_gain_vertical_per_s)
                .clamp(-up_limit, p.max_descent_speed_m_s)
        };
        match self.mode {
            FlightMode::Hold => {
                let xy = hold_xy(self.hold_target_ned_m);
                let z = vertical_to(self.hold_target_ned_m.z, p.max_climb_speed_m_s);
                Vector3::new(xy.x, xy.y, z)
            }
            FlightMode::Takeoff => {
                if (pos.z - self.takeoff_target_down_m).abs() < TAKEOFF_DONE_M {
                    // Done: PX4 switches to Hold (Loiter) at the takeoff altitude.
                    self.mode = FlightMode::Hold;
                    self.hold_target_ned_m.z = self.takeoff_target_down_m;
                    let xy = hold_xy(self.hold_target_ned_m);
                    let z = vertical_to(self.hold_target_ned_m.z, p.max_climb_speed_m_s);
                    return Vector3::new(xy.x, xy.y, z);
                }
                let xy = hold_xy(self.hold_target_ned_m);
                let z = vertical_to(self.takeoff_target_down_m, p.takeoff_speed_m_s);
                Vector3::new(xy.x, xy.y, z)
            }
            FlightMode::Land => {
                let xy = hold_xy(self.hold_target_ned_m);
                Vector3::new(xy.x, xy.y, p.land_speed_m_s)
            }
            FlightMode::Offboard => {
                let (v, yaw) = self.setpoint.unwrap_or((Vector3::zeros(), None));
                if let Some(yaw) = yaw {
                    self.yaw_setpoint_rad = wrap_angle(yaw);
                }
                let xy = clamp_norm(v.xy(), p.max_horizontal_speed_m_s);
                Vector3::new(
                    xy.x,
                    xy.y,
                    v.z.clamp(-p.max_climb_speed_m_s, p.max_descent_speed_m_s),
                )
            }
        }
    }

    /// PX4's velocity PI with anti-windup → thrust vector (NED), tilt and thrust limited with
    /// the vertical component first.
    fn thrust_vector(&mut self, v_sp: Vector3<f64>, h: f64) -> Vector3<f64> {
        let p = self.params;
        let m = p.mass_kg;
        let error = v_sp - self.velocity_ned_m_s;
        let gains = Vector3::new(
            p.velocity_p_horizontal_per_s,
            p.velocity_p_horizontal_per_s,
            p.velocity_p_vertical_per_s,
        );
        let i_gains = Vector3::new(
            p.velocity_i_horizontal_per_s2,
            p.velocity_i_horizontal_per_s2,
            p.velocity_i_vertical_per_s2,
        );
        let acc_sp = gains.component_mul(&error) + self.velocity_integral_m_s2;

        // Vertical first: upward thrust between idle and maximum.
        let min_thrust = p.min_thrust_fraction * p.max_thrust_n;
        let up_n = (m * (GRAVITY_M_S2 - acc_sp.z)).clamp(min_thrust, p.max_thrust_n);
        // Horizontal within the tilt limit and what thrust is left.
        let room = (p.max_thrust_n * p.max_thrust_n - up_n * up_n)
            .max(0.0)
            .sqrt();
        let horizontal_n = clamp_norm(acc_sp.xy() * m, (up_n * p.max_tilt_rad.tan()).min(room));
        let thrust = Vector3::new(horizontal_n.x, horizontal_n.y, -up_n);

        // Anti-windup (PX4): integrate the error as if the limited acceleration had been asked.
        let acc_lim = Vector3::new(
            horizontal_n.x / m,
            horizontal_n.y / m,
            GRAVITY_M_S2 - up_n / m,
        );
        let error_lim = error + (acc_lim - acc_sp).component_div(&gains);
        self.velocity_integral_m_s2 += i_gains.component_mul(&error_lim) * h;
        self.velocity_integral_m_s2 = self
            .velocity_integral_m_s2
            .map(|c| c.clamp(-MAX_INTEGRAL_M_S2, MAX_INTEGRAL_M_S2));
        thrust
    }

    fn drag_n(&self) -> Vector3<f64> {
        let p = &self.params;
        let v = self.velocity_ned_m_s;
        let vh = v.xy();
        let horizontal = -vh
            * (p.drag_linear_horizontal_n_s_per_m
                + p.drag_quadratic_horizontal_n_s2_per_m2 * vh.norm());
        let vertical = -v.z
            * (p.drag_linear_vertical_n_s_per_m
                + p.drag_quadratic_vertical_n_s2_per_m2 * v.z.abs());
        Vector3::new(horizontal.x, horizontal.y, vertical)
    }

    #[allow(clippy::too_many_arguments)]
    fn substep(
        &mut self,
        h: f64,
        time_s: f64,
        wind_force_ned_n: Vector3<f64>,
        pad: &PadState,
        previous_pad: &PadState,
        pad_dt_s: f64,
    ) {
        let p = self.params;
        let v_sp = self.velocity_setpoint();
        let wants_to_fly = match self.mode {
            FlightMode::Takeoff => true,
            FlightMode::Offboard => v_sp.z < -OFFBOARD_TAKEOFF_CLIMB_M_S,
            FlightMode::Hold | FlightMode::Land => false,
        };
        // A landed vehicle idles (PX4 keeps the motors at idle until a takeoff is asked).
        let idle = !self.armed || (self.landed && !wants_to_fly);
        let (thrust_vector, roll_cmd, pitch_cmd) = if idle {
            self.velocity_integral_m_s2 = Vector3::zeros();
            self.yaw_setpoint_rad = self.attitude.yaw_rad;
            let idle_n = if self.armed {
                p.min_thrust_fraction * p.max_thrust_n
            } else {
                0.0
            };
            (Vector3::new(0.0, 0.0, -idle_n), 0.0, 0.0)
        } else {
            let f = self.thrust_vector(v_sp, h);
            // Roll and pitch (ZYX) that point the body's −z along f at the current yaw.
            let z_body = -f / f.norm().max(1e-9);
            let psi = self.attitude.yaw_rad;
            let in_yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), -psi) * z_body;
            let roll = (-in_yaw.y).clamp(-1.0, 1.0).asin();
            let pitch = in_yaw.x.atan2(in_yaw.z);
            (f, roll, pitch)
        };
        let thrust_magnitude_n = thrust_vector.norm();

        // Attitude: exact first-order lag for roll and pitch (a convex combination, so the tilt
        // never leaves the convex tilt-limited set), rate-limited yaw.
        let previous = self.attitude;
        let blend = 1.0 - (-h / p.attitude_time_constant_s).exp();
        let mut roll = previous.roll_rad + (roll_cmd - previous.roll_rad) * blend;
        let mut pitch = previous.pitch_rad + (pitch_cmd - previous.pitch_rad) * blend;
        let yaw_rate = (wrap_angle(self.yaw_setpoint_rad - previous.yaw_rad)
            / p.yaw_time_constant_s)
            .clamp(-p.max_yaw_rate_rad_s, p.max_yaw_rate_rad_s);
        let mut yaw = wrap_angle(previous.yaw_rad + yaw_rate * h);

        // Forces with the new attitude: thrust along the body's −z, gravity, drag, wind.
        self.attitude = Attitude::new(roll, pitch, yaw);
        self.thrust_n = thrust_magnitude_n;
        let thrust_ned = -self.body_down_ned() * thrust_magnitude_n;
        let force = thrust_ned
            + Vector3::new(0.0, 0.0, p.mass_kg * GRAVITY_M_S2)
            + self.drag_n()
            + wind_force_ned_n;
        let previous_velocity = self.velocity_ned_m_s;

        // Resting on a surface: the surface holds the vehicle until the net force lifts it.
        if let Some(contact) = self.contact {
            if force.z < 0.0 {
                self.contact = None;
                self.landed = false;
                self.low_thrust_since_s = None;
                self.landed_since_s = None;
            } else {
                roll = 0.0;
                pitch = 0.0;
                match contact {
                    Contact::Ground => {
                        self.position_ned_m.z = 0.0;
                        self.velocity_ned_m_s = Vector3::zeros();
                    }
                    Contact::Pad {
                        offset_pad_m,
                        yaw_offset_rad,
                    } => {
                        let ne = pad.from_pad_frame(offset_pad_m);
                        self.position_ned_m = Vector3::new(ne.x, ne.y, pad.centre_ned_m.z);
                        // Pad velocity plus the turn's contribution at the offset.
                        let pad_yaw_rate =
                            wrap_angle(pad.yaw_rad - previous_pad.yaw_rad) / pad_dt_s;
                        let r = ne - pad.centre_ned_m.xy();
                        self.velocity_ned_m_s = pad.velocity_ned_m_s
                            + Vector3::new(-pad_yaw_rate * r.y, pad_yaw_rate * r.x, 0.0);
                        yaw = wrap_angle(pad.yaw_rad + yaw_offset_rad);
                    }
                }
                self.attitude = Attitude::new(roll, pitch, yaw);
                self.acceleration_ned_m_s2 = (self.velocity_ned_m_s - previous_velocity) / h;
                self.euler_rates_rad_s = Vector3::new(
                    (roll - previous.roll_rad) / h,
                    (pitch - previous.pitch_rad) / h,
                    wrap_angle(yaw - previous.yaw_rad) / h,
                );
                self.detect_landing(time_s, thrust_magnitude_n, 0.0);
                return;
            }
        }

        // Free flight: semi-implicit Euler.
        let acceleration = force / p.mass_kg;
        let previous_down = self.position_ned_m.z;
        self.velocity_ned_m_s += acceleration * h;
        self.position_ned_m += self.velocity_ned_m_s * h;
        self.acceleration_ned_m_s2 = acceleration;
        self.euler_rates_rad_s = Vector3::new(
            (roll - previous.roll_rad) / h,
            (pitch - previous.pitch_rad) / h,
            wrap_angle(yaw - previous.yaw_rad) / h,
        );

        // Touchdown: crossing the pad's top inside its square, or reaching the ground.
        // The pad heaves: a top that rose past the vehicle since the last step still counts as
        // crossed from above (it was above the lower of the two tops).
        let pad_top = pad.centre_ned_m.z;
        let hits_pad = previous_down <= pad_top.max(previous_pad.centre_ned_m.z)
            && self.position_ned_m.z >= pad_top
            && pad.contains_ne(self.position_ned_m.xy());
        let hits_ground = self.position_ned_m.z >= 0.0;
        if hits_pad || hits_ground {
            let offset = pad.to_pad_frame(self.position_ned_m.xy());
            let surface_velocity = if hits_pad {
                pad.velocity_ned_m_s
            } else {
                Vector3::zeros()
            };
            let vertical_speed = self.velocity_ned_m_s.z;
            self.touchdowns.push(Touchdown {
                time_s,
                on_pad: hits_pad,
                offset_in_pad_frame_m: offset,
                horizontal_error_m: offset.norm(),
                vertical_speed_m_s: vertical_speed,
                relative_horizontal_speed_m_s: (self.velocity_ned_m_s - surface_velocity)
                    .xy()
                    .norm(),
                tilt_deg: self.tilt_rad().to_degrees(),
            });
            if hits_pad {
                self.contact = Some(Contact::Pad {
                    offset_pad_m: offset,
                    yaw_offset_rad: wrap_angle(yaw - pad.yaw_rad),
                });
                self.position_ned_m.z = pad_top;
            } else {
                self.contact = Some(Contact::Ground);
                self.position_ned_m.z = 0.0;
            }
            self.velocity_ned_m_s = surface_velocity;
            self.detect_landing(time_s, thrust_magnitude_n, vertical_speed);
        }
    }

    /// PX4-like landed detector: on a surface, small vertical speed relative to it, low thrust,
    /// all for a while; in Land mode it then disarms after the delay.
    fn detect_landing(&mut self, time_s: f64, thrust_n: f64, relative_vertical_speed_m_s: f64) {
        let p = self.params;
        let low_thrust = thrust_n < p.land_detect_thrust_fraction * p.hover_thrust_n();
        let slow = relative_vertical_speed_m_s.abs() < p.land_detect_max_vertical_speed_m_s;
        if !self.landed {
            if self.contact.is_some() && low_thrust && slow {
                let since = *self.low_thrust_since_s.get_or_insert(time_s);
                if time_s - since >= p.land_detect_time_s {
                    self.landed = true;
                    self.landed_since_s = Some(time_s);
                    self.velocity_integral_m_s2 = Vector3::zeros();
                }
            } else {
                self.low_thrust_since_s = None;
            }
        }
        if self.landed && self.armed && self.mode == FlightMode::Land {
            let since = *self.landed_since_s.get_or_insert(time_s);
            if time_s - since >= p.land_disarm_delay_s {
                self.armed = false;
                self.enter_hold();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 0.005;

    fn far_pad() -> PadState {
        PadState {
            centre_ned_m: Vector3::new(1000.0, 1000.0, -1.0),
            yaw_rad: 0.0,
            velocity_ned_m_s: Vector3::zeros(),
            half_size_m: 0.5,
        }
    }

    fn battery() -> BatteryReading {
        BatteryReading {
            voltage_v: 16.0,
            current_a: 10.0,
            consumed_mah: 0.0,
            remaining_fraction: 1.0,
        }
    }

    struct Run {
        v: Multirotor,
        t: f64,
    }

    impl Run {
        fn new() -> Self {
            Self {
                v: Multirotor::on_ground(VehicleParams::default(), Vector3::zeros()).unwrap(),
                t: 0.0,
            }
        }
        fn step(&mut self, force: Vector3<f64>, pad: &PadState) {
            self.t += DT;
            self.v.step(DT, self.t, force, pad).unwrap();
        }
        fn run(&mut self, seconds: f64) {
            for _ in 0..(seconds / DT).round() as usize {
                self.step(Vector3::zeros(), &far_pad());
            }
        }
        fn cmd(&mut self, c: AutopilotCommand) -> Result<(), CommandRejected> {
            self.v.command(c, self.t)
        }
        /// Armed and holding at `altitude_m`.
        fn airborne(altitude_m: f64) -> Self {
            let mut r = Self::new();
            r.cmd(AutopilotCommand::Arm).unwrap();
            r.cmd(AutopilotCommand::Takeoff { altitude_m }).unwrap();
            r.run(altitude_m / 1.5 + 10.0);
            r
        }
        /// Airborne and in Offboard, streaming a zero velocity setpoint.
        fn offboard(altitude_m: f64) -> Self {
            let mut r = Self::airborne(altitude_m);
            r.stream(Vector3::zeros());
            r.cmd(AutopilotCommand::SetMode(FlightMode::Offboard))
                .unwrap();
            r
        }
        fn stream(&mut self, v: Vector3<f64>) {
            self.cmd(AutopilotCommand::VelocitySetpoint {
                velocity_ned_m_s: v,
                yaw_rad: None,
            })
            .unwrap();
        }
    }

    /// A vehicle holding its place against a steady 8 N of wind leans into it; the camera in
    /// its gimbal stays level on the heading, and the snapshot reports where it points.
    #[test]
    fn a_gimballed_camera_stays_level_while_the_vehicle_leans() {
        let mut r = Run::airborne(10.0);
        r.v =
            r.v.with_gimbal(Gimbal::new(crate::gimbal::GimbalParams::default()).unwrap());
        for _ in 0..(10.0 / DT) as usize {
            r.step(Vector3::new(0.0, 8.0, 0.0), &far_pad());
        }
        assert!(r.v.tilt_rad() > 20f64.to_radians(), "{:?}", r.v.attitude());
        let camera = r.v.camera_pose();
        assert!(camera.attitude.roll_rad.abs() < 1e-3, "{camera:?}");
        assert!(camera.attitude.pitch_rad.abs() < 1e-3, "{camera:?}");
        assert_eq!(camera.attitude.yaw_rad, r.v.attitude().yaw_rad);
        assert_eq!(camera.position_ned_m, r.v.position_ned_m());
        let snap = r.v.snapshot(r.t, battery());
        assert_eq!(snap.gimbal_attitude, Some(camera.attitude));
        // Without a gimbal the camera is the body's, and no gimbal is reported.
        let body = Run::airborne(10.0);
        assert_eq!(body.v.camera_pose().attitude, body.v.attitude());
        assert_eq!(body.v.snapshot(body.t, battery()).gimbal_attitude, None);
    }

    #[test]
    fn hover_holds_altitude() {
        let mut r = Run::airborne(10.0);
        assert_eq!(r.v.mode(), FlightMode::Hold);
        for _ in 0..(30.0 / DT) as usize {
            r.step(Vector3::zeros(), &far_pad());
            assert!((r.v.position_ned_m().z + 10.0).abs() < 0.05);
        }
        // Thrust equals the weight; the vehicle is level.
        assert!((r.v.thrust_n() - 1.5 * GRAVITY_M_S2).abs() < 1e-3);
        assert!(r.v.tilt_rad() < 1e-6);
        assert_eq!(r.v.landed_state(), LandedState::InAir);
        let snap = r.v.snapshot(r.t, battery());
        assert!((snap.rangefinder_m.unwrap() - 10.0).abs() < 0.05);
    }

    #[test]
    fn velocity_step_converges_within_the_tilt_limit() {
        let mut r = Run::offboard(10.0);
        let start = r.t;
        let mut t90 = None;
        let max_tilt = VehicleParams::default().max_tilt_rad;
        for _ in 0..(8.0 / DT) as usize {
            r.stream(Vector3::new(5.0, 0.0, 0.0));
            r.step(Vector3::zeros(), &far_pad());
            assert!(r.v.tilt_rad() <= max_tilt + 1e-9);
            if t90.is_none() && r.v.velocity_ned_m_s().x >= 4.5 {
                t90 = Some(r.t - start);
            }
        }
        let t90 = t90.unwrap();
        // Faster than the tilt limit allows is impossible; slower than the velocity loop's
        // time scale (1/Kp · ln 10 ≈ 1.3 s, plus the attitude lag) would be wrong.
        let physical_bound_s = 4.5 / (GRAVITY_M_S2 * max_tilt.tan());
        assert!(t90 > physical_bound_s && t90 < 2.5, "{t90}");
        assert!((r.v.velocity_ned_m_s() - Vector3::new(5.0, 0.0, 0.0)).norm() < 0.05);
        assert!((r.v.position_ned_m().z + 10.0).abs() < 0.3);
        // Flying level at 5 m/s the vehicle pitches nose down.
        assert!(r.v.attitude().pitch_rad < 0.0);
    }

    #[test]
    fn terminal_speed_matches_the_drag_model() {
        let p = VehicleParams::default();
        let mut r = Run::offboard(20.0);
        // Full tilt north against an 8 N headwind force: m·g·tan(tilt) − 8 = c1·v + c2·v².
        let headwind = Vector3::new(-8.0, 0.0, 0.0);
        for _ in 0..(40.0 / DT) as usize {
            r.stream(Vector3::new(12.0, 0.0, 0.0));
            r.step(headwind, &far_pad());
        }
        let push = p.mass_kg * GRAVITY_M_S2 * p.max_tilt_rad.tan() - 8.0;
        let (c1, c2) = (
            p.drag_linear_horizontal_n_s_per_m,
            p.drag_quadratic_horizontal_n_s2_per_m2,
        );
        let expected = (-c1 + (c1 * c1 + 4.0 * c2 * push).sqrt()) / (2.0 * c2);
        let v = r.v.velocity_ned_m_s().x;
        assert!(expected < 12.0);
        assert!((v / expected - 1.0).abs() < 0.01, "{v} vs {expected}");
    }

    #[test]
    fn offboard_setpoint_timeout_fails_safe_to_hold() {
        let mut r = Run::airborne(5.0);
        assert_eq!(
            r.cmd(AutopilotCommand::SetMode(FlightMode::Offboard)),
            Err(CommandRejected::NoOffboardSetpoint)
        );
        r.stream(Vector3::new(1.0, 0.0, 0.0));
        r.cmd(AutopilotCommand::SetMode(FlightMode::Offboard))
            .unwrap();
        r.run(0.45);
        assert_eq!(r.v.mode(), FlightMode::Offboard);
        r.run(0.1);
        assert_eq!(r.v.mode(), FlightMode::Hold);
        // Hold brakes and stays.
        r.run(10.0);
        assert!(r.v.velocity_ned_m_s().norm() < 0.05);
    }

    #[test]
    fn arming_and_takeoff_rules() {
        let mut r = Run::new();
        assert_eq!(r.v.landed_state(), LandedState::OnGround);
        assert_eq!(
            r.cmd(AutopilotCommand::Takeoff { altitude_m: 5.0 }),
            Err(CommandRejected::NotArmed)
        );
        assert_eq!(
            r.cmd(AutopilotCommand::Land),
            Err(CommandRejected::NotArmed)
        );
        r.cmd(AutopilotCommand::Arm).unwrap();
        assert!(matches!(
            r.cmd(AutopilotCommand::Takeoff { altitude_m: -1.0 }),
            Err(CommandRejected::Invalid(_))
        ));
        assert!(matches!(
            r.cmd(AutopilotCommand::VelocitySetpoint {
                velocity_ned_m_s: Vector3::new(f64::NAN, 0.0, 0.0),
                yaw_rad: None
            }),
            Err(CommandRejected::Invalid(_))
        ));
        // Armed in Hold on the ground: it idles and stays landed.
        r.run(3.0);
        assert!(r.v.is_landed() && r.v.position_ned_m().z == 0.0);
        r.cmd(AutopilotCommand::Takeoff { altitude_m: 5.0 })
            .unwrap();
        r.run(1.0);
        assert_eq!(r.v.landed_state(), LandedState::Takeoff);
        assert_eq!(
            r.cmd(AutopilotCommand::Arm),
            Err(CommandRejected::InAir("arm"))
        );
        assert_eq!(
            r.cmd(AutopilotCommand::Disarm),
            Err(CommandRejected::InAir("disarm"))
        );
        assert_eq!(
            r.cmd(AutopilotCommand::Takeoff { altitude_m: 5.0 }),
            Err(CommandRejected::InAir("take off"))
        );
        assert!(r.v.armed());
    }

    #[test]
    fn takeoff_reaches_its_altitude_at_the_takeoff_speed() {
        let mut r = Run::new();
        r.cmd(AutopilotCommand::Arm).unwrap();
        r.cmd(AutopilotCommand::Takeoff { altitude_m: 6.0 })
            .unwrap();
        let mut fastest_climb: f64 = 0.0;
        for _ in 0..(15.0 / DT) as usize {
            r.step(Vector3::zeros(), &far_pad());
            fastest_climb = fastest_climb.max(-r.v.velocity_ned_m_s().z);
        }
        assert!((r.v.position_ned_m().z + 6.0).abs() < 0.1);
        assert!(r.v.position_ned_m().xy().norm() < 0.05);
        assert_eq!(r.v.mode(), FlightMode::Hold);
        assert_eq!(r.v.landed_state(), LandedState::InAir);
        assert!(
            fastest_climb > 1.3 && fastest_climb < 1.5 * 1.1,
            "{fastest_climb}"
        );
    }

    #[test]
    fn land_descends_at_land_speed_then_detects_landing_and_disarms() {
        let mut r = Run::airborne(8.0);
        r.cmd(AutopilotCommand::Land).unwrap();
        assert_eq!(r.v.landed_state(), LandedState::Landing);
        r.run(5.0);
        assert!((r.v.velocity_ned_m_s().z - 0.7).abs() < 0.02);
        let mut landed_at = None;
        for _ in 0..(20.0 / DT) as usize {
            r.step(Vector3::zeros(), &far_pad());
            if landed_at.is_none() && r.v.is_landed() {
                landed_at = Some(r.t);
            }
        }
        let touchdown = r.v.touchdown().unwrap();
        assert!(!touchdown.on_pad);
        assert!((touchdown.vertical_speed_m_s - 0.7).abs() < 0.05);
        let landed_at = landed_at.unwrap();
        assert!(landed_at - touchdown.time_s >= 0.5 && landed_at - touchdown.time_s < 3.0);
        assert!(!r.v.armed());
        assert_eq!(r.v.landed_state(), LandedState::OnGround);
        assert_eq!(r.v.position_ned_m().z, 0.0);
        // Disarmed on the ground it can arm again.
        r.cmd(AutopilotCommand::Arm).unwrap();
    }

    fn moving_pad(t: f64) -> PadState {
        PadState {
            centre_ned_m: Vector3::new(1.5 * t, 0.0, -1.0),
            yaw_rad: 0.0,
            velocity_ned_m_s: Vector3::new(1.5, 0.0, 0.0),
            half_size_m: 0.5,
        }
    }

    /// Offboard chase of the pad with a P controller, descending when over it; `aim_offset_m`
    /// aims beside the pad to miss it.
    fn land_on_moving_pad(aim_offset_m: Vector2<f64>) -> (Run, Touchdown, PadState) {
        let mut r = Run::offboard(5.0);
        let start = r.t;
        let mut touchdown_pad = None;
        for _ in 0..(60.0 / DT) as usize {
            let pad = moving_pad(r.t - start);
            let error = pad.centre_ned_m.xy() + aim_offset_m - r.v.position_ned_m().xy();
            let xy = pad.velocity_ned_m_s.xy() + error * 1.0;
            let down = if error.norm() < 0.2 { 0.5 } else { 0.0 };
            r.stream(Vector3::new(xy.x, xy.y, down));
            let next = moving_pad(r.t + DT - start);
            r.step(Vector3::zeros(), &next);
            if touchdown_pad.is_none() && r.v.touchdown().is_some() {
                touchdown_pad = Some((next, r.v.position_ned_m()));
            }
        }
        let (pad, position) = touchdown_pad.unwrap();
        // The offset, computed independently from the positions at touchdown.
        let touchdown = r.v.touchdowns()[0];
        let d = position.xy() - pad.centre_ned_m.xy();
        let expected = Vector2::new(d.x, d.y); // pad yaw 0: frames coincide
        assert!((touchdown.offset_in_pad_frame_m - expected).norm() < 1e-9);
        (r, touchdown, pad)
    }

    #[test]
    fn landing_on_a_moving_pad_and_riding_it() {
        let (mut r, touchdown, _) = land_on_moving_pad(Vector2::zeros());
        assert!(touchdown.on_pad, "{touchdown:?}");
        assert!(touchdown.horizontal_error_m < 0.3, "{touchdown:?}");
        assert!(touchdown.relative_horizontal_speed_m_s < 0.3);
        assert!(touchdown.vertical_speed_m_s > 0.3);
        assert!(r.v.on_pad_now());
        // Riding: 20 s later it is still at the same place on the pad, at its height, at its speed.
        let start = r.t - 60.0;
        for _ in 0..(20.0 / DT) as usize {
            r.stream(Vector3::zeros());
            let next = moving_pad(r.t + DT - start);
            r.step(Vector3::zeros(), &next);
        }
        let pad = moving_pad(r.t - start);
        let offset = r.v.position_ned_m().xy() - pad.centre_ned_m.xy();
        assert!((offset - touchdown.offset_in_pad_frame_m).norm() < 1e-9);
        assert_eq!(r.v.position_ned_m().z, -1.0);
        assert!((r.v.velocity_ned_m_s() - pad.velocity_ned_m_s).norm() < 1e-9);
        let snap = r.v.snapshot(r.t, battery());
        assert_eq!(snap.rangefinder_m, None); // 0 m to the pad: below the minimum range
    }

    #[test]
    fn a_pad_rising_into_a_descending_vehicle_is_a_landing_on_it() {
        let mut r = Run::offboard(5.0);
        let below = r.v.position_ned_m().xy();
        let pad_at = |top_down_m: f64| PadState {
            centre_ned_m: Vector3::new(below.x, below.y, top_down_m),
            yaw_rad: 0.0,
            velocity_ned_m_s: Vector3::zeros(),
            half_size_m: 0.5,
        };
        // Down to a centimetre or two above the pad's top, slowly.
        while r.v.position_ned_m().z < -1.02 {
            let down_m_s = if r.v.position_ned_m().z < -1.5 {
                1.0
            } else {
                0.3
            };
            r.stream(Vector3::new(0.0, 0.0, down_m_s));
            r.step(Vector3::zeros(), &pad_at(-1.0));
            assert!(r.v.touchdown().is_none());
        }
        assert!(r.v.position_ned_m().z < -1.0);
        // A heave lifts the top 5 cm within one step: past the vehicle, which never crosses it
        // from above within the step.
        r.stream(Vector3::new(0.0, 0.0, 0.3));
        r.step(Vector3::zeros(), &pad_at(-1.05));
        let touchdown = r.v.touchdown().expect("a touchdown");
        assert!(touchdown.on_pad, "{touchdown:?}");
        assert!(r.v.on_pad_now());
    }

    #[test]
    fn missing_the_pad_lands_on_the_ground() {
        let (r, touchdown, _) = land_on_moving_pad(Vector2::new(0.0, 2.0));
        assert!(!touchdown.on_pad);
        assert!((touchdown.offset_in_pad_frame_m.y - 2.0).abs() < 0.25);
        assert!(r.v.touchdowns().iter().all(|t| !t.on_pad));
        // The ground does not move: relative speed is the vehicle's own.
        assert!((touchdown.relative_horizontal_speed_m_s - 1.5).abs() < 0.3);
    }

    #[test]
    fn starting_on_a_turning_pad_then_taking_off() {
        use crate::tractor::{PathKind, Tractor, TractorParams};
        let mut tractor =
            Tractor::new(PathKind::Circle, TractorParams::default(), [0.0, 0.0], 0.0).unwrap();
        let offset = Vector2::new(0.2, -0.1);
        let mut v = Multirotor::on_pad(VehicleParams::default(), &tractor.pad(), offset).unwrap();
        let mut t = 0.0;
        let step = |v: &mut Multirotor, tractor: &mut Tractor, t: &mut f64| {
            tractor.step(DT).unwrap();
            *t += DT;
            v.step(DT, *t, Vector3::zeros(), &tractor.pad()).unwrap();
        };
        for _ in 0..(10.0 / DT) as usize {
            step(&mut v, &mut tractor, &mut t);
        }
        let pad = tractor.pad();
        // Rides at its place on the turning pad, facing with it.
        assert!((pad.to_pad_frame(v.position_ned_m().xy()) - offset).norm() < 1e-9);
        assert!(wrap_angle(v.attitude().yaw_rad - pad.yaw_rad).abs() < 1e-9);
        assert!(pad.yaw_rad.abs() > 0.5);
        assert!(v.touchdowns().is_empty());
        v.command(AutopilotCommand::Arm, t).unwrap();
        v.command(AutopilotCommand::Takeoff { altitude_m: 3.0 }, t)
            .unwrap();
        for _ in 0..(12.0 / DT) as usize {
            step(&mut v, &mut tractor, &mut t);
        }
        assert!(v.is_flying() && !v.is_landed());
        assert!(
            (v.position_ned_m().z + 4.0).abs() < 0.1,
            "{:?}",
            v.position_ned_m()
        );
        assert!(v.touchdowns().is_empty());
        let snap = v.snapshot(t, battery());
        assert!(snap.armed && snap.mode == FlightMode::Hold);
    }

    #[test]
    fn bad_parameters_and_inputs_are_refused() {
        let p = VehicleParams {
            max_thrust_n: 10.0,
            ..VehicleParams::default()
        };
        assert!(matches!(p.validate(), Err(VehicleError::TooWeak { .. })));
        let p = VehicleParams {
            mass_kg: f64::NAN,
            ..VehicleParams::default()
        };
        assert!(matches!(
            p.validate(),
            Err(VehicleError::NotPositive {
                name: "mass_kg",
                ..
            })
        ));
        let mut r = Run::new();
        let before = r.v.clone();
        assert!(r.v.step(0.0, 1.0, Vector3::zeros(), &far_pad()).is_err());
        assert!(r
            .v
            .step(DT, 1.0, Vector3::new(f64::NAN, 0.0, 0.0), &far_pad())
            .is_err());
        assert_eq!(r.v, before);
    }
}
