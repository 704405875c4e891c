//! `qosrt run --mavlink` against the real PX4 v1.16.0 SITL (SIH quadrotor) in `../shared/px4-sitl/`:
//! it flies with `--control`, stays passive without it, and lets go when a ground station takes
//! the vehicle over. Each test runs its own PX4 instance, so they run side by side.

mod common;
use common::{qosrt_run, repo_root, report_of, short_mission, Px4};

use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn event_lines(report: &Value) -> Vec<String> {
    report["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e[1].as_str().unwrap().to_string())
        .collect()
}

fn modes(report: &Value) -> Vec<(String, bool)> {
    report["modes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| {
            (
                m["mode"].as_str().unwrap().to_string(),
                m["armed"].as_bool().unwrap(),
            )
        })
        .collect()
}

#[test]
fn flies_px4_through_offboard_and_lands_it_with_auto_land() {
    let Some(px4) = Px4::start(1) else { return };
    let dir = tempfile::tempdir().unwrap();
    let config = short_mission(dir.path(), 4.0);
    let child = qosrt_run(
        &config,
        &[
            "--mavlink",
            &px4.mavlink(),
            "--control",
            "--meeting-point-ne-m",
            "5,0",
            "--duration-s",
            "150",
            "--json",
        ],
    );
    let (report, stderr) = report_of(child, Duration::from_secs(200));
    let events = event_lines(&report);
    assert_eq!(report["autopilot"], "PX4", "{stderr}");
    assert_eq!(report["finished"], true, "{events:?}\n{stderr}");
    let order = [
        "armed",
        "took off",
        "phase transit started",
        "offboard engaged",
        "phase tracking started",
        "phase landing started",
        "landing where the vehicle is: no vision landing (no camera, or no landing task in the last phase): the autopilot lands where the vehicle is",
        "landed and disarmed",
    ];
    let positions: Vec<Option<usize>> = order
        .iter()
        .map(|wanted| events.iter().position(|e| e == wanted))
        .collect();
    assert!(positions.iter().all(Option::is_some), "{events:?}");
    assert!(positions.windows(2).all(|p| p[0] < p[1]), "{events:?}");
    let modes = modes(&report);
    assert!(modes.contains(&("Offboard".into(), true)), "{modes:?}");
    assert!(modes.contains(&("Land".into(), true)), "{modes:?}");
    assert_eq!(
        modes.last().map(|m| m.1),
        Some(false),
        "disarmed at the end"
    );
    // BATTERY_STATUS at the 2 Hz asked for, not PX4's default 0.5 Hz.
    let battery = report["messages_received"]["BATTERY_STATUS"]
        .as_f64()
        .unwrap();
    let wall_s = report["wall_s"].as_f64().unwrap();
    assert!(
        battery / wall_s > 1.5,
        "{battery} BATTERY_STATUS in {wall_s} s"
    );
    assert!(report["battery"]["samples"].as_u64().unwrap() > 10);
    // SIH keeps to the wall clock, and falls behind it by up to a fifth while the other
    // SITL tests share this machine's cores.
    assert_tracked_the_autopilots_clock(&report, 0.75..=1.1);
}

/// The link asked the autopilot's clock over TIMESYNC and the autopilot answered; its clock
/// ran at a rate within `rate_range` of the runtime's (a SITL's `--speedup`).
fn assert_tracked_the_autopilots_clock(report: &Value, rate_range: std::ops::RangeInclusive<f64>) {
    let clock = &report["autopilot_clock"];
    let number = |key: &str| {
        clock[key]
            .as_i64()
            .unwrap_or_else(|| panic!("{key}: {clock}"))
    };
    assert!(number("replies") >= 3, "{clock}");
    // The autopilot's clock counts from its boot, before qosrt started counting: at the
    // estimate's sample it reads more than the companion's time since qosrt started, by
    // the start's lead when the rates are equal, by less when the autopilot ran slower.
    let autopilot_ns = number("offset_ns") + number("midpoint_ns");
    assert!(autopilot_ns > 0, "{clock}");
    if clock["rate"].as_f64() == Some(1.0) {
        assert!(number("offset_ns") > 0, "{clock}");
    }
    assert!(number("round_trip_ns") < 50_000_000, "{clock}");
    let rate = clock["rate"].as_f64().unwrap();
    assert!(rate_range.contains(&rate), "{clock}");
}

#[test]
fn without_control_px4_stays_disarmed() {
    let Some(px4) = Px4::start(2) else { return };
    let dir = tempfile::tempdir().unwrap();
    let config = short_mission(dir.path(), 4.0);
    let recording = dir.path().join("observe.mcap");
    let child = qosrt_run(
        &config,
        &[
            "--mavlink",
            &px4.mavlink(),
            "--duration-s",
            "8",
            "--json",
            "--record",
            recording.to_str().unwrap(),
        ],
    );
    let (report, stderr) = report_of(child, Duration::from_secs(30));
    assert_eq!(report["autopilot"], "PX4", "{stderr}");
    assert_eq!(report["control"], false);
    // The flight's recording replays: every step, and what the link made of PX4's telemetry
    // and sent back is what it did in flight.
    let replayed = common::qosrt(&["replay", recording.to_str().unwrap(), "--json"]);
    let replay: Value = serde_json::from_slice(&replayed.stdout)
        .unwrap_or_else(|_| panic!("{}", common::output_text(&replayed)));
    assert_eq!(
        replay["steps_replayed"], replay["steps_recorded"],
        "{replay:#}"
    );
    assert!(replay["stopped"].is_null(), "{replay:#}");
    let channel = |topic: &str| {
        replay["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["topic"] == topic)
            .cloned()
            .unwrap_or_else(|| panic!("no {topic}: {replay:#}"))
    };
    for topic in ["/bus/vehicle/state", "/mavlink/out"] {
        let c = channel(topic);
        assert!(c["recorded"].as_u64().unwrap() > 20, "{c}");
        assert_eq!(c["differing"], 0, "{c}");
    }
    let modes = modes(&report);
    assert!(!modes.is_empty());
    assert!(modes.iter().all(|(_, armed)| !armed), "{modes:?}");
    let events = event_lines(&report);
    assert!(
        !events
            .iter()
            .any(|e| e == "armed" || e.starts_with("phase")),
        "{events:?}"
    );
    // It still listens and asks for its telemetry.
    assert!(report["messages_received"]["ATTITUDE"].as_u64().unwrap() > 100);
}

#[test]
fn a_ground_station_taking_px4_over_stops_qosrt_commanding() {
    let Some(px4) = Px4::start(3) else { return };
    let dir = tempfile::tempdir().unwrap();
    let config = short_mission(dir.path(), 60.0);
    let mut child = qosrt_run(
        &config,
        &[
            "--mavlink",
            &px4.mavlink(),
            "--control",
            "--duration-s",
            "50",
            "--json",
        ],
    );
    // Wait (on qosrt's log) for the tracking phase with OFFBOARD engaged (on a loaded machine
    // PX4 may be switched to OFFBOARD after the phase began): qosrt holds OFFBOARD.
    let stderr = child.stderr.take().unwrap();
    let (lines_tx, lines_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = lines_tx.send(line);
        }
    });
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut log = Vec::new();
    let seen = |log: &[String], text: &str| log.iter().any(|l| l.contains(text));
    while !(seen(&log, "phase tracking started") && seen(&log, "offboard engaged")) {
        assert!(
            Instant::now() < deadline,
            "never reached tracking: {log:#?}"
        );
        if let Ok(line) = lines_rx.recv_timeout(Duration::from_secs(1)) {
            log.push(line);
        }
    }
    // A ground station (system 255) switches PX4 to AUTO.LOITER on its own link.
    let gcs = UdpSocket::bind("127.0.0.1:0").unwrap();
    let set_loiter = mavlink::dialects::common::MavMessage::COMMAND_LONG(
        mavlink::dialects::common::COMMAND_LONG_DATA {
            // PX4 SITL instance i is system i + 1.
            target_system: px4.instance + 1,
            target_component: 1,
            command: mavlink::dialects::common::MavCmd::MAV_CMD_DO_SET_MODE,
            param1: 1.0,
            param2: 4.0,
            param3: 3.0,
            ..Default::default()
        },
    );
    let mut bytes = Vec::new();
    mavlink::write_versioned_msg(
        &mut bytes,
        mavlink::MavlinkVersion::V2,
        mavlink::MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: 0,
        },
        &set_loiter,
    )
    .unwrap();
    let px4_gcs_port = 18570 + u16::from(px4.instance);
    gcs.send_to(&bytes, ("127.0.0.1", px4_gcs_port)).unwrap();
    let output = child.wait_with_output().unwrap();
    let report: Value = serde_json::from_slice(&output.stdout).expect("a JSON report");
    let events = event_lines(&report);
    let taken = events
        .iter()
        .position(|e| e.starts_with("control taken over"))
        .unwrap_or_else(|| panic!("no takeover: {events:?}"));
    // Nothing qosrt commands after the takeover: no landing of its own, no offboard again.
    assert!(
        !events[taken..]
            .iter()
            .any(|e| e.starts_with("landing where") || e == "offboard engaged"),
        "{events:?}"
    );
    let modes = modes(&report);
    let loiter = modes
        .iter()
        .rposition(|(mode, _)| mode == "Hold")
        .unwrap_or_else(|| panic!("PX4 never loitered: {modes:?}"));
    assert!(
        modes[loiter..].iter().all(|(mode, _)| mode != "Offboard"),
        "{modes:?}"
    );
}

/// A running ArduCopter SITL instance, stopped when dropped.
struct ArduPilot {
    pid: u32,
    instance: u8,
}

impl ArduPilot {
    /// Starts instance `instance` at `speedup`× real time with `params` (`NAME=VALUE`) set at
    /// boot, or `None` when the SITL is absent.
    fn start(instance: u8, speedup: u32, params: &[&str]) -> Option<Self> {
        let start = repo_root().join("../shared/ardupilot-sitl/start");
        if !start.exists() {
            eprintln!("skipped: {} is absent", start.display());
            return None;
        }
        let output = Command::new(&start)
            .args(["-I", &instance.to_string(), "-s", &speedup.to_string()])
            .args(params.iter().flat_map(|param| ["-P", param]))
            .stdin(Stdio::null())
            .output()
            .expect("the ArduPilot start script runs");
        assert!(
            output.status.success(),
            "ArduPilot did not start: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        let pid = String::from_utf8_lossy(&output.stdout)
            .trim()
            .parse()
            .expect("the start script prints arducopter's pid");
        Some(Self { pid, instance })
    }

    /// Its first MAVLink TCP server (SERIAL0).
    fn mavlink(&self) -> String {
        format!("tcpout:127.0.0.1:{}", 5760 + 10 * u16::from(self.instance))
    }
}

impl Drop for ArduPilot {
    fn drop(&mut self) {
        let _ = Command::new("kill").arg(self.pid.to_string()).status();
    }
}

#[test]
fn flies_ardupilot_through_guided_and_lands_it_with_land() {
    // 5× real time: its EKF's wait for GPS (about 41 s) takes about 8 s here.
    let Some(copter) = ArduPilot::start(1, 5, &[]) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let config = short_mission(dir.path(), 3.0);
    let child = qosrt_run(
        &config,
        &[
            "--mavlink",
            &copter.mavlink(),
            "--control",
            "--meeting-point-ne-m",
            "5,0",
            "--duration-s",
            "120",
            "--json",
        ],
    );
    let (report, stderr) = report_of(child, Duration::from_secs(160));
    let events = event_lines(&report);
    assert_eq!(report["autopilot"], "ArduPilot", "{stderr}");
    assert_eq!(report["finished"], true, "{events:?}\n{stderr}");
    // Started at 5× real time: up to 5×, slower when this machine cannot keep up.
    assert_tracked_the_autopilots_clock(&report, 1.5..=5.5);
    for wanted in [
        "armed",
        "took off",
        "phase tracking started",
        "phase landing started",
        "landed and disarmed",
    ] {
        assert!(events.iter().any(|e| e == wanted), "{wanted}: {events:?}");
    }
    let modes = modes(&report);
    // GUIDED (Offboard to qosrt) armed, then LAND armed, then disarmed.
    assert!(modes.contains(&("Offboard".into(), true)), "{modes:?}");
    assert!(modes.contains(&("Land".into(), true)), "{modes:?}");
    assert_eq!(modes.last().map(|m| m.1), Some(false));
    // Nothing streams until asked: the telemetry the loop flies on arrived.
    for message in [
        "ATTITUDE",
        "LOCAL_POSITION_NED",
        "BATTERY_STATUS",
        "EXTENDED_SYS_STATE",
    ] {
        assert!(
            report["messages_received"][message].as_u64().unwrap_or(0) > 0,
            "{message}: {}",
            report["messages_received"]
        );
    }
}

#[test]
fn an_ardupilot_without_a_battery_monitor_gives_no_battery_telemetry_and_no_refusals() {
    // BATT_MONITOR = 0: SYS_STATUS still comes, at 0 V, with the battery sensor present but
    // not enabled. That is no reading, not a bad one.
    let Some(copter) = ArduPilot::start(2, 1, &["BATT_MONITOR=0"]) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let config = short_mission(dir.path(), 3.0);
    let child = qosrt_run(
        &config,
        &[
            "--mavlink",
            &copter.mavlink(),
            "--duration-s",
            "5",
            "--json",
        ],
    );
    let (report, stderr) = report_of(child, Duration::from_secs(60));
    assert_eq!(report["autopilot"], "ArduPilot", "{stderr}");
    let sys_status = report["messages_received"]["SYS_STATUS"]
        .as_u64()
        .unwrap_or(0);
    assert!(sys_status >= 3, "{}", report["messages_received"]);
    assert_eq!(report["battery"]["samples"], 0, "{}", report["battery"]);
    let events = event_lines(&report);
    assert!(
        !events.iter().any(|e| e.starts_with("telemetry refused")),
        "{events:?}"
    );
}

#[test]
fn when_the_time_is_up_qosrt_lands_px4_where_it_is_and_exits_once_disarmed() {
    let Some(px4) = Px4::start(4) else { return };
    let dir = tempfile::tempdir().unwrap();
    // Tracking would last 10 minutes; the run is over after 30 s, mid-tracking.
    let config = short_mission(dir.path(), 600.0);
    let child = qosrt_run(
        &config,
        &[
            "--mavlink",
            &px4.mavlink(),
            "--control",
            "--duration-s",
            "30",
            "--json",
        ],
    );
    let (report, stderr) = report_of(child, Duration::from_secs(150));
    let events = event_lines(&report);
    assert_eq!(report["finished"], true, "{events:?}\n{stderr}");
    let tracking = events
        .iter()
        .position(|e| e == "phase tracking started")
        .unwrap_or_else(|| panic!("{events:?}"));
    let landing = events
        .iter()
        .position(|e| e == "landing where the vehicle is: --duration-s ran out")
        .unwrap_or_else(|| panic!("{events:?}"));
    assert!(tracking < landing, "{events:?}");
    assert_eq!(
        events.last().map(String::as_str),
        Some("landed and disarmed")
    );
    assert!(
        !events.iter().any(|e| e == "phase landing started"),
        "{events:?}"
    );
    let modes = modes(&report);
    assert!(modes.contains(&("Land".into(), true)), "{modes:?}");
    assert_eq!(modes.last().map(|m| m.1), Some(false), "{modes:?}");
}
