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
mod tests;
