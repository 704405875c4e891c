//! The landing marker: one n-fold marker at the pad's centre (the touchdown point) and a few
//! ArUco markers with known ids and offsets around it, detected together into one observation.
//!
//! The n-fold marker is found from far away and gives a sub-pixel centre; the ArUco markers give
//! the pad's orientation and a homography, and keep the position available when the n-fold tip
//! is occluded (by the landing gear's shadow, say) or out of the frame. Any one part seen gives a
//! position.
//!
//! Pad coordinates: metres from the pad's centre, x to the pad's right and y to its bottom, as
//! an image of the pad seen from above with its top forward (the renderer's patch u and v axes
//! scaled to metres).

use super::aruco::{
    ArucoConfig, ArucoDetector, ArucoError, ArucoMarker, Dictionary, DictionaryError, PixelRect,
};
use super::image::ImageView;
use super::nfold::{NfoldConfig, NfoldConfigError, NfoldDetection, NfoldDetector, NfoldError, Roi};
use super::render::{Patch, RenderError, Texture};
use nalgebra::{DMatrix, Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum LandingMarkerError {
    #[error("landing-marker layout: {0}")]
    Layout(String),
    #[error("landing-marker layout: {0}")]
    Dictionary(#[source] DictionaryError),
    #[error("landing-marker layout: the n-fold detector: {0}")]
    NfoldConfig(#[source] NfoldConfigError),
    #[error(transparent)]
    Nfold(#[from] NfoldError),
    #[error(transparent)]
    Aruco(#[from] ArucoError),
    #[error(transparent)]
    Render(#[from] RenderError),
}

/// One ArUco marker of the layout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArucoPart {
    pub id: usize,
    /// Side of the marker's black square, metres.
    pub size_m: f64,
    /// Centre in pad coordinates, metres.
    pub centre_m: [f64; 2],
}

/// What is printed on the pad.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LandingMarkerLayout {
    /// Side of the (white) pad, metres.
    pub pad_size_m: f64,
    /// n of the n-fold marker at the pad's centre.
    pub nfold_order: u32,
    /// One black leg is left white, which gives the marker an orientation.
    pub nfold_oriented: bool,
    /// Side of the square the n-fold pattern fills, metres.
    pub nfold_size_m: f64,
    /// OpenCV dictionary name of the ArUco markers (`DICT_4X4_50` or `DICT_ARUCO_ORIGINAL`).
    pub dictionary: String,
    pub aruco: Vec<ArucoPart>,
}

impl Default for LandingMarkerLayout {
    /// The reference 1 × 1 m pad: a 0.44 m oriented 4-fold marker in the centre and three 0.18 m
    /// DICT_4X4_50 markers (ids 1, 2, 3) in three corners, each with a white margin of at least
    /// one cell for its detector.
    fn default() -> Self {
        let aruco = |id, x, y| ArucoPart {
            id,
            size_m: 0.18,
            centre_m: [x, y],
        };
        Self {
            pad_size_m: 1.0,
            nfold_order: 4,
            nfold_oriented: true,
            nfold_size_m: 0.44,
            dictionary: "DICT_4X4_50".into(),
            aruco: vec![
                aruco(1, -0.38, -0.38),
                aruco(2, 0.38, -0.38),
                aruco(3, -0.38, 0.38),
            ],
        }
    }
}

impl LandingMarkerLayout {
    /// Checks sizes, ids and that no part overlaps another or leaves the pad.
    pub fn validate(&self) -> Result<Dictionary, LandingMarkerError> {
        let bad = |message: String| Err(LandingMarkerError::Layout(message));
        let dictionary =
            Dictionary::by_name(&self.dictionary).map_err(LandingMarkerError::Dictionary)?;
        if !(self.pad_size_m.is_finite() && self.pad_size_m > 0.0) {
            return bad(format!("pad_size_m must be > 0, got {}", self.pad_size_m));
        }
        if !(self.nfold_size_m > 0.0 && self.nfold_size_m <= self.pad_size_m) {
            return bad(format!(
                "nfold_size_m must be within (0, pad_size_m], got {}",
                self.nfold_size_m
            ));
        }
        let half_pad = self.pad_size_m / 2.0;
        let mut boxes = vec![(
            "the n-fold marker".to_string(),
            [0.0, 0.0],
            self.nfold_size_m,
        )];
        for part in &self.aruco {
            if part.id >= dictionary.len() {
                return bad(format!(
                    "ArUco id {} is not in {} (ids 0..{})",
                    part.id,
                    dictionary.name(),
                    dictionary.len()
                ));
            }
            if !(part.size_m.is_finite() && part.size_m > 0.0) {
                return bad(format!("ArUco {}: size_m must be > 0", part.id));
            }
            let reach = part.centre_m[0].abs().max(part.centre_m[1].abs()) + part.size_m / 2.0;
            if reach.is_nan() || reach > half_pad + 1e-9 {
                return bad(format!("ArUco {} does not fit on the pad", part.id));
            }
            boxes.push((format!("ArUco {}", part.id), part.centre_m, part.size_m));
        }
        for (i, a) in boxes.iter().enumerate() {
            for b in &boxes[i + 1..] {
                let gap = (a.1[0] - b.1[0]).abs().max((a.1[1] - b.1[1]).abs());
                if gap < (a.2 + b.2) / 2.0 {
                    return bad(format!("{} overlaps {}", a.0, b.0));
                }
            }
            if boxes[i + 1..].iter().any(|b| a.0 == b.0) {
                return bad(format!("{} is listed twice", a.0));
            }
        }
        Ok(dictionary)
    }

    /// The pad's patches for the renderer: the white pad, the n-fold marker, the ArUco markers.
    /// `north_m`, `east_m`, `down_m`, `yaw_rad` place the pad's centre in the world.
    pub fn patches(
        &self,
        north_m: f64,
        east_m: f64,
        down_m: f64,
        yaw_rad: f64,
    ) -> Result<Vec<Patch>, LandingMarkerError> {
        let dictionary = self.validate()?;
        let pad = Patch::square(
            north_m,
            east_m,
            yaw_rad,
            self.pad_size_m,
            Texture::uniform(1.0),
        )
        .at_down_m(down_m);
        // A part's centre in pad metres → world, through the pad patch's own axes.
        let half = self.pad_size_m / 2.0;
        let place = |centre_m: [f64; 2]| pad.point_world(centre_m[0] / half, centre_m[1] / half);
        let mut patches = Vec::with_capacity(2 + self.aruco.len());
        let nfold_texture = Texture::nfold(self.nfold_order, self.nfold_oriented)?;
        patches.push(pad.clone());
        patches.push(
            Patch::square(north_m, east_m, yaw_rad, self.nfold_size_m, nfold_texture)
                .at_down_m(down_m),
        );
        for part in &self.aruco {
            let bits = dictionary.marker_bits(part.id).ok_or_else(|| {
                LandingMarkerError::Layout(format!("ArUco id {} has no code", part.id))
            })?;
            let texture = Texture::aruco(&bits, dictionary.marker_size_bits())?;
            let centre = place(part.centre_m);
            patches.push(
                Patch::square(centre.x, centre.y, yaw_rad, part.size_m, texture).at_down_m(down_m),
            );
        }
        Ok(patches)
    }

    /// The four corners of an ArUco part in pad metres, in OpenCV's order (top-left, top-right,
    /// bottom-right, bottom-left of the upright marker).
    fn corners_m(part: &ArucoPart) -> [[f64; 2]; 4] {
        let h = part.size_m / 2.0;
        let [x, y] = part.centre_m;
        [
            [x - h, y - h],
            [x + h, y - h],
            [x + h, y + h],
            [x - h, y + h],
        ]
    }
}

/// Where the pad is in one frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LandingMarkerObservation {
    /// The pad's centre (touchdown point), sub-pixel, integer values at pixel centres.
    pub centre_px: [f64; 2],
    /// Angle of the pad's x axis in the image, from the image's u axis towards v; `None` when
    /// only a marker without orientation was seen.
    pub orientation_rad: Option<f64>,
    /// Which part gave the centre.
    pub centre_from: CentreSource,
    /// The n-fold marker, if seen and consistent with the ArUco markers.
    pub nfold: Option<NfoldSeen>,
    /// The layout's ArUco markers seen.
    pub aruco: Vec<ArucoSeen>,
    /// Pad metres → pixels, when ArUco markers gave one (row-major 3×3).
    pub homography: Option<[f64; 9]>,
    /// The pad's side in pixels along its x axis, when ArUco markers gave it: how large a
    /// region the next frame's search needs.
    pub pad_size_px: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CentreSource {
    Nfold,
    Aruco,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NfoldSeen {
    pub centre_px: [f64; 2],
    pub orientation_rad: f64,
    pub orientation_resolved: bool,
    pub quality: f64,
    pub kernel_size_px: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArucoSeen {
    pub id: usize,
    pub corners_px: [[f64; 2]; 4],
    pub hamming_distance: u32,
}

/// Settings of the combined detector.
#[derive(Debug, Clone, PartialEq)]
pub struct LandingMarkerConfig {
    pub layout: LandingMarkerLayout,
    pub nfold: NfoldConfig,
    pub aruco: ArucoConfig,
    /// An n-fold detection farther than this fraction of the pad's size (in pixels) from where
    /// the ArUco markers put the pad's centre is taken for something else on the field.
    pub consistency_fraction: f64,
}

impl Default for LandingMarkerConfig {
    fn default() -> Self {
        let layout = LandingMarkerLayout::default();
        let nfold = NfoldConfig {
            order: layout.nfold_order,
            oriented: layout.nfold_oriented,
            ..NfoldConfig::default()
        };
        Self {
            layout,
            nfold,
            aruco: ArucoConfig::default(),
            consistency_fraction: 0.15,
        }
    }
}

/// Finds the landing marker: ArUco markers first (cheap, exact ids), then the n-fold marker
/// where they predict it (or in the whole frame / the given region when none is seen).
pub struct LandingMarkerDetector {
    layout: LandingMarkerLayout,
    nfold: NfoldDetector,
    aruco: ArucoDetector,
    consistency_fraction: f64,
}

impl LandingMarkerDetector {
    pub fn new(config: LandingMarkerConfig) -> Result<Self, LandingMarkerError> {
        let dictionary = config.layout.validate()?;
        if config.nfold.order != config.layout.nfold_order
            || config.nfold.oriented != config.layout.nfold_oriented
        {
            return Err(LandingMarkerError::Layout(
                "the n-fold detector's order and orientation must match the layout's".into(),
            ));
        }
        let nfold = NfoldDetector::new(config.nfold).map_err(LandingMarkerError::NfoldConfig)?;
        Ok(Self {
            layout: config.layout,
            nfold,
            aruco: ArucoDetector::new(dictionary, config.aruco)?,
            consistency_fraction: config.consistency_fraction,
        })
    }

    pub fn layout(&self) -> &LandingMarkerLayout {
        &self.layout
    }

    /// Detects the pad in a frame; `roi` restricts the search around a predicted position.
    pub fn detect(
        &mut self,
        image: &ImageView<'_>,
        roi: Option<&Roi>,
    ) -> Result<Option<LandingMarkerObservation>, LandingMarkerError> {
        let markers = match roi {
            Some(roi) => match pixel_rect(roi, image) {
                Some(rect) => self.aruco.detect_in_roi(image, rect)?,
                None => Vec::new(),
            },
            None => self.aruco.detect(image)?,
        };
        let seen: Vec<(&ArucoPart, ArucoMarker)> = markers
            .into_iter()
            .filter_map(|m| {
                let part = self.layout.aruco.iter().find(|p| p.id == m.id)?;
                Some((part, m))
            })
            .collect();
        let homography = pad_homography(&seen);

        let predicted = homography.map(|h| apply(&h, [0.0, 0.0]));
        let pad_size_px = homography.map(|h| {
            let [x0, y0] = apply(&h, [0.0, 0.0]);
            let [x1, y1] = apply(&h, [self.layout.pad_size_m, 0.0]);
            ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt()
        });
        let nfold = match (predicted, pad_size_px) {
            (Some([u, v]), Some(scale_px)) => {
                // The markers place the centre to a few pixels: search a small box around it.
                let half_px = (scale_px * 0.08).max(12.0);
                self.nfold
                    .detect_in_roi(image, &Roi::around(u, v, half_px))?
                    .filter(|d| {
                        let distance = ((d.u_px - u).powi(2) + (d.v_px - v).powi(2)).sqrt();
                        distance <= self.consistency_fraction * scale_px
                    })
            }
            _ => match roi {
                Some(roi) => self.nfold.detect_in_roi(image, roi)?,
                None => self.nfold.detect(image)?,
            },
        };

        let orientation_from_homography = homography.map(|h| {
            let [x0, y0] = apply(&h, [0.0, 0.0]);
            let [x1, y1] = apply(&h, [1.0, 0.0]);
            (y1 - y0).atan2(x1 - x0)
        });
        let (centre_px, centre_from) = match (&nfold, predicted) {
            (Some(d), _) => ([d.u_px, d.v_px], CentreSource::Nfold),
            (None, Some(centre)) => (centre, CentreSource::Aruco),
            (None, None) => return Ok(None),
        };
        let orientation_rad = orientation_from_homography.or_else(|| {
            nfold
                .as_ref()
                .filter(|d| d.orientation_resolved)
                .map(|d| d.orientation_rad)
        });
        Ok(Some(LandingMarkerObservation {
            centre_px,
            orientation_rad,
            centre_from,
            nfold: nfold.map(|d: NfoldDetection| NfoldSeen {
                centre_px: [d.u_px, d.v_px],
                orientation_rad: d.orientation_rad,
                orientation_resolved: d.orientation_resolved,
                quality: d.quality,
                kernel_size_px: d.kernel_size_px,
            }),
            aruco: seen
                .iter()
                .map(|(_, m)| ArucoSeen {
                    id: m.id,
                    corners_px: m.corners_px.map(|(u, v)| [u, v]),
                    hamming_distance: m.hamming_distance,
                })
                .collect(),
            pad_size_px,
            homography: homography.map(|h| {
                let mut out = [0.0; 9];
                for (i, value) in out.iter_mut().enumerate() {
                    *value = h[(i / 3, i % 3)];
                }
                out
            }),
        }))
    }
}

/// The n-fold region of interest as the ArUco detector's pixel rectangle (`None` when it lies
/// outside the frame).
fn pixel_rect(roi: &Roi, image: &ImageView<'_>) -> Option<PixelRect> {
    let x0 = roi.min_u_px.floor().max(0.0);
    let y0 = roi.min_v_px.floor().max(0.0);
    let x1 = roi.max_u_px.ceil().min(image.width() as f64);
    let y1 = roi.max_v_px.ceil().min(image.height() as f64);
    (x1 > x0 && y1 > y0).then_some(PixelRect {
        x: x0 as usize,
        y: y0 as usize,
        width: (x1 - x0) as usize,
        height: (y1 - y0) as usize,
    })
}

/// The homography from pad metres to pixels fitted to every seen marker's four corners (DLT with
/// Hartley normalisation); `None` without a marker.
fn pad_homography(seen: &[(&ArucoPart, ArucoMarker)]) -> Option<Matrix3<f64>> {
    let pairs: Vec<([f64; 2], [f64; 2])> = seen
        .iter()
        .flat_map(|(part, marker)| {
            LandingMarkerLayout::corners_m(part)
                .into_iter()
                .zip(marker.corners_px.map(|(u, v)| [u, v]))
        })
        .collect();
    fit_homography(&pairs)
}

/// Similarity that moves points to their centroid and scales their mean distance to √2.
fn normalising_transform(points: impl Iterator<Item = [f64; 2]> + Clone) -> Matrix3<f64> {
    let count = points.clone().count() as f64;
    let (sx, sy) = points
        .clone()
        .fold((0.0, 0.0), |(sx, sy), [x, y]| (sx + x, sy + y));
    let (cx, cy) = (sx / count, sy / count);
    let mean_distance = points
        .map(|[x, y]| ((x - cx).powi(2) + (y - cy).powi(2)).sqrt())
        .sum::<f64>()
        / count;
    let s = if mean_distance > 0.0 {
        std::f64::consts::SQRT_2 / mean_distance
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * cx, 0.0, s, -s * cy, 0.0, 0.0, 1.0)
}

/// Least-squares homography mapping `from` to `to` for four or more point pairs.
pub fn fit_homography(pairs: &[([f64; 2], [f64; 2])]) -> Option<Matrix3<f64>> {
    if pairs.len() < 4 {
        return None;
    }
    let t_from = normalising_transform(pairs.iter().map(|p| p.0));
    let t_to = normalising_transform(pairs.iter().map(|p| p.1));
    let mut a = DMatrix::<f64>::zeros(2 * pairs.len(), 9);
    for (i, (from, to)) in pairs.iter().enumerate() {
        let p = t_from * Vector3::new(from[0], from[1], 1.0);
        let q = t_to * Vector3::new(to[0], to[1], 1.0);
        let (x, y, u, v) = (p.x / p.z, p.y / p.z, q.x / q.z, q.y / q.z);
        let rows = [
            [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u],
            [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v],
        ];
        for (r, row) in rows.iter().enumerate() {
            for (c, value) in row.iter().enumerate() {
                a[(2 * i + r, c)] = *value;
            }
        }
    }
    // The solution is the right singular vector of the smallest singular value: the last row
    // of Vᵀ from the SVD of AᵀA (9×9, so the SVD is cheap whatever the point count).
    let svd = (a.transpose() * &a).svd(false, true);
    let v_t = svd.v_t?;
    let (smallest, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = v_t.row(smallest);
    let normalised = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let homography = t_to.try_inverse()? * normalised * t_from;
    let scale = homography[(2, 2)];
    (scale.abs() > 1e-12).then(|| homography / scale)
}

/// Applies a homography to a point.
pub fn apply(h: &Matrix3<f64>, point: [f64; 2]) -> [f64; 2] {
    let q = h * Vector3::new(point[0], point[1], 1.0);
    [q.x / q.z, q.y / q.z]
}

#[cfg(test)]
mod tests;
