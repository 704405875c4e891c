use super::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn names(n: usize) -> Vec<String> {
    (0..n).map(|k| format!("task{k}.knob")).collect()
}

/// A random strictly increasing axis of 2–5 values, all > 0 (so it suits both scales).
fn random_axis(rng: &mut StdRng) -> Vec<f64> {
    let len = rng.random_range(2..=5);
    let mut v = rng.random_range(0.05..2.0);
    (0..len)
        .map(|_| {
            let x = v;
            v += rng.random_range(0.1..3.0);
            x
        })
        .collect()
}

/// Every point of the tensor product of `axes`, knob 0 slowest.
fn grid_points(axes: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let mut out = vec![vec![]];
    for axis in axes {
        out = out
            .into_iter()
            .flat_map(|p| {
                axis.iter().map(move |&v| {
                    let mut q = p.clone();
                    q.push(v);
                    q
                })
            })
            .collect();
    }
    out
}

/// f(x) = Σ over subsets S of c_S Π_{i∈S} g(x_i): multilinear in g(x).
struct Multilinear {
    coeffs: Vec<f64>,
    log: bool,
}

impl Multilinear {
    fn random(rng: &mut StdRng, n: usize, log: bool) -> Self {
        Multilinear {
            coeffs: (0..1 << n).map(|_| rng.random_range(-3.0..3.0)).collect(),
            log,
        }
    }
    fn at(&self, x: &[f64]) -> f64 {
        let g = |v: f64| if self.log { v.ln() } else { v };
        self.coeffs
            .iter()
            .enumerate()
            .map(|(s, c)| {
                c * x
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| s & (1 << i) != 0)
                    .map(|(_, &v)| g(v))
                    .product::<f64>()
            })
            .sum()
    }
}

fn random_inside(rng: &mut StdRng, axes: &[Vec<f64>]) -> Vec<f64> {
    axes.iter()
        .map(|a| rng.random_range(a[0]..=a[a.len() - 1]))
        .collect()
}

/// Independent reference: nested 1-D linear interpolation, one axis at a time, with the
/// query clamped into the grid first, in plain or ln coordinates.
fn nested(axes: &[Vec<f64>], f: &dyn Fn(&[f64]) -> f64, x: &[f64], log: bool) -> f64 {
    fn rec(
        axes: &[Vec<f64>],
        f: &dyn Fn(&[f64]) -> f64,
        x: &[f64],
        fixed: &mut Vec<f64>,
        log: bool,
    ) -> f64 {
        let k = fixed.len();
        if k == axes.len() {
            return f(fixed);
        }
        let a = &axes[k];
        let xk = x[k].clamp(a[0], a[a.len() - 1]);
        let mut j = 0;
        while j + 2 < a.len() && xk > a[j + 1] {
            j += 1;
        }
        let g = |v: f64| if log { v.ln() } else { v };
        let t = (g(xk) - g(a[j])) / (g(a[j + 1]) - g(a[j]));
        fixed.push(a[j]);
        let lo = rec(axes, f, x, fixed, log);
        fixed.pop();
        fixed.push(a[j + 1]);
        let hi = rec(axes, f, x, fixed, log);
        fixed.pop();
        lo + t * (hi - lo)
    }
    rec(axes, f, x, &mut Vec::new(), log)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

#[test]
fn exact_at_grid_points() {
    let mut rng = StdRng::seed_from_u64(1);
    for n in 1..=5 {
        for scale in [AxisScale::Linear, AxisScale::Log] {
            let axes: Vec<Vec<f64>> = (0..n).map(|_| random_axis(&mut rng)).collect();
            let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
                .into_iter()
                .map(|p| (p, rng.random_range(-10.0..10.0)))
                .collect();
            let m = GridModel::from_samples(names(n), &points, scale).unwrap();
            assert_eq!(m.axes(), &axes[..]);
            assert!(m.inferred_points().is_empty());
            for (x, v) in &points {
                let e = m.eval(x);
                assert_eq!(e.value, *v, "n={n} {scale:?} at {x:?}");
                assert!(!e.extrapolated);
            }
        }
    }
}

#[test]
fn multilinear_functions_are_reproduced() {
    let mut rng = StdRng::seed_from_u64(2);
    for n in 1..=5 {
        for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
            let axes: Vec<Vec<f64>> = (0..n).map(|_| random_axis(&mut rng)).collect();
            let f = Multilinear::random(&mut rng, n, log);
            let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
                .into_iter()
                .map(|p| {
                    let v = f.at(&p);
                    (p, v)
                })
                .collect();
            let m = GridModel::from_samples(names(n), &points, scale).unwrap();
            for _ in 0..200 {
                let x = random_inside(&mut rng, &axes);
                let got = m.eval(&x).value;
                assert!(
                    close(got, f.at(&x), 1e-9),
                    "n={n} {scale:?} {x:?}: {got} vs {}",
                    f.at(&x)
                );
            }
        }
    }
}

#[test]
fn matches_nested_1d_interpolation_inside_and_outside() {
    let mut rng = StdRng::seed_from_u64(3);
    for n in 1..=5 {
        for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
            let axes: Vec<Vec<f64>> = (0..n).map(|_| random_axis(&mut rng)).collect();
            // A non-multilinear function: interpolation differs from it between points.
            let f = |x: &[f64]| {
                x.iter()
                    .enumerate()
                    .map(|(i, v)| (v * (i + 1) as f64).sin())
                    .sum::<f64>()
            };
            let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
                .into_iter()
                .map(|p| {
                    let v = f(&p);
                    (p, v)
                })
                .collect();
            let m = GridModel::from_samples(names(n), &points, scale).unwrap();
            for _ in 0..300 {
                // Queries up to 30 % beyond each end, but > 0 for the log scale.
                let x: Vec<f64> = axes
                    .iter()
                    .map(|a| {
                        let (lo, hi) = (a[0], a[a.len() - 1]);
                        let w = hi - lo;
                        rng.random_range((lo - 0.3 * w).max(lo * 0.2)..hi + 0.3 * w)
                    })
                    .collect();
                let e = m.eval(&x);
                let want = nested(&axes, &f, &x, log);
                assert!(
                    close(e.value, want, 1e-12),
                    "n={n} {scale:?} {x:?}: {} vs {want}",
                    e.value
                );
                for (k, a) in axes.iter().enumerate() {
                    let outside = x[k] < a[0] || x[k] > a[a.len() - 1];
                    assert_eq!(e.is_clamped(k), outside, "knob {k} of {x:?}");
                }
                assert_eq!(e.extrapolated, e.clamped != 0);
            }
        }
    }
}

#[test]
fn long_axes_match_nested_interpolation() {
    // Axes longer than 18 values take the binary-search path for the cell.
    let mut rng = StdRng::seed_from_u64(6);
    for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
        let axes: Vec<Vec<f64>> = [50, 19, 3]
            .iter()
            .map(|&len| {
                let mut v = 0.01;
                (0..len)
                    .map(|_| {
                        v += rng.random_range(0.01..1.0);
                        v
                    })
                    .collect()
            })
            .collect();
        let f = |x: &[f64]| x[0].cos() * x[1] + x[2] * x[2];
        let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
            .into_iter()
            .map(|p| {
                let v = f(&p);
                (p, v)
            })
            .collect();
        let m = GridModel::from_samples(names(3), &points, scale).unwrap();
        for (x, v) in points.iter().step_by(7) {
            assert_eq!(m.eval(x).value, *v);
        }
        for _ in 0..500 {
            let x = random_inside(&mut rng, &axes);
            let want = nested(&axes, &f, &x, log);
            assert!(close(m.eval(&x).value, want, 1e-12), "{scale:?} {x:?}");
        }
    }
}

#[test]
fn log_scale_interpolates_in_ln_space() {
    // 1-D, axis {1, 100}: at x = 10, ln-weight 1/2; linear weight 9/99.
    let pts = vec![(vec![1.0], 2.0), (vec![100.0], 4.0)];
    let log = GridModel::from_samples(names(1), &pts, AxisScale::Log).unwrap();
    let lin = GridModel::from_samples(names(1), &pts, AxisScale::Linear).unwrap();
    assert!((log.eval(&[10.0]).value - 3.0).abs() < 1e-12);
    assert!((lin.eval(&[10.0]).value - (2.0 + 2.0 * 9.0 / 99.0)).abs() < 1e-12);
}

#[test]
fn clamps_outside_the_grid_and_says_so() {
    let pts = vec![
        (vec![1.0, 10.0], 1.0),
        (vec![2.0, 10.0], 2.0),
        (vec![1.0, 20.0], 3.0),
        (vec![2.0, 20.0], 5.0),
    ];
    let m = GridModel::from_samples(names(2), &pts, AxisScale::Linear).unwrap();
    let e = m.eval(&[0.5, 15.0]);
    assert_eq!(e.value, 2.0); // (1 + 3) / 2 at x0 = 1
    assert!(e.extrapolated && e.is_clamped(0) && !e.is_clamped(1));
    let e = m.eval(&[3.0, 25.0]);
    assert_eq!(e.value, 5.0);
    assert_eq!(e.clamped, 0b11);
    let e = m.eval(&[1.5, 10.0]);
    assert_eq!(e.value, 1.5);
    assert!(!e.extrapolated);
    // Exactly on the boundary is inside.
    assert!(!m.eval(&[2.0, 20.0]).extrapolated);
}

#[test]
fn single_value_axes_and_zero_knobs() {
    let pts = vec![(vec![5.0, 1.0], 2.0), (vec![5.0, 3.0], 4.0)];
    let m = GridModel::from_samples(names(2), &pts, AxisScale::Linear).unwrap();
    let e = m.eval(&[5.0, 2.0]);
    assert_eq!((e.value, e.extrapolated), (3.0, false));
    let e = m.eval(&[7.0, 2.0]);
    assert_eq!((e.value, e.clamped), (3.0, 0b01));
    let c = GridModel::from_samples(vec![], &[(vec![], 3.25)], AxisScale::Log).unwrap();
    assert_eq!(c.eval(&[]).value, 3.25);
}

#[test]
fn missing_interior_points_of_a_multilinear_function_are_inferred_exactly() {
    let mut rng = StdRng::seed_from_u64(4);
    for n in 1..=4 {
        for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
            // At least 3 values per axis, so there are interior points to remove.
            let axes: Vec<Vec<f64>> = (0..n)
                .map(|_| loop {
                    let a = random_axis(&mut rng);
                    if a.len() >= 3 {
                        break a;
                    }
                })
                .collect();
            let f = Multilinear::random(&mut rng, n, log);
            let all = grid_points(&axes);
            let interior = |p: &[f64]| {
                p.iter()
                    .zip(&axes)
                    .all(|(v, a)| *v != a[0] && *v != a[a.len() - 1])
            };
            let mut removed = Vec::new();
            let mut points = Vec::new();
            for p in all {
                if interior(&p) && rng.random_bool(0.6) {
                    removed.push(p);
                } else {
                    let v = f.at(&p);
                    points.push((p, v));
                }
            }
            // The given axes: a removed point may hold the only sample of an axis value.
            let m = GridModel::with_axes(names(n), axes.clone(), &points, scale).unwrap();
            assert_eq!(m.inferred_points(), removed, "n={n}");
            for p in &removed {
                assert!(
                    close(m.eval(p).value, f.at(p), 1e-9),
                    "n={n} {scale:?} {p:?}"
                );
            }
            for _ in 0..50 {
                let x = random_inside(&mut rng, &axes);
                assert!(close(m.eval(&x).value, f.at(&x), 1e-9));
            }
        }
    }
}

#[test]
fn missing_corners_of_an_affine_function_are_inferred_exactly() {
    let mut rng = StdRng::seed_from_u64(5);
    for n in 1..=4 {
        for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
            let axes: Vec<Vec<f64>> = (0..n)
                .map(|_| loop {
                    let a = random_axis(&mut rng);
                    if a.len() >= 4 {
                        break a;
                    }
                })
                .collect();
            let c: Vec<f64> = (0..=n).map(|_| rng.random_range(-2.0..2.0)).collect();
            let g = |v: f64| if log { v.ln() } else { v };
            let f = |x: &[f64]| c[0] + x.iter().zip(&c[1..]).map(|(v, b)| b * g(*v)).sum::<f64>();
            let all = grid_points(&axes);
            // Drop every corner of the grid (none has a neighbour on both sides) and a
            // few random points, but keep the block at axis indices 1 and 2: it spans the
            // space, so the affine fit is determined.
            let corner = |p: &[f64]| {
                p.iter()
                    .zip(&axes)
                    .all(|(v, a)| *v == a[0] || *v == a[a.len() - 1])
            };
            let block = |p: &[f64]| p.iter().zip(&axes).all(|(v, a)| *v == a[1] || *v == a[2]);
            let (removed, kept): (Vec<_>, Vec<_>) = all
                .into_iter()
                .partition(|p| corner(p) || (!block(p) && rng.random_bool(0.2)));
            let points: Vec<(Vec<f64>, f64)> = kept
                .into_iter()
                .map(|p| {
                    let v = f(&p);
                    (p, v)
                })
                .collect();
            let m = GridModel::with_axes(names(n), axes.clone(), &points, scale).unwrap();
            assert_eq!(m.inferred_points(), removed);
            for p in &removed {
                assert!(
                    close(m.eval(p).value, f(p), 1e-9),
                    "n={n} {scale:?} {p:?}: {} vs {}",
                    m.eval(p).value,
                    f(p)
                );
            }
        }
    }
}

#[test]
fn inference_by_hand() {
    // 1-D: 2 is bracketed by 1 and 4 → 10 + (20 − 10)·(2 − 1)/(4 − 1).
    let pts = vec![(vec![1.0], 10.0), (vec![4.0], 20.0)];
    let m =
        GridModel::with_axes(names(1), vec![vec![1.0, 2.0, 4.0]], &pts, AxisScale::Linear).unwrap();
    assert!((m.eval(&[2.0]).value - (10.0 + 10.0 / 3.0)).abs() < 1e-12);
    // In ln coordinates: weight ln 2 / ln 4 = 1/2.
    let m =
        GridModel::with_axes(names(1), vec![vec![1.0, 2.0, 4.0]], &pts, AxisScale::Log).unwrap();
    assert!((m.eval(&[2.0]).value - 15.0).abs() < 1e-12);
    // 2-D cross: the centre is bracketed on both axes → mean of the two estimates.
    let pts = vec![
        (vec![0.0, 1.0], 1.0),
        (vec![2.0, 1.0], 3.0), // axis 0 estimate: 2
        (vec![1.0, 0.0], 10.0),
        (vec![1.0, 4.0], 14.0), // axis 1 estimate: 11
    ];
    let m = GridModel::from_samples(names(2), &pts, AxisScale::Linear).unwrap();
    assert!((m.eval(&[1.0, 1.0]).value - 6.5).abs() < 1e-12);
    // Beyond the measured points on every axis: the affine fit. Points on a line along
    // axis 0 say nothing about axis 1, so the fit is constant along it.
    let pts = vec![
        (vec![0.0, 0.0], 1.0),
        (vec![1.0, 0.0], 3.0),
        (vec![2.0, 0.0], 5.0),
    ];
    let m = GridModel::with_axes(
        names(2),
        vec![vec![0.0, 1.0, 2.0, 3.0], vec![0.0, 5.0]],
        &pts,
        AxisScale::Linear,
    )
    .unwrap();
    assert!((m.eval(&[3.0, 0.0]).value - 7.0).abs() < 1e-12);
    assert!((m.eval(&[1.0, 5.0]).value - 3.0).abs() < 1e-12);
    assert!((m.eval(&[3.0, 5.0]).value - 7.0).abs() < 1e-12);
}

#[test]
fn bad_inputs_are_errors() {
    let ok = vec![(vec![1.0, 2.0], 3.0)];
    let sc = AxisScale::Linear;
    assert_eq!(
        GridModel::from_samples(names(2), &[], sc),
        Err(ModelError::NoPoints)
    );
    assert!(matches!(
        GridModel::from_samples(names(2), &[(vec![1.0], 3.0)], sc),
        Err(ModelError::DimensionMismatch {
            point: 0,
            got: 1,
            expected: 2
        })
    ));
    assert!(matches!(
        GridModel::from_samples(names(2), &[(vec![1.0, f64::NAN], 3.0)], sc),
        Err(ModelError::NonFiniteKnob { point: 0, .. })
    ));
    assert!(matches!(
        GridModel::from_samples(names(2), &[(vec![1.0, 2.0], f64::NAN)], sc),
        Err(ModelError::NonFiniteValue { point: 0, .. })
    ));
    assert!(matches!(
        GridModel::from_samples(names(2), &[(vec![1.0, 2.0], f64::INFINITY)], sc),
        Err(ModelError::NonFiniteValue { .. })
    ));
    assert!(matches!(
        GridModel::from_samples(names(2), &[(vec![1.0, 0.0], 3.0)], AxisScale::Log),
        Err(ModelError::NonPositiveOnLogAxis { value: 0.0, .. })
    ));
    assert!(matches!(
        GridModel::from_samples(names(2), &[(vec![-1.0, 1.0], 3.0)], AxisScale::Log),
        Err(ModelError::NonPositiveOnLogAxis { .. })
    ));
    assert!(GridModel::from_samples(names(2), &[(vec![-1.0, 0.0], 3.0)], sc).is_ok());
    assert!(matches!(
        GridModel::from_samples(
            names(2),
            &[(vec![1.0, 2.0], 3.0), (vec![1.0, 2.0], 4.0)],
            sc
        ),
        Err(ModelError::DuplicatePoint {
            first: 0,
            second: 1,
            ..
        })
    ));
    assert!(matches!(
        GridModel::from_samples(names(9), &[(vec![1.0; 9], 3.0)], sc),
        Err(ModelError::TooManyKnobs { count: 9 })
    ));
    assert!(matches!(
        GridModel::from_samples(vec!["a.b".into(), "a.b".into()], &ok, sc),
        Err(ModelError::DuplicateKnob(_))
    ));
    // Scattered points whose tensor grid would be huge.
    let scattered: Vec<(Vec<f64>, f64)> = (0..40).map(|i| (vec![i as f64; 4], 1.0)).collect();
    assert!(matches!(
        GridModel::from_samples(names(4), &scattered, sc),
        Err(ModelError::GridTooLarge { points: 2_560_000 })
    ));
    assert!(matches!(
        GridModel::with_axes(names(2), vec![vec![1.0], vec![3.0]], &ok, sc),
        Err(ModelError::OffAxis { point: 0, .. })
    ));
    assert!(matches!(
        GridModel::with_axes(names(2), vec![vec![1.0], vec![2.0, 2.0]], &ok, sc),
        Err(ModelError::BadAxis { .. })
    ));
    assert!(matches!(
        GridModel::with_axes(names(2), vec![vec![1.0]], &ok, sc),
        Err(ModelError::DimensionMismatch { .. })
    ));
    let m = GridModel::from_samples(names(2), &ok, sc).unwrap();
    assert!(matches!(
        m.try_eval(&[1.0]),
        Err(ModelError::QueryDimension {
            got: 1,
            expected: 2
        })
    ));
    assert!(matches!(
        m.try_eval(&[1.0, f64::NAN]),
        Err(ModelError::QueryNaN { .. })
    ));
    assert!(m.eval(&[f64::NAN, 1.0]).value.is_nan());
    assert_eq!(m.try_eval(&[1.0, 2.0]).unwrap().value, 3.0);
    assert!(matches!(
        leave_one_out(&names(2), &ok, sc),
        Err(ModelError::TooFewForLoo(1))
    ));
}

#[test]
fn additive_model_sums_its_parts_over_the_knob_union() {
    let a = GridModel::from_samples(
        vec!["hazard.rate_fps".into()],
        &[(vec![1.0], 1.0), (vec![4.0], 2.5)],
        AxisScale::Linear,
    )
    .unwrap();
    let b = GridModel::from_samples(
        vec!["detection.rate_fps".into(), "detection.kernel_px".into()],
        &[
            (vec![1.0, 10.0], 0.1),
            (vec![10.0, 10.0], 0.4),
            (vec![1.0, 22.0], 0.2),
            (vec![10.0, 22.0], 0.6),
        ],
        AxisScale::Linear,
    )
    .unwrap();
    // Shares `hazard.rate_fps` with `a`: listed once, fed to both.
    let c = GridModel::from_samples(
        vec!["hazard.rate_fps".into()],
        &[(vec![1.0], 0.0), (vec![4.0], 0.3)],
        AxisScale::Linear,
    )
    .unwrap();
    let m = PowerModel::additive(3.0, vec![a.clone(), b.clone(), c.clone()]).unwrap();
    assert_eq!(
        m.knob_names(),
        [
            "hazard.rate_fps",
            "detection.rate_fps",
            "detection.kernel_px"
        ]
    );
    let x = [2.0, 5.5, 30.0];
    let want = 3.0 + a.eval(&[2.0]).value + b.eval(&[5.5, 30.0]).value + c.eval(&[2.0]).value;
    let e = m.eval(&x);
    assert!((e.value - want).abs() < 1e-12);
    // By hand: a = 1 + 1.5/3, b at kernel 22: 0.2 + 0.4·0.5, c = 0.1.
    assert!((e.value - (3.0 + 1.5 + 0.4 + 0.1)).abs() < 1e-12);
    assert_eq!(e.clamped, 0b100, "only the kernel knob is outside");
    let e = m.eval(&[5.0, 5.5, 22.0]);
    assert_eq!(e.clamped, 0b001);
    assert!(matches!(
        m.try_eval(&[1.0, 2.0]),
        Err(ModelError::QueryDimension { .. })
    ));
    assert!(matches!(
        PowerModel::additive(f64::NAN, vec![]),
        Err(ModelError::BadBasePower(_))
    ));
    // A shifted part models the power above the base.
    let above = a.shifted(-0.5);
    assert!((above.eval(&[4.0]).value - 2.0).abs() < 1e-12);
    let joint = PowerModel::Joint(b.clone());
    assert_eq!(
        joint.knob_names(),
        ["detection.rate_fps", "detection.kernel_px"]
    );
    assert_eq!(joint.eval(&[5.5, 30.0]), b.eval(&[5.5, 30.0]));
    let empty = PowerModel::additive(2.0, vec![]).unwrap();
    assert_eq!(empty.eval(&[]).value, 2.0);
}

// -----------------------------------------------------------------------------------------
// Seed data

fn seed_file(rel: &str) -> Option<String> {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(rel);
    match std::fs::read_to_string(&path) {
        Ok(t) => Some(t),
        Err(_) => {
            eprintln!(
                "SKIP: {} is absent, the test needs the shared seed data",
                path.display()
            );
            None
        }
    }
}

fn shipped_profile(file: &str) -> Profile {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../profiles/jetson-nano-seed")
        .join(file);
    Profile::from_toml_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn loo_by_hand_on_the_tracking_grid() {
    let p = shipped_profile("tracking.toml");
    let r = leave_one_out_profile(&p, AxisScale::Linear).unwrap();
    // (1, 10) without itself: bracketed on the hazard axis by 4 and 0.25 at detection 10.
    let (v4, v025) = (6.22922, 4.35776);
    let want = v4 + (1.0 - 4.0) / (0.25 - 4.0) * (v025 - v4);
    let got = r.per_point.iter().find(|q| q.knobs == [1.0, 10.0]).unwrap();
    assert!(
        (got.predicted_w - want).abs() < 1e-12,
        "{} vs {want}",
        got.predicted_w
    );
    assert!((got.abs_pct_error - (want - 4.99916f64).abs() / 4.99916 * 100.0).abs() < 1e-9);
    let w = (1.0f64.ln() - 4.0f64.ln()) / (0.25f64.ln() - 4.0f64.ln());
    let r = leave_one_out_profile(&p, AxisScale::Log).unwrap();
    let got = r.per_point.iter().find(|q| q.knobs == [1.0, 10.0]).unwrap();
    assert!((got.predicted_w - (v4 + w * (v025 - v4))).abs() < 1e-12);
    let mean = r.per_point.iter().map(|q| q.abs_pct_error).sum::<f64>() / 8.0;
    assert!((r.mape_pct - mean).abs() < 1e-12);
}

/// The 5×5 CNN grid, `knob1,knob2,W` rows.
fn cnn_grid(text: &str) -> Vec<(Vec<f64>, f64)> {
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|c| c.trim().parse().unwrap()).collect();
            (vec![v[0], v[1]], v[2])
        })
        .collect()
}

#[test]
fn seed_loo_prefers_the_default_scale() {
    type Grid = (&'static str, Vec<String>, Vec<(Vec<f64>, f64)>);
    let mut grids: Vec<Grid> = ["tracking.toml", "landing.toml", "landing-kernel22.toml"]
        .iter()
        .map(|f| {
            let p = shipped_profile(f);
            (*f, p.knobs.clone(), p.power_points())
        })
        .collect();
    if let Some(text) = seed_file("jetson-nano-cnn-grid/computational_energy.csv") {
        grids.push((
            "computational_energy.csv",
            vec!["cnn.rate_fps".into(), "cnn.knob2".into()],
            cnn_grid(&text),
        ));
    }
    // Criterion: the mean absolute percentage error over the leave-one-out predictions
    // made by interpolation (a neighbour on both sides along some axis), pooled over the
    // grids. The axis scale exists for interpolation between measured points; the other
    // predictions (grid ends) come from the affine fallback, which a fully measured grid
    // never uses. The all-point figures are printed too.
    let mut interpolated = [Vec::new(), Vec::new()];
    let mut all = [Vec::new(), Vec::new()];
    for (name, knobs, points) in &grids {
        let mut line = format!("LOO {name}:");
        for (s, scale) in [AxisScale::Linear, AxisScale::Log].into_iter().enumerate() {
            let r = leave_one_out(knobs, points, scale).unwrap();
            let between: Vec<f64> = r
                .per_point
                .iter()
                .filter(|p| {
                    p.knobs.iter().enumerate().any(|(k, v)| {
                        points.iter().any(|q| q.0[k] < *v) && points.iter().any(|q| q.0[k] > *v)
                    })
                })
                .map(|p| p.abs_pct_error)
                .collect();
            line += &format!(
                " {scale:?} all {} points {:.2} %, interpolated {} points {:.2} %;",
                r.per_point.len(),
                r.mape_pct,
                between.len(),
                between.iter().sum::<f64>() / between.len().max(1) as f64,
            );
            interpolated[s].extend(between);
            all[s].extend(r.per_point.iter().map(|p| p.abs_pct_error));
        }
        eprintln!("{line}");
    }
    let mape = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    let (lin, log) = (mape(&interpolated[0]), mape(&interpolated[1]));
    eprintln!(
        "LOO pooled, interpolated {} points: Linear {lin:.3} %, Log {log:.3} %; all {} points: Linear {:.3} %, Log {:.3} %",
        interpolated[0].len(),
        all[0].len(),
        mape(&all[0]),
        mape(&all[1])
    );
    let (default, other) = match AxisScale::default() {
        AxisScale::Log => (log, lin),
        AxisScale::Linear => (lin, log),
    };
    assert!(
        default <= other,
        "default scale {:?} interpolates worse on the seed grids",
        AxisScale::default()
    );
}
