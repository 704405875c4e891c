//! Estimation: the pad's position from a pixel, the relative-position Kalman tracker and the
//! platform's velocity (seed 003, §IV-A and §IV-B), and seed 000's hybrid-camera UGV state
//! estimation (§2.2).

pub mod attitude_history;
pub mod camera_mount;
pub mod hybrid_tracking;
pub mod kalman;
pub mod pad_height;
pub mod platform_velocity;
pub mod projection;
pub mod stereo_altitude;
pub mod velocity_observer;
