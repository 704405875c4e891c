//! A rendered frame developed as the sensor records it: motion blur along the vehicle's motion,
//! the exposure's drift and the sensor's noise, row by row on the thread pool.

use algorithms::vision::image::GrayImage;
use algorithms::vision::render::{ImageEffects, MotionBlur, RenderError, SplitMix64};

use super::in_bands;

/// The camera's effects on a rendered frame (intensities 0 to 1), in the renderer's order
/// (motion blur, contrast and brightness, noise) and with its formulas, but written for speed:
/// the blur adds whole shifted rows, and the noise is read from a table of Gaussian samples
/// (see [`develop_rows`]) instead of drawn per pixel, each row from a generator of its own so
/// bands of rows go to threads and give the same frame. Gaussian blur is not used by the camera
/// and is refused.
pub(super) fn post_process(
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
