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

use super::mpc::{MpcConfig, MpcController, MpcError, MpcInput};
use super::pid::{HorizontalPid, PidConfig, PidError, PidInput};
use super::wind_shear::descent_feed_forward_ne_m_s;

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
                "touchdown_correction_height_m",
                self.touchdown_correction_height_m,
            ),
            (
                "max_touchdown_correction_m_s",
                self.max_touchdown_correction_m_s,
            ),
            ("gust_feed_forward_s", self.gust_feed_forward_s),
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

/// Low-pass time constant on the aerodynamic acceleration (the link differentiates velocities).
const AERODYNAMIC_ACCEL_TAU_S: f64 = 0.2;
/// Low-pass time constant on the descent rate, and the fraction of the final descent speed
/// below which a committed descent near the pad counts as stopped by it.
const DESCENT_RATE_TAU_S: f64 = 0.05;
const STALLED_DESCENT_FRACTION: f64 = 0.3;

/// Reacquire's pull towards the predicted pad position, per second of offset…
const REACQUIRE_GAIN_PER_S: f64 = 0.5;
/// …and its limit on top of the platform's velocity.
const REACQUIRE_MAX_CATCH_UP_M_S: f64 = 3.0;

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

/// The state machine proper, with the PID's state.
#[derive(Debug, Clone, PartialEq)]
struct Machine {
    config: LandingConfig,
    pid: HorizontalPid,
    mode: LandingMode,
    last_time_s: Option<f64>,
    last_pid_time_s: Option<f64>,
    last_fix_time_s: Option<f64>,
    centred_since_s: Option<f64>,
    hold_height_m: f64,
    /// The previous step's platform velocity, for its acceleration.
    previous_platform_velocity_ne_m_s: Option<Vector2<f64>>,
    platform_accel_ne_m_s2: Vector2<f64>,
    /// The last horizontal command, and the autopilot's estimated shortfall against it.
    last_command_ne_m_s: Option<Vector2<f64>>,
    /// The velocity the commands so far should have given, by the autopilot's lag.
    expected_velocity_ne_m_s: Option<Vector2<f64>>,
    velocity_shortfall_ne_m_s: Vector2<f64>,
    /// The keep-in-view offset per metre of height, low-passed.
    pad_in_view_offset_per_height: Option<Vector2<f64>>,
    /// How far Search's commands have moved the vehicle since it began.
    search_displacement_ne_m: Vector2<f64>,
    /// The aerodynamic acceleration on the vehicle, low-passed.
    aerodynamic_accel_ne_m_s2: Option<Vector2<f64>>,
    /// The same over `gust_baseline_tau_s`: what the autopilot's integrator has learned.
    aerodynamic_baseline_ne_m_s2: Option<Vector2<f64>>,
    /// The previous step's height above the pad, and the descent rate from it, low-passed.
    previous_height_m: Option<f64>,
    descent_rate_m_s: f64,
}

impl Machine {
    fn new(config: LandingConfig) -> Result<Self, LandingError> {
        config.validate()?;
        Ok(Self {
            pid: HorizontalPid::new(config.pid)?,
            config,
            mode: LandingMode::Search,
            last_time_s: None,
            last_pid_time_s: None,
            last_fix_time_s: None,
            centred_since_s: None,
            hold_height_m: config.initial_height_m,
            previous_platform_velocity_ne_m_s: None,
            platform_accel_ne_m_s2: Vector2::zeros(),
            last_command_ne_m_s: None,
            expected_velocity_ne_m_s: None,
            velocity_shortfall_ne_m_s: Vector2::zeros(),
            pad_in_view_offset_per_height: None,
            search_displacement_ne_m: Vector2::zeros(),
            aerodynamic_accel_ne_m_s2: None,
            aerodynamic_baseline_ne_m_s2: None,
            previous_height_m: None,
            descent_rate_m_s: 0.0,
        })
    }

    fn step(
        &mut self,
        input: &LandingInput,
        mpc: Option<&mut MpcController>,
    ) -> Result<LandingOutput, LandingError> {
        let time_s = input.time_s;
        let height_m = input.height_above_pad_m;
        if !time_s.is_finite() {
            return Err(LandingError::NonFinite { name: "time_s" });
        }
        if !height_m.is_finite() {
            return Err(LandingError::NonFinite {
                name: "height_above_pad_m",
            });
        }
        if !input.platform_velocity_ne_m_s.iter().all(|v| v.is_finite()) {
            return Err(LandingError::NonFinite {
                name: "platform_velocity_ne_m_s",
            });
        }
        if let Some(previous_s) = self.last_time_s {
            if time_s <= previous_s {
                return Err(LandingError::TimeNotIncreasing { previous_s, time_s });
            }
        }
        // Work on a copy so that a failure below leaves the machine untouched. The MPC never
        // fails a step (a failed solve flies its fallback), so it is stepped in place.
        let mut next = self.clone();
        let output = next.advance(input, mpc)?;
        *self = next;
        Ok(output)
    }

    fn advance(
        &mut self,
        input: &LandingInput,
        mut mpc: Option<&mut MpcController>,
    ) -> Result<LandingOutput, LandingError> {
        let c = self.config;
        let time_s = input.time_s;
        let height_m = input.height_above_pad_m;
        if let (Some(previous_s), Some(previous_v)) =
            (self.last_time_s, self.previous_platform_velocity_ne_m_s)
        {
            let dt_s = time_s - previous_s;
            let raw = (input.platform_velocity_ne_m_s - previous_v) / dt_s;
            self.platform_accel_ne_m_s2 = low_pass(
                self.platform_accel_ne_m_s2,
                raw,
                dt_s,
                c.platform_accel_filter_tau_s,
            );
        }
        self.previous_platform_velocity_ne_m_s = Some(input.platform_velocity_ne_m_s);
        if !input.setpoints_followed {
            // Nor do the PID's integral and the wind estimate mean anything while nobody flies
            // the commands: they restart when the autopilot takes them again.
            self.velocity_shortfall_ne_m_s = Vector2::zeros();
            self.expected_velocity_ne_m_s = None;
            self.pid.reset();
            self.last_pid_time_s = None;
        } else if let (Some(previous_s), Some(command)) =
            (self.last_time_s, self.last_command_ne_m_s)
        {
            if c.wind_compensation_tau_s > 0.0 {
                let dt_s = time_s - previous_s;
                let expected = self
                    .expected_velocity_ne_m_s
                    .unwrap_or(input.uav_velocity_ne_m_s);
                let expected = low_pass(expected, command, dt_s, c.autopilot_velocity_tau_s);
                self.expected_velocity_ne_m_s = Some(expected);
                let shortfall = expected - input.uav_velocity_ne_m_s;
                self.velocity_shortfall_ne_m_s = clamp_norm(
                    low_pass(
                        self.velocity_shortfall_ne_m_s,
                        shortfall,
                        dt_s,
                        c.wind_compensation_tau_s,
                    ),
                    c.max_wind_compensation_m_s,
                );
            }
        }
        let dt_s = self
            .last_time_s
            .map_or(0.0, |previous_s| time_s - previous_s);
        let raw_offset = input.pad_in_view_offset_per_height;
        let view_offset = low_pass_from(
            self.pad_in_view_offset_per_height,
            raw_offset,
            dt_s,
            c.keep_in_view_tau_s,
        );
        self.pad_in_view_offset_per_height = Some(view_offset);
        let wind = input.near_ground_wind.filter(|wind| {
            wind.altitude_m.is_finite()
                && wind.aerodynamic_accel_ne_m_s2.iter().all(|v| v.is_finite())
        });
        let raw_aero = wind.map(|wind| wind.aerodynamic_accel_ne_m_s2);
        self.aerodynamic_accel_ne_m_s2 = raw_aero.map(|raw| {
            low_pass_from(
                self.aerodynamic_accel_ne_m_s2,
                raw,
                dt_s,
                AERODYNAMIC_ACCEL_TAU_S,
            )
        });
        self.aerodynamic_baseline_ne_m_s2 = raw_aero.map(|raw| {
            low_pass_from(
                self.aerodynamic_baseline_ne_m_s2,
                raw,
                dt_s,
                c.gust_baseline_tau_s,
            )
        });
        if let Some(previous_m) = self.previous_height_m.filter(|_| dt_s > 0.0) {
            let raw_m_s = (previous_m - height_m) / dt_s;
            self.descent_rate_m_s =
                low_pass(self.descent_rate_m_s, raw_m_s, dt_s, DESCENT_RATE_TAU_S);
        }
        self.previous_height_m = Some(height_m);
        // Where the vehicle holds itself relative to the pad (UAV − pad): over it, or upwind
        // by what keeps the pad in view.
        let setpoint_ne_m = -view_offset * height_m.max(0.0);
        self.last_time_s = Some(time_s);

        let usable_fix = input.fix.filter(|fix| {
            fix.horizontal_std_m()
                .is_some_and(|std_m| std_m <= c.max_fix_std_m)
        });
        if usable_fix.is_some() {
            self.last_fix_time_s = Some(time_s);
        }
        let lost_for_s = self
            .last_fix_time_s
            .map_or(f64::INFINITY, |seen_s| time_s - seen_s);
        let error_m = usable_fix.map(|fix| (fix.uav_minus_pad_ned_m.xy() - setpoint_ne_m).norm());
        let radius_m = c.centred_radius_m(height_m);
        let centred = error_m.is_some_and(|e| e <= radius_m);

        let mode_before = self.mode;
        self.update_mode(input, lost_for_s, error_m, radius_m, centred);
        if let Some(mpc) = mpc.as_deref_mut() {
            // Coming back from no target: the previous command is stale.
            if matches!(mode_before, LandingMode::Search | LandingMode::Reacquire)
                && self.mode == LandingMode::Follow
            {
                mpc.reset();
            }
        }

        let mut tracking_velocity = |this: &mut Self| -> Result<Vector2<f64>, LandingError> {
            this.horizontal_tracking(input, usable_fix, setpoint_ne_m, mpc.as_deref_mut())
        };
        let (horizontal, vertical_down_m_s, land_command) = match self.mode {
            // Held where it began, or as far upwind of there as its camera needs to see the
            // spot it first hovered over (where the pad was expected).
            LandingMode::Search => {
                let shift = clamp_norm(
                    (setpoint_ne_m - self.search_displacement_ne_m) * REACQUIRE_GAIN_PER_S,
                    REACQUIRE_MAX_CATCH_UP_M_S,
                );
                // Where the commands have taken it (the autopilot flies them).
                self.search_displacement_ne_m += shift * dt_s;
                (shift, self.hold_height(height_m, c.initial_height_m), false)
            }
            LandingMode::Follow => {
                let h = tracking_velocity(self)?;
                (h, self.hold_height(height_m, self.hold_height_m), false)
            }
            LandingMode::Descend => {
                let h = tracking_velocity(self)?;
                // Only descend while centred; hold height while off centre or out of view.
                let down = if centred { c.descent_speed_m_s } else { 0.0 };
                (h, down, false)
            }
            LandingMode::Reacquire => {
                let catch_up = input
                    .predicted_uav_minus_pad_ne_m
                    .filter(|p| p.iter().all(|v| v.is_finite()))
                    .map_or_else(Vector2::zeros, |p| {
                        clamp_norm(
                            (setpoint_ne_m - p) * REACQUIRE_GAIN_PER_S,
                            REACQUIRE_MAX_CATCH_UP_M_S,
                        )
                    });
                (
                    input.platform_velocity_ne_m_s + catch_up,
                    self.hold_height(height_m, c.initial_height_m),
                    false,
                )
            }
            LandingMode::FinalLanding => {
                let h = tracking_velocity(self)?;
                (h, c.final_descent_speed_m_s, true)
            }
            LandingMode::Landed => (Vector2::zeros(), 0.0, true),
        };
        // Descending into the weaker wind near the ground: lean less before the velocity loop
        // finds out.
        let horizontal = match (wind, self.aerodynamic_accel_ne_m_s2) {
            (Some(wind), Some(aero))
                if c.wind_shear_roughness_m > 0.0
                    && vertical_down_m_s > 0.0
                    && matches!(self.mode, LandingMode::Descend | LandingMode::FinalLanding) =>
            {
                // The descent ends on the pad: the wind is never predicted below it.
                let lead_m = (vertical_down_m_s * c.wind_shear_lead_s).min(height_m.max(0.0));
                horizontal
                    + descent_feed_forward_ne_m_s(
                        aero,
                        wind.altitude_m,
                        lead_m,
                        c.wind_shear_roughness_m,
                        c.autopilot_velocity_tau_s,
                    )
            }
            _ => horizontal,
        };
        // After the commit a gust is answered as the vehicle feels it: its push (the aerodynamic
        // acceleration less what the autopilot's integrator has learned) is asked of the
        // velocity loop the other way, before a drift shows it. Earlier, the tracking itself
        // answers (the answer there made the tail worse: Dryden p95 up to 0.41 m); in the last
        // centimetres it only tips the vehicle, as the corrections do.
        let gust_shift_ne_m_s = match (
            self.aerodynamic_accel_ne_m_s2,
            self.aerodynamic_baseline_ne_m_s2,
        ) {
            (Some(now), Some(baseline))
                if self.mode == LandingMode::FinalLanding
                    && height_m > c.touchdown_correction_height_m =>
            {
                -(now - baseline) * c.gust_feed_forward_s
            }
            _ => Vector2::zeros(),
        };
        // The autopilot's shortfall is made up while the vehicle steers (not while it only
        // holds still in Search, nor on the ground).
        let steering = !matches!(self.mode, LandingMode::Search | LandingMode::Landed);
        let horizontal = if steering && c.wind_compensation_tau_s > 0.0 {
            horizontal + self.velocity_shortfall_ne_m_s
        } else {
            self.velocity_shortfall_ne_m_s = Vector2::zeros();
            self.expected_velocity_ne_m_s = None;
            horizontal
        };
        // After the commit the vehicle moves with the pad (its velocity and turn, the wind's
        // shortfall made up) plus a bounded correction, a small one in the last centimetres:
        // so late a correction cannot centre the vehicle, it only tips it. The gust's answer
        // comes on top, unbounded: it is no correction, it meets a force.
        let horizontal = if self.mode == LandingMode::FinalLanding {
            let with_the_pad =
                self.platform_feed_forward_ne_m_s(input) + self.velocity_shortfall_ne_m_s;
            let limit_m_s = if height_m <= c.touchdown_correction_height_m {
                c.max_touchdown_correction_m_s
            } else {
                c.max_final_correction_m_s
            };
            with_the_pad + clamp_norm(horizontal - with_the_pad, limit_m_s) + gust_shift_ne_m_s
        } else {
            horizontal
        };
        let horizontal = clamp_norm(horizontal, c.max_horizontal_speed_m_s);
        // The gust's answer is spent on the gust: the shortfall estimate expects the rest.
        self.last_command_ne_m_s = steering.then_some(horizontal - gust_shift_ne_m_s);
        Ok(LandingOutput {
            mode: self.mode,
            velocity_setpoint_ned_m_s: Vector3::new(horizontal.x, horizontal.y, vertical_down_m_s),
            land_command,
            horizontal_error_m: error_m,
            centred_radius_m: radius_m,
        })
    }

    fn update_mode(
        &mut self,
        input: &LandingInput,
        lost_for_s: f64,
        error_m: Option<f64>,
        radius_m: f64,
        centred: bool,
    ) {
        let c = self.config;
        let time_s = input.time_s;
        let height_m = input.height_above_pad_m;
        // Committed and in the last centimetres, a descent that has all but stopped has met
        // the pad (the rate settles within a few steps of the commit's faster descent).
        let stalled = self.mode == LandingMode::FinalLanding
            && height_m <= c.touchdown_correction_height_m
            && self.descent_rate_m_s < STALLED_DESCENT_FRACTION * c.final_descent_speed_m_s;
        if self.mode != LandingMode::Landed
            && (input.touchdown_detected
                || stalled
                || (self.mode == LandingMode::FinalLanding && height_m <= c.touchdown_height_m))
        {
            self.mode = LandingMode::Landed;
            return;
        }
        match self.mode {
            // Airborne again (a mission that starts on the ground, or a take-off after a
            // landing): the procedure starts over.
            LandingMode::Landed => {
                if !input.touchdown_detected && height_m > c.final_landing_height_m {
                    self.mode = LandingMode::Search;
                    self.search_displacement_ne_m = Vector2::zeros();
                    self.last_fix_time_s = None;
                    self.centred_since_s = None;
                    self.hold_height_m = c.initial_height_m;
                }
            }
            LandingMode::FinalLanding => {}
            LandingMode::Search | LandingMode::Reacquire => {
                if error_m.is_some() {
                    self.enter_follow(c.initial_height_m);
                } else if self.mode == LandingMode::Reacquire && lost_for_s > c.search_timeout_s {
                    self.mode = LandingMode::Search;
                    self.search_displacement_ne_m = Vector2::zeros();
                }
            }
            LandingMode::Follow => {
                if lost_for_s > c.lost_timeout_s {
                    self.mode = LandingMode::Reacquire;
                    return;
                }
                let at_height = (height_m - self.hold_height_m).abs() <= c.height_tolerance_m;
                if at_height && centred && input.descent_allowed {
                    let since_s = *self.centred_since_s.get_or_insert(time_s);
                    if time_s - since_s >= c.centred_dwell_s {
                        self.mode = LandingMode::Descend;
                        // The commit's dwell is timed afresh, below LH.
                        self.centred_since_s = None;
                    }
                } else if error_m.is_some() {
                    // A missing frame does not reset the dwell; a seen off-centre target does.
                    self.centred_since_s = None;
                }
            }
            LandingMode::Descend => {
                if lost_for_s > c.lost_timeout_s {
                    self.mode = LandingMode::Reacquire;
                } else if error_m.is_some_and(|e| e > c.recentre_factor * radius_m) {
                    // Below LH the camera sees a patch about a metre across, and a gust that
                    // took the vehicle off centre there lost the pad within seconds (Dryden
                    // 12 m/s, 1 m): the vehicle follows again from LH at least.
                    self.enter_follow(height_m.max(c.final_landing_height_m));
                } else if centred && height_m <= c.final_landing_height_m {
                    let since_s = *self.centred_since_s.get_or_insert(time_s);
                    if time_s - since_s >= c.commit_dwell_s {
                        self.mode = LandingMode::FinalLanding;
                    }
                } else if error_m.is_some() {
                    self.centred_since_s = None;
                }
            }
        }
    }

    fn enter_follow(&mut self, hold_height_m: f64) {
        if self.mode != LandingMode::Descend {
            // Coming from no target: the PID's memory is stale.
            self.pid.reset();
            self.last_pid_time_s = None;
        }
        self.mode = LandingMode::Follow;
        self.hold_height_m = hold_height_m;
        self.centred_since_s = None;
    }

    /// The PID or the MPC on a fix, the platform's velocity alone without one; the PID with the
    /// platform's acceleration fed forward over the configured lead, the MPC with it in its
    /// prediction.
    fn horizontal_tracking(
        &mut self,
        input: &LandingInput,
        fix: Option<RelativeFix>,
        setpoint_ne_m: Vector2<f64>,
        mpc: Option<&mut MpcController>,
    ) -> Result<Vector2<f64>, LandingError> {
        let feed_forward_ne_m_s = self.platform_feed_forward_ne_m_s(input);
        let Some(fix) = fix else {
            return Ok(feed_forward_ne_m_s);
        };
        if let Some(mpc) = mpc {
            let result = mpc.step(&MpcInput {
                uav_minus_pad_ne_m: fix.uav_minus_pad_ned_m.xy(),
                setpoint_ne_m,
                uav_velocity_ne_m_s: input.uav_velocity_ne_m_s,
                platform_velocity_ne_m_s: input.platform_velocity_ne_m_s,
                platform_accel_ne_m_s2: self.platform_accel_ne_m_s2,
            });
            return Ok(match result {
                Ok(out) => out.velocity_ne_m_s,
                // A late or failed solve flies the MPC's own safe fallback.
                Err(error) => error.fallback_ne_m_s().unwrap_or(feed_forward_ne_m_s),
            });
        }
        // dt since the PID last ran, so a dropout does not look like a jump in one step.
        let Some(previous_s) = self.last_pid_time_s.replace(input.time_s) else {
            // No interval yet: feed-forward only; the PID starts on the next step.
            return Ok(feed_forward_ne_m_s);
        };
        let out = self.pid.step(&PidInput {
            dt_s: input.time_s - previous_s,
            height_m: input.height_above_pad_m,
            uav_minus_pad_ne_m: fix.uav_minus_pad_ned_m.xy(),
            setpoint_ne_m,
            platform_velocity_ne_m_s: feed_forward_ne_m_s,
        })?;
        Ok(out.velocity_ne_m_s)
    }

    /// The platform's velocity with its acceleration fed forward over the configured lead.
    fn platform_feed_forward_ne_m_s(&self, input: &LandingInput) -> Vector2<f64> {
        input.platform_velocity_ne_m_s
            + self.platform_accel_ne_m_s2 * self.config.platform_accel_lead_s
    }

    /// Vertical speed (down positive) towards a height above the pad.
    fn hold_height(&self, height_m: f64, target_m: f64) -> f64 {
        let limit = self.config.max_height_hold_speed_m_s;
        (self.config.height_gain_per_s * (height_m - target_m)).clamp(-limit, limit)
    }
}

/// [`low_pass`] from the filter's state, or from `raw` itself when it has none yet.
fn low_pass_from<T>(filtered: Option<T>, raw: T, dt_s: f64, tau_s: f64) -> T
where
    T: Copy
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + std::ops::Mul<f64, Output = T>,
{
    filtered.map_or(raw, |filtered| low_pass(filtered, raw, dt_s, tau_s))
}

/// One step of a first-order low-pass (backward Euler): `filtered` moves towards `raw` by
/// dt / (τ + dt).
fn low_pass<T>(filtered: T, raw: T, dt_s: f64, tau_s: f64) -> T
where
    T: Copy
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + std::ops::Mul<f64, Output = T>,
{
    filtered + (raw - filtered) * (dt_s / (tau_s + dt_s))
}

fn clamp_norm(v: Vector2<f64>, max_norm: f64) -> Vector2<f64> {
    let norm = v.norm();
    if norm > max_norm {
        v * (max_norm / norm)
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT_S: f64 = 0.05;

    fn fix_at(north_m: f64, east_m: f64, height_m: f64) -> Option<RelativeFix> {
        Some(RelativeFix::with_std(
            Vector3::new(north_m, east_m, -height_m),
            0.02,
        ))
    }

    fn input(time_s: f64, fix: Option<RelativeFix>, height_m: f64) -> LandingInput {
        LandingInput {
            time_s,
            fix,
            height_above_pad_m: height_m,
            platform_velocity_ne_m_s: Vector2::new(3.0, 0.0),
            touchdown_detected: false,
            uav_velocity_ne_m_s: Vector2::new(3.0, 0.0),
            descent_allowed: true,
            predicted_uav_minus_pad_ne_m: None,
            setpoints_followed: true,
            pad_in_view_offset_per_height: Vector2::zeros(),
            near_ground_wind: None,
        }
    }

    /// Steps at DT_S from `t_s` for `duration_s` with the same fix offset and height; returns
    /// the last output and the time after.
    fn run(
        c: &mut LandingController,
        t_s: &mut f64,
        duration_s: f64,
        offset_m: Option<f64>,
        height_m: f64,
    ) -> LandingOutput {
        let steps = (duration_s / DT_S).round() as usize;
        let mut out = None;
        for _ in 0..steps.max(1) {
            *t_s += DT_S;
            let fix = offset_m.and_then(|o| fix_at(o, 0.0, height_m));
            out = Some(c.step(&input(*t_s, fix, height_m)).unwrap());
        }
        out.unwrap()
    }

    /// The reference mission's close-in PID (8/s and 2.5) and final descent (2 m/s).
    fn close_in_config() -> LandingConfig {
        let mut pid = PidConfig::default();
        pid.gains.low.kp_per_s = 8.0;
        pid.gains.low.kd = 2.5;
        LandingConfig {
            final_descent_speed_m_s: 2.0,
            pid,
            ..LandingConfig::default()
        }
    }

    /// A controller brought to Descend at IH with the target centred.
    fn descending() -> (LandingController, f64) {
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let mut t_s = 0.0;
        let out = run(&mut c, &mut t_s, 1.0, Some(0.0), 7.5);
        assert_eq!(out.mode, LandingMode::Descend);
        (c, t_s)
    }

    /// A vehicle leaning so far that its camera sees the pad only west of it (pad − UAV
    /// = (0, −0.15)·height): it follows east of the pad by that much, descends, and the offset
    /// shrinks with height so that it touches down on the pad. The vehicle flies the commands
    /// with the autopilot's lag; the platform drives north at 1.5 m/s.
    #[test]
    fn a_leaning_vehicle_follows_where_its_camera_sees_the_pad_and_lands_on_it() {
        let per_height = Vector2::new(0.0, -0.15);
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let platform = Vector2::new(1.5, 0.0);
        let (mut uav, mut pad) = (Vector2::new(0.0, 0.0), Vector2::new(0.5, 0.0));
        let (mut velocity, mut height_m) = (platform, 7.5);
        let tau_s = LandingConfig::default().autopilot_velocity_tau_s;
        let mut checked_at_4_m = false;
        for step in 1..=1200 {
            let t_s = step as f64 * DT_S;
            let out = c
                .step(&LandingInput {
                    uav_velocity_ne_m_s: velocity,
                    platform_velocity_ne_m_s: platform,
                    pad_in_view_offset_per_height: per_height,
                    ..input(
                        t_s,
                        fix_at((uav - pad).x, (uav - pad).y, height_m),
                        height_m,
                    )
                })
                .unwrap();
            if out.mode == LandingMode::Landed {
                // The PID trails the setpoint sliding towards the pad with the descent (by
                // ~0.15 m at 4 m, less as the slide slows near the pad). Feeding the slide's
                // rate forward halved this here but flew worse in the realistic world's gusts.
                assert!(
                    (uav - pad).norm() < 0.15,
                    "landed {} m off",
                    (uav - pad).norm()
                );
                assert!(checked_at_4_m);
                return;
            }
            if out.mode == LandingMode::Descend && (height_m - 4.0).abs() < 0.05 {
                let want = -per_height * height_m;
                assert!(
                    ((uav - pad) - want).norm() < 0.2,
                    "at {height_m} m: {} vs {want}",
                    uav - pad
                );
                checked_at_4_m = true;
            }
            let command = out.velocity_setpoint_ned_m_s;
            velocity += (command.xy() - velocity) * (DT_S / (tau_s + DT_S));
            uav += velocity * DT_S;
            pad += platform * DT_S;
            height_m = (height_m - command.z * DT_S).max(0.0);
        }
        panic!("never landed");
    }

    /// Knocked off centre below LH before the commit: the vehicle follows again from LH,
    /// climbing, not from where the gust caught it; centred there, it descends and commits.
    #[test]
    fn a_recentre_below_the_commit_height_climbs_back_to_it() {
        let (mut c, mut t_s) = descending();
        let lh_m = LandingConfig::default().final_landing_height_m;
        let low_m = 0.8 * lh_m;
        let out = run(&mut c, &mut t_s, DT_S, Some(0.6), low_m);
        assert_eq!(out.mode, LandingMode::Follow);
        assert!(
            out.velocity_setpoint_ned_m_s.z < -0.1,
            "climbs: {}",
            out.velocity_setpoint_ned_m_s.z
        );
        // A recentre above LH holds the height it was caught at, as before.
        let (mut above, mut t_above_s) = descending();
        let out = run(&mut above, &mut t_above_s, DT_S, Some(2.5), 4.0);
        assert_eq!(out.mode, LandingMode::Follow);
        assert!(out.velocity_setpoint_ned_m_s.z.abs() < 1e-9);
        // Back at LH and centred: down again, and committed after its dwell.
        let out = run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m);
        assert_eq!(out.mode, LandingMode::FinalLanding);
    }

    /// Committed, 0.8 m north of the pad: the command strays from the platform's velocity
    /// towards the pad by at most the final correction, and by at most the touchdown one in the
    /// last centimetres.
    #[test]
    fn in_the_last_centimetres_the_correction_is_bounded() {
        let config = LandingConfig::default();
        let committed_then_off_centre = |height_m: f64| {
            let (mut c, mut t_s) = descending();
            let lh_m = c.config().final_landing_height_m;
            assert_eq!(
                run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m).mode,
                LandingMode::FinalLanding
            );
            let out = run(&mut c, &mut t_s, DT_S, Some(0.8), height_m);
            assert_eq!(out.mode, LandingMode::FinalLanding);
            let platform = input(0.0, None, 0.0).platform_velocity_ne_m_s;
            out.velocity_setpoint_ned_m_s.xy() - platform
        };
        // The PID asks for more than either limit (1.5/s × 0.8 m alone).
        let above = committed_then_off_centre(config.touchdown_correction_height_m + 0.2);
        assert!(
            (above.norm() - config.max_final_correction_m_s).abs() < 1e-12,
            "{above:?}"
        );
        assert!(above.x < 0.0 && above.y.abs() < 1e-12, "{above:?}");
        let within = committed_then_off_centre(0.5 * config.touchdown_correction_height_m);
        assert!(
            (within.norm() - config.max_touchdown_correction_m_s).abs() < 1e-12,
            "{within:?}"
        );
        assert!(within.x < 0.0 && within.y.abs() < 1e-12, "{within:?}");
    }

    /// Searching with no fix, the same lean: the vehicle moves upwind until its camera sees
    /// the spot it began over, and holds there.
    #[test]
    fn a_leaning_vehicle_searches_where_it_began() {
        let per_height = Vector2::new(0.0, -0.2);
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let (mut moved, mut velocity) = (Vector2::zeros(), Vector2::zeros());
        for step in 1..=400 {
            let out = c
                .step(&LandingInput {
                    uav_velocity_ne_m_s: velocity,
                    platform_velocity_ne_m_s: Vector2::zeros(),
                    pad_in_view_offset_per_height: per_height,
                    ..input(step as f64 * DT_S, None, 7.5)
                })
                .unwrap();
            assert_eq!(out.mode, LandingMode::Search);
            velocity = out.velocity_setpoint_ned_m_s.xy();
            moved += velocity * DT_S;
        }
        let want = -per_height * 7.5;
        assert!((moved - want).norm() < 0.05, "moved {moved}, want {want}");
    }

    /// An autopilot that falls 0.8 m/s short of every command (a wind its integrator does not
    /// hold): with the feed-forward, the vehicle's true velocity comes to what the guidance
    /// wants; without it, it stays 0.8 m/s short. The vehicle is simulated here as exactly
    /// that: the command, lagged by the configured response, minus the shortfall.
    #[test]
    fn wind_feed_forward_makes_up_the_autopilots_shortfall() {
        let shortfall = Vector2::new(0.8, -0.3);
        let fly = |tau_s: f64| {
            let config = LandingConfig {
                wind_compensation_tau_s: tau_s,
                ..LandingConfig::default()
            };
            let mut c = LandingController::new(config).unwrap();
            let platform = Vector2::new(2.0, 0.0);
            let mut velocity = Vector2::zeros();
            let mut desired = Vector2::zeros();
            for step in 1..=400 {
                let t_s = step as f64 * DT_S;
                let out = c
                    .step(&LandingInput {
                        uav_velocity_ne_m_s: velocity,
                        platform_velocity_ne_m_s: platform,
                        ..input(t_s, fix_at(0.0, 0.0, 7.5), 7.5)
                    })
                    .unwrap();
                let command = out.velocity_setpoint_ned_m_s.xy();
                // Centred on the pad: the guidance wants the platform's velocity.
                desired = platform;
                let lag = DT_S / (config.autopilot_velocity_tau_s + DT_S);
                velocity += lag * (command - shortfall - velocity);
            }
            (velocity - desired).norm()
        };
        let without = fly(0.0);
        let with = fly(1.0);
        assert!(
            (without - shortfall.norm()).abs() < 0.05,
            "without: {without}"
        );
        assert!(with < 0.05, "with the feed-forward still {with} m/s off");
    }

    /// Descending at 0.7 m/s from 3 m above the ground with the wind pushing west at 4 m/s²:
    /// the command moves west by what the log profile takes off the force 0.3 s lower, over
    /// the velocity loop's gain (worked out here by hand); not while the vehicle only follows.
    #[test]
    fn the_wind_shear_feed_forward_leans_less_only_while_descending() {
        let config = LandingConfig {
            wind_shear_roughness_m: 0.05,
            ..LandingConfig::default()
        };
        let wind = NearGroundWind {
            altitude_m: 3.0,
            aerodynamic_accel_ne_m_s2: Vector2::new(0.0, -4.0),
        };
        let command = |descent_allowed: bool, wind: Option<NearGroundWind>| {
            let mut c = LandingController::new(config).unwrap();
            let mut t_s = 0.0;
            let mut out = None;
            for _ in 0..40 {
                t_s += DT_S;
                out = Some(
                    c.step(&LandingInput {
                        descent_allowed,
                        near_ground_wind: wind,
                        ..input(t_s, fix_at(0.0, 0.0, 7.5), 7.5)
                    })
                    .unwrap(),
                );
            }
            out.unwrap()
        };
        let descending = command(true, Some(wind));
        assert_eq!(descending.mode, LandingMode::Descend);
        let plain = command(true, None);
        let ratio = ((2.79f64 / 0.05).ln() / (3.0f64 / 0.05).ln()).powi(2);
        let expected_east_m_s = -4.0 * (1.0 - ratio) * config.autopilot_velocity_tau_s;
        let shift = descending.velocity_setpoint_ned_m_s - plain.velocity_setpoint_ned_m_s;
        assert!(shift.x.abs() < 1e-12 && shift.z == 0.0, "{shift:?}");
        assert!((shift.y - expected_east_m_s).abs() < 1e-9, "{shift:?}");
        // Telemetry that gives no finite wind counts as none: no shift, no error.
        let garbled = NearGroundWind {
            altitude_m: f64::NAN,
            ..wind
        };
        assert_eq!(command(true, Some(garbled)), plain);
        let following = command(false, Some(wind));
        assert_eq!(following.mode, LandingMode::Follow);
        assert_eq!(following, command(false, None));
    }

    /// Committed 0.4 m over a pad 1 m above the ground at 2 m/s, the feed-forward's 0.6 m lead
    /// would reach below the pad: the wind is predicted at the pad's surface, where the descent
    /// ends (worked out by hand).
    #[test]
    fn the_wind_shear_is_never_predicted_below_the_pad() {
        let config = LandingConfig {
            wind_shear_roughness_m: 0.05,
            final_descent_speed_m_s: 2.0,
            ..LandingConfig::default()
        };
        let height_m = 0.4;
        let command = |wind: Option<NearGroundWind>| {
            let mut c = LandingController::new(config).unwrap();
            let mut t_s = 0.0;
            run(&mut c, &mut t_s, 1.0, Some(0.0), 7.5);
            assert_eq!(
                run(&mut c, &mut t_s, 1.0, Some(0.0), 1.5).mode,
                LandingMode::FinalLanding
            );
            t_s += DT_S;
            c.step(&LandingInput {
                near_ground_wind: wind,
                ..input(t_s, fix_at(0.0, 0.0, height_m), height_m)
            })
            .unwrap()
        };
        let wind = NearGroundWind {
            altitude_m: 1.0 + height_m,
            aerodynamic_accel_ne_m_s2: Vector2::new(0.0, -4.0),
        };
        let shift =
            command(Some(wind)).velocity_setpoint_ned_m_s - command(None).velocity_setpoint_ned_m_s;
        let ratio = ((1.0f64 / 0.05).ln() / (1.4f64 / 0.05).ln()).powi(2);
        let expected_east_m_s = -4.0 * (1.0 - ratio) * config.autopilot_velocity_tau_s;
        assert!(
            (shift.y - expected_east_m_s).abs() < 1e-9,
            "{shift:?} vs {expected_east_m_s}"
        );
    }

    /// Closed loop, east only: a velocity loop (proportional 1/τ, a slow integrator) holds the
    /// vehicle over the pad against a west wind that weakens by the log profile as it comes
    /// down onto a pad 1 m above the ground, with the reference mission's close-in gains. Its
    /// integrator holds the lean of the wind aloft, so the vehicle drifts upwind on the way
    /// down (7 cm); the feed-forward takes a third of that off.
    #[test]
    fn the_wind_shear_feed_forward_keeps_the_descent_over_the_pad() {
        let roughness_m = 0.05;
        let pad_altitude_m = 1.0;
        let wind_at = |altitude_m: f64| {
            -4.0 * ((altitude_m / roughness_m).ln() / (8.5f64 / roughness_m).ln()).powi(2)
        };
        let land = |wind_shear_roughness_m: f64| {
            let config = LandingConfig {
                wind_shear_roughness_m,
                ..close_in_config()
            };
            let gain_per_s = 1.0 / config.autopilot_velocity_tau_s;
            let mut c = LandingController::new(config).unwrap();
            let (mut east_m, mut velocity_m_s, mut height_m) = (0.0, 0.0, 7.5);
            // Settled at IH: the integrator holds the wind there.
            let mut integral_m_s2 = -wind_at(pad_altitude_m + height_m);
            let mut worst_m: f64 = 0.0;
            for step in 1..4000 {
                let t_s = step as f64 * 0.02;
                let aero = wind_at(pad_altitude_m + height_m);
                let out = c
                    .step(&LandingInput {
                        platform_velocity_ne_m_s: Vector2::zeros(),
                        uav_velocity_ne_m_s: Vector2::new(0.0, velocity_m_s),
                        near_ground_wind: Some(NearGroundWind {
                            altitude_m: pad_altitude_m + height_m,
                            aerodynamic_accel_ne_m_s2: Vector2::new(0.0, aero),
                        }),
                        ..input(t_s, fix_at(0.0, east_m, height_m), height_m)
                    })
                    .unwrap();
                if out.mode == LandingMode::Landed {
                    return (east_m.abs(), worst_m);
                }
                let error_m_s = out.velocity_setpoint_ned_m_s.y - velocity_m_s;
                integral_m_s2 += 0.4 * error_m_s * 0.02;
                velocity_m_s += (gain_per_s * error_m_s + integral_m_s2 + aero) * 0.02;
                east_m += velocity_m_s * 0.02;
                height_m = (height_m - out.velocity_setpoint_ned_m_s.z * 0.02).max(0.0);
                if height_m < 2.0 {
                    worst_m = worst_m.max(east_m.abs());
                }
            }
            panic!("never landed");
        };
        let (without_m, worst_without_m) = land(0.0);
        let (with_m, worst_with_m) = land(roughness_m);
        assert!(
            without_m > 0.04,
            "the shear should push it off: {without_m} m"
        );
        assert!(
            with_m < 0.75 * without_m && worst_with_m < 0.75 * worst_without_m,
            "touchdown {with_m} m against {without_m} m, worst below 2 m {worst_with_m} against {worst_without_m} m"
        );
    }

    /// A gust that strikes after the commit, against a P+I velocity loop with a lagging
    /// attitude: answered as it is felt, it pushes the vehicle off the pad by much less, and
    /// before the commit (the same gust while following) the answer is not given.
    #[test]
    fn a_gust_after_the_commit_is_answered_as_it_is_felt() {
        let steady_m_s2 = -3.0;
        let gust_m_s2 = 2.5;
        let land = |gust_feed_forward_s: f64, gust_below_m: f64| {
            let config = LandingConfig {
                gust_feed_forward_s,
                ..close_in_config()
            };
            let mut c = LandingController::new(config).unwrap();
            let (mut east_m, mut velocity_m_s, mut height_m) = (0.0, 0.0, 7.5);
            // PX4's MPC_XY_VEL_P_ACC and _I_ACC, the attitude's 0.1 s lag; settled at IH.
            let (p_per_s, i_per_s2, attitude_tau_s) = (1.8, 0.4, 0.1);
            let mut integral_m_s2 = -steady_m_s2;
            let mut thrust_m_s2 = integral_m_s2;
            let mut shifts_before_commit_m_s: f64 = 0.0;
            for step in 1..4000 {
                let t_s = step as f64 * 0.02;
                let aero = if height_m < gust_below_m {
                    steady_m_s2 + gust_m_s2
                } else {
                    steady_m_s2
                };
                let out = c
                    .step(&LandingInput {
                        platform_velocity_ne_m_s: Vector2::zeros(),
                        uav_velocity_ne_m_s: Vector2::new(0.0, velocity_m_s),
                        near_ground_wind: Some(NearGroundWind {
                            altitude_m: height_m,
                            aerodynamic_accel_ne_m_s2: Vector2::new(0.0, aero),
                        }),
                        ..input(t_s, fix_at(0.0, east_m, height_m), height_m)
                    })
                    .unwrap();
                if out.mode == LandingMode::Landed {
                    return (east_m.abs(), shifts_before_commit_m_s);
                }
                if out.mode != LandingMode::FinalLanding {
                    // With the vehicle over the pad and still, anything asked is an answer.
                    shifts_before_commit_m_s = shifts_before_commit_m_s
                        .max((out.velocity_setpoint_ned_m_s.y - velocity_m_s).abs());
                }
                let error_m_s = out.velocity_setpoint_ned_m_s.y - velocity_m_s;
                integral_m_s2 += i_per_s2 * error_m_s * 0.02;
                let wanted_m_s2 = p_per_s * error_m_s + integral_m_s2;
                thrust_m_s2 += (wanted_m_s2 - thrust_m_s2) * 0.02 / attitude_tau_s;
                velocity_m_s += (thrust_m_s2 + aero) * 0.02;
                east_m += velocity_m_s * 0.02;
                height_m = (height_m - out.velocity_setpoint_ned_m_s.z * 0.02).max(0.0);
            }
            panic!("never landed");
        };
        // The gust strikes just below the commit height (1.5 m).
        let (without_m, _) = land(0.0, 1.2);
        let (with_m, _) = land(0.75, 1.2);
        assert!(
            without_m > 0.03,
            "the gust should push it off: {without_m} m"
        );
        assert!(
            with_m < 0.6 * without_m,
            "touchdown {with_m} m with the answer against {without_m} m without"
        );
        // Struck while following high above the pad, the vehicle is steered by the tracking
        // alone: the feed-forward asks for nothing beyond what the same flight without it asks.
        let (_, asked_with_m_s) = land(0.75, 5.0);
        let (_, asked_without_m_s) = land(0.0, 5.0);
        assert!(
            (asked_with_m_s - asked_without_m_s).abs() < 1e-12,
            "before the commit: {asked_with_m_s} against {asked_without_m_s} m/s"
        );
    }

    /// The same flight, with and without the gust's answer: after the commit a gust of
    /// 2 m/s² east is answered by about its push × `gust_feed_forward_s` west (less what the
    /// baseline has learned meanwhile); in the last centimetres not at all, so the commands
    /// there are the same to the bit.
    #[test]
    fn the_gust_is_answered_after_the_commit_and_not_in_the_last_centimetres() {
        let controller = |gust_feed_forward_s: f64| {
            LandingController::new(LandingConfig {
                gust_feed_forward_s,
                ..LandingConfig::default()
            })
            .unwrap()
        };
        let (mut plain, mut answering) = (controller(0.0), controller(0.75));
        let mut t_s = 0.0;
        let mut both = |duration_s: f64, height_m: f64, aero_east_m_s2: f64| {
            let mut outputs = (None, None);
            for _ in 0..(duration_s / DT_S).round() as usize {
                t_s += DT_S;
                let step = LandingInput {
                    near_ground_wind: Some(NearGroundWind {
                        altitude_m: height_m + 1.0,
                        aerodynamic_accel_ne_m_s2: Vector2::new(0.0, aero_east_m_s2),
                    }),
                    ..input(t_s, fix_at(0.0, 0.0, height_m), height_m)
                };
                outputs = (
                    Some(plain.step(&step).unwrap()),
                    Some(answering.step(&step).unwrap()),
                );
            }
            let (plain, answering) = (outputs.0.unwrap(), outputs.1.unwrap());
            assert_eq!(plain.mode, answering.mode);
            (plain, answering)
        };
        // Following and descending in a steady wind: no gust, nothing to answer.
        let (plain_out, answering_out) = both(1.0, 7.5, -3.0);
        assert_eq!(plain_out.mode, LandingMode::Descend);
        assert_eq!(plain_out, answering_out);
        let (plain_out, answering_out) = both(1.0, 1.4, -3.0);
        assert_eq!(plain_out.mode, LandingMode::FinalLanding);
        assert!(
            (plain_out.velocity_setpoint_ned_m_s - answering_out.velocity_setpoint_ned_m_s).norm()
                < 1e-9
        );
        // The gust, 0.3 s long: felt through the 0.2 s filter, less the 1 s baseline's share.
        let (plain_out, answering_out) = both(0.3, 0.8, -1.0);
        let answer_east_m_s =
            answering_out.velocity_setpoint_ned_m_s.y - plain_out.velocity_setpoint_ned_m_s.y;
        let felt = 1.0 - (0.2f64 / (0.2 + DT_S)).powi(6);
        let learned = 1.0 - (1.0f64 / (1.0 + DT_S)).powi(6);
        let expected_m_s = -2.0 * (felt - learned) * 0.75;
        assert!(
            (answer_east_m_s - expected_m_s).abs() < 1e-9 && expected_m_s < -0.5,
            "answered {answer_east_m_s} m/s, expected {expected_m_s}"
        );
        // In the last centimetres the gust goes unanswered.
        let (plain_out, answering_out) = both(DT_S, 0.2, -1.0);
        assert_eq!(plain_out.mode, LandingMode::FinalLanding);
        assert_eq!(plain_out, answering_out);
    }

    /// A vehicle held still by its autopilot (a failsafe, a pilot) while the guidance asks for
    /// 2 m/s: told its setpoints are not flown, the controller learns no wind, and once they
    /// are flown again it asks for what it would ask of a vehicle that had never been held.
    #[test]
    fn no_wind_is_learned_while_the_setpoints_are_not_flown() {
        let config = LandingConfig {
            wind_compensation_tau_s: 1.0,
            ..LandingConfig::default()
        };
        let platform = Vector2::new(2.0, 0.0);
        let step = |c: &mut LandingController, t_s: f64, followed: bool| {
            c.step(&LandingInput {
                uav_velocity_ne_m_s: Vector2::zeros(),
                platform_velocity_ne_m_s: platform,
                setpoints_followed: followed,
                pad_in_view_offset_per_height: Vector2::zeros(),
                ..input(t_s, fix_at(0.0, 0.0, 7.5), 7.5)
            })
            .unwrap()
            .velocity_setpoint_ned_m_s
            .xy()
        };
        let mut held = LandingController::new(config).unwrap();
        for k in 1..=200 {
            step(&mut held, k as f64 * DT_S, false);
        }
        let after_hold = step(&mut held, 201.0 * DT_S, true);
        let mut fresh = LandingController::new(config).unwrap();
        let first = step(&mut fresh, 201.0 * DT_S, true);
        // (One step of learning apart: the first step flown after the hold.)
        assert!(
            (after_hold - first).norm() < 0.05,
            "{after_hold} after the hold, {first} fresh"
        );
        // Whereas a vehicle that does not move although it flies the setpoints is short of
        // them: that is learned as wind.
        let mut short = LandingController::new(config).unwrap();
        for k in 1..=200 {
            step(&mut short, k as f64 * DT_S, true);
        }
        let compensated = step(&mut short, 201.0 * DT_S, true);
        assert!(
            (compensated - first).norm() > 1.0,
            "{compensated} vs {first}"
        );
    }

    #[test]
    fn defaults_are_the_seed_altitudes() {
        let config = LandingConfig::default();
        assert_eq!(config.initial_height_m, 7.5);
        assert_eq!(config.final_landing_height_m, 1.5);
        assert!(config.validate().is_ok());
    }

    #[test]
    fn search_holds_at_ih_until_a_fix() {
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let mut t_s = 0.0;
        let out = run(&mut c, &mut t_s, 2.0, None, 5.0);
        assert_eq!(out.mode, LandingMode::Search);
        assert_eq!(out.velocity_setpoint_ned_m_s.xy(), Vector2::zeros());
        // 2.5 m below IH: climb (NED down negative) at the hold limit.
        assert_eq!(out.velocity_setpoint_ned_m_s.z, -1.0);
        assert!(!out.land_command);
        let out = run(&mut c, &mut t_s, DT_S, Some(2.0), 5.0);
        assert_eq!(out.mode, LandingMode::Follow);
    }

    #[test]
    fn follow_descends_only_at_ih_and_centred_for_the_dwell() {
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let mut t_s = 0.0;
        // Centred but still climbing to IH: stays in Follow and climbs.
        let out = run(&mut c, &mut t_s, 2.0, Some(0.0), 5.0);
        assert_eq!(out.mode, LandingMode::Follow);
        assert!(out.velocity_setpoint_ned_m_s.z < 0.0);
        // At IH but 1.5 m off centre (radius at IH is 1.0 m): stays.
        let out = run(&mut c, &mut t_s, 2.0, Some(1.5), 7.5);
        assert_eq!(out.mode, LandingMode::Follow);
        // The PID pulls towards the pad on top of the platform's 3 m/s: uav is north of the
        // pad, so the north velocity is below 3 m/s.
        assert!(out.velocity_setpoint_ned_m_s.x < 3.0);
        // Centred: not before the 0.5 s dwell …
        let out = run(&mut c, &mut t_s, 0.4, Some(0.5), 7.5);
        assert_eq!(out.mode, LandingMode::Follow);
        // … then Descend, going down at the descent speed.
        let out = run(&mut c, &mut t_s, 0.2, Some(0.5), 7.5);
        assert_eq!(out.mode, LandingMode::Descend);
        assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.7);
    }

    #[test]
    fn centred_threshold_tightens_with_altitude() {
        let config = LandingConfig::default();
        assert_eq!(config.centred_radius_m(7.5), 1.0);
        assert_eq!(config.centred_radius_m(20.0), 1.0);
        assert_eq!(config.centred_radius_m(1.5), 0.15);
        assert_eq!(config.centred_radius_m(0.2), 0.15);
        assert!((config.centred_radius_m(4.5) - 0.575).abs() < 1e-12);

        // 0.5 m off is centred at 7.5 m but not at 3 m (radius 0.3625 m): the descent stops,
        // and at 2 × the radius it goes back to Follow holding its height.
        let (mut c, mut t_s) = descending();
        let out = run(&mut c, &mut t_s, DT_S, Some(0.5), 3.0);
        assert_eq!(out.mode, LandingMode::Descend);
        assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.0);
        let out = run(&mut c, &mut t_s, DT_S, Some(0.8), 3.0);
        assert_eq!(out.mode, LandingMode::Follow);
        assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.0);
    }

    #[test]
    fn commit_below_lh_then_landed() {
        let (mut c, mut t_s) = descending();
        // Above LH: no commit however centred.
        let out = run(&mut c, &mut t_s, 1.0, Some(0.0), 1.6);
        assert_eq!(out.mode, LandingMode::Descend);
        // Below LH but 0.2 m off (radius 0.15 m): no commit.
        let out = run(&mut c, &mut t_s, 1.0, Some(0.2), 1.4);
        assert_eq!(out.mode, LandingMode::Descend);
        // Centred below LH: commit after the 0.3 s dwell.
        let out = run(&mut c, &mut t_s, 0.2, Some(0.05), 1.4);
        assert_eq!(out.mode, LandingMode::Descend);
        let out = run(&mut c, &mut t_s, 0.2, Some(0.05), 1.4);
        assert_eq!(out.mode, LandingMode::FinalLanding);
        assert!(out.land_command);
        assert_eq!(out.velocity_setpoint_ned_m_s.z, 1.0);
        // Still steering horizontally: about the platform's velocity.
        assert!((out.velocity_setpoint_ned_m_s.x - 3.0).abs() < 0.2);
        let out = run(&mut c, &mut t_s, DT_S, Some(0.0), 0.04);
        assert_eq!(out.mode, LandingMode::Landed);
        assert!(out.land_command);
        assert_eq!(out.velocity_setpoint_ned_m_s, Vector3::zeros());
    }

    /// Committed and descending at the final speed, the vehicle meets the pad 0.1 m above
    /// where it thought the pad was (the estimate's bias): the height stops falling, and within
    /// a few steps the landing counts as done, before the autopilot's land detector says so.
    /// A descent still under way that low is not a touchdown.
    #[test]
    fn a_descent_stopped_by_the_pad_is_the_touchdown() {
        let (mut c, mut t_s) = descending();
        let lh_m = c.config().final_landing_height_m;
        assert_eq!(
            run(&mut c, &mut t_s, 1.0, Some(0.0), lh_m).mode,
            LandingMode::FinalLanding
        );
        let speed_m_s = c.config().final_descent_speed_m_s;
        let mut height_m = lh_m;
        while height_m > 0.12 {
            height_m -= speed_m_s * DT_S;
            let out = run(&mut c, &mut t_s, DT_S, Some(0.0), height_m);
            assert_eq!(out.mode, LandingMode::FinalLanding, "at {height_m} m");
        }
        let mut steps = 0;
        while run(&mut c, &mut t_s, DT_S, Some(0.0), 0.1).mode != LandingMode::Landed {
            steps += 1;
            assert!(steps < 4, "still not landed after {steps} steps on the pad");
        }
    }

    #[test]
    fn autopilot_touchdown_means_landed() {
        let (mut c, mut t_s) = descending();
        t_s += DT_S;
        let mut i = input(t_s, fix_at(0.0, 0.0, 3.0), 3.0);
        i.touchdown_detected = true;
        assert_eq!(c.step(&i).unwrap().mode, LandingMode::Landed);
    }

    #[test]
    fn lost_target_aborts_and_climbs_back_to_ih() {
        let (mut c, mut t_s) = descending();
        run(&mut c, &mut t_s, 2.0, Some(0.0), 4.0);
        // A dropout shorter than the 1 s timeout: keep descending mode, hold height, feed the
        // platform's velocity forward.
        let out = run(&mut c, &mut t_s, 0.9, None, 4.0);
        assert_eq!(out.mode, LandingMode::Descend);
        assert_eq!(out.velocity_setpoint_ned_m_s.z, 0.0);
        assert!((out.velocity_setpoint_ned_m_s.x - 3.0).abs() < 1e-9);
        // Past the timeout: Reacquire, climbing towards IH.
        let out = run(&mut c, &mut t_s, 0.2, None, 4.0);
        assert_eq!(out.mode, LandingMode::Reacquire);
        assert_eq!(out.velocity_setpoint_ned_m_s.z, -1.0);
        assert!(!out.land_command);
        // With the tracker's prediction of where the pad went, Reacquire flies towards it:
        // 0.5 /s of the offset on top of the platform's 3 m/s, at most 3 m/s more.
        for (behind_m, expected_m_s) in [(2.0, 4.0), (10.0, 6.0)] {
            t_s += DT_S;
            let mut i = input(t_s, None, 4.0);
            i.predicted_uav_minus_pad_ne_m = Some(Vector2::new(-behind_m, 0.0));
            let out = c.step(&i).unwrap();
            assert_eq!(out.mode, LandingMode::Reacquire);
            assert!(
                (out.velocity_setpoint_ned_m_s.x - expected_m_s).abs() < 1e-9,
                "{out:?}"
            );
        }
        // Seen again: Follow, holding IH.
        let out = run(&mut c, &mut t_s, DT_S, Some(0.0), 5.0);
        assert_eq!(out.mode, LandingMode::Follow);
        assert!(out.velocity_setpoint_ned_m_s.z < 0.0);
        // Lost for longer than the search timeout: Search.
        let out = run(&mut c, &mut t_s, 1.5, None, 7.5);
        assert_eq!(out.mode, LandingMode::Reacquire);
        let out = run(&mut c, &mut t_s, 9.0, None, 7.5);
        assert_eq!(out.mode, LandingMode::Search);
        assert_eq!(out.velocity_setpoint_ned_m_s.xy(), Vector2::zeros());
    }

    #[test]
    fn an_uncertain_or_nan_fix_counts_as_lost() {
        let (mut c, mut t_s) = descending();
        for k in 0..30 {
            t_s += DT_S;
            let fix = if k % 2 == 0 {
                Some(RelativeFix::with_std(Vector3::new(0.0, 0.0, -7.0), 1.0))
            } else {
                Some(RelativeFix::with_std(
                    Vector3::new(f64::NAN, 0.0, -7.0),
                    0.02,
                ))
            };
            let out = c.step(&input(t_s, fix, 7.0)).unwrap();
            assert_eq!(out.horizontal_error_m, None);
        }
        assert_eq!(c.mode(), LandingMode::Reacquire);
    }

    #[test]
    fn no_abort_after_commit() {
        let (mut c, mut t_s) = descending();
        run(&mut c, &mut t_s, 0.5, Some(0.0), 1.4);
        assert_eq!(c.mode(), LandingMode::FinalLanding);
        // The pad fills the view and the target is lost for 10 s: still landing.
        let out = run(&mut c, &mut t_s, 10.0, None, 0.5);
        assert_eq!(out.mode, LandingMode::FinalLanding);
        assert!(out.land_command);
        assert_eq!(out.velocity_setpoint_ned_m_s.z, 1.0);
        assert!((out.velocity_setpoint_ned_m_s.x - 3.0).abs() < 1e-9);
        // Nor does an off-centre fix undo it.
        let out = run(&mut c, &mut t_s, 1.0, Some(2.0), 0.5);
        assert_eq!(out.mode, LandingMode::FinalLanding);
    }

    #[test]
    fn platform_acceleration_is_fed_forward() {
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let mut t_s = 0.0;
        run(&mut c, &mut t_s, 1.0, Some(0.0), 7.5);
        // The platform speeds up east at 1 m/s²; with no fix the setpoint is the platform's
        // velocity plus (filtered) acceleration × 0.2 s lead.
        let mut out = None;
        for k in 1..=60 {
            t_s += DT_S;
            let mut i = input(t_s, fix_at(0.0, 0.0, 7.5), 7.5);
            i.platform_velocity_ne_m_s = Vector2::new(3.0, k as f64 * DT_S);
            out = Some(c.step(&i).unwrap());
        }
        let out = out.unwrap();
        let east_platform_m_s = 60.0 * DT_S;
        let lead_m_s = out.velocity_setpoint_ned_m_s.y - east_platform_m_s;
        assert!((lead_m_s - 0.2).abs() < 0.01, "lead {lead_m_s}");
    }

    #[test]
    fn bad_input_is_an_error_and_changes_nothing() {
        let (mut c, t_s) = descending();
        let before = c.machine.clone();
        let mut i = input(t_s + DT_S, fix_at(0.0, 0.0, 5.0), 5.0);
        i.uav_velocity_ne_m_s.y = f64::NAN;
        assert!(matches!(c.step(&i), Err(LandingError::NonFinite { .. })));
        i.uav_velocity_ne_m_s.y = 0.0;
        i.time_s = f64::NAN;
        assert_eq!(c.step(&i), Err(LandingError::NonFinite { name: "time_s" }));
        let mut i = input(t_s + DT_S, None, f64::NAN);
        assert!(matches!(c.step(&i), Err(LandingError::NonFinite { .. })));
        i.height_above_pad_m = 5.0;
        i.platform_velocity_ne_m_s.x = f64::INFINITY;
        assert!(matches!(c.step(&i), Err(LandingError::NonFinite { .. })));
        assert!(matches!(
            c.step(&input(t_s, None, 5.0)),
            Err(LandingError::TimeNotIncreasing { .. })
        ));
        assert_eq!(c.machine, before);
        let hover = LandingOutput::hover(c.mode());
        assert_eq!(hover.velocity_setpoint_ned_m_s, Vector3::zeros());
        assert!(!hover.land_command);
        assert!(LandingOutput::hover(LandingMode::FinalLanding).land_command);
    }

    /// A vehicle that starts on the ground reports touchdown; once it is airborne above LH
    /// the procedure starts over from Search, and finds the target again.
    #[test]
    fn a_take_off_after_landed_starts_over() {
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let mut on_ground = input(0.0, None, 0.0);
        on_ground.touchdown_detected = true;
        assert_eq!(c.step(&on_ground).unwrap().mode, LandingMode::Landed);
        // Climbing through 1 m (below LH): still Landed, nothing commanded.
        let climbing = input(1.0, None, 1.0);
        assert_eq!(c.step(&climbing).unwrap().mode, LandingMode::Landed);
        let airborne = input(2.0, None, 5.0);
        assert_eq!(c.step(&airborne).unwrap().mode, LandingMode::Search);
        let seen = input(2.1, fix_at(0.5, 0.0, 7.5), 7.5);
        assert_eq!(c.step(&seen).unwrap().mode, LandingMode::Follow);
    }

    #[test]
    fn bad_config_is_named() {
        let config = LandingConfig {
            final_landing_height_m: 8.0,
            ..LandingConfig::default()
        };
        assert!(matches!(
            LandingController::new(config),
            Err(LandingError::Config {
                name: "final_landing_height_m",
                ..
            })
        ));
        let config = LandingConfig {
            lost_timeout_s: f64::NAN,
            ..LandingConfig::default()
        };
        assert!(matches!(
            LandingController::new(config),
            Err(LandingError::Config {
                name: "lost_timeout_s",
                ..
            })
        ));
        let config = LandingConfig {
            keep_in_view_tau_s: -1.0,
            ..LandingConfig::default()
        };
        assert!(matches!(
            LandingController::new(config),
            Err(LandingError::Config {
                name: "keep_in_view_tau_s",
                ..
            })
        ));
        // A non-finite keep-in-view offset is refused and leaves the machine as it was.
        let mut c = LandingController::new(LandingConfig::default()).unwrap();
        let bad = LandingInput {
            pad_in_view_offset_per_height: Vector2::new(f64::NAN, 0.0),
            ..input(0.1, None, 7.5)
        };
        assert_eq!(
            c.step(&bad),
            Err(LandingError::NonFinite {
                name: "pad_in_view_offset_per_height"
            })
        );
        assert!(c.step(&input(0.1, None, 7.5)).is_ok());
        let mut config = LandingConfig::default();
        config.pid.max_ctrl_speed_m_s = -1.0;
        assert!(matches!(
            LandingController::new(config),
            Err(LandingError::Pid(_))
        ));
    }
}
