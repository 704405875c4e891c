//! What a simulated mission flies with, and how it can fail.

use super::*;

/// One lockstep tick.
pub const TICK_S: f64 = 0.02;
/// The physics step inside a tick.
pub const PHYSICS_DT_S: f64 = 0.005;

/// Faults to inject, as (from, until) in simulated seconds after the tracking phase began.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Faults {
    /// The MAVLink link drops everything both ways.
    pub link_loss: Option<(f64, f64)>,
    /// The camera keeps delivering its last frame.
    pub camera_freeze: Option<(f64, f64)>,
    /// The camera delivers nothing (a stalled pipeline, an unplugged camera).
    pub camera_stall: Option<(f64, f64)>,
}

/// What to fly.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SimOptions {
    /// The world to fly in; its seed is the runtime's too.
    pub world: WorldOptions,
    /// Overrides the duration of the middle phases (the tracking), e.g. to evaluate landings.
    pub tracking_s: Option<f64>,
    /// Tasks held at the level whose knob value is given (the governor leaves them alone).
    pub fixed_levels: Vec<(String, f64)>,
    /// The simulation gives up after this much simulated time; `None`: the configured
    /// mission's length (tracking override included) plus [`TIME_MARGIN_S`].
    pub max_time_s: Option<f64>,
    pub faults: Faults,
    /// Keep a 1 Hz track of vehicle, tractor and battery for plotting.
    pub record_track: bool,
    /// The downward stereo depth camera; it flies only when a task reads depth frames.
    pub stereo: StereoCameraConfig,
    /// Fly on the wall clock: the tasks on the real-time scheduler's threads, the autopilot
    /// streaming as a real one does (no lockstep), the world stepped at the pace of real time.
    /// Not deterministic; this is how the onboard path is flown end to end in one process.
    pub real_time: bool,
    /// Threads a camera frame is rendered on; 0: one per core.
    pub render_threads: usize,
    /// Record the mission to MCAP and/or serve it live to Foxglove.
    pub record: Option<SimRecording>,
    /// Told how far the mission is, once a simulated second.
    pub progress: Option<ProgressSink>,
    /// A real PX4 or ArduPilot flies the world's vehicle (the world its physics backend);
    /// `None`: the built-in autopilot.
    pub autopilot: Option<RealAutopilot>,
    /// Publish the mission on ROS 2 under `/qosrt/<this vehicle>/` (`--ros2`).
    pub ros2_vehicle: Option<String>,
    /// Plan changes a ground station asks for at these mission times (`--plan-change`), as
    /// `qosrt fleet set` would: to see what an operator's change does, deterministically.
    pub plan_changes: Vec<ScheduledPlanChange>,
}

/// A plan change asked for once the mission's clock reaches `at_s`.
#[derive(Debug, Clone, PartialEq)]
pub struct ScheduledPlanChange {
    pub at_s: f64,
    pub request: runtime::mission::PlanRequest,
}

impl std::str::FromStr for ScheduledPlanChange {
    type Err = String;

    /// `AT_S:KEY=VALUE[,KEY=VALUE…]`, e.g. `300:reserve=0.35,hazard=0..1`.
    fn from_str(text: &str) -> Result<Self, String> {
        let (at, changes) = text.split_once(':').ok_or_else(|| {
            format!("expected AT_S:KEY=VALUE[,KEY=VALUE…] (e.g. 300:reserve=0.35), found `{text}`")
        })?;
        let at_s: f64 = at
            .trim()
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite() && *t >= 0.0)
            .ok_or_else(|| format!("`{at}` is not a mission time in seconds ≥ 0"))?;
        let mut request = runtime::mission::PlanRequest::default();
        for change in changes.split(',') {
            request.add_change(change)?;
        }
        Ok(Self { at_s, request })
    }
}

/// How far a flying mission is.
#[derive(Debug, Clone, PartialEq)]
pub struct SimProgress {
    pub time_s: f64,
    /// Where the simulation gives up: the mission's length with a margin.
    pub max_time_s: f64,
    /// The phase in flight (index into the config's phases) and its name; `None` before the
    /// first starts.
    pub phase: Option<(usize, String)>,
    pub phase_count: usize,
    /// Wall time since the mission started flying.
    pub wall_s: f64,
}

/// What a mission reports its progress to (the CLI's progress line).
#[derive(Clone)]
pub struct ProgressSink(pub std::sync::Arc<dyn Fn(&SimProgress) + Send + Sync>);

impl std::fmt::Debug for ProgressSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ProgressSink")
    }
}

impl PartialEq for ProgressSink {
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

/// Where a simulated mission is recorded, and the config files it flies (the recording keeps
/// them, so a replay needs nothing else).
#[derive(Debug, Clone, PartialEq)]
pub struct SimRecording {
    pub recorder: RecorderOptions,
    pub config_files: Vec<ConfigFile>,
}

/// What failed beneath a setup or link error: the underlying error, or a message.
pub type Cause = Box<dyn std::error::Error + Send + Sync>;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("simulation setup: {0}")]
    Setup(#[source] Cause),
    #[error("scheduler: {0}")]
    Scheduler(#[from] runtime::scheduler::SchedulerError),
    #[error("MAVLink: {0}")]
    Link(#[source] Cause),
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error(transparent)]
    Ros2(#[from] runtime::ros2::Ros2Error),
    #[error(
        "the built-in autopilot has no precision landing of its own, and this mission asks for one \
         ([link] landing_target = true, no landing task in the last phase): fly it with \
         --autopilot px4 (-m gazebo-classic_iris_irlock) or --autopilot ardupilot (PLND_ENABLED=1), \
         or give the last phase a landing task"
    )]
    NoPrecisionLanding,
    #[error("--fix {task}={value}: {why}")]
    FixedLevel {
        task: String,
        value: f64,
        why: String,
    },
}

/// Time allowed beyond the configured mission before the simulation gives up: take-off,
/// transit and a few landing attempts.
pub const TIME_MARGIN_S: f64 = 120.0;

/// A setup failure, keeping its cause.
impl From<sim::world::WorldError> for SimError {
    fn from(error: sim::world::WorldError) -> Self {
        setup(error)
    }
}

pub(crate) fn setup(error: impl Into<Cause>) -> SimError {
    SimError::Setup(error.into())
}

/// A link failure, keeping its cause.
pub(crate) fn link_error(error: impl Into<Cause>) -> SimError {
    SimError::Link(error.into())
}
