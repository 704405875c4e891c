//! Building the simulated world from the mission: powers, wind, camera, pad, track.

use super::*;
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

/// The camera the tracker's params describe (field of view and image size: the
/// `kalman_tracker`'s, else the `hybrid_tracking`'s), at `[camera] rate_fps`, else 10 fps like
/// the seed's.
pub(crate) fn camera_config(model: &MissionModel) -> SimCameraConfig {
    let mut config = SimCameraConfig::default();
    if let Some(rate_fps) = model.config.camera.as_ref().and_then(|c| c.rate_fps) {
        config.rate_fps = rate_fps;
    }
    let number = |key| {
        let config = &model.config;
        config
            .plugin_number("kalman_tracker", key)
            .or_else(|| config.plugin_number("hybrid_tracking", key))
    };
    if let Some(fov) = number("camera_horizontal_fov_deg") {
        config.horizontal_fov_deg = fov;
    }
    if let Some(width) = number("image_width_px") {
        config.width_px = width as usize;
    }
    if let Some(height) = number("image_height_px") {
        config.height_px = height as usize;
    }
    config
}

/// The camera's gimbal, when the tracker's params put the camera on one
/// (`camera_mount = "gimbal"`): the world then carries one and its autopilot reports it.
pub(crate) fn camera_gimbal(model: &MissionModel) -> Result<Option<Gimbal>, GimbalError> {
    let on_gimbal = model.config.tasks.iter().any(|task| {
        matches!(task.plugin.as_str(), "kalman_tracker" | "hybrid_tracking")
            && task.params.get("camera_mount").and_then(|v| v.as_str()) == Some("gimbal")
    });
    on_gimbal
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
