//! The served camera's RTP/H.264 stream (feature `gstreamer`; without it the world serves
//! MAVLink only and asking for video is an error).

use std::time::Duration;

use super::ServeError;

#[cfg(feature = "gstreamer")]
pub(super) type Video = Option<crate::video_out::RtpH264Sender>;
/// Without GStreamer the world has no video stream to feed.
#[cfg(not(feature = "gstreamer"))]
pub(super) struct Video;

#[cfg(feature = "gstreamer")]
pub(super) fn open_video(
    port: Option<u16>,
    width_px: usize,
    height_px: usize,
    rate_fps: f64,
) -> Result<Video, ServeError> {
    use crate::video_out::{RtpH264Sender, VideoStreamConfig};
    port.map(|port| {
        RtpH264Sender::open(VideoStreamConfig::new(port, width_px, height_px, rate_fps))
            .map_err(ServeError::from)
    })
    .transpose()
}

#[cfg(not(feature = "gstreamer"))]
pub(super) fn open_video(
    port: Option<u16>,
    _width_px: usize,
    _height_px: usize,
    _rate_fps: f64,
) -> Result<Video, ServeError> {
    match port {
        Some(_) => Err(ServeError::NoVideo),
        None => Ok(Video),
    }
}

#[cfg(feature = "gstreamer")]
pub(super) fn send_frame(
    video: &mut Video,
    image: &algorithms::vision::image::GrayImage,
    age: Duration,
) -> Result<(), ServeError> {
    if let Some(video) = video {
        video.send(image, age)?;
    }
    Ok(())
}

#[cfg(not(feature = "gstreamer"))]
pub(super) fn send_frame(
    _video: &mut Video,
    _image: &algorithms::vision::image::GrayImage,
    _age: Duration,
) -> Result<(), ServeError> {
    Ok(())
}

#[cfg(feature = "gstreamer")]
pub(super) fn video_stats(video: &Video) -> (u64, Option<[f64; 2]>) {
    video.as_ref().map_or((0, None), |video| {
        (
            video.frames_sent(),
            video.latency_ms().map(|(p50, p99)| [p50, p99]),
        )
    })
}

#[cfg(not(feature = "gstreamer"))]
pub(super) fn video_stats(_video: &Video) -> (u64, Option<[f64; 2]>) {
    (0, None)
}
