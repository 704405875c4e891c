//! The bus topics the built-in tasks exchange, and their message types. One place, so a camera
//! source, the detector and the tracker agree on names and types.

use crate::bus::Topic;
use algorithms::vision::image::GrayImage;
use algorithms::vision::landing_marker::LandingMarkerObservation;
use std::sync::Arc;

/// `topic!(NAME: Message = "name")`: the topic's constant, its message type named once.
macro_rules! topic {
    ($(#[$doc:meta])* $constant:ident: $message:ident = $name:literal) => {
        $(#[$doc])*
        pub const $constant: Topic<$message> = Topic::new($name, stringify!($message));
    };
}

topic!(
    /// Latest camera frame (latest-value topic): a detector always wants the newest image.
    CAMERA_FRAME: CameraFrame = "camera/frame"
);
topic!(
    /// Latest landing-marker observation, one per processed frame.
    LANDING_MARKER: MarkerObservation = "vision/landing_marker"
);

/// One grayscale frame from the downward camera.
#[derive(Debug, Clone)]
pub struct CameraFrame {
    /// Counts frames from the source's start; gaps mean dropped frames.
    pub frame_index: u64,
    pub image: Arc<GrayImage>,
    /// The vehicle's attitude, height and position when the frame was exposed, interpolated
    /// from telemetry by the mission runner that publishes the frame (`None` from the camera
    /// source itself, or before any telemetry): a task placing what it sees on the ground uses
    /// this, not the vehicle as it is when the task gets round to the frame.
    pub vehicle_at_capture: Option<algorithms::estimation::attitude_history::AttitudeSample>,
}

/// What the detector made of one frame.
#[derive(Debug, Clone, serde::Serialize)]
pub struct MarkerObservation {
    pub frame_index: u64,
    /// `None` when the pad was not seen (or the frame could not be read: see `frame_error`).
    pub observation: Option<LandingMarkerObservation>,
    /// Why the frame could not be read, if it could not; the mission goes on without it.
    pub frame_error: Option<String>,
    /// Whether the search was restricted to a region around the previous detection.
    pub used_roi: bool,
}

topic!(
    /// Latest vehicle state from the autopilot (MAVLink ATTITUDE, LOCAL_POSITION_NED, distance
    /// sensor), or from the simulator or a dry run's synthetic vehicle.
    VEHICLE_STATE: VehicleState = "vehicle/state"
);
topic!(
    /// Latest estimate of the UAV's position relative to the platform.
    RELATIVE_STATE: RelativeState = "tracking/relative_state"
);
topic!(
    /// Latest landing setpoint for the autopilot.
    LANDING_SETPOINT: LandingSetpoint = "landing/setpoint"
);

/// What the autopilot says about the vehicle.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct VehicleState {
    pub attitude: algorithms::estimation::projection::Attitude,
    pub velocity_ned_m_s: nalgebra::Vector3<f64>,
    pub acceleration_ned_m_s2: nalgebra::Vector3<f64>,
    /// Height of the camera above the landing pad's surface.
    pub height_above_pad_m: f64,
    /// Local position (MAVLink LOCAL_POSITION_NED: from the home point, down positive), when the
    /// autopilot reports one; the hazard task places what it sees on the ground with it.
    pub position_ned_m: Option<nalgebra::Vector3<f64>>,
    /// The autopilot reports the vehicle on the ground.
    pub landed: bool,
    /// The camera gimbal's attitude (GIMBAL_DEVICE_ATTITUDE_STATUS, as
    /// [`algorithms::estimation::camera_mount`] describes a camera), while it reports.
    pub gimbal_attitude: Option<algorithms::estimation::projection::Attitude>,
    /// The autopilot's last heartbeat says it flies the companion's setpoints (PX4 OFFBOARD,
    /// ArduPilot GUIDED).
    pub offboard: bool,
}

/// The tracker's output.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RelativeState {
    pub estimate: algorithms::estimation::kalman::RelativeEstimate,
    /// The platform's velocity, once two fixes far enough apart have come in.
    pub platform_velocity_ned_m_s: Option<nalgebra::Vector3<f64>>,
    /// When the last accepted vision fix was captured.
    pub last_fix_time_s: Option<f64>,
}

/// The landing logic's output, for the autopilot link.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LandingSetpoint {
    pub mode: algorithms::control::landing::LandingMode,
    pub velocity_setpoint_ned_m_s: nalgebra::Vector3<f64>,
}

topic!(
    /// The mission's current phase, published by the mission runner when a phase begins. Which
    /// tasks run in it is the scheduler's business (a task's `phases`); a task that behaves
    /// differently in the landing reads it.
    MISSION_PHASE: MissionPhase = "mission/phase"
);

/// Which phase of the mission is flying.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MissionPhase {
    /// Index into the config's `[[mission.phase]]`, in flight order.
    pub index: usize,
    pub name: Arc<str>,
    /// The mission's last phase: the one that lands.
    pub landing: bool,
}

topic!(
    /// Latest hazard report, one per frame the hazard CNN processed.
    HAZARDS: HazardReport = "vision/hazards"
);

/// One hazard the CNN saw.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HazardDetection {
    /// Index into the task's `classes`.
    pub class_id: usize,
    pub class_name: Arc<str>,
    pub confidence: f64,
    /// In the frame's pixels.
    pub bbox: algorithms::vision::yolo::PixelBox,
    /// Where the box's centre lies on the ground (local NED, down = 0 at the home point's level);
    /// `None` without a vehicle position or when the pixel looks above the horizon.
    pub position_ned_m: Option<nalgebra::Vector3<f64>>,
}

/// What the hazard CNN made of one frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HazardReport {
    pub frame_index: u64,
    /// When the frame was captured (the camera message's stamp), seconds on the task clock.
    pub capture_time_s: f64,
    pub detections: Vec<HazardDetection>,
    /// The inference backend that ran ("tract-cpu", "onnxruntime-cuda", ...).
    pub backend: &'static str,
    /// Wall time of preprocessing, inference and decoding (a measurement of the machine, not
    /// an output: left out of a recording's outputs, which a replay compares bit for bit).
    #[serde(skip)]
    pub inference_ms: f64,
}

topic!(
    /// Latest pair of PTU readings of the ground stereo rig (seed 001), one per camera frame.
    PTU_PAIR: PtuPairReading = "ground/ptu_pair"
);
topic!(
    /// Latest target position from the ground stereo rig, one per PTU pair read.
    GROUND_STEREO_FIX: GroundStereoFix = "ground/stereo_fix"
);

/// One PTU's pan and tilt and where its tracker sees the target (pixels right of and above the
/// image centre), in the stereo frame of `algorithms::stereo`.
pub use algorithms::stereo::triangulation::PtuReading;

/// Both PTUs' readings for one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PtuPairReading {
    /// When both cameras captured the frame, seconds on the task clock.
    pub time_s: f64,
    pub left: PtuReading,
    pub right: PtuReading,
}

/// What the ground stereo task made of one PTU pair.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundStereoFix {
    /// The readings' capture time.
    pub time_s: f64,
    /// The target in the runway frame, or why this pair gave none (the task carries on).
    pub result: Result<
        algorithms::stereo::triangulation::StereoFix,
        algorithms::stereo::triangulation::TriangulationError,
    >,
    /// Pairs located and pairs refused since the task started.
    pub located: u64,
    pub rejected: u64,
    /// Pairs published while the task was not looking (it runs slower than the cameras).
    pub missed: u64,
}

topic!(
    /// Latest depth frame from the downward stereo camera (seed 000's hybrid camera array), one per
    /// camera frame, with the camera frame's index.
    DEPTH_FRAME: DepthFrame = "camera/depth"
);

/// One depth image: metres along the optical axis, NaN (or any non-positive value) where the
/// stereo matcher found no depth.
#[derive(Debug, Clone)]
pub struct DepthFrame {
    /// The index of the camera frame captured with it.
    pub frame_index: u64,
    pub image: Arc<algorithms::vision::image::DepthImage>,
}

topic!(
    /// Latest status of the `hybrid_tracking` task, one per frame it processed.
    HYBRID_TRACKING_STATUS: HybridTrackingStatus = "tracking/hybrid_status"
);

pub use algorithms::estimation::hybrid_tracking::HybridTrackingStatus;
