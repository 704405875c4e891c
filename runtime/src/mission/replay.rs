//! Replay: the recorded mission's tasks re-run on its recorded inputs (the loop's clock, the
//! MAVLink it received, the frames it was delivered), on the virtual-time scheduler, and their
//! outputs compared with the recording's, channel by channel.
//!
//! A simulated mission (lockstep, virtual time) replays bit for bit with the same config and
//! binary. A flight's tasks ran on their own threads on the wall clock; replayed on virtual
//! time at their levels' periods, they see the same frames and telemetry but step at their
//! nominal times, so a flight's replay shows that timing as differences too.

use super::{MissionRunner, RunnerError, RunnerOptions};
use crate::camera::{CapturedFrame, MemorySource};
use crate::clock::Timestamp;
use crate::energy::MissionModel;
use crate::link::{LinkConfig, MavlinkLink, ReplayFeed};
use crate::record::channels::{self as ch, MavlinkBatch, Role, StepRecord};
use crate::record::reader::{read_recording, RecordedMessage, Recording};
use crate::record::recorder::{Recorder, RecorderOptions};
use crate::record::RecordError;
use crate::registry::PluginRegistry;
use crate::scheduler::SchedulerBuilder;
use crate::topics::{CameraFrame, DepthFrame, DEPTH_FRAME};
use serde::Serialize;
use std::collections::BTreeSet;
use std::sync::Arc;

/// Why a recorded message is unreadable.
#[derive(Debug, thiserror::Error)]
pub enum BadMessage {
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    #[error(transparent)]
    Channel(#[from] ch::ChannelError),
}

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error("cannot set up the replay: {0}")]
    Setup(#[source] RunnerError),
    #[error("the recording's {topic} message at t = {time_s:.3} s is unreadable: {source}")]
    BadMessage {
        topic: &'static str,
        time_s: f64,
        #[source]
        source: BadMessage,
    },
}

/// What to change in the replay.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayOptions {
    /// Hold these tasks at these levels instead of the recording's `--fix`es.
    pub fixed_levels: Option<Vec<(String, f64)>>,
}

/// Where one output channel of the replay differs from the recording.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelDiff {
    pub topic: String,
    pub recorded: usize,
    pub replayed: usize,
    /// Message pairs (by order on the channel) that differ, counting unpaired ones.
    pub differing: usize,
    /// The first difference: its time, and which fields changed (recorded → replayed).
    pub first_difference_s: Option<f64>,
    pub last_difference_s: Option<f64>,
    pub first_fields: Vec<String>,
}

impl ChannelDiff {
    pub fn identical(&self) -> bool {
        self.differing == 0
    }
}

/// What a replay found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplayReport {
    /// Steps of the loop in the recording, and how many were replayed.
    pub steps_recorded: usize,
    pub steps_replayed: usize,
    /// The time of the last step replayed; outputs are compared up to it.
    pub replayed_until_s: f64,
    /// Why the recording ends early (cut off mid-flight), if it does.
    pub recording_truncated: Option<String>,
    /// Why the replay stopped before the recording's last step, if it did.
    pub stopped: Option<String>,
    pub channels: Vec<ChannelDiff>,
    /// The flight's capture to setpoint, read from the recording ([`super::latency`]).
    pub capture_to_setpoint: crate::scheduler::DurationSummary,
}

impl ReplayReport {
    /// Every output channel as recorded.
    pub fn identical(&self) -> bool {
        self.channels.iter().all(ChannelDiff::identical)
    }
}

/// Re-runs the recorded mission with `model` (the recorded config, or another) and compares.
pub fn replay(
    recording: &Recording,
    mut model: MissionModel,
    registry: &PluginRegistry,
    options: &ReplayOptions,
) -> Result<ReplayReport, ReplayError> {
    let header = &recording.header;
    // The phases flown for as long as they were, where the config has the same phases.
    let phases = &mut model.config.mission.phases;
    if phases.len() == header.phase_durations_s.len() {
        for (phase, &duration_s) in phases.iter_mut().zip(&header.phase_durations_s) {
            phase.duration_s = duration_s;
        }
    }
    let mut builder = SchedulerBuilder::new(registry);
    builder.seed(header.seed);
    for task in &model.config.tasks {
        if registry.contains(&task.plugin) {
            builder.task(task);
        }
    }
    let scheduler = builder
        .build_virtual()
        .map_err(|e| ReplayError::Setup(e.into()))?;
    let bus = scheduler.bus().clone();
    let depth_frames = bus
        .publisher::<DepthFrame>(DEPTH_FRAME)
        .map_err(|e| ReplayError::Setup(e.into()))?;
    let feed = ReplayFeed::new(header.link_peer_known);
    let frames = MemorySource::new();
    let runner_options = RunnerOptions {
        landing_target: header.landing_target,
        fixed_levels: options
            .fixed_levels
            .clone()
            .unwrap_or_else(|| header.fixed_levels.clone()),
    };
    let mut runner = MissionRunner::new(
        model,
        scheduler,
        MavlinkLink::replay(feed.clone(), LinkConfig::default()),
        header.plan.clone(),
        header
            .camera
            .then(|| Box::new(frames.clone()) as Box<dyn crate::camera::CameraSource>),
        runner_options,
    )
    .map_err(ReplayError::Setup)?;
    let recorder = Recorder::start(
        &RecorderOptions {
            in_memory: true,
            outputs_only: true,
            ..RecorderOptions::default()
        },
        header,
        &[],
    )?;
    runner.record(recorder).map_err(ReplayError::Setup)?;

    let bad =
        |topic: &'static str, message: &RecordedMessage, why: BadMessage| ReplayError::BadMessage {
            topic,
            time_s: message.log_time_ns as f64 * 1e-9,
            source: why,
        };
    let steps_recorded = recording.topic(ch::STEP.topic).count();
    let mut steps_replayed = 0;
    let mut replayed_until_ns = 0;
    let mut stopped = None;
    for message in &recording.messages {
        match message.topic.as_str() {
            t if t == ch::MAVLINK_IN.topic => {
                let batch: MavlinkBatch = serde_json::from_slice(&message.data)
                    .map_err(|e| bad(ch::MAVLINK_IN.topic, message, e.into()))?;
                let incoming = batch
                    .to_incoming()
                    .map_err(|why| bad(ch::MAVLINK_IN.topic, message, why.into()))?;
                feed.push(incoming);
            }
            t if t == ch::CAMERA_IMAGE.topic => {
                let image = ch::decode_gray_image(&message.data)
                    .map_err(|why| bad(ch::CAMERA_IMAGE.topic, message, why.into()))?;
                frames.push(CapturedFrame {
                    frame: CameraFrame {
                        frame_index: u64::from(message.sequence),
                        image: Arc::new(image),
                        vehicle_at_capture: None,
                    },
                    capture_time_s: Timestamp::from_nanos(message.publish_time_ns).as_secs_f64(),
                    // Recorded as the runner took it.
                    arrived_s: Timestamp::from_nanos(message.log_time_ns).as_secs_f64(),
                });
            }
            t if t == ch::CAMERA_DEPTH.topic => {
                let image = ch::decode_depth_image(&message.data)
                    .map_err(|why| bad(ch::CAMERA_DEPTH.topic, message, why.into()))?;
                depth_frames.publish(
                    Timestamp::from_nanos(message.log_time_ns),
                    DepthFrame {
                        frame_index: u64::from(message.sequence),
                        image: Arc::new(image),
                    },
                );
            }
            t if t == ch::STEP.topic => {
                let step: StepRecord = serde_json::from_slice(&message.data)
                    .map_err(|e| bad(ch::STEP.topic, message, e.into()))?;
                if let Err(error) = runner.step(step.now_s, step.lockstep_ns) {
                    stopped = Some(format!("at t = {:.3} s: {error}", step.now_s));
                    break;
                }
                steps_replayed += 1;
                replayed_until_ns = message.log_time_ns;
            }
            _ => {}
        }
    }
    runner.stop();
    let replayed = runner
        .finish_recording()
        .transpose()?
        .and_then(|summary| summary.data)
        .unwrap_or_default();
    let replayed = read_recording(&replayed)?;
    Ok(ReplayReport {
        steps_recorded,
        steps_replayed,
        replayed_until_s: replayed_until_ns as f64 * 1e-9,
        recording_truncated: recording.truncated.clone(),
        capture_to_setpoint: crate::record::latency::capture_to_setpoint(recording),
        stopped,
        channels: compare(recording, &replayed, replayed_until_ns),
    })
}

/// Every output channel of either recording, compared message by message up to `until_ns`.
pub fn compare(recorded: &Recording, replayed: &Recording, until_ns: u64) -> Vec<ChannelDiff> {
    let topics: BTreeSet<&str> = recorded
        .messages
        .iter()
        .chain(&replayed.messages)
        .map(|m| m.topic.as_str())
        .filter(|topic| ch::channel(topic).is_some_and(|c| c.role == Role::Output))
        .collect();
    topics
        .into_iter()
        .map(|topic| {
            let upto = |recording: &'_ Recording| -> Vec<RecordedMessage> {
                recording
                    .topic(topic)
                    .filter(|m| m.log_time_ns <= until_ns)
                    .cloned()
                    .collect()
            };
            diff_channel(topic, &upto(recorded), &upto(replayed))
        })
        .collect()
}

fn diff_channel(
    topic: &str,
    recorded: &[RecordedMessage],
    replayed: &[RecordedMessage],
) -> ChannelDiff {
    let mut diff = ChannelDiff {
        topic: topic.to_string(),
        recorded: recorded.len(),
        replayed: replayed.len(),
        differing: 0,
        first_difference_s: None,
        last_difference_s: None,
        first_fields: Vec::new(),
    };
    for index in 0..recorded.len().max(replayed.len()) {
        let (a, b) = (recorded.get(index), replayed.get(index));
        let same = matches!((a, b), (Some(a), Some(b)) if a.data == b.data && a.log_time_ns == b.log_time_ns);
        if same {
            continue;
        }
        diff.differing += 1;
        let time_ns = a.or(b).map_or(0, |m| m.log_time_ns);
        let time_s = time_ns as f64 * 1e-9;
        diff.last_difference_s = Some(time_s);
        if diff.first_difference_s.is_none() {
            diff.first_difference_s = Some(time_s);
            diff.first_fields = match (a, b) {
                (Some(a), Some(b)) => field_differences(a, b),
                (Some(_), None) => vec!["(not produced by the replay)".into()],
                _ => vec!["(not in the recording)".into()],
            };
        }
    }
    diff
}

/// At most this many fields are named per difference.
const MAX_FIELDS: usize = 6;

/// The fields of two messages that differ, as `path: recorded → replayed` (JSON), or what else
/// differs.
fn field_differences(a: &RecordedMessage, b: &RecordedMessage) -> Vec<String> {
    let mut fields = Vec::new();
    if a.log_time_ns != b.log_time_ns {
        fields.push(format!(
            "time: {:.6} s → {:.6} s",
            a.log_time_ns as f64 * 1e-9,
            b.log_time_ns as f64 * 1e-9
        ));
    }
    match (
        serde_json::from_slice::<serde_json::Value>(&a.data),
        serde_json::from_slice::<serde_json::Value>(&b.data),
    ) {
        (Ok(x), Ok(y)) => json_differences("", &x, &y, &mut fields),
        _ if a.data != b.data => fields.push("(binary message differs)".into()),
        _ => {}
    }
    fields.truncate(MAX_FIELDS);
    fields
}

fn json_differences(
    path: &str,
    a: &serde_json::Value,
    b: &serde_json::Value,
    out: &mut Vec<String>,
) {
    use serde_json::Value;
    if out.len() >= MAX_FIELDS || a == b {
        return;
    }
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let keys: BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for key in keys {
                let (p, q) = (
                    x.get(key).unwrap_or(&Value::Null),
                    y.get(key).unwrap_or(&Value::Null),
                );
                json_differences(&format!("{path}.{key}"), p, q, out);
            }
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                json_differences(&format!("{path}[{i}]"), p, q, out);
            }
        }
        _ => out.push(format!(
            "{}: {} → {}",
            path.strip_prefix('.').unwrap_or(path),
            shortened(a),
            shortened(b)
        )),
    }
}

/// A value as JSON, cut to a readable length.
fn shortened(value: &serde_json::Value) -> String {
    const MAX_CHARS: usize = 60;
    let text = value.to_string();
    match text.char_indices().nth(MAX_CHARS) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(topic: &str, time_ns: u64, json: &str) -> RecordedMessage {
        RecordedMessage {
            topic: topic.into(),
            log_time_ns: time_ns,
            publish_time_ns: time_ns,
            sequence: 0,
            data: json.as_bytes().to_vec(),
        }
    }

    #[test]
    fn a_difference_is_placed_in_time_and_named_by_field() {
        let topic = "/bus/landing/setpoint";
        let recorded = [
            message(
                topic,
                1_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.0,1.0]}"#,
            ),
            message(
                topic,
                2_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.1,1.0]}"#,
            ),
            message(
                topic,
                3_000_000_000,
                r#"{"mode":"Final","v":[0.0,0.0,2.0]}"#,
            ),
        ];
        let replayed = [
            message(
                topic,
                1_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.0,1.0]}"#,
            ),
            message(
                topic,
                2_000_000_000,
                r#"{"mode":"Descend","v":[0.5,0.2,1.0]}"#,
            ),
        ];
        let diff = diff_channel(topic, &recorded, &replayed);
        assert_eq!((diff.recorded, diff.replayed, diff.differing), (3, 2, 2));
        assert_eq!(diff.first_difference_s, Some(2.0));
        assert_eq!(diff.last_difference_s, Some(3.0));
        assert_eq!(diff.first_fields, ["v[1]: 0.1 → 0.2"]);
        let same = diff_channel(topic, &recorded, &recorded);
        assert!(same.identical(), "{same:?}");
    }

    #[test]
    fn a_message_at_another_time_differs_even_with_the_same_content() {
        let topic = "/qosrt/governor";
        let diff = diff_channel(
            topic,
            &[message(topic, 1_000_000_000, "{}")],
            &[message(topic, 1_500_000_000, "{}")],
        );
        assert_eq!(diff.differing, 1);
        assert_eq!(diff.first_fields, ["time: 1.000000 s → 1.500000 s"]);
    }
}
