//! Flying the evaluation, or merging shard files, and printing the table.

use super::batch::resolve_shard;
use super::*;

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
        world: WorldOptions {
            path: cell.path,
            wind_speed_m_s: cell.wind_m_s,
            wind_kind: cell.wind_kind.kind(),
            platform_speed_m_s: cell.tractor_speed_m_s,
            seed,
            realism: cell.world.realism(),
            ..WorldOptions::default()
        },
        tracking_s: Some(evaluation.tracking_s),
        fixed_levels,
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
        autopilot: args.autopilot.name().to_string(),
        qosrt_version: qosrt_version(),
    };
    let shard = match args.shard {
        None => Shard::WHOLE,
        Some(spec) => match resolve_shard(spec, |name| std::env::var(name).ok()) {
            Ok((shard, Some(source))) => {
                eprintln!("--shard auto: shard {shard}, from {source}");
                shard
            }
            Ok((shard, None)) => shard,
            Err(error) => return invalid(error.to_string()),
        },
    };
    let jobs: Vec<(usize, SimOptions)> = shard_jobs(evaluation.cells.len(), runs, shard)
        .map(|(cell, seed)| {
            let options = mission_options(
                &evaluation,
                &marker.name,
                &evaluation.cells[cell],
                evaluation.seeds[seed],
            );
            // The autopilot the arguments name (its instance and command).
            let autopilot = args.options(evaluation.seeds[seed]).autopilot;
            (
                cell,
                SimOptions {
                    autopilot,
                    ..options
                },
            )
        })
        .collect();
    eprintln!(
        "landing evaluation{}: {} of {} ({} × {} each)",
        args.shard
            .map_or_else(String::new, |_| format!(", shard {shard}")),
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
        if let Err(error) = write_replacing(out, &(document + "\n")) {
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

/// Writes `text` to `path` whole or not at all: a shard re-run after a failure (a requeued
/// Slurm task, a retried Kubernetes pod) replaces its earlier file, and a task killed while
/// writing leaves no half a file for the merge to read.
fn write_replacing(path: &Path, text: &str) -> std::io::Result<()> {
    let name = path.file_name().map_or_else(
        || "shard".into(),
        |name| name.to_string_lossy().into_owned(),
    );
    let partial = path.with_file_name(format!(".{name}.{}.partial", std::process::id()));
    std::fs::write(&partial, text)?;
    std::fs::rename(&partial, path).inspect_err(|_| {
        let _ = std::fs::remove_file(&partial);
    })
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
    if args.allow_partial {
        return match merge_partial(&files) {
            Ok((merged, holes)) => {
                let status = report(&merged, args);
                if holes.is_empty() {
                    return status;
                }
                for hole in &holes {
                    eprintln!("warning: {hole}");
                }
                ExitCode::from(EXIT_PARTIAL)
            }
            Err(error) => {
                eprintln!("error: {error}");
                ExitCode::from(EXIT_INVALID_CONFIG)
            }
        };
    }
    match merge(&files) {
        Ok(merged) => report(&merged, args),
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::from(EXIT_INVALID_CONFIG)
        }
    }
}

/// Exit status of `--merge --allow-partial` when the table has holes: the table is printed,
/// but a script must not take it for the whole sweep.
pub const EXIT_PARTIAL: u8 = 3;

/// The table on stdout (or its rows as JSON with `--json`), and as CSV with `--csv`.
fn report(merged: &Merged, args: &SimArgs) -> ExitCode {
    let rows = rows(merged);
    if let Some(path) = &args.csv {
        if let Err(error) = std::fs::write(path, csv(&merged.evaluation.autopilot, &rows)) {
            eprintln!("error: cannot write {}: {error}", path.display());
            return ExitCode::FAILURE;
        }
        eprintln!("wrote {}", path.display());
    }
    crate::output::print_result(args.json, &rows, |rows| table(&merged.evaluation, rows));
    ExitCode::SUCCESS
}
