//! Box overlap as the tracker's distance (seed 000, equations 2–3). Boxes are the detectors'
//! [`PixelBox`] (pixels, x right, y down).

pub use crate::vision::yolo::PixelBox;

/// Intersection over union of two boxes, in [0, 1] (equation 2); 0 when either box is empty or
/// not finite.
pub fn iou(a: &PixelBox, b: &PixelBox) -> f64 {
    let finite = |p: &PixelBox| {
        [p.x_min, p.y_min, p.x_max, p.y_max]
            .iter()
            .all(|c| c.is_finite())
    };
    if !(finite(a) && finite(b)) {
        return 0.0;
    }
    a.iou(b).clamp(0.0, 1.0)
}

/// The IoU dissimilarity `s_IOU = 1 − IOU`, in [0, 1] (equation 3): 0 for identical boxes, 1 for
/// disjoint ones. It is the `s_distance` of equation 5.
pub fn iou_dissimilarity(a: &PixelBox, b: &PixelBox) -> f64 {
    1.0 - iou(a, b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// IoU by counting the cells of a fine grid that fall in each box: independent of the
    /// closed form and exact for boxes on the grid.
    fn iou_by_counting(a: &PixelBox, b: &PixelBox, cell: f64) -> f64 {
        let inside = |p: &PixelBox, x: f64, y: f64| {
            x >= p.x_min && x < p.x_max && y >= p.y_min && y < p.y_max
        };
        let (mut both, mut either) = (0usize, 0usize);
        let steps = (40.0 / cell) as usize;
        for i in 0..steps {
            for j in 0..steps {
                let (x, y) = ((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell);
                let (in_a, in_b) = (inside(a, x, y), inside(b, x, y));
                both += usize::from(in_a && in_b);
                either += usize::from(in_a || in_b);
            }
        }
        if either == 0 {
            0.0
        } else {
            both as f64 / either as f64
        }
    }

    #[test]
    fn iou_equals_counting_on_random_grid_boxes() {
        let mut rng = StdRng::seed_from_u64(2);
        let random_box = |rng: &mut StdRng| {
            // Corners on a 0.5 grid inside [0, 40].
            let x0 = rng.random_range(0..70) as f64 * 0.5;
            let y0 = rng.random_range(0..70) as f64 * 0.5;
            let w = rng.random_range(1..20) as f64 * 0.5;
            let h = rng.random_range(1..20) as f64 * 0.5;
            PixelBox {
                x_min: x0,
                y_min: y0,
                x_max: (x0 + w).min(40.0),
                y_max: (y0 + h).min(40.0),
            }
        };
        for _ in 0..200 {
            let a = random_box(&mut rng);
            let b = random_box(&mut rng);
            let expected = iou_by_counting(&a, &b, 0.25);
            assert!((iou(&a, &b) - expected).abs() < 1e-12, "{a:?} {b:?}");
            assert!((iou_dissimilarity(&a, &b) - (1.0 - expected)).abs() < 1e-12);
            assert!((iou(&a, &b) - iou(&b, &a)).abs() < 1e-15, "symmetric");
        }
    }

    #[test]
    fn identical_disjoint_and_degenerate_boxes() {
        let a = PixelBox::from_centre(10.0, 10.0, 4.0, 2.0);
        assert_eq!(iou(&a, &a), 1.0);
        assert_eq!(iou_dissimilarity(&a, &a), 0.0);
        let far = PixelBox::from_centre(30.0, 10.0, 4.0, 2.0);
        assert_eq!(iou_dissimilarity(&a, &far), 1.0);
        // Half-overlapping along x: intersection 2×2 = 4, union 8 + 8 − 4 = 12.
        let half = PixelBox::from_centre(12.0, 10.0, 4.0, 2.0);
        assert!((iou(&a, &half) - 4.0 / 12.0).abs() < 1e-15);
        let empty = PixelBox::from_centre(10.0, 10.0, 0.0, 0.0);
        assert_eq!(iou(&empty, &empty), 0.0);
        let nan = PixelBox::from_centre(f64::NAN, 10.0, 4.0, 2.0);
        assert_eq!(iou(&a, &nan), 0.0);
    }
}
