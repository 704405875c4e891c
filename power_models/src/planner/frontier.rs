//! The exact method: Pareto frontiers of terms, phases and the mission, their pruned sums, and
//! the back-pointers that recover every task's level (see the planner's module documentation).

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use super::validate::validate;
use super::{
    LevelRange, PhasePlan, PlanError, PlanPhase, PlanProblem, PlanTask, PowerTerm, TaskLevel,
    SECONDS_PER_HOUR, TIE_TOLERANCE,
};

/// A frontier point with a back-pointer pair, whose meaning depends on the frontier it is in.
#[derive(Debug, Clone, Copy)]
pub(super) struct Point {
    pub(super) energy_wh: f64,
    pub(super) utility: f64,
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

pub(super) struct Frontiers {
    phases: Vec<PhaseFrontier>,
    /// `steps[0]` is the empty mission; `steps[p + 1]` is the sum of `steps[p]` (via `left`) and
    /// phase `p`'s frontier (via `right`).
    steps: Vec<Vec<Point>>,
}

impl Frontiers {
    pub(super) fn build(problem: &PlanProblem) -> Result<Self, PlanError> {
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

    pub(super) fn mission(&self) -> &[Point] {
        &self.steps[self.steps.len() - 1]
    }

    /// Follows the back-pointers of mission point `index` down to every task's level.
    pub(super) fn phase_plans(&self, problem: &PlanProblem, index: usize) -> Vec<PhasePlan> {
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
            level: best_level(&problem.tasks[task]),
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
            .filter(|(level, _)| problem.tasks[by_level.task].allows(*level))
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
            let allowed = term
                .tasks
                .iter()
                .zip(&levels)
                .all(|(&task, &level)| problem.tasks[task].allows(level));
            if !allowed {
                return None;
            }
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

/// The allowed level with the highest utility; on a tie the higher level (the higher QoS).
fn best_level(task: &PlanTask) -> usize {
    let range = task.allowed_levels.unwrap_or(LevelRange {
        min: 0,
        max: task.utility.len() - 1,
    });
    let mut best = range.min;
    for level in range.min..=range.max {
        if task.utility[level] >= task.utility[best] {
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

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
}
