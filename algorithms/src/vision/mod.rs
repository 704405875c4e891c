//! Vision: images, camera models, the marker renderer and the landing-marker detectors.

pub mod image;
