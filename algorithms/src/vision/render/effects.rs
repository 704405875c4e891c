//! What happens to a rendered image on its way out of the camera: blur (optics), contrast and
//! brightness (exposure), noise (sensor); and the seeded generator behind the noise and the
//! textures.

use std::f64::consts::PI;

use super::RenderError;
use crate::vision::image::GrayImage;

/// Blur along a straight line, as a camera moving during the exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionBlur {
    pub length_px: f64,
    /// Direction of motion in the image, from the u axis towards v.
    pub angle_rad: f64,
}

/// Image effects, applied in the order optics (blur), exposure (contrast, brightness), sensor (noise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageEffects {
    /// Standard deviation of a Gaussian blur; 0 for none.
    pub gaussian_blur_sigma_px: f64,
    pub motion_blur: Option<MotionBlur>,
    /// Scales intensity about mid-grey: I′ = contrast·(I − ½) + ½ + brightness (I in [0, 1]).
    pub contrast: f64,
    /// Added intensity, in [0, 1] units.
    pub brightness: f64,
    /// Standard deviation of additive Gaussian noise, grey levels (0–255).
    pub noise_sigma: f64,
    pub noise_seed: u64,
}

impl Default for ImageEffects {
    fn default() -> Self {
        Self {
            gaussian_blur_sigma_px: 0.0,
            motion_blur: None,
            contrast: 1.0,
            brightness: 0.0,
            noise_sigma: 0.0,
            noise_seed: 0,
        }
    }
}

impl ImageEffects {
    pub(super) fn validate(&self) -> Result<(), RenderError> {
        let mut checks = vec![
            ("gaussian_blur_sigma_px", self.gaussian_blur_sigma_px),
            ("noise_sigma", self.noise_sigma),
        ];
        if let Some(m) = self.motion_blur {
            checks.push(("motion_blur.length_px", m.length_px));
            if !m.angle_rad.is_finite() {
                return Err(RenderError::Effect {
                    name: "motion_blur.angle_rad",
                    value: m.angle_rad,
                });
            }
        }
        for (name, value) in checks {
            if !(value.is_finite() && value >= 0.0) {
                return Err(RenderError::Effect { name, value });
            }
        }
        for (name, value) in [("contrast", self.contrast), ("brightness", self.brightness)] {
            if !value.is_finite() {
                return Err(RenderError::Effect { name, value });
            }
        }
        Ok(())
    }
}

/// Applies `effects` to an existing image.
pub fn apply_effects(image: &GrayImage, effects: &ImageEffects) -> Result<GrayImage, RenderError> {
    effects.validate()?;
    let pixels = image.data().iter().map(|&p| p as f32 / 255.0).collect();
    finish(pixels, image.width(), image.height(), effects)
}

/// Blur, exposure and noise on intensities in [0, 1], then 8-bit quantisation.
/// Intensities (0 black to 1 white) to a grey image, with the effects.
pub fn finish(
    mut pixels: Vec<f32>,
    width: usize,
    height: usize,
    effects: &ImageEffects,
) -> Result<GrayImage, RenderError> {
    effects.validate()?;
    if effects.gaussian_blur_sigma_px > 0.0 {
        gaussian_blur(&mut pixels, width, height, effects.gaussian_blur_sigma_px);
    }
    if let Some(m) = effects.motion_blur {
        if m.length_px > 0.0 {
            pixels = motion_blur(&pixels, width, height, m);
        }
    }
    let contrast = effects.contrast as f32;
    let brightness = effects.brightness as f32;
    let mut rng = SplitMix64::new(effects.noise_seed);
    let noise = effects.noise_sigma as f32;
    let data = pixels
        .iter()
        .map(|&p| {
            let mut level = (contrast * (p - 0.5) + 0.5 + brightness) * 255.0;
            if noise > 0.0 {
                level += noise * rng.next_gaussian() as f32;
            }
            // Round half up after clamping (no libm call).
            (level.clamp(0.0, 255.0) + 0.5) as u8
        })
        .collect();
    Ok(GrayImage::from_vec(width, height, data)?)
}

/// Separable Gaussian blur, edges clamped.
fn gaussian_blur(pixels: &mut [f32], width: usize, height: usize, sigma_px: f64) {
    let radius = (3.0 * sigma_px).ceil().max(1.0) as usize;
    let mut taps: Vec<f32> = (0..=2 * radius)
        .map(|i| {
            let d = i as f64 - radius as f64;
            (-(d * d) / (2.0 * sigma_px * sigma_px)).exp() as f32
        })
        .collect();
    let total: f32 = taps.iter().sum();
    taps.iter_mut().for_each(|t| *t /= total);
    let mut tmp = vec![0f32; pixels.len()];
    for y in 0..height {
        let row = &pixels[y * width..(y + 1) * width];
        for x in 0..width {
            let mut acc = 0f32;
            for (i, t) in taps.iter().enumerate() {
                let xs = (x + i).saturating_sub(radius).min(width - 1);
                acc += t * row[xs];
            }
            tmp[y * width + x] = acc;
        }
    }
    for y in 0..height {
        for x in 0..width {
            let mut acc = 0f32;
            for (i, t) in taps.iter().enumerate() {
                let ys = (y + i).saturating_sub(radius).min(height - 1);
                acc += t * tmp[ys * width + x];
            }
            pixels[y * width + x] = acc;
        }
    }
}

/// Mean along a centred segment of the motion, sampled bilinearly about every half pixel.
fn motion_blur(pixels: &[f32], width: usize, height: usize, blur: MotionBlur) -> Vec<f32> {
    let steps = (2.0 * blur.length_px).ceil().max(1.0) as usize + 1;
    let (sin, cos) = blur.angle_rad.sin_cos();
    let offsets: Vec<(f64, f64)> = (0..steps)
        .map(|k| {
            let s = (k as f64 / (steps - 1) as f64 - 0.5) * blur.length_px;
            (s * cos, s * sin)
        })
        .collect();
    let at = |x: f64, y: f64| -> f32 {
        let x = x.clamp(0.0, (width - 1) as f64);
        let y = y.clamp(0.0, (height - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let top = pixels[y0 * width + x0] * (1.0 - fx) + pixels[y0 * width + x1] * fx;
        let bottom = pixels[y1 * width + x0] * (1.0 - fx) + pixels[y1 * width + x1] * fx;
        top * (1.0 - fy) + bottom * fy
    };
    let mut out = vec![0f32; pixels.len()];
    for y in 0..height {
        for x in 0..width {
            let sum: f32 = offsets
                .iter()
                .map(|&(dx, dy)| at(x as f64 + dx, y as f64 + dy))
                .sum();
            out[y * width + x] = sum / steps as f32;
        }
    }
    out
}

/// SplitMix64: a small, seedable generator, so the crate needs no random-number dependency.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitMix64 {
    state: u64,
    spare_gaussian: Option<f64>,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self {
            state: seed,
            spare_gaussian: None,
        }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    pub fn next_gaussian(&mut self) -> f64 {
        if let Some(z) = self.spare_gaussian.take() {
            return z;
        }
        let u1 = 1.0 - self.next_f64(); // (0, 1]: ln stays finite
        let u2 = self.next_f64();
        let radius = (-2.0 * u1.ln()).sqrt();
        let (sin, cos) = (2.0 * PI * u2).sin_cos();
        self.spare_gaussian = Some(radius * sin);
        radius * cos
    }
}
