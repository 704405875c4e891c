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

use nalgebra::{Matrix3, Point3, Vector3};
use thiserror::Error;

use super::image::{DepthImage, FrameError, GrayImage};
use crate::camera::{CameraPose, PinholeCamera};

mod effects;
mod scene;
pub use effects::{apply_effects, finish, ImageEffects, MotionBlur, SplitMix64};
pub use scene::{Patch, Scene, Texture};

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
    check_row_buffer(camera, ss, first_row, out.len())?;
    let width = camera.width_px;
    let prepared = prepare_patches(pose, scene)?;

    let rotation = pose.camera_to_world.rotation.to_rotation_matrix();
    let frame = FrameRays::new(camera, scene, rotation.matrix(), pose.position_ned_m(), ss);

    let mut candidates: Vec<&PreparedPatch<'_>> = Vec::with_capacity(prepared.len());
    // The row's columns as runs that may meet one of its patches or may not: without
    // distortion, the others (most of a frame: the ground) skip the patch tests, which they
    // would all fail; with it, one run that may.
    let mut patch_spans: Vec<(usize, usize)> = Vec::new();
    let mut runs: Vec<(std::ops::Range<usize>, bool)> = Vec::new();
    // The fast path's row buffers.
    let mut ground_points = vec![[0f64; 2]; width];
    let mut ground_values = vec![0f32; width];
    for (chunk_row, row_out) in out.chunks_exact_mut(width).enumerate() {
        let row = first_row + chunk_row;
        // Without distortion a row's samples share their normalised y: only the patches that
        // span it need testing in this row.
        candidates.clear();
        let (row_y0, row_y1) = frame.row_y_span(row);
        candidates.extend(
            prepared
                .iter()
                .filter(|p| !frame.undistorted || (p.bounds[2] <= row_y1 && p.bounds[3] >= row_y0)),
        );
        runs.clear();
        if frame.undistorted {
            frame.column_runs(&candidates, row_y0, &mut patch_spans, &mut runs);
        } else {
            runs.push((0..width, true));
        }
        // One sample per pixel without distortion: the whole row is drawn as ground (or sky)
        // first, and only the pixels that may see a patch take the path below.
        let fast_row = frame.undistorted && ss == 1;
        if fast_row {
            frame.draw_row_as_ground(row, &mut ground_points, &mut ground_values, row_out);
        }
        for (columns, may_meet_patch) in runs.iter().cloned() {
            if fast_row && !may_meet_patch {
                continue;
            }
            let candidates: &[&PreparedPatch<'_>] = if may_meet_patch { &candidates } else { &[] };
            for col in columns {
                let out = &mut row_out[col];
                *out = frame.pixel_intensity(candidates, col, row);
            }
        }
    }
    Ok(())
}

/// The supersampling factor, the camera's size and `len` values of rows from `first_row`
/// checked before [`render_rows`] draws into them.
fn check_row_buffer(
    camera: &PinholeCamera,
    ss: usize,
    first_row: usize,
    len: usize,
) -> Result<(), RenderError> {
    if !(1..=16).contains(&ss) {
        return Err(RenderError::Supersampling(ss));
    }
    // The camera's fields are public, so its size is checked here too.
    let (width, height) = (camera.width_px, camera.height_px);
    if width == 0 || height == 0 {
        return Err(FrameError::Empty { width, height }.into());
    }
    let rows = len / width;
    if !len.is_multiple_of(width) || first_row + rows > height {
        return Err(RenderError::RowBuffer {
            width,
            height,
            first_row,
            len,
        });
    }
    Ok(())
}

/// What every row of one [`render_rows`] call shares: the camera and its rays in the world,
/// the supersampling pattern, and each column's normalised x.
struct FrameRays<'a> {
    camera: &'a PinholeCamera,
    scene: &'a Scene,
    /// The camera-to-world rotation: a sample's ray is `r · (x, y, 1)`.
    r: &'a Matrix3<f64>,
    origin: Vector3<f64>,
    undistorted: bool,
    /// Samples per pixel side, their offsets from the pixel's centre, and 1 / samples.
    ss: usize,
    offsets: Vec<f64>,
    inv_samples: f32,
    width: usize,
    /// The ground's depth below the camera, for the fast path.
    ground_height_m: f64,
    /// Each column's normalised x (the same in every row), for the fast path.
    column_x: Vec<f64>,
}

impl<'a> FrameRays<'a> {
    #[inline(always)]
    fn new(
        camera: &'a PinholeCamera,
        scene: &'a Scene,
        r: &'a Matrix3<f64>,
        origin: Vector3<f64>,
        ss: usize,
    ) -> Self {
        let width = camera.width_px;
        let undistorted = camera.distortion.is_zero();
        let inv_samples = 1.0 / (ss * ss) as f32;
        let offsets: Vec<f64> = (0..ss)
            .map(|i| (i as f64 + 0.5) / ss as f64 - 0.5)
            .collect();
        let ground_height_m = scene.ground_down_m - origin.z;
        let column_x: Vec<f64> = (0..width)
            .map(|col| (col as f64 - camera.cx_px) / camera.fx_px)
            .collect();
        Self {
            camera,
            scene,
            r,
            origin,
            undistorted,
            ss,
            offsets,
            inv_samples,
            width,
            ground_height_m,
            column_x,
        }
    }

    /// The normalised y of the row's first and last sample row (without distortion).
    #[inline(always)]
    fn row_y_span(&self, row: usize) -> (f64, f64) {
        let camera = self.camera;
        let (offsets, ss) = (&self.offsets, self.ss);
        (
            (row as f64 + offsets[0] - camera.cy_px) / camera.fy_px,
            (row as f64 + offsets[ss - 1] - camera.cy_px) / camera.fy_px,
        )
    }

    /// Without distortion: the row's columns as `runs` in order, each marked with whether it
    /// may meet one of the row's `candidates` (`patch_spans` is scratch space).
    #[inline(always)]
    fn column_runs(
        &self,
        candidates: &[&PreparedPatch<'_>],
        row_y0: f64,
        patch_spans: &mut Vec<(usize, usize)>,
        runs: &mut Vec<(std::ops::Range<usize>, bool)>,
    ) {
        let (camera, offsets, ss, width) = (self.camera, &self.offsets, self.ss, self.width);
        patch_spans.clear();
        for p in candidates {
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
        for &(first, last) in patch_spans.iter() {
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
    }

    /// The fast path (one sample per pixel, no distortion): every pixel's ray meets the ground
    /// at a point that is a plain function of its column (ray(x) = c0 + x·c1 in the row), so
    /// the row's ground points are computed and the background sampled at them in one pass
    /// each, into `row_out`.
    #[inline(always)]
    fn draw_row_as_ground(
        &self,
        row: usize,
        ground_points: &mut [[f64; 2]],
        ground_values: &mut [f32],
        row_out: &mut [f32],
    ) {
        let (camera, r, origin, scene) = (self.camera, self.r, &self.origin, self.scene);
        let ground_height_m = self.ground_height_m;
        let y_row = (row as f64 - camera.cy_px) / camera.fy_px;
        let c0 = [
            r[(0, 1)] * y_row + r[(0, 2)],
            r[(1, 1)] * y_row + r[(1, 2)],
            r[(2, 1)] * y_row + r[(2, 2)],
        ];
        let c1 = [r[(0, 0)], r[(1, 0)], r[(2, 0)]];
        for (point, &x) in ground_points.iter_mut().zip(&self.column_x) {
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
        scene.background.sample_many(ground_points, ground_values);
        // The whole row as ground (or sky), in a pass with no branches to vectorise; the
        // columns that may see a patch are drawn again by the caller.
        for ((out, point), &value) in row_out
            .iter_mut()
            .zip(ground_points.iter())
            .zip(ground_values.iter())
        {
            *out = if point[0].is_nan() { scene.sky } else { value }.clamp(0.0, 1.0);
        }
    }

    /// The intensity of pixel (`col`, `row`): the mean of its samples, each meeting one of
    /// `candidates`, the ground or the sky.
    #[inline(always)]
    fn pixel_intensity(&self, candidates: &[&PreparedPatch<'_>], col: usize, row: usize) -> f32 {
        let (camera, r, scene) = (self.camera, self.r, self.scene);
        let undistorted = self.undistorted;
        let mut sum = 0f32;
        // The background is texture, not truth: it is sampled once per pixel, at the
        // centroid of the samples that see it, which makes supersampling cost little
        // more than the patches' edges need. Patches are sampled at every sample.
        let (mut ground_n, mut ground_e, mut ground_samples) = (0.0, 0.0, 0u32);
        for &dv in &self.offsets {
            for &du in &self.offsets {
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
                match self.shade(candidates, x, y, ray) {
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
        sum * self.inv_samples
    }

    /// A sample sees a patch's texture or the sky (`Ok`), or the ground at world (north, east)
    /// (`Err`).
    #[inline(always)]
    fn shade(
        &self,
        candidates: &[&PreparedPatch<'_>],
        x: f64,
        y: f64,
        ray: Vector3<f64>,
    ) -> Result<f32, (f64, f64)> {
        let (origin, scene) = (&self.origin, self.scene);
        match nearest_hit(candidates, x, y, &ray, origin, scene.ground_down_m) {
            Hit::Patch { patch, u, v, .. } => Ok(patch.texture.sample(u, v)),
            Hit::Ground { t } => Err((origin.x + ray.x * t, origin.y + ray.y * t)),
            Hit::Nothing => Ok(scene.sky),
        }
    }
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

#[cfg(test)]
mod tests;
