//! What the planner accepts: every check, each failing with an error that names the thing.

use super::{DurationByLevel, PlanError, PlanPhase, PlanProblem, PowerTerm, SECONDS_PER_HOUR};

/// Checks the problem; returns the largest attainable utility (the scale of the tie tolerance).
pub(super) fn validate(problem: &PlanProblem) -> Result<f64, PlanError> {
    validate_tasks(problem)?;
    let mut max_utility = 0.0;
    let mut max_energy_wh = 0.0;
    for phase in &problem.phases {
        max_energy_wh += validate_phase(problem, phase, &mut max_utility)?;
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

/// Every task has levels, utilities in [0, 1] and a finite, non-negative weight.
fn validate_tasks(problem: &PlanProblem) -> Result<(), PlanError> {
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
        if let Some(range) = task.allowed_levels {
            if !range.fits(task.utility.len()) {
                return Err(PlanError::BadLevelRange {
                    task: task.name.clone(),
                    min: range.min,
                    max: range.max,
                    count: task.utility.len(),
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
    Ok(())
}

/// Checks one phase; adds its active tasks' best utility to `max_utility` and returns its
/// largest energy (Wh), the bound used to detect an overflowing sum.
fn validate_phase(
    problem: &PlanProblem,
    phase: &PlanPhase,
    max_utility: &mut f64,
) -> Result<f64, PlanError> {
    let mut max_duration_s = non_negative(phase, "duration_s", phase.duration_s)?;
    let mut max_power_w = non_negative(phase, "flight_power_w", phase.flight_power_w)?;
    max_power_w += non_negative(phase, "base_power_w", phase.base_power_w)?;

    let active = validate_active_tasks(problem, phase, max_utility)?;

    // Each task is in at most one term: the first term that named it.
    let mut covered_by: Vec<Option<usize>> = vec![None; problem.tasks.len()];
    for (term_index, term) in phase.terms.iter().enumerate() {
        max_power_w +=
            validate_term_max_power_w(problem, phase, &active, &mut covered_by, term_index, term)?;
    }

    if let Some(by_level) = &phase.duration_by_level {
        max_duration_s = validate_duration_by_level_max_s(problem, phase, by_level, &active)?;
    }
    Ok(max_duration_s * max_power_w / SECONDS_PER_HOUR)
}

/// The phase's active tasks are known and listed once; adds each one's best weighted utility
/// to `max_utility`. Returns which tasks are active, by task index.
fn validate_active_tasks(
    problem: &PlanProblem,
    phase: &PlanPhase,
    max_utility: &mut f64,
) -> Result<Vec<bool>, PlanError> {
    let mut active = vec![false; problem.tasks.len()];
    for &task in &phase.active_tasks {
        known_task(problem, phase, task)?;
        if active[task] {
            return Err(PlanError::DuplicateActiveTask {
                phase: phase.name.clone(),
                task: task_name(problem, task),
            });
        }
        active[task] = true;
        let t = &problem.tasks[task];
        *max_utility += t.weight * t.utility.iter().copied().fold(0.0, f64::max);
    }
    Ok(active)
}

/// Checks one power term (its tasks active and in no other term, its table one power per
/// combination of their levels, every power finite and non-negative); returns its largest
/// power (W).
fn validate_term_max_power_w(
    problem: &PlanProblem,
    phase: &PlanPhase,
    active: &[bool],
    covered_by: &mut [Option<usize>],
    term_index: usize,
    term: &PowerTerm,
) -> Result<f64, PlanError> {
    if term.tasks.is_empty() {
        return Err(PlanError::EmptyTerm {
            phase: phase.name.clone(),
            term: term_index,
        });
    }
    let mut combinations: usize = 1;
    for &task in &term.tasks {
        known_task(problem, phase, task)?;
        if !active[task] {
            return Err(PlanError::TermTaskNotActive {
                phase: phase.name.clone(),
                term: term_index,
                task: task_name(problem, task),
            });
        }
        match covered_by[task] {
            Some(first) if first == term_index => {
                return Err(PlanError::DuplicateTermTask {
                    phase: phase.name.clone(),
                    term: term_index,
                    task: task_name(problem, task),
                })
            }
            Some(first) => {
                return Err(PlanError::OverlappingTerms {
                    phase: phase.name.clone(),
                    task: task_name(problem, task),
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
        term_max_w = term_max_w.max(non_negative(
            phase,
            &format!("power_w[{i}] of term {term_index}"),
            p,
        )?);
    }
    Ok(term_max_w)
}

/// Checks the durations by level (an active task's, one per level, each finite and
/// non-negative); returns the longest (s).
fn validate_duration_by_level_max_s(
    problem: &PlanProblem,
    phase: &PlanPhase,
    by_level: &DurationByLevel,
    active: &[bool],
) -> Result<f64, PlanError> {
    known_task(problem, phase, by_level.task)?;
    if !active[by_level.task] {
        return Err(PlanError::DurationTaskNotActive {
            phase: phase.name.clone(),
            task: task_name(problem, by_level.task),
        });
    }
    let expected = problem.tasks[by_level.task].utility.len();
    if by_level.duration_s.len() != expected {
        return Err(PlanError::DurationTableSize {
            phase: phase.name.clone(),
            task: task_name(problem, by_level.task),
            expected,
            found: by_level.duration_s.len(),
        });
    }
    let mut max_duration_s: f64 = 0.0;
    for (level, &d) in by_level.duration_s.iter().enumerate() {
        let d = non_negative(phase, &format!("duration_by_level.duration_s[{level}]"), d)?;
        max_duration_s = max_duration_s.max(d);
    }
    Ok(max_duration_s)
}

/// `value` when finite and non-negative, else the phase's error naming `what`.
fn non_negative(phase: &PlanPhase, what: &str, value: f64) -> Result<f64, PlanError> {
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err(PlanError::BadPhaseValue {
            phase: phase.name.clone(),
            what: what.to_string(),
            value,
        })
    }
}

/// `task` when the problem has it, else the phase's error.
fn known_task(problem: &PlanProblem, phase: &PlanPhase, task: usize) -> Result<usize, PlanError> {
    let task_count = problem.tasks.len();
    if task < task_count {
        Ok(task)
    } else {
        Err(PlanError::UnknownTask {
            phase: phase.name.clone(),
            task,
            task_count,
        })
    }
}

fn task_name(problem: &PlanProblem, task: usize) -> String {
    problem.tasks[task].name.clone()
}
