//! `qosrt profile`: measure this board's power over the QoS grid and write the profile that
//! `plan`, `sim` and the governor read; or build one from traces measured by hand
//! (`--from-csv`).

use crate::check::{report_failure, EXIT_INVALID_CONFIG};
use indicatif::{ProgressBar, ProgressStyle};
use power_models::profile::{summarise_trace, Profile};
use runtime::catalog::{PluginCatalog, BUILTIN_PLUGINS};
use runtime::config::{load_str, MissionConfig};
use runtime::diagnostic::{Diagnostic, FileReport};
use runtime::plugins::builtin_registry;
use runtime::power_meter::{csv_log, discover, selects, DiscoverOptions, PowerMeter, Probe};
use runtime::profile_sweep::{
    describe_method, plan_sweep, run_sweep, to_profile, LevelChoice, Measurement, SweepObserver,
    SweepOptions, SweepPlan,
};
use runtime::registry::PluginRegistry;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

/// Exit status when no usable power meter was found.
pub const EXIT_NO_METER: u8 = 3;

#[derive(clap::Args, Debug)]
pub struct ProfileArgs {
    /// The mission config whose tasks are measured (not read with --from-csv).
    #[arg(default_value = "qos.toml")]
    pub file: PathBuf,
    /// The meter to read: a kind as --list-meters names it (jetson-ina3221, rapl, hwmon, nvml,
    /// …), or csv:PATH for an external meter logging `timestamp_s,power_w` rows to PATH.
    /// Default: the best meter found. With --from-csv: the name of the meter that took the
    /// traces, written into the profile.
    #[arg(long, value_name = "NAME")]
    pub meter: Option<String>,
    /// The phase whose tasks run (default: the one with the most tasks this binary can run).
    #[arg(long, value_name = "NAME")]
    pub phase: Option<String>,
    /// Measuring time per combination of levels, after the warm-up.
    #[arg(long, default_value_t = 60.0, value_name = "S")]
    pub duration_s: f64,
    /// Time discarded after each change of levels while the tasks settle.
    #[arg(long, default_value_t = 5.0, value_name = "S")]
    pub warmup_s: f64,
    /// Meter readings per second (with --from-csv: the rate the traces were taken at).
    #[arg(long, default_value_t = 10.0, value_name = "HZ")]
    pub rate_hz: f64,
    /// The levels of one knob to sweep, TASK.KNOB=VALUE,VALUE,… (repeat per knob); a single
    /// value holds the knob there. Knobs not named sweep all their levels.
    #[arg(long, value_name = "KNOB=VALUES")]
    pub levels: Vec<String>,
    /// Where to write the profile (default: profiles/<board>/<phase>.toml).
    #[arg(long, value_name = "PATH")]
    pub out: Option<PathBuf>,
    /// Replace the profile at --out if there is one.
    #[arg(long)]
    pub force: bool,
    /// Also write the profile as a powprofiler CSV (flags 200…, 100, 101, 102, 130).
    #[arg(long, value_name = "PATH")]
    pub powprofiler: Option<PathBuf>,
    /// The board's name in the profile (default: the device tree's or DMI's model).
    #[arg(long, value_name = "NAME")]
    pub board: Option<String>,
    /// Build the profile from traces measured by hand instead of running the tasks: one
    /// argument per combination, KNOB=VALUE[,KNOB=VALUE…]:PATH, each PATH a powprofiler raw
    /// trace (flag row `100[,101,102]`, then one row of watts per reading at --rate-hz).
    #[arg(long, value_name = "KNOBS:PATH")]
    pub from_csv: Vec<String>,
    /// Probe every meter, say what was found and why the rest were rejected, and exit.
    #[arg(long)]
    pub list_meters: bool,
    /// Root of the filesystem the meters read (for tests on fake sysfs trees).
    #[arg(long, hide = true, default_value = "/", value_name = "PATH")]
    pub sysfs_root: PathBuf,
    /// The NVML library to load (for tests); `none` skips NVML.
    #[arg(long, hide = true, value_name = "PATH")]
    pub nvml_library: Option<PathBuf>,
}

pub fn run(args: &ProfileArgs) -> ExitCode {
    if !(args.rate_hz.is_finite() && args.rate_hz > 0.0 && args.rate_hz <= 1000.0) {
        eprintln!(
            "error: --rate-hz must be within (0, 1000], found {}",
            args.rate_hz
        );
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    if args.list_meters {
        return list_meters(args);
    }
    if !args.from_csv.is_empty() {
        return from_csv(args);
    }
    sweep(args)
}

fn discover_options(args: &ProfileArgs) -> DiscoverOptions {
    let nvml_library = match &args.nvml_library {
        Some(path) if path.as_os_str() == "none" => None,
        Some(path) => Some(path.clone()),
        None => DiscoverOptions::default().nvml_library,
    };
    DiscoverOptions {
        root: args.sysfs_root.clone(),
        nvml_library,
    }
}

fn print_probes(probes: &[Probe]) {
    for probe in probes {
        eprintln!("  {probe}");
    }
}

fn list_meters(args: &ProfileArgs) -> ExitCode {
    let discovery = discover(&discover_options(args));
    for probe in &discovery.probes {
        println!("{probe}");
    }
    if discovery.meters.is_empty() {
        eprintln!("no power meter found");
        return ExitCode::from(EXIT_NO_METER);
    }
    println!();
    for (n, meter) in discovery.meters.iter().enumerate() {
        let mark = if n == 0 { " (the default)" } else { "" };
        println!("--meter {}{mark}: {}", meter.name(), meter.describe());
    }
    ExitCode::SUCCESS
}

/// The meter `--meter` names, or the best one found; `Err` has been reported.
fn open_meter(args: &ProfileArgs) -> Result<Box<dyn PowerMeter>, ExitCode> {
    if let Some(path) = args.meter.as_deref().and_then(|m| m.strip_prefix("csv:")) {
        return csv_log::CsvLogMeter::open(
            Path::new(path),
            csv_log::unix_clock(),
            csv_log::DEFAULT_MAX_AGE_S,
        )
        .map(|meter| Box::new(meter) as Box<dyn PowerMeter>)
        .map_err(|error| {
            eprintln!("error: --meter csv:{path}: {error}");
            ExitCode::from(EXIT_NO_METER)
        });
    }
    let discovery = discover(&discover_options(args));
    let names: Vec<String> = discovery
        .meters
        .iter()
        .map(|m| m.name().to_string())
        .collect();
    let mut meters = discovery.meters.into_iter();
    let chosen = match &args.meter {
        None => meters.next(),
        Some(wanted) => meters.find(|m| selects(wanted, m.name())),
    };
    match chosen {
        Some(meter) => Ok(meter),
        None => {
            match &args.meter {
                Some(wanted) if !names.is_empty() => eprintln!(
                    "error: no meter `{wanted}` here; found: {}. What was probed:",
                    names.join(", ")
                ),
                _ => eprintln!(
                    "error: no power meter found, so nothing can be measured (a profile is never made up). What was probed:"
                ),
            }
            print_probes(&discovery.probes);
            eprintln!(
                "On a Jetson, run on the board itself (INA3221 under /sys); elsewhere log an external meter and pass --meter csv:PATH, or measure by hand and use --from-csv."
            );
            Err(ExitCode::from(EXIT_NO_METER))
        }
    }
}

/// The board's model as the firmware names it, or `unknown`.
fn board_name(args: &ProfileArgs) -> String {
    if let Some(board) = &args.board {
        return board.clone();
    }
    for file in [
        "proc/device-tree/model",
        "sys/firmware/devicetree/base/model",
        "sys/class/dmi/id/product_name",
    ] {
        if let Ok(text) = std::fs::read_to_string(args.sysfs_root.join(file)) {
            let model = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
            if !model.is_empty() {
                return model.to_string();
            }
        }
    }
    "unknown".to_string()
}

/// `NVIDIA Jetson Nano Developer Kit` → `nvidia-jetson-nano-developer-kit`.
fn slug(text: &str) -> String {
    let lower: String = text
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect();
    lower
        .split('-')
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join("-")
}

/// Checks up front that the profile can be written, so an hour of measuring is never lost to
/// an existing file or a missing folder.
fn prepare_out(out: &Path, force: bool) -> Result<(), OutputError> {
    if out.exists() && !force {
        return Err(OutputError::Exists(out.to_path_buf()));
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| OutputError::CreateDir {
            dir: dir.to_path_buf(),
            source,
        })?;
    }
    Ok(())
}

/// Why the profile could not be written.
#[derive(Debug, thiserror::Error)]
enum OutputError {
    #[error("{} exists: choose another --out, or --force to replace it", .0.display())]
    Exists(PathBuf),
    #[error("cannot create {}: {source}", dir.display())]
    CreateDir {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot write {}: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The profile's own message (power_models gives no error type to keep).
    #[error("{0}")]
    Serialise(String),
    #[error("the profile does not read back: {0}")]
    ReadBack(String),
}

/// Writes via a temporary file in the same folder, so a profile is never half written.
fn write_file(path: &Path, text: &str) -> Result<(), OutputError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, text)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|source| OutputError::Write {
            path: path.to_path_buf(),
            source,
        })
}

/// The profile as TOML, checked to read back, then written (and as powprofiler CSV).
fn write_profile(
    profile: &Profile,
    out: &Path,
    powprofiler: Option<&Path>,
) -> Result<(), OutputError> {
    let body = profile
        .to_toml_string()
        .map_err(|e| OutputError::Serialise(e.message))?;
    if let Err(error) = Profile::from_toml_str(&body) {
        return Err(OutputError::ReadBack(error.message));
    }
    let text = format!(
        "# Power profile of {} written by `qosrt profile`; `source` says how it was measured.\n{body}",
        profile.board
    );
    write_file(out, &text)?;
    if let Some(csv) = powprofiler {
        write_file(csv, &profile.to_powprofiler_csv())?;
    }
    Ok(())
}

fn registry_catalog(registry: &PluginRegistry) -> PluginCatalog {
    // The built-in names are always known, so a config naming a plugin this binary lacks
    // loads, and its task is reported as skipped rather than the config as wrong.
    let extra = registry
        .names()
        .filter(|name| !BUILTIN_PLUGINS.iter().any(|p| p.name == *name))
        .filter_map(|name| registry.info(name).cloned());
    PluginCatalog::from_plugins(BUILTIN_PLUGINS.iter().cloned().chain(extra))
}

/// Loads the config without requiring its profiles to exist: profiling is how they come to be.
fn load_config(file: &Path, catalog: &PluginCatalog) -> Result<MissionConfig, ExitCode> {
    let failure = |source: String, diagnostics: Vec<Diagnostic>| {
        report_failure(
            &FileReport {
                path: file.to_path_buf(),
                source,
                diagnostics,
            },
            false,
        );
        ExitCode::from(EXIT_INVALID_CONFIG)
    };
    let source = std::fs::read_to_string(file).map_err(|error| {
        failure(
            String::new(),
            vec![Diagnostic::error(
                None,
                format!("cannot read the config file: {error}"),
            )],
        )
    })?;
    let mut config = load_str(&source, None, catalog).map_err(|d| failure(source.clone(), d))?;
    let dir = file.parent().unwrap_or(Path::new(".")).to_path_buf();
    for task in &mut config.tasks {
        task.config_dir = Some(dir.clone());
    }
    Ok(config)
}

fn print_plan(plan: &SweepPlan, meter: &dyn PowerMeter, options: &SweepOptions) {
    eprintln!("meter: {}", meter.describe());
    eprintln!("phase `{}`:", plan.phase);
    for axis in &plan.axes {
        eprintln!("  sweep {} over {:?}", axis.name, axis.values);
    }
    for held in &plan.held {
        eprintln!("  hold  {} = {}", held.name, held.values[0]);
    }
    for skipped in &plan.skipped {
        eprintln!(
            "  skip  task `{}`: its plugin `{}` is not built into this binary",
            skipped.task, skipped.plugin
        );
    }
    let steps = plan.combinations().len() + 1;
    let step_s = (options.warmup + options.duration).as_secs_f64();
    let total_s = steps as f64 * step_s;
    let total = if total_s < 120.0 {
        format!("{total_s:.1} s")
    } else {
        format!("{:.1} min", total_s / 60.0)
    };
    eprintln!(
        "{} combination(s) and the idle baseline, {step_s} s each: about {total}",
        steps - 1
    );
}

/// The progress bar, with warnings and each point's result printed above it.
struct Progress {
    bar: ProgressBar,
    step: usize,
}

const TICKS_PER_STEP: u64 = 1000;

impl SweepObserver for Progress {
    fn step_started(&mut self, step: usize, steps: usize, label: &str) {
        self.step = step;
        self.bar.set_length(steps as u64 * TICKS_PER_STEP);
        self.bar.set_position(step as u64 * TICKS_PER_STEP);
        self.bar.set_message(label.to_string());
    }

    fn progress(&mut self, fraction: f64) {
        let within = (fraction.clamp(0.0, 1.0) * TICKS_PER_STEP as f64) as u64;
        self.bar
            .set_position(self.step as u64 * TICKS_PER_STEP + within);
    }

    fn step_finished(&mut self, label: &str, m: &Measurement) {
        self.bar.suspend(|| {
            eprintln!(
                "  {label}: {:.3} W ± {:.3} ({} readings in {:.1} s)",
                m.total.mean_w, m.total.std_w, m.readings, m.window_s
            )
        });
    }

    fn warning(&mut self, message: &str) {
        self.bar.suspend(|| eprintln!("warning: {message}"));
    }
}

fn sweep(args: &ProfileArgs) -> ExitCode {
    let seconds = |name: &str, s: f64, min: f64| -> Result<Duration, ExitCode> {
        if s.is_finite() && s >= min && s <= 86_400.0 {
            Ok(Duration::from_secs_f64(s))
        } else {
            eprintln!("error: {name} must be within [{min}, 86400] s, found {s}");
            Err(ExitCode::from(EXIT_INVALID_CONFIG))
        }
    };
    let options = match (
        seconds("--duration-s", args.duration_s, 0.01),
        seconds("--warmup-s", args.warmup_s, 0.0),
    ) {
        (Ok(duration), Ok(warmup)) => SweepOptions {
            duration,
            warmup,
            rate_hz: args.rate_hz,
        },
        (Err(code), _) | (_, Err(code)) => return code,
    };
    let mut choices = Vec::new();
    for text in &args.levels {
        match text.parse::<LevelChoice>() {
            Ok(choice) => choices.push(choice),
            Err(error) => {
                eprintln!("error: {error}");
                return ExitCode::from(EXIT_INVALID_CONFIG);
            }
        }
    }
    let registry = match builtin_registry() {
        Ok(registry) => registry,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    };
    let config = match load_config(&args.file, &registry_catalog(&registry)) {
        Ok(config) => config,
        Err(code) => return code,
    };
    let can_run = |plugin: &str| registry.contains(plugin);
    let plan = match plan_sweep(&config, &can_run, args.phase.as_deref(), &choices) {
        Ok(plan) => plan,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    let mut meter = match open_meter(args) {
        Ok(meter) => meter,
        Err(code) => return code,
    };
    let board = board_name(args);
    let out = args.out.clone().unwrap_or_else(|| {
        PathBuf::from("profiles")
            .join(slug(&board))
            .join(format!("{}.toml", slug(&plan.phase)))
    });
    if let Err(error) = prepare_out(&out, args.force) {
        eprintln!("error: {error}");
        return ExitCode::from(EXIT_INVALID_CONFIG);
    }
    print_plan(&plan, meter.as_ref(), &options);

    let bar = ProgressBar::new(TICKS_PER_STEP);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {elapsed} elapsed, ETA {eta}: {msg}")
            .expect("a valid template"),
    );
    let mut progress = Progress { bar, step: 0 };
    let result = run_sweep(
        &config,
        &registry,
        &plan,
        meter.as_mut(),
        &options,
        &mut progress,
    );
    progress.bar.finish_and_clear();
    let result = match result {
        Ok(result) => result,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    };
    let profile = to_profile(
        &plan,
        &result,
        &board,
        &meter.describe(),
        options.rate_hz,
        describe_method(&plan, &config, &options),
    );
    if let Err(error) = write_profile(&profile, &out, args.powprofiler.as_deref()) {
        eprintln!("error: {error}");
        return ExitCode::FAILURE;
    }
    print!(
        "{}",
        summary(
            &profile,
            &plan.phase,
            &out,
            &args.file,
            result.warnings.len()
        )
    );
    ExitCode::SUCCESS
}

/// `out` as the config names profiles: relative to the config's folder where it lies below
/// it, else absolute.
fn config_relative(out: &Path, config: &Path) -> PathBuf {
    let config_dir = config.parent().filter(|d| !d.as_os_str().is_empty());
    let (Ok(out_abs), Ok(dir_abs)) = (
        std::fs::canonicalize(out),
        std::fs::canonicalize(config_dir.unwrap_or(Path::new("."))),
    ) else {
        return out.to_path_buf();
    };
    out_abs
        .strip_prefix(&dir_abs)
        .map(Path::to_path_buf)
        .unwrap_or(out_abs)
}

fn summary(profile: &Profile, phase: &str, out: &Path, config: &Path, warnings: usize) -> String {
    let mut text = format!("{:<40} {:>9} {:>9}\n", "point", "power_w", "std_w");
    if let (Some(w), Some(s)) = (profile.idle_power_w, profile.idle_power_std_w) {
        text += &format!("{:<40} {w:>9.3} {s:>9.3}\n", "idle");
    }
    for sample in &profile.samples {
        let point: Vec<String> = profile
            .knobs
            .iter()
            .zip(&sample.knobs)
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        text += &format!(
            "{:<40} {:>9.3} {:>9.3}\n",
            if point.is_empty() {
                "held levels".to_string()
            } else {
                point.join(" ")
            },
            sample.power_w,
            sample.power_std_w.unwrap_or(0.0)
        );
    }
    if warnings > 0 {
        text += &format!("\n{warnings} warning(s) above: read them before trusting the figures\n");
    }
    text += &format!(
        "\nwrote {}\nto use it, add to the config:\n\n[[power_model.profile]]\npath = {:?}\nphases = [\"{phase}\"]\n",
        out.display(),
        config_relative(out, config).display().to_string()
    );
    if let Some(idle_w) = profile.idle_power_w {
        text += &format!(
            "\n(where a phase is modelled by several profiles, also set `idle_power_w = {idle_w:.3}` under [power_model])\n"
        );
    }
    text
}

/// One `--from-csv` argument: `KNOB=VALUE[,KNOB=VALUE…]:PATH`.
fn parse_from_csv(text: &str) -> Result<(Vec<(String, f64)>, PathBuf), String> {
    let (knobs, path) = text.split_once(':').ok_or_else(|| {
        format!("--from-csv `{text}`: expected KNOB=VALUE[,KNOB=VALUE…]:PATH, e.g. hazard.rate_fps=4,detection.rate_fps=10:trace.csv")
    })?;
    if path.trim().is_empty() {
        return Err(format!("--from-csv `{text}`: no file after `:`"));
    }
    let mut point = Vec::new();
    for pair in knobs.split(',').filter(|p| !p.trim().is_empty()) {
        let (knob, value) = pair
            .split_once('=')
            .ok_or_else(|| format!("--from-csv `{text}`: `{pair}` is not KNOB=VALUE"))?;
        let value: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| format!("--from-csv `{text}`: `{}` is not a number", value.trim()))?;
        let knob = knob.trim().to_string();
        if point.iter().any(|(k, _)| *k == knob) {
            return Err(format!("--from-csv `{text}`: {knob} is given twice"));
        }
        point.push((knob, value));
    }
    Ok((point, PathBuf::from(path)))
}

/// Builds the profile from raw traces, one per combination.
fn from_csv(args: &ProfileArgs) -> ExitCode {
    let fail = |message: String| {
        eprintln!("error: {message}");
        ExitCode::from(EXIT_INVALID_CONFIG)
    };
    let mut entries = Vec::new();
    for text in &args.from_csv {
        match parse_from_csv(text) {
            Ok(entry) => entries.push(entry),
            Err(message) => return fail(message),
        }
    }
    let knobs: Vec<String> = entries[0].0.iter().map(|(k, _)| k.clone()).collect();
    let mut samples = Vec::new();
    for (point, path) in &entries {
        let mut names: Vec<&String> = point.iter().map(|(k, _)| k).collect();
        let mut expected: Vec<&String> = knobs.iter().collect();
        names.sort();
        expected.sort();
        if names != expected {
            return fail(format!(
                "--from-csv {}: names knobs {:?}, the first names {:?}: every trace needs a value for the same knobs",
                path.display(),
                point.iter().map(|(k, _)| k).collect::<Vec<_>>(),
                knobs
            ));
        }
        let text = match std::fs::read_to_string(path) {
            Ok(text) => text,
            Err(error) => return fail(format!("cannot read {}: {error}", path.display())),
        };
        let trace = match summarise_trace(&text, args.rate_hz) {
            Ok(trace) => trace,
            Err(error) => {
                let place = match error.line_col(&text) {
                    Some((line, col)) => format!("{}:{line}:{col}", path.display()),
                    None => path.display().to_string(),
                };
                return fail(format!("{place}: {}", error.message));
            }
        };
        let values = knobs
            .iter()
            .map(|k| point.iter().find(|(n, _)| n == k).map_or(0.0, |(_, v)| *v))
            .collect();
        samples.push(trace.to_sample(values));
    }
    let files: Vec<String> = entries
        .iter()
        .map(|(_, p)| {
            p.file_name().map_or_else(
                || p.display().to_string(),
                |f| f.to_string_lossy().into_owned(),
            )
        })
        .collect();
    let board = board_name(args);
    let profile = Profile {
        board: board.clone(),
        meter: args
            .meter
            .clone()
            .unwrap_or_else(|| "unnamed meter (traces measured by hand)".to_string()),
        sample_rate_hz: Some(args.rate_hz),
        source: Some(format!(
            "qosrt profile --from-csv: raw traces at {} Hz, one per point: {}",
            args.rate_hz,
            files.join(", ")
        )),
        idle_power_w: None,
        idle_power_std_w: None,
        knobs,
        samples,
    };
    if let Err(error) = Profile::from_toml_str(&profile.to_toml_string().unwrap_or_default()) {
        return fail(format!(
            "these traces make no valid profile: {}",
            error.message
        ));
    }
    let out = args.out.clone().unwrap_or_else(|| {
        PathBuf::from("profiles")
            .join(slug(&board))
            .join("hand-measured.toml")
    });
    if let Err(error) = prepare_out(&out, args.force) {
        return fail(error.to_string());
    }
    if let Err(error) = write_profile(&profile, &out, args.powprofiler.as_deref()) {
        eprintln!("error: {error}");
        return ExitCode::FAILURE;
    }
    let phase = args.phase.as_deref().unwrap_or("PHASE");
    print!("{}", summary(&profile, phase, &out, &args.file, 0));
    ExitCode::SUCCESS
}

#[cfg(test)]
mod tests;
