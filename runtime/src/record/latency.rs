//! Capture to setpoint read back from a recording: each velocity setpoint on `/mavlink/out`
//! carries in its `time_boot_ms` the capture of the frame whose fix it answers, and the frames
//! on `/camera/image` (and `/camera/unread`) carry their capture as their publish time. The first setpoint sent for a
//! capture gives that frame's delay: the flight's own figure, from the file alone.

use std::collections::{BTreeMap, BTreeSet};

use mavlink::dialects::common::MavMessage;

use super::channels::{self as ch, MavlinkRecord};
use super::reader::{RecordedMessage, Recording};
use crate::scheduler::stats::Histogram;
use crate::scheduler::DurationSummary;

/// Whole milliseconds of the same instant may round apart by one.
const MATCH_MS: u64 = 1;

/// From each recorded frame's capture to the first velocity setpoint that answers it.
pub fn capture_to_setpoint(recording: &Recording) -> DurationSummary {
    let mut stamps = CaptureStamps::default();
    for message in &recording.messages {
        stamps.add(message);
    }
    stamps.capture_to_setpoint()
}

/// What capture to setpoint needs of a recording, gathered as its messages stream by: each
/// frame's capture and each velocity setpoint's stamp and time, not the frames.
#[derive(Debug, Default)]
pub struct CaptureStamps {
    captures_ns: Vec<u64>,
    /// (the capture the setpoint carries, in whole ms; when it was sent)
    setpoints: Vec<(u64, u64)>,
}

impl CaptureStamps {
    pub fn add(&mut self, message: &RecordedMessage) {
        if message.topic == ch::CAMERA_IMAGE.topic || message.topic == ch::CAMERA_UNREAD.topic {
            self.captures_ns.push(message.publish_time_ns);
        } else if message.topic == ch::MAVLINK_OUT.topic {
            if let Some(stamp_ms) = setpoint_stamp_ms(&message.data) {
                self.setpoints.push((stamp_ms, message.log_time_ns));
            }
        }
    }

    /// From each frame's capture to the first setpoint that answers it.
    pub fn capture_to_setpoint(&self) -> DurationSummary {
        // Capture instants by whole millisecond, as a setpoint's `time_boot_ms` carries them.
        let captures_ns: BTreeMap<u64, u64> = self
            .captures_ns
            .iter()
            .map(|&capture_ns| (capture_ns / 1_000_000, capture_ns))
            .collect();
        let mut answered = BTreeSet::new();
        let mut delays = Histogram::default();
        for &(stamp_ms, sent_ns) in &self.setpoints {
            let capture = captures_ns
                .range(stamp_ms.saturating_sub(MATCH_MS)..=stamp_ms + MATCH_MS)
                .map(|(_, &capture_ns)| capture_ns)
                .find(|&capture_ns| capture_ns < sent_ns);
            if let Some(capture_ns) = capture {
                if answered.insert(capture_ns) {
                    delays.record(sent_ns - capture_ns);
                }
            }
        }
        delays.summary()
    }
}

/// A recorded velocity setpoint's `time_boot_ms`; `None` for anything else.
fn setpoint_stamp_ms(data: &[u8]) -> Option<u64> {
    let record: MavlinkRecord = serde_json::from_slice(data).ok()?;
    if record.name != "SET_POSITION_TARGET_LOCAL_NED" {
        return None;
    }
    match record.message().ok()? {
        (_, MavMessage::SET_POSITION_TARGET_LOCAL_NED(setpoint)) => {
            Some(u64::from(setpoint.time_boot_ms))
        }
        _ => None,
    }
}
