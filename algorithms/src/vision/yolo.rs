//! Decoding a YOLO-style detector's output into boxes, and non-maximum suppression: what the
//! hazard task does with its network's raw tensor, so a user's own exported YOLO model works by
//! configuration (input size, class names, thresholds).
//!
//! Two output layouts are understood, both with boxes as centre x, centre y, width, height in
//! input pixels:
//! - [`YoloFormat::WithObjectness`] (YOLOv3/v5 exports): one row per candidate,
//!   `[cx, cy, w, h, objectness, class_0 … class_{C−1}]`, confidence = objectness × class score;
//! - [`YoloFormat::ClassScoresOnly`] (YOLOv8 exports): `[cx, cy, w, h, class_0 …]`, confidence =
//!   the class score.
//!
//! Either may come candidate-major (`[N, 4 (+1) + C]`) or attribute-major (`[4 (+1) + C, N]`,
//! YOLOv8's default); the shape says which. Boxes are mapped back from the letterboxed network
//! input to the original image.

use super::image::ImageView;
use thiserror::Error;

/// How the network lays out one candidate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum YoloFormat {
    WithObjectness,
    ClassScoresOnly,
}

impl YoloFormat {
    fn attributes(self, classes: usize) -> usize {
        match self {
            YoloFormat::WithObjectness => 5 + classes,
            YoloFormat::ClassScoresOnly => 4 + classes,
        }
    }
}

/// An axis-aligned box in pixels: `x` right, `y` down, min corner inclusive.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PixelBox {
    pub x_min: f64,
    pub y_min: f64,
    pub x_max: f64,
    pub y_max: f64,
}

impl PixelBox {
    pub fn from_centre(cx: f64, cy: f64, width: f64, height: f64) -> Self {
        Self {
            x_min: cx - width / 2.0,
            y_min: cy - height / 2.0,
            x_max: cx + width / 2.0,
            y_max: cy + height / 2.0,
        }
    }

    pub fn area(&self) -> f64 {
        (self.x_max - self.x_min).max(0.0) * (self.y_max - self.y_min).max(0.0)
    }

    pub fn centre(&self) -> (f64, f64) {
        (
            (self.x_min + self.x_max) / 2.0,
            (self.y_min + self.y_max) / 2.0,
        )
    }

    /// Intersection over union; 0 when either box is empty.
    pub fn iou(&self, other: &PixelBox) -> f64 {
        let width = (self.x_max.min(other.x_max) - self.x_min.max(other.x_min)).max(0.0);
        let height = (self.y_max.min(other.y_max) - self.y_min.max(other.y_min)).max(0.0);
        let intersection = width * height;
        let union = self.area() + other.area() - intersection;
        if union <= 0.0 {
            0.0
        } else {
            intersection / union
        }
    }
}

/// One detection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    pub class_id: usize,
    pub confidence: f64,
    pub bbox: PixelBox,
}

/// How the original image was fitted into the network's input: scaled by `scale` (the same on
/// both axes, so shapes keep their aspect), then padded by `pad_x_px`, `pad_y_px` on the left and
/// top.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    pub scale: f64,
    pub pad_x_px: f64,
    pub pad_y_px: f64,
}

impl Letterbox {
    /// The letterbox that fits `width × height` into `input_size × input_size`, centred.
    pub fn fit(width_px: usize, height_px: usize, input_size_px: usize) -> Self {
        Self::fit_into(width_px, height_px, input_size_px, input_size_px)
    }

    /// The letterbox that fits `width × height` into `input_width × input_height`, centred.
    pub fn fit_into(
        width_px: usize,
        height_px: usize,
        input_width_px: usize,
        input_height_px: usize,
    ) -> Self {
        let scale = (input_width_px as f64 / width_px.max(1) as f64)
            .min(input_height_px as f64 / height_px.max(1) as f64);
        Self {
            scale,
            pad_x_px: (input_width_px as f64 - width_px as f64 * scale) / 2.0,
            pad_y_px: (input_height_px as f64 - height_px as f64 * scale) / 2.0,
        }
    }

    /// A box in network-input pixels → original-image pixels.
    pub fn to_image(&self, b: &PixelBox) -> PixelBox {
        PixelBox {
            x_min: (b.x_min - self.pad_x_px) / self.scale,
            y_min: (b.y_min - self.pad_y_px) / self.scale,
            x_max: (b.x_max - self.pad_x_px) / self.scale,
            y_max: (b.y_max - self.pad_y_px) / self.scale,
        }
    }
}

/// Grey level of the letterbox's padding, as YOLO exports use (114 of 255).
pub const LETTERBOX_PAD_VALUE: f32 = 114.0 / 255.0;

/// The network input for a grayscale image: letterboxed into `input_width × input_height`, each
/// input pixel the area-weighted mean of the image pixels it covers (an exact 2×2 mean at half
/// scale, so small objects keep their contrast), scaled to [0, 1], padding at
/// [`LETTERBOX_PAD_VALUE`]. Row-major, one channel; the training tool and the hazard task both
/// use this, so a model sees in flight what it was trained on.
pub fn letterbox_gray(
    image: &ImageView<'_>,
    input_width_px: usize,
    input_height_px: usize,
) -> (Vec<f32>, Letterbox) {
    let letterbox = Letterbox::fit_into(
        image.width(),
        image.height(),
        input_width_px,
        input_height_px,
    );
    let mut input = vec![LETTERBOX_PAD_VALUE; input_width_px * input_height_px];
    let (width, height) = (image.width(), image.height());
    if width == 0 || height == 0 {
        return (input, letterbox);
    }
    // Per input column (row), the image columns (rows) it covers with their weights.
    let spans = |count_in: usize, pad: f64, count_image: usize| -> Vec<Vec<(usize, f32)>> {
        (0..count_in)
            .map(|i| {
                let from = (i as f64 - pad) / letterbox.scale;
                let to = (i as f64 + 1.0 - pad) / letterbox.scale;
                let (from, to) = (from.max(0.0), to.min(count_image as f64));
                if to <= from {
                    return Vec::new();
                }
                let mut weights = Vec::new();
                let mut k = from.floor() as usize;
                while (k as f64) < to && k < count_image {
                    let overlap = (to.min(k as f64 + 1.0) - from.max(k as f64)).max(0.0);
                    if overlap > 0.0 {
                        weights.push((k, (overlap / (to - from)) as f32));
                    }
                    k += 1;
                }
                weights
            })
            .collect()
    };
    let columns = spans(input_width_px, letterbox.pad_x_px, width);
    let rows = spans(input_height_px, letterbox.pad_y_px, height);
    // An input row's image rows are looked up once, not once per input pixel.
    let mut image_rows: Vec<(&[u8], f32)> = Vec::new();
    for (row_weights, input_row) in rows.iter().zip(input.chunks_exact_mut(input_width_px)) {
        if row_weights.is_empty() {
            continue;
        }
        image_rows.clear();
        image_rows.extend(
            row_weights
                .iter()
                .map(|&(image_y, wy)| (image.row(image_y), wy)),
        );
        for (column_weights, value) in columns.iter().zip(input_row.iter_mut()) {
            if column_weights.is_empty() {
                continue;
            }
            let mut sum = 0.0f32;
            for &(row, wy) in &image_rows {
                for &(image_x, wx) in column_weights {
                    sum += wy * wx * f32::from(row[image_x]);
                }
            }
            *value = sum / 255.0;
        }
    }
    (input, letterbox)
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum YoloError {
    #[error(
        "output shape {shape:?} does not fit {classes} classes in the {format:?} layout: \
         expected [N, {attributes}] or [{attributes}, N] (a leading batch of 1 is allowed)"
    )]
    Shape {
        shape: Vec<usize>,
        classes: usize,
        format: YoloFormat,
        attributes: usize,
    },
    #[error("output has {found} values but its shape {shape:?} says {expected}")]
    Length {
        shape: Vec<usize>,
        expected: usize,
        found: usize,
    },
    #[error("{name} = {value} is invalid: {why}")]
    Threshold {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
}

/// Decodes every candidate whose confidence reaches `confidence_threshold` (best class per
/// candidate), boxes in original-image pixels. Non-finite values make a candidate count as
/// nothing, never a panic.
pub fn decode(
    output: &[f32],
    shape: &[usize],
    format: YoloFormat,
    classes: usize,
    confidence_threshold: f64,
    letterbox: &Letterbox,
) -> Result<Vec<Detection>, YoloError> {
    if !(confidence_threshold.is_finite() && (0.0..=1.0).contains(&confidence_threshold)) {
        return Err(YoloError::Threshold {
            name: "confidence_threshold",
            value: confidence_threshold,
            why: "must be within [0, 1]",
        });
    }
    let attributes = format.attributes(classes);
    let dims: Vec<usize> = match shape {
        [1, rest @ ..] if rest.len() == 2 => rest.to_vec(),
        [a, b] => vec![*a, *b],
        _ => Vec::new(),
    };
    let shape_error = || YoloError::Shape {
        shape: shape.to_vec(),
        classes,
        format,
        attributes,
    };
    if dims.len() != 2 || classes == 0 {
        return Err(shape_error());
    }
    let expected = dims[0] * dims[1];
    if output.len() != expected {
        return Err(YoloError::Length {
            shape: shape.to_vec(),
            expected,
            found: output.len(),
        });
    }
    // Candidate-major when the rows are candidates; a square ambiguity resolves to it.
    let (candidates, value): (usize, Box<dyn Fn(usize, usize) -> f64>) = if dims[1] == attributes {
        (
            dims[0],
            Box::new(move |n, a| f64::from(output[n * attributes + a])),
        )
    } else if dims[0] == attributes {
        let count = dims[1];
        (
            count,
            Box::new(move |n, a| f64::from(output[a * count + n])),
        )
    } else {
        return Err(shape_error());
    };
    let first_class = attributes - classes;
    let mut detections = Vec::new();
    for n in 0..candidates {
        let objectness = match format {
            YoloFormat::WithObjectness => value(n, 4),
            YoloFormat::ClassScoresOnly => 1.0,
        };
        let (mut best_class, mut best_score) = (0, f64::NEG_INFINITY);
        for class in 0..classes {
            let score = value(n, first_class + class);
            if score > best_score {
                (best_class, best_score) = (class, score);
            }
        }
        let confidence = objectness * best_score;
        let [cx, cy, w, h] = [value(n, 0), value(n, 1), value(n, 2), value(n, 3)];
        let finite = [confidence, cx, cy, w, h].iter().all(|v| v.is_finite());
        if !finite || confidence < confidence_threshold || w <= 0.0 || h <= 0.0 {
            continue;
        }
        detections.push(Detection {
            class_id: best_class,
            confidence,
            bbox: letterbox.to_image(&PixelBox::from_centre(cx, cy, w, h)),
        });
    }
    Ok(detections)
}

/// Greedy non-maximum suppression per class: the most confident box is kept and every box of
/// its class overlapping it by more than `iou_threshold` is dropped, then the next. Returns the
/// kept detections, most confident first.
pub fn non_maximum_suppression(
    mut detections: Vec<Detection>,
    iou_threshold: f64,
) -> Result<Vec<Detection>, YoloError> {
    if !(iou_threshold.is_finite() && (0.0..=1.0).contains(&iou_threshold)) {
        return Err(YoloError::Threshold {
            name: "iou_threshold",
            value: iou_threshold,
            why: "must be within [0, 1]",
        });
    }
    detections.sort_by(|a, b| b.confidence.total_cmp(&a.confidence));
    let mut kept: Vec<Detection> = Vec::with_capacity(detections.len());
    for candidate in detections {
        let suppressed = kept.iter().any(|k| {
            k.class_id == candidate.class_id && k.bbox.iou(&candidate.bbox) > iou_threshold
        });
        if !suppressed {
            kept.push(candidate);
        }
    }
    Ok(kept)
}

#[cfg(test)]
mod tests {
    use super::*;

    const NO_LETTERBOX: Letterbox = Letterbox {
        scale: 1.0,
        pad_x_px: 0.0,
        pad_y_px: 0.0,
    };

    #[test]
    fn letterbox_input_is_the_area_mean_of_the_image() {
        use crate::vision::image::GrayImage;
        // A pseudo-random 640×480 image.
        let mut state = 12345u32;
        let data: Vec<u8> = (0..640 * 480)
            .map(|_| {
                state = state.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                (state >> 16) as u8
            })
            .collect();
        let image = GrayImage::from_vec(640, 480, data).unwrap();
        // Half scale: every input pixel is the plain mean of a 2×2 block.
        let (input, letterbox) = letterbox_gray(&image.view(), 320, 240);
        assert_eq!(
            (letterbox.scale, letterbox.pad_x_px, letterbox.pad_y_px),
            (0.5, 0.0, 0.0)
        );
        for (x, y) in [(0, 0), (17, 93), (319, 239), (200, 5)] {
            let block: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|(dx, dy)| u32::from(image.get(2 * x + dx, 2 * y + dy)))
                .sum();
            let expected = block as f32 / 4.0 / 255.0;
            assert!((input[y * 320 + x] - expected).abs() < 1e-5, "({x}, {y})");
        }
        // Into a square: 40 rows of padding above and below, the image between.
        let (input, letterbox) = letterbox_gray(&image.view(), 320, 320);
        assert_eq!((letterbox.pad_x_px, letterbox.pad_y_px), (0.0, 40.0));
        assert!(input[..320 * 40].iter().all(|&v| v == LETTERBOX_PAD_VALUE));
        assert!(input[320 * 280..].iter().all(|&v| v == LETTERBOX_PAD_VALUE));
        let first = [(0, 0), (1, 0), (0, 1), (1, 1)]
            .iter()
            .map(|&(x, y)| f32::from(image.get(x, y)))
            .sum::<f32>()
            / 4.0
            / 255.0;
        assert!((input[320 * 40] - first).abs() < 1e-5);
        // A non-integer scale keeps a uniform image uniform and a box maps back to its place.
        let grey = GrayImage::filled(640, 480, 200).unwrap();
        let (input, letterbox) = letterbox_gray(&grey.view(), 416, 416);
        let inside = &input[416 * 80..416 * 320];
        assert!(inside.iter().all(|&v| (v - 200.0 / 255.0).abs() < 1e-4));
        let b = letterbox.to_image(&PixelBox::from_centre(208.0, 208.0, 41.6, 41.6));
        assert!((b.centre().0 - 320.0).abs() < 1e-9 && (b.centre().1 - 240.0).abs() < 1e-9);
        assert!((b.x_max - b.x_min - 64.0).abs() < 1e-9);
    }

    #[test]
    fn iou_of_hand_computed_boxes() {
        let a = PixelBox::from_centre(5.0, 5.0, 10.0, 10.0);
        // Shifted by half its width: intersection 50, union 150.
        let b = PixelBox::from_centre(10.0, 5.0, 10.0, 10.0);
        assert!((a.iou(&b) - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(a.iou(&a), 1.0);
        let far = PixelBox::from_centre(50.0, 50.0, 2.0, 2.0);
        assert_eq!(a.iou(&far), 0.0);
        // A 4×4 box inside a 10×10 one: 16 / 100.
        let inner = PixelBox::from_centre(5.0, 5.0, 4.0, 4.0);
        assert!((a.iou(&inner) - 0.16).abs() < 1e-12);
        let empty = PixelBox::from_centre(5.0, 5.0, 0.0, 0.0);
        assert_eq!(empty.iou(&empty), 0.0);
    }

    /// Three candidates, two classes, YOLOv5 rows: confidences 0.9·0.8, 0.5·0.9, 0.2·0.9.
    #[test]
    fn decodes_candidate_major_rows_with_objectness() {
        #[rustfmt::skip]
        let rows: [f32; 21] = [
            100.0, 50.0, 20.0, 10.0, 0.9, 0.8, 0.1,
            30.0, 40.0, 8.0, 8.0, 0.5, 0.1, 0.9,
            10.0, 10.0, 4.0, 4.0, 0.2, 0.9, 0.05,
        ];
        let found = decode(
            &rows,
            &[1, 3, 7],
            YoloFormat::WithObjectness,
            2,
            0.25,
            &NO_LETTERBOX,
        )
        .unwrap();
        assert_eq!(found.len(), 2, "{found:?}");
        assert_eq!(found[0].class_id, 0);
        assert!((found[0].confidence - 0.72).abs() < 1e-6);
        assert_eq!(
            found[0].bbox,
            PixelBox {
                x_min: 90.0,
                y_min: 45.0,
                x_max: 110.0,
                y_max: 55.0
            }
        );
        assert_eq!(found[1].class_id, 1);
        assert!((found[1].confidence - 0.45).abs() < 1e-6);
    }

    /// The same candidates transposed, YOLOv8 style (no objectness), through a letterbox.
    #[test]
    fn decodes_attribute_major_scores_through_a_letterbox() {
        // Two candidates, attributes [cx, cy, w, h, c0, c1].
        #[rustfmt::skip]
        let columns: [f32; 12] = [
            320.0, 100.0,   // cx
            320.0, 200.0,   // cy
            64.0, 10.0,     // w
            32.0, 10.0,     // h
            0.3, 0.05,      // class 0
            0.7, 0.1,       // class 1
        ];
        // A 640×480 image in a 640 input: scale 1, 80 px bars top and bottom.
        let letterbox = Letterbox::fit(640, 480, 640);
        assert_eq!(letterbox.pad_y_px, 80.0);
        let found = decode(
            &columns,
            &[1, 6, 2],
            YoloFormat::ClassScoresOnly,
            2,
            0.5,
            &letterbox,
        )
        .unwrap();
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].class_id, 1);
        assert!((found[0].confidence - 0.7).abs() < 1e-6);
        // Centre (320, 320) in the input → (320, 240) in the image.
        let (cx, cy) = found[0].bbox.centre();
        assert_eq!((cx, cy), (320.0, 240.0));
        // A 1280×960 image in a 640 input: half scale, so sizes double on the way back.
        let half = Letterbox::fit(1280, 960, 640);
        let found = decode(
            &columns,
            &[6, 2],
            YoloFormat::ClassScoresOnly,
            2,
            0.5,
            &half,
        )
        .unwrap();
        let b = found[0].bbox;
        assert_eq!((b.x_max - b.x_min, b.y_max - b.y_min), (128.0, 64.0));
        assert_eq!(b.centre(), (640.0, 480.0));
    }

    #[test]
    fn bad_shapes_values_and_thresholds_are_named() {
        let values = [0.0f32; 14];
        assert!(matches!(
            decode(
                &values,
                &[2, 7],
                YoloFormat::ClassScoresOnly,
                2,
                0.5,
                &NO_LETTERBOX
            ),
            Err(YoloError::Shape { attributes: 6, .. })
        ));
        assert!(matches!(
            decode(
                &values,
                &[3, 7],
                YoloFormat::WithObjectness,
                2,
                0.5,
                &NO_LETTERBOX
            ),
            Err(YoloError::Length {
                expected: 21,
                found: 14,
                ..
            })
        ));
        assert!(matches!(
            decode(
                &values,
                &[2, 7],
                YoloFormat::WithObjectness,
                2,
                1.5,
                &NO_LETTERBOX
            ),
            Err(YoloError::Threshold { .. })
        ));
        // NaN and negative sizes are not detections.
        let mut nan = [1.0f32; 14];
        nan[0] = f32::NAN;
        nan[7 + 2] = -3.0;
        let found = decode(
            &nan,
            &[2, 7],
            YoloFormat::WithObjectness,
            2,
            0.5,
            &NO_LETTERBOX,
        )
        .unwrap();
        assert!(found.is_empty(), "{found:?}");
        assert!(non_maximum_suppression(Vec::new(), f64::NAN).is_err());
    }

    fn detection(class_id: usize, confidence: f64, cx: f64, cy: f64, size: f64) -> Detection {
        Detection {
            class_id,
            confidence,
            bbox: PixelBox::from_centre(cx, cy, size, size),
        }
    }

    #[test]
    fn nms_on_a_hand_worked_case() {
        let detections = vec![
            detection(0, 0.6, 12.0, 10.0, 10.0), // IoU with the 0.9 box: 80/120 = 0.667
            detection(0, 0.9, 10.0, 10.0, 10.0),
            detection(0, 0.7, 17.0, 10.0, 10.0), // IoU with the 0.9 box: 30/170 = 0.176
            detection(1, 0.8, 10.0, 10.0, 10.0), // another class: never suppressed by class 0
        ];
        let kept = non_maximum_suppression(detections, 0.5).unwrap();
        let confidences: Vec<f64> = kept.iter().map(|d| d.confidence).collect();
        assert_eq!(confidences, vec![0.9, 0.8, 0.7]);
    }

    /// Random boxes: the kept set satisfies NMS's defining properties, checked directly.
    #[test]
    fn nms_output_has_the_defining_properties() {
        use rand::rngs::StdRng;
        use rand::{Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..200 {
            let detections: Vec<Detection> = (0..30)
                .map(|_| {
                    detection(
                        rng.random_range(0..3),
                        rng.random::<f64>(),
                        rng.random_range(0.0..60.0),
                        rng.random_range(0.0..60.0),
                        rng.random_range(5.0..25.0),
                    )
                })
                .collect();
            let threshold = 0.4;
            let kept = non_maximum_suppression(detections.clone(), threshold).unwrap();
            // No two kept boxes of a class overlap beyond the threshold.
            for (i, a) in kept.iter().enumerate() {
                for b in &kept[i + 1..] {
                    assert!(a.class_id != b.class_id || a.bbox.iou(&b.bbox) <= threshold);
                }
            }
            // Every dropped box overlaps a kept, more confident box of its class.
            for d in &detections {
                if kept.contains(d) {
                    continue;
                }
                assert!(kept.iter().any(|k| k.class_id == d.class_id
                    && k.confidence >= d.confidence
                    && k.bbox.iou(&d.bbox) > threshold));
            }
            // The most confident box always survives.
            let best = detections
                .iter()
                .max_by(|a, b| a.confidence.total_cmp(&b.confidence))
                .unwrap();
            assert_eq!(kept[0], *best);
        }
    }
}
