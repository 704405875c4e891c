//! The re-plan: the rest of the mission, the budget at a plan's own mean power, and the
//! hysteresis between switching down, switching up and landing now (see the module
//! documentation of the governor).

use super::{
    ChangeReason, Decision, DrainWatch, Governor, GovernorEvent, LandNow, LevelChange,
    ReplanSummary, ReplanTrigger,
};
use crate::telemetry::MissionProgress;
use power_models::battery::BatteryError;
use power_models::planner::{solve, Evaluation, PlanError, PlanPhase, PlanProblem, TaskLevel};
use thiserror::Error;

/// The budget depends on the plan's mean power and the plan on the budget; the fixed point is
/// reached in one or two rounds because usable energy varies slowly with power.
const RATING_ROUNDS: usize = 6;
/// Utilities closer than this (relative) are equal: no change for summation-order rounding.
const UTILITY_TOLERANCE: f64 = 1e-9;
/// A switch up is triggered when a better plan would keep this many margins (and then keeps
/// one): the gap between the two is the hysteresis band that absorbs slowly growing slack.
const SWITCH_UP_TRIGGER_MARGINS: f64 = 2.0;

/// Why a re-plan could not be computed; the levels in force stay.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ReplanError {
    #[error("remaining energy at {power_w} W: {source}")]
    RemainingEnergy { power_w: f64, source: BatteryError },
    #[error("{0}")]
    Plan(#[from] PlanError),
    #[error("the planner's levels do not match its problem")]
    PlanLevelsDoNotMatch,
    #[error("the levels in force do not match the mission's problem")]
    LevelsInForceDoNotMatch,
}

/// A plan that fits its own budget.
pub(super) struct Candidate {
    levels: Vec<Vec<TaskLevel>>,
    pub(super) evaluation: Evaluation,
    pub(super) available_wh: f64,
}

impl Governor {
    /// The rest of the mission with every power scaled by `correction_ratio`.
    pub(super) fn remaining_problem(&self, correction_ratio: f64) -> PlanProblem {
        let MissionProgress {
            phase,
            phase_elapsed_s,
        } = self.progress;
        let mut phases: Vec<PlanPhase> = self.problem.phases[phase..].to_vec();
        if let Some(current) = phases.first_mut() {
            current.duration_s = (current.duration_s - phase_elapsed_s).max(0.0);
            if let Some(by_level) = &mut current.duration_by_level {
                for duration_s in &mut by_level.duration_s {
                    *duration_s = (*duration_s - phase_elapsed_s).max(0.0);
                }
            }
        }
        for phase in &mut phases {
            phase.flight_power_w *= correction_ratio;
            phase.base_power_w *= correction_ratio;
            for term in &mut phase.terms {
                for power_w in &mut term.power_w {
                    *power_w *= correction_ratio;
                }
            }
        }
        PlanProblem {
            tasks: self.problem.tasks.clone(),
            phases,
        }
    }

    /// Remaining energy at a constant `power_w` minus the reserve.
    fn available_wh(&self, power_w: f64) -> Result<f64, ReplanError> {
        Ok(self.remaining_energy_wh_at(power_w)? - self.reserve_wh)
    }

    /// The estimator's remaining energy at a constant `power_w`.
    fn remaining_energy_wh_at(&self, power_w: f64) -> Result<f64, ReplanError> {
        self.estimator
            .remaining_energy_wh_at(power_w)
            .map_err(|source| ReplanError::RemainingEnergy { power_w, source })
    }

    /// The best plan that fits, with `margin_wh` to spare, the budget rated at its own mean
    /// power; None when even the cheapest does not.
    fn best_fitting(
        &self,
        problem: &PlanProblem,
        margin_wh: f64,
        mut rating_power_w: f64,
    ) -> Result<Option<Candidate>, ReplanError> {
        for _ in 0..RATING_ROUNDS {
            let budget_wh = self.available_wh(rating_power_w)? - margin_wh;
            let plan = solve(problem, budget_wh)?;
            if !plan.feasible {
                return Ok(None);
            }
            let levels: Vec<Vec<TaskLevel>> =
                plan.phases.iter().map(|p| p.levels.clone()).collect();
            let evaluation = problem
                .evaluate(&levels)
                .ok_or(ReplanError::PlanLevelsDoNotMatch)?;
            let power_w = evaluation.mean_power_w(rating_power_w);
            let available_wh = self.available_wh(power_w)?;
            if evaluation.energy_wh <= available_wh - margin_wh {
                return Ok(Some(Candidate {
                    levels,
                    evaluation,
                    available_wh,
                }));
            }
            // Rated too lightly: a heavier load gets less out of the pack. Rate again.
            rating_power_w = power_w;
        }
        // Not settled: answer for the cheapest plan rather than report "nothing fits".
        let cheapest = self.cheapest(problem, rating_power_w)?;
        Ok(
            (cheapest.evaluation.energy_wh <= cheapest.available_wh - margin_wh)
                .then_some(cheapest),
        )
    }

    pub(super) fn replan(
        &mut self,
        trigger: ReplanTrigger,
        time_s: f64,
        events: &mut Vec<GovernorEvent>,
    ) {
        if let Err(error) = self.try_replan(trigger, time_s, events) {
            tracing::warn!(
                target: "qosrt::governor",
                time_s,
                message = %error,
                "re-plan failed; the levels in force stay"
            );
            events.push(GovernorEvent::ReplanFailed { time_s, error });
        }
        // Retry at the next period, not on every sample.
        self.last_replan_s = Some(time_s);
    }

    fn try_replan(
        &mut self,
        trigger: ReplanTrigger,
        time_s: f64,
        events: &mut Vec<GovernorEvent>,
    ) -> Result<(), ReplanError> {
        let phase = self.progress.phase;
        let correction_ratio = self.correction_ratio;
        let problem = self.remaining_problem(correction_ratio);
        let current_levels = self.levels[phase..].to_vec();
        let current = problem
            .evaluate(&current_levels)
            .ok_or(ReplanError::LevelsInForceDoNotMatch)?;
        let phase_power_w = self
            .model_power_w(phase)
            .map_or(0.0, |w| w * correction_ratio);
        let rating_power_w = current.mean_power_w(phase_power_w);
        let remaining_energy_wh = self.remaining_energy_wh_at(rating_power_w)?;
        self.watch = Some(DrainWatch {
            rating_power_w,
            remaining_at_replan_wh: remaining_energy_wh,
            predicted_used_wh: 0.0,
            correction_ratio,
        });
        let available_wh = remaining_energy_wh - self.reserve_wh;
        // One unit of SoC holds about the pack's nominal energy.
        let sigma_wh = self.estimator.soc_sigma() * self.estimator.spec().nominal_energy_wh();
        let margin_wh = (self.config.switch_up_margin_fraction * available_wh.max(0.0))
            .max(self.config.switch_up_margin_sigma * sigma_wh);
        let mut summary = ReplanSummary {
            time_s,
            trigger,
            phase,
            remaining_energy_wh,
            available_wh,
            needed_wh: current.energy_wh,
            margin_wh,
            sigma_wh,
            correction_ratio,
            decision: Decision::Kept,
        };
        tracing::debug!(
            target: "qosrt::governor",
            time_s,
            %trigger,
            phase,
            remaining_energy_wh,
            available_wh,
            needed_wh = current.energy_wh,
            margin_wh,
            correction_ratio,
            "re-plan"
        );
        if current.duration_s <= 0.0 {
            // The mission's planned time is over: nothing left to choose.
            self.last_replan = Some(summary);
            return Ok(());
        }
        let with_margin = self.best_fitting(&problem, margin_wh, rating_power_w)?;
        let tolerance = UTILITY_TOLERANCE * current.utility.abs().max(1.0);
        let change = if !self.levels_in_force_allowed(&current_levels) {
            // An operator narrowed a task's levels: the best plan within them, now.
            self.switch_down(&problem, with_margin, rating_power_w, &summary, events)?
                .map(|(candidate, reason)| match reason {
                    ChangeReason::CurrentLevelsDoNotFit => {
                        (candidate, ChangeReason::LevelsNotAllowed)
                    }
                    other => (candidate, other),
                })
        } else if current.energy_wh > available_wh {
            // Safety first: down now, whatever the dwell.
            self.switch_down(&problem, with_margin, rating_power_w, &summary, events)?
        } else {
            self.switch_up(
                &problem,
                with_margin,
                &current,
                tolerance,
                rating_power_w,
                &summary,
            )?
        };
        if let Some((candidate, reason)) = change {
            if candidate.levels != current_levels {
                let change = LevelChange {
                    time_s,
                    phase,
                    reason,
                    trigger,
                    old_levels: current_levels,
                    new_levels: candidate.levels,
                    old_utility: current.utility,
                    new_utility: candidate.evaluation.utility,
                    old_energy_wh: current.energy_wh,
                    new_energy_wh: candidate.evaluation.energy_wh,
                    available_wh: candidate.available_wh,
                    margin_wh,
                    reserve_wh: self.reserve_wh,
                    correction_ratio,
                };
                self.apply(&change);
                summary.decision = Decision::Changed(reason);
                events.push(GovernorEvent::LevelsChanged(change));
            }
        }
        self.last_replan = Some(summary);
        Ok(())
    }

    /// The levels in force do not fit: the best plan that fits with the margin, else without
    /// it, else the cheapest (landing now when even that is short by more than the estimate's
    /// uncertainty). `summary` is this re-plan's so far: its time, phase, σ and correction.
    fn switch_down(
        &mut self,
        problem: &PlanProblem,
        with_margin: Option<Candidate>,
        rating_power_w: f64,
        summary: &ReplanSummary,
        events: &mut Vec<GovernorEvent>,
    ) -> Result<Option<(Candidate, ChangeReason)>, ReplanError> {
        let fitting = match with_margin {
            Some(candidate) => Some(candidate),
            None => self.best_fitting(problem, 0.0, rating_power_w)?,
        };
        Ok(match fitting {
            Some(candidate) => Some((candidate, ChangeReason::CurrentLevelsDoNotFit)),
            None => Some(self.cheapest_or_land_now(problem, rating_power_w, summary, events)?),
        })
    }

    /// Nothing fits: the cheapest levels, landing now when even they are short by more than
    /// the estimate's uncertainty allows.
    fn cheapest_or_land_now(
        &mut self,
        problem: &PlanProblem,
        rating_power_w: f64,
        summary: &ReplanSummary,
        events: &mut Vec<GovernorEvent>,
    ) -> Result<(Candidate, ChangeReason), ReplanError> {
        let (time_s, phase, sigma_wh, correction_ratio) = (
            summary.time_s,
            summary.phase,
            summary.sigma_wh,
            summary.correction_ratio,
        );
        let cheapest = self.cheapest(problem, rating_power_w)?;
        let shortfall_wh = cheapest.evaluation.energy_wh - cheapest.available_wh;
        let tolerance_wh = (self.config.land_now_sigma * sigma_wh)
            .min(self.config.land_now_max_tolerance_fraction * self.reserve_wh);
        if shortfall_wh > tolerance_wh {
            let land_now = LandNow {
                time_s,
                phase,
                needed_wh: cheapest.evaluation.energy_wh,
                available_wh: cheapest.available_wh,
                shortfall_wh,
                tolerance_wh,
                reserve_wh: self.reserve_wh,
                correction_ratio,
            };
            tracing::error!(
                target: "qosrt::governor",
                time_s,
                phase = %self.problem.phases[phase].name,
                needed_wh = land_now.needed_wh,
                available_wh = land_now.available_wh,
                shortfall_wh,
                tolerance_wh,
                reserve_wh = land_now.reserve_wh,
                correction_ratio,
                "LAND NOW: even the lowest QoS levels cannot finish the mission with the reserve"
            );
            self.land_now = true;
            events.push(GovernorEvent::LandNow(land_now));
            Ok((cheapest, ChangeReason::LandNow))
        } else {
            // Short by less than the estimate's uncertainty: the lowest levels,
            // watched at every re-plan.
            Ok((cheapest, ChangeReason::CurrentLevelsDoNotFit))
        }
    }

    /// The levels in force fit: the best plan that keeps the margin, when it is better than
    /// `current` by more than `tolerance`, the dwell is over and the switch up is triggered.
    fn switch_up(
        &self,
        problem: &PlanProblem,
        with_margin: Option<Candidate>,
        current: &Evaluation,
        tolerance: f64,
        rating_power_w: f64,
        summary: &ReplanSummary,
    ) -> Result<Option<(Candidate, ChangeReason)>, ReplanError> {
        let (time_s, margin_wh) = (summary.time_s, summary.margin_wh);
        let dwell_over = self
            .last_change_s
            .is_none_or(|t| time_s - t >= self.config.min_dwell_s);
        let better = |c: &Candidate| c.evaluation.utility > current.utility + tolerance;
        // Schmitt trigger: go up only once a better plan would keep twice the margin, then
        // as high as keeps the margin. Slack that grows slowly (the estimate settling, the
        // mission shortening) then makes one step up instead of a staircase of small ones.
        let triggered = dwell_over
            && with_margin.as_ref().is_some_and(better)
            && self
                .best_fitting(
                    problem,
                    SWITCH_UP_TRIGGER_MARGINS * margin_wh,
                    rating_power_w,
                )?
                .as_ref()
                .is_some_and(better);
        Ok(with_margin
            .filter(|_| triggered)
            .map(|c| (c, ChangeReason::MoreEnergyAvailable)))
    }

    /// The cheapest levels and the budget at their mean power.
    pub(super) fn cheapest(
        &self,
        problem: &PlanProblem,
        fallback_w: f64,
    ) -> Result<Candidate, ReplanError> {
        let plan = solve(problem, f64::MIN)?;
        let levels: Vec<Vec<TaskLevel>> = plan.phases.iter().map(|p| p.levels.clone()).collect();
        let evaluation = problem
            .evaluate(&levels)
            .ok_or(ReplanError::PlanLevelsDoNotMatch)?;
        let available_wh = self.available_wh(evaluation.mean_power_w(fallback_w))?;
        Ok(Candidate {
            levels,
            evaluation,
            available_wh,
        })
    }

    fn apply(&mut self, change: &LevelChange) {
        tracing::info!(
            target: "qosrt::governor",
            time_s = change.time_s,
            phase = %self.problem.phases[change.phase].name,
            reason = %change.reason,
            trigger = %change.trigger,
            old_levels = %self.describe(change.phase, &change.old_levels),
            new_levels = %self.describe(change.phase, &change.new_levels),
            old_utility = change.old_utility,
            new_utility = change.new_utility,
            energy_needed_wh = change.new_energy_wh,
            energy_needed_before_wh = change.old_energy_wh,
            available_wh = change.available_wh,
            margin_wh = change.margin_wh,
            reserve_wh = change.reserve_wh,
            correction_ratio = change.correction_ratio,
            "QoS levels changed"
        );
        for (slot, levels) in self.levels[change.phase..]
            .iter_mut()
            .zip(&change.new_levels)
        {
            slot.clone_from(levels);
        }
        self.last_change_s = Some(change.time_s);
    }

    /// `phase: task=level …; next: …` for the log.
    fn describe(&self, first_phase: usize, levels: &[Vec<TaskLevel>]) -> String {
        let mut text = String::new();
        for (phase, phase_levels) in self.problem.phases[first_phase..].iter().zip(levels) {
            if !text.is_empty() {
                text.push_str("; ");
            }
            text.push_str(&phase.name);
            text.push(':');
            for level in phase_levels {
                let name = self
                    .problem
                    .tasks
                    .get(level.task)
                    .map_or("?", |t| t.name.as_str());
                text.push_str(&format!(" {name}={}", level.level));
            }
        }
        text
    }
}
