//! `qosrt replay F.mcap`: the recorded mission's tasks re-run on its recorded frames, telemetry
//! and clock, and where their outputs differ from the recording.

use crate::check::EXIT_INVALID_CONFIG;
use crate::load::load_model;
use runtime::mission::{replay, ReplayOptions, ReplayReport};
use runtime::plugins::builtin_registry;
use runtime::record::extract_config;
use runtime::record::RecordingReader;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Exit status when the replay's outputs differ from the recording's.
pub const EXIT_OUTPUTS_DIFFER: u8 = 5;

/// `qosrt replay`'s arguments.
#[derive(clap::Args)]
pub struct ReplayArgs {
    /// The recording (`qosrt sim --record` or `qosrt run --record`).
    pub file: PathBuf,
    /// Re-run with this config instead of the one the recording flew.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Hold a task at one of its levels, by knob value, instead of the recording's: --fix
    /// detection=2 (repeatable).
    #[arg(long = "fix", value_name = "TASK=VALUE", value_parser = crate::args::parse_fixed_level)]
    pub fixed_levels: Vec<(String, f64)>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &ReplayArgs) -> ExitCode {
    // Its header and config files only: the replay streams the messages itself.
    let recording = match RecordingReader::open(&args.file) {
        Ok(recording) => recording,
        Err(error) => {
            eprintln!("error: {}: {error}", args.file.display());
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    let registry = match builtin_registry() {
        Ok(registry) => registry,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    };
    let model = match &args.config {
        Some(path) => load_model(path, args.json),
        None => {
            // The config the recording flew, as it was, with its profiles beside it.
            let dir = std::env::temp_dir().join(format!("qosrt-replay-{}", std::process::id()));
            let model =
                extract_config(&recording.config_files, &recording.header.config_file, &dir)
                    .map_err(|error| eprintln!("error: {}: {error}", args.file.display()))
                    .ok()
                    .and_then(|path| load_model(&path, args.json));
            let _ = std::fs::remove_dir_all(&dir);
            model
        }
    };
    let Some(model) = model else {
        return ExitCode::from(EXIT_INVALID_CONFIG);
    };
    let options = ReplayOptions {
        fixed_levels: (!args.fixed_levels.is_empty()).then(|| args.fixed_levels.clone()),
    };
    let report = match replay(&args.file, model, &registry, &options) {
        Ok(report) => report,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    };
    crate::output::print_result(args.json, &report, |report| describe(report, &args.file));
    if report.identical() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_OUTPUTS_DIFFER)
    }
}

/// The report, for people.
pub fn describe(report: &ReplayReport, file: &Path) -> String {
    let mut out = format!(
        "replayed {} of {} steps of {} (up to t = {:.2} s)\n",
        report.steps_replayed,
        report.steps_recorded,
        file.display(),
        report.replayed_until_s
    );
    if let Some(why) = &report.recording_truncated {
        out += &format!(
            "the recording ends early (cut off mid-flight?): {why}; replayed up to its last complete step\n"
        );
    }
    if !report.without_frames.is_empty() {
        out += &format!(
            "the recording kept no camera frames (--record-frames none): {} saw none, so their \
             outputs and what follows from them differ; the rest is compared as flown\n",
            report.without_frames.join(", ")
        );
    }
    if let Some(why) = &report.stopped {
        out += &format!("the replay stopped {why}\n");
    }
    let latency = &report.capture_to_setpoint;
    if latency.count > 0 {
        out += &format!(
            "the flight's capture to setpoint: {:.1} ms median, {:.1} ms p99, {:.1} ms max ({} frames answered)\n",
            latency.p50_us * 1e-3,
            latency.p99_us * 1e-3,
            latency.max_us * 1e-3,
            latency.count
        );
    }
    out += &format!(
        "{:<32} {:>9} {:>9} {:>9}  first difference\n",
        "output channel", "recorded", "replayed", "differ"
    );
    for channel in &report.channels {
        let first = match channel.first_difference_s {
            None => "—".to_string(),
            Some(first_s) => format!(
                "t = {first_s:.2} s (last t = {:.2} s): {}",
                channel.last_difference_s.unwrap_or(first_s),
                channel.first_fields.join("; ")
            ),
        };
        out += &format!(
            "{:<32} {:>9} {:>9} {:>9}  {first}\n",
            channel.topic, channel.recorded, channel.replayed, channel.differing
        );
    }
    let differing = report.channels.iter().filter(|c| !c.identical()).count();
    out += &if differing == 0 {
        "no difference: every output as recorded, bit for bit\n".to_string()
    } else {
        format!(
            "outputs differ on {differing} of {} channels\n",
            report.channels.len()
        )
    };
    out
}
