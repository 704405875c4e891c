//! What recording costs the loop: the reference mission (tracking 30 s, every task, the
//! realistic world) flown without a recording — the baseline — and with one under each frame
//! policy (`--record`: every frame in the compact codec, telemetry, topic and decision to a
//! zstd MCAP file; every frame as PNG; only the frames a task read; no frames), alternated in
//! the same run. It prints the runtime
//! loop's step time (p50, p99), the simulation's speed, the ratios to the baseline, and the
//! file's megabytes per simulated minute.
//!
//! `cargo bench -p sitl --bench record`

use runtime::catalog::PluginCatalog;
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use runtime::record::{ConfigFile, FrameCodec, FramePolicy, RecorderOptions};
use sim::world::WorldOptions;
use sitl::mission::{simulate, SimOptions, SimRecording};
use std::path::Path;

const REPEATS: u64 = 7;

fn main() {
    let registry = builtin_registry().expect("the built-in plugins register");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("the reference config");
    let model = load_mission_model(&loaded).expect("the reference power model");
    let dir = std::env::temp_dir().join(format!("qosrt-record-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch folder");
    let config_files = ConfigFile::collect(&path, &model.config).expect("the config files");
    // What each run records: nothing (the baseline), then each frame policy.
    // The baseline again at the end: its ratio to the first is the measurement's own noise.
    let policies: [(&str, Option<(FramePolicy, FrameCodec)>); 6] = [
        ("without a recording (baseline)", None),
        (
            "--record, every frame (compact)",
            Some((FramePolicy::Every, FrameCodec::Compact)),
        ),
        (
            "--record-codec png",
            Some((FramePolicy::Every, FrameCodec::Png)),
        ),
        (
            "--record-frames consumed",
            Some((FramePolicy::Consumed, FrameCodec::Compact)),
        ),
        (
            "--record-frames none",
            Some((FramePolicy::None, FrameCodec::Compact)),
        ),
        ("without a recording, again", None),
    ];
    // (p50 µs, p99 µs, speed ×, MB per simulated minute) per repeat, for each.
    let mut runs: Vec<Vec<(f64, f64, f64, f64)>> = vec![Vec::new(); policies.len()];
    for repeat in 0..REPEATS {
        for ((_, policy), results) in policies.iter().zip(&mut runs) {
            let file = dir.join(format!("m{repeat}.mcap"));
            let options = SimOptions {
                world: WorldOptions {
                    seed: repeat,
                    ..WorldOptions::default()
                },
                tracking_s: Some(30.0),
                record: policy.map(|(frames, codec)| SimRecording {
                    recorder: RecorderOptions {
                        file: Some(file.clone()),
                        frames,
                        codec,
                        ..RecorderOptions::default()
                    },
                    config_files: config_files.clone(),
                }),
                ..SimOptions::default()
            };
            let outcome = simulate(&model, &registry, &options).expect("the mission flies");
            let mb_per_min = std::fs::metadata(&file).map_or(0.0, |m| m.len() as f64 / 1e6)
                / (outcome.mission_time_s / 60.0);
            let _ = std::fs::remove_file(&file);
            results.push((
                outcome.loop_step_p50_us,
                outcome.loop_step_p99_us,
                outcome.speedup,
                mb_per_min,
            ));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    // Each policy's runs against the baseline's run of the same repeat: paired, so the
    // machine's slower and faster spells fall on both.
    let median = |mut values: Vec<f64>| {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    };
    let baseline = &runs[0];
    for (index, ((label, policy), results)) in policies.iter().zip(&runs).enumerate() {
        let of =
            |pick: fn(&(f64, f64, f64, f64)) -> f64| median(results.iter().map(pick).collect());
        let (p50, p99, speed, mb_per_min) = (of(|r| r.0), of(|r| r.1), of(|r| r.2), of(|r| r.3));
        let ratio = |pick: fn(&(f64, f64, f64, f64)) -> f64| {
            median(
                results
                    .iter()
                    .zip(baseline)
                    .map(|(r, b)| pick(r) / pick(b))
                    .collect(),
            )
        };
        let ratios = match (index, policy) {
            (0, _) => String::new(),
            (_, Some(_)) => format!(
                "; p99 x{:.2}, speed x{:.2}, {mb_per_min:.1} MB per simulated minute",
                ratio(|r| r.1),
                ratio(|r| r.2)
            ),
            (_, None) => format!("; p99 x{:.2}, speed x{:.2}", ratio(|r| r.1), ratio(|r| r.2)),
        };
        println!(
            "{label:<32} loop step p50 {p50:>6.0} µs, p99 {p99:>6.0} µs, {speed:>5.1}x real time{ratios} (median of {REPEATS})"
        );
    }
}
