//! Height above the landing pad from a downward rangefinder and the autopilot's altitude.
//!
//! A rangefinder under a vehicle following a tractor sees the pad's top or, when its beam
//! (along the leaning body's down axis) misses the 1 m pad, the field a pad-height lower: taken
//! as it is, the height jumps by that much, and a landing holding a height climbs and sinks
//! with every jump. The surfaces are told apart by their altitude (the autopilot's altitude
//! minus the reading): the ground is the lowest level the rangefinder has seen (from the
//! take-off point on) and tracks slowly; a surface more than `gate_m` above it is the pad, whose height
//! above the ground is learned from those readings. The height above the pad is then the
//! vehicle's altitude above the ground level less the pad's height, smooth whichever surface
//! the beam hits, and right while the beam sees only the ground (the vehicle upwind of the pad
//! in strong wind). The field is taken as level where the vehicle flies (a farm field).

use thiserror::Error;

/// The estimator's tuning.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadHeightConfig {
    /// A surface this much above the ground level is the pad. Below the pad's height and above
    /// the rangefinder's noise and the field's bumps.
    pub gate_m: f64,
    /// Low-pass time constant of the ground level and the pad's height: longer than the
    /// rangefinder's noise, shorter than the drift of the autopilot's altitude (tens of s).
    pub level_tau_s: f64,
    /// While the latest reading hit the pad and is younger than this, the height is that
    /// reading (moved by the altitude change since): exact to its noise on the pad, where a
    /// low-passed level could be a decimetre off and end a descent in the air.
    pub reading_fresh_s: f64,
}

impl Default for PadHeightConfig {
    fn default() -> Self {
        Self {
            gate_m: 0.4,
            level_tau_s: 1.0,
            reading_fresh_s: 0.5,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Error)]
pub enum PadHeightError {
    #[error("pad height config: {name} = {value} must be a finite number > 0")]
    Config { name: &'static str, value: f64 },
}

/// Which surface a reading was taken to come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    Ground,
    Pad,
}

/// See the module docs.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PadHeightEstimator {
    config: PadHeightConfig,
    /// The ground's altitude (up, in the autopilot's frame), metres.
    ground_up_m: Option<f64>,
    /// The pad's top above the ground, once a reading has hit it.
    pad_above_ground_m: Option<f64>,
    last_time_s: Option<f64>,
    /// The latest reading that hit the pad: the pad's altitude then, and when.
    latest_pad_up_m: Option<(f64, f64)>,
}

impl PadHeightEstimator {
    pub fn new(config: PadHeightConfig) -> Result<Self, PadHeightError> {
        for (name, value) in [
            ("gate_m", config.gate_m),
            ("level_tau_s", config.level_tau_s),
            ("reading_fresh_s", config.reading_fresh_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(PadHeightError::Config { name, value });
            }
        }
        Ok(Self {
            config,
            ground_up_m: None,
            pad_above_ground_m: None,
            last_time_s: None,
            latest_pad_up_m: None,
        })
    }

    /// Folds in a tilt-corrected rangefinder height taken at `altitude_up_m` (the autopilot's,
    /// up positive). Non-finite input is ignored (`None`).
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
        let dt_s = self
            .last_time_s
            .map_or(0.0, |previous_s| (time_s - previous_s).max(0.0));
        self.last_time_s = Some(time_s);
        let alpha = dt_s / (self.config.level_tau_s + dt_s);
        let surface_up_m = altitude_up_m - rangefinder_height_m;
        let Some(ground_up_m) = self.ground_up_m.as_mut() else {
            self.ground_up_m = Some(surface_up_m);
            return Some(Surface::Ground);
        };
        let above_ground_m = surface_up_m - *ground_up_m;
        let on_pad = above_ground_m > self.config.gate_m;
        self.latest_pad_up_m = on_pad.then_some((surface_up_m, time_s));
        if on_pad {
            let pad = self.pad_above_ground_m.get_or_insert(above_ground_m);
            // A pad level far from the learned one is a new pad (or another surface): start
            // there rather than creep.
            if (above_ground_m - *pad).abs() > self.config.gate_m {
                *pad = above_ground_m;
            } else {
                *pad += alpha * (above_ground_m - *pad);
            }
            Some(Surface::Pad)
        } else if above_ground_m < -self.config.gate_m {
            // Lower than the ground: the first surface was not the ground (a take-off from the
            // pad); this is.
            *ground_up_m = surface_up_m;
            Some(Surface::Ground)
        } else {
            *ground_up_m += alpha * above_ground_m;
            Some(Surface::Ground)
        }
    }

    /// The height above the pad at `altitude_up_m` and `time_s`: from the latest reading
    /// while it is fresh and hit the pad, else from the levels; above the ground until a
    /// reading has hit the pad, `None` before any reading.
    pub fn height_above_pad_m(&self, time_s: f64, altitude_up_m: f64) -> Option<f64> {
        if let Some((pad_up_m, at_s)) = self.latest_pad_up_m {
            if time_s - at_s <= self.config.reading_fresh_s {
                return Some(altitude_up_m - pad_up_m);
            }
        }
        let ground_up_m = self.ground_up_m?;
        Some(altitude_up_m - ground_up_m - self.pad_above_ground_m.unwrap_or(0.0))
    }

    /// The pad's top above the ground, once seen.
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
                let got_m = estimator
                    .height_above_pad_m(time_s, true_up_m + drift_m)
                    .unwrap();
                worst_m = worst_m.max((got_m - truth_m).abs());
            }
            raw_jump_m = raw_jump_m.max((reading_m - truth_m).abs());
        }
        assert!(raw_jump_m > 0.9, "the scenario must jump: {raw_jump_m}");
        assert!(worst_m < 0.06, "height error up to {worst_m} m");
        // The pad's height also takes up the ground level's lag behind the drift (~3 cm).
        let learned_m = estimator.pad_above_ground_m().unwrap();
        assert!((learned_m - pad_m).abs() < 0.05, "pad {learned_m} m");
    }

    /// Upwind of the pad the beam sees only the ground: the height above the pad is still the
    /// height above the ground less the pad's height learned before; before any pad reading
    /// it is the height above the ground.
    #[test]
    fn the_pad_height_is_remembered_while_the_beam_sees_only_the_ground() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        assert_eq!(estimator.height_above_pad_m(0.0, 5.0), None);
        estimator.update(0.0, 0.1, 0.1);
        estimator.update(1.0, 7.5, 7.5);
        assert!((estimator.height_above_pad_m(1.0, 7.5).unwrap() - 7.5).abs() < 1e-9);
        for tick in 0..40 {
            estimator.update(2.0 + tick as f64 * 0.1, 6.3, 7.5);
        }
        // Just after a pad reading the height is that reading, moved by the altitude since.
        assert!((estimator.height_above_pad_m(5.95, 7.4).unwrap() - 6.2).abs() < 1e-9);
        for tick in 0..40 {
            let surface = estimator.update(6.0 + tick as f64 * 0.1, 7.5, 7.5);
            assert_eq!(surface, Some(Surface::Ground));
        }
        assert!((estimator.height_above_pad_m(10.0, 7.5).unwrap() - 6.3).abs() < 0.01);
    }

    #[test]
    fn bad_readings_are_ignored_and_bad_config_is_named() {
        let mut estimator = PadHeightEstimator::new(PadHeightConfig::default()).unwrap();
        assert_eq!(estimator.update(0.0, f64::NAN, 1.0), None);
        assert_eq!(estimator.height_above_pad_m(0.0, 1.0), None);
        let error = PadHeightEstimator::new(PadHeightConfig {
            gate_m: 0.0,
            ..PadHeightConfig::default()
        })
        .unwrap_err();
        assert!(error.to_string().contains("gate_m"), "{error}");
    }
}
