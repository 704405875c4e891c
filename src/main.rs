//! `qosrt`: the energy-aware QoS mission runtime's command line.

mod check;
mod detect;
mod frames;
mod model;
mod plan;
mod plot;
mod run;
mod sim;

use clap::{Parser, Subcommand};
use power_models::grid::AxisScale;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "qosrt",
    version,
    about = "Energy-aware QoS mission runtime for drones"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Fly the whole mission in the built-in simulator: vehicle, tractor, wind, camera, battery
    /// and a MAVLink autopilot over UDP, with the real runtime and tasks, in virtual time.
    Sim {
        /// The mission config.
        #[arg(default_value = "qos.toml")]
        file: PathBuf,
        /// The tractor's path: straight, s-shape, rectangle, circle, figure8, turn90, turn180.
        #[arg(long, default_value = "straight")]
        path: ::sim::tractor::PathKind,
        /// Mean wind speed (the seed's gust model).
        #[arg(long = "wind-mps", default_value_t = 0.0, value_name = "M_S")]
        wind_m_s: f64,
        /// Dryden turbulence around the mean wind instead of the seed's gusts.
        #[arg(long)]
        dryden: bool,
        /// The tractor's speed.
        #[arg(long = "platform-speed-mps", default_value_t = 1.5, value_name = "M_S")]
        platform_speed_m_s: f64,
        /// Random seed (wind, camera noise, hazards); the same seed flies the same mission.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Fly this many seeds (seed, seed + 1, ...) and print a summary.
        #[arg(long, default_value_t = 1)]
        runs: usize,
        /// Override the tracking phase's duration (s), e.g. to evaluate landings.
        #[arg(long, value_name = "S")]
        tracking_s: Option<f64>,
        /// Hold a task at one of its levels, by knob value: --fix detection=10 (repeatable).
        #[arg(long = "fix", value_name = "TASK=VALUE", value_parser = parse_fixed_level)]
        fixed_levels: Vec<(String, f64)>,
        /// Print the outcome as JSON.
        #[arg(long)]
        json: bool,
        /// Draw the vehicle's and the tractor's tracks and the battery over time as SVG.
        #[arg(long, value_name = "PATH")]
        svg: Option<PathBuf>,
        /// Evaluate landings: every landing-marker rate × wind {0, 8, 12} m/s × path {straight,
        /// figure8, turn180}, --runs seeds per cell (tracking shortened to 15 s unless
        /// --tracking-s says otherwise), as a table.
        #[arg(long)]
        evaluate: bool,
    },
    /// Validate a mission's QoS config and print a summary of it.
    Check {
        /// The mission config.
        #[arg(default_value = "qos.toml")]
        file: PathBuf,
        /// Print the summary (or the errors) as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Run the landing-marker detector on image files (PNG, JPEG, PGM).
    Detect {
        /// Image files.
        #[arg(required = true)]
        images: Vec<PathBuf>,
        /// The pad's layout (TOML: pad_size_m, nfold_order, nfold_oriented, nfold_size_m,
        /// dictionary, [[aruco]] id/size_m/centre_m); the reference pad by default.
        #[arg(long, value_name = "FILE")]
        layout: Option<PathBuf>,
        /// Print the detections as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Describe a power profile's model, evaluate it at a point, measure its error.
    Model {
        /// A profile: the project's TOML format, or a powprofiler CSV (`.csv`).
        profile: PathBuf,
        /// Leave-one-out error of every measured point, and the mean (MAPE).
        #[arg(long)]
        loo: bool,
        /// Evaluate at a point: one KNOB=VALUE per knob, e.g. --at hazard.rate_fps=2.
        #[arg(long, value_name = "KNOB=VALUE")]
        at: Vec<String>,
        /// Interpolate on linear or log-scaled knob axes (default: linear, the better on the seed data).
        #[arg(long, value_parser = ["log", "linear"])]
        scale: Option<String>,
        /// Names of a powprofiler CSV's knob columns (200, 201, …), comma-separated.
        #[arg(long, value_delimiter = ',', value_name = "NAMES")]
        knob_names: Vec<String>,
        /// Print the description as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Run the mission's tasks onboard. For now as a dry run on synthetic inputs (rendered
    /// frames, modelled battery telemetry): flight needs the MAVLink link.
    Run {
        /// The mission config.
        #[arg(default_value = "qos.toml")]
        file: PathBuf,
        /// Start every task and run it on synthetic inputs, then print per-task statistics.
        #[arg(long, required = true)]
        dry_run: bool,
        /// How long the dry run lasts.
        #[arg(long, default_value_t = 5.0, value_name = "S")]
        duration_s: f64,
        /// The mission phase to run (default: the one with the most tasks).
        #[arg(long, value_name = "NAME")]
        phase: Option<String>,
    },
    /// Plan the mission's QoS levels offline to fit the battery.
    Plan {
        /// The mission config.
        #[arg(default_value = "qos.toml")]
        file: PathBuf,
        /// Battery energy (Wh) instead of the config's capacity.
        #[arg(long, value_name = "WH")]
        battery_wh: Option<f64>,
        /// Reserve fraction instead of the config's, in [0, 1).
        #[arg(long, value_name = "FRACTION")]
        reserve: Option<f64>,
        /// Print the plan as JSON.
        #[arg(long)]
        json: bool,
        /// Also write the Pareto frontier (utility against energy) as an SVG plot.
        #[arg(long, value_name = "PATH")]
        svg: Option<PathBuf>,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Check { file, json } => check::run(&file, json),
        Command::Sim {
            file,
            path,
            wind_m_s,
            dryden,
            platform_speed_m_s,
            seed,
            runs,
            tracking_s,
            fixed_levels,
            json,
            svg,
            evaluate,
        } => sim::run(&sim::SimArgs {
            file,
            path,
            wind_m_s,
            dryden,
            platform_speed_m_s,
            seed,
            runs,
            tracking_s,
            fixed_levels,
            json,
            svg,
            evaluate,
        }),
        Command::Detect {
            images,
            layout,
            json,
        } => detect::run(&images, layout.as_deref(), json),
        Command::Model {
            profile,
            loo,
            at,
            scale,
            knob_names,
            json,
        } => model::run(&model::ModelArgs {
            profile,
            loo,
            at,
            scale: scale.map(|s| {
                if s == "linear" {
                    AxisScale::Linear
                } else {
                    AxisScale::Log
                }
            }),
            knob_names,
            json,
        }),
        Command::Run {
            file,
            dry_run: _,
            duration_s,
            phase,
        } => run::run(&file, duration_s, phase),
        Command::Plan {
            file,
            battery_wh,
            reserve,
            json,
            svg,
        } => plan::run(&plan::PlanArgs {
            file,
            battery_wh,
            reserve_fraction: reserve,
            json,
            svg,
        }),
    }
}

/// `TASK=VALUE` for `--fix`.
fn parse_fixed_level(text: &str) -> Result<(String, f64), String> {
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
