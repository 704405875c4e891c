//! Whole missions of the reference `qos.toml` in the simulator: the real runtime and tasks over
//! real MAVLink on the loopback. The tracking phase is shortened to keep the suite quick.

use runtime::config::load_file;
use runtime::energy::{load_mission_model, MissionModel};
use runtime::plugins::builtin_registry;
use runtime::registry::PluginRegistry;
use sim::mission::{simulate, Faults, SimOptions};
use sim::outcome::SimOutcome;
use sim::tractor::PathKind;
use std::path::Path;

fn reference() -> (MissionModel, PluginRegistry) {
    let registry = builtin_registry().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &runtime::catalog::PluginCatalog::builtin()).unwrap();
    (load_mission_model(&loaded).unwrap(), registry)
}

fn fly(options: SimOptions) -> SimOutcome {
    let (model, registry) = reference();
    simulate(&model, &registry, &options).unwrap()
}

fn short(seed: u64) -> SimOptions {
    SimOptions {
        seed,
        tracking_s: Some(5.0),
        ..SimOptions::default()
    }
}

fn has_event(outcome: &SimOutcome, text: &str) -> bool {
    outcome.events.iter().any(|(_, event)| event.contains(text))
}

#[test]
fn no_wind_straight_path_lands_within_15_cm() {
    let outcome = fly(short(1));
    assert!(outcome.landed_on_pad, "{:#?}", outcome.events);
    let error_m = outcome.touchdown_error_m.unwrap();
    assert!(error_m <= 0.15, "touchdown error {error_m} m");
    // The phases ran in order and the pack paid for both loads.
    let phases: Vec<&str> = outcome
        .events
        .iter()
        .filter_map(|(_, e)| e.strip_prefix("phase "))
        .collect();
    assert_eq!(
        phases,
        vec!["transit started", "tracking started", "landing started"]
    );
    assert!(outcome.flight_energy_wh > 0.5 && outcome.companion_energy_wh > 0.0);
    assert!(outcome.battery_left_fraction < 1.0);
    // The hazard CNN is not in this build: reported, not silently dropped.
    assert!(outcome
        .skipped_tasks
        .iter()
        .any(|t| t.starts_with("hazard")));
}

#[test]
fn the_same_seed_flies_the_same_mission() {
    let options = SimOptions {
        wind_speed_m_s: 8.0,
        path: PathKind::Turn180,
        ..short(7)
    };
    let mut first = fly(options.clone());
    let mut second = fly(options);
    // Wall-clock speed is the only thing allowed to differ.
    first.speedup = 0.0;
    second.speedup = 0.0;
    assert_eq!(first, second);
    assert!(first.touched_down);
}

/// The link drops for 2 s while following: the runtime notices, sends nothing, PX4's own
/// offboard-loss failsafe holds the vehicle; the link returns, offboard is re-entered, the
/// tracker catches up with the pad it fell behind, and the mission lands.
#[test]
fn a_lost_mavlink_link_triggers_the_failsafe_and_the_mission_recovers() {
    let outcome = fly(SimOptions {
        tracking_s: Some(15.0),
        faults: Faults {
            link_loss: Some((8.0, 10.0)),
            ..Faults::default()
        },
        ..short(2)
    });
    let lost = outcome
        .events
        .iter()
        .find(|(_, e)| e.contains("link lost"))
        .map(|(t, _)| *t)
        .expect("the loss was noticed");
    let restored = outcome
        .events
        .iter()
        .find(|(_, e)| e.contains("link restored"))
        .map(|(t, _)| *t)
        .expect("the link came back");
    // Noticed by the 0.5 s telemetry timeout; back with the first heartbeat after the window.
    assert!(
        (1.0..=2.5).contains(&(restored - lost)),
        "lost {lost} s, restored {restored} s"
    );
    let offboard_again = outcome
        .events
        .iter()
        .filter(|(_, e)| e.contains("offboard engaged"))
        .count();
    assert_eq!(offboard_again, 2, "{:#?}", outcome.events);
    assert!(outcome.landed_on_pad, "{:#?}", outcome.events);
}

/// The camera freezes during the descent: the detector names the frozen frames, the tracker
/// gets no fixes, the landing aborts and climbs to reacquire, then lands once the camera is
/// back.
#[test]
fn a_frozen_camera_makes_the_landing_abort_and_retry() {
    let outcome = fly(SimOptions {
        faults: Faults {
            // Tracking lasts 5 s; the descent begins a few seconds into the landing phase.
            camera_freeze: Some((10.0, 16.0)),
            ..Faults::default()
        },
        ..short(3)
    });
    assert!(outcome.landing_aborts >= 1, "{:#?}", outcome.events);
    assert!(has_event(&outcome, "reacquire"));
    assert!(outcome.landed_on_pad, "{:#?}", outcome.events);
}
