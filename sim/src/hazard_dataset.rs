//! Labelled frames for training and evaluating the hazard detector: the simulated camera's image
//! of a random but mission-like situation (height, tilt, motion, field, hazards, sometimes the
//! tractor and its pad) with the true box of every hazard in view.
//!
//! A frame is a pure function of its seed, so a training set is a list of seeds and a held-out
//! set is a disjoint list.
//!
//! Boxes are in full-resolution image pixels with pixel `k` spanning `[k, k + 1)` — the
//! convention of [`algorithms::vision::yolo::letterbox_gray`] and of the boxes
//! [`algorithms::vision::yolo::decode`] maps back — so the whole image is `[0, width] × [0, height]`.
//! A box bounds the hazard's visible shape (the ellipse of a person or an animal, the rectangle
//! of a vehicle), not its bounding rectangle: a rotated ellipse's rectangle overstates it by up to
//! 40 %, which a detector could only learn by guessing the yaw of a near-round person.

use std::f64::consts::PI;

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::estimation::projection::Attitude;
use algorithms::vision::image::GrayImage;
use algorithms::vision::render::{SplitMix64, Texture};
use algorithms::vision::yolo::PixelBox;
use nalgebra::{Point3, Vector3};
use thiserror::Error;

use crate::camera::{CameraError, SimCamera, SimCameraConfig, VehiclePose};
use crate::scene::{Hazard, HazardClass, HazardField, PadPose, SceneError, SimScene, TractorBody};
use crate::tractor::TractorParams;

/// A frame that could not be made.
#[derive(Debug, Error)]
pub enum DatasetError {
    #[error("could not build the scene for a labelled frame: {0}")]
    Scene(#[from] SceneError),
    #[error("could not capture a labelled frame: {0}")]
    Camera(#[from] CameraError),
    #[error("the camera at {altitude_m} m, tilted {tilt_deg:.1}°, does not see the ground with all four image corners")]
    NoGround { altitude_m: f64, tilt_deg: f64 },
}

/// One true hazard in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HazardLabel {
    pub class: HazardClass,
    /// Full-resolution image pixels (see the module docs), clipped to the image.
    pub bbox: PixelBox,
    pub hazard_id: u32,
}

/// An image and its labels.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelledFrame {
    pub image: GrayImage,
    pub labels: Vec<HazardLabel>,
    /// Hazards whose centre is out of view but part of which shows at the image's edge, boxes
    /// clipped to the image: not labels, and not background either — a detector may or may not
    /// report them, so training and scoring leave them out.
    pub cut_off: Vec<HazardLabel>,
}

/// Everything a labelled frame is rendered from; drawn from a seed by [`draw_situation`].
#[derive(Debug, Clone, PartialEq)]
pub struct Situation {
    pub field_seed: u64,
    pub camera_seed: u64,
    /// Capture time: sets the camera's brightness and contrast drift.
    pub time_s: f64,
    pub vehicle: VehiclePose,
    pub hazards: Vec<Hazard>,
    /// The tractor's roof and the landing pad, when in view.
    pub pad: Option<PadPose>,
}

/// Most hazards a frame holds.
pub const MAX_HAZARDS_PER_FRAME: usize = 6;
/// Camera heights above the ground a frame is taken from, metres.
pub const ALTITUDE_RANGE_M: [f64; 2] = [4.0, 12.0];
/// Where most frames are taken from: around the mission's tracking height (7.5 m above a 1 m pad).
pub const TYPICAL_ALTITUDE_RANGE_M: [f64; 2] = [6.0, 9.0];
/// Largest lean into the wind, degrees: a multirotor holds about 28° in 12 m/s and more in its
/// gusts. A model trained on leans to 15° only took the field seen at 28° for people (74 false
/// detections in 89 frames of a 12 m/s flight with no hazard in it, none in calm air).
pub const MAX_LEAN_DEG: f64 = 35.0;
/// Largest wobble about that lean (gusts, manoeuvres), degrees.
pub const MAX_WOBBLE_DEG: f64 = 5.0;
/// Largest roll or pitch a situation can have.
pub const MAX_TILT_DEG: f64 = MAX_LEAN_DEG + MAX_WOBBLE_DEG;
/// Least gap between hazards' bounding circles, metres: hazards never overlap.
const HAZARD_GAP_M: f64 = 0.3;
/// Hazards keep this many pixels clear of the tractor's roof in the image.
const ROOF_CLEARANCE_PX: f64 = 6.0;
/// Points on an ellipse's outline when boxing it: the box is short by under 0.2 % of the radius.
const OUTLINE_POINTS: usize = 64;

/// The labelled frame of `seed`: [`draw_situation`] seen by the default simulated camera.
pub fn render_labelled_frame(seed: u64) -> Result<LabelledFrame, DatasetError> {
    render_situation(&draw_situation(seed)?, &SimCameraConfig::default(), None)
}

/// A random situation as the mission meets it, the same for the same seed: a camera 4–12 m above
/// the field (mostly 6–9 m), leaning into the wind by up to 35° (plus a 5° wobble), any heading, moving a little (motion
/// blur); 0–6 hazards of random classes, most inside the view and some cut by its edge; in about
/// half the frames the tractor's roof and the pad in view, with no hazard under them.
pub fn draw_situation(seed: u64) -> Result<Situation, DatasetError> {
    let mut rng = SplitMix64::new(seed ^ 0x0064_6174_6173_6574);
    let rng = &mut rng;
    let altitude_m = if uniform(rng, 0.0, 1.0) < 0.6 {
        uniform(
            rng,
            TYPICAL_ALTITUDE_RANGE_M[0],
            TYPICAL_ALTITUDE_RANGE_M[1],
        )
    } else {
        uniform(rng, ALTITUDE_RANGE_M[0], ALTITUDE_RANGE_M[1])
    };
    // A lean as steady wind gives it, from calm to strong alike, towards any side; a wobble
    // about it, small ones common (the mean of two uniforms).
    let lean_rad = uniform(rng, 0.0, MAX_LEAN_DEG.to_radians());
    let lean_towards_rad = uniform(rng, -PI, PI);
    let mut wobble =
        || MAX_WOBBLE_DEG.to_radians() * (uniform(rng, -1.0, 1.0) + uniform(rng, -1.0, 1.0)) / 2.0;
    let roll_rad = lean_rad * lean_towards_rad.sin() + wobble();
    let pitch_rad = lean_rad * lean_towards_rad.cos() + wobble();
    let yaw_rad = uniform(rng, -PI, PI);
    let position_ned_m = Vector3::new(
        uniform(rng, -250.0, 250.0),
        uniform(rng, -250.0, 250.0),
        -altitude_m,
    );
    let (speed_m_s, heading_rad) = (uniform(rng, 0.0, 4.0), uniform(rng, -PI, PI));
    let velocity_ned_m_s = Vector3::new(
        speed_m_s * heading_rad.cos(),
        speed_m_s * heading_rad.sin(),
        uniform(rng, -0.5, 0.5),
    );
    let body_rates_rad_s = Vector3::new(
        uniform(rng, -0.3, 0.3),
        uniform(rng, -0.3, 0.3),
        uniform(rng, -0.2, 0.2),
    );
    let field_seed = rng.next_u64();
    let camera_seed = rng.next_u64();
    let time_s = uniform(rng, 0.0, 200.0);
    let vehicle = VehiclePose {
        position_ned_m,
        attitude: Attitude::new(roll_rad, pitch_rad, yaw_rad),
        velocity_ned_m_s,
        body_rates_rad_s,
    };

    let camera = SimCameraConfig::default()
        .validate()
        .map_err(CameraError::from)?;
    let pose = SimCamera::pose(&vehicle.position_ned_m, &vehicle.attitude);
    let (width, height) = (camera.width_px as f64, camera.height_px as f64);
    let no_ground = || DatasetError::NoGround {
        altitude_m,
        tilt_deg: pose.tilt_rad().to_degrees(),
    };
    // Where the ray through a random pixel of [u_lo, u_hi] × [v_lo, v_hi] (fractions of the
    // image) meets the plane down = plane_down_m.
    let ground_at = |rng: &mut SplitMix64,
                     [u_lo, u_hi]: [f64; 2],
                     [v_lo, v_hi]: [f64; 2],
                     plane_down_m: f64| {
        let (u, v) = (
            uniform(rng, u_lo, u_hi) * width,
            uniform(rng, v_lo, v_hi) * height,
        );
        camera.pixel_to_plane(&pose, u, v, plane_down_m)
    };

    let pad = if uniform(rng, 0.0, 1.0) < 0.5 {
        let pad_height_m = TractorParams::default().pad_height_m;
        let centre = ground_at(rng, [0.1, 0.9], [0.1, 0.9], -pad_height_m).ok_or_else(no_ground)?;
        Some(PadPose {
            north_m: centre.x,
            east_m: centre.y,
            height_m: pad_height_m,
            yaw_rad: uniform(rng, -PI, PI),
        })
    } else {
        None
    };
    let roof_box = pad.and_then(|p| roof_box_px(&camera, &pose, &p, &TractorBody::default()));

    let count =
        (uniform(rng, 0.0, (MAX_HAZARDS_PER_FRAME + 1) as f64) as usize).min(MAX_HAZARDS_PER_FRAME);
    let mut hazards: Vec<Hazard> = Vec::with_capacity(count);
    for _ in 0..count {
        // Persons are small and the mission's main concern: drawn most often.
        let pick = uniform(rng, 0.0, 1.0);
        let class = if pick < 0.4 {
            HazardClass::Person
        } else if pick < 0.75 {
            HazardClass::Animal
        } else {
            HazardClass::Vehicle
        };
        // A few tries for a free spot; a crowded view just holds fewer hazards.
        for _ in 0..20 {
            // A little beyond the image on each side: some hazards are cut by its edge.
            let Some(spot) = ground_at(rng, [-0.05, 1.05], [-0.05, 1.05], 0.0) else {
                return Err(no_ground());
            };
            let hazard = Hazard {
                class,
                north_m: spot.x,
                east_m: spot.y,
                yaw_rad: uniform(rng, -PI, PI),
                id: hazards.len() as u32,
            };
            let clear_of_others = hazards.iter().all(|h| {
                let gap_m = (h.north_m - hazard.north_m).hypot(h.east_m - hazard.east_m);
                gap_m >= h.class.bounding_radius_m() + class.bounding_radius_m() + HAZARD_GAP_M
            });
            let clear_of_roof = match (&roof_box, hazard_box_px(&camera, &pose, &hazard)) {
                (Some(roof), Some(b)) => !overlaps(roof, &b, ROOF_CLEARANCE_PX),
                _ => true,
            };
            if clear_of_others && clear_of_roof {
                hazards.push(hazard);
                break;
            }
        }
    }
    Ok(Situation {
        field_seed,
        camera_seed,
        time_s,
        vehicle,
        hazards,
        pad,
    })
}

fn uniform(rng: &mut SplitMix64, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.next_f64()
}

/// Renders a situation with `camera_config`; `field` replaces the procedural field (tests use a
/// uniform one).
pub fn render_situation(
    situation: &Situation,
    camera_config: &SimCameraConfig,
    field: Option<Texture>,
) -> Result<LabelledFrame, DatasetError> {
    let mut scene = SimScene::new(situation.field_seed).with_hazards(HazardField {
        hazards: situation.hazards.clone(),
    });
    if let Some(field) = field {
        scene = scene.with_field_texture(field);
    }
    if let Some(pad) = situation.pad {
        scene = scene
            .with_tractor_body(TractorBody::default())?
            .with_pad(pad)?;
    }
    let mut camera = SimCamera::new(*camera_config, situation.camera_seed)?;
    let v = &situation.vehicle;
    let image = camera.capture(
        situation.time_s,
        &v.position_ned_m,
        &v.attitude,
        &v.velocity_ned_m_s,
        &v.body_rates_rad_s,
        &scene,
    )?;
    let model = camera.model();
    let pose = SimCamera::pose(&v.position_ned_m, &v.attitude);
    let (mut labels, mut cut_off) = (Vec::new(), Vec::new());
    for hazard in &situation.hazards {
        match label(model, &pose, hazard) {
            Some((label, true)) => labels.push(label),
            Some((label, false)) => cut_off.push(label),
            None => {}
        }
    }
    Ok(LabelledFrame {
        image,
        labels,
        cut_off,
    })
}

/// The box of a hazard that shows in the image, clipped to it, and whether its centre is in
/// view (a label) or not (cut off); `None` when no part of it is in the image.
fn label(
    camera: &PinholeCamera,
    pose: &CameraPose,
    hazard: &Hazard,
) -> Option<(HazardLabel, bool)> {
    let centre = Point3::new(hazard.north_m, hazard.east_m, 0.0);
    let (u, v) = camera.project_world(pose, &centre)?;
    let b = hazard_box_px(camera, pose, hazard)?;
    let (width, height) = (camera.width_px as f64, camera.height_px as f64);
    let clipped = PixelBox {
        x_min: b.x_min.clamp(0.0, width),
        y_min: b.y_min.clamp(0.0, height),
        x_max: b.x_max.clamp(0.0, width),
        y_max: b.y_max.clamp(0.0, height),
    };
    if clipped.area() <= 0.0 {
        return None;
    }
    let label = HazardLabel {
        class: hazard.class,
        bbox: clipped,
        hazard_id: hazard.id,
    };
    Some((label, camera.contains(u, v)))
}

/// The image box (not clipped) of a hazard's visible shape; `None` when part of it is behind the
/// camera.
pub fn hazard_box_px(
    camera: &PinholeCamera,
    pose: &CameraPose,
    hazard: &Hazard,
) -> Option<PixelBox> {
    // The renderer's own patch: the same axes and sizes as what it draws.
    let patch = hazard.patch(&Texture::uniform(0.0));
    let outline: Vec<(f64, f64)> = match hazard.class {
        HazardClass::Person | HazardClass::Animal => (0..OUTLINE_POINTS)
            .map(|k| {
                let angle_rad = 2.0 * PI * k as f64 / OUTLINE_POINTS as f64;
                (angle_rad.cos(), angle_rad.sin())
            })
            .collect(),
        HazardClass::Vehicle => vec![(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)],
    };
    let points = outline
        .into_iter()
        .map(|(u, v)| camera.project_world(pose, &patch.point_world(u, v)))
        .collect::<Option<Vec<_>>>()?;
    Some(box_of_centres(&points))
}

/// The box of the tractor's roof (which the pad lies on) in the image, not clipped.
fn roof_box_px(
    camera: &PinholeCamera,
    pose: &CameraPose,
    pad: &PadPose,
    body: &TractorBody,
) -> Option<PixelBox> {
    let roof = algorithms::vision::render::Patch::new(
        pad.north_m,
        pad.east_m,
        pad.yaw_rad,
        body.width_m,
        body.length_m,
        Texture::uniform(body.intensity),
    )
    .at_down_m(-pad.height_m);
    let points = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
        .into_iter()
        .map(|(u, v)| camera.project_world(pose, &roof.point_world(u, v)))
        .collect::<Option<Vec<_>>>()?;
    Some(box_of_centres(&points))
}

/// The box around projected points: pixel centres (the camera's convention) shifted by half a
/// pixel to the `[k, k + 1)` convention of the labels.
fn box_of_centres(points: &[(f64, f64)]) -> PixelBox {
    let mut b = PixelBox {
        x_min: f64::INFINITY,
        y_min: f64::INFINITY,
        x_max: f64::NEG_INFINITY,
        y_max: f64::NEG_INFINITY,
    };
    for &(u, v) in points {
        b.x_min = b.x_min.min(u + 0.5);
        b.y_min = b.y_min.min(v + 0.5);
        b.x_max = b.x_max.max(u + 0.5);
        b.y_max = b.y_max.max(v + 0.5);
    }
    b
}

/// Whether two boxes come closer than `margin_px`.
fn overlaps(a: &PixelBox, b: &PixelBox, margin_px: f64) -> bool {
    a.x_min - margin_px < b.x_max
        && b.x_min - margin_px < a.x_max
        && a.y_min - margin_px < b.y_max
        && b.y_min - margin_px < a.y_max
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera that adds nothing: no noise, blur or drift, so a uniform field renders uniform.
    fn clean_camera() -> SimCameraConfig {
        SimCameraConfig {
            noise_sigma: 0.0,
            motion_blur: false,
            brightness_amplitude: 0.0,
            contrast_amplitude: 0.0,
            ..SimCameraConfig::default()
        }
    }

    /// Background level: apart from every hazard shade (0.08, 0.62, 0.38–0.5, 0.92, 0.12).
    const BACKGROUND: f32 = 0.27;

    #[test]
    fn labels_box_exactly_the_hazard_pixels_on_a_uniform_field() {
        let background_level = (BACKGROUND * 255.0 + 0.5) as u8;
        let (mut frames_checked, mut labels_checked, mut tight_checked) = (0, 0, 0);
        let mut cut_off_seen = 0;
        for seed in 0..40u64 {
            let mut situation = draw_situation(seed).unwrap();
            // The pad and roof differ from the background too; they have their own test below.
            situation.pad = None;
            let frame = render_situation(
                &situation,
                &clean_camera(),
                Some(Texture::uniform(BACKGROUND)),
            )
            .unwrap();
            let camera = clean_camera().validate().unwrap();
            let pose = SimCamera::pose(
                &situation.vehicle.position_ned_m,
                &situation.vehicle.attitude,
            );
            // Hazards whose centre is out of view have no label but may show at the edge.
            let all_boxes: Vec<PixelBox> = frame
                .labels
                .iter()
                .chain(&frame.cut_off)
                .map(|l| l.bbox)
                .collect();
            let image = &frame.image;
            let mut differing_per_label = vec![Vec::new(); frame.labels.len()];
            for y in 0..image.height() {
                for x in 0..image.width() {
                    if image.get(x, y) == background_level {
                        continue;
                    }
                    let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                    let inside = |b: &PixelBox| {
                        px >= b.x_min - 2.0
                            && px <= b.x_max + 2.0
                            && py >= b.y_min - 2.0
                            && py <= b.y_max + 2.0
                    };
                    assert!(
                        all_boxes.iter().any(inside),
                        "seed {seed}: pixel ({x}, {y}) = {} is in no hazard's box",
                        image.get(x, y)
                    );
                    for (k, l) in frame.labels.iter().enumerate() {
                        if inside(&l.bbox) {
                            differing_per_label[k].push((px, py));
                        }
                    }
                }
            }
            for (l, pixels) in frame.labels.iter().zip(&differing_per_label) {
                assert!(
                    !pixels.is_empty(),
                    "seed {seed}: {l:?} holds no hazard pixel"
                );
                labels_checked += 1;
                // A hazard well inside the image, alone in its box: the box is tight.
                let b = &l.bbox;
                let well_inside = b.x_min > 3.0
                    && b.y_min > 3.0
                    && b.x_max < image.width() as f64 - 3.0
                    && b.y_max < image.height() as f64 - 3.0;
                let alone = frame
                    .labels
                    .iter()
                    .filter(|o| overlaps(&o.bbox, b, 3.0))
                    .count()
                    == 1;
                if well_inside && alone {
                    let x_min = pixels.iter().map(|p| p.0 - 0.5).fold(f64::MAX, f64::min);
                    let x_max = pixels.iter().map(|p| p.0 + 0.5).fold(f64::MIN, f64::max);
                    let y_min = pixels.iter().map(|p| p.1 - 0.5).fold(f64::MAX, f64::min);
                    let y_max = pixels.iter().map(|p| p.1 + 0.5).fold(f64::MIN, f64::max);
                    for (drawn, labelled) in [
                        (x_min, b.x_min),
                        (x_max, b.x_max),
                        (y_min, b.y_min),
                        (y_max, b.y_max),
                    ] {
                        assert!(
                            (drawn - labelled).abs() <= 1.5,
                            "seed {seed}: {l:?} against the drawn box [{x_min}, {y_min}, {x_max}, {y_max}]"
                        );
                    }
                    tight_checked += 1;
                }
            }
            // Exactly the hazards whose centre is in view are labelled.
            let in_view = situation
                .hazards
                .iter()
                .filter(|h| {
                    let (u, v) = camera
                        .project_world(&pose, &Point3::new(h.north_m, h.east_m, 0.0))
                        .unwrap();
                    (0.0..640.0).contains(&(u + 0.5)) && (0.0..480.0).contains(&(v + 0.5))
                })
                .count();
            assert_eq!(frame.labels.len(), in_view, "seed {seed}");
            for c in &frame.cut_off {
                assert!(c.bbox.area() > 0.0, "seed {seed}: {c:?}");
                assert!(frame.labels.iter().all(|l| l.hazard_id != c.hazard_id));
            }
            cut_off_seen += frame.cut_off.len();
            frames_checked += 1;
        }
        assert_eq!(frames_checked, 40);
        assert!(labels_checked >= 60, "{labels_checked}");
        assert!(tight_checked >= 30, "{tight_checked}");
        assert!(cut_off_seen >= 3, "{cut_off_seen}");
    }

    #[test]
    fn the_same_seed_gives_the_same_frame_and_seeds_differ() {
        let a = render_labelled_frame(11).unwrap();
        assert_eq!(a, render_labelled_frame(11).unwrap());
        assert_ne!(a.image, render_labelled_frame(12).unwrap().image);
    }

    #[test]
    fn situations_span_the_mission_heights_tilts_and_contents() {
        let situations: Vec<Situation> = (0..400).map(|s| draw_situation(s).unwrap()).collect();
        let altitudes_m: Vec<f64> = situations
            .iter()
            .map(|s| -s.vehicle.position_ned_m.z)
            .collect();
        assert!(altitudes_m.iter().all(|a| (4.0..=12.0).contains(a)));
        let typical = altitudes_m
            .iter()
            .filter(|a| (6.0..=9.0).contains(*a))
            .count();
        // 60 % drawn in 6–9 m plus 3/8 of the other 40 %: 75 %.
        assert!((260..=340).contains(&typical), "{typical}");
        for s in &situations {
            let a = s.vehicle.attitude;
            assert!(a.roll_rad.abs() <= MAX_TILT_DEG.to_radians());
            assert!(a.pitch_rad.abs() <= MAX_TILT_DEG.to_radians());
            assert!(s.hazards.len() <= MAX_HAZARDS_PER_FRAME);
        }
        // Leans from calm to 12 m/s gusts alike: uniform in 0–35°, so about 3/7 beyond 20°
        // and 2/7 within 10°.
        let leans_deg: Vec<f64> = situations
            .iter()
            .map(|s| {
                let a = s.vehicle.attitude;
                a.roll_rad.hypot(a.pitch_rad).to_degrees()
            })
            .collect();
        let beyond_20 = leans_deg.iter().filter(|l| **l > 20.0).count();
        let within_10 = leans_deg.iter().filter(|l| **l < 10.0).count();
        assert!((140..=205).contains(&beyond_20), "{beyond_20}");
        assert!((85..=145).contains(&within_10), "{within_10}");
        let with_pad = situations.iter().filter(|s| s.pad.is_some()).count();
        assert!((160..=240).contains(&with_pad), "{with_pad}");
        for class in HazardClass::ALL {
            let count = situations
                .iter()
                .flat_map(|s| &s.hazards)
                .filter(|h| h.class == class)
                .count();
            assert!(count > 150, "{class}: {count}");
        }
    }

    #[test]
    fn the_pad_is_in_view_and_no_hazard_lies_under_the_roof() {
        let camera = clean_camera().validate().unwrap();
        let mut pads = 0;
        for seed in 0..100u64 {
            let situation = draw_situation(seed).unwrap();
            let Some(pad) = situation.pad else { continue };
            pads += 1;
            let pose = SimCamera::pose(
                &situation.vehicle.position_ned_m,
                &situation.vehicle.attitude,
            );
            let centre = Point3::new(pad.north_m, pad.east_m, -pad.height_m);
            let (u, v) = camera.project_world(&pose, &centre).unwrap();
            assert!(camera.contains(u, v), "seed {seed}: pad at ({u}, {v})");
            let roof = roof_box_px(&camera, &pose, &pad, &TractorBody::default()).unwrap();
            for h in &situation.hazards {
                let b = hazard_box_px(&camera, &pose, h).unwrap();
                assert!(
                    !overlaps(&roof, &b, 0.0),
                    "seed {seed}: {h:?} under the roof"
                );
            }
            // The roof really is drawn there: its shade at the pad's edge, the pad's white inside.
            let frame = render_situation(
                &situation,
                &clean_camera(),
                Some(Texture::uniform(BACKGROUND)),
            )
            .unwrap();
            let roof_level = (TractorBody::default().intensity * 255.0 + 0.5) as u8;
            let (x0, x1) = (
                roof.x_min.max(0.0) as usize,
                (roof.x_max.min(640.0) as usize).min(639),
            );
            let (y0, y1) = (
                roof.y_min.max(0.0) as usize,
                (roof.y_max.min(480.0) as usize).min(479),
            );
            let roof_pixels = (y0..=y1)
                .flat_map(|y| (x0..=x1).map(move |x| (x, y)))
                .filter(|&(x, y)| frame.image.get(x, y) == roof_level)
                .count();
            assert!(roof_pixels > 100, "seed {seed}: {roof_pixels} roof pixels");
        }
        assert!(pads > 30, "{pads}");
    }
}
