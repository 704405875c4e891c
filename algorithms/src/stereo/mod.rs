//! The ground-based long-baseline stereo system of seed 001: two pan-tilt units (PTUs) on either
//! side of the runway, each carrying a long-focus camera that tracks the landing aircraft; the
//! aircraft's position is where their lines of sight (nearly) meet.
//!
//! - [`triangulation`]: lines of sight from PTU angles and the target's pixel offset (Eq. 5),
//!   the closed form of Eq. 6, the common perpendicular of two skew lines (Eqs. 8–14) and the
//!   stereo rig's placement on the runway.
//! - [`error_analysis`]: the error of a disturbed line of sight (§4.1–4.2): Tables 1 and 2, the
//!   partial derivatives of Eq. 7 and the error fields of Figures 8–10.
//! - [`bbp`]: bounding-box prediction with PTU rotation compensation (§4.3).
//! - [`approach`]: a scripted fixed-wing approach that produces the PTU readings the system would
//!   see, and the per-interval errors of Table 5.
//!
//! # The stereo frame (the seed's, §3.2 and Eq. 9)
//!
//! Origin at the left PTU's rotation centre (the camera's optical centre is taken to coincide with
//! it); X along the baseline towards the right PTU, which stands at (D, 0, 0); Y horizontal, out
//! along the runway towards the approaching aircraft (the optical axes at zero pan and tilt); Z up.
//! A line of sight with pan ψ and tilt ϕ has the direction (cos ϕ sin ψ, cos ϕ cos ψ, sin ϕ)
//! (Eq. 9): pan turns from +Y towards +X, tilt raises the line above the horizon. Seen from above,
//! positive pan is clockwise; the seed's text calls it counterclockwise, but its Eqs. 6 and 9,
//! and its tables, follow the direction above, so this module does too.

pub mod approach;
pub mod bbp;
pub mod error_analysis;
pub mod triangulation;
