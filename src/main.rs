//! `qosrt`: the energy-aware QoS mission runtime's command line.

mod args;
mod check;
mod detect;
mod evaluate;
mod fleet;
mod fly;
mod frames;
mod load;
mod model;
mod output;
mod plan;
mod plot;
mod profile;
mod ptu_stereo;
mod replay;
mod run;
mod serve;
mod sim;

use clap::{Parser, Subcommand};
use power_models::grid::AxisScale;
use std::ffi::OsString;
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
    /// Log events as JSON lines on stderr instead of readable text.
    #[arg(long, global = true)]
    log_json: bool,
}

#[derive(Subcommand)]
enum Command {
    /// Fly the whole mission in the built-in simulator: vehicle, tractor, wind, camera, battery
    /// and a MAVLink autopilot over UDP, with the real runtime and tasks, in virtual time.
    Sim(Box<sim::args::SimArgs>),
    /// Re-run a recorded mission's tasks on its recorded frames, telemetry and clock, and say
    /// where their outputs differ from the recording (none: bit for bit).
    Replay(replay::ReplayArgs),
    /// The ground station's view of every vehicle flying with --ros2 (phase, battery, energy
    /// margin, time left, levels), and `qosrt fleet set VEHICLE reserve=0.3` to change a
    /// vehicle's plan in flight.
    Fleet(fleet::FleetArgs),
    /// Validate a mission's QoS config and print a summary of it.
    Check {
        /// The mission config.
        #[arg(default_value = "qos.toml")]
        file: PathBuf,
        /// Print the summary (or the errors) as JSON.
        #[arg(long)]
        json: bool,
        /// Print the task graph instead of the summary: who feeds whom over the bus (`dot` for
        /// Graphviz: `qosrt check --graph dot | dot -Tsvg > graph.svg`).
        #[arg(long, value_enum, num_args = 0..=1, require_equals = true, default_missing_value = "text")]
        graph: Option<check::GraphFormat>,
        /// The task graph in this format (implies --graph).
        #[arg(long, value_enum, value_name = "FORMAT", conflicts_with = "graph")]
        graph_format: Option<check::GraphFormat>,
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
    /// Run the mission onboard beside a PX4 or ArduPilot autopilot (`--mavlink`), observing
    /// unless `--control` is given; or as a dry run on synthetic inputs (`--dry-run`).
    Run {
        /// The mission config.
        #[arg(default_value = "qos.toml")]
        file: PathBuf,
        /// The autopilot: udpin:HOST:PORT, udpout:HOST:PORT, tcpout:HOST:PORT or
        /// serial:DEVICE:BAUD (e.g. udpin:0.0.0.0:14540 for PX4's onboard link).
        #[arg(
            long,
            value_name = "URL",
            required_unless_present = "dry_run",
            conflicts_with = "dry_run"
        )]
        mavlink: Option<String>,
        /// Camera frames: folder:PATH[@FPS], gst:PIPELINE, v4l2:DEVICE, rtp-h264:PORT,
        /// rtsp://URL or file:PATH (all but folders need a build with --features gstreamer).
        #[arg(long, value_name = "SOURCE", requires = "mavlink")]
        camera: Option<String>,
        /// Command the vehicle: arm, take off, fly the phases in OFFBOARD/GUIDED and land.
        /// Without it qosrt never arms, changes mode or sends a setpoint.
        #[arg(long, requires = "mavlink")]
        control: bool,
        /// Where the tractor waits, metres north and east of the take-off point.
        #[arg(long, value_name = "N,E", value_parser = args::parse_north_east, default_value = "0,0", requires = "mavlink")]
        meeting_point_ne_m: [f64; 2],
        /// Print one JSON report at the end.
        #[arg(long, requires = "mavlink")]
        json: bool,
        /// Start every task and run it on synthetic inputs, then print per-task statistics.
        #[arg(long)]
        dry_run: bool,
        /// How long to run: the dry run (default 5 s), or the flight (then qosrt lands the
        /// vehicle where it is if it holds control).
        #[arg(long, value_name = "S")]
        duration_s: Option<f64>,
        /// The mission phase of a dry run (default: the one with the most tasks).
        #[arg(long, value_name = "NAME", requires = "dry_run")]
        phase: Option<String>,
        #[command(flatten)]
        recording: args::RecordArgs,
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
    let cli = Cli::parse_from(join_optional_values(std::env::args_os()));
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_log_level(&cli.command)));
    let logs = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(filter);
    if cli.log_json {
        logs.json().init();
    } else {
        logs.with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .init();
    }
    match cli.command {
        Command::Check {
            file,
            json,
            graph,
            graph_format,
        } => check::run(&file, json, graph.or(graph_format)),
        Command::Sim(args) => sim::run(&args),
        Command::Replay(args) => replay::run(&args),
        Command::Fleet(args) => fleet::run(&args),
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
            mavlink: Some(mavlink),
            camera,
            control,
            meeting_point_ne_m,
            json,
            dry_run: false,
            duration_s,
            phase: _,
            recording,
        } => fly::run(&fly::FlyArgs {
            file,
            mavlink,
            camera,
            control,
            duration_s,
            json,
            meeting_point_ne_m,
            recording,
        }),
        Command::Run {
            file,
            duration_s,
            phase,
            ..
        } => run::run(&file, duration_s.unwrap_or(5.0), phase),
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

/// The flags whose value may be left out (`--graph`, `--foxglove`), with the values they take.
/// Their value must then follow an `=`, or a config file after them would be read as their
/// value; a following word that is one of their values is joined to them here, so
/// `--graph dot` and `--foxglove 0.0.0.0:8765` keep working and `--graph qos.toml` means the
/// graph of qos.toml.
const OPTIONAL_VALUE_FLAGS: [(&str, IsValue); 2] = [
    ("--graph", |word| {
        <check::GraphFormat as clap::ValueEnum>::from_str(word, false).is_ok()
    }),
    ("--foxglove", |word| {
        word.parse::<std::net::SocketAddr>().is_ok()
    }),
];

/// Whether a word is one of a flag's values.
type IsValue = fn(&str) -> bool;

/// The command line with each optional-value flag joined to a following word that is its value.
fn join_optional_values(args: impl IntoIterator<Item = OsString>) -> Vec<OsString> {
    let mut joined: Vec<OsString> = Vec::new();
    for arg in args {
        let value_of = joined.last().and_then(|previous| {
            OPTIONAL_VALUE_FLAGS
                .iter()
                .find(|(flag, _)| previous.to_str() == Some(flag))
        });
        match (value_of, arg.to_str()) {
            (Some((flag, is_value)), Some(word)) if is_value(word) => {
                *joined.last_mut().expect("the flag is there") = format!("{flag}={word}").into();
            }
            _ => joined.push(arg),
        }
    }
    joined
}

/// Flying logs what it does as it goes (mode changes, QoS changes, faults); the other commands
/// print their results and log only warnings.
fn default_log_level(command: &Command) -> String {
    // RustDDS (the ROS 2 node) logs every datagram a network it cannot reach refuses (an IPv6
    // locator on an IPv4-only host) and, as errors, the events it gets after its entities are
    // gone at the end: noise to a user (RUST_LOG=rustdds=warn shows it). ros2-client's node
    // logs as an error every count of matched peers asked before the first has matched, which
    // is how `qosrt fleet set` waits for a vehicle. It warns at every start that ROS_DISTRO is
    // unset, as it is where no ROS is installed (the node needs none); a ROS_DISTRO other than
    // the one it was built for is an error, and shown.
    let level = match command {
        Command::Run { dry_run: false, .. } => "info",
        _ => "warn",
    };
    format!("{level},rustdds=off,ros2_client::node=off,ros2_client::distributions=error")
}

#[cfg(test)]
mod tests;
