//! A two-axis stabilising gimbal under the vehicle: it holds the camera looking straight down
//! whatever the vehicle's lean, within its joints' range, with the lag of its control loop.
//!
//! Each joint (roll, pitch) drives towards the angle that cancels the vehicle's, clamped to its
//! range, as a first-order lag. The camera's roll and pitch are the vehicle's plus the joint's
//! (Euler angles added: exact for one axis, close for the leans of flight); its heading is the
//! vehicle's (the gimbal follows yaw). Past the range the camera leans by the excess.

use algorithms::estimation::projection::Attitude;

use crate::camera::VehiclePose;
use nalgebra::Vector3;
use thiserror::Error;

/// The gimbal's limits and loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GimbalParams {
    /// Each joint's range either side of straight down. Small three-axis camera gimbals allow
    /// ±45° of roll and more pitch; the smaller figure serves both joints.
    pub max_joint_rad: f64,
    /// The stabilisation loop's time constant. Brushless gimbals run it at kHz from their own
    /// IMU with tens of Hz of bandwidth, holding the horizon to a few tenths of a degree in
    /// flight: 5 ms lags 0.25° behind a 50°/s roll.
    pub time_constant_s: f64,
}

impl Default for GimbalParams {
    fn default() -> Self {
        Self {
            max_joint_rad: 45f64.to_radians(),
            time_constant_s: 0.005,
        }
    }
}

/// A gimbal that cannot work.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum GimbalError {
    #[error("max_joint_rad must be within (0, π/2), got {0}")]
    Range(f64),
    #[error("time_constant_s must be finite and ≥ 0, got {0}")]
    TimeConstant(f64),
}

impl GimbalParams {
    pub fn validate(&self) -> Result<(), GimbalError> {
        if !(self.max_joint_rad > 0.0 && self.max_joint_rad < std::f64::consts::FRAC_PI_2) {
            return Err(GimbalError::Range(self.max_joint_rad));
        }
        if !(self.time_constant_s.is_finite() && self.time_constant_s >= 0.0) {
            return Err(GimbalError::TimeConstant(self.time_constant_s));
        }
        Ok(())
    }
}

/// The gimbal's state: its two joint angles and how fast they last moved.
#[derive(Debug, Clone, PartialEq)]
pub struct Gimbal {
    params: GimbalParams,
    joint_roll_rad: f64,
    joint_pitch_rad: f64,
    /// Roll and pitch joint rates over the last step.
    joint_rates_rad_s: Vector3<f64>,
}

impl Gimbal {
    /// A gimbal at rest in its centre (the camera along the body's down axis).
    pub fn new(params: GimbalParams) -> Result<Self, GimbalError> {
        params.validate()?;
        Ok(Self {
            params,
            joint_roll_rad: 0.0,
            joint_pitch_rad: 0.0,
            joint_rates_rad_s: Vector3::zeros(),
        })
    }

    /// Moves the joints over `dt_s` towards levelling a vehicle at `vehicle`.
    pub fn step(&mut self, dt_s: f64, vehicle: &Attitude) {
        let max = self.params.max_joint_rad;
        let gain = if self.params.time_constant_s > 0.0 {
            1.0 - (-dt_s.max(0.0) / self.params.time_constant_s).exp()
        } else {
            1.0
        };
        let before = (self.joint_roll_rad, self.joint_pitch_rad);
        self.joint_roll_rad += ((-vehicle.roll_rad).clamp(-max, max) - self.joint_roll_rad) * gain;
        self.joint_pitch_rad +=
            ((-vehicle.pitch_rad).clamp(-max, max) - self.joint_pitch_rad) * gain;
        if dt_s > 0.0 {
            self.joint_rates_rad_s = Vector3::new(
                (self.joint_roll_rad - before.0) / dt_s,
                (self.joint_pitch_rad - before.1) / dt_s,
                0.0,
            );
        }
    }

    /// The camera on this gimbal under a vehicle at `vehicle`: where it points and how fast
    /// it turns (the vehicle's rates less what the joints take out, for the motion blur).
    pub fn camera_pose(&self, vehicle: &VehiclePose) -> VehiclePose {
        VehiclePose {
            attitude: self.camera_attitude(&vehicle.attitude),
            body_rates_rad_s: vehicle.body_rates_rad_s + self.joint_rates_rad_s,
            ..*vehicle
        }
    }

    /// Where the camera points on a vehicle at `vehicle`, the joints as they are.
    pub fn camera_attitude(&self, vehicle: &Attitude) -> Attitude {
        Attitude::new(
            vehicle.roll_rad + self.joint_roll_rad,
            vehicle.pitch_rad + self.joint_pitch_rad,
            vehicle.yaw_rad,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settle(gimbal: &mut Gimbal, vehicle: &Attitude) -> Attitude {
        for _ in 0..200 {
            gimbal.step(0.005, vehicle);
        }
        gimbal.camera_attitude(vehicle)
    }

    #[test]
    fn within_its_range_the_gimbal_holds_the_camera_level_on_the_heading() {
        let mut gimbal = Gimbal::new(GimbalParams::default()).unwrap();
        let vehicle = Attitude::new(0.5, -0.3, 1.2);
        let camera = settle(&mut gimbal, &vehicle);
        assert!(camera.roll_rad.abs() < 1e-9 && camera.pitch_rad.abs() < 1e-9);
        assert_eq!(camera.yaw_rad, 1.2);
    }

    #[test]
    fn past_its_range_the_camera_leans_by_the_excess() {
        let params = GimbalParams {
            max_joint_rad: 40f64.to_radians(),
            ..GimbalParams::default()
        };
        let mut gimbal = Gimbal::new(params).unwrap();
        let vehicle = Attitude::new(50f64.to_radians(), -45f64.to_radians(), 0.0);
        let camera = settle(&mut gimbal, &vehicle);
        assert!((camera.roll_rad - 10f64.to_radians()).abs() < 1e-9);
        assert!((camera.pitch_rad + 5f64.to_radians()).abs() < 1e-9);
    }

    /// After a sudden lean the camera comes back as e^(−t/τ), whatever the steps' length.
    #[test]
    fn the_camera_returns_to_level_with_the_loops_time_constant() {
        let tau_s = 0.02;
        let params = GimbalParams {
            time_constant_s: tau_s,
            ..GimbalParams::default()
        };
        let lean_rad = 0.3;
        for dt_s in [0.001, 0.005] {
            let mut gimbal = Gimbal::new(params).unwrap();
            let vehicle = Attitude::new(lean_rad, 0.0, 0.0);
            let steps = (0.03_f64 / dt_s).round() as usize;
            let mut camera = gimbal.camera_attitude(&vehicle);
            assert_eq!(camera.roll_rad, lean_rad);
            for _ in 0..steps {
                gimbal.step(dt_s, &vehicle);
                camera = gimbal.camera_attitude(&vehicle);
            }
            let expected = lean_rad * (-0.03f64 / tau_s).exp();
            assert!((camera.roll_rad - expected).abs() < 1e-9, "{camera:?}");
        }
    }

    #[test]
    fn the_cameras_rates_are_the_vehicles_less_what_the_joints_take_out() {
        let mut gimbal = Gimbal::new(GimbalParams::default()).unwrap();
        let rates = Vector3::new(1.0, -0.5, 0.2);
        let dt_s = 0.005;
        // The vehicle turns steadily; once the loop has caught up the camera turns with the
        // lag's steady error only: its rate goes to zero on roll and pitch, yaw stays.
        let mut vehicle = VehiclePose {
            position_ned_m: Vector3::new(1.0, 2.0, -5.0),
            attitude: Attitude::default(),
            velocity_ned_m_s: Vector3::new(0.5, 0.0, 0.0),
            body_rates_rad_s: rates,
        };
        for i in 1..=100 {
            let t = i as f64 * dt_s;
            vehicle.attitude = Attitude::new(rates.x * t, rates.y * t, rates.z * t);
            gimbal.step(dt_s, &vehicle.attitude);
        }
        let camera = gimbal.camera_pose(&vehicle);
        assert!(camera.body_rates_rad_s.x.abs() < 1e-6 && camera.body_rates_rad_s.y.abs() < 1e-6);
        assert_eq!(camera.body_rates_rad_s.z, 0.2);
        assert_eq!(camera.position_ned_m, vehicle.position_ned_m);
        assert_eq!(camera.velocity_ned_m_s, vehicle.velocity_ned_m_s);
    }

    #[test]
    fn a_gimbal_that_cannot_work_is_refused() {
        for (max, tau) in [(0.0, 0.005), (1.6, 0.005), (0.5, -1.0), (0.5, f64::NAN)] {
            let params = GimbalParams {
                max_joint_rad: max,
                time_constant_s: tau,
            };
            assert!(Gimbal::new(params).is_err(), "{params:?}");
        }
    }
}
