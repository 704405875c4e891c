//! Time per 640×480 grayscale frame of the n-fold marker detector on one core: full-frame search
//! (coarse to fine, the default), full-frame search at full resolution, a region of interest around
//! a prediction, and a markerless frame (the worst case: every candidate and kernel size is tried).
//! Baseline in the same run: direct 2-D correlation with the full complex 13×13 kernel, on a
//! 160×120 crop (throughput in pixels/s compares it with the full frame; × 16 for a frame).
//! Also the renderer that makes the test frames: 640×480, 2×2 supersampling, field background.
//!
//! `cargo bench -p algorithms --bench nfold`

use std::hint::black_box;
use std::time::Duration;

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::vision::image::{GrayImage, ImageView};
use algorithms::vision::nfold::{NfoldConfig, NfoldDetector, Roi};
use algorithms::vision::render::{render, ImageEffects, Patch, RenderOptions, Scene, Texture};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nalgebra::{Point3, Vector3};

/// A 0.5 m marker on a white board on a field, seen from 5 m with a little tilt, noise and blur;
/// with the marker's true pixel. `marker: false` leaves the board and marker out.
fn frame(marker: bool) -> (GrayImage, (f64, f64)) {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).expect("camera");
    let pose = CameraPose::downward(Vector3::new(0.4, -0.3, -5.0), 0.06, -0.04, 0.5);
    let mut scene = Scene::new(Texture::field(7));
    if marker {
        scene = scene
            .with_patch(Patch::square(0.0, 0.0, 0.3, 0.7, Texture::uniform(1.0)))
            .with_patch(Patch::square(
                0.0,
                0.0,
                0.3,
                0.5,
                Texture::nfold(4, false).expect("order 4"),
            ));
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
    let image = render(&camera, &pose, &scene, &options).expect("render");
    let truth = camera
        .project_world(&pose, &Point3::origin())
        .expect("in front");
    (image, truth)
}

/// The naive baseline: |R|² by direct 2-D correlation with the complex kernel, f32, every pixel
/// of `view` where the kernel fits; returns the strongest position.
fn naive_correlation(
    view: &ImageView<'_>,
    kernel_re: &[f32],
    kernel_im: &[f32],
    size: usize,
) -> (usize, usize) {
    let mut best = (0, 0, f32::MIN);
    for y in 0..view.height() - size + 1 {
        for x in 0..view.width() - size + 1 {
            let (mut re, mut im) = (0f32, 0f32);
            for j in 0..size {
                let row = &view.row(y + j)[x..x + size];
                for (i, &p) in row.iter().enumerate() {
                    re += p as f32 * kernel_re[j * size + i];
                    im += p as f32 * kernel_im[j * size + i];
                }
            }
            let magnitude = re * re + im * im;
            if magnitude > best.2 {
                best = (x, y, magnitude);
            }
        }
    }
    (best.0, best.1)
}

/// K = zⁿ·exp(−8|z|²) over [−1, 1]², n = 4.
fn kernel(size: usize) -> (Vec<f32>, Vec<f32>) {
    let r = (size / 2) as f32;
    let mut re = Vec::new();
    let mut im = Vec::new();
    for j in 0..size {
        for i in 0..size {
            let (x, y) = (i as f32 / r - 1.0, j as f32 / r - 1.0);
            let (m, a) = ((x * x + y * y).sqrt(), y.atan2(x));
            let g = m.powi(4) * (-8.0 * m * m).exp();
            re.push(g * (4.0 * a).cos());
            im.push(g * (4.0 * a).sin());
        }
    }
    (re, im)
}

fn bench(c: &mut Criterion) {
    let (image, (u, v)) = frame(true);
    let (empty, _) = frame(false);
    let view = image.view();
    let default = NfoldDetector::new(NfoldConfig::default()).expect("config");
    let full_res = NfoldDetector::new(NfoldConfig {
        search_level: 0,
        search_kernel_px: 13,
        ..NfoldConfig::default()
    })
    .expect("config");
    let found = default.detect(&view).expect("frame").expect("marker");
    assert!(
        (found.u_px - u).hypot(found.v_px - v) < 0.5,
        "{found:?} vs ({u}, {v})"
    );
    let roi = Roi::around(u + 7.0, v - 5.0, 40.0);
    assert!(default.detect_in_roi(&view, &roi).expect("frame").is_some());
    assert!(default.detect(&empty.view()).expect("frame").is_none());

    let mut group = c.benchmark_group("nfold");
    group.throughput(Throughput::Elements((640 * 480) as u64));
    group.bench_function("full_frame", |b| {
        b.iter(|| default.detect(black_box(&view)).expect("frame"))
    });
    group.bench_function("full_frame_search_at_full_resolution", |b| {
        b.iter(|| full_res.detect(black_box(&view)).expect("frame"))
    });
    group.bench_function("full_frame_markerless", |b| {
        b.iter(|| default.detect(black_box(&empty.view())).expect("frame"))
    });
    group.bench_function("roi_81x81", |b| {
        b.iter(|| {
            default
                .detect_in_roi(black_box(&view), black_box(&roi))
                .expect("frame")
        })
    });
    // The baseline on a 160×120 crop around the marker: 1/16 of the frame's pixels.
    let (x0, y0) = (
        (u as usize).saturating_sub(80).min(480),
        (v as usize).saturating_sub(60).min(360),
    );
    let mut crop = Vec::with_capacity(172 * 132);
    for y in y0..y0 + 132 {
        crop.extend_from_slice(&view.row(y)[x0..x0 + 172]);
    }
    let crop = ImageView::new(172, 132, 172, &crop).expect("crop");
    let (kre, kim) = kernel(13);
    group.throughput(Throughput::Elements((160 * 120) as u64));
    group.bench_function("naive_direct_13px_crop_160x120", |b| {
        b.iter(|| naive_correlation(black_box(&crop), &kre, &kim, 13))
    });
    group.finish();

    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).expect("camera");
    let pose = CameraPose::downward(Vector3::new(0.4, -0.3, -5.0), 0.06, -0.04, 0.5);
    let scene = Scene::new(Texture::field(7))
        .with_patch(Patch::square(0.0, 0.0, 0.3, 0.7, Texture::uniform(1.0)))
        .with_patch(Patch::square(
            0.0,
            0.0,
            0.3,
            0.5,
            Texture::nfold(4, false).expect("order 4"),
        ));
    let options = RenderOptions {
        supersampling: 2,
        effects: ImageEffects {
            gaussian_blur_sigma_px: 0.7,
            noise_sigma: 3.0,
            noise_seed: 1,
            ..ImageEffects::default()
        },
    };
    c.bench_function("render/640x480_supersampling_2x2_field_blur_noise", |b| {
        b.iter(|| render(&camera, black_box(&pose), &scene, &options).expect("render"))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
