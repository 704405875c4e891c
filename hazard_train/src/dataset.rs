//! The training set: frames rendered by `sim::hazard_dataset` from a range of seeds, kept in
//! memory as the network's input (exactly `letterbox_gray`'s output) with boxes in input pixels,
//! and batches cut from them as random grid-aligned crops with random flips.

use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

use algorithms::vision::render::SplitMix64;
use algorithms::vision::yolo::{letterbox_gray, PixelBox};
use candle_core::{Device, Tensor};
use sim::camera::SimCameraConfig;
use sim::hazard_dataset::{draw_situation, render_situation, DatasetError, LabelledFrame};
use sim::scene::HazardClass;
use thiserror::Error;

use crate::model::{INPUT_HEIGHT_PX, INPUT_WIDTH_PX, STRIDE_PX};
use crate::target::{assign, InputBox, TargetError, Targets};

#[derive(Debug, Error)]
pub enum SetError {
    #[error("rendering frame {seed}: {source}")]
    Render { seed: u64, source: DatasetError },
    #[error("a rendering thread panicked")]
    Thread,
    #[error("the crop must be a positive multiple of {STRIDE_PX} px no larger than {INPUT_WIDTH_PX}×{INPUT_HEIGHT_PX}, got {width_px}×{height_px}")]
    Crop { width_px: usize, height_px: usize },
    #[error("a batch needs at least one sample")]
    EmptyBatch,
    #[error(transparent)]
    Target(#[from] TargetError),
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// One frame as the network sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub seed: u64,
    /// [`INPUT_HEIGHT_PX`] rows of [`INPUT_WIDTH_PX`] values in [0, 1].
    pub input: Vec<f32>,
    /// Labels in input pixels.
    pub boxes: Vec<InputBox>,
    /// Hazards cut off at the frame's edge (see `LabelledFrame::cut_off`), input pixels: neither
    /// hazards nor background to the loss.
    pub ignore: Vec<PixelBox>,
    /// Camera height above the ground, metres.
    pub altitude_m: f64,
}

/// The class index the network uses: the position in [`HazardClass::ALL`].
pub fn class_index(class: HazardClass) -> usize {
    HazardClass::ALL
        .iter()
        .position(|&c| c == class)
        .unwrap_or_default()
}

impl Sample {
    /// The frame letterboxed as in flight; its boxes mapped into the input the same way.
    pub fn from_frame(seed: u64, frame: &LabelledFrame, altitude_m: f64) -> Self {
        let (input, letterbox) =
            letterbox_gray(&frame.image.view(), INPUT_WIDTH_PX, INPUT_HEIGHT_PX);
        let to_input = |b: &PixelBox| PixelBox {
            x_min: b.x_min * letterbox.scale + letterbox.pad_x_px,
            y_min: b.y_min * letterbox.scale + letterbox.pad_y_px,
            x_max: b.x_max * letterbox.scale + letterbox.pad_x_px,
            y_max: b.y_max * letterbox.scale + letterbox.pad_y_px,
        };
        let boxes = frame
            .labels
            .iter()
            .map(|l| InputBox {
                class_id: class_index(l.class),
                bbox: to_input(&l.bbox),
            })
            .collect();
        Self {
            seed,
            input,
            boxes,
            ignore: frame.cut_off.iter().map(|c| to_input(&c.bbox)).collect(),
            altitude_m,
        }
    }

    /// The labelled frame of `seed` with the simulator's default camera.
    pub fn render(seed: u64) -> Result<(Self, LabelledFrame), SetError> {
        let render = |seed| -> Result<_, DatasetError> {
            let situation = draw_situation(seed)?;
            let frame = render_situation(&situation, &SimCameraConfig::default(), None)?;
            Ok((frame, -situation.vehicle.position_ned_m.z))
        };
        let (frame, altitude_m) =
            render(seed).map_err(|source| SetError::Render { seed, source })?;
        Ok((Self::from_frame(seed, &frame, altitude_m), frame))
    }
}

/// Renders the frames of `seeds` on `threads` threads, in seed order; `progress` hears the count
/// done now and then.
pub fn render_samples(
    seeds: Range<u64>,
    threads: usize,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Vec<Sample>, SetError> {
    let seeds: Vec<u64> = seeds.collect();
    let done = AtomicUsize::new(0);
    let threads = threads.max(1);
    let parts: Vec<Result<Vec<(usize, Sample)>, SetError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|thread| {
                let (seeds, done) = (&seeds, &done);
                scope.spawn(move || {
                    let mut mine = Vec::new();
                    for index in (thread..seeds.len()).step_by(threads) {
                        let (sample, _) = Sample::render(seeds[index])?;
                        mine.push((index, sample));
                        let count = done.fetch_add(1, Ordering::Relaxed) + 1;
                        if count % 250 == 0 {
                            progress(count);
                        }
                    }
                    Ok(mine)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or(Err(SetError::Thread)))
            .collect()
    });
    let mut all = Vec::with_capacity(seeds.len());
    for part in parts {
        all.extend(part?);
    }
    all.sort_by_key(|(index, _)| *index);
    Ok(all.into_iter().map(|(_, s)| s).collect())
}

/// How training crops are cut.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CropConfig {
    pub width_px: usize,
    pub height_px: usize,
    /// Random horizontal and vertical flips (the hazards look the same mirrored).
    pub flips: bool,
}

impl CropConfig {
    pub fn validate(&self) -> Result<(), SetError> {
        let fits =
            |side: usize, max: usize| side > 0 && side.is_multiple_of(STRIDE_PX) && side <= max;
        if fits(self.width_px, INPUT_WIDTH_PX) && fits(self.height_px, INPUT_HEIGHT_PX) {
            Ok(())
        } else {
            Err(SetError::Crop {
                width_px: self.width_px,
                height_px: self.height_px,
            })
        }
    }
}

/// Where one crop lies in its sample's input and how it is flipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CropPlacement {
    pub x0_px: usize,
    pub y0_px: usize,
    pub flip_x: bool,
    pub flip_y: bool,
}

impl CropPlacement {
    /// A random placement on the grid (so cells line up with those of the whole input).
    pub fn random(config: &CropConfig, rng: &mut SplitMix64) -> Self {
        let mut pick = |span_px: usize| {
            let steps = (span_px / STRIDE_PX) as u64 + 1;
            (rng.next_u64() % steps) as usize * STRIDE_PX
        };
        let x0_px = pick(INPUT_WIDTH_PX - config.width_px);
        let y0_px = pick(INPUT_HEIGHT_PX - config.height_px);
        let bits = rng.next_u64();
        Self {
            x0_px,
            y0_px,
            flip_x: config.flips && bits & 1 == 1,
            flip_y: config.flips && bits & 2 == 2,
        }
    }
}

/// A crop's pixels (row-major), its labels and the boxes the loss ignores.
#[derive(Debug, Clone, PartialEq)]
pub struct Crop {
    pub pixels: Vec<f32>,
    pub boxes: Vec<InputBox>,
    pub ignore: Vec<PixelBox>,
}

/// A crop of `sample`: a label whose centre falls in the crop is cut to the crop — as the frame's
/// own labels are cut to the frame; one whose centre falls outside but that reaches into the crop
/// is ignored, as are the frame's own cut-off hazards.
pub fn crop(sample: &Sample, config: &CropConfig, at: &CropPlacement) -> Crop {
    let (width, height) = (config.width_px, config.height_px);
    let mut pixels = Vec::with_capacity(width * height);
    for y in 0..height {
        let source_y = at.y0_px + if at.flip_y { height - 1 - y } else { y };
        let row = &sample.input[source_y * INPUT_WIDTH_PX..(source_y + 1) * INPUT_WIDTH_PX];
        let row = &row[at.x0_px..at.x0_px + width];
        if at.flip_x {
            pixels.extend(row.iter().rev());
        } else {
            pixels.extend_from_slice(row);
        }
    }
    let (w, h) = (width as f64, height as f64);
    // Into crop coordinates, flipped and clipped to the crop.
    let place = |b: &PixelBox| {
        let mut x = [b.x_min - at.x0_px as f64, b.x_max - at.x0_px as f64];
        let mut y = [b.y_min - at.y0_px as f64, b.y_max - at.y0_px as f64];
        if at.flip_x {
            x = [w - x[1], w - x[0]];
        }
        if at.flip_y {
            y = [h - y[1], h - y[0]];
        }
        PixelBox {
            x_min: x[0].clamp(0.0, w),
            y_min: y[0].clamp(0.0, h),
            x_max: x[1].clamp(0.0, w),
            y_max: y[1].clamp(0.0, h),
        }
    };
    let (mut boxes, mut ignore) = (Vec::new(), Vec::new());
    for b in &sample.boxes {
        let (cx, cy) = b.bbox.centre();
        let (cx, cy) = (cx - at.x0_px as f64, cy - at.y0_px as f64);
        let placed = place(&b.bbox);
        if cx >= 0.0 && cy >= 0.0 && cx < w && cy < h {
            boxes.push(InputBox {
                class_id: b.class_id,
                bbox: placed,
            });
        } else if placed.area() > 0.0 {
            ignore.push(placed);
        }
    }
    ignore.extend(sample.ignore.iter().map(place).filter(|b| b.area() > 0.0));
    Crop {
        pixels,
        boxes,
        ignore,
    }
}

/// A batch of crops of `samples[indices]`: images [batch, 1, height, width] and their targets.
pub fn batch(
    samples: &[Sample],
    indices: &[usize],
    config: &CropConfig,
    anchor_px: f64,
    rng: &mut SplitMix64,
    device: &Device,
) -> Result<(Tensor, Targets), SetError> {
    config.validate()?;
    if indices.is_empty() {
        return Err(SetError::EmptyBatch);
    }
    let (rows, columns) = (config.height_px / STRIDE_PX, config.width_px / STRIDE_PX);
    let mut pixels = Vec::with_capacity(indices.len() * config.width_px * config.height_px);
    let mut cells = Vec::with_capacity(indices.len());
    let mut ignore = Vec::with_capacity(indices.len());
    for &index in indices {
        let at = CropPlacement::random(config, rng);
        let c = crop(&samples[index], config, &at);
        pixels.extend(c.pixels);
        cells.push(assign(&c.boxes, rows, columns, anchor_px)?);
        ignore.push(c.ignore);
    }
    let images = Tensor::from_vec(
        pixels,
        (indices.len(), 1, config.height_px, config.width_px),
        device,
    )?;
    Ok((
        images,
        Targets::new(&cells, &ignore, rows, columns, device)?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_with(boxes: Vec<InputBox>) -> Sample {
        // Each input pixel holds its own coordinates, to follow it through crops and flips.
        let input = (0..INPUT_HEIGHT_PX * INPUT_WIDTH_PX)
            .map(|i| ((i / INPUT_WIDTH_PX) * 1000 + i % INPUT_WIDTH_PX) as f32)
            .collect();
        Sample {
            seed: 0,
            input,
            boxes,
            ignore: vec![PixelBox {
                x_min: 40.0,
                y_min: 70.0,
                x_max: 56.0,
                y_max: 90.0,
            }],
            altitude_m: 7.5,
        }
    }

    fn b(class_id: usize, x_min: f64, y_min: f64, x_max: f64, y_max: f64) -> InputBox {
        InputBox {
            class_id,
            bbox: PixelBox {
                x_min,
                y_min,
                x_max,
                y_max,
            },
        }
    }

    #[test]
    fn crops_move_pixels_and_boxes_together() {
        let sample = sample_with(vec![
            // Centre (70, 40): inside a crop at (48, 32); reaches past its right edge at 48+32=80.
            b(0, 60.0, 30.0, 90.0, 50.0),
            // Centre (150, 40): outside.
            b(2, 140.0, 30.0, 160.0, 50.0),
        ]);
        let config = CropConfig {
            width_px: 32,
            height_px: 48,
            flips: true,
        };
        let plain = CropPlacement {
            x0_px: 48,
            y0_px: 32,
            flip_x: false,
            flip_y: false,
        };
        let c = crop(&sample, &config, &plain);
        assert_eq!(c.pixels.len(), 32 * 48);
        assert_eq!(c.pixels[0], (32 * 1000 + 48) as f32);
        assert_eq!(c.pixels[2 * 32 + 5], (34 * 1000 + 53) as f32);
        assert_eq!(c.boxes, vec![b(0, 12.0, 0.0, 32.0, 18.0)]);
        // The frame's cut-off hazard (x 40–56, y 70–90) reaches in; the vehicle at x ≥ 140 not.
        assert_eq!(c.ignore, vec![b(0, 0.0, 38.0, 8.0, 48.0).bbox]);
        // A crop whose edge cuts the person's box off its centre: ignored, not background.
        let right = CropPlacement { x0_px: 80, ..plain };
        let c = crop(&sample, &config, &right);
        assert!(c.boxes.is_empty());
        assert_eq!(c.ignore, vec![b(0, 0.0, 0.0, 10.0, 18.0).bbox]);
        let flipped = CropPlacement {
            flip_x: true,
            flip_y: true,
            ..plain
        };
        let c = crop(&sample, &config, &flipped);
        // Crop pixel (0, 0) is the source's last row and column of the crop.
        assert_eq!(c.pixels[0], ((32 + 47) * 1000 + 48 + 31) as f32);
        assert_eq!(c.boxes, vec![b(0, 0.0, 30.0, 20.0, 48.0)]);
        assert_eq!(c.ignore, vec![b(0, 24.0, 0.0, 32.0, 10.0).bbox]);
    }

    #[test]
    fn random_placements_stay_on_the_grid_and_inside() {
        let config = CropConfig {
            width_px: 160,
            height_px: 160,
            flips: true,
        };
        let mut rng = SplitMix64::new(3);
        let mut seen_x = std::collections::BTreeSet::new();
        let mut flips = [0; 2];
        for _ in 0..2000 {
            let at = CropPlacement::random(&config, &mut rng);
            assert_eq!(at.x0_px % STRIDE_PX, 0);
            assert_eq!(at.y0_px % STRIDE_PX, 0);
            assert!(at.x0_px + 160 <= INPUT_WIDTH_PX && at.y0_px + 160 <= INPUT_HEIGHT_PX);
            seen_x.insert(at.x0_px);
            flips[0] += at.flip_x as usize;
            flips[1] += at.flip_y as usize;
        }
        // Every one of the (320 − 160) / 16 + 1 = 11 columns is used.
        assert_eq!(seen_x.len(), 11);
        assert!(flips.iter().all(|&f| (800..1200).contains(&f)), "{flips:?}");
        assert!(CropConfig {
            width_px: 150,
            ..config
        }
        .validate()
        .is_err());
    }

    #[test]
    fn a_rendered_sample_holds_the_letterboxed_frame_and_half_size_boxes() {
        let (sample, frame) = Sample::render(5).unwrap();
        let (input, _) = letterbox_gray(&frame.image.view(), INPUT_WIDTH_PX, INPUT_HEIGHT_PX);
        assert_eq!(sample.input, input);
        assert_eq!(sample.boxes.len(), frame.labels.len());
        for (b, l) in sample.boxes.iter().zip(&frame.labels) {
            assert_eq!(b.class_id, class_index(l.class));
            assert!((b.bbox.x_min - l.bbox.x_min / 2.0).abs() < 1e-9);
            assert!((b.bbox.y_max - l.bbox.y_max / 2.0).abs() < 1e-9);
        }
    }
}
