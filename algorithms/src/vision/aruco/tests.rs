//! Detector tests against known truth: markers drawn cell by cell, and markers rendered under
//! random camera poses by [`crate::vision::render`].

use super::*;
use crate::camera::{CameraPose, PinholeCamera};
use crate::vision::image::GrayImage;
use crate::vision::render::{
    render, ImageEffects, MotionBlur, Patch, RenderOptions, Scene, SplitMix64, Texture,
};
use nalgebra::Vector3;

fn detector(dictionary: Dictionary) -> ArucoDetector {
    ArucoDetector::new(dictionary, ArucoConfig::default()).unwrap()
}

/// Cells of the upright marker with its border, `true` = black, turned `quarter_turns`
/// clockwise on screen.
fn turned_cells(dict: &Dictionary, id: usize, quarter_turns: usize) -> Vec<Vec<bool>> {
    let n = dict.marker_size_bits();
    let side = n + 2;
    let bits = dict.marker_bits(id).unwrap();
    let mut cells = vec![vec![true; side]; side];
    for row in 0..n {
        for col in 0..n {
            cells[row + 1][col + 1] = !bits[row * n + col];
        }
    }
    for _ in 0..quarter_turns {
        // Clockwise: the left column, read bottom-up, becomes the top row.
        cells = (0..side)
            .map(|r| (0..side).map(|c| cells[side - 1 - c][r]).collect())
            .collect();
    }
    cells
}

/// Draws cells of `cell_px` pixels with their top-left pixel at (x0, y0); black 30, white 220.
fn draw_cells(image: &mut GrayImage, cells: &[Vec<bool>], x0: usize, y0: usize, cell_px: usize) {
    for (r, row) in cells.iter().enumerate() {
        for (c, &black) in row.iter().enumerate() {
            for y in 0..cell_px {
                for x in 0..cell_px {
                    let value = if black { 30 } else { 220 };
                    image.set(x0 + c * cell_px + x, y0 + r * cell_px + y, value);
                }
            }
        }
    }
}

fn distance(a: (f64, f64), b: (f64, f64)) -> f64 {
    ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()
}

#[test]
fn drawn_markers_are_read_in_every_rotation_with_opencv_corner_order() {
    for dict in [Dictionary::dict_4x4_50(), Dictionary::aruco_original()] {
        let side = dict.marker_size_bits() + 2;
        let cell_px = 9;
        let mut detector = detector(dict.clone());
        for (id, quarter_turns) in [(0, 0), (7, 1), (23, 2), (49, 3)] {
            let mut image = GrayImage::filled(160, 120, 220).unwrap();
            let (x0, y0) = (37, 21);
            draw_cells(
                &mut image,
                &turned_cells(&dict, id, quarter_turns),
                x0,
                y0,
                cell_px,
            );
            let markers = detector.detect(&image.view()).unwrap();
            assert_eq!(markers.len(), 1, "{} id {id}", dict.name());
            let marker = &markers[0];
            assert_eq!(marker.id, id);
            assert_eq!(marker.hamming_distance, 0);
            assert_eq!(usize::from(marker.rotation_quarter_turns), quarter_turns);
            // Pixel edges lie half a pixel outside the outermost pixel centres.
            let (l, t) = (x0 as f64 - 0.5, y0 as f64 - 0.5);
            let (r, b) = (l + (side * cell_px) as f64, t + (side * cell_px) as f64);
            let screen = [(l, t), (r, t), (r, b), (l, b)];
            // The marker's top-left is turned onto screen corner `quarter_turns`.
            for (j, &corner) in marker.corners_px.iter().enumerate() {
                let truth = screen[(j + quarter_turns) % 4];
                assert!(
                    distance(corner, truth) < 0.1,
                    "{} id {id} corner {j}: {corner:?} vs {truth:?}",
                    dict.name()
                );
            }
        }
    }
}

#[test]
fn one_flipped_bit_is_corrected_and_more_are_rejected() {
    let dict = Dictionary::dict_4x4_50();
    let mut detector = detector(dict.clone());
    let id = 12;
    let code = dict.code(id).unwrap();
    let draw = |code: u64| {
        let mut cells = vec![vec![true; 6]; 6];
        for row in 0..4 {
            for col in 0..4 {
                cells[row + 1][col + 1] = (code >> (row * 4 + col)) & 1 == 1;
            }
        }
        let mut image = GrayImage::filled(100, 100, 220).unwrap();
        draw_cells(&mut image, &cells, 20, 20, 10);
        image
    };
    for bit in 0..16 {
        let markers = detector.detect(&draw(code ^ (1 << bit)).view()).unwrap();
        assert_eq!(markers.len(), 1, "bit {bit}");
        assert_eq!((markers[0].id, markers[0].hamming_distance), (id, 1));
    }
    // Two or three flipped bits that leave the code more than one bit from every code (in any
    // rotation) must not be read at all.
    let mut rejected = 0;
    for a in 0..16 {
        for b in a + 1..16 {
            for c in [None].into_iter().chain((b + 1..16).map(Some)) {
                let damaged = code ^ (1 << a) ^ (1 << b) ^ c.map_or(0, |c| 1 << c);
                if dict.identify(damaged, 1).is_none() {
                    assert!(detector.detect(&draw(damaged).view()).unwrap().is_empty());
                    rejected += 1;
                }
            }
        }
    }
    assert!(rejected > 50, "{rejected}");
}

#[test]
fn bad_frames_settings_and_regions_are_named_errors() {
    let mut detector = detector(Dictionary::dict_4x4_50());
    assert!(matches!(
        detector.detect_buffer(0, 480, 640, &[]),
        Err(ArucoError::Frame(FrameError::Empty { .. }))
    ));
    assert!(matches!(
        detector.detect_buffer(640, 480, 600, &vec![0; 640 * 480]),
        Err(ArucoError::Frame(FrameError::StrideTooShort { .. }))
    ));
    assert!(matches!(
        detector.detect_buffer(640, 480, 640, &vec![0; 1000]),
        Err(ArucoError::Frame(FrameError::BufferTooShort { .. }))
    ));
    let image = GrayImage::filled(64, 48, 128).unwrap();
    let roi = PixelRect {
        x: 64,
        y: 0,
        width: 10,
        height: 10,
    };
    assert!(matches!(
        detector.detect_in_roi(&image.view(), roi),
        Err(ArucoError::RoiOutsideFrame { .. })
    ));
    // Tiny and uniform frames are valid and hold nothing.
    assert!(detector.detect_buffer(1, 1, 1, &[0]).unwrap().is_empty());
    assert!(detector.detect(&image.view()).unwrap().is_empty());
    for config in [
        ArucoConfig {
            threshold_windows_px: vec![],
            ..ArucoConfig::default()
        },
        ArucoConfig {
            threshold_windows_px: vec![16],
            ..ArucoConfig::default()
        },
        ArucoConfig {
            min_perimeter_px: f32::NAN,
            ..ArucoConfig::default()
        },
        ArucoConfig {
            max_correction_bits: Some(2),
            ..ArucoConfig::default()
        },
    ] {
        assert!(matches!(
            ArucoDetector::new(Dictionary::dict_4x4_50(), config),
            Err(ArucoError::Config { .. })
        ));
    }
}

#[test]
fn a_padded_buffer_is_read_through_its_stride() {
    let dict = Dictionary::dict_4x4_50();
    let mut image = GrayImage::filled(120, 90, 220).unwrap();
    draw_cells(&mut image, &turned_cells(&dict, 3, 0), 30, 20, 8);
    let stride = 128;
    let mut padded = vec![0u8; stride * 90];
    for y in 0..90 {
        padded[y * stride..y * stride + 120].copy_from_slice(&image.data()[y * 120..(y + 1) * 120]);
    }
    let mut detector = detector(dict);
    let direct = detector.detect(&image.view()).unwrap();
    let strided = detector.detect_buffer(120, 90, stride, &padded).unwrap();
    assert_eq!(direct, strided);
    assert_eq!(direct.len(), 1);
}

#[test]
fn roi_mode_finds_the_same_corners_in_frame_pixels() {
    let dict = Dictionary::dict_4x4_50();
    let mut image = GrayImage::filled(200, 150, 220).unwrap();
    draw_cells(&mut image, &turned_cells(&dict, 5, 1), 120, 70, 7);
    draw_cells(&mut image, &turned_cells(&dict, 9, 0), 10, 10, 7);
    let mut detector = detector(dict);
    let full = detector.detect(&image.view()).unwrap();
    assert_eq!(full.len(), 2);
    let roi = PixelRect {
        x: 100,
        y: 50,
        width: 90,
        height: 90,
    };
    let in_roi = detector.detect_in_roi(&image.view(), roi).unwrap();
    assert_eq!(in_roi.len(), 1);
    let same = full.iter().find(|m| m.id == 5).unwrap();
    for (a, b) in in_roi[0].corners_px.iter().zip(same.corners_px) {
        assert!(distance(*a, b) < 1e-3);
    }
    // A region of interest past the frame's edge is clipped, not refused.
    let roi = PixelRect {
        x: 100,
        y: 50,
        width: 500,
        height: 500,
    };
    assert_eq!(detector.detect_in_roi(&image.view(), roi).unwrap().len(), 1);
}

// ---- Rendered frames -------------------------------------------------------------------

/// One marker placed in a rendered scene, with where its corners truly are.
struct Truth {
    id: usize,
    corners_px: [(f64, f64); 4],
}

impl Truth {
    fn shortest_side_px(&self) -> f64 {
        (0..4)
            .map(|i| distance(self.corners_px[i], self.corners_px[(i + 1) % 4]))
            .fold(f64::MAX, f64::min)
    }

    fn centre_px(&self) -> (f64, f64) {
        let (mut u, mut v) = (0.0, 0.0);
        for (cu, cv) in self.corners_px {
            u += cu / 4.0;
            v += cv / 4.0;
        }
        (u, v)
    }
}

fn uniform(rng: &mut SplitMix64, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.next_f64()
}

fn camera() -> PinholeCamera {
    PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap()
}

/// A random downward pose: altitude log-uniform in 1–20 m, tilt up to 25°, any yaw.
fn random_pose(rng: &mut SplitMix64) -> CameraPose {
    let altitude_m = (uniform(rng, 0.0, 20f64.ln())).exp();
    let tilt_rad = uniform(rng, 0.0, 25f64.to_radians());
    let tilt_dir_rad = uniform(rng, 0.0, std::f64::consts::TAU);
    let yaw_rad = uniform(rng, -std::f64::consts::PI, std::f64::consts::PI);
    CameraPose::downward(
        Vector3::new(
            uniform(rng, -50.0, 50.0),
            uniform(rng, -50.0, 50.0),
            -altitude_m,
        ),
        tilt_rad * tilt_dir_rad.cos(),
        tilt_rad * tilt_dir_rad.sin(),
        yaw_rad,
    )
}

/// Focus blur, motion blur in one frame of three, contrast, brightness and sensor noise.
fn random_effects(rng: &mut SplitMix64, seed: u64) -> ImageEffects {
    let motion = rng.next_f64() < 1.0 / 3.0;
    let motion_blur = MotionBlur {
        length_px: uniform(rng, 0.5, 3.0),
        angle_rad: uniform(rng, 0.0, std::f64::consts::PI),
    };
    ImageEffects {
        gaussian_blur_sigma_px: uniform(rng, 0.0, 1.2),
        motion_blur: motion.then_some(motion_blur),
        contrast: uniform(rng, 0.6, 1.0),
        brightness: uniform(rng, -0.1, 0.1),
        noise_sigma: uniform(rng, 0.0, 6.0),
        noise_seed: seed,
    }
}

/// A field with up to `count` markers of `dict` (distinct random ids, 0.2–0.5 m, one cell of
/// white quiet zone each) placed wholly inside the view; their truth.
fn random_marker_scene(
    rng: &mut SplitMix64,
    seed: u64,
    dict: &Dictionary,
    camera: &PinholeCamera,
    pose: &CameraPose,
    count: usize,
) -> (Scene, Vec<Truth>) {
    let mut scene = Scene::new(Texture::field(seed));
    let mut truths: Vec<Truth> = Vec::new();
    let mut placed: Vec<((f64, f64), f64)> = Vec::new();
    let cells = (dict.marker_size_bits() + 2) as f64;
    'markers: for _ in 0..count {
        let size_m = uniform(rng, 0.2, 0.5);
        let quiet_m = size_m * (cells + 2.0) / cells;
        let yaw_rad = uniform(rng, -std::f64::consts::PI, std::f64::consts::PI);
        // A symmetric marker's corner order cannot be known (see is_rotation_symmetric).
        let id = loop {
            let id = (rng.next_u64() % dict.len() as u64) as usize;
            let symmetric = dict.is_rotation_symmetric(id) == Some(true);
            if !symmetric && truths.iter().all(|t| t.id != id) {
                break id;
            }
        };
        for _ in 0..20 {
            let (u, v) = (uniform(rng, 20.0, 620.0), uniform(rng, 20.0, 460.0));
            let Some(ground) = camera.pixel_to_plane(pose, u, v, 0.0) else {
                continue;
            };
            let quiet = Patch::square(ground.x, ground.y, yaw_rad, quiet_m, Texture::uniform(1.0));
            let fits = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                .iter()
                .all(|&(a, b)| {
                    camera
                        .project_world(pose, &quiet.point_world(a, b))
                        .is_some_and(|(x, y)| x > 3.0 && y > 3.0 && x < 636.0 && y < 476.0)
                });
            let apart = placed.iter().all(|&((n, e), r)| {
                ((n - ground.x).powi(2) + (e - ground.y).powi(2)).sqrt() > r + quiet_m
            });
            if !fits || !apart {
                continue;
            }
            let bits = dict.marker_bits(id).unwrap();
            let texture = Texture::aruco(&bits, dict.marker_size_bits()).unwrap();
            let marker = Patch::square(ground.x, ground.y, yaw_rad, size_m, texture);
            let corners_px = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(a, b)| {
                camera
                    .project_world(pose, &marker.point_world(a, b))
                    .unwrap_or((f64::NAN, f64::NAN))
            });
            placed.push(((ground.x, ground.y), quiet_m));
            truths.push(Truth { id, corners_px });
            scene = scene.with_patch(quiet).with_patch(marker);
            continue 'markers;
        }
    }
    (scene, truths)
}

#[derive(Debug, Default)]
struct Tally {
    frames: usize,
    markers: usize,
    big_markers: usize,
    big_found: usize,
    small_markers: usize,
    small_found: usize,
    wrong_ids: usize,
    missed_big: Vec<String>,
    corner_errors_px: Vec<f64>,
}

impl Tally {
    fn median_and_p95(&self) -> (f64, f64, f64) {
        let mut e = self.corner_errors_px.clone();
        e.sort_by(f64::total_cmp);
        if e.is_empty() {
            return (f64::NAN, f64::NAN, f64::NAN);
        }
        (
            e[e.len() / 2],
            e[(e.len() * 95 / 100).min(e.len() - 1)],
            e[e.len() - 1],
        )
    }
}

/// Renders `frames` random frames with up to three markers and scores the detector.
fn score_rendered_frames(dict: &Dictionary, frames: usize, seed: u64) -> Tally {
    score_with(dict, frames, seed, ArucoConfig::default(), 3)
}

fn score_with(
    dict: &Dictionary,
    frames: usize,
    seed: u64,
    config: ArucoConfig,
    supersampling: usize,
) -> Tally {
    let camera = camera();
    let mut detector = ArucoDetector::new(dict.clone(), config).unwrap();
    let mut rng = SplitMix64::new(seed);
    let mut tally = Tally::default();
    for frame in 0..frames {
        let frame_seed = seed.wrapping_mul(1000).wrapping_add(frame as u64);
        let pose = random_pose(&mut rng);
        let (scene, truths) = random_marker_scene(&mut rng, frame_seed, dict, &camera, &pose, 3);
        let options = RenderOptions {
            supersampling,
            effects: random_effects(&mut rng, frame_seed),
        };
        let image = render(&camera, &pose, &scene, &options).unwrap();
        let found = detector.detect(&image.view()).unwrap();
        tally.frames += 1;
        tally.markers += truths.len();
        for marker in &found {
            let matching = truths.iter().find(|t| {
                let side = t.shortest_side_px();
                distance(t.centre_px(), marker.centre_px()) < 0.5 * side.max(2.0)
            });
            if matching.is_none_or(|t| t.id != marker.id) {
                tally.wrong_ids += 1;
            }
        }
        for truth in &truths {
            let hit = found.iter().find(|m| {
                m.id == truth.id
                    && distance(m.centre_px(), truth.centre_px()) < 0.5 * truth.shortest_side_px()
            });
            if truth.shortest_side_px() >= 30.0 {
                tally.big_markers += 1;
                match hit {
                    Some(m) => {
                        tally.big_found += 1;
                        for (c, t) in m.corners_px.iter().zip(truth.corners_px) {
                            tally.corner_errors_px.push(distance(*c, t));
                        }
                    }
                    None => tally.missed_big.push(format!(
                        "frame {frame}: id {} side {:.1} px, {:?}",
                        truth.id,
                        truth.shortest_side_px(),
                        options.effects
                    )),
                }
            } else {
                tally.small_markers += 1;
                tally.small_found += usize::from(hit.is_some());
            }
        }
    }
    tally
}

fn check_rendered(dict: &Dictionary, frames: usize, seed: u64) {
    let tally = score_rendered_frames(dict, frames, seed);
    let (median, p95, max) = tally.median_and_p95();
    eprintln!(
        "{}: {} frames, {} markers; ≥30 px: {}/{} found, corner error median {median:.3} px, \
         p95 {p95:.3} px, max {max:.3} px; <30 px: {}/{} found; wrong ids {}",
        dict.name(),
        tally.frames,
        tally.markers,
        tally.big_found,
        tally.big_markers,
        tally.small_found,
        tally.small_markers,
        tally.wrong_ids
    );
    assert_eq!(tally.wrong_ids, 0);
    assert!(tally.big_markers >= frames / 2, "{tally:?}");
    assert!(tally.missed_big.is_empty(), "{:#?}", tally.missed_big);
    assert!(median < 0.5 && p95 < 1.0, "{median} {p95}");
}

#[test]
fn rendered_dict_4x4_50_markers_are_read_under_random_poses() {
    check_rendered(&Dictionary::dict_4x4_50(), 80, 11);
}

#[test]
fn rendered_aruco_original_markers_are_read_under_random_poses() {
    check_rendered(&Dictionary::aruco_original(), 40, 12);
}

/// The larger run: `cargo test -p algorithms --release aruco -- --ignored`.
#[test]
#[ignore = "about a minute in release; the default suite runs a smaller sample"]
fn rendered_markers_many_poses() {
    check_rendered(&Dictionary::dict_4x4_50(), 600, 21);
    check_rendered(&Dictionary::aruco_original(), 300, 22);
}

/// Marker-like decoys: black-bordered squares whose bits are more than the correction limit
/// away from every code, plus plain dark squares, on a field.
fn decoy_scene(
    rng: &mut SplitMix64,
    seed: u64,
    dict: &Dictionary,
    camera: &PinholeCamera,
    pose: &CameraPose,
) -> Scene {
    let mut scene = Scene::new(Texture::field(seed));
    let n = dict.marker_size_bits();
    let mut placed: Vec<(f64, f64, f64)> = Vec::new();
    for _ in 0..3 {
        let (u, v) = (uniform(rng, 60.0, 580.0), uniform(rng, 60.0, 420.0));
        let Some(ground) = camera.pixel_to_plane(pose, u, v, 0.0) else {
            continue;
        };
        let size_m = uniform(rng, 0.2, 0.5);
        // Apart, so that no decoy covers part of another and leaves a real code showing.
        let reach_m = size_m * 1.4 / std::f64::consts::SQRT_2;
        if placed.iter().any(|&(n, e, r)| {
            ((n - ground.x).powi(2) + (e - ground.y).powi(2)).sqrt() < r + reach_m
        }) {
            continue;
        }
        placed.push((ground.x, ground.y, reach_m));
        let yaw_rad = uniform(rng, -3.2, 3.2);
        let code = loop {
            let code = rng.next_u64() & ((1 << (n * n)) - 1);
            if dict
                .identify(code, dict.max_correction_bits() + 1)
                .is_none()
            {
                break code;
            }
        };
        let bits: Vec<bool> = (0..n * n).map(|i| (code >> i) & 1 == 0).collect();
        let texture = if rng.next_f64() < 0.7 {
            Texture::aruco(&bits, n).unwrap()
        } else {
            Texture::uniform(0.05)
        };
        let quiet = size_m * 1.4;
        scene = scene
            .with_patch(Patch::square(
                ground.x,
                ground.y,
                yaw_rad,
                quiet,
                Texture::uniform(1.0),
            ))
            .with_patch(Patch::square(ground.x, ground.y, yaw_rad, size_m, texture));
    }
    scene
}

fn count_false_ids(frames: usize, seed: u64) -> (usize, usize) {
    let camera = camera();
    let dicts = [Dictionary::dict_4x4_50(), Dictionary::aruco_original()];
    let mut detectors: Vec<ArucoDetector> = dicts.iter().map(|d| detector(d.clone())).collect();
    let mut rng = SplitMix64::new(seed);
    let mut false_ids = 0;
    for frame in 0..frames {
        let frame_seed = seed.wrapping_mul(7919).wrapping_add(frame as u64);
        let pose = random_pose(&mut rng);
        let dict = &dicts[frame % 2];
        let scene = if frame % 3 == 0 {
            Scene::new(Texture::field(frame_seed))
        } else {
            decoy_scene(&mut rng, frame_seed, dict, &camera, &pose)
        };
        let options = RenderOptions {
            supersampling: 1,
            effects: random_effects(&mut rng, frame_seed),
        };
        let image = render(&camera, &pose, &scene, &options).unwrap();
        for detector in &mut detectors {
            let found = detector.detect(&image.view()).unwrap();
            if !found.is_empty() {
                eprintln!("frame {frame}: false ids {found:?}");
            }
            false_ids += found.len();
        }
    }
    (frames, false_ids)
}

#[test]
fn markerless_and_decoy_frames_give_no_ids() {
    let (frames, false_ids) = count_false_ids(300, 5);
    eprintln!("{frames} markerless/decoy frames × 2 dictionaries: {false_ids} false ids");
    assert_eq!(false_ids, 0);
}

/// The 1,000 frames: `cargo test -p algorithms --release aruco -- --ignored`.
#[test]
#[ignore = "about a minute in release; the default suite runs 300 frames"]
fn markerless_and_decoy_frames_thousand() {
    let (frames, false_ids) = count_false_ids(1000, 6);
    eprintln!("{frames} markerless/decoy frames × 2 dictionaries: {false_ids} false ids");
    assert!(false_ids * 100 < frames, "{false_ids}");
}
