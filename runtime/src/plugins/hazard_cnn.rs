//! The `hazard_cnn` plugin: a YOLO-style ONNX detector watching the field for people, animals and
//! vehicles at the task's QoS frame rate, each detection placed on the ground in local NED.
//!
//! The model is the one shipped with qosrt (trained on the simulator's renders, compiled into
//! the binary) unless `model = "path.onnx"` names a user's own export; `classes`, the input size,
//! the output layout and the thresholds make any YOLOv3/v5/v8-style export work. A model that
//! cannot be loaded fails the task at start-up with a named error; the scheduler reports it and
//! the mission flies on without hazard detection.

use crate::bus::{Publisher, Subscriber};
use crate::catalog::BUILTIN_PLUGINS;
use crate::config::Resource;
use crate::inference::{
    open_backend, resolve_path, BackendChoice, BackendOptions, InferenceBackend, ModelSource,
};
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::{Task, TaskBuild, TaskContext, TaskError};
use crate::topics::{
    CameraFrame, HazardDetection, HazardReport, RelativeState, VehicleState, CAMERA_FRAME, HAZARDS,
    RELATIVE_STATE, VEHICLE_STATE,
};
use algorithms::camera::PinholeCamera;
use algorithms::estimation::camera_mount::CameraMount;
use algorithms::estimation::projection::{pad_relative_to_uav_ned_m, Attitude};
use algorithms::vision::yolo::{
    decode, letterbox_gray, non_maximum_suppression, Detection, YoloFormat,
};
use nalgebra::Vector3;
use serde::Deserialize;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use crate::inference::pipeline::Pipeline;
use algorithms::vision::image::GrayImage;

/// A frame's boxes and the wall time they took (preprocessing, inference, decoding), ms.
type InferenceResult = Result<(Vec<Detection>, f64), TaskError>;

/// The backend on a thread of its own: a frame and its placement in, the placement and the
/// frame's boxes out.
type InferencePipeline = Pipeline<(Arc<GrayImage>, Placement), (Placement, InferenceResult)>;

/// What places a frame's boxes on the ground, fixed when the frame is taken up.
struct Placement {
    frame_index: u64,
    capture_time_s: f64,
    camera: PinholeCamera,
    /// The camera's attitude and the vehicle's position at the frame's capture.
    at_capture: Option<(Attitude, Option<Vector3<f64>>)>,
    /// The followed pad on the ground (north, east).
    pad_ne_m: Option<(f64, f64)>,
}

pub const PLUGIN_NAME: &str = "hazard_cnn";

/// The detector shipped with qosrt: `cargo run --release -p hazard_train` makes it.
pub const SHIPPED_MODEL: ModelSource = ModelSource::Embedded {
    name: "models/hazard_yolo.onnx",
    bytes: include_bytes!(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../models/hazard_yolo.onnx"
    )),
};
/// The shipped model's classes, in its output's order.
pub const SHIPPED_CLASSES: [&str; 3] = ["person", "animal", "vehicle"];

/// How the model lays out one candidate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum OutputFormat {
    /// `[cx, cy, w, h, objectness, classes…]` (YOLOv3/v5 exports, the shipped model).
    Objectness,
    /// `[cx, cy, w, h, classes…]` (YOLOv8 exports).
    ScoresOnly,
}

/// `[task.params]` of the plugin.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// The ONNX file, relative to the config file; the shipped model when absent.
    #[serde(default)]
    model: Option<PathBuf>,
    /// Class names in the model's output order.
    #[serde(default = "default_classes")]
    classes: Vec<String>,
    #[serde(default = "default_confidence")]
    confidence_threshold: f64,
    /// Boxes of one class overlapping a more confident one by more than this are dropped.
    #[serde(default = "default_iou")]
    iou_threshold: f64,
    #[serde(default = "default_format")]
    output_format: OutputFormat,
    /// Network input size, for models that leave it open.
    #[serde(default)]
    input_width_px: Option<usize>,
    #[serde(default)]
    input_height_px: Option<usize>,
    /// `auto` (CUDA when built in and present, else CPU), `cpu` or `cuda`.
    #[serde(default)]
    backend: BackendChoice,
    /// `libonnxruntime.so` for the CUDA backend.
    #[serde(default)]
    onnxruntime_library: Option<PathBuf>,
    /// At most this many detections per frame are reported, most confident first.
    #[serde(default = "default_max_detections")]
    max_detections: usize,
    /// Frames taken lower than this above the ground are not looked at: a model sees nonsense
    /// outside the heights it was trained on (the shipped one: 4–12 m), e.g. the field's grass
    /// from a take-off or the tractor's roof filling the view while landing.
    #[serde(default = "default_min_height")]
    min_height_m: f64,
    /// Detections on the ground within this distance of the tracked pad are the tractor being
    /// followed, not a hazard beside it (its roof and pad are no hazard); 0 keeps them all.
    #[serde(default = "default_pad_exclusion")]
    pad_exclusion_radius_m: f64,
    /// Infer on a thread of its own: a frame's report is published at the task's next step
    /// (a period later) and the step returns at once, so the tasks sharing the scheduler's
    /// thread (the landing loop) are not held up by an inference, and a simulation renders and
    /// infers on two cores. False: the step waits for the inference and reports at once.
    #[serde(default)]
    pipelined: bool,
}

fn default_classes() -> Vec<String> {
    SHIPPED_CLASSES.iter().map(|c| c.to_string()).collect()
}
fn default_confidence() -> f64 {
    0.4
}
fn default_iou() -> f64 {
    0.45
}
fn default_format() -> OutputFormat {
    OutputFormat::Objectness
}
fn default_max_detections() -> usize {
    100
}
fn default_min_height() -> f64 {
    // The shipped model was trained on frames from 4 to 12 m.
    4.0
}
fn default_pad_exclusion() -> f64 {
    2.5
}

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    let info = BUILTIN_PLUGINS
        .iter()
        .find(|p| p.name == PLUGIN_NAME)
        .cloned()
        .expect("the catalogue lists every built-in plugin");
    // Said once per task, not at every restart.
    let cpu_fallback_said = Arc::new(AtomicBool::new(false));
    registry.register_plugin(info, move |build| {
        let task = HazardCnnTask::new(build.parse_params()?, build, cpu_fallback_said.clone())?;
        Ok(Box::new(task) as Box<dyn Task>)
    })?;
    Ok(())
}

pub struct HazardCnnTask {
    source: ModelSource,
    backend_options: BackendOptions,
    classes: Vec<Arc<str>>,
    format: YoloFormat,
    confidence_threshold: f64,
    iou_threshold: f64,
    horizontal_fov_rad: f64,
    camera_mount: CameraMount,
    max_detections: usize,
    min_height_m: f64,
    pad_exclusion_radius_m: f64,
    resource: Resource,
    cpu_fallback_said: Arc<AtomicBool>,
    pipelined: bool,
    backend: Option<Box<dyn InferenceBackend>>,
    /// With `pipelined`, the backend on its own thread; a frame's placement travels with it.
    pipeline: Option<InferencePipeline>,
    backend_name: &'static str,
    frames: Subscriber<CameraFrame>,
    vehicle: Subscriber<VehicleState>,
    output: Publisher<HazardReport>,
    relative: Subscriber<RelativeState>,
}

impl HazardCnnTask {
    fn new(
        params: Params,
        build: &TaskBuild<'_>,
        cpu_fallback_said: Arc<AtomicBool>,
    ) -> Result<Self, TaskError> {
        let (config_dir, resource) = (
            build.config().config_dir.as_deref(),
            build.config().resource,
        );
        let bad = |message: String| Err(TaskError::Params(message));
        if params.classes.is_empty() || params.classes.iter().any(|c| c.trim().is_empty()) {
            return bad("classes must list at least one non-empty class name".into());
        }
        for (name, value) in [
            ("confidence_threshold", params.confidence_threshold),
            ("iou_threshold", params.iou_threshold),
        ] {
            if !(value.is_finite() && (0.0..=1.0).contains(&value)) {
                return bad(format!("{name} must be within [0, 1], got {value}"));
            }
        }
        // The mission's one camera places detections on the ground (with the gimbal's
        // attitude where it hangs in one).
        let camera = &build.config().camera;
        let fov = camera.horizontal_fov_deg;
        if !(fov.is_finite() && fov > 0.0 && fov < 180.0) {
            return bad(format!(
                "the camera's horizontal_fov_deg must be within (0, 180), got {fov}"
            ));
        }
        if !(params.min_height_m.is_finite() && params.min_height_m >= 0.0) {
            return bad(format!(
                "min_height_m must be a height ≥ 0, got {}",
                params.min_height_m
            ));
        }
        let radius = params.pad_exclusion_radius_m;
        if !(radius.is_finite() && radius >= 0.0) {
            return bad(format!(
                "pad_exclusion_radius_m must be a distance ≥ 0, got {radius}"
            ));
        }
        if params.max_detections == 0 {
            return bad("max_detections must be at least 1".into());
        }
        let input_size_px = match (params.input_height_px, params.input_width_px) {
            (Some(h), Some(w)) => Some((h, w)),
            (None, None) => None,
            _ => return bad("set both input_width_px and input_height_px, or neither".into()),
        };
        let source = match &params.model {
            Some(path) => ModelSource::File(resolve_path(path, config_dir)),
            None => {
                if params.classes != default_classes() {
                    return bad(format!(
                        "the shipped model detects {}; name your own model with `model = \"….onnx\"` to use other classes",
                        SHIPPED_CLASSES.join(", ")
                    ));
                }
                SHIPPED_MODEL
            }
        };
        Ok(Self {
            source,
            backend_options: BackendOptions {
                choice: params.backend,
                input_size_px,
                onnxruntime_library: params
                    .onnxruntime_library
                    .map(|p| resolve_path(&p, config_dir)),
            },
            classes: params
                .classes
                .iter()
                .map(|c| Arc::from(c.as_str()))
                .collect(),
            format: match params.output_format {
                OutputFormat::Objectness => YoloFormat::WithObjectness,
                OutputFormat::ScoresOnly => YoloFormat::ClassScoresOnly,
            },
            confidence_threshold: params.confidence_threshold,
            iou_threshold: params.iou_threshold,
            horizontal_fov_rad: fov.to_radians(),
            camera_mount: camera.mount,
            max_detections: params.max_detections,
            min_height_m: params.min_height_m,
            pad_exclusion_radius_m: params.pad_exclusion_radius_m,
            resource,
            cpu_fallback_said,
            pipelined: params.pipelined,
            backend: None,
            pipeline: None,
            backend_name: "",
            frames: build.input(CAMERA_FRAME)?,
            vehicle: build.input(VEHICLE_STATE)?,
            output: build.output(HAZARDS)?,
            relative: build.input(RELATIVE_STATE)?,
        })
    }

    /// Boxes of one frame: preprocess, infer, decode, suppress.
    fn detect(
        backend: &mut dyn InferenceBackend,
        image: &algorithms::vision::image::ImageView<'_>,
        format: YoloFormat,
        classes: usize,
        confidence_threshold: f64,
        iou_threshold: f64,
    ) -> Result<Vec<Detection>, TaskError> {
        let spec = backend.input();
        let (grey, letterbox) = letterbox_gray(image, spec.width_px, spec.height_px);
        let input = if spec.channels == 3 {
            // A colour model sees the grey frame on all three channels.
            grey.repeat(3)
        } else {
            grey
        };
        let output = backend.run(&input).map_err(TaskError::other)?;
        let detections = decode(
            &output.values,
            &output.shape,
            format,
            classes,
            confidence_threshold,
            &letterbox,
        )
        .map_err(TaskError::other)?;
        non_maximum_suppression(detections, iou_threshold).map_err(TaskError::other)
    }

    /// [`Self::detect`] on a frame, with its wall time in ms.
    fn timed_detect(
        backend: &mut dyn InferenceBackend,
        image: &GrayImage,
        format: YoloFormat,
        classes: usize,
        confidence_threshold: f64,
        iou_threshold: f64,
    ) -> InferenceResult {
        let started = Instant::now();
        let detections = Self::detect(
            backend,
            &image.view(),
            format,
            classes,
            confidence_threshold,
            iou_threshold,
        )?;
        Ok((detections, started.elapsed().as_secs_f64() * 1e3))
    }

    /// Where a frame's boxes will be placed, from the vehicle and the tracker now; `None` for a
    /// frame taken below `min_height_m`, which is not looked at.
    fn placement(
        &mut self,
        frame: &CameraFrame,
        capture_time_s: f64,
    ) -> Result<Option<Placement>, TaskError> {
        let state = self.vehicle.latest().map(|m| m.value);
        let height_m = state.as_ref().and_then(|s| s.position_ned_m).map(|p| -p.z);
        if height_m.is_some_and(|h| h < self.min_height_m) {
            return Ok(None);
        }
        let camera = PinholeCamera::from_fov(
            frame.image.width(),
            frame.image.height(),
            self.horizontal_fov_rad,
        )
        .map_err(TaskError::other)?;
        // Where the followed pad lies on the ground, from the tracker (UAV − pad) and the vehicle.
        let pad_ne_m = match (
            state.as_ref().and_then(|s| s.position_ned_m),
            self.relative.latest(),
        ) {
            (Some(position), Some(relative)) => {
                let pad = position - relative.value.estimate.uav_relative_ned_m;
                Some((pad.x, pad.y))
            }
            _ => None,
        };
        // The vehicle as it was when the frame was exposed (the runner interpolates it from
        // telemetry); as it is now when the frame came without it. A box is placed with it:
        // in gusts the vehicle turns by degrees between the exposure and this step.
        let mount = self.camera_mount;
        let at_capture = frame
            .vehicle_at_capture
            .map(|s| (s.attitude, s.gimbal_attitude, s.position_ned_m))
            .or_else(|| {
                state
                    .as_ref()
                    .map(|s| (s.attitude, s.gimbal_attitude, s.position_ned_m))
            })
            .and_then(|(attitude, gimbal, position)| {
                Some((mount.camera_attitude(&attitude, gimbal.as_ref())?, position))
            });
        Ok(Some(Placement {
            frame_index: frame.frame_index,
            capture_time_s,
            camera,
            at_capture,
            pad_ne_m,
        }))
    }

    /// A frame's report: its most confident boxes placed on the ground, those on the followed
    /// pad left out.
    fn publish(
        &mut self,
        ctx: &TaskContext<'_>,
        placement: &Placement,
        mut detections: Vec<Detection>,
        inference_ms: f64,
    ) -> Result<(), TaskError> {
        let output = &self.output;
        detections.truncate(self.max_detections);
        let radius_m = self.pad_exclusion_radius_m;
        let detections: Vec<HazardDetection> = detections
            .into_iter()
            .map(|d| {
                let (u, v) = d.bbox.centre();
                HazardDetection {
                    class_id: d.class_id,
                    class_name: self.classes[d.class_id].clone(),
                    confidence: d.confidence,
                    bbox: d.bbox,
                    position_ned_m: placement.at_capture.and_then(|(attitude, position)| {
                        ground_position_ned_m(&placement.camera, &attitude, position, u, v)
                    }),
                }
            })
            .filter(|d| match (d.position_ned_m, placement.pad_ne_m) {
                (Some(p), Some((north_m, east_m))) => {
                    (p.x - north_m).hypot(p.y - east_m) > radius_m
                }
                _ => true,
            })
            .collect();
        output.publish(
            ctx.now(),
            HazardReport {
                frame_index: placement.frame_index,
                capture_time_s: placement.capture_time_s,
                detections,
                backend: self.backend_name,
                inference_ms,
            },
        );
        Ok(())
    }
}

/// Where the ground point seen at pixel (u, v) lies, local NED with down = 0 at the ground,
/// from the vehicle's attitude and position when the frame was exposed.
fn ground_position_ned_m(
    camera: &PinholeCamera,
    attitude: &Attitude,
    position_ned_m: Option<Vector3<f64>>,
    u_px: f64,
    v_px: f64,
) -> Option<Vector3<f64>> {
    let position = position_ned_m?;
    // The field is flat and at the home point's level: the camera is −down above it.
    let height_above_ground_m = -position.z;
    let relative =
        pad_relative_to_uav_ned_m(camera, attitude, height_above_ground_m, u_px, v_px).ok()?;
    Some(Vector3::new(
        position.x + relative.x,
        position.y + relative.y,
        0.0,
    ))
}

impl Task for HazardCnnTask {
    fn start(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let opened = open_backend(&self.source, &self.backend_options).map_err(TaskError::other)?;
        let mut backend = opened.backend;
        // One inference on a blank frame: a model whose output does not fit the classes and
        // layout fails now, at start-up, not in flight.
        let spec = backend.input();
        let blank = algorithms::vision::image::GrayImage::filled(
            spec.width_px.max(1),
            spec.height_px.max(1),
            0,
        )
        .map_err(TaskError::other)?;
        Self::detect(
            backend.as_mut(),
            &blank.view(),
            self.format,
            self.classes.len(),
            1.0,
            self.iou_threshold,
        )
        .map_err(|e| TaskError::failed(format!("model {}: {e}", self.source)))?;
        if let Some(reason) = opened.cpu_fallback_reason {
            if self.resource == Resource::Gpu
                && !self.cpu_fallback_said.swap(true, Ordering::SeqCst)
            {
                tracing::warn!(
                    task = ctx.name(),
                    %reason,
                    "no GPU backend: the hazard CNN runs on the CPU (tract)"
                );
            }
        }
        tracing::info!(task = ctx.name(), model = %self.source, backend = backend.name(), input = ?spec, "hazard model loaded");
        self.backend_name = backend.name();
        if self.pipelined {
            let (format, classes) = (self.format, self.classes.len());
            let (confidence, iou) = (self.confidence_threshold, self.iou_threshold);
            let pipeline = Pipeline::spawn(
                &format!("{}-inference", ctx.name()),
                move |(image, placement): (Arc<GrayImage>, Placement)| {
                    let result = Self::timed_detect(
                        backend.as_mut(),
                        &image,
                        format,
                        classes,
                        confidence,
                        iou,
                    );
                    (placement, result)
                },
            )
            .map_err(TaskError::other)?;
            self.pipeline = Some(pipeline);
        } else {
            self.backend = Some(backend);
        }
        Ok(())
    }

    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        // The frame handed over at the last step: its report now.
        if let Some(pipeline) = self.pipeline.as_mut() {
            if let Some((placement, result)) = pipeline.collect().map_err(TaskError::other)? {
                let (detections, inference_ms) = result?;
                self.publish(ctx, &placement, detections, inference_ms)?;
            }
        }
        let Some(frame) = self.frames.take_new() else {
            return Ok(());
        };
        let Some(placement) = self.placement(&frame.value, frame.stamp.as_secs_f64())? else {
            return Ok(());
        };
        let image = Arc::clone(&frame.value.image);
        if let Some(pipeline) = self.pipeline.as_mut() {
            // Nothing is in flight (collected above), so nothing comes back here.
            pipeline
                .submit((image, placement))
                .map_err(TaskError::other)?;
            return Ok(());
        }
        let Some(backend) = self.backend.as_mut() else {
            return Err(TaskError::failed("stepped before start"));
        };
        let (detections, inference_ms) = Self::timed_detect(
            backend.as_mut(),
            &image,
            self.format,
            self.classes.len(),
            self.confidence_threshold,
            self.iou_threshold,
        )?;
        self.publish(ctx, &placement, detections, inference_ms)
    }

    fn stop(&mut self) {
        self.backend = None;
        self.pipeline = None;
    }
}

#[cfg(test)]
mod tests;
