//! Sub-pixel corners: each side of the marker is located across its length at many points, a
//! straight line is fitted to them, and neighbouring lines are intersected.
//!
//! Each point is where the edge lies along a short profile across the side, found from the
//! profile's area: for a step from the dark level D to the bright level B at offset e, blurred
//! by any symmetric kernel, ∫ (I(s) − D)/(B − D) ds over [−R, R] equals R − e. This is linear
//! in the samples, so noise averages out, and it has no bias from where the edge falls between
//! pixel centres.

use super::decode::sample_bilinear;
use crate::vision::image::ImageView;

/// Longest step along a profile, px.
const PROFILE_STEP_PX: f32 = 0.5;

/// How sides are searched.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RefineParams {
    /// Half-length of a profile across a side, px.
    pub search_radius_px: f32,
    /// Dark and bright grey levels of the marker (from its Otsu classes).
    pub dark_level: f32,
    pub bright_level: f32,
}

/// A line as a point on it and a unit direction.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Line {
    pub point: [f32; 2],
    pub direction: [f32; 2],
}

/// Reusable buffers of the refinement.
#[derive(Debug, Default)]
pub(crate) struct RefineScratch {
    points: Vec<[f32; 2]>,
    residuals: Vec<f32>,
}

/// Refines the corners of a clockwise (on screen) quad whose corners are within about
/// `params.search_radius_px / 2` of the truth. `None` when a side cannot be located.
pub(crate) fn refine_corners(
    image: &ImageView<'_>,
    quad: &[[f32; 2]; 4],
    params: &RefineParams,
    scratch: &mut RefineScratch,
) -> Option<[[f32; 2]; 4]> {
    let mut lines = [Line {
        point: [0.0; 2],
        direction: [1.0, 0.0],
    }; 4];
    for (side, line) in lines.iter_mut().enumerate() {
        *line = locate_side(image, quad[side], quad[(side + 1) % 4], params, scratch)?;
    }
    let mut refined = [[0.0f32; 2]; 4];
    for (i, corner) in refined.iter_mut().enumerate() {
        *corner = intersect(&lines[(i + 3) % 4], &lines[i])?;
    }
    Some(refined)
}

/// Fits a line to edge points across the side from `p` to `q` (interior on the right on screen).
fn locate_side(
    image: &ImageView<'_>,
    p: [f32; 2],
    q: [f32; 2],
    params: &RefineParams,
    scratch: &mut RefineScratch,
) -> Option<Line> {
    let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
    let length = (dx * dx + dy * dy).sqrt();
    if length < 4.0 {
        return None;
    }
    let t = [dx / length, dy / length];
    // Outward normal: with y down and the interior on the right, right of t is (−ty, tx).
    let normal = [t[1], -t[0]];
    let radius = params.search_radius_px;
    let contrast = params.bright_level - params.dark_level;
    if contrast <= 0.0 {
        return None;
    }
    // Keep clear of the corners, where a profile would also cross the neighbouring side.
    let margin = (radius + 1.5).max(0.1 * length);
    if length - 2.0 * margin < 2.0 {
        return None;
    }
    let count = ((length - 2.0 * margin) / 2.0).clamp(4.0, 24.0) as usize;
    // A whole number of steps over exactly [−R, R]: the area formula needs the full span.
    let steps = ((2.0 * radius / PROFILE_STEP_PX).ceil() as usize).max(2);
    let step = 2.0 * radius / steps as f32;
    scratch.points.clear();
    for k in 0..count {
        let along = margin + (length - 2.0 * margin) * (k as f32 + 0.5) / count as f32;
        let base = [p[0] + t[0] * along, p[1] + t[1] * along];
        // Trapezoid rule over the profile of the normalised intensity.
        let mut area = 0.0;
        let mut previous = None;
        for i in 0..=steps {
            let s = -radius + i as f32 * step;
            let value = sample_bilinear(image, base[0] + normal[0] * s, base[1] + normal[1] * s);
            let level = ((value - params.dark_level) / contrast).clamp(-0.25, 1.25);
            if let Some(prev) = previous {
                area += 0.5 * (prev + level) * step;
            }
            previous = Some(level);
        }
        let offset = radius - area;
        if offset.abs() < radius {
            scratch
                .points
                .push([base[0] + normal[0] * offset, base[1] + normal[1] * offset]);
        }
    }
    if scratch.points.len() < 3 {
        return None;
    }
    let line = fit_line(&scratch.points)?;
    // One pass of outlier rejection: whatever else the profile crossed (a neighbouring blob,
    // an occluder) shows up as points far off the line.
    scratch.residuals.clear();
    scratch
        .residuals
        .extend(scratch.points.iter().map(|pt| distance(&line, *pt)));
    let mut sorted = scratch.residuals.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[sorted.len() / 2];
    let cutoff = (3.0 * median).max(0.3);
    let residuals = &scratch.residuals;
    let mut index = 0;
    scratch.points.retain(|_| {
        let keep = residuals[index] <= cutoff;
        index += 1;
        keep
    });
    if scratch.points.len() < 3 {
        return None;
    }
    fit_line(&scratch.points)
}

fn distance(line: &Line, p: [f32; 2]) -> f32 {
    let (ux, uy) = (p[0] - line.point[0], p[1] - line.point[1]);
    (ux * line.direction[1] - uy * line.direction[0]).abs()
}

/// Total least squares line through the points.
pub(crate) fn fit_line(points: &[[f32; 2]]) -> Option<Line> {
    let n = points.len() as f64;
    let (mut mx, mut my) = (0.0f64, 0.0f64);
    for p in points {
        mx += f64::from(p[0]);
        my += f64::from(p[1]);
    }
    mx /= n;
    my /= n;
    let (mut sxx, mut sxy, mut syy) = (0.0f64, 0.0f64, 0.0f64);
    for p in points {
        let (x, y) = (f64::from(p[0]) - mx, f64::from(p[1]) - my);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
    }
    // Direction of the largest eigenvector of the scatter matrix.
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    // No spread at all (or NaN from a bad sample) gives no direction.
    if sxx + syy <= 0.0 || (sxx + syy).is_nan() {
        return None;
    }
    Some(Line {
        point: [mx as f32, my as f32],
        direction: [angle.cos() as f32, angle.sin() as f32],
    })
}

pub(crate) fn intersect(a: &Line, b: &Line) -> Option<[f32; 2]> {
    let den = a.direction[0] * b.direction[1] - a.direction[1] * b.direction[0];
    if den.abs() < 1e-3 {
        return None;
    }
    let (wx, wy) = (b.point[0] - a.point[0], b.point[1] - a.point[1]);
    let s = (wx * b.direction[1] - wy * b.direction[0]) / den;
    Some([
        a.point[0] + s * a.direction[0],
        a.point[1] + s * a.direction[1],
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::image::GrayImage;

    /// A dark quad on white, each pixel the exact fraction of its area inside (supersampled).
    fn area_sampled_quad(quad: &[[f32; 2]; 4], width: usize, height: usize) -> GrayImage {
        let inside = |x: f32, y: f32| {
            (0..4).all(|i| {
                let (a, b) = (quad[i], quad[(i + 1) % 4]);
                (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]) >= 0.0
            })
        };
        let mut image = GrayImage::filled(width, height, 0).unwrap();
        const SUB: usize = 16;
        for y in 0..height {
            for x in 0..width {
                let mut covered = 0;
                for sy in 0..SUB {
                    for sx in 0..SUB {
                        let fx = x as f32 - 0.5 + (sx as f32 + 0.5) / SUB as f32;
                        let fy = y as f32 - 0.5 + (sy as f32 + 0.5) / SUB as f32;
                        covered += usize::from(inside(fx, fy));
                    }
                }
                let value = 220.0 - 190.0 * covered as f32 / (SUB * SUB) as f32;
                image.set(x, y, value.round() as u8);
            }
        }
        image
    }

    #[test]
    fn corners_of_an_area_sampled_quad_come_back_within_a_twentieth_of_a_pixel() {
        let truth = [[12.3, 10.8], [45.7, 14.2], [41.1, 47.6], [9.6, 41.9]];
        let image = area_sampled_quad(&truth, 60, 60);
        // Start a pixel or so off, as the polygon approximation leaves them.
        let rough = [[13.0, 11.5], [45.0, 15.0], [40.2, 46.8], [10.4, 41.0]];
        let params = RefineParams {
            search_radius_px: 3.0,
            dark_level: 30.0,
            bright_level: 220.0,
        };
        let mut scratch = RefineScratch::default();
        let refined = refine_corners(&image.view(), &rough, &params, &mut scratch).unwrap();
        for (r, t) in refined.iter().zip(truth) {
            let error = ((r[0] - t[0]).powi(2) + (r[1] - t[1]).powi(2)).sqrt();
            assert!(error < 0.05, "{r:?} vs {t:?}: {error}");
        }
    }

    #[test]
    fn a_flat_image_has_no_sides() {
        let image = GrayImage::filled(40, 40, 128).unwrap();
        let quad = [[5.0, 5.0], [30.0, 5.0], [30.0, 30.0], [5.0, 30.0]];
        let params = RefineParams {
            search_radius_px: 3.0,
            dark_level: 128.0,
            bright_level: 128.0,
        };
        let mut scratch = RefineScratch::default();
        assert!(refine_corners(&image.view(), &quad, &params, &mut scratch).is_none());
    }
}
