//! Leave-one-out validation: how well a grid predicts each measured point without it.

use serde::Serialize;

use super::{AxisScale, GridModel, ModelError};
use crate::profile::Profile;

/// One measured point predicted by the model built without it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LooPoint {
    pub knobs: Vec<f64>,
    pub measured_w: f64,
    pub predicted_w: f64,
    /// `|predicted − measured| / |measured| · 100`.
    pub abs_pct_error: f64,
}

/// Leave-one-out validation of a grid model.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LooReport {
    pub per_point: Vec<LooPoint>,
    /// Mean of the per-point absolute percentage errors.
    pub mape_pct: f64,
}

/// For each measured point, rebuilds the model on the full grid without it (so it becomes an
/// inferred point) and compares the prediction with the measurement.
pub fn leave_one_out(
    knob_names: &[String],
    points: &[(Vec<f64>, f64)],
    scale: AxisScale,
) -> Result<LooReport, ModelError> {
    let full = GridModel::from_samples(knob_names.to_vec(), points, scale)?;
    if points.len() < 2 {
        return Err(ModelError::TooFewForLoo(points.len()));
    }
    let mut per_point = Vec::with_capacity(points.len());
    let mut rest: Vec<(Vec<f64>, f64)> = Vec::with_capacity(points.len() - 1);
    for (i, (x, measured_w)) in points.iter().enumerate() {
        rest.clear();
        rest.extend(
            points
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, p)| p.clone()),
        );
        let model = GridModel::with_axes(knob_names.to_vec(), full.axes.clone(), &rest, scale)?;
        let predicted_w = model.eval(x).value;
        per_point.push(LooPoint {
            knobs: x.clone(),
            measured_w: *measured_w,
            predicted_w,
            abs_pct_error: (predicted_w - measured_w).abs() / measured_w.abs() * 100.0,
        });
    }
    let mape_pct = per_point.iter().map(|p| p.abs_pct_error).sum::<f64>() / per_point.len() as f64;
    Ok(LooReport {
        per_point,
        mape_pct,
    })
}

/// [`leave_one_out`] over a profile's total power.
pub fn leave_one_out_profile(profile: &Profile, scale: AxisScale) -> Result<LooReport, ModelError> {
    leave_one_out(&profile.knobs, &profile.power_points(), scale)
}
