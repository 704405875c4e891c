//! `qosrt sim --serve`: the world as its own process, on the wall clock, standing in for PX4
//! SITL + Gazebo. The runtime is another process (`qosrt run`) and sees only what it would see
//! of a real vehicle:
//!
//! - **MAVLink** from the world's autopilot, sent to UDP 127.0.0.1:14540 as PX4 SITL's onboard
//!   link sends (or, with a real autopilot, from that autopilot itself: the world sends none);
//! - **the downward camera** as RTP/H.264 on UDP 5600, as Gazebo's camera plugin streams it
//!   (feature `gstreamer`; without it the world serves MAVLink only).
//!
//! With [`ServeVehicle::Px4Sih`], PX4 SITL's SIH flies the vehicle: the world reads its true
//! pose from the SIH display link and renders the camera, the pad and the field around it.
//! The pad then lies on the ground (SIH's vehicle knows only the ground) and the world judges
//! the touchdown from PX4's pose.
//!
//! With [`ServeVehicle::Px4Hil`] or [`ServeVehicle::ArduPilotJson`] the world is the physics
//! backend of a real autopilot the user started, as Gazebo is: PX4 with
//! `../shared/px4-sitl/start -i N -m none_iris` (HIL on TCP 4560+N, its MAVLink on UDP
//! 14540+N), ArduPilot Copter with `../shared/ardupilot-sitl/start -I N -M JSON:127.0.0.1 -s 100
//! -P FRAME_TYPE=1 -P RNGFND1_TYPE=100 -P BATT_MONITOR=0 -P ANGLE_MAX=4500 -O
//! 47.397742,8.545594,488,0` (JSON on UDP 9002+10N, its MAVLink on TCP 5760+10N: an X frame like
//! the world's body, the rangefinder from the JSON, no battery monitor since the JSON interface
//! has no battery, PX4's 45° tilt limit to hold in 12 m/s, the world's home, and never pacing
//! itself: the world sets the pace). The world steps its rigid body in lockstep with the
//! autopilot, tick by tick on the wall clock, with the pad on the tractor at its real height,
//! the tractor in the scene, the world's wind, and judges the touchdown from the body's contact.
//!
//! The tractor waits at the meeting point and drives off once the vehicle hovers above it
//! (within [`MEET_RADIUS_M`], at least [`MEET_HEIGHT_M`] above the pad, for [`MEET_DWELL_S`]):
//! the world does not know the runtime's phases.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nalgebra::{Vector2, Vector3};
use runtime::energy::MissionModel;
use sim::autopilot::MavlinkAutopilot;
use sim::camera::{SimCamera, VehiclePose};
use sim::power::{RotorPowerModel, SimBattery, SimPack};
use sim::realism::Realism;
use sim::scene::{SimScene, TractorBody};
use sim::tractor::{PadState, TractorParams};
use sim::vehicle::Touchdown;
use sim::vehicle::{Multirotor, VehicleParams};
use sim::world::{World, WorldOptions};

use crate::mission::{
    camera_config, camera_gimbal, flight_power_w, hover_power_w, pad_pose, AutopilotKind,
    CameraGimbal, GimballedVehicle, RealAutopilot, RealVehicle, SimError, PHYSICS_DT_S, TICK_S,
};
use crate::px4_sih::SihListener;

/// The tractor drives off once the vehicle has been this close to the pad, horizontally …
pub const MEET_RADIUS_M: f64 = 1.0;
/// … at least this high above it …
pub const MEET_HEIGHT_M: f64 = 2.0;
/// … for this long.
pub const MEET_DWELL_S: f64 = 2.0;
/// How long the world runs on after the touchdown, for the runtime to see it land and disarm.
pub const AFTER_TOUCHDOWN_S: f64 = 5.0;
/// A real autopilot's clock is the world's: the world runs on until it has stopped the motors
/// for this long, for the runtime to hear it disarmed.
pub const AFTER_DISARM_S: f64 = 2.0;
/// A PX4 vehicle counts as airborne above this height, and as touched down below
/// [`PX4_TOUCHDOWN_HEIGHT_M`].
const PX4_AIRBORNE_HEIGHT_M: f64 = 1.0;
const PX4_TOUCHDOWN_HEIGHT_M: f64 = 0.15;
/// How long the world waits for a real autopilot to connect to it.
pub const REAL_CONNECT_TIMEOUT: Duration = Duration::from_secs(120);

/// Who flies the vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServeVehicle {
    /// The world's own multirotor and PX4-like autopilot.
    Simulated,
    /// PX4 SITL (SIH) instance `instance` in `../shared/px4-sitl` or elsewhere.
    Px4Sih { instance: u8 },
    /// A real PX4 (`none_iris`) instance `instance`, the world its HIL simulator.
    Px4Hil { instance: u8 },
    /// A real ArduPilot Copter instance `instance`, the world its JSON physics backend.
    ArduPilotJson { instance: u8 },
}

impl ServeVehicle {
    /// The real autopilot the world is the physics backend of, if any: started by the user,
    /// waited for up to `connect_timeout`.
    pub fn real_autopilot(self, connect_timeout: Duration) -> Option<RealAutopilot> {
        let (kind, instance) = match self {
            Self::Px4Hil { instance } => (AutopilotKind::Px4, instance),
            Self::ArduPilotJson { instance } => (AutopilotKind::ArduPilot, instance),
            Self::Simulated | Self::Px4Sih { .. } => return None,
        };
        Some(RealAutopilot {
            kind,
            instance,
            command: None,
            connect_timeout,
        })
    }

    /// Who flies, in words.
    pub fn describe(self) -> String {
        match self {
            Self::Simulated => "simulated".into(),
            Self::Px4Sih { instance } => format!("PX4 SITL SIH instance {instance}"),
            Self::Px4Hil { instance } => format!("PX4 SITL HIL instance {instance}"),
            Self::ArduPilotJson { instance } => format!("ArduPilot SITL JSON instance {instance}"),
        }
    }
}

impl std::str::FromStr for ServeVehicle {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let (name, instance) = match text.split_once(':') {
            Some((name, instance)) => (name, Some(instance)),
            None => (text, None),
        };
        let vehicle: fn(u8) -> Self = match name {
            "sim" if instance.is_none() => return Ok(Self::Simulated),
            "px4-sih" => |instance| Self::Px4Sih { instance },
            "px4-hil" => |instance| Self::Px4Hil { instance },
            "ardupilot-json" => |instance| Self::ArduPilotJson { instance },
            _ => {
                return Err(format!(
                    "expected sim, px4-sih, px4-hil or ardupilot-json (each but sim with an \
                     optional :INSTANCE), found {text:?}"
                ))
            }
        };
        match instance {
            None => Ok(vehicle(0)),
            Some(instance) => instance
                .parse::<u8>()
                .ok()
                .filter(|i| *i <= 9)
                .map(vehicle)
                .ok_or_else(|| format!("{name}:{instance}: the instance is 0-9")),
        }
    }
}

/// What the world serves.
#[derive(Debug, Clone, PartialEq)]
pub struct ServeOptions {
    /// The world to serve.
    pub world: WorldOptions,
    pub vehicle: ServeVehicle,
    /// The runtime's MAVLink address (the simulated autopilot sends there).
    pub mavlink_addr: SocketAddr,
    /// The camera's RTP/H.264 stream goes to 127.0.0.1 on this port; `None`: no video.
    pub video_port: Option<u16>,
    /// The world stops after this long.
    pub max_time_s: f64,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            // A scripted driver and a still pad: with a real autopilot the estimator's errors
            // are its own.
            world: WorldOptions {
                realism: Realism::ideal(),
                ..WorldOptions::default()
            },
            vehicle: ServeVehicle::Simulated,
            mavlink_addr: SocketAddr::from(([127, 0, 0, 1], 14540)),
            video_port: Some(5600),
            max_time_s: 600.0,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("world setup: {0}")]
    Setup(#[source] crate::mission::Cause),
    #[error(transparent)]
    Px4Sih(#[from] crate::px4_sih::Px4SihError),
    #[error("simulated autopilot: {0}")]
    Autopilot(#[from] sim::autopilot::AutopilotError),
    #[error("real autopilot: {0}")]
    Real(#[from] SimError),
    #[error(
        "the video stream needs a qosrt built with --features gstreamer (or serve without video)"
    )]
    NoVideo,
    #[cfg(feature = "gstreamer")]
    #[error(transparent)]
    Video(#[from] crate::video_out::VideoError),
}

/// The world's truth at one instant.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Truth {
    pub time_s: f64,
    pub vehicle_ned_m: [f64; 3],
    pub pad_ned_m: [f64; 3],
    pub tractor_moving: bool,
}

/// Where the vehicle came down.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ServedTouchdown {
    pub time_s: f64,
    pub on_pad: bool,
    /// Vehicle centre minus pad centre, horizontally.
    pub horizontal_error_m: f64,
    pub vertical_speed_m_s: f64,
    /// The body's tilt from the vertical at contact.
    pub tilt_deg: f64,
}

/// How the served flight ended.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ServeOutcome {
    pub vehicle: String,
    pub touchdown: Option<ServedTouchdown>,
    pub landed_on_pad: bool,
    pub time_s: f64,
    pub frames_rendered: u64,
    pub frames_sent: u64,
    /// Capture to its RTP packets on the wire (ms), median and 99th percentile.
    pub video_latency_ms: Option<[f64; 2]>,
    /// Ticks that overran their 20 ms (the world fell behind the wall clock).
    pub late_ticks: u64,
    pub end: String,
}

/// The vehicle, as the world moves it or as PX4 reports it.
enum Flyer {
    Simulated {
        vehicle: Box<Multirotor>,
        autopilot: Box<MavlinkAutopilot>,
        battery: SimBattery,
        rotors: RotorPowerModel,
    },
    Px4Sih {
        listener: SihListener,
        airborne: bool,
        previous_down_m: Option<f64>,
        touchdown: Option<ServedTouchdown>,
    },
    /// A real autopilot flying the world's rigid body.
    Real(Box<GimballedVehicle>),
}

/// Serves the world until the vehicle has landed, `max_time_s` passes or `stop` is set;
/// `on_truth` hears the truth once a second and at the touchdown.
pub fn serve(
    model: &MissionModel,
    options: &ServeOptions,
    stop: &AtomicBool,
    mut on_truth: impl FnMut(&Truth, Option<&ServedTouchdown>),
) -> Result<ServeOutcome, ServeError> {
    let sih = matches!(options.vehicle, ServeVehicle::Px4Sih { .. });
    let real = options.vehicle.real_autopilot(REAL_CONNECT_TIMEOUT);
    // SIH's vehicle knows only the ground: its pad lies on it. The world's own vehicle and the
    // real autopilots' rigid body land on the pad where it is, on the tractor.
    let pad_height_m = if sih {
        0.0
    } else {
        TractorParams::default().pad_height_m
    };
    let mut world = World::build(&options.world, pad_height_m)?;
    let mut scene = SimScene::new(options.world.seed);
    if !sih {
        scene = scene
            .with_tractor_body(TractorBody::default())
            .map_err(setup)?;
    }
    let camera_config = camera_config(model);
    let (width_px, height_px, rate_fps) = (
        camera_config.width_px,
        camera_config.height_px,
        camera_config.rate_fps,
    );
    let mut camera = SimCamera::new(camera_config, options.world.seed).map_err(setup)?;
    let gimbal = camera_gimbal(model).map_err(setup)?;
    if sih && gimbal.is_some() {
        // SIH streams PX4's own telemetry: no gimbal reports the camera's attitude.
        return Err(setup(
            "PX4 SIH flies no camera gimbal: set the tracker's camera_mount = \"body\"",
        ));
    }
    let mut video = open_video(options.video_port, width_px, height_px, rate_fps)?;

    let mut flyer = match options.vehicle {
        ServeVehicle::Simulated => {
            let spec = model.battery_spec(None).map_err(setup)?;
            let pack = SimPack::new(
                spec.capacity_mah,
                spec.cell_count,
                spec.internal_resistance_ohm,
            )
            .map_err(setup)?;
            let hover_power_w = hover_power_w(model)
                .ok_or_else(|| ServeError::Setup("[flight] gives no hover_power_w".into()))?;
            let rotors = RotorPowerModel::iris(hover_power_w);
            rotors.validate().map_err(setup)?;
            Flyer::Simulated {
                vehicle: Box::new({
                    let vehicle = Multirotor::on_ground(VehicleParams::default(), Vector3::zeros())
                        .map_err(setup)?;
                    match gimbal {
                        Some(gimbal) => vehicle.with_gimbal(gimbal),
                        None => vehicle,
                    }
                }),
                autopilot: Box::new(MavlinkAutopilot::bind_local(options.mavlink_addr, false)?),
                battery: SimBattery::new(pack),
                rotors,
            }
        }
        ServeVehicle::Px4Sih { instance } => Flyer::Px4Sih {
            listener: SihListener::bind(instance)?,
            airborne: false,
            previous_down_m: None,
            touchdown: None,
        },
        ServeVehicle::Px4Hil { .. } | ServeVehicle::ArduPilotJson { .. } => {
            let real = real.as_ref().expect("a real autopilot");
            // The user started it: no process of ours to keep.
            let (mut vehicle, _no_process) = RealVehicle::connect(real, options.world.seed)?;
            if let RealVehicle::ArduPilot(ardupilot) = &mut vehicle {
                // ArduPilot's first servo packet is its connection: waited for before the
                // world's clock starts, which then does not race to catch up with the wait.
                ardupilot
                    .step(&mut world)
                    .map_err(|error| SimError::Link(error.into()))?;
            }
            // The gimbal reports itself on the vehicle's MAVLink network, as in a mission.
            let gimbal = gimbal
                .map(|gimbal| CameraGimbal::for_autopilot(gimbal, real))
                .transpose()?;
            Flyer::Real(Box::new(GimballedVehicle::new(vehicle, gimbal)))
        }
    };

    let start = Instant::now();
    let mut tick = 0u64;
    let mut late_ticks = 0u64;
    let mut frames_rendered = 0u64;
    let mut next_truth_s = 0.0;
    let mut above_since_s: Option<f64> = None;
    let mut touchdown_seen: Option<ServedTouchdown> = None;
    let mut motors_stopped_since_s: Option<f64> = None;
    let end = loop {
        let time_s = tick as f64 * TICK_S;
        if stop.load(Ordering::SeqCst) {
            break "stopped".to_string();
        }
        if time_s > options.max_time_s {
            break format!("time limit of {:.0} s reached", options.max_time_s);
        }
        let pad = world.pad();
        // The vehicle's pose now, and its commands.
        let pose = match &mut flyer {
            Flyer::Simulated {
                vehicle,
                autopilot,
                battery,
                ..
            } => {
                autopilot.publish(&vehicle.snapshot(time_s, battery.reading()))?;
                apply_commands(vehicle, autopilot, time_s)?;
                // The camera's pose (the gimbal's, where it hangs in one); the same position.
                Some(vehicle.camera_pose())
            }
            Flyer::Px4Sih {
                listener,
                airborne,
                previous_down_m,
                touchdown,
            } => {
                // Stamped at arrival (within the poll), not at the tick.
                listener.poll(start.elapsed().as_secs_f64())?;
                let pose = listener.track.pose_at(time_s);
                if let Some(pose) = &pose {
                    let down_m = pose.position_ned_m.z;
                    *airborne |= -down_m > PX4_AIRBORNE_HEIGHT_M;
                    if let (true, None, Some(previous)) = (*airborne, *touchdown, *previous_down_m)
                    {
                        if previous < -PX4_TOUCHDOWN_HEIGHT_M && down_m >= -PX4_TOUCHDOWN_HEIGHT_M {
                            *touchdown = Some(judge(time_s, pose, &pad));
                        }
                    }
                    *previous_down_m = Some(down_m);
                }
                pose
            }
            // The body's camera; its commands reach the autopilot, not the world.
            Flyer::Real(real) => Some(real.camera_pose()),
        };
        let Some(pose) = pose else {
            // PX4 has not spoken yet: nothing to render from.
            tick += 1;
            pace(start, tick);
            continue;
        };

        // The tractor drives off once the vehicle is with it.
        let relative = pose.position_ned_m - pad.centre_ned_m;
        let above = relative.xy().norm() <= MEET_RADIUS_M && -relative.z >= MEET_HEIGHT_M;
        above_since_s = if above {
            above_since_s.or(Some(time_s))
        } else {
            None
        };
        world.tractor_moving |=
            above_since_s.is_some_and(|since_s| time_s - since_s >= MEET_DWELL_S);

        if camera.is_due(time_s) {
            scene
                .set_pad_pose(pad_pose(&world.tractor))
                .map_err(setup)?;
            match camera.capture_frame(time_s, &pose, &scene) {
                Ok(frame) => {
                    frames_rendered += 1;
                    // Captured at the tick's instant on the wall clock, however late the
                    // world runs.
                    let captured = start + Duration::from_secs_f64(time_s);
                    send_frame(&mut video, &frame.image, captured.elapsed())?;
                }
                Err(error) => eprintln!("camera: {error}"),
            }
        }

        // Physics: the world's one step (the tractor, the wind, the body), to the tick's end.
        let substeps = (TICK_S / PHYSICS_DT_S).round() as usize;
        match &mut flyer {
            Flyer::Simulated {
                vehicle, autopilot, ..
            } => {
                // A real autopilot acts on a setpoint as it arrives, not on the next 50 Hz tick.
                world.step_tick(
                    time_s,
                    TICK_S,
                    PHYSICS_DT_S,
                    vehicle.as_mut(),
                    |t_s, vehicle| {
                        pace_to(start, t_s);
                        apply_commands(vehicle, autopilot, t_s)
                    },
                )?
            }
            // SIH moves its own vehicle: the world moves only the tractor.
            Flyer::Px4Sih { .. } => {
                if world.tractor_moving {
                    for _ in 0..substeps {
                        world.tractor.step(PHYSICS_DT_S).map_err(setup)?;
                    }
                }
            }
            // In lockstep with the autopilot: its steps up to the tick's end.
            Flyer::Real(real) => real.step_until(&mut world, time_s + TICK_S, TICK_S)?,
        }
        let touchdown = match &mut flyer {
            Flyer::Simulated {
                vehicle,
                battery,
                rotors,
                ..
            } => {
                let flight_w = flight_power_w(vehicle.as_ref(), &mut world.wind, rotors, time_s);
                // The companion computer's draw is the runtime's to report, not the world's.
                battery.drain(flight_w, 0.0, TICK_S).map_err(setup)?;
                vehicle.touchdown().map(ServedTouchdown::from)
            }
            Flyer::Px4Sih { touchdown, .. } => *touchdown,
            // The body's real contact with the pad or the ground.
            Flyer::Real(real) => real.vehicle.body().touchdown().map(ServedTouchdown::from),
        };
        let truth = Truth {
            time_s,
            vehicle_ned_m: pose.position_ned_m.into(),
            pad_ned_m: world.pad().centre_ned_m.into(),
            tractor_moving: world.tractor_moving,
        };
        if touchdown.is_some() && touchdown_seen.is_none() {
            touchdown_seen = touchdown;
            on_truth(&truth, touchdown.as_ref());
        } else if time_s >= next_truth_s {
            on_truth(&truth, None);
            next_truth_s += 1.0;
        }
        // The world's own vehicle needs no world to disarm; a real autopilot does.
        let motors_stopped = match &flyer {
            Flyer::Real(real) => !motors_running(&real.vehicle),
            Flyer::Simulated { .. } | Flyer::Px4Sih { .. } => true,
        };
        motors_stopped_since_s = if motors_stopped {
            motors_stopped_since_s.or(Some(time_s))
        } else {
            None
        };
        if let Some(landed) = touchdown_seen {
            if time_s - landed.time_s >= AFTER_TOUCHDOWN_S
                && motors_stopped_since_s.is_some_and(|since_s| time_s - since_s >= AFTER_DISARM_S)
            {
                break "landed".to_string();
            }
        }
        tick += 1;
        if Instant::now() > start + Duration::from_secs_f64(tick as f64 * TICK_S) {
            late_ticks += 1;
        }
        pace(start, tick);
    };
    let (frames_sent, video_latency_ms) = video_stats(&video);
    Ok(ServeOutcome {
        vehicle: options.vehicle.describe(),
        touchdown: touchdown_seen,
        landed_on_pad: touchdown_seen.is_some_and(|t| t.on_pad),
        time_s: tick as f64 * TICK_S,
        frames_rendered,
        frames_sent,
        video_latency_ms,
        late_ticks,
        end,
    })
}

/// Whether the real autopilot drives its motors (PX4: armed; ArduPilot: any motor spinning,
/// all its servo outputs tell).
fn motors_running(real: &RealVehicle) -> bool {
    match real {
        RealVehicle::Px4(px4) => px4.last_commands.as_ref().is_some_and(|c| c.armed),
        RealVehicle::ArduPilot(ardupilot) => ardupilot.motors_spinning(),
    }
}

impl From<Touchdown> for ServedTouchdown {
    fn from(t: Touchdown) -> Self {
        Self {
            time_s: t.time_s,
            on_pad: t.on_pad,
            horizontal_error_m: t.horizontal_error_m,
            vertical_speed_m_s: t.vertical_speed_m_s,
            tilt_deg: t.tilt_deg,
        }
    }
}

/// A touchdown on the ground under PX4's vehicle, against the pad lying there.
fn judge(time_s: f64, pose: &VehiclePose, pad: &PadState) -> ServedTouchdown {
    let offset: Vector2<f64> = pad.to_pad_frame(pose.position_ned_m.xy());
    ServedTouchdown {
        time_s,
        on_pad: pad.contains_ne(pose.position_ned_m.xy()),
        horizontal_error_m: offset.norm(),
        vertical_speed_m_s: pose.velocity_ned_m_s.z,
        tilt_deg: pose.attitude.tilt_rad().to_degrees(),
    }
}

/// Sleeps until tick `tick` is due on the wall clock.
fn pace(start: Instant, tick: u64) {
    pace_to(start, tick as f64 * TICK_S);
}

/// Sleeps until world time `time_s` is due on the wall clock.
fn pace_to(start: Instant, time_s: f64) {
    let due = start + Duration::from_secs_f64(time_s);
    std::thread::sleep(due.saturating_duration_since(Instant::now()));
}

/// The runtime's commands that have arrived, applied and acknowledged.
fn apply_commands(
    vehicle: &mut Multirotor,
    autopilot: &mut MavlinkAutopilot,
    time_s: f64,
) -> Result<(), ServeError> {
    for received in autopilot.receive()? {
        let result = vehicle.command(received.command, time_s);
        if let Some(pending) = received.ack {
            autopilot.ack(pending, &result)?;
        }
    }
    Ok(())
}

#[cfg(feature = "gstreamer")]
type Video = Option<crate::video_out::RtpH264Sender>;
/// Without GStreamer the world has no video stream to feed.
#[cfg(not(feature = "gstreamer"))]
struct Video;

#[cfg(feature = "gstreamer")]
fn open_video(
    port: Option<u16>,
    width_px: usize,
    height_px: usize,
    rate_fps: f64,
) -> Result<Video, ServeError> {
    use crate::video_out::{RtpH264Sender, VideoStreamConfig};
    port.map(|port| {
        RtpH264Sender::open(VideoStreamConfig::new(port, width_px, height_px, rate_fps))
            .map_err(ServeError::from)
    })
    .transpose()
}

#[cfg(not(feature = "gstreamer"))]
fn open_video(
    port: Option<u16>,
    _width_px: usize,
    _height_px: usize,
    _rate_fps: f64,
) -> Result<Video, ServeError> {
    match port {
        Some(_) => Err(ServeError::NoVideo),
        None => Ok(Video),
    }
}

#[cfg(feature = "gstreamer")]
fn send_frame(
    video: &mut Video,
    image: &algorithms::vision::image::GrayImage,
    age: Duration,
) -> Result<(), ServeError> {
    if let Some(video) = video {
        video.send(image, age)?;
    }
    Ok(())
}

#[cfg(not(feature = "gstreamer"))]
fn send_frame(
    _video: &mut Video,
    _image: &algorithms::vision::image::GrayImage,
    _age: Duration,
) -> Result<(), ServeError> {
    Ok(())
}

#[cfg(feature = "gstreamer")]
fn video_stats(video: &Video) -> (u64, Option<[f64; 2]>) {
    video.as_ref().map_or((0, None), |video| {
        (
            video.frames_sent(),
            video.latency_ms().map(|(p50, p99)| [p50, p99]),
        )
    })
}

#[cfg(not(feature = "gstreamer"))]
fn video_stats(_video: &Video) -> (u64, Option<[f64; 2]>) {
    (0, None)
}

#[cfg(test)]
mod tests;

/// A setup failure, keeping its cause.
impl From<sim::world::WorldError> for ServeError {
    fn from(error: sim::world::WorldError) -> Self {
        setup(error)
    }
}

fn setup(error: impl Into<crate::mission::Cause>) -> ServeError {
    ServeError::Setup(error.into())
}
