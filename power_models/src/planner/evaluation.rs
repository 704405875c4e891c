//! What given levels cost and earn on a [`PlanProblem`], and the layout of a power term's
//! table: the one evaluation the planner, the governor, the dry run and the simulator share.

use super::{PlanPhase, PlanProblem, PlanTask, PowerTerm, TaskLevel, SECONDS_PER_HOUR};

/// Cost and worth of one set of levels per phase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evaluation {
    pub energy_wh: f64,
    pub utility: f64,
    pub duration_s: f64,
}

impl Evaluation {
    /// Mean power over the levels' duration; `fallback_w` when they last no time.
    pub fn mean_power_w(&self, fallback_w: f64) -> f64 {
        if self.duration_s > 0.0 {
            self.energy_wh * SECONDS_PER_HOUR / self.duration_s
        } else {
            fallback_w
        }
    }
}

/// The level `levels` give `task`; None when it has none.
pub fn level_of(levels: &[TaskLevel], task: usize) -> Option<usize> {
    levels.iter().find(|l| l.task == task).map(|l| l.level)
}

impl PowerTerm {
    /// The index into [`PowerTerm::power_w`] of the levels `levels` give the term's tasks
    /// (row-major, first task slowest); None when one is missing or out of range.
    pub fn index_of(&self, tasks: &[PlanTask], levels: &[TaskLevel]) -> Option<usize> {
        let mut index = 0;
        for &task in &self.tasks {
            let count = tasks.get(task)?.utility.len();
            let level = level_of(levels, task).filter(|&l| l < count)?;
            index = index * count + level;
        }
        Some(index)
    }

    /// The levels of the term's tasks, in the term's order, at table index `index`: the
    /// inverse of [`PowerTerm::index_of`].
    pub fn levels_at(&self, tasks: &[PlanTask], mut index: usize) -> Vec<usize> {
        let mut levels = vec![0; self.tasks.len()];
        for (slot, &task) in self.tasks.iter().enumerate().rev() {
            let count = tasks[task].utility.len();
            levels[slot] = index % count;
            index /= count;
        }
        levels
    }
}

impl PlanProblem {
    /// The modelled power of phase `phase` at `levels`: flight + base + every term; None when
    /// the phase does not exist or a term's task has no level in range.
    pub fn phase_power_w(&self, phase: usize, levels: &[TaskLevel]) -> Option<f64> {
        self.power_w(self.phases.get(phase)?, levels)
    }

    /// The companion computer's modelled power in phase `phase` at `levels` (base plus every
    /// term; flight excluded): what a simulator drains the pack with for the levels it runs.
    pub fn companion_power_w(&self, phase: usize, levels: &[TaskLevel]) -> Option<f64> {
        // Taken off the phase's power rather than summed apart: the same bits the simulator's
        // figures were made with.
        Some(self.phase_power_w(phase, levels)? - self.phases.get(phase)?.flight_power_w)
    }

    /// How long phase `phase` lasts at `levels`; None when the phase does not exist or its
    /// duration task has no level in range.
    pub fn phase_duration_s(&self, phase: usize, levels: &[TaskLevel]) -> Option<f64> {
        duration_s(self.phases.get(phase)?, levels)
    }

    /// Energy, utility and duration of `levels`, one list per phase; None when the lists do not
    /// match the phases or a level is missing or out of range.
    pub fn evaluate(&self, levels: &[Vec<TaskLevel>]) -> Option<Evaluation> {
        if levels.len() != self.phases.len() {
            return None;
        }
        let mut evaluation = Evaluation {
            energy_wh: 0.0,
            utility: 0.0,
            duration_s: 0.0,
        };
        for (phase, phase_levels) in self.phases.iter().zip(levels) {
            let duration_s = duration_s(phase, phase_levels)?;
            evaluation.energy_wh +=
                self.power_w(phase, phase_levels)? * duration_s / SECONDS_PER_HOUR;
            evaluation.duration_s += duration_s;
            for level in phase_levels {
                let task = self.tasks.get(level.task)?;
                evaluation.utility += task.weight * task.utility.get(level.level)?;
            }
        }
        Some(evaluation)
    }

    fn power_w(&self, phase: &PlanPhase, levels: &[TaskLevel]) -> Option<f64> {
        let mut power_w = phase.flight_power_w + phase.base_power_w;
        for term in &phase.terms {
            power_w += term.power_w.get(term.index_of(&self.tasks, levels)?)?;
        }
        Some(power_w)
    }
}

fn duration_s(phase: &PlanPhase, levels: &[TaskLevel]) -> Option<f64> {
    match &phase.duration_by_level {
        Some(by_level) => by_level
            .duration_s
            .get(level_of(levels, by_level.task)?)
            .copied(),
        None => Some(phase.duration_s),
    }
}

#[cfg(test)]
mod tests {
    use super::super::DurationByLevel;
    use super::*;

    fn level(task: usize, level: usize) -> TaskLevel {
        TaskLevel { task, level }
    }

    /// Survey: tasks a (2 levels) and b (3 levels) share a joint table, a slowest. Landing: c
    /// alone, and it lands in 1800 s or 900 s by its level.
    fn problem() -> PlanProblem {
        let task = |name: &str, utility: &[f64], weight: f64| PlanTask {
            name: name.into(),
            utility: utility.to_vec(),
            weight,
            allowed_levels: None,
        };
        PlanProblem {
            tasks: vec![
                task("a", &[0.25, 0.75], 1.0),
                task("b", &[0.125, 0.5, 1.0], 2.0),
                task("c", &[0.5, 1.0], 0.5),
            ],
            phases: vec![
                PlanPhase {
                    name: "survey".into(),
                    duration_s: 3600.0,
                    duration_by_level: None,
                    flight_power_w: 100.0,
                    base_power_w: 2.0,
                    active_tasks: vec![0, 1],
                    terms: vec![PowerTerm {
                        tasks: vec![0, 1],
                        power_w: vec![1.0, 2.0, 3.0, 10.0, 20.0, 30.0],
                    }],
                },
                PlanPhase {
                    name: "landing".into(),
                    duration_s: 0.0,
                    duration_by_level: Some(DurationByLevel {
                        task: 2,
                        duration_s: vec![1800.0, 900.0],
                    }),
                    flight_power_w: 200.0,
                    base_power_w: 0.0,
                    active_tasks: vec![2],
                    terms: vec![PowerTerm {
                        tasks: vec![2],
                        power_w: vec![4.0, 8.0],
                    }],
                },
            ],
        }
    }

    #[test]
    fn a_joint_table_is_row_major_with_the_first_task_slowest() {
        let problem = problem();
        let term = &problem.phases[0].terms[0];
        // (a, b) = (1, 0) is row 1, column 0 of a 2 × 3 table.
        assert_eq!(
            term.index_of(&problem.tasks, &[level(1, 0), level(0, 1)]),
            Some(3)
        );
        assert_eq!(term.levels_at(&problem.tasks, 3), vec![1, 0]);
        assert_eq!(term.levels_at(&problem.tasks, 5), vec![1, 2]);
        // Listed the other way round, b is slowest: (b, a) = (2, 0) is 2 × 2 + 0.
        let swapped = PowerTerm {
            tasks: vec![1, 0],
            power_w: vec![0.0; 6],
        };
        assert_eq!(
            swapped.index_of(&problem.tasks, &[level(0, 0), level(1, 2)]),
            Some(4)
        );
        assert_eq!(swapped.levels_at(&problem.tasks, 4), vec![2, 0]);
        for index in 0..6 {
            let levels: Vec<TaskLevel> = term
                .levels_at(&problem.tasks, index)
                .into_iter()
                .zip(&term.tasks)
                .map(|(l, &t)| level(t, l))
                .collect();
            assert_eq!(term.index_of(&problem.tasks, &levels), Some(index));
        }
    }

    #[test]
    fn powers_energy_and_utility_by_hand() {
        let problem = problem();
        let survey = [level(0, 1), level(1, 2)];
        let landing = [level(2, 1)];
        // 100 W flight + 2 W base + table cell (1, 2) = 30 W.
        assert_eq!(problem.phase_power_w(0, &survey), Some(132.0));
        assert_eq!(problem.companion_power_w(0, &survey), Some(32.0));
        assert_eq!(problem.phase_duration_s(0, &survey), Some(3600.0));
        // 200 W + 8 W for the 900 s the fast level takes.
        assert_eq!(problem.phase_power_w(1, &landing), Some(208.0));
        assert_eq!(problem.companion_power_w(1, &landing), Some(8.0));
        assert_eq!(problem.phase_duration_s(1, &landing), Some(900.0));

        let evaluation = problem
            .evaluate(&[survey.to_vec(), landing.to_vec()])
            .unwrap();
        // 132 W for 1 h + 208 W for 1/4 h = 132 + 52 Wh.
        assert_eq!(evaluation.energy_wh, 184.0);
        // 1 × 0.75 + 2 × 1 + 0.5 × 1.
        assert_eq!(evaluation.utility, 3.25);
        assert_eq!(evaluation.duration_s, 4500.0);
        // 184 Wh over 1.25 h.
        assert_eq!(evaluation.mean_power_w(0.0), 147.2);

        // The lowest levels: 103 W for 1 h + 204 W for 1/2 h.
        let lowest = problem
            .evaluate(&[vec![level(0, 0), level(1, 0)], vec![level(2, 0)]])
            .unwrap();
        assert_eq!(lowest.energy_wh, 205.0);
        assert_eq!(lowest.utility, 0.25 + 0.25 + 0.25);
        assert_eq!(lowest.duration_s, 5400.0);
    }

    #[test]
    fn levels_that_do_not_fit_the_problem_evaluate_to_none() {
        let problem = problem();
        let survey = vec![level(0, 1), level(1, 2)];
        let landing = vec![level(2, 1)];
        // A term's task without a level, or with one past its last.
        assert_eq!(problem.phase_power_w(0, &[level(0, 1)]), None);
        assert_eq!(problem.phase_power_w(0, &[level(0, 2), level(1, 0)]), None);
        // No such phase.
        assert_eq!(problem.phase_power_w(2, &survey), None);
        assert_eq!(problem.companion_power_w(2, &survey), None);
        assert_eq!(problem.phase_duration_s(2, &survey), None);
        // The duration task without a level.
        assert_eq!(problem.phase_duration_s(1, &[]), None);
        // One list per phase, no more, no fewer.
        assert_eq!(problem.evaluate(std::slice::from_ref(&survey)), None);
        assert_eq!(
            problem.evaluate(&[survey.clone(), landing.clone(), landing.clone()]),
            None
        );
        // A level past a task's utilities, or a task that does not exist.
        assert_eq!(problem.evaluate(&[survey.clone(), vec![level(2, 2)]]), None);
        assert_eq!(
            problem.evaluate(&[survey.clone(), vec![level(2, 1), level(7, 0)]]),
            None
        );
        assert!(problem.evaluate(&[survey, landing]).is_some());
    }

    #[test]
    fn levels_that_last_no_time_have_the_fallback_mean_power() {
        let evaluation = Evaluation {
            energy_wh: 0.0,
            utility: 1.0,
            duration_s: 0.0,
        };
        assert_eq!(evaluation.mean_power_w(42.0), 42.0);
    }
}
