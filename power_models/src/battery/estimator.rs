//! The state-of-charge estimator: battery telemetry in, SoC and remaining energy out.

use super::{check_power, check_soc, BatteryError, BatterySpec};

/// A connected LiPo cell never reads below this; lower readings are a disconnected or
/// mis-scaled sensor (PX4 itself treats a pack below 2.1 V as absent).
const MIN_PLAUSIBLE_CELL_V: f64 = 2.5;
/// Headroom above the full-charge voltage before a reading is implausible: calibration and
/// noise stay well inside it, a wrong cell count or a broken divider does not.
const MAX_CELL_OVERSHOOT_V: f64 = 0.3;
/// Hall and shunt sensors read slightly negative at idle (offset); such readings are clamped
/// to 0. More negative than this is not an offset (PX4/MAVLink use -1 for "not measured").
const NEGATIVE_CURRENT_TOLERANCE_A: f64 = 0.5;
/// One mAh is 3.6 A·s.
const AS_PER_MAH: f64 = 3.6;
/// Shortest interval used to weigh two measurements against their correlation time.
const MIN_FUSION_DT_S: f64 = 1e-3;

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

#[cfg(test)]
mod tests;
