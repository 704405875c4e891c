//! Software in the loop: the harness that couples the simulated world (`sim`, which knows
//! nothing of the runtime) to the qosrt runtime's mission runner. The world speaks to the
//! runtime only as a real vehicle does: MAVLink over UDP and camera frames.
//!
//! [`mission::simulate`] flies one mission in lockstep: a virtual clock advanced tick by tick
//! with the world, deterministic for a seed and faster than real time. [`serve::serve`] runs
//! the world alone on the wall clock, for a runtime in another process (`qosrt sim --serve`).

pub mod hil;
pub mod mission;
pub mod outcome;
pub mod px4_sih;
pub mod score;
pub mod serve;
#[cfg(feature = "gstreamer")]
pub mod video_out;
