//! Power models, battery and the offline QoS planner: pure computation, no I/O beyond parsing
//! the text handed in.

pub mod battery;
pub mod grid;
pub mod planner;
pub mod profile;
