//! The `landing_marker` plugin: the n-fold + ArUco landing-marker detector on the CPU, at the
//! task's QoS rate, reading the newest camera frame and publishing what it saw.

use crate::bus::{Publisher, Subscriber};
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::{Task, TaskBuild, TaskContext, TaskError};
use crate::topics::{CameraFrame, MarkerObservation, CAMERA_FRAME, LANDING_MARKER};
use algorithms::vision::landing_marker::{
    LandingMarkerConfig, LandingMarkerDetector, LandingMarkerLayout,
};
use algorithms::vision::nfold::Roi;
use serde::Deserialize;
use std::sync::Arc;

pub const PLUGIN_NAME: &str = "landing_marker";

/// `[task.params]` of the plugin.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// n of the n-fold marker; must match the layout's.
    #[serde(default = "default_order")]
    nfold_order: u32,
    /// The smallest correlation kernel (odd, px); larger ones are tried when it fails.
    #[serde(default = "default_kernel")]
    kernel_size_px: usize,
    /// Candidates below this quality are rejected.
    #[serde(default = "default_quality")]
    quality_threshold: f64,
    /// Half-side of the search box around the previous detection (at least; it grows with the
    /// pad's size in the image, so the whole pad is in it); 0 searches every frame whole.
    #[serde(default = "default_roi")]
    roi_half_size_px: f64,
    /// The pad's layout; the reference pad when absent.
    #[serde(default)]
    layout: Option<LandingMarkerLayout>,
}

fn default_order() -> u32 {
    4
}
fn default_kernel() -> usize {
    13
}
fn default_quality() -> f64 {
    0.5
}
fn default_roi() -> f64 {
    60.0
}

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    super::register_builtin(registry, PLUGIN_NAME, LandingMarkerTask::new)
}

pub struct LandingMarkerTask {
    detector: LandingMarkerDetector,
    roi_half_size_px: f64,
    /// Centre and (if known) size in pixels of the pad in the last frame it was seen in.
    last_seen: Option<([f64; 2], Option<f64>)>,
    /// The previous frame, to recognise a frozen camera: a live sensor's noise never repeats a
    /// frame bit for bit.
    previous_frame: Option<CameraFrame>,
    frames: Subscriber<CameraFrame>,
    output: Publisher<MarkerObservation>,
}

impl LandingMarkerTask {
    fn new(params: Params, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        let layout = params.layout.unwrap_or_default();
        if layout.nfold_order != params.nfold_order {
            return Err(TaskError::Params(format!(
                "nfold_order = {} but the layout's n-fold marker has order {}",
                params.nfold_order, layout.nfold_order
            )));
        }
        let mut config = LandingMarkerConfig {
            layout,
            ..LandingMarkerConfig::default()
        };
        config.nfold.order = params.nfold_order;
        config.nfold.oriented = config.layout.nfold_oriented;
        config.nfold.quality_threshold = params.quality_threshold;
        config.nfold.kernel_sizes_px = [0, 4, 8, 12]
            .iter()
            .map(|grow| params.kernel_size_px + grow)
            .collect();
        let detector =
            LandingMarkerDetector::new(config).map_err(|e| TaskError::Params(e.to_string()))?;
        Ok(Self {
            detector,
            roi_half_size_px: params.roi_half_size_px,
            last_seen: None,
            previous_frame: None,
            frames: build.input(CAMERA_FRAME)?,
            output: build.output(LANDING_MARKER)?,
        })
    }
}

impl Task for LandingMarkerTask {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let (frames, output) = (&mut self.frames, &self.output);
        // Only the newest frame matters; none new since the last step means nothing to do.
        let Some(message) = frames.take_new() else {
            return Ok(());
        };
        let frame = &message.value;
        let frozen = self.previous_frame.as_ref().filter(|previous| {
            previous.frame_index != frame.frame_index
                && (Arc::ptr_eq(&previous.image, &frame.image)
                    || previous.image.data() == frame.image.data())
        });
        if let Some(previous) = frozen {
            let error = format!(
                "camera frozen: frame {} repeats frame {} exactly",
                frame.frame_index, previous.frame_index
            );
            tracing::warn!(task = ctx.name(), frame = frame.frame_index, %error, "stale camera frame");
            self.last_seen = None;
            let published = MarkerObservation {
                frame_index: frame.frame_index,
                observation: None,
                frame_error: Some(error),
                used_roi: false,
            };
            output.publish(message.stamp, published);
            return Ok(());
        }
        self.previous_frame = Some(frame.clone());
        // Search around the last detection first (cheap), the whole frame when that fails.
        let roi =
            self.last_seen
                .filter(|_| self.roi_half_size_px > 0.0)
                .map(|([u, v], pad_size_px)| {
                    let half_px = self.roi_half_size_px.max(pad_size_px.unwrap_or(0.0) * 0.8);
                    Roi::around(u, v, half_px)
                });
        let view = frame.image.view();
        let mut used_roi = roi.is_some();
        let mut result = self.detector.detect(&view, roi.as_ref());
        if matches!(result, Ok(None)) && roi.is_some() {
            used_roi = false;
            result = self.detector.detect(&view, None);
        }
        let published = match result {
            Ok(observation) => {
                self.last_seen = observation.as_ref().map(|o| (o.centre_px, o.pad_size_px));
                MarkerObservation {
                    frame_index: frame.frame_index,
                    observation,
                    frame_error: None,
                    used_roi,
                }
            }
            Err(error) => {
                // A bad frame is the camera's fault, not the detector's: report it, keep going.
                tracing::warn!(task = ctx.name(), frame = frame.frame_index, %error, "unreadable camera frame");
                self.last_seen = None;
                MarkerObservation {
                    frame_index: frame.frame_index,
                    observation: None,
                    frame_error: Some(error.to_string()),
                    used_roi: false,
                }
            }
        };
        output.publish(message.stamp, published);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::{PluginInfo, Port};
    use crate::config::{Knob, Resource, TaskConfig};
    use crate::scheduler::SchedulerBuilder;
    use crate::topics::CameraFrame;
    use algorithms::camera::{CameraPose, PinholeCamera};
    use algorithms::vision::image::GrayImage;
    use algorithms::vision::render::{render, true_pixel, RenderOptions, Scene, Texture};
    use nalgebra::Vector3;
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    /// A camera over a pad that moves 0.2 m east per frame, publishing rendered frames and
    /// recording where the pad's centre truly is in each.
    struct RenderedCamera {
        frame_index: u64,
        truth: Arc<Mutex<Vec<[f64; 2]>>>,
        output: Publisher<CameraFrame>,
    }

    impl Task for RenderedCamera {
        fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
            let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
            let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -4.0), 0.05, -0.04, 0.3);
            let east_m = -0.8 + 0.2 * self.frame_index as f64;
            let mut scene = Scene::new(Texture::field(7));
            scene.patches = LandingMarkerLayout::default()
                .patches(0.3, east_m, 0.0, 1.0)
                .unwrap();
            let image = render(&camera, &pose, &scene, &RenderOptions::default()).unwrap();
            let centre =
                true_pixel(&camera, &pose, &scene.patches[0].point_world(0.0, 0.0)).unwrap();
            self.truth.lock().unwrap().push([centre.0, centre.1]);
            let frame = CameraFrame {
                vehicle_at_capture: None,
                frame_index: self.frame_index,
                image: Arc::new(image),
            };
            self.output.publish(ctx.now(), frame);
            self.frame_index += 1;
            Ok(())
        }
    }

    fn task_config(name: &str, plugin: &str, params: &str) -> TaskConfig {
        TaskConfig {
            name: name.into(),
            plugin: plugin.into(),
            resource: Resource::Cpu,
            cores: vec![],
            phases: vec!["landing".into()],
            weight: 1.0,
            knob: Knob::RateFps,
            levels: vec![10.0],
            utility: vec![1.0],
            restart: None,
            params: toml::from_str(params).unwrap(),
            trigger: Default::default(),
            max_idle_ms: None,
            config_dir: None,
            camera: Default::default(),
        }
    }

    #[test]
    fn the_detection_plugin_runs_under_the_scheduler_on_rendered_frames() {
        let mut registry = crate::plugins::builtin_registry().unwrap();
        let truth = Arc::new(Mutex::new(Vec::new()));
        let camera_truth = truth.clone();
        let info = PluginInfo {
            outputs: const { &[Port::of(CAMERA_FRAME)] },
            ..PluginInfo::user("rendered_camera")
        };
        registry
            .register_plugin(info, move |build| {
                Ok(Box::new(RenderedCamera {
                    frame_index: 0,
                    truth: camera_truth.clone(),
                    output: build.output(CAMERA_FRAME)?,
                }))
            })
            .unwrap();
        // The reference mission's detection task, its params as qos.toml gives them.
        let reference = include_str!("../../../qos.toml");
        let catalog = crate::catalog::PluginCatalog::builtin();
        let config = crate::config::load_str(reference, None, &catalog).unwrap();
        let detection = config.task("detection").unwrap().clone();
        let camera = task_config("camera", "rendered_camera", "step_cost_ms = [1.0]");

        let mut scheduler = SchedulerBuilder::new(&registry)
            .task(&camera)
            .task(&detection)
            .build_virtual()
            .unwrap();
        let mut observations = scheduler
            .bus()
            .subscriber::<MarkerObservation>(LANDING_MARKER)
            .unwrap();
        scheduler.start().unwrap();
        let mut seen = Vec::new();
        // The camera runs at 10 fps (its only level); detection at its highest level, 10 fps.
        for _ in 0..8 {
            scheduler.run_for(Duration::from_millis(100)).unwrap();
            if let Some(message) = observations.take_new() {
                seen.push(message.value.clone());
            }
        }
        let truth = truth.lock().unwrap();
        assert!(seen.len() >= 6, "{} observations", seen.len());
        for message in &seen {
            let observation = message.observation.as_ref().expect("the pad is in view");
            let [u, v] = truth[message.frame_index as usize];
            let error = (observation.centre_px[0] - u).hypot(observation.centre_px[1] - v);
            assert!(
                error < 1.0,
                "frame {}: error {error} px",
                message.frame_index
            );
        }
        // After the first detection the detector searches around it.
        assert!(seen.iter().skip(1).any(|m| m.used_roi));
        let stats = scheduler.task_stats("detection").unwrap();
        assert!(stats.activations >= 7 && stats.failures == 0, "{stats:?}");
    }

    #[test]
    fn a_bad_frame_is_reported_and_the_task_goes_on() {
        let registry = crate::plugins::builtin_registry().unwrap();
        let detection = task_config("detection", PLUGIN_NAME, "");
        let mut scheduler = SchedulerBuilder::new(&registry)
            .task(&detection)
            .build_virtual()
            .unwrap();
        let frames = scheduler
            .bus()
            .publisher::<CameraFrame>(CAMERA_FRAME)
            .unwrap();
        let mut observations = scheduler
            .bus()
            .subscriber::<MarkerObservation>(LANDING_MARKER)
            .unwrap();
        scheduler.start().unwrap();
        // Too small for the detector's kernels.
        let tiny = GrayImage::filled(8, 8, 128).unwrap();
        frames.publish(
            scheduler.now(),
            CameraFrame {
                vehicle_at_capture: None,
                frame_index: 0,
                image: Arc::new(tiny),
            },
        );
        scheduler.run_for(Duration::from_millis(150)).unwrap();
        let message = observations
            .take_new()
            .expect("an observation of the bad frame");
        assert!(message.value.observation.is_none());
        assert!(message
            .value
            .frame_error
            .as_deref()
            .unwrap()
            .contains("8×8"));
        let stats = scheduler.task_stats("detection").unwrap();
        assert_eq!(stats.failures, 0);
        assert!(!scheduler.health().is_degraded());
    }

    /// A frozen camera delivers the same picture under new frame numbers: the detector says so
    /// instead of reporting a stale pad position as fresh. A copy of the same bytes counts too.
    #[test]
    fn a_frozen_camera_is_named_and_not_a_detection() {
        let registry = crate::plugins::builtin_registry().unwrap();
        let detection = task_config("detection", PLUGIN_NAME, "");
        let mut scheduler = SchedulerBuilder::new(&registry)
            .task(&detection)
            .build_virtual()
            .unwrap();
        let frames = scheduler
            .bus()
            .publisher::<CameraFrame>(CAMERA_FRAME)
            .unwrap();
        let mut observations = scheduler
            .bus()
            .subscriber::<MarkerObservation>(LANDING_MARKER)
            .unwrap();
        scheduler.start().unwrap();
        let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -5.0), 0.0, 0.0, 0.3);
        let mut scene = Scene::new(Texture::field(2));
        scene.patches = LandingMarkerLayout::default()
            .patches(0.3, 0.2, 0.0, 0.0)
            .unwrap();
        let image = Arc::new(render(&camera, &pose, &scene, &RenderOptions::default()).unwrap());
        let copy = Arc::new((*image).clone());
        let mut results = Vec::new();
        for (frame_index, image) in [(0, image.clone()), (1, image), (2, copy)] {
            frames.publish(
                scheduler.now(),
                CameraFrame {
                    vehicle_at_capture: None,
                    frame_index,
                    image,
                },
            );
            scheduler.run_for(Duration::from_millis(150)).unwrap();
            results.push(
                observations
                    .take_new()
                    .expect("an observation")
                    .value
                    .clone(),
            );
        }
        assert!(results[0].observation.is_some(), "{:?}", results[0]);
        for frozen in &results[1..] {
            assert!(frozen.observation.is_none());
            let error = frozen.frame_error.as_deref().expect("a named error");
            assert!(
                error.contains("camera frozen") && error.contains("frame 0"),
                "{error}"
            );
        }
        assert_eq!(scheduler.task_stats("detection").unwrap().failures, 0);
    }

    #[test]
    fn params_that_contradict_the_layout_are_refused() {
        let registry = crate::plugins::builtin_registry().unwrap();
        let detection = task_config("detection", PLUGIN_NAME, "nfold_order = 6");
        let error = SchedulerBuilder::new(&registry)
            .task(&detection)
            .build_virtual()
            .err()
            .expect("a build error");
        assert!(error.to_string().contains("nfold_order = 6"), "{error}");
        let detection = task_config("detection", PLUGIN_NAME, "kernal_size_px = 13");
        let error = SchedulerBuilder::new(&registry)
            .task(&detection)
            .build_virtual()
            .err()
            .expect("a build error");
        assert!(error.to_string().contains("kernal_size_px"), "{error}");
    }
}
