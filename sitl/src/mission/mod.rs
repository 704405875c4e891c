//! One simulated mission: the world (vehicle, tractor, wind, camera, pack) and the runtime's
//! mission runner (the configured task plugins on the virtual-time scheduler, the governor, the
//! mission sequencer), joined only by MAVLink over UDP on the loopback and by camera frames.
//!
//! Time advances in ticks of [`TICK_S`] (50 Hz, the rate at which PX4 streams attitude and
//! position); physics integrates at [`PHYSICS_DT_S`] inside a tick. Each tick, in lockstep:
//! the autopilot sends its telemetry ending in a TIMESYNC; the runtime's link reads up to that
//! barrier; the camera renders if a consumer will look; the runtime's tasks run up to the
//! tick; the sequencer's commands go back over the link, again up to a barrier; the autopilot
//! applies them; physics moves on. Nothing depends on the host's speed, so the same config and
//! seed fly the same mission.

use crate::outcome::SimOutcome;
use algorithms::vision::render::SplitMix64;
use runtime::config::{Mission, PhaseKind};
use runtime::energy::MissionModel;
use runtime::mission::MissionPlan;
use runtime::record::{ConfigFile, RecordError, RecorderOptions};
use runtime::registry::PluginRegistry;
use sim::camera::SimCameraConfig;
use sim::gimbal::{Gimbal, GimbalError, GimbalParams};
use sim::power::RotorPowerModel;
use sim::realism::CameraRealism;
use sim::scene::{PadOccluder, PadPose, TrackScatterConfig};
use sim::stereo_camera::StereoCameraConfig;
use sim::tractor::Tractor;
use sim::wind::Wind;
use sim::world::WorldOptions;
use std::time::Instant;

mod autopilot;
mod camera_feed;
mod flyer;
mod harness;
mod options;
mod world;

pub use autopilot::{
    AutopilotKind, AutopilotProcess, RealAutopilot, RealVehicle, REAL_AUTOPILOT_READY_S,
};
pub(crate) use autopilot::{CameraGimbal, GimballedVehicle};
use harness::Harness;
pub use options::*;
pub use world::*;

/// Flies one mission.
pub fn simulate(
    model: &MissionModel,
    registry: &PluginRegistry,
    options: &SimOptions,
) -> Result<SimOutcome, SimError> {
    let wall_start = Instant::now();
    let mut harness = Harness::build(model, registry, options)?;
    let end_s = harness.fly()?;
    harness.finish(end_s, wall_start)
}

/// The summed duration of the mission's phases whose kind `counts`.
fn phases_duration_s(mission: &Mission, counts: impl Fn(PhaseKind) -> bool) -> f64 {
    mission
        .phases
        .iter()
        .zip(mission.phase_kinds())
        .filter(|&(_, kind)| counts(kind))
        .map(|(phase, _)| phase.duration_s)
        .sum()
}
