//! The `hybrid_tracking` plugin: seed 000's UGV state estimation (§2.2,
//! [`algorithms::estimation::hybrid_tracking`]) on the runtime's bus, so `landing_guidance`
//! flies the seed's system instead of the default tracker.
//!
//! Inputs: `vision/landing_marker`, `camera/frame`, `camera/depth`, `vehicle/state`. Outputs:
//! `tracking/relative_state` (at the task's rate) and `tracking/hybrid_status` (per frame).
//! The camera frames and depth frames are matched to the detector's observations by frame
//! index; the task's period should not exceed the camera's, so that it sees every frame.
//! Altitude fallbacks are logged, at warn level only in flight.

use std::collections::VecDeque;

use crate::bus::{Publisher, Subscriber};
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::{Task, TaskBuild, TaskContext, TaskError};
use crate::topics::{
    CameraFrame, DepthFrame, HybridTrackingStatus, MarkerObservation, RelativeState, VehicleState,
    CAMERA_FRAME, DEPTH_FRAME, HYBRID_TRACKING_STATUS, LANDING_MARKER, RELATIVE_STATE,
    VEHICLE_STATE,
};
use algorithms::estimation::hybrid_tracking::{
    FrameInput, HybridTracker, HybridTrackingConfig, HybridTrackingConfigError, VehicleSample,
};
use algorithms::estimation::stereo_altitude::{AltitudeFilterConfig, AltitudeWindow};
use algorithms::estimation::velocity_observer::{Averaging, VelocityObserverConfig};
use algorithms::tracking::tracker::TrackerConfig;
use algorithms::vision::homography::RansacConfig;
use serde::Deserialize;

pub const PLUGIN_NAME: &str = "hybrid_tracking";

/// Camera frames and depth frames kept for matching with late observations.
const FRAME_HISTORY: usize = 8;
/// Fallbacks logged at warn level: the first, then one in this many.
const FALLBACK_LOG_EVERY: u64 = 50;

/// `[task.params]` of the plugin; every key is optional, the defaults are the seed's.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
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

impl From<HybridTrackingConfigError> for TaskError {
    fn from(error: HybridTrackingConfigError) -> Self {
        TaskError::Params(error.to_string())
    }
}

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    super::register_builtin(registry, PLUGIN_NAME, HybridTrackingTask::new)
}

pub struct HybridTrackingTask {
    tracker: HybridTracker,
    frames: VecDeque<CameraFrame>,
    depths: VecDeque<DepthFrame>,
    /// Fallbacks in flight (the ones worth a warning).
    airborne_fallbacks: u64,
    vehicle: Subscriber<VehicleState>,
    frame_input: Subscriber<CameraFrame>,
    depth_input: Subscriber<DepthFrame>,
    markers: Subscriber<MarkerObservation>,
    output: Publisher<RelativeState>,
    status_output: Publisher<HybridTrackingStatus>,
}

impl HybridTrackingTask {
    fn new(params: Params, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        // The mission's (rectified) camera the detector looks through.
        let camera = build
            .config()
            .camera
            .pinhole()
            .map_err(|e| TaskError::Params(format!("camera: {e}")))?;
        let tracker = HybridTracker::new(HybridTrackingConfig {
            camera,
            pad_size_m: params.pad_size_m,
            tracker: TrackerConfig {
                a1_distance: params.a1_distance,
                a2_colour: params.a2_colour,
                max_cost: params.max_cost,
                min_iou: params.min_iou,
                confirm_hits: params.confirm_hits,
                max_misses: params.max_misses,
                measurement_std_px: params.measurement_std_px,
                acceleration_std_px_s2: params.acceleration_std_px_s2,
                ..TrackerConfig::default()
            },
            altitude_window_fraction: params.altitude_window_fraction,
            altitude_min_valid_fraction: params.altitude_min_valid_fraction,
            stereo_min_range_m: params.stereo_min_range_m,
            stereo_max_range_m: params.stereo_max_range_m,
            altitude_filter: AltitudeFilterConfig {
                measurement_std_m: params.altitude_measurement_std_m,
                ..AltitudeFilterConfig::default()
            },
            velocity_observer: VelocityObserverConfig {
                sigma_s: params.velocity_sigma_s,
                window_s: params.velocity_window_s,
                averaging: match params.velocity_averaging {
                    AveragingParam::SpeedAndCourse => Averaging::SpeedAndCourse,
                    AveragingParam::Velocity => Averaging::Velocity,
                },
            },
            homography_min_altitude_m: params.homography_min_altitude_m,
            max_ugv_speed_m_s: params.max_ugv_speed_m_s,
            ransac_threshold_px: params.ransac_threshold_px,
            homography_min_inliers: params.homography_min_inliers,
        })?;
        Ok(Self {
            tracker,
            frames: VecDeque::new(),
            depths: VecDeque::new(),
            airborne_fallbacks: 0,
            vehicle: build.input(VEHICLE_STATE)?,
            frame_input: build.input(CAMERA_FRAME)?,
            depth_input: build.input(DEPTH_FRAME)?,
            markers: build.input(LANDING_MARKER)?,
            output: build.output(RELATIVE_STATE)?,
            status_output: build.output(HYBRID_TRACKING_STATUS)?,
        })
    }

    /// One frame the detector looked at, with the camera and depth frames of its index.
    fn process(
        &mut self,
        ctx: &TaskContext<'_>,
        message: &MarkerObservation,
        time_s: f64,
    ) -> Result<(), TaskError> {
        let frame = self
            .frames
            .iter()
            .find(|f| f.frame_index == message.frame_index);
        let depth = self
            .depths
            .iter()
            .find(|d| d.frame_index == message.frame_index);
        let report = self
            .tracker
            .process(&FrameInput {
                frame_index: message.frame_index,
                time_s,
                observation: message.observation.as_ref(),
                image: frame.map(|f| f.image.as_ref()),
                depth: depth.map(|d| d.image.as_ref()),
            })
            .map_err(|e| TaskError::failed(format!("tracker: {e}")))?;
        if let Some(fallback) = &report.altitude_fallback {
            // On the ground, in the take-off and in the last of the landing the stereo camera
            // is too near to measure: expected, not worth a warning.
            if !report.fallback_airborne {
                tracing::debug!(task = ctx.name(), reason = %fallback, "altitude from the autopilot");
            } else {
                self.airborne_fallbacks += 1;
                if self.airborne_fallbacks % FALLBACK_LOG_EVERY == 1 {
                    tracing::warn!(
                        task = ctx.name(),
                        fallbacks = self.tracker.status().depth_fallbacks,
                        reason = %fallback,
                        "altitude from the autopilot's height, not the stereo depth"
                    );
                }
            }
        }
        if let Some(error) = &report.homography_error {
            tracing::debug!(task = ctx.name(), %error, "no motion compensation");
        }
        if report.tracked {
            let stamp = crate::clock::Timestamp::from_secs_f64(time_s);
            self.status_output
                .publish(stamp, self.tracker.status().clone());
        }
        Ok(())
    }
}

impl Task for HybridTrackingTask {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let now_s = ctx.now().as_secs_f64();
        if let Some(message) = self.vehicle.take_new() {
            let state = message.value;
            self.tracker.add_vehicle_state(
                message.stamp.as_secs_f64(),
                VehicleSample {
                    attitude: state.attitude,
                    velocity_ned_m_s: state.velocity_ned_m_s,
                    height_above_pad_m: state.height_above_pad_m,
                    landed: state.landed,
                },
            );
        }
        self.tracker.forget_old_states(now_s);
        if let Some(message) = self.frame_input.take_new() {
            self.frames.push_back(message.value.clone());
            if self.frames.len() > FRAME_HISTORY {
                self.frames.pop_front();
            }
        }
        if let Some(message) = self.depth_input.take_new() {
            self.depths.push_back(message.value.clone());
            if self.depths.len() > FRAME_HISTORY {
                self.depths.pop_front();
            }
        }
        let observation = self.markers.take_new();
        if let Some(message) = observation {
            let time_s = message.stamp.as_secs_f64();
            self.process(ctx, &message.value, time_s)?;
        }
        let Some(estimate) = self.tracker.estimate_at(now_s) else {
            return Ok(());
        };
        self.output.publish(
            ctx.now(),
            RelativeState {
                estimate: estimate.estimate,
                platform_velocity_ned_m_s: estimate.platform_velocity_ned_m_s,
                last_fix_time_s: estimate.last_fix_time_s,
            },
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests;
