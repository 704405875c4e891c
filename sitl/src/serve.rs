//! `qosrt sim --serve`: the world as its own process, on the wall clock, standing in for PX4
//! SITL + Gazebo. The runtime is another process (`qosrt run`) and sees only what it would see
//! of a real vehicle:
//!
//! - **MAVLink** from the world's autopilot, sent to UDP 127.0.0.1:14540 as PX4 SITL's onboard
//!   link sends (or, with [`ServeVehicle::Px4Sih`], from the real PX4 itself);
//! - **the downward camera** as RTP/H.264 on UDP 5600, as Gazebo's camera plugin streams it
//!   (feature `gstreamer`; without it the world serves MAVLink only).
//!
//! With [`ServeVehicle::Px4Sih`], PX4 SITL's SIH flies the vehicle: the world reads its true
//! pose from the SIH display link and renders the camera, the pad and the field around it.
//! The pad then lies on the ground (SIH's vehicle knows only the ground) and the world judges
//! the touchdown from PX4's pose.
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
use sim::scene::{SimScene, TractorBody};
use sim::tractor::{PadState, PathKind, Tractor, TractorParams};
use sim::vehicle::{Multirotor, VehicleParams};
use sim::wind::Wind;

use crate::mission::{
    camera_config, camera_gimbal, flight_power_w, hover_power_w, pad_pose, wind_config, WindKind,
    PHYSICS_DT_S, TICK_S,
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
/// A PX4 vehicle counts as airborne above this height, and as touched down below
/// [`PX4_TOUCHDOWN_HEIGHT_M`].
const PX4_AIRBORNE_HEIGHT_M: f64 = 1.0;
const PX4_TOUCHDOWN_HEIGHT_M: f64 = 0.15;

/// Who flies the vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServeVehicle {
    /// The world's own multirotor and PX4-like autopilot.
    Simulated,
    /// PX4 SITL (SIH) instance `instance` in `../shared/px4-sitl` or elsewhere.
    Px4Sih { instance: u8 },
}

impl std::str::FromStr for ServeVehicle {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        match text.split_once(':') {
            None if text == "sim" => Ok(Self::Simulated),
            None if text == "px4-sih" => Ok(Self::Px4Sih { instance: 0 }),
            Some(("px4-sih", instance)) => instance
                .parse::<u8>()
                .ok()
                .filter(|i| *i <= 9)
                .map(|instance| Self::Px4Sih { instance })
                .ok_or_else(|| format!("px4-sih:{instance}: the instance is 0-9")),
            _ => Err(format!(
                "expected sim, px4-sih or px4-sih:INSTANCE, found {text:?}"
            )),
        }
    }
}

/// What the world serves.
#[derive(Debug, Clone, PartialEq)]
pub struct ServeOptions {
    pub path: PathKind,
    pub wind_speed_m_s: f64,
    pub wind_kind: WindKind,
    pub platform_speed_m_s: f64,
    pub seed: u64,
    pub meeting_point_ne_m: [f64; 2],
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
            path: PathKind::Straight,
            wind_speed_m_s: 0.0,
            wind_kind: WindKind::Gusts,
            platform_speed_m_s: 1.5,
            seed: 0,
            meeting_point_ne_m: [15.0, 0.0],
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
        wind: Box<Wind>,
        battery: SimBattery,
        rotors: RotorPowerModel,
    },
    Px4 {
        listener: SihListener,
        airborne: bool,
        previous_down_m: Option<f64>,
        touchdown: Option<ServedTouchdown>,
    },
}

/// Serves the world until the vehicle has landed, `max_time_s` passes or `stop` is set;
/// `on_truth` hears the truth once a second and at the touchdown.
pub fn serve(
    model: &MissionModel,
    options: &ServeOptions,
    stop: &AtomicBool,
    mut on_truth: impl FnMut(&Truth, Option<&ServedTouchdown>),
) -> Result<ServeOutcome, ServeError> {
    let px4 = matches!(options.vehicle, ServeVehicle::Px4Sih { .. });
    // SIH's vehicle knows only the ground: its pad lies on it.
    let tractor_params = TractorParams {
        speed_m_s: options.platform_speed_m_s,
        pad_height_m: if px4 {
            0.0
        } else {
            TractorParams::default().pad_height_m
        },
        ..TractorParams::default()
    };
    let mut tractor = Tractor::new(
        options.path,
        tractor_params,
        options.meeting_point_ne_m,
        0.0,
    )
    .map_err(setup)?
    .parked();
    let mut scene = SimScene::new(options.seed);
    if !px4 {
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
    let mut camera = SimCamera::new(camera_config, options.seed).map_err(setup)?;
    let gimbal = camera_gimbal(model).map_err(setup)?;
    if px4 && gimbal.is_some() {
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
                wind: Box::new(
                    Wind::new(
                        wind_config(options.wind_speed_m_s, options.wind_kind),
                        options.seed ^ 0x5749_4e44,
                    )
                    .map_err(setup)?,
                ),
                battery: SimBattery::new(pack),
                rotors,
            }
        }
        ServeVehicle::Px4Sih { instance } => Flyer::Px4 {
            listener: SihListener::bind(instance)?,
            airborne: false,
            previous_down_m: None,
            touchdown: None,
        },
    };

    let start = Instant::now();
    let mut tick = 0u64;
    let mut late_ticks = 0u64;
    let mut frames_rendered = 0u64;
    let mut next_truth_s = 0.0;
    let mut tractor_moving = false;
    let mut above_since_s: Option<f64> = None;
    let mut touchdown_seen: Option<ServedTouchdown> = None;
    let end = loop {
        let time_s = tick as f64 * TICK_S;
        if stop.load(Ordering::SeqCst) {
            break "stopped".to_string();
        }
        if time_s > options.max_time_s {
            break format!("time limit of {:.0} s reached", options.max_time_s);
        }
        let pad = tractor.pad();
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
            Flyer::Px4 {
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
        tractor_moving |= above_since_s.is_some_and(|since_s| time_s - since_s >= MEET_DWELL_S);

        if camera.is_due(time_s) {
            scene.set_pad_pose(pad_pose(&tractor)).map_err(setup)?;
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

        // Physics (the simulated vehicle), the tractor, the touchdown.
        for substep in 0..(TICK_S / PHYSICS_DT_S).round() as usize {
            let t_s = time_s + substep as f64 * PHYSICS_DT_S;
            if tractor_moving {
                tractor.step(PHYSICS_DT_S).map_err(setup)?;
            }
            if let Flyer::Simulated {
                vehicle,
                wind,
                autopilot,
                ..
            } = &mut flyer
            {
                // A real autopilot acts on a setpoint as it arrives, not on the next 50 Hz tick.
                if substep > 0 {
                    pace_to(start, t_s);
                    apply_commands(vehicle, autopilot, t_s)?;
                }
                let position = vehicle.position_ned_m();
                let force = wind.force_ned_n(t_s, -position.z, vehicle.velocity_ned_m_s());
                vehicle
                    .step(PHYSICS_DT_S, t_s + PHYSICS_DT_S, force, &tractor.pad())
                    .map_err(setup)?;
            }
        }
        let touchdown = match &mut flyer {
            Flyer::Simulated {
                vehicle,
                wind,
                battery,
                rotors,
                ..
            } => {
                let flight_w = flight_power_w(vehicle.as_ref(), wind, rotors, time_s);
                // The companion computer's draw is the runtime's to report, not the world's.
                battery.drain(flight_w, 0.0, TICK_S).map_err(setup)?;
                vehicle.touchdown().map(|t| ServedTouchdown {
                    time_s: t.time_s,
                    on_pad: t.on_pad,
                    horizontal_error_m: t.horizontal_error_m,
                    vertical_speed_m_s: t.vertical_speed_m_s,
                    tilt_deg: t.tilt_deg,
                })
            }
            Flyer::Px4 { touchdown, .. } => *touchdown,
        };
        let truth = Truth {
            time_s,
            vehicle_ned_m: pose.position_ned_m.into(),
            pad_ned_m: tractor.pad().centre_ned_m.into(),
            tractor_moving,
        };
        if touchdown.is_some() && touchdown_seen.is_none() {
            touchdown_seen = touchdown;
            on_truth(&truth, touchdown.as_ref());
        } else if time_s >= next_truth_s {
            on_truth(&truth, None);
            next_truth_s += 1.0;
        }
        if let Some(landed) = touchdown_seen {
            if time_s - landed.time_s >= AFTER_TOUCHDOWN_S {
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
        vehicle: match options.vehicle {
            ServeVehicle::Simulated => "simulated".into(),
            ServeVehicle::Px4Sih { instance } => format!("PX4 SITL SIH instance {instance}"),
        },
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
fn setup(error: impl Into<crate::mission::Cause>) -> ServeError {
    ServeError::Setup(error.into())
}
