//! End-to-end tests of `qosrt plan` and `qosrt model` on the reference mission and the shipped
//! Jetson Nano profiles.

mod common;
use common::{qosrt, repo_root};

use std::path::PathBuf;

fn plan_json(extra: &[&str]) -> (Option<i32>, serde_json::Value) {
    let mut args = vec!["plan", "qos.toml", "--json"];
    args.extend_from_slice(extra);
    let output = qosrt(&args);
    let json = serde_json::from_slice(&output.stdout).unwrap_or_else(|e| {
        panic!(
            "not JSON ({e}):\n{}\n{}",
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        )
    });
    (output.status.code(), json)
}

fn reference() -> toml::Table {
    std::fs::read_to_string(repo_root().join("qos.toml"))
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn the_reference_plan_fits_and_adds_up() {
    let (code, plan) = plan_json(&[]);
    assert_eq!(code, Some(0), "{plan}");
    assert_eq!(plan["feasible"], true);
    let energy_wh = plan["energy_wh"].as_f64().unwrap();
    let available_wh = plan["available_wh"].as_f64().unwrap();
    assert!(energy_wh <= available_wh);
    let config = reference();
    let tasks = config["task"].as_array().unwrap();
    let phases = plan["phases"].as_array().unwrap();
    assert_eq!(
        phases.len(),
        config["mission"]["phase"].as_array().unwrap().len()
    );
    let mut total_wh = 0.0;
    for phase in phases {
        let duration_s = phase["duration_s"].as_f64().unwrap();
        let power_w = phase["companion_power_w"].as_f64().unwrap()
            + phase["flight_power_w"].as_f64().unwrap();
        let phase_wh = phase["energy_wh"].as_f64().unwrap();
        assert!((phase_wh - duration_s * power_w / 3600.0).abs() < 1e-9);
        total_wh += phase_wh;
        // Every task running in the phase has a level, one of its configured values.
        let name = phase["name"].as_str().unwrap();
        for task in tasks {
            let runs = task["phases"]
                .as_array()
                .unwrap()
                .iter()
                .any(|p| p.as_str() == Some(name));
            let chosen = &phase["levels"][task["name"].as_str().unwrap()];
            assert_eq!(runs, !chosen.is_null(), "phase {name}: {phase}");
            if runs {
                let levels = task["levels"].as_array().unwrap();
                assert!(levels.iter().any(|l| l.as_float() == chosen.as_f64()));
            }
        }
    }
    assert!((total_wh - energy_wh).abs() < 1e-9);
    let margin_wh = plan["margin_wh"].as_f64().unwrap();
    assert!((margin_wh - (available_wh - energy_wh)).abs() < 1e-9);
    // The frontier's best point within the budget is the plan.
    let best_within = plan["pareto_frontier"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["energy_wh"].as_f64().unwrap() <= available_wh)
        .map(|p| p["utility"].as_f64().unwrap())
        .fold(f64::NEG_INFINITY, f64::max);
    assert_eq!(best_within, plan["utility"].as_f64().unwrap());
}

#[test]
fn more_battery_never_lowers_the_utility_and_enough_buys_everything() {
    let mut previous = f64::NEG_INFINITY;
    let mut first = None;
    for battery_wh in ["74", "74.2", "74.4", "74.6", "90"] {
        let (code, plan) = plan_json(&["--battery-wh", battery_wh]);
        assert_eq!(code, Some(0), "{battery_wh} Wh: {plan}");
        let utility = plan["utility"].as_f64().unwrap();
        assert!(
            utility >= previous,
            "{battery_wh} Wh: {utility} < {previous}"
        );
        previous = utility;
        first.get_or_insert(utility);
    }
    // The range spans real trade-offs: the smallest pack cannot buy everything.
    assert!(first.unwrap() < previous);
    let (_, plan) = plan_json(&["--battery-wh", "200"]);
    assert_eq!(plan["utility"], plan["max_utility"]);
}

#[test]
fn an_impossible_budget_exits_3_with_the_shortfall() {
    let (code, plan) = plan_json(&["--battery-wh", "30"]);
    assert_eq!(code, Some(3));
    assert_eq!(plan["feasible"], false);
    assert!(plan["energy_wh"].as_f64().unwrap() > plan["available_wh"].as_f64().unwrap());
    let output = qosrt(&["plan", "qos.toml", "--battery-wh", "30"]);
    assert_eq!(output.status.code(), Some(3));
    let stderr = String::from_utf8_lossy(&output.stderr);
    let shortfall = plan["energy_wh"].as_f64().unwrap() - plan["available_wh"].as_f64().unwrap();
    assert!(
        stderr.contains(&format!("short by {shortfall:.2} Wh")),
        "{stderr}"
    );
}

#[test]
fn a_larger_reserve_leaves_less_to_spend() {
    let (_, loose) = plan_json(&["--reserve", "0.1"]);
    let (_, tight) = plan_json(&["--reserve", "0.3"]);
    assert!(tight["available_wh"].as_f64().unwrap() < loose["available_wh"].as_f64().unwrap());
    assert!(tight["utility"].as_f64().unwrap() <= loose["utility"].as_f64().unwrap());
    let output = qosrt(&["plan", "--reserve", "1.5"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("--reserve must be a fraction"));
}

#[test]
fn the_svg_plots_the_frontier() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("frontier.svg");
    let output = qosrt(&["plan", "--svg", svg.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(0));
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg") && text.contains("energy budget"));
    assert!(text.contains("chosen plan"));
}

/// A scratch copy of the reference mission whose landing phase is modelled by a profile with
/// the given text; returns (folder, config path, config text, profile path).
fn mission_with_landing_profile(
    profile_text: &str,
) -> (tempfile::TempDir, PathBuf, String, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let profile = dir.path().join("landing-profile.toml");
    std::fs::write(&profile, profile_text).unwrap();
    let text = std::fs::read_to_string(repo_root().join("qos.toml"))
        .unwrap()
        .replace(
            "path = \"profiles/",
            &format!("path = \"{}/profiles/", repo_root().display()),
        )
        .replacen(
            &format!(
                "{}/profiles/jetson-nano-seed/landing.toml",
                repo_root().display()
            ),
            profile.to_str().unwrap(),
            1,
        );
    let config = dir.path().join("qos.toml");
    std::fs::write(&config, &text).unwrap();
    (dir, config, text, profile)
}

#[test]
fn a_profile_knob_no_task_has_is_an_error_in_the_config() {
    let (_dir, config, text, profile) = mission_with_landing_profile(
        "board = \"x\"\nmeter = \"y\"\nknobs = [\"radar.rate_fps\"]\n[[sample]]\nknobs = [1.0]\npower_w = 3.0\n[[sample]]\nknobs = [2.0]\npower_w = 4.0\n",
    );
    let output = qosrt(&["plan", config.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&output.stderr);
    let offset = text.find(profile.to_str().unwrap()).unwrap() - 1;
    let line = text[..offset].matches('\n').count() + 1;
    let column = offset - text[..offset].rfind('\n').unwrap();
    assert!(
        stderr.contains(&format!(
            "{}:{line}:{column}: error: profile `{}` models knob `radar.rate_fps`, which no task has",
            config.display(),
            profile.display()
        )),
        "{stderr}"
    );
}

#[test]
fn a_broken_profile_is_located_in_the_profile() {
    let (_dir, config, _, profile) = mission_with_landing_profile(
        "board = \"x\"\nmeter = \"y\"\nknobs = [\"detection.rate_fps\"]\n[[sample]]\nknobs = [1.0]\npower_w = \"three\"\n",
    );
    let output = qosrt(&["plan", config.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.starts_with(&format!("{}:6:11: error:", profile.display())),
        "{stderr}"
    );
}

#[test]
fn model_evaluates_at_grid_points_and_reports_loo() {
    // At a measured point the model returns the measurement (figure typed from the profile).
    let output = qosrt(&[
        "model",
        "profiles/jetson-nano-seed/tracking.toml",
        "--json",
        "--loo",
        "--at",
        "hazard.rate_fps=1",
        "--at",
        "detection.rate_fps=10",
    ]);
    assert_eq!(output.status.code(), Some(0));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let profile: toml::Table =
        std::fs::read_to_string(repo_root().join("profiles/jetson-nano-seed/tracking.toml"))
            .unwrap()
            .parse()
            .unwrap();
    let measured = profile["sample"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| {
            let knobs = s["knobs"].as_array().unwrap();
            knobs[0].as_float() == Some(1.0) && knobs[1].as_float() == Some(10.0)
        })
        .unwrap()["power_w"]
        .as_float()
        .unwrap();
    assert!((report["evaluation"]["power_w"].as_f64().unwrap() - measured).abs() < 1e-9);
    assert_eq!(report["evaluation"]["extrapolated"], false);
    let loo = &report["leave_one_out"];
    let points = loo["per_point"].as_array().unwrap();
    assert_eq!(points.len(), profile["sample"].as_array().unwrap().len());
    let mean: f64 = points
        .iter()
        .map(|p| p["abs_pct_error"].as_f64().unwrap())
        .sum::<f64>()
        / points.len() as f64;
    assert!((loo["mape_pct"].as_f64().unwrap() - mean).abs() < 1e-9);

    // Outside the grid the value is clamped and said to be.
    let output = qosrt(&[
        "model",
        "profiles/jetson-nano-seed/tracking.toml",
        "--at",
        "hazard.rate_fps=30",
        "--at",
        "detection.rate_fps=10",
    ]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        stdout.contains("extrapolated: hazard.rate_fps clamped"),
        "{stdout}"
    );

    // A knob the model lacks is a clear error.
    let output = qosrt(&[
        "model",
        "profiles/jetson-nano-seed/tracking.toml",
        "--at",
        "radar.rate_fps=1",
    ]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&output.stderr).contains("the model has no knob `radar.rate_fps`")
    );
}
