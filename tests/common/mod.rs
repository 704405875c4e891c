//! What every end-to-end test needs: the `qosrt` binary run from the repository's root.

// Each test crate uses its own part of this module.
#![allow(dead_code)]

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The repository's root, where the reference `qos.toml` and `profiles/` are.
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `qosrt` with `args` in the repository's root and waits for it.
pub fn qosrt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .args(args)
        .current_dir(repo_root())
        .output()
        .expect("the qosrt binary runs")
}

/// Its standard output followed by its standard error, as text.
pub fn output_text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

/// A running PX4 SITL instance, stopped when dropped.
pub struct Px4 {
    pub pid: u32,
    pub instance: u8,
}

impl Px4 {
    /// Starts instance `instance`, or `None` (with a message) when the SITL is not here.
    pub fn start(instance: u8) -> Option<Self> {
        let start = repo_root().join("../shared/px4-sitl/start");
        if !start.exists() {
            eprintln!("skipped: {} is absent", start.display());
            return None;
        }
        let output = Command::new(&start)
            .args(["-i", &instance.to_string()])
            .output()
            .expect("the PX4 start script runs");
        assert!(
            output.status.success(),
            "PX4 did not start: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        let pid = String::from_utf8_lossy(&output.stdout)
            .trim()
            .parse()
            .expect("the start script prints PX4's pid");
        Some(Self { pid, instance })
    }

    /// The companion computer's link, as `qosrt run` takes it.
    pub fn mavlink(&self) -> String {
        format!("udpin:0.0.0.0:{}", 14540 + u16::from(self.instance))
    }
}

impl Drop for Px4 {
    fn drop(&mut self) {
        let _ = Command::new("kill").arg(self.pid.to_string()).status();
    }
}

/// The reference mission, made short: 4 s of tracking.
pub fn short_mission(dir: &Path, tracking_s: f64) -> PathBuf {
    let text = std::fs::read_to_string(repo_root().join("qos.toml")).unwrap();
    let text = text
        .replace("duration_s = 900.0", &format!("duration_s = {tracking_s}"))
        .replace(
            "path = \"profiles/",
            &format!("path = \"{}/profiles/", repo_root().display()),
        );
    let path = dir.join("short.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Waits for qosrt to exit (killing it after `limit`) and parses its JSON report; stderr is
/// handed back for messages.
pub fn report_of(child: Child, limit: Duration) -> (Value, String) {
    try_report_of(child, limit).unwrap_or_else(|message| panic!("{message}"))
}

/// As `report_of`, but a missing report is handed back, with the exit status and stderr, for
/// a test that has the other process's side of the story to tell too.
pub fn try_report_of(mut child: Child, limit: Duration) -> Result<(Value, String), String> {
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > limit {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    match serde_json::from_slice(&output.stdout) {
        Ok(report) => Ok((report, stderr)),
        Err(e) => Err(format!(
            "no JSON report ({e}), exit {:?}; stderr:\n{stderr}",
            output.status
        )),
    }
}

/// Starts `qosrt SUBCOMMAND CONFIG ARGS…` in the background, its output piped.
pub fn qosrt_spawn(subcommand: &str, config: &Path, args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .arg(subcommand)
        .arg(config)
        .args(args)
        .current_dir(repo_root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("qosrt runs")
}

/// `qosrt run CONFIG ARGS…` in the background.
pub fn qosrt_run(config: &Path, args: &[&str]) -> Child {
    qosrt_spawn("run", config, args)
}

/// The short mission of seed 2 recorded to `file`, with `extra` flags.
pub fn record_short_mission(file: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "sim",
        "--tracking-s",
        "3",
        "--seed",
        "2",
        "--record",
        file.to_str().unwrap(),
    ];
    args.extend(extra);
    let sim = qosrt(&args);
    assert!(sim.status.success(), "{}", output_text(&sim));
    sim
}

/// Cyclone DDS's discovery for the test clients: multicast as by default, and beside it unicast
/// to the well-known ports of this host's participants (where RustDDS listens too), announced
/// every second rather than every 30 s, so that one lost announcement does not leave a short
/// mission unheard. A client once heard nothing of a 30 s mission in a CI run; its stderr now
/// says how many writers each of its readers ever matched.
const CYCLONE_DISCOVERY: &str = "<CycloneDDS><Domain Id=\"any\"><Discovery>\
    <ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>\
    <Peers><Peer Address=\"127.0.0.1\"/></Peers><SPDPInterval>1s</SPDPInterval>\
    </Discovery></Domain></CycloneDDS>";

/// A Cyclone DDS client: `script` under `tests/ros2/`, run by the binding's Python with Cyclone
/// DDS's own discovery (as the benchmark runs it).
pub fn cyclone_script(python: &std::path::Path, script: &str) -> Command {
    let mut command = Command::new(python);
    command
        .current_dir(repo_root().join("tests/ros2"))
        .arg(script);
    command
}

/// A test's Cyclone DDS client: [`cyclone_script`] with the tests' discovery.
pub fn cyclone_client(python: &std::path::Path, script: &str) -> Command {
    let mut command = cyclone_script(python, script);
    command.env("CYCLONEDDS_URI", CYCLONE_DISCOVERY);
    command
}

/// A Python with Cyclone DDS's binding, installed once under `target/`; `None`, said, where it
/// cannot be installed (no network to PyPI, no Python).
pub fn cyclonedds_python() -> Option<PathBuf> {
    let venv = repo_root().join("target/ros2-test-venv");
    let python = venv.join("bin/python");
    let has_binding = |python: &PathBuf| {
        Command::new(python)
            .args(["-c", "import cyclonedds.domain"])
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if has_binding(&python) {
        return Some(python);
    }
    let steps: [&[&str]; 2] = [
        &["python3", "-m", "venv", venv.to_str().unwrap()],
        &[
            python.to_str().unwrap(),
            "-m",
            "pip",
            "install",
            "--quiet",
            "cyclonedds==11.0.1",
        ],
    ];
    for step in steps {
        let status = Command::new(step[0]).args(&step[1..]).output();
        if !status.as_ref().is_ok_and(|o| o.status.success()) {
            eprintln!(
                "skipped: cannot install Cyclone DDS's Python binding ({}): {:?}",
                step.join(" "),
                status.map(|o| String::from_utf8_lossy(&o.stderr).into_owned())
            );
            return None;
        }
    }
    has_binding(&python).then_some(python)
}
