//! Phases: a task runs only in the phases it lists.

use super::*;

/// Two probes: `watch` in transit and tracking, `land` in tracking and landing.
fn phased_probes() -> (Probes, Vec<TaskConfig>) {
    let probes = probes();
    let mut watch = probe("watch", Knob::PeriodMs, &[100.0], "");
    watch.phases = vec!["transit".into(), "tracking".into()];
    let mut land = probe("land", Knob::PeriodMs, &[100.0], "");
    land.phases = vec!["tracking".into(), "landing".into()];
    (probes, vec![watch, land])
}

#[test]
fn virtual_time_steps_a_task_only_in_its_phases() {
    let (probes, tasks) = phased_probes();
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .tasks(&tasks)
        .phase_gate(PhaseGate::NoPhase)
        .record_trace(true)
        .build_virtual()
        .unwrap();
    let ms = Timestamp::from_millis;
    // Before the first phase nothing runs; then each phase for one second.
    scheduler.run_until(ms(1000)).unwrap();
    for (phase, until_ms) in [("transit", 2000), ("tracking", 3000), ("landing", 4000)] {
        scheduler.set_phase(&PhaseGate::Phase(phase.into()));
        scheduler.run_until(ms(until_ms)).unwrap();
    }
    scheduler.set_phase(&PhaseGate::NoPhase);
    scheduler.run_until(ms(5000)).unwrap();
    let watch = times_of(&probes.log, "watch");
    let land = times_of(&probes.log, "land");
    // Every 100 ms while its phases fly (`run_until` includes its end instant, at which the
    // phase still flies): watch from 1 s to 3 s, land from 2 s to 4 s, never outside.
    let every_100_ms = |from_ms: u64, to_ms: u64| -> Vec<u64> {
        (from_ms / 100..=to_ms / 100)
            .map(|k| k * 100 * MS)
            .collect()
    };
    assert_eq!(watch, every_100_ms(1000, 3000));
    assert_eq!(land, every_100_ms(2000, 4000));
    let kinds: Vec<&TraceKind> = scheduler
        .trace()
        .iter()
        .filter(|e| &*e.task == "land")
        .map(|e| &e.kind)
        .filter(|k| matches!(k, TraceKind::Suspended | TraceKind::Resumed))
        .collect();
    assert_eq!(kinds, [&TraceKind::Resumed, &TraceKind::Suspended]);
}

#[test]
fn real_time_suspends_a_task_outside_its_phases() {
    let (probes, tasks) = phased_probes();
    let mut scheduler = SchedulerBuilder::new(&probes.registry)
        .tasks(&tasks)
        .phase_gate(PhaseGate::Phase("transit".into()))
        .build_real_time(unpinned())
        .unwrap();
    scheduler.start().unwrap();
    std::thread::sleep(Duration::from_millis(250));
    assert!(times_of(&probes.log, "land").is_empty());
    let watch_before = times_of(&probes.log, "watch").len();
    assert!(
        watch_before >= 2,
        "{watch_before} steps in 250 ms at 100 ms"
    );
    // The tasks' threads run while the phase changes, so the switch is
    // bracketed: a step may land between the change and a later clock read.
    let before_switch = scheduler.now().as_nanos();
    scheduler.set_phase(&PhaseGate::Phase("landing".into()));
    let after_switch = scheduler.now().as_nanos();
    std::thread::sleep(Duration::from_millis(250));
    scheduler.stop();
    let watch = times_of(&probes.log, "watch");
    let land = times_of(&probes.log, "land");
    assert!(
        watch.iter().all(|&t| t <= after_switch),
        "watch stepped in landing: {watch:?}"
    );
    assert!(land.len() >= 2, "{land:?}");
    assert!(
        land[0] >= before_switch,
        "land stepped in transit: {land:?}"
    );
    // Resumed at once (within a loaded machine's wake-up slack).
    assert!(
        land[0] - before_switch < 20 * MS,
        "{} ms",
        (land[0] - before_switch) / MS
    );
}
