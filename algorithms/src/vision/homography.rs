//! Frame-to-frame homography for motion compensation (seed 000, §2.2.2, equations 7–10): the
//! ground plane seen from two camera poses is related by a homography H; mapping the target's
//! previous position through H removes the camera's own motion, so what is left between the
//! mapped previous position and the current one is the target's motion over the ground.
//!
//! Estimation: normalised DLT (Hartley) on matched points, inside RANSAC with a seeded
//! generator (deterministic for a seed), then a least-squares DLT refit on the inliers. Frames
//! must be rectified (pinhole): the seed corrects the fisheye image first.

use nalgebra::{DMatrix, Matrix3, Vector3};
use thiserror::Error;

use super::features::Correspondence;
use super::render::SplitMix64;

/// A homography that cannot be estimated or built.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HomographyError {
    #[error("a homography needs at least {needed} point pairs, got {found}")]
    TooFewPoints { needed: usize, found: usize },
    #[error("{previous} points in the previous frame but {current} in the current one")]
    LengthMismatch { previous: usize, current: usize },
    #[error("point pair {index} is not finite")]
    NotFinite { index: usize },
    #[error(
        "the points are degenerate (coincident or collinear): they do not determine a homography"
    )]
    Degenerate,
    #[error("the matrix is singular or not finite: it is not a homography")]
    Singular,
    #[error(
        "RANSAC found no homography that {needed} point pairs agree with (best: {found}); the \
         frames may share too little texture"
    )]
    NoConsensus { found: usize, needed: usize },
    #[error("RANSAC setting {name} must be {why}, got {value}")]
    Config {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
}

/// A plane-to-plane projective map of pixels, scaled so that its Frobenius norm is 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Homography {
    matrix: Matrix3<f64>,
}

impl Homography {
    /// Checks that `matrix` is finite and invertible; it is rescaled (a homography's scale is
    /// free).
    pub fn from_matrix(matrix: Matrix3<f64>) -> Result<Self, HomographyError> {
        let norm = matrix.norm();
        if !(norm.is_finite() && norm > 0.0) {
            return Err(HomographyError::Singular);
        }
        let matrix = matrix / norm;
        if matrix.determinant().abs() < 1e-12 {
            return Err(HomographyError::Singular);
        }
        Ok(Self { matrix })
    }

    pub fn identity() -> Self {
        Self {
            matrix: Matrix3::identity() / 3f64.sqrt(),
        }
    }

    /// The matrix (Frobenius norm 1).
    pub fn matrix(&self) -> &Matrix3<f64> {
        &self.matrix
    }

    /// The matrix scaled so that its bottom-right entry is 1, when that entry is not ~0.
    pub fn normalized_matrix(&self) -> Option<Matrix3<f64>> {
        let h33 = self.matrix[(2, 2)];
        (h33.abs() > 1e-12).then(|| self.matrix / h33)
    }

    /// Equations 7–9: `(x′, y′, w′) = H (u, v, 1)`, then `(x′/w′, y′/w′)`. `None` where w′ is ~0
    /// (the point maps to infinity).
    pub fn map(&self, u_px: f64, v_px: f64) -> Option<(f64, f64)> {
        let p = self.matrix * Vector3::new(u_px, v_px, 1.0);
        let scale = self.matrix.row(2).abs().sum() * (u_px.abs() + v_px.abs() + 1.0);
        // Written so that a NaN refuses too.
        if p.z.abs().partial_cmp(&(1e-12 * scale)) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        Some((p.x / p.z, p.y / p.z))
    }

    /// The inverse map (current frame → previous).
    pub fn inverse(&self) -> Option<Self> {
        self.matrix
            .try_inverse()
            .and_then(|m| Self::from_matrix(m).ok())
    }
}

/// Equation 10: the pixel displacement between the previous target position mapped into the
/// current frame and the current position.
pub fn pixel_displacement_px(previous_mapped_px: (f64, f64), current_px: (f64, f64)) -> f64 {
    (previous_mapped_px.0 - current_px.0).hypot(previous_mapped_px.1 - current_px.1)
}

/// Hartley's normalisation: the similarity that moves the points' centroid to the origin and
/// their mean distance from it to √2. `None` for coincident points.
fn normalizing_transform(points: &[[f64; 2]]) -> Option<Matrix3<f64>> {
    let n = points.len() as f64;
    let cx = points.iter().map(|p| p[0]).sum::<f64>() / n;
    let cy = points.iter().map(|p| p[1]).sum::<f64>() / n;
    let mean_distance = points
        .iter()
        .map(|p| (p[0] - cx).hypot(p[1] - cy))
        .sum::<f64>()
        / n;
    if mean_distance.is_nan() || mean_distance <= 1e-12 * (cx.abs() + cy.abs() + 1.0) {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_distance;
    Some(Matrix3::new(
        s,
        0.0,
        -s * cx,
        0.0,
        s,
        -s * cy,
        0.0,
        0.0,
        1.0,
    ))
}

/// Whether all points lie on one line: the smaller principal spread is ~0 next to the larger.
fn all_collinear(points: &[[f64; 2]]) -> bool {
    let n = points.len() as f64;
    let cx = points.iter().map(|p| p[0]).sum::<f64>() / n;
    let cy = points.iter().map(|p| p[1]).sum::<f64>() / n;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in points {
        let (dx, dy) = (p[0] - cx, p[1] - cy);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    // Eigenvalues of [[sxx, sxy], [sxy, syy]].
    let mean = (sxx + syy) / 2.0;
    let spread = (((sxx - syy) / 2.0).powi(2) + sxy * sxy).sqrt();
    let (large, small) = (mean + spread, mean - spread);
    small.is_nan() || small <= 1e-12 * large
}

fn transform(m: &Matrix3<f64>, p: &[f64; 2]) -> [f64; 2] {
    let q = m * Vector3::new(p[0], p[1], 1.0);
    [q.x / q.z, q.y / q.z]
}

fn check_pairs(previous: &[[f64; 2]], current: &[[f64; 2]]) -> Result<(), HomographyError> {
    if previous.len() != current.len() {
        return Err(HomographyError::LengthMismatch {
            previous: previous.len(),
            current: current.len(),
        });
    }
    if previous.len() < 4 {
        return Err(HomographyError::TooFewPoints {
            needed: 4,
            found: previous.len(),
        });
    }
    for (index, (p, c)) in previous.iter().zip(current).enumerate() {
        if !p.iter().chain(c).all(|v| v.is_finite()) {
            return Err(HomographyError::NotFinite { index });
        }
    }
    Ok(())
}

/// The homography taking `previous[i]` to `current[i]` in the least-squares (algebraic) sense,
/// by the normalised DLT; exact for four points in general position or exact correspondences.
pub fn fit_dlt(previous: &[[f64; 2]], current: &[[f64; 2]]) -> Result<Homography, HomographyError> {
    check_pairs(previous, current)?;
    if all_collinear(previous) || all_collinear(current) {
        return Err(HomographyError::Degenerate);
    }
    let (Some(t_prev), Some(t_cur)) = (
        normalizing_transform(previous),
        normalizing_transform(current),
    ) else {
        return Err(HomographyError::Degenerate);
    };
    let n = previous.len();
    // At least 9 rows so that the SVD yields the whole right null space.
    let mut a = DMatrix::<f64>::zeros((2 * n).max(9), 9);
    for (i, (p, c)) in previous.iter().zip(current).enumerate() {
        let [x, y] = transform(&t_prev, p);
        let [xp, yp] = transform(&t_cur, c);
        let r = 2 * i;
        a.row_mut(r)
            .copy_from_slice(&[-x, -y, -1.0, 0.0, 0.0, 0.0, xp * x, xp * y, xp]);
        a.row_mut(r + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, -x, -y, -1.0, yp * x, yp * y, yp]);
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t.ok_or(HomographyError::Degenerate)?;
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    let (smallest, second) = (order[0], order[1]);
    let largest = svd.singular_values[order[order.len() - 1]];
    // A second (near-)zero singular value: the solution is not unique.
    let second_value = svd.singular_values[second];
    if second_value.is_nan() || second_value <= 1e-9 * largest {
        return Err(HomographyError::Degenerate);
    }
    let h = v_t.row(smallest);
    let normalized = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let t_cur_inv = t_cur.try_inverse().ok_or(HomographyError::Degenerate)?;
    Homography::from_matrix(t_cur_inv * normalized * t_prev)
        .map_err(|_| HomographyError::Degenerate)
}

/// RANSAC settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RansacConfig {
    /// A pair is an inlier when H maps its previous point within this of its current point, px.
    pub threshold_px: f64,
    /// Upper bound on the number of samples.
    pub max_iterations: usize,
    /// Probability of drawing at least one all-inlier sample, which sets the adaptive count.
    pub confidence: f64,
    /// Fewer inliers than this is no consensus (at least 4).
    pub min_inliers: usize,
    /// Refit-on-inliers rounds after the best sample.
    pub refine_rounds: usize,
    pub seed: u64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        Self {
            threshold_px: 2.0,
            max_iterations: 2000,
            confidence: 0.999,
            min_inliers: 12,
            refine_rounds: 3,
            seed: 0x4a45_4d53,
        }
    }
}

impl RansacConfig {
    fn validate(&self) -> Result<(), HomographyError> {
        let err = |name, value: f64, why| Err(HomographyError::Config { name, value, why });
        if !(self.threshold_px.is_finite() && self.threshold_px > 0.0) {
            return err("threshold_px", self.threshold_px, "positive and finite");
        }
        if self.max_iterations == 0 {
            return err("max_iterations", 0.0, "at least 1");
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return err("confidence", self.confidence, "strictly between 0 and 1");
        }
        Ok(())
    }
}

/// RANSAC's result.
#[derive(Debug, Clone, PartialEq)]
pub struct HomographyFit {
    pub homography: Homography,
    /// Indices of the pairs that agree with it, ascending.
    pub inliers: Vec<usize>,
    /// Root-mean-square transfer error over the inliers, px.
    pub rms_error_px: f64,
    /// Samples drawn.
    pub iterations: usize,
}

/// Forward transfer errors `|H·previous − current|` (∞ where H maps to infinity).
fn transfer_errors(h: &Homography, previous: &[[f64; 2]], current: &[[f64; 2]]) -> Vec<f64> {
    previous
        .iter()
        .zip(current)
        .map(|(p, c)| match h.map(p[0], p[1]) {
            Some((x, y)) => (x - c[0]).hypot(y - c[1]),
            None => f64::INFINITY,
        })
        .collect()
}

/// Whether three points are (nearly) on a line.
fn collinear(a: &[f64; 2], b: &[f64; 2], c: &[f64; 2]) -> bool {
    let (ux, uy) = (b[0] - a[0], b[1] - a[1]);
    let (vx, vy) = (c[0] - a[0], c[1] - a[1]);
    let cross = (ux * vy - uy * vx).abs();
    cross <= 1e-6 * (ux * ux + uy * uy + vx * vx + vy * vy)
}

fn sample_is_degenerate(points: &[[f64; 2]], idx: &[usize; 4]) -> bool {
    let p = |k: usize| &points[idx[k]];
    [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]
        .iter()
        .any(|&(a, b, c)| collinear(p(a), p(b), p(c)))
}

/// The homography most point pairs agree with, by RANSAC over minimal 4-point samples, refit
/// by least squares on its inliers.
pub fn fit_ransac(
    previous: &[[f64; 2]],
    current: &[[f64; 2]],
    config: &RansacConfig,
) -> Result<HomographyFit, HomographyError> {
    config.validate()?;
    check_pairs(previous, current)?;
    let n = previous.len();
    let needed = config.min_inliers.max(4);
    let mut rng = SplitMix64::new(config.seed);
    let mut best: Option<(Vec<usize>, f64)> = None;
    let mut any_valid_sample = false;
    let mut budget = config.max_iterations;
    let mut iterations = 0;
    while iterations < budget {
        iterations += 1;
        let mut idx = [0usize; 4];
        for k in 0..4 {
            idx[k] = loop {
                let i = (rng.next_u64() % n as u64) as usize;
                if !idx[..k].contains(&i) {
                    break i;
                }
            };
        }
        if sample_is_degenerate(previous, &idx) || sample_is_degenerate(current, &idx) {
            continue;
        }
        let sample = |pts: &[[f64; 2]]| idx.map(|i| pts[i]);
        let Ok(h) = fit_dlt(&sample(previous), &sample(current)) else {
            continue;
        };
        any_valid_sample = true;
        let errors = transfer_errors(&h, previous, current);
        let inliers: Vec<usize> = (0..n)
            .filter(|&i| errors[i] < config.threshold_px)
            .collect();
        let score: f64 = inliers.iter().map(|&i| errors[i]).sum();
        let better = match &best {
            None => true,
            Some((b, s)) => inliers.len() > b.len() || (inliers.len() == b.len() && score < *s),
        };
        if better {
            let ratio = inliers.len() as f64 / n as f64;
            budget = budget.min(adaptive_iterations(ratio, config.confidence));
            best = Some((inliers, score));
        }
    }
    if !any_valid_sample {
        return Err(HomographyError::Degenerate);
    }
    let (mut inliers, _) = best.unwrap_or_default();
    if inliers.len() < needed {
        return Err(HomographyError::NoConsensus {
            found: inliers.len(),
            needed,
        });
    }
    let mut homography = refit(previous, current, &inliers)?;
    for _ in 0..config.refine_rounds {
        let errors = transfer_errors(&homography, previous, current);
        let next: Vec<usize> = (0..n)
            .filter(|&i| errors[i] < config.threshold_px)
            .collect();
        if next == inliers || next.len() < needed {
            break;
        }
        inliers = next;
        homography = refit(previous, current, &inliers)?;
    }
    let errors = transfer_errors(&homography, previous, current);
    let rms_error_px =
        (inliers.iter().map(|&i| errors[i].powi(2)).sum::<f64>() / inliers.len() as f64).sqrt();
    Ok(HomographyFit {
        homography,
        inliers,
        rms_error_px,
        iterations,
    })
}

/// Samples needed to draw an all-inlier 4-point sample with probability `confidence`.
fn adaptive_iterations(inlier_ratio: f64, confidence: f64) -> usize {
    let all_inliers = inlier_ratio.powi(4);
    if all_inliers >= 1.0 - 1e-12 {
        return 1;
    }
    if all_inliers <= 1e-12 {
        return usize::MAX;
    }
    let k = (1.0 - confidence).ln() / (1.0 - all_inliers).ln();
    k.ceil().min(usize::MAX as f64) as usize
}

fn refit(
    previous: &[[f64; 2]],
    current: &[[f64; 2]],
    inliers: &[usize],
) -> Result<Homography, HomographyError> {
    let p: Vec<[f64; 2]> = inliers.iter().map(|&i| previous[i]).collect();
    let c: Vec<[f64; 2]> = inliers.iter().map(|&i| current[i]).collect();
    fit_dlt(&p, &c)
}

/// RANSAC on matched features (previous frame → current frame).
pub fn fit_correspondences(
    matches: &[Correspondence],
    config: &RansacConfig,
) -> Result<HomographyFit, HomographyError> {
    let previous: Vec<[f64; 2]> = matches.iter().map(|m| m.previous_px).collect();
    let current: Vec<[f64; 2]> = matches.iter().map(|m| m.current_px).collect();
    fit_ransac(&previous, &current, config)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraPose, PinholeCamera};
    use crate::vision::features::{FeatureConfig, FeatureMatcher};
    use crate::vision::render::{render, RenderOptions, Scene, Texture};
    use nalgebra::{Point3, Vector3};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    fn intrinsics(camera: &PinholeCamera) -> Matrix3<f64> {
        Matrix3::new(
            camera.fx_px,
            0.0,
            camera.cx_px,
            0.0,
            camera.fy_px,
            camera.cy_px,
            0.0,
            0.0,
            1.0,
        )
    }

    /// The ground-plane homography between two poses in closed form, H = K (R − t nᵀ/d) K⁻¹:
    /// camera-2 points are R·X1 + t, and the ground (down = 0) is nᵀX1 + d = 0 in camera 1's
    /// frame with n its upward normal and d the camera's height.
    fn closed_form(camera: &PinholeCamera, pose1: &CameraPose, pose2: &CameraPose) -> Matrix3<f64> {
        let r_wc1 = pose1.camera_to_world.rotation.to_rotation_matrix();
        let r_wc2 = pose2.camera_to_world.rotation.to_rotation_matrix();
        let r = (r_wc2.inverse() * r_wc1).into_inner();
        let t = r_wc2.inverse() * (pose1.position_ned_m() - pose2.position_ned_m());
        let n = r_wc1.inverse() * Vector3::new(0.0, 0.0, -1.0);
        let d = -pose1.position_ned_m().z;
        let k = intrinsics(camera);
        k * (r - t * n.transpose() / d) * k.try_inverse().unwrap()
    }

    fn poses() -> (PinholeCamera, CameraPose, CameraPose) {
        let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let pose1 = CameraPose::downward(Vector3::new(0.0, 0.0, -8.0), 0.02, -0.03, 0.4);
        let pose2 = CameraPose::downward(Vector3::new(0.45, -0.3, -7.7), -0.03, 0.02, 0.47);
        (camera, pose1, pose2)
    }

    fn map_h(h: &Matrix3<f64>, p: [f64; 2]) -> [f64; 2] {
        transform(h, &p)
    }

    #[test]
    fn the_closed_form_agrees_with_projecting_ground_points() {
        // The test's own reference is checked first: a ground point's two projections.
        let (camera, pose1, pose2) = poses();
        let h = closed_form(&camera, &pose1, &pose2);
        for (n, e) in [(0.0, 0.0), (1.5, -2.0), (-2.0, 1.0), (2.5, 2.5)] {
            let world = Point3::new(n, e, 0.0);
            let (u1, v1) = camera.project_world(&pose1, &world).unwrap();
            let (u2, v2) = camera.project_world(&pose2, &world).unwrap();
            let [x, y] = map_h(&h, [u1, v1]);
            assert!((x - u2).abs() < 1e-9 && (y - v2).abs() < 1e-9);
        }
    }

    #[test]
    fn exact_correspondences_give_the_true_homography() {
        let (camera, pose1, pose2) = poses();
        let truth = closed_form(&camera, &pose1, &pose2);
        let mut rng = StdRng::seed_from_u64(3);
        for count in [4, 5, 50] {
            let previous: Vec<[f64; 2]> = (0..count)
                .map(|_| [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)])
                .collect();
            let current: Vec<[f64; 2]> = previous.iter().map(|p| map_h(&truth, *p)).collect();
            let h = fit_dlt(&previous, &current).unwrap();
            let fitted = h.normalized_matrix().unwrap();
            let expected = truth / truth[(2, 2)];
            assert!(
                (fitted - expected).abs().max() < 1e-9 * expected.abs().max(),
                "{count} points:\n{fitted}\n{expected}"
            );
            let (x, y) = h.map(100.0, 400.0).unwrap();
            let [ex, ey] = map_h(&truth, [100.0, 400.0]);
            assert!((x - ex).abs() < 1e-8 && (y - ey).abs() < 1e-8);
            // The inverse maps back.
            let (bx, by) = h.inverse().unwrap().map(x, y).unwrap();
            assert!((bx - 100.0).abs() < 1e-8 && (by - 400.0).abs() < 1e-8);
        }
    }

    #[test]
    fn ransac_recovers_the_homography_despite_30_percent_outliers() {
        let (camera, pose1, pose2) = poses();
        let truth = closed_form(&camera, &pose1, &pose2);
        let mut rng = StdRng::seed_from_u64(4);
        let (mut previous, mut current, mut is_inlier) = (vec![], vec![], vec![]);
        for i in 0..200 {
            let p = [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)];
            let outlier = i % 10 < 3;
            let c = if outlier {
                [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)]
            } else {
                // Feature positions are integers: ±0.5 px of quantisation.
                let [x, y] = map_h(&truth, p);
                [x.round(), y.round()]
            };
            previous.push(p);
            current.push(c);
            is_inlier.push(!outlier);
        }
        let fit = fit_ransac(&previous, &current, &RansacConfig::default()).unwrap();
        let expected: Vec<usize> = (0..200).filter(|&i| is_inlier[i]).collect();
        assert_eq!(fit.inliers, expected);
        assert!(fit.rms_error_px < 0.5, "{}", fit.rms_error_px);
        for p in [[50.0, 50.0], [600.0, 60.0], [320.0, 240.0], [40.0, 440.0]] {
            let (x, y) = fit.homography.map(p[0], p[1]).unwrap();
            let [ex, ey] = map_h(&truth, p);
            assert!((x - ex).hypot(y - ey) < 0.3, "{p:?}: {x},{y} vs {ex},{ey}");
        }
        // Seeded: the same input gives the same result.
        assert_eq!(
            fit,
            fit_ransac(&previous, &current, &RansacConfig::default()).unwrap()
        );
    }

    #[test]
    fn rendered_frames_give_the_closed_form_ground_homography() {
        let (camera, pose1, pose2) = poses();
        let scene = Scene::new(Texture::field(77));
        let options = RenderOptions::default();
        let frame1 = render(&camera, &pose1, &scene, &options).unwrap();
        let frame2 = render(&camera, &pose2, &scene, &options).unwrap();
        let matcher = FeatureMatcher::new(FeatureConfig::default());
        let (f1, f2) = (
            matcher.features(&frame1.view()),
            matcher.features(&frame2.view()),
        );
        let matches = matcher.correspondences(&f1, &f2);
        let fit = fit_correspondences(&matches, &RansacConfig::default()).unwrap();
        assert!(fit.inliers.len() > 100, "{} inliers", fit.inliers.len());
        let truth = closed_form(&camera, &pose1, &pose2);
        for p in [
            [80.0, 80.0],
            [560.0, 90.0],
            [320.0, 240.0],
            [100.0, 400.0],
            [540.0, 380.0],
        ] {
            let (x, y) = fit.homography.map(p[0], p[1]).unwrap();
            let [ex, ey] = map_h(&truth, p);
            assert!((x - ex).hypot(y - ey) < 0.5, "{p:?}: {x},{y} vs {ex},{ey}");
        }
        // The previous target position, mapped (eq. 7–9), against where the ground point is now
        // (eq. 10 is then the target's own motion: here zero).
        let target = Point3::new(1.0, -0.5, 0.0);
        let (u1, v1) = camera.project_world(&pose1, &target).unwrap();
        let (u2, v2) = camera.project_world(&pose2, &target).unwrap();
        let mapped = fit.homography.map(u1, v1).unwrap();
        assert!(pixel_displacement_px(mapped, (u2, v2)) < 1.0);
        assert!(
            pixel_displacement_px((u1, v1), (u2, v2)) > 20.0,
            "the camera moved"
        );
    }

    #[test]
    fn degenerate_input_is_a_named_error() {
        let three = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
        assert_eq!(
            fit_dlt(&three, &three).unwrap_err(),
            HomographyError::TooFewPoints {
                needed: 4,
                found: 3
            }
        );
        let line: Vec<[f64; 2]> = (0..10).map(|i| [i as f64, 2.0 * i as f64 + 1.0]).collect();
        let moved: Vec<[f64; 2]> = line.iter().map(|p| [p[0] + 3.0, p[1] - 1.0]).collect();
        assert_eq!(fit_dlt(&line, &moved), Err(HomographyError::Degenerate));
        assert_eq!(
            fit_ransac(&line, &moved, &RansacConfig::default()),
            Err(HomographyError::Degenerate)
        );
        // Three of four on a line: four points then do not fix a homography.
        let quad = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [0.0, 5.0]];
        let quad_moved = quad.map(|p| [p[0] + 1.0, p[1]]);
        assert_eq!(
            fit_dlt(&quad, &quad_moved),
            Err(HomographyError::Degenerate)
        );
        let same = [[1.0, 1.0]; 6];
        assert_eq!(fit_dlt(&same, &same), Err(HomographyError::Degenerate));
        assert!(matches!(
            fit_dlt(&quad, &quad_moved[..3]),
            Err(HomographyError::LengthMismatch { .. })
        ));
        let mut bad = quad;
        bad[2][1] = f64::NAN;
        assert_eq!(
            fit_dlt(&bad, &quad_moved),
            Err(HomographyError::NotFinite { index: 2 })
        );
        assert_eq!(
            Homography::from_matrix(Matrix3::zeros()),
            Err(HomographyError::Singular)
        );
        // Pure noise: no consensus.
        let mut rng = StdRng::seed_from_u64(9);
        let noise: Vec<[f64; 2]> = (0..60)
            .map(|_| [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)])
            .collect();
        let other: Vec<[f64; 2]> = (0..60)
            .map(|_| [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)])
            .collect();
        assert!(matches!(
            fit_ransac(&noise, &other, &RansacConfig::default()),
            Err(HomographyError::NoConsensus { .. })
        ));
    }
}
