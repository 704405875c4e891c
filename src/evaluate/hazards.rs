//! `qosrt sim --evaluate-hazards`: the seed's hazard experiment, every hazard-CNN rate × wind.

use super::fly::fly_cells;
use crate::check::EXIT_INVALID_CONFIG;
use crate::sim::args::SimArgs;
use runtime::energy::MissionModel;
use runtime::registry::PluginRegistry;
use sim::world::WorldOptions;
use sitl::mission::SimOptions;
use sitl::outcome::SimOutcome;
use std::process::ExitCode;

/// The tracking phase of a hazard evaluation: 300 m of track at 1.5 m/s, room for the seed's 32
/// hazards.
const HAZARD_EVALUATION_TRACKING_S: f64 = 200.0;

/// The seed's hazard experiment: every hazard-CNN rate × wind, `args.runs` seeds per cell.
pub fn evaluate_hazards(
    model: &MissionModel,
    registry: &PluginRegistry,
    args: &SimArgs,
) -> ExitCode {
    let Some(hazard) = model.config.tasks.iter().find(|t| t.plugin == "hazard_cnn") else {
        eprintln!("error: --evaluate-hazards needs a hazard_cnn task in the config");
        return ExitCode::from(EXIT_INVALID_CONFIG);
    };
    let mut cells = Vec::new();
    for &rate in &hazard.levels {
        for wind_m_s in [0.0, 8.0, 12.0] {
            cells.push((rate, wind_m_s));
        }
    }
    let results = fly_cells(model, registry, &cells, args, |&(rate, wind_m_s), seed| {
        let mut fixed_levels = args.fixed_levels.clone();
        fixed_levels.push((hazard.name.clone(), rate));
        let options = args.options(seed);
        SimOptions {
            world: WorldOptions {
                wind_speed_m_s: wind_m_s,
                ..options.world
            },
            tracking_s: Some(args.tracking_s.unwrap_or(HAZARD_EVALUATION_TRACKING_S)),
            fixed_levels,
            record_track: false,
            ..options
        }
    });
    let Ok(results) = results else {
        return ExitCode::FAILURE;
    };
    let rows: Vec<HazardRow> = cells
        .iter()
        .zip(&results)
        .map(|(&(rate_fps, wind_m_s), outcomes)| HazardRow::of(rate_fps, wind_m_s, outcomes))
        .collect();
    crate::output::print_result(args.json, &rows, |rows| hazard_table(rows, args));
    ExitCode::SUCCESS
}

/// One cell of the hazard evaluation, over its seeds.
#[derive(serde::Serialize)]
struct HazardRow {
    rate_fps: f64,
    wind_m_s: f64,
    runs: usize,
    seen: usize,
    total: usize,
    false_detections_per_run: f64,
    frames_per_run: f64,
    companion_energy_mean_wh: f64,
    landed_fraction: f64,
    backend: String,
}

impl HazardRow {
    fn of(rate_fps: f64, wind_m_s: f64, outcomes: &[SimOutcome]) -> Self {
        let runs = outcomes.len();
        let per_run = |f: &dyn Fn(&SimOutcome) -> f64| {
            outcomes.iter().map(f).sum::<f64>() / runs.max(1) as f64
        };
        Self {
            rate_fps,
            wind_m_s,
            runs,
            seen: outcomes.iter().filter_map(|o| o.hazards_seen).sum(),
            total: outcomes.iter().map(|o| o.hazards_total).sum(),
            false_detections_per_run: per_run(&|o| o.hazard_false_detections as f64),
            frames_per_run: per_run(&|o| o.hazard_frames as f64),
            companion_energy_mean_wh: per_run(&|o| o.companion_energy_wh),
            landed_fraction: per_run(&|o| f64::from(u8::from(o.landed_on_pad))),
            backend: outcomes
                .iter()
                .find_map(|o| o.hazard_backend.clone())
                .unwrap_or_else(|| "none".into()),
        }
    }
}

fn hazard_table(rows: &[HazardRow], args: &SimArgs) -> String {
    let mut out = format!(
        "{} seeds per cell from seed {}, straight path, tractor at {} m/s, {} wind\n\n",
        args.runs(),
        args.seed,
        args.platform_speed_m_s,
        if args.dryden { "Dryden" } else { "gust" }
    );
    out += "| hazard CNN rate (fps) | wind (m/s) | hazards seen | seen per run | false detections per run | frames per run | companion energy (Wh) | landed |\n";
    out += "| --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for r in rows {
        let share = if r.total == 0 {
            0.0
        } else {
            r.seen as f64 / r.total as f64
        };
        out += &format!(
            "| {} | {} | {}/{} ({:.0} %) | {:.1} of {:.0} | {:.1} | {:.0} | {:.3} | {:.0} % |\n",
            r.rate_fps,
            r.wind_m_s,
            r.seen,
            r.total,
            100.0 * share,
            r.seen as f64 / r.runs.max(1) as f64,
            r.total as f64 / r.runs.max(1) as f64,
            r.false_detections_per_run,
            r.frames_per_run,
            r.companion_energy_mean_wh,
            100.0 * r.landed_fraction
        );
    }
    if let Some(backend) = rows.first().map(|r| &r.backend) {
        out += &format!("\nhazard CNN backend: {backend}\n");
    }
    out
}
