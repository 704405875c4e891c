//! The simulated autopilot against the runtime's MAVLink link: telemetry maps, commands are
//! decoded and acknowledged, lockstep is deterministic, link loss is seen and recovered.

use algorithms::estimation::projection::Attitude;
use mavlink::dialects::common::*;
use nalgebra::Vector3;
use runtime::link::{
    AckResult, AutopilotMode, FailsafeAction, LinkConfig, LinkStatus, MavlinkLink, Sent,
    VehicleCommand,
};
use sim::autopilot::*;
use sim::flight::BatteryReading;
use sim::flight::{AutopilotCommand, CommandRejected, FlightMode, LandedState, VehicleSnapshot};
use std::net::UdpSocket;
use std::time::{Duration, Instant};

const STEP: Duration = Duration::from_secs(2);

fn snapshot(tick: u64) -> VehicleSnapshot {
    let time_s = tick as f64 * 0.02;
    VehicleSnapshot {
        time_s,
        position_ned_m: Vector3::new(0.1 * time_s, -0.05 * time_s, -5.0),
        velocity_ned_m_s: Vector3::new(0.1, -0.05, 0.0),
        acceleration_ned_m_s2: Vector3::zeros(),
        attitude: Attitude::new(0.05, -0.1, 0.3 + 0.01 * time_s),
        body_rates_rad_s: Vector3::new(0.0, 0.0, 0.01),
        armed: true,
        mode: FlightMode::Offboard,
        landed_state: LandedState::InAir,
        rangefinder_m: Some(4.0),
        battery: BatteryReading {
            voltage_v: 15.8,
            current_a: 20.5,
            consumed_mah: 420.0 + time_s,
            remaining_fraction: 0.8,
        },
        gimbal_attitude: None,
    }
}

fn pair(lockstep: bool, config: LinkConfig) -> (MavlinkLink, MavlinkAutopilot) {
    let link = MavlinkLink::bind_local_ephemeral(config).unwrap();
    let autopilot = MavlinkAutopilot::bind_local(link.local_addr().unwrap(), lockstep).unwrap();
    (link, autopilot)
}

/// Polls (not lockstep) until `done` or a wall-clock second has passed.
fn poll_until(
    link: &mut MavlinkLink,
    now_s: f64,
    mut done: impl FnMut(&runtime::link::LinkUpdate) -> bool,
) {
    let deadline = Instant::now() + Duration::from_secs(1);
    while Instant::now() < deadline {
        if done(&link.poll(now_s)) {
            return;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    panic!("nothing arrived within 1 s: {link:?}");
}

#[test]
fn autopilot_telemetry_arrives_and_maps() {
    let (mut link, mut autopilot) = pair(false, LinkConfig::default());
    autopilot.publish(&snapshot(0)).unwrap();
    let (mut state, mut battery, mut status) = (None, None, None);
    poll_until(&mut link, 0.0, |update| {
        state = update.vehicle_state.or(state);
        battery = update.battery.or(battery);
        status = update.autopilot.or(status);
        state.is_some() && battery.is_some() && status.is_some()
    });
    let state = state.unwrap();
    assert_eq!(state.attitude.roll_rad, f64::from(0.05f32));
    assert_eq!(state.attitude.pitch_rad, f64::from(-0.1f32));
    let tilt = f64::from(0.05f32).cos() * f64::from(-0.1f32).cos();
    assert!((state.height_above_pad_m - 4.0 * tilt).abs() < 1e-9);
    assert_eq!(state.velocity_ned_m_s.x, f64::from(0.1f32));
    assert!(!state.landed);
    let battery = battery.unwrap();
    assert_eq!(battery.voltage_v, Some(15.8));
    assert_eq!(battery.current_a, Some(20.5));
    assert_eq!(battery.consumed_mah, Some(420.0));
    assert_eq!(battery.remaining_fraction, Some(0.8));
    let status = status.unwrap();
    assert_eq!(status.mode, AutopilotMode::Offboard);
    assert_eq!(status.custom_mode, 6 << 16);
    assert!(status.armed);
    assert_eq!(link.status(), LinkStatus::Connected);
}

/// A vehicle with a camera gimbal: GIMBAL_DEVICE_ATTITUDE_STATUS with each ATTITUDE, and the
/// runtime reads the camera's attitude from it (to f32 precision).
#[test]
fn a_gimbal_reports_the_cameras_attitude_beside_the_vehicles() {
    let (mut link, mut autopilot) = pair(false, LinkConfig::default());
    let camera = Attitude::new(0.02, -0.01, 0.3);
    let mut sent = 0;
    for tick in 0..50 {
        let mut snap = snapshot(tick);
        snap.gimbal_attitude = Some(camera);
        autopilot.publish(&snap).unwrap();
        sent += 1;
    }
    let mut state = None;
    poll_until(&mut link, 1.0, |update| {
        state = update.vehicle_state.or(state);
        state.is_some_and(|s| s.gimbal_attitude.is_some())
    });
    let reported = state.unwrap().gimbal_attitude.unwrap();
    for (got, want) in [
        (reported.roll_rad, camera.roll_rad),
        (reported.pitch_rad, camera.pitch_rad),
        (reported.yaw_rad, camera.yaw_rad),
    ] {
        assert!((got - want).abs() < 1e-6, "{reported:?}");
    }
    // One per ATTITUDE: 50 ticks at 50 Hz, on top of the telemetry without a gimbal.
    let without = {
        let (_link, mut plain) = pair(false, LinkConfig::default());
        for tick in 0..sent {
            plain.publish(&snapshot(tick)).unwrap();
        }
        plain.stats().messages_sent
    };
    assert_eq!(autopilot.stats().messages_sent, without + 50);
}

#[test]
fn rates_follow_px4_on_the_snapshot_clock() {
    let (link, mut autopilot) = pair(false, LinkConfig::default());
    // One simulated second (t = 0 … 0.99 s) stepped at 100 Hz.
    for tick in 0..100 {
        let mut snap = snapshot(0);
        snap.time_s = tick as f64 * 0.01;
        autopilot.publish(&snap).unwrap();
    }
    // 1 HEARTBEAT + 50 ATTITUDE + 50 POSITION + 20 DISTANCE + 2×2 battery + 5 EXTENDED
    // + 5 GLOBAL_POSITION_INT.
    assert_eq!(
        autopilot.stats().messages_sent,
        1 + 50 + 50 + 20 + 4 + 5 + 5
    );
    drop(link);
}

#[test]
fn velocity_setpoint_and_arm_arrive_decoded_and_are_acked() {
    let (mut link, mut autopilot) = pair(false, LinkConfig::default());
    autopilot.publish(&snapshot(0)).unwrap();
    poll_until(&mut link, 0.0, |update| update.autopilot.is_some());
    let velocity = Vector3::new(1.0, -0.5, 0.25);
    assert_eq!(
        link.send(&VehicleCommand::VelocityNed {
            velocity_ned_m_s: velocity,
            yaw_rad: Some(0.5),
        })
        .unwrap(),
        Sent::Sent
    );
    assert_eq!(link.send(&VehicleCommand::Arm).unwrap(), Sent::Sent);
    link.send(&VehicleCommand::SetHold).unwrap();
    let mut received = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(1);
    while received.len() < 3 && Instant::now() < deadline {
        received.extend(autopilot.receive().unwrap());
    }
    assert_eq!(received.len(), 3, "{received:?}");
    assert_eq!(
        received[0].command,
        AutopilotCommand::VelocitySetpoint {
            velocity_ned_m_s: velocity,
            yaw_rad: Some(0.5),
        }
    );
    assert!(received[0].ack.is_none());
    assert_eq!(received[1].command, AutopilotCommand::Arm);
    assert_eq!(
        received[2].command,
        AutopilotCommand::SetMode(FlightMode::Hold)
    );
    autopilot.ack(received[1].ack.unwrap(), &Ok(())).unwrap();
    autopilot
        .ack(received[2].ack.unwrap(), &Err(CommandRejected::NotArmed))
        .unwrap();
    let mut acks = Vec::new();
    poll_until(&mut link, 0.0, |update| {
        acks.extend(update.acks.iter().copied());
        acks.len() == 2
    });
    assert_eq!(
        (acks[0].command_id, acks[0].result),
        (400, AckResult::Accepted)
    );
    assert_eq!(
        (acks[1].command_id, acks[1].result),
        (176, AckResult::Denied)
    );
    assert_eq!(link.stats().commands_denied, 1);
    assert!(autopilot.stats().runtime_heartbeats >= 1);
}

#[test]
fn setpoints_other_than_velocity_are_refused() {
    let mut setpoint = SET_POSITION_TARGET_LOCAL_NED_DATA {
        coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
        type_mask: runtime::link::mapping::velocity_type_mask(false),
        vx: 1.0,
        ..Default::default()
    };
    assert!(decode_velocity_setpoint(&setpoint).is_ok());
    setpoint.type_mask = PositionTargetTypemask::empty();
    assert_eq!(
        decode_velocity_setpoint(&setpoint),
        Err("position setpoints are not supported (velocity only)")
    );
    setpoint.type_mask = runtime::link::mapping::velocity_type_mask(false);
    setpoint.coordinate_frame = MavFrame::MAV_FRAME_BODY_FRD;
    assert!(decode_velocity_setpoint(&setpoint).is_err());
    setpoint.coordinate_frame = MavFrame::MAV_FRAME_LOCAL_NED;
    setpoint.vx = f32::NAN;
    assert!(decode_velocity_setpoint(&setpoint).is_err());
    let long = COMMAND_LONG_DATA {
        command: MavCmd::MAV_CMD_DO_SET_MODE,
        param1: 1.0,
        param2: 3.0,
        ..Default::default()
    };
    // POSCTL: the simulator has no pilot.
    assert_eq!(
        decode_command_long(&long),
        Err(MavResult::MAV_RESULT_DENIED)
    );
    let land = COMMAND_LONG_DATA {
        param2: 4.0,
        param3: 6.0,
        ..long
    };
    assert_eq!(
        decode_command_long(&land),
        Ok(AutopilotCommand::SetMode(FlightMode::Land))
    );
    let reboot = COMMAND_LONG_DATA {
        command: MavCmd::MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN,
        ..long
    };
    assert_eq!(
        decode_command_long(&reboot),
        Err(MavResult::MAV_RESULT_UNSUPPORTED)
    );
    assert_eq!(px4_mode_of(FlightMode::Land).custom_mode(), 0x0604_0000);
}

/// One lockstep run: the runtime answers each tick with a velocity setpoint derived from
/// what it received; the trace holds everything both sides saw.
fn lockstep_run(ticks: u64) -> Vec<String> {
    let (mut link, mut autopilot) = pair(true, LinkConfig::default());
    let mut trace = Vec::new();
    for tick in 0..ticks {
        let t_ns = autopilot.publish(&snapshot(tick)).unwrap();
        let update = link.poll_lockstep(t_ns, STEP).unwrap();
        trace.push(format!("{tick} runtime {update:?}"));
        if let Some(state) = update.vehicle_state {
            link.send(&VehicleCommand::VelocityNed {
                velocity_ned_m_s: state.velocity_ned_m_s * 2.0,
                yaw_rad: None,
            })
            .unwrap();
        }
        if tick == 10 {
            link.send(&VehicleCommand::Takeoff { altitude_m: 3.0 })
                .unwrap();
        }
        link.end_tick(t_ns).unwrap();
        let commands = autopilot.receive_lockstep(t_ns, STEP).unwrap();
        trace.push(format!("{tick} autopilot {commands:?}"));
    }
    trace.push(format!("{:?} {:?}", link.stats(), autopilot.stats()));
    trace
}

#[test]
fn lockstep_is_deterministic_over_200_ticks() {
    let first = lockstep_run(200);
    let second = lockstep_run(200);
    assert_eq!(first.len(), 401);
    assert_eq!(first, second);
    // Every tick after the first brought a setpoint to the autopilot.
    let with_setpoint = first
        .iter()
        .filter(|line| line.contains("autopilot") && line.contains("VelocitySetpoint"))
        .count();
    assert_eq!(with_setpoint, 200);
    assert!(first
        .iter()
        .any(|line| line.contains("Takeoff { altitude_m: 3.0 }")));
}

#[test]
fn link_loss_is_detected_after_the_timeout_and_recovers() {
    // Telemetry timeout out of the way: the heartbeat timeout decides.
    let config = LinkConfig {
        telemetry_timeout_s: 10.0,
        ..LinkConfig::default()
    };
    let (mut link, mut autopilot) = pair(true, config);
    let mut lost_at = None;
    let mut recovered_commands = Vec::new();
    for tick in 0..=300u64 {
        let time_s = tick as f64 * 0.02;
        // Down from t = 2 s (the last heartbeat got through at t = 1 s) to t = 4 s.
        autopilot.set_link_down((100..200).contains(&tick));
        let t_ns = autopilot.publish(&snapshot(tick)).unwrap();
        let update = link.poll_lockstep(t_ns, STEP).unwrap();
        match update.status {
            LinkStatus::Lost { since_s } => {
                lost_at.get_or_insert((time_s, since_s));
                assert_eq!(link.failsafe_action(), FailsafeAction::StopSetpoints);
                let suppressed = link
                    .send(&VehicleCommand::VelocityNed {
                        velocity_ned_m_s: Vector3::zeros(),
                        yaw_rad: None,
                    })
                    .unwrap();
                assert_eq!(suppressed, Sent::Suppressed);
            }
            LinkStatus::Connected if tick >= 200 => {
                if link.failsafe_action() == FailsafeAction::HoldThenReenter {
                    link.recover().unwrap();
                }
                assert_eq!(link.failsafe_action(), FailsafeAction::Continue);
            }
            LinkStatus::Connected => assert!(tick < 126, "still connected at {time_s}"),
            LinkStatus::Connecting => panic!("connecting at {time_s}"),
        }
        link.end_tick(t_ns).unwrap();
        let commands = autopilot.receive_lockstep(t_ns, STEP).unwrap();
        if tick >= 200 {
            recovered_commands.extend(commands.into_iter().map(|c| c.command));
        }
    }
    let (detected_s, since_s) = lost_at.expect("the link was never lost");
    assert!((since_s - 2.5).abs() < 1e-9, "lost since {since_s}");
    assert!((detected_s - 2.52).abs() < 1e-9, "detected at {detected_s}");
    assert_eq!(link.status(), LinkStatus::Connected);
    assert_eq!(
        recovered_commands,
        vec![
            AutopilotCommand::SetMode(FlightMode::Hold),
            AutopilotCommand::VelocitySetpoint {
                velocity_ned_m_s: Vector3::zeros(),
                yaw_rad: None
            },
            AutopilotCommand::SetMode(FlightMode::Offboard),
        ]
    );
    assert!(link.stats().suppressed_setpoints > 0);
    assert!(autopilot.stats().dropped > 0);
}

#[test]
fn default_telemetry_timeout_loses_the_link_first() {
    let (mut link, mut autopilot) = pair(true, LinkConfig::default());
    let mut since = None;
    for tick in 0..=140u64 {
        autopilot.set_link_down(tick >= 100);
        let t_ns = autopilot.publish(&snapshot(tick)).unwrap();
        if let LinkStatus::Lost { since_s } = link.poll_lockstep(t_ns, STEP).unwrap().status {
            since.get_or_insert(since_s);
        }
        link.end_tick(t_ns).unwrap();
        autopilot.receive_lockstep(t_ns, STEP).unwrap();
    }
    // Last position at t = 1.98 s, + 0.5 s.
    assert!((since.unwrap() - 2.48).abs() < 1e-6, "{since:?}");
}

#[test]
fn garbage_datagrams_are_skipped_and_counted_both_ways() {
    let (mut link, mut autopilot) = pair(false, LinkConfig::default());
    let vandal = UdpSocket::bind("127.0.0.1:0").unwrap();
    let garbage: [&[u8]; 4] = [
        b"hello",
        &[0xfd; 40],
        &[0xfe, 9, 0, 1, 1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0xaa, 0xbb],
        &[],
    ];
    for datagram in garbage {
        vandal
            .send_to(datagram, link.local_addr().unwrap())
            .unwrap();
        vandal
            .send_to(datagram, autopilot.local_addr().unwrap())
            .unwrap();
    }
    autopilot.publish(&snapshot(0)).unwrap();
    poll_until(&mut link, 0.0, |update| update.vehicle_state.is_some());
    assert_eq!(link.stats().malformed, 4);
    // The vandal's address did not become the link's peer: the heartbeat reached the autopilot.
    let deadline = Instant::now() + Duration::from_secs(1);
    while autopilot.stats().runtime_heartbeats == 0 && Instant::now() < deadline {
        autopilot.receive().unwrap();
    }
    assert_eq!(autopilot.stats().runtime_heartbeats, 1);
    assert_eq!(autopilot.stats().malformed, 4);
}

#[test]
fn lockstep_times_out_with_a_named_error() {
    let (_link, mut autopilot) = pair(true, LinkConfig::default());
    let error = autopilot
        .receive_lockstep(5, Duration::from_millis(50))
        .unwrap_err();
    assert!(
        matches!(error, AutopilotError::LockstepTimeout { t_ns: 5, .. }),
        "{error}"
    );
}
