//! The sequencer's plan: the phases in flight order, the flight out, who lands, and whether
//! qosrt commands the vehicle at all; made from the config and the command line.

use super::{MissionConfig, PhaseKind};

/// The sequencer's configuration.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MissionPlan {
    /// Phase names in flight order.
    pub phase_names: Vec<String>,
    /// Each phase's kind (a recording made before kinds had none: by position).
    #[serde(default)]
    pub phase_kinds: Vec<PhaseKind>,
    /// How long each middle phase flies; the first and last end on events (ignored there).
    pub phase_durations_s: Vec<f64>,
    /// Height above the take-off point at which the vehicle flies out and follows.
    pub cruise_altitude_m: f64,
    /// Where the tractor waits (local NED, north and east; down is ignored).
    pub meeting_point_ne_m: [f64; 2],
    /// Speed of the flight out.
    pub transit_speed_m_s: f64,
    /// Over the meeting point within this horizontal distance counts as arrived.
    pub arrival_radius_m: f64,
    /// Gain of the flight-out position loop (per second).
    pub position_gain_per_s: f64,
    /// Give up when arming or taking off is refused for this long.
    pub command_timeout_s: f64,
    /// Re-send a command the autopilot has not acted on after this long.
    pub command_retry_s: f64,
    /// Setpoints must stream this long before offboard is requested (PX4 needs > 2 Hz).
    pub offboard_preamble_s: f64,
    /// After the landing task's touchdown, the vehicle rides with the pad for at most this
    /// long waiting for the autopilot's land detector before the autopilot's land mode.
    pub touchdown_confirm_s: f64,
    /// Command the vehicle (`--control`); without it the sequencer only follows the flight.
    pub control: bool,
    /// Who lands the vehicle in the last phase.
    #[serde(default)]
    pub landing: LandingBy,
    /// Observe mode only: hold this one phase from the first time the autopilot is heard (a
    /// dry run of one phase).
    pub only_phase: Option<usize>,
}

impl MissionPlan {
    /// The plan a config flies: its phases and their durations, the follow height (the
    /// landing task's IH above the take-off point); the vehicle follows the tractor where it
    /// takes off unless told where to meet it.
    pub fn for_mission(config: &MissionConfig) -> Self {
        let phases = &config.mission.phases;
        let mut plan = Self::new(
            phases.iter().map(|p| p.name.clone()).collect(),
            phases.iter().map(|p| p.duration_s).collect(),
        );
        plan.phase_kinds = config.mission.phase_kinds();
        plan.cruise_altitude_m = config
            .plugin_number("landing_guidance", "initial_altitude_m")
            .unwrap_or(algorithms::control::landing::LandingConfig::default().initial_height_m);
        let landing_phase = plan
            .landing_phase()
            .and_then(|index| phases.get(index))
            .map(|p| p.name.as_str());
        let steered = config.tasks.iter().any(|task| {
            task.plugin == "landing_guidance"
                && landing_phase.is_some_and(|landing| task.runs_in(landing))
        });
        let landing_target = config.link.as_ref().is_some_and(|l| l.landing_target);
        plan.landing = match (steered, landing_target) {
            (true, _) => LandingBy::Vision,
            (false, true) => LandingBy::AutopilotPrecision,
            (false, false) => LandingBy::Autopilot,
        };
        plan
    }

    /// A plan with our defaults for the given phases, their kinds by position.
    pub fn new(phase_names: Vec<String>, phase_durations_s: Vec<f64>) -> Self {
        let count = phase_names.len();
        Self {
            phase_kinds: (0..count)
                .map(|index| PhaseKind::by_position(index, count))
                .collect(),
            phase_names,
            phase_durations_s,
            cruise_altitude_m: 8.5,
            meeting_point_ne_m: [0.0, 0.0],
            transit_speed_m_s: 3.0,
            arrival_radius_m: 0.5,
            position_gain_per_s: 0.6,
            command_timeout_s: 30.0,
            command_retry_s: 1.0,
            offboard_preamble_s: 0.5,
            touchdown_confirm_s: 5.0,
            control: true,
            landing: LandingBy::Vision,
            only_phase: None,
        }
    }

    /// The kind of phase `index`.
    pub fn kind(&self, index: usize) -> Option<PhaseKind> {
        let count = self.phase_names.len();
        (index < count).then(|| {
            self.phase_kinds
                .get(index)
                .copied()
                .unwrap_or_else(|| PhaseKind::by_position(index, count))
        })
    }

    /// Whether phase `index` ends after its duration: a tracking phase, and in observe mode
    /// (which follows the flight without steering it) every phase but the landing.
    pub fn ends_by_duration(&self, index: usize) -> bool {
        if !self.control && self.only_phase.is_some() {
            // Observing one phase: it lasts as long as the flight.
            return false;
        }
        match self.kind(index) {
            Some(PhaseKind::Track) => true,
            Some(PhaseKind::Transit) => !self.control,
            _ => false,
        }
    }

    /// The landing phase: the last, where the config's kinds are valid.
    pub fn landing_phase(&self) -> Option<usize> {
        (0..self.phase_names.len()).rfind(|&index| self.kind(index) == Some(PhaseKind::Land))
    }
}

/// Who lands the vehicle in the mission's last phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LandingBy {
    /// The landing task steers it onto the pad with offboard setpoints.
    #[default]
    Vision,
    /// The autopilot's land mode, where the vehicle is (no camera, or no landing task).
    Autopilot,
    /// The autopilot's own precision landing on the tracker's LANDING_TARGETs (`[link]
    /// landing_target = true` and no landing task in the last phase).
    AutopilotPrecision,
}
