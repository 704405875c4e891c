//! `qosrt`: the energy-aware QoS mission runtime's command line.

mod check;

use clap::{Parser, Subcommand};
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
    /// Validate a mission's QoS config and print a summary of it.
    Check {
        /// The mission config.
        #[arg(default_value = "qos.toml")]
        file: PathBuf,
        /// Print the summary (or the errors) as JSON.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Check { file, json } => check::run(&file, json),
    }
}
