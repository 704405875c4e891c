//! The tractor's scripted paths (seed 000, §3.1) and the dense polyline it pursues along them.
//!
//! Each path's shape is laid out in its own frame, starting at the origin heading north (+x);
//! the tractor places it at its start point and heading.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::fmt;
use std::str::FromStr;

use nalgebra::{Rotation2, Vector2};
use thiserror::Error;

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

/// A polyline in world NE with its cumulative arc length.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Polyline {
    points: Vec<Vector2<f64>>,
    /// Arc length at each point; for a closed path the last point equals the first.
    cumulative_m: Vec<f64>,
    pub(super) closed: bool,
}

impl Polyline {
    pub(super) fn new(points: Vec<Vector2<f64>>, closed: bool) -> Self {
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

    pub(super) fn length_m(&self) -> f64 {
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
    pub(super) fn point_at(&self, s_m: f64) -> Vector2<f64> {
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
    pub(super) fn project(&self, point: Vector2<f64>, s_lo: f64, s_hi: f64) -> f64 {
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
pub(super) fn local_path(kind: PathKind) -> Vec<Vector2<f64>> {
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
