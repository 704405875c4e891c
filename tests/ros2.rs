//! `qosrt sim --ros2` seen by an independent ROS 2 client: Eclipse Cyclone DDS's Python binding
//! (from PyPI, into a virtual environment under `target/`), subscribing to `rt/qosrt/<vehicle>/…`
//! with ROS 2's type names and CDR layouts. Every message it receives must carry the values the
//! run recorded for the same instant.

mod common;
use common::{cyclone_client, cyclonedds_python, output_text, repo_root, short_mission, Px4};
use serde_json::Value;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};

/// The messages of `topic` in the recording, as JSON, with their log times in seconds.
fn recorded(recording: &runtime::record::Recording, topic: &str) -> Vec<(f64, Value)> {
    recording
        .topic(topic)
        .map(|m| {
            let value = serde_json::from_slice(&m.data).unwrap_or(Value::Null);
            (m.log_time_ns as f64 * 1e-9, value)
        })
        .collect()
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance
}

#[test]
fn an_independent_ros2_client_receives_what_the_mission_recorded() {
    let Some(python) = cyclonedds_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("m.mcap");
    // A vehicle name of this run's own: other runs on the machine share DDS domain 0.
    let vehicle = format!("test_{}", std::process::id());
    let mut listener = cyclone_client(&python, "listen.py")
        .args([vehicle.as_str(), "60"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(listener.stdout.take().unwrap()).lines();
    assert_eq!(lines.next().unwrap().unwrap(), "ready");
    let received = std::thread::spawn(move || {
        let mut received: BTreeMap<String, Vec<Value>> = BTreeMap::new();
        for line in lines.map_while(Result::ok) {
            let message: Value = serde_json::from_str(&line).unwrap();
            let topic = message["topic"].as_str().unwrap().to_string();
            let last_phase =
                topic == "phase" && message["data"].as_str().unwrap().ends_with("null}");
            received.entry(topic).or_default().push(message);
            if last_phase {
                break;
            }
        }
        received
    });
    let sim = common::record_short_mission(&file, &[&format!("--ros2={vehicle}")]);
    assert!(
        output_text(&sim).contains(&format!("publishing ROS 2 topics under /qosrt/{vehicle}")),
        "{}",
        output_text(&sim)
    );
    let received = received.join().unwrap();
    let _ = listener.kill();
    let _ = listener.wait();
    let counts: BTreeMap<&String, usize> = received.iter().map(|(t, m)| (t, m.len())).collect();
    eprintln!("received: {counts:?}");
    let recording = runtime::record::read_recording_file(&file).unwrap();

    // The phases, in order, each as it began; the end of the mission last.
    let phases: Vec<Value> = received["phase"]
        .iter()
        .map(|m| serde_json::from_str::<Value>(m["data"].as_str().unwrap()).unwrap())
        .collect();
    let flown: Vec<Value> = recorded(&recording, "/bus/mission/phase")
        .into_iter()
        .map(|(_, phase)| phase["name"].clone())
        .chain([Value::Null])
        .collect();
    let heard: Vec<Value> = phases.iter().map(|p| p["phase"].clone()).collect();
    assert!(flown.ends_with(&heard), "heard {heard:?}, flown {flown:?}");
    assert!(heard.len() >= 2, "{heard:?}");

    // Each battery reading as the autopilot sent it: ROS's signs, f32.
    let batteries = recorded(&recording, "/qosrt/battery");
    let readings = &received["battery"];
    assert!(readings.len() >= 5, "{} battery messages", readings.len());
    for reading in readings {
        let t = reading["t"].as_f64().unwrap();
        let (_, sample) = batteries
            .iter()
            .find(|(_, b)| close(b["telemetry"]["time_s"].as_f64().unwrap(), t, 1e-6))
            .unwrap_or_else(|| panic!("no recorded battery reading at {t}"));
        let telemetry = &sample["telemetry"];
        let as_f32 = |v: &Value| v.as_f64().map(|v| v as f32 as f64);
        assert_eq!(
            reading["voltage"].as_f64(),
            as_f32(&telemetry["voltage_v"]),
            "{reading}"
        );
        assert_eq!(
            reading["current"].as_f64(),
            as_f32(&telemetry["current_a"]).map(|a| -a),
            "{reading}"
        );
        assert_eq!(
            reading["percentage"].as_f64(),
            as_f32(&telemetry["remaining_fraction"]),
            "{reading}"
        );
        assert_eq!(reading["design_capacity"], 5.0, "the config's 5000 mAh");
    }

    // The pose in ENU: east, north, up; the heading turned to ENU's yaw (from east, to the
    // left), worked out here from the recorded NED state, not by the runtime's conversion.
    let states = recorded(&recording, "/bus/vehicle/state");
    let poses = &received["pose"];
    assert!(poses.len() >= 50, "{} poses", poses.len());
    for pose in poses {
        let t = pose["t"].as_f64().unwrap();
        let (_, state) = states
            .iter()
            .find(|(time_s, _)| close(*time_s, t, 1e-6))
            .unwrap_or_else(|| panic!("no recorded vehicle state at {t}"));
        let ned: Vec<f64> = serde_json::from_value(state["position_ned_m"].clone()).unwrap();
        let position: Vec<f64> = serde_json::from_value(pose["position"].clone()).unwrap();
        assert_eq!(position, [ned[1], ned[0], -ned[2]], "{pose}");
        let [x, y, z, w]: [f64; 4] = serde_json::from_value(pose["orientation"].clone()).unwrap();
        let yaw_enu = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
        let yaw_ned = state["attitude"]["yaw_rad"].as_f64().unwrap();
        let turned = std::f64::consts::FRAC_PI_2 - yaw_ned - yaw_enu;
        assert!(
            close(turned.sin(), 0.0, 1e-9) && turned.cos() > 0.0,
            "{pose} {state}"
        );
        assert_eq!(pose["frame"], "map");
    }

    // Each velocity setpoint as the link sent it (SET_POSITION_TARGET_LOCAL_NED's f32s).
    let sent: Vec<(f64, [f64; 3])> = recording
        .topic("/mavlink/out")
        .filter_map(|m| {
            let record: runtime::record::channels::MavlinkRecord =
                serde_json::from_slice(&m.data).ok()?;
            match record.message().ok()?.1 {
                mavlink::dialects::common::MavMessage::SET_POSITION_TARGET_LOCAL_NED(s) => Some((
                    m.log_time_ns as f64 * 1e-9,
                    [f64::from(s.vx), f64::from(s.vy), f64::from(s.vz)],
                )),
                _ => None,
            }
        })
        .collect();
    let setpoints = &received["velocity_setpoint"];
    assert!(setpoints.len() >= 10, "{} setpoints", setpoints.len());
    for setpoint in setpoints {
        let t = setpoint["t"].as_f64().unwrap();
        let linear: Vec<f64> = serde_json::from_value(setpoint["linear"].clone()).unwrap();
        let matching = sent.iter().any(|(time_s, ned)| {
            close(*time_s, t, 1e-6)
                && close(linear[0], ned[1], 1e-5)
                && close(linear[1], ned[0], 1e-5)
                && close(linear[2], -ned[2], 1e-5)
        });
        assert!(matching, "no setpoint sent at {t} as {setpoint}");
    }

    // Every task's level, as the mission last recorded them.
    let levels = recorded(&recording, "/qosrt/qos_levels");
    let (_, last_levels) = levels.last().unwrap();
    let diagnostics = received["diagnostics"].last().unwrap();
    let statuses = diagnostics["status"].as_array().unwrap();
    let tasks = last_levels["tasks"].as_object().unwrap();
    assert_eq!(statuses.len(), tasks.len(), "{diagnostics}");
    for (task, level) in tasks {
        let status = statuses
            .iter()
            .find(|s| s["name"] == format!("qosrt/{task}"))
            .unwrap_or_else(|| panic!("no diagnostics of {task}: {diagnostics}"));
        assert_eq!(status["values"]["level"], level["level"].to_string());
        assert!(
            status["values"]["activations"]
                .as_str()
                .unwrap()
                .parse::<u64>()
                .unwrap()
                > 0
        );
    }

    // The pad where the tracker put it: the vehicle's position less the estimate of the vehicle
    // relative to the pad (the vehicle's as the node last heard it: within a step's travel).
    let relatives = recorded(&recording, "/bus/tracking/relative_state");
    let pads = &received["pad_pose"];
    assert!(pads.len() >= 20, "{} pad poses", pads.len());
    for pad in pads {
        let t = pad["t"].as_f64().unwrap();
        let (_, relative) = relatives
            .iter()
            .find(|(_, r)| close(r["estimate"]["time_s"].as_f64().unwrap(), t, 1e-6))
            .unwrap_or_else(|| panic!("no recorded estimate at {t}"));
        let (_, state) = states
            .iter()
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .unwrap();
        let ned: Vec<f64> = serde_json::from_value(state["position_ned_m"].clone()).unwrap();
        let rel: Vec<f64> =
            serde_json::from_value(relative["estimate"]["uav_relative_ned_m"].clone()).unwrap();
        let expected = [ned[1] - rel[1], ned[0] - rel[0], -(ned[2] - rel[2])];
        let position: Vec<f64> = serde_json::from_value(pad["position"].clone()).unwrap();
        let off = (0..3)
            .map(|i| (position[i] - expected[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(off < 0.5, "{pad}: {off} m from {expected:?}");
    }

    // The hazards, each report as the CNN made it: class, score and box per detection.
    let reports = recorded(&recording, "/bus/vision/hazards");
    let hazards = &received["hazards"];
    assert!(!hazards.is_empty(), "no hazard reports");
    for message in hazards {
        let t = message["t"].as_f64().unwrap();
        let (_, report) = reports
            .iter()
            .find(|(_, r)| close(r["capture_time_s"].as_f64().unwrap(), t, 1e-6))
            .unwrap_or_else(|| panic!("no recorded hazard report captured at {t}"));
        let detections = message["detections"].as_array().unwrap();
        let recorded_detections = report["detections"].as_array().unwrap();
        assert_eq!(detections.len(), recorded_detections.len(), "{message}");
        for (got, want) in detections.iter().zip(recorded_detections) {
            assert_eq!(got["class"], want["class_name"]);
            assert_eq!(got["score"], want["confidence"]);
            let b = &want["bbox"];
            let centre_x = (b["x_min"].as_f64().unwrap() + b["x_max"].as_f64().unwrap()) / 2.0;
            assert!(
                close(got["box"][0].as_f64().unwrap(), centre_x, 1e-9),
                "{got} {want}"
            );
            assert_eq!(got["covariance0"], -1.0, "the covariance marked unknown");
        }
    }

    // The plan for the rest of the mission and its forecast, after a re-plan.
    let plan: Value = serde_json::from_str(
        received["plan"].last().expect("a plan")["data"]
            .as_str()
            .unwrap(),
    )
    .unwrap();
    assert_eq!(plan["reserve_fraction"], 0.25, "{plan}");
    for key in ["remaining_energy_wh", "needed_wh", "margin_wh", "sigma_wh"] {
        assert!(plan[key].is_number(), "{key}: {plan}");
    }
    let planned = plan["phases"].as_array().unwrap();
    assert!(!planned.is_empty(), "{plan}");
    for phase in planned {
        let name = phase["name"].as_str().unwrap();
        assert!(
            ["transit", "tracking", "landing"].contains(&name),
            "{phase}"
        );
        let levels = phase["levels"].as_object().unwrap();
        assert!(
            !levels.is_empty() && levels.values().all(Value::is_number),
            "{phase}"
        );
    }

    // The governor's decisions, each as recorded.
    let decisions: Vec<Value> = recorded(&recording, "/qosrt/governor")
        .into_iter()
        .map(|(_, d)| d)
        .collect();
    for message in received.get("governor").into_iter().flatten() {
        let decision: Value = serde_json::from_str(message["data"].as_str().unwrap()).unwrap();
        assert!(decisions.contains(&decision), "{decision}");
    }
}

/// Processes killed when dropped, whether the test passes or panics.
struct Children(Vec<std::process::Child>);

impl Drop for Children {
    fn drop(&mut self) {
        for child in &mut self.0 {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// `qosrt fleet ARGS…`, waited for.
fn fleet(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .arg("fleet")
        .args(args)
        .output()
        .unwrap()
}

/// One `qosrt fleet --json` view for `duration_s`, as a ground station keeps it open, and its
/// snapshots in order.
fn fleet_view(duration_s: u32) -> (std::process::Child, impl Iterator<Item = Value>) {
    let mut view = Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .args(["fleet", "--json", "--period-s", "0.2", "--duration-s"])
        .arg(duration_s.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let snapshots = BufReader::new(view.stdout.take().unwrap())
        .lines()
        .map_while(Result::ok)
        .map(|line| serde_json::from_str::<Value>(&line).unwrap());
    (view, snapshots)
}

/// `name`'s row in a fleet snapshot.
fn vehicle_in(snapshot: &Value, name: &str) -> Option<Value> {
    snapshot["vehicles"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["vehicle"] == name)
        .cloned()
}

/// Two simulated vehicles flying with `--ros2` and a ground station's `qosrt fleet`: it sees both,
/// each with its phase and energy margin. One's reserve is changed in flight; the other's time
/// left, first too short (refused, saying how much the landing needs), then just that plus a
/// few seconds with its hazard detector bounded: its tracking ends within seconds and the
/// bound holds. Meanwhile an independent client sends it malformed CDR and JSON that is not a
/// request, each answered with why; and a vehicle that is not there is a named error.
#[test]
fn the_fleet_sees_every_vehicle_and_changes_their_plans_in_flight() {
    let names = [1, 2].map(|n| format!("fleet_{}_{n}", std::process::id()));
    let logs = tempfile::tempdir().unwrap();
    let log_of = |name: &str| logs.path().join(format!("{name}.log"));
    let _vehicles = Children(
        names
            .iter()
            .enumerate()
            .map(|(seed, name)| {
                Command::new(env!("CARGO_BIN_EXE_qosrt"))
                    .current_dir(repo_root())
                    .args(["sim", "--tracking-s", "150", "--seed", &seed.to_string()])
                    .arg(format!("--ros2={name}"))
                    .stdout(Stdio::null())
                    .stderr(std::fs::File::create(log_of(name)).unwrap())
                    .spawn()
                    .unwrap()
            })
            .collect(),
    );
    // What each vehicle said, for a failure's message.
    let said = || {
        names
            .iter()
            .map(|name| {
                format!(
                    "{name}: {}",
                    std::fs::read_to_string(log_of(name)).unwrap_or_default()
                )
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    // The bad requests go out while the rest of the test runs.
    let bad_requests = cyclonedds_python().map(|python| {
        cyclone_client(&python, "bad_plan_requests.py")
            .args([&names[1], "60"])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap()
    });
    // One view for the whole test, as a ground station keeps it open: its snapshots in order.
    let view_started = std::time::Instant::now();
    let (mut view, mut snapshots) = fleet_view(180);
    // Both flying, with the margin of the governor's first re-plan (which follows the
    // governor's warm-up).
    let last = snapshots
        .find(|snapshot| {
            names
                .iter()
                .all(|name| vehicle_in(snapshot, name).is_some_and(|v| v["margin_wh"].is_number()))
        })
        .unwrap_or_else(|| {
            panic!(
                "both vehicles not seen with a margin; they said:\n{}",
                said()
            )
        });
    for name in &names {
        let vehicle = vehicle_in(&last, name).unwrap();
        assert!(vehicle["phase"].is_string(), "{vehicle}");
        assert!(vehicle["link_age_s"].as_f64().unwrap() < 1.5, "{vehicle}");
        assert_eq!(
            vehicle["reserve_fraction"], 0.25,
            "the config's reserve: {vehicle}"
        );
        assert!(vehicle["levels"]["detection"].is_number(), "{vehicle}");
    }

    let margin_before = vehicle_in(&last, &names[0]).unwrap()["margin_wh"]
        .as_f64()
        .unwrap();
    let set = fleet(&["set", &names[0], "reserve=0.4", "--json"]);
    let answered = std::time::Instant::now();
    assert!(set.status.success(), "{}", output_text(&set));
    let answer: Value = serde_json::from_slice(&set.stdout).unwrap();
    assert_eq!(answer["accepted"], true, "{answer}");
    assert_eq!(answer["reserve_fraction"], 0.4, "{answer}");
    assert!(
        answer["levels"]["tasks"]["hazard"]["level"].is_number(),
        "{answer}"
    );
    eprintln!(
        "reserve: the vehicle was found in {:.1} s and answered {:.0} ms after the ask",
        answer["found_s"].as_f64().unwrap(),
        answer["answered_ms"].as_f64().unwrap()
    );
    // 15 % more of a pack of some 70 usable Wh kept back: several Wh less left over at the end
    // (less if the governor stepped the levels down to save some of it).
    let margin_after = answer["margin_wh"].as_f64().unwrap();
    assert!(
        margin_after < margin_before - 3.0,
        "margin {margin_before} Wh before, {margin_after} Wh after"
    );
    // The open view shows the change within a second or so of the answer.
    let changed = snapshots
        .find(|snapshot| {
            vehicle_in(snapshot, &names[0]).is_some_and(|v| v["reserve_fraction"] == 0.4)
        })
        .expect("the change seen");
    eprintln!(
        "the answer came {:.1} s after the view started, the change was in its snapshot of {:.1} s",
        answered.duration_since(view_started).as_secs_f64(),
        changed["time_s"].as_f64().unwrap()
    );
    let other = vehicle_in(&changed, &names[1]).expect("the other vehicle");
    assert_eq!(other["reserve_fraction"], 0.25, "{other}");

    // Tracking: the time left is the tracking's and the landing's.
    snapshots
        .find(|snapshot| vehicle_in(snapshot, &names[1]).is_some_and(|v| v["phase"] == "tracking"))
        .expect("the tracking seen");
    // Too short a time left is refused with what the landing still needs.
    let refused = fleet(&["set", &names[1], "time_left_s=1", "reserve=0.3"]);
    assert_eq!(refused.status.code(), Some(3), "{}", output_text(&refused));
    let text = output_text(&refused);
    let needed_s: f64 = text
        .split("still need ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no time needed in: {text}"));
    assert!((30.0..200.0).contains(&needed_s), "{text}");
    // Then that and five seconds, the hazard detector at its two lowest levels: the tracking,
    // planned for 150 s, ends within seconds.
    let asked_s = needed_s + 5.0;
    let set = fleet(&[
        "set",
        &names[1],
        &format!("time_left_s={asked_s}"),
        "hazard=0..1",
        "--json",
    ]);
    assert!(set.status.success(), "{}", output_text(&set));
    let answer: Value = serde_json::from_slice(&set.stdout).unwrap();
    let answered = std::time::Instant::now();
    assert_eq!(answer["accepted"], true, "{answer}");
    assert_eq!(
        answer["reserve_fraction"], 0.25,
        "refused whole before: {answer}"
    );
    // Planned from the moment the request arrived; the answer follows it within the step.
    let time_left_s = answer["time_left_s"].as_f64().unwrap();
    assert!(
        (time_left_s - asked_s).abs() < 1.0,
        "{time_left_s} s for {asked_s} s: {answer}"
    );
    assert_eq!(
        answer["allowed_levels"]["hazard"],
        serde_json::json!({"min": 0, "max": 1}),
        "{answer}"
    );
    assert!(
        answer["levels"]["tasks"]["hazard"]["level"]
            .as_u64()
            .unwrap()
            <= 1,
        "{answer}"
    );
    eprintln!(
        "time left: answered {:.0} ms after the ask",
        answer["answered_ms"].as_f64().unwrap()
    );
    // The bound holds from a second after the answer (the status's latency) until the
    // landing, where the hazard detector does not run.
    let answered_s = answered.duration_since(view_started).as_secs_f64();
    let mut shown_time_left_s = None;
    let landing = snapshots
        .find(|snapshot| {
            let vehicle = vehicle_in(snapshot, &names[1]).unwrap();
            let hazard = vehicle["levels"]["hazard"].as_u64();
            if snapshot["time_s"].as_f64().unwrap() > answered_s + 1.0 {
                assert!(hazard.is_none_or(|level| level <= 1), "{vehicle}");
                shown_time_left_s = shown_time_left_s.or(vehicle["mission_time_left_s"].as_f64());
            }
            vehicle["phase"] == "landing"
        })
        .expect("the landing seen");
    // The view shows the mission's new time left, counting down from what was asked.
    let shown_time_left_s = shown_time_left_s.expect("the mission's time left shown");
    assert!(
        shown_time_left_s <= asked_s + 0.5 && shown_time_left_s >= asked_s - 4.0,
        "{shown_time_left_s} s shown for {asked_s} s asked"
    );
    let landing_after_s = landing["time_s"].as_f64().unwrap() - answered_s;
    assert!(
        landing_after_s < 12.0,
        "the landing began {landing_after_s:.1} s after the answer"
    );
    let _ = view.kill();
    let _ = view.wait();

    if let Some(mut bad_requests) = bad_requests {
        let answers: Vec<Value> = BufReader::new(bad_requests.stdout.take().unwrap())
            .lines()
            .map_while(Result::ok)
            .map(|line| serde_json::from_str(&line).unwrap())
            .collect();
        let _ = bad_requests.wait();
        let refusals: Vec<&str> = answers
            .iter()
            .map(|a| a["refusal"].as_str().unwrap_or_default())
            .collect();
        assert_eq!(answers.len(), 3, "{refusals:?}\n{}", said());
        assert!(answers
            .iter()
            .all(|a| a["accepted"] == false && a["id"] == 0));
        for expected in [
            "malformed CDR",
            "expected value at line 1",
            "unknown field `reserve`",
        ] {
            assert!(
                refusals.iter().any(|r| r.contains(expected)),
                "{expected}: {refusals:?}"
            );
        }
    }
    let nobody = fleet(&["set", "nobody_here", "reserve=0.3", "--timeout-s", "2"]);
    assert_eq!(nobody.status.code(), Some(4), "{}", output_text(&nobody));
    assert!(output_text(&nobody).contains("no answer from `nobody_here`"));
}

/// `--camera ros2:/TOPIC` fed by an independent publisher (Cyclone DDS, as a camera driver):
/// every frame arrives pixel for pixel (mono8, and rgb8 as its luma), stamped with its header's
/// capture time; a frame in an encoding qosrt does not read, or of another size, is a named
/// error counted as malformed, and the frames after it still come.
#[test]
fn a_ros2_image_topic_is_a_camera() {
    let Some(python) = cyclonedds_python() else {
        return;
    };
    let topic = format!("/test_{}/image_raw", std::process::id());
    let mut camera = runtime::camera::open(&format!("ros2:{topic}"), Some((64, 48))).unwrap();
    let mut publisher = cyclone_client(&python, "publish_frames.py")
        .args([topic.as_str(), "40"])
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let (mut frames, mut errors) = (Vec::new(), Vec::new());
    while start.elapsed() < std::time::Duration::from_secs(40) && frames.len() < 150 {
        let now_s = start.elapsed().as_secs_f64();
        match camera.next_frame(now_s) {
            Ok(Some(frame)) => frames.push(frame),
            Ok(None) => std::thread::sleep(std::time::Duration::from_micros(200)),
            Err(error) => errors.push(error.to_string()),
        }
    }
    let _ = publisher.kill();
    let _ = publisher.wait();
    assert!(
        frames.len() >= 150,
        "{} frames, errors {errors:?}",
        frames.len()
    );
    let mut colour = 0;
    for frame in &frames {
        let pixels = frame.frame.image.data();
        let n = usize::from(pixels[0]) + 256 * usize::from(pixels[1]);
        assert!(
            n % 10 != 0 && n % 10 != 5,
            "frame {n} should have been refused"
        );
        colour += usize::from(n % 10 == 3);
        for (i, &pixel) in pixels.iter().enumerate().skip(2) {
            let (x, y) = (i % 64, i / 64);
            assert_eq!(
                usize::from(pixel),
                (x * 3 + y * 5) % 256,
                "frame {n} pixel {x},{y}"
            );
        }
    }
    assert!(colour > 10, "{colour} rgb8 frames");
    assert!(errors.iter().any(|e| e.contains("yuv422")), "{errors:?}");
    assert!(
        errors.iter().any(|e| e.contains("80×48 pixels")),
        "{errors:?}"
    );
    let stats = camera.stats();
    assert_eq!(stats.malformed as usize, errors.len());
    assert_eq!(
        stats.sender_stamped, stats.delivered,
        "every frame stamped by its header"
    );
    // From the driver's stamp (just before it published) to the frame on qosrt's queue.
    let mut delays_ms: Vec<f64> = frames
        .iter()
        .map(|f| (f.arrived_s - f.capture_time_s) * 1e3)
        .collect();
    delays_ms.sort_by(f64::total_cmp);
    let p99 = delays_ms[delays_ms.len() * 99 / 100];
    eprintln!(
        "stamp to queue: p50 {:.2} ms, p99 {p99:.2} ms over {} frames",
        delays_ms[delays_ms.len() / 2],
        delays_ms.len()
    );
    assert!(delays_ms[0] >= 0.0 && p99 <= 5.0, "{delays_ms:?}");
}

/// Three real PX4 autopilots (SITL, SIH), each flown by its own `qosrt run --control --ros2`, as
/// a farm's three drones: `qosrt fleet --json` sees all three with their phases and margins,
/// and one's reserve changed in flight by `qosrt fleet set` shows in the view while the other
/// two keep theirs.
#[test]
fn the_fleet_sees_three_px4_vehicles_and_changes_one_in_flight() {
    let Some(first) = Px4::start(7) else { return };
    let autopilots: Vec<Px4> = std::iter::once(first)
        .chain([8, 9].map(|i| Px4::start(i).expect("the PX4 SITL that started instance 7")))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let config = short_mission(dir.path(), 120.0);
    let names: Vec<String> = autopilots
        .iter()
        .map(|px4| format!("px4_{}_{}", std::process::id(), px4.instance))
        .collect();
    let logs: Vec<PathBuf> = names
        .iter()
        .map(|name| dir.path().join(format!("{name}.log")))
        .collect();
    let _runs = Children(
        autopilots
            .iter()
            .zip(&names)
            .zip(&logs)
            .map(|((px4, name), log)| {
                Command::new(env!("CARGO_BIN_EXE_qosrt"))
                    .current_dir(repo_root())
                    .arg("run")
                    .arg(&config)
                    .args(["--mavlink", &px4.mavlink(), "--control"])
                    .args(["--meeting-point-ne-m", "5,0", "--duration-s", "200"])
                    .arg(format!("--ros2={name}"))
                    .stdout(Stdio::null())
                    .stderr(std::fs::File::create(log).unwrap())
                    .spawn()
                    .unwrap()
            })
            .collect(),
    );
    let said = || {
        logs.iter()
            .map(|log| std::fs::read_to_string(log).unwrap_or_default())
            .collect::<Vec<_>>()
            .join("\n")
    };
    let (mut view, mut snapshots) = fleet_view(150);
    // All three flying a phase, each with the margin of its governor's first re-plan (after
    // its 30 s warm-up on PX4's battery telemetry).
    let all_seen = snapshots
        .find(|snapshot| {
            names.iter().all(|name| {
                vehicle_in(snapshot, name)
                    .is_some_and(|v| v["margin_wh"].is_number() && v["phase"].is_string())
            })
        })
        .unwrap_or_else(|| panic!("not all three seen with a margin; they said:\n{}", said()));
    for name in &names {
        let vehicle = vehicle_in(&all_seen, name).unwrap();
        assert!(
            vehicle["battery_fraction"].as_f64().unwrap() > 0.5,
            "{vehicle}"
        );
        assert_eq!(vehicle["reserve_fraction"], 0.25, "{vehicle}");
    }
    let set = fleet(&["set", &names[1], "reserve=0.35", "--json"]);
    assert!(set.status.success(), "{}", output_text(&set));
    let answer: Value = serde_json::from_slice(&set.stdout).unwrap();
    assert_eq!(answer["accepted"], true, "{answer}");
    eprintln!(
        "three PX4: {} found in {:.1} s, answered {:.0} ms after the ask",
        names[1],
        answer["found_s"].as_f64().unwrap(),
        answer["answered_ms"].as_f64().unwrap()
    );
    let changed = snapshots
        .find(|snapshot| {
            vehicle_in(snapshot, &names[1]).is_some_and(|v| v["reserve_fraction"] == 0.35)
        })
        .unwrap_or_else(|| panic!("the change not seen; they said:\n{}", said()));
    for name in [&names[0], &names[2]] {
        let vehicle = vehicle_in(&changed, name).expect("still seen");
        assert_eq!(vehicle["reserve_fraction"], 0.25, "{vehicle}");
        assert!(vehicle["link_age_s"].as_f64().unwrap() < 1.5, "{vehicle}");
    }
    let _ = view.kill();
    let _ = view.wait();
}
