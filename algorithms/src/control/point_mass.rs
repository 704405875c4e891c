//! A point-mass multirotor for closed-loop tests: the autopilot's velocity loop seen from outside,
//! as a first-order lag on the velocity setpoint with speed and acceleration limits.
//!
//! It is deliberately simple (no attitude, no drag, no wind) so a controller's test measures the
//! controller; the simulator may wrap it with its own disturbances.

use nalgebra::{Vector2, Vector3};
use thiserror::Error;

/// Errors from the point mass's configuration or from one step's input.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PointMassError {
    #[error("point mass {name} = {value} must be a finite number > 0")]
    NotPositive { name: &'static str, value: f64 },
    #[error("point mass {name} is not finite; every input must be a finite number")]
    NonFinite { name: &'static str },
}

/// Limits and the velocity loop's time constant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointMassConfig {
    /// Time constant of the first-order response to a velocity setpoint.
    pub velocity_time_constant_s: f64,
    pub max_horizontal_speed_m_s: f64,
    pub max_vertical_speed_m_s: f64,
    pub max_horizontal_accel_m_s2: f64,
    pub max_vertical_accel_m_s2: f64,
}

impl Default for PointMassConfig {
    /// Roughly a PX4 quadrotor's defaults (MPC_XY_VEL_MAX 12, MPC_ACC_HOR 3, MPC_Z_VEL_MAX_DN 1.5,
    /// MPC_ACC_DOWN_MAX 3) with a velocity loop of about 0.2 s.
    fn default() -> Self {
        Self {
            velocity_time_constant_s: 0.2,
            max_horizontal_speed_m_s: 12.0,
            max_vertical_speed_m_s: 1.5,
            max_horizontal_accel_m_s2: 3.0,
            max_vertical_accel_m_s2: 3.0,
        }
    }
}

impl PointMassConfig {
    pub fn validate(&self) -> Result<(), PointMassError> {
        for (name, value) in [
            ("velocity_time_constant_s", self.velocity_time_constant_s),
            ("max_horizontal_speed_m_s", self.max_horizontal_speed_m_s),
            ("max_vertical_speed_m_s", self.max_vertical_speed_m_s),
            ("max_horizontal_accel_m_s2", self.max_horizontal_accel_m_s2),
            ("max_vertical_accel_m_s2", self.max_vertical_accel_m_s2),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(PointMassError::NotPositive { name, value });
            }
        }
        Ok(())
    }
}

/// The vehicle's state in the NED world frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PointMass {
    config: PointMassConfig,
    pub position_ned_m: Vector3<f64>,
    pub velocity_ned_m_s: Vector3<f64>,
}

impl PointMass {
    /// A vehicle at rest at `position_ned_m`.
    pub fn new(
        config: PointMassConfig,
        position_ned_m: Vector3<f64>,
    ) -> Result<Self, PointMassError> {
        config.validate()?;
        if !position_ned_m.iter().all(|v| v.is_finite()) {
            return Err(PointMassError::NonFinite {
                name: "position_ned_m",
            });
        }
        Ok(Self {
            config,
            position_ned_m,
            velocity_ned_m_s: Vector3::zeros(),
        })
    }

    pub fn config(&self) -> &PointMassConfig {
        &self.config
    }

    /// Advances by `dt_s` towards the velocity setpoint (NED). On error the state is unchanged.
    pub fn step(
        &mut self,
        setpoint_ned_m_s: Vector3<f64>,
        dt_s: f64,
    ) -> Result<(), PointMassError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(PointMassError::NotPositive {
                name: "dt_s",
                value: dt_s,
            });
        }
        if !setpoint_ned_m_s.iter().all(|v| v.is_finite()) {
            return Err(PointMassError::NonFinite {
                name: "setpoint_ned_m_s",
            });
        }
        let c = &self.config;
        let horizontal_sp = clamp_norm(setpoint_ned_m_s.xy(), c.max_horizontal_speed_m_s);
        let vertical_sp = setpoint_ned_m_s
            .z
            .clamp(-c.max_vertical_speed_m_s, c.max_vertical_speed_m_s);

        // The lag's acceleration, never more than what reaches the setpoint within this step
        // (so a large dt cannot overshoot), then the acceleration limits.
        let gain_per_s = 1.0 / c.velocity_time_constant_s.max(dt_s);
        let horizontal_accel = clamp_norm(
            (horizontal_sp - self.velocity_ned_m_s.xy()) * gain_per_s,
            c.max_horizontal_accel_m_s2,
        );
        let vertical_accel = ((vertical_sp - self.velocity_ned_m_s.z) * gain_per_s)
            .clamp(-c.max_vertical_accel_m_s2, c.max_vertical_accel_m_s2);

        let previous_velocity = self.velocity_ned_m_s;
        self.velocity_ned_m_s = Vector3::new(
            previous_velocity.x + horizontal_accel.x * dt_s,
            previous_velocity.y + horizontal_accel.y * dt_s,
            previous_velocity.z + vertical_accel * dt_s,
        );
        // Trapezoidal position update: exact for constant acceleration over the step.
        self.position_ned_m += (previous_velocity + self.velocity_ned_m_s) * (0.5 * dt_s);
        Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_order_response_matches_exponential() {
        // Limits far away, small step: v(t) = v_sp·(1 − exp(−t/τ)).
        let config = PointMassConfig {
            velocity_time_constant_s: 0.5,
            max_horizontal_speed_m_s: 100.0,
            max_vertical_speed_m_s: 100.0,
            max_horizontal_accel_m_s2: 100.0,
            max_vertical_accel_m_s2: 100.0,
        };
        let mut pm = PointMass::new(config, Vector3::zeros()).unwrap();
        let dt_s = 1e-3;
        for _ in 0..1000 {
            pm.step(Vector3::new(2.0, 0.0, -1.0), dt_s).unwrap();
        }
        let expected = 1.0 - (-1.0f64 / 0.5).exp();
        assert!((pm.velocity_ned_m_s.x - 2.0 * expected).abs() < 2e-3);
        assert!((pm.velocity_ned_m_s.z + expected).abs() < 1e-3);
    }

    #[test]
    fn limits_hold() {
        let config = PointMassConfig::default();
        let mut pm = PointMass::new(config, Vector3::zeros()).unwrap();
        let dt_s = 0.01;
        let mut previous = pm.velocity_ned_m_s;
        for _ in 0..1000 {
            pm.step(Vector3::new(30.0, 30.0, 10.0), dt_s).unwrap();
            let v = pm.velocity_ned_m_s;
            let accel = (v - previous) / dt_s;
            assert!(accel.xy().norm() <= config.max_horizontal_accel_m_s2 + 1e-9);
            assert!(accel.z.abs() <= config.max_vertical_accel_m_s2 + 1e-9);
            assert!(v.xy().norm() <= config.max_horizontal_speed_m_s + 1e-9);
            assert!(v.z.abs() <= config.max_vertical_speed_m_s + 1e-9);
            previous = v;
        }
        assert!((pm.velocity_ned_m_s.xy().norm() - 12.0).abs() < 1e-6);
    }

    #[test]
    fn large_step_does_not_overshoot_and_bad_input_is_rejected() {
        let mut pm = PointMass::new(PointMassConfig::default(), Vector3::zeros()).unwrap();
        for _ in 0..10 {
            pm.step(Vector3::new(0.5, 0.0, 0.0), 1.0).unwrap();
            assert!(pm.velocity_ned_m_s.x <= 0.5 + 1e-12);
        }
        let before = pm.clone();
        assert!(pm.step(Vector3::new(f64::NAN, 0.0, 0.0), 0.1).is_err());
        assert!(pm.step(Vector3::zeros(), 0.0).is_err());
        assert!(pm.step(Vector3::zeros(), f64::NAN).is_err());
        assert_eq!(pm, before);
        let bad = PointMassConfig {
            velocity_time_constant_s: 0.0,
            ..PointMassConfig::default()
        };
        assert!(PointMass::new(bad, Vector3::zeros()).is_err());
    }
}
