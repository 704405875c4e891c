//! What the governor reports: level changes, land-now, failed re-plans, and each re-plan's
//! numbers.

use super::ReplanError;
use power_models::planner::TaskLevel;
use serde::Serialize;
use std::fmt;

/// What started a re-plan.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum ReplanTrigger {
    /// The first re-plan, once the warm-up is over.
    Start,
    /// A new phase began.
    PhaseStarted,
    /// `replan_period_s` passed.
    Periodic,
    /// The measured remaining energy fell `divergence_wh` below the prediction.
    DrainFaster { divergence_wh: f64 },
    /// The plan was changed in flight (a ground station's reserve, time left or levels).
    PlanChanged,
}

impl fmt::Display for ReplanTrigger {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ReplanTrigger::Start => f.write_str("start"),
            ReplanTrigger::PhaseStarted => f.write_str("phase started"),
            ReplanTrigger::Periodic => f.write_str("periodic"),
            ReplanTrigger::PlanChanged => f.write_str("the plan was changed in flight"),
            ReplanTrigger::DrainFaster { divergence_wh } => {
                write!(
                    f,
                    "battery drains faster than predicted by {divergence_wh:.2} Wh"
                )
            }
        }
    }
}

/// Why the levels changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ChangeReason {
    /// The levels in force no longer fit the budget: down at once.
    CurrentLevelsDoNotFit,
    /// A plan of higher utility fits with the margin and the dwell has passed.
    MoreEnergyAvailable,
    /// Nothing fits: the cheapest levels, with a land-now event.
    LandNow,
    /// The levels in force are outside a task's allowed levels (changed in flight).
    LevelsNotAllowed,
}

impl fmt::Display for ChangeReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ChangeReason::CurrentLevelsDoNotFit => "the levels in force no longer fit the budget",
            ChangeReason::MoreEnergyAvailable => "a better plan fits with the margin",
            ChangeReason::LandNow => "even the lowest levels do not fit: land now",
            ChangeReason::LevelsNotAllowed => "a task's levels in force are no longer allowed",
        })
    }
}

/// A change of the planned levels, with the numbers behind it. Energies are for the rest of
/// the mission, corrected by the measured-to-predicted power ratio.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LevelChange {
    pub time_s: f64,
    /// The phase in flight; `old_levels[0]` and `new_levels[0]` are its levels, the rest are
    /// the later phases'.
    pub phase: usize,
    pub reason: ChangeReason,
    pub trigger: ReplanTrigger,
    pub old_levels: Vec<Vec<TaskLevel>>,
    pub new_levels: Vec<Vec<TaskLevel>>,
    pub old_utility: f64,
    pub new_utility: f64,
    pub old_energy_wh: f64,
    pub new_energy_wh: f64,
    /// Remaining energy rated at the new plan's mean power, minus the reserve.
    pub available_wh: f64,
    /// Margin a switch up had to keep.
    pub margin_wh: f64,
    pub reserve_wh: f64,
    pub correction_ratio: f64,
}

/// Even the cheapest levels cannot reach the end of the mission with the reserve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LandNow {
    pub time_s: f64,
    pub phase: usize,
    /// Energy the cheapest levels need for the rest of the mission.
    pub needed_wh: f64,
    /// Remaining energy rated at their mean power, minus the reserve.
    pub available_wh: f64,
    pub shortfall_wh: f64,
    /// The shortfall the estimate's uncertainty excused (`land_now_sigma` σ, capped).
    pub tolerance_wh: f64,
    pub reserve_wh: f64,
    pub correction_ratio: f64,
}

/// What the governor reports from one update.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "event")]
pub enum GovernorEvent {
    LevelsChanged(LevelChange),
    LandNow(LandNow),
    /// A re-plan could not be computed; the levels in force stay.
    ReplanFailed {
        time_s: f64,
        /// Written as its message, as the event always was.
        #[serde(rename = "message", serialize_with = "serialize_display")]
        error: ReplanError,
    },
}

fn serialize_display<S: serde::Serializer>(
    value: &impl fmt::Display,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    serializer.collect_str(value)
}

impl GovernorEvent {
    /// The event in one line for people: which task moved between which knob values, why, and
    /// the energy behind it. `tasks` are the config's, in order.
    pub fn describe(&self, tasks: &[crate::config::TaskConfig]) -> String {
        match self {
            GovernorEvent::LevelsChanged(change) => {
                let (old, new) = (
                    change.old_levels.first().map(Vec::as_slice).unwrap_or(&[]),
                    change.new_levels.first().map(Vec::as_slice).unwrap_or(&[]),
                );
                let moves: Vec<String> = new
                    .iter()
                    .filter_map(|after| {
                        let before = old.iter().find(|b| b.task == after.task)?;
                        let task = tasks.get(after.task)?;
                        (before.level != after.level).then(|| {
                            format!(
                                "{} {} → {} {}",
                                task.name,
                                task.levels[before.level],
                                task.levels[after.level],
                                task.knob
                            )
                        })
                    })
                    .collect();
                let moves = if moves.is_empty() {
                    "later phases' levels".to_string()
                } else {
                    moves.join(", ")
                };
                format!(
                    "{moves}: {} ({}); utility {:.2} → {:.2}, energy to go {:.2} → {:.2} Wh of {:.2} Wh available",
                    change.reason,
                    change.trigger,
                    change.old_utility,
                    change.new_utility,
                    change.old_energy_wh,
                    change.new_energy_wh,
                    change.available_wh
                )
            }
            GovernorEvent::LandNow(land) => format!(
                "land now: the cheapest levels need {:.2} Wh, {:.2} Wh available (short by {:.2} Wh)",
                land.needed_wh, land.available_wh, land.shortfall_wh
            ),
            GovernorEvent::ReplanFailed { time_s, error } => {
                format!("re-plan failed at {time_s:.1} s: {error}")
            }
        }
    }
}

/// What a re-plan decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    Kept,
    Changed(ChangeReason),
}

/// The numbers of the latest re-plan, whether or not it changed anything.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplanSummary {
    pub time_s: f64,
    pub trigger: ReplanTrigger,
    pub phase: usize,
    /// Estimated energy left before the cutoff, rated at the mean power of the levels that
    /// were in force.
    pub remaining_energy_wh: f64,
    /// That minus the reserve.
    pub available_wh: f64,
    /// Corrected energy the levels that were in force need for the rest of the mission.
    pub needed_wh: f64,
    /// The margin a plan must keep to be switched up to (hysteresis): not what is left over.
    pub margin_wh: f64,
    /// Standard deviation of the remaining energy (the estimator's SoC σ × pack energy).
    pub sigma_wh: f64,
    pub correction_ratio: f64,
    pub decision: Decision,
}

impl ReplanSummary {
    /// The energy left over the reserve at the mission's end, if the levels in force at the
    /// re-plan fly the rest: what a ground station calls the margin against the plan.
    pub fn end_margin_wh(&self) -> f64 {
        self.available_wh - self.needed_wh
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::PluginCatalog;

    /// The one-line description names the task that moved and its knob values, read from the
    /// config, and carries the reason and the energies.
    #[test]
    fn events_are_described_in_the_configs_words() {
        let config = crate::config::load_str(
            include_str!("../../../qos.toml"),
            None,
            &PluginCatalog::builtin(),
        )
        .unwrap();
        let level = |task, level| TaskLevel { task, level };
        let change = GovernorEvent::LevelsChanged(LevelChange {
            time_s: 60.0,
            phase: 1,
            reason: ChangeReason::MoreEnergyAvailable,
            trigger: ReplanTrigger::Periodic,
            old_levels: vec![vec![level(0, 3), level(3, 1)]],
            new_levels: vec![vec![level(0, 3), level(3, 3)]],
            old_utility: 9.75,
            new_utility: 10.0,
            old_energy_wh: 42.7,
            new_energy_wh: 42.98,
            available_wh: 51.86,
            margin_wh: 1.0,
            reserve_wh: 18.0,
            correction_ratio: 0.94,
        });
        let text = change.describe(&config.tasks);
        assert!(text.starts_with("hazard 0.25 → 4 rate_fps: "), "{text}");
        assert!(text.contains("9.75 → 10.00") && text.contains("of 51.86 Wh available"));
        assert!(
            !text.contains("detection"),
            "an unchanged task is not listed: {text}"
        );
        let land = GovernorEvent::LandNow(LandNow {
            time_s: 30.0,
            phase: 1,
            needed_wh: 40.0,
            available_wh: 36.8,
            shortfall_wh: 3.2,
            tolerance_wh: 0.5,
            reserve_wh: 18.0,
            correction_ratio: 1.1,
        });
        assert!(land.describe(&config.tasks).contains("short by 3.20 Wh"));
    }

    /// A failed re-plan keeps the error behind it as its cause and reads as it always did: its
    /// message in the description and, under `message`, in the event's JSON.
    #[test]
    fn a_failed_replan_keeps_its_cause() {
        let cause = power_models::battery::BatteryError::InvalidArgument {
            name: "load_power_w",
            value: -1.0,
            expected: "a power >= 0 W",
        };
        let error = ReplanError::RemainingEnergy {
            power_w: -1.0,
            source: cause.clone(),
        };
        assert_eq!(
            error.to_string(),
            format!("remaining energy at -1 W: {cause}")
        );
        let source = std::error::Error::source(&error).expect("a cause");
        assert_eq!(source.to_string(), cause.to_string());

        let event = GovernorEvent::ReplanFailed {
            time_s: 12.0,
            error: error.clone(),
        };
        assert_eq!(
            serde_json::to_value(&event).unwrap(),
            serde_json::json!({
                "event": "replan_failed",
                "time_s": 12.0,
                "message": error.to_string(),
            })
        );
        assert_eq!(
            event.describe(&[]),
            format!("re-plan failed at 12.0 s: {error}")
        );
    }
}
