//! What recording costs the loop: the reference mission (tracking 30 s, every task, the
//! realistic world) flown without a recording — the baseline — and with one (`--record`: every
//! frame, telemetry, topic and decision to a zstd MCAP file), alternated in the same run. It
//! prints the runtime loop's step time (p50, p99), the simulation's speed, and the ratios.
//!
//! `cargo bench -p sitl --bench record`

use runtime::catalog::PluginCatalog;
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use runtime::record::{ConfigFile, RecorderOptions};
use sim::world::WorldOptions;
use sitl::mission::{simulate, SimOptions, SimRecording};
use std::path::Path;

const REPEATS: u64 = 3;

fn main() {
    let registry = builtin_registry().expect("the built-in plugins register");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("the reference config");
    let model = load_mission_model(&loaded).expect("the reference power model");
    let dir = std::env::temp_dir().join(format!("qosrt-record-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch folder");
    let config_files = ConfigFile::collect(&path, &model.config).expect("the config files");
    // (p50 µs, p99 µs, speed ×) per repeat, without and with the recording.
    let mut runs: [Vec<(f64, f64, f64)>; 2] = [Vec::new(), Vec::new()];
    let mut file_mb = 0.0;
    for repeat in 0..REPEATS {
        for (recorded, results) in runs.iter_mut().enumerate() {
            let file = dir.join(format!("m{repeat}.mcap"));
            let options = SimOptions {
                world: WorldOptions {
                    seed: repeat,
                    ..WorldOptions::default()
                },
                tracking_s: Some(30.0),
                record: (recorded == 1).then(|| SimRecording {
                    recorder: RecorderOptions {
                        file: Some(file.clone()),
                        ..RecorderOptions::default()
                    },
                    config_files: config_files.clone(),
                }),
                ..SimOptions::default()
            };
            let outcome = simulate(&model, &registry, &options).expect("the mission flies");
            results.push((
                outcome.loop_step_p50_us,
                outcome.loop_step_p99_us,
                outcome.speedup,
            ));
            if recorded == 1 {
                file_mb = std::fs::metadata(&file).map_or(0.0, |m| m.len() as f64 / 1e6);
                let _ = std::fs::remove_file(&file);
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    let median = |values: &mut Vec<f64>| {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    };
    let mut summary = Vec::new();
    for (label, results) in ["without a recording (baseline)", "with --record"]
        .iter()
        .zip(&runs)
    {
        let mut p50: Vec<f64> = results.iter().map(|r| r.0).collect();
        let mut p99: Vec<f64> = results.iter().map(|r| r.1).collect();
        let mut speed: Vec<f64> = results.iter().map(|r| r.2).collect();
        let (p50, p99, speed) = (median(&mut p50), median(&mut p99), median(&mut speed));
        println!(
            "{label:<32} loop step p50 {p50:>7.0} µs, p99 {p99:>7.0} µs, {speed:>5.1}x real time (median of {REPEATS})"
        );
        summary.push((p50, p99, speed));
    }
    let (base, with) = (summary[0], summary[1]);
    println!(
        "recording: loop step p99 x{:.2}, p50 x{:.2}, speed x{:.2}; file {file_mb:.0} MB for one mission",
        with.1 / base.1,
        with.0 / base.0,
        with.2 / base.2
    );
}
