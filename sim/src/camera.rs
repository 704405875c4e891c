//! The simulated downward camera: renders the [`SimScene`] from the vehicle's pose at a fixed
//! frame rate, with lens distortion, sensor noise, motion blur from the vehicle's motion during
//! the exposure, and a slow drift of brightness and contrast (cloud shadows, auto-exposure).
//!
//! Mounting: the camera sits at the vehicle's position and looks along the body's down axis, the
//! image top towards the body's front — exactly [`CameraPose::downward`] with the vehicle's PX4
//! attitude. The runtime's projection
//! ([`algorithms::estimation::projection::pad_relative_to_uav_ned_m`]) assumes the same mounting,
//! so a pixel it projects lands where the renderer drew it (see the round-trip test below).
//!
//! Faults for tests: [`SimCamera::freeze`] (the camera keeps delivering its last frame) and
//! [`SimCamera::drop_frames`] (no frame: [`CameraError::Dropped`], and a gap in the frame index).

use std::f64::consts::PI;
use std::sync::{Arc, Condvar, Mutex, PoisonError};

use algorithms::camera::{self, CameraPose, PinholeCamera, RadialTangential};
use algorithms::estimation::projection::Attitude;
use algorithms::vision::image::GrayImage;
use algorithms::vision::render::{
    render_rows, ImageEffects, MotionBlur, RenderError, Scene, SplitMix64,
};
use nalgebra::Vector3;
use rayon::prelude::*;
use thiserror::Error;

use crate::scene::{SceneError, SimScene};

mod develop;
use develop::post_process;

/// A camera configuration that cannot work.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CameraConfigError {
    #[error("the image must be 16 to 8192 pixels a side, got {width_px}×{height_px}")]
    ImageSize { width_px: usize, height_px: usize },
    #[error("horizontal_fov_deg must be within (0, 170), got {0}")]
    FieldOfView(f64),
    #[error("rate_fps must be within (0, 1000], got {0}")]
    Rate(f64),
    #[error("exposure_ms must be within [0, frame period {period_ms} ms], got {exposure_ms}")]
    Exposure { exposure_ms: f64, period_ms: f64 },
    #[error("`{name}` must be finite and within [0, {max}], got {value}")]
    Range {
        name: &'static str,
        value: f64,
        max: f64,
    },
    #[error("supersampling must be 1 to 4 samples per pixel side, got {0}")]
    Supersampling(usize),
    #[error("the lens distortion coefficients must be finite")]
    Distortion,
}

/// Why a capture gave no image.
#[derive(Debug, Error)]
pub enum CameraError {
    #[error(transparent)]
    Config(#[from] CameraConfigError),
    #[error(
        "the vehicle state at t = {time_s} s is not finite (position, attitude, velocity or rates)"
    )]
    VehicleState { time_s: f64 },
    #[error("the frame at t = {time_s} s was dropped (injected fault)")]
    Dropped { time_s: f64 },
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Render(#[from] RenderError),
}

/// One frame as the camera hands it out: its number (frames it dropped leave gaps) and the
/// image, shared so that a frozen camera repeats it without a copy.
#[derive(Debug, Clone)]
pub struct SimFrame {
    pub frame_index: u64,
    pub image: Arc<GrayImage>,
}

/// How the simulated camera is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimCameraConfig {
    pub width_px: usize,
    pub height_px: usize,
    pub horizontal_fov_deg: f64,
    pub rate_fps: f64,
    pub distortion: RadialTangential,
    /// Standard deviation of the sensor noise, grey levels (0–255).
    pub noise_sigma: f64,
    /// Blur from the vehicle's velocity and body rates during the exposure.
    pub motion_blur: bool,
    pub exposure_ms: f64,
    /// Amplitude of the slow brightness drift, intensity units ([0, 1] is black to white).
    pub brightness_amplitude: f64,
    /// Amplitude of the slow contrast drift, as a fraction of contrast 1.
    pub contrast_amplitude: f64,
    /// The drift's main period, seconds (cloud shadows pass in tens of seconds).
    pub drift_period_s: f64,
    /// Samples per pixel side: 1 is fast; 2 anti-aliases patch edges at 4× the patch cost.
    pub supersampling: usize,
    /// Threads a frame is rendered on, in bands of rows (the image is the same on any number);
    /// 0: one per core.
    pub render_threads: usize,
}

impl Default for SimCameraConfig {
    fn default() -> Self {
        Self {
            width_px: 640,
            height_px: 480,
            horizontal_fov_deg: 60.0,
            rate_fps: 10.0,
            distortion: RadialTangential::NONE,
            noise_sigma: 2.0,
            motion_blur: true,
            exposure_ms: 5.0,
            brightness_amplitude: 0.05,
            contrast_amplitude: 0.1,
            drift_period_s: 40.0,
            supersampling: 1,
            render_threads: 0,
        }
    }
}

impl SimCameraConfig {
    /// Checks every setting and builds the camera model it describes.
    pub fn validate(&self) -> Result<PinholeCamera, CameraConfigError> {
        let side = 16..=8192;
        if !(side.contains(&self.width_px) && side.contains(&self.height_px)) {
            return Err(CameraConfigError::ImageSize {
                width_px: self.width_px,
                height_px: self.height_px,
            });
        }
        if !(self.horizontal_fov_deg > 0.0 && self.horizontal_fov_deg < 170.0) {
            return Err(CameraConfigError::FieldOfView(self.horizontal_fov_deg));
        }
        if !(self.rate_fps > 0.0 && self.rate_fps <= 1000.0) {
            return Err(CameraConfigError::Rate(self.rate_fps));
        }
        let period_ms = 1000.0 / self.rate_fps;
        if !(self.exposure_ms >= 0.0 && self.exposure_ms <= period_ms) {
            return Err(CameraConfigError::Exposure {
                exposure_ms: self.exposure_ms,
                period_ms,
            });
        }
        for (name, value, max) in [
            ("noise_sigma", self.noise_sigma, 128.0),
            ("brightness_amplitude", self.brightness_amplitude, 0.5),
            ("contrast_amplitude", self.contrast_amplitude, 0.9),
            ("drift_period_s", self.drift_period_s, 1e6),
        ] {
            if !(value.is_finite() && (0.0..=max).contains(&value)) {
                return Err(CameraConfigError::Range { name, value, max });
            }
        }
        if self.drift_period_s <= 0.0 {
            return Err(CameraConfigError::Range {
                name: "drift_period_s",
                value: self.drift_period_s,
                max: 1e6,
            });
        }
        if !(1..=4).contains(&self.supersampling) {
            return Err(CameraConfigError::Supersampling(self.supersampling));
        }
        let model = PinholeCamera::from_fov(
            self.width_px,
            self.height_px,
            self.horizontal_fov_deg.to_radians(),
        )
        .map_err(|error| match error {
            camera::CameraError::FieldOfView { .. } => {
                CameraConfigError::FieldOfView(self.horizontal_fov_deg)
            }
            _ => CameraConfigError::ImageSize {
                width_px: self.width_px,
                height_px: self.height_px,
            },
        })?;
        let d = self.distortion;
        if ![d.k1, d.k2, d.p1, d.p2, d.k3].iter().all(|c| c.is_finite()) {
            return Err(CameraConfigError::Distortion);
        }
        Ok(model.with_distortion(d))
    }
}

/// The vehicle's state at the moment of a capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehiclePose {
    pub position_ned_m: Vector3<f64>,
    pub attitude: Attitude,
    pub velocity_ned_m_s: Vector3<f64>,
    /// Body (FRD) angular rates p, q, r.
    pub body_rates_rad_s: Vector3<f64>,
}

/// A time window [from, until) in seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Window {
    from_s: f64,
    until_s: f64,
}

impl Window {
    fn contains(&self, time_s: f64) -> bool {
        time_s >= self.from_s && time_s < self.until_s
    }
}

/// The downward camera.
#[derive(Debug, Clone)]
pub struct SimCamera {
    config: SimCameraConfig,
    model: PinholeCamera,
    seed: u64,
    /// Phases and period ratios of the brightness and contrast drift.
    drift: [(f64, f64); 4],
    /// The frame slot (⌊t · rate⌋) of the last capture.
    last_slot: Option<i64>,
    next_frame_index: u64,
    /// The last frame rendered (or being rendered), which a frozen camera repeats.
    last_frame: Option<Arc<FrameSlot>>,
    frozen: Vec<Window>,
    dropped: Vec<Window>,
    /// Bands a frame is rendered in, resolved once (asking for the cores reads cgroup files).
    render_threads: usize,
}

impl SimCamera {
    pub fn new(config: SimCameraConfig, seed: u64) -> Result<Self, CameraError> {
        let model = config.validate()?;
        let mut rng = SplitMix64::new(seed ^ 0x6361_6d65_7261);
        let mut drift = [(0.0, 0.0); 4];
        for slot in &mut drift {
            // Incommensurate periods between 0.6 and 1.6 of the main one: no visible repetition.
            *slot = (2.0 * PI * rng.next_f64(), 0.6 + rng.next_f64());
        }
        Ok(Self {
            config,
            model,
            seed,
            drift,
            last_slot: None,
            next_frame_index: 0,
            last_frame: None,
            frozen: Vec::new(),
            dropped: Vec::new(),
            render_threads: match config.render_threads {
                0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
                n => n,
            }
            .clamp(1, config.height_px.max(1)),
        })
    }

    pub fn config(&self) -> &SimCameraConfig {
        &self.config
    }

    /// The camera model, as the runtime's projection should be configured.
    pub fn model(&self) -> &PinholeCamera {
        &self.model
    }

    /// Whether a frame is due at `time_s`: once per frame period (slots of 1 / rate_fps seconds),
    /// the first at once.
    pub fn is_due(&self, time_s: f64) -> bool {
        match (self.slot(time_s), self.last_slot) {
            (Some(slot), Some(last)) => slot > last,
            (Some(_), None) => true,
            (None, _) => false,
        }
    }

    fn slot(&self, time_s: f64) -> Option<i64> {
        // A small tolerance so t = k / rate lands in slot k despite rounding.
        time_s
            .is_finite()
            .then(|| (time_s * self.config.rate_fps + 1e-9).floor() as i64)
    }

    /// From `from_s` until `until_s` the camera delivers its last frame again (a frozen driver).
    pub fn freeze(&mut self, from_s: f64, until_s: f64) {
        self.frozen.push(Window { from_s, until_s });
    }

    /// From `from_s` until `until_s` every capture fails with [`CameraError::Dropped`].
    pub fn drop_frames(&mut self, from_s: f64, until_s: f64) {
        self.dropped.push(Window { from_s, until_s });
    }

    /// The camera's pose for a vehicle pose: at the vehicle, looking along the body's down axis.
    pub fn pose(position_ned_m: &Vector3<f64>, attitude: &Attitude) -> CameraPose {
        CameraPose::downward(
            *position_ned_m,
            attitude.roll_rad,
            attitude.pitch_rad,
            attitude.yaw_rad,
        )
    }

    /// Takes a picture at `time_s`. Every call consumes a frame index, dropped ones included, so a
    /// consumer sees drops as gaps.
    pub fn capture(
        &mut self,
        time_s: f64,
        vehicle_position_ned_m: &Vector3<f64>,
        vehicle_attitude: &Attitude,
        vehicle_velocity_ned_m_s: &Vector3<f64>,
        body_rates_rad_s: &Vector3<f64>,
        scene: &SimScene,
    ) -> Result<GrayImage, CameraError> {
        self.capture_shared(
            time_s,
            &VehiclePose {
                position_ned_m: *vehicle_position_ned_m,
                attitude: *vehicle_attitude,
                velocity_ned_m_s: *vehicle_velocity_ned_m_s,
                body_rates_rad_s: *body_rates_rad_s,
            },
            scene,
        )
        .map(|frame| Arc::unwrap_or_clone(frame.image))
    }

    /// As [`Self::capture`], numbered and shared: what the camera hands out, as a real one does.
    pub fn capture_frame(
        &mut self,
        time_s: f64,
        vehicle: &VehiclePose,
        scene: &SimScene,
    ) -> Result<SimFrame, CameraError> {
        self.capture_shared(time_s, vehicle, scene)
    }

    /// As [`Self::capture_frame`], rendered on other threads while the caller goes on: what
    /// the camera saw is fixed now, the image is ready when [`PendingFrame::wait`] returns. A
    /// simulation renders a frame during its capture-to-delivery latency this way.
    pub fn capture_deferred(
        &mut self,
        time_s: f64,
        vehicle: &VehiclePose,
        scene: &SimScene,
    ) -> Result<PendingFrame, CameraError> {
        let (frame_index, frame) = self.begin(time_s, vehicle, scene)?;
        let slot = match frame {
            Begun::Repeat(slot) => slot,
            Begun::Render(job) => {
                let slot = Arc::new(FrameSlot::default());
                let filled = Arc::clone(&slot);
                rayon::spawn(move || filled.fill(job.run()));
                self.last_frame = Some(Arc::clone(&slot));
                slot
            }
        };
        Ok(PendingFrame { frame_index, slot })
    }

    fn capture_shared(
        &mut self,
        time_s: f64,
        vehicle: &VehiclePose,
        scene: &SimScene,
    ) -> Result<SimFrame, CameraError> {
        let (frame_index, frame) = self.begin(time_s, vehicle, scene)?;
        let image = match frame {
            Begun::Repeat(slot) => slot.wait()?,
            Begun::Render(job) => {
                let slot = Arc::new(FrameSlot::default());
                slot.fill(job.run());
                self.last_frame = Some(Arc::clone(&slot));
                slot.wait()?
            }
        };
        Ok(SimFrame { frame_index, image })
    }

    /// A capture up to the rendering: the checks, the frame's number, the injected faults,
    /// and what the camera sees with which effects.
    fn begin(
        &mut self,
        time_s: f64,
        vehicle: &VehiclePose,
        scene: &SimScene,
    ) -> Result<(u64, Begun), CameraError> {
        let a = &vehicle.attitude;
        let finite = time_s.is_finite()
            && vehicle.position_ned_m.iter().all(|x| x.is_finite())
            && vehicle.velocity_ned_m_s.iter().all(|x| x.is_finite())
            && vehicle.body_rates_rad_s.iter().all(|x| x.is_finite())
            && [a.roll_rad, a.pitch_rad, a.yaw_rad]
                .iter()
                .all(|x| x.is_finite());
        if !finite {
            return Err(CameraError::VehicleState { time_s });
        }
        self.last_slot = self.slot(time_s);
        let frame_index = self.next_frame_index;
        self.next_frame_index += 1;
        if self.dropped.iter().any(|w| w.contains(time_s)) {
            return Err(CameraError::Dropped { time_s });
        }
        if self.frozen.iter().any(|w| w.contains(time_s)) {
            if let Some(slot) = &self.last_frame {
                return Ok((frame_index, Begun::Repeat(Arc::clone(slot))));
            }
        }
        let pose = Self::pose(&vehicle.position_ned_m, a);
        let visible = scene.visible_scene(&self.model, &pose)?;
        let effects = self.effects(time_s, frame_index, vehicle, &pose);
        Ok((
            frame_index,
            Begun::Render(Box::new(RenderJob {
                model: self.model,
                pose,
                visible,
                effects,
                supersampling: self.config.supersampling,
                threads: self.render_threads,
            })),
        ))
    }

    /// Brightness, contrast, noise and motion blur for one frame.
    fn effects(
        &self,
        time_s: f64,
        frame_index: u64,
        vehicle: &VehiclePose,
        pose: &CameraPose,
    ) -> ImageEffects {
        let c = &self.config;
        let wave = |(phase, ratio): (f64, f64)| {
            (2.0 * PI * time_s / (c.drift_period_s * ratio) + phase).sin()
        };
        let brightness =
            c.brightness_amplitude * (0.6 * wave(self.drift[0]) + 0.4 * wave(self.drift[1]));
        let contrast =
            1.0 + c.contrast_amplitude * (0.6 * wave(self.drift[2]) + 0.4 * wave(self.drift[3]));
        let motion_blur = if c.motion_blur && c.exposure_ms > 0.0 {
            self.motion_blur(vehicle, pose)
        } else {
            None
        };
        ImageEffects {
            gaussian_blur_sigma_px: 0.0,
            motion_blur,
            contrast,
            brightness,
            noise_sigma: c.noise_sigma,
            // A fresh noise pattern every frame, reproducible per seed.
            noise_seed: self.seed ^ frame_index.wrapping_mul(0x9e37_79b9_7f4a_7c15),
        }
    }

    /// The image motion of the ground at the image centre during the exposure: for a camera
    /// rotating at ω and moving at v (camera frame), a point on the axis at depth Z moves in
    /// normalised coordinates at (−ω_y − v_x / Z, ω_x − v_y / Z).
    fn motion_blur(&self, vehicle: &VehiclePose, pose: &CameraPose) -> Option<MotionBlur> {
        let to_camera = pose.camera_to_world.rotation.inverse();
        // Body rates → world → camera (the camera is fixed to the body).
        let a = &vehicle.attitude;
        let body_rotation =
            nalgebra::Rotation3::from_euler_angles(a.roll_rad, a.pitch_rad, a.yaw_rad);
        let omega_camera = to_camera * (body_rotation * vehicle.body_rates_rad_s);
        let velocity_camera = to_camera * vehicle.velocity_ned_m_s;
        let axis_down = (pose.camera_to_world.rotation * Vector3::z()).z;
        let height_m = -pose.position_ned_m().z;
        // Looking at or above the horizon, or from below ground: only rotation blurs.
        let inverse_depth = if axis_down > 1e-3 && height_m > 1e-3 {
            axis_down / height_m
        } else {
            0.0
        };
        let vx = -omega_camera.y - velocity_camera.x * inverse_depth;
        let vy = omega_camera.x - velocity_camera.y * inverse_depth;
        let exposure_s = self.config.exposure_ms / 1000.0;
        let (dx_px, dy_px) = (
            vx * exposure_s * self.model.fx_px,
            vy * exposure_s * self.model.fy_px,
        );
        let length_px = dx_px.hypot(dy_px);
        // Under a quarter pixel the blur is invisible and costs a pass over the image.
        (length_px >= 0.25).then(|| MotionBlur {
            length_px,
            angle_rad: dy_px.atan2(dx_px),
        })
    }
}

/// A frame being rendered: its number now, its image when [`Self::wait`] returns.
#[derive(Debug)]
pub struct PendingFrame {
    pub frame_index: u64,
    slot: Arc<FrameSlot>,
}

impl PendingFrame {
    /// The frame, once rendered (at once if it already is).
    pub fn wait(self) -> Result<SimFrame, CameraError> {
        Ok(SimFrame {
            frame_index: self.frame_index,
            image: self.slot.wait()?,
        })
    }
}

/// Where a frame's image arrives from the thread that renders it.
#[derive(Debug, Default)]
struct FrameSlot {
    image: Mutex<Option<Result<Arc<GrayImage>, RenderError>>>,
    ready: Condvar,
}

impl FrameSlot {
    fn fill(&self, result: Result<GrayImage, RenderError>) {
        let mut image = self.image.lock().unwrap_or_else(PoisonError::into_inner);
        *image = Some(result.map(Arc::new));
        self.ready.notify_all();
    }

    fn wait(&self) -> Result<Arc<GrayImage>, RenderError> {
        let mut image = self.image.lock().unwrap_or_else(PoisonError::into_inner);
        loop {
            if let Some(result) = image.as_ref() {
                return result.clone();
            }
            image = self
                .ready
                .wait(image)
                .unwrap_or_else(PoisonError::into_inner);
        }
    }
}

/// A capture after its checks: the last frame again (a frozen camera), or one to render.
enum Begun {
    Repeat(Arc<FrameSlot>),
    Render(Box<RenderJob>),
}

/// Everything a frame's rendering needs, owned, so another thread can do it.
struct RenderJob {
    model: PinholeCamera,
    pose: CameraPose,
    visible: Scene,
    effects: ImageEffects,
    supersampling: usize,
    threads: usize,
}

impl RenderJob {
    /// The frame: its bands of rows rendered on their own threads, then the camera's effects
    /// applied to them on their own threads (the blur reads rows of the neighbouring bands, so
    /// all are rendered first).
    fn run(&self) -> Result<GrayImage, RenderError> {
        let (width, height) = (self.model.width_px, self.model.height_px);
        let mut clean = vec![0f32; width * height];
        in_bands(&mut clean, width, self.threads, |first_row, out| {
            render_rows(
                &self.model,
                &self.pose,
                &self.visible,
                self.supersampling,
                first_row,
                out,
            )
        })?;
        post_process(&clean, width, height, &self.effects, self.threads)
    }
}

/// Bands of rows [`in_bands`] cuts per rendering thread.
const BANDS_PER_THREAD: usize = 6;

/// Fills `out` (rows of `width`) band by band, the bands on the process's thread pool:
/// `fill(first_row, band)`.
fn in_bands<T: Send, E: Send>(
    out: &mut [T],
    width: usize,
    threads: usize,
    fill: impl Fn(usize, &mut [T]) -> Result<(), E> + Sync,
) -> Result<(), E> {
    let rows = out.len() / width.max(1);
    // More bands than threads: a thread that finishes early (the other core busy with the
    // hazard CNN or the mission loop) takes the next band instead of idling.
    let rows_per_band = rows.div_ceil(BANDS_PER_THREAD * threads.max(1)).max(1);
    if threads <= 1 {
        return fill(0, out);
    }
    out.par_chunks_mut(rows_per_band * width)
        .enumerate()
        .try_for_each(|(band, rows)| fill(band * rows_per_band, rows))
}

#[cfg(test)]
mod tests;
