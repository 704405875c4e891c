//! The runtime's view of the vehicle: battery telemetry and mission progress, independent of
//! MAVLink. A link adapter converts BATTERY_STATUS / SYS_STATUS into [`BatteryTelemetry`]
//! (MAVLink's -1 "not measured" sentinels become `None`, `battery_remaining` % becomes a
//! fraction); the mission logic reports [`MissionProgress`]. The governor consumes both.

use power_models::battery::BatterySample;
use serde::{Deserialize, Serialize};

/// One battery reading. Fields the autopilot did not measure are `None`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct BatteryTelemetry {
    /// When the reading was taken, on the runtime's monotonic clock (not the autopilot's boot
    /// clock, which restarts when the autopilot reboots).
    pub time_s: f64,
    /// Pack terminal voltage.
    pub voltage_v: Option<f64>,
    /// Discharge current, positive out of the pack.
    pub current_a: Option<f64>,
    /// The autopilot's own integral of current since it booted.
    pub consumed_mah: Option<f64>,
    /// The autopilot's remaining estimate, 0..1.
    pub remaining_fraction: Option<f64>,
}

impl BatteryTelemetry {
    /// Power delivered by the pack (V·I), when the reading has both; not validated (the
    /// estimator validates the reading).
    pub fn power_w(&self) -> Option<f64> {
        Some(self.voltage_v? * self.current_a?)
    }

    /// The reading as the battery estimator takes it.
    pub fn to_sample(&self) -> BatterySample {
        BatterySample {
            time_s: self.time_s,
            voltage_v: self.voltage_v,
            current_a: self.current_a,
            consumed_mah: self.consumed_mah,
            remaining_fraction: self.remaining_fraction,
        }
    }
}

impl From<BatteryTelemetry> for BatterySample {
    fn from(telemetry: BatteryTelemetry) -> Self {
        telemetry.to_sample()
    }
}

/// Where the mission is: the phase in flight (an index into the config's
/// `[[mission.phase]]`, in flight order) and how long it has been running.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct MissionProgress {
    pub phase: usize,
    pub phase_elapsed_s: f64,
}

impl MissionProgress {
    /// The first phase, just begun.
    pub fn start() -> Self {
        Self::default()
    }

    /// `phase`, `phase_elapsed_s` into it.
    pub fn new(phase: usize, phase_elapsed_s: f64) -> Self {
        Self {
            phase,
            phase_elapsed_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converts_to_the_estimators_sample_field_by_field() {
        let telemetry = BatteryTelemetry {
            time_s: 12.5,
            voltage_v: Some(15.8),
            current_a: None,
            consumed_mah: Some(420.0),
            remaining_fraction: Some(0.8),
        };
        let sample: BatterySample = telemetry.into();
        assert_eq!(sample.time_s, 12.5);
        assert_eq!(sample.voltage_v, Some(15.8));
        assert_eq!(sample.current_a, None);
        assert_eq!(sample.consumed_mah, Some(420.0));
        assert_eq!(sample.remaining_fraction, Some(0.8));
        assert_eq!(telemetry.power_w(), None);
        let with_current = BatteryTelemetry {
            current_a: Some(10.0),
            ..telemetry
        };
        assert_eq!(with_current.power_w(), Some(158.0));
    }
}
