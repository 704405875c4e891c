//! The served world: built once, then stepped tick by tick on the wall clock, with whoever
//! flies its vehicle (the world's own autopilot, PX4's SIH, or a real autopilot the world is
//! the physics backend of).

use std::time::{Duration, Instant};

use nalgebra::{Vector2, Vector3};
use runtime::energy::MissionModel;
use sim::autopilot::MavlinkAutopilot;
use sim::camera::{SimCamera, VehiclePose};
use sim::power::{RotorPowerModel, SimBattery};
use sim::scene::{SimScene, TractorBody};
use sim::tractor::{PadState, TractorParams};
use sim::vehicle::{Multirotor, Touchdown, VehicleParams};
use sim::world::World;

use super::video::{open_video, send_frame, Video};
use super::*;
use crate::mission::{
    camera_config, camera_gimbal, flight_power_w, pack_and_rotors, pad_pose, CameraGimbal,
    GimballedVehicle, RealVehicle, SimError, PHYSICS_DT_S, TICK_S,
};
use crate::px4_sih::SihListener;

/// The vehicle, as the world moves it or as PX4 reports it.
enum Flyer {
    Simulated {
        vehicle: Box<Multirotor>,
        autopilot: Box<MavlinkAutopilot>,
        battery: SimBattery,
        rotors: RotorPowerModel,
    },
    Px4Sih {
        listener: SihListener,
        airborne: bool,
        previous_down_m: Option<f64>,
        touchdown: Option<ServedTouchdown>,
    },
    /// A real autopilot flying the world's rigid body.
    Real(Box<GimballedVehicle>),
}

/// The world, what sees it and who flies in it.
pub(super) struct ServedWorld {
    pub(super) world: World,
    scene: SimScene,
    camera: SimCamera,
    pub(super) video: Video,
    flyer: Flyer,
    pub(super) frames_rendered: u64,
    /// Since when the vehicle has hovered above the waiting tractor.
    above_since_s: Option<f64>,
}

fn motors_running(real: &RealVehicle) -> bool {
    match real {
        RealVehicle::Px4(px4) => px4.last_commands.as_ref().is_some_and(|c| c.armed),
        RealVehicle::ArduPilot(ardupilot) => ardupilot.motors_spinning(),
    }
}

impl From<Touchdown> for ServedTouchdown {
    fn from(t: Touchdown) -> Self {
        Self {
            time_s: t.time_s,
            on_pad: t.on_pad,
            horizontal_error_m: t.horizontal_error_m,
            vertical_speed_m_s: t.vertical_speed_m_s,
            tilt_deg: t.tilt_deg,
        }
    }
}

/// A touchdown on the ground under PX4's vehicle, against the pad lying there.
pub(super) fn judge(time_s: f64, pose: &VehiclePose, pad: &PadState) -> ServedTouchdown {
    let offset: Vector2<f64> = pad.to_pad_frame(pose.position_ned_m.xy());
    ServedTouchdown {
        time_s,
        on_pad: pad.contains_ne(pose.position_ned_m.xy()),
        horizontal_error_m: offset.norm(),
        vertical_speed_m_s: pose.velocity_ned_m_s.z,
        tilt_deg: pose.attitude.tilt_rad().to_degrees(),
    }
}

/// Sleeps until tick `tick` is due on the wall clock.
pub(super) fn pace(start: Instant, tick: u64) {
    pace_to(start, tick as f64 * TICK_S);
}

/// Sleeps until world time `time_s` is due on the wall clock.
fn pace_to(start: Instant, time_s: f64) {
    let due = start + Duration::from_secs_f64(time_s);
    std::thread::sleep(due.saturating_duration_since(Instant::now()));
}

/// The runtime's commands that have arrived, applied and acknowledged.
fn apply_commands(
    vehicle: &mut Multirotor,
    autopilot: &mut MavlinkAutopilot,
    time_s: f64,
) -> Result<(), ServeError> {
    for received in autopilot.receive()? {
        let result = vehicle.command(received.command, time_s);
        if let Some(pending) = received.ack {
            autopilot.ack(pending, &result)?;
        }
    }
    Ok(())
}

impl ServedWorld {
    /// The world `options` describe, its camera as the mission's config gives it, and who
    /// flies: a real autopilot the user started is waited for here.
    pub(super) fn build(model: &MissionModel, options: &ServeOptions) -> Result<Self, ServeError> {
        let sih = matches!(options.vehicle, ServeVehicle::Px4Sih { .. });
        // SIH's vehicle knows only the ground: its pad lies on it. The world's own vehicle and
        // the real autopilots' rigid body land on the pad where it is, on the tractor.
        let pad_height_m = if sih {
            0.0
        } else {
            TractorParams::default().pad_height_m
        };
        let mut world = World::build(&options.world, pad_height_m)?;
        let mut scene = SimScene::new(options.world.seed);
        if !sih {
            scene = scene
                .with_tractor_body(TractorBody::default())
                .map_err(setup)?;
        }
        let camera_config = camera_config(model);
        let (width_px, height_px, rate_fps) = (
            camera_config.width_px,
            camera_config.height_px,
            camera_config.rate_fps,
        );
        let camera = SimCamera::new(camera_config, options.world.seed).map_err(setup)?;
        let gimbal = camera_gimbal(model).map_err(setup)?;
        if sih && gimbal.is_some() {
            // SIH streams PX4's own telemetry: no gimbal reports the camera's attitude.
            return Err(setup(
                "PX4 SIH flies no camera gimbal: set [camera] mount = \"body\"",
            ));
        }
        let video = open_video(options.video_port, width_px, height_px, rate_fps)?;
        let flyer = Flyer::connect(model, options, gimbal, &mut world)?;
        Ok(Self {
            world,
            scene,
            camera,
            video,
            flyer,
            frames_rendered: 0,
            above_since_s: None,
        })
    }

    /// The camera's pose now (`None` while PX4 has not spoken), the world's own autopilot
    /// having sent its telemetry and applied the commands that came.
    pub(super) fn pose(
        &mut self,
        time_s: f64,
        pad: &PadState,
        start: Instant,
    ) -> Result<Option<VehiclePose>, ServeError> {
        Ok(match &mut self.flyer {
            Flyer::Simulated {
                vehicle,
                autopilot,
                battery,
                ..
            } => {
                autopilot.publish(&vehicle.snapshot(time_s, battery.reading()))?;
                apply_commands(vehicle, autopilot, time_s)?;
                // The camera's pose (the gimbal's, where it hangs in one); the same position.
                Some(vehicle.camera_pose())
            }
            Flyer::Px4Sih {
                listener,
                airborne,
                previous_down_m,
                touchdown,
            } => {
                // Stamped at arrival (within the poll), not at the tick.
                listener.poll(start.elapsed().as_secs_f64())?;
                let pose = listener.track.pose_at(time_s);
                if let Some(pose) = &pose {
                    let down_m = pose.position_ned_m.z;
                    *airborne |= -down_m > PX4_AIRBORNE_HEIGHT_M;
                    if let (true, None, Some(previous)) = (*airborne, *touchdown, *previous_down_m)
                    {
                        if previous < -PX4_TOUCHDOWN_HEIGHT_M && down_m >= -PX4_TOUCHDOWN_HEIGHT_M {
                            *touchdown = Some(judge(time_s, pose, pad));
                        }
                    }
                    *previous_down_m = Some(down_m);
                }
                pose
            }
            // The body's camera; its commands reach the autopilot, not the world.
            Flyer::Real(real) => Some(real.camera_pose()),
        })
    }

    /// The tractor drives off once the vehicle has hovered above it for long enough: the world
    /// does not know the runtime's phases.
    pub(super) fn follow_meeting(&mut self, time_s: f64, pose: &VehiclePose, pad: &PadState) {
        let relative = pose.position_ned_m - pad.centre_ned_m;
        let above = relative.xy().norm() <= MEET_RADIUS_M && -relative.z >= MEET_HEIGHT_M;
        self.above_since_s = if above {
            self.above_since_s.or(Some(time_s))
        } else {
            None
        };
        self.world.tractor_moving |= self
            .above_since_s
            .is_some_and(|since_s| time_s - since_s >= MEET_DWELL_S);
    }

    /// A frame when one is due, onto the video stream, stamped at the tick's instant on the
    /// wall clock however late the world runs.
    pub(super) fn render(
        &mut self,
        time_s: f64,
        pose: &VehiclePose,
        start: Instant,
    ) -> Result<(), ServeError> {
        if !self.camera.is_due(time_s) {
            return Ok(());
        }
        self.scene
            .set_pad_pose(pad_pose(&self.world.tractor))
            .map_err(setup)?;
        match self.camera.capture_frame(time_s, pose, &self.scene) {
            Ok(frame) => {
                self.frames_rendered += 1;
                let captured = start + Duration::from_secs_f64(time_s);
                send_frame(&mut self.video, &frame.image, captured.elapsed())?;
            }
            Err(error) => eprintln!("camera: {error}"),
        }
        Ok(())
    }

    /// Physics: the world's one step (the tractor, the wind, the body), to the tick's end; then
    /// the touchdown, if the vehicle has come down.
    pub(super) fn step(
        &mut self,
        time_s: f64,
        start: Instant,
    ) -> Result<Option<ServedTouchdown>, ServeError> {
        let world = &mut self.world;
        match &mut self.flyer {
            Flyer::Simulated {
                vehicle, autopilot, ..
            } => {
                // A real autopilot acts on a setpoint as it arrives, not on the next 50 Hz tick.
                world.step_tick(
                    time_s,
                    TICK_S,
                    PHYSICS_DT_S,
                    vehicle.as_mut(),
                    |t_s, vehicle| {
                        pace_to(start, t_s);
                        apply_commands(vehicle, autopilot, t_s)
                    },
                )?
            }
            // SIH moves its own vehicle: the world moves only the tractor.
            Flyer::Px4Sih { .. } => {
                if world.tractor_moving {
                    let substeps = (TICK_S / PHYSICS_DT_S).round() as usize;
                    for _ in 0..substeps {
                        world.tractor.step(PHYSICS_DT_S).map_err(setup)?;
                    }
                }
            }
            // In lockstep with the autopilot: its steps up to the tick's end.
            Flyer::Real(real) => real.step_until(world, time_s + TICK_S, TICK_S)?,
        }
        Ok(match &mut self.flyer {
            Flyer::Simulated {
                vehicle,
                battery,
                rotors,
                ..
            } => {
                let flight_w = flight_power_w(vehicle.as_ref(), &mut world.wind, rotors, time_s);
                // The companion computer's draw is the runtime's to report, not the world's.
                battery.drain(flight_w, 0.0, TICK_S).map_err(setup)?;
                vehicle.touchdown().map(ServedTouchdown::from)
            }
            Flyer::Px4Sih { touchdown, .. } => *touchdown,
            // The body's real contact with the pad or the ground.
            Flyer::Real(real) => real.vehicle.body().touchdown().map(ServedTouchdown::from),
        })
    }

    /// Whether the motors have stopped: the world's own vehicle needs no world to disarm; a
    /// real autopilot does.
    pub(super) fn motors_stopped(&self) -> bool {
        match &self.flyer {
            Flyer::Real(real) => !motors_running(&real.vehicle),
            Flyer::Simulated { .. } | Flyer::Px4Sih { .. } => true,
        }
    }
}

impl Flyer {
    /// Who `options` say flies, connected.
    fn connect(
        model: &MissionModel,
        options: &ServeOptions,
        gimbal: Option<sim::gimbal::Gimbal>,
        world: &mut World,
    ) -> Result<Self, ServeError> {
        Ok(match options.vehicle {
            ServeVehicle::Simulated => {
                let (battery, rotors) = pack_and_rotors(model).map_err(ServeError::Setup)?;
                let mut vehicle = Multirotor::on_ground(VehicleParams::default(), Vector3::zeros())
                    .map_err(setup)?;
                if let Some(gimbal) = gimbal {
                    vehicle = vehicle.with_gimbal(gimbal);
                }
                Self::Simulated {
                    vehicle: Box::new(vehicle),
                    autopilot: Box::new(MavlinkAutopilot::bind_local(options.mavlink_addr, false)?),
                    battery,
                    rotors,
                }
            }
            ServeVehicle::Px4Sih { instance } => Self::Px4Sih {
                listener: SihListener::bind(instance)?,
                airborne: false,
                previous_down_m: None,
                touchdown: None,
            },
            ServeVehicle::Px4Hil { .. } | ServeVehicle::ArduPilotJson { .. } => {
                let real = options
                    .vehicle
                    .real_autopilot(REAL_CONNECT_TIMEOUT)
                    .expect("a real autopilot");
                // The user started it: no process of ours to keep.
                let (mut vehicle, _no_process) = RealVehicle::connect(&real, options.world.seed)?;
                if let RealVehicle::ArduPilot(ardupilot) = &mut vehicle {
                    // ArduPilot's first servo packet is its connection: waited for before the
                    // world's clock starts, which then does not race to catch up with the wait.
                    ardupilot
                        .step(world)
                        .map_err(|error| SimError::Link(error.into()))?;
                }
                // The gimbal reports itself on the vehicle's MAVLink network, as in a mission.
                let gimbal = gimbal
                    .map(|gimbal| CameraGimbal::for_autopilot(gimbal, &real))
                    .transpose()?;
                Self::Real(Box::new(GimballedVehicle::new(vehicle, gimbal)))
            }
        })
    }
}
