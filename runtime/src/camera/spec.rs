//! `--camera SOURCE`: the strings that name a camera, and opening one.
//!
//! | form | source |
//! | --- | --- |
//! | `folder:PATH[@FPS]`, or a folder's path | an image folder at FPS (default 10), looping |
//! | `gst:PIPELINE` | any GStreamer pipeline that ends in raw video |
//! | `v4l2:DEVICE` | a USB or CSI camera through V4L2 (`v4l2src`) |
//! | `rtp-h264:PORT` | RTP/H.264 on UDP, as Gazebo's camera plugin and `qosrt sim --serve` send |
//! | `rtsp://…` | an IP camera |
//! | `file:PATH` | a video file, played at its own rate |
//! | `ros2:/TOPIC` | a ROS 2 image topic (`sensor_msgs/Image`; `…/compressed`: `CompressedImage`) |
//!
//! The GStreamer forms are parsed in every build, so a wrong string is named the same way with
//! or without the `gstreamer` feature; only opening one needs it.

use std::path::{Path, PathBuf};

use super::{CameraSource, CameraSourceError, ImageFolderConfig, ImageFolderSource};

/// An image folder plays at this rate unless the spec gives one.
pub const DEFAULT_FOLDER_FPS: f64 = 10.0;

/// A parsed `--camera` string.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraSpec {
    Folder {
        path: PathBuf,
        rate_fps: f64,
    },
    /// A ROS 2 image topic.
    Ros2 {
        topic: String,
    },
    Gstreamer {
        /// The pipeline up to raw video; the source appends the conversion to grey and its sink.
        pipeline: String,
        /// Deliver at the stream's own pace (a file) rather than as fast as frames arrive (a
        /// live source).
        sync: bool,
    },
}

impl CameraSpec {
    pub fn parse(spec: &str) -> Result<Self, CameraSourceError> {
        let invalid = |reason: String| CameraSourceError::Spec {
            spec: spec.to_string(),
            reason,
        };
        let not_empty = |what: &str, value: &str| {
            if value.trim().is_empty() {
                Err(invalid(format!("expected {what} after the colon")))
            } else {
                Ok(())
            }
        };
        let live = |pipeline: String| CameraSpec::Gstreamer {
            pipeline,
            sync: false,
        };
        if let Some(topic) = spec.strip_prefix("ros2:") {
            let topic = topic.trim();
            let segments_valid = topic.strip_prefix('/').is_some_and(|rest| {
                rest.split('/').all(|segment| {
                    segment
                        .chars()
                        .next()
                        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                        && segment
                            .chars()
                            .all(|c| c.is_ascii_alphanumeric() || c == '_')
                })
            });
            if !segments_valid {
                return Err(invalid(format!(
                    "expected a ROS 2 topic such as ros2:/camera/image_raw, found {topic:?}"
                )));
            }
            return Ok(CameraSpec::Ros2 {
                topic: topic.to_string(),
            });
        }
        if let Some(pipeline) = spec.strip_prefix("gst:") {
            not_empty("a GStreamer pipeline", pipeline)?;
            return Ok(live(pipeline.trim().to_string()));
        }
        if let Some(device) = spec.strip_prefix("v4l2:") {
            not_empty("a V4L2 device such as /dev/video0", device)?;
            return Ok(live(format!(
                "v4l2src device={} ! videoconvert",
                quoted(device)
            )));
        }
        if let Some(port) = spec.strip_prefix("rtp-h264:") {
            let port: u16 = port
                .trim()
                .parse()
                .ok()
                .filter(|&p| p != 0)
                .ok_or_else(|| invalid(format!("expected a UDP port (1-65535), found {port:?}")))?;
            return Ok(live(rtp_h264_pipeline(port)));
        }
        if spec.starts_with("rtsp://") || spec.starts_with("rtsps://") {
            return Ok(live(format!(
                "rtspsrc location={} latency=0 ! decodebin ! videoconvert",
                quoted(spec)
            )));
        }
        if let Some(file) = spec.strip_prefix("file:") {
            not_empty("a video file", file)?;
            return Ok(CameraSpec::Gstreamer {
                pipeline: format!(
                    "filesrc location={} ! decodebin ! videoconvert",
                    quoted(file)
                ),
                sync: true,
            });
        }
        let (folder, rate_fps) = match spec.strip_prefix("folder:") {
            Some(rest) => match rest.rsplit_once('@') {
                Some((folder, fps)) => {
                    let rate_fps = fps
                        .parse::<f64>()
                        .ok()
                        .filter(|r| r.is_finite() && *r > 0.0)
                        .ok_or_else(|| {
                            invalid(format!(
                                "the rate {fps:?} is not a positive number of frames per second"
                            ))
                        })?;
                    (folder, rate_fps)
                }
                None => (rest, DEFAULT_FOLDER_FPS),
            },
            None if Path::new(spec).is_dir() => (spec, DEFAULT_FOLDER_FPS),
            None => {
                return Err(invalid(
                    "expected folder:PATH[@FPS], gst:PIPELINE, v4l2:DEVICE, rtp-h264:PORT, \
                     rtsp://URL, file:PATH or ros2:/TOPIC"
                        .into(),
                ))
            }
        };
        if !Path::new(folder).is_dir() {
            return Err(invalid(format!("{folder} is not a folder")));
        }
        Ok(CameraSpec::Folder {
            path: PathBuf::from(folder),
            rate_fps,
        })
    }
}

/// Receives RTP/H.264 on a UDP port: the caps PX4's Gazebo camera documentation gives for
/// port 5600. The jitter buffer stamps each frame from its RTP timestamp (the sender's capture
/// clock, skew-corrected) rather than its arrival: frames that arrive bunched together keep
/// their true spacing, which the tracker's velocity estimate depends on. Extension id 1 is
/// RFC 6051's NTP-64 capture time, which `qosrt sim --serve` writes; the depayloader leaves it
/// on the frame and the camera source stamps the frame with it (a sender without it is
/// stamped as before).
pub fn rtp_h264_pipeline(port: u16) -> String {
    format!(
        "udpsrc port={port} caps=\"application/x-rtp,media=video,clock-rate=90000,\
         encoding-name=H264,payload=96,extmap-{RTP_CAPTURE_TIME_EXTENSION_ID}=(string)\
         urn:ietf:params:rtp-hdrext:ntp-64\" ! rtpjitterbuffer latency={RTP_JITTER_LATENCY_MS} \
         ! rtph264depay ! h264parse ! avdec_h264 ! videoconvert"
    )
}

/// The RTP header extension id that carries the capture time (NTP-64) on `rtp-h264:` streams.
pub const RTP_CAPTURE_TIME_EXTENSION_ID: u8 = 1;

/// The jitter buffer's wait for late packets: enough for a loopback or wired link.
pub const RTP_JITTER_LATENCY_MS: u32 = 30;

/// A value for a GStreamer pipeline description, quoted so spaces and `!` stay in it.
fn quoted(value: &str) -> String {
    format!("\"{}\"", value.replace('\\', "\\\\").replace('"', "\\\""))
}

/// Opens the source a spec names; a frame of another size than `expected_size_px` (the
/// mission's `[camera]`, which the tasks project with) is a named error, counted as malformed.
/// `None` takes the first good frame's size.
pub fn open(
    spec: &str,
    expected_size_px: Option<(usize, usize)>,
) -> Result<Box<dyn CameraSource>, CameraSourceError> {
    match CameraSpec::parse(spec)? {
        // A recorded folder flown as a camera starts again at its end, as a camera keeps going.
        CameraSpec::Folder { path, rate_fps } => {
            Ok(Box::new(ImageFolderSource::open(ImageFolderConfig {
                looping: true,
                expected_size_px,
                ..ImageFolderConfig::new(path, rate_fps)
            })?))
        }
        #[cfg(feature = "ros2")]
        CameraSpec::Ros2 { topic } => Ok(Box::new(super::ros2::Ros2Camera::open(
            &topic,
            expected_size_px,
        )?)),
        #[cfg(not(feature = "ros2"))]
        CameraSpec::Ros2 { .. } => Err(CameraSourceError::Spec {
            spec: spec.to_string(),
            reason: "this qosrt was built without the `ros2` feature".into(),
        }),
        #[cfg(feature = "gstreamer")]
        CameraSpec::Gstreamer { pipeline, sync } => {
            let config = super::gstreamer::GstreamerConfig {
                sync,
                expected_size_px,
                ..super::gstreamer::GstreamerConfig::new(pipeline)
            };
            Ok(Box::new(super::gstreamer::GstreamerSource::open(config)?))
        }
        #[cfg(not(feature = "gstreamer"))]
        CameraSpec::Gstreamer { .. } => Err(CameraSourceError::NoGstreamer {
            spec: spec.to_string(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pipeline(spec: &str) -> (String, bool) {
        match CameraSpec::parse(spec).unwrap() {
            CameraSpec::Gstreamer { pipeline, sync } => (pipeline, sync),
            other => panic!("{spec}: expected a pipeline, got {other:?}"),
        }
    }

    #[test]
    fn shortcuts_become_the_usual_pipelines() {
        assert_eq!(
            pipeline("v4l2:/dev/video0"),
            (
                "v4l2src device=\"/dev/video0\" ! videoconvert".into(),
                false
            )
        );
        let (rtp, sync) = pipeline("rtp-h264:5600");
        assert!(rtp.starts_with("udpsrc port=5600 "), "{rtp}");
        assert!(rtp.contains("encoding-name=H264") && rtp.contains("avdec_h264"));
        assert!(!sync);
        // A file plays at its own pace; a path with a space and a quote stays one value.
        assert_eq!(
            pipeline("file:/videos/my \"best\" run.mp4"),
            (
                "filesrc location=\"/videos/my \\\"best\\\" run.mp4\" ! decodebin ! videoconvert"
                    .into(),
                true
            )
        );
        assert_eq!(
            pipeline("gst: videotestsrc ! videoconvert ").0,
            "videotestsrc ! videoconvert"
        );
        assert!(pipeline("rtsp://10.0.0.5:8554/cam")
            .0
            .starts_with("rtspsrc "));
    }

    #[test]
    fn folders_take_a_rate() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().display().to_string();
        assert_eq!(
            CameraSpec::parse(&format!("folder:{path}@2.5")).unwrap(),
            CameraSpec::Folder {
                path: dir.path().into(),
                rate_fps: 2.5
            }
        );
        assert_eq!(
            CameraSpec::parse(&path).unwrap(),
            CameraSpec::Folder {
                path: dir.path().into(),
                rate_fps: DEFAULT_FOLDER_FPS
            }
        );
    }

    /// The mission's `[camera]` size holds for a folder camera: a frame of another size is a
    /// named error, the first one included; without it the first frame sets the size.
    #[test]
    fn a_folder_camera_refuses_frames_not_of_the_missions_size() {
        let dir = tempfile::tempdir().unwrap();
        image::GrayImage::from_pixel(32, 24, image::Luma([90]))
            .save(dir.path().join("frame.png"))
            .unwrap();
        let spec = format!("folder:{}@5", dir.path().display());
        let mut camera = open(&spec, Some((640, 480))).unwrap();
        assert!(matches!(
            camera.next_frame(0.0),
            Err(CameraSourceError::WrongSize {
                expected_width: 640,
                expected_height: 480,
                found_width: 32,
                found_height: 24,
                ..
            })
        ));
        let mut camera = open(&spec, None).unwrap();
        assert!(camera.next_frame(0.0).unwrap().is_some());
    }

    #[test]
    fn bad_specs_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().display().to_string();
        for (spec, wanted) in [
            ("rtp-h264:notaport", "expected a UDP port"),
            ("rtp-h264:0", "expected a UDP port"),
            ("rtp-h264:70000", "expected a UDP port"),
            ("gst:", "expected a GStreamer pipeline"),
            ("v4l2: ", "expected a V4L2 device"),
            ("/no/such/folder", "expected folder:PATH"),
            ("folder:/no/such/folder", "is not a folder"),
            (&format!("folder:{path}@fast"), "not a positive number"),
            (&format!("folder:{path}@-1"), "not a positive number"),
        ] {
            match CameraSpec::parse(spec) {
                Err(error @ CameraSourceError::Spec { .. }) => {
                    let message = error.to_string();
                    assert!(message.contains(wanted), "{spec}: {message}");
                    assert!(message.starts_with(&format!("--camera {spec}")));
                }
                other => panic!("{spec}: expected a named error, got {other:?}"),
            }
        }
    }

    #[cfg(not(feature = "gstreamer"))]
    #[test]
    fn without_gstreamer_a_pipeline_says_how_to_get_it() {
        let error = open("rtp-h264:5600", None)
            .err()
            .expect("no GStreamer here");
        assert!(matches!(error, CameraSourceError::NoGstreamer { .. }));
        assert!(error.to_string().contains("--features gstreamer"));
    }
}
