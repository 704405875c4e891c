//! The n-fold marker detector (after MarkerLocator; seed 003 §IV-A).
//!
//! An n-fold marker is an angular square wave about its centre (the "tip"): at angle θ it is black
//! where sin(n(θ − φ)) > 0, φ being the marker's orientation; the oriented variant leaves the black
//! leg φ < θ < φ + π/n white, which fixes φ in (−π, π] instead of modulo 2π/n. Angles are measured in
//! the image from the u axis towards v (v down), the same sense as [`crate::vision::render`] draws.
//!
//! Detection correlates the image with the complex kernel K = zⁿ·exp(−8|z|²), z = x + iy sampled
//! over [−1, 1]² at the kernel size. Its response R at the tip is −i·c·e^{inφ} (c > 0 with the
//! marker's contrast), so |R| finds the tip and arg R gives φ modulo 2π/n. The pipeline:
//!
//! 1. search: |R|² over the whole frame at a coarse pyramid level (or over an ROI at full
//!    resolution), using the separable form of K: (x + iy)ⁿ = Σₘ C(n, m)·iᵐ·x^{n−m}·y^m, times the
//!    separable Gaussian, is n + 1 real row filters followed by n + 1 real column filters;
//! 2. the strongest responses, apart by a kernel radius, are the candidates;
//! 3. for each candidate and each kernel size from smallest to largest: hill-climb |R| at full
//!    resolution, fit a quadratic to the 3×3 around the peak (sub-pixel centre), read φ from the
//!    phase, pick the missing leg for oriented markers, and score quality; the first candidate and
//!    size whose quality passes the threshold is the detection (adaptive kernel size).
//!
//! Quality, in [0, 1], is the product of three checks over the kernel's disc against the black and
//! white sectors the phase predicts: the weighted correlation of image and pattern; the consistency
//! of 3 × 2 cells per sector (each on its predicted side of the black–white midpoint: wedges, not
//! the constant-width arms of a plus sign); and the tangentiality of the image gradient (every edge
//! of a marker passes through its tip). A sharp marker scores about 0.8 at 13 px (pixels near the
//! tip mix sectors) and more with larger kernels; markerless frames stay below 0.4 (see the tests),
//! and the default threshold is 0.5.
//!
//! Oriented markers of even order get two more steps: the missing leg skews the response, so the
//! tip is taken as the centre of point symmetry of the other legs, and the phase is read with the
//! missing leg filled by its opposite reflected through the tip. For every marker the phase is
//! read over the largest kernel's disc where that disc's quality still passes.

use std::f64::consts::{PI, TAU};

use thiserror::Error;

use super::image::{FrameError, ImageView};

/// A configuration the detector cannot run with.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum NfoldConfigError {
    #[error("the marker order must be 2 to 16, got {0}")]
    Order(u32),
    #[error("kernel sizes must be odd and 5 to 63 px, got {0} px")]
    KernelSize(usize),
    #[error("at least one kernel size is needed for refinement")]
    NoKernelSizes,
    #[error("the quality threshold must lie in [0, 1], got {0}")]
    QualityThreshold(f64),
    #[error("the search pyramid level must be 0 to 3, got {0}")]
    SearchLevel(u32),
    #[error("at least one candidate must be examined")]
    NoCandidates,
}

/// A frame the detector cannot read.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum NfoldError {
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error("a {width_px}×{height_px} frame is smaller than the detector's {min_px}×{min_px} px minimum")]
    FrameTooSmall {
        width_px: usize,
        height_px: usize,
        min_px: usize,
    },
}

/// How to detect. `Default` follows the seed: a 13×13 kernel on 640×480 frames, grown adaptively
/// to 17, 21 and 25 px; order 4; the full-frame search at half resolution with a 9 px kernel
/// (about 17 px at full resolution); quality threshold 0.5; three candidates.
#[derive(Debug, Clone, PartialEq)]
pub struct NfoldConfig {
    /// n: the number of black legs. 4 by default: right-angle structure (ArUco cells, corners,
    /// the junctions of a grid) has no 4th angular harmonic, so it barely responds.
    pub order: u32,
    /// The marker has one black leg left white, which resolves the orientation.
    pub oriented: bool,
    /// Kernel sizes (odd, px) tried from smallest to largest at full resolution; the smallest whose
    /// quality passes is used. Larger kernels see past an occluded tip.
    pub kernel_sizes_px: Vec<usize>,
    /// Kernel size (odd, px) of the full-frame search at `search_level`.
    pub search_kernel_px: usize,
    /// Pyramid level of the full-frame search: 0 full resolution, 1 half, 2 quarter, 3 eighth.
    pub search_level: u32,
    /// Candidates below this quality are rejected. Markers score 0.7–1, markerless frames below
    /// 0.4 in the tests.
    pub quality_threshold: f64,
    /// How many of the strongest responses are examined before giving up.
    pub candidates: usize,
    /// If set, frames of any other size are rejected with [`FrameError::WrongSize`].
    pub expected_frame_size_px: Option<(usize, usize)>,
}

impl Default for NfoldConfig {
    fn default() -> Self {
        Self {
            order: 4,
            oriented: false,
            kernel_sizes_px: vec![13, 17, 21, 25],
            search_kernel_px: 9,
            search_level: 1,
            quality_threshold: 0.5,
            candidates: 3,
            expected_frame_size_px: None,
        }
    }
}

/// Where to look, in full-resolution pixel coordinates (integer values are pixel centres): the
/// marker's centre is searched inside this box; the kernel may read pixels around it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Roi {
    pub min_u_px: f64,
    pub min_v_px: f64,
    pub max_u_px: f64,
    pub max_v_px: f64,
}

impl Roi {
    /// A square box of half-side `half_size_px` around a predicted centre.
    pub fn around(u_px: f64, v_px: f64, half_size_px: f64) -> Self {
        Self {
            min_u_px: u_px - half_size_px,
            min_v_px: v_px - half_size_px,
            max_u_px: u_px + half_size_px,
            max_v_px: v_px + half_size_px,
        }
    }
}

/// A detected n-fold marker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NfoldDetection {
    /// Sub-pixel centre (tip), integer values at pixel centres.
    pub u_px: f64,
    pub v_px: f64,
    /// φ: for an oriented marker in (−π, π]; otherwise modulo 2π/n, in [0, 2π/n).
    pub orientation_rad: f64,
    /// Oriented markers only: whether the white leg stood out clearly (false for plain markers).
    pub orientation_resolved: bool,
    /// In [0, 1]; at least the configured threshold.
    pub quality: f64,
    pub kernel_size_px: usize,
    /// |R| / Σ|K| at the centre, in grey levels: about 0.3 × the marker's black–white contrast.
    pub response_magnitude: f64,
}

/// The n-fold marker detector; build once, run on every frame (`&self`, so it can be shared).
#[derive(Debug, Clone)]
pub struct NfoldDetector {
    config: NfoldConfig,
    search: SeparableKernel,
    roi_search: SeparableKernel,
    refine: Vec<DirectKernel>,
}

impl NfoldDetector {
    pub fn new(config: NfoldConfig) -> Result<Self, NfoldConfigError> {
        if !(2..=16).contains(&config.order) {
            return Err(NfoldConfigError::Order(config.order));
        }
        if !(0.0..=1.0).contains(&config.quality_threshold) {
            return Err(NfoldConfigError::QualityThreshold(config.quality_threshold));
        }
        if config.search_level > 3 {
            return Err(NfoldConfigError::SearchLevel(config.search_level));
        }
        if config.candidates == 0 {
            return Err(NfoldConfigError::NoCandidates);
        }
        let valid = |size: usize| !is_even(size) && (5..=63).contains(&size);
        let mut sizes = config.kernel_sizes_px.clone();
        if let Some(&bad) = sizes
            .iter()
            .chain(std::iter::once(&config.search_kernel_px))
            .find(|&&s| !valid(s))
        {
            return Err(NfoldConfigError::KernelSize(bad));
        }
        sizes.sort_unstable();
        sizes.dedup();
        let Some(&smallest) = sizes.first() else {
            return Err(NfoldConfigError::NoKernelSizes);
        };
        let n = config.order as usize;
        Ok(Self {
            search: SeparableKernel::new(n, config.search_kernel_px),
            roi_search: SeparableKernel::new(n, smallest),
            refine: sizes.iter().map(|&s| DirectKernel::new(n, s)).collect(),
            config: NfoldConfig {
                kernel_sizes_px: sizes,
                ..config
            },
        })
    }

    pub fn config(&self) -> &NfoldConfig {
        &self.config
    }

    /// The smallest frame side the detector can search.
    pub fn min_frame_px(&self) -> usize {
        let search = self.config.search_kernel_px << self.config.search_level;
        search.max(*self.config.kernel_sizes_px.last().unwrap_or(&5))
    }

    /// Searches the whole frame (coarse to fine); `Ok(None)` when no candidate passes the quality
    /// threshold.
    pub fn detect(&self, image: &ImageView<'_>) -> Result<Option<NfoldDetection>, NfoldError> {
        self.check_frame(image)?;
        let level = self.config.search_level;
        let mut plane = Plane::from_view(image, 0, 0, image.width(), image.height(), level);
        for _ in 1..level {
            plane = plane.downsample();
        }
        if plane.width < self.search.size || plane.height < self.search.size {
            return Ok(None);
        }
        let response = self.search.magnitude_squared(&plane);
        let scale = (1usize << level) as f64;
        let offset = (scale - 1.0) / 2.0 + self.search.radius as f64 * scale;
        let peaks = strongest_peaks(response, self.config.candidates, self.search.radius);
        let starts = peaks
            .into_iter()
            .map(|(x, y)| (x as f64 * scale + offset, y as f64 * scale + offset));
        Ok(self.refine_candidates(image, starts))
    }

    /// Searches only where the centre may be, at full resolution, with the smallest kernel size.
    /// A box wholly outside the frame (or too thin for the kernel) finds nothing: `Ok(None)`.
    pub fn detect_in_roi(
        &self,
        image: &ImageView<'_>,
        roi: &Roi,
    ) -> Result<Option<NfoldDetection>, NfoldError> {
        self.check_frame(image)?;
        let r = self.roi_search.radius as f64;
        let (w, h) = (image.width() as f64, image.height() as f64);
        // Centres must keep the whole kernel inside the frame.
        let min_u = roi.min_u_px.ceil().max(r);
        let min_v = roi.min_v_px.ceil().max(r);
        let max_u = roi.max_u_px.floor().min(w - 1.0 - r);
        let max_v = roi.max_v_px.floor().min(h - 1.0 - r);
        if !(min_u <= max_u && min_v <= max_v) {
            return Ok(None);
        }
        let (x0, y0) = ((min_u - r) as usize, (min_v - r) as usize);
        let (x1, y1) = ((max_u + r) as usize + 1, (max_v + r) as usize + 1);
        let plane = Plane::from_view(image, x0, y0, x1 - x0, y1 - y0, 0);
        let response = self.roi_search.magnitude_squared(&plane);
        let peaks = strongest_peaks(response, self.config.candidates, self.roi_search.radius);
        let starts = peaks
            .into_iter()
            .map(|(x, y)| ((x0 + x) as f64 + r, (y0 + y) as f64 + r));
        Ok(self.refine_candidates(image, starts))
    }

    fn check_frame(&self, image: &ImageView<'_>) -> Result<(), NfoldError> {
        if let Some((w, h)) = self.config.expected_frame_size_px {
            image.expect_size(w, h)?;
        }
        let min_px = self.min_frame_px();
        if image.width() < min_px || image.height() < min_px {
            return Err(NfoldError::FrameTooSmall {
                width_px: image.width(),
                height_px: image.height(),
                min_px,
            });
        }
        Ok(())
    }

    /// Candidates in order of response; for each, kernel sizes from the smallest: the first pass.
    fn refine_candidates(
        &self,
        image: &ImageView<'_>,
        starts: impl Iterator<Item = (f64, f64)>,
    ) -> Option<NfoldDetection> {
        for (u, v) in starts {
            for kernel in &self.refine {
                // Each size starts from the search's position: a smaller kernel that failed (an
                // occluded tip) may have wandered.
                let Some(peak) = kernel.climb(image, u.round() as i64, v.round() as i64) else {
                    continue;
                };
                let detection = self.assess(image, kernel, &peak);
                if detection.quality >= self.config.quality_threshold {
                    return Some(detection);
                }
            }
        }
        None
    }

    /// Orientation, quality and the result for a refined peak.
    fn assess(&self, image: &ImageView<'_>, kernel: &DirectKernel, peak: &Peak) -> NfoldDetection {
        let order = self.config.order as usize;
        let n = order as f64;
        let radius_px = kernel.radius as f64;
        let (mut u, mut v) = (peak.u_px, peak.v_px);
        let phase = peak.response_im.atan2(peak.response_re);
        let mut phi = ((phase + PI / 2.0) / n).rem_euclid(TAU / n);
        let mut resolved = false;
        let mut fill_leg = false;
        let sectors = SectorStats::measure(image, u, v, radius_px, order, phi);
        // Refinement moves φ and the tip only a little: a candidate far below the threshold is
        // rejected here (most candidates in markerless frames), before the costlier steps.
        let preliminary = if self.config.oriented {
            sectors.quality(Some(sectors.brightest_leg().0))
        } else {
            sectors.quality(None)
        };
        if preliminary < 0.75 * self.config.quality_threshold {
            return NfoldDetection {
                u_px: u,
                v_px: v,
                orientation_rad: phi,
                orientation_resolved: false,
                quality: preliminary,
                kernel_size_px: kernel.size,
                response_magnitude: peak.magnitude / kernel.abs_sum,
            };
        }
        if self.config.oriented {
            let leg;
            (leg, resolved) = sectors.brightest_leg();
            phi += leg as f64 * TAU / n;
            if is_even(order) {
                // The missing leg skews the response: its peak moves off the tip and the phase
                // follows. An even marker is point-symmetric about its tip, and stays so under
                // any affine view: take the tip as the centre of that symmetry (leaving out the
                // missing leg and its opposite), and read the phase below with the missing leg
                // filled by its opposite leg reflected through the tip.
                (u, v) = symmetry_centre(image, u, v, radius_px, n, phi);
                fill_leg = true;
            }
        }
        let missing_leg = |phi: f64| {
            self.config.oriented.then(|| {
                let base = phi.rem_euclid(TAU / n);
                ((phi.rem_euclid(TAU) - base) / (TAU / n)).round() as usize % order
            })
        };
        // The phase is steadier over a larger disc: use the largest kernel size's where the
        // marker still fills it (its quality passes too).
        let wide_px = self.refine.last().map_or(radius_px, |k| k.radius as f64);
        let phase_radius_px = if wide_px > radius_px
            && SectorStats::measure(image, u, v, wide_px, order, phi.rem_euclid(TAU / n))
                .quality(missing_leg(phi))
                >= self.config.quality_threshold
        {
            wide_px
        } else {
            radius_px
        };
        if fill_leg || phase_radius_px > radius_px {
            if let Some((re, im)) =
                filled_response(image, u, v, phase_radius_px, n, fill_leg.then_some(phi))
            {
                let refined = (im.atan2(re) + PI / 2.0) / n;
                // The representative of the new phase nearest φ keeps the resolved leg.
                phi += (refined - phi + PI / n).rem_euclid(TAU / n) - PI / n;
            }
        }
        let orientation_rad = if self.config.oriented {
            PI - (PI - phi).rem_euclid(TAU) // (−π, π]
        } else {
            phi.rem_euclid(TAU / n)
        };
        let sectors = SectorStats::measure(
            image,
            u,
            v,
            radius_px,
            order,
            orientation_rad.rem_euclid(TAU / n),
        );
        NfoldDetection {
            u_px: u,
            v_px: v,
            orientation_rad,
            orientation_resolved: resolved,
            quality: sectors.quality(missing_leg(orientation_rad)),
            kernel_size_px: kernel.size,
            response_magnitude: peak.magnitude / kernel.abs_sum,
        }
    }
}

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
fn symmetry_centre(
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

/// R at a sub-pixel centre (kernel evaluated analytically at `radius_px`); with `missing_leg_phi`,
/// the missing leg (φ < θ < φ + π/n, widened by a quarter leg) is replaced by the image reflected
/// through the centre. `None` if the disc leaves the image.
fn filled_response(
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
fn bilinear(image: &ImageView<'_>, u: f64, v: f64) -> Option<f64> {
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
struct Plane {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl Plane {
    /// The crop [x0, x0 + w) × [y0, y0 + h), downsampled once by 2×2 means if `level` ≥ 1.
    fn from_view(
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

    fn downsample(&self) -> Self {
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
fn is_even(k: usize) -> bool {
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
struct SeparableKernel {
    size: usize,
    radius: usize,
    order: usize,
    /// row_taps[m][t] = (t/r)^{n−m} g(t/r)
    row_taps: Vec<Vec<f32>>,
    /// col_taps[m][t] = ±C(n, m) (t/r)^m g(t/r), the sign of iᵐ folded in
    col_taps: Vec<Vec<f32>>,
}

impl SeparableKernel {
    fn new(order: usize, size: usize) -> Self {
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
    fn magnitude_squared(&self, plane: &Plane) -> Plane {
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
fn strongest_peaks(mut response: Plane, count: usize, suppress_px: usize) -> Vec<(usize, usize)> {
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
struct DirectKernel {
    size: usize,
    radius: usize,
    re: Vec<f64>,
    im: Vec<f64>,
    abs_sum: f64,
}

/// A refined response peak.
#[derive(Debug, Clone, Copy)]
struct Peak {
    u_px: f64,
    v_px: f64,
    response_re: f64,
    response_im: f64,
    magnitude: f64,
}

impl DirectKernel {
    fn new(order: usize, size: usize) -> Self {
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
    fn response(&self, image: &ImageView<'_>, x: i64, y: i64) -> Option<(f64, f64)> {
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
    fn climb(&self, image: &ImageView<'_>, x: i64, y: i64) -> Option<Peak> {
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
fn quadratic_peak(m: &[[f64; 3]; 3]) -> (f64, f64) {
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

/// Weighted intensity sums over the 2n sectors around a centre: sector s spans
/// φ₀ + sπ/n < θ < φ₀ + (s + 1)π/n; even sectors are the black legs (leg k is sector 2k). Each
/// sector is also split into cells, 3 angular thirds × 2 rings (inside and outside half the
/// radius), for the consistency part of the quality.
struct SectorStats {
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

    fn measure(
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
    fn brightest_leg(&self) -> (usize, bool) {
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
    fn quality(&self, missing_leg: Option<usize>) -> f64 {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraPose, PinholeCamera};
    use crate::vision::image::GrayImage;
    use crate::vision::render::{
        render, ImageEffects, MotionBlur, Patch, RenderOptions, Scene, Texture,
    };
    use nalgebra::{Point3, Vector3};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    const MARKER_M: f64 = 0.5;

    fn camera() -> PinholeCamera {
        PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap()
    }

    fn wrap(a: f64) -> f64 {
        PI - (PI - a).rem_euclid(TAU)
    }

    /// A rendered frame and the marker's truth.
    struct Case {
        image: GrayImage,
        u_px: f64,
        v_px: f64,
        orientation_rad: f64,
        /// The marker's smallest projected diameter.
        span_px: f64,
    }

    /// A 0.5 m marker on a 0.7 m white board on a random field, seen from a random pose: altitude
    /// log-uniform in `altitude_m` (so that about three frames in four show the marker at 30 px
    /// or more), tilt up to 25° in any direction, any yaw, the marker anywhere at least 80 px
    /// inside the frame; random Gaussian blur (half the frames, σ ≤ 1.2 px), motion blur (three
    /// in ten, ≤ 3 px), contrast 0.5–1, brightness ±0.15, noise σ ≤ 6 grey levels.
    fn random_case(
        rng: &mut StdRng,
        oriented: bool,
        occluder: Option<Patch>,
        altitude_m: (f64, f64),
    ) -> Case {
        let cam = camera();
        let marker_yaw = rng.random_range(-PI..PI);
        let marker = Patch::square(
            0.0,
            0.0,
            marker_yaw,
            MARKER_M,
            Texture::nfold(4, oriented).unwrap(),
        );
        let board = Patch::square(0.0, 0.0, marker_yaw, 0.7, Texture::uniform(1.0));
        let mut scene = Scene::new(Texture::field(rng.random()))
            .with_patch(board)
            .with_patch(marker.clone());
        if let Some(o) = occluder {
            scene = scene.with_patch(o);
        }
        let altitude_m = rng.random_range(altitude_m.0.ln()..altitude_m.1.ln()).exp();
        let tilt = rng.random_range(0.0..25f64.to_radians());
        let dir = rng.random_range(-PI..PI);
        let (roll, pitch, yaw) = (
            tilt * dir.cos(),
            tilt * dir.sin(),
            rng.random_range(-PI..PI),
        );
        // Put the camera where it sees the marker at a random pixel.
        let attitude = CameraPose::downward(Vector3::zeros(), roll, pitch, yaw);
        let (u0, v0) = (rng.random_range(80.0..560.0), rng.random_range(80.0..400.0));
        let ray = attitude.camera_to_world.rotation * cam.unproject(u0, v0).into_inner();
        let pose = CameraPose::downward(-ray * (altitude_m / ray.z), roll, pitch, yaw);
        let effects = ImageEffects {
            gaussian_blur_sigma_px: if rng.random_bool(0.5) {
                rng.random_range(0.0..1.2)
            } else {
                0.0
            },
            motion_blur: rng.random_bool(0.3).then(|| MotionBlur {
                length_px: rng.random_range(0.0..3.0),
                angle_rad: rng.random_range(0.0..PI),
            }),
            contrast: rng.random_range(0.5..1.0),
            brightness: rng.random_range(-0.15..0.15),
            noise_sigma: rng.random_range(0.0..6.0),
            noise_seed: rng.random(),
        };
        let options = RenderOptions {
            supersampling: 2,
            effects,
        };
        let image = render(&cam, &pose, &scene, &options).unwrap();
        let (u_px, v_px) = cam.project_world(&pose, &Point3::origin()).unwrap();
        let at = |t: f64, rho: f64| {
            cam.project_world(&pose, &marker.point_world(rho * t.cos(), rho * t.sin()))
                .unwrap()
        };
        // Orientation truth: perspective turns directions around the tip by different amounts;
        // the n-th harmonic's phase follows their mean turn (exactly so to first order for an
        // affine view), so the truth is the marker's orientation (0 on the patch) plus that mean.
        let turns: Vec<f64> = (0..72)
            .map(|k| {
                let t = k as f64 * TAU / 72.0;
                let (u, v) = at(t, 0.02);
                (v - v_px).atan2(u - u_px) - t
            })
            .collect();
        // Unwrapped about the first turn, so that turns near ±π average correctly.
        let orientation_rad =
            turns[0] + turns.iter().map(|t| wrap(t - turns[0])).sum::<f64>() / 72.0;
        let span_px = (0..36)
            .map(|k| {
                let t = k as f64 * PI / 36.0;
                let (a, b) = (at(t, 1.0), at(t + PI, 1.0));
                (a.0 - b.0).hypot(a.1 - b.1)
            })
            .fold(f64::MAX, f64::min);
        Case {
            image,
            u_px,
            v_px,
            orientation_rad,
            span_px,
        }
    }

    fn percentile(values: &[f64], p: f64) -> f64 {
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        sorted
            .get(((sorted.len().max(1) - 1) as f64 * p).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    }

    /// Errors over frames whose marker spans at least 30 px, and the detection rate below that.
    #[derive(Default)]
    struct Errors {
        counted: usize,
        detected: usize,
        small: usize,
        small_detected: usize,
        centre_px: Vec<f64>,
        orientation_deg: Vec<f64>,
    }

    impl Errors {
        fn report(&self, name: &str) {
            let (c, o) = (&self.centre_px, &self.orientation_deg);
            println!(
                "{name}: {}/{} markers ≥ 30 px detected ({}/{} smaller); centre error median \
                 {:.3} px, p95 {:.3} px, max {:.3} px; orientation error median {:.3}°, p95 \
                 {:.3}°, max {:.3}°",
                self.detected,
                self.counted,
                self.small_detected,
                self.small,
                percentile(c, 0.5),
                percentile(c, 0.95),
                percentile(c, 1.0),
                percentile(o, 0.5),
                percentile(o, 0.95),
                percentile(o, 1.0),
            );
        }
    }

    enum Mode {
        FullFrame,
        /// An ROI of this half-size around the truth moved up to 10 px.
        Roi(f64),
    }

    fn run(
        seed: u64,
        frames: usize,
        config: NfoldConfig,
        mode: Mode,
        occluder: fn(&mut StdRng) -> Option<Patch>,
        altitude_m: (f64, f64),
    ) -> Errors {
        let oriented = config.oriented;
        let detector = NfoldDetector::new(config).unwrap();
        let mut rng = StdRng::seed_from_u64(seed);
        let mut errors = Errors::default();
        for _ in 0..frames {
            let occluder = occluder(&mut rng);
            let case = random_case(&mut rng, oriented, occluder, altitude_m);
            let view = case.image.view();
            let found = match mode {
                Mode::FullFrame => detector.detect(&view),
                Mode::Roi(half) => {
                    let (du, dv) = (rng.random_range(-10.0..10.0), rng.random_range(-10.0..10.0));
                    let roi = Roi::around(case.u_px + du, case.v_px + dv, half);
                    detector.detect_in_roi(&view, &roi)
                }
            }
            .unwrap();
            if case.span_px < 30.0 {
                errors.small += 1;
                errors.small_detected += usize::from(found.is_some());
                continue;
            }
            errors.counted += 1;
            let Some(d) = found else { continue };
            errors.detected += 1;
            errors
                .centre_px
                .push((d.u_px - case.u_px).hypot(d.v_px - case.v_px));
            let period = if oriented { TAU } else { TAU / 4.0 };
            let e = (d.orientation_rad - case.orientation_rad).rem_euclid(period);
            errors.orientation_deg.push(e.min(period - e).to_degrees());
        }
        errors
    }

    fn no_occluder(_: &mut StdRng) -> Option<Patch> {
        None
    }

    /// A grey square over the tip, 4 cm (8 % of the marker's diameter).
    fn tip_occluder(rng: &mut StdRng) -> Option<Patch> {
        let level = rng.random_range(0.3..0.8);
        let yaw = rng.random_range(0.0..PI);
        Some(Patch::square(0.0, 0.0, yaw, 0.04, Texture::uniform(level)))
    }

    /// A square of any grey over the outer part of a sector, tip clear: 10 cm, centred 13 cm out.
    fn sector_occluder(rng: &mut StdRng) -> Option<Patch> {
        let (dir, level) = (rng.random_range(-PI..PI), rng.random_range(0.0..1.0));
        let (north, east) = (0.13 * dir.cos(), 0.13 * dir.sin());
        Some(Patch::square(
            north,
            east,
            dir,
            0.1,
            Texture::uniform(level),
        ))
    }

    #[test]
    fn random_poses_give_the_centre_and_orientation() {
        let errors = run(
            11,
            100,
            NfoldConfig::default(),
            Mode::FullFrame,
            no_occluder,
            (1.0, 20.0),
        );
        errors.report("n-fold, full frame");
        assert!(errors.counted >= 60);
        assert_eq!(
            errors.detected, errors.counted,
            "every marker ≥ 30 px is found"
        );
        assert!(percentile(&errors.centre_px, 0.5) < 0.5);
        assert!(percentile(&errors.centre_px, 0.95) < 1.5);
        assert!(percentile(&errors.orientation_deg, 1.0) < 2.0);
    }

    #[test]
    #[ignore = "500 frames: about half a minute"]
    fn random_poses_give_the_centre_and_orientation_500() {
        let errors = run(
            31,
            500,
            NfoldConfig::default(),
            Mode::FullFrame,
            no_occluder,
            (1.0, 20.0),
        );
        errors.report("n-fold, full frame, 500 frames");
        assert_eq!(errors.detected, errors.counted);
        assert!(percentile(&errors.centre_px, 0.5) < 0.5);
        assert!(percentile(&errors.centre_px, 0.95) < 1.5);
        assert!(percentile(&errors.orientation_deg, 1.0) < 2.0);
        let config = NfoldConfig {
            oriented: true,
            ..NfoldConfig::default()
        };
        let errors = run(32, 500, config, Mode::FullFrame, no_occluder, (1.0, 20.0));
        errors.report("oriented n-fold, full frame, 500 frames");
        assert_eq!(errors.detected, errors.counted);
        assert!(percentile(&errors.orientation_deg, 0.95) < 2.0);
    }

    #[test]
    fn oriented_markers_give_the_full_orientation() {
        let config = NfoldConfig {
            oriented: true,
            ..NfoldConfig::default()
        };
        let errors = run(12, 50, config, Mode::FullFrame, no_occluder, (1.0, 20.0));
        errors.report("oriented n-fold, full frame");
        assert_eq!(errors.detected, errors.counted);
        assert!(percentile(&errors.centre_px, 0.5) < 0.5);
        assert!(percentile(&errors.centre_px, 0.95) < 1.5);
        // Errors are modulo 2π here: a wrong leg would show as 90° or more.
        assert!(percentile(&errors.orientation_deg, 0.95) < 2.0);
        assert!(percentile(&errors.orientation_deg, 1.0) < 3.0);
    }

    #[test]
    fn a_region_of_interest_finds_the_predicted_marker() {
        let errors = run(
            13,
            30,
            NfoldConfig::default(),
            Mode::Roi(40.0),
            no_occluder,
            (1.0, 20.0),
        );
        errors.report("n-fold, ROI ±40 px");
        assert_eq!(errors.detected, errors.counted);
        assert!(percentile(&errors.centre_px, 0.5) < 0.5);
        assert!(percentile(&errors.centre_px, 0.95) < 1.5);
        assert!(percentile(&errors.orientation_deg, 1.0) < 2.0);
        // A prediction far from the marker, or off the frame, finds nothing.
        let mut rng = StdRng::seed_from_u64(14);
        let case = random_case(&mut rng, false, None, (4.0, 5.0));
        let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
        let view = case.image.view();
        let far_u = if case.u_px < 320.0 { 560.0 } else { 80.0 };
        let far = Roi::around(far_u, case.v_px, 30.0);
        assert_eq!(detector.detect_in_roi(&view, &far).unwrap(), None);
        let outside = Roi::around(-100.0, -100.0, 30.0);
        assert_eq!(detector.detect_in_roi(&view, &outside).unwrap(), None);
    }

    #[test]
    fn an_occluded_tip_is_still_detected() {
        // 3–8 m: the 4 cm occluder is 3–7 px wide, within the larger kernels' reach.
        let errors = run(
            15,
            25,
            NfoldConfig::default(),
            Mode::FullFrame,
            tip_occluder,
            (3.0, 8.0),
        );
        errors.report("n-fold, tip occluded");
        assert_eq!(errors.detected, errors.counted);
        assert!(percentile(&errors.centre_px, 1.0) < 1.5);
    }

    #[test]
    fn an_occluded_sector_is_still_detected() {
        let errors = run(
            16,
            25,
            NfoldConfig::default(),
            Mode::FullFrame,
            sector_occluder,
            (1.5, 9.0),
        );
        errors.report("n-fold, sector occluded");
        assert_eq!(errors.detected, errors.counted);
        assert!(percentile(&errors.centre_px, 0.5) < 0.5);
        assert!(percentile(&errors.centre_px, 1.0) < 1.5);
    }

    /// A random frame without an n-fold marker: a field, and up to five of ArUco markers on white
    /// boards, plain rectangles of any grey, and patches of another field; random pose and effects.
    fn random_markerless(rng: &mut StdRng, supersampling: usize) -> GrayImage {
        let mut scene = Scene::new(Texture::field(rng.random()));
        for _ in 0..rng.random_range(0..6) {
            let (n, e) = (rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
            let yaw = rng.random_range(-PI..PI);
            let size = rng.random_range(0.1..0.8);
            scene = match rng.random_range(0..3) {
                0 => {
                    let bits: Vec<bool> = (0..16).map(|_| rng.random_bool(0.5)).collect();
                    let aruco = Texture::aruco(&bits, 4).unwrap();
                    scene
                        .with_patch(Patch::square(n, e, yaw, size * 1.4, Texture::uniform(1.0)))
                        .with_patch(Patch::square(n, e, yaw, size, aruco))
                }
                1 => {
                    let (level, aspect) = (rng.random_range(0.0..1.0), rng.random_range(0.2..3.0));
                    let texture = Texture::uniform(level);
                    scene.with_patch(Patch::new(n, e, yaw, size, size * aspect, texture))
                }
                _ => {
                    let texture = Texture::field(rng.random());
                    scene.with_patch(Patch::square(n, e, yaw, size * 3.0, texture))
                }
            };
        }
        let altitude_m = rng.random_range(1.0f64.ln()..20f64.ln()).exp();
        let tilt = rng.random_range(0.0..25f64.to_radians());
        let dir = rng.random_range(-PI..PI);
        let position = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            -altitude_m,
        );
        let yaw = rng.random_range(-PI..PI);
        let pose = CameraPose::downward(position, tilt * dir.cos(), tilt * dir.sin(), yaw);
        let effects = ImageEffects {
            gaussian_blur_sigma_px: if rng.random_bool(0.5) {
                rng.random_range(0.0..1.2)
            } else {
                0.0
            },
            contrast: rng.random_range(0.5..1.3),
            brightness: rng.random_range(-0.15..0.15),
            noise_sigma: rng.random_range(0.0..6.0),
            noise_seed: rng.random(),
            ..Default::default()
        };
        let options = RenderOptions {
            supersampling,
            effects,
        };
        render(&camera(), &pose, &scene, &options).unwrap()
    }

    fn false_positives(seed: u64, frames: usize, oriented: bool) -> usize {
        let config = NfoldConfig {
            oriented,
            ..NfoldConfig::default()
        };
        let detector = NfoldDetector::new(config).unwrap();
        let mut rng = StdRng::seed_from_u64(seed);
        (0..frames)
            .filter(|_| {
                // Without anti-aliasing: it is texture, and this keeps the test quick.
                let image = random_markerless(&mut rng, 1);
                detector.detect(&image.view()).unwrap().is_some()
            })
            .count()
    }

    #[test]
    fn markerless_frames_give_no_detection() {
        // 200 frames (100 for the oriented variant) in the default suite; the 1,000-frame version
        // is ignored (run it with --ignored). Fewer than 1 % may be false positives.
        for (oriented, frames) in [(false, 200), (true, 100)] {
            let fp = false_positives(17, frames, oriented);
            println!("markerless frames (oriented: {oriented}): {fp} false positives in {frames}");
            assert!(fp * 100 < frames, "{fp} false positives in {frames} frames");
        }
    }

    #[test]
    #[ignore = "1,000 frames: about a minute"]
    fn markerless_frames_give_no_detection_1000() {
        let fp = false_positives(18, 1000, false);
        println!("markerless frames: {fp} false positives in 1000");
        assert!(fp * 100 < 1000, "{fp} false positives in 1000 frames");
    }

    #[test]
    fn flat_frames_give_no_detection() {
        let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
        let grey = GrayImage::filled(640, 480, 128).unwrap();
        assert_eq!(detector.detect(&grey.view()).unwrap(), None);
        let mut noise = crate::vision::render::SplitMix64::new(3);
        let data = (0..640 * 480)
            .map(|_| (noise.next_u64() >> 56) as u8)
            .collect();
        let noise = GrayImage::from_vec(640, 480, data).unwrap();
        assert_eq!(detector.detect(&noise.view()).unwrap(), None);
    }

    #[test]
    fn bad_frames_are_named_errors() {
        let config = NfoldConfig {
            expected_frame_size_px: Some((640, 480)),
            ..NfoldConfig::default()
        };
        let detector = NfoldDetector::new(config).unwrap();
        let small = GrayImage::filled(320, 240, 0).unwrap();
        assert!(matches!(
            detector.detect(&small.view()),
            Err(NfoldError::Frame(FrameError::WrongSize { .. }))
        ));
        let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
        let tiny = GrayImage::filled(20, 400, 0).unwrap();
        assert_eq!(
            detector.detect(&tiny.view()),
            Err(NfoldError::FrameTooSmall {
                width_px: 20,
                height_px: 400,
                min_px: 25
            })
        );
        assert!(matches!(
            detector.detect_in_roi(&tiny.view(), &Roi::around(10.0, 10.0, 5.0)),
            Err(NfoldError::FrameTooSmall { .. })
        ));
        // Zero size, short strides and short buffers are refused when the view is made.
        assert!(ImageView::new(0, 480, 640, &[]).is_err());
        assert!(ImageView::new(640, 480, 600, &vec![0; 640 * 480]).is_err());
        assert!(ImageView::new(640, 480, 640, &vec![0; 1000]).is_err());
    }

    #[test]
    fn padded_rows_are_read_through_the_stride() {
        let mut rng = StdRng::seed_from_u64(19);
        let case = random_case(&mut rng, false, None, (3.0, 4.0));
        let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
        let packed = detector.detect(&case.image.view()).unwrap().unwrap();
        // The same frame in rows of 704 bytes whose padding is white noise.
        let stride = 704;
        let mut padded = vec![0u8; stride * 480];
        for (y, row) in padded.chunks_mut(stride).enumerate() {
            row[..640].copy_from_slice(&case.image.data()[y * 640..(y + 1) * 640]);
            row[640..]
                .iter_mut()
                .enumerate()
                .for_each(|(i, p)| *p = (i * 97 % 251) as u8);
        }
        let view = ImageView::new(640, 480, stride, &padded).unwrap();
        assert_eq!(detector.detect(&view).unwrap(), Some(packed));
    }

    #[test]
    fn bad_configs_are_named_errors() {
        let with = |f: fn(&mut NfoldConfig)| {
            let mut c = NfoldConfig::default();
            f(&mut c);
            NfoldDetector::new(c).unwrap_err()
        };
        assert_eq!(with(|c| c.order = 1), NfoldConfigError::Order(1));
        assert_eq!(
            with(|c| c.kernel_sizes_px = vec![13, 16]),
            NfoldConfigError::KernelSize(16)
        );
        assert_eq!(
            with(|c| c.search_kernel_px = 3),
            NfoldConfigError::KernelSize(3)
        );
        assert_eq!(
            with(|c| c.kernel_sizes_px.clear()),
            NfoldConfigError::NoKernelSizes
        );
        assert_eq!(
            with(|c| c.quality_threshold = 1.5),
            NfoldConfigError::QualityThreshold(1.5)
        );
        assert_eq!(
            with(|c| c.search_level = 4),
            NfoldConfigError::SearchLevel(4)
        );
        assert_eq!(with(|c| c.candidates = 0), NfoldConfigError::NoCandidates);
    }

    #[test]
    fn the_separable_search_equals_the_direct_kernel() {
        let mut rng = StdRng::seed_from_u64(20);
        let (w, h) = (61, 47);
        let data: Vec<u8> = (0..w * h).map(|_| rng.random()).collect();
        let image = GrayImage::from_vec(w, h, data).unwrap();
        let view = image.view();
        for (order, size) in [(4, 13), (3, 9), (5, 25), (2, 7)] {
            let separable = SeparableKernel::new(order, size);
            let direct = DirectKernel::new(order, size);
            let plane = Plane::from_view(&view, 0, 0, w, h, 0);
            let response = separable.magnitude_squared(&plane);
            let r = size / 2;
            assert_eq!((response.width, response.height), (w - 2 * r, h - 2 * r));
            for y in 0..response.height {
                for x in 0..response.width {
                    let (re, im) = direct
                        .response(&view, (x + r) as i64, (y + r) as i64)
                        .unwrap();
                    let exact = re * re + im * im;
                    let got = response.data[y * response.width + x] as f64;
                    // f32 accumulation against f64.
                    let scale = (direct.abs_sum * 255.0).powi(2);
                    assert!(
                        (got - exact).abs() < 1e-5 * scale,
                        "{order}/{size} at {x},{y}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_phase_gives_the_drawn_orientation() {
        // A level camera with yaw 0 sees the patch upright: the image orientation is the
        // patch's yaw.
        let cam = camera();
        let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -4.0), 0.0, 0.0, 0.0);
        for oriented in [false, true] {
            let config = NfoldConfig {
                oriented,
                ..NfoldConfig::default()
            };
            let detector = NfoldDetector::new(config).unwrap();
            for k in 0..12 {
                let yaw = -PI + (k as f64 + 0.3) * TAU / 12.0;
                let marker = Patch::square(
                    0.2,
                    -0.3,
                    yaw,
                    MARKER_M,
                    Texture::nfold(4, oriented).unwrap(),
                );
                let scene = Scene::new(Texture::uniform(1.0)).with_patch(marker);
                let options = RenderOptions {
                    supersampling: 4,
                    ..Default::default()
                };
                let image = render(&cam, &pose, &scene, &options).unwrap();
                let d = detector.detect(&image.view()).unwrap().unwrap();
                let (u, v) = cam
                    .project_world(&pose, &Point3::new(0.2, -0.3, 0.0))
                    .unwrap();
                assert!((d.u_px - u).abs() < 0.1 && (d.v_px - v).abs() < 0.1);
                let period = if oriented { TAU } else { TAU / 4.0 };
                let e = (d.orientation_rad - yaw).rem_euclid(period);
                assert!(e.min(period - e) < 0.5f64.to_radians(), "{yaw}: {d:?}");
                assert_eq!(d.orientation_resolved, oriented);
                assert!(d.quality > 0.7 && d.kernel_size_px == 13, "{d:?}");
                // Black 0 and white 255: |R|/Σ|K| is about 0.3 × 255, ¾ of that with a leg missing.
                let expected = if oriented { 0.75 * 75.0 } else { 75.0 };
                assert!((d.response_magnitude / expected - 1.0).abs() < 0.1, "{d:?}");
            }
        }
    }

    #[test]
    fn the_quadratic_fit_finds_the_peak_of_a_quadratic() {
        let f = |x: f64, y: f64| {
            10.0 - 2.0 * (x - 0.3).powi(2) - (y + 0.2).powi(2) - 0.5 * (x - 0.3) * (y + 0.2)
        };
        let grid = [-1.0, 0.0, 1.0].map(|y| [-1.0, 0.0, 1.0].map(|x| f(x, y)));
        let (du, dv) = quadratic_peak(&grid);
        assert!((du - 0.3).abs() < 1e-12 && (dv + 0.2).abs() < 1e-12);
    }
}
