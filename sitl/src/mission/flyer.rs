//! The world's vehicle in a mission and who flies it: the built-in multirotor with its PX4-like
//! autopilot on the loopback, or a real PX4 or ArduPilot flying the world's rigid body. Either
//! way the runtime reaches it only over its MAVLink link.

use nalgebra::Vector3;
use runtime::link::{LinkConfig, MavlinkLink};
use runtime::mission::runner::LOCKSTEP_TIMEOUT;
use sim::autopilot::{MavlinkAutopilot, StreamRates};
use sim::camera::VehiclePose;
use sim::estimate::EstimatedTelemetry;
use sim::flight::BatteryReading;
use sim::gimbal::Gimbal;
use sim::power::RotorPowerModel;
use sim::realism::Realism;
use sim::vehicle::{Multirotor, Touchdown, VehicleParams};
use sim::wind::Wind;
use sim::world::World;

use super::autopilot::{AutopilotProcess, CameraGimbal, GimballedVehicle, RealVehicle};
use super::{link_error, setup, RealAutopilot, SimError, PHYSICS_DT_S, TICK_S};

/// The world's vehicle in a mission, and who flies it.
pub(super) enum Flyer {
    /// The built-in multirotor with its PX4-like autopilot on the loopback, and the estimator
    /// errors its telemetry carries.
    Builtin {
        vehicle: Box<Multirotor>,
        autopilot: Box<MavlinkAutopilot>,
        estimate: Box<EstimatedTelemetry>,
    },
    /// A real autopilot, and the camera's gimbal reporting itself where the mission has one.
    Real(Box<GimballedVehicle>),
}

/// The flyer, the runtime's end of its MAVLink link, and the autopilot process qosrt started
/// (kept alive for the mission).
pub(super) type Connected = (Flyer, MavlinkLink, Option<AutopilotProcess>);

impl Flyer {
    /// The built-in autopilot on the loopback, sending to the runtime's port as PX4 SITL does,
    /// in lockstep unless the mission flies on the wall clock.
    pub(super) fn builtin(
        gimbal: Option<Gimbal>,
        realism: &Realism,
        seed: u64,
        real_time: bool,
    ) -> Result<Connected, SimError> {
        let link = MavlinkLink::bind_local_ephemeral(LinkConfig::default()).map_err(link_error)?;
        let runtime_addr = link
            .local_addr()
            .ok_or_else(|| SimError::Link("the link has no local UDP address".into()))?;
        let telemetry = &realism.telemetry;
        let autopilot = MavlinkAutopilot::bind_local(runtime_addr, !real_time)
            .map_err(link_error)?
            .with_stream_rates(StreamRates {
                attitude_hz: telemetry.attitude_rate_hz,
                position_hz: telemetry.position_rate_hz,
                distance_hz: telemetry.distance_rate_hz,
            });
        let mut vehicle =
            Multirotor::on_ground(VehicleParams::default(), Vector3::zeros()).map_err(setup)?;
        if let Some(gimbal) = gimbal {
            vehicle = vehicle.with_gimbal(gimbal);
        }
        let estimate = EstimatedTelemetry::new(
            realism.estimator,
            realism.rangefinder,
            telemetry.latency_s,
            seed,
        );
        let flyer = Self::Builtin {
            vehicle: Box::new(vehicle),
            autopilot: Box::new(autopilot),
            estimate: Box::new(estimate),
        };
        Ok((flyer, link, None))
    }

    /// A real autopilot flying the world's rigid body (started by qosrt where it has the
    /// command), and the runtime's link to it.
    pub(super) fn real(
        real: &RealAutopilot,
        gimbal: Option<Gimbal>,
        seed: u64,
    ) -> Result<Connected, SimError> {
        let gimbal = gimbal
            .map(|gimbal| CameraGimbal::for_autopilot(gimbal, real))
            .transpose()?;
        let (vehicle, process) = RealVehicle::connect(real, seed)?;
        let link = real.open_link(process.as_ref())?;
        let flyer = Self::Real(Box::new(GimballedVehicle::new(vehicle, gimbal)));
        Ok((flyer, link, process))
    }

    /// The built-in autopilot's MAVLink drops everything both ways while `down`; a real one's
    /// link is its own.
    pub(super) fn set_link_down(&mut self, down: bool) {
        if let Self::Builtin { autopilot, .. } = self {
            autopilot.set_link_down(down);
        }
    }

    /// The built-in autopilot sends its telemetry (as its estimator reports the vehicle),
    /// ending, in lockstep, with the barrier the runtime reads up to; a real autopilot streams
    /// on its own.
    pub(super) fn send_telemetry(
        &mut self,
        time_s: f64,
        battery: BatteryReading,
        lockstep: bool,
    ) -> Result<Option<u64>, SimError> {
        match self {
            Self::Builtin {
                vehicle,
                autopilot,
                estimate,
            } => {
                let snapshot = estimate.report(&vehicle.snapshot(time_s, battery));
                let t_ns = autopilot.publish(&snapshot).map_err(link_error)?;
                Ok(lockstep.then_some(t_ns))
            }
            Self::Real(_) => Ok(None),
        }
    }

    /// The built-in autopilot applies the runtime's commands (up to the barrier `lockstep`
    /// names, or as they came) and acknowledges them; a real autopilot has its own.
    pub(super) fn apply_commands(
        &mut self,
        time_s: f64,
        lockstep: Option<u64>,
    ) -> Result<(), SimError> {
        let Self::Builtin {
            vehicle, autopilot, ..
        } = self
        else {
            return Ok(());
        };
        let received = match lockstep {
            Some(t_ns) => autopilot.receive_lockstep(t_ns, LOCKSTEP_TIMEOUT),
            None => autopilot.receive(),
        }
        .map_err(link_error)?;
        for received in received {
            let result = vehicle.command(received.command, time_s);
            if let Some(pending) = received.ack {
                autopilot.ack(pending, &result).map_err(link_error)?;
            }
        }
        Ok(())
    }

    /// One tick of physics from `time_s`: the world's steps with the built-in vehicle, or in
    /// lockstep with the real autopilot.
    pub(super) fn step_world(&mut self, world: &mut World, time_s: f64) -> Result<(), SimError> {
        match self {
            Self::Builtin { vehicle, .. } => {
                world.step_tick(time_s, TICK_S, PHYSICS_DT_S, vehicle.as_mut(), |_, _| {
                    Ok::<(), SimError>(())
                })
            }
            Self::Real(real) => real.step_until(world, time_s + TICK_S, TICK_S),
        }
    }

    pub(super) fn camera_pose(&self) -> VehiclePose {
        match self {
            Self::Builtin { vehicle, .. } => vehicle.camera_pose(),
            Self::Real(real) => real.camera_pose(),
        }
    }

    pub(super) fn position_ned_m(&self) -> Vector3<f64> {
        match self {
            Self::Builtin { vehicle, .. } => vehicle.position_ned_m(),
            Self::Real(real) => real.vehicle.body().position_ned_m(),
        }
    }

    /// Where it last came down.
    pub(super) fn touchdown(&self) -> Option<Touchdown> {
        self.touchdowns().last().copied()
    }

    /// Its first contact after flying.
    pub(super) fn first_touchdown(&self) -> Option<Touchdown> {
        self.touchdowns().first().copied()
    }

    fn touchdowns(&self) -> &[Touchdown] {
        match self {
            Self::Builtin { vehicle, .. } => vehicle.touchdowns(),
            Self::Real(real) => real.vehicle.body().touchdowns(),
        }
    }

    pub(super) fn flight_power_w(
        &self,
        wind: &mut Wind,
        rotors: &RotorPowerModel,
        time_s: f64,
    ) -> f64 {
        match self {
            Self::Builtin { vehicle, .. } => {
                super::flight_power_w(vehicle.as_ref(), wind, rotors, time_s)
            }
            Self::Real(real) => super::flight_power_w(real.vehicle.body(), wind, rotors, time_s),
        }
    }
}
