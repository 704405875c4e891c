//! End-to-end test of `qosrt sim --evaluate` split into shards and `qosrt sim --merge`: a
//! one-cell grid of two seeds, flown as two shards of one mission each.

mod common;
use common::{output_text, qosrt};
use serde_json::Value;

#[test]
fn two_shards_merge_into_the_table_of_their_runs() {
    let dir = tempfile::tempdir().unwrap();
    let shard_path = |i: usize| dir.path().join(format!("shard-{i}.json"));
    let mut records = Vec::new();
    for i in 1..=2 {
        let shard = format!("{i}/2");
        let out = shard_path(i);
        let mut args = vec!["sim"];
        args.extend(SMALL_SWEEP);
        args.extend(["--shard", &shard, "--out", out.to_str().unwrap()]);
        let output = qosrt(&args);
        assert!(output.status.success(), "{}", output_text(&output));
        let file: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        assert_eq!(file["shard"]["index"], i);
        assert_eq!(file["shard"]["count"], 2);
        assert_eq!(file["evaluation"]["seeds"], serde_json::json!([0, 1]));
        let cells = file["evaluation"]["cells"].as_array().unwrap();
        assert_eq!(cells.len(), 1);
        assert_eq!(cells[0]["world"], "ideal");
        assert_eq!(cells[0]["path"], "straight");
        // Job k = seed k of the one cell; shard i flies job i − 1.
        let runs = file["runs"][0].as_array().unwrap();
        assert_eq!(runs.len(), 1, "{file:#}");
        assert_eq!(runs[0]["seed"], i - 1);
        records.push(runs[0].clone());
    }

    let csv = dir.path().join("table.csv");
    let output = qosrt(&[
        "sim",
        "--merge",
        shard_path(2).to_str().unwrap(),
        shard_path(1).to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
    ]);
    assert!(output.status.success(), "{}", output_text(&output));
    let table = String::from_utf8_lossy(&output.stdout);
    assert!(
        table.contains("| ideal | 10 | 0 | calm | straight | 1.5 |"),
        "{table}"
    );

    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2, "one header and one cell:\n{text}");
    let header: Vec<&str> = lines[0].split(',').collect();
    let row: Vec<&str> = lines[1].split(',').collect();
    assert_eq!(header.len(), row.len());
    let column = |name: &str| row[header.iter().position(|h| *h == name).unwrap()];
    assert_eq!(column("world"), "ideal");
    assert_eq!(column("rate_fps"), "10");
    assert_eq!(column("wind_kind"), "calm");
    assert_eq!(column("runs"), "2");
    // The success rate and the energy are those of the shards' two records.
    let landed = records
        .iter()
        .filter(|r| r["landed_on_pad"] == true)
        .count();
    let success_rate: f64 = column("success_rate").parse().unwrap();
    assert_eq!(success_rate, landed as f64 / 2.0);
    let energy_wh: Vec<f64> = records
        .iter()
        .map(|r| {
            r["flight_energy_wh"].as_f64().unwrap() + r["companion_energy_wh"].as_f64().unwrap()
        })
        .collect();
    let mean_wh: f64 = column("energy_mean_wh").parse().unwrap();
    assert!(
        (mean_wh - (energy_wh[0] + energy_wh[1]) / 2.0).abs() < 1e-12,
        "{text}"
    );
    assert!(mean_wh > 0.5, "{text}");

    // One shard alone is not the evaluation: the missing one is named.
    let output = qosrt(&["sim", "--merge", shard_path(1).to_str().unwrap()]);
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("shard 2 of 2 is missing"), "{stderr}");
    assert!(stderr.contains("--shard 2/2"), "{stderr}");
}

/// A one-cell evaluation of two seeds, as flags.
const SMALL_SWEEP: [&str; 13] = [
    "--worlds",
    "ideal",
    "--rates",
    "10",
    "--winds",
    "0",
    "--paths",
    "straight",
    "--runs",
    "2",
    "--tracking-s",
    "5",
    "--evaluate",
];

/// `qosrt sim` in the repository's root with `args` and the batch scheduler's variables `env`
/// (none of the caller's own).
fn qosrt_in_batch(args: &[&str], env: &[(&str, &str)]) -> std::process::Output {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_qosrt"));
    command
        .arg("sim")
        .args(args)
        .current_dir(common::repo_root());
    for (name, _) in std::env::vars() {
        if name.starts_with("SLURM_") || name == "JOB_COMPLETION_INDEX" {
            command.env_remove(name);
        }
    }
    command.envs(env.iter().copied()).output().unwrap()
}

/// A Kubernetes Indexed Job's pods take their shards from JOB_COMPLETION_INDEX with the count
/// given, say so, and merge into the unsharded table; outside a scheduler `auto` is a named
/// error.
#[test]
fn indexed_job_pods_take_their_shards_from_the_completion_index() {
    let dir = tempfile::tempdir().unwrap();
    let whole = qosrt_in_batch(&SMALL_SWEEP, &[]);
    assert!(whole.status.success(), "{}", output_text(&whole));
    let mut shards = Vec::new();
    for index in ["0", "1"] {
        let out = dir.path().join(format!("shard-{index}.json"));
        let mut args = SMALL_SWEEP.to_vec();
        args.extend(["--shard", "auto/2", "--out", out.to_str().unwrap()]);
        let output = qosrt_in_batch(&args, &[("JOB_COMPLETION_INDEX", index)]);
        assert!(output.status.success(), "{}", output_text(&output));
        let said = String::from_utf8_lossy(&output.stderr);
        assert!(
            said.contains(&format!("from Kubernetes completion index {index}")),
            "{said}"
        );
        let file: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        assert_eq!(file["shard"]["index"], index.parse::<u64>().unwrap() + 1);
        shards.push(out);
    }
    let merged = qosrt(&[
        "sim",
        "--merge",
        shards[0].to_str().unwrap(),
        shards[1].to_str().unwrap(),
    ]);
    assert!(merged.status.success(), "{}", output_text(&merged));
    assert_eq!(merged.stdout, whole.stdout);

    let mut args = SMALL_SWEEP.to_vec();
    args.extend(["--shard", "auto"]);
    let outside = qosrt_in_batch(&args, &[]);
    assert_eq!(outside.status.code(), Some(2), "{}", output_text(&outside));
    assert!(String::from_utf8_lossy(&outside.stderr).contains("no scheduler index"));
    let no_count = qosrt_in_batch(&args, &[("JOB_COMPLETION_INDEX", "1")]);
    assert_eq!(
        no_count.status.code(),
        Some(2),
        "{}",
        output_text(&no_count)
    );
    assert!(String::from_utf8_lossy(&no_count.stderr).contains("--shard auto/N"));
}

/// The cluster files agree with themselves: the Indexed Job's completions are the shards its
/// pods are told of, the merge reads where the pods write, and the Slurm scripts parse.
#[test]
fn the_deploy_files_agree_with_themselves() {
    let root = common::repo_root().join("deploy");
    let sweep = std::fs::read_to_string(root.join("kubernetes/sweep.yaml")).unwrap();
    let merge = std::fs::read_to_string(root.join("kubernetes/merge.yaml")).unwrap();
    let value_of = |text: &str, key: &str| -> String {
        text.lines()
            .find_map(|l| l.trim().strip_prefix(key))
            .unwrap_or_else(|| panic!("no `{key}`"))
            .trim()
            .to_string()
    };
    assert_eq!(value_of(&sweep, "completionMode:"), "Indexed");
    let completions = value_of(&sweep, "completions:");
    assert!(
        sweep.contains(&format!("--shard auto/{completions}")),
        "the pods must be told of {completions} shards"
    );
    assert!(sweep.contains("--out /sweep/shard-$JOB_COMPLETION_INDEX.json"));
    assert!(merge.contains("--merge /sweep/shard-*.json"));
    for text in [&sweep, &merge] {
        assert_eq!(value_of(text, "claimName:"), "qosrt-sweep");
        assert_eq!(value_of(text, "mountPath:"), "/sweep");
    }
    for script in [
        "slurm/sweep.sbatch",
        "slurm/merge.sbatch",
        "slurm/submit.sh",
    ] {
        let path = root.join(script);
        let status = std::process::Command::new("bash")
            .arg("-n")
            .arg(&path)
            .status()
            .unwrap();
        assert!(status.success(), "{script} does not parse");
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("#!/bin/bash\n"), "{script}");
    }
    let array = std::fs::read_to_string(root.join("slurm/sweep.sbatch")).unwrap();
    assert!(array.contains("--shard auto") && array.contains("#SBATCH --requeue"));
    let submit = std::fs::read_to_string(root.join("slurm/submit.sh")).unwrap();
    assert!(submit.contains("--dependency=\"afterok:$array\""));
}
