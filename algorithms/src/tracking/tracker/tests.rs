use super::*;
use crate::vision::rgb::RgbImage;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const DT_S: f64 = 1.0 / 30.0;

/// A box of `size` px centred at (x, y), drawn in `colour` on a noisy gray frame; returns
/// the detections (box + histogram of the frame inside the box) for the given targets.
fn frame_detections(
    targets: &[((f64, f64), [u8; 3])],
    size: f64,
    rng: &mut StdRng,
) -> Vec<BoxDetection> {
    let mut image = RgbImage::filled(320, 240, [0, 0, 0]).unwrap();
    for y in 0..240 {
        for x in 0..320 {
            let g = rng.random_range(90..130);
            image.set(x, y, [g, g, g]);
        }
    }
    let boxes: Vec<PixelBox> = targets
        .iter()
        .map(|&((x, y), _)| PixelBox::from_centre(x, y, size, size))
        .collect();
    for (b, &(_, colour)) in boxes.iter().zip(targets) {
        for y in 0..240usize {
            for x in 0..320usize {
                let (xf, yf) = (x as f64, y as f64);
                if xf >= b.x_min && xf < b.x_max && yf >= b.y_min && yf < b.y_max {
                    image.set(x, y, colour);
                }
            }
        }
    }
    boxes
        .iter()
        .map(|b| BoxDetection {
            bbox: *b,
            histogram: ColourHistogram::of_rgb_box(&image, b).unwrap(),
        })
        .collect()
}

/// Two targets crossing head-on; asserts that each keeps its track id throughout.
fn crossing(colours: [[u8; 3]; 2], vertical_offset_px: f64) {
    let mut rng = StdRng::seed_from_u64(5);
    let mut tracker = MultiTracker::new(TrackerConfig::default()).unwrap();
    // A moves right at 4 px/frame, B left; they pass each other around frame 25.
    let position = |k: usize| {
        let a = (60.0 + 4.0 * k as f64, 120.0);
        let b = (262.0 - 4.0 * k as f64, 120.0 + vertical_offset_px);
        (a, b)
    };
    let mut ids: Option<(TrackId, TrackId)> = None;
    for k in 0..50 {
        let (a, b) = position(k);
        let detections = frame_detections(&[(a, colours[0]), (b, colours[1])], 24.0, &mut rng);
        let owners = tracker.step(DT_S, &detections).unwrap();
        let now = (owners[0], owners[1]);
        match ids {
            None => ids = Some(now),
            Some(first) => assert_eq!(now, first, "identities swapped at frame {k}"),
        }
        // Both tracks follow their own target closely.
        for (id, truth) in [(now.0, a), (now.1, b)] {
            assert_eq!(tracker.track(id).unwrap().is_confirmed(), k >= 2);
            let (x, y) = tracker.track(id).unwrap().centre_px();
            assert!((x - truth.0).hypot(y - truth.1) < 3.0, "frame {k}");
        }
    }
    let (a_id, b_id) = ids.unwrap();
    assert_ne!(a_id, b_id);
    assert_eq!(tracker.confirmed().count(), 2);
}

#[test]
fn crossing_targets_of_different_colours_keep_their_identities() {
    crossing([[220, 30, 30], [30, 30, 220]], 0.0);
}

#[test]
fn crossing_look_alikes_keep_their_identities_by_the_prediction() {
    // Same colour: only the Kalman prediction of each box tells them apart.
    crossing([[220, 30, 30], [220, 30, 30]], 6.0);
}

#[test]
fn a_one_frame_false_alarm_never_becomes_confirmed() {
    let mut rng = StdRng::seed_from_u64(6);
    let config = TrackerConfig::default();
    let mut tracker = MultiTracker::new(config).unwrap();
    let red = [220, 30, 30];
    // Frame 40, the last, has no false alarm: frame 39's is deleted there.
    for k in 0..41 {
        let target = (100.0 + 2.0 * k as f64, 100.0);
        let mut targets = vec![(target, red)];
        // A look-alike false alarm in every other frame, each time somewhere else.
        if k % 2 == 1 {
            let alarm = (
                rng.random_range(20.0..300.0),
                rng.random_range(160.0..220.0),
            );
            targets.push((alarm, red));
        }
        let detections = frame_detections(&targets, 20.0, &mut rng);
        let owners = tracker.step(DT_S, &detections).unwrap();
        if k % 2 == 1 {
            let alarm_track = tracker.track(owners[1]).unwrap();
            assert_eq!(alarm_track.status(), TrackStatus::Tentative);
        }
        let confirmed: Vec<TrackId> = tracker.confirmed().map(|t| t.id()).collect();
        assert!(confirmed.len() <= 1, "frame {k}: {confirmed:?}");
        if k >= config.confirm_hits as usize - 1 {
            assert_eq!(confirmed.len(), 1);
            let (x, y) = tracker.track(confirmed[0]).unwrap().centre_px();
            assert!((x - target.0).hypot(y - target.1) < 2.0);
        } else {
            assert!(
                confirmed.is_empty(),
                "confirmed before {} hits",
                config.confirm_hits
            );
        }
    }
    // Only the target's track is left: every false alarm was deleted at its first miss.
    assert_eq!(tracker.tracks().len(), 1);
}

#[test]
fn a_missed_detection_is_bridged_by_the_prediction() {
    let mut rng = StdRng::seed_from_u64(7);
    let mut tracker = MultiTracker::new(TrackerConfig::default()).unwrap();
    // 9 px/frame with a 24 px box: three frames without the prediction's motion would leave
    // the target 27 px from the held box, with no overlap at all.
    let truth = |k: usize| (40.0 + 9.0 * k as f64, 60.0 + 3.0 * k as f64);
    let green = [30, 200, 30];
    let mut id = None;
    for k in 0..24 {
        let missed = (12..15).contains(&k);
        let targets = if missed {
            vec![]
        } else {
            vec![(truth(k), green)]
        };
        let detections = frame_detections(&targets, 24.0, &mut rng);
        let owners = tracker.step(DT_S, &detections).unwrap();
        if k == 10 {
            id = Some(owners[0]);
            assert!(tracker.track(owners[0]).unwrap().is_confirmed());
            // The filter learnt the velocity: 270 px/s, 90 px/s.
            let (vx, vy) = tracker.track(owners[0]).unwrap().velocity_px_s();
            assert!(
                (vx - 270.0).abs() < 15.0 && (vy - 90.0).abs() < 15.0,
                "{vx} {vy}"
            );
        }
        if let Some(id) = id {
            let track = tracker.track(id).expect("the track survives the gap");
            let (x, y) = track.centre_px();
            let (tx, ty) = truth(k);
            assert!(
                (x - tx).hypot(y - ty) < 2.0,
                "frame {k}: {x},{y} vs {tx},{ty}"
            );
            assert_eq!(track.misses(), if missed { k as u32 - 11 } else { 0 });
            if !missed {
                assert_eq!(owners, vec![id], "frame {k}: the same track after the gap");
            }
        }
    }
    assert_eq!(tracker.tracks().len(), 1);
}

#[test]
fn a_confirmed_track_is_deleted_after_max_misses() {
    let mut rng = StdRng::seed_from_u64(8);
    let config = TrackerConfig {
        max_misses: 3,
        ..TrackerConfig::default()
    };
    let mut tracker = MultiTracker::new(config).unwrap();
    for _ in 0..5 {
        let detections = frame_detections(&[((100.0, 100.0), [200, 200, 0])], 20.0, &mut rng);
        tracker.step(DT_S, &detections).unwrap();
    }
    assert_eq!(tracker.confirmed().count(), 1);
    tracker.step(DT_S, &[]).unwrap();
    tracker.step(DT_S, &[]).unwrap();
    assert_eq!(tracker.tracks().len(), 1, "two misses are bridged");
    tracker.step(DT_S, &[]).unwrap();
    assert!(tracker.tracks().is_empty(), "the third miss deletes it");
}

#[test]
fn the_target_stays_locked_until_its_track_dies() {
    let mut rng = StdRng::seed_from_u64(9);
    let mut tracker = MultiTracker::new(TrackerConfig::default()).unwrap();
    let centre = TargetPolicy::NearestTo {
        u_px: 160.0,
        v_px: 120.0,
    };
    assert!(tracker.select_target(centre).is_none());
    let (red, blue) = ([220, 30, 30], [30, 30, 220]);
    // Red (31.6 px from the centre) is nearer when both are confirmed; blue passes within
    // 4 px of the centre from frame 23 on, but the lock holds.
    let mut locked = None;
    for k in 0..30 {
        let detections = frame_detections(
            &[
                ((150.0, 150.0), red),
                ((40.0 + 4.0 * k as f64, 118.0), blue),
            ],
            20.0,
            &mut rng,
        );
        let owners = tracker.step(DT_S, &detections).unwrap();
        let target = tracker.select_target(centre).map(|t| t.id());
        if k >= 2 {
            assert_eq!(target, Some(owners[0]), "frame {k}: red stays the target");
            locked = target;
        }
    }
    // Red disappears for good: after its track dies, blue is chosen.
    for k in 30..40 {
        let detections =
            frame_detections(&[((40.0 + 4.0 * k as f64, 118.0), blue)], 20.0, &mut rng);
        let owners = tracker.step(DT_S, &detections).unwrap();
        let target = tracker.select_target(centre).map(|t| t.id());
        if tracker.track(locked.unwrap()).is_some() {
            assert_eq!(target, locked);
        } else {
            assert_eq!(target, Some(owners[0]));
        }
    }
    assert_ne!(tracker.target().map(|t| t.id()), locked);
    tracker.release_target();
    assert!(tracker.target().is_none());
    assert_eq!(
        tracker
            .select_target(TargetPolicy::MostHits)
            .map(|t| t.hits()),
        Some(40)
    );
}

#[test]
fn bad_settings_and_inputs_are_named_errors() {
    let bad = TrackerConfig {
        a1_distance: 0.7,
        ..TrackerConfig::default()
    };
    assert!(matches!(
        MultiTracker::new(bad),
        Err(TrackingError::Config {
            name: "a1_distance + a2_colour",
            ..
        })
    ));
    let bad = TrackerConfig {
        confirm_hits: 0,
        ..TrackerConfig::default()
    };
    assert!(MultiTracker::new(bad).is_err());
    let mut tracker = MultiTracker::new(TrackerConfig::default()).unwrap();
    assert!(matches!(
        tracker.step(0.0, &[]),
        Err(TrackingError::FrameInterval { .. })
    ));
    let image = RgbImage::filled(10, 10, [1, 2, 3]).unwrap();
    let good = PixelBox::from_centre(5.0, 5.0, 4.0, 4.0);
    let histogram = ColourHistogram::of_rgb_box(&image, &good).unwrap();
    let flat = BoxDetection {
        bbox: PixelBox::from_centre(5.0, 5.0, 4.0, 0.0),
        histogram: histogram.clone(),
    };
    assert!(matches!(
        tracker.step(DT_S, &[flat]),
        Err(TrackingError::Detection { index: 0 })
    ));
    tracker
        .step(
            DT_S,
            &[BoxDetection {
                bbox: good,
                histogram,
            }],
        )
        .unwrap();
    let gray = ColourHistogram::of_gray_box(&image.to_gray().view(), &good).unwrap();
    let err = tracker.step(
        DT_S,
        &[BoxDetection {
            bbox: good,
            histogram: gray,
        }],
    );
    assert!(matches!(
        err,
        Err(TrackingError::Histogram { index: 0, .. })
    ));
    // A failed step changed nothing: the track was not aged or predicted.
    assert_eq!(tracker.tracks()[0].age_frames(), 0);
}
