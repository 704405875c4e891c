//! Ray triangulation of the ground stereo rig (seed 001, §3.2 and §4.2).
//!
//! Each PTU reports its pan ψp and tilt ϕp; its camera sees the target (u − u0, v − v0) pixels
//! off the image centre. Eq. 5 turns the offset into angles ψc, ϕc, and the line of sight is
//! ψ = ψc + ψp, ϕ = ϕc + ϕp. Two lines of sight from PTUs D metres apart give the target:
//! - [`closed_form`]: Eq. 6, where the lines' horizontal projections cross, at the height of the
//!   left line of sight there. It is what the seed's Tables 1 and 2 were computed with (see
//!   [`super::error_analysis`]).
//! - [`common_perpendicular`]: Eqs. 8–14. Measured lines are skew; the target is the weighted
//!   point w·Pl + (1 − w)·Pr of the shortest segment PlPr between them, found from
//!   ∂J/∂tl = ∂J/∂tr = 0 (Eq. 12), which needs det H ≠ 0.
//!
//! Frames: see [`super`] for the stereo frame; [`StereoRig`] places it on the runway.

use nalgebra::Vector3;
use std::fmt;
use thiserror::Error;

/// The default threshold on det H = |l × r|² (the squared sine of the angle between the lines of
/// sight): 1e-12 is an angle of 1 µrad, a target 10 000 km off a 10 m baseline, so only lines
/// that really are parallel (or a rig that is not on one target) are refused.
pub const DEFAULT_MIN_DET_H: f64 = 1e-12;

/// Which PTU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Left,
    Right,
}

impl fmt::Display for Side {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Side::Left => "left",
            Side::Right => "right",
        })
    }
}

/// Why one pair of readings gives no position. A reading's problem, not the rig's: the next pair
/// may well be fine.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TriangulationError {
    #[error("{what} is not a finite number ({value})")]
    NonFinite { what: &'static str, value: f64 },
    #[error("the {side} camera has no target in its image")]
    NoTarget { side: Side },
    #[error(
        "the lines of sight are near-parallel (det H = {det_h:.3e}, below {min_det_h:.1e}): \
         the target is too far for the baseline, or the PTUs are not on the same target"
    )]
    NearParallel { det_h: f64, min_det_h: f64 },
    #[error(
        "the lines of sight meet behind the {side} PTU ({range_m:.1} m along its line of sight): \
         the PTUs are not on the same target"
    )]
    BehindPtu { side: Side, range_m: f64 },
    #[error(
        "the {side} pan {pan_rad:.4} rad is not within ±π/2: Eq. 6 only holds for targets in \
         front of the baseline"
    )]
    PanOutOfRange { side: Side, pan_rad: f64 },
}

/// A rig that cannot be built as configured.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RigError {
    #[error("baseline_m must be a finite number > 0, got {0}")]
    Baseline(f64),
    #[error("focal_length_mm must be a finite number > 0, got {0}")]
    FocalLength(f64),
    #[error("pixel_pitch_um must be a finite number > 0, got {0}")]
    PixelPitch(f64),
    #[error("the left weight w of Eq. 14 must lie in [0, 1], got {0}")]
    Weight(f64),
    #[error("min_det_h must be a finite number ≥ 0, got {0}")]
    MinDetH(f64),
    #[error("{what} must be finite, got {value}")]
    NonFinite { what: &'static str, value: f64 },
}

fn finite(what: &'static str, value: f64) -> Result<f64, TriangulationError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(TriangulationError::NonFinite { what, value })
    }
}

/// A line of sight's pan ψ and tilt ϕ in the stereo frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineOfSight {
    pub pan_rad: f64,
    pub tilt_rad: f64,
}

impl LineOfSight {
    pub fn new(pan_rad: f64, tilt_rad: f64) -> Self {
        Self { pan_rad, tilt_rad }
    }

    /// The unit direction (a, b, c) of Eq. 9.
    pub fn direction(&self) -> Vector3<f64> {
        let (sin_psi, cos_psi) = self.pan_rad.sin_cos();
        let (sin_phi, cos_phi) = self.tilt_rad.sin_cos();
        Vector3::new(cos_phi * sin_psi, cos_phi * cos_psi, sin_phi)
    }

    /// The line of sight from `from` to `to` (stereo frame): the exact angles a PTU at `from`
    /// would need to centre `to`. `None` when the points coincide.
    pub fn towards(from: &Vector3<f64>, to: &Vector3<f64>) -> Option<Self> {
        let d = to - from;
        let horizontal = d.x.hypot(d.y);
        if horizontal == 0.0 && d.z == 0.0 {
            return None;
        }
        Some(Self {
            pan_rad: d.x.atan2(d.y),
            tilt_rad: d.z.atan2(horizontal),
        })
    }

    fn check(&self, side: Side) -> Result<(), TriangulationError> {
        let (pan, tilt) = match side {
            Side::Left => ("left pan", "left tilt"),
            Side::Right => ("right pan", "right tilt"),
        };
        finite(pan, self.pan_rad)?;
        finite(tilt, self.tilt_rad)?;
        Ok(())
    }
}

/// The camera on a PTU: focal length and (square) pixel pitch, du = dv of Eq. 5.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraIntrinsics {
    focal_length_mm: f64,
    pixel_pitch_um: f64,
}

impl CameraIntrinsics {
    /// The seed's camera: 100 mm lens on a DFK 23G445 (Sony ICX445, 3.75 µm pixels), §5.1.
    pub const SEED_FOCAL_LENGTH_MM: f64 = 100.0;
    pub const SEED_PIXEL_PITCH_UM: f64 = 3.75;

    pub fn new(focal_length_mm: f64, pixel_pitch_um: f64) -> Result<Self, RigError> {
        if !(focal_length_mm.is_finite() && focal_length_mm > 0.0) {
            return Err(RigError::FocalLength(focal_length_mm));
        }
        if !(pixel_pitch_um.is_finite() && pixel_pitch_um > 0.0) {
            return Err(RigError::PixelPitch(pixel_pitch_um));
        }
        Ok(Self {
            focal_length_mm,
            pixel_pitch_um,
        })
    }

    /// The seed's camera and lens.
    pub fn seed() -> Self {
        Self {
            focal_length_mm: Self::SEED_FOCAL_LENGTH_MM,
            pixel_pitch_um: Self::SEED_PIXEL_PITCH_UM,
        }
    }

    pub fn focal_length_mm(&self) -> f64 {
        self.focal_length_mm
    }

    pub fn pixel_pitch_um(&self) -> f64 {
        self.pixel_pitch_um
    }

    /// f / du: the focal length in pixels (the unit of [`super::bbp`]).
    pub fn focal_length_px(&self) -> f64 {
        self.focal_length_mm * 1000.0 / self.pixel_pitch_um
    }

    /// Eq. 5: the angles (ψc, ϕc) of a target `offset_right_px` right of and `offset_up_px` above
    /// the image centre: ψc = arctan((u − u0)·du / f), ϕc = arctan((v − v0)·cos ψc·dv / f).
    /// Exact for a pinhole camera whose axes are those of an untilted PTU.
    pub fn compensation_rad(&self, offset_right_px: f64, offset_up_px: f64) -> (f64, f64) {
        let pixel_over_focal = self.pixel_pitch_um / (self.focal_length_mm * 1000.0);
        let psi_c = (offset_right_px * pixel_over_focal).atan();
        let phi_c = (offset_up_px * psi_c.cos() * pixel_over_focal).atan();
        (psi_c, phi_c)
    }
}

/// What one PTU reports for one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PtuReading {
    /// The PTU's pan ψp (encoder), stereo-frame convention.
    pub pan_rad: f64,
    /// The PTU's tilt ϕp (encoder).
    pub tilt_rad: f64,
    /// Where the tracker put the target's centre: pixels [right of, above] the image centre
    /// (u − u0, v − v0 of Eq. 5, v counted upwards). `None` when the tracker lost it.
    pub target_offset_px: Option<[f64; 2]>,
}

impl PtuReading {
    /// The line of sight to the target: ψ = ψc + ψp, ϕ = ϕc + ϕp (the equation after Eq. 5).
    pub fn line_of_sight(
        &self,
        camera: &CameraIntrinsics,
        side: Side,
    ) -> Result<LineOfSight, TriangulationError> {
        let [right_px, up_px] = self
            .target_offset_px
            .ok_or(TriangulationError::NoTarget { side })?;
        let (pan, tilt, right, up) = match side {
            Side::Left => (
                "left PTU pan",
                "left PTU tilt",
                "left target offset (right)",
                "left target offset (up)",
            ),
            Side::Right => (
                "right PTU pan",
                "right PTU tilt",
                "right target offset (right)",
                "right target offset (up)",
            ),
        };
        finite(pan, self.pan_rad)?;
        finite(tilt, self.tilt_rad)?;
        finite(right, right_px)?;
        finite(up, up_px)?;
        let (psi_c, phi_c) = camera.compensation_rad(right_px, up_px);
        Ok(LineOfSight::new(
            self.pan_rad + psi_c,
            self.tilt_rad + phi_c,
        ))
    }
}

/// The shortest segment between the two lines of sight (Eqs. 10–14), in the stereo frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommonPerpendicular {
    /// Its foot Pl = (xlp, ylp, zlp) on the left line of sight.
    pub left_foot_m: Vector3<f64>,
    /// Its foot Pr = (xrp, yrp, zrp) on the right line of sight.
    pub right_foot_m: Vector3<f64>,
    /// tl, tr: how far along each line of sight the feet are.
    pub left_range_m: f64,
    pub right_range_m: f64,
    /// det H of Eq. 13.
    pub det_h: f64,
}

impl CommonPerpendicular {
    /// Eq. 14: w·Pl + (1 − w)·Pr.
    pub fn point(&self, weight_left: f64) -> Vector3<f64> {
        self.left_foot_m * weight_left + self.right_foot_m * (1.0 - weight_left)
    }

    /// |PlPr|: how far the lines of sight miss each other, a check on the readings.
    pub fn miss_distance_m(&self) -> f64 {
        (self.left_foot_m - self.right_foot_m).norm()
    }
}

/// Eqs. 10–14: the common perpendicular of the lines of sight from Ol = (0, 0, 0) and
/// Or = (D, 0, 0). Refused when det H < `min_det_h` (near-parallel lines: no unique
/// perpendicular) or when the feet lie behind a PTU.
pub fn common_perpendicular(
    baseline_m: f64,
    left: LineOfSight,
    right: LineOfSight,
    min_det_h: f64,
) -> Result<CommonPerpendicular, TriangulationError> {
    finite("baseline", baseline_m)?;
    left.check(Side::Left)?;
    right.check(Side::Right)?;
    let l = left.direction();
    let r = right.direction();
    // H of Eq. 13: [[l·l, −l·r], [−l·r, r·r]].
    let ll = l.dot(&l);
    let rr = r.dot(&r);
    let lr = l.dot(&r);
    let det_h = ll * rr - lr * lr;
    if det_h.is_nan() || det_h < min_det_h || det_h <= 0.0 {
        return Err(TriangulationError::NearParallel { det_h, min_det_h });
    }
    // The seed's denominator, |l × r|² (equal to det H by Lagrange's identity, but free of the
    // cancellation in ll·rr − lr² when the lines are close to parallel).
    let cross = (l.x * r.y - l.y * r.x).powi(2)
        + (l.y * r.z - l.z * r.y).powi(2)
        + (l.x * r.z - l.z * r.x).powi(2);
    // Eq. 14's parameters with Ol − Or = (−D, 0, 0).
    let t_l = baseline_m * (l.x * rr - r.x * lr) / cross;
    let t_r = baseline_m * (l.x * lr - r.x * ll) / cross;
    if t_l <= 0.0 {
        return Err(TriangulationError::BehindPtu {
            side: Side::Left,
            range_m: t_l,
        });
    }
    if t_r <= 0.0 {
        return Err(TriangulationError::BehindPtu {
            side: Side::Right,
            range_m: t_r,
        });
    }
    Ok(CommonPerpendicular {
        left_foot_m: l * t_l,
        right_foot_m: Vector3::new(baseline_m, 0.0, 0.0) + r * t_r,
        left_range_m: t_l,
        right_range_m: t_r,
        det_h,
    })
}

/// Eq. 6: xM = D tan ψl / (tan ψl − tan ψr), yM = D / (tan ψl − tan ψr),
/// zM = D tan ϕl / (cos ψl (tan ψl − tan ψr)). The right tilt does not enter.
pub fn closed_form(
    baseline_m: f64,
    left: LineOfSight,
    right: LineOfSight,
    min_det_h: f64,
) -> Result<Vector3<f64>, TriangulationError> {
    finite("baseline", baseline_m)?;
    left.check(Side::Left)?;
    right.check(Side::Right)?;
    for (side, line) in [(Side::Left, left), (Side::Right, right)] {
        if line.pan_rad.abs() >= std::f64::consts::FRAC_PI_2 {
            return Err(TriangulationError::PanOutOfRange {
                side,
                pan_rad: line.pan_rad,
            });
        }
    }
    // The same parallelism test as the common perpendicular, so both estimators refuse alike.
    let (l, r) = (left.direction(), right.direction());
    let det_h = l.cross(&r).norm_squared();
    if det_h.is_nan() || det_h < min_det_h || det_h <= 0.0 {
        return Err(TriangulationError::NearParallel { det_h, min_det_h });
    }
    let tan_l = left.pan_rad.tan();
    let disparity = tan_l - right.pan_rad.tan();
    let y = baseline_m / disparity;
    if !(y > 0.0 && y.is_finite()) {
        // Horizontal projections that diverge (or are parallel) meet behind the baseline.
        return Err(TriangulationError::BehindPtu {
            side: Side::Left,
            range_m: y,
        });
    }
    Ok(Vector3::new(
        y * tan_l,
        y,
        y * left.tilt_rad.tan() / left.pan_rad.cos(),
    ))
}

/// Which estimate of the target to make from two lines of sight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Estimator {
    /// Eq. 14 with the left weight w ∈ [0, 1] (0.5: the middle of the common perpendicular).
    CommonPerpendicular { weight_left: f64 },
    /// Eq. 6.
    ClosedForm,
}

impl Default for Estimator {
    fn default() -> Self {
        Estimator::CommonPerpendicular { weight_left: 0.5 }
    }
}

/// A position from one pair of readings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoFix {
    pub position_runway_m: Vector3<f64>,
    pub position_stereo_m: Vector3<f64>,
    /// How far the two lines of sight miss each other (0 for the closed form, which forces them
    /// to meet): large values mean the PTUs are on different targets or badly calibrated.
    pub miss_distance_m: f64,
}

/// The two PTUs on the runway, their cameras and the estimator.
///
/// The runway frame: origin at the touchdown point on the centre line, Y along the centre line
/// out towards the approaching aircraft (a point's Y is its distance to touchdown), Z up, X to the
/// right seen from the PTUs looking out along Y (right-handed). The stereo frame's origin, the
/// left PTU, stands at `left_ptu_runway_m`; its X axis (the baseline) is the runway's X turned by
/// `baseline_yaw_rad` about Z (counterclockwise seen from above), so with yaw 0 the two frames
/// are parallel and zero pan looks straight out along the approach.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoRig {
    baseline_m: f64,
    left_ptu_runway_m: Vector3<f64>,
    baseline_yaw_rad: f64,
    camera: CameraIntrinsics,
    estimator: Estimator,
    min_det_h: f64,
}

impl StereoRig {
    pub fn new(
        baseline_m: f64,
        left_ptu_runway_m: Vector3<f64>,
        baseline_yaw_rad: f64,
        camera: CameraIntrinsics,
        estimator: Estimator,
        min_det_h: f64,
    ) -> Result<Self, RigError> {
        if !(baseline_m.is_finite() && baseline_m > 0.0) {
            return Err(RigError::Baseline(baseline_m));
        }
        for (what, value) in [
            ("left_ptu_runway_m[0]", left_ptu_runway_m.x),
            ("left_ptu_runway_m[1]", left_ptu_runway_m.y),
            ("left_ptu_runway_m[2]", left_ptu_runway_m.z),
            ("baseline yaw", baseline_yaw_rad),
        ] {
            if !value.is_finite() {
                return Err(RigError::NonFinite { what, value });
            }
        }
        if let Estimator::CommonPerpendicular { weight_left } = estimator {
            if !(0.0..=1.0).contains(&weight_left) {
                return Err(RigError::Weight(weight_left));
            }
        }
        if !(min_det_h.is_finite() && min_det_h >= 0.0) {
            return Err(RigError::MinDetH(min_det_h));
        }
        Ok(Self {
            baseline_m,
            left_ptu_runway_m,
            baseline_yaw_rad,
            camera,
            estimator,
            min_det_h,
        })
    }

    /// The seed's rig (D = 10 m, 100 mm lens, 3.75 µm pixels) straddling the centre line
    /// `setback_m` behind the touchdown point, midpoint of the common perpendicular.
    pub fn seed(setback_m: f64) -> Result<Self, RigError> {
        Self::new(
            10.0,
            Vector3::new(-5.0, -setback_m, 0.0),
            0.0,
            CameraIntrinsics::seed(),
            Estimator::default(),
            DEFAULT_MIN_DET_H,
        )
    }

    pub fn baseline_m(&self) -> f64 {
        self.baseline_m
    }

    pub fn camera(&self) -> &CameraIntrinsics {
        &self.camera
    }

    pub fn estimator(&self) -> Estimator {
        self.estimator
    }

    pub fn left_ptu_runway_m(&self) -> Vector3<f64> {
        self.left_ptu_runway_m
    }

    pub fn right_ptu_runway_m(&self) -> Vector3<f64> {
        self.stereo_to_runway(&Vector3::new(self.baseline_m, 0.0, 0.0))
    }

    /// The stereo frame's origin, in the stereo frame: (D, 0, 0) for the right PTU.
    pub fn ptu_stereo_m(&self, side: Side) -> Vector3<f64> {
        match side {
            Side::Left => Vector3::zeros(),
            Side::Right => Vector3::new(self.baseline_m, 0.0, 0.0),
        }
    }

    pub fn stereo_to_runway(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let (s, c) = self.baseline_yaw_rad.sin_cos();
        self.left_ptu_runway_m + Vector3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z)
    }

    pub fn runway_to_stereo(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let (s, c) = self.baseline_yaw_rad.sin_cos();
        let d = p - self.left_ptu_runway_m;
        Vector3::new(c * d.x + s * d.y, -s * d.x + c * d.y, d.z)
    }

    /// Triangulates two lines of sight (stereo frame) with the rig's estimator.
    pub fn triangulate(
        &self,
        left: LineOfSight,
        right: LineOfSight,
    ) -> Result<StereoFix, TriangulationError> {
        let (position_stereo_m, miss_distance_m) = match self.estimator {
            Estimator::CommonPerpendicular { weight_left } => {
                let segment = common_perpendicular(self.baseline_m, left, right, self.min_det_h)?;
                (segment.point(weight_left), segment.miss_distance_m())
            }
            Estimator::ClosedForm => (
                closed_form(self.baseline_m, left, right, self.min_det_h)?,
                0.0,
            ),
        };
        Ok(StereoFix {
            position_runway_m: self.stereo_to_runway(&position_stereo_m),
            position_stereo_m,
            miss_distance_m,
        })
    }

    /// One pair of readings → the target's position: Eq. 5 on each side, then the estimator.
    pub fn locate(
        &self,
        left: &PtuReading,
        right: &PtuReading,
    ) -> Result<StereoFix, TriangulationError> {
        let left = left.line_of_sight(&self.camera, Side::Left)?;
        let right = right.line_of_sight(&self.camera, Side::Right)?;
        self.triangulate(left, right)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    const D: f64 = 10.0;

    fn sight(from: Vector3<f64>, to: Vector3<f64>) -> LineOfSight {
        LineOfSight::towards(&from, &to).unwrap()
    }

    fn pair(target: Vector3<f64>) -> (LineOfSight, LineOfSight) {
        (
            sight(Vector3::zeros(), target),
            sight(Vector3::new(D, 0.0, 0.0), target),
        )
    }

    /// The closest points of two lines by a generic least-squares solve (nalgebra's SVD of the
    /// 3×2 system [l, −r]·[tl, tr]ᵀ = Or − Ol), independent of Eq. 14's closed form.
    fn least_squares_feet(left: LineOfSight, right: LineOfSight) -> (Vector3<f64>, Vector3<f64>) {
        let l = left.direction();
        let r = right.direction();
        let a = DMatrix::from_row_slice(3, 2, &[l.x, -r.x, l.y, -r.y, l.z, -r.z]);
        let b = DVector::from_vec(vec![D, 0.0, 0.0]);
        let t = a.svd(true, true).solve(&b, 1e-15).unwrap();
        (l * t[0], Vector3::new(D, 0.0, 0.0) + r * t[1])
    }

    /// Brute force: the distance between the lines minimised over (tl, tr) by shrinking a grid
    /// search, with no calculus at all.
    fn grid_search_feet(left: LineOfSight, right: LineOfSight) -> (f64, f64) {
        let l = left.direction();
        let r = right.direction();
        let or = Vector3::new(D, 0.0, 0.0);
        let distance = |tl: f64, tr: f64| (l * tl - (or + r * tr)).norm_squared();
        let (mut tl, mut tr, mut step) = (500.0, 500.0, 250.0);
        while step > 1e-7 {
            let mut best = (distance(tl, tr), tl, tr);
            for i in -4..=4 {
                for j in -4..=4 {
                    let (a, b) = (tl + i as f64 * step / 4.0, tr + j as f64 * step / 4.0);
                    let d = distance(a, b);
                    if d < best.0 {
                        best = (d, a, b);
                    }
                }
            }
            (tl, tr) = (best.1, best.2);
            step *= 0.6;
        }
        (tl, tr)
    }

    #[test]
    fn noise_free_angles_recover_the_point_exactly() {
        for target in [
            Vector3::new(5.0, 1000.0, 52.4),
            Vector3::new(-40.0, 300.0, 20.0),
            Vector3::new(60.0, 25.0, -1.0),
            Vector3::new(5.0, 4000.0, 490.0),
        ] {
            let (l, r) = pair(target);
            let segment = common_perpendicular(D, l, r, DEFAULT_MIN_DET_H).unwrap();
            for w in [0.0, 0.3, 0.5, 1.0] {
                let error = (segment.point(w) - target).norm();
                assert!(error < 1e-9 * target.norm(), "{target:?} w={w}: {error}");
            }
            assert!(segment.miss_distance_m() < 1e-8, "{segment:?}");
            let closed = closed_form(D, l, r, DEFAULT_MIN_DET_H).unwrap();
            assert!(
                (closed - target).norm() < 1e-9 * target.norm(),
                "{closed:?}"
            );
        }
    }

    #[test]
    fn skew_lines_meet_at_the_least_squares_and_brute_force_feet() {
        let target = Vector3::new(3.0, 600.0, 40.0);
        let (mut l, mut r) = pair(target);
        // Disturb the lines so they are skew: 2 mrad on the left tilt, 0.5 mrad on the right pan.
        l.tilt_rad += 2e-3;
        r.pan_rad -= 5e-4;
        let segment = common_perpendicular(D, l, r, DEFAULT_MIN_DET_H).unwrap();
        assert!(segment.miss_distance_m() > 0.1, "{segment:?}");
        let (left_foot, right_foot) = least_squares_feet(l, r);
        assert!(
            (segment.left_foot_m - left_foot).norm() < 1e-6,
            "{segment:?} vs {left_foot:?}"
        );
        assert!((segment.right_foot_m - right_foot).norm() < 1e-6);
        let (tl, tr) = grid_search_feet(l, r);
        assert!((segment.left_range_m - tl).abs() < 1e-3, "{tl} {segment:?}");
        assert!(
            (segment.right_range_m - tr).abs() < 1e-3,
            "{tr} {segment:?}"
        );
        // The segment is perpendicular to both lines.
        let pq = segment.right_foot_m - segment.left_foot_m;
        assert!(pq.dot(&l.direction()).abs() < 1e-9 * pq.norm());
        assert!(pq.dot(&r.direction()).abs() < 1e-9 * pq.norm());
        // det H is |l × r|² (Lagrange's identity, the seed's denominator).
        let cross = l.direction().cross(&r.direction()).norm_squared();
        assert!((segment.det_h - cross).abs() < 1e-12);
    }

    #[test]
    fn parallel_lines_are_a_named_error() {
        let l = LineOfSight::new(0.01, 0.05);
        let error = common_perpendicular(D, l, l, DEFAULT_MIN_DET_H).unwrap_err();
        assert!(
            matches!(error, TriangulationError::NearParallel { .. }),
            "{error}"
        );
        assert!(error.to_string().contains("near-parallel"));
        // 1e-7 rad apart: det H ≈ 1e-14 < 1e-12.
        let nearly = LineOfSight::new(0.01 + 1e-7, 0.05);
        assert!(matches!(
            common_perpendicular(D, l, nearly, DEFAULT_MIN_DET_H),
            Err(TriangulationError::NearParallel { .. })
        ));
        assert!(matches!(
            closed_form(D, l, nearly, DEFAULT_MIN_DET_H),
            Err(TriangulationError::NearParallel { .. })
        ));
        // A target at 4 km off a 10 m baseline is well within reach.
        let (l, r) = pair(Vector3::new(5.0, 4000.0, 300.0));
        assert!(common_perpendicular(D, l, r, DEFAULT_MIN_DET_H).is_ok());
    }

    #[test]
    fn lines_that_diverge_meet_behind_the_ptus() {
        // Left looks left, right looks right: they "meet" behind the baseline.
        let l = LineOfSight::new(-0.1, 0.0);
        let r = LineOfSight::new(0.1, 0.0);
        assert!(matches!(
            common_perpendicular(D, l, r, DEFAULT_MIN_DET_H),
            Err(TriangulationError::BehindPtu {
                side: Side::Left,
                ..
            })
        ));
        assert!(matches!(
            closed_form(D, l, r, DEFAULT_MIN_DET_H),
            Err(TriangulationError::BehindPtu { .. })
        ));
        assert!(matches!(
            closed_form(D, LineOfSight::new(1.6, 0.0), r, DEFAULT_MIN_DET_H),
            Err(TriangulationError::PanOutOfRange {
                side: Side::Left,
                ..
            })
        ));
    }

    #[test]
    fn non_finite_input_is_a_named_error_not_a_panic() {
        let good = LineOfSight::new(0.0, 0.0);
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let error =
                common_perpendicular(D, LineOfSight::new(bad, 0.0), good, 1e-12).unwrap_err();
            assert!(
                matches!(error, TriangulationError::NonFinite { what: "left pan", value } if !value.is_finite()),
                "{error}"
            );
            assert!(matches!(
                closed_form(D, good, LineOfSight::new(0.0, bad), 1e-12),
                Err(TriangulationError::NonFinite {
                    what: "right tilt",
                    ..
                })
            ));
            assert!(matches!(
                common_perpendicular(bad, good, good, 1e-12),
                Err(TriangulationError::NonFinite {
                    what: "baseline",
                    ..
                })
            ));
            let reading = PtuReading {
                pan_rad: 0.0,
                tilt_rad: 0.0,
                target_offset_px: Some([1.0, bad]),
            };
            assert!(matches!(
                reading.line_of_sight(&CameraIntrinsics::seed(), Side::Right),
                Err(TriangulationError::NonFinite {
                    what: "right target offset (up)",
                    ..
                })
            ));
        }
    }

    /// Eq. 5 against a pinhole camera: a target that projects `offset` pixels off the centre of an
    /// untilted camera at pan ψp has the line of sight ψp + ψc, ϕc.
    #[test]
    fn pixel_compensation_matches_a_pinhole_projection() {
        let camera = CameraIntrinsics::new(100.0, 3.75).unwrap();
        let f_px = camera.focal_length_px();
        assert!((f_px - 26_666.666_666).abs() < 1e-3);
        let pan_p = 0.2;
        for (right_px, up_px) in [(0.0, 0.0), (120.0, -35.0), (-600.0, 400.0)] {
            // The ray through the pixel, in the camera frame (x right, y up, z along the axis)...
            let ray = Vector3::new(right_px, up_px, f_px);
            // ...and in the stereo frame: the untilted camera's axes after a pan ψp.
            let (s, c) = f64::sin_cos(pan_p);
            let world = Vector3::new(c * ray.x + s * ray.z, -s * ray.x + c * ray.z, ray.y);
            let truth = sight(Vector3::zeros(), world);
            let reading = PtuReading {
                pan_rad: pan_p,
                tilt_rad: 0.0,
                target_offset_px: Some([right_px, up_px]),
            };
            let los = reading.line_of_sight(&camera, Side::Left).unwrap();
            assert!(
                (los.pan_rad - truth.pan_rad).abs() < 1e-12,
                "{los:?} {truth:?}"
            );
            assert!((los.tilt_rad - truth.tilt_rad).abs() < 1e-12);
        }
        let lost = PtuReading {
            pan_rad: 0.0,
            tilt_rad: 0.0,
            target_offset_px: None,
        };
        assert_eq!(
            lost.line_of_sight(&camera, Side::Left),
            Err(TriangulationError::NoTarget { side: Side::Left })
        );
    }

    #[test]
    fn the_rig_places_the_stereo_frame_on_the_runway() {
        let rig = StereoRig::new(
            12.0,
            Vector3::new(-6.0, -30.0, 1.5),
            0.2,
            CameraIntrinsics::seed(),
            Estimator::default(),
            DEFAULT_MIN_DET_H,
        )
        .unwrap();
        // Round trip, and the right PTU D metres from the left along the yawed baseline.
        let p = Vector3::new(3.0, 700.0, 40.0);
        assert!((rig.stereo_to_runway(&rig.runway_to_stereo(&p)) - p).norm() < 1e-9);
        let right = rig.right_ptu_runway_m();
        assert!(((right - rig.left_ptu_runway_m()).norm() - 12.0).abs() < 1e-12);
        assert!(
            (right - Vector3::new(-6.0 + 12.0 * 0.2f64.cos(), -30.0 + 12.0 * 0.2f64.sin(), 1.5))
                .norm()
                < 1e-12
        );
        // Exact angles from both PTUs (computed in the runway frame, rotated by hand) → p.
        let angles = |ptu: Vector3<f64>| {
            let d = p - ptu;
            // Rotate the offset into the stereo frame by −yaw.
            let (s, c) = 0.2f64.sin_cos();
            let ds = Vector3::new(c * d.x + s * d.y, -s * d.x + c * d.y, d.z);
            LineOfSight::new(ds.x.atan2(ds.y), ds.z.atan2(ds.x.hypot(ds.y)))
        };
        let fix = rig
            .triangulate(angles(rig.left_ptu_runway_m()), angles(right))
            .unwrap();
        assert!((fix.position_runway_m - p).norm() < 1e-8, "{fix:?}");
        // Bad rigs are named errors.
        let camera = CameraIntrinsics::seed();
        assert_eq!(
            StereoRig::new(
                0.0,
                Vector3::zeros(),
                0.0,
                camera,
                Estimator::default(),
                1e-12
            ),
            Err(RigError::Baseline(0.0))
        );
        assert_eq!(
            StereoRig::new(
                10.0,
                Vector3::zeros(),
                0.0,
                camera,
                Estimator::CommonPerpendicular { weight_left: 1.5 },
                1e-12
            ),
            Err(RigError::Weight(1.5))
        );
        assert_eq!(
            CameraIntrinsics::new(-1.0, 3.75),
            Err(RigError::FocalLength(-1.0))
        );
        assert_eq!(
            CameraIntrinsics::new(100.0, 0.0),
            Err(RigError::PixelPitch(0.0))
        );
    }
}
