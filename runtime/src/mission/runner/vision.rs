//! The vision side of the loop: camera frames in (published at their capture, recorded, with
//! the vehicle's pose at capture), the capture-to-setpoint latency of each fix, and the
//! tracker's fix out as LANDING_TARGET for an autopilot's own precision landing.

use super::{MissionRunner, ARRIVALS_KEPT, SETPOINT_MAX_AGE_S};
use crate::camera::CameraSourceError;
use crate::clock::Timestamp;
use crate::link::VehicleCommand;
use crate::scheduler::TaskScheduler;

impl<S: TaskScheduler> MissionRunner<S> {
    /// Every frame the camera has ready, published at its capture time.
    pub(super) fn take_frames(&mut self, now_s: f64) {
        let Some(camera) = self.camera.as_mut() else {
            return;
        };
        let mut faults = Vec::new();
        loop {
            match camera.next_frame(now_s) {
                Ok(Some(captured)) => {
                    self.log.frames += 1;
                    if let Some(recorder) = &self.recorder {
                        recorder.frame(
                            now_s,
                            captured.capture_time_s,
                            captured.frame.frame_index,
                            captured.frame.image.clone(),
                        );
                    }
                    let capture_s = captured.capture_time_s.min(now_s);
                    let index = captured.frame.frame_index;
                    let mut frame = captured.frame;
                    frame.vehicle_at_capture = self.vehicle_history.at(capture_s);
                    let stamp = Timestamp::from_secs_f64(capture_s.max(0.0));
                    if self.arrivals.len() == ARRIVALS_KEPT {
                        self.arrivals.pop_front();
                    }
                    self.arrivals
                        .push_back((stamp.as_secs_f64(), captured.arrived_s.min(now_s)));
                    let (_, replaced_read) = self.frames.publish_noting_read(stamp, frame);
                    let replaced = self.frame_on_topic.replace(index);
                    if let (Some(recorder), Some(replaced), Some(read)) =
                        (&self.recorder, replaced, replaced_read)
                    {
                        recorder.frame_read(replaced, read);
                    }
                }
                Ok(None) => break,
                Err(error @ CameraSourceError::Ended { .. }) => {
                    faults.push(format!("camera: {error}"));
                    self.ended_camera_stats = Some(camera.stats());
                    self.camera = None;
                    break;
                }
                Err(error) => {
                    self.log.camera_errors += 1;
                    tracing::warn!(%error, "camera frame lost");
                    faults.push(format!("camera: {error}"));
                    break;
                }
            }
        }
        for fault in faults {
            self.note(now_s, fault);
        }
    }

    /// The first velocity setpoint sent after a new vision fix: capture-to-setpoint latency.
    pub(super) fn note_vision_latency(&mut self, now_s: f64, commands: &[VehicleCommand]) {
        let steered = commands
            .iter()
            .any(|c| matches!(c, VehicleCommand::VelocityNed { .. }));
        let fix_s = self.relative.peek().and_then(|m| m.value.last_fix_time_s);
        if let (true, Some(fix_s)) = (steered, fix_s) {
            if self.last_timed_fix_s != Some(fix_s) && now_s >= fix_s {
                self.last_timed_fix_s = Some(fix_s);
                self.log
                    .capture_to_setpoint
                    .record(((now_s - fix_s) * 1e9) as u64);
                // The fix is stamped with its frame's capture: the frame it came from.
                let arrived_s = self
                    .arrivals
                    .iter()
                    .find(|(capture_s, _)| (capture_s - fix_s).abs() < 1e-6)
                    .map(|&(_, arrived_s)| arrived_s);
                if let Some(arrived_s) = arrived_s.filter(|&a| now_s >= a) {
                    self.log
                        .delivered_to_setpoint
                        .record(((now_s - arrived_s) * 1e9) as u64);
                }
            }
        }
    }

    /// LANDING_TARGET from the tracker's latest fix: the pad's direction in the body frame
    /// (angles off the down axis) and its distance.
    pub(super) fn landing_target(&mut self, now_s: f64) -> Option<VehicleCommand> {
        let relative = self.relative.take_new()?.value;
        let fix_s = relative.last_fix_time_s?;
        if now_s - fix_s > SETPOINT_MAX_AGE_S {
            return None;
        }
        let attitude = self.link.telemetry().vehicle_state(now_s)?.attitude;
        let pad_from_uav_ned = -relative.estimate.uav_relative_ned_m;
        let body = attitude.ned_to_body_frd(&pad_from_uav_ned);
        if body.z <= 0.0 {
            return None;
        }
        Some(VehicleCommand::LandingTarget {
            angle_x_rad: body.y.atan2(body.z),
            angle_y_rad: (-body.x).atan2(body.z),
            distance_m: body.norm(),
            size_x_rad: 0.0,
            size_y_rad: 0.0,
            // The capture in the autopilot's clock once TIMESYNC has found it, else in ours.
            time_usec: self
                .link
                .autopilot_time_us(fix_s)
                .unwrap_or((fix_s.max(0.0) * 1e6) as u64),
        })
    }
}
