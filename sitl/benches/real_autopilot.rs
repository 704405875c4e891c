//! Simulation speed with the real PX4 in lockstep: simulated seconds per wall second of the
//! reference mission (tracking 15 s, the 180° turn in 12 m/s gusts, the realistic world) with
//! PX4 v1.16.0 SITL (`none_iris` over HIL) flying the world's rigid body, against the same
//! mission with the built-in autopilot in the same run — the baseline. PX4 must keep up with
//! the world at ≥ 4× real time. Skips, saying why, without `../shared/px4-sitl`.
//!
//! `cargo bench -p sitl --bench real_autopilot`

use runtime::catalog::PluginCatalog;
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use sim::tractor::PathKind;
use sim::world::WorldOptions;
use sitl::mission::{simulate, AutopilotKind, RealAutopilot, SimOptions};
use std::path::Path;
use std::time::{Duration, Instant};

const REPEATS: u64 = 2;
/// An instance no test uses.
const PX4_INSTANCE: u8 = 0;

fn main() {
    let start = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/px4-sitl/start");
    if !start.exists() {
        println!("skipped: {} is absent", start.display());
        return;
    }
    let registry = builtin_registry().expect("the built-in plugins register");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("the reference config");
    let model = load_mission_model(&loaded).expect("the reference power model");
    let px4 = RealAutopilot {
        kind: AutopilotKind::Px4,
        instance: PX4_INSTANCE,
        command: Some(format!(
            "PX4_PARAMS='EKF2_RNG_CTRL 0;LNDMC_XY_VEL_MAX 4' {} -i {{i}} -m none_iris",
            start.display()
        )),
        connect_timeout: Duration::from_secs(30),
    };
    let mut speeds = Vec::new();
    for (label, autopilot) in [
        ("built-in (baseline)", None),
        ("PX4 HIL in lockstep", Some(px4)),
    ] {
        let mut best: f64 = 0.0;
        let mut simulated_s = 0.0;
        for seed in 0..REPEATS {
            let options = SimOptions {
                world: WorldOptions {
                    seed,
                    path: PathKind::Turn180,
                    wind_speed_m_s: 12.0,
                    ..WorldOptions::default()
                },
                tracking_s: Some(15.0),
                autopilot: autopilot.clone(),
                ..SimOptions::default()
            };
            let started = Instant::now();
            let outcome = simulate(&model, &registry, &options).expect("the mission flies");
            let wall_s = started.elapsed().as_secs_f64();
            simulated_s = outcome.mission_time_s;
            best = best.max(outcome.mission_time_s / wall_s);
        }
        println!(
            "{label:<22}: {simulated_s:.0} simulated s, best of {REPEATS}: {best:.1}× real time"
        );
        speeds.push(best);
    }
    println!(
        "the mission with PX4 in lockstep runs at {:.2}× the built-in autopilot's speed",
        speeds[1] / speeds[0]
    );
}
