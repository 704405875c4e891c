//! What the flights against the real autopilots in `../shared` share: finding a SITL, starting
//! it with its `start` script, and stopping it whatever happens.

// Each test crate uses its own part of this module.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// A SITL process, killed when dropped (a failed assertion included) with SIGKILL: PX4 waiting
/// for its simulator and ArduPilot waiting for a JSON answer both ignore SIGTERM.
pub struct SitlProcess(pub u32);

impl Drop for SitlProcess {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-9", &self.0.to_string()])
            .status();
    }
}

/// `../shared/NAME` (e.g. `px4-sitl`) when its start script is there; otherwise `None`, saying
/// so (the test skips).
pub fn shared_dir(name: &str) -> Option<PathBuf> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared")
        .join(name);
    if path.join("start").exists() {
        Some(path)
    } else {
        eprintln!("skipped: {} is absent", path.join("start").display());
        None
    }
}

/// Runs `DIR/start ARGS` with `env` and takes the pid it prints.
pub fn start(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> SitlProcess {
    let output = Command::new(dir.join("start"))
        .args(args)
        .envs(env.iter().copied())
        .stdin(Stdio::null())
        .output()
        .expect("the start script runs");
    assert!(
        output.status.success(),
        "{} did not start: {}",
        dir.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    SitlProcess(
        String::from_utf8_lossy(&output.stdout)
            .trim()
            .parse()
            .expect("the start script prints the pid"),
    )
}

/// A ground station's COMMAND_LONG to the autopilot of `target_system`.
pub fn command_long(
    target_system: u8,
    command: mavlink::dialects::common::MavCmd,
    params: [f32; 7],
) -> mavlink::dialects::common::MavMessage {
    mavlink::dialects::common::MavMessage::COMMAND_LONG(
        mavlink::dialects::common::COMMAND_LONG_DATA {
            target_system,
            target_component: 1,
            command,
            confirmation: 0,
            param1: params[0],
            param2: params[1],
            param3: params[2],
            param4: params[3],
            param5: params[4],
            param6: params[5],
            param7: params[6],
        },
    )
}
