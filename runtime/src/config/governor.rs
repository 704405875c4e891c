//! The governor's tuning: the `[governor]` section of the mission config.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A `[governor]` value out of its range.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("governor config: {field} = {value} is invalid, expected {expected}")]
pub struct BadGovernorConfig {
    pub field: &'static str,
    pub value: f64,
    pub expected: &'static str,
}

/// Tuning of the governor. Every field has a default suited to a multirotor mission of tens of
/// minutes with telemetry at 1–50 Hz.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GovernorConfig {
    /// Re-plan at least this often.
    pub replan_period_s: f64,
    /// A switch to higher levels waits this long after the previous change.
    pub min_dwell_s: f64,
    /// A switch up needs this fraction of the budget left over after the new plan.
    pub switch_up_margin_fraction: f64,
    /// …and at least this many standard deviations of the estimated remaining energy.
    pub switch_up_margin_sigma: f64,
    /// Time constant of the low-pass on the measured-to-predicted power ratio.
    pub correction_tau_s: f64,
    /// Ratios of measured to predicted power outside this range are ignored.
    pub correction_min: f64,
    pub correction_max: f64,
    /// Re-plan at once when the measured remaining energy falls this fraction of the pack's
    /// usable energy below the prediction made at the last re-plan.
    pub drain_divergence_fraction: f64,
    /// Land now only when the cheapest levels fall short by more than this many standard
    /// deviations of the estimated remaining energy…
    pub land_now_sigma: f64,
    /// …capped at this fraction of the reserve, so an uncertain estimate cannot eat into the
    /// reserve without limit.
    pub land_now_max_tolerance_fraction: f64,
    /// Time constant of the low-pass on voltage and current before the battery estimator;
    /// 0 feeds it raw readings.
    pub telemetry_filter_tau_s: f64,
    /// No decision before telemetry has come in for this long: the estimator reads the SoC
    /// from the first voltages, and one noisy reading must not land the vehicle.
    pub warmup_s: f64,
}

impl Default for GovernorConfig {
    fn default() -> Self {
        Self {
            replan_period_s: 10.0,
            min_dwell_s: 60.0,
            switch_up_margin_fraction: 0.02,
            switch_up_margin_sigma: 1.0,
            correction_tau_s: 30.0,
            correction_min: 0.5,
            correction_max: 2.0,
            drain_divergence_fraction: 0.005,
            land_now_sigma: 1.0,
            land_now_max_tolerance_fraction: 0.25,
            telemetry_filter_tau_s: 5.0,
            warmup_s: 30.0,
        }
    }
}

impl GovernorConfig {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), BadGovernorConfig> {
        let bad = |field: &'static str, value: f64, expected: &'static str| {
            Err(BadGovernorConfig {
                field,
                value,
                expected,
            })
        };
        let positive = [
            ("replan_period_s", self.replan_period_s),
            ("correction_tau_s", self.correction_tau_s),
            ("drain_divergence_fraction", self.drain_divergence_fraction),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return bad(field, value, "a finite number > 0");
            }
        }
        let non_negative = [
            ("min_dwell_s", self.min_dwell_s),
            ("switch_up_margin_sigma", self.switch_up_margin_sigma),
            ("land_now_sigma", self.land_now_sigma),
            ("telemetry_filter_tau_s", self.telemetry_filter_tau_s),
            ("warmup_s", self.warmup_s),
        ];
        for (field, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return bad(field, value, "a finite number >= 0");
            }
        }
        if !(0.0..1.0).contains(&self.switch_up_margin_fraction) {
            return bad(
                "switch_up_margin_fraction",
                self.switch_up_margin_fraction,
                "a fraction in [0, 1)",
            );
        }
        if !(0.0..=1.0).contains(&self.land_now_max_tolerance_fraction) {
            return bad(
                "land_now_max_tolerance_fraction",
                self.land_now_max_tolerance_fraction,
                "a fraction in [0, 1]",
            );
        }
        if !(self.correction_min.is_finite()
            && self.correction_min > 0.0
            && self.correction_min <= 1.0)
        {
            return bad("correction_min", self.correction_min, "a ratio in (0, 1]");
        }
        if !(self.correction_max.is_finite() && self.correction_max >= 1.0) {
            return bad("correction_max", self.correction_max, "a finite ratio >= 1");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The proposed `[governor]` section of qos.toml: every key optional, unknown keys named.
    #[test]
    fn config_reads_from_a_toml_section() {
        let config: GovernorConfig =
            toml::from_str("replan_period_s = 5.0\nmin_dwell_s = 90.0\n").unwrap();
        assert_eq!(config.replan_period_s, 5.0);
        assert_eq!(config.min_dwell_s, 90.0);
        assert_eq!(
            config.correction_tau_s,
            GovernorConfig::default().correction_tau_s
        );
        let error = toml::from_str::<GovernorConfig>("replan_period = 5.0\n").unwrap_err();
        assert!(error.to_string().contains("replan_period"), "{error}");
    }
}
