//! Scoring a simulated flight against the world's truth: where the runtime thought the pad was
//! while it tracked it, what the hazard CNN found, how often the landing lost its target, and
//! the track and levels for the plots. It reads the runtime's bus and the world; it steers
//! nothing.

pub mod hazards;
pub mod localisation;

use algorithms::control::landing::LandingMode;
use nalgebra::Vector3;
use runtime::bus::{Bus, BusError, Subscriber};
use runtime::topics::{HazardReport, LandingSetpoint, RelativeState, HAZARDS, RELATIVE_STATE};
use sim::scene::Hazard;
use sim::tractor::PadState;

use crate::outcome::{QosSample, TrackSample};
use hazards::HazardScore;
use localisation::LocalisationAccumulator;

/// A relative state counts towards the localisation error when it is at most this old …
pub const LOCALISATION_MAX_AGE_S: f64 = 0.1;
/// … and its last vision fix at most this old (the tracker has the target, not a memory of it).
pub const LOCALISATION_MAX_FIX_GAP_S: f64 = 1.0;

/// The tally of one flight.
pub struct FlightScore {
    relative_states: Subscriber<RelativeState>,
    hazard_reports: Subscriber<HazardReport>,
    pub localisation: LocalisationAccumulator,
    pub hazards: HazardScore,
    /// The inference backend of the last hazard report; `None`: no report came.
    pub hazard_backend: Option<&'static str>,
    /// The landing went back to searching this many times.
    pub landing_aborts: u32,
    /// How old the tracker's latest vision fix was at the last step scored (the runtime's
    /// clock); `None` before its first fix.
    pub fix_age_s: Option<f64>,
    last_landing_mode: Option<LandingMode>,
    /// Keep the 1 Hz track and the levels' changes.
    record_track: bool,
    pub track: Vec<TrackSample>,
    pub qos_track: Vec<QosSample>,
    next_track_s: f64,
}

/// The world's state the track samples.
pub struct TrackTruth {
    pub vehicle_ned_m: Vector3<f64>,
    pub tractor_ne_m: [f64; 2],
    pub battery_soc: f64,
}

impl FlightScore {
    /// Listening on the runtime's bus; with `record_track`, keeping the track for the plots.
    pub fn new(bus: &Bus, record_track: bool) -> Result<Self, BusError> {
        Ok(Self {
            relative_states: bus.subscriber::<RelativeState>(RELATIVE_STATE)?,
            hazard_reports: bus.subscriber::<HazardReport>(HAZARDS)?,
            localisation: LocalisationAccumulator::default(),
            fix_age_s: None,
            hazards: HazardScore::default(),
            hazard_backend: None,
            landing_aborts: 0,
            last_landing_mode: None,
            record_track,
            track: Vec::new(),
            qos_track: Vec::new(),
            next_track_s: 0.0,
        })
    }

    /// Where the runtime thinks the pad is, against the truth: its latest relative state, when
    /// fresh and with a recent vision fix.
    pub fn localise(&mut self, runtime_now_s: f64, vehicle_ned_m: &Vector3<f64>, pad: &PadState) {
        let Some(message) = self.relative_states.latest() else {
            return;
        };
        let relative = &message.value;
        self.fix_age_s = relative.last_fix_time_s.map(|fix_s| runtime_now_s - fix_s);
        let fresh = runtime_now_s - relative.estimate.time_s <= LOCALISATION_MAX_AGE_S;
        let seen = relative
            .last_fix_time_s
            .is_some_and(|fix_s| runtime_now_s - fix_s <= LOCALISATION_MAX_FIX_GAP_S);
        if fresh && seen {
            let truth = vehicle_ned_m - pad.centre_ned_m;
            self.localisation.add(
                &relative.estimate.uav_relative_ned_m,
                &truth,
                relative
                    .platform_velocity_ned_m_s
                    .map(|v| (v, pad.velocity_ned_m_s)),
            );
        }
    }

    /// The hazard CNN's new report, against the hazards in the field.
    pub fn hazards(&mut self, hazards: &[Hazard]) {
        if let Some(report) = self.hazard_reports.take_new() {
            self.hazards.add(hazards, &report.value);
            self.hazard_backend = Some(report.value.backend);
        }
    }

    /// The landing's setpoint this step: a new climb to reacquire counts as an abort (and is
    /// told in `events`).
    pub fn landing(
        &mut self,
        time_s: f64,
        setpoint: &LandingSetpoint,
        events: &mut Vec<(f64, String)>,
    ) {
        if setpoint.mode == LandingMode::Reacquire
            && self.last_landing_mode != Some(LandingMode::Reacquire)
        {
            self.landing_aborts += 1;
            events.push((time_s, "landing: target lost, climbing to reacquire".into()));
        }
        self.last_landing_mode = Some(setpoint.mode);
    }

    /// With `record_track`: the levels when they changed, and the track once a second.
    pub fn sample(
        &mut self,
        time_s: f64,
        levels: impl FnOnce() -> Vec<(String, usize, f64)>,
        truth: impl FnOnce() -> TrackTruth,
    ) {
        if !self.record_track {
            return;
        }
        let levels = levels();
        if self
            .qos_track
            .last()
            .is_none_or(|last: &QosSample| last.levels != levels)
        {
            self.qos_track.push(QosSample { time_s, levels });
        }
        if time_s >= self.next_track_s {
            let truth = truth();
            let position = truth.vehicle_ned_m;
            self.track.push(TrackSample {
                time_s,
                vehicle_ne_m: [position.x, position.y],
                altitude_m: -position.z,
                tractor_ne_m: truth.tractor_ne_m,
                battery_soc: truth.battery_soc,
            });
            self.next_track_s += 1.0;
        }
    }
}
