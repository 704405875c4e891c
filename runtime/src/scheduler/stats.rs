//! Per-task statistics: counters and step-time / activation-lateness distributions.
//!
//! Distributions are log-linear histograms over the whole run (32 buckets per power of two,
//! exact below 64 ns): recording is O(1) without allocation, and a quantile is the midpoint of
//! its bucket, within 1.6 % of the exact value (clamped to the exact min and max).

use crate::task::TaskHealth;

const SUB_BITS: u32 = 5;
const SUB_BUCKETS: u64 = 1 << SUB_BITS;
/// Values below this are their own bucket.
const EXACT_BELOW: u64 = 2 * SUB_BUCKETS;
/// 64 exact buckets + 32 per octave for octaves 6..=63.
const BUCKETS: usize = (EXACT_BELOW + (64 - 6) * SUB_BUCKETS) as usize;

#[derive(Debug, Clone)]
pub(crate) struct Histogram {
    counts: Vec<u64>,
    count: u64,
    sum_ns: u128,
    min_ns: u64,
    max_ns: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram {
            counts: vec![0; BUCKETS],
            count: 0,
            sum_ns: 0,
            min_ns: u64::MAX,
            max_ns: 0,
        }
    }
}

fn bucket_of(value: u64) -> usize {
    if value < EXACT_BELOW {
        return value as usize;
    }
    let octave = 63 - value.leading_zeros(); // ≥ 6
    let mantissa = value >> (octave - SUB_BITS); // in [32, 64)
    ((u64::from(octave) - 6) * SUB_BUCKETS + mantissa + SUB_BUCKETS) as usize
}

/// The midpoint of bucket `index`.
fn bucket_value(index: usize) -> u64 {
    let index = index as u64;
    if index < EXACT_BELOW {
        return index;
    }
    let octave = index / SUB_BUCKETS + 4;
    let mantissa = index % SUB_BUCKETS + SUB_BUCKETS;
    let width = 1u64 << (octave - u64::from(SUB_BITS));
    (mantissa << (octave - u64::from(SUB_BITS))).saturating_add(width / 2)
}

impl Histogram {
    pub fn record(&mut self, value_ns: u64) {
        self.counts[bucket_of(value_ns)] += 1;
        self.count += 1;
        self.sum_ns += u128::from(value_ns);
        self.min_ns = self.min_ns.min(value_ns);
        self.max_ns = self.max_ns.max(value_ns);
    }

    /// The `q`-quantile (0 ≤ q ≤ 1), or 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        if self.count == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).clamp(1, self.count);
        // The extremes are known exactly.
        if rank == self.count {
            return self.max_ns;
        }
        if rank == 1 {
            return self.min_ns;
        }
        let mut seen = 0;
        for (index, &count) in self.counts.iter().enumerate() {
            seen += count;
            if seen >= rank {
                return bucket_value(index).clamp(self.min_ns, self.max_ns);
            }
        }
        self.max_ns
    }

    pub fn summary(&self) -> DurationSummary {
        let us = |ns: u64| ns as f64 * 1e-3;
        DurationSummary {
            count: self.count,
            p50_us: us(self.quantile_ns(0.50)),
            p99_us: us(self.quantile_ns(0.99)),
            max_us: us(self.max_ns),
            mean_us: if self.count == 0 {
                0.0
            } else {
                (self.sum_ns as f64 / self.count as f64) * 1e-3
            },
        }
    }
}

/// A distribution of durations, in microseconds.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct DurationSummary {
    pub count: u64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub max_us: f64,
    pub mean_us: f64,
}

/// A snapshot of one task's statistics.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TaskStats {
    pub name: String,
    pub health: TaskHealth,
    /// Current QoS level index and its period.
    pub level: usize,
    pub period_ms: f64,
    /// Activations at which `step` ran (successfully or not).
    pub activations: u64,
    /// Steps that took longer than their period.
    pub overruns: u64,
    /// Activation instants that fell while the previous step was still running, never run.
    pub skipped: u64,
    /// Input-triggered tasks: inputs superseded before the task could take them (it arrived
    /// within the rate cap, or while the task was busy), never stepped on.
    pub dropped_inputs: u64,
    /// Failed `start`, `step` or `set_qos` calls (errors and panics) and failed restarts.
    pub failures: u64,
    /// Restart attempts (each builds a fresh instance from the factory).
    pub restarts: u64,
    /// Step time: measured in real time; the timing model's cost in virtual time.
    pub step_time: DurationSummary,
    /// How late steps started after their activation instant (always 0 in virtual time).
    pub lateness: DurationSummary,
    /// Real time: the worker's own time per activation, from the end of a step to its next
    /// sleep or step (statistics, cadence, level and stop checks, clock reads). Empty in
    /// virtual time.
    pub overhead: DurationSummary,
    pub last_error: Option<String>,
}

/// What the task's runner accumulates; read by snapshots from other threads.
#[derive(Debug, Clone, Default)]
pub(crate) struct StatsAccum {
    pub level: usize,
    pub period_ms: f64,
    pub activations: u64,
    pub overruns: u64,
    pub skipped: u64,
    pub dropped_inputs: u64,
    pub failures: u64,
    pub restarts: u64,
    pub step_time: Histogram,
    pub lateness: Histogram,
    pub overhead: Histogram,
    pub last_error: Option<String>,
}

impl StatsAccum {
    pub fn snapshot(&self, name: &str, health: TaskHealth) -> TaskStats {
        TaskStats {
            name: name.to_string(),
            health,
            level: self.level,
            period_ms: self.period_ms,
            activations: self.activations,
            overruns: self.overruns,
            skipped: self.skipped,
            dropped_inputs: self.dropped_inputs,
            failures: self.failures,
            restarts: self.restarts,
            step_time: self.step_time.summary(),
            lateness: self.lateness.summary(),
            overhead: self.overhead.summary(),
            last_error: self.last_error.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_are_contiguous_and_cover_u64() {
        let mut previous = 0;
        for value in (0..10_000u64).chain([u64::MAX / 3, u64::MAX - 1, u64::MAX]) {
            let bucket = bucket_of(value);
            assert!(bucket < BUCKETS, "{value} → {bucket}");
            assert!(bucket >= previous || value > 10_000);
            previous = bucket;
        }
        assert_eq!(bucket_of(63), 63);
        assert_eq!(bucket_of(64), 64);
        assert_eq!(bucket_of(u64::MAX), BUCKETS - 1);
        // Each bucket's midpoint falls back into the same bucket.
        for index in 0..BUCKETS - 1 {
            assert_eq!(bucket_of(bucket_value(index)), index, "bucket {index}");
        }
    }

    #[test]
    fn quantiles_are_within_the_bucket_error_of_exact() {
        // A skewed, deterministic sample: step times from 1 µs to ~50 ms.
        let mut state = 99u64;
        let mut values: Vec<u64> = (0..20_000)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
                let u = (state >> 11) as f64 / (1u64 << 53) as f64;
                (1_000.0 * (u * 10.8).exp()) as u64
            })
            .collect();
        let mut histogram = Histogram::default();
        for &value in &values {
            histogram.record(value);
        }
        values.sort_unstable();
        for q in [0.01, 0.5, 0.9, 0.99, 0.999] {
            let exact = values[((q * values.len() as f64).ceil() as usize).max(1) - 1] as f64;
            let estimate = histogram.quantile_ns(q) as f64;
            assert!(
                (estimate - exact).abs() <= exact * 0.016 + 1.0,
                "q={q}: {estimate} vs {exact}"
            );
        }
        assert_eq!(histogram.quantile_ns(1.0), *values.last().unwrap());
        assert_eq!(histogram.quantile_ns(0.0), values[0]);
        let summary = histogram.summary();
        assert_eq!(summary.count, 20_000);
        let mean = values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64;
        assert!((summary.mean_us - mean * 1e-3).abs() < 1e-6 * mean);
    }

    #[test]
    fn an_empty_histogram_reads_zero() {
        let histogram = Histogram::default();
        assert_eq!(histogram.quantile_ns(0.99), 0);
        assert_eq!(histogram.summary(), DurationSummary::default());
    }
}
