//! The vehicle's recent attitude, height and position, to look up at a camera frame's capture
//! time.
//!
//! A fix is projected with the attitude the vehicle had when the frame was exposed, not the
//! one it has when the detector gets round to the frame: a frame reaches the tracker 30–130 ms
//! after capture (the camera pipeline, the detector's period), and a vehicle pitching at
//! 0.5 rad/s turns 3° in 100 ms, 0.4 m on the ground from 7.5 m. The history holds what
//! telemetry said, stamped at its arrival, and interpolates between samples (yaw across ±π).

use std::collections::VecDeque;

use nalgebra::Vector3;

use super::projection::Attitude;

/// One telemetry sample.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct AttitudeSample {
    pub time_s: f64,
    pub attitude: Attitude,
    pub height_above_pad_m: f64,
    /// Local NED position, when the autopilot reports one.
    pub position_ned_m: Option<Vector3<f64>>,
    pub velocity_ned_m_s: Vector3<f64>,
    /// The camera gimbal's attitude, when the vehicle reports one
    /// ([`super::camera_mount::CameraMount::Gimbal`]).
    pub gimbal_attitude: Option<Attitude>,
}

/// A bounded window of samples in time order.
#[derive(Debug, Clone)]
pub struct AttitudeHistory {
    samples: VecDeque<AttitudeSample>,
    window_s: f64,
}

impl AttitudeHistory {
    /// Keeps `window_s` of samples (older ones are dropped as new ones come).
    pub fn new(window_s: f64) -> Self {
        Self {
            samples: VecDeque::new(),
            window_s: window_s.max(0.0),
        }
    }

    /// Adds a sample; one not newer than the last is ignored (the same message seen again).
    pub fn push(&mut self, sample: AttitudeSample) {
        if self
            .samples
            .back()
            .is_some_and(|last| sample.time_s <= last.time_s)
        {
            return;
        }
        self.samples.push_back(sample);
        while self
            .samples
            .front()
            .is_some_and(|first| sample.time_s - first.time_s > self.window_s)
        {
            self.samples.pop_front();
        }
    }

    /// The attitude and height at `time_s`: interpolated between the samples around it, the
    /// nearest end's outside them; `None` while empty.
    pub fn at(&self, time_s: f64) -> Option<AttitudeSample> {
        let first = self.samples.front()?;
        let last = self.samples.back()?;
        if time_s <= first.time_s {
            return Some(*first);
        }
        if time_s >= last.time_s {
            return Some(*last);
        }
        let after = self.samples.iter().position(|s| s.time_s > time_s)?;
        let (a, b) = (&self.samples[after - 1], &self.samples[after]);
        let t = (time_s - a.time_s) / (b.time_s - a.time_s);
        let lerp = |x: f64, y: f64| x + (y - x) * t;
        let nearest = |p: Option<Attitude>, q: Option<Attitude>| if t < 0.5 { p } else { q };
        Some(AttitudeSample {
            time_s,
            attitude: lerp_attitude(&a.attitude, &b.attitude, t),
            gimbal_attitude: match (a.gimbal_attitude, b.gimbal_attitude) {
                (Some(p), Some(q)) => Some(lerp_attitude(&p, &q, t)),
                (p, q) => nearest(p, q),
            },
            height_above_pad_m: lerp(a.height_above_pad_m, b.height_above_pad_m),
            velocity_ned_m_s: a.velocity_ned_m_s + (b.velocity_ned_m_s - a.velocity_ned_m_s) * t,
            position_ned_m: match (a.position_ned_m, b.position_ned_m) {
                (Some(p), Some(q)) => Some(p + (q - p) * t),
                (p, q) => {
                    if t < 0.5 {
                        p
                    } else {
                        q
                    }
                }
            },
        })
    }
}

/// Between two attitudes, a fraction `t` of the way (yaw the short way across ±π).
fn lerp_attitude(a: &Attitude, b: &Attitude, t: f64) -> Attitude {
    let lerp = |x: f64, y: f64| x + (y - x) * t;
    let yaw_step = wrap_pi(b.yaw_rad - a.yaw_rad);
    Attitude::new(
        lerp(a.roll_rad, b.roll_rad),
        lerp(a.pitch_rad, b.pitch_rad),
        wrap_pi(a.yaw_rad + yaw_step * t),
    )
}

fn wrap_pi(angle_rad: f64) -> f64 {
    let wrapped = (angle_rad + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU);
    wrapped - std::f64::consts::PI
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(time_s: f64, pitch_rad: f64, yaw_rad: f64, height_m: f64) -> AttitudeSample {
        AttitudeSample {
            time_s,
            attitude: Attitude::new(0.0, pitch_rad, yaw_rad),
            height_above_pad_m: height_m,
            position_ned_m: Some(Vector3::new(time_s, -2.0 * time_s, -height_m)),
            velocity_ned_m_s: Vector3::new(1.0, 2.0 * time_s, 0.0),
            // A gimbal holding the camera at a tenth of the pitch, on the heading.
            gimbal_attitude: Some(Attitude::new(0.1 * pitch_rad, 0.0, yaw_rad)),
        }
    }

    #[test]
    fn between_samples_it_interpolates_and_outside_it_holds_the_ends() {
        let mut history = AttitudeHistory::new(1.0);
        assert!(history.at(0.0).is_none());
        history.push(sample(10.0, 0.0, 3.1, 7.0));
        history.push(sample(10.02, 0.1, -3.1, 8.0));
        // A repeat of the last message changes nothing.
        history.push(sample(10.02, 0.5, 0.0, 1.0));
        let middle = history.at(10.005).unwrap();
        assert!((middle.attitude.pitch_rad - 0.025).abs() < 1e-12);
        assert!((middle.height_above_pad_m - 7.25).abs() < 1e-12);
        // Position too: a quarter of the way from the one sample's to the next's.
        let position = middle.position_ned_m.unwrap();
        assert!(
            (position - Vector3::new(10.005, -20.01, -7.25)).norm() < 1e-9,
            "{position}"
        );
        let velocity = middle.velocity_ned_m_s;
        assert!(
            (velocity - Vector3::new(1.0, 20.01, 0.0)).norm() < 1e-9,
            "{velocity}"
        );
        // Yaw goes the short way across ±π: 3.1 → −3.1 passes π, not 0.
        let yaw = middle.attitude.yaw_rad;
        let expected = 3.1 + 0.25 * (2.0 * std::f64::consts::PI - 6.2);
        assert!((yaw - expected).abs() < 1e-9, "{yaw}");
        // The gimbal's attitude the same way.
        let gimbal = middle.gimbal_attitude.unwrap();
        assert!((gimbal.roll_rad - 0.0025).abs() < 1e-12, "{gimbal:?}");
        assert!((gimbal.yaw_rad - expected).abs() < 1e-9, "{gimbal:?}");
        assert_eq!(history.at(9.0).unwrap().attitude.pitch_rad, 0.0);
        assert_eq!(history.at(11.0).unwrap().attitude.pitch_rad, 0.1);
    }

    /// A gimbal that begins or stops reporting between two samples: the nearest sample's word.
    #[test]
    fn a_gimbal_attitude_on_one_side_only_is_the_nearer_sides() {
        let mut history = AttitudeHistory::new(1.0);
        history.push(AttitudeSample {
            gimbal_attitude: None,
            ..sample(0.0, 0.0, 0.0, 5.0)
        });
        history.push(sample(0.02, 0.2, 0.0, 5.0));
        assert_eq!(history.at(0.005).unwrap().gimbal_attitude, None);
        let later = history.at(0.015).unwrap().gimbal_attitude.unwrap();
        assert!((later.roll_rad - 0.02).abs() < 1e-12, "{later:?}");
    }

    #[test]
    fn old_samples_leave_the_window() {
        let mut history = AttitudeHistory::new(0.5);
        for k in 0..100 {
            history.push(sample(k as f64 * 0.02, k as f64, 0.0, 5.0));
        }
        // 1.98 s is the newest; nothing before 1.48 s is kept.
        assert_eq!(history.at(0.0).unwrap().time_s, 1.48);
    }
}
