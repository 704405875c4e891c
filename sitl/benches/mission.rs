//! Simulation speed: simulated seconds per wall second of the reference mission (tracking
//! shortened to 60 s), with the landing-marker detector at 10 fps, against the same mission with
//! the detector at 2 fps in the same run — the baseline, the slowest rate that still lands
//! this mission, where the camera renders a fifth as often — so the ratio is what the
//! vision loop costs the simulator.
//!
//! `cargo bench -p sitl --bench mission`

use runtime::catalog::PluginCatalog;
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use sitl::mission::{simulate, SimOptions};
use std::path::Path;
use std::time::Instant;

const REPEATS: usize = 3;

fn main() {
    let registry = builtin_registry().expect("the built-in plugins register");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("the reference config");
    let model = load_mission_model(&loaded).expect("the reference power model");
    let mut speedups = Vec::new();
    for fps in [2.0, 10.0] {
        let mut best: f64 = 0.0;
        let mut simulated_s = 0.0;
        for repeat in 0..REPEATS {
            let options = SimOptions {
                seed: repeat as u64,
                tracking_s: Some(60.0),
                fixed_levels: vec![("detection".into(), fps)],
                ..SimOptions::default()
            };
            let started = Instant::now();
            let outcome = simulate(&model, &registry, &options).expect("the mission flies");
            let wall_s = started.elapsed().as_secs_f64();
            simulated_s = outcome.mission_time_s;
            best = best.max(outcome.mission_time_s / wall_s);
        }
        println!(
            "detection at {fps:>4} fps: {simulated_s:.0} simulated s, best of {REPEATS}: {best:.1} simulated s per wall s"
        );
        speedups.push(best);
    }
    println!(
        "the 10 fps vision loop costs {:.1}× the 2 fps baseline's wall time per simulated second",
        speedups[0] / speedups[1]
    );
}
