//! Interpolation throughput of `GridModel::eval` on 1-D to 4-D grids (8 points per axis,
//! non-uniform, the default linear scale), against a naive baseline in the same run: nested 1-D
//! interpolation by recursion, a linear scan for the cell and a fresh vector per level.
//!
//! Run: `cargo bench -p power_models --bench interpolation`; criterion prints the throughput
//! (queries/s) of each; their ratio is the speed-up.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use power_models::grid::{AxisScale, GridModel};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const POINTS_PER_AXIS: usize = 8;
const QUERIES: usize = 1024;

fn model(dims: usize, rng: &mut StdRng) -> GridModel {
    // Rates from 0.1 upward with uneven steps, like QoS levels.
    let axes: Vec<Vec<f64>> = (0..dims)
        .map(|_| {
            let mut v = 0.1;
            (0..POINTS_PER_AXIS)
                .map(|_| {
                    let x = v;
                    v += rng.random_range(0.2..3.0);
                    x
                })
                .collect()
        })
        .collect();
    let mut points: Vec<(Vec<f64>, f64)> = vec![(vec![], 0.0)];
    for axis in &axes {
        points = points
            .into_iter()
            .flat_map(|(p, _)| {
                axis.iter().map(move |&v| {
                    let mut q = p.clone();
                    q.push(v);
                    (q, 0.0)
                })
            })
            .collect();
    }
    for (_, v) in &mut points {
        *v = rng.random_range(3.0..10.0);
    }
    let names = (0..dims).map(|k| format!("task{k}.rate_fps")).collect();
    GridModel::from_samples(names, &points, AxisScale::Linear).expect("valid grid")
}

/// The straightforward way: recurse over the axes, scanning each for the cell, slicing the
/// sub-grid of each neighbour and copying the remaining coordinates into a new vector.
fn naive(axes: &[Vec<f64>], values: &[f64], x: &[f64]) -> f64 {
    if axes.is_empty() {
        return values[0];
    }
    let axis = &axes[0];
    let sub_len = values.len() / axis.len();
    let xk = x[0].clamp(axis[0], axis[axis.len() - 1]);
    let mut j = 0;
    while j + 2 < axis.len() && xk > axis[j + 1] {
        j += 1;
    }
    let t = (xk - axis[j]) / (axis[j + 1] - axis[j]);
    let rest: Vec<f64> = x[1..].to_vec();
    let lo = naive(&axes[1..], &values[j * sub_len..(j + 1) * sub_len], &rest);
    let hi = naive(
        &axes[1..],
        &values[(j + 1) * sub_len..(j + 2) * sub_len],
        &rest,
    );
    (1.0 - t) * lo + t * hi
}

fn interpolation(c: &mut Criterion) {
    let mut rng = StdRng::seed_from_u64(42);
    let mut group = c.benchmark_group("interpolation");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .throughput(Throughput::Elements(QUERIES as u64));
    for dims in 1..=4 {
        let m = model(dims, &mut rng);
        let queries: Vec<Vec<f64>> = (0..QUERIES)
            .map(|_| {
                m.axes()
                    .iter()
                    .map(|a| rng.random_range(a[0]..a[a.len() - 1]))
                    .collect()
            })
            .collect();
        // The two must agree before their speeds are worth comparing.
        for q in &queries {
            let (a, b) = (m.eval(q).value, naive(m.axes(), m.values(), q));
            assert!(
                (a - b).abs() <= 1e-9 * a.abs().max(1.0),
                "{a} vs {b} at {q:?}"
            );
        }
        group.bench_with_input(
            BenchmarkId::new("grid_eval", format!("{dims}d")),
            &queries,
            |b, qs| {
                b.iter(|| {
                    let mut sum = 0.0;
                    for q in qs {
                        sum += m.eval(black_box(q)).value;
                    }
                    sum
                })
            },
        );
        group.bench_with_input(
            BenchmarkId::new("naive", format!("{dims}d")),
            &queries,
            |b, qs| {
                b.iter(|| {
                    let mut sum = 0.0;
                    for q in qs {
                        sum += naive(m.axes(), m.values(), black_box(q));
                    }
                    sum
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, interpolation);
criterion_main!(benches);
