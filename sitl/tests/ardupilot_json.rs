//! The real ArduPilot (Copter 4.6.3 SITL, `-M JSON:127.0.0.1`: no physics of its own) flying
//! the world's rigid-body quadrotor over its JSON interface: its EKF3 estimates from the
//! world's IMU, position and rangefinder, its controllers fly the world's body in the world's
//! wind, as fast as both sides answer. The camera's gimbal, wired to ArduPilot's SERIAL2,
//! reaches the ground station on SERIAL0 through ArduPilot's MAVLink routing. Skips, saying
//! why, without `../shared/ardupilot-sitl`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use algorithms::estimation::projection::Attitude;
use mavlink::dialects::common::{
    MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavResult, MavType, HEARTBEAT_DATA,
};
use mavlink::{MavConnection, MavHeader};
use nalgebra::Vector3;
use sim::quadrotor::{Quadrotor, QuadrotorParams};
use sim::sensors::{Home, SensorParams, Sensors};
use sim::tractor::{PathKind, Tractor, TractorParams};
use sim::vehicle::Touchdown;
use sim::wind::{Wind, WindConfig};
use sim::world::World;
use sitl::hil::ardupilot_json::{ArduPilotJson, ArduPilotVehicle};
use sitl::hil::gimbal_device::GimbalDevice;

mod common;
use common::{command_long, shared_dir, start, SitlProcess};

/// Ports 5800 (MAVLink), 14590, 9042 (JSON): no other test's (ArduPilot 1 and 2, PX4 0–9).
const INSTANCE: u8 = 4;
const TAKEOFF_ALTITUDE_M: f64 = 5.0;
const GUIDED: f32 = 4.0;
const LAND: f32 = 9.0;
/// The world's trace of the true position, every 50 ms of simulated time.
const TRACE_PERIOD_S: f64 = 0.05;

/// Where the gimbal holds the camera: straight down, rolled 3° and turned to 40°, so that a
/// quaternion that arrives unchanged is told from a default one.
fn gimbal_camera() -> Attitude {
    Attitude::new(3f64.to_radians(), -90f64.to_radians(), 40f64.to_radians())
}

fn start_ardupilot() -> Option<SitlProcess> {
    let dir = shared_dir("ardupilot-sitl")?;
    let home = Home::default();
    let home = format!(
        "{},{},{},0",
        home.latitude_deg, home.longitude_deg, home.altitude_m
    );
    let instance = INSTANCE.to_string();
    let args = [
        "-I",
        &instance,
        "-M",
        "JSON:127.0.0.1",
        // Its pacing: sleep only to keep the simulated clock at 100× the wall clock, i.e.
        // never here: the world and ArduPilot run as fast as they answer each other.
        "-s",
        "100",
        // The bundled copter.parm flies a quad "+" (FRAME_TYPE 0); the world's body is the
        // quad X whose rotor order the servo channels follow.
        "-P",
        "FRAME_TYPE=1",
        // Read the world's downward rangefinder (`rng_1`) as rangefinder 1.
        "-P",
        "RNGFND1_TYPE=100",
        // ArduPilot's home is the world's (sim::sensors::Home), not SITL's default in Canberra.
        "-O",
        &home,
    ];
    Some(start(&dir, &args, &[]))
}

/// What the world thread shares: the truth ArduPilot does not see.
#[derive(Debug, Default, Clone)]
struct Truth {
    time_s: f64,
    position_ned_m: Vector3<f64>,
    touchdowns: Vec<Touchdown>,
    frames: u64,
    resends: u64,
    frame_rate_hz: u16,
    motors_spinning: bool,
    trace: Vec<(f64, Vector3<f64>)>,
    error: Option<String>,
}

/// The world ArduPilot flies in: 8 m/s gusts from the east (they push the body west), the
/// tractor parked with its pad far away, so only the ground is under the body.
fn world() -> World {
    let tractor = Tractor::new(
        PathKind::Straight,
        TractorParams::default(),
        [1_000.0, 1_000.0],
        0.0,
    )
    .unwrap()
    .parked();
    let wind = Wind::new(
        WindConfig::Gusts {
            speed_m_s: 8.0,
            direction_from_rad: std::f64::consts::FRAC_PI_2,
        },
        11,
    )
    .unwrap();
    World::new(tractor, wind)
}

/// The lockstep loop, one [`ArduPilotVehicle::step`] per servo frame, recording the truth.
fn run_world(json: ArduPilotJson, truth: Arc<Mutex<Truth>>, stop: Arc<AtomicBool>) -> f64 {
    let mut world = world();
    let body = Quadrotor::on_ground(QuadrotorParams::default(), Vector3::zeros()).unwrap();
    let sensors = Sensors::new(SensorParams::default(), Home::default(), 11);
    let mut vehicle = ArduPilotVehicle::new(json, body, sensors);
    let serial2 = std::net::SocketAddr::from(([127, 0, 0, 1], 5763 + 10 * u16::from(INSTANCE)));
    let mut gimbal = GimbalDevice::through_autopilot(serial2, 1);
    let wall = Instant::now();
    let mut next_trace_s = 0.0;
    while !stop.load(Ordering::Relaxed) {
        if let Err(error) = vehicle.step(&mut world) {
            truth.lock().unwrap().error = Some(error.to_string());
            break;
        }
        let time_boot_ms = (vehicle.time_s * 1000.0) as u32;
        if let Err(error) = gimbal.report(vehicle.time_s, time_boot_ms, &gimbal_camera()) {
            truth.lock().unwrap().error = Some(format!("gimbal: {error}"));
            break;
        }
        let mut t = truth.lock().unwrap();
        t.time_s = vehicle.time_s;
        t.position_ned_m = vehicle.body.position_ned_m();
        t.frames = vehicle.frames;
        t.resends = vehicle.resends;
        t.motors_spinning = vehicle.motors_spinning();
        if let Some(packet) = &vehicle.last_servos {
            t.frame_rate_hz = packet.frame_rate_hz;
        }
        if vehicle.body.touchdowns().len() != t.touchdowns.len() {
            t.touchdowns = vehicle.body.touchdowns().to_vec();
        }
        if vehicle.time_s >= next_trace_s {
            let sample = (vehicle.time_s, t.position_ned_m);
            t.trace.push(sample);
            next_trace_s += TRACE_PERIOD_S;
        }
    }
    vehicle.time_s / wall.elapsed().as_secs_f64()
}

/// A ground station on ArduPilot's first MAVLink server.
struct Gcs {
    link: mavlink::Connection<MavMessage>,
    acks: Vec<(MavCmd, MavResult)>,
    texts: Vec<String>,
    armed: bool,
    custom_mode: u32,
    /// The last DISTANCE_SENSOR: what ArduPilot read from `rng_1`, m.
    rangefinder_m: Option<f64>,
    /// GIMBAL_DEVICE_ATTITUDE_STATUS from the vehicle's gimbal (system 1, component 154),
    /// forwarded by ArduPilot, and the last one's quaternion.
    gimbal_reports: u32,
    gimbal_q: Option<[f32; 4]>,
}

impl Gcs {
    fn connect(port: u16) -> Self {
        let link = mavlink::connect::<MavMessage>(&format!("tcpout:127.0.0.1:{port}"))
            .expect("ArduPilot's MAVLink TCP server accepts");
        Self {
            link,
            acks: Vec::new(),
            texts: Vec::new(),
            armed: false,
            custom_mode: 0,
            rangefinder_m: None,
            gimbal_reports: 0,
            gimbal_q: None,
        }
    }

    /// A companion computer's heartbeat: ArduPilot routes the vehicle's broadcasts (the
    /// gimbal's reports among them) only to links it has heard a component on.
    fn heartbeat(&self) {
        let heartbeat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            ..Default::default()
        });
        let header = MavHeader {
            system_id: 1,
            component_id: 191,
            sequence: 0,
        };
        self.link.send(&header, &heartbeat).expect("MAVLink send");
    }

    fn command(&self, command: MavCmd, params: [f32; 7]) {
        let message = command_long(1, command, params);
        let header = MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: 0,
        };
        self.link.send(&header, &message).expect("MAVLink send");
    }

    fn set_mode(&self, mode: f32) {
        // p1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, p2 = ArduCopter's mode number.
        self.command(
            MavCmd::MAV_CMD_DO_SET_MODE,
            [1.0, mode, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
    }

    /// Reads what ArduPilot sends for `wall` (the link's reads time out every 100 ms).
    fn pump(&mut self, wall: Duration) {
        self.heartbeat();
        let until = Instant::now() + wall;
        while Instant::now() < until {
            match self.link.recv() {
                Ok((_, MavMessage::COMMAND_ACK(ack))) => self.acks.push((ack.command, ack.result)),
                Ok((_, MavMessage::STATUSTEXT(text))) => {
                    let text = String::from_utf8_lossy(&text.text.to_vec())
                        .trim_end_matches('\0')
                        .to_string();
                    self.texts.push(text);
                }
                Ok((header, MavMessage::HEARTBEAT(heartbeat))) if header.component_id == 1 => {
                    self.armed = heartbeat
                        .base_mode
                        .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
                    self.custom_mode = heartbeat.custom_mode;
                }
                Ok((_, MavMessage::DISTANCE_SENSOR(distance))) => {
                    self.rangefinder_m = Some(f64::from(distance.current_distance) / 100.0);
                }
                Ok((header, MavMessage::GIMBAL_DEVICE_ATTITUDE_STATUS(status)))
                    if header.system_id == 1 && header.component_id == 154 =>
                {
                    self.gimbal_reports += 1;
                    self.gimbal_q = Some(status.q);
                }
                Ok(_) => {}
                Err(_) => {}
            }
        }
    }

    fn accepted(&mut self, command: MavCmd) -> bool {
        let accepted = self
            .acks
            .contains(&(command, MavResult::MAV_RESULT_ACCEPTED));
        self.acks.retain(|(c, _)| *c != command);
        accepted
    }

    fn last_texts(&self) -> &[String] {
        &self.texts[self.texts.len().saturating_sub(8)..]
    }
}

#[test]
fn ardupilot_takes_off_holds_in_8_m_s_gusts_and_lands_in_our_world() {
    // Listen before ArduPilot starts: its first servo packets find the world there.
    let backend = ArduPilotJson::bind(INSTANCE).unwrap();
    let Some(_ardupilot) = start_ardupilot() else {
        return;
    };
    let wall = Instant::now();
    let deadline = wall + Duration::from_secs(90);
    let truth = Arc::new(Mutex::new(Truth::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let world = {
        let (truth, stop) = (truth.clone(), stop.clone());
        std::thread::spawn(move || run_world(backend, truth, stop))
    };
    let snapshot = || {
        let t = truth.lock().unwrap().clone();
        assert!(t.error.is_none(), "the world stopped: {t:?}");
        t
    };
    let mut gcs = Gcs::connect(5760 + 10 * u16::from(INSTANCE));

    // GUIDED and arm: refused until EKF3 has a position (GPS), then accepted.
    loop {
        assert!(
            Instant::now() < deadline,
            "never armed by t = {:.1} s: {:?}",
            snapshot().time_s,
            gcs.last_texts()
        );
        gcs.set_mode(GUIDED);
        gcs.command(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        );
        gcs.pump(Duration::from_millis(300));
        if gcs.accepted(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM) {
            break;
        }
    }
    let armed_at_s = snapshot().time_s;
    // ArduPilot streams nothing until asked: its rangefinder reading at 5 Hz. (Asked at boot,
    // the request is accepted and then forgotten when its streams start.)
    gcs.command(
        MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        [132.0, 200_000.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    );
    let wall_at_arm_s = wall.elapsed().as_secs_f64();
    // Take off within ArduPilot's 10 s, or it disarms.
    loop {
        assert!(
            Instant::now() < deadline,
            "NAV_TAKEOFF refused: {:?}",
            gcs.last_texts()
        );
        gcs.command(
            MavCmd::MAV_CMD_NAV_TAKEOFF,
            [
                0.0,
                0.0,
                0.0,
                f32::NAN,
                f32::NAN,
                f32::NAN,
                TAKEOFF_ALTITUDE_M as f32,
            ],
        );
        gcs.pump(Duration::from_millis(200));
        if gcs.accepted(MavCmd::MAV_CMD_NAV_TAKEOFF) {
            break;
        }
    }
    let takeoff_at_s = snapshot().time_s;

    // Up, settled, then a 5 s hold in the wind, judged on the world's true position.
    let mut reached_at_s = None;
    let hold_from_s = loop {
        assert!(
            Instant::now() < deadline,
            "no hover at 5 m: {:?}, {:?}",
            snapshot().position_ned_m,
            gcs.last_texts()
        );
        gcs.pump(Duration::from_millis(50));
        let t = snapshot();
        if reached_at_s.is_none() && (-t.position_ned_m.z - TAKEOFF_ALTITUDE_M).abs() < 0.5 {
            reached_at_s = Some(t.time_s);
        }
        if let Some(reached) = reached_at_s {
            if t.time_s >= reached + 3.0 {
                break t.time_s;
            }
        }
    };
    let mut rangefinder_at_hover_m = None;
    // The world's reading of the servo outputs: the motors turn all through the hold.
    let mut motors_still_in_hold = 0;
    while snapshot().time_s < hold_from_s + 5.0 {
        assert!(Instant::now() < deadline, "the hold never ended");
        gcs.pump(Duration::from_millis(50));
        rangefinder_at_hover_m = gcs.rangefinder_m.or(rangefinder_at_hover_m);
        motors_still_in_hold += u32::from(!snapshot().motors_spinning);
    }
    let hold: Vec<Vector3<f64>> = snapshot()
        .trace
        .iter()
        .filter(|(t, _)| (hold_from_s..=hold_from_s + 5.0).contains(t))
        .map(|(_, p)| *p)
        .collect();
    assert!(hold.len() > 50, "{} samples in the hold", hold.len());
    let start = hold[0];
    let worst_horizontal_m = hold
        .iter()
        .map(|p| (p - start).xy().norm())
        .fold(0.0, f64::max);
    let worst_altitude_error_m = hold
        .iter()
        .map(|p| (-p.z - TAKEOFF_ALTITUDE_M).abs())
        .fold(0.0, f64::max);
    let mean = hold.iter().sum::<Vector3<f64>>() / hold.len() as f64;

    // LAND: ArduPilot's descent onto the world's ground.
    let touchdowns_before = snapshot().touchdowns.len();
    loop {
        assert!(
            Instant::now() < deadline,
            "LAND refused: {:?}",
            gcs.last_texts()
        );
        gcs.set_mode(LAND);
        gcs.pump(Duration::from_millis(200));
        if gcs.accepted(MavCmd::MAV_CMD_DO_SET_MODE) {
            break;
        }
    }
    let land_at_s = snapshot().time_s;
    let touchdown = loop {
        assert!(
            Instant::now() < deadline,
            "never touched down: {:?}, {:?}",
            snapshot().position_ned_m,
            gcs.last_texts()
        );
        gcs.pump(Duration::from_millis(50));
        if let Some(touchdown) = snapshot().touchdowns.get(touchdowns_before) {
            break *touchdown;
        }
    };
    // ArduPilot's land detector disarms it once it is sure it is down.
    while gcs.armed && Instant::now() < deadline {
        gcs.pump(Duration::from_millis(100));
    }
    let disarmed_at_s = snapshot().time_s;
    // Disarmed, ArduPilot drives its motors at the still 1000 µs.
    gcs.pump(Duration::from_millis(100));
    let motors_spinning_after_disarm = snapshot().motors_spinning;
    stop.store(true, Ordering::Relaxed);
    let t = snapshot();
    let real_time_factor = world.join().unwrap();

    eprintln!(
        "ArduPilot over JSON at {} Hz: {} frames, {} resends, {:.1}× real time ({:.1} s of flight in {:.1} s)",
        t.frame_rate_hz,
        t.frames,
        t.resends,
        real_time_factor,
        t.time_s,
        wall.elapsed().as_secs_f64()
    );
    eprintln!(
        "armed at t = {armed_at_s:.1} s ({wall_at_arm_s:.1} s wall); take-off at {takeoff_at_s:.1} s, at 5 m ± 0.5 by {:.1} s",
        reached_at_s.unwrap_or(f64::NAN)
    );
    eprintln!(
        "hold over 5 s: mean altitude {:.2} m, worst altitude error {worst_altitude_error_m:.2} m, worst horizontal excursion {worst_horizontal_m:.2} m, {:.2} m from the take-off point; ArduPilot's rangefinder {rangefinder_at_hover_m:?} m",
        -mean.z,
        mean.xy().norm()
    );
    eprintln!(
        "LAND at {land_at_s:.1} s: touchdown at {:.1} s at {:.2} m/s down, {:.2} m/s across, tilt {:.1}°; disarmed by {disarmed_at_s:.1} s",
        touchdown.time_s,
        touchdown.vertical_speed_m_s,
        touchdown.relative_horizontal_speed_m_s,
        touchdown.tilt_deg
    );
    assert!(worst_altitude_error_m < 1.0, "{worst_altitude_error_m}");
    assert!(worst_horizontal_m < 1.0, "{worst_horizontal_m}");
    if let Some(range) = rangefinder_at_hover_m {
        assert!(
            (range - TAKEOFF_ALTITUDE_M).abs() < 1.0,
            "rangefinder {range} m"
        );
    }
    assert!(touchdown.vertical_speed_m_s < 1.5, "{touchdown:?}");
    assert_eq!(
        motors_still_in_hold, 0,
        "snapshots of still motors in the hold"
    );
    assert!(
        !gcs.armed,
        "still armed {:.1} s after touchdown",
        disarmed_at_s - touchdown.time_s
    );
    assert!(!motors_spinning_after_disarm, "motors turning after disarm");
    // The gimbal's own reports, through ArduPilot, unchanged.
    let MavMessage::GIMBAL_DEVICE_ATTITUDE_STATUS(sent) =
        sim::autopilot::gimbal_device_attitude_status(&gimbal_camera(), 0)
    else {
        unreachable!()
    };
    eprintln!(
        "{} gimbal reports forwarded from SERIAL2 to SERIAL0",
        gcs.gimbal_reports
    );
    assert!(
        gcs.gimbal_reports > 100,
        "{} gimbal reports",
        gcs.gimbal_reports
    );
    assert_eq!(gcs.gimbal_q, Some(sent.q));
}
