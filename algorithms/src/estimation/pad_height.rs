//! Height above the landing pad from a downward rangefinder and the autopilot's altitude.
//!
//! A rangefinder under a vehicle following a tractor sees the pad's top or, when its beam
//! (along the leaning body's down axis) misses the 1 m pad, the field a pad-height lower: taken
//! as it is, the height jumps by that much, and a landing holding a height climbs and sinks
//! with every jump. The surfaces are told apart by the steps between consecutive readings:
//! the surface's altitude (the autopilot's altitude less the reading) rises by the pad's
//! height where the beam climbs onto the pad and falls by it where it slips off, while the
//! autopilot's altitude moves by millimetres between two readings. Each step measures the
//! pad's height above the ground; between steps the beam stays on the surface it stepped
//! onto. The height above the pad is then the latest reading, less the pad's height when
//! that reading hit the ground, moved by the autopilot's altitude change since.
//!
//! No absolute level is kept: the autopilot's altitude (barometric, drifting half a metre in
//! a minute of a real PX4's flight) never has to agree with itself across the flight, only
//! across one step. The field is taken as level where the vehicle flies (a farm field).

use thiserror::Error;

/// The estimator's tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadHeightConfig {
    /// A step of the surface's altitude larger than this between two readings is the beam
    /// changing surface. Below the pad's height and above the rangefinder's noise, the
    /// field's bumps and the altitude's change between readings.
    pub gate_m: f64,
    /// How far one step's measurement moves the learned pad height (0–1]: the steps' noise
    /// is the rangefinder's, twice.
    pub step_weight: f64,
}

impl Default for PadHeightConfig {
    fn default() -> Self {
        Self {
            gate_m: 0.4,
            step_weight: 0.25,
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

impl Reading {
    /// The altitude of the surface it hit, in the autopilot's frame.
    fn surface_up_m(&self) -> f64 {
        self.altitude_up_m - self.height_m
    }
}

/// See the module docs.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PadHeightEstimator {
    config: PadHeightConfig,
    latest: Option<Reading>,
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
        if !(config.step_weight > 0.0 && config.step_weight <= 1.0) {
            return Err(PadHeightError::Config {
                name: "step_weight",
                value: config.step_weight,
                why: "must be in (0, 1]",
            });
        }
        Ok(Self {
            config,
            latest: None,
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
        let mut reading = Reading {
            height_m: rangefinder_height_m,
            altitude_up_m,
            surface: Surface::Ground,
        };
        // The first surface is taken for the ground (a take-off from the field) until a step
        // says otherwise.
        if let Some(previous) = self.latest {
            let step_m = reading.surface_up_m() - previous.surface_up_m();
            reading.surface = if step_m.abs() <= self.config.gate_m {
                previous.surface
            } else if step_m > 0.0 {
                // Up onto the pad: a measurement, unless it was on the pad already (something
                // on it, or a higher part of the tractor).
                if previous.surface == Surface::Ground {
                    self.learn_pad_height(step_m);
                }
                Surface::Pad
            } else {
                // Down onto the ground, from the pad or from what was taken for the ground (a
                // take-off from the pad): either way the step is the pad's height.
                self.learn_pad_height(-step_m);
                Surface::Ground
            };
        }
        self.latest = Some(reading);
        Some(reading.surface)
    }

    fn learn_pad_height(&mut self, step_m: f64) {
        let weight = self.config.step_weight;
        let pad_m = self.pad_above_ground_m.get_or_insert(step_m);
        *pad_m += weight * (step_m - *pad_m);
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
        ] {
            let error = PadHeightEstimator::new(config).unwrap_err();
            assert!(error.to_string().contains(name), "{error}");
        }
    }
}
