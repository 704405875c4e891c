use super::super::lipo_4s;
use super::*;

/// Linear interpolation written apart from `OcvCurve`, so the tests do not check the
/// curve against itself.
fn interp(points: &[(f64, f64)], x: f64) -> f64 {
    for w in points.windows(2) {
        if x <= w[1].0 {
            return w[0].1 + (w[1].1 - w[0].1) * (x - w[0].0) / (w[1].0 - w[0].0);
        }
    }
    points[points.len() - 1].1
}

// ---- OCV curve and spec ------------------------------------------------------------

#[test]
fn ocv_curve_rejects_points_it_cannot_invert() {
    let bad = [
        vec![(0.0, 3.3)],
        vec![(0.0, 3.3), (0.5, f64::NAN), (1.0, 4.2)],
        vec![(0.1, 3.3), (1.0, 4.2)],
        vec![(0.0, 3.3), (0.9, 4.2)],
        vec![(0.0, 3.3), (0.5, 3.8), (0.5, 3.9), (1.0, 4.2)],
        vec![(0.0, 3.3), (0.5, 3.8), (0.7, 3.8), (1.0, 4.2)],
        vec![(0.0, 3.3), (0.5, 3.9), (0.7, 3.8), (1.0, 4.2)],
        vec![(0.0, -1.0), (1.0, 4.2)],
    ];
    for points in bad {
        assert!(
            matches!(
                OcvCurve::new(points.clone()),
                Err(BatteryError::InvalidOcvCurve { .. })
            ),
            "{points:?} accepted"
        );
    }
    assert!(OcvCurve::new(LIPO_OCV_POINTS.to_vec()).is_ok());
}

#[test]
fn ocv_curve_interpolates_inverts_and_clamps() {
    let c = OcvCurve::lipo();
    for &(s, v) in &LIPO_OCV_POINTS {
        assert!((c.cell_ocv_v(s) - v).abs() < 1e-12);
    }
    for k in 0..=1000 {
        let s = k as f64 / 1000.0;
        let v = c.cell_ocv_v(s);
        assert!((v - interp(&LIPO_OCV_POINTS, s)).abs() < 1e-12);
        assert!((c.soc_at_cell_ocv_v(v) - s).abs() < 1e-9, "soc {s}");
        // Slope against a central difference inside the piece.
        let h = 1e-6;
        if s > h && s < 1.0 - h && LIPO_OCV_POINTS.iter().all(|p| (p.0 - s).abs() > 2.0 * h) {
            let fd = (c.cell_ocv_v(s + h) - c.cell_ocv_v(s - h)) / (2.0 * h);
            assert!((c.slope_v_per_soc(s) - fd).abs() < 1e-6);
        }
    }
    assert_eq!(c.soc_at_cell_ocv_v(5.0), 1.0);
    assert_eq!(c.soc_at_cell_ocv_v(2.0), 0.0);
    assert_eq!(c.cell_ocv_v(-0.5), 3.30);
    assert_eq!(c.cell_ocv_v(1.5), 4.20);
    assert!(c.cell_ocv_v(f64::NAN).is_nan());
    assert!(c.soc_at_cell_ocv_v(f64::NAN).is_nan());
}

#[test]
fn spec_from_energy_and_from_charge_agree() {
    let from_wh = BatterySpec::from_capacity_wh(74.0, 4, 3.7, 0.02).unwrap();
    assert!((from_wh.capacity_mah - 5000.0).abs() < 1e-9);
    assert!((from_wh.nominal_energy_wh() - 74.0).abs() < 1e-9);
    let from_mah = lipo_4s(5000.0, 0.02);
    assert_eq!(from_wh, from_mah);
    assert!((from_mah.pack_ocv_v(1.0) - 16.8).abs() < 1e-12);
    assert!((from_mah.terminal_voltage_v(1.0, 10.0) - 16.6).abs() < 1e-12);
    assert!((from_mah.cutoff_voltage_v() - 14.0).abs() < 1e-12);
}

#[test]
fn spec_rejects_bad_values_by_name() {
    let field_of = |r: Result<BatterySpec, BatteryError>| match r {
        Err(BatteryError::InvalidSpec { field, .. }) => field,
        other => panic!("expected InvalidSpec, got {other:?}"),
    };
    assert_eq!(
        field_of(BatterySpec::from_capacity_mah(-1.0, 4, 3.7, 0.02)),
        "capacity_mah"
    );
    assert_eq!(
        field_of(BatterySpec::from_capacity_mah(f64::NAN, 4, 3.7, 0.02)),
        "capacity_mah"
    );
    assert_eq!(
        field_of(BatterySpec::from_capacity_mah(5000.0, 0, 3.7, 0.02)),
        "cell_count"
    );
    assert_eq!(
        field_of(BatterySpec::from_capacity_mah(5000.0, 4, 3.7, -0.1)),
        "internal_resistance_ohm"
    );
    assert_eq!(
        field_of(BatterySpec::from_capacity_wh(0.0, 4, 3.7, 0.02)),
        "capacity_wh"
    );
    assert_eq!(
        field_of(lipo_4s(5000.0, 0.02).with_empty_cell_voltage_v(4.3)),
        "empty_cell_voltage_v"
    );
    let mut lihv_mismatch = lipo_4s(5000.0, 0.02);
    lihv_mismatch.full_cell_voltage_v = 4.35;
    assert_eq!(
        field_of(lihv_mismatch.validate().map(|_| lipo_4s(1.0, 0.0))),
        "full_cell_voltage_v"
    );
    // with_ocv keeps the two consistent.
    let lihv = OcvCurve::new(vec![(0.0, 3.4), (0.5, 3.9), (1.0, 4.35)]).unwrap();
    let spec = lipo_4s(5000.0, 0.02).with_ocv(lihv).unwrap();
    assert_eq!(spec.full_cell_voltage_v, 4.35);
}

// ---- usable energy -------------------------------------------------------------------

#[test]
fn usable_energy_without_resistance_is_capacity_times_mean_ocv() {
    // R = 0 and a cutoff below the curve: every mAh leaves at the OCV, so the energy is
    // C·n·∫OCV dSoC, the trapezoid sum of the table (exact for a piecewise-linear curve).
    let spec = lipo_4s(5000.0, 0.0).with_empty_cell_voltage_v(3.0).unwrap();
    let mean_ocv: f64 = LIPO_OCV_POINTS
        .windows(2)
        .map(|w| 0.5 * (w[0].1 + w[1].1) * (w[1].0 - w[0].0))
        .sum();
    let expected = 5.0 * 4.0 * mean_ocv;
    for power_w in [0.0, 50.0, 500.0] {
        let e = spec.usable_energy_wh(power_w, 1.0, 0.0).unwrap();
        assert!(
            (e - expected).abs() < 1e-9 * expected,
            "P {power_w}: {e} vs {expected}"
        );
    }
    // A partial range between knots: trapezoid over the interpolated end points.
    let (a, b) = (0.23, 0.87);
    let mut knots = vec![(a, interp(&LIPO_OCV_POINTS, a))];
    knots.extend(
        LIPO_OCV_POINTS
            .iter()
            .copied()
            .filter(|p| p.0 > a && p.0 < b),
    );
    knots.push((b, interp(&LIPO_OCV_POINTS, b)));
    let mean: f64 = knots
        .windows(2)
        .map(|w| 0.5 * (w[0].1 + w[1].1) * (w[1].0 - w[0].0))
        .sum();
    let e = spec.usable_energy_wh(100.0, b, a).unwrap();
    assert!((e - 5.0 * 4.0 * mean).abs() < 1e-9);
}

/// ∫ (E + √(E² − c²))/2 dE, the closed form for a linear OCV curve.
fn antiderivative(e: f64, c2: f64) -> f64 {
    let root = (e * e - c2).max(0.0).sqrt();
    0.25 * e * e + 0.25 * (e * root - c2 * (e + root).ln())
}

#[test]
fn usable_energy_matches_closed_form_for_linear_ocv_with_resistance() {
    // OCV = 3.5 + 0.7·SoC per cell, 4S, 5 Ah, R = 0.05 Ω, cutoff 3.6 V/cell under load.
    let curve = OcvCurve::new(vec![(0.0, 3.5), (1.0, 4.2)]).unwrap();
    let spec = lipo_4s(5000.0, 0.05)
        .with_ocv(curve)
        .unwrap()
        .with_empty_cell_voltage_v(3.6)
        .unwrap();
    let (n, a, b, r, cap_ah) = (4.0, 3.5, 0.7, 0.05, 5.0);
    for power_w in [100.0, 300.0, 600.0] {
        // Cutoff where V = 14.4 V: I = P/14.4, OCV_pack = 14.4 + R·I.
        let vc = 14.4;
        let e_cut: f64 = vc + r * power_w / vc;
        let (from, to) = (0.95, 0.0);
        let e_lo = e_cut.max(n * (a + b * to));
        let e_hi = n * (a + b * from);
        let c2 = 4.0 * r * power_w;
        // dSoC = dE / (n·b).
        let expected = cap_ah / (n * b) * (antiderivative(e_hi, c2) - antiderivative(e_lo, c2));
        let got = spec.usable_energy_wh(power_w, from, to).unwrap();
        assert!(
            (got - expected).abs() < 1e-7 * expected,
            "P {power_w}: {got} vs {expected}"
        );
        let soc_cut = (e_cut / n - a) / b;
        assert!((spec.cutoff_soc(power_w).unwrap().unwrap() - soc_cut).abs() < 1e-12);
    }
}

/// A LiPo-curve pack for the brute-force simulation, described by plain numbers.
struct SimPack {
    cells: f64,
    r: f64,
    cap_ah: f64,
    cutoff_v: f64,
}

/// Discharge at constant power in small time steps (midpoint rule), independent of the
/// quadrature: returns (energy to the load Wh, I²R loss Wh, final soc).
fn brute_force_discharge(
    pack: &SimPack,
    power_w: f64,
    from_soc: f64,
    to_soc: f64,
) -> (f64, f64, f64) {
    let SimPack {
        cells,
        r,
        cap_ah,
        cutoff_v,
    } = *pack;
    let points = &LIPO_OCV_POINTS;
    let dt = 0.01;
    let current = |soc: f64| {
        let e = cells * interp(points, soc);
        let disc = e * e - 4.0 * r * power_w;
        (disc >= 0.0).then(|| {
            if r == 0.0 {
                power_w / e
            } else {
                (e - disc.sqrt()) / (2.0 * r)
            }
        })
    };
    let (mut soc, mut energy_j, mut loss_j) = (from_soc, 0.0, 0.0);
    while let Some(i0) = current(soc) {
        if cells * interp(points, soc) - i0 * r < cutoff_v {
            break;
        }
        let Some(i_mid) = current(soc - 0.5 * dt * i0 / (cap_ah * 3600.0)) else {
            break;
        };
        let next = soc - dt * i_mid / (cap_ah * 3600.0);
        if next <= to_soc {
            // Last partial step, to land exactly on to_soc.
            let frac = (soc - to_soc) / (soc - next);
            energy_j += power_w * dt * frac;
            loss_j += i_mid * i_mid * r * dt * frac;
            soc = to_soc;
            break;
        }
        energy_j += power_w * dt;
        loss_j += i_mid * i_mid * r * dt;
        soc = next;
    }
    (energy_j / 3600.0, loss_j / 3600.0, soc)
}

#[test]
fn usable_energy_matches_brute_force_time_simulation() {
    let spec = lipo_4s(5000.0, 0.06);
    let lossless = lipo_4s(5000.0, 0.0);
    for (power_w, from, to) in [(250.0, 0.95, 0.0), (500.0, 1.0, 0.2), (60.0, 0.7, 0.1)] {
        let got = spec.usable_energy_wh(power_w, from, to).unwrap();
        let (energy, loss, _) = brute_force_discharge(
            &SimPack {
                cells: 4.0,
                r: 0.06,
                cap_ah: 5.0,
                cutoff_v: 14.0,
            },
            power_w,
            from,
            to,
        );
        assert!(
            (got - energy).abs() < 2e-4 * energy,
            "P {power_w}: {got} vs {energy}"
        );
        // Energy balance: the energy that left the cells over the same SoC span
        // (C·∫OCV, the lossless pack's) is what the load got plus the simulated I²R loss.
        let cut = spec.cutoff_soc(power_w).unwrap().unwrap();
        let chemical = lossless.usable_energy_wh(0.0, from, to.max(cut)).unwrap();
        eprintln!(
            "P {power_w} W: quadrature {got:.4} Wh, simulation {energy:.4} Wh, \
                 loss {loss:.3} Wh, chemical {chemical:.4} Wh"
        );
        assert!(loss > 0.0);
        assert!(
            (got + loss - chemical).abs() < 2e-4 * chemical,
            "P {power_w}: {got} + {loss} vs {chemical}"
        );
    }
    // A load near the pack's maximum power: the power limit, not the cutoff voltage, ends
    // the discharge (R = 1 Ω, cutoff 1 V/cell, max power 70.6 W when full).
    let weak = lipo_4s(5000.0, 1.0).with_empty_cell_voltage_v(1.0).unwrap();
    let got = weak.usable_energy_wh(50.0, 1.0, 0.0).unwrap();
    let (energy, _, soc_end) = brute_force_discharge(
        &SimPack {
            cells: 4.0,
            r: 1.0,
            cap_ah: 5.0,
            cutoff_v: 4.0,
        },
        50.0,
        1.0,
        0.0,
    );
    assert!((got - energy).abs() < 2e-3 * energy, "{got} vs {energy}");
    let cut = weak.cutoff_soc(50.0).unwrap().unwrap();
    assert!(
        (cut - soc_end).abs() < 2e-3,
        "cutoff {cut} vs simulated {soc_end}"
    );
}

#[test]
fn usable_energy_edge_cases() {
    let spec = lipo_4s(5000.0, 0.05);
    assert_eq!(spec.usable_energy_wh(100.0, 0.3, 0.5).unwrap(), 0.0);
    assert_eq!(spec.usable_energy_wh(100.0, 0.5, 0.5).unwrap(), 0.0);
    // Beyond the maximum power of a full pack (16.8² / 0.2 = 1411 W): nothing.
    assert_eq!(spec.usable_energy_wh(1500.0, 1.0, 0.0).unwrap(), 0.0);
    assert_eq!(spec.cutoff_soc(1500.0).unwrap(), None);
    assert!(spec.current_for_power_a(1.0, 1500.0).is_none());
    // More power, less energy (more loss, earlier cutoff).
    let mut last = f64::INFINITY;
    for p in [0.0, 100.0, 300.0, 600.0, 900.0] {
        let e = spec.usable_energy_wh(p, 1.0, 0.0).unwrap();
        assert!(e < last, "{p} W: {e} >= {last}");
        last = e;
    }
    for (p, from, to) in [
        (f64::NAN, 1.0, 0.0),
        (-1.0, 1.0, 0.0),
        (10.0, 1.2, 0.0),
        (10.0, 1.0, -0.1),
        (10.0, f64::NAN, 0.0),
    ] {
        assert!(matches!(
            spec.usable_energy_wh(p, from, to),
            Err(BatteryError::InvalidArgument { .. })
        ));
    }
    assert!(spec.endurance_s(0.0, 1.0).is_err());
    let e = spec.usable_energy_wh(200.0, 0.8, 0.0).unwrap();
    assert!((spec.endurance_s(200.0, 0.8).unwrap() - e / 200.0 * 3600.0).abs() < 1e-9);
    // current_for_power_a solves n·OCV·I − R·I² = P.
    let i = spec.current_for_power_a(0.6, 300.0).unwrap();
    assert!((spec.terminal_voltage_v(0.6, i) * i - 300.0).abs() < 1e-9);
}
