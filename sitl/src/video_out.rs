//! The simulated camera as a network camera (feature `gstreamer`): frames encoded to H.264 and
//! sent as RTP over UDP, as PX4's and ArduPilot's Gazebo camera plugins send to port 5600.
//!
//! `appsrc` (GRAY8, stamped at capture) → `videoconvert` → `x264enc` (zero-latency tuning, no
//! B-frames, a key frame every second so a receiver that joins late decodes within one) →
//! `rtph264pay` (SPS/PPS with every key frame; each frame's first packet carries its capture
//! time in RFC 6051's NTP-64 header extension, from the wall clock) → `udpsink`. A probe on
//! the sink measures how long a frame takes from capture to leaving on the wire.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime};

use algorithms::vision::image::GrayImage;
use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use gstreamer_rtp as gst_rtp;
use gstreamer_rtp::prelude::*;
use runtime::camera::gstreamer::{ntp_time, ntp_timestamp_caps, NTP_64_EXTENSION_URI};
use runtime::camera::RTP_CAPTURE_TIME_EXTENSION_ID;

/// Why the stream could not be built or fed.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    #[error("video stream: GStreamer: {0}")]
    Gstreamer(#[source] Box<dyn std::error::Error + Send + Sync>),
    #[error(
        "video stream: frame {width}×{height}, the stream's is {stream_width}×{stream_height}"
    )]
    WrongSize {
        width: usize,
        height: usize,
        stream_width: usize,
        stream_height: usize,
    },
    #[error("video stream: the pipeline failed: {0}")]
    Pipeline(#[source] gst::glib::Error),
    #[error("video stream: the pipeline failed: {0:?}")]
    Flow(#[source] gst::FlowError),
}

/// Where and how the stream goes.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoStreamConfig {
    pub host: String,
    pub port: u16,
    pub width_px: usize,
    pub height_px: usize,
    pub rate_fps: f64,
    /// Enough that the marker's corners survive the encoding within a pixel.
    pub bitrate_kbit_s: u32,
}

impl VideoStreamConfig {
    pub fn new(port: u16, width_px: usize, height_px: usize, rate_fps: f64) -> Self {
        Self {
            host: "127.0.0.1".into(),
            port,
            width_px,
            height_px,
            rate_fps,
            bitrate_kbit_s: 4_000,
        }
    }
}

/// Capture-to-wire latencies of the RTP packets the sink saw, in seconds.
#[derive(Debug, Default)]
struct Latencies {
    samples_s: Vec<f64>,
}

/// An RTP/H.264 stream on UDP.
pub struct RtpH264Sender {
    pipeline: gst::Pipeline,
    source: gst_app::AppSrc,
    bus: gst::Bus,
    config: VideoStreamConfig,
    latencies: Arc<Mutex<Latencies>>,
    sent: u64,
}

impl RtpH264Sender {
    pub fn open(config: VideoStreamConfig) -> Result<Self, VideoError> {
        gst::init().map_err(gst_error)?;
        let fps = config.rate_fps.round().max(1.0) as u32;
        let description = format!(
            "appsrc name=frames is-live=true format=time \
             caps=video/x-raw,format=GRAY8,width={w},height={h},framerate={fps}/1 \
             ! videoconvert ! video/x-raw,format=I420 \
             ! x264enc tune=zerolatency speed-preset=ultrafast bitrate={kbit} key-int-max={fps} \
             ! rtph264pay name=payloader config-interval=-1 pt=96 \
             ! udpsink name=wire host={host} port={port} sync=false async=false",
            w = config.width_px,
            h = config.height_px,
            kbit = config.bitrate_kbit_s,
            host = config.host,
            port = config.port,
        );
        let pipeline = gst::parse::launch(&description)
            .map_err(gst_error)?
            .downcast::<gst::Pipeline>()
            .map_err(|_| VideoError::Gstreamer("not a pipeline".into()))?;
        let source = pipeline
            .by_name("frames")
            .and_then(|e| e.downcast::<gst_app::AppSrc>().ok())
            .ok_or_else(|| VideoError::Gstreamer("the appsrc is missing".into()))?;
        add_capture_time_extension(&pipeline)?;
        let wire = pipeline
            .by_name("wire")
            .ok_or_else(|| VideoError::Gstreamer("the udpsink is missing".into()))?;
        let latencies = Arc::new(Mutex::new(Latencies::default()));
        let probe_latencies = latencies.clone();
        let sink_pad = wire
            .static_pad("sink")
            .ok_or_else(|| VideoError::Gstreamer("the udpsink has no sink pad".into()))?;
        // The pipeline's clock and base time (a weak reference: the pipeline owns the probe).
        let probe_pipeline = pipeline.downgrade();
        // The payloader pushes a frame's RTP packets as a buffer list, or one by one.
        let probe_types = gst::PadProbeType::BUFFER | gst::PadProbeType::BUFFER_LIST;
        sink_pad.add_probe(probe_types, move |pad, info| {
            let pts = match &info.data {
                Some(gst::PadProbeData::Buffer(buffer)) => buffer.pts(),
                Some(gst::PadProbeData::BufferList(list)) => list.get(0).and_then(|b| b.pts()),
                _ => None,
            };
            // The encoder shifts timestamps (x264enc by 1000 h): running time is in the segment.
            let running = pts.and_then(|pts| {
                let segment = pad.sticky_event::<gst::event::Segment>(0)?;
                segment
                    .segment()
                    .downcast_ref::<gst::ClockTime>()?
                    .to_running_time(pts)
            });
            let pipeline = probe_pipeline.upgrade();
            if let (Some(running), Some(pipeline)) = (running, pipeline) {
                if let (Some(base), Some(clock)) = (pipeline.base_time(), pipeline.clock()) {
                    // Every RTP packet of a frame carries the frame's PTS, the capture's.
                    let captured = base + running;
                    let now = clock.time();
                    if now > captured {
                        let mut latencies = probe_latencies
                            .lock()
                            .unwrap_or_else(PoisonError::into_inner);
                        let seconds = (now - captured).nseconds() as f64 * 1e-9;
                        if latencies.samples_s.len() < 100_000 {
                            latencies.samples_s.push(seconds);
                        }
                    }
                }
            }
            gst::PadProbeReturn::Ok
        });
        let bus = pipeline
            .bus()
            .ok_or_else(|| VideoError::Gstreamer("no bus".into()))?;
        pipeline.set_state(gst::State::Playing).map_err(gst_error)?;
        Ok(Self {
            pipeline,
            source,
            bus,
            config,
            latencies,
            sent: 0,
        })
    }

    /// Sends a frame captured `age` ago.
    pub fn send(&mut self, image: &GrayImage, age: Duration) -> Result<(), VideoError> {
        while let Some(message) = self.bus.pop() {
            if let gst::MessageView::Error(error) = message.view() {
                return Err(VideoError::Pipeline(error.error()));
            }
        }
        let (width, height) = (image.width(), image.height());
        if (width, height) != (self.config.width_px, self.config.height_px) {
            return Err(VideoError::WrongSize {
                width,
                height,
                stream_width: self.config.width_px,
                stream_height: self.config.height_px,
            });
        }
        // GStreamer's GRAY8 rows are padded to 4 bytes.
        let stride = width.div_ceil(4) * 4;
        let mut bytes = vec![0u8; stride * height];
        for (row, out) in bytes.chunks_mut(stride).enumerate() {
            for (column, pixel) in out[..width].iter_mut().enumerate() {
                *pixel = image.get(column, row);
            }
        }
        let mut buffer = gst::Buffer::from_mut_slice(bytes);
        let captured_wall = SystemTime::now() - age;
        // Stamped at capture: running time now, less the frame's age.
        let running = match (self.pipeline.clock(), self.pipeline.base_time()) {
            (Some(clock), Some(base)) => {
                let now = clock.time();
                let age = gst::ClockTime::from_nseconds(age.as_nanos() as u64);
                (now > base + age).then(|| now - base - age)
            }
            _ => None,
        };
        {
            let buffer = buffer.get_mut().expect("a new buffer is writable");
            buffer.set_pts(running);
            // The capture on the wall clock, for the payloader's NTP-64 header extension.
            gst::ReferenceTimestampMeta::add(
                buffer,
                &ntp_timestamp_caps(),
                ntp_time(captured_wall),
                gst::ClockTime::NONE,
            );
            buffer.set_duration(gst::ClockTime::from_nseconds(
                (1e9 / self.config.rate_fps.max(1.0)) as u64,
            ));
        }
        self.source.push_buffer(buffer).map_err(VideoError::Flow)?;
        self.sent += 1;
        Ok(())
    }

    pub fn frames_sent(&self) -> u64 {
        self.sent
    }

    /// Capture-to-wire latency of the frames sent so far (RTP packets), median and 99th
    /// percentile, in milliseconds.
    pub fn latency_ms(&self) -> Option<(f64, f64)> {
        let latencies = self
            .latencies
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let mut samples = latencies.samples_s.clone();
        if samples.is_empty() {
            return None;
        }
        samples.sort_by(f64::total_cmp);
        let at = |p: f64| samples[((samples.len() - 1) as f64 * p).round() as usize] * 1e3;
        Some((at(0.5), at(0.99)))
    }
}

impl Drop for RtpH264Sender {
    fn drop(&mut self) {
        let _ = self.source.end_of_stream();
        let _ = self.pipeline.set_state(gst::State::Null);
    }
}

/// Adds RFC 6051's NTP-64 header extension to the payloader, at the id `rtp-h264:` receivers
/// expect. Every packet carries it: a GStreamer 1.22 depayloader reads the extension of a
/// frame's last packet only (1.24 aggregates them).
fn add_capture_time_extension(pipeline: &gst::Pipeline) -> Result<(), VideoError> {
    let payloader = pipeline
        .by_name("payloader")
        .ok_or_else(|| VideoError::Gstreamer("the payloader is missing".into()))?;
    let extension = gst_rtp::RTPHeaderExtension::create_from_uri(NTP_64_EXTENSION_URI)
        .ok_or_else(|| VideoError::Gstreamer("no RTP NTP-64 header extension".into()))?;
    extension.set_id(u32::from(RTP_CAPTURE_TIME_EXTENSION_ID));
    extension.set_property("every-packet", true);
    payloader.emit_by_name::<()>("add-extension", &[&extension]);
    Ok(())
}

/// A GStreamer call's failure, keeping its error.
fn gst_error(error: impl std::error::Error + Send + Sync + 'static) -> VideoError {
    VideoError::Gstreamer(Box::new(error))
}
