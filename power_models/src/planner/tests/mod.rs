use super::*;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};

mod exact;

fn task(name: &str, utility: &[f64], weight: f64) -> PlanTask {
    PlanTask {
        name: name.to_string(),
        utility: utility.to_vec(),
        weight,
        allowed_levels: None,
    }
}

fn phase(name: &str, duration_s: f64, active_tasks: &[usize], terms: Vec<PowerTerm>) -> PlanPhase {
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
        let allowed = slots
            .iter()
            .all(|&(p, t)| match problem.tasks[t].allowed_levels {
                Some(range) => (range.min..=range.max).contains(&levels[p][t]),
                None => true,
            });
        if allowed {
            out.push(evaluate(problem, &levels));
        }
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
                    allowed_levels: None,
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
                    let cells: usize = members.iter().map(|&t| tasks[t].utility.len()).product();
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
fn bounded_levels_are_the_only_ones_chosen_and_the_best_among_them() {
    let mut rng = StdRng::seed_from_u64(0x5eed_0042);
    let mut narrowed = 0;
    for _ in 0..300 {
        let mut problem = random_problem(&mut rng);
        for task in &mut problem.tasks {
            let count = task.utility.len();
            if count > 1 && rng.random_bool(0.6) {
                let min = rng.random_range(0..count);
                let max = rng.random_range(min..count);
                task.allowed_levels = Some(LevelRange { min, max });
                narrowed += usize::from(max - min + 1 < count);
            }
        }
        let combos = brute_force(&problem);
        let scale = utility_scale(&problem);
        let min_e = combos.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
        let max_e = combos.iter().map(|c| c.0).fold(0.0, f64::max);
        for budget_wh in [
            min_e - 1.0,
            rng.random_range(min_e..=max_e) * (1.0 + 1e-9),
            max_e + 1.0,
        ] {
            let plan = solve(&problem, budget_wh).unwrap();
            assert!(close(plan.min_energy_wh, min_e, min_e), "cheapest allowed");
            for phase in &plan.phases {
                for level in &phase.levels {
                    assert!(
                        problem.tasks[level.task].allows(level.level),
                        "task {} at level {} outside {:?}",
                        level.task,
                        level.level,
                        problem.tasks[level.task].allowed_levels
                    );
                }
            }
            let best = combos
                .iter()
                .filter(|c| c.0 <= budget_wh)
                .map(|c| c.1)
                .fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(plan.feasible, best > f64::NEG_INFINITY);
            if plan.feasible {
                assert!(
                    close(plan.utility, best, scale),
                    "{} vs {best}",
                    plan.utility
                );
            }
        }
    }
    assert!(narrowed > 100, "{narrowed} tasks narrowed");
}

#[test]
fn allowed_levels_outside_a_task_are_named() {
    let mut problem = random_problem(&mut StdRng::seed_from_u64(3));
    let count = problem.tasks[0].utility.len();
    problem.tasks[0].allowed_levels = Some(LevelRange { min: 0, max: count });
    let error = solve(&problem, 100.0).unwrap_err();
    assert!(matches!(error, PlanError::BadLevelRange { .. }), "{error}");
    assert!(
        error.to_string().contains(&format!("0..={}", count - 1)),
        "{error}"
    );
    problem.tasks[0].allowed_levels = Some(LevelRange { min: 1, max: 0 });
    assert!(matches!(
        solve(&problem, 100.0),
        Err(PlanError::BadLevelRange { .. })
    ));
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
