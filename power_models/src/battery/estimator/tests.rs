use super::super::lipo_4s;
use super::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn gaussian(rng: &mut StdRng) -> f64 {
    // Box-Muller; 1 - u keeps the logarithm finite.
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random::<f64>();
    (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
}

// ---- estimator: synthetic data from the Rint model ---------------------------------------

struct Flight {
    samples: Vec<BatterySample>,
    true_soc: Vec<f64>,
    true_mah: Vec<f64>,
}

fn load_current_a(t: f64) -> f64 {
    let burst = if t % 120.0 < 5.0 { 10.0 } else { 0.0 };
    if t < 20.0 {
        30.0
    } else {
        12.0 + 4.0 * (t / 37.0 * std::f64::consts::TAU).sin()
            + 3.0 * (t / 11.0 * std::f64::consts::TAU).sin()
            + burst
    }
}

/// A flight drawn from the Rint model itself: irregular 0.2–0.4 s sampling, voltage noise
/// 0.04 V, current noise 0.1 A; the truth is integrated in 10 ms steps.
fn synthetic_flight(truth: &BatterySpec, soc0: f64, duration_s: f64, seed: u64) -> Flight {
    let mut rng = StdRng::seed_from_u64(seed);
    let (mut t, mut soc, mut mah) = (0.0, soc0, 0.0);
    let mut flight = Flight {
        samples: vec![],
        true_soc: vec![],
        true_mah: vec![],
    };
    while t < duration_s {
        let i = load_current_a(t);
        flight.samples.push(BatterySample {
            time_s: t,
            voltage_v: Some(truth.terminal_voltage_v(soc, i) + 0.04 * gaussian(&mut rng)),
            current_a: Some(i + 0.1 * gaussian(&mut rng)),
            consumed_mah: None,
            remaining_fraction: None,
        });
        flight.true_soc.push(soc);
        flight.true_mah.push(mah);
        let next = t + rng.random_range(0.2..0.4);
        while t < next {
            let h = (next - t).min(0.01);
            let d_mah = load_current_a(t + 0.5 * h) * h / 3.6;
            mah += d_mah;
            soc -= d_mah / truth.capacity_mah;
            t += h;
        }
    }
    flight
}

/// Runs the estimator; returns (max |error| after `settle_s`, RMS after, final error,
/// final estimate).
fn track(
    est: &mut BatteryEstimator,
    flight: &Flight,
    settle_s: f64,
) -> (f64, f64, f64, BatteryEstimate) {
    let (mut max_err, mut sum_sq, mut count) = (0.0_f64, 0.0, 0);
    let mut last = None;
    for (k, sample) in flight.samples.iter().enumerate() {
        let e = est.update(*sample).unwrap();
        let err = e.soc - flight.true_soc[k];
        if sample.time_s >= settle_s {
            max_err = max_err.max(err.abs());
            sum_sq += err * err;
            count += 1;
        }
        last = Some((e, err));
    }
    let (e, final_err) = last.unwrap();
    (max_err, (sum_sq / count as f64).sqrt(), final_err, e)
}

#[test]
fn estimator_recovers_true_soc_on_rint_synthetic_flight() {
    let truth = lipo_4s(5000.0, 0.03);
    for (seed, soc0) in [(1, 0.92), (2, 0.75), (3, 0.55)] {
        let flight = synthetic_flight(&truth, soc0, 700.0, seed);
        let mut est = BatteryEstimator::new(truth.clone()).unwrap();
        let (max_err, rms, final_err, last) = track(&mut est, &flight, 60.0);
        eprintln!(
            "synthetic soc0 {soc0}: max |err| {max_err:.4}, RMS {rms:.4}, final {final_err:+.4}, \
             sigma {:.4}, true final {:.3}",
            last.soc_sigma,
            flight.true_soc.last().unwrap()
        );
        // Voltage noise 0.01 V/cell on a curve as flat as 0.3 V per unit SoC is up to
        // 0.03 SoC per sample before averaging; after a minute the filter must be inside it.
        assert!(max_err < 0.03, "soc0 {soc0}: max error {max_err}");
        assert!(rms < 0.015, "soc0 {soc0}: RMS {rms}");
        // Its own integral: trapezoid over noisy 0.3 s samples of a current that swings
        // ±7 A within seconds: within 0.3 % of the true charge.
        let true_mah = *flight.true_mah.last().unwrap();
        assert!(
            (last.consumed_mah - true_mah).abs() < 3e-3 * true_mah,
            "{} vs {true_mah}",
            last.consumed_mah
        );
        // The reported energy is the model's own from the estimated SoC at the filtered power.
        let expect = truth.usable_energy_wh(last.power_w, last.soc, 0.0).unwrap();
        assert!((last.remaining_energy_wh - expect).abs() < 1e-9);
    }
}

#[test]
fn voltage_pulls_back_the_drift_of_a_wrong_capacity() {
    // The estimator believes 4000 mAh, the pack holds 5000: counting alone would read
    // 25 % more SoC drop than true.
    let truth = lipo_4s(5000.0, 0.03);
    let believed = lipo_4s(4000.0, 0.03);
    let flight = synthetic_flight(&truth, 0.9, 900.0, 7);
    let drop = flight.true_soc[0] - flight.true_soc.last().unwrap();
    let counting_only_err = drop * (5000.0 / 4000.0 - 1.0);
    let mut est = BatteryEstimator::new(believed).unwrap();
    let (max_err, _, final_err, _) = track(&mut est, &flight, 60.0);
    eprintln!(
        "wrong capacity: drop {drop:.3}, counting alone would err {counting_only_err:.3}, \
         fused max {max_err:.4} final {final_err:+.4}"
    );
    assert!(
        max_err < 0.5 * counting_only_err,
        "{max_err} vs {counting_only_err}"
    );
}

#[test]
fn voltage_only_telemetry_still_tracks_soc() {
    // No current, no consumed charge: SoC from uncompensated voltage alone. The unseen sag
    // (12 A·0.02 Ω/4 = 0.06 V/cell) reads 0.07 to 0.2 SoC low, depending on the curve's
    // slope; the smoothing (voltage sigma widened for the unknown load) averages the
    // bursts out and lags the other way. The bound says it stays usable, not exact.
    let truth = lipo_4s(5000.0, 0.02);
    let mut flight = synthetic_flight(&truth, 0.9, 600.0, 11);
    for s in &mut flight.samples {
        s.current_a = None;
    }
    let mut est = BatteryEstimator::new(truth).unwrap();
    let (max_err, rms, final_err, last) = track(&mut est, &flight, 120.0);
    eprintln!("voltage only: max {max_err:.4} RMS {rms:.4} final {final_err:+.4}");
    assert!(max_err < 0.12, "{max_err}");
    assert!(rms < 0.08, "{rms}");
    assert_eq!(last.charge_source, ChargeSource::Blind);
    assert_eq!(last.consumed_mah, 0.0);
}

#[test]
fn autopilot_remaining_is_used_only_without_voltage() {
    let spec = lipo_4s(5000.0, 0.03);
    let mut est = BatteryEstimator::new(spec.clone()).unwrap();
    for k in 0..100 {
        est.update(BatterySample {
            time_s: k as f64,
            remaining_fraction: Some(0.8),
            ..Default::default()
        })
        .unwrap();
    }
    assert!((est.soc() - 0.8).abs() < 0.01, "{}", est.soc());
    // With a voltage, a contradicting remaining is ignored: SoC follows the voltage.
    let mut est = BatteryEstimator::new(spec.clone()).unwrap();
    let v = spec.pack_ocv_v(0.4);
    for k in 0..100 {
        est.update(BatterySample {
            time_s: k as f64,
            voltage_v: Some(v),
            current_a: Some(0.0),
            remaining_fraction: Some(0.9),
            ..Default::default()
        })
        .unwrap();
    }
    assert!((est.soc() - 0.4).abs() < 0.01, "{}", est.soc());
}

// ---- estimator: counting, time, bad input -----------------------------------------------

fn current_sample(time_s: f64, current_a: f64) -> BatterySample {
    BatterySample {
        time_s,
        current_a: Some(current_a),
        ..Default::default()
    }
}

#[test]
fn trapezoid_is_exact_for_a_linear_current_over_irregular_steps() {
    let mut est = BatteryEstimator::new(lipo_4s(5000.0, 0.03)).unwrap();
    let mut rng = StdRng::seed_from_u64(5);
    let current = |t: f64| 2.0 + 0.5 * t;
    let mut t = 0.0;
    while t < 100.0 {
        est.update(current_sample(t, current(t))).unwrap();
        t += rng.random_range(0.05..1.5);
    }
    let t_end = 100.0;
    let e = est.update(current_sample(t_end, current(t_end))).unwrap();
    let exact_mah = (2.0 * t_end + 0.25 * t_end * t_end) / 3.6;
    assert!((e.consumed_mah - exact_mah).abs() < 1e-9 * exact_mah);
    assert_eq!(e.charge_source, ChargeSource::Trapezoid);
}

#[test]
fn time_going_backwards_repeats_and_gaps() {
    let spec = lipo_4s(5000.0, 0.03);
    let mut est = BatteryEstimator::new(spec.clone()).unwrap();
    assert_eq!(
        est.update(current_sample(10.0, 10.0))
            .unwrap()
            .charge_source,
        ChargeSource::Start
    );
    est.update(current_sample(11.0, 10.0)).unwrap();
    assert!((est.consumed_mah() - 10.0 / 3.6).abs() < 1e-12);
    // Same timestamp: nothing added.
    let e = est.update(current_sample(11.0, 10.0)).unwrap();
    assert_eq!(e.charge_source, ChargeSource::Repeated);
    assert!((e.consumed_mah - 10.0 / 3.6).abs() < 1e-12);
    // Backwards: nothing added, counting restarts from the new time.
    let e = est.update(current_sample(5.0, 10.0)).unwrap();
    assert_eq!(e.charge_source, ChargeSource::TimeReset);
    assert!((e.consumed_mah - 10.0 / 3.6).abs() < 1e-12);
    est.update(current_sample(6.0, 10.0)).unwrap();
    assert!((est.consumed_mah() - 20.0 / 3.6).abs() < 1e-12);
    assert_eq!(est.time_resets(), 1);

    // A 30 s gap with the autopilot's count at both ends: its difference is used.
    let mut est = BatteryEstimator::new(spec.clone()).unwrap();
    let with_consumed = |t: f64, i: f64, c: f64| BatterySample {
        time_s: t,
        current_a: Some(i),
        consumed_mah: Some(c),
        ..Default::default()
    };
    est.update(with_consumed(0.0, 10.0, 100.0)).unwrap();
    let e = est.update(with_consumed(30.0, 10.0, 200.0)).unwrap();
    assert_eq!(e.charge_source, ChargeSource::AutopilotConsumed);
    assert!((e.consumed_mah - 100.0).abs() < 1e-12);
    assert_eq!(est.gaps(), 1);
    // Inside normal steps the own trapezoid wins over the autopilot's count.
    let e = est.update(with_consumed(31.0, 10.0, 999.0)).unwrap();
    assert_eq!(e.charge_source, ChargeSource::Trapezoid);
    assert!((e.consumed_mah - 100.0 - 10.0 / 3.6).abs() < 1e-12);

    // A gap without the autopilot's count: trapezoid across it, uncertainty widened.
    let mut est = BatteryEstimator::new(spec.clone()).unwrap();
    est.update(current_sample(0.0, 10.0)).unwrap();
    let sigma_before = est.soc_sigma();
    let e = est.update(current_sample(30.0, 20.0)).unwrap();
    assert_eq!(e.charge_source, ChargeSource::GapEstimate);
    assert!((e.consumed_mah - 15.0 * 30.0 / 3.6).abs() < 1e-9);
    let d_soc = e.consumed_mah / 5000.0;
    let widened = sigma_before + (0.05 + 0.5) * d_soc;
    assert!((e.soc_sigma - widened).abs() < 1e-12);

    // No current, but the autopilot's count: used, and its rate gives the power.
    let mut est = BatteryEstimator::new(spec).unwrap();
    let counted = |t: f64, c: f64| BatterySample {
        time_s: t,
        voltage_v: Some(15.0),
        consumed_mah: Some(c),
        ..Default::default()
    };
    est.update(counted(0.0, 50.0)).unwrap();
    let e = est.update(counted(2.0, 55.0)).unwrap();
    assert_eq!(e.charge_source, ChargeSource::AutopilotConsumed);
    assert!((e.consumed_mah - 5.0).abs() < 1e-12);
    // 5 mAh in 2 s is 9 A; 15 V·9 A = 135 W, first power reading taken as is.
    assert!((e.power_w - 135.0).abs() < 1e-9);
}

#[test]
fn bad_samples_are_named_and_change_nothing() {
    let spec = lipo_4s(5000.0, 0.03);
    let mut est = BatteryEstimator::new(spec).unwrap();
    est.update(BatterySample {
        time_s: 0.0,
        voltage_v: Some(15.5),
        current_a: Some(10.0),
        consumed_mah: Some(1.0),
        remaining_fraction: Some(0.7),
    })
    .unwrap();
    let good = BatterySample {
        time_s: 1.0,
        voltage_v: Some(15.4),
        current_a: Some(11.0),
        consumed_mah: Some(4.0),
        remaining_fraction: Some(0.69),
    };
    let cases: Vec<(BatterySample, &str)> = vec![
        (
            BatterySample {
                time_s: f64::NAN,
                ..good
            },
            "NonFinite",
        ),
        (
            BatterySample {
                voltage_v: Some(f64::NAN),
                ..good
            },
            "NonFinite",
        ),
        (
            BatterySample {
                current_a: Some(f64::INFINITY),
                ..good
            },
            "NonFinite",
        ),
        (
            BatterySample {
                consumed_mah: Some(f64::NAN),
                ..good
            },
            "NonFinite",
        ),
        (
            BatterySample {
                remaining_fraction: Some(f64::NAN),
                ..good
            },
            "NonFinite",
        ),
        (
            BatterySample {
                voltage_v: Some(25.2),
                ..good
            },
            "VoltageOutOfRange",
        ),
        (
            BatterySample {
                voltage_v: Some(0.0),
                ..good
            },
            "VoltageOutOfRange",
        ),
        (
            BatterySample {
                voltage_v: Some(9.9),
                ..good
            },
            "VoltageOutOfRange",
        ),
        (
            BatterySample {
                current_a: Some(-1.0),
                ..good
            },
            "CurrentOutOfRange",
        ),
        (
            BatterySample {
                current_a: Some(600.0),
                ..good
            },
            "CurrentOutOfRange",
        ),
        (
            BatterySample {
                consumed_mah: Some(-1.0),
                ..good
            },
            "NegativeConsumed",
        ),
        (
            BatterySample {
                remaining_fraction: Some(1.5),
                ..good
            },
            "RemainingOutOfRange",
        ),
        (
            BatterySample {
                remaining_fraction: Some(-0.01),
                ..good
            },
            "RemainingOutOfRange",
        ),
        (
            BatterySample {
                time_s: 1.0,
                ..Default::default()
            },
            "EmptySample",
        ),
    ];
    for (sample, expected) in cases {
        let before = est.clone();
        let err = est.update(sample).unwrap_err();
        let name = format!("{err:?}");
        assert!(name.starts_with(expected), "{sample:?}: {name}");
        assert!(!err.to_string().is_empty());
        assert_eq!(est, before, "{sample:?} changed the state");
    }
    // A small negative current is a sensor offset: accepted as 0 A.
    let e = est
        .update(BatterySample {
            current_a: Some(-0.2),
            ..good
        })
        .unwrap();
    assert!((e.consumed_mah - 0.5 * 10.0 / 3.6).abs() < 1e-12);
}

#[test]
fn power_is_a_first_order_filter_of_v_times_i() {
    let mut est = BatteryEstimator::new(lipo_4s(5000.0, 0.0)).unwrap();
    let s = |t: f64, i: f64| BatterySample {
        time_s: t,
        voltage_v: Some(16.0),
        current_a: Some(i),
        ..Default::default()
    };
    for k in 0..=20 {
        est.update(s(k as f64 * 0.5, 10.0)).unwrap();
    }
    assert!((est.power_w() - 160.0).abs() < 1e-9);
    // Step to 320 W after t = 10 s, sampled irregularly: 2 s (one τ) later the filter
    // has covered 1 − 1/e of the step.
    for t in [10.3, 10.45, 11.2, 11.9, 12.0] {
        est.update(s(t, 20.0)).unwrap();
    }
    let expected = 320.0 - 160.0 * (-1.0_f64).exp();
    assert!((est.power_w() - expected).abs() < 1e-9, "{}", est.power_w());
}

#[test]
fn estimator_config_is_validated() {
    let spec = lipo_4s(5000.0, 0.03);
    let bad = [
        EstimatorConfig {
            voltage_sigma_cell_v: 0.0,
            ..Default::default()
        },
        EstimatorConfig {
            max_gap_s: -1.0,
            ..Default::default()
        },
        EstimatorConfig {
            initial_soc: 1.5,
            ..Default::default()
        },
        EstimatorConfig {
            coulomb_rel_sigma: f64::NAN,
            ..Default::default()
        },
    ];
    for config in bad {
        assert!(BatteryEstimator::with_config(spec.clone(), config).is_err());
    }
    let mut bad_spec = spec;
    bad_spec.capacity_mah = 0.0;
    assert!(BatteryEstimator::new(bad_spec).is_err());
}
