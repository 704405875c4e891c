//! Where the downward camera points: fixed to the body, or on a gimbal that holds it level.
//!
//! Seed 003 fixes the camera to the body and projects with the vehicle's roll and pitch
//! ([`CameraPose::downward`](crate::camera::CameraPose::downward)). In strong wind a
//! quadrotor leans further than such a camera's half field of view, so the ground straight
//! below, and everything on the upwind side, leaves the image. A stabilising gimbal holds the
//! camera looking down whatever the lean (within its joints' range) and reports its own
//! attitude (MAVLink GIMBAL_DEVICE_ATTITUDE_STATUS); the frame is then projected with that.
//!
//! Both mounts are described by one [`Attitude`]: the attitude of a body to which the camera
//! would be fixed as [`CameraPose::downward`](crate::camera::CameraPose::downward)
//! fixes it. On the body that is the vehicle's attitude; on a gimbal looking straight down it
//! is (0, 0, heading). MAVLink's gimbal frame differs: its null rotation looks forward, so a
//! camera looking down is pitched −90° ([`gimbal_quaternion`], [`camera_attitude_of_gimbal`]).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::projection::Attitude;

/// How the camera is mounted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraMount {
    /// Fixed to the body, looking along its down axis (seed 003).
    #[default]
    Body,
    /// On a stabilising gimbal that reports its attitude.
    Gimbal,
}

impl CameraMount {
    /// The attitude to project a frame with: the vehicle's for a body-fixed camera, the
    /// gimbal's for a gimballed one (`None` until the gimbal has reported: no frame can be
    /// placed on the ground then).
    pub fn camera_attitude(
        self,
        vehicle: &Attitude,
        gimbal: Option<&Attitude>,
    ) -> Option<Attitude> {
        match self {
            Self::Body => Some(*vehicle),
            Self::Gimbal => gimbal.copied(),
        }
    }
}

/// MAVLink's gimbal frame is the camera frame of [`Attitude`] pitched up by 90°: its x axis is
/// the optical axis.
fn gimbal_from_camera() -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -std::f64::consts::FRAC_PI_2)
}

/// The earth-frame quaternion (w, x, y, z) a gimbal reports for a camera at `camera`.
pub fn gimbal_quaternion(camera: &Attitude) -> [f64; 4] {
    let q = UnitQuaternion::from_euler_angles(camera.roll_rad, camera.pitch_rad, camera.yaw_rad)
        * gimbal_from_camera();
    [q.w, q.i, q.j, q.k]
}

/// The camera's [`Attitude`] from a gimbal's earth-frame quaternion (w, x, y, z); `None` for a
/// quaternion that is not finite or has no length (MAVLink's "unknown" is NaN).
pub fn camera_attitude_of_gimbal(q_wxyz: [f64; 4]) -> Option<Attitude> {
    let [w, x, y, z] = q_wxyz;
    let q = Quaternion::new(w, x, y, z);
    if !q_wxyz.iter().all(|c| c.is_finite()) || q.norm() < 1e-6 {
        return None;
    }
    let camera = UnitQuaternion::from_quaternion(q) * gimbal_from_camera().inverse();
    let (roll_rad, pitch_rad, yaw_rad) = camera.euler_angles();
    Some(Attitude::new(roll_rad, pitch_rad, yaw_rad))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraPose;

    /// A camera held level looking down is, in MAVLink's gimbal frame, pitched down by 90°
    /// and turned to the heading: its optical axis (the gimbal's x) points down, and the image
    /// top (the gimbal's −z) along the heading.
    #[test]
    fn a_level_downward_camera_is_a_gimbal_pitched_down() {
        let heading_rad = 0.7;
        let [w, x, y, z] = gimbal_quaternion(&Attitude::new(0.0, 0.0, heading_rad));
        let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
        let optical_axis = q * Vector3::x();
        assert!(
            (optical_axis - Vector3::z()).norm() < 1e-12,
            "{optical_axis}"
        );
        let image_top = q * -Vector3::z();
        let heading = Vector3::new(heading_rad.cos(), heading_rad.sin(), 0.0);
        assert!((image_top - heading).norm() < 1e-12, "{image_top}");
        // The same axes as the body-fixed camera's pose at that attitude.
        let pose = CameraPose::downward(Vector3::zeros(), 0.0, 0.0, heading_rad);
        let seen = pose.world_to_camera(&nalgebra::Point3::new(0.0, 0.0, 5.0));
        assert!(seen.x.abs() < 1e-9 && seen.y.abs() < 1e-9 && (seen.z - 5.0).abs() < 1e-9);
    }

    #[test]
    fn the_quaternion_round_trips_to_the_camera_attitude() {
        for (roll, pitch, yaw) in [(0.0, 0.0, 0.0), (0.1, -0.2, 2.5), (-0.6, 0.4, -3.0)] {
            let camera = Attitude::new(roll, pitch, yaw);
            let back = camera_attitude_of_gimbal(gimbal_quaternion(&camera)).unwrap();
            assert!((back.roll_rad - roll).abs() < 1e-9, "{back:?}");
            assert!((back.pitch_rad - pitch).abs() < 1e-9, "{back:?}");
            assert!((back.yaw_rad - yaw).abs() < 1e-9, "{back:?}");
        }
    }

    #[test]
    fn an_unknown_or_empty_quaternion_is_no_attitude() {
        assert_eq!(camera_attitude_of_gimbal([f64::NAN, 0.0, 0.0, 0.0]), None);
        assert_eq!(camera_attitude_of_gimbal([0.0; 4]), None);
    }

    #[test]
    fn the_mount_picks_the_attitude_to_project_with() {
        let vehicle = Attitude::new(0.5, 0.1, 1.0);
        let gimbal = Attitude::new(0.01, 0.0, 1.0);
        assert_eq!(
            CameraMount::Body.camera_attitude(&vehicle, Some(&gimbal)),
            Some(vehicle)
        );
        assert_eq!(
            CameraMount::Gimbal.camera_attitude(&vehicle, Some(&gimbal)),
            Some(gimbal)
        );
        assert_eq!(CameraMount::Gimbal.camera_attitude(&vehicle, None), None);
    }
}
