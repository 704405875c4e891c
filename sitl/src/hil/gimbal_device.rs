//! The camera's gimbal as a MAVLink gimbal device beside a real autopilot: it reports where
//! the camera points (GIMBAL_DEVICE_ATTITUDE_STATUS, component MAV_COMP_ID_GIMBAL of the
//! vehicle's system), as a gimbal on the vehicle's MAVLink network does. Beside PX4 it sends
//! to the companion computer's UDP link itself; beside ArduPilot it is wired to one of
//! ArduPilot's MAVLink ports (SERIAL2, as a Gremsy or SIYI gimbal on a flight controller's
//! UART), and ArduPilot's MAVLink routing forwards its reports to the companion on SERIAL0.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::time::Duration;

use algorithms::estimation::projection::Attitude;
use mavlink::{MavHeader, MavlinkVersion};
use runtime::link::GIMBAL_COMPONENT_ID;
use sim::autopilot::gimbal_device_attitude_status;

/// How often the gimbal reports (a Gremsy or SIYI gimbal streams at 50 Hz or faster).
pub const REPORT_PERIOD_S: f64 = 0.02;
/// How long (world time) the gimbal waits before trying an autopilot's port again: the
/// autopilot may not listen yet while the world starts.
const RECONNECT_PERIOD_S: f64 = 1.0;

/// Where the reports go.
enum Wire {
    /// Straight to the companion computer's UDP link.
    Companion {
        socket: UdpSocket,
        companion: SocketAddr,
    },
    /// Into an autopilot's MAVLink TCP port, which routes them on.
    Autopilot {
        port: SocketAddr,
        stream: Option<TcpStream>,
        next_connect_s: f64,
    },
}

pub struct GimbalDevice {
    wire: Wire,
    system_id: u8,
    sequence: u8,
    next_report_s: f64,
}

impl GimbalDevice {
    /// A gimbal of system `system_id` reporting to the companion's link at `companion`.
    pub fn new(companion: SocketAddr, system_id: u8) -> std::io::Result<Self> {
        Ok(Self::on(
            Wire::Companion {
                socket: UdpSocket::bind("127.0.0.1:0")?,
                companion,
            },
            system_id,
        ))
    }

    /// A gimbal of system `system_id` wired to the autopilot's MAVLink TCP server at `port`;
    /// it connects on its first report and again whenever the connection is lost.
    pub fn through_autopilot(port: SocketAddr, system_id: u8) -> Self {
        Self::on(
            Wire::Autopilot {
                port,
                stream: None,
                next_connect_s: 0.0,
            },
            system_id,
        )
    }

    fn on(wire: Wire, system_id: u8) -> Self {
        Self {
            wire,
            system_id,
            sequence: 0,
            next_report_s: 0.0,
        }
    }

    /// Reports the camera's attitude when a report is due at `time_s`; `time_boot_ms` is the
    /// vehicle's clock.
    pub fn report(
        &mut self,
        time_s: f64,
        time_boot_ms: u32,
        camera: &Attitude,
    ) -> std::io::Result<()> {
        if time_s + 1e-9 < self.next_report_s {
            return Ok(());
        }
        self.next_report_s = time_s + REPORT_PERIOD_S;
        let header = MavHeader {
            system_id: u32::from(self.system_id),
            component_id: GIMBAL_COMPONENT_ID,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let mut bytes = Vec::with_capacity(64);
        mavlink::write_versioned_msg(
            &mut bytes,
            MavlinkVersion::V2,
            header,
            &gimbal_device_attitude_status(camera, time_boot_ms),
        )
        .map_err(|error| std::io::Error::other(error.to_string()))?;
        match &mut self.wire {
            Wire::Companion { socket, companion } => match socket.send_to(&bytes, *companion) {
                // Nobody listening yet: UDP drops it.
                Err(error) if error.kind() == ErrorKind::ConnectionRefused => Ok(()),
                other => other.map(|_| ()),
            },
            Wire::Autopilot {
                port,
                stream,
                next_connect_s,
            } => {
                if stream.is_none() && time_s >= *next_connect_s {
                    *next_connect_s = time_s + RECONNECT_PERIOD_S;
                    *stream = connect(*port);
                }
                let Some(connected) = stream else {
                    return Ok(());
                };
                if send_and_drain(connected, &bytes).is_err() {
                    // The autopilot went away: drop the report, connect again later.
                    *stream = None;
                }
                Ok(())
            }
        }
    }
}

/// A non-blocking connection to the autopilot's port, or none while it does not listen.
fn connect(port: SocketAddr) -> Option<TcpStream> {
    let stream = TcpStream::connect_timeout(&port, Duration::from_millis(100)).ok()?;
    stream.set_nodelay(true).ok()?;
    stream.set_nonblocking(true).ok()?;
    Some(stream)
}

/// Writes one report (dropped when the autopilot's buffer is full, as a UART drops bytes)
/// and discards what the autopilot sent: the gimbal listens to nothing, and an unread socket
/// would fill.
fn send_and_drain(stream: &mut TcpStream, bytes: &[u8]) -> std::io::Result<()> {
    match stream.write(bytes) {
        Ok(_) => {}
        Err(error) if error.kind() == ErrorKind::WouldBlock => {}
        Err(error) => return Err(error),
    }
    let mut buffer = [0u8; 4096];
    loop {
        match stream.read(&mut buffer) {
            Ok(0) => return Err(ErrorKind::ConnectionReset.into()),
            Ok(_) => continue,
            Err(error) if error.kind() == ErrorKind::WouldBlock => return Ok(()),
            Err(error) => return Err(error),
        }
    }
}
