//! The tractor carrying the landing pad: a unicycle (heading, speed) with turn-rate and
//! acceleration limits that follows one of seed 000's scripted paths (§3.1: straight, S-shape,
//! rectangle, circle, figure-of-eight, 90° and 180° turns) by pure pursuit on a dense polyline.
//!
//! Conventions: world NED, metres; NE positions are `Vector2(north, east)`; heading and pad yaw
//! from north towards east. Every path starts at its start point heading along the start heading.

use std::f64::consts::{PI, TAU};

use algorithms::vision::render::SplitMix64;
use nalgebra::{Rotation2, Vector2, Vector3};
use thiserror::Error;

use crate::realism::{DriverBehaviour, GaussMarkov, PadMotion};

mod path;
use path::{local_path, Polyline};
pub use path::{PathKind, UnknownPathKind};

/// A tractor configuration or step input that cannot be used.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TractorError {
    #[error("tractor {name} = {value} must be a finite number > 0")]
    NotPositive { name: &'static str, value: f64 },
    #[error("tractor {name} = {value} must be a finite number ≥ 0")]
    Negative { name: &'static str, value: f64 },
    #[error("tractor {name} must be finite")]
    NonFinite { name: &'static str },
}

/// The tractor's limits and its pad.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TractorParams {
    /// Cruise speed; the tractor slows below it only where a corner needs more than its turn rate.
    pub speed_m_s: f64,
    pub max_turn_rate_rad_s: f64,
    pub max_accel_m_s2: f64,
    /// Height of the pad's top above the ground.
    pub pad_height_m: f64,
    /// Side of the square pad.
    pub pad_size_m: f64,
    /// Pure pursuit's lookahead distance along the path.
    pub lookahead_m: f64,
}

impl Default for TractorParams {
    fn default() -> Self {
        Self {
            speed_m_s: 1.5,
            max_turn_rate_rad_s: 0.5,
            max_accel_m_s2: 0.5,
            pad_height_m: 1.0,
            pad_size_m: 1.0,
            lookahead_m: 4.0,
        }
    }
}

impl TractorParams {
    pub fn validate(&self) -> Result<(), TractorError> {
        for (name, value) in [
            ("max_turn_rate_rad_s", self.max_turn_rate_rad_s),
            ("max_accel_m_s2", self.max_accel_m_s2),
            ("pad_size_m", self.pad_size_m),
            ("lookahead_m", self.lookahead_m),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(TractorError::NotPositive { name, value });
            }
        }
        for (name, value) in [
            ("speed_m_s", self.speed_m_s),
            ("pad_height_m", self.pad_height_m),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(TractorError::Negative { name, value });
            }
        }
        Ok(())
    }
}

/// The pad on the tractor's roof, as the vehicle model needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadState {
    /// Centre of the pad's top surface, NED; its down coordinate is −(pad top height).
    pub centre_ned_m: Vector3<f64>,
    /// The pad's x axis (the tractor's heading), from north towards east.
    pub yaw_rad: f64,
    pub velocity_ned_m_s: Vector3<f64>,
    /// Half the side of the square pad.
    pub half_size_m: f64,
}

impl PadState {
    /// A world NE point in the pad frame (x along the pad's yaw, y to its right).
    pub fn to_pad_frame(&self, point_ne_m: Vector2<f64>) -> Vector2<f64> {
        Rotation2::new(-self.yaw_rad) * (point_ne_m - self.centre_ned_m.xy())
    }

    /// A pad-frame point in world NE.
    pub fn from_pad_frame(&self, point_pad_m: Vector2<f64>) -> Vector2<f64> {
        self.centre_ned_m.xy() + Rotation2::new(self.yaw_rad) * point_pad_m
    }

    /// Whether a world NE point lies over the pad's square.
    pub fn contains_ne(&self, point_ne_m: Vector2<f64>) -> bool {
        let p = self.to_pad_frame(point_ne_m);
        p.x.abs() <= self.half_size_m && p.y.abs() <= self.half_size_m
    }

    pub fn is_finite(&self) -> bool {
        self.centre_ned_m.iter().all(|v| v.is_finite())
            && self.velocity_ned_m_s.iter().all(|v| v.is_finite())
            && self.yaw_rad.is_finite()
            && self.half_size_m.is_finite()
    }
}

/// The tractor's pose and motion at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TractorPose {
    pub position_ne_m: Vector2<f64>,
    pub heading_rad: f64,
    pub speed_m_s: f64,
    pub velocity_ne_m_s: Vector2<f64>,
    pub yaw_rate_rad_s: f64,
}

fn wrap_angle(angle_rad: f64) -> f64 {
    (angle_rad + PI).rem_euclid(TAU) - PI
}

/// The tractor driving its path.
#[derive(Debug, Clone, PartialEq)]
pub struct Tractor {
    kind: PathKind,
    params: TractorParams,
    path: Polyline,
    position_ne_m: Vector2<f64>,
    heading_rad: f64,
    speed_m_s: f64,
    yaw_rate_rad_s: f64,
    /// Arc length of the closest path point, unrolled over laps.
    progress_m: f64,
    distance_driven_m: f64,
    /// A person at the wheel; `None`: the path at cruise speed exactly.
    driver: Option<Driver>,
    /// The field's roughness rocks the pad; `None`: a pad that stays level.
    rough_field: Option<RoughField>,
}

/// The driver's state: how far off the cruise speed and off the path they are now.
#[derive(Debug, Clone, PartialEq)]
struct Driver {
    rng: SplitMix64,
    speed_fraction: GaussMarkov,
    wander_m: GaussMarkov,
}

/// The pad's rocking as a function of the distance driven (bumps are where they are on the
/// field, so a stopped tractor stands still): two incommensurate waves per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
struct RoughField {
    motion: PadMotion,
    /// Wavelengths (m) and phases (rad) of roll, pitch and heave.
    waves: [[(f64, f64); 2]; 3],
}

impl RoughField {
    /// Roll, pitch and heave (rad, rad, m) after `distance_m`, and their rates per metre.
    fn at(&self, distance_m: f64) -> ([f64; 3], [f64; 3]) {
        let mut value = [0.0; 3];
        let mut per_m = [0.0; 3];
        let amplitude = [
            self.motion.tilt_rad,
            self.motion.tilt_rad,
            self.motion.heave_m,
        ];
        for axis in 0..3 {
            for (weight, (wavelength_m, phase)) in [0.6, 0.4].into_iter().zip(self.waves[axis]) {
                let k = TAU / wavelength_m;
                value[axis] += amplitude[axis] * weight * (k * distance_m + phase).sin();
                per_m[axis] += amplitude[axis] * weight * k * (k * distance_m + phase).cos();
            }
        }
        (value, per_m)
    }
}

impl Tractor {
    /// A tractor at `start_ne_m` heading `start_heading_rad`, already driving at its cruise
    /// speed (a tractor at field work drives steadily), with the path laid out from there.
    pub fn new(
        kind: PathKind,
        params: TractorParams,
        start_ne_m: [f64; 2],
        start_heading_rad: f64,
    ) -> Result<Self, TractorError> {
        params.validate()?;
        if !start_ne_m.iter().all(|v| v.is_finite()) {
            return Err(TractorError::NonFinite { name: "start_ne_m" });
        }
        if !start_heading_rad.is_finite() {
            return Err(TractorError::NonFinite {
                name: "start_heading_rad",
            });
        }
        let start = Vector2::new(start_ne_m[0], start_ne_m[1]);
        let rotation = Rotation2::new(start_heading_rad);
        let points = local_path(kind)
            .into_iter()
            .map(|p| start + rotation * p)
            .collect();
        Ok(Self {
            kind,
            params,
            path: Polyline::new(points, kind.is_closed()),
            position_ne_m: start,
            heading_rad: wrap_angle(start_heading_rad),
            speed_m_s: params.speed_m_s,
            yaw_rate_rad_s: 0.0,
            progress_m: 0.0,
            distance_driven_m: 0.0,
            driver: None,
            rough_field: None,
        })
    }

    /// A person drives: the speed wanders around the cruise speed and the line around the path
    /// as [`DriverBehaviour`] says, reproducibly for `seed`.
    pub fn with_driver(mut self, behaviour: DriverBehaviour, seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x6472_6976_6572);
        let speed_fraction = GaussMarkov::new(
            behaviour.speed_variation,
            behaviour.speed_tau_s,
            rng.next_gaussian(),
        );
        let wander_m = GaussMarkov::new(
            behaviour.wander_m,
            behaviour.wander_tau_s,
            rng.next_gaussian(),
        );
        self.driver = Some(Driver {
            rng,
            speed_fraction,
            wander_m,
        });
        self
    }

    /// The field rocks the pad as [`PadMotion`] says, reproducibly for `seed`.
    pub fn with_rough_field(mut self, motion: PadMotion, seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x0066_6965_6c64);
        // One period's travel at cruise speed is the main wavelength; the second wave is
        // 0.6–1.6 of it, so the rocking never repeats exactly.
        let main_m = (motion.tilt_period_s * self.params.speed_m_s).max(0.5);
        let mut waves = [[(1.0, 0.0); 2]; 3];
        for axis in &mut waves {
            axis[0] = (main_m, TAU * rng.next_f64());
            let ratio = 0.6 + rng.next_f64();
            axis[1] = (main_m * ratio, TAU * rng.next_f64());
        }
        self.rough_field = Some(RoughField { motion, waves });
        self
    }

    pub fn kind(&self) -> PathKind {
        self.kind
    }

    pub fn params(&self) -> &TractorParams {
        &self.params
    }

    /// Length of one lap of a closed path; `None` for open paths.
    pub fn lap_length_m(&self) -> Option<f64> {
        self.path.closed.then(|| self.path.length_m())
    }

    /// The same tractor parked: it pulls away within its acceleration limit once stepped (a
    /// tractor waiting for the drone at the meeting point).
    pub fn parked(mut self) -> Self {
        self.speed_m_s = 0.0;
        self
    }

    /// Distance driven since the start.
    pub fn distance_driven_m(&self) -> f64 {
        self.distance_driven_m
    }

    /// Advances by `dt_s`: pure pursuit gives the curvature; the speed drops where that curvature
    /// needs more than the turn-rate limit, within the acceleration limit.
    pub fn step(&mut self, dt_s: f64) -> Result<(), TractorError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(TractorError::NotPositive {
                name: "dt_s",
                value: dt_s,
            });
        }
        let p = &self.params;
        let lookahead = p.lookahead_m;
        self.progress_m = self.path.project(
            self.position_ne_m,
            self.progress_m - 1.0,
            self.progress_m + lookahead + 2.0 * self.speed_m_s.max(p.speed_m_s) * dt_s + 1.0,
        );
        let mut target = self.path.point_at(self.progress_m + lookahead);
        let mut cruise_m_s = p.speed_m_s;
        if let Some(driver) = &mut self.driver {
            let fraction = driver.speed_fraction.step(dt_s, driver.rng.next_gaussian());
            // A driver eases off or picks up, but keeps driving.
            cruise_m_s *= 1.0 + fraction.clamp(-0.6, 0.6);
            let wander_m = driver.wander_m.step(dt_s, driver.rng.next_gaussian());
            // Aim off the path to the side by the wander: the line drifts, the path stays.
            let ahead = self.path.point_at(self.progress_m + lookahead + 0.5) - target;
            if let Some(along) = ahead.try_normalize(1e-9) {
                target += Vector2::new(-along.y, along.x) * wander_m;
            }
        }
        let to_target = target - self.position_ne_m;
        let distance = to_target.norm().max(1e-6);
        let alpha = wrap_angle(to_target.y.atan2(to_target.x) - self.heading_rad);
        let curvature_per_m = 2.0 * alpha.sin() / distance;

        let cornering_speed = if curvature_per_m.abs() > 1e-9 {
            p.max_turn_rate_rad_s / curvature_per_m.abs()
        } else {
            f64::INFINITY
        };
        let wanted_speed = cruise_m_s.min(cornering_speed);
        let max_change = p.max_accel_m_s2 * dt_s;
        let speed = self.speed_m_s + (wanted_speed - self.speed_m_s).clamp(-max_change, max_change);
        let yaw_rate =
            (speed * curvature_per_m).clamp(-p.max_turn_rate_rad_s, p.max_turn_rate_rad_s);

        // Midpoint heading: exact for straight lines, second order on arcs.
        let mid_heading = self.heading_rad + 0.5 * yaw_rate * dt_s;
        self.position_ne_m += Vector2::new(mid_heading.cos(), mid_heading.sin()) * (speed * dt_s);
        self.heading_rad = wrap_angle(self.heading_rad + yaw_rate * dt_s);
        self.speed_m_s = speed;
        self.yaw_rate_rad_s = yaw_rate;
        self.distance_driven_m += speed * dt_s;
        Ok(())
    }

    pub fn pose(&self) -> TractorPose {
        TractorPose {
            position_ne_m: self.position_ne_m,
            heading_rad: self.heading_rad,
            speed_m_s: self.speed_m_s,
            velocity_ne_m_s: Vector2::new(self.heading_rad.cos(), self.heading_rad.sin())
                * self.speed_m_s,
            yaw_rate_rad_s: self.yaw_rate_rad_s,
        }
    }

    /// The pad's top. On a rough field the roof rolls and pitches about the axles: the pad's
    /// centre sways by the roof's height times the tilt and heaves; the pad itself is drawn
    /// level (2° of tilt foreshortens the marker by 0.06 %, the sway moves it centimetres).
    pub fn pad(&self) -> PadState {
        let pose = self.pose();
        let mut centre_ned_m = Vector3::new(
            pose.position_ne_m.x,
            pose.position_ne_m.y,
            -self.params.pad_height_m,
        );
        let mut velocity_ned_m_s =
            Vector3::new(pose.velocity_ne_m_s.x, pose.velocity_ne_m_s.y, 0.0);
        if let Some(field) = &self.rough_field {
            let ([roll, pitch, heave], [roll_per_m, pitch_per_m, heave_per_m]) =
                field.at(self.distance_driven_m);
            let height_m = self.params.pad_height_m;
            // Pitching nose-down moves the roof forward; rolling right moves it right.
            let sway_pad_m = Vector2::new(height_m * pitch.sin(), height_m * roll.sin());
            let sway_rate_pad_m_s = Vector2::new(
                height_m * pitch.cos() * pitch_per_m,
                height_m * roll.cos() * roll_per_m,
            ) * pose.speed_m_s;
            let rotation = Rotation2::new(pose.heading_rad);
            let sway_ne_m = rotation * sway_pad_m;
            let sway_rate_ne_m_s = rotation * sway_rate_pad_m_s;
            centre_ned_m += Vector3::new(sway_ne_m.x, sway_ne_m.y, -heave);
            velocity_ned_m_s += Vector3::new(
                sway_rate_ne_m_s.x,
                sway_rate_ne_m_s.y,
                -heave_per_m * pose.speed_m_s,
            );
        }
        PadState {
            centre_ned_m,
            yaw_rad: pose.heading_rad,
            velocity_ned_m_s,
            half_size_m: 0.5 * self.params.pad_size_m,
        }
    }
}

#[cfg(test)]
mod tests;
