//! Grayscale images as the detectors see them: 8-bit, row-major, with a row stride so a camera's
//! padded buffers can be read in place; and depth images as a stereo camera delivers them.

use thiserror::Error;

/// A camera frame that cannot be read as the size and layout it claims.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum FrameError {
    #[error("the frame is empty ({width}×{height} pixels)")]
    Empty { width: usize, height: usize },
    #[error("row stride {stride} is shorter than the width {width}")]
    StrideTooShort { width: usize, stride: usize },
    #[error("a {width}×{height} frame with stride {stride} needs {needed} bytes, the buffer has {found}")]
    BufferTooShort {
        width: usize,
        height: usize,
        stride: usize,
        needed: usize,
        found: usize,
    },
    #[error("expected a {expected_width}×{expected_height} frame, got {width}×{height}")]
    WrongSize {
        expected_width: usize,
        expected_height: usize,
        width: usize,
        height: usize,
    },
    #[error("a {width}×{height} depth image needs {needed} values, got {found}")]
    DepthLength {
        width: usize,
        height: usize,
        needed: usize,
        found: usize,
    },
}

/// A borrowed grayscale image: `height` rows of `width` pixels, rows `stride` bytes apart.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    width: usize,
    height: usize,
    stride: usize,
    data: &'a [u8],
}

impl<'a> ImageView<'a> {
    /// Checks that `data` holds a `width`×`height` image with rows `stride` bytes apart.
    pub fn new(
        width: usize,
        height: usize,
        stride: usize,
        data: &'a [u8],
    ) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        if stride < width {
            return Err(FrameError::StrideTooShort { width, stride });
        }
        // The last row needs only `width` bytes, not a whole stride.
        let needed = stride
            .checked_mul(height - 1)
            .and_then(|n| n.checked_add(width))
            .unwrap_or(usize::MAX);
        if data.len() < needed {
            return Err(FrameError::BufferTooShort {
                width,
                height,
                stride,
                needed,
                found: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            stride,
            data,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Row `y` (`width` pixels).
    pub fn row(&self, y: usize) -> &'a [u8] {
        let start = y * self.stride;
        &self.data[start..start + self.width]
    }

    /// Pixel at (x, y); x, y must be inside the image.
    pub fn get(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.stride + x]
    }

    /// Fails unless the image is `width`×`height`.
    pub fn expect_size(&self, width: usize, height: usize) -> Result<(), FrameError> {
        if (self.width, self.height) == (width, height) {
            Ok(())
        } else {
            Err(FrameError::WrongSize {
                expected_width: width,
                expected_height: height,
                width: self.width,
                height: self.height,
            })
        }
    }

    /// The image at half the resolution: each pixel the rounded mean of a 2×2 block (an odd
    /// last row or column is left out), so that pixel k covers pixels 2k and 2k + 1. `None`
    /// for an image less than 2 pixels wide or high.
    pub fn half_resolution(&self) -> Option<GrayImage> {
        let (width, height) = (self.width / 2, self.height / 2);
        if width == 0 || height == 0 {
            return None;
        }
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            let (top, bottom) = (self.row(2 * y), self.row(2 * y + 1));
            data.extend(
                top.chunks_exact(2)
                    .zip(bottom.chunks_exact(2))
                    .map(|(t, b)| {
                        let sum =
                            u16::from(t[0]) + u16::from(t[1]) + u16::from(b[0]) + u16::from(b[1]);
                        ((sum + 2) / 4) as u8
                    }),
            );
        }
        Some(GrayImage {
            width,
            height,
            data,
        })
    }

    /// A tightly packed copy.
    pub fn to_owned(&self) -> GrayImage {
        let mut data = Vec::with_capacity(self.width * self.height);
        for y in 0..self.height {
            data.extend_from_slice(self.row(y));
        }
        GrayImage {
            width: self.width,
            height: self.height,
            data,
        }
    }
}

/// An owned, tightly packed grayscale image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GrayImage {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl GrayImage {
    /// A `width`×`height` image filled with `value`.
    pub fn filled(width: usize, height: usize, value: u8) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        Ok(Self {
            width,
            height,
            data: vec![value; width * height],
        })
    }

    /// Takes a tightly packed buffer of `width`×`height` pixels.
    pub fn from_vec(width: usize, height: usize, data: Vec<u8>) -> Result<Self, FrameError> {
        ImageView::new(width, height, width, &data)?;
        if data.len() != width * height {
            return Err(FrameError::BufferTooShort {
                width,
                height,
                stride: width,
                needed: width * height,
                found: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn view(&self) -> ImageView<'_> {
        ImageView {
            width: self.width,
            height: self.height,
            stride: self.width,
            data: &self.data,
        }
    }

    pub fn data(&self) -> &[u8] {
        &self.data
    }

    pub fn data_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }

    pub fn get(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }

    pub fn set(&mut self, x: usize, y: usize, value: u8) {
        self.data[y * self.width + x] = value;
    }
}

/// Whether a depth value is a measurement: finite and positive (NaN, ±∞, 0 and negative values
/// mean "no depth": a hole, the sky, out of range).
pub fn is_valid_depth(depth_m: f32) -> bool {
    depth_m.is_finite() && depth_m > 0.0
}

/// A depth image: metres along the optical axis (the camera's z, not the ray's length),
/// row-major, tightly packed; see [`is_valid_depth`] for what counts as no depth. The
/// renderer's [`crate::vision::render::render_depth`] makes exact ones; a stereo camera makes
/// noisy ones ([`crate::estimation::stereo_altitude`] reads them).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    width: usize,
    height: usize,
    depth_m: Vec<f32>,
}

impl DepthImage {
    /// Takes `width × height` depths, row-major.
    pub fn from_vec(width: usize, height: usize, depth_m: Vec<f32>) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        let needed = width.saturating_mul(height);
        if depth_m.len() != needed {
            return Err(FrameError::DepthLength {
                width,
                height,
                needed,
                found: depth_m.len(),
            });
        }
        Ok(Self {
            width,
            height,
            depth_m,
        })
    }

    /// A `width × height` image of one depth everywhere (NaN for an image with no depth).
    pub fn filled(width: usize, height: usize, depth_m: f32) -> Result<Self, FrameError> {
        Self::from_vec(width, height, vec![depth_m; width.saturating_mul(height)])
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Depth at (x, y), metres; x, y must be inside the image.
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.depth_m[y * self.width + x]
    }

    pub fn set(&mut self, x: usize, y: usize, depth_m: f32) {
        self.depth_m[y * self.width + x] = depth_m;
    }

    /// Row `y` (`width` depths).
    pub fn row(&self, y: usize) -> &[f32] {
        &self.depth_m[y * self.width..(y + 1) * self.width]
    }

    pub fn data(&self) -> &[f32] {
        &self.depth_m
    }

    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.depth_m
    }

    /// How many pixels hold a valid depth.
    pub fn valid_count(&self) -> usize {
        self.depth_m.iter().filter(|&&z| is_valid_depth(z)).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_images_check_their_size_and_count_valid_pixels() {
        let mut depth =
            DepthImage::from_vec(3, 2, vec![1.0, f32::NAN, 0.0, -2.0, 4.0, 5.5]).unwrap();
        assert_eq!(depth.valid_count(), 3);
        assert_eq!(depth.row(1), &[-2.0, 4.0, 5.5]);
        depth.set(1, 0, 2.0);
        assert_eq!(depth.get(1, 0), 2.0);
        assert_eq!(depth.valid_count(), 4);
        assert!(!is_valid_depth(f32::INFINITY));
        assert_eq!(
            DepthImage::from_vec(3, 2, vec![1.0; 5]).unwrap_err(),
            FrameError::DepthLength {
                width: 3,
                height: 2,
                needed: 6,
                found: 5
            }
        );
        assert!(matches!(
            DepthImage::filled(0, 4, 1.0),
            Err(FrameError::Empty { .. })
        ));
        assert_eq!(DepthImage::filled(4, 4, f32::NAN).unwrap().valid_count(), 0);
    }

    #[test]
    fn views_respect_the_stride() {
        // 3×2 image in rows of 4 bytes; the padding byte must never be read as a pixel.
        let data = [1, 2, 3, 99, 4, 5, 6];
        let view = ImageView::new(3, 2, 4, &data).unwrap();
        assert_eq!(view.row(1), &[4, 5, 6]);
        assert_eq!(view.get(2, 1), 6);
        assert_eq!(view.to_owned().data(), &[1, 2, 3, 4, 5, 6]);
    }

    #[test]
    fn half_resolution_averages_blocks_and_drops_an_odd_edge() {
        // 5×3 in rows of 6 bytes: the last column, the last row and the padding never count.
        let data = [
            0, 1, 10, 10, 7, 99, //
            2, 2, 10, 11, 7, 99, //
            9, 9, 9, 9, 9, 99,
        ];
        let half = ImageView::new(5, 3, 6, &data)
            .unwrap()
            .half_resolution()
            .unwrap();
        assert_eq!((half.width(), half.height()), (2, 1));
        // (0 + 1 + 2 + 2) / 4 = 1.25 and (10 + 10 + 10 + 11) / 4 = 10.25, to the nearest.
        assert_eq!(half.data(), &[1, 10]);
        // 1.75 rounds to 2.
        let rounds_up = [1, 2, 2, 2];
        let half = ImageView::new(2, 2, 2, &rounds_up)
            .unwrap()
            .half_resolution();
        assert_eq!(half.unwrap().data(), &[2]);
        let white = [255; 4];
        let half = ImageView::new(2, 2, 2, &white).unwrap().half_resolution();
        assert_eq!(half.unwrap().data(), &[255]);
        assert!(ImageView::new(1, 4, 1, &[0; 4])
            .unwrap()
            .half_resolution()
            .is_none());
    }

    #[test]
    fn bad_layouts_are_named_errors() {
        let data = [0u8; 10];
        assert_eq!(
            ImageView::new(0, 2, 4, &data).unwrap_err(),
            FrameError::Empty {
                width: 0,
                height: 2
            }
        );
        assert_eq!(
            ImageView::new(4, 2, 3, &data).unwrap_err(),
            FrameError::StrideTooShort {
                width: 4,
                stride: 3
            }
        );
        assert!(matches!(
            ImageView::new(4, 3, 4, &data),
            Err(FrameError::BufferTooShort {
                needed: 12,
                found: 10,
                ..
            })
        ));
        let view = ImageView::new(2, 2, 2, &data).unwrap();
        assert!(matches!(
            view.expect_size(640, 480),
            Err(FrameError::WrongSize { .. })
        ));
        assert!(GrayImage::from_vec(3, 3, vec![0; 8]).is_err());
    }
}
