//! The recorder's queue for `frames = "consumed"`: a delivered frame waits, and every message
//! after it, until the runner says whether a task read it (known once the next frame replaces
//! it), so the file keeps its order and a replay meets each frame before the step that took it.

use super::channels as ch;
use super::encoded::Encoded;
use super::frames::{encode_frame, UnreadFrame};
use super::FrameCodec;
use algorithms::vision::image::GrayImage;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A frame the runner delivered, on its way to the file.
pub struct DeliveredFrame {
    pub now_ns: u64,
    pub capture_ns: u64,
    pub index: u64,
    pub image: Arc<GrayImage>,
    pub codec: FrameCodec,
}

impl DeliveredFrame {
    /// The frame's message: its pixels where a task read it, else its size alone.
    fn encode(&self, read: bool) -> Encoded {
        let (spec, data) = if read {
            (
                ch::CAMERA_IMAGE,
                encode_frame(self.codec, &self.image, self.capture_ns),
            )
        } else {
            (ch::CAMERA_UNREAD, ch::json(&UnreadFrame::of(&self.image)))
        };
        Encoded {
            publish_time_ns: self.capture_ns,
            // MCAP's sequence is 32 bits; a frame index past it wraps, as it always has.
            sequence: Some(self.index as u32),
            viewer_frame: (read && self.codec == FrameCodec::Compact).then(|| self.image.clone()),
            ..Encoded::at(spec, self.now_ns, data)
        }
    }
}

enum Held {
    Message(Encoded),
    Frame {
        frame: DeliveredFrame,
        /// Whether a task read it; `None` until the runner knows.
        read: Option<bool>,
        since: Instant,
    },
}

/// Messages in the order they came, held behind the oldest frame whose fate is not known.
pub struct FrameHold {
    queue: VecDeque<Held>,
    /// How long a frame may wait: past it the frame is kept whole (a replay then meets pixels
    /// no task reads, which changes nothing), so a stalled camera holds nothing back for long.
    max_wait: Duration,
}

impl FrameHold {
    pub fn new(max_wait: Duration) -> Self {
        Self {
            queue: VecDeque::new(),
            max_wait,
        }
    }

    pub fn message(&mut self, message: Encoded) {
        self.queue.push_back(Held::Message(message));
    }

    /// A delivered frame; `read` where it is known already (every frame is kept).
    pub fn frame(&mut self, frame: DeliveredFrame, read: Option<bool>) {
        self.queue.push_back(Held::Frame {
            frame,
            read,
            since: Instant::now(),
        });
    }

    /// The runner's word on frame `index` (a frame already let go is not asked about again).
    pub fn mark(&mut self, index: u64, was_read: bool) {
        for held in &mut self.queue {
            if let Held::Frame { frame, read, .. } = held {
                if frame.index == index && read.is_none() {
                    *read = Some(was_read);
                    return;
                }
            }
        }
    }

    /// The messages that may be written now, in order.
    pub fn ready(&mut self, now: Instant) -> Vec<Encoded> {
        let mut out = Vec::new();
        while let Some(front) = self.queue.front_mut() {
            if let Held::Frame { read, since, .. } = front {
                if read.is_none() {
                    if now.duration_since(*since) < self.max_wait {
                        break;
                    }
                    *read = Some(true);
                }
            }
            out.push(match self.queue.pop_front() {
                Some(Held::Message(message)) => message,
                Some(Held::Frame { frame, read, .. }) => frame.encode(read != Some(false)),
                None => break,
            });
        }
        out
    }

    /// Everything left, at the end: a frame never answered for is kept whole.
    pub fn drain(&mut self) -> Vec<Encoded> {
        self.queue
            .drain(..)
            .map(|held| match held {
                Held::Message(message) => message,
                Held::Frame { frame, read, .. } => frame.encode(read != Some(false)),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(index: u64) -> DeliveredFrame {
        DeliveredFrame {
            now_ns: index * 100,
            capture_ns: index * 100 - 30,
            index,
            image: Arc::new(GrayImage::from_vec(4, 3, vec![index as u8; 12]).unwrap()),
            codec: FrameCodec::Png,
        }
    }

    fn step(time_ns: u64) -> Encoded {
        Encoded::at(ch::STEP, time_ns, Vec::new())
    }

    fn topics(messages: &[Encoded]) -> Vec<(&str, u64)> {
        messages
            .iter()
            .map(|m| (m.spec.topic, m.log_time_ns))
            .collect()
    }

    #[test]
    fn messages_wait_behind_a_frame_until_the_runner_says_whether_it_was_read() {
        let mut hold = FrameHold::new(Duration::from_secs(1));
        let now = Instant::now();
        hold.message(step(50));
        hold.frame(frame(1), None);
        hold.message(step(100));
        hold.frame(frame(2), None);
        hold.message(step(200));
        // The first step goes; the rest waits behind frame 1.
        assert_eq!(topics(&hold.ready(now)), [("/qosrt/step", 50)]);
        // Frame 2's answer first changes nothing: frame 1 still holds the line.
        hold.mark(2, true);
        assert!(hold.ready(now).is_empty());
        hold.mark(1, false);
        let out = hold.ready(now);
        assert_eq!(
            topics(&out),
            [
                ("/camera/unread", 100),
                ("/qosrt/step", 100),
                ("/camera/image", 200),
                ("/qosrt/step", 200)
            ]
        );
        // The unread frame is its size, stamped at capture, numbered as delivered.
        let unread: UnreadFrame = serde_json::from_slice(&out[0].data).unwrap();
        assert_eq!((unread.width_px, unread.height_px), (4, 3));
        assert_eq!((out[0].publish_time_ns, out[0].sequence), (70, Some(1)));
        let pixels = super::super::frames::decode_png_image(&out[2].data).unwrap();
        assert_eq!(pixels.data(), &[2; 12]);
    }

    #[test]
    fn a_compact_frame_carries_its_pixels_for_the_viewer_and_a_png_or_unread_one_does_not() {
        let compact = DeliveredFrame {
            codec: FrameCodec::Compact,
            ..frame(5)
        };
        let kept = compact.encode(true);
        let viewer = kept
            .viewer_frame
            .as_ref()
            .expect("a compact frame's pixels");
        assert!(Arc::ptr_eq(viewer, &compact.image));
        // The viewer's PNG holds the file's pixels.
        let png = super::super::frames::png_image(viewer, kept.publish_time_ns);
        let from_file =
            super::super::frames::decode_frame(FrameCodec::Compact, &kept.data).unwrap();
        assert_eq!(
            super::super::frames::decode_png_image(&png).unwrap().data(),
            from_file.data()
        );
        assert!(compact.encode(false).viewer_frame.is_none());
        assert!(frame(5).encode(true).viewer_frame.is_none());
    }

    #[test]
    fn a_frame_not_answered_for_in_time_is_kept_whole() {
        let mut hold = FrameHold::new(Duration::from_millis(10));
        let start = Instant::now();
        hold.frame(frame(1), None);
        hold.message(step(150));
        assert!(hold.ready(start).is_empty());
        let later = start + Duration::from_millis(20);
        assert_eq!(
            topics(&hold.ready(later)),
            [("/camera/image", 100), ("/qosrt/step", 150)]
        );
        // A late answer finds nothing to change.
        hold.mark(1, false);
        assert!(hold.ready(later).is_empty());
        // At the end, an unanswered frame is kept too, a known-unread one is not.
        hold.frame(frame(2), None);
        hold.frame(frame(3), None);
        hold.mark(3, false);
        assert_eq!(
            topics(&hold.drain()),
            [("/camera/image", 200), ("/camera/unread", 300)]
        );
    }
}
