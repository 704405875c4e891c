//! `qosrt sim`: the whole mission in the built-in simulator — the real runtime, the real tasks,
//! real MAVLink over UDP — in virtual time; one run's outcome, or a summary over many seeds.

use crate::check::{report_failure, EXIT_INVALID_CONFIG};
use indicatif::{ProgressBar, ProgressStyle};
use runtime::config::load_file;
use runtime::energy::{load_mission_model, MissionModel};
use runtime::plugins::builtin_registry;
use runtime::record::ConfigFile;
use runtime::registry::PluginRegistry;
use sim::outcome::{SimOutcome, SimSummary};
use sim::realism::Realism;
use sim::tractor::PathKind;
use sitl::mission::{simulate, Faults, SimOptions, SimProgress, SimRecording, WindKind};
use sitl::mission::{AutopilotKind, RealAutopilot};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// `qosrt sim`'s arguments.
#[derive(clap::Args)]
pub struct SimArgs {
    /// The mission config.
    #[arg(default_value = "qos.toml")]
    pub file: PathBuf,
    /// The tractor's path: straight, s-shape, rectangle, circle, figure8, turn90, turn180.
    #[arg(long, default_value = "straight")]
    pub path: PathKind,
    /// Mean wind speed (the seed's gust model).
    #[arg(
        long = "wind-m-s",
        alias = "wind-mps",
        default_value_t = 0.0,
        value_name = "M_S"
    )]
    pub wind_m_s: f64,
    /// Dryden turbulence around the mean wind instead of the seed's gusts.
    #[arg(long)]
    pub dryden: bool,
    /// The tractor's speed.
    #[arg(
        long = "platform-speed-m-s",
        alias = "platform-speed-mps",
        default_value_t = 1.5,
        value_name = "M_S"
    )]
    pub platform_speed_m_s: f64,
    /// Random seed (wind, camera noise, hazards); the same seed flies the same mission.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Fly this many seeds (seed, seed + 1, ...) and print a summary; with an evaluation, seeds
    /// per cell (default: 20 for --evaluate, 1 for the others).
    #[arg(long, value_name = "N")]
    pub runs: Option<usize>,
    /// Fly the ideal world (the autopilot hands out the truth, frames arrive at once, a still
    /// pad) instead of the realistic one.
    #[arg(long, conflicts_with = "serve")]
    pub ideal: bool,
    /// Override the tracking phase's duration (s), e.g. to evaluate landings.
    #[arg(long, value_name = "S")]
    pub tracking_s: Option<f64>,
    /// Hold a task at one of its levels, by knob value: --fix detection=10 (repeatable).
    #[arg(long = "fix", value_name = "TASK=VALUE", value_parser = parse_fixed_level)]
    pub fixed_levels: Vec<(String, f64)>,
    /// Print the outcome as JSON.
    #[arg(long)]
    pub json: bool,
    /// Draw the vehicle's and the tractor's tracks and the battery over time as SVG.
    #[arg(long, value_name = "PATH")]
    pub svg: Option<PathBuf>,
    /// Evaluate landings: world {realistic, ideal} × landing-marker rate × wind {0, 8 and 12 m/s
    /// gusts, 12 m/s Dryden} × path {straight, figure8, turn180} with the tractor at 1.5 m/s, and
    /// per world and rate the tractor at 3 m/s on turn180 in 8 m/s gusts; --runs seeds per cell
    /// (default 20; tracking 15 s unless --tracking-s says otherwise), as a table.
    #[arg(long, conflicts_with_all = ["path", "wind_m_s", "dryden", "platform_speed_m_s", "svg"])]
    pub evaluate: bool,
    /// The evaluation's worlds: realistic, ideal (default both; --ideal: ideal only).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        requires = "evaluate",
        conflicts_with = "ideal"
    )]
    pub worlds: Vec<crate::evaluate::World>,
    /// The evaluation's landing-marker rates, among the config's levels (default all).
    #[arg(
        long,
        value_name = "FPS,…",
        value_delimiter = ',',
        requires = "evaluate"
    )]
    pub rates: Vec<f64>,
    /// The evaluation's winds: 0, 8, 12 (m/s, gusts), dryden12 (default all).
    #[arg(long, value_name = "WIND,…", value_delimiter = ',', value_parser = crate::evaluate::parse_wind, requires = "evaluate")]
    pub winds: Vec<crate::evaluate::GridWind>,
    /// The evaluation's paths: straight, figure8, turn180 (default all).
    #[arg(long, value_name = "PATH,…", value_delimiter = ',', value_parser = crate::evaluate::parse_grid_path, requires = "evaluate")]
    pub paths: Vec<PathKind>,
    /// Fly only shard I of N of the evaluation (the missions k with k mod N = I − 1) and write
    /// its runs as a shard file (to --out, else stdout) for --merge.
    #[arg(long, value_name = "I/N", value_parser = crate::evaluate::parse_shard, requires = "evaluate")]
    pub shard: Option<crate::evaluate::Shard>,
    /// Write the evaluation's runs as a shard file (the whole evaluation as shard 1/1).
    #[arg(long, value_name = "PATH", requires = "evaluate")]
    pub out: Option<PathBuf>,
    /// Also write the evaluation's table as CSV, one row per cell.
    #[arg(long, value_name = "PATH", conflicts_with = "shard")]
    pub csv: Option<PathBuf>,
    /// Fly nothing: join the shard files of a sweep (`--evaluate --shard I/N --out FILE`) into
    /// the table the unsharded evaluation prints.
    #[arg(long, value_name = "SHARD.json", num_args = 1.., conflicts_with_all = ["evaluate", "evaluate_hazards", "evaluate_paths", "serve", "ideal", "runs", "seed", "svg", "tracking_s", "fixed_levels", "path", "wind_m_s", "dryden", "platform_speed_m_s"])]
    pub merge: Vec<PathBuf>,
    /// Evaluate hazard detection as the seed scored it (a hazard seen = a detection of its class
    /// within 2 m): every hazard-CNN rate × wind {0, 8, 12} m/s on the straight path, --runs
    /// seeds per cell (tracking 200 s, 32 hazards beside the track, unless --tracking-s says
    /// otherwise), as a table.
    #[arg(long, conflicts_with = "evaluate")]
    pub evaluate_hazards: bool,
    /// Seed 000's simulated trials (§3.1): path {straight, s-shape, rectangle, circle, figure8}
    /// × UGV speed {0.2, 0.5, 0.8} m/s, following at the landing task's IH, --runs seeds per
    /// cell (tracking 30 s, the rectangle's until past its first corner, unless --tracking-s
    /// says otherwise; the marker detector at its top rate), with the localisation error while
    /// tracking, the touchdown error and the success rate, as a table.
    #[arg(long, conflicts_with_all = ["evaluate", "evaluate_hazards"])]
    pub evaluate_paths: bool,
    /// Serve the world as its own process on the wall clock, standing in for PX4 SITL + Gazebo:
    /// MAVLink to UDP --mavlink-port, the camera as RTP/H.264 to UDP --video-port; fly it with
    /// `qosrt run --mavlink udpin:0.0.0.0:14540 --camera rtp-h264:5600 --control`.
    #[arg(long, conflicts_with_all = ["evaluate", "evaluate_hazards", "evaluate_paths", "runs", "svg", "fixed_levels", "tracking_s"])]
    pub serve: bool,
    /// Who flies the served vehicle: sim (the world's own), px4-sih[:INSTANCE] (PX4 SITL's
    /// SIH, whose true pose the world reads on UDP 19410+INSTANCE), px4-hil[:INSTANCE] (a PX4
    /// you started with `-m none_iris`, the world its HIL simulator on TCP 4560+INSTANCE) or
    /// ardupilot-json[:INSTANCE] (an ArduCopter you started with `-M JSON:127.0.0.1`, the world
    /// its physics on UDP 9002+10·INSTANCE). A real autopilot's MAVLink is its own: `qosrt run
    /// --mavlink udpin:0.0.0.0:14540+INSTANCE` (PX4) or `tcpout:127.0.0.1:5760+10·INSTANCE`
    /// (ArduPilot).
    #[arg(long, default_value = "sim", requires = "serve")]
    pub vehicle: sitl::serve::ServeVehicle,
    /// The UDP port on 127.0.0.1 the simulated autopilot sends MAVLink to.
    #[arg(long, default_value_t = 14540, requires = "serve")]
    pub mavlink_port: u16,
    /// The UDP port on 127.0.0.1 the camera's RTP/H.264 stream goes to.
    #[arg(long, default_value_t = 5600, requires = "serve")]
    pub video_port: u16,
    /// Serve MAVLink only, no camera stream.
    #[arg(long, requires = "serve")]
    pub no_video: bool,
    /// Where the tractor waits, metres north and east of the take-off point (give `qosrt run`
    /// the same).
    #[arg(long, value_name = "N,E", value_parser = crate::parse_north_east, default_value = "15,0", requires = "serve")]
    pub meeting_point_ne_m: [f64; 2],
    /// The served world stops after this long.
    #[arg(long, value_name = "S", default_value_t = 600.0, requires = "serve")]
    pub max_time_s: f64,
    /// Who flies the vehicle: builtin (the world's own PX4-like autopilot, fast and
    /// deterministic), px4 (a real PX4 with a `none_iris`-style airframe, the world its HIL
    /// simulator on TCP 4560+i) or ardupilot (a real ArduPilot Copter, the world its JSON
    /// physics backend on UDP 9002+10i). The runtime talks to it over MAVLink as on a drone.
    #[arg(long, default_value = "builtin", conflicts_with = "serve")]
    pub autopilot: sitl::mission::AutopilotKind,
    /// The command that starts one autopilot instance, `{i}` replaced by its number, e.g.
    /// `'../shared/px4-sitl/start -i {i} -m none_iris'` or `make px4_sitl none_iris`; without
    /// it qosrt waits for an autopilot you started (instance --autopilot-instance).
    #[arg(long, value_name = "CMD")]
    pub autopilot_cmd: Option<String>,
    /// The real autopilot's instance number (with --autopilot-cmd, the first of one per worker).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub autopilot_instance: u8,
    #[command(flatten)]
    pub recording: crate::replay::RecordArgs,
}

impl SimArgs {
    /// One mission as the arguments describe it, flown with `seed`.
    pub(crate) fn options(&self, seed: u64) -> SimOptions {
        SimOptions {
            path: self.path,
            wind_speed_m_s: self.wind_m_s,
            wind_kind: if self.dryden {
                WindKind::Dryden
            } else {
                WindKind::Gusts
            },
            platform_speed_m_s: self.platform_speed_m_s,
            seed,
            tracking_s: self.tracking_s,
            fixed_levels: self.fixed_levels.clone(),
            faults: Faults::default(),
            record_track: self.svg.is_some(),
            realism: if self.ideal {
                Realism::ideal()
            } else {
                Realism::default()
            },
            autopilot: (self.autopilot != AutopilotKind::Builtin).then(|| RealAutopilot {
                kind: self.autopilot,
                instance: self.autopilot_instance,
                command: self.autopilot_cmd.clone(),
                connect_timeout: std::time::Duration::from_secs(60),
            }),
            ..SimOptions::default()
        }
    }

    /// Seeds to fly: of a plain run, or per cell of the hazard and path evaluations (1 unless
    /// --runs says otherwise; --evaluate has its own default).
    pub(crate) fn runs(&self) -> usize {
        self.runs.unwrap_or(1)
    }
}

/// Exit status when the mission did not land on the pad (or no run of many did).
pub const EXIT_NOT_LANDED: u8 = 4;

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
    let recording = args.recording.options();
    let several = args.evaluate || args.evaluate_hazards || args.evaluate_paths || args.serve;
    if recording.is_some() && (several || args.runs() > 1) {
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
        if args.json {
            println!(
                "{}",
                serde_json::to_string_pretty(&outcome).expect("outcomes serialise")
            );
        } else {
            print!("{}", report(&outcome));
        }
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
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "summary": summary,
                "runs": outcomes,
            }))
            .expect("outcomes serialise")
        );
    } else {
        print!("{}", summary_report(&summary, args));
    }
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

fn load(file: &Path, json: bool) -> Option<(MissionModel, PluginRegistry)> {
    let registry = match builtin_registry() {
        Ok(registry) => registry,
        Err(error) => {
            eprintln!("error: {error}");
            return None;
        }
    };
    Some((load_model(file, json)?, registry))
}

/// The config at `file` and everything it refers to, its mistakes reported located. The full
/// catalogue: a task whose plugin this build lacks is reported and flown without.
pub(crate) fn load_model(file: &Path, json: bool) -> Option<MissionModel> {
    let loaded = match load_file(file, &runtime::catalog::PluginCatalog::builtin()) {
        Ok(loaded) => loaded,
        Err(failure) => {
            report_failure(&failure, json);
            return None;
        }
    };
    match load_mission_model(&loaded) {
        Ok(model) => Some(model),
        Err(reports) => {
            for report in &reports {
                report_failure(report, json);
            }
            None
        }
    }
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
        out += &format!("  at contact           {speed:.2} m/s down, {tilt:.1}° of lean\n");
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

/// Flies `args.runs` seeds (default 1, from `args.seed`) of every cell, with the options `options_of(cell,
/// seed)`; the outcomes grouped by cell. A mission that cannot be flown is reported, and ends
/// the evaluation.
fn fly_cells<C>(
    model: &MissionModel,
    registry: &PluginRegistry,
    cells: &[C],
    args: &SimArgs,
    options_of: impl Fn(&C, u64) -> SimOptions,
) -> Result<Vec<Vec<SimOutcome>>, ()> {
    let mut jobs = Vec::with_capacity(cells.len() * args.runs());
    for (index, cell) in cells.iter().enumerate() {
        for run in 0..args.runs() as u64 {
            jobs.push((index, options_of(cell, args.seed + run)));
        }
    }
    fly_all(model, registry, jobs, cells.len()).map_err(|error| eprintln!("error: {error}"))
}

/// Flies every job on all cores with a progress bar (on stderr, hidden when that is no
/// terminal); the outcomes grouped by the job's cell, each cell's in the order of their seeds
/// whatever order the workers finished in, so that statistics summed over them come out the same
/// on every run.
pub(crate) fn fly_all(
    model: &MissionModel,
    registry: &PluginRegistry,
    jobs: Vec<(usize, SimOptions)>,
    cells: usize,
) -> Result<Vec<Vec<SimOutcome>>, String> {
    let bar = ProgressBar::new(jobs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} missions, {elapsed} elapsed, ETA {eta}")
            .expect("a valid template"),
    );
    // A real autopilot per worker, each its own instance (its own ports); one the user started
    // serves one mission at a time.
    let real = jobs.first().and_then(|(_, o)| o.autopilot.clone());
    let workers = match &real {
        Some(autopilot) if autopilot.command.is_none() => 1,
        _ => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(vec![Vec::new(); cells]);
    let failure = std::sync::Mutex::new(None);
    std::thread::scope(|scope| {
        for worker in 0..workers {
            let (next, results, failure, bar, jobs) = (&next, &results, &failure, &bar, &jobs);
            scope.spawn(move || loop {
                let index = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some((cell, options)) = jobs.get(index) else {
                    break;
                };
                let mut options = options.clone();
                if let Some(autopilot) = options.autopilot.as_mut() {
                    autopilot.instance += worker as u8;
                }
                match simulate(model, registry, &options) {
                    Ok(outcome) => results.lock().expect("no worker panics")[*cell].push(outcome),
                    Err(error) => {
                        *failure.lock().expect("no worker panics") =
                            Some(format!("seed {}: {error}", options.seed));
                        break;
                    }
                }
                bar.inc(1);
            });
        }
    });
    bar.finish_and_clear();
    if let Some(error) = failure.into_inner().expect("no worker panics") {
        return Err(error);
    }
    let mut results = results.into_inner().expect("no worker panics");
    for outcomes in &mut results {
        outcomes.sort_by_key(|o| o.seed);
    }
    Ok(results)
}

/// The tracking phase of a hazard evaluation: 300 m of track at 1.5 m/s, room for the seed's 32
/// hazards.
const HAZARD_EVALUATION_TRACKING_S: f64 = 200.0;

/// The seed's hazard experiment: every hazard-CNN rate × wind, `args.runs` seeds per cell.
fn evaluate_hazards(model: &MissionModel, registry: &PluginRegistry, args: &SimArgs) -> ExitCode {
    let Some(hazard) = model.config.tasks.iter().find(|t| t.plugin == "hazard_cnn") else {
        eprintln!("error: --evaluate-hazards needs a hazard_cnn task in the config");
        return ExitCode::from(EXIT_INVALID_CONFIG);
    };
    let mut cells = Vec::new();
    for &rate in &hazard.levels {
        for wind_m_s in [0.0, 8.0, 12.0] {
            cells.push((rate, wind_m_s));
        }
    }
    let results = fly_cells(model, registry, &cells, args, |&(rate, wind_m_s), seed| {
        let mut fixed_levels = args.fixed_levels.clone();
        fixed_levels.push((hazard.name.clone(), rate));
        SimOptions {
            wind_speed_m_s: wind_m_s,
            tracking_s: Some(args.tracking_s.unwrap_or(HAZARD_EVALUATION_TRACKING_S)),
            fixed_levels,
            record_track: false,
            ..args.options(seed)
        }
    });
    let Ok(results) = results else {
        return ExitCode::FAILURE;
    };
    let rows: Vec<HazardRow> = cells
        .iter()
        .zip(&results)
        .map(|(&(rate_fps, wind_m_s), outcomes)| HazardRow::of(rate_fps, wind_m_s, outcomes))
        .collect();
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).expect("rows serialise")
        );
    } else {
        print!("{}", hazard_table(&rows, args));
    }
    ExitCode::SUCCESS
}

/// One cell of the hazard evaluation, over its seeds.
#[derive(serde::Serialize)]
struct HazardRow {
    rate_fps: f64,
    wind_m_s: f64,
    runs: usize,
    seen: usize,
    total: usize,
    false_detections_per_run: f64,
    frames_per_run: f64,
    companion_energy_mean_wh: f64,
    landed_fraction: f64,
    backend: String,
}

impl HazardRow {
    fn of(rate_fps: f64, wind_m_s: f64, outcomes: &[SimOutcome]) -> Self {
        let runs = outcomes.len();
        let per_run = |f: &dyn Fn(&SimOutcome) -> f64| {
            outcomes.iter().map(f).sum::<f64>() / runs.max(1) as f64
        };
        Self {
            rate_fps,
            wind_m_s,
            runs,
            seen: outcomes.iter().filter_map(|o| o.hazards_seen).sum(),
            total: outcomes.iter().map(|o| o.hazards_total).sum(),
            false_detections_per_run: per_run(&|o| o.hazard_false_detections as f64),
            frames_per_run: per_run(&|o| o.hazard_frames as f64),
            companion_energy_mean_wh: per_run(&|o| o.companion_energy_wh),
            landed_fraction: per_run(&|o| f64::from(u8::from(o.landed_on_pad))),
            backend: outcomes
                .iter()
                .find_map(|o| o.hazard_backend.clone())
                .unwrap_or_else(|| "none".into()),
        }
    }
}

fn hazard_table(rows: &[HazardRow], args: &SimArgs) -> String {
    let mut out = format!(
        "{} seeds per cell from seed {}, straight path, tractor at {} m/s, {} wind\n\n",
        args.runs(),
        args.seed,
        args.platform_speed_m_s,
        if args.dryden { "Dryden" } else { "gust" }
    );
    out += "| hazard CNN rate (fps) | wind (m/s) | hazards seen | seen per run | false detections per run | frames per run | companion energy (Wh) | landed |\n";
    out += "| --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for r in rows {
        let share = if r.total == 0 {
            0.0
        } else {
            r.seen as f64 / r.total as f64
        };
        out += &format!(
            "| {} | {} | {}/{} ({:.0} %) | {:.1} of {:.0} | {:.1} | {:.0} | {:.3} | {:.0} % |\n",
            r.rate_fps,
            r.wind_m_s,
            r.seen,
            r.total,
            100.0 * share,
            r.seen as f64 / r.runs.max(1) as f64,
            r.total as f64 / r.runs.max(1) as f64,
            r.false_detections_per_run,
            r.frames_per_run,
            r.companion_energy_mean_wh,
            100.0 * r.landed_fraction
        );
    }
    if let Some(backend) = rows.first().map(|r| &r.backend) {
        out += &format!("\nhazard CNN backend: {backend}\n");
    }
    out
}

/// The tracking phase of a path trial, at least: the S, the circle and the figure-eight curve
/// from their start, and 30 s is enough for the follower to settle at IH.
const PATH_TRIAL_TRACKING_S: f64 = 30.0;

/// A path trial's tracking phase: [`PATH_TRIAL_TRACKING_S`], or longer where the path's first
/// turn lies further on (the rectangle's first corner, 20 m on), so that the follower turns
/// with the UGV 5 s before the landing begins.
fn trial_tracking_s(path: PathKind, speed_m_s: f64) -> f64 {
    let to_turn_s = path
        .first_turn_m()
        .filter(|_| speed_m_s > 0.0)
        .map_or(0.0, |m| m / speed_m_s + 5.0);
    PATH_TRIAL_TRACKING_S.max(to_turn_s)
}

/// Seed 000's paths and UGV speeds (§3.1).
const TRIAL_PATHS: [PathKind; 5] = [
    PathKind::Straight,
    PathKind::SShape,
    PathKind::Rectangle,
    PathKind::Circle,
    PathKind::FigureEight,
];
const TRIAL_SPEEDS_M_S: [f64; 3] = [0.2, 0.5, 0.8];

/// One cell of the path trials, over its seeds.
#[derive(Debug, serde::Serialize)]
struct PathRow {
    path: String,
    ugv_speed_m_s: f64,
    runs: usize,
    success_rate: f64,
    /// Horizontal localisation error while tracking: RMS over every sample of every run, and
    /// the largest.
    localisation_rms_m: Option<f64>,
    localisation_max_m: Option<f64>,
    /// Height-above-pad error, RMS over every sample.
    altitude_rms_m: Option<f64>,
    /// The platform-velocity estimate's error, RMS over every sample that had one.
    platform_velocity_rms_m_s: Option<f64>,
    touchdown_error_p50_m: Option<f64>,
    touchdown_error_max_m: Option<f64>,
    time_to_land_p50_s: Option<f64>,
}

impl PathRow {
    fn of(path: PathKind, ugv_speed_m_s: f64, outcomes: &[SimOutcome]) -> Self {
        let summary = SimSummary::of(outcomes);
        let localised: Vec<_> = outcomes.iter().filter_map(|o| o.localisation).collect();
        let samples: usize = localised.iter().map(|l| l.samples).sum();
        let pooled = |f: &dyn Fn(&sim::outcome::LocalisationError) -> f64| {
            (samples > 0).then(|| {
                (localised
                    .iter()
                    .map(|l| l.samples as f64 * f(l).powi(2))
                    .sum::<f64>()
                    / samples as f64)
                    .sqrt()
            })
        };
        let with_velocity: Vec<(usize, f64)> = localised
            .iter()
            .filter_map(|l| l.platform_velocity_rms_m_s.map(|v| (l.samples, v)))
            .collect();
        let velocity_samples: usize = with_velocity.iter().map(|(n, _)| n).sum();
        let touchdown_errors: Vec<f64> = outcomes
            .iter()
            .filter(|o| o.landed_on_pad)
            .filter_map(|o| o.touchdown_error_m)
            .collect();
        Self {
            path: path.to_string(),
            ugv_speed_m_s,
            runs: summary.runs,
            success_rate: summary.success_rate,
            localisation_rms_m: pooled(&|l| l.horizontal_rms_m),
            localisation_max_m: localised
                .iter()
                .map(|l| l.horizontal_max_m)
                .reduce(f64::max),
            altitude_rms_m: pooled(&|l| l.vertical_rms_m),
            platform_velocity_rms_m_s: (velocity_samples > 0).then(|| {
                (with_velocity
                    .iter()
                    .map(|&(n, v)| n as f64 * v * v)
                    .sum::<f64>()
                    / velocity_samples as f64)
                    .sqrt()
            }),
            touchdown_error_p50_m: summary.touchdown_error_p50_m,
            touchdown_error_max_m: touchdown_errors.into_iter().reduce(f64::max),
            time_to_land_p50_s: summary.time_to_land_p50_s,
        }
    }
}

/// Seed 000's simulated trials: every path × UGV speed, `args.runs` seeds per cell, following
/// at the landing task's IH with the marker detector at its top rate.
fn evaluate_paths(model: &MissionModel, registry: &PluginRegistry, args: &SimArgs) -> ExitCode {
    let mut fixed_levels = args.fixed_levels.clone();
    if let Some(detection) = model
        .config
        .tasks
        .iter()
        .find(|t| t.plugin == "landing_marker")
    {
        if !fixed_levels.iter().any(|(name, _)| *name == detection.name) {
            if let Some(&top) = detection.levels.last() {
                fixed_levels.push((detection.name.clone(), top));
            }
        }
    }
    let mut cells = Vec::new();
    for path in TRIAL_PATHS {
        for speed_m_s in TRIAL_SPEEDS_M_S {
            cells.push((path, speed_m_s));
        }
    }
    let started = std::time::Instant::now();
    let results = fly_cells(model, registry, &cells, args, |&(path, speed_m_s), seed| {
        SimOptions {
            path,
            platform_speed_m_s: speed_m_s,
            tracking_s: Some(
                args.tracking_s
                    .unwrap_or_else(|| trial_tracking_s(path, speed_m_s)),
            ),
            fixed_levels: fixed_levels.clone(),
            record_track: false,
            ..args.options(seed)
        }
    });
    let Ok(results) = results else {
        return ExitCode::FAILURE;
    };
    let wall_s = started.elapsed().as_secs_f64();
    let rows: Vec<PathRow> = cells
        .iter()
        .zip(&results)
        .map(|(&(path, speed), outcomes)| PathRow::of(path, speed, outcomes))
        .collect();
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).expect("rows serialise")
        );
    } else {
        print!("{}", path_table(&rows, args, wall_s));
    }
    ExitCode::SUCCESS
}

fn path_table(rows: &[PathRow], args: &SimArgs, wall_s: f64) -> String {
    let metres = |v: Option<f64>| v.map_or_else(|| "—".into(), |v| format!("{v:.3}"));
    let tracking = args.tracking_s.map_or_else(
        || format!("tracking {PATH_TRIAL_TRACKING_S} s (the rectangle's until 5 s past its first corner)"),
        |s| format!("tracking {s} s"),
    );
    let mut out = format!(
        "{} seeds per cell from seed {}, {tracking}, wind {} m/s; {} missions in {:.0} s\n\n",
        args.runs(),
        args.seed,
        args.wind_m_s,
        rows.iter().map(|r| r.runs).sum::<usize>(),
        wall_s
    );
    out += "| path | UGV speed (m/s) | success | localisation RMS / max (m) | altitude RMS (m) | UGV velocity RMS (m/s) | touchdown error p50 / max (m) | time to land p50 (s) |\n";
    out += "| --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for r in rows {
        out += &format!(
            "| {} | {} | {:.0} % | {} / {} | {} | {} | {} / {} | {} |\n",
            r.path,
            r.ugv_speed_m_s,
            100.0 * r.success_rate,
            metres(r.localisation_rms_m),
            metres(r.localisation_max_m),
            metres(r.altitude_rms_m),
            metres(r.platform_velocity_rms_m_s),
            metres(r.touchdown_error_p50_m),
            metres(r.touchdown_error_max_m),
            r.time_to_land_p50_s
                .map_or_else(|| "—".into(), |v| format!("{v:.1}"))
        );
    }
    out
}

/// `TASK=VALUE` for `--fix`.
pub(crate) fn parse_fixed_level(text: &str) -> Result<(String, f64), String> {
    let (task, value) = text
        .split_once('=')
        .ok_or_else(|| format!("expected TASK=VALUE (e.g. detection=10), found `{text}`"))?;
    let value: f64 = value
        .trim()
        .parse()
        .map_err(|_| format!("`{value}` is not a number; expected TASK=VALUE"))?;
    if task.trim().is_empty() {
        return Err(format!("no task name in `{text}`; expected TASK=VALUE"));
    }
    Ok((task.trim().to_string(), value))
}
