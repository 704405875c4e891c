use super::*;
use std::f64::consts::PI;

fn level_camera(altitude_m: f64) -> (PinholeCamera, CameraPose) {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
    let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -altitude_m), 0.0, 0.0, 0.0);
    (camera, pose)
}

fn exact() -> RenderOptions {
    RenderOptions {
        supersampling: 1,
        effects: ImageEffects::default(),
    }
}

#[test]
fn a_patch_appears_where_the_camera_projects_it() {
    let (camera, pose) = {
        let camera = PinholeCamera::from_fov(640, 480, 1.1).unwrap();
        let pose = CameraPose::downward(Vector3::new(-1.0, 0.5, -6.0), 0.12, -0.08, 0.7);
        (camera, pose)
    };
    let patch = Patch::square(0.3, 0.2, 0.4, 1.0, Texture::uniform(1.0));
    let scene = Scene::new(Texture::uniform(0.0)).with_patch(patch.clone());
    let image = render(&camera, &pose, &scene, &exact()).unwrap();
    // Pixels just inside the projected corners are white, just outside black.
    for (u, v) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        let inside = true_pixel(&camera, &pose, &patch.point_world(0.9 * u, 0.9 * v)).unwrap();
        let outside = true_pixel(&camera, &pose, &patch.point_world(1.1 * u, 1.1 * v)).unwrap();
        let px = |(x, y): (f64, f64)| image.get(x.round() as usize, y.round() as usize);
        assert_eq!(px(inside), 255);
        assert_eq!(px(outside), 0);
    }
}

#[test]
fn a_level_camera_sees_the_texture_upright() {
    // Patch yaw 0 with a level camera of yaw 0: patch u → image right, v → image down.
    let (camera, pose) = level_camera(4.0);
    let texture = Texture::from_fn(|u, v| if u > 0.0 && v > 0.0 { 1.0 } else { 0.0 });
    let scene =
        Scene::new(Texture::uniform(0.5)).with_patch(Patch::square(0.0, 0.0, 0.0, 2.0, texture));
    let image = render(&camera, &pose, &scene, &exact()).unwrap();
    assert_eq!(image.get(400, 300), 255, "bottom right is white");
    assert_eq!(image.get(240, 300), 0);
    assert_eq!(image.get(400, 180), 0);
}

#[test]
fn the_nfold_texture_is_black_where_sin_n_theta_is_positive() {
    let tex = Texture::nfold(4, false).unwrap();
    for k in 0..64 {
        let theta = (k as f64 + 0.37) * 2.0 * PI / 64.0;
        let (u, v) = (0.5 * theta.cos(), 0.5 * theta.sin());
        let black = (4.0 * theta).sin() > 0.0;
        assert_eq!(
            tex.sample(u, v),
            if black { 0.0 } else { 1.0 },
            "θ = {theta}"
        );
    }
    assert_eq!(tex.sample(0.9, 0.9), 1.0, "outside the disc");
    let oriented = Texture::nfold(4, true).unwrap();
    assert_eq!(oriented.sample(0.5 * 0.3f64.cos(), 0.5 * 0.3f64.sin()), 1.0);
    assert_eq!(oriented.sample(0.5 * 1.8f64.cos(), 0.5 * 1.8f64.sin()), 0.0);
    assert!(matches!(
        Texture::nfold(1, false),
        Err(RenderError::NfoldOrder(1))
    ));
}

#[test]
fn the_aruco_texture_has_a_black_border_and_the_bits_inside() {
    // 2×2 bits: white, black / black, white → 4×4 cells with the border.
    let tex = Texture::aruco(&[true, false, false, true], 2).unwrap();
    let cell = |col: usize, row: usize| {
        tex.sample(
            -1.0 + (col as f64 + 0.5) * 0.5,
            -1.0 + (row as f64 + 0.5) * 0.5,
        )
    };
    for i in 0..4 {
        assert_eq!(cell(i, 0), 0.0);
        assert_eq!(cell(0, i), 0.0);
        assert_eq!(cell(3, i), 0.0);
        assert_eq!(cell(i, 3), 0.0);
    }
    assert_eq!(
        (cell(1, 1), cell(2, 1), cell(1, 2), cell(2, 2)),
        (1.0, 0.0, 0.0, 1.0)
    );
    assert!(matches!(
        Texture::aruco(&[true; 5], 2),
        Err(RenderError::ArucoBits {
            expected: 4,
            found: 5,
            ..
        })
    ));
}

#[test]
fn supersampling_averages_an_edge() {
    // A patch edge through the middle of pixel column 320: half white, half black. (Patches are
    // supersampled; the background is sampled once per pixel.)
    let (camera, pose) = level_camera(5.0);
    let edge_east_m = 0.5 * 5.0 / camera.fx_px; // the centre of column 320, east of the axis
    let white = Patch::new(
        0.0,
        edge_east_m + 5.0,
        0.0,
        10.0,
        10.0,
        Texture::uniform(1.0),
    );
    let options = RenderOptions {
        supersampling: 4,
        effects: ImageEffects::default(),
    };
    let scene = Scene::new(Texture::uniform(0.0)).with_patch(white);
    let image = render(&camera, &pose, &scene, &options).unwrap();
    assert_eq!(image.get(319, 240), 0);
    assert_eq!(image.get(321, 240), 255);
    assert!((image.get(320, 240) as i32 - 128).abs() <= 1);
    // Without supersampling the pixel takes one side.
    let options = RenderOptions {
        supersampling: 1,
        ..options
    };
    let image = render(&camera, &pose, &scene, &options).unwrap();
    assert!([0, 255].contains(&image.get(320, 240)));
}

#[test]
fn effects_change_the_image_as_asked() {
    let image = GrayImage::filled(64, 48, 128).unwrap();
    let bright = apply_effects(
        &image,
        &ImageEffects {
            brightness: 0.1,
            contrast: 2.0,
            ..Default::default()
        },
    )
    .unwrap();
    // 2·(128/255 − ½) + ½ + 0.1 → 153.5 grey levels.
    assert!((bright.get(5, 5) as i32 - 154).abs() <= 1);
    let noisy = ImageEffects {
        noise_sigma: 10.0,
        noise_seed: 7,
        ..Default::default()
    };
    let a = apply_effects(&image, &noisy).unwrap();
    assert_eq!(a, apply_effects(&image, &noisy).unwrap(), "seeded");
    let levels: Vec<f64> = a.data().iter().map(|&p| p as f64).collect();
    let mean = levels.iter().sum::<f64>() / levels.len() as f64;
    let sd = (levels.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / levels.len() as f64).sqrt();
    assert!(
        (mean - 128.0).abs() < 1.0 && (sd - 10.0).abs() < 1.0,
        "{mean} {sd}"
    );
    // Blur keeps a uniform image uniform and smooths a step.
    let mut step = GrayImage::filled(32, 8, 0).unwrap();
    for y in 0..8 {
        for x in 16..32 {
            step.set(x, y, 255);
        }
    }
    for effects in [
        ImageEffects {
            gaussian_blur_sigma_px: 1.5,
            ..Default::default()
        },
        ImageEffects {
            motion_blur: Some(MotionBlur {
                length_px: 4.0,
                angle_rad: 0.0,
            }),
            ..Default::default()
        },
    ] {
        let blurred = apply_effects(&step, &effects).unwrap();
        assert!(blurred.get(15, 4) > 60 && blurred.get(16, 4) < 195);
        assert_eq!(blurred.get(2, 4), 0);
        assert_eq!(blurred.get(29, 4), 255);
    }
    assert!(matches!(
        apply_effects(
            &image,
            &ImageEffects {
                noise_sigma: -1.0,
                ..Default::default()
            }
        ),
        Err(RenderError::Effect {
            name: "noise_sigma",
            ..
        })
    ));
}

#[test]
fn bad_scenes_are_named_errors() {
    let (camera, pose) = level_camera(3.0);
    let scene = Scene::new(Texture::uniform(0.5)).with_patch(Patch::square(
        0.0,
        0.0,
        0.0,
        0.0,
        Texture::uniform(1.0),
    ));
    assert!(matches!(
        render(&camera, &pose, &scene, &exact()),
        Err(RenderError::PatchSize { index: 0, .. })
    ));
    let mut empty = camera;
    empty.width_px = 0;
    assert!(matches!(
        render(&empty, &pose, &Scene::new(Texture::uniform(0.5)), &exact()),
        Err(RenderError::Frame(FrameError::Empty { .. }))
    ));
    let options = RenderOptions {
        supersampling: 0,
        ..Default::default()
    };
    assert!(matches!(
        render(&camera, &pose, &Scene::new(Texture::uniform(0.5)), &options),
        Err(RenderError::Supersampling(0))
    ));
}

#[test]
fn a_raised_patch_hides_what_is_below_it() {
    let (camera, pose) = level_camera(10.0);
    let scene = Scene::new(Texture::uniform(0.0))
        .with_patch(Patch::square(0.0, 0.0, 0.0, 1.0, Texture::uniform(1.0)).at_down_m(-2.0))
        .with_patch(Patch::square(0.0, 0.0, 0.0, 4.0, Texture::uniform(0.5)));
    let image = render(&camera, &pose, &scene, &exact()).unwrap();
    // The later patch lies on the ground, below the raised one: the raised one stays visible.
    assert_eq!(image.get(320, 240), 255);
    assert_eq!(image.get(320 + 60, 240), 128);
}

/// The closed form for a plane: with n the plane's unit normal (world down) and d the
/// camera's distance to it, both in the camera frame, the point seen through the normalised
/// ray r = (x, y, 1) lies at depth d / (n·r).
fn plane_depth(
    camera: &PinholeCamera,
    pose: &CameraPose,
    plane_down_m: f64,
    u: f64,
    v: f64,
) -> Option<f64> {
    let n_camera = pose.camera_to_world.rotation.inverse() * Vector3::z();
    let d = plane_down_m - pose.position_ned_m().z;
    let unit = camera.unproject(u, v).into_inner();
    let ray = unit / unit.z;
    let along = n_camera.dot(&ray);
    (along > 1e-9).then(|| d / along)
}

#[test]
fn depth_of_flat_ground_matches_the_closed_form_under_a_tilted_camera() {
    let pinhole = PinholeCamera::from_fov(80, 60, 70f64.to_radians()).unwrap();
    let distorted = pinhole.with_distortion(crate::camera::RadialTangential {
        k1: -0.12,
        k2: 0.03,
        p1: 0.001,
        p2: -0.0008,
        k3: 0.0,
    });
    let pose = CameraPose::downward(Vector3::new(2.0, -1.0, -6.0), 0.2, -0.15, 0.8);
    let scene = Scene::new(Texture::uniform(0.5));
    for camera in [pinhole, distorted] {
        let depth = render_depth(&camera, &pose, &scene).unwrap();
        assert_eq!((depth.width(), depth.height()), (80, 60));
        let mut spread = (f64::INFINITY, 0f64);
        for y in 0..60 {
            for x in 0..80 {
                let expected = plane_depth(&camera, &pose, 0.0, x as f64, y as f64).unwrap();
                let got = depth.get(x, y) as f64;
                assert!(
                    (got - expected).abs() < 1e-5 * expected,
                    "({x}, {y}): {got} vs {expected}"
                );
                // And the point at that depth on the pixel's ray lies on the ground.
                let (nx, ny) = camera.normalized(x as f64, y as f64);
                let point = pose.camera_to_world_point(&Point3::new(nx * got, ny * got, got));
                assert!(point.z.abs() < 1e-4, "{point}");
                spread = (spread.0.min(got), spread.1.max(got));
            }
        }
        // Tilted: the depth is not uniform (a level camera's would be).
        assert!(spread.1 - spread.0 > 1.0, "{spread:?}");
    }
}

#[test]
fn depth_sees_raised_patches_where_the_image_does_and_nan_is_the_sky() {
    // A white raised patch (2 m above a black ground) under a tilted camera: every pixel the
    // renderer draws white has the patch plane's depth, every black one the ground's.
    let camera = PinholeCamera::from_fov(96, 72, 60f64.to_radians()).unwrap();
    let pose = CameraPose::downward(Vector3::new(0.4, 0.3, -7.0), -0.1, 0.12, 0.3);
    let scene = Scene::new(Texture::uniform(0.0))
        .with_patch(Patch::square(0.0, 0.0, 0.5, 2.0, Texture::uniform(1.0)).at_down_m(-2.0));
    let image = render(&camera, &pose, &scene, &exact()).unwrap();
    let depth = render_depth(&camera, &pose, &scene).unwrap();
    let mut on_patch = 0;
    for y in 0..72 {
        for x in 0..96 {
            let (u, v) = (x as f64, y as f64);
            let z = depth.get(x, y) as f64;
            let plane = if image.get(x, y) == 255 {
                on_patch += 1;
                -2.0
            } else {
                0.0
            };
            let expected = plane_depth(&camera, &pose, plane, u, v).unwrap();
            assert!((z - expected).abs() < 1e-5 * expected, "({x}, {y})");
        }
    }
    assert!(on_patch > 100, "{on_patch} pixels on the patch");
    // A level camera sees flat ground at its height everywhere, the patch 2 m nearer.
    let level = CameraPose::downward(Vector3::new(0.0, 0.0, -7.0), 0.0, 0.0, 0.0);
    let depth = render_depth(&camera, &level, &scene).unwrap();
    assert!((depth.get(48, 36) - 5.0).abs() < 1e-5);
    assert!((depth.get(2, 2) - 7.0).abs() < 1e-5);
    // Pitched up 80°: the top of the image sees the sky (NaN), the bottom the ground.
    let horizon = CameraPose::downward(Vector3::new(0.0, 0.0, -7.0), 0.0, 1.4, 0.0);
    let depth = render_depth(&camera, &horizon, &scene).unwrap();
    for (x, y) in [(10, 0), (50, 5), (90, 70), (48, 36)] {
        let expected = plane_depth(&camera, &horizon, 0.0, x as f64, y as f64);
        let z = depth.get(x, y);
        match expected {
            None => assert!(z.is_nan(), "({x}, {y}): {z}"),
            Some(e) => assert!((z as f64 - e).abs() < 1e-4 * e, "({x}, {y}): {z} vs {e}"),
        }
    }
    assert!(depth.get(48, 0).is_nan() && depth.get(48, 71).is_finite());
    // Bad scenes are refused as the renderer refuses them.
    let bad = Scene::new(Texture::uniform(0.5)).with_patch(Patch::square(
        0.0,
        0.0,
        f64::NAN,
        1.0,
        Texture::uniform(1.0),
    ));
    assert!(matches!(
        render_depth(&camera, &pose, &bad),
        Err(RenderError::PatchPose { index: 0 })
    ));
}

#[test]
fn the_field_texture_is_seeded_and_textured() {
    let a = Texture::field(3);
    let b = Texture::field(3);
    let c = Texture::field(4);
    let pts: Vec<(f64, f64)> = (0..200)
        .map(|i| (i as f64 * 0.173, i as f64 * -0.091))
        .collect();
    assert!(pts.iter().all(|&(n, e)| a.sample(n, e) == b.sample(n, e)));
    assert!(pts.iter().any(|&(n, e)| a.sample(n, e) != c.sample(n, e)));
    let values: Vec<f32> = pts.iter().map(|&(n, e)| a.sample(n, e)).collect();
    let spread = values.iter().cloned().fold(f32::MIN, f32::max)
        - values.iter().cloned().fold(f32::MAX, f32::min);
    assert!(spread > 0.2, "{spread}");
}

#[test]
fn every_pixel_off_the_patches_shows_the_ground_under_its_ray_or_the_sky() {
    // A camera pitched up so the top rows see the sky, over a textured ground with one raised
    // patch, its bounds cutting rows in two: each pixel is checked against the ground point
    // of its own ray (`pixel_to_plane`, the camera's geometry, not the renderer's), whether
    // the texture is sampled one point at a time or many at once.
    let camera = PinholeCamera::from_fov(160, 120, 70f64.to_radians()).unwrap();
    let pose = CameraPose::downward(Vector3::new(0.3, -0.2, -5.0), 0.1, 1.2, 0.4);
    let ground = |n: f64, e: f64| (0.5 + 0.4 * (3.1 * n).sin() * (1.7 * e).cos()) as f32;
    let centre = camera.pixel_to_plane(&pose, 80.0, 90.0, -0.5).unwrap();
    let patch = Patch::square(centre.x, centre.y, 0.2, 0.8, Texture::uniform(0.0)).at_down_m(-0.5);
    for background in [
        Texture::from_fn(ground),
        Texture::from_fns(ground, move |points, out| {
            for (&[n, e], value) in points.iter().zip(out) {
                *value = ground(n, e);
            }
        }),
    ] {
        let scene = Scene::new(background).with_patch(patch.clone());
        let image = render(&camera, &pose, &scene, &exact()).unwrap();
        let (mut sky, mut ground_px, mut patch_px) = (0, 0, 0);
        for v in 0..120 {
            for u in 0..160 {
                let got = image.get(u, v) as f32;
                let point = camera.pixel_to_plane(&pose, u as f64, v as f64, 0.0);
                let on_patch = camera
                    .pixel_to_plane(&pose, u as f64, v as f64, -0.5)
                    .is_some_and(|p| {
                        let (dn, de) = (p.x - centre.x, p.y - centre.y);
                        let (c, s) = (0.2f64.cos(), 0.2f64.sin());
                        (dn * c + de * s).abs() < 0.4 && (-dn * s + de * c).abs() < 0.4
                    });
                let expected = match point {
                    _ if on_patch => {
                        patch_px += 1;
                        0.0
                    }
                    Some(p) => {
                        ground_px += 1;
                        ground(p.x, p.y) * 255.0
                    }
                    None => {
                        sky += 1;
                        scene.sky * 255.0
                    }
                };
                assert!(
                    (got - expected).abs() <= 1.0,
                    "({u}, {v}): {got} vs {expected}"
                );
            }
        }
        assert!(
            sky > 1000 && ground_px > 1000 && patch_px > 50,
            "{sky} {ground_px} {patch_px}"
        );
    }
}
