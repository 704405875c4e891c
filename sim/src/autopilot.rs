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
//! EXTENDED_SYS_STATE 5 Hz.
//!
//! Lockstep (see `runtime::link::link`): `publish` ends its batch with
//! TIMESYNC { tc1: 0, ts1: t_ns }; `receive_lockstep(t_ns)` reads the runtime's commands until
//! its TIMESYNC { tc1 ≠ 0, ts1: t_ns } reply. `set_link_down(true)` drops every other message
//! both ways: the TIMESYNC pair is the simulation's clock, not part of the simulated radio link,
//! so a simulated link loss still runs deterministically.

use crate::flight::{AutopilotCommand, CommandRejected, FlightMode, LandedState, VehicleSnapshot};
use mavlink::dialects::common::{
    MavAutopilot, MavBatteryFunction, MavBatteryType, MavCmd, MavDistanceSensor, MavFrame,
    MavLandedState, MavMessage, MavModeFlag, MavResult, MavSensorOrientation, MavState,
    MavSysStatusSensor, MavType, MavVtolState, PositionTargetTypemask, ATTITUDE_DATA,
    BATTERY_STATUS_DATA, COMMAND_ACK_DATA, COMMAND_LONG_DATA, DISTANCE_SENSOR_DATA,
    EXTENDED_SYS_STATE_DATA, GLOBAL_POSITION_INT_DATA, HEARTBEAT_DATA, LOCAL_POSITION_NED_DATA,
    SET_POSITION_TARGET_LOCAL_NED_DATA, SYS_STATUS_DATA, TIMESYNC_DATA,
};
use mavlink::{MavHeader, MavlinkVersion};
use nalgebra::Vector3;
use runtime::link::connection::decode_datagram;
use runtime::link::mapping::{
    px4_custom_mode, px4_mode_parts, PX4_AUTO_SUB_MODE_LAND, PX4_AUTO_SUB_MODE_LOITER,
    PX4_AUTO_SUB_MODE_TAKEOFF, PX4_MAIN_MODE_AUTO, PX4_MAIN_MODE_OFFBOARD,
};
use std::io::{self, ErrorKind};
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

/// The autopilot's MAVLink ids, as PX4's defaults.
pub const AUTOPILOT_SYSTEM_ID: u8 = 1;
pub const AUTOPILOT_COMPONENT_ID: u8 = 1;
/// The simulated downward rangefinder's range, as DISTANCE_SENSOR reports it.
pub const RANGEFINDER_MIN_CM: u16 = 10;
pub const RANGEFINDER_MAX_CM: u16 = 4_000;

/// Stream periods (PX4 onboard-link rates).
const HEARTBEAT_PERIOD_S: f64 = 1.0;
const ATTITUDE_PERIOD_S: f64 = 1.0 / 50.0;
const POSITION_PERIOD_S: f64 = 1.0 / 50.0;
const DISTANCE_PERIOD_S: f64 = 1.0 / 20.0;
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
        })
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
        if take_due(&mut due.attitude_s, time_s, ATTITUDE_PERIOD_S) {
            self.send(&attitude(snapshot, time_boot_ms))?;
        }
        if take_due(&mut due.position_s, time_s, POSITION_PERIOD_S) {
            self.send(&local_position(snapshot, time_boot_ms))?;
            self.send(&global_position(snapshot, time_boot_ms))?;
        }
        if take_due(&mut due.distance_s, time_s, DISTANCE_PERIOD_S) {
            self.send(&distance_sensor(snapshot, time_boot_ms))?;
        }
        if take_due(&mut due.battery_s, time_s, BATTERY_PERIOD_S) {
            self.send(&battery_status(snapshot))?;
            self.send(&sys_status(snapshot))?;
        }
        if take_due(&mut due.extended_state_s, time_s, EXTENDED_STATE_PERIOD_S) {
            self.send(&extended_sys_state(snapshot))?;
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
                    tracing::warn!(command = ?long.command, ?result, "command refused");
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
            .map_err(|error| io::Error::other(error.to_string()))?;
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

/// PX4 `custom_mode` for a simulated flight mode.
pub fn px4_mode_of(mode: FlightMode) -> u32 {
    match mode {
        FlightMode::Hold => px4_custom_mode(PX4_MAIN_MODE_AUTO, PX4_AUTO_SUB_MODE_LOITER),
        FlightMode::Takeoff => px4_custom_mode(PX4_MAIN_MODE_AUTO, PX4_AUTO_SUB_MODE_TAKEOFF),
        FlightMode::Offboard => px4_custom_mode(PX4_MAIN_MODE_OFFBOARD, 0),
        FlightMode::Land => px4_custom_mode(PX4_MAIN_MODE_AUTO, PX4_AUTO_SUB_MODE_LAND),
    }
}

/// The flight mode a PX4 main/sub mode pair names, when the simulator has it.
pub fn flight_mode_of_px4(main_mode: u8, sub_mode: u8) -> Option<FlightMode> {
    match (main_mode, sub_mode) {
        (PX4_MAIN_MODE_OFFBOARD, _) => Some(FlightMode::Offboard),
        (PX4_MAIN_MODE_AUTO, PX4_AUTO_SUB_MODE_LOITER) => Some(FlightMode::Hold),
        (PX4_MAIN_MODE_AUTO, PX4_AUTO_SUB_MODE_TAKEOFF) => Some(FlightMode::Takeoff),
        (PX4_MAIN_MODE_AUTO, PX4_AUTO_SUB_MODE_LAND) => Some(FlightMode::Land),
        _ => None,
    }
}

fn heartbeat(snapshot: &VehicleSnapshot) -> MavMessage {
    let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        | MavModeFlag::MAV_MODE_FLAG_STABILIZE_ENABLED
        | MavModeFlag::MAV_MODE_FLAG_GUIDED_ENABLED;
    if snapshot.mode != FlightMode::Offboard {
        base_mode |= MavModeFlag::MAV_MODE_FLAG_AUTO_ENABLED;
    }
    if snapshot.armed {
        base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    }
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: px4_mode_of(snapshot.mode),
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode,
        system_status: if snapshot.armed {
            MavState::MAV_STATE_ACTIVE
        } else {
            MavState::MAV_STATE_STANDBY
        },
        mavlink_version: 3,
    })
}

fn attitude(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    MavMessage::ATTITUDE(ATTITUDE_DATA {
        time_boot_ms,
        roll: snapshot.attitude.roll_rad as f32,
        pitch: snapshot.attitude.pitch_rad as f32,
        yaw: snapshot.attitude.yaw_rad as f32,
        rollspeed: snapshot.body_rates_rad_s.x as f32,
        pitchspeed: snapshot.body_rates_rad_s.y as f32,
        yawspeed: snapshot.body_rates_rad_s.z as f32,
    })
}

fn local_position(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
        time_boot_ms,
        x: snapshot.position_ned_m.x as f32,
        y: snapshot.position_ned_m.y as f32,
        z: snapshot.position_ned_m.z as f32,
        vx: snapshot.velocity_ned_m_s.x as f32,
        vy: snapshot.velocity_ned_m_s.y as f32,
        vz: snapshot.velocity_ned_m_s.z as f32,
    })
}

/// The home point's altitude above mean sea level, as PX4's SIH starts (its default location).
pub const HOME_AMSL_M: f64 = 488.0;
/// The home point's latitude and longitude (degrees), SIH's default.
const HOME_LAT_LON_DEG: (f64, f64) = (47.397_742, 8.545_594);
const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// GLOBAL_POSITION_INT: the local position on a flat earth around home; PX4 gives AMSL and
/// relative altitudes in mm, which a companion needs for MAV_CMD_NAV_TAKEOFF (AMSL).
fn global_position(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    let position = snapshot.position_ned_m;
    let (lat0, lon0) = HOME_LAT_LON_DEG;
    let lat_deg = lat0 + (position.x / EARTH_RADIUS_M).to_degrees();
    let lon_deg = lon0 + (position.y / (EARTH_RADIUS_M * lat0.to_radians().cos())).to_degrees();
    let height_m = -position.z;
    MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
        time_boot_ms,
        lat: (lat_deg * 1e7).round() as i32,
        lon: (lon_deg * 1e7).round() as i32,
        alt: ((HOME_AMSL_M + height_m) * 1000.0).round() as i32,
        relative_alt: (height_m * 1000.0).round() as i32,
        vx: (snapshot.velocity_ned_m_s.x * 100.0).round() as i16,
        vy: (snapshot.velocity_ned_m_s.y * 100.0).round() as i16,
        vz: (snapshot.velocity_ned_m_s.z * 100.0).round() as i16,
        hdg: u16::MAX,
    })
}

/// Out of range (`None`) is reported as UINT16_MAX, which the runtime reads as "no reading".
fn distance_sensor(snapshot: &VehicleSnapshot, time_boot_ms: u32) -> MavMessage {
    let current_distance = match snapshot.rangefinder_m {
        Some(distance_m) if distance_m.is_finite() => {
            let centimetres = (distance_m * 100.0).round();
            if (f64::from(RANGEFINDER_MIN_CM)..=f64::from(RANGEFINDER_MAX_CM))
                .contains(&centimetres)
            {
                centimetres as u16
            } else {
                u16::MAX
            }
        }
        _ => u16::MAX,
    };
    MavMessage::DISTANCE_SENSOR(DISTANCE_SENSOR_DATA {
        time_boot_ms,
        min_distance: RANGEFINDER_MIN_CM,
        max_distance: RANGEFINDER_MAX_CM,
        current_distance,
        mavtype: MavDistanceSensor::MAV_DISTANCE_SENSOR_LASER,
        id: 0,
        orientation: MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270,
        covariance: u8::MAX,
        ..Default::default()
    })
}

fn clamp_to_i16(value: f64) -> i16 {
    value
        .round()
        .clamp(f64::from(i16::MIN + 1), f64::from(i16::MAX)) as i16
}

fn remaining_percent(fraction: f64) -> i8 {
    (fraction * 100.0).round().clamp(0.0, 100.0) as i8
}

/// The simulator knows only the pack voltage, so it is reported as MAVLink says to when cells
/// are not measured: the total in cell 0, the rest UINT16_MAX (with the 65534 mV overflow form).
fn battery_status(snapshot: &VehicleSnapshot) -> MavMessage {
    let battery = snapshot.battery;
    let mut voltages = [u16::MAX; 10];
    let total_mv = (battery.voltage_v * 1000.0)
        .round()
        .clamp(0.0, 2.0 * 65_534.0) as u32;
    if total_mv > 65_534 {
        voltages[0] = 65_534;
        voltages[1] = (total_mv - 65_534) as u16;
    } else {
        voltages[0] = total_mv as u16;
    }
    MavMessage::BATTERY_STATUS(BATTERY_STATUS_DATA {
        current_consumed: battery.consumed_mah.round().clamp(0.0, f64::from(i32::MAX)) as i32,
        energy_consumed: -1,
        temperature: i16::MAX,
        voltages,
        current_battery: clamp_to_i16(battery.current_a * 100.0),
        id: 0,
        battery_function: MavBatteryFunction::MAV_BATTERY_FUNCTION_ALL,
        mavtype: MavBatteryType::MAV_BATTERY_TYPE_LIPO,
        battery_remaining: remaining_percent(battery.remaining_fraction),
        ..Default::default()
    })
}

fn sys_status(snapshot: &VehicleSnapshot) -> MavMessage {
    let battery = snapshot.battery;
    MavMessage::SYS_STATUS(SYS_STATUS_DATA {
        onboard_control_sensors_present: MavSysStatusSensor::empty(),
        onboard_control_sensors_enabled: MavSysStatusSensor::empty(),
        onboard_control_sensors_health: MavSysStatusSensor::empty(),
        load: 0,
        voltage_battery: (battery.voltage_v * 1000.0).round().clamp(0.0, 65_534.0) as u16,
        current_battery: clamp_to_i16(battery.current_a * 100.0),
        drop_rate_comm: 0,
        errors_comm: 0,
        errors_count1: 0,
        errors_count2: 0,
        errors_count3: 0,
        errors_count4: 0,
        battery_remaining: remaining_percent(battery.remaining_fraction),
        ..Default::default()
    })
}

fn extended_sys_state(snapshot: &VehicleSnapshot) -> MavMessage {
    MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
        vtol_state: MavVtolState::MAV_VTOL_STATE_MC,
        landed_state: match snapshot.landed_state {
            LandedState::OnGround => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
            LandedState::InAir => MavLandedState::MAV_LANDED_STATE_IN_AIR,
            LandedState::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
            LandedState::Landing => MavLandedState::MAV_LANDED_STATE_LANDING,
        },
    })
}

/// A velocity-only setpoint in LOCAL_NED (yaw optional); anything that asks for position or
/// acceleration control is refused, as the simulator flies velocity only.
pub fn decode_velocity_setpoint(
    setpoint: &SET_POSITION_TARGET_LOCAL_NED_DATA,
) -> Result<AutopilotCommand, &'static str> {
    if setpoint.coordinate_frame != MavFrame::MAV_FRAME_LOCAL_NED {
        return Err("only MAV_FRAME_LOCAL_NED setpoints are supported");
    }
    let mask = setpoint.type_mask;
    let position_ignored = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_X_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Y_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_Z_IGNORE;
    let velocity_ignored = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VX_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VY_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VZ_IGNORE;
    let acceleration_ignored = PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AX_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AY_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AZ_IGNORE;
    if !mask.contains(position_ignored) {
        return Err("position setpoints are not supported (velocity only)");
    }
    if mask.intersects(velocity_ignored) {
        return Err("the velocity must be given on all three axes");
    }
    if !mask.contains(acceleration_ignored) {
        return Err("acceleration setpoints are not supported (velocity only)");
    }
    let velocity = Vector3::new(
        f64::from(setpoint.vx),
        f64::from(setpoint.vy),
        f64::from(setpoint.vz),
    );
    if !velocity.iter().all(|v| v.is_finite()) {
        return Err("the velocity is not finite");
    }
    let yaw_rad = (!mask.contains(PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_IGNORE))
        .then_some(f64::from(setpoint.yaw))
        .filter(|yaw| yaw.is_finite());
    Ok(AutopilotCommand::VelocitySetpoint {
        velocity_ned_m_s: velocity,
        yaw_rad,
    })
}

/// COMMAND_LONG → command; `Err` carries the MAV_RESULT to answer at once (an unsupported
/// command, an unknown mode, or a request needing no action).
pub fn decode_command_long(long: &COMMAND_LONG_DATA) -> Result<AutopilotCommand, MavResult> {
    match long.command {
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => {
            if long.param1 == 1.0 {
                Ok(AutopilotCommand::Arm)
            } else if long.param1 == 0.0 {
                Ok(AutopilotCommand::Disarm)
            } else {
                Err(MavResult::MAV_RESULT_DENIED)
            }
        }
        MavCmd::MAV_CMD_NAV_TAKEOFF => {
            // PX4 reads param7 as altitude above mean sea level; NaN takes MIS_TAKEOFF_ALT.
            let amsl_m = f64::from(long.param7);
            if amsl_m.is_nan() {
                Ok(AutopilotCommand::SetMode(FlightMode::Takeoff))
            } else if amsl_m.is_finite() && amsl_m > HOME_AMSL_M {
                Ok(AutopilotCommand::Takeoff {
                    altitude_m: amsl_m - HOME_AMSL_M,
                })
            } else {
                Err(MavResult::MAV_RESULT_DENIED)
            }
        }
        MavCmd::MAV_CMD_NAV_LAND => Ok(AutopilotCommand::Land),
        // Answered at once: like PX4 it accepts the request, and its fixed streams already
        // run at the rates the runtime asks for.
        MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => Err(MavResult::MAV_RESULT_ACCEPTED),
        MavCmd::MAV_CMD_DO_SET_MODE => {
            let custom_flag = f32::from(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits());
            let base_mode = long.param1;
            if !base_mode.is_finite() || (base_mode as u32) & (custom_flag as u32) == 0 {
                return Err(MavResult::MAV_RESULT_DENIED);
            }
            if !(0.0..=255.0).contains(&long.param2) || !(0.0..=255.0).contains(&long.param3) {
                return Err(MavResult::MAV_RESULT_DENIED);
            }
            let custom_mode = px4_custom_mode(long.param2 as u8, long.param3 as u8);
            let (main_mode, sub_mode) = px4_mode_parts(custom_mode);
            flight_mode_of_px4(main_mode, sub_mode)
                .map(AutopilotCommand::SetMode)
                .ok_or(MavResult::MAV_RESULT_DENIED)
        }
        _ => Err(MavResult::MAV_RESULT_UNSUPPORTED),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flight::BatteryReading;
    use algorithms::estimation::projection::Attitude;
    use runtime::link::{
        AckResult, AutopilotMode, FailsafeAction, LinkConfig, LinkStatus, MavlinkLink, Sent,
        VehicleCommand,
    };

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

    #[test]
    fn rates_follow_px4_on_the_snapshot_clock() {
        let (link, mut autopilot) = pair(false, LinkConfig::default());
        // One simulated second (t = 0 … 0.99 s) stepped at 100 Hz.
        for tick in 0..100 {
            let mut snap = snapshot(0);
            snap.time_s = tick as f64 * 0.01;
            autopilot.publish(&snap).unwrap();
        }
        // 1 HEARTBEAT + 50 ATTITUDE + 50 POSITION + 20 DISTANCE + 2×2 battery + 5 EXTENDED.
        assert_eq!(autopilot.stats().messages_sent, 1 + 50 + 50 + 20 + 4 + 5);
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
        assert_eq!(px4_mode_of(FlightMode::Land), 0x0604_0000);
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
}
