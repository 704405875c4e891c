//! Precision and recall of an ONNX hazard model on rendered frames, run exactly as the hazard
//! task runs it: `letterbox_gray` → tract → `yolo::decode` → non-maximum suppression.
//!
//! Matching: detections are taken most confident first; each one is a true positive when it
//! overlaps a not yet matched label of the same class by IoU ≥ the match threshold (the best such
//! label), and a false positive otherwise; labels left unmatched are misses. A detection that
//! matches no label but lies mostly (half its area or more) on a hazard cut off at the image's
//! edge — one whose centre is out of view, so it has no label — counts as neither.

use algorithms::vision::yolo::PixelBox;

use std::path::Path;
use std::sync::Arc;

use algorithms::vision::image::GrayImage;
use algorithms::vision::yolo::{
    decode, letterbox_gray, non_maximum_suppression, Detection, Letterbox, YoloError, YoloFormat,
};
use thiserror::Error;
// The prelude brings the traits tract's builder methods live on.
use tract_onnx::prelude::*;

use crate::dataset::{class_index, Sample, SetError};
use crate::model::CLASSES;

#[derive(Debug, Error)]
pub enum EvalError {
    #[error("the ONNX model {what}: {message}")]
    Onnx { what: String, message: String },
    #[error("the model's input is {expected} values ({width_px}×{height_px}), got {found}")]
    InputLength {
        expected: usize,
        found: usize,
        width_px: usize,
        height_px: usize,
    },
    #[error(transparent)]
    Yolo(#[from] YoloError),
    #[error(transparent)]
    Set(#[from] SetError),
    #[error("an evaluation thread panicked")]
    Thread,
}

fn onnx_error(what: impl Into<String>) -> impl FnOnce(TractError) -> EvalError {
    let what = what.into();
    move |e| EvalError::Onnx {
        what,
        message: format!("{e:#}"),
    }
}

/// An ONNX detector of a fixed input size, run by tract.
#[derive(Debug, Clone)]
pub struct OnnxDetector {
    plan: Arc<TypedRunnableModel>,
    width_px: usize,
    height_px: usize,
}

impl OnnxDetector {
    pub fn load(path: &Path, width_px: usize, height_px: usize) -> Result<Self, EvalError> {
        let bytes = std::fs::read(path).map_err(|e| EvalError::Onnx {
            what: format!("{} could not be read", path.display()),
            message: e.to_string(),
        })?;
        Self::from_bytes(&bytes, width_px, height_px)
    }

    pub fn from_bytes(bytes: &[u8], width_px: usize, height_px: usize) -> Result<Self, EvalError> {
        let plan = tract_onnx::onnx()
            .model_for_read(&mut &bytes[..])
            .map_err(onnx_error("could not be parsed"))?
            .with_input_fact(0, f32::fact([1, 1, height_px, width_px]).into())
            .map_err(onnx_error("does not take a [1, 1, height, width] input"))?
            .into_optimized()
            .map_err(onnx_error("could not be optimised"))?
            .into_runnable()
            .map_err(onnx_error("could not be planned"))?;
        Ok(Self {
            plan,
            width_px,
            height_px,
        })
    }

    /// The raw output and its shape for one input (row-major, [height, width]).
    pub fn run(&self, input: &[f32]) -> Result<(Vec<f32>, Vec<usize>), EvalError> {
        let expected = self.width_px * self.height_px;
        if input.len() != expected {
            return Err(EvalError::InputLength {
                expected,
                found: input.len(),
                width_px: self.width_px,
                height_px: self.height_px,
            });
        }
        let tensor = Tensor::from_shape(&[1, 1, self.height_px, self.width_px], input)
            .map_err(onnx_error("rejected the input"))?;
        let outputs = self
            .plan
            .run(tvec!(tensor.into()))
            .map_err(onnx_error("failed to run"))?;
        let output = outputs.first().ok_or_else(|| EvalError::Onnx {
            what: "gave no output".into(),
            message: String::new(),
        })?;
        let view = output
            .to_plain_array_view::<f32>()
            .map_err(onnx_error("gave a non-f32 output"))?;
        Ok((view.iter().copied().collect(), view.shape().to_vec()))
    }

    /// Detections in a frame, in the frame's pixels, as the hazard task finds them.
    pub fn detect(
        &self,
        image: &GrayImage,
        thresholds: &Thresholds,
    ) -> Result<Vec<Detection>, EvalError> {
        let (input, letterbox) = letterbox_gray(&image.view(), self.width_px, self.height_px);
        self.detect_input(&input, &letterbox, thresholds)
    }

    /// As [`Self::detect`] for an input already letterboxed.
    pub fn detect_input(
        &self,
        input: &[f32],
        letterbox: &Letterbox,
        thresholds: &Thresholds,
    ) -> Result<Vec<Detection>, EvalError> {
        let (output, shape) = self.run(input)?;
        let detections = decode(
            &output,
            &shape,
            YoloFormat::WithObjectness,
            CLASSES,
            thresholds.confidence,
            letterbox,
        )?;
        Ok(non_maximum_suppression(detections, thresholds.nms_iou)?)
    }
}

/// The detection thresholds, as the hazard task's configuration gives them.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Thresholds {
    pub confidence: f64,
    pub nms_iou: f64,
    /// Least IoU between a detection and a label of its class to count as found.
    pub match_iou: f64,
}

impl Default for Thresholds {
    fn default() -> Self {
        Self {
            confidence: 0.5,
            nms_iou: 0.45,
            match_iou: 0.5,
        }
    }
}

/// True positives, false positives and misses of one class.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Counts {
    pub true_positives: usize,
    pub false_positives: usize,
    pub misses: usize,
}

impl Counts {
    /// TP / (TP + FP); 1 when nothing was detected (no false alarm).
    pub fn precision(&self) -> f64 {
        let detected = self.true_positives + self.false_positives;
        if detected == 0 {
            1.0
        } else {
            self.true_positives as f64 / detected as f64
        }
    }

    /// TP / (TP + misses); 1 when there was nothing to find.
    pub fn recall(&self) -> f64 {
        let labelled = self.true_positives + self.misses;
        if labelled == 0 {
            1.0
        } else {
            self.true_positives as f64 / labelled as f64
        }
    }

    pub fn add(&mut self, other: &Counts) {
        self.true_positives += other.true_positives;
        self.false_positives += other.false_positives;
        self.misses += other.misses;
    }
}

/// Counts per class, in class order.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ClassCounts {
    pub per_class: [Counts; CLASSES],
}

impl ClassCounts {
    pub fn overall(&self) -> Counts {
        let mut all = Counts::default();
        for c in &self.per_class {
            all.add(c);
        }
        all
    }

    pub fn add(&mut self, other: &ClassCounts) {
        for (a, b) in self.per_class.iter_mut().zip(&other.per_class) {
            a.add(b);
        }
    }
}

/// Matches one frame's detections to its labels (see the module docs).
pub fn match_frame(
    detections: &[Detection],
    labels: &[(usize, PixelBox)],
    cut_off: &[PixelBox],
    match_iou: f64,
) -> ClassCounts {
    let mut counts = ClassCounts::default();
    let mut order: Vec<&Detection> = detections.iter().collect();
    order.sort_by(|a, b| b.confidence.total_cmp(&a.confidence));
    let mut matched = vec![false; labels.len()];
    for d in order {
        let best = labels
            .iter()
            .enumerate()
            .filter(|(i, (class_id, _))| !matched[*i] && *class_id == d.class_id)
            .map(|(i, (_, bbox))| (i, d.bbox.iou(bbox)))
            .filter(|&(_, iou)| iou >= match_iou)
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let Some(class_counts) = counts.per_class.get_mut(d.class_id) else {
            continue;
        };
        let on_cut_off = || {
            cut_off
                .iter()
                .any(|c| intersection_area(&d.bbox, c) >= 0.5 * d.bbox.area())
        };
        match best {
            Some((i, _)) => {
                matched[i] = true;
                class_counts.true_positives += 1;
            }
            None if on_cut_off() => {}
            None => class_counts.false_positives += 1,
        }
    }
    for ((class_id, _), found) in labels.iter().zip(&matched) {
        if !found {
            if let Some(c) = counts.per_class.get_mut(*class_id) {
                c.misses += 1;
            }
        }
    }
    counts
}

fn intersection_area(a: &PixelBox, b: &PixelBox) -> f64 {
    let width = (a.x_max.min(b.x_max) - a.x_min.max(b.x_min)).max(0.0);
    let height = (a.y_max.min(b.y_max) - a.y_min.max(b.y_min)).max(0.0);
    width * height
}

/// Counts over held-out frames: all of them, and those taken 6–9 m above the ground (the
/// mission's tracking heights).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Evaluation {
    pub frames: usize,
    pub all: ClassCounts,
    pub typical_altitude_frames: usize,
    pub typical_altitude: ClassCounts,
}

/// Renders the frames of `seeds` and scores `detector` on them, on `threads` threads.
pub fn evaluate(
    detector: &OnnxDetector,
    seeds: std::ops::Range<u64>,
    thresholds: &Thresholds,
    threads: usize,
) -> Result<Evaluation, EvalError> {
    let seeds: Vec<u64> = seeds.collect();
    let threads = threads.max(1);
    let parts: Vec<Result<Evaluation, EvalError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|thread| {
                let seeds = &seeds;
                scope.spawn(move || {
                    let mut part = Evaluation::default();
                    for &seed in seeds.iter().skip(thread).step_by(threads) {
                        let (sample, frame) = Sample::render(seed)?;
                        let detections = detector.detect(&frame.image, thresholds)?;
                        let labels: Vec<_> = frame
                            .labels
                            .iter()
                            .map(|l| (class_index(l.class), l.bbox))
                            .collect();
                        let cut_off: Vec<PixelBox> = frame.cut_off.iter().map(|c| c.bbox).collect();
                        let counts =
                            match_frame(&detections, &labels, &cut_off, thresholds.match_iou);
                        part.frames += 1;
                        part.all.add(&counts);
                        let [low_m, high_m] = sim::hazard_dataset::TYPICAL_ALTITUDE_RANGE_M;
                        if (low_m..=high_m).contains(&sample.altitude_m) {
                            part.typical_altitude_frames += 1;
                            part.typical_altitude.add(&counts);
                        }
                    }
                    Ok(part)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or(Err(EvalError::Thread)))
            .collect()
    });
    let mut total = Evaluation::default();
    for part in parts {
        let part = part?;
        total.frames += part.frames;
        total.all.add(&part.all);
        total.typical_altitude_frames += part.typical_altitude_frames;
        total.typical_altitude.add(&part.typical_altitude);
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(class_id: usize, confidence: f64, x: f64) -> Detection {
        Detection {
            class_id,
            confidence,
            bbox: PixelBox::from_centre(x, 50.0, 20.0, 20.0),
        }
    }

    #[test]
    fn matching_counts_hits_duplicates_wrong_classes_and_misses() {
        let labels = vec![
            (0, PixelBox::from_centre(100.0, 50.0, 20.0, 20.0)),
            (1, PixelBox::from_centre(200.0, 50.0, 20.0, 20.0)),
            (2, PixelBox::from_centre(300.0, 50.0, 20.0, 20.0)),
        ];
        let detections = [
            // Person found, 2 px off: IoU 18·20 / (2·400 − 360) = 0.82.
            det(0, 0.9, 102.0),
            // A duplicate of it, less confident: a false positive.
            det(0, 0.8, 101.0),
            // At the animal but called a vehicle: a false positive, the animal missed.
            det(2, 0.7, 200.0),
            // 8 px off the vehicle: IoU 12·20 / (800 − 240) = 0.43 < 0.5, a false positive.
            det(2, 0.6, 308.0),
        ];
        let counts = match_frame(&detections, &labels, &[], 0.5);
        let expect = |tp, fp, misses| Counts {
            true_positives: tp,
            false_positives: fp,
            misses,
        };
        assert_eq!(counts.per_class[0], expect(1, 1, 0));
        assert_eq!(counts.per_class[1], expect(0, 0, 1));
        assert_eq!(counts.per_class[2], expect(0, 2, 1));
        let overall = counts.overall();
        assert_eq!(overall, expect(1, 3, 2));
        assert!((overall.precision() - 0.25).abs() < 1e-12);
        assert!((overall.recall() - 1.0 / 3.0).abs() < 1e-12);
        // A hazard cut off at the edge (x 390–410): the vehicle's false positive at x 398–418
        // lies 12/20 on it and no longer counts; the animal's at 190–210 still does.
        let cut_off = [PixelBox::from_centre(400.0, 50.0, 20.0, 20.0)];
        let mut detections = detections.to_vec();
        detections[3] = det(2, 0.6, 408.0);
        let counts = match_frame(&detections, &labels, &cut_off, 0.5);
        assert_eq!(counts.per_class[2], expect(0, 1, 1));
        assert_eq!(counts.per_class[0], expect(1, 1, 0));
        // Nothing detected, nothing to find: no error either way.
        assert_eq!(Counts::default().precision(), 1.0);
        assert_eq!(Counts::default().recall(), 1.0);
    }
}
