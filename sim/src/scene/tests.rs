use super::baked::TILE_TEXELS;
use super::*;
use algorithms::vision::render::{render, RenderOptions};

fn camera_at(altitude_m: f64) -> (PinholeCamera, CameraPose) {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
    let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -altitude_m), 0.0, 0.0, 0.0);
    (camera, pose)
}

#[test]
fn hazards_along_a_track_lie_beside_it_and_clear_of_it() {
    // An L-shaped track: 200 m north, then 100 m east.
    let mut track = Vec::new();
    for i in 0..=200 {
        track.push([f64::from(i), 0.0]);
    }
    for i in 1..=100 {
        track.push([200.0, f64::from(i)]);
    }
    let config = TrackScatterConfig::default();
    let field = HazardField::along_track(3, &track, &config).unwrap();
    assert_eq!(field.hazards.len(), 32);
    for class in HazardClass::ALL {
        let count = field.hazards.iter().filter(|h| h.class == class).count();
        assert_eq!(count, config.count_per_class[class as usize]);
    }
    for h in &field.hazards {
        // Brute force: the distance to the densely sampled track.
        let distance = track
            .iter()
            .map(|p| (p[0] - h.north_m).hypot(p[1] - h.east_m))
            .fold(f64::INFINITY, f64::min);
        let half_across = match h.class {
            HazardClass::Vehicle => 1.0,
            _ => h.class.bounding_radius_m(),
        };
        assert!(
            distance >= TRACTOR_HALF_WIDTH_M + half_across - 1e-6,
            "{h:?}: {distance}"
        );
        assert!(
            distance <= 3.0 + 1e-6,
            "{h:?} is {distance} m off the track"
        );
        // Not on the first 10 m (the first leg runs north from 0).
        assert!(h.north_m >= 10.0 - 1e-9, "{h:?}");
        if h.class == HazardClass::Vehicle {
            // Parked along its leg.
            let along = [0.0, std::f64::consts::FRAC_PI_2];
            assert!(along.iter().any(|a| (h.yaw_rad - a).abs() < 1e-9), "{h:?}");
        }
    }
    for (i, a) in field.hazards.iter().enumerate() {
        for b in &field.hazards[i + 1..] {
            let gap = (a.north_m - b.north_m).hypot(a.east_m - b.east_m);
            let least = a.class.bounding_radius_m() + b.class.bounding_radius_m() + 1.0;
            assert!(gap >= least - 1e-9);
        }
    }
    assert_eq!(field, HazardField::along_track(3, &track, &config).unwrap());
    assert_ne!(field, HazardField::along_track(4, &track, &config).unwrap());
    // A track too short to hold them, and bad settings, are named errors.
    assert!(matches!(
        HazardField::along_track(3, &track[..5], &config),
        Err(SceneError::Crowded { .. })
    ));
    let bad = TrackScatterConfig {
        lateral_offset_m: [3.0, 1.0],
        ..config
    };
    assert!(matches!(
        HazardField::along_track(3, &track, &bad),
        Err(SceneError::Setting {
            name: "lateral_offset_m",
            ..
        })
    ));
}

#[test]
fn hazard_class_names_round_trip() {
    for class in HazardClass::ALL {
        assert_eq!(class.to_string().parse::<HazardClass>().unwrap(), class);
    }
    assert!(matches!(
        "tractor".parse::<HazardClass>(),
        Err(SceneError::UnknownHazardClass(name)) if name == "tractor"
    ));
}

#[test]
fn scatter_is_deterministic_per_seed_and_never_overlaps() {
    let config = ScatterConfig {
        north_m: [-30.0, 30.0],
        east_m: [-30.0, 30.0],
        count_per_class: [20, 12, 6],
        keep_out_path_ne_m: vec![[-30.0, 0.0], [30.0, 0.0]],
        keep_out_radius_m: 3.0,
        min_gap_m: 0.3,
    };
    let a = HazardField::scatter(7, &config).unwrap();
    assert_eq!(a, HazardField::scatter(7, &config).unwrap());
    assert_ne!(a, HazardField::scatter(8, &config).unwrap());
    assert_eq!(a.hazards.len(), 38);
    for class in HazardClass::ALL {
        let count = a.hazards.iter().filter(|h| h.class == class).count();
        assert_eq!(count, config.count_per_class[class as usize]);
    }
    for (i, h) in a.hazards.iter().enumerate() {
        assert!(h.north_m.abs() <= 30.0 && h.east_m.abs() <= 30.0);
        // The path runs along east = 0.
        assert!(h.east_m.abs() >= 3.0 + h.class.bounding_radius_m(), "{h:?}");
        assert_eq!(h.id as usize, i);
        for g in &a.hazards[i + 1..] {
            let gap = (h.north_m - g.north_m).hypot(h.east_m - g.east_m);
            assert!(
                gap >= h.class.bounding_radius_m() + g.class.bounding_radius_m() + 0.3,
                "{h:?} overlaps {g:?}"
            );
        }
    }
}

#[test]
fn bad_scatter_settings_are_named_errors() {
    let crowded = ScatterConfig {
        north_m: [0.0, 5.0],
        east_m: [0.0, 5.0],
        count_per_class: [0, 0, 10],
        ..Default::default()
    };
    assert!(matches!(
        HazardField::scatter(1, &crowded),
        Err(SceneError::Crowded {
            class: HazardClass::Vehicle,
            ..
        })
    ));
    let flat = ScatterConfig {
        north_m: [5.0, 5.0],
        ..Default::default()
    };
    assert!(matches!(
        HazardField::scatter(1, &flat),
        Err(SceneError::Area { .. })
    ));
    let negative = ScatterConfig {
        min_gap_m: -1.0,
        ..Default::default()
    };
    assert!(matches!(
        HazardField::scatter(1, &negative),
        Err(SceneError::Setting {
            name: "min_gap_m",
            ..
        })
    ));
    assert!(matches!(
        SimScene::new(1).with_pad(PadPose {
            height_m: f64::NAN,
            ..Default::default()
        }),
        Err(SceneError::PadPose(_))
    ));
}

/// Pixels of a lone hazard seen from 7.5 m: those that do not change with the background.
fn hazard_pixels(hazard: Hazard) -> Vec<(usize, usize, u8)> {
    let (camera, pose) = camera_at(7.5);
    let options = RenderOptions {
        supersampling: 1,
        ..Default::default()
    };
    let images: Vec<_> = [0.0f32, 1.0]
        .into_iter()
        .map(|level| {
            let field = Texture::uniform(level);
            let scene = Scene::new(field.clone()).with_patch(hazard.patch(&field));
            render(&camera, &pose, &scene, &options).unwrap()
        })
        .collect();
    let mut pixels = Vec::new();
    for y in 0..480 {
        for x in 0..640 {
            if images[0].get(x, y) == images[1].get(x, y) {
                pixels.push((x, y, images[0].get(x, y)));
            }
        }
    }
    pixels
}

#[test]
fn each_class_has_its_own_size_shape_and_shade_at_7_5_m() {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
    let gsd_m = 7.5 / camera.fx_px;
    let mut means = Vec::new();
    for class in HazardClass::ALL {
        let hazard = Hazard {
            class,
            north_m: 0.3,
            east_m: -0.2,
            yaw_rad: 0.6,
            id: 0,
        };
        let pixels = hazard_pixels(hazard);
        let area_m2 = pixels.len() as f64 * gsd_m * gsd_m;
        let expected_m2 = class.shape_area_m2();
        assert!(
            (area_m2 / expected_m2 - 1.0).abs() < 0.2,
            "{class}: {area_m2} m² against {expected_m2} m²"
        );
        // Elongation from the second moments: the ratio of the principal axes.
        let n = pixels.len() as f64;
        let (mx, my) = pixels.iter().fold((0.0, 0.0), |(a, b), &(x, y, _)| {
            (a + x as f64 / n, b + y as f64 / n)
        });
        let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
        for &(x, y, _) in &pixels {
            let (dx, dy) = (x as f64 - mx, y as f64 - my);
            sxx += dx * dx / n;
            syy += dy * dy / n;
            sxy += dx * dy / n;
        }
        let half_trace = 0.5 * (sxx + syy);
        let root = (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt();
        let elongation = ((half_trace + root) / (half_trace - root)).sqrt();
        let (length_m, width_m) = class.size_m();
        let expected = length_m.max(width_m) / length_m.min(width_m);
        assert!(
            (elongation / expected - 1.0).abs() < 0.2,
            "{class}: elongation {elongation}"
        );
        let mean = pixels.iter().map(|p| p.2 as f64).sum::<f64>() / n;
        means.push((class, mean));
    }
    for (i, a) in means.iter().enumerate() {
        for b in &means[i + 1..] {
            assert!((a.1 - b.1).abs() > 40.0, "{means:?}");
        }
    }
}

#[test]
fn a_hazard_shows_the_field_outside_its_shape() {
    let field = Texture::field(5);
    let hazard = Hazard {
        class: HazardClass::Person,
        north_m: 1.0,
        east_m: 2.0,
        yaw_rad: 0.3,
        id: 0,
    };
    let patch = hazard.patch(&field);
    // The rectangle's corner is outside the round shape: the field's value there.
    let corner = patch.point_world(0.98, -0.98);
    assert_eq!(
        patch.texture.sample(0.98, -0.98),
        field.sample(corner.x, corner.y)
    );
    assert_eq!(patch.texture.sample(0.0, 0.0), 0.62);
}

#[test]
fn the_baked_field_matches_the_field_at_its_texels_and_between() {
    let source = Texture::field(9);
    let baked = baked_texture(source.clone(), 0.02, 10.0);
    let half_m =
        0.5 * (10.0f64 / (TILE_TEXELS as f64 * 0.02) * 2.0).ceil() * TILE_TEXELS as f64 * 0.02;
    let mut worst = 0f32;
    for k in 0..500 {
        // Texel corners, in several tiles.
        let (i, j) = ((k * 37) % 900, (k * 53) % 900);
        let (n, e) = (-half_m + i as f64 * 0.02, -half_m + j as f64 * 0.02);
        worst = worst.max((baked.sample(n, e) - source.sample(n, e)).abs());
    }
    assert!(worst < 1e-4, "at texels: {worst}");
    // Between texels the bilinear value is close.
    let mut sum = 0f32;
    for k in 0..500 {
        let (n, e) = (k as f64 * 0.0137 - 3.0, k as f64 * -0.0191 + 2.0);
        sum += (baked.sample(n, e) - source.sample(n, e)).abs();
    }
    assert!(sum / 500.0 < 0.03, "between texels: {}", sum / 500.0);
    // Outside the baked square the field repeats with the square's side as period.
    let period_m = 2.0 * half_m;
    for (n, e) in [(50.0, -70.0), (3.3, 1.7), (-9.9, 0.01)] {
        let inside = baked.sample(n, e);
        assert_eq!(baked.sample(n + period_m, e), inside);
        assert_eq!(baked.sample(n - 3.0 * period_m, e + period_m), inside);
    }
    // A non-finite coordinate is the source's business, not a panic.
    let _ = baked.sample(f64::NAN, 0.0);
    // Many points at once (runs within a tile, jumps between tiles, the periodic copies,
    // a point off the grid) give what one point at a time gives.
    let mut points: Vec<[f64; 2]> = (0..300)
        .map(|k| [k as f64 * 0.031 - 4.0, (k % 17) as f64 * 0.9 - 7.0])
        .collect();
    points.extend([[50.0, -70.0], [f64::INFINITY, 1.0], [3.3, 1.7]]);
    // A run far outside the square (a tractor kilometres out), crossing a repetition's edge.
    points.extend((0..200).map(|k| [1200.0 + k as f64 * 0.013, -830.0 - k as f64 * 0.07]));
    let mut many = vec![0f32; points.len()];
    baked.sample_many(&points, &mut many);
    for (&[n, e], value) in points.iter().zip(&many) {
        let one = baked.sample(n, e);
        assert!(
            one == *value || (one.is_nan() && value.is_nan()),
            "({n}, {e}): {value} at once, {one} alone"
        );
    }
}

#[test]
fn the_visible_scene_culls_what_the_camera_cannot_see() {
    let config = ScatterConfig {
        north_m: [-100.0, 100.0],
        east_m: [-100.0, 100.0],
        count_per_class: [30, 20, 10],
        ..Default::default()
    };
    let scene = SimScene::new(2)
        .with_hazards(HazardField::scatter(3, &config).unwrap())
        .with_tractor_body(TractorBody::default())
        .unwrap()
        .with_pad(PadPose {
            north_m: 0.5,
            east_m: 0.0,
            height_m: 2.0,
            yaw_rad: 0.2,
        })
        .unwrap();
    let (camera, pose) = camera_at(8.0);
    let visible = scene.visible_scene(&camera, &pose).unwrap();
    let full = scene.full_scene().unwrap();
    // Roof + pad + n-fold + 3 ArUco.
    assert_eq!(full.patches.len(), 60 + 6);
    assert!(visible.patches.len() < 20, "{}", visible.patches.len());
    assert!(visible.patches.len() >= 6);
    // Culling does not change the image.
    let options = RenderOptions {
        supersampling: 1,
        ..Default::default()
    };
    assert_eq!(
        render(&camera, &pose, &visible, &options).unwrap(),
        render(&camera, &pose, &full, &options).unwrap()
    );
}
