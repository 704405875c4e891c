//! `qosrt`: the energy-aware QoS mission runtime's command line.

mod check;
mod detect;
mod frames;
mod model;
mod plan;
mod plot;
mod profile;
mod ptu_stereo;
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
    Sim(sim::SimArgs),
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
    /// Measure this board's power at each combination of the tasks' QoS levels with its power
    /// meter (Jetson INA3221, RAPL, hwmon, NVML or an external meter's log) and write the
    /// profile `plan` reads; or build one from traces measured by hand (--from-csv).
    Profile(profile::ProfileArgs),
    /// The ground-based PTU stereo localisation of seed 001: reproduce its error tables and
    /// figures, or fly a scripted fixed-wing approach through the ground_stereo task.
    PtuStereo(ptu_stereo::PtuStereoArgs),
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
    // Warnings and errors from the runtime (a task that failed, the hazard CNN falling back to
    // the CPU) reach the user on stderr; RUST_LOG=info (or debug) shows every QoS and mode change.
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
    let cli = Cli::parse();
    match cli.command {
        Command::Check { file, json } => check::run(&file, json),
        Command::Sim(args) => sim::run(&args),
        Command::Profile(args) => profile::run(&args),
        Command::PtuStereo(args) => ptu_stereo::run(&args),
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
