//! A simulated mission recorded to MCAP and replayed: the same config re-runs bit for bit, a
//! slower detector shows where its outputs part, the file reads in the mcap crate's own
//! indexed reader with Foxglove's schemas, and a file cut off mid-flight still replays up to
//! its last complete chunk.

use runtime::config::load_file;
use runtime::energy::{load_mission_model, MissionModel};
use runtime::mission::{replay, ChannelDiff, ReplayOptions, ReplayReport};
use runtime::plugins::builtin_registry;
use runtime::record::read_recording_file;
use runtime::record::{read_recording, ConfigFile, RecorderOptions};
use runtime::registry::PluginRegistry;
use sim::world::WorldOptions;
use sitl::mission::{simulate, SimOptions, SimRecording};
use sitl::outcome::SimOutcome;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

fn config_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml")
}

fn reference() -> (MissionModel, PluginRegistry) {
    let loaded = load_file(&config_path(), &runtime::catalog::PluginCatalog::builtin()).unwrap();
    (
        load_mission_model(&loaded).unwrap(),
        builtin_registry().unwrap(),
    )
}

struct Recorded {
    _dir: tempfile::TempDir,
    path: PathBuf,
    outcome: SimOutcome,
}

/// One short mission, recorded once for every test here.
fn recorded() -> &'static Recorded {
    static RECORDED: OnceLock<Recorded> = OnceLock::new();
    RECORDED.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mission.mcap");
        let (model, registry) = reference();
        let options = SimOptions {
            world: WorldOptions {
                seed: 3,
                ..WorldOptions::default()
            },
            tracking_s: Some(4.0),
            fixed_levels: vec![("detection".into(), 10.0)],
            record: Some(SimRecording {
                recorder: RecorderOptions {
                    file: Some(path.clone()),
                    ..RecorderOptions::default()
                },
                config_files: ConfigFile::collect(&config_path(), &model.config).unwrap(),
            }),
            ..SimOptions::default()
        };
        let outcome = simulate(&model, &registry, &options).unwrap();
        assert!(outcome.landed_on_pad, "{:#?}", outcome.events);
        Recorded {
            _dir: dir,
            path,
            outcome,
        }
    })
}

fn replay_with(recording_path: &Path, options: &ReplayOptions) -> ReplayReport {
    let (model, registry) = reference();
    replay(recording_path, model, &registry, options).unwrap()
}

fn channel<'a>(report: &'a ReplayReport, topic: &str) -> &'a ChannelDiff {
    report
        .channels
        .iter()
        .find(|c| c.topic == topic)
        .unwrap_or_else(|| panic!("no channel {topic} in {report:#?}"))
}

#[test]
fn a_recorded_mission_replays_bit_for_bit() {
    let recorded = recorded();
    let report = replay_with(&recorded.path, &ReplayOptions::default());
    assert_eq!(report.steps_replayed, report.steps_recorded);
    assert!(report.stopped.is_none() && report.recording_truncated.is_none());
    let differing: Vec<_> = report.channels.iter().filter(|c| !c.identical()).collect();
    assert!(differing.is_empty(), "{differing:#?}");
    // Every kind of output was there to compare, in numbers a landing makes.
    for (topic, at_least) in [
        ("/bus/vision/landing_marker", 20),
        ("/bus/tracking/relative_state", 100),
        ("/bus/landing/setpoint", 100),
        ("/bus/vision/hazards", 2),
        ("/bus/mission/phase", 3),
        ("/bus/vehicle/state", 1000),
        ("/mavlink/out", 1000),
        ("/qosrt/events", 5),
        ("/qosrt/qos_levels", 1),
        ("/qosrt/battery", 10),
    ] {
        let c = channel(&report, topic);
        assert!(c.recorded >= at_least, "{topic}: {c:?}");
        assert_eq!(c.recorded, c.replayed, "{topic}");
    }
    // The runtime's events are the recording's, word for word.
    let recording = read_recording_file(&recorded.path).unwrap();
    let touchdown = recorded
        .outcome
        .events
        .iter()
        .any(|(_, e)| e == "touchdown");
    let logged = recording
        .topic("/qosrt/events")
        .any(|m| String::from_utf8_lossy(&m.data).contains("touchdown"));
    assert_eq!(touchdown, logged);
}

#[test]
fn a_replay_with_a_slower_detector_says_where_its_outputs_part() {
    let recorded = recorded();
    let report = replay_with(
        &recorded.path,
        &ReplayOptions {
            fixed_levels: Some(vec![("detection".into(), 2.0)]),
        },
    );
    assert!(!report.identical());
    let marker = channel(&report, "/bus/vision/landing_marker");
    // Five times fewer frames looked at.
    assert!(
        marker.replayed * 3 < marker.recorded,
        "{} replayed against {} recorded",
        marker.replayed,
        marker.recorded
    );
    // The detector runs from the tracking phase on: before it, nothing differs.
    let recording = read_recording_file(&recorded.path).unwrap();
    let tracking_s = recording
        .topic("/bus/mission/phase")
        .find(|m| String::from_utf8_lossy(&m.data).contains("\"tracking\""))
        .map(|m| m.log_time_ns as f64 * 1e-9)
        .expect("the tracking phase was recorded");
    for topic in [
        "/bus/vision/landing_marker",
        "/bus/landing/setpoint",
        "/mavlink/out",
    ] {
        let c = channel(&report, topic);
        let first_s = c.first_difference_s.unwrap_or_else(|| panic!("{c:?}"));
        assert!(
            first_s >= tracking_s - 1e-9,
            "{topic} differs at {first_s} s, before {tracking_s} s"
        );
        assert!(!c.first_fields.is_empty(), "{c:?}");
    }
    // The QoS levels say so from the start.
    let levels = channel(&report, "/qosrt/qos_levels");
    assert!(
        levels.first_fields.iter().any(|f| f.contains("detection")),
        "{levels:?}"
    );
    // What the detector does not feed is untouched before the tracking phase: the battery.
    let battery = channel(&report, "/qosrt/battery");
    assert!(
        battery.first_difference_s.is_none_or(|t| t >= tracking_s),
        "{battery:?}"
    );
}

#[test]
fn the_file_reads_in_the_mcap_crates_indexed_reader_with_foxglove_schemas() {
    let recorded = recorded();
    let bytes = std::fs::read(&recorded.path).unwrap();
    let summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("a summary section");
    let channels: BTreeMap<&str, (&str, &str, &str)> = summary
        .channels
        .values()
        .map(|c| {
            let schema = c.schema.as_ref().expect("every channel has a schema");
            (
                c.topic.as_str(),
                (
                    c.message_encoding.as_str(),
                    schema.name.as_str(),
                    schema.encoding.as_str(),
                ),
            )
        })
        .collect();
    for (topic, schema) in [
        ("/camera/image", "foxglove.CompressedImage"),
        ("/camera/annotations", "foxglove.ImageAnnotations"),
        ("/vehicle/pose", "foxglove.PoseInFrame"),
        ("/tf", "foxglove.FrameTransform"),
        ("/qosrt/events", "foxglove.Log"),
    ] {
        assert_eq!(
            channels.get(topic),
            Some(&("protobuf", schema, "protobuf")),
            "{topic}"
        );
    }
    assert_eq!(
        channels.get("/bus/landing/setpoint"),
        Some(&("json", "qosrt.LandingSetpoint", "jsonschema"))
    );
    // The statistics' counts are what a strict pass over every message finds.
    let stats = summary.stats.as_ref().expect("statistics");
    let mut counted: BTreeMap<u16, u64> = BTreeMap::new();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        *counted.entry(message.unwrap().channel.id).or_default() += 1;
    }
    assert_eq!(counted, stats.channel_message_counts);
    assert_eq!(counted.values().sum::<u64>(), stats.message_count);
    // And they are what the run said it recorded.
    let said = recorded
        .outcome
        .events
        .iter()
        .find_map(|(_, e)| e.strip_prefix("recorded "))
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse::<u64>().ok())
        .expect("the run says how many messages it recorded");
    assert_eq!(said, stats.message_count);
    // A frame decodes as the image the camera delivered: 640 x 480, grey, a
    // `foxglove.CompressedImage` in the compact codec (the default).
    let image = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .find(|m| m.channel.topic == "/camera/image")
        .unwrap();
    assert_eq!(
        image.channel.schema.as_ref().unwrap().name,
        "foxglove.CompressedImage"
    );
    let frame =
        runtime::record::frames::decode_frame(runtime::record::FrameCodec::Compact, &image.data)
            .unwrap();
    assert_eq!((frame.width(), frame.height()), (640, 480));
    // The config it flew is attached.
    let attached: Vec<String> = summary
        .attachment_indexes
        .iter()
        .map(|a| a.name.clone())
        .collect();
    assert!(attached.contains(&"qos.toml".to_string()), "{attached:?}");
}

/// Every velocity setpoint the landing chain steers carries, in its `time_boot_ms`, the capture
/// of the frame whose fix it answers: one of the recorded frames' capture instants, before the
/// setpoint was sent. Before the first fix, setpoints carry the time they are sent.
#[test]
fn each_vision_setpoint_carries_the_capture_of_the_frame_it_answers() {
    let bytes = std::fs::read(&recorded().path).unwrap();
    let messages: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .collect();
    let captures_ms: std::collections::BTreeSet<u32> = messages
        .iter()
        .filter(|m| m.channel.topic == "/camera/image")
        .map(|m| (m.publish_time / 1_000_000) as u32)
        .collect();
    assert!(captures_ms.len() > 50, "{} frames", captures_ms.len());
    let (mut answering, mut at_send) = (0, 0);
    for message in messages
        .iter()
        .filter(|m| m.channel.topic == "/mavlink/out")
    {
        let record: runtime::record::channels::MavlinkRecord =
            serde_json::from_slice(&message.data).unwrap();
        if record.name != "SET_POSITION_TARGET_LOCAL_NED" {
            continue;
        }
        let decoded = record.message().unwrap();
        let (_, mavlink::dialects::common::MavMessage::SET_POSITION_TARGET_LOCAL_NED(setpoint)) =
            &decoded
        else {
            panic!("not a setpoint: {decoded:?}");
        };
        // Both sides are whole milliseconds of the same instants, rounded apart.
        let stamp_ms = setpoint.time_boot_ms;
        let sent_ms = (message.log_time / 1_000_000) as u32;
        let a_capture = captures_ms
            .range(stamp_ms.saturating_sub(1)..=stamp_ms + 1)
            .next()
            .is_some();
        if a_capture && stamp_ms + 1 < sent_ms {
            answering += 1;
        } else {
            assert!(
                stamp_ms.abs_diff(sent_ms) <= 1,
                "{stamp_ms} ms is neither a capture nor the send time {sent_ms} ms"
            );
            at_send += 1;
        }
    }
    assert!(
        answering > 100,
        "{answering} answering a frame, {at_send} at their send time"
    );
    assert!(at_send > 0, "the setpoints before the first fix");
}

/// The replay reads the flight's capture to setpoint back from the file alone (frames' capture
/// instants, setpoints' stamps and send times): what the runner measured as it flew.
#[test]
fn the_recording_gives_back_the_flights_capture_to_setpoint() {
    let recorded = recorded();
    let report = replay_with(&recorded.path, &ReplayOptions::default());
    let from_file = report.capture_to_setpoint;
    let [p50_ms, p99_ms, max_ms] = recorded
        .outcome
        .capture_to_setpoint_ms
        .expect("the flight steered by vision");
    assert_eq!(from_file.count, recorded.outcome.capture_to_setpoint_fixes);
    for (file_us, flight_ms) in [
        (from_file.p50_us, p50_ms),
        (from_file.p99_us, p99_ms),
        (from_file.max_us, max_ms),
    ] {
        assert!(
            (file_us * 1e-3 - flight_ms).abs() < 0.5,
            "{from_file:?} against {p50_ms} / {p99_ms} / {max_ms} ms"
        );
    }
}

#[test]
fn a_file_cut_off_mid_flight_replays_up_to_its_last_complete_chunk() {
    let recorded = recorded();
    let bytes = std::fs::read(&recorded.path).unwrap();
    let whole = read_recording(&bytes).unwrap();
    let cut = &bytes[..bytes.len() * 6 / 10];
    let partial = read_recording(cut).unwrap();
    assert!(partial.truncated.is_some());
    assert!(!partial.messages.is_empty());
    assert!(partial.messages.len() < whole.messages.len());
    // What it kept is the whole file's beginning, message for message.
    assert_eq!(
        partial.messages[..],
        whole.messages[..partial.messages.len()]
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.mcap");
    std::fs::write(&path, cut).unwrap();
    let report = replay_with(&path, &ReplayOptions::default());
    assert!(report.recording_truncated.is_some());
    assert!(
        report.steps_replayed > 0 && report.steps_replayed < whole.topic("/qosrt/step").count()
    );
    assert!(report.replayed_until_s < whole.end_s());
    // Up to where it ends, the outputs are the recording's.
    assert!(report.identical(), "{:#?}", report.channels);
}
