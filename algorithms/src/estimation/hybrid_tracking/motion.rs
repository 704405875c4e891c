//! How the platform moves, seen from a moving UAV (seed 000, equations 7–10 and 15–17): the
//! ground's features matched from frame to frame give a homography that takes the UAV's own
//! motion out of the target's; low over the platform, where the ground shows too few features,
//! the UAV's reported velocity does instead.

use super::*;

impl HybridTracker {
    /// The frame's features of the ground for the motion compensation, those on the target's
    /// `detection` masked out; `None` without an image or a detection, or below
    /// `homography_min_altitude_m`.
    pub(super) fn ground_features(
        &self,
        frame: &FrameInput<'_>,
        detection: Option<&Detection>,
        altitude_m: f64,
    ) -> Option<FrameFeatures> {
        let homography_altitude = altitude_m >= self.homography_min_altitude_m;
        frame
            .image
            .zip(detection)
            .filter(|_| homography_altitude)
            .map(|(image, d)| {
                let mut features = self.matcher.features(&image.view());
                mask_out(&mut features, &d.bbox, 1.2);
                features
            })
    }

    /// Feeds the platform's instantaneous motion to the velocity observer, unless it is faster
    /// than the UGV can drive (a bad match).
    pub(super) fn observe_platform_motion(
        &mut self,
        time_s: f64,
        instant: &InstantMotion,
        yaw_rad: f64,
    ) {
        if instant.speed_m_s > self.max_ugv_speed_m_s {
            self.status.velocity_rejected += 1;
        } else if let Ok(velocity) = self.observer.update(time_s, instant, yaw_rad) {
            self.status.velocity_samples += 1;
            self.platform_velocity_ned_m_s = Some(Vector3::new(
                velocity.velocity_ned_m_s.x,
                velocity.velocity_ned_m_s.y,
                0.0,
            ));
        }
    }

    /// Equations 7–10 and 15–17: the homography of the ground from the previous frame's
    /// features to the current one's maps the target's previous pixel into the current frame;
    /// what is left to its current pixel is its own motion. `Err` when there is no homography.
    pub(super) fn compensated_motion(
        &mut self,
        previous: &FrameFeatures,
        current: &FrameFeatures,
        previous_px: (f64, f64),
        current_px: (f64, f64),
        altitude_m: f64,
        dt_s: f64,
    ) -> Result<Option<InstantMotion>, HomographyError> {
        let matches = self.matcher.correspondences(previous, current);
        let fit = match fit_correspondences(&matches, &self.ransac) {
            Ok(fit) => fit,
            Err(error) => {
                self.status.homography_failures += 1;
                self.status.last_homography_error = Some(error.to_string());
                return Err(error);
            }
        };
        let Some(mapped) = fit.homography.map(previous_px.0, previous_px.1) else {
            return Ok(None);
        };
        let motion = PixelMotion {
            previous_mapped_px: mapped,
            current_px,
        };
        self.status.homography_motions += 1;
        Ok(instant_motion(&motion, altitude_m, self.camera.fx_px, dt_s).ok())
    }

    /// The same motion where the ground's features are too few (low over the platform): the
    /// UAV's displacement by its reported velocity, less the change of its position relative to
    /// the target, as the instantaneous motion the observer takes.
    pub(super) fn ego_motion(
        &mut self,
        previous_relative_ned_m: Vector3<f64>,
        relative_ned_m: Vector3<f64>,
        previous_s: f64,
        time_s: f64,
        yaw_rad: f64,
    ) -> Option<InstantMotion> {
        let dt_s = time_s - previous_s;
        if dt_s.is_nan() || dt_s <= 0.0 {
            return None;
        }
        let displacement = (self.uav_displacement_m(previous_s, time_s)
            - (relative_ned_m - previous_relative_ned_m))
            .xy();
        let velocity_ned = displacement / dt_s;
        // Body axes (x forward, y right) for the observer, which rotates back by the yaw.
        let (sin, cos) = yaw_rad.sin_cos();
        let velocity_body = nalgebra::Vector2::new(
            cos * velocity_ned.x + sin * velocity_ned.y,
            -sin * velocity_ned.x + cos * velocity_ned.y,
        );
        self.status.ego_motions += 1;
        Some(InstantMotion {
            displacement_px: f64::NAN,
            displacement_m: displacement.norm(),
            speed_m_s: velocity_ned.norm(),
            heading_body_rad: velocity_body.y.atan2(velocity_body.x),
            velocity_body_m_s: velocity_body,
        })
    }
}

/// Drops the keypoints inside `bbox` grown by `grow` about its centre: on the target, they move
/// with it, not with the ground.
pub(super) fn mask_out(features: &mut FrameFeatures, bbox: &PixelBox, grow: f64) {
    let (cx, cy) = bbox.centre();
    let half_w = 0.5 * grow * (bbox.x_max - bbox.x_min);
    let half_h = 0.5 * grow * (bbox.y_max - bbox.y_min);
    let keep: Vec<bool> = features
        .keypoints
        .iter()
        .map(|k| (k.x_px - cx).abs() > half_w || (k.y_px - cy).abs() > half_h)
        .collect();
    let mut flags = keep.iter();
    features
        .keypoints
        .retain(|_| *flags.next().unwrap_or(&true));
    let mut flags = keep.iter();
    features
        .descriptors
        .retain(|_| *flags.next().unwrap_or(&true));
}
