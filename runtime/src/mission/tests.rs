//! The mission runner on the reference mission, observing a hovering vehicle over MAVLink.

use super::*;
use crate::catalog::PluginCatalog;
use crate::config::load_file;
use crate::dry_run::SyntheticVehicle;
use crate::energy::load_mission_model;
use crate::link::{LinkConfig, MavlinkLink};
use crate::plugins::builtin_registry;
use crate::scheduler::SchedulerBuilder;
use std::path::Path;

const STEP_S: f64 = 0.02;

/// The sequencer owns the phase and hands each change on at once: with BATTERY_STATUS silent
/// the whole flight (an autopilot that does not stream it), the step that starts a phase
/// leaves that phase's planned levels in force, for the scheduler and for what is recorded.
#[test]
fn a_phase_change_applies_the_new_phases_levels_within_one_step_without_battery_telemetry() {
    let reference = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&reference, &PluginCatalog::builtin()).unwrap();
    let mut model = load_mission_model(&loaded).unwrap();
    // Observe mode moves on by the phases' durations: a short transit and tracking.
    for phase in &mut model.config.mission.phases[..2] {
        phase.duration_s = 0.3;
    }
    let config = model.config.clone();
    let registry = builtin_registry().unwrap();
    let scheduler = SchedulerBuilder::new(&registry)
        .tasks(&config.tasks)
        .build_virtual()
        .unwrap();
    let link = MavlinkLink::bind_local_ephemeral(LinkConfig::default()).unwrap();
    let mut vehicle = SyntheticVehicle::new(link.local_addr().unwrap()).unwrap();
    let mut plan = MissionPlan::for_mission(&config);
    plan.control = false;
    let mut runner =
        MissionRunner::new(model, scheduler, link, plan, None, RunnerOptions::default()).unwrap();

    let mut seen_phases = Vec::new();
    for step in 0..200 {
        let now_s = f64::from(step) * STEP_S;
        vehicle.send(now_s, None).unwrap();
        // The loopback delivers at once; the runner reads what has arrived.
        std::thread::sleep(std::time::Duration::from_millis(1));
        runner.step(now_s, None).unwrap();
        let Some(phase) = runner.status().phase else {
            continue;
        };
        if seen_phases.last() == Some(&phase) {
            continue;
        }
        seen_phases.push(phase);
        let phase_name = &config.mission.phases[phase].name;
        let planned = runner.governor().phase_levels(phase).unwrap();
        let expected: Vec<(String, usize)> = planned
            .iter()
            .map(|l| (config.tasks[l.task].name.clone(), l.level))
            .collect();
        let in_phase: Vec<&str> = config
            .tasks
            .iter()
            .filter(|t| t.runs_in(phase_name))
            .map(|t| t.name.as_str())
            .collect();
        assert_eq!(
            expected.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>(),
            in_phase,
            "the plan of phase {phase_name} covers its tasks"
        );
        let mut recorded: Vec<(String, usize)> = runner
            .qos_levels()
            .tasks
            .into_iter()
            .map(|(name, record)| (name, record.level))
            .collect();
        recorded.sort();
        let mut expected_by_name = expected.clone();
        expected_by_name.sort();
        assert_eq!(
            recorded, expected_by_name,
            "levels in force at the start of {phase_name}"
        );
        for (name, level) in &expected {
            let id = runner.scheduler().task_id(name).unwrap();
            assert_eq!(
                runner.scheduler().level(id),
                Some(*level),
                "{name} at the start of {phase_name}"
            );
        }
    }
    assert_eq!(seen_phases, [0, 1, 2], "every phase started");
    assert_eq!(runner.log().battery.samples, 0, "no battery telemetry came");
}

/// A scheduler without one of the config's tasks (its plugin not built in) holds fewer tasks
/// than the config names, so a config index is not a scheduler id: every level the runner sets
/// reaches the task of that name, and a level for the missing task reaches none.
#[test]
fn levels_reach_the_named_task_when_the_scheduler_lacks_a_config_task() {
    let reference = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&reference, &PluginCatalog::builtin()).unwrap();
    let model = load_mission_model(&loaded).unwrap();
    let config = model.config.clone();
    assert!(config.tasks.len() >= 3, "a task to skip in the middle");
    let skipped = 1;
    let registry = builtin_registry().unwrap();
    let scheduler = SchedulerBuilder::new(&registry)
        .tasks(
            config
                .tasks
                .iter()
                .enumerate()
                .filter(|&(i, _)| i != skipped)
                .map(|(_, task)| task),
        )
        .build_virtual()
        .unwrap();
    // Every task (the skipped one too) held one below its highest level, where it starts.
    let fixed_level = |task: &crate::config::TaskConfig| task.levels.len() - 2;
    let fixed_levels = config
        .tasks
        .iter()
        .map(|task| (task.name.clone(), task.levels[fixed_level(task)]))
        .collect();
    let link = MavlinkLink::bind_local_ephemeral(LinkConfig::default()).unwrap();
    let mut plan = MissionPlan::for_mission(&config);
    plan.control = false;
    let options = RunnerOptions {
        fixed_levels,
        ..RunnerOptions::default()
    };
    let mut runner = MissionRunner::new(model, scheduler, link, plan, None, options).unwrap();
    assert_eq!(runner.task_id(skipped), None);
    for (index, task) in config.tasks.iter().enumerate().skip(skipped + 1) {
        let id = runner.task_id(index).unwrap();
        assert_eq!(
            id.index(),
            index - 1,
            "{} after the skipped task",
            task.name
        );
        assert_eq!(runner.scheduler().task_id(&task.name), Some(id));
    }

    // The first step applies the levels in force, before the scheduler starts.
    runner.step(0.0, None).unwrap();
    let levels: Vec<(String, usize)> = runner
        .scheduler()
        .stats()
        .into_iter()
        .map(|stats| (stats.name, stats.level))
        .collect();
    let expected: Vec<(String, usize)> = config
        .tasks
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != skipped)
        .map(|(_, task)| (task.name.clone(), fixed_level(task)))
        .collect();
    assert_eq!(levels, expected);
    for (index, task) in config.tasks.iter().enumerate() {
        if let Some(id) = runner.task_id(index) {
            assert_eq!(runner.scheduler().level(id), Some(fixed_level(task)));
        }
    }
}
