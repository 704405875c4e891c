//! Vision: images, the marker renderer and the landing-marker detectors (the camera models are
//! [`crate::camera`]).

pub mod aruco;
pub mod features;
pub mod homography;
pub mod image;
pub mod landing_marker;
pub mod nfold;
pub mod render;
pub mod rgb;
pub mod yolo;
