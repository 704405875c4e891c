//! Reading a candidate quad: the homography from the marker's square to the image, the mean
//! of the centre of every cell, Otsu's threshold over the marker's samples, and the bits.

use crate::vision::image::ImageView;

/// Bilinear interpolation of the image at (x, y), integer coordinates at pixel centres;
/// points outside are clamped to the edge pixels.
#[inline]
pub(crate) fn sample_bilinear(image: &ImageView<'_>, x: f32, y: f32) -> f32 {
    let max_x = (image.width() - 1) as f32;
    let max_y = (image.height() - 1) as f32;
    let x = x.clamp(0.0, max_x);
    let y = y.clamp(0.0, max_y);
    let x0 = x.floor();
    let y0 = y.floor();
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as usize, y0 as usize);
    let x1 = (x0 + 1).min(image.width() - 1);
    let y1 = (y0 + 1).min(image.height() - 1);
    let top = image.row(y0);
    let bottom = image.row(y1);
    let t = f32::from(top[x0]) + fx * (f32::from(top[x1]) - f32::from(top[x0]));
    let b = f32::from(bottom[x0]) + fx * (f32::from(bottom[x1]) - f32::from(bottom[x0]));
    t + fy * (b - t)
}

/// The projective map from the unit square, corners (0,0), (1,0), (1,1), (0,1), onto a quad in
/// that order (Heckbert's closed form: no linear system to solve for four points).
#[derive(Debug, Clone, Copy)]
pub(crate) struct SquareToQuad {
    a: f32,
    b: f32,
    c: f32,
    d: f32,
    e: f32,
    f: f32,
    g: f32,
    h: f32,
}

impl SquareToQuad {
    /// `None` for a degenerate quad (three corners in a line).
    pub fn new(quad: &[[f32; 2]; 4]) -> Option<Self> {
        let [[x0, y0], [x1, y1], [x2, y2], [x3, y3]] = *quad;
        let (dx1, dy1) = (x1 - x2, y1 - y2);
        let (dx2, dy2) = (x3 - x2, y3 - y2);
        let (dx3, dy3) = (x0 - x1 + x2 - x3, y0 - y1 + y2 - y3);
        let den = dx1 * dy2 - dx2 * dy1;
        if den.abs() < 1e-6 {
            return None;
        }
        let g = (dx3 * dy2 - dx2 * dy3) / den;
        let h = (dx1 * dy3 - dx3 * dy1) / den;
        Some(Self {
            a: x1 - x0 + g * x1,
            b: x3 - x0 + h * x3,
            c: x0,
            d: y1 - y0 + g * y1,
            e: y3 - y0 + h * y3,
            f: y0,
            g,
            h,
        })
    }

    #[inline]
    pub fn map(&self, u: f32, v: f32) -> [f32; 2] {
        let w = self.g * u + self.h * v + 1.0;
        [
            (self.a * u + self.b * v + self.c) / w,
            (self.d * u + self.e * v + self.f) / w,
        ]
    }
}

/// How a quad's cells are read.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SamplingParams {
    /// Inner bits per side.
    pub marker_size_bits: usize,
    /// Fraction of a cell's side left out at each edge.
    pub cell_margin_rate: f32,
    /// Samples per cell side.
    pub samples_per_cell: usize,
    /// Smallest difference of the Otsu class means, grey levels.
    pub min_contrast: f32,
    /// Largest spread (standard deviation) of the samples within their classes, as a fraction
    /// of the contrast: printed black and white are flat, textures are not.
    pub max_spread_rate: f32,
    /// A cell whose mean lies within this fraction of the contrast of the threshold, or whose
    /// samples fall on both sides of it, is unsure.
    pub unsure_cell_rate: f32,
    /// Unsure cells allowed.
    pub max_unsure_cells: usize,
    /// Where the quiet zone around the marker is sampled, in cells outside the border; 0
    /// skips the check.
    pub quiet_zone_cells: f32,
    /// Fraction of the quiet zone's samples that must be bright.
    pub min_quiet_zone_bright_rate: f32,
}

/// What a quad's cells say.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SampledMarker {
    /// Inner bits, black = 1, bit `row * n + col` (row 0 along corner 0 → corner 1).
    pub code: u64,
    /// Border cells that read white.
    pub border_errors: usize,
    /// Mean grey level of the dark and the bright class.
    pub dark_level: f32,
    pub bright_level: f32,
}

/// Reusable buffers of the sampling.
#[derive(Debug, Default)]
pub(crate) struct SamplingScratch {
    samples: Vec<u8>,
    cell_means: Vec<f32>,
}

/// Samples the centre region of every cell of the quad (border included) and classifies the
/// cells with Otsu's threshold over all samples. `None` when the quad is degenerate or its
/// samples show no contrast (a uniform blob is not a marker, whatever its noise says).
pub(crate) fn sample_marker(
    image: &ImageView<'_>,
    quad: &[[f32; 2]; 4],
    params: &SamplingParams,
    scratch: &mut SamplingScratch,
) -> Option<SampledMarker> {
    let map = SquareToQuad::new(quad)?;
    let n = params.marker_size_bits;
    let cells = n + 2;
    let s = params.samples_per_cell.max(1);
    let inner = 1.0 - 2.0 * params.cell_margin_rate;
    let step = inner / s as f32;
    let scale = 1.0 / cells as f32;
    scratch.samples.clear();
    scratch.cell_means.clear();
    for row in 0..cells {
        for col in 0..cells {
            let mut sum = 0.0;
            for i in 0..s {
                let v = (row as f32 + params.cell_margin_rate + (i as f32 + 0.5) * step) * scale;
                for j in 0..s {
                    let u =
                        (col as f32 + params.cell_margin_rate + (j as f32 + 0.5) * step) * scale;
                    let [x, y] = map.map(u, v);
                    let value = sample_bilinear(image, x, y);
                    sum += value;
                    scratch.samples.push(value.round() as u8);
                }
            }
            scratch.cell_means.push(sum / (s * s) as f32);
        }
    }
    let classes = otsu(&scratch.samples)?;
    let (dark_level, bright_level) = (classes.dark_mean, classes.bright_mean);
    // Cells are judged against the midpoint of the class means rather than Otsu's level
    // itself: with two clean levels every split between them is equally good to Otsu, and its
    // first choice hugs the dark level.
    let threshold = 0.5 * (dark_level + bright_level);
    let contrast = bright_level - dark_level;
    if contrast < params.min_contrast || classes.within_std > params.max_spread_rate * contrast {
        return None;
    }
    // A cell is unsure when its mean is near the threshold or its samples disagree: the cells
    // of a real marker are flat, while a grid that does not match the pattern (texture, or a
    // marker of another size) cuts across its edges.
    // (Samples only count as disagreeing when they are clearly across: blur softens the
    // samples near a small cell's edges without flipping them.)
    let per_cell = s * s;
    let margin = params.unsure_cell_rate * contrast;
    let unsure = scratch
        .cell_means
        .iter()
        .zip(scratch.samples.chunks_exact(per_cell))
        .filter(|&(&mean, samples)| {
            let across = |v: &u8| {
                let v = f32::from(*v);
                if mean <= threshold {
                    v > threshold + margin
                } else {
                    v < threshold - margin
                }
            };
            (mean - threshold).abs() < margin || samples.iter().any(across)
        })
        .count();
    if unsure > params.max_unsure_cells {
        return None;
    }
    if params.quiet_zone_cells > 0.0 && !quiet_zone_is_bright(image, &map, cells, params, threshold)
    {
        return None;
    }
    let mut code = 0u64;
    let mut border_errors = 0;
    for row in 0..cells {
        for col in 0..cells {
            let black = scratch.cell_means[row * cells + col] <= threshold;
            let border = row == 0 || col == 0 || row == cells - 1 || col == cells - 1;
            if border {
                border_errors += usize::from(!black);
            } else if black {
                code |= 1 << ((row - 1) * n + col - 1);
            }
        }
    }
    Some(SampledMarker {
        code,
        border_errors,
        dark_level,
        bright_level,
    })
}

/// A marker needs a bright surround: a dark blob of texture with a bright spot inside can pass
/// for a marker's border and bits, but not also for its quiet zone.
fn quiet_zone_is_bright(
    image: &ImageView<'_>,
    map: &SquareToQuad,
    cells: usize,
    params: &SamplingParams,
    threshold: f32,
) -> bool {
    let scale = 1.0 / cells as f32;
    let outside = params.quiet_zone_cells;
    let (low, high) = (-outside * scale, 1.0 + outside * scale);
    let mut bright = 0;
    let mut total = 0;
    for k in 0..=cells {
        let along = k as f32 * scale;
        for [u, v] in [
            [along, low],
            [high, along],
            [1.0 - along, high],
            [low, 1.0 - along],
        ] {
            let [x, y] = map.map(u, v);
            bright += usize::from(sample_bilinear(image, x, y) > threshold);
            total += 1;
        }
    }
    bright as f32 >= params.min_quiet_zone_bright_rate * total as f32
}

/// Otsu's split of a set of grey levels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct OtsuClasses {
    /// Levels at or below it are dark.
    pub threshold: f32,
    pub dark_mean: f32,
    pub bright_mean: f32,
    /// Standard deviation of the samples about their own class's mean.
    pub within_std: f32,
}

/// Otsu's threshold of grey levels. `None` when all samples are one level.
pub(crate) fn otsu(samples: &[u8]) -> Option<OtsuClasses> {
    let mut histogram = [0u32; 256];
    for &s in samples {
        histogram[s as usize] += 1;
    }
    let total = samples.len() as f64;
    let sum_all: f64 = histogram
        .iter()
        .enumerate()
        .map(|(level, &count)| level as f64 * f64::from(count))
        .sum();
    let (mut weight_dark, mut sum_dark) = (0.0, 0.0);
    let mut best: Option<(f64, usize, f64, f64)> = None;
    for (level, &count) in histogram.iter().enumerate() {
        weight_dark += f64::from(count);
        sum_dark += level as f64 * f64::from(count);
        let weight_bright = total - weight_dark;
        if weight_dark == 0.0 || weight_bright == 0.0 {
            continue;
        }
        let mean_dark = sum_dark / weight_dark;
        let mean_bright = (sum_all - sum_dark) / weight_bright;
        let between = weight_dark * weight_bright * (mean_bright - mean_dark).powi(2);
        if best.is_none_or(|b| between > b.0) {
            best = Some((between, level, mean_dark, mean_bright));
        }
    }
    let (between, level, dark, bright) = best?;
    // Total variance = between-class + within-class (per sample).
    let sum_sq: f64 = histogram
        .iter()
        .enumerate()
        .map(|(l, &count)| (l * l) as f64 * f64::from(count))
        .sum();
    let total_var = sum_sq / total - (sum_all / total).powi(2);
    let within_var = (total_var - between / (total * total)).max(0.0);
    Some(OtsuClasses {
        threshold: level as f32 + 0.5,
        dark_mean: dark as f32,
        bright_mean: bright as f32,
        within_std: within_var.sqrt() as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::image::GrayImage;

    #[test]
    fn the_square_maps_onto_the_quad_corners() {
        let quad = [[10.0, 12.0], [50.0, 8.0], [58.0, 47.0], [7.0, 40.0]];
        let map = SquareToQuad::new(&quad).unwrap();
        for (corner, [u, v]) in quad
            .iter()
            .zip([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        {
            let p = map.map(u, v);
            assert!((p[0] - corner[0]).abs() < 1e-3 && (p[1] - corner[1]).abs() < 1e-3);
        }
        // Projective maps keep lines: the middle of the square is where the diagonals cross.
        let centre = map.map(0.5, 0.5);
        let cross = |p: [f32; 2], a: [f32; 2], b: [f32; 2]| {
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
        };
        assert!(cross(centre, quad[0], quad[2]).abs() < 1e-2);
        assert!(cross(centre, quad[1], quad[3]).abs() < 1e-2);
        let line = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]];
        assert!(SquareToQuad::new(&line).is_none());
    }

    #[test]
    fn otsu_splits_two_levels_and_refuses_one() {
        let mut samples = vec![30u8; 40];
        samples.extend(vec![200u8; 60]);
        let classes = otsu(&samples).unwrap();
        assert!((30.0..200.0).contains(&classes.threshold));
        assert_eq!((classes.dark_mean, classes.bright_mean), (30.0, 200.0));
        assert!(classes.within_std < 1e-3);
        // Two classes of ±10 about their means: within-class spread 10.
        let spread: Vec<u8> = [20u8, 40, 190, 210].repeat(25);
        let classes = otsu(&spread).unwrap();
        assert!((classes.within_std - 10.0).abs() < 1e-3, "{classes:?}");
        assert_eq!(otsu(&[77; 10]), None);
    }

    #[test]
    fn bilinear_is_exact_at_centres_and_linear_between() {
        let image = GrayImage::from_vec(2, 2, vec![0, 100, 50, 150]).unwrap();
        let view = image.view();
        assert_eq!(sample_bilinear(&view, 1.0, 0.0), 100.0);
        assert_eq!(sample_bilinear(&view, 0.5, 0.5), 75.0);
        assert_eq!(sample_bilinear(&view, -3.0, 9.0), 50.0);
    }
}
