//! The `landing_guidance` plugin: the landing state machine and controller, turning the
//! tracker's relative state into velocity setpoints and the land command.
//!
//! `controller = "pid"` (default) flies seed 000's two-stage PID; `controller = "mpc"` the MPC,
//! whose model step is kept equal to the task's QoS period (re-timed on every level change,
//! horizon `mpc_horizon_s` long). The descent starts only in the mission's landing phase (its
//! last, as [`MissionPhase::landing`] says) once a phase is published; with no phase on the bus
//! (a dry run, a bench test) it is always allowed.

use crate::bus::{Publisher, Subscriber};
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::QosLevel;
use crate::task::{Task, TaskBuild, TaskContext, TaskError};
use crate::topics::{
    LandingSetpoint, MissionPhase, RelativeState, VehicleState, LANDING_SETPOINT, MISSION_PHASE,
    RELATIVE_STATE, VEHICLE_STATE,
};
use algorithms::camera::PinholeCamera;
use algorithms::control::landing::{
    HorizontalController, LandingConfig, LandingController, LandingInput, NearGroundWind,
    RelativeFix,
};
use algorithms::control::mpc::MpcConfig;
use algorithms::control::pid::TwoStageGains;
use algorithms::control::wind_shear::aerodynamic_accel_ne_m_s2;
use algorithms::estimation::camera_mount::CameraMount;
use algorithms::estimation::projection::pad_in_view_offset_ne_m;
use nalgebra::{Vector2, Vector3};
use serde::Deserialize;

pub const PLUGIN_NAME: &str = "landing_guidance";

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// IH: the height at which the vehicle follows the platform before descending.
    #[serde(default = "default_initial")]
    initial_altitude_m: f64,
    /// LH: below this height, once centred, the landing is committed.
    #[serde(default = "default_final")]
    final_altitude_m: f64,
    /// A relative state older than this counts as no fix.
    #[serde(default = "default_max_age")]
    max_fix_age_s: f64,
    /// Setpoint lead: the relative state is carried forward, at the vehicle's velocity less
    /// the pad's, by its age plus this, so the command answers where the vehicle will be when
    /// the autopilot acts on it (0: the estimate as it is).
    #[serde(default)]
    setpoint_lead_s: f64,
    /// The tracker bridges gaps between vision fixes by prediction; a prediction whose last
    /// vision fix is older than this counts as no fix (a frozen or blind camera), so the
    /// landing aborts instead of descending on dead reckoning. Longer than the slowest
    /// detection period.
    #[serde(default = "default_max_vision_gap")]
    max_vision_gap_s: f64,
    /// Descent speed after the commit.
    #[serde(default = "default_final_descent_speed")]
    final_descent_speed_m_s: f64,
    /// The flare: the descent slows at this deceleration to `touchdown_speed_m_s` at the pad,
    /// reading the profile `flare_lead_s` ahead (the autopilot's vertical lag); 0: no flare.
    #[serde(default)]
    flare_deceleration_m_s2: f64,
    #[serde(default = "default_touchdown_speed")]
    touchdown_speed_m_s: f64,
    #[serde(default = "default_flare_lead")]
    flare_lead_s: f64,
    /// Wind feed-forward: the low-pass time constant of the autopilot's estimated velocity
    /// shortfall, added to the commands (0: off).
    #[serde(default)]
    wind_compensation_tau_s: f64,
    /// Integral gain of the PID's close-in stage (seed 000's Table 2: 0).
    #[serde(default)]
    integral_gain_close_per_s2: f64,
    /// Proportional and derivative gains of the PID's close-in stage (seed 000's Table 2:
    /// 1.5 and 0.5).
    #[serde(default = "default_proportional_gain_close")]
    proportional_gain_close_per_s: f64,
    #[serde(default = "default_derivative_gain_close")]
    derivative_gain_close: f64,
    /// Below this height above the pad the close-in gains fly (seed 000's Table 2: 4 m).
    #[serde(default = "default_gain_switch_height")]
    gain_switch_height_m: f64,
    /// Wind-shear feed-forward while descending: the roughness length of the ground's
    /// logarithmic wind profile (0.05 m over crops; 0: off).
    #[serde(default)]
    wind_shear_roughness_m: f64,
    /// How far ahead the descent's wind is predicted.
    #[serde(default = "default_wind_shear_lead")]
    wind_shear_lead_s: f64,
    /// After the commit, the command strays from the platform's velocity by at most
    /// `max_final_correction_m_s`, and in the last `touchdown_correction_height_m` by at most
    /// `max_touchdown_correction_m_s`: so late, a large correction only tips the vehicle.
    #[serde(default = "default_max_final_correction")]
    max_final_correction_m_s: f64,
    #[serde(default = "default_touchdown_correction_height")]
    touchdown_correction_height_m: f64,
    /// The band reaches at least this long before contact at the measured descent rate.
    #[serde(default = "default_touchdown_correction_lead")]
    touchdown_correction_lead_s: f64,
    #[serde(default = "default_max_touchdown_correction")]
    max_touchdown_correction_m_s: f64,
    /// After the commit and above `touchdown_correction_height_m`, a gust's push (the
    /// aerodynamic acceleration less its baseline over `gust_baseline_tau_s`) × this is taken
    /// off the command, so the autopilot pushes back before a drift shows it (0: off).
    #[serde(default)]
    gust_feed_forward_s: f64,
    #[serde(default = "default_gust_baseline_tau")]
    gust_baseline_tau_s: f64,
    #[serde(default)]
    controller: ControllerKind,
    /// The MPC's horizon in seconds; its step count follows from the QoS period.
    #[serde(default = "default_mpc_horizon")]
    mpc_horizon_s: f64,
    /// The MPC's per-axis speed and acceleration limits.
    #[serde(default = "default_mpc_max_speed")]
    mpc_max_speed_m_s: f64,
    #[serde(default = "default_mpc_max_accel")]
    mpc_max_accel_m_s2: f64,
    /// Wall-clock time a solve may take before the MPC flies its safe fallback; a board
    /// slower than the one the default suits needs more.
    #[serde(default = "default_mpc_solve_time_limit")]
    mpc_solve_time_limit_s: f64,
    /// Keep the pad in the camera's view: in strong wind the vehicle leans further than the
    /// camera's half field of view, so it follows from upwind, by as much as keeps the pad
    /// inside the image less this margin (a fraction of its half-size on each side).
    #[serde(default = "default_keep_in_view")]
    keep_in_view: bool,
    #[serde(default = "default_keep_in_view_margin")]
    keep_in_view_margin_fraction: f64,
}

#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
enum ControllerKind {
    #[default]
    Pid,
    Mpc,
}

fn default_proportional_gain_close() -> f64 {
    TwoStageGains::seed_simulation().low.kp_per_s
}
fn default_derivative_gain_close() -> f64 {
    TwoStageGains::seed_simulation().low.kd
}
fn default_gain_switch_height() -> f64 {
    TwoStageGains::seed_simulation().switch_height_m
}
fn default_wind_shear_lead() -> f64 {
    LandingConfig::default().wind_shear_lead_s
}
fn default_max_final_correction() -> f64 {
    LandingConfig::default().max_final_correction_m_s
}
fn default_touchdown_correction_height() -> f64 {
    LandingConfig::default().touchdown_correction_height_m
}
fn default_touchdown_correction_lead() -> f64 {
    LandingConfig::default().touchdown_correction_lead_s
}
fn default_max_touchdown_correction() -> f64 {
    LandingConfig::default().max_touchdown_correction_m_s
}
fn default_gust_baseline_tau() -> f64 {
    LandingConfig::default().gust_baseline_tau_s
}
fn default_mpc_horizon() -> f64 {
    1.0
}
fn default_mpc_max_speed() -> f64 {
    MpcConfig::default().max_speed_m_s
}
fn default_mpc_max_accel() -> f64 {
    MpcConfig::default().max_accel_m_s2
}
fn default_mpc_solve_time_limit() -> f64 {
    MpcConfig::default().solve_time_limit_s
}
fn default_keep_in_view() -> bool {
    true
}

fn default_keep_in_view_margin() -> f64 {
    0.3
}

fn default_final_descent_speed() -> f64 {
    LandingConfig::default().final_descent_speed_m_s
}
fn default_touchdown_speed() -> f64 {
    LandingConfig::default().touchdown_speed_m_s
}
fn default_flare_lead() -> f64 {
    LandingConfig::default().flare_lead_s
}
fn default_initial() -> f64 {
    7.5
}
fn default_final() -> f64 {
    1.5
}
fn default_max_age() -> f64 {
    0.5
}
fn default_max_vision_gap() -> f64 {
    3.0
}

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    super::register_builtin(registry, PLUGIN_NAME, GuidanceTask::new)
}

/// The vehicle's offset from the pad `ahead_s` on, at `relative_velocity` (the vehicle's less
/// the pad's): what the estimate will be when the autopilot acts on a command sent now.
fn relative_ahead(
    uav_minus_pad_ned_m: &Vector3<f64>,
    relative_velocity_ned_m_s: &Vector3<f64>,
    ahead_s: f64,
) -> Vector3<f64> {
    uav_minus_pad_ned_m + relative_velocity_ned_m_s * ahead_s
}

struct GuidanceTask {
    controller: LandingController,
    /// The camera and the margin the pad is kept inside, when keeping it in view.
    keep_in_view: Option<(PinholeCamera, f64)>,
    camera_mount: CameraMount,
    max_fix_age_s: f64,
    max_vision_gap_s: f64,
    setpoint_lead_s: f64,
    vehicle: Subscriber<VehicleState>,
    phase: Subscriber<MissionPhase>,
    relative: Subscriber<RelativeState>,
    output: Publisher<LandingSetpoint>,
}

impl GuidanceTask {
    fn new(params: Params, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        let defaults = LandingConfig::default();
        let controller = match params.controller {
            ControllerKind::Pid => HorizontalController::Pid,
            ControllerKind::Mpc => {
                if !(params.mpc_horizon_s.is_finite() && params.mpc_horizon_s > 0.0) {
                    return Err(TaskError::Params(format!(
                        "mpc_horizon_s = {} must be a finite number > 0",
                        params.mpc_horizon_s
                    )));
                }
                // Timed for a 50 ms period until the scheduler sets the level's period.
                let mpc = MpcConfig::default();
                HorizontalController::Mpc(MpcConfig {
                    horizon_steps: ((params.mpc_horizon_s / mpc.dt_s).round() as usize).max(1),
                    max_speed_m_s: params.mpc_max_speed_m_s,
                    max_accel_m_s2: params.mpc_max_accel_m_s2,
                    solve_time_limit_s: params.mpc_solve_time_limit_s,
                    ..mpc
                })
            }
        };
        let controller = LandingController::new(LandingConfig {
            initial_height_m: params.initial_altitude_m,
            final_landing_height_m: params.final_altitude_m,
            final_descent_speed_m_s: params.final_descent_speed_m_s,
            flare_deceleration_m_s2: params.flare_deceleration_m_s2,
            touchdown_speed_m_s: params.touchdown_speed_m_s,
            flare_lead_s: params.flare_lead_s,
            wind_compensation_tau_s: params.wind_compensation_tau_s,
            wind_shear_roughness_m: params.wind_shear_roughness_m,
            wind_shear_lead_s: params.wind_shear_lead_s,
            max_final_correction_m_s: params.max_final_correction_m_s,
            touchdown_correction_height_m: params.touchdown_correction_height_m,
            touchdown_correction_lead_s: params.touchdown_correction_lead_s,
            max_touchdown_correction_m_s: params.max_touchdown_correction_m_s,
            gust_feed_forward_s: params.gust_feed_forward_s,
            gust_baseline_tau_s: params.gust_baseline_tau_s,
            pid: {
                let mut pid = defaults.pid;
                pid.gains.low.ki_per_s2 = params.integral_gain_close_per_s2;
                pid.gains.low.kp_per_s = params.proportional_gain_close_per_s;
                pid.gains.low.kd = params.derivative_gain_close;
                pid.gains.switch_height_m = params.gain_switch_height_m;
                pid
            },
            controller,
            // The MPC predicts with the platform's acceleration: a fresher estimate suits it.
            platform_accel_filter_tau_s: match params.controller {
                ControllerKind::Pid => defaults.platform_accel_filter_tau_s,
                ControllerKind::Mpc => 0.1,
            },
            ..defaults
        })
        .map_err(|e| TaskError::Params(e.to_string()))?;
        if !(params.setpoint_lead_s.is_finite() && params.setpoint_lead_s >= 0.0) {
            return Err(TaskError::Params(format!(
                "setpoint_lead_s = {} must be a finite number of seconds >= 0",
                params.setpoint_lead_s
            )));
        }
        let margin = params.keep_in_view_margin_fraction;
        if !(0.0..1.0).contains(&margin) {
            return Err(TaskError::Params(format!(
                "keep_in_view_margin_fraction = {margin} must lie in [0, 1)"
            )));
        }
        // The mission's one camera; a gimballed one sees below the vehicle whatever its lean.
        let camera_settings = &build.config().camera;
        let camera = camera_settings
            .pinhole()
            .map_err(|e| TaskError::Params(format!("the landing's camera: {e}")))?;
        Ok(Self {
            controller,
            keep_in_view: params.keep_in_view.then_some((camera, margin)),
            camera_mount: camera_settings.mount,
            max_fix_age_s: params.max_fix_age_s,
            max_vision_gap_s: params.max_vision_gap_s,
            setpoint_lead_s: params.setpoint_lead_s,
            vehicle: build.input(VEHICLE_STATE)?,
            phase: build.input(MISSION_PHASE)?,
            relative: build.input(RELATIVE_STATE)?,
            output: build.output(LANDING_SETPOINT)?,
        })
    }
}

impl Task for GuidanceTask {
    fn set_qos(&mut self, level: &QosLevel) -> Result<(), TaskError> {
        self.controller
            .set_control_period(level.period().as_secs_f64())
            .map_err(|e| TaskError::Params(e.to_string()))
    }

    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let (vehicle, relative, output) = (&mut self.vehicle, &mut self.relative, &self.output);
        let Some(state_message) = vehicle.latest() else {
            return Ok(());
        };
        let state = state_message.value;
        let now_s = ctx.now().as_secs_f64();
        // Setpoints are flown while the autopilot is in offboard and still reporting (a lost
        // link leaves the last state standing).
        let setpoints_followed =
            state.offboard && now_s - state_message.stamp.as_secs_f64() <= self.max_fix_age_s;
        let latest = relative.latest().map(|m| m.value);
        let fresh = latest
            .filter(|r| now_s - r.estimate.time_s <= self.max_fix_age_s)
            .map(|mut r| {
                if self.setpoint_lead_s > 0.0 {
                    let pad_velocity = r.platform_velocity_ned_m_s.unwrap_or_else(Vector3::zeros);
                    let ahead_s = (now_s - r.estimate.time_s).max(0.0) + self.setpoint_lead_s;
                    r.estimate.uav_relative_ned_m = relative_ahead(
                        &r.estimate.uav_relative_ned_m,
                        &(state.velocity_ned_m_s - pad_velocity),
                        ahead_s,
                    );
                }
                r
            });
        let fix = fresh
            .filter(|r| {
                r.last_fix_time_s
                    .is_some_and(|fix_s| now_s - fix_s <= self.max_vision_gap_s)
            })
            .map(|r| RelativeFix {
                uav_minus_pad_ned_m: r.estimate.uav_relative_ned_m,
                covariance_ned_m2: r.estimate.covariance_m2,
            });
        let platform_velocity = latest
            .and_then(|r| r.platform_velocity_ned_m_s)
            .map(|v| Vector2::new(v.x, v.y))
            .unwrap_or_else(Vector2::zeros);
        let descent_allowed = self
            .phase
            .latest()
            // The mission's landing phase (outside a mission, no phase: descend).
            .is_none_or(|phase| phase.value.landing);
        let step = self.controller.step(&LandingInput {
            time_s: now_s,
            fix,
            height_above_pad_m: state.height_above_pad_m,
            platform_velocity_ne_m_s: platform_velocity,
            touchdown_detected: state.landed,
            uav_velocity_ne_m_s: state.velocity_ned_m_s.xy(),
            descent_allowed,
            predicted_uav_minus_pad_ne_m: fresh.map(|r| r.estimate.uav_relative_ned_m.xy()),
            setpoints_followed,
            pad_in_view_offset_per_height: self
                .keep_in_view
                .as_ref()
                .zip(
                    self.camera_mount
                        .camera_attitude(&state.attitude, state.gimbal_attitude.as_ref()),
                )
                .and_then(|((camera, margin), camera_attitude)| {
                    pad_in_view_offset_ne_m(camera, &camera_attitude, 1.0, *margin)
                })
                .unwrap_or_else(Vector2::zeros),
            near_ground_wind: state.position_ned_m.and_then(|position| {
                aerodynamic_accel_ne_m_s2(
                    &state.attitude.body_to_ned(),
                    &state.acceleration_ned_m_s2,
                )
                .map(|aerodynamic_accel_ne_m_s2| NearGroundWind {
                    altitude_m: -position.z,
                    aerodynamic_accel_ne_m_s2,
                })
            }),
        });
        match step {
            Ok(out) => {
                output.publish(
                    ctx.now(),
                    LandingSetpoint {
                        mode: out.mode,
                        velocity_setpoint_ned_m_s: out.velocity_setpoint_ned_m_s,
                    },
                );
                Ok(())
            }
            // Bad vehicle telemetry: hold position this step, as the controller's docs ask.
            Err(error) => {
                tracing::warn!(task = ctx.name(), %error, "landing step refused; hovering");
                let hover =
                    algorithms::control::landing::LandingOutput::hover(self.controller.mode());
                output.publish(
                    ctx.now(),
                    LandingSetpoint {
                        mode: hover.mode,
                        velocity_setpoint_ned_m_s: hover.velocity_setpoint_ned_m_s,
                    },
                );
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Knob;

    fn task(params: &str) -> Result<GuidanceTask, TaskError> {
        super::super::build_from_params(PLUGIN_NAME, params, GuidanceTask::new)
    }

    fn mpc_config(task: &GuidanceTask) -> MpcConfig {
        match task.controller.config().controller {
            HorizontalController::Mpc(config) => config,
            other => panic!("not the MPC: {other:?}"),
        }
    }

    #[test]
    fn the_controller_is_chosen_by_params() {
        let pid = task("").unwrap();
        assert_eq!(
            pid.controller.config().controller,
            HorizontalController::Pid
        );
        let mpc =
            task("controller = \"mpc\"\nmpc_horizon_s = 1.5\nmpc_max_speed_m_s = 4.0").unwrap();
        let config = mpc_config(&mpc);
        assert_eq!(config.max_speed_m_s, 4.0);
        assert_eq!(config.horizon_steps as f64 * config.dt_s, 1.5);
        let Err(TaskError::Params(why)) = task("controller = \"lqr\"") else {
            panic!("an unknown controller must be refused");
        };
        assert!(why.contains("lqr") && why.contains("mpc"), "{why}");
        assert!(matches!(
            task("controller = \"mpc\"\nmpc_horizon_s = -1.0"),
            Err(TaskError::Params(_))
        ));
        assert!(matches!(
            task("controller = \"mpc\"\nmpc_max_accel_m_s2 = 0.0"),
            Err(TaskError::Params(_))
        ));
    }

    /// The wind parameters reach the controller, and a bad one is refused by name.
    #[test]
    fn the_wind_parameters_are_taken_and_checked() {
        let windy = task(
            "wind_compensation_tau_s = 1.0\nintegral_gain_close_per_s2 = 0.5\nfinal_descent_speed_m_s = 1.5\n\
             proportional_gain_close_per_s = 8.0\nderivative_gain_close = 2.5\n\
             wind_shear_roughness_m = 0.05\nwind_shear_lead_s = 0.4\ngain_switch_height_m = 1.5\n\
             touchdown_correction_height_m = 0.25\nmax_touchdown_correction_m_s = 0.2\n\
             touchdown_correction_lead_s = 0.4\n\
             max_final_correction_m_s = 1.2\ngust_feed_forward_s = 0.6\ngust_baseline_tau_s = 2.0\n\
             flare_deceleration_m_s2 = 2.5\ntouchdown_speed_m_s = 0.6\nflare_lead_s = 0.3",
        )
        .unwrap();
        let config = windy.controller.config();
        assert_eq!(config.wind_compensation_tau_s, 1.0);
        assert_eq!(config.pid.gains.low.ki_per_s2, 0.5);
        assert_eq!(config.pid.gains.low.kp_per_s, 8.0);
        assert_eq!(config.pid.gains.low.kd, 2.5);
        assert_eq!(config.pid.gains.switch_height_m, 1.5);
        assert_eq!(config.final_descent_speed_m_s, 1.5);
        assert_eq!(config.wind_shear_roughness_m, 0.05);
        assert_eq!(config.wind_shear_lead_s, 0.4);
        assert_eq!(config.touchdown_correction_height_m, 0.25);
        assert_eq!(config.touchdown_correction_lead_s, 0.4);
        assert_eq!(config.max_touchdown_correction_m_s, 0.2);
        assert_eq!(config.max_final_correction_m_s, 1.2);
        assert_eq!(config.gust_feed_forward_s, 0.6);
        assert_eq!(config.gust_baseline_tau_s, 2.0);
        assert_eq!(config.flare_deceleration_m_s2, 2.5);
        assert_eq!(config.touchdown_speed_m_s, 0.6);
        assert_eq!(config.flare_lead_s, 0.3);
        // Unset, they are the seed's law (Table 2's close-in gains, no feed-forward).
        let plain = task("").unwrap();
        let plain = plain.controller.config();
        assert_eq!(plain.wind_compensation_tau_s, 0.0);
        assert_eq!(plain.pid.gains.low.ki_per_s2, 0.0);
        assert_eq!(
            (plain.pid.gains.low.kp_per_s, plain.pid.gains.low.kd),
            (1.5, 0.5)
        );
        assert_eq!(plain.wind_shear_roughness_m, 0.0);
        assert_eq!(plain.gust_feed_forward_s, 0.0);
        assert_eq!(plain.touchdown_correction_lead_s, 0.0);
        assert_eq!(plain.flare_deceleration_m_s2, 0.0);
        assert_eq!(plain.pid.gains.switch_height_m, 4.0);
        for (params, name) in [
            ("wind_compensation_tau_s = -1.0", "wind_compensation_tau_s"),
            ("final_descent_speed_m_s = 0.0", "final_descent_speed_m_s"),
            ("integral_gain_close_per_s2 = -0.5", "ki_per_s2"),
            ("proportional_gain_close_per_s = -8.0", "kp_per_s"),
            ("derivative_gain_close = -1.0", "kd"),
            ("wind_shear_roughness_m = -0.05", "wind_shear_roughness_m"),
            ("wind_shear_lead_s = -0.3", "wind_shear_lead_s"),
            (
                "touchdown_correction_height_m = -0.1",
                "touchdown_correction_height_m",
            ),
            (
                "touchdown_correction_lead_s = -0.4",
                "touchdown_correction_lead_s",
            ),
            ("max_final_correction_m_s = 0.0", "max_final_correction_m_s"),
            (
                "max_touchdown_correction_m_s = nan",
                "max_touchdown_correction_m_s",
            ),
            ("gust_feed_forward_s = -0.5", "gust_feed_forward_s"),
            ("gust_baseline_tau_s = 0.0", "gust_baseline_tau_s"),
            ("flare_deceleration_m_s2 = -2.0", "flare_deceleration_m_s2"),
            ("touchdown_speed_m_s = 0.0", "touchdown_speed_m_s"),
            ("flare_lead_s = inf", "flare_lead_s"),
            ("setpoint_lead_s = -0.05", "setpoint_lead_s"),
        ] {
            let Err(TaskError::Params(why)) = task(params) else {
                panic!("{params} must be refused");
            };
            assert!(why.contains(name), "{params}: {why}");
        }
    }

    /// The lead carries the offset forward at the closing velocity: 1.5 m behind a pad that
    /// the vehicle closes on at 2 m/s is 1.4 m behind 50 ms on (worked by hand).
    #[test]
    fn the_setpoint_lead_carries_the_offset_forward_at_the_closing_velocity() {
        let ahead = relative_ahead(
            &Vector3::new(-1.5, 0.2, -3.0),
            &Vector3::new(2.0, 0.0, 0.5),
            0.05,
        );
        assert!(
            (ahead - Vector3::new(-1.4, 0.2, -2.975)).norm() < 1e-12,
            "{ahead}"
        );
        assert_eq!(task("").unwrap().setpoint_lead_s, 0.0);
        assert_eq!(
            task("setpoint_lead_s = 0.05").unwrap().setpoint_lead_s,
            0.05
        );
    }

    /// Keeping the pad in view is on by default with the mission's camera; off, or with another
    /// camera and margin; bad values are named.
    #[test]
    fn the_keep_in_view_parameters_are_taken_and_checked() {
        let default = task("").unwrap();
        let (camera, margin) = default.keep_in_view.expect("on by default");
        assert_eq!((camera.width_px, camera.height_px), (640, 480));
        assert_eq!(margin, 0.3);
        assert!(task("keep_in_view = false").unwrap().keep_in_view.is_none());
        let wide_camera = crate::config::CameraSettings {
            horizontal_fov_deg: 90.0,
            ..Default::default()
        };
        let with_camera = |params: &str, camera: &crate::config::CameraSettings| {
            super::super::build_with_camera(PLUGIN_NAME, params, camera.clone(), GuidanceTask::new)
        };
        let wide = with_camera("keep_in_view_margin_fraction = 0.1", &wide_camera)
            .unwrap()
            .keep_in_view
            .unwrap();
        assert!((wide.0.fx_px - 320.0).abs() < 1e-9, "{}", wide.0.fx_px);
        assert_eq!(wide.1, 0.1);
        for (params, name) in [
            (
                "keep_in_view_margin_fraction = 1.0",
                "keep_in_view_margin_fraction",
            ),
            (
                "keep_in_view_margin_fraction = -0.1",
                "keep_in_view_margin_fraction",
            ),
        ] {
            let Err(TaskError::Params(why)) = task(params) else {
                panic!("{params} must be refused");
            };
            assert!(why.contains(name), "{params}: {why}");
        }
        let flat = crate::config::CameraSettings {
            horizontal_fov_deg: 0.0,
            ..Default::default()
        };
        let Err(TaskError::Params(why)) = with_camera("", &flat) else {
            panic!("a camera with no field of view must be refused");
        };
        assert!(why.contains("camera"), "{why}");
    }

    /// The MPC's model step follows the QoS period; its horizon keeps its length in seconds.
    #[test]
    fn the_mpc_is_retimed_to_each_qos_period() {
        let mut mpc = task("controller = \"mpc\"").unwrap();
        for (period_ms, steps) in [(100.0, 10), (20.0, 50), (50.0, 20)] {
            let level = QosLevel {
                index: 0,
                knob: Knob::PeriodMs,
                value: period_ms,
                period_ms,
            };
            mpc.set_qos(&level).unwrap();
            let config = mpc_config(&mpc);
            assert!(
                (config.dt_s - period_ms / 1000.0).abs() < 1e-12,
                "{config:?}"
            );
            assert_eq!(config.horizon_steps, steps);
        }
        // The PID needs no re-timing and accepts any level.
        let mut pid = task("").unwrap();
        let level = QosLevel {
            index: 2,
            knob: Knob::PeriodMs,
            value: 20.0,
            period_ms: 20.0,
        };
        pid.set_qos(&level).unwrap();
        assert_eq!(
            pid.controller.config().controller,
            HorizontalController::Pid
        );
    }
}
