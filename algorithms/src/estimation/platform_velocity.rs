//! The platform's velocity (seed 003, §IV-B, last paragraphs): from successive vision fixes of
//! the UAV's position relative to the platform plus the UAV's own velocity.
//!
//! The seed differences successive fixes and low-pass filters the result. Differencing over a
//! fixed baseline amplifies the fixes' noise and the filter adds its lag whatever the fixes'
//! quality: in the realistic simulator the estimate was 0.2 m/s RMS off a tractor at 1.5 m/s,
//! and the landing's last, blind half-metre drifted with that error. We run a Kalman filter
//! with a constant-velocity model on the platform's horizontal position instead: the same
//! measurements, weighted by their variance, with the platform's acceleration as process noise.
//! The position is measured in a frame carried by the UAV's integrated velocity, so only the
//! fixes and the UAV's velocity are needed (no GPS position).
//!
//! The platform is a tractor: nonholonomic, so it moves along its heading. When the marker's
//! orientation gives the platform's yaw, the velocity is put along it; otherwise the heading is
//! the direction of the estimated velocity, held while the platform is too slow to have one.
//!
//! Between fixes, and for a while after the last one, the velocity is carried round at the
//! heading's measured rate of turn ([`PlatformVelocityEstimator::velocity_at`]): below about a
//! metre the camera sees too little of the marker, and a tractor turning while the vehicle
//! descends that last, blind second moved on a curve the frozen velocity did not follow (the
//! real ArduPilot on the figure-eight: 0.23 m off at contact, the estimate reading 0.01 m).

use nalgebra::{Matrix2, RowVector2, Vector2, Vector3};
use std::f64::consts::{PI, TAU};
use thiserror::Error;

/// A velocity estimator that cannot be built or fed as asked.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlatformVelocityError {
    #[error("{name} must be positive and finite, got {value}")]
    Config { name: &'static str, value: f64 },
    #[error("a time, position, velocity or variance given to the platform velocity estimator is not finite (or the variance is not positive)")]
    NotFinite,
    #[error("time went backwards: {time_s} s is before the last fix at {last_s} s")]
    TimeBackwards { time_s: f64, last_s: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatformVelocityConfig {
    /// Spectral density of the platform's acceleration (white noise) along each horizontal
    /// axis, m²/s³: how fast its velocity may change. A tractor braking or turning at 1.5 m/s
    /// accelerates at up to about 0.5 m/s².
    pub acceleration_noise_m2_per_s3: f64,
    /// Standard deviation of the platform's speed before any fix, along each axis, m/s.
    pub initial_velocity_std_m_s: f64,
    /// Below this speed the direction of motion is noise and the heading is held.
    pub min_speed_for_heading_m_s: f64,
    /// After a gap longer than this (target lost) the filter restarts.
    pub max_gap_s: f64,
    /// The estimate is given out only once its standard deviation along each axis is at most
    /// this, m/s. Right after a (re)start a few fixes define the velocity, and one fix off by
    /// the attitude's timing (a body-fixed camera at 7 m, a real PX4) read 1.5 m/s for a
    /// parked tractor, which the landing fed forward and lost the pad.
    pub max_velocity_std_m_s: f64,
    /// Low-pass time constant on the heading's rate of turn. One fix's heading wobbles with the
    /// fixes' noise, and a fix thrown off by a gust swung it 28° in 0.1 s (the realistic world,
    /// Dryden): over 0.5 s that read as a turn of 0.9 rad/s the tractor never made, and carried
    /// on it lost the pad. A tractor's turn lasts seconds.
    pub turn_rate_tau_s: f64,
    /// The rate of turn is taken as at most this, rad/s: half again a tractor's (about 4 m of
    /// radius at 2 m/s, 0.5 rad/s), so that the noise on a turn at that rate still averages
    /// out, while a heading thrown further than the low-pass absorbs is not carried on.
    pub max_turn_rate_rad_s: f64,
    /// The velocity is carried round at that rate for at most this long after the last fix
    /// (about the blind last metre of a descent); 0: held as the last fix left it.
    pub max_turn_extrapolation_s: f64,
}

impl Default for PlatformVelocityConfig {
    fn default() -> Self {
        Self {
            acceleration_noise_m2_per_s3: 0.5,
            initial_velocity_std_m_s: 3.0,
            min_speed_for_heading_m_s: 0.5,
            max_gap_s: 1.0,
            max_velocity_std_m_s: 0.5,
            turn_rate_tau_s: 1.0,
            max_turn_rate_rad_s: 0.75,
            max_turn_extrapolation_s: 1.5,
        }
    }
}

/// One vision fix with the autopilot's velocity at the same instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatformFix {
    pub time_s: f64,
    /// UAV − platform, NED, metres (the tracker's convention).
    pub uav_relative_ned_m: Vector3<f64>,
    /// Variance of the fix along each horizontal axis, m².
    pub horizontal_variance_m2: f64,
    pub uav_velocity_ned_m_s: Vector3<f64>,
    /// The platform's yaw from the marker's orientation, when the detector gives it.
    pub platform_yaw_rad: Option<f64>,
}

/// The estimate: horizontal velocity in NED (down component 0), signed speed along the heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatformVelocity {
    pub velocity_ned_m_s: Vector3<f64>,
    pub speed_m_s: f64,
    pub heading_rad: f64,
}

/// The filter: rows position and velocity, columns north and east. Both axes see the same
/// fixes, intervals and noise, so they share one covariance.
#[derive(Debug, Clone, Copy)]
struct Filter {
    time_s: f64,
    state: Matrix2<f64>,
    covariance: Matrix2<f64>,
    /// The UAV's displacement since the filter started, integrated from its velocity.
    uav_displacement_ne_m: Vector2<f64>,
    uav_velocity_ne_m_s: Vector2<f64>,
    fixes: usize,
}

/// See the module docs.
#[derive(Debug, Clone)]
pub struct PlatformVelocityEstimator {
    config: PlatformVelocityConfig,
    filter: Option<Filter>,
    /// Unit vector (north, east) of the heading.
    heading: Option<Vector2<f64>>,
    measured_heading: bool,
    /// The heading's rate of turn, kept while the heading is known fix after fix.
    turn: Option<Turn>,
}

/// The heading at the last fix that gave one, and its rate of turn, low-passed.
#[derive(Debug, Clone, Copy)]
struct Turn {
    time_s: f64,
    heading: Vector2<f64>,
    rate_rad_s: f64,
}

impl PlatformVelocityEstimator {
    pub fn new(config: PlatformVelocityConfig) -> Result<Self, PlatformVelocityError> {
        for (name, value) in [
            (
                "acceleration_noise_m2_per_s3",
                config.acceleration_noise_m2_per_s3,
            ),
            ("initial_velocity_std_m_s", config.initial_velocity_std_m_s),
            (
                "min_speed_for_heading_m_s",
                config.min_speed_for_heading_m_s,
            ),
            ("max_gap_s", config.max_gap_s),
            ("max_velocity_std_m_s", config.max_velocity_std_m_s),
            ("turn_rate_tau_s", config.turn_rate_tau_s),
            ("max_turn_rate_rad_s", config.max_turn_rate_rad_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(PlatformVelocityError::Config { name, value });
            }
        }
        let extrapolation_s = config.max_turn_extrapolation_s;
        if !(extrapolation_s.is_finite() && extrapolation_s >= 0.0) {
            return Err(PlatformVelocityError::Config {
                name: "max_turn_extrapolation_s",
                value: extrapolation_s,
            });
        }
        Ok(Self {
            config,
            filter: None,
            heading: None,
            measured_heading: false,
            turn: None,
        })
    }

    /// The estimate carried on to `time_s`: turned at the heading's rate of turn for the time
    /// since the last fix, at most `max_turn_extrapolation_s` (a straight-driving platform's
    /// is [`Self::velocity`]).
    pub fn velocity_at(&self, time_s: f64) -> Option<PlatformVelocity> {
        let estimate = self.velocity()?;
        let (Some(filter), Some(turn)) = (self.filter, self.turn) else {
            return Some(estimate);
        };
        let ahead_s = (time_s - filter.time_s).clamp(0.0, self.config.max_turn_extrapolation_s);
        let angle_rad = turn.rate_rad_s * ahead_s;
        let (sin, cos) = angle_rad.sin_cos();
        let v = estimate.velocity_ned_m_s;
        Some(PlatformVelocity {
            velocity_ned_m_s: Vector3::new(cos * v.x - sin * v.y, sin * v.x + cos * v.y, 0.0),
            heading_rad: {
                // Kept within ±π; untouched (to the bit) where it is already.
                let heading_rad = estimate.heading_rad + angle_rad;
                if heading_rad.abs() > PI {
                    heading_rad - TAU * heading_rad.signum()
                } else {
                    heading_rad
                }
            },
            ..estimate
        })
    }

    /// The current estimate; `None` until two fixes in a row have been taken and the velocity
    /// is known to `max_velocity_std_m_s`.
    pub fn velocity(&self) -> Option<PlatformVelocity> {
        let max_variance = self.config.max_velocity_std_m_s.powi(2);
        let filter = self
            .filter
            .filter(|f| f.fixes >= 2 && f.covariance[(1, 1)] <= max_variance)?;
        let velocity = Vector2::new(filter.state[(1, 0)], filter.state[(1, 1)]);
        let (velocity, heading) = match self.heading {
            // The tractor moves along its measured heading only.
            Some(h) if self.measured_heading => (h * velocity.dot(&h), h),
            Some(h) => (velocity, h),
            None => (
                velocity,
                velocity.try_normalize(1e-9).unwrap_or(Vector2::x()),
            ),
        };
        Some(PlatformVelocity {
            velocity_ned_m_s: Vector3::new(velocity.x, velocity.y, 0.0),
            speed_m_s: velocity.dot(&heading),
            heading_rad: heading.y.atan2(heading.x),
        })
    }

    /// The heading's rate of turn from its change since the previous fix, low-passed; none
    /// while the platform is too slow to have a heading of its own (a parked tractor does not
    /// turn).
    fn update_turn(&mut self, time_s: f64, heading_known: bool) {
        let heading = match self.heading {
            Some(heading) if heading_known => heading,
            _ => {
                self.turn = None;
                return;
            }
        };
        let rate_rad_s = match self.turn {
            Some(turn) if time_s > turn.time_s => {
                let dt_s = time_s - turn.time_s;
                let turned_rad = turn
                    .heading
                    .perp(&heading)
                    .atan2(turn.heading.dot(&heading));
                let blend = 1.0 - (-dt_s / self.config.turn_rate_tau_s).exp();
                // Each fix's own rate is mostly noise (its heading's wobble over a tenth of a
                // second): only the low-passed rate is bounded.
                let max_rad_s = self.config.max_turn_rate_rad_s;
                (turn.rate_rad_s + (turned_rad / dt_s - turn.rate_rad_s) * blend)
                    .clamp(-max_rad_s, max_rad_s)
            }
            Some(turn) => turn.rate_rad_s,
            None => 0.0,
        };
        self.turn = Some(Turn {
            time_s,
            heading,
            rate_rad_s,
        });
    }

    /// Takes a fix and returns the updated estimate.
    pub fn update(
        &mut self,
        fix: &PlatformFix,
    ) -> Result<Option<PlatformVelocity>, PlatformVelocityError> {
        let finite = fix.time_s.is_finite()
            && fix.uav_relative_ned_m.iter().all(|c| c.is_finite())
            && fix.uav_velocity_ned_m_s.iter().all(|c| c.is_finite())
            && fix.horizontal_variance_m2.is_finite()
            && fix.horizontal_variance_m2 > 0.0
            && fix.platform_yaw_rad.is_none_or(|y| y.is_finite());
        if !finite {
            return Err(PlatformVelocityError::NotFinite);
        }
        if let Some(filter) = &self.filter {
            if fix.time_s < filter.time_s {
                return Err(PlatformVelocityError::TimeBackwards {
                    time_s: fix.time_s,
                    last_s: filter.time_s,
                });
            }
        }
        // A measured yaw is used as is: it carries no lag.
        self.measured_heading = fix.platform_yaw_rad.is_some();
        if let Some(yaw) = fix.platform_yaw_rad {
            self.heading = Some(Vector2::new(yaw.cos(), yaw.sin()));
        }
        let relative_ne_m = fix.uav_relative_ned_m.xy();
        let uav_velocity_ne_m_s = fix.uav_velocity_ned_m_s.xy();
        let variance_m2 = fix.horizontal_variance_m2;
        let mut filter = match self.filter {
            Some(f) if fix.time_s - f.time_s <= self.config.max_gap_s => f,
            _ => {
                // platform = UAV − relative, in the frame that starts at the UAV.
                let position = -relative_ne_m;
                self.filter = Some(Filter {
                    time_s: fix.time_s,
                    state: Matrix2::new(position.x, position.y, 0.0, 0.0),
                    covariance: Matrix2::new(
                        variance_m2,
                        0.0,
                        0.0,
                        self.config.initial_velocity_std_m_s.powi(2),
                    ),
                    uav_displacement_ne_m: Vector2::zeros(),
                    uav_velocity_ne_m_s,
                    fixes: 1,
                });
                self.turn = None;
                return Ok(self.velocity());
            }
        };
        let dt_s = fix.time_s - filter.time_s;
        let transition = Matrix2::new(1.0, dt_s, 0.0, 1.0);
        let q = self.config.acceleration_noise_m2_per_s3;
        let process = Matrix2::new(
            dt_s.powi(3) / 3.0,
            dt_s.powi(2) / 2.0,
            dt_s.powi(2) / 2.0,
            dt_s,
        ) * q;
        filter.state = transition * filter.state;
        filter.covariance = transition * filter.covariance * transition.transpose() + process;
        filter.uav_displacement_ne_m +=
            (filter.uav_velocity_ne_m_s + uav_velocity_ne_m_s) * 0.5 * dt_s;
        filter.uav_velocity_ne_m_s = uav_velocity_ne_m_s;
        let measured = filter.uav_displacement_ne_m - relative_ne_m;
        let innovation = RowVector2::new(measured.x, measured.y) - filter.state.row(0);
        let gain = filter.covariance.column(0) / (filter.covariance[(0, 0)] + variance_m2);
        filter.state += gain * innovation;
        filter.covariance -= gain * filter.covariance.row(0);
        filter.time_s = fix.time_s;
        filter.fixes += 1;
        let velocity = Vector2::new(filter.state[(1, 0)], filter.state[(1, 1)]);
        let moving = velocity.norm() >= self.config.min_speed_for_heading_m_s;
        if fix.platform_yaw_rad.is_none() && moving {
            self.heading = Some(velocity.normalize());
        }
        self.filter = Some(filter);
        self.update_turn(fix.time_s, moving || self.measured_heading);
        Ok(self.velocity())
    }
}

#[cfg(test)]
mod tests;
