//! The simulated vehicle's MAVLink autopilot: it speaks for a [`VehicleSnapshot`] as PX4 does
//! (system 1, component 1, MAV_AUTOPILOT_PX4, MAV_TYPE_QUADROTOR, MAVLink 2) and decodes what the
//! runtime sends into [`AutopilotCommand`]s.
//!
//! Addressing: the autopilot is the `udpout` side. It binds 127.0.0.1 on an OS-chosen port
//! and sends to the runtime's `udpin` address (`MavlinkLink::bind_local_ephemeral` then
//! `local_addr`), as PX4 SITL sends to a companion's 14540; the runtime answers the address the
//! autopilot's datagrams come from.
//!
//! Rates follow PX4's onboard-link defaults, on the snapshot's clock: HEARTBEAT 1 Hz, ATTITUDE
//! and LOCAL_POSITION_NED 50 Hz, DISTANCE_SENSOR 20 Hz, BATTERY_STATUS and SYS_STATUS 2 Hz,
//! EXTENDED_SYS_STATE 5 Hz; a vehicle with a camera gimbal adds GIMBAL_DEVICE_ATTITUDE_STATUS
//! with each ATTITUDE.
//!
//! Lockstep (see `runtime::link::link`): `publish` ends its batch with
//! TIMESYNC { tc1: 0, ts1: t_ns }; `receive_lockstep(t_ns)` reads the runtime's commands until
//! its TIMESYNC { tc1 ≠ 0, ts1: t_ns } reply. `set_link_down(true)` drops every other message
//! both ways: the TIMESYNC pair is the simulation's clock, not part of the simulated radio link,
//! so a simulated link loss still runs deterministically.

use crate::flight::{AutopilotCommand, CommandRejected, FlightMode, VehicleSnapshot};
use autopilot_modes::Px4Mode;
use mavlink::dialects::common::{MavCmd, MavMessage, MavResult, COMMAND_ACK_DATA, TIMESYNC_DATA};
use mavlink::{MavHeader, MavlinkVersion};
use std::io::{self, ErrorKind};
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

mod messages;
use messages::{
    attitude, battery_status, distance_sensor, extended_sys_state, gimbal_attitude,
    global_position, heartbeat, local_position, sys_status,
};
pub use messages::{
    decode_command_long, decode_velocity_setpoint, gimbal_device_attitude_status, HOME_AMSL_M,
};

/// Every CRC-valid MAVLink message in one datagram; garbage between frames is skipped.
pub fn decode_datagram(datagram: &[u8]) -> Vec<(MavHeader, MavMessage)> {
    let mut reader = mavlink::MavlinkReader::new(datagram);
    let mut messages = Vec::new();
    // A frame is at least 8 bytes: this bounds the loop whatever the reader does.
    for _ in 0..=datagram.len() / 8 {
        match reader.read_any_message::<MavMessage>() {
            Ok(message) => messages.push(message),
            Err(mavlink::error::MessageReadError::Parse(_)) => {}
            Err(mavlink::error::MessageReadError::Io(_)) => break,
        }
    }
    messages
}

/// The autopilot's MAVLink ids, as PX4's defaults.
pub const AUTOPILOT_SYSTEM_ID: u8 = 1;
pub const AUTOPILOT_COMPONENT_ID: u8 = 1;
/// The simulated downward rangefinder's range, as DISTANCE_SENSOR reports it.
pub const RANGEFINDER_MIN_CM: u16 = 10;
pub const RANGEFINDER_MAX_CM: u16 = 4_000;

/// Stream periods (PX4 onboard-link rates).
const HEARTBEAT_PERIOD_S: f64 = 1.0;
const BATTERY_PERIOD_S: f64 = 1.0 / 2.0;
const EXTENDED_STATE_PERIOD_S: f64 = 1.0 / 5.0;
/// Float slack for "is this stream due" on a fixed-step clock.
const DUE_SLACK_S: f64 = 1e-9;

/// Failures of the autopilot's socket or of the lockstep handshake.
#[derive(Debug, thiserror::Error)]
pub enum AutopilotError {
    #[error("simulated autopilot socket: {0}")]
    Io(#[from] io::Error),
    #[error(
        "lockstep: no TIMESYNC reply from the runtime for t = {t_ns} ns within {timeout_s} s \
         (did the runtime call end_tick?)"
    )]
    LockstepTimeout { t_ns: u64, timeout_s: f64 },
}

/// A COMMAND_LONG waiting for its COMMAND_ACK: give it back to [`MavlinkAutopilot::ack`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PendingAck {
    pub command: MavCmd,
}

/// One decoded command, with what is needed to acknowledge it (COMMAND_LONG only; setpoint
/// streams are not acknowledged in MAVLink).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReceivedCommand {
    pub command: AutopilotCommand,
    pub ack: Option<PendingAck>,
}

/// The latest LANDING_TARGET the runtime sent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandingTargetReport {
    /// Simulated time it arrived.
    pub received_s: f64,
    pub time_usec: u64,
    pub angle_x_rad: f64,
    pub angle_y_rad: f64,
    pub distance_m: f64,
}

/// Counters since the autopilot started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AutopilotStats {
    pub messages_sent: u64,
    pub messages_received: u64,
    /// Datagrams with no valid MAVLink message.
    pub malformed: u64,
    /// Setpoints refused: a position setpoint, a wrong frame, a non-finite velocity.
    pub rejected_setpoints: u64,
    /// Messages dropped by `set_link_down`.
    pub dropped: u64,
    pub runtime_heartbeats: u64,
}

#[derive(Debug, Clone, Copy, Default)]
struct Schedule {
    heartbeat_s: f64,
    attitude_s: f64,
    position_s: f64,
    distance_s: f64,
    battery_s: f64,
    extended_state_s: f64,
}

/// The simulated PX4, speaking MAVLink 2 over UDP.
pub struct MavlinkAutopilot {
    socket: UdpSocket,
    runtime_addr: SocketAddr,
    lockstep: bool,
    link_down: bool,
    next_due: Option<Schedule>,
    now_s: f64,
    sequence: u8,
    landing_target: Option<LandingTargetReport>,
    stats: AutopilotStats,
    buffer: Vec<u8>,
    encode_buffer: Vec<u8>,
    rates: StreamRates,
}

/// How often the fast streams go out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamRates {
    pub attitude_hz: f64,
    pub position_hz: f64,
    pub distance_hz: f64,
}

impl Default for StreamRates {
    /// 50 Hz attitude and position, 20 Hz distance: one message a 50 Hz tick.
    fn default() -> Self {
        Self {
            attitude_hz: 50.0,
            position_hz: 50.0,
            distance_hz: 20.0,
        }
    }
}

impl MavlinkAutopilot {
    /// Binds 127.0.0.1 on an OS-chosen port and sends to `runtime_addr` (the runtime link's
    /// `udpin` address). `lockstep`: end each `publish` batch with the TIMESYNC barrier.
    pub fn bind_local(runtime_addr: SocketAddr, lockstep: bool) -> Result<Self, AutopilotError> {
        let socket = UdpSocket::bind(("127.0.0.1", 0))?;
        Ok(Self {
            socket,
            runtime_addr,
            lockstep,
            link_down: false,
            next_due: None,
            now_s: 0.0,
            sequence: 0,
            landing_target: None,
            stats: AutopilotStats::default(),
            buffer: vec![0; 65_536],
            encode_buffer: Vec::with_capacity(300),
            rates: StreamRates::default(),
        })
    }

    /// Streams ATTITUDE, LOCAL_POSITION_NED and DISTANCE_SENSOR at these rates (each at most
    /// once a `publish`); rates that are not finite and positive keep the defaults.
    pub fn with_stream_rates(mut self, rates: StreamRates) -> Self {
        let defaults = StreamRates::default();
        let pick = |hz: f64, default: f64| {
            if hz.is_finite() && hz > 0.0 {
                hz
            } else {
                default
            }
        };
        self.rates = StreamRates {
            attitude_hz: pick(rates.attitude_hz, defaults.attitude_hz),
            position_hz: pick(rates.position_hz, defaults.position_hz),
            distance_hz: pick(rates.distance_hz, defaults.distance_hz),
        };
        self
    }

    /// The autopilot's own UDP address.
    pub fn local_addr(&self) -> Result<SocketAddr, AutopilotError> {
        Ok(self.socket.local_addr()?)
    }

    /// Fault injection: drop every message both ways (except the lockstep TIMESYNC pair).
    pub fn set_link_down(&mut self, down: bool) {
        self.link_down = down;
    }

    pub fn link_down(&self) -> bool {
        self.link_down
    }

    pub fn stats(&self) -> AutopilotStats {
        self.stats
    }

    /// The latest LANDING_TARGET the runtime sent.
    pub fn landing_target(&self) -> Option<LandingTargetReport> {
        self.landing_target
    }

    /// The lockstep stamp for a simulated time.
    pub fn time_ns(time_s: f64) -> u64 {
        (time_s.max(0.0) * 1e9).round() as u64
    }

    /// Sends what is due at `snapshot.time_s`, and in lockstep the TIMESYNC barrier; returns
    /// the barrier's t_ns (give it to `receive_lockstep` and the runtime's `poll_lockstep`).
    pub fn publish(&mut self, snapshot: &VehicleSnapshot) -> Result<u64, AutopilotError> {
        let time_s = snapshot.time_s;
        self.now_s = time_s;
        let mut due = self.next_due.unwrap_or(Schedule {
            heartbeat_s: time_s,
            attitude_s: time_s,
            position_s: time_s,
            distance_s: time_s,
            battery_s: time_s,
            extended_state_s: time_s,
        });
        let time_boot_ms = (time_s.max(0.0) * 1000.0).round() as u32;
        if take_due(&mut due.heartbeat_s, time_s, HEARTBEAT_PERIOD_S) {
            self.send(&heartbeat(snapshot))?;
        }
        if take_due(&mut due.attitude_s, time_s, 1.0 / self.rates.attitude_hz) {
            self.send(&attitude(snapshot, time_boot_ms))?;
            // A gimbal streams its attitude as fast as the vehicle's: the camera's frames are
            // projected with it.
            if let Some(message) = gimbal_attitude(snapshot, time_boot_ms) {
                self.send(&message)?;
            }
        }
        if take_due(&mut due.position_s, time_s, 1.0 / self.rates.position_hz) {
            self.send(&local_position(snapshot, time_boot_ms))?;
        }
        if take_due(&mut due.distance_s, time_s, 1.0 / self.rates.distance_hz) {
            self.send(&distance_sensor(snapshot, time_boot_ms))?;
        }
        if take_due(&mut due.battery_s, time_s, BATTERY_PERIOD_S) {
            self.send(&battery_status(snapshot))?;
            self.send(&sys_status(snapshot))?;
        }
        if take_due(&mut due.extended_state_s, time_s, EXTENDED_STATE_PERIOD_S) {
            self.send(&extended_sys_state(snapshot))?;
            // At 5 Hz too: a companion reads only home's altitude from it.
            self.send(&global_position(snapshot, time_boot_ms))?;
        }
        self.next_due = Some(due);
        let t_ns = Self::time_ns(time_s);
        if self.lockstep {
            self.send_clock(&MavMessage::TIMESYNC(TIMESYNC_DATA {
                tc1: 0,
                ts1: t_ns as i64,
                ..Default::default()
            }))?;
        }
        Ok(t_ns)
    }

    /// Not lockstep: the commands that have arrived, without blocking.
    pub fn receive(&mut self) -> Result<Vec<ReceivedCommand>, AutopilotError> {
        self.socket.set_nonblocking(true)?;
        let mut commands = Vec::new();
        loop {
            match self.socket.recv_from(&mut self.buffer) {
                Ok((length, _)) => {
                    self.process_datagram(length, &mut commands, None)?;
                }
                Err(error) if no_data(&error) => break,
                Err(error) => return Err(error.into()),
            }
        }
        Ok(commands)
    }

    /// Lockstep: the commands the runtime sent for tick t_ns, read until its TIMESYNC reply,
    /// waiting up to `timeout` of wall-clock time.
    pub fn receive_lockstep(
        &mut self,
        t_ns: u64,
        timeout: Duration,
    ) -> Result<Vec<ReceivedCommand>, AutopilotError> {
        self.socket.set_nonblocking(false)?;
        let deadline = Instant::now() + timeout;
        let mut commands = Vec::new();
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Err(AutopilotError::LockstepTimeout {
                    t_ns,
                    timeout_s: timeout.as_secs_f64(),
                });
            }
            self.socket.set_read_timeout(Some(remaining))?;
            match self.socket.recv_from(&mut self.buffer) {
                Ok((length, _)) => {
                    if self.process_datagram(length, &mut commands, Some(t_ns))? {
                        return Ok(commands);
                    }
                }
                Err(error) if no_data(&error) => {}
                Err(error) => return Err(error.into()),
            }
        }
    }

    /// Acknowledges a COMMAND_LONG with what the vehicle made of it.
    pub fn ack(
        &mut self,
        pending: PendingAck,
        result: &Result<(), CommandRejected>,
    ) -> Result<(), AutopilotError> {
        let result = match result {
            Ok(()) => MavResult::MAV_RESULT_ACCEPTED,
            Err(CommandRejected::NoOffboardSetpoint) => MavResult::MAV_RESULT_TEMPORARILY_REJECTED,
            Err(CommandRejected::NotArmed | CommandRejected::InAir(_)) => {
                MavResult::MAV_RESULT_DENIED
            }
            Err(CommandRejected::Invalid(_)) => MavResult::MAV_RESULT_DENIED,
        };
        self.send_ack(pending.command, result)
    }

    fn send_ack(&mut self, command: MavCmd, result: MavResult) -> Result<(), AutopilotError> {
        self.send(&MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command,
            result,
            ..Default::default()
        }))
    }

    /// Decodes one datagram; true when it held the lockstep reply for `lockstep`.
    fn process_datagram(
        &mut self,
        length: usize,
        commands: &mut Vec<ReceivedCommand>,
        lockstep: Option<u64>,
    ) -> Result<bool, AutopilotError> {
        let messages = decode_datagram(&self.buffer[..length]);
        if messages.is_empty() {
            self.stats.malformed += 1;
            return Ok(false);
        }
        let mut end_of_tick = false;
        for (_header, message) in messages {
            if let MavMessage::TIMESYNC(timesync) = &message {
                match lockstep {
                    Some(t_ns) if timesync.tc1 != 0 && timesync.ts1 == t_ns as i64 => {
                        end_of_tick = true;
                    }
                    // PX4 answers a timesync request with its own clock.
                    None if timesync.tc1 == 0 && !self.link_down => {
                        self.send(&MavMessage::TIMESYNC(TIMESYNC_DATA {
                            tc1: Self::time_ns(self.now_s).max(1) as i64,
                            ts1: timesync.ts1,
                            ..Default::default()
                        }))?;
                    }
                    _ => {}
                }
                continue;
            }
            if self.link_down {
                self.stats.dropped += 1;
                continue;
            }
            self.stats.messages_received += 1;
            self.decode(&message, commands)?;
        }
        Ok(end_of_tick)
    }

    fn decode(
        &mut self,
        message: &MavMessage,
        commands: &mut Vec<ReceivedCommand>,
    ) -> Result<(), AutopilotError> {
        match message {
            MavMessage::HEARTBEAT(_) => self.stats.runtime_heartbeats += 1,
            MavMessage::SET_POSITION_TARGET_LOCAL_NED(setpoint) => {
                match decode_velocity_setpoint(setpoint) {
                    Ok(command) => commands.push(ReceivedCommand { command, ack: None }),
                    Err(why) => {
                        self.stats.rejected_setpoints += 1;
                        tracing::warn!(
                            type_mask = setpoint.type_mask.bits(),
                            why,
                            "setpoint rejected"
                        );
                    }
                }
            }
            MavMessage::COMMAND_LONG(long) => match decode_command_long(long) {
                Ok(command) => commands.push(ReceivedCommand {
                    command,
                    ack: Some(PendingAck {
                        command: long.command,
                    }),
                }),
                Err(result) => {
                    if result != MavResult::MAV_RESULT_ACCEPTED {
                        tracing::warn!(command = ?long.command, ?result, "command refused");
                    }
                    self.send_ack(long.command, result)?;
                }
            },
            MavMessage::LANDING_TARGET(target) => {
                self.landing_target = Some(LandingTargetReport {
                    received_s: self.now_s,
                    time_usec: target.time_usec,
                    angle_x_rad: f64::from(target.angle_x),
                    angle_y_rad: f64::from(target.angle_y),
                    distance_m: f64::from(target.distance),
                });
            }
            _ => {}
        }
        Ok(())
    }

    fn send(&mut self, message: &MavMessage) -> Result<(), AutopilotError> {
        if self.link_down {
            self.stats.dropped += 1;
            return Ok(());
        }
        self.send_clock(message)
    }

    /// Sends regardless of `link_down` (the lockstep clock).
    fn send_clock(&mut self, message: &MavMessage) -> Result<(), AutopilotError> {
        let header = MavHeader {
            system_id: u32::from(AUTOPILOT_SYSTEM_ID),
            component_id: AUTOPILOT_COMPONENT_ID,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        self.encode_buffer.clear();
        mavlink::write_versioned_msg(&mut self.encode_buffer, MavlinkVersion::V2, header, message)
            .map_err(io::Error::other)?;
        match self.socket.send_to(&self.encode_buffer, self.runtime_addr) {
            Ok(_) => {}
            // The runtime is not listening (yet): dropped, as over a radio.
            Err(error) if error.kind() == ErrorKind::ConnectionRefused => {}
            Err(error) => return Err(error.into()),
        }
        self.stats.messages_sent += 1;
        Ok(())
    }
}

fn no_data(error: &io::Error) -> bool {
    matches!(
        error.kind(),
        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::ConnectionRefused
    )
}

/// Whether a stream is due at `time_s`; advances its next due time. Falls back to
/// `time_s + period` after a gap, so a paused simulation does not burst.
fn take_due(next_s: &mut f64, time_s: f64, period_s: f64) -> bool {
    if time_s + DUE_SLACK_S < *next_s {
        return false;
    }
    *next_s += period_s;
    if *next_s + DUE_SLACK_S < time_s {
        *next_s = time_s + period_s;
    }
    true
}

/// The PX4 mode a simulated flight mode reports itself as.
pub fn px4_mode_of(mode: FlightMode) -> Px4Mode {
    match mode {
        FlightMode::Hold => Px4Mode::Loiter,
        FlightMode::Takeoff => Px4Mode::Takeoff,
        FlightMode::Offboard => Px4Mode::Offboard,
        FlightMode::Land => Px4Mode::Land,
    }
}

/// The flight mode a PX4 mode names, when the simulator has it (it has no position mode and
/// no precision landing of its own).
pub fn flight_mode_of_px4(mode: Px4Mode) -> Option<FlightMode> {
    match mode {
        Px4Mode::Offboard => Some(FlightMode::Offboard),
        Px4Mode::Loiter => Some(FlightMode::Hold),
        Px4Mode::Takeoff => Some(FlightMode::Takeoff),
        Px4Mode::Land => Some(FlightMode::Land),
        Px4Mode::Position | Px4Mode::PrecisionLand => None,
    }
}
