//! A recording's camera frames decoded ahead of the replay, on the process's thread pool: a
//! frame takes a few milliseconds to decode, longer than the replay's own work for it, and each
//! decodes on its own, so the replay meets frames already decoded while the next ones are.

use crate::record::channels::{ChannelError, CAMERA_IMAGE};
use crate::record::frames::decode_frame;
use crate::record::reader::RecordedMessage;
use crate::record::FrameCodec;
use algorithms::vision::image::GrayImage;
use std::collections::VecDeque;
use std::sync::mpsc;

/// How many frames may be decoding or waiting ahead of the replay: enough to keep every core
/// busy, few enough that memory does not grow with the flight (a 640×480 frame is 300 kB).
const FRAMES_AHEAD: usize = 4;
/// How many messages may wait ahead of the replay, frames or not: the reference mission has
/// about 64 a frame, and a recording without frames (or a replay that stopped decoding) must
/// not be read ahead to its end.
const MESSAGES_AHEAD: usize = 512;

type Decoded = Result<GrayImage, ChannelError>;

/// The messages of `source` in order, each camera frame with its pixels.
pub struct DecodeAhead<I> {
    source: I,
    codec: FrameCodec,
    /// The messages read ahead, each frame with where its pixels will arrive.
    ahead: VecDeque<(RecordedMessage, Option<mpsc::Receiver<Decoded>>)>,
    frames_ahead: usize,
    /// Whether frames still need their pixels.
    decoding: bool,
}

impl<I: Iterator<Item = RecordedMessage>> DecodeAhead<I> {
    pub fn new(source: I, codec: FrameCodec) -> Self {
        Self {
            source,
            codec,
            ahead: VecDeque::new(),
            frames_ahead: 0,
            decoding: true,
        }
    }

    /// The frames from here on are only counted, not decoded (the replay has stopped).
    pub fn stop_decoding(&mut self) {
        self.decoding = false;
    }

    /// Reads on until enough frames are on their way, as many messages wait, or the source
    /// ends.
    fn read_ahead(&mut self) {
        while self.frames_ahead < FRAMES_AHEAD && self.ahead.len() < MESSAGES_AHEAD {
            let Some(message) = self.source.next() else {
                return;
            };
            let pixels = (self.decoding && message.topic == CAMERA_IMAGE.topic).then(|| {
                let (sender, receiver) = mpsc::sync_channel(1);
                let (codec, data) = (self.codec, message.data.clone());
                rayon::spawn(move || {
                    // The replay may have stopped and let go of the receiver: nothing to do.
                    let _ = sender.send(decode_frame(codec, &data));
                });
                receiver
            });
            self.frames_ahead += usize::from(pixels.is_some());
            self.ahead.push_back((message, pixels));
        }
    }
}

impl<I: Iterator<Item = RecordedMessage>> Iterator for DecodeAhead<I> {
    /// A message, and for a camera frame its pixels (or why they do not decode), until
    /// decoding stops.
    type Item = (RecordedMessage, Option<Decoded>);

    fn next(&mut self) -> Option<Self::Item> {
        self.read_ahead();
        let (message, pixels) = self.ahead.pop_front()?;
        let pixels = pixels.map(|receiver| {
            self.frames_ahead -= 1;
            // The decoding task always sends; a receive error would mean it panicked, and the
            // frame is then decoded here, where the error reaches the replay.
            receiver
                .recv()
                .unwrap_or_else(|_| decode_frame(self.codec, &message.data))
        });
        Some((message, pixels))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::frames::encode_frame;

    fn message(topic: &str, data: Vec<u8>, sequence: u32) -> RecordedMessage {
        RecordedMessage {
            topic: topic.into(),
            log_time_ns: u64::from(sequence),
            publish_time_ns: u64::from(sequence),
            sequence,
            data,
        }
    }

    #[test]
    fn every_message_comes_in_order_and_each_frame_with_its_own_pixels() {
        let frames: Vec<GrayImage> = (0..10u8)
            .map(|k| GrayImage::from_vec(8, 6, (0..48).map(|i| i * k).collect()).unwrap())
            .collect();
        let mut messages = Vec::new();
        for (index, frame) in frames.iter().enumerate() {
            let index = index as u32;
            messages.push(message("/qosrt/step", vec![index as u8], 2 * index));
            let data = encode_frame(FrameCodec::Compact, frame, u64::from(index));
            messages.push(message(CAMERA_IMAGE.topic, data, 2 * index + 1));
        }
        // A frame that does not decode is named in its place; the rest go on.
        messages.push(message(CAMERA_IMAGE.topic, b"not a frame".to_vec(), 99));
        let replayed: Vec<_> =
            DecodeAhead::new(messages.clone().into_iter(), FrameCodec::Compact).collect();
        assert_eq!(replayed.len(), messages.len());
        for ((message, pixels), original) in replayed.iter().zip(&messages) {
            assert_eq!(message, original);
            match pixels {
                None => assert_eq!(message.topic, "/qosrt/step"),
                Some(Ok(image)) => {
                    assert_eq!(image.data(), frames[(message.sequence / 2) as usize].data())
                }
                Some(Err(_)) => assert_eq!(message.sequence, 99),
            }
        }
        assert!(matches!(replayed.last(), Some((_, Some(Err(_))))));
    }

    #[test]
    fn a_source_without_frames_is_read_ahead_only_so_far() {
        // Endless, and no frame in it: the reader must not wait for frames that never come.
        let mut read = 0;
        let source = std::iter::from_fn(|| {
            read += 1;
            Some(message("/qosrt/step", Vec::new(), read))
        });
        let mut messages = DecodeAhead::new(source, FrameCodec::Compact);
        let (first, pixels) = messages.next().unwrap();
        assert_eq!((first.sequence, pixels.is_none()), (1, true));
        assert_eq!(messages.ahead.len(), MESSAGES_AHEAD - 1);
        // Frames no longer decoded once the replay stops: still read only so far ahead.
        let frame = GrayImage::from_vec(4, 4, vec![9; 16]).unwrap();
        let frames = std::iter::repeat_with(move || {
            message(
                CAMERA_IMAGE.topic,
                encode_frame(FrameCodec::Compact, &frame, 0),
                0,
            )
        });
        let mut stopped = DecodeAhead::new(frames, FrameCodec::Compact);
        stopped.stop_decoding();
        assert!(stopped.next().unwrap().1.is_none());
        assert_eq!(stopped.ahead.len(), MESSAGES_AHEAD - 1);
    }
}
