//! Who flies the world's vehicle in a simulated mission: the built-in PX4-like autopilot, or a
//! real PX4 or ArduPilot for which the world is the physics backend (HIL / JSON). With a real
//! one the runtime talks to it over MAVLink exactly as on a drone, on its own ports.

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use runtime::link::{LinkConfig, MavlinkLink};
use sim::camera::VehiclePose;
use sim::quadrotor::{Quadrotor, QuadrotorParams};
use sim::sensors::{Home, SensorParams, Sensors};
use sim::world::World;

use crate::hil::ardupilot_json::{ArduPilotJson, ArduPilotVehicle};
use crate::hil::gimbal_device::GimbalDevice;
use crate::hil::px4::{Px4Hil, Px4Vehicle};
use algorithms::estimation::projection::Attitude;
use sim::gimbal::Gimbal;

use super::{link_error, SimError};

/// A real autopilot may take this long to be ready to arm (its estimator converging on the
/// world's sensors: PX4 about 16 s, ArduPilot about 42 s).
pub const REAL_AUTOPILOT_READY_S: f64 = 90.0;

/// Longest wait for a connected autopilot's answer to one step.
const STEP_TIMEOUT: Duration = Duration::from_secs(5);

/// Which autopilot flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AutopilotKind {
    /// The world's own PX4-like autopilot: fast, deterministic, the default for sweeps.
    #[default]
    Builtin,
    /// PX4 (`none_iris`-style airframe) over HIL on TCP 4560+i.
    Px4,
    /// ArduPilot Copter over JSON on UDP 9002+10i.
    ArduPilot,
}

impl AutopilotKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Builtin => "builtin",
            Self::Px4 => "px4",
            Self::ArduPilot => "ardupilot",
        }
    }
}

impl std::str::FromStr for AutopilotKind {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        match text {
            "builtin" => Ok(Self::Builtin),
            "px4" => Ok(Self::Px4),
            "ardupilot" => Ok(Self::ArduPilot),
            _ => Err(format!(
                "expected builtin, px4 or ardupilot, found {text:?}"
            )),
        }
    }
}

/// A real autopilot for one mission.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RealAutopilot {
    pub kind: AutopilotKind,
    /// The instance number: its ports shift by it (PX4: +i, ArduPilot: +10i).
    pub instance: u8,
    /// The command that starts it, `{i}` replaced by the instance; `None`: the user started it
    /// and qosrt waits for it.
    pub command: Option<String>,
    /// How long to wait for it to connect.
    pub connect_timeout: Duration,
}

impl RealAutopilot {
    /// The companion computer's MAVLink to it, as on a drone.
    pub fn mavlink_address(&self) -> String {
        match self.kind {
            AutopilotKind::ArduPilot => {
                format!("tcpout:127.0.0.1:{}", 5760 + 10 * u16::from(self.instance))
            }
            _ => format!("udpin:127.0.0.1:{}", 14540 + u16::from(self.instance)),
        }
    }
}

impl RealAutopilot {
    /// The runtime's link to it. ArduPilot's MAVLink server opens a moment after it starts:
    /// a refused connection is tried again until [`Self::connect_timeout`].
    pub fn open_link(&self, process: Option<&AutopilotProcess>) -> Result<MavlinkLink, SimError> {
        let start = std::time::Instant::now();
        loop {
            match MavlinkLink::connect(&self.mavlink_address(), LinkConfig::default()) {
                Ok(link) => return Ok(link),
                Err(error) if start.elapsed() >= self.connect_timeout => {
                    return Err(failed_start(error, process))
                }
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    }
}

/// An autopilot process qosrt started; killed with its process group when dropped (a PX4 still
/// waiting for its simulator ignores SIGTERM, and ArduPilot waiting for a JSON answer too).
pub struct AutopilotProcess {
    child: Child,
    /// What it printed, for the error when it fails.
    output: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
}

impl AutopilotProcess {
    fn spawn(command: &str, instance: u8) -> Result<Self, SimError> {
        let command = command.replace("{i}", &instance.to_string());
        let mut child = Command::new("sh")
            .args(["-c", &command])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            // Its own process group: the autopilot it starts in the background goes with it.
            .process_group(0)
            .spawn()
            .map_err(|error| {
                SimError::Setup(
                    format!("--autopilot-cmd {command:?} did not start: {error}").into(),
                )
            })?;
        let output = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        for stream in [
            child
                .stdout
                .take()
                .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
            child
                .stderr
                .take()
                .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
        ]
        .into_iter()
        .flatten()
        {
            let output = output.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    if let Ok(mut lines) = output.lock() {
                        lines.push(line);
                    }
                }
            });
        }
        Ok(Self { child, output })
    }

    fn tail(&self) -> String {
        self.output
            .lock()
            .map(|lines| {
                lines
                    .iter()
                    .rev()
                    .take(5)
                    .rev()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(" | ")
            })
            .unwrap_or_default()
    }
}

/// The longest wait for a killed autopilot's processes to be gone.
const EXIT_TIMEOUT: Duration = Duration::from_secs(5);

impl Drop for AutopilotProcess {
    /// Kills the autopilot's process group and waits until none of it runs: an autopilot still
    /// dying holds its ports, and the next mission's instance (the same ports) would be refused
    /// them, or its link would connect to the dying one and be reset (a listening socket
    /// completes a connection before its process is gone): 3 of 80 missions of an ArduPilot
    /// evaluation never flew, each after such a reset.
    fn drop(&mut self) {
        let group_id = self.child.id();
        let _ = Command::new("kill")
            .args(["-9", "--", &format!("-{group_id}")])
            .status();
        let _ = self.child.wait();
        let start = std::time::Instant::now();
        while group_runs(group_id) && start.elapsed() < EXIT_TIMEOUT {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

/// Whether a process of group `group_id` still runs (a zombie holds no port), from `/proc`.
fn group_runs(group_id: u32) -> bool {
    let Ok(processes) = std::fs::read_dir("/proc") else {
        return false;
    };
    let group_id = group_id.to_string();
    processes.flatten().any(|process| {
        let stat = std::fs::read_to_string(process.path().join("stat")).unwrap_or_default();
        // After the command's name in parentheses: the state, the parent, the group.
        let fields: Vec<&str> = stat
            .rsplit_once(')')
            .map_or(Vec::new(), |(_, rest)| rest.split_whitespace().collect());
        matches!(fields[..], [state, _, group, ..] if state != "Z" && group == group_id)
    })
}

/// A real autopilot flying the world's rigid body.
pub enum RealVehicle {
    Px4(Box<Px4Vehicle>),
    ArduPilot(Box<ArduPilotVehicle>),
}

impl RealVehicle {
    /// Listens where the autopilot's simulator interface connects, starts it if told how, and
    /// waits for it.
    pub fn connect(
        autopilot: &RealAutopilot,
        seed: u64,
    ) -> Result<(Self, Option<AutopilotProcess>), SimError> {
        let sensors = Sensors::new(SensorParams::default(), Home::default(), seed);
        let body = Quadrotor::on_ground(QuadrotorParams::default(), nalgebra::Vector3::zeros())
            .map_err(super::setup)?;
        match autopilot.kind {
            AutopilotKind::Px4 => {
                let listener = Px4Hil::listen(autopilot.instance).map_err(link_error)?;
                let process = spawn(autopilot)?;
                let hil = Px4Hil::accept(&listener, autopilot.instance, autopilot.connect_timeout)
                    .map_err(|error| failed_start(error, process.as_ref()))?;
                Ok((
                    Self::Px4(Box::new(Px4Vehicle::new(hil, body, sensors))),
                    process,
                ))
            }
            AutopilotKind::ArduPilot => {
                let json = ArduPilotJson::bind(autopilot.instance).map_err(link_error)?;
                let process = spawn(autopilot)?;
                let mut vehicle = ArduPilotVehicle::new(json, body, sensors);
                // ArduPilot's first servo packet is its connection: it may take a while.
                vehicle.step_timeout = autopilot.connect_timeout;
                Ok((Self::ArduPilot(Box::new(vehicle)), process))
            }
            AutopilotKind::Builtin => Err(SimError::Setup(
                "the built-in autopilot is not a real one".into(),
            )),
        }
    }

    /// Steps the world with the autopilot in lockstep until `time_s`.
    pub fn step_until(&mut self, world: &mut World, time_s: f64) -> Result<(), SimError> {
        // Half a step of slack: the last step due before `time_s` is taken, none after.
        match self {
            Self::Px4(px4) => {
                while px4.time_s < time_s - 0.5 * Px4Vehicle::STEP_S {
                    px4.step(world).map_err(link_error)?;
                }
            }
            Self::ArduPilot(ardupilot) => {
                while ardupilot.time_s < time_s - 1e-9 {
                    ardupilot.step(world).map_err(link_error)?;
                    ardupilot.step_timeout = STEP_TIMEOUT;
                }
            }
        }
        Ok(())
    }

    pub fn body(&self) -> &Quadrotor {
        match self {
            Self::Px4(px4) => &px4.body,
            Self::ArduPilot(ardupilot) => &ardupilot.body,
        }
    }

    pub fn camera_pose(&self) -> VehiclePose {
        self.body().pose()
    }
}

fn spawn(autopilot: &RealAutopilot) -> Result<Option<AutopilotProcess>, SimError> {
    autopilot
        .command
        .as_deref()
        .map(|command| AutopilotProcess::spawn(command, autopilot.instance))
        .transpose()
}

/// An autopilot that did not connect: with what its command printed, if qosrt started it.
fn failed_start(
    error: impl std::error::Error + Send + Sync + 'static,
    process: Option<&AutopilotProcess>,
) -> SimError {
    match process {
        Some(process) => SimError::Link(
            format!(
                "{error}; the autopilot's command printed: {}",
                process.tail()
            )
            .into(),
        ),
        None => link_error(error),
    }
}

/// A real autopilot's vehicle in the world, and its camera's gimbal where the mission has one:
/// the mission harness and the served world fly it alike.
pub(crate) struct GimballedVehicle {
    pub(crate) vehicle: RealVehicle,
    gimbal: Option<CameraGimbal>,
}

impl GimballedVehicle {
    pub(crate) fn new(vehicle: RealVehicle, gimbal: Option<CameraGimbal>) -> Self {
        Self { vehicle, gimbal }
    }

    /// Steps the world with the autopilot until `until_s`, then the gimbal over that tick of
    /// `tick_s` on the body's new attitude.
    pub(crate) fn step_until(
        &mut self,
        world: &mut World,
        until_s: f64,
        tick_s: f64,
    ) -> Result<(), SimError> {
        self.vehicle.step_until(world, until_s)?;
        if let Some(gimbal) = &mut self.gimbal {
            gimbal
                .step(tick_s, until_s, &self.vehicle.body().state().euler())
                .map_err(link_error)?;
        }
        Ok(())
    }

    /// Where the camera is: the gimbal's pose where it hangs in one, else the body's.
    pub(crate) fn camera_pose(&self) -> VehiclePose {
        let body = self.vehicle.camera_pose();
        self.gimbal
            .as_ref()
            .map_or(body, |gimbal| gimbal.camera_pose(&body))
    }
}

/// The camera's stabilising gimbal on a vehicle a real autopilot flies: the world moves it
/// with the body, and it reports itself on the vehicle's MAVLink network as a gimbal device.
pub(crate) struct CameraGimbal {
    gimbal: Gimbal,
    device: GimbalDevice,
    autopilot: AutopilotKind,
}

/// ArduPilot's system id (`SYSID_THISMAV` 1).
const ARDUPILOT_SYSTEM_ID: u8 = 1;

impl CameraGimbal {
    /// PX4's companion link is UDP: the gimbal device reports there itself. ArduPilot's is
    /// TCP to ArduPilot: the gimbal is wired to ArduPilot's SERIAL2 (TCP 5763+10i), whose
    /// MAVLink routing forwards the reports to the companion.
    pub(crate) fn for_autopilot(
        gimbal: Gimbal,
        autopilot: &RealAutopilot,
    ) -> Result<Self, SimError> {
        let device = match autopilot.kind {
            AutopilotKind::Px4 | AutopilotKind::Builtin => {
                let companion = std::net::SocketAddr::from((
                    [127, 0, 0, 1],
                    14540 + u16::from(autopilot.instance),
                ));
                // PX4 instance i is MAVLink system i + 1.
                GimbalDevice::new(companion, autopilot.instance + 1).map_err(link_error)?
            }
            AutopilotKind::ArduPilot => {
                let serial2 = std::net::SocketAddr::from((
                    [127, 0, 0, 1],
                    5763 + 10 * u16::from(autopilot.instance),
                ));
                GimbalDevice::through_autopilot(serial2, ARDUPILOT_SYSTEM_ID)
            }
        };
        Ok(Self {
            gimbal,
            device,
            autopilot: autopilot.kind,
        })
    }

    /// Moves the gimbal by `dt_s` on the body's attitude and reports it at `time_s`.
    fn step(&mut self, dt_s: f64, time_s: f64, body: &Attitude) -> std::io::Result<()> {
        self.gimbal.step(dt_s, body);
        // On the autopilot's clock, as its own messages are stamped: PX4's HIL time, or
        // ArduPilot's, which is the JSON answers' timestamp, the world's time.
        let time_boot_ms = match self.autopilot {
            AutopilotKind::ArduPilot => (time_s * 1000.0) as u32,
            AutopilotKind::Px4 | AutopilotKind::Builtin => {
                (crate::hil::px4::time_usec(time_s) / 1000) as u32
            }
        };
        self.device
            .report(time_s, time_boot_ms, &self.gimbal.camera_attitude(body))
    }

    fn camera_pose(&self, body: &VehiclePose) -> VehiclePose {
        self.gimbal.camera_pose(body)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An autopilot's command that leaves a listening server in the background, as ArduPilot's
    /// start script does: once dropped, nothing of its group runs and its port is free again.
    #[test]
    fn a_dropped_autopilot_is_gone_with_its_background_server() {
        if Command::new("python3").arg("--version").output().is_err() {
            eprintln!("skipped: no python3 to serve a port in the background");
            return;
        }
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        drop(listener);
        let command = format!(
            "python3 -c 'import socket,time; s=socket.socket(); \
             s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1); \
             s.bind((\"127.0.0.1\", {port})); s.listen(); print(\"listening\", flush=True); \
             time.sleep(60)' &"
        );
        let process = AutopilotProcess::spawn(&command, 0).unwrap();
        let start = std::time::Instant::now();
        while !process.tail().contains("listening") {
            assert!(
                start.elapsed() < Duration::from_secs(10),
                "{}",
                process.tail()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        let group_id = process.child.id();
        assert!(group_runs(group_id));
        assert!(std::net::TcpStream::connect(("127.0.0.1", port)).is_ok());
        drop(process);
        assert!(!group_runs(group_id));
        let refused = std::net::TcpStream::connect(("127.0.0.1", port));
        assert!(
            refused.is_err(),
            "a connection to the dropped autopilot's port"
        );
    }
}
