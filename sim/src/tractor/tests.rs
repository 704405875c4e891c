use super::*;
use std::f64::consts::FRAC_PI_2;

const DT: f64 = 0.01;

fn tractor(kind: PathKind) -> Tractor {
    Tractor::new(kind, TractorParams::default(), [0.0, 0.0], 0.0).unwrap()
}

fn drive(t: &mut Tractor, seconds: f64) -> Vec<TractorPose> {
    let steps = (seconds / DT).round() as usize;
    (0..steps)
        .map(|_| {
            t.step(DT).unwrap();
            t.pose()
        })
        .collect()
}

#[test]
fn the_rectangle_turns_where_first_turn_m_says() {
    // At its default speed the heading stays north until the first corner, then turns east.
    let mut t = tractor(PathKind::Rectangle);
    let corner_m = PathKind::Rectangle.first_turn_m().unwrap();
    let mut heading_at = Vec::new();
    for step in 0..(30.0 / 0.01) as usize {
        t.step(0.01).unwrap();
        heading_at.push((
            step as f64 * 0.01,
            t.pose().heading_rad,
            t.distance_driven_m(),
        ));
    }
    // Pure pursuit cuts the corner, starting its turn a few metres early.
    let before = heading_at.iter().filter(|(_, _, d)| *d < corner_m - 6.0);
    assert!(before.clone().count() > 100);
    let worst = before.clone().map(|(_, h, _)| h.abs()).fold(0.0, f64::max);
    assert!(worst < 0.05, "{worst}");
    let after = heading_at
        .iter()
        .find(|(_, _, d)| *d > corner_m + 8.0)
        .unwrap();
    assert!(
        (after.1 - std::f64::consts::FRAC_PI_2).abs() < 0.1,
        "{after:?}"
    );
    assert_eq!(PathKind::Straight.first_turn_m(), None);
    assert_eq!(PathKind::Circle.first_turn_m(), Some(0.0));
}

#[test]
fn limits_hold_on_every_path() {
    let p = TractorParams::default();
    for kind in PathKind::ALL {
        let mut t = tractor(kind);
        let mut previous = t.pose();
        for pose in drive(&mut t, 300.0) {
            assert!(pose.speed_m_s <= p.speed_m_s + 1e-12, "{kind}");
            assert!(pose.yaw_rate_rad_s.abs() <= p.max_turn_rate_rad_s + 1e-12);
            // Heading change and position change measured independently of the state's
            // own rate fields.
            let turned = wrap_angle(pose.heading_rad - previous.heading_rad).abs();
            assert!(turned <= p.max_turn_rate_rad_s * DT + 1e-9, "{kind}");
            let moved = (pose.position_ne_m - previous.position_ne_m).norm();
            assert!(moved <= p.speed_m_s * DT + 1e-9, "{kind}");
            let accel = (pose.speed_m_s - previous.speed_m_s).abs() / DT;
            assert!(accel <= p.max_accel_m_s2 + 1e-9, "{kind}");
            previous = pose;
        }
        // It keeps moving for the whole five minutes.
        assert!(t.distance_driven_m() > 0.8 * 300.0 * p.speed_m_s, "{kind}");
    }
}

#[test]
fn closed_paths_come_back_to_the_start_after_a_lap() {
    for kind in [PathKind::Rectangle, PathKind::Circle, PathKind::FigureEight] {
        let mut t = tractor(kind);
        let lap = t.lap_length_m().unwrap();
        let lap_time = lap / t.params().speed_m_s;
        let poses = drive(&mut t, 1.4 * lap_time);
        // Far from the start a quarter of the way round (the figure-eight passes its start
        // again half way), then back near it around one lap.
        let quarter = &poses[(0.25 * lap_time / DT) as usize];
        assert!(quarter.position_ne_m.norm() > 10.0, "{kind}");
        let closest = poses[(0.8 * lap_time / DT) as usize..]
            .iter()
            .map(|p| p.position_ne_m.norm())
            .fold(f64::INFINITY, f64::min);
        assert!(closest < 1.0, "{kind}: closest {closest}");
        // The second lap starts: it follows the path again rather than stopping.
        assert!(t.pose().speed_m_s > 1.0);
    }
}

#[test]
fn turns_change_heading_by_their_angle() {
    for (kind, expected) in [(PathKind::Turn90, FRAC_PI_2), (PathKind::Turn180, PI)] {
        let mut t = tractor(kind);
        let poses = drive(&mut t, 90.0);
        let end = poses.last().unwrap();
        let change = wrap_angle(end.heading_rad - 0.0).abs();
        assert!(
            (change - expected).abs() < 5f64.to_radians(),
            "{kind}: {}°",
            change.to_degrees()
        );
        // It went straight first: 15 s in, still heading north on the east = 0 line.
        let early = &poses[(15.0 / DT) as usize];
        assert!(early.heading_rad.abs() < 1e-6 && early.position_ne_m.y.abs() < 1e-6);
        // And the turn was driven, not jumped: the heading passed through the middle.
        assert!(poses
            .iter()
            .any(|p| (p.heading_rad.abs() - expected / 2.0).abs() < 0.05));
    }
}

fn segments_cross(a: Vector2<f64>, b: Vector2<f64>, c: Vector2<f64>, d: Vector2<f64>) -> bool {
    let cross = |o: Vector2<f64>, p: Vector2<f64>, q: Vector2<f64>| {
        (p - o).x * (q - o).y - (p - o).y * (q - o).x
    };
    let (d1, d2) = (cross(c, d, a), cross(c, d, b));
    let (d3, d4) = (cross(a, b, c), cross(a, b, d));
    d1 * d2 < 0.0 && d3 * d4 < 0.0
}

#[test]
fn figure_eight_crosses_itself() {
    let mut t = tractor(PathKind::FigureEight);
    let lap_time = t.lap_length_m().unwrap() / t.params().speed_m_s;
    // The crossing is at the start point, passed half way round and again after a lap; skip
    // the very start so the crossing lies inside segments rather than at an end.
    let track: Vec<_> = drive(&mut t, 1.2 * lap_time)
        .iter()
        .skip(100)
        .step_by(50)
        .map(|p| p.position_ne_m)
        .collect();
    let mut crossings = 0;
    for i in 0..track.len() - 1 {
        for j in i + 2..track.len() - 1 {
            if segments_cross(track[i], track[i + 1], track[j], track[j + 1]) {
                crossings += 1;
            }
        }
    }
    assert!(crossings >= 1, "{crossings}");
    // A circle does not.
    let mut c = tractor(PathKind::Circle);
    let lap_time = c.lap_length_m().unwrap() / c.params().speed_m_s;
    let track: Vec<_> = drive(&mut c, 0.95 * lap_time)
        .iter()
        .step_by(50)
        .map(|p| p.position_ne_m)
        .collect();
    for i in 0..track.len() - 1 {
        for j in i + 2..track.len() - 1 {
            assert!(!segments_cross(
                track[i],
                track[i + 1],
                track[j],
                track[j + 1]
            ));
        }
    }
}

#[test]
fn straight_keeps_going_and_start_pose_is_honoured() {
    let mut t = Tractor::new(
        PathKind::Straight,
        TractorParams::default(),
        [10.0, -5.0],
        FRAC_PI_2,
    )
    .unwrap();
    drive(&mut t, 200.0);
    let pose = t.pose();
    // 200 s at 1.5 m/s due east from (10, −5), far past the 100 m polyline.
    assert!((pose.position_ne_m - Vector2::new(10.0, 295.0)).norm() < 1e-6);
    let pad = t.pad();
    assert_eq!(pad.centre_ned_m.z, -1.0);
    assert!((pad.velocity_ned_m_s - Vector3::new(0.0, 1.5, 0.0)).norm() < 1e-9);
    assert!(pad.contains_ne(Vector2::new(10.4, 295.4)));
    assert!(!pad.contains_ne(Vector2::new(10.6, 295.0)));
}

#[test]
fn names_parse_and_print() {
    for kind in PathKind::ALL {
        assert_eq!(kind.to_string().parse::<PathKind>().unwrap(), kind);
    }
    let err = "zigzag".parse::<PathKind>().unwrap_err();
    assert_eq!(err.given, "zigzag");
    let message = err.to_string();
    for kind in PathKind::ALL {
        assert!(message.contains(kind.name()), "{message}");
    }
    assert!("Circle".parse::<PathKind>().is_err());
}

#[test]
fn bad_parameters_are_refused() {
    let bad = TractorParams {
        max_turn_rate_rad_s: 0.0,
        ..TractorParams::default()
    };
    assert!(matches!(
        Tractor::new(PathKind::Circle, bad, [0.0, 0.0], 0.0),
        Err(TractorError::NotPositive {
            name: "max_turn_rate_rad_s",
            ..
        })
    ));
    let bad = TractorParams {
        speed_m_s: f64::NAN,
        ..TractorParams::default()
    };
    assert!(bad.validate().is_err());
    assert!(Tractor::new(
        PathKind::Circle,
        TractorParams::default(),
        [f64::INFINITY, 0.0],
        0.0
    )
    .is_err());
    let mut t = tractor(PathKind::Circle);
    assert!(t.step(-1.0).is_err());
    assert!(t.step(f64::NAN).is_err());
}

#[test]
fn a_parked_tractor_pulls_away_within_its_acceleration_limit() {
    let params = TractorParams::default();
    let mut tractor = Tractor::new(PathKind::Straight, params, [0.0, 0.0], 0.0)
        .unwrap()
        .parked();
    assert_eq!(tractor.pose().speed_m_s, 0.0);
    let dt_s = 0.01;
    for _ in 0..100 {
        tractor.step(dt_s).unwrap();
    }
    // 1 s at 0.5 m/s²: 0.5 m/s and 0.25 m driven.
    assert!((tractor.pose().speed_m_s - 0.5).abs() < 1e-9);
    assert!((tractor.distance_driven_m() - 0.25).abs() < 0.01);
    for _ in 0..1000 {
        tractor.step(dt_s).unwrap();
    }
    assert!((tractor.pose().speed_m_s - params.speed_m_s).abs() < 1e-9);
}

/// A driven tractor's speed wanders around the cruise speed with the configured spread (over
/// a long straight), and its line wanders off the path by about the configured amount; the
/// scripted one does neither.
#[test]
fn a_driver_varies_speed_and_line() {
    let params = TractorParams::default();
    let behaviour = crate::realism::DriverBehaviour::default();
    let scripted = Tractor::new(PathKind::Straight, params, [0.0, 0.0], 0.0).unwrap();
    let mut driven = scripted.clone().with_driver(behaviour, 4);
    let mut speeds = Vec::new();
    let mut offsets = Vec::new();
    for _ in 0..(1200.0 / 0.05) as usize {
        driven.step(0.05).unwrap();
        let pose = driven.pose();
        speeds.push(pose.speed_m_s);
        offsets.push(pose.position_ne_m.y);
    }
    let n = speeds.len() as f64;
    let mean = speeds.iter().sum::<f64>() / n;
    let spread = (speeds.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / n).sqrt();
    let expected = behaviour.speed_variation * params.speed_m_s;
    assert!(
        (mean - params.speed_m_s).abs() < 0.1 * params.speed_m_s,
        "mean {mean}"
    );
    assert!(
        spread > 0.5 * expected && spread < 1.5 * expected,
        "speed spread {spread} m/s against {expected}"
    );
    let offset_rms = (offsets.iter().map(|y| y * y).sum::<f64>() / n).sqrt();
    assert!(
        offset_rms > 0.3 * behaviour.wander_m && offset_rms < 2.0 * behaviour.wander_m,
        "line {offset_rms} m off the path"
    );
    // The same seed drives the same tractor.
    let mut again = scripted.clone().with_driver(behaviour, 4);
    for _ in 0..100 {
        again.step(0.05).unwrap();
    }
    let mut first = scripted.with_driver(behaviour, 4);
    for _ in 0..100 {
        first.step(0.05).unwrap();
    }
    assert_eq!(again.pose(), first.pose());
}

/// On a rough field the pad sways by about height × tilt and heaves; its velocity is the
/// derivative of its position (checked by finite differences); parked, it is still.
#[test]
fn a_rough_field_rocks_the_pad() {
    let params = TractorParams::default();
    let motion = crate::realism::PadMotion::default();
    let mut tractor = Tractor::new(PathKind::Straight, params, [0.0, 0.0], 0.0)
        .unwrap()
        .with_rough_field(motion, 9);
    let mut max_sway_m: f64 = 0.0;
    let mut max_heave_m: f64 = 0.0;
    let dt_s = 0.01;
    for _ in 0..3000 {
        let before = tractor.pad();
        tractor.step(dt_s).unwrap();
        let after = tractor.pad();
        let pose = tractor.pose();
        max_sway_m = max_sway_m.max((after.centre_ned_m.y - pose.position_ne_m.y).abs());
        max_heave_m = max_heave_m.max((after.centre_ned_m.z + params.pad_height_m).abs());
        let velocity = (after.centre_ned_m - before.centre_ned_m) / dt_s;
        let mean_velocity = 0.5 * (after.velocity_ned_m_s + before.velocity_ned_m_s);
        assert!(
            (velocity - mean_velocity).norm() < 0.02,
            "finite difference {velocity:?} against {mean_velocity:?}"
        );
    }
    let expected_sway_m = params.pad_height_m * motion.tilt_rad.sin();
    assert!(
        max_sway_m > 0.5 * expected_sway_m && max_sway_m <= expected_sway_m + 1e-9,
        "sway {max_sway_m} m against {expected_sway_m}"
    );
    assert!(max_heave_m > 0.5 * motion.heave_m && max_heave_m <= motion.heave_m + 1e-9);
    let parked = Tractor::new(PathKind::Straight, params, [0.0, 0.0], 0.0)
        .unwrap()
        .parked()
        .with_rough_field(motion, 9);
    assert_eq!(parked.pad().velocity_ned_m_s, Vector3::zeros());
}
