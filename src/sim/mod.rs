//! `qosrt sim`: the whole mission in the built-in simulator — the real runtime, the real tasks,
//! real MAVLink over UDP — in virtual time; one run's outcome, or a summary over many seeds.

use crate::check::EXIT_INVALID_CONFIG;
use crate::evaluate::{evaluate_hazards, evaluate_paths};
use crate::load::load;
use indicatif::{ProgressBar, ProgressStyle};
use runtime::record::ConfigFile;
use sitl::mission::{simulate, SimProgress, SimRecording};
use sitl::outcome::{SimOutcome, SimSummary};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

pub mod args;

use args::{SimArgs, EXIT_NOT_LANDED};

pub fn run(args: &SimArgs) -> ExitCode {
    if !(args.wind_m_s.is_finite() && (0.0..=30.0).contains(&args.wind_m_s)) {
        eprintln!(
            "error: --wind-m-s must be within [0, 30] m/s, found {}",
            args.wind_m_s
        );
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    if !(args.platform_speed_m_s.is_finite() && (0.0..=10.0).contains(&args.platform_speed_m_s)) {
        eprintln!(
            "error: --platform-speed-m-s must be within [0, 10] m/s, found {}",
            args.platform_speed_m_s
        );
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    if args.runs == Some(0) {
        eprintln!("error: --runs must be at least 1");
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    if args.csv.is_some() && !args.evaluate && args.merge.is_empty() {
        eprintln!(
            "error: --csv writes the landing evaluation's table: use it with --evaluate or --merge"
        );
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    if !args.merge.is_empty() {
        return crate::evaluate::run_merge(args);
    }
    let records = args.recording.record.is_some() || args.recording.foxglove.is_some();
    let several = args.evaluate || args.evaluate_hazards || args.evaluate_paths || args.serve;
    if records && (several || args.runs() > 1) {
        eprintln!("error: --record and --foxglove record one mission: leave out --runs, --evaluate*, --serve");
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    let Some((model, registry)) = load(&args.file, args.json) else {
        return ExitCode::from(EXIT_INVALID_CONFIG);
    };
    if args.serve {
        return crate::serve::run(&model, args);
    }
    if args.evaluate {
        return crate::evaluate::run(&model, &registry, args);
    }
    if args.evaluate_hazards {
        return evaluate_hazards(&model, &registry, args);
    }
    if args.evaluate_paths {
        return evaluate_paths(&model, &registry, args);
    }
    let recording = args.recording.options(&model.config);
    let options = |seed: u64| args.options(seed);
    let runs = args.runs();
    if runs == 1 {
        let mut options = options(args.seed);
        if let Some(recorder) = recording {
            match ConfigFile::collect(&args.file, &model.config) {
                Ok(config_files) => {
                    options.record = Some(SimRecording {
                        recorder,
                        config_files,
                    })
                }
                Err(error) => {
                    eprintln!("error: {error}");
                    return ExitCode::FAILURE;
                }
            }
        }
        let bar = mission_progress_bar();
        options.progress = Some(progress_sink(&bar));
        let outcome = simulate(&model, &registry, &options);
        bar.finish_and_clear();
        let outcome = match outcome {
            Ok(outcome) => outcome,
            Err(error) => {
                eprintln!("error: {error}");
                return ExitCode::FAILURE;
            }
        };
        crate::output::print_result(args.json, &outcome, report);
        if let Some(svg) = &args.svg {
            // The tracks and battery where asked, the QoS levels and battery beside it.
            let qos_path = qos_svg_path(svg);
            let plots = [
                (svg.clone(), crate::plot::mission_svg(&outcome)),
                (qos_path, crate::plot::qos_svg(&outcome)),
            ];
            for (path, plot) in plots {
                match plot.and_then(|doc| crate::plot::write_text(&path, &doc)) {
                    Ok(()) => eprintln!("wrote {}", path.display()),
                    Err(error) => {
                        // A write error names its file; a plot not drawn is named here.
                        match error {
                            crate::plot::PlotError::Write { .. } => eprintln!("error: {error}"),
                            _ => eprintln!("error: cannot write {}: {error}", path.display()),
                        }
                        return ExitCode::FAILURE;
                    }
                }
            }
        }
        return if outcome.landed_on_pad {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(EXIT_NOT_LANDED)
        };
    }
    let bar = ProgressBar::new(runs as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} runs, {elapsed} elapsed, ETA {eta}")
            .expect("a valid template"),
    );
    let mut outcomes = Vec::with_capacity(runs);
    for run in 0..runs as u64 {
        match simulate(&model, &registry, &options(args.seed + run)) {
            Ok(outcome) => outcomes.push(outcome),
            Err(error) => {
                bar.abandon();
                eprintln!("error: seed {}: {error}", args.seed + run);
                return ExitCode::FAILURE;
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let summary = SimSummary::of(&outcomes);
    let result = serde_json::json!({ "summary": summary, "runs": outcomes });
    crate::output::print_result(args.json, &result, |_| summary_report(&summary, args));
    if summary.success_rate > 0.0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_NOT_LANDED)
    }
}

/// The one mission's progress line on stderr (hidden when stderr is not a terminal): phase,
/// simulated time and speed, so a long mission shows it is flying.
fn mission_progress_bar() -> ProgressBar {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {msg}")
            .expect("a valid template")
            .progress_chars("=> "),
    );
    bar
}

fn progress_sink(bar: &ProgressBar) -> sitl::mission::ProgressSink {
    let bar = bar.clone();
    sitl::mission::ProgressSink(std::sync::Arc::new(move |p: &SimProgress| {
        bar.set_length(p.max_time_s.round() as u64);
        bar.set_position(p.time_s.round() as u64);
        bar.set_message(progress_message(p));
    }))
}

/// `phase tracking (2/3) · 312 s simulated · 21.4× real time`.
fn progress_message(p: &SimProgress) -> String {
    let phase = match &p.phase {
        Some((index, name)) => format!("phase {name} ({}/{})", index + 1, p.phase_count),
        None => "starting".to_string(),
    };
    let speed = if p.wall_s > 0.0 {
        format!("{:.1}× real time", p.time_s / p.wall_s)
    } else {
        "…".to_string()
    };
    format!("{phase} · {:.0} s simulated · {speed}", p.time_s)
}

/// Where the QoS plot goes beside `--svg PATH`: `PATH` with `-qos` before its extension.
fn qos_svg_path(svg: &Path) -> PathBuf {
    let stem = svg
        .file_stem()
        .map_or("mission".into(), |s| s.to_string_lossy());
    svg.with_file_name(format!("{stem}-qos.svg"))
}

fn fmt_opt(value: Option<f64>, unit: &str, digits: usize) -> String {
    value.map_or_else(|| "—".into(), |v| format!("{v:.digits$} {unit}"))
}

/// One run, for people.
pub fn report(outcome: &SimOutcome) -> String {
    let mut out = String::new();
    let verdict = match (outcome.landed_on_pad, outcome.touched_down) {
        (true, _) => "landed on the pad",
        (false, true) => "touched down OFF the pad",
        (false, false) => "did not land",
    };
    out += &format!("mission (seed {}): {verdict}\n", outcome.seed);
    out += &format!(
        "  touchdown error      {}\n",
        fmt_opt(outcome.touchdown_error_m, "m", 3)
    );
    if let (Some(speed), Some(tilt)) = (
        outcome.touchdown_vertical_speed_m_s,
        outcome.touchdown_tilt_deg,
    ) {
        out += &format!("  at contact           {speed:.2} m/s down, {tilt:.1}° of lean");
        if let Some(blind_s) = outcome.blind_before_contact_s {
            out += &format!(", the last vision fix {blind_s:.2} s before");
        }
        out += "\n";
    }
    out += &format!(
        "  time to land         {} (from the start of the landing phase)\n",
        fmt_opt(outcome.time_to_land_s, "s", 1)
    );
    out += &format!("  mission time         {:.1} s\n", outcome.mission_time_s);
    out += &format!(
        "  energy used          {:.2} Wh flight + {:.2} Wh companion\n",
        outcome.flight_energy_wh, outcome.companion_energy_wh
    );
    out += &format!(
        "  battery left         {:.1} %\n",
        100.0 * outcome.battery_left_fraction
    );
    out += &format!("  landing aborts       {}\n", outcome.landing_aborts);
    if let Some(l) = &outcome.localisation {
        out += &format!(
            "  localisation error   RMS {:.3} m, max {:.3} m horizontal; RMS {:.3} m vertical ({} samples while tracking)\n",
            l.horizontal_rms_m, l.horizontal_max_m, l.vertical_rms_m, l.samples
        );
    }
    out += &match outcome.hazards_seen {
        Some(seen) => format!(
            "  hazards seen         {seen}/{} within 2 m and rightly classified ({} frames on {}, {} false detections)\n",
            outcome.hazards_total,
            outcome.hazard_frames,
            outcome.hazard_backend.as_deref().unwrap_or("?"),
            outcome.hazard_false_detections
        ),
        None => format!(
            "  hazards seen         —/{} (no hazard detector ran)\n",
            outcome.hazards_total
        ),
    };
    if let Some([p50, p99, max]) = outcome.capture_to_setpoint_ms {
        out += &format!(
            "  capture → setpoint   p50 {p50:.1} ms, p99 {p99:.1} ms, max {max:.1} ms (frame capture to the setpoint answering it, {} fixes)\n",
            outcome.capture_to_setpoint_fixes
        );
    }
    if let Some([p50, p99, max]) = outcome.delivered_to_setpoint_ms {
        out += &format!(
            "  arrival → setpoint   p50 {p50:.1} ms, p99 {p99:.1} ms, max {max:.1} ms (the runtime's own share; the camera delivers on the loop's {:.0} ms tick)\n",
            sitl::mission::TICK_S * 1e3
        );
    }
    out += &format!("  simulated            {:.1}× real time\n", outcome.speedup);
    for skipped in &outcome.skipped_tasks {
        out += &format!("  not flown            task {skipped}\n");
    }
    for failed in &outcome.failed_tasks {
        out += &format!("  failed, flew on without it: task {failed}\n");
    }
    out += &format!("QoS changes ({}):\n", outcome.qos_changes.len());
    for change in &outcome.qos_changes {
        out += &format!("  {:>7.1} s  {}\n", change.time_s, change.description);
    }
    out += "events:\n";
    for (time_s, event) in &outcome.events {
        out += &format!("  {time_s:>7.1} s  {event}\n");
    }
    out
}

fn summary_report(summary: &SimSummary, args: &SimArgs) -> String {
    let mut out = format!(
        "{} runs, {} world, path {}, wind {} m/s{}, tractor {} m/s\n",
        summary.runs,
        if args.ideal { "ideal" } else { "realistic" },
        args.path,
        args.wind_m_s,
        if args.dryden { " (Dryden)" } else { "" },
        args.platform_speed_m_s
    );
    out += &format!(
        "  success rate         {:.1} %\n",
        100.0 * summary.success_rate
    );
    out += &format!(
        "  touchdown error      p50 {}, p95 {}\n",
        fmt_opt(summary.touchdown_error_p50_m, "m", 3),
        fmt_opt(summary.touchdown_error_p95_m, "m", 3)
    );
    out += &format!(
        "  time to land p50     {}\n",
        fmt_opt(summary.time_to_land_p50_s, "s", 1)
    );
    out += &format!(
        "  energy (mean)        {:.2} Wh, of which companion {:.2} Wh\n",
        summary.energy_mean_wh, summary.companion_energy_mean_wh
    );
    out
}
