//! Who else hears what the mission does, beside its recording: the ROS 2 node, a ground
//! station's link. The runner calls each observer as things happen; an observer only queues
//! (its own thread publishes), so the loop does not wait on it.

use crate::governor::GovernorDecision;
use crate::record::recorder::QosLevels;
use crate::scheduler::TaskStats;
use crate::telemetry::BatteryTelemetry;
use crate::topics::VehicleState;
use nalgebra::Vector3;
use power_models::planner::LevelRange;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// What the mission tells its observers. Each has a default that ignores it.
pub trait MissionObserver: Send {
    /// The vehicle's state, as the autopilot reported it.
    fn vehicle(&self, _time_s: f64, _state: &VehicleState) {}
    /// A battery reading.
    fn battery(&self, _telemetry: &BatteryTelemetry) {}
    /// A velocity setpoint sent to the autopilot (NED).
    fn velocity_setpoint(&self, _time_s: f64, _velocity_ned_m_s: &Vector3<f64>) {}
    /// A phase began (`None`: the mission is over).
    fn phase(&self, _time_s: f64, _phase: Option<&str>) {}
    /// A decision of the governor, with its reason.
    fn governor(&self, _decision: &GovernorDecision) {}
    /// Every task's level and statistics: when a level changes, and once a second.
    fn tasks(&self, _time_s: f64, _levels: &QosLevels, _stats: &[TaskStats]) {}
    /// The mission at a glance, with the tasks' levels.
    fn status(&self, _status: &VehicleStatus) {}
    /// Plan changes asked for since the last call, at `now_s` (taken: each is asked for once).
    fn plan_requests(&self, _now_s: f64) -> Vec<PlanRequest> {
        Vec::new()
    }
    /// The answer to a plan change.
    fn plan_answer(&self, _answer: &PlanAnswer) {}
    /// The plan and the energy forecast, after each re-plan.
    fn plan(&self, _plan: &PlanForecast) {}
    /// The mission's bus, to follow topics the runner does not hand on (the tracker's estimate,
    /// the hazards): called once, when the observer is added.
    fn watch_bus(&mut self, _bus: &crate::bus::Bus) {}
}

/// The plan for the rest of the mission and its energy forecast, as the last re-plan made them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanForecast {
    pub time_s: f64,
    /// What set the re-plan off.
    pub trigger: String,
    pub reserve_fraction: f64,
    /// Energy left before the cutoff, the energy the rest needs at the planned levels, the
    /// margin over the reserve at the end, and the remaining energy's standard deviation.
    pub remaining_energy_wh: f64,
    pub needed_wh: f64,
    pub margin_wh: f64,
    pub sigma_wh: f64,
    /// The phases still to fly, each with every task's planned level.
    pub phases: Vec<PlannedPhase>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannedPhase {
    pub name: String,
    pub levels: BTreeMap<String, usize>,
}

/// A change to the plan asked for in flight (`qosrt fleet set VEHICLE reserve=0.3
/// time_left_s=600 hazard=1..3`). Fields left out stay as they are; the change is applied whole
/// or refused whole.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanRequest {
    /// The asker's number for it, given back in the answer.
    pub id: u64,
    /// The reserve to keep, a fraction of the full pack's usable energy (0 ≤ r < 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reserve_fraction: Option<f64>,
    /// How long the rest of the mission lasts from now (s): the phases that end after their
    /// duration (tracking) take the time the others (transit, landing) leave.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_left_s: Option<f64>,
    /// Per task, the levels the governor may choose from now on (`null`: all of them).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub levels: BTreeMap<String, Option<LevelRange>>,
}

/// The changes a request takes, as `KEY=VALUE` (`qosrt fleet set`, `qosrt sim --plan-change`).
pub const PLAN_CHANGE_KEYS: &str = "reserve=FRACTION, time_left_s=SECONDS or TASK=MIN..MAX|N|all";

impl PlanRequest {
    /// Adds one change, written `reserve=0.3`, `time_left_s=600`, `hazard=1..3`, `hazard=2` or
    /// `hazard=all`; an error says what was expected.
    pub fn add_change(&mut self, text: &str) -> Result<(), String> {
        let (key, value) = text
            .split_once('=')
            .map(|(k, v)| (k.trim(), v.trim()))
            .ok_or_else(|| format!("expected KEY=VALUE ({PLAN_CHANGE_KEYS}), found `{text}`"))?;
        let number = |value: &str| {
            value
                .parse::<f64>()
                .map_err(|_| format!("`{value}` is not a number; expected {key}=NUMBER"))
        };
        let level = |value: &str| {
            value.parse::<usize>().map_err(|_| {
                format!("`{value}` is not a level; expected {key}=MIN..MAX, {key}=N or {key}=all")
            })
        };
        match key {
            "reserve" => self.reserve_fraction = Some(number(value)?),
            "time_left_s" => self.time_left_s = Some(number(value)?),
            "" => {
                return Err(format!(
                    "`{text}` names nothing; expected {PLAN_CHANGE_KEYS}"
                ))
            }
            task if value == "all" => {
                self.levels.insert(task.into(), None);
            }
            task => {
                let (min, max) = match value.split_once("..") {
                    Some((min, max)) => (level(min)?, level(max.trim_start_matches('='))?),
                    None => (level(value)?, level(value)?),
                };
                self.levels
                    .insert(task.into(), Some(LevelRange { min, max }));
            }
        }
        Ok(())
    }
}

/// The mission's answer to a [`PlanRequest`]: the plan in force after it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanAnswer {
    pub id: u64,
    pub accepted: bool,
    /// Why not, when refused (out of range, infeasible, not a request).
    pub refusal: Option<String>,
    pub reserve_fraction: f64,
    /// The energy left over the reserve at the end of the mission, by the re-plan (its energy
    /// above the reserve less what the levels in force need for the rest).
    pub margin_wh: Option<f64>,
    /// The re-plan found no levels that finish the mission: the vehicle lands.
    pub land_now: bool,
    /// Every task's level now.
    pub levels: QosLevels,
    /// The rest of the mission's planned time, at the levels in force (s).
    #[serde(default)]
    pub time_left_s: Option<f64>,
    /// The tasks whose levels are bounded, with their bounds.
    #[serde(default)]
    pub allowed_levels: BTreeMap<String, LevelRange>,
}

/// The mission at a glance, once a second: what a fleet's ground station shows of a vehicle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VehicleStatus {
    pub time_s: f64,
    /// The phase flying (`None` before the first and after the last).
    pub phase: Option<String>,
    /// The autopilot's estimate of the charge left, 0..1.
    pub battery_fraction: Option<f64>,
    pub reserve_fraction: f64,
    /// The last re-plan's energy left over the reserve at the mission's end, and the energy
    /// above the reserve it found (`None` before the first re-plan).
    pub margin_wh: Option<f64>,
    pub available_wh: Option<f64>,
    /// How long the energy above the reserve lasts at the power the levels in force draw.
    pub flight_time_left_s: Option<f64>,
    /// The rest of the mission's planned time at the levels in force (`None` once it is over).
    #[serde(default)]
    pub mission_time_left_s: Option<f64>,
    pub land_now: bool,
    /// Every task's level index.
    pub levels: BTreeMap<String, usize>,
    pub last_event: Option<String>,
}
