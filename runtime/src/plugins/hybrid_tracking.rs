//! The `hybrid_tracking` plugin: seed 000's UGV state estimation (§2.2) on the runtime's bus, so
//! `landing_guidance` flies the seed's system instead of the default tracker.
//!
//! Per frame the detector looked at (each [`MarkerObservation`]):
//! 1. **Tracking by detection** (§2.2.1, equations 2–6): the detected pad's centre and apparent
//!    size become a box, its gray histogram (25 bins) the appearance; [`MultiTracker`] assigns
//!    it to Kalman-predicted tracks by the Hungarian algorithm on `0.5·(1 − IoU) + 0.5·s_colour`;
//!    a track is the target once confirmed (false alarms rarely persist). The boxes are tracked
//!    in the pixels of a level, north-facing camera at the UAV ([`level_pixel`]): in the raw
//!    image a tilt of a few degrees moves the pad by tens of pixels in one frame, which the
//!    tracker's constant-velocity prediction cannot follow (its IoU gate then drops the track).
//!    The target's pixel is the detection its track took. A missed detection is bridged: the
//!    track's prediction keeps the association, and the relative position is predicted in the
//!    world frame (3).
//! 2. **Altitude from depth** (§2.2.3, equations 11–14): the mean valid depth of the depth
//!    image's central window (the seed's 100 × 100 of 752 px, as a fraction of the width),
//!    times the cosine of the camera's tilt (the window's depth lies along the optical axis),
//!    through the seed's two-state Kalman filter. With no depth frame, too few valid pixels or
//!    a refused measurement, the altitude falls back to the autopilot's height: a named
//!    [`AltitudeFallback`], counted in [`HybridTrackingStatus`] and logged, never a panic.
//! 3. **Relative position**: the target's pixel, the altitude and the attitude at the frame's
//!    capture give the UAV's position relative to the pad (the projection `kalman_tracker`
//!    uses); between frames, and over missed detections, it is carried forward by the UAV's
//!    velocity less the platform's.
//! 4. **Motion compensation** (§2.2.2, equations 7–10): FAST + steered BRIEF features of the
//!    previous and the current frame (those on the target masked out: they move with it), a
//!    RANSAC homography of the ground, and the target's previous pixel mapped into the current
//!    frame. Below `homography_min_altitude_m` (3 m) the view holds little but the platform,
//!    and the platform's height above the ground whose homography it is biases the result by
//!    the ratio of the two depths (a third at 2 m over a 1 m high pad); there the UAV's own
//!    displacement (the autopilot's velocity) less the change of the relative position gives
//!    the platform's motion instead.
//! 5. **Velocity observer** (equations 15–22): the compensated displacement, scaled by
//!    altitude over focal length, Gaussian-weighted over recent frames, rotated into NED: the
//!    platform's velocity that `landing_guidance` feeds forward (equations 26–27). A motion
//!    faster than `max_ugv_speed_m_s` is a bad match, not the UGV, and is left out.
//!
//! Inputs: `vision/landing_marker`, `camera/frame`, `camera/depth`, `vehicle/state`. Outputs:
//! `tracking/relative_state` (at the task's rate) and `tracking/hybrid_status` (per frame).
//! The camera frames and depth frames are matched to the detector's observations by frame
//! index; the task's period should not exceed the camera's, so that it sees every frame.

use std::collections::VecDeque;

use crate::bus::{Publisher, Subscriber};
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::{Task, TaskBuild, TaskContext, TaskError};
use crate::topics::{
    CameraFrame, DepthFrame, HybridTrackingStatus, MarkerObservation, RelativeState, VehicleState,
    CAMERA_FRAME, DEPTH_FRAME, HYBRID_TRACKING_STATUS, LANDING_MARKER, RELATIVE_STATE,
    VEHICLE_STATE,
};
use algorithms::estimation::kalman::RelativeEstimate;
use algorithms::estimation::projection::{pad_relative_to_uav_ned_m, Attitude};
use algorithms::estimation::stereo_altitude::{
    central_window_altitude, AltitudeFilter, AltitudeFilterConfig, AltitudeWindow,
    StereoAltitudeError,
};
use algorithms::estimation::velocity_observer::{
    instant_motion, Averaging, InstantMotion, PixelMotion, VelocityObserver, VelocityObserverConfig,
};
use algorithms::tracking::histogram::ColourHistogram;
use algorithms::tracking::iou::PixelBox;
use algorithms::tracking::tracker::{BoxDetection, MultiTracker, TargetPolicy, TrackerConfig};
use algorithms::vision::camera::{CameraPose, PinholeCamera};
use algorithms::vision::features::{FeatureConfig, FeatureMatcher, FrameFeatures};
use algorithms::vision::homography::{fit_correspondences, RansacConfig};
use algorithms::vision::landing_marker::LandingMarkerObservation;
use nalgebra::{Matrix3, Vector3};
use serde::Deserialize;
use thiserror::Error;

pub const PLUGIN_NAME: &str = "hybrid_tracking";

/// Camera frames, depth frames and vehicle states kept for matching with late observations.
const FRAME_HISTORY: usize = 8;
const STATE_HISTORY_S: f64 = 2.0;
/// Fallbacks logged at warn level: the first, then one in this many.
const FALLBACK_LOG_EVERY: u64 = 50;

/// `[task.params]` of the plugin; every key is optional, the defaults are the seed's.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// The (rectified) camera the detector looks through.
    #[serde(default = "default_fov")]
    camera_horizontal_fov_deg: f64,
    #[serde(default = "default_width")]
    image_width_px: usize,
    #[serde(default = "default_height")]
    image_height_px: usize,
    /// The pad's side: its box in the image when the detector gives no size.
    #[serde(default = "default_pad_size")]
    pad_size_m: f64,
    /// a1 and a2 of equation 5 (the seed: 0.5 and 0.5).
    #[serde(default = "half")]
    a1_distance: f64,
    #[serde(default = "half")]
    a2_colour: f64,
    /// Pairs costlier than this are never assigned.
    #[serde(default = "default_max_cost")]
    max_cost: f64,
    /// Pairs overlapping the predicted box less than this are never assigned.
    #[serde(default = "default_min_iou")]
    min_iou: f64,
    /// Detections that confirm a track; misses in a row that end one.
    #[serde(default = "default_confirm_hits")]
    confirm_hits: u32,
    #[serde(default = "default_max_misses")]
    max_misses: u32,
    /// The spread of a detection's box, px; also the fix's pixel uncertainty.
    #[serde(default = "default_measurement_std")]
    measurement_std_px: f64,
    /// The box's white acceleration in the tracker's Kalman filter, px/s².
    #[serde(default = "default_acceleration_std")]
    acceleration_std_px_s2: f64,
    /// Side of the central depth window as a fraction of the depth image's width (the seed:
    /// 100 px of 752).
    #[serde(default = "default_window_fraction")]
    altitude_window_fraction: f64,
    /// Fewer valid window pixels than this fraction: no altitude from depth.
    #[serde(default = "default_min_valid")]
    altitude_min_valid_fraction: f64,
    /// Depths outside this range are not measurements. The seed's camera is accurate over
    /// about 0.7–8 m and degrades beyond; the default upper bound is 10 m, not 8, because a
    /// hard cut just above the follow height (7.5 m) would drop the noisy window's upper tail
    /// and bias its mean low.
    #[serde(default = "default_stereo_min")]
    stereo_min_range_m: f64,
    #[serde(default = "default_stereo_max")]
    stereo_max_range_m: f64,
    /// The altitude filter's measurement noise, m.
    #[serde(default = "default_altitude_std")]
    altitude_measurement_std_m: f64,
    /// σ of the velocity observer's Gaussian weights and the window it averages, s.
    #[serde(default = "default_velocity_sigma")]
    velocity_sigma_s: f64,
    #[serde(default = "default_velocity_window")]
    velocity_window_s: f64,
    /// `"speed_and_course"` (the seed's equations 18–19) or `"velocity"` (vector mean).
    #[serde(default)]
    velocity_averaging: AveragingParam,
    /// Below this altitude the motion compensation takes the UAV's own motion from the
    /// autopilot instead of the ground's homography: the ground's features thin out under the
    /// platform, and the platform's height above the ground they lie on biases the compensation
    /// more the lower the UAV flies (see the module docs).
    #[serde(default = "default_homography_min_altitude")]
    homography_min_altitude_m: f64,
    /// An instantaneous motion faster than this is a bad homography or detection, not the UGV
    /// (the seed's UGV: 3 m/s at most); it is left out.
    #[serde(default = "default_max_ugv_speed")]
    max_ugv_speed_m_s: f64,
    /// RANSAC's inlier threshold, px, and the fewest inliers that make a homography.
    #[serde(default = "default_ransac_threshold")]
    ransac_threshold_px: f64,
    #[serde(default = "default_min_inliers")]
    homography_min_inliers: usize,
}

#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
enum AveragingParam {
    #[default]
    SpeedAndCourse,
    Velocity,
}

fn default_fov() -> f64 {
    60.0
}
fn default_width() -> usize {
    640
}
fn default_height() -> usize {
    480
}
fn default_pad_size() -> f64 {
    1.0
}
fn half() -> f64 {
    0.5
}
fn default_max_cost() -> f64 {
    TrackerConfig::default().max_cost
}
fn default_min_iou() -> f64 {
    TrackerConfig::default().min_iou
}
fn default_confirm_hits() -> u32 {
    TrackerConfig::default().confirm_hits
}
fn default_max_misses() -> u32 {
    TrackerConfig::default().max_misses
}
fn default_measurement_std() -> f64 {
    TrackerConfig::default().measurement_std_px
}
fn default_acceleration_std() -> f64 {
    TrackerConfig::default().acceleration_std_px_s2
}
fn default_window_fraction() -> f64 {
    100.0 / 752.0
}
fn default_min_valid() -> f64 {
    AltitudeWindow::default().min_valid_fraction
}
fn default_stereo_min() -> f64 {
    0.7
}
fn default_stereo_max() -> f64 {
    10.0
}
fn default_altitude_std() -> f64 {
    AltitudeFilterConfig::default().measurement_std_m
}
fn default_velocity_sigma() -> f64 {
    VelocityObserverConfig::default().sigma_s
}
fn default_velocity_window() -> f64 {
    VelocityObserverConfig::default().window_s
}
fn default_homography_min_altitude() -> f64 {
    3.0
}
fn default_max_ugv_speed() -> f64 {
    3.0
}
fn default_ransac_threshold() -> f64 {
    RansacConfig::default().threshold_px
}
fn default_min_inliers() -> usize {
    RansacConfig::default().min_inliers
}

/// `[task.params]` that cannot work, named.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HybridTrackingParamsError {
    #[error("camera: {0}")]
    Camera(String),
    #[error("`{name}` = {value} must be {why}")]
    Value {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("tracker: {0}")]
    Tracker(String),
    #[error("altitude filter: {0}")]
    Altitude(String),
    #[error("velocity observer: {0}")]
    Velocity(String),
}

impl From<HybridTrackingParamsError> for TaskError {
    fn from(error: HybridTrackingParamsError) -> Self {
        TaskError::Params(error.to_string())
    }
}

/// Why a frame's altitude came from the autopilot instead of the depth image.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AltitudeFallback {
    #[error("no depth frame for camera frame {frame_index}")]
    NoDepthFrame { frame_index: u64 },
    #[error("depth frame {frame_index}: {source}")]
    Depth {
        frame_index: u64,
        source: StereoAltitudeError,
    },
    #[error("depth frame {frame_index}: the camera looks {tilt_deg:.0}° from straight down")]
    Tilt { frame_index: u64, tilt_deg: f64 },
}

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    super::register_builtin(registry, PLUGIN_NAME, |params: Params, build| {
        Ok(HybridTrackingTask::new(params, Ports::take(build)?)?)
    })
}

/// What the previous processed frame left for motion compensation.
struct PreviousFrame {
    time_s: f64,
    features: Option<FrameFeatures>,
    /// The UAV's position relative to the target, when a detection gave it in that frame.
    uav_relative_ned_m: Option<Vector3<f64>>,
    /// The target's centre, when a detection confirmed it in that frame.
    target_px: Option<(f64, f64)>,
}

/// The relative position at a frame's capture.
#[derive(Debug, Clone, Copy)]
struct Fix {
    time_s: f64,
    uav_relative_ned_m: Vector3<f64>,
    horizontal_std_m: f64,
    vertical_std_m: f64,
}

pub struct HybridTrackingTask {
    camera: PinholeCamera,
    pad_size_m: f64,
    measurement_std_px: f64,
    homography_min_altitude_m: f64,
    max_ugv_speed_m_s: f64,
    window_fraction: f64,
    window: AltitudeWindow,
    altitude_filter_config: AltitudeFilterConfig,
    altitude_filter: AltitudeFilter,
    tracker: MultiTracker,
    matcher: FeatureMatcher,
    ransac: RansacConfig,
    observer: VelocityObserver,
    frames: VecDeque<CameraFrame>,
    depths: VecDeque<DepthFrame>,
    states: VecDeque<(f64, VehicleState)>,
    previous: Option<PreviousFrame>,
    fix: Option<Fix>,
    last_fix_time_s: Option<f64>,
    platform_velocity_ned_m_s: Option<Vector3<f64>>,
    status: HybridTrackingStatus,
    /// Fallbacks in flight (the ones worth a warning).
    airborne_fallbacks: u64,
    ports: Ports,
}

/// The task's ends on the bus.
struct Ports {
    vehicle: Subscriber<VehicleState>,
    frames: Subscriber<CameraFrame>,
    depths: Subscriber<DepthFrame>,
    markers: Subscriber<MarkerObservation>,
    output: Publisher<RelativeState>,
    status: Publisher<HybridTrackingStatus>,
}

impl Ports {
    fn take(build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        Ok(Ports {
            vehicle: build.input(VEHICLE_STATE)?,
            frames: build.input(CAMERA_FRAME)?,
            depths: build.input(DEPTH_FRAME)?,
            markers: build.input(LANDING_MARKER)?,
            output: build.output(RELATIVE_STATE)?,
            status: build.output(HYBRID_TRACKING_STATUS)?,
        })
    }
}

impl HybridTrackingTask {
    fn new(params: Params, ports: Ports) -> Result<Self, HybridTrackingParamsError> {
        let value = |name, value: f64, why| HybridTrackingParamsError::Value { name, value, why };
        let camera = PinholeCamera::from_fov(
            params.image_width_px,
            params.image_height_px,
            params.camera_horizontal_fov_deg.to_radians(),
        )
        .map_err(|e| HybridTrackingParamsError::Camera(e.to_string()))?;
        if !(params.homography_min_altitude_m.is_finite()
            && params.homography_min_altitude_m >= 0.0)
        {
            return Err(value(
                "homography_min_altitude_m",
                params.homography_min_altitude_m,
                "finite and not negative",
            ));
        }
        for (name, v) in [
            ("max_ugv_speed_m_s", params.max_ugv_speed_m_s),
            ("pad_size_m", params.pad_size_m),
            ("measurement_std_px", params.measurement_std_px),
            ("stereo_min_range_m", params.stereo_min_range_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(value(name, v, "positive and finite"));
            }
        }
        if !(params.altitude_window_fraction > 0.0 && params.altitude_window_fraction <= 1.0) {
            return Err(value(
                "altitude_window_fraction",
                params.altitude_window_fraction,
                "within (0, 1]",
            ));
        }
        if !(0.0..=1.0).contains(&params.altitude_min_valid_fraction) {
            return Err(value(
                "altitude_min_valid_fraction",
                params.altitude_min_valid_fraction,
                "within [0, 1]",
            ));
        }
        if params.stereo_max_range_m.is_nan()
            || params.stereo_max_range_m <= params.stereo_min_range_m
        {
            return Err(value(
                "stereo_max_range_m",
                params.stereo_max_range_m,
                "above stereo_min_range_m",
            ));
        }
        if !(params.ransac_threshold_px.is_finite() && params.ransac_threshold_px > 0.0) {
            return Err(value(
                "ransac_threshold_px",
                params.ransac_threshold_px,
                "positive and finite",
            ));
        }
        if params.homography_min_inliers < 4 {
            return Err(value(
                "homography_min_inliers",
                params.homography_min_inliers as f64,
                "at least 4",
            ));
        }
        let tracker_config = TrackerConfig {
            a1_distance: params.a1_distance,
            a2_colour: params.a2_colour,
            max_cost: params.max_cost,
            min_iou: params.min_iou,
            confirm_hits: params.confirm_hits,
            max_misses: params.max_misses,
            measurement_std_px: params.measurement_std_px,
            acceleration_std_px_s2: params.acceleration_std_px_s2,
            ..TrackerConfig::default()
        };
        let tracker = MultiTracker::new(tracker_config)
            .map_err(|e| HybridTrackingParamsError::Tracker(e.to_string()))?;
        let altitude_filter_config = AltitudeFilterConfig {
            measurement_std_m: params.altitude_measurement_std_m,
            ..AltitudeFilterConfig::default()
        };
        let altitude_filter = AltitudeFilter::new(altitude_filter_config)
            .map_err(|e| HybridTrackingParamsError::Altitude(e.to_string()))?;
        let observer = VelocityObserver::new(VelocityObserverConfig {
            sigma_s: params.velocity_sigma_s,
            window_s: params.velocity_window_s,
            averaging: match params.velocity_averaging {
                AveragingParam::SpeedAndCourse => Averaging::SpeedAndCourse,
                AveragingParam::Velocity => Averaging::Velocity,
            },
        })
        .map_err(|e| HybridTrackingParamsError::Velocity(e.to_string()))?;
        Ok(Self {
            camera,
            pad_size_m: params.pad_size_m,
            measurement_std_px: params.measurement_std_px,
            homography_min_altitude_m: params.homography_min_altitude_m,
            max_ugv_speed_m_s: params.max_ugv_speed_m_s,
            window_fraction: params.altitude_window_fraction,
            window: AltitudeWindow {
                width_px: 1,
                height_px: 1,
                min_valid_fraction: params.altitude_min_valid_fraction,
                min_depth_m: params.stereo_min_range_m,
                max_depth_m: params.stereo_max_range_m,
            },
            altitude_filter_config,
            altitude_filter,
            tracker,
            matcher: FeatureMatcher::new(FeatureConfig::default()),
            ransac: RansacConfig {
                threshold_px: params.ransac_threshold_px,
                min_inliers: params.homography_min_inliers,
                ..RansacConfig::default()
            },
            observer,
            frames: VecDeque::new(),
            depths: VecDeque::new(),
            states: VecDeque::new(),
            previous: None,
            fix: None,
            last_fix_time_s: None,
            platform_velocity_ned_m_s: None,
            status: HybridTrackingStatus::default(),
            airborne_fallbacks: 0,
            ports,
        })
    }

    /// The vehicle state nearest `time_s` in the history.
    fn state_at(&self, time_s: f64) -> Option<VehicleState> {
        self.states
            .iter()
            .min_by(|a, b| (a.0 - time_s).abs().total_cmp(&(b.0 - time_s).abs()))
            .map(|(_, state)| *state)
    }

    /// The UAV's displacement from `from_s` to `to_s` by its reported velocities (each state's
    /// velocity held until the next).
    fn uav_displacement_m(&self, from_s: f64, to_s: f64) -> Vector3<f64> {
        let mut displacement = Vector3::zeros();
        let mut states = self.states.iter().peekable();
        while let Some((t, state)) = states.next() {
            let until = states.peek().map_or(to_s, |(next, _)| next.min(to_s));
            let start = t.max(from_s);
            if until > start {
                displacement += state.velocity_ned_m_s * (until - start);
            }
        }
        // Before the oldest state in the history: its velocity.
        if let Some((oldest, state)) = self.states.front() {
            if from_s < *oldest {
                displacement += state.velocity_ned_m_s * (oldest.min(to_s) - from_s);
            }
        }
        displacement
    }

    /// The altitude above the pad for camera frame `frame_index`, captured at `time_s` with the
    /// vehicle in `state`: from the depth image, or why not.
    fn depth_altitude_m(
        &mut self,
        frame_index: u64,
        time_s: f64,
        attitude: &Attitude,
    ) -> Result<f64, AltitudeFallback> {
        let depth = self
            .depths
            .iter()
            .find(|d| d.frame_index == frame_index)
            .ok_or(AltitudeFallback::NoDepthFrame { frame_index })?;
        let image = &depth.image;
        let side = (self.window_fraction * image.width() as f64)
            .round()
            .max(1.0) as usize;
        let window = AltitudeWindow {
            width_px: side,
            height_px: side,
            ..self.window
        };
        let sample =
            central_window_altitude(image, &window).map_err(|source| AltitudeFallback::Depth {
                frame_index,
                source,
            })?;
        // The window looks along the optical axis, the body's down axis: its depth is the
        // height over the cosine of the tilt.
        let cos_tilt = attitude.cos_tilt();
        if cos_tilt < 0.5 {
            return Err(AltitudeFallback::Tilt {
                frame_index,
                tilt_deg: attitude.tilt_rad().to_degrees(),
            });
        }
        let estimate = self
            .altitude_filter
            .update(time_s, sample.altitude_m * cos_tilt)
            .map_err(|source| AltitudeFallback::Depth {
                frame_index,
                source,
            })?;
        Ok(estimate.altitude_m)
    }

    /// The detector's observation as the tracker's detection: a box around the pad's centre,
    /// its side the pad's apparent size (the detector's when it agrees with the pad's side at
    /// this altitude within −30 %/+40 %, else the latter), grown to hold the pad at its
    /// orientation; `None` when the box holds no pixel.
    fn detection(
        &self,
        observation: &LandingMarkerObservation,
        image: &algorithms::vision::image::GrayImage,
        altitude_m: f64,
        attitude: &Attitude,
    ) -> Option<Detection> {
        let [u, v] = observation.centre_px;
        // The detector's size comes from whichever ArUco markers it read, and one marker seen
        // at a slant can make it several times too large or small: a size far from what the
        // pad's side and the altitude say is not trusted.
        let expected_px = self.pad_size_m * self.camera.fx_px / altitude_m;
        let side_px = observation
            .pad_size_px
            .filter(|s| (0.7 * expected_px..=1.4 * expected_px).contains(s))
            .unwrap_or(expected_px);
        let grow = observation
            .orientation_rad
            .map_or(1.0, |a| a.cos().abs() + a.sin().abs());
        let side_px = side_px * grow;
        let bbox = PixelBox::from_centre(u, v, side_px, side_px);
        let histogram = ColourHistogram::of_gray_box(&image.view(), &bbox).ok()?;
        let (level_u, level_v) = level_pixel(&self.camera, attitude, u, v)?;
        Some(Detection {
            tracked: BoxDetection {
                bbox: PixelBox::from_centre(level_u, level_v, side_px, side_px),
                histogram,
            },
            centre_px: (u, v),
            bbox,
        })
    }

    /// One frame the detector looked at.
    fn process(
        &mut self,
        ctx: &TaskContext<'_>,
        message: &MarkerObservation,
        time_s: f64,
    ) -> Result<(), TaskError> {
        if let Some(previous) = &self.previous {
            if time_s <= previous.time_s {
                return Ok(());
            }
        }
        let Some(state) = self.state_at(time_s) else {
            return Ok(());
        };
        self.status.frames += 1;
        let frame = self
            .frames
            .iter()
            .find(|f| f.frame_index == message.frame_index)
            .cloned();
        let altitude_m = match self.depth_altitude_m(message.frame_index, time_s, &state.attitude) {
            Ok(altitude_m) => {
                self.status.depth_altitudes += 1;
                self.status.altitude_from_depth = true;
                altitude_m
            }
            Err(fallback) => {
                self.status.depth_fallbacks += 1;
                self.status.altitude_from_depth = false;
                // On the ground, in the take-off and in the last of the landing the stereo
                // camera is too near to measure: expected, not worth a warning.
                let near = |height_m: f64| height_m < 1.5 * self.window.min_depth_m;
                let airborne = !state.landed
                    && !near(state.height_above_pad_m)
                    && !self
                        .altitude_filter
                        .estimate()
                        .is_some_and(|e| near(e.altitude_m) && time_s - e.time_s < 2.0);
                if !airborne {
                    tracing::debug!(task = ctx.name(), reason = %fallback, "altitude from the autopilot");
                } else {
                    self.airborne_fallbacks += 1;
                }
                if airborne && self.airborne_fallbacks % FALLBACK_LOG_EVERY == 1 {
                    tracing::warn!(
                        task = ctx.name(),
                        fallbacks = self.status.depth_fallbacks,
                        reason = %fallback,
                        "altitude from the autopilot's height, not the stereo depth"
                    );
                }
                self.status.last_depth_error = Some(fallback.to_string());
                state.height_above_pad_m
            }
        };
        self.status.altitude_m = Some(altitude_m);
        if !(altitude_m.is_finite() && altitude_m > 0.0) {
            // Nothing to scale pixels with (on the ground, or bad telemetry): skip the frame.
            return Ok(());
        }
        let detections: Vec<Detection> = match (&message.observation, &frame) {
            (Some(observation), Some(frame)) => self
                .detection(observation, &frame.image, altitude_m, &state.attitude)
                .into_iter()
                .collect(),
            _ => Vec::new(),
        };
        let tracked: Vec<BoxDetection> = detections.iter().map(|d| d.tracked.clone()).collect();
        let dt_s = self
            .previous
            .as_ref()
            .map_or(0.1, |p| (time_s - p.time_s).max(1e-3));
        self.tracker
            .step(dt_s, &tracked)
            .map_err(|e| TaskError::failed(format!("tracker: {e}")))?;
        let target = self
            .tracker
            .select_target(TargetPolicy::MostHits)
            .map(|t| t.detection_index());
        let Some(matched) = target else {
            // No confirmed target: the velocity history ends here.
            self.observer.reset();
            self.previous = Some(PreviousFrame {
                time_s,
                features: None,
                target_px: None,
                uav_relative_ned_m: None,
            });
            self.publish_status();
            return Ok(());
        };
        // The target's pixel is the detection its track took, in the frame's own pixels as the
        // projection needs them (the track's box is in level pixels, and filtered). A frame
        // whose detection is missing is bridged in the world frame: the last fix is carried
        // forward by the UAV's and the platform's velocities (see `step`), while the track's
        // prediction keeps the association.
        let detection = matched.and_then(|index| detections.get(index));
        let detected_px = detection.map(|d| d.centre_px);
        match detected_px {
            Some((u, v)) => {
                self.status.detections += 1;
                self.last_fix_time_s = Some(time_s);
                if let Ok(pad_relative) =
                    pad_relative_to_uav_ned_m(&self.camera, &state.attitude, altitude_m, u, v)
                {
                    self.fix = Some(Fix {
                        time_s,
                        uav_relative_ned_m: -pad_relative,
                        horizontal_std_m: self.measurement_std_px * altitude_m / self.camera.fx_px,
                        vertical_std_m: self.altitude_filter_config.measurement_std_m,
                    });
                }
            }
            None => self.status.bridged += 1,
        }
        // The platform's motion between this frame and the previous one, when the target was
        // detected in both: from high enough up by the seed's motion compensation (the
        // homography of the ground between the frames), lower down by the UAV's own motion.
        let homography_altitude = altitude_m >= self.homography_min_altitude_m;
        let features = frame
            .as_ref()
            .zip(detection)
            .filter(|_| homography_altitude)
            .map(|(f, d)| {
                let mut features = self.matcher.features(&f.image.view());
                mask_out(&mut features, &d.bbox, 1.2);
                features
            });
        let previous = self.previous.take();
        let instant = match (&previous, detected_px, self.fix) {
            (Some(p), Some(current_px), Some(fix)) if p.target_px.is_some() => {
                let dt_s = time_s - p.time_s;
                match (&p.features, &features) {
                    (Some(previous_features), Some(current_features)) => self.compensated_motion(
                        ctx,
                        previous_features,
                        current_features,
                        p.target_px.unwrap_or(current_px),
                        current_px,
                        altitude_m,
                        dt_s,
                    ),
                    _ => p.uav_relative_ned_m.and_then(|previous_relative| {
                        self.ego_motion(
                            previous_relative,
                            fix.uav_relative_ned_m,
                            p.time_s,
                            time_s,
                            state.attitude.yaw_rad,
                        )
                    }),
                }
            }
            _ => None,
        };
        if let Some(instant) = instant {
            if instant.speed_m_s > self.max_ugv_speed_m_s {
                self.status.velocity_rejected += 1;
            } else if let Ok(velocity) =
                self.observer
                    .update(time_s, &instant, state.attitude.yaw_rad)
            {
                self.status.velocity_samples += 1;
                self.platform_velocity_ned_m_s = Some(Vector3::new(
                    velocity.velocity_ned_m_s.x,
                    velocity.velocity_ned_m_s.y,
                    0.0,
                ));
            }
        }
        self.previous = Some(PreviousFrame {
            time_s,
            features,
            target_px: detected_px,
            uav_relative_ned_m: detected_px.and(self.fix.map(|f| f.uav_relative_ned_m)),
        });
        self.publish_status();
        Ok(())
    }

    /// Equations 7–10 and 15–17: the homography of the ground from the previous frame's
    /// features to the current one's maps the target's previous pixel into the current frame;
    /// what is left to its current pixel is its own motion.
    #[allow(clippy::too_many_arguments)]
    fn compensated_motion(
        &mut self,
        ctx: &TaskContext<'_>,
        previous: &FrameFeatures,
        current: &FrameFeatures,
        previous_px: (f64, f64),
        current_px: (f64, f64),
        altitude_m: f64,
        dt_s: f64,
    ) -> Option<InstantMotion> {
        let matches = self.matcher.correspondences(previous, current);
        let fit = match fit_correspondences(&matches, &self.ransac) {
            Ok(fit) => fit,
            Err(error) => {
                self.status.homography_failures += 1;
                self.status.last_homography_error = Some(error.to_string());
                tracing::debug!(task = ctx.name(), %error, "no motion compensation");
                return None;
            }
        };
        let mapped = fit.homography.map(previous_px.0, previous_px.1)?;
        let motion = PixelMotion {
            previous_mapped_px: mapped,
            current_px,
        };
        self.status.homography_motions += 1;
        instant_motion(&motion, altitude_m, self.camera.fx_px, dt_s).ok()
    }

    /// The same motion where the ground's features are too few (low over the platform): the
    /// UAV's displacement by its reported velocity, less the change of its position relative to
    /// the target, as the instantaneous motion the observer takes.
    fn ego_motion(
        &mut self,
        previous_relative_ned_m: Vector3<f64>,
        relative_ned_m: Vector3<f64>,
        previous_s: f64,
        time_s: f64,
        yaw_rad: f64,
    ) -> Option<InstantMotion> {
        let dt_s = time_s - previous_s;
        if dt_s.is_nan() || dt_s <= 0.0 {
            return None;
        }
        let displacement = (self.uav_displacement_m(previous_s, time_s)
            - (relative_ned_m - previous_relative_ned_m))
            .xy();
        let velocity_ned = displacement / dt_s;
        // Body axes (x forward, y right) for the observer, which rotates back by the yaw.
        let (sin, cos) = yaw_rad.sin_cos();
        let velocity_body = nalgebra::Vector2::new(
            cos * velocity_ned.x + sin * velocity_ned.y,
            -sin * velocity_ned.x + cos * velocity_ned.y,
        );
        self.status.ego_motions += 1;
        Some(InstantMotion {
            displacement_px: f64::NAN,
            displacement_m: displacement.norm(),
            speed_m_s: velocity_ned.norm(),
            heading_body_rad: velocity_body.y.atan2(velocity_body.x),
            velocity_body_m_s: velocity_body,
        })
    }

    fn publish_status(&self) {
        let stamp = crate::clock::Timestamp::from_secs_f64(
            self.previous.as_ref().map_or(0.0, |p| p.time_s),
        );
        self.ports.status.publish(stamp, self.status.clone());
    }
}

/// The pixel at which a level camera facing north, at the same place, would see what `camera`
/// on a vehicle at `attitude` sees at (u, v): the tracker works in these coordinates, where the
/// target moves only as the UAV and the platform move, not as the UAV tilts. `None` for a pixel
/// at or above the horizon.
fn level_pixel(camera: &PinholeCamera, attitude: &Attitude, u: f64, v: f64) -> Option<(f64, f64)> {
    let (x, y) = camera.normalized(u, v);
    let tilted = CameraPose::downward(
        Vector3::zeros(),
        attitude.roll_rad,
        attitude.pitch_rad,
        attitude.yaw_rad,
    );
    let level = CameraPose::downward(Vector3::zeros(), 0.0, 0.0, 0.0);
    let world = tilted.camera_to_world.rotation * Vector3::new(x, y, 1.0);
    let ray = level.camera_to_world.rotation.inverse() * world;
    (ray.z > 1e-6).then(|| {
        (
            camera.cx_px + camera.fx_px * ray.x / ray.z,
            camera.cy_px + camera.fy_px * ray.y / ray.z,
        )
    })
}

/// A detection: as the tracker sees it (its box in level-camera pixels, see [`level_pixel`],
/// with the appearance of its box in the frame), and where it is in the frame.
struct Detection {
    tracked: BoxDetection,
    centre_px: (f64, f64),
    bbox: PixelBox,
}

/// Drops the keypoints inside `bbox` grown by `grow` about its centre: on the target, they move
/// with it, not with the ground.
fn mask_out(features: &mut FrameFeatures, bbox: &PixelBox, grow: f64) {
    let (cx, cy) = bbox.centre();
    let half_w = 0.5 * grow * (bbox.x_max - bbox.x_min);
    let half_h = 0.5 * grow * (bbox.y_max - bbox.y_min);
    let keep: Vec<bool> = features
        .keypoints
        .iter()
        .map(|k| (k.x_px - cx).abs() > half_w || (k.y_px - cy).abs() > half_h)
        .collect();
    let mut flags = keep.iter();
    features
        .keypoints
        .retain(|_| *flags.next().unwrap_or(&true));
    let mut flags = keep.iter();
    features
        .descriptors
        .retain(|_| *flags.next().unwrap_or(&true));
}

impl Task for HybridTrackingTask {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let Ports {
            vehicle,
            frames,
            depths,
            markers,
            ..
        } = &mut self.ports;
        let now_s = ctx.now().as_secs_f64();
        if let Some(message) = vehicle.take_new() {
            self.states
                .push_back((message.stamp.as_secs_f64(), message.value));
        }
        while self
            .states
            .front()
            .is_some_and(|(t, _)| now_s - t > STATE_HISTORY_S)
            && self.states.len() > 1
        {
            self.states.pop_front();
        }
        if let Some(message) = frames.take_new() {
            self.frames.push_back(message.value.clone());
            if self.frames.len() > FRAME_HISTORY {
                self.frames.pop_front();
            }
        }
        if let Some(message) = depths.take_new() {
            self.depths.push_back(message.value.clone());
            if self.depths.len() > FRAME_HISTORY {
                self.depths.pop_front();
            }
        }
        let observation = markers.take_new();
        if let Some(message) = observation {
            let time_s = message.stamp.as_secs_f64();
            self.process(ctx, &message.value, time_s)?;
        }
        let Some(fix) = self.fix else {
            return Ok(());
        };
        let output = &self.ports.output;
        // Carried forward from the capture: the UAV moved, the platform moved.
        let elapsed_s = (now_s - fix.time_s).max(0.0);
        let platform = self
            .platform_velocity_ned_m_s
            .unwrap_or_else(Vector3::zeros);
        let relative = fix.uav_relative_ned_m + self.uav_displacement_m(fix.time_s, now_s)
            - platform * elapsed_s;
        let horizontal = fix.horizontal_std_m.hypot(0.1 * elapsed_s);
        let covariance = Matrix3::from_diagonal(&Vector3::new(
            horizontal * horizontal,
            horizontal * horizontal,
            fix.vertical_std_m.powi(2),
        ));
        output.publish(
            ctx.now(),
            RelativeState {
                estimate: RelativeEstimate {
                    time_s: now_s,
                    uav_relative_ned_m: relative,
                    covariance_m2: covariance,
                },
                platform_velocity_ned_m_s: self.platform_velocity_ned_m_s,
                last_fix_time_s: self.last_fix_time_s,
            },
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    //! The plugin on the bus in virtual time, fed by a world that renders a pad driving under a
    //! hovering UAV: frames, exact depth (or none, or all holes), the autopilot's state and,
    //! where the test controls detections, the detector's observations.

    use super::*;
    use crate::bus::Publisher;
    use crate::catalog::{PluginInfo, Port};
    use crate::config::{Knob, Resource, TaskConfig};
    use crate::scheduler::SchedulerBuilder;
    use algorithms::vision::camera::CameraPose;
    use algorithms::vision::image::{DepthImage, GrayImage};
    use algorithms::vision::landing_marker::{CentreSource, LandingMarkerLayout};
    use algorithms::vision::render::{
        render, render_depth, true_pixel, RenderOptions, Scene, Texture,
    };
    use nalgebra::Point3;
    use std::sync::Arc;
    use std::time::Duration;

    #[derive(Debug, Clone, Copy, PartialEq)]
    enum DepthMode {
        Exact,
        /// Every pixel a hole.
        AllNan,
        /// No depth frames at all.
        Missing,
    }

    /// The world: a UAV hovering at `uav_ned_m`, a pad on the ground driving at constant
    /// velocity.
    #[derive(Debug, Clone)]
    struct WorldConfig {
        /// Where the UAV is at t = 0, and its constant velocity.
        uav_ned_m: Vector3<f64>,
        uav_velocity_ned_m_s: Vector3<f64>,
        attitude: Attitude,
        pad_start_ne_m: [f64; 2],
        pad_velocity_ne_m_s: [f64; 2],
        /// What the autopilot reports as the height above the pad.
        autopilot_height_m: f64,
        depth: DepthMode,
        /// `Some(dropped)`: the world publishes the detector's observations itself (the pad's
        /// true centre and size) except in the frames listed; `None`: a detector task does.
        observations: Option<Vec<u64>>,
    }

    impl WorldConfig {
        fn hovering(depth: DepthMode) -> Self {
            Self {
                uav_ned_m: Vector3::new(0.0, 0.0, -6.0),
                uav_velocity_ned_m_s: Vector3::zeros(),
                attitude: Attitude::new(0.03, -0.02, 0.4),
                pad_start_ne_m: [0.3, -1.0],
                pad_velocity_ne_m_s: [0.0, 0.5],
                autopilot_height_m: 6.0,
                depth,
                observations: None,
            }
        }

        fn pad_ne_m(&self, time_s: f64) -> [f64; 2] {
            [
                self.pad_start_ne_m[0] + self.pad_velocity_ne_m_s[0] * time_s,
                self.pad_start_ne_m[1] + self.pad_velocity_ne_m_s[1] * time_s,
            ]
        }

        fn uav_at(&self, time_s: f64) -> Vector3<f64> {
            self.uav_ned_m + self.uav_velocity_ned_m_s * time_s
        }

        /// UAV − pad, NED: what the plugin estimates.
        fn truth_ned_m(&self, time_s: f64) -> Vector3<f64> {
            let [n, e] = self.pad_ne_m(time_s);
            self.uav_at(time_s) - Vector3::new(n, e, 0.0)
        }

        fn pose(&self, time_s: f64) -> CameraPose {
            let a = &self.attitude;
            CameraPose::downward(self.uav_at(time_s), a.roll_rad, a.pitch_rad, a.yaw_rad)
        }
    }

    struct World {
        config: WorldConfig,
        frame_index: u64,
        camera: PinholeCamera,
        depth_camera: PinholeCamera,
        state: Option<Publisher<VehicleState>>,
        frames: Option<Publisher<CameraFrame>>,
        depths: Option<Publisher<DepthFrame>>,
        markers: Option<Publisher<MarkerObservation>>,
    }

    /// The test world's plugin: it publishes what the mission would, and the detector's
    /// observations when the world scripts them.
    const WORLD: PluginInfo = PluginInfo {
        outputs: &[
            Port::of(VEHICLE_STATE),
            Port::of(CAMERA_FRAME),
            Port::of(DEPTH_FRAME),
            Port::of(LANDING_MARKER),
        ],
        ..PluginInfo::user("test_world")
    };

    impl World {
        fn new(config: WorldConfig, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
            let markers = match config.observations {
                Some(_) => Some(build.output(LANDING_MARKER)?),
                None => None,
            };
            Ok(Self {
                config,
                frame_index: 0,
                camera: PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap(),
                depth_camera: PinholeCamera::from_fov(160, 120, 60f64.to_radians()).unwrap(),
                state: Some(build.output(VEHICLE_STATE)?),
                frames: Some(build.output(CAMERA_FRAME)?),
                depths: Some(build.output(DEPTH_FRAME)?),
                markers,
            })
        }
    }

    impl Task for World {
        fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
            let c = &self.config;
            let now = ctx.now();
            let t = now.as_secs_f64();
            self.state.as_ref().unwrap().publish(
                now,
                VehicleState {
                    attitude: c.attitude,
                    velocity_ned_m_s: c.uav_velocity_ned_m_s,
                    acceleration_ned_m_s2: Vector3::zeros(),
                    height_above_pad_m: c.autopilot_height_m,
                    position_ned_m: Some(c.uav_at(t)),
                    landed: false,
                    gimbal_attitude: None,
                    offboard: true,
                },
            );
            let [pad_n, pad_e] = c.pad_ne_m(t);
            let mut scene = Scene::new(Texture::field(5));
            scene.patches = LandingMarkerLayout::default()
                .patches(pad_n, pad_e, 0.0, 0.0)
                .unwrap();
            let pose = c.pose(t);
            let options = RenderOptions {
                supersampling: 1,
                ..RenderOptions::default()
            };
            let image = render(&self.camera, &pose, &scene, &options).unwrap();
            self.frames.as_ref().unwrap().publish(
                now,
                CameraFrame {
                    vehicle_at_capture: None,
                    frame_index: self.frame_index,
                    image: Arc::new(image),
                },
            );
            let depth = match c.depth {
                DepthMode::Exact => Some(render_depth(&self.depth_camera, &pose, &scene).unwrap()),
                DepthMode::AllNan => Some(DepthImage::filled(160, 120, f32::NAN).unwrap()),
                DepthMode::Missing => None,
            };
            if let Some(depth) = depth {
                self.depths.as_ref().unwrap().publish(
                    now,
                    DepthFrame {
                        frame_index: self.frame_index,
                        image: Arc::new(depth),
                    },
                );
            }
            if let (Some(dropped), Some(markers)) = (&c.observations, &self.markers) {
                let project = |n: f64, e: f64| {
                    true_pixel(&self.camera, &pose, &Point3::new(n, e, 0.0)).unwrap()
                };
                let (u, v) = project(pad_n, pad_e);
                let (u1, _) = project(pad_n, pad_e + 0.5);
                let (u0, _) = project(pad_n, pad_e - 0.5);
                let observation =
                    (!dropped.contains(&self.frame_index)).then(|| LandingMarkerObservation {
                        centre_px: [u, v],
                        orientation_rad: None,
                        centre_from: CentreSource::Nfold,
                        nfold: None,
                        aruco: Vec::new(),
                        homography: None,
                        pad_size_px: Some((u1 - u0).abs()),
                    });
                markers.publish(
                    now,
                    MarkerObservation {
                        frame_index: self.frame_index,
                        observation,
                        frame_error: None,
                        used_roi: false,
                    },
                );
            }
            self.frame_index += 1;
            Ok(())
        }
    }

    fn task_config(name: &str, plugin: &str, knob: Knob, level: f64, params: &str) -> TaskConfig {
        TaskConfig {
            name: name.into(),
            plugin: plugin.into(),
            resource: Resource::Cpu,
            cores: vec![],
            phases: vec!["landing".into()],
            weight: 1.0,
            knob,
            levels: vec![level],
            utility: vec![1.0],
            restart: None,
            params: toml::from_str(params).unwrap(),
            config_dir: None,
        }
    }

    /// What a run leaves: the relative state halfway between frames (`relative[k]` at
    /// 0.1·k + 0.05 s, after frame k), and the status.
    struct Run {
        relative: Vec<Option<RelativeState>>,
        status: HybridTrackingStatus,
        failures: u64,
    }

    /// Flies `world` for `frames` camera frames (10 fps) with the hybrid tracker at 50 Hz, and
    /// the landing-marker detector at 10 fps unless the world publishes the observations.
    fn fly(world: WorldConfig, frames: usize) -> Run {
        let mut registry = crate::plugins::builtin_registry().unwrap();
        let for_factory = world.clone();
        let detector = world.observations.is_none();
        registry
            .register_plugin(WORLD, move |build| {
                Ok(Box::new(World::new(for_factory.clone(), build)?))
            })
            .unwrap();
        let world_task = task_config("world", "test_world", Knob::RateFps, 10.0, "");
        let detection = task_config("detection", "landing_marker", Knob::RateFps, 10.0, "");
        let tracking = task_config("tracking", PLUGIN_NAME, Knob::PeriodMs, 20.0, "");
        let mut builder = SchedulerBuilder::new(&registry);
        builder.task(&world_task);
        if detector {
            builder.task(&detection);
        }
        builder.task(&tracking);
        let mut scheduler = builder.build_virtual().unwrap();
        let mut relative = scheduler
            .bus()
            .subscriber::<RelativeState>(RELATIVE_STATE)
            .unwrap();
        let mut status = scheduler
            .bus()
            .subscriber::<HybridTrackingStatus>(HYBRID_TRACKING_STATUS)
            .unwrap();
        scheduler.start().unwrap();
        let mut states = Vec::new();
        scheduler.run_for(Duration::from_millis(50)).unwrap();
        for k in 0..frames {
            if k > 0 {
                scheduler.run_for(Duration::from_millis(100)).unwrap();
            }
            states.push(relative.latest().map(|m| m.value));
        }
        Run {
            relative: states,
            status: status.latest().map(|m| m.value.clone()).unwrap_or_default(),
            failures: scheduler.task_stats("tracking").unwrap().failures,
        }
    }

    fn horizontal_error_m(world: &WorldConfig, state: &RelativeState) -> f64 {
        let truth = world.truth_ned_m(state.estimate.time_s);
        (state.estimate.uav_relative_ned_m - truth).xy().norm()
    }

    #[test]
    fn a_driving_pad_is_located_with_the_stereo_altitude_and_its_velocity_observed() {
        // The autopilot's height is 10 % off: only the depth gives the true 6 m. The UAV flies
        // north at 0.3 m/s: the homography must take its motion out of the pad's.
        let world = WorldConfig {
            autopilot_height_m: 6.6,
            uav_velocity_ned_m_s: Vector3::new(0.3, 0.0, 0.0),
            ..WorldConfig::hovering(DepthMode::Exact)
        };
        let run = fly(world.clone(), 30);
        assert_eq!(run.failures, 0);
        // The track is confirmed at its third detection.
        assert!(run.relative[1].is_none() && run.relative[2].is_some());
        let last = run.relative[29].as_ref().unwrap();
        let error_m = horizontal_error_m(&world, last);
        assert!(error_m < 0.05, "horizontal error {error_m} m: {last:?}");
        // Height above the pad from the depth (with the tilt taken out), not the autopilot's.
        let z = last.estimate.uav_relative_ned_m.z;
        assert!((z + 6.0).abs() < 0.05, "{z}");
        // Every state after the track's confirmation is right, carried forward between frames.
        let worst = run.relative[5..]
            .iter()
            .map(|s| horizontal_error_m(&world, s.as_ref().unwrap()))
            .fold(0.0, f64::max);
        assert!(worst < 0.08, "worst {worst} m");
        // The pad drives east at 0.5 m/s: its velocity over the ground, not relative to the UAV.
        let velocity = last.platform_velocity_ned_m_s.expect("a platform velocity");
        assert!(
            (velocity - Vector3::new(0.0, 0.5, 0.0)).norm() < 0.08,
            "{velocity}"
        );
        let s = &run.status;
        assert_eq!(s.depth_fallbacks, 0, "{s:?}");
        assert!(s.depth_altitudes >= 25 && s.altitude_from_depth, "{s:?}");
        assert!(s.detections >= 25 && s.velocity_samples >= 20, "{s:?}");
        assert_eq!(s.homography_failures, 0, "{s:?}");
        assert_eq!(s.homography_motions, s.velocity_samples, "{s:?}");
        assert_eq!(s.ego_motions, 0, "{s:?}");
        assert!(last.last_fix_time_s.is_some());
    }

    #[test]
    fn all_nan_depth_falls_back_to_the_autopilot_height_and_says_so() {
        for (depth, reason) in [
            (DepthMode::AllNan, "hold a valid depth"),
            (DepthMode::Missing, "no depth frame"),
        ] {
            // The autopilot says 6.3 m: the estimate must use exactly that.
            let world = WorldConfig {
                autopilot_height_m: 6.3,
                observations: Some(Vec::new()),
                ..WorldConfig::hovering(depth)
            };
            let run = fly(world.clone(), 12);
            assert_eq!(run.failures, 0, "{depth:?}");
            let s = &run.status;
            assert!(s.frames >= 10, "{depth:?}: {s:?}");
            assert_eq!(s.depth_fallbacks, s.frames, "{depth:?}: {s:?}");
            assert_eq!(s.depth_altitudes, 0);
            assert!(!s.altitude_from_depth);
            assert_eq!(s.altitude_m, Some(6.3));
            let why = s.last_depth_error.as_deref().unwrap_or_default();
            assert!(why.contains(reason), "{depth:?}: {why}");
            let last = run.relative[11].as_ref().expect("relative states");
            assert!((last.estimate.uav_relative_ned_m.z + 6.3).abs() < 1e-9);
            // 5 % too high: the offset from the pad comes out 5 % too long, not more.
            let truth = world.truth_ned_m(last.estimate.time_s);
            let error = (last.estimate.uav_relative_ned_m - truth).xy().norm();
            assert!(error < 0.05 * truth.xy().norm() + 0.03, "{error} m");
        }
    }

    #[test]
    fn low_over_the_pad_the_uavs_own_motion_compensates() {
        // 2.5 m up, under `homography_min_altitude_m`: the platform's motion comes from the
        // UAV's reported velocity (north 0.3 m/s) less the change of the relative position.
        let world = WorldConfig {
            uav_ned_m: Vector3::new(0.0, 0.0, -2.5),
            uav_velocity_ned_m_s: Vector3::new(0.3, 0.0, 0.0),
            pad_start_ne_m: [0.1, -0.5],
            autopilot_height_m: 2.5,
            observations: Some(Vec::new()),
            ..WorldConfig::hovering(DepthMode::Exact)
        };
        let run = fly(world.clone(), 16);
        assert_eq!(run.failures, 0);
        let s = &run.status;
        assert!(s.ego_motions >= 10, "{s:?}");
        assert_eq!(s.homography_motions, 0, "{s:?}");
        let last = run.relative[15].unwrap();
        let velocity = last.platform_velocity_ned_m_s.expect("a platform velocity");
        // The pad's own velocity, not the relative one (−0.3, 0.5).
        assert!(
            (velocity - Vector3::new(0.0, 0.5, 0.0)).norm() < 0.05,
            "{velocity}"
        );
        assert!(horizontal_error_m(&world, &last) < 0.03);
    }

    /// The same pad with the detections of some frames missing: (the relative states after
    /// each frame, the status).
    fn with_gap(dropped: std::ops::RangeInclusive<u64>) -> (WorldConfig, Run) {
        let world = WorldConfig {
            observations: Some(dropped.collect()),
            ..WorldConfig::hovering(DepthMode::Exact)
        };
        let run = fly(world.clone(), 30);
        (world, run)
    }

    #[test]
    fn missing_detections_are_bridged_by_prediction() {
        // Frames 15–18 without a detection: four misses, under max_misses = 5.
        let (world, run) = with_gap(15..=18);
        assert_eq!(run.failures, 0);
        assert_eq!(run.status.bridged, 4, "{:?}", run.status);
        let last_detected_s = 1.4;
        for k in 15..=18 {
            let state = run.relative[k].as_ref().unwrap();
            // The last fix stays at the last detection …
            let fix_s = state.last_fix_time_s.unwrap();
            assert!((fix_s - last_detected_s).abs() < 1e-6, "frame {k}: {fix_s}");
            // … while the estimate follows the pad, which moves 5 cm a frame: 0.2 m by the
            // end of the gap, that a held estimate would be off by.
            let error_m = horizontal_error_m(&world, state);
            assert!(error_m < 0.04, "frame {k}: {error_m} m");
        }
        let held = world.truth_ned_m(1.4) - world.truth_ned_m(1.8);
        assert!(held.xy().norm() > 0.19);
        // The detections resume on the same track: no new confirmation needed.
        let after = run.relative[19].as_ref().unwrap();
        assert!((after.last_fix_time_s.unwrap() - 1.9).abs() < 1e-6);
        assert!(horizontal_error_m(&world, run.relative[29].as_ref().unwrap()) < 0.03);
        assert_eq!(run.status.detections + run.status.bridged, 30 - 2);
    }

    #[test]
    fn a_track_missed_max_misses_times_is_dropped_and_reconfirmed() {
        // Frames 15–20 without a detection: the fifth miss ends the track.
        let (_, run) = with_gap(15..=20);
        assert_eq!(run.status.bridged, 4, "{:?}", run.status);
        // Frames 0–1 and 21–22 wait for a confirmation (3 hits), 19–20 have no target: the
        // detections that count are frames 2–14 and 23–29.
        assert_eq!(run.status.detections, 13 + 7, "{:?}", run.status);
        // The fix time stands still from frame 14 until the new track is confirmed.
        for k in [18, 20, 22] {
            let fix_s = run.relative[k].unwrap().last_fix_time_s.unwrap();
            assert!((fix_s - 1.4).abs() < 1e-6, "frame {k}: {fix_s}");
        }
        let fix_s = run.relative[23].unwrap().last_fix_time_s.unwrap();
        assert!((fix_s - 2.3).abs() < 1e-6, "{fix_s}");
    }

    #[test]
    fn bad_params_are_named_errors() {
        let build = |text: &str| -> Result<HybridTrackingTask, TaskError> {
            super::super::build_from_params(PLUGIN_NAME, text, |params: Params, build| {
                Ok(HybridTrackingTask::new(params, Ports::take(build)?)?)
            })
        };
        assert!(build("").is_ok());
        for (text, named) in [
            ("a1_distance = 0.7", "a1_distance + a2_colour"),
            ("altitude_window_fraction = 0.0", "altitude_window_fraction"),
            (
                "stereo_min_range_m = 3.0\nstereo_max_range_m = 2.0",
                "stereo_max_range_m",
            ),
            ("pad_size_m = -1.0", "pad_size_m"),
            ("velocity_sigma_s = 0.0", "sigma_s"),
            ("homography_min_inliers = 3", "homography_min_inliers"),
            (
                "homography_min_altitude_m = -1.0",
                "homography_min_altitude_m",
            ),
            ("max_ugv_speed_m_s = 0.0", "max_ugv_speed_m_s"),
            ("camera_horizontal_fov_deg = 0.0", "camera"),
            ("velocity_averaging = \"median\"", "speed_and_course"),
            ("altitude_windw_fraction = 0.1", "altitude_windw_fraction"),
        ] {
            let Err(TaskError::Params(why)) = build(text) else {
                panic!("`{text}` was accepted");
            };
            assert!(why.contains(named), "`{text}`: {why}");
        }
    }

    #[test]
    fn level_pixels_are_where_a_level_north_facing_camera_sees_the_point() {
        let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let position = Vector3::new(1.0, -2.0, -7.0);
        let level = CameraPose::downward(position, 0.0, 0.0, 0.0);
        for attitude in [
            Attitude::new(0.0, 0.0, 0.0),
            Attitude::new(0.12, -0.08, 0.0),
            Attitude::new(-0.2, 0.15, 2.1),
        ] {
            let tilted = CameraPose::downward(
                position,
                attitude.roll_rad,
                attitude.pitch_rad,
                attitude.yaw_rad,
            );
            for point in [Point3::new(1.5, -1.0, 0.0), Point3::new(-0.5, -3.0, -1.0)] {
                let (u, v) = camera.project_world(&tilted, &point).unwrap();
                let (lu, lv) = level_pixel(&camera, &attitude, u, v).unwrap();
                let (eu, ev) = camera.project_world(&level, &point).unwrap();
                assert!(
                    (lu - eu).abs() < 1e-6 && (lv - ev).abs() < 1e-6,
                    "{attitude:?}"
                );
            }
        }
        // Looking at the horizon: no level pixel.
        assert!(level_pixel(&camera, &Attitude::new(0.0, 1.55, 0.0), 320.0, 0.0).is_none());
    }

    #[test]
    fn keypoints_on_the_target_are_masked_out() {
        let image = GrayImage::filled(64, 48, 0).unwrap();
        let matcher = FeatureMatcher::new(FeatureConfig::default());
        let mut features = matcher.features(&image.view());
        assert!(features.keypoints.is_empty());
        // Three keypoints with their descriptors; the middle one is inside the box.
        for (x, y) in [(5.0, 5.0), (30.0, 20.0), (60.0, 40.0)] {
            features
                .keypoints
                .push(algorithms::vision::features::Keypoint {
                    x_px: x,
                    y_px: y,
                    score: 1.0,
                    angle_rad: 0.0,
                });
            features
                .descriptors
                .push(algorithms::vision::features::Descriptor([
                    x as u64, 0, 0, 0,
                ]));
        }
        mask_out(
            &mut features,
            &PixelBox::from_centre(30.0, 20.0, 10.0, 10.0),
            1.2,
        );
        let left: Vec<f64> = features.keypoints.iter().map(|k| k.x_px).collect();
        assert_eq!(left, vec![5.0, 60.0]);
        assert_eq!(features.descriptors[1].0[0], 60);
    }
}
