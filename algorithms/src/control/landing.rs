//! The landing state machine of seed 000 §3, driving the two-stage PID of §2.3.
//!
//! ```text
//! Search ──fix──▶ Follow ──at the held height (IH at first), centred for a dwell──▶ Descend
//! Descend ──off centre by the hysteresis factor──▶ Follow (holding the current height)
//! Descend ──below LH, centred for the commit dwell──▶ FinalLanding (land command) ──▶ Landed
//! Follow / Descend ──target lost > lost timeout──▶ Reacquire (climb to IH)
//! Reacquire ──fix──▶ Follow at IH;  Reacquire ──lost > search timeout──▶ Search
//! FinalLanding never aborts; touchdown reported by the autopilot → Landed from any mode.
//! ```
//!
//! The seed sets an initial altitude IH (7.5 m in its simulation) at which following starts, and
//! a final altitude LH (1.5 m) below which it sends the land command and stops steering. Our
//! platform is a tractor moving at up to 3 m/s: a vertical landing with no horizontal control
//! would drift off the pad by metres, so after the commit we keep streaming the PID's
//! horizontal setpoint (or the platform's velocity when the target is out of view) together with
//! the land command. What the commit does change is that nothing aborts it any more.
//!
//! Bad input: a non-finite time, height or platform velocity, or a time that does not increase,
//! is a [`LandingError`] and leaves the machine untouched (the caller should hover, see
//! [`LandingOutput::hover`]). A fix with non-finite numbers, or one whose covariance says it is
//! too uncertain, counts as no fix: it is what a lost target looks like, and the machine handles
//! it by its timeouts.

use nalgebra::{Matrix3, Vector2, Vector3};
use thiserror::Error;

use super::mpc::{MpcConfig, MpcController, MpcError};
use super::pid::{PidConfig, PidError};

mod machine;
use machine::Machine;

/// Which controller steers horizontally while a fix is in hand.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HorizontalController {
    /// Seed 000's two-stage PID (`LandingConfig::pid`).
    Pid,
    /// The MPC; its `dt_s` must be the period at which the controller is stepped, see
    /// [`LandingController::set_control_period`].
    Mpc(MpcConfig),
}

/// The mode of the landing procedure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum LandingMode {
    /// No target yet: hold position at the initial height IH.
    Search,
    /// Target in view: track the pad and hold height (IH at first).
    Follow,
    /// Centred: track the pad and descend.
    Descend,
    /// Target lost too long before the commit: climb back to IH, keep the platform's velocity.
    Reacquire,
    /// Below LH and centred: the land command is sent; no abort any more.
    FinalLanding,
    /// On the pad.
    Landed,
}

/// Errors from the configuration or from one step's input.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LandingError {
    #[error("landing config: {name} = {value} is invalid: {why}")]
    Config {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("landing input {name} is not finite; every input must be a finite number")]
    NonFinite { name: &'static str },
    #[error("landing input time_s = {time_s} does not increase (previous {previous_s})")]
    TimeNotIncreasing { previous_s: f64, time_s: f64 },
    #[error(transparent)]
    Pid(#[from] PidError),
    #[error(transparent)]
    Mpc(#[from] MpcError),
}

/// The landing procedure's configuration. Defaults: seed 000 §3's IH = 7.5 m and LH = 1.5 m; the
/// rest are our choices, named so a mission can tune them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandingConfig {
    /// IH: the height above the platform at which following starts and to which an abort climbs.
    pub initial_height_m: f64,
    /// LH: below this height, once centred, the land command is sent.
    pub final_landing_height_m: f64,
    /// How close to the held height counts as "reached".
    pub height_tolerance_m: f64,
    /// The horizontal error that counts as centred at IH …
    pub centred_radius_at_initial_height_m: f64,
    /// … and at LH; linear in between, so the threshold tightens as the UAV comes down.
    pub centred_radius_at_final_height_m: f64,
    /// Descend → Follow when the error exceeds this factor × the centred radius (hysteresis).
    pub recentre_factor: f64,
    /// How long Follow must see the target centred before descending.
    pub centred_dwell_s: f64,
    /// How long the target must stay centred below LH before the commit; one lucky noisy
    /// sample must not commit a landing.
    pub commit_dwell_s: f64,
    /// Descent speed in Descend while centred.
    pub descent_speed_m_s: f64,
    /// Descent speed after the commit.
    pub final_descent_speed_m_s: f64,
    /// The flare: in the last of the descent the commanded rate falls at this deceleration
    /// (a constant-deceleration profile, `√(v_td² + 2·a·h)`) to `touchdown_speed_m_s` at the
    /// pad, so the commit can be quick where the wind changes fastest and the contact still
    /// soft (PX4's MPC_LAND_SPEED is 0.7 m/s, ArduPilot's LAND_SPEED 0.5). 0 (the default):
    /// no flare, the seed's constant final descent.
    pub flare_deceleration_m_s2: f64,
    pub touchdown_speed_m_s: f64,
    /// The profile is read this far ahead at the measured descent rate: the autopilot's
    /// vertical velocity loop lags a falling command (PX4's MPC_Z_VEL_P_ACC = 4: about 0.25 s),
    /// and a profile followed late meets the pad faster than it asks.
    pub flare_lead_s: f64,
    /// Limit on climb/descent speed when holding a height.
    pub max_height_hold_speed_m_s: f64,
    /// Vertical speed per metre of height error when holding a height.
    pub height_gain_per_s: f64,
    /// Target unseen for longer than this before the commit → Reacquire.
    pub lost_timeout_s: f64,
    /// Target unseen for longer than this → Search.
    pub search_timeout_s: f64,
    /// A fix whose horizontal standard deviation (√ of the larger NE variance) exceeds this
    /// counts as no fix.
    pub max_fix_std_m: f64,
    /// At or below this height in FinalLanding the UAV counts as landed.
    pub touchdown_height_m: f64,
    /// The platform's acceleration (differentiated from its velocity input) is fed forward
    /// over this lead, about the autopilot's velocity-loop lag, so a turning tractor does not
    /// pull the UAV off centre. 0 gives the seed's law (equations 26–27) unchanged.
    pub platform_accel_lead_s: f64,
    /// Low-pass time constant on that acceleration.
    pub platform_accel_filter_tau_s: f64,
    /// Limit on the commanded horizontal speed.
    pub max_horizontal_speed_m_s: f64,
    /// Wind feed-forward: what the autopilot's velocity loop falls short of the command (its
    /// integrator lags a changing wind, e.g. the wind fading as the vehicle descends) is
    /// estimated with this low-pass time constant and added to the next command. 0 (the
    /// default): off, the seed's law.
    pub wind_compensation_tau_s: f64,
    /// Limit on that compensation.
    pub max_wind_compensation_m_s: f64,
    /// The autopilot's velocity response, as a first-order lag (PX4's MPC_XY_VEL_P_ACC = 1.8
    /// and the attitude loop: about 0.4 s): what a command is expected to give, so that the
    /// lag of a manoeuvre is not taken for wind.
    pub autopilot_velocity_tau_s: f64,
    /// Low-pass time constant on the keep-in-view offset ([`LandingInput::pad_in_view_offset_per_height`]):
    /// it follows the lean the wind holds, not each manoeuvre's.
    pub keep_in_view_tau_s: f64,
    /// Wind-shear feed-forward while descending: the roughness length of the ground's
    /// logarithmic wind profile (0.05 m over crops). 0 (the default): off, the seed's law.
    pub wind_shear_roughness_m: f64,
    /// How far ahead the descent's wind is predicted, about the velocity loop's lag.
    pub wind_shear_lead_s: f64,
    /// After the commit, the command strays from the platform's velocity (with its
    /// acceleration fed forward and the wind's shortfall made up) by at most this: descending
    /// fast, the autopilot spends its thrust on the descent and follows a large correction
    /// late, with a steep lean (the real PX4 pitched 45° at 0.4 m under the stiff close-in PID
    /// asking 3 m/s more than the pad's speed).
    pub max_final_correction_m_s: f64,
    /// In the last this many metres above the pad, by at most `max_touchdown_correction_m_s`:
    /// a correction that late cannot centre the vehicle, it only tips it. A descent that
    /// stalls there is the touchdown (the autopilot's own land detector takes about a second,
    /// while a vehicle on the ground pushed by setpoints leans over).
    pub touchdown_correction_height_m: f64,
    /// The band reaches higher when the descent is fast: at least this long before contact at
    /// the measured descent rate. The autopilot's lean answers a command about this late (the
    /// real PX4 descending at 1.5 m/s still leaned into the last 0.3 m's correction at contact).
    pub touchdown_correction_lead_s: f64,
    pub max_touchdown_correction_m_s: f64,
    /// Gust feed-forward after the commit: the change of the aerodynamic acceleration from its
    /// baseline (low-passed over `gust_baseline_tau_s`, what the autopilot's velocity integrator
    /// has learned) × this is taken off the velocity command, so the velocity loop pushes back
    /// at once instead of after a drift; not in the last `touchdown_correction_height_m`,
    /// where it only tipped the real PX4 (a wind-free world, where the "gust" is the lag
    /// between its attitude and its velocity). 1/MPC_XY_VEL_P_ACC (0.56 s) asks the loop for
    /// exactly the gust's acceleration; its attitude lag wants a little more. 0 (the
    /// default): off.
    pub gust_feed_forward_s: f64,
    pub gust_baseline_tau_s: f64,
    pub pid: PidConfig,
    pub controller: HorizontalController,
}

impl Default for LandingConfig {
    fn default() -> Self {
        Self {
            initial_height_m: 7.5,
            final_landing_height_m: 1.5,
            height_tolerance_m: 0.3,
            centred_radius_at_initial_height_m: 1.0,
            centred_radius_at_final_height_m: 0.15,
            recentre_factor: 2.0,
            centred_dwell_s: 0.5,
            commit_dwell_s: 0.3,
            descent_speed_m_s: 0.7,
            final_descent_speed_m_s: 1.0,
            flare_deceleration_m_s2: 0.0,
            touchdown_speed_m_s: 0.7,
            flare_lead_s: 0.25,
            max_height_hold_speed_m_s: 1.0,
            height_gain_per_s: 1.0,
            lost_timeout_s: 1.0,
            search_timeout_s: 10.0,
            max_fix_std_m: 0.5,
            touchdown_height_m: 0.05,
            platform_accel_lead_s: 0.2,
            platform_accel_filter_tau_s: 0.2,
            max_horizontal_speed_m_s: 10.0,
            wind_compensation_tau_s: 0.0,
            max_wind_compensation_m_s: 3.0,
            autopilot_velocity_tau_s: 0.4,
            keep_in_view_tau_s: 1.0,
            wind_shear_roughness_m: 0.0,
            wind_shear_lead_s: 0.3,
            max_final_correction_m_s: 1.5,
            touchdown_correction_height_m: 0.3,
            touchdown_correction_lead_s: 0.0,
            max_touchdown_correction_m_s: 0.3,
            gust_feed_forward_s: 0.0,
            gust_baseline_tau_s: 1.0,
            pid: PidConfig::default(),
            controller: HorizontalController::Pid,
        }
    }
}

impl LandingConfig {
    pub fn validate(&self) -> Result<(), LandingError> {
        let positive = [
            ("initial_height_m", self.initial_height_m),
            ("final_landing_height_m", self.final_landing_height_m),
            ("height_tolerance_m", self.height_tolerance_m),
            (
                "centred_radius_at_initial_height_m",
                self.centred_radius_at_initial_height_m,
            ),
            (
                "centred_radius_at_final_height_m",
                self.centred_radius_at_final_height_m,
            ),
            ("descent_speed_m_s", self.descent_speed_m_s),
            ("final_descent_speed_m_s", self.final_descent_speed_m_s),
            ("touchdown_speed_m_s", self.touchdown_speed_m_s),
            ("max_height_hold_speed_m_s", self.max_height_hold_speed_m_s),
            ("height_gain_per_s", self.height_gain_per_s),
            ("lost_timeout_s", self.lost_timeout_s),
            ("search_timeout_s", self.search_timeout_s),
            ("max_fix_std_m", self.max_fix_std_m),
            ("max_horizontal_speed_m_s", self.max_horizontal_speed_m_s),
            ("max_final_correction_m_s", self.max_final_correction_m_s),
            ("gust_baseline_tau_s", self.gust_baseline_tau_s),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(config_error(name, value, "must be a finite number > 0"));
            }
        }
        for (name, value) in [
            ("centred_dwell_s", self.centred_dwell_s),
            ("commit_dwell_s", self.commit_dwell_s),
            ("platform_accel_lead_s", self.platform_accel_lead_s),
            (
                "platform_accel_filter_tau_s",
                self.platform_accel_filter_tau_s,
            ),
            ("touchdown_height_m", self.touchdown_height_m),
            ("wind_compensation_tau_s", self.wind_compensation_tau_s),
            ("max_wind_compensation_m_s", self.max_wind_compensation_m_s),
            ("autopilot_velocity_tau_s", self.autopilot_velocity_tau_s),
            ("keep_in_view_tau_s", self.keep_in_view_tau_s),
            ("wind_shear_roughness_m", self.wind_shear_roughness_m),
            ("wind_shear_lead_s", self.wind_shear_lead_s),
            (
                "touchdown_correction_lead_s",
                self.touchdown_correction_lead_s,
            ),
            (
                "touchdown_correction_height_m",
                self.touchdown_correction_height_m,
            ),
            (
                "max_touchdown_correction_m_s",
                self.max_touchdown_correction_m_s,
            ),
            ("gust_feed_forward_s", self.gust_feed_forward_s),
            ("flare_deceleration_m_s2", self.flare_deceleration_m_s2),
            ("flare_lead_s", self.flare_lead_s),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(config_error(name, value, "must be a finite number ≥ 0"));
            }
        }
        if self.final_landing_height_m >= self.initial_height_m {
            return Err(config_error(
                "final_landing_height_m",
                self.final_landing_height_m,
                "LH must be below IH (initial_height_m)",
            ));
        }
        if self.centred_radius_at_final_height_m > self.centred_radius_at_initial_height_m {
            return Err(config_error(
                "centred_radius_at_final_height_m",
                self.centred_radius_at_final_height_m,
                "the centred radius must tighten with altitude: at LH ≤ at IH",
            ));
        }
        if !(self.recentre_factor.is_finite() && self.recentre_factor >= 1.0) {
            return Err(config_error(
                "recentre_factor",
                self.recentre_factor,
                "must be ≥ 1 (it is a hysteresis band)",
            ));
        }
        if self.search_timeout_s < self.lost_timeout_s {
            return Err(config_error(
                "search_timeout_s",
                self.search_timeout_s,
                "must be ≥ lost_timeout_s",
            ));
        }
        self.pid.validate()?;
        if let HorizontalController::Mpc(mpc) = self.controller {
            mpc.validate()?;
        }
        Ok(())
    }

    /// The descent rate commanded after the commit at a height above the pad, descending at
    /// `descent_rate_m_s`: `final_descent_speed_m_s`, or less in the flare.
    pub fn final_descent_rate_m_s(&self, height_m: f64, descent_rate_m_s: f64) -> f64 {
        if self.flare_deceleration_m_s2 <= 0.0 {
            return self.final_descent_speed_m_s;
        }
        let ahead_m = (height_m - descent_rate_m_s.max(0.0) * self.flare_lead_s).max(0.0);
        let touchdown_m_s = self.touchdown_speed_m_s.min(self.final_descent_speed_m_s);
        (touchdown_m_s.powi(2) + 2.0 * self.flare_deceleration_m_s2 * ahead_m)
            .sqrt()
            .min(self.final_descent_speed_m_s)
    }

    /// The centred radius at a height: `centred_radius_at_final_height_m` at or below LH,
    /// `centred_radius_at_initial_height_m` at or above IH, linear in between.
    pub fn centred_radius_m(&self, height_m: f64) -> f64 {
        let span_m = self.initial_height_m - self.final_landing_height_m;
        let fraction = ((height_m - self.final_landing_height_m) / span_m).clamp(0.0, 1.0);
        self.centred_radius_at_final_height_m
            + fraction
                * (self.centred_radius_at_initial_height_m - self.centred_radius_at_final_height_m)
    }
}

fn config_error(name: &'static str, value: f64, why: &'static str) -> LandingError {
    LandingError::Config { name, value, why }
}

/// The tracker's estimate of where the UAV is relative to the pad.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativeFix {
    /// UAV position minus pad-centre position, NED.
    pub uav_minus_pad_ned_m: Vector3<f64>,
    /// Its covariance.
    pub covariance_ned_m2: Matrix3<f64>,
}

impl RelativeFix {
    /// A fix with a diagonal covariance of `std_m`² on every axis.
    pub fn with_std(uav_minus_pad_ned_m: Vector3<f64>, std_m: f64) -> Self {
        Self {
            uav_minus_pad_ned_m,
            covariance_ned_m2: Matrix3::identity() * (std_m * std_m),
        }
    }

    /// √ of the larger horizontal variance, or None when any number is not finite.
    fn horizontal_std_m(&self) -> Option<f64> {
        let finite = self.uav_minus_pad_ned_m.iter().all(|v| v.is_finite())
            && self.covariance_ned_m2.iter().all(|v| v.is_finite());
        let variance_m2 = self.covariance_ned_m2[(0, 0)].max(self.covariance_ned_m2[(1, 1)]);
        (finite && variance_m2 >= 0.0).then(|| variance_m2.sqrt())
    }
}

/// One step's input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandingInput {
    /// Monotonic time; must increase strictly from step to step.
    pub time_s: f64,
    /// The relative position estimate, if the tracker has one.
    pub fix: Option<RelativeFix>,
    /// Height of the UAV above the platform's landing surface.
    pub height_above_pad_m: f64,
    /// The platform's estimated horizontal velocity, NE.
    pub platform_velocity_ne_m_s: Vector2<f64>,
    /// The autopilot reports that it is on the ground (e.g. MAVLink EXTENDED_SYS_STATE).
    pub touchdown_detected: bool,
    /// The UAV's own horizontal velocity from the autopilot (the MPC's initial state).
    pub uav_velocity_ne_m_s: Vector2<f64>,
    /// Whether the mission allows the descent now; while false the machine follows at its
    /// height and never leaves Follow for Descend (e.g. the tracking phase before landing).
    pub descent_allowed: bool,
    /// Where the tracker predicts the UAV is relative to the pad (UAV − pad, NE) when no fix
    /// is usable: Reacquire flies towards it rather than only matching the platform's speed,
    /// so a vehicle left behind (a link loss, a blind camera) catches up.
    pub predicted_uav_minus_pad_ne_m: Option<Vector2<f64>>,
    /// The autopilot is flying these setpoints (PX4 OFFBOARD, ArduPilot GUIDED) on fresh
    /// telemetry. Only then does the wind feed-forward learn from the gap between what was
    /// commanded and what was flown: a vehicle held by a failsafe or a pilot is not wind.
    pub setpoints_followed: bool,
    /// Where the pad must lie relative to the vehicle for its camera to see it, per metre of
    /// height (pad − UAV, NE; [`crate::estimation::projection::pad_in_view_offset_ne_m`] at
    /// 1 m). Zero (a level vehicle, or no camera model) flies straight over the pad; in strong
    /// wind the vehicle leans further than its camera's half field of view and follows from
    /// upwind instead, by this times its height, so the offset vanishes at touchdown.
    pub pad_in_view_offset_per_height: Vector2<f64>,
    /// The wind the vehicle leans against and its height above the ground, when the autopilot
    /// reports them: the descent's wind-shear feed-forward works from it.
    pub near_ground_wind: Option<NearGroundWind>,
}

/// What the wind does to the vehicle now, and where.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearGroundWind {
    /// Height above the ground (not the pad), m.
    pub altitude_m: f64,
    /// The horizontal aerodynamic acceleration on the vehicle, NE
    /// ([`super::wind_shear::aerodynamic_accel_ne_m_s2`]).
    pub aerodynamic_accel_ne_m_s2: Vector2<f64>,
}

/// One step's output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandingOutput {
    pub mode: LandingMode,
    /// Velocity setpoint, NED (z positive down).
    pub velocity_setpoint_ned_m_s: Vector3<f64>,
    /// Send (and keep sending) the land command.
    pub land_command: bool,
    /// Horizontal distance to the pad centre, when a usable fix came in this step.
    pub horizontal_error_m: Option<f64>,
    /// The centred threshold at the current height.
    pub centred_radius_m: f64,
}

impl LandingOutput {
    /// What a caller should command when [`LandingController::step`] fails: hover, no land
    /// command unless the commit was already made.
    pub fn hover(mode: LandingMode) -> Self {
        Self {
            mode,
            velocity_setpoint_ned_m_s: Vector3::zeros(),
            land_command: matches!(mode, LandingMode::FinalLanding | LandingMode::Landed),
            horizontal_error_m: None,
            centred_radius_m: 0.0,
        }
    }
}

/// The landing state machine with its horizontal controller.
pub struct LandingController {
    machine: Machine,
    /// Outside the machine because a clarabel solver cannot be cloned; a step only touches it
    /// after every check that can fail has passed.
    mpc: Option<MpcController>,
}

impl std::fmt::Debug for LandingController {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LandingController")
            .field("machine", &self.machine)
            .field("mpc", &self.mpc.as_ref().map(|m| *m.config()))
            .finish()
    }
}

impl LandingController {
    pub fn new(config: LandingConfig) -> Result<Self, LandingError> {
        let machine = Machine::new(config)?;
        let mpc = match config.controller {
            HorizontalController::Pid => None,
            HorizontalController::Mpc(mpc) => Some(MpcController::new(mpc)?),
        };
        Ok(Self { machine, mpc })
    }

    pub fn mode(&self) -> LandingMode {
        self.machine.mode
    }

    pub fn config(&self) -> &LandingConfig {
        &self.machine.config
    }

    /// Re-times the MPC for a new control period (a QoS change of the landing task): its model
    /// step becomes `period_s` and its horizon keeps its length in seconds. No-op for the PID,
    /// whose integral and derivative use the measured interval.
    pub fn set_control_period(&mut self, period_s: f64) -> Result<(), LandingError> {
        let Some(mpc) = &self.mpc else {
            return Ok(());
        };
        let old = *mpc.config();
        if !(period_s.is_finite() && period_s > 0.0) {
            return Err(config_error(
                "control period_s",
                period_s,
                "must be a finite number > 0",
            ));
        }
        let horizon_s = old.horizon_steps as f64 * old.dt_s;
        let new = MpcConfig {
            dt_s: period_s,
            horizon_steps: ((horizon_s / period_s).round() as usize).max(1),
            ..old
        };
        if new != old {
            self.mpc = Some(MpcController::new(new)?);
            self.machine.config.controller = HorizontalController::Mpc(new);
        }
        Ok(())
    }

    /// One step: update the mode from the input, then compute the setpoint for the new mode.
    pub fn step(&mut self, input: &LandingInput) -> Result<LandingOutput, LandingError> {
        if !input.uav_velocity_ne_m_s.iter().all(|v| v.is_finite()) {
            return Err(LandingError::NonFinite {
                name: "uav_velocity_ne_m_s",
            });
        }
        if !input
            .pad_in_view_offset_per_height
            .iter()
            .all(|v| v.is_finite())
        {
            return Err(LandingError::NonFinite {
                name: "pad_in_view_offset_per_height",
            });
        }
        self.machine.step(input, self.mpc.as_mut())
    }
}

#[cfg(test)]
mod tests;
