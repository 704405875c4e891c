//! The field the simulated camera looks at: a procedural agricultural field, the landing pad on
//! the tractor's roof, and hazards (people, animals, vehicles) scattered over the field.
//!
//! Everything is built from the renderer's opaque rectangular patches
//! ([`algorithms::vision::render::Patch`]). A hazard's shape (a round person, an elliptical animal)
//! is drawn inside its rectangle; outside the shape the hazard's texture samples the field's own
//! texture at the same world point, so the rectangle itself is invisible. That keeps the renderer
//! unchanged and exact: the hazard lies on the ground plane, where the field is.
//!
//! Conventions: world NED, metres, the ground at down = 0. A hazard's yaw is its heading (its
//! long axis) from north towards east, as PX4's yaw.

use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;
use std::sync::{Arc, OnceLock};

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::vision::landing_marker::{LandingMarkerError, LandingMarkerLayout};
use algorithms::vision::render::{Patch, Scene, SplitMix64, Texture};
use nalgebra::Vector3;
use thiserror::Error;

/// A scene that cannot be built as asked.
#[derive(Debug, Error)]
pub enum SceneError {
    #[error("unknown hazard class `{0}` (expected person, animal or vehicle)")]
    UnknownHazardClass(String),
    #[error("the scatter area must have finite extents with min < max, got north {north_m:?}, east {east_m:?}")]
    Area { north_m: [f64; 2], east_m: [f64; 2] },
    #[error("scatter setting `{name}` must be finite and not negative, got {value}")]
    Setting { name: &'static str, value: f64 },
    #[error("could not place {class} {placed_of} of {wanted} without overlapping another hazard or the keep-out path; use a larger area or fewer hazards")]
    Crowded {
        class: HazardClass,
        placed_of: usize,
        wanted: usize,
    },
    #[error("the pad pose must be finite with a height ≥ 0, got {0:?}")]
    PadPose(PadPose),
    #[error("the tractor body must have a positive, finite size, got {length_m} m × {width_m} m")]
    TractorBody { length_m: f64, width_m: f64 },
    #[error(transparent)]
    Layout(#[from] LandingMarkerError),
}

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

/// Where the pad is: its centre's NED position (height above the ground) and heading.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PadPose {
    pub north_m: f64,
    pub east_m: f64,
    /// Height of the pad's surface above the ground (the tractor's roof), metres.
    pub height_m: f64,
    pub yaw_rad: f64,
}

/// The tractor's roof around the pad, drawn darker than the pad so the pad stands out as on a
/// real vehicle. It lies on the pad's plane: the pad is mounted on it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TractorBody {
    /// Along the pad's heading, metres.
    pub length_m: f64,
    /// Across the pad's heading, metres.
    pub width_m: f64,
    pub intensity: f32,
}

impl Default for TractorBody {
    fn default() -> Self {
        Self {
            length_m: 3.0,
            width_m: 2.0,
            intensity: 0.22,
        }
    }
}

/// The simulated world as the camera sees it. Build it once; move the pad every frame with
/// [`SimScene::set_pad_pose`]; [`SimScene::visible_scene`] gives the renderer what one camera can see.
#[derive(Debug, Clone)]
pub struct SimScene {
    field: Texture,
    layout: LandingMarkerLayout,
    pad: Option<PadPose>,
    tractor_body: Option<TractorBody>,
    hazards: Vec<Hazard>,
    hazard_patches: Vec<Patch>,
    occluders: Vec<PadOccluder>,
}

/// Something lying on the pad over part of the marker (a clod of mud, straw, a dark shadow's
/// edge): a square in the pad's frame, drawn over the marker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadOccluder {
    /// Centre, metres forward and right of the pad's centre.
    pub forward_m: f64,
    pub right_m: f64,
    pub yaw_rad: f64,
    pub size_m: f64,
    /// Grey level, 0 black to 1 white.
    pub intensity: f32,
}

impl SimScene {
    /// A bare field of the given seed (no pad, no hazards); the reference pad layout. The field
    /// is [`baked_texture`] of [`Texture::field`]: the procedural field costs ~50 ns a sample,
    /// too much for a 640×480 frame in a few milliseconds.
    pub fn new(field_seed: u64) -> Self {
        Self {
            field: baked_texture(
                Texture::field(field_seed),
                FIELD_TEXEL_M,
                FIELD_BAKED_HALF_EXTENT_M,
            ),
            layout: LandingMarkerLayout::default(),
            pad: None,
            tractor_body: None,
            hazards: Vec::new(),
            hazard_patches: Vec::new(),
            occluders: Vec::new(),
        }
    }

    /// Things lying on the pad, drawn over the marker wherever the pad goes.
    pub fn with_pad_occluders(mut self, occluders: Vec<PadOccluder>) -> Self {
        self.occluders = occluders;
        self
    }

    /// A different background texture (tests use uniform ones).
    pub fn with_field_texture(mut self, field: Texture) -> Self {
        self.field = field;
        let hazards = std::mem::take(&mut self.hazards);
        self.with_hazards(HazardField { hazards })
    }

    /// The pad's printed layout; checked here so a bad one fails before the first frame.
    pub fn with_layout(mut self, layout: LandingMarkerLayout) -> Result<Self, SceneError> {
        layout.validate()?;
        self.layout = layout;
        Ok(self)
    }

    pub fn with_pad(mut self, pose: PadPose) -> Result<Self, SceneError> {
        self.set_pad_pose(pose)?;
        Ok(self)
    }

    pub fn with_tractor_body(mut self, body: TractorBody) -> Result<Self, SceneError> {
        let ok = |x: f64| x.is_finite() && x > 0.0;
        if !(ok(body.length_m) && ok(body.width_m)) {
            return Err(SceneError::TractorBody {
                length_m: body.length_m,
                width_m: body.width_m,
            });
        }
        self.tractor_body = Some(body);
        Ok(self)
    }

    pub fn with_hazards(mut self, field: HazardField) -> Self {
        self.hazard_patches = field.hazards.iter().map(|h| h.patch(&self.field)).collect();
        self.hazards = field.hazards;
        self
    }

    /// Moves the pad (the tractor drives).
    pub fn set_pad_pose(&mut self, pose: PadPose) -> Result<(), SceneError> {
        let finite = [pose.north_m, pose.east_m, pose.height_m, pose.yaw_rad]
            .iter()
            .all(|x| x.is_finite());
        if !(finite && pose.height_m >= 0.0) {
            return Err(SceneError::PadPose(pose));
        }
        self.pad = Some(pose);
        Ok(())
    }

    pub fn pad_pose(&self) -> Option<PadPose> {
        self.pad
    }

    pub fn layout(&self) -> &LandingMarkerLayout {
        &self.layout
    }

    pub fn hazards(&self) -> &[Hazard] {
        &self.hazards
    }

    pub fn field_texture(&self) -> &Texture {
        &self.field
    }

    /// The whole scene, nothing culled.
    pub fn full_scene(&self) -> Result<Scene, SceneError> {
        self.build(|_, _| true)
    }

    /// The part of the scene `camera` at `pose` can see: patches whose bounding circle misses the
    /// image's footprint on their plane are left out, so rendering costs what the view holds, not
    /// what the field holds.
    pub fn visible_scene(
        &self,
        camera: &PinholeCamera,
        pose: &CameraPose,
    ) -> Result<Scene, SceneError> {
        let ground = footprint_circle(camera, pose, 0.0);
        let pad_plane = self
            .pad
            .and_then(|p| footprint_circle(camera, pose, -p.height_m));
        self.build(|patch: &Patch, radius_m: f64| {
            let circle = if patch.down_m == 0.0 {
                ground
            } else {
                pad_plane
            };
            // No footprint (a corner above the horizon): keep everything.
            circle
                .is_none_or(|(n, e, r)| (patch.north_m - n).hypot(patch.east_m - e) <= r + radius_m)
        })
    }

    fn build(&self, keep: impl Fn(&Patch, f64) -> bool) -> Result<Scene, SceneError> {
        let mut scene = Scene::new(self.field.clone());
        for (patch, hazard) in self.hazard_patches.iter().zip(&self.hazards) {
            if keep(patch, hazard.class.bounding_radius_m()) {
                scene.patches.push(patch.clone());
            }
        }
        if let Some(pad) = self.pad {
            let down_m = -pad.height_m;
            if let Some(body) = self.tractor_body {
                let roof = Patch::new(
                    pad.north_m,
                    pad.east_m,
                    pad.yaw_rad,
                    body.width_m,
                    body.length_m,
                    Texture::uniform(body.intensity),
                )
                .at_down_m(down_m);
                if keep(&roof, 0.5 * body.length_m.hypot(body.width_m)) {
                    scene.patches.push(roof);
                }
            }
            let pad_radius_m = self.layout.pad_size_m * std::f64::consts::FRAC_1_SQRT_2;
            let probe = Patch::square(pad.north_m, pad.east_m, 0.0, 1.0, Texture::uniform(1.0))
                .at_down_m(down_m);
            if keep(&probe, pad_radius_m) {
                // Drawn after the roof on the same plane: the pad covers it.
                scene.patches.extend(self.layout.patches(
                    pad.north_m,
                    pad.east_m,
                    down_m,
                    pad.yaw_rad,
                )?);
                let (sin, cos) = pad.yaw_rad.sin_cos();
                for occluder in &self.occluders {
                    let north_m = pad.north_m + cos * occluder.forward_m - sin * occluder.right_m;
                    let east_m = pad.east_m + sin * occluder.forward_m + cos * occluder.right_m;
                    scene.patches.push(
                        Patch::square(
                            north_m,
                            east_m,
                            pad.yaw_rad + occluder.yaw_rad,
                            occluder.size_m,
                            Texture::uniform(occluder.intensity),
                        )
                        .at_down_m(down_m),
                    );
                }
            }
        }
        Ok(scene)
    }
}

/// Texel of the baked field: finer than the camera's ground sampling distance at the heights where
/// the field matters (1.35 cm a pixel at 7.5 m with the default camera), bilinear in between.
pub const FIELD_TEXEL_M: f64 = 0.02;
/// The baked part of the field reaches this far from the origin; beyond it the field repeats.
pub const FIELD_BAKED_HALF_EXTENT_M: f64 = 300.0;

/// Texels a tile side; a tile is baked on the first sample that falls in it.
const TILE_TEXELS: usize = 64;

/// Points [`BakedTexture::sample_many`] takes at a time (stack buffers of a few kilobytes).
const SAMPLE_CHUNK: usize = 64;

/// A ground texture sampled on a grid of tiles, each computed once on first use and bilinearly
/// interpolated: a few nanoseconds a sample whatever the source costs, and memory only for the
/// tiles the camera has seen.
struct BakedTexture {
    source: Texture,
    texel_m: f64,
    texels_per_m: f64,
    limit_texels: f64,
    origin_m: [f64; 2],
    tiles_per_side: usize,
    /// Each tile holds (TILE_TEXELS + 1)² values: one texel of overlap, so interpolation never
    /// needs a neighbouring tile.
    tiles: Box<[OnceLock<Box<[f32]>>]>,
}

impl BakedTexture {
    fn sample(&self, north_m: f64, east_m: f64) -> f32 {
        match self.locate(north_m, east_m) {
            Some(texel) => self.interpolate(self.tile(texel.tile), &texel),
            None => self.source.sample(north_m, east_m),
        }
    }

    /// [`Self::sample`] at every point, [`SAMPLE_CHUNK`] points at a time: a chunk's texel
    /// coordinates, tiles and fractions are computed in branch-free passes the compiler
    /// vectorises, with one wrap into the baked square for the whole chunk (a tractor drives
    /// out of the square within minutes; wrapping each point was half a frame's time), and
    /// only the texel lookups stay one at a time. A chunk that is not all inside one
    /// repetition of the square (its edge, a point off the grid) takes the one-point path.
    fn sample_many(&self, points: &[[f64; 2]], out: &mut [f32]) {
        // The same arithmetic on every CPU (no fused multiply-adds), in wider vectors where
        // the CPU has them.
        pulp::Arch::new().dispatch(SampleMany {
            texture: self,
            points,
            out,
        });
    }

    #[inline(always)]
    fn sample_chunks(&self, points: &[[f64; 2]], out: &mut [f32]) {
        let stride = TILE_TEXELS + 1;
        let limit = self.limit_texels;
        let [origin_n, origin_e] = self.origin_m;
        let k = self.texels_per_m;
        let mut cached: (u32, &[f32]) = (u32::MAX, &[]);
        // Whole repetitions of the square subtracted from the points' texel coordinates.
        let mut wrap = [0.0f64; 2];
        let mut texel = [[0.0f64; SAMPLE_CHUNK]; 2];
        let mut tile = [0u32; SAMPLE_CHUNK];
        let mut offset = [0u32; SAMPLE_CHUNK];
        let mut fraction = [[0.0f32; SAMPLE_CHUNK]; 2];
        for (points, out) in points
            .chunks(SAMPLE_CHUNK)
            .zip(out.chunks_mut(SAMPLE_CHUNK))
        {
            let n = points.len().min(SAMPLE_CHUNK);
            let texel_coordinates = |wrap: [f64; 2], texel: &mut [[f64; SAMPLE_CHUNK]; 2]| {
                // False for NaN too.
                let mut inside = true;
                for (i, &[north_m, east_m]) in points.iter().enumerate() {
                    // Exact: the wrap is a whole number of texels (as `rem_euclid` in `locate`).
                    let (gn, ge) = (
                        (north_m - origin_n) * k - wrap[0],
                        (east_m - origin_e) * k - wrap[1],
                    );
                    texel[0][i] = gn;
                    texel[1][i] = ge;
                    inside &= (gn >= 0.0) & (gn < limit) & (ge >= 0.0) & (ge < limit);
                }
                inside
            };
            if !texel_coordinates(wrap, &mut texel) {
                let [north_m, east_m] = points[0];
                let raw = [(north_m - origin_n) * k, (east_m - origin_e) * k];
                if raw.iter().all(|g| g.is_finite()) {
                    wrap = raw.map(|g| (g / limit).floor() * limit);
                }
                if !texel_coordinates(wrap, &mut texel) {
                    for (&[north_m, east_m], value) in points.iter().zip(out.iter_mut()) {
                        *value = self.sample(north_m, east_m);
                    }
                    continue;
                }
            }
            // In range and not negative, so ⌊·⌋ is a whole number below 2^52: added to 2^52,
            // it is the low bits of the sum's representation. An `as` cast would check each
            // value for NaN and range, one lane at a time.
            const TWO_TO_52: f64 = 4_503_599_627_370_496.0;
            for i in 0..n {
                let (gn, ge) = (texel[0][i], texel[1][i]);
                let (floor_n, floor_e) = (gn.floor(), ge.floor());
                let (in_, ie) = (
                    (floor_n + TWO_TO_52).to_bits() as u32,
                    (floor_e + TWO_TO_52).to_bits() as u32,
                );
                let per_side = TILE_TEXELS as u32;
                tile[i] = (in_ / per_side) * self.tiles_per_side as u32 + ie / per_side;
                offset[i] = (in_ % per_side) * stride as u32 + ie % per_side;
                fraction[0][i] = (gn - floor_n) as f32;
                fraction[1][i] = (ge - floor_e) as f32;
            }
            for i in 0..n {
                if tile[i] != cached.0 {
                    cached = (tile[i], self.tile(tile[i] as usize));
                }
                let texel = Texel {
                    tile: tile[i] as usize,
                    offset: offset[i] as usize,
                    fraction_n: fraction[0][i],
                    fraction_e: fraction[1][i],
                };
                out[i] = self.interpolate(cached.1, &texel);
            }
        }
    }

    /// Where a point falls: its tile, the texel's offset in the tile, and the fractions
    /// between texels; `None` off the grid (not finite), where the source is sampled itself.
    fn locate(&self, north_m: f64, east_m: f64) -> Option<Texel> {
        let gn = (north_m - self.origin_m[0]) * self.texels_per_m;
        let ge = (east_m - self.origin_m[1]) * self.texels_per_m;
        let limit = self.limit_texels;
        if !(gn.is_finite() && ge.is_finite()) {
            return None;
        }
        // Beyond the baked square the field repeats: a tractor drives kilometres in a long
        // mission, and computing the field there would cost the renderer half its speed.
        // `rem_euclid` is a library fmod call; inside the square (nearly every sample) it is
        // the identity, so it is skipped there.
        let wrap = |g: f64| {
            if (0.0..limit).contains(&g) {
                g
            } else {
                g.rem_euclid(limit)
            }
        };
        let (gn, ge) = (wrap(gn), wrap(ge));
        if !(gn < limit && ge < limit) {
            return None;
        }
        // In range and not negative: truncation is ⌊·⌋, and u32 conversions are cheap.
        let (in_, ie) = (gn as u32 as usize, ge as u32 as usize);
        let (tn, te) = (in_ / TILE_TEXELS, ie / TILE_TEXELS);
        let tile = tn * self.tiles_per_side + te;
        (tile < self.tiles.len()).then(|| Texel {
            tile,
            offset: (in_ % TILE_TEXELS) * (TILE_TEXELS + 1) + ie % TILE_TEXELS,
            fraction_n: (gn - in_ as f64) as f32,
            fraction_e: (ge - ie as f64) as f32,
        })
    }

    /// A tile's values, baked on first use.
    fn tile(&self, index: usize) -> &[f32] {
        let (tile_n, tile_e) = (index / self.tiles_per_side, index % self.tiles_per_side);
        self.tiles[index].get_or_init(|| self.bake(tile_n, tile_e))
    }

    #[inline(always)]
    fn interpolate(&self, tile: &[f32], texel: &Texel) -> f32 {
        let stride = TILE_TEXELS + 1;
        // The offset is at most (TILE_TEXELS − 1)·(stride + 1), so the two rows the
        // interpolation needs are in the tile.
        let q = &tile[texel.offset..texel.offset + stride + 2];
        let fe = texel.fraction_e;
        let top = q[0] + (q[1] - q[0]) * fe;
        let bottom = q[stride] + (q[stride + 1] - q[stride]) * fe;
        top + (bottom - top) * texel.fraction_n
    }

    fn bake(&self, tile_n: usize, tile_e: usize) -> Box<[f32]> {
        let stride = TILE_TEXELS + 1;
        let mut values = Vec::with_capacity(stride * stride);
        for n in 0..stride {
            for e in 0..stride {
                let north_m = self.origin_m[0] + ((tile_n * TILE_TEXELS + n) as f64) * self.texel_m;
                let east_m = self.origin_m[1] + ((tile_e * TILE_TEXELS + e) as f64) * self.texel_m;
                values.push(self.source.sample(north_m, east_m));
            }
        }
        values.into_boxed_slice()
    }
}

/// [`BakedTexture::sample_many`]'s work, for [`pulp`] to compile for each instruction set.
struct SampleMany<'a> {
    texture: &'a BakedTexture,
    points: &'a [[f64; 2]],
    out: &'a mut [f32],
}

impl pulp::WithSimd for SampleMany<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        self.texture.sample_chunks(self.points, self.out);
    }
}

/// A point's place on the baked grid.
struct Texel {
    tile: usize,
    offset: usize,
    fraction_n: f32,
    fraction_e: f32,
}

/// `source` (a function of world north, east) baked lazily on a grid of `texel_m` texels over
/// the square of half-side `half_extent_m` around the origin, repeated periodically outside it. A bad
/// texel or extent (not finite, not positive) gives `source` itself.
pub fn baked_texture(source: Texture, texel_m: f64, half_extent_m: f64) -> Texture {
    if !(texel_m.is_finite() && texel_m > 0.0 && half_extent_m.is_finite() && half_extent_m > 0.0) {
        return source;
    }
    let tile_m = TILE_TEXELS as f64 * texel_m;
    let tiles_per_side = ((2.0 * half_extent_m / tile_m).ceil() as usize).clamp(1, 4096);
    let half_m = 0.5 * tiles_per_side as f64 * tile_m;
    let baked = Arc::new(BakedTexture {
        source,
        texel_m,
        texels_per_m: 1.0 / texel_m,
        limit_texels: (tiles_per_side * TILE_TEXELS) as f64,
        origin_m: [-half_m, -half_m],
        tiles_per_side,
        tiles: (0..tiles_per_side * tiles_per_side)
            .map(|_| OnceLock::new())
            .collect(),
    });
    let many = Arc::clone(&baked);
    Texture::from_fns(
        move |north_m, east_m| baked.sample(north_m, east_m),
        move |points, out| many.sample_many(points, out),
    )
}

/// The circle (north, east, radius) around where the image's corners meet the plane
/// `down = plane_down_m`; `None` when a corner misses it (looks above the horizon).
fn footprint_circle(
    camera: &PinholeCamera,
    pose: &CameraPose,
    plane_down_m: f64,
) -> Option<(f64, f64, f64)> {
    let (right, bottom) = (camera.width_px as f64 - 0.5, camera.height_px as f64 - 0.5);
    let mut corners = Vec::with_capacity(4);
    for (u, v) in [(-0.5, -0.5), (right, -0.5), (right, bottom), (-0.5, bottom)] {
        corners.push(camera.pixel_to_plane(pose, u, v, plane_down_m)?);
    }
    let centre: Vector3<f64> = corners.iter().map(|c| c.coords).sum::<Vector3<f64>>() / 4.0;
    // Barrel distortion can push the edges' middles beyond the corners' hull: a margin.
    let radius_m = corners
        .iter()
        .map(|c| (c.x - centre.x).hypot(c.y - centre.y))
        .fold(0.0, f64::max)
        * 1.1;
    Some((centre.x, centre.y, radius_m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use algorithms::vision::render::{render, RenderOptions};

    fn camera_at(altitude_m: f64) -> (PinholeCamera, CameraPose) {
        let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -altitude_m), 0.0, 0.0, 0.0);
        (camera, pose)
    }

    #[test]
    fn hazards_along_a_track_lie_beside_it_and_clear_of_it() {
        // An L-shaped track: 200 m north, then 100 m east.
        let mut track = Vec::new();
        for i in 0..=200 {
            track.push([f64::from(i), 0.0]);
        }
        for i in 1..=100 {
            track.push([200.0, f64::from(i)]);
        }
        let config = TrackScatterConfig::default();
        let field = HazardField::along_track(3, &track, &config).unwrap();
        assert_eq!(field.hazards.len(), 32);
        for class in HazardClass::ALL {
            let count = field.hazards.iter().filter(|h| h.class == class).count();
            assert_eq!(count, config.count_per_class[class as usize]);
        }
        for h in &field.hazards {
            // Brute force: the distance to the densely sampled track.
            let distance = track
                .iter()
                .map(|p| (p[0] - h.north_m).hypot(p[1] - h.east_m))
                .fold(f64::INFINITY, f64::min);
            let half_across = match h.class {
                HazardClass::Vehicle => 1.0,
                _ => h.class.bounding_radius_m(),
            };
            assert!(
                distance >= TRACTOR_HALF_WIDTH_M + half_across - 1e-6,
                "{h:?}: {distance}"
            );
            assert!(
                distance <= 3.0 + 1e-6,
                "{h:?} is {distance} m off the track"
            );
            // Not on the first 10 m (the first leg runs north from 0).
            assert!(h.north_m >= 10.0 - 1e-9, "{h:?}");
            if h.class == HazardClass::Vehicle {
                // Parked along its leg.
                let along = [0.0, std::f64::consts::FRAC_PI_2];
                assert!(along.iter().any(|a| (h.yaw_rad - a).abs() < 1e-9), "{h:?}");
            }
        }
        for (i, a) in field.hazards.iter().enumerate() {
            for b in &field.hazards[i + 1..] {
                let gap = (a.north_m - b.north_m).hypot(a.east_m - b.east_m);
                let least = a.class.bounding_radius_m() + b.class.bounding_radius_m() + 1.0;
                assert!(gap >= least - 1e-9);
            }
        }
        assert_eq!(field, HazardField::along_track(3, &track, &config).unwrap());
        assert_ne!(field, HazardField::along_track(4, &track, &config).unwrap());
        // A track too short to hold them, and bad settings, are named errors.
        assert!(matches!(
            HazardField::along_track(3, &track[..5], &config),
            Err(SceneError::Crowded { .. })
        ));
        let bad = TrackScatterConfig {
            lateral_offset_m: [3.0, 1.0],
            ..config
        };
        assert!(matches!(
            HazardField::along_track(3, &track, &bad),
            Err(SceneError::Setting {
                name: "lateral_offset_m",
                ..
            })
        ));
    }

    #[test]
    fn hazard_class_names_round_trip() {
        for class in HazardClass::ALL {
            assert_eq!(class.to_string().parse::<HazardClass>().unwrap(), class);
        }
        assert!(matches!(
            "tractor".parse::<HazardClass>(),
            Err(SceneError::UnknownHazardClass(name)) if name == "tractor"
        ));
    }

    #[test]
    fn scatter_is_deterministic_per_seed_and_never_overlaps() {
        let config = ScatterConfig {
            north_m: [-30.0, 30.0],
            east_m: [-30.0, 30.0],
            count_per_class: [20, 12, 6],
            keep_out_path_ne_m: vec![[-30.0, 0.0], [30.0, 0.0]],
            keep_out_radius_m: 3.0,
            min_gap_m: 0.3,
        };
        let a = HazardField::scatter(7, &config).unwrap();
        assert_eq!(a, HazardField::scatter(7, &config).unwrap());
        assert_ne!(a, HazardField::scatter(8, &config).unwrap());
        assert_eq!(a.hazards.len(), 38);
        for class in HazardClass::ALL {
            let count = a.hazards.iter().filter(|h| h.class == class).count();
            assert_eq!(count, config.count_per_class[class as usize]);
        }
        for (i, h) in a.hazards.iter().enumerate() {
            assert!(h.north_m.abs() <= 30.0 && h.east_m.abs() <= 30.0);
            // The path runs along east = 0.
            assert!(h.east_m.abs() >= 3.0 + h.class.bounding_radius_m(), "{h:?}");
            assert_eq!(h.id as usize, i);
            for g in &a.hazards[i + 1..] {
                let gap = (h.north_m - g.north_m).hypot(h.east_m - g.east_m);
                assert!(
                    gap >= h.class.bounding_radius_m() + g.class.bounding_radius_m() + 0.3,
                    "{h:?} overlaps {g:?}"
                );
            }
        }
    }

    #[test]
    fn bad_scatter_settings_are_named_errors() {
        let crowded = ScatterConfig {
            north_m: [0.0, 5.0],
            east_m: [0.0, 5.0],
            count_per_class: [0, 0, 10],
            ..Default::default()
        };
        assert!(matches!(
            HazardField::scatter(1, &crowded),
            Err(SceneError::Crowded {
                class: HazardClass::Vehicle,
                ..
            })
        ));
        let flat = ScatterConfig {
            north_m: [5.0, 5.0],
            ..Default::default()
        };
        assert!(matches!(
            HazardField::scatter(1, &flat),
            Err(SceneError::Area { .. })
        ));
        let negative = ScatterConfig {
            min_gap_m: -1.0,
            ..Default::default()
        };
        assert!(matches!(
            HazardField::scatter(1, &negative),
            Err(SceneError::Setting {
                name: "min_gap_m",
                ..
            })
        ));
        assert!(matches!(
            SimScene::new(1).with_pad(PadPose {
                height_m: f64::NAN,
                ..Default::default()
            }),
            Err(SceneError::PadPose(_))
        ));
    }

    /// Pixels of a lone hazard seen from 7.5 m: those that do not change with the background.
    fn hazard_pixels(hazard: Hazard) -> Vec<(usize, usize, u8)> {
        let (camera, pose) = camera_at(7.5);
        let options = RenderOptions {
            supersampling: 1,
            ..Default::default()
        };
        let images: Vec<_> = [0.0f32, 1.0]
            .into_iter()
            .map(|level| {
                let field = Texture::uniform(level);
                let scene = Scene::new(field.clone()).with_patch(hazard.patch(&field));
                render(&camera, &pose, &scene, &options).unwrap()
            })
            .collect();
        let mut pixels = Vec::new();
        for y in 0..480 {
            for x in 0..640 {
                if images[0].get(x, y) == images[1].get(x, y) {
                    pixels.push((x, y, images[0].get(x, y)));
                }
            }
        }
        pixels
    }

    #[test]
    fn each_class_has_its_own_size_shape_and_shade_at_7_5_m() {
        let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
        let gsd_m = 7.5 / camera.fx_px;
        let mut means = Vec::new();
        for class in HazardClass::ALL {
            let hazard = Hazard {
                class,
                north_m: 0.3,
                east_m: -0.2,
                yaw_rad: 0.6,
                id: 0,
            };
            let pixels = hazard_pixels(hazard);
            let area_m2 = pixels.len() as f64 * gsd_m * gsd_m;
            let expected_m2 = class.shape_area_m2();
            assert!(
                (area_m2 / expected_m2 - 1.0).abs() < 0.2,
                "{class}: {area_m2} m² against {expected_m2} m²"
            );
            // Elongation from the second moments: the ratio of the principal axes.
            let n = pixels.len() as f64;
            let (mx, my) = pixels.iter().fold((0.0, 0.0), |(a, b), &(x, y, _)| {
                (a + x as f64 / n, b + y as f64 / n)
            });
            let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
            for &(x, y, _) in &pixels {
                let (dx, dy) = (x as f64 - mx, y as f64 - my);
                sxx += dx * dx / n;
                syy += dy * dy / n;
                sxy += dx * dy / n;
            }
            let half_trace = 0.5 * (sxx + syy);
            let root = (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt();
            let elongation = ((half_trace + root) / (half_trace - root)).sqrt();
            let (length_m, width_m) = class.size_m();
            let expected = length_m.max(width_m) / length_m.min(width_m);
            assert!(
                (elongation / expected - 1.0).abs() < 0.2,
                "{class}: elongation {elongation}"
            );
            let mean = pixels.iter().map(|p| p.2 as f64).sum::<f64>() / n;
            means.push((class, mean));
        }
        for (i, a) in means.iter().enumerate() {
            for b in &means[i + 1..] {
                assert!((a.1 - b.1).abs() > 40.0, "{means:?}");
            }
        }
    }

    #[test]
    fn a_hazard_shows_the_field_outside_its_shape() {
        let field = Texture::field(5);
        let hazard = Hazard {
            class: HazardClass::Person,
            north_m: 1.0,
            east_m: 2.0,
            yaw_rad: 0.3,
            id: 0,
        };
        let patch = hazard.patch(&field);
        // The rectangle's corner is outside the round shape: the field's value there.
        let corner = patch.point_world(0.98, -0.98);
        assert_eq!(
            patch.texture.sample(0.98, -0.98),
            field.sample(corner.x, corner.y)
        );
        assert_eq!(patch.texture.sample(0.0, 0.0), 0.62);
    }

    #[test]
    fn the_baked_field_matches_the_field_at_its_texels_and_between() {
        let source = Texture::field(9);
        let baked = baked_texture(source.clone(), 0.02, 10.0);
        let half_m =
            0.5 * (10.0f64 / (TILE_TEXELS as f64 * 0.02) * 2.0).ceil() * TILE_TEXELS as f64 * 0.02;
        let mut worst = 0f32;
        for k in 0..500 {
            // Texel corners, in several tiles.
            let (i, j) = ((k * 37) % 900, (k * 53) % 900);
            let (n, e) = (-half_m + i as f64 * 0.02, -half_m + j as f64 * 0.02);
            worst = worst.max((baked.sample(n, e) - source.sample(n, e)).abs());
        }
        assert!(worst < 1e-4, "at texels: {worst}");
        // Between texels the bilinear value is close.
        let mut sum = 0f32;
        for k in 0..500 {
            let (n, e) = (k as f64 * 0.0137 - 3.0, k as f64 * -0.0191 + 2.0);
            sum += (baked.sample(n, e) - source.sample(n, e)).abs();
        }
        assert!(sum / 500.0 < 0.03, "between texels: {}", sum / 500.0);
        // Outside the baked square the field repeats with the square's side as period.
        let period_m = 2.0 * half_m;
        for (n, e) in [(50.0, -70.0), (3.3, 1.7), (-9.9, 0.01)] {
            let inside = baked.sample(n, e);
            assert_eq!(baked.sample(n + period_m, e), inside);
            assert_eq!(baked.sample(n - 3.0 * period_m, e + period_m), inside);
        }
        // A non-finite coordinate is the source's business, not a panic.
        let _ = baked.sample(f64::NAN, 0.0);
        // Many points at once (runs within a tile, jumps between tiles, the periodic copies,
        // a point off the grid) give what one point at a time gives.
        let mut points: Vec<[f64; 2]> = (0..300)
            .map(|k| [k as f64 * 0.031 - 4.0, (k % 17) as f64 * 0.9 - 7.0])
            .collect();
        points.extend([[50.0, -70.0], [f64::INFINITY, 1.0], [3.3, 1.7]]);
        // A run far outside the square (a tractor kilometres out), crossing a repetition's edge.
        points.extend((0..200).map(|k| [1200.0 + k as f64 * 0.013, -830.0 - k as f64 * 0.07]));
        let mut many = vec![0f32; points.len()];
        baked.sample_many(&points, &mut many);
        for (&[n, e], value) in points.iter().zip(&many) {
            let one = baked.sample(n, e);
            assert!(
                one == *value || (one.is_nan() && value.is_nan()),
                "({n}, {e}): {value} at once, {one} alone"
            );
        }
    }

    #[test]
    fn the_visible_scene_culls_what_the_camera_cannot_see() {
        let config = ScatterConfig {
            north_m: [-100.0, 100.0],
            east_m: [-100.0, 100.0],
            count_per_class: [30, 20, 10],
            ..Default::default()
        };
        let scene = SimScene::new(2)
            .with_hazards(HazardField::scatter(3, &config).unwrap())
            .with_tractor_body(TractorBody::default())
            .unwrap()
            .with_pad(PadPose {
                north_m: 0.5,
                east_m: 0.0,
                height_m: 2.0,
                yaw_rad: 0.2,
            })
            .unwrap();
        let (camera, pose) = camera_at(8.0);
        let visible = scene.visible_scene(&camera, &pose).unwrap();
        let full = scene.full_scene().unwrap();
        // Roof + pad + n-fold + 3 ArUco.
        assert_eq!(full.patches.len(), 60 + 6);
        assert!(visible.patches.len() < 20, "{}", visible.patches.len());
        assert!(visible.patches.len() >= 6);
        // Culling does not change the image.
        let options = RenderOptions {
            supersampling: 1,
            ..Default::default()
        };
        assert_eq!(
            render(&camera, &pose, &visible, &options).unwrap(),
            render(&camera, &pose, &full, &options).unwrap()
        );
    }
}
