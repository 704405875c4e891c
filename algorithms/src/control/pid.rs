//! The two-stage horizontal PID of seed 000 §2.3 (equations 24–27, Table 2).
//!
//! One PID per horizontal axis (north, east). The gain set switches at a height threshold
//! (Table 2: the seed used one set above 4 m and a stiffer one below). The controller's output is
//! a velocity correction `v_ctrl`; the commanded velocity is `v_uav = v_platform + v_ctrl` per
//! axis (equations 26–27), so the platform's own motion is fed forward and the PID only removes
//! the remaining offset.
//!
//! Units of the gains: `v_ctrl = kp·e + ki·∫e dt + kd·de/dt`, with `e` in metres, so `kp` is in
//! 1/s, `ki` in 1/s² and `kd` is dimensionless. The seed writes the derivative per sample,
//! `Kd·(e(k) − e(k−1))`; we use the derivative per second so that the behaviour does not change
//! with the task's QoS rate. Table 2's values are used as they stand, which equals the seed's form
//! at a 1 s sample period.
//!
//! Bad input (non-finite numbers, a non-positive time step) is rejected with a [`PidError`] and
//! leaves the controller's state untouched, so one bad sample cannot poison the integral.

use nalgebra::Vector2;
use thiserror::Error;

/// Errors from the PID's configuration or from one step's input.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PidError {
    /// A number in the configuration or the input is NaN or infinite.
    #[error("PID {name} is not finite ({value}); every input must be a finite number")]
    NonFinite { name: &'static str, value: f64 },
    /// A gain or limit that must not be negative is negative.
    #[error("PID {name} is negative ({value}); it must be ≥ 0")]
    Negative { name: &'static str, value: f64 },
    /// The time step is zero or negative.
    #[error("PID time step dt_s = {dt_s} must be > 0 s")]
    NonPositiveTimeStep { dt_s: f64 },
}

/// One set of PID gains (see the module documentation for their units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidGains {
    /// Proportional gain, (m/s) per m of offset.
    pub kp_per_s: f64,
    /// Integral gain, (m/s) per m·s of accumulated offset.
    pub ki_per_s2: f64,
    /// Derivative gain, (m/s) per m/s of offset rate.
    pub kd: f64,
}

impl PidGains {
    fn validate(&self) -> Result<(), PidError> {
        check_non_negative("kp_per_s", self.kp_per_s)?;
        check_non_negative("ki_per_s2", self.ki_per_s2)?;
        check_non_negative("kd", self.kd)
    }
}

/// Which of the two gain sets is active.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GainStage {
    /// Height ≥ the switch height: the softer, far-away gains.
    High,
    /// Height < the switch height: the stiffer, close-in gains.
    Low,
}

/// The two gain sets and the height at which they switch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwoStageGains {
    /// At or above this height above the platform the `high` set is used, below it the `low` set.
    pub switch_height_m: f64,
    pub high: PidGains,
    pub low: PidGains,
}

impl TwoStageGains {
    /// Seed 000 Table 2, "Simulation": ≥ 4 m: Kp 0.80, Ki 0.00, Kd 0.35; < 4 m: Kp 1.50, Ki 0.00,
    /// Kd 0.50.
    pub fn seed_simulation() -> Self {
        Self {
            switch_height_m: 4.0,
            high: PidGains {
                kp_per_s: 0.80,
                ki_per_s2: 0.0,
                kd: 0.35,
            },
            low: PidGains {
                kp_per_s: 1.50,
                ki_per_s2: 0.0,
                kd: 0.50,
            },
        }
    }

    /// Seed 000 Table 2, "Real-World (DJI)": ≥ 3 m: Kp 0.50, Ki 0.00, Kd 0.20; < 3 m: Kp 0.70,
    /// Ki 0.00, Kd 0.25.
    pub fn seed_real_dji() -> Self {
        Self {
            switch_height_m: 3.0,
            high: PidGains {
                kp_per_s: 0.50,
                ki_per_s2: 0.0,
                kd: 0.20,
            },
            low: PidGains {
                kp_per_s: 0.70,
                ki_per_s2: 0.0,
                kd: 0.25,
            },
        }
    }

    /// The stage for a height above the platform (the seed's "≥ threshold" goes to `High`).
    pub fn stage_for_height(&self, height_m: f64) -> GainStage {
        if height_m >= self.switch_height_m {
            GainStage::High
        } else {
            GainStage::Low
        }
    }

    /// The gains of a stage.
    pub fn gains(&self, stage: GainStage) -> PidGains {
        match stage {
            GainStage::High => self.high,
            GainStage::Low => self.low,
        }
    }
}

impl Default for TwoStageGains {
    fn default() -> Self {
        Self::seed_simulation()
    }
}

/// The PID's configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidConfig {
    pub gains: TwoStageGains,
    /// Per-axis limit on `v_ctrl` (the correction, not the total velocity).
    pub max_ctrl_speed_m_s: f64,
    /// Per-axis limit on the integral term's contribution, a second guard besides the clamping.
    pub max_integral_m_s: f64,
    /// Time constant of the first-order low-pass on the derivative; 0 disables it. Vision
    /// offsets are noisy and differentiating them raw would shake the vehicle.
    pub derivative_filter_tau_s: f64,
}

impl Default for PidConfig {
    fn default() -> Self {
        Self {
            gains: TwoStageGains::default(),
            max_ctrl_speed_m_s: 3.0,
            max_integral_m_s: 1.0,
            derivative_filter_tau_s: 0.1,
        }
    }
}

impl PidConfig {
    /// Checks every number; called by [`HorizontalPid::new`].
    pub fn validate(&self) -> Result<(), PidError> {
        check_finite("gains.switch_height_m", self.gains.switch_height_m)?;
        self.gains.high.validate()?;
        self.gains.low.validate()?;
        check_non_negative("max_ctrl_speed_m_s", self.max_ctrl_speed_m_s)?;
        check_non_negative("max_integral_m_s", self.max_integral_m_s)?;
        check_non_negative("derivative_filter_tau_s", self.derivative_filter_tau_s)
    }
}

/// One step's input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidInput {
    /// Time since the previous step.
    pub dt_s: f64,
    /// Height of the UAV above the platform; selects the gain stage.
    pub height_m: f64,
    /// Measured horizontal position of the UAV relative to the pad centre, NE (uav − pad).
    pub uav_minus_pad_ne_m: Vector2<f64>,
    /// Wanted horizontal position of the UAV relative to the pad centre (normally zero).
    pub setpoint_ne_m: Vector2<f64>,
    /// The platform's horizontal velocity, fed forward (equations 26–27).
    pub platform_velocity_ne_m_s: Vector2<f64>,
}

/// One step's output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidOutput {
    /// `v_uav = v_platform + v_ctrl`, NE.
    pub velocity_ne_m_s: Vector2<f64>,
    /// `v_ctrl` alone, after saturation.
    pub ctrl_velocity_ne_m_s: Vector2<f64>,
    pub stage: GainStage,
    /// Whether either axis hit `max_ctrl_speed_m_s`.
    pub saturated: bool,
}

/// One axis's memory.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct AxisState {
    /// The integral term's contribution (ki already applied), so a gain switch does not make
    /// it jump.
    integral_m_s: f64,
    previous_measurement_m: Option<f64>,
    filtered_measurement_rate_m_s: f64,
}

impl AxisState {
    /// Returns (v_ctrl after saturation, saturated) and the new state, without committing it.
    fn step(
        &self,
        gains: &PidGains,
        config: &PidConfig,
        setpoint_m: f64,
        measurement_m: f64,
        dt_s: f64,
    ) -> (f64, bool, AxisState) {
        let error_m = setpoint_m - measurement_m;
        let mut next = *self;

        // Derivative on the measurement, not the error: a setpoint change gives no kick.
        let raw_rate_m_s = match self.previous_measurement_m {
            Some(previous_m) => (measurement_m - previous_m) / dt_s,
            None => 0.0,
        };
        next.filtered_measurement_rate_m_s = if self.previous_measurement_m.is_none() {
            raw_rate_m_s
        } else {
            let alpha = dt_s / (config.derivative_filter_tau_s + dt_s);
            self.filtered_measurement_rate_m_s
                + alpha * (raw_rate_m_s - self.filtered_measurement_rate_m_s)
        };
        next.previous_measurement_m = Some(measurement_m);

        let p_m_s = gains.kp_per_s * error_m;
        let d_m_s = -gains.kd * next.filtered_measurement_rate_m_s;
        let limit = config.max_ctrl_speed_m_s;

        // Anti-windup by conditional integration: integrate only if the unsaturated output
        // would not be pushed further into saturation by this step's error.
        let candidate_integral_m_s = (self.integral_m_s + gains.ki_per_s2 * error_m * dt_s)
            .clamp(-config.max_integral_m_s, config.max_integral_m_s);
        let unsaturated_m_s = p_m_s + candidate_integral_m_s + d_m_s;
        let winding_up = (unsaturated_m_s > limit && error_m > 0.0)
            || (unsaturated_m_s < -limit && error_m < 0.0);
        if !winding_up {
            next.integral_m_s = candidate_integral_m_s;
        }
        let total_m_s = p_m_s + next.integral_m_s + d_m_s;
        let saturated = total_m_s.abs() > limit;
        (total_m_s.clamp(-limit, limit), saturated, next)
    }
}

/// The two-stage PID on the north and east axes.
#[derive(Debug, Clone, PartialEq)]
pub struct HorizontalPid {
    config: PidConfig,
    axes: [AxisState; 2],
}

impl HorizontalPid {
    /// A controller with empty memory; fails on a bad configuration.
    pub fn new(config: PidConfig) -> Result<Self, PidError> {
        config.validate()?;
        Ok(Self {
            config,
            axes: [AxisState::default(); 2],
        })
    }

    pub fn config(&self) -> &PidConfig {
        &self.config
    }

    /// Forgets the integral and the derivative's memory (e.g. after the target was lost).
    pub fn reset(&mut self) {
        self.axes = [AxisState::default(); 2];
    }

    /// One control step. On error the state is unchanged.
    pub fn step(&mut self, input: &PidInput) -> Result<PidOutput, PidError> {
        check_finite("dt_s", input.dt_s)?;
        if input.dt_s <= 0.0 {
            return Err(PidError::NonPositiveTimeStep { dt_s: input.dt_s });
        }
        check_finite("height_m", input.height_m)?;
        for axis in 0..2 {
            check_finite("uav_minus_pad_ne_m", input.uav_minus_pad_ne_m[axis])?;
            check_finite("setpoint_ne_m", input.setpoint_ne_m[axis])?;
            check_finite(
                "platform_velocity_ne_m_s",
                input.platform_velocity_ne_m_s[axis],
            )?;
        }

        let stage = self.config.gains.stage_for_height(input.height_m);
        let gains = self.config.gains.gains(stage);
        let mut ctrl = Vector2::zeros();
        let mut saturated = false;
        for axis in 0..2 {
            let (v_m_s, axis_saturated, next) = self.axes[axis].step(
                &gains,
                &self.config,
                input.setpoint_ne_m[axis],
                input.uav_minus_pad_ne_m[axis],
                input.dt_s,
            );
            self.axes[axis] = next;
            ctrl[axis] = v_m_s;
            saturated |= axis_saturated;
        }
        Ok(PidOutput {
            velocity_ne_m_s: input.platform_velocity_ne_m_s + ctrl,
            ctrl_velocity_ne_m_s: ctrl,
            stage,
            saturated,
        })
    }
}

fn check_finite(name: &'static str, value: f64) -> Result<(), PidError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(PidError::NonFinite { name, value })
    }
}

fn check_non_negative(name: &'static str, value: f64) -> Result<(), PidError> {
    check_finite(name, value)?;
    if value < 0.0 {
        Err(PidError::Negative { name, value })
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p_only(kp_per_s: f64) -> PidConfig {
        let gains = PidGains {
            kp_per_s,
            ki_per_s2: 0.0,
            kd: 0.0,
        };
        PidConfig {
            gains: TwoStageGains {
                switch_height_m: 4.0,
                high: gains,
                low: gains,
            },
            max_ctrl_speed_m_s: 100.0,
            max_integral_m_s: 1.0,
            derivative_filter_tau_s: 0.0,
        }
    }

    fn input(dt_s: f64, height_m: f64, uav_minus_pad_ne_m: Vector2<f64>) -> PidInput {
        PidInput {
            dt_s,
            height_m,
            uav_minus_pad_ne_m,
            setpoint_ne_m: Vector2::zeros(),
            platform_velocity_ne_m_s: Vector2::zeros(),
        }
    }

    #[test]
    fn table_2_defaults() {
        let g = TwoStageGains::default();
        assert_eq!(g.switch_height_m, 4.0);
        assert_eq!(
            (g.high.kp_per_s, g.high.ki_per_s2, g.high.kd),
            (0.80, 0.0, 0.35)
        );
        assert_eq!(
            (g.low.kp_per_s, g.low.ki_per_s2, g.low.kd),
            (1.50, 0.0, 0.50)
        );
        let dji = TwoStageGains::seed_real_dji();
        assert_eq!(dji.switch_height_m, 3.0);
        assert_eq!((dji.high.kp_per_s, dji.high.kd), (0.50, 0.20));
        assert_eq!((dji.low.kp_per_s, dji.low.kd), (0.70, 0.25));
    }

    /// P-only on a pure integrator (x' = v): the discrete loop gives e(k) = e0·(1 − kp·dt)^k,
    /// which tends to e0·exp(−kp·t); both closed forms are checked, on both axes.
    #[test]
    fn p_only_on_integrator_matches_closed_form() {
        let kp_per_s = 0.8;
        let dt_s = 0.01;
        let mut pid = HorizontalPid::new(p_only(kp_per_s)).unwrap();
        let mut x = Vector2::new(2.0, -1.0);
        let x0 = x;
        for k in 1..=500 {
            let out = pid.step(&input(dt_s, 10.0, x)).unwrap();
            x += out.velocity_ne_m_s * dt_s;
            let discrete = x0 * (1.0 - kp_per_s * dt_s).powi(k);
            assert!((x - discrete).norm() < 1e-12, "step {k}: {x} vs {discrete}");
            let continuous = x0 * (-kp_per_s * k as f64 * dt_s).exp();
            assert!((x - continuous).norm() < 0.01 * x0.norm());
        }
        // Monotone, no overshoot: after 5 s (4 time constants) about 1.8 % remains.
        assert!(x[0] > 0.0 && x[0] < 0.02 * 2.0 + 1e-3);
    }

    #[test]
    fn feed_forward_adds_platform_velocity() {
        let mut pid = HorizontalPid::new(PidConfig::default()).unwrap();
        let mut i = input(0.05, 7.5, Vector2::zeros());
        i.platform_velocity_ne_m_s = Vector2::new(3.0, -1.0);
        let out = pid.step(&i).unwrap();
        assert_eq!(out.ctrl_velocity_ne_m_s, Vector2::zeros());
        assert_eq!(out.velocity_ne_m_s, Vector2::new(3.0, -1.0));
    }

    #[test]
    fn gain_switches_at_threshold() {
        let config = PidConfig {
            derivative_filter_tau_s: 0.0,
            ..PidConfig::default()
        };
        let offset = Vector2::new(-1.0, 0.5);
        for (height_m, stage, kp) in [
            (4.0, GainStage::High, 0.80),
            (4.0 + 1e-9, GainStage::High, 0.80),
            (4.0 - 1e-9, GainStage::Low, 1.50),
            (1.0, GainStage::Low, 1.50),
        ] {
            // A fresh controller per height: first step has no derivative, so v_ctrl = kp·e.
            let mut pid = HorizontalPid::new(config).unwrap();
            let out = pid.step(&input(0.05, height_m, offset)).unwrap();
            assert_eq!(out.stage, stage, "height {height_m}");
            assert!((out.ctrl_velocity_ne_m_s - (-offset * kp)).norm() < 1e-12);
        }
    }

    #[test]
    fn derivative_uses_measurement_rate_and_ignores_setpoint_steps() {
        let mut config = p_only(0.0);
        config.gains.high.kd = 0.5;
        config.gains.low.kd = 0.5;
        let mut pid = HorizontalPid::new(config).unwrap();
        pid.step(&input(0.1, 10.0, Vector2::new(1.0, 0.0))).unwrap();
        // Measurement moving at +2 m/s north → d-term −kd·2 = −1 m/s.
        let out = pid.step(&input(0.1, 10.0, Vector2::new(1.2, 0.0))).unwrap();
        assert!((out.ctrl_velocity_ne_m_s[0] + 1.0).abs() < 1e-12);
        // The measurement stops; the setpoint jumps: no derivative kick.
        let mut i = input(0.1, 10.0, Vector2::new(1.2, 0.0));
        i.setpoint_ne_m = Vector2::new(5.0, 5.0);
        let out = pid.step(&i).unwrap();
        assert_eq!(out.ctrl_velocity_ne_m_s, Vector2::zeros());
    }

    #[test]
    fn saturation_and_anti_windup() {
        let gains = PidGains {
            kp_per_s: 1.0,
            ki_per_s2: 0.5,
            kd: 0.0,
        };
        let config = PidConfig {
            gains: TwoStageGains {
                switch_height_m: 4.0,
                high: gains,
                low: gains,
            },
            max_ctrl_speed_m_s: 2.0,
            max_integral_m_s: 10.0,
            derivative_filter_tau_s: 0.0,
        };
        let mut pid = HorizontalPid::new(config).unwrap();
        // A large offset held for 20 s: the output is pinned at the limit …
        for _ in 0..200 {
            let out = pid
                .step(&input(0.1, 10.0, Vector2::new(-10.0, 0.0)))
                .unwrap();
            assert_eq!(out.ctrl_velocity_ne_m_s[0], 2.0);
            assert!(out.saturated);
        }
        // … and the integral did not wind up: kp·e alone saturates, so nothing was integrated.
        assert_eq!(pid.axes[0].integral_m_s, 0.0);
        // Once the offset is gone the output falls at once instead of staying pinned.
        let out = pid.step(&input(0.1, 10.0, Vector2::zeros())).unwrap();
        assert!(out.ctrl_velocity_ne_m_s[0].abs() < 1e-12);
        assert!(!out.saturated);

        // Without saturation the integral does accumulate (so the guard above is meaningful),
        // and it is bounded by max_integral_m_s.
        let mut pid = HorizontalPid::new(PidConfig {
            max_ctrl_speed_m_s: 100.0,
            max_integral_m_s: 0.3,
            ..config
        })
        .unwrap();
        for _ in 0..100 {
            pid.step(&input(0.1, 10.0, Vector2::new(-1.0, 0.0)))
                .unwrap();
        }
        assert_eq!(pid.axes[0].integral_m_s, 0.3);
    }

    #[test]
    fn bad_input_is_rejected_and_leaves_state_untouched() {
        let mut pid = HorizontalPid::new(PidConfig::default()).unwrap();
        pid.step(&input(0.1, 5.0, Vector2::new(1.0, 1.0))).unwrap();
        let before = pid.clone();
        let nan_offset = input(0.1, 5.0, Vector2::new(f64::NAN, 0.0));
        assert!(matches!(
            pid.step(&nan_offset),
            Err(PidError::NonFinite {
                name: "uav_minus_pad_ne_m",
                ..
            })
        ));
        assert_eq!(
            pid.step(&input(0.0, 5.0, Vector2::zeros())),
            Err(PidError::NonPositiveTimeStep { dt_s: 0.0 })
        );
        assert!(pid
            .step(&input(0.1, f64::INFINITY, Vector2::zeros()))
            .is_err());
        assert_eq!(pid, before);

        let mut bad = PidConfig::default();
        bad.gains.low.kp_per_s = -1.0;
        assert!(matches!(
            HorizontalPid::new(bad),
            Err(PidError::Negative {
                name: "kp_per_s",
                ..
            })
        ));
    }
}
