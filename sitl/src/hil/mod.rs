//! The world as the physics backend of a real autopilot, the way Gazebo, jMAVSim and Webots
//! are: PX4 over its HIL MAVLink interface (TCP 4560+i), ArduPilot over its JSON interface
//! (UDP 9002+10i). Each exchange is lockstep: the autopilot's clock is the world's.

pub mod ardupilot_json;
pub mod gimbal_device;
pub mod px4;
