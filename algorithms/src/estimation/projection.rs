//! Pixel → relative position: where the landing pad is, relative to the UAV, in NED.
//!
//! The seed (003, §IV-A steps 1–7) builds the camera's pose from roll and pitch, projects the image
//! corners onto the ground at the UAV's altitude, fits the image-to-ground homography and rotates by
//! yaw. For a planar ground that homography is exactly the map "ray through the pixel ∩ ground
//! plane", so we intersect the ray directly: the same result, without the corner fit, and it stays
//! exact with lens distortion (a homography cannot model distortion) and with a fisheye lens
//! ([`FisheyeCamera`](crate::camera::FisheyeCamera), Kannala–Brandt, for a wide-FOV camera like
//! seed 000's). Step 8 (an ArUco id's known offset from the pad centre) is
//! [`pad_centre_from_marker`].

use nalgebra::{Point3, Vector2, Vector3};
use thiserror::Error;

use crate::camera::{CameraModel, CameraPose};

/// Why a pixel could not be turned into a relative position.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ProjectionError {
    #[error("the altitude above the pad must be positive and finite, got {altitude_m} m")]
    Altitude { altitude_m: f64 },
    #[error(
        "the attitude must be finite, got roll {roll_rad}, pitch {pitch_rad}, yaw {yaw_rad} rad"
    )]
    Attitude {
        roll_rad: f64,
        pitch_rad: f64,
        yaw_rad: f64,
    },
    #[error("the pixel ({u_px}, {v_px}) is not finite")]
    Pixel { u_px: f64, v_px: f64 },
    #[error(
        "the ray through pixel ({u_px}, {v_px}) does not meet the pad plane (it points at or above \
         the horizon); check the attitude and the camera mounting"
    )]
    AboveHorizon { u_px: f64, v_px: f64 },
    #[error(
        "a fix's noise needs a standard deviation at the pad ≥ 0 m and an angle ≥ 0 rad, finite \
         and not both zero; got {std_at_pad_m} m and {angle_std_rad} rad"
    )]
    FixNoise {
        std_at_pad_m: f64,
        angle_std_rad: f64,
    },
}

/// The vehicle's attitude as PX4 reports it: ZYX Euler angles of the FRD body in NED.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Attitude {
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub yaw_rad: f64,
}

impl Attitude {
    pub fn new(roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> Self {
        Self {
            roll_rad,
            pitch_rad,
            yaw_rad,
        }
    }

    /// The body FRD → NED rotation (ZYX: yaw, then pitch, then roll).
    pub fn body_to_ned(&self) -> nalgebra::Rotation3<f64> {
        nalgebra::Rotation3::from_euler_angles(self.roll_rad, self.pitch_rad, self.yaw_rad)
    }

    /// The cosine of the body's z axis from the vertical (ZYX Euler: cos roll · cos pitch):
    /// what a range along that axis is scaled by to give a height.
    pub fn cos_tilt(&self) -> f64 {
        self.roll_rad.cos() * self.pitch_rad.cos()
    }

    /// The body's z axis from the vertical.
    pub fn tilt_rad(&self) -> f64 {
        self.cos_tilt().clamp(-1.0, 1.0).acos()
    }

    /// A NED vector in the body's FRD frame.
    pub fn ned_to_body_frd(&self, ned: &Vector3<f64>) -> Vector3<f64> {
        self.body_to_ned().inverse() * ned
    }

    fn check(&self) -> Result<(), ProjectionError> {
        if [self.roll_rad, self.pitch_rad, self.yaw_rad]
            .iter()
            .all(|a| a.is_finite())
        {
            Ok(())
        } else {
            Err(ProjectionError::Attitude {
                roll_rad: self.roll_rad,
                pitch_rad: self.pitch_rad,
                yaw_rad: self.yaw_rad,
            })
        }
    }
}

/// The NED position (north, east, down), metres, of the ground point seen at pixel (u, v),
/// relative to the camera, for a downward camera on a vehicle at `attitude` that is
/// `altitude_above_pad_m` above the pad's plane (see [`CameraPose::downward`] for the mounting).
/// The down component equals the altitude.
pub fn pad_relative_to_uav_ned_m(
    camera: &impl CameraModel,
    attitude: &Attitude,
    altitude_above_pad_m: f64,
    u_px: f64,
    v_px: f64,
) -> Result<Vector3<f64>, ProjectionError> {
    if !(altitude_above_pad_m.is_finite() && altitude_above_pad_m > 0.0) {
        return Err(ProjectionError::Altitude {
            altitude_m: altitude_above_pad_m,
        });
    }
    attitude.check()?;
    if !(u_px.is_finite() && v_px.is_finite()) {
        return Err(ProjectionError::Pixel { u_px, v_px });
    }
    // Only the camera's orientation matters: the ray from the camera, scaled until it has
    // dropped by the altitude, is the relative position.
    let pose = CameraPose::downward(
        Vector3::zeros(),
        attitude.roll_rad,
        attitude.pitch_rad,
        attitude.yaw_rad,
    );
    let above = ProjectionError::AboveHorizon { u_px, v_px };
    let ray_camera = camera.unproject_pixel(u_px, v_px).ok_or(above.clone())?;
    let ray_ned = pose.camera_to_world.rotation * ray_camera.into_inner();
    // Rays within ~0.06° of the horizon would hit kilometres away: no use for landing.
    if ray_ned.z < 1e-3 {
        return Err(above);
    }
    let relative = ray_ned * (altitude_above_pad_m / ray_ned.z);
    Ok(relative)
}

/// The yaw (from north towards east) of the line on the pad's plane that the image shows through
/// pixel (u, v) along `orientation_rad` (from the image's u axis towards v), for the camera of
/// [`pad_relative_to_uav_ned_m`]: a line in an undistorted image is a line on the plane, so two of
/// its points either side of (u, v), projected, give its direction.
pub fn ground_line_yaw_rad(
    camera: &impl CameraModel,
    attitude: &Attitude,
    altitude_above_pad_m: f64,
    [u_px, v_px]: [f64; 2],
    orientation_rad: f64,
) -> Result<f64, ProjectionError> {
    // Far enough apart that a pixel's rounding moves the yaw by little, near enough that both
    // points stay on the pad's plane in view.
    const HALF_SPAN_PX: f64 = 20.0;
    let (sin, cos) = orientation_rad.sin_cos();
    let at = |k: f64| {
        pad_relative_to_uav_ned_m(
            camera,
            attitude,
            altitude_above_pad_m,
            u_px + k * HALF_SPAN_PX * cos,
            v_px + k * HALF_SPAN_PX * sin,
        )
    };
    let direction = at(1.0)? - at(-1.0)?;
    Ok(direction.y.atan2(direction.x))
}

/// How far a vision fix from [`pad_relative_to_uav_ned_m`] may be off: a floor (the pad's own
/// sway, the detector's pixel error at close range) plus an angular error that grows with the
/// height (the attitude's noise and timing, the frame's latency and blur). A fix from 7.5 m is
/// decimetres off, one from 1 m a few centimetres: filters that weigh them alike lag near the
/// ground, where the landing needs them most.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixNoise {
    pub std_at_pad_m: f64,
    pub angle_std_rad: f64,
}

impl FixNoise {
    /// Both parts must be finite and ≥ 0, and not both zero.
    pub fn new(std_at_pad_m: f64, angle_std_rad: f64) -> Result<Self, ProjectionError> {
        let valid = |v: f64| v.is_finite() && v >= 0.0;
        if !(valid(std_at_pad_m) && valid(angle_std_rad) && std_at_pad_m + angle_std_rad > 0.0) {
            return Err(ProjectionError::FixNoise {
                std_at_pad_m,
                angle_std_rad,
            });
        }
        Ok(Self {
            std_at_pad_m,
            angle_std_rad,
        })
    }

    /// The variance of a fix along each horizontal axis taken `height_m` above the pad, m².
    pub fn variance_m2(&self, height_m: f64) -> f64 {
        let angular_m = height_m.max(0.0) * self.angle_std_rad.tan();
        self.std_at_pad_m.powi(2) + angular_m.powi(2)
    }
}

/// The ground footprint of the image: NED positions relative to the camera of the four image
/// corners (outer pixel edges, clockwise from the top left), as in the seed's step 3. Fails when a
/// corner looks at or above the horizon.
pub fn image_footprint_ned_m(
    camera: &impl CameraModel,
    attitude: &Attitude,
    altitude_above_pad_m: f64,
) -> Result<[Vector3<f64>; 4], ProjectionError> {
    let (right, bottom) = (
        camera.width_px() as f64 - 0.5,
        camera.height_px() as f64 - 0.5,
    );
    let corners = [(-0.5, -0.5), (right, -0.5), (right, bottom), (-0.5, bottom)];
    let mut footprint = [Vector3::zeros(); 4];
    for (slot, (u, v)) in footprint.iter_mut().zip(corners) {
        *slot = pad_relative_to_uav_ned_m(camera, attitude, altitude_above_pad_m, u, v)?;
    }
    Ok(footprint)
}

/// Where the pad must lie, relative to a vehicle `height_m` above it, for the camera to see it
/// inside the image shrunk by `margin_fraction` of its half-size on each side: the point nearest
/// straight below that does (pad − UAV, north and east, metres). Zero while straight below is
/// in that part of the image; in strong wind a quadrotor leans by more than a fixed downward
/// camera's half field of view (28° in 12 m/s for an Iris-class vehicle, 23° half of a 60°
/// 4:3 camera's short side), and the pad under it is out of sight. `None` where the camera
/// cannot see below the vehicle at all (a lean past the horizon).
pub fn pad_in_view_offset_ne_m(
    camera: &impl CameraModel,
    attitude: &Attitude,
    height_m: f64,
    margin_fraction: f64,
) -> Option<Vector2<f64>> {
    if attitude.check().is_err() || !(height_m.is_finite() && height_m > 0.0) {
        return None;
    }
    let pose = CameraPose::downward(
        Vector3::zeros(),
        attitude.roll_rad,
        attitude.pitch_rad,
        attitude.yaw_rad,
    );
    let below = pose.world_to_camera(&Point3::new(0.0, 0.0, height_m));
    let (u_px, v_px) = camera.project_point(&below)?;
    let keep = (1.0 - margin_fraction).clamp(0.0, 1.0);
    let (half_w, half_h) = (
        camera.width_px() as f64 / 2.0,
        camera.height_px() as f64 / 2.0,
    );
    let (centre_u, centre_v) = (half_w - 0.5, half_h - 0.5);
    let clamped_u = u_px.clamp(centre_u - keep * half_w, centre_u + keep * half_w);
    let clamped_v = v_px.clamp(centre_v - keep * half_h, centre_v + keep * half_h);
    if clamped_u == u_px && clamped_v == v_px {
        return Some(Vector2::zeros());
    }
    pad_relative_to_uav_ned_m(camera, attitude, height_m, clamped_u, clamped_v)
        .ok()
        .map(|relative| relative.xy())
}

/// The seed's step 8: the pad centre from one marker of the pad whose centre lies at
/// `marker_offset_frd_m` = (forward, right) metres from the pad centre in the pad's own frame,
/// the pad heading `pad_yaw_rad` from north.
pub fn pad_centre_from_marker(
    marker_relative_ned_m: &Vector3<f64>,
    marker_offset_frd_m: &Vector2<f64>,
    pad_yaw_rad: f64,
) -> Vector3<f64> {
    let (s, c) = pad_yaw_rad.sin_cos();
    let offset_north_m = c * marker_offset_frd_m.x - s * marker_offset_frd_m.y;
    let offset_east_m = s * marker_offset_frd_m.x + c * marker_offset_frd_m.y;
    marker_relative_ned_m - Vector3::new(offset_north_m, offset_east_m, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tilt is the angle between the body's z axis, rotated into NED, and down; yaw does
    /// not change it.
    #[test]
    fn the_tilt_is_the_body_axis_angle_from_down() {
        for (roll_deg, pitch_deg, yaw_deg) in
            [(0.0, 0.0, 30.0), (20.0, 0.0, 0.0), (25.0, -35.0, 120.0)]
        {
            let attitude = Attitude::new(
                f64::to_radians(roll_deg),
                f64::to_radians(pitch_deg),
                f64::to_radians(yaw_deg),
            );
            let body_down = attitude.body_to_ned() * Vector3::z();
            let expected_rad = body_down.angle(&Vector3::z());
            assert!(
                (attitude.tilt_rad() - expected_rad).abs() < 1e-12,
                "{roll_deg} {pitch_deg}"
            );
        }
        let pure_roll = Attitude::new(f64::to_radians(20.0), 0.0, 1.0);
        assert!((pure_roll.tilt_rad().to_degrees() - 20.0).abs() < 1e-9);
    }

    /// A line drawn on the ground, projected into the image by the camera model, comes back
    /// with its yaw, whatever the vehicle's attitude.
    #[test]
    fn a_ground_line_seen_in_the_image_comes_back_with_its_yaw() {
        let camera =
            crate::camera::PinholeCamera::from_fov(640, 480, 80f64.to_radians()).expect("a camera");
        for (roll_deg, pitch_deg, yaw_deg) in
            [(0.0, 0.0, 0.0), (12.0, -8.0, 40.0), (-20.0, 15.0, -150.0)]
        {
            let (roll, pitch, yaw) = (
                f64::to_radians(roll_deg),
                f64::to_radians(pitch_deg),
                f64::to_radians(yaw_deg),
            );
            let altitude_m = 4.0;
            let pose = CameraPose::downward(Vector3::zeros(), roll, pitch, yaw);
            let attitude = Attitude::new(roll, pitch, yaw);
            // A ground point in view: straight below the camera's axis, near enough.
            let centre = pose.camera_to_world.rotation * Vector3::z();
            let centre = centre * (altitude_m / centre.z);
            for line_yaw_deg in [0.0, 35.0, 90.0, -120.0, 179.0] {
                let line_yaw = f64::to_radians(line_yaw_deg);
                let along = Vector3::new(line_yaw.cos(), line_yaw.sin(), 0.0) * 0.3;
                let pixel = |p: Vector3<f64>| {
                    camera
                        .project_world(&pose, &Point3::from(p))
                        .expect("in front of the camera")
                };
                let (u0, v0) = pixel(centre);
                let (u1, v1) = pixel(centre + along);
                let orientation = (v1 - v0).atan2(u1 - u0);
                let found =
                    ground_line_yaw_rad(&camera, &attitude, altitude_m, [u0, v0], orientation)
                        .unwrap();
                let error_deg = (found - line_yaw)
                    .sin()
                    .atan2((found - line_yaw).cos())
                    .to_degrees();
                assert!(
                    error_deg.abs() < 0.1,
                    "attitude {roll_deg}/{pitch_deg}/{yaw_deg}°, line {line_yaw_deg}°: {error_deg}°"
                );
            }
        }
    }

    /// The angular part is what a camera tilted by the angle std sees: the fix of a pixel
    /// straight below, projected with the attitude off by that angle, lands that far away.
    #[test]
    fn fix_noise_grows_with_height_as_a_tilt_error_does() {
        let angle_rad = 1.7f64.to_radians();
        let noise = FixNoise::new(0.01, angle_rad).unwrap();
        let camera = crate::camera::PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let (cx, cy) = (319.5, 239.5);
        for height_m in [1.0, 7.5] {
            let level =
                pad_relative_to_uav_ned_m(&camera, &Attitude::new(0.0, 0.0, 0.0), height_m, cx, cy)
                    .unwrap();
            let tilted = pad_relative_to_uav_ned_m(
                &camera,
                &Attitude::new(angle_rad, 0.0, 0.0),
                height_m,
                cx,
                cy,
            )
            .unwrap();
            let shift_m = (tilted - level).xy().norm();
            let expected_m2 = 0.01f64.powi(2) + shift_m.powi(2);
            assert!(
                (noise.variance_m2(height_m) - expected_m2).abs() < 1e-9,
                "{height_m} m: {} vs {expected_m2}",
                noise.variance_m2(height_m)
            );
        }
        // 7.5 m is decimetres, 1 m centimetres; below the pad counts as on it.
        assert!(noise.variance_m2(7.5).sqrt() > 0.2);
        assert!(noise.variance_m2(1.0).sqrt() < 0.035);
        assert_eq!(noise.variance_m2(-1.0), 0.01f64.powi(2));
        for (at_pad, angle) in [(-0.1, 0.01), (0.01, f64::NAN), (0.0, 0.0)] {
            assert!(matches!(
                FixNoise::new(at_pad, angle),
                Err(ProjectionError::FixNoise { .. })
            ));
        }
    }

    #[test]
    fn ned_to_body_frd_matches_the_elementary_rotations() {
        // Yaw 90°: north is the body's left (−y), east its front (+x).
        let yawed = Attitude::new(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let north = yawed.ned_to_body_frd(&Vector3::new(1.0, 0.0, 0.0));
        assert!(
            (north - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-12,
            "{north}"
        );
        // Nose up 30°: the down axis tilts forward, so the point straight below lies behind (−x).
        let pitch = 30f64.to_radians();
        let pitched = Attitude::new(0.0, pitch, 0.0);
        let below = pitched.ned_to_body_frd(&Vector3::new(0.0, 0.0, 1.0));
        assert!((below - Vector3::new(-pitch.sin(), 0.0, pitch.cos())).norm() < 1e-12);
        // Right wing down 20°: the point straight below lies to the right (+y).
        let roll = 20f64.to_radians();
        let rolled = Attitude::new(roll, 0.0, 0.0);
        let below = rolled.ned_to_body_frd(&Vector3::new(0.0, 0.0, 1.0));
        assert!(
            (below - Vector3::new(0.0, roll.sin(), roll.cos())).norm() < 1e-12,
            "{below}"
        );
    }
    use crate::camera::{PinholeCamera, RadialTangential};
    use crate::vision::render::true_pixel;
    use nalgebra::{Matrix3, Point3};

    const MM: f64 = 1e-3;

    fn camera() -> PinholeCamera {
        PinholeCamera::new(640, 480, 500.0, 505.0, 321.0, 238.0, RadialTangential::NONE).unwrap()
    }

    fn close(a: &Vector3<f64>, b: &Vector3<f64>, tol_m: f64) -> bool {
        (a - b).norm() < tol_m
    }

    #[test]
    fn nadir_camera_scales_pixels_by_altitude_over_focal_length() {
        let cam = camera();
        let h = 10.0;
        // 100 px right, 50 px up: east = 100/fx·h, north = 50/fy·h.
        let got = pad_relative_to_uav_ned_m(
            &cam,
            &Attitude::default(),
            h,
            cam.cx_px + 100.0,
            cam.cy_px - 50.0,
        )
        .unwrap();
        let want = Vector3::new(50.0 / 505.0 * h, 100.0 / 500.0 * h, h);
        assert!(close(&got, &want, MM), "{got} vs {want}");
    }

    #[test]
    fn tilted_camera_adds_the_tilt_to_the_ray_angle() {
        let cam = camera();
        let h = 10.0;
        let pitch = 0.25;
        let alpha = 0.1f64;
        // A pixel alpha above the image centre looks alpha further forward: north = h·tan(θ + α).
        let v = cam.cy_px - cam.fy_px * alpha.tan();
        let got = pad_relative_to_uav_ned_m(&cam, &Attitude::new(0.0, pitch, 0.0), h, cam.cx_px, v)
            .unwrap();
        let want = Vector3::new(h * (pitch + alpha).tan(), 0.0, h);
        assert!(close(&got, &want, MM), "{got} vs {want}");
        // Rolling right swings the optical axis to the left (west): east = −h·tan φ.
        let roll = -0.2;
        let got = pad_relative_to_uav_ned_m(
            &cam,
            &Attitude::new(roll, 0.0, 0.0),
            h,
            cam.cx_px,
            cam.cy_px,
        )
        .unwrap();
        let want = Vector3::new(0.0, -h * roll.tan(), h);
        assert!(close(&got, &want, MM), "{got} vs {want}");
    }

    #[test]
    fn yawed_vehicle_rotates_the_body_offset_into_ned() {
        let cam = camera();
        let h = 10.0;
        let yaw = 2.3f64;
        let (du, dv) = (80.0, 60.0);
        let got = pad_relative_to_uav_ned_m(
            &cam,
            &Attitude::new(0.0, 0.0, yaw),
            h,
            cam.cx_px + du,
            cam.cy_px + dv,
        )
        .unwrap();
        // Body frame: forward = −dv/fy·h, right = du/fx·h; then rotate by yaw.
        let (f, r) = (-dv / cam.fy_px * h, du / cam.fx_px * h);
        let want = Vector3::new(
            f * yaw.cos() - r * yaw.sin(),
            f * yaw.sin() + r * yaw.cos(),
            h,
        );
        assert!(close(&got, &want, MM), "{got} vs {want}");
    }

    #[test]
    fn recovers_known_points_through_the_renderers_truth_with_distortion() {
        let cam = camera().with_distortion(RadialTangential {
            k1: -0.25,
            k2: 0.06,
            p1: 0.001,
            p2: -0.0007,
            k3: -0.005,
        });
        let attitudes = [
            Attitude::new(0.0, 0.0, 0.0),
            Attitude::new(0.12, -0.08, 1.1),
            Attitude::new(-0.2, 0.15, -2.9),
            Attitude::new(0.05, 0.3, 3.1),
        ];
        for (i, attitude) in attitudes.iter().enumerate() {
            let uav_ned_m = Vector3::new(5.0 * i as f64, -3.0, -10.0);
            let pose = CameraPose::downward(
                uav_ned_m,
                attitude.roll_rad,
                attitude.pitch_rad,
                attitude.yaw_rad,
            );
            for (dn, de) in [(0.0, 0.0), (1.5, -2.0), (-2.5, 1.0), (0.7, 3.0)] {
                let pad = Point3::new(uav_ned_m.x + dn, uav_ned_m.y + de, 0.0);
                let (u, v) = true_pixel(&cam, &pose, &pad).unwrap();
                let got = pad_relative_to_uav_ned_m(&cam, attitude, 10.0, u, v).unwrap();
                let want = pad.coords - uav_ned_m;
                assert!(close(&got, &want, MM), "{attitude:?}: {got} vs {want}");
            }
        }
    }

    /// The seed's homography route, computed independently from the footprint's four corners by
    /// the direct linear transform, agrees with the ray intersection for an undistorted camera.
    #[test]
    fn footprint_homography_agrees_with_the_ray_intersection() {
        let cam = camera();
        let attitude = Attitude::new(0.1, -0.15, 0.7);
        let h = 10.0;
        let footprint = image_footprint_ned_m(&cam, &attitude, h).unwrap();
        let (r, b) = (cam.width_px as f64 - 0.5, cam.height_px as f64 - 0.5);
        let corners = [(-0.5, -0.5), (r, -0.5), (r, b), (-0.5, b)];
        // H maps (u, v, 1) to (n, e, 1) up to scale; with h33 = 1 the four pairs give 8 equations.
        let mut a = nalgebra::SMatrix::<f64, 8, 8>::zeros();
        let mut rhs = nalgebra::SVector::<f64, 8>::zeros();
        for (k, ((u, v), g)) in corners.iter().zip(footprint.iter()).enumerate() {
            let (x, y) = (g.x, g.y);
            let rows = [
                [*u, *v, 1.0, 0.0, 0.0, 0.0, -u * x, -v * x],
                [0.0, 0.0, 0.0, *u, *v, 1.0, -u * y, -v * y],
            ];
            for (j, row) in rows.iter().enumerate() {
                for (c, val) in row.iter().enumerate() {
                    a[(2 * k + j, c)] = *val;
                }
            }
            rhs[2 * k] = x;
            rhs[2 * k + 1] = y;
        }
        let hv = a.lu().solve(&rhs).unwrap();
        let hm = Matrix3::new(hv[0], hv[1], hv[2], hv[3], hv[4], hv[5], hv[6], hv[7], 1.0);
        for (u, v) in [(320.0, 240.0), (10.0, 470.0), (600.0, 30.0), (123.4, 321.0)] {
            let p = hm * Vector3::new(u, v, 1.0);
            let via_h = Vector3::new(p.x / p.z, p.y / p.z, h);
            let direct = pad_relative_to_uav_ned_m(&cam, &attitude, h, u, v).unwrap();
            assert!(close(&via_h, &direct, MM), "{via_h} vs {direct}");
        }
    }

    #[test]
    fn the_pad_in_view_offset_is_where_the_leaning_camera_sees_the_pad_at_its_margin() {
        let cam = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let (h, margin) = (7.5, 0.3);
        let offset = |attitude: Attitude| pad_in_view_offset_ne_m(&cam, &attitude, h, margin);
        // Level, or leaning less than the kept part of the view: straight below is seen.
        assert_eq!(offset(Attitude::default()), Some(Vector2::zeros()));
        assert_eq!(
            offset(Attitude::new(0.2, -0.1, 1.0)),
            Some(Vector2::zeros())
        );
        // Rolled right 28° (wind from the east): the axis looks 28° west, the image's right
        // margin (kept angle atan(0.7·tan 30°) east of the axis) looks 28° − kept west of
        // straight down, and there the pad must be.
        let roll = 28f64.to_radians();
        let kept_x = (0.7 * 30f64.to_radians().tan()).atan();
        let got = offset(Attitude::new(roll, 0.0, 0.0)).unwrap();
        let want = Vector2::new(0.0, -h * (roll - kept_x).tan());
        assert!((got - want).norm() < MM, "{got} vs {want}");
        // Pitched up 30°: the axis looks north; the short side's margin decides.
        let pitch = 30f64.to_radians();
        let kept_y = (0.7 * 240.0 / cam.fy_px).atan();
        let got = offset(Attitude::new(0.0, pitch, 0.0)).unwrap();
        let want = Vector2::new(h * (pitch - kept_y).tan(), 0.0);
        assert!((got - want).norm() < MM, "{got} vs {want}");
        // Yawed east the same lean points the offset east.
        let got = offset(Attitude::new(0.0, pitch, std::f64::consts::FRAC_PI_2)).unwrap();
        assert!((got - Vector2::new(0.0, want.x)).norm() < MM, "{got}");
        // Leaning past the horizon, or no height: nothing to say.
        assert_eq!(offset(Attitude::new(0.0, 1.7, 0.0)), None);
        assert_eq!(
            pad_in_view_offset_ne_m(&cam, &Attitude::default(), 0.0, margin),
            None
        );
    }

    #[test]
    fn step_eight_removes_the_markers_offset_in_the_pads_frame() {
        // A pad heading east (yaw 90°) with a marker 1 m forward and 0.5 m right of its centre:
        // forward is east and right is south, so the marker sits 1 m east and 0.5 m south.
        let marker = Vector3::new(3.0 - 0.5, 4.0 + 1.0, 10.0);
        let centre = pad_centre_from_marker(
            &marker,
            &Vector2::new(1.0, 0.5),
            std::f64::consts::FRAC_PI_2,
        );
        assert!(
            close(&centre, &Vector3::new(3.0, 4.0, 10.0), 1e-12),
            "{centre}"
        );
    }

    #[test]
    fn bad_input_is_a_named_error() {
        let cam = camera();
        let level = Attitude::default();
        assert!(matches!(
            pad_relative_to_uav_ned_m(&cam, &level, 0.0, 1.0, 1.0),
            Err(ProjectionError::Altitude { .. })
        ));
        assert!(matches!(
            pad_relative_to_uav_ned_m(&cam, &level, f64::NAN, 1.0, 1.0),
            Err(ProjectionError::Altitude { .. })
        ));
        assert!(matches!(
            pad_relative_to_uav_ned_m(&cam, &level, 5.0, f64::INFINITY, 1.0),
            Err(ProjectionError::Pixel { .. })
        ));
        assert!(matches!(
            pad_relative_to_uav_ned_m(&cam, &Attitude::new(f64::NAN, 0.0, 0.0), 5.0, 1.0, 1.0),
            Err(ProjectionError::Attitude { .. })
        ));
        // Pitched 80° nose up, the top of a 90°-FOV image looks above the horizon.
        let steep = Attitude::new(0.0, 80f64.to_radians(), 0.0);
        assert!(matches!(
            pad_relative_to_uav_ned_m(&cam, &steep, 5.0, 320.0, 0.0),
            Err(ProjectionError::AboveHorizon { .. })
        ));
        assert!(image_footprint_ned_m(&cam, &steep, 5.0).is_err());
    }
}
