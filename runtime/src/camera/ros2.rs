//! `--camera ros2:/TOPIC`: frames a ROS 2 camera driver publishes, as `sensor_msgs/Image`
//! (mono8, rgb8, bgr8) or, on a topic ending in `/compressed` (image_transport's name),
//! `sensor_msgs/CompressedImage` (JPEG or PNG). Each frame is stamped with its header's stamp
//! (the driver's capture time, ROS time) where that is plausible, else at its arrival. A frame
//! of another encoding or size is a named error, counted as malformed; the mission goes on.

use super::live::{deliver, lock, LiveQueue};
use super::{CameraSource, CameraSourceError, CameraStats, CapturedFrame};
use crate::ros2::messages::{CompressedImage, Header, Image};
use crate::ros2::{open_node, sensor_data_qos, subscription, Subscription};
use algorithms::vision::image::GrayImage;
use ros2_client::Gid;
use ros2_client::MessageInfo;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// A header stamp older than this at arrival (or in the future) is not the capture time of a
/// live frame: the clocks disagree, and the frame is stamped at arrival.
pub const MAX_STAMP_AGE_S: f64 = 1.0;
/// Frames held for the loop; older ones are dropped when it falls behind.
const QUEUE_FRAMES: usize = 2;
/// How often the subscription is looked at: the frame's added delay is at most this.
const POLL_PERIOD: Duration = Duration::from_micros(500);

/// Why a frame is not a grey image of the camera's.
#[derive(Debug, thiserror::Error)]
pub enum FrameProblem {
    #[error("encoding `{0}` is not one qosrt reads (mono8, rgb8, bgr8)")]
    Encoding(String),
    #[error("{width}×{height} {encoding} with step {step} needs {needed} bytes, the message has {found}")]
    Layout {
        width: u32,
        height: u32,
        encoding: String,
        step: u32,
        needed: usize,
        found: usize,
    },
    #[error("compressed frame ({format}) does not decode: {source}")]
    Compressed {
        format: String,
        #[source]
        source: image::ImageError,
    },
    #[error(transparent)]
    Image(#[from] algorithms::vision::image::FrameError),
}

/// The camera: a ROS 2 subscription read on its own thread.
pub struct Ros2Camera {
    name: String,
    shared: Arc<Mutex<LiveQueue<FrameProblem>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    expected_size_px: Option<(usize, usize)>,
    stats: CameraStats,
}

impl Ros2Camera {
    /// Subscribes to `topic` (a ROS 2 name such as `/camera/image_raw`).
    pub fn open(
        topic: &str,
        expected_size_px: Option<(usize, usize)>,
    ) -> Result<Self, CameraSourceError> {
        let name = format!("ros2:{topic}");
        let failed = |reason: String| CameraSourceError::Device {
            source_name: name.clone(),
            reason,
        };
        let (namespace, base) = topic
            .rsplit_once('/')
            .map(|(ns, base)| (if ns.is_empty() { "/" } else { ns }, base))
            .ok_or_else(|| {
                failed(format!(
                    "`{topic}` is not a ROS 2 topic such as /camera/image_raw"
                ))
            })?;
        let compressed = base == "compressed";
        let (context, mut node) =
            open_node("/qosrt", "camera").map_err(|e| failed(e.to_string()))?;
        let reader = if compressed {
            Reader::Compressed(
                subscription(
                    &mut node,
                    namespace,
                    base,
                    ("sensor_msgs", "CompressedImage"),
                    sensor_data_qos(),
                )
                .map_err(|e| failed(e.to_string()))?,
            )
        } else {
            Reader::Raw(
                subscription(
                    &mut node,
                    namespace,
                    base,
                    ("sensor_msgs", "Image"),
                    sensor_data_qos(),
                )
                .map_err(|e| failed(e.to_string()))?,
            )
        };
        let shared = LiveQueue::shared(QUEUE_FRAMES);
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (shared, stop) = (shared.clone(), stop.clone());
            std::thread::Builder::new()
                .name("qosrt-ros2-camera".into())
                .spawn(move || {
                    // The node and its context live as long as the thread reads.
                    let _node = (context, node);
                    let mut gaps = SequenceGaps::default();
                    while !stop.load(Ordering::Acquire) {
                        let Some((image, header, info)) = reader.take() else {
                            std::thread::sleep(POLL_PERIOD);
                            continue;
                        };
                        let arrived_at = Instant::now();
                        let age = stamp_age(&header, SystemTime::now());
                        let captured_at = age.map_or(arrived_at, |age| arrived_at - age);
                        let mut queue = lock(&shared);
                        let sequence = info.sequence_number();
                        queue.note_lost(gaps.lost_before(info.publisher_gid(), sequence));
                        queue.push(image, captured_at, age.is_some(), age.is_none());
                    }
                })
                .map_err(|e| failed(format!("cannot start its thread: {e}")))?
        };
        Ok(Self {
            name,
            shared,
            stop,
            thread: Some(thread),
            expected_size_px,
            stats: CameraStats::default(),
        })
    }
}

/// The subscription, of either type.
enum Reader {
    Raw(Subscription<Image>),
    Compressed(Subscription<CompressedImage>),
}

impl Reader {
    /// The next message, as a grey image (or why not), its header and who sent it.
    fn take(&self) -> Option<(Result<GrayImage, FrameProblem>, Header, MessageInfo)> {
        match self {
            Reader::Raw(reader) => {
                let (image, info) = reader.take().ok()??;
                let gray = gray_of_raw(&image);
                Some((gray, image.header, info))
            }
            Reader::Compressed(reader) => {
                let (image, info) = reader.take().ok()??;
                let gray = gray_of_compressed(&image);
                Some((gray, image.header, info))
            }
        }
    }
}

/// Counts the frames a writer published that never arrived, from the gaps in its sequence
/// numbers (best effort: a frame that loses one of its fragments is lost whole).
#[derive(Default)]
struct SequenceGaps {
    last: HashMap<Gid, i64>,
    warned: bool,
}

impl SequenceGaps {
    /// The frames lost before frame `sequence` of `writer`.
    fn lost_before(&mut self, writer: Gid, sequence: i64) -> u64 {
        let last = self.last.entry(writer).or_insert(sequence - 1);
        let lost = (sequence - *last - 1).max(0) as u64;
        *last = (*last).max(sequence);
        if lost > 0 && !self.warned {
            self.warned = true;
            tracing::warn!(
                lost,
                "ROS 2 camera frames lost on the way: a frame larger than the kernel's socket \
                 receive buffer overflows it (RustDDS keeps the default, net.core.rmem_default); \
                 raise it, e.g. sysctl -w net.core.rmem_default=4194304"
            );
        }
        lost
    }
}

/// How old the header's stamp is at `now`; `None` where it cannot be the capture time (zero,
/// in the future, older than [`MAX_STAMP_AGE_S`]).
fn stamp_age(header: &Header, now: SystemTime) -> Option<Duration> {
    let stamp = &header.stamp;
    if stamp.sec <= 0 && stamp.nanosec == 0 {
        return None;
    }
    let captured = UNIX_EPOCH + Duration::new(stamp.sec.max(0) as u64, stamp.nanosec);
    now.duration_since(captured)
        .ok()
        .filter(|age| age.as_secs_f64() <= MAX_STAMP_AGE_S)
}

/// A `sensor_msgs/Image` as grey: mono8 as it is, rgb8 and bgr8 by ITU-R BT.601 luma.
pub fn gray_of_raw(image: &Image) -> Result<GrayImage, FrameProblem> {
    let channels = match image.encoding.as_str() {
        "mono8" | "8UC1" => 1,
        "rgb8" | "bgr8" => 3,
        other => return Err(FrameProblem::Encoding(other.into())),
    };
    let (width, height) = (image.width as usize, image.height as usize);
    let step = image.step as usize;
    let needed = step * height;
    if step < width * channels || image.data.len() < needed {
        return Err(FrameProblem::Layout {
            width: image.width,
            height: image.height,
            encoding: image.encoding.clone(),
            step: image.step,
            needed: needed.max(width * channels * height),
            found: image.data.len(),
        });
    }
    let (r, b) = if image.encoding == "bgr8" {
        (2, 0)
    } else {
        (0, 2)
    };
    let mut pixels = Vec::with_capacity(width * height);
    for row in image.data.chunks(step).take(height) {
        let row = &row[..width * channels];
        if channels == 1 {
            pixels.extend_from_slice(row);
        } else {
            pixels.extend(row.chunks_exact(3).map(|p| {
                let luma =
                    0.299 * f32::from(p[r]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[b]);
                luma.round() as u8
            }));
        }
    }
    Ok(GrayImage::from_vec(width, height, pixels)?)
}

/// A `sensor_msgs/CompressedImage` (JPEG or PNG) as grey.
pub fn gray_of_compressed(image: &CompressedImage) -> Result<GrayImage, FrameProblem> {
    let decoded =
        image::load_from_memory(&image.data).map_err(|source| FrameProblem::Compressed {
            format: image.format.clone(),
            source,
        })?;
    let luma = decoded.to_luma8();
    let (width, height) = (luma.width() as usize, luma.height() as usize);
    Ok(GrayImage::from_vec(width, height, luma.into_raw())?)
}

impl CameraSource for Ros2Camera {
    fn name(&self) -> &str {
        &self.name
    }

    fn next_frame(&mut self, now_s: f64) -> Result<Option<CapturedFrame>, CameraSourceError> {
        let Some(arrived) = lock(&self.shared).pop() else {
            return Ok(None);
        };
        deliver(
            &self.name,
            arrived,
            &mut self.expected_size_px,
            &mut self.stats,
            now_s,
        )
        .map(Some)
    }

    fn wake_on_frame(&mut self, thread: std::thread::Thread) {
        lock(&self.shared).wake(thread);
    }

    fn stats(&self) -> CameraStats {
        lock(&self.shared).counted(self.stats)
    }
}

impl Drop for Ros2Camera {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros2::messages::Time;

    #[test]
    fn frames_missing_from_a_writers_sequence_are_counted_lost() {
        let writer = |n: u8| Gid::from([n; 16]);
        let mut gaps = SequenceGaps::default();
        let lost: Vec<u64> = [(1, 1), (1, 2), (2, 10), (1, 6), (2, 11), (1, 5), (1, 9)]
            .into_iter()
            .map(|(w, sequence)| gaps.lost_before(writer(w), sequence))
            .collect();
        // 3, 4 and 5 missing from writer 1; nothing before a writer's first; a late number
        // loses nothing and moves nothing back; 7 and 8 missing between 6 and 9.
        assert_eq!(lost, vec![0, 0, 0, 3, 0, 0, 2]);
    }

    fn image(encoding: &str, width: u32, height: u32, step: u32, data: Vec<u8>) -> Image {
        Image {
            header: Header::default(),
            height,
            width,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data,
        }
    }

    #[test]
    fn mono_and_colour_frames_become_grey_with_their_row_padding_skipped() {
        // Two rows of two pixels, each row padded to four bytes.
        let mono = gray_of_raw(&image("mono8", 2, 2, 4, vec![10, 20, 0, 0, 30, 40, 0, 0])).unwrap();
        assert_eq!(mono.data(), &[10, 20, 30, 40]);
        // Pure red, green and blue, then white: BT.601's weights, channel order honoured.
        let rgb = vec![255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255];
        let gray = gray_of_raw(&image("rgb8", 4, 1, 12, rgb.clone())).unwrap();
        assert_eq!(gray.data(), &[76, 150, 29, 255]);
        let bgr: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[2], p[1], p[0]]).collect();
        assert_eq!(
            gray_of_raw(&image("bgr8", 4, 1, 12, bgr)).unwrap().data(),
            gray.data()
        );
    }

    #[test]
    fn a_frame_qosrt_cannot_read_is_named() {
        let error = gray_of_raw(&image("yuv422", 2, 2, 4, vec![0; 8])).unwrap_err();
        assert!(error.to_string().contains("yuv422"), "{error}");
        let short = gray_of_raw(&image("mono8", 4, 4, 4, vec![0; 10])).unwrap_err();
        assert!(
            matches!(short, FrameProblem::Layout { found: 10, .. }),
            "{short}"
        );
        let garbage = CompressedImage {
            header: Header::default(),
            format: "jpeg".into(),
            data: vec![1, 2, 3],
        };
        assert!(matches!(
            gray_of_compressed(&garbage),
            Err(FrameProblem::Compressed { .. })
        ));
    }

    #[test]
    fn a_compressed_png_decodes_to_the_same_grey() {
        let pixels: Vec<u8> = (0..12).map(|i| i * 20).collect();
        let mut png = Vec::new();
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(&mut png),
            &pixels,
            4,
            3,
            image::ExtendedColorType::L8,
        )
        .unwrap();
        let message = CompressedImage {
            header: Header::default(),
            format: "png".into(),
            data: png,
        };
        assert_eq!(gray_of_compressed(&message).unwrap().data(), &pixels[..]);
    }

    #[test]
    fn a_stamp_is_the_capture_time_only_when_it_is_recent_and_not_in_the_future() {
        let now = UNIX_EPOCH + Duration::from_secs(1_800_000_000);
        let header = |sec: i32, nanosec: u32| Header {
            stamp: Time { sec, nanosec },
            frame_id: String::new(),
        };
        assert_eq!(
            stamp_age(&header(1_799_999_999, 980_000_000), now),
            Some(Duration::from_millis(20))
        );
        assert_eq!(stamp_age(&header(0, 0), now), None, "unset");
        assert_eq!(stamp_age(&header(1_800_000_001, 0), now), None, "future");
        assert_eq!(stamp_age(&header(1_799_999_990, 0), now), None, "stale");
    }
}
