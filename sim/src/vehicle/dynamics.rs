//! One sub-step of flight: PX4's position and velocity control into a thrust vector, the
//! translational dynamics with drag, contact with the ground and the pad, and landed detection.

use algorithms::estimation::projection::Attitude;
use nalgebra::{Rotation3, Vector2, Vector3};

use super::{resting_state, touchdown_crossing, wrap_angle, Contact, Multirotor, GRAVITY_M_S2};
use crate::flight::FlightMode;
use crate::tractor::PadState;

/// An offboard setpoint climbing faster than this lifts a landed vehicle off (PX4 takes off in
/// offboard when the setpoint asks to climb).
const OFFBOARD_TAKEOFF_CLIMB_M_S: f64 = 0.2;
/// Takeoff is complete within this distance of the target altitude.
const TAKEOFF_DONE_M: f64 = 0.1;
/// Integrator bound (acceleration), a backstop behind the anti-windup.
const MAX_INTEGRAL_M_S2: f64 = 8.0;

impl Multirotor {
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
        self.params.drag().force_n(&self.velocity_ned_m_s)
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn substep(
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
                let (position, velocity, resting_yaw) = resting_state(
                    contact,
                    self.position_ned_m,
                    yaw,
                    pad,
                    previous_pad,
                    pad_dt_s,
                );
                self.position_ned_m = position;
                self.velocity_ned_m_s = velocity;
                yaw = resting_yaw;
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
        if let Some(touchdown) = touchdown_crossing(
            time_s,
            previous_down,
            self.position_ned_m,
            self.velocity_ned_m_s,
            self.tilt_rad(),
            pad,
            previous_pad,
        ) {
            let vertical_speed = touchdown.vertical_speed_m_s;
            self.touchdowns.push(touchdown);
            if touchdown.on_pad {
                self.contact = Some(Contact::Pad {
                    offset_pad_m: touchdown.offset_in_pad_frame_m,
                    yaw_offset_rad: wrap_angle(yaw - pad.yaw_rad),
                });
                self.position_ned_m.z = pad.centre_ned_m.z;
                self.velocity_ned_m_s = pad.velocity_ned_m_s;
            } else {
                self.contact = Some(Contact::Ground);
                self.position_ned_m.z = 0.0;
                self.velocity_ned_m_s = Vector3::zeros();
            }
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

fn clamp_norm(v: Vector2<f64>, max_norm: f64) -> Vector2<f64> {
    let norm = v.norm();
    if norm > max_norm {
        v * (max_norm / norm)
    } else {
        v
    }
}
