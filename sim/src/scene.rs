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

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::vision::landing_marker::{LandingMarkerError, LandingMarkerLayout};
use algorithms::vision::render::{Patch, Scene, Texture};
use nalgebra::Vector3;
use thiserror::Error;

mod baked;
mod hazards;
pub use baked::{baked_texture, FIELD_BAKED_HALF_EXTENT_M, FIELD_TEXEL_M};
pub use hazards::{
    Hazard, HazardClass, HazardField, ScatterConfig, TrackScatterConfig, TRACTOR_HALF_WIDTH_M,
};

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
mod tests;
