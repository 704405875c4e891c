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

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use serde::{Deserialize, Serialize};
use thiserror::Error;

mod evaluation;
pub use evaluation::{level_of, Evaluation};

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

/// A frontier point with a back-pointer pair, whose meaning depends on the frontier it is in.
#[derive(Debug, Clone, Copy)]
struct Point {
    energy_wh: f64,
    utility: f64,
    left: usize,
    right: usize,
}

/// One fixed duration of a phase (one level of its duration task) and the frontiers built for it.
struct Chain {
    duration_level: Option<usize>,
    duration_s: f64,
    /// Per term: its frontier; `left` is the combination index into the term's table.
    terms: Vec<Vec<Point>>,
    /// `steps[0]` is the single point of the phase's fixed part; `steps[i + 1]` is the sum of
    /// `steps[i]` (via `left`) and `terms[i]` (via `right`).
    steps: Vec<Vec<Point>>,
}

struct PhaseFrontier {
    chains: Vec<Chain>,
    /// Active tasks in no term (and not the duration task): they cost nothing, so best level.
    free: Vec<TaskLevel>,
    /// Union of the chains' last steps: `left` is the chain, `right` the point in its last step.
    points: Vec<Point>,
}

struct Frontiers {
    phases: Vec<PhaseFrontier>,
    /// `steps[0]` is the empty mission; `steps[p + 1]` is the sum of `steps[p]` (via `left`) and
    /// phase `p`'s frontier (via `right`).
    steps: Vec<Vec<Point>>,
}

impl Frontiers {
    fn build(problem: &PlanProblem) -> Result<Self, PlanError> {
        let tolerance = validate(problem)? * TIE_TOLERANCE;
        let phases: Vec<PhaseFrontier> = problem
            .phases
            .iter()
            .map(|phase| build_phase(problem, phase, tolerance))
            .collect();
        let mut steps = vec![vec![Point {
            energy_wh: 0.0,
            utility: 0.0,
            left: 0,
            right: 0,
        }]];
        for phase in &phases {
            let next = minkowski_sum(&steps[steps.len() - 1], &phase.points, tolerance);
            steps.push(next);
        }
        Ok(Frontiers { phases, steps })
    }

    fn mission(&self) -> &[Point] {
        &self.steps[self.steps.len() - 1]
    }

    /// Follows the back-pointers of mission point `index` down to every task's level.
    fn phase_plans(&self, problem: &PlanProblem, index: usize) -> Vec<PhasePlan> {
        let mut phase_points = vec![0; self.phases.len()];
        let mut at = index;
        for p in (0..self.phases.len()).rev() {
            let point = self.steps[p + 1][at];
            phase_points[p] = point.right;
            at = point.left;
        }
        problem
            .phases
            .iter()
            .zip(&self.phases)
            .zip(phase_points)
            .map(|((phase, frontier), point)| phase_plan(problem, phase, frontier, point))
            .collect()
    }
}

fn phase_plan(
    problem: &PlanProblem,
    phase: &PlanPhase,
    frontier: &PhaseFrontier,
    index: usize,
) -> PhasePlan {
    let top = frontier.points[index];
    let chain = &frontier.chains[top.left];
    let mut level_of = vec![usize::MAX; problem.tasks.len()];
    for free in &frontier.free {
        level_of[free.task] = free.level;
    }
    if let (Some(by_level), Some(level)) = (&phase.duration_by_level, chain.duration_level) {
        level_of[by_level.task] = level;
    }
    let mut companion_power_w = phase.base_power_w;
    let mut at = top.right;
    let mut combos = vec![0; phase.terms.len()];
    for t in (0..phase.terms.len()).rev() {
        let point = chain.steps[t + 1][at];
        combos[t] = chain.terms[t][point.right].left;
        at = point.left;
    }
    for (term, &combo) in phase.terms.iter().zip(&combos) {
        for (&task, level) in term.tasks.iter().zip(term.levels_at(&problem.tasks, combo)) {
            level_of[task] = level;
        }
        companion_power_w += term.power_w[combo];
    }
    PhasePlan {
        name: phase.name.clone(),
        levels: phase
            .active_tasks
            .iter()
            .map(|&task| TaskLevel {
                task,
                level: level_of[task],
            })
            .collect(),
        duration_s: chain.duration_s,
        flight_power_w: phase.flight_power_w,
        companion_power_w,
        energy_wh: top.energy_wh,
        utility: top.utility,
    }
}

fn build_phase(problem: &PlanProblem, phase: &PlanPhase, tolerance: f64) -> PhaseFrontier {
    let in_term: Vec<usize> = phase.terms.iter().flat_map(|t| t.tasks.clone()).collect();
    let duration_task = phase.duration_by_level.as_ref().map(|d| d.task);
    let free: Vec<TaskLevel> = phase
        .active_tasks
        .iter()
        .filter(|t| !in_term.contains(t) && duration_task != Some(**t))
        .map(|&task| TaskLevel {
            task,
            level: best_level(&problem.tasks[task].utility),
        })
        .collect();
    let free_utility: f64 = free
        .iter()
        .map(|f| weighted_utility(problem, f.task, f.level))
        .sum();

    // One chain per possible duration: the duration task's level is fixed inside it.
    let options: Vec<(Option<usize>, f64)> = match &phase.duration_by_level {
        None => vec![(None, phase.duration_s)],
        Some(by_level) => by_level
            .duration_s
            .iter()
            .enumerate()
            .map(|(level, &d)| (Some(level), d))
            .collect(),
    };
    let chains: Vec<Chain> = options
        .into_iter()
        .map(|(duration_level, duration_s)| {
            let fixed = match (duration_task, duration_level) {
                (Some(task), Some(level)) => Some((task, level)),
                _ => None,
            };
            let mut start_utility = free_utility;
            if let Some((task, level)) = fixed {
                if !in_term.contains(&task) {
                    start_utility += weighted_utility(problem, task, level);
                }
            }
            let start = Point {
                energy_wh: duration_s * (phase.flight_power_w + phase.base_power_w)
                    / SECONDS_PER_HOUR,
                utility: start_utility,
                left: 0,
                right: 0,
            };
            let terms: Vec<Vec<Point>> = phase
                .terms
                .iter()
                .map(|term| term_frontier(problem, term, duration_s, fixed, tolerance))
                .collect();
            let mut steps = vec![vec![start]];
            for term in &terms {
                let next = minkowski_sum(&steps[steps.len() - 1], term, tolerance);
                steps.push(next);
            }
            Chain {
                duration_level,
                duration_s,
                terms,
                steps,
            }
        })
        .collect();

    let union = chains
        .iter()
        .enumerate()
        .flat_map(|(c, chain)| {
            chain.steps[chain.steps.len() - 1]
                .iter()
                .enumerate()
                .map(move |(i, p)| Point {
                    left: c,
                    right: i,
                    ..*p
                })
        })
        .collect();
    PhaseFrontier {
        chains,
        free,
        points: prune(union, tolerance),
    }
}

/// The frontier of one term's combinations at a fixed phase duration; `fixed` pins the
/// duration task's level when it belongs to this term.
fn term_frontier(
    problem: &PlanProblem,
    term: &PowerTerm,
    duration_s: f64,
    fixed: Option<(usize, usize)>,
    tolerance: f64,
) -> Vec<Point> {
    let pinned = fixed.and_then(|(task, level)| {
        term.tasks
            .iter()
            .position(|&t| t == task)
            .map(|slot| (slot, level))
    });
    let candidates = term
        .power_w
        .iter()
        .enumerate()
        .filter_map(|(combo, &power_w)| {
            let levels = term.levels_at(&problem.tasks, combo);
            if let Some((slot, level)) = pinned {
                if levels[slot] != level {
                    return None;
                }
            }
            let utility = term
                .tasks
                .iter()
                .zip(&levels)
                .map(|(&task, &level)| weighted_utility(problem, task, level))
                .sum();
            Some(Point {
                energy_wh: duration_s * power_w / SECONDS_PER_HOUR,
                utility,
                left: combo,
                right: 0,
            })
        })
        .collect();
    prune(candidates, tolerance)
}

fn weighted_utility(problem: &PlanProblem, task: usize, level: usize) -> f64 {
    problem.tasks[task].weight * problem.tasks[task].utility[level]
}

/// The level with the highest utility; on a tie the higher level (the higher QoS).
fn best_level(utility: &[f64]) -> usize {
    let mut best = 0;
    for (level, &u) in utility.iter().enumerate() {
        if u >= utility[best] {
            best = level;
        }
    }
    best
}

/// Keeps the non-dominated points, by strictly increasing energy and utility.
fn prune(mut points: Vec<Point>, tolerance: f64) -> Vec<Point> {
    // Cheapest first; at equal energy the best utility first, so the sweep keeps it.
    points.sort_by(|a, b| {
        a.energy_wh
            .total_cmp(&b.energy_wh)
            .then(b.utility.total_cmp(&a.utility))
    });
    let mut kept: Vec<Point> = Vec::with_capacity(points.len());
    for p in points {
        if kept
            .last()
            .is_none_or(|last| p.utility > last.utility + tolerance)
        {
            kept.push(p);
        }
    }
    kept
}

/// A candidate sum `rows[row] + cols[col]` waiting in the merge heap.
struct Candidate {
    energy_wh: f64,
    utility: f64,
    row: usize,
    col: usize,
}

impl Ord for Candidate {
    // BinaryHeap pops the greatest: make that the least energy, then the most utility.
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .energy_wh
            .total_cmp(&self.energy_wh)
            .then(self.utility.total_cmp(&other.utility))
            .then(other.row.cmp(&self.row))
    }
}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Candidate {}

/// The pruned frontier of `{x + y : x in a, y in b}` for two frontiers (energy and utility
/// non-decreasing). Output points have `left` into `a` and `right` into `b`.
///
/// Each row (a point of the shorter frontier) walks the longer frontier in order of energy; the
/// heap pops candidates by increasing energy, so a popped candidate is kept exactly when it beats
/// the best utility so far. A row's candidates that cannot beat that utility are skipped at once
/// by binary search: they cost at least as much, so they are dominated.
fn minkowski_sum(a: &[Point], b: &[Point], tolerance: f64) -> Vec<Point> {
    let swapped = a.len() > b.len();
    let (rows, cols) = if swapped { (b, a) } else { (a, b) };
    let mut heap = BinaryHeap::with_capacity(rows.len());
    if let Some(first) = cols.first() {
        for (row, r) in rows.iter().enumerate() {
            heap.push(Candidate {
                energy_wh: r.energy_wh + first.energy_wh,
                utility: r.utility + first.utility,
                row,
                col: 0,
            });
        }
    }
    let mut out: Vec<Point> = Vec::new();
    let mut best = f64::NEG_INFINITY;
    while let Some(c) = heap.pop() {
        if c.utility > best + tolerance {
            best = c.utility;
            let (left, right) = if swapped {
                (c.col, c.row)
            } else {
                (c.row, c.col)
            };
            out.push(Point {
                energy_wh: c.energy_wh,
                utility: c.utility,
                left,
                right,
            });
        }
        let row_utility = rows[c.row].utility;
        let rest = &cols[c.col + 1..];
        let col = c.col + 1 + rest.partition_point(|p| row_utility + p.utility <= best + tolerance);
        if let Some(next) = cols.get(col) {
            heap.push(Candidate {
                energy_wh: rows[c.row].energy_wh + next.energy_wh,
                utility: row_utility + next.utility,
                row: c.row,
                col,
            });
        }
    }
    out
}

/// Checks the problem; returns the largest attainable utility (the scale of the tie tolerance).
fn validate(problem: &PlanProblem) -> Result<f64, PlanError> {
    for task in &problem.tasks {
        if task.utility.is_empty() {
            return Err(PlanError::NoLevels {
                task: task.name.clone(),
            });
        }
        for (level, &value) in task.utility.iter().enumerate() {
            // Written so that NaN fails too.
            if !(0.0..=1.0).contains(&value) {
                return Err(PlanError::BadUtility {
                    task: task.name.clone(),
                    level,
                    value,
                });
            }
        }
        if !(task.weight.is_finite() && task.weight >= 0.0) {
            return Err(PlanError::BadWeight {
                task: task.name.clone(),
                value: task.weight,
            });
        }
    }
    let task_count = problem.tasks.len();
    let name = |t: usize| problem.tasks[t].name.clone();
    let mut max_utility = 0.0;
    let mut max_energy_wh = 0.0;
    for phase in &problem.phases {
        let bad = |what: String, value: f64| PlanError::BadPhaseValue {
            phase: phase.name.clone(),
            what,
            value,
        };
        let check = |what: &str, value: f64| {
            if value.is_finite() && value >= 0.0 {
                Ok(value)
            } else {
                Err(bad(what.to_string(), value))
            }
        };
        let mut max_duration_s = check("duration_s", phase.duration_s)?;
        let mut max_power_w = check("flight_power_w", phase.flight_power_w)?;
        max_power_w += check("base_power_w", phase.base_power_w)?;

        let known = |task: usize| {
            if task < task_count {
                Ok(task)
            } else {
                Err(PlanError::UnknownTask {
                    phase: phase.name.clone(),
                    task,
                    task_count,
                })
            }
        };
        let mut active = vec![false; task_count];
        for &task in &phase.active_tasks {
            known(task)?;
            if active[task] {
                return Err(PlanError::DuplicateActiveTask {
                    phase: phase.name.clone(),
                    task: name(task),
                });
            }
            active[task] = true;
            let t = &problem.tasks[task];
            max_utility += t.weight * t.utility.iter().copied().fold(0.0, f64::max);
        }

        let mut covered_by: Vec<Option<usize>> = vec![None; task_count];
        for (term_index, term) in phase.terms.iter().enumerate() {
            if term.tasks.is_empty() {
                return Err(PlanError::EmptyTerm {
                    phase: phase.name.clone(),
                    term: term_index,
                });
            }
            let mut combinations: usize = 1;
            for &task in &term.tasks {
                known(task)?;
                if !active[task] {
                    return Err(PlanError::TermTaskNotActive {
                        phase: phase.name.clone(),
                        term: term_index,
                        task: name(task),
                    });
                }
                match covered_by[task] {
                    Some(first) if first == term_index => {
                        return Err(PlanError::DuplicateTermTask {
                            phase: phase.name.clone(),
                            term: term_index,
                            task: name(task),
                        })
                    }
                    Some(first) => {
                        return Err(PlanError::OverlappingTerms {
                            phase: phase.name.clone(),
                            task: name(task),
                            first,
                            second: term_index,
                        })
                    }
                    None => covered_by[task] = Some(term_index),
                }
                combinations = combinations
                    .checked_mul(problem.tasks[task].utility.len())
                    .ok_or_else(|| PlanError::TermTooLarge {
                        phase: phase.name.clone(),
                        term: term_index,
                    })?;
            }
            if term.power_w.len() != combinations {
                return Err(PlanError::TermTableSize {
                    phase: phase.name.clone(),
                    term: term_index,
                    expected: combinations,
                    found: term.power_w.len(),
                });
            }
            let mut term_max_w: f64 = 0.0;
            for (i, &p) in term.power_w.iter().enumerate() {
                term_max_w =
                    term_max_w.max(check(&format!("power_w[{i}] of term {term_index}"), p)?);
            }
            max_power_w += term_max_w;
        }

        if let Some(by_level) = &phase.duration_by_level {
            known(by_level.task)?;
            if !active[by_level.task] {
                return Err(PlanError::DurationTaskNotActive {
                    phase: phase.name.clone(),
                    task: name(by_level.task),
                });
            }
            let expected = problem.tasks[by_level.task].utility.len();
            if by_level.duration_s.len() != expected {
                return Err(PlanError::DurationTableSize {
                    phase: phase.name.clone(),
                    task: name(by_level.task),
                    expected,
                    found: by_level.duration_s.len(),
                });
            }
            max_duration_s = 0.0;
            for (level, &d) in by_level.duration_s.iter().enumerate() {
                let d = check(&format!("duration_by_level.duration_s[{level}]"), d)?;
                max_duration_s = max_duration_s.max(d);
            }
        }
        max_energy_wh += max_duration_s * max_power_w / SECONDS_PER_HOUR;
    }
    // Finite inputs can still sum to infinity, which would make comparisons meaningless.
    if !max_utility.is_finite() {
        return Err(PlanError::Overflow { what: "utility" });
    }
    if !max_energy_wh.is_finite() {
        return Err(PlanError::Overflow { what: "energy" });
    }
    Ok(max_utility)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};

    fn task(name: &str, utility: &[f64], weight: f64) -> PlanTask {
        PlanTask {
            name: name.to_string(),
            utility: utility.to_vec(),
            weight,
        }
    }

    fn phase(
        name: &str,
        duration_s: f64,
        active_tasks: &[usize],
        terms: Vec<PowerTerm>,
    ) -> PlanPhase {
        PlanPhase {
            name: name.to_string(),
            duration_s,
            duration_by_level: None,
            flight_power_w: 100.0,
            base_power_w: 1.0,
            active_tasks: active_tasks.to_vec(),
            terms,
        }
    }

    fn term(tasks: &[usize], power_w: &[f64]) -> PowerTerm {
        PowerTerm {
            tasks: tasks.to_vec(),
            power_w: power_w.to_vec(),
        }
    }

    /// Independent evaluation of a full assignment, straight from the definition:
    /// `levels[phase][task]` (inactive tasks are ignored). Returns (energy Wh, utility).
    fn evaluate(problem: &PlanProblem, levels: &[Vec<usize>]) -> (f64, f64) {
        let mut energy_wh = 0.0;
        let mut utility = 0.0;
        for (phase, lv) in problem.phases.iter().zip(levels) {
            let duration_s = match &phase.duration_by_level {
                Some(d) => d.duration_s[lv[d.task]],
                None => phase.duration_s,
            };
            let mut power_w = phase.flight_power_w + phase.base_power_w;
            for term in &phase.terms {
                // Row-major index, first task slowest.
                let mut index = 0;
                for &t in &term.tasks {
                    index = index * problem.tasks[t].utility.len() + lv[t];
                }
                power_w += term.power_w[index];
            }
            energy_wh += duration_s * power_w / 3600.0;
            for &t in &phase.active_tasks {
                utility += problem.tasks[t].weight * problem.tasks[t].utility[lv[t]];
            }
        }
        (energy_wh, utility)
    }

    fn plan_levels(problem: &PlanProblem, phases: &[PhasePlan]) -> Vec<Vec<usize>> {
        assert_eq!(phases.len(), problem.phases.len());
        phases
            .iter()
            .zip(&problem.phases)
            .map(|(pp, phase)| {
                let listed: Vec<usize> = pp.levels.iter().map(|l| l.task).collect();
                assert_eq!(
                    listed, phase.active_tasks,
                    "one level per active task, in order"
                );
                let mut lv = vec![usize::MAX; problem.tasks.len()];
                for l in &pp.levels {
                    assert!(l.level < problem.tasks[l.task].utility.len());
                    lv[l.task] = l.level;
                }
                lv
            })
            .collect()
    }

    /// Every combination of levels of every active task in every phase: (energy, utility).
    fn brute_force(problem: &PlanProblem) -> Vec<(f64, f64)> {
        let slots: Vec<(usize, usize)> = problem
            .phases
            .iter()
            .enumerate()
            .flat_map(|(p, ph)| ph.active_tasks.iter().map(move |&t| (p, t)))
            .collect();
        let mut levels = vec![vec![0; problem.tasks.len()]; problem.phases.len()];
        let mut out = Vec::new();
        loop {
            out.push(evaluate(problem, &levels));
            // Odometer step.
            let mut i = 0;
            loop {
                if i == slots.len() {
                    return out;
                }
                let (p, t) = slots[i];
                levels[p][t] += 1;
                if levels[p][t] < problem.tasks[t].utility.len() {
                    break;
                }
                levels[p][t] = 0;
                i += 1;
            }
        }
    }

    fn combinations(problem: &PlanProblem) -> usize {
        problem
            .phases
            .iter()
            .flat_map(|ph| &ph.active_tasks)
            .map(|&t| problem.tasks[t].utility.len())
            .product()
    }

    /// Small random instances: non-decreasing utilities (some with exact ties), coupled terms,
    /// free tasks, zero weights, duration_by_level, integer powers (exact energy ties).
    fn random_problem(rng: &mut StdRng) -> PlanProblem {
        loop {
            let task_count = rng.random_range(1..=4);
            let tasks: Vec<PlanTask> = (0..task_count)
                .map(|i| {
                    let levels = if rng.random_bool(0.1) {
                        1
                    } else {
                        rng.random_range(2..=4)
                    };
                    let coarse = rng.random_bool(0.3);
                    let mut u: f64 = 0.0;
                    let utility = (0..levels)
                        .map(|_| {
                            let step = if coarse {
                                0.25 * f64::from(rng.random_range(0..=1))
                            } else {
                                0.35 * rng.random::<f64>()
                            };
                            u = (u + step).min(1.0);
                            u
                        })
                        .collect();
                    let weight = if rng.random_bool(0.1) {
                        0.0
                    } else if coarse {
                        1.0
                    } else {
                        2.0 * rng.random::<f64>()
                    };
                    PlanTask {
                        name: format!("task{i}"),
                        utility,
                        weight,
                    }
                })
                .collect();
            let phase_count = rng.random_range(1..=3);
            let phases = (0..phase_count)
                .map(|p| {
                    let mut active: Vec<usize> =
                        (0..task_count).filter(|_| rng.random_bool(0.75)).collect();
                    active.shuffle(rng);
                    let integer_powers = rng.random_bool(0.3);
                    let mut terms = Vec::new();
                    let mut i = 0;
                    while i < active.len() {
                        if rng.random_bool(0.15) {
                            i += 1; // a free task
                            continue;
                        }
                        let size = if i + 1 < active.len() && rng.random_bool(0.4) {
                            2
                        } else {
                            1
                        };
                        let members = active[i..i + size].to_vec();
                        let cells: usize =
                            members.iter().map(|&t| tasks[t].utility.len()).product();
                        let power_w = (0..cells)
                            .map(|_| {
                                if integer_powers {
                                    f64::from(rng.random_range(0..4))
                                } else {
                                    10.0 * rng.random::<f64>()
                                }
                            })
                            .collect();
                        terms.push(PowerTerm {
                            tasks: members,
                            power_w,
                        });
                        i += size;
                    }
                    let duration_by_level = if !active.is_empty() && rng.random_bool(0.4) {
                        let t = active[rng.random_range(0..active.len())];
                        Some(DurationByLevel {
                            task: t,
                            duration_s: (0..tasks[t].utility.len())
                                .map(|_| {
                                    if rng.random_bool(0.1) {
                                        0.0
                                    } else {
                                        rng.random_range(30.0..300.0)
                                    }
                                })
                                .collect(),
                        })
                    } else {
                        None
                    };
                    PlanPhase {
                        name: format!("phase{p}"),
                        duration_s: if rng.random_bool(0.05) {
                            0.0
                        } else if integer_powers {
                            // Whole watt-hours: exact energy ties between different plans.
                            3600.0
                        } else {
                            rng.random_range(10.0..600.0)
                        },
                        duration_by_level,
                        flight_power_w: if integer_powers {
                            100.0
                        } else {
                            rng.random_range(0.0..200.0)
                        },
                        base_power_w: if integer_powers {
                            2.0
                        } else {
                            rng.random_range(0.0..5.0)
                        },
                        active_tasks: active,
                        terms,
                    }
                })
                .collect();
            let problem = PlanProblem { tasks, phases };
            if combinations(&problem) <= 20_000 {
                return problem;
            }
        }
    }

    fn utility_scale(problem: &PlanProblem) -> f64 {
        let max: f64 = problem
            .phases
            .iter()
            .flat_map(|ph| &ph.active_tasks)
            .map(|&t| problem.tasks[t].weight)
            .sum();
        max.max(1.0)
    }

    fn close(a: f64, b: f64, scale: f64) -> bool {
        (a - b).abs() <= 1e-9 * scale.max(1.0)
    }

    #[test]
    fn solve_equals_brute_force() {
        let mut rng = StdRng::seed_from_u64(0x5eed_0001);
        let mut infeasible_seen = 0;
        let mut cases = 0;
        for _ in 0..400 {
            let problem = random_problem(&mut rng);
            let combos = brute_force(&problem);
            let scale = utility_scale(&problem);
            let min_e = combos.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
            let max_e = combos.iter().map(|c| c.0).fold(0.0, f64::max);
            let pick = combos[rng.random_range(0..combos.len())].0;
            let budgets = [
                min_e - 1.0,
                min_e * (1.0 - 1e-6) - 1e-9,
                min_e * (1.0 + 1e-9) + 1e-12,
                pick * (1.0 + 1e-9) + 1e-12,
                // Nudged so no plan sits within rounding of the budget (order-of-summation noise).
                rng.random_range(min_e..=max_e) * (1.0 + 1e-9),
                max_e * (1.0 + 1e-9) + 1e-12,
                max_e + 100.0,
            ];
            for budget_wh in budgets {
                cases += 1;
                let plan = solve(&problem, budget_wh).unwrap();
                assert!(close(plan.min_energy_wh, min_e, min_e), "min energy");
                let (e, u) = evaluate(&problem, &plan_levels(&problem, &plan.phases));
                assert!(
                    close(e, plan.energy_wh, e),
                    "energy recomputed {e} vs {}",
                    plan.energy_wh
                );
                assert!(
                    close(u, plan.utility, scale),
                    "utility recomputed {u} vs {}",
                    plan.utility
                );
                let phase_energy: f64 = plan.phases.iter().map(|p| p.energy_wh).sum();
                assert!(close(phase_energy, plan.energy_wh, e));
                let phase_utility: f64 = plan.phases.iter().map(|p| p.utility).sum();
                assert!(close(phase_utility, plan.utility, scale));
                for pp in &plan.phases {
                    let from_power =
                        pp.duration_s * (pp.flight_power_w + pp.companion_power_w) / 3600.0;
                    assert!(close(from_power, pp.energy_wh, from_power));
                }

                let best = combos
                    .iter()
                    .filter(|c| c.0 <= budget_wh)
                    .map(|c| c.1)
                    .fold(f64::NEG_INFINITY, f64::max);
                if best == f64::NEG_INFINITY {
                    infeasible_seen += 1;
                    assert!(!plan.feasible, "budget {budget_wh} below every plan");
                    assert_eq!(plan.energy_wh, plan.min_energy_wh);
                    // Among the cheapest plans, the best utility.
                    let cheapest_best = combos
                        .iter()
                        .filter(|c| c.0 <= min_e + 1e-9 * min_e.max(1.0))
                        .map(|c| c.1)
                        .fold(f64::NEG_INFINITY, f64::max);
                    assert!(close(plan.utility, cheapest_best, scale));
                } else {
                    assert!(plan.feasible, "budget {budget_wh}, best {best}");
                    assert!(plan.energy_wh <= budget_wh);
                    assert!(e <= budget_wh + 1e-9 * budget_wh.max(1.0));
                    assert!(
                        close(plan.utility, best, scale),
                        "utility {} vs brute force {best}",
                        plan.utility
                    );
                    // Ties: no plan of (essentially) the same utility is cheaper.
                    let cheapest_tie = combos
                        .iter()
                        .filter(|c| c.0 <= budget_wh && c.1 >= plan.utility - 1e-11 * scale)
                        .map(|c| c.0)
                        .fold(f64::INFINITY, f64::min);
                    assert!(plan.energy_wh <= cheapest_tie + 1e-9 * cheapest_tie.max(1.0));
                }
            }
        }
        assert!(cases >= 2000 && infeasible_seen >= 400);
    }

    #[test]
    fn more_budget_never_lowers_utility() {
        let mut rng = StdRng::seed_from_u64(0x5eed_0002);
        for _ in 0..100 {
            let problem = random_problem(&mut rng);
            let top = pareto_frontier(&problem).unwrap().last().unwrap().energy_wh;
            let mut previous = (false, f64::NEG_INFINITY);
            for step in 0..=60 {
                let budget_wh = top * 1.1 * f64::from(step) / 60.0;
                let plan = solve(&problem, budget_wh).unwrap();
                if previous.0 {
                    assert!(plan.feasible);
                    assert!(plan.utility >= previous.1, "budget {budget_wh}");
                }
                previous = (
                    plan.feasible,
                    if plan.feasible {
                        plan.utility
                    } else {
                        f64::NEG_INFINITY
                    },
                );
            }
            assert!(previous.0, "the top of the frontier fits");
        }
    }

    #[test]
    fn pareto_frontier_is_exact() {
        let mut rng = StdRng::seed_from_u64(0x5eed_0003);
        for _ in 0..300 {
            let problem = random_problem(&mut rng);
            let scale = utility_scale(&problem);
            let frontier = pareto_frontier(&problem).unwrap();
            assert!(!frontier.is_empty());
            for pair in frontier.windows(2) {
                assert!(pair[1].energy_wh > pair[0].energy_wh);
                assert!(pair[1].utility > pair[0].utility);
            }
            // Every frontier point is a real plan with the stated energy and utility.
            for point in &frontier {
                let (e, u) = evaluate(&problem, &plan_levels(&problem, &point.phases));
                assert!(close(e, point.energy_wh, e));
                assert!(close(u, point.utility, scale));
            }
            // Every plan is dominated by (or equal to) a frontier point.
            let combos = brute_force(&problem);
            for &(e, u) in &combos {
                let reachable = frontier.partition_point(|f| f.energy_wh <= e + 1e-9 * e.max(1.0));
                assert!(
                    reachable > 0,
                    "plan of energy {e} is cheaper than the frontier"
                );
                assert!(frontier[reachable - 1].utility >= u - 1e-9 * scale);
            }
            let min_e = combos.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
            let max_u = combos.iter().map(|c| c.1).fold(f64::NEG_INFINITY, f64::max);
            assert!(close(frontier[0].energy_wh, min_e, min_e));
            assert!(close(frontier.last().unwrap().utility, max_u, scale));
        }
    }

    #[test]
    fn hand_computed_single_task() {
        // 1 h at 100 W flight + 1 W base + task power 2 W or 6 W: 103 Wh or 107 Wh.
        let problem = PlanProblem {
            tasks: vec![task("detection", &[0.5, 1.0], 1.0)],
            phases: vec![phase(
                "tracking",
                3600.0,
                &[0],
                vec![term(&[0], &[2.0, 6.0])],
            )],
        };
        let plan = solve(&problem, 105.0).unwrap();
        assert!(plan.feasible);
        assert_eq!(plan.phases[0].levels, vec![TaskLevel { task: 0, level: 0 }]);
        assert!((plan.energy_wh - 103.0).abs() < 1e-12);
        assert_eq!(plan.utility, 0.5);
        assert_eq!(plan.phases[0].companion_power_w, 3.0);

        let plan = solve(&problem, 107.0).unwrap();
        assert_eq!(plan.phases[0].levels[0].level, 1);
        assert!((plan.energy_wh - 107.0).abs() < 1e-12);

        let plan = solve(&problem, 102.0).unwrap();
        assert!(!plan.feasible);
        assert!((plan.min_energy_wh - 103.0).abs() < 1e-12);
        assert_eq!(plan.energy_wh, plan.min_energy_wh);
        assert_eq!(plan.phases[0].levels[0].level, 0);
    }

    #[test]
    fn faster_landing_detection_can_save_energy() {
        // Level 0: 120 s at 305 W = 10.17 Wh; level 1 lands in 60 s at 320 W = 5.33 Wh.
        let mut landing = phase("landing", 0.0, &[0], vec![term(&[0], &[5.0, 20.0])]);
        landing.flight_power_w = 300.0;
        landing.base_power_w = 0.0;
        landing.duration_by_level = Some(DurationByLevel {
            task: 0,
            duration_s: vec![120.0, 60.0],
        });
        let problem = PlanProblem {
            tasks: vec![task("landing_marker", &[0.3, 0.9], 1.0)],
            phases: vec![landing],
        };
        let frontier = pareto_frontier(&problem).unwrap();
        assert_eq!(frontier.len(), 1, "the fast level dominates");
        let plan = solve(&problem, 6.0).unwrap();
        assert!(plan.feasible);
        assert_eq!(plan.phases[0].levels[0].level, 1);
        assert_eq!(plan.phases[0].duration_s, 60.0);
        assert!((plan.min_energy_wh - 60.0 * 320.0 / 3600.0).abs() < 1e-12);
    }

    #[test]
    fn free_task_runs_at_its_best_level_and_coupled_levels_decode() {
        // hazard × detection joint table (2 × 3, hazard slowest); tracking costs no power.
        let problem = PlanProblem {
            tasks: vec![
                task("hazard", &[0.2, 0.8], 1.0),
                task("detection", &[0.1, 0.5, 0.9], 1.0),
                task("tracking", &[0.4, 0.7, 0.7], 1.0),
            ],
            phases: vec![phase(
                "tracking",
                3600.0,
                &[2, 0, 1],
                vec![term(&[0, 1], &[1.0, 2.0, 3.0, 4.0, 50.0, 60.0])],
            )],
        };
        // Budget 101 + 4 Wh allows (hazard 0, detection 2) at 3 W or (1, 0) at 4 W: 0.2 + 0.9 wins.
        let plan = solve(&problem, 105.0).unwrap();
        assert_eq!(
            plan.phases[0].levels,
            vec![
                TaskLevel { task: 2, level: 2 },
                TaskLevel { task: 0, level: 0 },
                TaskLevel { task: 1, level: 2 },
            ]
        );
        assert!((plan.utility - (0.7 + 0.2 + 0.9)).abs() < 1e-12);
        assert_eq!(plan.phases[0].companion_power_w, 1.0 + 3.0);
    }

    #[test]
    fn equal_utility_prefers_less_energy() {
        // Levels 0 and 1 have the same utility; level 1 is cheaper. Level 2 does not fit.
        let problem = PlanProblem {
            tasks: vec![task("hazard", &[0.5, 0.5, 1.0], 1.0)],
            phases: vec![phase(
                "transit",
                3600.0,
                &[0],
                vec![term(&[0], &[3.0, 1.0, 10.0])],
            )],
        };
        let plan = solve(&problem, 105.0).unwrap();
        assert_eq!(plan.phases[0].levels[0].level, 1);
        assert!((plan.energy_wh - 102.0).abs() < 1e-12);
    }

    #[test]
    fn empty_problem_is_a_zero_plan() {
        let problem = PlanProblem {
            tasks: vec![],
            phases: vec![],
        };
        let plan = solve(&problem, 0.0).unwrap();
        assert!(plan.feasible);
        assert_eq!((plan.energy_wh, plan.utility), (0.0, 0.0));
        assert!(!solve(&problem, -1.0).unwrap().feasible);
    }

    /// The heap merge against the definition: every pairwise sum, then prune. Small integers
    /// make many exact ties in energy and in utility.
    #[test]
    fn minkowski_sum_equals_all_sums_pruned() {
        let mut rng = StdRng::seed_from_u64(0x5eed_0004);
        let random_frontier = |rng: &mut StdRng| {
            let n = rng.random_range(1..=6);
            let points = (0..n)
                .map(|i| Point {
                    energy_wh: f64::from(rng.random_range(0..6)),
                    utility: f64::from(rng.random_range(0..6)),
                    left: i,
                    right: 0,
                })
                .collect();
            prune(points, 0.0)
        };
        for _ in 0..2000 {
            let a = random_frontier(&mut rng);
            let b = random_frontier(&mut rng);
            let all = a
                .iter()
                .enumerate()
                .flat_map(|(i, x)| {
                    b.iter().enumerate().map(move |(j, y)| Point {
                        energy_wh: x.energy_wh + y.energy_wh,
                        utility: x.utility + y.utility,
                        left: i,
                        right: j,
                    })
                })
                .collect();
            let expected: Vec<(f64, f64)> = prune(all, 0.0)
                .iter()
                .map(|p| (p.energy_wh, p.utility))
                .collect();
            let merged = minkowski_sum(&a, &b, 0.0);
            let got: Vec<(f64, f64)> = merged.iter().map(|p| (p.energy_wh, p.utility)).collect();
            assert_eq!(got, expected, "a {a:?} b {b:?}");
            for p in &merged {
                assert_eq!(p.energy_wh, a[p.left].energy_wh + b[p.right].energy_wh);
                assert_eq!(p.utility, a[p.left].utility + b[p.right].utility);
            }
        }
    }

    #[test]
    fn bad_problems_give_named_errors() {
        let good = PlanProblem {
            tasks: vec![task("a", &[0.2, 0.8], 1.0), task("b", &[0.5, 1.0], 1.0)],
            phases: vec![phase(
                "p",
                60.0,
                &[0, 1],
                vec![term(&[0, 1], &[1.0, 2.0, 3.0, 4.0])],
            )],
        };
        assert!(solve(&good, 10.0).is_ok());
        let with = |edit: &dyn Fn(&mut PlanProblem)| {
            let mut p = good.clone();
            edit(&mut p);
            solve(&p, 10.0).unwrap_err()
        };
        assert!(matches!(
            with(&|p| p.tasks[0].utility.clear()),
            PlanError::NoLevels { .. }
        ));
        assert!(matches!(
            with(&|p| p.tasks[0].utility[1] = f64::NAN),
            PlanError::BadUtility { level: 1, .. }
        ));
        assert!(matches!(
            with(&|p| p.tasks[0].utility[0] = 1.5),
            PlanError::BadUtility { .. }
        ));
        assert!(matches!(
            with(&|p| p.tasks[1].weight = -1.0),
            PlanError::BadWeight { .. }
        ));
        assert!(matches!(
            with(&|p| p.tasks[1].weight = f64::INFINITY),
            PlanError::BadWeight { .. }
        ));
        assert!(matches!(
            with(&|p| p.phases[0].duration_s = -5.0),
            PlanError::BadPhaseValue { ref what, .. } if what == "duration_s"
        ));
        assert!(matches!(
            with(&|p| p.phases[0].flight_power_w = f64::NAN),
            PlanError::BadPhaseValue { ref what, .. } if what == "flight_power_w"
        ));
        assert!(matches!(
            with(&|p| p.phases[0].terms[0].power_w[2] = -1.0),
            PlanError::BadPhaseValue { ref what, .. } if what == "power_w[2] of term 0"
        ));
        assert!(matches!(
            with(&|p| p.phases[0].active_tasks.push(7)),
            PlanError::UnknownTask {
                task: 7,
                task_count: 2,
                ..
            }
        ));
        assert!(matches!(
            with(&|p| p.phases[0].active_tasks.push(0)),
            PlanError::DuplicateActiveTask { .. }
        ));
        assert!(matches!(
            with(&|p| p.phases[0].terms.push(term(&[], &[1.0]))),
            PlanError::EmptyTerm { term: 1, .. }
        ));
        assert!(matches!(
            with(&|p| p.phases[0].terms[0] = term(&[0, 0], &[1.0; 4])),
            PlanError::DuplicateTermTask { .. }
        ));
        assert!(matches!(
            with(&|p| p.phases[0].active_tasks = vec![0]),
            PlanError::TermTaskNotActive { .. }
        ));
        assert!(matches!(
            with(&|p| p.phases[0].terms.push(term(&[1], &[1.0, 2.0]))),
            PlanError::OverlappingTerms {
                first: 0,
                second: 1,
                ..
            }
        ));
        assert!(matches!(
            with(&|p| p.phases[0].terms[0].power_w.pop().map(|_| ()).unwrap_or(())),
            PlanError::TermTableSize {
                expected: 4,
                found: 3,
                ..
            }
        ));
        assert!(matches!(
            with(&|p| {
                p.phases[0].duration_by_level = Some(DurationByLevel {
                    task: 1,
                    duration_s: vec![10.0],
                })
            }),
            PlanError::DurationTableSize {
                expected: 2,
                found: 1,
                ..
            }
        ));
        assert!(matches!(
            with(&|p| {
                p.phases[0].duration_by_level = Some(DurationByLevel {
                    task: 1,
                    duration_s: vec![10.0, -1.0],
                })
            }),
            PlanError::BadPhaseValue { .. }
        ));
        assert!(matches!(
            with(&|p| {
                p.phases[0].terms.clear();
                p.phases[0].active_tasks = vec![0];
                p.phases[0].duration_by_level = Some(DurationByLevel {
                    task: 1,
                    duration_s: vec![10.0, 20.0],
                })
            }),
            PlanError::DurationTaskNotActive { .. }
        ));
        assert!(matches!(
            with(&|p| {
                p.phases[0].flight_power_w = f64::MAX;
                p.phases[0].base_power_w = f64::MAX;
            }),
            PlanError::Overflow { what: "energy" }
        ));
        assert!(matches!(
            solve(&good, f64::NAN),
            Err(PlanError::BadBudget { .. })
        ));
        // Messages name the thing to fix.
        let message = with(&|p| p.phases[0].terms[0].power_w.truncate(3)).to_string();
        assert!(
            message.contains("phase `p`") && message.contains("power term 0"),
            "{message}"
        );
    }
}
