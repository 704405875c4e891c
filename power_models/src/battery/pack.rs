//! The pack: an OCV(SoC) curve, capacity, cells and the energy the pack can deliver.
//!
//! # Model: Rint (internal resistance) with an OCV(SoC) curve
//!
//! The terminal voltage of the pack is `V = n·OCV(SoC) − I·R`: a per-cell open-circuit
//! voltage read from a piecewise-linear curve of state of charge, in series with one pack
//! resistance. We chose it over Peukert's law because, for a multirotor drawing 10–35 A from
//! a LiPo, what shortens the flight is (1) the I²R loss and (2) the voltage sag that reaches the
//! empty cutoff while charge is still in the pack; Rint gives both, and it gives the terminal
//! voltage, which the estimator needs to read SoC from voltage telemetry (`OCV ≈ V + I·R`).
//! Peukert only rescales capacity with a rate exponent fitted for lead-acid at low rates
//! (≈ 1.0–1.05 for LiPo) and says nothing about voltage. Autopilots model the pack the same
//! way (PX4's `BAT_R_INTERNAL` load compensation, ArduPilot's resting-voltage estimate).
//! Polarisation (the slow voltage recovery after a load step) is not modelled: its error
//! shows up as extra voltage-measurement noise in the estimator.

use super::{check_power, check_soc, BatteryError};

/// Simpson panels per linear piece of the OCV curve; the integrand is smooth inside a piece,
/// so this is far below 1e-6 relative error (checked against closed forms in the tests).
const SIMPSON_PANELS: usize = 64;

fn invalid_spec(field: &'static str, value: f64, expected: &'static str) -> BatteryError {
    BatteryError::InvalidSpec {
        field,
        value,
        expected,
    }
}

/// Resting voltage of one LiPo cell against SoC, typical of hobby packs at room temperature:
/// steep above 80 % and below 10 %, flat (hard to read SoC from) around 40–60 %.
const LIPO_OCV_POINTS: [(f64, f64); 12] = [
    (0.00, 3.30),
    (0.05, 3.60),
    (0.10, 3.68),
    (0.20, 3.73),
    (0.30, 3.77),
    (0.40, 3.80),
    (0.50, 3.84),
    (0.60, 3.87),
    (0.70, 3.95),
    (0.80, 4.02),
    (0.90, 4.11),
    (1.00, 4.20),
];

/// Open-circuit voltage of one cell as a piecewise-linear function of SoC.
///
/// Both SoC and voltage rise strictly from point to point, so the curve can be inverted
/// (SoC from a load-compensated voltage).
#[derive(Debug, Clone, PartialEq)]
pub struct OcvCurve {
    /// `(soc, cell_ocv_v)`, soc from exactly 0 to exactly 1.
    points: Vec<(f64, f64)>,
}

impl OcvCurve {
    /// A curve through `(soc, cell_ocv_v)` points: at least two, finite, SoC from 0 to 1,
    /// both coordinates strictly increasing.
    pub fn new(points: Vec<(f64, f64)>) -> Result<Self, BatteryError> {
        let problem = |p: String| Err(BatteryError::InvalidOcvCurve { problem: p });
        if points.len() < 2 {
            return problem(format!("{} point(s), need at least 2", points.len()));
        }
        for (i, &(soc, v)) in points.iter().enumerate() {
            if !soc.is_finite() || !v.is_finite() {
                return problem(format!("point {i} ({soc}, {v}) is not finite"));
            }
            if v <= 0.0 {
                return problem(format!("point {i}: voltage {v} V must be positive"));
            }
        }
        let (first, last) = (points[0].0, points[points.len() - 1].0);
        if first != 0.0 || last != 1.0 {
            return problem(format!("SoC must run from 0 to 1, found {first} to {last}"));
        }
        for (i, w) in points.windows(2).enumerate() {
            if w[1].0 <= w[0].0 {
                return problem(format!(
                    "SoC must increase strictly (points {i} and {})",
                    i + 1
                ));
            }
            if w[1].1 <= w[0].1 {
                // A flat or falling piece would make SoC unreadable from voltage.
                return problem(format!(
                    "voltage must increase strictly with SoC (points {i} and {})",
                    i + 1
                ));
            }
        }
        Ok(Self { points })
    }

    /// The typical LiPo curve (4.20 V full, 3.30 V at SoC 0).
    pub fn lipo() -> Self {
        Self {
            points: LIPO_OCV_POINTS.to_vec(),
        }
    }

    /// The `(soc, cell_ocv_v)` points.
    pub fn points(&self) -> &[(f64, f64)] {
        &self.points
    }

    /// Index of the linear piece that holds `soc` (clamped to the curve).
    fn piece_at_soc(&self, soc: f64) -> usize {
        let idx = self.points.partition_point(|p| p.0 <= soc);
        idx.saturating_sub(1).min(self.points.len() - 2)
    }

    /// Cell OCV at `soc`; SoC outside 0..1 is clamped, NaN gives NaN.
    pub fn cell_ocv_v(&self, soc: f64) -> f64 {
        let s = soc.clamp(0.0, 1.0);
        let i = self.piece_at_soc(s);
        let ((s0, v0), (s1, v1)) = (self.points[i], self.points[i + 1]);
        v0 + (v1 - v0) * (s - s0) / (s1 - s0)
    }

    /// SoC whose OCV is `cell_ocv_v`; voltages beyond the curve give 0 or 1, NaN gives NaN.
    pub fn soc_at_cell_ocv_v(&self, cell_ocv_v: f64) -> f64 {
        let (bottom, top) = (self.points[0], self.points[self.points.len() - 1]);
        if cell_ocv_v <= bottom.1 {
            return 0.0;
        }
        if cell_ocv_v >= top.1 {
            return 1.0;
        }
        let idx = self.points.partition_point(|p| p.1 <= cell_ocv_v);
        let i = idx.saturating_sub(1).min(self.points.len() - 2);
        let ((s0, v0), (s1, v1)) = (self.points[i], self.points[i + 1]);
        s0 + (s1 - s0) * (cell_ocv_v - v0) / (v1 - v0)
    }

    /// dOCV/dSoC (V per unit SoC) of the piece holding `soc`.
    pub fn slope_v_per_soc(&self, soc: f64) -> f64 {
        let i = self.piece_at_soc(soc.clamp(0.0, 1.0));
        let ((s0, v0), (s1, v1)) = (self.points[i], self.points[i + 1]);
        (v1 - v0) / (s1 - s0)
    }

    /// OCV of a full cell (SoC 1).
    pub fn full_cell_v(&self) -> f64 {
        self.points[self.points.len() - 1].1
    }
}

/// A battery pack: capacity, cells, voltages and the Rint discharge model.
///
/// Fields are public for configuration; every computation validates them first
/// ([`BatterySpec::validate`]).
#[derive(Debug, Clone, PartialEq)]
pub struct BatterySpec {
    /// Charge from SoC 1 to SoC 0.
    pub capacity_mah: f64,
    /// Cells in series.
    pub cell_count: u32,
    /// Rated cell voltage (3.7 V for LiPo): a label that converts Wh ↔ mAh as manufacturers
    /// do; the physics uses the OCV curve.
    pub nominal_cell_voltage_v: f64,
    /// Full-charge cell voltage (4.2 V LiPo, 4.35 V LiHV); must match the OCV curve's top.
    pub full_cell_voltage_v: f64,
    /// Cutoff cell voltage *under load*: a flight ends when the terminal voltage reaches it.
    pub empty_cell_voltage_v: f64,
    /// Pack internal resistance (cells + wiring + connectors).
    pub internal_resistance_ohm: f64,
    /// Largest plausible current reading; above it a sample is rejected as a sensor glitch.
    pub max_current_a: f64,
    /// Cell OCV against SoC.
    pub ocv: OcvCurve,
}

impl BatterySpec {
    /// A LiPo pack (4.2 V full, 3.5 V empty under load, typical LiPo OCV curve) from its
    /// rated charge.
    pub fn from_capacity_mah(
        capacity_mah: f64,
        cell_count: u32,
        nominal_cell_voltage_v: f64,
        internal_resistance_ohm: f64,
    ) -> Result<Self, BatteryError> {
        let spec = Self {
            capacity_mah,
            cell_count,
            nominal_cell_voltage_v,
            full_cell_voltage_v: 4.2,
            empty_cell_voltage_v: 3.5,
            internal_resistance_ohm,
            max_current_a: 500.0,
            ocv: OcvCurve::lipo(),
        };
        spec.validate()?;
        Ok(spec)
    }

    /// A LiPo pack from its rated energy: `capacity_mah = capacity_wh / (cells × nominal) × 1000`,
    /// the manufacturers' convention.
    pub fn from_capacity_wh(
        capacity_wh: f64,
        cell_count: u32,
        nominal_cell_voltage_v: f64,
        internal_resistance_ohm: f64,
    ) -> Result<Self, BatteryError> {
        if !(capacity_wh.is_finite() && capacity_wh > 0.0) {
            return Err(invalid_spec(
                "capacity_wh",
                capacity_wh,
                "a positive number",
            ));
        }
        if !(nominal_cell_voltage_v.is_finite() && nominal_cell_voltage_v > 0.0) {
            return Err(invalid_spec(
                "nominal_cell_voltage_v",
                nominal_cell_voltage_v,
                "a positive cell voltage",
            ));
        }
        let pack_nominal_v = f64::from(cell_count) * nominal_cell_voltage_v;
        if pack_nominal_v <= 0.0 {
            return Err(invalid_spec("cell_count", 0.0, "at least 1 cell"));
        }
        Self::from_capacity_mah(
            capacity_wh / pack_nominal_v * 1000.0,
            cell_count,
            nominal_cell_voltage_v,
            internal_resistance_ohm,
        )
    }

    /// The same pack with another OCV curve; `full_cell_voltage_v` follows the curve's top.
    pub fn with_ocv(mut self, ocv: OcvCurve) -> Result<Self, BatteryError> {
        self.full_cell_voltage_v = ocv.full_cell_v();
        self.ocv = ocv;
        self.validate()?;
        Ok(self)
    }

    /// The same pack with another empty cutoff (cell voltage under load).
    pub fn with_empty_cell_voltage_v(
        mut self,
        empty_cell_voltage_v: f64,
    ) -> Result<Self, BatteryError> {
        self.empty_cell_voltage_v = empty_cell_voltage_v;
        self.validate()?;
        Ok(self)
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), BatteryError> {
        if !(self.capacity_mah.is_finite() && self.capacity_mah > 0.0) {
            return Err(invalid_spec(
                "capacity_mah",
                self.capacity_mah,
                "a positive charge",
            ));
        }
        if self.cell_count == 0 || self.cell_count > 30 {
            return Err(invalid_spec(
                "cell_count",
                f64::from(self.cell_count),
                "1 to 30 cells in series",
            ));
        }
        let cell_v = |v: f64| v.is_finite() && v > 0.0 && v <= 5.0;
        if !cell_v(self.nominal_cell_voltage_v) {
            return Err(invalid_spec(
                "nominal_cell_voltage_v",
                self.nominal_cell_voltage_v,
                "a cell voltage in 0..5 V",
            ));
        }
        if !cell_v(self.full_cell_voltage_v) {
            return Err(invalid_spec(
                "full_cell_voltage_v",
                self.full_cell_voltage_v,
                "a cell voltage in 0..5 V",
            ));
        }
        if !cell_v(self.empty_cell_voltage_v)
            || self.empty_cell_voltage_v >= self.full_cell_voltage_v
        {
            return Err(invalid_spec(
                "empty_cell_voltage_v",
                self.empty_cell_voltage_v,
                "a cell voltage above 0 and below full_cell_voltage_v",
            ));
        }
        // A LiHV pack configured with the LiPo curve would read 15 % full when it is 100 %.
        if (self.ocv.full_cell_v() - self.full_cell_voltage_v).abs() > 0.1 {
            return Err(invalid_spec(
                "full_cell_voltage_v",
                self.full_cell_voltage_v,
                "the OCV curve's voltage at SoC 1 (within 0.1 V); set both with with_ocv",
            ));
        }
        if !(self.internal_resistance_ohm.is_finite() && self.internal_resistance_ohm >= 0.0) {
            return Err(invalid_spec(
                "internal_resistance_ohm",
                self.internal_resistance_ohm,
                "a resistance >= 0",
            ));
        }
        if !(self.max_current_a.is_finite() && self.max_current_a > 0.0) {
            return Err(invalid_spec(
                "max_current_a",
                self.max_current_a,
                "a positive current",
            ));
        }
        Ok(())
    }

    /// Capacity in Ah.
    pub fn capacity_ah(&self) -> f64 {
        self.capacity_mah / 1000.0
    }

    /// Rated energy: capacity × cells × nominal cell voltage.
    pub fn nominal_energy_wh(&self) -> f64 {
        self.capacity_ah() * f64::from(self.cell_count) * self.nominal_cell_voltage_v
    }

    /// Pack open-circuit voltage at `soc`.
    pub fn pack_ocv_v(&self, soc: f64) -> f64 {
        f64::from(self.cell_count) * self.ocv.cell_ocv_v(soc)
    }

    /// Terminal voltage at `soc` while delivering `current_a`: `n·OCV(soc) − I·R`.
    pub fn terminal_voltage_v(&self, soc: f64, current_a: f64) -> f64 {
        self.pack_ocv_v(soc) - current_a * self.internal_resistance_ohm
    }

    /// Pack cutoff voltage under load: `cells × empty_cell_voltage_v`.
    pub fn cutoff_voltage_v(&self) -> f64 {
        f64::from(self.cell_count) * self.empty_cell_voltage_v
    }

    /// Current that delivers `power_w` to the load at `soc`: the smaller root of
    /// `n·OCV·I − R·I² = P`. None when the pack cannot deliver that power at all
    /// (`P > (n·OCV)²/4R`) or `power_w` is negative or not finite.
    pub fn current_for_power_a(&self, soc: f64, power_w: f64) -> Option<f64> {
        if !(power_w.is_finite() && power_w >= 0.0 && soc.is_finite()) {
            return None;
        }
        let e = self.pack_ocv_v(soc);
        let disc = e * e - 4.0 * self.internal_resistance_ohm * power_w;
        if disc < 0.0 {
            return None;
        }
        // 2P / (E + √disc) is the small root without the cancellation of (E − √disc) / 2R.
        Some(2.0 * power_w / (e + disc.sqrt()))
    }

    /// Terminal voltage while delivering `power_w` at `soc` (the high root); beyond the
    /// maximum power it gives the maximum-power-point voltage E/2.
    fn terminal_voltage_at_power_v(&self, soc: f64, power_w: f64) -> f64 {
        let e = self.pack_ocv_v(soc);
        let disc = (e * e - 4.0 * self.internal_resistance_ohm * power_w).max(0.0);
        0.5 * (e + disc.sqrt())
    }

    /// Lowest pack OCV at which `power_w` is still delivered at or above the cutoff voltage.
    fn min_pack_ocv_for_load_v(&self, power_w: f64) -> f64 {
        let vc = self.cutoff_voltage_v();
        let rp = self.internal_resistance_ohm * power_w;
        if rp <= 0.0 {
            vc
        } else if vc * vc > rp {
            // Terminal voltage = vc means I = P/vc and OCV = vc + R·P/vc.
            vc + rp / vc
        } else {
            // The cutoff lies below the maximum-power point: the power limit ends the flight.
            2.0 * rp.sqrt()
        }
    }

    /// SoC at which a constant `load_power_w` pulls the terminal voltage down to the cutoff
    /// (0 when it never does); None when the pack cannot carry that load even when full.
    pub fn cutoff_soc(&self, load_power_w: f64) -> Result<Option<f64>, BatteryError> {
        self.validate()?;
        check_power(load_power_w)?;
        Ok(self.cutoff_soc_unchecked(load_power_w))
    }

    fn cutoff_soc_unchecked(&self, load_power_w: f64) -> Option<f64> {
        let cell_v = self.min_pack_ocv_for_load_v(load_power_w) / f64::from(self.cell_count);
        if cell_v > self.ocv.full_cell_v() {
            None
        } else {
            Some(self.ocv.soc_at_cell_ocv_v(cell_v))
        }
    }

    /// Energy (Wh) the pack delivers to a constant-power load while its SoC falls from
    /// `from_soc` to `to_soc`, stopping early at the cutoff voltage.
    ///
    /// Integrates the Rint model: charge `dQ = C·dSoC` leaves the pack at terminal voltage
    /// `V(SoC) = (E + √(E² − 4RP))/2`, `E = n·OCV(SoC)`, so the load receives
    /// `C·∫V dSoC`; the I²R loss is the difference from `C·∫E dSoC`. The integral is taken
    /// with Simpson's rule on each linear piece of the OCV curve. Returns 0 when
    /// `from_soc <= to_soc` or the load cannot be carried at `from_soc`.
    pub fn usable_energy_wh(
        &self,
        load_power_w: f64,
        from_soc: f64,
        to_soc: f64,
    ) -> Result<f64, BatteryError> {
        self.validate()?;
        check_power(load_power_w)?;
        check_soc("from_soc", from_soc)?;
        check_soc("to_soc", to_soc)?;
        Ok(self.usable_energy_unchecked_wh(load_power_w, from_soc, to_soc))
    }

    pub(super) fn usable_energy_unchecked_wh(
        &self,
        load_power_w: f64,
        from_soc: f64,
        to_soc: f64,
    ) -> f64 {
        let Some(cutoff_soc) = self.cutoff_soc_unchecked(load_power_w) else {
            return 0.0;
        };
        let lo = to_soc.max(cutoff_soc);
        if lo >= from_soc {
            return 0.0;
        }
        let mut edges = vec![lo];
        edges.extend(
            self.ocv
                .points()
                .iter()
                .map(|p| p.0)
                .filter(|&s| s > lo && s < from_soc),
        );
        edges.push(from_soc);
        let v = |s: f64| self.terminal_voltage_at_power_v(s, load_power_w);
        let integral: f64 = edges.windows(2).map(|w| simpson(v, w[0], w[1])).sum();
        self.capacity_ah() * integral
    }

    /// Seconds a constant `load_power_w` (> 0) can be carried from `from_soc` to the cutoff.
    pub fn endurance_s(&self, load_power_w: f64, from_soc: f64) -> Result<f64, BatteryError> {
        if !(load_power_w.is_finite() && load_power_w > 0.0) {
            return Err(BatteryError::InvalidArgument {
                name: "load_power_w",
                value: load_power_w,
                expected: "a positive power",
            });
        }
        Ok(self.usable_energy_wh(load_power_w, from_soc, 0.0)? / load_power_w * 3600.0)
    }
}

/// Composite Simpson's rule on `[a, b]` with [`SIMPSON_PANELS`] panels.
fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64) -> f64 {
    let h = (b - a) / SIMPSON_PANELS as f64;
    let inner: f64 = (1..SIMPSON_PANELS)
        .map(|k| {
            let w = if k % 2 == 1 { 4.0 } else { 2.0 };
            w * f(a + h * k as f64)
        })
        .sum();
    h / 3.0 * (f(a) + inner + f(b))
}

#[cfg(test)]
mod tests {
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
}
