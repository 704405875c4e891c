//! The GPU's exclusivity, and failing tasks restarted per policy.

use super::*;

#[test]
fn gpu_is_exclusive_at_build_and_at_run_time() {
    let probes = probes();
    let mut hazard = probe("hazard", Knob::RateFps, &[4.0], "");
    hazard.resource = Resource::Gpu;
    let mut second = probe("hazard2", Knob::RateFps, &[4.0], "");
    second.resource = Resource::Gpu;

    // Two GPU tasks in one scheduler: refused, naming both.
    let error = SchedulerBuilder::new(&probes.registry)
        .task(&hazard)
        .task(&second)
        .build_virtual()
        .err()
        .unwrap();
    assert!(
        matches!(&error, SchedulerError::Resource(ResourceError::Busy { holder, claimant, .. })
            if holder == "hazard" && claimant == "hazard2"),
        "{error:?}"
    );

    // At run time the running GPU task holds the lease: any other claimant is refused.
    let resources = Resources::new();
    let mut running = SchedulerBuilder::new(&probes.registry)
        .task(&hazard)
        .resources(resources.clone())
        .build_real_time(RealTimeOptions::default())
        .unwrap();
    running.start().unwrap();
    assert_eq!(resources.gpu().holder().as_deref(), Some("hazard"));
    assert!(matches!(
        resources.gpu().claim("intruder"),
        Err(ResourceError::Busy { holder, .. }) if holder == "hazard"
    ));
    let refused = SchedulerBuilder::new(&probes.registry)
        .task(&second)
        .resources(resources.clone())
        .build_virtual();
    assert!(matches!(
        refused,
        Err(SchedulerError::Resource(ResourceError::Busy { .. }))
    ));
    running.stop();
    // Released with the task.
    assert_eq!(resources.gpu().holder(), None);
    assert!(resources.gpu().claim("hazard2").is_ok());
}

#[test]
fn a_gpu_task_that_fails_for_good_releases_the_gpu() {
    let probes = probes();
    let mut hazard = probe("hazard", Knob::RateFps, &[4.0], "panic_on_step = 0");
    hazard.resource = Resource::Gpu;
    let resources = Resources::new();
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task_with(
            &hazard,
            TaskOptions {
                restart: RestartPolicy::Never,
                ..TaskOptions::default()
            },
        )
        .resources(resources.clone())
        .build_virtual()
        .unwrap();
    assert_eq!(resources.gpu().holder().as_deref(), Some("hazard"));
    scheduler.run_until(Timestamp::from_millis(1)).unwrap();
    assert_eq!(scheduler.failed_tasks(), vec!["hazard".to_string()]);
    assert_eq!(resources.gpu().holder(), None);
}

// ---------------------------------------------------------------------------------------------
// Failures

#[test]
fn a_panicking_task_is_restarted_per_policy_and_the_others_keep_their_rates() {
    let probes = probes();
    let steady = probe("steady", Knob::PeriodMs, &[20.0], "");
    // Every instance panics at its third step: t = 40, 100, 160 ms (the restart is at the next
    // activation, 20 ms after each failure).
    let crashy = probe("crashy", Knob::PeriodMs, &[20.0], "panic_on_step = 2");
    let once = probe("once", Knob::RateFps, &[50.0], "panic_once_at = 5");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder
        .task(&steady)
        .task_with(
            &crashy,
            TaskOptions {
                restart: RestartPolicy::OnFailure { max_restarts: 2 },
                ..TaskOptions::default()
            },
        )
        .task(&once)
        .record_trace(true);
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.run_until(Timestamp::from_millis(1_000)).unwrap();

    let crashy = scheduler.task_stats("crashy").unwrap();
    assert_eq!((crashy.failures, crashy.restarts), (3, 2), "{crashy:?}");
    assert_eq!(crashy.health, TaskHealth::Failed);
    assert_eq!(crashy.activations, 9, "three instances of three steps");
    assert!(crashy
        .last_error
        .as_deref()
        .unwrap()
        .contains("probe panics at step 2"));
    assert_eq!(
        times_of(&probes.log, "crashy"),
        [0, 20, 40, 60, 80, 100, 120, 140, 160]
            .map(|t| t * MS)
            .to_vec()
    );
    // Its neighbours never missed an activation.
    let steady = scheduler.task_stats("steady").unwrap();
    assert_eq!(steady.activations, 51);
    assert_eq!((steady.failures, steady.skipped), (0, 0));
    assert_eq!(
        times_of(&probes.log, "steady"),
        (0..=50).map(|k| k * 20 * MS).collect::<Vec<_>>()
    );
    // A one-off panic: one restart, then it runs on at its rate.
    let once = scheduler.task_stats("once").unwrap();
    assert_eq!((once.failures, once.restarts), (1, 1));
    assert_eq!(once.health, TaskHealth::Running);
    assert_eq!(once.activations, 51);
    assert_eq!(scheduler.failed_tasks(), vec!["crashy".to_string()]);
    let gave_up = scheduler.trace().iter().find(|event| {
        matches!(&event.kind, TraceKind::Failed { gave_up: true, .. }) && &*event.task == "crashy"
    });
    assert_eq!(gave_up.unwrap().time, Timestamp::from_millis(160));
    // Each failed instance was stopped (3 crashy + 1 once) before it was dropped.
    assert_eq!(probes.stops.load(Ordering::SeqCst), 4);
}

#[test]
fn never_policy_fails_for_good_and_tasks_see_the_degraded_mission() {
    let probes = probes();
    let detection = probe("detection", Knob::PeriodMs, &[50.0], "error_on_step = 1");
    let landing = probe("landing", Knob::PeriodMs, &[20.0], "");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task_with(
            &detection,
            TaskOptions {
                restart: RestartPolicy::Never,
                ..TaskOptions::default()
            },
        )
        .task(&landing)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(200)).unwrap();
    assert_eq!(times_of(&probes.log, "detection"), vec![0, 50 * MS]);
    let detection = scheduler.task_stats("detection").unwrap();
    assert_eq!((detection.failures, detection.restarts), (1, 0));
    assert!(detection
        .last_error
        .unwrap()
        .contains("probe fails at step 1"));
    // The landing task sees the mission healthy until 50 ms, degraded from then on.
    let log = probes.log.lock().unwrap();
    let landing: Vec<&Seen> = log.iter().filter(|seen| seen.task == "landing").collect();
    assert_eq!(landing.len(), 11);
    for seen in landing {
        let expect_degraded = seen.at > Timestamp::from_millis(50);
        assert_eq!(seen.degraded, expect_degraded, "{seen:?}");
        if expect_degraded {
            assert_eq!(seen.failed, vec!["detection".to_string()]);
        }
    }
    assert_eq!(
        scheduler.health().health_of("detection"),
        Some(TaskHealth::Failed)
    );
}

#[test]
fn a_failing_start_is_a_failure_restarted_per_policy() {
    let probes = probes();
    let camera = probe("camera", Knob::PeriodMs, &[10.0], "fail_start = true");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task_with(
            &camera,
            TaskOptions {
                restart: RestartPolicy::OnFailure { max_restarts: 4 },
                ..TaskOptions::default()
            },
        )
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(100)).unwrap();
    let stats = scheduler.task_stats("camera").unwrap();
    // Start fails, then four restarts at 0, 10, 20, 30 ms each fail again; never a step.
    assert_eq!(
        (stats.failures, stats.restarts, stats.activations),
        (5, 4, 0)
    );
    assert_eq!(stats.health, TaskHealth::Failed);
    assert!(stats.last_error.unwrap().contains("camera not found"));
}

#[test]
fn real_time_panicking_task_is_isolated_and_the_others_keep_their_rates() {
    let probes = probes();
    let steady = probe("steady", Knob::PeriodMs, &[10.0], "");
    let crashy = probe("crashy", Knob::PeriodMs, &[10.0], "panic_on_step = 2");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&steady)
        .task_with(
            &crashy,
            TaskOptions {
                restart: RestartPolicy::OnFailure { max_restarts: 2 },
                ..TaskOptions::default()
            },
        )
        .build_real_time(unpinned())
        .unwrap();
    let started = Instant::now();
    scheduler.start().unwrap();
    // A panic can take long (the default hook prints a backtrace when RUST_BACKTRACE is set):
    // wait for the crashy task to give up rather than assume a time.
    while scheduler.health().health_of("crashy") != Some(TaskHealth::Failed) {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "crashy never gave up"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let crashed_ms = started.elapsed().as_secs_f64() * 1e3;
    let during = scheduler.task_stats("steady").unwrap().activations;
    std::thread::sleep(Duration::from_millis(300));
    let after = scheduler.task_stats("steady").unwrap().activations - during;
    scheduler.stop();
    let crashy = scheduler.task_stats("crashy").unwrap();
    assert_eq!((crashy.failures, crashy.restarts), (3, 2), "{crashy:?}");
    assert_eq!(crashy.health, TaskHealth::Failed);
    assert_eq!(crashy.activations, 9);
    let steady = scheduler.task_stats("steady").unwrap();
    assert_eq!(steady.failures, 0);
    // At 10 ms: kept its rate while the other task crashed three times (a loaded machine may
    // skip a few activations, never run extra)…
    let expected_during = crashed_ms / 10.0;
    assert!(
        during as f64 >= 0.7 * expected_during - 2.0 && during as f64 <= expected_during + 2.0,
        "{during} activations in the {crashed_ms:.0} ms of crashes"
    );
    // …and after it.
    assert!((21..=32).contains(&after), "{after} activations in 300 ms");
    assert_eq!(scheduler.failed_tasks(), vec!["crashy".to_string()]);
}
