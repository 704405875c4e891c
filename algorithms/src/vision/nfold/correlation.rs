//! The correlation with the kernel K = zⁿ·exp(−8|z|²): the separable filter bank that searches a
//! frame, the direct kernel that hill-climbs at full resolution, and the response at a sub-pixel
//! centre.

use std::f64::consts::{PI, TAU};

use crate::vision::image::ImageView;

/// R at a sub-pixel centre (kernel evaluated analytically at `radius_px`); with `missing_leg_phi`,
/// the missing leg (φ < θ < φ + π/n, widened by a quarter leg) is replaced by the image reflected
/// through the centre. `None` if the disc leaves the image.
pub(super) fn filled_response(
    image: &ImageView<'_>,
    u: f64,
    v: f64,
    radius_px: f64,
    n: f64,
    missing_leg_phi: Option<f64>,
) -> Option<(f64, f64)> {
    let margin = PI / (4.0 * n);
    let (mut re, mut im) = (0.0, 0.0);
    let r = radius_px.ceil() as i64 + 1;
    let (cu, cv) = (u.round() as i64, v.round() as i64);
    for y in cv - r..=cv + r {
        for x in cu - r..=cu + r {
            let (dx, dy) = (x as f64 - u, y as f64 - v);
            let (zx, zy) = (dx / radius_px, dy / radius_px);
            let r2 = zx * zx + zy * zy;
            if r2 > 1.0 {
                continue;
            }
            let in_leg = missing_leg_phi.is_some_and(|phi| {
                (dy.atan2(dx) - phi + margin).rem_euclid(TAU) < PI / n + 2.0 * margin
            });
            let value = if in_leg {
                bilinear(image, u - dx, v - dy)?
            } else {
                bilinear(image, x as f64, y as f64)?
            };
            let (mut a, mut b) = (1.0f64, 0.0f64);
            for _ in 0..n as u32 {
                (a, b) = (a * zx - b * zy, a * zy + b * zx);
            }
            let g = value * (-8.0 * r2).exp();
            re += g * a;
            im += g * b;
        }
    }
    Some((re, im))
}

/// The image at a sub-pixel position; `None` outside.
pub(super) fn bilinear(image: &ImageView<'_>, u: f64, v: f64) -> Option<f64> {
    if !(u >= 0.0 && v >= 0.0) {
        return None;
    }
    let (x, y) = (u as usize, v as usize);
    if x + 1 >= image.width() || y + 1 >= image.height() {
        return None;
    }
    let (fx, fy) = (u - x as f64, v - y as f64);
    let (top, bottom) = (image.row(y), image.row(y + 1));
    let t = top[x] as f64 * (1.0 - fx) + top[x + 1] as f64 * fx;
    let b = bottom[x] as f64 * (1.0 - fx) + bottom[x + 1] as f64 * fx;
    Some(t * (1.0 - fy) + b * fy)
}

/// An f32 image plane (a crop of the frame, possibly downsampled).
pub(super) struct Plane {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) data: Vec<f32>,
}

impl Plane {
    /// The crop [x0, x0 + w) × [y0, y0 + h), downsampled once by 2×2 means if `level` ≥ 1.
    pub(super) fn from_view(
        view: &ImageView<'_>,
        x0: usize,
        y0: usize,
        w: usize,
        h: usize,
        level: u32,
    ) -> Self {
        if level == 0 {
            let mut data = Vec::with_capacity(w * h);
            for y in y0..y0 + h {
                data.extend(view.row(y)[x0..x0 + w].iter().map(|&p| p as f32));
            }
            return Self {
                width: w,
                height: h,
                data,
            };
        }
        let (wo, ho) = (w / 2, h / 2);
        let mut data = Vec::with_capacity(wo * ho);
        for y in 0..ho {
            let top = &view.row(y0 + 2 * y)[x0..x0 + 2 * wo];
            let bottom = &view.row(y0 + 2 * y + 1)[x0..x0 + 2 * wo];
            data.extend(
                top.chunks_exact(2)
                    .zip(bottom.chunks_exact(2))
                    .map(|(t, b)| {
                        (t[0] as u32 + t[1] as u32 + b[0] as u32 + b[1] as u32) as f32 * 0.25
                    }),
            );
        }
        Self {
            width: wo,
            height: ho,
            data,
        }
    }

    pub(super) fn downsample(&self) -> Self {
        let (wo, ho) = (self.width / 2, self.height / 2);
        let mut data = Vec::with_capacity(wo * ho);
        for y in 0..ho {
            let top = &self.data[2 * y * self.width..][..2 * wo];
            let bottom = &self.data[(2 * y + 1) * self.width..][..2 * wo];
            data.extend(
                top.chunks_exact(2)
                    .zip(bottom.chunks_exact(2))
                    .map(|(t, b)| (t[0] + t[1] + b[0] + b[1]) * 0.25),
            );
        }
        Self {
            width: wo,
            height: ho,
            data,
        }
    }

    fn row(&self, y: usize) -> &[f32] {
        &self.data[y * self.width..(y + 1) * self.width]
    }
}

/// (`usize::is_multiple_of` needs Rust 1.87; the workspace supports 1.85.)
pub(super) fn is_even(k: usize) -> bool {
    k & 1 == 0
}

/// Normalised kernel coordinate of tap t (−r ..= r) and the Gaussian envelope's factor there.
fn tap(t: i64, radius: usize) -> (f64, f64) {
    let x = t as f64 / radius as f64;
    (x, (-8.0 * x * x).exp())
}

fn binomial(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

/// K as n + 1 separable real terms, for dense correlation. Term m: C(n, m)·iᵐ · [x^{n−m} g(x)] ⊗
/// [y^m g(y)]; even m feed the real part, odd m the imaginary part. Taps are stored for t ≥ 0 only:
/// a filter of even power is symmetric, of odd power antisymmetric, so each pair of taps costs one
/// multiply on the sum or difference of the two pixels.
#[derive(Debug, Clone)]
pub(super) struct SeparableKernel {
    pub(super) size: usize,
    pub(super) radius: usize,
    order: usize,
    /// row_taps[m][t] = (t/r)^{n−m} g(t/r)
    row_taps: Vec<Vec<f32>>,
    /// col_taps[m][t] = ±C(n, m) (t/r)^m g(t/r), the sign of iᵐ folded in
    col_taps: Vec<Vec<f32>>,
}

impl SeparableKernel {
    pub(super) fn new(order: usize, size: usize) -> Self {
        let radius = size / 2;
        let power = |x: f64, p: usize| if p == 0 { 1.0 } else { x.powi(p as i32) };
        let filter = |p: usize, scale: f64| -> Vec<f32> {
            (0..=radius as i64)
                .map(|t| {
                    let (x, g) = tap(t, radius);
                    (scale * power(x, p) * g) as f32
                })
                .collect()
        };
        let row_taps = (0..=order).map(|m| filter(order - m, 1.0)).collect();
        let col_taps = (0..=order)
            .map(|m| {
                // iᵐ = 1, i, −1, −i: the real or imaginary part's sign.
                let sign = if m % 4 < 2 { 1.0 } else { -1.0 };
                filter(m, sign * binomial(order, m))
            })
            .collect();
        Self {
            size,
            radius,
            order,
            row_taps,
            col_taps,
        }
    }

    /// |R|² at every position of `plane` where the kernel fits: a (w − 2r)×(h − 2r) plane whose
    /// (x, y) is the plane's (x + r, y + r).
    pub(super) fn magnitude_squared(&self, plane: &Plane) -> Plane {
        let r = self.radius;
        let k = self.size;
        let terms = self.order + 1;
        let (wo, ho) = (plane.width - 2 * r, plane.height - 2 * r);
        // Row-filtered rows for the last k input rows, per term: a ring indexed by row mod k.
        let mut ring = vec![0f32; terms * k * wo];
        let mut sum = vec![0f32; wo];
        let mut dif = vec![0f32; wo];
        let mut re = vec![0f32; wo];
        let mut im = vec![0f32; wo];
        let mut out = Vec::with_capacity(wo * ho);
        for y in 0..plane.height {
            let src = plane.row(y);
            let slot = y % k;
            // Row pass into the ring.
            for m in 0..terms {
                let dst = &mut ring[(m * k + slot) * wo..][..wo];
                let centre = self.row_taps[m][0];
                let centre_src = &src[r..r + wo];
                if is_even(self.order - m) {
                    dst.iter_mut()
                        .zip(centre_src)
                        .for_each(|(d, &s)| *d = centre * s);
                } else {
                    dst.fill(0.0);
                }
            }
            for t in 1..=r {
                let plus = &src[r + t..r + t + wo];
                let minus = &src[r - t..r - t + wo];
                for (((s, d), &p), &q) in sum.iter_mut().zip(dif.iter_mut()).zip(plus).zip(minus) {
                    *s = p + q;
                    *d = p - q;
                }
                for m in 0..terms {
                    let c = self.row_taps[m][t];
                    let s = if is_even(self.order - m) { &sum } else { &dif };
                    let dst = &mut ring[(m * k + slot) * wo..][..wo];
                    dst.iter_mut().zip(s).for_each(|(d, &s)| *d += c * s);
                }
            }
            if y + 1 < k {
                continue;
            }
            // Column pass for the output row whose centre input row is y − r.
            let centre_row = y - r;
            let ring_row = |m: usize, row: usize| &ring[(m * k + row % k) * wo..][..wo];
            re.fill(0.0);
            im.fill(0.0);
            for m in 0..terms {
                // Slices, not the Vecs: the compiler then knows they do not alias and vectorises.
                let acc: &mut [f32] = if is_even(m) { &mut re } else { &mut im };
                if is_even(m) {
                    let c = self.col_taps[m][0];
                    acc.iter_mut()
                        .zip(ring_row(m, centre_row))
                        .for_each(|(a, &h)| *a += c * h);
                }
                for t in 1..=r {
                    let c = self.col_taps[m][t];
                    let below = ring_row(m, centre_row + t);
                    let above = ring_row(m, centre_row - t);
                    let pairs = acc.iter_mut().zip(below).zip(above);
                    if is_even(m) {
                        pairs.for_each(|((a, &b), &o)| *a += c * (b + o));
                    } else {
                        pairs.for_each(|((a, &b), &o)| *a += c * (b - o));
                    }
                }
            }
            out.extend(re.iter().zip(&im).map(|(&a, &b)| a * a + b * b));
        }
        Plane {
            width: wo,
            height: ho,
            data: out,
        }
    }
}

/// The strongest local responses, each at least `suppress_px` (Chebyshev) from a stronger one.
pub(super) fn strongest_peaks(
    mut response: Plane,
    count: usize,
    suppress_px: usize,
) -> Vec<(usize, usize)> {
    let width = response.width;
    // Row maxima, computed once and refreshed only for the rows a suppression touches.
    let row_max = |row: &[f32]| {
        // 8 independent lanes, so that it vectorises.
        let mut lanes = [0f32; 8];
        let chunks = row.chunks_exact(8);
        let rest = chunks.remainder();
        for chunk in chunks {
            for (lane, &v) in lanes.iter_mut().zip(chunk) {
                *lane = if v > *lane { v } else { *lane };
            }
        }
        lanes
            .iter()
            .chain(rest)
            .fold(0f32, |a, &b| if b > a { b } else { a })
    };
    let mut maxima: Vec<f32> = response.data.chunks_exact(width).map(row_max).collect();
    let mut peaks = Vec::with_capacity(count);
    for _ in 0..count {
        let Some((y, &max)) = maxima.iter().enumerate().fold(
            None,
            |best: Option<(usize, &f32)>, (y, m)| match best {
                Some((_, b)) if *b >= *m => best,
                _ => Some((y, m)),
            },
        ) else {
            break;
        };
        if max <= 0.0 {
            break;
        }
        let row = &response.data[y * width..][..width];
        let Some(x) = row.iter().position(|&v| v == max) else {
            break;
        };
        peaks.push((x, y));
        let rows = y.saturating_sub(suppress_px)..(y + suppress_px + 1).min(response.height);
        for (row, max) in response.data[rows.start * width..rows.end * width]
            .chunks_exact_mut(width)
            .zip(&mut maxima[rows])
        {
            row[x.saturating_sub(suppress_px)..(x + suppress_px + 1).min(width)].fill(-1.0);
            *max = row_max(row);
        }
    }
    peaks
}

/// K sampled at full resolution, for exact responses at a few positions.
#[derive(Debug, Clone)]
pub(super) struct DirectKernel {
    pub(super) size: usize,
    pub(super) radius: usize,
    re: Vec<f64>,
    im: Vec<f64>,
    pub(super) abs_sum: f64,
}

/// A refined response peak.
#[derive(Debug, Clone, Copy)]
pub(super) struct Peak {
    pub(super) u_px: f64,
    pub(super) v_px: f64,
    pub(super) response_re: f64,
    pub(super) response_im: f64,
    pub(super) magnitude: f64,
}

impl DirectKernel {
    pub(super) fn new(order: usize, size: usize) -> Self {
        let radius = size / 2;
        let mut re = Vec::with_capacity(size * size);
        let mut im = Vec::with_capacity(size * size);
        for ty in -(radius as i64)..=radius as i64 {
            for tx in -(radius as i64)..=radius as i64 {
                let (x, gx) = tap(tx, radius);
                let (y, gy) = tap(ty, radius);
                // (x + iy)ⁿ by repeated multiplication.
                let (mut a, mut b) = (1.0f64, 0.0f64);
                for _ in 0..order {
                    (a, b) = (a * x - b * y, a * y + b * x);
                }
                re.push(a * gx * gy);
                im.push(b * gx * gy);
            }
        }
        let abs_sum = re.iter().zip(&im).map(|(a, b)| a.hypot(*b)).sum();
        Self {
            size,
            radius,
            re,
            im,
            abs_sum,
        }
    }

    /// R at integer centre (x, y); `None` unless the kernel lies inside the image.
    pub(super) fn response(&self, image: &ImageView<'_>, x: i64, y: i64) -> Option<(f64, f64)> {
        let r = self.radius as i64;
        if x < r || y < r || x + r >= image.width() as i64 || y + r >= image.height() as i64 {
            return None;
        }
        let (mut sum_re, mut sum_im) = (0.0, 0.0);
        for (j, yy) in (y - r..=y + r).enumerate() {
            let row = &image.row(yy as usize)[(x - r) as usize..=(x + r) as usize];
            let kr = &self.re[j * self.size..][..self.size];
            let ki = &self.im[j * self.size..][..self.size];
            for ((&p, &a), &b) in row.iter().zip(kr).zip(ki) {
                sum_re += p as f64 * a;
                sum_im += p as f64 * b;
            }
        }
        Some((sum_re, sum_im))
    }

    /// Hill-climbs |R| from (x, y) to a local maximum, then fits a quadratic to its 3×3
    /// neighbourhood for the sub-pixel peak. `None` if the climb leaves the image or its range.
    pub(super) fn climb(&self, image: &ImageView<'_>, x: i64, y: i64) -> Option<Peak> {
        const REACH: i64 = 8;
        const SIDE: usize = (2 * REACH + 1) as usize;
        let mut memo: [Option<(f64, f64)>; SIDE * SIDE] = [None; SIDE * SIDE];
        let mut at = |px: i64, py: i64| -> Option<(f64, f64)> {
            let (i, j) = (px - x + REACH, py - y + REACH);
            if !(0..SIDE as i64).contains(&i) || !(0..SIDE as i64).contains(&j) {
                return None;
            }
            let slot = &mut memo[j as usize * SIDE + i as usize];
            if slot.is_none() {
                *slot = self.response(image, px, py);
            }
            *slot
        };
        let (mut cx, mut cy) = (x, y);
        let mut grid = [[(0.0f64, 0.0f64); 3]; 3];
        for _ in 0..(4 * REACH) {
            let mut best = (0i64, 0i64, f64::MIN);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let value = at(cx + dx, cy + dy)?;
                    grid[(dy + 1) as usize][(dx + 1) as usize] = value;
                    let mag = value.0.hypot(value.1);
                    if mag > best.2 {
                        best = (dx, dy, mag);
                    }
                }
            }
            if (best.0, best.1) == (0, 0) {
                let mags = grid.map(|row| row.map(|(a, b)| a.hypot(b)));
                let (du, dv) = quadratic_peak(&mags);
                // The phase, bilinear between the four responses around the sub-pixel peak.
                let (ix, iy) = (if du < 0.0 { 0 } else { 1 }, if dv < 0.0 { 0 } else { 1 });
                let (fx, fy) = (du - (ix as f64 - 1.0), dv - (iy as f64 - 1.0));
                let lerp = |a: (f64, f64), b: (f64, f64), t: f64| {
                    (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t)
                };
                let top = lerp(grid[iy][ix], grid[iy][ix + 1], fx);
                let bottom = lerp(grid[iy + 1][ix], grid[iy + 1][ix + 1], fx);
                let (response_re, response_im) = lerp(top, bottom, fy);
                return Some(Peak {
                    u_px: cx as f64 + du,
                    v_px: cy as f64 + dv,
                    response_re,
                    response_im,
                    magnitude: mags[1][1],
                });
            }
            cx += best.0;
            cy += best.1;
        }
        None
    }
}

/// Offset (du, dv) of the maximum of the least-squares quadratic through a 3×3 patch whose centre
/// is its largest value; falls back to per-axis parabolas when the fit is not a clean maximum.
pub(super) fn quadratic_peak(m: &[[f64; 3]; 3]) -> (f64, f64) {
    let col = |i: usize| m[0][i] + m[1][i] + m[2][i];
    let row = |j: usize| m[j][0] + m[j][1] + m[j][2];
    let b = (col(2) - col(0)) / 6.0;
    let c = (row(2) - row(0)) / 6.0;
    let d = (col(2) + col(0) - 2.0 * col(1)) / 6.0;
    let g = (row(2) + row(0) - 2.0 * row(1)) / 6.0;
    let e = (m[2][2] - m[2][0] - m[0][2] + m[0][0]) / 4.0;
    // Gradient zero: [2d e; e 2g]·(du, dv) = −(b, c).
    let det = 4.0 * d * g - e * e;
    if d < 0.0 && det > 0.0 {
        let du = (-2.0 * g * b + e * c) / det;
        let dv = (-2.0 * d * c + e * b) / det;
        if du.abs() <= 1.0 && dv.abs() <= 1.0 {
            return (du, dv);
        }
    }
    let parabola = |lo: f64, mid: f64, hi: f64| {
        let curvature = lo - 2.0 * mid + hi;
        if curvature < 0.0 {
            (0.5 * (lo - hi) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    (
        parabola(m[1][0], m[1][1], m[1][2]),
        parabola(m[0][1], m[1][1], m[2][1]),
    )
}
