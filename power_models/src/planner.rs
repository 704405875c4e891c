//! The offline QoS planner: choose one QoS level per task per mission phase to maximise the
//! weighted utility while the predicted mission energy stays within a budget.
//!
//! # Problem
//!
//! Phases run one after the other. In phase `p` the active tasks each take a level; the phase
//! earns `Σ weight_t × utility_t(level_t)` and costs
//! `duration_p × (flight_power_p + base_power_p + Σ_terms term_power(levels of the term's tasks)) / 3600`
//! watt-hours. A power term is a precomputed table over the joint levels of a few coupled tasks
//! (a joint power model); the terms of one phase cover disjoint tasks. A phase's duration may
//! depend on one task's level (a faster landing loop lands sooner).
//!
//! # Method (exact)
//!
//! This is a multiple-choice knapsack. Each power term is a group whose options are the
//! combinations of its tasks' levels. Instead of a budget-indexed table we build Pareto frontiers
//! in the (energy, utility) plane, which needs no discretisation of energy:
//!
//! 1. a term's frontier: its combinations as (energy, utility) points, dominated ones removed;
//! 2. a phase's frontier: fix the level of the duration task (if any; this fixes the phase's
//!    duration, so every term's energy is known), sum the terms' frontiers one after another
//!    (the Minkowski sum of two frontiers, pruned), then take the union over the duration
//!    task's levels and prune again;
//! 3. the mission's frontier: the pruned sum of the phases' frontiers.
//!
//! A point dropped by pruning is dominated (no less energy, no more utility) by a kept one, and
//! sums preserve domination, so no optimum is ever lost: the mission frontier is exactly the set
//! of Pareto-optimal plans, and the best plan within a budget is its last point that fits.
//! Every kept point remembers where it came from, so the levels are recovered exactly.
//!
//! The sum of two frontiers is computed by a heap merge in order of energy that skips, with a
//! binary search, the runs of candidates already dominated, so it usually examines far fewer
//! than the product of the two sizes.
//!
//! # Growth
//!
//! Frontier sizes are what the time depends on. For realistic tables (power and utility both
//! rising with the level) they stay small and grow roughly polynomially with the number of tasks:
//! `benches/planner.rs` measures 6 tasks × 8 levels × 3 phases in under 1 ms and 12 tasks in
//! about 7 ms (mission frontiers of about 900 and 3 200 points). In the worst case they cannot: the problem contains 0/1 knapsack,
//! which is NP-hard, and tables built like subset-sum instances (powers of two) make the frontier
//! grow exponentially with the number of terms. The planner stays exact then and gets slow; it
//! never truncates a frontier.
//!
//! # Numerics
//!
//! Utilities within [`TIE_TOLERANCE`] × (the largest attainable utility) of each other count as
//! equal and the cheaper point wins. Table values carry no such precision, so this only merges
//! genuine ties that differ by summation-order rounding, and it keeps "ties: prefer lower energy"
//! true despite it. The budget test itself is exact: a plan is feasible when its `energy_wh`, as
//! reported, is ≤ the budget.

use serde::{Deserialize, Serialize};
use thiserror::Error;

mod evaluation;
mod frontier;
mod validate;

pub use evaluation::{level_of, Evaluation};

use frontier::Frontiers;

/// Relative tolerance under which two utilities are a tie (relative to the largest attainable
/// mission utility). Summation-order rounding is around 1e-16 relative; this leaves a wide margin
/// while staying far below any meaningful difference in utility tables.
pub const TIE_TOLERANCE: f64 = 1e-12;

const SECONDS_PER_HOUR: f64 = 3600.0;

/// A task whose QoS the planner chooses: level `l` (0 = lowest QoS) earns `weight × utility[l]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanTask {
    pub name: String,
    /// Utility of each level, lowest QoS first, each in [0, 1]. Its length is the level count.
    pub utility: Vec<f64>,
    /// Importance of the task, ≥ 0.
    pub weight: f64,
    /// The levels the planner may choose (all of them when `None`): an operator's bounds,
    /// e.g. a hazard detector that must not drop below level 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub allowed_levels: Option<LevelRange>,
}

/// Levels `min..=max` of a task, 0 = lowest QoS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LevelRange {
    pub min: usize,
    pub max: usize,
}

impl LevelRange {
    pub fn contains(&self, level: usize) -> bool {
        (self.min..=self.max).contains(&level)
    }

    /// Whether it names levels a task of `count` levels has (and at least one).
    pub fn fits(&self, count: usize) -> bool {
        self.min <= self.max && self.max < count
    }
}

impl PlanTask {
    /// Whether the planner may choose `level` for this task.
    pub fn allows(&self, level: usize) -> bool {
        self.allowed_levels
            .is_none_or(|range| range.contains(level))
    }
}

/// Companion-computer power of a set of coupled tasks, from a joint power model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PowerTerm {
    /// Indices into [`PlanProblem::tasks`]; all active in the phase, none in another term of it.
    pub tasks: Vec<usize>,
    /// Power (W) of every combination of the tasks' levels, row-major with the first task
    /// slowest: the index of levels `(l0, l1)` is `l0 × levels(task1) + l1`
    /// ([`PowerTerm::index_of`], [`PowerTerm::levels_at`]).
    pub power_w: Vec<f64>,
}

/// A phase whose duration depends on one task's level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DurationByLevel {
    /// Index into [`PlanProblem::tasks`]; must be active in the phase.
    pub task: usize,
    /// The phase's duration (s) at each level of the task.
    pub duration_s: Vec<f64>,
}

/// One phase of the mission (transit, tracking, landing, …).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanPhase {
    pub name: String,
    /// Duration (s), used when `duration_by_level` is `None`.
    pub duration_s: f64,
    pub duration_by_level: Option<DurationByLevel>,
    /// Power drawn by the vehicle's flight (W), independent of QoS.
    pub flight_power_w: f64,
    /// Companion-computer power not attributed to any task (W).
    pub base_power_w: f64,
    /// Tasks that run in this phase; each gets a level. One in no term costs no power, so it
    /// runs at its best level.
    pub active_tasks: Vec<usize>,
    pub terms: Vec<PowerTerm>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanProblem {
    pub tasks: Vec<PlanTask>,
    pub phases: Vec<PlanPhase>,
}

/// The level chosen for one task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct TaskLevel {
    pub task: usize,
    pub level: usize,
}

/// The chosen levels of one phase and what they cost.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhasePlan {
    pub name: String,
    /// One entry per active task, in the order of [`PlanPhase::active_tasks`].
    pub levels: Vec<TaskLevel>,
    pub duration_s: f64,
    pub flight_power_w: f64,
    /// Base power plus every term's power at the chosen levels (W).
    pub companion_power_w: f64,
    pub energy_wh: f64,
    pub utility: f64,
}

/// The planner's answer for one budget.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Plan {
    /// False when even the cheapest plan needs more than the budget; the plan is then the
    /// cheapest one, so `energy_wh - budget_wh` is the shortfall.
    pub feasible: bool,
    pub budget_wh: f64,
    pub utility: f64,
    pub energy_wh: f64,
    /// Energy of the cheapest plan (all phases at their cheapest levels).
    pub min_energy_wh: f64,
    pub phases: Vec<PhasePlan>,
}

/// One Pareto-optimal plan: no plan has less energy and at least this utility.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParetoPoint {
    pub energy_wh: f64,
    pub utility: f64,
    pub phases: Vec<PhasePlan>,
}

/// A problem the planner cannot accept; each names the thing to fix.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlanError {
    #[error("task `{task}` has no QoS levels; give it at least one utility value")]
    NoLevels { task: String },
    #[error("task `{task}`, level {level}: utility {value} is not in [0, 1]")]
    BadUtility {
        task: String,
        level: usize,
        value: f64,
    },
    #[error("task `{task}`: weight {value} must be a finite number ≥ 0")]
    BadWeight { task: String, value: f64 },
    #[error("phase `{phase}`: {what} is {value}; it must be a finite number ≥ 0")]
    BadPhaseValue {
        phase: String,
        what: String,
        value: f64,
    },
    #[error(
        "phase `{phase}`: task index {task} does not exist (the problem has {task_count} tasks)"
    )]
    UnknownTask {
        phase: String,
        task: usize,
        task_count: usize,
    },
    #[error("phase `{phase}`: task `{task}` is listed twice in active_tasks")]
    DuplicateActiveTask { phase: String, task: String },
    #[error("phase `{phase}`: power term {term} covers no task")]
    EmptyTerm { phase: String, term: usize },
    #[error("phase `{phase}`: power term {term} lists task `{task}` twice")]
    DuplicateTermTask {
        phase: String,
        term: usize,
        task: String,
    },
    #[error("phase `{phase}`: power term {term} covers task `{task}`, which is not active in this phase")]
    TermTaskNotActive {
        phase: String,
        term: usize,
        task: String,
    },
    #[error("phase `{phase}`: task `{task}` is covered by power terms {first} and {second}; the terms of a phase must cover disjoint tasks")]
    OverlappingTerms {
        phase: String,
        task: String,
        first: usize,
        second: usize,
    },
    #[error("phase `{phase}`: power term {term} has {found} power values; it needs {expected}, the product of its tasks' level counts")]
    TermTableSize {
        phase: String,
        term: usize,
        expected: usize,
        found: usize,
    },
    #[error("phase `{phase}`: power term {term} has too many level combinations to enumerate")]
    TermTooLarge { phase: String, term: usize },
    #[error("phase `{phase}`: duration_by_level task `{task}` is not active in this phase")]
    DurationTaskNotActive { phase: String, task: String },
    #[error("phase `{phase}`: duration_by_level gives {found} durations for task `{task}`, which has {expected} levels")]
    DurationTableSize {
        phase: String,
        task: String,
        expected: usize,
        found: usize,
    },
    #[error("the problem's {what} overflows a 64-bit float; scale its values down")]
    Overflow { what: &'static str },
    #[error("task `{task}`: allowed levels {min}..={max} are not within its {count} levels (0..={last})", last = count.saturating_sub(1))]
    BadLevelRange {
        task: String,
        min: usize,
        max: usize,
        count: usize,
    },
    #[error("energy budget {value} Wh is not a finite number")]
    BadBudget { value: f64 },
}

/// The best plan whose energy is within `budget_wh`, or, when none is, the cheapest plan with
/// `feasible: false`. Among plans of equal utility the one with less energy wins.
pub fn solve(problem: &PlanProblem, budget_wh: f64) -> Result<Plan, PlanError> {
    if !budget_wh.is_finite() {
        return Err(PlanError::BadBudget { value: budget_wh });
    }
    let built = Frontiers::build(problem)?;
    let mission = built.mission();
    // Energies strictly increase along the frontier, so the points within budget are a prefix
    // and its last point has the highest utility.
    let fitting = mission.partition_point(|p| p.energy_wh <= budget_wh);
    let feasible = fitting > 0;
    let index = if feasible { fitting - 1 } else { 0 };
    let chosen = mission[index];
    Ok(Plan {
        feasible,
        budget_wh,
        utility: chosen.utility,
        energy_wh: chosen.energy_wh,
        min_energy_wh: mission[0].energy_wh,
        phases: built.phase_plans(problem, index),
    })
}

/// Every Pareto-optimal plan, by increasing energy; energy and utility both strictly increase
/// along it. The first point is the cheapest plan, the last the best regardless of energy.
pub fn pareto_frontier(problem: &PlanProblem) -> Result<Vec<ParetoPoint>, PlanError> {
    let built = Frontiers::build(problem)?;
    Ok(built
        .mission()
        .iter()
        .enumerate()
        .map(|(index, p)| ParetoPoint {
            energy_wh: p.energy_wh,
            utility: p.utility,
            phases: built.phase_plans(problem, index),
        })
        .collect())
}

#[cfg(test)]
mod tests;
