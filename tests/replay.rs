//! End-to-end: `qosrt sim --record F.mcap` then `qosrt replay F.mcap`, as the README shows it;
//! a replay that differs says where; a cut-off or foreign file is named, never a panic.

mod common;
use common::{output_text, qosrt};

use common::record_short_mission as record;

#[test]
fn a_recorded_simulation_replays_with_no_difference_and_a_slower_detector_differs() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("m.mcap");
    let file_arg = file.to_str().unwrap();
    let sim = record(&file, &[]);
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

/// The peak resident memory of `qosrt` run with `args` (VmHWM, read until it exits), with its
/// output.
fn peak_resident_bytes(args: &[&str]) -> (u64, std::process::Output) {
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .args(args)
        .current_dir(common::repo_root())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let status = format!("/proc/{}/status", child.id());
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let sampler = {
        let done = done.clone();
        std::thread::spawn(move || {
            let mut peak_kb = 0u64;
            while !done.load(std::sync::atomic::Ordering::SeqCst) {
                let high_water_kb = std::fs::read_to_string(&status).ok().and_then(|text| {
                    text.lines()
                        .find_map(|l| l.strip_prefix("VmHWM:"))
                        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
                });
                peak_kb = peak_kb.max(high_water_kb.unwrap_or(0));
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            peak_kb * 1024
        })
    };
    let output = child.wait_with_output().unwrap();
    done.store(true, std::sync::atomic::Ordering::SeqCst);
    (sampler.join().unwrap(), output)
}

/// A replay streams the recording: it holds the recorded outputs, not the frames, so it needs
/// far less memory than the file is large, and still finds no difference.
#[test]
fn a_replay_needs_far_less_memory_than_its_recording_is_large() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("long.mcap");
    let file_arg = file.to_str().unwrap();
    let sim = qosrt(&["sim", "--tracking-s", "60", "--record", file_arg]);
    assert!(sim.status.success(), "{}", output_text(&sim));
    let size_bytes = std::fs::metadata(&file).unwrap().len();
    let (peak_bytes, replay) = peak_resident_bytes(&["replay", file_arg]);
    let text = output_text(&replay);
    assert!(replay.status.success(), "{text}");
    assert!(text.contains("no difference"), "{text}");
    eprintln!(
        "replay of a {:.0} MB recording: {:.0} MB resident at its peak",
        size_bytes as f64 / 1e6,
        peak_bytes as f64 / 1e6
    );
    assert!(peak_bytes > 0, "the replay's memory was not read");
    assert!(
        peak_bytes * 2 < size_bytes,
        "{peak_bytes} bytes resident for a {size_bytes}-byte recording"
    );
}

/// A recording without frames is a small fraction of one with them; its replay names the tasks
/// that saw no frames, their outputs part from the flight's, and what comes from telemetry
/// alone replays as flown.
#[test]
fn a_recording_without_frames_is_small_and_its_replay_says_what_it_cannot_compare() {
    let dir = tempfile::tempdir().unwrap();
    let recorded = |name: &str, frames: &str| {
        let file = dir.path().join(name);
        record(&file, &["--record-frames", frames]);
        file
    };
    let every = recorded("every.mcap", "every");
    let none = recorded("none.mcap", "none");
    let size = |file: &std::path::Path| std::fs::metadata(file).unwrap().len();
    assert!(
        size(&none) * 10 < size(&every),
        "{} bytes without frames, {} with",
        size(&none),
        size(&every)
    );

    let replay = qosrt(&["replay", none.to_str().unwrap(), "--json"]);
    assert_eq!(replay.status.code(), Some(5), "{}", output_text(&replay));
    let report: serde_json::Value = serde_json::from_slice(&replay.stdout).unwrap();
    assert_eq!(
        report["without_frames"],
        serde_json::json!(["detection", "hazard"]),
        "{report:#}"
    );
    let channel = |topic: &str| {
        report["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["topic"] == topic)
            .unwrap_or_else(|| panic!("no {topic} in {report:#}"))
            .clone()
    };
    assert!(
        channel("/bus/vision/landing_marker")["differing"]
            .as_u64()
            .unwrap()
            > 0
    );
    let pose = channel("/vehicle/pose");
    assert!(pose["recorded"].as_u64().unwrap() > 100, "{pose}");
    assert_eq!(pose["differing"], 0, "{pose}");
    let text = output_text(&qosrt(&["replay", none.to_str().unwrap()]));
    assert!(
        text.contains("the recording kept no camera frames") && text.contains("detection, hazard"),
        "{text}"
    );
}

/// Keeping only the frames a task read: each other frame is its size alone, the file is
/// smaller than with every frame, and the whole mission still replays bit for bit.
#[test]
fn a_recording_of_the_consumed_frames_replays_the_whole_mission() {
    let dir = tempfile::tempdir().unwrap();
    let every = dir.path().join("every.mcap");
    let consumed = dir.path().join("consumed.mcap");
    record(&every, &["--record-frames", "every"]);
    record(&consumed, &["--record-frames", "consumed"]);
    let count = |file: &std::path::Path, topic: &str| {
        runtime::record::read_recording_file(file)
            .unwrap()
            .topic(topic)
            .count()
    };
    let delivered = count(&every, "/camera/image");
    let (kept, unread) = (
        count(&consumed, "/camera/image"),
        count(&consumed, "/camera/unread"),
    );
    assert_eq!(count(&every, "/camera/unread"), 0);
    assert_eq!(kept + unread, delivered, "{kept} kept, {unread} unread");
    assert!(kept > 0 && unread > 0, "{kept} kept, {unread} unread");
    let size = |file: &std::path::Path| std::fs::metadata(file).unwrap().len();
    assert!(size(&consumed) < size(&every));

    let replay = qosrt(&["replay", consumed.to_str().unwrap(), "--json"]);
    assert!(replay.status.success(), "{}", output_text(&replay));
    let report: serde_json::Value = serde_json::from_slice(&replay.stdout).unwrap();
    assert_eq!(
        report["without_frames"],
        serde_json::json!([]),
        "{report:#}"
    );
    assert!(report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .all(|c| c["differing"] == 0));
}

/// A size budget splits the recording at steps of the loop: each part stays within it and is
/// a recording of its own (header, config, index), the parts hold between them exactly what
/// one file holds, the first part replays through all of them with no difference, a later
/// part alone is refused by name, and a missing part is said.
#[test]
fn a_size_budget_splits_the_recording_at_steps_and_the_replay_follows_the_parts() {
    use runtime::record::{part_path, read_recording};
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole.mcap");
    let split = dir.path().join("split.mcap");
    record(&whole, &[]);
    let sim = record(&split, &["--record-max-mb", "4"]);
    let parts: Vec<_> = (0..)
        .map(|index| part_path(&split, index))
        .take_while(|path| path.exists())
        .collect();
    assert!(parts.len() >= 3, "{} parts", parts.len());
    assert!(
        output_text(&sim).contains(&format!("in {} parts", parts.len())),
        "{}",
        output_text(&sim)
    );
    // Each part alone: within the budget, a qosrt recording numbered in order, ending on a
    // step of the loop (all but the last).
    let mut joined: std::collections::BTreeMap<String, Vec<(u64, Vec<u8>)>> = Default::default();
    let mut recording_ids = std::collections::BTreeSet::new();
    for (index, part) in parts.iter().enumerate() {
        let bytes = std::fs::read(part).unwrap();
        assert!(
            bytes.len() <= 4_000_000,
            "{}: {} bytes",
            part.display(),
            bytes.len()
        );
        let recording = read_recording(&bytes).unwrap();
        assert_eq!(recording.header.part, index as u32);
        assert!(recording.truncated.is_none());
        recording_ids.insert(recording.header.recording_id.clone());
        assert!(recording.config_files.iter().any(|f| f.path == "qos.toml"));
        let next = parts
            .get(index + 1)
            .map(|p| p.file_name().unwrap().to_str().unwrap());
        assert_eq!(recording.continues_in.as_deref(), next);
        if next.is_some() {
            assert_eq!(recording.messages.last().unwrap().topic, "/qosrt/step");
        }
        for message in recording.messages {
            joined
                .entry(message.topic)
                .or_default()
                .push((message.log_time_ns, message.data));
        }
    }
    assert_eq!(recording_ids.len(), 1, "{recording_ids:?}");
    // Between them, what one file of the same mission holds: nothing lost or doubled at a cut.
    let mut one: std::collections::BTreeMap<String, Vec<(u64, Vec<u8>)>> = Default::default();
    for message in runtime::record::read_recording_file(&whole)
        .unwrap()
        .messages
    {
        one.entry(message.topic)
            .or_default()
            .push((message.log_time_ns, message.data));
    }
    // The tasks' statistics are the machine's timings, never the same twice.
    for topics in [&mut joined, &mut one] {
        topics.remove("/qosrt/task_stats");
    }
    assert_eq!(
        joined.keys().collect::<Vec<_>>(),
        one.keys().collect::<Vec<_>>()
    );
    for (topic, messages) in &one {
        assert!(joined[topic] == *messages, "{topic} differs");
    }

    let replay = qosrt(&["replay", split.to_str().unwrap(), "--json"]);
    assert!(replay.status.success(), "{}", output_text(&replay));
    let report: serde_json::Value = serde_json::from_slice(&replay.stdout).unwrap();
    assert_eq!(
        report["steps_replayed"].as_u64().unwrap(),
        one["/qosrt/step"].len() as u64
    );
    assert_eq!(report["recording_truncated"], serde_json::Value::Null);

    let later = qosrt(&["replay", parts[1].to_str().unwrap()]);
    assert!(!later.status.success());
    assert!(
        output_text(&later).contains("part 1 of a recording split")
            && output_text(&later).contains("split.mcap"),
        "{}",
        output_text(&later)
    );

    std::fs::remove_file(parts.last().unwrap()).unwrap();
    let missing = qosrt(&["replay", split.to_str().unwrap(), "--json"]);
    let report: serde_json::Value = serde_json::from_slice(&missing.stdout).unwrap();
    let truncated = report["recording_truncated"].as_str().unwrap_or_default();
    assert!(truncated.contains("unread"), "{report:#}");
}

/// A short mission whose config has a `[record]` section of `setting`.
fn short_mission_recording(dir: &std::path::Path, setting: &str) -> std::path::PathBuf {
    let config = common::short_mission(dir, 3.0);
    let text = std::fs::read_to_string(&config).unwrap();
    let section = format!("[record]\n{setting}\n\n[camera]\n");
    std::fs::write(&config, text.replace("[camera]\n", &section)).unwrap();
    config
}

/// `[record] frames = "none"` in the mission keeps the frames out as the flag does; the flag
/// overrides it.
#[test]
fn the_missions_record_section_sets_the_frame_policy_and_the_flag_overrides_it() {
    let dir = tempfile::tempdir().unwrap();
    let config = short_mission_recording(dir.path(), "frames = \"none\"");
    let recorded = |name: &str, extra: &[&str]| {
        let file = dir.path().join(name);
        let mut args = vec![
            "sim",
            config.to_str().unwrap(),
            "--record",
            file.to_str().unwrap(),
        ];
        args.extend(extra);
        let sim = qosrt(&args);
        assert!(sim.status.success(), "{}", output_text(&sim));
        std::fs::metadata(&file).unwrap().len()
    };
    let configured = recorded("configured.mcap", &[]);
    let overridden = recorded("every.mcap", &["--record-frames", "every"]);
    assert!(
        configured * 10 < overridden,
        "{configured} bytes as configured, {overridden} with every frame"
    );
}

/// A plan change asked for in flight is recorded as the runner took it, and the replay hands it
/// to the same step: the mission replays with no difference, its re-plan and events included.
#[test]
fn a_plan_change_in_flight_is_recorded_and_replayed() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("m.mcap");
    let sim = record(&file, &["--plan-change", "10:reserve=0.35,hazard=0..1"]);
    assert!(sim.status.success(), "{}", output_text(&sim));
    let recording = runtime::record::read_recording_file(&file).unwrap();
    let requests: Vec<serde_json::Value> = recording
        .topic("/qosrt/plan_request")
        .map(|m| serde_json::from_slice(&m.data).unwrap())
        .collect();
    assert_eq!(requests.len(), 1, "{requests:?}");
    assert_eq!(requests[0]["reserve_fraction"], 0.35);
    assert_eq!(requests[0]["levels"]["hazard"]["max"], 1);
    let replay = qosrt(&["replay", file.to_str().unwrap()]);
    let text = output_text(&replay);
    assert!(replay.status.success(), "{text}");
    assert!(text.contains("no difference"), "{text}");
}

/// Frames stored in the compact codec (the default) and as PNG hold the same pixels, each
/// decoded by its own decoder (PNG's is the `image` crate's); the compact frames are smaller,
/// its header says which codec it holds, and `[record] codec` in the mission chooses it.
#[test]
fn compact_and_png_frames_hold_the_same_pixels_and_compact_is_smaller() {
    use runtime::record::frames::decode_frame;
    use runtime::record::{read_recording_file, FrameCodec};
    let dir = tempfile::tempdir().unwrap();
    let (compact, png) = (dir.path().join("compact.mcap"), dir.path().join("png.mcap"));
    record(&compact, &[]);
    record(&png, &["--record-codec", "png"]);
    let (compact, png) = (
        read_recording_file(&compact).unwrap(),
        read_recording_file(&png).unwrap(),
    );
    assert_eq!(compact.header.frame_codec, FrameCodec::Compact);
    assert_eq!(png.header.frame_codec, FrameCodec::Png);
    let frames = |recording: &runtime::record::Recording| -> Vec<(Vec<u8>, usize)> {
        recording
            .topic("/camera/image")
            .map(|m| {
                let image = decode_frame(recording.header.frame_codec, &m.data).unwrap();
                (image.data().to_vec(), m.data.len())
            })
            .collect()
    };
    let (compact_frames, png_frames) = (frames(&compact), frames(&png));
    assert_eq!(compact_frames.len(), png_frames.len());
    assert!(compact_frames.len() > 20, "{} frames", compact_frames.len());
    let mut sizes = (0, 0);
    for ((compact_pixels, compact_bytes), (png_pixels, png_bytes)) in
        compact_frames.iter().zip(&png_frames)
    {
        assert_eq!(compact_pixels, png_pixels);
        sizes = (sizes.0 + compact_bytes, sizes.1 + png_bytes);
    }
    assert!(
        (sizes.0 as f64) < 0.92 * sizes.1 as f64,
        "compact frames {} bytes, PNG {}",
        sizes.0,
        sizes.1
    );

    // The mission's `[record] codec`.
    let config = short_mission_recording(dir.path(), "codec = \"png\"");
    let configured = dir.path().join("configured.mcap");
    let sim = qosrt(&[
        "sim",
        config.to_str().unwrap(),
        "--record",
        configured.to_str().unwrap(),
    ]);
    assert!(sim.status.success(), "{}", output_text(&sim));
    let header = read_recording_file(&configured).unwrap().header;
    assert_eq!(header.frame_codec, FrameCodec::Png);
}
