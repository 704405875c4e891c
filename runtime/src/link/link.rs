//! [`MavlinkLink`]: the runtime's end of the MAVLink connection.
//!
//! **Link loss.** The link is [`LinkStatus::Lost`] when no autopilot HEARTBEAT came for
//! `heartbeat_timeout_s` or no LOCAL_POSITION_NED for `telemetry_timeout_s` (counted from the
//! first heartbeat until a position arrives). While lost, offboard setpoints are not sent
//! (PX4's own offboard-loss failsafe flies the vehicle); when the link comes back,
//! [`MavlinkLink::failsafe_action`] says [`FailsafeAction::HoldThenReenter`] and setpoints stay
//! suppressed until the mission calls [`MavlinkLink::recover`] (Hold, a zero velocity setpoint,
//! then OFFBOARD again).
//!
//! **Lockstep** (simulation only). Each simulated tick, the autopilot sends its telemetry and
//! ends the batch with TIMESYNC { tc1: 0, ts1: t_ns }. [`MavlinkLink::poll_lockstep`] blocks
//! (wall-clock timeout) until that TIMESYNC, processing everything before it with the runtime
//! clock at t_ns; after sending the tick's commands the runtime calls
//! [`MavlinkLink::end_tick`], which sends TIMESYNC { tc1: t_ns, ts1: t_ns } (the standard
//! reply form; tc1 is forced to at least 1 so that t = 0 is not mistaken for a request). The
//! autopilot reads commands until that reply. UDP keeps datagram order on loopback, so both
//! sides see the same messages at the same simulated time on every run.
//!
//! **Not lockstep** (real autopilot): TIMESYNC requests (tc1 = 0) are answered with
//! tc1 = own clock in ns and ts1 echoed (PX4 converts the companion's timestamps with them).
//! The link asks the autopilot in turn, once every `timesync_period_s`, and tracks the
//! autopilot's clock ([`ClockSync`]): LANDING_TARGET carries the capture in that clock. A poll
//! that sends a request waits up to `timesync_wait_s` for its reply (processing whatever comes
//! meanwhile), so the round trip is measured, not the mission loop's period; each batch is
//! stamped when taken ([`Incoming::received_s`]), and a recording keeps the stamps, so a
//! replay measures the same round trips.

use super::connection::{ConnectionSpec, Incoming, ReplayFeed, Transport};
use super::mapping::{
    command_message, companion_heartbeat, AutopilotKind, AutopilotStatus, CommandAck,
    CommandTarget, TelemetryState, VehicleCommand,
};
use super::redial::{connection_gone, Redial};
use super::timesync::{ClockSync, ClockSyncStats};
use super::LinkError;
use crate::telemetry::BatteryTelemetry;
use crate::topics::VehicleState;
use mavlink::dialects::common::{MavMessage, TIMESYNC_DATA};
use mavlink::{MavHeader, Message};
use nalgebra::Vector3;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

/// MAVLink's component id of a gimbal device (MAV_COMP_ID_GIMBAL).
pub const GIMBAL_COMPONENT_ID: u8 = 154;

/// Upper bound on datagrams drained by one `poll`, so a flood cannot starve the mission loop.
const MAX_DATAGRAMS_PER_POLL: usize = 10_000;

/// The link's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkConfig {
    /// No autopilot HEARTBEAT for this long: the link is lost.
    pub heartbeat_timeout_s: f64,
    /// No LOCAL_POSITION_NED for this long: the link is lost (the landing loop flies on it).
    pub telemetry_timeout_s: f64,
    /// The companion's own HEARTBEAT period.
    pub heartbeat_period_s: f64,
    /// The companion's system id (the vehicle's, as PX4 expects of an onboard computer).
    pub system_id: u8,
    /// MAV_COMP_ID_ONBOARD_COMPUTER.
    pub component_id: u8,
    /// The autopilot's system id; `None` learns it from the first autopilot HEARTBEAT (PX4
    /// SITL instance i is system i + 1). Telemetry from anyone else is ignored.
    pub target_system_id: Option<u8>,
    pub target_component_id: u8,
    /// MAVLink 2 signing: sign what is sent, refuse what is not signed with this key.
    pub signing_key: Option<[u8; 32]>,
    /// How often the link asks the autopilot's clock (TIMESYNC); not in lockstep.
    pub timesync_period_s: f64,
    /// How long a poll that asked waits for the answer (the round trip's resolution).
    pub timesync_wait_s: f64,
}

impl Default for LinkConfig {
    fn default() -> Self {
        Self {
            heartbeat_timeout_s: 1.5,
            telemetry_timeout_s: 0.5,
            heartbeat_period_s: 1.0,
            system_id: 1,
            component_id: super::mapping::ONBOARD_COMPUTER_COMPONENT_ID,
            target_system_id: None,
            target_component_id: 1,
            signing_key: None,
            timesync_period_s: 1.0,
            timesync_wait_s: 0.005,
        }
    }
}

/// Whether the autopilot is heard.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinkStatus {
    /// No autopilot heartbeat yet.
    Connecting,
    Connected,
    /// Lost since `since_s` (runtime clock): the first deadline that expired.
    Lost {
        since_s: f64,
    },
}

/// What the mission must do about the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FailsafeAction {
    /// Fly as usual.
    Continue,
    /// No link (yet or any more): stop streaming offboard setpoints; the autopilot's own
    /// failsafe is in charge.
    StopSetpoints,
    /// The link is back after a loss: call [`MavlinkLink::recover`] (Hold, then re-enter
    /// OFFBOARD) before streaming setpoints again.
    HoldThenReenter,
}

/// Counters since the link opened.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LinkStats {
    pub messages_received: u64,
    /// Datagrams (UDP) or frames (TCP/serial) that held no valid MAVLink message.
    pub malformed: u64,
    /// Messages from systems or components other than the autopilot.
    pub ignored: u64,
    /// Messages refused for a missing or wrong signature (signing on).
    pub unsigned: u64,
    pub messages_sent: u64,
    /// Messages not sent because no autopilot address is known yet (udpin).
    pub unsent_no_peer: u64,
    /// Offboard setpoints held back by the failsafe.
    pub suppressed_setpoints: u64,
    pub commands_denied: u64,
    /// Sends and receives the transport refused (a closed TCP link refuses every one).
    pub send_failures: u64,
    pub receive_failures: u64,
    /// `tcpout` connections dialled again after the autopilot reset or closed one.
    pub redials: u64,
}

/// A send or receive path that may fail for a while (the autopilot gone, its TCP link closed):
/// warned of once when it starts failing and once when it works again, not on every poll.
#[derive(Debug, Default)]
struct Outage {
    failing: bool,
}

impl Outage {
    fn failed(&mut self, what: &str, error: &dyn std::fmt::Display) {
        if !self.failing {
            tracing::warn!(%error, "MAVLink {what} failed; not repeated until it works again");
        }
        self.failing = true;
    }

    fn worked(&mut self, what: &str) {
        if self.failing {
            tracing::info!("MAVLink {what} works again");
        }
        self.failing = false;
    }
}

/// What one poll brought.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkUpdate {
    pub status: LinkStatus,
    /// The latest vehicle state, when this poll brought new attitude/position/height data.
    pub vehicle_state: Option<VehicleState>,
    /// The latest battery reading, when this poll brought one.
    pub battery: Option<BatteryTelemetry>,
    /// The latest autopilot heartbeat, when this poll brought one.
    pub autopilot: Option<AutopilotStatus>,
    /// COMMAND_ACKs, in arrival order.
    pub acks: Vec<CommandAck>,
    pub messages: usize,
    pub malformed: usize,
}

/// What happened to one command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sent {
    Sent,
    /// No autopilot address known yet (udpin before the autopilot spoke).
    NoPeer,
    /// An offboard setpoint while the link is lost or recovering.
    Suppressed,
}

/// The runtime's MAVLink connection to the autopilot.
pub struct MavlinkLink {
    transport: Transport,
    /// Dials a `tcpout` connection again when it goes.
    redial: Option<Redial>,
    config: LinkConfig,
    telemetry: TelemetryState,
    now_s: f64,
    first_heartbeat_s: Option<f64>,
    last_heartbeat_s: Option<f64>,
    last_position_s: Option<f64>,
    last_sent_heartbeat_s: Option<f64>,
    send_outage: Outage,
    receive_outage: Outage,
    status: LinkStatus,
    recovery_pending: bool,
    sequence: u8,
    autopilot_kind: AutopilotKind,
    stats: LinkStats,
    /// Messages from the autopilot, by MAVLink message name.
    received_by_type: std::collections::BTreeMap<&'static str, u64>,
    /// What was received and sent since the recorder last took it, while one records.
    capture: Option<LinkCapture>,
    /// The autopilot's clock, from the TIMESYNC exchange.
    clock_sync: ClockSync,
    /// When the current poll began, to stamp what it takes.
    poll_started: Instant,
}

/// What the link received (every batch, as it came) and sent, for a recorder.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LinkCapture {
    pub received: Vec<Incoming>,
    pub sent: Vec<(MavHeader, MavMessage)>,
}

impl MavlinkLink {
    /// Opens a connection string (see [`ConnectionSpec::parse`]).
    pub fn connect(address: &str, config: LinkConfig) -> Result<Self, LinkError> {
        let spec = ConnectionSpec::parse(address)?;
        Self::open(&spec, config)
    }

    pub fn open(spec: &ConnectionSpec, config: LinkConfig) -> Result<Self, LinkError> {
        let mut link = Self::with_transport(spec.open(config.signing_key)?, config);
        link.redial = Redial::of(spec, config.signing_key);
        Ok(link)
    }

    /// A link over a recording's MAVLink (`qosrt replay`): it receives what `feed` is given.
    pub fn replay(feed: ReplayFeed, config: LinkConfig) -> Self {
        Self::with_transport(Transport::Replay(feed), config)
    }

    /// Whether what the link sends has somewhere to go yet (udpin: once the autopilot spoke).
    pub fn has_peer(&self) -> bool {
        self.transport.has_peer()
    }

    /// Keeps what is received and sent from now on for [`Self::take_capture`] (a recorder).
    pub fn start_capture(&mut self) {
        self.capture.get_or_insert_with(LinkCapture::default);
    }

    /// What was received and sent since the last call (nothing unless capturing).
    pub fn take_capture(&mut self) -> LinkCapture {
        self.capture
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// `udpin` on 127.0.0.1 with an OS-chosen port, for the simulator: give
    /// [`Self::local_addr`] to the simulated autopilot, which sends there.
    pub fn bind_local_ephemeral(config: LinkConfig) -> Result<Self, LinkError> {
        Self::open(
            &ConnectionSpec::UdpIn {
                host: "127.0.0.1".to_string(),
                port: 0,
            },
            config,
        )
    }

    fn with_transport(transport: Transport, config: LinkConfig) -> Self {
        Self {
            transport,
            redial: None,
            config,
            telemetry: TelemetryState::new(),
            now_s: 0.0,
            first_heartbeat_s: None,
            last_heartbeat_s: None,
            last_position_s: None,
            last_sent_heartbeat_s: None,
            send_outage: Outage::default(),
            receive_outage: Outage::default(),
            status: LinkStatus::Connecting,
            recovery_pending: false,
            sequence: 0,
            autopilot_kind: AutopilotKind::Px4,
            stats: LinkStats::default(),
            received_by_type: std::collections::BTreeMap::new(),
            capture: None,
            clock_sync: ClockSync::new(config.timesync_period_s),
            poll_started: Instant::now(),
        }
    }

    /// The local UDP address (None for TCP/serial).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.transport.local_addr()
    }

    pub fn config(&self) -> &LinkConfig {
        &self.config
    }

    pub fn status(&self) -> LinkStatus {
        self.status
    }

    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Messages received from the autopilot, by MAVLink message name.
    pub fn received_by_type(&self) -> &std::collections::BTreeMap<&'static str, u64> {
        &self.received_by_type
    }

    /// Everything the autopilot reported so far.
    pub fn telemetry(&self) -> &TelemetryState {
        &self.telemetry
    }

    /// The latest vehicle state, whether or not the last poll refreshed it.
    pub fn vehicle_state(&self) -> Option<VehicleState> {
        self.telemetry.vehicle_state(self.now_s)
    }

    /// Drains what has arrived without blocking (but for a TIMESYNC request's reply, up to
    /// `timesync_wait_s`); `now_s` is the runtime's monotonic clock.
    pub fn poll(&mut self, now_s: f64) -> LinkUpdate {
        self.now_s = now_s;
        self.poll_started = Instant::now();
        if let Some(transport) = self.redial.as_mut().and_then(Redial::poll) {
            self.transport = transport;
            self.stats.redials += 1;
        }
        let asked = self.request_autopilot_time(now_s);
        let mut update = self.empty_update();
        for _ in 0..MAX_DATAGRAMS_PER_POLL {
            match self.receive(None) {
                Ok(Some(incoming)) => {
                    self.process(incoming, &mut update, None);
                }
                Ok(None) | Err(()) => break,
            }
        }
        // A recording holds what the wait took in the step's own batches, drained above.
        if let Some(ts1_ns) = asked.filter(|_| !self.transport.is_replay()) {
            let wait = Duration::from_secs_f64(self.config.timesync_wait_s.max(0.0));
            while self.clock_sync.is_pending(ts1_ns) {
                let remaining = wait.saturating_sub(self.poll_started.elapsed());
                if remaining.is_zero() {
                    break;
                }
                match self.receive(Some(remaining)) {
                    Ok(Some(incoming)) => {
                        self.process(incoming, &mut update, None);
                    }
                    Ok(None) => {}
                    Err(()) => break,
                }
            }
        }
        self.finish_poll(now_s, update)
    }

    /// Sends a TIMESYNC request when one is due and the autopilot is known; its ts1.
    fn request_autopilot_time(&mut self, now_s: f64) -> Option<i64> {
        let target_system = self.config.target_system_id?;
        if !self.transport.has_peer() || self.config.timesync_period_s <= 0.0 {
            return None;
        }
        let ts1 = self.clock_sync.request_if_due(now_s)?;
        let request = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1,
            target_system,
            target_component: self.config.target_component_id,
        });
        self.send_message(&request).ok().map(|_| ts1)
    }

    /// `time_s` on the runtime's clock in microseconds on the autopilot's, once known.
    pub fn autopilot_time_us(&self, time_s: f64) -> Option<u64> {
        self.clock_sync.autopilot_time_us(time_s)
    }

    pub fn clock_sync_stats(&self) -> ClockSyncStats {
        self.clock_sync.stats()
    }

    /// Lockstep: processes everything up to the autopilot's TIMESYNC { tc1: 0, ts1: t_ns },
    /// waiting for it up to `timeout` of wall-clock time. The runtime clock is t_ns.
    pub fn poll_lockstep(&mut self, t_ns: u64, timeout: Duration) -> Result<LinkUpdate, LinkError> {
        let now_s = t_ns as f64 / 1e9;
        self.now_s = now_s;
        let deadline = Instant::now() + timeout;
        let mut update = self.empty_update();
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Err(LinkError::LockstepTimeout {
                    t_ns,
                    timeout_s: timeout.as_secs_f64(),
                });
            }
            let Some(incoming) = self.transport.receive(Some(remaining))? else {
                continue;
            };
            match self.process(incoming, &mut update, Some(t_ns)) {
                Some(got_ns) if got_ns == t_ns => break,
                Some(got_ns) if got_ns > t_ns => {
                    return Err(LinkError::LockstepOutOfStep {
                        expected_ns: t_ns,
                        got_ns,
                    })
                }
                // A barrier from an earlier tick (a retried run), or none yet.
                _ => {}
            }
        }
        Ok(self.finish_poll(now_s, update))
    }

    /// Lockstep: the runtime has sent its commands for tick t_ns; tells the autopilot so with
    /// TIMESYNC { tc1: t_ns, ts1: t_ns }.
    pub fn end_tick(&mut self, t_ns: u64) -> Result<(), LinkError> {
        let message = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: t_ns.max(1) as i64,
            ts1: t_ns as i64,
            ..Default::default()
        });
        self.send_message(&message)?;
        Ok(())
    }

    /// Sends one command. Offboard setpoints are held back while the link is not connected
    /// or a recovery is pending ([`Sent::Suppressed`]).
    pub fn send(&mut self, command: &VehicleCommand) -> Result<Sent, LinkError> {
        self.send_stamped(command, self.now_s)
    }

    /// [`Self::send`] with the message's `time_boot_ms` (where it has one) at `stamp_s` on the
    /// runtime's clock: a velocity setpoint carries the capture of the frame it answers.
    pub fn send_stamped(
        &mut self,
        command: &VehicleCommand,
        stamp_s: f64,
    ) -> Result<Sent, LinkError> {
        if command.is_offboard_setpoint() && self.failsafe_action() != FailsafeAction::Continue {
            self.stats.suppressed_setpoints += 1;
            return Ok(Sent::Suppressed);
        }
        let target = CommandTarget {
            system_id: self.config.target_system_id.unwrap_or(1),
            component_id: self.config.target_component_id,
            kind: self.autopilot_kind,
            home_amsl_m: self.telemetry.home_amsl_m(),
        };
        let time_boot_ms = (stamp_s.max(0.0) * 1000.0) as u32;
        let message = command_message(command, &target, time_boot_ms);
        self.send_message(&message)
    }

    /// What the mission must do about the link now.
    pub fn failsafe_action(&self) -> FailsafeAction {
        match self.status {
            LinkStatus::Connected if self.recovery_pending => FailsafeAction::HoldThenReenter,
            LinkStatus::Connected => FailsafeAction::Continue,
            LinkStatus::Connecting | LinkStatus::Lost { .. } => FailsafeAction::StopSetpoints,
        }
    }

    /// After a link loss: commands Hold, a zero velocity setpoint (PX4 needs one streaming
    /// before it accepts OFFBOARD) and OFFBOARD, then lets setpoints through again.
    pub fn recover(&mut self) -> Result<(), LinkError> {
        if self.failsafe_action() != FailsafeAction::HoldThenReenter {
            return Ok(());
        }
        self.recovery_pending = false;
        tracing::info!("MAVLink link recovered: Hold, then re-entering offboard");
        self.send(&VehicleCommand::SetHold)?;
        self.send(&VehicleCommand::VelocityNed {
            velocity_ned_m_s: Vector3::zeros(),
            yaw_rad: None,
        })?;
        self.send(&VehicleCommand::SetOffboard)?;
        Ok(())
    }

    fn empty_update(&self) -> LinkUpdate {
        LinkUpdate {
            status: self.status,
            vehicle_state: None,
            battery: None,
            autopilot: None,
            acks: Vec::new(),
            messages: 0,
            malformed: 0,
        }
    }

    /// Applies one datagram; returns ts1 of a lockstep barrier (TIMESYNC with tc1 = 0) when
    /// `lockstep` is set and the datagram held one.
    fn process(
        &mut self,
        mut incoming: Incoming,
        update: &mut LinkUpdate,
        lockstep: Option<u64>,
    ) -> Option<u64> {
        // Stamped when taken: the poll's time plus how long the poll has run (a replay keeps
        // the recorded stamp; lockstep time does not advance within a poll).
        let received_s = *incoming.received_s.get_or_insert_with(|| match lockstep {
            Some(_) => self.now_s,
            None => self.now_s + self.poll_started.elapsed().as_secs_f64(),
        });
        if let Some(capture) = &mut self.capture {
            capture.received.push(incoming.clone());
        }
        self.stats.unsigned += incoming.unsigned as u64;
        if incoming.malformed {
            self.stats.malformed += 1;
            update.malformed += 1;
            return None;
        }
        let mut barrier = None;
        let mut from_autopilot = false;
        for (header, message) in incoming.messages {
            if self.config.target_system_id.is_none()
                && header.component_id == self.config.target_component_id
            {
                if let MavMessage::HEARTBEAT(heartbeat) = &message {
                    if super::mapping::decode_heartbeat(heartbeat).is_some() {
                        // The companion shares the vehicle's system id.
                        let system_id = header.system_id as u8;
                        tracing::info!(system_id, "autopilot found");
                        self.config.target_system_id = Some(system_id);
                        self.config.system_id = system_id;
                    }
                }
            }
            let of_vehicle = self.config.target_system_id.map(u32::from) == Some(header.system_id);
            // A MAVLink gimbal device of the vehicle reports its attitude itself (component
            // MAV_COMP_ID_GIMBAL); everything else comes from the autopilot.
            let from_gimbal = of_vehicle
                && header.component_id == GIMBAL_COMPONENT_ID
                && matches!(message, MavMessage::GIMBAL_DEVICE_ATTITUDE_STATUS(_));
            let from_autopilot_component =
                of_vehicle && self.config.target_component_id == header.component_id;
            if !(from_gimbal || from_autopilot_component) {
                self.stats.ignored += 1;
                continue;
            }
            from_autopilot |= !from_gimbal;
            self.stats.messages_received += 1;
            *self
                .received_by_type
                .entry(message.message_name())
                .or_default() += 1;
            update.messages += 1;
            if let MavMessage::TIMESYNC(timesync) = &message {
                if timesync.tc1 != 0 && lockstep.is_none() {
                    self.clock_sync
                        .on_reply(timesync.tc1, timesync.ts1, received_s);
                } else if timesync.tc1 == 0 {
                    if lockstep.is_some() {
                        barrier = Some(timesync.ts1.max(0) as u64);
                    } else {
                        // Addressed to whoever asked (MAVLink 2's TIMESYNC extension).
                        let reply = MavMessage::TIMESYNC(TIMESYNC_DATA {
                            tc1: (self.now_s * 1e9) as i64,
                            ts1: timesync.ts1,
                            target_system: header.system_id as u8,
                            target_component: header.component_id,
                        });
                        // A failure is counted and warned of by the sender.
                        let _ = self.send_message(&reply);
                    }
                }
                continue;
            }
            let applied = self.telemetry.apply(&message, self.now_s);
            if let Some(status) = applied.heartbeat {
                self.first_heartbeat_s.get_or_insert(self.now_s);
                self.last_heartbeat_s = Some(self.now_s);
                self.autopilot_kind = status.kind;
                update.autopilot = Some(status);
            }
            if matches!(message, MavMessage::LOCAL_POSITION_NED(_)) {
                self.last_position_s = Some(self.now_s);
            }
            if applied.vehicle_state {
                update.vehicle_state = self.telemetry.vehicle_state(self.now_s);
            }
            if applied.battery {
                update.battery = self.telemetry.battery();
            }
            if let Some(ack) = applied.ack {
                if !ack.result.is_accepted() {
                    self.stats.commands_denied += 1;
                    tracing::warn!(command = ack.command_id, result = ?ack.result, "autopilot refused a command");
                }
                update.acks.push(ack);
            }
        }
        if from_autopilot {
            self.transport.learn_peer(incoming.from);
        }
        barrier
    }

    fn finish_poll(&mut self, now_s: f64, mut update: LinkUpdate) -> LinkUpdate {
        self.send_heartbeat_if_due(now_s);
        self.update_status(now_s);
        update.status = self.status;
        update
    }

    fn send_heartbeat_if_due(&mut self, now_s: f64) {
        let due = self
            .last_sent_heartbeat_s
            .is_none_or(|last| now_s - last >= self.config.heartbeat_period_s - 1e-9);
        if !due {
            return;
        }
        // Sent or refused, the next try is a period on (a failure is counted and warned of
        // by the sender); with no peer yet, it goes as soon as there is one.
        if !matches!(self.send_message(&companion_heartbeat()), Ok(Sent::NoPeer)) {
            self.last_sent_heartbeat_s = Some(now_s);
        }
    }

    fn update_status(&mut self, now_s: f64) {
        let Some(last_heartbeat_s) = self.last_heartbeat_s else {
            return;
        };
        let heartbeat_deadline_s = last_heartbeat_s + self.config.heartbeat_timeout_s;
        let position_since_s = self
            .last_position_s
            .or(self.first_heartbeat_s)
            .unwrap_or(last_heartbeat_s);
        let position_deadline_s = position_since_s + self.config.telemetry_timeout_s;
        let expired = [heartbeat_deadline_s, position_deadline_s]
            .into_iter()
            .filter(|deadline_s| now_s > *deadline_s)
            .reduce(f64::min);
        self.status = match (self.status, expired) {
            (LinkStatus::Lost { since_s }, Some(_)) => LinkStatus::Lost { since_s },
            (_, Some(since_s)) => {
                tracing::warn!(
                    since_s,
                    heartbeat_age_s = now_s - last_heartbeat_s,
                    "MAVLink link lost: stopping offboard setpoints"
                );
                LinkStatus::Lost { since_s }
            }
            (LinkStatus::Lost { since_s }, None) => {
                tracing::info!(lost_for_s = now_s - since_s, "MAVLink link back");
                self.recovery_pending = true;
                LinkStatus::Connected
            }
            (_, None) => LinkStatus::Connected,
        };
    }

    /// What the transport has (waiting at most `wait`); a failure is counted and warned of
    /// here, once per outage.
    fn receive(&mut self, wait: Option<Duration>) -> Result<Option<Incoming>, ()> {
        match self.transport.receive(wait) {
            Ok(incoming) => {
                if incoming.is_some() {
                    self.receive_outage.worked("receive");
                }
                Ok(incoming)
            }
            Err(error) => {
                self.stats.receive_failures += 1;
                self.receive_outage.failed("receive", &error);
                self.connection_failed(&error);
                Err(())
            }
        }
    }

    /// A send or receive failed: where its connection is gone, dial again.
    fn connection_failed(&mut self, error: &std::io::Error) {
        if let Some(redial) = self.redial.as_mut().filter(|_| connection_gone(error)) {
            redial.connection_lost();
        }
    }

    fn send_message(&mut self, message: &MavMessage) -> Result<Sent, LinkError> {
        let header = MavHeader {
            system_id: u32::from(self.config.system_id),
            component_id: self.config.component_id,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        if let Some(capture) = &mut self.capture {
            capture.sent.push((header, message.clone()));
        }
        let sent = match self.transport.send(header, message) {
            Ok(sent) => {
                self.send_outage.worked("send");
                sent
            }
            Err(error) => {
                self.stats.send_failures += 1;
                self.send_outage.failed("send", &error);
                self.connection_failed(&error);
                return Err(error.into());
            }
        };
        if sent {
            self.stats.messages_sent += 1;
            Ok(Sent::Sent)
        } else {
            self.stats.unsent_no_peer += 1;
            Ok(Sent::NoPeer)
        }
    }
}

impl std::fmt::Debug for MavlinkLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MavlinkLink")
            .field("local_addr", &self.local_addr())
            .field("status", &self.status)
            .field("stats", &self.stats)
            .finish()
    }
}

#[cfg(test)]
mod tests;
