//! `qosrt run --mavlink` fed a real PX4 flight's battery log (`../shared/data/px4-flight-battery/`)
//! by a PX4-like peer over UDP, at 50× speed: qosrt reads BATTERY_STATUS as PX4 encodes it and
//! its governor calls for a landing once, when the pack can no longer keep the reserve.

mod common;
use common::repo_root;

use mavlink::dialects::common::*;
use mavlink::{MavHeader, MavlinkVersion};
use serde_json::Value;
use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const SPEEDUP: f64 = 50.0;

/// One row of the log: time (s), voltage (V), current (A), discharged (mAh), remaining (0–1).
struct Row {
    time_s: f64,
    voltage_v: f64,
    current_a: f64,
    discharged_mah: f64,
    remaining: f64,
}

fn read_log(text: &str) -> Vec<Row> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (t, v, i, mah, rem) = (
        column("timestamp"),
        column("voltage_v"),
        column("current_a"),
        column("discharged_mah"),
        column("remaining"),
    );
    lines
        .map(|line| {
            let fields: Vec<f64> = line.split(',').map(|f| f.parse().unwrap()).collect();
            Row {
                time_s: fields[t] / 1e6,
                voltage_v: fields[v],
                current_a: fields[i],
                discharged_mah: fields[mah],
                remaining: fields[rem],
            }
        })
        .collect()
}

/// BATTERY_STATUS as PX4 fills it: the pack voltage in cell 0 (cells unknown), current in cA,
/// consumed charge in mAh, remaining in %, energy_consumed −1.
fn battery_status(row: &Row) -> MavMessage {
    let mut voltages = [u16::MAX; 10];
    voltages[0] = (row.voltage_v * 1000.0).round() as u16;
    MavMessage::BATTERY_STATUS(BATTERY_STATUS_DATA {
        current_consumed: row.discharged_mah.round() as i32,
        energy_consumed: -1,
        temperature: i16::MAX,
        voltages,
        current_battery: (row.current_a * 100.0).round() as i16,
        id: 0,
        battery_function: MavBatteryFunction::MAV_BATTERY_FUNCTION_ALL,
        mavtype: MavBatteryType::MAV_BATTERY_TYPE_LIPO,
        battery_remaining: (row.remaining * 100.0).round() as i8,
        ..Default::default()
    })
}

fn px4_heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 3 << 16, // POSCTL: the pilot flies
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

#[test]
fn a_real_px4_battery_log_drives_the_governor_through_the_link() {
    let log_path = repo_root().join("../shared/data/px4-flight-battery/battery_status.csv");
    let Ok(text) = std::fs::read_to_string(&log_path) else {
        eprintln!("skipped: {} is absent", log_path.display());
        return;
    };
    let rows = read_log(&text);
    let t0 = rows[0].time_s;
    let replay_s = (rows.last().unwrap().time_s - t0) / SPEEDUP;

    // A free port for qosrt's udpin.
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    // qosrt's clock starts before the replay does (its start-up): room for both.
    let duration_s = replay_s + 8.0;
    let mut child = Command::new(env!("CARGO_BIN_EXE_qosrt"))
        .args([
            "run",
            "qos.toml",
            "--mavlink",
            &format!("udpin:127.0.0.1:{port}"),
            "--duration-s",
            &format!("{duration_s:.1}"),
            "--json",
        ])
        .current_dir(repo_root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();

    let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut sequence = 0u8;
    let mut send = |message: &MavMessage| {
        let mut bytes = Vec::new();
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence,
        };
        sequence = sequence.wrapping_add(1);
        mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, message).unwrap();
        let _ = peer.send_to(&bytes, ("127.0.0.1", port));
    };
    // The replay starts once qosrt answers (its heartbeat): nothing of the log is lost to its
    // start-up.
    peer.set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    let waiting = Instant::now();
    loop {
        send(&px4_heartbeat());
        let mut buffer = [0u8; 512];
        if peer.recv_from(&mut buffer).is_ok() {
            break;
        }
        assert!(
            waiting.elapsed() < Duration::from_secs(30),
            "qosrt never answered"
        );
    }
    let started = Instant::now();
    let mut next_row = 0;
    let mut tick = 0u64;
    while next_row < rows.len() {
        let wall_s = started.elapsed().as_secs_f64();
        // The vehicle: airborne, hovering, at 20 Hz of wall time.
        if tick.is_multiple_of(20) {
            send(&px4_heartbeat());
            send(&MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
                vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
                landed_state: MavLandedState::MAV_LANDED_STATE_IN_AIR,
            }));
        }
        send(&MavMessage::ATTITUDE(ATTITUDE_DATA::default()));
        send(&MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: (wall_s * 1000.0) as u32,
            z: -10.0,
            ..Default::default()
        }));
        while next_row < rows.len() && (rows[next_row].time_s - t0) / SPEEDUP <= wall_s {
            send(&battery_status(&rows[next_row]));
            next_row += 1;
        }
        tick += 1;
        std::thread::sleep(Duration::from_millis(50));
    }
    // Keep the link alive until qosrt's time is up.
    while child.try_wait().unwrap().is_none() {
        assert!(
            started.elapsed().as_secs_f64() < duration_s + 30.0,
            "qosrt did not stop"
        );
        send(&px4_heartbeat());
        std::thread::sleep(Duration::from_millis(200));
    }
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    let report: Value = serde_json::from_slice(&output.stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stderr}"));

    // The battery as qosrt saw it: the log's first and last charge, within 1 %.
    let battery = &report["battery"];
    let first = battery["first"]["consumed_mah"].as_f64().unwrap();
    let last = battery["last"]["consumed_mah"].as_f64().unwrap();
    let log_first = rows[0].discharged_mah;
    let log_last = rows.last().unwrap().discharged_mah;
    assert!(
        (first - log_first).abs() <= 0.01 * log_last,
        "{first} vs {log_first}"
    );
    assert!(
        (last - log_last).abs() <= 0.01 * log_last,
        "{last} vs {log_last}"
    );
    let voltage = battery["last"]["voltage_v"].as_f64().unwrap();
    assert!(
        (voltage - rows.last().unwrap().voltage_v).abs() < 0.01,
        "{voltage}"
    );
    let current = battery["last"]["current_a"].as_f64().unwrap();
    assert!(
        (current - rows.last().unwrap().current_a).abs() < 0.01,
        "{current}"
    );
    // Nearly every row arrived (UDP on the loopback); the governor takes the newest reading of
    // each loop step (the replay sends bursts of rows 20 times a second).
    let received = report["messages_received"]["BATTERY_STATUS"]
        .as_u64()
        .unwrap();
    assert!(
        received as f64 >= 0.99 * rows.len() as f64,
        "{received} of {}",
        rows.len()
    );
    let samples = battery["samples"].as_u64().unwrap();
    assert!(
        samples as f64 >= 15.0 * replay_s,
        "{samples} readings in {replay_s} s"
    );

    // The governor called for a landing exactly once.
    let land_now: Vec<&Value> = report["governor"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|d| d["kind"] == "land_now")
        .collect();
    assert_eq!(land_now.len(), 1, "{}", report["governor"]);
    let events: Vec<&str> = report["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e[1].as_str().unwrap())
        .collect();
    assert_eq!(
        events.iter().filter(|e| e.starts_with("land now")).count(),
        1,
        "{events:?}"
    );
    // Observe mode: nothing was commanded, however the battery went.
    assert_eq!(report["control"], false);
    assert!(
        !events.iter().any(|e| e.starts_with("landing where")),
        "{events:?}"
    );
}
