//! Wind: the seed's gust model (seed 003, PX4 SITL with an Iris) and a Dryden turbulence option.
//!
//! Direction convention: `direction_from_rad` is meteorological, the direction the wind blows
//! *from*, clockwise from north (0 = a north wind blowing towards the south, π/2 = an east wind
//! blowing towards the west). The wind's velocity therefore points towards `direction_from_rad + π`.
//!
//! Force convention: the vehicle model applies its own drag against its ground velocity (still
//! air). What the wind adds is the change of that drag when the air moves:
//! `k·|v|·v − k·|v − w|·(v − w)` for vehicle velocity `v` and wind `w` (the Dryden option), with
//! the quadratic coefficient `k` fitted to the seed's figures. The seed's own model (`Gusts`) is a
//! pure force `k·speed²` downwind, independent of the vehicle's motion, as in the seed.

use std::f64::consts::PI;

use nalgebra::{Vector2, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use thiserror::Error;

/// Least-squares fit of `F = k·v²` to the seed's two figures: 3.45 N at 8 m/s and 7.76 N at
/// 12 m/s (k = Σ F·v² / Σ v⁴). Both are reproduced within 0.1 %.
pub const SEED_FORCE_COEFFICIENT_N_S2_PER_M2: f64 =
    (3.45 * 64.0 + 7.76 * 144.0) / (64.0 * 64.0 + 144.0 * 144.0);
/// The seed redraws the gust factor this often.
pub const GUST_PERIOD_S: f64 = 5.5;
/// The gust factor's range, as a fraction of the nominal speed.
pub const GUST_FACTOR_MIN: f64 = -0.10;
pub const GUST_FACTOR_MAX: f64 = 0.20;
/// Below this altitude the seed's force decreases linearly to zero at the ground.
pub const GROUND_RAMP_ALTITUDE_M: f64 = 6.0;

/// MIL-F-8785C's reference height for the low-altitude model: the wind speed is given at 20 ft.
const REFERENCE_HEIGHT_M: f64 = 6.096;
/// Surface roughness of MIL-F-8785C's log wind profile (0.15 ft, category C flight phases).
const ROUGHNESS_LENGTH_M: f64 = 0.04572;
/// The low-altitude turbulence formulas hold from 10 ft to 1000 ft; outside, clamp.
const TURBULENCE_MIN_ALTITUDE_M: f64 = 3.048;
const TURBULENCE_MAX_ALTITUDE_M: f64 = 304.8;
const FEET_PER_METRE: f64 = 1.0 / 0.3048;
/// Turbulence is frozen and carried past the vehicle at the relative airspeed; a hovering vehicle
/// in calm air still sees some, so the speed has a floor.
const MIN_TURBULENCE_AIRSPEED_M_S: f64 = 1.0;

/// Which wind to simulate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WindConfig {
    Calm,
    /// The seed's model: constant direction, nominal `speed_m_s` times a factor redrawn every
    /// 5.5 s uniformly in [−10 %, +20 %], the force ramping to zero below 6 m.
    Gusts {
        speed_m_s: f64,
        direction_from_rad: f64,
    },
    /// The seed's force law and ground ramp at a constant `speed_m_s`, no gusts: a clean step
    /// input when switched on in flight (the autopilots' hover-in-gust response).
    Steady {
        speed_m_s: f64,
        direction_from_rad: f64,
    },
    /// MIL-F-8785C low-altitude Dryden turbulence around a mean wind whose speed at 6 m (20 ft)
    /// is `speed_m_s`, following the standard's log profile with altitude.
    Dryden {
        speed_m_s: f64,
        direction_from_rad: f64,
    },
}

/// Which wind model blows at a given mean speed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WindKind {
    /// The seed's gust model.
    #[default]
    Gusts,
    /// Dryden turbulence around the mean wind.
    Dryden,
}

impl WindConfig {
    /// The wind of `kind` at `speed_m_s`, from the east as the seed's; calm at 0.
    pub fn from_east(speed_m_s: f64, kind: WindKind) -> Self {
        match (speed_m_s > 0.0, kind) {
            (false, _) => Self::Calm,
            (true, WindKind::Gusts) => Self::Gusts {
                speed_m_s,
                direction_from_rad: std::f64::consts::FRAC_PI_2,
            },
            (true, WindKind::Dryden) => Self::Dryden {
                speed_m_s,
                direction_from_rad: std::f64::consts::FRAC_PI_2,
            },
        }
    }
}

/// A wind configuration or a query that cannot be used.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum WindError {
    #[error("wind speed {0} m/s must be a finite number ≥ 0")]
    Speed(f64),
    #[error("wind direction {0} rad must be finite")]
    Direction(f64),
}

/// The three Dryden turbulence intensities (standard deviations of the gust velocity).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrydenIntensities {
    pub longitudinal_m_s: f64,
    pub lateral_m_s: f64,
    pub vertical_m_s: f64,
}

/// The three Dryden length scales.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrydenLengthScales {
    pub longitudinal_m: f64,
    pub lateral_m: f64,
    pub vertical_m: f64,
}

/// MIL-F-8785C low altitude: `h` in feet, clamped to [10, 1000] ft.
fn low_altitude_factor(altitude_m: f64) -> (f64, f64) {
    let h_m = altitude_m.clamp(TURBULENCE_MIN_ALTITUDE_M, TURBULENCE_MAX_ALTITUDE_M);
    let h_ft = h_m * FEET_PER_METRE;
    (h_m, 0.177 + 0.000823 * h_ft)
}

/// σ_w = 0.1·W20, σ_u = σ_v = σ_w / (0.177 + 0.000823·h)^0.4 (h in ft).
pub fn dryden_intensities(altitude_m: f64, speed_at_6m_m_s: f64) -> DrydenIntensities {
    let (_, factor) = low_altitude_factor(altitude_m);
    let vertical_m_s = 0.1 * speed_at_6m_m_s;
    let horizontal_m_s = vertical_m_s / factor.powf(0.4);
    DrydenIntensities {
        longitudinal_m_s: horizontal_m_s,
        lateral_m_s: horizontal_m_s,
        vertical_m_s,
    }
}

/// L_w = h, L_u = L_v = h / (0.177 + 0.000823·h)^1.2 (h in ft; the ratio keeps metres).
pub fn dryden_length_scales(altitude_m: f64) -> DrydenLengthScales {
    let (h_m, factor) = low_altitude_factor(altitude_m);
    let horizontal_m = h_m / factor.powf(1.2);
    DrydenLengthScales {
        longitudinal_m: horizontal_m,
        lateral_m: horizontal_m,
        vertical_m: h_m,
    }
}

/// MIL-F-8785C's mean wind profile: W(h) = W20·ln(h/z0)/ln(20 ft/z0), zero at the roughness
/// height and below.
pub fn mean_wind_speed_m_s(altitude_m: f64, speed_at_6m_m_s: f64) -> f64 {
    if altitude_m <= ROUGHNESS_LENGTH_M {
        return 0.0;
    }
    speed_at_6m_m_s * (altitude_m / ROUGHNESS_LENGTH_M).ln()
        / (REFERENCE_HEIGHT_M / ROUGHNESS_LENGTH_M).ln()
}

/// The seed's altitude ramp: 0 at the ground, 1 from 6 m up.
pub fn ground_ramp(altitude_m: f64) -> f64 {
    (altitude_m / GROUND_RAMP_ALTITUDE_M).clamp(0.0, 1.0)
}

/// Unit vector the wind blows towards, NE.
fn downwind_ne(direction_from_rad: f64) -> Vector2<f64> {
    -Vector2::new(direction_from_rad.cos(), direction_from_rad.sin())
}

fn standard_normal(rng: &mut StdRng) -> f64 {
    // Box–Muller; 1 − U keeps the logarithm's argument in (0, 1].
    let u1 = 1.0 - rng.random::<f64>();
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

/// Dryden's lateral/vertical shaping filter (1 + √3·T·s)/(1 + T·s)², written as two identical
/// first-order lags x1 → x2 with output √3·x1 + (1 − √3)·x2, normalised to unit output variance.
/// Its stationary covariance P does not depend on T, so the exact discretisation's noise
/// covariance is Q = P − Φ·P·Φᵀ for any step and any T.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SecondOrderShaping {
    x1: f64,
    x2: f64,
}

const SHAPING_P11: f64 = 0.5;
const SHAPING_P12: f64 = 0.25;
const SHAPING_P22: f64 = 0.25;

impl SecondOrderShaping {
    fn stationary(rng: &mut StdRng) -> Self {
        let (l11, l21, l22) = cholesky(SHAPING_P11, SHAPING_P12, SHAPING_P22);
        let (n1, n2) = (standard_normal(rng), standard_normal(rng));
        Self {
            x1: l11 * n1,
            x2: l21 * n1 + l22 * n2,
        }
    }

    fn advance(&mut self, dt_s: f64, time_constant_s: f64, rng: &mut StdRng) {
        let a = (-dt_s / time_constant_s).exp();
        let b = dt_s / time_constant_s;
        let a2 = a * a;
        let q11 = SHAPING_P11 * (1.0 - a2);
        let q12 = SHAPING_P12 - a2 * (SHAPING_P11 * b + SHAPING_P12);
        let q22 = SHAPING_P22 - a2 * (SHAPING_P11 * b * b + 2.0 * SHAPING_P12 * b + SHAPING_P22);
        let (l11, l21, l22) = cholesky(q11, q12, q22);
        let (n1, n2) = (standard_normal(rng), standard_normal(rng));
        let x1 = a * self.x1 + l11 * n1;
        let x2 = a * (b * self.x1 + self.x2) + l21 * n1 + l22 * n2;
        self.x1 = x1;
        self.x2 = x2;
    }

    fn output(&self) -> f64 {
        3f64.sqrt() * self.x1 + (1.0 - 3f64.sqrt()) * self.x2
    }
}

/// Lower-triangular factor of [[p11, p12], [p12, p22]]; rounding can make a tiny covariance
/// slightly indefinite, which is clamped to zero.
fn cholesky(p11: f64, p12: f64, p22: f64) -> (f64, f64, f64) {
    if p11 <= 0.0 {
        return (0.0, 0.0, p22.max(0.0).sqrt());
    }
    let l11 = p11.sqrt();
    let l21 = p12 / l11;
    let l22 = (p22 - l21 * l21).max(0.0).sqrt();
    (l11, l21, l22)
}

/// Dryden state: unit-variance longitudinal (first order), lateral and vertical (second order).
#[derive(Debug, Clone)]
struct DrydenState {
    longitudinal: f64,
    lateral: SecondOrderShaping,
    vertical: SecondOrderShaping,
    last_time_s: Option<f64>,
    airspeed_m_s: f64,
    gust_ned_m_s: Vector3<f64>,
}

/// The wind field seen by one vehicle; deterministic for a given seed.
#[derive(Debug, Clone)]
pub struct Wind {
    config: WindConfig,
    seed: u64,
    /// The gust interval whose factor is cached, and the factor.
    cached_gust: Option<(i64, f64)>,
    rng: StdRng,
    dryden: Option<DrydenState>,
}

impl Wind {
    pub fn new(config: WindConfig, seed: u64) -> Result<Self, WindError> {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut dryden = None;
        match config {
            WindConfig::Calm => {}
            WindConfig::Gusts {
                speed_m_s,
                direction_from_rad,
            }
            | WindConfig::Steady {
                speed_m_s,
                direction_from_rad,
            }
            | WindConfig::Dryden {
                speed_m_s,
                direction_from_rad,
            } => {
                if !(speed_m_s.is_finite() && speed_m_s >= 0.0) {
                    return Err(WindError::Speed(speed_m_s));
                }
                if !direction_from_rad.is_finite() {
                    return Err(WindError::Direction(direction_from_rad));
                }
                if matches!(config, WindConfig::Dryden { .. }) {
                    dryden = Some(DrydenState {
                        longitudinal: standard_normal(&mut rng),
                        lateral: SecondOrderShaping::stationary(&mut rng),
                        vertical: SecondOrderShaping::stationary(&mut rng),
                        last_time_s: None,
                        airspeed_m_s: speed_m_s.max(MIN_TURBULENCE_AIRSPEED_M_S),
                        gust_ned_m_s: Vector3::zeros(),
                    });
                }
            }
        }
        Ok(Self {
            config,
            seed,
            cached_gust: None,
            rng,
            dryden,
        })
    }

    pub fn config(&self) -> WindConfig {
        self.config
    }

    /// The seed's gust factor in force at `time_s`: one uniform draw per 5.5 s interval, from a
    /// generator seeded by (seed, interval), so it does not depend on how often it is asked.
    pub fn gust_factor(&mut self, time_s: f64) -> f64 {
        let interval = if time_s.is_finite() {
            (time_s.max(0.0) / GUST_PERIOD_S).floor() as i64
        } else {
            0
        };
        if let Some((cached, factor)) = self.cached_gust {
            if cached == interval {
                return factor;
            }
        }
        let interval_seed = self
            .seed
            .wrapping_add((interval as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let mut rng = StdRng::seed_from_u64(interval_seed);
        let factor = GUST_FACTOR_MIN + (GUST_FACTOR_MAX - GUST_FACTOR_MIN) * rng.random::<f64>();
        self.cached_gust = Some((interval, factor));
        factor
    }

    /// The speed of the seed's force law at `time_s` (above the ground ramp): the nominal speed
    /// times the gust factor for `Gusts`, the speed for `Steady`, 0 otherwise.
    fn seed_speed_m_s(&mut self, time_s: f64) -> f64 {
        match self.config {
            WindConfig::Gusts { speed_m_s, .. } => speed_m_s * (1.0 + self.gust_factor(time_s)),
            WindConfig::Steady { speed_m_s, .. } => speed_m_s,
            WindConfig::Calm | WindConfig::Dryden { .. } => 0.0,
        }
    }

    /// The wind's velocity at the vehicle, NED. For `Gusts` it is the speed whose seed force is
    /// applied (so it also ramps below 6 m, as √ of the force ramp). For `Dryden` the turbulence
    /// advances to `time_s` using the airspeed of the last [`Self::force_ned_n`] call.
    pub fn wind_velocity_ned_m_s(&mut self, time_s: f64, altitude_m: f64) -> Vector3<f64> {
        match self.config {
            WindConfig::Calm => Vector3::zeros(),
            WindConfig::Gusts {
                direction_from_rad, ..
            }
            | WindConfig::Steady {
                direction_from_rad, ..
            } => {
                let speed = self.seed_speed_m_s(time_s) * ground_ramp(altitude_m).sqrt();
                let d = downwind_ne(direction_from_rad);
                Vector3::new(d.x, d.y, 0.0) * speed
            }
            WindConfig::Dryden {
                speed_m_s,
                direction_from_rad,
            } => {
                let mean = mean_wind_speed_m_s(altitude_m, speed_m_s);
                let d = downwind_ne(direction_from_rad);
                let mean_ned = Vector3::new(d.x, d.y, 0.0) * mean;
                mean_ned + self.advance_dryden(time_s, altitude_m, speed_m_s, direction_from_rad)
            }
        }
    }

    /// The force the wind puts on the vehicle, NED (see the module's force convention).
    pub fn force_ned_n(
        &mut self,
        time_s: f64,
        altitude_m: f64,
        vehicle_velocity_ned_m_s: Vector3<f64>,
    ) -> Vector3<f64> {
        let k = SEED_FORCE_COEFFICIENT_N_S2_PER_M2;
        match self.config {
            WindConfig::Calm => Vector3::zeros(),
            WindConfig::Gusts {
                direction_from_rad, ..
            }
            | WindConfig::Steady {
                direction_from_rad, ..
            } => {
                let speed = self.seed_speed_m_s(time_s);
                let d = downwind_ne(direction_from_rad);
                Vector3::new(d.x, d.y, 0.0) * (k * speed * speed * ground_ramp(altitude_m))
            }
            WindConfig::Dryden { .. } => {
                let wind = self.wind_velocity_ned_m_s(time_s, altitude_m);
                let v = vehicle_velocity_ned_m_s;
                if !v.iter().all(|c| c.is_finite()) {
                    return Vector3::zeros();
                }
                let air = v - wind;
                if let Some(state) = &mut self.dryden {
                    // The turbulence is carried past the vehicle at its speed through the mean wind.
                    state.airspeed_m_s = air.norm().max(MIN_TURBULENCE_AIRSPEED_M_S);
                }
                (v * v.norm() - air * air.norm()) * k
            }
        }
    }

    /// The Dryden gust velocity (without the mean wind), NED, advanced to `time_s`.
    fn advance_dryden(
        &mut self,
        time_s: f64,
        altitude_m: f64,
        speed_m_s: f64,
        direction_from_rad: f64,
    ) -> Vector3<f64> {
        let Some(state) = &mut self.dryden else {
            return Vector3::zeros();
        };
        let dt_s = match state.last_time_s {
            Some(last) if time_s.is_finite() => time_s - last,
            _ => 0.0,
        };
        if time_s.is_finite() && (state.last_time_s.is_none() || dt_s > 0.0) {
            state.last_time_s = Some(time_s);
        }
        if dt_s > 0.0 {
            let scales = dryden_length_scales(altitude_m);
            let v = state.airspeed_m_s;
            let a = (-dt_s * v / scales.longitudinal_m).exp();
            state.longitudinal =
                a * state.longitudinal + (1.0 - a * a).sqrt() * standard_normal(&mut self.rng);
            state
                .lateral
                .advance(dt_s, scales.lateral_m / v, &mut self.rng);
            state
                .vertical
                .advance(dt_s, scales.vertical_m / v, &mut self.rng);
        }
        let sigma = dryden_intensities(altitude_m, speed_m_s);
        let along = downwind_ne(direction_from_rad);
        let across = Vector2::new(-along.y, along.x);
        let horizontal = along * (sigma.longitudinal_m_s * state.longitudinal)
            + across * (sigma.lateral_m_s * state.lateral.output());
        state.gust_ned_m_s = Vector3::new(
            horizontal.x,
            horizontal.y,
            sigma.vertical_m_s * state.vertical.output(),
        );
        state.gust_ned_m_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gusts(speed_m_s: f64) -> Wind {
        Wind::new(
            WindConfig::Gusts {
                speed_m_s,
                direction_from_rad: 0.0,
            },
            7,
        )
        .unwrap()
    }

    #[test]
    fn a_steady_wind_is_the_seed_force_without_its_gusts() {
        let mut wind = Wind::new(
            WindConfig::Steady {
                speed_m_s: 8.0,
                direction_from_rad: PI / 2.0,
            },
            3,
        )
        .unwrap();
        // The seed's 3.45 N at 8 m/s, towards the west, at every time (the gusts would redraw
        // it every 5.5 s), and half of it at 3 m, half-way up the ground ramp.
        for time_s in [0.0, 3.0, 7.0, 60.0] {
            let force = wind.force_ned_n(time_s, 10.0, Vector3::zeros());
            assert!((force.y + 3.45).abs() < 0.01, "{time_s} s: {force}");
            assert!(
                force.x.abs() < 1e-9 && force.z == 0.0,
                "{time_s} s: {force}"
            );
            let low = wind.force_ned_n(time_s, 3.0, Vector3::zeros());
            assert!((low.y * 2.0 - force.y).abs() < 1e-9, "{low} at 3 m");
            let velocity = wind.wind_velocity_ned_m_s(time_s, 10.0);
            assert!((velocity.y + 8.0).abs() < 1e-9, "{velocity}");
        }
    }

    #[test]
    fn seed_force_figures_are_reproduced() {
        let k = SEED_FORCE_COEFFICIENT_N_S2_PER_M2;
        for (speed, force) in [(8.0, 3.45), (12.0, 7.76)] {
            let model = k * speed * speed;
            assert!(
                ((model - force) / force).abs() < 0.01,
                "{speed} m/s: {model} N vs {force} N"
            );
        }
    }

    #[test]
    fn gust_factor_is_bounded_and_changes_only_at_period_boundaries() {
        let mut wind = gusts(8.0);
        let dt = 0.05;
        let mut previous = wind.gust_factor(0.0);
        let mut distinct = 1;
        let (mut lowest, mut highest) = (previous, previous);
        for i in 1..20_000 {
            let t = i as f64 * dt;
            let f = wind.gust_factor(t);
            assert!((GUST_FACTOR_MIN..=GUST_FACTOR_MAX).contains(&f));
            if f != previous {
                distinct += 1;
                let phase = t / GUST_PERIOD_S - (t / GUST_PERIOD_S).round();
                // The change happens at the first sample at or after a boundary.
                let since_boundary_s = t - (t / GUST_PERIOD_S).floor() * GUST_PERIOD_S;
                assert!(since_boundary_s < dt + 1e-9, "changed at {t} s ({phase})");
            }
            lowest = lowest.min(f);
            highest = highest.max(f);
            previous = f;
        }
        // 1000 s / 5.5 s ≈ 181 intervals; the draws spread over the range.
        assert!(distinct > 150, "{distinct}");
        assert!(lowest < -0.08 && highest > 0.18, "{lowest} {highest}");
    }

    #[test]
    fn force_follows_the_factor_direction_and_ground_ramp() {
        let mut wind = Wind::new(
            WindConfig::Gusts {
                speed_m_s: 10.0,
                direction_from_rad: PI / 2.0,
            },
            3,
        )
        .unwrap();
        let t = 12.0;
        let f = wind.gust_factor(t);
        let expected = 0.0538923 * (10.0 * (1.0 + f)).powi(2);
        let high = wind.force_ned_n(t, 20.0, Vector3::new(3.0, 0.0, 0.0));
        // An east wind blows towards the west (−east), horizontally.
        assert!((high.y + expected).abs() < 1e-3 * expected, "{high:?}");
        assert!(high.x.abs() < 1e-12 && high.z == 0.0);
        let low = wind.force_ned_n(t, 3.0, Vector3::zeros());
        assert!((low.y / high.y - 0.5).abs() < 1e-12);
        assert_eq!(wind.force_ned_n(t, 0.0, Vector3::zeros()).norm(), 0.0);
        assert_eq!(wind.force_ned_n(t, 6.0, Vector3::zeros()), high);
    }

    #[test]
    fn deterministic_per_seed() {
        let config = WindConfig::Dryden {
            speed_m_s: 6.0,
            direction_from_rad: 1.0,
        };
        let run = |seed: u64| {
            let mut wind = Wind::new(config, seed).unwrap();
            let mut gusts = gusts(8.0);
            (0..2000)
                .map(|i| {
                    let t = i as f64 * 0.01;
                    let v = Vector3::new(1.0, 0.0, 0.0);
                    (wind.force_ned_n(t, 10.0, v), gusts.gust_factor(t * 50.0))
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(run(11), run(11));
        assert_ne!(run(11), run(12));
        let mut a = Wind::new(config, 11).unwrap();
        let mut b = Wind::new(config, 11).unwrap();
        assert_eq!(a.gust_factor(100.0), b.gust_factor(100.0));
    }

    #[test]
    fn dryden_gust_standard_deviations_match_the_intensities() {
        let speed = 8.0;
        let altitude = 20.0;
        let mut wind = Wind::new(
            WindConfig::Dryden {
                speed_m_s: speed,
                direction_from_rad: 0.0,
            },
            5,
        )
        .unwrap();
        // Independent MIL-F-8785C numbers at 20 m = 65.6 ft: σ_w = 0.8 m/s,
        // σ_u = σ_v = 0.8 / (0.177 + 0.000823·65.62)^0.4.
        let h_ft: f64 = 20.0 / 0.3048;
        let sigma_w = 0.1 * speed;
        let sigma_uv = sigma_w / (0.177 + 0.000823 * h_ft).powf(0.4);
        let sigma = dryden_intensities(altitude, speed);
        assert!((sigma.vertical_m_s - sigma_w).abs() < 1e-12);
        assert!((sigma.longitudinal_m_s - sigma_uv).abs() < 1e-12);

        // Hovering vehicle: turbulence carried at the mean wind speed. Many correlation times
        // (L_u ≈ 116 m → ~13 s), with a coarse step since the discretisation is exact.
        let mean = mean_wind_speed_m_s(altitude, speed);
        let dt = 0.1;
        let n = 400_000;
        let mut sum = Vector3::zeros();
        let mut sum_sq = Vector3::zeros();
        for i in 0..n {
            let t = i as f64 * dt;
            wind.force_ned_n(t, altitude, Vector3::zeros());
            let gust = wind.wind_velocity_ned_m_s(t, altitude) - Vector3::new(-mean, 0.0, 0.0);
            sum += gust;
            sum_sq += gust.component_mul(&gust);
        }
        let mean_gust = sum / n as f64;
        let std = (sum_sq / n as f64 - mean_gust.component_mul(&mean_gust)).map(f64::sqrt);
        for (measured, expected) in [(std.x, sigma_uv), (std.y, sigma_uv), (std.z, sigma_w)] {
            assert!(
                (measured / expected - 1.0).abs() < 0.15,
                "{measured} vs {expected}"
            );
        }
    }

    #[test]
    fn dryden_force_is_the_drag_change_from_the_moving_air() {
        let mut wind = Wind::new(
            WindConfig::Dryden {
                speed_m_s: 0.0,
                direction_from_rad: 0.0,
            },
            1,
        )
        .unwrap();
        // No wind: no force whatever the vehicle does.
        assert_eq!(
            wind.force_ned_n(1.0, 10.0, Vector3::new(5.0, 0.0, 0.0)),
            Vector3::zeros()
        );
        // A hovering vehicle in mean wind gets the seed's k·W² downwind (gusts are random, so
        // average over a long run).
        let mut wind = Wind::new(
            WindConfig::Dryden {
                speed_m_s: 8.0,
                direction_from_rad: 0.0,
            },
            1,
        )
        .unwrap();
        let mut sum = 0.0;
        let n = 20_000;
        for i in 0..n {
            sum += wind
                .force_ned_n(i as f64 * 0.1, REFERENCE_HEIGHT_M, Vector3::zeros())
                .x;
        }
        let expected = -SEED_FORCE_COEFFICIENT_N_S2_PER_M2 * 64.0;
        // The mean of (W + u)² exceeds W² by σ_u²; allow for it.
        assert!(((sum / n as f64) / expected - 1.0).abs() < 0.1);
    }

    #[test]
    fn bad_configurations_are_refused() {
        assert_eq!(
            Wind::new(
                WindConfig::Gusts {
                    speed_m_s: -1.0,
                    direction_from_rad: 0.0
                },
                0
            )
            .unwrap_err(),
            WindError::Speed(-1.0)
        );
        assert!(matches!(
            Wind::new(
                WindConfig::Dryden {
                    speed_m_s: 1.0,
                    direction_from_rad: f64::NAN
                },
                0
            ),
            Err(WindError::Direction(_))
        ));
        let mut calm = Wind::new(WindConfig::Calm, 0).unwrap();
        assert_eq!(
            calm.force_ned_n(1.0, 10.0, Vector3::new(1.0, 2.0, 3.0)),
            Vector3::zeros()
        );
    }
}
