use super::*;

#[test]
fn the_telemetry_filter_smooths_and_never_blends_in_a_stale_value() {
    let tau_s = 5.0;
    let reading = |time_s: f64, voltage_v: Option<f64>| BatteryTelemetry {
        time_s,
        voltage_v,
        current_a: Some(10.0),
        ..BatteryTelemetry::default()
    };
    let (filter, first) = TelemetryFilter::default().step(&reading(0.0, Some(16.0)), tau_s);
    assert_eq!(first.voltage_v, Some(16.0));
    let (filter, second) = filter.step(&reading(1.0, Some(15.0)), tau_s);
    let alpha = 1.0 - (-1.0_f64 / tau_s).exp();
    assert!((second.voltage_v.unwrap() - (16.0 - alpha)).abs() < 1e-12);
    assert_eq!(second.current_a, Some(10.0));
    // A reading without voltage passes none on, and the next voltage starts afresh.
    let (filter, third) = filter.step(&reading(2.0, None), tau_s);
    assert_eq!(third.voltage_v, None);
    let (_, fourth) = filter.step(&reading(3.0, Some(14.0)), tau_s);
    assert_eq!(fourth.voltage_v, Some(14.0));
}

// ---- bad input ------------------------------------------------------------------------------

#[test]
fn bad_telemetry_is_rejected_and_changes_nothing() {
    let mut governor = reference_governor(None);
    let good = |time_s: f64| BatteryTelemetry {
        time_s,
        voltage_v: Some(16.4),
        current_a: Some(11.5),
        consumed_mah: None,
        remaining_fraction: None,
    };
    for t in 0..40 {
        governor
            .update(&good(f64::from(t)), MissionProgress::new(0, f64::from(t)))
            .unwrap();
    }
    let before = governor.clone();
    let at = |phase, elapsed| MissionProgress::new(phase, elapsed);
    let cases: Vec<(BatteryTelemetry, MissionProgress, &str)> = vec![
        (
            BatteryTelemetry {
                voltage_v: Some(f64::NAN),
                ..good(40.0)
            },
            at(0, 40.0),
            "NonFinite",
        ),
        (
            BatteryTelemetry {
                current_a: Some(f64::INFINITY),
                ..good(40.0)
            },
            at(0, 40.0),
            "NonFinite",
        ),
        (
            BatteryTelemetry {
                time_s: f64::NAN,
                ..good(40.0)
            },
            at(0, 40.0),
            "NonFinite",
        ),
        (
            BatteryTelemetry {
                voltage_v: Some(60.0),
                ..good(40.0)
            },
            at(0, 40.0),
            "VoltageOutOfRange",
        ),
        (
            BatteryTelemetry {
                voltage_v: Some(3.0),
                ..good(40.0)
            },
            at(0, 40.0),
            "VoltageOutOfRange",
        ),
        (
            BatteryTelemetry {
                current_a: Some(-5.0),
                ..good(40.0)
            },
            at(0, 40.0),
            "CurrentOutOfRange",
        ),
        (
            BatteryTelemetry {
                remaining_fraction: Some(75.0),
                ..good(40.0)
            },
            at(0, 40.0),
            "RemainingOutOfRange",
        ),
        (
            BatteryTelemetry {
                time_s: 40.0,
                ..BatteryTelemetry::default()
            },
            at(0, 40.0),
            "EmptySample",
        ),
        (good(20.0), at(0, 40.0), "TimeWentBack"),
        (good(40.0), at(3, 0.0), "UnknownPhase"),
        (good(40.0), at(0, f64::NAN), "BadElapsed"),
        (good(40.0), at(0, -1.0), "BadElapsed"),
    ];
    for (telemetry, progress, expected) in cases {
        let error = governor.update(&telemetry, progress).unwrap_err();
        assert!(
            format!("{error:?}").contains(expected),
            "{expected}: {error:?}"
        );
        assert!(!error.to_string().is_empty());
        assert_eq!(governor, before, "{expected} changed the governor");
    }
    // Phases are flown in order.
    governor.update(&good(41.0), at(1, 0.0)).unwrap();
    let before = governor.clone();
    let error = governor.update(&good(42.0), at(0, 42.0)).unwrap_err();
    assert_eq!(error, GovernorError::PhaseWentBack { from: 1, to: 0 });
    assert_eq!(governor, before);
    // And a good sample is taken again.
    assert!(governor.update(&good(42.0), at(1, 1.0)).is_ok());
}

/// On the ground, motors off: the pack's power is a few percent of the model's flight
/// power. That is not a model error; the correction ignores it.
#[test]
fn implausible_power_ratios_are_ignored() {
    let mut governor = reference_governor(None);
    for t in 0..20 {
        let telemetry = BatteryTelemetry {
            time_s: f64::from(t),
            voltage_v: Some(16.7),
            current_a: Some(0.4),
            consumed_mah: None,
            remaining_fraction: None,
        };
        governor
            .update(&telemetry, MissionProgress::start())
            .unwrap();
    }
    assert_eq!(governor.correction_ratio(), 1.0);
    assert_eq!(governor.ignored_power_samples(), 20);
}
