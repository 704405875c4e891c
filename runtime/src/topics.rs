//! The bus topics the built-in tasks exchange, and their message types. One place, so a camera
//! source, the detector and the tracker agree on names and types.

use algorithms::vision::image::GrayImage;
use algorithms::vision::landing_marker::LandingMarkerObservation;
use std::sync::Arc;

/// Latest camera frame (latest-value topic): a detector always wants the newest image.
pub const CAMERA_FRAME: &str = "camera/frame";
/// Latest landing-marker observation, one per processed frame.
pub const LANDING_MARKER: &str = "vision/landing_marker";

/// One grayscale frame from the downward camera.
#[derive(Debug, Clone)]
pub struct CameraFrame {
    /// Counts frames from the source's start; gaps mean dropped frames.
    pub frame_index: u64,
    pub image: Arc<GrayImage>,
}

/// What the detector made of one frame.
#[derive(Debug, Clone)]
pub struct MarkerObservation {
    pub frame_index: u64,
    /// `None` when the pad was not seen (or the frame could not be read: see `frame_error`).
    pub observation: Option<LandingMarkerObservation>,
    /// Why the frame could not be read, if it could not; the mission goes on without it.
    pub frame_error: Option<String>,
    /// Whether the search was restricted to a region around the previous detection.
    pub used_roi: bool,
}
