//! The plugin on the bus in virtual time, fed by a world that renders a pad driving under a
//! hovering UAV: frames, exact depth (or none, or all holes), the autopilot's state and,
//! where the test controls detections, the detector's observations.

use super::*;
use crate::bus::Publisher;
use crate::catalog::{PluginInfo, Port};
use crate::config::{Knob, Resource, TaskConfig};
use crate::scheduler::SchedulerBuilder;
use algorithms::camera::CameraPose;
use algorithms::camera::PinholeCamera;
use algorithms::estimation::projection::Attitude;
use algorithms::vision::image::DepthImage;
use algorithms::vision::landing_marker::{
    CentreSource, LandingMarkerLayout, LandingMarkerObservation,
};
use algorithms::vision::render::{render, render_depth, true_pixel, RenderOptions, Scene, Texture};
use nalgebra::{Point3, Vector3};
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
    state: Publisher<VehicleState>,
    frames: Publisher<CameraFrame>,
    depths: Publisher<DepthFrame>,
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
            state: build.output(VEHICLE_STATE)?,
            frames: build.output(CAMERA_FRAME)?,
            depths: build.output(DEPTH_FRAME)?,
            markers,
        })
    }
}

impl Task for World {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let c = &self.config;
        let now = ctx.now();
        let t = now.as_secs_f64();
        self.state.publish(
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
        self.frames.publish(
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
            self.depths.publish(
                now,
                DepthFrame {
                    frame_index: self.frame_index,
                    image: Arc::new(depth),
                },
            );
        }
        if let (Some(dropped), Some(markers)) = (&c.observations, &self.markers) {
            let project =
                |n: f64, e: f64| true_pixel(&self.camera, &pose, &Point3::new(n, e, 0.0)).unwrap();
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
        trigger: Default::default(),
        max_idle_ms: None,
        config_dir: None,
        camera: Default::default(),
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
        super::super::build_from_params(PLUGIN_NAME, text, HybridTrackingTask::new)
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
        ("velocity_averaging = \"median\"", "speed_and_course"),
        ("altitude_windw_fraction = 0.1", "altitude_windw_fraction"),
    ] {
        let Err(TaskError::Params(why)) = build(text) else {
            panic!("`{text}` was accepted");
        };
        assert!(why.contains(named), "`{text}`: {why}");
    }
    // The mission's camera, not a param of the task's, and a bad one is named.
    let flat = crate::config::CameraSettings {
        horizontal_fov_deg: 0.0,
        ..Default::default()
    };
    let Err(TaskError::Params(why)) =
        super::super::build_with_camera(PLUGIN_NAME, "", flat, HybridTrackingTask::new)
    else {
        panic!("a camera with no field of view was accepted");
    };
    assert!(why.contains("camera"), "{why}");
    assert!(build("camera_horizontal_fov_deg = 60.0").is_err());
}
