//! The `kalman_tracker` plugin: turns landing-marker observations into the UAV's position
//! relative to the platform (projection through the camera model, the seed's Kalman filter with
//! delayed fixes, the platform's velocity), predicting between frames at the task's rate.

use crate::bus::{Publisher, Subscriber};
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::{Task, TaskBuild, TaskContext, TaskError};
use crate::topics::{
    MarkerObservation, RelativeState, VehicleState, LANDING_MARKER, RELATIVE_STATE, VEHICLE_STATE,
};
use algorithms::camera::PinholeCamera;
use algorithms::estimation::attitude_history::{AttitudeHistory, AttitudeSample};
use algorithms::estimation::camera_mount::CameraMount;
use algorithms::estimation::kalman::{FixOutcome, MotionInput, Tracker, TrackerConfig, VisionFix};
use algorithms::estimation::platform_velocity::{
    PlatformFix, PlatformVelocityConfig, PlatformVelocityEstimator,
};
use algorithms::estimation::projection::{
    ground_line_yaw_rad, pad_relative_to_uav_ned_m, Attitude, FixNoise,
};
use algorithms::vision::landing_marker::LandingMarkerObservation;

/// How far back a frame's capture can be looked up (a frame older than this is projected
/// with the oldest attitude kept).
const ATTITUDE_HISTORY_S: f64 = 1.0;
use nalgebra::{Matrix3, Vector3};
use serde::Deserialize;

pub const PLUGIN_NAME: &str = "kalman_tracker";

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Process noise q of the relative position (Q = dt·q·I), m²/s.
    #[serde(default = "default_process_noise")]
    process_noise_m2_per_s: f64,
    /// Standard deviation of one vision fix on the pad (height 0), metres…
    #[serde(default = "default_fix_std")]
    fix_std_m: f64,
    /// …plus this angle's worth of the height (attitude noise and timing, latency, blur).
    #[serde(default = "default_fix_angle_std")]
    fix_angle_std_deg: f64,
    /// Put the platform's velocity along the heading the marker's orientation gives, which
    /// does not lag a turn as the direction of the filtered velocity does.
    #[serde(default)]
    heading_from_marker: bool,
    /// With `heading_from_marker`: the angle from the platform's direction of travel to the
    /// pad's x axis as the detector reports it, from north towards east. 90 for the built-in
    /// world's pad, whose x axis points to the tractor's right.
    #[serde(default = "default_pad_x_axis_from_heading")]
    pad_x_axis_from_heading_deg: f64,
    /// The platform's velocity is given out only once known to this, m/s (see
    /// `PlatformVelocityConfig::max_velocity_std_m_s`).
    #[serde(default = "default_platform_velocity_max_std")]
    platform_velocity_max_std_m_s: f64,
    /// After the last fix the platform's velocity is carried round at its measured rate of
    /// turn for at most this long, seconds (see
    /// `PlatformVelocityConfig::max_turn_extrapolation_s`); 0: held as the last fix left it.
    #[serde(default = "default_platform_turn_extrapolation")]
    platform_turn_extrapolation_s: f64,
}

fn default_platform_turn_extrapolation() -> f64 {
    PlatformVelocityConfig::default().max_turn_extrapolation_s
}

fn default_platform_velocity_max_std() -> f64 {
    PlatformVelocityConfig::default().max_velocity_std_m_s
}

fn default_pad_x_axis_from_heading() -> f64 {
    90.0
}

fn default_process_noise() -> f64 {
    0.05
}
fn default_fix_std() -> f64 {
    0.01
}
/// Measured in the realistic simulator (calm, 180° turn, seeds 1–20, 15 s of tracking): with a
/// constant 0.1 m a fix from 1 m weighed as little as one from 7.5 m; with 0.01 m + 1.7° (and the
/// platform's velocity filtered with the same variances) the touchdown error went from p50 0.13 /
/// p95 0.30 m to 0.06 / 0.17 m.
fn default_fix_angle_std() -> f64 {
    1.7
}

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    super::register_builtin(registry, PLUGIN_NAME, TrackerTask::new)
}

/// Vehicle telemetry older than this is stale (the autopilot streams it at 10 Hz or more).
const MAX_STATE_AGE_S: f64 = 0.5;

struct TrackerTask {
    camera: PinholeCamera,
    camera_mount: CameraMount,
    fix_noise: FixNoise,
    tracker: Tracker,
    platform: PlatformVelocityEstimator,
    last_fix_time_s: Option<f64>,
    /// The vehicle's recent attitude and height, to project a fix as at its capture.
    attitude_history: AttitudeHistory,
    /// With the heading from the marker: the pad's x axis from the direction of travel.
    pad_x_axis_from_heading_rad: Option<f64>,
    vehicle: Subscriber<VehicleState>,
    markers: Subscriber<MarkerObservation>,
    output: Publisher<RelativeState>,
}

impl TrackerTask {
    fn new(params: Params, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        let bad = |e: &dyn std::fmt::Display| TaskError::Params(e.to_string());
        let fix_noise = FixNoise::new(params.fix_std_m, params.fix_angle_std_deg.to_radians())
            .map_err(|e| bad(&e))?;
        if !params.pad_x_axis_from_heading_deg.is_finite() {
            return Err(bad(&format!(
                "pad_x_axis_from_heading_deg = {} must be a finite angle in degrees",
                params.pad_x_axis_from_heading_deg
            )));
        }
        // The mission's one camera: fixes are projected with its intrinsics and its mount.
        let camera_settings = &build.config().camera;
        let camera = camera_settings.pinhole().map_err(|e| bad(&e))?;
        let tracker = Tracker::new(TrackerConfig {
            process_noise_m2_per_s: params.process_noise_m2_per_s,
            // A restart needs a second of gated fixes: at 10 fps two false marker detections
            // in a row moved the estimate metres in the realistic world (the reference mission
            // lost the pad at 541 s, its localisation error 5.7 m at worst; 1.1 m with this).
            restart_after_rejected_s: 1.0,
            // …unless they are near the prediction: it lags a turn or a gust, and a second of
            // waiting loses the pad (the 3 m/s tractor's 180° turn in 8 m/s: 75 % landed).
            quick_restart_within_m: 1.5,
            ..TrackerConfig::default()
        })
        .map_err(|e| bad(&e))?;
        Ok(Self {
            camera,
            camera_mount: camera_settings.mount,
            fix_noise,
            tracker,
            platform: PlatformVelocityEstimator::new(PlatformVelocityConfig {
                // Fixes come 2 s apart at the slowest detection rate (0.5 fps).
                max_gap_s: 3.0,
                max_velocity_std_m_s: params.platform_velocity_max_std_m_s,
                max_turn_extrapolation_s: params.platform_turn_extrapolation_s,
                ..PlatformVelocityConfig::default()
            })
            .map_err(|e| bad(&e))?,
            last_fix_time_s: None,
            attitude_history: AttitudeHistory::new(ATTITUDE_HISTORY_S),
            pad_x_axis_from_heading_rad: params
                .heading_from_marker
                .then(|| params.pad_x_axis_from_heading_deg.to_radians()),
            vehicle: build.input(VEHICLE_STATE)?,
            markers: build.input(LANDING_MARKER)?,
            output: build.output(RELATIVE_STATE)?,
        })
    }
}

impl TrackerTask {
    /// The platform's heading from a fix, where the marker's heading is asked for and the
    /// detector saw the pad's orientation: the pad's x axis on the ground, less its mounting.
    fn platform_yaw_rad(
        &self,
        camera_attitude: &Attitude,
        height_above_pad_m: f64,
        observation: &LandingMarkerObservation,
    ) -> Option<f64> {
        let from_heading_rad = self.pad_x_axis_from_heading_rad?;
        let axis_yaw_rad = ground_line_yaw_rad(
            &self.camera,
            camera_attitude,
            height_above_pad_m,
            observation.centre_px,
            observation.orientation_rad?,
        )
        .ok()?;
        Some(axis_yaw_rad - from_heading_rad)
    }
}

impl Task for TrackerTask {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let (vehicle, markers, output) = (&mut self.vehicle, &mut self.markers, &self.output);
        // Without the vehicle's attitude and height there is nothing to project with.
        let Some(latest) = vehicle.latest() else {
            return Ok(());
        };
        let state = latest.value;
        self.attitude_history.push(AttitudeSample {
            time_s: latest.stamp.as_secs_f64(),
            attitude: state.attitude,
            height_above_pad_m: state.height_above_pad_m,
            position_ned_m: state.position_ned_m,
            velocity_ned_m_s: state.velocity_ned_m_s,
            gimbal_attitude: state.gimbal_attitude,
        });
        let now_s = ctx.now().as_secs_f64();
        let state_fresh = now_s - latest.stamp.as_secs_f64() <= MAX_STATE_AGE_S;
        let platform_velocity = self.platform.velocity_at(now_s).map(|p| p.velocity_ned_m_s);
        if self.tracker.estimate().is_some() {
            let input = MotionInput {
                uav_velocity_ned_m_s: state.velocity_ned_m_s,
                uav_acceleration_ned_m_s2: state.acceleration_ned_m_s2,
                platform_velocity_ned_m_s: platform_velocity.unwrap_or_else(Vector3::zeros),
            };
            self.tracker
                .predict(now_s, &input)
                .map_err(|e| TaskError::failed(e.to_string()))?;
        }
        if let Some(message) = markers.take_new() {
            if let Some(observation) = &message.value.observation {
                let [u, v] = observation.centre_px;
                // The vehicle as it was when the frame was exposed.
                let at_capture = self
                    .attitude_history
                    .at(message.stamp.as_secs_f64())
                    .unwrap_or(AttitudeSample {
                        time_s: now_s,
                        attitude: state.attitude,
                        height_above_pad_m: state.height_above_pad_m,
                        position_ned_m: state.position_ned_m,
                        velocity_ned_m_s: state.velocity_ned_m_s,
                        gimbal_attitude: state.gimbal_attitude,
                    });
                // A gimballed camera whose gimbal has not reported: the fix cannot be placed.
                let camera_attitude = self
                    .camera_mount
                    .camera_attitude(&at_capture.attitude, at_capture.gimbal_attitude.as_ref());
                let projected = camera_attitude.as_ref().map(|camera_attitude| {
                    pad_relative_to_uav_ned_m(
                        &self.camera,
                        camera_attitude,
                        at_capture.height_above_pad_m,
                        u,
                        v,
                    )
                });
                match projected {
                    Some(Ok(pad_relative)) => {
                        let capture_time_s = message.stamp.as_secs_f64();
                        // The tracker's state is UAV − platform: the pad's position negated.
                        let uav_relative = -pad_relative;
                        let fix_variance_m2 =
                            self.fix_noise.variance_m2(at_capture.height_above_pad_m);
                        let fix = VisionFix {
                            capture_time_s,
                            uav_relative_ned_m: uav_relative,
                            covariance_m2: Matrix3::identity() * fix_variance_m2,
                        };
                        let outcome = self
                            .tracker
                            .correct(&fix)
                            .map_err(|e| TaskError::failed(e.to_string()))?;
                        if let FixOutcome::Restarted { nis } = outcome {
                            // The platform estimator only ever saw accepted fixes, which were
                            // right; it carries on.
                            tracing::info!(
                                task = ctx.name(),
                                nis,
                                "tracker restarted at the vision fixes"
                            );
                        }
                        if matches!(
                            outcome,
                            FixOutcome::Initialized
                                | FixOutcome::Accepted { .. }
                                | FixOutcome::Restarted { .. }
                        ) {
                            self.last_fix_time_s = Some(capture_time_s);
                            // The platform's velocity is the vehicle's plus the fixes' drift:
                            // on stale telemetry (a lost link) the vehicle's is not known, and
                            // learning from the last one reported would fly the vehicle after
                            // a platform that is not there once the link is back.
                            if state_fresh {
                                let platform_yaw_rad =
                                    camera_attitude.as_ref().and_then(|camera_attitude| {
                                        self.platform_yaw_rad(
                                            camera_attitude,
                                            at_capture.height_above_pad_m,
                                            observation,
                                        )
                                    });
                                let _ = self.platform.update(&PlatformFix {
                                    time_s: capture_time_s,
                                    uav_relative_ned_m: uav_relative,
                                    horizontal_variance_m2: fix_variance_m2,
                                    // As the fix: at the frame's capture.
                                    uav_velocity_ned_m_s: at_capture.velocity_ned_m_s,
                                    platform_yaw_rad,
                                });
                            }
                        }
                    }
                    // A pixel above the horizon or a bad height: skip the fix, keep predicting.
                    Some(Err(error)) => {
                        tracing::debug!(task = ctx.name(), %error, "fix not projected")
                    }
                    None => tracing::debug!(
                        task = ctx.name(),
                        "fix not projected: the camera's gimbal has not reported its attitude"
                    ),
                }
            }
        }
        if let Some(estimate) = self.tracker.estimate() {
            output.publish(
                ctx.now(),
                RelativeState {
                    estimate,
                    platform_velocity_ned_m_s: self
                        .platform
                        .velocity_at(now_s)
                        .map(|p| p.velocity_ned_m_s),
                    last_fix_time_s: self.last_fix_time_s,
                },
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn task(params: &str) -> Result<TrackerTask, TaskError> {
        super::super::build_from_params(PLUGIN_NAME, params, TrackerTask::new)
    }

    #[test]
    fn a_fix_is_trusted_more_the_lower_it_is_taken() {
        let tracker = task("fix_std_m = 0.02\nfix_angle_std_deg = 2.0").unwrap();
        let expected =
            |height_m: f64| 0.02f64.powi(2) + (height_m * 2f64.to_radians().tan()).powi(2);
        for height_m in [0.5, 7.5] {
            assert!((tracker.fix_noise.variance_m2(height_m) - expected(height_m)).abs() < 1e-12);
        }
        let defaults = task("").unwrap();
        assert!(defaults.fix_noise.variance_m2(1.0) < defaults.fix_noise.variance_m2(7.5) / 20.0);
    }

    #[test]
    fn the_heading_from_the_marker_is_taken_only_when_asked_with_its_mounting() {
        assert_eq!(task("").unwrap().pad_x_axis_from_heading_rad, None);
        let asked =
            task("heading_from_marker = true\npad_x_axis_from_heading_deg = -30.0").unwrap();
        let mounting_rad = asked.pad_x_axis_from_heading_rad.unwrap();
        assert!((mounting_rad.to_degrees() + 30.0).abs() < 1e-9);
        let Err(TaskError::Params(message)) =
            task("heading_from_marker = true\npad_x_axis_from_heading_deg = nan")
        else {
            panic!("a NaN mounting was accepted");
        };
        assert!(message.contains("pad_x_axis_from_heading_deg"), "{message}");
    }

    #[test]
    fn bad_params_are_named() {
        for (params, named) in [
            ("fix_std_m = -0.1", "fix's noise"),
            ("fix_angle_std_deg = -1.0", "fix's noise"),
            ("fix_std_m = 0.0\nfix_angle_std_deg = 0.0", "fix's noise"),
            (
                "platform_velocity_max_std_m_s = 0.0",
                "max_velocity_std_m_s",
            ),
            (
                "platform_velocity_max_std_m_s = -1.0",
                "max_velocity_std_m_s",
            ),
            (
                "platform_velocity_max_std_m_s = inf",
                "max_velocity_std_m_s",
            ),
            (
                "platform_turn_extrapolation_s = -0.5",
                "max_turn_extrapolation_s",
            ),
        ] {
            let Err(TaskError::Params(message)) = task(params) else {
                panic!("{params} was accepted");
            };
            assert!(message.contains(named), "{params}: {message}");
        }
        assert!(task("platform_velocity_max_std_m_s = 0.8").is_ok());
        assert!(task("platform_turn_extrapolation_s = 0.0").is_ok());
    }
}
