//! `qosrt sim --evaluate`: the landing evaluation, every world × landing-marker rate × wind ×
//! path with `--runs` seeds per cell, flown whole or as one shard of a sweep split across
//! machines; and `qosrt sim --merge`, which joins the shards' files into the table the whole
//! evaluation gives.
//!
//! A shard file holds the evaluation's identity and each run's record, enough to compute every
//! statistic of the table again: the whole evaluation tabulates itself as the merge of its one
//! shard, so a merged sweep and an unsharded run print the same table.

use crate::check::EXIT_INVALID_CONFIG;
use crate::sim::args::SimArgs;
use fly::fly_all;
use runtime::energy::MissionModel;
use runtime::registry::PluginRegistry;
use serde::{Deserialize, Serialize};
use sim::tractor::PathKind;
use sim::world::WorldOptions;
use sitl::mission::SimOptions;
use sitl::outcome::{SimOutcome, SimSummary};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::ExitCode;

#[cfg(test)]
mod tests;

/// Seeds per cell unless `--runs` says otherwise.
pub const DEFAULT_RUNS: usize = 20;

/// The tracking phase of an evaluation mission. The tractor pulls away when tracking begins and
/// the turn paths turn 30 m on, about 21 s later at 1.5 m/s: 15 s of tracking puts the turn in
/// the middle of the landing.
pub const TRACKING_S: f64 = 15.0;

/// The tractor's speed in every cell but the fast one.
const TRACTOR_SPEED_M_S: f64 = 1.5;
/// The fast cell: the tractor at twice the speed through the 180° turn in 8 m/s gusts, where the
/// follower is pushed hardest.
const FAST_TRACTOR_SPEED_M_S: f64 = 3.0;

/// The shard file's layout; a file of another version is refused rather than misread.
pub const FORMAT_VERSION: u32 = 1;

/// The part of the grid to fly; each list non-empty.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    pub worlds: Vec<World>,
    pub rates_fps: Vec<f64>,
    pub winds: Vec<GridWind>,
    pub paths: Vec<PathKind>,
}

impl Selection {
    /// The filters `--ideal`, `--worlds`, `--rates`, `--winds` and `--paths` select; a filter
    /// not given selects all. `levels` are the landing-marker task's.
    pub fn new(args: &SimArgs, levels: &[f64]) -> Result<Self, String> {
        Ok(Self {
            worlds: select_worlds(args.ideal, &args.worlds),
            rates_fps: select_rates(levels, &args.rates)?,
            winds: if args.winds.is_empty() {
                GridWind::ALL.to_vec()
            } else {
                args.winds.clone()
            },
            paths: if args.paths.is_empty() {
                GRID_PATHS.to_vec()
            } else {
                args.paths.clone()
            },
        })
    }
}

/// `--ideal` flies the ideal world only; otherwise `--worlds`, or both.
pub fn select_worlds(ideal: bool, worlds: &[World]) -> Vec<World> {
    if ideal {
        vec![World::Ideal]
    } else if worlds.is_empty() {
        World::ALL.to_vec()
    } else {
        worlds.to_vec()
    }
}

/// The configured levels `requested` names, in the config's order; all of them for none.
pub fn select_rates(levels: &[f64], requested: &[f64]) -> Result<Vec<f64>, String> {
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
    if let Some(unknown) = requested
        .iter()
        .find(|&&r| !levels.iter().any(|&l| same(r, l)))
    {
        let levels: Vec<String> = levels.iter().map(f64::to_string).collect();
        return Err(format!(
            "--rates {unknown}: the landing_marker task has no such level; its levels (fps): {}",
            levels.join(", ")
        ));
    }
    Ok(levels
        .iter()
        .copied()
        .filter(|&l| requested.is_empty() || requested.iter().any(|&r| same(r, l)))
        .collect())
}

/// The selected cells in the grid's fixed order (whatever order the filters were given in, so
/// that every shard of a sweep lists the same cells): world × rate × wind × path at 1.5 m/s, and
/// after each world and rate's twelve the fast tractor on turn180 in 8 m/s gusts.
pub fn grid(selection: &Selection) -> Vec<Cell> {
    let mut cells = Vec::new();
    for world in World::ALL
        .into_iter()
        .filter(|w| selection.worlds.contains(w))
    {
        for &rate_fps in &selection.rates_fps {
            for wind in GridWind::ALL
                .into_iter()
                .filter(|w| selection.winds.contains(w))
            {
                for path in GRID_PATHS
                    .into_iter()
                    .filter(|p| selection.paths.contains(p))
                {
                    cells.push(Cell::new(world, rate_fps, wind, path, TRACTOR_SPEED_M_S));
                }
            }
            if selection.winds.contains(&GridWind::Gusts8)
                && selection.paths.contains(&PathKind::Turn180)
            {
                cells.push(Cell::new(
                    world,
                    rate_fps,
                    GridWind::Gusts8,
                    PathKind::Turn180,
                    FAST_TRACTOR_SPEED_M_S,
                ));
            }
        }
    }
    cells
}

/// What makes two shard files parts of the same evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// The mission config as given on the command line, and the SHA-256 of its text.
    pub config_path: String,
    pub config_sha256: String,
    pub tracking_s: f64,
    /// `--fix` levels of the other tasks.
    pub fixed_levels: Vec<(String, f64)>,
    /// Every cell flies each of these.
    pub seeds: Vec<u64>,
    pub cells: Vec<Cell>,
    /// Who flew the vehicle: builtin, px4 or ardupilot (shards from before it was recorded:
    /// the built-in autopilot).
    #[serde(default = "builtin_autopilot")]
    pub autopilot: String,
    /// The qosrt that flew it: its version and its binary's SHA-256 (empty in shards from
    /// before it was recorded). Two binaries may fly the same seed differently.
    #[serde(default)]
    pub qosrt_version: String,
}

/// This qosrt: its version and the first 16 hex digits of its binary's SHA-256 (a rebuild is
/// another binary), or the version alone where the binary cannot be read.
pub fn qosrt_version() -> String {
    let version = env!("CARGO_PKG_VERSION");
    match std::env::current_exe().and_then(std::fs::read) {
        Ok(binary) => format!("{version} (binary {})", &sha256_hex(&binary)[..16]),
        Err(_) => version.to_string(),
    }
}

fn builtin_autopilot() -> String {
    sitl::mission::AutopilotKind::Builtin.name().to_string()
}

impl Evaluation {
    /// What differs between two evaluations, for the mismatch error: what, its value here and
    /// its value in `other`; `None` when nothing does.
    fn difference(&self, other: &Evaluation) -> Option<(&'static str, String, String)> {
        let seeds = |e: &Evaluation| match (e.seeds.first(), e.seeds.last()) {
            (Some(first), Some(last)) => format!("{} seeds {first}..={last}", e.seeds.len()),
            _ => "no seeds".into(),
        };
        let cells = |e: &Evaluation| format!("{} cells", e.cells.len());
        if self.config_path != other.config_path {
            Some((
                "the config",
                self.config_path.clone(),
                other.config_path.clone(),
            ))
        } else if self.config_sha256 != other.config_sha256 {
            Some((
                "the config's text (SHA-256)",
                self.config_sha256.clone(),
                other.config_sha256.clone(),
            ))
        } else if self.tracking_s != other.tracking_s {
            Some((
                "the tracking time (s)",
                self.tracking_s.to_string(),
                other.tracking_s.to_string(),
            ))
        } else if self.fixed_levels != other.fixed_levels {
            Some((
                "the --fix levels",
                format!("{:?}", self.fixed_levels),
                format!("{:?}", other.fixed_levels),
            ))
        } else if self.seeds != other.seeds {
            Some(("the seeds (--seed, --runs)", seeds(self), seeds(other)))
        } else if self.qosrt_version != other.qosrt_version {
            Some((
                "the qosrt binary",
                self.qosrt_version.clone(),
                other.qosrt_version.clone(),
            ))
        } else if self.autopilot != other.autopilot {
            Some((
                "the autopilot (--autopilot)",
                self.autopilot.clone(),
                other.autopilot.clone(),
            ))
        } else if self.cells != other.cells {
            Some((
                "the grid's cells (--worlds, --rates, --winds, --paths, --ideal)",
                cells(self),
                cells(other),
            ))
        } else {
            None
        }
    }
}

/// `1 cell`, `2 cells`.
fn plural(count: usize, what: &str) -> String {
    format!("{count} {what}{}", if count == 1 { "" } else { "s" })
}

fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

pub mod batch;
mod fly;
pub mod grid;
mod hazards;
mod merge;
mod paths;
mod run;
mod table;

pub use grid::*;
pub use hazards::evaluate_hazards;
pub use merge::*;
pub use paths::evaluate_paths;
pub use run::{run, run_merge};
pub use table::*;
