//! Simulation speed: simulated seconds per wall second of the reference mission (every task,
//! the hazard CNN included, at the governor's levels; tracking shortened to 60 s; the realistic
//! world), with each camera frame rendered on every core, against the same mission with frames
//! rendered on one thread in the same run — the baseline — so the ratio is what spreading the
//! renderer over the cores buys.
//!
//! `cargo bench -p sitl --bench mission`

use runtime::catalog::PluginCatalog;
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use sim::world::WorldOptions;
use sitl::mission::{simulate, SimOptions};
use std::path::Path;
use std::time::Instant;

const REPEATS: usize = 3;

fn main() {
    let registry = builtin_registry().expect("the built-in plugins register");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("the reference config");
    let model = load_mission_model(&loaded).expect("the reference power model");
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut speedups = Vec::new();
    for (label, render_threads) in [("one thread (baseline)", 1), ("every core", 0)] {
        let mut best: f64 = 0.0;
        let mut simulated_s = 0.0;
        for repeat in 0..REPEATS {
            let options = SimOptions {
                world: WorldOptions {
                    seed: repeat as u64,
                    ..WorldOptions::default()
                },
                tracking_s: Some(60.0),
                render_threads,
                ..SimOptions::default()
            };
            let started = Instant::now();
            let outcome = simulate(&model, &registry, &options).expect("the mission flies");
            let wall_s = started.elapsed().as_secs_f64();
            simulated_s = outcome.mission_time_s;
            best = best.max(outcome.mission_time_s / wall_s);
        }
        println!(
            "frames rendered on {label:<22}: {simulated_s:.0} simulated s, best of {REPEATS}: {best:.1} simulated s per wall s"
        );
        speedups.push(best);
    }
    println!(
        "rendering on {cores} cores runs the mission {:.2}× as fast as on one",
        speedups[1] / speedups[0]
    );
}
