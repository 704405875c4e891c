//! How far the world a companion computer sees is from the truth: the autopilot's estimate
//! instead of the true state, telemetry rates and latency, the camera's latency and blur, a
//! partly hidden marker, a pad that sways on a rough field, a noisy rangefinder and a tractor
//! driven by a person. Each effect is a parameter with a realistic default and where that
//! default comes from; [`Realism::ideal`] turns them all off (the world before them: the
//! autopilot hands out the truth, frames arrive at once).

/// Every effect, realistic by default.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Realism {
    pub estimator: EstimatorErrors,
    pub telemetry: TelemetryTiming,
    pub camera: CameraRealism,
    pub pad: PadMotion,
    pub rangefinder: RangefinderErrors,
    pub driver: DriverBehaviour,
}

impl Realism {
    /// The ideal world: truth at 50 Hz with no latency, frames delivered at capture, a still
    /// and clean pad, an exact rangefinder, a tractor at constant speed on its path.
    pub fn ideal() -> Self {
        Self {
            estimator: EstimatorErrors::NONE,
            telemetry: TelemetryTiming::IDEAL,
            camera: CameraRealism::IDEAL,
            pad: PadMotion::STILL,
            rangefinder: RangefinderErrors::NONE,
            driver: DriverBehaviour::SCRIPTED,
        }
    }

    /// Whether every effect is off.
    pub fn is_ideal(&self) -> bool {
        *self == Self::ideal()
    }

    /// Checks every parameter: finite, not negative, probabilities within [0, 1].
    pub fn validate(&self) -> Result<(), RealismError> {
        let e = &self.estimator;
        let t = &self.telemetry;
        let c = &self.camera;
        let p = &self.pad;
        let r = &self.rangefinder;
        let d = &self.driver;
        for (name, value) in [
            ("estimator.position_noise_m", e.position_noise_m),
            ("estimator.position_bias_m", e.position_bias_m),
            ("estimator.position_bias_tau_s", e.position_bias_tau_s),
            ("estimator.velocity_noise_m_s", e.velocity_noise_m_s),
            ("estimator.velocity_bias_m_s", e.velocity_bias_m_s),
            ("estimator.velocity_bias_tau_s", e.velocity_bias_tau_s),
            ("estimator.attitude_noise_rad", e.attitude_noise_rad),
            ("estimator.attitude_bias_rad", e.attitude_bias_rad),
            ("estimator.attitude_bias_tau_s", e.attitude_bias_tau_s),
            ("telemetry.latency_s", t.latency_s),
            ("telemetry.attitude_rate_hz", t.attitude_rate_hz),
            ("telemetry.position_rate_hz", t.position_rate_hz),
            ("telemetry.distance_rate_hz", t.distance_rate_hz),
            ("camera.latency_min_s", c.latency_min_s),
            ("camera.latency_max_s", c.latency_max_s),
            ("camera.exposure_ms", c.exposure_ms),
            ("camera.occluder_size_m", c.occluder_size_m),
            ("pad.tilt_rad", p.tilt_rad),
            ("pad.tilt_period_s", p.tilt_period_s),
            ("pad.heave_m", p.heave_m),
            ("rangefinder.noise_m", r.noise_m),
            ("rangefinder.noise_fraction", r.noise_fraction),
            ("driver.speed_variation", d.speed_variation),
            ("driver.speed_tau_s", d.speed_tau_s),
            ("driver.wander_m", d.wander_m),
            ("driver.wander_tau_s", d.wander_tau_s),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(RealismError { name, value });
            }
        }
        for (name, value) in [
            ("camera.occluded_fraction", c.occluded_fraction),
            ("rangefinder.dropout_probability", r.dropout_probability),
            ("driver.speed_variation", d.speed_variation),
        ] {
            if value > 1.0 {
                return Err(RealismError { name, value });
            }
        }
        if c.latency_min_s > c.latency_max_s {
            return Err(RealismError {
                name: "camera.latency_min_s (above latency_max_s)",
                value: c.latency_min_s,
            });
        }
        Ok(())
    }
}

/// A parameter out of its range.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "realism parameter {name} = {value} must be finite, not negative, and a probability at most 1"
)]
pub struct RealismError {
    pub name: &'static str,
    pub value: f64,
}

/// How the autopilot's estimate (what LOCAL_POSITION_NED and ATTITUDE carry) differs from the
/// truth: white noise plus a bias that wanders as a first-order Gauss–Markov process (standard
/// deviation and correlation time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EstimatorErrors {
    /// White noise on each position axis (EKF2's output is smooth: centimetres).
    pub position_noise_m: f64,
    /// GPS drift on each horizontal axis (vertical: half of it, the baro's share). A u-blox M8/M9
    /// without RTK wanders by decimetres over tens of seconds (u-blox M8 datasheet: 2.5 m CEP
    /// absolute, far less over a minute); PX4's EKF2 passes it through to the local position.
    pub position_bias_m: f64,
    pub position_bias_tau_s: f64,
    /// White noise on each velocity axis (EKF2 with GPS: a few cm/s).
    pub velocity_noise_m_s: f64,
    /// Slow velocity error, from GPS Doppler and accelerometer bias.
    pub velocity_bias_m_s: f64,
    pub velocity_bias_tau_s: f64,
    /// White noise on roll, pitch and yaw.
    pub attitude_noise_rad: f64,
    /// Slow roll/pitch error: EKF2 tilt within about 0.5° in flight, plus the camera mount's
    /// misalignment. At 5 m it moves a vision fix by 4 cm.
    pub attitude_bias_rad: f64,
    pub attitude_bias_tau_s: f64,
}

impl EstimatorErrors {
    pub const NONE: Self = Self {
        position_noise_m: 0.0,
        position_bias_m: 0.0,
        position_bias_tau_s: 30.0,
        velocity_noise_m_s: 0.0,
        velocity_bias_m_s: 0.0,
        velocity_bias_tau_s: 10.0,
        attitude_noise_rad: 0.0,
        attitude_bias_rad: 0.0,
        attitude_bias_tau_s: 60.0,
    };
}

impl Default for EstimatorErrors {
    fn default() -> Self {
        Self {
            position_noise_m: 0.02,
            position_bias_m: 0.3,
            position_bias_tau_s: 30.0,
            velocity_noise_m_s: 0.03,
            velocity_bias_m_s: 0.03,
            velocity_bias_tau_s: 10.0,
            attitude_noise_rad: 0.2_f64.to_radians(),
            attitude_bias_rad: 0.5_f64.to_radians(),
            attitude_bias_tau_s: 60.0,
        }
    }
}

/// When telemetry reaches the companion computer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TelemetryTiming {
    /// From the estimate to its arrival on the companion: EKF2's output predictor, the MAVLink
    /// stream's scheduling and a 921,600 baud serial link together are 10–30 ms.
    pub latency_s: f64,
    /// PX4's MAVLink "onboard" mode streams ATTITUDE at 100 Hz, LOCAL_POSITION_NED at 30 Hz and
    /// DISTANCE_SENSOR at 10 Hz (mavlink_main.cpp, MAVLINK_MODE_ONBOARD). The simulator ticks at
    /// 50 Hz, so attitude comes at most once a tick.
    pub attitude_rate_hz: f64,
    pub position_rate_hz: f64,
    pub distance_rate_hz: f64,
}

impl TelemetryTiming {
    pub const IDEAL: Self = Self {
        latency_s: 0.0,
        attitude_rate_hz: 50.0,
        position_rate_hz: 50.0,
        distance_rate_hz: 20.0,
    };
}

impl Default for TelemetryTiming {
    fn default() -> Self {
        Self {
            latency_s: 0.02,
            attitude_rate_hz: 100.0,
            position_rate_hz: 30.0,
            distance_rate_hz: 10.0,
        }
    }
}

/// The downward camera, beyond its sensor noise and drift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraRealism {
    /// Capture to delivery, uniform per frame in [min, max]: exposure readout, ISP and the
    /// driver's buffers on a Jetson CSI camera (nvarguscamerasrc) are 30–80 ms; frames still
    /// carry their capture time.
    pub latency_min_s: f64,
    pub latency_max_s: f64,
    /// Exposure, for motion blur: 5–10 ms outdoors in daylight with auto-exposure.
    pub exposure_ms: f64,
    /// Fraction of missions whose pad carries an occluder (a clod of mud, straw, a shadow's
    /// dark edge) over part of the marker.
    pub occluded_fraction: f64,
    /// Side of an occluder.
    pub occluder_size_m: f64,
}

impl CameraRealism {
    pub const IDEAL: Self = Self {
        latency_min_s: 0.0,
        latency_max_s: 0.0,
        exposure_ms: 5.0,
        occluded_fraction: 0.0,
        occluder_size_m: 0.0,
    };
}

impl Default for CameraRealism {
    fn default() -> Self {
        Self {
            latency_min_s: 0.03,
            latency_max_s: 0.08,
            exposure_ms: 8.0,
            occluded_fraction: 0.5,
            occluder_size_m: 0.12,
        }
    }
}

/// The pad on a tractor crossing a rough field: it rolls and pitches, so its centre sways by
/// the roof's height times the tilt, and it heaves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadMotion {
    /// Amplitude of roll and pitch: 2–4° for a tractor on a ploughed field at walking pace.
    pub tilt_rad: f64,
    /// Main period of the rocking (wheel base over speed, a few seconds).
    pub tilt_period_s: f64,
    /// Amplitude of the vertical motion.
    pub heave_m: f64,
}

impl PadMotion {
    pub const STILL: Self = Self {
        tilt_rad: 0.0,
        tilt_period_s: 3.0,
        heave_m: 0.0,
    };
}

impl Default for PadMotion {
    fn default() -> Self {
        Self {
            tilt_rad: 2.0_f64.to_radians(),
            tilt_period_s: 3.0,
            heave_m: 0.03,
        }
    }
}

/// The downward rangefinder's errors (the pad/ground jump is geometry, always there).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangefinderErrors {
    /// Noise: a fixed part plus a part proportional to the range (Benewake TFmini: ±6 cm below
    /// 6 m, 1 % beyond; LightWare LW20: ±10 cm).
    pub noise_m: f64,
    pub noise_fraction: f64,
    /// Readings lost (no return from stubble, sun glare), each independently.
    pub dropout_probability: f64,
}

impl RangefinderErrors {
    pub const NONE: Self = Self {
        noise_m: 0.0,
        noise_fraction: 0.0,
        dropout_probability: 0.0,
    };
}

impl Default for RangefinderErrors {
    fn default() -> Self {
        Self {
            noise_m: 0.03,
            noise_fraction: 0.01,
            dropout_probability: 0.05,
        }
    }
}

/// A person driving the tractor: the speed wanders around the cruise speed and the line
/// wanders around the path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriverBehaviour {
    /// Standard deviation of the speed, as a fraction of the cruise speed, and how slowly it
    /// changes (a driver eases off and picks up over seconds).
    pub speed_variation: f64,
    pub speed_tau_s: f64,
    /// Standard deviation of the lateral offset from the path, and its correlation time.
    pub wander_m: f64,
    pub wander_tau_s: f64,
}

impl DriverBehaviour {
    pub const SCRIPTED: Self = Self {
        speed_variation: 0.0,
        speed_tau_s: 8.0,
        wander_m: 0.0,
        wander_tau_s: 10.0,
    };
}

impl Default for DriverBehaviour {
    fn default() -> Self {
        Self {
            speed_variation: 0.15,
            speed_tau_s: 8.0,
            wander_m: 0.5,
            wander_tau_s: 10.0,
        }
    }
}

/// A first-order Gauss–Markov process: stationary standard deviation `sigma`, correlation
/// time `tau_s`, advanced exactly over any step, so its statistics do not depend on the step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GaussMarkov {
    pub value: f64,
    sigma: f64,
    tau_s: f64,
}

impl GaussMarkov {
    /// Starts from a draw of its stationary distribution (`gaussian`: a standard normal draw).
    pub fn new(sigma: f64, tau_s: f64, gaussian: f64) -> Self {
        Self {
            value: sigma * gaussian,
            sigma,
            tau_s,
        }
    }

    /// Advances by `dt_s` with a fresh standard normal draw.
    pub fn step(&mut self, dt_s: f64, gaussian: f64) -> f64 {
        if self.sigma <= 0.0 || self.tau_s <= 0.0 {
            self.value = 0.0;
            return 0.0;
        }
        let decay = (-dt_s / self.tau_s).exp();
        self.value = decay * self.value + self.sigma * (1.0 - decay * decay).sqrt() * gaussian;
        self.value
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use algorithms::vision::render::SplitMix64;

    #[test]
    fn the_default_is_valid_and_ideal_is_all_off() {
        assert!(Realism::default().validate().is_ok());
        assert!(Realism::ideal().validate().is_ok());
        assert!(Realism::ideal().is_ideal());
        assert!(!Realism::default().is_ideal());
    }

    #[test]
    fn bad_parameters_are_named() {
        let mut realism = Realism::default();
        realism.rangefinder.dropout_probability = 1.5;
        assert_eq!(
            realism.validate().unwrap_err().name,
            "rangefinder.dropout_probability"
        );
        let mut realism = Realism::default();
        realism.estimator.position_bias_m = f64::NAN;
        assert_eq!(
            realism.validate().unwrap_err().name,
            "estimator.position_bias_m"
        );
        let mut realism = Realism::default();
        realism.camera.latency_min_s = 0.1;
        assert!(realism.validate().is_err());
    }

    /// The process's variance and its lag-τ autocorrelation (e⁻¹) against theory, from the
    /// samples alone, at two step sizes.
    #[test]
    fn gauss_markov_has_its_variance_and_correlation_time() {
        for dt_s in [0.02, 0.5] {
            let (sigma, tau_s) = (0.3, 5.0);
            let mut rng = SplitMix64::new(7);
            let mut process = GaussMarkov::new(sigma, tau_s, rng.next_gaussian());
            let samples: Vec<f64> = (0..400_000)
                .map(|_| process.step(dt_s, rng.next_gaussian()))
                .collect();
            let n = samples.len() as f64;
            let mean = samples.iter().sum::<f64>() / n;
            let variance = samples.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
            assert!(
                (variance.sqrt() - sigma).abs() < 0.05 * sigma,
                "dt {dt_s}: σ {} against {sigma}",
                variance.sqrt()
            );
            let lag = (tau_s / dt_s).round() as usize;
            let covariance = samples
                .iter()
                .zip(&samples[lag..])
                .map(|(a, b)| (a - mean) * (b - mean))
                .sum::<f64>()
                / (n - lag as f64);
            let correlation = covariance / variance;
            assert!(
                (correlation - (-1.0f64).exp()).abs() < 0.06,
                "dt {dt_s}: lag-τ correlation {correlation}"
            );
        }
    }
}
