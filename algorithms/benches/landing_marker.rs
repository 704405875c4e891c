//! Time per 640×480 grayscale frame of the whole landing-marker detector (n-fold + three ArUco
//! markers on the reference pad), full frame and with a region of interest around the previous
//! detection, against its own parts measured in the same run.
//!
//! `cargo bench -p algorithms --bench landing_marker`

use std::hint::black_box;

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::vision::image::GrayImage;
use algorithms::vision::landing_marker::{
    LandingMarkerConfig, LandingMarkerDetector, LandingMarkerLayout,
};
use algorithms::vision::nfold::{NfoldDetector, Roi};
use algorithms::vision::render::{render, ImageEffects, RenderOptions, Scene, Texture};
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Vector3;

/// The reference pad seen from 3 m on a field, with a little tilt, noise and blur: the final
/// approach, where every part of the pad is in view.
fn frame() -> GrayImage {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).expect("camera");
    let pose = CameraPose::downward(Vector3::new(0.1, -0.2, -3.0), 0.06, -0.04, 0.5);
    let mut scene = Scene::new(Texture::field(4));
    scene.patches = LandingMarkerLayout::default()
        .patches(0.0, 0.0, 0.0, 1.2)
        .expect("reference layout");
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

fn bench(c: &mut Criterion) {
    let frame = frame();
    let view = frame.view();
    let config = LandingMarkerConfig::default();
    let nfold = NfoldDetector::new(config.nfold.clone()).expect("n-fold config");
    let mut detector = LandingMarkerDetector::new(config).expect("config");
    let seen = detector
        .detect(&view, None)
        .expect("frame")
        .expect("the pad is in view");
    let [u, v] = seen.centre_px;
    // The ROI the detection task uses: the last frame's pad with a margin.
    let pad_size_px = seen.pad_size_px.expect("ArUco markers in view");
    let roi = Roi::around(u, v, 0.8 * pad_size_px);
    // The n-fold marker's centre alone, predicted to a few pixels.
    let nfold_roi = Roi::around(u + 3.0, v - 2.0, 16.0);
    assert!(detector.detect(&view, Some(&roi)).expect("frame").is_some());

    let mut group = c.benchmark_group("landing_marker_640x480");
    group.sample_size(30);
    group.measurement_time(std::time::Duration::from_secs(4));
    group.bench_function("whole marker, full frame", |b| {
        b.iter(|| detector.detect(black_box(&view), None).expect("frame"))
    });
    group.bench_function("whole marker, ROI", |b| {
        b.iter(|| {
            detector
                .detect(black_box(&view), Some(&roi))
                .expect("frame")
        })
    });
    group.bench_function("n-fold alone, full frame", |b| {
        b.iter(|| nfold.detect(black_box(&view)).expect("frame"))
    });
    group.bench_function("n-fold alone, ROI", |b| {
        b.iter(|| {
            nfold
                .detect_in_roi(black_box(&view), &nfold_roi)
                .expect("frame")
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
