//! N-dimensional grid models: measured points on a tensor grid, multilinear interpolation
//! between them, clamping outside, and inference of the grid points nobody measured.
//!
//! Layout: the grid's values are stored row-major, knob 0 slowest and the last knob fastest,
//! so the value at axis indices `(i_0, …, i_{n-1})` is `values()[Σ i_k · stride_k]` with
//! `stride_{n-1} = 1` and `stride_k = stride_{k+1} · len_{k+1}`.

use serde::Serialize;

use crate::profile::Profile;

mod inference;
mod loo;
mod power_model;

pub use loo::{leave_one_out, leave_one_out_profile, LooPoint, LooReport};
pub use power_model::PowerModel;

/// Most knobs one grid model interpolates over; `eval` keeps its 2^N corners on the stack.
pub const MAX_DIMS: usize = 8;
/// Most points one grid may hold (measured and inferred together).
pub const MAX_GRID_POINTS: usize = 1 << 20;
/// Most knobs a [`PowerModel`] reports clamping for (one bit each in [`Evaluation::clamped`]).
pub const MAX_MODEL_KNOBS: usize = 64;

/// The coordinate an axis interpolates in.
///
/// The default is [`AxisScale::Linear`], measured by leave-one-out on the seed's Jetson Nano
/// grids (test `seed_loo_prefers_the_default_scale`). On the predictions made by interpolation
/// (29 of 41), linear weights are better on every grid: mean absolute percentage error 1.72 %
/// against 2.19 % for ln weights (tracking 4×2: 3.88 / 4.88 %; landing: 0.31 / 0.71 %; landing
/// with the 22-px kernel: 0.78 / 0.85 %; the 5×5 CNN grid: 1.53 / 1.95 %). Over all 41
/// points ln weights come out ahead, 2.70 % against 2.86 %, but only through the grid-end
/// points that the affine fallback extrapolates, which a fully measured grid never uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub enum AxisScale {
    /// Weights are linear in the knob value.
    #[default]
    Linear,
    /// Weights are linear in ln(knob value); every axis value must be > 0.
    Log,
}

impl AxisScale {
    #[inline]
    fn coord(self, x: f64) -> f64 {
        match self {
            AxisScale::Linear => x,
            AxisScale::Log => x.ln(),
        }
    }
}

/// A mistake in the input of a model; point indices are 0-based positions in the input slice.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    #[error("a model needs at least one measured point")]
    NoPoints,
    #[error("{count} knobs: a grid model handles at most {MAX_DIMS}")]
    TooManyKnobs { count: usize },
    #[error("knob `{0}` is named twice")]
    DuplicateKnob(String),
    #[error("points[{point}] has {got} knob values, the model has {expected} knobs")]
    DimensionMismatch {
        point: usize,
        got: usize,
        expected: usize,
    },
    #[error("points[{point}]: knob `{knob}` = {value} is not finite")]
    NonFiniteKnob {
        point: usize,
        knob: String,
        value: f64,
    },
    #[error("points[{point}]: value {value} is not finite")]
    NonFiniteValue { point: usize, value: f64 },
    #[error(
        "knob `{knob}` = {value}: a log-scale axis needs values > 0 (use AxisScale::Linear for this knob's model)"
    )]
    NonPositiveOnLogAxis { knob: String, value: f64 },
    #[error("points[{first}] and points[{second}] are the same knob point {knobs:?}")]
    DuplicatePoint {
        first: usize,
        second: usize,
        knobs: Vec<f64>,
    },
    #[error(
        "the grid would hold {points} points (limit {MAX_GRID_POINTS}): the samples should share axis values"
    )]
    GridTooLarge { points: usize },
    #[error("axis of `{knob}` must hold strictly increasing finite values")]
    BadAxis { knob: String },
    #[error("points[{point}]: knob `{knob}` = {value} is not a value of its axis")]
    OffAxis {
        point: usize,
        knob: String,
        value: f64,
    },
    #[error("the query has {got} values, the model has {expected} knobs")]
    QueryDimension { got: usize, expected: usize },
    #[error("the query value of knob `{knob}` is NaN")]
    QueryNaN { knob: String },
    #[error("leave-one-out needs at least 2 measured points, got {0}")]
    TooFewForLoo(usize),
    #[error("base power {0} W must be finite")]
    BadBasePower(f64),
    #[error("an additive model over {0} knobs: at most {MAX_MODEL_KNOBS}")]
    TooManyModelKnobs(usize),
}

/// The result of evaluating a model at a query point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Evaluation {
    /// The interpolated value (W for power models).
    pub value: f64,
    /// True when any knob lay outside its axis and was clamped to the boundary.
    pub extrapolated: bool,
    /// Bit `i` set: knob `i` (in the model's knob order) was clamped.
    pub clamped: u64,
}

impl Evaluation {
    /// Whether knob `knob` (index in the model's knob order) was clamped.
    pub fn is_clamped(&self, knob: usize) -> bool {
        knob < 64 && self.clamped & (1 << knob) != 0
    }
}

/// A tensor grid over N knobs with a value at every grid point, measured or inferred.
#[derive(Debug, Clone, PartialEq)]
pub struct GridModel {
    knob_names: Vec<String>,
    scale: AxisScale,
    axes: Vec<Vec<f64>>,
    /// Axis values in interpolation coordinates (the values, or their logarithms).
    coords: Vec<Vec<f64>>,
    strides: Vec<usize>,
    values: Vec<f64>,
    measured: Vec<bool>,
}

fn check_names(knob_names: &[String]) -> Result<(), ModelError> {
    if knob_names.len() > MAX_DIMS {
        return Err(ModelError::TooManyKnobs {
            count: knob_names.len(),
        });
    }
    for (i, name) in knob_names.iter().enumerate() {
        if knob_names[..i].contains(name) {
            return Err(ModelError::DuplicateKnob(name.clone()));
        }
    }
    Ok(())
}

fn check_points(
    knob_names: &[String],
    points: &[(Vec<f64>, f64)],
    scale: AxisScale,
) -> Result<(), ModelError> {
    if points.is_empty() {
        return Err(ModelError::NoPoints);
    }
    for (p, (x, v)) in points.iter().enumerate() {
        if x.len() != knob_names.len() {
            return Err(ModelError::DimensionMismatch {
                point: p,
                got: x.len(),
                expected: knob_names.len(),
            });
        }
        for (&value, knob) in x.iter().zip(knob_names) {
            if !value.is_finite() {
                return Err(ModelError::NonFiniteKnob {
                    point: p,
                    knob: knob.clone(),
                    value,
                });
            }
            if scale == AxisScale::Log && value <= 0.0 {
                return Err(ModelError::NonPositiveOnLogAxis {
                    knob: knob.clone(),
                    value,
                });
            }
        }
        if !v.is_finite() {
            return Err(ModelError::NonFiniteValue {
                point: p,
                value: *v,
            });
        }
    }
    Ok(())
}

impl GridModel {
    /// Builds a grid whose axes are the sorted distinct values each knob takes in `points`
    /// (`(knob values, value)` pairs). Grid points without a sample are inferred, see
    /// [`GridModel::with_axes`].
    pub fn from_samples(
        knob_names: Vec<String>,
        points: &[(Vec<f64>, f64)],
        scale: AxisScale,
    ) -> Result<GridModel, ModelError> {
        check_names(&knob_names)?;
        check_points(&knob_names, points, scale)?;
        let axes = (0..knob_names.len())
            .map(|k| {
                let mut axis: Vec<f64> = points.iter().map(|(x, _)| x[k]).collect();
                axis.sort_by(f64::total_cmp);
                axis.dedup();
                axis
            })
            .collect();
        Self::with_axes(knob_names, axes, points, scale)
    }

    /// Builds a model of a profile's total power over its knobs.
    pub fn from_profile(profile: &Profile, scale: AxisScale) -> Result<GridModel, ModelError> {
        Self::from_samples(profile.knobs.clone(), &profile.power_points(), scale)
    }

    /// Builds a grid on given axes (strictly increasing) from points lying on them.
    ///
    /// Grid points without a sample are inferred from the others, as powprofiler does, by
    /// linear interpolation: each missing point that has known neighbours on both sides along
    /// some axis gets the mean of those 1-D interpolations (in the axis scale's coordinates);
    /// points so filled count as known in the next round, until no round fills anything. Points
    /// still missing (beyond every known neighbour on every axis) get a least-squares affine fit
    /// over the measured points. A multilinear function is thus reproduced exactly wherever the
    /// interpolation rounds reach, and an affine one everywhere.
    pub fn with_axes(
        knob_names: Vec<String>,
        axes: Vec<Vec<f64>>,
        points: &[(Vec<f64>, f64)],
        scale: AxisScale,
    ) -> Result<GridModel, ModelError> {
        check_names(&knob_names)?;
        if axes.len() != knob_names.len() {
            return Err(ModelError::DimensionMismatch {
                point: 0,
                got: axes.len(),
                expected: knob_names.len(),
            });
        }
        check_points(&knob_names, points, scale)?;
        let mut total: usize = 1;
        for (axis, knob) in axes.iter().zip(&knob_names) {
            let increasing = axis.windows(2).all(|w| w[0] < w[1]);
            if axis.is_empty() || !increasing || !axis.iter().all(|v| v.is_finite()) {
                return Err(ModelError::BadAxis { knob: knob.clone() });
            }
            if let Some(&value) = axis.iter().find(|&&v| scale == AxisScale::Log && v <= 0.0) {
                return Err(ModelError::NonPositiveOnLogAxis {
                    knob: knob.clone(),
                    value,
                });
            }
            total = total.saturating_mul(axis.len());
        }
        if total > MAX_GRID_POINTS {
            return Err(ModelError::GridTooLarge { points: total });
        }

        let n = axes.len();
        let mut strides = vec![1usize; n];
        for k in (0..n.saturating_sub(1)).rev() {
            strides[k] = strides[k + 1] * axes[k + 1].len();
        }
        let coords = axes
            .iter()
            .map(|a| a.iter().map(|&v| scale.coord(v)).collect())
            .collect();

        let mut values = vec![0.0; total];
        let mut measured = vec![false; total];
        let mut source = vec![usize::MAX; total];
        for (p, (x, v)) in points.iter().enumerate() {
            let mut cell = 0;
            for k in 0..n {
                // Exact match: the axes hold the very values the samples were taken at.
                let i =
                    axes[k]
                        .iter()
                        .position(|&a| a == x[k])
                        .ok_or_else(|| ModelError::OffAxis {
                            point: p,
                            knob: knob_names[k].clone(),
                            value: x[k],
                        })?;
                cell += i * strides[k];
            }
            if measured[cell] {
                return Err(ModelError::DuplicatePoint {
                    first: source[cell],
                    second: p,
                    knobs: x.clone(),
                });
            }
            measured[cell] = true;
            source[cell] = p;
            values[cell] = *v;
        }

        let mut model = GridModel {
            knob_names,
            scale,
            axes,
            coords,
            strides,
            values,
            measured,
        };
        model.infer_missing();
        Ok(model)
    }

    /// Axis indices of grid point `cell`.
    fn unravel(&self, mut cell: usize, idx: &mut [usize]) {
        for (k, stride) in self.strides.iter().enumerate() {
            idx[k] = cell / stride;
            cell %= stride;
        }
    }
    /// Number of knobs.
    pub fn dims(&self) -> usize {
        self.axes.len()
    }

    pub fn knob_names(&self) -> &[String] {
        &self.knob_names
    }

    pub fn scale(&self) -> AxisScale {
        self.scale
    }

    /// Sorted axis values of each knob.
    pub fn axes(&self) -> &[Vec<f64>] {
        &self.axes
    }

    /// Values at every grid point, row-major (see the module's layout note).
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Knob values of the grid points that were inferred rather than measured.
    pub fn inferred_points(&self) -> Vec<Vec<f64>> {
        let mut idx = vec![0usize; self.dims()];
        (0..self.values.len())
            .filter(|&c| !self.measured[c])
            .map(|c| {
                self.unravel(c, &mut idx);
                idx.iter()
                    .enumerate()
                    .map(|(k, &i)| self.axes[k][i])
                    .collect()
            })
            .collect()
    }

    /// The same model with `delta` added to every value: e.g. `-base_power_w` to turn a
    /// task's measured total power into the power it adds above the base load.
    pub fn shifted(&self, delta: f64) -> GridModel {
        let mut m = self.clone();
        for v in &mut m.values {
            *v += delta;
        }
        m
    }

    /// Multilinear interpolation at `x` (one value per knob, in the model's order). A value
    /// outside its axis is clamped to the nearest end and reported. A NaN coordinate gives a
    /// NaN value; [`GridModel::try_eval`] rejects it instead.
    ///
    /// # Panics
    /// When `x.len() != self.dims()`: the caller built the model and knows its knobs; use
    /// [`GridModel::try_eval`] for queries from outside.
    #[inline]
    pub fn eval(&self, x: &[f64]) -> Evaluation {
        assert_eq!(
            x.len(),
            self.dims(),
            "query length must equal the model's knob count"
        );
        // One monomorphised body per dimension and scale: the corner arrays get exact sizes,
        // and the linear body holds no `ln` (LLVM would otherwise speculate the call and
        // select its result away, paying for it on every linear query).
        macro_rules! dispatch {
            ($($n:literal => $c:literal),*) => {
                match (self.dims(), self.scale) {
                    $(($n, AxisScale::Linear) => self.eval_n::<$n, $c, false>(x),
                      ($n, AxisScale::Log) => self.eval_n::<$n, $c, true>(x),)*
                    (_, AxisScale::Linear) => self.eval_n::<8, 256, false>(x),
                    (_, AxisScale::Log) => self.eval_n::<8, 256, true>(x),
                }
            };
        }
        dispatch!(0 => 1, 1 => 2, 2 => 4, 3 => 8, 4 => 16, 5 => 32, 6 => 64, 7 => 128)
    }

    /// [`GridModel::eval`] with the query checked: length and no NaN.
    pub fn try_eval(&self, x: &[f64]) -> Result<Evaluation, ModelError> {
        if x.len() != self.dims() {
            return Err(ModelError::QueryDimension {
                got: x.len(),
                expected: self.dims(),
            });
        }
        if let Some(k) = x.iter().position(|v| v.is_nan()) {
            return Err(ModelError::QueryNaN {
                knob: self.knob_names[k].clone(),
            });
        }
        Ok(self.eval(x))
    }

    #[inline]
    fn eval_n<const N: usize, const C: usize, const LOG: bool>(&self, x: &[f64]) -> Evaluation {
        let mut weight = [0.0f64; N];
        let mut delta = [0usize; N];
        let mut base = 0usize;
        let mut clamped = 0u64;
        for k in 0..N {
            let axis = &self.axes[k];
            let xk = x[k];
            if xk.is_nan() {
                return Evaluation {
                    value: f64::NAN,
                    extrapolated: false,
                    clamped: 0,
                };
            }
            let last = axis.len() - 1;
            let (first_v, last_v) = (axis[0], axis[last]);
            clamped |= u64::from(xk < first_v || xk > last_v) << k;
            if last == 0 {
                continue;
            }
            let xc = xk.clamp(first_v, last_v);
            // Cell index: how many inner knots lie at or below x. A branch-free count beats
            // a binary search on the short axes of QoS grids.
            let inner = &axis[1..last];
            let lo = if inner.len() <= 16 {
                inner.iter().map(|&a| usize::from(a <= xc)).sum::<usize>()
            } else {
                inner.partition_point(|&a| a <= xc)
            };
            let t = &self.coords[k];
            let tx = if LOG { xc.ln() } else { xc };
            weight[k] = (tx - t[lo]) / (t[lo + 1] - t[lo]);
            base += lo * self.strides[k];
            delta[k] = self.strides[k];
        }

        // Gather the 2^N corners: bit k of the corner index selects the upper neighbour on
        // axis k; each offset extends the one without its lowest set bit.
        let mut offset = [0usize; C];
        let mut corner = [0.0f64; C];
        offset[0] = base;
        corner[0] = self.values[base];
        for c in 1..C {
            let low = c.trailing_zeros() as usize;
            offset[c] = offset[c & (c - 1)] + delta[low];
            corner[c] = self.values[offset[c]];
        }
        // Collapse axis 0 (the lowest bit), then axis 1, …; `(1 − w)·a + w·b` is exact at
        // w = 0 and w = 1, so grid points come back unchanged.
        let mut len = C;
        for &w in &weight {
            len /= 2;
            for c in 0..len {
                corner[c] = (1.0 - w) * corner[2 * c] + w * corner[2 * c + 1];
            }
        }
        Evaluation {
            value: corner[0],
            extrapolated: clamped != 0,
            clamped,
        }
    }
}

#[cfg(test)]
mod tests;
