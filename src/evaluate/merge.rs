//! Shard files: what each run recorded, read back and joined into one evaluation.

use super::*;

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
    /// Down-positive speed at touchdown (absent from shards written before it was recorded).
    #[serde(default)]
    pub touchdown_vertical_speed_m_s: Option<f64>,
    /// How long the tracker had been without a vision fix at contact (absent from shards
    /// written before it was recorded).
    #[serde(default)]
    pub blind_before_contact_s: Option<f64>,
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
            touchdown_vertical_speed_m_s: o.touchdown_vertical_speed_m_s,
            blind_before_contact_s: o.blind_before_contact_s,
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
            touchdown_vertical_speed_m_s: self.touchdown_vertical_speed_m_s,
            blind_before_contact_s: self.blind_before_contact_s,
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
    join(files, false).map(|(merged, _)| merged)
}

/// As [`merge`], but missing shards leave holes rather than fail: every run the files hold,
/// and what is missing, in words. Everything else (another sweep, a shard twice, a seed twice)
/// still fails.
pub fn merge_partial(files: &[(String, ShardFile)]) -> Result<(Merged, Vec<String>), MergeError> {
    join(files, true)
}

fn join(files: &[(String, ShardFile)], partial: bool) -> Result<(Merged, Vec<String>), MergeError> {
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
    let mut holes = Vec::new();
    if !missing.is_empty() {
        let given: Vec<String> = shards.keys().map(|i| format!("{i}/{count}")).collect();
        let error = MergeError::Missing {
            missing,
            count,
            given: given.join(", "),
        };
        if !partial {
            return Err(error);
        }
        holes.push(error.to_string());
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
            match by_seed.get(&seed) {
                Some((record, _)) => cell_runs.push(*record),
                // A missing shard's runs: already named as the shard.
                None if partial && !holes.is_empty() => {}
                None => return Err(MergeError::Incomplete { seed, cell: *cell }),
            }
        }
        runs.push(cell_runs);
    }
    let merged = Merged {
        evaluation: evaluation.clone(),
        runs,
    };
    Ok((merged, holes))
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
