//! The built-in autopilot (`sim::vehicle::Multirotor`, `VehicleParams::default()`) against the
//! real PX4 (v1.16.0 `none_iris` over HIL) and the real ArduPilot (Copter 4.6.3 over JSON) on
//! the same input: hovering at 8 m in calm air, a velocity step from 0 to 2 m/s north held for
//! 6 s, then back to 0 for 6 s; then, still asked to hold 0 m/s, a 12 m/s wind from the north
//! switched on at once and held 20 s. Each response is measured on the world's truth at
//! 100 Hz: the step's 63 % rise time, overshoot, peak tilt and settling time (±10 % of the
//! step); the gust's peak drift speed and distance, recovery time and tilts.
//! Skips, saying why, without `../shared/px4-sitl` and `../shared/ardupilot-sitl`. PX4 and
//! ArduPilot fly one after the other, never together.

use std::net::{SocketAddr, UdpSocket};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use mavlink::dialects::common::{
    MavCmd, MavFrame, MavMessage, MavResult, PositionTargetTypemask,
    SET_POSITION_TARGET_LOCAL_NED_DATA,
};
use mavlink::{MavConnection, MavHeader, MavlinkVersion};
use nalgebra::Vector3;
use sim::flight::{AutopilotCommand, FlightMode};
use sim::quadrotor::{BodyState, Quadrotor, QuadrotorParams};
use sim::sensors::{Home, SensorParams, Sensors};
use sim::tractor::{PathKind, Tractor, TractorParams};
use sim::vehicle::{Multirotor, VehicleParams};
use sim::wind::{Wind, WindConfig};
use sim::world::World;
use sitl::hil::ardupilot_json::{world_start_args, ArduPilotJson, ArduPilotVehicle};
use sitl::hil::px4::{Px4Hil, Px4Vehicle};

mod common;
use common::{command_long, shared_dir, start};
#[path = "autopilot_response/figures.rs"]
mod figures;
use figures::{
    gust_figures, north_setpoint, print_gust_table, print_table, response, GustFigures, Response,
    Sample, GUST_HOLD_S, GUST_SPEED_M_S, STEP_HOLD_S,
};

/// Instances no other test uses: PX4 9 (HIL TCP 4569, onboard UDP 14549, system 10) and
/// ArduPilot 9 (MAVLink TCP 5850, JSON UDP 9092; 7 is what `qosrt evaluate` runs were seen on).
const PX4_INSTANCE: u8 = 9;
const ARDUPILOT_INSTANCE: u8 = 9;

/// Above the seed wind's 6 m ground ramp: the gust pushes every vehicle alike.
const HOVER_ALTITUDE_M: f64 = 8.0;
const SAMPLE_PERIOD_S: f64 = 0.01;
const SETPOINT_PERIOD_S: f64 = 0.05;
/// Velocity only, in LOCAL_NED: position, acceleration, yaw and yaw rate ignored (3527).
const VELOCITY_TYPE_MASK: u16 = 3527;
const GUIDED: f32 = 4.0;

fn tilt_deg(state: &BodyState) -> f64 {
    let z = state.attitude * Vector3::z();
    z.z.clamp(-1.0, 1.0).acos().to_degrees()
}

/// Calm air over the ground; the tractor parked far away.
fn calm_world() -> World {
    let tractor = Tractor::new(
        PathKind::Straight,
        TractorParams::default(),
        [1_000.0, 1_000.0],
        0.0,
    )
    .unwrap()
    .parked();
    World::new(tractor, Wind::new(WindConfig::Calm, 1).unwrap())
}

/// The gust switched on in the calm world: steady, from the north.
fn gust() -> Wind {
    Wind::new(
        WindConfig::Steady {
            speed_m_s: GUST_SPEED_M_S,
            direction_from_rad: 0.0,
        },
        1,
    )
    .unwrap()
}

/// The two responses of one vehicle.
#[derive(Debug, Clone, Copy)]
struct Responses {
    step: Response,
    gust: GustFigures,
}

/// What the world thread shares with the ground station.
#[derive(Debug, Default)]
struct Shared {
    time_s: f64,
    altitude_m: f64,
    samples: Vec<Sample>,
    /// While true, the world thread streams velocity setpoints every 50 ms of simulated time.
    streaming: bool,
    /// The simulated time of the step up; the world thread applies it on its own clock.
    step_at_s: Option<f64>,
    /// The simulated time the gust starts; the world thread switches the wind on then.
    gust_at_s: Option<f64>,
    error: Option<String>,
}

/// The lockstep loop: `step` moves `world` by one autopilot frame and returns the time and
/// the body's state; `send_north` sends a velocity setpoint north to the autopilot.
fn world_loop(
    mut world: World,
    mut step: impl FnMut(&mut World) -> Result<(f64, BodyState), String>,
    mut send_north: impl FnMut(f64),
    shared: &Mutex<Shared>,
    stop: &AtomicBool,
) -> f64 {
    let wall = Instant::now();
    let mut next_sample_s = 0.0;
    let mut next_setpoint_s = 0.0;
    let mut time_s = 0.0;
    while !stop.load(Ordering::Relaxed) {
        let state = match step(&mut world) {
            Ok((t, state)) => {
                time_s = t;
                state
            }
            Err(error) => {
                shared.lock().unwrap().error = Some(error);
                break;
            }
        };
        let mut s = shared.lock().unwrap();
        s.time_s = time_s;
        s.altitude_m = -state.position_ned_m.z;
        if s.gust_at_s.is_some_and(|at| time_s >= at) && world.wind.config() == WindConfig::Calm {
            world.wind = gust();
        }
        if time_s >= next_sample_s {
            s.samples.push(Sample {
                time_s,
                north_m_s: state.velocity_ned_m_s.x,
                tilt_deg: tilt_deg(&state),
            });
            while next_sample_s <= time_s {
                next_sample_s += SAMPLE_PERIOD_S;
            }
        }
        if s.streaming && time_s >= next_setpoint_s {
            send_north(north_setpoint(time_s, s.step_at_s));
            next_setpoint_s = time_s + SETPOINT_PERIOD_S;
        }
    }
    time_s / wall.elapsed().as_secs_f64()
}

fn velocity_setpoint(target_system: u8, north_m_s: f64) -> MavMessage {
    MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
        target_system,
        target_component: 1,
        coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
        type_mask: PositionTargetTypemask::from_bits_truncate(VELOCITY_TYPE_MASK),
        vx: north_m_s as f32,
        ..Default::default()
    })
}

const GCS_HEADER: MavHeader = MavHeader {
    system_id: 255,
    component_id: 190,
    sequence: 0,
};

/// Waits, checking the world, until `done` holds for the shared state or the deadline passes.
fn wait_until(
    shared: &Mutex<Shared>,
    deadline: Instant,
    what: &str,
    mut pump: impl FnMut(),
    done: impl Fn(&Shared) -> bool,
) {
    loop {
        {
            let s = shared.lock().unwrap();
            assert!(s.error.is_none(), "the world stopped: {:?}", s.error);
            if done(&s) {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "{what}: not by t = {:.1} s (altitude {:.2} m)",
                s.time_s,
                s.altitude_m
            );
        }
        pump();
    }
}

/// The hover, the setpoint stream, the step, the gust: common to both real autopilots once
/// airborne. `pump` reads the ground station's link; `enter_offboard` is called once the stream
/// runs. Returns the times of the step and of the gust.
fn fly_step_and_gust(
    shared: &Mutex<Shared>,
    deadline: Instant,
    mut pump: impl FnMut(),
    enter_offboard: impl FnOnce(&mut dyn FnMut()),
) -> (f64, f64) {
    wait_until(shared, deadline, "hover at 8 m", &mut pump, |s| {
        (s.altitude_m - HOVER_ALTITUDE_M).abs() < 0.5
    });
    let settle_until = shared.lock().unwrap().time_s + 3.0;
    wait_until(shared, deadline, "settled hover", &mut pump, |s| {
        s.time_s >= settle_until
    });
    let stream_from_s = {
        let mut s = shared.lock().unwrap();
        s.streaming = true;
        s.time_s
    };
    wait_until(shared, deadline, "a second of setpoints", &mut pump, |s| {
        s.time_s >= stream_from_s + 1.0
    });
    enter_offboard(&mut pump);
    let offboard_at_s = shared.lock().unwrap().time_s;
    wait_until(shared, deadline, "hover under setpoints", &mut pump, |s| {
        s.time_s >= offboard_at_s + 2.0
    });
    let step_at_s = {
        let mut s = shared.lock().unwrap();
        let at = s.time_s + 0.5;
        s.step_at_s = Some(at);
        at
    };
    wait_until(shared, deadline, "the step's end", &mut pump, |s| {
        s.time_s >= step_at_s + 2.0 * STEP_HOLD_S + 0.2
    });
    let gust_at_s = {
        let mut s = shared.lock().unwrap();
        let at = s.time_s + 0.5;
        s.gust_at_s = Some(at);
        at
    };
    wait_until(shared, deadline, "the gust's end", &mut pump, |s| {
        s.time_s >= gust_at_s + GUST_HOLD_S + 0.2
    });
    (step_at_s, gust_at_s)
}

/// The figures of a real autopilot's flight, printed with its pace.
fn responses_of(
    name: &str,
    shared: &Mutex<Shared>,
    times: (f64, f64),
    speedup: f64,
    wall: Instant,
) -> Responses {
    let (step_at_s, gust_at_s) = times;
    let samples = std::mem::take(&mut shared.lock().unwrap().samples);
    eprintln!(
        "{name}: step at t = {step_at_s:.1} s, gust at {gust_at_s:.1} s, {speedup:.1}× real time, {:.1} s wall",
        wall.elapsed().as_secs_f64()
    );
    Responses {
        step: response(&samples, step_at_s),
        gust: gust_figures(&samples, gust_at_s),
    }
}

fn px4_responses(dir: &Path) -> Responses {
    let wall = Instant::now();
    let deadline = wall + Duration::from_secs(150);
    let listener = Px4Hil::listen(PX4_INSTANCE).unwrap();
    let _px4 = start(
        dir,
        &["-i", &PX4_INSTANCE.to_string(), "-m", "none_iris"],
        &[(
            "PX4_PARAMS",
            &format!("MIS_TAKEOFF_ALT {HOVER_ALTITUDE_M}") as &str,
        )],
    );
    let hil = Px4Hil::accept(&listener, PX4_INSTANCE, Duration::from_secs(20)).unwrap();
    let body = Quadrotor::on_ground(QuadrotorParams::default(), Vector3::zeros()).unwrap();
    let sensors = Sensors::new(SensorParams::default(), Home::default(), 9);
    let mut vehicle = Px4Vehicle::new(hil, body, sensors);
    let gcs = UdpSocket::bind(("127.0.0.1", 14540 + u16::from(PX4_INSTANCE))).unwrap();
    gcs.set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let peer: Arc<OnceLock<SocketAddr>> = Arc::new(OnceLock::new());
    let shared = Arc::new(Mutex::new(Shared::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let system = PX4_INSTANCE + 1;
    let send = |socket: &UdpSocket, to: SocketAddr, message: &MavMessage| {
        let mut bytes = Vec::new();
        mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, GCS_HEADER, message).unwrap();
        let _ = socket.send_to(&bytes, to);
    };
    let world = {
        let (shared, stop, peer) = (shared.clone(), stop.clone(), peer.clone());
        let socket = gcs.try_clone().unwrap();
        std::thread::spawn(move || {
            world_loop(
                calm_world(),
                |world| {
                    vehicle.step(world).map_err(|e| e.to_string())?;
                    Ok((vehicle.time_s, *vehicle.body.state()))
                },
                |north| {
                    if let Some(to) = peer.get() {
                        send(&socket, *to, &velocity_setpoint(system, north));
                    }
                },
                &shared,
                &stop,
            )
        })
    };
    // Whatever arrives on the onboard link: its sender and the command acks.
    let acks = Mutex::new(Vec::<(MavCmd, MavResult)>::new());
    let pump = || {
        let mut buffer = [0u8; 4096];
        if let Ok((n, from)) = gcs.recv_from(&mut buffer) {
            let _ = peer.set(from);
            let mut reader = mavlink::MavlinkReader::new(&buffer[..n]);
            while let Ok((_, message)) = reader.read_any_message::<MavMessage>() {
                if let MavMessage::COMMAND_ACK(ack) = message {
                    acks.lock().unwrap().push((ack.command, ack.result));
                }
            }
        }
    };
    let accepted = |command: MavCmd| {
        let mut acks = acks.lock().unwrap();
        let yes = acks.contains(&(command, MavResult::MAV_RESULT_ACCEPTED));
        acks.retain(|(c, _)| *c != command);
        yes
    };
    let issue = |command: MavCmd, params: [f32; 7]| {
        let to = *peer.get().expect("PX4's address is known");
        send(&gcs, to, &command_long(system, command, params));
    };
    while peer.get().is_none() {
        assert!(Instant::now() < deadline, "PX4 sends nothing on its link");
        assert!(shared.lock().unwrap().error.is_none());
        pump();
    }
    // Arm (refused until EKF2 is ready), then take off to MIS_TAKEOFF_ALT = 8 m.
    loop {
        assert!(Instant::now() < deadline, "PX4 never armed");
        assert!(shared.lock().unwrap().error.is_none());
        issue(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
        for _ in 0..6 {
            pump();
        }
        if accepted(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM) {
            break;
        }
    }
    issue(
        MavCmd::MAV_CMD_NAV_TAKEOFF,
        [0.0, 0.0, 0.0, f32::NAN, f32::NAN, f32::NAN, f32::NAN],
    );
    let times = fly_step_and_gust(&shared, deadline, pump, |pump| loop {
        assert!(Instant::now() < deadline, "OFFBOARD refused");
        issue(
            MavCmd::MAV_CMD_DO_SET_MODE,
            [1.0, 6.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
        for _ in 0..4 {
            pump();
        }
        if accepted(MavCmd::MAV_CMD_DO_SET_MODE) {
            break;
        }
    });
    stop.store(true, Ordering::Relaxed);
    let speedup = world.join().unwrap();
    responses_of("PX4", &shared, times, speedup, wall)
}

fn ardupilot_responses(dir: &Path) -> Responses {
    let wall = Instant::now();
    let deadline = wall + Duration::from_secs(150);
    let backend = ArduPilotJson::bind(ARDUPILOT_INSTANCE).unwrap();
    let instance = ARDUPILOT_INSTANCE.to_string();
    let mut args = vec!["-I", &instance];
    let world_args = world_start_args();
    args.extend(world_args.split_whitespace());
    let _ardupilot = start(dir, &args, &[]);
    let link = Arc::new(
        mavlink::connect::<MavMessage>(&format!(
            "tcpout:127.0.0.1:{}",
            5760 + 10 * u16::from(ARDUPILOT_INSTANCE)
        ))
        .expect("ArduPilot's MAVLink TCP server accepts"),
    );
    let body = Quadrotor::on_ground(QuadrotorParams::default(), Vector3::zeros()).unwrap();
    let sensors = Sensors::new(SensorParams::default(), Home::default(), 7);
    let mut vehicle = ArduPilotVehicle::new(backend, body, sensors);
    let shared = Arc::new(Mutex::new(Shared::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let world = {
        let (shared, stop, link) = (shared.clone(), stop.clone(), link.clone());
        std::thread::spawn(move || {
            world_loop(
                calm_world(),
                |world| {
                    vehicle.step(world).map_err(|e| e.to_string())?;
                    Ok((vehicle.time_s, *vehicle.body.state()))
                },
                |north| {
                    let _ = link.send(&GCS_HEADER, &velocity_setpoint(1, north));
                },
                &shared,
                &stop,
            )
        })
    };
    let acks = Mutex::new(Vec::<(MavCmd, MavResult)>::new());
    let texts = Mutex::new(Vec::<String>::new());
    let last_texts = || {
        let texts = texts.lock().unwrap();
        texts[texts.len().saturating_sub(8)..].to_vec()
    };
    let pump = || {
        // The link's reads time out every 100 ms.
        match link.recv() {
            Ok((_, MavMessage::COMMAND_ACK(ack))) => {
                acks.lock().unwrap().push((ack.command, ack.result));
            }
            Ok((_, MavMessage::STATUSTEXT(text))) => {
                let text = String::from_utf8_lossy(&text.text.to_vec())
                    .trim_end_matches('\0')
                    .to_string();
                texts.lock().unwrap().push(text);
            }
            _ => {}
        }
    };
    let accepted = |command: MavCmd| {
        let mut acks = acks.lock().unwrap();
        let yes = acks.contains(&(command, MavResult::MAV_RESULT_ACCEPTED));
        acks.retain(|(c, _)| *c != command);
        yes
    };
    let issue = |command: MavCmd, params: [f32; 7]| {
        link.send(&GCS_HEADER, &command_long(1, command, params))
            .expect("MAVLink send");
    };
    let pump_for = |wall: Duration| {
        let until = Instant::now() + wall;
        while Instant::now() < until {
            pump();
        }
    };
    // GUIDED, arm (refused until EKF3 has a position) and take off, all again until the
    // take-off is accepted: armed at this pace, ArduPilot may disarm (10 s on the ground
    // without a take-off) before the take-off arrives.
    let mut tries = 0;
    loop {
        tries += 1;
        assert!(
            Instant::now() < deadline,
            "ArduPilot never took off: {:?}, {:?}",
            last_texts(),
            acks.lock().unwrap()
        );
        assert!(shared.lock().unwrap().error.is_none());
        issue(
            MavCmd::MAV_CMD_DO_SET_MODE,
            [1.0, GUIDED, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
        issue(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
        pump_for(Duration::from_millis(300));
        if !accepted(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM) {
            continue;
        }
        issue(
            MavCmd::MAV_CMD_NAV_TAKEOFF,
            [
                0.0,
                0.0,
                0.0,
                f32::NAN,
                f32::NAN,
                f32::NAN,
                HOVER_ALTITUDE_M as f32,
            ],
        );
        pump_for(Duration::from_millis(200));
        if accepted(MavCmd::MAV_CMD_NAV_TAKEOFF) {
            break;
        }
    }
    eprintln!(
        "ArduPilot: took off at t = {:.1} s after {tries} tries; its last words {:?}",
        shared.lock().unwrap().time_s,
        last_texts()
    );
    // GUIDED takes velocity setpoints as they come: no mode change.
    let times = fly_step_and_gust(&shared, deadline, pump, |_| {});
    stop.store(true, Ordering::Relaxed);
    let speedup = world.join().unwrap();
    responses_of("ArduPilot", &shared, times, speedup, wall)
}

/// The built-in vehicle with `params` on the same flight: take-off to 8 m, a settled hover,
/// offboard setpoints every 50 ms, the step, the gust; the world at 100 Hz.
fn builtin_responses(params: VehicleParams) -> Responses {
    let mut world = calm_world();
    let mut vehicle = Multirotor::on_ground(params, Vector3::zeros()).unwrap();
    let mut t = 0.0;
    vehicle.command(AutopilotCommand::Arm, t).unwrap();
    vehicle
        .command(
            AutopilotCommand::Takeoff {
                altitude_m: HOVER_ALTITUDE_M,
            },
            t,
        )
        .unwrap();
    let mut samples = Vec::new();
    let advance =
        |world: &mut World, vehicle: &mut Multirotor, t: &mut f64, samples: &mut Vec<Sample>| {
            world.step(*t, SAMPLE_PERIOD_S, vehicle).unwrap();
            *t += SAMPLE_PERIOD_S;
            samples.push(Sample {
                time_s: *t,
                north_m_s: vehicle.velocity_ned_m_s().x,
                tilt_deg: vehicle.tilt_rad().to_degrees(),
            });
        };
    while (-vehicle.position_ned_m().z - HOVER_ALTITUDE_M).abs() >= 0.5 {
        assert!(t < 60.0, "the built-in never reached 8 m");
        advance(&mut world, &mut vehicle, &mut t, &mut samples);
    }
    let settle_until = t + 3.0;
    while t < settle_until {
        advance(&mut world, &mut vehicle, &mut t, &mut samples);
    }
    let setpoint = |north: f64| AutopilotCommand::VelocitySetpoint {
        velocity_ned_m_s: Vector3::new(north, 0.0, 0.0),
        yaw_rad: None,
    };
    vehicle.command(setpoint(0.0), t).unwrap();
    vehicle
        .command(AutopilotCommand::SetMode(FlightMode::Offboard), t)
        .unwrap();
    // As the real autopilots fly it: the step 2.5 s after offboard, the gust 0.7 s after the
    // step's end.
    let step_at_s = t + 2.5;
    let gust_at_s = step_at_s + 2.0 * STEP_HOLD_S + 0.7;
    let end_s = gust_at_s + GUST_HOLD_S + 0.2;
    let mut next_setpoint_s = t + SETPOINT_PERIOD_S;
    while t < end_s {
        if t >= next_setpoint_s - 1e-9 {
            vehicle
                .command(setpoint(north_setpoint(t, Some(step_at_s))), t)
                .unwrap();
            next_setpoint_s = t + SETPOINT_PERIOD_S;
        }
        if t >= gust_at_s - 1e-9 && world.wind.config() == WindConfig::Calm {
            world.wind = gust();
        }
        advance(&mut world, &mut vehicle, &mut t, &mut samples);
    }
    assert_eq!(vehicle.mode(), FlightMode::Offboard);
    Responses {
        step: response(&samples, step_at_s),
        gust: gust_figures(&samples, gust_at_s),
    }
}

/// |ln(b / p)|, or a large distance where either is missing.
fn log_ratio(b: Option<f64>, p: Option<f64>) -> f64 {
    match (b, p) {
        (Some(b), Some(p)) if b > 0.0 && p > 0.0 => (b / p).ln().abs(),
        (Some(_), Some(_)) => 1.0,
        _ => 10.0,
    }
}

/// The candidate built-in parameters whose responses are nearest PX4's: on the step, rise and
/// settling time (log of the ratio), peak tilt (per 10°) and overshoot (per 10 %), up and
/// down; in the gust, peak drift speed, distance and recovery time (log of the ratio) and peak
/// tilt (per 10°).
fn nearest_to(px4: &Responses) -> Vec<(f64, VehicleParams, Responses)> {
    let distance = |r: &Responses| {
        let step: f64 = [(r.step.up, px4.step.up), (r.step.down, px4.step.down)]
            .iter()
            .map(|(b, p)| {
                log_ratio(b.rise_63_s, p.rise_63_s)
                    + log_ratio(b.settling_s, p.settling_s)
                    + (b.peak_tilt_deg - p.peak_tilt_deg).abs() / 10.0
                    + (b.overshoot - p.overshoot).abs() / 0.1
            })
            .sum();
        let (b, p) = (r.gust, px4.gust);
        let gust = log_ratio(Some(b.peak_drift_m_s), Some(p.peak_drift_m_s))
            + log_ratio(Some(b.peak_displacement_m), Some(p.peak_displacement_m))
            + log_ratio(b.recovery_s, p.recovery_s)
            + (b.peak_tilt_deg - p.peak_tilt_deg).abs() / 10.0;
        step + gust
    };
    let mut candidates = Vec::new();
    for tau in [0.05, 0.1, 0.15, 0.2, 0.3] {
        for p in [0.8, 1.0, 1.2, 1.5, 1.8, 2.2, 2.7, 3.5] {
            for i in [0.1, 0.4, 1.0, 2.0] {
                let params = VehicleParams {
                    attitude_time_constant_s: tau,
                    velocity_p_horizontal_per_s: p,
                    velocity_i_horizontal_per_s2: i,
                    ..Default::default()
                };
                let r = builtin_responses(params);
                candidates.push((distance(&r), params, r));
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    candidates.truncate(3);
    candidates
}

#[test]
fn the_builtin_follows_px4_and_ardupilot_on_a_velocity_step_and_in_a_gust() {
    let wall = Instant::now();
    let (Some(px4_dir), Some(ardupilot_dir)) =
        (shared_dir("px4-sitl"), shared_dir("ardupilot-sitl"))
    else {
        eprintln!("skipped: ../shared/px4-sitl or ../shared/ardupilot-sitl is absent");
        return;
    };
    // One after the other: each SITL and its world take a core.
    let px4 = px4_responses(&px4_dir);
    let ardupilot = ardupilot_responses(&ardupilot_dir);
    let builtin = builtin_responses(VehicleParams::default());
    let nearest = nearest_to(&px4);
    let mut rows = vec![
        ("PX4 v1.16 (none_iris)", px4),
        ("ArduPilot 4.6.3 (JSON)", ardupilot),
        ("built-in (default)", builtin),
    ];
    for (k, (_, _, r)) in nearest.iter().enumerate() {
        rows.push((["candidate 1", "candidate 2", "candidate 3"][k], *r));
    }
    let steps: Vec<(&str, Response)> = rows.iter().map(|(name, r)| (*name, r.step)).collect();
    print_table(&steps);
    let gusts: Vec<(&str, GustFigures)> = rows.iter().map(|(name, r)| (*name, r.gust)).collect();
    print_gust_table(&gusts);
    for (k, (d, p, _)) in nearest.iter().enumerate() {
        eprintln!(
            "candidate {}: attitude_time_constant_s {}, velocity_p_horizontal_per_s {}, velocity_i_horizontal_per_s2 {} (distance {d:.2})",
            k + 1,
            p.attitude_time_constant_s,
            p.velocity_p_horizontal_per_s,
            p.velocity_i_horizontal_per_s2
        );
    }
    eprintln!("wall time {:.1} s", wall.elapsed().as_secs_f64());

    // The real autopilots follow the step and ride out the gust: the test drives them right.
    for (name, r) in [("PX4", px4), ("ArduPilot", ardupilot)] {
        assert!(
            r.step.up.reached && r.step.down.reached,
            "{name} did not follow the step: {r:?}"
        );
        assert!(
            r.gust.recovery_s.is_some(),
            "{name} did not recover from the gust: {r:?}"
        );
    }
    // The built-in against PX4.
    let best = &nearest[0].1;
    let suggestion = format!(
        "nearest candidate: attitude_time_constant_s {}, velocity_p_horizontal_per_s {}, velocity_i_horizontal_per_s2 {}",
        best.attitude_time_constant_s,
        best.velocity_p_horizontal_per_s,
        best.velocity_i_horizontal_per_s2
    );
    for (label, b, p) in [
        ("up", builtin.step.up, px4.step.up),
        ("down", builtin.step.down, px4.step.down),
    ] {
        let (Some(rise_b), Some(rise_p)) = (b.rise_63_s, p.rise_63_s) else {
            panic!("step {label}: no 63 % rise: built-in {b:?}, PX4 {p:?}");
        };
        let ratio = rise_b / rise_p;
        assert!(
            (0.5..=2.0).contains(&ratio),
            "step {label}: the built-in's 63 % rise {rise_b:.2} s is {ratio:.2}× PX4's {rise_p:.2} s (allowed 0.5–2); {suggestion}"
        );
        let gap = b.peak_tilt_deg - p.peak_tilt_deg;
        assert!(
            gap.abs() <= 10.0,
            "step {label}: the built-in's peak tilt {:.1}° is {gap:+.1}° from PX4's {:.1}° (allowed ±10°); {suggestion}",
            b.peak_tilt_deg,
            p.peak_tilt_deg
        );
    }
    let (b, p) = (builtin.gust, px4.gust);
    for (what, built, real) in [
        ("peak drift speed", b.peak_drift_m_s, p.peak_drift_m_s),
        (
            "drift distance",
            b.peak_displacement_m,
            p.peak_displacement_m,
        ),
    ] {
        let ratio = built / real;
        assert!(
            (0.5..=2.0).contains(&ratio),
            "gust: the built-in's {what} {built:.2} is {ratio:.2}× PX4's {real:.2} (allowed 0.5–2); {suggestion}"
        );
    }
    let (Some(recovery_b), Some(recovery_p)) = (b.recovery_s, p.recovery_s) else {
        panic!("gust: the built-in never recovered: {b:?}; {suggestion}");
    };
    let ratio = recovery_b / recovery_p;
    assert!(
        (0.5..=2.0).contains(&ratio),
        "gust: the built-in's recovery {recovery_b:.2} s is {ratio:.2}× PX4's {recovery_p:.2} s (allowed 0.5–2); {suggestion}"
    );
}
