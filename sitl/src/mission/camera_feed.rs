//! The world's downward camera as the runtime meets it: frames rendered from the true pose
//! only when a task will look, delivered after their capture-to-delivery latency, in order,
//! stamped with their capture time; and the stereo depth camera beside it where a task reads
//! depth.

use std::collections::VecDeque;

use algorithms::vision::render::SplitMix64;
use runtime::bus::Publisher;
use runtime::camera::{CapturedFrame, MemorySource};
use runtime::clock::Timestamp;
use runtime::config::TaskConfig;
use runtime::registry::PluginRegistry;
use runtime::scheduler::{TaskId, TaskScheduler};
use runtime::topics::{CameraFrame, DepthFrame, CAMERA_FRAME, DEPTH_FRAME};
use sim::camera::{PendingFrame, SimCamera, SimCameraConfig};
use sim::realism::CameraRealism;
use sim::scene::SimScene;
use sim::stereo_camera::{SimStereoCamera, StereoCameraConfig};
use sim::tractor::Tractor;

use super::flyer::Flyer;
use super::{pad_pose, setup, Faults, SimError};

/// A frame on its way: (delivery time, capture time on the runtime's clock, the frame being
/// rendered).
type InTransit = (f64, f64, PendingFrame);

pub(super) struct CameraFeed {
    camera: SimCamera,
    period_s: f64,
    realism: CameraRealism,
    in_transit: VecDeque<InTransit>,
    latency_rng: SplitMix64,
    /// The tasks that read camera frames (the catalogue says), by their ids in the scheduler:
    /// a frame is rendered only when one of them will look at it.
    consumers: Vec<TaskId>,
    /// On the wall clock the scheduler does not say ahead: every frame is rendered.
    every_frame: bool,
    stereo: Option<(SimStereoCamera, Publisher<DepthFrame>)>,
    /// Where the runtime takes its frames from, as from a real camera.
    frames: MemorySource,
}

impl CameraFeed {
    /// The camera `config` describes, seen through `realism`; the stereo camera flies only
    /// for a task that reads depth, so the missions without one are not slowed by it.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        config: SimCameraConfig,
        realism: CameraRealism,
        tasks: &[TaskConfig],
        registry: &PluginRegistry,
        stereo: StereoCameraConfig,
        scheduler: &dyn TaskScheduler,
        seed: u64,
        every_frame: bool,
    ) -> Result<Self, SimError> {
        let period_s = 1.0 / config.rate_fps;
        let latency_rng = SplitMix64::new(seed ^ 0x006c_6174_656e_6379);
        let camera = SimCamera::new(config, seed).map_err(setup)?;
        let consumers = tasks
            .iter()
            .filter(|t| registry.reads(t, CAMERA_FRAME.name()))
            .filter_map(|t| scheduler.task_id(&t.name))
            .collect();
        let reads_depth = tasks.iter().any(|t| registry.reads(t, DEPTH_FRAME.name()));
        let stereo = if reads_depth {
            let camera = SimStereoCamera::new(stereo, seed).map_err(setup)?;
            let depth_frames = scheduler
                .bus()
                .publisher::<DepthFrame>(DEPTH_FRAME)
                .map_err(setup)?;
            Some((camera, depth_frames))
        } else {
            None
        };
        Ok(Self {
            camera,
            period_s,
            realism,
            in_transit: VecDeque::new(),
            latency_rng,
            consumers,
            every_frame,
            stereo,
            frames: MemorySource::new(),
        })
    }

    /// The frame source the runtime reads.
    pub(super) fn source(&self) -> MemorySource {
        self.frames.clone()
    }

    /// The camera faults, timed from `start_s` (the tracking's start).
    pub(super) fn inject(&mut self, faults: &Faults, start_s: f64) {
        if let Some((from_s, until_s)) = faults.camera_freeze {
            self.camera.freeze(start_s + from_s, start_s + until_s);
        }
        if let Some((from_s, until_s)) = faults.camera_stall {
            self.camera.drop_frames(start_s + from_s, start_s + until_s);
        }
    }

    /// Captures a frame when one is due and a task will look at it before the next: rendered
    /// on other threads during its latency while the loop goes on. The depth frame of the same
    /// instant is published at once.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn capture(
        &mut self,
        time_s: f64,
        now: Timestamp,
        runtime_now_s: f64,
        scheduler: &dyn TaskScheduler,
        flyer: &Flyer,
        tractor: &Tractor,
        scene: &mut SimScene,
        events: &mut Vec<(f64, String)>,
    ) -> Result<(), SimError> {
        if !self.camera.is_due(time_s) || !self.wanted(time_s, scheduler) {
            return Ok(());
        }
        scene.set_pad_pose(pad_pose(tractor)).map_err(setup)?;
        let pose = flyer.camera_pose();
        let frame = match self.camera.capture_deferred(time_s, &pose, scene) {
            Ok(frame) => frame,
            Err(error) => {
                events.push((time_s, format!("camera: {error}")));
                return Ok(());
            }
        };
        let frame_index = frame.frame_index;
        let c = &self.realism;
        let latency_s =
            c.latency_min_s + (c.latency_max_s - c.latency_min_s) * self.latency_rng.next_f64();
        // Not before the frame ahead of it: a camera delivers in order.
        let deliver_s = self
            .in_transit
            .back()
            .map_or(time_s + latency_s, |(s, _, _)| s.max(time_s + latency_s));
        self.in_transit.push_back((deliver_s, runtime_now_s, frame));
        if let Some((stereo, depth_frames)) = self.stereo.as_mut() {
            match stereo.capture(frame_index, &pose.position_ned_m, &pose.attitude, scene) {
                Ok(depth) => {
                    depth_frames.publish(
                        now,
                        DepthFrame {
                            frame_index: depth.frame_index,
                            image: depth.image,
                        },
                    );
                }
                Err(error) => events.push((time_s, format!("stereo camera: {error}"))),
            }
        }
        Ok(())
    }

    /// Whether a task reading frames runs before the next frame (and its latency) is due.
    fn wanted(&self, time_s: f64, scheduler: &dyn TaskScheduler) -> bool {
        let horizon_s = time_s + self.period_s + self.realism.latency_max_s;
        self.every_frame
            || self.consumers.iter().any(|&id| {
                scheduler
                    .next_activation(id)
                    .is_some_and(|next| next.as_secs_f64() < horizon_s)
            })
    }

    /// Hands the runtime the frames whose delivery time has come.
    pub(super) fn deliver(
        &mut self,
        time_s: f64,
        runtime_now_s: f64,
        events: &mut Vec<(f64, String)>,
    ) {
        while self
            .in_transit
            .front()
            .is_some_and(|(deliver_s, _, _)| *deliver_s <= time_s + 1e-9)
        {
            let Some((_, capture_time_s, frame)) = self.in_transit.pop_front() else {
                break;
            };
            match frame.wait() {
                Ok(frame) => self.frames.push(CapturedFrame {
                    frame: CameraFrame {
                        vehicle_at_capture: None,
                        frame_index: frame.frame_index,
                        image: frame.image,
                    },
                    capture_time_s,
                    arrived_s: runtime_now_s,
                }),
                Err(error) => events.push((time_s, format!("camera: {error}"))),
            }
        }
    }
}
