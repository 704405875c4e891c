//! Hazard CNN benchmark (`cargo bench -p runtime --bench hazard_inference`).
//!
//! Per 640×480 frame of a rendered field, on the CPU backend (tract, one thread): the shipped
//! model's preprocessing, inference and decoding, median of `QOSRT_BENCH_FRAMES` frames (default
//! 60). Baseline in the same run: the landing-marker detector (the CPU vision task that shares
//! the board) on the same frames. Then the frame rate the task sustains on one core, and the
//! hazard CNN's share of the companion power model (qos.toml's profiles) at each of its levels.

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::vision::landing_marker::{
    LandingMarkerConfig, LandingMarkerDetector, LandingMarkerLayout,
};
use algorithms::vision::render::{render, RenderOptions, Scene, Texture};
use algorithms::vision::yolo::{decode, letterbox_gray, non_maximum_suppression, YoloFormat};
use nalgebra::Vector3;
use power_models::planner::TaskLevel;
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::inference::{open_backend, BackendChoice, BackendOptions};
use runtime::plugins::builtin_registry;
use runtime::plugins::hazard_cnn::SHIPPED_MODEL;
use std::hint::black_box;
use std::time::{Duration, Instant};

fn median(mut samples: Vec<Duration>) -> Duration {
    samples.sort();
    samples[samples.len() / 2]
}

fn main() {
    let frames_wanted: usize = std::env::var("QOSRT_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(60);
    // Frames over a textured field with the pad, the camera drifting, as in flight.
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).expect("a camera");
    let frames: Vec<_> = (0..8)
        .map(|i| {
            let mut scene = Scene::new(Texture::field(7));
            scene.patches = LandingMarkerLayout::default()
                .patches(0.2 * i as f64, -0.3, 0.0, 0.4)
                .expect("the reference pad");
            let pose = CameraPose::downward(
                Vector3::new(3.0 * i as f64, 1.0, -8.5),
                0.03,
                -0.02,
                0.1 * i as f64,
            );
            render(&camera, &pose, &scene, &RenderOptions::default()).expect("a frame")
        })
        .collect();

    let mut backend = open_backend(
        &SHIPPED_MODEL,
        &BackendOptions {
            choice: BackendChoice::Cpu,
            ..BackendOptions::default()
        },
    )
    .expect("the shipped model loads")
    .backend;
    let spec = backend.input();
    let (mut preprocess, mut inference, mut postprocess, mut total) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    // Warm-up: the first runs allocate.
    for frame in frames.iter().take(3) {
        let (input, _) = letterbox_gray(&frame.view(), spec.width_px, spec.height_px);
        black_box(backend.run(&input).expect("inference"));
    }
    for i in 0..frames_wanted {
        let frame = &frames[i % frames.len()];
        let t0 = Instant::now();
        let (input, letterbox) = letterbox_gray(&frame.view(), spec.width_px, spec.height_px);
        let t1 = Instant::now();
        let output = backend.run(&input).expect("inference");
        let t2 = Instant::now();
        let detections = decode(
            &output.values,
            &output.shape,
            YoloFormat::WithObjectness,
            3,
            0.4,
            &letterbox,
        )
        .expect("decodes");
        black_box(non_maximum_suppression(detections, 0.45).expect("nms"));
        let t3 = Instant::now();
        preprocess.push(t1 - t0);
        inference.push(t2 - t1);
        postprocess.push(t3 - t2);
        total.push(t3 - t0);
    }

    let mut marker = LandingMarkerDetector::new(LandingMarkerConfig::default()).expect("detector");
    let mut marker_times = Vec::new();
    for i in 0..frames_wanted {
        let frame = &frames[i % frames.len()];
        let t0 = Instant::now();
        black_box(marker.detect(&frame.view(), None).expect("detects"));
        marker_times.push(t0.elapsed());
    }

    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let total_ms = ms(median(total));
    let marker_ms = ms(median(marker_times));
    println!(
        "hazard CNN on {} ({}×{}×{} input), median of {frames_wanted} frames:",
        backend.name(),
        spec.channels,
        spec.height_px,
        spec.width_px
    );
    println!(
        "  preprocess (letterbox)   {:8.3} ms",
        ms(median(preprocess))
    );
    println!(
        "  inference                {:8.3} ms",
        ms(median(inference))
    );
    println!(
        "  decode + NMS             {:8.3} ms",
        ms(median(postprocess))
    );
    println!("  per frame                {total_ms:8.3} ms");
    println!(
        "  sustains                 {:8.1} fps on one core",
        1e3 / total_ms
    );
    println!("baseline, same frames: landing-marker detection {marker_ms:.3} ms per frame");
    println!(
        "ratio: the hazard CNN costs {:.2}× a marker detection per frame",
        total_ms / marker_ms
    );

    // The hazard CNN's share of the companion's modelled power, tracking phase, the other
    // tasks at their top levels.
    let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../qos.toml"));
    let registry = builtin_registry().expect("the built-in plugins register");
    let loaded = load_file(path, &registry.catalog()).expect("qos.toml loads");
    let model = load_mission_model(&loaded).expect("its profiles load");
    let problem = model.plan_problem();
    let phase = model
        .config
        .mission
        .phases
        .iter()
        .position(|p| p.name == "tracking")
        .expect("a tracking phase");
    let hazard = model
        .config
        .tasks
        .iter()
        .position(|t| t.plugin == "hazard_cnn")
        .expect("a hazard task");
    let levels_with = |hazard_level: usize| -> Vec<TaskLevel> {
        model
            .config
            .tasks
            .iter()
            .enumerate()
            .map(|(task, config)| TaskLevel {
                task,
                level: if task == hazard {
                    hazard_level
                } else {
                    config.levels.len() - 1
                },
            })
            .collect()
    };
    let hazard_config = &model.config.tasks[hazard];
    // The landing phase runs the same CPU tasks without the CNN: the board's power without it.
    let landing = model.config.mission.phases.len() - 1;
    let without_w = problem
        .companion_power_w(landing, &levels_with(0))
        .expect("modelled");
    println!(
        "companion power by hazard CNN rate, tracking phase, the other tasks at their top levels \
         (without the CNN: {without_w:.2} W, the landing phase's):"
    );
    for (level, rate) in hazard_config.levels.iter().enumerate() {
        let power_w = problem
            .companion_power_w(phase, &levels_with(level))
            .expect("modelled");
        let busy = total_ms * rate / 1e3;
        println!(
            "  {rate:>5} fps: {power_w:.2} W, of which the CNN {:.2} W ({:.0} %); here its CPU backend would keep one core {:.1} % busy",
            power_w - without_w,
            100.0 * (power_w - without_w) / power_w,
            100.0 * busy
        );
    }
}
