//! ArUco marker detection: OpenCV's dictionaries read from a grayscale frame.
//!
//! The pipeline, per threshold window: adaptive threshold (window mean − offset, from an
//! integral image) → dark regions (run-length labelling) → the outer contour of each region of
//! plausible size → Douglas–Peucker polygon, kept when it is a convex quad of fair sides away
//! from the frame's edge → cells sampled through the quad's homography and classified with
//! Otsu's threshold over the marker's samples → checks that it looks printed (contrast, flat
//! classes, at most one unsure cell, a bright quiet zone around it) → all border cells black →
//! the closest code over four rotations within the dictionary's correction limit → sub-pixel
//! corners from lines fitted to the four sides.
//!
//! Corners follow OpenCV: corner 0 is the marker's top-left (as its image is drawn upright),
//! then top-right, bottom-right, bottom-left, which is clockwise on screen. Pixel coordinates
//! have integer values at pixel centres, as in [`crate::camera`].

mod contour;
mod decode;
mod dictionary;
mod refine;
mod threshold;

pub use dictionary::{
    rotate_code, CodeMatch, Dictionary, DictionaryError, DICT_4X4_50, DICT_ARUCO_ORIGINAL,
};
pub use threshold::{PixelRect, ThresholdMethod};

use crate::vision::image::{FrameError, ImageView};
use contour::{ContourScratch, Region};
use decode::{SamplingParams, SamplingScratch};
use refine::{RefineParams, RefineScratch};
use thiserror::Error;
use threshold::{BinaryImage, ThresholdScratch};

/// Tuning of the detector. The defaults suit 640×480 frames with markers from about 12 px
/// across to most of the frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ArucoConfig {
    /// Sides of the square windows of the adaptive threshold, px (odd, at least 3). Each is a
    /// full pass over the frame; one window finds markers from about 12 px across to the whole
    /// frame (larger ones are only hollowed inside, and their outline is what counts).
    pub threshold_windows_px: Vec<usize>,
    /// A pixel is dark when it is this many grey levels below its window's mean. Markers have
    /// far more contrast than this; textured ground has little more than sensor noise, and a
    /// higher offset leaves fewer of its specks to trace.
    pub threshold_offset: u8,
    /// Which way the window means are computed.
    pub threshold_method: ThresholdMethod,
    /// Perimeter range of a marker's quad, px.
    pub min_perimeter_px: f32,
    pub max_perimeter_px: f32,
    /// Douglas–Peucker tolerance as a fraction of the contour's length (at least 1 px).
    pub polygon_epsilon_rate: f32,
    /// Shortest side of a quad as a fraction of its perimeter (rejects slivers).
    pub min_side_rate: f32,
    /// Quads with a corner closer than this to the edge of the frame (or of the region of
    /// interest) are cut off, so they are skipped, px.
    pub min_distance_to_border_px: f32,
    /// Fraction of each cell's side left out at each edge when sampling it.
    pub cell_margin_rate: f32,
    /// Samples per cell side (this squared per cell).
    pub samples_per_cell: usize,
    /// Smallest difference between the dark and bright grey levels of a marker.
    pub min_contrast: f32,
    /// Largest standard deviation of a marker's samples within the dark and bright classes, as
    /// a fraction of its contrast (printed black and white are flat; texture is not).
    pub max_spread_rate: f32,
    /// A cell whose mean lies within this fraction of the contrast of the threshold, or whose
    /// samples fall on both sides of it, is unsure; `max_unsure_cells` of them are allowed.
    pub unsure_cell_rate: f32,
    pub max_unsure_cells: usize,
    /// The quiet zone (white margin) around the marker is checked this many cells outside its
    /// border; 0 skips the check.
    pub quiet_zone_cells: f32,
    /// Fraction of the quiet zone's samples that must read bright.
    pub min_quiet_zone_bright_rate: f32,
    /// Border cells that may read white.
    pub max_border_errors: usize,
    /// Bit errors corrected; `None` uses the dictionary's own limit.
    pub max_correction_bits: Option<u32>,
    /// Locate the sides in the grey levels for sub-pixel corners (otherwise the corners come
    /// from lines through the thresholded outline, good to about half a pixel).
    pub refine_corners: bool,
}

impl Default for ArucoConfig {
    fn default() -> Self {
        Self {
            threshold_windows_px: vec![15],
            threshold_offset: 14,
            threshold_method: ThresholdMethod::IntegralImage,
            min_perimeter_px: 40.0,
            max_perimeter_px: 2000.0,
            polygon_epsilon_rate: 0.04,
            min_side_rate: 0.1,
            min_distance_to_border_px: 2.0,
            cell_margin_rate: 0.2,
            samples_per_cell: 3,
            min_contrast: 25.0,
            max_spread_rate: 0.2,
            unsure_cell_rate: 0.15,
            max_unsure_cells: 1,
            quiet_zone_cells: 0.5,
            min_quiet_zone_bright_rate: 0.8,
            max_border_errors: 0,
            max_correction_bits: None,
            refine_corners: true,
        }
    }
}

/// Widest box (either way) of a region that may be a marker.
const MAX_BOX_ASPECT: f32 = 4.0;

/// A marker found in a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ArucoMarker {
    /// Index of its code in the dictionary.
    pub id: usize,
    /// Corners (u, v) in pixels of the whole frame, sub-pixel, in OpenCV's order: top-left,
    /// top-right, bottom-right, bottom-left of the upright marker.
    pub corners_px: [(f64, f64); 4],
    /// Bits that differed from the code (corrected).
    pub hamming_distance: u32,
    /// How the marker is turned on screen: quarter turns clockwise from upright (top edge
    /// pointing right, corner 0 at the top-left), nearest to the top edge's direction.
    pub rotation_quarter_turns: u8,
}

impl ArucoMarker {
    /// Mean of the four corners, px.
    pub fn centre_px(&self) -> (f64, f64) {
        let (mut u, mut v) = (0.0, 0.0);
        for (cu, cv) in self.corners_px {
            u += cu / 4.0;
            v += cv / 4.0;
        }
        (u, v)
    }

    /// Length of the quad's outline, px.
    pub fn perimeter_px(&self) -> f64 {
        (0..4)
            .map(|i| {
                let (a, b) = (self.corners_px[i], self.corners_px[(i + 1) % 4]);
                ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt()
            })
            .sum()
    }
}

/// Why detection did not run.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ArucoError {
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error("the region of interest {roi:?} does not overlap the {width}×{height} frame")]
    RoiOutsideFrame {
        roi: PixelRect,
        width: usize,
        height: usize,
    },
    #[error("invalid ArUco detector setting {setting}: {reason}")]
    Config {
        setting: &'static str,
        reason: String,
    },
}

/// The detector: a dictionary, its settings and reusable buffers.
#[derive(Debug)]
pub struct ArucoDetector {
    dictionary: Dictionary,
    config: ArucoConfig,
    binary: BinaryImage,
    threshold_scratch: ThresholdScratch,
    contour_scratch: ContourScratch,
    sampling_scratch: SamplingScratch,
    refine_scratch: RefineScratch,
}

/// A quad that read as a marker, before the duplicates across windows are merged.
#[derive(Debug, Clone, Copy)]
struct Found {
    id: usize,
    corners: [[f32; 2]; 4],
    hamming_distance: u32,
    perimeter_px: f32,
}

fn config_error(setting: &'static str, reason: impl Into<String>) -> ArucoError {
    ArucoError::Config {
        setting,
        reason: reason.into(),
    }
}

fn validate(config: &ArucoConfig) -> Result<(), ArucoError> {
    if config.threshold_windows_px.is_empty() {
        return Err(config_error(
            "threshold_windows_px",
            "needs at least one window",
        ));
    }
    for &w in &config.threshold_windows_px {
        if w < 3 || w % 2 == 0 || w > 1001 {
            return Err(config_error(
                "threshold_windows_px",
                format!("window {w} px must be odd and between 3 and 1001"),
            ));
        }
    }
    let positive = |v: f32| v.is_finite() && v > 0.0;
    let ordered = config
        .max_perimeter_px
        .partial_cmp(&config.min_perimeter_px);
    if !positive(config.min_perimeter_px) || ordered != Some(std::cmp::Ordering::Greater) {
        return Err(config_error(
            "min_perimeter_px/max_perimeter_px",
            "need 0 < min < max",
        ));
    }
    if !(config.polygon_epsilon_rate > 0.0 && config.polygon_epsilon_rate < 0.5) {
        return Err(config_error("polygon_epsilon_rate", "must be in (0, 0.5)"));
    }
    if !(config.min_side_rate >= 0.0 && config.min_side_rate < 0.25) {
        return Err(config_error("min_side_rate", "must be in [0, 0.25)"));
    }
    if !(config.min_distance_to_border_px >= 0.0 && config.min_distance_to_border_px.is_finite()) {
        return Err(config_error("min_distance_to_border_px", "must be ≥ 0"));
    }
    if !(config.cell_margin_rate >= 0.0 && config.cell_margin_rate < 0.5) {
        return Err(config_error("cell_margin_rate", "must be in [0, 0.5)"));
    }
    if !(1..=8).contains(&config.samples_per_cell) {
        return Err(config_error("samples_per_cell", "must be 1 to 8"));
    }
    if !(config.min_contrast >= 0.0 && config.min_contrast < 255.0) {
        return Err(config_error("min_contrast", "must be in [0, 255)"));
    }
    let rate = |v: f32| (0.0..=1.0).contains(&v);
    if !rate(config.max_spread_rate) {
        return Err(config_error("max_spread_rate", "must be in [0, 1]"));
    }
    if !(config.unsure_cell_rate >= 0.0 && config.unsure_cell_rate < 0.5) {
        return Err(config_error("unsure_cell_rate", "must be in [0, 0.5)"));
    }
    if !(config.quiet_zone_cells >= 0.0 && config.quiet_zone_cells <= 4.0) {
        return Err(config_error("quiet_zone_cells", "must be in [0, 4]"));
    }
    if !rate(config.min_quiet_zone_bright_rate) {
        return Err(config_error(
            "min_quiet_zone_bright_rate",
            "must be in [0, 1]",
        ));
    }
    Ok(())
}

impl ArucoDetector {
    /// A detector for `dictionary`; fails on settings that cannot work.
    pub fn new(dictionary: Dictionary, config: ArucoConfig) -> Result<Self, ArucoError> {
        validate(&config)?;
        if let Some(bits) = config.max_correction_bits {
            if bits > dictionary.max_correction_bits() {
                return Err(config_error(
                    "max_correction_bits",
                    format!(
                        "{bits} is more than {} can correct ({})",
                        dictionary.name(),
                        dictionary.max_correction_bits()
                    ),
                ));
            }
        }
        Ok(Self {
            dictionary,
            config,
            binary: BinaryImage::default(),
            threshold_scratch: ThresholdScratch::default(),
            contour_scratch: ContourScratch::default(),
            sampling_scratch: SamplingScratch::default(),
            refine_scratch: RefineScratch::default(),
        })
    }

    pub fn dictionary(&self) -> &Dictionary {
        &self.dictionary
    }

    pub fn config(&self) -> &ArucoConfig {
        &self.config
    }

    /// Markers in the whole frame.
    pub fn detect(&mut self, image: &ImageView<'_>) -> Result<Vec<ArucoMarker>, ArucoError> {
        let rect = PixelRect {
            x: 0,
            y: 0,
            width: image.width(),
            height: image.height(),
        };
        Ok(self.detect_rect(image, rect))
    }

    /// Markers in a raw buffer: `height` rows of `width` pixels, `stride` bytes apart.
    pub fn detect_buffer(
        &mut self,
        width: usize,
        height: usize,
        stride: usize,
        data: &[u8],
    ) -> Result<Vec<ArucoMarker>, ArucoError> {
        let view = ImageView::new(width, height, stride, data)?;
        self.detect(&view)
    }

    /// Markers wholly inside `roi` (clipped to the frame); corners are in frame pixels.
    pub fn detect_in_roi(
        &mut self,
        image: &ImageView<'_>,
        roi: PixelRect,
    ) -> Result<Vec<ArucoMarker>, ArucoError> {
        let x1 = roi.x.saturating_add(roi.width).min(image.width());
        let y1 = roi.y.saturating_add(roi.height).min(image.height());
        if roi.x >= x1 || roi.y >= y1 {
            return Err(ArucoError::RoiOutsideFrame {
                roi,
                width: image.width(),
                height: image.height(),
            });
        }
        let rect = PixelRect {
            x: roi.x,
            y: roi.y,
            width: x1 - roi.x,
            height: y1 - roi.y,
        };
        Ok(self.detect_rect(image, rect))
    }

    fn detect_rect(&mut self, image: &ImageView<'_>, rect: PixelRect) -> Vec<ArucoMarker> {
        let mut found: Vec<Found> = Vec::new();
        for w in 0..self.config.threshold_windows_px.len() {
            let window_px = self.config.threshold_windows_px[w];
            threshold::adaptive_threshold(
                image,
                rect,
                window_px,
                self.config.threshold_offset,
                self.config.threshold_method,
                &mut self.threshold_scratch,
                &mut self.binary,
            );
            contour::label_regions(&self.binary, &mut self.contour_scratch);
            let regions = std::mem::take(&mut self.contour_scratch.regions);
            for region in &regions {
                if let Some(quad) = self.quad_of(region, rect) {
                    // A quad already read from an earlier window is not read again.
                    if found.iter().any(|f| same_quad(&f.corners, &quad)) {
                        continue;
                    }
                    if let Some(marker) = self.read_quad(image, &quad) {
                        found.push(marker);
                    }
                }
            }
            self.contour_scratch.regions = regions;
        }
        // A quad inside a larger marker is a piece of it (a block of its cells), never a
        // marker of its own.
        let mut markers = Vec::with_capacity(found.len());
        for (i, f) in found.iter().enumerate() {
            let centre = quad_centre(&f.corners);
            let nested = found.iter().enumerate().any(|(j, g)| {
                j != i && g.perimeter_px > f.perimeter_px && inside(&g.corners, centre)
            });
            if !nested {
                markers.push(to_marker(f));
            }
        }
        markers
    }

    /// The convex quad of a region's outer contour, in frame pixels, clockwise on screen.
    fn quad_of(&mut self, region: &Region, rect: PixelRect) -> Option<[[f32; 2]; 4]> {
        let c = &self.config;
        let (w, h) = (
            (region.max_x - region.min_x + 1) as f32,
            (region.max_y - region.min_y + 1) as f32,
        );
        // A quad's perimeter lies between its box's diagonal ×2 and the box's perimeter.
        if 2.0 * (w + h) < c.min_perimeter_px || 2.0 * (w * w + h * h).sqrt() > c.max_perimeter_px {
            return None;
        }
        let border = c.min_distance_to_border_px;
        if (region.min_x as f32) < border
            || (region.min_y as f32) < border
            || (region.max_x as f32) > rect.width as f32 - 1.0 - border
            || (region.max_y as f32) > rect.height as f32 - 1.0 - border
        {
            return None;
        }
        // Squares seen from at most a steep angle have boxes of moderate aspect; crop rows and
        // shadows do not, and are the bulk of a field's dark regions.
        if w > MAX_BOX_ASPECT * h || h > MAX_BOX_ASPECT * w {
            return None;
        }
        let scratch = &mut self.contour_scratch;
        // The outer contour of a convex shape takes at most its box's perimeter in 8-connected
        // steps (a little more with noisy edges); a ragged blob of texture takes far more, so
        // stop tracing there.
        let max_points = (1.25 * 2.0 * (w + h)).min(2.0 * c.max_perimeter_px) as usize + 8;
        let mut contour = std::mem::take(&mut scratch.contour);
        let closed = contour::trace_outer_contour(
            &self.binary,
            region.start_x,
            region.start_y,
            max_points,
            &mut contour,
        );
        let length = contour::contour_length_px(&contour);
        scratch.contour = contour;
        if !closed || length < c.min_perimeter_px || length > c.max_perimeter_px {
            return None;
        }
        contour::approximate_polygon(scratch, (c.polygon_epsilon_rate * length).max(1.0));
        let vertices = contour::polygon_quad(scratch)?;
        if !contour::is_convex(&vertices) {
            return None;
        }
        // Lines through the sides give better corners than the vertices, unless a side is too
        // ragged to fit (then its corners would land far from the vertices).
        let mut quad = match contour::fitted_quad(scratch) {
            Some(fitted) if (0..4).all(|i| dist(fitted[i], vertices[i]) < 3.0) => fitted,
            _ => vertices,
        };
        if !contour::is_convex(&quad) {
            return None;
        }
        if contour::signed_area2(&quad) < 0.0 {
            quad.swap(1, 3);
        }
        let perimeter: f32 = (0..4).map(|i| dist(quad[i], quad[(i + 1) % 4])).sum();
        let min_side = (0..4)
            .map(|i| dist(quad[i], quad[(i + 1) % 4]))
            .fold(f32::MAX, f32::min);
        if min_side < c.min_side_rate * perimeter {
            return None;
        }
        for corner in &mut quad {
            corner[0] += rect.x as f32;
            corner[1] += rect.y as f32;
        }
        Some(quad)
    }

    /// Reads a quad as a marker of the dictionary.
    fn read_quad(&mut self, image: &ImageView<'_>, quad: &[[f32; 2]; 4]) -> Option<Found> {
        let c = &self.config;
        let n = self.dictionary.marker_size_bits();
        let params = SamplingParams {
            marker_size_bits: n,
            cell_margin_rate: c.cell_margin_rate,
            samples_per_cell: c.samples_per_cell,
            min_contrast: c.min_contrast,
            max_spread_rate: c.max_spread_rate,
            unsure_cell_rate: c.unsure_cell_rate,
            max_unsure_cells: c.max_unsure_cells,
            quiet_zone_cells: c.quiet_zone_cells,
            min_quiet_zone_bright_rate: c.min_quiet_zone_bright_rate,
        };
        let sampled = decode::sample_marker(image, quad, &params, &mut self.sampling_scratch)?;
        if sampled.border_errors > c.max_border_errors {
            return None;
        }
        let max_bits = c
            .max_correction_bits
            .unwrap_or(self.dictionary.max_correction_bits());
        let matched = self.dictionary.identify(sampled.code, max_bits)?;
        // The sampled grid is the marker turned k quarter turns counter-clockwise, so the
        // quad's corner i is the marker's corner i + k: the marker's corner j is quad j − k.
        let k = usize::from(matched.quarter_turns);
        let mut corners = [[0.0f32; 2]; 4];
        for (j, corner) in corners.iter_mut().enumerate() {
            *corner = quad[(j + 4 - k) % 4];
        }
        let perimeter_px: f32 = (0..4).map(|i| dist(corners[i], corners[(i + 1) % 4])).sum();
        if c.refine_corners {
            let cell_px = perimeter_px / 4.0 / (n + 2) as f32;
            let params = RefineParams {
                // Within the black border on the inside and the quiet zone outside.
                search_radius_px: (0.5 * cell_px).clamp(1.5, 4.0),
                dark_level: sampled.dark_level,
                bright_level: sampled.bright_level,
            };
            let first = refine::refine_corners(image, &corners, &params, &mut self.refine_scratch);
            let refined = first.and_then(|first| {
                // Again from the better corners, with the profiles now centred on the edges.
                refine::refine_corners(image, &first, &params, &mut self.refine_scratch)
            });
            if let Some(refined) = refined {
                // A refinement that wandered off is worse than the polygon's corners.
                let limit = (0.5 * cell_px).max(2.0);
                if (0..4).all(|i| dist(refined[i], corners[i]) <= limit) {
                    corners = refined;
                }
            }
        }
        Some(Found {
            id: matched.id,
            corners,
            hamming_distance: matched.hamming_distance,
            perimeter_px,
        })
    }
}

fn dist(a: [f32; 2], b: [f32; 2]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

fn quad_centre(quad: &[[f32; 2]; 4]) -> [f32; 2] {
    let mut c = [0.0; 2];
    for p in quad {
        c[0] += p[0] / 4.0;
        c[1] += p[1] / 4.0;
    }
    c
}

/// Whether `p` lies inside a clockwise-on-screen convex quad.
fn inside(quad: &[[f32; 2]; 4], p: [f32; 2]) -> bool {
    (0..4).all(|i| {
        let (a, b) = (quad[i], quad[(i + 1) % 4]);
        (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0.0
    })
}

/// Whether two quads (any starting corner) are the same outline within a fraction of a side.
fn same_quad(a: &[[f32; 2]; 4], b: &[[f32; 2]; 4]) -> bool {
    let side = dist(a[0], a[1]).min(dist(a[1], a[2]));
    let tolerance = (0.2 * side).max(2.0);
    a.iter()
        .all(|p| b.iter().any(|q| dist(*p, *q) <= tolerance))
}

fn to_marker(found: &Found) -> ArucoMarker {
    let corners_px = found.corners.map(|[u, v]| (f64::from(u), f64::from(v)));
    let (top_u, top_v) = (
        corners_px[1].0 - corners_px[0].0,
        corners_px[1].1 - corners_px[0].1,
    );
    // With v down, a positive angle turns clockwise on screen.
    let quarter = (top_v.atan2(top_u) / std::f64::consts::FRAC_PI_2).round() as i64;
    ArucoMarker {
        id: found.id,
        corners_px,
        hamming_distance: found.hamming_distance,
        rotation_quarter_turns: quarter.rem_euclid(4) as u8,
    }
}

#[cfg(test)]
mod tests;
