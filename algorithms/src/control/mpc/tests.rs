use super::*;
use crate::control::point_mass::{PointMass, PointMassConfig};
use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

#[test]
fn a_solver_setup_error_keeps_clarabels_error() {
    let clarabel = DefaultSettingsBuilder::<f64>::default()
        .direct_solve_method("no-such-method".to_string())
        .build()
        .unwrap_err();
    let message = clarabel.to_string();
    let error = MpcError::Setup(SolverSetupError::new(clarabel));
    assert_eq!(
        error.to_string(),
        format!("MPC solver setup failed: {message}")
    );
    let cause = std::error::Error::source(&error).expect("clarabel's error");
    assert_eq!(cause.to_string(), message);
    // Shared, not copied: a clone is the same error, another error with the same text is not.
    assert_eq!(error.clone(), error);
    let again = DefaultSettingsBuilder::<f64>::default()
        .direct_solve_method("no-such-method".to_string())
        .build()
        .unwrap_err();
    assert_ne!(MpcError::Setup(SolverSetupError::new(again)), error);
}

/// The cost of a correction sequence on one axis by an independent rollout: the lag's
/// continuous solution step by step in the original variables (absolute setpoints, the
/// pad's position), not through the condensed matrices.
fn rollout_cost(c: &MpcConfig, x: &MpcInput, previous: f64, axis: usize, d: &[f64]) -> f64 {
    let tau = c.velocity_time_constant_s;
    let mut p = x.uav_minus_pad_ne_m[axis] - x.setpoint_ne_m[axis];
    let mut pad = 0.0;
    let mut v = x.uav_velocity_ne_m_s[axis];
    let (vp0, ap0) = (
        x.platform_velocity_ne_m_s[axis],
        x.platform_accel_ne_m_s2[axis],
    );
    let mut prev_u = previous;
    let mut cost = 0.0;
    for (k, dk) in d.iter().enumerate() {
        let t0 = k as f64 * c.dt_s;
        let vpk = vp0 + ap0 * t0.min(c.platform_accel_horizon_s);
        let u = vpk + dk;
        // Continuous solution of v' = (u − v)/τ over dt.
        let decay = (-c.dt_s / tau).exp();
        p += u * c.dt_s + (v - u) * tau * (1.0 - decay);
        v = u + (v - u) * decay;
        let vpk1 = vp0 + ap0 * (t0 + c.dt_s).min(c.platform_accel_horizon_s);
        pad += 0.5 * c.dt_s * (vpk + vpk1);
        cost += c.weight(k) * (p - pad).powi(2)
            + c.effort_weight * dk * dk
            + c.rate_weight * (u - prev_u).powi(2);
        prev_u = u;
    }
    0.5 * cost
}

fn random_input(rng: &mut StdRng, scale: f64) -> MpcInput {
    let mut r2 = |s: f64| Vector2::new(rng.random_range(-s..s), rng.random_range(-s..s));
    MpcInput {
        uav_minus_pad_ne_m: r2(5.0 * scale),
        setpoint_ne_m: r2(0.2 * scale),
        uav_velocity_ne_m_s: r2(2.0 * scale),
        platform_velocity_ne_m_s: r2(3.0 * scale),
        platform_accel_ne_m_s2: r2(1.5 * scale),
    }
}

/// Tests of what the solver computes give it ample time: on a loaded 2-core CI machine a
/// solve can pass the flight default of 5 ms, and the time bound has its own test.
const SOLUTION_TESTS_TIME_LIMIT_S: f64 = 1.0;

#[test]
// The axis indexes the input's vectors and the plan's entries alike.
#[allow(clippy::needless_range_loop)]
fn unconstrained_solution_matches_an_independent_quadratic() {
    let config = MpcConfig {
        max_speed_m_s: 1e4,
        max_accel_m_s2: 1e5,
        solve_time_limit_s: SOLUTION_TESTS_TIME_LIMIT_S,
        ..MpcConfig::default()
    };
    let n = config.horizon_steps;
    let mut rng = StdRng::seed_from_u64(1);
    for _ in 0..10 {
        let input = random_input(&mut rng, 0.3);
        let mut mpc = MpcController::new(config).unwrap();
        mpc.step(&input).unwrap();
        let plan = mpc.plan().to_vec();
        for axis in 0..2 {
            let previous = input.uav_velocity_ne_m_s[axis];
            // The quadratic's Hessian and gradient at 0 from the rollout, by exact
            // second differences (the cost is quadratic).
            let j = |d: &[f64]| rollout_cost(&config, &input, previous, axis, d);
            let zero = vec![0.0; n];
            let j0 = j(&zero);
            let unit = |i: usize, s: f64| {
                let mut d = zero.clone();
                d[i] = s;
                d
            };
            let mut h = DMatrix::zeros(n, n);
            let mut f = DVector::zeros(n);
            for i in 0..n {
                f[i] = 0.5 * (j(&unit(i, 1.0)) - j(&unit(i, -1.0)));
                for k in 0..n {
                    let mut d = unit(i, 1.0);
                    d[k] += 1.0;
                    h[(i, k)] = j(&d) - j(&unit(i, 1.0)) - j(&unit(k, 1.0)) + j0;
                }
            }
            let d_star = h.lu().solve(&(-f)).unwrap();
            for k in 0..n {
                let vp = config.platform_velocity(
                    input.platform_velocity_ne_m_s[axis],
                    input.platform_accel_ne_m_s2[axis],
                    k,
                );
                let got = plan[k][axis] - vp;
                assert!(
                    (got - d_star[k]).abs() < 1e-5,
                    "axis {axis} step {k}: clarabel {got}, closed form {}",
                    d_star[k]
                );
            }
        }
    }
}

#[test]
fn limits_hold_in_every_plan() {
    let config = MpcConfig {
        solve_time_limit_s: SOLUTION_TESTS_TIME_LIMIT_S,
        ..MpcConfig::default()
    };
    let du_max = config.max_accel_m_s2 * config.dt_s;
    let tol = 1e-6;
    let mut rng = StdRng::seed_from_u64(7);
    let mut mpc = MpcController::new(config).unwrap();
    let mut active = 0;
    for i in 0..300 {
        if i % 10 == 0 {
            mpc.reset();
        }
        let input = random_input(&mut rng, 2.0);
        let previous = mpc
            .previous_command
            .unwrap_or(input.uav_velocity_ne_m_s)
            .map(|x| x.clamp(-config.max_speed_m_s, config.max_speed_m_s));
        let out = mpc.step(&input).unwrap();
        let mut prev = previous;
        for u in mpc.plan() {
            for axis in 0..2 {
                assert!(u[axis].abs() <= config.max_speed_m_s + tol, "speed {u:?}");
                assert!((u[axis] - prev[axis]).abs() <= du_max + tol, "rate {u:?}");
                if (u[axis] - prev[axis]).abs() > du_max - 1e-3
                    || u[axis].abs() > config.max_speed_m_s - 1e-3
                {
                    active += 1;
                }
            }
            prev = *u;
        }
        let v = out.velocity_ne_m_s;
        assert!(v.iter().all(|x| x.abs() <= config.max_speed_m_s));
        assert!((v - previous).iter().all(|x| x.abs() <= du_max + 1e-12));
    }
    // The random states are far enough out that the limits bind.
    assert!(active > 1000, "only {active} active constraints");
}

#[test]
fn bad_input_and_config_are_rejected_and_timeouts_fall_back() {
    assert!(MpcController::new(MpcConfig {
        dt_s: 0.0,
        ..MpcConfig::default()
    })
    .is_err());
    assert!(MpcController::new(MpcConfig {
        horizon_steps: 0,
        ..MpcConfig::default()
    })
    .is_err());
    let mut mpc = MpcController::new(MpcConfig::default()).unwrap();
    let mut input = MpcInput {
        uav_minus_pad_ne_m: Vector2::new(3.0, -2.0),
        setpoint_ne_m: Vector2::zeros(),
        uav_velocity_ne_m_s: Vector2::zeros(),
        platform_velocity_ne_m_s: Vector2::new(3.0, 0.0),
        platform_accel_ne_m_s2: Vector2::zeros(),
    };
    input.uav_velocity_ne_m_s.x = f64::NAN;
    assert_eq!(
        mpc.step(&input),
        Err(MpcError::NonFinite {
            name: "uav_velocity_ne_m_s"
        })
    );
    input.uav_velocity_ne_m_s.x = 0.0;

    // One iteration cannot converge: a named error with the rate-limited platform velocity.
    let mut starved = MpcController::new(MpcConfig {
        max_iterations: 1,
        ..MpcConfig::default()
    })
    .unwrap();
    let err = starved.step(&input).unwrap_err();
    assert!(matches!(err, MpcError::IterationLimit { .. }), "{err}");
    let du = MpcConfig::default().max_accel_m_s2 * MpcConfig::default().dt_s;
    assert_eq!(err.fallback_ne_m_s(), Some(Vector2::new(du, 0.0)));

    let mut hurried = MpcController::new(MpcConfig {
        solve_time_limit_s: 1e-9,
        ..MpcConfig::default()
    })
    .unwrap();
    let err = hurried.step(&input).unwrap_err();
    assert!(matches!(err, MpcError::TimeLimit { .. }), "{err}");
    assert!(err.fallback_ne_m_s().is_some());

    // After a good step the first fallback is the old plan's next setpoint, the second
    // the platform's velocity.
    let out = mpc.step(&input).unwrap();
    let next = mpc.plan()[1];
    let settings = mpc.solver.settings().clone();
    let mut starving = settings.clone();
    starving.max_iter = 1;
    mpc.solver.update_settings(starving).unwrap();
    let first = mpc.step(&input).unwrap_err().fallback_ne_m_s().unwrap();
    let expected = next.zip_map(&out.velocity_ne_m_s, |u, p| u.clamp(p - du, p + du));
    assert!(
        (first - expected).norm() < 1e-12,
        "{first:?} vs {expected:?}"
    );
    let second = mpc.step(&input).unwrap_err().fallback_ne_m_s().unwrap();
    let expected = input
        .platform_velocity_ne_m_s
        .zip_map(&first, |u, p| u.clamp(p - du, p + du));
    assert!((second - expected).norm() < 1e-12);
    mpc.solver.update_settings(settings).unwrap();
    assert!(mpc.step(&input).is_ok());
}

// The same 3 m/s path with a 180° turn as the PID's closed-loop test.
use crate::control::closed_loop_tests::platform;

/// Follows the pad from 4 m behind and 3 m aside while descending at 0.4 m/s from 5 m;
/// returns the horizontal error at touchdown and the solve times.
fn fly(turn_start_s: f64, noise_std_m: f64, seed: u64, solve_times: &mut Vec<f64>) -> f64 {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut gaussian = move || {
        let u1: f64 = 1.0 - rng.random::<f64>();
        let u2: f64 = rng.random::<f64>();
        (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
    };
    // What is tested is the landing, not this machine's speed (see SOLUTION_TESTS_TIME_LIMIT_S).
    let config = MpcConfig {
        solve_time_limit_s: SOLUTION_TESTS_TIME_LIMIT_S,
        ..MpcConfig::default()
    };
    let du_max = config.max_accel_m_s2 * config.dt_s;
    let mut mpc = MpcController::new(config).unwrap();
    let mut vehicle =
        PointMass::new(PointMassConfig::default(), Vector3::new(-4.0, 3.0, -5.0)).unwrap();
    let physics_dt_s = 0.005;
    let control_every = (config.dt_s / physics_dt_s).round() as usize;
    let mut setpoint = Vector3::zeros();
    let mut previous: Option<Vector2<f64>> = None;
    for k in 0..(60.0 / physics_dt_s) as usize {
        let t_s = k as f64 * physics_dt_s;
        let (pad, pad_velocity) = platform(t_s, turn_start_s);
        let error = vehicle.position_ned_m.xy() - pad;
        if vehicle.position_ned_m.z >= 0.0 {
            return error.norm();
        }
        if k % control_every == 0 {
            let (_, ahead) = platform(t_s + 0.01, turn_start_s);
            let noise = Vector2::new(gaussian(), gaussian()) * noise_std_m;
            let started = Instant::now();
            let result = mpc.step(&MpcInput {
                uav_minus_pad_ne_m: error + noise,
                setpoint_ne_m: Vector2::zeros(),
                uav_velocity_ne_m_s: vehicle.velocity_ned_m_s.xy(),
                platform_velocity_ne_m_s: pad_velocity,
                platform_accel_ne_m_s2: (ahead - pad_velocity) / 0.01,
            });
            solve_times.push(started.elapsed().as_secs_f64());
            // A time-out on a loaded test machine flies the fallback, as the task would.
            let v = match result {
                Ok(out) => out.velocity_ne_m_s,
                Err(e) => e.fallback_ne_m_s().expect("a solver error"),
            };
            assert!(v.iter().all(|x| x.abs() <= config.max_speed_m_s));
            if let Some(p) = previous {
                assert!((v - p).iter().all(|x| x.abs() <= du_max + 1e-12));
            }
            previous = Some(v);
            let descend = if t_s >= 2.0 { 0.4 } else { 0.0 };
            setpoint = Vector3::new(v.x, v.y, descend);
        }
        vehicle.step(setpoint, physics_dt_s).unwrap();
    }
    panic!("no touchdown within 60 s");
}

#[test]
fn closed_loop_lands_on_a_turning_platform_within_15_cm() {
    let mut solve_times = Vec::new();
    let mut worst_m: f64 = 0.0;
    for half_seconds in 0..=28 {
        let turn_start_s = half_seconds as f64 * 0.5;
        for (noise_std_m, seed) in [(0.0, 0), (0.03, half_seconds)] {
            let error_m = fly(turn_start_s, noise_std_m, seed, &mut solve_times);
            if half_seconds % 4 == 0 {
                println!(
                    "turn at {turn_start_s:>4.1} s, noise {noise_std_m:.2} m: \
                         touchdown error {error_m:.3} m"
                );
            }
            worst_m = worst_m.max(error_m);
        }
    }
    let straight_m = fly(1e6, 0.0, 0, &mut solve_times);
    println!("straight line: touchdown error {straight_m:.3} m");
    solve_times.sort_by(f64::total_cmp);
    let pct = |p: f64| solve_times[((solve_times.len() - 1) as f64 * p) as usize] * 1e6;
    println!(
            "MPC N = {}, dt = {} s: step (q, b update + solve) p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs over {} solves",
            MpcConfig::default().horizon_steps,
            MpcConfig::default().dt_s,
            pct(0.5),
            pct(0.99),
            pct(1.0),
            solve_times.len()
        );
    println!("worst touchdown error {worst_m:.3} m");
    assert!(straight_m <= 0.05, "straight line: {straight_m:.3} m");
    assert!(worst_m <= 0.15, "worst touchdown error {worst_m:.3} m");
}
