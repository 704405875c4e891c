//! From the binary image to candidate quadrilaterals: connected dark regions (run-length
//! labelling), the outer contour of each plausible region (Moore-neighbour following), and a
//! Douglas–Peucker polygon that must come out as a convex quad.

use super::threshold::BinaryImage;

/// A dark 8-connected region: its bounding box and its first pixel in raster order, which is
/// always on its outer contour.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Region {
    pub min_x: i32,
    pub max_x: i32,
    pub min_y: i32,
    pub max_y: i32,
    pub start_x: i32,
    pub start_y: i32,
}

#[derive(Debug, Clone, Copy)]
struct Run {
    y: i32,
    /// First pixel.
    x0: i32,
    /// One past the last pixel.
    x1: i32,
}

/// Bounding box of the runs joined to a root so far.
#[derive(Debug, Clone, Copy)]
struct Bounds {
    min_x: i32,
    max_x: i32,
    max_y: i32,
}

/// Reusable buffers of the contour stage.
#[derive(Debug, Default)]
pub(crate) struct ContourScratch {
    runs: Vec<Run>,
    parent: Vec<u32>,
    /// Per run; meaningful for roots only.
    bounds: Vec<Bounds>,
    pub regions: Vec<Region>,
    pub contour: Vec<[i32; 2]>,
    keep: Vec<bool>,
    stack: Vec<(usize, usize)>,
    /// The polygon's vertices as indices into `contour`, in contour order.
    pub polygon: Vec<usize>,
    side_points: Vec<[f32; 2]>,
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let grand = parent[parent[i as usize] as usize];
        parent[i as usize] = grand;
        i = grand;
    }
    i
}

const BYTE_ONES: u64 = 0x0101_0101_0101_0101;

/// First index from `x` whose byte is `value` (0 or 1), or `row.len()`; eight bytes at a time,
/// since runs are long and most of a row is one or the other.
#[inline]
fn next_with(row: &[u8], mut x: usize, value: u8) -> usize {
    // Bytes equal to `value` become 1, the others 0.
    let flip = if value == 1 { 0 } else { BYTE_ONES };
    while x + 8 <= row.len() {
        let mut word = [0u8; 8];
        word.copy_from_slice(&row[x..x + 8]);
        let hits = u64::from_le_bytes(word) ^ flip;
        if hits != 0 {
            return x + (hits.trailing_zeros() / 8) as usize;
        }
        x += 8;
    }
    while x < row.len() && row[x] != value {
        x += 1;
    }
    x
}

fn merge(bounds: &mut [Bounds], into: u32, from: Bounds) {
    let b = &mut bounds[into as usize];
    b.min_x = b.min_x.min(from.min_x);
    b.max_x = b.max_x.max(from.max_x);
    b.max_y = b.max_y.max(from.max_y);
}

/// Labels the dark regions of `bin` into `scratch.regions`.
pub(crate) fn label_regions(bin: &BinaryImage, scratch: &mut ContourScratch) {
    let runs = &mut scratch.runs;
    let parent = &mut scratch.parent;
    let bounds = &mut scratch.bounds;
    runs.clear();
    parent.clear();
    bounds.clear();
    let mut prev_start = 0usize;
    let mut prev_end = 0usize;
    for y in 0..bin.height {
        let row_start = (y + 1) * bin.stride + 1;
        let row = &bin.data[row_start..row_start + bin.width];
        let this_start = runs.len();
        let mut above = prev_start;
        let mut x = next_with(row, 0, 1);
        while x < row.len() {
            let end = next_with(row, x, 0);
            let run = Run {
                y: y as i32,
                x0: x as i32,
                x1: end as i32,
            };
            x = next_with(row, end, 1);
            let id = runs.len() as u32;
            runs.push(run);
            parent.push(id);
            let own = Bounds {
                min_x: run.x0,
                max_x: run.x1 - 1,
                max_y: run.y,
            };
            bounds.push(own);
            // Runs of the row above that touch this one, diagonals included (8-connectivity).
            while above < prev_end && runs[above].x1 < run.x0 {
                above += 1;
            }
            let mut k = above;
            // The new run joins the first run it touches; it is a root until then.
            let mut root = id;
            while k < prev_end && runs[k].x0 <= run.x1 {
                let other = find(parent, k as u32);
                if root == id {
                    root = other;
                    parent[id as usize] = other;
                    merge(bounds, other, own);
                } else if other != root {
                    // The older root wins, so a region's root is its first run.
                    let (lo, hi) = if other < root {
                        (other, root)
                    } else {
                        (root, other)
                    };
                    parent[hi as usize] = lo;
                    let moved = bounds[hi as usize];
                    merge(bounds, lo, moved);
                    root = lo;
                }
                k += 1;
            }
            // The last touching run may also touch the next run of this row.
            above = k.saturating_sub(1).max(above);
        }
        prev_start = this_start;
        prev_end = runs.len();
    }

    scratch.regions.clear();
    for (i, run) in runs.iter().enumerate() {
        if parent[i] == i as u32 {
            // A root is its region's first run, so it starts at the region's first pixel.
            let b = bounds[i];
            scratch.regions.push(Region {
                min_x: b.min_x,
                max_x: b.max_x,
                min_y: run.y,
                max_y: b.max_y,
                start_x: run.x0,
                start_y: run.y,
            });
        }
    }
}

/// Neighbour steps clockwise on screen (y down), starting east.
const STEPS: [[i32; 2]; 8] = [
    [1, 0],
    [1, 1],
    [0, 1],
    [-1, 1],
    [-1, 0],
    [-1, -1],
    [0, -1],
    [1, -1],
];

/// Follows the outer contour of the region whose first pixel is (x, y), clockwise on screen,
/// into `out`. Gives up (returns false) past `max_points`.
pub(crate) fn trace_outer_contour(
    bin: &BinaryImage,
    x: i32,
    y: i32,
    max_points: usize,
    out: &mut Vec<[i32; 2]>,
) -> bool {
    let stride = bin.stride as isize;
    let offsets: [isize; 8] = STEPS.map(|[dx, dy]| dy as isize * stride + dx as isize);
    let start_index = bin.index(x as isize, y as isize);
    out.clear();
    out.push([x, y]);
    let (mut px, mut py, mut index) = (x, y, start_index);
    // The first pixel's west neighbour is background: the region has no pixel before it.
    let mut backtrack = 4usize;
    let mut first_step = None;
    loop {
        let mut found = None;
        for i in 1..8 {
            let dir = (backtrack + i) & 7;
            if bin.data[(index as isize + offsets[dir]) as usize] != 0 {
                found = Some(dir);
                break;
            }
        }
        let Some(dir) = found else {
            return true; // a lone pixel
        };
        if index == start_index {
            match first_step {
                // Back at the start about to repeat the first step: the contour is closed.
                Some(first) if first == dir => {
                    out.pop();
                    return true;
                }
                None => first_step = Some(dir),
                _ => {}
            }
        }
        px += STEPS[dir][0];
        py += STEPS[dir][1];
        index = (index as isize + offsets[dir]) as usize;
        out.push([px, py]);
        if out.len() > max_points {
            return false;
        }
        // The last background pixel seen, now relative to the new pixel.
        backtrack = if dir % 2 == 0 {
            (dir + 6) & 7
        } else {
            (dir + 5) & 7
        };
    }
}

/// Length of a closed chain of 8-connected pixels.
pub(crate) fn contour_length_px(contour: &[[i32; 2]]) -> f32 {
    let mut length = 0.0;
    for (i, p) in contour.iter().enumerate() {
        let q = contour[(i + 1) % contour.len()];
        length += if p[0] != q[0] && p[1] != q[1] {
            std::f32::consts::SQRT_2
        } else {
            1.0
        };
    }
    length
}

fn distance_sq(a: [i32; 2], b: [i32; 2]) -> i64 {
    let dx = i64::from(a[0] - b[0]);
    let dy = i64::from(a[1] - b[1]);
    dx * dx + dy * dy
}

/// Distance of `p` from the line through `a` and `b` (from `a` when they coincide).
fn line_distance(p: [f32; 2], a: [f32; 2], b: [f32; 2]) -> f32 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let length = (dx * dx + dy * dy).sqrt();
    if length < 1e-6 {
        return ((p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2)).sqrt();
    }
    ((p[0] - a[0]) * dy - (p[1] - a[1]) * dx).abs() / length
}

fn as_f32(p: [i32; 2]) -> [f32; 2] {
    [p[0] as f32, p[1] as f32]
}

/// Douglas–Peucker approximation of the closed `scratch.contour` with tolerance `epsilon_px`,
/// into `scratch.polygon` (in contour order). Vertices that end up within `epsilon_px` of the
/// line through their neighbours are dropped, so where the chain starts does not matter.
pub(crate) fn approximate_polygon(scratch: &mut ContourScratch, epsilon_px: f32) {
    let contour = &scratch.contour;
    let n = contour.len();
    scratch.polygon.clear();
    if n < 3 {
        return;
    }
    // Split at two far-apart points, both vertices of any convex shape, so neither chain
    // starts mid-edge.
    let far_a = (0..n)
        .max_by_key(|&i| distance_sq(contour[0], contour[i]))
        .unwrap_or(0);
    let far_b = (0..n)
        .max_by_key(|&i| distance_sq(contour[far_a], contour[i]))
        .unwrap_or(0);
    let keep = &mut scratch.keep;
    keep.clear();
    keep.resize(n, false);
    keep[far_a] = true;
    keep[far_b] = true;
    let stack = &mut scratch.stack;
    stack.clear();
    // Chains as (start, length) along the closed contour.
    let span = (far_b + n - far_a) % n;
    stack.push((far_a, span));
    stack.push((far_b, n - span));
    while let Some((start, length)) = stack.pop() {
        if length < 2 {
            continue;
        }
        let a = as_f32(contour[start]);
        let b = as_f32(contour[(start + length) % n]);
        let mut worst = 0.0;
        let mut worst_k = 0;
        for k in 1..length {
            let d = line_distance(as_f32(contour[(start + k) % n]), a, b);
            if d > worst {
                worst = d;
                worst_k = k;
            }
        }
        if worst > epsilon_px {
            keep[(start + worst_k) % n] = true;
            stack.push((start, worst_k));
            stack.push(((start + worst_k) % n, length - worst_k));
        }
    }
    let polygon = &mut scratch.polygon;
    polygon.extend((0..n).filter(|&i| keep[i]));
    // Drop vertices that are not corners (nearly on the line through their neighbours).
    let at = |i: usize| as_f32(contour[i]);
    let mut changed = true;
    while changed && polygon.len() > 3 {
        changed = false;
        for i in 0..polygon.len() {
            let m = polygon.len();
            let prev = at(polygon[(i + m - 1) % m]);
            let next = at(polygon[(i + 1) % m]);
            if line_distance(at(polygon[i]), prev, next) <= epsilon_px {
                polygon.remove(i);
                changed = true;
                break;
            }
        }
    }
}

/// The vertices of a four-vertex `scratch.polygon` as pixel coordinates.
pub(crate) fn polygon_quad(scratch: &ContourScratch) -> Option<[[f32; 2]; 4]> {
    if scratch.polygon.len() != 4 {
        return None;
    }
    Some([0, 1, 2, 3].map(|k| as_f32(scratch.contour[scratch.polygon[k]])))
}

/// Corners of a four-vertex polygon from lines fitted to the contour between its vertices,
/// which blur cannot round off as it does the vertices themselves. The contour runs through
/// the centres of the region's edge pixels, so each line is moved out by half a pixel onto
/// the region's edge. `None` when a side is too short to fit.
pub(crate) fn fitted_quad(scratch: &mut ContourScratch) -> Option<[[f32; 2]; 4]> {
    let quad = polygon_quad(scratch)?;
    let n = scratch.contour.len();
    // Outward is left of the direction of travel for a clockwise contour, right otherwise.
    let outward = if signed_area2(&quad) > 0.0 { 1.0 } else { -1.0 };
    let mut lines = [None; 4];
    for (side, line) in lines.iter_mut().enumerate() {
        let start = scratch.polygon[side];
        let end = scratch.polygon[(side + 1) % 4];
        let length = (end + n - start) % n;
        // Leave out the ends, where the corner is rounded.
        let skip = length / 5;
        scratch.side_points.clear();
        scratch
            .side_points
            .extend((skip..=length - skip).map(|k| as_f32(scratch.contour[(start + k) % n])));
        if scratch.side_points.len() < 3 {
            return None;
        }
        let mut fitted = super::refine::fit_line(&scratch.side_points)?;
        // Point the direction along the travel so that the normal's side is known.
        let (a, b) = (quad[side], quad[(side + 1) % 4]);
        let along = (b[0] - a[0]) * fitted.direction[0] + (b[1] - a[1]) * fitted.direction[1];
        if along < 0.0 {
            fitted.direction = [-fitted.direction[0], -fitted.direction[1]];
        }
        let normal = [
            fitted.direction[1] * outward,
            -fitted.direction[0] * outward,
        ];
        fitted.point = [
            fitted.point[0] + 0.5 * normal[0],
            fitted.point[1] + 0.5 * normal[1],
        ];
        *line = Some(fitted);
    }
    let mut corners = [[0.0f32; 2]; 4];
    for (i, corner) in corners.iter_mut().enumerate() {
        let (a, b) = (lines[(i + 3) % 4]?, lines[i]?);
        *corner = super::refine::intersect(&a, &b)?;
    }
    Some(corners)
}

/// Twice the signed area; positive for clockwise on screen (y down).
pub(crate) fn signed_area2(quad: &[[f32; 2]; 4]) -> f32 {
    (0..4)
        .map(|i| {
            let (p, q) = (quad[i], quad[(i + 1) % 4]);
            p[0] * q[1] - q[0] * p[1]
        })
        .sum()
}

/// Whether the quad turns the same way at every corner.
pub(crate) fn is_convex(quad: &[[f32; 2]; 4]) -> bool {
    let mut sign = 0.0f32;
    for i in 0..4 {
        let (a, b, c) = (quad[i], quad[(i + 1) % 4], quad[(i + 2) % 4]);
        let cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]);
        if cross == 0.0 || (sign != 0.0 && cross.signum() != sign) {
            return false;
        }
        sign = cross.signum();
    }
    true
}

#[cfg(test)]
mod tests {
    use super::super::threshold::{
        adaptive_threshold, PixelRect, ThresholdMethod, ThresholdScratch,
    };
    use super::*;
    use crate::vision::image::GrayImage;

    fn binary_of(image: &GrayImage) -> BinaryImage {
        let mut bin = BinaryImage::default();
        let rect = PixelRect {
            x: 0,
            y: 0,
            width: image.width(),
            height: image.height(),
        };
        let method = ThresholdMethod::IntegralImage;
        let mut scratch = ThresholdScratch::default();
        adaptive_threshold(&image.view(), rect, 31, 10, method, &mut scratch, &mut bin);
        bin
    }

    #[test]
    fn regions_are_labelled_with_8_connectivity() {
        let mut image = GrayImage::filled(30, 20, 220).unwrap();
        // Two squares joined only diagonally, and a separate bar; U shape to force merges.
        for (x0, y0, x1, y1) in [(2, 2, 5, 5), (6, 6, 9, 9), (15, 2, 17, 12), (21, 2, 23, 12)] {
            for y in y0..=y1 {
                for x in x0..=x1 {
                    image.set(x, y, 10);
                }
            }
        }
        for x in 15..=23 {
            image.set(x, 12, 10);
        }
        let bin = binary_of(&image);
        let mut scratch = ContourScratch::default();
        label_regions(&bin, &mut scratch);
        let mut boxes: Vec<_> = scratch
            .regions
            .iter()
            .map(|r| (r.min_x, r.min_y, r.max_x, r.max_y, r.start_x, r.start_y))
            .collect();
        boxes.sort();
        assert_eq!(boxes, vec![(2, 2, 9, 9, 2, 2), (15, 2, 23, 12, 15, 2)]);
    }

    #[test]
    fn the_contour_of_a_rotated_square_gives_its_four_corners() {
        // A square of side 40 turned by 30° about (50, 50), drawn by point-in-polygon.
        let mut image = GrayImage::filled(100, 100, 230).unwrap();
        let (c, s) = (30f32.to_radians().cos(), 30f32.to_radians().sin());
        let corners: Vec<[f32; 2]> = [[-20.0, -20.0], [20.0, -20.0], [20.0, 20.0], [-20.0, 20.0]]
            .iter()
            .map(|[x, y]| [50.0 + c * x - s * y, 50.0 + s * x + c * y])
            .collect();
        for y in 0..100 {
            for x in 0..100 {
                let (u, v) = (x as f32 - 50.0, y as f32 - 50.0);
                let (ru, rv) = (c * u + s * v, -s * u + c * v);
                if ru.abs() < 20.0 && rv.abs() < 20.0 {
                    image.set(x, y, 15);
                }
            }
        }
        let bin = binary_of(&image);
        let mut scratch = ContourScratch::default();
        label_regions(&bin, &mut scratch);
        assert_eq!(scratch.regions.len(), 1);
        let region = scratch.regions[0];
        let mut contour = std::mem::take(&mut scratch.contour);
        assert!(trace_outer_contour(
            &bin,
            region.start_x,
            region.start_y,
            1000,
            &mut contour
        ));
        // Every step moves to an 8-neighbour and the chain closes.
        for (i, p) in contour.iter().enumerate() {
            let q = contour[(i + 1) % contour.len()];
            assert!((p[0] - q[0]).abs() <= 1 && (p[1] - q[1]).abs() <= 1 && p != &q);
        }
        let length = contour_length_px(&contour);
        assert!((length - 160.0).abs() < 12.0, "{length}");
        scratch.contour = contour;
        approximate_polygon(&mut scratch, 0.03 * length);
        assert_eq!(scratch.polygon.len(), 4, "{:?}", scratch.polygon);
        let quad = polygon_quad(&scratch).unwrap();
        assert!(is_convex(&quad));
        assert!(signed_area2(&quad) > 0.0, "clockwise on screen");
        for corner in corners {
            let nearest = quad
                .iter()
                .map(|p| ((p[0] - corner[0]).powi(2) + (p[1] - corner[1]).powi(2)).sqrt())
                .fold(f32::MAX, f32::min);
            assert!(nearest < 2.0, "{corner:?} vs {quad:?}");
        }
    }

    #[test]
    fn lone_pixels_and_overlong_contours() {
        let mut image = GrayImage::filled(20, 20, 220).unwrap();
        image.set(10, 10, 0);
        let bin = binary_of(&image);
        let mut out = Vec::new();
        assert!(trace_outer_contour(&bin, 10, 10, 100, &mut out));
        assert_eq!(out, vec![[10, 10]]);

        let mut image = GrayImage::filled(40, 40, 220).unwrap();
        for y in 5..35 {
            for x in 5..35 {
                image.set(x, y, 0);
            }
        }
        let bin = binary_of(&image);
        assert!(!trace_outer_contour(&bin, 5, 5, 50, &mut out));
        assert!(trace_outer_contour(&bin, 5, 5, 500, &mut out));
        assert_eq!(out.len(), 4 * 29);
    }

    #[test]
    fn convexity() {
        let square = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        assert!(is_convex(&square));
        let dart = [[0.0, 0.0], [2.0, 0.0], [0.5, 0.5], [0.0, 2.0]];
        assert!(!is_convex(&dart));
        let bow_tie = [[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]];
        assert!(!is_convex(&bow_tie));
    }
}
