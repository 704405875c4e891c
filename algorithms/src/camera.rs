//! The camera models, the pinhole camera with radial-tangential (Brown–Conrady, OpenCV)
//! distortion and the Kannala–Brandt fisheye (both a [`CameraModel`]), and the camera's pose.
//!
//! Conventions, used by the renderer and every detector:
//! - Pixel coordinates (u, v): u to the right, v down, **integer values at pixel centres** (the OpenCV
//!   convention): pixel (col, row) covers [col − ½, col + ½] × [row − ½, row + ½].
//! - Camera frame: x right, y down, z forward along the optical axis, metres.
//! - World frame: NED (north, east, down) as PX4; the ground is a horizontal plane of constant down.
//! - [`CameraPose`] holds the camera **in the world**: `camera_to_world` maps camera-frame points into
//!   NED world points (its translation is the camera's NED position).

use nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3,
};
use thiserror::Error;

/// A camera that cannot be built as asked.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CameraError {
    #[error("the camera image is empty ({width_px}×{height_px} pixels)")]
    EmptyImage { width_px: usize, height_px: usize },
    #[error("the horizontal field of view must lie strictly between 0 and π rad, got {fov_rad}")]
    FieldOfView { fov_rad: f64 },
    #[error("focal lengths must be positive and finite, got fx = {fx_px} px, fy = {fy_px} px")]
    FocalLength { fx_px: f64, fy_px: f64 },
    #[error("the principal point ({cx_px}, {cy_px}) px is not finite")]
    PrincipalPoint { cx_px: f64, cy_px: f64 },
    #[error("distortion coefficients must be finite")]
    Distortion,
}

/// Radial-tangential lens distortion (OpenCV's k1, k2, p1, p2, k3), applied to normalised coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RadialTangential {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl RadialTangential {
    /// No distortion.
    pub const NONE: Self = Self {
        k1: 0.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
        k3: 0.0,
    };

    pub fn is_zero(&self) -> bool {
        *self == Self::NONE
    }

    /// Distorts ideal normalised coordinates (x/z, y/z) into distorted normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Inverts [`Self::distort`] by Gauss–Newton from the distorted point; converges in a few steps
    /// for any lens whose distortion is monotonic over the image, which a calibrated lens's is.
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        if self.is_zero() {
            return (xd, yd);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..30 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex * ex + ey * ey < 1e-26 {
                break;
            }
            let (a, b, c, d) = self.jacobian(x, y);
            let det = a * d - b * c;
            if det.abs() < 1e-12 || !det.is_finite() {
                // A degenerate Jacobian means we left the lens's valid region: keep the best so far.
                break;
            }
            x -= (d * ex - b * ey) / det;
            y -= (-c * ex + a * ey) / det;
        }
        (x, y)
    }

    /// ∂(xd, yd)/∂(x, y) as (∂xd/∂x, ∂xd/∂y, ∂yd/∂x, ∂yd/∂y).
    fn jacobian(&self, x: f64, y: f64) -> (f64, f64, f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d(radial)/d(r2)
        let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let dxd_dx = radial + 2.0 * x * x * dradial + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
        let dxd_dy = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dyd_dx = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let dyd_dy = radial + 2.0 * y * y * dradial + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
        (dxd_dx, dxd_dy, dyd_dx, dyd_dy)
    }
}

/// A pinhole camera with lens distortion; see the module docs for the pixel convention.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    pub width_px: usize,
    pub height_px: usize,
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    pub distortion: RadialTangential,
}

/// Checks the intrinsics every camera model shares: a non-empty image, positive finite focal
/// lengths and a finite principal point.
fn check_intrinsics(
    width_px: usize,
    height_px: usize,
    fx_px: f64,
    fy_px: f64,
    cx_px: f64,
    cy_px: f64,
) -> Result<(), CameraError> {
    if width_px == 0 || height_px == 0 {
        return Err(CameraError::EmptyImage {
            width_px,
            height_px,
        });
    }
    if !(fx_px.is_finite() && fy_px.is_finite() && fx_px > 0.0 && fy_px > 0.0) {
        return Err(CameraError::FocalLength { fx_px, fy_px });
    }
    if !(cx_px.is_finite() && cy_px.is_finite()) {
        return Err(CameraError::PrincipalPoint { cx_px, cy_px });
    }
    Ok(())
}

impl PinholeCamera {
    /// A camera from calibrated intrinsics; rejects empty images and non-finite or non-positive values.
    pub fn new(
        width_px: usize,
        height_px: usize,
        fx_px: f64,
        fy_px: f64,
        cx_px: f64,
        cy_px: f64,
        distortion: RadialTangential,
    ) -> Result<Self, CameraError> {
        check_intrinsics(width_px, height_px, fx_px, fy_px, cx_px, cy_px)?;
        let d = distortion;
        if ![d.k1, d.k2, d.p1, d.p2, d.k3].iter().all(|c| c.is_finite()) {
            return Err(CameraError::Distortion);
        }
        Ok(Self {
            width_px,
            height_px,
            fx_px,
            fy_px,
            cx_px,
            cy_px,
            distortion,
        })
    }

    /// An ideal camera (square pixels, centred principal point, no distortion) whose image spans
    /// `horizontal_fov_rad` from the left edge of the first column to the right edge of the last.
    pub fn from_fov(
        width_px: usize,
        height_px: usize,
        horizontal_fov_rad: f64,
    ) -> Result<Self, CameraError> {
        if !(horizontal_fov_rad > 0.0 && horizontal_fov_rad < std::f64::consts::PI) {
            return Err(CameraError::FieldOfView {
                fov_rad: horizontal_fov_rad,
            });
        }
        let focal_px = width_px as f64 / 2.0 / (horizontal_fov_rad / 2.0).tan();
        Self::new(
            width_px,
            height_px,
            focal_px,
            focal_px,
            // Integer coordinates are pixel centres, so the image centre is at (w − 1)/2.
            (width_px as f64 - 1.0) / 2.0,
            (height_px as f64 - 1.0) / 2.0,
            RadialTangential::NONE,
        )
    }

    /// The same camera with lens distortion.
    pub fn with_distortion(mut self, distortion: RadialTangential) -> Self {
        self.distortion = distortion;
        self
    }

    /// Pixel (u, v) of a point in the camera frame (metres); `None` when it is not in front of the
    /// camera. The pixel may lie outside the image: see [`Self::contains`].
    pub fn project(&self, point_camera: &Point3<f64>) -> Option<(f64, f64)> {
        // Written so that a NaN depth is refused too.
        if point_camera.z.is_nan() || point_camera.z <= 1e-9 {
            return None;
        }
        let (xd, yd) = self.distortion.distort(
            point_camera.x / point_camera.z,
            point_camera.y / point_camera.z,
        );
        Some((self.fx_px * xd + self.cx_px, self.fy_px * yd + self.cy_px))
    }

    /// Pixel (u, v) of a NED world point seen from `pose`; the truth the renderer draws.
    pub fn project_world(
        &self,
        pose: &CameraPose,
        point_world: &Point3<f64>,
    ) -> Option<(f64, f64)> {
        self.project(&pose.world_to_camera(point_world))
    }

    /// Ideal (undistorted) normalised coordinates (x/z, y/z) of pixel (u, v).
    pub fn normalized(&self, u_px: f64, v_px: f64) -> (f64, f64) {
        let xd = (u_px - self.cx_px) / self.fx_px;
        let yd = (v_px - self.cy_px) / self.fy_px;
        self.distortion.undistort(xd, yd)
    }

    /// Unit ray, in the camera frame, through pixel (u, v) (distortion removed iteratively).
    pub fn unproject(&self, u_px: f64, v_px: f64) -> Unit<Vector3<f64>> {
        let (x, y) = self.normalized(u_px, v_px);
        Unit::new_normalize(Vector3::new(x, y, 1.0))
    }

    /// Where the ray through pixel (u, v) meets the horizontal plane `down = plane_down_m` (NED);
    /// `None` when the ray runs parallel to it or away from it.
    pub fn pixel_to_plane(
        &self,
        pose: &CameraPose,
        u_px: f64,
        v_px: f64,
        plane_down_m: f64,
    ) -> Option<Point3<f64>> {
        let ray_world = pose.camera_to_world.rotation * self.unproject(u_px, v_px).into_inner();
        let origin = pose.position_ned_m();
        if ray_world.z.abs() < 1e-12 {
            return None;
        }
        let t = (plane_down_m - origin.z) / ray_world.z;
        (t > 0.0).then(|| Point3::from(origin + ray_world * t))
    }

    /// Whether (u, v) falls on the image (pixel centres run 0 ..= width − 1).
    pub fn contains(&self, u_px: f64, v_px: f64) -> bool {
        u_px >= -0.5
            && v_px >= -0.5
            && u_px < self.width_px as f64 - 0.5
            && v_px < self.height_px as f64 - 0.5
    }
}

/// A camera model as the projection needs it: pixels ↔ rays in the camera frame (x right, y down,
/// z forward; pixel centres at integer coordinates, as in the module docs).
pub trait CameraModel {
    fn width_px(&self) -> usize;
    fn height_px(&self) -> usize;
    /// Pixel (u, v) of a camera-frame point; `None` where the model cannot see it.
    fn project_point(&self, point_camera: &Point3<f64>) -> Option<(f64, f64)>;
    /// Unit ray through pixel (u, v); `None` where the model has no inverse there.
    fn unproject_pixel(&self, u_px: f64, v_px: f64) -> Option<Unit<Vector3<f64>>>;
}

impl CameraModel for PinholeCamera {
    fn width_px(&self) -> usize {
        self.width_px
    }
    fn height_px(&self) -> usize {
        self.height_px
    }
    fn project_point(&self, point_camera: &Point3<f64>) -> Option<(f64, f64)> {
        self.project(point_camera)
    }
    fn unproject_pixel(&self, u_px: f64, v_px: f64) -> Option<Unit<Vector3<f64>>> {
        Some(self.unproject(u_px, v_px))
    }
}

/// A fisheye camera, Kannala–Brandt / OpenCV `fisheye` model: the image radius grows with the
/// angle θ off the axis, θ_d = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸); all k = 0 is equidistant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FisheyeCamera {
    pub width_px: usize,
    pub height_px: usize,
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    pub k: [f64; 4],
}

impl FisheyeCamera {
    pub fn new(
        width_px: usize,
        height_px: usize,
        fx_px: f64,
        fy_px: f64,
        cx_px: f64,
        cy_px: f64,
        k: [f64; 4],
    ) -> Result<Self, CameraError> {
        check_intrinsics(width_px, height_px, fx_px, fy_px, cx_px, cy_px)?;
        if !k.iter().all(|c| c.is_finite()) {
            return Err(CameraError::Distortion);
        }
        Ok(Self {
            width_px,
            height_px,
            fx_px,
            fy_px,
            cx_px,
            cy_px,
            k,
        })
    }

    fn distorted_angle(&self, theta_rad: f64) -> f64 {
        let t2 = theta_rad * theta_rad;
        let [k1, k2, k3, k4] = self.k;
        theta_rad * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    }

    fn distorted_angle_slope(&self, theta_rad: f64) -> f64 {
        let t2 = theta_rad * theta_rad;
        let [k1, k2, k3, k4] = self.k;
        1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    }
}

impl CameraModel for FisheyeCamera {
    fn width_px(&self) -> usize {
        self.width_px
    }
    fn height_px(&self) -> usize {
        self.height_px
    }
    fn project_point(&self, point_camera: &Point3<f64>) -> Option<(f64, f64)> {
        let radial = point_camera.x.hypot(point_camera.y);
        // θ from atan2 so rays beyond 90° (a >180° lens) still project.
        let theta_rad = radial.atan2(point_camera.z);
        if !theta_rad.is_finite() || point_camera.coords.norm() < 1e-12 {
            return None;
        }
        let theta_d = self.distorted_angle(theta_rad);
        let (cos_phi, sin_phi) = if radial > 0.0 {
            (point_camera.x / radial, point_camera.y / radial)
        } else {
            (1.0, 0.0)
        };
        Some((
            self.cx_px + self.fx_px * theta_d * cos_phi,
            self.cy_px + self.fy_px * theta_d * sin_phi,
        ))
    }
    fn unproject_pixel(&self, u_px: f64, v_px: f64) -> Option<Unit<Vector3<f64>>> {
        let (xd, yd) = (
            (u_px - self.cx_px) / self.fx_px,
            (v_px - self.cy_px) / self.fy_px,
        );
        let theta_d = xd.hypot(yd);
        if !theta_d.is_finite() {
            return None;
        }
        // Newton on θ_d(θ) = target from θ = θ_d; the lens polynomial is monotonic over a
        // calibrated image, so a non-positive slope means the pixel is outside the valid region.
        let mut theta_rad = theta_d;
        for _ in 0..30 {
            let slope = self.distorted_angle_slope(theta_rad);
            if slope <= 1e-9 {
                return None;
            }
            let step = (self.distorted_angle(theta_rad) - theta_d) / slope;
            theta_rad -= step;
            if step.abs() < 1e-15 {
                break;
            }
        }
        if !(0.0..std::f64::consts::PI).contains(&theta_rad) {
            return None;
        }
        let (cos_phi, sin_phi) = if theta_d > 0.0 {
            (xd / theta_d, yd / theta_d)
        } else {
            (1.0, 0.0)
        };
        let (s, c) = theta_rad.sin_cos();
        Some(Unit::new_normalize(Vector3::new(
            s * cos_phi,
            s * sin_phi,
            c,
        )))
    }
}

/// Where the camera is and where it looks: `camera_to_world` maps camera-frame points (x right,
/// y down, z forward) to NED world points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    pub camera_to_world: Isometry3<f64>,
}

impl CameraPose {
    pub fn from_camera_to_world(camera_to_world: Isometry3<f64>) -> Self {
        Self { camera_to_world }
    }

    /// A downward-looking camera fixed to a vehicle whose body (FRD) has the PX4 attitude roll,
    /// pitch, yaw (ZYX Euler) at NED position `position_ned_m`. The optical axis is the body's down
    /// axis and the image top points to the body's front, so with zero attitude image right is
    /// east and image up is north.
    pub fn downward(
        position_ned_m: Vector3<f64>,
        roll_rad: f64,
        pitch_rad: f64,
        yaw_rad: f64,
    ) -> Self {
        let body_to_world = Rotation3::from_euler_angles(roll_rad, pitch_rad, yaw_rad);
        #[rustfmt::skip]
        let camera_to_body = Rotation3::from_matrix_unchecked(Matrix3::new(
            0.0, -1.0, 0.0,
            1.0,  0.0, 0.0,
            0.0,  0.0, 1.0,
        ));
        let rotation = UnitQuaternion::from_rotation_matrix(&(body_to_world * camera_to_body));
        Self {
            camera_to_world: Isometry3::from_parts(Translation3::from(position_ned_m), rotation),
        }
    }

    /// The camera's NED position, metres.
    pub fn position_ned_m(&self) -> Vector3<f64> {
        self.camera_to_world.translation.vector
    }

    /// A NED world point in the camera frame.
    pub fn world_to_camera(&self, point_world: &Point3<f64>) -> Point3<f64> {
        self.camera_to_world.inverse_transform_point(point_world)
    }

    /// A camera-frame point in the NED world.
    pub fn camera_to_world_point(&self, point_camera: &Point3<f64>) -> Point3<f64> {
        self.camera_to_world.transform_point(point_camera)
    }

    /// Angle between the optical axis and straight down, radians.
    pub fn tilt_rad(&self) -> f64 {
        let axis = self.camera_to_world.rotation * Vector3::z();
        axis.z.clamp(-1.0, 1.0).acos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens() -> RadialTangential {
        RadialTangential {
            k1: -0.28,
            k2: 0.07,
            p1: 0.0012,
            p2: -0.0008,
            k3: -0.01,
        }
    }

    #[test]
    fn from_fov_puts_the_image_edges_at_half_the_field_of_view() {
        let cam = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        assert!((cam.cx_px - 319.5).abs() < 1e-12 && (cam.cy_px - 239.5).abs() < 1e-12);
        // The left edge of pixel 0 is at u = −0.5, 30° left of the axis.
        let ray = cam.unproject(-0.5, cam.cy_px);
        assert!((ray.x.atan2(ray.z) + 30f64.to_radians()).abs() < 1e-12);
    }

    #[test]
    fn distortion_matches_a_hand_computed_case() {
        // x = 0.2, y = −0.1: r² = 0.05, radial = 1 − 0.28·0.05 + 0.07·0.0025 − 0.01·0.000125
        //   = 0.98617375; xd = 0.2·radial + 2·0.0012·0.2·(−0.1) − 0.0008·(0.05 + 0.08)
        //   = 0.19723475 − 0.000048 − 0.000104 = 0.19708275;
        // yd = −0.1·radial + 0.0012·(0.05 + 0.02) + 2·(−0.0008)·0.2·(−0.1)
        //   = −0.098617375 + 0.000084 + 0.000032 = −0.098501375.
        let (xd, yd) = lens().distort(0.2, -0.1);
        assert!((xd - 0.19708275).abs() < 1e-12, "{xd}");
        assert!((yd + 0.098501375).abs() < 1e-12, "{yd}");
        let cam = PinholeCamera::new(640, 480, 500.0, 510.0, 320.0, 240.0, lens()).unwrap();
        let (u, v) = cam.project(&Point3::new(0.4, -0.2, 2.0)).unwrap();
        assert!((u - (320.0 + 500.0 * 0.19708275)).abs() < 1e-9);
        assert!((v - (240.0 - 510.0 * 0.098501375)).abs() < 1e-9);
    }

    #[test]
    fn project_and_unproject_round_trip_with_distortion() {
        let cam = PinholeCamera::new(640, 480, 520.0, 515.0, 322.3, 236.9, lens()).unwrap();
        for row in 0..=12 {
            for col in 0..=16 {
                let (u, v) = (col as f64 * 40.0 - 0.5, row as f64 * 40.0 - 0.5);
                let ray = cam.unproject(u, v);
                assert!((ray.norm() - 1.0).abs() < 1e-12);
                let (u2, v2) = cam.project(&Point3::from(ray.into_inner() * 7.0)).unwrap();
                assert!(
                    (u2 - u).abs() < 1e-8 && (v2 - v).abs() < 1e-8,
                    "{u},{v} → {u2},{v2}"
                );
            }
        }
    }

    #[test]
    fn points_behind_the_camera_do_not_project() {
        let cam = PinholeCamera::from_fov(640, 480, 1.0).unwrap();
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        assert!(cam.project(&Point3::new(1.0, 0.0, 0.0)).is_none());
    }

    #[test]
    fn bad_intrinsics_are_named_errors() {
        assert!(matches!(
            PinholeCamera::from_fov(0, 480, 1.0),
            Err(CameraError::EmptyImage { .. })
        ));
        assert!(matches!(
            PinholeCamera::from_fov(640, 480, 3.2),
            Err(CameraError::FieldOfView { .. })
        ));
        assert!(matches!(
            PinholeCamera::new(640, 480, -1.0, 1.0, 0.0, 0.0, RadialTangential::NONE),
            Err(CameraError::FocalLength { .. })
        ));
    }

    #[test]
    fn a_level_downward_camera_sees_north_up_and_east_right() {
        let cam = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -10.0), 0.0, 0.0, 0.0);
        let (u0, v0) = cam
            .project_world(&pose, &Point3::new(0.0, 0.0, 0.0))
            .unwrap();
        assert!((u0 - cam.cx_px).abs() < 1e-9 && (v0 - cam.cy_px).abs() < 1e-9);
        let (u, v) = cam
            .project_world(&pose, &Point3::new(1.0, 0.0, 0.0))
            .unwrap();
        assert!(v < v0 && (u - u0).abs() < 1e-9, "north is up");
        let (u, v) = cam
            .project_world(&pose, &Point3::new(0.0, 1.0, 0.0))
            .unwrap();
        assert!(u > u0 && (v - v0).abs() < 1e-9, "east is right");
        // Yawing the vehicle 90° to the east puts east at the top of the image.
        let pose =
            CameraPose::downward(Vector3::new(0.0, 0.0, -10.0), 0.0, 0.0, 90f64.to_radians());
        let (u, v) = cam
            .project_world(&pose, &Point3::new(0.0, 1.0, 0.0))
            .unwrap();
        assert!(v < v0 && (u - u0).abs() < 1e-9);
        // Nose up (positive pitch) turns the optical axis ahead (north), so the ground point right
        // below the vehicle now lies behind the axis: lower in the image.
        let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -10.0), 0.0, 0.2, 0.0);
        let (_, v) = cam
            .project_world(&pose, &Point3::new(0.0, 0.0, 0.0))
            .unwrap();
        assert!(v > v0);
        assert!((pose.tilt_rad() - 0.2).abs() < 1e-12);
    }

    #[test]
    fn pixels_meet_the_ground_where_they_project_from() {
        let cam = PinholeCamera::from_fov(640, 480, 1.2)
            .unwrap()
            .with_distortion(lens());
        let pose = CameraPose::downward(Vector3::new(3.0, -2.0, -12.0), 0.1, -0.15, 2.0);
        let ground = cam.pixel_to_plane(&pose, 100.0, 400.0, 0.0).unwrap();
        assert!(ground.z.abs() < 1e-9);
        let (u, v) = cam.project_world(&pose, &ground).unwrap();
        assert!((u - 100.0).abs() < 1e-7 && (v - 400.0).abs() < 1e-7);
    }

    // The fisheye, checked through the projection it serves.
    use crate::estimation::projection::{pad_relative_to_uav_ned_m, Attitude, ProjectionError};

    const MM: f64 = 1e-3;

    fn close(a: &Vector3<f64>, b: &Vector3<f64>, tol_m: f64) -> bool {
        (a - b).norm() < tol_m
    }

    fn fisheye() -> FisheyeCamera {
        FisheyeCamera::new(
            1280,
            960,
            330.0,
            332.0,
            641.2,
            478.5,
            [0.02, -0.004, 0.001, -0.0002],
        )
        .unwrap()
    }

    #[test]
    fn equidistant_fisheye_puts_angle_times_focal_length_on_the_image() {
        let cam = FisheyeCamera::new(1280, 960, 330.0, 330.0, 640.0, 480.0, [0.0; 4]).unwrap();
        let h = 10.0;
        // Nadir, a pixel θ·f to the right of centre looks θ off the axis: east = h·tan θ.
        for theta in [0.0f64, 0.3, 0.9, 1.3] {
            let got = pad_relative_to_uav_ned_m(
                &cam,
                &Attitude::default(),
                h,
                640.0 + 330.0 * theta,
                480.0,
            )
            .unwrap();
            let want = Vector3::new(0.0, h * theta.tan(), h);
            assert!(close(&got, &want, MM), "{got} vs {want}");
        }
        // Beyond 90° off a nadir axis the ray looks up: no ground.
        assert!(matches!(
            pad_relative_to_uav_ned_m(&cam, &Attitude::default(), h, 640.0 + 330.0 * 1.7, 480.0),
            Err(ProjectionError::AboveHorizon { .. })
        ));
    }

    #[test]
    fn fisheye_recovers_known_ground_points() {
        let cam = fisheye();
        for attitude in [
            Attitude::new(0.0, 0.0, 0.4),
            Attitude::new(0.15, -0.1, -1.9),
            Attitude::new(-0.05, 0.25, 3.0),
        ] {
            let uav_ned_m = Vector3::new(2.0, 1.0, -10.0);
            let pose = CameraPose::downward(
                uav_ned_m,
                attitude.roll_rad,
                attitude.pitch_rad,
                attitude.yaw_rad,
            );
            for (dn, de) in [(0.0, 0.0), (4.0, -6.0), (-9.0, 3.0), (12.0, 12.0)] {
                let pad = Point3::new(uav_ned_m.x + dn, uav_ned_m.y + de, 0.0);
                let (u, v) = cam.project_point(&pose.world_to_camera(&pad)).unwrap();
                assert!(
                    (-0.5..1279.5).contains(&u) && (-0.5..959.5).contains(&v),
                    "{u}, {v}"
                );
                let got = pad_relative_to_uav_ned_m(&cam, &attitude, 10.0, u, v).unwrap();
                let want = pad.coords - uav_ned_m;
                assert!(close(&got, &want, MM), "{attitude:?}: {got} vs {want}");
            }
        }
        assert!(matches!(
            FisheyeCamera::new(640, 480, 0.0, 1.0, 0.0, 0.0, [0.0; 4]),
            Err(CameraError::FocalLength { .. })
        ));
        assert!(matches!(
            FisheyeCamera::new(640, 480, 1.0, 1.0, 0.0, 0.0, [f64::NAN, 0.0, 0.0, 0.0]),
            Err(CameraError::Distortion)
        ));
    }
}
