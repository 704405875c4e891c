use super::*;
use crate::camera::{CameraPose, PinholeCamera};
use crate::vision::image::GrayImage;
use crate::vision::render::{render, true_pixel, ImageEffects, RenderOptions, Scene};
use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

fn camera() -> PinholeCamera {
    PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap()
}

fn wrap(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

/// A pad seen from a random pose, the frame and the truth: centre pixel and the image angle
/// of the pad's x axis.
struct Case {
    frame: GrayImage,
    centre_px: [f64; 2],
    orientation_rad: f64,
    pad_in_view: bool,
}

fn render_case(
    rng: &mut StdRng,
    extra: &[Patch],
    seed: u64,
    altitude_range_m: std::ops::Range<f64>,
) -> Case {
    let layout = LandingMarkerLayout::default();
    let camera = camera();
    let altitude_m = rng.random_range(altitude_range_m);
    let pad_yaw = rng.random_range(-PI..PI);
    let (north, east) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
    let pose = CameraPose::downward(
        Vector3::new(0.0, 0.0, -altitude_m),
        rng.random_range(-0.3..0.3),
        rng.random_range(-0.3..0.3),
        rng.random_range(-PI..PI),
    );
    let mut scene = Scene::new(Texture::field(seed));
    scene.patches = layout.patches(north, east, 0.0, pad_yaw).unwrap();
    scene.patches.extend(extra.iter().cloned().map(|mut p| {
        p.north_m += north;
        p.east_m += east;
        p
    }));
    let options = RenderOptions {
        supersampling: 2,
        effects: ImageEffects {
            gaussian_blur_sigma_px: rng.random_range(0.0..1.0),
            noise_sigma: rng.random_range(0.0..4.0),
            noise_seed: seed,
            ..ImageEffects::default()
        },
    };
    let frame = render(&camera, &pose, &scene, &options).unwrap();
    let pad = &scene.patches[0];
    let centre = true_pixel(&camera, &pose, &pad.point_world(0.0, 0.0)).unwrap();
    let along_x = true_pixel(&camera, &pose, &pad.point_world(0.02, 0.0)).unwrap();
    let corners_in_view = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
        .iter()
        .all(|&(u, v)| {
            true_pixel(&camera, &pose, &pad.point_world(u, v))
                .is_some_and(|(x, y)| (8.0..632.0).contains(&x) && (8.0..472.0).contains(&y))
        });
    Case {
        frame,
        centre_px: [centre.0, centre.1],
        orientation_rad: (along_x.1 - centre.1).atan2(along_x.0 - centre.0),
        pad_in_view: corners_in_view,
    }
}

#[test]
fn the_pad_is_found_at_its_true_centre_and_orientation() {
    let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
    let mut rng = StdRng::seed_from_u64(11);
    let (mut errors_px, mut angle_errors_deg, mut missed) = (Vec::new(), Vec::new(), 0);
    let mut cases = 0;
    while cases < 40 {
        let case = render_case(&mut rng, &[], cases as u64, 2.0..9.0);
        if !case.pad_in_view {
            continue;
        }
        cases += 1;
        match detector.detect(&case.frame.view(), None).unwrap() {
            None => missed += 1,
            Some(observation) => {
                let [u, v] = observation.centre_px;
                errors_px.push(((u - case.centre_px[0]).hypot(v - case.centre_px[1])).abs());
                let angle = observation.orientation_rad.expect("ArUco markers in view");
                angle_errors_deg.push(wrap(angle - case.orientation_rad).abs().to_degrees());
            }
        }
    }
    errors_px.sort_by(f64::total_cmp);
    angle_errors_deg.sort_by(f64::total_cmp);
    let median = errors_px[errors_px.len() / 2];
    let p95 = errors_px[errors_px.len() * 95 / 100];
    assert!(missed <= 1, "missed {missed} of {cases}");
    assert!(
        median < 0.5 && p95 < 1.5,
        "centre error median {median} p95 {p95}"
    );
    let worst_angle = angle_errors_deg.last().unwrap();
    assert!(*worst_angle < 2.0, "orientation error up to {worst_angle}°");
}

#[test]
fn an_occluded_nfold_tip_leaves_the_aruco_markers_to_place_the_pad() {
    let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
    let mut rng = StdRng::seed_from_u64(5);
    // A grey disc-sized square over the tip, 1 cm above the pad.
    let occluder = Patch::square(0.0, 0.0, 0.3, 0.2, Texture::uniform(0.5)).at_down_m(-0.01);
    let mut checked = 0;
    while checked < 10 {
        // Low enough for the 0.18 m ArUco markers to span 30 px or more.
        let case = render_case(
            &mut rng,
            std::slice::from_ref(&occluder),
            100 + checked,
            1.5..3.2,
        );
        if !case.pad_in_view {
            continue;
        }
        checked += 1;
        let observation = detector.detect(&case.frame.view(), None).unwrap().unwrap();
        assert_eq!(observation.centre_from, CentreSource::Aruco);
        let [u, v] = observation.centre_px;
        let error = (u - case.centre_px[0]).hypot(v - case.centre_px[1]);
        assert!(error < 2.0, "error {error} px");
    }
}

#[test]
fn with_the_aruco_markers_covered_the_nfold_marker_alone_gives_the_centre() {
    let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
    let mut rng = StdRng::seed_from_u64(9);
    let layout = LandingMarkerLayout::default();
    // White squares over each ArUco marker (in pad coordinates with the pad's yaw 0: the
    // case adds the pad's offset, and the pad yaw is random, so cover a ring instead).
    let covers: Vec<Patch> = (0..16)
        .map(|k| {
            let angle = k as f64 * PI / 8.0;
            let radius = 0.38 * 2f64.sqrt();
            Patch::square(
                radius * angle.cos(),
                radius * angle.sin(),
                angle,
                0.3,
                Texture::uniform(1.0),
            )
            .at_down_m(-0.01)
        })
        .collect();
    assert_eq!(layout.aruco.len(), 3);
    let mut checked = 0;
    while checked < 10 {
        let case = render_case(&mut rng, &covers, 200 + checked, 2.0..9.0);
        if !case.pad_in_view {
            continue;
        }
        checked += 1;
        let observation = detector.detect(&case.frame.view(), None).unwrap().unwrap();
        assert!(observation.aruco.is_empty());
        assert_eq!(observation.centre_from, CentreSource::Nfold);
        let [u, v] = observation.centre_px;
        let error = (u - case.centre_px[0]).hypot(v - case.centre_px[1]);
        assert!(error < 1.5, "error {error} px");
    }
}

#[test]
fn a_field_without_the_pad_gives_no_observation() {
    let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
    let camera = camera();
    let mut rng = StdRng::seed_from_u64(3);
    let mut false_positives = 0;
    for seed in 0..60 {
        let pose = CameraPose::downward(
            Vector3::new(0.0, 0.0, -rng.random_range(2.0..15.0)),
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
            rng.random_range(-PI..PI),
        );
        let scene = Scene::new(Texture::field(1000 + seed));
        let frame = render(&camera, &pose, &scene, &RenderOptions::default()).unwrap();
        if detector.detect(&frame.view(), None).unwrap().is_some() {
            false_positives += 1;
        }
    }
    assert_eq!(false_positives, 0);
}

#[test]
fn the_fitted_homography_reproduces_a_known_one() {
    let truth = Matrix3::new(40.0, -12.0, 320.0, 9.0, 38.0, 240.0, 0.01, -0.02, 1.0);
    let mut rng = StdRng::seed_from_u64(1);
    let pairs: Vec<([f64; 2], [f64; 2])> = (0..12)
        .map(|_| {
            let p = [rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5)];
            (p, apply(&truth, p))
        })
        .collect();
    let fitted = fit_homography(&pairs).unwrap();
    for i in 0..3 {
        for j in 0..3 {
            assert!((fitted[(i, j)] - truth[(i, j)]).abs() < 1e-6 * truth[(i, j)].abs().max(1.0));
        }
    }
    assert!(fit_homography(&pairs[..3]).is_none());
}

#[test]
fn bad_layouts_are_named_errors() {
    let mut overlapping = LandingMarkerLayout::default();
    overlapping.aruco[0].centre_m = [-0.2, -0.2];
    assert!(
        matches!(overlapping.validate(), Err(LandingMarkerError::Layout(m)) if m.contains("overlaps"))
    );
    let mut unknown_id = LandingMarkerLayout::default();
    unknown_id.aruco[0].id = 50;
    assert!(
        matches!(unknown_id.validate(), Err(LandingMarkerError::Layout(m)) if m.contains("not in DICT_4X4_50"))
    );
    let mut off_pad = LandingMarkerLayout::default();
    off_pad.aruco[1].centre_m = [0.45, -0.38];
    assert!(
        matches!(off_pad.validate(), Err(LandingMarkerError::Layout(m)) if m.contains("does not fit"))
    );
    let dictionary = LandingMarkerLayout {
        dictionary: "DICT_9X9".into(),
        ..LandingMarkerLayout::default()
    };
    // The dictionary's own error is kept as the cause.
    let Err(error @ LandingMarkerError::Dictionary(_)) = dictionary.validate() else {
        panic!("an unknown dictionary must be named as such");
    };
    let cause = std::error::Error::source(&error).expect("the dictionary's error");
    assert!(cause.to_string().contains("DICT_9X9"), "{cause}");
    let mut order = LandingMarkerConfig::default();
    order.layout.nfold_order = 1;
    order.nfold.order = 1;
    let Err(LandingMarkerError::NfoldConfig(NfoldConfigError::Order(1))) =
        LandingMarkerDetector::new(order)
    else {
        panic!("an n-fold order of 1 must be refused by the n-fold detector");
    };
}

#[test]
fn a_frame_of_the_wrong_layout_is_a_named_error() {
    let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
    let data = [0u8; 16];
    let view = ImageView::new(4, 4, 4, &data).unwrap();
    assert!(detector.detect(&view, None).is_err());
}
