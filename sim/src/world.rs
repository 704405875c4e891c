//! The world's one physics step: the tractor drives on, the wind blows, the vehicle's body
//! (the built-in multirotor, or the rigid body a real autopilot flies) integrates its forces.
//! The in-process simulator, the served world and the real autopilots' backends all step it
//! here.

use nalgebra::Vector3;

use crate::quadrotor::{Quadrotor, QuadrotorError};
use crate::realism::{DriverBehaviour, PadMotion, Realism, RealismError};
use crate::tractor::{PadState, PathKind, Tractor, TractorError, TractorParams};
use crate::vehicle::{Multirotor, VehicleError};
use crate::wind::{Wind, WindConfig, WindError, WindKind};

/// A body the world moves.
pub trait Body {
    fn position_ned_m(&self) -> Vector3<f64>;
    fn velocity_ned_m_s(&self) -> Vector3<f64>;
    /// Off every surface.
    fn is_flying(&self) -> bool;
    /// Integrates `dt_s` up to `time_s` under the wind's force, above the pad as it is then.
    fn advance(
        &mut self,
        dt_s: f64,
        time_s: f64,
        wind_force_ned_n: Vector3<f64>,
        pad: &PadState,
    ) -> Result<(), WorldError>;
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorldError {
    #[error(transparent)]
    Tractor(#[from] TractorError),
    #[error(transparent)]
    Vehicle(#[from] VehicleError),
    #[error(transparent)]
    Quadrotor(#[from] QuadrotorError),
    #[error(transparent)]
    Wind(#[from] WindError),
    #[error(transparent)]
    Realism(#[from] RealismError),
}

/// What world to build: the same for every way it runs (the in-process harness, the served
/// world, the real autopilots' physics backend).
#[derive(Debug, Clone, PartialEq)]
pub struct WorldOptions {
    /// The tractor's path.
    pub path: PathKind,
    /// The mean wind, from the east.
    pub wind_speed_m_s: f64,
    pub wind_kind: WindKind,
    /// The tractor's speed on its path.
    pub platform_speed_m_s: f64,
    /// Where the tractor waits for the vehicle.
    pub meeting_point_ne_m: [f64; 2],
    /// Every random draw of the world (gusts, driver, field, camera, hazards) follows from it.
    pub seed: u64,
    /// How far the world is from the ideal one: the driver, the pad's motion, and what the
    /// runtime sees of it (camera, estimator, telemetry).
    pub realism: Realism,
}

impl Default for WorldOptions {
    /// A straight path in calm air, the tractor at 1.5 m/s waiting 15 m north, realistic.
    fn default() -> Self {
        Self {
            path: PathKind::Straight,
            wind_speed_m_s: 0.0,
            wind_kind: WindKind::Gusts,
            platform_speed_m_s: 1.5,
            meeting_point_ne_m: [15.0, 0.0],
            seed: 0,
            realism: Realism::default(),
        }
    }
}

impl Body for Multirotor {
    fn position_ned_m(&self) -> Vector3<f64> {
        Multirotor::position_ned_m(self)
    }
    fn velocity_ned_m_s(&self) -> Vector3<f64> {
        Multirotor::velocity_ned_m_s(self)
    }
    fn is_flying(&self) -> bool {
        Multirotor::is_flying(self)
    }
    fn advance(
        &mut self,
        dt_s: f64,
        time_s: f64,
        wind_force_ned_n: Vector3<f64>,
        pad: &PadState,
    ) -> Result<(), WorldError> {
        Ok(self.step(dt_s, time_s, wind_force_ned_n, pad)?)
    }
}

impl Body for Quadrotor {
    fn position_ned_m(&self) -> Vector3<f64> {
        Quadrotor::position_ned_m(self)
    }
    fn velocity_ned_m_s(&self) -> Vector3<f64> {
        Quadrotor::velocity_ned_m_s(self)
    }
    fn is_flying(&self) -> bool {
        Quadrotor::is_flying(self)
    }
    fn advance(
        &mut self,
        dt_s: f64,
        time_s: f64,
        wind_force_ned_n: Vector3<f64>,
        pad: &PadState,
    ) -> Result<(), WorldError> {
        Ok(self.step(dt_s, time_s, wind_force_ned_n, pad)?)
    }
}

/// The tractor with its pad and the air around the vehicle.
#[derive(Debug, Clone)]
pub struct World {
    pub tractor: Tractor,
    pub wind: Wind,
    /// The tractor waits parked until the vehicle is with it.
    pub tractor_moving: bool,
}

impl World {
    pub fn new(tractor: Tractor, wind: Wind) -> Self {
        Self {
            tractor,
            wind,
            tractor_moving: false,
        }
    }

    /// The tractor parked at the meeting point with its pad `pad_height_m` up (0: on the
    /// ground), its driver and field as the realism says, and the wind.
    pub fn build(options: &WorldOptions, pad_height_m: f64) -> Result<Self, WorldError> {
        options.realism.validate()?;
        let params = TractorParams {
            speed_m_s: options.platform_speed_m_s,
            pad_height_m,
            ..TractorParams::default()
        };
        let mut tractor =
            Tractor::new(options.path, params, options.meeting_point_ne_m, 0.0)?.parked();
        let realism = &options.realism;
        if realism.driver != DriverBehaviour::SCRIPTED {
            tractor = tractor.with_driver(realism.driver, options.seed);
        }
        if realism.pad != PadMotion::STILL {
            tractor = tractor.with_rough_field(realism.pad, options.seed);
        }
        let wind = Wind::new(
            WindConfig::from_east(options.wind_speed_m_s, options.wind_kind),
            options.seed ^ 0x5749_4e44,
        )?;
        Ok(Self::new(tractor, wind))
    }

    pub fn pad(&self) -> PadState {
        self.tractor.pad()
    }

    /// One tick of physics, `tick_s` from `time_s` in steps of `dt_s`: the one sub-step loop
    /// of every world that moves the body itself. `between(t_s, body)` runs before each step
    /// but the first: a served world acts on the commands that arrived meanwhile, as a real
    /// autopilot does, rather than on the next tick.
    pub fn step_tick<B: Body, E: From<WorldError>>(
        &mut self,
        time_s: f64,
        tick_s: f64,
        dt_s: f64,
        body: &mut B,
        mut between: impl FnMut(f64, &mut B) -> Result<(), E>,
    ) -> Result<(), E> {
        let steps = (tick_s / dt_s).round() as usize;
        for step in 0..steps {
            let t_s = time_s + step as f64 * dt_s;
            if step > 0 {
                between(t_s, body)?;
            }
            self.step(t_s, dt_s, body)?;
        }
        Ok(())
    }

    /// One physics step from `time_s` to `time_s + dt_s`.
    pub fn step(&mut self, time_s: f64, dt_s: f64, body: &mut impl Body) -> Result<(), WorldError> {
        if self.tractor_moving {
            self.tractor.step(dt_s)?;
        }
        let position = body.position_ned_m();
        let force = self
            .wind
            .force_ned_n(time_s, -position.z, body.velocity_ned_m_s());
        body.advance(dt_s, time_s + dt_s, force, &self.tractor.pad())
    }
}
