use super::*;
use crate::scene::{HazardField, PadPose, ScatterConfig, TractorBody};
use algorithms::estimation::projection::pad_relative_to_uav_ned_m;
use algorithms::vision::landing_marker::{LandingMarkerConfig, LandingMarkerDetector};
use algorithms::vision::render::Texture;
use algorithms::vision::render::{render, RenderOptions};

fn still() -> Vector3<f64> {
    Vector3::zeros()
}

fn small_config() -> SimCameraConfig {
    SimCameraConfig {
        width_px: 160,
        height_px: 120,
        ..Default::default()
    }
}

fn field_with_pad() -> SimScene {
    SimScene::new(11)
        .with_tractor_body(TractorBody::default())
        .unwrap()
        .with_pad(PadPose {
            north_m: 1.2,
            east_m: -0.7,
            height_m: 1.5,
            yaw_rad: 0.5,
        })
        .unwrap()
}

/// Bands of rows on several threads give the very image one thread gives (an odd
/// number of bands, so they are not all the same height).
#[test]
fn threaded_rendering_gives_the_same_frame() {
    let scene = field_with_pad();
    let vehicle = VehiclePose {
        position_ned_m: Vector3::new(0.5, -0.2, -6.0),
        attitude: Attitude {
            roll_rad: 0.05,
            pitch_rad: -0.1,
            yaw_rad: 0.3,
        },
        velocity_ned_m_s: Vector3::new(1.0, 0.0, 0.0),
        body_rates_rad_s: Vector3::zeros(),
    };
    let frame = |threads: usize| {
        let config = SimCameraConfig {
            render_threads: threads,
            ..small_config()
        };
        let mut camera = SimCamera::new(config, 3).unwrap();
        camera.capture_frame(0.0, &vehicle, &scene).unwrap().image
    };
    let one = frame(1);
    assert_eq!(*frame(3), *one);
    assert_eq!(*frame(0), *one);
    // The pad is in the picture: the comparison is of a frame with content.
    let (min, max) = one
        .data()
        .iter()
        .fold((u8::MAX, 0), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    assert!(max - min > 100, "a flat frame: {min}..{max}");
}

#[test]
fn the_detector_and_the_projection_recover_the_true_relative_position() {
    let scene = field_with_pad();
    let mut camera = SimCamera::new(SimCameraConfig::default(), 3).unwrap();
    let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
    let pad = scene.pad_pose().unwrap();
    for (position, attitude) in [
        (
            Vector3::new(0.3, 0.1, -9.0),
            Attitude::new(0.08, -0.06, 1.0),
        ),
        (
            Vector3::new(2.0, -1.5, -6.5),
            Attitude::new(-0.1, 0.12, -2.3),
        ),
    ] {
        let image = camera
            .capture(0.0, &position, &attitude, &still(), &still(), &scene)
            .unwrap();
        camera.last_slot = None;
        let observation = detector
            .detect(&image.view(), None)
            .unwrap()
            .expect("the pad is in view");
        let [u, v] = observation.centre_px;
        let height_above_pad_m = -pad.height_m - position.z;
        let relative =
            pad_relative_to_uav_ned_m(camera.model(), &attitude, height_above_pad_m, u, v).unwrap();
        let truth = Vector3::new(
            pad.north_m - position.x,
            pad.east_m - position.y,
            height_above_pad_m,
        );
        assert!(
            (relative - truth).norm() < 0.03,
            "recovered {relative:?}, truth {truth:?}"
        );
    }
}

#[test]
fn frames_are_due_once_per_period() {
    let scene = SimScene::new(1);
    let mut camera = SimCamera::new(small_config(), 1).unwrap();
    let at = Vector3::new(0.0, 0.0, -5.0);
    let level = Attitude::default();
    assert!(camera.is_due(0.0));
    camera
        .capture(0.0, &at, &level, &still(), &still(), &scene)
        .unwrap();
    assert!(!camera.is_due(0.0));
    assert!(!camera.is_due(0.099));
    assert!(camera.is_due(0.1));
    camera
        .capture(0.1, &at, &level, &still(), &still(), &scene)
        .unwrap();
    assert!(!camera.is_due(0.1999));
    assert!(camera.is_due(0.2));
    assert!(camera.is_due(0.35));
    assert!(!camera.is_due(f64::NAN));
}

#[test]
fn a_frozen_camera_repeats_its_last_frame_and_dropped_frames_leave_gaps() {
    let scene = field_with_pad();
    let mut camera = SimCamera::new(small_config(), 2).unwrap();
    camera.freeze(1.0, 1.3);
    camera.drop_frames(2.0, 2.2);
    let vehicle = |north_m: f64| VehiclePose {
        position_ned_m: Vector3::new(north_m, 0.0, -8.0),
        attitude: Attitude::default(),
        velocity_ned_m_s: Vector3::new(1.0, 0.0, 0.0),
        body_rates_rad_s: still(),
    };
    let before = camera.capture_frame(0.9, &vehicle(0.9), &scene).unwrap();
    for t in [1.0, 1.1, 1.2] {
        let frozen = camera.capture_frame(t, &vehicle(t), &scene).unwrap();
        assert_eq!(frozen.image, before.image, "t = {t}");
    }
    let live = camera.capture_frame(1.3, &vehicle(1.3), &scene).unwrap();
    assert_ne!(live.image, before.image);
    assert_eq!(live.frame_index, 4);
    for t in [2.0, 2.1] {
        assert!(matches!(
            camera.capture_frame(t, &vehicle(t), &scene),
            Err(CameraError::Dropped { .. })
        ));
    }
    let after = camera.capture_frame(2.2, &vehicle(2.2), &scene).unwrap();
    assert_eq!(after.frame_index, 7, "the dropped frames are a gap");
}

#[test]
fn bad_configs_and_states_are_named_errors() {
    let bad = |change: fn(&mut SimCameraConfig)| {
        let mut config = SimCameraConfig::default();
        change(&mut config);
        SimCamera::new(config, 0).unwrap_err()
    };
    assert!(matches!(
        bad(|c| c.width_px = 0),
        CameraError::Config(CameraConfigError::ImageSize { .. })
    ));
    assert!(matches!(
        bad(|c| c.horizontal_fov_deg = 0.0),
        CameraError::Config(CameraConfigError::FieldOfView(_))
    ));
    assert!(matches!(
        bad(|c| c.rate_fps = f64::NAN),
        CameraError::Config(CameraConfigError::Rate(_))
    ));
    assert!(matches!(
        bad(|c| c.exposure_ms = 150.0),
        CameraError::Config(CameraConfigError::Exposure { .. })
    ));
    assert!(matches!(
        bad(|c| c.noise_sigma = -1.0),
        CameraError::Config(CameraConfigError::Range {
            name: "noise_sigma",
            ..
        })
    ));
    assert!(matches!(
        bad(|c| c.drift_period_s = 0.0),
        CameraError::Config(CameraConfigError::Range {
            name: "drift_period_s",
            ..
        })
    ));
    assert!(matches!(
        bad(|c| c.supersampling = 0),
        CameraError::Config(CameraConfigError::Supersampling(0))
    ));
    assert!(matches!(
        bad(|c| c.distortion.k1 = f64::INFINITY),
        CameraError::Config(CameraConfigError::Distortion)
    ));
    let mut camera = SimCamera::new(small_config(), 0).unwrap();
    assert!(matches!(
        camera.capture(
            0.0,
            &Vector3::new(0.0, f64::NAN, -5.0),
            &Attitude::default(),
            &still(),
            &still(),
            &SimScene::new(0)
        ),
        Err(CameraError::VehicleState { .. })
    ));
}

#[test]
fn noise_has_the_configured_spread_and_the_drift_changes_brightness() {
    let flat = SimScene::new(0).with_field_texture(Texture::uniform(0.5));
    let config = SimCameraConfig {
        noise_sigma: 6.0,
        brightness_amplitude: 0.0,
        contrast_amplitude: 0.0,
        ..Default::default()
    };
    let mut camera = SimCamera::new(config, 4).unwrap();
    let at = Vector3::new(0.0, 0.0, -5.0);
    let image = camera
        .capture(0.0, &at, &Attitude::default(), &still(), &still(), &flat)
        .unwrap();
    let levels: Vec<f64> = image.data().iter().map(|&p| p as f64).collect();
    let n = levels.len() as f64;
    let mean = levels.iter().sum::<f64>() / n;
    let sd = (levels.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / n).sqrt();
    assert!((mean - 127.5).abs() < 1.0, "{mean}");
    assert!((sd - 6.0).abs() < 0.3, "{sd}");

    // With a drift, the mean wanders over tens of seconds.
    let drifting = SimCameraConfig {
        noise_sigma: 0.0,
        brightness_amplitude: 0.2,
        ..Default::default()
    };
    let mut camera = SimCamera::new(drifting, 4).unwrap();
    let means: Vec<f64> = (0..20)
        .map(|k| {
            let image = camera
                .capture(
                    k as f64 * 5.0,
                    &at,
                    &Attitude::default(),
                    &still(),
                    &still(),
                    &flat,
                )
                .unwrap();
            image.data().iter().map(|&p| p as f64).sum::<f64>() / n
        })
        .collect();
    let spread = means.iter().cloned().fold(f64::MIN, f64::max)
        - means.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread > 20.0, "{means:?}");
}

#[test]
fn motion_blur_follows_the_velocity_and_the_body_rates() {
    let config = SimCameraConfig {
        exposure_ms: 10.0,
        ..Default::default()
    };
    let camera = SimCamera::new(config, 0).unwrap();
    let fx = camera.model().fx_px;
    let position = Vector3::new(0.0, 0.0, -10.0);
    let pose = SimCamera::pose(&position, &Attitude::default());
    let moving_north = VehiclePose {
        position_ned_m: position,
        attitude: Attitude::default(),
        velocity_ned_m_s: Vector3::new(5.0, 0.0, 0.0),
        body_rates_rad_s: still(),
    };
    // 5 m/s at 10 m for 10 ms: 5 mm of ground, along the image's vertical (north is up).
    let blur = camera.motion_blur(&moving_north, &pose).unwrap();
    assert!((blur.length_px - 0.005 * fx).abs() < 1e-6, "{blur:?}");
    assert!(blur.angle_rad.sin().abs() > 0.999);
    let pitching = VehiclePose {
        velocity_ned_m_s: still(),
        body_rates_rad_s: Vector3::new(0.0, 0.5, 0.0),
        ..moving_north
    };
    let blur = camera.motion_blur(&pitching, &pose).unwrap();
    assert!((blur.length_px - 0.005 * fx).abs() < 1e-6, "{blur:?}");
    assert!(blur.angle_rad.sin().abs() > 0.999);
    // Rolling blurs sideways.
    let rolling = VehiclePose {
        body_rates_rad_s: Vector3::new(0.5, 0.0, 0.0),
        ..pitching
    };
    let blur = camera.motion_blur(&rolling, &pose).unwrap();
    assert!(blur.angle_rad.cos().abs() > 0.999, "{blur:?}");
    let hovering = VehiclePose {
        body_rates_rad_s: still(),
        ..pitching
    };
    assert!(camera.motion_blur(&hovering, &pose).is_none());
}

#[test]
fn the_fast_effects_match_the_renderers() {
    // A textured frame; the renderer's own effects are the reference.
    let data: Vec<u8> = (0..80 * 60)
        .map(|i| ((i % 80) * 3 + (i / 80) * 2 % 255) as u8)
        .collect();
    let image = GrayImage::from_vec(80, 60, data).unwrap();
    for (length_px, angle_rad) in [(0.7, 0.55), (3.3, -2.0), (6.0, 1.571)] {
        let effects = ImageEffects {
            motion_blur: Some(MotionBlur {
                length_px,
                angle_rad,
            }),
            contrast: 1.2,
            brightness: -0.05,
            ..Default::default()
        };
        let clean: Vec<f32> = image.data().iter().map(|&p| p as f32 / 255.0).collect();
        let fast = post_process(&clean, 80, 60, &effects, 1).unwrap();
        // In bands on threads, noise included: the same frame.
        let noisy = ImageEffects {
            noise_sigma: 3.0,
            noise_seed: 7,
            ..effects
        };
        assert_eq!(
            post_process(&clean, 80, 60, &noisy, 3).unwrap(),
            post_process(&clean, 80, 60, &noisy, 1).unwrap()
        );
        let reference = algorithms::vision::render::apply_effects(&image, &effects).unwrap();
        let worst = fast
            .data()
            .iter()
            .zip(reference.data())
            .map(|(&a, &b)| (a as i32 - b as i32).abs())
            .max()
            .unwrap();
        assert!(worst <= 1, "blur {length_px} px: {worst} grey levels apart");
    }
}

/// Prints the cost of one 640×480 capture of a busy field (run with `--ignored`).
#[test]
#[ignore]
fn capture_time_640x480() {
    let hazards = HazardField::scatter(
        5,
        &ScatterConfig {
            north_m: [-20.0, 20.0],
            east_m: [-20.0, 20.0],
            count_per_class: [10, 6, 3],
            ..Default::default()
        },
    )
    .unwrap();
    let scene = field_with_pad().with_hazards(hazards);
    let mut camera = SimCamera::new(SimCameraConfig::default(), 1).unwrap();
    let vehicle = VehiclePose {
        position_ned_m: Vector3::new(0.0, 0.0, -9.0),
        attitude: Attitude::new(0.05, -0.04, 0.3),
        velocity_ned_m_s: Vector3::new(2.0, 0.5, 0.3),
        body_rates_rad_s: Vector3::new(0.2, -0.1, 0.05),
    };
    let frames = 30;
    // The fastest of many captures: this VM's timings are noisy.
    let mut best_ms = f64::INFINITY;
    for k in 0..frames * 3 {
        let started = std::time::Instant::now();
        camera
            .capture_frame(k as f64 * 0.1, &vehicle, &scene)
            .unwrap();
        best_ms = best_ms.min(started.elapsed().as_secs_f64() * 1000.0);
    }
    println!(
        "one 640×480 capture, fastest of {}: {best_ms:.2} ms",
        frames * 3
    );
    let mut single = SimCamera::new(
        SimCameraConfig {
            render_threads: 1,
            ..SimCameraConfig::default()
        },
        1,
    )
    .unwrap();
    let mut best_ms = f64::INFINITY;
    for k in 0..frames * 3 {
        let started = std::time::Instant::now();
        single
            .capture_frame(k as f64 * 0.1, &vehicle, &scene)
            .unwrap();
        best_ms = best_ms.min(started.elapsed().as_secs_f64() * 1000.0);
    }
    println!("on one thread: {best_ms:.2} ms");
    // Where the time goes: the ray casting alone, then each effect on its own.
    let pose = SimCamera::pose(&vehicle.position_ned_m, &vehicle.attitude);
    let visible = scene.visible_scene(camera.model(), &pose).unwrap();
    let effects = camera.effects(0.0, 0, &vehicle, &pose);
    for (what, effects) in [
        ("ray casting only", ImageEffects::default()),
        (
            "+ noise",
            ImageEffects {
                noise_sigma: effects.noise_sigma,
                ..Default::default()
            },
        ),
        (
            "+ motion blur",
            ImageEffects {
                motion_blur: effects.motion_blur,
                ..Default::default()
            },
        ),
        ("uniform background", ImageEffects::default()),
    ] {
        let options = RenderOptions {
            supersampling: 1,
            effects,
        };
        let mut visible = visible.clone();
        if what == "uniform background" {
            visible.background = Texture::uniform(0.4);
        }
        let started = std::time::Instant::now();
        for _ in 0..frames {
            render(camera.model(), &pose, &visible, &options).unwrap();
        }
        let ms = started.elapsed().as_secs_f64() * 1000.0 / frames as f64;
        println!("{what}: {ms:.2} ms ({} patches)", visible.patches.len());
    }
    let clean = render(
        camera.model(),
        &pose,
        &visible,
        &RenderOptions {
            supersampling: 1,
            effects: ImageEffects::default(),
        },
    )
    .unwrap();
    let clean: Vec<f32> = clean.data().iter().map(|&p| p as f32 / 255.0).collect();
    let (width, height) = (camera.model().width_px, camera.model().height_px);
    let started = std::time::Instant::now();
    for _ in 0..frames {
        post_process(&clean, width, height, &effects, 1).unwrap();
    }
    let ms = started.elapsed().as_secs_f64() * 1000.0 / frames as f64;
    println!("the camera's effects ({effects:?}): {ms:.2} ms");
}
