//! The field's texture baked into tiles of texels, sampled bilinearly: the procedural field costs
//! too much to evaluate per ray.

use std::sync::{Arc, OnceLock};

use algorithms::vision::render::Texture;

/// Texel of the baked field: finer than the camera's ground sampling distance at the heights where
/// the field matters (1.35 cm a pixel at 7.5 m with the default camera), bilinear in between.
pub const FIELD_TEXEL_M: f64 = 0.02;
/// The baked part of the field reaches this far from the origin; beyond it the field repeats.
pub const FIELD_BAKED_HALF_EXTENT_M: f64 = 300.0;

/// Texels a tile side; a tile is baked on the first sample that falls in it.
pub(super) const TILE_TEXELS: usize = 64;

/// Points [`BakedTexture::sample_many`] takes at a time (stack buffers of a few kilobytes).
const SAMPLE_CHUNK: usize = 64;

/// A ground texture sampled on a grid of tiles, each computed once on first use and bilinearly
/// interpolated: a few nanoseconds a sample whatever the source costs, and memory only for the
/// tiles the camera has seen.
struct BakedTexture {
    source: Texture,
    texel_m: f64,
    texels_per_m: f64,
    limit_texels: f64,
    origin_m: [f64; 2],
    tiles_per_side: usize,
    /// Each tile holds (TILE_TEXELS + 1)² values: one texel of overlap, so interpolation never
    /// needs a neighbouring tile.
    tiles: Box<[OnceLock<Box<[f32]>>]>,
}

impl BakedTexture {
    fn sample(&self, north_m: f64, east_m: f64) -> f32 {
        match self.locate(north_m, east_m) {
            Some(texel) => self.interpolate(self.tile(texel.tile), &texel),
            None => self.source.sample(north_m, east_m),
        }
    }

    /// [`Self::sample`] at every point, [`SAMPLE_CHUNK`] points at a time: a chunk's texel
    /// coordinates, tiles and fractions are computed in branch-free passes the compiler
    /// vectorises, with one wrap into the baked square for the whole chunk (a tractor drives
    /// out of the square within minutes; wrapping each point was half a frame's time), and
    /// only the texel lookups stay one at a time. A chunk that is not all inside one
    /// repetition of the square (its edge, a point off the grid) takes the one-point path.
    fn sample_many(&self, points: &[[f64; 2]], out: &mut [f32]) {
        // The same arithmetic on every CPU (no fused multiply-adds), in wider vectors where
        // the CPU has them.
        pulp::Arch::new().dispatch(SampleMany {
            texture: self,
            points,
            out,
        });
    }

    #[inline(always)]
    fn sample_chunks(&self, points: &[[f64; 2]], out: &mut [f32]) {
        let stride = TILE_TEXELS + 1;
        let limit = self.limit_texels;
        let [origin_n, origin_e] = self.origin_m;
        let k = self.texels_per_m;
        let mut cached: (u32, &[f32]) = (u32::MAX, &[]);
        // Whole repetitions of the square subtracted from the points' texel coordinates.
        let mut wrap = [0.0f64; 2];
        let mut texel = [[0.0f64; SAMPLE_CHUNK]; 2];
        let mut tile = [0u32; SAMPLE_CHUNK];
        let mut offset = [0u32; SAMPLE_CHUNK];
        let mut fraction = [[0.0f32; SAMPLE_CHUNK]; 2];
        for (points, out) in points
            .chunks(SAMPLE_CHUNK)
            .zip(out.chunks_mut(SAMPLE_CHUNK))
        {
            let n = points.len().min(SAMPLE_CHUNK);
            let texel_coordinates = |wrap: [f64; 2], texel: &mut [[f64; SAMPLE_CHUNK]; 2]| {
                // False for NaN too.
                let mut inside = true;
                for (i, &[north_m, east_m]) in points.iter().enumerate() {
                    // Exact: the wrap is a whole number of texels (as `rem_euclid` in `locate`).
                    let (gn, ge) = (
                        (north_m - origin_n) * k - wrap[0],
                        (east_m - origin_e) * k - wrap[1],
                    );
                    texel[0][i] = gn;
                    texel[1][i] = ge;
                    inside &= (gn >= 0.0) & (gn < limit) & (ge >= 0.0) & (ge < limit);
                }
                inside
            };
            if !texel_coordinates(wrap, &mut texel) {
                let [north_m, east_m] = points[0];
                let raw = [(north_m - origin_n) * k, (east_m - origin_e) * k];
                if raw.iter().all(|g| g.is_finite()) {
                    wrap = raw.map(|g| (g / limit).floor() * limit);
                }
                if !texel_coordinates(wrap, &mut texel) {
                    for (&[north_m, east_m], value) in points.iter().zip(out.iter_mut()) {
                        *value = self.sample(north_m, east_m);
                    }
                    continue;
                }
            }
            // In range and not negative, so ⌊·⌋ is a whole number below 2^52: added to 2^52,
            // it is the low bits of the sum's representation. An `as` cast would check each
            // value for NaN and range, one lane at a time.
            const TWO_TO_52: f64 = 4_503_599_627_370_496.0;
            for i in 0..n {
                let (gn, ge) = (texel[0][i], texel[1][i]);
                let (floor_n, floor_e) = (gn.floor(), ge.floor());
                let (in_, ie) = (
                    (floor_n + TWO_TO_52).to_bits() as u32,
                    (floor_e + TWO_TO_52).to_bits() as u32,
                );
                let per_side = TILE_TEXELS as u32;
                tile[i] = (in_ / per_side) * self.tiles_per_side as u32 + ie / per_side;
                offset[i] = (in_ % per_side) * stride as u32 + ie % per_side;
                fraction[0][i] = (gn - floor_n) as f32;
                fraction[1][i] = (ge - floor_e) as f32;
            }
            for i in 0..n {
                if tile[i] != cached.0 {
                    cached = (tile[i], self.tile(tile[i] as usize));
                }
                let texel = Texel {
                    tile: tile[i] as usize,
                    offset: offset[i] as usize,
                    fraction_n: fraction[0][i],
                    fraction_e: fraction[1][i],
                };
                out[i] = self.interpolate(cached.1, &texel);
            }
        }
    }

    /// Where a point falls: its tile, the texel's offset in the tile, and the fractions
    /// between texels; `None` off the grid (not finite), where the source is sampled itself.
    fn locate(&self, north_m: f64, east_m: f64) -> Option<Texel> {
        let gn = (north_m - self.origin_m[0]) * self.texels_per_m;
        let ge = (east_m - self.origin_m[1]) * self.texels_per_m;
        let limit = self.limit_texels;
        if !(gn.is_finite() && ge.is_finite()) {
            return None;
        }
        // Beyond the baked square the field repeats: a tractor drives kilometres in a long
        // mission, and computing the field there would cost the renderer half its speed.
        // `rem_euclid` is a library fmod call; inside the square (nearly every sample) it is
        // the identity, so it is skipped there.
        let wrap = |g: f64| {
            if (0.0..limit).contains(&g) {
                g
            } else {
                g.rem_euclid(limit)
            }
        };
        let (gn, ge) = (wrap(gn), wrap(ge));
        if !(gn < limit && ge < limit) {
            return None;
        }
        // In range and not negative: truncation is ⌊·⌋, and u32 conversions are cheap.
        let (in_, ie) = (gn as u32 as usize, ge as u32 as usize);
        let (tn, te) = (in_ / TILE_TEXELS, ie / TILE_TEXELS);
        let tile = tn * self.tiles_per_side + te;
        (tile < self.tiles.len()).then(|| Texel {
            tile,
            offset: (in_ % TILE_TEXELS) * (TILE_TEXELS + 1) + ie % TILE_TEXELS,
            fraction_n: (gn - in_ as f64) as f32,
            fraction_e: (ge - ie as f64) as f32,
        })
    }

    /// A tile's values, baked on first use.
    fn tile(&self, index: usize) -> &[f32] {
        let (tile_n, tile_e) = (index / self.tiles_per_side, index % self.tiles_per_side);
        self.tiles[index].get_or_init(|| self.bake(tile_n, tile_e))
    }

    #[inline(always)]
    fn interpolate(&self, tile: &[f32], texel: &Texel) -> f32 {
        let stride = TILE_TEXELS + 1;
        // The offset is at most (TILE_TEXELS − 1)·(stride + 1), so the two rows the
        // interpolation needs are in the tile.
        let q = &tile[texel.offset..texel.offset + stride + 2];
        let fe = texel.fraction_e;
        let top = q[0] + (q[1] - q[0]) * fe;
        let bottom = q[stride] + (q[stride + 1] - q[stride]) * fe;
        top + (bottom - top) * texel.fraction_n
    }

    fn bake(&self, tile_n: usize, tile_e: usize) -> Box<[f32]> {
        let stride = TILE_TEXELS + 1;
        let mut values = Vec::with_capacity(stride * stride);
        for n in 0..stride {
            for e in 0..stride {
                let north_m = self.origin_m[0] + ((tile_n * TILE_TEXELS + n) as f64) * self.texel_m;
                let east_m = self.origin_m[1] + ((tile_e * TILE_TEXELS + e) as f64) * self.texel_m;
                values.push(self.source.sample(north_m, east_m));
            }
        }
        values.into_boxed_slice()
    }
}

/// [`BakedTexture::sample_many`]'s work, for [`pulp`] to compile for each instruction set.
struct SampleMany<'a> {
    texture: &'a BakedTexture,
    points: &'a [[f64; 2]],
    out: &'a mut [f32],
}

impl pulp::WithSimd for SampleMany<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        self.texture.sample_chunks(self.points, self.out);
    }
}

/// A point's place on the baked grid.
struct Texel {
    tile: usize,
    offset: usize,
    fraction_n: f32,
    fraction_e: f32,
}

/// `source` (a function of world north, east) baked lazily on a grid of `texel_m` texels over
/// the square of half-side `half_extent_m` around the origin, repeated periodically outside it. A bad
/// texel or extent (not finite, not positive) gives `source` itself.
pub fn baked_texture(source: Texture, texel_m: f64, half_extent_m: f64) -> Texture {
    if !(texel_m.is_finite() && texel_m > 0.0 && half_extent_m.is_finite() && half_extent_m > 0.0) {
        return source;
    }
    let tile_m = TILE_TEXELS as f64 * texel_m;
    let tiles_per_side = ((2.0 * half_extent_m / tile_m).ceil() as usize).clamp(1, 4096);
    let half_m = 0.5 * tiles_per_side as f64 * tile_m;
    let baked = Arc::new(BakedTexture {
        source,
        texel_m,
        texels_per_m: 1.0 / texel_m,
        limit_texels: (tiles_per_side * TILE_TEXELS) as f64,
        origin_m: [-half_m, -half_m],
        tiles_per_side,
        tiles: (0..tiles_per_side * tiles_per_side)
            .map(|_| OnceLock::new())
            .collect(),
    });
    let many = Arc::clone(&baked);
    Texture::from_fns(
        move |north_m, east_m| baked.sample(north_m, east_m),
        move |points, out| many.sample_many(points, out),
    )
}
