//! Colour histograms as the tracker's appearance model (seed 000, equation 4): one histogram of
//! 25 bins per channel over a detection's box, the channels concatenated (75 values for RGB, 25
//! for a gray camera) and L1-normalised, compared by histogram intersection.

use thiserror::Error;

use super::iou::PixelBox;
use crate::vision::image::ImageView;
use crate::vision::rgb::RgbImage;

/// Bins per channel, as in the seed.
pub const BINS_PER_CHANNEL: usize = 25;

/// A histogram that cannot be computed or compared.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HistogramError {
    #[error(
        "the box x {x_min}..{x_max}, y {y_min}..{y_max} px holds no pixel centre of the \
         {width}×{height} image"
    )]
    EmptyBox {
        x_min: f64,
        y_min: f64,
        x_max: f64,
        y_max: f64,
        width: usize,
        height: usize,
    },
    #[error("a histogram of {a} channels cannot be compared with one of {b}")]
    ChannelMismatch { a: usize, b: usize },
}

/// The L1-normalised concatenated channel histograms of a box (the seed's c_i).
#[derive(Debug, Clone, PartialEq)]
pub struct ColourHistogram {
    channels: usize,
    /// `channels × BINS_PER_CHANNEL` values summing to 1, channel-major.
    bins: Vec<f64>,
}

/// The bin of an 8-bit value: 25 equal bins over 0–255.
pub fn bin_of(value: u8) -> usize {
    value as usize * BINS_PER_CHANNEL / 256
}

/// Pixel columns (or rows) whose centres c satisfy `min ≤ c < max`, clipped to `0..len`;
/// `None` when none do.
fn centres_in(min: f64, max: f64, len: usize) -> Option<std::ops::Range<usize>> {
    if !(min.is_finite() && max.is_finite()) {
        return None;
    }
    let start = min.ceil().max(0.0);
    let end = max.ceil().min(len as f64);
    (start < end).then_some(start as usize..end as usize)
}

impl ColourHistogram {
    /// The 75-bin RGB histogram of the pixels whose centres lie in `bbox` (clipped to the image).
    pub fn of_rgb_box(image: &RgbImage, bbox: &PixelBox) -> Result<Self, HistogramError> {
        let (xs, ys) = Self::pixel_ranges(bbox, image.width(), image.height())?;
        let mut bins = vec![0.0; 3 * BINS_PER_CHANNEL];
        for y in ys {
            for x in xs.clone() {
                for (channel, &value) in image.get(x, y).iter().enumerate() {
                    bins[channel * BINS_PER_CHANNEL + bin_of(value)] += 1.0;
                }
            }
        }
        Ok(Self::normalised(3, bins))
    }

    /// The 25-bin histogram of a gray image's pixels whose centres lie in `bbox`.
    pub fn of_gray_box(image: &ImageView<'_>, bbox: &PixelBox) -> Result<Self, HistogramError> {
        let (xs, ys) = Self::pixel_ranges(bbox, image.width(), image.height())?;
        let mut bins = vec![0.0; BINS_PER_CHANNEL];
        for y in ys {
            for &value in &image.row(y)[xs.clone()] {
                bins[bin_of(value)] += 1.0;
            }
        }
        Ok(Self::normalised(1, bins))
    }

    fn pixel_ranges(
        bbox: &PixelBox,
        width: usize,
        height: usize,
    ) -> Result<(std::ops::Range<usize>, std::ops::Range<usize>), HistogramError> {
        let xs = centres_in(bbox.x_min, bbox.x_max, width);
        let ys = centres_in(bbox.y_min, bbox.y_max, height);
        match (xs, ys) {
            (Some(xs), Some(ys)) => Ok((xs, ys)),
            _ => Err(HistogramError::EmptyBox {
                x_min: bbox.x_min,
                y_min: bbox.y_min,
                x_max: bbox.x_max,
                y_max: bbox.y_max,
                width,
                height,
            }),
        }
    }

    fn normalised(channels: usize, mut bins: Vec<f64>) -> Self {
        let total: f64 = bins.iter().sum();
        // Callers only build from non-empty boxes, so the total is positive.
        bins.iter_mut().for_each(|b| *b /= total);
        Self { channels, bins }
    }

    /// 3 for RGB, 1 for gray.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// The normalised bins, channel-major, summing to 1.
    pub fn bins(&self) -> &[f64] {
        &self.bins
    }

    /// Histogram intersection Σ_k min(c_i^k, c_j^k), in [0, 1]: 1 for identical histograms.
    pub fn intersection(&self, other: &Self) -> Result<f64, HistogramError> {
        if self.channels != other.channels {
            return Err(HistogramError::ChannelMismatch {
                a: self.channels,
                b: other.channels,
            });
        }
        let sum: f64 = self
            .bins
            .iter()
            .zip(&other.bins)
            .map(|(a, b)| a.min(*b))
            .sum();
        Ok(sum.clamp(0.0, 1.0))
    }

    /// The colour dissimilarity `s_colour = 1 − Σ min(c_i^k, c_j^k)`, in [0, 1] (equation 4).
    pub fn dissimilarity(&self, other: &Self) -> Result<f64, HistogramError> {
        Ok(1.0 - self.intersection(other)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::image::GrayImage;

    #[test]
    fn bins_split_0_to_255_into_25_equal_parts() {
        // Bin k covers [256k/25, 256(k+1)/25): 10.24 wide.
        assert_eq!(bin_of(0), 0);
        assert_eq!(bin_of(10), 0);
        assert_eq!(bin_of(11), 1);
        assert_eq!(bin_of(128), 12);
        assert_eq!(bin_of(255), 24);
    }

    #[test]
    fn an_rgb_box_counts_its_pixels_per_channel() {
        // 4×2 image: the left 2×2 pure red, the right 2×2 (0, 128, 255).
        let mut image = RgbImage::filled(4, 2, [255, 0, 0]).unwrap();
        for y in 0..2 {
            for x in 2..4 {
                image.set(x, y, [0, 128, 255]);
            }
        }
        // Pixel centres 0..=3 and 0..=1 lie in [−0.5, 3.5) × [−0.5, 1.5).
        let whole = PixelBox {
            x_min: -0.5,
            y_min: -0.5,
            x_max: 3.5,
            y_max: 1.5,
        };
        let h = ColourHistogram::of_rgb_box(&image, &whole).unwrap();
        assert_eq!(h.channels(), 3);
        let mut expected = vec![0.0; 75];
        // 8 pixels × 3 channels = 24 counts. R: 4 at 255 (bin 24), 4 at 0. G: 4 at 0, 4 at 128
        // (bin 12). B: 4 at 0, 4 at 255.
        for (channel, bin) in [(0, 24), (0, 0), (1, 0), (1, 12), (2, 0), (2, 24)] {
            expected[channel * 25 + bin] = 4.0 / 24.0;
        }
        assert_eq!(h.bins(), expected.as_slice());

        // The left half alone, pure red, has R 24, G 0 and B 0 at 1/3 each; the whole box has
        // each of them at 1/6: Σ min = 3/6.
        let left = PixelBox {
            x_min: -0.5,
            y_min: -0.5,
            x_max: 1.5,
            y_max: 1.5,
        };
        let red = ColourHistogram::of_rgb_box(&image, &left).unwrap();
        assert!((red.intersection(&h).unwrap() - 0.5).abs() < 1e-12);
        assert!((red.dissimilarity(&h).unwrap() - 0.5).abs() < 1e-12);
        assert_eq!(red.dissimilarity(&red).unwrap(), 0.0);
        // The right half (R 0, G 12, B 24) shares no bin with pure red (R 24, G 0, B 0).
        let right = PixelBox {
            x_min: 1.5,
            y_min: -0.5,
            x_max: 3.5,
            y_max: 1.5,
        };
        let other = ColourHistogram::of_rgb_box(&image, &right).unwrap();
        assert!((red.dissimilarity(&other).unwrap() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn gray_histograms_agree_with_the_rgb_histogram_of_the_same_frame() {
        let data: Vec<u8> = (0..64u32).map(|i| (i * 37 % 256) as u8).collect();
        let gray = GrayImage::from_vec(8, 8, data).unwrap();
        let rgb = RgbImage::from_gray(&gray);
        let bbox = PixelBox::from_centre(3.0, 4.0, 5.0, 6.0);
        let g = ColourHistogram::of_gray_box(&gray.view(), &bbox).unwrap();
        let c = ColourHistogram::of_rgb_box(&rgb, &bbox).unwrap();
        assert_eq!(g.channels(), 1);
        assert!((g.bins().iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // Each RGB channel is the gray histogram scaled by 1/3.
        for channel in 0..3 {
            for k in 0..25 {
                assert!((c.bins()[channel * 25 + k] - g.bins()[k] / 3.0).abs() < 1e-12);
            }
        }
        // Independent count: the box covers pixel centres x 1..=5, y 1..=6, 30 pixels.
        let mut counts = [0usize; 25];
        for y in 1..=6 {
            for x in 1..=5 {
                counts[gray.get(x, y) as usize * 25 / 256] += 1;
            }
        }
        for (bin, count) in g.bins().iter().zip(counts) {
            assert!((bin - count as f64 / 30.0).abs() < 1e-12);
        }
        assert!(matches!(
            g.intersection(&c),
            Err(HistogramError::ChannelMismatch { a: 1, b: 3 })
        ));
    }

    #[test]
    fn boxes_are_clipped_and_empty_ones_are_errors() {
        let gray = GrayImage::filled(4, 4, 200).unwrap();
        let partly_out = PixelBox::from_centre(0.0, 0.0, 3.0, 3.0);
        let h = ColourHistogram::of_gray_box(&gray.view(), &partly_out).unwrap();
        assert_eq!(h.bins()[bin_of(200)], 1.0);
        let outside = PixelBox::from_centre(10.0, 10.0, 2.0, 2.0);
        assert!(matches!(
            ColourHistogram::of_gray_box(&gray.view(), &outside),
            Err(HistogramError::EmptyBox { width: 4, .. })
        ));
        let nan = PixelBox::from_centre(f64::NAN, 1.0, 2.0, 2.0);
        assert!(ColourHistogram::of_gray_box(&gray.view(), &nan).is_err());
        // Too thin to hold a pixel centre.
        let thin = PixelBox {
            x_min: 1.1,
            y_min: 0.0,
            x_max: 1.9,
            y_max: 3.0,
        };
        assert!(ColourHistogram::of_gray_box(&gray.view(), &thin).is_err());
    }
}
