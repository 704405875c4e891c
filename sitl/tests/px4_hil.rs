//! The real PX4 (v1.16.0 SITL, airframe `none_iris`, no physics of its own) flying the world's
//! rigid-body quadrotor over HIL: its EKF2 estimates from the world's sensors, its controllers
//! fly the world's body in the world's wind. Skips, saying why, without `../shared/px4-sitl`.

use std::net::UdpSocket;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use mavlink::dialects::common::{MavCmd, MavMessage, MavResult};
use mavlink::{MavHeader, MavlinkVersion};
use nalgebra::Vector3;
use sim::quadrotor::{Quadrotor, QuadrotorParams};
use sim::sensors::{Home, SensorParams, Sensors};
use sim::tractor::{PathKind, Tractor, TractorParams};
use sim::vehicle::Touchdown;
use sim::wind::{Wind, WindConfig};
use sim::world::World;
use sitl::hil::px4::{Px4Hil, Px4Vehicle};

mod common;
use common::{command_long, shared_dir, start, SitlProcess};

const INSTANCE: u8 = 5;

fn start_px4() -> Option<SitlProcess> {
    let dir = shared_dir("px4-sitl")?;
    Some(start(
        &dir,
        &["-i", &INSTANCE.to_string(), "-m", "none_iris"],
        &[],
    ))
}

#[derive(Debug, Default, Clone)]
struct Truth {
    time_s: f64,
    position_ned_m: Vector3<f64>,
    touchdown: Option<Touchdown>,
    armed: bool,
    error: Option<String>,
}

fn command(socket: &UdpSocket, peer: std::net::SocketAddr, command: MavCmd, params: [f32; 7]) {
    // PX4 instance i is system i + 1.
    let message = command_long(INSTANCE + 1, command, params);
    let mut bytes = Vec::new();
    let header = MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 0,
    };
    mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, &message).unwrap();
    socket.send_to(&bytes, peer).unwrap();
}

/// Acks received on the ground station's socket within `wait`.
fn acks(socket: &UdpSocket, wait: Duration) -> Vec<(MavCmd, MavResult)> {
    let mut buffer = [0u8; 4096];
    let mut out = Vec::new();
    let start = Instant::now();
    while start.elapsed() < wait {
        let Ok((n, _)) = socket.recv_from(&mut buffer) else {
            continue;
        };
        let mut reader = mavlink::MavlinkReader::new(&buffer[..n]);
        while let Ok((_, message)) = reader.read_any_message::<MavMessage>() {
            if let MavMessage::COMMAND_ACK(ack) = message {
                out.push((ack.command, ack.result));
            }
        }
    }
    out
}

#[test]
fn px4_takes_off_holds_in_12_m_s_gusts_and_lands_in_our_world() {
    let listener = Px4Hil::listen(INSTANCE).unwrap();
    let Some(_px4) = start_px4() else { return };
    let hil = Px4Hil::accept(&listener, INSTANCE, Duration::from_secs(20)).unwrap();
    let tractor = Tractor::new(
        PathKind::Straight,
        TractorParams::default(),
        [200.0, 0.0],
        0.0,
    )
    .unwrap()
    .parked();
    let wind = Wind::new(
        WindConfig::Gusts {
            speed_m_s: 12.0,
            direction_from_rad: std::f64::consts::FRAC_PI_2,
        },
        3,
    )
    .unwrap();
    let mut world = World::new(tractor, wind);
    let body = Quadrotor::on_ground(QuadrotorParams::default(), Vector3::zeros()).unwrap();
    let mut vehicle = Px4Vehicle::new(
        hil,
        body,
        Sensors::new(SensorParams::default(), Home::default(), 3),
    );
    let truth = Arc::new(Mutex::new(Truth::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let world_thread = {
        let (truth, stop) = (truth.clone(), stop.clone());
        std::thread::spawn(move || {
            let wall = Instant::now();
            while !stop.load(Ordering::SeqCst) {
                if let Err(error) = vehicle.step(&mut world) {
                    truth.lock().unwrap().error = Some(error.to_string());
                    return 0.0;
                }
                let mut t = truth.lock().unwrap();
                t.time_s = vehicle.time_s;
                t.position_ned_m = vehicle.body.position_ned_m();
                t.touchdown = vehicle.body.touchdown();
                t.armed = vehicle.last_commands.is_some_and(|c| c.armed);
            }
            vehicle.time_s / wall.elapsed().as_secs_f64()
        })
    };
    // A ground station on PX4's onboard link.
    let gcs = UdpSocket::bind(("127.0.0.1", 14540 + u16::from(INSTANCE))).unwrap();
    gcs.set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let mut buffer = [0u8; 2048];
    let snapshot = || truth.lock().unwrap().clone();
    let waiting = Instant::now();
    let px4_addr = loop {
        if let Ok((_, from)) = gcs.recv_from(&mut buffer) {
            break from;
        }
        assert!(
            waiting.elapsed() < Duration::from_secs(30),
            "PX4 sends nothing on its onboard link: {:?}",
            snapshot()
        );
    };
    let deadline = Instant::now() + Duration::from_secs(150);
    // Arm (refused until EKF2 is ready), then take off to 2.5 m in AUTO.TAKEOFF.
    let mut armed_at = None;
    while armed_at.is_none() {
        assert!(
            Instant::now() < deadline,
            "PX4 never armed: {:?}",
            snapshot()
        );
        assert!(snapshot().error.is_none(), "{:?}", snapshot());
        command(
            &gcs,
            px4_addr,
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
        if acks(&gcs, Duration::from_millis(300)).contains(&(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            MavResult::MAV_RESULT_ACCEPTED,
        )) {
            armed_at = Some(snapshot().time_s);
        }
    }
    command(
        &gcs,
        px4_addr,
        MavCmd::MAV_CMD_NAV_TAKEOFF,
        [0.0, 0.0, 0.0, f32::NAN, f32::NAN, f32::NAN, f32::NAN],
    );
    // Hold for 10 s of simulated time once up: the horizontal excursion in the gusts.
    let mut hold: Vec<Vector3<f64>> = Vec::new();
    let mut hold_from = None;
    loop {
        assert!(
            Instant::now() < deadline,
            "no steady hover: {:?}",
            snapshot()
        );
        let t = snapshot();
        assert!(t.error.is_none(), "{t:?}");
        if hold_from.is_none() && -t.position_ned_m.z > 2.0 {
            hold_from = Some(t.time_s + 5.0);
        }
        if let Some(from) = hold_from {
            if t.time_s >= from {
                hold.push(t.position_ned_m);
            }
            if t.time_s >= from + 10.0 {
                break;
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let mean = hold.iter().sum::<Vector3<f64>>() / hold.len() as f64;
    let worst = hold
        .iter()
        .map(|p| (p - mean).xy().norm())
        .fold(0.0, f64::max);
    eprintln!(
        "hover at {:.2} m, ±{worst:.2} m horizontally, {:.1} m from take-off",
        -mean.z,
        mean.xy().norm()
    );
    assert!((-mean.z - 2.5).abs() < 0.7, "{mean}");
    assert!(worst < 1.5, "{worst}");
    assert!(mean.xy().norm() < 3.0, "{mean}");
    // AUTO.LAND: PX4's descent at MPC_LAND_SPEED onto the ground.
    command(
        &gcs,
        px4_addr,
        MavCmd::MAV_CMD_NAV_LAND,
        [0.0, 0.0, 0.0, f32::NAN, f32::NAN, f32::NAN, f32::NAN],
    );
    while snapshot().touchdown.is_none() {
        assert!(Instant::now() < deadline, "never landed: {:?}", snapshot());
        assert!(snapshot().error.is_none(), "{:?}", snapshot());
        std::thread::sleep(Duration::from_millis(20));
    }
    let touchdown = snapshot().touchdown.unwrap();
    eprintln!("touchdown {touchdown:?}");
    assert!(touchdown.vertical_speed_m_s < 1.0, "{touchdown:?}");
    assert!(touchdown.tilt_deg < 15.0, "{touchdown:?}");
    stop.store(true, Ordering::SeqCst);
    let speedup = world_thread.join().unwrap();
    eprintln!(
        "armed at {:?} s; world ran at {speedup:.1}× real time",
        armed_at
    );
}
