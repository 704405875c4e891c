//! Where camera frames come from: the [`CameraSource`] trait and its sources.
//!
//! - [`folder::ImageFolderSource`] plays a folder of recorded frames (PNG, JPEG, PGM) as a camera;
//! - [`MemorySource`] takes frames rendered in the same process (the simulator's harness);
//! - `gstreamer::GstreamerSource` (feature `gstreamer`) reads any GStreamer pipeline that ends in
//!   raw video: a V4L2 or CSI camera, an RTSP camera, RTP/H.264 on UDP (PX4's and ArduPilot's
//!   Gazebo cameras, `qosrt sim --serve`), a video file.
//!
//! [`CameraSpec`] parses the `--camera` strings that choose one, and [`open`] opens it.
//!
//! A source is polled: [`CameraSource::next_frame`] returns `Ok(Some(frame))` when a new frame is
//! ready, `Ok(None)` when none is yet, and a named [`CameraSourceError`] when a frame could not be
//! had. A bad frame is not the end of the mission: the caller reports it and polls again, and the
//! next frame plays; only [`CameraSourceError::Ended`] says no more will come.
//!
//! Frame indices count the frames the source tried to deliver, bad ones included, so a consumer
//! sees a bad or dropped frame as a gap (see [`CameraFrame::frame_index`]).

pub mod folder;
#[cfg(feature = "gstreamer")]
pub mod gstreamer;
#[cfg(any(feature = "gstreamer", feature = "ros2"))]
mod live;
#[cfg(feature = "ros2")]
pub mod ros2;
mod spec;

pub use folder::{load_gray, ImageFolderConfig, ImageFolderSource};
pub use spec::{open, CameraSpec, DEFAULT_FOLDER_FPS, RTP_CAPTURE_TIME_EXTENSION_ID};

use std::path::PathBuf;
use std::sync::Arc;

use thiserror::Error;

use crate::topics::CameraFrame;

/// The underlying error of a frame that could not be decoded: the image crate's, the frame
/// layout's, or a GStreamer sample's, kept whole so a report names what failed.
pub type BoxedError = Box<dyn std::error::Error + Send + Sync>;

/// Why a source gave no frame this time.
#[derive(Debug, Error)]
pub enum CameraSourceError {
    #[error("{path}: cannot read: {source}")]
    Unreadable {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a readable PNG, JPEG or PGM image: {source}")]
    Format {
        path: PathBuf,
        #[source]
        source: BoxedError,
    },
    #[error("{path}: the frame is {found_width}×{found_height} pixels, the camera's are {expected_width}×{expected_height}")]
    WrongSize {
        path: PathBuf,
        expected_width: usize,
        expected_height: usize,
        found_width: usize,
        found_height: usize,
    },
    #[error("{folder}: no PNG, JPEG or PGM files to play")]
    EmptyFolder { folder: PathBuf },
    #[error("{folder}: cannot list the folder: {source}")]
    Folder {
        folder: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("camera source `{source_name}` has no more frames")]
    Ended { source_name: String },
    #[error("camera source `{source_name}`: device error: {reason}")]
    Device { source_name: String, reason: String },
    #[error("camera source setting `{name}` is invalid: {reason}")]
    Config { name: &'static str, reason: String },
    #[error("--camera {spec}: {reason}")]
    Spec { spec: String, reason: String },
    #[error("--camera {spec}: this qosrt was built without GStreamer; rebuild it with `cargo build --release --features gstreamer`")]
    NoGstreamer { spec: String },
    #[error("camera source `{source_name}`: GStreamer pipeline: {reason}")]
    Pipeline { source_name: String, reason: String },
    #[error("camera source `{source_name}`: no frame for {silent_s:.1} s (stalled)")]
    Stalled { source_name: String, silent_s: f64 },
    #[error("camera source `{source_name}`: frame {frame_index} is malformed: {problem}")]
    Malformed {
        source_name: String,
        frame_index: u64,
        #[source]
        problem: BoxedError,
    },
}

/// What a source counted since it opened: what a consumer never sees as a frame is named here.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct CameraStats {
    pub delivered: u64,
    /// Frames the source threw away because the consumer polled too slowly to take them all.
    pub dropped: u64,
    /// Frames delivered older than the source's lateness bound.
    pub late: u64,
    /// Frames that arrived but could not be read as a grey image of the camera's size.
    pub malformed: u64,
    /// Times the source fell silent for longer than its stall bound.
    pub stalls: u64,
    /// Frames the sender published that never arrived whole (gaps in a DDS writer's sequence
    /// numbers): lost on the way, before the source could queue them.
    pub lost_in_transport: u64,
    /// Frames delivered stamped with the sender's own capture time (RTP's NTP-64 header
    /// extension, RTCP); counted as delivered, so a frame still queued at the end is in neither.
    pub sender_stamped: u64,
    /// Sender capture stamps refused (in the future or too old: the clocks are not in sync);
    /// those frames are stamped at arrival.
    pub sender_stamps_refused: u64,
}

/// A frame with the time its exposure was taken, on the runtime's clock: the tracker's delay
/// compensation works from it, so a source stamps as close to the sensor as it can.
#[derive(Debug, Clone)]
pub struct CapturedFrame {
    pub frame: CameraFrame,
    pub capture_time_s: f64,
    /// When the frame reached the runtime (the source's own queue, before the runner took it),
    /// on the same clock: from it the runtime's own delay is measured.
    pub arrived_s: f64,
}

/// Anything that delivers camera frames: the simulator, an image folder, a GStreamer pipeline.
pub trait CameraSource: Send {
    /// A short name for logs and errors.
    fn name(&self) -> &str;

    /// The next frame if one is ready at `now_s` (seconds on the runtime's clock), `Ok(None)` if
    /// not yet.
    fn next_frame(&mut self, now_s: f64) -> Result<Option<CapturedFrame>, CameraSourceError>;

    /// Unpark `thread` whenever a frame arrives, so a loop that sleeps between polls takes it
    /// at once. Sources whose frames are due at known times (a folder) need not.
    fn wake_on_frame(&mut self, _thread: std::thread::Thread) {}

    /// Counters of what the source delivered and lost; sources that cannot lose frames between
    /// polls report none.
    fn stats(&self) -> CameraStats {
        CameraStats::default()
    }
}

/// Frames handed in by their producer in the same process (the simulator's harness renders
/// them): a queue, drained in order by [`CameraSource::next_frame`].
#[derive(Debug, Clone, Default)]
pub struct MemorySource {
    queue: Arc<std::sync::Mutex<std::collections::VecDeque<CapturedFrame>>>,
}

impl MemorySource {
    pub fn new() -> Self {
        Self::default()
    }

    /// Hands in a frame; the source delivers it once the clock reaches its capture time.
    pub fn push(&self, frame: CapturedFrame) {
        self.lock().push_back(frame);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, std::collections::VecDeque<CapturedFrame>> {
        self.queue
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

impl CameraSource for MemorySource {
    fn name(&self) -> &str {
        "memory"
    }

    fn next_frame(&mut self, now_s: f64) -> Result<Option<CapturedFrame>, CameraSourceError> {
        let mut queue = self.lock();
        match queue.front() {
            Some(frame) if frame.capture_time_s <= now_s => Ok(queue.pop_front()),
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use algorithms::vision::image::GrayImage;

    #[test]
    fn a_memory_source_delivers_in_order_once_captured() {
        let source = MemorySource::new();
        let mut reader = source.clone();
        for (index, capture_time_s) in [(0u64, 1.0), (1, 1.1)] {
            source.push(CapturedFrame {
                frame: CameraFrame {
                    vehicle_at_capture: None,
                    frame_index: index,
                    image: Arc::new(GrayImage::filled(4, 4, 0).unwrap()),
                },
                capture_time_s,
                arrived_s: capture_time_s + 0.05,
            });
        }
        assert!(reader.next_frame(0.99).unwrap().is_none());
        let first = reader.next_frame(1.2).unwrap().unwrap();
        let second = reader.next_frame(1.2).unwrap().unwrap();
        assert_eq!((first.frame.frame_index, second.frame.frame_index), (0, 1));
        assert!(reader.next_frame(5.0).unwrap().is_none());
    }
}
