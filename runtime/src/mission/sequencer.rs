//! The mission sequencer: what the companion computer tells the autopilot, step by step, to fly
//! the mission — arm, take off, enter offboard, fly out to the tractor (transit), follow it
//! (tracking), land on it (landing) — and which phase is flying. Pure logic: the caller feeds it
//! what the link reports and what the landing task publishes, and sends the commands it returns.
//! The simulator and `qosrt run --mavlink` drive the same sequencer.
//!
//! Phases follow the config's `[[mission.phase]]` order and end by their kind: a transit when
//! the vehicle is over the tractor's meeting point at the follow height, a tracking phase after
//! its configured duration, the landing at touchdown. A "land now" from the governor skips
//! straight to the landing phase. The sequencer is the one owner of the phase flying: the runner
//! hands each change to the scheduler and the governor as it happens.
//!
//! Link loss: nothing can be sent, so the sequencer only records it; PX4 leaves offboard by
//! itself when setpoints stop (COM_OF_LOSS_T) and holds. When the link returns the sequencer
//! streams setpoints again and re-enters offboard, and the phase goes on where it was.
//!
//! Safety: without `control` (observe mode) the sequencer never commands anything; it follows
//! the flight the pilot or the autopilot's own mission flies (the first phase begins when the
//! vehicle is airborne, the middle ones last their configured time, the last ends on the
//! ground). With `control`, a mode change that the sequencer did not ask for while the link is
//! up (a pilot's switch, a ground station) is a takeover: it stops commanding at once, for
//! good. [`MissionSequencer::request_landing`] (the run's time is up, Ctrl-C) lands the vehicle
//! where it is with the autopilot's land mode.

pub use crate::config::{LandingBy, MissionPlan, PhaseKind};
pub use crate::link::{AutopilotKind, AutopilotMode, VehicleCommand};
use crate::topics::LandingSetpoint;
use nalgebra::Vector3;

/// What the link says about the autopilot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutopilotView {
    /// Which firmware: ArduPilot arms and takes off in GUIDED, PX4 in any mode.
    pub kind: AutopilotKind,
    pub armed: bool,
    pub mode: AutopilotMode,
    /// On the ground (EXTENDED_SYS_STATE).
    pub landed: bool,
    /// Local NED position from the autopilot.
    pub position_ned_m: Vector3<f64>,
}

/// Something worth reporting, with the time it happened.
#[derive(Debug, Clone, PartialEq)]
pub enum MissionEvent {
    Armed,
    TookOff,
    OffboardEngaged,
    PhaseStarted {
        phase: usize,
        name: String,
    },
    LinkLost,
    LinkRestored,
    LandNow {
        reason: String,
    },
    Touchdown,
    /// The mission cannot go on (e.g. the autopilot refused to arm for too long).
    Aborted {
        reason: String,
    },
    /// Someone else changed the mode while qosrt held control: it commands nothing more.
    TakenOver {
        mode: AutopilotMode,
    },
    /// Landing where the vehicle is, with the autopilot's land mode.
    LandingHere {
        reason: String,
    },
    /// Landed and disarmed.
    Disarmed,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Stage {
    WaitingForAutopilot,
    Arming {
        since_s: f64,
        sent_s: f64,
    },
    TakingOff {
        since_s: f64,
        sent_s: f64,
    },
    EnteringOffboard {
        since_s: f64,
        sent_s: Option<f64>,
    },
    Flying,
    Landing {
        sent_s: f64,
        /// By the autopilot's precision landing rather than its plain land mode.
        precise: bool,
    },
    /// Observe mode: following the flight, never commanding.
    Observing,
    /// Control was taken away: nothing more is sent.
    Released,
    Done,
}

/// Where the mission is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionStatus {
    /// The phase flying, once the first has begun.
    pub phase: Option<usize>,
    /// When that phase began.
    pub phase_started_s: f64,
    pub link_up: bool,
    pub finished: bool,
    /// qosrt is commanding the vehicle (armed it or holds offboard), so a stop must land it.
    pub holds_control: bool,
}

/// The sequencer.
#[derive(Debug, Clone)]
pub struct MissionSequencer {
    plan: MissionPlan,
    stage: Stage,
    phase: Option<usize>,
    phase_started_s: f64,
    link_up: bool,
    land_now: bool,
    takeoff_altitude_down_m: Option<f64>,
    /// The first connection is not a restoration.
    ever_connected: bool,
    /// The autopilot has reported its land mode since Land was sent.
    land_seen: bool,
    /// When GUIDED was last asked for (ArduPilot, before arming).
    guided_sent_s: f64,
    /// PX4 has reported AUTO.TAKEOFF since the take-off was sent.
    takeoff_mode_seen: bool,
    /// When the landing task last said the vehicle is down while the autopilot had not yet.
    touchdown_unconfirmed_since_s: Option<f64>,
}

/// One step's input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SequencerInput {
    pub time_s: f64,
    pub link_up: bool,
    /// `None` until the autopilot has been heard.
    pub autopilot: Option<AutopilotView>,
    /// The landing task's latest setpoint (fresh enough to fly).
    pub landing: Option<LandingSetpoint>,
    /// The governor asked to land now.
    pub land_now: Option<&'static str>,
}

impl MissionSequencer {
    pub fn new(plan: MissionPlan) -> Self {
        let stage = if plan.control {
            Stage::WaitingForAutopilot
        } else {
            Stage::Observing
        };
        Self {
            plan,
            stage,
            phase: None,
            phase_started_s: 0.0,
            link_up: false,
            land_now: false,
            takeoff_altitude_down_m: None,
            ever_connected: false,
            land_seen: false,
            guided_sent_s: f64::NEG_INFINITY,
            takeoff_mode_seen: false,
            touchdown_unconfirmed_since_s: None,
        }
    }

    pub fn status(&self) -> MissionStatus {
        MissionStatus {
            phase: self.phase,
            phase_started_s: self.phase_started_s,
            link_up: self.link_up,
            finished: self.stage == Stage::Done,
            holds_control: matches!(
                self.stage,
                Stage::Arming { .. }
                    | Stage::TakingOff { .. }
                    | Stage::EnteringOffboard { .. }
                    | Stage::Flying
            ),
        }
    }

    /// Ends the mission early (time up, Ctrl-C): when qosrt holds control it lands the vehicle
    /// where it is and finishes once disarmed; otherwise it finishes at once.
    pub fn request_landing(&mut self, reason: &str) -> (Vec<VehicleCommand>, Vec<MissionEvent>) {
        if self.status().holds_control {
            self.stage = Stage::Landing {
                sent_s: f64::NEG_INFINITY,
                precise: false,
            };
            let event = MissionEvent::LandingHere {
                reason: reason.to_string(),
            };
            (vec![VehicleCommand::Land], vec![event])
        } else {
            if !matches!(self.stage, Stage::Landing { .. }) {
                self.stage = Stage::Done;
            }
            (Vec::new(), Vec::new())
        }
    }

    pub fn plan(&self) -> &MissionPlan {
        &self.plan
    }

    /// New durations for phases (index, seconds from the phase's start): the time left changed
    /// in flight. A phase flying past its new duration ends at the next step.
    pub fn set_phase_durations(&mut self, durations_s: &[(usize, f64)]) {
        for &(phase, duration_s) in durations_s {
            if let Some(slot) = self.plan.phase_durations_s.get_mut(phase) {
                *slot = duration_s;
            }
        }
    }

    /// One step: the commands to send now, and what happened.
    pub fn step(&mut self, input: &SequencerInput) -> (Vec<VehicleCommand>, Vec<MissionEvent>) {
        let mut commands = Vec::new();
        let mut events = Vec::new();
        let now_s = input.time_s;
        self.note_link(input.link_up, now_s, &mut events);
        self.note_land_now(input.land_now, &mut events);
        let (true, Some(autopilot)) = (input.link_up, input.autopilot) else {
            return (commands, events);
        };
        let landing_phase = self.in_phase_of_kind(PhaseKind::Land);
        if matches!(self.stage, Stage::Landing { .. }) {
            self.land_seen |= autopilot.mode == AutopilotMode::Land;
        }
        if let Some(mode) = self.taken_over(&autopilot) {
            events.push(MissionEvent::TakenOver { mode });
            self.stage = Stage::Released;
            return (commands, events);
        }
        match self.stage {
            Stage::Observing => self.observe(&autopilot, now_s, &mut events),
            Stage::Released => {}
            Stage::WaitingForAutopilot => {
                self.step_waiting_for_autopilot(&autopilot, now_s, &mut commands)
            }
            Stage::Arming { since_s, sent_s } => self.step_arming(
                &autopilot,
                now_s,
                since_s,
                sent_s,
                &mut commands,
                &mut events,
            ),
            Stage::TakingOff { since_s, sent_s } => self.step_taking_off(
                &autopilot,
                now_s,
                since_s,
                sent_s,
                &mut commands,
                &mut events,
            ),
            Stage::EnteringOffboard { since_s, sent_s } => self.step_entering_offboard(
                &autopilot,
                input,
                since_s,
                sent_s,
                &mut commands,
                &mut events,
            ),
            Stage::Flying if self.plan.landing != LandingBy::Vision && landing_phase => {
                self.hand_landing_to_autopilot(now_s, &mut commands, &mut events)
            }
            Stage::Flying => {
                self.step_flying(&autopilot, input, landing_phase, &mut commands, &mut events)
            }
            Stage::Landing { sent_s, precise } => self.step_landing(
                &autopilot,
                now_s,
                sent_s,
                precise,
                &mut commands,
                &mut events,
            ),
            Stage::Done => {}
        }
        (commands, events)
    }

    /// Records a link change (lost, restored); the first connection is not a restoration.
    fn note_link(&mut self, link_up: bool, now_s: f64, events: &mut Vec<MissionEvent>) {
        if link_up != self.link_up {
            if link_up && self.ever_connected {
                events.push(MissionEvent::LinkRestored);
            } else if !link_up {
                events.push(MissionEvent::LinkLost);
            }
            self.ever_connected |= link_up;
            self.link_up = link_up;
            if link_up && self.stage == Stage::Flying {
                // The autopilot has left offboard meanwhile: stream, then re-enter.
                self.stage = Stage::EnteringOffboard {
                    since_s: now_s,
                    sent_s: None,
                };
            }
        }
    }

    /// Latches the governor's first "land now" (reported once).
    fn note_land_now(&mut self, land_now: Option<&'static str>, events: &mut Vec<MissionEvent>) {
        if let Some(reason) = land_now {
            if !self.land_now {
                self.land_now = true;
                events.push(MissionEvent::LandNow {
                    reason: reason.to_string(),
                });
            }
        }
    }

    /// Before arming: GUIDED first on ArduPilot, then arm (or straight to the take-off when
    /// already armed).
    fn step_waiting_for_autopilot(
        &mut self,
        autopilot: &AutopilotView,
        now_s: f64,
        commands: &mut Vec<VehicleCommand>,
    ) {
        if autopilot.kind == AutopilotKind::ArduPilot && autopilot.mode != AutopilotMode::Offboard {
            // ArduCopter takes off only in GUIDED: enter it first (once a second).
            if now_s - self.guided_sent_s >= self.plan.command_retry_s {
                commands.push(VehicleCommand::SetOffboard);
                self.guided_sent_s = now_s;
            }
        } else if autopilot.armed {
            // Already armed (a restarted companion): go straight to the take-off.
            self.stage = Stage::TakingOff {
                since_s: now_s,
                sent_s: f64::NEG_INFINITY,
            };
        } else {
            commands.push(VehicleCommand::Arm);
            self.stage = Stage::Arming {
                since_s: now_s,
                sent_s: now_s,
            };
        }
    }

    /// Waiting for the arming (retried, aborted after the command timeout); once armed, the
    /// take-off is sent.
    fn step_arming(
        &mut self,
        autopilot: &AutopilotView,
        now_s: f64,
        since_s: f64,
        sent_s: f64,
        commands: &mut Vec<VehicleCommand>,
        events: &mut Vec<MissionEvent>,
    ) {
        if autopilot.armed {
            events.push(MissionEvent::Armed);
            self.takeoff_altitude_down_m = Some(autopilot.position_ned_m.z);
            commands.push(VehicleCommand::Takeoff {
                altitude_m: self.plan.cruise_altitude_m,
            });
            self.stage = Stage::TakingOff {
                since_s: now_s,
                sent_s: now_s,
            };
        } else if now_s - since_s > self.plan.command_timeout_s {
            events.push(MissionEvent::Aborted {
                reason: format!(
                    "the autopilot did not arm within {} s",
                    self.plan.command_timeout_s
                ),
            });
            self.stage = Stage::Done;
        } else if now_s - sent_s >= self.plan.command_retry_s {
            commands.push(VehicleCommand::Arm);
            self.stage = Stage::Arming {
                since_s,
                sent_s: now_s,
            };
        }
    }

    /// Climbing to the cruise altitude (the take-off retried, aborted with a landing after the
    /// command timeout); once up, the first phase begins and offboard is entered.
    fn step_taking_off(
        &mut self,
        autopilot: &AutopilotView,
        now_s: f64,
        since_s: f64,
        sent_s: f64,
        commands: &mut Vec<VehicleCommand>,
        events: &mut Vec<MissionEvent>,
    ) {
        let start_down_m = *self
            .takeoff_altitude_down_m
            .get_or_insert(autopilot.position_ned_m.z);
        let climbed_m = start_down_m - autopilot.position_ned_m.z;
        self.takeoff_mode_seen |= autopilot.mode == AutopilotMode::Takeoff;
        // PX4 may finish its take-off lower (MIS_TAKEOFF_ALT) and hold: the flight out
        // climbs the rest.
        let px4_takeoff_done =
            self.takeoff_mode_seen && autopilot.mode != AutopilotMode::Takeoff && climbed_m > 1.0;
        if climbed_m >= self.plan.cruise_altitude_m - 0.3 || px4_takeoff_done {
            events.push(MissionEvent::TookOff);
            self.start_phase(0, now_s, events);
            self.stage = Stage::EnteringOffboard {
                since_s: now_s,
                sent_s: None,
            };
        } else if !autopilot.armed && now_s - since_s > 2.0 * self.plan.command_retry_s {
            // Disarmed on the ground again (a refused take-off times out the arming).
            self.stage = Stage::WaitingForAutopilot;
        } else if now_s - since_s > self.plan.command_timeout_s {
            events.push(MissionEvent::Aborted {
                reason: format!(
                    "the take-off did not reach {} m within {} s",
                    self.plan.cruise_altitude_m, self.plan.command_timeout_s
                ),
            });
            commands.push(VehicleCommand::Land);
            self.stage = Stage::Done;
        } else if !self.taking_off(autopilot, climbed_m)
            && now_s - sent_s >= self.plan.command_retry_s
        {
            commands.push(VehicleCommand::Takeoff {
                altitude_m: self.plan.cruise_altitude_m,
            });
            self.stage = Stage::TakingOff {
                since_s,
                sent_s: now_s,
            };
        }
    }

    /// Streaming setpoints, and after the preamble asking for offboard (retried) until the
    /// autopilot reports it.
    fn step_entering_offboard(
        &mut self,
        autopilot: &AutopilotView,
        input: &SequencerInput,
        since_s: f64,
        sent_s: Option<f64>,
        commands: &mut Vec<VehicleCommand>,
        events: &mut Vec<MissionEvent>,
    ) {
        let now_s = input.time_s;
        commands.push(self.flying_setpoint(autopilot, input, now_s, events));
        if autopilot.mode == AutopilotMode::Offboard {
            events.push(MissionEvent::OffboardEngaged);
            self.stage = Stage::Flying;
        } else if now_s - since_s >= self.plan.offboard_preamble_s
            && sent_s.is_none_or(|sent| now_s - sent >= self.plan.command_retry_s)
        {
            commands.push(VehicleCommand::SetOffboard);
            self.stage = Stage::EnteringOffboard {
                since_s,
                sent_s: Some(now_s),
            };
        }
    }

    /// The landing phase without vision landing: the autopilot lands, by its precision landing
    /// or where the vehicle is.
    fn hand_landing_to_autopilot(
        &mut self,
        now_s: f64,
        commands: &mut Vec<VehicleCommand>,
        events: &mut Vec<MissionEvent>,
    ) {
        let precise = self.plan.landing == LandingBy::AutopilotPrecision;
        let reason = if precise {
            "the autopilot's precision landing on the tracker's LANDING_TARGET"
        } else {
            "no vision landing (no camera, or no landing task in the last phase): the autopilot lands where the vehicle is"
        };
        events.push(MissionEvent::LandingHere {
            reason: reason.into(),
        });
        commands.push(land_command(precise));
        self.stage = Stage::Landing {
            sent_s: now_s,
            precise,
        };
    }

    /// In offboard: the phase's setpoint, until touchdown in the landing phase hands over to
    /// the autopilot's land mode.
    fn step_flying(
        &mut self,
        autopilot: &AutopilotView,
        input: &SequencerInput,
        landing_phase: bool,
        commands: &mut Vec<VehicleCommand>,
        events: &mut Vec<MissionEvent>,
    ) {
        let now_s = input.time_s;
        // The landing task's touchdown rides on with the pad (its setpoint holds the
        // pad's velocity and presses down) until the autopilot's land detector agrees,
        // or for at most `touchdown_confirm_s`: the autopilot's land mode holds still
        // over the ground, and a moving pad would drive away from under a vehicle
        // still a hand's breadth above it.
        let task_touchdown = input.landing.is_some_and(|setpoint| {
            setpoint.mode == algorithms::control::landing::LandingMode::Landed
        });
        let since_s = if task_touchdown && !autopilot.landed {
            Some(*self.touchdown_unconfirmed_since_s.get_or_insert(now_s))
        } else {
            None
        };
        self.touchdown_unconfirmed_since_s = since_s;
        let touchdown = autopilot.landed
            || since_s.is_some_and(|since_s| now_s - since_s >= self.plan.touchdown_confirm_s);
        if landing_phase && touchdown {
            events.push(MissionEvent::Touchdown);
            commands.push(VehicleCommand::Land);
            self.stage = Stage::Landing {
                sent_s: now_s,
                precise: false,
            };
        } else {
            commands.push(self.flying_setpoint(autopilot, input, now_s, events));
        }
    }

    /// Landing by the autopilot: the land command retried until its land mode shows, done once
    /// disarmed.
    fn step_landing(
        &mut self,
        autopilot: &AutopilotView,
        now_s: f64,
        sent_s: f64,
        precise: bool,
        commands: &mut Vec<VehicleCommand>,
        events: &mut Vec<MissionEvent>,
    ) {
        if !autopilot.armed {
            events.push(MissionEvent::Disarmed);
            self.stage = Stage::Done;
        } else if autopilot.mode != AutopilotMode::Land
            && now_s - sent_s >= self.plan.command_retry_s
        {
            commands.push(land_command(precise));
            self.stage = Stage::Landing {
                sent_s: now_s,
                precise,
            };
        }
    }

    /// The mode someone else chose while qosrt held offboard or was landing: `None` while the
    /// mode is the one qosrt asked for.
    fn taken_over(&self, autopilot: &AutopilotView) -> Option<AutopilotMode> {
        let expected = match self.stage {
            Stage::Flying => AutopilotMode::Offboard,
            // Once the autopilot has entered its land mode; disarmed on the ground, PX4 reports
            // its previous mode again, which is not a takeover.
            Stage::Landing { .. } if self.land_seen && autopilot.armed => AutopilotMode::Land,
            _ => return None,
        };
        (autopilot.mode != expected).then_some(autopilot.mode)
    }

    /// Whether the take-off command is being flown (PX4: AUTO.TAKEOFF; ArduPilot climbs in
    /// GUIDED, so: off the ground).
    fn taking_off(&self, autopilot: &AutopilotView, climbed_m: f64) -> bool {
        match autopilot.kind {
            AutopilotKind::ArduPilot => autopilot.armed && climbed_m > 0.2,
            _ => autopilot.mode == AutopilotMode::Takeoff,
        }
    }

    /// Observe mode: the phases follow the flight (airborne, durations, on the ground).
    fn observe(&mut self, autopilot: &AutopilotView, now_s: f64, events: &mut Vec<MissionEvent>) {
        if let Some(phase) = self.plan.only_phase {
            if self.phase.is_none() {
                self.start_phase(phase, now_s, events);
            }
            return;
        }
        match self.phase {
            None if autopilot.armed && !autopilot.landed => {
                events.push(MissionEvent::TookOff);
                self.start_phase(0, now_s, events);
            }
            Some(phase) if self.plan.kind(phase) != Some(PhaseKind::Land) => {
                let duration_s = self.plan.phase_durations_s.get(phase).copied();
                if now_s - self.phase_started_s >= duration_s.unwrap_or(0.0) {
                    self.start_phase(phase + 1, now_s, events);
                }
            }
            Some(_) if autopilot.landed && !autopilot.armed => {
                events.push(MissionEvent::Touchdown);
                self.stage = Stage::Done;
            }
            _ => {}
        }
    }

    /// Whether the phase flying is of `kind`.
    fn in_phase_of_kind(&self, kind: PhaseKind) -> bool {
        self.phase.and_then(|phase| self.plan.kind(phase)) == Some(kind)
    }

    fn start_phase(&mut self, phase: usize, now_s: f64, events: &mut Vec<MissionEvent>) {
        self.phase = Some(phase);
        self.phase_started_s = now_s;
        events.push(MissionEvent::PhaseStarted {
            phase,
            name: self
                .plan
                .phase_names
                .get(phase)
                .cloned()
                .unwrap_or_default(),
        });
    }

    /// Advances the phase when its end condition holds, then gives the velocity to fly.
    fn flying_setpoint(
        &mut self,
        autopilot: &AutopilotView,
        input: &SequencerInput,
        now_s: f64,
        events: &mut Vec<MissionEvent>,
    ) -> VehicleCommand {
        let phase = *self.phase.get_or_insert(0);
        match self.plan.kind(phase) {
            Some(kind) if self.land_now && kind != PhaseKind::Land => {
                let last_phase = self.plan.phase_names.len().saturating_sub(1);
                let landing = self.plan.landing_phase().unwrap_or(last_phase);
                self.start_phase(landing, now_s, events);
            }
            Some(PhaseKind::Transit) => {
                if self.transit_offset(autopilot).norm() <= self.plan.arrival_radius_m {
                    self.start_phase(phase + 1, now_s, events);
                }
            }
            Some(PhaseKind::Track) => {
                let duration_s = self
                    .plan
                    .phase_durations_s
                    .get(phase)
                    .copied()
                    .unwrap_or(0.0);
                if now_s - self.phase_started_s >= duration_s {
                    self.start_phase(phase + 1, now_s, events);
                }
            }
            Some(PhaseKind::Land) | None => {}
        }
        let velocity_ned_m_s = if self.in_phase_of_kind(PhaseKind::Transit) {
            self.transit_velocity(autopilot)
        } else {
            // The landing task steers; until it has spoken, hold.
            input
                .landing
                .map_or_else(Vector3::zeros, |s| s.velocity_setpoint_ned_m_s)
        };
        VehicleCommand::VelocityNed {
            velocity_ned_m_s,
            yaw_rad: None,
        }
    }

    /// Meeting point minus vehicle, NED, with the height error in down.
    fn transit_offset(&self, autopilot: &AutopilotView) -> Vector3<f64> {
        let start_down_m = self.takeoff_altitude_down_m.unwrap_or(0.0);
        let target = Vector3::new(
            self.plan.meeting_point_ne_m[0],
            self.plan.meeting_point_ne_m[1],
            start_down_m - self.plan.cruise_altitude_m,
        );
        target - autopilot.position_ned_m
    }

    fn transit_velocity(&self, autopilot: &AutopilotView) -> Vector3<f64> {
        let velocity = self.transit_offset(autopilot) * self.plan.position_gain_per_s;
        let speed = velocity.norm();
        if speed > self.plan.transit_speed_m_s {
            velocity * (self.plan.transit_speed_m_s / speed)
        } else {
            velocity
        }
    }
}

/// The autopilot's land command: its precision landing, or its plain land mode.
fn land_command(precise: bool) -> VehicleCommand {
    if precise {
        VehicleCommand::PrecisionLand
    } else {
        VehicleCommand::Land
    }
}

#[cfg(test)]
mod tests;
