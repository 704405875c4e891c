use super::*;
use crate::vision::render::SplitMix64;

fn gaussian3(rng: &mut SplitMix64, std: f64) -> Vector3<f64> {
    Vector3::new(
        rng.next_gaussian(),
        rng.next_gaussian(),
        rng.next_gaussian(),
    ) * std
}

/// Wilson–Hilferty approximation of the chi-square quantile for `dof` degrees of freedom at
/// standard-normal quantile `z`.
fn chi2_quantile(dof: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + z * a.sqrt()).powi(3)
}

struct Scenario {
    /// Platform velocity (NED) as a function of time.
    platform_velocity: fn(f64) -> Vector3<f64>,
    fix_std_m: f64,
    delay_s: f64,
    drop_every: usize,
    compensate_delay: bool,
}

struct RunStats {
    first_error_m: f64,
    final_error_m: f64,
    /// √(mean trace P) over the second half: the error the filter claims.
    predicted_rms_late_m: f64,
    rms_error_late_m: f64,
    nees: Vec<f64>,
}

/// The truth follows the filter's model: the relative position moves with the known inputs
/// plus a random walk of intensity q (what the imperfect velocity inputs leave over).
fn run(scenario: &Scenario, config: TrackerConfig, seed: u64, steps: usize) -> RunStats {
    let mut rng = SplitMix64::new(seed);
    let dt_s = 0.02; // 50 Hz autopilot telemetry
    let frame_every = 3; // ≈ 17 fps camera
    let mut tracker = Tracker::new(config).unwrap();
    let mut truth = Vector3::new(6.0, -4.0, -10.0);
    let mut truth_log: Vec<(f64, Vector3<f64>)> = vec![];
    let fix_cov = Matrix3::identity() * scenario.fix_std_m.powi(2);
    // A poor first fix (σ = 2 m per axis), so convergence shows.
    tracker
        .correct(&VisionFix {
            capture_time_s: 0.0,
            uav_relative_ned_m: truth + gaussian3(&mut rng, 2.0),
            covariance_m2: Matrix3::identity() * 4.0,
        })
        .unwrap();
    let mut pending: Vec<VisionFix> = vec![];
    let mut nees = vec![];
    let mut errors = vec![];
    let mut traces = vec![];
    let delay_steps = (scenario.delay_s / dt_s).round() as usize;
    for k in 1..=steps {
        let t = k as f64 * dt_s;
        let uav_velocity = Vector3::new((0.5 * t).sin() * 2.0, 1.0, 0.2);
        let input = MotionInput {
            uav_velocity_ned_m_s: uav_velocity,
            uav_acceleration_ned_m_s2: Vector3::zeros(),
            platform_velocity_ned_m_s: (scenario.platform_velocity)(t),
        };
        truth += (uav_velocity - input.platform_velocity_ned_m_s) * dt_s
            + gaussian3(&mut rng, (config.process_noise_m2_per_s * dt_s).sqrt());
        truth_log.push((t, truth));
        tracker.predict(t, &input).unwrap();
        // A frame captured now is delivered `delay_s` later, unless dropped.
        if k % frame_every == 0 && (k / frame_every) % scenario.drop_every != 0 {
            pending.push(VisionFix {
                capture_time_s: t,
                uav_relative_ned_m: truth + gaussian3(&mut rng, scenario.fix_std_m),
                covariance_m2: fix_cov,
            });
        }
        let due: Vec<VisionFix> = pending
            .iter()
            .copied()
            .filter(|f| ((t - f.capture_time_s) / dt_s).round() as usize >= delay_steps)
            .collect();
        pending.retain(|f| (((t - f.capture_time_s) / dt_s).round() as usize) < delay_steps);
        for mut fix in due {
            if !scenario.compensate_delay {
                fix.capture_time_s = t;
            }
            tracker.correct(&fix).unwrap();
        }
        let est = tracker.estimate().unwrap();
        let e = est.uav_relative_ned_m - truth;
        errors.push(e.norm());
        traces.push(est.covariance_m2.trace());
        nees.push(e.dot(&(est.covariance_m2.try_inverse().unwrap() * e)));
    }
    let late = &errors[steps / 2..];
    RunStats {
        first_error_m: errors[0],
        final_error_m: *errors.last().unwrap(),
        predicted_rms_late_m: (traces[steps / 2..].iter().sum::<f64>()
            / (steps - steps / 2) as f64)
            .sqrt(),
        rms_error_late_m: (late.iter().map(|e| e * e).sum::<f64>() / late.len() as f64).sqrt(),
        nees,
    }
}

fn constant_velocity(_t: f64) -> Vector3<f64> {
    Vector3::new(3.0, 0.0, 0.0)
}

/// A tractor at 3 m/s turning through 180° between 4 s and 4 + π·2 s (radius 6 m).
fn turning(t: f64) -> Vector3<f64> {
    let heading = ((t - 4.0).clamp(0.0, std::f64::consts::PI * 2.0)) * 0.5;
    Vector3::new(heading.cos(), heading.sin(), 0.0) * 3.0
}

fn scenario(platform_velocity: fn(f64) -> Vector3<f64>) -> Scenario {
    Scenario {
        platform_velocity,
        fix_std_m: 0.15,
        delay_s: 0.1,
        drop_every: 4,
        compensate_delay: true,
    }
}

/// With the platform's velocity given exactly, the two paths give the same error (the filter
/// is linear in its inputs); the turn with an *estimated* platform velocity is tested in
/// `platform_velocity`.
#[test]
fn error_converges_with_noisy_delayed_dropped_fixes() {
    let config = TrackerConfig::default();
    for (name, velocity) in [
        ("constant", constant_velocity as fn(f64) -> Vector3<f64>),
        ("turning", turning),
    ] {
        let stats = run(&scenario(velocity), config, 7, 1000);
        // Fixes σ = 0.15 m per axis at ~13 fps, 0.1 s late, one in four dropped: the steady
        // error must beat one fix's 3-D error (0.15·√3 ≈ 0.26 m) and match the covariance.
        let (rms, claimed) = (stats.rms_error_late_m, stats.predicted_rms_late_m);
        assert!(rms < 0.26, "{name}: rms {rms}");
        assert!(
            (rms / claimed - 1.0).abs() < 0.15,
            "{name}: {rms} vs {claimed}"
        );
        assert!(
            stats.first_error_m > 1.0 && stats.final_error_m < 0.5,
            "{name}: {} → {}",
            stats.first_error_m,
            stats.final_error_m
        );
        eprintln!(
            "{name}: rms {rms:.3} m, claimed {claimed:.3} m, first {:.2} m",
            stats.first_error_m
        );
    }
}

#[test]
fn nees_is_consistent_over_monte_carlo_runs() {
    let config = TrackerConfig::default();
    let runs = 40;
    let steps = 500;
    let mut mean_nees = vec![0.0; steps];
    for seed in 0..runs {
        let stats = run(&scenario(turning), config, 100 + seed, steps);
        for (m, n) in mean_nees.iter_mut().zip(stats.nees) {
            *m += n / runs as f64;
        }
    }
    // Σ over runs of NEES ~ χ²(3·runs) per step; 95 % two-sided band.
    let dof = 3.0 * runs as f64;
    let (lo, hi) = (
        chi2_quantile(dof, -1.96) / runs as f64,
        chi2_quantile(dof, 1.96) / runs as f64,
    );
    let inside = mean_nees.iter().filter(|n| (lo..=hi).contains(*n)).count();
    let overall = mean_nees.iter().sum::<f64>() / steps as f64;
    assert!(
        inside as f64 >= 0.9 * steps as f64,
        "{inside}/{steps} inside [{lo:.2}, {hi:.2}]"
    );
    assert!((overall - 3.0).abs() < 0.3, "mean NEES {overall}");
    eprintln!("NEES: mean {overall:.3}, {inside}/{steps} steps inside [{lo:.2}, {hi:.2}]");
}

#[test]
fn delay_compensation_beats_applying_late_fixes_as_if_fresh() {
    let config = TrackerConfig {
        process_noise_m2_per_s: 0.01,
        ..TrackerConfig::default()
    };
    let mut with = scenario(turning);
    with.delay_s = 0.2;
    with.fix_std_m = 0.05;
    let without = Scenario {
        compensate_delay: false,
        ..with
    };
    let a = run(&with, config, 3, 1000).rms_error_late_m;
    let b = run(&without, config, 3, 1000).rms_error_late_m;
    assert!(a < 0.5 * b, "compensated {a} vs uncompensated {b}");
    eprintln!("delay 0.2 s: rms {a:.3} m compensated, {b:.3} m uncompensated");
}

/// A late fix applied through the history gives exactly what a filter would have given had
/// the fix arrived on time and the same inputs been predicted after it.
#[test]
fn a_late_fix_equals_an_on_time_fix_replayed() {
    let config = TrackerConfig::default();
    let input_at = |k: usize| MotionInput {
        uav_velocity_ned_m_s: Vector3::new(k as f64 * 0.1, -1.0, 0.3),
        uav_acceleration_ned_m_s2: Vector3::new(0.5, 0.0, -0.2),
        platform_velocity_ned_m_s: Vector3::new(2.0, 0.5, 0.0),
    };
    let first = VisionFix {
        capture_time_s: 0.0,
        uav_relative_ned_m: Vector3::new(3.0, 1.0, -9.0),
        covariance_m2: Matrix3::identity() * 0.3,
    };
    #[rustfmt::skip]
        let late_cov = Matrix3::new(
            0.02, 0.005, 0.0,
            0.005, 0.03, 0.0,
            0.0, 0.0, 0.05,
        );
    let late = |capture_time_s| VisionFix {
        capture_time_s,
        uav_relative_ned_m: Vector3::new(2.6, 0.9, -8.8),
        covariance_m2: late_cov,
    };
    // On a prediction boundary (t = 0.1) and inside an interval without acceleration
    // (t = 0.13, where the held input makes interpolation exact).
    for (capture_s, zero_acceleration) in [(0.1, false), (0.13, true)] {
        let input = |k| {
            let mut i = input_at(k);
            if zero_acceleration {
                i.uav_acceleration_ned_m_s2 = Vector3::zeros();
            }
            i
        };
        let times: Vec<f64> = (1..=10).map(|k| k as f64 * 0.02).collect();
        let mut delayed = Tracker::new(config).unwrap();
        delayed.correct(&first).unwrap();
        for (k, t) in times.iter().enumerate() {
            delayed.predict(*t, &input(k)).unwrap();
        }
        delayed.correct(&late(capture_s)).unwrap();
        let mut on_time = Tracker::new(config).unwrap();
        on_time.correct(&first).unwrap();
        for (k, t) in times.iter().enumerate() {
            if *t > capture_s && on_time.estimate().unwrap().time_s < capture_s {
                on_time.predict(capture_s, &input(k)).unwrap();
                on_time.correct(&late(capture_s)).unwrap();
            }
            on_time.predict(*t, &input(k)).unwrap();
            if *t == capture_s {
                on_time.correct(&late(capture_s)).unwrap();
            }
        }
        let (a, b) = (delayed.estimate().unwrap(), on_time.estimate().unwrap());
        assert!(
            (a.uav_relative_ned_m - b.uav_relative_ned_m).norm() < 1e-12,
            "{capture_s}: {a:?} vs {b:?}"
        );
        assert!((a.covariance_m2 - b.covariance_m2).norm() < 1e-12);
    }
}

#[test]
fn an_outlier_is_gated_and_leaves_the_state_alone() {
    let mut tracker = Tracker::new(TrackerConfig::default()).unwrap();
    let cov = Matrix3::identity() * 0.01;
    let start = Vector3::new(1.0, 2.0, -8.0);
    let fix = |t: f64, p: Vector3<f64>| VisionFix {
        capture_time_s: t,
        uav_relative_ned_m: p,
        covariance_m2: cov,
    };
    assert_eq!(
        tracker.correct(&fix(0.0, start)).unwrap(),
        FixOutcome::Initialized
    );
    tracker.predict(0.1, &MotionInput::default()).unwrap();
    let before = tracker.estimate().unwrap();
    // 3 m off with σ ≈ 0.14 m: NIS ≈ 9 / 0.025 = 360 ≫ 11.3.
    let outcome = tracker
        .correct(&fix(0.1, start + Vector3::new(3.0, 0.0, 0.0)))
        .unwrap();
    assert!(matches!(outcome, FixOutcome::Rejected { nis } if nis > 300.0));
    assert_eq!(tracker.estimate().unwrap(), before);
    // A consistent fix passes, with the closed-form gain P/(P + R) per axis.
    let outcome = tracker
        .correct(&fix(0.1, start + Vector3::new(0.1, 0.0, 0.0)))
        .unwrap();
    assert!(matches!(outcome, FixOutcome::Accepted { .. }));
    let p = 0.01 + 0.1 * TrackerConfig::default().process_noise_m2_per_s;
    let k = p / (p + 0.01);
    let est = tracker.estimate().unwrap();
    assert!((est.uav_relative_ned_m.x - (1.0 + 0.1 * k)).abs() < 1e-12);
    assert!((est.covariance_m2[(0, 0)] - (1.0 - k) * p).abs() < 1e-12);
}

/// A platform that starts moving while fixes are slow: the prediction lags, every fix
/// is gated, and after two in a row the filter restarts at the latest one (carried to
/// the present), then accepts the next consistent fix. Restarts can be switched off.
#[test]
fn persistent_rejections_restart_the_filter_at_the_fixes() {
    let cov = Matrix3::identity() * 0.01;
    let fix = |t: f64, north_m: f64| VisionFix {
        capture_time_s: t,
        uav_relative_ned_m: Vector3::new(north_m, 0.0, -7.5),
        covariance_m2: cov,
    };
    for restart_after_rejections in [2, 0] {
        let config = TrackerConfig {
            restart_after_rejections,
            ..TrackerConfig::default()
        };
        let mut tracker = Tracker::new(config).unwrap();
        tracker.correct(&fix(0.0, 0.0)).unwrap();
        // The UAV hovers; the platform runs away north at 1.5 m/s, fixes every 0.5 s.
        let mut outcomes = Vec::new();
        for k in 1..=4 {
            let t = 0.5 * k as f64;
            tracker.predict(t + 0.05, &MotionInput::default()).unwrap();
            outcomes.push(tracker.correct(&fix(t, -1.5 * t)).unwrap());
        }
        if restart_after_rejections == 0 {
            assert!(outcomes
                .iter()
                .all(|o| matches!(o, FixOutcome::Rejected { .. })));
            continue;
        }
        assert!(
            matches!(outcomes[0], FixOutcome::Rejected { .. }),
            "{outcomes:?}"
        );
        assert!(matches!(outcomes[1], FixOutcome::Restarted { .. }));
        // The count starts over after a restart: the next gated fix is only rejected.
        assert!(matches!(outcomes[2], FixOutcome::Rejected { .. }));
        assert!(matches!(outcomes[3], FixOutcome::Restarted { .. }));
        // Restarted at the 2 s fix (−3 m); no motion input, nothing carried since.
        let est = tracker.estimate().unwrap();
        assert!((est.uav_relative_ned_m.x + 3.0).abs() < 1e-9, "{est:?}");
    }
}

/// At 10 fps, with restarts only after 1 s of gated fixes: two false detections in a row
/// (the pad seen 5 m off) are rejected and do not move the estimate; a pad truly 5 m off
/// for a second restarts it there.
#[test]
fn a_restart_needs_the_gated_fixes_to_span_the_configured_time() {
    let cov = Matrix3::identity() * 0.01;
    let fix = |t: f64, east_m: f64| VisionFix {
        capture_time_s: t,
        uav_relative_ned_m: Vector3::new(0.0, east_m, -7.5),
        covariance_m2: cov,
    };
    let config = TrackerConfig {
        restart_after_rejected_s: 1.0,
        ..TrackerConfig::default()
    };
    let mut tracker = Tracker::new(config).unwrap();
    tracker.correct(&fix(0.0, 0.0)).unwrap();
    let mut step = |t: f64, east_m: f64| {
        tracker.predict(t + 0.01, &MotionInput::default()).unwrap();
        let outcome = tracker.correct(&fix(t, east_m)).unwrap();
        (outcome, tracker.estimate().unwrap().uav_relative_ned_m.y)
    };
    for (t, east_m) in [(0.1, 5.0), (0.2, 5.0)] {
        let (outcome, estimate_m) = step(t, east_m);
        assert!(
            matches!(outcome, FixOutcome::Rejected { .. }),
            "{outcome:?}"
        );
        assert!(estimate_m.abs() < 1e-9, "moved to {estimate_m}");
    }
    // The true pad again: accepted, and the count starts over.
    assert!(matches!(step(0.3, 0.0).0, FixOutcome::Accepted { .. }));
    let mut restarted_at = None;
    for k in 4..=20 {
        let t = 0.1 * k as f64;
        if let (FixOutcome::Restarted { .. }, estimate_m) = step(t, 5.0) {
            restarted_at = Some((t, estimate_m));
            break;
        }
    }
    let (t, estimate_m) = restarted_at.expect("a second of consistent fixes restarts");
    assert!((t - 1.4).abs() < 1e-9, "restarted at {t} s");
    assert!((estimate_m - 5.0).abs() < 1e-9);
}

/// Gated fixes close to the prediction are the prediction lagging (a turn): with
/// `quick_restart_within_m` they restart the filter at the second, while fixes further
/// off still need the span.
#[test]
fn gated_fixes_near_the_prediction_restart_at_once() {
    let fix = |t: f64, east_m: f64| VisionFix {
        capture_time_s: t,
        uav_relative_ned_m: Vector3::new(0.0, east_m, -7.5),
        covariance_m2: Matrix3::identity() * 0.01,
    };
    let mut tracker = Tracker::new(TrackerConfig {
        restart_after_rejected_s: 1.0,
        quick_restart_within_m: 1.5,
        ..TrackerConfig::default()
    })
    .unwrap();
    tracker.correct(&fix(0.0, 0.0)).unwrap();
    let mut step = |t: f64, east_m: f64| {
        tracker.predict(t + 0.01, &MotionInput::default()).unwrap();
        tracker.correct(&fix(t, east_m)).unwrap()
    };
    // 1.2 m off: gated (σ 0.1 m), and the second restarts.
    assert!(matches!(step(0.1, 1.2), FixOutcome::Rejected { .. }));
    assert!(matches!(step(0.2, 1.2), FixOutcome::Restarted { .. }));
    // From there, 5 m off twice: rejected both times.
    assert!(matches!(step(0.3, 6.2), FixOutcome::Rejected { .. }));
    assert!(matches!(step(0.4, 6.2), FixOutcome::Rejected { .. }));
    // One near fix after a far one in the same run does not make the run quick.
    assert!(matches!(step(0.5, 2.0), FixOutcome::Rejected { .. }));
}

#[test]
fn prediction_follows_equation_one_and_grows_the_covariance() {
    let config = TrackerConfig::default();
    let mut tracker = Tracker::new(config).unwrap();
    tracker
        .correct(&VisionFix {
            capture_time_s: 1.0,
            uav_relative_ned_m: Vector3::zeros(),
            covariance_m2: Matrix3::identity() * 0.04,
        })
        .unwrap();
    let input = MotionInput {
        uav_velocity_ned_m_s: Vector3::new(2.0, 1.0, 0.0),
        uav_acceleration_ned_m_s2: Vector3::new(0.0, 2.0, 0.0),
        platform_velocity_ned_m_s: Vector3::new(3.0, 0.0, 0.0),
    };
    // Frames missed for 2 s: it keeps predicting.
    for k in 1..=100 {
        tracker.predict(1.0 + k as f64 * 0.02, &input).unwrap();
    }
    let est = tracker.estimate().unwrap();
    // Per step: x += (2 − 3)·0.02; y += 1·0.02 + ½·2·0.02².
    let want = Vector3::new(-2.0, 100.0 * (0.02 + 0.0004), 0.0);
    assert!((est.uav_relative_ned_m - want).norm() < 1e-9, "{est:?}");
    assert!(
        (est.covariance_m2[(0, 0)] - (0.04 + 2.0 * config.process_noise_m2_per_s)).abs() < 1e-9
    );
}

#[test]
fn bad_input_is_a_named_error_and_stale_fixes_are_ignored() {
    assert!(matches!(
        Tracker::new(TrackerConfig {
            process_noise_m2_per_s: -1.0,
            ..TrackerConfig::default()
        }),
        Err(TrackerError::ProcessNoise { .. })
    ));
    assert!(matches!(
        Tracker::new(TrackerConfig {
            gate_nis: f64::NAN,
            ..TrackerConfig::default()
        }),
        Err(TrackerError::Gate { .. })
    ));
    let error = Tracker::new(TrackerConfig {
        restart_after_rejected_s: -1.0,
        ..TrackerConfig::default()
    })
    .unwrap_err();
    assert_eq!(error, TrackerError::RestartSpan { span_s: -1.0 });
    assert!(error.to_string().contains("restart_after_rejected_s"));
    let error = Tracker::new(TrackerConfig {
        quick_restart_within_m: f64::NAN,
        ..TrackerConfig::default()
    })
    .unwrap_err();
    assert!(
        matches!(error, TrackerError::QuickRestart { .. }),
        "{error}"
    );
    assert!(error.to_string().contains("quick_restart_within_m"));
    let mut tracker = Tracker::new(TrackerConfig::default()).unwrap();
    assert_eq!(
        tracker.predict(0.0, &MotionInput::default()),
        Err(TrackerError::NotInitialized)
    );
    let good = VisionFix {
        capture_time_s: 0.0,
        uav_relative_ned_m: Vector3::zeros(),
        covariance_m2: Matrix3::identity(),
    };
    let not_pd = VisionFix {
        covariance_m2: -Matrix3::identity(),
        ..good
    };
    assert_eq!(tracker.correct(&not_pd), Err(TrackerError::Covariance));
    let nan = VisionFix {
        uav_relative_ned_m: Vector3::new(f64::NAN, 0.0, 0.0),
        ..good
    };
    assert_eq!(tracker.correct(&nan), Err(TrackerError::NotFinite));
    tracker.correct(&good).unwrap();
    for k in 1..=100 {
        tracker
            .predict(k as f64 * 0.01, &MotionInput::default())
            .unwrap();
    }
    assert!(matches!(
        tracker.predict(0.5, &MotionInput::default()),
        Err(TrackerError::TimeBackwards { .. })
    ));
    // Older than the 0.5 s history.
    let old = VisionFix {
        capture_time_s: 0.2,
        ..good
    };
    assert_eq!(tracker.correct(&old).unwrap(), FixOutcome::Stale);
    // Out of order: a fix before one already applied.
    let later = VisionFix {
        capture_time_s: 0.9,
        ..good
    };
    assert!(matches!(
        tracker.correct(&later).unwrap(),
        FixOutcome::Accepted { .. }
    ));
    let earlier = VisionFix {
        capture_time_s: 0.8,
        ..good
    };
    assert_eq!(tracker.correct(&earlier).unwrap(), FixOutcome::Stale);
    let future = VisionFix {
        capture_time_s: 1.5,
        ..good
    };
    assert!(matches!(
        tracker.correct(&future),
        Err(TrackerError::TimeBackwards { .. })
    ));
}
