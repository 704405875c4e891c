//! What the planner accepts: every check, each failing with an error that names the thing.

use super::{PlanError, PlanProblem, SECONDS_PER_HOUR};

/// Checks the problem; returns the largest attainable utility (the scale of the tie tolerance).
pub(super) fn validate(problem: &PlanProblem) -> Result<f64, PlanError> {
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
