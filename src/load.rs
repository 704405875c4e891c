//! A command's mission: its config and power models loaded, their mistakes reported located.

use crate::check::report_failure;
use runtime::config::load_file;
use runtime::energy::{load_mission_model, MissionModel};
use runtime::plugins::builtin_registry;
use runtime::registry::PluginRegistry;
use std::path::Path;

/// The mission at `file` and the built-in plugins to fly it with.
pub fn load(file: &Path, json: bool) -> Option<(MissionModel, PluginRegistry)> {
    let registry = match builtin_registry() {
        Ok(registry) => registry,
        Err(error) => {
            eprintln!("error: {error}");
            return None;
        }
    };
    Some((load_model(file, json)?, registry))
}

/// The config at `file` and everything it refers to, its mistakes reported located. The full
/// catalogue: a task whose plugin this build lacks is reported and flown without.
pub fn load_model(file: &Path, json: bool) -> Option<MissionModel> {
    let loaded = match load_file(file, &runtime::catalog::PluginCatalog::builtin()) {
        Ok(loaded) => loaded,
        Err(failure) => {
            report_failure(&failure, json);
            return None;
        }
    };
    match load_mission_model(&loaded) {
        Ok(model) => Some(model),
        Err(reports) => {
            for report in &reports {
                report_failure(report, json);
            }
            None
        }
    }
}
