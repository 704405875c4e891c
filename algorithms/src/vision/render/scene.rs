//! What the renderer draws: textured patches on the ground plane, and the textures.

use std::f64::consts::PI;
use std::fmt;
use std::sync::Arc;

use nalgebra::Point3;

use super::{RenderError, SplitMix64};

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
    pub(super) fn axes(&self) -> ([f64; 2], [f64; 2]) {
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
