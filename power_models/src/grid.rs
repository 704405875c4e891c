//! N-dimensional grid models: measured points on a tensor grid, multilinear interpolation
//! between them, clamping outside, and inference of the grid points nobody measured.
//!
//! Layout: the grid's values are stored row-major, knob 0 slowest and the last knob fastest,
//! so the value at axis indices `(i_0, …, i_{n-1})` is `values()[Σ i_k · stride_k]` with
//! `stride_{n-1} = 1` and `stride_k = stride_{k+1} · len_{k+1}`.

use serde::Serialize;

use crate::profile::Profile;

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

    fn infer_missing(&mut self) {
        let n = self.dims();
        let mut known = self.measured.clone();
        let mut idx = vec![0usize; n];
        let mut updates: Vec<(usize, f64)> = Vec::new();
        loop {
            updates.clear();
            for cell in (0..self.values.len()).filter(|&c| !known[c]) {
                self.unravel(cell, &mut idx);
                let (mut sum, mut count) = (0.0, 0usize);
                for (k, &i) in idx.iter().enumerate() {
                    let stride = self.strides[k];
                    let below = (0..i).rev().find(|&j| known[cell - (i - j) * stride]);
                    let above =
                        (i + 1..self.axes[k].len()).find(|&j| known[cell + (j - i) * stride]);
                    if let (Some(lo), Some(hi)) = (below, above) {
                        let t = &self.coords[k];
                        let w = (t[i] - t[lo]) / (t[hi] - t[lo]);
                        let v_lo = self.values[cell - (i - lo) * stride];
                        let v_hi = self.values[cell + (hi - i) * stride];
                        sum += (1.0 - w) * v_lo + w * v_hi;
                        count += 1;
                    }
                }
                if count > 0 {
                    updates.push((cell, sum / count as f64));
                }
            }
            if updates.is_empty() {
                break;
            }
            // All of a round's estimates use the previous round's values: order-independent.
            for &(cell, v) in &updates {
                self.values[cell] = v;
                known[cell] = true;
            }
        }

        if known.iter().all(|&k| k) {
            return;
        }
        let fit = self.affine_fit();
        for (cell, &k) in known.iter().enumerate() {
            if !k {
                self.unravel(cell, &mut idx);
                self.values[cell] =
                    fit.eval(idx.iter().enumerate().map(|(k, &i)| self.coords[k][i]));
            }
        }
    }

    /// Least-squares affine fit `v ≈ c + Σ b_k (t_k − mean_k)` over the measured points, in
    /// interpolation coordinates. Directions the points do not span get `b_k = 0`, so the fit
    /// is constant along them instead of blowing up.
    fn affine_fit(&self) -> AffineFit {
        let n = self.dims();
        let cells: Vec<usize> = (0..self.values.len())
            .filter(|&c| self.measured[c])
            .collect();
        let m = cells.len();
        let mut idx = vec![0usize; n];
        // Column 0 is the intercept, column k+1 the centred coordinate of knob k.
        let mut columns = vec![vec![1.0; m]; n + 1];
        for (r, &cell) in cells.iter().enumerate() {
            self.unravel(cell, &mut idx);
            for k in 0..n {
                columns[k + 1][r] = self.coords[k][idx[k]];
            }
        }
        let mut means = vec![0.0; n];
        for k in 0..n {
            means[k] = columns[k + 1].iter().sum::<f64>() / m as f64;
            for v in &mut columns[k + 1] {
                *v -= means[k];
            }
        }
        let y: Vec<f64> = cells.iter().map(|&c| self.values[c]).collect();
        let beta = least_squares(columns, &y);
        AffineFit {
            intercept: beta[0],
            slopes: beta[1..].to_vec(),
            means,
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

struct AffineFit {
    intercept: f64,
    slopes: Vec<f64>,
    means: Vec<f64>,
}

impl AffineFit {
    fn eval(&self, coords: impl Iterator<Item = f64>) -> f64 {
        self.intercept
            + coords
                .zip(self.slopes.iter().zip(&self.means))
                .map(|(t, (b, m))| b * (t - m))
                .sum::<f64>()
    }
}

/// Least squares `min |A β − y|` by modified Gram–Schmidt on the columns of `A`. A column
/// (nearly) in the span of the earlier ones is dropped and its coefficient left at 0.
fn least_squares(columns: Vec<Vec<f64>>, y: &[f64]) -> Vec<f64> {
    let p = columns.len();
    let mut q: Vec<Vec<f64>> = Vec::with_capacity(p);
    let mut kept: Vec<usize> = Vec::with_capacity(p);
    // r[a][b]: coefficient of kept column a in original column kept[b] (upper triangular).
    let mut r: Vec<Vec<f64>> = Vec::with_capacity(p);
    for (j, mut v) in columns.into_iter().enumerate() {
        let norm0 = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let mut rcol = Vec::with_capacity(q.len() + 1);
        for qa in &q {
            let dot: f64 = qa.iter().zip(&v).map(|(a, b)| a * b).sum();
            for (vi, qi) in v.iter_mut().zip(qa) {
                *vi -= dot * qi;
            }
            rcol.push(dot);
        }
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm <= 1e-10 * norm0 || norm == 0.0 {
            continue;
        }
        for vi in &mut v {
            *vi /= norm;
        }
        rcol.push(norm);
        q.push(v);
        kept.push(j);
        r.push(rcol);
    }
    // Solve R β_kept = Qᵀ y by back substitution; r[b] is column b of R.
    let qty: Vec<f64> = q
        .iter()
        .map(|qa| qa.iter().zip(y).map(|(a, b)| a * b).sum())
        .collect();
    let kn = kept.len();
    let mut beta_kept = vec![0.0; kn];
    for a in (0..kn).rev() {
        let mut s = qty[a];
        for b in a + 1..kn {
            s -= r[b][a] * beta_kept[b];
        }
        beta_kept[a] = s / r[a][a];
    }
    let mut beta = vec![0.0; p];
    for (a, &j) in kept.iter().enumerate() {
        beta[j] = beta_kept[a];
    }
    beta
}

// ---------------------------------------------------------------------------------------------
// Leave-one-out validation

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

// ---------------------------------------------------------------------------------------------
// Power models

/// Computation power as a function of the QoS knobs.
#[derive(Debug, Clone, PartialEq)]
pub enum PowerModel {
    /// One grid over all knobs of coupled tasks (e.g. tasks sharing the GPU); its values are
    /// the board's total power.
    Joint(GridModel),
    /// `base_power_w + Σ parts`: each part is one task's model of the power it adds ABOVE the
    /// base load (board idle with the mission software loaded), not its measured total. Build
    /// a part from a task's profile with `GridModel::from_profile(..)?.shifted(-base_power_w)`.
    Additive {
        base_power_w: f64,
        parts: Vec<GridModel>,
    },
}

impl PowerModel {
    /// An additive model, checked: a finite base and at most [`MAX_MODEL_KNOBS`] knobs.
    pub fn additive(base_power_w: f64, parts: Vec<GridModel>) -> Result<PowerModel, ModelError> {
        if !base_power_w.is_finite() {
            return Err(ModelError::BadBasePower(base_power_w));
        }
        let model = PowerModel::Additive {
            base_power_w,
            parts,
        };
        let count = model.knob_names().len();
        if count > MAX_MODEL_KNOBS {
            return Err(ModelError::TooManyModelKnobs(count));
        }
        Ok(model)
    }

    /// The knobs a query gives values for, in order: the joint grid's knobs, or the parts'
    /// knobs in part order with a knob shared by several parts listed once, where it first
    /// appears.
    pub fn knob_names(&self) -> Vec<&str> {
        match self {
            PowerModel::Joint(g) => g.knob_names().iter().map(String::as_str).collect(),
            PowerModel::Additive { parts, .. } => {
                let mut names: Vec<&str> = Vec::new();
                for name in parts.iter().flat_map(|p| p.knob_names()) {
                    if !names.contains(&name.as_str()) {
                        names.push(name);
                    }
                }
                names
            }
        }
    }

    /// Predicted power at `x`, given in [`PowerModel::knob_names`] order.
    ///
    /// # Panics
    /// When `x` is shorter than the model's knob list, or a hand-built `Additive` has more
    /// than [`MAX_MODEL_KNOBS`] knobs; [`PowerModel::try_eval`] checks both.
    pub fn eval(&self, x: &[f64]) -> Evaluation {
        match self {
            PowerModel::Joint(g) => g.eval(x),
            PowerModel::Additive {
                base_power_w,
                parts,
            } => {
                // Union positions are recomputed by name on each call, so no lookup table has
                // to live in the enum; it costs a few short string comparisons, no allocation.
                let mut seen: [&str; MAX_MODEL_KNOBS] = [""; MAX_MODEL_KNOBS];
                let mut count = 0usize;
                let mut value = *base_power_w;
                let mut clamped = 0u64;
                for part in parts {
                    let mut sub = [0.0f64; MAX_DIMS];
                    let mut pos = [0usize; MAX_DIMS];
                    for (j, name) in part.knob_names().iter().enumerate() {
                        let u = match seen[..count].iter().position(|s| *s == name.as_str()) {
                            Some(u) => u,
                            None => {
                                seen[count] = name;
                                count += 1;
                                count - 1
                            }
                        };
                        pos[j] = u;
                        sub[j] = x[u];
                    }
                    let e = part.eval(&sub[..part.dims()]);
                    value += e.value;
                    for (j, &u) in pos.iter().enumerate().take(part.dims()) {
                        if e.is_clamped(j) {
                            clamped |= 1 << u;
                        }
                    }
                }
                Evaluation {
                    value,
                    extrapolated: clamped != 0,
                    clamped,
                }
            }
        }
    }

    /// [`PowerModel::eval`] with the query checked: length, no NaN, knob count.
    pub fn try_eval(&self, x: &[f64]) -> Result<Evaluation, ModelError> {
        let names = self.knob_names();
        if names.len() > MAX_MODEL_KNOBS {
            return Err(ModelError::TooManyModelKnobs(names.len()));
        }
        if x.len() != names.len() {
            return Err(ModelError::QueryDimension {
                got: x.len(),
                expected: names.len(),
            });
        }
        if let Some(k) = x.iter().position(|v| v.is_nan()) {
            return Err(ModelError::QueryNaN {
                knob: names[k].to_string(),
            });
        }
        Ok(self.eval(x))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    fn names(n: usize) -> Vec<String> {
        (0..n).map(|k| format!("task{k}.knob")).collect()
    }

    /// A random strictly increasing axis of 2–5 values, all > 0 (so it suits both scales).
    fn random_axis(rng: &mut StdRng) -> Vec<f64> {
        let len = rng.random_range(2..=5);
        let mut v = rng.random_range(0.05..2.0);
        (0..len)
            .map(|_| {
                let x = v;
                v += rng.random_range(0.1..3.0);
                x
            })
            .collect()
    }

    /// Every point of the tensor product of `axes`, knob 0 slowest.
    fn grid_points(axes: &[Vec<f64>]) -> Vec<Vec<f64>> {
        let mut out = vec![vec![]];
        for axis in axes {
            out = out
                .into_iter()
                .flat_map(|p| {
                    axis.iter().map(move |&v| {
                        let mut q = p.clone();
                        q.push(v);
                        q
                    })
                })
                .collect();
        }
        out
    }

    /// f(x) = Σ over subsets S of c_S Π_{i∈S} g(x_i): multilinear in g(x).
    struct Multilinear {
        coeffs: Vec<f64>,
        log: bool,
    }

    impl Multilinear {
        fn random(rng: &mut StdRng, n: usize, log: bool) -> Self {
            Multilinear {
                coeffs: (0..1 << n).map(|_| rng.random_range(-3.0..3.0)).collect(),
                log,
            }
        }
        fn at(&self, x: &[f64]) -> f64 {
            let g = |v: f64| if self.log { v.ln() } else { v };
            self.coeffs
                .iter()
                .enumerate()
                .map(|(s, c)| {
                    c * x
                        .iter()
                        .enumerate()
                        .filter(|(i, _)| s & (1 << i) != 0)
                        .map(|(_, &v)| g(v))
                        .product::<f64>()
                })
                .sum()
        }
    }

    fn random_inside(rng: &mut StdRng, axes: &[Vec<f64>]) -> Vec<f64> {
        axes.iter()
            .map(|a| rng.random_range(a[0]..=a[a.len() - 1]))
            .collect()
    }

    /// Independent reference: nested 1-D linear interpolation, one axis at a time, with the
    /// query clamped into the grid first, in plain or ln coordinates.
    fn nested(axes: &[Vec<f64>], f: &dyn Fn(&[f64]) -> f64, x: &[f64], log: bool) -> f64 {
        fn rec(
            axes: &[Vec<f64>],
            f: &dyn Fn(&[f64]) -> f64,
            x: &[f64],
            fixed: &mut Vec<f64>,
            log: bool,
        ) -> f64 {
            let k = fixed.len();
            if k == axes.len() {
                return f(fixed);
            }
            let a = &axes[k];
            let xk = x[k].clamp(a[0], a[a.len() - 1]);
            let mut j = 0;
            while j + 2 < a.len() && xk > a[j + 1] {
                j += 1;
            }
            let g = |v: f64| if log { v.ln() } else { v };
            let t = (g(xk) - g(a[j])) / (g(a[j + 1]) - g(a[j]));
            fixed.push(a[j]);
            let lo = rec(axes, f, x, fixed, log);
            fixed.pop();
            fixed.push(a[j + 1]);
            let hi = rec(axes, f, x, fixed, log);
            fixed.pop();
            lo + t * (hi - lo)
        }
        rec(axes, f, x, &mut Vec::new(), log)
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn exact_at_grid_points() {
        let mut rng = StdRng::seed_from_u64(1);
        for n in 1..=5 {
            for scale in [AxisScale::Linear, AxisScale::Log] {
                let axes: Vec<Vec<f64>> = (0..n).map(|_| random_axis(&mut rng)).collect();
                let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
                    .into_iter()
                    .map(|p| (p, rng.random_range(-10.0..10.0)))
                    .collect();
                let m = GridModel::from_samples(names(n), &points, scale).unwrap();
                assert_eq!(m.axes(), &axes[..]);
                assert!(m.inferred_points().is_empty());
                for (x, v) in &points {
                    let e = m.eval(x);
                    assert_eq!(e.value, *v, "n={n} {scale:?} at {x:?}");
                    assert!(!e.extrapolated);
                }
            }
        }
    }

    #[test]
    fn multilinear_functions_are_reproduced() {
        let mut rng = StdRng::seed_from_u64(2);
        for n in 1..=5 {
            for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
                let axes: Vec<Vec<f64>> = (0..n).map(|_| random_axis(&mut rng)).collect();
                let f = Multilinear::random(&mut rng, n, log);
                let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
                    .into_iter()
                    .map(|p| {
                        let v = f.at(&p);
                        (p, v)
                    })
                    .collect();
                let m = GridModel::from_samples(names(n), &points, scale).unwrap();
                for _ in 0..200 {
                    let x = random_inside(&mut rng, &axes);
                    let got = m.eval(&x).value;
                    assert!(
                        close(got, f.at(&x), 1e-9),
                        "n={n} {scale:?} {x:?}: {got} vs {}",
                        f.at(&x)
                    );
                }
            }
        }
    }

    #[test]
    fn matches_nested_1d_interpolation_inside_and_outside() {
        let mut rng = StdRng::seed_from_u64(3);
        for n in 1..=5 {
            for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
                let axes: Vec<Vec<f64>> = (0..n).map(|_| random_axis(&mut rng)).collect();
                // A non-multilinear function: interpolation differs from it between points.
                let f = |x: &[f64]| {
                    x.iter()
                        .enumerate()
                        .map(|(i, v)| (v * (i + 1) as f64).sin())
                        .sum::<f64>()
                };
                let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
                    .into_iter()
                    .map(|p| {
                        let v = f(&p);
                        (p, v)
                    })
                    .collect();
                let m = GridModel::from_samples(names(n), &points, scale).unwrap();
                for _ in 0..300 {
                    // Queries up to 30 % beyond each end, but > 0 for the log scale.
                    let x: Vec<f64> = axes
                        .iter()
                        .map(|a| {
                            let (lo, hi) = (a[0], a[a.len() - 1]);
                            let w = hi - lo;
                            rng.random_range((lo - 0.3 * w).max(lo * 0.2)..hi + 0.3 * w)
                        })
                        .collect();
                    let e = m.eval(&x);
                    let want = nested(&axes, &f, &x, log);
                    assert!(
                        close(e.value, want, 1e-12),
                        "n={n} {scale:?} {x:?}: {} vs {want}",
                        e.value
                    );
                    for (k, a) in axes.iter().enumerate() {
                        let outside = x[k] < a[0] || x[k] > a[a.len() - 1];
                        assert_eq!(e.is_clamped(k), outside, "knob {k} of {x:?}");
                    }
                    assert_eq!(e.extrapolated, e.clamped != 0);
                }
            }
        }
    }

    #[test]
    fn long_axes_match_nested_interpolation() {
        // Axes longer than 18 values take the binary-search path for the cell.
        let mut rng = StdRng::seed_from_u64(6);
        for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
            let axes: Vec<Vec<f64>> = [50, 19, 3]
                .iter()
                .map(|&len| {
                    let mut v = 0.01;
                    (0..len)
                        .map(|_| {
                            v += rng.random_range(0.01..1.0);
                            v
                        })
                        .collect()
                })
                .collect();
            let f = |x: &[f64]| x[0].cos() * x[1] + x[2] * x[2];
            let points: Vec<(Vec<f64>, f64)> = grid_points(&axes)
                .into_iter()
                .map(|p| {
                    let v = f(&p);
                    (p, v)
                })
                .collect();
            let m = GridModel::from_samples(names(3), &points, scale).unwrap();
            for (x, v) in points.iter().step_by(7) {
                assert_eq!(m.eval(x).value, *v);
            }
            for _ in 0..500 {
                let x = random_inside(&mut rng, &axes);
                let want = nested(&axes, &f, &x, log);
                assert!(close(m.eval(&x).value, want, 1e-12), "{scale:?} {x:?}");
            }
        }
    }

    #[test]
    fn log_scale_interpolates_in_ln_space() {
        // 1-D, axis {1, 100}: at x = 10, ln-weight 1/2; linear weight 9/99.
        let pts = vec![(vec![1.0], 2.0), (vec![100.0], 4.0)];
        let log = GridModel::from_samples(names(1), &pts, AxisScale::Log).unwrap();
        let lin = GridModel::from_samples(names(1), &pts, AxisScale::Linear).unwrap();
        assert!((log.eval(&[10.0]).value - 3.0).abs() < 1e-12);
        assert!((lin.eval(&[10.0]).value - (2.0 + 2.0 * 9.0 / 99.0)).abs() < 1e-12);
    }

    #[test]
    fn clamps_outside_the_grid_and_says_so() {
        let pts = vec![
            (vec![1.0, 10.0], 1.0),
            (vec![2.0, 10.0], 2.0),
            (vec![1.0, 20.0], 3.0),
            (vec![2.0, 20.0], 5.0),
        ];
        let m = GridModel::from_samples(names(2), &pts, AxisScale::Linear).unwrap();
        let e = m.eval(&[0.5, 15.0]);
        assert_eq!(e.value, 2.0); // (1 + 3) / 2 at x0 = 1
        assert!(e.extrapolated && e.is_clamped(0) && !e.is_clamped(1));
        let e = m.eval(&[3.0, 25.0]);
        assert_eq!(e.value, 5.0);
        assert_eq!(e.clamped, 0b11);
        let e = m.eval(&[1.5, 10.0]);
        assert_eq!(e.value, 1.5);
        assert!(!e.extrapolated);
        // Exactly on the boundary is inside.
        assert!(!m.eval(&[2.0, 20.0]).extrapolated);
    }

    #[test]
    fn single_value_axes_and_zero_knobs() {
        let pts = vec![(vec![5.0, 1.0], 2.0), (vec![5.0, 3.0], 4.0)];
        let m = GridModel::from_samples(names(2), &pts, AxisScale::Linear).unwrap();
        let e = m.eval(&[5.0, 2.0]);
        assert_eq!((e.value, e.extrapolated), (3.0, false));
        let e = m.eval(&[7.0, 2.0]);
        assert_eq!((e.value, e.clamped), (3.0, 0b01));
        let c = GridModel::from_samples(vec![], &[(vec![], 3.25)], AxisScale::Log).unwrap();
        assert_eq!(c.eval(&[]).value, 3.25);
    }

    #[test]
    fn missing_interior_points_of_a_multilinear_function_are_inferred_exactly() {
        let mut rng = StdRng::seed_from_u64(4);
        for n in 1..=4 {
            for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
                // At least 3 values per axis, so there are interior points to remove.
                let axes: Vec<Vec<f64>> = (0..n)
                    .map(|_| loop {
                        let a = random_axis(&mut rng);
                        if a.len() >= 3 {
                            break a;
                        }
                    })
                    .collect();
                let f = Multilinear::random(&mut rng, n, log);
                let all = grid_points(&axes);
                let interior = |p: &[f64]| {
                    p.iter()
                        .zip(&axes)
                        .all(|(v, a)| *v != a[0] && *v != a[a.len() - 1])
                };
                let mut removed = Vec::new();
                let mut points = Vec::new();
                for p in all {
                    if interior(&p) && rng.random_bool(0.6) {
                        removed.push(p);
                    } else {
                        let v = f.at(&p);
                        points.push((p, v));
                    }
                }
                // The given axes: a removed point may hold the only sample of an axis value.
                let m = GridModel::with_axes(names(n), axes.clone(), &points, scale).unwrap();
                assert_eq!(m.inferred_points(), removed, "n={n}");
                for p in &removed {
                    assert!(
                        close(m.eval(p).value, f.at(p), 1e-9),
                        "n={n} {scale:?} {p:?}"
                    );
                }
                for _ in 0..50 {
                    let x = random_inside(&mut rng, &axes);
                    assert!(close(m.eval(&x).value, f.at(&x), 1e-9));
                }
            }
        }
    }

    #[test]
    fn missing_corners_of_an_affine_function_are_inferred_exactly() {
        let mut rng = StdRng::seed_from_u64(5);
        for n in 1..=4 {
            for (scale, log) in [(AxisScale::Linear, false), (AxisScale::Log, true)] {
                let axes: Vec<Vec<f64>> = (0..n)
                    .map(|_| loop {
                        let a = random_axis(&mut rng);
                        if a.len() >= 4 {
                            break a;
                        }
                    })
                    .collect();
                let c: Vec<f64> = (0..=n).map(|_| rng.random_range(-2.0..2.0)).collect();
                let g = |v: f64| if log { v.ln() } else { v };
                let f =
                    |x: &[f64]| c[0] + x.iter().zip(&c[1..]).map(|(v, b)| b * g(*v)).sum::<f64>();
                let all = grid_points(&axes);
                // Drop every corner of the grid (none has a neighbour on both sides) and a
                // few random points, but keep the block at axis indices 1 and 2: it spans the
                // space, so the affine fit is determined.
                let corner = |p: &[f64]| {
                    p.iter()
                        .zip(&axes)
                        .all(|(v, a)| *v == a[0] || *v == a[a.len() - 1])
                };
                let block = |p: &[f64]| p.iter().zip(&axes).all(|(v, a)| *v == a[1] || *v == a[2]);
                let (removed, kept): (Vec<_>, Vec<_>) = all
                    .into_iter()
                    .partition(|p| corner(p) || (!block(p) && rng.random_bool(0.2)));
                let points: Vec<(Vec<f64>, f64)> = kept
                    .into_iter()
                    .map(|p| {
                        let v = f(&p);
                        (p, v)
                    })
                    .collect();
                let m = GridModel::with_axes(names(n), axes.clone(), &points, scale).unwrap();
                assert_eq!(m.inferred_points(), removed);
                for p in &removed {
                    assert!(
                        close(m.eval(p).value, f(p), 1e-9),
                        "n={n} {scale:?} {p:?}: {} vs {}",
                        m.eval(p).value,
                        f(p)
                    );
                }
            }
        }
    }

    #[test]
    fn inference_by_hand() {
        // 1-D: 2 is bracketed by 1 and 4 → 10 + (20 − 10)·(2 − 1)/(4 − 1).
        let pts = vec![(vec![1.0], 10.0), (vec![4.0], 20.0)];
        let m = GridModel::with_axes(names(1), vec![vec![1.0, 2.0, 4.0]], &pts, AxisScale::Linear)
            .unwrap();
        assert!((m.eval(&[2.0]).value - (10.0 + 10.0 / 3.0)).abs() < 1e-12);
        // In ln coordinates: weight ln 2 / ln 4 = 1/2.
        let m = GridModel::with_axes(names(1), vec![vec![1.0, 2.0, 4.0]], &pts, AxisScale::Log)
            .unwrap();
        assert!((m.eval(&[2.0]).value - 15.0).abs() < 1e-12);
        // 2-D cross: the centre is bracketed on both axes → mean of the two estimates.
        let pts = vec![
            (vec![0.0, 1.0], 1.0),
            (vec![2.0, 1.0], 3.0), // axis 0 estimate: 2
            (vec![1.0, 0.0], 10.0),
            (vec![1.0, 4.0], 14.0), // axis 1 estimate: 11
        ];
        let m = GridModel::from_samples(names(2), &pts, AxisScale::Linear).unwrap();
        assert!((m.eval(&[1.0, 1.0]).value - 6.5).abs() < 1e-12);
        // Beyond the measured points on every axis: the affine fit. Points on a line along
        // axis 0 say nothing about axis 1, so the fit is constant along it.
        let pts = vec![
            (vec![0.0, 0.0], 1.0),
            (vec![1.0, 0.0], 3.0),
            (vec![2.0, 0.0], 5.0),
        ];
        let m = GridModel::with_axes(
            names(2),
            vec![vec![0.0, 1.0, 2.0, 3.0], vec![0.0, 5.0]],
            &pts,
            AxisScale::Linear,
        )
        .unwrap();
        assert!((m.eval(&[3.0, 0.0]).value - 7.0).abs() < 1e-12);
        assert!((m.eval(&[1.0, 5.0]).value - 3.0).abs() < 1e-12);
        assert!((m.eval(&[3.0, 5.0]).value - 7.0).abs() < 1e-12);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let ok = vec![(vec![1.0, 2.0], 3.0)];
        let sc = AxisScale::Linear;
        assert_eq!(
            GridModel::from_samples(names(2), &[], sc),
            Err(ModelError::NoPoints)
        );
        assert!(matches!(
            GridModel::from_samples(names(2), &[(vec![1.0], 3.0)], sc),
            Err(ModelError::DimensionMismatch {
                point: 0,
                got: 1,
                expected: 2
            })
        ));
        assert!(matches!(
            GridModel::from_samples(names(2), &[(vec![1.0, f64::NAN], 3.0)], sc),
            Err(ModelError::NonFiniteKnob { point: 0, .. })
        ));
        assert!(matches!(
            GridModel::from_samples(names(2), &[(vec![1.0, 2.0], f64::NAN)], sc),
            Err(ModelError::NonFiniteValue { point: 0, .. })
        ));
        assert!(matches!(
            GridModel::from_samples(names(2), &[(vec![1.0, 2.0], f64::INFINITY)], sc),
            Err(ModelError::NonFiniteValue { .. })
        ));
        assert!(matches!(
            GridModel::from_samples(names(2), &[(vec![1.0, 0.0], 3.0)], AxisScale::Log),
            Err(ModelError::NonPositiveOnLogAxis { value: 0.0, .. })
        ));
        assert!(matches!(
            GridModel::from_samples(names(2), &[(vec![-1.0, 1.0], 3.0)], AxisScale::Log),
            Err(ModelError::NonPositiveOnLogAxis { .. })
        ));
        assert!(GridModel::from_samples(names(2), &[(vec![-1.0, 0.0], 3.0)], sc).is_ok());
        assert!(matches!(
            GridModel::from_samples(
                names(2),
                &[(vec![1.0, 2.0], 3.0), (vec![1.0, 2.0], 4.0)],
                sc
            ),
            Err(ModelError::DuplicatePoint {
                first: 0,
                second: 1,
                ..
            })
        ));
        assert!(matches!(
            GridModel::from_samples(names(9), &[(vec![1.0; 9], 3.0)], sc),
            Err(ModelError::TooManyKnobs { count: 9 })
        ));
        assert!(matches!(
            GridModel::from_samples(vec!["a.b".into(), "a.b".into()], &ok, sc),
            Err(ModelError::DuplicateKnob(_))
        ));
        // Scattered points whose tensor grid would be huge.
        let scattered: Vec<(Vec<f64>, f64)> = (0..40).map(|i| (vec![i as f64; 4], 1.0)).collect();
        assert!(matches!(
            GridModel::from_samples(names(4), &scattered, sc),
            Err(ModelError::GridTooLarge { points: 2_560_000 })
        ));
        assert!(matches!(
            GridModel::with_axes(names(2), vec![vec![1.0], vec![3.0]], &ok, sc),
            Err(ModelError::OffAxis { point: 0, .. })
        ));
        assert!(matches!(
            GridModel::with_axes(names(2), vec![vec![1.0], vec![2.0, 2.0]], &ok, sc),
            Err(ModelError::BadAxis { .. })
        ));
        assert!(matches!(
            GridModel::with_axes(names(2), vec![vec![1.0]], &ok, sc),
            Err(ModelError::DimensionMismatch { .. })
        ));
        let m = GridModel::from_samples(names(2), &ok, sc).unwrap();
        assert!(matches!(
            m.try_eval(&[1.0]),
            Err(ModelError::QueryDimension {
                got: 1,
                expected: 2
            })
        ));
        assert!(matches!(
            m.try_eval(&[1.0, f64::NAN]),
            Err(ModelError::QueryNaN { .. })
        ));
        assert!(m.eval(&[f64::NAN, 1.0]).value.is_nan());
        assert_eq!(m.try_eval(&[1.0, 2.0]).unwrap().value, 3.0);
        assert!(matches!(
            leave_one_out(&names(2), &ok, sc),
            Err(ModelError::TooFewForLoo(1))
        ));
    }

    #[test]
    fn additive_model_sums_its_parts_over_the_knob_union() {
        let a = GridModel::from_samples(
            vec!["hazard.rate_fps".into()],
            &[(vec![1.0], 1.0), (vec![4.0], 2.5)],
            AxisScale::Linear,
        )
        .unwrap();
        let b = GridModel::from_samples(
            vec!["detection.rate_fps".into(), "detection.kernel_px".into()],
            &[
                (vec![1.0, 10.0], 0.1),
                (vec![10.0, 10.0], 0.4),
                (vec![1.0, 22.0], 0.2),
                (vec![10.0, 22.0], 0.6),
            ],
            AxisScale::Linear,
        )
        .unwrap();
        // Shares `hazard.rate_fps` with `a`: listed once, fed to both.
        let c = GridModel::from_samples(
            vec!["hazard.rate_fps".into()],
            &[(vec![1.0], 0.0), (vec![4.0], 0.3)],
            AxisScale::Linear,
        )
        .unwrap();
        let m = PowerModel::additive(3.0, vec![a.clone(), b.clone(), c.clone()]).unwrap();
        assert_eq!(
            m.knob_names(),
            [
                "hazard.rate_fps",
                "detection.rate_fps",
                "detection.kernel_px"
            ]
        );
        let x = [2.0, 5.5, 30.0];
        let want = 3.0 + a.eval(&[2.0]).value + b.eval(&[5.5, 30.0]).value + c.eval(&[2.0]).value;
        let e = m.eval(&x);
        assert!((e.value - want).abs() < 1e-12);
        // By hand: a = 1 + 1.5/3, b at kernel 22: 0.2 + 0.4·0.5, c = 0.1.
        assert!((e.value - (3.0 + 1.5 + 0.4 + 0.1)).abs() < 1e-12);
        assert_eq!(e.clamped, 0b100, "only the kernel knob is outside");
        let e = m.eval(&[5.0, 5.5, 22.0]);
        assert_eq!(e.clamped, 0b001);
        assert!(matches!(
            m.try_eval(&[1.0, 2.0]),
            Err(ModelError::QueryDimension { .. })
        ));
        assert!(matches!(
            PowerModel::additive(f64::NAN, vec![]),
            Err(ModelError::BadBasePower(_))
        ));
        // A shifted part models the power above the base.
        let above = a.shifted(-0.5);
        assert!((above.eval(&[4.0]).value - 2.0).abs() < 1e-12);
        let joint = PowerModel::Joint(b.clone());
        assert_eq!(
            joint.knob_names(),
            ["detection.rate_fps", "detection.kernel_px"]
        );
        assert_eq!(joint.eval(&[5.5, 30.0]), b.eval(&[5.5, 30.0]));
        let empty = PowerModel::additive(2.0, vec![]).unwrap();
        assert_eq!(empty.eval(&[]).value, 2.0);
    }

    // -----------------------------------------------------------------------------------------
    // Seed data

    fn seed_file(rel: &str) -> Option<String> {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data")
            .join(rel);
        match std::fs::read_to_string(&path) {
            Ok(t) => Some(t),
            Err(_) => {
                eprintln!(
                    "SKIP: {} is absent, the test needs the shared seed data",
                    path.display()
                );
                None
            }
        }
    }

    fn shipped_profile(file: &str) -> Profile {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../profiles/jetson-nano-seed")
            .join(file);
        Profile::from_toml_str(&std::fs::read_to_string(path).unwrap()).unwrap()
    }

    #[test]
    fn loo_by_hand_on_the_tracking_grid() {
        let p = shipped_profile("tracking.toml");
        let r = leave_one_out_profile(&p, AxisScale::Linear).unwrap();
        // (1, 10) without itself: bracketed on the hazard axis by 4 and 0.25 at detection 10.
        let (v4, v025) = (6.22922, 4.35776);
        let want = v4 + (1.0 - 4.0) / (0.25 - 4.0) * (v025 - v4);
        let got = r.per_point.iter().find(|q| q.knobs == [1.0, 10.0]).unwrap();
        assert!(
            (got.predicted_w - want).abs() < 1e-12,
            "{} vs {want}",
            got.predicted_w
        );
        assert!((got.abs_pct_error - (want - 4.99916f64).abs() / 4.99916 * 100.0).abs() < 1e-9);
        let w = (1.0f64.ln() - 4.0f64.ln()) / (0.25f64.ln() - 4.0f64.ln());
        let r = leave_one_out_profile(&p, AxisScale::Log).unwrap();
        let got = r.per_point.iter().find(|q| q.knobs == [1.0, 10.0]).unwrap();
        assert!((got.predicted_w - (v4 + w * (v025 - v4))).abs() < 1e-12);
        let mean = r.per_point.iter().map(|q| q.abs_pct_error).sum::<f64>() / 8.0;
        assert!((r.mape_pct - mean).abs() < 1e-12);
    }

    /// The 5×5 CNN grid, `knob1,knob2,W` rows.
    fn cnn_grid(text: &str) -> Vec<(Vec<f64>, f64)> {
        text.lines()
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                let v: Vec<f64> = l.split(',').map(|c| c.trim().parse().unwrap()).collect();
                (vec![v[0], v[1]], v[2])
            })
            .collect()
    }

    #[test]
    fn seed_loo_prefers_the_default_scale() {
        type Grid = (&'static str, Vec<String>, Vec<(Vec<f64>, f64)>);
        let mut grids: Vec<Grid> = ["tracking.toml", "landing.toml", "landing-kernel22.toml"]
            .iter()
            .map(|f| {
                let p = shipped_profile(f);
                (*f, p.knobs.clone(), p.power_points())
            })
            .collect();
        if let Some(text) = seed_file("jetson-nano-cnn-grid/computational_energy.csv") {
            grids.push((
                "computational_energy.csv",
                vec!["cnn.rate_fps".into(), "cnn.knob2".into()],
                cnn_grid(&text),
            ));
        }
        // Criterion: the mean absolute percentage error over the leave-one-out predictions
        // made by interpolation (a neighbour on both sides along some axis), pooled over the
        // grids. The axis scale exists for interpolation between measured points; the other
        // predictions (grid ends) come from the affine fallback, which a fully measured grid
        // never uses. The all-point figures are printed too.
        let mut interpolated = [Vec::new(), Vec::new()];
        let mut all = [Vec::new(), Vec::new()];
        for (name, knobs, points) in &grids {
            let mut line = format!("LOO {name}:");
            for (s, scale) in [AxisScale::Linear, AxisScale::Log].into_iter().enumerate() {
                let r = leave_one_out(knobs, points, scale).unwrap();
                let between: Vec<f64> = r
                    .per_point
                    .iter()
                    .filter(|p| {
                        p.knobs.iter().enumerate().any(|(k, v)| {
                            points.iter().any(|q| q.0[k] < *v) && points.iter().any(|q| q.0[k] > *v)
                        })
                    })
                    .map(|p| p.abs_pct_error)
                    .collect();
                line += &format!(
                    " {scale:?} all {} points {:.2} %, interpolated {} points {:.2} %;",
                    r.per_point.len(),
                    r.mape_pct,
                    between.len(),
                    between.iter().sum::<f64>() / between.len().max(1) as f64,
                );
                interpolated[s].extend(between);
                all[s].extend(r.per_point.iter().map(|p| p.abs_pct_error));
            }
            eprintln!("{line}");
        }
        let mape = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
        let (lin, log) = (mape(&interpolated[0]), mape(&interpolated[1]));
        eprintln!(
            "LOO pooled, interpolated {} points: Linear {lin:.3} %, Log {log:.3} %; all {} points: Linear {:.3} %, Log {:.3} %",
            interpolated[0].len(),
            all[0].len(),
            mape(&all[0]),
            mape(&all[1])
        );
        let (default, other) = match AxisScale::default() {
            AxisScale::Log => (log, lin),
            AxisScale::Linear => (lin, log),
        };
        assert!(
            default <= other,
            "default scale {:?} interpolates worse on the seed grids",
            AxisScale::default()
        );
    }
}
