//! `qosrt run --mavlink URL`: the mission on the companion computer, beside a PX4 or ArduPilot
//! autopilot, on the wall clock. The mission runner does the work; this module opens the link
//! and the camera, drives the runner at the loop rate, ends the run (time up, Ctrl-C: landing
//! where the vehicle is when qosrt holds control) and reports.

use crate::check::{report_failure, EXIT_INVALID_CONFIG};
use runtime::config::{load_file, LoadedConfig};
use runtime::energy::load_mission_model;
use runtime::link::{LinkConfig, MavlinkLink};
use runtime::mission::{LandingBy, MissionLog, MissionPlan, MissionRunner, RunnerOptions};
use runtime::plugins::builtin_registry;
use runtime::record::{ConfigFile, Recorder, RecordingHeader, RecordingSource};
use runtime::scheduler::{RealTimeOptions, SchedulerBuilder, TaskStats};
use serde::Serialize;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The loop's period: 50 Hz, so velocity setpoints stream well above PX4's 2 Hz minimum and
/// the 10 Hz the issue of control asks for. A camera frame or a new setpoint wakes it sooner.
const LOOP_PERIOD: Duration = Duration::from_millis(20);
/// How long a landing ordered at the end may take before qosrt gives up waiting.
const LANDING_TIMEOUT_S: f64 = 90.0;
/// The program ended but the vehicle did not land and disarm in time.
const EXIT_LANDING_TIMEOUT: u8 = 4;

/// The flight's runner: the mission loop on the real-time scheduler.
type Runner = MissionRunner<runtime::scheduler::RealTimeScheduler>;

/// What `qosrt run --mavlink` was asked.
pub struct FlyArgs {
    pub file: PathBuf,
    pub mavlink: String,
    pub camera: Option<String>,
    pub control: bool,
    pub duration_s: Option<f64>,
    pub json: bool,
    pub meeting_point_ne_m: [f64; 2],
    pub recording: crate::args::RecordArgs,
}

/// The report `--json` prints at the end.
#[derive(Serialize)]
struct FlightReport<'a> {
    autopilot: Option<&'a str>,
    control: bool,
    wall_s: f64,
    messages_received: &'a std::collections::BTreeMap<&'static str, u64>,
    messages_rejected: Rejected,
    battery: &'a runtime::mission::report::BatterySeen,
    governor: &'a [runtime::mission::GovernorDecision],
    modes: &'a [runtime::mission::report::ModeChange],
    events: &'a [(f64, String)],
    tasks: Vec<TaskLine>,
    frames: u64,
    camera_errors: u64,
    /// What the camera source counted: delivered, dropped, late, malformed, stalls.
    camera: Option<runtime::camera::CameraStats>,
    /// From a frame's capture to the first velocity setpoint sent with its fix (µs).
    capture_to_setpoint: runtime::scheduler::DurationSummary,
    /// From the frame's arrival at the runtime to that setpoint: the runtime's own delay (µs).
    delivered_to_setpoint: runtime::scheduler::DurationSummary,
    /// The autopilot's clock from TIMESYNC: offset (autopilot minus runtime) and round trip (ns).
    autopilot_clock: runtime::link::ClockSyncStats,
    /// Messages a second on the topics that trigger tasks, as the governor prices them
    /// (declared in the config, then measured over ten seconds).
    input_rates: &'a runtime::energy::InputRates,
    finished: bool,
}

#[derive(Serialize)]
struct Rejected {
    garbled: u64,
    unsigned: u64,
    from_others: u64,
}

#[derive(Serialize)]
struct TaskLine {
    name: String,
    level: usize,
    period_ms: f64,
    activations: u64,
    overruns: u64,
    failures: u64,
    step_p50_us: f64,
    step_p99_us: f64,
}

impl From<&TaskStats> for TaskLine {
    fn from(stats: &TaskStats) -> Self {
        Self {
            name: stats.name.clone(),
            level: stats.level,
            period_ms: stats.period_ms,
            activations: stats.activations,
            overruns: stats.overruns,
            failures: stats.failures,
            step_p50_us: stats.step_time.p50_us,
            step_p99_us: stats.step_time.p99_us,
        }
    }
}

pub fn run(args: &FlyArgs) -> ExitCode {
    match fly(args) {
        Ok(code) => code,
        Err(Failure::Config) => ExitCode::from(EXIT_INVALID_CONFIG),
        Err(Failure::Other(message)) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

enum Failure {
    /// Already reported, located.
    Config,
    /// Anything else, with its cause.
    Other(Box<dyn std::error::Error>),
}

impl<E: Into<Box<dyn std::error::Error>>> From<E> for Failure {
    fn from(error: E) -> Self {
        Failure::Other(error.into())
    }
}

/// The link's signing key file could not be read, or does not hold a key.
#[derive(Debug, thiserror::Error)]
enum SigningKeyError {
    #[error("{}: cannot read the signing key: {source}", path.display())]
    Read {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {source}", path.display())]
    Format {
        path: std::path::PathBuf,
        #[source]
        source: KeyFormatError,
    },
}

/// Why a key file's bytes are not a MAVLink 2 signing key.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum KeyFormatError {
    #[error("expected 32 raw bytes or 64 hex digits, found {0} bytes")]
    Bytes(usize),
    #[error("expected 32 raw bytes or 64 hex digits, found {0} characters")]
    Characters(usize),
    #[error("not a hex byte: {0}")]
    Hex(#[source] std::num::ParseIntError),
}

fn fly(args: &FlyArgs) -> Result<ExitCode, Failure> {
    let mut runner = start_runner(args)?;
    let started = Instant::now();
    let timed_out = fly_until_done(&mut runner, args, started)?;
    report(&mut runner, args, started)?;
    Ok(if timed_out {
        ExitCode::from(EXIT_LANDING_TIMEOUT)
    } else {
        ExitCode::SUCCESS
    })
}

/// The flight's runner: the config and its models loaded, the link and the camera open, the
/// tasks on the real-time scheduler, the recorder started when asked.
fn start_runner(args: &FlyArgs) -> Result<Runner, Failure> {
    if let Some(duration_s) = args.duration_s {
        if !(duration_s.is_finite() && duration_s > 0.0) {
            return Err(format!(
                "--duration-s must be a positive number of seconds, found {duration_s}"
            )
            .into());
        }
    }
    let registry = builtin_registry()?;
    let loaded = load_file(&args.file, &registry.catalog()).map_err(|failure| {
        report_failure(&failure, false);
        Failure::Config
    })?;
    let model = load_mission_model(&loaded).map_err(|reports| {
        for report in &reports {
            report_failure(report, false);
        }
        Failure::Config
    })?;
    let link_settings = loaded.config.link.clone().unwrap_or_default();
    let link_config = LinkConfig {
        signing_key: signing_key(&loaded)?,
        ..LinkConfig::default()
    };
    let link = MavlinkLink::connect(&args.mavlink, link_config)?;
    // The tasks project with the mission's camera: a frame of another size is refused.
    let camera_settings = loaded.config.camera_settings();
    let camera = args
        .camera
        .as_deref()
        .map(|spec| {
            let size_px = (camera_settings.width_px, camera_settings.height_px);
            runtime::camera::open(spec, Some(size_px))
        })
        .transpose()?;
    let mut plan = MissionPlan::for_mission(&loaded.config);
    plan.control = args.control;
    if camera.is_none() {
        // Nothing to see the pad with: the autopilot lands where the vehicle is.
        plan.landing = LandingBy::Autopilot;
    }
    plan.meeting_point_ne_m = args.meeting_point_ne_m;

    let scheduler = SchedulerBuilder::new(&registry)
        .tasks(&loaded.config.tasks)
        .build_real_time(RealTimeOptions::default())?;
    let runner_options = RunnerOptions {
        landing_target: link_settings.landing_target,
        fixed_levels: Vec::new(),
    };
    let has_camera = camera.is_some();
    let mut runner = MissionRunner::new(
        model,
        scheduler,
        link,
        plan.clone(),
        camera,
        runner_options.clone(),
    )?;
    if let Some(vehicle) = &args.recording.ros2 {
        let capacity_ah = loaded.config.battery.capacity_ah().unwrap_or(f64::NAN);
        let node = runtime::ros2::Ros2Node::start(vehicle, capacity_ah)?;
        tracing::info!("publishing ROS 2 topics under {}", node.namespace());
        runner.observe(Box::new(node));
    }
    if let Some(options) = args.recording.options(&loaded.config) {
        let files = ConfigFile::collect(&args.file, &loaded.config)?;
        let mut header = RecordingHeader::new(
            RecordingSource::Flight,
            SchedulerBuilder::DEFAULT_SEED,
            plan,
            &loaded.config,
            has_camera,
            files[0].path.clone(),
        );
        header.fixed_levels = runner_options.fixed_levels.clone();
        header.landing_target = runner_options.landing_target;
        header.link_peer_known = runner.link().has_peer();
        let recorder = Recorder::start(&options, &header, &files)?;
        if let Some(port) = recorder.live_port() {
            tracing::info!(
                "Foxglove: open ws://{}:{port}",
                options
                    .live
                    .map_or("127.0.0.1".into(), |a| a.ip().to_string())
            );
        }
        runner.record(recorder)?;
    }
    Ok(runner)
}

/// Steps the runner until the mission ends, or lands the vehicle when the time is up or on
/// Ctrl-C; whether the landing then timed out.
fn fly_until_done(runner: &mut Runner, args: &FlyArgs, started: Instant) -> Result<bool, Failure> {
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let interrupted = interrupted.clone();
        ctrlc::set_handler(move || interrupted.store(true, Ordering::SeqCst))?;
    }
    tracing::info!(
        mavlink = %args.mavlink,
        control = args.control,
        "qosrt run: {}",
        if args.control {
            "commanding the vehicle (--control)"
        } else {
            "observe mode: no arming, no mode change, no setpoint"
        }
    );
    // The loop runs on the scheduler's clock, the one the tasks stamp their messages with.
    let clock_start_s = runner.scheduler().now().as_secs_f64();
    // A frame or a setpoint wakes the loop: taken and sent at once, not at the next tick.
    runner.wake_on_input(std::thread::current())?;
    let mut stop_asked_s: Option<f64> = None;
    let mut timed_out = false;
    loop {
        let now_s = runner.scheduler().now().as_secs_f64();
        let run_s = now_s - clock_start_s;
        runner.step(now_s, None)?;
        let status = runner.status();
        if status.finished {
            break;
        }
        let time_up = args.duration_s.is_some_and(|d| run_s >= d);
        let stop = time_up || interrupted.load(Ordering::SeqCst);
        match stop_asked_s {
            None if stop => {
                let reason = if time_up {
                    "--duration-s ran out"
                } else {
                    "interrupted (Ctrl-C)"
                };
                runner.request_landing(now_s, reason)?;
                stop_asked_s = Some(now_s);
                if !runner.status().finished && !args.control {
                    break;
                }
            }
            Some(asked_s) if now_s - asked_s > LANDING_TIMEOUT_S => {
                timed_out = true;
                eprintln!(
                    "error: the vehicle did not land and disarm within {LANDING_TIMEOUT_S} s; the autopilot's land mode is still in charge"
                );
                break;
            }
            _ => {}
        }
        let next = started + Duration::from_secs_f64(run_s) + LOOP_PERIOD;
        std::thread::park_timeout(next.saturating_duration_since(Instant::now()));
    }
    Ok(timed_out)
}

/// Stops the runner, closes the recording and prints the flight's report.
fn report(runner: &mut Runner, args: &FlyArgs, started: Instant) -> Result<(), Failure> {
    runner.stop();
    if let Some(summary) = runner.finish_recording().transpose()? {
        if summary.file.is_some() {
            eprintln!("{}", summary.describe());
        }
    }
    let wall_s = started.elapsed().as_secs_f64();
    let stats = runner.scheduler().stats();
    let link_stats = runner.link().stats();
    let log = runner.log();
    if args.json {
        let report = FlightReport {
            autopilot: log.autopilot.as_deref(),
            control: args.control,
            wall_s,
            messages_received: runner.link().received_by_type(),
            messages_rejected: Rejected {
                garbled: link_stats.malformed,
                unsigned: link_stats.unsigned,
                from_others: link_stats.ignored,
            },
            battery: &log.battery,
            governor: &log.governor,
            modes: &log.modes,
            events: &log.events,
            tasks: stats.iter().map(TaskLine::from).collect(),
            frames: log.frames,
            camera_errors: log.camera_errors,
            camera: runner.camera_stats(),
            capture_to_setpoint: log.capture_to_setpoint(),
            delivered_to_setpoint: log.delivered_to_setpoint(),
            autopilot_clock: runner.link().clock_sync_stats(),
            input_rates: runner.input_rates(),
            finished: runner.status().finished,
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!(
            "{}",
            summary(log, &stats, &runner.link().clock_sync_stats(), wall_s)
        );
    }
    Ok(())
}

fn signing_key(loaded: &LoadedConfig) -> Result<Option<[u8; 32]>, Failure> {
    let Some(file) = loaded
        .config
        .link
        .as_ref()
        .and_then(|l| l.signing_key_file.clone())
    else {
        return Ok(None);
    };
    let path = loaded.base_dir().join(file);
    let bytes = std::fs::read(&path).map_err(|source| SigningKeyError::Read {
        path: path.clone(),
        source,
    })?;
    let key =
        parse_signing_key(&bytes).map_err(|source| SigningKeyError::Format { path, source })?;
    Ok(Some(key))
}

/// A MAVLink 2 signing key from a key file's bytes.
pub fn parse_signing_key(bytes: &[u8]) -> Result<[u8; 32], KeyFormatError> {
    if let Ok(raw) = <[u8; 32]>::try_from(bytes) {
        return Ok(raw);
    }
    let text = std::str::from_utf8(bytes)
        .map_err(|_| KeyFormatError::Bytes(bytes.len()))?
        .trim();
    if text.len() != 64 || !text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(KeyFormatError::Characters(text.len()));
    }
    let mut key = [0u8; 32];
    for (i, byte) in key.iter_mut().enumerate() {
        *byte = u8::from_str_radix(&text[2 * i..2 * i + 2], 16).map_err(KeyFormatError::Hex)?;
    }
    Ok(key)
}

fn summary(
    log: &MissionLog,
    stats: &[TaskStats],
    clock: &runtime::link::ClockSyncStats,
    wall_s: f64,
) -> String {
    let mut out = format!(
        "qosrt run: {:.1} s with {}; {} frames ({} lost)\n",
        wall_s,
        log.autopilot.as_deref().unwrap_or("no autopilot heard"),
        log.frames,
        log.camera_errors
    );
    let latency = log.capture_to_setpoint();
    if latency.count > 0 {
        let delivered = log.delivered_to_setpoint();
        out += &format!(
            "vision loop: capture to setpoint {:.0} ms median, {:.0} ms p99 ({} fixes); frame arrival to setpoint {:.1} ms median, {:.1} ms p99\n",
            latency.p50_us * 1e-3,
            latency.p99_us * 1e-3,
            latency.count,
            delivered.p50_us * 1e-3,
            delivered.p99_us * 1e-3,
        );
    }
    if let (Some(offset_ns), Some(round_trip_ns)) = (clock.offset_ns, clock.round_trip_ns) {
        out += &format!(
            "autopilot clock: {:+.3} s from the runtime's, to within {:.2} ms ({} of {} TIMESYNC answered)\n",
            offset_ns as f64 * 1e-9,
            round_trip_ns as f64 * 0.5e-6,
            clock.replies,
            clock.requests
        );
    }
    if let Some(last) = log.battery.last {
        out += &format!(
            "battery: {} samples; last {:.2} V, {:.1} A, {:.0} mAh consumed, {:.0} % remaining\n",
            log.battery.samples,
            last.voltage_v.unwrap_or(f64::NAN),
            last.current_a.unwrap_or(f64::NAN),
            last.consumed_mah.unwrap_or(f64::NAN),
            last.remaining_fraction.map_or(f64::NAN, |r| r * 100.0)
        );
    }
    for decision in &log.governor {
        out += &format!(
            "governor at {:.1} s: {}\n",
            decision.time_s, decision.description
        );
    }
    for stats in stats {
        out += &format!(
            "task {}: level {}, {} activations, {} failures, step p99 {:.1} µs\n",
            stats.name, stats.level, stats.activations, stats.failures, stats.step_time.p99_us
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::{parse_signing_key, KeyFormatError};

    #[test]
    fn a_signing_key_is_32_raw_bytes_or_64_hex_digits() {
        let raw: Vec<u8> = (0..32).collect();
        assert_eq!(parse_signing_key(&raw).unwrap().to_vec(), raw);
        let hex: String = raw.iter().map(|b| format!("{b:02X}")).collect();
        assert_eq!(
            parse_signing_key(format!("{hex}\n").as_bytes())
                .unwrap()
                .to_vec(),
            raw
        );
        let short = parse_signing_key(b"abcd").unwrap_err();
        assert_eq!(short, KeyFormatError::Characters(4));
        assert!(short.to_string().contains("found 4 characters"), "{short}");
        let not_hex = "zz".repeat(32);
        assert_eq!(
            parse_signing_key(not_hex.as_bytes()).unwrap_err(),
            KeyFormatError::Characters(64)
        );
        let binary = parse_signing_key(&[0xff; 31]).unwrap_err();
        assert!(binary.to_string().contains("found 31 bytes"), "{binary}");
    }
}
