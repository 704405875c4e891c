//! The qosrt runtime: mission configuration, and (as the project grows) the scheduler, task
//! plugins, resources, clock, energy governor and MAVLink link.

pub mod bus;
pub mod camera;
pub mod catalog;
pub mod clock;
pub mod config;
pub mod dataflow;
pub mod diagnostic;
pub mod dry_run;
pub mod energy;
pub mod governor;
pub mod inference;
pub mod link;
pub mod mission;
pub mod plugins;
pub mod power_meter;
pub mod profile_sweep;
pub mod record;
pub mod registry;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod scheduler;
pub mod task;
pub mod telemetry;
pub mod topics;
