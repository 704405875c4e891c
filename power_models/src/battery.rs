//! Battery: a LiPo pack model, the energy it can deliver to a constant-power load, a
//! state-of-charge estimator fed by autopilot telemetry, and a parser for PX4's
//! `battery_status` CSV export.
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
//!
//! # SoC conventions
//!
//! SoC is the chemical state of charge, 0 = fully discharged, 1 = full at rest. The empty
//! cutoff (`empty_cell_voltage_v`, a voltage *under load*) is reached at a SoC above 0, and
//! earlier the heavier the load: that is exactly what [`BatterySpec::usable_energy_wh`] and
//! [`BatteryEstimate::remaining_energy_wh`] account for.

use thiserror::Error;

/// A connected LiPo cell never reads below this; lower readings are a disconnected or
/// mis-scaled sensor (PX4 itself treats a pack below 2.1 V as absent).
const MIN_PLAUSIBLE_CELL_V: f64 = 2.5;
/// Headroom above the full-charge voltage before a reading is implausible: calibration and
/// noise stay well inside it, a wrong cell count or a broken divider does not.
const MAX_CELL_OVERSHOOT_V: f64 = 0.3;
/// Hall and shunt sensors read slightly negative at idle (offset); such readings are clamped
/// to 0. More negative than this is not an offset (PX4/MAVLink use -1 for "not measured").
const NEGATIVE_CURRENT_TOLERANCE_A: f64 = 0.5;
/// Simpson panels per linear piece of the OCV curve; the integrand is smooth inside a piece,
/// so this is far below 1e-6 relative error (checked against closed forms in the tests).
const SIMPSON_PANELS: usize = 64;
/// One mAh is 3.6 A·s.
const AS_PER_MAH: f64 = 3.6;
/// Shortest interval used to weigh two measurements against their correlation time.
const MIN_FUSION_DT_S: f64 = 1e-3;

/// Everything that can go wrong in this module: bad specs, bad arguments, bad telemetry, bad
/// CSV. Each message names the thing and, where there is one, the fix.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BatteryError {
    #[error("battery spec: {field} = {value} is invalid, expected {expected}")]
    InvalidSpec {
        field: &'static str,
        value: f64,
        expected: &'static str,
    },
    #[error("OCV curve: {problem}")]
    InvalidOcvCurve { problem: String },
    #[error("{name} = {value} is invalid, expected {expected}")]
    InvalidArgument {
        name: &'static str,
        value: f64,
        expected: &'static str,
    },
    #[error(
        "battery sample at t = {time_s} s: {field} is {value}, not a finite number; \
         leave the field out (None) when the autopilot did not measure it"
    )]
    NonFinite {
        time_s: f64,
        field: &'static str,
        value: f64,
    },
    #[error(
        "battery sample at t = {time_s} s: pack voltage {voltage_v} V is outside the physical \
         range {min_v:.2}..{max_v:.2} V of a {cell_count}-cell pack; check the cell count and \
         the voltage sensor calibration"
    )]
    VoltageOutOfRange {
        time_s: f64,
        voltage_v: f64,
        min_v: f64,
        max_v: f64,
        cell_count: u32,
    },
    #[error(
        "battery sample at t = {time_s} s: current {current_a} A is outside {min_a}..{max_a} A; \
         PX4 and MAVLink send -1 for 'not measured': pass None instead"
    )]
    CurrentOutOfRange {
        time_s: f64,
        current_a: f64,
        min_a: f64,
        max_a: f64,
    },
    #[error(
        "battery sample at t = {time_s} s: consumed charge {consumed_mah} mAh is negative; \
         MAVLink sends -1 for 'not measured': pass None instead"
    )]
    NegativeConsumed { time_s: f64, consumed_mah: f64 },
    #[error(
        "battery sample at t = {time_s} s: remaining fraction {remaining_fraction} is outside \
         0..1; MAVLink's battery_remaining is a percentage (divide by 100) with -1 for \
         'unknown' (pass None)"
    )]
    RemainingOutOfRange {
        time_s: f64,
        remaining_fraction: f64,
    },
    #[error(
        "battery sample at t = {time_s} s carries no voltage, current, consumed charge or \
         remaining fraction"
    )]
    EmptySample { time_s: f64 },
    #[error("PX4 battery CSV is empty: expected a header line naming the columns")]
    CsvEmpty,
    #[error(
        "PX4 battery CSV: the header has no column `{column}` (needed: timestamp, voltage_v, \
         current_a, discharged_mah, remaining)"
    )]
    CsvMissingColumn { column: &'static str },
    #[error("PX4 battery CSV line {line}: {found} fields, but the header names {expected}")]
    CsvFieldCount {
        line: usize,
        expected: usize,
        found: usize,
    },
    #[error("PX4 battery CSV line {line}, column `{column}`: `{text}` is not {expected}")]
    CsvBadValue {
        line: usize,
        column: String,
        text: String,
        expected: &'static str,
    },
}

fn invalid_spec(field: &'static str, value: f64, expected: &'static str) -> BatteryError {
    BatteryError::InvalidSpec {
        field,
        value,
        expected,
    }
}

// ---------------------------------------------------------------------------------------------
// OCV curve
// ---------------------------------------------------------------------------------------------

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

// ---------------------------------------------------------------------------------------------
// Pack
// ---------------------------------------------------------------------------------------------

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

    fn usable_energy_unchecked_wh(&self, load_power_w: f64, from_soc: f64, to_soc: f64) -> f64 {
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

fn check_power(load_power_w: f64) -> Result<(), BatteryError> {
    if load_power_w.is_finite() && load_power_w >= 0.0 {
        Ok(())
    } else {
        Err(BatteryError::InvalidArgument {
            name: "load_power_w",
            value: load_power_w,
            expected: "a power >= 0 W",
        })
    }
}

fn check_soc(name: &'static str, soc: f64) -> Result<(), BatteryError> {
    if (0.0..=1.0).contains(&soc) {
        Ok(())
    } else {
        Err(BatteryError::InvalidArgument {
            name,
            value: soc,
            expected: "a state of charge in 0..1",
        })
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

// ---------------------------------------------------------------------------------------------
// Estimator
// ---------------------------------------------------------------------------------------------

/// One battery telemetry sample, as MAVLink BATTERY_STATUS / SYS_STATUS carry it. Fields the
/// autopilot did not measure are None (convert MAVLink's -1 sentinels to None).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BatterySample {
    /// Sample time; any origin, seconds.
    pub time_s: f64,
    /// Pack terminal voltage.
    pub voltage_v: Option<f64>,
    /// Discharge current (positive out of the pack).
    pub current_a: Option<f64>,
    /// The autopilot's own integral of current since it booted.
    pub consumed_mah: Option<f64>,
    /// The autopilot's remaining estimate, 0..1.
    pub remaining_fraction: Option<f64>,
}

/// Tuning of [`BatteryEstimator`]. The defaults suit a LiPo read at 1–100 Hz.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorConfig {
    /// Error of a resting cell voltage read against the OCV curve (sensor + curve spread).
    pub voltage_sigma_cell_v: f64,
    /// Error of the load compensation as a fraction of `I·R` (polarisation is not in Rint).
    pub load_compensation_rel_sigma: f64,
    /// Cell-voltage error when the current is unknown, so the sag cannot be compensated.
    pub unknown_load_sigma_cell_v: f64,
    /// Voltage errors (model mismatch, polarisation) persist this long: measurements closer
    /// than this share their error and count as one, so the weight given to voltage does not
    /// grow with the telemetry rate.
    pub voltage_correlation_s: f64,
    /// Relative error of counted charge (current-sensor scale, capacity): the SoC standard
    /// deviation grows by this fraction of every counted SoC step (added linearly because the
    /// error is systematic, not random).
    pub coulomb_rel_sigma: f64,
    /// SoC random walk (per √s) while there is nothing to count charge with; voltage then
    /// carries the estimate.
    pub blind_soc_sigma_per_sqrt_s: f64,
    /// Standard deviation given to the autopilot's remaining fraction, used only in samples
    /// without voltage (it is itself a voltage estimate, often load-inflated).
    pub remaining_fraction_sigma: f64,
    /// Intervals longer than this are telemetry gaps.
    pub max_gap_s: f64,
    /// Extra relative error of charge guessed across a gap from the currents at its ends.
    pub gap_rel_sigma: f64,
    /// Time constant of the first-order low-pass on V·I.
    pub power_filter_tau_s: f64,
    /// SoC assumed before any measurement, with its standard deviation. The default (0.5 ±
    /// 0.3, about a uniform prior) means "unknown": the first voltage reading dominates.
    pub initial_soc: f64,
    pub initial_soc_sigma: f64,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            voltage_sigma_cell_v: 0.02,
            load_compensation_rel_sigma: 0.3,
            unknown_load_sigma_cell_v: 0.15,
            voltage_correlation_s: 20.0,
            coulomb_rel_sigma: 0.05,
            blind_soc_sigma_per_sqrt_s: 0.01,
            remaining_fraction_sigma: 0.1,
            max_gap_s: 5.0,
            gap_rel_sigma: 0.5,
            power_filter_tau_s: 2.0,
            initial_soc: 0.5,
            initial_soc_sigma: 0.3,
        }
    }
}

impl EstimatorConfig {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), BatteryError> {
        let non_negative = [
            (
                "load_compensation_rel_sigma",
                self.load_compensation_rel_sigma,
            ),
            ("unknown_load_sigma_cell_v", self.unknown_load_sigma_cell_v),
            ("voltage_correlation_s", self.voltage_correlation_s),
            ("coulomb_rel_sigma", self.coulomb_rel_sigma),
            (
                "blind_soc_sigma_per_sqrt_s",
                self.blind_soc_sigma_per_sqrt_s,
            ),
            ("gap_rel_sigma", self.gap_rel_sigma),
        ];
        for (name, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(BatteryError::InvalidArgument {
                    name,
                    value,
                    expected: "a finite value >= 0",
                });
            }
        }
        // A zero sigma on a measurement would make it infinitely certain.
        let positive = [
            ("voltage_sigma_cell_v", self.voltage_sigma_cell_v),
            ("remaining_fraction_sigma", self.remaining_fraction_sigma),
            ("max_gap_s", self.max_gap_s),
            ("power_filter_tau_s", self.power_filter_tau_s),
            ("initial_soc_sigma", self.initial_soc_sigma),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(BatteryError::InvalidArgument {
                    name,
                    value,
                    expected: "a finite value > 0",
                });
            }
        }
        check_soc("initial_soc", self.initial_soc)
    }
}

/// How the charge of the last interval was counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChargeSource {
    /// First sample: no interval yet.
    Start,
    /// Trapezoid over the currents at both ends.
    Trapezoid,
    /// Only one end had a current: rectangle with it.
    OneEndCurrent,
    /// Difference of the autopilot's consumed_mah (no current, or across a gap).
    AutopilotConsumed,
    /// A gap longer than `max_gap_s` bridged with the currents at its ends, with extra
    /// uncertainty (the drone kept flying while telemetry was lost).
    GapEstimate,
    /// Nothing to count with: SoC uncertainty grows and voltage takes over.
    Blind,
    /// Same timestamp as the previous sample: nothing to integrate.
    Repeated,
    /// Time went backwards (autopilot reboot, reordered packets): no charge counted, the
    /// integration restarts from this sample.
    TimeReset,
}

/// The estimator's answer after one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryEstimate {
    /// Time of the sample.
    pub time_s: f64,
    /// State of charge, 0..1 (chemical: the cutoff is reached above 0).
    pub soc: f64,
    /// Standard deviation of `soc`.
    pub soc_sigma: f64,
    /// Charge counted by this estimator since its first sample (its own integral).
    pub consumed_mah: f64,
    /// Energy still deliverable before the cutoff voltage if the present (filtered) power
    /// were held. It follows the load: a climb burst near the cutoff drops it to 0, as the
    /// pack would at that power. To plan, ask [`BatteryEstimator::remaining_energy_wh_at`]
    /// with the mission's mean power.
    pub remaining_energy_wh: f64,
    /// Filtered V·I; 0 until a sample gives both voltage and current.
    pub power_w: f64,
    /// SoC read from this sample's load-compensated voltage, if it had one.
    pub voltage_soc: Option<f64>,
    /// How this interval's charge was counted.
    pub charge_source: ChargeSource,
}

/// The end of the previous accepted sample, from which the next interval is integrated.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Anchor {
    time_s: f64,
    current_a: Option<f64>,
    consumed_mah: Option<f64>,
}

/// A validated sample (current clamped to >= 0).
#[derive(Debug, Clone, Copy)]
struct CleanSample {
    time_s: f64,
    voltage_v: Option<f64>,
    current_a: Option<f64>,
    consumed_mah: Option<f64>,
    remaining_fraction: Option<f64>,
}

/// Battery state estimator from autopilot telemetry, in the manner of PX4's: coulomb counting
/// fused with SoC read from the load-compensated voltage (`OCV ≈ V + I·R`).
///
/// It is a scalar Kalman filter on SoC. Counting charge moves the estimate and widens its
/// uncertainty a little; each voltage reading pulls it toward the OCV curve's SoC with a
/// weight set by the two uncertainties. That weighs voltage heavily where it should, without
/// special cases: at start (the prior is "unknown"), when there is no current to count with
/// (the uncertainty grows with time), on the steep parts of the curve (a volt says more about
/// SoC there) and at low load (less to compensate). Voltage errors are treated as correlated
/// over `voltage_correlation_s`, so a 100 Hz feed is not trusted more than a 1 Hz one.
///
/// Bad samples are rejected with a named error and leave the state untouched.
#[derive(Debug, Clone, PartialEq)]
pub struct BatteryEstimator {
    spec: BatterySpec,
    config: EstimatorConfig,
    soc: f64,
    soc_var: f64,
    consumed_mah: f64,
    power_w: f64,
    power_time_s: Option<f64>,
    last_fusion_time_s: Option<f64>,
    anchor: Option<Anchor>,
    gaps: u32,
    time_resets: u32,
}

impl BatteryEstimator {
    /// An estimator with the default tuning.
    pub fn new(spec: BatterySpec) -> Result<Self, BatteryError> {
        Self::with_config(spec, EstimatorConfig::default())
    }

    /// An estimator with the given tuning.
    pub fn with_config(spec: BatterySpec, config: EstimatorConfig) -> Result<Self, BatteryError> {
        spec.validate()?;
        config.validate()?;
        Ok(Self {
            soc: config.initial_soc,
            soc_var: config.initial_soc_sigma * config.initial_soc_sigma,
            spec,
            config,
            consumed_mah: 0.0,
            power_w: 0.0,
            power_time_s: None,
            last_fusion_time_s: None,
            anchor: None,
            gaps: 0,
            time_resets: 0,
        })
    }

    pub fn spec(&self) -> &BatterySpec {
        &self.spec
    }

    pub fn config(&self) -> &EstimatorConfig {
        &self.config
    }

    pub fn soc(&self) -> f64 {
        self.soc
    }

    pub fn soc_sigma(&self) -> f64 {
        self.soc_var.sqrt()
    }

    /// Charge counted since the first sample.
    pub fn consumed_mah(&self) -> f64 {
        self.consumed_mah
    }

    /// Filtered V·I.
    pub fn power_w(&self) -> f64 {
        self.power_w
    }

    /// Telemetry gaps longer than `max_gap_s` seen so far.
    pub fn gaps(&self) -> u32 {
        self.gaps
    }

    /// Times the sample clock went backwards.
    pub fn time_resets(&self) -> u32 {
        self.time_resets
    }

    /// Energy deliverable from the present SoC to the cutoff at a constant `load_power_w`
    /// (the planner's question, for a power other than the present one).
    pub fn remaining_energy_wh_at(&self, load_power_w: f64) -> Result<f64, BatteryError> {
        check_power(load_power_w)?;
        Ok(self
            .spec
            .usable_energy_unchecked_wh(load_power_w, self.soc, 0.0))
    }

    /// Folds one sample in. A sample with a non-finite field, a voltage outside the physical
    /// range of the pack, a current below -0.5 A or above `max_current_a`, a negative consumed
    /// charge, a remaining fraction outside 0..1, or no measurement at all is rejected with a
    /// [`BatteryError`] and changes nothing. Currents in -0.5..0 A (sensor offset at idle)
    /// count as 0.
    pub fn update(&mut self, sample: BatterySample) -> Result<BatteryEstimate, BatteryError> {
        let s = self.validate_sample(&sample)?;

        let (delta_mah, source, derived_current_a) = self.count_charge(&s);
        self.consumed_mah += delta_mah;
        let delta_soc = delta_mah / self.spec.capacity_mah;
        let mut sigma = self.soc_var.sqrt() + self.config.coulomb_rel_sigma * delta_soc.abs();
        if source == ChargeSource::GapEstimate {
            sigma += self.config.gap_rel_sigma * delta_soc.abs();
        }
        self.soc_var = sigma * sigma;
        if source == ChargeSource::Blind {
            if let Some(a) = self.anchor {
                let blind = self.config.blind_soc_sigma_per_sqrt_s;
                self.soc_var += blind * blind * (s.time_s - a.time_s);
            }
        }
        self.soc = (self.soc - delta_soc).clamp(0.0, 1.0);

        let current_a = s.current_a.or(derived_current_a);
        let mut voltage_soc = None;
        if let Some(voltage_v) = s.voltage_v {
            let n = f64::from(self.spec.cell_count);
            let r = self.spec.internal_resistance_ohm;
            let (i_comp, load_sigma) = match current_a {
                Some(i) => (i, self.config.load_compensation_rel_sigma * i * r / n),
                None => (0.0, self.config.unknown_load_sigma_cell_v),
            };
            let cell_ocv_v = (voltage_v + i_comp * r) / n;
            let measured = self.spec.ocv.soc_at_cell_ocv_v(cell_ocv_v);
            let sigma_cell_v = self.config.voltage_sigma_cell_v.hypot(load_sigma);
            let sigma_soc = sigma_cell_v / self.spec.ocv.slope_v_per_soc(measured);
            self.fuse(measured, sigma_soc, s.time_s);
            voltage_soc = Some(measured);
        } else if let Some(remaining) = s.remaining_fraction {
            // Only without voltage: with it, this would count the same voltage twice.
            self.fuse(remaining, self.config.remaining_fraction_sigma, s.time_s);
        }

        if let (Some(v), Some(i)) = (s.voltage_v, current_a) {
            self.filter_power(v * i, s.time_s);
        }

        self.anchor = Some(Anchor {
            time_s: s.time_s,
            current_a: s.current_a,
            consumed_mah: s.consumed_mah,
        });

        Ok(BatteryEstimate {
            time_s: s.time_s,
            soc: self.soc,
            soc_sigma: self.soc_var.sqrt(),
            consumed_mah: self.consumed_mah,
            remaining_energy_wh: self
                .spec
                .usable_energy_unchecked_wh(self.power_w, self.soc, 0.0),
            power_w: self.power_w,
            voltage_soc,
            charge_source: source,
        })
    }

    fn validate_sample(&self, sample: &BatterySample) -> Result<CleanSample, BatteryError> {
        let time_s = sample.time_s;
        let finite = |field: &'static str, value: f64| {
            if value.is_finite() {
                Ok(value)
            } else {
                Err(BatteryError::NonFinite {
                    time_s,
                    field,
                    value,
                })
            }
        };
        finite("time_s", time_s)?;
        let n = f64::from(self.spec.cell_count);
        let voltage_v = match sample.voltage_v {
            Some(v) => {
                let v = finite("voltage_v", v)?;
                let min_v = n * MIN_PLAUSIBLE_CELL_V;
                let max_v = n * (self.spec.full_cell_voltage_v + MAX_CELL_OVERSHOOT_V);
                if v < min_v || v > max_v {
                    return Err(BatteryError::VoltageOutOfRange {
                        time_s,
                        voltage_v: v,
                        min_v,
                        max_v,
                        cell_count: self.spec.cell_count,
                    });
                }
                Some(v)
            }
            None => None,
        };
        let current_a = match sample.current_a {
            Some(i) => {
                let i = finite("current_a", i)?;
                if !(-NEGATIVE_CURRENT_TOLERANCE_A..=self.spec.max_current_a).contains(&i) {
                    return Err(BatteryError::CurrentOutOfRange {
                        time_s,
                        current_a: i,
                        min_a: -NEGATIVE_CURRENT_TOLERANCE_A,
                        max_a: self.spec.max_current_a,
                    });
                }
                Some(i.max(0.0))
            }
            None => None,
        };
        let consumed_mah = match sample.consumed_mah {
            Some(c) => {
                let c = finite("consumed_mah", c)?;
                if c < 0.0 {
                    return Err(BatteryError::NegativeConsumed {
                        time_s,
                        consumed_mah: c,
                    });
                }
                Some(c)
            }
            None => None,
        };
        let remaining_fraction = match sample.remaining_fraction {
            Some(f) => {
                let f = finite("remaining_fraction", f)?;
                if !(0.0..=1.0).contains(&f) {
                    return Err(BatteryError::RemainingOutOfRange {
                        time_s,
                        remaining_fraction: f,
                    });
                }
                Some(f)
            }
            None => None,
        };
        if voltage_v.is_none()
            && current_a.is_none()
            && consumed_mah.is_none()
            && remaining_fraction.is_none()
        {
            return Err(BatteryError::EmptySample { time_s });
        }
        Ok(CleanSample {
            time_s,
            voltage_v,
            current_a,
            consumed_mah,
            remaining_fraction,
        })
    }

    /// Charge (mAh) drawn since the previous sample, how it was counted, and the mean current
    /// implied by the autopilot's count when that was used (for compensation and power).
    /// Records gaps and time resets.
    fn count_charge(&mut self, s: &CleanSample) -> (f64, ChargeSource, Option<f64>) {
        let Some(a) = self.anchor else {
            return (0.0, ChargeSource::Start, None);
        };
        let dt = s.time_s - a.time_s;
        if dt < 0.0 {
            self.time_resets += 1;
            return (0.0, ChargeSource::TimeReset, None);
        }
        if dt == 0.0 {
            return (0.0, ChargeSource::Repeated, None);
        }
        // The autopilot integrates every sensor reading; its difference is exact when usable
        // (it falls when the autopilot reboots).
        let autopilot = match (a.consumed_mah, s.consumed_mah) {
            (Some(c0), Some(c1)) if c1 >= c0 => Some(c1 - c0),
            _ => None,
        };
        let from_autopilot = |d: f64| {
            (
                d,
                ChargeSource::AutopilotConsumed,
                Some(d * AS_PER_MAH / dt),
            )
        };
        let gap = dt > self.config.max_gap_s;
        if gap {
            self.gaps += 1;
        }
        match (a.current_a, s.current_a, autopilot) {
            (_, _, Some(d)) if gap => from_autopilot(d),
            (Some(i0), Some(i1), _) => {
                let source = if gap {
                    ChargeSource::GapEstimate
                } else {
                    ChargeSource::Trapezoid
                };
                (0.5 * (i0 + i1) * dt / AS_PER_MAH, source, None)
            }
            (_, _, Some(d)) => from_autopilot(d),
            (Some(i), None, None) | (None, Some(i), None) => {
                let source = if gap {
                    ChargeSource::GapEstimate
                } else {
                    ChargeSource::OneEndCurrent
                };
                (i * dt / AS_PER_MAH, source, None)
            }
            (None, None, None) => (0.0, ChargeSource::Blind, None),
        }
    }

    /// Kalman update of SoC with a measurement `measured_soc ± sigma_soc`.
    fn fuse(&mut self, measured_soc: f64, sigma_soc: f64, time_s: f64) {
        // Errors persist for the correlation time: a measurement `dt` after the previous one
        // brings only `dt / correlation` of an independent one.
        let inflation = match self.last_fusion_time_s {
            None => 1.0,
            Some(t) => {
                let dt = (time_s - t).max(MIN_FUSION_DT_S);
                (self.config.voltage_correlation_s / dt).max(1.0)
            }
        };
        let r = sigma_soc * sigma_soc * inflation;
        let gain = self.soc_var / (self.soc_var + r);
        self.soc = (self.soc + gain * (measured_soc - self.soc)).clamp(0.0, 1.0);
        self.soc_var *= 1.0 - gain;
        self.last_fusion_time_s = Some(time_s);
    }

    /// First-order low-pass of V·I over irregular steps; restarts when time runs backwards.
    fn filter_power(&mut self, power_w: f64, time_s: f64) {
        match self.power_time_s {
            Some(t) if time_s >= t => {
                let alpha = 1.0 - (-(time_s - t) / self.config.power_filter_tau_s).exp();
                self.power_w += alpha * (power_w - self.power_w);
            }
            _ => self.power_w = power_w,
        }
        self.power_time_s = Some(time_s);
    }
}

// ---------------------------------------------------------------------------------------------
// PX4 battery_status CSV
// ---------------------------------------------------------------------------------------------

/// One row of a PX4 ULog `battery_status` topic exported to CSV (pyulog's `ulog2csv`).
/// Columns newer PX4 versions dropped (`voltage_filtered_v`, `current_filtered_a`) or added
/// later are optional.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Px4BatteryRow {
    pub timestamp_us: u64,
    pub voltage_v: f64,
    pub voltage_filtered_v: Option<f64>,
    pub current_a: f64,
    pub current_filtered_a: Option<f64>,
    pub discharged_mah: f64,
    pub remaining: f64,
    pub scale: Option<f64>,
    pub cell_count: Option<u32>,
    pub connected: Option<bool>,
    pub warning: Option<u32>,
}

impl Px4BatteryRow {
    /// Timestamp in seconds.
    pub fn time_s(&self) -> f64 {
        self.timestamp_us as f64 * 1e-6
    }

    /// The row as the estimator's sample. PX4's "unknown" markers become None: a voltage of 0
    /// or less (no battery), a negative current, discharged charge or remaining (-1).
    /// Non-finite values pass through, so the estimator reports them.
    pub fn to_sample(&self) -> BatterySample {
        // NaN is kept (and reported by the estimator), only PX4's sentinels are dropped.
        let known_if = |v: f64, known: bool| (known || v.is_nan()).then_some(v);
        BatterySample {
            time_s: self.time_s(),
            voltage_v: known_if(self.voltage_v, self.voltage_v > 0.0),
            current_a: known_if(self.current_a, self.current_a >= 0.0),
            consumed_mah: known_if(self.discharged_mah, self.discharged_mah >= 0.0),
            remaining_fraction: known_if(self.remaining, self.remaining >= 0.0),
        }
    }
}

/// Parses the CSV of a PX4 `battery_status` topic, finding columns by their header names
/// (any order, extra columns ignored). Required: `timestamp` (µs, integer), `voltage_v`,
/// `current_a`, `discharged_mah`, `remaining`. Blank lines are skipped; `nan` parses as NaN.
/// Line numbers in errors count the header as line 1.
pub fn parse_px4_battery_csv(text: &str) -> Result<Vec<Px4BatteryRow>, BatteryError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')))
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().ok_or(BatteryError::CsvEmpty)?;
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let find = |name: &str| names.iter().position(|&n| n == name);
    let require =
        |name: &'static str| find(name).ok_or(BatteryError::CsvMissingColumn { column: name });
    let c_timestamp = require("timestamp")?;
    let c_voltage = require("voltage_v")?;
    let c_current = require("current_a")?;
    let c_discharged = require("discharged_mah")?;
    let c_remaining = require("remaining")?;
    let c_voltage_f = find("voltage_filtered_v");
    let c_current_f = find("current_filtered_a");
    let c_scale = find("scale");
    let c_cells = find("cell_count");
    let c_connected = find("connected");
    let c_warning = find("warning");

    let mut rows = Vec::new();
    for (line, text) in lines {
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err(BatteryError::CsvFieldCount {
                line,
                expected: names.len(),
                found: fields.len(),
            });
        }
        let bad = |col: usize, expected: &'static str| BatteryError::CsvBadValue {
            line,
            column: names[col].to_string(),
            text: fields[col].to_string(),
            expected,
        };
        let float = |col: usize| fields[col].parse::<f64>().map_err(|_| bad(col, "a number"));
        let unsigned = |col: usize| {
            fields[col]
                .parse::<u32>()
                .map_err(|_| bad(col, "a non-negative integer"))
        };
        let opt_float = |col: Option<usize>| col.map(float).transpose();
        let connected = match c_connected {
            None => None,
            Some(col) => Some(match fields[col] {
                "1" | "true" | "True" => true,
                "0" | "false" | "False" => false,
                _ => return Err(bad(col, "a boolean (0/1/true/false)")),
            }),
        };
        rows.push(Px4BatteryRow {
            timestamp_us: fields[c_timestamp]
                .parse::<u64>()
                .map_err(|_| bad(c_timestamp, "a timestamp in integer microseconds"))?,
            voltage_v: float(c_voltage)?,
            voltage_filtered_v: opt_float(c_voltage_f)?,
            current_a: float(c_current)?,
            current_filtered_a: opt_float(c_current_f)?,
            discharged_mah: float(c_discharged)?,
            remaining: float(c_remaining)?,
            scale: opt_float(c_scale)?,
            cell_count: c_cells.map(unsigned).transpose()?,
            connected,
            warning: c_warning.map(unsigned).transpose()?,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    fn lipo_4s(capacity_mah: f64, r_ohm: f64) -> BatterySpec {
        BatterySpec::from_capacity_mah(capacity_mah, 4, 3.7, r_ohm).unwrap()
    }

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

    fn gaussian(rng: &mut StdRng) -> f64 {
        // Box-Muller; 1 - u keeps the logarithm finite.
        let u: f64 = 1.0 - rng.random::<f64>();
        let v: f64 = rng.random::<f64>();
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
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

    // ---- PX4 CSV ------------------------------------------------------------------------

    const CSV_HEADER: &str = "timestamp,voltage_v,voltage_filtered_v,current_a,current_filtered_a,discharged_mah,remaining,scale,cell_count,connected,warning";

    #[test]
    fn csv_parses_by_column_name() {
        let text = format!(
            "{CSV_HEADER}\r\n226493702,14.002368,15.776365,33.366684,20.161938,24.618793,0.91272706,1.0171117,4,1,0\r\n\n\
             226793719,13.794987,15.381584,-1,25.297806,27.37938,0.8928354,1.021094,4,0,2\n"
        );
        let rows = parse_px4_battery_csv(&text).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].timestamp_us, 226_493_702);
        assert_eq!(rows[0].voltage_v, 14.002368);
        assert_eq!(rows[0].voltage_filtered_v, Some(15.776365));
        assert_eq!(rows[0].cell_count, Some(4));
        assert_eq!(rows[1].connected, Some(false));
        assert_eq!(rows[1].warning, Some(2));
        let s = rows[1].to_sample();
        assert_eq!(s.current_a, None, "PX4's -1 means unknown");
        assert_eq!(s.voltage_v, Some(13.794987));
        assert!((s.time_s - 226.793719).abs() < 1e-9);

        // Another column order, optional columns absent.
        let rows = parse_px4_battery_csv(
            "remaining,current_a,timestamp,discharged_mah,voltage_v\n0.5,3.0,1000000,12.5,15.9\n",
        )
        .unwrap();
        assert_eq!(rows[0].remaining, 0.5);
        assert_eq!(rows[0].voltage_filtered_v, None);
        assert_eq!(rows[0].connected, None);
    }

    #[test]
    fn csv_errors_name_the_column_and_line() {
        assert_eq!(parse_px4_battery_csv(""), Err(BatteryError::CsvEmpty));
        assert_eq!(
            parse_px4_battery_csv("timestamp,voltage_v,current_a,remaining\n"),
            Err(BatteryError::CsvMissingColumn {
                column: "discharged_mah"
            })
        );
        let text = format!("{CSV_HEADER}\n1,15,15,3,3,1,0.9,1,4,1,0\n2,15,15,3x,3,1,0.9,1,4,1,0\n");
        match parse_px4_battery_csv(&text) {
            Err(BatteryError::CsvBadValue {
                line, column, text, ..
            }) => {
                assert_eq!(
                    (line, column.as_str(), text.as_str()),
                    (3, "current_a", "3x")
                );
            }
            other => panic!("{other:?}"),
        }
        let text = format!("{CSV_HEADER}\n1.5,15,15,3,3,1,0.9,1,4,1,0\n");
        assert!(matches!(
            parse_px4_battery_csv(&text),
            Err(BatteryError::CsvBadValue { line: 2, .. })
        ));
        let text = format!("{CSV_HEADER}\n1,15,15,3,3,1,0.9,1,4,maybe,0\n");
        assert!(matches!(
            parse_px4_battery_csv(&text),
            Err(BatteryError::CsvBadValue { .. })
        ));
        let text = format!("{CSV_HEADER}\n1,15,15,3\n");
        assert_eq!(
            parse_px4_battery_csv(&text),
            Err(BatteryError::CsvFieldCount {
                line: 2,
                expected: 11,
                found: 4
            })
        );
        let msg = BatteryError::CsvMissingColumn {
            column: "remaining",
        }
        .to_string();
        assert!(msg.contains("remaining"));
    }

    // ---- the real PX4 flight log --------------------------------------------------------------

    fn px4_log_rows() -> Option<Vec<Px4BatteryRow>> {
        let rel = "data/px4-flight-battery/battery_status.csv";
        let candidates = [
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../../shared")
                .join(rel),
            std::path::Path::new("/work/shared").join(rel),
        ];
        for path in &candidates {
            if let Ok(text) = std::fs::read_to_string(path) {
                return Some(parse_px4_battery_csv(&text).unwrap());
            }
        }
        eprintln!("skipped: the PX4 flight log is absent (looked for {candidates:?})");
        None
    }

    /// Capacity and resistance from the log's own voltage and current, without `remaining`:
    /// for each trial R, read SoC from the OCV curve at (V + I·R)/n and regress it on
    /// discharged_mah; the slope is −1/C and the R with the smallest residual wins.
    /// Returns (capacity mAh, R Ω, residual).
    fn fit_capacity_and_resistance(rows: &[Px4BatteryRow], cells: f64) -> (f64, f64, f64) {
        let curve = OcvCurve::lipo();
        let mut best = (f64::NAN, f64::NAN, f64::INFINITY);
        for k in 0..=60 {
            let r = k as f64 * 0.0025;
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .map(|row| {
                    (
                        row.discharged_mah,
                        curve.soc_at_cell_ocv_v((row.voltage_v + row.current_a * r) / cells),
                    )
                })
                .collect();
            let n = pts.len() as f64;
            let (mx, my) = (
                pts.iter().map(|p| p.0).sum::<f64>() / n,
                pts.iter().map(|p| p.1).sum::<f64>() / n,
            );
            let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
            let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
            let slope = sxy / sxx;
            let resid = (pts
                .iter()
                .map(|p| (p.1 - my - slope * (p.0 - mx)).powi(2))
                .sum::<f64>()
                / n)
                .sqrt();
            if resid < best.2 {
                best = (-1.0 / slope, r, resid);
            }
        }
        best
    }

    /// Capacity from the drop of PX4's `remaining` against discharged_mah, between the first
    /// and the last 30 % of the in-flight stretch where `remaining` is no longer clipped at 1,
    /// comparing rows at the same load (median current ± 1 A) so PX4's load compensation,
    /// which inflates `remaining` in flight, cancels.
    fn capacity_from_remaining_drop(rows: &[Px4BatteryRow], landing: usize) -> f64 {
        let last_clipped = rows[..landing]
            .iter()
            .rposition(|r| r.remaining >= 0.9999)
            .unwrap_or(0);
        let span = &rows[last_clipped..landing];
        let mut currents: Vec<f64> = span.iter().map(|r| r.current_a).collect();
        currents.sort_by(f64::total_cmp);
        let median = currents[currents.len() / 2];
        let (t0, t1) = (span[0].time_s(), span[span.len() - 1].time_s());
        let mean_of = |lo: f64, hi: f64| {
            let sel: Vec<&Px4BatteryRow> = span
                .iter()
                .filter(|r| {
                    r.time_s() >= lo && r.time_s() < hi && (r.current_a - median).abs() <= 1.0
                })
                .collect();
            let n = sel.len() as f64;
            (
                sel.iter().map(|r| r.discharged_mah).sum::<f64>() / n,
                sel.iter().map(|r| r.remaining).sum::<f64>() / n,
            )
        };
        let w = 0.3 * (t1 - t0);
        let (mah_a, rem_a) = mean_of(t0, t0 + w);
        let (mah_b, rem_b) = mean_of(t1 - w, t1 + 1.0);
        (mah_b - mah_a) / (rem_a - rem_b)
    }

    struct Px4Run {
        rows: Vec<Px4BatteryRow>,
        estimates: Vec<BatteryEstimate>,
        capacity_mah: f64,
        resistance_ohm: f64,
        capacity_from_remaining_mah: f64,
        landing: usize,
    }

    fn run_on_px4_log() -> Option<Px4Run> {
        let rows = px4_log_rows()?;
        let cells = rows[0].cell_count.unwrap_or(4);
        assert_eq!(cells, 4);
        // Landing: the last row drawing flight current (> 1 A); after it the pack rests.
        let landing = rows.iter().rposition(|r| r.current_a > 1.0).unwrap();
        let (capacity_mah, resistance_ohm, resid) =
            fit_capacity_and_resistance(&rows, f64::from(cells));
        let capacity_from_remaining_mah = capacity_from_remaining_drop(&rows, landing);
        eprintln!(
            "PX4 log: {} rows, {:.0} s; capacity fitted from V, I, discharged: {capacity_mah:.0} mAh, \
             R {resistance_ohm:.4} ohm (SoC residual {resid:.4}); from the drop of `remaining`: \
             {capacity_from_remaining_mah:.0} mAh",
            rows.len(),
            rows[rows.len() - 1].time_s() - rows[0].time_s()
        );
        let spec =
            BatterySpec::from_capacity_mah(capacity_mah, cells, 3.7, resistance_ohm).unwrap();
        let mut est = BatteryEstimator::new(spec).unwrap();
        let estimates = rows
            .iter()
            .map(|r| est.update(r.to_sample()).unwrap())
            .collect::<Vec<_>>();
        // PX4_TRACE=1 prints the run every 100 rows.
        if std::env::var_os("PX4_TRACE").is_some() {
            for (r, e) in rows.iter().zip(&estimates).step_by(100) {
                eprintln!("{:8.1} V {:6.3} I {:6.2} soc {:.4} sig {:.4} vsoc {:.4} rem {:.4} E {:.1} P {:.1}", r.time_s() - rows[0].time_s(), r.voltage_v, r.current_a, e.soc, e.soc_sigma, e.voltage_soc.unwrap_or(f64::NAN), r.remaining, e.remaining_energy_wh, e.power_w);
            }
        }
        Some(Px4Run {
            rows,
            estimates,
            capacity_mah,
            resistance_ohm,
            capacity_from_remaining_mah,
            landing,
        })
    }

    #[test]
    fn px4_log_coulomb_count_matches_discharged_mah() {
        let Some(run) = run_on_px4_log() else { return };
        let base = run.rows[0].discharged_mah;
        let total = run.rows[run.rows.len() - 1].discharged_mah - base;
        let (mut max_err, mut bound_sq) = (0.0_f64, 0.0);
        for (k, (row, e)) in run.rows.iter().zip(&run.estimates).enumerate() {
            max_err = max_err.max((e.consumed_mah - (row.discharged_mah - base)).abs());
            if k > 0 {
                let prev = &run.rows[k - 1];
                let dt = row.time_s() - prev.time_s();
                bound_sq += ((row.current_a - prev.current_a).abs() * dt / 2.0 / 3.6).powi(2);
            }
        }
        let final_err = run.estimates[run.estimates.len() - 1].consumed_mah - total;
        // PX4 integrates every sensor reading, the log keeps one every ~0.3 s. Within a step
        // the trapezoid cannot know the path; its error there is of the order of half the
        // current change times dt. Summed as independent errors that is `bound`; 3 bound
        // is the tolerance.
        let bound = 3.0 * bound_sq.sqrt();
        eprintln!(
            "PX4 log coulomb count: {:.2} mAh counted vs {total:.2} logged; final error \
             {final_err:+.3} mAh ({:+.4} %), max error {max_err:.3} mAh ({:.4} %); tolerance {bound:.2} mAh",
            run.estimates[run.estimates.len() - 1].consumed_mah,
            100.0 * final_err / total,
            100.0 * max_err / total,
        );
        assert!(final_err.abs() <= bound, "final {final_err} > {bound}");
        assert!(max_err <= bound, "max {max_err} > {bound}");
        assert!(
            bound < 0.005 * total,
            "the tolerance itself must stay small: {bound}"
        );
    }

    #[test]
    fn px4_log_soc_against_logged_remaining() {
        let Some(run) = run_on_px4_log() else { return };
        let Px4Run {
            rows,
            estimates,
            landing,
            ..
        } = &run;
        // The two capacity estimates come from independent data; they must roughly agree.
        let ratio = run.capacity_from_remaining_mah / run.capacity_mah;
        assert!(
            (0.75..=1.25).contains(&ratio),
            "capacities disagree: ratio {ratio}"
        );
        assert!(
            (0.03..=0.12).contains(&run.resistance_ohm),
            "R {}",
            run.resistance_ohm
        );

        let stats = |sel: &[usize]| {
            let errs: Vec<f64> = sel
                .iter()
                .map(|&k| estimates[k].soc - rows[k].remaining)
                .collect();
            let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
            let max = errs.iter().fold(0.0_f64, |m, e| m.max(e.abs()));
            let mean = errs.iter().sum::<f64>() / errs.len() as f64;
            (rms, max, mean, errs.len())
        };
        let all: Vec<usize> = (0..rows.len()).collect();
        let unclipped: Vec<usize> = (0..*landing)
            .filter(|&k| rows[k].remaining < 0.9999)
            .collect();
        // At rest after landing, 5 s on, when PX4's load compensation no longer inflates it.
        let t_land = rows[*landing].time_s();
        let rest: Vec<usize> = (*landing..rows.len())
            .filter(|&k| rows[k].time_s() > t_land + 5.0)
            .collect();
        let (rms_all, max_all, mean_all, n_all) = stats(&all);
        let (rms_unc, max_unc, mean_unc, n_unc) = stats(&unclipped);
        let (rms_rest, max_rest, mean_rest, n_rest) = stats(&rest);
        // How much PX4's in-flight compensation lifts `remaining`: its jump at landing, where
        // no charge is drawn (mean of the last 10 s of flight against the rest).
        let flight_tail: Vec<usize> = (0..*landing)
            .filter(|&k| rows[k].time_s() > t_land - 10.0)
            .collect();
        let mean_rem =
            |sel: &[usize]| sel.iter().map(|&k| rows[k].remaining).sum::<f64>() / sel.len() as f64;
        let inflation = mean_rem(&flight_tail) - mean_rem(&rest);
        // PX4 computes `scale = v_charged / (v_empty + (v_charged - v_empty)·soc_voltage)` from
        // its voltage-only SoC; if `remaining` is that SoC, 1/scale = r + a·(1 - r) holds with
        // one constant a = v_empty / v_charged on every row.
        let ratios: Vec<f64> = rows
            .iter()
            .filter(|r| r.remaining < 0.99)
            .filter_map(|r| Some((1.0 / r.scale? - r.remaining) / (1.0 - r.remaining)))
            .collect();
        let (a_min, a_max) = ratios
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &a| {
                (lo.min(a), hi.max(a))
            });
        let t_settled = rows[0].time_s() + 60.0;
        let settled = rows.iter().position(|r| r.time_s() >= t_settled).unwrap();
        let first = &estimates[settled];
        let last = &estimates[estimates.len() - 1];
        eprintln!(
            "PX4 log SoC (ours - remaining): all {n_all} rows RMS {rms_all:.3} max {max_all:.3} mean {mean_all:+.3}; \
             unclipped in flight {n_unc} rows RMS {rms_unc:.3} max {max_unc:.3} mean {mean_unc:+.3}; \
             at rest after landing {n_rest} rows RMS {rms_rest:.3} max {max_rest:.3} mean {mean_rest:+.3}; \
             `remaining` clipped at 1 in {} rows; its jump at landing {inflation:.3}; PX4 v_empty/v_charged \
             from `scale` {a_min:.5}..{a_max:.5} over {} rows; our SoC {:.3} (60 s) -> {:.3} \
             (sigma {:.3}), remaining {:.3} -> {:.3}; remaining energy at rest {:.1} Wh",
            rows.len() - rows.iter().filter(|r| r.remaining < 0.9999).count(),
            ratios.len(),
            first.soc,
            last.soc,
            last.soc_sigma,
            rows[0].remaining,
            rows[rows.len() - 1].remaining,
            last.remaining_energy_wh,
        );
        // So the reference is PX4's voltage-only estimate (no capacity configured: it also stays
        // at 1 while 1.6 Ah are drawn), a linear map of cell voltage between v_empty and
        // v_charged (ratio ~0.807, e.g. 3.35/4.15 V), lifted in flight by its throttle-based load
        // compensation and clipped at 1. It is not a true SoC, and the assertions say what
        // agreement that allows:
        // - at rest after landing, where the lift is (mostly) gone, the two voltage→SoC maps
        //   (linear vs LiPo curve) must agree within 0.1;
        // - in flight, ours sits below by about PX4's lift, which the log itself shows as the
        //   jump of `remaining` at landing (no charge drawn then), within 0.1;
        // - over the whole log the gap is that lift plus clipping: RMS 0.25, max 0.3.
        assert!(
            a_max - a_min < 1e-3,
            "remaining is not PX4's voltage estimate"
        );
        assert!(
            inflation > 0.05,
            "expected PX4's remaining to drop at landing: {inflation}"
        );
        assert!(max_rest < 0.1, "at rest: {max_rest}");
        assert!(
            mean_unc < 0.0,
            "ours should sit below the load-lifted reference: {mean_unc}"
        );
        assert!(
            (mean_unc.abs() - inflation).abs() < 0.1,
            "lift {inflation} vs mean gap {mean_unc}"
        );
        assert!(max_unc < inflation + 0.15, "{max_unc}");
        assert!(max_all < 0.3, "{max_all}");
        assert!(rms_all < 0.25, "{rms_all}");
        // After the first minute ours never steps up by more than voltage noise allows.
        let rises = estimates[settled..]
            .windows(2)
            .map(|w| w[1].soc - w[0].soc)
            .fold(0.0_f64, f64::max);
        assert!(rises < 0.01, "largest single-step rise {rises}");
    }
}
