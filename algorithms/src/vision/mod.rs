//! Vision: images, camera models, the marker renderer and the landing-marker detectors.

pub mod aruco;
pub mod camera;
pub mod features;
pub mod homography;
pub mod image;
pub mod landing_marker;
pub mod nfold;
pub mod render;
pub mod rgb;
pub mod yolo;
