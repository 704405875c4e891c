//! The built-in simulator: multirotor, tractor, wind, battery, downward camera and a MAVLink
//! autopilot, speaking to the runtime only through MAVLink and camera frames.

pub mod autopilot;
pub mod camera;
pub mod flight;
pub mod hazard_dataset;
pub mod hazard_score;
pub mod mission;
pub mod outcome;
pub mod power;
pub mod scene;
pub mod stereo_camera;
pub mod tractor;
pub mod vehicle;
pub mod wind;
