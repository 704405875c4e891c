use super::motion::mask_out;
use super::*;
use crate::vision::features::{Descriptor, Keypoint};
use nalgebra::Point3;

#[test]
fn level_pixels_are_where_a_level_north_facing_camera_sees_the_point() {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
    let position = Vector3::new(1.0, -2.0, -7.0);
    let level = CameraPose::downward(position, 0.0, 0.0, 0.0);
    for attitude in [
        Attitude::new(0.0, 0.0, 0.0),
        Attitude::new(0.12, -0.08, 0.0),
        Attitude::new(-0.2, 0.15, 2.1),
    ] {
        let tilted = CameraPose::downward(
            position,
            attitude.roll_rad,
            attitude.pitch_rad,
            attitude.yaw_rad,
        );
        for point in [Point3::new(1.5, -1.0, 0.0), Point3::new(-0.5, -3.0, -1.0)] {
            let (u, v) = camera.project_world(&tilted, &point).unwrap();
            let (lu, lv) = level_pixel(&camera, &attitude, u, v).unwrap();
            let (eu, ev) = camera.project_world(&level, &point).unwrap();
            assert!(
                (lu - eu).abs() < 1e-6 && (lv - ev).abs() < 1e-6,
                "{attitude:?}"
            );
        }
    }
    // Looking at the horizon: no level pixel.
    assert!(level_pixel(&camera, &Attitude::new(0.0, 1.55, 0.0), 320.0, 0.0).is_none());
}

#[test]
fn keypoints_on_the_target_are_masked_out() {
    let image = GrayImage::filled(64, 48, 0).unwrap();
    let matcher = FeatureMatcher::new(FeatureConfig::default());
    let mut features = matcher.features(&image.view());
    assert!(features.keypoints.is_empty());
    // Three keypoints with their descriptors; the middle one is inside the box.
    for (x, y) in [(5.0, 5.0), (30.0, 20.0), (60.0, 40.0)] {
        features.keypoints.push(Keypoint {
            x_px: x,
            y_px: y,
            score: 1.0,
            angle_rad: 0.0,
        });
        features.descriptors.push(Descriptor([x as u64, 0, 0, 0]));
    }
    mask_out(
        &mut features,
        &PixelBox::from_centre(30.0, 20.0, 10.0, 10.0),
        1.2,
    );
    let left: Vec<f64> = features.keypoints.iter().map(|k| k.x_px).collect();
    assert_eq!(left, vec![5.0, 60.0]);
    assert_eq!(features.descriptors[1].0[0], 60);
}

fn valid_config() -> HybridTrackingConfig {
    HybridTrackingConfig {
        camera: PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap(),
        pad_size_m: 1.0,
        tracker: TrackerConfig::default(),
        altitude_window_fraction: 0.2,
        altitude_min_valid_fraction: 0.3,
        stereo_min_range_m: 0.5,
        stereo_max_range_m: 20.0,
        altitude_filter: AltitudeFilterConfig::default(),
        velocity_observer: VelocityObserverConfig::default(),
        homography_min_altitude_m: 3.0,
        max_ugv_speed_m_s: 5.0,
        ransac_threshold_px: 3.0,
        homography_min_inliers: 8,
    }
}

#[test]
fn a_bad_part_config_names_the_part_and_keeps_its_error() {
    assert!(HybridTracker::new(valid_config()).is_ok());
    let mut config = valid_config();
    config.tracker.a1_distance = -0.5;
    let error = HybridTracker::new(config).err().unwrap();
    assert!(
        matches!(
            &error,
            HybridTrackingConfigError::Tracker(TrackingError::Config {
                name: "a1_distance",
                ..
            })
        ),
        "{error:?}"
    );
    let cause = std::error::Error::source(&error).expect("the tracker's error");
    assert!(error.to_string().starts_with("tracker: "), "{error}");
    assert!(error.to_string().ends_with(&cause.to_string()), "{error}");

    let mut config = valid_config();
    config.velocity_observer.sigma_s = -1.0;
    let error = HybridTracker::new(config).err().unwrap();
    assert!(
        matches!(&error, HybridTrackingConfigError::Velocity(_)),
        "{error:?}"
    );
    assert!(std::error::Error::source(&error).is_some());
}
