//! Bounding-box prediction (BBP) with PTU rotation compensation (seed 001, §4.3).
//!
//! When the PTU turns between two frames, everything in the image shifts by about f·Δψ pixels;
//! a tracker that searches around the previous box loses a target the PTU jumped away from. The
//! seed predicts the box centre from the PTU's rotation:
//!
//! x_t = f·(x_{t−1} − f·ψ) / (x_{t−1}·ψ + y_{t−1}·ϕ + f),
//! y_t = f·(y_{t−1} − f·ϕ) / (x_{t−1}·ψ + y_{t−1}·ϕ + f),
//!
//! with ψ, ϕ the pan and tilt change and f in pixels. This is the first-order (small-angle)
//! rotation of the ray (x, y, f). The seed prints the denominator's tilt term as −ϕ·y_{t−1}; a
//! rotation that moves y by −f·ϕ in the numerator adds +y·ϕ to the depth (the pan terms show the
//! same pairing), and the test below shows the printed sign is first-order wrong against a real
//! pinhole projection, so this module uses +.
//!
//! Like the seed, it treats the PTU's pan as a turn about the camera's own vertical axis. With the
//! camera tilted up by ϕ0 a pan about the PTU's vertical turns it by Δψ·cos ϕ0 about that axis
//! and rolls it by Δψ·sin ϕ0: at the 3°–7° of an approach, under 1 % of the shift.
//!
//! Image coordinates are those of Eq. 5: offsets from the principal point, x to the right,
//! y **up**, pixels; a positive pan turns the camera to the right, a positive tilt up.

use thiserror::Error;

/// A tracker's box: its centre (offset from the principal point, x right, y up) and size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoundingBox {
    pub centre_px: [f64; 2],
    pub size_px: [f64; 2],
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum BbpError {
    #[error("{what} is not a finite number ({value})")]
    NonFinite { what: &'static str, value: f64 },
    #[error("the focal length must be a finite number of pixels > 0, got {0}")]
    FocalLength(f64),
    #[error(
        "the rotation ({pan_change_rad:.4}, {tilt_change_rad:.4}) rad turns the box centre \
         behind the camera: the PTU jumped too far for a prediction"
    )]
    BehindCamera {
        pan_change_rad: f64,
        tilt_change_rad: f64,
    },
}

fn finite(what: &'static str, value: f64) -> Result<f64, BbpError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(BbpError::NonFinite { what, value })
    }
}

/// §4.3's prediction of where a point at `previous_px` appears after the camera pans by
/// `pan_change_rad` and tilts by `tilt_change_rad`.
pub fn predict_centre(
    previous_px: [f64; 2],
    pan_change_rad: f64,
    tilt_change_rad: f64,
    focal_px: f64,
) -> Result<[f64; 2], BbpError> {
    if !(focal_px.is_finite() && focal_px > 0.0) {
        return Err(BbpError::FocalLength(focal_px));
    }
    let x = finite("box centre x", previous_px[0])?;
    let y = finite("box centre y", previous_px[1])?;
    let psi = finite("pan change", pan_change_rad)?;
    let phi = finite("tilt change", tilt_change_rad)?;
    let depth = x * psi + y * phi + focal_px;
    if depth <= 0.0 {
        return Err(BbpError::BehindCamera {
            pan_change_rad,
            tilt_change_rad,
        });
    }
    Ok([
        focal_px * (x - focal_px * psi) / depth,
        focal_px * (y - focal_px * phi) / depth,
    ])
}

/// A tracker's helper: remembers the PTU's last angles and moves each new search box by the
/// rotation since, keeping its size (scale is the tracker's own business, e.g. DSST's).
#[derive(Debug, Clone, PartialEq)]
pub struct RotationCompensator {
    focal_px: f64,
    last_ptu_rad: Option<(f64, f64)>,
}

impl RotationCompensator {
    pub fn new(focal_px: f64) -> Result<Self, BbpError> {
        if !(focal_px.is_finite() && focal_px > 0.0) {
            return Err(BbpError::FocalLength(focal_px));
        }
        Ok(Self {
            focal_px,
            last_ptu_rad: None,
        })
    }

    /// The box to search in the frame taken at PTU angles (`pan_rad`, `tilt_rad`), given the
    /// box found in the previous frame. The first frame has nothing to compensate.
    pub fn predict(
        &mut self,
        previous: &BoundingBox,
        pan_rad: f64,
        tilt_rad: f64,
    ) -> Result<BoundingBox, BbpError> {
        finite("PTU pan", pan_rad)?;
        finite("PTU tilt", tilt_rad)?;
        let centre_px = match self.last_ptu_rad {
            Some((last_pan, last_tilt)) => predict_centre(
                previous.centre_px,
                pan_rad - last_pan,
                tilt_rad - last_tilt,
                self.focal_px,
            )?,
            None => previous.centre_px,
        };
        self.last_ptu_rad = Some((pan_rad, tilt_rad));
        Ok(BoundingBox {
            centre_px,
            size_px: previous.size_px,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::approach::ptu_camera_offset_px;
    use nalgebra::Vector3;

    const F_PX: f64 = 26_666.7; // 100 mm behind 3.75 µm pixels

    /// A pinhole camera turned by pan ψ about its own vertical (y) axis, then tilted by ϕ about
    /// its new horizontal (x) axis: where does the ray through `pixel` land? Exact rotation, by
    /// hand, with no small-angle step.
    fn exact(pixel: [f64; 2], psi: f64, phi: f64) -> [f64; 2] {
        let point = Vector3::new(pixel[0], pixel[1], F_PX);
        let (sp, cp) = psi.sin_cos();
        let (st, ct) = phi.sin_cos();
        // The turned camera's axes in the old camera frame.
        let x1 = Vector3::new(cp, 0.0, -sp);
        let z1 = Vector3::new(sp, 0.0, cp);
        let y1 = Vector3::new(0.0, 1.0, 0.0);
        let z2 = z1 * ct + y1 * st;
        let y2 = y1 * ct - z1 * st;
        let depth = point.dot(&z2);
        [F_PX * point.dot(&x1) / depth, F_PX * point.dot(&y2) / depth]
    }

    fn printed_sign(pixel: [f64; 2], psi: f64, phi: f64) -> [f64; 2] {
        let depth = pixel[0] * psi - pixel[1] * phi + F_PX;
        [
            F_PX * (pixel[0] - F_PX * psi) / depth,
            F_PX * (pixel[1] - F_PX * phi) / depth,
        ]
    }

    fn miss(a: [f64; 2], b: [f64; 2]) -> f64 {
        (a[0] - b[0]).hypot(a[1] - b[1])
    }

    #[test]
    fn the_prediction_follows_a_pinhole_rotation_to_second_order() {
        for pixel in [[0.0, 0.0], [400.0, 300.0], [-600.0, 450.0], [350.0, -420.0]] {
            for (psi, phi) in [(2e-3, 1e-3), (-3e-3, 2e-3), (1e-3, -4e-3)] {
                let truth = exact(pixel, psi, phi);
                let shift = miss(truth, pixel);
                let ours = predict_centre(pixel, psi, phi, F_PX).unwrap();
                // Tens of pixels of shift, predicted to a hundredth of a pixel.
                assert!(shift > 20.0);
                assert!(
                    miss(ours, truth) < 0.02,
                    "{pixel:?} {psi} {phi}: {ours:?} vs {truth:?}"
                );
                // Second order: half the rotation, a quarter of the error (or below rounding).
                let half = miss(
                    predict_centre(pixel, psi / 2.0, phi / 2.0, F_PX).unwrap(),
                    exact(pixel, psi / 2.0, phi / 2.0),
                );
                let full = miss(ours, truth);
                if full > 1e-6 {
                    assert!(half < 0.3 * full, "{pixel:?}: {half} vs {full}");
                }
            }
        }
    }

    #[test]
    fn the_printed_tilt_sign_is_first_order_wrong() {
        let pixel = [450.0, 400.0];
        let (psi, phi) = (2e-3, 3e-3);
        let truth = exact(pixel, psi, phi);
        let ours = miss(predict_centre(pixel, psi, phi, F_PX).unwrap(), truth);
        let printed = miss(printed_sign(pixel, psi, phi), truth);
        assert!(printed > 10.0 * ours, "printed {printed}, ours {ours}");
        // First order: halving the rotation only halves the printed form's error.
        let printed_half = miss(
            printed_sign(pixel, psi / 2.0, phi / 2.0),
            exact(pixel, psi / 2.0, phi / 2.0),
        );
        assert!(
            (0.4..0.6).contains(&(printed_half / printed)),
            "{printed_half} {printed}"
        );
    }

    /// The real use: a PTU (pan about the vertical, tilt about its horizontal axis, the camera
    /// looking out 5° up) jumps by a few mrad between frames while a world point stays put.
    #[test]
    fn a_ptu_jump_is_compensated_against_a_world_projection() {
        let ptu = Vector3::zeros();
        let target = Vector3::new(30.0, 900.0, 78.0);
        let (pan0, tilt0) = ((30.0f64 / 900.0).atan() + 2e-4, 0.0863);
        let mut compensator = RotationCompensator::new(F_PX).unwrap();
        let before = ptu_camera_offset_px(&ptu, pan0, tilt0, F_PX, &target).unwrap();
        let first = BoundingBox {
            centre_px: before,
            size_px: [40.0, 18.0],
        };
        assert_eq!(compensator.predict(&first, pan0, tilt0).unwrap(), first);
        let (pan1, tilt1) = (pan0 + 4e-3, tilt0 - 2.5e-3);
        let after = ptu_camera_offset_px(&ptu, pan1, tilt1, F_PX, &target).unwrap();
        let predicted = compensator.predict(&first, pan1, tilt1).unwrap();
        let shift = miss(after, before);
        assert!(shift > 100.0, "{shift}");
        assert!(
            miss(predicted.centre_px, after) < 0.01 * shift,
            "{predicted:?} vs {after:?}"
        );
        assert_eq!(predicted.size_px, first.size_px);
    }

    #[test]
    fn bad_input_is_a_named_error() {
        assert_eq!(
            predict_centre([0.0, 0.0], 0.0, 0.0, 0.0),
            Err(BbpError::FocalLength(0.0))
        );
        assert!(matches!(
            predict_centre([f64::NAN, 0.0], 0.0, 0.0, F_PX),
            Err(BbpError::NonFinite {
                what: "box centre x",
                ..
            })
        ));
        assert!(matches!(
            predict_centre([0.0, 0.0], f64::INFINITY, 0.0, F_PX),
            Err(BbpError::NonFinite {
                what: "pan change",
                ..
            })
        ));
        // A point far right of a camera panned far left lands behind it.
        assert!(matches!(
            predict_centre([-30_000.0, 0.0], 1.0, 0.0, F_PX),
            Err(BbpError::BehindCamera { .. })
        ));
        assert!(RotationCompensator::new(f64::NAN).is_err());
    }
}
