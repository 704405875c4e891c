//! The world's vehicle as a rigid body flown by a real autopilot's motor commands: PX4's
//! `none_iris` over HIL and ArduPilot's quad X over JSON. Four rotors whose speed lags the
//! command, thrust and reaction torque from each, the body's translational drag (the same
//! coefficients as the built-in vehicle), the world's wind force, rotational damping, and the
//! ground and the moving pad as surfaces it rests on and lands on.
//!
//! Conventions as the rest of the world: NED, FRD body, the ground at down = 0. The attitude
//! is a unit quaternion rotating FRD into NED.

use algorithms::estimation::projection::Attitude;
use nalgebra::{UnitQuaternion, Vector2, Vector3};
use thiserror::Error;

use crate::camera::VehiclePose;
use crate::tractor::PadState;
use crate::vehicle::{
    range_to_surface_m, resting_state, touchdown_crossing, Contact, Drag, Touchdown, VehicleParams,
};

const GRAVITY_M_S2: f64 = 9.80665;
/// Integration sub-step: a 4 ms HIL step is split in four, well inside the rotational modes.
const MAX_SUBSTEP_S: f64 = 0.001;
/// How fast the landing gear stops the body on a surface (a skid's give: a 1 m/s touchdown
/// peaks at about 3 g).
const GEAR_TIME_CONSTANT_S: f64 = 0.03;

/// One rotor: where it sits and which way it turns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rotor {
    /// Forward and right of the centre of mass [PX4 CA_ROTORn_PX, CA_ROTORn_PY].
    pub position_frd_m: Vector2<f64>,
    /// Reaction torque per newton of thrust about the body's z axis; positive for a rotor that
    /// turns counter-clockwise seen from above, which yaws the body clockwise [CA_ROTORn_KM].
    pub moment_coefficient_m: f64,
}

/// The rigid body's parameters. Defaults: the Iris that PX4's `none_iris` airframe and
/// Gazebo Classic's `iris.sdf` describe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadrotorParams {
    /// Gazebo Classic iris.sdf: 1.5 kg base and four 5 g rotors.
    pub mass_kg: f64,
    /// Principal moments of inertia about FRD x, y, z (iris.sdf: 0.029125, 0.029125, 0.055225).
    pub inertia_kg_m2: Vector3<f64>,
    /// PX4 airframe 10016_none_iris's rotor geometry, in its order: the motor commands come in
    /// this order. It is ArduPilot's quad X order too (1 front right, 2 back left, 3 front
    /// left, 4 back right).
    pub rotors: [Rotor; 4],
    /// Thrust at full command: iris.sdf's motorConstant 8.54858e-6 N/(rad/s)² at its
    /// maxRotVelocity 1100 rad/s. Thrust goes with the rotor speed squared, the speed with the
    /// command (as Gazebo's motor model).
    pub max_thrust_per_rotor_n: f64,
    /// The rotor speed follows the command as a first-order lag, faster up than down
    /// (iris.sdf timeConstantUp 0.0125 s, timeConstantDown 0.025 s).
    pub motor_time_constant_up_s: f64,
    pub motor_time_constant_down_s: f64,
    /// Aerodynamic damping of the body rates, N·m per rad/s (small: the rotors' flapping).
    pub rotational_damping_n_m_s: f64,
    /// Translational drag: the built-in vehicle's, so both bodies feel the same air.
    pub drag: Drag,
}

impl Default for QuadrotorParams {
    fn default() -> Self {
        let rotor = |px: f64, py: f64, km: f64| Rotor {
            position_frd_m: Vector2::new(px, py),
            moment_coefficient_m: km,
        };
        Self {
            mass_kg: 1.52,
            inertia_kg_m2: Vector3::new(0.029125, 0.029125, 0.055225),
            rotors: [
                rotor(0.1515, 0.245, 0.05),
                rotor(-0.1515, -0.1875, 0.05),
                rotor(0.1515, -0.245, -0.05),
                rotor(-0.1515, 0.1875, -0.05),
            ],
            max_thrust_per_rotor_n: 8.54858e-6 * 1100.0 * 1100.0,
            motor_time_constant_up_s: 0.0125,
            motor_time_constant_down_s: 0.025,
            rotational_damping_n_m_s: 0.003,
            drag: VehicleParams::default().drag(),
        }
    }
}

impl QuadrotorParams {
    /// The motor command that holds the body in hover.
    pub fn hover_command(&self) -> f64 {
        (self.mass_kg * GRAVITY_M_S2 / (4.0 * self.max_thrust_per_rotor_n)).sqrt()
    }

    pub fn validate(&self) -> Result<(), QuadrotorError> {
        for (name, value) in [
            ("mass_kg", self.mass_kg),
            ("inertia_kg_m2.x", self.inertia_kg_m2.x),
            ("inertia_kg_m2.y", self.inertia_kg_m2.y),
            ("inertia_kg_m2.z", self.inertia_kg_m2.z),
            ("max_thrust_per_rotor_n", self.max_thrust_per_rotor_n),
            ("motor_time_constant_up_s", self.motor_time_constant_up_s),
            (
                "motor_time_constant_down_s",
                self.motor_time_constant_down_s,
            ),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(QuadrotorError::NotPositive { name, value });
            }
        }
        if 4.0 * self.max_thrust_per_rotor_n <= self.mass_kg * GRAVITY_M_S2 {
            return Err(QuadrotorError::TooWeak {
                max_thrust_n: 4.0 * self.max_thrust_per_rotor_n,
                weight_n: self.mass_kg * GRAVITY_M_S2,
            });
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum QuadrotorError {
    #[error("quadrotor {name} = {value} must be a finite number > 0")]
    NotPositive { name: &'static str, value: f64 },
    #[error("the rotors' {max_thrust_n} N cannot lift the {weight_n} N quadrotor")]
    TooWeak { max_thrust_n: f64, weight_n: f64 },
    #[error("quadrotor step input {0} is not finite")]
    NonFinite(&'static str),
}

/// The body's true state, as sensors sample it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyState {
    pub position_ned_m: Vector3<f64>,
    pub velocity_ned_m_s: Vector3<f64>,
    /// The acceleration over the last step (NED): what the accelerometer feels, less gravity.
    pub acceleration_ned_m_s2: Vector3<f64>,
    /// FRD → NED.
    pub attitude: UnitQuaternion<f64>,
    pub body_rates_rad_s: Vector3<f64>,
}

impl BodyState {
    /// The specific force in the body frame: what an accelerometer at the centre of mass reads
    /// (−g on z at rest).
    pub fn specific_force_frd_m_s2(&self) -> Vector3<f64> {
        self.attitude.inverse()
            * (self.acceleration_ned_m_s2 - Vector3::new(0.0, 0.0, GRAVITY_M_S2))
    }

    pub fn euler(&self) -> Attitude {
        let (roll, pitch, yaw) = self.attitude.euler_angles();
        Attitude::new(roll, pitch, yaw)
    }
}

/// The rigid-body quadrotor.
#[derive(Debug, Clone, PartialEq)]
pub struct Quadrotor {
    params: QuadrotorParams,
    state: BodyState,
    /// Each rotor's speed as a fraction of its maximum.
    rotor_speed_fraction: [f64; 4],
    /// What the autopilot last commanded, 0–1 in the rotors' order.
    motor_commands: [f64; 4],
    contact: Option<Contact>,
    touchdowns: Vec<Touchdown>,
    last_pad: Option<PadState>,
}

impl Quadrotor {
    /// At rest on the ground at `position_ned_m`'s north and east, yaw north, rotors still.
    pub fn on_ground(
        params: QuadrotorParams,
        position_ned_m: Vector3<f64>,
    ) -> Result<Self, QuadrotorError> {
        params.validate()?;
        if !position_ned_m.iter().all(|v| v.is_finite()) {
            return Err(QuadrotorError::NonFinite("position_ned_m"));
        }
        Ok(Self {
            params,
            state: BodyState {
                position_ned_m: Vector3::new(position_ned_m.x, position_ned_m.y, 0.0),
                velocity_ned_m_s: Vector3::zeros(),
                acceleration_ned_m_s2: Vector3::zeros(),
                attitude: UnitQuaternion::identity(),
                body_rates_rad_s: Vector3::zeros(),
            },
            rotor_speed_fraction: [0.0; 4],
            motor_commands: [0.0; 4],
            contact: Some(Contact::Ground),
            touchdowns: Vec::new(),
            last_pad: None,
        })
    }

    /// In free flight at `position_ned_m` with `velocity_ned_m_s`, level, yaw north, the rotors
    /// turning at hover speed.
    pub fn airborne(
        params: QuadrotorParams,
        position_ned_m: Vector3<f64>,
        velocity_ned_m_s: Vector3<f64>,
    ) -> Result<Self, QuadrotorError> {
        let mut body = Self::on_ground(params, position_ned_m)?;
        if !velocity_ned_m_s.iter().all(|v| v.is_finite()) {
            return Err(QuadrotorError::NonFinite("velocity_ned_m_s"));
        }
        body.state.position_ned_m = position_ned_m;
        body.state.velocity_ned_m_s = velocity_ned_m_s;
        body.rotor_speed_fraction = [params.hover_command(); 4];
        body.motor_commands = body.rotor_speed_fraction;
        body.contact = None;
        Ok(body)
    }

    pub fn params(&self) -> &QuadrotorParams {
        &self.params
    }

    pub fn state(&self) -> &BodyState {
        &self.state
    }

    pub fn position_ned_m(&self) -> Vector3<f64> {
        self.state.position_ned_m
    }

    pub fn velocity_ned_m_s(&self) -> Vector3<f64> {
        self.state.velocity_ned_m_s
    }

    /// Whether the body is off every surface.
    pub fn is_flying(&self) -> bool {
        self.contact.is_none()
    }

    /// Every touchdown so far, in order.
    pub fn touchdowns(&self) -> &[Touchdown] {
        &self.touchdowns
    }

    pub fn touchdown(&self) -> Option<Touchdown> {
        self.touchdowns.last().copied()
    }

    /// The pose a camera fixed to the body sees from.
    pub fn pose(&self) -> VehiclePose {
        VehiclePose {
            position_ned_m: self.state.position_ned_m,
            attitude: self.state.euler(),
            velocity_ned_m_s: self.state.velocity_ned_m_s,
            body_rates_rad_s: self.state.body_rates_rad_s,
        }
    }

    /// The downward rangefinder's true range to the pad's top or the ground.
    pub fn rangefinder_m(&self) -> Option<f64> {
        range_to_surface_m(
            self.state.position_ned_m,
            self.state.attitude * Vector3::z(),
            self.last_pad.as_ref(),
        )
    }

    /// The autopilot's motor commands, 0–1 in the rotors' order; out-of-range commands
    /// saturate, and a NaN (PX4's disarmed output) is a stopped motor.
    pub fn set_motor_commands(&mut self, motor_commands: [f64; 4]) {
        self.motor_commands = motor_commands.map(|u| {
            if u.is_finite() {
                u.clamp(0.0, 1.0)
            } else {
                0.0
            }
        });
    }

    pub fn motor_commands(&self) -> [f64; 4] {
        self.motor_commands
    }

    /// Advances by `dt_s` to `time_s` (the end of the step) with the wind's force and the
    /// pad's state at the end of the step. On error nothing changes.
    pub fn step(
        &mut self,
        dt_s: f64,
        time_s: f64,
        wind_force_ned_n: Vector3<f64>,
        pad: &PadState,
    ) -> Result<(), QuadrotorError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(QuadrotorError::NotPositive {
                name: "dt_s",
                value: dt_s,
            });
        }
        if !time_s.is_finite() {
            return Err(QuadrotorError::NonFinite("time_s"));
        }
        if !wind_force_ned_n.iter().all(|v| v.is_finite()) {
            return Err(QuadrotorError::NonFinite("wind_force_ned_n"));
        }
        if !pad.is_finite() {
            return Err(QuadrotorError::NonFinite("pad"));
        }
        let commands = self.motor_commands;
        let substeps = (dt_s / MAX_SUBSTEP_S).ceil().max(1.0) as usize;
        let h = dt_s / substeps as f64;
        let previous_pad = self.last_pad.unwrap_or(*pad);
        for i in 0..substeps {
            let t = time_s - dt_s + (i + 1) as f64 * h;
            self.substep(h, t, &commands, wind_force_ned_n, pad, &previous_pad, dt_s);
        }
        self.last_pad = Some(*pad);
        Ok(())
    }

    /// Thrust (FRD, along −z) and torque (FRD) of the rotors at their present speeds.
    fn rotor_wrench(&self) -> (Vector3<f64>, Vector3<f64>) {
        let p = &self.params;
        let mut thrust_n = 0.0;
        let mut torque = Vector3::zeros();
        for (rotor, speed) in p.rotors.iter().zip(self.rotor_speed_fraction) {
            let t = p.max_thrust_per_rotor_n * speed * speed;
            thrust_n += t;
            // r × (0, 0, −T) plus the reaction torque about z.
            torque += Vector3::new(
                -rotor.position_frd_m.y * t,
                rotor.position_frd_m.x * t,
                rotor.moment_coefficient_m * t,
            );
        }
        (Vector3::new(0.0, 0.0, -thrust_n), torque)
    }

    #[allow(clippy::too_many_arguments)]
    fn substep(
        &mut self,
        h: f64,
        time_s: f64,
        commands: &[f64; 4],
        wind_force_ned_n: Vector3<f64>,
        pad: &PadState,
        previous_pad: &PadState,
        pad_dt_s: f64,
    ) {
        let p = self.params;
        for (speed, command) in self.rotor_speed_fraction.iter_mut().zip(commands) {
            let tau = if *command > *speed {
                p.motor_time_constant_up_s
            } else {
                p.motor_time_constant_down_s
            };
            *speed += (command - *speed) * (1.0 - (-h / tau).exp());
        }
        let (thrust_frd, torque_frd) = self.rotor_wrench();
        let force = self.state.attitude * thrust_frd
            + Vector3::new(0.0, 0.0, p.mass_kg * GRAVITY_M_S2)
            + p.drag.force_n(&self.state.velocity_ned_m_s)
            + wind_force_ned_n;
        let previous_velocity = self.state.velocity_ned_m_s;

        // Resting on a surface: it holds the body until the net force lifts it.
        if let Some(contact) = self.contact {
            if force.z < 0.0 {
                self.contact = None;
            } else {
                self.rest_on(contact, h, pad, previous_pad, pad_dt_s);
                return;
            }
        }

        // Free flight: semi-implicit Euler; the attitude by the exact rotation of the rates.
        let acceleration = force / p.mass_kg;
        let previous_down = self.state.position_ned_m.z;
        self.state.velocity_ned_m_s += acceleration * h;
        self.state.position_ned_m += self.state.velocity_ned_m_s * h;
        self.state.acceleration_ned_m_s2 = acceleration;
        let inertia = p.inertia_kg_m2;
        let omega = self.state.body_rates_rad_s;
        let angular_momentum = inertia.component_mul(&omega);
        let angular_acceleration =
            (torque_frd - omega.cross(&angular_momentum) - omega * p.rotational_damping_n_m_s)
                .component_div(&inertia);
        self.state.body_rates_rad_s += angular_acceleration * h;
        self.state.attitude *= UnitQuaternion::from_scaled_axis(self.state.body_rates_rad_s * h);

        let tilt_rad = (self.state.attitude * Vector3::z())
            .z
            .clamp(-1.0, 1.0)
            .acos();
        if let Some(touchdown) = touchdown_crossing(
            time_s,
            previous_down,
            self.state.position_ned_m,
            self.state.velocity_ned_m_s,
            tilt_rad,
            pad,
            previous_pad,
        ) {
            let (_, _, yaw) = self.state.attitude.euler_angles();
            self.contact = Some(if touchdown.on_pad {
                Contact::Pad {
                    offset_pad_m: touchdown.offset_in_pad_frame_m,
                    yaw_offset_rad: crate::vehicle::wrap_angle(yaw - pad.yaw_rad),
                }
            } else {
                Contact::Ground
            });
            self.touchdowns.push(touchdown);
            // The surface takes over from the step's start: the gear's give absorbs the rest.
            self.state.velocity_ned_m_s = previous_velocity;
            self.rest_on(
                self.contact.unwrap_or(Contact::Ground),
                h,
                pad,
                previous_pad,
                pad_dt_s,
            );
        }
    }

    /// One sub-step on the surface: the body sits where the surface holds it; its velocity and
    /// attitude settle to the surface's through the landing gear's give within tens of
    /// milliseconds (not at once: an instant stop would read as a 100 g spike on the IMU, which
    /// no real accelerometer reports and an estimator would take for a fault).
    fn rest_on(
        &mut self,
        contact: Contact,
        h: f64,
        pad: &PadState,
        previous_pad: &PadState,
        pad_dt_s: f64,
    ) {
        let (_, _, yaw) = self.state.attitude.euler_angles();
        let (position, surface_velocity, yaw) = resting_state(
            contact,
            self.state.position_ned_m,
            yaw,
            pad,
            previous_pad,
            pad_dt_s,
        );
        let give = 1.0 - (-h / GEAR_TIME_CONSTANT_S).exp();
        let previous_velocity = self.state.velocity_ned_m_s;
        let previous_attitude = self.state.attitude;
        let velocity = previous_velocity + (surface_velocity - previous_velocity) * give;
        let level = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
        let attitude = previous_attitude.slerp(&level, give);
        self.state.position_ned_m = position;
        self.state.velocity_ned_m_s = velocity;
        self.state.acceleration_ned_m_s2 = (velocity - previous_velocity) / h;
        self.state.attitude = attitude;
        self.state.body_rates_rad_s = (previous_attitude.inverse() * attitude).scaled_axis() / h;
    }
}

#[cfg(test)]
mod tests;
