//! Frame to setpoint through the real scheduler and bus (`cargo bench -p runtime --bench
//! frame_to_setpoint`).
//!
//! The reference mission's tasks (the real plugins: marker detection, Kalman tracker, landing
//! guidance, and the hazard CNN on the CPU loading the other core) run in real time in a dry run
//! (`qosrt run --dry-run`: rendered frames of the pad at 10 fps, a hovering vehicle over
//! MAVLink), the landing chain pinned to core 0. Measured on the bus: from a frame's
//! publication to the first landing setpoint computed from its fix. Twice in the same run: the
//! chain on its periods (the baseline) and triggered by its inputs, as `qos.toml` has it.
//!
//! `QOSRT_BENCH_SECS` sets each run's length (default 20 s).

use runtime::config::{load_file, TaskTrigger};
use runtime::dry_run::{dry_run, DryRunOptions};
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use runtime::scheduler::DurationSummary;
use std::path::Path;
use std::time::Duration;

const LANDING_CHAIN: [&str; 3] = ["detection", "tracking", "landing"];

fn main() {
    let seconds: f64 = std::env::var("QOSRT_BENCH_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20.0);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let catalog = runtime::catalog::PluginCatalog::builtin();
    let loaded = load_file(&path, &catalog).expect("qos.toml loads");
    let mut triggered = load_mission_model(&loaded).expect("its power model loads");
    for task in &mut triggered.config.tasks {
        if LANDING_CHAIN.contains(&task.name.as_str()) {
            task.cores = vec![0];
        }
    }
    let mut periodic = triggered.clone();
    for task in &mut periodic.config.tasks {
        task.trigger = TaskTrigger::Period;
        task.max_idle_ms = None;
    }
    let registry = builtin_registry().expect("the built-in plugins register");
    let options = DryRunOptions {
        duration: Duration::from_secs_f64(seconds),
        phase: Some("tracking".into()),
    };
    let run = |name: &str, model| {
        let report = dry_run(model, &registry, &options).expect("the dry run runs");
        let latency = report.frame_to_setpoint;
        println!(
            "{name:<10} frame to setpoint p50 {:>6.2} ms  p99 {:>6.2} ms  max {:>6.2} ms  ({} of {} frames)",
            latency.p50_us * 1e-3,
            latency.p99_us * 1e-3,
            latency.max_us * 1e-3,
            latency.count,
            report.frames_published
        );
        latency
    };
    println!("{seconds} s each, the landing chain on core 0, the hazard CNN (CPU) beside it");
    let before: DurationSummary = run("periodic", &periodic);
    let after: DurationSummary = run("triggered", &triggered);
    println!(
        "triggered / periodic: p50 ×{:.3}, p99 ×{:.3}",
        after.p50_us / before.p50_us,
        after.p99_us / before.p99_us
    );
}
