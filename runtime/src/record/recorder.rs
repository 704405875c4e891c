//! The recorder: the mission runner and the bus hand it what happened, its own thread encodes
//! it and writes the MCAP file (and serves it live over the Foxglove WebSocket protocol), so
//! the loop and the tasks only queue a message.

use super::channels::{self as ch, ChannelSpec, MavlinkBatch, MavlinkRecord, StepRecord};
use super::encoded::Encoded;
use super::frame_hold::{DeliveredFrame, FrameHold};
pub use super::sink::RecordingSummary;
use super::sink::{McapSink, Output};
use super::{ConfigFile, FrameCodec, FramePolicy, RecordError, RecordingHeader};
use crate::bus::{Bus, Message, Topic};
use crate::clock::Timestamp;
use crate::governor::GovernorDecision;
use crate::link::LinkCapture;
use crate::scheduler::TaskStats;
use crate::telemetry::BatteryTelemetry;
use crate::topics::{
    DepthFrame, HazardReport, HybridTrackingStatus, LandingSetpoint, MarkerObservation,
    MissionPhase, RelativeState, VehicleState, DEPTH_FRAME, HAZARDS, HYBRID_TRACKING_STATUS,
    LANDING_MARKER, LANDING_SETPOINT, MISSION_PHASE, RELATIVE_STATE, VEHICLE_STATE,
};
use algorithms::vision::image::GrayImage;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::io::Cursor;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::mpsc;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Where a recording goes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RecorderOptions {
    /// The MCAP file; `None` with `live` only serves the channels.
    pub file: Option<PathBuf>,
    /// Serve the channels live over the Foxglove WebSocket protocol on this address.
    pub live: Option<SocketAddr>,
    /// Keep the file in memory and hand it back when finished (a replay's own run).
    pub in_memory: bool,
    /// Leave out what a replay is fed (frames, telemetry in): a replay's own run records only
    /// what it made.
    pub outputs_only: bool,
    /// Which camera and depth frames to keep (the header says which were kept).
    pub frames: FramePolicy,
    /// How the kept camera frames are stored (the header says).
    pub codec: FrameCodec,
    /// Each file's size budget: past it the recording goes on in a next part.
    pub max_bytes: Option<u64>,
}

/// Work for the recorder's thread: encoding happens there, not on the caller's.
type Job = Box<dyn FnOnce() -> Vec<Encoded> + Send>;

/// What the recorder's thread is sent. The bus's taps hold senders for as long as the bus
/// lives, so the end is a message, not the channel closing.
enum Work {
    Job(Job),
    /// A delivered camera frame, and whether a task read it where that is known already.
    Frame(DeliveredFrame, Option<bool>),
    /// Whether a task read frame `index` (`frames = "consumed"`).
    FrameRead {
        index: u64,
        read: bool,
    },
    Finish,
}

/// A recording in progress. Dropping it finishes the file; [`Recorder::finish`] also says how
/// it went.
pub struct Recorder {
    jobs: Option<mpsc::Sender<Work>>,
    thread: Option<JoinHandle<Result<RecordingSummary, RecordError>>>,
    outputs_only: bool,
    frames: FramePolicy,
    codec: FrameCodec,
    live_port: Option<u16>,
}

/// An id for a new recording, which its parts share: when and by which process it began.
fn recording_id() -> String {
    let since_epoch = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    format!("{:x}-{:x}", since_epoch.as_nanos(), std::process::id())
}

/// A time on the runtime's clock in nanoseconds, rounded as the runner's own stamps are (so a
/// replay gets back the same seconds).
fn ns(time_s: f64) -> u64 {
    Timestamp::from_secs_f64(time_s).as_nanos()
}

impl Recorder {
    /// Opens the file (and the live server), writes the header and the config files, and
    /// starts the writer thread.
    pub fn start(
        options: &RecorderOptions,
        header: &RecordingHeader,
        config_files: &[ConfigFile],
    ) -> Result<Self, RecordError> {
        let output = match (&options.file, options.in_memory) {
            (_, true) => Output::Memory(Cursor::new(Vec::new())),
            (Some(path), false) => Output::create(path)?,
            (None, false) => Output::None,
        };
        let header = RecordingHeader {
            frames: options.frames,
            frame_codec: options.codec,
            recording_id: recording_id(),
            ..header.clone()
        };
        let writer = McapSink::new(
            output,
            options.file.clone(),
            &header,
            config_files,
            options.max_bytes,
        )?;
        let live = options.live.map(LiveServer::start).transpose()?;
        let live_port = live.as_ref().map(|l| l.port);
        let (jobs, receiver) = mpsc::channel::<Work>();
        let thread = std::thread::Builder::new()
            .name("qosrt-recorder".into())
            .spawn(move || {
                // Encoding and compressing wait for the time the mission leaves: a recording
                // never slows the loop or the tasks on a busy companion.
                crate::scheduler::lower_current_thread_priority(10);
                write_loop(receiver, writer, live)
            })
            .map_err(RecordError::Thread)?;
        Ok(Self {
            jobs: Some(jobs),
            thread: Some(thread),
            outputs_only: options.outputs_only,
            frames: options.frames,
            codec: options.codec,
            live_port,
        })
    }

    /// Whether camera and depth frames go into the recording (depth frames whole, under
    /// `consumed` too).
    fn keeps_frames(&self) -> bool {
        !self.outputs_only && self.frames != FramePolicy::None
    }

    /// The live server's port, when serving.
    pub fn live_port(&self) -> Option<u16> {
        self.live_port
    }

    fn send(&self, job: Job) {
        if let Some(jobs) = &self.jobs {
            // The writer thread ends only when told to, or after a write error that finish
            // reports: nothing to do here either way.
            let _ = jobs.send(Work::Job(job));
        }
    }

    /// Records every message published on the bus topics a recording keeps (and the depth
    /// frames a simulator publishes, as input).
    pub fn tap_bus(&self, bus: &Bus) -> Result<(), crate::bus::BusError> {
        let [vehicle, phase, marker, relative, setpoint, hazards, hybrid] = ch::BUS_TOPICS;
        self.tap(bus, VEHICLE_STATE, move |m: &Message<VehicleState>| {
            let t = m.stamp.as_nanos();
            let mut out = vec![Encoded::at(vehicle, t, ch::json(&m.value))];
            if let Some((pose, tf)) = ch::vehicle_pose(t, &m.value) {
                out.push(Encoded::at(ch::VEHICLE_POSE, t, pose));
                out.push(Encoded::at(ch::VEHICLE_TF, t, tf));
            }
            out
        })?;
        self.tap(bus, MISSION_PHASE, move |m: &Message<MissionPhase>| {
            vec![Encoded::at(phase, m.stamp.as_nanos(), ch::json(&m.value))]
        })?;
        self.tap(
            bus,
            LANDING_MARKER,
            move |m: &Message<MarkerObservation>| {
                let t = m.stamp.as_nanos();
                vec![
                    Encoded::at(marker, t, ch::json(&m.value)),
                    Encoded::at(ch::ANNOTATIONS, t, ch::marker_annotations(t, &m.value)),
                ]
            },
        )?;
        self.tap(bus, RELATIVE_STATE, move |m: &Message<RelativeState>| {
            vec![Encoded::at(
                relative,
                m.stamp.as_nanos(),
                ch::json(&m.value),
            )]
        })?;
        self.tap(
            bus,
            LANDING_SETPOINT,
            move |m: &Message<LandingSetpoint>| {
                vec![Encoded::at(
                    setpoint,
                    m.stamp.as_nanos(),
                    ch::json(&m.value),
                )]
            },
        )?;
        self.tap(bus, HAZARDS, move |m: &Message<HazardReport>| {
            let t = m.stamp.as_nanos();
            vec![
                Encoded::at(hazards, t, ch::json(&m.value)),
                Encoded::at(ch::ANNOTATIONS, t, ch::hazard_annotations(&m.value)),
            ]
        })?;
        self.tap(
            bus,
            HYBRID_TRACKING_STATUS,
            move |m: &Message<HybridTrackingStatus>| {
                vec![Encoded::at(hybrid, m.stamp.as_nanos(), ch::json(&m.value))]
            },
        )?;
        if self.keeps_frames() {
            self.tap(bus, DEPTH_FRAME, |m: &Message<DepthFrame>| {
                let t = m.stamp.as_nanos();
                vec![Encoded {
                    sequence: Some(m.value.frame_index as u32),
                    ..Encoded::at(ch::CAMERA_DEPTH, t, ch::depth_image(&m.value.image, t))
                }]
            })?;
        }
        Ok(())
    }

    fn tap<T: Send + Sync + 'static>(
        &self,
        bus: &Bus,
        topic: Topic<T>,
        encode: impl Fn(&Message<T>) -> Vec<Encoded> + Send + Sync + 'static,
    ) -> Result<(), crate::bus::BusError> {
        let Some(jobs) = self.jobs.clone() else {
            return Ok(());
        };
        let encode = Arc::new(encode);
        bus.tap(
            topic,
            Box::new(move |message: &Arc<Message<T>>| {
                let (message, encode) = (message.clone(), encode.clone());
                let _ = jobs.send(Work::Job(Box::new(move || encode(&message))));
            }),
        )
    }

    /// The end of one step of the loop: the replay's clock.
    pub fn step(&self, record: StepRecord) {
        if self.outputs_only {
            return;
        }
        let t = ns(record.now_s);
        self.send(Box::new(move || {
            vec![Encoded::at(ch::STEP, t, ch::json(&record))]
        }));
    }

    /// What the link received and sent during the step at `now_s`.
    pub fn link(&self, now_s: f64, capture: LinkCapture) {
        if capture == LinkCapture::default() {
            return;
        }
        let t = ns(now_s);
        let inputs = !self.outputs_only;
        self.send(Box::new(move || {
            let received = capture.received.iter().filter(|_| inputs).map(|incoming| {
                let batch = MavlinkBatch::from_incoming(incoming);
                Encoded::at(ch::MAVLINK_IN, t, ch::json(&batch))
            });
            let sent = capture.sent.iter().map(|(header, message)| {
                Encoded::at(
                    ch::MAVLINK_OUT,
                    t,
                    ch::json(&MavlinkRecord::new(header, message)),
                )
            });
            received.chain(sent).collect()
        }));
    }

    /// A camera frame the runner delivered at `now_s`, captured at `capture_s`. Under
    /// `frames = "consumed"` it waits for [`Recorder::frame_read`].
    pub fn frame(&self, now_s: f64, capture_s: f64, frame_index: u64, image: Arc<GrayImage>) {
        if !self.keeps_frames() {
            return;
        }
        let frame = DeliveredFrame {
            now_ns: ns(now_s),
            capture_ns: ns(capture_s),
            index: frame_index,
            image,
            codec: self.codec,
        };
        let read = (self.frames == FramePolicy::Every).then_some(true);
        if let Some(jobs) = &self.jobs {
            let _ = jobs.send(Work::Frame(frame, read));
        }
    }

    /// Whether any task read frame `frame_index`: the runner knows once the next frame
    /// replaces it, or at the end.
    pub fn frame_read(&self, frame_index: u64, read: bool) {
        if self.frames != FramePolicy::Consumed || self.outputs_only {
            return;
        }
        if let Some(jobs) = &self.jobs {
            let _ = jobs.send(Work::FrameRead {
                index: frame_index,
                read,
            });
        }
    }

    /// A plan change the runner takes at `now_s`, before that step's record.
    pub fn plan_request(&self, now_s: f64, request: &crate::mission::PlanRequest) {
        if self.outputs_only {
            return;
        }
        let t = ns(now_s);
        let data = ch::json(request);
        self.send(Box::new(move || {
            vec![Encoded::at(ch::PLAN_REQUEST, t, data)]
        }));
    }

    /// A mission event (phases, landing modes, faults).
    pub fn event(&self, now_s: f64, text: String) {
        let t = ns(now_s);
        self.send(Box::new(move || {
            vec![Encoded::at(ch::EVENTS, t, ch::log_message(t, &text))]
        }));
    }

    /// A governor decision, with its reason.
    pub fn governor(&self, decision: GovernorDecision) {
        let t = ns(decision.time_s);
        self.send(Box::new(move || {
            vec![Encoded::at(ch::GOVERNOR, t, ch::json(&decision))]
        }));
    }

    /// The level every task runs at, whenever one changes.
    pub fn levels(&self, now_s: f64, levels: QosLevels) {
        let t = ns(now_s);
        self.send(Box::new(move || {
            vec![Encoded::at(ch::QOS_LEVELS, t, ch::json(&levels))]
        }));
    }

    /// A battery sample and what the companion draws by the model.
    pub fn battery(&self, now_s: f64, estimate: BatteryEstimate) {
        let t = ns(now_s);
        self.send(Box::new(move || {
            vec![Encoded::at(ch::BATTERY, t, ch::json(&estimate))]
        }));
    }

    /// The tasks' statistics at the end of the run.
    pub fn task_stats(&self, now_s: f64, stats: Vec<TaskStats>) {
        let t = ns(now_s);
        self.send(Box::new(move || {
            vec![Encoded::at(ch::TASK_STATS, t, ch::json(&stats))]
        }));
    }

    /// Writes what is queued, closes the file and says what it holds.
    pub fn finish(mut self) -> Result<RecordingSummary, RecordError> {
        self.close();
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(RecordError::WriterPanicked),
            None => Ok(RecordingSummary::default()),
        }
    }
}

impl Recorder {
    /// Tells the writer thread to write what is queued and close the file.
    fn close(&mut self) {
        if let Some(jobs) = self.jobs.take() {
            let _ = jobs.send(Work::Finish);
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.close();
        if let Some(thread) = self.thread.take() {
            if let Ok(Err(error)) = thread.join() {
                tracing::warn!(%error, "the recording did not finish");
            }
        }
    }
}

/// Every task's level (index) and knob value, by task name.
#[derive(Debug, Clone, PartialEq, Default, Serialize, serde::Deserialize)]
pub struct QosLevels {
    pub tasks: BTreeMap<String, TaskLevelRecord>,
}

#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct TaskLevelRecord {
    pub level: usize,
    pub value: f64,
}

/// A battery reading and the companion's modelled draw at the levels in force.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BatteryEstimate {
    pub telemetry: BatteryTelemetry,
    pub companion_power_w: f64,
}

/// How long queued messages may wait before the chunk is closed: a crash loses at most this
/// much of the flight.
const FLUSH_PERIOD: Duration = Duration::from_secs(1);
/// How long the writer thread lets telemetry gather once it has written all it was given,
/// before it waits on the queue again. Waking a waiting thread is a system call on the
/// sender's side, which every bus message of the loop would otherwise pay: gathered, a step's
/// messages cost one wake (`cargo bench -p sitl --bench record`, `--record-frames none`). A
/// frame is waited for at once: its encoding then fills the time the loop leaves a core idle.
const GATHER_PERIOD: Duration = Duration::from_millis(1);

fn write_loop(
    jobs: mpsc::Receiver<Work>,
    mut writer: McapSink,
    mut live: Option<LiveServer>,
) -> Result<RecordingSummary, RecordError> {
    let mut last_flush = Instant::now();
    let mut hold = FrameHold::new(FLUSH_PERIOD);
    let mut last_was_frame = false;
    loop {
        let work = match jobs.try_recv() {
            Ok(work) => Ok(work),
            Err(mpsc::TryRecvError::Disconnected) => Err(mpsc::RecvTimeoutError::Disconnected),
            Err(mpsc::TryRecvError::Empty) => {
                if !last_was_frame {
                    std::thread::sleep(GATHER_PERIOD);
                }
                jobs.recv_timeout(FLUSH_PERIOD)
            }
        };
        last_was_frame = matches!(work, Ok(Work::Frame(..)));
        match work {
            Ok(Work::Job(job)) => job().into_iter().for_each(|m| hold.message(m)),
            Ok(Work::Frame(frame, read)) => hold.frame(frame, read),
            Ok(Work::FrameRead { index, read }) => hold.mark(index, read),
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Ok(Work::Finish) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        emit(hold.ready(Instant::now()), &mut writer, &mut live)?;
        if last_flush.elapsed() >= FLUSH_PERIOD {
            writer.flush()?;
            last_flush = Instant::now();
        }
    }
    emit(hold.drain(), &mut writer, &mut live)?;
    if let Some(live) = live {
        live.stop();
    }
    writer.finish()
}

/// Writes `messages` to the file and the live view.
fn emit(
    messages: Vec<Encoded>,
    writer: &mut McapSink,
    live: &mut Option<LiveServer>,
) -> Result<(), RecordError> {
    for message in messages {
        if let Some(live) = live {
            live.log(&message);
        }
        writer.write(&message)?;
    }
    Ok(())
}

/// The channels served live over the Foxglove WebSocket protocol.
struct LiveServer {
    context: Arc<foxglove::Context>,
    handle: foxglove::WebSocketServerHandle,
    channels: HashMap<&'static str, Arc<foxglove::RawChannel>>,
    port: u16,
}

impl LiveServer {
    fn start(address: SocketAddr) -> Result<Self, RecordError> {
        let context = foxglove::Context::new();
        let handle = foxglove::WebSocketServer::new()
            .name("qosrt")
            .bind(address.ip().to_string(), address.port())
            .context(&context)
            .start_blocking()
            .map_err(|source| RecordError::Live {
                address,
                source: Box::new(source),
            })?;
        let port = handle.port();
        let mut live = Self {
            context,
            handle,
            channels: HashMap::new(),
            port,
        };
        // Every channel is advertised from the start, so a viewer can subscribe before the
        // first message of each.
        for spec in ch::all_channels() {
            live.channel(spec);
        }
        Ok(live)
    }

    fn channel(&mut self, spec: ChannelSpec) -> Option<Arc<foxglove::RawChannel>> {
        if let Some(channel) = self.channels.get(spec.topic) {
            return Some(channel.clone());
        }
        match foxglove::ChannelBuilder::new(spec.topic)
            .context(&self.context)
            .message_encoding(spec.message_encoding())
            .schema(spec.schema())
            .build_raw()
        {
            Ok(channel) => {
                self.channels.insert(spec.topic, channel.clone());
                Some(channel)
            }
            Err(error) => {
                tracing::warn!(%error, topic = spec.topic, "live channel not served");
                None
            }
        }
    }

    fn log(&mut self, message: &Encoded) {
        if let Some(channel) = self.channel(message.spec) {
            // A viewer shows PNG frames, whatever the file stores them as.
            let data: std::borrow::Cow<'_, [u8]> = match &message.viewer_frame {
                Some(image) => super::frames::png_image(image, message.publish_time_ns).into(),
                None => message.data.as_slice().into(),
            };
            channel.log_with_meta(
                &data,
                foxglove::PartialMetadata {
                    log_time: Some(message.log_time_ns),
                },
            );
        }
    }

    fn stop(self) {
        self.handle.stop().wait_blocking();
    }
}
