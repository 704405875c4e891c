//! What the autopilot reports instead of the truth: its estimator's noise and slow bias, the
//! rangefinder's noise and dropouts, and the latency from the estimate to the companion
//! computer ([`crate::realism`] holds the parameters and where they come from).

use crate::flight::VehicleSnapshot;
use crate::realism::{EstimatorErrors, GaussMarkov, RangefinderErrors};
use algorithms::vision::render::SplitMix64;
use std::collections::VecDeque;

/// Turns the true state, tick by tick, into the telemetry a companion computer receives.
#[derive(Debug, Clone)]
pub struct EstimatedTelemetry {
    errors: EstimatorErrors,
    rangefinder: RangefinderErrors,
    latency_s: f64,
    rng: SplitMix64,
    position_bias_m: [GaussMarkov; 3],
    velocity_bias_m_s: [GaussMarkov; 3],
    attitude_bias_rad: [GaussMarkov; 3],
    last_time_s: Option<f64>,
    /// Estimates not yet old enough to be delivered, oldest first.
    pending: VecDeque<VehicleSnapshot>,
}

impl EstimatedTelemetry {
    pub fn new(
        errors: EstimatorErrors,
        rangefinder: RangefinderErrors,
        latency_s: f64,
        seed: u64,
    ) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x6573_7469_6d61_7465);
        let mut process =
            |sigma: f64, tau_s: f64| GaussMarkov::new(sigma, tau_s, rng.next_gaussian());
        let e = &errors;
        // Vertical position drift is the baro's, about half the GPS's horizontal one; yaw's
        // bias matters little to a downward camera (it rotates the image about the pad).
        let position_bias_m = [
            process(e.position_bias_m, e.position_bias_tau_s),
            process(e.position_bias_m, e.position_bias_tau_s),
            process(0.5 * e.position_bias_m, e.position_bias_tau_s),
        ];
        let velocity_bias_m_s = [
            process(e.velocity_bias_m_s, e.velocity_bias_tau_s),
            process(e.velocity_bias_m_s, e.velocity_bias_tau_s),
            process(0.5 * e.velocity_bias_m_s, e.velocity_bias_tau_s),
        ];
        let attitude_bias_rad = [
            process(e.attitude_bias_rad, e.attitude_bias_tau_s),
            process(e.attitude_bias_rad, e.attitude_bias_tau_s),
            process(e.attitude_bias_rad, e.attitude_bias_tau_s),
        ];
        Self {
            errors,
            rangefinder,
            latency_s: latency_s.max(0.0),
            rng,
            position_bias_m,
            velocity_bias_m_s,
            attitude_bias_rad,
            last_time_s: None,
            pending: VecDeque::new(),
        }
    }

    /// The slow position error now (north, east, down).
    pub fn position_bias_ned_m(&self) -> [f64; 3] {
        self.position_bias_m.map(|p| p.value)
    }

    /// What the autopilot reports at `truth.time_s`: the estimate made `latency_s` earlier (the
    /// first one until there is one that old), stamped now. Call once a tick, in time order.
    pub fn report(&mut self, truth: &VehicleSnapshot) -> VehicleSnapshot {
        let estimate = self.estimate(truth);
        self.pending.push_back(estimate);
        let due_s = truth.time_s - self.latency_s;
        // Keep the newest estimate that is old enough; drop the ones before it.
        while self.pending.len() > 1 && self.pending[1].time_s <= due_s + 1e-9 {
            self.pending.pop_front();
        }
        let mut delivered = self.pending[0];
        delivered.time_s = truth.time_s;
        // Arming, mode and landed state are events, not estimates: they are not delayed.
        delivered.armed = truth.armed;
        delivered.mode = truth.mode;
        delivered.landed_state = truth.landed_state;
        delivered.battery = truth.battery;
        delivered
    }

    /// The estimate of `truth` with this tick's errors.
    fn estimate(&mut self, truth: &VehicleSnapshot) -> VehicleSnapshot {
        let dt_s = self
            .last_time_s
            .map_or(0.0, |last| (truth.time_s - last).max(0.0));
        self.last_time_s = Some(truth.time_s);
        let e = self.errors;
        let mut out = *truth;
        for axis in 0..3 {
            let bias = self.position_bias_m[axis].step(dt_s, self.rng.next_gaussian());
            out.position_ned_m[axis] += bias + e.position_noise_m * self.rng.next_gaussian();
            let bias = self.velocity_bias_m_s[axis].step(dt_s, self.rng.next_gaussian());
            out.velocity_ned_m_s[axis] += bias + e.velocity_noise_m_s * self.rng.next_gaussian();
        }
        let mut attitude_error = [0.0; 3];
        for (axis, error) in attitude_error.iter_mut().enumerate() {
            let bias = self.attitude_bias_rad[axis].step(dt_s, self.rng.next_gaussian());
            *error = bias + e.attitude_noise_rad * self.rng.next_gaussian();
        }
        out.attitude.roll_rad += attitude_error[0];
        out.attitude.pitch_rad += attitude_error[1];
        out.attitude.yaw_rad += attitude_error[2];
        // The gimbal's IMU is of the vehicle's class, and its heading is the autopilot's.
        if let Some(gimbal) = out.gimbal_attitude.as_mut() {
            gimbal.roll_rad += attitude_error[0];
            gimbal.pitch_rad += attitude_error[1];
            gimbal.yaw_rad += attitude_error[2];
        }
        let r = self.rangefinder;
        out.rangefinder_m = truth.rangefinder_m.and_then(|range_m| {
            if self.rng.next_f64() < r.dropout_probability {
                return None;
            }
            let sigma_m = r.noise_m + r.noise_fraction * range_m;
            Some((range_m + sigma_m * self.rng.next_gaussian()).max(0.0))
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flight::{BatteryReading, FlightMode, LandedState};
    use crate::realism::{EstimatorErrors, RangefinderErrors};
    use algorithms::estimation::projection::Attitude;
    use nalgebra::Vector3;

    fn truth(time_s: f64) -> VehicleSnapshot {
        VehicleSnapshot {
            time_s,
            // Moving north at 1 m/s, so a delayed report is visibly behind.
            position_ned_m: Vector3::new(time_s, 2.0, -5.0),
            velocity_ned_m_s: Vector3::new(1.0, 0.0, 0.0),
            acceleration_ned_m_s2: Vector3::zeros(),
            attitude: Attitude {
                roll_rad: 0.0,
                pitch_rad: 0.0,
                yaw_rad: 0.0,
            },
            body_rates_rad_s: Vector3::zeros(),
            armed: true,
            mode: FlightMode::Offboard,
            landed_state: LandedState::InAir,
            rangefinder_m: Some(5.0),
            gimbal_attitude: None,
            battery: BatteryReading {
                voltage_v: 16.0,
                current_a: 10.0,
                consumed_mah: 0.0,
                remaining_fraction: 1.0,
            },
        }
    }

    #[test]
    fn the_ideal_estimate_is_the_truth_now() {
        let mut telemetry =
            EstimatedTelemetry::new(EstimatorErrors::NONE, RangefinderErrors::NONE, 0.0, 1);
        for tick in 0..50 {
            let t = truth(tick as f64 * 0.02);
            assert_eq!(telemetry.report(&t), t);
        }
    }

    #[test]
    fn latency_delivers_the_state_of_latency_ago_stamped_now() {
        let mut telemetry =
            EstimatedTelemetry::new(EstimatorErrors::NONE, RangefinderErrors::NONE, 0.04, 1);
        for tick in 0..50 {
            let now_s = tick as f64 * 0.02;
            let reported = telemetry.report(&truth(now_s));
            assert_eq!(reported.time_s, now_s);
            let expected_north_m = (now_s - 0.04).max(0.0);
            assert!(
                (reported.position_ned_m.x - expected_north_m).abs() < 1e-9,
                "at {now_s} s: {} m north",
                reported.position_ned_m.x
            );
        }
    }

    /// Over a long flight the position error's spread is the bias's and the noise's together,
    /// and its slow part changes little over a second: drift, not jitter.
    #[test]
    fn position_errors_are_a_slow_drift_of_decimetres() {
        let errors = EstimatorErrors::default();
        let mut telemetry = EstimatedTelemetry::new(errors, RangefinderErrors::NONE, 0.0, 3);
        let dt_s = 0.02;
        let errors_north_m: Vec<f64> = (0..200_000)
            .map(|tick| {
                let t = truth(tick as f64 * dt_s);
                telemetry.report(&t).position_ned_m.x - t.position_ned_m.x
            })
            .collect();
        let n = errors_north_m.len() as f64;
        let rms_m = (errors_north_m.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
        let expected_m = errors.position_bias_m.hypot(errors.position_noise_m);
        assert!(
            (rms_m - expected_m).abs() < 0.25 * expected_m,
            "rms {rms_m} m against {expected_m} m"
        );
        // Changes over one second: the noise's √2·σ plus a small share of the bias's.
        let step = (1.0 / dt_s) as usize;
        let change_rms_m = (errors_north_m
            .windows(step + 1)
            .map(|w| (w[step] - w[0]).powi(2))
            .sum::<f64>()
            / (n - step as f64))
            .sqrt();
        assert!(change_rms_m < 0.3 * rms_m, "{change_rms_m} m a second");
    }

    #[test]
    fn the_rangefinder_drops_and_scatters_readings() {
        let rangefinder = RangefinderErrors::default();
        let mut telemetry = EstimatedTelemetry::new(EstimatorErrors::NONE, rangefinder, 0.0, 5);
        let readings: Vec<Option<f64>> = (0..20_000)
            .map(|tick| telemetry.report(&truth(tick as f64 * 0.02)).rangefinder_m)
            .collect();
        let dropped = readings.iter().filter(|r| r.is_none()).count() as f64 / 20_000.0;
        assert!(
            (dropped - rangefinder.dropout_probability).abs() < 0.01,
            "{dropped} dropped"
        );
        let values: Vec<f64> = readings.into_iter().flatten().collect();
        let n = values.len() as f64;
        let rms_m = (values.iter().map(|r| (r - 5.0).powi(2)).sum::<f64>() / n).sqrt();
        let expected_m = rangefinder.noise_m + rangefinder.noise_fraction * 5.0;
        assert!(
            (rms_m - expected_m).abs() < 0.05 * expected_m,
            "rms {rms_m} m"
        );
    }
}
