//! Tracking by detection (seed 000, §2.2.1 "Target Tracking"): each frame's detections (box +
//! colour histogram) are assigned to tracks by the Hungarian algorithm on the cost of equation 5,
//! `s = a1·s_IOU + a2·s_colour` (a1 = a2 = 0.5), with each track's box predicted by a Kalman
//! filter; false alarms are removed by track persistence.
//!
//! - Kalman filter: constant velocity on the box centre and size, state
//!   `[cx, cy, w, h, ċx, ċy, ẇ, ḣ]` (pixels, pixels/s), white-acceleration process noise, the
//!   detection's box as the measurement. The IoU of equation 3 is taken against the *predicted*
//!   box, so a target keeps overlapping its track while it moves.
//! - Persistence: a new track is tentative; it is confirmed at its `confirm_hits`-th matched
//!   detection. A tentative track is deleted at its first miss (a false alarm rarely repeats at
//!   the predicted place), a confirmed one at its `max_misses`-th miss in a row; until then the
//!   prediction bridges the gap.
//! - Gating (not in the seed, needed for a fixed cost matrix size): pairs whose IoU is below
//!   `min_iou` are never matched (otherwise a look-alike anywhere in the image could take over a
//!   track, since colour alone then costs only a2·s_colour), and pairs costlier than `max_cost`
//!   are left unassigned.

use nalgebra::{DMatrix, SMatrix, SVector};
use thiserror::Error;

use super::histogram::{ColourHistogram, HistogramError};
use super::hungarian::{assign, AssignmentError};
use super::iou::{iou, PixelBox};

/// A track's identity: unique for the tracker's life, never reused.
pub type TrackId = u64;

type State = SVector<f64, 8>;
type Covariance = SMatrix<f64, 8, 8>;

/// A tracker that cannot be built or fed as asked.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TrackingError {
    #[error("tracker setting {name} must be {why}, got {value}")]
    Config {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("the frame interval must be positive and finite, got {dt_s} s")]
    FrameInterval { dt_s: f64 },
    #[error("detection {index} has a box that is not finite or has no area")]
    Detection { index: usize },
    #[error("detection {index}: {source}")]
    Histogram {
        index: usize,
        source: HistogramError,
    },
    #[error(transparent)]
    Assignment(#[from] AssignmentError),
}

/// The tracker's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerConfig {
    /// a1 of equation 5: weight of the IoU distance (seed: 0.5).
    pub a1_distance: f64,
    /// a2 of equation 5: weight of the colour distance (seed: 0.5); a1 + a2 = 1.
    pub a2_colour: f64,
    /// Pairs costlier than this stay unassigned (default 0.7).
    pub max_cost: f64,
    /// Pairs whose IoU with the predicted box is below this are never matched (default 0.05).
    pub min_iou: f64,
    /// Matched detections that confirm a track (N, default 3).
    pub confirm_hits: u32,
    /// Misses in a row that delete a confirmed track (M, default 5: four frames are bridged).
    pub max_misses: u32,
    /// Standard deviation of the box's white acceleration, px/s² (default 200).
    pub acceleration_std_px_s2: f64,
    /// Standard deviation of a detection's box coordinates, px (default 2).
    pub measurement_std_px: f64,
    /// Standard deviation of a new track's unknown velocity, px/s (default 100).
    pub initial_velocity_std_px_s: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            a1_distance: 0.5,
            a2_colour: 0.5,
            max_cost: 0.7,
            min_iou: 0.05,
            confirm_hits: 3,
            max_misses: 5,
            acceleration_std_px_s2: 200.0,
            measurement_std_px: 2.0,
            initial_velocity_std_px_s: 100.0,
        }
    }
}

impl TrackerConfig {
    pub fn validate(&self) -> Result<(), TrackingError> {
        let err = |name, value, why| Err(TrackingError::Config { name, value, why });
        for (name, value) in [
            ("a1_distance", self.a1_distance),
            ("a2_colour", self.a2_colour),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return err(name, value, "finite and not negative");
            }
        }
        let sum = self.a1_distance + self.a2_colour;
        if (sum - 1.0).abs() > 1e-9 {
            return err("a1_distance + a2_colour", sum, "1");
        }
        if !(self.max_cost.is_finite() && self.max_cost >= 0.0) {
            return err("max_cost", self.max_cost, "finite and not negative");
        }
        if !(0.0..=1.0).contains(&self.min_iou) {
            return err("min_iou", self.min_iou, "in [0, 1]");
        }
        if self.confirm_hits == 0 {
            return err("confirm_hits", 0.0, "at least 1");
        }
        if self.max_misses == 0 {
            return err("max_misses", 0.0, "at least 1");
        }
        for (name, value) in [
            ("acceleration_std_px_s2", self.acceleration_std_px_s2),
            ("measurement_std_px", self.measurement_std_px),
            ("initial_velocity_std_px_s", self.initial_velocity_std_px_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return err(name, value, "positive and finite");
            }
        }
        Ok(())
    }
}

/// One detection: its box and the colour histogram of the box (equation 4).
#[derive(Debug, Clone, PartialEq)]
pub struct BoxDetection {
    pub bbox: PixelBox,
    pub histogram: ColourHistogram,
}

/// Whether a track has earned trust yet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackStatus {
    Tentative,
    Confirmed,
}

/// One tracked object.
#[derive(Debug, Clone)]
pub struct Track {
    id: TrackId,
    status: TrackStatus,
    state: State,
    covariance: Covariance,
    histogram: ColourHistogram,
    hits: u32,
    misses: u32,
    age_frames: u32,
    detection_index: Option<usize>,
}

impl Track {
    pub fn id(&self) -> TrackId {
        self.id
    }

    pub fn status(&self) -> TrackStatus {
        self.status
    }

    pub fn is_confirmed(&self) -> bool {
        self.status == TrackStatus::Confirmed
    }

    /// The filtered box (after this frame's update, or the prediction when it was missed).
    pub fn bbox(&self) -> PixelBox {
        box_of(&self.state)
    }

    /// The box centre, pixels.
    pub fn centre_px(&self) -> (f64, f64) {
        (self.state[0], self.state[1])
    }

    /// The box centre's velocity in the image, px/s.
    pub fn velocity_px_s(&self) -> (f64, f64) {
        (self.state[4], self.state[5])
    }

    /// Detections matched so far.
    pub fn hits(&self) -> u32 {
        self.hits
    }

    /// Frames missed in a row (0 when this frame's detection was matched).
    pub fn misses(&self) -> u32 {
        self.misses
    }

    /// Frames since the track began.
    pub fn age_frames(&self) -> u32 {
        self.age_frames
    }

    /// The index, in the latest frame's detections, of the one matched to this track.
    pub fn detection_index(&self) -> Option<usize> {
        self.detection_index
    }

    /// The appearance of the latest matched detection.
    pub fn histogram(&self) -> &ColourHistogram {
        &self.histogram
    }
}

/// How to pick the landing target among confirmed tracks when none is locked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TargetPolicy {
    /// The track with the most matched detections (the most persistent).
    MostHits,
    /// The track whose centre is nearest this pixel (e.g. the image centre, below the UAV).
    NearestTo { u_px: f64, v_px: f64 },
}

/// The multi-target tracker; see the module docs.
#[derive(Debug, Clone)]
pub struct MultiTracker {
    config: TrackerConfig,
    tracks: Vec<Track>,
    next_id: TrackId,
    target: Option<TrackId>,
}

impl MultiTracker {
    pub fn new(config: TrackerConfig) -> Result<Self, TrackingError> {
        config.validate()?;
        Ok(Self {
            config,
            tracks: Vec::new(),
            next_id: 1,
            target: None,
        })
    }

    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    /// All live tracks, tentative ones included.
    pub fn tracks(&self) -> &[Track] {
        &self.tracks
    }

    /// The confirmed tracks.
    pub fn confirmed(&self) -> impl Iterator<Item = &Track> {
        self.tracks.iter().filter(|t| t.is_confirmed())
    }

    pub fn track(&self, id: TrackId) -> Option<&Track> {
        self.tracks.iter().find(|t| t.id == id)
    }

    /// Advances by `dt_s` (time since the previous frame) and takes this frame's detections.
    /// Returns, for each detection, the track it now belongs to (a new tentative track for an
    /// unmatched detection).
    pub fn step(
        &mut self,
        dt_s: f64,
        detections: &[BoxDetection],
    ) -> Result<Vec<TrackId>, TrackingError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(TrackingError::FrameInterval { dt_s });
        }
        for (index, d) in detections.iter().enumerate() {
            let b = &d.bbox;
            let finite = [b.x_min, b.y_min, b.x_max, b.y_max]
                .iter()
                .all(|c| c.is_finite());
            if !finite || b.x_max <= b.x_min || b.y_max <= b.y_min {
                return Err(TrackingError::Detection { index });
            }
        }
        let costs = self.cost_matrix(dt_s, detections)?;
        // Only now, with every input checked, does the state change.
        for track in &mut self.tracks {
            predict(track, dt_s, self.config.acceleration_std_px_s2);
            track.age_frames += 1;
            track.detection_index = None;
        }
        let assignment = assign(&costs, self.config.max_cost)?;
        let mut owners: Vec<Option<TrackId>> = vec![None; detections.len()];
        for &(t, d) in &assignment.pairs {
            let track = &mut self.tracks[t];
            correct(track, &detections[d].bbox, self.config.measurement_std_px);
            track.histogram = detections[d].histogram.clone();
            track.hits += 1;
            track.misses = 0;
            track.detection_index = Some(d);
            if track.hits >= self.config.confirm_hits {
                track.status = TrackStatus::Confirmed;
            }
            owners[d] = Some(track.id);
        }
        for &t in &assignment.unassigned_rows {
            self.tracks[t].misses += 1;
        }
        let max_misses = self.config.max_misses;
        self.tracks.retain(|t| match t.status {
            TrackStatus::Tentative => t.misses == 0,
            TrackStatus::Confirmed => t.misses < max_misses,
        });
        for &d in &assignment.unassigned_cols {
            owners[d] = Some(self.start_track(d, &detections[d]));
        }
        if let Some(target) = self.target {
            if self.track(target).is_none() {
                self.target = None;
            }
        }
        Ok(owners.into_iter().flatten().collect())
    }

    /// Equation 6: `s(track, detection)` of equation 5 for every pair, +∞ where the IoU with the
    /// box predicted `dt_s` ahead is below `min_iou`.
    fn cost_matrix(
        &self,
        dt_s: f64,
        detections: &[BoxDetection],
    ) -> Result<DMatrix<f64>, TrackingError> {
        let mut costs = DMatrix::from_element(self.tracks.len(), detections.len(), f64::INFINITY);
        for (t, track) in self.tracks.iter().enumerate() {
            let predicted = predicted_box(&track.state, dt_s);
            for (d, detection) in detections.iter().enumerate() {
                let colour = track
                    .histogram
                    .dissimilarity(&detection.histogram)
                    .map_err(|source| TrackingError::Histogram { index: d, source })?;
                let overlap = iou(&predicted, &detection.bbox);
                if self.config.min_iou == 0.0 || overlap >= self.config.min_iou {
                    costs[(t, d)] =
                        self.config.a1_distance * (1.0 - overlap) + self.config.a2_colour * colour;
                }
            }
        }
        Ok(costs)
    }

    fn start_track(&mut self, index: usize, detection: &BoxDetection) -> TrackId {
        let id = self.next_id;
        self.next_id += 1;
        let (cx, cy) = detection.bbox.centre();
        let w = detection.bbox.x_max - detection.bbox.x_min;
        let h = detection.bbox.y_max - detection.bbox.y_min;
        let position_var = self.config.measurement_std_px.powi(2);
        let velocity_var = self.config.initial_velocity_std_px_s.powi(2);
        let mut covariance = Covariance::zeros();
        for i in 0..4 {
            covariance[(i, i)] = position_var;
            covariance[(i + 4, i + 4)] = velocity_var;
        }
        let status = if self.config.confirm_hits <= 1 {
            TrackStatus::Confirmed
        } else {
            TrackStatus::Tentative
        };
        self.tracks.push(Track {
            id,
            status,
            state: State::from_column_slice(&[cx, cy, w, h, 0.0, 0.0, 0.0, 0.0]),
            covariance,
            histogram: detection.histogram.clone(),
            hits: 1,
            misses: 0,
            age_frames: 0,
            detection_index: Some(index),
        });
        id
    }

    /// The landing target: the locked track while it lives and is confirmed; otherwise the
    /// confirmed track `policy` prefers, which becomes the locked one. `None` when no track is
    /// confirmed.
    pub fn select_target(&mut self, policy: TargetPolicy) -> Option<&Track> {
        let locked = self
            .target
            .filter(|&id| self.track(id).is_some_and(|t| t.is_confirmed()));
        let chosen = locked.or_else(|| {
            let score = |t: &Track| match policy {
                TargetPolicy::MostHits => -(t.hits as f64),
                TargetPolicy::NearestTo { u_px, v_px } => {
                    let (x, y) = t.centre_px();
                    (x - u_px).hypot(y - v_px)
                }
            };
            self.confirmed()
                .min_by(|a, b| score(a).total_cmp(&score(b)).then(a.id.cmp(&b.id)))
                .map(|t| t.id)
        });
        self.target = chosen;
        chosen.and_then(|id| self.track(id))
    }

    /// The locked target, if any (without choosing one).
    pub fn target(&self) -> Option<&Track> {
        self.target.and_then(|id| self.track(id))
    }

    /// Forgets the lock: the next [`Self::select_target`] chooses afresh.
    pub fn release_target(&mut self) {
        self.target = None;
    }
}

/// The box of a state; sizes are kept at 1 px or more.
fn box_of(s: &State) -> PixelBox {
    PixelBox::from_centre(s[0], s[1], s[2].max(1.0), s[3].max(1.0))
}

/// The box a state predicts `dt_s` ahead (constant velocity).
fn predicted_box(s: &State, dt_s: f64) -> PixelBox {
    let mut ahead = *s;
    for i in 0..4 {
        ahead[i] += s[i + 4] * dt_s;
    }
    box_of(&ahead)
}

/// Constant-velocity prediction over `dt_s` with white-acceleration noise of standard
/// deviation `accel_std` (px/s²) on each coordinate.
fn predict(track: &mut Track, dt_s: f64, accel_std: f64) {
    let mut f = Covariance::identity();
    for i in 0..4 {
        f[(i, i + 4)] = dt_s;
    }
    let q_var = accel_std * accel_std;
    let mut q = Covariance::zeros();
    for i in 0..4 {
        q[(i, i)] = q_var * dt_s.powi(4) / 4.0;
        q[(i, i + 4)] = q_var * dt_s.powi(3) / 2.0;
        q[(i + 4, i)] = q_var * dt_s.powi(3) / 2.0;
        q[(i + 4, i + 4)] = q_var * dt_s * dt_s;
    }
    track.state = f * track.state;
    track.covariance = f * track.covariance * f.transpose() + q;
}

/// Kalman update with the detected box (centre and size), Joseph form.
fn correct(track: &mut Track, bbox: &PixelBox, measurement_std_px: f64) {
    let (cx, cy) = bbox.centre();
    let z = SVector::<f64, 4>::new(cx, cy, bbox.x_max - bbox.x_min, bbox.y_max - bbox.y_min);
    let h = SMatrix::<f64, 4, 8>::identity();
    let r = SMatrix::<f64, 4, 4>::identity() * measurement_std_px.powi(2);
    let s = h * track.covariance * h.transpose() + r;
    // S = HPHᵀ + R with R positive definite is always invertible; should rounding ever say
    // otherwise, restart the box from the detection rather than corrupt the state.
    let Some(s_inv) = s.try_inverse() else {
        track.state.fixed_rows_mut::<4>(0).copy_from(&z);
        return;
    };
    let k = track.covariance * h.transpose() * s_inv;
    track.state += k * (z - h * track.state);
    let i_kh = Covariance::identity() - k * h;
    track.covariance = i_kh * track.covariance * i_kh.transpose() + k * r * k.transpose();
}

#[cfg(test)]
mod tests;
