//! The platform's velocity (seed 003, §IV-B, last paragraphs): differences of successive vision
//! fixes of the UAV's position relative to the platform, plus the UAV's own velocity, low-pass
//! filtered, and put along the platform's heading.
//!
//! The platform is a tractor: nonholonomic, so it moves along its heading, and it may turn through
//! 180°. Filtering the NED velocity components directly would drag the estimate through zero in a
//! U-turn; we filter the (signed) speed along the heading and the heading separately. When the
//! marker's orientation gives the platform's yaw, the heading comes from it without lag; otherwise
//! it is the low-passed direction of motion.

use nalgebra::{Vector2, Vector3};
use thiserror::Error;

/// A velocity estimator that cannot be built or fed as asked.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlatformVelocityError {
    #[error("{name} must be positive and finite, got {value}")]
    Config { name: &'static str, value: f64 },
    #[error("a time, position or velocity given to the platform velocity estimator is not finite")]
    NotFinite,
    #[error("time went backwards: {time_s} s is before the last fix at {last_s} s")]
    TimeBackwards { time_s: f64, last_s: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatformVelocityConfig {
    /// Time constant of the first-order low-pass on speed and heading, seconds.
    pub time_constant_s: f64,
    /// Shortest interval to difference over: shorter ones amplify the fixes' noise.
    pub min_baseline_s: f64,
    /// Below this speed the direction of motion is noise and the heading is held.
    pub min_speed_for_heading_mps: f64,
    /// After a gap longer than this (target lost) differencing restarts.
    pub max_gap_s: f64,
}

impl Default for PlatformVelocityConfig {
    fn default() -> Self {
        Self {
            time_constant_s: 0.5,
            min_baseline_s: 0.2,
            min_speed_for_heading_mps: 0.5,
            max_gap_s: 1.0,
        }
    }
}

/// One vision fix with the autopilot's velocity at the same instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatformFix {
    pub time_s: f64,
    /// UAV − platform, NED, metres (the tracker's convention).
    pub uav_relative_ned_m: Vector3<f64>,
    pub uav_velocity_ned_mps: Vector3<f64>,
    /// The platform's yaw from the marker's orientation, when the detector gives it.
    pub platform_yaw_rad: Option<f64>,
}

/// The estimate: horizontal velocity in NED (down component 0), signed speed along the heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatformVelocity {
    pub velocity_ned_mps: Vector3<f64>,
    pub speed_mps: f64,
    pub heading_rad: f64,
}

#[derive(Debug, Clone, Copy)]
struct Reference {
    time_s: f64,
    uav_relative_ned_m: Vector3<f64>,
    uav_velocity_ned_mps: Vector3<f64>,
}

/// See the module docs.
#[derive(Debug, Clone)]
pub struct PlatformVelocityEstimator {
    config: PlatformVelocityConfig,
    reference: Option<Reference>,
    last_time_s: f64,
    speed_mps: Option<f64>,
    /// Unit vector (north, east) of the heading.
    heading: Option<Vector2<f64>>,
}

impl PlatformVelocityEstimator {
    pub fn new(config: PlatformVelocityConfig) -> Result<Self, PlatformVelocityError> {
        for (name, value) in [
            ("time_constant_s", config.time_constant_s),
            ("min_baseline_s", config.min_baseline_s),
            (
                "min_speed_for_heading_mps",
                config.min_speed_for_heading_mps,
            ),
            ("max_gap_s", config.max_gap_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(PlatformVelocityError::Config { name, value });
            }
        }
        Ok(Self {
            config,
            reference: None,
            last_time_s: f64::NEG_INFINITY,
            speed_mps: None,
            heading: None,
        })
    }

    /// The current estimate; `None` until a speed and a heading are known.
    pub fn velocity(&self) -> Option<PlatformVelocity> {
        let (speed_mps, heading) = (self.speed_mps?, self.heading?);
        Some(PlatformVelocity {
            velocity_ned_mps: Vector3::new(heading.x, heading.y, 0.0) * speed_mps,
            speed_mps,
            heading_rad: heading.y.atan2(heading.x),
        })
    }

    /// Takes a fix and returns the updated estimate (unchanged until the baseline has elapsed).
    pub fn update(
        &mut self,
        fix: &PlatformFix,
    ) -> Result<Option<PlatformVelocity>, PlatformVelocityError> {
        let finite = fix.time_s.is_finite()
            && fix.uav_relative_ned_m.iter().all(|c| c.is_finite())
            && fix.uav_velocity_ned_mps.iter().all(|c| c.is_finite())
            && fix.platform_yaw_rad.is_none_or(|y| y.is_finite());
        if !finite {
            return Err(PlatformVelocityError::NotFinite);
        }
        if fix.time_s < self.last_time_s {
            return Err(PlatformVelocityError::TimeBackwards {
                time_s: fix.time_s,
                last_s: self.last_time_s,
            });
        }
        // A measured yaw is used as is: it carries no differencing lag.
        if let Some(yaw) = fix.platform_yaw_rad {
            self.heading = Some(Vector2::new(yaw.cos(), yaw.sin()));
        }
        let here = Reference {
            time_s: fix.time_s,
            uav_relative_ned_m: fix.uav_relative_ned_m,
            uav_velocity_ned_mps: fix.uav_velocity_ned_mps,
        };
        let gap_s = fix.time_s - self.last_time_s;
        self.last_time_s = fix.time_s;
        let reference = match self.reference {
            Some(r) if gap_s <= self.config.max_gap_s => r,
            _ => {
                self.reference = Some(here);
                return Ok(self.velocity());
            }
        };
        let baseline_s = fix.time_s - reference.time_s;
        if baseline_s < self.config.min_baseline_s {
            return Ok(self.velocity());
        }
        self.reference = Some(here);
        // platform = UAV − relative, so v_platform = mean v_UAV − Δrelative/Δt.
        let mean_uav_velocity = (reference.uav_velocity_ned_mps + fix.uav_velocity_ned_mps) * 0.5;
        let raw = mean_uav_velocity
            - (fix.uav_relative_ned_m - reference.uav_relative_ned_m) / baseline_s;
        let raw = Vector2::new(raw.x, raw.y);
        let alpha = 1.0 - (-baseline_s / self.config.time_constant_s).exp();
        if fix.platform_yaw_rad.is_none() && raw.norm() >= self.config.min_speed_for_heading_mps {
            let direction = raw.normalize();
            let blended = match self.heading {
                Some(h) => h + (direction - h) * alpha,
                None => direction,
            };
            // A blend through zero (a reversal in one step) carries no direction: keep the old.
            if blended.norm() > 1e-6 {
                self.heading = Some(blended.normalize());
            }
        }
        if let Some(h) = self.heading {
            let raw_speed_mps = raw.dot(&h);
            self.speed_mps = Some(match self.speed_mps {
                Some(s) => s + (raw_speed_mps - s) * alpha,
                None => raw_speed_mps,
            });
        }
        Ok(self.velocity())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimation::kalman::{FixOutcome, MotionInput, Tracker, TrackerConfig, VisionFix};
    use crate::vision::render::SplitMix64;
    use nalgebra::Matrix3;
    use std::f64::consts::PI;

    const SPEED_MPS: f64 = 3.0;
    const YAW_RATE_RAD_PER_S: f64 = 0.5; // radius 6 m
    const TURN_START_S: f64 = 5.0;
    const TURN_END_S: f64 = TURN_START_S + PI / YAW_RATE_RAD_PER_S;

    /// A tractor heading north at 3 m/s, U-turning through 180° at 0.5 rad/s, then heading south.
    fn tractor(t: f64) -> (Vector3<f64>, Vector3<f64>, f64) {
        let r = SPEED_MPS / YAW_RATE_RAD_PER_S;
        let yaw = (t.clamp(TURN_START_S, TURN_END_S) - TURN_START_S) * YAW_RATE_RAD_PER_S;
        let velocity = Vector3::new(yaw.cos(), yaw.sin(), 0.0) * SPEED_MPS;
        // Position in closed form: straight, arc (centre 6 m east of the turn's start), straight.
        let start = Vector3::new(SPEED_MPS * TURN_START_S, 0.0, 0.0);
        let position = if t <= TURN_START_S {
            Vector3::new(SPEED_MPS * t, 0.0, 0.0)
        } else {
            let arc = start + Vector3::new(r * yaw.sin(), r * (1.0 - yaw.cos()), 0.0);
            arc + velocity * (t - t.min(TURN_END_S))
        };
        (position, velocity, yaw)
    }

    /// The UAV hovers above the tractor with a lagging, wobbling offset.
    fn uav(t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let (p, v, _) = tractor(t);
        let offset = Vector3::new(1.5 * (0.7 * t).sin(), -1.0 + 0.5 * (0.4 * t).cos(), -8.0);
        let offset_rate = Vector3::new(1.05 * (0.7 * t).cos(), -0.2 * (0.4 * t).sin(), 0.0);
        (p + offset, v + offset_rate)
    }

    struct Errors {
        max_in_turn_mps: f64,
        max_after_turn_mps: f64,
        final_heading_rad: f64,
    }

    fn run(use_yaw: bool, seed: u64) -> Errors {
        let config = PlatformVelocityConfig::default();
        let mut estimator = PlatformVelocityEstimator::new(config).unwrap();
        let mut rng = SplitMix64::new(seed);
        let (fix_std_m, velocity_std_mps) = (0.05, 0.05);
        let mut errors = Errors {
            max_in_turn_mps: 0.0,
            max_after_turn_mps: 0.0,
            final_heading_rad: f64::NAN,
        };
        for k in 0..=(20.0 * 15.0) as usize {
            let t = k as f64 / 15.0; // 15 fps
            let (platform, platform_velocity, yaw) = tractor(t);
            let (uav_position, uav_velocity) = uav(t);
            let noise = |rng: &mut SplitMix64, s: f64| {
                Vector3::new(
                    rng.next_gaussian(),
                    rng.next_gaussian(),
                    rng.next_gaussian(),
                ) * s
            };
            let fix = PlatformFix {
                time_s: t,
                uav_relative_ned_m: uav_position - platform + noise(&mut rng, fix_std_m),
                uav_velocity_ned_mps: uav_velocity + noise(&mut rng, velocity_std_mps),
                platform_yaw_rad: use_yaw.then(|| yaw + 0.02 * rng.next_gaussian()),
            };
            let Some(est) = estimator.update(&fix).unwrap() else {
                continue;
            };
            let error = (est.velocity_ned_mps - platform_velocity).norm();
            if (TURN_START_S..=TURN_END_S).contains(&t) {
                errors.max_in_turn_mps = errors.max_in_turn_mps.max(error);
            } else if t > TURN_END_S + 3.0 {
                errors.max_after_turn_mps = errors.max_after_turn_mps.max(error);
            }
            errors.final_heading_rad = est.heading_rad;
        }
        errors
    }

    #[test]
    fn follows_a_u_turn_with_the_markers_yaw() {
        let e = run(true, 11);
        eprintln!(
            "with yaw: max error {:.3} m/s in the turn, {:.3} m/s after",
            e.max_in_turn_mps, e.max_after_turn_mps
        );
        // Speed is constant, so the turn costs nothing beyond noise: per axis the raw difference
        // has σ ≈ √2·0.05/0.2 ≈ 0.35 m/s, the low-pass keeps √(α/(2−α)) ≈ 0.45 of it.
        assert!(e.max_in_turn_mps < 0.5, "{}", e.max_in_turn_mps);
        assert!(e.max_after_turn_mps < 0.5, "{}", e.max_after_turn_mps);
        assert!((e.final_heading_rad.abs() - PI).abs() < 0.1);
    }

    #[test]
    fn follows_a_u_turn_from_the_direction_of_motion_alone() {
        let e = run(false, 12);
        eprintln!(
            "without yaw: max error {:.3} m/s in the turn, {:.3} m/s after",
            e.max_in_turn_mps, e.max_after_turn_mps
        );
        // The heading lags by about ω·(τ + baseline/2) = 0.5·0.6 = 0.3 rad: an error of
        // 2·v·sin(0.15) ≈ 0.9 m/s, plus noise.
        let lag_rad = YAW_RATE_RAD_PER_S * (0.5 + 0.1);
        let bound = 2.0 * SPEED_MPS * (lag_rad / 2.0).sin() + 0.5;
        assert!(
            e.max_in_turn_mps < bound,
            "{} vs {bound}",
            e.max_in_turn_mps
        );
        // It never collapses through zero and ends heading south.
        assert!(e.max_after_turn_mps < 0.5, "{}", e.max_after_turn_mps);
        assert!((e.final_heading_rad.abs() - PI).abs() < 0.15);
    }

    /// The tracker fed with this estimator's platform velocity through the U-turn.
    #[test]
    fn the_tracker_holds_the_relative_position_through_the_turn() {
        let mut estimator =
            PlatformVelocityEstimator::new(PlatformVelocityConfig::default()).unwrap();
        let mut tracker = Tracker::new(TrackerConfig {
            // The platform velocity's error (≲ 0.5 m/s) drives the relative position: its
            // variance growth is about (0.3 m/s)²·τ per second.
            process_noise_m2_per_s: 0.1,
            ..TrackerConfig::default()
        })
        .unwrap();
        let mut rng = SplitMix64::new(5);
        let fix_cov = Matrix3::identity() * 0.05f64.powi(2);
        let dt_s = 0.02;
        let mut worst_m: f64 = 0.0;
        let mut platform_velocity = Vector3::zeros();
        for k in 0..=1000 {
            let t = k as f64 * dt_s;
            let (platform, _, yaw) = tractor(t);
            let (uav_position, uav_velocity) = uav(t);
            let truth = uav_position - platform;
            if k > 0 {
                let input = MotionInput {
                    uav_velocity_ned_mps: uav_velocity,
                    uav_acceleration_ned_mps2: Vector3::zeros(),
                    platform_velocity_ned_mps: platform_velocity,
                };
                tracker.predict(t, &input).unwrap();
            }
            // ~17 fps, every fifth frame dropped.
            if k % 3 == 0 && (k / 3) % 5 != 4 {
                let noise = Vector3::new(rng.next_gaussian(), rng.next_gaussian(), 0.0) * 0.05;
                let measured = truth + noise;
                let outcome = tracker
                    .correct(&VisionFix {
                        capture_time_s: t,
                        uav_relative_ned_m: measured,
                        covariance_m2: fix_cov,
                    })
                    .unwrap();
                // Until the estimator has a velocity the tracker predicts with a still platform
                // and may gate fixes out; after that none may be lost.
                if estimator.velocity().is_some() {
                    assert!(!matches!(outcome, FixOutcome::Rejected { .. }), "t = {t}");
                }
                let fix = PlatformFix {
                    time_s: t,
                    uav_relative_ned_m: measured,
                    uav_velocity_ned_mps: uav_velocity,
                    platform_yaw_rad: Some(yaw),
                };
                if let Some(v) = estimator.update(&fix).unwrap() {
                    platform_velocity = v.velocity_ned_mps;
                }
            }
            if t > 2.0 {
                let est = tracker.estimate().unwrap();
                worst_m = worst_m.max((est.uav_relative_ned_m - truth).norm());
            }
        }
        eprintln!("tracker through the U-turn: worst error {worst_m:.3} m");
        assert!(worst_m < 0.2, "{worst_m}");
    }

    #[test]
    fn bad_input_is_a_named_error() {
        assert!(matches!(
            PlatformVelocityEstimator::new(PlatformVelocityConfig {
                time_constant_s: 0.0,
                ..PlatformVelocityConfig::default()
            }),
            Err(PlatformVelocityError::Config {
                name: "time_constant_s",
                ..
            })
        ));
        let mut e = PlatformVelocityEstimator::new(PlatformVelocityConfig::default()).unwrap();
        let fix = PlatformFix {
            time_s: 1.0,
            uav_relative_ned_m: Vector3::zeros(),
            uav_velocity_ned_mps: Vector3::zeros(),
            platform_yaw_rad: None,
        };
        assert_eq!(e.update(&fix).unwrap(), None);
        assert!(matches!(
            e.update(&PlatformFix { time_s: 0.5, ..fix }),
            Err(PlatformVelocityError::TimeBackwards { .. })
        ));
        assert_eq!(
            e.update(&PlatformFix {
                platform_yaw_rad: Some(f64::NAN),
                ..fix
            }),
            Err(PlatformVelocityError::NotFinite)
        );
    }
}
