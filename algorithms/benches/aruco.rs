//! Time per 640×480 grayscale frame of the ArUco detector, three DICT_4X4_50 markers on a field,
//! full frame and a region of interest around the markers, against a baseline in the same run:
//! the same pipeline with a naive per-pixel window mean in the adaptive threshold instead of
//! the integral image.
//!
//! `cargo bench -p algorithms --bench aruco`

use std::hint::black_box;

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::vision::aruco::{
    ArucoConfig, ArucoDetector, Dictionary, PixelRect, ThresholdMethod,
};
use algorithms::vision::image::GrayImage;
use algorithms::vision::render::{render, ImageEffects, Patch, RenderOptions, Scene, Texture};
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Vector3;

/// Three 0.3 m markers (ids 3, 17, 42) a metre apart on a field, seen from 6 m with a little
/// tilt and yaw, with noise and blur: a landing approach.
fn frame() -> GrayImage {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).expect("camera");
    let pose = CameraPose::downward(Vector3::new(0.3, -0.2, -6.0), 0.08, -0.05, 0.6);
    let dict = Dictionary::dict_4x4_50();
    let mut scene = Scene::new(Texture::field(4));
    for (id, north_m, east_m) in [(3, 0.5, -0.5), (17, 0.5, 0.5), (42, -0.5, 0.0)] {
        let bits = dict.marker_bits(id).expect("id in the dictionary");
        let texture = Texture::aruco(&bits, 4).expect("4×4 bits");
        scene = scene
            .with_patch(Patch::square(
                north_m,
                east_m,
                0.2,
                0.4,
                Texture::uniform(1.0),
            ))
            .with_patch(Patch::square(north_m, east_m, 0.2, 0.3, texture));
    }
    let options = RenderOptions {
        supersampling: 2,
        effects: ImageEffects {
            gaussian_blur_sigma_px: 0.7,
            noise_sigma: 3.0,
            noise_seed: 1,
            ..ImageEffects::default()
        },
    };
    render(&camera, &pose, &scene, &options).expect("render")
}

fn detector(method: ThresholdMethod) -> ArucoDetector {
    let config = ArucoConfig {
        threshold_method: method,
        ..ArucoConfig::default()
    };
    ArucoDetector::new(Dictionary::dict_4x4_50(), config).expect("valid config")
}

fn bench(c: &mut Criterion) {
    let image = frame();
    let view = image.view();
    let mut check = detector(ThresholdMethod::IntegralImage);
    let markers = check.detect(&view).expect("frame");
    assert_eq!(
        markers.len(),
        3,
        "the benchmark frame must hold its three markers"
    );
    // The region of interest a tracker would give: the markers' box plus a margin.
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for (u, v) in markers.iter().flat_map(|m| m.corners_px) {
        (x0, y0, x1, y1) = (x0.min(u), y0.min(v), x1.max(u), y1.max(v));
    }
    let margin = 20.0;
    let roi = PixelRect {
        x: (x0 - margin).max(0.0) as usize,
        y: (y0 - margin).max(0.0) as usize,
        width: (x1 - x0 + 2.0 * margin) as usize,
        height: (y1 - y0 + 2.0 * margin) as usize,
    };
    assert_eq!(check.detect_in_roi(&view, roi).expect("roi").len(), 3);
    eprintln!("region of interest: {roi:?}");

    let mut group = c.benchmark_group("aruco_640x480_3_markers");
    for (name, method) in [
        ("integral_image", ThresholdMethod::IntegralImage),
        (
            "naive_window_mean_baseline",
            ThresholdMethod::NaiveWindowMean,
        ),
    ] {
        let mut detector = detector(method);
        group.bench_function(format!("full_frame/{name}"), |b| {
            b.iter(|| detector.detect(black_box(&view)).expect("frame"))
        });
        group.bench_function(format!("roi/{name}"), |b| {
            b.iter(|| detector.detect_in_roi(black_box(&view), roi).expect("roi"))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = bench
}
criterion_main!(benches);
