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
        let output = qosrt(&[
            "sim",
            "--evaluate",
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
            "--shard",
            &shard,
            "--out",
            out.to_str().unwrap(),
        ]);
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
