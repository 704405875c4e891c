//! The tracker: a Kalman filter on the UAV's position relative to the platform, NED (seed 003,
//! §IV-B, equations 1–4).
//!
//! State x = UAV − platform (north, east, down), metres. Prediction (eq. 1–2): F = I,
//! x += (v_uav − v_platform)·dt + a_uav·dt²/2, P += Q with Q = dt·q·I (q is the seed's σ²_IMU).
//! Correction (eq. 3) with H = I from a vision fix.
//!
//! Delay (eq. 4): the seed shifts a late fix by the mean velocity × delay. We instead correct the
//! state *at the frame's capture time* from a short history and carry the correction forward.
//! Because F = I and the input enters additively, carrying it forward is exact and needs no
//! re-run of the inputs: every later state moves by K·e and every later covariance loses K·H·P at
//! the capture time.

use std::collections::VecDeque;

use nalgebra::{Matrix3, Vector3};
use thiserror::Error;

/// Chi-square 99 % quantile for 3 degrees of freedom: the default innovation gate.
pub const CHI2_3DOF_99: f64 = 11.344_866_730_144_37;

/// A tracker that cannot be built or fed as asked.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TrackerError {
    #[error("process noise q must be positive and finite, got {q_m2_per_s} m²/s")]
    ProcessNoise { q_m2_per_s: f64 },
    #[error("the innovation gate must be positive, got {gate}")]
    Gate { gate: f64 },
    #[error("the history must be non-negative and finite, got {history_s} s")]
    History { history_s: f64 },
    #[error("restart_after_rejected_s must be non-negative and finite, got {span_s} s")]
    RestartSpan { span_s: f64 },
    #[error("quick_restart_within_m must be non-negative and finite, got {within_m} m")]
    QuickRestart { within_m: f64 },
    #[error("a time or value given to the tracker is not finite")]
    NotFinite,
    #[error("time went backwards: {time_s} s is before the tracker's {now_s} s")]
    TimeBackwards { time_s: f64, now_s: f64 },
    #[error("the measurement covariance is not symmetric positive definite")]
    Covariance,
    #[error("the tracker has no state yet: give it a vision fix first")]
    NotInitialized,
}

/// What the tracker needs to know, fixed for a flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerConfig {
    /// q in Q = dt·q·I: the growth rate of the position variance between fixes, m²/s (σ²_IMU).
    pub process_noise_m2_per_s: f64,
    /// Normalised innovation squared above which a fix is rejected (chi-square, 3 dof).
    pub gate_nis: f64,
    /// How far back a late fix may be applied, seconds.
    pub history_s: f64,
    /// After this many fixes in a row are gated out, the filter restarts from the latest: the
    /// fixes agree with each other, not with the prediction, so the prediction is what is
    /// wrong (a platform that started moving between two slow fixes). 0 never restarts.
    pub restart_after_rejections: u32,
    /// …and only once the gated fixes in a row span at least this long (0: the count alone).
    /// At 10 fps two gated fixes are 0.1 s apart: two false detections would move the
    /// estimate metres; at the seed's 0.5 fps two span 2 s.
    pub restart_after_rejected_s: f64,
    /// …unless every gated fix in the run lay within this horizontal distance of the
    /// prediction: that is the prediction lagging a manoeuvre (a tractor turning, a gust), not
    /// a false detection metres away, and waiting would lose the pad (0: the span always).
    pub quick_restart_within_m: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            process_noise_m2_per_s: 0.05,
            gate_nis: CHI2_3DOF_99,
            history_s: 0.5,
            restart_after_rejections: 2,
            restart_after_rejected_s: 0.0,
            quick_restart_within_m: 0.0,
        }
    }
}

/// The inputs of one prediction, NED, held over the interval up to the prediction's time.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MotionInput {
    pub uav_velocity_ned_m_s: Vector3<f64>,
    pub uav_acceleration_ned_m_s2: Vector3<f64>,
    pub platform_velocity_ned_m_s: Vector3<f64>,
}

/// A vision fix: the UAV's position relative to the platform, taken at `capture_time_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionFix {
    pub capture_time_s: f64,
    pub uav_relative_ned_m: Vector3<f64>,
    pub covariance_m2: Matrix3<f64>,
}

/// The tracker's estimate at `time_s`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RelativeEstimate {
    pub time_s: f64,
    /// UAV − platform, NED, metres.
    pub uav_relative_ned_m: Vector3<f64>,
    pub covariance_m2: Matrix3<f64>,
}

/// What became of a fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixOutcome {
    /// The first fix: the state starts from it.
    Initialized,
    /// Applied; `nis` is its normalised innovation squared.
    Accepted { nis: f64 },
    /// Gated out as an outlier; the state is unchanged.
    Rejected { nis: f64 },
    /// The last of [`TrackerConfig::restart_after_rejections`] gated fixes in a row: the state
    /// restarted from it, with the fix's covariance.
    Restarted { nis: f64 },
    /// Older than the history, or older than a fix already applied: ignored (applying it would
    /// double-count what the later fix already told us).
    Stale,
}

/// The relative-position Kalman filter; see the module docs.
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackerConfig,
    /// States at past prediction times, oldest first; the last is the current estimate.
    history: VecDeque<RelativeEstimate>,
    last_fix_time_s: f64,
    /// Fixes gated out since the last accepted one, and the capture time of the first.
    rejections_in_a_row: u32,
    first_rejection_s: f64,
    /// The furthest of them from the prediction, horizontally.
    rejected_furthest_m: f64,
}

impl Tracker {
    pub fn new(config: TrackerConfig) -> Result<Self, TrackerError> {
        let q = config.process_noise_m2_per_s;
        if !(q.is_finite() && q > 0.0) {
            return Err(TrackerError::ProcessNoise { q_m2_per_s: q });
        }
        if config.gate_nis.is_nan() || config.gate_nis <= 0.0 {
            return Err(TrackerError::Gate {
                gate: config.gate_nis,
            });
        }
        if !(config.history_s.is_finite() && config.history_s >= 0.0) {
            return Err(TrackerError::History {
                history_s: config.history_s,
            });
        }
        let span_s = config.restart_after_rejected_s;
        if !(span_s.is_finite() && span_s >= 0.0) {
            return Err(TrackerError::RestartSpan { span_s });
        }
        let within_m = config.quick_restart_within_m;
        if !(within_m.is_finite() && within_m >= 0.0) {
            return Err(TrackerError::QuickRestart { within_m });
        }
        Ok(Self {
            config,
            history: VecDeque::new(),
            last_fix_time_s: f64::NEG_INFINITY,
            rejections_in_a_row: 0,
            first_rejection_s: f64::NAN,
            rejected_furthest_m: 0.0,
        })
    }

    /// The current estimate; `None` before the first fix.
    pub fn estimate(&self) -> Option<RelativeEstimate> {
        self.history.back().copied()
    }

    /// Forgets the state (target lost for good); the next fix starts it again.
    pub fn reset(&mut self) {
        self.history.clear();
        self.last_fix_time_s = f64::NEG_INFINITY;
    }

    /// Predicts to `time_s` with `input` held since the last prediction (eq. 1–2). Before the
    /// first fix there is nothing to predict and it returns `NotInitialized`.
    pub fn predict(&mut self, time_s: f64, input: &MotionInput) -> Result<(), TrackerError> {
        let finite = time_s.is_finite()
            && input.uav_velocity_ned_m_s.iter().all(|c| c.is_finite())
            && input
                .uav_acceleration_ned_m_s2
                .iter()
                .all(|c| c.is_finite())
            && input
                .platform_velocity_ned_m_s
                .iter()
                .all(|c| c.is_finite());
        if !finite {
            return Err(TrackerError::NotFinite);
        }
        let now = self.history.back().ok_or(TrackerError::NotInitialized)?;
        let dt_s = time_s - now.time_s;
        if dt_s < 0.0 {
            return Err(TrackerError::TimeBackwards {
                time_s,
                now_s: now.time_s,
            });
        }
        if dt_s == 0.0 {
            return Ok(());
        }
        let relative_velocity = input.uav_velocity_ned_m_s - input.platform_velocity_ned_m_s;
        let next = RelativeEstimate {
            time_s,
            uav_relative_ned_m: now.uav_relative_ned_m
                + relative_velocity * dt_s
                + input.uav_acceleration_ned_m_s2 * (0.5 * dt_s * dt_s),
            covariance_m2: now.covariance_m2
                + Matrix3::identity() * (dt_s * self.config.process_noise_m2_per_s),
        };
        self.history.push_back(next);
        // Keep one entry at or before the oldest time a fix may come from.
        let oldest_s = time_s - self.config.history_s;
        while self.history.len() > 1 && self.history[1].time_s <= oldest_s {
            self.history.pop_front();
        }
        Ok(())
    }

    /// Corrects with a vision fix taken at its capture time (eq. 3), compensating its delay.
    /// The fix must not be later than the last prediction: predict to the arrival time first.
    pub fn correct(&mut self, fix: &VisionFix) -> Result<FixOutcome, TrackerError> {
        let finite = fix.capture_time_s.is_finite()
            && fix.uav_relative_ned_m.iter().all(|c| c.is_finite())
            && fix.covariance_m2.iter().all(|c| c.is_finite());
        if !finite {
            return Err(TrackerError::NotFinite);
        }
        let r = fix.covariance_m2;
        if (r - r.transpose()).abs().max() > 1e-9 * r.abs().max().max(1e-12)
            || r.cholesky().is_none()
        {
            return Err(TrackerError::Covariance);
        }
        let Some(now) = self.history.back().copied() else {
            self.history.push_back(RelativeEstimate {
                time_s: fix.capture_time_s,
                uav_relative_ned_m: fix.uav_relative_ned_m,
                covariance_m2: r,
            });
            self.last_fix_time_s = fix.capture_time_s;
            return Ok(FixOutcome::Initialized);
        };
        if fix.capture_time_s > now.time_s {
            return Err(TrackerError::TimeBackwards {
                time_s: now.time_s,
                now_s: fix.capture_time_s,
            });
        }
        let Some(at_capture) = self.state_at(fix.capture_time_s) else {
            return Ok(FixOutcome::Stale);
        };
        if fix.capture_time_s < self.last_fix_time_s {
            return Ok(FixOutcome::Stale);
        }
        let p = at_capture.covariance_m2;
        let innovation = fix.uav_relative_ned_m - at_capture.uav_relative_ned_m;
        let s = p + r;
        let Some(s_chol) = s.cholesky() else {
            return Err(TrackerError::Covariance);
        };
        let nis = innovation.dot(&s_chol.solve(&innovation));
        if nis > self.config.gate_nis {
            let off_m = innovation.xy().norm();
            if self.rejections_in_a_row == 0 {
                self.first_rejection_s = fix.capture_time_s;
                self.rejected_furthest_m = 0.0;
            }
            self.rejections_in_a_row += 1;
            self.rejected_furthest_m = self.rejected_furthest_m.max(off_m);
            let restart = self.config.restart_after_rejections;
            let span_s = fix.capture_time_s - self.first_rejection_s;
            let lagging = self.rejected_furthest_m <= self.config.quick_restart_within_m;
            if restart > 0
                && self.rejections_in_a_row >= restart
                && (span_s >= self.config.restart_after_rejected_s || lagging)
            {
                // Restart at the fix, carried to the present by the motion since its capture.
                let carried = now.uav_relative_ned_m - at_capture.uav_relative_ned_m;
                self.history.clear();
                self.history.push_back(RelativeEstimate {
                    time_s: now.time_s,
                    uav_relative_ned_m: fix.uav_relative_ned_m + carried,
                    covariance_m2: r,
                });
                self.last_fix_time_s = fix.capture_time_s;
                self.rejections_in_a_row = 0;
                return Ok(FixOutcome::Restarted { nis });
            }
            return Ok(FixOutcome::Rejected { nis });
        }
        self.rejections_in_a_row = 0;
        // K = P·S⁻¹ (H = I); S is symmetric, so K = (S⁻¹·P)ᵀ.
        let gain = s_chol.solve(&p).transpose();
        let shift = gain * innovation;
        let covariance_drop = gain * p;
        // The state at capture time becomes an entry of its own, so later fixes see it.
        let insert_at = self
            .history
            .iter()
            .position(|e| e.time_s > fix.capture_time_s)
            .unwrap_or(self.history.len());
        let corrected = RelativeEstimate {
            time_s: fix.capture_time_s,
            uav_relative_ned_m: at_capture.uav_relative_ned_m + shift,
            covariance_m2: symmetric(p - covariance_drop),
        };
        if insert_at > 0 && self.history[insert_at - 1].time_s == fix.capture_time_s {
            self.history[insert_at - 1] = corrected;
        } else {
            self.history.insert(insert_at, corrected);
        }
        for later in self
            .history
            .iter_mut()
            .filter(|e| e.time_s > fix.capture_time_s)
        {
            later.uav_relative_ned_m += shift;
            later.covariance_m2 = symmetric(later.covariance_m2 - covariance_drop);
        }
        self.last_fix_time_s = fix.capture_time_s;
        Ok(FixOutcome::Accepted { nis })
    }

    /// The state at `time_s` within the history, interpolated between stored predictions (exact
    /// for an input held constant over the interval, which is how `predict` uses it, apart from
    /// the small acceleration term).
    fn state_at(&self, time_s: f64) -> Option<RelativeEstimate> {
        let after = self.history.iter().position(|e| e.time_s >= time_s)?;
        let b = self.history[after];
        if b.time_s == time_s {
            return Some(b);
        }
        let a = self.history.get(after.checked_sub(1)?)?;
        let w = (time_s - a.time_s) / (b.time_s - a.time_s);
        Some(RelativeEstimate {
            time_s,
            uav_relative_ned_m: a.uav_relative_ned_m.lerp(&b.uav_relative_ned_m, w),
            covariance_m2: a.covariance_m2 * (1.0 - w) + b.covariance_m2 * w,
        })
    }
}

fn symmetric(m: Matrix3<f64>) -> Matrix3<f64> {
    (m + m.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::render::SplitMix64;

    fn gaussian3(rng: &mut SplitMix64, std: f64) -> Vector3<f64> {
        Vector3::new(
            rng.next_gaussian(),
            rng.next_gaussian(),
            rng.next_gaussian(),
        ) * std
    }

    /// Wilson–Hilferty approximation of the chi-square quantile for `dof` degrees of freedom at
    /// standard-normal quantile `z`.
    fn chi2_quantile(dof: f64, z: f64) -> f64 {
        let a = 2.0 / (9.0 * dof);
        dof * (1.0 - a + z * a.sqrt()).powi(3)
    }

    struct Scenario {
        /// Platform velocity (NED) as a function of time.
        platform_velocity: fn(f64) -> Vector3<f64>,
        fix_std_m: f64,
        delay_s: f64,
        drop_every: usize,
        compensate_delay: bool,
    }

    struct RunStats {
        first_error_m: f64,
        final_error_m: f64,
        /// √(mean trace P) over the second half: the error the filter claims.
        predicted_rms_late_m: f64,
        rms_error_late_m: f64,
        nees: Vec<f64>,
    }

    /// The truth follows the filter's model: the relative position moves with the known inputs
    /// plus a random walk of intensity q (what the imperfect velocity inputs leave over).
    fn run(scenario: &Scenario, config: TrackerConfig, seed: u64, steps: usize) -> RunStats {
        let mut rng = SplitMix64::new(seed);
        let dt_s = 0.02; // 50 Hz autopilot telemetry
        let frame_every = 3; // ≈ 17 fps camera
        let mut tracker = Tracker::new(config).unwrap();
        let mut truth = Vector3::new(6.0, -4.0, -10.0);
        let mut truth_log: Vec<(f64, Vector3<f64>)> = vec![];
        let fix_cov = Matrix3::identity() * scenario.fix_std_m.powi(2);
        // A poor first fix (σ = 2 m per axis), so convergence shows.
        tracker
            .correct(&VisionFix {
                capture_time_s: 0.0,
                uav_relative_ned_m: truth + gaussian3(&mut rng, 2.0),
                covariance_m2: Matrix3::identity() * 4.0,
            })
            .unwrap();
        let mut pending: Vec<VisionFix> = vec![];
        let mut nees = vec![];
        let mut errors = vec![];
        let mut traces = vec![];
        let delay_steps = (scenario.delay_s / dt_s).round() as usize;
        for k in 1..=steps {
            let t = k as f64 * dt_s;
            let uav_velocity = Vector3::new((0.5 * t).sin() * 2.0, 1.0, 0.2);
            let input = MotionInput {
                uav_velocity_ned_m_s: uav_velocity,
                uav_acceleration_ned_m_s2: Vector3::zeros(),
                platform_velocity_ned_m_s: (scenario.platform_velocity)(t),
            };
            truth += (uav_velocity - input.platform_velocity_ned_m_s) * dt_s
                + gaussian3(&mut rng, (config.process_noise_m2_per_s * dt_s).sqrt());
            truth_log.push((t, truth));
            tracker.predict(t, &input).unwrap();
            // A frame captured now is delivered `delay_s` later, unless dropped.
            if k % frame_every == 0 && (k / frame_every) % scenario.drop_every != 0 {
                pending.push(VisionFix {
                    capture_time_s: t,
                    uav_relative_ned_m: truth + gaussian3(&mut rng, scenario.fix_std_m),
                    covariance_m2: fix_cov,
                });
            }
            let due: Vec<VisionFix> = pending
                .iter()
                .copied()
                .filter(|f| ((t - f.capture_time_s) / dt_s).round() as usize >= delay_steps)
                .collect();
            pending.retain(|f| (((t - f.capture_time_s) / dt_s).round() as usize) < delay_steps);
            for mut fix in due {
                if !scenario.compensate_delay {
                    fix.capture_time_s = t;
                }
                tracker.correct(&fix).unwrap();
            }
            let est = tracker.estimate().unwrap();
            let e = est.uav_relative_ned_m - truth;
            errors.push(e.norm());
            traces.push(est.covariance_m2.trace());
            nees.push(e.dot(&(est.covariance_m2.try_inverse().unwrap() * e)));
        }
        let late = &errors[steps / 2..];
        RunStats {
            first_error_m: errors[0],
            final_error_m: *errors.last().unwrap(),
            predicted_rms_late_m: (traces[steps / 2..].iter().sum::<f64>()
                / (steps - steps / 2) as f64)
                .sqrt(),
            rms_error_late_m: (late.iter().map(|e| e * e).sum::<f64>() / late.len() as f64).sqrt(),
            nees,
        }
    }

    fn constant_velocity(_t: f64) -> Vector3<f64> {
        Vector3::new(3.0, 0.0, 0.0)
    }

    /// A tractor at 3 m/s turning through 180° between 4 s and 4 + π·2 s (radius 6 m).
    fn turning(t: f64) -> Vector3<f64> {
        let heading = ((t - 4.0).clamp(0.0, std::f64::consts::PI * 2.0)) * 0.5;
        Vector3::new(heading.cos(), heading.sin(), 0.0) * 3.0
    }

    fn scenario(platform_velocity: fn(f64) -> Vector3<f64>) -> Scenario {
        Scenario {
            platform_velocity,
            fix_std_m: 0.15,
            delay_s: 0.1,
            drop_every: 4,
            compensate_delay: true,
        }
    }

    /// With the platform's velocity given exactly, the two paths give the same error (the filter
    /// is linear in its inputs); the turn with an *estimated* platform velocity is tested in
    /// `platform_velocity`.
    #[test]
    fn error_converges_with_noisy_delayed_dropped_fixes() {
        let config = TrackerConfig::default();
        for (name, velocity) in [
            ("constant", constant_velocity as fn(f64) -> Vector3<f64>),
            ("turning", turning),
        ] {
            let stats = run(&scenario(velocity), config, 7, 1000);
            // Fixes σ = 0.15 m per axis at ~13 fps, 0.1 s late, one in four dropped: the steady
            // error must beat one fix's 3-D error (0.15·√3 ≈ 0.26 m) and match the covariance.
            let (rms, claimed) = (stats.rms_error_late_m, stats.predicted_rms_late_m);
            assert!(rms < 0.26, "{name}: rms {rms}");
            assert!(
                (rms / claimed - 1.0).abs() < 0.15,
                "{name}: {rms} vs {claimed}"
            );
            assert!(
                stats.first_error_m > 1.0 && stats.final_error_m < 0.5,
                "{name}: {} → {}",
                stats.first_error_m,
                stats.final_error_m
            );
            eprintln!(
                "{name}: rms {rms:.3} m, claimed {claimed:.3} m, first {:.2} m",
                stats.first_error_m
            );
        }
    }

    #[test]
    fn nees_is_consistent_over_monte_carlo_runs() {
        let config = TrackerConfig::default();
        let runs = 40;
        let steps = 500;
        let mut mean_nees = vec![0.0; steps];
        for seed in 0..runs {
            let stats = run(&scenario(turning), config, 100 + seed, steps);
            for (m, n) in mean_nees.iter_mut().zip(stats.nees) {
                *m += n / runs as f64;
            }
        }
        // Σ over runs of NEES ~ χ²(3·runs) per step; 95 % two-sided band.
        let dof = 3.0 * runs as f64;
        let (lo, hi) = (
            chi2_quantile(dof, -1.96) / runs as f64,
            chi2_quantile(dof, 1.96) / runs as f64,
        );
        let inside = mean_nees.iter().filter(|n| (lo..=hi).contains(*n)).count();
        let overall = mean_nees.iter().sum::<f64>() / steps as f64;
        assert!(
            inside as f64 >= 0.9 * steps as f64,
            "{inside}/{steps} inside [{lo:.2}, {hi:.2}]"
        );
        assert!((overall - 3.0).abs() < 0.3, "mean NEES {overall}");
        eprintln!("NEES: mean {overall:.3}, {inside}/{steps} steps inside [{lo:.2}, {hi:.2}]");
    }

    #[test]
    fn delay_compensation_beats_applying_late_fixes_as_if_fresh() {
        let config = TrackerConfig {
            process_noise_m2_per_s: 0.01,
            ..TrackerConfig::default()
        };
        let mut with = scenario(turning);
        with.delay_s = 0.2;
        with.fix_std_m = 0.05;
        let without = Scenario {
            compensate_delay: false,
            ..with
        };
        let a = run(&with, config, 3, 1000).rms_error_late_m;
        let b = run(&without, config, 3, 1000).rms_error_late_m;
        assert!(a < 0.5 * b, "compensated {a} vs uncompensated {b}");
        eprintln!("delay 0.2 s: rms {a:.3} m compensated, {b:.3} m uncompensated");
    }

    /// A late fix applied through the history gives exactly what a filter would have given had
    /// the fix arrived on time and the same inputs been predicted after it.
    #[test]
    fn a_late_fix_equals_an_on_time_fix_replayed() {
        let config = TrackerConfig::default();
        let input_at = |k: usize| MotionInput {
            uav_velocity_ned_m_s: Vector3::new(k as f64 * 0.1, -1.0, 0.3),
            uav_acceleration_ned_m_s2: Vector3::new(0.5, 0.0, -0.2),
            platform_velocity_ned_m_s: Vector3::new(2.0, 0.5, 0.0),
        };
        let first = VisionFix {
            capture_time_s: 0.0,
            uav_relative_ned_m: Vector3::new(3.0, 1.0, -9.0),
            covariance_m2: Matrix3::identity() * 0.3,
        };
        #[rustfmt::skip]
        let late_cov = Matrix3::new(
            0.02, 0.005, 0.0,
            0.005, 0.03, 0.0,
            0.0, 0.0, 0.05,
        );
        let late = |capture_time_s| VisionFix {
            capture_time_s,
            uav_relative_ned_m: Vector3::new(2.6, 0.9, -8.8),
            covariance_m2: late_cov,
        };
        // On a prediction boundary (t = 0.1) and inside an interval without acceleration
        // (t = 0.13, where the held input makes interpolation exact).
        for (capture_s, zero_acceleration) in [(0.1, false), (0.13, true)] {
            let input = |k| {
                let mut i = input_at(k);
                if zero_acceleration {
                    i.uav_acceleration_ned_m_s2 = Vector3::zeros();
                }
                i
            };
            let times: Vec<f64> = (1..=10).map(|k| k as f64 * 0.02).collect();
            let mut delayed = Tracker::new(config).unwrap();
            delayed.correct(&first).unwrap();
            for (k, t) in times.iter().enumerate() {
                delayed.predict(*t, &input(k)).unwrap();
            }
            delayed.correct(&late(capture_s)).unwrap();
            let mut on_time = Tracker::new(config).unwrap();
            on_time.correct(&first).unwrap();
            for (k, t) in times.iter().enumerate() {
                if *t > capture_s && on_time.estimate().unwrap().time_s < capture_s {
                    on_time.predict(capture_s, &input(k)).unwrap();
                    on_time.correct(&late(capture_s)).unwrap();
                }
                on_time.predict(*t, &input(k)).unwrap();
                if *t == capture_s {
                    on_time.correct(&late(capture_s)).unwrap();
                }
            }
            let (a, b) = (delayed.estimate().unwrap(), on_time.estimate().unwrap());
            assert!(
                (a.uav_relative_ned_m - b.uav_relative_ned_m).norm() < 1e-12,
                "{capture_s}: {a:?} vs {b:?}"
            );
            assert!((a.covariance_m2 - b.covariance_m2).norm() < 1e-12);
        }
    }

    #[test]
    fn an_outlier_is_gated_and_leaves_the_state_alone() {
        let mut tracker = Tracker::new(TrackerConfig::default()).unwrap();
        let cov = Matrix3::identity() * 0.01;
        let start = Vector3::new(1.0, 2.0, -8.0);
        let fix = |t: f64, p: Vector3<f64>| VisionFix {
            capture_time_s: t,
            uav_relative_ned_m: p,
            covariance_m2: cov,
        };
        assert_eq!(
            tracker.correct(&fix(0.0, start)).unwrap(),
            FixOutcome::Initialized
        );
        tracker.predict(0.1, &MotionInput::default()).unwrap();
        let before = tracker.estimate().unwrap();
        // 3 m off with σ ≈ 0.14 m: NIS ≈ 9 / 0.025 = 360 ≫ 11.3.
        let outcome = tracker
            .correct(&fix(0.1, start + Vector3::new(3.0, 0.0, 0.0)))
            .unwrap();
        assert!(matches!(outcome, FixOutcome::Rejected { nis } if nis > 300.0));
        assert_eq!(tracker.estimate().unwrap(), before);
        // A consistent fix passes, with the closed-form gain P/(P + R) per axis.
        let outcome = tracker
            .correct(&fix(0.1, start + Vector3::new(0.1, 0.0, 0.0)))
            .unwrap();
        assert!(matches!(outcome, FixOutcome::Accepted { .. }));
        let p = 0.01 + 0.1 * TrackerConfig::default().process_noise_m2_per_s;
        let k = p / (p + 0.01);
        let est = tracker.estimate().unwrap();
        assert!((est.uav_relative_ned_m.x - (1.0 + 0.1 * k)).abs() < 1e-12);
        assert!((est.covariance_m2[(0, 0)] - (1.0 - k) * p).abs() < 1e-12);
    }

    /// A platform that starts moving while fixes are slow: the prediction lags, every fix
    /// is gated, and after two in a row the filter restarts at the latest one (carried to
    /// the present), then accepts the next consistent fix. Restarts can be switched off.
    #[test]
    fn persistent_rejections_restart_the_filter_at_the_fixes() {
        let cov = Matrix3::identity() * 0.01;
        let fix = |t: f64, north_m: f64| VisionFix {
            capture_time_s: t,
            uav_relative_ned_m: Vector3::new(north_m, 0.0, -7.5),
            covariance_m2: cov,
        };
        for restart_after_rejections in [2, 0] {
            let config = TrackerConfig {
                restart_after_rejections,
                ..TrackerConfig::default()
            };
            let mut tracker = Tracker::new(config).unwrap();
            tracker.correct(&fix(0.0, 0.0)).unwrap();
            // The UAV hovers; the platform runs away north at 1.5 m/s, fixes every 0.5 s.
            let mut outcomes = Vec::new();
            for k in 1..=4 {
                let t = 0.5 * k as f64;
                tracker.predict(t + 0.05, &MotionInput::default()).unwrap();
                outcomes.push(tracker.correct(&fix(t, -1.5 * t)).unwrap());
            }
            if restart_after_rejections == 0 {
                assert!(outcomes
                    .iter()
                    .all(|o| matches!(o, FixOutcome::Rejected { .. })));
                continue;
            }
            assert!(
                matches!(outcomes[0], FixOutcome::Rejected { .. }),
                "{outcomes:?}"
            );
            assert!(matches!(outcomes[1], FixOutcome::Restarted { .. }));
            // The count starts over after a restart: the next gated fix is only rejected.
            assert!(matches!(outcomes[2], FixOutcome::Rejected { .. }));
            assert!(matches!(outcomes[3], FixOutcome::Restarted { .. }));
            // Restarted at the 2 s fix (−3 m); no motion input, nothing carried since.
            let est = tracker.estimate().unwrap();
            assert!((est.uav_relative_ned_m.x + 3.0).abs() < 1e-9, "{est:?}");
        }
    }

    /// At 10 fps, with restarts only after 1 s of gated fixes: two false detections in a row
    /// (the pad seen 5 m off) are rejected and do not move the estimate; a pad truly 5 m off
    /// for a second restarts it there.
    #[test]
    fn a_restart_needs_the_gated_fixes_to_span_the_configured_time() {
        let cov = Matrix3::identity() * 0.01;
        let fix = |t: f64, east_m: f64| VisionFix {
            capture_time_s: t,
            uav_relative_ned_m: Vector3::new(0.0, east_m, -7.5),
            covariance_m2: cov,
        };
        let config = TrackerConfig {
            restart_after_rejected_s: 1.0,
            ..TrackerConfig::default()
        };
        let mut tracker = Tracker::new(config).unwrap();
        tracker.correct(&fix(0.0, 0.0)).unwrap();
        let mut step = |t: f64, east_m: f64| {
            tracker.predict(t + 0.01, &MotionInput::default()).unwrap();
            let outcome = tracker.correct(&fix(t, east_m)).unwrap();
            (outcome, tracker.estimate().unwrap().uav_relative_ned_m.y)
        };
        for (t, east_m) in [(0.1, 5.0), (0.2, 5.0)] {
            let (outcome, estimate_m) = step(t, east_m);
            assert!(
                matches!(outcome, FixOutcome::Rejected { .. }),
                "{outcome:?}"
            );
            assert!(estimate_m.abs() < 1e-9, "moved to {estimate_m}");
        }
        // The true pad again: accepted, and the count starts over.
        assert!(matches!(step(0.3, 0.0).0, FixOutcome::Accepted { .. }));
        let mut restarted_at = None;
        for k in 4..=20 {
            let t = 0.1 * k as f64;
            if let (FixOutcome::Restarted { .. }, estimate_m) = step(t, 5.0) {
                restarted_at = Some((t, estimate_m));
                break;
            }
        }
        let (t, estimate_m) = restarted_at.expect("a second of consistent fixes restarts");
        assert!((t - 1.4).abs() < 1e-9, "restarted at {t} s");
        assert!((estimate_m - 5.0).abs() < 1e-9);
    }

    /// Gated fixes close to the prediction are the prediction lagging (a turn): with
    /// `quick_restart_within_m` they restart the filter at the second, while fixes further
    /// off still need the span.
    #[test]
    fn gated_fixes_near_the_prediction_restart_at_once() {
        let fix = |t: f64, east_m: f64| VisionFix {
            capture_time_s: t,
            uav_relative_ned_m: Vector3::new(0.0, east_m, -7.5),
            covariance_m2: Matrix3::identity() * 0.01,
        };
        let mut tracker = Tracker::new(TrackerConfig {
            restart_after_rejected_s: 1.0,
            quick_restart_within_m: 1.5,
            ..TrackerConfig::default()
        })
        .unwrap();
        tracker.correct(&fix(0.0, 0.0)).unwrap();
        let mut step = |t: f64, east_m: f64| {
            tracker.predict(t + 0.01, &MotionInput::default()).unwrap();
            tracker.correct(&fix(t, east_m)).unwrap()
        };
        // 1.2 m off: gated (σ 0.1 m), and the second restarts.
        assert!(matches!(step(0.1, 1.2), FixOutcome::Rejected { .. }));
        assert!(matches!(step(0.2, 1.2), FixOutcome::Restarted { .. }));
        // From there, 5 m off twice: rejected both times.
        assert!(matches!(step(0.3, 6.2), FixOutcome::Rejected { .. }));
        assert!(matches!(step(0.4, 6.2), FixOutcome::Rejected { .. }));
        // One near fix after a far one in the same run does not make the run quick.
        assert!(matches!(step(0.5, 2.0), FixOutcome::Rejected { .. }));
    }

    #[test]
    fn prediction_follows_equation_one_and_grows_the_covariance() {
        let config = TrackerConfig::default();
        let mut tracker = Tracker::new(config).unwrap();
        tracker
            .correct(&VisionFix {
                capture_time_s: 1.0,
                uav_relative_ned_m: Vector3::zeros(),
                covariance_m2: Matrix3::identity() * 0.04,
            })
            .unwrap();
        let input = MotionInput {
            uav_velocity_ned_m_s: Vector3::new(2.0, 1.0, 0.0),
            uav_acceleration_ned_m_s2: Vector3::new(0.0, 2.0, 0.0),
            platform_velocity_ned_m_s: Vector3::new(3.0, 0.0, 0.0),
        };
        // Frames missed for 2 s: it keeps predicting.
        for k in 1..=100 {
            tracker.predict(1.0 + k as f64 * 0.02, &input).unwrap();
        }
        let est = tracker.estimate().unwrap();
        // Per step: x += (2 − 3)·0.02; y += 1·0.02 + ½·2·0.02².
        let want = Vector3::new(-2.0, 100.0 * (0.02 + 0.0004), 0.0);
        assert!((est.uav_relative_ned_m - want).norm() < 1e-9, "{est:?}");
        assert!(
            (est.covariance_m2[(0, 0)] - (0.04 + 2.0 * config.process_noise_m2_per_s)).abs() < 1e-9
        );
    }

    #[test]
    fn bad_input_is_a_named_error_and_stale_fixes_are_ignored() {
        assert!(matches!(
            Tracker::new(TrackerConfig {
                process_noise_m2_per_s: -1.0,
                ..TrackerConfig::default()
            }),
            Err(TrackerError::ProcessNoise { .. })
        ));
        assert!(matches!(
            Tracker::new(TrackerConfig {
                gate_nis: f64::NAN,
                ..TrackerConfig::default()
            }),
            Err(TrackerError::Gate { .. })
        ));
        let error = Tracker::new(TrackerConfig {
            restart_after_rejected_s: -1.0,
            ..TrackerConfig::default()
        })
        .unwrap_err();
        assert_eq!(error, TrackerError::RestartSpan { span_s: -1.0 });
        assert!(error.to_string().contains("restart_after_rejected_s"));
        let error = Tracker::new(TrackerConfig {
            quick_restart_within_m: f64::NAN,
            ..TrackerConfig::default()
        })
        .unwrap_err();
        assert!(
            matches!(error, TrackerError::QuickRestart { .. }),
            "{error}"
        );
        assert!(error.to_string().contains("quick_restart_within_m"));
        let mut tracker = Tracker::new(TrackerConfig::default()).unwrap();
        assert_eq!(
            tracker.predict(0.0, &MotionInput::default()),
            Err(TrackerError::NotInitialized)
        );
        let good = VisionFix {
            capture_time_s: 0.0,
            uav_relative_ned_m: Vector3::zeros(),
            covariance_m2: Matrix3::identity(),
        };
        let not_pd = VisionFix {
            covariance_m2: -Matrix3::identity(),
            ..good
        };
        assert_eq!(tracker.correct(&not_pd), Err(TrackerError::Covariance));
        let nan = VisionFix {
            uav_relative_ned_m: Vector3::new(f64::NAN, 0.0, 0.0),
            ..good
        };
        assert_eq!(tracker.correct(&nan), Err(TrackerError::NotFinite));
        tracker.correct(&good).unwrap();
        for k in 1..=100 {
            tracker
                .predict(k as f64 * 0.01, &MotionInput::default())
                .unwrap();
        }
        assert!(matches!(
            tracker.predict(0.5, &MotionInput::default()),
            Err(TrackerError::TimeBackwards { .. })
        ));
        // Older than the 0.5 s history.
        let old = VisionFix {
            capture_time_s: 0.2,
            ..good
        };
        assert_eq!(tracker.correct(&old).unwrap(), FixOutcome::Stale);
        // Out of order: a fix before one already applied.
        let later = VisionFix {
            capture_time_s: 0.9,
            ..good
        };
        assert!(matches!(
            tracker.correct(&later).unwrap(),
            FixOutcome::Accepted { .. }
        ));
        let earlier = VisionFix {
            capture_time_s: 0.8,
            ..good
        };
        assert_eq!(tracker.correct(&earlier).unwrap(), FixOutcome::Stale);
        let future = VisionFix {
            capture_time_s: 1.5,
            ..good
        };
        assert!(matches!(
            tracker.correct(&future),
            Err(TrackerError::TimeBackwards { .. })
        ));
    }
}
