//! `qosrt sim --evaluate-paths`: seed 000's path trials, every path × tractor speed.

use super::fly::fly_cells;
use crate::sim::args::SimArgs;
use runtime::energy::MissionModel;
use runtime::registry::PluginRegistry;
use sim::tractor::PathKind;
use sim::world::WorldOptions;
use sitl::mission::SimOptions;
use sitl::outcome::{SimOutcome, SimSummary};
use std::process::ExitCode;

/// The tracking phase of a path trial, at least: the S, the circle and the figure-eight curve
/// from their start, and 30 s is enough for the follower to settle at IH.
const PATH_TRIAL_TRACKING_S: f64 = 30.0;

/// A path trial's tracking phase: [`PATH_TRIAL_TRACKING_S`], or longer where the path's first
/// turn lies further on (the rectangle's first corner, 20 m on), so that the follower turns
/// with the UGV 5 s before the landing begins.
fn trial_tracking_s(path: PathKind, speed_m_s: f64) -> f64 {
    let to_turn_s = path
        .first_turn_m()
        .filter(|_| speed_m_s > 0.0)
        .map_or(0.0, |m| m / speed_m_s + 5.0);
    PATH_TRIAL_TRACKING_S.max(to_turn_s)
}

/// Seed 000's paths and UGV speeds (§3.1).
const TRIAL_PATHS: [PathKind; 5] = [
    PathKind::Straight,
    PathKind::SShape,
    PathKind::Rectangle,
    PathKind::Circle,
    PathKind::FigureEight,
];
const TRIAL_SPEEDS_M_S: [f64; 3] = [0.2, 0.5, 0.8];

/// One cell of the path trials, over its seeds.
#[derive(Debug, serde::Serialize)]
struct PathRow {
    path: String,
    ugv_speed_m_s: f64,
    runs: usize,
    success_rate: f64,
    /// Horizontal localisation error while tracking: RMS over every sample of every run, and
    /// the largest.
    localisation_rms_m: Option<f64>,
    localisation_max_m: Option<f64>,
    /// Height-above-pad error, RMS over every sample.
    altitude_rms_m: Option<f64>,
    /// The platform-velocity estimate's error, RMS over every sample that had one.
    platform_velocity_rms_m_s: Option<f64>,
    touchdown_error_p50_m: Option<f64>,
    touchdown_error_max_m: Option<f64>,
    time_to_land_p50_s: Option<f64>,
}

impl PathRow {
    fn of(path: PathKind, ugv_speed_m_s: f64, outcomes: &[SimOutcome]) -> Self {
        let summary = SimSummary::of(outcomes);
        let localised: Vec<_> = outcomes.iter().filter_map(|o| o.localisation).collect();
        let samples: usize = localised.iter().map(|l| l.samples).sum();
        let pooled = |f: &dyn Fn(&sitl::outcome::LocalisationError) -> f64| {
            (samples > 0).then(|| {
                (localised
                    .iter()
                    .map(|l| l.samples as f64 * f(l).powi(2))
                    .sum::<f64>()
                    / samples as f64)
                    .sqrt()
            })
        };
        let with_velocity: Vec<(usize, f64)> = localised
            .iter()
            .filter_map(|l| l.platform_velocity_rms_m_s.map(|v| (l.samples, v)))
            .collect();
        let velocity_samples: usize = with_velocity.iter().map(|(n, _)| n).sum();
        let touchdown_errors: Vec<f64> = outcomes
            .iter()
            .filter(|o| o.landed_on_pad)
            .filter_map(|o| o.touchdown_error_m)
            .collect();
        Self {
            path: path.to_string(),
            ugv_speed_m_s,
            runs: summary.runs,
            success_rate: summary.success_rate,
            localisation_rms_m: pooled(&|l| l.horizontal_rms_m),
            localisation_max_m: localised
                .iter()
                .map(|l| l.horizontal_max_m)
                .reduce(f64::max),
            altitude_rms_m: pooled(&|l| l.vertical_rms_m),
            platform_velocity_rms_m_s: (velocity_samples > 0).then(|| {
                (with_velocity
                    .iter()
                    .map(|&(n, v)| n as f64 * v * v)
                    .sum::<f64>()
                    / velocity_samples as f64)
                    .sqrt()
            }),
            touchdown_error_p50_m: summary.touchdown_error_p50_m,
            touchdown_error_max_m: touchdown_errors.into_iter().reduce(f64::max),
            time_to_land_p50_s: summary.time_to_land_p50_s,
        }
    }
}

/// Seed 000's simulated trials: every path × UGV speed, `args.runs` seeds per cell, following
/// at the landing task's IH with the marker detector at its top rate.
pub fn evaluate_paths(model: &MissionModel, registry: &PluginRegistry, args: &SimArgs) -> ExitCode {
    let mut fixed_levels = args.fixed_levels.clone();
    if let Some(detection) = model
        .config
        .tasks
        .iter()
        .find(|t| t.plugin == "landing_marker")
    {
        if !fixed_levels.iter().any(|(name, _)| *name == detection.name) {
            if let Some(&top) = detection.levels.last() {
                fixed_levels.push((detection.name.clone(), top));
            }
        }
    }
    let mut cells = Vec::new();
    for path in TRIAL_PATHS {
        for speed_m_s in TRIAL_SPEEDS_M_S {
            cells.push((path, speed_m_s));
        }
    }
    let started = std::time::Instant::now();
    let results = fly_cells(model, registry, &cells, args, |&(path, speed_m_s), seed| {
        let options = args.options(seed);
        SimOptions {
            world: WorldOptions {
                path,
                platform_speed_m_s: speed_m_s,
                ..options.world
            },
            tracking_s: Some(
                args.tracking_s
                    .unwrap_or_else(|| trial_tracking_s(path, speed_m_s)),
            ),
            fixed_levels: fixed_levels.clone(),
            record_track: false,
            ..options
        }
    });
    let Ok(results) = results else {
        return ExitCode::FAILURE;
    };
    let wall_s = started.elapsed().as_secs_f64();
    let rows: Vec<PathRow> = cells
        .iter()
        .zip(&results)
        .map(|(&(path, speed), outcomes)| PathRow::of(path, speed, outcomes))
        .collect();
    crate::output::print_result(args.json, &rows, |rows| path_table(rows, args, wall_s));
    ExitCode::SUCCESS
}

fn path_table(rows: &[PathRow], args: &SimArgs, wall_s: f64) -> String {
    let metres = |v: Option<f64>| v.map_or_else(|| "—".into(), |v| format!("{v:.3}"));
    let tracking = args.tracking_s.map_or_else(
        || format!("tracking {PATH_TRIAL_TRACKING_S} s (the rectangle's until 5 s past its first corner)"),
        |s| format!("tracking {s} s"),
    );
    let mut out = format!(
        "{} seeds per cell from seed {}, {tracking}, wind {} m/s; {} missions in {:.0} s\n\n",
        args.runs(),
        args.seed,
        args.wind_m_s,
        rows.iter().map(|r| r.runs).sum::<usize>(),
        wall_s
    );
    out += "| path | UGV speed (m/s) | success | localisation RMS / max (m) | altitude RMS (m) | UGV velocity RMS (m/s) | touchdown error p50 / max (m) | time to land p50 (s) |\n";
    out += "| --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for r in rows {
        out += &format!(
            "| {} | {} | {:.0} % | {} / {} | {} | {} | {} / {} | {} |\n",
            r.path,
            r.ugv_speed_m_s,
            100.0 * r.success_rate,
            metres(r.localisation_rms_m),
            metres(r.localisation_max_m),
            metres(r.altitude_rms_m),
            metres(r.platform_velocity_rms_m_s),
            metres(r.touchdown_error_p50_m),
            metres(r.touchdown_error_max_m),
            r.time_to_land_p50_s
                .map_or_else(|| "—".into(), |v| format!("{v:.1}"))
        );
    }
    out
}
