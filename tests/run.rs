//! End-to-end tests of `qosrt run --dry-run`: the real registry, scheduler and governor on
//! synthetic frames and battery telemetry.

mod common;
use common::qosrt;

use std::path::PathBuf;

/// A landing-only mission whose one task is the built-in landing-marker detector.
fn detection_mission(dir: &tempfile::TempDir) -> PathBuf {
    let profile =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("profiles/jetson-nano-seed/landing.toml");
    let text = format!(
        r#"
[mission]
name = "pad-check"
reserve_fraction = 0.2
[[mission.phase]]
name = "landing"
duration_s = 60.0

[battery]
capacity_wh = 74.0
cell_count = 4

[flight]
hover_power_w = 160.0

[power_model]
[[power_model.profile]]
path = "{}"
phases = ["landing"]

[[task]]
name = "detection"
plugin = "landing_marker"
resource = "cpu"
phases = ["landing"]
weight = 1.0
knob = "rate_fps"
levels = [0.5, 1.0, 2.0, 10.0]
utility = [0.1, 0.3, 0.5, 1.0]
"#,
        profile.display()
    );
    let path = dir.path().join("mission.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn a_dry_run_steps_the_detector_at_its_planned_rate_and_prints_its_statistics() {
    let dir = tempfile::tempdir().unwrap();
    let mission = detection_mission(&dir);
    let output = qosrt(&[
        "run",
        mission.to_str().unwrap(),
        "--dry-run",
        "--duration-s",
        "2",
    ]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert_eq!(
        output.status.code(),
        Some(0),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let row = stdout
        .lines()
        .find(|l| l.starts_with("detection"))
        .unwrap_or_else(|| panic!("no detection row:\n{stdout}"));
    let fields: Vec<&str> = row.split_whitespace().collect();
    // The battery is ample: the governor keeps the top level, 10 fps = 100 ms.
    assert_eq!(fields[1], "3", "{row}");
    assert_eq!(fields[2], "100.0", "{row}");
    let activations: u64 = fields[4].parse().unwrap();
    // 2 s at 10 fps, give or take the start and the end.
    assert!((18..=22).contains(&activations), "{row}");
    assert_eq!(fields[7], "0", "failures: {row}");
    assert!(stdout.contains("synthetic frames"));
}

#[test]
fn the_reference_mission_dry_runs_all_four_tasks() {
    let output = qosrt(&["run", "qos.toml", "--dry-run", "--duration-s", "3"]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert_eq!(
        output.status.code(),
        Some(0),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    for task in ["detection", "tracking", "landing", "hazard"] {
        let row = stdout
            .lines()
            .find(|l| l.starts_with(task))
            .unwrap_or_else(|| panic!("no {task} row:\n{stdout}"));
        let fields: Vec<&str> = row.split_whitespace().collect();
        let activations: u64 = fields[4].parse().unwrap();
        assert!(activations >= 1, "{row}");
        assert_eq!(fields[7], "0", "failures: {row}");
    }
    // The rendered pad gave fixes, and the landing chain turned them into setpoints.
    let latency = stdout
        .lines()
        .find(|l| l.starts_with("frame to setpoint"))
        .unwrap_or_else(|| panic!("no frame-to-setpoint line:\n{stdout}"));
    let frames: u64 = latency
        .split_whitespace()
        .rev()
        .nth(1)
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{latency}"));
    assert!(frames >= 10, "{latency}");
}

#[test]
fn a_plugin_this_binary_lacks_is_a_located_error() {
    let dir = tempfile::tempdir().unwrap();
    let mission = detection_mission(&dir);
    let text = std::fs::read_to_string(&mission)
        .unwrap()
        .replace("plugin = \"landing_marker\"", "plugin = \"my_detector\"");
    std::fs::write(&mission, &text).unwrap();
    let output = qosrt(&["run", mission.to_str().unwrap(), "--dry-run"]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&output.stderr);
    let offset = text.find("\"my_detector\"").unwrap();
    let line = text[..offset].matches('\n').count() + 1;
    let column = offset - text[..offset].rfind('\n').unwrap();
    assert!(
        stderr.contains(&format!(
            "{}:{line}:{column}: error: unknown plugin `my_detector`",
            mission.display()
        )),
        "{stderr}"
    );
}

#[test]
fn a_dry_run_needs_a_sensible_duration() {
    let output = qosrt(&["run", "--dry-run", "--duration-s=0"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("--duration-s"));
}
