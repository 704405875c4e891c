//! How well the runtime knew where the pad was: its relative state against the truth.

use crate::outcome::LocalisationError;

/// Sums for [`LocalisationError`], one sample at a time.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LocalisationAccumulator {
    samples: usize,
    horizontal_sq_m2: f64,
    horizontal_max_m: f64,
    vertical_sq_m2: f64,
    velocity_samples: usize,
    velocity_sq_m2_s2: f64,
}

impl LocalisationAccumulator {
    /// One sample: the estimated and the true UAV − pad position (NED), and, when the
    /// estimate has one, the estimated and the true platform velocity (NED; only north and east
    /// count). Non-finite estimates count as no sample.
    pub fn add(
        &mut self,
        estimate_ned_m: &nalgebra::Vector3<f64>,
        truth_ned_m: &nalgebra::Vector3<f64>,
        platform_velocity_ned_m_s: Option<(nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)>,
    ) {
        if !estimate_ned_m.iter().all(|v| v.is_finite()) {
            return;
        }
        let error = estimate_ned_m - truth_ned_m;
        let horizontal = error.xy().norm();
        self.samples += 1;
        self.horizontal_sq_m2 += horizontal * horizontal;
        self.horizontal_max_m = self.horizontal_max_m.max(horizontal);
        self.vertical_sq_m2 += error.z * error.z;
        if let Some((estimate, truth)) = platform_velocity_ned_m_s {
            if estimate.iter().all(|v| v.is_finite()) {
                self.velocity_samples += 1;
                self.velocity_sq_m2_s2 += (estimate - truth).xy().norm_squared();
            }
        }
    }

    pub fn finish(&self) -> Option<LocalisationError> {
        (self.samples > 0).then(|| {
            let n = self.samples as f64;
            LocalisationError {
                samples: self.samples,
                horizontal_rms_m: (self.horizontal_sq_m2 / n).sqrt(),
                horizontal_max_m: self.horizontal_max_m,
                vertical_rms_m: (self.vertical_sq_m2 / n).sqrt(),
                platform_velocity_rms_m_s: (self.velocity_samples > 0)
                    .then(|| (self.velocity_sq_m2_s2 / self.velocity_samples as f64).sqrt()),
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn localisation_errors_are_rms_and_max_over_the_samples() {
        use nalgebra::Vector3;
        let mut sums = LocalisationAccumulator::default();
        assert_eq!(sums.finish(), None);
        let truth = Vector3::new(1.0, -2.0, -7.0);
        // Horizontal errors 0.3 (3-4-5 scaled) and 0.0; vertical 0.2 and 0.4.
        sums.add(&Vector3::new(1.18, -2.24, -7.2), &truth, None);
        let velocity = Vector3::new(0.5, 0.0, 0.0);
        sums.add(
            &Vector3::new(1.0, -2.0, -7.4),
            &truth,
            Some((Vector3::new(0.5, 0.1, 9.0), velocity)),
        );
        // Not finite: not a sample.
        sums.add(&Vector3::new(f64::NAN, 0.0, 0.0), &truth, None);
        let error = sums.finish().unwrap();
        assert_eq!(error.samples, 2);
        assert!((error.horizontal_rms_m - (0.09f64 / 2.0).sqrt()).abs() < 1e-12);
        assert!((error.horizontal_max_m - 0.3).abs() < 1e-12);
        assert!((error.vertical_rms_m - (0.2f64 / 2.0).sqrt()).abs() < 1e-12);
        // The vertical velocity does not count.
        assert!((error.platform_velocity_rms_m_s.unwrap() - 0.1).abs() < 1e-12);
    }
}
