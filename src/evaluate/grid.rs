//! The landing evaluation's grid: its worlds, winds, paths and cells, the shards a sweep is cut
//! into, and the words `--worlds`, `--winds`, `--paths` and `--shard` take.

use serde::{Deserialize, Serialize};
use sim::realism::Realism;
use sim::tractor::PathKind;
use sim::wind::WindKind;
use std::fmt;
use std::str::FromStr;

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
    pub(super) const ALL: [World; 2] = [World::Realistic, World::Ideal];

    pub fn realism(self) -> Realism {
        match self {
            World::Realistic => Realism::default(),
            World::Ideal => Realism::ideal(),
        }
    }

    pub(super) fn name(self) -> &'static str {
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
    pub(super) fn name(self) -> &'static str {
        match self {
            WindModel::Calm => "calm",
            WindModel::Gusts => "gusts",
            WindModel::Dryden => "dryden",
        }
    }

    /// The simulator's wind kind (calm air is the gust model at 0 m/s).
    pub(super) fn kind(self) -> WindKind {
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
    pub(super) const ALL: [GridWind; 4] = [
        GridWind::Calm,
        GridWind::Gusts8,
        GridWind::Gusts12,
        GridWind::Dryden12,
    ];

    pub(super) fn name(self) -> &'static str {
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
pub(super) const GRID_PATHS: [PathKind; 3] =
    [PathKind::Straight, PathKind::FigureEight, PathKind::Turn180];

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
    pub(super) fn new(
        world: World,
        rate_fps: f64,
        wind: GridWind,
        path: PathKind,
        speed_m_s: f64,
    ) -> Self {
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
