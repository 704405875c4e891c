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

/// The camera's effects on a rendered frame (intensities 0 to 1), in the renderer's order
/// (motion blur, contrast and brightness, noise) and with its formulas, but written for speed:
/// the blur adds whole shifted rows, and the noise is read from a table of Gaussian samples
/// (see [`develop_rows`]) instead of drawn per pixel, each row from a generator of its own so
/// bands of rows go to threads and give the same frame. Gaussian blur is not used by the camera
/// and is refused.
fn post_process(
    clean: &[f32],
    width: usize,
    height: usize,
    effects: &ImageEffects,
    threads: usize,
) -> Result<GrayImage, RenderError> {
    if effects.gaussian_blur_sigma_px != 0.0 {
        return Err(RenderError::Effect {
            name: "gaussian_blur_sigma_px",
            value: effects.gaussian_blur_sigma_px,
        });
    }
    let taps = match effects.motion_blur {
        Some(blur) if blur.length_px > 0.0 && blur.length_px.is_finite() => blur_kernel(blur),
        _ => Vec::new(),
    };
    let mut data = vec![0u8; width * height];
    in_bands(&mut data, width, threads, |first_row, out| {
        // The same arithmetic on every CPU, in wider vectors where the CPU has them.
        pulp::Arch::new().dispatch(DevelopRows {
            clean,
            width,
            height,
            taps: &taps,
            effects,
            first_row,
            out,
        });
        Ok::<(), RenderError>(())
    })?;
    Ok(GrayImage::from_vec(width, height, data)?)
}

/// One tap of a motion blur's kernel: the image shifted by whole pixels (dx, dy), weighted.
#[derive(Debug, Clone, Copy, PartialEq)]
struct BlurTap {
    dx: isize,
    dy: isize,
    weight: f32,
}

/// The blur's kernel: the mean over a centred segment of the motion, sampled about every half
/// pixel, each sample bilinear between four whole-pixel taps; samples share taps, so the
/// taps are merged (a 4 px blur has about 15 taps, not 36).
fn blur_kernel(blur: MotionBlur) -> Vec<BlurTap> {
    let steps = (2.0 * blur.length_px).ceil().max(1.0) as usize + 1;
    let (sin, cos) = blur.angle_rad.sin_cos();
    let weight_per_step = 1.0 / steps as f32;
    let mut taps: Vec<BlurTap> = Vec::new();
    for k in 0..steps {
        let s = (k as f64 / (steps - 1) as f64 - 0.5) * blur.length_px;
        let (x, y) = (s * cos, s * sin);
        let (ix, iy) = (x.floor() as isize, y.floor() as isize);
        let (fx, fy) = ((x - ix as f64) as f32, (y - iy as f64) as f32);
        for (dx, dy, weight) in [
            (ix, iy, (1.0 - fx) * (1.0 - fy)),
            (ix + 1, iy, fx * (1.0 - fy)),
            (ix, iy + 1, (1.0 - fx) * fy),
            (ix + 1, iy + 1, fx * fy),
        ] {
            let weight = weight * weight_per_step;
            if weight == 0.0 {
                continue;
            }
            match taps.iter_mut().find(|t| t.dx == dx && t.dy == dy) {
                Some(tap) => tap.weight += weight,
                None => taps.push(BlurTap { dx, dy, weight }),
            }
        }
    }
    taps
}

/// [`develop_rows`]' arguments, for [`pulp`] to compile it for each instruction set.
struct DevelopRows<'a> {
    clean: &'a [f32],
    width: usize,
    height: usize,
    taps: &'a [BlurTap],
    effects: &'a ImageEffects,
    first_row: usize,
    out: &'a mut [u8],
}

impl pulp::WithSimd for DevelopRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        develop_rows(
            self.clean,
            self.width,
            self.height,
            self.taps,
            self.effects,
            self.first_row,
            self.out,
        );
    }
}

/// The developed rows from `first_row` into `out`.
#[inline(always)]
fn develop_rows(
    clean: &[f32],
    width: usize,
    height: usize,
    taps: &[BlurTap],
    effects: &ImageEffects,
    first_row: usize,
    out: &mut [u8],
) {
    let contrast = effects.contrast as f32 * 255.0;
    let offset = (0.5 - 0.5 * effects.contrast as f32 + effects.brightness as f32) * 255.0;
    let noise_sigma = effects.noise_sigma as f32 / std::f32::consts::SQRT_2;
    let table = noise_table();
    let mut line = vec![0f32; width];
    let zeros = vec![0f32; width];
    for (chunk_row, out_row) in out.chunks_exact_mut(width).enumerate() {
        let y = first_row + chunk_row;
        if taps.is_empty() {
            line.copy_from_slice(&clean[y * width..(y + 1) * width]);
        } else {
            blur_row(clean, width, height, taps, y, &mut line);
        }
        // Each row's noise is the sum of two windows of the table at offsets drawn for this
        // frame and row: the same pattern again needs both offsets to coincide.
        let mut rng = SplitMix64::new(
            effects.noise_seed ^ (y as u64 + 1).wrapping_mul(0xd1b5_4a32_d192_ed03),
        );
        let windows = table.len().saturating_sub(width).max(1) as u64;
        let (a, b) = (
            (rng.next_u64() % windows) as usize,
            (rng.next_u64() % windows) as usize,
        );
        let (noise_a, noise_b) = if noise_sigma > 0.0 && table.len() >= width {
            (&table[a..a + width], &table[b..b + width])
        } else {
            (&zeros[..], &zeros[..])
        };
        for (((pixel, &level), &na), &nb) in out_row.iter_mut().zip(&line).zip(noise_a).zip(noise_b)
        {
            let level = contrast * level + offset + noise_sigma * (na + nb);
            *pixel = (level.clamp(0.0, 255.0) + 0.5) as u8;
        }
    }
}

/// 64 Ki samples of unit Gaussian noise, drawn once: the camera's sensor noise is read from it.
fn noise_table() -> &'static [f32] {
    static TABLE: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rng = SplitMix64::new(0x006e_6f69_7365);
        (0..1 << 16).map(|_| rng.next_gaussian() as f32).collect()
    })
}

/// Row `y` of the motion-blurred image: each tap adds a shifted source row, edges clamped.
#[inline(always)]
fn blur_row(
    source: &[f32],
    width: usize,
    height: usize,
    taps: &[BlurTap],
    y: usize,
    line: &mut [f32],
) {
    line.fill(0.0);
    let last = width as isize - 1;
    for tap in taps {
        let row = (y as isize + tap.dy).clamp(0, height as isize - 1) as usize;
        let source_row = &source[row * width..(row + 1) * width];
        let dx = tap.dx;
        // Output columns whose source column x + dx lies on the image.
        let lo = (-dx).clamp(0, width as isize) as usize;
        let hi = (width as isize - dx).clamp(lo as isize, width as isize) as usize;
        if hi > lo {
            let start = (lo as isize + dx) as usize;
            for (o, &v) in line[lo..hi]
                .iter_mut()
                .zip(&source_row[start..start + (hi - lo)])
            {
                *o += tap.weight * v;
            }
        }
        // The few columns at the edges, clamped.
        for x in (0..lo).chain(hi..width) {
            line[x] += tap.weight * source_row[(x as isize + dx).clamp(0, last) as usize];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{HazardField, PadPose, ScatterConfig, TractorBody};
    use algorithms::estimation::projection::pad_relative_to_uav_ned_m;
    use algorithms::vision::landing_marker::{LandingMarkerConfig, LandingMarkerDetector};
    use algorithms::vision::render::Texture;
    use algorithms::vision::render::{render, RenderOptions};

    fn still() -> Vector3<f64> {
        Vector3::zeros()
    }

    fn small_config() -> SimCameraConfig {
        SimCameraConfig {
            width_px: 160,
            height_px: 120,
            ..Default::default()
        }
    }

    fn field_with_pad() -> SimScene {
        SimScene::new(11)
            .with_tractor_body(TractorBody::default())
            .unwrap()
            .with_pad(PadPose {
                north_m: 1.2,
                east_m: -0.7,
                height_m: 1.5,
                yaw_rad: 0.5,
            })
            .unwrap()
    }

    /// Bands of rows on several threads give the very image one thread gives (an odd
    /// number of bands, so they are not all the same height).
    #[test]
    fn threaded_rendering_gives_the_same_frame() {
        let scene = field_with_pad();
        let vehicle = VehiclePose {
            position_ned_m: Vector3::new(0.5, -0.2, -6.0),
            attitude: Attitude {
                roll_rad: 0.05,
                pitch_rad: -0.1,
                yaw_rad: 0.3,
            },
            velocity_ned_m_s: Vector3::new(1.0, 0.0, 0.0),
            body_rates_rad_s: Vector3::zeros(),
        };
        let frame = |threads: usize| {
            let config = SimCameraConfig {
                render_threads: threads,
                ..small_config()
            };
            let mut camera = SimCamera::new(config, 3).unwrap();
            camera.capture_frame(0.0, &vehicle, &scene).unwrap().image
        };
        let one = frame(1);
        assert_eq!(*frame(3), *one);
        assert_eq!(*frame(0), *one);
        // The pad is in the picture: the comparison is of a frame with content.
        let (min, max) = one
            .data()
            .iter()
            .fold((u8::MAX, 0), |(lo, hi), &p| (lo.min(p), hi.max(p)));
        assert!(max - min > 100, "a flat frame: {min}..{max}");
    }

    #[test]
    fn the_detector_and_the_projection_recover_the_true_relative_position() {
        let scene = field_with_pad();
        let mut camera = SimCamera::new(SimCameraConfig::default(), 3).unwrap();
        let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
        let pad = scene.pad_pose().unwrap();
        for (position, attitude) in [
            (
                Vector3::new(0.3, 0.1, -9.0),
                Attitude::new(0.08, -0.06, 1.0),
            ),
            (
                Vector3::new(2.0, -1.5, -6.5),
                Attitude::new(-0.1, 0.12, -2.3),
            ),
        ] {
            let image = camera
                .capture(0.0, &position, &attitude, &still(), &still(), &scene)
                .unwrap();
            camera.last_slot = None;
            let observation = detector
                .detect(&image.view(), None)
                .unwrap()
                .expect("the pad is in view");
            let [u, v] = observation.centre_px;
            let height_above_pad_m = -pad.height_m - position.z;
            let relative =
                pad_relative_to_uav_ned_m(camera.model(), &attitude, height_above_pad_m, u, v)
                    .unwrap();
            let truth = Vector3::new(
                pad.north_m - position.x,
                pad.east_m - position.y,
                height_above_pad_m,
            );
            assert!(
                (relative - truth).norm() < 0.03,
                "recovered {relative:?}, truth {truth:?}"
            );
        }
    }

    #[test]
    fn frames_are_due_once_per_period() {
        let scene = SimScene::new(1);
        let mut camera = SimCamera::new(small_config(), 1).unwrap();
        let at = Vector3::new(0.0, 0.0, -5.0);
        let level = Attitude::default();
        assert!(camera.is_due(0.0));
        camera
            .capture(0.0, &at, &level, &still(), &still(), &scene)
            .unwrap();
        assert!(!camera.is_due(0.0));
        assert!(!camera.is_due(0.099));
        assert!(camera.is_due(0.1));
        camera
            .capture(0.1, &at, &level, &still(), &still(), &scene)
            .unwrap();
        assert!(!camera.is_due(0.1999));
        assert!(camera.is_due(0.2));
        assert!(camera.is_due(0.35));
        assert!(!camera.is_due(f64::NAN));
    }

    #[test]
    fn a_frozen_camera_repeats_its_last_frame_and_dropped_frames_leave_gaps() {
        let scene = field_with_pad();
        let mut camera = SimCamera::new(small_config(), 2).unwrap();
        camera.freeze(1.0, 1.3);
        camera.drop_frames(2.0, 2.2);
        let vehicle = |north_m: f64| VehiclePose {
            position_ned_m: Vector3::new(north_m, 0.0, -8.0),
            attitude: Attitude::default(),
            velocity_ned_m_s: Vector3::new(1.0, 0.0, 0.0),
            body_rates_rad_s: still(),
        };
        let before = camera.capture_frame(0.9, &vehicle(0.9), &scene).unwrap();
        for t in [1.0, 1.1, 1.2] {
            let frozen = camera.capture_frame(t, &vehicle(t), &scene).unwrap();
            assert_eq!(frozen.image, before.image, "t = {t}");
        }
        let live = camera.capture_frame(1.3, &vehicle(1.3), &scene).unwrap();
        assert_ne!(live.image, before.image);
        assert_eq!(live.frame_index, 4);
        for t in [2.0, 2.1] {
            assert!(matches!(
                camera.capture_frame(t, &vehicle(t), &scene),
                Err(CameraError::Dropped { .. })
            ));
        }
        let after = camera.capture_frame(2.2, &vehicle(2.2), &scene).unwrap();
        assert_eq!(after.frame_index, 7, "the dropped frames are a gap");
    }

    #[test]
    fn bad_configs_and_states_are_named_errors() {
        let bad = |change: fn(&mut SimCameraConfig)| {
            let mut config = SimCameraConfig::default();
            change(&mut config);
            SimCamera::new(config, 0).unwrap_err()
        };
        assert!(matches!(
            bad(|c| c.width_px = 0),
            CameraError::Config(CameraConfigError::ImageSize { .. })
        ));
        assert!(matches!(
            bad(|c| c.horizontal_fov_deg = 0.0),
            CameraError::Config(CameraConfigError::FieldOfView(_))
        ));
        assert!(matches!(
            bad(|c| c.rate_fps = f64::NAN),
            CameraError::Config(CameraConfigError::Rate(_))
        ));
        assert!(matches!(
            bad(|c| c.exposure_ms = 150.0),
            CameraError::Config(CameraConfigError::Exposure { .. })
        ));
        assert!(matches!(
            bad(|c| c.noise_sigma = -1.0),
            CameraError::Config(CameraConfigError::Range {
                name: "noise_sigma",
                ..
            })
        ));
        assert!(matches!(
            bad(|c| c.drift_period_s = 0.0),
            CameraError::Config(CameraConfigError::Range {
                name: "drift_period_s",
                ..
            })
        ));
        assert!(matches!(
            bad(|c| c.supersampling = 0),
            CameraError::Config(CameraConfigError::Supersampling(0))
        ));
        assert!(matches!(
            bad(|c| c.distortion.k1 = f64::INFINITY),
            CameraError::Config(CameraConfigError::Distortion)
        ));
        let mut camera = SimCamera::new(small_config(), 0).unwrap();
        assert!(matches!(
            camera.capture(
                0.0,
                &Vector3::new(0.0, f64::NAN, -5.0),
                &Attitude::default(),
                &still(),
                &still(),
                &SimScene::new(0)
            ),
            Err(CameraError::VehicleState { .. })
        ));
    }

    #[test]
    fn noise_has_the_configured_spread_and_the_drift_changes_brightness() {
        let flat = SimScene::new(0).with_field_texture(Texture::uniform(0.5));
        let config = SimCameraConfig {
            noise_sigma: 6.0,
            brightness_amplitude: 0.0,
            contrast_amplitude: 0.0,
            ..Default::default()
        };
        let mut camera = SimCamera::new(config, 4).unwrap();
        let at = Vector3::new(0.0, 0.0, -5.0);
        let image = camera
            .capture(0.0, &at, &Attitude::default(), &still(), &still(), &flat)
            .unwrap();
        let levels: Vec<f64> = image.data().iter().map(|&p| p as f64).collect();
        let n = levels.len() as f64;
        let mean = levels.iter().sum::<f64>() / n;
        let sd = (levels.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!((mean - 127.5).abs() < 1.0, "{mean}");
        assert!((sd - 6.0).abs() < 0.3, "{sd}");

        // With a drift, the mean wanders over tens of seconds.
        let drifting = SimCameraConfig {
            noise_sigma: 0.0,
            brightness_amplitude: 0.2,
            ..Default::default()
        };
        let mut camera = SimCamera::new(drifting, 4).unwrap();
        let means: Vec<f64> = (0..20)
            .map(|k| {
                let image = camera
                    .capture(
                        k as f64 * 5.0,
                        &at,
                        &Attitude::default(),
                        &still(),
                        &still(),
                        &flat,
                    )
                    .unwrap();
                image.data().iter().map(|&p| p as f64).sum::<f64>() / n
            })
            .collect();
        let spread = means.iter().cloned().fold(f64::MIN, f64::max)
            - means.iter().cloned().fold(f64::MAX, f64::min);
        assert!(spread > 20.0, "{means:?}");
    }

    #[test]
    fn motion_blur_follows_the_velocity_and_the_body_rates() {
        let config = SimCameraConfig {
            exposure_ms: 10.0,
            ..Default::default()
        };
        let camera = SimCamera::new(config, 0).unwrap();
        let fx = camera.model().fx_px;
        let position = Vector3::new(0.0, 0.0, -10.0);
        let pose = SimCamera::pose(&position, &Attitude::default());
        let moving_north = VehiclePose {
            position_ned_m: position,
            attitude: Attitude::default(),
            velocity_ned_m_s: Vector3::new(5.0, 0.0, 0.0),
            body_rates_rad_s: still(),
        };
        // 5 m/s at 10 m for 10 ms: 5 mm of ground, along the image's vertical (north is up).
        let blur = camera.motion_blur(&moving_north, &pose).unwrap();
        assert!((blur.length_px - 0.005 * fx).abs() < 1e-6, "{blur:?}");
        assert!(blur.angle_rad.sin().abs() > 0.999);
        let pitching = VehiclePose {
            velocity_ned_m_s: still(),
            body_rates_rad_s: Vector3::new(0.0, 0.5, 0.0),
            ..moving_north
        };
        let blur = camera.motion_blur(&pitching, &pose).unwrap();
        assert!((blur.length_px - 0.005 * fx).abs() < 1e-6, "{blur:?}");
        assert!(blur.angle_rad.sin().abs() > 0.999);
        // Rolling blurs sideways.
        let rolling = VehiclePose {
            body_rates_rad_s: Vector3::new(0.5, 0.0, 0.0),
            ..pitching
        };
        let blur = camera.motion_blur(&rolling, &pose).unwrap();
        assert!(blur.angle_rad.cos().abs() > 0.999, "{blur:?}");
        let hovering = VehiclePose {
            body_rates_rad_s: still(),
            ..pitching
        };
        assert!(camera.motion_blur(&hovering, &pose).is_none());
    }

    #[test]
    fn the_fast_effects_match_the_renderers() {
        // A textured frame; the renderer's own effects are the reference.
        let data: Vec<u8> = (0..80 * 60)
            .map(|i| ((i % 80) * 3 + (i / 80) * 2 % 255) as u8)
            .collect();
        let image = GrayImage::from_vec(80, 60, data).unwrap();
        for (length_px, angle_rad) in [(0.7, 0.55), (3.3, -2.0), (6.0, 1.571)] {
            let effects = ImageEffects {
                motion_blur: Some(MotionBlur {
                    length_px,
                    angle_rad,
                }),
                contrast: 1.2,
                brightness: -0.05,
                ..Default::default()
            };
            let clean: Vec<f32> = image.data().iter().map(|&p| p as f32 / 255.0).collect();
            let fast = post_process(&clean, 80, 60, &effects, 1).unwrap();
            // In bands on threads, noise included: the same frame.
            let noisy = ImageEffects {
                noise_sigma: 3.0,
                noise_seed: 7,
                ..effects
            };
            assert_eq!(
                post_process(&clean, 80, 60, &noisy, 3).unwrap(),
                post_process(&clean, 80, 60, &noisy, 1).unwrap()
            );
            let reference = algorithms::vision::render::apply_effects(&image, &effects).unwrap();
            let worst = fast
                .data()
                .iter()
                .zip(reference.data())
                .map(|(&a, &b)| (a as i32 - b as i32).abs())
                .max()
                .unwrap();
            assert!(worst <= 1, "blur {length_px} px: {worst} grey levels apart");
        }
    }

    /// Prints the cost of one 640×480 capture of a busy field (run with `--ignored`).
    #[test]
    #[ignore]
    fn capture_time_640x480() {
        let hazards = HazardField::scatter(
            5,
            &ScatterConfig {
                north_m: [-20.0, 20.0],
                east_m: [-20.0, 20.0],
                count_per_class: [10, 6, 3],
                ..Default::default()
            },
        )
        .unwrap();
        let scene = field_with_pad().with_hazards(hazards);
        let mut camera = SimCamera::new(SimCameraConfig::default(), 1).unwrap();
        let vehicle = VehiclePose {
            position_ned_m: Vector3::new(0.0, 0.0, -9.0),
            attitude: Attitude::new(0.05, -0.04, 0.3),
            velocity_ned_m_s: Vector3::new(2.0, 0.5, 0.3),
            body_rates_rad_s: Vector3::new(0.2, -0.1, 0.05),
        };
        let frames = 30;
        // The fastest of many captures: this VM's timings are noisy.
        let mut best_ms = f64::INFINITY;
        for k in 0..frames * 3 {
            let started = std::time::Instant::now();
            camera
                .capture_frame(k as f64 * 0.1, &vehicle, &scene)
                .unwrap();
            best_ms = best_ms.min(started.elapsed().as_secs_f64() * 1000.0);
        }
        println!(
            "one 640×480 capture, fastest of {}: {best_ms:.2} ms",
            frames * 3
        );
        let mut single = SimCamera::new(
            SimCameraConfig {
                render_threads: 1,
                ..SimCameraConfig::default()
            },
            1,
        )
        .unwrap();
        let mut best_ms = f64::INFINITY;
        for k in 0..frames * 3 {
            let started = std::time::Instant::now();
            single
                .capture_frame(k as f64 * 0.1, &vehicle, &scene)
                .unwrap();
            best_ms = best_ms.min(started.elapsed().as_secs_f64() * 1000.0);
        }
        println!("on one thread: {best_ms:.2} ms");
        // Where the time goes: the ray casting alone, then each effect on its own.
        let pose = SimCamera::pose(&vehicle.position_ned_m, &vehicle.attitude);
        let visible = scene.visible_scene(camera.model(), &pose).unwrap();
        let effects = camera.effects(0.0, 0, &vehicle, &pose);
        for (what, effects) in [
            ("ray casting only", ImageEffects::default()),
            (
                "+ noise",
                ImageEffects {
                    noise_sigma: effects.noise_sigma,
                    ..Default::default()
                },
            ),
            (
                "+ motion blur",
                ImageEffects {
                    motion_blur: effects.motion_blur,
                    ..Default::default()
                },
            ),
            ("uniform background", ImageEffects::default()),
        ] {
            let options = RenderOptions {
                supersampling: 1,
                effects,
            };
            let mut visible = visible.clone();
            if what == "uniform background" {
                visible.background = Texture::uniform(0.4);
            }
            let started = std::time::Instant::now();
            for _ in 0..frames {
                render(camera.model(), &pose, &visible, &options).unwrap();
            }
            let ms = started.elapsed().as_secs_f64() * 1000.0 / frames as f64;
            println!("{what}: {ms:.2} ms ({} patches)", visible.patches.len());
        }
        let clean = render(
            camera.model(),
            &pose,
            &visible,
            &RenderOptions {
                supersampling: 1,
                effects: ImageEffects::default(),
            },
        )
        .unwrap();
        let clean: Vec<f32> = clean.data().iter().map(|&p| p as f32 / 255.0).collect();
        let (width, height) = (camera.model().width_px, camera.model().height_px);
        let started = std::time::Instant::now();
        for _ in 0..frames {
            post_process(&clean, width, height, &effects, 1).unwrap();
        }
        let ms = started.elapsed().as_secs_f64() * 1000.0 / frames as f64;
        println!("the camera's effects ({effects:?}): {ms:.2} ms");
    }
}
