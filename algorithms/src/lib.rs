//! Pure computation for the mission, no I/O and no async: camera models, vision, estimation,
//! control, tracking, stereo and the hazard CNN.

pub mod camera;
pub mod control;
pub mod estimation;
pub mod stereo;
pub mod tracking;
pub mod vision;
