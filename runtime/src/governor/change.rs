//! Changes to the plan asked for in flight (a ground station's `qosrt fleet set`): the reserve,
//! the mission's time left, a task's allowed levels. A change is checked whole and applied
//! whole, then the governor re-plans at once; a change the battery cannot carry is refused and
//! changes nothing, so an operator's request never lands the vehicle by itself.

use super::{Governor, GovernorEvent, ReplanError, ReplanTrigger};
use crate::telemetry::MissionProgress;
use power_models::planner::{LevelRange, TaskLevel};
use std::collections::BTreeMap;
use thiserror::Error;

/// A change to the rest of the mission. Fields left out stay as they are.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlanChange {
    /// The reserve to keep, a fraction of the full pack's usable energy.
    pub reserve_fraction: Option<f64>,
    /// New durations of phases (index, seconds from the phase's start), from
    /// [`Governor::durations_for_time_left`].
    pub phase_durations_s: Vec<(usize, f64)>,
    /// Per task name, the levels the planner may choose from now (`None`: all of them).
    pub allowed_levels: BTreeMap<String, Option<LevelRange>>,
}

/// Why a change was refused; nothing changed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlanChangeError {
    #[error("nothing to change: give a reserve, a time left or a task's levels")]
    Empty,
    #[error("reserve {value} is out of range: expected a fraction in [0, 1)")]
    BadReserve { value: f64 },
    #[error("time left {value} s is out of range: expected a finite number of seconds ≥ 0")]
    BadTimeLeft { value: f64 },
    #[error(
        "time left {asked_s:.0} s is too short: the phases that end on their own (transit, \
         landing) still need {needed_s:.0} s"
    )]
    TimeLeftTooShort { asked_s: f64, needed_s: f64 },
    #[error("no phase that ends after its duration is left to lengthen or shorten")]
    NoTimedPhaseLeft,
    #[error("`{task}` is not a task the governor plans (it plans: {known})")]
    UnknownTask { task: String, known: String },
    #[error(
        "`{task}` levels {min}..={max} are out of range: it has levels 0..={last}",
        last = count.saturating_sub(1)
    )]
    BadLevels {
        task: String,
        min: usize,
        max: usize,
        count: usize,
    },
    #[error(
        "infeasible: even the cheapest levels need {needed_wh:.2} Wh for the rest of the \
         mission, and {available_wh:.2} Wh are left above the reserve"
    )]
    Infeasible { needed_wh: f64, available_wh: f64 },
    #[error("the change could not be planned: {0}")]
    Replan(#[from] ReplanError),
}

impl Governor {
    /// Applies `change` and re-plans at once (from the last battery reading; before the first,
    /// the first re-plan uses it). Refused whole, with nothing changed, when a value is out of
    /// range or when even the cheapest levels would not finish the mission above the reserve.
    pub fn change_plan(
        &mut self,
        change: &PlanChange,
    ) -> Result<Vec<GovernorEvent>, PlanChangeError> {
        if change.reserve_fraction.is_none()
            && change.phase_durations_s.is_empty()
            && change.allowed_levels.is_empty()
        {
            return Err(PlanChangeError::Empty);
        }
        let mut changed = self.clone();
        if let Some(value) = change.reserve_fraction {
            if !(0.0..1.0).contains(&value) {
                return Err(PlanChangeError::BadReserve { value });
            }
            changed.reserve_wh = changed.usable_full_wh * value;
        }
        for &(phase, duration_s) in &change.phase_durations_s {
            if !(duration_s.is_finite() && duration_s >= 0.0) {
                return Err(PlanChangeError::BadTimeLeft { value: duration_s });
            }
            if let Some(phase) = changed.problem.phases.get_mut(phase) {
                phase.duration_s = duration_s;
            }
        }
        for (name, range) in &change.allowed_levels {
            changed.allow_levels(name, *range)?;
        }
        let mut events = Vec::new();
        if let (Some(time_s), false) = (changed.last_time_s, changed.land_now) {
            changed.check_feasible()?;
            changed.replan(ReplanTrigger::PlanChanged, time_s, &mut events);
        }
        *self = changed;
        Ok(events)
    }

    /// The durations of the phases that end after their duration (`timed[phase]`) that make
    /// the rest of the mission, from `progress`, last `time_left_s` at the levels in force. They
    /// share the time the other phases leave in proportion to what each has left (equally when
    /// none has any).
    pub fn durations_for_time_left(
        &self,
        progress: MissionProgress,
        time_left_s: f64,
        timed: &[bool],
    ) -> Result<Vec<(usize, f64)>, PlanChangeError> {
        if !(time_left_s.is_finite() && time_left_s >= 0.0) {
            return Err(PlanChangeError::BadTimeLeft { value: time_left_s });
        }
        let mut fixed_s = 0.0;
        let mut stretched: Vec<(usize, f64)> = Vec::new();
        for (phase, left_s) in self.times_left_s(progress) {
            let is_timed = timed.get(phase).copied().unwrap_or(false)
                && self.problem.phases[phase].duration_by_level.is_none();
            if is_timed {
                stretched.push((phase, left_s));
            } else {
                fixed_s += left_s;
            }
        }
        if stretched.is_empty() {
            return Err(PlanChangeError::NoTimedPhaseLeft);
        }
        let share_s = time_left_s - fixed_s;
        if share_s < 0.0 {
            return Err(PlanChangeError::TimeLeftTooShort {
                asked_s: time_left_s,
                needed_s: fixed_s,
            });
        }
        let total_left_s: f64 = stretched.iter().map(|(_, left_s)| left_s).sum();
        let count = stretched.len() as f64;
        Ok(stretched
            .into_iter()
            .map(|(phase, left_s)| {
                let weight = if total_left_s > 0.0 {
                    left_s / total_left_s
                } else {
                    1.0 / count
                };
                (phase, elapsed_in(progress, phase) + share_s * weight)
            })
            .collect())
    }

    /// The rest of the mission's planned time from `progress`, at the levels in force.
    pub fn planned_time_left_s(&self, progress: MissionProgress) -> f64 {
        self.times_left_s(progress)
            .into_iter()
            .map(|(_, left_s)| left_s)
            .sum()
    }

    /// Each phase from `progress` on, with its planned time left at the levels in force.
    fn times_left_s(&self, progress: MissionProgress) -> Vec<(usize, f64)> {
        self.problem
            .phases
            .iter()
            .zip(&self.levels)
            .enumerate()
            .skip(progress.phase)
            .map(|(phase, (plan_phase, levels))| {
                let duration_s = self
                    .problem
                    .phase_duration_s(phase, levels)
                    .unwrap_or(plan_phase.duration_s);
                (phase, (duration_s - elapsed_in(progress, phase)).max(0.0))
            })
            .collect()
    }

    /// The levels the planner may choose for `task`, by name (`None`: all of them).
    pub fn allowed_levels(&self, task: &str) -> Option<LevelRange> {
        self.problem
            .tasks
            .iter()
            .find(|t| t.name == task)
            .and_then(|t| t.allowed_levels)
    }

    /// Whether the levels in force from the phase in flight on are all allowed.
    pub(super) fn levels_in_force_allowed(&self, levels: &[Vec<TaskLevel>]) -> bool {
        levels.iter().flatten().all(|level| {
            self.problem
                .tasks
                .get(level.task)
                .is_none_or(|task| task.allows(level.level))
        })
    }

    fn allow_levels(
        &mut self,
        name: &str,
        range: Option<LevelRange>,
    ) -> Result<(), PlanChangeError> {
        let known = || {
            self.problem
                .tasks
                .iter()
                .map(|t| t.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let Some(index) = self.problem.tasks.iter().position(|t| t.name == name) else {
            return Err(PlanChangeError::UnknownTask {
                task: name.into(),
                known: known(),
            });
        };
        let task = &mut self.problem.tasks[index];
        if let Some(LevelRange { min, max }) = range {
            let count = task.utility.len();
            if !(LevelRange { min, max }).fits(count) {
                return Err(PlanChangeError::BadLevels {
                    task: name.into(),
                    min,
                    max,
                    count,
                });
            }
        }
        task.allowed_levels = range;
        Ok(())
    }

    /// Refuses a plan the battery cannot carry: even the cheapest allowed levels need more
    /// than what is left above the reserve.
    fn check_feasible(&self) -> Result<(), PlanChangeError> {
        let problem = self.remaining_problem(self.correction_ratio);
        let phase_power_w = self
            .model_power_w(self.progress.phase)
            .map_or(0.0, |w| w * self.correction_ratio);
        let cheapest = self.cheapest(&problem, phase_power_w)?;
        if cheapest.evaluation.energy_wh > cheapest.available_wh {
            return Err(PlanChangeError::Infeasible {
                needed_wh: cheapest.evaluation.energy_wh,
                available_wh: cheapest.available_wh,
            });
        }
        Ok(())
    }
}

/// How long phase `phase` has flown at `progress` (0 for a later one).
fn elapsed_in(progress: MissionProgress, phase: usize) -> f64 {
    if phase == progress.phase {
        progress.phase_elapsed_s
    } else {
        0.0
    }
}
