//! PX4's simulator interface (its `simulator_mavlink` module), served by the world as Gazebo
//! Classic and jMAVSim serve it: the world listens on TCP 4560+i, PX4 connects, the world sends
//! HIL_SENSOR (IMU, magnetometer, barometer), HIL_GPS and the downward DISTANCE_SENSOR, and PX4
//! answers each sensor step with HIL_ACTUATOR_CONTROLS, the motor commands. PX4's clock is the
//! sensors' `time_usec` (lockstep): the world sets the pace.

use std::io::{ErrorKind, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::time::{Duration, Instant};

use mavlink::dialects::common::{
    HilSensorUpdatedFlags, MavAutopilot, MavDistanceSensor, MavMessage, MavModeFlag,
    MavSensorOrientation, MavState, MavType, DISTANCE_SENSOR_DATA, HEARTBEAT_DATA, HIL_GPS_DATA,
    HIL_SENSOR_DATA,
};
use mavlink::{MavHeader, MavlinkReader, MavlinkVersion};
use sim::quadrotor::Quadrotor;
use sim::sensors::{GpsFix, ImuSample, Sensors};
use sim::world::World;

/// PX4 instance i connects to this port + i.
pub const PX4_SIMULATOR_PORT: u16 = 4560;
/// Every field of HIL_SENSOR is fresh: accelerometer, gyroscope, magnetometer (3 × 3 bits),
/// absolute and differential pressure, pressure altitude, temperature.
const ALL_SENSOR_FIELDS: u32 = 0x1FFF;
/// The simulator's MAVLink ids on this link (jMAVSim's and Gazebo's).
const SIMULATOR_SYSTEM_ID: u8 = 1;
const SIMULATOR_COMPONENT_ID: u8 = 51;

#[derive(Debug, thiserror::Error)]
pub enum Px4HilError {
    #[error("PX4 HIL: cannot listen on TCP 127.0.0.1:{port}: {source}")]
    Listen {
        port: u16,
        #[source]
        source: std::io::Error,
    },
    #[error("PX4 HIL: no PX4 connected to TCP 127.0.0.1:{port} within {waited_s:.1} s (is PX4 started with a `none_iris`-style airframe and instance {instance}?)")]
    NoConnection {
        port: u16,
        instance: u8,
        waited_s: f64,
    },
    #[error("PX4 HIL: PX4 sent no motor commands for {waited_s:.1} s after the sensors of t = {time_s:.3} s ({bytes} bytes of other traffic; stalled or not a PX4 simulator link)")]
    Stalled {
        time_s: f64,
        waited_s: f64,
        bytes: u64,
    },
    #[error("PX4 HIL: PX4 closed the simulator connection")]
    Closed,
    #[error("PX4 HIL: the world: {0}")]
    World(#[from] sim::world::WorldError),
    #[error("PX4 HIL: simulator connection: {0}")]
    Io(#[from] std::io::Error),
}

/// A byte counter under the reader: how much the peer sent, valid or not.
struct Counted {
    stream: TcpStream,
    bytes: u64,
}

impl std::io::Read for Counted {
    fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        let n = self.stream.read(buffer)?;
        self.bytes += n as u64;
        Ok(n)
    }
}

/// What PX4 last commanded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorCommands {
    /// PX4's own clock for the step it answers.
    pub time_usec: u64,
    /// The first four outputs, 0–1 (NaN or below 0: stopped).
    pub motors: [f64; 4],
    pub armed: bool,
}

/// One PX4 connected to the world.
pub struct Px4Hil {
    writer: TcpStream,
    reader: MavlinkReader<Counted>,
    sequence: u8,
    last_heartbeat_s: Option<f64>,
    /// Longest wait for PX4's answer to one sensor step.
    pub step_timeout: Duration,
    pub peer: SocketAddr,
}

impl Px4Hil {
    /// Listens where PX4 instance `instance` will connect (TCP 127.0.0.1:4560+instance).
    pub fn listen(instance: u8) -> Result<TcpListener, Px4HilError> {
        let port = PX4_SIMULATOR_PORT + u16::from(instance);
        let listener = TcpListener::bind(("127.0.0.1", port))
            .map_err(|source| Px4HilError::Listen { port, source })?;
        listener.set_nonblocking(true)?;
        Ok(listener)
    }

    /// Waits up to `timeout` for PX4 to connect (it retries every second until one listens).
    pub fn accept(
        listener: &TcpListener,
        instance: u8,
        timeout: Duration,
    ) -> Result<Self, Px4HilError> {
        let start = Instant::now();
        let port = listener.local_addr()?.port();
        loop {
            match listener.accept() {
                Ok((stream, peer)) => return Self::over(stream, peer),
                Err(error) if error.kind() == ErrorKind::WouldBlock => {
                    if start.elapsed() >= timeout {
                        return Err(Px4HilError::NoConnection {
                            port,
                            instance,
                            waited_s: start.elapsed().as_secs_f64(),
                        });
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
                Err(error) => return Err(error.into()),
            }
        }
    }

    fn over(stream: TcpStream, peer: SocketAddr) -> Result<Self, Px4HilError> {
        stream.set_nonblocking(false)?;
        // Lockstep is a ping-pong of small messages: no Nagle delay.
        stream.set_nodelay(true)?;
        let writer = stream.try_clone()?;
        Ok(Self {
            writer,
            reader: MavlinkReader::new(Counted { stream, bytes: 0 }),
            sequence: 0,
            last_heartbeat_s: None,
            step_timeout: Duration::from_secs(5),
            peer,
        })
    }

    fn send(&mut self, message: &MavMessage) -> Result<(), Px4HilError> {
        let header = MavHeader {
            system_id: u32::from(SIMULATOR_SYSTEM_ID),
            component_id: SIMULATOR_COMPONENT_ID,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let mut bytes = Vec::with_capacity(64);
        mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, message)
            .map_err(|error| Px4HilError::Io(std::io::Error::other(error.to_string())))?;
        self.writer
            .write_all(&bytes)
            .map_err(|error| match error.kind() {
                ErrorKind::BrokenPipe | ErrorKind::ConnectionReset => Px4HilError::Closed,
                _ => Px4HilError::Io(error),
            })
    }

    /// One sensor step at `time_s` of the world's clock: HIL_SENSOR, with HIL_GPS and the
    /// rangefinder when they are due, and a 1 Hz HEARTBEAT.
    pub fn send_sensors(
        &mut self,
        time_s: f64,
        imu: &ImuSample,
        gps: Option<&GpsFix>,
        rangefinder_m: Option<Option<f64>>,
    ) -> Result<(), Px4HilError> {
        let time_usec = time_usec(time_s);
        if self
            .last_heartbeat_s
            .is_none_or(|last| time_s - last >= 1.0)
        {
            self.last_heartbeat_s = Some(time_s);
            self.send(&MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: MavType::MAV_TYPE_GENERIC,
                autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                base_mode: MavModeFlag::empty(),
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            }))?;
        }
        self.send(&hil_sensor(time_usec, imu))?;
        if let Some(fix) = gps {
            self.send(&hil_gps(time_usec, fix))?;
        }
        if let Some(range) = rangefinder_m {
            self.send(&distance_sensor(time_s, range))?;
        }
        Ok(())
    }

    /// Waits for PX4's answer to the sensor step at `time_s`, its HIL_ACTUATOR_CONTROLS, for
    /// at most [`Self::step_timeout`]: none is a [`Px4HilError::Stalled`].
    pub fn receive_motors(&mut self, time_s: f64) -> Result<MotorCommands, Px4HilError> {
        let start = Instant::now();
        let bytes_before = self.reader.get_ref().bytes;
        self.receive_motors_within(self.step_timeout)?
            .ok_or_else(|| Px4HilError::Stalled {
                time_s,
                waited_s: start.elapsed().as_secs_f64(),
                bytes: self.reader.get_ref().bytes - bytes_before,
            })
    }

    /// PX4's next HIL_ACTUATOR_CONTROLS if one comes within `wait`.
    pub fn receive_motors_within(
        &mut self,
        wait: Duration,
    ) -> Result<Option<MotorCommands>, Px4HilError> {
        let start = Instant::now();
        loop {
            let left = wait.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Ok(None);
            }
            self.reader
                .get_mut()
                .stream
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))?;
            match self.reader.read_any_message::<MavMessage>() {
                Ok((_, MavMessage::HIL_ACTUATOR_CONTROLS(controls))) => {
                    return Ok(Some(MotorCommands {
                        time_usec: controls.time_usec,
                        motors: [0, 1, 2, 3].map(|i| f64::from(controls.controls[i])),
                        armed: controls
                            .mode
                            .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
                    }));
                }
                // PX4's heartbeats and anything else on this link.
                Ok(_) => {}
                Err(mavlink::error::MessageReadError::Parse(_)) => {}
                Err(mavlink::error::MessageReadError::Io(error)) => match error.kind() {
                    ErrorKind::WouldBlock | ErrorKind::TimedOut => {}
                    ErrorKind::UnexpectedEof | ErrorKind::ConnectionReset => {
                        return Err(Px4HilError::Closed)
                    }
                    _ => return Err(error.into()),
                },
            }
        }
    }
}

/// PX4 flying the world's rigid body: one lockstep sensor step at a time.
pub struct Px4Vehicle {
    pub hil: Px4Hil,
    pub body: Quadrotor,
    pub sensors: Sensors,
    /// The world's time of the next sensor step.
    pub time_s: f64,
    steps: u64,
    pub last_commands: Option<MotorCommands>,
    waiting_since: Option<Instant>,
}

impl Px4Vehicle {
    /// PX4's IMU rate (`IMU_INTEG_RATE` 250 Hz): one sensor step.
    pub const STEP_S: f64 = 0.004;
    /// The rangefinder reports every fifth step (50 Hz).
    const RANGEFINDER_EVERY: u64 = 5;
    /// PX4 boots in about a second; it must answer the sensors well within this.
    const FIRST_ANSWER_TIMEOUT: Duration = Duration::from_secs(30);

    pub fn new(hil: Px4Hil, body: Quadrotor, sensors: Sensors) -> Self {
        Self {
            hil,
            body,
            sensors,
            time_s: 0.0,
            steps: 0,
            last_commands: None,
            waiting_since: None,
        }
    }

    /// Sends the sensors at the present instant, waits for PX4's motor commands, and moves
    /// the world on by one step under them.
    pub fn step(&mut self, world: &mut World) -> Result<(), Px4HilError> {
        let state = *self.body.state();
        let imu = self.sensors.imu(Self::STEP_S, &state);
        let gps = self.sensors.gps(self.time_s, &state);
        let range = self
            .steps
            .is_multiple_of(Self::RANGEFINDER_EVERY)
            .then(|| self.sensors.rangefinder(self.body.rangefinder_m()));
        self.hil
            .send_sensors(self.time_s, &imu, gps.as_ref(), range)?;
        if self.last_commands.is_some() {
            let commands = self.hil.receive_motors(self.time_s)?;
            self.body.set_motor_commands(commands.motors);
            self.last_commands = Some(commands);
        } else {
            // PX4 answers only once its modules run: until its first answer the world steps on
            // at about the wall clock's pace (as Gazebo's plugin does), the motors still.
            let started = *self.waiting_since.get_or_insert_with(Instant::now);
            match self
                .hil
                .receive_motors_within(Duration::from_secs_f64(Self::STEP_S))?
            {
                Some(commands) => {
                    self.body.set_motor_commands(commands.motors);
                    self.last_commands = Some(commands);
                }
                None if started.elapsed() > Self::FIRST_ANSWER_TIMEOUT => {
                    return Err(Px4HilError::Stalled {
                        time_s: self.time_s,
                        waited_s: started.elapsed().as_secs_f64(),
                        bytes: 0,
                    })
                }
                None => {}
            }
        }
        world.step(self.time_s, Self::STEP_S, &mut self.body)?;
        self.steps += 1;
        self.time_s = self.steps as f64 * Self::STEP_S;
        Ok(())
    }
}

/// The world's time as PX4's clock. It starts at 1 s: PX4 takes 0 for "no time yet".
pub fn time_usec(time_s: f64) -> u64 {
    ((time_s + 1.0) * 1e6).round() as u64
}

fn hil_sensor(time_usec: u64, imu: &ImuSample) -> MavMessage {
    MavMessage::HIL_SENSOR(HIL_SENSOR_DATA {
        time_usec,
        xacc: imu.accel_frd_m_s2.x as f32,
        yacc: imu.accel_frd_m_s2.y as f32,
        zacc: imu.accel_frd_m_s2.z as f32,
        xgyro: imu.gyro_frd_rad_s.x as f32,
        ygyro: imu.gyro_frd_rad_s.y as f32,
        zgyro: imu.gyro_frd_rad_s.z as f32,
        xmag: imu.mag_frd_gauss.x as f32,
        ymag: imu.mag_frd_gauss.y as f32,
        zmag: imu.mag_frd_gauss.z as f32,
        abs_pressure: imu.pressure_hpa as f32,
        diff_pressure: 0.0,
        pressure_alt: imu.pressure_altitude_m as f32,
        temperature: imu.temperature_c as f32,
        fields_updated: HilSensorUpdatedFlags::from_bits_truncate(ALL_SENSOR_FIELDS),
        id: 0,
    })
}

fn hil_gps(time_usec: u64, fix: &GpsFix) -> MavMessage {
    let v = fix.velocity_ned_m_s;
    let ground_speed = v.xy().norm();
    // Course over ground, centidegrees from north, 0–35999.
    let cog = (v.y.atan2(v.x).to_degrees().rem_euclid(360.0) * 100.0).round() as u16 % 36_000;
    let cm_s = |value: f64| (value * 100.0).round().clamp(-32_767.0, 32_767.0) as i16;
    MavMessage::HIL_GPS(HIL_GPS_DATA {
        time_usec,
        lat: (fix.latitude_deg * 1e7).round() as i32,
        lon: (fix.longitude_deg * 1e7).round() as i32,
        alt: (fix.altitude_m * 1e3).round() as i32,
        // PX4 reads these as the accuracies in cm.
        eph: (fix.horizontal_accuracy_m * 100.0).round() as u16,
        epv: (fix.vertical_accuracy_m * 100.0).round() as u16,
        vel: (ground_speed * 100.0).round() as u16,
        vn: cm_s(v.x),
        ve: cm_s(v.y),
        vd: cm_s(v.z),
        cog,
        fix_type: 3,
        satellites_visible: fix.satellites,
        id: 0,
        yaw: 0,
    })
}

fn distance_sensor(time_s: f64, range_m: Option<f64>) -> MavMessage {
    let (min_cm, max_cm) = (10u16, 1_500u16);
    // Out of range reads as just beyond the maximum, as a LiDAR reports "no return".
    let current = range_m.map_or(max_cm + 1, |r| {
        (r * 100.0).round().clamp(0.0, 65_535.0) as u16
    });
    MavMessage::DISTANCE_SENSOR(DISTANCE_SENSOR_DATA {
        time_boot_ms: (time_s * 1e3) as u32,
        min_distance: min_cm,
        max_distance: max_cm,
        current_distance: current,
        mavtype: MavDistanceSensor::MAV_DISTANCE_SENSOR_LASER,
        id: 0,
        orientation: MavSensorOrientation::MAV_SENSOR_ROTATION_PITCH_270,
        covariance: 0,
        ..Default::default()
    })
}

#[cfg(test)]
mod tests;
