//! The UGV's velocity from the downward camera (seed 000, §2.2.3 "Velocity Observer" and §2.3,
//! equations 15–22): the target's motion-compensated pixel displacement between frames, scaled
//! by altitude over focal length, gives its instantaneous speed and heading; a Gaussian-weighted
//! average over recent frames steadies them; the result is decomposed on the body axes and
//! rotated into NED.
//!
//! Axes: the camera is mounted as [`crate::camera::CameraPose::downward`], so image right
//! is body right (FRD y) and image up is body forward (FRD x). Headings are angles from body
//! forward towards body right, so `course_ned = heading_body + yaw`.
//!
//! Departures from the seed, each for a reason:
//! - Equation 17, `atan((x_j − x_i)/(y_j − y_i))`, loses the quadrant and measures from image
//!   *down*; we use `atan2(Δx, −Δy)`, the heading from body forward, over all four quadrants.
//! - The Gaussian weights of equations 18–19 are normalised to sum to 1 (the seed's density
//!   values do not, over a discrete window), with the peak at the current frame and the sample
//!   age in seconds as x.
//! - Headings are averaged as angles on the circle (weighted mean of unit vectors), and in NED
//!   rather than body axes: an arithmetic mean of −179° and 179° would point the wrong way, and
//!   a body-axis mean would blur when the UAV yaws within the window.
//! - Averaging speeds (equation 18) is biased upwards when the per-frame displacement is not
//!   much larger than the detection noise (the mean of |d + noise| exceeds |d|), as at high
//!   altitude or a high frame rate. [`Averaging::Velocity`] averages the NED velocity vectors
//!   instead, which is unbiased; the seed's way stays the default.
//! - Equation 21 as printed is the transpose of the body-to-NED matrix of the quaternion (it
//!   maps NED to body); [`body_to_ned`] uses the body-to-NED rotation that equation 22 needs.

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector2, Vector3};
use thiserror::Error;

/// An observer that cannot be built or fed as asked.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum VelocityObserverError {
    #[error("velocity observer setting {name} must be {why}, got {value}")]
    Config {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("the altitude must be positive and finite, got {altitude_m} m")]
    Altitude { altitude_m: f64 },
    #[error("the focal length must be positive and finite, got {focal_px} px")]
    FocalLength { focal_px: f64 },
    #[error("the frame interval must be positive and finite, got {dt_s} s")]
    FrameInterval { dt_s: f64 },
    #[error("a pixel position, time or yaw given to the velocity observer is not finite")]
    NotFinite,
    #[error("time must advance: {time_s} s is not after the last sample at {last_s} s")]
    TimeNotAdvancing { time_s: f64, last_s: f64 },
}

/// The target in two consecutive frames, both in the current frame's pixels (rectified).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelMotion {
    /// (x_i, y_i): the previous position mapped into the current frame by the homography
    /// (equations 7–9).
    pub previous_mapped_px: (f64, f64),
    /// (x_j, y_j): the current position.
    pub current_px: (f64, f64),
}

/// One frame pair's motion (equations 10, 15–17).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstantMotion {
    /// f_pd, equation 10.
    pub displacement_px: f64,
    /// s_ugv = f_pd·Z / f, equation 15.
    pub displacement_m: f64,
    /// v_Δt = s_ugv / Δt, equation 16.
    pub speed_m_s: f64,
    /// o_Δt, equation 17: from body forward towards body right.
    pub heading_body_rad: f64,
    /// The same motion as a body-frame velocity (x forward, y right), m/s.
    pub velocity_body_m_s: Vector2<f64>,
}

/// Equations 10 and 15–17 for one frame pair `dt_s` apart, at `altitude_m` above the ground,
/// with the (rectified) camera's focal length `focal_px`.
pub fn instant_motion(
    motion: &PixelMotion,
    altitude_m: f64,
    focal_px: f64,
    dt_s: f64,
) -> Result<InstantMotion, VelocityObserverError> {
    if !(altitude_m.is_finite() && altitude_m > 0.0) {
        return Err(VelocityObserverError::Altitude { altitude_m });
    }
    if !(focal_px.is_finite() && focal_px > 0.0) {
        return Err(VelocityObserverError::FocalLength { focal_px });
    }
    if !(dt_s.is_finite() && dt_s > 0.0) {
        return Err(VelocityObserverError::FrameInterval { dt_s });
    }
    let (xi, yi) = motion.previous_mapped_px;
    let (xj, yj) = motion.current_px;
    if ![xi, yi, xj, yj].iter().all(|v| v.is_finite()) {
        return Err(VelocityObserverError::NotFinite);
    }
    let (dx, dy) = (xj - xi, yj - yi);
    let displacement_px = dx.hypot(dy);
    let metres_per_px = altitude_m / focal_px;
    let displacement_m = displacement_px * metres_per_px;
    let speed_m_s = displacement_m / dt_s;
    // Image up (−y) is body forward, image right (+x) is body right.
    let velocity_body_m_s = Vector2::new(-dy, dx) * (metres_per_px / dt_s);
    Ok(InstantMotion {
        displacement_px,
        displacement_m,
        speed_m_s,
        heading_body_rad: dx.atan2(-dy),
        velocity_body_m_s,
    })
}

/// Equation 22 for a level vehicle: a body-frame horizontal vector (x forward, y right) rotated
/// into NED (north, east) by the yaw.
pub fn body_to_ned_by_yaw(v_body: Vector2<f64>, yaw_rad: f64) -> Vector2<f64> {
    let (s, c) = yaw_rad.sin_cos();
    Vector2::new(c * v_body.x - s * v_body.y, s * v_body.x + c * v_body.y)
}

/// Equations 20–22 with the full attitude: `V_w = R V_b`, R the body-to-NED rotation of the
/// attitude quaternion (PX4's `q`, Hamilton, body to NED). A velocity needs no translation.
pub fn body_to_ned(v_body: &Vector3<f64>, attitude: &UnitQuaternion<f64>) -> Vector3<f64> {
    attitude * v_body
}

/// What the Gaussian weights average.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Averaging {
    /// The seed's equations 18–19: speed, and course (as a circular mean).
    #[default]
    SpeedAndCourse,
    /// The NED velocity vectors: unbiased when the displacement is small against the noise.
    Velocity,
}

/// The observer's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityObserverConfig {
    /// σ of the Gaussian weight over sample age, seconds (default 0.2).
    pub sigma_s: f64,
    /// Samples older than this are dropped, seconds (default 0.6, 3σ).
    pub window_s: f64,
    pub averaging: Averaging,
}

impl Default for VelocityObserverConfig {
    fn default() -> Self {
        Self {
            sigma_s: 0.2,
            window_s: 0.6,
            averaging: Averaging::SpeedAndCourse,
        }
    }
}

impl VelocityObserverConfig {
    pub fn validate(&self) -> Result<(), VelocityObserverError> {
        for (name, value) in [("sigma_s", self.sigma_s), ("window_s", self.window_s)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(VelocityObserverError::Config {
                    name,
                    value,
                    why: "positive and finite",
                });
            }
        }
        Ok(())
    }
}

/// The UGV's estimated motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UgvVelocity {
    pub time_s: f64,
    /// v_ugv, equation 18.
    pub speed_m_s: f64,
    /// Course over the ground, radians from north towards east (o_ugv of equation 19 + yaw).
    pub course_ned_rad: f64,
    /// o_ugv, equation 19: the course relative to the body's current heading.
    pub heading_body_rad: f64,
    /// (v_x, v_y) on the body axes (forward, right), m/s.
    pub velocity_body_m_s: Vector2<f64>,
    /// V_w of equation 22: (north, east), m/s.
    pub velocity_ned_m_s: Vector2<f64>,
    /// Samples averaged.
    pub samples: usize,
}

#[derive(Debug, Clone, Copy)]
struct Sample {
    time_s: f64,
    speed_m_s: f64,
    course_ned_rad: f64,
}

/// Gaussian-weighted averaging of the instantaneous motions (equations 18–19) and the frame
/// transformation (equations 20–22); see the module docs.
#[derive(Debug, Clone)]
pub struct VelocityObserver {
    config: VelocityObserverConfig,
    samples: VecDeque<Sample>,
}

impl VelocityObserver {
    pub fn new(config: VelocityObserverConfig) -> Result<Self, VelocityObserverError> {
        config.validate()?;
        Ok(Self {
            config,
            samples: VecDeque::new(),
        })
    }

    /// Forgets the history (target lost).
    pub fn reset(&mut self) {
        self.samples.clear();
    }

    /// Adds the frame pair ending at `time_s`, seen with the vehicle at `yaw_rad`, and returns
    /// the averaged motion.
    pub fn update(
        &mut self,
        time_s: f64,
        motion: &InstantMotion,
        yaw_rad: f64,
    ) -> Result<UgvVelocity, VelocityObserverError> {
        if !(time_s.is_finite() && yaw_rad.is_finite() && motion.speed_m_s.is_finite()) {
            return Err(VelocityObserverError::NotFinite);
        }
        if let Some(last) = self.samples.back() {
            if time_s <= last.time_s {
                return Err(VelocityObserverError::TimeNotAdvancing {
                    time_s,
                    last_s: last.time_s,
                });
            }
        }
        self.samples.push_back(Sample {
            time_s,
            speed_m_s: motion.speed_m_s,
            course_ned_rad: motion.heading_body_rad + yaw_rad,
        });
        while self
            .samples
            .front()
            .is_some_and(|s| time_s - s.time_s > self.config.window_s)
        {
            self.samples.pop_front();
        }
        let two_sigma2 = 2.0 * self.config.sigma_s.powi(2);
        let (mut weight_sum, mut speed, mut cos, mut sin) = (0.0, 0.0, 0.0, 0.0);
        let mut velocity = Vector2::zeros();
        for s in &self.samples {
            let age = time_s - s.time_s;
            let w = (-age * age / two_sigma2).exp();
            let direction = Vector2::new(s.course_ned_rad.cos(), s.course_ned_rad.sin());
            weight_sum += w;
            speed += w * s.speed_m_s;
            cos += w * direction.x;
            sin += w * direction.y;
            velocity += direction * (w * s.speed_m_s);
        }
        // The newest sample has weight 1, so the sum is at least 1.
        let (speed_m_s, course_ned_rad) = match self.config.averaging {
            Averaging::SpeedAndCourse => (speed / weight_sum, sin.atan2(cos)),
            Averaging::Velocity => {
                let mean = velocity / weight_sum;
                (mean.norm(), mean.y.atan2(mean.x))
            }
        };
        let velocity_ned_m_s = Vector2::new(course_ned_rad.cos(), course_ned_rad.sin()) * speed_m_s;
        let heading_body_rad = wrap(course_ned_rad - yaw_rad);
        Ok(UgvVelocity {
            time_s,
            speed_m_s,
            course_ned_rad,
            heading_body_rad,
            velocity_body_m_s: Vector2::new(heading_body_rad.cos(), heading_body_rad.sin())
                * speed_m_s,
            velocity_ned_m_s,
            samples: self.samples.len(),
        })
    }
}

/// An angle in (−π, π].
fn wrap(a: f64) -> f64 {
    let s = a.sin();
    let c = a.cos();
    s.atan2(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraPose, PinholeCamera};
    use crate::vision::render::SplitMix64;
    use nalgebra::{Matrix3, Point3, Rotation3};
    use std::f64::consts::PI;

    /// The ground homography from pose 1 to pose 2, H = K (R − t nᵀ/d) K⁻¹ (see
    /// `vision::homography`'s tests), so the test's motion compensation is exact and
    /// independent of the observer.
    fn ground_homography(
        camera: &PinholeCamera,
        pose1: &CameraPose,
        pose2: &CameraPose,
    ) -> Matrix3<f64> {
        let r_wc1 = pose1.camera_to_world.rotation.to_rotation_matrix();
        let r_wc2 = pose2.camera_to_world.rotation.to_rotation_matrix();
        let r = (r_wc2.inverse() * r_wc1).into_inner();
        let t = r_wc2.inverse() * (pose1.position_ned_m() - pose2.position_ned_m());
        let n = r_wc1.inverse() * Vector3::new(0.0, 0.0, -1.0);
        let d = -pose1.position_ned_m().z;
        #[rustfmt::skip]
        let k = Matrix3::new(
            camera.fx_px, 0.0, camera.cx_px,
            0.0, camera.fy_px, camera.cy_px,
            0.0, 0.0, 1.0,
        );
        k * (r - t * n.transpose() / d) * k.try_inverse().unwrap()
    }

    /// A UGV driving at a constant NED velocity under a level UAV that flies, climbs and yaws:
    /// the motion of each frame pair, with the altitude and yaw of its second frame.
    fn scenario(
        ugv_velocity_ne: Vector2<f64>,
        frames: usize,
    ) -> Vec<(f64, PixelMotion, f64, f64, f64)> {
        let camera = PinholeCamera::from_fov(640, 480, 100f64.to_radians()).unwrap();
        let dt = 1.0 / 30.0;
        let uav = |t: f64| {
            let position = Vector3::new(1.0 + 1.5 * t, -0.5 + 0.7 * t, -9.0 - 0.05 * t);
            let yaw = 0.6 + 0.25 * t;
            (
                CameraPose::downward(position, 0.0, 0.0, yaw),
                yaw,
                -position.z,
            )
        };
        let ugv = |t: f64| Point3::new(ugv_velocity_ne.x * t, ugv_velocity_ne.y * t, 0.0);
        (1..frames)
            .map(|k| {
                let (t0, t1) = ((k - 1) as f64 * dt, k as f64 * dt);
                let ((pose0, _, _), (pose1, yaw1, altitude1)) = (uav(t0), uav(t1));
                let (u0, v0) = camera.project_world(&pose0, &ugv(t0)).unwrap();
                let (u1, v1) = camera.project_world(&pose1, &ugv(t1)).unwrap();
                let h = ground_homography(&camera, &pose0, &pose1);
                let p = h * Vector3::new(u0, v0, 1.0);
                let motion = PixelMotion {
                    previous_mapped_px: (p.x / p.z, p.y / p.z),
                    current_px: (u1, v1),
                };
                (t1, motion, altitude1, yaw1, camera.fx_px)
            })
            .collect()
    }

    #[test]
    fn a_constant_ugv_velocity_comes_out_in_ned() {
        let dt = 1.0 / 30.0;
        for truth in [
            Vector2::new(2.0, -1.0),
            Vector2::new(-3.0, 0.01),
            Vector2::new(0.0, 1.5),
        ] {
            let mut observer = VelocityObserver::new(VelocityObserverConfig::default()).unwrap();
            for (t, motion, altitude, yaw, focal) in scenario(truth, 40) {
                let instant = instant_motion(&motion, altitude, focal, dt).unwrap();
                // The instantaneous speed is already exact for a level camera (equations 15–16).
                assert!((instant.speed_m_s - truth.norm()).abs() < 1e-6);
                // Its body velocity, rotated by the yaw, is the NED velocity (equation 22).
                let ned = body_to_ned_by_yaw(instant.velocity_body_m_s, yaw);
                assert!((ned - truth).norm() < 1e-6, "{ned} vs {truth}");
                let v = observer.update(t, &instant, yaw).unwrap();
                assert!(
                    (v.velocity_ned_m_s - truth).norm() < 1e-6,
                    "{} vs {truth}",
                    v.velocity_ned_m_s
                );
                assert!((v.speed_m_s - truth.norm()).abs() < 1e-6);
                // Body components rotate back to the same NED velocity.
                let back = body_to_ned_by_yaw(v.velocity_body_m_s, yaw);
                assert!((back - truth).norm() < 1e-6);
            }
        }
    }

    /// Runs the observer over `frames` of the scenario with `noise_px` of Gaussian noise on
    /// every position: (RMS error of the raw NED velocity, RMS error of the averaged one, norm of
    /// the averaged velocity's mean error), after the first window.
    fn noisy_run(averaging: Averaging, noise_px: f64, frames: usize) -> (f64, f64, f64) {
        let truth = Vector2::new(1.2, 2.0);
        let dt = 1.0 / 30.0;
        let mut rng = SplitMix64::new(3);
        let config = VelocityObserverConfig {
            averaging,
            ..VelocityObserverConfig::default()
        };
        let mut observer = VelocityObserver::new(config).unwrap();
        let (mut raw_sq, mut averaged_sq, mut n) = (0.0, 0.0, 0usize);
        let mut error_sum = Vector2::zeros();
        for (t, mut motion, altitude, yaw, focal) in scenario(truth, frames) {
            motion.current_px.0 += noise_px * rng.next_gaussian();
            motion.current_px.1 += noise_px * rng.next_gaussian();
            motion.previous_mapped_px.0 += noise_px * rng.next_gaussian();
            motion.previous_mapped_px.1 += noise_px * rng.next_gaussian();
            let instant = instant_motion(&motion, altitude, focal, dt).unwrap();
            let v = observer.update(t, &instant, yaw).unwrap();
            if t > 0.6 {
                let raw = body_to_ned_by_yaw(instant.velocity_body_m_s, yaw);
                raw_sq += (raw - truth).norm_squared();
                averaged_sq += (v.velocity_ned_m_s - truth).norm_squared();
                error_sum += v.velocity_ned_m_s - truth;
                n += 1;
            }
        }
        let n = n as f64;
        (
            (raw_sq / n).sqrt(),
            (averaged_sq / n).sqrt(),
            (error_sum / n).norm(),
        )
    }

    #[test]
    fn gaussian_weighting_reduces_the_noise() {
        // About 2.5 px of motion per frame here; 0.4 px of noise on each position. The weights
        // average about ten frames: the error should shrink by about √10.
        for averaging in [Averaging::SpeedAndCourse, Averaging::Velocity] {
            let (raw, averaged, _) = noisy_run(averaging, 0.4, 600);
            assert!(
                averaged < 0.45 * raw,
                "{averaging:?}: averaged {averaged} m/s vs raw {raw} m/s"
            );
        }
    }

    #[test]
    fn averaging_speeds_is_biased_at_low_signal_to_noise_and_averaging_vectors_is_not() {
        // 1 px of noise on each position against about 2.5 px of motion per frame: the mean of
        // |v + noise| is about √(|v|² + 2σ²) ≈ |v| + 0.75 m/s here, and averaging speeds keeps
        // that; the mean of the vectors is the true velocity.
        let (_, _, speed_bias) = noisy_run(Averaging::SpeedAndCourse, 1.0, 1800);
        let (raw, averaged, vector_bias) = noisy_run(Averaging::Velocity, 1.0, 1800);
        assert!(speed_bias > 0.4, "{speed_bias} m/s");
        assert!(vector_bias < 0.12, "{vector_bias} m/s");
        assert!(
            averaged < 0.45 * raw,
            "averaged {averaged} m/s vs raw {raw} m/s"
        );
    }

    #[test]
    fn headings_near_south_average_on_the_circle() {
        // A UGV heading south: noisy headings straddle ±180°. Their arithmetic mean would be
        // near 0° (north); the circular mean stays south.
        let config = VelocityObserverConfig {
            window_s: 0.62,
            ..VelocityObserverConfig::default()
        };
        let mut observer = VelocityObserver::new(config).unwrap();
        let mut rng = SplitMix64::new(4);
        let mut last = None;
        for k in 0..30 {
            let heading = PI + 0.1 * rng.next_gaussian();
            let instant = InstantMotion {
                displacement_px: 0.0,
                displacement_m: 0.0,
                speed_m_s: 2.0,
                heading_body_rad: wrap(heading),
                velocity_body_m_s: Vector2::zeros(),
            };
            last = Some(observer.update(k as f64 / 30.0, &instant, 0.0).unwrap());
        }
        let v = last.unwrap();
        assert!(v.velocity_ned_m_s.x < -1.9, "{}", v.velocity_ned_m_s);
        assert!(v.velocity_ned_m_s.y.abs() < 0.1);
        assert_eq!(v.samples, 19, "ages 0 to 18/30 s fit in 0.62 s");
    }

    #[test]
    fn equation_21_as_printed_is_the_transpose_of_body_to_ned() {
        let attitude = UnitQuaternion::from_euler_angles(0.1, -0.2, 2.5);
        let (q0, q1, q2, q3) = (attitude.w, attitude.i, attitude.j, attitude.k);
        #[rustfmt::skip]
        let printed = Matrix3::new(
            1.0 - 2.0 * q2 * q2 - 2.0 * q3 * q3, 2.0 * (q1 * q2 + q0 * q3), 2.0 * (q1 * q3 - q0 * q2),
            2.0 * (q1 * q2 - q0 * q3), 1.0 - 2.0 * q1 * q1 - 2.0 * q3 * q3, 2.0 * (q2 * q3 + q0 * q1),
            2.0 * (q1 * q3 + q0 * q2), 2.0 * (q2 * q3 - q0 * q1), 1.0 - 2.0 * q1 * q1 - 2.0 * q2 * q2,
        );
        let v_body = Vector3::new(1.0, 2.0, -0.5);
        assert!((body_to_ned(&v_body, &attitude) - printed.transpose() * v_body).norm() < 1e-12);
        // Yaw only: the level shortcut agrees, and 90° turns body forward to east.
        let yaw = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7);
        let full = body_to_ned(&Vector3::new(1.0, 2.0, 0.0), &yaw);
        let level = body_to_ned_by_yaw(Vector2::new(1.0, 2.0), 0.7);
        assert!((full.xy() - level).norm() < 1e-12);
        let east = body_to_ned_by_yaw(Vector2::new(1.0, 0.0), PI / 2.0);
        assert!((east - Vector2::new(0.0, 1.0)).norm() < 1e-12);
        let rot = Rotation3::from_euler_angles(0.0, 0.0, 0.7);
        assert!((rot * Vector3::new(1.0, 2.0, 0.0) - full).norm() < 1e-12);
    }

    #[test]
    fn bad_input_is_a_named_error() {
        let motion = PixelMotion {
            previous_mapped_px: (0.0, 0.0),
            current_px: (1.0, 1.0),
        };
        assert!(matches!(
            instant_motion(&motion, 0.0, 300.0, 0.1),
            Err(VelocityObserverError::Altitude { .. })
        ));
        assert!(matches!(
            instant_motion(&motion, 5.0, f64::NAN, 0.1),
            Err(VelocityObserverError::FocalLength { .. })
        ));
        assert!(matches!(
            instant_motion(&motion, 5.0, 300.0, 0.0),
            Err(VelocityObserverError::FrameInterval { .. })
        ));
        let bad = PixelMotion {
            current_px: (f64::INFINITY, 0.0),
            ..motion
        };
        assert!(matches!(
            instant_motion(&bad, 5.0, 300.0, 0.1),
            Err(VelocityObserverError::NotFinite)
        ));
        // Equations 10 and 15–17 by hand: (3, −4) px is 5 px; at 6 m with f = 300 px that is
        // 0.1 m, over 0.05 s 2 m/s; up-right of the image is forward-right: atan2(3, 4).
        let motion = PixelMotion {
            previous_mapped_px: (10.0, 10.0),
            current_px: (13.0, 6.0),
        };
        let m = instant_motion(&motion, 6.0, 300.0, 0.05).unwrap();
        assert_eq!(m.displacement_px, 5.0);
        assert!((m.displacement_m - 0.1).abs() < 1e-12);
        assert!((m.speed_m_s - 2.0).abs() < 1e-12);
        assert!((m.heading_body_rad - 3f64.atan2(4.0)).abs() < 1e-12);
        assert!((m.velocity_body_m_s - Vector2::new(1.6, 1.2)).norm() < 1e-12);
        let mut observer = VelocityObserver::new(VelocityObserverConfig::default()).unwrap();
        observer.update(1.0, &m, 0.0).unwrap();
        assert!(matches!(
            observer.update(1.0, &m, 0.0),
            Err(VelocityObserverError::TimeNotAdvancing { .. })
        ));
        assert!(VelocityObserver::new(VelocityObserverConfig {
            sigma_s: 0.0,
            ..VelocityObserverConfig::default()
        })
        .is_err());
    }
}
