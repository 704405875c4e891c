//! Height above the landing pad from a downward rangefinder and the autopilot's altitude.
//!
//! A rangefinder under a vehicle following a tractor sees the pad's top or, when its beam
//! (along the leaning body's down axis) misses the 1 m pad, the field a pad-height lower: taken
//! as it is, the height jumps by that much, and a landing holding a height climbs and sinks
//! with every jump. Each reading gives the altitude of the surface it hit (the autopilot's
//! altitude less the reading). The estimator keeps the field's altitude in the autopilot's
//! frame, filtered over a few readings, and the pad's height above it: a reading is on the pad
//! when its surface lies nearer the pad's top than the field. Until the pad has been seen, a
//! surface more than a gate above the field is the pad, and that first step measures it; each
//! later change of surface refines it. The height above the pad is then the latest reading,
//! less the pad's height when that reading hit the ground, moved by the autopilot's altitude
//! change since.
//!
//! Each reading is judged against the filtered level, not against the reading before it: a
//! TFmini-class rangefinder is noisy by 3 cm plus 1 % of the range, so two readings at 8 m
//! differ by 0.15 m (1σ) on the same surface, and a step rule with a 0.4 m gate took one pair
//! of them for a change of surface, and the pad for the field, for the rest of a descent.
//!
//! No absolute level is kept: the field's level follows whatever surface the beam sees, so the
//! autopilot's altitude (barometric, drifting half a metre in a minute of a real PX4's flight)
//! never has to agree with itself across the flight, only across a few readings. The field is
//! taken as level where the vehicle flies (a farm field).

use thiserror::Error;

/// The estimator's tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadHeightConfig {
    /// Before the pad has been seen, a surface this far above the field's level is the pad
    /// (and this far below it, the field beside a pad the vehicle took off from). Below the
    /// pad's height and above the rangefinder's noise and the field's bumps.
    pub gate_m: f64,
    /// How far one change of surface moves the learned pad height (0–1].
    pub step_weight: f64,
    /// How far each reading moves the field's level (0–1]: low enough to average the
    /// rangefinder's noise, high enough to follow the altitude's drift and its lag in a descent
    /// (0.3 at 10 Hz: about 0.3 s).
    pub level_weight: f64,
}

impl Default for PadHeightConfig {
    fn default() -> Self {
        Self {
            gate_m: 0.4,
            step_weight: 0.25,
            level_weight: 0.3,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum PadHeightError {
    #[error("pad height config: {name} = {value} is invalid: {why}")]
    Config {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
}

/// Which surface a reading was taken to come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    Ground,
    Pad,
}

/// One reading, as folded in.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Reading {
    height_m: f64,
    altitude_up_m: f64,
    surface: Surface,
}

/// See the module docs.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PadHeightEstimator {
    config: PadHeightConfig,
    latest: Option<Reading>,
    /// The field's altitude in the autopilot's frame, filtered.
    ground_up_m: Option<f64>,
    /// The pad's top above the ground, once a step has measured it.
    pad_above_ground_m: Option<f64>,
}

impl PadHeightEstimator {
    pub fn new(config: PadHeightConfig) -> Result<Self, PadHeightError> {
        if !(config.gate_m.is_finite() && config.gate_m > 0.0) {
            return Err(PadHeightError::Config {
                name: "gate_m",
                value: config.gate_m,
                why: "must be a finite number > 0",
            });
        }
        for (name, value) in [
            ("step_weight", config.step_weight),
            ("level_weight", config.level_weight),
        ] {
            if !(value > 0.0 && value <= 1.0) {
                return Err(PadHeightError::Config {
                    name,
                    value,
                    why: "must be in (0, 1]",
                });
            }
        }
        Ok(Self {
            config,
            latest: None,
            ground_up_m: None,
            pad_above_ground_m: None,
        })
    }

    /// Folds in a tilt-corrected rangefinder height taken at `altitude_up_m` (the autopilot's,
    /// up positive), and says which surface it hit. Non-finite input is ignored (`None`).
    pub fn update(
        &mut self,
        time_s: f64,
        rangefinder_height_m: f64,
        altitude_up_m: f64,
    ) -> Option<Surface> {
        if ![time_s, rangefinder_height_m, altitude_up_m]
            .iter()
            .all(|v| v.is_finite())
        {
            return None;
        }
        let surface_up_m = altitude_up_m - rangefinder_height_m;
        // The first surface is taken for the ground (a take-off from the field) until a step
        // says otherwise.
        let ground_up_m = *self.ground_up_m.get_or_insert(surface_up_m);
        let above_ground_m = surface_up_m - ground_up_m;
        let surface = match self.pad_above_ground_m {
            Some(pad_m) if above_ground_m > 0.5 * pad_m => Surface::Pad,
            Some(_) => Surface::Ground,
            None if above_ground_m > self.config.gate_m => {
                self.pad_above_ground_m = Some(above_ground_m);
                Surface::Pad
            }
            None if above_ground_m < -self.config.gate_m => {
                // Down onto the field from what was taken for it: a take-off from the pad.
                self.pad_above_ground_m = Some(-above_ground_m);
                self.ground_up_m = Some(surface_up_m);
                Surface::Ground
            }
            None => Surface::Ground,
        };
        let pad_m = self.pad_above_ground_m.unwrap_or(0.0);
        let mut residual_m = match surface {
            Surface::Pad => above_ground_m - pad_m,
            Surface::Ground => surface_up_m - self.ground_up_m.unwrap_or(ground_up_m),
        };
        // A change of surface measures the pad: the new surface's residual is the learned
        // height's error (a pad above it, a field below it: both say the pad is higher).
        if self
            .latest
            .is_some_and(|previous| previous.surface != surface)
        {
            let error_m = match surface {
                Surface::Pad => residual_m,
                Surface::Ground => -residual_m,
            };
            let learned_m = pad_m + self.config.step_weight * error_m;
            self.pad_above_ground_m = Some(learned_m);
            residual_m = match surface {
                Surface::Pad => above_ground_m - learned_m,
                Surface::Ground => residual_m,
            };
        }
        if let Some(level_m) = self.ground_up_m.as_mut() {
            *level_m += self.config.level_weight * residual_m;
        }
        self.latest = Some(Reading {
            height_m: rangefinder_height_m,
            altitude_up_m,
            surface,
        });
        Some(surface)
    }

    /// The height above the pad at `altitude_up_m`: the latest reading (less the pad's
    /// height when it hit the ground) moved by the altitude change since; above the ground
    /// until a step has measured the pad, `None` before any reading.
    pub fn height_above_pad_m(&self, altitude_up_m: f64) -> Option<f64> {
        let latest = self.latest?;
        let height_m = latest.height_m + (altitude_up_m - latest.altitude_up_m);
        Some(match latest.surface {
            Surface::Pad => height_m,
            Surface::Ground => height_m - self.pad_above_ground_m.unwrap_or(0.0),
        })
    }

    /// The pad's top above the ground, once measured.
    pub fn pad_above_ground_m(&self) -> Option<f64> {
        self.pad_above_ground_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vehicle descending from 8 m to 1.5 m above the ground over 30 s beside and over a
    /// 1 m pad, its beam on the pad two readings in three, its altitude drifting 0.3 m. The
    /// truth is altitude above the ground − 1 m, computed here from the scenario alone.
    #[test]
    fn the_height_stays_smooth_whichever_surface_the_beam_hits() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        let pad_m = 1.0;
        let dt_s = 0.05;
        let mut worst_m: f64 = 0.0;
        let mut raw_jump_m: f64 = 0.0;
        // Take-off: a few readings from the ground.
        for tick in 0..20 {
            estimator.update(tick as f64 * dt_s, 0.2, 0.2);
        }
        for tick in 0..600 {
            let time_s = 1.0 + tick as f64 * dt_s;
            let true_up_m = 8.0 - 6.5 * tick as f64 / 600.0;
            // The autopilot's altitude drifts slowly; the rangefinder has noise.
            let drift_m = 0.3 * (time_s / 30.0);
            let noise_m = 0.03 * ((tick * 7919) % 13) as f64 / 13.0 - 0.015;
            let on_pad = tick % 3 != 0;
            let reading_m = true_up_m - if on_pad { pad_m } else { 0.0 } + noise_m;
            let surface = estimator.update(time_s, reading_m, true_up_m + drift_m);
            assert_eq!(
                surface,
                Some(if on_pad {
                    Surface::Pad
                } else {
                    Surface::Ground
                })
            );
            let truth_m = true_up_m - pad_m;
            if tick > 40 {
                let got_m = estimator.height_above_pad_m(true_up_m + drift_m).unwrap();
                worst_m = worst_m.max((got_m - truth_m).abs());
            }
            raw_jump_m = raw_jump_m.max((reading_m - truth_m).abs());
        }
        assert!(raw_jump_m > 0.9, "the scenario must jump: {raw_jump_m}");
        assert!(worst_m < 0.06, "height error up to {worst_m} m");
        let learned_m = estimator.pad_above_ground_m().unwrap();
        assert!((learned_m - pad_m).abs() < 0.05, "pad {learned_m} m");
    }

    /// At 7 m a TFmini-class rangefinder is noisy by about 0.1 m: two readings on the pad
    /// 0.42 m apart (1.18 m, then 0.77 m of surface altitude, from seed 12 of the reference
    /// mission) are noise, and the readings after them are on the pad too. A rule comparing
    /// each reading with the one before took the pair for a step down and the pad for the
    /// field for the rest of the descent (0.8 m low, 0.3 m off the pad at touchdown).
    #[test]
    fn one_noisy_pair_of_readings_is_not_a_change_of_surface() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        let pad_m = 0.95;
        let altitude_up_m = 8.0;
        estimator.update(0.0, altitude_up_m, altitude_up_m);
        let surfaces_up_m = [
            0.0, 0.1, -0.05, 0.97, 0.0, 1.0, 0.92, 1.02, 1.18, 0.77, 0.98, 1.02, 0.94, 1.09, 1.16,
        ];
        for (tick, surface_up_m) in surfaces_up_m.into_iter().enumerate() {
            let expected = if surface_up_m > 0.5 {
                Surface::Pad
            } else {
                Surface::Ground
            };
            let reading_m = altitude_up_m - surface_up_m;
            let surface = estimator.update(1.0 + 0.1 * tick as f64, reading_m, altitude_up_m);
            assert_eq!(
                surface,
                Some(expected),
                "reading {tick}: {surface_up_m} m up"
            );
            if tick < 3 {
                continue; // the pad not yet seen: the height is above the field
            }
            let height_m = estimator.height_above_pad_m(altitude_up_m).unwrap();
            let truth_m = altitude_up_m - pad_m;
            assert!(
                (height_m - truth_m).abs() < 0.3,
                "reading {tick}: {height_m} m above the pad, truly {truth_m} m"
            );
        }
    }

    /// A long, noisy flight at the realistic world's rangefinder noise (3 cm + 1 % of the
    /// range, here Gaussian from a fixed generator) over a 0.9 m pad, the beam on the pad in
    /// runs of a few readings: every reading is put on the surface it hit.
    #[test]
    fn noisy_readings_at_height_are_put_on_their_surface() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        let pad_m = 0.9;
        let mut state: u64 = 0x2545_f491_4f6c_dd1d;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut gaussian = move || {
            let (u1, u2) = (uniform().max(1e-12), uniform());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        estimator.update(0.0, 0.1, 0.1);
        let mut on_pad = false;
        let mut wrong = 0;
        for tick in 0..5000 {
            let time_s = 1.0 + 0.1 * tick as f64;
            let true_up_m = 7.5 + 0.5 * (time_s / 7.0).sin();
            // The beam changes surface every 4th reading on average.
            if (gaussian() * 10.0) as i64 % 4 == 0 {
                on_pad = !on_pad;
            }
            let range_m = true_up_m - if on_pad { pad_m } else { 0.0 };
            let reading_m = range_m + (0.03 + 0.01 * range_m) * gaussian();
            let altitude_up_m = true_up_m + 0.02 * gaussian();
            let surface = estimator.update(time_s, reading_m, altitude_up_m);
            let expected = if on_pad {
                Surface::Pad
            } else {
                Surface::Ground
            };
            if surface != Some(expected) {
                wrong += 1;
            }
        }
        assert!(
            wrong <= 2,
            "{wrong} readings of 5000 put on the wrong surface"
        );
        let learned_m = estimator.pad_above_ground_m().unwrap();
        assert!((learned_m - pad_m).abs() < 0.05, "pad {learned_m} m");
    }

    /// Upwind of the pad the beam sees only the ground: the height above the pad is still the
    /// height above the ground less the pad's height learned before; before any pad reading
    /// it is the height above the ground.
    #[test]
    fn the_pad_height_is_remembered_while_the_beam_sees_only_the_ground() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        assert_eq!(estimator.height_above_pad_m(5.0), None);
        estimator.update(0.0, 0.1, 0.1);
        estimator.update(1.0, 7.5, 7.5);
        assert!((estimator.height_above_pad_m(7.5).unwrap() - 7.5).abs() < 1e-9);
        for tick in 0..40 {
            estimator.update(2.0 + tick as f64 * 0.1, 6.3, 7.5);
        }
        // After a pad reading the height is that reading, moved by the altitude since.
        assert!((estimator.height_above_pad_m(7.4).unwrap() - 6.2).abs() < 1e-9);
        for tick in 0..40 {
            let surface = estimator.update(6.0 + tick as f64 * 0.1, 7.5, 7.5);
            assert_eq!(surface, Some(Surface::Ground));
        }
        assert!((estimator.height_above_pad_m(7.5).unwrap() - 6.3).abs() < 1e-9);
    }

    /// A real PX4's barometric altitude drifts: here 0.8 m (twice the gate) over a minute in
    /// which the beam never leaves the pad, then the vehicle descends onto it. A level-based
    /// estimate took the pad for the ground by then and ended the descent 0.45 m up; the
    /// height must stay the reading.
    #[test]
    fn an_altitude_drifting_past_the_gate_does_not_move_the_pad() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        let pad_m = 1.1;
        // Take-off from the field, a flight out at 8.5 m, and onto the pad.
        estimator.update(0.0, 0.1, 0.1);
        estimator.update(5.0, 8.5, 8.5);
        assert_eq!(estimator.update(5.1, 8.5 - pad_m, 8.5), Some(Surface::Pad));
        let dt_s = 0.05;
        for tick in 0..1200 {
            let time_s = 5.2 + tick as f64 * dt_s;
            let true_up_m = 8.5 - 7.0 * (tick as f64 / 1200.0).powi(2);
            let drift_m = -0.8 * tick as f64 / 1200.0;
            let reading_m = true_up_m - pad_m;
            let surface = estimator.update(time_s, reading_m, true_up_m + drift_m);
            assert_eq!(surface, Some(Surface::Pad), "at {time_s} s");
            let got_m = estimator.height_above_pad_m(true_up_m + drift_m).unwrap();
            assert!(
                (got_m - reading_m).abs() < 1e-9,
                "{got_m} against {reading_m}"
            );
        }
    }

    /// Taken off from the pad, the first surface is the pad, not the field: the step down
    /// onto the field says so, and measures the pad.
    #[test]
    fn a_take_off_from_the_pad_learns_it_from_the_step_down() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        estimator.update(0.0, 0.1, 0.1);
        estimator.update(1.0, 3.0, 3.0);
        assert!((estimator.height_above_pad_m(3.0).unwrap() - 3.0).abs() < 1e-9);
        // Off the tractor's side: the surface drops by the pad's height.
        assert_eq!(estimator.update(1.1, 4.0, 3.0), Some(Surface::Ground));
        assert_eq!(estimator.pad_above_ground_m(), Some(1.0));
        assert!((estimator.height_above_pad_m(3.0).unwrap() - 3.0).abs() < 1e-9);
    }

    #[test]
    fn bad_readings_are_ignored_and_bad_config_is_named() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        assert_eq!(estimator.update(0.0, f64::NAN, 1.0), None);
        assert_eq!(estimator.height_above_pad_m(1.0), None);
        for (config, name) in [
            (
                PadHeightConfig {
                    gate_m: 0.0,
                    ..PadHeightConfig::default()
                },
                "gate_m",
            ),
            (
                PadHeightConfig {
                    step_weight: 1.5,
                    ..PadHeightConfig::default()
                },
                "step_weight",
            ),
            (
                PadHeightConfig {
                    level_weight: 0.0,
                    ..PadHeightConfig::default()
                },
                "level_weight",
            ),
        ] {
            let error = PadHeightEstimator::new(config).unwrap_err();
            assert!(error.to_string().contains(name), "{error}");
        }
    }
}
