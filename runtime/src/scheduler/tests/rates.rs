//! Rate changes take effect within one period.

use super::*;

#[test]
fn virtual_rate_change_takes_effect_within_one_period() {
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[100.0, 20.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            initial_level: Some(0),
            ..TaskOptions::default()
        },
    );
    let mut scheduler = builder.build_virtual().unwrap();
    let tracking = scheduler.task_id("tracking").unwrap();
    scheduler.run_until(Timestamp::from_millis(1_050)).unwrap();
    assert_eq!(
        times_of(&probes.log, "tracking"),
        (0..=10).map(|k| k * 100 * MS).collect::<Vec<_>>()
    );
    // Faster: the last activation was at 1000 ms, 1000 + 20 is past, so it runs now.
    scheduler.set_level(tracking, 1).unwrap();
    scheduler.run_until(Timestamp::from_millis(1_200)).unwrap();
    let after: Vec<u64> = times_of(&probes.log, "tracking")
        .into_iter()
        .filter(|&t| t > 1_000 * MS)
        .collect();
    assert_eq!(
        after,
        (0..8).map(|k| (1_050 + 20 * k) * MS).collect::<Vec<_>>()
    );
    assert!(probes.log.lock().unwrap().last().unwrap().level == 1);
    // Slower: the last activation was at 1190 ms; the next is 1190 + 100, within 100 ms of now.
    scheduler.set_level(tracking, 0).unwrap();
    scheduler.run_until(Timestamp::from_millis(1_500)).unwrap();
    let after: Vec<u64> = times_of(&probes.log, "tracking")
        .into_iter()
        .filter(|&t| t > 1_200 * MS)
        .collect();
    assert_eq!(after, vec![1_290 * MS, 1_390 * MS, 1_490 * MS]);
    let stats = scheduler.task_stats("tracking").unwrap();
    assert_eq!((stats.level, stats.period_ms), (0, 100.0));
    assert_eq!(stats.activations, 11 + 8 + 3);
}

#[test]
fn real_time_rate_change_takes_effect_within_one_period() {
    let probes = probes();
    let config = probe("tracking", Knob::PeriodMs, &[300.0, 10.0], "");
    let mut builder = SchedulerBuilder::new(&probes.registry);
    builder.task_with(
        &config,
        TaskOptions {
            initial_level: Some(0),
            ..TaskOptions::default()
        },
    );
    let mut scheduler = builder.build_real_time(unpinned()).unwrap();
    let tracking = scheduler.task_id("tracking").unwrap();
    scheduler.start().unwrap();
    std::thread::sleep(Duration::from_millis(60));
    // One activation at start; at 300 ms the next would be 240 ms away.
    assert_eq!(times_of(&probes.log, "tracking").len(), 1);
    let changed_at = scheduler.now();
    scheduler.set_level(tracking, 1).unwrap();
    std::thread::sleep(Duration::from_millis(150));
    scheduler.stop();
    let times = times_of(&probes.log, "tracking");
    let first_after = times[1];
    // Within one new period (10 ms), plus wake-up slack for a loaded 2-core machine.
    let delay_ms = (first_after - changed_at.as_nanos()) as f64 / MS as f64;
    assert!(
        delay_ms < 10.0 + 15.0,
        "first activation {delay_ms} ms after the change"
    );
    let after = times.len() - 1;
    assert!(
        (8..=17).contains(&after),
        "{after} activations in 150 ms at 10 ms"
    );
    assert_eq!(scheduler.level(tracking), Some(1));
}
