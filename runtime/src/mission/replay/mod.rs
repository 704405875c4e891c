//! Replay: the recorded mission's tasks re-run on its recorded inputs (the loop's clock, the
//! MAVLink it received, the frames it was delivered), on the virtual-time scheduler, and their
//! outputs compared with the recording's, channel by channel.
//!
//! A simulated mission (lockstep, virtual time) replays bit for bit with the same config and
//! binary. A flight's tasks ran on their own threads on the wall clock; replayed on virtual
//! time at their levels' periods, they see the same frames and telemetry but step at their
//! nominal times, so a flight's replay shows that timing as differences too.

use super::{MissionObserver, MissionRunner, PlanRequest, RunnerError, RunnerOptions};
use crate::camera::{CapturedFrame, MemorySource};
use crate::clock::Timestamp;
use crate::energy::MissionModel;
use crate::link::{LinkConfig, MavlinkLink, ReplayFeed};
use crate::record::channels::{self as ch, MavlinkBatch, StepRecord};
use crate::record::frames::{decode_frame, UnreadFrame};
use crate::record::latency::CaptureStamps;
use crate::record::reader::{RecordedMessage, RecordingReader};
use crate::record::recorder::{Recorder, RecorderOptions};
use crate::record::{FramePolicy, RecordError, RecordingHeader};
use crate::registry::PluginRegistry;
use crate::scheduler::SchedulerBuilder;
use crate::topics::{CameraFrame, DepthFrame, CAMERA_FRAME, DEPTH_FRAME};
use compare::{compare, messages_at, OutputPrints};
use decode_ahead::DecodeAhead;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

mod compare;
mod decode_ahead;

/// The recording's plan requests, for the runner to take at the next step, as it took them from
/// the ground station's link in flight.
#[derive(Clone, Default)]
struct RecordedPlanRequests(Arc<Mutex<Vec<PlanRequest>>>);

impl RecordedPlanRequests {
    fn push(&self, request: PlanRequest) {
        self.lock().push(request);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<PlanRequest>> {
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

impl MissionObserver for RecordedPlanRequests {
    fn plan_requests(&self, _now_s: f64) -> Vec<PlanRequest> {
        std::mem::take(&mut *self.lock())
    }
}

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
    #[error(
        "this file is part {part} of a recording split by its size budget, and begins at \
         t = {starts_s:.3} s, mid-mission: replay its first part, {first}, which goes on \
         through every part"
    )]
    LaterPart {
        part: u32,
        starts_s: f64,
        first: String,
    },
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
    /// The tasks that read camera or depth frames where the recording kept none
    /// (`--record-frames none`): they see no frames in the replay, so their outputs, and what
    /// follows from them, cannot be as flown.
    pub without_frames: Vec<String>,
}

impl ReplayReport {
    /// Every output channel as recorded.
    pub fn identical(&self) -> bool {
        self.channels.iter().all(ChannelDiff::identical)
    }
}

/// Re-runs the recording at `path` with `model` (the recorded config, or another) and compares.
/// The recording is read as a stream: each frame and telemetry batch is fed to the tasks and
/// let go; of the recorded outputs only their times and fingerprints are kept, the replay's
/// own outputs go to a temporary file compared the same way, and a channel's first differing
/// pair is read back to name its fields. Memory does not grow with the flight.
pub fn replay(
    path: &Path,
    mut model: MissionModel,
    registry: &PluginRegistry,
    options: &ReplayOptions,
) -> Result<ReplayReport, ReplayError> {
    let mut recording = RecordingReader::open(path)?;
    let header = &recording.header.clone();
    if header.part > 0 {
        // The runner's and the tasks' state at a part's start lives only in the parts before.
        return Err(ReplayError::LaterPart {
            part: header.part,
            starts_s: header.part_starts_ns.unwrap_or(0) as f64 * 1e-9,
            first: header.first_part.clone().unwrap_or_default(),
        });
    }
    let without_frames = tasks_without_frames(header, &model, registry);
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
    let outputs = ReplayOutputs::new()?;
    let recorder = Recorder::start(
        &RecorderOptions {
            file: Some(outputs.path.clone()),
            outputs_only: true,
            ..RecorderOptions::default()
        },
        header,
        &[],
    )?;
    runner.record(recorder).map_err(ReplayError::Setup)?;
    // The plan changes a ground station asked for in flight, handed to the steps that took them.
    let plan_requests = RecordedPlanRequests::default();
    runner.observe(Box::new(plan_requests.clone()));

    let bad =
        |topic: &'static str, message: &RecordedMessage, why: BadMessage| ReplayError::BadMessage {
            topic,
            time_s: message.log_time_ns as f64 * 1e-9,
            source: why,
        };
    // What is compared afterwards: the recorded outputs' fingerprints, and what the flight's
    // capture to setpoint needs.
    let mut recorded_outputs = OutputPrints::default();
    let mut stamps = CaptureStamps::default();
    let mut steps_recorded = 0;
    let mut steps_replayed = 0;
    let mut replayed_until_ns = 0;
    let mut stopped = None;
    let mut messages = DecodeAhead::new(recording.by_ref(), header.frame_codec);
    while let Some((message, pixels)) = messages.next() {
        let message = &message;
        recorded_outputs.add(message);
        stamps.add(message);
        if message.topic == ch::STEP.topic {
            steps_recorded += 1;
        }
        if stopped.is_some() {
            // The replay has stopped; the rest is read only to count its steps.
            messages.stop_decoding();
            continue;
        }
        match message.topic.as_str() {
            t if t == ch::MAVLINK_IN.topic => {
                let batch: MavlinkBatch = serde_json::from_slice(&message.data)
                    .map_err(|e| bad(ch::MAVLINK_IN.topic, message, e.into()))?;
                let incoming = batch
                    .to_incoming()
                    .map_err(|why| bad(ch::MAVLINK_IN.topic, message, why.into()))?;
                feed.push(incoming);
            }
            t if t == ch::CAMERA_IMAGE.topic || t == ch::CAMERA_UNREAD.topic => {
                let image = if t == ch::CAMERA_IMAGE.topic {
                    pixels
                        .unwrap_or_else(|| decode_frame(header.frame_codec, &message.data))
                        .map_err(|why| bad(ch::CAMERA_IMAGE.topic, message, why.into()))?
                } else {
                    // No task read it in flight: a blank frame of its size takes its place.
                    serde_json::from_slice::<UnreadFrame>(&message.data)
                        .map_err(|e| bad(ch::CAMERA_UNREAD.topic, message, e.into()))?
                        .blank()
                        .map_err(|why| bad(ch::CAMERA_UNREAD.topic, message, why.into()))?
                };
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
            t if t == ch::PLAN_REQUEST.topic => {
                let request: PlanRequest = serde_json::from_slice(&message.data)
                    .map_err(|e| bad(ch::PLAN_REQUEST.topic, message, e.into()))?;
                plan_requests.push(request);
            }
            t if t == ch::STEP.topic => {
                let step: StepRecord = serde_json::from_slice(&message.data)
                    .map_err(|e| bad(ch::STEP.topic, message, e.into()))?;
                if let Err(error) = runner.step(step.now_s, step.lockstep_ns) {
                    stopped = Some(format!("at t = {:.3} s: {error}", step.now_s));
                    continue;
                }
                steps_replayed += 1;
                replayed_until_ns = message.log_time_ns;
            }
            _ => {}
        }
    }
    runner.stop();
    runner.finish_recording().transpose()?;
    let replayed_outputs = OutputPrints::of_file(&outputs.path)?;
    let channels = compare(
        &recorded_outputs,
        &replayed_outputs,
        replayed_until_ns,
        |first_at| {
            Ok((
                messages_at(path, first_at)?,
                messages_at(&outputs.path, first_at)?,
            ))
        },
    )?;
    Ok(ReplayReport {
        steps_recorded,
        steps_replayed,
        replayed_until_s: replayed_until_ns as f64 * 1e-9,
        recording_truncated: recording.truncated().map(str::to_string),
        capture_to_setpoint: stamps.capture_to_setpoint(),
        stopped,
        channels,
        without_frames,
    })
}

/// The tasks that read frames, where the recording kept none.
fn tasks_without_frames(
    header: &RecordingHeader,
    model: &MissionModel,
    registry: &PluginRegistry,
) -> Vec<String> {
    if header.frames != FramePolicy::None {
        return Vec::new();
    }
    model
        .config
        .tasks
        .iter()
        .filter(|t| registry.reads(t, CAMERA_FRAME.name()) || registry.reads(t, DEPTH_FRAME.name()))
        .map(|t| t.name.clone())
        .collect()
}

/// The replay's own outputs: a temporary MCAP file, removed when the replay is done.
struct ReplayOutputs {
    path: PathBuf,
}

impl ReplayOutputs {
    fn new() -> Result<Self, ReplayError> {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let serial = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path =
            std::env::temp_dir().join(format!("qosrt-replay-{}-{serial}.mcap", std::process::id()));
        Ok(Self { path })
    }
}

impl Drop for ReplayOutputs {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}
