use super::batch::ShardSpec;
use super::*;
use clap::Parser;

/// A small generator for synthetic outcomes (xorshift64*), so the tests need no crate.
struct Numbers(u64);

impl Numbers {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// In [0, 1), with all 53 bits used: floats that JSON must carry to the last bit.
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A run of `seed` as the simulator might report it: some miss the pad, some never touch down.
fn synthetic_outcome(numbers: &mut Numbers, seed: u64) -> SimOutcome {
    let touched_down = numbers.unit() < 0.9;
    let landed_on_pad = touched_down && numbers.unit() < 0.7;
    SimOutcome {
        seed,
        landed_on_pad,
        touched_down,
        touchdown_error_m: touched_down.then(|| numbers.unit() * 0.5),
        time_to_land_s: touched_down.then(|| 10.0 + numbers.unit() * 20.0),
        mission_time_s: 60.0 + numbers.unit() * 100.0,
        flight_energy_wh: 1.0 + numbers.unit() * 8.0,
        companion_energy_wh: numbers.unit() * 0.2,
        landing_aborts: (numbers.next() % 4) as u32,
        // What a record leaves out must not matter to the table.
        battery_left_fraction: numbers.unit(),
        speedup: 7.0,
        ..SimOutcome::default()
    }
}

fn cells() -> Vec<Cell> {
    let selection = Selection {
        worlds: World::ALL.to_vec(),
        rates_fps: vec![2.0],
        winds: vec![GridWind::Gusts8],
        paths: vec![PathKind::Straight, PathKind::Turn180],
    };
    grid(&selection)
}

fn evaluation(cells: Vec<Cell>, seeds: Vec<u64>) -> Evaluation {
    Evaluation {
        config_path: "qos.toml".into(),
        config_sha256: sha256_hex(b"[mission]\n"),
        tracking_s: TRACKING_S,
        fixed_levels: vec![("hazard".into(), 2.0)],
        seeds,
        cells,
        autopilot: "builtin".into(),
        qosrt_version: "0.1.0 (binary 0123456789abcdef)".into(),
    }
}

/// Every cell's outcomes, in seed order.
fn synthetic_outcomes(evaluation: &Evaluation) -> Vec<Vec<SimOutcome>> {
    let mut numbers = Numbers(0x9e37_79b9_7f4a_7c15);
    evaluation
        .cells
        .iter()
        .map(|_| {
            evaluation
                .seeds
                .iter()
                .map(|&seed| synthetic_outcome(&mut numbers, seed))
                .collect()
        })
        .collect()
}

/// The shard files a sweep of `count` shards writes, each through its JSON text and back.
fn shard_files(
    evaluation: &Evaluation,
    outcomes: &[Vec<SimOutcome>],
    count: usize,
) -> Vec<(String, ShardFile)> {
    (1..=count)
        .map(|index| {
            let shard = Shard { index, count };
            let mut runs = vec![Vec::new(); evaluation.cells.len()];
            for (cell, seed) in shard_jobs(evaluation.cells.len(), evaluation.seeds.len(), shard) {
                runs[cell].push(RunRecord::from(&outcomes[cell][seed]));
            }
            // A shard's workers finish in any order.
            for cell in &mut runs {
                cell.reverse();
            }
            let file = ShardFile {
                format_version: FORMAT_VERSION,
                evaluation: evaluation.clone(),
                shard,
                runs,
            };
            let text = serde_json::to_string_pretty(&file).unwrap();
            (
                format!("shard-{index}-of-{count}.json"),
                serde_json::from_str(&text).unwrap(),
            )
        })
        .collect()
}

#[test]
fn every_job_is_in_exactly_one_shard() {
    for (cells, runs) in [(1, 1), (3, 7), (104, 20), (5, 2)] {
        let jobs = cells * runs;
        for count in [1, 2, 3, 4, 7, 16, jobs, jobs + 3] {
            let mut owner = vec![None; jobs];
            let mut sizes = Vec::new();
            for index in 1..=count {
                let shard = Shard { index, count };
                let mine: Vec<(usize, usize)> = shard_jobs(cells, runs, shard).collect();
                sizes.push(mine.len());
                for (cell, seed) in mine {
                    assert!(cell < cells && seed < runs);
                    let job = cell * runs + seed;
                    assert_eq!(job % count, index - 1, "job {job} in shard {shard}");
                    assert_eq!(owner[job], None, "job {job} in two shards");
                    owner[job] = Some(index);
                }
            }
            assert!(
                owner.iter().all(Option::is_some),
                "{cells}×{runs} over {count}"
            );
            // Round-robin: the shards' loads differ by one mission at most.
            let (min, max) = (sizes.iter().min(), sizes.iter().max());
            assert!(max.unwrap() - min.unwrap() <= 1, "{sizes:?}");
        }
    }
}

#[test]
fn shards_parse_and_bad_ones_are_explained() {
    assert_eq!(parse_shard("2/4"), Ok(Shard { index: 2, count: 4 }));
    assert_eq!(parse_shard("1/1"), Ok(Shard::WHOLE));
    assert_eq!(parse_shard("4/4"), Ok(Shard { index: 4, count: 4 }));
    for (text, expected) in [
        ("0/4", "within 1..=4"),
        ("5/4", "within 1..=4"),
        ("a/b", "`a` is not a shard number"),
        ("2/b", "`b` is not a shard count"),
        ("3", "expected I/N"),
        ("1/0", "at least 1"),
        ("-1/4", "not a shard number"),
        ("1/2/3", "not a shard count"),
    ] {
        let error = parse_shard(text).unwrap_err();
        assert!(error.contains(expected), "{text}: {error}");
        assert!(error.contains(text), "{text}: {error}");
    }
}

#[test]
fn winds_worlds_and_paths_are_filtered_by_name() {
    assert_eq!(parse_wind("0"), Ok(GridWind::Calm));
    assert_eq!(parse_wind("8"), Ok(GridWind::Gusts8));
    assert_eq!(parse_wind("12.0"), Ok(GridWind::Gusts12));
    assert_eq!(parse_wind("dryden12"), Ok(GridWind::Dryden12));
    assert_eq!(parse_wind(" Dryden12"), Ok(GridWind::Dryden12));
    for bad in ["5", "dryden8", "gusts", ""] {
        let error = parse_wind(bad).unwrap_err();
        assert!(
            error.contains("0, 8, 12") && error.contains("dryden12"),
            "{error}"
        );
    }
    assert_eq!(parse_grid_path("turn180"), Ok(PathKind::Turn180));
    assert!(parse_grid_path("circle")
        .unwrap_err()
        .contains("straight, figure8, turn180"));
    assert!(parse_grid_path("zigzag").unwrap_err().contains("zigzag"));

    assert_eq!(
        select_worlds(false, &[]),
        vec![World::Realistic, World::Ideal]
    );
    assert_eq!(select_worlds(true, &[]), vec![World::Ideal]);
    assert_eq!(select_worlds(false, &[World::Ideal]), vec![World::Ideal]);
}

#[test]
fn rates_must_be_configured_levels() {
    let levels = [0.5, 1.0, 2.0, 10.0];
    assert_eq!(select_rates(&levels, &[]).unwrap(), levels.to_vec());
    // The config's order, whatever order they were asked in.
    assert_eq!(
        select_rates(&levels, &[10.0, 2.0]).unwrap(),
        vec![2.0, 10.0]
    );
    let error = select_rates(&levels, &[10.0, 3.0]).unwrap_err();
    assert!(error.contains("--rates 3"), "{error}");
    assert!(error.contains("0.5, 1, 2, 10"), "{error}");
}

#[test]
fn the_grid_is_every_world_rate_wind_and_path_plus_the_fast_tractor() {
    let all = Selection {
        worlds: World::ALL.to_vec(),
        rates_fps: vec![0.5, 1.0, 2.0, 10.0],
        winds: GridWind::ALL.to_vec(),
        paths: GRID_PATHS.to_vec(),
    };
    let cells = grid(&all);
    // 2 worlds × 4 rates × (4 winds × 3 paths + the fast cell).
    assert_eq!(cells.len(), 2 * 4 * 13);
    let fast: Vec<&Cell> = cells
        .iter()
        .filter(|c| c.tractor_speed_m_s == 3.0)
        .collect();
    assert_eq!(fast.len(), 8);
    assert!(fast.iter().all(|c| c.path == PathKind::Turn180
        && c.wind_m_s == 8.0
        && c.wind_kind == WindModel::Gusts));
    let dryden = cells.iter().filter(|c| c.wind_kind == WindModel::Dryden);
    assert!(dryden.clone().all(|c| c.wind_m_s == 12.0));
    assert_eq!(dryden.count(), 2 * 4 * 3);
    assert_eq!(
        cells
            .iter()
            .filter(|c| c.wind_kind == WindModel::Calm)
            .count(),
        24
    );
    assert_eq!(cells[0].world, World::Realistic);
    assert_eq!(cells[cells.len() - 1].world, World::Ideal);
    // No cell twice.
    for (i, a) in cells.iter().enumerate() {
        assert!(cells[i + 1..].iter().all(|b| a != b), "{a} twice");
    }

    // The end-to-end test's grid: one cell.
    let tiny = Selection {
        worlds: vec![World::Ideal],
        rates_fps: vec![10.0],
        winds: vec![GridWind::Calm],
        paths: vec![PathKind::Straight],
    };
    assert_eq!(
        grid(&tiny),
        vec![Cell {
            world: World::Ideal,
            rate_fps: 10.0,
            wind_m_s: 0.0,
            wind_kind: WindModel::Calm,
            path: PathKind::Straight,
            tractor_speed_m_s: 1.5,
        }]
    );
    // Filters given in another order select the same cells in the same order.
    let turn = Selection {
        worlds: vec![World::Ideal, World::Realistic],
        rates_fps: vec![2.0],
        winds: vec![GridWind::Gusts12, GridWind::Gusts8],
        paths: vec![PathKind::Turn180],
    };
    let reordered = Selection {
        worlds: World::ALL.to_vec(),
        winds: vec![GridWind::Gusts8, GridWind::Gusts12],
        ..turn.clone()
    };
    let cells = grid(&turn);
    assert_eq!(cells, grid(&reordered));
    // Per world: 8 and 12 m/s on turn180 at 1.5 m/s, then the fast cell.
    assert_eq!(cells.len(), 6);
    let speeds: Vec<f64> = cells.iter().map(|c| c.tractor_speed_m_s).collect();
    assert_eq!(speeds, [1.5, 1.5, 3.0, 1.5, 1.5, 3.0]);
}

#[test]
fn the_cli_flags_select_the_grid_and_refuse_what_does_not_fit() {
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        sim: SimArgs,
    }
    let parse = |args: &[&str]| {
        Cli::try_parse_from(std::iter::once("sim").chain(args.iter().copied())).map(|c| c.sim)
    };
    let args = parse(&[
        "--evaluate",
        "--worlds",
        "ideal",
        "--rates",
        "10,2",
        "--winds",
        "0,dryden12",
        "--paths",
        "straight,turn180",
        "--shard",
        "2/3",
    ])
    .unwrap();
    assert_eq!(args.runs, None);
    let selection = Selection::new(&args, &[0.5, 1.0, 2.0, 10.0]).unwrap();
    assert_eq!(selection.worlds, [World::Ideal]);
    assert_eq!(selection.rates_fps, [2.0, 10.0]);
    assert_eq!(selection.winds, [GridWind::Calm, GridWind::Dryden12]);
    assert_eq!(
        args.shard,
        Some(ShardSpec::Fixed(Shard { index: 2, count: 3 }))
    );
    // --ideal is the ideal world only.
    let args = parse(&["--evaluate", "--ideal", "--runs", "3"]).unwrap();
    assert_eq!(args.runs, Some(3));
    let selection = Selection::new(&args, &[1.0]).unwrap();
    assert_eq!(selection.worlds, [World::Ideal]);
    assert_eq!(selection.winds, GridWind::ALL);
    assert_eq!(selection.paths, GRID_PATHS);
    assert!(Selection::new(&parse(&["--evaluate", "--rates", "4"]).unwrap(), &[1.0]).is_err());

    for (bad, expected) in [
        (vec!["--serve", "--ideal"], "--ideal"),
        (
            vec!["--evaluate", "--ideal", "--worlds", "realistic"],
            "--worlds",
        ),
        (vec!["--worlds", "ideal"], "--evaluate"),
        (vec!["--evaluate", "--worlds", "mars"], "mars"),
        (vec!["--evaluate", "--shard", "5/4"], "within 1..=4"),
        (vec!["--evaluate", "--winds", "9"], "dryden12"),
        (vec!["--evaluate", "--dryden"], "--dryden"),
        (
            vec!["--evaluate", "--shard", "1/2", "--csv", "t.csv"],
            "--csv",
        ),
        (vec!["--merge", "a.json", "--evaluate"], "--evaluate"),
    ] {
        let error = parse(&bad)
            .err()
            .unwrap_or_else(|| panic!("{bad:?} was accepted"));
        assert!(error.to_string().contains(expected), "{bad:?}: {error}");
    }
    let args = parse(&["--merge", "a.json", "b.json", "--csv", "t.csv", "--json"]).unwrap();
    assert_eq!(args.merge.len(), 2);
    // A single run keeps one seed; the options honour --ideal.
    let args = parse(&["--ideal"]).unwrap();
    assert_eq!(args.runs(), 1);
    assert!(args.options(3).world.realism.is_ideal());
    assert!(!parse(&[]).unwrap().options(3).world.realism.is_ideal());
}

#[test]
fn records_survive_json_to_the_last_bit() {
    let mut numbers = Numbers(7);
    for seed in 0..200 {
        let record = RunRecord::from(&synthetic_outcome(&mut numbers, seed));
        let text = serde_json::to_string(&record).unwrap();
        let back: RunRecord = serde_json::from_str(&text).unwrap();
        assert_eq!(back, record, "{text}");
    }
}

#[test]
fn merged_shards_give_the_summaries_of_all_outcomes() {
    let evaluation = evaluation(cells(), (40..47).collect());
    let outcomes = synthetic_outcomes(&evaluation);
    let mut tables = Vec::new();
    for count in [1, 2, 3, 5, 30] {
        let mut files = shard_files(&evaluation, &outcomes, count);
        // The order the files are given in does not matter.
        files.reverse();
        let merged = merge(&files).unwrap_or_else(|e| panic!("{count} shards: {e}"));
        let rows = rows(&merged);
        assert_eq!(rows.len(), evaluation.cells.len());
        for ((row, cell), outcomes) in rows.iter().zip(&evaluation.cells).zip(&outcomes) {
            let expected = SimSummary::of(outcomes);
            assert_eq!(row.runs, 7);
            assert_eq!(row.runs, expected.runs);
            assert_eq!(row.success_rate, expected.success_rate);
            assert_eq!(row.touchdown_error_p50_m, expected.touchdown_error_p50_m);
            assert_eq!(row.touchdown_error_p95_m, expected.touchdown_error_p95_m);
            assert_eq!(row.time_to_land_p50_s, expected.time_to_land_p50_s);
            assert_eq!(row.energy_mean_wh, expected.energy_mean_wh);
            assert_eq!(
                row.companion_energy_mean_wh,
                expected.companion_energy_mean_wh
            );
            let aborts: u32 = outcomes.iter().map(|o| o.landing_aborts).sum();
            assert_eq!(row.landing_aborts_mean, f64::from(aborts) / 7.0);
            assert_eq!(
                (
                    row.world,
                    row.rate_fps,
                    row.path.as_str(),
                    row.tractor_speed_m_s
                ),
                (
                    cell.world,
                    cell.rate_fps,
                    cell.path.name(),
                    cell.tractor_speed_m_s
                )
            );
        }
        // The synthetic runs are not all alike, or the comparison would prove little.
        assert!(rows
            .iter()
            .any(|r| r.success_rate > 0.0 && r.success_rate < 1.0));
        tables.push((
            table(&merged.evaluation, &rows),
            csv(&merged.evaluation.autopilot, &rows),
        ));
    }
    // Every split prints the same table and CSV as the whole.
    assert!(tables.iter().all(|t| *t == tables[0]));
}

fn error_of(files: &[(String, ShardFile)]) -> String {
    merge(files)
        .err()
        .unwrap_or_else(|| panic!("the merge was accepted"))
        .to_string()
}

#[test]
fn each_merge_error_is_detected_and_named() {
    let evaluation = evaluation(cells(), (0..5).collect());
    let outcomes = synthetic_outcomes(&evaluation);
    let files = shard_files(&evaluation, &outcomes, 4);
    assert!(merge(&files).is_ok());

    // Shards missing: which ones, and the flags that fly them.
    let error = error_of(&[files[0].clone(), files[2].clone()]);
    assert!(error.contains("shards 2, 4 of 4 are missing"), "{error}");
    assert!(
        error.contains("--shard 2/4") && error.contains("given: 1/4, 3/4"),
        "{error}"
    );
    let error = error_of(&files[..3]);
    assert!(error.contains("shard 4 of 4 is missing"), "{error}");

    // A shard twice, even under another name.
    let mut twice = files.clone();
    twice.push(("copy.json".into(), files[1].1.clone()));
    let error = error_of(&twice);
    assert!(
        error.contains("shard 2/4 is given twice")
            && error.contains("shard-2-of-4.json")
            && error.contains("copy.json"),
        "{error}"
    );

    // Another evaluation: each part of the identity is compared.
    type Change = fn(&mut Evaluation);
    let changes: [(&str, Change); 7] = [
        ("the config", |e| e.config_path = "other.toml".into()),
        ("SHA-256", |e| e.config_sha256 = sha256_hex(b"other")),
        ("tracking", |e| e.tracking_s = 30.0),
        ("--fix", |e| e.fixed_levels.clear()),
        ("the seeds", |e| e.seeds = (1..6).collect()),
        ("cells", |e| e.cells[1].rate_fps = 10.0),
        ("the qosrt binary", |e| {
            e.qosrt_version = "0.1.0 (binary fedcba9876543210)".into()
        }),
    ];
    for (expected, change) in changes {
        let mut other = files.clone();
        change(&mut other[3].1.evaluation);
        let error = error_of(&other);
        assert!(
            error.contains(
                "shard-4-of-4.json is from a different evaluation than shard-1-of-4.json"
            ) && error.contains(expected),
            "{expected}: {error}"
        );
    }

    // Another split of the same evaluation.
    let mut split = files[..2].to_vec();
    split.push(shard_files(&evaluation, &outcomes, 3).remove(2));
    let error = error_of(&split);
    assert!(error.contains("shard-3-of-3.json is shard 3/3"), "{error}");
    assert!(error.contains("different numbers of shards"), "{error}");

    // A seed of a cell twice.
    let mut duplicated = files.clone();
    let stolen = duplicated[0].1.runs[2][0];
    duplicated[1].1.runs[2].push(stolen);
    let error = error_of(&duplicated);
    assert!(
        error.contains(&format!("seed {} of cell", stolen.seed))
            && error.contains("appears twice")
            && error.contains("shard-1-of-4.json")
            && error.contains("shard-2-of-4.json"),
        "{error}"
    );

    // A seed the evaluation does not fly, and one no file holds.
    let mut foreign = files.clone();
    foreign[2].1.runs[0][0].seed = 99;
    let error = error_of(&foreign);
    assert!(error.contains("shard-3-of-4.json holds seed 99"), "{error}");
    let mut lost = files.clone();
    let gone = lost[0].1.runs[1].pop().unwrap();
    let error = error_of(&lost);
    assert!(
        error.contains(&format!("no shard file holds seed {} of cell", gone.seed)),
        "{error}"
    );

    // A file that contradicts itself.
    let mut short = files.clone();
    short[1].1.runs.pop();
    let error = error_of(&short);
    assert!(
        error.contains("shard-2-of-4.json contradicts itself"),
        "{error}"
    );

    assert!(matches!(merge(&[]), Err(MergeError::Nothing)));
}

#[test]
fn unreadable_malformed_and_foreign_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("absent.json");
    let error = read_shard_file(&missing).unwrap_err().to_string();
    assert!(
        error.contains("cannot read shard file") && error.contains("absent.json"),
        "{error}"
    );

    let broken = dir.path().join("broken.json");
    std::fs::write(&broken, "{\n  \"format_version\": 1,\n  \"shard\": [\n").unwrap();
    let error = read_shard_file(&broken).unwrap_err().to_string();
    assert!(error.contains("broken.json is not a shard file"), "{error}");
    assert!(error.contains("line 4 column 0"), "{error}");

    let evaluation = evaluation(cells(), vec![0]);
    let (_, file) = shard_files(&evaluation, &synthetic_outcomes(&evaluation), 1).remove(0);
    let good = dir.path().join("good.json");
    std::fs::write(&good, serde_json::to_string(&file).unwrap()).unwrap();
    assert_eq!(read_shard_file(&good).unwrap(), file);

    let mut value = serde_json::to_value(&file).unwrap();
    value["format_version"] = 2.into();
    let future = dir.path().join("future.json");
    std::fs::write(&future, value.to_string()).unwrap();
    let error = read_shard_file(&future).unwrap_err().to_string();
    assert!(
        error.contains("future.json is a shard file of format version 2"),
        "{error}"
    );

    let mut value = serde_json::to_value(&file).unwrap();
    value["evaluation"]["cells"][0]["path"] = "zigzag".into();
    let odd = dir.path().join("odd.json");
    std::fs::write(&odd, value.to_string()).unwrap();
    let error = read_shard_file(&odd).unwrap_err().to_string();
    assert!(
        error.contains("odd.json") && error.contains("zigzag"),
        "{error}"
    );
}

#[test]
fn csv_has_the_columns_and_quotes_what_needs_it() {
    assert_eq!(csv_field("turn180"), "turn180");
    assert_eq!(csv_field("a,b"), "\"a,b\"");
    assert_eq!(csv_field("say \"hi\""), "\"say \"\"hi\"\"\"");
    assert_eq!(csv_field("two\nlines"), "\"two\nlines\"");

    let cell = cells()[0];
    let runs = [
        RunRecord {
            seed: 0,
            landed_on_pad: false,
            touched_down: false,
            touchdown_error_m: None,
            touchdown_tilt_deg: None,
            touchdown_vertical_speed_m_s: None,
            blind_before_contact_s: None,
            time_to_land_s: None,
            mission_time_s: 300.0,
            flight_energy_wh: 9.0,
            companion_energy_wh: 0.25,
            landing_aborts: 3,
        },
        RunRecord {
            seed: 1,
            landed_on_pad: false,
            touched_down: true,
            touchdown_error_m: Some(1.5),
            touchdown_tilt_deg: Some(12.0),
            touchdown_vertical_speed_m_s: Some(0.8),
            blind_before_contact_s: Some(0.25),
            time_to_land_s: Some(20.0),
            mission_time_s: 90.0,
            flight_energy_wh: 2.0,
            companion_energy_wh: 0.125,
            landing_aborts: 0,
        },
    ];
    let text = csv("builtin", &[Row::of(&cell, &runs)]);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0], CSV_HEADER);
    assert_eq!(lines[0].split(',').count(), 18);
    // No landing on the pad: no touchdown error or time, empty fields; the one run that
    // touched down (off the pad) gives how hard and how leaning.
    assert_eq!(
        lines[1],
        "builtin,realistic,2,8,gusts,straight,1.5,2,0,,,0.8,12,0.25,,5.6875,0.1875,1.5"
    );
}

/// A shard written before the touchdown tilt was recorded still merges: its runs have none.
#[test]
fn a_run_record_without_the_touchdown_tilt_reads_as_none() {
    let text = r#"{"seed": 4, "landed_on_pad": true, "touched_down": true,
        "touchdown_error_m": 0.05, "time_to_land_s": 20.0, "mission_time_s": 90.0,
        "flight_energy_wh": 2.0, "companion_energy_wh": 0.1, "landing_aborts": 0}"#;
    let record: RunRecord = serde_json::from_str(text).unwrap();
    assert_eq!(record.touchdown_vertical_speed_m_s, None);
    assert_eq!(record.touchdown_tilt_deg, None);
    assert_eq!(record.blind_before_contact_s, None);
    assert_eq!(record.touchdown_error_m, Some(0.05));
}

/// A partial merge prints what the shards it has hold, says which shards are missing, and marks
/// every cell that lacks runs; it still refuses what is no hole (another sweep, a shard twice).
#[test]
fn a_partial_merge_marks_the_holes_and_refuses_the_rest() {
    let evaluation = evaluation(cells(), (0..6).collect());
    let outcomes = synthetic_outcomes(&evaluation);
    let files = shard_files(&evaluation, &outcomes, 4);
    let (whole, holes) = merge_partial(&files).unwrap();
    assert!(holes.is_empty());
    assert_eq!(whole, merge(&files).unwrap());

    let without_third: Vec<_> = files
        .iter()
        .filter(|(_, f)| f.shard.index != 3)
        .cloned()
        .collect();
    let (merged, holes) = merge_partial(&without_third).unwrap();
    assert_eq!(holes.len(), 1);
    assert!(
        holes[0].contains("shard 3 of 4 is missing") && holes[0].contains("--shard 3/4"),
        "{holes:?}"
    );
    // Each cell keeps exactly the runs the three files hold, in seed order.
    let jobs: Vec<(usize, usize)> = shard_jobs(
        evaluation.cells.len(),
        evaluation.seeds.len(),
        Shard { index: 3, count: 4 },
    )
    .collect();
    for (cell, runs) in merged.runs.iter().enumerate() {
        let lost: Vec<u64> = jobs
            .iter()
            .filter(|(c, _)| *c == cell)
            .map(|&(_, seed)| evaluation.seeds[seed])
            .collect();
        let kept: Vec<u64> = runs.iter().map(|r| r.seed).collect();
        let expected: Vec<u64> = evaluation
            .seeds
            .iter()
            .copied()
            .filter(|s| !lost.contains(s))
            .collect();
        assert_eq!(kept, expected, "cell {cell}");
    }
    let rows = rows(&merged);
    let text = table(&merged.evaluation, &rows);
    let marked = text.matches("(partial: ").count();
    let short_cells = rows.iter().filter(|r| r.runs < 6).count();
    assert!(short_cells > 0);
    assert_eq!(marked, short_cells, "{text}");

    let mut other = without_third.clone();
    other[1].1.evaluation.tracking_s = 30.0;
    assert!(matches!(
        merge_partial(&other),
        Err(MergeError::DifferentEvaluation { .. })
    ));
    let mut twice = without_third.clone();
    twice.push(("copy.json".into(), without_third[0].1.clone()));
    assert!(matches!(
        merge_partial(&twice),
        Err(MergeError::ShardTwice { .. })
    ));
}
