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

use runtime::energy::MissionModel;
use sim::realism::Realism;
use sim::world::WorldOptions;

use crate::mission::{AutopilotKind, RealAutopilot, SimError, TICK_S};

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

/// Serves the world until the vehicle has landed, `max_time_s` passes or `stop` is set;
/// `on_truth` hears the truth once a second and at the touchdown.
pub fn serve(
    model: &MissionModel,
    options: &ServeOptions,
    stop: &AtomicBool,
    mut on_truth: impl FnMut(&Truth, Option<&ServedTouchdown>),
) -> Result<ServeOutcome, ServeError> {
    let mut served = ServedWorld::build(model, options)?;
    let start = Instant::now();
    let mut tick = 0u64;
    let mut late_ticks = 0u64;
    let mut next_truth_s = 0.0;
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
        let pad = served.world.pad();
        let Some(pose) = served.pose(time_s, &pad, start)? else {
            // PX4 has not spoken yet: nothing to render from.
            tick += 1;
            pace(start, tick);
            continue;
        };
        served.follow_meeting(time_s, &pose, &pad);
        served.render(time_s, &pose, start)?;
        let touchdown = served.step(time_s, start)?;
        let truth = Truth {
            time_s,
            vehicle_ned_m: pose.position_ned_m.into(),
            pad_ned_m: served.world.pad().centre_ned_m.into(),
            tractor_moving: served.world.tractor_moving,
        };
        if touchdown.is_some() && touchdown_seen.is_none() {
            touchdown_seen = touchdown;
            on_truth(&truth, touchdown.as_ref());
        } else if time_s >= next_truth_s {
            on_truth(&truth, None);
            next_truth_s += 1.0;
        }
        motors_stopped_since_s = if served.motors_stopped() {
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
    let (frames_sent, video_latency_ms) = video_stats(&served.video);
    Ok(ServeOutcome {
        vehicle: options.vehicle.describe(),
        touchdown: touchdown_seen,
        landed_on_pad: touchdown_seen.is_some_and(|t| t.on_pad),
        time_s: tick as f64 * TICK_S,
        frames_rendered: served.frames_rendered,
        frames_sent,
        video_latency_ms,
        late_ticks,
        end,
    })
}

mod served;
#[cfg(test)]
mod tests;
mod video;

use served::{pace, ServedWorld};
use video::video_stats;

/// A setup failure, keeping its cause.
impl From<sim::world::WorldError> for ServeError {
    fn from(error: sim::world::WorldError) -> Self {
        setup(error)
    }
}

fn setup(error: impl Into<crate::mission::Cause>) -> ServeError {
    ServeError::Setup(error.into())
}
