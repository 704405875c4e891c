//! `configs/ardupilot.toml`: the reference mission with the landing's close-in controller set
//! for ArduPilot's GUIDED. It checks, and it is the reference config in everything else, so
//! that the two cannot drift apart (the real ArduPilot flies it in `sitl/tests/real_autopilots.rs`
//! and in the evaluation, docs/simulator.md).

mod common;
use common::{output_text, qosrt, repo_root};

/// The landing task's parameters the ArduPilot config sets its own way.
const ARDUPILOT_LANDING_KEYS: [&str; 3] = [
    "proportional_gain_close_per_s",
    "derivative_gain_close",
    "flare_lead_s",
];

#[test]
fn the_ardupilot_config_checks() {
    let out = qosrt(&["check", "configs/ardupilot.toml"]);
    assert!(out.status.success(), "{}", output_text(&out));
}

fn read(path: &str) -> toml::Table {
    let text = std::fs::read_to_string(repo_root().join(path)).unwrap();
    text.parse().unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// The landing task's table in `config`.
fn landing_params(config: &mut toml::Table) -> &mut toml::Table {
    config["task"]
        .as_array_mut()
        .unwrap()
        .iter_mut()
        .find(|task| task["plugin"].as_str() == Some("landing_guidance"))
        .expect("a landing_guidance task")["params"]
        .as_table_mut()
        .unwrap()
}

#[test]
fn the_ardupilot_config_is_the_reference_one_but_for_the_close_in_landing() {
    let mut reference = read("qos.toml");
    let mut ardupilot = read("configs/ardupilot.toml");
    // Softer close-in, a longer flare lead: what was measured with ArduPilot.
    let (r, a) = (
        landing_params(&mut reference),
        landing_params(&mut ardupilot),
    );
    let value = |table: &toml::Table, key: &str| table[key].as_float().unwrap();
    assert!(value(a, ARDUPILOT_LANDING_KEYS[0]) < value(r, ARDUPILOT_LANDING_KEYS[0]));
    assert!(value(a, ARDUPILOT_LANDING_KEYS[1]) < value(r, ARDUPILOT_LANDING_KEYS[1]));
    assert!(value(a, ARDUPILOT_LANDING_KEYS[2]) > value(r, ARDUPILOT_LANDING_KEYS[2]));
    for key in ARDUPILOT_LANDING_KEYS {
        r.remove(key);
        a.remove(key);
    }
    // Its own name, and the profiles found from configs/.
    for config in [&mut reference, &mut ardupilot] {
        config["mission"].as_table_mut().unwrap().remove("name");
        for profile in config["power_model"]["profile"].as_array_mut().unwrap() {
            let path = profile["path"].as_str().unwrap().trim_start_matches("../");
            profile["path"] = toml::Value::String(path.to_string());
        }
    }
    assert_eq!(reference, ardupilot);
}
