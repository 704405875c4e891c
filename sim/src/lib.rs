//! The built-in simulator's world: multirotor, tractor, wind, battery, downward camera and a
//! PX4-like MAVLink autopilot. It knows nothing of the runtime: like a real vehicle it speaks
//! MAVLink and hands out camera frames; the `sitl` crate couples it to the runtime.

pub mod autopilot;
pub mod camera;
pub mod estimate;
pub mod flight;
pub mod gimbal;
pub mod hazard_dataset;
pub mod power;
pub mod quadrotor;
pub mod realism;
pub mod scene;
pub mod sensors;
pub mod stereo_camera;
pub mod tractor;
pub mod vehicle;
pub mod wind;
pub mod world;
