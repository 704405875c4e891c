//! End-to-end tests of `qosrt check`: the reference mission, and bad configs that must each exit 2
//! with `FILE:LINE:COL: error: MESSAGE` pointing at the offending text.

mod common;
use common::{qosrt, repo_root};

#[path = "check/bad_cases.rs"]
mod bad_cases;
use bad_cases::BAD_CASES;

use std::path::{Path, PathBuf};
use std::process::Output;

const EXIT_INVALID_CONFIG: i32 = 2;

fn reference_text() -> String {
    std::fs::read_to_string(repo_root().join("qos.toml")).expect("the reference qos.toml exists")
}

/// The reference config with its profile paths made absolute, so it can live in a temp folder.
fn relocatable_reference() -> String {
    let profiles = repo_root().join("profiles");
    reference_text().replace(
        "path = \"profiles/",
        &format!("path = \"{}/", profiles.display()),
    )
}

fn write_temp(dir: &tempfile::TempDir, name: &str, text: &[u8]) -> PathBuf {
    let path = dir.path().join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// 1-based line and column of byte `offset`, counted independently of the crate under test.
fn expected_location(text: &str, offset: usize) -> (usize, usize) {
    let mut line = 1;
    let mut column = 1;
    for (index, character) in text.char_indices() {
        if index == offset {
            break;
        }
        if character == '\n' {
            line += 1;
            column = 1;
        } else {
            column += 1;
        }
    }
    (line, column)
}

fn nth_offset(text: &str, marker: &str, occurrence: usize) -> Option<usize> {
    text.match_indices(marker).nth(occurrence).map(|(i, _)| i)
}

#[test]
fn the_reference_mission_is_valid() {
    let output = qosrt(&["check", "qos.toml"]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert_eq!(
        output.status.code(),
        Some(0),
        "stdout: {stdout}\nstderr: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(stdout.contains("valid"));
    for task in ["detection", "tracking", "landing", "hazard"] {
        assert!(
            stdout.contains(task),
            "summary lacks task {task}:\n{stdout}"
        );
    }
}

#[test]
fn the_json_summary_says_what_the_file_says() {
    let output = qosrt(&["check", "--json", "qos.toml"]);
    assert_eq!(output.status.code(), Some(0));
    let summary: serde_json::Value = serde_json::from_slice(&output.stdout).expect("valid JSON");
    assert_eq!(summary["valid"], true);

    // Read the file independently, as plain TOML, and compare.
    let file: toml::Table = reference_text().parse().unwrap();
    let file_tasks = file["task"].as_array().unwrap();
    let json_tasks = summary["tasks"].as_array().unwrap();
    assert_eq!(json_tasks.len(), 4);
    assert_eq!(json_tasks.len(), file_tasks.len());
    for (json_task, file_task) in json_tasks.iter().zip(file_tasks) {
        assert_eq!(json_task["name"], file_task["name"].as_str().unwrap());
        assert_eq!(json_task["plugin"], file_task["plugin"].as_str().unwrap());
        assert_eq!(
            json_task["resource"],
            file_task["resource"].as_str().unwrap()
        );
        assert_eq!(json_task["knob"], file_task["knob"].as_str().unwrap());
        let file_levels = file_task["levels"].as_array().unwrap();
        let file_utility = file_task["utility"].as_array().unwrap();
        let json_levels = json_task["levels"].as_array().unwrap();
        assert_eq!(json_levels.len(), file_levels.len());
        for ((json_level, value), utility) in json_levels.iter().zip(file_levels).zip(file_utility)
        {
            let value = value.as_float().unwrap();
            assert_eq!(json_level["value"].as_f64().unwrap(), value);
            assert_eq!(
                json_level["utility"].as_f64().unwrap(),
                utility.as_float().unwrap()
            );
            let period_ms = if file_task["knob"].as_str() == Some("rate_fps") {
                1000.0 / value
            } else {
                value
            };
            assert!((json_level["period_ms"].as_f64().unwrap() - period_ms).abs() < 1e-9);
        }
    }
    let file_phases = file["mission"]["phase"].as_array().unwrap();
    let json_phases = summary["phases"].as_array().unwrap();
    assert_eq!(json_phases.len(), file_phases.len());
    for (json_phase, file_phase) in json_phases.iter().zip(file_phases) {
        assert_eq!(json_phase["name"], file_phase["name"].as_str().unwrap());
        assert_eq!(json_phase["kind"], file_phase["kind"].as_str().unwrap());
        assert_eq!(
            json_phase["duration_s"].as_f64().unwrap(),
            file_phase["duration_s"].as_float().unwrap()
        );
    }
    let battery = &file["battery"];
    let capacity_wh = battery["capacity_mah"].as_float().unwrap() / 1000.0
        * battery["nominal_cell_voltage_v"].as_float().unwrap()
        * battery["cell_count"].as_integer().unwrap() as f64;
    assert!((summary["battery"]["capacity_wh"].as_f64().unwrap() - capacity_wh).abs() < 1e-9);
}

/// `--graph` prints who feeds whom; each line checked against the reference mission's tasks as
/// the file names them (read here as plain TOML) and the plugins' documented ports.
#[test]
fn the_graph_shows_the_reference_missions_dataflow() {
    let output = qosrt(&["check", "qos.toml", "--graph"]);
    assert_eq!(output.status.code(), Some(0));
    let text = String::from_utf8(output.stdout).unwrap();
    let file: toml::Table = reference_text().parse().unwrap();
    let headers: Vec<String> = file["task"]
        .as_array()
        .unwrap()
        .iter()
        .map(|task| {
            format!(
                "{} ({})",
                task["name"].as_str().unwrap(),
                task["plugin"].as_str().unwrap()
            )
        })
        .collect();
    let found: Vec<&str> = text.lines().filter(|line| !line.starts_with(' ')).collect();
    assert_eq!(found, headers, "{text}");
    for line in [
        "  reads  camera/frame (CameraFrame) ← camera",
        "  writes vision/landing_marker (MarkerObservation) → tracking",
        "  reads  vision/landing_marker (MarkerObservation) ← detection",
        "  writes landing/setpoint (LandingSetpoint) → autopilot",
    ] {
        assert!(text.lines().any(|l| l == line), "no `{line}` in\n{text}");
    }

    let output = qosrt(&["check", "--graph", "dot", "qos.toml"]);
    assert_eq!(output.status.code(), Some(0));
    let dot = String::from_utf8(output.stdout).unwrap();
    assert!(dot.starts_with("digraph \"tractor-landing\" {"), "{dot}");
    assert!(
        dot.contains("\"task:detection\" -> \"task:tracking\" [label=\"vision/landing_marker\"];")
    );
    assert!(dot.contains("\"task:landing\" -> \"mission:autopilot\" [label=\"landing/setpoint\"];"));

    // The file after `--graph` is the file, not the graph's format; `--graph-format` names one.
    for flags in [
        &["--graph", "qos.toml"][..],
        &["qos.toml", "--graph-format", "text"],
    ] {
        let output = qosrt(&[&["check"][..], flags].concat());
        assert_eq!(output.status.code(), Some(0), "{flags:?}");
        assert_eq!(String::from_utf8(output.stdout).unwrap(), text, "{flags:?}");
    }
    let output = qosrt(&["check", "--graph-format", "dot", "qos.toml"]);
    assert_eq!(String::from_utf8(output.stdout).unwrap(), dot);

    let output = qosrt(&["check", "qos.toml", "--json", "--graph"]);
    let graph: serde_json::Value = serde_json::from_slice(&output.stdout).expect("JSON");
    let edges = graph["edges"].as_array().unwrap();
    assert_eq!(edges.len(), dot.matches(" -> ").count());
    assert!(graph["unfed"].as_array().unwrap().is_empty());
}

fn check_bad(text: &[u8], file_name: &str) -> (tempfile::TempDir, PathBuf, Output) {
    let dir = tempfile::tempdir().unwrap();
    let path = write_temp(&dir, file_name, text);
    let output = qosrt(&["check", path.to_str().unwrap()]);
    (dir, path, output)
}

#[test]
fn each_bad_config_exits_2_pointing_at_the_mistake() {
    let base = relocatable_reference();
    let mut failures = Vec::new();
    for case in BAD_CASES {
        let mut text = base.clone();
        for (from, to) in case.replace {
            assert!(
                text.contains(from),
                "case `{}`: `{from}` not in the reference",
                case.name
            );
            text = text.replacen(from, to, 1);
        }
        let (_dir, path, output) = check_bad(text.as_bytes(), "bad.toml");
        let stderr = String::from_utf8_lossy(&output.stderr).to_string();
        if output.status.code() != Some(EXIT_INVALID_CONFIG) {
            failures.push(format!(
                "{}: exit {:?}\n{stderr}",
                case.name,
                output.status.code()
            ));
            continue;
        }
        let error_lines: Vec<&str> = stderr.lines().filter(|l| l.contains(": error: ")).collect();
        if error_lines.len() != case.expect.len() {
            failures.push(format!(
                "{}: expected {} error(s), got {}:\n{stderr}",
                case.name,
                case.expect.len(),
                error_lines.len()
            ));
            continue;
        }
        for expect in case.expect {
            let (line, column) = match expect.marker {
                None => (1, 1),
                Some((marker, occurrence)) => match nth_offset(&text, marker, occurrence) {
                    Some(offset) => expected_location(&text, offset),
                    None => panic!("case `{}`: marker `{marker}` not in the text", case.name),
                },
            };
            let prefix = format!("{}:{line}:{column}: error: ", path.display());
            let found = error_lines
                .iter()
                .any(|l| l.starts_with(&prefix) && l.contains(expect.message));
            if !found {
                failures.push(format!(
                    "{}: no error `{prefix}…{}…`; got:\n{stderr}",
                    case.name, expect.message
                ));
            }
        }
        // The offending line is shown under the message, with a caret.
        assert!(stderr.contains(" | ") && stderr.contains('^'), "{stderr}");
    }
    assert!(BAD_CASES.len() >= 20);
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn an_empty_file_is_an_error_at_its_start() {
    for text in ["", "   \n\n# only a comment\n"] {
        let (_dir, path, output) = check_bad(text.as_bytes(), "empty.toml");
        assert_eq!(output.status.code(), Some(EXIT_INVALID_CONFIG));
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            stderr.starts_with(&format!("{}:1:1: error: the file is empty", path.display())),
            "{stderr}"
        );
    }
}

#[test]
fn a_file_that_is_not_utf8_points_at_the_bad_byte() {
    let mut bytes = b"[mission]\nname = \"tr".to_vec();
    bytes.push(0xff);
    bytes.extend_from_slice(b"ctor\"\n");
    let (_dir, path, output) = check_bad(&bytes, "binary.toml");
    assert_eq!(output.status.code(), Some(EXIT_INVALID_CONFIG));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.starts_with(&format!(
            "{}:2:11: error: the file is not UTF-8",
            path.display()
        )),
        "{stderr}"
    );
}

#[test]
fn an_unreadable_file_is_a_located_error() {
    let missing = Path::new("no/such/mission.toml");
    let output = qosrt(&["check", missing.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(EXIT_INVALID_CONFIG));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.starts_with("no/such/mission.toml:1:1: error: cannot read the config file"),
        "{stderr}"
    );
}

#[test]
fn json_errors_carry_file_line_and_column() {
    let text = relocatable_reference().replacen("cell_count = 4 ", "cell_count = 0 ", 1);
    let dir = tempfile::tempdir().unwrap();
    let path = write_temp(&dir, "bad.toml", text.as_bytes());
    let output = qosrt(&["check", "--json", path.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(EXIT_INVALID_CONFIG));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["valid"], false);
    let errors = report["errors"].as_array().unwrap();
    assert_eq!(errors.len(), 1);
    let offset = text.find("cell_count = 0").unwrap() + "cell_count = ".len();
    let (line, column) = expected_location(&text, offset);
    assert_eq!(errors[0]["line"], line);
    assert_eq!(errors[0]["column"], column);
    assert_eq!(errors[0]["file"], path.to_str().unwrap());
}

/// Random damage to the reference file never crashes `check`: it exits 0 or 2, and on 2 every
/// message is located.
#[test]
fn damaged_files_never_panic() {
    let base = relocatable_reference().into_bytes();
    let dir = tempfile::tempdir().unwrap();
    // A small deterministic generator keeps the test reproducible without a dependency.
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let replacements = b"[]{}=\"'.,#\n 0-x";
    for round in 0..120 {
        let mut bytes = base.clone();
        match round % 3 {
            0 => bytes.truncate((next() as usize) % bytes.len()),
            1 => {
                for _ in 0..3 {
                    let at = (next() as usize) % bytes.len();
                    bytes[at] = replacements[(next() as usize) % replacements.len()];
                }
            }
            _ => {
                let at = (next() as usize) % bytes.len();
                let len = ((next() as usize) % 40).min(bytes.len() - at);
                bytes.drain(at..at + len);
            }
        }
        let path = write_temp(&dir, "damaged.toml", &bytes);
        let output = qosrt(&["check", path.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        match output.status.code() {
            Some(0) => {}
            Some(EXIT_INVALID_CONFIG) => {
                let prefix = format!("{}:", path.display());
                for line in stderr.lines().filter(|l| l.contains(": error: ")) {
                    let rest = line
                        .strip_prefix(&prefix)
                        .unwrap_or_else(|| panic!("{line}"));
                    let mut parts = rest.splitn(3, ':');
                    let line_no: usize = parts.next().unwrap().parse().unwrap();
                    let column: usize = parts.next().unwrap().parse().unwrap();
                    assert!(line_no >= 1 && column >= 1);
                }
            }
            other => panic!("round {round}: exit {other:?}\n{stderr}"),
        }
    }
}
