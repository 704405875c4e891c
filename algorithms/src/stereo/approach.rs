//! A scripted fixed-wing approach as the ground stereo rig sees it: the aircraft flies a straight
//! glide slope down the runway centre line to the touchdown point, each PTU follows it one frame
//! late, and each reading carries the seed's disturbances. It feeds the `ground_stereo` task
//! and scores its fixes per distance interval, like the seed's Table 5.
//!
//! The disturbances (seeded, so a run replays exactly):
//! - the PTU's reported pan and tilt: N(0, σ²) with σ the PTU-D300E's 0.006° (§5.1; the seed
//!   calls it the PTU's accuracy). §4.2's 1 mrad is available by raising `ptu_noise_rad`;
//! - the tracker's target centre: N(0, σ²) pixels in u and v (1 px by default, the unit of
//!   Tables 1–2) on the seed's camera (100 mm lens, 3.75 µm pixels).
//!
//! The camera image is an exact pinhole projection of the target through the PTU's actual pan
//! and tilt, so the plugin's Eq. 5 (which adds the pixel angles to the PTU angles) is itself an
//! approximation here, as on a real rig: for offsets of a few pixels it is far below the noise.

use super::triangulation::{CameraIntrinsics, LineOfSight, PtuReading, RigError, StereoRig};
use nalgebra::Vector3;
use thiserror::Error;

/// The scripted approach.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApproachConfig {
    /// The glide slope, 3° by default (the seed's range is 3°–7°).
    pub glide_angle_rad: f64,
    /// Where the approach starts, metres from touchdown along the centre line.
    pub start_distance_m: f64,
    /// Ground speed along the centre line (the seed's Pioneer cruises at 30 m/s, Table 3).
    pub ground_speed_m_s: f64,
    /// Camera frames per second (the seed's DSST + BBP runs at about 28 fps, Table 6).
    pub frame_rate_hz: f64,
    /// A constant offset of the flight path from the centre line (to the right).
    pub lateral_offset_m: f64,
    pub baseline_m: f64,
    /// The PTUs stand this far behind the touchdown point, one on each side of the centre line.
    pub ptu_setback_m: f64,
    pub camera: CameraIntrinsics,
    /// σ of the PTU's reported pan and tilt.
    pub ptu_noise_rad: f64,
    /// σ of the tracked target centre, pixels, in u and in v.
    pub pixel_noise_px: f64,
    pub seed: u64,
}

impl Default for ApproachConfig {
    fn default() -> Self {
        Self {
            glide_angle_rad: 3f64.to_radians(),
            start_distance_m: 1000.0,
            ground_speed_m_s: 25.0,
            frame_rate_hz: 25.0,
            lateral_offset_m: 0.0,
            baseline_m: 10.0,
            ptu_setback_m: 20.0,
            camera: CameraIntrinsics::seed(),
            ptu_noise_rad: 0.006f64.to_radians(),
            pixel_noise_px: 1.0,
            seed: 0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum ApproachError {
    #[error("{what} must be a finite number > 0, got {value}")]
    NotPositive { what: &'static str, value: f64 },
    #[error("{what} must be a finite number ≥ 0, got {value}")]
    Negative { what: &'static str, value: f64 },
    #[error("{what} must be finite, got {value}")]
    NonFinite { what: &'static str, value: f64 },
    #[error("the glide angle must lie strictly between 0° and 45°, got {0} rad")]
    GlideAngle(f64),
    #[error("the distance interval must be a finite number > 0, got {0} m")]
    Interval(f64),
    #[error(transparent)]
    Rig(#[from] RigError),
}

impl ApproachConfig {
    pub fn validate(&self) -> Result<(), ApproachError> {
        for (what, value) in [
            ("start_distance_m", self.start_distance_m),
            ("ground_speed_m_s", self.ground_speed_m_s),
            ("frame_rate_hz", self.frame_rate_hz),
            ("baseline_m", self.baseline_m),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(ApproachError::NotPositive { what, value });
            }
        }
        for (what, value) in [
            ("ptu_setback_m", self.ptu_setback_m),
            ("ptu_noise_rad", self.ptu_noise_rad),
            ("pixel_noise_px", self.pixel_noise_px),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ApproachError::Negative { what, value });
            }
        }
        if !self.lateral_offset_m.is_finite() {
            return Err(ApproachError::NonFinite {
                what: "lateral_offset_m",
                value: self.lateral_offset_m,
            });
        }
        if !(self.glide_angle_rad > 0.0 && self.glide_angle_rad < std::f64::consts::FRAC_PI_4) {
            return Err(ApproachError::GlideAngle(self.glide_angle_rad));
        }
        Ok(())
    }

    /// The rig that watches the approach: left PTU at (−D/2, −setback, 0) in the runway frame,
    /// baseline square to the centre line, the midpoint of the common perpendicular.
    pub fn rig(&self) -> Result<StereoRig, ApproachError> {
        Ok(StereoRig::new(
            self.baseline_m,
            Vector3::new(-self.baseline_m / 2.0, -self.ptu_setback_m, 0.0),
            0.0,
            self.camera,
            Default::default(),
            super::triangulation::DEFAULT_MIN_DET_H,
        )?)
    }

    /// Frames from the start to touchdown, both included.
    pub fn frame_count(&self) -> usize {
        (self.start_distance_m / self.ground_speed_m_s * self.frame_rate_hz).floor() as usize + 1
    }

    pub fn frame_time_s(&self, frame: usize) -> f64 {
        frame as f64 / self.frame_rate_hz
    }

    /// Where the aircraft is at `time_s` (runway frame): on the glide slope, `time_s` into the
    /// approach, stopped at touchdown.
    pub fn truth_at(&self, time_s: f64) -> Vector3<f64> {
        let distance = (self.start_distance_m - self.ground_speed_m_s * time_s).max(0.0);
        Vector3::new(
            self.lateral_offset_m,
            distance,
            distance * self.glide_angle_rad.tan(),
        )
    }

    /// The readings, frame by frame.
    pub fn frames(&self) -> Result<ApproachFrames, ApproachError> {
        self.validate()?;
        Ok(ApproachFrames {
            config: *self,
            rig: self.rig()?,
            rng: SplitMix64(self.seed ^ 0x9E37_79B9_7F4A_7C15),
            frame: 0,
        })
    }
}

/// One frame of the approach: what both PTUs report, and the truth to score against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApproachFrame {
    pub index: usize,
    pub time_s: f64,
    pub truth_runway_m: Vector3<f64>,
    pub left: PtuReading,
    pub right: PtuReading,
}

/// The approach's frames, in order.
#[derive(Debug, Clone)]
pub struct ApproachFrames {
    config: ApproachConfig,
    rig: StereoRig,
    rng: SplitMix64,
    frame: usize,
}

impl ApproachFrames {
    fn reading(
        &mut self,
        ptu: Vector3<f64>,
        aim: &Vector3<f64>,
        truth: &Vector3<f64>,
    ) -> PtuReading {
        let focal_px = self.config.camera.focal_length_px();
        let pointing = LineOfSight::towards(&ptu, aim).unwrap_or(LineOfSight::new(0.0, 0.0));
        let offset =
            ptu_camera_offset_px(&ptu, pointing.pan_rad, pointing.tilt_rad, focal_px, truth);
        let pixel_sigma = self.config.pixel_noise_px;
        let ptu_sigma = self.config.ptu_noise_rad;
        // Draw all four numbers every frame, so the noise sequence does not depend on whether
        // the target was in view.
        let noise = [
            self.rng.normal(),
            self.rng.normal(),
            self.rng.normal(),
            self.rng.normal(),
        ];
        PtuReading {
            pan_rad: pointing.pan_rad + ptu_sigma * noise[0],
            tilt_rad: pointing.tilt_rad + ptu_sigma * noise[1],
            target_offset_px: offset
                .map(|[u, v]| [u + pixel_sigma * noise[2], v + pixel_sigma * noise[3]]),
        }
    }
}

impl Iterator for ApproachFrames {
    type Item = ApproachFrame;

    fn next(&mut self) -> Option<ApproachFrame> {
        if self.frame >= self.config.frame_count() {
            return None;
        }
        let index = self.frame;
        self.frame += 1;
        let time_s = self.config.frame_time_s(index);
        let truth_runway_m = self.config.truth_at(time_s);
        // The PTUs point where the aircraft was one frame ago (their servo loop's lag), so the
        // target is a few pixels off centre, as in flight.
        let aim_runway = self
            .config
            .truth_at(self.config.frame_time_s(index.saturating_sub(1)));
        let truth = self.rig.runway_to_stereo(&truth_runway_m);
        let aim = self.rig.runway_to_stereo(&aim_runway);
        let left = self.reading(Vector3::zeros(), &aim, &truth);
        let right = self.reading(Vector3::new(self.config.baseline_m, 0.0, 0.0), &aim, &truth);
        Some(ApproachFrame {
            index,
            time_s,
            truth_runway_m,
            left,
            right,
        })
    }
}

/// Where `point` (stereo frame) appears in the camera of a PTU at `ptu` turned to (`pan_rad`,
/// `tilt_rad`): pixels right of and above the image centre, exact pinhole projection. `None`
/// behind the camera.
pub fn ptu_camera_offset_px(
    ptu: &Vector3<f64>,
    pan_rad: f64,
    tilt_rad: f64,
    focal_px: f64,
    point: &Vector3<f64>,
) -> Option<[f64; 2]> {
    let forward = LineOfSight::new(pan_rad, tilt_rad).direction();
    let (sin_psi, cos_psi) = pan_rad.sin_cos();
    let (sin_phi, cos_phi) = tilt_rad.sin_cos();
    let right = Vector3::new(cos_psi, -sin_psi, 0.0);
    let up = Vector3::new(-sin_phi * sin_psi, -sin_phi * cos_psi, cos_phi);
    let d = point - ptu;
    let depth = d.dot(&forward);
    (depth > 0.0).then(|| {
        [
            focal_px * d.dot(&right) / depth,
            focal_px * d.dot(&up) / depth,
        ]
    })
}

/// A fix's error, estimate − truth (runway frame), at the aircraft's distance to touchdown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixError {
    pub distance_m: f64,
    pub error_m: Vector3<f64>,
}

/// One row of a Table 5-like summary: the fixes whose distance lies in (near_m, far_m]
/// (the nearest interval includes 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntervalRow {
    pub far_m: f64,
    pub near_m: f64,
    pub count: usize,
    /// Mean |error| per axis [X lateral, Y along the runway, Z height].
    pub mean_abs_error_m: [f64; 3],
    pub rms_error_m: [f64; 3],
}

/// Mean absolute and RMS errors per `interval_m` of distance, farthest first (the seed's
/// Table 5 layout). Intervals without fixes are left out.
pub fn interval_table(
    errors: &[FixError],
    interval_m: f64,
) -> Result<Vec<IntervalRow>, ApproachError> {
    if !(interval_m.is_finite() && interval_m > 0.0) {
        return Err(ApproachError::Interval(interval_m));
    }
    let bin = |distance: f64| ((distance / interval_m).ceil() as usize).saturating_sub(1);
    let bins = errors
        .iter()
        .map(|e| bin(e.distance_m))
        .max()
        .map_or(0, |b| b + 1);
    let mut sums = vec![([0.0; 3], [0.0; 3], 0usize); bins];
    for e in errors.iter().filter(|e| e.distance_m.is_finite()) {
        let (abs, sq, count) = &mut sums[bin(e.distance_m)];
        for axis in 0..3 {
            abs[axis] += e.error_m[axis].abs();
            sq[axis] += e.error_m[axis].powi(2);
        }
        *count += 1;
    }
    Ok(sums
        .iter()
        .enumerate()
        .rev()
        .filter(|(_, (_, _, count))| *count > 0)
        .map(|(i, (abs, sq, count))| {
            let n = *count as f64;
            IntervalRow {
                far_m: (i + 1) as f64 * interval_m,
                near_m: i as f64 * interval_m,
                count: *count,
                mean_abs_error_m: abs.map(|s| s / n),
                rms_error_m: sq.map(|s| (s / n).sqrt()),
            }
        })
        .collect())
}

/// The seed's Table 5 (DSST + BBP in flight against DGPS): (far, near, i, j, k) in metres, the
/// errors along its axes i (lateral), j (depth, along the runway) and k (height) of O_c.
pub const PAPER_TABLE_5: [(f64, f64, f64, f64, f64); 30] = [
    (600.0, 580.0, 0.348, 1.862, 0.441),
    (580.0, 560.0, 0.322, 1.444, 0.362),
    (560.0, 540.0, 0.218, 1.557, 0.327),
    (540.0, 520.0, 0.197, 1.558, 0.284),
    (520.0, 500.0, 0.228, 1.841, 0.183),
    (500.0, 480.0, 0.229, 1.430, 0.226),
    (480.0, 460.0, 0.192, 1.483, 0.233),
    (460.0, 440.0, 0.183, 1.472, 0.239),
    (440.0, 420.0, 0.192, 1.431, 0.121),
    (420.0, 400.0, 0.191, 1.663, 0.199),
    (400.0, 380.0, 0.169, 1.662, 0.193),
    (380.0, 360.0, 0.171, 1.542, 0.185),
    (360.0, 340.0, 0.173, 1.541, 0.183),
    (340.0, 320.0, 0.153, 1.333, 0.161),
    (320.0, 300.0, 0.156, 1.311, 0.163),
    (300.0, 280.0, 0.138, 1.526, 0.153),
    (280.0, 260.0, 0.142, 1.413, 0.178),
    (260.0, 240.0, 0.103, 1.114, 0.124),
    (240.0, 220.0, 0.094, 0.711, 0.132),
    (220.0, 200.0, 0.105, 0.898, 0.143),
    (200.0, 180.0, 0.151, 0.831, 0.163),
    (180.0, 160.0, 0.163, 0.842, 0.134),
    (160.0, 140.0, 0.157, 0.913, 0.192),
    (140.0, 120.0, 0.142, 0.725, 0.160),
    (120.0, 100.0, 0.169, 0.922, 0.149),
    (100.0, 80.0, 0.147, 0.797, 0.069),
    (80.0, 60.0, 0.133, 0.697, 0.079),
    (60.0, 40.0, 0.114, 0.441, 0.068),
    (40.0, 20.0, 0.124, 0.312, 0.064),
    (20.0, 0.0, 0.082, 0.284, 0.103),
];

/// The mean of Table 5's rows inside (near_m, far_m], when they cover it exactly.
pub fn paper_table_5_mean(far_m: f64, near_m: f64) -> Option<[f64; 3]> {
    let rows: Vec<_> = PAPER_TABLE_5
        .iter()
        .filter(|r| r.0 <= far_m + 1e-9 && r.1 >= near_m - 1e-9)
        .collect();
    let covered: f64 = rows.iter().map(|r| r.0 - r.1).sum();
    if rows.is_empty() || (covered - (far_m - near_m)).abs() > 1e-6 {
        return None;
    }
    let n = rows.len() as f64;
    Some([
        rows.iter().map(|r| r.2).sum::<f64>() / n,
        rows.iter().map(|r| r.3).sum::<f64>() / n,
        rows.iter().map(|r| r.4).sum::<f64>() / n,
    ])
}

/// SplitMix64 with Box–Muller: small, seedable and the same on every platform.
#[derive(Debug, Clone)]
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1].
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) + 1) as f64 / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::triangulation::Side;

    fn noise_free() -> ApproachConfig {
        ApproachConfig {
            ptu_noise_rad: 0.0,
            pixel_noise_px: 0.0,
            ..ApproachConfig::default()
        }
    }

    #[test]
    fn the_flight_follows_the_glide_slope_to_touchdown() {
        let config = ApproachConfig::default();
        let frames: Vec<_> = config.frames().unwrap().collect();
        assert_eq!(frames.len(), 1001); // 40 s at 25 fps, both ends
        let first = frames[0].truth_runway_m;
        let last = frames.last().unwrap().truth_runway_m;
        assert_eq!(first.y, 1000.0);
        assert!((first.z - 1000.0 * 3f64.to_radians().tan()).abs() < 1e-9);
        assert!(last.norm() < 1e-9, "{last:?}");
        for w in frames.windows(2) {
            let step = w[0].truth_runway_m - w[1].truth_runway_m;
            assert!((step.y - 1.0).abs() < 1e-9, "{step:?}"); // 25 m/s at 25 fps
            assert!((step.z / step.y - 3f64.to_radians().tan()).abs() < 1e-9);
        }
        // Deterministic for a seed, different across seeds.
        let again: Vec<_> = config.frames().unwrap().collect();
        assert_eq!(frames, again);
        let other: Vec<_> = ApproachConfig { seed: 1, ..config }
            .frames()
            .unwrap()
            .collect();
        assert_ne!(frames[5].left, other[5].left);
    }

    /// Without noise the readings triangulate back to the truth: the projection, Eq. 5 and
    /// Eq. 14 agree, up to Eq. 5's small-offset approximation on a tilted PTU.
    #[test]
    fn noise_free_readings_give_the_truth() {
        let config = noise_free();
        let rig = config.rig().unwrap();
        for frame in config.frames().unwrap().step_by(50) {
            let offset = frame.left.target_offset_px.unwrap();
            assert!(offset[0].abs() + offset[1].abs() > 0.0 || frame.index == 0);
            // Eq. 5's lines of sight against the exact ones. Adding the pixel's pan to a tilted
            // PTU's pan misses by about ψc·ϕp²/2: largest (~1 µrad) some 40 m out, where the
            // PTU lags most and still looks up; 2 % of the PTU's 0.1 mrad noise.
            let truth = rig.runway_to_stereo(&frame.truth_runway_m);
            for (side, reading) in [(Side::Left, frame.left), (Side::Right, frame.right)] {
                let exact = LineOfSight::towards(&rig.ptu_stereo_m(side), &truth).unwrap();
                let los = reading.line_of_sight(rig.camera(), side).unwrap();
                let miss = (los.pan_rad - exact.pan_rad).hypot(los.tilt_rad - exact.tilt_rad);
                assert!(miss < 2e-6, "frame {} {side}: {miss} rad", frame.index);
            }
            // ...so the fix is off by at most what 2 µrad does at this depth (y²/D per rad).
            let fix = rig.locate(&frame.left, &frame.right).unwrap();
            let error = (fix.position_runway_m - frame.truth_runway_m).norm();
            let tolerance = 1e-6 + truth.y.powi(2) / config.baseline_m * 4e-6;
            assert!(error < tolerance, "frame {}: {error} m", frame.index);
        }
    }

    #[test]
    fn the_camera_projection_matches_eq_5_on_an_untilted_ptu() {
        let focal_px = 26_666.7;
        let camera = CameraIntrinsics::new(100.0, 100_000.0 / 26_666.7).unwrap();
        let point = Vector3::new(40.0, 500.0, 0.0);
        let (pan, tilt) = (0.07, 0.0);
        let [u, v] = ptu_camera_offset_px(&Vector3::zeros(), pan, tilt, focal_px, &point).unwrap();
        let reading = PtuReading {
            pan_rad: pan,
            tilt_rad: tilt,
            target_offset_px: Some([u, v]),
        };
        let los = reading.line_of_sight(&camera, Side::Left).unwrap();
        assert!((los.pan_rad - (40.0f64 / 500.0).atan()).abs() < 1e-12);
        assert!(los.tilt_rad.abs() < 1e-12);
        // A point straight ahead is at the centre; one behind is not imaged.
        let ahead = LineOfSight::new(0.3, 0.1).direction() * 100.0;
        let centre = ptu_camera_offset_px(&Vector3::zeros(), 0.3, 0.1, focal_px, &ahead).unwrap();
        assert!(centre[0].abs() < 1e-9 && centre[1].abs() < 1e-9);
        assert!(ptu_camera_offset_px(&Vector3::zeros(), 0.3, 0.1, focal_px, &-ahead).is_none());
    }

    #[test]
    fn the_noise_has_the_configured_spread() {
        let config = ApproachConfig {
            ptu_noise_rad: 1e-3,
            pixel_noise_px: 2.0,
            ..ApproachConfig::default()
        };
        let clean: Vec<_> = noise_free().frames().unwrap().collect();
        let noisy: Vec<_> = config.frames().unwrap().collect();
        let n = clean.len() as f64;
        let (mut pan_sq, mut px_sq) = (0.0, 0.0);
        for (c, d) in clean.iter().zip(&noisy) {
            pan_sq += (d.right.pan_rad - c.right.pan_rad).powi(2);
            px_sq +=
                (d.left.target_offset_px.unwrap()[1] - c.left.target_offset_px.unwrap()[1]).powi(2);
        }
        let pan_sigma = (pan_sq / n).sqrt();
        let px_sigma = (px_sq / n).sqrt();
        assert!((0.9e-3..1.1e-3).contains(&pan_sigma), "{pan_sigma}");
        assert!((1.8..2.2).contains(&px_sigma), "{px_sigma}");
    }

    #[test]
    fn intervals_average_by_distance() {
        let errors = [
            FixError {
                distance_m: 0.0,
                error_m: Vector3::new(1.0, -2.0, 0.0),
            },
            FixError {
                distance_m: 100.0,
                error_m: Vector3::new(-3.0, 2.0, 4.0),
            },
            FixError {
                distance_m: 100.5,
                error_m: Vector3::new(1.0, 1.0, 1.0),
            },
            FixError {
                distance_m: 350.0,
                error_m: Vector3::new(0.0, 6.0, 0.0),
            },
        ];
        let rows = interval_table(&errors, 100.0).unwrap();
        // Farthest first; the empty 200–300 interval is left out.
        let spans: Vec<_> = rows.iter().map(|r| (r.far_m, r.near_m, r.count)).collect();
        assert_eq!(
            spans,
            vec![(400.0, 300.0, 1), (200.0, 100.0, 1), (100.0, 0.0, 2)]
        );
        assert_eq!(rows[2].mean_abs_error_m, [2.0, 2.0, 2.0]);
        assert!((rows[2].rms_error_m[0] - 5f64.sqrt()).abs() < 1e-12);
        assert!(interval_table(&errors, 0.0).is_err());
    }

    #[test]
    fn table_5_means_cover_whole_intervals_only() {
        let near = paper_table_5_mean(40.0, 0.0).unwrap();
        assert!((near[1] - (0.312 + 0.284) / 2.0).abs() < 1e-12);
        assert_eq!(paper_table_5_mean(700.0, 600.0), None);
        assert_eq!(paper_table_5_mean(650.0, 550.0), None);
        let all = paper_table_5_mean(600.0, 0.0).unwrap();
        assert!(
            all[1] > all[0] && all[1] > all[2],
            "depth has the largest errors"
        );
    }

    #[test]
    fn bad_configs_are_named_errors() {
        let bad = ApproachConfig {
            ground_speed_m_s: 0.0,
            ..ApproachConfig::default()
        };
        assert!(matches!(
            bad.frames(),
            Err(ApproachError::NotPositive {
                what: "ground_speed_m_s",
                ..
            })
        ));
        let steep = ApproachConfig {
            glide_angle_rad: 1.0,
            ..ApproachConfig::default()
        };
        assert!(matches!(
            steep.validate(),
            Err(ApproachError::GlideAngle(_))
        ));
        let noisy = ApproachConfig {
            pixel_noise_px: f64::NAN,
            ..ApproachConfig::default()
        };
        assert!(noisy.validate().is_err());
    }
}
