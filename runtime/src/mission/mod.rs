//! The mission: the sequencer (what to command, which phase flies), the runner (the one loop
//! that joins link, governor, camera, scheduler and sequencer, onboard and in simulation) and
//! what a run logs.

pub mod input_rates;
pub mod observer;
pub mod replay;
pub mod report;
pub mod runner;
pub mod sequencer;

pub use crate::governor::GovernorDecision;
pub use observer::{
    MissionObserver, PlanAnswer, PlanForecast, PlanRequest, PlannedPhase, VehicleStatus,
    PLAN_CHANGE_KEYS,
};
pub use replay::{replay, ChannelDiff, ReplayError, ReplayOptions, ReplayReport};
pub use report::MissionLog;
pub use runner::{describe_mission, MissionRunner, RunnerError, RunnerOptions, StepReport};
pub use sequencer::{
    AutopilotView, LandingBy, MissionEvent, MissionPlan, MissionSequencer, MissionStatus,
    SequencerInput,
};

#[cfg(test)]
mod tests;
