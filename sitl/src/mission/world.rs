//! Building the simulated world from the mission: powers, wind, camera, pad, track.

use super::*;
use algorithms::estimation::camera_mount::CameraMount;
use sim::power::{SimBattery, SimPack};
use sim::world::Body;

/// The rotors' hover power: the config's, or without one the first phase's flight power.
pub(crate) fn hover_power_w(model: &MissionModel) -> Option<f64> {
    let config = &model.config;
    config.flight.hover_power_w.or_else(|| {
        config
            .mission
            .phases
            .iter()
            .find_map(|p| config.flight.power_w(&p.name))
    })
}

/// The world's pack, with the config's capacity, cells and resistance, and the rotors' power at
/// the config's hover power.
pub(crate) fn pack_and_rotors(
    model: &MissionModel,
) -> Result<(SimBattery, RotorPowerModel), Cause> {
    let spec = model.battery_spec(None)?;
    let pack = SimPack::new(
        spec.capacity_mah,
        spec.cell_count,
        spec.internal_resistance_ohm,
    )?;
    let hover_power_w = hover_power_w(model).ok_or("[flight] gives no hover_power_w")?;
    let rotors = RotorPowerModel::iris(hover_power_w);
    rotors.validate()?;
    Ok((SimBattery::new(pack), rotors))
}

/// What the rotors draw now: by the vehicle's airspeed and climb rate while it flies. The wind
/// is asked every tick, flying or not: its gusts advance with each query.
pub(crate) fn flight_power_w(
    vehicle: &impl Body,
    wind: &mut Wind,
    rotors: &RotorPowerModel,
    time_s: f64,
) -> f64 {
    let velocity = vehicle.velocity_ned_m_s();
    let air = velocity - wind.wind_velocity_ned_m_s(time_s, -vehicle.position_ned_m().z);
    if vehicle.is_flying() {
        rotors.power_w(air.xy().norm(), -velocity.z)
    } else {
        0.0
    }
}

/// The mission's `[camera]` as the world renders it (10 fps without a declared rate, like the
/// seed's).
pub(crate) fn camera_config(model: &MissionModel) -> SimCameraConfig {
    let camera = model.config.camera_settings();
    let mut config = SimCameraConfig {
        horizontal_fov_deg: camera.horizontal_fov_deg,
        width_px: camera.width_px,
        height_px: camera.height_px,
        ..SimCameraConfig::default()
    };
    if let Some(rate_fps) = camera.rate_fps {
        config.rate_fps = rate_fps;
    }
    config
}

/// The camera's gimbal, when `[camera]` puts the camera on one (`mount = "gimbal"`): the
/// world then carries one and its autopilot reports it.
pub(crate) fn camera_gimbal(model: &MissionModel) -> Result<Option<Gimbal>, GimbalError> {
    (model.config.camera_settings().mount == CameraMount::Gimbal)
        .then(|| Gimbal::new(GimbalParams::default()))
        .transpose()
}

/// The sequencer's plan from the config (its tracking time already the one to fly), with the
/// simulated world's meeting point and pad height.
pub(super) fn mission_plan(
    model: &MissionModel,
    meeting: [f64; 2],
    pad_height_m: f64,
) -> MissionPlan {
    let mut plan = MissionPlan::for_mission(&model.config);
    plan.cruise_altitude_m += pad_height_m;
    plan.meeting_point_ne_m = meeting;
    plan
}

/// Where the tractor will drive in the next `duration_s`: its track sampled every half second,
/// from a copy driven ahead (the tractor is deterministic).
pub(super) fn future_track_ne_m(
    tractor: &Tractor,
    duration_s: f64,
) -> Result<Vec<[f64; 2]>, sim::tractor::TractorError> {
    const SAMPLE_S: f64 = 0.5;
    let mut ahead = tractor.clone();
    let mut track = vec![ahead.pose().position_ne_m.into()];
    let samples = (duration_s.max(0.0) / SAMPLE_S).ceil() as usize;
    for _ in 0..samples {
        // The same step as the flight's physics, so the copy drives the same track.
        for _ in 0..(SAMPLE_S / PHYSICS_DT_S).round() as usize {
            ahead.step(PHYSICS_DT_S)?;
        }
        track.push(ahead.pose().position_ne_m.into());
    }
    Ok(track)
}

/// The seed's 32 hazards on a track of at least [`FULL_HAZARD_TRACK_M`]; proportionally fewer
/// on a shorter one, so a short test flight is not crowded.
pub(super) fn track_scatter(track_ne_m: &[[f64; 2]]) -> TrackScatterConfig {
    let full = TrackScatterConfig::default();
    let length_m: f64 = track_ne_m
        .windows(2)
        .map(|p| (p[1][0] - p[0][0]).hypot(p[1][1] - p[0][1]))
        .sum();
    let usable = ((length_m - full.skip_start_m) / FULL_HAZARD_TRACK_M).clamp(0.0, 1.0);
    TrackScatterConfig {
        count_per_class: full
            .count_per_class
            .map(|count| (count as f64 * usable).floor() as usize),
        ..full
    }
}

/// Track length that holds the full set of hazards (one every ~9 m).
pub const FULL_HAZARD_TRACK_M: f64 = 290.0;

pub(crate) fn pad_pose(tractor: &Tractor) -> PadPose {
    let pad = tractor.pad();
    PadPose {
        north_m: pad.centre_ned_m.x,
        east_m: pad.centre_ned_m.y,
        height_m: -pad.centre_ned_m.z,
        yaw_rad: pad.yaw_rad,
    }
}

/// What lies on the pad for this seed: with probability `occluded_fraction` one square of
/// `occluder_size_m` somewhere over the marker, dark (mud, a shadow's edge) or light (straw).
pub(super) fn pad_occluders(camera: &CameraRealism, seed: u64) -> Vec<PadOccluder> {
    let mut rng = SplitMix64::new(seed ^ 0x6f63_636c_7564_6572);
    if camera.occluder_size_m <= 0.0 || rng.next_f64() >= camera.occluded_fraction {
        return Vec::new();
    }
    let mut within = |half_m: f64| half_m * (2.0 * rng.next_f64() - 1.0);
    let forward_m = within(0.35);
    let right_m = within(0.35);
    let yaw_rad = within(std::f64::consts::FRAC_PI_4);
    let intensity = if rng.next_f64() < 0.5 { 0.2 } else { 0.85 };
    vec![PadOccluder {
        forward_m,
        right_m,
        yaw_rad,
        size_m: camera.occluder_size_m,
        intensity,
    }]
}

#[cfg(test)]
mod tests {
    use super::*;
    use runtime::catalog::PluginCatalog;
    use runtime::config::{load_str, LoadedConfig};
    use runtime::energy::load_mission_model;

    /// The reference mission with its `[camera]` keys replaced as `edits` say.
    fn reference_with(edits: &[(&str, &str)]) -> MissionModel {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let mut text = std::fs::read_to_string(dir.join("qos.toml")).unwrap();
        for (from, to) in edits {
            assert!(text.contains(from), "{from}");
            text = text.replacen(from, to, 1);
        }
        let config = load_str(&text, Some(&dir), &PluginCatalog::builtin()).unwrap();
        let loaded = LoadedConfig {
            path: dir.join("qos.toml"),
            source: text,
            config,
        };
        load_mission_model(&loaded).unwrap()
    }

    /// The world renders the mission's one camera and hangs it where `[camera]` says: the
    /// same values the tasks project with.
    #[test]
    fn the_simulated_camera_is_the_missions_camera() {
        let model = reference_with(&[
            ("horizontal_fov_deg = 60.0", "horizontal_fov_deg = 80.0"),
            ("width_px = 640", "width_px = 320"),
            ("height_px = 480", "height_px = 240"),
            (
                "rate_fps = 10.0\n# The downward",
                "rate_fps = 4.0\n# The downward",
            ),
        ]);
        let config = camera_config(&model);
        assert_eq!((config.width_px, config.height_px), (320, 240));
        assert_eq!((config.horizontal_fov_deg, config.rate_fps), (80.0, 4.0));
        let tracking = model.config.task("tracking").unwrap();
        assert_eq!(tracking.camera.width_px, 320);
        assert!(camera_gimbal(&model).unwrap().is_some());
        let on_body = reference_with(&[("mount = \"gimbal\"", "mount = \"body\"")]);
        assert!(camera_gimbal(&on_body).unwrap().is_none());
        assert_eq!(
            on_body.config.task("landing").unwrap().camera.mount,
            CameraMount::Body
        );
    }
}
