//! The vehicle's and its autopilot's parameters, and the checks they must pass.

use nalgebra::Vector3;

use super::{VehicleError, GRAVITY_M_S2};

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

/// The body's translational drag in still air, −(c1 + c2·|v|)·v horizontally and vertically.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drag {
    pub linear_horizontal_n_s_per_m: f64,
    pub quadratic_horizontal_n_s2_per_m2: f64,
    pub linear_vertical_n_s_per_m: f64,
    pub quadratic_vertical_n_s2_per_m2: f64,
}

impl Drag {
    /// The force on a body moving at `velocity_ned_m_s`, NED.
    pub fn force_n(&self, velocity_ned_m_s: &Vector3<f64>) -> Vector3<f64> {
        let v = velocity_ned_m_s;
        let vh = v.xy();
        let horizontal = -vh
            * (self.linear_horizontal_n_s_per_m
                + self.quadratic_horizontal_n_s2_per_m2 * vh.norm());
        let vertical = -v.z
            * (self.linear_vertical_n_s_per_m + self.quadratic_vertical_n_s2_per_m2 * v.z.abs());
        Vector3::new(horizontal.x, horizontal.y, vertical)
    }
}

impl VehicleParams {
    /// Its drag coefficients.
    pub fn drag(&self) -> Drag {
        Drag {
            linear_horizontal_n_s_per_m: self.drag_linear_horizontal_n_s_per_m,
            quadratic_horizontal_n_s2_per_m2: self.drag_quadratic_horizontal_n_s2_per_m2,
            linear_vertical_n_s_per_m: self.drag_linear_vertical_n_s_per_m,
            quadratic_vertical_n_s2_per_m2: self.drag_quadratic_vertical_n_s2_per_m2,
        }
    }

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

    pub(super) fn hover_thrust_n(&self) -> f64 {
        self.mass_kg * GRAVITY_M_S2
    }
}
