//! What recording costs the loop: the reference mission (tracking 30 s, every task, the
//! realistic world) flown with a recording under each frame policy (`--record`: every frame in
//! the compact codec, telemetry, topic and decision to a zstd MCAP file; every frame as PNG;
//! only the frames a task read; no frames), each between two flights without one (the
//! baseline), in the same run. It prints the runtime loop's step time (p50, p99), the
//! simulation's speed, the ratios to the baselines either side, and the file's megabytes per
//! simulated minute.
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

/// Fifteen: on this 2-core machine one paired ratio moves by ±8 % from repeat to repeat.
const REPEATS: u64 = 15;

fn main() {
    let registry = builtin_registry().expect("the built-in plugins register");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("the reference config");
    let model = load_mission_model(&loaded).expect("the reference power model");
    let dir = std::env::temp_dir().join(format!("qosrt-record-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch folder");
    let config_files = ConfigFile::collect(&path, &model.config).expect("the config files");
    // What each run records: each frame policy, every one between two runs without a
    // recording (the baseline), so that a drift of the machine's speed within a repeat falls
    // on both sides of it.
    let policies: [(&str, FramePolicy, FrameCodec); 4] = [
        (
            "--record, every frame (compact)",
            FramePolicy::Every,
            FrameCodec::Compact,
        ),
        ("--record-codec png", FramePolicy::Every, FrameCodec::Png),
        (
            "--record-frames consumed",
            FramePolicy::Consumed,
            FrameCodec::Compact,
        ),
        (
            "--record-frames none",
            FramePolicy::None,
            FrameCodec::Compact,
        ),
    ];
    let fly = |seed: u64, record: Option<(FramePolicy, FrameCodec)>| {
        let file = dir.join(format!("m{seed}.mcap"));
        let options = SimOptions {
            world: WorldOptions {
                seed,
                ..WorldOptions::default()
            },
            tracking_s: Some(30.0),
            record: record.map(|(frames, codec)| SimRecording {
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
        Run {
            p50_us: outcome.loop_step_p50_us,
            p99_us: outcome.loop_step_p99_us,
            speed: outcome.speedup,
            mb_per_min,
        }
    };
    // Per repeat: the baselines (one more than the policies), and each policy's run.
    let mut baselines: Vec<Vec<Run>> = Vec::new();
    let mut recorded: Vec<Vec<Run>> = vec![Vec::new(); policies.len()];
    for repeat in 0..REPEATS {
        let mut around = vec![fly(repeat, None)];
        for ((_, frames, codec), runs) in policies.iter().zip(&mut recorded) {
            runs.push(fly(repeat, Some((*frames, *codec))));
            around.push(fly(repeat, None));
        }
        baselines.push(around);
    }
    let _ = std::fs::remove_dir_all(&dir);
    let median = |mut values: Vec<f64>| {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    };
    // A run against the mean of the two runs either side of it in its repeat, one ratio a
    // repeat.
    let ratios =
        |run: &dyn Fn(usize) -> Run, sides: [&dyn Fn(usize) -> Run; 2], pick: fn(&Run) -> f64| {
            (0..REPEATS as usize)
                .map(|r| pick(&run(r)) / ((pick(&sides[0](r)) + pick(&sides[1](r))) / 2.0))
                .collect::<Vec<f64>>()
        };
    // The median and the quartiles: how far one repeat's ratio strays.
    let spread = |mut ratios: Vec<f64>| {
        ratios.sort_by(f64::total_cmp);
        let at = |q: f64| ratios[((ratios.len() - 1) as f64 * q).round() as usize];
        format!(
            "x{:.2} (quartiles {:.2}–{:.2})",
            at(0.5),
            at(0.25),
            at(0.75)
        )
    };
    let all_baselines: Vec<Run> = baselines.iter().flatten().copied().collect();
    let of = |runs: &[Run], pick: fn(&Run) -> f64| median(runs.iter().map(pick).collect());
    println!(
        "{:<32} loop step p50 {:>6.0} µs, p99 {:>6.0} µs, {:>5.1}x real time (median of {})",
        "without a recording (baseline)",
        of(&all_baselines, |r| r.p50_us),
        of(&all_baselines, |r| r.p99_us),
        of(&all_baselines, |r| r.speed),
        all_baselines.len()
    );
    // The measurement's own noise: the middle baseline against the ones two runs away.
    let middle = policies.len() / 2;
    let noise = ratios(
        &|r| baselines[r][middle],
        [&|r| baselines[r][middle - 1], &|r| baselines[r][middle + 1]],
        |r| r.speed,
    );
    println!(
        "{:<32} speed {}",
        "baseline against its neighbours",
        spread(noise)
    );
    for (index, ((label, _, _), runs)) in policies.iter().zip(&recorded).enumerate() {
        let sides: [&dyn Fn(usize) -> Run; 2] =
            [&|r| baselines[r][index], &|r| baselines[r][index + 1]];
        println!(
            "{label:<32} loop step p50 {:>6.0} µs, p99 {:>6.0} µs, {:>5.1}x real time; p99 x{:.2}, \
             speed {}, {:.1} MB per simulated minute (median of {REPEATS})",
            of(runs, |r| r.p50_us),
            of(runs, |r| r.p99_us),
            of(runs, |r| r.speed),
            median(ratios(&|r| runs[r], sides, |r| r.p99_us)),
            spread(ratios(&|r| runs[r], sides, |r| r.speed)),
            of(runs, |r| r.mb_per_min),
        );
    }
}

/// One mission's figures.
#[derive(Clone, Copy)]
struct Run {
    p50_us: f64,
    p99_us: f64,
    speed: f64,
    mb_per_min: f64,
}
