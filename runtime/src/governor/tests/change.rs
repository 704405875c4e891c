//! Plan changes in flight: the reserve, the time left and a task's levels, each applied whole
//! with a re-plan at once, or refused whole with nothing changed.

use super::*;
use power_models::planner::LevelRange;

/// One reading at 16.4 V and `current_a`, `second` seconds into the survey (phase 1).
fn survey_reading(governor: &mut Governor, second: u32, current_a: f64) {
    let telemetry = BatteryTelemetry {
        time_s: f64::from(second),
        voltage_v: Some(16.4),
        current_a: Some(current_a),
        consumed_mah: None,
        remaining_fraction: None,
    };
    governor
        .update(&telemetry, MissionProgress::new(1, f64::from(second)))
        .unwrap();
}

/// The survey governor after 40 s of survey at 16.4 V and 8 A: warmed up and re-planned.
fn flown_governor() -> Governor {
    let mut governor = survey_governor(60.0, EstimatorConfig::default(), GovernorConfig::default());
    for second in 0..=40 {
        survey_reading(&mut governor, second, 8.0);
    }
    assert!(
        governor.last_replan().is_some(),
        "re-planned after the warm-up"
    );
    governor
}

fn reserve(fraction: f64) -> PlanChange {
    PlanChange {
        reserve_fraction: Some(fraction),
        ..PlanChange::default()
    }
}

fn levels(task: &str, range: Option<LevelRange>) -> PlanChange {
    PlanChange {
        allowed_levels: [(task.to_string(), range)].into(),
        ..PlanChange::default()
    }
}

/// The landing's duration at the detector level in force, from the survey's own table.
fn landing_duration_s(governor: &Governor) -> f64 {
    let detector = governor.levels[2]
        .iter()
        .find(|l| l.task == 1)
        .unwrap()
        .level;
    [100.0, 85.0, 70.0, 60.0][detector]
}

#[test]
fn a_reserve_changed_before_any_reading_waits_for_the_first_replan() {
    let mut governor = survey_governor(60.0, EstimatorConfig::default(), GovernorConfig::default());
    assert!(governor.change_plan(&reserve(0.3)).unwrap().is_empty());
    assert!((governor.reserve_fraction() - 0.3).abs() < 1e-12);
    assert!(governor.last_replan().is_none());
}

#[test]
fn a_larger_reserve_replans_at_once_with_that_much_less_to_fly_with() {
    let mut governor = flown_governor();
    let before = governor.last_replan().unwrap().clone();
    governor.change_plan(&reserve(0.35)).unwrap();
    let after = governor.last_replan().unwrap();
    assert_eq!(after.trigger, ReplanTrigger::PlanChanged);
    // A tenth of the full pack's usable energy more kept back (the rating at the plan's mean
    // power moves a little if the levels changed with it).
    let kept_wh = 0.10 * governor.usable_full_wh();
    let drop_wh = before.available_wh - after.available_wh;
    assert!(
        (drop_wh - kept_wh).abs() < 0.05 * kept_wh,
        "available fell {drop_wh} Wh for {kept_wh} Wh more reserve"
    );
}

#[test]
fn a_change_the_battery_cannot_carry_or_out_of_range_changes_nothing() {
    let mut governor = flown_governor();
    let untouched = governor.clone();
    let error = governor.change_plan(&reserve(0.9)).unwrap_err();
    let PlanChangeError::Infeasible {
        needed_wh,
        available_wh,
    } = error
    else {
        panic!("{error}");
    };
    assert!(needed_wh > available_wh, "{error}");
    assert!(error.to_string().starts_with("infeasible"), "{error}");
    assert_eq!(governor, untouched);
    for (change, expected) in [
        (reserve(1.2), "[0, 1)"),
        (PlanChange::default(), "nothing to change"),
        (levels("lidar", None), "it plans: cnn, detector"),
        (
            levels("detector", Some(LevelRange { min: 1, max: 4 })),
            "levels 0..=3",
        ),
        (
            levels("detector", Some(LevelRange { min: 2, max: 1 })),
            "out of range",
        ),
    ] {
        let error = governor.change_plan(&change).unwrap_err();
        assert!(error.to_string().contains(expected), "{error}");
        assert_eq!(governor, untouched, "{error}");
    }
    // Two changes, one bad: neither is applied.
    let mut both = reserve(0.3);
    both.allowed_levels = levels("lidar", None).allowed_levels;
    assert!(governor.change_plan(&both).is_err());
    assert_eq!(governor, untouched);
}

#[test]
fn levels_narrowed_in_flight_move_at_once_and_stay_within_their_bounds() {
    let mut governor = flown_governor();
    let detector_now = governor.current_level_of(1).unwrap();
    assert!(
        detector_now > 0,
        "the detector flies above its lowest level"
    );
    let events = governor
        .change_plan(&levels("detector", Some(LevelRange { min: 0, max: 0 })))
        .unwrap();
    let change = events
        .iter()
        .find_map(|e| match e {
            GovernorEvent::LevelsChanged(change) => Some(change),
            _ => None,
        })
        .expect("a level change");
    assert_eq!(change.reason, ChangeReason::LevelsNotAllowed);
    assert_eq!(change.trigger, ReplanTrigger::PlanChanged);
    // Every phase left runs the detector at level 0.
    for phase in &change.new_levels {
        for level in phase.iter().filter(|l| l.task == 1) {
            assert_eq!(level.level, 0, "{:?}", change.new_levels);
        }
    }
    assert_eq!(governor.current_level_of(1), Some(0));
    assert_eq!(
        governor.allowed_levels("detector"),
        Some(LevelRange { min: 0, max: 0 })
    );
    // Later re-plans keep the bound, whatever the battery says.
    for second in 41..=200 {
        survey_reading(&mut governor, second, 4.0);
        assert_eq!(governor.current_level_of(1), Some(0), "at {second} s");
    }
    // Lifted: the bound is gone.
    governor.change_plan(&levels("detector", None)).unwrap();
    assert_eq!(governor.allowed_levels("detector"), None);
}

#[test]
fn the_time_left_goes_to_the_phases_that_end_after_their_duration() {
    let mut governor = flown_governor();
    let progress = MissionProgress::new(1, 40.0);
    let survey_only = [false, true, false];
    let landing_s = landing_duration_s(&governor);
    let durations = governor
        .durations_for_time_left(progress, 600.0, &survey_only)
        .unwrap();
    // The survey started 40 s ago; the landing after it takes its own time.
    assert_eq!(durations, vec![(1, 40.0 + 600.0 - landing_s)]);

    let needed_before = governor.last_replan().unwrap().needed_wh;
    governor
        .change_plan(&PlanChange {
            phase_durations_s: durations,
            ..PlanChange::default()
        })
        .unwrap();
    assert!((governor.planned_time_left_s(progress) - 600.0).abs() < 1e-9);
    let needed_after = governor.last_replan().unwrap().needed_wh;
    // 860 s of survey left became 600 − landing: the rest needs less.
    assert!(
        needed_after < needed_before * 0.9,
        "{needed_before} Wh before, {needed_after} Wh after"
    );

    // Too short for the landing, nothing timed left, not a time.
    let error = governor
        .durations_for_time_left(progress, 30.0, &survey_only)
        .unwrap_err();
    assert_eq!(
        error,
        PlanChangeError::TimeLeftTooShort {
            asked_s: 30.0,
            needed_s: landing_s
        }
    );
    assert_eq!(
        governor.durations_for_time_left(MissionProgress::new(2, 5.0), 300.0, &survey_only),
        Err(PlanChangeError::NoTimedPhaseLeft)
    );
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            governor.durations_for_time_left(progress, bad, &survey_only),
            Err(PlanChangeError::BadTimeLeft { .. })
        ));
    }
}

#[test]
fn two_timed_phases_share_the_time_left_as_they_had_it() {
    let governor = survey_governor(60.0, EstimatorConfig::default(), GovernorConfig::default());
    let landing_s = landing_duration_s(&governor);
    // 20 s into a 120 s transit: 100 s of it and 900 s of survey left, one to nine.
    let durations = governor
        .durations_for_time_left(MissionProgress::new(0, 20.0), 500.0, &[true, true, false])
        .unwrap();
    let share_s = 500.0 - landing_s;
    assert_eq!(durations.len(), 2);
    assert_eq!(durations[0].0, 0);
    assert!(
        (durations[0].1 - (20.0 + 0.1 * share_s)).abs() < 1e-9,
        "{durations:?}"
    );
    assert_eq!(durations[1].0, 1);
    assert!(
        (durations[1].1 - 0.9 * share_s).abs() < 1e-9,
        "{durations:?}"
    );
}
