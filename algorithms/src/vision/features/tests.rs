use super::*;
use crate::camera::{CameraPose, PinholeCamera};
use crate::vision::image::GrayImage;
use crate::vision::render::{render, RenderOptions, Scene, Texture};
use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

/// Wraps an angle to (−π, π].
fn wrap_angle(a: f64) -> f64 {
    let mut a = a % (2.0 * PI);
    if a > PI {
        a -= 2.0 * PI;
    } else if a <= -PI {
        a += 2.0 * PI;
    }
    a
}

/// The segment test written out directly: some start k with 9 circle pixels in a row all
/// brighter than centre + t, or all darker than centre − t.
fn naive_is_corner(image: &GrayImage, x: usize, y: usize, t: i32) -> bool {
    let c = image.get(x, y) as i32;
    let v = |k: usize| {
        let (dx, dy) = CIRCLE[k % 16];
        image.get((x as i32 + dx) as usize, (y as i32 + dy) as usize) as i32
    };
    (0..16)
        .any(|start| (0..9).all(|i| v(start + i) > c + t) || (0..9).all(|i| v(start + i) < c - t))
}

#[test]
fn the_segment_test_matches_a_direct_implementation() {
    let mut rng = StdRng::seed_from_u64(1);
    // Blocky random images give many corners and near-corners.
    let (w, h) = (64, 48);
    let mut image = GrayImage::filled(w, h, 0).unwrap();
    for by in 0..h / 4 {
        for bx in 0..w / 4 {
            let level = rng.random_range(0..=255u8);
            for y in 0..4 {
                for x in 0..4 {
                    let noise = rng.random_range(0..=12u8);
                    image.set(bx * 4 + x, by * 4 + y, level.saturating_add(noise));
                }
            }
        }
    }
    let config = FastConfig {
        threshold: 25,
        nonmax_suppression: false,
        max_keypoints: usize::MAX,
        grid_cells: 1,
        border_px: 3,
    };
    let found: Vec<(usize, usize)> = detect_fast(&image.view(), &config)
        .iter()
        .map(|k| (k.x_px as usize, k.y_px as usize))
        .collect();
    let mut expected = Vec::new();
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            if naive_is_corner(&image, x, y, 25) {
                expected.push((x, y));
            }
        }
    }
    let mut found_sorted = found.clone();
    found_sorted.sort_by_key(|&(x, y)| (y, x));
    assert!(
        expected.len() > 50,
        "the image has corners: {}",
        expected.len()
    );
    assert_eq!(found_sorted, expected);
}

#[test]
fn fast_finds_the_corners_of_a_square_and_nothing_on_its_edges() {
    let mut image = GrayImage::filled(100, 100, 40).unwrap();
    for y in 30..70 {
        for x in 20..60 {
            image.set(x, y, 200);
        }
    }
    let config = FastConfig {
        border_px: 3,
        ..FastConfig::default()
    };
    let corners = detect_fast(&image.view(), &config);
    // The square's corners lie between pixels 19|20, 59|60 and 29|30, 69|70.
    let truth = [(19.5, 29.5), (59.5, 29.5), (19.5, 69.5), (59.5, 69.5)];
    let near = |k: &Keypoint, (x, y): (f64, f64)| (k.x_px - x).hypot(k.y_px - y) < 2.5;
    for k in &corners {
        assert!(truth.iter().any(|&t| near(k, t)), "spurious corner {k:?}");
    }
    for t in truth {
        let n = corners.iter().filter(|k| near(k, t)).count();
        assert!((1..=2).contains(&n), "corner {t:?} found {n} times");
    }
}

fn field_image(yaw_rad: f64, north_m: f64) -> GrayImage {
    let camera = PinholeCamera::from_fov(320, 240, 60f64.to_radians()).unwrap();
    let pose = CameraPose::downward(Vector3::new(north_m, 0.0, -6.0), 0.0, 0.0, yaw_rad);
    let scene = Scene::new(Texture::field(21));
    render(&camera, &pose, &scene, &RenderOptions::default()).unwrap()
}

/// The image moved by (dx, dy) whole pixels, edges clamped.
fn shifted(image: &GrayImage, dx: i32, dy: i32) -> GrayImage {
    let (w, h) = (image.width() as i32, image.height() as i32);
    let mut out = GrayImage::filled(w as usize, h as usize, 0).unwrap();
    for y in 0..h {
        for x in 0..w {
            let (sx, sy) = ((x - dx).clamp(0, w - 1), (y - dy).clamp(0, h - 1));
            out.set(x as usize, y as usize, image.get(sx as usize, sy as usize));
        }
    }
    out
}

#[test]
fn descriptors_are_unchanged_by_translation_and_match_the_shifted_frame() {
    let a = field_image(0.3, 0.0);
    let (dx, dy) = (7, -5);
    let b = shifted(&a, dx, dy);
    let matcher = FeatureMatcher::new(FeatureConfig::default());
    let (fa, fb) = (matcher.features(&a.view()), matcher.features(&b.view()));
    assert!(fa.keypoints.len() > 100, "{}", fa.keypoints.len());
    // Keypoints well inside both images appear shifted, with the very same descriptor.
    let mut same = 0;
    for (k, d) in fa.keypoints.iter().zip(&fa.descriptors) {
        let (x, y) = (k.x_px + dx as f64, k.y_px + dy as f64);
        if let Some(j) = fb.keypoints.iter().position(|q| q.x_px == x && q.y_px == y) {
            if (30.0..290.0).contains(&x) && (30.0..210.0).contains(&y) {
                assert_eq!(fb.descriptors[j].hamming(d), 0);
                same += 1;
            }
        }
    }
    assert!(same > 50, "{same}");
    let matches = matcher.correspondences(&fa, &fb);
    assert!(matches.len() > 50, "{}", matches.len());
    let right = matches
        .iter()
        .filter(|m| {
            m.current_px[0] - m.previous_px[0] == dx as f64
                && m.current_px[1] - m.previous_px[1] == dy as f64
        })
        .count();
    assert!(
        right as f64 >= 0.95 * matches.len() as f64,
        "{right} of {}",
        matches.len()
    );
}

#[test]
fn steered_descriptors_survive_a_quarter_turn() {
    let a = field_image(0.0, 0.0);
    // Rotate by 90°: pixel (x, y) of `a` goes to (h − 1 − y, x).
    let (w, h) = (a.width(), a.height());
    let mut b = GrayImage::filled(h, w, 0).unwrap();
    for y in 0..h {
        for x in 0..w {
            b.set(h - 1 - y, x, a.get(x, y));
        }
    }
    let steered = BriefExtractor::new(3, true);
    let plain = BriefExtractor::new(3, false);
    let config = FastConfig::default();
    let ka = detect_fast(&a.view(), &config);
    let kb = detect_fast(&b.view(), &config);
    let median_distance = |extractor: &BriefExtractor| {
        let da = extractor.describe(&a.view(), &ka);
        let db = extractor.describe(&b.view(), &kb);
        let mut distances = Vec::new();
        for (k, d) in &da {
            let (x, y) = ((h - 1) as f64 - k.y_px, k.x_px);
            if let Some((kq, dq)) = db.iter().find(|(q, _)| q.x_px == x && q.y_px == y) {
                let turned = wrap_angle(kq.angle_rad - k.angle_rad);
                if extractor.steered {
                    assert!((turned - PI / 2.0).abs() < 1e-6, "orientation turns too");
                }
                distances.push(d.hamming(dq));
            }
        }
        assert!(distances.len() > 30, "{}", distances.len());
        distances.sort_unstable();
        distances[distances.len() / 2]
    };
    let (with, without) = (median_distance(&steered), median_distance(&plain));
    // Unrelated descriptors differ in about half their bits.
    assert!(with < 16, "steered: median {with} of 256 bits");
    assert!(without > 90, "unsteered: median {without} of 256 bits");
}

#[test]
fn matching_agrees_with_the_definitions_of_the_ratio_test_and_the_cross_check() {
    let mut rng = StdRng::seed_from_u64(4);
    let random = |rng: &mut StdRng| Descriptor([rng.random(), rng.random(), 0, 0]);
    let train: Vec<Descriptor> = (0..40).map(|_| random(&mut rng)).collect();
    // Half the queries are noisy copies of train descriptors, half unrelated.
    let query: Vec<Descriptor> = (0..40)
        .map(|i| {
            if i % 2 == 0 {
                let mut d = train[(i * 7) % 40];
                for _ in 0..rng.random_range(0..30) {
                    d.0[rng.random_range(0..2)] ^= 1 << rng.random_range(0..64);
                }
                d
            } else {
                random(&mut rng)
            }
        })
        .collect();
    // Nearest by (distance, index), written out.
    let nearest = |d: &Descriptor, set: &[Descriptor]| {
        let mut all: Vec<(u32, usize)> = set
            .iter()
            .enumerate()
            .map(|(j, t)| (d.hamming(t), j))
            .collect();
        all.sort();
        all
    };
    for (ratio, cross_check, max_distance) in [
        (None, false, 256),
        (Some(0.8), false, 256),
        (None, true, 256),
        (Some(0.7), true, 40),
    ] {
        let config = MatchConfig {
            max_distance,
            ratio,
            cross_check,
        };
        let expected: Vec<DescriptorMatch> = (0..query.len())
            .filter_map(|i| {
                let all = nearest(&query[i], &train);
                let (best, j) = all[0];
                let ratio_ok = ratio.is_none_or(|r| (best as f64) < r * all[1].0 as f64);
                let cross_ok = !cross_check || nearest(&train[j], &query)[0].1 == i;
                (best <= max_distance && ratio_ok && cross_ok).then_some(DescriptorMatch {
                    query_index: i,
                    train_index: j,
                    distance: best,
                })
            })
            .collect();
        let found = match_descriptors(&query, &train, &config);
        assert_eq!(found, expected, "{config:?}");
        assert!(!found.is_empty());
    }
    assert!(match_descriptors(&query, &[], &MatchConfig::default()).is_empty());
}
