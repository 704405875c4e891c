//! `qosrt sim --evaluate`: the landing evaluation, every world × landing-marker rate × wind ×
//! path with `--runs` seeds per cell, flown whole or as one shard of a sweep split across
//! machines; and `qosrt sim --merge`, which joins the shards' files into the table the whole
//! evaluation gives.
//!
//! A shard file holds the evaluation's identity and each run's record, enough to compute every
//! statistic of the table again: the whole evaluation tabulates itself as the merge of its one
//! shard, so a merged sweep and an unsharded run print the same table.

use crate::check::EXIT_INVALID_CONFIG;
use crate::sim::{fly_all, SimArgs};
use runtime::energy::MissionModel;
use runtime::registry::PluginRegistry;
use serde::{Deserialize, Serialize};
use sim::outcome::{SimOutcome, SimSummary};
use sim::realism::Realism;
use sim::tractor::PathKind;
use sitl::mission::{SimOptions, WindKind};
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::process::ExitCode;
use std::str::FromStr;

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

/// The world a cell flies in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum World {
    /// Estimator noise, telemetry and camera latency, blur, a swaying pad, a human driver.
    Realistic,
    /// The truth at once: no estimator errors or latency, a still pad, a scripted tractor.
    Ideal,
}

impl World {
    const ALL: [World; 2] = [World::Realistic, World::Ideal];

    pub fn realism(self) -> Realism {
        match self {
            World::Realistic => Realism::default(),
            World::Ideal => Realism::ideal(),
        }
    }

    fn name(self) -> &'static str {
        match self {
            World::Realistic => "realistic",
            World::Ideal => "ideal",
        }
    }
}

impl fmt::Display for World {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The wind model of a cell, as the table and the files name it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WindModel {
    Calm,
    /// The seed's gust model around the mean wind.
    Gusts,
    /// Dryden turbulence around the mean wind.
    Dryden,
}

impl WindModel {
    fn name(self) -> &'static str {
        match self {
            WindModel::Calm => "calm",
            WindModel::Gusts => "gusts",
            WindModel::Dryden => "dryden",
        }
    }

    /// The simulator's wind kind (calm air is the gust model at 0 m/s).
    fn kind(self) -> WindKind {
        match self {
            WindModel::Calm | WindModel::Gusts => WindKind::Gusts,
            WindModel::Dryden => WindKind::Dryden,
        }
    }
}

/// One of the evaluation's winds, as `--winds` names them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GridWind {
    Calm,
    Gusts8,
    Gusts12,
    Dryden12,
}

impl GridWind {
    const ALL: [GridWind; 4] = [
        GridWind::Calm,
        GridWind::Gusts8,
        GridWind::Gusts12,
        GridWind::Dryden12,
    ];

    fn name(self) -> &'static str {
        match self {
            GridWind::Calm => "0",
            GridWind::Gusts8 => "8",
            GridWind::Gusts12 => "12",
            GridWind::Dryden12 => "dryden12",
        }
    }

    fn speed_m_s(self) -> f64 {
        match self {
            GridWind::Calm => 0.0,
            GridWind::Gusts8 => 8.0,
            GridWind::Gusts12 | GridWind::Dryden12 => 12.0,
        }
    }

    fn model(self) -> WindModel {
        match self {
            GridWind::Calm => WindModel::Calm,
            GridWind::Gusts8 | GridWind::Gusts12 => WindModel::Gusts,
            GridWind::Dryden12 => WindModel::Dryden,
        }
    }
}

/// `--winds`: `0`, `8`, `12` (m/s, gusts) or `dryden12`.
pub fn parse_wind(text: &str) -> Result<GridWind, String> {
    let text = text.trim();
    let by_speed = text
        .parse::<f64>()
        .ok()
        .and_then(|speed| [0.0, 8.0, 12.0].iter().position(|&s| s == speed));
    by_speed
        .map(|i| GridWind::ALL[i])
        .or_else(|| {
            GridWind::ALL
                .into_iter()
                .find(|w| w.name().eq_ignore_ascii_case(text))
        })
        .ok_or_else(|| {
            format!("unknown wind `{text}`; the landing evaluation flies 0, 8, 12 (m/s, gusts) and dryden12")
        })
}

/// The evaluation's paths.
const GRID_PATHS: [PathKind; 3] = [PathKind::Straight, PathKind::FigureEight, PathKind::Turn180];

/// `--paths`: one of the evaluation's paths.
pub fn parse_grid_path(text: &str) -> Result<PathKind, String> {
    let path = PathKind::from_str(text.trim()).map_err(|e| e.to_string())?;
    if GRID_PATHS.contains(&path) {
        Ok(path)
    } else {
        Err(format!(
            "the landing evaluation does not fly path `{path}`; its paths: straight, figure8, turn180"
        ))
    }
}

/// One shard of a sweep: the `index`-th (1-based) of `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    /// The unsharded evaluation.
    pub const WHOLE: Shard = Shard { index: 1, count: 1 };

    /// Whether job `k` of the evaluation's job list is this shard's: round-robin, so that each
    /// shard flies a share of every part of the grid.
    pub fn holds(self, job: usize) -> bool {
        job % self.count == self.index - 1
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// `--shard I/N`, 1 ≤ I ≤ N.
pub fn parse_shard(text: &str) -> Result<Shard, String> {
    let (index, count) = text.split_once('/').ok_or_else(|| {
        format!("expected I/N (e.g. 2/4, the second of four shards), found `{text}`")
    })?;
    let number = |part: &str, what: &str| {
        part.trim()
            .parse::<usize>()
            .map_err(|_| format!("`{part}` is not a {what} in `{text}`; expected I/N (e.g. 2/4)"))
    };
    let index = number(index, "shard number")?;
    let count = number(count, "shard count")?;
    if count == 0 {
        return Err(format!(
            "`{text}`: the shard count must be at least 1 (1/1 is the whole evaluation)"
        ));
    }
    if !(1..=count).contains(&index) {
        return Err(format!(
            "`{text}`: the shard number must be within 1..={count} (shards count from 1)"
        ));
    }
    Ok(Shard { index, count })
}

/// The jobs of an evaluation of `cells` cells with `runs` seeds each that `shard` flies, as
/// (cell, seed's index): job k is cell k / runs with seed k % runs.
pub fn shard_jobs(cells: usize, runs: usize, shard: Shard) -> impl Iterator<Item = (usize, usize)> {
    (0..cells * runs)
        .filter(move |&job| shard.holds(job))
        .map(move |job| (job / runs, job % runs))
}

/// One cell of the grid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Cell {
    pub world: World,
    pub rate_fps: f64,
    pub wind_m_s: f64,
    pub wind_kind: WindModel,
    #[serde(with = "path_name")]
    pub path: PathKind,
    pub tractor_speed_m_s: f64,
}

impl Cell {
    fn new(world: World, rate_fps: f64, wind: GridWind, path: PathKind, speed_m_s: f64) -> Self {
        Self {
            world,
            rate_fps,
            wind_m_s: wind.speed_m_s(),
            wind_kind: wind.model(),
            path,
            tractor_speed_m_s: speed_m_s,
        }
    }
}

impl fmt::Display for Cell {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let wind = match self.wind_kind {
            WindModel::Calm => "calm".to_string(),
            kind => format!("{} m/s {}", self.wind_m_s, kind.name()),
        };
        write!(
            f,
            "({} world, {} fps, {wind}, {}, tractor {} m/s)",
            self.world, self.rate_fps, self.path, self.tractor_speed_m_s
        )
    }
}

/// Paths in files by their names.
mod path_name {
    use serde::{Deserialize, Deserializer, Serializer};
    use sim::tractor::PathKind;

    pub fn serialize<S: Serializer>(path: &PathKind, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(path.name())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(deserializer: D) -> Result<PathKind, D::Error> {
        let name = String::deserialize(deserializer)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

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

mod merge;
mod run;
mod table;

pub use merge::*;
pub use run::{run, run_merge};
pub use table::*;
