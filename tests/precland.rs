//! `configs/precland.toml`: the reference mission landed by the autopilot's own precision
//! landing. The config checks, and the built-in autopilot, which has none, refuses it by name
//! before flying (the real PX4's precision landing is flown in the evaluation, see
//! docs/simulator.md).

mod common;
use common::{output_text, qosrt};

#[test]
fn the_precland_config_checks() {
    let out = qosrt(&["check", "configs/precland.toml"]);
    assert!(out.status.success(), "{}", output_text(&out));
}

#[test]
fn the_built_in_autopilot_refuses_a_precision_landing_by_name() {
    let out = qosrt(&["sim", "configs/precland.toml", "--tracking-s", "5"]);
    assert!(!out.status.success(), "flew a precision landing it has not");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("the built-in autopilot has no precision landing")
            && stderr.contains("--autopilot px4"),
        "{stderr}"
    );
}
