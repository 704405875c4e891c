//! Seed 000's UGV state estimation (§2.2): the UAV's position relative to a pad on a moving UGV
//! and the UGV's velocity, from the landing-marker detector's observations, the downward
//! camera's frames, the stereo camera's depth and the autopilot's state.
//!
//! Per frame the detector looked at ([`HybridTracker::process`]):
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
//!    [`AltitudeFallback`], counted in [`HybridTrackingStatus`], never a panic.
//! 3. **Relative position**: the target's pixel, the altitude and the attitude at the frame's
//!    capture give the UAV's position relative to the pad (the projection the Kalman tracker
//!    uses); between frames, and over missed detections, it is carried forward by the UAV's
//!    velocity less the platform's ([`HybridTracker::estimate_at`]).
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
//!    platform's velocity that the landing guidance feeds forward (equations 26–27). A motion
//!    faster than `max_ugv_speed_m_s` is a bad match, not the UGV, and is left out.

use std::collections::VecDeque;

use nalgebra::{Matrix3, Vector3};
use thiserror::Error;

use super::kalman::RelativeEstimate;
use super::projection::{pad_relative_to_uav_ned_m, Attitude};
use super::stereo_altitude::{
    central_window_altitude, AltitudeFilter, AltitudeFilterConfig, AltitudeWindow,
    StereoAltitudeError,
};
use super::velocity_observer::{
    instant_motion, InstantMotion, PixelMotion, VelocityObserver, VelocityObserverConfig,
    VelocityObserverError,
};
use crate::camera::{CameraPose, PinholeCamera};
use crate::tracking::histogram::ColourHistogram;
use crate::tracking::iou::PixelBox;
use crate::tracking::tracker::{
    BoxDetection, MultiTracker, TargetPolicy, TrackerConfig, TrackingError,
};
use crate::vision::features::{FeatureConfig, FeatureMatcher, FrameFeatures};
use crate::vision::homography::{fit_correspondences, HomographyError, RansacConfig};
use crate::vision::image::{DepthImage, GrayImage};
use crate::vision::landing_marker::LandingMarkerObservation;

mod motion;

/// Vehicle states kept before the newest, s: the carry-forward from a frame's capture to now
/// integrates their velocities.
const STATE_HISTORY_S: f64 = 2.0;

/// The estimator's settings. The names of the plain fields are the plugin's `[task.params]`
/// keys, which a [`HybridTrackingConfigError`] names.
#[derive(Debug, Clone)]
pub struct HybridTrackingConfig {
    /// The (rectified) camera the detector looks through.
    pub camera: PinholeCamera,
    /// The pad's side: its box in the image when the detector gives no size.
    pub pad_size_m: f64,
    /// Tracking by detection; its `measurement_std_px` is also the fix's pixel uncertainty.
    pub tracker: TrackerConfig,
    /// Side of the central depth window as a fraction of the depth image's width.
    pub altitude_window_fraction: f64,
    /// Fewer valid window pixels than this fraction: no altitude from depth.
    pub altitude_min_valid_fraction: f64,
    /// Depths outside this range are not measurements.
    pub stereo_min_range_m: f64,
    pub stereo_max_range_m: f64,
    pub altitude_filter: AltitudeFilterConfig,
    pub velocity_observer: VelocityObserverConfig,
    /// Below this altitude the motion compensation takes the UAV's own motion from the
    /// autopilot instead of the ground's homography (see the module docs).
    pub homography_min_altitude_m: f64,
    /// An instantaneous motion faster than this is a bad homography or detection, not the UGV;
    /// it is left out.
    pub max_ugv_speed_m_s: f64,
    /// RANSAC's inlier threshold, px, and the fewest inliers that make a homography.
    pub ransac_threshold_px: f64,
    pub homography_min_inliers: usize,
}

/// A configuration that cannot work, named.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HybridTrackingConfigError {
    #[error("`{name}` = {value} must be {why}")]
    Value {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("tracker: {0}")]
    Tracker(#[source] TrackingError),
    #[error("altitude filter: {0}")]
    Altitude(#[source] StereoAltitudeError),
    #[error("velocity observer: {0}")]
    Velocity(#[source] VelocityObserverError),
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

/// What the estimator did so far: counts since it started, and the latest frame's sources.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct HybridTrackingStatus {
    /// Detector observations processed (one per frame the detector looked at).
    pub frames: u64,
    /// Frames whose detection the target's track took.
    pub detections: u64,
    /// Frames the target's track was bridged by its prediction (no detection matched).
    pub bridged: u64,
    /// Frames whose altitude came from the stereo depth (central window + filter).
    pub depth_altitudes: u64,
    /// Frames whose altitude fell back to the autopilot's height, and why the last one did.
    pub depth_fallbacks: u64,
    pub last_depth_error: Option<String>,
    /// Frame pairs whose target motion came from the ground's homography (the seed's motion
    /// compensation), and those, low over the platform, from the UAV's own reported motion.
    pub homography_motions: u64,
    pub ego_motions: u64,
    /// Frame pairs whose motion compensation failed (no homography), and why the last did.
    pub homography_failures: u64,
    pub last_homography_error: Option<String>,
    /// Instantaneous UGV motions fed to the velocity observer, and those left out as faster
    /// than the UGV can drive.
    pub velocity_samples: u64,
    pub velocity_rejected: u64,
    /// The latest frame's altitude and whether it came from the depth image.
    pub altitude_m: Option<f64>,
    pub altitude_from_depth: bool,
}

/// What the autopilot says about the vehicle, as the estimator uses it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleSample {
    pub attitude: Attitude,
    pub velocity_ned_m_s: Vector3<f64>,
    /// The autopilot's height of the camera above the pad: the altitude without depth.
    pub height_above_pad_m: f64,
    pub landed: bool,
}

/// One frame the detector looked at, with what was captured with it.
#[derive(Debug, Clone, Copy)]
pub struct FrameInput<'a> {
    pub frame_index: u64,
    /// When the frame was captured.
    pub time_s: f64,
    /// The detector's finding, `None` when it saw no pad.
    pub observation: Option<&'a LandingMarkerObservation>,
    /// The camera frame and the depth frame of that index, when they are at hand.
    pub image: Option<&'a GrayImage>,
    pub depth: Option<&'a DepthImage>,
}

/// What one frame did, for the caller to log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameReport {
    /// The frame went through the tracker, and [`HybridTracker::status`] is its; `false` for a
    /// frame skipped as stale, before any vehicle state, or with no usable altitude.
    pub tracked: bool,
    /// Why the frame's altitude came from the autopilot, if it did, and whether the UAV was
    /// airborne then (not on the ground, taking off or in the last of the landing, where the
    /// stereo camera is too near to measure and a fallback is expected).
    pub altitude_fallback: Option<AltitudeFallback>,
    pub fallback_airborne: bool,
    /// Why the motion compensation found no homography, if it did not.
    pub homography_error: Option<HomographyError>,
}

/// The relative position at a time, with what it rests on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HybridEstimate {
    pub estimate: RelativeEstimate,
    /// The platform's velocity, once the observer has one.
    pub platform_velocity_ned_m_s: Option<Vector3<f64>>,
    /// When the last detection was captured.
    pub last_fix_time_s: Option<f64>,
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

/// The estimator: fed vehicle states and frames in time order.
pub struct HybridTracker {
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
    states: VecDeque<(f64, VehicleSample)>,
    previous: Option<PreviousFrame>,
    fix: Option<Fix>,
    last_fix_time_s: Option<f64>,
    platform_velocity_ned_m_s: Option<Vector3<f64>>,
    status: HybridTrackingStatus,
}

impl HybridTracker {
    pub fn new(config: HybridTrackingConfig) -> Result<Self, HybridTrackingConfigError> {
        let value = |name, value: f64, why| HybridTrackingConfigError::Value { name, value, why };
        if !(config.homography_min_altitude_m.is_finite()
            && config.homography_min_altitude_m >= 0.0)
        {
            return Err(value(
                "homography_min_altitude_m",
                config.homography_min_altitude_m,
                "finite and not negative",
            ));
        }
        for (name, v) in [
            ("max_ugv_speed_m_s", config.max_ugv_speed_m_s),
            ("pad_size_m", config.pad_size_m),
            ("measurement_std_px", config.tracker.measurement_std_px),
            ("stereo_min_range_m", config.stereo_min_range_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(value(name, v, "positive and finite"));
            }
        }
        if !(config.altitude_window_fraction > 0.0 && config.altitude_window_fraction <= 1.0) {
            return Err(value(
                "altitude_window_fraction",
                config.altitude_window_fraction,
                "within (0, 1]",
            ));
        }
        if !(0.0..=1.0).contains(&config.altitude_min_valid_fraction) {
            return Err(value(
                "altitude_min_valid_fraction",
                config.altitude_min_valid_fraction,
                "within [0, 1]",
            ));
        }
        if config.stereo_max_range_m.is_nan()
            || config.stereo_max_range_m <= config.stereo_min_range_m
        {
            return Err(value(
                "stereo_max_range_m",
                config.stereo_max_range_m,
                "above stereo_min_range_m",
            ));
        }
        if !(config.ransac_threshold_px.is_finite() && config.ransac_threshold_px > 0.0) {
            return Err(value(
                "ransac_threshold_px",
                config.ransac_threshold_px,
                "positive and finite",
            ));
        }
        if config.homography_min_inliers < 4 {
            return Err(value(
                "homography_min_inliers",
                config.homography_min_inliers as f64,
                "at least 4",
            ));
        }
        let tracker =
            MultiTracker::new(config.tracker).map_err(HybridTrackingConfigError::Tracker)?;
        let altitude_filter = AltitudeFilter::new(config.altitude_filter)
            .map_err(HybridTrackingConfigError::Altitude)?;
        let observer = VelocityObserver::new(config.velocity_observer)
            .map_err(HybridTrackingConfigError::Velocity)?;
        Ok(Self {
            camera: config.camera,
            pad_size_m: config.pad_size_m,
            measurement_std_px: config.tracker.measurement_std_px,
            homography_min_altitude_m: config.homography_min_altitude_m,
            max_ugv_speed_m_s: config.max_ugv_speed_m_s,
            window_fraction: config.altitude_window_fraction,
            window: AltitudeWindow {
                width_px: 1,
                height_px: 1,
                min_valid_fraction: config.altitude_min_valid_fraction,
                min_depth_m: config.stereo_min_range_m,
                max_depth_m: config.stereo_max_range_m,
            },
            altitude_filter_config: config.altitude_filter,
            altitude_filter,
            tracker,
            matcher: FeatureMatcher::new(FeatureConfig::default()),
            ransac: RansacConfig {
                threshold_px: config.ransac_threshold_px,
                min_inliers: config.homography_min_inliers,
                ..RansacConfig::default()
            },
            observer,
            states: VecDeque::new(),
            previous: None,
            fix: None,
            last_fix_time_s: None,
            platform_velocity_ned_m_s: None,
            status: HybridTrackingStatus::default(),
        })
    }

    /// What the estimator did so far.
    pub fn status(&self) -> &HybridTrackingStatus {
        &self.status
    }

    /// Adds the vehicle's state at `time_s` to the history.
    pub fn add_vehicle_state(&mut self, time_s: f64, state: VehicleSample) {
        self.states.push_back((time_s, state));
    }

    /// Drops the states older than the history's span before `now_s`, keeping the newest.
    pub fn forget_old_states(&mut self, now_s: f64) {
        while self
            .states
            .front()
            .is_some_and(|(t, _)| now_s - t > STATE_HISTORY_S)
            && self.states.len() > 1
        {
            self.states.pop_front();
        }
    }

    /// The vehicle state nearest `time_s` in the history.
    fn state_at(&self, time_s: f64) -> Option<VehicleSample> {
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
    /// vehicle at `attitude`: from `depth`, or why not.
    fn depth_altitude_m(
        &mut self,
        frame_index: u64,
        depth: Option<&DepthImage>,
        time_s: f64,
        attitude: &Attitude,
    ) -> Result<f64, AltitudeFallback> {
        let image = depth.ok_or(AltitudeFallback::NoDepthFrame { frame_index })?;
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
        image: &GrayImage,
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

    /// One frame the detector looked at. Frames come in capture order; an older one than the
    /// last is skipped. Fails only when the tracker refuses the frame's detections.
    pub fn process(&mut self, frame: &FrameInput<'_>) -> Result<FrameReport, TrackingError> {
        let mut report = FrameReport::default();
        let time_s = frame.time_s;
        if let Some(previous) = &self.previous {
            if time_s <= previous.time_s {
                return Ok(report);
            }
        }
        let Some(state) = self.state_at(time_s) else {
            return Ok(report);
        };
        self.status.frames += 1;
        let altitude_m = self.frame_altitude_m(frame, &state, &mut report);
        self.status.altitude_m = Some(altitude_m);
        if !(altitude_m.is_finite() && altitude_m > 0.0) {
            // Nothing to scale pixels with (on the ground, or bad telemetry): skip the frame.
            return Ok(report);
        }
        let detections: Vec<Detection> = match (frame.observation, frame.image) {
            (Some(observation), Some(image)) => self
                .detection(observation, image, altitude_m, &state.attitude)
                .into_iter()
                .collect(),
            _ => Vec::new(),
        };
        let tracked: Vec<BoxDetection> = detections.iter().map(|d| d.tracked.clone()).collect();
        let dt_s = self
            .previous
            .as_ref()
            .map_or(0.1, |p| (time_s - p.time_s).max(1e-3));
        self.tracker.step(dt_s, &tracked)?;
        let target = self
            .tracker
            .select_target(TargetPolicy::MostHits)
            .map(|t| t.detection_index());
        report.tracked = true;
        let Some(matched) = target else {
            // No confirmed target: the velocity history ends here.
            self.observer.reset();
            self.previous = Some(PreviousFrame {
                time_s,
                features: None,
                target_px: None,
                uav_relative_ned_m: None,
            });
            return Ok(report);
        };
        // The target's pixel is the detection its track took, in the frame's own pixels as the
        // projection needs them (the track's box is in level pixels, and filtered). A frame
        // whose detection is missing is bridged in the world frame: the last fix is carried
        // forward by the UAV's and the platform's velocities (see `estimate_at`), while the
        // track's prediction keeps the association.
        let detection = matched.and_then(|index| detections.get(index));
        let detected_px = detection.map(|d| d.centre_px);
        self.record_fix(time_s, detected_px, &state.attitude, altitude_m);
        // The platform's motion between this frame and the previous one, when the target was
        // detected in both: from high enough up by the seed's motion compensation (the
        // homography of the ground between the frames), lower down by the UAV's own motion.
        let features = self.ground_features(frame, detection, altitude_m);
        let previous = self.previous.take();
        let instant = match (&previous, detected_px, self.fix) {
            (Some(p), Some(current_px), Some(fix)) if p.target_px.is_some() => {
                let dt_s = time_s - p.time_s;
                match (&p.features, &features) {
                    (Some(previous_features), Some(current_features)) => {
                        let motion = self.compensated_motion(
                            previous_features,
                            current_features,
                            p.target_px.unwrap_or(current_px),
                            current_px,
                            altitude_m,
                            dt_s,
                        );
                        motion.unwrap_or_else(|error| {
                            report.homography_error = Some(error);
                            None
                        })
                    }
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
            self.observe_platform_motion(time_s, &instant, state.attitude.yaw_rad);
        }
        self.previous = Some(PreviousFrame {
            time_s,
            features,
            target_px: detected_px,
            uav_relative_ned_m: detected_px.and(self.fix.map(|f| f.uav_relative_ned_m)),
        });
        Ok(report)
    }

    /// The frame's altitude above the pad: from its depth image, else the autopilot's height,
    /// with why (and whether the UAV was airborne then) in `report` and the status counted.
    fn frame_altitude_m(
        &mut self,
        frame: &FrameInput<'_>,
        state: &VehicleSample,
        report: &mut FrameReport,
    ) -> f64 {
        let time_s = frame.time_s;
        match self.depth_altitude_m(frame.frame_index, frame.depth, time_s, &state.attitude) {
            Ok(altitude_m) => {
                self.status.depth_altitudes += 1;
                self.status.altitude_from_depth = true;
                altitude_m
            }
            Err(fallback) => {
                self.status.depth_fallbacks += 1;
                self.status.altitude_from_depth = false;
                // On the ground, in the take-off and in the last of the landing the stereo
                // camera is too near to measure: expected.
                let near = |height_m: f64| height_m < 1.5 * self.window.min_depth_m;
                report.fallback_airborne = !state.landed
                    && !near(state.height_above_pad_m)
                    && !self
                        .altitude_filter
                        .estimate()
                        .is_some_and(|e| near(e.altitude_m) && time_s - e.time_s < 2.0);
                self.status.last_depth_error = Some(fallback.to_string());
                report.altitude_fallback = Some(fallback);
                state.height_above_pad_m
            }
        }
    }

    /// A detection of the target at `detected_px` becomes the fix (its relative position at
    /// `time_s`, when the pixel projects onto the pad's plane); a frame without one is counted
    /// as bridged.
    fn record_fix(
        &mut self,
        time_s: f64,
        detected_px: Option<(f64, f64)>,
        attitude: &Attitude,
        altitude_m: f64,
    ) {
        match detected_px {
            Some((u, v)) => {
                self.status.detections += 1;
                self.last_fix_time_s = Some(time_s);
                if let Ok(pad_relative) =
                    pad_relative_to_uav_ned_m(&self.camera, attitude, altitude_m, u, v)
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
    }

    /// The relative position at `now_s`: the last fix carried forward from its capture (the
    /// UAV moved, the platform moved); `None` before the first fix.
    pub fn estimate_at(&self, now_s: f64) -> Option<HybridEstimate> {
        let fix = self.fix?;
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
        Some(HybridEstimate {
            estimate: RelativeEstimate {
                time_s: now_s,
                uav_relative_ned_m: relative,
                covariance_m2: covariance,
            },
            platform_velocity_ned_m_s: self.platform_velocity_ned_m_s,
            last_fix_time_s: self.last_fix_time_s,
        })
    }
}

/// The pixel at which a level camera facing north, at the same place, would see what `camera`
/// on a vehicle at `attitude` sees at (u, v): the tracker works in these coordinates, where the
/// target moves only as the UAV and the platform move, not as the UAV tilts. `None` for a pixel
/// at or above the horizon.
pub fn level_pixel(
    camera: &PinholeCamera,
    attitude: &Attitude,
    u: f64,
    v: f64,
) -> Option<(f64, f64)> {
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

#[cfg(test)]
mod tests;
