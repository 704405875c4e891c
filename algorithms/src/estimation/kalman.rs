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
mod tests;
