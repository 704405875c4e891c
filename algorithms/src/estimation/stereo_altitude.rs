//! Flight altitude from the downward stereo camera (seed 000, §2.2.3, equations 11–14): depth
//! from disparity, the mean depth of a central window as the altitude, and a two-state Kalman
//! filter on altitude and its rate to take out the vibration noise.
//!
//! Equation 12 averages over the whole window; a real depth map has holes (no texture, occlusion),
//! so we average over the window's *valid* pixels and refuse a window with too few of them.
//! Equations 13–14 are written per frame (A = [1 1; 0 1]); we use A = [1 dt; 0 1] with the rate
//! in metres per second, which is the same filter at a fixed frame interval and stays right when
//! frames are dropped.

use nalgebra::{Matrix2, Vector2};
use thiserror::Error;

use crate::vision::image::FrameError;
/// The depth image lives with the other images; re-exported here, where it is read.
pub use crate::vision::image::{is_valid_depth, DepthImage};

/// Depth data or a filter that cannot be used as given.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum StereoAltitudeError {
    #[error("depth image: {0}")]
    Frame(#[from] FrameError),
    #[error(
        "stereo focal length {focal_px} px and baseline {baseline_m} m must be positive and finite"
    )]
    Stereo { focal_px: f64, baseline_m: f64 },
    #[error("altitude setting {name} must be {why}, got {value}")]
    Config {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error(
        "only {valid} of the {window} pixels of the central window hold a valid depth, {needed} \
         are needed (ground out of the stereo range, or no texture)"
    )]
    TooFewValid {
        valid: usize,
        window: usize,
        needed: usize,
    },
    #[error("the altitude measurement {altitude_m} m or its time {time_s} s is not usable")]
    Measurement { altitude_m: f64, time_s: f64 },
    #[error("time must advance: {time_s} s is not after the last measurement at {last_s} s")]
    TimeNotAdvancing { time_s: f64, last_s: f64 },
}

impl DepthImage {
    /// Equation 11: `Z = f·Tx / d` from a disparity map (pixels); a disparity that is not
    /// positive and finite gives no depth.
    pub fn from_disparity(
        width: usize,
        height: usize,
        disparity_px: &[f32],
        focal_px: f64,
        baseline_m: f64,
    ) -> Result<Self, StereoAltitudeError> {
        if !(focal_px.is_finite() && focal_px > 0.0 && baseline_m.is_finite() && baseline_m > 0.0) {
            return Err(StereoAltitudeError::Stereo {
                focal_px,
                baseline_m,
            });
        }
        let depth = disparity_px
            .iter()
            .map(|&d| {
                if d.is_finite() && d > 0.0 {
                    (focal_px * baseline_m / d as f64) as f32
                } else {
                    f32::NAN
                }
            })
            .collect();
        Ok(Self::from_vec(width, height, depth)?)
    }
}

/// The central window of equation 12 and what makes it usable.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AltitudeWindow {
    /// Window size M × N, pixels, centred on the image (clipped to it).
    pub width_px: usize,
    pub height_px: usize,
    /// Fewer valid pixels than this fraction of the window is an error (default 0.3).
    pub min_valid_fraction: f64,
    /// Depths outside [min, max] are treated as invalid (the stereo camera's range; the seed's
    /// MYNT EYE measures about 0.7–8 m). Defaults 0 and ∞.
    pub min_depth_m: f64,
    pub max_depth_m: f64,
}

impl Default for AltitudeWindow {
    fn default() -> Self {
        Self {
            width_px: 64,
            height_px: 64,
            min_valid_fraction: 0.3,
            min_depth_m: 0.0,
            max_depth_m: f64::INFINITY,
        }
    }
}

/// One altitude measurement from a depth image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AltitudeSample {
    pub altitude_m: f64,
    /// Valid pixels averaged.
    pub valid_px: usize,
    /// Pixels in the (clipped) window.
    pub window_px: usize,
}

/// Equation 12: the mean valid depth over the central window, as the flight altitude (the
/// stereo camera looks straight down).
pub fn central_window_altitude(
    depth: &DepthImage,
    window: &AltitudeWindow,
) -> Result<AltitudeSample, StereoAltitudeError> {
    let config = |name, value, why| Err(StereoAltitudeError::Config { name, value, why });
    if window.width_px == 0 || window.height_px == 0 {
        return config("window size", 0.0, "at least 1×1 px");
    }
    if !(0.0..=1.0).contains(&window.min_valid_fraction) {
        return config("min_valid_fraction", window.min_valid_fraction, "in [0, 1]");
    }
    if window.min_depth_m.is_nan()
        || window.max_depth_m.is_nan()
        || window.min_depth_m > window.max_depth_m
    {
        return config("min_depth_m..max_depth_m", window.min_depth_m, "a range");
    }
    let w = window.width_px.min(depth.width());
    let h = window.height_px.min(depth.height());
    let (x0, y0) = ((depth.width() - w) / 2, (depth.height() - h) / 2);
    let (mut sum, mut valid) = (0.0f64, 0usize);
    for y in y0..y0 + h {
        for &z in &depth.row(y)[x0..x0 + w] {
            let z64 = z as f64;
            if is_valid_depth(z) && z64 >= window.min_depth_m && z64 <= window.max_depth_m {
                sum += z64;
                valid += 1;
            }
        }
    }
    let window_px = w * h;
    let needed = ((window.min_valid_fraction * window_px as f64).ceil() as usize).max(1);
    if valid < needed {
        return Err(StereoAltitudeError::TooFewValid {
            valid,
            window: window_px,
            needed,
        });
    }
    Ok(AltitudeSample {
        altitude_m: sum / valid as f64,
        valid_px: valid,
        window_px,
    })
}

/// Noise levels of the altitude filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AltitudeFilterConfig {
    /// Standard deviation of one altitude measurement (vibration, stereo noise), metres.
    pub measurement_std_m: f64,
    /// Process noise on the altitude: variance added per second, m²/s.
    pub altitude_process_noise_m2_per_s: f64,
    /// Process noise on the rate: variance added per second, (m/s)²/s.
    pub rate_process_noise_m2_per_s3: f64,
    /// Uncertainty of the rate when the filter starts, m/s.
    pub initial_rate_std_m_s: f64,
    /// After a longer gap between measurements the filter restarts from the next one, seconds.
    pub max_gap_s: f64,
}

impl Default for AltitudeFilterConfig {
    fn default() -> Self {
        Self {
            measurement_std_m: 0.1,
            altitude_process_noise_m2_per_s: 1e-3,
            rate_process_noise_m2_per_s3: 0.5,
            initial_rate_std_m_s: 1.0,
            max_gap_s: 1.0,
        }
    }
}

impl AltitudeFilterConfig {
    pub fn validate(&self) -> Result<(), StereoAltitudeError> {
        for (name, value) in [
            ("measurement_std_m", self.measurement_std_m),
            (
                "altitude_process_noise_m2_per_s",
                self.altitude_process_noise_m2_per_s,
            ),
            (
                "rate_process_noise_m2_per_s3",
                self.rate_process_noise_m2_per_s3,
            ),
            ("initial_rate_std_m_s", self.initial_rate_std_m_s),
            ("max_gap_s", self.max_gap_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(StereoAltitudeError::Config {
                    name,
                    value,
                    why: "positive and finite",
                });
            }
        }
        Ok(())
    }
}

/// The filtered altitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AltitudeEstimate {
    pub time_s: f64,
    /// Height above the ground below, metres (d_k).
    pub altitude_m: f64,
    /// Rate of change of the altitude, m/s, positive climbing (Δd_k per second); the NED down
    /// velocity is its negative.
    pub altitude_rate_m_s: f64,
    pub altitude_std_m: f64,
}

/// The two-state Kalman filter of equations 13–14: x = [d, ḋ], x_k = A x_{k−1} + ω,
/// z_k = H x_k + ν with z = [Z, ΔZ/dt], H = I.
#[derive(Debug, Clone)]
pub struct AltitudeFilter {
    config: AltitudeFilterConfig,
    state: Option<FilterState>,
}

#[derive(Debug, Clone, Copy)]
struct FilterState {
    time_s: f64,
    x: Vector2<f64>,
    p: Matrix2<f64>,
    last_measurement_m: f64,
}

impl FilterState {
    fn estimate(&self) -> AltitudeEstimate {
        AltitudeEstimate {
            time_s: self.time_s,
            altitude_m: self.x[0],
            altitude_rate_m_s: self.x[1],
            altitude_std_m: self.p[(0, 0)].sqrt(),
        }
    }
}

impl AltitudeFilter {
    pub fn new(config: AltitudeFilterConfig) -> Result<Self, StereoAltitudeError> {
        config.validate()?;
        Ok(Self {
            config,
            state: None,
        })
    }

    /// The latest estimate; `None` before the first measurement.
    pub fn estimate(&self) -> Option<AltitudeEstimate> {
        self.state.as_ref().map(FilterState::estimate)
    }

    pub fn reset(&mut self) {
        self.state = None;
    }

    /// Takes the altitude Z measured at `time_s` (e.g. [`central_window_altitude`]): predicts
    /// with A, then corrects with z = [Z, (Z − Z_prev)/dt].
    pub fn update(
        &mut self,
        time_s: f64,
        altitude_m: f64,
    ) -> Result<AltitudeEstimate, StereoAltitudeError> {
        if !(time_s.is_finite() && altitude_m.is_finite() && altitude_m > 0.0) {
            return Err(StereoAltitudeError::Measurement { altitude_m, time_s });
        }
        let sigma2 = self.config.measurement_std_m.powi(2);
        let restart = match self.state {
            None => true,
            Some(s) if time_s <= s.time_s => {
                return Err(StereoAltitudeError::TimeNotAdvancing {
                    time_s,
                    last_s: s.time_s,
                })
            }
            Some(s) => time_s - s.time_s > self.config.max_gap_s,
        };
        let Some(mut s) = self.state.filter(|_| !restart) else {
            let start = FilterState {
                time_s,
                x: Vector2::new(altitude_m, 0.0),
                p: Matrix2::new(sigma2, 0.0, 0.0, self.config.initial_rate_std_m_s.powi(2)),
                last_measurement_m: altitude_m,
            };
            self.state = Some(start);
            return Ok(start.estimate());
        };
        let dt = time_s - s.time_s;
        // Equation 13: prediction.
        let a = Matrix2::new(1.0, dt, 0.0, 1.0);
        let q = Matrix2::new(
            self.config.altitude_process_noise_m2_per_s,
            0.0,
            0.0,
            self.config.rate_process_noise_m2_per_s3,
        ) * dt;
        s.x = a * s.x;
        s.p = a * s.p * a.transpose() + q;
        // Equation 14 with H = I: the altitude and its finite-difference rate. The difference of
        // two noisy altitudes has variance 2σ²/dt² and covariance σ²/dt with the newer one.
        let z = Vector2::new(altitude_m, (altitude_m - s.last_measurement_m) / dt);
        let r = Matrix2::new(sigma2, sigma2 / dt, sigma2 / dt, 2.0 * sigma2 / (dt * dt));
        let innovation_cov = s.p + r;
        if let Some(inv) = innovation_cov.try_inverse() {
            let k = s.p * inv;
            s.x += k * (z - s.x);
            let i_k = Matrix2::identity() - k;
            s.p = i_k * s.p * i_k.transpose() + k * r * k.transpose();
        }
        s.time_s = time_s;
        s.last_measurement_m = altitude_m;
        self.state = Some(s);
        Ok(s.estimate())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::render::SplitMix64;

    #[test]
    fn depth_follows_equation_11() {
        // f = 400 px, Tx = 0.12 m: 8 px of disparity is 6 m, 48 px is 1 m.
        let depth =
            DepthImage::from_disparity(2, 2, &[8.0, 48.0, 0.0, f32::NAN], 400.0, 0.12).unwrap();
        assert!((depth.get(0, 0) - 6.0).abs() < 1e-6);
        assert!((depth.get(1, 0) - 1.0).abs() < 1e-6);
        assert!(!is_valid_depth(depth.get(0, 1)) && !is_valid_depth(depth.get(1, 1)));
        assert!(matches!(
            DepthImage::from_disparity(1, 1, &[1.0], 0.0, 0.1),
            Err(StereoAltitudeError::Stereo { .. })
        ));
        assert!(matches!(
            DepthImage::from_disparity(3, 2, &[1.0; 5], 400.0, 0.12),
            Err(StereoAltitudeError::Frame(FrameError::DepthLength {
                needed: 6,
                found: 5,
                ..
            }))
        ));
    }

    #[test]
    fn the_window_mean_ignores_holes_and_everything_outside_it() {
        // 40×30 image, a tilted ground: depth = 5 + 0.01·x + 0.02·y. Outside the central
        // 16×10 window the depth is 100 m, which must not count.
        let (w, h) = (40, 30);
        let (x0, y0, ww, wh) = (12, 10, 16, 10);
        let mut rng = SplitMix64::new(1);
        let mut data = vec![100.0f32; w * h];
        let mut expected_sum = 0.0f64;
        let mut expected_count = 0usize;
        for y in y0..y0 + wh {
            for x in x0..x0 + ww {
                let r = rng.next_f64();
                data[y * w + x] = if r < 0.15 {
                    f32::NAN
                } else if r < 0.3 {
                    0.0
                } else {
                    let z = (5.0 + 0.01 * x as f64 + 0.02 * y as f64) as f32;
                    expected_sum += z as f64;
                    expected_count += 1;
                    z
                };
            }
        }
        let depth = DepthImage::from_vec(w, h, data).unwrap();
        let window = AltitudeWindow {
            width_px: ww,
            height_px: wh,
            min_valid_fraction: 0.5,
            ..AltitudeWindow::default()
        };
        let sample = central_window_altitude(&depth, &window).unwrap();
        assert_eq!(sample.window_px, 160);
        assert_eq!(sample.valid_px, expected_count);
        assert!(expected_count < 140, "the window has holes");
        assert!((sample.altitude_m - expected_sum / expected_count as f64).abs() < 1e-9);
        // A stricter validity requirement than the holes allow is an error.
        let strict = AltitudeWindow {
            min_valid_fraction: 0.95,
            ..window
        };
        assert!(matches!(
            central_window_altitude(&depth, &strict),
            Err(StereoAltitudeError::TooFewValid {
                window: 160,
                needed: 152,
                ..
            })
        ));
        // Out of the stereo range counts as invalid: all window depths are above 5 m.
        let range = AltitudeWindow {
            max_depth_m: 5.0,
            ..window
        };
        assert!(matches!(
            central_window_altitude(&depth, &range),
            Err(StereoAltitudeError::TooFewValid { valid: 0, .. })
        ));
    }

    #[test]
    fn an_all_invalid_window_is_a_named_error() {
        let mut data = vec![3.0f32; 20 * 20];
        for y in 5..15 {
            for x in 5..15 {
                data[y * 20 + x] = if (x + y) % 2 == 0 { f32::NAN } else { -1.0 };
            }
        }
        let depth = DepthImage::from_vec(20, 20, data).unwrap();
        let window = AltitudeWindow {
            width_px: 10,
            height_px: 10,
            ..AltitudeWindow::default()
        };
        assert_eq!(
            central_window_altitude(&depth, &window),
            Err(StereoAltitudeError::TooFewValid {
                valid: 0,
                window: 100,
                needed: 30
            })
        );
        // A window larger than the image is clipped to it: then the valid border counts.
        let large = AltitudeWindow {
            width_px: 500,
            height_px: 500,
            ..window
        };
        let sample = central_window_altitude(&depth, &large).unwrap();
        assert_eq!((sample.window_px, sample.valid_px), (400, 300));
        assert!((sample.altitude_m - 3.0).abs() < 1e-12);
    }

    #[test]
    fn the_filter_tracks_a_noisy_descent_better_than_the_raw_altitude() {
        let mut filter = AltitudeFilter::new(AltitudeFilterConfig::default()).unwrap();
        let mut rng = SplitMix64::new(12);
        let dt = 1.0 / 30.0;
        let (mut raw_sq, mut filtered_sq, mut n) = (0.0, 0.0, 0usize);
        let mut rates = Vec::new();
        for k in 0..300 {
            let t = k as f64 * dt;
            // Descent at 0.5 m/s from 8 m, with 0.1 m of vibration noise.
            let truth = 8.0 - 0.5 * t;
            let measured = truth + 0.1 * rng.next_gaussian();
            let estimate = filter.update(t, measured).unwrap();
            if t >= 1.0 {
                raw_sq += (measured - truth).powi(2);
                filtered_sq += (estimate.altitude_m - truth).powi(2);
                n += 1;
                rates.push(estimate.altitude_rate_m_s);
            }
        }
        let (raw_rms, filtered_rms) = ((raw_sq / n as f64).sqrt(), (filtered_sq / n as f64).sqrt());
        assert!(
            filtered_rms < 0.6 * raw_rms,
            "filtered {filtered_rms} m vs raw {raw_rms} m"
        );
        let mean_rate = rates.iter().sum::<f64>() / rates.len() as f64;
        assert!((mean_rate + 0.5).abs() < 0.05, "{mean_rate}");
    }

    #[test]
    fn the_filter_refuses_bad_input_and_restarts_after_a_gap() {
        let mut filter = AltitudeFilter::new(AltitudeFilterConfig::default()).unwrap();
        assert!(filter.estimate().is_none());
        filter.update(0.0, 5.0).unwrap();
        filter.update(0.1, 5.0).unwrap();
        assert!(matches!(
            filter.update(0.1, 5.0),
            Err(StereoAltitudeError::TimeNotAdvancing { .. })
        ));
        assert!(matches!(
            filter.update(0.2, f64::NAN),
            Err(StereoAltitudeError::Measurement { .. })
        ));
        // Five seconds without depth: the next measurement restarts the filter at it.
        let e = filter.update(5.2, 3.0).unwrap();
        assert_eq!((e.altitude_m, e.altitude_rate_m_s), (3.0, 0.0));
        assert!(AltitudeFilter::new(AltitudeFilterConfig {
            measurement_std_m: 0.0,
            ..AltitudeFilterConfig::default()
        })
        .is_err());
    }
}
