//! The planner against brute force on small random problems: the same best utility in every
//! budget, never less for more budget, and the exact Pareto frontier.

use super::*;

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
