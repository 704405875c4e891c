//! ArduPilot's JSON physics interface (`-M JSON:127.0.0.1`, its `SIM_JSON` backend), served by
//! the world as Gazebo's `ardupilot_gazebo` plugin and Webots serve it. ArduPilot runs no
//! physics of its own: each frame it sends its servo outputs (a small binary packet) to UDP
//! 9002+10·instance and waits for the world's answer, one line of JSON with the time, the IMU,
//! the pose and the velocity, sent back to the packet's source. ArduPilot's clock is the
//! answer's `timestamp` (lockstep): the world sets the pace and may run faster than real time.
//!
//! The protocol is ArduPilot's `libraries/SITL/examples/JSON/readme.md`. Its reader is a few
//! `strstr` and `sscanf` calls, not a JSON parser: keys are found by name, a value must follow
//! `"key":` at once, and `1.3e-05` fails to parse as a vector element. So the line is written
//! compact and in fixed-point only.

use std::fmt::Write as _;
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use sim::quadrotor::{BodyState, Quadrotor};
use sim::sensors::{ImuSample, Sensors};
use sim::world::World;

/// ArduPilot instance N sends its servo outputs to this port + 10·N.
pub const JSON_SERVO_PORT: u16 = 9002;
/// The servo packet's magic: 16 channels, or 32 with `SERVO_32_ENABLE = 1`.
pub const MAGIC_16_CHANNELS: u16 = 18458;
pub const MAGIC_32_CHANNELS: u16 = 29569;
/// `u16` magic, `u16` frame rate, `u32` frame count, then the PWM values.
const HEADER_BYTES: usize = 8;
/// What ArduPilot Copter must be told to fly the world's vehicle through this interface, each
/// for a reason; its start command takes them as `-P NAME=VALUE` ([`world_start_args`]).
pub const WORLD_PARAMETERS: &[(&str, &str)] = &[
    // The world's body is a quad X, whose rotor order the servo channels follow (the bundled
    // copter.parm flies a "+").
    ("FRAME_TYPE", "1"),
    // The world's downward rangefinder (`rng_1`) as rangefinder 1, with the world's sensor's
    // 0.1–15 m range (ArduPilot's default 7 m maximum loses the pad when following at 7.5 m
    // leaning into 12 m/s, and the pad-height estimate then misses the steps between pad and
    // field).
    ("RNGFND1_TYPE", "100"),
    ("RNGFND1_MIN_CM", "10"),
    ("RNGFND1_MAX_CM", "1500"),
    // No battery monitor: the JSON interface models no battery and would report 0 V.
    ("BATT_MONITOR", "0"),
    // PX4's 45° tilt limit: at 30° it cannot hold 12 m/s gusts and drifts off downwind.
    ("ANGLE_MAX", "4500"),
];

/// How GUIDED should answer a companion computer's vision landing on a moving pad (on a real
/// ArduPilot as in the world; measured in the landing evaluation, docs/simulator.md):
pub const VISION_LANDING_PARAMETERS: &[(&str, &str)] = &[
    // Velocity setpoints as velocities, as PX4's OFFBOARD takes them: by default GUIDED also
    // pulls back to the position the commanded velocities integrate to, an integrator of its
    // own inside the landing's loop (with it 20 of 24 evaluation missions landed on the pad, 16 without).
    ("GUID_OPTIONS", "16"),
    // The commands' shaping: 20 m/s³ of jerk (default 5) reaches 5 m/s² (default 2.5) in a
    // quarter second, horizontally and (3 m/s², default 1) vertically, where the flare asks
    // to slow down.
    ("PSC_JERK_XY", "20"),
    ("WPNAV_ACCEL", "500"),
    ("PSC_JERK_Z", "20"),
    ("WPNAV_ACCEL_Z", "300"),
];

/// The arguments that start ArduPilot Copter's SITL as the world's autopilot (after `-I N`):
/// this interface, no pacing of its own (the world sets the pace), [`WORLD_PARAMETERS`],
/// [`VISION_LANDING_PARAMETERS`] and the world's home.
pub fn world_start_args() -> String {
    let home = sim::sensors::Home::default();
    let mut args = String::from("-M JSON:127.0.0.1 -s 100");
    for (name, value) in WORLD_PARAMETERS.iter().chain(VISION_LANDING_PARAMETERS) {
        let _ = write!(args, " -P {name}={value}");
    }
    let _ = write!(
        args,
        " -O {},{},{},0",
        home.latitude_deg, home.longitude_deg, home.altitude_m
    );
    args
}

/// What `rng_1` says when the rangefinder has no return: beyond any LiDAR's maximum, which
/// ArduPilot reads as "out of range high", as a real LiDAR's no-return. (A NaN would read as
/// "no data", a sensor fault that fails its pre-arm check.)
pub const NO_RETURN_RANGE_M: f64 = 999.0;
/// The PWM range ArduPilot's SITL motors span (RCn_MIN, RCn_MAX of its default parameters).
const PWM_MIN_US: f64 = 1000.0;
const PWM_SPAN_US: f64 = 1000.0;
/// What ArduPilot's SITL motors get when still: disarmed, or armed with `MOT_SPIN_ARM = 0`
/// (its `MOT_PWM_MIN`, the RCn_MIN of its default parameters).
const PWM_STOPPED_US: u16 = 1000;

/// One frame of ArduPilot's servo outputs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServoPacket {
    /// The physics step ArduPilot asks for: 1/frame_rate s (`SIM_RATE_HZ`).
    pub frame_rate_hz: u16,
    /// Counts the frames; the same count again is a resend (ArduPilot heard no answer).
    pub frame_count: u32,
    /// Servo outputs 1..=16 (or 32), microseconds.
    pub pwm_us: Vec<u16>,
}

/// A datagram on the servo port that is not a servo packet.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ServoPacketError {
    #[error("magic {found} is neither {MAGIC_16_CHANNELS} (16 channels) nor {MAGIC_32_CHANNELS} (32 channels): not an ArduPilot servo packet, or a protocol this backend does not know ({bytes} bytes)")]
    WrongMagic { found: u16, bytes: usize },
    #[error("{bytes} bytes where a servo packet of {channels} channels has {expected}")]
    Length {
        bytes: usize,
        expected: usize,
        channels: usize,
    },
    #[error("frame rate 0 Hz in frame {frame_count}: no time step to take")]
    ZeroFrameRate { frame_count: u32 },
}

impl ServoPacket {
    /// Reads a servo packet (little-endian), checking its magic and length.
    pub fn parse(bytes: &[u8]) -> Result<Self, ServoPacketError> {
        let u16_at = |i: usize| u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        if bytes.len() < 2 {
            return Err(ServoPacketError::Length {
                bytes: bytes.len(),
                expected: HEADER_BYTES + 2 * 16,
                channels: 16,
            });
        }
        let channels = match u16_at(0) {
            MAGIC_16_CHANNELS => 16,
            MAGIC_32_CHANNELS => 32,
            found => {
                return Err(ServoPacketError::WrongMagic {
                    found,
                    bytes: bytes.len(),
                })
            }
        };
        let expected = HEADER_BYTES + 2 * channels;
        if bytes.len() != expected {
            return Err(ServoPacketError::Length {
                bytes: bytes.len(),
                expected,
                channels,
            });
        }
        let frame_rate_hz = u16_at(2);
        let frame_count = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
        if frame_rate_hz == 0 {
            return Err(ServoPacketError::ZeroFrameRate { frame_count });
        }
        let pwm_us = (0..channels)
            .map(|k| u16_at(HEADER_BYTES + 2 * k))
            .collect();
        Ok(Self {
            frame_rate_hz,
            frame_count,
            pwm_us,
        })
    }

    /// The packet as ArduPilot writes it (for stand-ins of ArduPilot in tests and tools).
    pub fn to_bytes(&self) -> Vec<u8> {
        let (magic, channels) = if self.pwm_us.len() > 16 {
            (MAGIC_32_CHANNELS, 32)
        } else {
            (MAGIC_16_CHANNELS, 16)
        };
        let mut bytes = Vec::with_capacity(HEADER_BYTES + 2 * channels);
        bytes.extend_from_slice(&magic.to_le_bytes());
        bytes.extend_from_slice(&self.frame_rate_hz.to_le_bytes());
        bytes.extend_from_slice(&self.frame_count.to_le_bytes());
        for k in 0..channels {
            let pwm = self.pwm_us.get(k).copied().unwrap_or(0);
            bytes.extend_from_slice(&pwm.to_le_bytes());
        }
        bytes
    }

    /// The physics step this frame asks for.
    pub fn step_s(&self) -> f64 {
        1.0 / f64::from(self.frame_rate_hz)
    }

    /// Whether any of the motors (channels 1–4) is driven above the still motor's 1000 µs.
    /// That is all the servo outputs tell: ArduPilot armed with `MOT_SPIN_ARM = 0`, or in the
    /// instant after arming before its spool-up, sends the same 1000 µs as disarmed.
    pub fn motors_spinning(&self) -> bool {
        self.pwm_us.iter().take(4).any(|&pwm| pwm > PWM_STOPPED_US)
    }

    /// Channels 1–4 as motor commands 0–1 in the rotors' order (ArduPilot's quad X: servo
    /// channel k drives motor k): (PWM − 1000 µs) / 1000 µs, saturated. An unused channel
    /// (PWM 0) is a stopped motor.
    pub fn motor_commands(&self) -> [f64; 4] {
        [0, 1, 2, 3].map(|k| {
            let pwm = self.pwm_us.get(k).copied().unwrap_or(0);
            ((f64::from(pwm) - PWM_MIN_US) / PWM_SPAN_US).clamp(0.0, 1.0)
        })
    }
}

#[derive(Debug, thiserror::Error)]
pub enum JsonBackendError {
    #[error(
        "ArduPilot JSON: cannot listen on UDP 127.0.0.1:{port} (instance {instance}): {source}"
    )]
    Bind {
        port: u16,
        instance: u8,
        #[source]
        source: std::io::Error,
    },
    #[error("ArduPilot JSON: no servo packet on UDP 127.0.0.1:{port} within {waited_s:.1} s ({bad_packets} bad datagrams{}); is arducopter running with `-M JSON:127.0.0.1` and `-I {instance}`?", last_bad.as_ref().map(|e| format!(", the last: {e}")).unwrap_or_default())]
    Silent {
        port: u16,
        instance: u8,
        waited_s: f64,
        bad_packets: u64,
        last_bad: Option<ServoPacketError>,
    },
    #[error("ArduPilot JSON: no servo packet has come yet, so there is no address to answer")]
    NoPeer,
    #[error("ArduPilot JSON: {field} = {value} is not finite; ArduPilot would read garbage")]
    NonFinite { field: &'static str, value: f64 },
    #[error("ArduPilot JSON: UDP 127.0.0.1:{port}: {source}")]
    Io {
        port: u16,
        #[source]
        source: std::io::Error,
    },
    #[error("ArduPilot JSON: the world: {0}")]
    World(#[from] sim::world::WorldError),
}

/// The world's answer to one servo frame: ArduPilot's JSON sensor line, preceded and followed
/// by a newline (its reader takes what lies between two). `time_s` is the physics time at the
/// end of the step; the attitude goes as the quaternion (FRD → NED, w first), the IMU as the
/// body's rates and specific force; `rangefinder_m` is `rng_1` (`None`: no return).
pub fn state_json(
    time_s: f64,
    state: &BodyState,
    imu: &ImuSample,
    rangefinder_m: Option<f64>,
) -> Result<String, JsonBackendError> {
    let q = state.attitude.quaternion();
    let range_m = rangefinder_m.unwrap_or(NO_RETURN_RANGE_M);
    let fields: [(&'static str, &[f64]); 7] = [
        ("timestamp", &[time_s]),
        ("imu.gyro", imu.gyro_frd_rad_s.as_slice()),
        ("imu.accel_body", imu.accel_frd_m_s2.as_slice()),
        ("position", state.position_ned_m.as_slice()),
        ("quaternion", &[q.w, q.i, q.j, q.k]),
        ("velocity", state.velocity_ned_m_s.as_slice()),
        ("rng_1", &[range_m]),
    ];
    for (field, values) in fields {
        if let Some(&value) = values.iter().find(|v| !v.is_finite()) {
            return Err(JsonBackendError::NonFinite { field, value });
        }
    }
    let mut line = String::with_capacity(400);
    // Nanoseconds for the time, so the steps ArduPilot derives from it are exact to 1e-6 of
    // a 1200 Hz frame; micro-units elsewhere are finer than any sensor's noise.
    let _ = write!(line, "\n{{\"timestamp\":{time_s:.9},\"imu\":{{\"gyro\":");
    vector(&mut line, imu.gyro_frd_rad_s.as_slice(), 6);
    line.push_str(",\"accel_body\":");
    vector(&mut line, imu.accel_frd_m_s2.as_slice(), 6);
    line.push_str("},\"position\":");
    vector(&mut line, state.position_ned_m.as_slice(), 6);
    line.push_str(",\"quaternion\":");
    vector(&mut line, &[q.w, q.i, q.j, q.k], 9);
    line.push_str(",\"velocity\":");
    vector(&mut line, state.velocity_ned_m_s.as_slice(), 6);
    let _ = writeln!(line, ",\"rng_1\":{range_m:.6}}}");
    Ok(line)
}

/// `[a,b,c]` in fixed point: Rust's `{:.N}` never writes an exponent.
fn vector(line: &mut String, values: &[f64], decimals: usize) {
    line.push('[');
    for (i, value) in values.iter().enumerate() {
        if i > 0 {
            line.push(',');
        }
        let _ = write!(line, "{value:.decimals$}");
    }
    line.push(']');
}

/// The world's end of ArduPilot's JSON interface: one UDP socket on 127.0.0.1:9002+10·instance.
#[derive(Debug)]
pub struct ArduPilotJson {
    socket: UdpSocket,
    port: u16,
    instance: u8,
    /// Where the last servo packet came from: the answer goes there.
    peer: Option<SocketAddr>,
    /// The frame count of the last servo packet received.
    received_frame: Option<u32>,
    /// The frame last answered and the answer: a resend of it gets the same bytes.
    answered: Option<(u32, String)>,
    bad_packets: u64,
    buffer: Vec<u8>,
}

impl ArduPilotJson {
    /// Listens where ArduPilot instance `instance` sends its servo outputs. Bind it before
    /// starting ArduPilot, or its first packets meet a closed port (it resends every second).
    pub fn bind(instance: u8) -> Result<Self, JsonBackendError> {
        let port = JSON_SERVO_PORT + 10 * u16::from(instance);
        let socket =
            UdpSocket::bind(("127.0.0.1", port)).map_err(|source| JsonBackendError::Bind {
                port,
                instance,
                source,
            })?;
        Ok(Self {
            socket,
            port,
            instance,
            peer: None,
            received_frame: None,
            answered: None,
            bad_packets: 0,
            // Larger than any servo packet, so an oversized datagram is seen whole as such.
            buffer: vec![0; 2048],
        })
    }

    pub fn port(&self) -> u16 {
        self.port
    }

    /// ArduPilot's address, once a servo packet has come.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.peer
    }

    /// Datagrams that were not servo packets, since binding.
    pub fn bad_packets(&self) -> u64 {
        self.bad_packets
    }

    /// Waits up to `timeout` for the next servo packet; other datagrams are skipped and
    /// counted. Nothing valid within the timeout is [`JsonBackendError::Silent`].
    pub fn receive_servos(&mut self, timeout: Duration) -> Result<ServoPacket, JsonBackendError> {
        let start = Instant::now();
        let mut bad_packets = 0;
        let mut last_bad = None;
        loop {
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(JsonBackendError::Silent {
                    port: self.port,
                    instance: self.instance,
                    waited_s: start.elapsed().as_secs_f64(),
                    bad_packets,
                    last_bad,
                });
            }
            // A zero read timeout is refused by the OS: wait at least a microsecond.
            self.socket
                .set_read_timeout(Some(left.max(Duration::from_micros(1))))
                .map_err(|source| self.io(source))?;
            match self.socket.recv_from(&mut self.buffer) {
                Ok((bytes, from)) => match ServoPacket::parse(&self.buffer[..bytes]) {
                    Ok(packet) => {
                        self.peer = Some(from);
                        self.received_frame = Some(packet.frame_count);
                        return Ok(packet);
                    }
                    Err(error) => {
                        bad_packets += 1;
                        self.bad_packets += 1;
                        last_bad = Some(error);
                    }
                },
                Err(error)
                    if matches!(
                        error.kind(),
                        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                    ) => {}
                // An ICMP "port unreachable" from an earlier answer (ArduPilot restarting):
                // not this socket's fault; keep listening.
                Err(error) if error.kind() == ErrorKind::ConnectionRefused => {}
                Err(error) => return Err(self.io(error)),
            }
        }
    }

    /// Whether `packet` repeats the frame already answered: ArduPilot heard nothing for a
    /// second and sent it again. Answer it with [`Self::resend_last_state`], without stepping.
    pub fn is_resend(&self, packet: &ServoPacket) -> bool {
        self.answered
            .as_ref()
            .is_some_and(|(frame, _)| *frame == packet.frame_count)
    }

    /// Answers the last servo packet with the world's state at `time_s` (the end of the step
    /// its frame asked for).
    pub fn send_state(
        &mut self,
        time_s: f64,
        state: &BodyState,
        imu: &ImuSample,
        rangefinder_m: Option<f64>,
    ) -> Result<(), JsonBackendError> {
        let (Some(peer), Some(frame)) = (self.peer, self.received_frame) else {
            return Err(JsonBackendError::NoPeer);
        };
        let line = state_json(time_s, state, imu, rangefinder_m)?;
        self.socket
            .send_to(line.as_bytes(), peer)
            .map_err(|source| self.io(source))?;
        self.answered = Some((frame, line));
        Ok(())
    }

    /// Sends the last answer again, unchanged; `false` when nothing was answered yet.
    pub fn resend_last_state(&mut self) -> Result<bool, JsonBackendError> {
        let (Some(peer), Some((_, line))) = (self.peer, self.answered.as_ref()) else {
            return Ok(false);
        };
        self.socket
            .send_to(line.as_bytes(), peer)
            .map_err(|source| self.io(source))?;
        Ok(true)
    }

    fn io(&self, source: std::io::Error) -> JsonBackendError {
        JsonBackendError::Io {
            port: self.port,
            source,
        }
    }
}

/// ArduPilot flying the world's rigid body over its JSON interface: one lockstep frame at a
/// time, the world's clock set by the frames ArduPilot asks for.
pub struct ArduPilotVehicle {
    pub json: ArduPilotJson,
    pub body: Quadrotor,
    pub sensors: Sensors,
    /// The world's time: the end of the last step taken (the `timestamp` last sent).
    pub time_s: f64,
    /// Longest wait for ArduPilot's next servo packet.
    pub step_timeout: Duration,
    /// The last servo packet received (a resend included).
    pub last_servos: Option<ServoPacket>,
    /// New frames answered (world steps taken), and resent frames answered again.
    pub frames: u64,
    pub resends: u64,
}

impl ArduPilotVehicle {
    pub fn new(json: ArduPilotJson, body: Quadrotor, sensors: Sensors) -> Self {
        Self {
            json,
            body,
            sensors,
            time_s: 0.0,
            step_timeout: Duration::from_secs(5),
            last_servos: None,
            frames: 0,
            resends: 0,
        }
    }

    /// Waits for ArduPilot's next servo frame. A resend of the frame last answered gets the
    /// same answer again and the world stays where it is; a new frame steps the world by
    /// 1/frame rate under its motor commands and is answered with the state at the step's end.
    /// No servo packet within [`Self::step_timeout`] is [`JsonBackendError::Silent`].
    pub fn step(&mut self, world: &mut World) -> Result<(), JsonBackendError> {
        let packet = self.json.receive_servos(self.step_timeout)?;
        if self.json.is_resend(&packet) {
            self.json.resend_last_state()?;
            self.resends += 1;
            self.last_servos = Some(packet);
            return Ok(());
        }
        let step_s = packet.step_s();
        self.body.set_motor_commands(packet.motor_commands());
        world.step(self.time_s, step_s, &mut self.body)?;
        self.time_s += step_s;
        let state = *self.body.state();
        let imu = self.sensors.imu(step_s, &state);
        let range = self.sensors.rangefinder(self.body.rangefinder_m());
        self.json.send_state(self.time_s, &state, &imu, range)?;
        self.frames += 1;
        self.last_servos = Some(packet);
        Ok(())
    }

    /// Whether the last servo packet drives any motor: see [`ServoPacket::motors_spinning`]
    /// (not whether ArduPilot is armed, which its servo outputs cannot tell).
    pub fn motors_spinning(&self) -> bool {
        self.last_servos
            .as_ref()
            .is_some_and(ServoPacket::motors_spinning)
    }
}

#[cfg(test)]
mod tests;
