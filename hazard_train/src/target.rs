//! What the network should output: each labelled box is given to the grid cell that holds its
//! centre and, as YOLOv5 does, to the neighbouring cells its centre lies nearest to across and
//! down; the loss compares the head's raw output with those cells.
//!
//! Per positive cell the targets are the centre's offset from the cell's corner (cell units, what
//! `2 · sigmoid(t) − 0.5` decodes: within (−0.5, 1.5), so a neighbour can reach the centre) and
//! the box's size as `ln(size / anchor)` (what `exp(t)` decodes), so the regression works in the
//! same terms as the decode. Three cells per hazard instead of one triple the positives the
//! objectness learns from, and a centre near a cell border no longer makes the neighbour across
//! it a negative.

use algorithms::vision::yolo::PixelBox;
use candle_core::{Device, Tensor};
use thiserror::Error;

use crate::model::{CLASSES, STRIDE_PX};

#[derive(Debug, Error)]
pub enum TargetError {
    #[error("class {class_id} is out of range: the network knows {CLASSES} classes")]
    Class { class_id: usize },
    #[error("the raw output must be [batch, 8, rows, columns] matching the targets' {expected:?}, got {found:?}")]
    Shape {
        expected: Vec<usize>,
        found: Vec<usize>,
    },
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// A labelled box in network-input pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputBox {
    pub class_id: usize,
    pub bbox: PixelBox,
}

/// The target of one positive cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellTarget {
    pub row: usize,
    pub column: usize,
    /// Centre from the cell's top-left corner, cell units: [0, 1) in the centre's own cell,
    /// within (−0.5, 1.5) in a neighbour.
    pub offset_x: f64,
    pub offset_y: f64,
    /// ln(width / anchor), ln(height / anchor).
    pub log_width: f64,
    pub log_height: f64,
    pub class_id: usize,
}

/// Boxes narrower than this (input pixels) are not learnt: their log-size would be a wild target.
const MIN_BOX_SIDE_PX: f64 = 1.0;

/// The positive cells of one image on a `rows × columns` grid: for each box the cell of its
/// centre, the column neighbour on the side the centre leans to (left when its offset is under ½,
/// right when over ½, none at exactly ½) and likewise the row neighbour. A box whose centre is off
/// the grid is left out. When two boxes claim a cell, a centre cell beats a neighbour, then the
/// larger box wins (both are rare: hazards never overlap on the ground).
pub fn assign(
    boxes: &[InputBox],
    rows: usize,
    columns: usize,
    anchor_px: f64,
) -> Result<Vec<CellTarget>, TargetError> {
    let stride = STRIDE_PX as f64;
    // Each claimed cell with its rank (centre cell first, then area).
    let mut cells: Vec<((bool, f64), CellTarget)> = Vec::with_capacity(3 * boxes.len());
    for b in boxes {
        if b.class_id >= CLASSES {
            return Err(TargetError::Class {
                class_id: b.class_id,
            });
        }
        let (width, height) = (b.bbox.x_max - b.bbox.x_min, b.bbox.y_max - b.bbox.y_min);
        if !(width >= MIN_BOX_SIDE_PX && height >= MIN_BOX_SIDE_PX) {
            continue;
        }
        let (cx, cy) = b.bbox.centre();
        let (gx, gy) = (cx / stride, cy / stride);
        if !(gx >= 0.0 && gy >= 0.0 && gx < columns as f64 && gy < rows as f64) {
            continue;
        }
        let (column, row) = (gx.floor() as isize, gy.floor() as isize);
        let (fx, fy) = (gx - column as f64, gy - row as f64);
        let lean = |f: f64| {
            if f < 0.5 {
                Some(-1)
            } else if f > 0.5 {
                Some(1)
            } else {
                None
            }
        };
        let mut claims = vec![(true, 0, 0)];
        if let Some(dx) = lean(fx) {
            claims.push((false, dx, 0));
        }
        if let Some(dy) = lean(fy) {
            claims.push((false, 0, dy));
        }
        let area = width * height;
        for (is_centre, dx, dy) in claims {
            let (c, r) = (column + dx, row + dy);
            if c < 0 || r < 0 || c >= columns as isize || r >= rows as isize {
                continue;
            }
            let target = CellTarget {
                row: r as usize,
                column: c as usize,
                offset_x: fx - dx as f64,
                offset_y: fy - dy as f64,
                log_width: (width / anchor_px).ln(),
                log_height: (height / anchor_px).ln(),
                class_id: b.class_id,
            };
            let rank = (is_centre, area);
            match cells
                .iter_mut()
                .find(|(_, t)| t.row == target.row && t.column == target.column)
            {
                Some(slot) if slot.0 < rank => *slot = (rank, target),
                Some(_) => {}
                None => cells.push((rank, target)),
            }
        }
    }
    Ok(cells.into_iter().map(|(_, t)| t).collect())
}

/// Dense targets of a batch on one grid.
#[derive(Debug, Clone)]
pub struct Targets {
    /// [batch, 1, rows, columns]: 1 on positive cells.
    pub positive: Tensor,
    /// [batch, 4, rows, columns]: offset x, offset y, log width, log height (0 off positives).
    pub boxes: Tensor,
    /// [batch, classes, rows, columns]: one-hot on positives.
    pub classes: Tensor,
    /// [batch, 1, rows, columns]: 0 where the objectness is not scored (a cut-off hazard lies
    /// there and the cell is no positive), 1 elsewhere.
    pub objectness_weight: Tensor,
    pub positives: usize,
}

impl Targets {
    /// `per_image` positives and `ignore` boxes (input pixels) of each image: a cell whose centre
    /// lies in an ignored box, or that holds the box's centre, is neither positive nor negative.
    pub fn new(
        per_image: &[Vec<CellTarget>],
        ignore: &[Vec<PixelBox>],
        rows: usize,
        columns: usize,
        device: &Device,
    ) -> Result<Self, TargetError> {
        let batch = per_image.len();
        let plane = rows * columns;
        let stride = STRIDE_PX as f64;
        let mut objectness_weight = vec![1f32; batch * plane];
        for (image, boxes) in ignore.iter().enumerate().take(batch) {
            for b in boxes {
                let (cx, cy) = b.centre();
                for row in 0..rows {
                    for column in 0..columns {
                        let (x, y) = ((column as f64 + 0.5) * stride, (row as f64 + 0.5) * stride);
                        let covers = x >= b.x_min && x <= b.x_max && y >= b.y_min && y <= b.y_max;
                        let holds_centre = (cx / stride).floor() == column as f64
                            && (cy / stride).floor() == row as f64;
                        if covers || holds_centre {
                            objectness_weight[image * plane + row * columns + column] = 0.0;
                        }
                    }
                }
            }
        }
        let mut positive = vec![0f32; batch * plane];
        let mut boxes = vec![0f32; batch * 4 * plane];
        let mut classes = vec![0f32; batch * CLASSES * plane];
        let mut positives = 0;
        for (image, cells) in per_image.iter().enumerate() {
            for t in cells {
                if t.class_id >= CLASSES {
                    return Err(TargetError::Class {
                        class_id: t.class_id,
                    });
                }
                let at = t.row * columns + t.column;
                positive[image * plane + at] = 1.0;
                objectness_weight[image * plane + at] = 1.0;
                let values = [t.offset_x, t.offset_y, t.log_width, t.log_height];
                for (channel, value) in values.into_iter().enumerate() {
                    boxes[(image * 4 + channel) * plane + at] = value as f32;
                }
                classes[(image * CLASSES + t.class_id) * plane + at] = 1.0;
                positives += 1;
            }
        }
        Ok(Self {
            positive: Tensor::from_vec(positive, (batch, 1, rows, columns), device)?,
            boxes: Tensor::from_vec(boxes, (batch, 4, rows, columns), device)?,
            classes: Tensor::from_vec(classes, (batch, CLASSES, rows, columns), device)?,
            objectness_weight: Tensor::from_vec(
                objectness_weight,
                (batch, 1, rows, columns),
                device,
            )?,
            positives,
        })
    }
}

/// How much each part weighs in the total.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LossWeights {
    pub objectness: f64,
    pub centre: f64,
    pub size: f64,
    pub class: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            objectness: 1.0,
            // Offsets are in cell units (a 16 px cell): an error of a quarter cell is 4 px.
            centre: 5.0,
            size: 2.0,
            class: 1.0,
        }
    }
}

/// The loss and its parts (each already divided by the positives).
#[derive(Debug, Clone)]
pub struct Loss {
    pub total: Tensor,
    pub objectness: f32,
    pub centre: f32,
    pub size: f32,
    pub class: f32,
}

/// Binary cross-entropy on logits, element-wise, in the form that cannot overflow:
/// max(x, 0) − x·t + ln(1 + e^−|x|).
pub fn bce_with_logits(logits: &Tensor, targets: &Tensor) -> candle_core::Result<Tensor> {
    let softplus_tail = ((logits.abs()?.neg()?.exp()? + 1.0)?).log()?;
    (logits.relu()? - (logits * targets)?)? + softplus_tail
}

/// The loss of `raw` [batch, 8, rows, columns] against `targets`: objectness BCE summed over every
/// scored cell, centre and size squared errors and class BCE summed over positive cells, all divided by
/// the number of positives (at least 1), so a batch's loss does not scale with its size.
pub fn loss(raw: &Tensor, targets: &Targets, weights: &LossWeights) -> Result<Loss, TargetError> {
    let (batch, _, rows, columns) = targets.boxes.dims4()?;
    let expected = vec![batch, 5 + CLASSES, rows, columns];
    if raw.dims() != expected.as_slice() {
        return Err(TargetError::Shape {
            expected,
            found: raw.dims().to_vec(),
        });
    }
    let per_positive = 1.0 / targets.positives.max(1) as f64;
    let positive = &targets.positive;
    let objectness = (bce_with_logits(&raw.narrow(1, 4, 1)?, positive)?
        .mul(&targets.objectness_weight)?
        .sum_all()?
        * per_positive)?;
    let centre_pred = ((candle_nn::ops::sigmoid(&raw.narrow(1, 0, 2)?)? * 2.0)? - 0.5)?;
    let centre_error = (centre_pred - targets.boxes.narrow(1, 0, 2)?)?.sqr()?;
    let centre = (centre_error.broadcast_mul(positive)?.sum_all()? * per_positive)?;
    let size_error = (raw.narrow(1, 2, 2)? - targets.boxes.narrow(1, 2, 2)?)?.sqr()?;
    let size = (size_error.broadcast_mul(positive)?.sum_all()? * per_positive)?;
    let class_error = bce_with_logits(&raw.narrow(1, 5, CLASSES)?, &targets.classes)?;
    let class = (class_error.broadcast_mul(positive)?.sum_all()? * per_positive)?;
    let total = ((((&objectness * weights.objectness)? + (&centre * weights.centre)?)?
        + (&size * weights.size)?)?
        + (&class * weights.class)?)?;
    Ok(Loss {
        total,
        objectness: objectness.to_scalar()?,
        centre: centre.to_scalar()?,
        size: size.to_scalar()?,
        class: class.to_scalar()?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input_box(class_id: usize, x_min: f64, y_min: f64, x_max: f64, y_max: f64) -> InputBox {
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

    /// (row, column, offset x, offset y) of each cell, sorted.
    fn placed(cells: &[CellTarget]) -> Vec<(usize, usize, f64, f64)> {
        let mut v: Vec<_> = cells
            .iter()
            .map(|t| (t.row, t.column, t.offset_x, t.offset_y))
            .collect();
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v
    }

    #[test]
    fn a_box_goes_to_its_centre_cell_and_the_neighbours_its_centre_leans_to() {
        // Centre (56, 28) = (3.5, 1.75) cells: cell (row 1, column 3), offsets 0.5 and 0.75. At
        // exactly ½ across there is no column neighbour; 0.75 down leans to row 2, where the
        // centre is −0.25 of a cell from its top. 32 × 16 px against a 32 px anchor: ln 1 and
        // ln ½.
        let cells = assign(&[input_box(1, 40.0, 20.0, 72.0, 36.0)], 4, 6, 32.0).unwrap();
        assert_eq!(placed(&cells), vec![(1, 3, 0.5, 0.75), (2, 3, 0.5, -0.25)]);
        for t in &cells {
            assert_eq!(t.class_id, 1);
            assert!(t.log_width.abs() < 1e-12);
            assert!((t.log_height - 0.5f64.ln()).abs() < 1e-12);
        }
        // Centre (20, 40) = (1.25, 2.5): cell (2, 1) and the column to its left, where the
        // centre is 1.25 cells from the corner.
        let cells = assign(&[input_box(0, 10.0, 30.0, 30.0, 50.0)], 4, 6, 32.0).unwrap();
        assert_eq!(placed(&cells), vec![(2, 0, 1.25, 0.5), (2, 1, 0.25, 0.5)]);
    }

    #[test]
    fn border_centres_belong_to_the_next_cell_and_off_grid_cells_are_left_out() {
        // Centre (64, 16): exactly the top-left corner of cell (1, 4), offsets 0; it leans left
        // and up, to cells (1, 3) and (0, 4), where it sits 1 cell from their corners.
        let cells = assign(&[input_box(0, 60.0, 12.0, 68.0, 20.0)], 4, 6, 32.0).unwrap();
        assert_eq!(
            placed(&cells),
            vec![(0, 4, 0.0, 1.0), (1, 3, 1.0, 0.0), (1, 4, 0.0, 0.0)]
        );
        // Centre (4, 40): leans left off the grid; only its own cell.
        let cells = assign(&[input_box(0, 0.0, 36.0, 8.0, 44.0)], 4, 6, 32.0).unwrap();
        assert_eq!(placed(&cells), vec![(2, 0, 0.25, 0.5)]);
        // Centre x = 96 = 6 cells: one past the last column.
        let off = input_box(0, 90.0, 0.0, 102.0, 10.0);
        // Centre y = -1: above the grid.
        let above = input_box(0, 0.0, -6.0, 10.0, 4.0);
        // Degenerate: no width.
        let flat = input_box(0, 10.0, 10.0, 10.0, 20.0);
        assert!(assign(&[off, above, flat], 4, 6, 32.0).unwrap().is_empty());
    }

    #[test]
    fn a_shared_cell_goes_to_a_centre_before_a_neighbour_then_to_the_larger_box() {
        // Both centres in cell (0, 0), leaning off the grid: the larger box keeps the cell.
        let small = input_box(0, 2.0, 2.0, 10.0, 10.0);
        let large = input_box(2, 0.0, 0.0, 14.0, 14.0);
        for order in [[small, large], [large, small]] {
            let cells = assign(&order, 2, 2, 32.0).unwrap();
            assert_eq!(cells.len(), 1);
            assert_eq!(cells[0].class_id, 2);
        }
        // A vehicle centred at (20, 8) = (1.25, 0.5) leans into cell (0, 0), where a small
        // person has its centre: the person keeps it, the vehicle has its own cell.
        let vehicle = input_box(2, 0.0, 0.0, 40.0, 16.0);
        for order in [[small, vehicle], [vehicle, small]] {
            let cells = assign(&order, 2, 2, 32.0).unwrap();
            let mut owners: Vec<_> = cells.iter().map(|t| (t.column, t.class_id)).collect();
            owners.sort();
            assert_eq!(owners, vec![(0, 0), (1, 2)]);
        }
        assert!(matches!(
            assign(&[input_box(3, 0.0, 0.0, 8.0, 8.0)], 2, 2, 32.0),
            Err(TargetError::Class { class_id: 3 })
        ));
    }

    #[test]
    fn the_loss_matches_a_hand_computation() {
        // One image, a 1 × 2 grid; cell (0, 1) holds an animal at offsets (0.25, 0.5), log-size
        // (0.1, −0.2).
        let target = CellTarget {
            row: 0,
            column: 1,
            offset_x: 0.25,
            offset_y: 0.5,
            log_width: 0.1,
            log_height: -0.2,
            class_id: 1,
        };
        let device = Device::Cpu;
        let targets = Targets::new(&[vec![target]], &[vec![]], 1, 2, &device).unwrap();
        assert_eq!(targets.positives, 1);
        // Raw values per channel for cells (0, 0) and (0, 1).
        let raw: [[f32; 2]; 8] = [
            [0.3, 0.0],
            [-0.2, 1.0],
            [0.5, 0.4],
            [0.0, -0.1],
            [-2.0, 1.5],
            [0.7, -1.0],
            [0.1, 2.0],
            [0.0, -0.5],
        ];
        let flat: Vec<f32> = raw.iter().flatten().copied().collect();
        let raw_tensor = Tensor::from_vec(flat, (1, 8, 1, 2), &device).unwrap();
        let weights = LossWeights {
            objectness: 1.0,
            centre: 3.0,
            size: 2.0,
            class: 0.5,
        };
        let got = loss(&raw_tensor, &targets, &weights).unwrap();

        let sigmoid = |x: f64| 1.0 / (1.0 + (-x).exp());
        let bce = |x: f64, t: f64| -(t * sigmoid(x).ln() + (1.0 - t) * (1.0 - sigmoid(x)).ln());
        let r = |channel: usize, cell: usize| raw[channel][cell] as f64;
        let objectness = bce(r(4, 0), 0.0) + bce(r(4, 1), 1.0);
        let centre = (2.0 * sigmoid(r(0, 1)) - 0.5 - 0.25).powi(2)
            + (2.0 * sigmoid(r(1, 1)) - 0.5 - 0.5).powi(2);
        let size = (r(2, 1) - 0.1).powi(2) + (r(3, 1) + 0.2).powi(2);
        let class = bce(r(5, 1), 0.0) + bce(r(6, 1), 1.0) + bce(r(7, 1), 0.0);
        let total = objectness + 3.0 * centre + 2.0 * size + 0.5 * class;
        for (name, got, want) in [
            ("objectness", got.objectness as f64, objectness),
            ("centre", got.centre as f64, centre),
            ("size", got.size as f64, size),
            ("class", got.class as f64, class),
            ("total", got.total.to_scalar::<f32>().unwrap() as f64, total),
        ] {
            assert!((got - want).abs() < 1e-5, "{name}: {got} against {want}");
        }
        // A cut-off hazard over both cells: the negative cell (0, 0) drops out of the objectness,
        // the positive (0, 1) stays; nothing else changes.
        let cut_off = PixelBox {
            x_min: 0.0,
            y_min: 0.0,
            x_max: 30.0,
            y_max: 16.0,
        };
        let ignoring = Targets::new(&[vec![target]], &[vec![cut_off]], 1, 2, &device).unwrap();
        let got = loss(&raw_tensor, &ignoring, &weights).unwrap();
        assert!((got.objectness as f64 - bce(r(4, 1), 1.0)).abs() < 1e-5);
        assert!((got.centre as f64 - centre).abs() < 1e-6);
        assert!((got.class as f64 - class).abs() < 1e-5);

        // The stable form agrees with the naive one where both are finite, and stays finite
        // where the naive one is not.
        let logits = Tensor::new(&[-80f32, 80.0], &device).unwrap();
        let ones = Tensor::new(&[1f32, 0.0], &device).unwrap();
        let values: Vec<f32> = bce_with_logits(&logits, &ones).unwrap().to_vec1().unwrap();
        assert!((values[0] - 80.0).abs() < 1e-3 && (values[1] - 80.0).abs() < 1e-3);
    }
}
