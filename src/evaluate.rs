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

/// What the table needs of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub seed: u64,
    pub landed_on_pad: bool,
    pub touched_down: bool,
    pub touchdown_error_m: Option<f64>,
    /// The vehicle's tilt at touchdown (absent from shards written before it was recorded).
    #[serde(default)]
    pub touchdown_tilt_deg: Option<f64>,
    pub time_to_land_s: Option<f64>,
    pub mission_time_s: f64,
    pub flight_energy_wh: f64,
    pub companion_energy_wh: f64,
    pub landing_aborts: u32,
}

impl From<&SimOutcome> for RunRecord {
    fn from(o: &SimOutcome) -> Self {
        Self {
            seed: o.seed,
            landed_on_pad: o.landed_on_pad,
            touched_down: o.touched_down,
            touchdown_error_m: o.touchdown_error_m,
            touchdown_tilt_deg: o.touchdown_tilt_deg,
            time_to_land_s: o.time_to_land_s,
            mission_time_s: o.mission_time_s,
            flight_energy_wh: o.flight_energy_wh,
            companion_energy_wh: o.companion_energy_wh,
            landing_aborts: o.landing_aborts,
        }
    }
}

impl RunRecord {
    /// The outcome as far as the record knows it, for [`SimSummary::of`].
    pub fn outcome(&self) -> SimOutcome {
        SimOutcome {
            seed: self.seed,
            landed_on_pad: self.landed_on_pad,
            touched_down: self.touched_down,
            touchdown_error_m: self.touchdown_error_m,
            touchdown_tilt_deg: self.touchdown_tilt_deg,
            time_to_land_s: self.time_to_land_s,
            mission_time_s: self.mission_time_s,
            flight_energy_wh: self.flight_energy_wh,
            companion_energy_wh: self.companion_energy_wh,
            landing_aborts: self.landing_aborts,
            ..SimOutcome::default()
        }
    }
}

/// What one shard of an evaluation (or the whole of it, as shard 1/1) flew.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardFile {
    pub format_version: u32,
    pub evaluation: Evaluation,
    pub shard: Shard,
    /// Per cell of `evaluation.cells`, in order: this shard's runs of it.
    pub runs: Vec<Vec<RunRecord>>,
}

/// Every run of an evaluation, joined from its shards: per cell, one record per seed in the
/// seeds' order.
#[derive(Debug, Clone, PartialEq)]
pub struct Merged {
    pub evaluation: Evaluation,
    pub runs: Vec<Vec<RunRecord>>,
}

/// Why shard files cannot be merged.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("cannot read shard file {file}: {error}")]
    Unreadable { file: String, error: std::io::Error },
    #[error("{file} is not a shard file of `qosrt sim --evaluate`: {error}")]
    Malformed {
        file: String,
        error: serde_json::Error,
    },
    #[error("{file} is a shard file of format version {found}; this qosrt reads version {FORMAT_VERSION} (tabulate it with the qosrt that wrote it)")]
    Version { file: String, found: u32 },
    #[error("{file} contradicts itself: {why}")]
    Inconsistent { file: String, why: String },
    #[error("{file} is from a different evaluation than {first}: {what} differs ({first}: {in_first}; {file}: {in_file}); merge the shards of one sweep only")]
    DifferentEvaluation {
        file: String,
        first: String,
        what: &'static str,
        in_first: String,
        in_file: String,
    },
    #[error("{file} is shard {shard} but {first} is shard {first_shard}: the two split the evaluation into different numbers of shards")]
    DifferentSplit {
        file: String,
        shard: Shard,
        first: String,
        first_shard: Shard,
    },
    #[error("shard {shard} is given twice: {first} and {second}")]
    ShardTwice {
        shard: Shard,
        first: String,
        second: String,
    },
    #[error("{}", missing_message(.missing, *.count, .given))]
    Missing {
        missing: Vec<usize>,
        count: usize,
        given: String,
    },
    #[error("seed {seed} of cell {cell} appears twice: in {first} and in {second}")]
    DuplicateSeed {
        seed: u64,
        cell: Cell,
        first: String,
        second: String,
    },
    #[error("{file} holds seed {seed} for cell {cell}, which is not among the evaluation's seeds")]
    UnknownSeed { file: String, seed: u64, cell: Cell },
    #[error("no shard file holds seed {seed} of cell {cell}; the sweep's files are incomplete")]
    Incomplete { seed: u64, cell: Cell },
    #[error("no shard files to merge")]
    Nothing,
}

fn missing_message(missing: &[usize], count: usize, given: &str) -> String {
    let list: Vec<String> = missing.iter().map(usize::to_string).collect();
    let flags: Vec<String> = missing
        .iter()
        .map(|i| format!("--shard {i}/{count}"))
        .collect();
    let missing = match missing {
        [_] => format!("shard {} of {count} is missing", list[0]),
        _ => format!("shards {} of {count} are missing", list.join(", ")),
    };
    format!(
        "{missing} (given: {given}); merge every shard file of the sweep, flying {} first if it was not",
        flags.join(", ")
    )
}

/// Reads one shard file.
pub fn read_shard_file(path: &Path) -> Result<ShardFile, MergeError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|error| MergeError::Unreadable {
        file: file.clone(),
        error,
    })?;
    // The version first, so that a file of another layout says so rather than fail to parse.
    #[derive(Deserialize)]
    struct Versioned {
        format_version: u32,
    }
    let malformed = |error| MergeError::Malformed {
        file: file.clone(),
        error,
    };
    let version: Versioned = serde_json::from_str(&text).map_err(malformed)?;
    if version.format_version != FORMAT_VERSION {
        return Err(MergeError::Version {
            file,
            found: version.format_version,
        });
    }
    serde_json::from_str(&text).map_err(malformed)
}

/// Joins the shard files of one evaluation, each given with its name; every shard exactly once,
/// every seed of every cell exactly once.
pub fn merge(files: &[(String, ShardFile)]) -> Result<Merged, MergeError> {
    let Some((first_name, first)) = files.first() else {
        return Err(MergeError::Nothing);
    };
    for (name, file) in files {
        check_consistent(name, file)?;
        if let Some((what, in_first, in_file)) = first.evaluation.difference(&file.evaluation) {
            return Err(MergeError::DifferentEvaluation {
                file: name.clone(),
                first: first_name.clone(),
                what,
                in_first,
                in_file,
            });
        }
        if file.shard.count != first.shard.count {
            return Err(MergeError::DifferentSplit {
                file: name.clone(),
                shard: file.shard,
                first: first_name.clone(),
                first_shard: first.shard,
            });
        }
    }
    let mut shards: BTreeMap<usize, &str> = BTreeMap::new();
    for (name, file) in files {
        if let Some(earlier) = shards.insert(file.shard.index, name) {
            return Err(MergeError::ShardTwice {
                shard: file.shard,
                first: earlier.to_string(),
                second: name.clone(),
            });
        }
    }
    let count = first.shard.count;
    let missing: Vec<usize> = (1..=count).filter(|i| !shards.contains_key(i)).collect();
    if !missing.is_empty() {
        let given: Vec<String> = shards.keys().map(|i| format!("{i}/{count}")).collect();
        return Err(MergeError::Missing {
            missing,
            count,
            given: given.join(", "),
        });
    }
    let evaluation = &first.evaluation;
    let mut runs = Vec::with_capacity(evaluation.cells.len());
    for (index, cell) in evaluation.cells.iter().enumerate() {
        // Seed → (record, the file it came from).
        let mut by_seed: BTreeMap<u64, (RunRecord, &str)> = BTreeMap::new();
        for (name, file) in files {
            for record in &file.runs[index] {
                if !evaluation.seeds.contains(&record.seed) {
                    return Err(MergeError::UnknownSeed {
                        file: name.clone(),
                        seed: record.seed,
                        cell: *cell,
                    });
                }
                if let Some((_, earlier)) = by_seed.insert(record.seed, (*record, name.as_str())) {
                    return Err(MergeError::DuplicateSeed {
                        seed: record.seed,
                        cell: *cell,
                        first: earlier.to_string(),
                        second: name.clone(),
                    });
                }
            }
        }
        let mut cell_runs = Vec::with_capacity(evaluation.seeds.len());
        for &seed in &evaluation.seeds {
            let Some((record, _)) = by_seed.get(&seed) else {
                return Err(MergeError::Incomplete { seed, cell: *cell });
            };
            cell_runs.push(*record);
        }
        runs.push(cell_runs);
    }
    Ok(Merged {
        evaluation: evaluation.clone(),
        runs,
    })
}

/// A file's own sanity: a shard of its count, a list of runs per cell, each seed once.
fn check_consistent(name: &str, file: &ShardFile) -> Result<(), MergeError> {
    let inconsistent = |why: String| MergeError::Inconsistent {
        file: name.to_string(),
        why,
    };
    let Shard { index, count } = file.shard;
    if count == 0 || !(1..=count).contains(&index) {
        return Err(inconsistent(format!(
            "shard {index}/{count} is not a shard (1 ≤ I ≤ N)"
        )));
    }
    if file.runs.len() != file.evaluation.cells.len() {
        return Err(inconsistent(format!(
            "it holds runs for {} cells but its evaluation has {}",
            file.runs.len(),
            file.evaluation.cells.len()
        )));
    }
    let mut seeds = file.evaluation.seeds.clone();
    seeds.sort_unstable();
    seeds.dedup();
    if seeds.len() != file.evaluation.seeds.len() {
        return Err(inconsistent("its evaluation lists a seed twice".into()));
    }
    Ok(())
}

/// One line of the table: a cell and its runs' statistics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Row {
    pub world: World,
    pub rate_fps: f64,
    pub wind_m_s: f64,
    pub wind_kind: WindModel,
    pub path: String,
    pub tractor_speed_m_s: f64,
    pub runs: usize,
    pub success_rate: f64,
    pub touchdown_error_p50_m: Option<f64>,
    pub touchdown_error_p95_m: Option<f64>,
    pub time_to_land_p50_s: Option<f64>,
    pub energy_mean_wh: f64,
    pub companion_energy_mean_wh: f64,
    pub landing_aborts_mean: f64,
}

impl Row {
    pub fn of(cell: &Cell, runs: &[RunRecord]) -> Self {
        let outcomes: Vec<SimOutcome> = runs.iter().map(RunRecord::outcome).collect();
        let summary = SimSummary::of(&outcomes);
        let aborts: u64 = runs.iter().map(|r| u64::from(r.landing_aborts)).sum();
        Self {
            world: cell.world,
            rate_fps: cell.rate_fps,
            wind_m_s: cell.wind_m_s,
            wind_kind: cell.wind_kind,
            path: cell.path.to_string(),
            tractor_speed_m_s: cell.tractor_speed_m_s,
            runs: summary.runs,
            success_rate: summary.success_rate,
            touchdown_error_p50_m: summary.touchdown_error_p50_m,
            touchdown_error_p95_m: summary.touchdown_error_p95_m,
            time_to_land_p50_s: summary.time_to_land_p50_s,
            energy_mean_wh: summary.energy_mean_wh,
            companion_energy_mean_wh: summary.companion_energy_mean_wh,
            landing_aborts_mean: if runs.is_empty() {
                0.0
            } else {
                aborts as f64 / runs.len() as f64
            },
        }
    }
}

pub fn rows(merged: &Merged) -> Vec<Row> {
    merged
        .evaluation
        .cells
        .iter()
        .zip(&merged.runs)
        .map(|(cell, runs)| Row::of(cell, runs))
        .collect()
}

/// The table, for people.
pub fn table(evaluation: &Evaluation, rows: &[Row]) -> String {
    let seeds = match (evaluation.seeds.first(), evaluation.seeds.last()) {
        (Some(first), Some(last)) => format!(
            "{} per cell ({first}..={last})",
            plural(evaluation.seeds.len(), "seed")
        ),
        _ => "no seeds".into(),
    };
    let mut out = format!(
        "{seeds}, {} s of tracking, {}, config {}\n\n",
        evaluation.tracking_s,
        plural(evaluation.cells.len(), "cell"),
        evaluation.config_path
    );
    out += "| world | marker rate (fps) | wind (m/s) | wind kind | path | tractor (m/s) | success | touchdown error p50 / p95 (m) | time to land p50 (s) | energy (Wh) | of which companion (Wh) | landing aborts (mean) |\n";
    out += "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
    let metres = |v: Option<f64>| v.map_or_else(|| "—".into(), |v| format!("{v:.3}"));
    for r in rows {
        out += &format!(
            "| {} | {} | {} | {} | {} | {} | {:.0} % | {} / {} | {} | {:.2} | {:.3} | {:.2} |\n",
            r.world,
            r.rate_fps,
            r.wind_m_s,
            r.wind_kind.name(),
            r.path,
            r.tractor_speed_m_s,
            100.0 * r.success_rate,
            metres(r.touchdown_error_p50_m),
            metres(r.touchdown_error_p95_m),
            r.time_to_land_p50_s
                .map_or_else(|| "—".into(), |v| format!("{v:.1}")),
            r.energy_mean_wh,
            r.companion_energy_mean_wh,
            r.landing_aborts_mean
        );
    }
    out
}

/// The CSV columns, one row per cell.
pub const CSV_HEADER: &str = "world,rate_fps,wind_m_s,wind_kind,path,tractor_speed_m_s,runs,success_rate,touchdown_error_p50_m,touchdown_error_p95_m,time_to_land_p50_s,energy_mean_wh,companion_energy_mean_wh,landing_aborts_mean";

/// The table as CSV (RFC 4180): a header line, then one row per cell; numbers in full
/// precision, a statistic with no runs to it empty.
pub fn csv(rows: &[Row]) -> String {
    let number = |v: f64| v.to_string();
    let optional = |v: Option<f64>| v.map_or_else(String::new, |v| v.to_string());
    let mut out = format!("{CSV_HEADER}\r\n");
    for r in rows {
        let fields = [
            r.world.to_string(),
            number(r.rate_fps),
            number(r.wind_m_s),
            r.wind_kind.name().to_string(),
            r.path.clone(),
            number(r.tractor_speed_m_s),
            r.runs.to_string(),
            number(r.success_rate),
            optional(r.touchdown_error_p50_m),
            optional(r.touchdown_error_p95_m),
            optional(r.time_to_land_p50_s),
            number(r.energy_mean_wh),
            number(r.companion_energy_mean_wh),
            number(r.landing_aborts_mean),
        ];
        let fields: Vec<String> = fields.iter().map(|f| csv_field(f)).collect();
        out += &fields.join(",");
        out += "\r\n";
    }
    out
}

/// A CSV field: quoted, its quotes doubled, when it holds a comma, a quote or a line break.
pub fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
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

/// The options of one mission of the evaluation.
fn mission_options(
    evaluation: &Evaluation,
    marker_task: &str,
    cell: &Cell,
    seed: u64,
) -> SimOptions {
    let mut fixed_levels = evaluation.fixed_levels.clone();
    fixed_levels.push((marker_task.to_string(), cell.rate_fps));
    SimOptions {
        path: cell.path,
        wind_speed_m_s: cell.wind_m_s,
        wind_kind: cell.wind_kind.kind(),
        platform_speed_m_s: cell.tractor_speed_m_s,
        seed,
        tracking_s: Some(evaluation.tracking_s),
        fixed_levels,
        realism: cell.world.realism(),
        ..SimOptions::default()
    }
}

/// `qosrt sim --evaluate`: flies the selected cells (the whole or `--shard`'s share of them) on
/// all cores; writes the shard file (`--out`, or stdout for a shard) and, unsharded, the table.
pub fn run(model: &MissionModel, registry: &PluginRegistry, args: &SimArgs) -> ExitCode {
    let invalid = |message: String| {
        eprintln!("error: {message}");
        ExitCode::from(EXIT_INVALID_CONFIG)
    };
    let Some(marker) = model
        .config
        .tasks
        .iter()
        .find(|t| t.plugin == "landing_marker")
    else {
        return invalid(format!(
            "--evaluate needs a landing_marker task in {}",
            args.file.display()
        ));
    };
    if let Some((task, value)) = args.fixed_levels.iter().find(|(t, _)| *t == marker.name) {
        return invalid(format!(
            "--fix {task}={value}: --evaluate sets the landing_marker task's rate per cell; choose rates with --rates"
        ));
    }
    let selection = match Selection::new(args, &marker.levels) {
        Ok(selection) => selection,
        Err(message) => return invalid(message),
    };
    let cells = grid(&selection);
    let runs = args.runs.unwrap_or(DEFAULT_RUNS);
    let Some(last_seed) = args.seed.checked_add(runs as u64 - 1) else {
        return invalid(format!(
            "--seed {} with --runs {runs} runs past the largest seed",
            args.seed
        ));
    };
    let text = match std::fs::read(&args.file) {
        Ok(text) => text,
        Err(error) => return invalid(format!("cannot read {}: {error}", args.file.display())),
    };
    let evaluation = Evaluation {
        config_path: args.file.display().to_string(),
        config_sha256: sha256_hex(&text),
        tracking_s: args.tracking_s.unwrap_or(TRACKING_S),
        fixed_levels: args.fixed_levels.clone(),
        seeds: (args.seed..=last_seed).collect(),
        cells,
    };
    let shard = args.shard.unwrap_or(Shard::WHOLE);
    let jobs: Vec<(usize, SimOptions)> = shard_jobs(evaluation.cells.len(), runs, shard)
        .map(|(cell, seed)| {
            let options = mission_options(
                &evaluation,
                &marker.name,
                &evaluation.cells[cell],
                evaluation.seeds[seed],
            );
            (cell, options)
        })
        .collect();
    eprintln!(
        "landing evaluation{}: {} of {} ({} × {} each)",
        args.shard
            .map_or_else(String::new, |s| format!(", shard {s}")),
        jobs.len(),
        plural(evaluation.cells.len() * runs, "mission"),
        plural(evaluation.cells.len(), "cell"),
        plural(runs, "seed"),
    );
    let outcomes = match fly_all(model, registry, jobs, evaluation.cells.len()) {
        Ok(outcomes) => outcomes,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    };
    let file = ShardFile {
        format_version: FORMAT_VERSION,
        evaluation,
        shard,
        runs: outcomes
            .iter()
            .map(|cell| cell.iter().map(RunRecord::from).collect())
            .collect(),
    };
    let document = serde_json::to_string_pretty(&file).expect("shard files serialise");
    if let Some(out) = &args.out {
        if let Err(error) = std::fs::write(out, document + "\n") {
            eprintln!("error: cannot write {}: {error}", out.display());
            return ExitCode::FAILURE;
        }
        eprintln!("wrote {}", out.display());
    } else if args.shard.is_some() {
        println!("{document}");
    }
    if args.shard.is_some() {
        return ExitCode::SUCCESS;
    }
    let name = args
        .out
        .as_ref()
        .map_or_else(|| "the evaluation".into(), |out| out.display().to_string());
    match merge(&[(name, file)]) {
        Ok(merged) => report(&merged, args),
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::FAILURE
        }
    }
}

/// `qosrt sim --merge SHARD.json…`: the table of a sharded sweep.
pub fn run_merge(args: &SimArgs) -> ExitCode {
    let mut files = Vec::with_capacity(args.merge.len());
    for path in &args.merge {
        match read_shard_file(path) {
            Ok(file) => files.push((path.display().to_string(), file)),
            Err(error) => {
                eprintln!("error: {error}");
                return ExitCode::from(EXIT_INVALID_CONFIG);
            }
        }
    }
    match merge(&files) {
        Ok(merged) => report(&merged, args),
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::from(EXIT_INVALID_CONFIG)
        }
    }
}

/// The table on stdout (or its rows as JSON with `--json`), and as CSV with `--csv`.
fn report(merged: &Merged, args: &SimArgs) -> ExitCode {
    let rows = rows(merged);
    if let Some(path) = &args.csv {
        if let Err(error) = std::fs::write(path, csv(&rows)) {
            eprintln!("error: cannot write {}: {error}", path.display());
            return ExitCode::FAILURE;
        }
        eprintln!("wrote {}", path.display());
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).expect("rows serialise")
        );
    } else {
        print!("{}", table(&merged.evaluation, &rows));
    }
    ExitCode::SUCCESS
}
