use super::correlation::quadratic_peak;
use super::*;
use crate::camera::{CameraPose, PinholeCamera};
use crate::vision::image::GrayImage;
use crate::vision::render::{
    render, ImageEffects, MotionBlur, Patch, RenderOptions, Scene, Texture,
};
use nalgebra::{Point3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const MARKER_M: f64 = 0.5;

fn camera() -> PinholeCamera {
    PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap()
}

fn wrap(a: f64) -> f64 {
    PI - (PI - a).rem_euclid(TAU)
}

/// A rendered frame and the marker's truth.
struct Case {
    image: GrayImage,
    u_px: f64,
    v_px: f64,
    orientation_rad: f64,
    /// The marker's smallest projected diameter.
    span_px: f64,
}

/// A 0.5 m marker on a 0.7 m white board on a random field, seen from a random pose: altitude
/// log-uniform in `altitude_m` (so that about three frames in four show the marker at 30 px
/// or more), tilt up to 25° in any direction, any yaw, the marker anywhere at least 80 px
/// inside the frame; random Gaussian blur (half the frames, σ ≤ 1.2 px), motion blur (three
/// in ten, ≤ 3 px), contrast 0.5–1, brightness ±0.15, noise σ ≤ 6 grey levels.
fn random_case(
    rng: &mut StdRng,
    oriented: bool,
    occluder: Option<Patch>,
    altitude_m: (f64, f64),
) -> Case {
    let cam = camera();
    let marker_yaw = rng.random_range(-PI..PI);
    let marker = Patch::square(
        0.0,
        0.0,
        marker_yaw,
        MARKER_M,
        Texture::nfold(4, oriented).unwrap(),
    );
    let board = Patch::square(0.0, 0.0, marker_yaw, 0.7, Texture::uniform(1.0));
    let mut scene = Scene::new(Texture::field(rng.random()))
        .with_patch(board)
        .with_patch(marker.clone());
    if let Some(o) = occluder {
        scene = scene.with_patch(o);
    }
    let altitude_m = rng.random_range(altitude_m.0.ln()..altitude_m.1.ln()).exp();
    let tilt = rng.random_range(0.0..25f64.to_radians());
    let dir = rng.random_range(-PI..PI);
    let (roll, pitch, yaw) = (
        tilt * dir.cos(),
        tilt * dir.sin(),
        rng.random_range(-PI..PI),
    );
    // Put the camera where it sees the marker at a random pixel.
    let attitude = CameraPose::downward(Vector3::zeros(), roll, pitch, yaw);
    let (u0, v0) = (rng.random_range(80.0..560.0), rng.random_range(80.0..400.0));
    let ray = attitude.camera_to_world.rotation * cam.unproject(u0, v0).into_inner();
    let pose = CameraPose::downward(-ray * (altitude_m / ray.z), roll, pitch, yaw);
    let effects = ImageEffects {
        gaussian_blur_sigma_px: if rng.random_bool(0.5) {
            rng.random_range(0.0..1.2)
        } else {
            0.0
        },
        motion_blur: rng.random_bool(0.3).then(|| MotionBlur {
            length_px: rng.random_range(0.0..3.0),
            angle_rad: rng.random_range(0.0..PI),
        }),
        contrast: rng.random_range(0.5..1.0),
        brightness: rng.random_range(-0.15..0.15),
        noise_sigma: rng.random_range(0.0..6.0),
        noise_seed: rng.random(),
    };
    let options = RenderOptions {
        supersampling: 2,
        effects,
    };
    let image = render(&cam, &pose, &scene, &options).unwrap();
    let (u_px, v_px) = cam.project_world(&pose, &Point3::origin()).unwrap();
    let at = |t: f64, rho: f64| {
        cam.project_world(&pose, &marker.point_world(rho * t.cos(), rho * t.sin()))
            .unwrap()
    };
    // Orientation truth: perspective turns directions around the tip by different amounts;
    // the n-th harmonic's phase follows their mean turn (exactly so to first order for an
    // affine view), so the truth is the marker's orientation (0 on the patch) plus that mean.
    let turns: Vec<f64> = (0..72)
        .map(|k| {
            let t = k as f64 * TAU / 72.0;
            let (u, v) = at(t, 0.02);
            (v - v_px).atan2(u - u_px) - t
        })
        .collect();
    // Unwrapped about the first turn, so that turns near ±π average correctly.
    let orientation_rad = turns[0] + turns.iter().map(|t| wrap(t - turns[0])).sum::<f64>() / 72.0;
    let span_px = (0..36)
        .map(|k| {
            let t = k as f64 * PI / 36.0;
            let (a, b) = (at(t, 1.0), at(t + PI, 1.0));
            (a.0 - b.0).hypot(a.1 - b.1)
        })
        .fold(f64::MAX, f64::min);
    Case {
        image,
        u_px,
        v_px,
        orientation_rad,
        span_px,
    }
}

fn percentile(values: &[f64], p: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted
        .get(((sorted.len().max(1) - 1) as f64 * p).round() as usize)
        .copied()
        .unwrap_or(f64::NAN)
}

/// Errors over frames whose marker spans at least 30 px, and the detection rate below that.
#[derive(Default)]
struct Errors {
    counted: usize,
    detected: usize,
    small: usize,
    small_detected: usize,
    centre_px: Vec<f64>,
    orientation_deg: Vec<f64>,
}

impl Errors {
    fn report(&self, name: &str) {
        let (c, o) = (&self.centre_px, &self.orientation_deg);
        println!(
            "{name}: {}/{} markers ≥ 30 px detected ({}/{} smaller); centre error median \
             {:.3} px, p95 {:.3} px, max {:.3} px; orientation error median {:.3}°, p95 \
             {:.3}°, max {:.3}°",
            self.detected,
            self.counted,
            self.small_detected,
            self.small,
            percentile(c, 0.5),
            percentile(c, 0.95),
            percentile(c, 1.0),
            percentile(o, 0.5),
            percentile(o, 0.95),
            percentile(o, 1.0),
        );
    }
}

enum Mode {
    FullFrame,
    /// An ROI of this half-size around the truth moved up to 10 px.
    Roi(f64),
}

fn run(
    seed: u64,
    frames: usize,
    config: NfoldConfig,
    mode: Mode,
    occluder: fn(&mut StdRng) -> Option<Patch>,
    altitude_m: (f64, f64),
) -> Errors {
    let oriented = config.oriented;
    let detector = NfoldDetector::new(config).unwrap();
    let mut rng = StdRng::seed_from_u64(seed);
    let mut errors = Errors::default();
    for _ in 0..frames {
        let occluder = occluder(&mut rng);
        let case = random_case(&mut rng, oriented, occluder, altitude_m);
        let view = case.image.view();
        let found = match mode {
            Mode::FullFrame => detector.detect(&view),
            Mode::Roi(half) => {
                let (du, dv) = (rng.random_range(-10.0..10.0), rng.random_range(-10.0..10.0));
                let roi = Roi::around(case.u_px + du, case.v_px + dv, half);
                detector.detect_in_roi(&view, &roi)
            }
        }
        .unwrap();
        if case.span_px < 30.0 {
            errors.small += 1;
            errors.small_detected += usize::from(found.is_some());
            continue;
        }
        errors.counted += 1;
        let Some(d) = found else { continue };
        errors.detected += 1;
        errors
            .centre_px
            .push((d.u_px - case.u_px).hypot(d.v_px - case.v_px));
        let period = if oriented { TAU } else { TAU / 4.0 };
        let e = (d.orientation_rad - case.orientation_rad).rem_euclid(period);
        errors.orientation_deg.push(e.min(period - e).to_degrees());
    }
    errors
}

fn no_occluder(_: &mut StdRng) -> Option<Patch> {
    None
}

/// A grey square over the tip, 4 cm (8 % of the marker's diameter).
fn tip_occluder(rng: &mut StdRng) -> Option<Patch> {
    let level = rng.random_range(0.3..0.8);
    let yaw = rng.random_range(0.0..PI);
    Some(Patch::square(0.0, 0.0, yaw, 0.04, Texture::uniform(level)))
}

/// A square of any grey over the outer part of a sector, tip clear: 10 cm, centred 13 cm out.
fn sector_occluder(rng: &mut StdRng) -> Option<Patch> {
    let (dir, level) = (rng.random_range(-PI..PI), rng.random_range(0.0..1.0));
    let (north, east) = (0.13 * dir.cos(), 0.13 * dir.sin());
    Some(Patch::square(
        north,
        east,
        dir,
        0.1,
        Texture::uniform(level),
    ))
}

#[test]
fn random_poses_give_the_centre_and_orientation() {
    let errors = run(
        11,
        100,
        NfoldConfig::default(),
        Mode::FullFrame,
        no_occluder,
        (1.0, 20.0),
    );
    errors.report("n-fold, full frame");
    assert!(errors.counted >= 60);
    assert_eq!(
        errors.detected, errors.counted,
        "every marker ≥ 30 px is found"
    );
    assert!(percentile(&errors.centre_px, 0.5) < 0.5);
    assert!(percentile(&errors.centre_px, 0.95) < 1.5);
    assert!(percentile(&errors.orientation_deg, 1.0) < 2.0);
}

#[test]
#[ignore = "500 frames: about half a minute"]
fn random_poses_give_the_centre_and_orientation_500() {
    let errors = run(
        31,
        500,
        NfoldConfig::default(),
        Mode::FullFrame,
        no_occluder,
        (1.0, 20.0),
    );
    errors.report("n-fold, full frame, 500 frames");
    assert_eq!(errors.detected, errors.counted);
    assert!(percentile(&errors.centre_px, 0.5) < 0.5);
    assert!(percentile(&errors.centre_px, 0.95) < 1.5);
    assert!(percentile(&errors.orientation_deg, 1.0) < 2.0);
    let config = NfoldConfig {
        oriented: true,
        ..NfoldConfig::default()
    };
    let errors = run(32, 500, config, Mode::FullFrame, no_occluder, (1.0, 20.0));
    errors.report("oriented n-fold, full frame, 500 frames");
    assert_eq!(errors.detected, errors.counted);
    assert!(percentile(&errors.orientation_deg, 0.95) < 2.0);
}

#[test]
fn oriented_markers_give_the_full_orientation() {
    let config = NfoldConfig {
        oriented: true,
        ..NfoldConfig::default()
    };
    let errors = run(12, 50, config, Mode::FullFrame, no_occluder, (1.0, 20.0));
    errors.report("oriented n-fold, full frame");
    assert_eq!(errors.detected, errors.counted);
    assert!(percentile(&errors.centre_px, 0.5) < 0.5);
    assert!(percentile(&errors.centre_px, 0.95) < 1.5);
    // Errors are modulo 2π here: a wrong leg would show as 90° or more.
    assert!(percentile(&errors.orientation_deg, 0.95) < 2.0);
    assert!(percentile(&errors.orientation_deg, 1.0) < 3.0);
}

#[test]
fn a_region_of_interest_finds_the_predicted_marker() {
    let errors = run(
        13,
        30,
        NfoldConfig::default(),
        Mode::Roi(40.0),
        no_occluder,
        (1.0, 20.0),
    );
    errors.report("n-fold, ROI ±40 px");
    assert_eq!(errors.detected, errors.counted);
    assert!(percentile(&errors.centre_px, 0.5) < 0.5);
    assert!(percentile(&errors.centre_px, 0.95) < 1.5);
    assert!(percentile(&errors.orientation_deg, 1.0) < 2.0);
    // A prediction far from the marker, or off the frame, finds nothing.
    let mut rng = StdRng::seed_from_u64(14);
    let case = random_case(&mut rng, false, None, (4.0, 5.0));
    let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
    let view = case.image.view();
    let far_u = if case.u_px < 320.0 { 560.0 } else { 80.0 };
    let far = Roi::around(far_u, case.v_px, 30.0);
    assert_eq!(detector.detect_in_roi(&view, &far).unwrap(), None);
    let outside = Roi::around(-100.0, -100.0, 30.0);
    assert_eq!(detector.detect_in_roi(&view, &outside).unwrap(), None);
}

#[test]
fn an_occluded_tip_is_still_detected() {
    // 3–8 m: the 4 cm occluder is 3–7 px wide, within the larger kernels' reach.
    let errors = run(
        15,
        25,
        NfoldConfig::default(),
        Mode::FullFrame,
        tip_occluder,
        (3.0, 8.0),
    );
    errors.report("n-fold, tip occluded");
    assert_eq!(errors.detected, errors.counted);
    assert!(percentile(&errors.centre_px, 1.0) < 1.5);
}

/// A grey square over the tip the size of the simulated world's occluders on its pad (0.12 m
/// on a 0.44 m marker): 14 cm here, 28 % of the marker's diameter.
fn large_tip_occluder(rng: &mut StdRng) -> Option<Patch> {
    let level = rng.random_range(0.2..0.9);
    let yaw = rng.random_range(0.0..PI);
    Some(Patch::square(0.0, 0.0, yaw, 0.14, Texture::uniform(level)))
}

#[test]
fn a_close_marker_with_its_tip_occluded_is_found_at_a_coarser_level() {
    // 0.6–1.6 m: the occluder is 50–130 px wide, past every full-resolution kernel (≤ 25 px).
    let close = (0.6, 1.6);
    let full_resolution_only = NfoldConfig {
        roi_fallback_levels: 0,
        ..NfoldConfig::default()
    };
    let before = run(
        17,
        20,
        full_resolution_only,
        Mode::Roi(40.0),
        large_tip_occluder,
        close,
    );
    before.report("n-fold, ROI ±40 px, large tip occluder, full resolution only");
    let errors = run(
        17,
        20,
        NfoldConfig::default(),
        Mode::Roi(40.0),
        large_tip_occluder,
        close,
    );
    errors.report("n-fold, ROI ±40 px, large tip occluder, with the coarser levels");
    assert_eq!(errors.counted, 20);
    assert!(before.detected <= 2, "{} of 20", before.detected);
    // A few, most of them the closest (the occluder 90–135 px), still hide the tip at every
    // level whose kernels fit the frame.
    assert!(errors.detected >= 15, "{} of 20", errors.detected);
    // A pixel at 1 m is 1.6 mm on the pad.
    assert!(percentile(&errors.centre_px, 0.5) < 0.5);
    assert!(percentile(&errors.centre_px, 1.0) < 1.5);
    // Without an occluder the full resolution still finds a close marker first.
    let clear = run(
        18,
        10,
        NfoldConfig::default(),
        Mode::Roi(40.0),
        no_occluder,
        close,
    );
    clear.report("n-fold, ROI ±40 px, close, no occluder");
    assert_eq!(clear.detected, clear.counted);
    assert!(percentile(&clear.centre_px, 1.0) < 1.5);
}

#[test]
fn an_occluded_sector_is_still_detected() {
    let errors = run(
        16,
        25,
        NfoldConfig::default(),
        Mode::FullFrame,
        sector_occluder,
        (1.5, 9.0),
    );
    errors.report("n-fold, sector occluded");
    assert_eq!(errors.detected, errors.counted);
    assert!(percentile(&errors.centre_px, 0.5) < 0.5);
    assert!(percentile(&errors.centre_px, 1.0) < 1.5);
}

/// A random frame without an n-fold marker: a field, and up to five of ArUco markers on white
/// boards, plain rectangles of any grey, and patches of another field; random pose and effects.
fn random_markerless(rng: &mut StdRng, supersampling: usize) -> GrayImage {
    let mut scene = Scene::new(Texture::field(rng.random()));
    for _ in 0..rng.random_range(0..6) {
        let (n, e) = (rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
        let yaw = rng.random_range(-PI..PI);
        let size = rng.random_range(0.1..0.8);
        scene = match rng.random_range(0..3) {
            0 => {
                let bits: Vec<bool> = (0..16).map(|_| rng.random_bool(0.5)).collect();
                let aruco = Texture::aruco(&bits, 4).unwrap();
                scene
                    .with_patch(Patch::square(n, e, yaw, size * 1.4, Texture::uniform(1.0)))
                    .with_patch(Patch::square(n, e, yaw, size, aruco))
            }
            1 => {
                let (level, aspect) = (rng.random_range(0.0..1.0), rng.random_range(0.2..3.0));
                let texture = Texture::uniform(level);
                scene.with_patch(Patch::new(n, e, yaw, size, size * aspect, texture))
            }
            _ => {
                let texture = Texture::field(rng.random());
                scene.with_patch(Patch::square(n, e, yaw, size * 3.0, texture))
            }
        };
    }
    let altitude_m = rng.random_range(1.0f64.ln()..20f64.ln()).exp();
    let tilt = rng.random_range(0.0..25f64.to_radians());
    let dir = rng.random_range(-PI..PI);
    let position = Vector3::new(
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        -altitude_m,
    );
    let yaw = rng.random_range(-PI..PI);
    let pose = CameraPose::downward(position, tilt * dir.cos(), tilt * dir.sin(), yaw);
    let effects = ImageEffects {
        gaussian_blur_sigma_px: if rng.random_bool(0.5) {
            rng.random_range(0.0..1.2)
        } else {
            0.0
        },
        contrast: rng.random_range(0.5..1.3),
        brightness: rng.random_range(-0.15..0.15),
        noise_sigma: rng.random_range(0.0..6.0),
        noise_seed: rng.random(),
        ..Default::default()
    };
    let options = RenderOptions {
        supersampling,
        effects,
    };
    render(&camera(), &pose, &scene, &options).unwrap()
}

fn false_positives(seed: u64, frames: usize, oriented: bool) -> usize {
    let config = NfoldConfig {
        oriented,
        ..NfoldConfig::default()
    };
    let detector = NfoldDetector::new(config).unwrap();
    let mut rng = StdRng::seed_from_u64(seed);
    (0..frames)
        .filter(|_| {
            // Without anti-aliasing: it is texture, and this keeps the test quick.
            let image = random_markerless(&mut rng, 1);
            // A region's search falls back to coarser levels: anywhere it looks counts too.
            let (u, v) = (rng.random_range(0.0..640.0), rng.random_range(0.0..480.0));
            let roi = Roi::around(u, v, 60.0);
            detector.detect(&image.view()).unwrap().is_some()
                || detector
                    .detect_in_roi(&image.view(), &roi)
                    .unwrap()
                    .is_some()
        })
        .count()
}

#[test]
fn markerless_frames_give_no_detection() {
    // 200 frames (100 for the oriented variant) in the default suite, each searched whole and
    // in a random region; the 1,000-frame version is ignored (run it with --ignored). Fewer
    // than 1 % may be false positives.
    for (oriented, frames) in [(false, 200), (true, 100)] {
        let fp = false_positives(17, frames, oriented);
        println!("markerless frames (oriented: {oriented}): {fp} false positives in {frames}");
        assert!(fp * 100 < frames, "{fp} false positives in {frames} frames");
    }
}

#[test]
#[ignore = "1,000 frames: about a minute"]
fn markerless_frames_give_no_detection_1000() {
    let fp = false_positives(18, 1000, false);
    println!("markerless frames: {fp} false positives in 1000");
    assert!(fp * 100 < 1000, "{fp} false positives in 1000 frames");
}

#[test]
fn flat_frames_give_no_detection() {
    let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
    let grey = GrayImage::filled(640, 480, 128).unwrap();
    assert_eq!(detector.detect(&grey.view()).unwrap(), None);
    let mut noise = crate::vision::render::SplitMix64::new(3);
    let data = (0..640 * 480)
        .map(|_| (noise.next_u64() >> 56) as u8)
        .collect();
    let noise = GrayImage::from_vec(640, 480, data).unwrap();
    assert_eq!(detector.detect(&noise.view()).unwrap(), None);
}

#[test]
fn bad_frames_are_named_errors() {
    let config = NfoldConfig {
        expected_frame_size_px: Some((640, 480)),
        ..NfoldConfig::default()
    };
    let detector = NfoldDetector::new(config).unwrap();
    let small = GrayImage::filled(320, 240, 0).unwrap();
    assert!(matches!(
        detector.detect(&small.view()),
        Err(NfoldError::Frame(FrameError::WrongSize { .. }))
    ));
    let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
    let tiny = GrayImage::filled(20, 400, 0).unwrap();
    assert_eq!(
        detector.detect(&tiny.view()),
        Err(NfoldError::FrameTooSmall {
            width_px: 20,
            height_px: 400,
            min_px: 25
        })
    );
    assert!(matches!(
        detector.detect_in_roi(&tiny.view(), &Roi::around(10.0, 10.0, 5.0)),
        Err(NfoldError::FrameTooSmall { .. })
    ));
    // Zero size, short strides and short buffers are refused when the view is made.
    assert!(ImageView::new(0, 480, 640, &[]).is_err());
    assert!(ImageView::new(640, 480, 600, &vec![0; 640 * 480]).is_err());
    assert!(ImageView::new(640, 480, 640, &vec![0; 1000]).is_err());
}

#[test]
fn padded_rows_are_read_through_the_stride() {
    let mut rng = StdRng::seed_from_u64(19);
    let case = random_case(&mut rng, false, None, (3.0, 4.0));
    let detector = NfoldDetector::new(NfoldConfig::default()).unwrap();
    let packed = detector.detect(&case.image.view()).unwrap().unwrap();
    // The same frame in rows of 704 bytes whose padding is white noise.
    let stride = 704;
    let mut padded = vec![0u8; stride * 480];
    for (y, row) in padded.chunks_mut(stride).enumerate() {
        row[..640].copy_from_slice(&case.image.data()[y * 640..(y + 1) * 640]);
        row[640..]
            .iter_mut()
            .enumerate()
            .for_each(|(i, p)| *p = (i * 97 % 251) as u8);
    }
    let view = ImageView::new(640, 480, stride, &padded).unwrap();
    assert_eq!(detector.detect(&view).unwrap(), Some(packed));
}

#[test]
fn bad_configs_are_named_errors() {
    let with = |f: fn(&mut NfoldConfig)| {
        let mut c = NfoldConfig::default();
        f(&mut c);
        NfoldDetector::new(c).unwrap_err()
    };
    assert_eq!(with(|c| c.order = 1), NfoldConfigError::Order(1));
    assert_eq!(
        with(|c| c.kernel_sizes_px = vec![13, 16]),
        NfoldConfigError::KernelSize(16)
    );
    assert_eq!(
        with(|c| c.search_kernel_px = 3),
        NfoldConfigError::KernelSize(3)
    );
    assert_eq!(
        with(|c| c.kernel_sizes_px.clear()),
        NfoldConfigError::NoKernelSizes
    );
    assert_eq!(
        with(|c| c.quality_threshold = 1.5),
        NfoldConfigError::QualityThreshold(1.5)
    );
    assert_eq!(
        with(|c| c.search_level = 4),
        NfoldConfigError::SearchLevel(4)
    );
    assert_eq!(
        with(|c| c.roi_fallback_levels = 5),
        NfoldConfigError::RoiFallbackLevels(5)
    );
    assert_eq!(with(|c| c.candidates = 0), NfoldConfigError::NoCandidates);
}

#[test]
fn the_separable_search_equals_the_direct_kernel() {
    let mut rng = StdRng::seed_from_u64(20);
    let (w, h) = (61, 47);
    let data: Vec<u8> = (0..w * h).map(|_| rng.random()).collect();
    let image = GrayImage::from_vec(w, h, data).unwrap();
    let view = image.view();
    for (order, size) in [(4, 13), (3, 9), (5, 25), (2, 7)] {
        let separable = SeparableKernel::new(order, size);
        let direct = DirectKernel::new(order, size);
        let plane = Plane::from_view(&view, 0, 0, w, h, 0);
        let response = separable.magnitude_squared(&plane);
        let r = size / 2;
        assert_eq!((response.width, response.height), (w - 2 * r, h - 2 * r));
        for y in 0..response.height {
            for x in 0..response.width {
                let (re, im) = direct
                    .response(&view, (x + r) as i64, (y + r) as i64)
                    .unwrap();
                let exact = re * re + im * im;
                let got = response.data[y * response.width + x] as f64;
                // f32 accumulation against f64.
                let scale = (direct.abs_sum * 255.0).powi(2);
                assert!(
                    (got - exact).abs() < 1e-5 * scale,
                    "{order}/{size} at {x},{y}"
                );
            }
        }
    }
}

#[test]
fn the_phase_gives_the_drawn_orientation() {
    // A level camera with yaw 0 sees the patch upright: the image orientation is the
    // patch's yaw.
    let cam = camera();
    let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -4.0), 0.0, 0.0, 0.0);
    for oriented in [false, true] {
        let config = NfoldConfig {
            oriented,
            ..NfoldConfig::default()
        };
        let detector = NfoldDetector::new(config).unwrap();
        for k in 0..12 {
            let yaw = -PI + (k as f64 + 0.3) * TAU / 12.0;
            let marker = Patch::square(
                0.2,
                -0.3,
                yaw,
                MARKER_M,
                Texture::nfold(4, oriented).unwrap(),
            );
            let scene = Scene::new(Texture::uniform(1.0)).with_patch(marker);
            let options = RenderOptions {
                supersampling: 4,
                ..Default::default()
            };
            let image = render(&cam, &pose, &scene, &options).unwrap();
            let d = detector.detect(&image.view()).unwrap().unwrap();
            let (u, v) = cam
                .project_world(&pose, &Point3::new(0.2, -0.3, 0.0))
                .unwrap();
            assert!((d.u_px - u).abs() < 0.1 && (d.v_px - v).abs() < 0.1);
            let period = if oriented { TAU } else { TAU / 4.0 };
            let e = (d.orientation_rad - yaw).rem_euclid(period);
            assert!(e.min(period - e) < 0.5f64.to_radians(), "{yaw}: {d:?}");
            assert_eq!(d.orientation_resolved, oriented);
            assert!(d.quality > 0.7 && d.kernel_size_px == 13, "{d:?}");
            // Black 0 and white 255: |R|/Σ|K| is about 0.3 × 255, ¾ of that with a leg missing.
            let expected = if oriented { 0.75 * 75.0 } else { 75.0 };
            assert!((d.response_magnitude / expected - 1.0).abs() < 0.1, "{d:?}");
        }
    }
}

#[test]
fn the_quadratic_fit_finds_the_peak_of_a_quadratic() {
    let f = |x: f64, y: f64| {
        10.0 - 2.0 * (x - 0.3).powi(2) - (y + 0.2).powi(2) - 0.5 * (x - 0.3) * (y + 0.2)
    };
    let grid = [-1.0, 0.0, 1.0].map(|y| [-1.0, 0.0, 1.0].map(|x| f(x, y)));
    let (du, dv) = quadratic_peak(&grid);
    assert!((du - 0.3).abs() < 1e-12 && (dv + 0.2).abs() < 1e-12);
}
