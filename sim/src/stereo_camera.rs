//! The simulated downward stereo depth camera of seed 000's hybrid camera array (§2.1: a MYNT
//! EYE beside the fisheye, both looking down): per camera frame, the exact depth of the scene
//! ([`render_depth`], the renderer's own ray casting) made into what a stereo matcher delivers.
//!
//! Noise lives where a stereo camera makes it, in the disparity `d = f·B / Z` (equation 11):
//! every pixel's disparity gets Gaussian noise of `disparity_noise_px`, plus one common offset
//! per frame of `frame_disparity_noise_px` (calibration drift and vibration move the whole map;
//! averaging a window removes only the first), and the depth is `f·B / d′`. To first order the
//! depth's spread is `σ_Z = Z²·σ_d / (f·B)`: it grows with the square of the depth, as the
//! seed's Figure 16 shows. A disparity outside the matcher's search range (depth nearer than
//! `min_range_m` or beyond `max_range_m`), a random `hole_fraction` of pixels (no texture to
//! match) and the sky give no depth (NaN).
//!
//! Mounting: beside the main camera, looking along the body's down axis with the image top to
//! the body's front ([`SimCamera::pose`]); the few centimetres between them are neglected.

use std::sync::Arc;

use algorithms::camera::{CameraError as ModelError, PinholeCamera};
use algorithms::estimation::projection::Attitude;
use algorithms::vision::image::DepthImage;
use algorithms::vision::render::{render_depth, RenderError, SplitMix64};
use nalgebra::Vector3;
use thiserror::Error;

use crate::camera::SimCamera;
use crate::scene::{SceneError, SimScene};

/// Why the stereo camera cannot be built or gave no depth frame.
#[derive(Debug, Error)]
pub enum StereoCameraError {
    #[error("stereo camera image must be 8 to 4096 pixels a side, got {width_px}×{height_px}")]
    ImageSize { width_px: usize, height_px: usize },
    #[error("stereo camera setting `{name}` must be {why}, got {value}")]
    Setting {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("the vehicle pose for depth frame {frame_index} is not finite")]
    VehicleState { frame_index: u64 },
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Render(#[from] RenderError),
}

/// A depth frame as the stereo camera hands it out, numbered like the camera frame it goes with.
#[derive(Debug, Clone)]
pub struct SimDepthFrame {
    pub frame_index: u64,
    pub image: Arc<DepthImage>,
}

/// The stereo camera's geometry and noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCameraConfig {
    /// The (downsampled) depth map's size. Only its central window feeds the altitude, so a
    /// coarse map serves and costs a sixteenth of a 640 × 480 render.
    pub width_px: usize,
    pub height_px: usize,
    pub horizontal_fov_deg: f64,
    /// B of equation 11 (the seed's MYNT EYE: 120 mm).
    pub baseline_m: f64,
    /// Per-pixel disparity noise σ_d, in this map's pixels.
    pub disparity_noise_px: f64,
    /// One disparity offset per frame, σ in this map's pixels.
    pub frame_disparity_noise_px: f64,
    /// Depths nearer than this or beyond that are out of the matcher's disparity range.
    pub min_range_m: f64,
    pub max_range_m: f64,
    /// Fraction of pixels the matcher leaves empty.
    pub hole_fraction: f64,
}

impl Default for StereoCameraConfig {
    /// 160 × 120 over the main camera's 60°: f ≈ 139 px, f·B ≈ 16.6 px·m. With 0.25 px per
    /// pixel and 0.05 px per frame, one pixel's depth is ±0.85 m at 7.5 m and ±0.03 m at 1.5 m,
    /// a 21 × 21 window's mean ±0.18 m and ±0.007 m: the seed's camera measures within 1 m over
    /// 3–8 m and 0.2 m below 3 m (Figure 16), and its raw altitude wanders by tenths of a metre
    /// (Figure 13).
    fn default() -> Self {
        Self {
            width_px: 160,
            height_px: 120,
            horizontal_fov_deg: 60.0,
            baseline_m: 0.12,
            disparity_noise_px: 0.25,
            frame_disparity_noise_px: 0.05,
            min_range_m: 0.3,
            max_range_m: 20.0,
            hole_fraction: 0.02,
        }
    }
}

impl StereoCameraConfig {
    /// Checks every setting and builds the depth map's camera model.
    pub fn validate(&self) -> Result<PinholeCamera, StereoCameraError> {
        let side = 8..=4096;
        if !(side.contains(&self.width_px) && side.contains(&self.height_px)) {
            return Err(StereoCameraError::ImageSize {
                width_px: self.width_px,
                height_px: self.height_px,
            });
        }
        let setting = |name, value, why| Err(StereoCameraError::Setting { name, value, why });
        if !(self.horizontal_fov_deg > 0.0 && self.horizontal_fov_deg < 170.0) {
            return setting(
                "horizontal_fov_deg",
                self.horizontal_fov_deg,
                "within (0, 170)",
            );
        }
        for (name, value) in [
            ("baseline_m", self.baseline_m),
            ("min_range_m", self.min_range_m),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return setting(name, value, "positive and finite");
            }
        }
        for (name, value) in [
            ("disparity_noise_px", self.disparity_noise_px),
            ("frame_disparity_noise_px", self.frame_disparity_noise_px),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return setting(name, value, "finite and not negative");
            }
        }
        if self.max_range_m.is_nan() || self.max_range_m <= self.min_range_m {
            return setting("max_range_m", self.max_range_m, "above min_range_m");
        }
        if !(0.0..1.0).contains(&self.hole_fraction) {
            return setting("hole_fraction", self.hole_fraction, "within [0, 1)");
        }
        PinholeCamera::from_fov(
            self.width_px,
            self.height_px,
            self.horizontal_fov_deg.to_radians(),
        )
        .map_err(|error| match error {
            ModelError::FieldOfView { .. } => StereoCameraError::Setting {
                name: "horizontal_fov_deg",
                value: self.horizontal_fov_deg,
                why: "within (0, 170)",
            },
            _ => StereoCameraError::ImageSize {
                width_px: self.width_px,
                height_px: self.height_px,
            },
        })
    }
}

/// The stereo depth camera.
#[derive(Debug, Clone)]
pub struct SimStereoCamera {
    config: StereoCameraConfig,
    model: PinholeCamera,
    seed: u64,
}

impl SimStereoCamera {
    pub fn new(config: StereoCameraConfig, seed: u64) -> Result<Self, StereoCameraError> {
        let model = config.validate()?;
        Ok(Self {
            config,
            model,
            seed: seed ^ 0x7374_6572_656f,
        })
    }

    pub fn config(&self) -> &StereoCameraConfig {
        &self.config
    }

    /// The depth map's camera model.
    pub fn model(&self) -> &PinholeCamera {
        &self.model
    }

    /// f·B, px·m: disparity = f·B / depth.
    pub fn focal_baseline_px_m(&self) -> f64 {
        self.model.fx_px * self.config.baseline_m
    }

    /// To first order, the spread of one pixel's depth at `depth_m`: Z²·σ_d / (f·B), with σ_d
    /// the per-pixel and per-frame disparity noise together.
    pub fn depth_std_m(&self, depth_m: f64) -> f64 {
        let sigma_d = self
            .config
            .disparity_noise_px
            .hypot(self.config.frame_disparity_noise_px);
        depth_m * depth_m * sigma_d / self.focal_baseline_px_m()
    }

    /// The depth frame that goes with camera frame `frame_index`, the vehicle at
    /// `position_ned_m` with `attitude`. The noise is seeded by the camera's seed and the frame
    /// index: the same frame is the same depth map.
    pub fn capture(
        &self,
        frame_index: u64,
        position_ned_m: &Vector3<f64>,
        attitude: &Attitude,
        scene: &SimScene,
    ) -> Result<SimDepthFrame, StereoCameraError> {
        let finite = position_ned_m.iter().all(|x| x.is_finite())
            && [attitude.roll_rad, attitude.pitch_rad, attitude.yaw_rad]
                .iter()
                .all(|x| x.is_finite());
        if !finite {
            return Err(StereoCameraError::VehicleState { frame_index });
        }
        let pose = SimCamera::pose(position_ned_m, attitude);
        let visible = scene.visible_scene(&self.model, &pose)?;
        let mut depth = render_depth(&self.model, &pose, &visible)?;
        self.add_stereo_noise(&mut depth, frame_index);
        Ok(SimDepthFrame {
            frame_index,
            image: Arc::new(depth),
        })
    }

    /// Turns an exact depth map into a stereo matcher's (see the module docs).
    pub fn add_stereo_noise(&self, depth: &mut DepthImage, frame_index: u64) {
        let c = &self.config;
        let fb = self.focal_baseline_px_m();
        let (min_disparity, max_disparity) = (fb / c.max_range_m, fb / c.min_range_m);
        let mut rng = SplitMix64::new(self.seed ^ frame_index.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let frame_offset_px = c.frame_disparity_noise_px * rng.next_gaussian();
        for z in depth.data_mut() {
            let truth = f64::from(*z);
            // Draw for every pixel, valid or not, so one pixel's fate never shifts another's.
            let noise_px = c.disparity_noise_px * rng.next_gaussian();
            let hole = rng.next_f64() < c.hole_fraction;
            if hole || !(truth.is_finite() && truth > 0.0) {
                *z = f32::NAN;
                continue;
            }
            let disparity = fb / truth + frame_offset_px + noise_px;
            *z = if (min_disparity..=max_disparity).contains(&disparity) {
                (fb / disparity) as f32
            } else {
                f32::NAN
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{PadPose, TractorBody};
    use algorithms::vision::image::is_valid_depth;
    use algorithms::vision::render::Texture;

    fn flat() -> SimScene {
        SimScene::new(0).with_field_texture(Texture::uniform(0.5))
    }

    /// Mean and standard deviation of the valid pixels.
    fn stats(depth: &DepthImage) -> (f64, f64, usize) {
        let valid: Vec<f64> = depth
            .data()
            .iter()
            .filter(|z| is_valid_depth(**z))
            .map(|&z| f64::from(z))
            .collect();
        let n = valid.len() as f64;
        let mean = valid.iter().sum::<f64>() / n;
        let sd = (valid.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / n).sqrt();
        (mean, sd, valid.len())
    }

    #[test]
    fn depth_noise_grows_with_the_square_of_the_depth() {
        // A level camera over flat ground sees one depth, its height, in every pixel: the
        // spread over a frame is the per-pixel noise, σ_Z = Z²·σ_d / (f·B).
        let config = StereoCameraConfig {
            frame_disparity_noise_px: 0.0,
            hole_fraction: 0.0,
            ..StereoCameraConfig::default()
        };
        let camera = SimStereoCamera::new(config, 9).unwrap();
        let fb = camera.focal_baseline_px_m();
        assert!((fb - 0.12 * 80.0 / 30f64.to_radians().tan()).abs() < 1e-9);
        let mut spreads = Vec::new();
        for height_m in [1.5, 3.0, 6.0] {
            let frame = camera
                .capture(
                    3,
                    &Vector3::new(0.0, 0.0, -height_m),
                    &Attitude::default(),
                    &flat(),
                )
                .unwrap();
            let (mean, sd, valid) = stats(&frame.image);
            assert_eq!(valid, 160 * 120);
            let expected_sd = height_m * height_m * 0.25 / fb;
            assert!(
                (sd - expected_sd).abs() < 0.06 * expected_sd,
                "at {height_m} m: sd {sd} vs {expected_sd}"
            );
            // f·B / (d + n) is biased by about Z·(σ_Z/Z)²: small, and it is there.
            assert!(
                (mean - height_m).abs() < 0.02 * height_m,
                "at {height_m} m: mean {mean}"
            );
            spreads.push(sd);
        }
        // Doubling the depth quadruples the spread.
        assert!((spreads[1] / spreads[0] - 4.0).abs() < 0.4, "{spreads:?}");
        assert!((spreads[2] / spreads[1] - 4.0).abs() < 0.4, "{spreads:?}");
    }

    #[test]
    fn the_frame_offset_moves_the_whole_map_and_is_seeded() {
        let config = StereoCameraConfig {
            disparity_noise_px: 0.0,
            frame_disparity_noise_px: 0.2,
            hole_fraction: 0.0,
            ..StereoCameraConfig::default()
        };
        let camera = SimStereoCamera::new(config, 1).unwrap();
        let at = Vector3::new(0.0, 0.0, -6.0);
        let means: Vec<f64> = (0..200)
            .map(|k| {
                let frame = camera
                    .capture(k, &at, &Attitude::default(), &flat())
                    .unwrap();
                let (mean, sd, _) = stats(&frame.image);
                // No per-pixel noise: the frame is one depth.
                assert!(sd < 1e-4, "{sd}");
                mean
            })
            .collect();
        let n = means.len() as f64;
        let mean = means.iter().sum::<f64>() / n;
        let sd = (means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / n).sqrt();
        let expected = 36.0 * 0.2 / camera.focal_baseline_px_m();
        assert!(
            (sd - expected).abs() < 0.15 * expected,
            "{sd} vs {expected}"
        );
        let again = camera
            .capture(7, &at, &Attitude::default(), &flat())
            .unwrap();
        assert_eq!(stats(&again.image).0, means[7], "seeded by the frame index");
    }

    #[test]
    fn the_pad_is_nearer_than_the_ground_and_range_limits_and_holes_leave_nan() {
        let scene = flat()
            .with_tractor_body(TractorBody::default())
            .unwrap()
            .with_pad(PadPose {
                north_m: 0.0,
                east_m: 0.0,
                height_m: 1.0,
                yaw_rad: 0.3,
            })
            .unwrap();
        let config = StereoCameraConfig {
            disparity_noise_px: 0.0,
            frame_disparity_noise_px: 0.0,
            hole_fraction: 0.1,
            max_range_m: 7.0,
            ..StereoCameraConfig::default()
        };
        let camera = SimStereoCamera::new(config, 2).unwrap();
        let frame = camera
            .capture(
                0,
                &Vector3::new(0.0, 0.0, -7.5),
                &Attitude::default(),
                &scene,
            )
            .unwrap();
        let depth = &frame.image;
        // The centre looks at the tractor's roof 6.5 m below; the corners at the ground 7.5 m
        // below, beyond the 7 m range: no depth there.
        let centre: Vec<f32> = (55..65)
            .flat_map(|y| (75..85).map(move |x| (x, y)))
            .map(|(x, y)| depth.get(x, y))
            .filter(|z| is_valid_depth(*z))
            .collect();
        assert!(centre.len() >= 80, "{} valid of 100", centre.len());
        assert!(centre.iter().all(|z| (z - 6.5).abs() < 1e-4));
        assert!((0..10).all(|y| (0..10).all(|x| depth.get(x, y).is_nan())));
        // About a tenth of the roof's pixels are holes.
        let holes = (50..70)
            .flat_map(|y| (70..90).map(move |x| (x, y)))
            .filter(|&(x, y)| depth.get(x, y).is_nan())
            .count();
        assert!((20..=65).contains(&holes), "{holes} holes of 400");
    }

    #[test]
    fn bad_settings_and_poses_are_named_errors() {
        let bad = |change: fn(&mut StereoCameraConfig)| {
            let mut config = StereoCameraConfig::default();
            change(&mut config);
            SimStereoCamera::new(config, 0).unwrap_err()
        };
        assert!(matches!(
            bad(|c| c.width_px = 2),
            StereoCameraError::ImageSize { .. }
        ));
        assert!(matches!(
            bad(|c| c.baseline_m = 0.0),
            StereoCameraError::Setting {
                name: "baseline_m",
                ..
            }
        ));
        assert!(matches!(
            bad(|c| c.disparity_noise_px = f64::NAN),
            StereoCameraError::Setting {
                name: "disparity_noise_px",
                ..
            }
        ));
        assert!(matches!(
            bad(|c| c.max_range_m = 0.1),
            StereoCameraError::Setting {
                name: "max_range_m",
                ..
            }
        ));
        assert!(matches!(
            bad(|c| c.hole_fraction = 1.0),
            StereoCameraError::Setting {
                name: "hole_fraction",
                ..
            }
        ));
        let camera = SimStereoCamera::new(StereoCameraConfig::default(), 0).unwrap();
        assert!(matches!(
            camera.capture(
                4,
                &Vector3::new(f64::NAN, 0.0, -3.0),
                &Attitude::default(),
                &flat()
            ),
            Err(StereoCameraError::VehicleState { frame_index: 4 })
        ));
    }
}
