//! Bad input as named errors, stopping, and core pinning.

use super::*;

#[test]
fn mistakes_are_named_errors() {
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[100.0, 20.0], "");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_virtual()
        .unwrap();
    assert_eq!(scheduler.task_id("trackin"), None);
    let tracking = scheduler.task_id("tracking").unwrap();
    assert!(matches!(
        scheduler.set_level(tracking, 2),
        Err(SchedulerError::Level(LevelError::OutOfRange {
            task,
            level: 2,
            count: 2,
        })) if task == "tracking"
    ));
    // An id of another scheduler, past this one's tasks, is named as such.
    let other = probe("landing", Knob::PeriodMs, &[100.0, 20.0], "");
    let foreign = SchedulerBuilder::new(&probes.registry)
        .tasks([&other, &config])
        .build_virtual()
        .unwrap()
        .task_id("tracking")
        .unwrap();
    let error = scheduler.set_level(foreign, 0).unwrap_err();
    assert!(
        matches!(&error, SchedulerError::UnknownTaskId { id, known } if *id == foreign && known == "tracking"),
        "{error:?}"
    );
    assert!(error.to_string().contains("no task with id #1"), "{error}");
    assert_eq!(scheduler.level(foreign), None);
    assert_eq!(scheduler.next_activation(foreign), None);
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(10)),
        Ok(1)
    ));
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(5)),
        Err(SchedulerError::Clock(ClockError::Backwards { .. }))
    ));
    // The clock advanced behind the scheduler's back is refused, not silently jumped.
    scheduler
        .clock()
        .advance_to(Timestamp::from_millis(500))
        .unwrap();
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(600)),
        Err(SchedulerError::Clock(_))
    ));

    let build = |configs: &[&TaskConfig], options: TaskOptions| {
        let mut builder = SchedulerBuilder::new(&probes.registry);
        for config in configs {
            builder.task_with(config, options.clone());
        }
        builder.build_virtual().err()
    };
    assert!(matches!(
        build(&[&config, &config], TaskOptions::default()),
        Some(SchedulerError::DuplicateTask { task }) if task == "tracking"
    ));
    assert!(matches!(
        build(
            &[&config],
            TaskOptions {
                initial_level: Some(5),
                ..TaskOptions::default()
            }
        ),
        Some(SchedulerError::Level(LevelError::OutOfRange {
            level: 5,
            ..
        }))
    ));
    let mut unknown = config.clone();
    unknown.plugin = "prob".into();
    assert!(matches!(
        build(&[&unknown], TaskOptions::default()),
        Some(SchedulerError::Registry(RegistryError::UnknownPlugin { suggestion: Some(s), .. })) if s == "probe"
    ));
    let bad_cost = probe(
        "tracking",
        Knob::PeriodMs,
        &[100.0, 20.0],
        "step_cost_ms = [1.0]",
    );
    let error = build(&[&bad_cost], TaskOptions::default()).unwrap();
    assert!(
        error.to_string().contains("tracking") && error.to_string().contains("step_cost_ms"),
        "{error}"
    );
    let bad_params = probe("tracking", Knob::PeriodMs, &[100.0], "panic_on = 1");
    let error = build(&[&bad_params], TaskOptions::default()).unwrap();
    assert!(error.to_string().contains("panic_on"), "{error}");
    let bad_level = probe("tracking", Knob::RateFps, &[0.0], "");
    assert!(matches!(
        build(&[&bad_level], TaskOptions::default()),
        Some(SchedulerError::Level(LevelError::BadValue { .. }))
    ));
}

#[test]
fn the_timing_param_is_the_schedulers_not_the_plugins() {
    // The probe's params deny unknown keys; step_cost_ms must not reach it.
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[20.0], "step_cost_ms = 5.0");
    assert!(SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_virtual()
        .is_ok());
}

#[test]
fn restart_policy_reads_from_toml() {
    #[derive(serde::Deserialize)]
    struct Holder {
        restart: RestartPolicy,
    }
    let never: Holder = toml::from_str("restart = { policy = \"never\" }").unwrap();
    assert_eq!(never.restart, RestartPolicy::Never);
    let limited: Holder =
        toml::from_str("restart = { policy = \"on_failure\", max_restarts = 5 }").unwrap();
    assert_eq!(
        limited.restart,
        RestartPolicy::OnFailure { max_restarts: 5 }
    );
    assert!(toml::from_str::<Holder>("restart = { policy = \"always\" }").is_err());
}

#[test]
fn stopping_stops_every_task_once() {
    let probes = probes();
    let a = probe("a", Knob::PeriodMs, &[10.0], "");
    let b = probe("b", Knob::PeriodMs, &[10.0], "");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&a)
        .task(&b)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(30)).unwrap();
    scheduler.stop();
    scheduler.stop();
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
    assert!(matches!(
        scheduler.run_until(Timestamp::from_millis(40)),
        Err(SchedulerError::Stopped)
    ));
    drop(scheduler);
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
}

#[test]
fn real_time_stop_stops_every_started_task_once() {
    let probes = probes();
    let a = probe("a", Knob::PeriodMs, &[5.0], "");
    let b = probe("b", Knob::PeriodMs, &[5.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task(&a).task(&b);
    let options = unpinned();
    // Built but never started: nothing to stop.
    drop(builder.build_real_time(options).unwrap());
    assert_eq!(probes.stops.load(Ordering::SeqCst), 0);
    let mut scheduler = builder.build_real_time(options).unwrap();
    scheduler.start().unwrap();
    assert!(matches!(
        scheduler.start(),
        Err(SchedulerError::AlreadyStarted)
    ));
    std::thread::sleep(Duration::from_millis(30));
    scheduler.stop();
    let stopped_with = [
        scheduler.task_stats("a").unwrap().activations,
        scheduler.task_stats("b").unwrap().activations,
    ];
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
    std::thread::sleep(Duration::from_millis(20));
    // No activation after the stop; a second stop (and the drop) changes nothing.
    scheduler.stop();
    assert_eq!(
        scheduler.task_stats("a").unwrap().activations,
        stopped_with[0]
    );
    drop(scheduler);
    assert_eq!(probes.stops.load(Ordering::SeqCst), 2);
    assert!(stopped_with.iter().all(|&n| n >= 2), "{stopped_with:?}");
}

#[cfg(target_os = "linux")]
#[test]
fn pinning_to_a_missing_core_is_an_error_only_when_required() {
    let probes = probes();
    let mut config = probe("pinned", Knob::PeriodMs, &[10.0], "");
    config.cores = vec![1000];
    let options = |pinning| RealTimeOptions {
        pinning,
        ..RealTimeOptions::default()
    };
    let mut required = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_real_time(options(Pinning::Required))
        .unwrap();
    assert!(matches!(
        required.start(),
        Err(SchedulerError::Pinning { task, cores, .. }) if task == "pinned" && cores == vec![1000]
    ));
    // Best effort: a warning, and the task runs.
    let mut best_effort = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_real_time(options(Pinning::BestEffort))
        .unwrap();
    best_effort.start().unwrap();
    std::thread::sleep(Duration::from_millis(30));
    best_effort.stop();
    assert!(best_effort.task_stats("pinned").unwrap().activations >= 1);
    // Core 0 exists everywhere.
    config.cores = vec![0];
    let mut on_core_0 = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_real_time(options(Pinning::Required))
        .unwrap();
    on_core_0.start().unwrap();
    on_core_0.stop();
}
