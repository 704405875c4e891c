//! The hazards on the field: their classes and shapes, and where they are scattered (over the
//! field, or beside the tractor's track).

use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;

use algorithms::vision::render::{Patch, SplitMix64, Texture};

use super::SceneError;

/// What a hazard is; the hazard CNN is trained on these classes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum HazardClass {
    Person,
    Animal,
    Vehicle,
}

impl HazardClass {
    pub const ALL: [HazardClass; 3] = [Self::Person, Self::Animal, Self::Vehicle];

    pub fn name(self) -> &'static str {
        match self {
            Self::Person => "person",
            Self::Animal => "animal",
            Self::Vehicle => "vehicle",
        }
    }

    /// (length along the heading, width across it), metres: the hazard's bounding rectangle.
    pub fn size_m(self) -> (f64, f64) {
        match self {
            // Shoulders are wider than a body is deep, seen from above.
            Self::Person => (0.4, 0.5),
            Self::Animal => (1.2, 0.6),
            Self::Vehicle => (4.0, 2.0),
        }
    }

    /// Area of the visible shape (not its bounding rectangle), m².
    pub fn shape_area_m2(self) -> f64 {
        let (length_m, width_m) = self.size_m();
        match self {
            Self::Person | Self::Animal => PI * length_m * width_m / 4.0,
            Self::Vehicle => length_m * width_m,
        }
    }

    /// Radius of the circle around the bounding rectangle, metres.
    pub fn bounding_radius_m(self) -> f64 {
        let (length_m, width_m) = self.size_m();
        0.5 * length_m.hypot(width_m)
    }

    /// Intensity in [0, 1] at patch coordinates (u across, v along, both in [−1, 1]; v = −1 is the
    /// front), or `None` outside the shape. Each class has its own shape and shading, so a
    /// classifier can tell them apart, and none looks like the white pad or the field's soil.
    fn shade(self, u: f64, v: f64) -> Option<f32> {
        match self {
            Self::Person => {
                // Dark clothing (shoulders), the lighter head in the middle.
                let r2 = u * u + v * v;
                (r2 <= 1.0).then_some(if r2 < 0.16 { 0.62 } else { 0.08 })
            }
            Self::Animal => {
                // A mid-grey back, a little darker along the spine and at the head (front).
                if u * u + v * v > 1.0 {
                    return None;
                }
                let spine = (1.0 - (u.abs() / 0.25).min(1.0)) as f32;
                let head = if v < -0.7 { 0.12 } else { 0.0 };
                Some(0.5 - 0.1 * spine - head)
            }
            Self::Vehicle => {
                // Bright paint with a dark windshield stripe across the front third.
                let windshield = (-0.55..=-0.3).contains(&v) && u.abs() <= 0.85;
                Some(if windshield { 0.12 } else { 0.92 })
            }
        }
    }
}

impl fmt::Display for HazardClass {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for HazardClass {
    type Err = SceneError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| SceneError::UnknownHazardClass(s.to_string()))
    }
}

/// One hazard on the ground.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hazard {
    pub class: HazardClass,
    pub north_m: f64,
    pub east_m: f64,
    /// Heading of the hazard's long axis, from north towards east.
    pub yaw_rad: f64,
    /// Unique within its field.
    pub id: u32,
}

impl Hazard {
    /// The hazard as a ground patch; `field` is the background texture seen outside its shape.
    pub fn patch(&self, field: &Texture) -> Patch {
        let (length_m, width_m) = self.class.size_m();
        // A patch's top faces its yaw, u to its right: width across, length along.
        let patch = Patch::new(
            self.north_m,
            self.east_m,
            self.yaw_rad,
            width_m,
            length_m,
            Texture::uniform(0.0),
        );
        let centre = patch.point_world(0.0, 0.0);
        let du = patch.point_world(1.0, 0.0) - centre;
        let dv = patch.point_world(0.0, 1.0) - centre;
        let (class, field) = (self.class, field.clone());
        let texture = Texture::from_fn(move |u, v| match class.shade(u, v) {
            Some(intensity) => intensity,
            None => field.sample(
                centre.x + u * du.x + v * dv.x,
                centre.y + u * du.y + v * dv.y,
            ),
        });
        Patch { texture, ..patch }
    }
}

/// Where and how many hazards to scatter.
#[derive(Debug, Clone, PartialEq)]
pub struct ScatterConfig {
    /// [min, max] north, metres.
    pub north_m: [f64; 2],
    /// [min, max] east, metres.
    pub east_m: [f64; 2],
    /// How many of each class, in the order of [`HazardClass::ALL`].
    pub count_per_class: [usize; 3],
    /// A path kept clear of hazards (the tractor's track, the approach): NED (north, east) points
    /// joined by straight segments; one point keeps a disc clear.
    pub keep_out_path_ne_m: Vec<[f64; 2]>,
    /// How far from the path a hazard's bounding circle must stay, metres.
    pub keep_out_radius_m: f64,
    /// Least gap between two hazards' bounding circles, metres.
    pub min_gap_m: f64,
}

impl Default for ScatterConfig {
    fn default() -> Self {
        Self {
            north_m: [-60.0, 60.0],
            east_m: [-60.0, 60.0],
            count_per_class: [6, 4, 2],
            keep_out_path_ne_m: Vec::new(),
            keep_out_radius_m: 4.0,
            min_gap_m: 0.5,
        }
    }
}

/// The hazards of one field.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HazardField {
    pub hazards: Vec<Hazard>,
}

impl HazardField {
    /// Scatters hazards uniformly over the area, with random headings, none overlapping another
    /// or the keep-out path. The same seed and config give the same field.
    pub fn scatter(seed: u64, config: &ScatterConfig) -> Result<Self, SceneError> {
        let [n0, n1] = config.north_m;
        let [e0, e1] = config.east_m;
        if !([n0, n1, e0, e1].iter().all(|x| x.is_finite()) && n0 < n1 && e0 < e1) {
            return Err(SceneError::Area {
                north_m: config.north_m,
                east_m: config.east_m,
            });
        }
        for (name, value) in [
            ("keep_out_radius_m", config.keep_out_radius_m),
            ("min_gap_m", config.min_gap_m),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SceneError::Setting { name, value });
            }
        }
        if let Some(bad) = config
            .keep_out_path_ne_m
            .iter()
            .flatten()
            .find(|x| !x.is_finite())
        {
            return Err(SceneError::Setting {
                name: "keep_out_path_ne_m",
                value: *bad,
            });
        }
        let rng = SplitMix64::new(seed ^ 0x6861_7a61_7264);
        let hazards = place_clear(
            config.count_per_class,
            config.min_gap_m,
            rng,
            |class, rng| {
                let north_m = n0 + (n1 - n0) * rng.next_f64();
                let east_m = e0 + (e1 - e0) * rng.next_f64();
                let clear_of_path = distance_to_path_m(&config.keep_out_path_ne_m, north_m, east_m)
                    >= class.bounding_radius_m() + config.keep_out_radius_m;
                clear_of_path.then_some((north_m, east_m, None))
            },
        )?;
        Ok(Self { hazards })
    }
}

/// Places `count_per_class` hazards, the largest class first (big objects are the hardest to
/// fit once the field fills up). Each takes the first of up to 2000 spots drawn by
/// `candidate` (north, east and a fixed yaw, or `None` for a spot it rejects) that keeps
/// `min_gap_m` between its bounding circle and every hazard placed before; a spot without a
/// fixed yaw faces anywhere.
fn place_clear(
    count_per_class: [usize; 3],
    min_gap_m: f64,
    mut rng: SplitMix64,
    mut candidate: impl FnMut(HazardClass, &mut SplitMix64) -> Option<(f64, f64, Option<f64>)>,
) -> Result<Vec<Hazard>, SceneError> {
    let mut hazards: Vec<Hazard> = Vec::new();
    for class in HazardClass::ALL.into_iter().rev() {
        let wanted = count_per_class[class as usize];
        let radius_m = class.bounding_radius_m();
        for placed in 0..wanted {
            let clear_of_others = |north_m: f64, east_m: f64| {
                hazards.iter().all(|h| {
                    let gap = (h.north_m - north_m).hypot(h.east_m - east_m);
                    gap >= radius_m + h.class.bounding_radius_m() + min_gap_m
                })
            };
            let spot = (0..2000)
                .filter_map(|_| candidate(class, &mut rng))
                .find(|&(north_m, east_m, _)| clear_of_others(north_m, east_m));
            let Some((north_m, east_m, fixed_yaw_rad)) = spot else {
                return Err(SceneError::Crowded {
                    class,
                    placed_of: placed,
                    wanted,
                });
            };
            let yaw_rad = fixed_yaw_rad.unwrap_or_else(|| (2.0 * rng.next_f64() - 1.0) * PI);
            hazards.push(Hazard {
                class,
                north_m,
                east_m,
                yaw_rad,
                id: hazards.len() as u32,
            });
        }
    }
    Ok(hazards)
}

/// Hazards along the tractor's track, where a drone following it can see them: the seed's
/// scenario, in which the CNN watches the field beside the tractor.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackScatterConfig {
    /// How many of each class, in the order of [`HazardClass::ALL`].
    pub count_per_class: [usize; 3],
    /// A hazard's centre lies this far to the left or right of the track, metres; at least far
    /// enough that the tractor (half-width [`TRACTOR_HALF_WIDTH_M`]) passes it by.
    pub lateral_offset_m: [f64; 2],
    /// Least gap between two hazards' bounding circles, metres.
    pub min_gap_m: f64,
    /// No hazards on the first metres of the track, where the drone is still joining.
    pub skip_start_m: f64,
}

impl Default for TrackScatterConfig {
    fn default() -> Self {
        Self {
            // 32 objects, as the seed counted.
            count_per_class: [14, 12, 6],
            lateral_offset_m: [1.5, 3.0],
            min_gap_m: 1.0,
            skip_start_m: 10.0,
        }
    }
}

/// Half the tractor's width plus a margin: hazards stay this far clear of the track.
pub const TRACTOR_HALF_WIDTH_M: f64 = 1.2;

impl HazardField {
    /// Places hazards at random points along `track_ne_m` (a polyline, the tractor's future
    /// track), each offset sideways by `lateral_offset_m` and clear of every part of the track
    /// by the tractor's half-width plus its own; vehicles park along the track, the others face
    /// anywhere. The same seed, track and config give the same field.
    pub fn along_track(
        seed: u64,
        track_ne_m: &[[f64; 2]],
        config: &TrackScatterConfig,
    ) -> Result<Self, SceneError> {
        let [lateral_min_m, lateral_max_m] = config.lateral_offset_m;
        for (name, value) in [
            ("lateral_offset_m", lateral_min_m),
            ("lateral_offset_m", lateral_max_m),
            ("min_gap_m", config.min_gap_m),
            ("skip_start_m", config.skip_start_m),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SceneError::Setting { name, value });
            }
        }
        if lateral_max_m < lateral_min_m {
            return Err(SceneError::Setting {
                name: "lateral_offset_m",
                value: lateral_max_m,
            });
        }
        if let Some(bad) = track_ne_m.iter().flatten().find(|x| !x.is_finite()) {
            return Err(SceneError::Setting {
                name: "track_ne_m",
                value: *bad,
            });
        }
        // Cumulative arc length of the track.
        let mut arc_m = vec![0.0];
        for pair in track_ne_m.windows(2) {
            let step = (pair[1][0] - pair[0][0]).hypot(pair[1][1] - pair[0][1]);
            arc_m.push(arc_m.last().copied().unwrap_or(0.0) + step);
        }
        let length_m = arc_m.last().copied().unwrap_or(0.0);
        let rng = SplitMix64::new(seed ^ 0x0074_7261_636b);
        let hazards = place_clear(
            config.count_per_class,
            config.min_gap_m,
            rng,
            |class, rng| {
                if length_m <= config.skip_start_m {
                    return None;
                }
                // Across the track: a parked vehicle shows its width, the others their widest
                // side.
                let half_across_m = match class {
                    HazardClass::Vehicle => 0.5 * class.size_m().1,
                    _ => class.bounding_radius_m(),
                };
                let clearance_m = TRACTOR_HALF_WIDTH_M + half_across_m;
                let lateral_from_m = lateral_min_m.max(clearance_m);
                let lateral_to_m = lateral_max_m.max(lateral_from_m);
                let s = config.skip_start_m + (length_m - config.skip_start_m) * rng.next_f64();
                let segment = arc_m.partition_point(|&a| a <= s).clamp(1, arc_m.len() - 1);
                let (a, b) = (track_ne_m[segment - 1], track_ne_m[segment]);
                let span = arc_m[segment] - arc_m[segment - 1];
                if span <= 0.0 {
                    return None;
                }
                let t = (s - arc_m[segment - 1]) / span;
                let heading = (b[1] - a[1]).atan2(b[0] - a[0]);
                let side = if rng.next_f64() < 0.5 { -1.0 } else { 1.0 };
                let lateral =
                    side * (lateral_from_m + (lateral_to_m - lateral_from_m) * rng.next_f64());
                // Left of the heading is (sin, −cos) in (north, east).
                let north_m = a[0] + t * (b[0] - a[0]) - lateral * heading.sin();
                let east_m = a[1] + t * (b[1] - a[1]) + lateral * heading.cos();
                let clear_of_track =
                    distance_to_path_m(track_ne_m, north_m, east_m) >= clearance_m - 1e-9;
                let fixed_yaw_rad = (class == HazardClass::Vehicle).then_some(heading);
                clear_of_track.then_some((north_m, east_m, fixed_yaw_rad))
            },
        )?;
        Ok(Self { hazards })
    }
}

/// Distance from (north, east) to a polyline; infinite for an empty path.
fn distance_to_path_m(path: &[[f64; 2]], north_m: f64, east_m: f64) -> f64 {
    let to_point = |p: &[f64; 2]| (p[0] - north_m).hypot(p[1] - east_m);
    let mut best = path.first().map_or(f64::INFINITY, to_point);
    for pair in path.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let (dn, de) = (b[0] - a[0], b[1] - a[1]);
        let length2 = dn * dn + de * de;
        let t = if length2 > 0.0 {
            (((north_m - a[0]) * dn + (east_m - a[1]) * de) / length2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        best = best.min((a[0] + t * dn - north_m).hypot(a[1] + t * de - east_m));
    }
    best
}
