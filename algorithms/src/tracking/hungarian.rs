//! Optimal assignment (Kuhn–Munkres with Jonker–Volgenant's shortest augmenting paths, O(n²m))
//! for a rectangular cost matrix, with a gate: the tracker's solver for the matching matrix of
//! seed 000, equation 6.
//!
//! Gating: a pair costlier than the gate is never assigned, and leaving a row (or column) of the
//! smaller side unassigned costs the gate. The solver minimises
//! `Σ cost(assigned pairs) + gate · (min(rows, cols) − pairs)`, which it does exactly by solving the
//! full problem on `min(cost, gate)` and dropping the pairs above the gate. A cost of `+∞` marks a
//! forbidden pair; with an infinite gate the result then has the fewest forbidden pairs possible,
//! and they are dropped.

use nalgebra::DMatrix;
use thiserror::Error;

/// A cost matrix or gate the solver cannot use.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AssignmentError {
    #[error("cost[{row}][{col}] is {value}: costs must be finite, or +∞ for a forbidden pair")]
    Cost { row: usize, col: usize, value: f64 },
    #[error("the gate must be finite or +∞, got {gate}")]
    Gate { gate: f64 },
}

/// The solution: which row goes with which column, and what was left over.
#[derive(Debug, Clone, PartialEq)]
pub struct Assignment {
    /// (row, column) pairs, sorted by row.
    pub pairs: Vec<(usize, usize)>,
    /// Rows with no column, ascending.
    pub unassigned_rows: Vec<usize>,
    /// Columns with no row, ascending.
    pub unassigned_cols: Vec<usize>,
    /// Σ cost over `pairs`.
    pub total_cost: f64,
}

impl Assignment {
    /// The column given to `row`, if any.
    pub fn col_of(&self, row: usize) -> Option<usize> {
        self.pairs.iter().find(|p| p.0 == row).map(|p| p.1)
    }

    /// The row given to `col`, if any.
    pub fn row_of(&self, col: usize) -> Option<usize> {
        self.pairs.iter().find(|p| p.1 == col).map(|p| p.0)
    }
}

/// The minimum-cost assignment of rows to columns; pairs costlier than `gate` stay unassigned
/// (see the module docs). `f64::INFINITY` as the gate assigns `min(rows, cols)` pairs.
pub fn assign(costs: &DMatrix<f64>, gate: f64) -> Result<Assignment, AssignmentError> {
    if gate.is_nan() || gate == f64::NEG_INFINITY {
        return Err(AssignmentError::Gate { gate });
    }
    let (rows, cols) = costs.shape();
    let mut max_abs = 0.0f64;
    for row in 0..rows {
        for col in 0..cols {
            let value = costs[(row, col)];
            if value.is_nan() || value == f64::NEG_INFINITY {
                return Err(AssignmentError::Cost { row, col, value });
            }
            if value.is_finite() {
                max_abs = max_abs.max(value.abs());
            }
        }
    }
    if gate.is_finite() {
        max_abs = max_abs.max(gate.abs());
    }
    // A finite stand-in for +∞ (a forbidden pair under an infinite gate), larger than any
    // difference the finite costs can make, so the solver uses as few of them as it can.
    let forbidden = 2.0 * (rows.min(cols) as f64 + 1.0) * (max_abs + 1.0);
    let effective = |c: f64| {
        if gate.is_finite() {
            c.min(gate)
        } else if c.is_finite() {
            c
        } else {
            forbidden
        }
    };
    // The solver wants rows ≤ columns: solve the transpose otherwise.
    let transposed = rows > cols;
    let (n, m) = if transposed {
        (cols, rows)
    } else {
        (rows, cols)
    };
    let cost_at = |i: usize, j: usize| {
        if transposed {
            effective(costs[(j, i)])
        } else {
            effective(costs[(i, j)])
        }
    };
    let row_to_col = shortest_augmenting_paths(n, m, cost_at);

    let mut pairs = Vec::new();
    for (i, j) in row_to_col.into_iter().enumerate() {
        let (row, col) = if transposed { (j, i) } else { (i, j) };
        if costs[(row, col)] <= gate && costs[(row, col)].is_finite() {
            pairs.push((row, col));
        }
    }
    pairs.sort_unstable();
    let mut row_used = vec![false; rows];
    let mut col_used = vec![false; cols];
    for &(row, col) in &pairs {
        row_used[row] = true;
        col_used[col] = true;
    }
    Ok(Assignment {
        total_cost: pairs.iter().map(|&(r, c)| costs[(r, c)]).sum(),
        unassigned_rows: (0..rows).filter(|&r| !row_used[r]).collect(),
        unassigned_cols: (0..cols).filter(|&c| !col_used[c]).collect(),
        pairs,
    })
}

/// Kuhn–Munkres with potentials for an `n`×`m` problem, n ≤ m, all costs finite: each row is
/// added by a Dijkstra-like search for the shortest augmenting path in reduced costs. Returns
/// the column of every row.
fn shortest_augmenting_paths(n: usize, m: usize, cost: impl Fn(usize, usize) -> f64) -> Vec<usize> {
    // Index 0 is a virtual column/row; real rows and columns are 1-based here.
    let mut u = vec![0.0f64; n + 1];
    let mut v = vec![0.0f64; m + 1];
    let mut row_of_col = vec![0usize; m + 1];
    let mut way = vec![0usize; m + 1];
    for i in 1..=n {
        row_of_col[0] = i;
        let mut j0 = 0usize;
        let mut min_reduced = vec![f64::INFINITY; m + 1];
        let mut used = vec![false; m + 1];
        loop {
            used[j0] = true;
            let i0 = row_of_col[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0usize;
            for j in 1..=m {
                if used[j] {
                    continue;
                }
                let reduced = cost(i0 - 1, j - 1) - u[i0] - v[j];
                if reduced < min_reduced[j] {
                    min_reduced[j] = reduced;
                    way[j] = j0;
                }
                if min_reduced[j] < delta {
                    delta = min_reduced[j];
                    j1 = j;
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[row_of_col[j]] += delta;
                    v[j] -= delta;
                } else {
                    min_reduced[j] -= delta;
                }
            }
            j0 = j1;
            if row_of_col[j0] == 0 {
                break;
            }
        }
        // Flip the augmenting path back to the virtual column.
        while j0 != 0 {
            let j1 = way[j0];
            row_of_col[j0] = row_of_col[j1];
            j0 = j1;
        }
    }
    let mut col_of_row = vec![0usize; n];
    for j in 1..=m {
        if row_of_col[j] != 0 {
            col_of_row[row_of_col[j] - 1] = j - 1;
        }
    }
    col_of_row
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// The best gated objective of the module docs, by enumerating every partial matching of
    /// the smaller side into the larger.
    fn brute_force(costs: &DMatrix<f64>, gate: f64) -> f64 {
        let (rows, cols) = costs.shape();
        let small = rows.min(cols);
        let c = |i: usize, j: usize| {
            if rows <= cols {
                costs[(i, j)]
            } else {
                costs[(j, i)]
            }
        };
        let large = rows.max(cols);
        fn recurse(
            i: usize,
            small: usize,
            large: usize,
            used: &mut Vec<bool>,
            c: &dyn Fn(usize, usize) -> f64,
            gate: f64,
        ) -> f64 {
            if i == small {
                return 0.0;
            }
            // Row i left unassigned costs the gate.
            let mut best = gate + recurse(i + 1, small, large, used, c, gate);
            for j in 0..large {
                if !used[j] && c(i, j) <= gate {
                    used[j] = true;
                    best = best.min(c(i, j) + recurse(i + 1, small, large, used, c, gate));
                    used[j] = false;
                }
            }
            best
        }
        recurse(0, small, large, &mut vec![false; large], &c, gate)
    }

    fn objective(costs: &DMatrix<f64>, gate: f64, a: &Assignment) -> f64 {
        let (rows, cols) = costs.shape();
        a.total_cost + gate * (rows.min(cols) - a.pairs.len()) as f64
    }

    fn check_consistent(costs: &DMatrix<f64>, gate: f64, a: &Assignment) {
        let (rows, cols) = costs.shape();
        let mut seen_rows = vec![false; rows];
        let mut seen_cols = vec![false; cols];
        for &(r, c) in &a.pairs {
            assert!(!seen_rows[r] && !seen_cols[c], "row or column used twice");
            seen_rows[r] = true;
            seen_cols[c] = true;
            assert!(costs[(r, c)] <= gate);
        }
        for (r, seen) in seen_rows.iter().enumerate() {
            assert_eq!(!seen, a.unassigned_rows.contains(&r));
        }
        for (c, seen) in seen_cols.iter().enumerate() {
            assert_eq!(!seen, a.unassigned_cols.contains(&c));
        }
        let sum: f64 = a.pairs.iter().map(|&(r, c)| costs[(r, c)]).sum();
        assert!((sum - a.total_cost).abs() < 1e-9);
    }

    #[test]
    fn matches_brute_force_on_random_square_and_rectangular_matrices() {
        let mut rng = StdRng::seed_from_u64(10);
        for trial in 0..400 {
            let rows = rng.random_range(1..=6);
            let cols = rng.random_range(1..=6);
            // Integer costs make ties common, real ones make them rare: test both.
            let costs = DMatrix::from_fn(rows, cols, |_, _| {
                if trial % 2 == 0 {
                    rng.random_range(0..10) as f64
                } else {
                    rng.random_range(-5.0..20.0)
                }
            });
            let a = assign(&costs, f64::INFINITY).unwrap();
            check_consistent(&costs, f64::INFINITY, &a);
            assert_eq!(
                a.pairs.len(),
                rows.min(cols),
                "ungated assigns the smaller side"
            );
            let best = brute_force(&costs, f64::INFINITY);
            assert!(
                (a.total_cost - best).abs() < 1e-9,
                "trial {trial}: {} vs brute force {best}\n{costs}",
                a.total_cost
            );
        }
    }

    #[test]
    fn gated_assignment_matches_brute_force() {
        let mut rng = StdRng::seed_from_u64(11);
        for trial in 0..400 {
            let rows = rng.random_range(1..=6);
            let cols = rng.random_range(1..=6);
            let costs = DMatrix::from_fn(rows, cols, |_, _| rng.random_range(0.0..1.0));
            let gate = rng.random_range(0.05..0.9);
            let a = assign(&costs, gate).unwrap();
            check_consistent(&costs, gate, &a);
            let best = brute_force(&costs, gate);
            assert!(
                (objective(&costs, gate, &a) - best).abs() < 1e-9,
                "trial {trial}, gate {gate}\n{costs}"
            );
        }
    }

    #[test]
    fn the_gate_prefers_no_pair_to_a_costly_one() {
        // Greedy on the cheapest pair (0,0) would force row 1 onto column 1 at cost 9 > gate.
        #[rustfmt::skip]
        let costs = DMatrix::from_row_slice(2, 2, &[
            1.0, 2.0,
            2.0, 9.0,
        ]);
        let ungated = assign(&costs, f64::INFINITY).unwrap();
        assert_eq!(ungated.pairs, vec![(0, 1), (1, 0)]);
        // Under a gate of 4 the effective costs are [1 2; 2 4]: the swap (4) still beats 1 + 4.
        let gated = assign(&costs, 4.0).unwrap();
        assert_eq!(gated.pairs, vec![(0, 1), (1, 0)]);
        let tight = assign(&costs, 1.5).unwrap();
        assert_eq!(tight.pairs, vec![(0, 0)]);
        assert_eq!(tight.unassigned_rows, vec![1]);
        assert_eq!(tight.unassigned_cols, vec![1]);
    }

    #[test]
    fn forbidden_pairs_are_avoided_and_never_returned() {
        let inf = f64::INFINITY;
        #[rustfmt::skip]
        let costs = DMatrix::from_row_slice(3, 2, &[
            inf, 5.0,
            inf, 1.0,
            inf, inf,
        ]);
        let a = assign(&costs, inf).unwrap();
        assert_eq!(a.pairs, vec![(1, 1)]);
        assert_eq!(a.unassigned_cols, vec![0]);
        let empty = assign(&DMatrix::<f64>::zeros(0, 3), inf).unwrap();
        assert!(empty.pairs.is_empty() && empty.unassigned_cols == vec![0, 1, 2]);
    }

    #[test]
    fn bad_costs_and_gates_are_named_errors() {
        let costs = DMatrix::from_row_slice(1, 2, &[0.0, f64::NAN]);
        assert!(matches!(
            assign(&costs, 1.0),
            Err(AssignmentError::Cost { row: 0, col: 1, .. })
        ));
        assert!(matches!(
            assign(&DMatrix::zeros(2, 2), f64::NAN),
            Err(AssignmentError::Gate { .. })
        ));
    }
}
