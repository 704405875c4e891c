//! The landing state machine proper: the mode transitions and the setpoints of each mode.

use nalgebra::{Vector2, Vector3};

use super::{
    LandingConfig, LandingError, LandingInput, LandingMode, LandingOutput, NearGroundWind,
    RelativeFix,
};
use crate::control::mpc::{MpcController, MpcInput};
use crate::control::pid::{HorizontalPid, PidInput};
use crate::control::wind_shear::descent_feed_forward_ne_m_s;

/// Low-pass time constant on the aerodynamic acceleration (the link differentiates velocities).
const AERODYNAMIC_ACCEL_TAU_S: f64 = 0.2;
/// Low-pass time constant on the descent rate, and the fraction of the commanded descent rate
/// below which a committed descent near the pad counts as stopped by it.
const DESCENT_RATE_TAU_S: f64 = 0.05;
const STALLED_DESCENT_FRACTION: f64 = 0.3;

/// Reacquire's pull towards the predicted pad position, per second of offset…
const REACQUIRE_GAIN_PER_S: f64 = 0.5;
/// …and its limit on top of the platform's velocity.
const REACQUIRE_MAX_CATCH_UP_M_S: f64 = 3.0;
/// Landed, the vehicle keeps asking to descend this fast: on the pad the autopilot's thrust
/// drops at once (its land detector wants low thrust: at 0.3 m/s the built-in one took 5 s to
/// agree), a few centimetres above it, it settles at no more than this.
const LANDED_PRESS_DOWN_M_S: f64 = 1.0;
/// Landed stays Landed this long after the last sign of being down, whatever the height
/// estimate says: longer than the autopilot takes to confirm a touchdown (see the sequencer's
/// `touchdown_confirm_s`), shorter than any take-off to above LH.
const LANDED_HOLD_S: f64 = 6.0;

/// The state machine proper, with the PID's state.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Machine {
    pub(super) config: LandingConfig,
    pid: HorizontalPid,
    pub(super) mode: LandingMode,
    last_time_s: Option<f64>,
    last_pid_time_s: Option<f64>,
    last_fix_time_s: Option<f64>,
    centred_since_s: Option<f64>,
    /// The last step that said the vehicle is down (the autopilot's touchdown, or entering
    /// Landed).
    down_at_s: Option<f64>,
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
    pub(super) fn new(config: LandingConfig) -> Result<Self, LandingError> {
        config.validate()?;
        Ok(Self {
            pid: HorizontalPid::new(config.pid)?,
            config,
            mode: LandingMode::Search,
            last_time_s: None,
            last_pid_time_s: None,
            last_fix_time_s: None,
            centred_since_s: None,
            down_at_s: None,
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

    pub(super) fn step(
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
        self.update_platform_accel(input);
        self.update_velocity_shortfall(input);
        let dt_s = self
            .last_time_s
            .map_or(0.0, |previous_s| time_s - previous_s);
        let view_offset = self.update_view_offset(input, dt_s);
        let wind = self.update_aerodynamic_accel(input, dt_s);
        self.update_descent_rate(height_m, dt_s);
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

        let (horizontal, vertical_down_m_s, land_command) =
            self.mode_setpoints(input, usable_fix, setpoint_ne_m, dt_s, centred, mpc)?;
        let horizontal =
            self.with_wind_shear_feed_forward(horizontal, wind, vertical_down_m_s, height_m);
        let gust_shift_ne_m_s = self.gust_shift_ne_m_s(height_m);
        // The autopilot's shortfall is made up while the vehicle steers (not while it only
        // holds still in Search, nor on the ground).
        let steering = !matches!(self.mode, LandingMode::Search | LandingMode::Landed);
        let horizontal = self.with_velocity_shortfall(horizontal, steering);
        let horizontal = self.with_final_correction_bound(input, horizontal, gust_shift_ne_m_s);
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

    /// The platform's acceleration, low-passed, from the change of its velocity since the
    /// previous step; then this step's velocity becomes the previous one.
    fn update_platform_accel(&mut self, input: &LandingInput) {
        let c = self.config;
        let time_s = input.time_s;
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
    }

    /// The autopilot's shortfall against the last command (the wind's push, by its velocity
    /// lag), low-passed and bounded; cleared with the PID while the commands are not flown.
    fn update_velocity_shortfall(&mut self, input: &LandingInput) {
        let c = self.config;
        let time_s = input.time_s;
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
    }

    /// The keep-in-view offset per metre of height, low-passed over `dt_s`.
    fn update_view_offset(&mut self, input: &LandingInput, dt_s: f64) -> Vector2<f64> {
        let c = self.config;
        let raw_offset = input.pad_in_view_offset_per_height;
        let view_offset = low_pass_from(
            self.pad_in_view_offset_per_height,
            raw_offset,
            dt_s,
            c.keep_in_view_tau_s,
        );
        self.pad_in_view_offset_per_height = Some(view_offset);
        view_offset
    }

    /// The aerodynamic acceleration and its slow baseline, low-passed over `dt_s`, from the
    /// input's wind when it is finite (gone without it); returns that wind.
    fn update_aerodynamic_accel(
        &mut self,
        input: &LandingInput,
        dt_s: f64,
    ) -> Option<NearGroundWind> {
        let c = self.config;
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
        wind
    }

    /// The descent rate from the previous step's height, low-passed (not on the first step);
    /// then this step's height becomes the previous one.
    fn update_descent_rate(&mut self, height_m: f64, dt_s: f64) {
        if let Some(previous_m) = self.previous_height_m.filter(|_| dt_s > 0.0) {
            let raw_m_s = (previous_m - height_m) / dt_s;
            self.descent_rate_m_s =
                low_pass(self.descent_rate_m_s, raw_m_s, dt_s, DESCENT_RATE_TAU_S);
        }
        self.previous_height_m = Some(height_m);
    }

    /// The current mode's horizontal velocity, vertical speed (down positive) and whether it
    /// asks the autopilot to land, before the wind's and the commit's shaping.
    fn mode_setpoints(
        &mut self,
        input: &LandingInput,
        usable_fix: Option<RelativeFix>,
        setpoint_ne_m: Vector2<f64>,
        dt_s: f64,
        centred: bool,
        mpc: Option<&mut MpcController>,
    ) -> Result<(Vector2<f64>, f64, bool), LandingError> {
        let c = self.config;
        let height_m = input.height_above_pad_m;
        Ok(match self.mode {
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
                let h = self.horizontal_tracking(input, usable_fix, setpoint_ne_m, mpc)?;
                (h, self.hold_height(height_m, self.hold_height_m), false)
            }
            LandingMode::Descend => {
                let h = self.horizontal_tracking(input, usable_fix, setpoint_ne_m, mpc)?;
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
                let h = self.horizontal_tracking(input, usable_fix, setpoint_ne_m, mpc)?;
                let down_m_s = c.final_descent_rate_m_s(height_m, self.descent_rate_m_s);
                (h, down_m_s, true)
            }
            // Down, or all but: ride with the pad, pressing onto it, until the autopilot takes
            // over.
            // Never faster than the flare meets the pad.
            LandingMode::Landed => (
                input.platform_velocity_ne_m_s,
                LANDED_PRESS_DOWN_M_S.min(c.final_descent_rate_m_s(0.0, 0.0)),
                true,
            ),
        })
    }

    /// Descending into the weaker wind near the ground: lean less before the velocity loop
    /// finds out.
    fn with_wind_shear_feed_forward(
        &self,
        horizontal: Vector2<f64>,
        wind: Option<NearGroundWind>,
        vertical_down_m_s: f64,
        height_m: f64,
    ) -> Vector2<f64> {
        let c = self.config;
        match (wind, self.aerodynamic_accel_ne_m_s2) {
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
        }
    }

    /// After the commit a gust is answered as the vehicle feels it: its push (the aerodynamic
    /// acceleration less what the autopilot's integrator has learned) is asked of the
    /// velocity loop the other way, before a drift shows it. Earlier, the tracking itself
    /// answers (the answer there made the tail worse: Dryden p95 up to 0.41 m); in the last
    /// centimetres it only tips the vehicle, as the corrections do.
    fn gust_shift_ne_m_s(&self, height_m: f64) -> Vector2<f64> {
        let c = self.config;
        match (
            self.aerodynamic_accel_ne_m_s2,
            self.aerodynamic_baseline_ne_m_s2,
        ) {
            (Some(now), Some(baseline))
                if self.mode == LandingMode::FinalLanding && !self.in_touchdown_band(height_m) =>
            {
                -(now - baseline) * c.gust_feed_forward_s
            }
            _ => Vector2::zeros(),
        }
    }

    /// The command with the autopilot's shortfall made up while `steering`; otherwise the
    /// shortfall estimate is dropped (it restarts when the vehicle steers again).
    fn with_velocity_shortfall(
        &mut self,
        horizontal: Vector2<f64>,
        steering: bool,
    ) -> Vector2<f64> {
        let c = self.config;
        if steering && c.wind_compensation_tau_s > 0.0 {
            horizontal + self.velocity_shortfall_ne_m_s
        } else {
            self.velocity_shortfall_ne_m_s = Vector2::zeros();
            self.expected_velocity_ne_m_s = None;
            horizontal
        }
    }

    /// After the commit the vehicle moves with the pad (its velocity and turn, the wind's
    /// shortfall made up) plus a bounded correction, a small one in the last centimetres:
    /// so late a correction cannot centre the vehicle, it only tips it. The gust's answer
    /// comes on top, unbounded: it is no correction, it meets a force.
    fn with_final_correction_bound(
        &self,
        input: &LandingInput,
        horizontal: Vector2<f64>,
        gust_shift_ne_m_s: Vector2<f64>,
    ) -> Vector2<f64> {
        let c = self.config;
        let height_m = input.height_above_pad_m;
        if self.mode == LandingMode::FinalLanding {
            let with_the_pad =
                self.platform_feed_forward_ne_m_s(input) + self.velocity_shortfall_ne_m_s;
            let limit_m_s = if self.in_touchdown_band(height_m) {
                c.max_touchdown_correction_m_s
            } else {
                c.max_final_correction_m_s
            };
            with_the_pad + clamp_norm(horizontal - with_the_pad, limit_m_s) + gust_shift_ne_m_s
        } else {
            horizontal
        }
    }

    /// The last centimetres before contact, where a correction only tips the vehicle: below
    /// `touchdown_correction_height_m`, or less than `touchdown_correction_lead_s` from the pad
    /// at the measured descent rate.
    fn in_touchdown_band(&self, height_m: f64) -> bool {
        let c = self.config;
        height_m
            <= c.touchdown_correction_height_m
                .max(self.descent_rate_m_s * c.touchdown_correction_lead_s)
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
            && self.descent_rate_m_s
                < STALLED_DESCENT_FRACTION * c.final_descent_rate_m_s(height_m, 0.0);
        if self.mode != LandingMode::Landed
            && (input.touchdown_detected
                || stalled
                || (self.mode == LandingMode::FinalLanding && height_m <= c.touchdown_height_m))
        {
            self.mode = LandingMode::Landed;
            self.down_at_s = Some(time_s);
            return;
        }
        if input.touchdown_detected {
            self.down_at_s = Some(time_s);
        }
        match self.mode {
            // Airborne again (a mission that starts on the ground, or a take-off after a
            // landing): the procedure starts over.
            LandingMode::Landed => {
                // Only a vehicle clearly gone from the pad: near it the camera sees too little
                // of the marker to tell the height (a real PX4 was sent climbing back to
                // Search within 0.1 s of its touchdown, before its land detector agreed).
                let down_for_s = self.down_at_s.map_or(f64::INFINITY, |at_s| time_s - at_s);
                if !input.touchdown_detected
                    && height_m > c.final_landing_height_m
                    && down_for_s >= LANDED_HOLD_S
                {
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
