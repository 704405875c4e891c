//! Vision: images, camera models, the marker renderer and the landing-marker detectors.

pub mod aruco;
pub mod camera;
pub mod image;
pub mod landing_marker;
pub mod nfold;
pub mod render;
pub mod yolo;
