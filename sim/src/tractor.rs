//! The tractor carrying the landing pad: a unicycle (heading, speed) with turn-rate and
//! acceleration limits that follows one of seed 000's scripted paths (§3.1: straight, S-shape,
//! rectangle, circle, figure-of-eight, 90° and 180° turns) by pure pursuit on a dense polyline.
//!
//! Conventions: world NED, metres; NE positions are `Vector2(north, east)`; heading and pad yaw
//! from north towards east. Every path starts at its start point heading along the start heading.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::fmt;
use std::str::FromStr;

use algorithms::vision::render::SplitMix64;
use nalgebra::{Rotation2, Vector2, Vector3};
use thiserror::Error;

use crate::realism::{DriverBehaviour, GaussMarkov, PadMotion};

/// Polyline spacing: dense against the lookahead so the pursuit point moves smoothly.
const PATH_SPACING_M: f64 = 0.25;
/// Turn paths: the straight run before the turn and the turn's radius.
const TURN_APPROACH_M: f64 = 30.0;
const TURN_RADIUS_M: f64 = 8.0;
const RECTANGLE_LENGTH_M: f64 = 40.0;
const RECTANGLE_WIDTH_M: f64 = 20.0;
const CIRCLE_RADIUS_M: f64 = 15.0;
/// Lemniscate of Gerono x = a·sin t, y = (b/2)·sin 2t: lobes 2a long, b wide.
const FIGURE8_HALF_LENGTH_M: f64 = 25.0;
const FIGURE8_WIDTH_M: f64 = 15.0;
/// S-shape weave y = A·(1 − cos(2πx/λ)), repeated long enough for a long mission.
const S_AMPLITUDE_M: f64 = 5.0;
const S_WAVELENGTH_M: f64 = 40.0;
const S_PERIODS: usize = 40;

/// The scripted paths.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PathKind {
    Straight,
    SShape,
    Rectangle,
    Circle,
    FigureEight,
    Turn90,
    Turn180,
}

impl PathKind {
    pub const ALL: [PathKind; 7] = [
        PathKind::Straight,
        PathKind::SShape,
        PathKind::Rectangle,
        PathKind::Circle,
        PathKind::FigureEight,
        PathKind::Turn90,
        PathKind::Turn180,
    ];

    pub fn name(self) -> &'static str {
        match self {
            PathKind::Straight => "straight",
            PathKind::SShape => "s-shape",
            PathKind::Rectangle => "rectangle",
            PathKind::Circle => "circle",
            PathKind::FigureEight => "figure8",
            PathKind::Turn90 => "turn90",
            PathKind::Turn180 => "turn180",
        }
    }

    /// How far the tractor drives before the path first turns: `Some(0)` for paths that
    /// curve from their start (S, circle, figure-eight), `None` for the straight line.
    pub fn first_turn_m(self) -> Option<f64> {
        match self {
            PathKind::Straight => None,
            PathKind::SShape | PathKind::Circle | PathKind::FigureEight => Some(0.0),
            PathKind::Rectangle => Some(RECTANGLE_LENGTH_M / 2.0),
            PathKind::Turn90 | PathKind::Turn180 => Some(TURN_APPROACH_M),
        }
    }

    /// Closed paths repeat lap after lap; open ones continue straight past their end.
    pub fn is_closed(self) -> bool {
        matches!(
            self,
            PathKind::Rectangle | PathKind::Circle | PathKind::FigureEight
        )
    }
}

impl fmt::Display for PathKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A path name that is none of the known ones.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("unknown tractor path `{given}`; valid paths: straight, s-shape, rectangle, circle, figure8, turn90, turn180")]
pub struct UnknownPathKind {
    pub given: String,
}

impl FromStr for PathKind {
    type Err = UnknownPathKind;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        PathKind::ALL
            .into_iter()
            .find(|kind| kind.name() == s)
            .ok_or_else(|| UnknownPathKind {
                given: s.to_string(),
            })
    }
}

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

/// A polyline in world NE with its cumulative arc length.
#[derive(Debug, Clone, PartialEq)]
struct Polyline {
    points: Vec<Vector2<f64>>,
    /// Arc length at each point; for a closed path the last point equals the first.
    cumulative_m: Vec<f64>,
    closed: bool,
}

impl Polyline {
    fn new(points: Vec<Vector2<f64>>, closed: bool) -> Self {
        let mut points = points;
        if closed && points.first() != points.last() {
            points.push(points[0]);
        }
        let mut cumulative_m = Vec::with_capacity(points.len());
        let mut total = 0.0;
        for (i, p) in points.iter().enumerate() {
            if i > 0 {
                total += (p - points[i - 1]).norm();
            }
            cumulative_m.push(total);
        }
        Self {
            points,
            cumulative_m,
            closed,
        }
    }

    fn length_m(&self) -> f64 {
        self.cumulative_m.last().copied().unwrap_or(0.0)
    }

    fn segments(&self) -> usize {
        self.points.len().saturating_sub(1)
    }

    /// Start point, end point and start arc length of unrolled segment `j` (closed paths repeat
    /// their segments lap after lap; open paths extend their last segment).
    fn segment(&self, j: i64) -> Option<(Vector2<f64>, Vector2<f64>, f64)> {
        let n = self.segments() as i64;
        if n == 0 || j < 0 {
            return None;
        }
        let (lap, i) = if self.closed {
            (j / n, (j % n) as usize)
        } else if j < n {
            (0, j as usize)
        } else {
            return None;
        };
        let offset = lap as f64 * self.length_m();
        Some((
            self.points[i],
            self.points[i + 1],
            offset + self.cumulative_m[i],
        ))
    }

    /// The point at arc length `s_m`; past an open path's end it continues straight on.
    fn point_at(&self, s_m: f64) -> Vector2<f64> {
        let length = self.length_m();
        let n = self.segments();
        if n == 0 || length <= 0.0 {
            return self.points.first().copied().unwrap_or_else(Vector2::zeros);
        }
        let s = if self.closed {
            s_m.rem_euclid(length)
        } else {
            s_m.max(0.0)
        };
        if !self.closed && s >= length {
            let (a, b) = (self.points[n - 1], self.points[n]);
            let dir = (b - a).try_normalize(1e-12).unwrap_or_else(Vector2::x);
            return b + dir * (s - length);
        }
        let i = match self
            .cumulative_m
            .binary_search_by(|c| c.partial_cmp(&s).unwrap_or(std::cmp::Ordering::Less))
        {
            Ok(i) => i.min(n - 1),
            Err(i) => i.saturating_sub(1).min(n - 1),
        };
        let (a, b) = (self.points[i], self.points[i + 1]);
        let seg = self.cumulative_m[i + 1] - self.cumulative_m[i];
        if seg <= 0.0 {
            return a;
        }
        a + (b - a) * ((s - self.cumulative_m[i]) / seg)
    }

    /// Arc length of the closest point within [s_lo, s_hi] (unrolled), past the end of an open
    /// path included. The window keeps the projection from jumping across a self-crossing.
    fn project(&self, point: Vector2<f64>, s_lo: f64, s_hi: f64) -> f64 {
        let mut best = (f64::INFINITY, s_lo.max(0.0));
        let n = self.segments() as i64;
        let length = self.length_m();
        if n == 0 || length <= 0.0 {
            return 0.0;
        }
        let mut consider = |a: Vector2<f64>, b: Vector2<f64>, s_a: f64, unbounded: bool| {
            let ab = b - a;
            let len2 = ab.norm_squared();
            let mut t = if len2 > 0.0 {
                (point - a).dot(&ab) / len2
            } else {
                0.0
            };
            t = if unbounded {
                t.max(0.0)
            } else {
                t.clamp(0.0, 1.0)
            };
            let s = s_a + t * len2.sqrt();
            if s < s_lo || s > s_hi {
                return;
            }
            let d = (a + ab * t - point).norm_squared();
            if d < best.0 {
                best = (d, s);
            }
        };
        // Segment index of s_lo, walking forward until past s_hi.
        let lap = if self.closed {
            (s_lo.max(0.0) / length).floor()
        } else {
            0.0
        };
        let within_lap = s_lo.max(0.0) - lap * length;
        let index = self
            .cumulative_m
            .partition_point(|c| *c <= within_lap)
            .saturating_sub(1) as i64;
        let first = lap as i64 * n + index.min(n - 1);
        let mut j = first;
        while let Some((a, b, s_a)) = self.segment(j) {
            if s_a > s_hi {
                break;
            }
            let s_b = s_a + (b - a).norm();
            let last_open = !self.closed && j == n - 1;
            if s_b >= s_lo || last_open {
                consider(a, b, s_a, last_open);
            }
            j += 1;
        }
        if best.0.is_finite() {
            best.1
        } else {
            s_lo.max(0.0)
        }
    }
}

/// The path's shape in its own frame: starts at the origin heading along +x (north).
fn local_path(kind: PathKind) -> Vec<Vector2<f64>> {
    let arc = |centre: Vector2<f64>, radius: f64, from: f64, to: f64| {
        let steps = ((to - from).abs() * radius / PATH_SPACING_M)
            .ceil()
            .max(1.0) as usize;
        (1..=steps)
            .map(move |i| {
                let a = from + (to - from) * i as f64 / steps as f64;
                centre + Vector2::new(a.cos(), a.sin()) * radius
            })
            .collect::<Vec<_>>()
    };
    let line = |from: Vector2<f64>, to: Vector2<f64>| {
        let steps = ((to - from).norm() / PATH_SPACING_M).ceil().max(1.0) as usize;
        (1..=steps)
            .map(move |i| from + (to - from) * (i as f64 / steps as f64))
            .collect::<Vec<_>>()
    };
    let origin = Vector2::zeros();
    match kind {
        PathKind::Straight => line(origin, Vector2::new(100.0, 0.0)),
        PathKind::SShape => {
            let total = S_WAVELENGTH_M * S_PERIODS as f64;
            let steps = (total / PATH_SPACING_M).ceil() as usize;
            (0..=steps)
                .map(|i| {
                    let x = total * i as f64 / steps as f64;
                    Vector2::new(x, S_AMPLITUDE_M * (1.0 - (TAU * x / S_WAVELENGTH_M).cos()))
                })
                .collect()
        }
        PathKind::Rectangle => {
            // Start in the middle of the west side heading north, right turns (clockwise).
            let half = RECTANGLE_LENGTH_M / 2.0;
            let corners = [
                Vector2::new(half, 0.0),
                Vector2::new(half, RECTANGLE_WIDTH_M),
                Vector2::new(-half, RECTANGLE_WIDTH_M),
                Vector2::new(-half, 0.0),
                origin,
            ];
            let mut points = vec![origin];
            let mut from = origin;
            for corner in corners {
                points.extend(line(from, corner));
                from = corner;
            }
            points
        }
        PathKind::Circle => {
            // Centre to the right: a clockwise circle through the origin.
            let centre = Vector2::new(0.0, CIRCLE_RADIUS_M);
            let mut points = vec![origin];
            points.extend(arc(centre, CIRCLE_RADIUS_M, -FRAC_PI_2, -FRAC_PI_2 + TAU));
            points
        }
        PathKind::FigureEight => {
            let (a, b) = (FIGURE8_HALF_LENGTH_M, FIGURE8_WIDTH_M);
            // Rotate so the tangent at the start, (a, b), points north.
            let rotation = Rotation2::new(-b.atan2(a));
            let length_estimate = 4.0 * a + 2.0 * b;
            let steps = (2.0 * length_estimate / PATH_SPACING_M).ceil() as usize;
            (0..=steps)
                .map(|i| {
                    let t = TAU * i as f64 / steps as f64;
                    rotation * Vector2::new(a * t.sin(), 0.5 * b * (2.0 * t).sin())
                })
                .collect()
        }
        PathKind::Turn90 | PathKind::Turn180 => {
            let angle = if kind == PathKind::Turn90 {
                FRAC_PI_2
            } else {
                PI
            };
            let start_turn = Vector2::new(TURN_APPROACH_M, 0.0);
            let mut points = vec![origin];
            points.extend(line(origin, start_turn));
            // A right turn around a centre to the east of the turn's start.
            let centre = start_turn + Vector2::new(0.0, TURN_RADIUS_M);
            points.extend(arc(centre, TURN_RADIUS_M, -FRAC_PI_2, -FRAC_PI_2 + angle));
            let end = *points.last().unwrap_or(&start_turn);
            let direction = Vector2::new(angle.cos(), angle.sin());
            points.extend(line(end, end + direction * 10.0));
            points
        }
    }
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
