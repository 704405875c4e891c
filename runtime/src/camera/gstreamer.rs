//! [`GstreamerSource`] (feature `gstreamer`): any GStreamer pipeline that ends in raw video, read
//! through an appsink: `v4l2src`, `nvarguscamerasrc`, `rtspsrc`, RTP/H.264 on UDP, a file.
//!
//! The source appends `videoconvert ! video/x-raw,format=GRAY8 ! appsink` to the pipeline it is
//! given. GStreamer's streaming thread hands each sample to a callback that copies its luma
//! plane into a small queue; [`CameraSource::next_frame`] takes from that queue without
//! blocking, so the mission loop never waits on the camera.
//!
//! - **Capture time.** The sender's own capture time where the stream carries it: a
//!   `timestamp/x-ntp` reference timestamp on the buffer, which RTP's NTP-64 header extension
//!   (RFC 6051, [`NTP_64_EXTENSION_URI`], written by `qosrt sim --serve`) and `rtpbin`'s
//!   `add-reference-timestamp-meta` (from RTCP sender reports) leave there. It is wall-clock
//!   time, so sender and receiver must share a clock (one host, or NTP/PTP between them); a
//!   stamp in the future or older than [`MAX_SENDER_STAMP_AGE_S`] is refused and counted.
//!   Otherwise a buffer's PTS is running time on the pipeline's clock; base time plus running
//!   time is when it was captured (a live source stamps at capture, `udpsrc` at arrival). The
//!   age, subtracted from the runtime's clock when the frame is taken, stamps the frame.
//! - **Losses are counted and named** ([`CameraStats`]): frames the queue dropped because the
//!   loop fell behind, frames older than `late_after_s` when taken, frames that are not a grey
//!   image of the expected size ([`CameraSourceError::Malformed`]). Every sample the sink saw
//!   takes a frame index, so a loss is a gap to the consumer.
//! - **A stalled pipeline** (no frame for `stall_after_s`, or none at all within
//!   `first_frame_timeout_s`) is [`CameraSourceError::Stalled`], once per stall: no frames reach
//!   the tasks, which the landing treats as it treats a frozen camera (no fresh fix: it holds,
//!   then climbs to reacquire).
//! - **A failing pipeline** (an element's error on the bus) is [`CameraSourceError::Pipeline`];
//!   the end of a file is [`CameraSourceError::Ended`].

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use algorithms::vision::image::GrayImage;
use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use gstreamer_video as gst_video;
use gstreamer_video::prelude::*;

use super::live::{deliver, lock, LiveQueue};
use super::{CameraSource, CameraSourceError, CameraStats, CapturedFrame};

/// The appsink's name inside the pipeline.
const SINK_NAME: &str = "qosrt_camera_sink";

/// RFC 6051's 64-bit NTP timestamp RTP header extension: the sender's capture time per frame.
pub const NTP_64_EXTENSION_URI: &str = "urn:ietf:params:rtp-hdrext:ntp-64";

/// A sender's capture stamp older than this is a clock that is not synchronised, not a frame.
pub const MAX_SENDER_STAMP_AGE_S: f64 = 10.0;

/// Seconds from the NTP epoch (1900-01-01) to the UNIX epoch (1970-01-01), RFC 5905.
const NTP_TO_UNIX_S: u64 = 2_208_988_800;

/// The caps that mark a reference timestamp as NTP time (GStreamer's convention).
pub fn ntp_timestamp_caps() -> gst::Caps {
    gst::Caps::new_empty_simple("timestamp/x-ntp")
}

/// A wall-clock instant as NTP time (since 1900), as a `timestamp/x-ntp` reference carries it.
pub fn ntp_time(at: SystemTime) -> gst::ClockTime {
    let since_unix = at.duration_since(UNIX_EPOCH).unwrap_or_default();
    gst::ClockTime::from_nseconds(since_unix.as_nanos() as u64 + NTP_TO_UNIX_S * 1_000_000_000)
}

/// NTP time (since 1900) as a wall-clock instant; `None` before the UNIX epoch.
fn system_time_of_ntp(ntp: gst::ClockTime) -> Option<SystemTime> {
    let since_unix_ns = ntp.nseconds().checked_sub(NTP_TO_UNIX_S * 1_000_000_000)?;
    Some(UNIX_EPOCH + Duration::from_nanos(since_unix_ns))
}

/// What a buffer's sender capture stamp says.
#[derive(Debug, Clone, Copy, PartialEq)]
enum SenderStamp {
    /// No `timestamp/x-ntp` reference on the buffer.
    Absent,
    /// Captured this long ago.
    Age(Duration),
    /// In the future or older than [`MAX_SENDER_STAMP_AGE_S`]: the clocks disagree.
    Refused,
}

/// The age of a sender's NTP capture stamp at `now` (wall clock).
fn sender_stamp_age(stamp: Option<gst::ClockTime>, now: SystemTime) -> SenderStamp {
    let Some(stamp) = stamp else {
        return SenderStamp::Absent;
    };
    match system_time_of_ntp(stamp).map(|captured| now.duration_since(captured)) {
        Some(Ok(age)) if age.as_secs_f64() <= MAX_SENDER_STAMP_AGE_S => SenderStamp::Age(age),
        _ => SenderStamp::Refused,
    }
}

/// How a pipeline is read.
#[derive(Debug, Clone, PartialEq)]
pub struct GstreamerConfig {
    /// The pipeline up to raw video (any format `videoconvert` takes).
    pub pipeline: String,
    /// Deliver at the stream's pace (a file) instead of as frames arrive (a live source).
    pub sync: bool,
    /// Frames held for the loop; older ones are dropped when it falls behind.
    pub queue_frames: usize,
    /// A frame older than this when taken counts as late (it is still delivered, stamped).
    pub late_after_s: f64,
    /// No frame for this long after the last is a stall.
    pub stall_after_s: f64,
    /// No first frame for this long after start is a stall (decoders wait for a key frame).
    pub first_frame_timeout_s: f64,
    /// The camera's frame size; `None` takes the first good frame's.
    pub expected_size_px: Option<(usize, usize)>,
}

impl GstreamerConfig {
    pub fn new(pipeline: impl Into<String>) -> Self {
        Self {
            pipeline: pipeline.into(),
            sync: false,
            queue_frames: 2,
            late_after_s: 0.25,
            stall_after_s: 1.0,
            first_frame_timeout_s: 10.0,
            expected_size_px: None,
        }
    }
}

/// A GStreamer pipeline as a camera.
pub struct GstreamerSource {
    name: String,
    pipeline: gst::Pipeline,
    bus: gst::Bus,
    shared: Arc<Mutex<LiveQueue<SampleError>>>,
    config: GstreamerConfig,
    expected_size_px: Option<(usize, usize)>,
    started_at: Instant,
    last_frame_at: Option<Instant>,
    stalled: bool,
    ended: bool,
    stats: CameraStats,
}

impl std::fmt::Debug for GstreamerSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GstreamerSource")
            .field("name", &self.name)
            .field("stats", &self.stats)
            .finish()
    }
}

impl GstreamerSource {
    /// Builds the pipeline and starts it playing; a pipeline that does not parse, names an
    /// element this system lacks, or cannot start is a [`CameraSourceError::Pipeline`].
    pub fn open(config: GstreamerConfig) -> Result<Self, CameraSourceError> {
        let name = format!("gst:{}", config.pipeline);
        let failed = |reason: String| CameraSourceError::Pipeline {
            source_name: name.clone(),
            reason,
        };
        for (setting, value) in [
            ("late_after_s", config.late_after_s),
            ("stall_after_s", config.stall_after_s),
            ("first_frame_timeout_s", config.first_frame_timeout_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(CameraSourceError::Config {
                    name: setting,
                    reason: format!("must be a positive number of seconds, got {value}"),
                });
            }
        }
        if config.queue_frames == 0 {
            return Err(CameraSourceError::Config {
                name: "queue_frames",
                reason: "must hold at least one frame".into(),
            });
        }
        gst::init().map_err(|e| failed(format!("GStreamer does not start: {e}")))?;
        let description = format!(
            "{} ! videoconvert ! video/x-raw,format=GRAY8 ! appsink name={SINK_NAME} sync={} \
             enable-last-sample=false",
            config.pipeline, config.sync
        );
        let pipeline = gst::parse::launch(&description)
            .map_err(|e| failed(e.to_string()))?
            .downcast::<gst::Pipeline>()
            .map_err(|_| failed("the description is not a pipeline".into()))?;
        let sink = pipeline
            .by_name(SINK_NAME)
            .and_then(|e| e.downcast::<gst_app::AppSink>().ok())
            .ok_or_else(|| failed("the appsink is missing from the pipeline".into()))?;
        let bus = pipeline
            .bus()
            .ok_or_else(|| failed("the pipeline has no bus".into()))?;
        let shared = LiveQueue::shared(config.queue_frames);
        let callback_shared = shared.clone();
        sink.set_callbacks(
            gst_app::AppSinkCallbacks::builder()
                .new_sample(move |sink| {
                    let sample = sink.pull_sample().map_err(|_| gst::FlowError::Eos)?;
                    let sender_stamp = sender_stamp_age(ntp_reference(&sample), SystemTime::now());
                    let age = match sender_stamp {
                        SenderStamp::Age(age) => age,
                        SenderStamp::Absent | SenderStamp::Refused => sample_age(sink, &sample),
                    };
                    let captured_at = Instant::now() - age;
                    let image = gray_image(&sample);
                    lock(&callback_shared).push(
                        image,
                        captured_at,
                        matches!(sender_stamp, SenderStamp::Age(_)),
                        sender_stamp == SenderStamp::Refused,
                    );
                    Ok(gst::FlowSuccess::Ok)
                })
                .build(),
        );
        if let Err(error) = pipeline.set_state(gst::State::Playing) {
            let reason = bus_error(&bus).unwrap_or_else(|| error.to_string());
            let _ = pipeline.set_state(gst::State::Null);
            return Err(failed(reason));
        }
        Ok(Self {
            name,
            pipeline,
            bus,
            shared,
            expected_size_px: config.expected_size_px,
            config,
            started_at: Instant::now(),
            last_frame_at: None,
            stalled: false,
            ended: false,
            stats: CameraStats::default(),
        })
    }

    /// An element of the pipeline by its `name=`: an `appsrc` to feed, a property to watch.
    pub fn element(&self, name: &str) -> Option<gst::Element> {
        self.pipeline.by_name(name)
    }

    /// Errors and the end of stream posted on the bus since the last poll.
    fn poll_bus(&mut self) -> Result<(), CameraSourceError> {
        while let Some(message) = self.bus.pop() {
            match message.view() {
                gst::MessageView::Error(error) => {
                    self.ended = true;
                    return Err(CameraSourceError::Pipeline {
                        source_name: self.name.clone(),
                        reason: describe_error(error),
                    });
                }
                gst::MessageView::Eos(_) => self.ended = true,
                gst::MessageView::Warning(warning) => {
                    tracing::warn!(source = %self.name, warning = %warning.error(), "camera pipeline")
                }
                _ => {}
            }
        }
        Ok(())
    }
}

impl CameraSource for GstreamerSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn wake_on_frame(&mut self, thread: std::thread::Thread) {
        lock(&self.shared).wake(thread);
    }

    fn next_frame(&mut self, now_s: f64) -> Result<Option<CapturedFrame>, CameraSourceError> {
        self.poll_bus()?;
        let arrived = lock(&self.shared).pop();
        let Some(arrived) = arrived else {
            if self.ended {
                // A file's end after its last frame; a failed pipeline said why once already.
                return Err(CameraSourceError::Ended {
                    source_name: self.name.clone(),
                });
            }
            let (since, bound_s) = match self.last_frame_at {
                Some(at) => (at, self.config.stall_after_s),
                None => (self.started_at, self.config.first_frame_timeout_s),
            };
            let silent_s = since.elapsed().as_secs_f64();
            if silent_s > bound_s && !self.stalled {
                self.stalled = true;
                self.stats.stalls += 1;
                return Err(CameraSourceError::Stalled {
                    source_name: self.name.clone(),
                    silent_s,
                });
            }
            return Ok(None);
        };
        self.last_frame_at = Some(Instant::now());
        self.stalled = false;
        let frame = deliver(
            &self.name,
            arrived,
            &mut self.expected_size_px,
            &mut self.stats,
            now_s,
        )?;
        if now_s - frame.capture_time_s > self.config.late_after_s {
            self.stats.late += 1;
        }
        Ok(Some(frame))
    }

    fn stats(&self) -> CameraStats {
        lock(&self.shared).counted(self.stats)
    }
}

impl Drop for GstreamerSource {
    fn drop(&mut self) {
        let _ = self.pipeline.set_state(gst::State::Null);
    }
}

/// The sender's capture time on the sample's buffer: a `timestamp/x-ntp` reference timestamp.
fn ntp_reference(sample: &gst::Sample) -> Option<gst::ClockTime> {
    let ntp = ntp_timestamp_caps();
    let buffer = sample.buffer()?;
    buffer
        .iter_meta::<gst::ReferenceTimestampMeta>()
        .find(|meta| meta.reference().can_intersect(&ntp))
        .map(|meta| meta.timestamp())
}

/// How long ago the sample was captured, on the pipeline's clock: now − (base time + running
/// time of its PTS). Zero when the sample has no timestamp or the sink no clock yet.
fn sample_age(sink: &gst_app::AppSink, sample: &gst::Sample) -> Duration {
    let running = sample
        .buffer()
        .and_then(|buffer| buffer.pts())
        .and_then(|pts| {
            sample
                .segment()
                .and_then(|segment| segment.downcast_ref::<gst::ClockTime>())
                .and_then(|segment| segment.to_running_time(pts))
        });
    let (Some(running), Some(base), Some(clock)) = (running, sink.base_time(), sink.clock()) else {
        return Duration::ZERO;
    };
    let captured = base + running;
    let now = clock.time();
    if now > captured {
        Duration::from_nanos((now - captured).nseconds())
    } else {
        Duration::ZERO
    }
}

/// Why a sample the sink delivered is not a grey frame the camera can use.
#[derive(Debug, thiserror::Error)]
enum SampleError {
    #[error("the sample has no caps")]
    NoCaps,
    #[error("the caps do not describe raw video")]
    Caps(#[source] gst::glib::BoolError),
    #[error("format {0:?}, expected GRAY8")]
    Format(gst_video::VideoFormat),
    #[error("the sample has no buffer")]
    NoBuffer,
    #[error("the buffer does not hold a {width}×{height} frame")]
    Map {
        width: u32,
        height: u32,
        #[source]
        source: gst::glib::BoolError,
    },
    #[error("the plane's stride {0} is negative")]
    Stride(i32),
    #[error("{bytes} bytes with stride {stride} cannot hold {width}×{height} pixels")]
    Short {
        bytes: usize,
        stride: usize,
        width: usize,
        height: usize,
    },
    #[error(transparent)]
    Image(#[from] algorithms::vision::image::FrameError),
}

/// The sample's grey plane, row by row (GStreamer pads rows to 4 bytes).
fn gray_image(sample: &gst::Sample) -> Result<GrayImage, SampleError> {
    let caps = sample.caps().ok_or(SampleError::NoCaps)?;
    let info = gst_video::VideoInfo::from_caps(caps).map_err(SampleError::Caps)?;
    if info.format() != gst_video::VideoFormat::Gray8 {
        return Err(SampleError::Format(info.format()));
    }
    let buffer = sample.buffer().ok_or(SampleError::NoBuffer)?;
    let unmapped = |source| SampleError::Map {
        width: info.width(),
        height: info.height(),
        source,
    };
    let frame =
        gst_video::VideoFrameRef::from_buffer_ref_readable(buffer, &info).map_err(unmapped)?;
    let (width, height) = (info.width() as usize, info.height() as usize);
    let stride_bytes = frame.plane_stride()[0];
    let stride = usize::try_from(stride_bytes).map_err(|_| SampleError::Stride(stride_bytes))?;
    let plane = frame.plane_data(0).map_err(unmapped)?;
    if width == 0 || height == 0 || stride < width || plane.len() < stride * (height - 1) + width {
        return Err(SampleError::Short {
            bytes: plane.len(),
            stride,
            width,
            height,
        });
    }
    let mut pixels = Vec::with_capacity(width * height);
    for row in plane.chunks(stride).take(height) {
        pixels.extend_from_slice(&row[..width]);
    }
    Ok(GrayImage::from_vec(width, height, pixels)?)
}

/// The first error waiting on the bus, described.
fn bus_error(bus: &gst::Bus) -> Option<String> {
    while let Some(message) = bus.pop() {
        if let gst::MessageView::Error(error) = message.view() {
            return Some(describe_error(error));
        }
    }
    None
}

fn describe_error(error: &gst::message::Error) -> String {
    let element = error
        .src()
        .map(|src| src.name().to_string())
        .unwrap_or_else(|| "pipeline".into());
    match error.debug() {
        Some(debug) => format!("{element}: {} ({debug})", error.error()),
        None => format!("{element}: {}", error.error()),
    }
}

// Tested against real pipelines in `runtime/tests/gstreamer_camera.rs`.

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ntp_time_counts_from_1900() {
        // 2000-01-01T00:00:00Z is 946_684_800 s after the UNIX epoch; NTP era 0 puts it at
        // 3_155_673_600 s (RFC 5905's table of epochs).
        let y2k = UNIX_EPOCH + Duration::from_secs(946_684_800);
        assert_eq!(ntp_time(y2k).seconds(), 3_155_673_600);
        let instant = y2k + Duration::from_nanos(123_456_789);
        assert_eq!(system_time_of_ntp(ntp_time(instant)), Some(instant));
        // A zero stamp (a sender with the extension but no capture time) is before 1970.
        assert_eq!(system_time_of_ntp(gst::ClockTime::ZERO), None);
    }

    #[test]
    fn sender_stamps_from_the_future_or_the_distant_past_are_refused() {
        let now = UNIX_EPOCH + Duration::from_secs(1_800_000_000);
        let stamp = |at: SystemTime| Some(ntp_time(at));
        assert_eq!(sender_stamp_age(None, now), SenderStamp::Absent);
        assert_eq!(
            sender_stamp_age(stamp(now - Duration::from_millis(35)), now),
            SenderStamp::Age(Duration::from_millis(35))
        );
        assert_eq!(
            sender_stamp_age(stamp(now + Duration::from_millis(1)), now),
            SenderStamp::Refused
        );
        let too_old = Duration::from_secs_f64(MAX_SENDER_STAMP_AGE_S + 1.0);
        assert_eq!(
            sender_stamp_age(stamp(now - too_old), now),
            SenderStamp::Refused
        );
        assert_eq!(
            sender_stamp_age(Some(gst::ClockTime::ZERO), now),
            SenderStamp::Refused
        );
    }
}
