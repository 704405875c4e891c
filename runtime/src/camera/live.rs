//! What the live camera sources (a GStreamer pipeline, a ROS 2 topic) share: the queue their
//! reading thread fills for the loop, the oldest frame dropped when the loop falls behind, and
//! the checks and stamps a frame gets when the loop takes it.

use super::{CameraFrame, CameraSourceError, CameraStats, CapturedFrame};
use algorithms::vision::image::GrayImage;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Instant;

/// A frame as the reading thread left it: its pixels (or why they are not a grey image).
pub struct Arrived<E> {
    pub frame_index: u64,
    pub image: Result<GrayImage, E>,
    /// When it was captured, on this host's monotonic clock.
    pub captured_at: Instant,
    /// When the reading thread took it.
    pub arrived_at: Instant,
    /// Its capture time is the sender's own stamp, not its arrival.
    pub sender_stamped: bool,
}

/// A frame of another size than the camera's (the mission's, else its first good frame's).
#[derive(Debug, thiserror::Error)]
#[error("{}×{} pixels, the camera's are {}×{}", found.0, found.1, expected.0, expected.1)]
pub struct WrongFrameSize {
    pub found: (usize, usize),
    pub expected: (usize, usize),
}

/// The frames waiting for the loop, and what the reading thread counted.
pub struct LiveQueue<E> {
    frames: VecDeque<Arrived<E>>,
    capacity: usize,
    received: u64,
    dropped: u64,
    lost_in_transport: u64,
    sender_stamps_refused: u64,
    /// Unparked at each frame (the runtime's loop, so it takes the frame at once).
    waker: Option<std::thread::Thread>,
}

impl<E> LiveQueue<E> {
    /// A queue holding `capacity` frames (at least one).
    pub fn shared(capacity: usize) -> Arc<Mutex<Self>> {
        Arc::new(Mutex::new(Self {
            frames: VecDeque::with_capacity(capacity),
            capacity: capacity.max(1),
            received: 0,
            dropped: 0,
            lost_in_transport: 0,
            sender_stamps_refused: 0,
            waker: None,
        }))
    }

    /// Queues the next frame (numbered in arrival order), dropping the oldest when full, and
    /// wakes the loop. `stamp_refused`: the sender's stamp was implausible, so the frame is
    /// stamped at arrival.
    pub fn push(
        &mut self,
        image: Result<GrayImage, E>,
        captured_at: Instant,
        sender_stamped: bool,
        stamp_refused: bool,
    ) {
        self.sender_stamps_refused += u64::from(stamp_refused);
        if self.frames.len() >= self.capacity {
            self.frames.pop_front();
            self.dropped += 1;
        }
        self.frames.push_back(Arrived {
            frame_index: self.received,
            image,
            captured_at,
            arrived_at: Instant::now(),
            sender_stamped,
        });
        self.received += 1;
        if let Some(waker) = &self.waker {
            waker.unpark();
        }
    }

    /// Frames the sender published that never reached the reading thread.
    pub fn note_lost(&mut self, frames: u64) {
        self.lost_in_transport += frames;
    }

    pub fn pop(&mut self) -> Option<Arrived<E>> {
        self.frames.pop_front()
    }

    pub fn wake(&mut self, thread: std::thread::Thread) {
        self.waker = Some(thread);
    }

    /// `stats` with what the reading thread counted.
    pub fn counted(&self, stats: CameraStats) -> CameraStats {
        CameraStats {
            dropped: self.dropped,
            lost_in_transport: self.lost_in_transport,
            sender_stamps_refused: self.sender_stamps_refused,
            ..stats
        }
    }
}

pub fn lock<E>(queue: &Mutex<LiveQueue<E>>) -> MutexGuard<'_, LiveQueue<E>> {
    // A queue of frames is whole whatever panicked while it was held.
    queue.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A frame the loop took at `now_s`, checked (readable, of the camera's size: the first good
/// frame's where the mission gave none), counted, and stamped on the runtime's clock. A frame
/// that fails a check is a named error counted as malformed.
pub fn deliver<E: std::error::Error + Send + Sync + 'static>(
    source_name: &str,
    arrived: Arrived<E>,
    expected_size_px: &mut Option<(usize, usize)>,
    stats: &mut CameraStats,
    now_s: f64,
) -> Result<CapturedFrame, CameraSourceError> {
    let mut malformed = |problem: Box<dyn std::error::Error + Send + Sync>| {
        stats.malformed += 1;
        CameraSourceError::Malformed {
            source_name: source_name.to_string(),
            frame_index: arrived.frame_index,
            problem,
        }
    };
    let image = arrived
        .image
        .map_err(|problem| malformed(Box::new(problem)))?;
    let found = (image.width(), image.height());
    let expected = *expected_size_px.get_or_insert(found);
    if found != expected {
        return Err(malformed(Box::new(WrongFrameSize { found, expected })));
    }
    stats.delivered += 1;
    stats.sender_stamped += u64::from(arrived.sender_stamped);
    Ok(CapturedFrame {
        frame: CameraFrame {
            vehicle_at_capture: None,
            frame_index: arrived.frame_index,
            image: Arc::new(image),
        },
        capture_time_s: now_s - arrived.captured_at.elapsed().as_secs_f64(),
        arrived_s: now_s - arrived.arrived_at.elapsed().as_secs_f64(),
    })
}
