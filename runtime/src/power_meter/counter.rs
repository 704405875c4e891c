//! Energy counters (RAPL `energy_uj`, hwmon `energy*_input`) turned into mean power between
//! two readings. Pure: the meters read the files and the clock, this does the arithmetic.

use super::MeterError;
use std::path::PathBuf;

/// One energy counter and its previous reading.
#[derive(Debug, Clone)]
pub struct EnergyCounter {
    path: PathBuf,
    /// The counter runs from 0 to this and then starts again from 0 (RAPL's
    /// `max_energy_range_uj`); `None` for a counter that does not wrap in practice.
    max_range_uj: Option<u64>,
    previous_uj: u64,
    previous_s: f64,
}

impl EnergyCounter {
    /// A counter read at `now_s` (seconds on any monotonic scale).
    pub fn new(
        path: PathBuf,
        max_range_uj: Option<u64>,
        now_uj: u64,
        now_s: f64,
    ) -> Result<Self, MeterError> {
        let counter = EnergyCounter {
            path,
            max_range_uj,
            previous_uj: now_uj,
            previous_s: now_s,
        };
        counter.check_range(now_uj)?;
        Ok(counter)
    }

    fn check_range(&self, now_uj: u64) -> Result<(), MeterError> {
        match self.max_range_uj {
            Some(max_uj) if now_uj > max_uj => Err(MeterError::CounterOutOfRange {
                path: self.path.clone(),
                now_uj,
                max_uj,
            }),
            _ => Ok(()),
        }
    }

    /// Energy since the previous reading, across one wrap-around where the counter has a range.
    pub fn delta_uj(&self, now_uj: u64) -> Result<u64, MeterError> {
        self.check_range(now_uj)?;
        if now_uj >= self.previous_uj {
            return Ok(now_uj - self.previous_uj);
        }
        match self.max_range_uj {
            // Up to the top of the range, then from 0 to now.
            Some(max_uj) => Ok(max_uj - self.previous_uj + now_uj),
            None => Err(MeterError::CounterBackwards {
                path: self.path.clone(),
                previous_uj: self.previous_uj,
                now_uj,
            }),
        }
    }

    /// Mean power since the previous reading, in W; this reading becomes the previous one. A
    /// counter that went back without a range restarts from this reading (so the next one
    /// works) and reports the error.
    pub fn update(&mut self, now_uj: u64, now_s: f64) -> Result<f64, MeterError> {
        let elapsed_s = now_s - self.previous_s;
        if elapsed_s.is_nan() || elapsed_s <= 0.0 {
            return Err(MeterError::NoTimeElapsed {
                what: self.path.display().to_string(),
            });
        }
        let delta = self.delta_uj(now_uj);
        if matches!(delta, Err(MeterError::CounterBackwards { .. })) {
            self.previous_uj = now_uj;
            self.previous_s = now_s;
        }
        let delta_uj = delta?;
        self.previous_uj = now_uj;
        self.previous_s = now_s;
        Ok(delta_uj as f64 * 1e-6 / elapsed_s)
    }
}
