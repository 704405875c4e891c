//! Battery: a LiPo pack model and the energy it can deliver to a constant-power load
//! (`pack.rs`), a state-of-charge estimator fed by autopilot telemetry (`estimator.rs`), and a
//! reader for PX4's `battery_status` CSV export (`px4_log.rs`).
//!
//! # SoC conventions
//!
//! SoC is the chemical state of charge, 0 = fully discharged, 1 = full at rest. The empty
//! cutoff (`empty_cell_voltage_v`, a voltage *under load*) is reached at a SoC above 0, and
//! earlier the heavier the load: that is exactly what [`BatterySpec::usable_energy_wh`] and
//! [`BatteryEstimate::remaining_energy_wh`] account for.

use thiserror::Error;

mod estimator;
mod pack;
mod px4_log;

pub use estimator::{
    BatteryEstimate, BatteryEstimator, BatterySample, ChargeSource, EstimatorConfig,
};
pub use pack::{BatterySpec, OcvCurve};
pub use px4_log::{parse_px4_battery_csv, Px4BatteryRow};

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

/// A 4-cell LiPo of 3.7 V cells, the pack most tests use.
#[cfg(test)]
fn lipo_4s(capacity_mah: f64, r_ohm: f64) -> BatterySpec {
    BatterySpec::from_capacity_mah(capacity_mah, 4, 3.7, r_ohm).unwrap()
}
