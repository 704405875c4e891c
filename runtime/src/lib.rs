//! The qosrt runtime: mission configuration, and (as the project grows) the scheduler, task
//! plugins, resources, clock, energy governor and MAVLink link.

pub mod catalog;
pub mod config;
pub mod diagnostic;
pub mod energy;
