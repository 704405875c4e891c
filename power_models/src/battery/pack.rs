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
mod tests;
