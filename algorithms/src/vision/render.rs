//! A renderer of planar textured patches on the ground, for tests with exact truth and for the
//! simulator's camera.
//!
//! Rendering is by inverse mapping: every (sub)pixel's ray is cast (camera.unproject), meets the
//! horizontal plane of each patch and of the ground, and the nearest hit's texture gives the
//! intensity. So the truth is exact: a world point appears where [`true_pixel`] says.
//!
//! Conventions (see also [`crate::camera`]):
//! - World NED, metres. The ground is the plane `down = Scene::ground_down_m` (0 unless given).
//! - A patch lies on the plane `down = Patch::down_m`, centred at (north_m, east_m), `width_m` along
//!   its u axis and `height_m` along its v axis. Patch coordinates (u, v) run over [−1, 1]²: u to the
//!   patch's right, v to its bottom, as an image. With yaw 0 the patch's top faces north and u points
//!   east, so a level camera with the same yaw sees the texture upright; positive yaw turns the patch
//!   clockwise seen from above (north towards east), as PX4's yaw.
//! - Textures return intensity in [0, 1]: 0 black, 1 white. The image stores intensity × 255.
//! - Patches are drawn in order: where two lie on the same plane, the later one covers the earlier.

use std::f64::consts::PI;
use std::fmt;
use std::sync::Arc;

use nalgebra::{Point3, Vector3};
use thiserror::Error;

use super::image::{DepthImage, FrameError, GrayImage};
use crate::camera::{CameraPose, PinholeCamera};

/// A scene or option that cannot be rendered as given.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RenderError {
    #[error("supersampling must be 1 to 16 samples per pixel side, got {0}")]
    Supersampling(usize),
    #[error("a buffer of {len} values is not whole rows of a {width}×{height} image from row {first_row}")]
    RowBuffer {
        width: usize,
        height: usize,
        first_row: usize,
        len: usize,
    },
    #[error("patch {index} must have a positive, finite size, got {width_m} m × {height_m} m")]
    PatchSize {
        index: usize,
        width_m: f64,
        height_m: f64,
    },
    #[error("patch {index} has a non-finite position or yaw")]
    PatchPose { index: usize },
    #[error("an n-fold marker needs order 2 or more, got {0}")]
    NfoldOrder(u32),
    #[error("an ArUco marker of {bits_per_side}×{bits_per_side} bits needs {expected} bits, got {found}")]
    ArucoBits {
        bits_per_side: usize,
        expected: usize,
        found: usize,
    },
    #[error("image effect `{name}` must be finite and not negative, got {value}")]
    Effect { name: &'static str, value: f64 },
    #[error(transparent)]
    Frame(#[from] FrameError),
}

/// Intensity in [0, 1] as a function of two coordinates: patch (u, v) for a patch's texture,
/// world (north_m, east_m) for the background.
#[derive(Clone)]
pub struct Texture {
    f: Arc<dyn Fn(f64, f64) -> f32 + Send + Sync>,
    /// The same function over many points at once, where the texture has a faster way than
    /// one call per point (a baked texture looks its tile up once per run of points).
    many: Option<ManyFn>,
}

type ManyFn = Arc<dyn Fn(&[[f64; 2]], &mut [f32]) + Send + Sync>;

impl fmt::Debug for Texture {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Texture(..)")
    }
}

impl Texture {
    /// Any function of the two coordinates; values outside [0, 1] are clamped when the image is made.
    pub fn from_fn(f: impl Fn(f64, f64) -> f32 + Send + Sync + 'static) -> Self {
        Self {
            f: Arc::new(f),
            many: None,
        }
    }

    /// As [`Self::from_fn`], with `many(points, out)` giving the same values as `one` at every
    /// point, faster.
    pub fn from_fns(
        one: impl Fn(f64, f64) -> f32 + Send + Sync + 'static,
        many: impl Fn(&[[f64; 2]], &mut [f32]) + Send + Sync + 'static,
    ) -> Self {
        Self {
            f: Arc::new(one),
            many: Some(Arc::new(many)),
        }
    }

    /// One intensity everywhere.
    pub fn uniform(intensity: f32) -> Self {
        Self::from_fn(move |_, _| intensity)
    }

    /// The intensity at (a, b).
    pub fn sample(&self, a: f64, b: f64) -> f32 {
        (self.f)(a, b)
    }

    /// The intensity at each point, into `out` (as long as `points`).
    pub fn sample_many(&self, points: &[[f64; 2]], out: &mut [f32]) {
        match &self.many {
            Some(many) => many(points, out),
            None => {
                for (&[a, b], value) in points.iter().zip(out) {
                    *value = (self.f)(a, b);
                }
            }
        }
    }

    /// The n-fold marker of order `order` on the unit disc of the patch, white outside it: a point at
    /// angle θ = atan2(v, u) (v down, as in the image) is black where sin(nθ) > 0. The oriented variant
    /// leaves the leg 0 < θ < π/n white. Drawn on a patch of yaw ψ and seen by a level camera of yaw
    /// ψ_c, the marker's orientation in the image is ψ − ψ_c (see [`crate::vision::nfold`]).
    pub fn nfold(order: u32, oriented: bool) -> Result<Self, RenderError> {
        if order < 2 {
            return Err(RenderError::NfoldOrder(order));
        }
        let leg_rad = PI / order as f64;
        Ok(Self::from_fn(move |u, v| {
            let r2 = u * u + v * v;
            if r2 > 1.0 {
                return 1.0;
            }
            // sin(nθ) > 0 ⇔ Im((u + iv)ⁿ) > 0, without an atan2 per sample.
            let (mut re, mut im) = (1.0f64, 0.0f64);
            for _ in 0..order {
                (re, im) = (re * u - im * v, re * v + im * u);
            }
            if im <= 0.0 {
                return 1.0;
            }
            if oriented && v > 0.0 && v.atan2(u) < leg_rad {
                return 1.0;
            }
            0.0
        }))
    }

    /// An ArUco marker: `bits` row-major (row 0 at the top, true = white, as OpenCV's dictionaries),
    /// `bits_per_side`² of them, inside a one-cell black border; the patch is the marker's outer
    /// square. Put a white patch under it for the quiet zone a detector needs.
    pub fn aruco(bits: &[bool], bits_per_side: usize) -> Result<Self, RenderError> {
        let expected = bits_per_side.saturating_mul(bits_per_side);
        if bits_per_side == 0 || bits.len() != expected {
            return Err(RenderError::ArucoBits {
                bits_per_side,
                expected,
                found: bits.len(),
            });
        }
        let bits: Arc<[bool]> = bits.into();
        let cells = bits_per_side + 2;
        Ok(Self::from_fn(move |u, v| {
            let cell = |c: f64| (((c + 1.0) * 0.5 * cells as f64) as usize).min(cells - 1);
            let (col, row) = (cell(u), cell(v));
            if col == 0 || row == 0 || col == cells - 1 || row == cells - 1 {
                return 0.0;
            }
            if bits[(row - 1) * bits_per_side + (col - 1)] {
                1.0
            } else {
                0.0
            }
        }))
    }

    /// A procedural agricultural field, a function of world (north_m, east_m): crop rows 0.75 m apart
    /// in a seeded direction, soil clumps from centimetres to metres, a few bright stones, and slow
    /// changes of brightness. Seeded: the same seed gives the same field.
    pub fn field(seed: u64) -> Self {
        let noise = Arc::new(ValueNoise::new(seed));
        // A different stream from the noise lattice's.
        let mut rng = SplitMix64::new(seed ^ 0x0066_6965_6c64);
        let row_heading_rad = rng.next_f64() * PI;
        let (row_n, row_e) = (row_heading_rad.cos(), row_heading_rad.sin());
        let row_spacing_m = 0.6 + 0.3 * rng.next_f64();
        let row_strength = 0.05 + 0.15 * rng.next_f64() as f32;
        let base = 0.3 + 0.3 * rng.next_f64() as f32;
        Self::from_fn(move |north_m, east_m| {
            let n = &noise;
            let slow = n.at(north_m / 7.0, east_m / 7.0, 0) - 0.5;
            let clumps = n.at(north_m / 0.35, east_m / 0.35, 1) - 0.5;
            let grain = n.at(north_m / 0.09, east_m / 0.09, 2) - 0.5;
            // Rows wander a little, as sown rows do. A smoothed triangle wave stands in for a
            // cosine at a fraction of its cost.
            let across = (north_m * -row_e + east_m * row_n + 0.08 * slow as f64) / row_spacing_m;
            let tri = (2.0 * (across - floor(across)) - 1.0).abs() as f32;
            let row = 2.0 * tri * tri * (3.0 - 2.0 * tri) - 1.0;
            let stone = n.at(north_m / 0.12 + 17.0, east_m / 0.12 - 5.0, 4);
            let mut value = base + 0.35 * slow + row_strength * row + 0.22 * clumps + 0.16 * grain;
            if stone > 0.86 {
                value += 0.35;
            }
            value
        })
    }
}

/// A textured rectangle on a horizontal plane; see the module docs for its coordinates.
#[derive(Debug, Clone)]
pub struct Patch {
    pub north_m: f64,
    pub east_m: f64,
    /// The NED down coordinate of the patch's plane (0 is the default ground; −2 is 2 m above it).
    pub down_m: f64,
    pub yaw_rad: f64,
    pub width_m: f64,
    pub height_m: f64,
    pub texture: Texture,
}

impl Patch {
    /// A patch on the plane down = 0.
    pub fn new(
        north_m: f64,
        east_m: f64,
        yaw_rad: f64,
        width_m: f64,
        height_m: f64,
        texture: Texture,
    ) -> Self {
        Self {
            north_m,
            east_m,
            down_m: 0.0,
            yaw_rad,
            width_m,
            height_m,
            texture,
        }
    }

    /// A square patch on the plane down = 0.
    pub fn square(north_m: f64, east_m: f64, yaw_rad: f64, size_m: f64, texture: Texture) -> Self {
        Self::new(north_m, east_m, yaw_rad, size_m, size_m, texture)
    }

    /// The same patch on the plane down = `down_m`.
    pub fn at_down_m(mut self, down_m: f64) -> Self {
        self.down_m = down_m;
        self
    }

    /// (north, east) unit vectors of the patch's u and v axes.
    fn axes(&self) -> ([f64; 2], [f64; 2]) {
        let (s, c) = self.yaw_rad.sin_cos();
        ([-s, c], [-c, -s])
    }

    /// The NED world point at patch coordinates (u, v): the truth for features drawn on it.
    pub fn point_world(&self, u: f64, v: f64) -> Point3<f64> {
        let (eu, ev) = self.axes();
        let (a, b) = (u * self.width_m / 2.0, v * self.height_m / 2.0);
        Point3::new(
            self.north_m + a * eu[0] + b * ev[0],
            self.east_m + a * eu[1] + b * ev[1],
            self.down_m,
        )
    }
}

/// What the camera looks at: a background texture over the ground plane and patches above it.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Intensity as a function of world (north_m, east_m) on the ground plane.
    pub background: Texture,
    pub ground_down_m: f64,
    pub patches: Vec<Patch>,
    /// Intensity of rays that meet nothing (above the horizon).
    pub sky: f32,
}

impl Scene {
    /// A scene on the ground plane down = 0 with no patches yet.
    pub fn new(background: Texture) -> Self {
        Self {
            background,
            ground_down_m: 0.0,
            patches: Vec::new(),
            sky: 0.9,
        }
    }

    /// Adds a patch on top of those already there.
    pub fn with_patch(mut self, patch: Patch) -> Self {
        self.patches.push(patch);
        self
    }
}

/// Blur along a straight line, as a camera moving during the exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionBlur {
    pub length_px: f64,
    /// Direction of motion in the image, from the u axis towards v.
    pub angle_rad: f64,
}

/// Image effects, applied in the order optics (blur), exposure (contrast, brightness), sensor (noise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageEffects {
    /// Standard deviation of a Gaussian blur; 0 for none.
    pub gaussian_blur_sigma_px: f64,
    pub motion_blur: Option<MotionBlur>,
    /// Scales intensity about mid-grey: I′ = contrast·(I − ½) + ½ + brightness (I in [0, 1]).
    pub contrast: f64,
    /// Added intensity, in [0, 1] units.
    pub brightness: f64,
    /// Standard deviation of additive Gaussian noise, grey levels (0–255).
    pub noise_sigma: f64,
    pub noise_seed: u64,
}

impl Default for ImageEffects {
    fn default() -> Self {
        Self {
            gaussian_blur_sigma_px: 0.0,
            motion_blur: None,
            contrast: 1.0,
            brightness: 0.0,
            noise_sigma: 0.0,
            noise_seed: 0,
        }
    }
}

impl ImageEffects {
    fn validate(&self) -> Result<(), RenderError> {
        let mut checks = vec![
            ("gaussian_blur_sigma_px", self.gaussian_blur_sigma_px),
            ("noise_sigma", self.noise_sigma),
        ];
        if let Some(m) = self.motion_blur {
            checks.push(("motion_blur.length_px", m.length_px));
            if !m.angle_rad.is_finite() {
                return Err(RenderError::Effect {
                    name: "motion_blur.angle_rad",
                    value: m.angle_rad,
                });
            }
        }
        for (name, value) in checks {
            if !(value.is_finite() && value >= 0.0) {
                return Err(RenderError::Effect { name, value });
            }
        }
        for (name, value) in [("contrast", self.contrast), ("brightness", self.brightness)] {
            if !value.is_finite() {
                return Err(RenderError::Effect { name, value });
            }
        }
        Ok(())
    }
}

/// How to render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Samples per pixel side (anti-aliasing by supersampling): 1 is none, 2 is 2×2.
    pub supersampling: usize,
    pub effects: ImageEffects,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            supersampling: 2,
            effects: ImageEffects::default(),
        }
    }
}

/// The pixel where a NED world point appears: the truth the renderer draws to (the camera's
/// projection; `None` behind the camera).
pub fn true_pixel(
    camera: &PinholeCamera,
    pose: &CameraPose,
    point_world: &Point3<f64>,
) -> Option<(f64, f64)> {
    camera.project_world(pose, point_world)
}

/// A patch prepared for the inner loop: u = (p − c)·eu, v = (p − c)·ev in patch units.
struct PreparedPatch<'a> {
    /// Bounds (x min, x max, y min, y max) of the patch in the camera's normalised (undistorted)
    /// coordinates, so rays that cannot meet it skip it; infinite when the patch reaches behind
    /// the camera (its image is then not the hull of its corners).
    bounds: [f64; 4],
    /// The corners' normalised coordinates, in order round the patch; `None` when one is at
    /// or behind the camera.
    corners: Option<[[f64; 2]; 4]>,
    centre: [f64; 2],
    eu: [f64; 2],
    ev: [f64; 2],
    down_m: f64,
    texture: &'a Texture,
}

/// Renders `scene` as seen by `camera` from `pose` into a camera-sized image.
pub fn render(
    camera: &PinholeCamera,
    pose: &CameraPose,
    scene: &Scene,
    options: &RenderOptions,
) -> Result<GrayImage, RenderError> {
    options.effects.validate()?;
    let (width, height) = (camera.width_px, camera.height_px);
    let mut pixels = vec![0f32; width * height];
    render_rows(camera, pose, scene, options.supersampling, 0, &mut pixels)?;
    finish(pixels, width, height, &options.effects)
}

/// The scene's intensity (0 black to 1 white, before effects) in the image rows from
/// `first_row` that `out` holds (`out.len()` a multiple of the image width): the part of
/// [`render`] that callers may split across threads, since rows are independent.
pub fn render_rows(
    camera: &PinholeCamera,
    pose: &CameraPose,
    scene: &Scene,
    supersampling: usize,
    first_row: usize,
    out: &mut [f32],
) -> Result<(), RenderError> {
    // The same arithmetic on every CPU (no fused multiply-adds), in wider vectors where the
    // CPU has them.
    pulp::Arch::new().dispatch(RenderRows {
        camera,
        pose,
        scene,
        supersampling,
        first_row,
        out,
    })
}

/// [`render_rows`]' arguments, for [`pulp`] to compile its work for each instruction set.
struct RenderRows<'a> {
    camera: &'a PinholeCamera,
    pose: &'a CameraPose,
    scene: &'a Scene,
    supersampling: usize,
    first_row: usize,
    out: &'a mut [f32],
}

impl pulp::WithSimd for RenderRows<'_> {
    type Output = Result<(), RenderError>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        render_rows_here(self)
    }
}

/// [`render_rows`]' work, inlined into each instruction set's copy.
#[inline(always)]
fn render_rows_here(rows: RenderRows<'_>) -> Result<(), RenderError> {
    let RenderRows {
        camera,
        pose,
        scene,
        supersampling,
        first_row,
        out,
    } = rows;
    let ss = supersampling;
    if !(1..=16).contains(&ss) {
        return Err(RenderError::Supersampling(ss));
    }
    // The camera's fields are public, so its size is checked here too.
    let (width, height) = (camera.width_px, camera.height_px);
    if width == 0 || height == 0 {
        return Err(FrameError::Empty { width, height }.into());
    }
    let rows = out.len() / width;
    if !out.len().is_multiple_of(width) || first_row + rows > height {
        return Err(RenderError::RowBuffer {
            width,
            height,
            first_row,
            len: out.len(),
        });
    }
    let prepared = prepare_patches(pose, scene)?;

    let rotation = pose.camera_to_world.rotation.to_rotation_matrix();
    let r = rotation.matrix();
    let origin = pose.position_ned_m();
    let undistorted = camera.distortion.is_zero();
    let inv_samples = 1.0 / (ss * ss) as f32;
    let offsets: Vec<f64> = (0..ss)
        .map(|i| (i as f64 + 0.5) / ss as f64 - 0.5)
        .collect();

    // A sample sees a patch's texture or the sky (`Ok`), or the ground at world (north, east) (`Err`).
    let shade = |candidates: &[&PreparedPatch<'_>],
                 x: f64,
                 y: f64,
                 ray: Vector3<f64>|
     -> Result<f32, (f64, f64)> {
        match nearest_hit(candidates, x, y, &ray, &origin, scene.ground_down_m) {
            Hit::Patch { patch, u, v, .. } => Ok(patch.texture.sample(u, v)),
            Hit::Ground { t } => Err((origin.x + ray.x * t, origin.y + ray.y * t)),
            Hit::Nothing => Ok(scene.sky),
        }
    };

    let mut candidates: Vec<&PreparedPatch<'_>> = Vec::with_capacity(prepared.len());
    // The row's columns as runs that may meet one of its patches or may not: without
    // distortion, the others (most of a frame: the ground) skip the patch tests, which they
    // would all fail; with it, one run that may.
    let mut patch_spans: Vec<(usize, usize)> = Vec::new();
    let mut runs: Vec<(std::ops::Range<usize>, bool)> = Vec::new();
    let ground_height_m = scene.ground_down_m - origin.z;
    // The fast path's row buffers, and each column's normalised x (the same in every row).
    let mut ground_points = vec![[0f64; 2]; width];
    let mut ground_values = vec![0f32; width];
    let column_x: Vec<f64> = (0..width)
        .map(|col| (col as f64 - camera.cx_px) / camera.fx_px)
        .collect();
    for (chunk_row, row_out) in out.chunks_exact_mut(width).enumerate() {
        let row = first_row + chunk_row;
        // Without distortion a row's samples share their normalised y: only the patches that
        // span it need testing in this row.
        candidates.clear();
        let (row_y0, row_y1) = (
            (row as f64 + offsets[0] - camera.cy_px) / camera.fy_px,
            (row as f64 + offsets[ss - 1] - camera.cy_px) / camera.fy_px,
        );
        candidates.extend(
            prepared
                .iter()
                .filter(|p| !undistorted || (p.bounds[2] <= row_y1 && p.bounds[3] >= row_y0)),
        );
        runs.clear();
        if undistorted {
            patch_spans.clear();
            for p in &candidates {
                // Columns whose first or last sample's x can fall within the patch's bounds
                // (an infinite bound saturates the conversion to the image's edge).
                // With one sample per pixel, the row's own span of the patch's image (a convex
                // quadrilateral) is narrower than its bounds when the patch is turned.
                let (x0, x1) = match (ss, &p.corners) {
                    (1, Some(corners)) => match row_span(corners, row_y0) {
                        Some(span) => span,
                        None => continue,
                    },
                    _ => (p.bounds[0], p.bounds[1]),
                };
                let first = ((x0 * camera.fx_px + camera.cx_px - offsets[ss - 1]).floor() - 1.0)
                    .clamp(0.0, width as f64) as usize;
                let last = ((x1 * camera.fx_px + camera.cx_px - offsets[0]).ceil() + 1.0)
                    .clamp(0.0, width as f64) as usize;
                if first < last {
                    patch_spans.push((first, last));
                }
            }
            patch_spans.sort_unstable();
            let mut next = 0;
            for &(first, last) in &patch_spans {
                match runs.last_mut() {
                    Some((run, true)) if first <= run.end => run.end = run.end.max(last),
                    _ => {
                        if next < first {
                            runs.push((next..first, false));
                        }
                        runs.push((first..last, true));
                    }
                }
                next = runs.last().map_or(0, |(run, _)| run.end);
            }
            if next < width {
                runs.push((next..width, false));
            }
        } else {
            runs.push((0..width, true));
        }
        // One sample per pixel without distortion: every pixel's ray meets the ground at a
        // point that is a plain function of its column (ray(x) = c0 + x·c1 in the row), so the
        // row's ground points are computed and the background sampled at them in one pass each,
        // and only the pixels that may see a patch take the path below.
        let fast_row = undistorted && ss == 1;
        if fast_row {
            let y_row = (row as f64 - camera.cy_px) / camera.fy_px;
            let c0 = [
                r[(0, 1)] * y_row + r[(0, 2)],
                r[(1, 1)] * y_row + r[(1, 2)],
                r[(2, 1)] * y_row + r[(2, 2)],
            ];
            let c1 = [r[(0, 0)], r[(1, 0)], r[(2, 0)]];
            for (point, &x) in ground_points.iter_mut().zip(&column_x) {
                let ray_z = c0[2] + x * c1[2];
                let t = ground_height_m / ray_z;
                *point = if ray_z.abs() > 1e-12 && t > 0.0 {
                    [
                        origin.x + (c0[0] + x * c1[0]) * t,
                        origin.y + (c0[1] + x * c1[1]) * t,
                    ]
                } else {
                    [f64::NAN; 2]
                };
            }
            scene
                .background
                .sample_many(&ground_points, &mut ground_values);
            // The whole row as ground (or sky), in a pass with no branches to vectorise; the
            // columns that may see a patch are drawn again below.
            for ((out, point), &value) in row_out.iter_mut().zip(&ground_points).zip(&ground_values)
            {
                *out = if point[0].is_nan() { scene.sky } else { value }.clamp(0.0, 1.0);
            }
        }
        for (columns, may_meet_patch) in runs.iter().cloned() {
            if fast_row && !may_meet_patch {
                continue;
            }
            let candidates: &[&PreparedPatch<'_>] = if may_meet_patch { &candidates } else { &[] };
            for col in columns {
                let out = &mut row_out[col];
                let mut sum = 0f32;
                // The background is texture, not truth: it is sampled once per pixel, at the
                // centroid of the samples that see it, which makes supersampling cost little
                // more than the patches' edges need. Patches are sampled at every sample.
                let (mut ground_n, mut ground_e, mut ground_samples) = (0.0, 0.0, 0u32);
                for &dv in &offsets {
                    for &du in &offsets {
                        let (u, v) = (col as f64 + du, row as f64 + dv);
                        let (x, y) = if undistorted {
                            (
                                (u - camera.cx_px) / camera.fx_px,
                                (v - camera.cy_px) / camera.fy_px,
                            )
                        } else {
                            camera.normalized(u, v)
                        };
                        // The ray need not be unit length: the plane intersection scales with it.
                        let ray = Vector3::new(
                            r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)],
                            r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)],
                            r[(2, 0)] * x + r[(2, 1)] * y + r[(2, 2)],
                        );
                        match shade(candidates, x, y, ray) {
                            Ok(value) => sum += value.clamp(0.0, 1.0),
                            Err((n, e)) => {
                                ground_n += n;
                                ground_e += e;
                                ground_samples += 1;
                            }
                        }
                    }
                }
                if ground_samples > 0 {
                    let k = ground_samples as f64;
                    let value = scene.background.sample(ground_n / k, ground_e / k);
                    sum += ground_samples as f32 * value.clamp(0.0, 1.0);
                }
                *out = sum * inv_samples;
            }
        }
    }
    Ok(())
}

/// The scene's patches checked and prepared for the inner loop, topmost first.
fn prepare_patches<'a>(
    pose: &CameraPose,
    scene: &'a Scene,
) -> Result<Vec<PreparedPatch<'a>>, RenderError> {
    let mut prepared = Vec::with_capacity(scene.patches.len());
    for (index, p) in scene.patches.iter().enumerate() {
        if !(p.width_m.is_finite() && p.height_m.is_finite() && p.width_m > 0.0 && p.height_m > 0.0)
        {
            return Err(RenderError::PatchSize {
                index,
                width_m: p.width_m,
                height_m: p.height_m,
            });
        }
        if ![p.north_m, p.east_m, p.down_m, p.yaw_rad]
            .iter()
            .all(|x| x.is_finite())
        {
            return Err(RenderError::PatchPose { index });
        }
        let (eu, ev) = p.axes();
        let (su, sv) = (2.0 / p.width_m, 2.0 / p.height_m);
        prepared.push(PreparedPatch {
            bounds: normalized_bounds(pose, p),
            corners: normalized_corners(pose, p),
            centre: [p.north_m, p.east_m],
            eu: [eu[0] * su, eu[1] * su],
            ev: [ev[0] * sv, ev[1] * sv],
            down_m: p.down_m,
            texture: &p.texture,
        });
    }
    // Topmost first, so that on equal distance the later patch wins (strict comparison below).
    prepared.reverse();
    Ok(prepared)
}

/// What a ray meets first.
enum Hit<'p, 't> {
    /// A patch at ray parameter `t`, at patch coordinates (u, v).
    Patch {
        t: f64,
        patch: &'p PreparedPatch<'t>,
        u: f64,
        v: f64,
    },
    /// The ground plane at ray parameter `t`.
    Ground { t: f64 },
    /// Nothing: the sky (the ray is level, or points away from every plane).
    Nothing,
}

/// The first surface the ray `origin + t·ray` (t > 0) meets among `candidates` and the ground
/// plane `down = ground_down_m`; `(x, y)` are the ray's normalised camera coordinates, for the
/// patches' bounds. The one geometry of [`render`] and [`render_depth`]: with `ray` the camera
/// ray (x, y, 1) rotated into the world, `t` is the hit's depth along the optical axis.
#[inline(always)]
fn nearest_hit<'p, 't>(
    candidates: &[&'p PreparedPatch<'t>],
    x: f64,
    y: f64,
    ray: &Vector3<f64>,
    origin: &Vector3<f64>,
    ground_down_m: f64,
) -> Hit<'p, 't> {
    if ray.z.abs() <= 1e-12 {
        return Hit::Nothing;
    }
    let inverse_z = 1.0 / ray.z;
    let ground_t = (ground_down_m - origin.z) * inverse_z;
    let mut best_t = if ground_t > 0.0 {
        ground_t
    } else {
        f64::INFINITY
    };
    let mut best: Option<(&'p PreparedPatch<'t>, f64, f64)> = None;
    for &p in candidates {
        let [x0, x1, y0, y1] = p.bounds;
        if x < x0 || x > x1 || y < y0 || y > y1 {
            continue;
        }
        let t = (p.down_m - origin.z) * inverse_z;
        // A patch on the ground plane itself must beat the ground: compare with a tolerance.
        if !(t > 0.0 && t <= best_t * (1.0 + 1e-12)) || (best.is_some() && t >= best_t) {
            continue;
        }
        let dn = origin.x + ray.x * t - p.centre[0];
        let de = origin.y + ray.y * t - p.centre[1];
        let u = dn * p.eu[0] + de * p.eu[1];
        let v = dn * p.ev[0] + de * p.ev[1];
        if u.abs() <= 1.0 && v.abs() <= 1.0 {
            best_t = t;
            best = Some((p, u, v));
        }
    }
    match best {
        Some((patch, u, v)) => Hit::Patch {
            t: best_t,
            patch,
            u,
            v,
        },
        None if best_t.is_finite() => Hit::Ground { t: best_t },
        None => Hit::Nothing,
    }
}

/// The depth of `scene` seen by `camera` from `pose`: for every pixel centre, the distance along
/// the optical axis (the camera's z) to the first surface its ray meets, by the same ray casting
/// and patch geometry as [`render`]; NaN where the ray meets nothing (the sky). An ideal depth
/// camera: a stereo camera's noise and range are the caller's to add.
pub fn render_depth(
    camera: &PinholeCamera,
    pose: &CameraPose,
    scene: &Scene,
) -> Result<DepthImage, RenderError> {
    let (width, height) = (camera.width_px, camera.height_px);
    if width == 0 || height == 0 {
        return Err(FrameError::Empty { width, height }.into());
    }
    let prepared = prepare_patches(pose, scene)?;
    let rotation = pose.camera_to_world.rotation.to_rotation_matrix();
    let r = rotation.matrix();
    let origin = pose.position_ned_m();
    let undistorted = camera.distortion.is_zero();
    let mut depth = vec![f32::NAN; width * height];
    let mut candidates: Vec<&PreparedPatch<'_>> = Vec::with_capacity(prepared.len());
    for row in 0..height {
        candidates.clear();
        let row_y = (row as f64 - camera.cy_px) / camera.fy_px;
        candidates.extend(
            prepared
                .iter()
                .filter(|p| !undistorted || (p.bounds[2] <= row_y && p.bounds[3] >= row_y)),
        );
        for (col, out) in depth[row * width..(row + 1) * width].iter_mut().enumerate() {
            let (x, y) = if undistorted {
                ((col as f64 - camera.cx_px) / camera.fx_px, row_y)
            } else {
                camera.normalized(col as f64, row as f64)
            };
            let ray = Vector3::new(
                r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)],
                r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)],
                r[(2, 0)] * x + r[(2, 1)] * y + r[(2, 2)],
            );
            *out = match nearest_hit(&candidates, x, y, &ray, &origin, scene.ground_down_m) {
                Hit::Patch { t, .. } | Hit::Ground { t } => t as f32,
                Hit::Nothing => f32::NAN,
            };
        }
    }
    Ok(DepthImage::from_vec(width, height, depth)?)
}

/// The normalised coordinates of a patch's corners seen from `pose`, round the patch; `None`
/// when one is at or behind the camera.
fn normalized_corners(pose: &CameraPose, patch: &Patch) -> Option<[[f64; 2]; 4]> {
    let mut corners = [[0.0; 2]; 4];
    for (corner, (u, v)) in
        corners
            .iter_mut()
            .zip([(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)])
    {
        let c = pose.world_to_camera(&patch.point_world(u, v));
        if c.z.is_nan() || c.z <= 1e-6 {
            return None;
        }
        *corner = [c.x / c.z, c.y / c.z];
    }
    Some(corners)
}

/// Where the line at normalised y = `y` crosses the convex quadrilateral `corners`: its
/// (x min, x max), widened by a hair for rounding; `None` when it misses.
fn row_span(corners: &[[f64; 2]; 4], y: f64) -> Option<(f64, f64)> {
    let (mut x_min, mut x_max) = (f64::INFINITY, f64::NEG_INFINITY);
    for (i, a) in corners.iter().enumerate() {
        let b = &corners[(i + 1) % 4];
        let (low, high) = if a[1] <= b[1] { (a, b) } else { (b, a) };
        if y < low[1] || y > high[1] {
            continue;
        }
        let x = if high[1] - low[1] > 1e-15 {
            low[0] + (y - low[1]) * (high[0] - low[0]) / (high[1] - low[1])
        } else {
            // A level edge on the line: both its ends.
            x_min = x_min.min(low[0].min(high[0]));
            x_max = x_max.max(low[0].max(high[0]));
            continue;
        };
        x_min = x_min.min(x);
        x_max = x_max.max(x);
    }
    let margin = 1e-9 * (1.0 + x_min.abs().max(x_max.abs()));
    (x_min <= x_max).then_some((x_min - margin, x_max + margin))
}

/// The normalised-coordinate bounds of a patch seen from `pose` (see [`PreparedPatch::bounds`]),
/// widened by a hair so rounding never drops a ray that meets the patch's edge.
fn normalized_bounds(pose: &CameraPose, patch: &Patch) -> [f64; 4] {
    let everywhere = [
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
    ];
    let mut bounds = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    for (u, v) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        let corner = pose.world_to_camera(&patch.point_world(u, v));
        // A corner at or behind the camera: the patch's image is unbounded.
        if corner.z.is_nan() || corner.z <= 1e-6 {
            return everywhere;
        }
        let (x, y) = (corner.x / corner.z, corner.y / corner.z);
        bounds = [
            bounds[0].min(x),
            bounds[1].max(x),
            bounds[2].min(y),
            bounds[3].max(y),
        ];
    }
    let margin = 1e-9 * (1.0 + bounds.iter().fold(0f64, |m, b| m.max(b.abs())));
    [
        bounds[0] - margin,
        bounds[1] + margin,
        bounds[2] - margin,
        bounds[3] + margin,
    ]
}

/// Applies `effects` to an existing image.
pub fn apply_effects(image: &GrayImage, effects: &ImageEffects) -> Result<GrayImage, RenderError> {
    effects.validate()?;
    let pixels = image.data().iter().map(|&p| p as f32 / 255.0).collect();
    finish(pixels, image.width(), image.height(), effects)
}

/// Blur, exposure and noise on intensities in [0, 1], then 8-bit quantisation.
/// Intensities (0 black to 1 white) to a grey image, with the effects.
pub fn finish(
    mut pixels: Vec<f32>,
    width: usize,
    height: usize,
    effects: &ImageEffects,
) -> Result<GrayImage, RenderError> {
    effects.validate()?;
    if effects.gaussian_blur_sigma_px > 0.0 {
        gaussian_blur(&mut pixels, width, height, effects.gaussian_blur_sigma_px);
    }
    if let Some(m) = effects.motion_blur {
        if m.length_px > 0.0 {
            pixels = motion_blur(&pixels, width, height, m);
        }
    }
    let contrast = effects.contrast as f32;
    let brightness = effects.brightness as f32;
    let mut rng = SplitMix64::new(effects.noise_seed);
    let noise = effects.noise_sigma as f32;
    let data = pixels
        .iter()
        .map(|&p| {
            let mut level = (contrast * (p - 0.5) + 0.5 + brightness) * 255.0;
            if noise > 0.0 {
                level += noise * rng.next_gaussian() as f32;
            }
            // Round half up after clamping (no libm call).
            (level.clamp(0.0, 255.0) + 0.5) as u8
        })
        .collect();
    Ok(GrayImage::from_vec(width, height, data)?)
}

/// Separable Gaussian blur, edges clamped.
fn gaussian_blur(pixels: &mut [f32], width: usize, height: usize, sigma_px: f64) {
    let radius = (3.0 * sigma_px).ceil().max(1.0) as usize;
    let mut taps: Vec<f32> = (0..=2 * radius)
        .map(|i| {
            let d = i as f64 - radius as f64;
            (-(d * d) / (2.0 * sigma_px * sigma_px)).exp() as f32
        })
        .collect();
    let total: f32 = taps.iter().sum();
    taps.iter_mut().for_each(|t| *t /= total);
    let mut tmp = vec![0f32; pixels.len()];
    for y in 0..height {
        let row = &pixels[y * width..(y + 1) * width];
        for x in 0..width {
            let mut acc = 0f32;
            for (i, t) in taps.iter().enumerate() {
                let xs = (x + i).saturating_sub(radius).min(width - 1);
                acc += t * row[xs];
            }
            tmp[y * width + x] = acc;
        }
    }
    for y in 0..height {
        for x in 0..width {
            let mut acc = 0f32;
            for (i, t) in taps.iter().enumerate() {
                let ys = (y + i).saturating_sub(radius).min(height - 1);
                acc += t * tmp[ys * width + x];
            }
            pixels[y * width + x] = acc;
        }
    }
}

/// Mean along a centred segment of the motion, sampled bilinearly about every half pixel.
fn motion_blur(pixels: &[f32], width: usize, height: usize, blur: MotionBlur) -> Vec<f32> {
    let steps = (2.0 * blur.length_px).ceil().max(1.0) as usize + 1;
    let (sin, cos) = blur.angle_rad.sin_cos();
    let offsets: Vec<(f64, f64)> = (0..steps)
        .map(|k| {
            let s = (k as f64 / (steps - 1) as f64 - 0.5) * blur.length_px;
            (s * cos, s * sin)
        })
        .collect();
    let at = |x: f64, y: f64| -> f32 {
        let x = x.clamp(0.0, (width - 1) as f64);
        let y = y.clamp(0.0, (height - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let top = pixels[y0 * width + x0] * (1.0 - fx) + pixels[y0 * width + x1] * fx;
        let bottom = pixels[y1 * width + x0] * (1.0 - fx) + pixels[y1 * width + x1] * fx;
        top * (1.0 - fy) + bottom * fy
    };
    let mut out = vec![0f32; pixels.len()];
    for y in 0..height {
        for x in 0..width {
            let sum: f32 = offsets
                .iter()
                .map(|&(dx, dy)| at(x as f64 + dx, y as f64 + dy))
                .sum();
            out[y * width + x] = sum / steps as f32;
        }
    }
    out
}

/// SplitMix64: a small, seedable generator, so the crate needs no random-number dependency.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitMix64 {
    state: u64,
    spare_gaussian: Option<f64>,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self {
            state: seed,
            spare_gaussian: None,
        }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    pub fn next_gaussian(&mut self) -> f64 {
        if let Some(z) = self.spare_gaussian.take() {
            return z;
        }
        let u1 = 1.0 - self.next_f64(); // (0, 1]: ln stays finite
        let u2 = self.next_f64();
        let radius = (-2.0 * u1.ln()).sqrt();
        let (sin, cos) = (2.0 * PI * u2).sin_cos();
        self.spare_gaussian = Some(radius * sin);
        radius * cos
    }
}

/// ⌊x⌋ without a libm call (x86-64's baseline has no rounding instruction); |x| < 2⁶³.
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// Smooth value noise from a seeded 64×64 lattice that wraps (small enough to stay in L1 cache);
/// `layer` picks an offset so the octaves of one field do not line up, and the octaves' periods are
/// incommensurate, so their sum does not visibly repeat.
struct ValueNoise {
    lattice: Box<[f32; ValueNoise::SIZE * ValueNoise::SIZE]>,
}

impl ValueNoise {
    const SIZE: usize = 64;

    fn new(seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed);
        let mut lattice = Box::new([0f32; Self::SIZE * Self::SIZE]);
        lattice.iter_mut().for_each(|v| *v = rng.next_f64() as f32);
        Self { lattice }
    }

    /// Value in [0, 1].
    fn at(&self, x: f64, y: f64, layer: usize) -> f32 {
        let (x, y) = (x + 37.7 * layer as f64, y + 91.3 * layer as f64);
        // ⌊x⌋ by truncation and a correction: no libm call.
        let (xi, yi) = (x as i64, y as i64);
        let (xi, yi) = (xi - i64::from(x < xi as f64), yi - i64::from(y < yi as f64));
        let (tx, ty) = ((x - xi as f64) as f32, (y - yi as f64) as f32);
        // Smoothstep hides the lattice's grid.
        let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
        let mask = Self::SIZE as i64 - 1;
        let (x0, y0) = ((xi & mask) as usize, (yi & mask) as usize);
        let (x1, y1) = ((x0 + 1) & (Self::SIZE - 1), (y0 + 1) & (Self::SIZE - 1));
        // A fixed-size lattice and masked indices: no bounds checks left.
        let at =
            |i: usize, j: usize| self.lattice[(j * Self::SIZE + i) & (Self::SIZE * Self::SIZE - 1)];
        let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * sx;
        let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * sx;
        top + (bottom - top) * sy
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level_camera(altitude_m: f64) -> (PinholeCamera, CameraPose) {
        let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -altitude_m), 0.0, 0.0, 0.0);
        (camera, pose)
    }

    fn exact() -> RenderOptions {
        RenderOptions {
            supersampling: 1,
            effects: ImageEffects::default(),
        }
    }

    #[test]
    fn a_patch_appears_where_the_camera_projects_it() {
        let (camera, pose) = {
            let camera = PinholeCamera::from_fov(640, 480, 1.1).unwrap();
            let pose = CameraPose::downward(Vector3::new(-1.0, 0.5, -6.0), 0.12, -0.08, 0.7);
            (camera, pose)
        };
        let patch = Patch::square(0.3, 0.2, 0.4, 1.0, Texture::uniform(1.0));
        let scene = Scene::new(Texture::uniform(0.0)).with_patch(patch.clone());
        let image = render(&camera, &pose, &scene, &exact()).unwrap();
        // Pixels just inside the projected corners are white, just outside black.
        for (u, v) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            let inside = true_pixel(&camera, &pose, &patch.point_world(0.9 * u, 0.9 * v)).unwrap();
            let outside = true_pixel(&camera, &pose, &patch.point_world(1.1 * u, 1.1 * v)).unwrap();
            let px = |(x, y): (f64, f64)| image.get(x.round() as usize, y.round() as usize);
            assert_eq!(px(inside), 255);
            assert_eq!(px(outside), 0);
        }
    }

    #[test]
    fn a_level_camera_sees_the_texture_upright() {
        // Patch yaw 0 with a level camera of yaw 0: patch u → image right, v → image down.
        let (camera, pose) = level_camera(4.0);
        let texture = Texture::from_fn(|u, v| if u > 0.0 && v > 0.0 { 1.0 } else { 0.0 });
        let scene = Scene::new(Texture::uniform(0.5))
            .with_patch(Patch::square(0.0, 0.0, 0.0, 2.0, texture));
        let image = render(&camera, &pose, &scene, &exact()).unwrap();
        assert_eq!(image.get(400, 300), 255, "bottom right is white");
        assert_eq!(image.get(240, 300), 0);
        assert_eq!(image.get(400, 180), 0);
    }

    #[test]
    fn the_nfold_texture_is_black_where_sin_n_theta_is_positive() {
        let tex = Texture::nfold(4, false).unwrap();
        for k in 0..64 {
            let theta = (k as f64 + 0.37) * 2.0 * PI / 64.0;
            let (u, v) = (0.5 * theta.cos(), 0.5 * theta.sin());
            let black = (4.0 * theta).sin() > 0.0;
            assert_eq!(
                tex.sample(u, v),
                if black { 0.0 } else { 1.0 },
                "θ = {theta}"
            );
        }
        assert_eq!(tex.sample(0.9, 0.9), 1.0, "outside the disc");
        let oriented = Texture::nfold(4, true).unwrap();
        assert_eq!(oriented.sample(0.5 * 0.3f64.cos(), 0.5 * 0.3f64.sin()), 1.0);
        assert_eq!(oriented.sample(0.5 * 1.8f64.cos(), 0.5 * 1.8f64.sin()), 0.0);
        assert!(matches!(
            Texture::nfold(1, false),
            Err(RenderError::NfoldOrder(1))
        ));
    }

    #[test]
    fn the_aruco_texture_has_a_black_border_and_the_bits_inside() {
        // 2×2 bits: white, black / black, white → 4×4 cells with the border.
        let tex = Texture::aruco(&[true, false, false, true], 2).unwrap();
        let cell = |col: usize, row: usize| {
            tex.sample(
                -1.0 + (col as f64 + 0.5) * 0.5,
                -1.0 + (row as f64 + 0.5) * 0.5,
            )
        };
        for i in 0..4 {
            assert_eq!(cell(i, 0), 0.0);
            assert_eq!(cell(0, i), 0.0);
            assert_eq!(cell(3, i), 0.0);
            assert_eq!(cell(i, 3), 0.0);
        }
        assert_eq!(
            (cell(1, 1), cell(2, 1), cell(1, 2), cell(2, 2)),
            (1.0, 0.0, 0.0, 1.0)
        );
        assert!(matches!(
            Texture::aruco(&[true; 5], 2),
            Err(RenderError::ArucoBits {
                expected: 4,
                found: 5,
                ..
            })
        ));
    }

    #[test]
    fn supersampling_averages_an_edge() {
        // A patch edge through the middle of pixel column 320: half white, half black. (Patches are
        // supersampled; the background is sampled once per pixel.)
        let (camera, pose) = level_camera(5.0);
        let edge_east_m = 0.5 * 5.0 / camera.fx_px; // the centre of column 320, east of the axis
        let white = Patch::new(
            0.0,
            edge_east_m + 5.0,
            0.0,
            10.0,
            10.0,
            Texture::uniform(1.0),
        );
        let options = RenderOptions {
            supersampling: 4,
            effects: ImageEffects::default(),
        };
        let scene = Scene::new(Texture::uniform(0.0)).with_patch(white);
        let image = render(&camera, &pose, &scene, &options).unwrap();
        assert_eq!(image.get(319, 240), 0);
        assert_eq!(image.get(321, 240), 255);
        assert!((image.get(320, 240) as i32 - 128).abs() <= 1);
        // Without supersampling the pixel takes one side.
        let options = RenderOptions {
            supersampling: 1,
            ..options
        };
        let image = render(&camera, &pose, &scene, &options).unwrap();
        assert!([0, 255].contains(&image.get(320, 240)));
    }

    #[test]
    fn effects_change_the_image_as_asked() {
        let image = GrayImage::filled(64, 48, 128).unwrap();
        let bright = apply_effects(
            &image,
            &ImageEffects {
                brightness: 0.1,
                contrast: 2.0,
                ..Default::default()
            },
        )
        .unwrap();
        // 2·(128/255 − ½) + ½ + 0.1 → 153.5 grey levels.
        assert!((bright.get(5, 5) as i32 - 154).abs() <= 1);
        let noisy = ImageEffects {
            noise_sigma: 10.0,
            noise_seed: 7,
            ..Default::default()
        };
        let a = apply_effects(&image, &noisy).unwrap();
        assert_eq!(a, apply_effects(&image, &noisy).unwrap(), "seeded");
        let levels: Vec<f64> = a.data().iter().map(|&p| p as f64).collect();
        let mean = levels.iter().sum::<f64>() / levels.len() as f64;
        let sd =
            (levels.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / levels.len() as f64).sqrt();
        assert!(
            (mean - 128.0).abs() < 1.0 && (sd - 10.0).abs() < 1.0,
            "{mean} {sd}"
        );
        // Blur keeps a uniform image uniform and smooths a step.
        let mut step = GrayImage::filled(32, 8, 0).unwrap();
        for y in 0..8 {
            for x in 16..32 {
                step.set(x, y, 255);
            }
        }
        for effects in [
            ImageEffects {
                gaussian_blur_sigma_px: 1.5,
                ..Default::default()
            },
            ImageEffects {
                motion_blur: Some(MotionBlur {
                    length_px: 4.0,
                    angle_rad: 0.0,
                }),
                ..Default::default()
            },
        ] {
            let blurred = apply_effects(&step, &effects).unwrap();
            assert!(blurred.get(15, 4) > 60 && blurred.get(16, 4) < 195);
            assert_eq!(blurred.get(2, 4), 0);
            assert_eq!(blurred.get(29, 4), 255);
        }
        assert!(matches!(
            apply_effects(
                &image,
                &ImageEffects {
                    noise_sigma: -1.0,
                    ..Default::default()
                }
            ),
            Err(RenderError::Effect {
                name: "noise_sigma",
                ..
            })
        ));
    }

    #[test]
    fn bad_scenes_are_named_errors() {
        let (camera, pose) = level_camera(3.0);
        let scene = Scene::new(Texture::uniform(0.5)).with_patch(Patch::square(
            0.0,
            0.0,
            0.0,
            0.0,
            Texture::uniform(1.0),
        ));
        assert!(matches!(
            render(&camera, &pose, &scene, &exact()),
            Err(RenderError::PatchSize { index: 0, .. })
        ));
        let mut empty = camera;
        empty.width_px = 0;
        assert!(matches!(
            render(&empty, &pose, &Scene::new(Texture::uniform(0.5)), &exact()),
            Err(RenderError::Frame(FrameError::Empty { .. }))
        ));
        let options = RenderOptions {
            supersampling: 0,
            ..Default::default()
        };
        assert!(matches!(
            render(&camera, &pose, &Scene::new(Texture::uniform(0.5)), &options),
            Err(RenderError::Supersampling(0))
        ));
    }

    #[test]
    fn a_raised_patch_hides_what_is_below_it() {
        let (camera, pose) = level_camera(10.0);
        let scene = Scene::new(Texture::uniform(0.0))
            .with_patch(Patch::square(0.0, 0.0, 0.0, 1.0, Texture::uniform(1.0)).at_down_m(-2.0))
            .with_patch(Patch::square(0.0, 0.0, 0.0, 4.0, Texture::uniform(0.5)));
        let image = render(&camera, &pose, &scene, &exact()).unwrap();
        // The later patch lies on the ground, below the raised one: the raised one stays visible.
        assert_eq!(image.get(320, 240), 255);
        assert_eq!(image.get(320 + 60, 240), 128);
    }

    /// The closed form for a plane: with n the plane's unit normal (world down) and d the
    /// camera's distance to it, both in the camera frame, the point seen through the normalised
    /// ray r = (x, y, 1) lies at depth d / (n·r).
    fn plane_depth(
        camera: &PinholeCamera,
        pose: &CameraPose,
        plane_down_m: f64,
        u: f64,
        v: f64,
    ) -> Option<f64> {
        let n_camera = pose.camera_to_world.rotation.inverse() * Vector3::z();
        let d = plane_down_m - pose.position_ned_m().z;
        let unit = camera.unproject(u, v).into_inner();
        let ray = unit / unit.z;
        let along = n_camera.dot(&ray);
        (along > 1e-9).then(|| d / along)
    }

    #[test]
    fn depth_of_flat_ground_matches_the_closed_form_under_a_tilted_camera() {
        let pinhole = PinholeCamera::from_fov(80, 60, 70f64.to_radians()).unwrap();
        let distorted = pinhole.with_distortion(crate::camera::RadialTangential {
            k1: -0.12,
            k2: 0.03,
            p1: 0.001,
            p2: -0.0008,
            k3: 0.0,
        });
        let pose = CameraPose::downward(Vector3::new(2.0, -1.0, -6.0), 0.2, -0.15, 0.8);
        let scene = Scene::new(Texture::uniform(0.5));
        for camera in [pinhole, distorted] {
            let depth = render_depth(&camera, &pose, &scene).unwrap();
            assert_eq!((depth.width(), depth.height()), (80, 60));
            let mut spread = (f64::INFINITY, 0f64);
            for y in 0..60 {
                for x in 0..80 {
                    let expected = plane_depth(&camera, &pose, 0.0, x as f64, y as f64).unwrap();
                    let got = depth.get(x, y) as f64;
                    assert!(
                        (got - expected).abs() < 1e-5 * expected,
                        "({x}, {y}): {got} vs {expected}"
                    );
                    // And the point at that depth on the pixel's ray lies on the ground.
                    let (nx, ny) = camera.normalized(x as f64, y as f64);
                    let point = pose.camera_to_world_point(&Point3::new(nx * got, ny * got, got));
                    assert!(point.z.abs() < 1e-4, "{point}");
                    spread = (spread.0.min(got), spread.1.max(got));
                }
            }
            // Tilted: the depth is not uniform (a level camera's would be).
            assert!(spread.1 - spread.0 > 1.0, "{spread:?}");
        }
    }

    #[test]
    fn depth_sees_raised_patches_where_the_image_does_and_nan_is_the_sky() {
        // A white raised patch (2 m above a black ground) under a tilted camera: every pixel the
        // renderer draws white has the patch plane's depth, every black one the ground's.
        let camera = PinholeCamera::from_fov(96, 72, 60f64.to_radians()).unwrap();
        let pose = CameraPose::downward(Vector3::new(0.4, 0.3, -7.0), -0.1, 0.12, 0.3);
        let scene = Scene::new(Texture::uniform(0.0))
            .with_patch(Patch::square(0.0, 0.0, 0.5, 2.0, Texture::uniform(1.0)).at_down_m(-2.0));
        let image = render(&camera, &pose, &scene, &exact()).unwrap();
        let depth = render_depth(&camera, &pose, &scene).unwrap();
        let mut on_patch = 0;
        for y in 0..72 {
            for x in 0..96 {
                let (u, v) = (x as f64, y as f64);
                let z = depth.get(x, y) as f64;
                let plane = if image.get(x, y) == 255 {
                    on_patch += 1;
                    -2.0
                } else {
                    0.0
                };
                let expected = plane_depth(&camera, &pose, plane, u, v).unwrap();
                assert!((z - expected).abs() < 1e-5 * expected, "({x}, {y})");
            }
        }
        assert!(on_patch > 100, "{on_patch} pixels on the patch");
        // A level camera sees flat ground at its height everywhere, the patch 2 m nearer.
        let level = CameraPose::downward(Vector3::new(0.0, 0.0, -7.0), 0.0, 0.0, 0.0);
        let depth = render_depth(&camera, &level, &scene).unwrap();
        assert!((depth.get(48, 36) - 5.0).abs() < 1e-5);
        assert!((depth.get(2, 2) - 7.0).abs() < 1e-5);
        // Pitched up 80°: the top of the image sees the sky (NaN), the bottom the ground.
        let horizon = CameraPose::downward(Vector3::new(0.0, 0.0, -7.0), 0.0, 1.4, 0.0);
        let depth = render_depth(&camera, &horizon, &scene).unwrap();
        for (x, y) in [(10, 0), (50, 5), (90, 70), (48, 36)] {
            let expected = plane_depth(&camera, &horizon, 0.0, x as f64, y as f64);
            let z = depth.get(x, y);
            match expected {
                None => assert!(z.is_nan(), "({x}, {y}): {z}"),
                Some(e) => assert!((z as f64 - e).abs() < 1e-4 * e, "({x}, {y}): {z} vs {e}"),
            }
        }
        assert!(depth.get(48, 0).is_nan() && depth.get(48, 71).is_finite());
        // Bad scenes are refused as the renderer refuses them.
        let bad = Scene::new(Texture::uniform(0.5)).with_patch(Patch::square(
            0.0,
            0.0,
            f64::NAN,
            1.0,
            Texture::uniform(1.0),
        ));
        assert!(matches!(
            render_depth(&camera, &pose, &bad),
            Err(RenderError::PatchPose { index: 0 })
        ));
    }

    #[test]
    fn the_field_texture_is_seeded_and_textured() {
        let a = Texture::field(3);
        let b = Texture::field(3);
        let c = Texture::field(4);
        let pts: Vec<(f64, f64)> = (0..200)
            .map(|i| (i as f64 * 0.173, i as f64 * -0.091))
            .collect();
        assert!(pts.iter().all(|&(n, e)| a.sample(n, e) == b.sample(n, e)));
        assert!(pts.iter().any(|&(n, e)| a.sample(n, e) != c.sample(n, e)));
        let values: Vec<f32> = pts.iter().map(|&(n, e)| a.sample(n, e)).collect();
        let spread = values.iter().cloned().fold(f32::MIN, f32::max)
            - values.iter().cloned().fold(f32::MAX, f32::min);
        assert!(spread > 0.2, "{spread}");
    }

    #[test]
    fn every_pixel_off_the_patches_shows_the_ground_under_its_ray_or_the_sky() {
        // A camera pitched up so the top rows see the sky, over a textured ground with one raised
        // patch, its bounds cutting rows in two: each pixel is checked against the ground point
        // of its own ray (`pixel_to_plane`, the camera's geometry, not the renderer's), whether
        // the texture is sampled one point at a time or many at once.
        let camera = PinholeCamera::from_fov(160, 120, 70f64.to_radians()).unwrap();
        let pose = CameraPose::downward(Vector3::new(0.3, -0.2, -5.0), 0.1, 1.2, 0.4);
        let ground = |n: f64, e: f64| (0.5 + 0.4 * (3.1 * n).sin() * (1.7 * e).cos()) as f32;
        let centre = camera.pixel_to_plane(&pose, 80.0, 90.0, -0.5).unwrap();
        let patch =
            Patch::square(centre.x, centre.y, 0.2, 0.8, Texture::uniform(0.0)).at_down_m(-0.5);
        for background in [
            Texture::from_fn(ground),
            Texture::from_fns(ground, move |points, out| {
                for (&[n, e], value) in points.iter().zip(out) {
                    *value = ground(n, e);
                }
            }),
        ] {
            let scene = Scene::new(background).with_patch(patch.clone());
            let image = render(&camera, &pose, &scene, &exact()).unwrap();
            let (mut sky, mut ground_px, mut patch_px) = (0, 0, 0);
            for v in 0..120 {
                for u in 0..160 {
                    let got = image.get(u, v) as f32;
                    let point = camera.pixel_to_plane(&pose, u as f64, v as f64, 0.0);
                    let on_patch = camera
                        .pixel_to_plane(&pose, u as f64, v as f64, -0.5)
                        .is_some_and(|p| {
                            let (dn, de) = (p.x - centre.x, p.y - centre.y);
                            let (c, s) = (0.2f64.cos(), 0.2f64.sin());
                            (dn * c + de * s).abs() < 0.4 && (-dn * s + de * c).abs() < 0.4
                        });
                    let expected = match point {
                        _ if on_patch => {
                            patch_px += 1;
                            0.0
                        }
                        Some(p) => {
                            ground_px += 1;
                            ground(p.x, p.y) * 255.0
                        }
                        None => {
                            sky += 1;
                            scene.sky * 255.0
                        }
                    };
                    assert!(
                        (got - expected).abs() <= 1.0,
                        "({u}, {v}): {got} vs {expected}"
                    );
                }
            }
            assert!(
                sky > 1000 && ground_px > 1000 && patch_px > 50,
                "{sky} {ground_px} {patch_px}"
            );
        }
    }
}
