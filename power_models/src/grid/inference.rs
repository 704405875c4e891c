//! The grid points nobody measured: filled by interpolation along the axes where known
//! neighbours allow, by a least-squares affine fit elsewhere (see [`GridModel::with_axes`]).

use super::GridModel;

impl GridModel {
    pub(super) fn infer_missing(&mut self) {
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
