//! Overruns and skips, and virtual time's speed.

use super::*;

#[test]
fn virtual_overruns_and_skips_follow_the_timing_model() {
    let probes = probes();
    let slow = probe("slow", Knob::PeriodMs, &[10.0], "step_cost_ms = 25.0");
    let exact = probe("exact", Knob::PeriodMs, &[10.0], "step_cost_ms = 10.0");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&slow)
        .task(&exact)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(1_000)).unwrap();
    // 25 ms steps at 10 ms: each step covers the next two instants; it runs at 0, 30, …, 990.
    let slow = scheduler.task_stats("slow").unwrap();
    assert_eq!(slow.activations, 34);
    assert_eq!(slow.overruns, 34);
    assert_eq!(slow.skipped, 68);
    assert_eq!(
        times_of(&probes.log, "slow")[..4],
        [0, 30 * MS, 60 * MS, 90 * MS]
    );
    assert!((slow.step_time.p50_us - 25_000.0).abs() < 25_000.0 * 0.016);
    assert_eq!(slow.lateness.max_us, 0.0);
    // A step exactly as long as its period is neither.
    let exact = scheduler.task_stats("exact").unwrap();
    assert_eq!(
        (exact.activations, exact.overruns, exact.skipped),
        (101, 0, 0)
    );
}

#[test]
fn a_tasks_own_cost_report_overrides_the_per_level_figure() {
    let probes = probes();
    let config = probe(
        "cnn",
        Knob::PeriodMs,
        &[100.0, 50.0],
        "step_cost_ms = [1.0, 1.0]\nreport_cost_ms = 120",
    );
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&config)
        .build_virtual()
        .unwrap();
    scheduler.run_until(Timestamp::from_millis(999)).unwrap();
    // 120 ms steps at 50 ms: runs at 0, 150, …, 900; skips two instants each time.
    let stats = scheduler.task_stats("cnn").unwrap();
    assert_eq!(
        (stats.activations, stats.overruns, stats.skipped),
        (7, 7, 14)
    );
}

#[test]
fn timing_model_from_code_and_its_level_count_is_checked() {
    let probes = probes();
    let config = probe("cnn", Knob::RateFps, &[1.0, 4.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            timing: Some(TimingModel::fixed_ms(&[300.0]).unwrap()),
            ..TaskOptions::default()
        },
    );
    assert!(matches!(
        builder.build_virtual(),
        Err(SchedulerError::Timing {
            source: TimingError::WrongLength {
                found: 1,
                levels: 2
            },
            ..
        })
    ));
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            timing: Some(TimingModel::fixed_ms(&[300.0, 300.0]).unwrap()),
            ..TaskOptions::default()
        },
    );
    let mut scheduler = builder.build_virtual().unwrap();
    scheduler.run_until(Timestamp::from_millis(1_000)).unwrap();
    // 300 ms steps at 250 ms: runs at 0, 500, 1000, skipping 250, 750 and (after the last
    // step, which ends at 1300) 1250.
    let stats = scheduler.task_stats("cnn").unwrap();
    assert_eq!(
        (stats.activations, stats.overruns, stats.skipped),
        (3, 3, 3)
    );
}

#[test]
fn real_time_overruns_and_skips_are_counted() {
    let probes = probes();
    let slow = probe("slow", Knob::PeriodMs, &[10.0], "sleep_ms = 25");
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .task(&slow)
        .build_real_time(unpinned())
        .unwrap();
    scheduler.start().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    scheduler.stop();
    let stats = scheduler.task_stats("slow").unwrap();
    assert!(stats.activations >= 5, "{stats:?}");
    assert_eq!(
        stats.overruns, stats.activations,
        "every 25 ms step overruns 10 ms"
    );
    // Each step covers at least two instants (a late wake-up may cover a third).
    assert!(stats.skipped >= 2 * stats.activations, "{stats:?}");
    assert!(stats.step_time.p50_us >= 25_000.0, "{stats:?}");
}

// ---------------------------------------------------------------------------------------------
// Speed

#[test]
fn virtual_time_runs_much_faster_than_real_time() {
    let probes = probes();
    let config = reference(&probes.registry.catalog());
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .tasks(&config.tasks)
        .build_virtual()
        .unwrap();
    let simulated_s = 600.0;
    let started = Instant::now();
    let activations = scheduler
        .run_until(Timestamp::from_secs_f64(simulated_s))
        .unwrap();
    let wall_s = started.elapsed().as_secs_f64();
    // Top levels. Every task is input-triggered and no camera frame comes here: detection
    // never runs; tracking, landing and hazard run on their idle times (20 ms, 50 ms, 1 s).
    assert_eq!(activations, 30_000 + 12_000 + 600);
    assert_eq!(scheduler.task_stats("detection").unwrap().activations, 0);
    let stats = scheduler.stats();
    assert_eq!(stats[3].activations, 600);
    assert!(
        simulated_s / wall_s > 100.0,
        "{simulated_s} s simulated in {wall_s:.3} s"
    );
}
