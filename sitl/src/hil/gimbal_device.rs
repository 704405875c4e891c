//! The camera's gimbal as a MAVLink gimbal device beside a real autopilot: it reports where
//! the camera points (GIMBAL_DEVICE_ATTITUDE_STATUS, component MAV_COMP_ID_GIMBAL of the
//! vehicle's system) to the companion computer's link itself, as a gimbal on the vehicle's
//! MAVLink network does.

use std::net::{SocketAddr, UdpSocket};

use algorithms::estimation::projection::Attitude;
use mavlink::{MavHeader, MavlinkVersion};
use runtime::link::GIMBAL_COMPONENT_ID;
use sim::autopilot::gimbal_device_attitude_status;

/// How often the gimbal reports (a Gremsy or SIYI gimbal streams at 50 Hz or faster).
pub const REPORT_PERIOD_S: f64 = 0.02;

pub struct GimbalDevice {
    socket: UdpSocket,
    companion: SocketAddr,
    system_id: u8,
    sequence: u8,
    next_report_s: f64,
}

impl GimbalDevice {
    /// A gimbal of system `system_id` reporting to the companion's link at `companion`.
    pub fn new(companion: SocketAddr, system_id: u8) -> std::io::Result<Self> {
        Ok(Self {
            socket: UdpSocket::bind("127.0.0.1:0")?,
            companion,
            system_id,
            sequence: 0,
            next_report_s: 0.0,
        })
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
        match self.socket.send_to(&bytes, self.companion) {
            // Nobody listening yet: UDP drops it.
            Err(error) if error.kind() == std::io::ErrorKind::ConnectionRefused => Ok(()),
            other => other.map(|_| ()),
        }
    }
}
