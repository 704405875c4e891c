//! The real PX4 as the world's vehicle: its SIH simulator's true pose, read from the
//! HIL_STATE_QUATERNION messages PX4 SITL sends on its SIH display link (from UDP 19450+i to
//! 127.0.0.1:19410+i, about 24 Hz).
//!
//! Positions are local NED from the first message (the vehicle on the ground at start, where
//! EKF2 puts its origin too). Each message is placed on this host's clock by the smallest
//! arrival-minus-stamp offset seen (the least-delayed message sets the mapping), so the pose at
//! any instant interpolates between the messages around it: position, velocity and rates
//! linearly, attitude by slerp; past the newest message it extrapolates by velocity for at
//! most [`MAX_EXTRAPOLATION_S`].

use std::collections::VecDeque;
use std::io::ErrorKind;
use std::net::UdpSocket;

use algorithms::estimation::projection::Attitude;
use mavlink::dialects::common::{MavMessage, HIL_STATE_QUATERNION_DATA};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use sim::autopilot::decode_datagram;
use sim::camera::VehiclePose;

/// PX4 SITL instance i sends its SIH display link to this port + i.
pub const SIH_DISPLAY_PORT: u16 = 19410;
/// The pose is never dead-reckoned further than this past the newest message.
pub const MAX_EXTRAPOLATION_S: f64 = 0.1;
/// Messages kept for interpolation (a few seconds at 24 Hz).
const KEPT_SAMPLES: usize = 64;
/// WGS-84 equatorial radius: the local tangent plane around the origin.
const EARTH_RADIUS_M: f64 = 6_378_137.0;

#[derive(Debug, thiserror::Error)]
pub enum Px4SihError {
    #[error("PX4 SIH display link: cannot listen on UDP 127.0.0.1:{port}: {source}")]
    Bind {
        port: u16,
        #[source]
        source: std::io::Error,
    },
    #[error("PX4 SIH display link: {0}")]
    Io(#[from] std::io::Error),
}

/// One HIL_STATE_QUATERNION in local terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    /// PX4's stamp (its boot clock).
    pub stamp_s: f64,
    pub position_ned_m: Vector3<f64>,
    pub velocity_ned_m_s: Vector3<f64>,
    pub attitude: UnitQuaternion<f64>,
    pub body_rates_rad_s: Vector3<f64>,
}

/// Geodetic origin of the local frame.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Origin {
    lat_rad: f64,
    lon_rad: f64,
    alt_m: f64,
}

/// Turns HIL_STATE_QUATERNION messages into poses on the local clock.
#[derive(Debug, Default)]
pub struct PoseTrack {
    origin: Option<Origin>,
    /// Local time minus PX4's stamp, the smallest seen.
    offset_s: Option<f64>,
    samples: VecDeque<PoseSample>,
    pub messages: u64,
}

impl PoseTrack {
    /// Adds a message that arrived at `arrival_s` on the local clock.
    pub fn add(&mut self, message: &HIL_STATE_QUATERNION_DATA, arrival_s: f64) {
        let stamp_s = message.time_usec as f64 * 1e-6;
        let offset_s = self
            .offset_s
            .map_or(arrival_s - stamp_s, |o| o.min(arrival_s - stamp_s));
        self.offset_s = Some(offset_s);
        let lat_rad = (f64::from(message.lat) * 1e-7).to_radians();
        let lon_rad = (f64::from(message.lon) * 1e-7).to_radians();
        let alt_m = f64::from(message.alt) * 1e-3;
        let origin = *self.origin.get_or_insert(Origin {
            lat_rad,
            lon_rad,
            alt_m,
        });
        let position_ned_m = Vector3::new(
            (lat_rad - origin.lat_rad) * EARTH_RADIUS_M,
            (lon_rad - origin.lon_rad) * origin.lat_rad.cos() * EARTH_RADIUS_M,
            origin.alt_m - alt_m,
        );
        let [w, x, y, z] = message.attitude_quaternion.map(f64::from);
        let sample = PoseSample {
            stamp_s,
            position_ned_m,
            velocity_ned_m_s: Vector3::new(
                f64::from(message.vx),
                f64::from(message.vy),
                f64::from(message.vz),
            ) * 0.01,
            attitude: UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
            body_rates_rad_s: Vector3::new(
                f64::from(message.rollspeed),
                f64::from(message.pitchspeed),
                f64::from(message.yawspeed),
            ),
        };
        self.messages += 1;
        if let Some(last) = self.samples.back() {
            if sample.stamp_s <= last.stamp_s {
                // Out of order or a PX4 restart: start the history again.
                self.samples.clear();
            }
        }
        self.samples.push_back(sample);
        while self.samples.len() > KEPT_SAMPLES {
            self.samples.pop_front();
        }
    }

    /// The newest sample.
    pub fn latest(&self) -> Option<&PoseSample> {
        self.samples.back()
    }

    /// A sample's time on the local clock.
    pub fn local_time_s(&self, sample: &PoseSample) -> f64 {
        sample.stamp_s + self.offset_s.unwrap_or(0.0)
    }

    /// The pose at `local_time_s` on the local clock.
    pub fn pose_at(&self, local_time_s: f64) -> Option<VehiclePose> {
        let time_s = local_time_s - self.offset_s?;
        let first = self.samples.front()?;
        let last = self.samples.back()?;
        let sample = if time_s <= first.stamp_s {
            *first
        } else if time_s >= last.stamp_s {
            let ahead_s = (time_s - last.stamp_s).min(MAX_EXTRAPOLATION_S);
            PoseSample {
                position_ned_m: last.position_ned_m + last.velocity_ned_m_s * ahead_s,
                ..*last
            }
        } else {
            let after = self.samples.iter().position(|s| s.stamp_s > time_s)?;
            let (a, b) = (&self.samples[after - 1], &self.samples[after]);
            let t = (time_s - a.stamp_s) / (b.stamp_s - a.stamp_s);
            PoseSample {
                stamp_s: time_s,
                position_ned_m: a.position_ned_m.lerp(&b.position_ned_m, t),
                velocity_ned_m_s: a.velocity_ned_m_s.lerp(&b.velocity_ned_m_s, t),
                attitude: a.attitude.slerp(&b.attitude, t),
                body_rates_rad_s: a.body_rates_rad_s.lerp(&b.body_rates_rad_s, t),
            }
        };
        let (roll_rad, pitch_rad, yaw_rad) = sample.attitude.euler_angles();
        Some(VehiclePose {
            position_ned_m: sample.position_ned_m,
            attitude: Attitude::new(roll_rad, pitch_rad, yaw_rad),
            velocity_ned_m_s: sample.velocity_ned_m_s,
            body_rates_rad_s: sample.body_rates_rad_s,
        })
    }
}

/// Listens on PX4 SITL's SIH display link.
pub struct SihListener {
    socket: UdpSocket,
    buffer: Vec<u8>,
    pub track: PoseTrack,
}

impl SihListener {
    /// Listens for instance `instance` (UDP 127.0.0.1:19410+instance).
    pub fn bind(instance: u8) -> Result<Self, Px4SihError> {
        let port = SIH_DISPLAY_PORT + u16::from(instance);
        let socket = UdpSocket::bind(("127.0.0.1", port))
            .map_err(|source| Px4SihError::Bind { port, source })?;
        socket.set_nonblocking(true)?;
        Ok(Self {
            socket,
            buffer: vec![0; 65_536],
            track: PoseTrack::default(),
        })
    }

    /// Takes every message that has arrived, stamping them `now_s`.
    pub fn poll(&mut self, now_s: f64) -> Result<usize, Px4SihError> {
        let mut count = 0;
        loop {
            match self.socket.recv_from(&mut self.buffer) {
                Ok((length, _)) => {
                    for (_, message) in decode_datagram(&self.buffer[..length]) {
                        if let MavMessage::HIL_STATE_QUATERNION(state) = message {
                            self.track.add(&state, now_s);
                            count += 1;
                        }
                    }
                }
                Err(error)
                    if matches!(error.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) =>
                {
                    return Ok(count)
                }
                Err(error) => return Err(error.into()),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// PX4 SIH's default home (Zurich), 488 m AMSL.
    const LAT0_E7: i32 = 473_977_420;
    const LON0_E7: i32 = 85_455_940;

    fn message(time_s: f64, dlat_e7: i32, dlon_e7: i32, alt_mm: i32) -> HIL_STATE_QUATERNION_DATA {
        HIL_STATE_QUATERNION_DATA {
            time_usec: (time_s * 1e6) as u64,
            attitude_quaternion: [1.0, 0.0, 0.0, 0.0],
            lat: LAT0_E7 + dlat_e7,
            lon: LON0_E7 + dlon_e7,
            alt: 488_000 + alt_mm,
            vx: 100,
            ..Default::default()
        }
    }

    #[test]
    fn positions_are_metres_from_the_first_message() {
        let mut track = PoseTrack::default();
        track.add(&message(10.0, 0, 0, 0), 0.0);
        // 1e-5 degree of latitude, 2e-5 of longitude at 47.4° N, 5 m up.
        track.add(&message(10.04, 100, 200, 5_000), 0.04);
        let p = track.latest().unwrap().position_ned_m;
        let metres_per_degree = std::f64::consts::PI / 180.0 * 6_378_137.0;
        let lat0 = 47.397742_f64.to_radians();
        assert!((p.x - 1e-5 * metres_per_degree).abs() < 1e-3, "{p}");
        assert!(
            (p.y - 2e-5 * metres_per_degree * lat0.cos()).abs() < 1e-3,
            "{p}"
        );
        assert!((p.z + 5.0).abs() < 1e-9, "{p}");
        assert!((track.latest().unwrap().velocity_ned_m_s.x - 1.0).abs() < 1e-9);
    }

    #[test]
    fn the_pose_between_messages_is_interpolated_and_after_them_extrapolated() {
        let mut track = PoseTrack::default();
        // PX4's clock runs 100 s ahead; the second message arrives 30 ms late, the first not.
        track.add(&message(100.0, 0, 0, 0), 0.0);
        let mut second = message(100.1, 0, 0, 2_000);
        let yaw = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.4);
        second.attitude_quaternion = [yaw.w, yaw.i, yaw.j, yaw.k].map(|v| v as f32);
        track.add(&second, 0.13);
        // The second message sits at 0.1 s on the local clock, not at its late arrival.
        assert!((track.local_time_s(track.latest().unwrap()) - 0.1).abs() < 1e-6);
        let middle = track.pose_at(0.05).unwrap();
        assert!((middle.position_ned_m.z + 1.0).abs() < 1e-6);
        assert!((middle.attitude.yaw_rad - 0.2).abs() < 1e-6);
        // Past the newest: by its velocity (1 m/s north), for at most 0.1 s.
        let ahead = track.pose_at(0.15).unwrap();
        assert!((ahead.position_ned_m.x - 0.05).abs() < 1e-6);
        let far = track.pose_at(5.0).unwrap();
        assert!((far.position_ned_m.x - MAX_EXTRAPOLATION_S).abs() < 1e-6);
    }

    #[test]
    fn the_listener_reads_real_datagrams() {
        let mut listener = SihListener::bind(9).unwrap();
        let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
        let mut bytes = Vec::new();
        mavlink::write_versioned_msg(
            &mut bytes,
            mavlink::MavlinkVersion::V2,
            mavlink::MavHeader::default(),
            &MavMessage::HIL_STATE_QUATERNION(message(1.0, 0, 0, 0)),
        )
        .unwrap();
        sender
            .send_to(&bytes, ("127.0.0.1", SIH_DISPLAY_PORT + 9))
            .unwrap();
        sender
            .send_to(b"garbage", ("127.0.0.1", SIH_DISPLAY_PORT + 9))
            .unwrap();
        let start = std::time::Instant::now();
        while listener.track.messages == 0 && start.elapsed().as_secs() < 2 {
            listener.poll(0.0).unwrap();
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert_eq!(listener.track.messages, 1);
    }
}
