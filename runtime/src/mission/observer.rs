//! Who else hears what the mission does, beside its recording: the ROS 2 node, a ground
//! station's link. The runner calls each observer as things happen; an observer only queues
//! (its own thread publishes), so the loop does not wait on it.

use crate::governor::GovernorDecision;
use crate::record::recorder::QosLevels;
use crate::scheduler::TaskStats;
use crate::telemetry::BatteryTelemetry;
use crate::topics::VehicleState;
use nalgebra::Vector3;

/// What the mission tells its observers. Each has a default that ignores it.
pub trait MissionObserver: Send {
    /// The vehicle's state, as the autopilot reported it.
    fn vehicle(&self, _time_s: f64, _state: &VehicleState) {}
    /// A battery reading.
    fn battery(&self, _telemetry: &BatteryTelemetry) {}
    /// A velocity setpoint sent to the autopilot (NED).
    fn velocity_setpoint(&self, _time_s: f64, _velocity_ned_m_s: &Vector3<f64>) {}
    /// A phase began (`None`: the mission is over).
    fn phase(&self, _time_s: f64, _phase: Option<&str>) {}
    /// A decision of the governor, with its reason.
    fn governor(&self, _decision: &GovernorDecision) {}
    /// Every task's level and statistics: when a level changes, and once a second.
    fn tasks(&self, _time_s: f64, _levels: &QosLevels, _stats: &[TaskStats]) {}
}
