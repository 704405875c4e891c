//! End-to-end: `qosrt sim --record F.mcap` then `qosrt replay F.mcap`, as the README shows it;
//! a replay that differs says where; a cut-off or foreign file is named, never a panic.

mod common;
use common::{output_text, qosrt};

#[test]
fn a_recorded_simulation_replays_with_no_difference_and_a_slower_detector_differs() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("m.mcap");
    let file_arg = file.to_str().unwrap();
    let sim = qosrt(&[
        "sim",
        "--tracking-s",
        "3",
        "--seed",
        "2",
        "--record",
        file_arg,
    ]);
    assert!(sim.status.success(), "{}", output_text(&sim));
    assert!(
        output_text(&sim).contains("recorded "),
        "{}",
        output_text(&sim)
    );

    let same = qosrt(&["replay", file_arg]);
    let text = output_text(&same);
    assert!(same.status.success(), "{text}");
    assert!(text.contains("no difference"), "{text}");

    let slower = qosrt(&["replay", file_arg, "--fix", "detection=1", "--json"]);
    assert_eq!(slower.status.code(), Some(5), "{}", output_text(&slower));
    let report: serde_json::Value = serde_json::from_slice(&slower.stdout).unwrap();
    let marker = report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == "/bus/vision/landing_marker")
        .expect("the detector's channel");
    assert!(marker["differing"].as_u64().unwrap() > 0, "{marker}");
    assert!(
        marker["first_difference_s"].as_f64().unwrap() > 0.0,
        "{marker}"
    );

    // Cut off mid-flight: replayed up to its last complete chunk, and said so.
    let bytes = std::fs::read(&file).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let partial = qosrt(&["replay", cut.to_str().unwrap()]);
    let text = output_text(&partial);
    assert!(partial.status.success(), "{text}");
    assert!(text.contains("the recording ends early"), "{text}");
    assert!(text.contains("no difference"), "{text}");
}

#[test]
fn a_file_that_is_not_a_recording_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let garbage = dir.path().join("garbage.mcap");
    std::fs::write(&garbage, b"this is not an MCAP file at all").unwrap();
    let missing = dir.path().join("missing.mcap");
    for (path, expected) in [(&garbage, "MCAP"), (&missing, "cannot read")] {
        let out = qosrt(&["replay", path.to_str().unwrap()]);
        let text = output_text(&out);
        assert_eq!(out.status.code(), Some(2), "{text}");
        assert!(
            text.contains(expected) && !text.contains("panicked"),
            "{text}"
        );
    }
    // Recording is of one mission.
    let out = qosrt(&["sim", "--runs", "2", "--record", garbage.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "{}", output_text(&out));
    assert!(output_text(&out).contains("--record"));
}
