//! What a mission run saw and decided, for the log while it runs and the report at its end:
//! mission events, governor decisions (task, level from → to, reason), the battery as the
//! autopilot reported it, the autopilot's modes, camera frames and their faults.

use crate::governor::GovernorDecision;
use crate::link::mapping::{AutopilotKind, AutopilotStatus};
use crate::telemetry::BatteryTelemetry;
use serde::Serialize;

/// A mode the autopilot reported, when it first did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModeChange {
    pub time_s: f64,
    pub mode: String,
    pub armed: bool,
}

/// The battery as qosrt saw it: the first and the latest reading.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct BatterySeen {
    pub samples: u64,
    pub first: Option<BatteryTelemetry>,
    pub last: Option<BatteryTelemetry>,
}

/// Everything the runner logged.
#[derive(Debug, Clone, Default, Serialize)]
pub struct MissionLog {
    pub autopilot: Option<String>,
    pub events: Vec<(f64, String)>,
    pub governor: Vec<GovernorDecision>,
    pub modes: Vec<ModeChange>,
    pub battery: BatterySeen,
    pub frames: u64,
    pub camera_errors: u64,
    pub telemetry_refused: u64,
    /// From a frame's capture (as its source stamped it) to the first velocity setpoint sent
    /// with the vision fix it gave.
    #[serde(skip)]
    pub(crate) capture_to_setpoint: crate::scheduler::stats::Histogram,
    /// From the frame's arrival at the runtime (its source's queue) to that setpoint: what the
    /// runtime itself adds.
    #[serde(skip)]
    pub(crate) delivered_to_setpoint: crate::scheduler::stats::Histogram,
    /// Wall time of one turn of the loop (link, governor, camera, tasks in virtual time,
    /// sequencer, commands, recording).
    #[serde(skip)]
    pub(crate) loop_step: crate::scheduler::stats::Histogram,
}

impl MissionLog {
    /// Capture-to-setpoint latency of the vision loop (count 0 when it never steered).
    pub fn capture_to_setpoint(&self) -> crate::scheduler::DurationSummary {
        self.capture_to_setpoint.summary()
    }

    /// Frame-arrival-to-setpoint latency: the runtime's own share of the above.
    pub fn delivered_to_setpoint(&self) -> crate::scheduler::DurationSummary {
        self.delivered_to_setpoint.summary()
    }

    /// Wall time of the loop's steps.
    pub fn loop_step(&self) -> crate::scheduler::DurationSummary {
        self.loop_step.summary()
    }

    pub fn event(&mut self, time_s: f64, what: String) {
        self.events.push((time_s, what));
    }

    pub fn governor(&mut self, decision: GovernorDecision) {
        self.governor.push(decision);
    }

    pub fn battery(&mut self, sample: BatteryTelemetry) {
        self.battery.samples += 1;
        self.battery.first.get_or_insert(sample);
        self.battery.last = Some(sample);
    }

    /// Notes the autopilot's kind and every change of its mode or armed state.
    pub fn autopilot(&mut self, time_s: f64, status: &AutopilotStatus) {
        if self.autopilot.is_none() {
            self.autopilot = Some(
                match status.kind {
                    AutopilotKind::Px4 => "PX4",
                    AutopilotKind::ArduPilot => "ArduPilot",
                    AutopilotKind::Other(_) => "other",
                }
                .to_string(),
            );
        }
        let mode = format!("{:?}", status.mode);
        let changed = self
            .modes
            .last()
            .is_none_or(|last| last.mode != mode || last.armed != status.armed);
        if changed {
            tracing::info!(time_s, %mode, armed = status.armed, "autopilot mode");
            self.modes.push(ModeChange {
                time_s,
                mode,
                armed: status.armed,
            });
        }
    }
}
