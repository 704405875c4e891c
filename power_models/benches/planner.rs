//! Planner time: the reference size (6 tasks × 8 levels × 3 phases, goal < 10 ms), growth from 2
//! to 12 tasks, and a brute-force baseline where enumerating every plan is still tractable.
//!
//! Run: `cargo bench -p power_models --bench planner`. Tables are random with a fixed seed, shaped
//! like profiles: utility and power rise with the level; coupled pairs (a 2-task joint power
//! model) alternate with single-task terms; the landing phase lands sooner at higher levels of
//! task 0. The mission Pareto frontier size is printed for each size, since planner time follows
//! it.
//!
//! Measured (2-core shared x86 VM, release): 6×8×3 solve 0.83 ms, pareto_frontier 1.3 ms; solve
//! for 2, 3, 4, 6, 8, 10, 12 tasks: 29 µs, 78 µs, 176 µs, 0.84 ms, 1.1 ms, 3.5 ms, 6.8 ms
//! (frontiers 34, 115, 216, 905, 814, 2 878, 3 232 points). Brute force: 0.65 ms for 2 tasks
//! (23× the planner), 333 ms for 3 tasks (4 250×); 4 tasks would be 6.9e10 plans.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use power_models::planner::{
    pareto_frontier, solve, DurationByLevel, PlanPhase, PlanProblem, PlanTask, PowerTerm,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const LEVELS: usize = 8;

/// Rising per-level power (W) of one task.
fn task_power_w(rng: &mut StdRng) -> Vec<f64> {
    let mut p = rng.random_range(0.5..2.0);
    (0..LEVELS)
        .map(|_| {
            p += rng.random_range(0.2..1.5);
            p
        })
        .collect()
}

fn mission(task_count: usize, seed: u64) -> PlanProblem {
    let mut rng = StdRng::seed_from_u64(seed);
    let tasks: Vec<PlanTask> = (0..task_count)
        .map(|i| {
            // Non-decreasing, ends at 1.
            let steps: Vec<f64> = (0..LEVELS).map(|_| rng.random_range(0.0..1.0)).collect();
            let total: f64 = steps.iter().sum();
            let mut u = 0.0;
            PlanTask {
                name: format!("task{i}"),
                utility: steps
                    .iter()
                    .map(|s| {
                        u += s / total;
                        u.min(1.0)
                    })
                    .collect(),
                weight: rng.random_range(0.5..2.0),
                allowed_levels: None,
            }
        })
        .collect();

    // Groups of 2 (coupled) and 1 task, alternating.
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut next = 0;
    while next < task_count {
        let size = if groups.len().is_multiple_of(2) && next + 1 < task_count {
            2
        } else {
            1
        };
        groups.push((next..next + size).collect());
        next += size;
    }
    let terms: Vec<PowerTerm> = groups
        .iter()
        .map(|g| {
            let power: Vec<Vec<f64>> = g.iter().map(|_| task_power_w(&mut rng)).collect();
            let power_w = if g.len() == 1 {
                power[0].clone()
            } else {
                // Joint model: sum plus a contention term growing with both levels.
                let contention_w = rng.random_range(0.5..3.0);
                (0..LEVELS * LEVELS)
                    .map(|i| {
                        let (a, b) = (i / LEVELS, i % LEVELS);
                        power[0][a]
                            + power[1][b]
                            + contention_w * (a * b) as f64 / (LEVELS * LEVELS) as f64
                    })
                    .collect()
            };
            PowerTerm {
                tasks: g.clone(),
                power_w,
            }
        })
        .collect();

    let all: Vec<usize> = (0..task_count).collect();
    // In transit the last group has no power term: its tasks run free.
    let transit_terms = terms[..terms.len() - 1].to_vec();
    PlanProblem {
        tasks,
        phases: vec![
            PlanPhase {
                name: "transit".into(),
                duration_s: 600.0,
                duration_by_level: None,
                flight_power_w: 180.0,
                base_power_w: 4.0,
                active_tasks: all.clone(),
                terms: transit_terms,
            },
            PlanPhase {
                name: "tracking".into(),
                duration_s: 900.0,
                duration_by_level: None,
                flight_power_w: 170.0,
                base_power_w: 4.0,
                active_tasks: all.clone(),
                terms: terms.clone(),
            },
            PlanPhase {
                name: "landing".into(),
                duration_s: 0.0,
                duration_by_level: Some(DurationByLevel {
                    task: 0,
                    duration_s: (0..LEVELS).map(|l| 120.0 - 8.0 * l as f64).collect(),
                }),
                flight_power_w: 200.0,
                base_power_w: 4.0,
                active_tasks: all,
                terms,
            },
        ],
    }
}

/// A budget 60 % of the way from the cheapest plan to the best one.
fn budget_wh(problem: &PlanProblem) -> f64 {
    let frontier = pareto_frontier(problem).expect("valid problem");
    let (low, high) = (
        frontier[0].energy_wh,
        frontier[frontier.len() - 1].energy_wh,
    );
    low + 0.6 * (high - low)
}

/// Every plan enumerated: each phase's level combinations evaluated, then every combination of
/// phases. Returns the best utility within the budget (lower energy on ties).
fn brute_force(problem: &PlanProblem, budget_wh: f64) -> f64 {
    let per_phase: Vec<Vec<(f64, f64)>> = problem
        .phases
        .iter()
        .map(|phase| {
            let tasks = &phase.active_tasks;
            let count = LEVELS.pow(tasks.len() as u32);
            let mut levels = vec![0; problem.tasks.len()];
            (0..count)
                .map(|mut c| {
                    for &t in tasks.iter().rev() {
                        levels[t] = c % LEVELS;
                        c /= LEVELS;
                    }
                    let duration_s = match &phase.duration_by_level {
                        Some(d) => d.duration_s[levels[d.task]],
                        None => phase.duration_s,
                    };
                    let mut power_w = phase.flight_power_w + phase.base_power_w;
                    for term in &phase.terms {
                        let index = term.tasks.iter().fold(0, |i, &t| i * LEVELS + levels[t]);
                        power_w += term.power_w[index];
                    }
                    let utility: f64 = tasks
                        .iter()
                        .map(|&t| problem.tasks[t].weight * problem.tasks[t].utility[levels[t]])
                        .sum();
                    (duration_s * power_w / 3600.0, utility)
                })
                .collect()
        })
        .collect();
    let mut best = (f64::NEG_INFINITY, f64::INFINITY);
    let mut pick = vec![0; per_phase.len()];
    loop {
        let (mut e, mut u) = (0.0, 0.0);
        for (options, &i) in per_phase.iter().zip(&pick) {
            e += options[i].0;
            u += options[i].1;
        }
        if e <= budget_wh && (u > best.0 || (u == best.0 && e < best.1)) {
            best = (u, e);
        }
        let mut k = 0;
        loop {
            if k == pick.len() {
                return best.0;
            }
            pick[k] += 1;
            if pick[k] < per_phase[k].len() {
                break;
            }
            pick[k] = 0;
            k += 1;
        }
    }
}

fn reference_size(c: &mut Criterion) {
    let problem = mission(6, 6);
    let budget = budget_wh(&problem);
    let mut group = c.benchmark_group("planner/6x8x3");
    group
        .sample_size(30)
        .measurement_time(Duration::from_secs(3));
    group.bench_function("solve", |b| b.iter(|| solve(black_box(&problem), budget)));
    group.bench_function("pareto_frontier", |b| {
        b.iter(|| pareto_frontier(black_box(&problem)))
    });
    group.finish();
}

fn growth(c: &mut Criterion) {
    let mut group = c.benchmark_group("planner/growth");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(3));
    for n in [2, 3, 4, 6, 8, 10, 12] {
        let problem = mission(n, n as u64);
        let budget = budget_wh(&problem);
        let frontier = pareto_frontier(&problem).expect("valid problem");
        let plans: f64 = (LEVELS as f64).powi(3 * n as i32);
        eprintln!(
            "{n} tasks: mission frontier {} points, {plans:.3e} plans",
            frontier.len()
        );
        let plan = solve(&problem, budget).expect("valid problem");
        if n <= 3 {
            // The baseline must agree before its time means anything.
            let brute = brute_force(&problem, budget);
            assert!(
                (brute - plan.utility).abs() < 1e-9,
                "{brute} vs {}",
                plan.utility
            );
            group.bench_with_input(BenchmarkId::new("brute_force", n), &problem, |b, p| {
                b.iter(|| brute_force(black_box(p), budget))
            });
        }
        group.bench_with_input(BenchmarkId::new("solve", n), &problem, |b, p| {
            b.iter(|| solve(black_box(p), budget))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_millis(500));
    targets = reference_size, growth
}
criterion_main!(benches);
