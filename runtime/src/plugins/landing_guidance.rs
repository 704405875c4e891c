//! The `landing_guidance` plugin: the landing state machine and controller, turning the
//! tracker's relative state into velocity setpoints and the land command.

use crate::bus::{Publisher, Subscriber};
use crate::registry::{PluginRegistry, RegistryError};
use crate::task::{Task, TaskContext, TaskError};
use crate::topics::{
    LandingSetpoint, RelativeState, VehicleState, LANDING_SETPOINT, RELATIVE_STATE, VEHICLE_STATE,
};
use algorithms::control::landing::{LandingConfig, LandingController, LandingInput, RelativeFix};
use nalgebra::Vector2;
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

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    super::register_builtin(registry, PLUGIN_NAME, GuidanceTask::new)
}

struct GuidanceTask {
    controller: LandingController,
    max_fix_age_s: f64,
    vehicle: Option<Subscriber<VehicleState>>,
    relative: Option<Subscriber<RelativeState>>,
    output: Option<Publisher<LandingSetpoint>>,
}

impl GuidanceTask {
    fn new(params: Params) -> Result<Self, TaskError> {
        let controller = LandingController::new(LandingConfig {
            initial_height_m: params.initial_altitude_m,
            final_landing_height_m: params.final_altitude_m,
            ..LandingConfig::default()
        })
        .map_err(|e| TaskError::Params(e.to_string()))?;
        Ok(Self {
            controller,
            max_fix_age_s: params.max_fix_age_s,
            vehicle: None,
            relative: None,
            output: None,
        })
    }
}

impl Task for GuidanceTask {
    fn start(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        self.vehicle = Some(ctx.bus().subscriber(VEHICLE_STATE)?);
        self.relative = Some(ctx.bus().subscriber(RELATIVE_STATE)?);
        self.output = Some(ctx.bus().publisher(LANDING_SETPOINT)?);
        Ok(())
    }

    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let (Some(vehicle), Some(relative), Some(output)) = (
            self.vehicle.as_mut(),
            self.relative.as_mut(),
            self.output.as_ref(),
        ) else {
            return Err(TaskError::failed("stepped before start"));
        };
        let Some(state) = vehicle.latest().map(|m| m.value) else {
            return Ok(());
        };
        let now_s = ctx.now().as_secs_f64();
        let latest = relative.latest().map(|m| m.value);
        let fix = latest
            .filter(|r| now_s - r.estimate.time_s <= self.max_fix_age_s)
            .map(|r| RelativeFix {
                uav_minus_pad_ned_m: r.estimate.uav_relative_ned_m,
                covariance_ned_m2: r.estimate.covariance_m2,
            });
        let platform_velocity = latest
            .and_then(|r| r.platform_velocity_ned_m_s)
            .map(|v| Vector2::new(v.x, v.y))
            .unwrap_or_else(Vector2::zeros);
        let step = self.controller.step(&LandingInput {
            time_s: now_s,
            fix,
            height_above_pad_m: state.height_above_pad_m,
            platform_velocity_ne_m_s: platform_velocity,
            touchdown_detected: state.landed,
        });
        match step {
            Ok(out) => {
                output.publish(
                    ctx.now(),
                    LandingSetpoint {
                        mode: out.mode,
                        velocity_setpoint_ned_m_s: out.velocity_setpoint_ned_m_s,
                        land_command: out.land_command,
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
                        land_command: hover.land_command,
                    },
                );
                Ok(())
            }
        }
    }
}
