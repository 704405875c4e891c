//! The energy governor: battery telemetry in, QoS levels out, re-planned during the mission.
//!
//! # What it does on every telemetry sample ([`Governor::update`])
//!
//! 1. The sample goes through [`BatteryEstimator`] (SoC, remaining energy). A bad sample is
//!    rejected with a named error and changes nothing: the levels in force stay (safe mode).
//!    Voltage and current are first smoothed by a first-order low-pass
//!    (`telemetry_filter_tau_s`), as PX4 smooths them before its own estimate: the OCV curve
//!    is nonlinear and the estimator weighs a reading by the curve's slope at it, so raw
//!    readings with ±5 % noise bias its SoC by up to 0.15 over a mission in our scenarios,
//!    where readings smoothed over 5 s leave at most about 0.04, for a delay of 5 s.
//! 2. **Online correction.** The measured pack power `V·I` is divided by the power the plan
//!    predicts for the phase in flight at the levels in force (flight + companion), and that
//!    ratio is low-pass filtered (time constant `correction_tau_s`, starting from 1: the model
//!    is trusted until measurements say otherwise). Ratios outside
//!    `correction_min..=correction_max` are ignored: they mean the vehicle is not in the
//!    modelled state (on the ground, motors off) or a glitch, not that the model is that far
//!    off.
//! 3. **Re-planning**, once telemetry has come in for `warmup_s` (the estimator reads the SoC
//!    from the first voltages), then every `replan_period_s`, at the start of every phase, and
//!    at once when the battery drains faster than predicted: since the last re-plan the
//!    measured remaining energy has fallen more than `drain_divergence_fraction` of the pack's
//!    usable energy below what the corrected plan predicted.
//!
//! # The re-plan
//!
//! The problem is the *rest* of the mission: the phase in flight shortened to its time left
//! (for a phase whose duration depends on a task's level, every level's duration is shortened
//! by the time elapsed), the later phases whole. The correction ratio scales every power of
//! the problem (flight, base and task tables). A pack measurement cannot tell whether the
//! motors or the computer draw more than modelled, so the ratio is applied uniformly; since
//! energy is linear in power this is the same as dividing the budget by the ratio, but scaling
//! the problem keeps every reported energy in real watt-hours.
//!
//! The budget for a plan is the estimator's remaining energy rated at that plan's mean power
//! (a heavier load sags the pack to its cutoff sooner) minus the reserve, which is fixed at the
//! start: `reserve_fraction` × the full pack's usable energy, rated like `qosrt plan` does (at
//! the mean power of the best plan). The first levels are the offline plan's, or, where the
//! offline optimum leaves less than the switch-up margin, the best plan that keeps it.
//!
//! # Hysteresis
//!
//! - **Down at once**: when the levels in force no longer fit the budget, the governor switches
//!   immediately (no dwell: safety first) to the best plan that fits with the margin, or, if
//!   none does, to the best that fits at all.
//! - **Up only with margin and after a dwell**: the levels go up only when `min_dwell_s` has
//!   passed since the last change and a better plan would fit the budget with *twice* the
//!   margin; they then go to the best plan that keeps the margin. The margin is the larger of
//!   `switch_up_margin_fraction` × the budget (covers the noise of the correction ratio, which
//!   scales with the energy still to be spent) and `switch_up_margin_sigma` standard deviations
//!   of the estimator's remaining energy (covers the SoC uncertainty). Between "fits" and "a
//!   better plan fits with two margins" nothing changes, and slack that grows slowly gives one
//!   step up, not a staircase.
//! - **Land now**: when even the cheapest levels need more than the budget, the governor
//!   switches to them; when they are short by more than `land_now_sigma` standard deviations
//!   of the remaining-energy estimate (at most `land_now_max_tolerance_fraction` of the
//!   reserve), it raises [`GovernorEvent::LandNow`], once, and holds the lowest levels from
//!   then on (the landing logic owns the mission after that). The tolerance keeps an
//!   estimate's error from aborting a mission that would have kept its reserve; it can cost
//!   at most that capped part of the reserve.
//!
//! Every change is returned as a [`GovernorEvent`] and logged as a `tracing` event (target
//! `qosrt::governor`) with the numbers behind it.

use crate::energy::{energy_budget, BudgetError, MissionModel};
use crate::telemetry::{BatteryTelemetry, MissionProgress};
use power_models::battery::{BatteryError, BatteryEstimator};
use power_models::planner::{level_of, solve, Plan, PlanError, PlanProblem, TaskLevel};
use thiserror::Error;

mod change;
mod decision;
mod events;
mod replan;

pub use crate::config::{BadGovernorConfig, GovernorConfig};
pub use change::{PlanChange, PlanChangeError};
pub use decision::{GovernorDecision, LevelMove};
pub use events::{
    ChangeReason, Decision, GovernorEvent, LandNow, LevelChange, ReplanSummary, ReplanTrigger,
};
pub use replan::ReplanError;

const SECONDS_PER_HOUR: f64 = 3600.0;

/// Why the governor cannot take an input; each names the thing and the fix. After an error
/// the governor is exactly as before the call.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum GovernorError {
    #[error("rejected battery telemetry: {0}")]
    Telemetry(#[source] BatteryError),
    #[error(
        "battery telemetry at t = {time_s} s is older than the previous sample (t = {previous_s} s); \
         stamp telemetry with the runtime's monotonic clock, not the autopilot's boot time"
    )]
    TimeWentBack { time_s: f64, previous_s: f64 },
    #[error(
        "mission progress names phase {phase}, but the mission has {phase_count} phase(s), \
         numbered from 0"
    )]
    UnknownPhase { phase: usize, phase_count: usize },
    #[error(
        "mission progress went back from phase {from} to phase {to}; phases are flown in order"
    )]
    PhaseWentBack { from: usize, to: usize },
    #[error(
        "mission progress: phase_elapsed_s = {value}, expected a finite number of seconds >= 0"
    )]
    BadElapsed { value: f64 },
    #[error(transparent)]
    BadConfig(#[from] BadGovernorConfig),
    #[error("reserve_fraction = {value} is invalid, expected a fraction in [0, 1)")]
    BadReserve { value: f64 },
    #[error("the mission has no phases to govern; add a [[mission.phase]]")]
    NoPhases,
    #[error("battery: {0}")]
    Battery(#[source] BatteryError),
    #[error("cannot plan the mission: {0}")]
    Plan(#[from] PlanError),
    #[error(
        "re-pricing: the new power model has other tasks, phases or tables than the plan's \
         (phase {phase})"
    )]
    RepriceShape { phase: usize },
}

/// First-order low-pass of the voltage and current handed to the estimator.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct TelemetryFilter {
    time_s: Option<f64>,
    voltage_v: Option<f64>,
    current_a: Option<f64>,
}

impl TelemetryFilter {
    /// The filter after `reading`, and the reading smoothed by it. A field the reading lacks
    /// stays absent (nothing is invented) and its filter restarts from its next reading, so a
    /// stale value is never blended in.
    fn step(self, reading: &BatteryTelemetry, tau_s: f64) -> (Self, BatteryTelemetry) {
        let alpha = match self.time_s {
            Some(previous_s) if tau_s > 0.0 => {
                1.0 - (-(reading.time_s - previous_s).max(0.0) / tau_s).exp()
            }
            _ => 1.0,
        };
        let smooth = |filtered: Option<f64>, raw: Option<f64>| {
            raw.map(|r| filtered.map_or(r, |f| f + alpha * (r - f)))
        };
        let next = Self {
            time_s: Some(reading.time_s),
            voltage_v: smooth(self.voltage_v, reading.voltage_v),
            current_a: smooth(self.current_a, reading.current_a),
        };
        let smoothed = BatteryTelemetry {
            voltage_v: next.voltage_v,
            current_a: next.current_a,
            ..*reading
        };
        (next, smoothed)
    }
}

/// What the prediction looked like at the last re-plan, to notice a faster drain.
#[derive(Debug, Clone, PartialEq)]
struct DrainWatch {
    rating_power_w: f64,
    remaining_at_replan_wh: f64,
    /// Corrected energy the plan predicted since the re-plan.
    predicted_used_wh: f64,
    correction_ratio: f64,
}

/// Re-plans the mission's QoS levels from battery telemetry; see the module documentation.
#[derive(Debug, Clone, PartialEq)]
pub struct Governor {
    /// The whole mission, with the model's (uncorrected) powers.
    problem: PlanProblem,
    config: GovernorConfig,
    estimator: BatteryEstimator,
    filter: TelemetryFilter,
    usable_full_wh: f64,
    reserve_rating_power_w: f64,
    reserve_wh: f64,
    initial_plan: Plan,
    /// Per phase of the mission, the levels in force (past phases keep their last levels).
    levels: Vec<Vec<TaskLevel>>,
    progress: MissionProgress,
    /// The phase flying, as the sequencer last said ([`Governor::enter_phase`] or a sample's
    /// progress): its levels are the ones in force, whether or not telemetry has come since.
    phase_in_flight: usize,
    correction_ratio: f64,
    ignored_power_samples: u64,
    first_time_s: Option<f64>,
    last_time_s: Option<f64>,
    last_power_time_s: Option<f64>,
    last_replan_s: Option<f64>,
    last_change_s: Option<f64>,
    watch: Option<DrainWatch>,
    land_now: bool,
    last_replan: Option<ReplanSummary>,
}

impl Governor {
    /// A governor for `problem` (model powers, as [`MissionModel::plan_problem`] gives it)
    /// fed through `estimator`, keeping `reserve_fraction` of the full pack's usable energy.
    /// The levels start at the best plan for a full pack that keeps the switch-up margin.
    pub fn new(
        problem: PlanProblem,
        estimator: BatteryEstimator,
        reserve_fraction: f64,
        config: GovernorConfig,
    ) -> Result<Self, GovernorError> {
        config.validate()?;
        if !(0.0..1.0).contains(&reserve_fraction) {
            return Err(GovernorError::BadReserve {
                value: reserve_fraction,
            });
        }
        if problem.phases.is_empty() {
            return Err(GovernorError::NoPhases);
        }
        // As `qosrt plan`: the pack rated at the best plan's mean power.
        let budget = energy_budget(&problem, estimator.spec(), reserve_fraction).map_err(
            |error| match error {
                BudgetError::Plan(error) => GovernorError::Plan(error),
                BudgetError::Battery(error) => GovernorError::Battery(error),
            },
        )?;
        let reserve_rating_power_w = budget.rating_power_w;
        let usable_full_wh = budget.usable_wh;
        let reserve_wh = budget.reserve_wh;
        // The offline optimum sits on the edge of its budget, where the first noisy reading
        // would force a switch down; start from the best plan that keeps the switch-up margin,
        // as any plan the governor adopts by choice does.
        let available_wh = budget.available_wh;
        let with_margin = solve(
            &problem,
            available_wh - config.switch_up_margin_fraction * available_wh.max(0.0),
        )?;
        let initial_plan = if with_margin.feasible {
            with_margin
        } else {
            solve(&problem, available_wh)?
        };
        let levels = initial_plan
            .phases
            .iter()
            .map(|p| p.levels.clone())
            .collect();
        Ok(Self {
            problem,
            config,
            estimator,
            filter: TelemetryFilter::default(),
            usable_full_wh,
            reserve_rating_power_w,
            reserve_wh,
            initial_plan,
            levels,
            progress: MissionProgress::start(),
            phase_in_flight: 0,
            correction_ratio: 1.0,
            ignored_power_samples: 0,
            first_time_s: None,
            last_time_s: None,
            last_power_time_s: None,
            last_replan_s: None,
            last_change_s: None,
            watch: None,
            land_now: false,
            last_replan: None,
        })
    }

    /// Prices the levels anew: the same tasks, phases and levels, other powers (a triggered
    /// task measured running slower than its level). The levels in force stay; the next
    /// re-plan and the drain watch use the new powers.
    pub fn reprice(&mut self, problem: PlanProblem) -> Result<(), GovernorError> {
        if problem.phases.len() != self.problem.phases.len() {
            return Err(GovernorError::RepriceShape {
                phase: problem.phases.len().min(self.problem.phases.len()),
            });
        }
        let same_tasks = problem.tasks.len() == self.problem.tasks.len();
        for (phase, (new, old)) in problem.phases.iter().zip(&self.problem.phases).enumerate() {
            let same_terms = new.terms.len() == old.terms.len()
                && new
                    .terms
                    .iter()
                    .zip(&old.terms)
                    .all(|(a, b)| a.tasks == b.tasks && a.power_w.len() == b.power_w.len());
            if !(same_tasks && same_terms && new.active_tasks == old.active_tasks) {
                return Err(GovernorError::RepriceShape { phase });
            }
        }
        self.problem = problem;
        Ok(())
    }

    /// The reserve, as a fraction of the full pack's usable energy.
    pub fn reserve_fraction(&self) -> f64 {
        self.reserve_wh / self.usable_full_wh
    }

    /// A governor for a loaded mission: its plan problem, its battery with the default
    /// estimator tuning, its reserve.
    pub fn from_mission(
        model: &MissionModel,
        config: GovernorConfig,
    ) -> Result<Self, GovernorError> {
        let spec = model.battery_spec(None).map_err(GovernorError::Battery)?;
        let estimator = BatteryEstimator::new(spec).map_err(GovernorError::Battery)?;
        Self::new(
            model.plan_problem(),
            estimator,
            model.config.mission.reserve_fraction,
            config,
        )
    }

    /// Takes one battery sample and the mission's progress at that time; returns what changed.
    /// On error nothing changes and the levels in force stay.
    pub fn update(
        &mut self,
        battery: &BatteryTelemetry,
        progress: MissionProgress,
    ) -> Result<Vec<GovernorEvent>, GovernorError> {
        self.check_progress(progress)?;
        if let Some(previous_s) = self.last_time_s {
            if battery.time_s < previous_s {
                return Err(GovernorError::TimeWentBack {
                    time_s: battery.time_s,
                    previous_s,
                });
            }
        }
        // Checked as received, so an error names the value that was sent, not a smoothed one.
        self.estimator
            .clone()
            .update(battery.to_sample())
            .map_err(GovernorError::Telemetry)?;
        let (filter, smoothed) = self
            .filter
            .step(battery, self.config.telemetry_filter_tau_s);
        let estimate = self
            .estimator
            .update(smoothed.to_sample())
            .map_err(GovernorError::Telemetry)?;
        self.filter = filter;
        // The sample is accepted: nothing below fails.
        let time_s = estimate.time_s;
        let dt_s = self.last_time_s.map_or(0.0, |t| time_s - t);
        // The interval just ended was flown in the previous phase at the levels in force.
        let flown_w = self.model_power_w(self.progress.phase);
        if let (Some(watch), Some(power_w)) = (&mut self.watch, flown_w) {
            watch.predicted_used_wh += watch.correction_ratio * power_w * dt_s / SECONDS_PER_HOUR;
        }
        let phase_started = progress.phase != self.progress.phase;
        self.progress = progress;
        self.phase_in_flight = self.phase_in_flight.max(progress.phase);
        self.last_time_s = Some(time_s);
        if let Some(measured_w) = battery.power_w() {
            self.update_correction(measured_w, time_s);
        }
        let first_time_s = *self.first_time_s.get_or_insert(time_s);
        // The initial plan came into force with the first sample.
        self.last_change_s.get_or_insert(time_s);
        let mut events = Vec::new();
        if self.land_now || time_s - first_time_s < self.config.warmup_s {
            return Ok(events);
        }
        if let Some(trigger) = self.replan_trigger(time_s, phase_started) {
            self.replan(trigger, time_s, &mut events);
        }
        Ok(events)
    }

    /// The sequencer started `phase`: its levels are in force from now, before any telemetry
    /// says so (the re-plan at a phase's start waits for the next sample, which prices the
    /// interval just flown).
    pub fn enter_phase(&mut self, phase: usize) -> Result<(), GovernorError> {
        let phase_count = self.problem.phases.len();
        if phase >= phase_count {
            return Err(GovernorError::UnknownPhase { phase, phase_count });
        }
        if phase < self.phase_in_flight {
            return Err(GovernorError::PhaseWentBack {
                from: self.phase_in_flight,
                to: phase,
            });
        }
        self.phase_in_flight = phase;
        Ok(())
    }

    /// The levels in force for the phase in flight: what the scheduler applies. One entry per
    /// task active in the phase; `task` indexes the config's tasks, `level` their levels.
    pub fn current_levels(&self) -> &[TaskLevel] {
        &self.levels[self.phase_in_flight]
    }

    /// The level in force for `task` in the phase in flight; None if it does not run in it.
    pub fn current_level_of(&self, task: usize) -> Option<usize> {
        level_of(self.current_levels(), task)
    }

    /// The planned levels of the phase in flight and every later phase, in order.
    pub fn planned_levels(&self) -> &[Vec<TaskLevel>] {
        &self.levels[self.phase_in_flight..]
    }

    /// The levels of any phase: planned for a later one, last in force for a past one.
    pub fn phase_levels(&self, phase: usize) -> Option<&[TaskLevel]> {
        self.levels.get(phase).map(Vec::as_slice)
    }

    /// The filtered ratio of measured to predicted power (1 = the model is right).
    pub fn correction_ratio(&self) -> f64 {
        self.correction_ratio
    }

    /// Power samples ignored because their ratio to the prediction was implausible.
    pub fn ignored_power_samples(&self) -> u64 {
        self.ignored_power_samples
    }

    /// Whether a land-now event has been raised.
    pub fn land_now_raised(&self) -> bool {
        self.land_now
    }

    /// Energy that must be left at touchdown.
    pub fn reserve_wh(&self) -> f64 {
        self.reserve_wh
    }

    /// The full pack's usable energy, rated at [`Governor::reserve_rating_power_w`].
    pub fn usable_full_wh(&self) -> f64 {
        self.usable_full_wh
    }

    /// The load at which the reserve was rated: the best plan's mean power.
    pub fn reserve_rating_power_w(&self) -> f64 {
        self.reserve_rating_power_w
    }

    /// The plan the governor started from: the best plan for a full pack that keeps the
    /// switch-up margin (the offline optimum when none does).
    pub fn initial_plan(&self) -> &Plan {
        &self.initial_plan
    }

    pub fn last_replan(&self) -> Option<&ReplanSummary> {
        self.last_replan.as_ref()
    }

    pub fn estimator(&self) -> &BatteryEstimator {
        &self.estimator
    }

    pub fn progress(&self) -> MissionProgress {
        self.progress
    }

    pub fn config(&self) -> &GovernorConfig {
        &self.config
    }

    /// The whole mission's problem with the model's powers.
    pub fn problem(&self) -> &PlanProblem {
        &self.problem
    }

    /// The model's power (flight + companion) of `phase` at the levels in force for it.
    pub fn model_power_w(&self, phase: usize) -> Option<f64> {
        self.problem.phase_power_w(phase, self.levels.get(phase)?)
    }

    fn check_progress(&self, progress: MissionProgress) -> Result<(), GovernorError> {
        let phase_count = self.problem.phases.len();
        if progress.phase >= phase_count {
            return Err(GovernorError::UnknownPhase {
                phase: progress.phase,
                phase_count,
            });
        }
        if progress.phase < self.progress.phase {
            return Err(GovernorError::PhaseWentBack {
                from: self.progress.phase,
                to: progress.phase,
            });
        }
        if !(progress.phase_elapsed_s.is_finite() && progress.phase_elapsed_s >= 0.0) {
            return Err(GovernorError::BadElapsed {
                value: progress.phase_elapsed_s,
            });
        }
        Ok(())
    }

    /// Folds one `V·I` reading into the filtered ratio of measured to predicted power.
    fn update_correction(&mut self, measured_w: f64, time_s: f64) {
        let Some(predicted_w) = self.model_power_w(self.progress.phase) else {
            return;
        };
        if predicted_w <= 0.0 {
            return;
        }
        let ratio = measured_w / predicted_w;
        if !(self.config.correction_min..=self.config.correction_max).contains(&ratio) {
            self.ignored_power_samples += 1;
            tracing::debug!(
                target: "qosrt::governor",
                time_s,
                measured_w,
                predicted_w,
                "power reading ignored: implausible ratio to the model"
            );
            return;
        }
        // The first reading has no interval to weigh it with: it only starts the filter.
        if let Some(previous_s) = self.last_power_time_s {
            let alpha = 1.0 - (-(time_s - previous_s) / self.config.correction_tau_s).exp();
            self.correction_ratio += alpha * (ratio - self.correction_ratio);
        }
        self.last_power_time_s = Some(time_s);
    }

    fn replan_trigger(&self, time_s: f64, phase_started: bool) -> Option<ReplanTrigger> {
        let Some(last_replan_s) = self.last_replan_s else {
            return Some(ReplanTrigger::Start);
        };
        if phase_started {
            return Some(ReplanTrigger::PhaseStarted);
        }
        if let Some(divergence_wh) = self.drain_divergence_wh() {
            if divergence_wh > self.config.drain_divergence_fraction * self.usable_full_wh {
                return Some(ReplanTrigger::DrainFaster { divergence_wh });
            }
        }
        (time_s - last_replan_s >= self.config.replan_period_s).then_some(ReplanTrigger::Periodic)
    }

    /// How far the measured remaining energy has fallen below the last re-plan's prediction.
    fn drain_divergence_wh(&self) -> Option<f64> {
        let watch = self.watch.as_ref()?;
        let measured_wh = self
            .estimator
            .remaining_energy_wh_at(watch.rating_power_w)
            .ok()?;
        Some(watch.remaining_at_replan_wh - watch.predicted_used_wh - measured_wh)
    }
}

#[cfg(test)]
mod tests;
