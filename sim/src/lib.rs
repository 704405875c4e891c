//! The built-in simulator: multirotor, tractor, wind, battery, downward camera and a MAVLink
//! autopilot, speaking to the runtime only through MAVLink and camera frames.

pub mod flight;
pub mod scene;
pub mod camera;
pub mod power;
pub mod outcome;
