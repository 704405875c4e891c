use super::*;

// ---- planning arithmetic ------------------------------------------------------------------

#[test]
fn the_rest_of_the_mission_is_shortened_and_corrected() {
    let mut governor = survey_governor(60.0, EstimatorConfig::default(), GovernorConfig::default());
    governor.progress = MissionProgress::new(1, 300.0);
    let rest = governor.remaining_problem(1.1);
    assert_eq!(rest.phases.len(), 2);
    assert_eq!(rest.phases[0].name, "survey");
    assert_eq!(rest.phases[0].duration_s, 600.0);
    assert!((rest.phases[0].flight_power_w - 132.0).abs() < 1e-12);
    assert!((rest.phases[0].base_power_w - 8.8).abs() < 1e-12);
    assert!((rest.phases[0].terms[0].power_w[0] - 3.3).abs() < 1e-12);
    // The landing is whole.
    assert_eq!(
        rest.phases[1]
            .duration_by_level
            .as_ref()
            .unwrap()
            .duration_s,
        vec![100.0, 85.0, 70.0, 60.0]
    );

    // 75 s into the landing, each level has its own time left, none below zero.
    governor.progress = MissionProgress::new(2, 75.0);
    let rest = governor.remaining_problem(1.0);
    assert_eq!(rest.phases.len(), 1);
    assert_eq!(
        rest.phases[0]
            .duration_by_level
            .as_ref()
            .unwrap()
            .duration_s,
        vec![25.0, 10.0, 0.0, 0.0]
    );
    assert_eq!(rest.phases[0].flight_power_w, 130.0);
}

/// A pack the config cannot describe stops the governor with the battery's own error.
#[test]
fn a_bad_battery_is_named_with_its_cause() {
    let mut model = reference_model();
    model.config.battery.capacity_mah = None;
    model.config.battery.capacity_wh = Some(0.0);
    let error = Governor::from_mission(&model, GovernorConfig::default())
        .err()
        .unwrap();
    assert!(
        matches!(
            &error,
            GovernorError::Battery(BatteryError::InvalidSpec {
                field: "capacity_wh",
                ..
            })
        ),
        "{error:?}"
    );
    let cause = std::error::Error::source(&error).expect("the battery's error");
    assert_eq!(error.to_string(), format!("battery: {cause}"));
    assert!(error.to_string().contains("capacity_wh = 0"), "{error}");
}

/// Without a margin the governor starts from `qosrt plan`'s plan: the same reserve, the
/// same usable energy, the same levels (74 Wh nominal, 72.5 usable, 18.1 reserve, 54.27 Wh
/// planned, utility 10.75). With the default margin the reference mission has no cheaper
/// plan that keeps it, so it starts there too.
#[test]
fn the_first_plan_is_the_offline_plan() {
    let model = reference_model();
    let problem = model.plan_problem();
    let spec = model.battery_spec(None).unwrap();
    let config = GovernorConfig {
        switch_up_margin_fraction: 0.0,
        ..GovernorConfig::default()
    };
    let governor = Governor::new(
        problem.clone(),
        BatteryEstimator::new(spec.clone()).unwrap(),
        0.25,
        config,
    )
    .unwrap();
    let best = solve(&problem, f64::MAX).unwrap();
    let duration_s: f64 = best.phases.iter().map(|p| p.duration_s).sum();
    let usable_wh = spec
        .usable_energy_wh(best.energy_wh * 3600.0 / duration_s, 1.0, 0.0)
        .unwrap();
    assert_eq!(governor.usable_full_wh(), usable_wh);
    assert_eq!(governor.reserve_wh(), 0.25 * usable_wh);
    let offline = solve(&problem, usable_wh - 0.25 * usable_wh).unwrap();
    assert_eq!(governor.initial_plan(), &offline);
    assert!(
        (offline.utility - 10.75).abs() < 1e-9,
        "{}",
        offline.utility
    );
    assert_eq!(reference_governor(None).initial_plan(), &offline);

    // The survey mission has room: the default start keeps the margin.
    let governor = survey_governor(62.0, EstimatorConfig::default(), GovernorConfig::default());
    let available_wh = governor.usable_full_wh() - governor.reserve_wh();
    let plan = governor.initial_plan();
    assert!(plan.energy_wh <= available_wh * (1.0 - governor.config().switch_up_margin_fraction));
    assert!(solve(governor.problem(), available_wh).unwrap().utility > plan.utility);
}

#[test]
fn from_mission_governs_the_reference_tasks() {
    let model = reference_model();
    let governor = Governor::from_mission(&model, GovernorConfig::default()).unwrap();
    let hazard = model
        .config
        .tasks
        .iter()
        .position(|t| t.name == "hazard")
        .unwrap();
    let detection = model
        .config
        .tasks
        .iter()
        .position(|t| t.name == "detection")
        .unwrap();
    // Transit runs only the hazard CNN.
    assert_eq!(governor.current_levels().len(), 1);
    assert!(governor.current_level_of(hazard).is_some());
    assert_eq!(governor.current_level_of(detection), None);
    assert_eq!(governor.planned_levels().len(), 3);
    assert_eq!(governor.planned_levels()[1].len(), 4);
    assert_eq!(governor.phase_levels(3), None);
    assert_eq!(governor.correction_ratio(), 1.0);
    assert!(!governor.land_now_raised());
}

#[test]
fn bad_configuration_is_named() {
    let problem = survey_problem();
    let estimator = || {
        BatteryEstimator::new(BatterySpec::from_capacity_wh(60.0, 4, 3.7, 0.025).unwrap()).unwrap()
    };
    let with = |edit: &dyn Fn(&mut GovernorConfig)| {
        let mut config = GovernorConfig::default();
        edit(&mut config);
        Governor::new(problem.clone(), estimator(), 0.25, config).unwrap_err()
    };
    let field = |error: GovernorError| match error {
        GovernorError::BadConfig(BadGovernorConfig { field, .. }) => field,
        other => panic!("{other:?}"),
    };
    assert_eq!(field(with(&|c| c.replan_period_s = 0.0)), "replan_period_s");
    assert_eq!(field(with(&|c| c.min_dwell_s = f64::NAN)), "min_dwell_s");
    assert_eq!(
        field(with(&|c| c.switch_up_margin_fraction = 1.0)),
        "switch_up_margin_fraction"
    );
    assert_eq!(field(with(&|c| c.correction_min = 1.5)), "correction_min");
    assert_eq!(field(with(&|c| c.correction_max = 0.9)), "correction_max");
    assert_eq!(
        field(with(&|c| c.land_now_max_tolerance_fraction = -0.1)),
        "land_now_max_tolerance_fraction"
    );
    assert_eq!(field(with(&|c| c.warmup_s = -1.0)), "warmup_s");
    assert_eq!(
        Governor::new(problem.clone(), estimator(), 1.0, GovernorConfig::default()).unwrap_err(),
        GovernorError::BadReserve { value: 1.0 }
    );
    let no_phases = PlanProblem {
        tasks: problem.tasks.clone(),
        phases: vec![],
    };
    assert_eq!(
        Governor::new(no_phases, estimator(), 0.25, GovernorConfig::default()).unwrap_err(),
        GovernorError::NoPhases
    );
    let mut bad_problem = problem.clone();
    bad_problem.tasks[0].utility[0] = 2.0;
    assert!(matches!(
        Governor::new(bad_problem, estimator(), 0.25, GovernorConfig::default()).unwrap_err(),
        GovernorError::Plan(PlanError::BadUtility { .. })
    ));
}
