//! Virtual time's timing model: what one step of a task costs at each QoS level, instead of the
//! host's wall time. A figure per level, or measured step times per level from which each step
//! draws one (deterministically, from the scheduler's seed).

use std::time::Duration;

/// The `[task.params]` key the scheduler reads the timing model from (and hides from the plugin):
/// `step_cost_ms = 2.0` (every level), `step_cost_ms = [8.0, 8.0, 9.0, 12.0]` (one per level), or
/// one list of measured step times per level: `step_cost_ms = [[7.9, 8.3], [8.1], …]`.
pub const STEP_COST_PARAM: &str = "step_cost_ms";

/// The cost of one step at one level.
#[derive(Debug, Clone, PartialEq)]
pub enum StepCost {
    Fixed(Duration),
    /// Measured step times; each step costs one of them, drawn uniformly.
    Samples(Vec<Duration>),
}

/// A task's step cost per QoS level, lowest level first.
#[derive(Debug, Clone, PartialEq)]
pub struct TimingModel {
    per_level: Vec<StepCost>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TimingError {
    #[error("`{STEP_COST_PARAM}` has {found} entries but the task has {levels} levels; give one per level or a single number")]
    WrongLength { found: usize, levels: usize },
    #[error("`{STEP_COST_PARAM}`: {0}")]
    BadValue(String),
}

fn cost_from_ms(value_ms: f64) -> Result<Duration, TimingError> {
    if !(value_ms.is_finite() && value_ms >= 0.0) {
        return Err(TimingError::BadValue(format!(
            "a step cost must be a finite number of milliseconds ≥ 0, found {value_ms}"
        )));
    }
    Duration::try_from_secs_f64(value_ms * 1e-3)
        .map_err(|_| TimingError::BadValue(format!("step cost {value_ms} ms is out of range")))
}

fn number(value: &toml::Value) -> Result<f64, TimingError> {
    match value {
        toml::Value::Float(x) => Ok(*x),
        toml::Value::Integer(x) => Ok(*x as f64),
        other => Err(TimingError::BadValue(format!(
            "expected a number of milliseconds, found {}",
            other.type_str()
        ))),
    }
}

impl TimingModel {
    /// One fixed cost per level, in milliseconds.
    pub fn fixed_ms(per_level_ms: &[f64]) -> Result<Self, TimingError> {
        let per_level = per_level_ms
            .iter()
            .map(|&ms| cost_from_ms(ms).map(StepCost::Fixed))
            .collect::<Result<_, _>>()?;
        Ok(TimingModel { per_level })
    }

    /// The same fixed cost at every one of `levels` levels.
    pub fn uniform_ms(cost_ms: f64, levels: usize) -> Result<Self, TimingError> {
        Ok(TimingModel {
            per_level: vec![StepCost::Fixed(cost_from_ms(cost_ms)?); levels],
        })
    }

    /// Measured step times per level, in milliseconds.
    pub fn samples_ms(per_level_ms: &[Vec<f64>]) -> Result<Self, TimingError> {
        let per_level = per_level_ms
            .iter()
            .map(|samples| {
                if samples.is_empty() {
                    return Err(TimingError::BadValue(
                        "a level's list of measured step times is empty".into(),
                    ));
                }
                samples
                    .iter()
                    .map(|&ms| cost_from_ms(ms))
                    .collect::<Result<_, _>>()
                    .map(StepCost::Samples)
            })
            .collect::<Result<_, _>>()?;
        Ok(TimingModel { per_level })
    }

    /// From the value of [`STEP_COST_PARAM`] for a task with `levels` levels.
    pub fn from_param(value: &toml::Value, levels: usize) -> Result<Self, TimingError> {
        let toml::Value::Array(entries) = value else {
            return Self::uniform_ms(number(value)?, levels);
        };
        if entries.len() != levels {
            return Err(TimingError::WrongLength {
                found: entries.len(),
                levels,
            });
        }
        let per_level = entries
            .iter()
            .map(|entry| match entry {
                toml::Value::Array(samples) => {
                    let samples_ms = samples.iter().map(number).collect::<Result<Vec<_>, _>>()?;
                    Ok(Self::samples_ms(&[samples_ms])?.per_level.remove(0))
                }
                single => Ok(StepCost::Fixed(cost_from_ms(number(single)?)?)),
            })
            .collect::<Result<_, TimingError>>()?;
        Ok(TimingModel { per_level })
    }

    pub fn levels(&self) -> usize {
        self.per_level.len()
    }

    /// The cost of one step at `level` (zero past the last level, which the builder prevents).
    pub(crate) fn cost(&self, level: usize, rng: &mut SplitMix64) -> Duration {
        match self.per_level.get(level) {
            Some(StepCost::Fixed(cost)) => *cost,
            Some(StepCost::Samples(samples)) if !samples.is_empty() => {
                samples[(rng.next_u64() % samples.len() as u64) as usize]
            }
            _ => Duration::ZERO,
        }
    }
}

/// A small, fast, seedable generator (SplitMix64): enough to draw step times reproducibly.
#[derive(Debug, Clone)]
pub(crate) struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        SplitMix64 { state: seed }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// The seed of task `index` under scheduler seed `seed`: distinct per task, fixed per run.
pub(crate) fn task_seed(seed: u64, index: usize) -> u64 {
    SplitMix64::new(seed ^ (index as u64).wrapping_mul(0xD1B5_4A32_D192_ED03)).next_u64()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn param(text: &str) -> toml::Value {
        let table: toml::Table = toml::from_str(&format!("v = {text}")).unwrap();
        table["v"].clone()
    }

    #[test]
    fn parses_every_form_of_the_param() {
        let mut rng = SplitMix64::new(1);
        let uniform = TimingModel::from_param(&param("2"), 3).unwrap();
        assert_eq!(uniform.levels(), 3);
        assert_eq!(uniform.cost(2, &mut rng), Duration::from_millis(2));
        let per_level = TimingModel::from_param(&param("[1.5, 3.0]"), 2).unwrap();
        assert_eq!(per_level.cost(0, &mut rng), Duration::from_micros(1500));
        assert_eq!(per_level.cost(1, &mut rng), Duration::from_millis(3));
        let measured = TimingModel::from_param(&param("[[1.0, 2.0], 5.0]"), 2).unwrap();
        let drawn: Vec<_> = (0..64).map(|_| measured.cost(0, &mut rng)).collect();
        assert!(drawn.contains(&Duration::from_millis(1)));
        assert!(drawn.contains(&Duration::from_millis(2)));
        assert!(drawn
            .iter()
            .all(|d| *d == Duration::from_millis(1) || *d == Duration::from_millis(2)));
    }

    #[test]
    fn bad_params_are_named_errors() {
        assert_eq!(
            TimingModel::from_param(&param("[1.0, 2.0]"), 3),
            Err(TimingError::WrongLength {
                found: 2,
                levels: 3
            })
        );
        assert!(matches!(
            TimingModel::from_param(&param("-1.0"), 1),
            Err(TimingError::BadValue(_))
        ));
        assert!(matches!(
            TimingModel::from_param(&param("\"fast\""), 1),
            Err(TimingError::BadValue(message)) if message.contains("string")
        ));
        assert!(matches!(
            TimingModel::from_param(&param("[[]]"), 1),
            Err(TimingError::BadValue(_))
        ));
        assert!(matches!(
            TimingModel::from_param(&param("nan"), 1),
            Err(TimingError::BadValue(_))
        ));
    }

    #[test]
    fn draws_repeat_for_a_seed_and_differ_across_seeds() {
        let draw = |seed| {
            let mut rng = SplitMix64::new(seed);
            (0..8).map(|_| rng.next_u64()).collect::<Vec<_>>()
        };
        assert_eq!(draw(7), draw(7));
        assert_ne!(draw(7), draw(8));
        assert_ne!(task_seed(7, 0), task_seed(7, 1));
    }
}
