//! Colour images: 8-bit RGB, interleaved, row-major, tightly packed. The tracker's appearance
//! model (seed 000, equation 4) reads colour histograms from them; a gray camera's frames convert
//! losslessly (R = G = B).

use super::image::{FrameError, GrayImage};

/// An owned RGB image: `height` rows of `width` pixels, each pixel three bytes R, G, B.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RgbImage {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl RgbImage {
    /// Takes interleaved bytes `R G B R G B …`, exactly `3·width·height` of them.
    pub fn from_interleaved(
        width: usize,
        height: usize,
        data: Vec<u8>,
    ) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        let needed = width
            .checked_mul(height)
            .and_then(|n| n.checked_mul(3))
            .unwrap_or(usize::MAX);
        if data.len() != needed {
            return Err(FrameError::BufferTooShort {
                width,
                height,
                stride: width.saturating_mul(3),
                needed,
                found: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// A `width`×`height` image filled with one colour.
    pub fn filled(width: usize, height: usize, rgb: [u8; 3]) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        let data = rgb.repeat(width * height);
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// A gray frame as colour: every channel equals the gray level.
    pub fn from_gray(gray: &GrayImage) -> Self {
        let data = gray.data().iter().flat_map(|&g| [g, g, g]).collect();
        Self {
            width: gray.width(),
            height: gray.height(),
            data,
        }
    }

    /// Luma (ITU-R BT.601 weights 0.299, 0.587, 0.114), rounded.
    pub fn to_gray(&self) -> GrayImage {
        let data = self
            .data
            .chunks_exact(3)
            .map(|p| {
                let y = 0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64;
                y.round().clamp(0.0, 255.0) as u8
            })
            .collect();
        // The size was checked when this image was made, so the buffer fits.
        GrayImage::from_vec(self.width, self.height, data)
            .unwrap_or_else(|_| unreachable!("an RgbImage is never empty"))
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// The interleaved bytes.
    pub fn data(&self) -> &[u8] {
        &self.data
    }

    /// Pixel (x, y) as [R, G, B]; x, y must be inside the image.
    pub fn get(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Sets pixel (x, y); x, y must be inside the image.
    pub fn set(&mut self, x: usize, y: usize, rgb: [u8; 3]) {
        let i = 3 * (y * self.width + x);
        self.data[i..i + 3].copy_from_slice(&rgb);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interleaved_bytes_are_read_as_rgb_pixels() {
        // 2×1: a red pixel, then a blue one.
        let image = RgbImage::from_interleaved(2, 1, vec![255, 0, 0, 0, 0, 255]).unwrap();
        assert_eq!(image.get(0, 0), [255, 0, 0]);
        assert_eq!(image.get(1, 0), [0, 0, 255]);
        let gray = image.to_gray();
        // 0.299·255 = 76.2, 0.114·255 = 29.1.
        assert_eq!((gray.get(0, 0), gray.get(1, 0)), (76, 29));
    }

    #[test]
    fn gray_converts_both_ways_without_loss() {
        let gray = GrayImage::from_vec(3, 2, vec![0, 10, 20, 128, 200, 255]).unwrap();
        let rgb = RgbImage::from_gray(&gray);
        assert_eq!(rgb.get(1, 1), [200, 200, 200]);
        assert_eq!(rgb.to_gray(), gray);
    }

    #[test]
    fn bad_buffers_are_named_errors() {
        assert!(matches!(
            RgbImage::from_interleaved(0, 3, vec![]),
            Err(FrameError::Empty { .. })
        ));
        assert!(matches!(
            RgbImage::from_interleaved(2, 2, vec![0; 11]),
            Err(FrameError::BufferTooShort {
                needed: 12,
                found: 11,
                ..
            })
        ));
        let mut image = RgbImage::filled(2, 2, [1, 2, 3]).unwrap();
        image.set(1, 0, [9, 8, 7]);
        assert_eq!(image.data()[3..6], [9, 8, 7]);
    }
}
