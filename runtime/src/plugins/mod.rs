//! The task plugins built into qosrt, and the registry that holds them.

pub mod ground_stereo;
pub mod hazard_cnn;
pub mod hybrid_tracking;
pub mod kalman_tracker;
pub mod landing_guidance;
pub mod landing_marker;

use crate::catalog::BUILTIN_PLUGINS;
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::{Task, TaskBuild, TaskError};
use serde::de::DeserializeOwned;

/// Registers the built-in plugin `name` with its catalogue entry (the resources, knobs and ports
/// it has); each task is made by `make` from its parsed `[task.params]` and its ports.
fn register_builtin<P, T>(
    registry: &mut PluginRegistry,
    name: &'static str,
    make: fn(P, &TaskBuild<'_>) -> Result<T, TaskError>,
) -> Result<(), RegistryError>
where
    P: DeserializeOwned + 'static,
    T: Task + 'static,
{
    let info = BUILTIN_PLUGINS
        .iter()
        .find(|p| p.name == name)
        .cloned()
        .expect("the catalogue lists every built-in plugin");
    registry.register_plugin(info, move |build| {
        Ok(Box::new(make(build.parse_params()?, build)?) as Box<dyn Task>)
    })?;
    Ok(())
}

/// Builds a built-in plugin's task for `config` on `bus`, as the registry would (a plugin's
/// tests, which look inside the concrete task).
#[cfg(test)]
pub(crate) fn build_for_test<T>(
    config: &crate::config::TaskConfig,
    bus: &crate::bus::Bus,
    make: impl FnOnce(&TaskBuild<'_>) -> Result<T, TaskError>,
) -> Result<T, TaskError> {
    let info = BUILTIN_PLUGINS
        .iter()
        .find(|p| p.name == config.plugin)
        .expect("a built-in plugin");
    make(&TaskBuild::new(&config.params, config, info, bus))
}

/// Builds a built-in plugin's task from its params `text` on a bus of its own, as the registry
/// would (a plugin's tests of its params).
#[cfg(test)]
pub(crate) fn build_from_params<P: DeserializeOwned, T>(
    plugin: &str,
    text: &str,
    make: impl FnOnce(P, &TaskBuild<'_>) -> Result<T, TaskError>,
) -> Result<T, TaskError> {
    build_with_camera(plugin, text, Default::default(), make)
}

/// [`build_from_params`] with the mission's `[camera]`.
#[cfg(test)]
pub(crate) fn build_with_camera<P: DeserializeOwned, T>(
    plugin: &str,
    text: &str,
    camera: crate::config::CameraSettings,
    make: impl FnOnce(P, &TaskBuild<'_>) -> Result<T, TaskError>,
) -> Result<T, TaskError> {
    let config = crate::config::TaskConfig {
        name: plugin.into(),
        plugin: plugin.into(),
        resource: crate::config::Resource::Cpu,
        cores: vec![],
        phases: vec!["tracking".into()],
        weight: 1.0,
        knob: crate::config::Knob::PeriodMs,
        levels: vec![20.0],
        utility: vec![1.0],
        restart: None,
        params: toml::from_str(text).expect("test params are TOML"),
        trigger: Default::default(),
        max_idle_ms: None,
        config_dir: None,
        camera,
    };
    build_for_test(&config, &crate::bus::Bus::new(), |build| {
        make(build.parse_params()?, build)
    })
}

/// A registry with every built-in plugin; users add their own to it.
pub fn builtin_registry() -> Result<PluginRegistry, RegistryError> {
    let mut registry = PluginRegistry::new();
    landing_marker::register(&mut registry)?;
    kalman_tracker::register(&mut registry)?;
    landing_guidance::register(&mut registry)?;
    hazard_cnn::register(&mut registry)?;
    ground_stereo::register(&mut registry)?;
    hybrid_tracking::register(&mut registry)?;
    Ok(registry)
}

#[cfg(test)]
mod tests {
    //! The landing loop's three plugins chained on the bus in virtual time: rendered frames →
    //! detection → tracking → landing guidance.

    use super::builtin_registry;
    use crate::bus::Publisher;
    use crate::catalog::PluginCatalog;
    use crate::catalog::{PluginInfo, Port};
    use crate::config::load_str;
    use crate::scheduler::SchedulerBuilder;
    use crate::task::{Task, TaskBuild, TaskContext, TaskError};
    use crate::topics::{
        CameraFrame, LandingSetpoint, MissionPhase, RelativeState, VehicleState, CAMERA_FRAME,
        LANDING_SETPOINT, MISSION_PHASE, RELATIVE_STATE, VEHICLE_STATE,
    };
    use algorithms::camera::{CameraPose, PinholeCamera};
    use algorithms::control::landing::LandingMode;
    use algorithms::estimation::camera_mount::CameraMount;
    use algorithms::estimation::projection::Attitude;
    use algorithms::vision::landing_marker::LandingMarkerLayout;
    use algorithms::vision::render::{
        apply_effects, render, ImageEffects, RenderOptions, Scene, Texture,
    };
    use nalgebra::Vector3;
    use std::sync::Arc;
    use std::time::Duration;

    const PAD_NORTH_M: f64 = 0.6;
    const PAD_EAST_M: f64 = -0.4;
    const HEIGHT_M: f64 = 5.0;
    const ROLL_RAD: f64 = 0.03;
    const PITCH_RAD: f64 = -0.05;
    const YAW_RAD: f64 = 0.4;

    /// A vehicle leaning this far into the wind while its gimbal holds the camera at the
    /// attitude above: projected with the vehicle's attitude, a fix from 5 m would be 1.8 m off.
    const LEAN_RAD: f64 = 0.35;

    /// A hovering vehicle over a still pad: its camera's frames and its autopilot's state.
    /// The camera is on a gimbal that reports it (the reference config's mount), or, with
    /// `body_camera`, fixed to a vehicle with the camera's attitude.
    struct HoveringVehicle {
        body_camera: bool,
        /// A few frames differing only in sensor noise: a live camera never repeats a frame.
        noisy_frames: Vec<Arc<algorithms::vision::image::GrayImage>>,
        frame_index: u64,
        frames: Publisher<CameraFrame>,
        state: Publisher<VehicleState>,
    }

    /// The hovering vehicle's plugin: it publishes what the mission would.
    const HOVERING_VEHICLE: PluginInfo = PluginInfo {
        outputs: &[Port::of(CAMERA_FRAME), Port::of(VEHICLE_STATE)],
        ..PluginInfo::user("hovering_vehicle")
    };

    impl HoveringVehicle {
        fn new(body_camera: bool, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
            let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
            let pose = CameraPose::downward(
                Vector3::new(0.0, 0.0, -HEIGHT_M),
                ROLL_RAD,
                PITCH_RAD,
                YAW_RAD,
            );
            let mut scene = Scene::new(Texture::field(5));
            scene.patches = LandingMarkerLayout::default()
                .patches(PAD_NORTH_M, PAD_EAST_M, 0.0, 0.9)
                .unwrap();
            let frame = render(&camera, &pose, &scene, &RenderOptions::default()).unwrap();
            let noisy_frames = (1..=3)
                .map(|noise_seed| {
                    let effects = ImageEffects {
                        noise_sigma: 2.0,
                        noise_seed,
                        ..ImageEffects::default()
                    };
                    Arc::new(apply_effects(&frame, &effects).unwrap())
                })
                .collect();
            Ok(Self {
                body_camera,
                noisy_frames,
                frame_index: 0,
                frames: build.output(CAMERA_FRAME)?,
                state: build.output(VEHICLE_STATE)?,
            })
        }
    }

    impl Task for HoveringVehicle {
        fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
            let camera = Attitude::new(ROLL_RAD, PITCH_RAD, YAW_RAD);
            let state = VehicleState {
                attitude: if self.body_camera {
                    camera
                } else {
                    Attitude::new(LEAN_RAD, PITCH_RAD, YAW_RAD)
                },
                velocity_ned_m_s: Vector3::zeros(),
                acceleration_ned_m_s2: Vector3::zeros(),
                height_above_pad_m: HEIGHT_M,
                position_ned_m: Some(Vector3::new(0.0, 0.0, -HEIGHT_M)),
                landed: false,
                gimbal_attitude: (!self.body_camera).then_some(camera),
                offboard: true,
            };
            self.state.publish(ctx.now(), state);
            let frame = CameraFrame {
                vehicle_at_capture: None,
                frame_index: self.frame_index,
                image: self.noisy_frames[self.frame_index as usize % 3].clone(),
            };
            self.frames.publish(ctx.now(), frame);
            self.frame_index += 1;
            Ok(())
        }
    }

    /// The hovering vehicle as a task at the detector's rate. It makes the frames detection is
    /// triggered by: it runs on its period.
    fn hovering_vehicle_task(config: &crate::config::MissionConfig) -> crate::config::TaskConfig {
        let mut vehicle = config.task("detection").unwrap().clone();
        vehicle.name = "vehicle".into();
        vehicle.plugin = "hovering_vehicle".into();
        vehicle.params = toml::Table::new();
        vehicle.trigger = crate::config::TaskTrigger::Period;
        vehicle
    }

    /// The reference config's chain on a camera mounted as `mount` says, the vehicle's
    /// camera mounted as `body_camera` says: the tracker's estimate after 2 s, and the chain's
    /// scheduler and setpoints.
    fn run_chain(
        mount: CameraMount,
        body_camera: bool,
    ) -> (
        crate::scheduler::VirtualScheduler,
        Option<RelativeState>,
        Option<LandingSetpoint>,
    ) {
        let mut registry = builtin_registry().unwrap();
        registry
            .register_plugin(HOVERING_VEHICLE, move |build| {
                Ok(Box::new(HoveringVehicle::new(body_camera, build)?))
            })
            .unwrap();
        let reference = include_str!("../../../qos.toml");
        let config = load_str(reference, None, &PluginCatalog::builtin()).unwrap();
        let vehicle = hovering_vehicle_task(&config);
        let mut builder = SchedulerBuilder::new(&registry);
        builder.task(&vehicle);
        let mut tasks = Vec::new();
        for name in ["detection", "tracking", "landing"] {
            let mut task = config.task(name).unwrap().clone();
            if name != "detection" {
                task.camera.mount = mount;
            }
            tasks.push(task);
        }
        for task in &tasks {
            builder.task(task);
        }
        let mut scheduler = builder.build_virtual().unwrap();
        let mut relative = scheduler
            .bus()
            .subscriber::<RelativeState>(RELATIVE_STATE)
            .unwrap();
        let mut setpoints = scheduler
            .bus()
            .subscriber::<LandingSetpoint>(LANDING_SETPOINT)
            .unwrap();
        scheduler.start().unwrap();
        scheduler.run_for(Duration::from_secs(2)).unwrap();
        let relative = relative.latest().map(|m| m.value);
        let setpoint = setpoints.latest().map(|m| m.value);
        (scheduler, relative, setpoint)
    }

    /// On a gimbal (the reference config) or fixed to the body, the fix is placed with the
    /// attitude the camera had: the vehicle leaning 20° under its gimbal changes nothing.
    #[test]
    fn frames_become_a_relative_position_and_landing_setpoints() {
        for (mount, body_camera) in [(CameraMount::Gimbal, false), (CameraMount::Body, true)] {
            chain_finds_the_pad(mount, body_camera);
        }
    }

    fn chain_finds_the_pad(mount: CameraMount, body_camera: bool) {
        let (scheduler, relative, setpoint) = run_chain(mount, body_camera);
        let estimate = relative.expect("a relative state").estimate;
        // UAV − pad, NED: the vehicle is at the origin, HEIGHT_M above the pad.
        let truth = Vector3::new(-PAD_NORTH_M, -PAD_EAST_M, -HEIGHT_M);
        let error_m = (estimate.uav_relative_ned_m - truth).norm();
        assert!(
            error_m < 0.05,
            "estimate {:?}, error {error_m} m",
            estimate.uav_relative_ned_m
        );
        let setpoint = setpoint.expect("a setpoint");
        assert_ne!(setpoint.mode, LandingMode::Search, "{setpoint:?}");
        assert!(setpoint
            .velocity_setpoint_ned_m_s
            .iter()
            .all(|v| v.is_finite()));
        for name in ["detection", "tracking", "landing"] {
            let stats = scheduler.task_stats(name).unwrap();
            assert_eq!(stats.failures, 0, "{name}: {stats:?}");
            assert!(stats.activations > 10, "{name}: {stats:?}");
        }
    }

    /// A config that says "body" on a vehicle whose camera hangs in a gimbal projects with the
    /// lean, and lands its fix h·tan(lean) away; one that says "gimbal" on a vehicle with no
    /// gimbal places no fix at all (and so never steers towards a wrong one).
    #[test]
    fn a_camera_mount_that_is_not_the_vehicles_is_no_good_fix() {
        let (_, relative, _) = run_chain(CameraMount::Body, false);
        let estimate = relative.expect("a relative state").estimate;
        let truth = Vector3::new(-PAD_NORTH_M, -PAD_EAST_M, -HEIGHT_M);
        let error_m = (estimate.uav_relative_ned_m - truth).xy().norm();
        let lean_shift_m = HEIGHT_M * ((LEAN_RAD).tan() - ROLL_RAD.tan());
        assert!(error_m > 0.5 * lean_shift_m, "error {error_m} m");
        let (_, relative, setpoint) = run_chain(CameraMount::Gimbal, true);
        assert!(relative.is_none(), "{relative:?}");
        assert_eq!(setpoint.map(|s| s.mode), Some(LandingMode::Search));
    }

    /// The chain with the landing task's IH at the hovering height, so the descent is only a
    /// matter of the phase: the tracking phase follows, the landing phase descends; with
    /// either controller.
    fn descent_waits_for_the_landing_phase(controller: &str) {
        let mut registry = builtin_registry().unwrap();
        registry
            .register_plugin(HOVERING_VEHICLE, |build| {
                Ok(Box::new(HoveringVehicle::new(false, build)?))
            })
            .unwrap();
        let reference = include_str!("../../../qos.toml");
        let config = load_str(reference, None, &PluginCatalog::builtin()).unwrap();
        let vehicle = hovering_vehicle_task(&config);
        let mut landing = config.task("landing").unwrap().clone();
        landing
            .params
            .insert("initial_altitude_m".into(), HEIGHT_M.into());
        landing
            .params
            .insert("controller".into(), controller.to_string().into());
        if controller == "mpc" {
            // What is tested is the phase gating, not this machine's speed: a solve that runs
            // late on a loaded machine would fly the fallback (hold the platform's velocity).
            landing
                .params
                .insert("mpc_solve_time_limit_s".into(), 0.5.into());
        }
        let mut builder = SchedulerBuilder::new(&registry);
        builder.task(&vehicle);
        builder.task(config.task("detection").unwrap());
        builder.task(config.task("tracking").unwrap());
        builder.task(&landing);
        let mut scheduler = builder.build_virtual().unwrap();
        let phase = scheduler
            .bus()
            .publisher::<MissionPhase>(MISSION_PHASE)
            .unwrap();
        let mut setpoints = scheduler
            .bus()
            .subscriber::<LandingSetpoint>(LANDING_SETPOINT)
            .unwrap();
        scheduler.start().unwrap();
        phase.publish(
            scheduler.now(),
            MissionPhase {
                index: 1,
                name: "tracking".into(),
                landing: false,
            },
        );
        scheduler.run_for(Duration::from_secs(3)).unwrap();
        let following = setpoints.latest().expect("a setpoint").value;
        assert_eq!(
            following.mode,
            LandingMode::Follow,
            "{controller}: {following:?}"
        );
        phase.publish(
            scheduler.now(),
            MissionPhase {
                index: 2,
                name: "landing".into(),
                landing: true,
            },
        );
        scheduler.run_for(Duration::from_secs(2)).unwrap();
        let descending = setpoints.latest().expect("a setpoint").value;
        assert_eq!(
            descending.mode,
            LandingMode::Descend,
            "{controller}: {descending:?}"
        );
        assert!(
            descending.velocity_setpoint_ned_m_s.z > 0.0,
            "{descending:?}"
        );
        // Hovering over a still pad 0.72 m away: the command points at the pad.
        let towards_pad = Vector3::new(PAD_NORTH_M, PAD_EAST_M, 0.0).normalize();
        let horizontal = Vector3::new(
            descending.velocity_setpoint_ned_m_s.x,
            descending.velocity_setpoint_ned_m_s.y,
            0.0,
        );
        assert!(
            horizontal.normalize().dot(&towards_pad) > 0.9,
            "{controller}: {horizontal:?}"
        );
        let stats = scheduler.task_stats("landing").unwrap();
        assert_eq!(stats.failures, 0, "{controller}: {stats:?}");
    }

    #[test]
    fn pid_descends_only_in_the_landing_phase() {
        descent_waits_for_the_landing_phase("pid");
    }

    #[test]
    fn mpc_descends_only_in_the_landing_phase() {
        descent_waits_for_the_landing_phase("mpc");
    }
}
