//! What every end-to-end test needs: the `qosrt` binary run from the repository's root.

// Each test crate uses its own part of this module.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

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
