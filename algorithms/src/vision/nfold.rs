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
//! A region's search (around a predicted centre) that finds nothing at full resolution tries
//! again at half, quarter, eighth and sixteenth resolution: close to the camera the marker is
//! tens of kernels wide, and an occluder on its tip fills every full-resolution kernel's disc.
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

use super::image::{FrameError, GrayImage, ImageView};

mod correlation;
mod sectors;
use correlation::{
    filled_response, is_even, strongest_peaks, DirectKernel, Peak, Plane, SeparableKernel,
};
use sectors::{symmetry_centre, SectorStats};

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
    #[error("a region's search falls back to at most 4 coarser levels, got {0}")]
    RoiFallbackLevels(u32),
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
    /// Coarser pyramid levels (half, quarter, … resolution) a region's search falls back to
    /// when it finds nothing at full resolution: close to the camera the marker is tens of
    /// kernels wide, and an occluder on its tip (mud, straw, a shadow) fills every
    /// full-resolution kernel, where a coarser level's kernels reach past it to the legs.
    pub roi_fallback_levels: u32,
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
            roi_fallback_levels: 4,
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
    /// The largest kernel, for a region's search at a coarser level (the tip hidden).
    roi_search_wide: SeparableKernel,
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
        if config.roi_fallback_levels > 4 {
            return Err(NfoldConfigError::RoiFallbackLevels(
                config.roi_fallback_levels,
            ));
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
            roi_search_wide: SeparableKernel::new(n, *sizes.last().unwrap_or(&smallest)),
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

    /// Searches only where the centre may be, at full resolution with the smallest kernel size,
    /// then (finding nothing) at each of `roi_fallback_levels` coarser levels in turn, the box
    /// and the detection in full-resolution pixels; a detection at level L reports its kernel's
    /// reach at full resolution (its size × 2^L). A box wholly outside the frame (or too thin
    /// for the kernel) finds nothing: `Ok(None)`.
    pub fn detect_in_roi(
        &self,
        image: &ImageView<'_>,
        roi: &Roi,
    ) -> Result<Option<NfoldDetection>, NfoldError> {
        self.check_frame(image)?;
        if let Some(found) = self.search_roi(image, roi, &self.roi_search) {
            return Ok(Some(found));
        }
        let mut coarse = None::<GrayImage>;
        for level in 1..=self.config.roi_fallback_levels {
            let finer = coarse.as_ref().map_or(*image, GrayImage::view);
            let Some(half) = finer.half_resolution() else {
                break;
            };
            let view = half.view();
            if view.width() < self.min_frame_px() || view.height() < self.min_frame_px() {
                break;
            }
            // Pixel k of level L covers full-resolution pixels k·2^L … (k + 1)·2^L − 1.
            let scale = f64::from(1u32 << level);
            let offset = (scale - 1.0) / 2.0;
            let to_level = |px: f64| (px - offset) / scale;
            let level_roi = Roi {
                min_u_px: to_level(roi.min_u_px),
                min_v_px: to_level(roi.min_v_px),
                max_u_px: to_level(roi.max_u_px),
                max_v_px: to_level(roi.max_v_px),
            };
            if let Some(found) = self.search_roi(&view, &level_roi, &self.roi_search_wide) {
                return Ok(Some(NfoldDetection {
                    u_px: found.u_px * scale + offset,
                    v_px: found.v_px * scale + offset,
                    kernel_size_px: found.kernel_size_px << level,
                    ..found
                }));
            }
            coarse = Some(half);
        }
        Ok(None)
    }

    /// [`Self::detect_in_roi`] at the image's own resolution.
    fn search_roi(
        &self,
        image: &ImageView<'_>,
        roi: &Roi,
        search: &SeparableKernel,
    ) -> Option<NfoldDetection> {
        let r = search.radius as f64;
        let (w, h) = (image.width() as f64, image.height() as f64);
        // Centres must keep the whole kernel inside the frame.
        let min_u = roi.min_u_px.ceil().max(r);
        let min_v = roi.min_v_px.ceil().max(r);
        let max_u = roi.max_u_px.floor().min(w - 1.0 - r);
        let max_v = roi.max_v_px.floor().min(h - 1.0 - r);
        if !(min_u <= max_u && min_v <= max_v) {
            return None;
        }
        let (x0, y0) = ((min_u - r) as usize, (min_v - r) as usize);
        let (x1, y1) = ((max_u + r) as usize + 1, (max_v + r) as usize + 1);
        let plane = Plane::from_view(image, x0, y0, x1 - x0, y1 - y0, 0);
        let response = search.magnitude_squared(&plane);
        let peaks = strongest_peaks(response, self.config.candidates, search.radius);
        let starts = peaks
            .into_iter()
            .map(|(x, y)| ((x0 + x) as f64 + r, (y0 + y) as f64 + r));
        self.refine_candidates(image, starts)
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

#[cfg(test)]
mod tests;
