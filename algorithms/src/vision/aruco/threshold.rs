//! Adaptive threshold: a pixel is dark where it is darker than the mean of the window around it
//! by more than a constant, so markers read the same under uneven light.

use crate::vision::image::ImageView;

/// How the window means are computed. Both give the same binary image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ThresholdMethod {
    /// Window sums from an integral image: four reads per pixel whatever the window.
    #[default]
    IntegralImage,
    /// Every window summed pixel by pixel: the slow reference the benchmark compares against.
    NaiveWindowMean,
}

/// A rectangle of the frame in pixels: columns `x..x + width`, rows `y..y + height`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelRect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

/// Dark (1) / not dark (0) pixels of a rectangle of the frame, with a one-pixel ring of 0 around
/// it so that contour following never needs a bounds check.
#[derive(Debug, Default)]
pub(crate) struct BinaryImage {
    pub width: usize,
    pub height: usize,
    /// Row length of `data`: `width + 2`.
    pub stride: usize,
    pub data: Vec<u8>,
}

impl BinaryImage {
    fn reset(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.stride = width + 2;
        self.data.clear();
        self.data.resize(self.stride * (height + 2), 0);
    }

    /// Index of pixel (x, y) of the rectangle (−1 and `width` / `height` are the zero ring).
    #[inline]
    pub fn index(&self, x: isize, y: isize) -> usize {
        ((y + 1) as usize) * self.stride + (x + 1) as usize
    }

    #[cfg(test)]
    pub fn is_dark(&self, x: usize, y: usize) -> bool {
        self.data[(y + 1) * self.stride + x + 1] == 1
    }
}

/// Reusable buffers of the threshold.
#[derive(Debug, Default)]
pub(crate) struct ThresholdScratch {
    integral: Vec<u32>,
}

/// Marks the pixels of `rect` that are darker than their `window_px`×`window_px` mean (clipped
/// at the rectangle's edges) minus `offset`. `rect` must lie inside `image`; `window_px` is odd.
pub(crate) fn adaptive_threshold(
    image: &ImageView<'_>,
    rect: PixelRect,
    window_px: usize,
    offset: u8,
    method: ThresholdMethod,
    scratch: &mut ThresholdScratch,
    out: &mut BinaryImage,
) {
    out.reset(rect.width, rect.height);
    match method {
        ThresholdMethod::IntegralImage => {
            integral_threshold(image, rect, window_px / 2, offset, scratch, out)
        }
        ThresholdMethod::NaiveWindowMean => {
            naive_threshold(image, rect, window_px / 2, offset, out)
        }
    }
}

fn integral_threshold(
    image: &ImageView<'_>,
    rect: PixelRect,
    radius: usize,
    offset: u8,
    scratch: &mut ThresholdScratch,
    out: &mut BinaryImage,
) {
    let (w, h) = (rect.width, rect.height);
    let iw = w + 1;
    let span = 2 * radius + 1;
    // Only the integral image's rows y − r and y + r + 1 are read at row y, so a ring of
    // span + 1 rows holds all that is needed and stays in cache.
    let ring = span + 1;
    let integral = &mut scratch.integral;
    integral.clear();
    integral.resize(iw * ring, 0);
    // Integral rows 0..next are computed; row j lives in slot j % ring. Row 0 is all zeros.
    let mut next = 1;
    let offset = u32::from(offset);
    for y in 0..h {
        let y0 = y.saturating_sub(radius);
        let y1 = (y + radius).min(h - 1);
        while next <= y1 + 1 {
            // Sums wrap in u32: a window's sum is below 2³² for any window under 16 M pixels,
            // and wrapping differences of wrapped prefix sums are exact below that.
            let src = &image.row(rect.y + next - 1)[rect.x..rect.x + w];
            let (prev_slot, slot) = ((next - 1) % ring, next % ring);
            let (above, current) = if prev_slot < slot {
                let (lo, hi) = integral.split_at_mut(slot * iw);
                (&lo[prev_slot * iw..(prev_slot + 1) * iw], &mut hi[..iw])
            } else {
                let (lo, hi) = integral.split_at_mut(prev_slot * iw);
                (&hi[..iw], &mut lo[slot * iw..(slot + 1) * iw])
            };
            let mut row_sum = 0u32;
            for ((cell, &up), &pixel) in current[1..].iter_mut().zip(&above[1..]).zip(src) {
                row_sum = row_sum.wrapping_add(u32::from(pixel));
                *cell = up.wrapping_add(row_sum);
            }
            next += 1;
        }
        let (top_slot, bottom_slot) = (y0 % ring, (y1 + 1) % ring);
        let top = &integral[top_slot * iw..(top_slot + 1) * iw];
        let bottom = &integral[bottom_slot * iw..(bottom_slot + 1) * iw];
        let rows = (y1 - y0 + 1) as u32;
        let src = &image.row(rect.y + y)[rect.x..rect.x + w];
        let dst_start = (y + 1) * out.stride + 1;
        let dst = &mut out.data[dst_start..dst_start + w];
        let clipped = |x: usize| {
            let x0 = x.saturating_sub(radius);
            let x1 = (x + radius).min(w - 1);
            let sum = bottom[x1 + 1]
                .wrapping_sub(bottom[x0])
                .wrapping_sub(top[x1 + 1])
                .wrapping_add(top[x0]);
            let area = rows * (x1 - x0 + 1) as u32;
            // pixel < mean − offset, without a division.
            u8::from((u32::from(src[x]) + offset) * area < sum)
        };
        if w <= span {
            for (x, d) in dst.iter_mut().enumerate() {
                *d = clipped(x);
            }
            continue;
        }
        for x in (0..radius).chain(w - radius..w) {
            dst[x] = clipped(x);
        }
        // Away from the left and right edges every window is whole: one area, no clipping, and
        // a loop the compiler vectorises.
        let area = rows * span as u32;
        let interior = w - 2 * radius;
        let sums = bottom[span..span + interior]
            .iter()
            .zip(&bottom[..interior])
            .zip(top[span..span + interior].iter().zip(&top[..interior]));
        for ((d, &p), ((&b_hi, &b_lo), (&t_hi, &t_lo))) in dst[radius..w - radius]
            .iter_mut()
            .zip(&src[radius..w - radius])
            .zip(sums)
        {
            let sum = b_hi
                .wrapping_sub(b_lo)
                .wrapping_sub(t_hi)
                .wrapping_add(t_lo);
            *d = u8::from((u32::from(p) + offset) * area < sum);
        }
    }
}

fn naive_threshold(
    image: &ImageView<'_>,
    rect: PixelRect,
    radius: usize,
    offset: u8,
    out: &mut BinaryImage,
) {
    let (w, h) = (rect.width, rect.height);
    let offset = u32::from(offset);
    for y in 0..h {
        let y0 = y.saturating_sub(radius);
        let y1 = (y + radius).min(h - 1);
        for x in 0..w {
            let x0 = x.saturating_sub(radius);
            let x1 = (x + radius).min(w - 1);
            let mut sum = 0u32;
            for wy in y0..=y1 {
                let row = image.row(rect.y + wy);
                for wx in x0..=x1 {
                    sum += u32::from(row[rect.x + wx]);
                }
            }
            let area = ((y1 - y0 + 1) * (x1 - x0 + 1)) as u32;
            let pixel = u32::from(image.get(rect.x + x, rect.y + y));
            out.data[(y + 1) * out.stride + x + 1] = u8::from((pixel + offset) * area < sum);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::image::GrayImage;

    fn pseudo_random_image(width: usize, height: usize, seed: u32) -> GrayImage {
        let mut state = seed;
        let data = (0..width * height)
            .map(|i| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                // A gradient plus noise, so that windows differ.
                ((i % width) as u32 / 3 + (state >> 26)) as u8
            })
            .collect();
        GrayImage::from_vec(width, height, data).unwrap()
    }

    #[test]
    fn integral_and_naive_agree_everywhere() {
        let image = pseudo_random_image(53, 31, 7);
        let rect = PixelRect {
            x: 4,
            y: 3,
            width: 41,
            height: 25,
        };
        for window_px in [3, 7, 15, 61] {
            let mut fast = BinaryImage::default();
            let mut slow = BinaryImage::default();
            let mut scratch = ThresholdScratch::default();
            let view = image.view();
            let integral = ThresholdMethod::IntegralImage;
            let naive = ThresholdMethod::NaiveWindowMean;
            adaptive_threshold(&view, rect, window_px, 3, integral, &mut scratch, &mut fast);
            adaptive_threshold(&view, rect, window_px, 3, naive, &mut scratch, &mut slow);
            assert_eq!(fast.data, slow.data, "window {window_px}");
            assert!(fast.data.contains(&1));
            assert!(fast.data.contains(&0));
        }
    }

    #[test]
    fn a_dark_square_on_white_is_dark_and_the_ring_stays_clear() {
        let mut image = GrayImage::filled(20, 20, 200).unwrap();
        for y in 5..10 {
            for x in 5..10 {
                image.set(x, y, 20);
            }
        }
        let rect = PixelRect {
            x: 0,
            y: 0,
            width: 20,
            height: 20,
        };
        let mut out = BinaryImage::default();
        let mut scratch = ThresholdScratch::default();
        let method = ThresholdMethod::IntegralImage;
        adaptive_threshold(&image.view(), rect, 7, 5, method, &mut scratch, &mut out);
        assert!(out.is_dark(5, 5) && out.is_dark(9, 9) && out.is_dark(7, 7));
        assert!(!out.is_dark(4, 5) && !out.is_dark(10, 10) && !out.is_dark(0, 0));
        assert_eq!(out.data[0], 0);
        assert_eq!(out.data.len(), 22 * 22);
    }
}
