//! `qosrt run --dry-run`: config → plugin registry → scheduler → governor, on synthetic inputs
//! for a few seconds, then the per-task statistics.

use crate::check::{report_failure, EXIT_INVALID_CONFIG};
use runtime::config::load_file;
use runtime::dry_run::{dry_run, DryRunOptions, DryRunReport};
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use std::path::Path;
use std::process::ExitCode;
use std::time::Duration;

pub fn run(file: &Path, duration_s: f64, phase: Option<String>) -> ExitCode {
    if !(duration_s.is_finite() && duration_s > 0.0 && duration_s <= 3600.0) {
        eprintln!("error: --duration-s must be within (0, 3600] s, found {duration_s}");
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    let registry = match builtin_registry() {
        Ok(registry) => registry,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    };
    // Checked against the plugins this binary really has, so a plugin it lacks is a located
    // error before anything starts.
    let loaded = match load_file(file, &registry.catalog()) {
        Ok(loaded) => loaded,
        Err(failure) => {
            report_failure(&failure, false);
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    let model = match load_mission_model(&loaded) {
        Ok(model) => model,
        Err(reports) => {
            for report in &reports {
                report_failure(report, false);
            }
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    let options = DryRunOptions {
        duration: Duration::from_secs_f64(duration_s),
        phase,
    };
    match dry_run(&model, &registry, &options) {
        Ok(report) => {
            print!("{}", table(&report));
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::FAILURE
        }
    }
}

fn table(report: &DryRunReport) -> String {
    let mut out = format!(
        "dry run of phase `{}` for {:.1} s: {} synthetic frames, {} battery samples\n\n",
        report.phase, report.wall_s, report.frames_published, report.telemetry_samples
    );
    out += &format!(
        "{:<10} {:>5} {:>10} {:>11} {:>8} {:>7} {:>8} {:>8} {:>10} {:>10}  {}\n",
        "task",
        "level",
        "period",
        "activations",
        "overruns",
        "skipped",
        "failures",
        "restarts",
        "step p50",
        "step p99",
        "health"
    );
    for (stats, in_phase) in &report.tasks {
        out += &format!(
            "{:<10} {:>5} {:>7.1} ms {:>11} {:>8} {:>7} {:>8} {:>8} {:>7.1} µs {:>7.1} µs  {:?}{}\n",
            stats.name,
            stats.level,
            stats.period_ms,
            stats.activations,
            stats.overruns,
            stats.skipped,
            stats.failures,
            stats.restarts,
            stats.step_time.p50_us,
            stats.step_time.p99_us,
            stats.health,
            if *in_phase { "" } else { " (not in this phase)" }
        );
    }
    let latency = &report.frame_to_setpoint;
    if latency.count > 0 {
        out += &format!(
            "\nframe to setpoint (the scheduler and the tasks, on the bus): p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms over {} frames\n",
            latency.p50_us * 1e-3,
            latency.p99_us * 1e-3,
            latency.max_us * 1e-3,
            latency.count
        );
    }
    if report.governor_events.is_empty() {
        out += "\ngovernor: kept the planned levels\n";
    } else {
        out += "\ngovernor:\n";
        for event in &report.governor_events {
            out += &format!("  {event}\n");
        }
    }
    out
}
