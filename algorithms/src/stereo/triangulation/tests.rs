use super::*;
use nalgebra::{DMatrix, DVector};

const D: f64 = 10.0;

fn sight(from: Vector3<f64>, to: Vector3<f64>) -> LineOfSight {
    LineOfSight::towards(&from, &to).unwrap()
}

fn pair(target: Vector3<f64>) -> (LineOfSight, LineOfSight) {
    (
        sight(Vector3::zeros(), target),
        sight(Vector3::new(D, 0.0, 0.0), target),
    )
}

/// The closest points of two lines by a generic least-squares solve (nalgebra's SVD of the
/// 3×2 system [l, −r]·[tl, tr]ᵀ = Or − Ol), independent of Eq. 14's closed form.
fn least_squares_feet(left: LineOfSight, right: LineOfSight) -> (Vector3<f64>, Vector3<f64>) {
    let l = left.direction();
    let r = right.direction();
    let a = DMatrix::from_row_slice(3, 2, &[l.x, -r.x, l.y, -r.y, l.z, -r.z]);
    let b = DVector::from_vec(vec![D, 0.0, 0.0]);
    let t = a.svd(true, true).solve(&b, 1e-15).unwrap();
    (l * t[0], Vector3::new(D, 0.0, 0.0) + r * t[1])
}

/// Brute force: the distance between the lines minimised over (tl, tr) by shrinking a grid
/// search, with no calculus at all.
fn grid_search_feet(left: LineOfSight, right: LineOfSight) -> (f64, f64) {
    let l = left.direction();
    let r = right.direction();
    let or = Vector3::new(D, 0.0, 0.0);
    let distance = |tl: f64, tr: f64| (l * tl - (or + r * tr)).norm_squared();
    let (mut tl, mut tr, mut step) = (500.0, 500.0, 250.0);
    while step > 1e-7 {
        let mut best = (distance(tl, tr), tl, tr);
        for i in -4..=4 {
            for j in -4..=4 {
                let (a, b) = (tl + i as f64 * step / 4.0, tr + j as f64 * step / 4.0);
                let d = distance(a, b);
                if d < best.0 {
                    best = (d, a, b);
                }
            }
        }
        (tl, tr) = (best.1, best.2);
        step *= 0.6;
    }
    (tl, tr)
}

#[test]
fn noise_free_angles_recover_the_point_exactly() {
    for target in [
        Vector3::new(5.0, 1000.0, 52.4),
        Vector3::new(-40.0, 300.0, 20.0),
        Vector3::new(60.0, 25.0, -1.0),
        Vector3::new(5.0, 4000.0, 490.0),
    ] {
        let (l, r) = pair(target);
        let segment = common_perpendicular(D, l, r, DEFAULT_MIN_DET_H).unwrap();
        for w in [0.0, 0.3, 0.5, 1.0] {
            let error = (segment.point(w) - target).norm();
            assert!(error < 1e-9 * target.norm(), "{target:?} w={w}: {error}");
        }
        assert!(segment.miss_distance_m() < 1e-8, "{segment:?}");
        let closed = closed_form(D, l, r, DEFAULT_MIN_DET_H).unwrap();
        assert!(
            (closed - target).norm() < 1e-9 * target.norm(),
            "{closed:?}"
        );
    }
}

#[test]
fn skew_lines_meet_at_the_least_squares_and_brute_force_feet() {
    let target = Vector3::new(3.0, 600.0, 40.0);
    let (mut l, mut r) = pair(target);
    // Disturb the lines so they are skew: 2 mrad on the left tilt, 0.5 mrad on the right pan.
    l.tilt_rad += 2e-3;
    r.pan_rad -= 5e-4;
    let segment = common_perpendicular(D, l, r, DEFAULT_MIN_DET_H).unwrap();
    assert!(segment.miss_distance_m() > 0.1, "{segment:?}");
    let (left_foot, right_foot) = least_squares_feet(l, r);
    assert!(
        (segment.left_foot_m - left_foot).norm() < 1e-6,
        "{segment:?} vs {left_foot:?}"
    );
    assert!((segment.right_foot_m - right_foot).norm() < 1e-6);
    let (tl, tr) = grid_search_feet(l, r);
    assert!((segment.left_range_m - tl).abs() < 1e-3, "{tl} {segment:?}");
    assert!(
        (segment.right_range_m - tr).abs() < 1e-3,
        "{tr} {segment:?}"
    );
    // The segment is perpendicular to both lines.
    let pq = segment.right_foot_m - segment.left_foot_m;
    assert!(pq.dot(&l.direction()).abs() < 1e-9 * pq.norm());
    assert!(pq.dot(&r.direction()).abs() < 1e-9 * pq.norm());
    // det H is |l × r|² (Lagrange's identity, the seed's denominator).
    let cross = l.direction().cross(&r.direction()).norm_squared();
    assert!((segment.det_h - cross).abs() < 1e-12);
}

#[test]
fn parallel_lines_are_a_named_error() {
    let l = LineOfSight::new(0.01, 0.05);
    let error = common_perpendicular(D, l, l, DEFAULT_MIN_DET_H).unwrap_err();
    assert!(
        matches!(error, TriangulationError::NearParallel { .. }),
        "{error}"
    );
    assert!(error.to_string().contains("near-parallel"));
    // 1e-7 rad apart: det H ≈ 1e-14 < 1e-12.
    let nearly = LineOfSight::new(0.01 + 1e-7, 0.05);
    assert!(matches!(
        common_perpendicular(D, l, nearly, DEFAULT_MIN_DET_H),
        Err(TriangulationError::NearParallel { .. })
    ));
    assert!(matches!(
        closed_form(D, l, nearly, DEFAULT_MIN_DET_H),
        Err(TriangulationError::NearParallel { .. })
    ));
    // A target at 4 km off a 10 m baseline is well within reach.
    let (l, r) = pair(Vector3::new(5.0, 4000.0, 300.0));
    assert!(common_perpendicular(D, l, r, DEFAULT_MIN_DET_H).is_ok());
}

#[test]
fn lines_that_diverge_meet_behind_the_ptus() {
    // Left looks left, right looks right: they "meet" behind the baseline.
    let l = LineOfSight::new(-0.1, 0.0);
    let r = LineOfSight::new(0.1, 0.0);
    assert!(matches!(
        common_perpendicular(D, l, r, DEFAULT_MIN_DET_H),
        Err(TriangulationError::BehindPtu {
            side: Side::Left,
            ..
        })
    ));
    assert!(matches!(
        closed_form(D, l, r, DEFAULT_MIN_DET_H),
        Err(TriangulationError::BehindPtu { .. })
    ));
    assert!(matches!(
        closed_form(D, LineOfSight::new(1.6, 0.0), r, DEFAULT_MIN_DET_H),
        Err(TriangulationError::PanOutOfRange {
            side: Side::Left,
            ..
        })
    ));
}

#[test]
fn non_finite_input_is_a_named_error_not_a_panic() {
    let good = LineOfSight::new(0.0, 0.0);
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let error = common_perpendicular(D, LineOfSight::new(bad, 0.0), good, 1e-12).unwrap_err();
        assert!(
            matches!(error, TriangulationError::NonFinite { what: "left pan", value } if !value.is_finite()),
            "{error}"
        );
        assert!(matches!(
            closed_form(D, good, LineOfSight::new(0.0, bad), 1e-12),
            Err(TriangulationError::NonFinite {
                what: "right tilt",
                ..
            })
        ));
        assert!(matches!(
            common_perpendicular(bad, good, good, 1e-12),
            Err(TriangulationError::NonFinite {
                what: "baseline",
                ..
            })
        ));
        let reading = PtuReading {
            pan_rad: 0.0,
            tilt_rad: 0.0,
            target_offset_px: Some([1.0, bad]),
        };
        assert!(matches!(
            reading.line_of_sight(&CameraIntrinsics::seed(), Side::Right),
            Err(TriangulationError::NonFinite {
                what: "right target offset (up)",
                ..
            })
        ));
    }
}

/// Eq. 5 against a pinhole camera: a target that projects `offset` pixels off the centre of an
/// untilted camera at pan ψp has the line of sight ψp + ψc, ϕc.
#[test]
fn pixel_compensation_matches_a_pinhole_projection() {
    let camera = CameraIntrinsics::new(100.0, 3.75).unwrap();
    let f_px = camera.focal_length_px();
    assert!((f_px - 26_666.666_666).abs() < 1e-3);
    let pan_p = 0.2;
    for (right_px, up_px) in [(0.0, 0.0), (120.0, -35.0), (-600.0, 400.0)] {
        // The ray through the pixel, in the camera frame (x right, y up, z along the axis)...
        let ray = Vector3::new(right_px, up_px, f_px);
        // ...and in the stereo frame: the untilted camera's axes after a pan ψp.
        let (s, c) = f64::sin_cos(pan_p);
        let world = Vector3::new(c * ray.x + s * ray.z, -s * ray.x + c * ray.z, ray.y);
        let truth = sight(Vector3::zeros(), world);
        let reading = PtuReading {
            pan_rad: pan_p,
            tilt_rad: 0.0,
            target_offset_px: Some([right_px, up_px]),
        };
        let los = reading.line_of_sight(&camera, Side::Left).unwrap();
        assert!(
            (los.pan_rad - truth.pan_rad).abs() < 1e-12,
            "{los:?} {truth:?}"
        );
        assert!((los.tilt_rad - truth.tilt_rad).abs() < 1e-12);
    }
    let lost = PtuReading {
        pan_rad: 0.0,
        tilt_rad: 0.0,
        target_offset_px: None,
    };
    assert_eq!(
        lost.line_of_sight(&camera, Side::Left),
        Err(TriangulationError::NoTarget { side: Side::Left })
    );
}

#[test]
fn the_rig_places_the_stereo_frame_on_the_runway() {
    let rig = StereoRig::new(
        12.0,
        Vector3::new(-6.0, -30.0, 1.5),
        0.2,
        CameraIntrinsics::seed(),
        Estimator::default(),
        DEFAULT_MIN_DET_H,
    )
    .unwrap();
    // Round trip, and the right PTU D metres from the left along the yawed baseline.
    let p = Vector3::new(3.0, 700.0, 40.0);
    assert!((rig.stereo_to_runway(&rig.runway_to_stereo(&p)) - p).norm() < 1e-9);
    let right = rig.right_ptu_runway_m();
    assert!(((right - rig.left_ptu_runway_m()).norm() - 12.0).abs() < 1e-12);
    assert!(
        (right - Vector3::new(-6.0 + 12.0 * 0.2f64.cos(), -30.0 + 12.0 * 0.2f64.sin(), 1.5)).norm()
            < 1e-12
    );
    // Exact angles from both PTUs (computed in the runway frame, rotated by hand) → p.
    let angles = |ptu: Vector3<f64>| {
        let d = p - ptu;
        // Rotate the offset into the stereo frame by −yaw.
        let (s, c) = 0.2f64.sin_cos();
        let ds = Vector3::new(c * d.x + s * d.y, -s * d.x + c * d.y, d.z);
        LineOfSight::new(ds.x.atan2(ds.y), ds.z.atan2(ds.x.hypot(ds.y)))
    };
    let fix = rig
        .triangulate(angles(rig.left_ptu_runway_m()), angles(right))
        .unwrap();
    assert!((fix.position_runway_m - p).norm() < 1e-8, "{fix:?}");
    // Bad rigs are named errors.
    let camera = CameraIntrinsics::seed();
    assert_eq!(
        StereoRig::new(
            0.0,
            Vector3::zeros(),
            0.0,
            camera,
            Estimator::default(),
            1e-12
        ),
        Err(RigError::Baseline(0.0))
    );
    assert_eq!(
        StereoRig::new(
            10.0,
            Vector3::zeros(),
            0.0,
            camera,
            Estimator::CommonPerpendicular { weight_left: 1.5 },
            1e-12
        ),
        Err(RigError::Weight(1.5))
    );
    assert_eq!(
        CameraIntrinsics::new(-1.0, 3.75),
        Err(RigError::FocalLength(-1.0))
    );
    assert_eq!(
        CameraIntrinsics::new(100.0, 0.0),
        Err(RigError::PixelPitch(0.0))
    );
}
