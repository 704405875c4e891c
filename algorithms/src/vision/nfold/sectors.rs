//! What the pixels around a tip say: the sector statistics behind the quality and the missing
//! leg, and the centre of point symmetry that an oriented even marker's tip is taken as.

use std::f64::consts::{PI, TAU};

use super::correlation::{bilinear, is_even, quadratic_peak};
use crate::vision::image::ImageView;

/// Σ w·(I(c + d) − I(c − d))² over the disc of `radius_px` around c, leaving out the wedges of the
/// missing leg (φ < θ < φ + π/n, widened by a quarter leg) and of its opposite; with the weight sum.
fn asymmetry(
    image: &ImageView<'_>,
    u: f64,
    v: f64,
    radius_px: f64,
    n: f64,
    phi: f64,
) -> (f64, f64) {
    let (mut sum, mut weights) = (0.0, 0.0);
    let margin = PI / (4.0 * n);
    let r = radius_px.ceil() as i64;
    for dy in -r..=r {
        for dx in -r..=r {
            let (dx, dy) = (dx as f64, dy as f64);
            let dist = dx.hypot(dy);
            if dist > radius_px || dist < 0.5 {
                continue;
            }
            // d and −d cover the same pair: each pair once (the upper half plane).
            if dy < 0.0 || (dy == 0.0 && dx < 0.0) {
                continue;
            }
            let rel = (dy.atan2(dx) - phi + margin).rem_euclid(PI);
            if rel < PI / n + 2.0 * margin {
                continue;
            }
            let (Some(a), Some(b)) = (
                bilinear(image, u + dx, v + dy),
                bilinear(image, u - dx, v - dy),
            ) else {
                continue;
            };
            sum += (a - b) * (a - b);
            weights += 1.0;
        }
    }
    (sum, weights)
}

/// The centre of point symmetry near (u, v): quadratic fits of the asymmetry on shrinking 3×3
/// grids.
pub(super) fn symmetry_centre(
    image: &ImageView<'_>,
    u: f64,
    v: f64,
    radius_px: f64,
    n: f64,
    phi: f64,
) -> (f64, f64) {
    let (mut u, mut v) = (u, v);
    for step in [0.5, 0.25, 0.125] {
        let mut grid = [[0.0; 3]; 3];
        for (j, row) in grid.iter_mut().enumerate() {
            for (i, cell) in row.iter_mut().enumerate() {
                let (cu, cv) = (u + (i as f64 - 1.0) * step, v + (j as f64 - 1.0) * step);
                let (sum, weights) = asymmetry(image, cu, cv, radius_px, n, phi);
                if weights <= 0.0 {
                    return (u, v);
                }
                // Negated: quadratic_peak finds maxima.
                *cell = -sum / weights;
            }
        }
        let (du, dv) = quadratic_peak(&grid);
        u += du * step;
        v += dv * step;
    }
    (u, v)
}

/// Weighted intensity sums over the 2n sectors around a centre: sector s spans
/// φ₀ + sπ/n < θ < φ₀ + (s + 1)π/n; even sectors are the black legs (leg k is sector 2k). Each
/// sector is also split into cells, 3 angular thirds × 2 rings (inside and outside half the
/// radius), for the consistency part of the quality.
pub(super) struct SectorStats {
    /// (Σw, Σw·I, Σw·I²) per sector, w favouring pixels far from sector boundaries.
    sums: Vec<[f64; 3]>,
    /// (Σw, Σw·I) per cell, index (sector·3 + third)·2 + ring, w not favouring any angle.
    cells: Vec<[f64; 2]>,
    /// Σw·(∇I·t̂)² and Σw·|∇I|², t̂ the tangential direction.
    tangential: [f64; 2],
}

impl SectorStats {
    const THIRDS: usize = 3;
    const RINGS: usize = 2;

    pub(super) fn measure(
        image: &ImageView<'_>,
        u_px: f64,
        v_px: f64,
        radius_px: f64,
        order: usize,
        phi0: f64,
    ) -> Self {
        let n = order as f64;
        let sector_rad = PI / n;
        // Near the tip the sectors are narrower than a pixel and blur mixes them: ramp the weight
        // up over the inner part of the disc.
        let ramp_px = (0.3 * radius_px).max(2.0);
        let mut sums = vec![[0.0; 3]; 2 * order];
        let mut cells = vec![[0.0; 2]; 2 * order * Self::THIRDS * Self::RINGS];
        let mut tangential = [0.0; 2];
        let (sin_phi, cos_phi) = phi0.sin_cos();
        let (w, h) = (image.width() as i64, image.height() as i64);
        let x0 = ((u_px - radius_px).ceil() as i64).max(0);
        let x1 = ((u_px + radius_px).floor() as i64).min(w - 1);
        let y0 = ((v_px - radius_px).ceil() as i64).max(0);
        let y1 = ((v_px + radius_px).floor() as i64).min(h - 1);
        for y in y0..=y1 {
            let row = image.row(y as usize);
            let dy = y as f64 - v_px;
            for x in x0..=x1 {
                let dx = x as f64 - u_px;
                let r = (dx * dx + dy * dy).sqrt();
                if r > radius_px || r < 1e-9 {
                    continue;
                }
                let rel = (dy.atan2(dx) - phi0).rem_euclid(TAU);
                let ramp = (r / ramp_px).min(1.0);
                // Pixels on a sector boundary belong to both sides: weight by |sin(n(θ − φ₀))|,
                // the imaginary part of (e^{i(θ − φ₀)})ⁿ.
                let (c, s) = (
                    (dx * cos_phi + dy * sin_phi) / r,
                    (dy * cos_phi - dx * sin_phi) / r,
                );
                let (mut a, mut b) = (1.0f64, 0.0f64);
                for _ in 0..order {
                    (a, b) = (a * c - b * s, a * s + b * c);
                }
                let weight = b.abs() * ramp;
                let position = rel / sector_rad;
                let sector = (position as usize).min(2 * order - 1);
                let third = (((position - sector as f64) * Self::THIRDS as f64) as usize)
                    .min(Self::THIRDS - 1);
                let ring = usize::from(r > 0.5 * radius_px);
                let value = row[x as usize] as f64;
                let s = &mut sums[sector];
                s[0] += weight;
                s[1] += weight * value;
                s[2] += weight * value * value;
                let c = &mut cells[(sector * Self::THIRDS + third) * Self::RINGS + ring];
                c[0] += ramp;
                c[1] += ramp * value;
                if x > 0 && y > 0 && x + 1 < w && y + 1 < h {
                    let (xu, yu) = (x as usize, y as usize);
                    let gx = (row[xu + 1] as f64 - row[xu - 1] as f64) / 2.0;
                    let gy = (image.row(yu + 1)[xu] as f64 - image.row(yu - 1)[xu] as f64) / 2.0;
                    // t̂ = (−dy, dx)/r
                    let along = (-dy * gx + dx * gy) / r;
                    tangential[0] += ramp * along * along;
                    tangential[1] += ramp * (gx * gx + gy * gy);
                }
            }
        }
        Self {
            sums,
            cells,
            tangential,
        }
    }

    fn mean(&self, sector: usize) -> f64 {
        let s = &self.sums[sector];
        if s[0] > 0.0 {
            s[1] / s[0]
        } else {
            0.0
        }
    }

    /// The black leg that is brightest (the oriented marker's white leg), and whether it stands out:
    /// closer to the white sectors' level than to the other legs'.
    pub(super) fn brightest_leg(&self) -> (usize, bool) {
        let legs = self.sums.len() / 2;
        let means: Vec<f64> = (0..legs).map(|k| self.mean(2 * k)).collect();
        let leg = (0..legs)
            .max_by(|&a, &b| means[a].total_cmp(&means[b]))
            .unwrap_or(0);
        let others = (0..legs).filter(|&k| k != leg).map(|k| means[k]);
        let dark = others.clone().sum::<f64>() / (legs - 1).max(1) as f64;
        let bright = (0..legs).map(|k| self.mean(2 * k + 1)).sum::<f64>() / legs as f64;
        let resolved = means[leg] - dark > 0.5 * (bright - dark) && bright > dark;
        (leg, resolved)
    }

    /// Quality in [0, 1]: correlation × consistency (see [`Self::quality_parts`]) × tangentiality.
    pub(super) fn quality(&self, missing_leg: Option<usize>) -> f64 {
        let (correlation, consistency) = self.quality_parts(missing_leg);
        correlation * consistency * self.tangentiality()
    }

    /// (correlation, consistency), each in [0, 1]. Correlation: weighted, between intensity and the
    /// predicted pattern (white = 1, black = 0; `missing_leg` is predicted white). Consistency: the
    /// weighted mean over cells of how far each lies on its predicted side of the black–white
    /// midpoint (1 at its class's mean or beyond, −1 at the other class's). A marker's sectors are
    /// wedges, alike at every radius and across their width; texture's are not (a plus sign of
    /// ArUco cells has arms of constant width, and it has a strong n-fold harmonic too), and an
    /// occluded sector costs only its share.
    fn quality_parts(&self, missing_leg: Option<usize>) -> (f64, f64) {
        let is_bright = |s: usize| !is_even(s) || missing_leg == Some(s / 2);
        let (mut bright, mut dark) = ([0.0; 3], [0.0; 3]);
        for (s, sums) in self.sums.iter().enumerate() {
            let acc = if is_bright(s) { &mut bright } else { &mut dark };
            for i in 0..3 {
                acc[i] += sums[i];
            }
        }
        let total = bright[0] + dark[0];
        if bright[0] <= 0.0 || dark[0] <= 0.0 {
            return (0.0, 0.0);
        }
        let mean = (bright[1] + dark[1]) / total;
        let variance = (bright[2] + dark[2]) / total - mean * mean;
        let (mean_bright, mean_dark) = (bright[1] / bright[0], dark[1] / dark[0]);
        let contrast = mean_bright - mean_dark;
        if variance <= 1e-9 || contrast <= 0.0 {
            return (0.0, 0.0);
        }
        let p = bright[0] / total;
        let correlation = (contrast * (p * (1.0 - p)).sqrt() / variance.sqrt()).clamp(0.0, 1.0);
        let midpoint = (mean_bright + mean_dark) / 2.0;
        let (mut votes, mut weights) = (0.0, 0.0);
        for (i, &[w, wi]) in self.cells.iter().enumerate() {
            if w <= 0.0 {
                continue;
            }
            let sector = i / (Self::THIRDS * Self::RINGS);
            let side = if is_bright(sector) { 1.0 } else { -1.0 };
            votes += w * (side * (wi / w - midpoint) / (contrast / 2.0)).clamp(-1.0, 1.0);
            weights += w;
        }
        let consistency = if weights > 0.0 { votes / weights } else { 0.0 };
        (correlation, consistency.max(0.0))
    }

    /// The share of the gradient energy that runs around the centre: 1 when every edge passes
    /// through it.
    fn tangentiality(&self) -> f64 {
        if self.tangential[1] > 0.0 {
            self.tangential[0] / self.tangential[1]
        } else {
            0.0
        }
    }
}
