//! `qosrt plan`: the offline energy plan of a mission — the QoS level of every task in every
//! phase, predicted power and energy, margin and endurance — as a table, JSON or an SVG plot.

use crate::check::report_failure;
use crate::plot::{frontier_svg, FrontierPlot, PlotError};
use power_models::planner::{pareto_frontier, solve, PhasePlan, Plan};
use runtime::catalog::PluginCatalog;
use runtime::config::{load_file, Knob, MissionConfig};
use runtime::energy::{energy_budget, load_mission_model, BudgetError, MissionModel};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use crate::check::EXIT_INVALID_CONFIG;
/// Exit status when no plan fits the battery.
pub const EXIT_INFEASIBLE: u8 = 3;

pub struct PlanArgs {
    pub file: PathBuf,
    pub battery_wh: Option<f64>,
    pub reserve_fraction: Option<f64>,
    pub json: bool,
    pub svg: Option<PathBuf>,
}

pub fn run(args: &PlanArgs) -> ExitCode {
    let loaded = match load_file(&args.file, &PluginCatalog::builtin()) {
        Ok(loaded) => loaded,
        Err(failure) => {
            report_failure(&failure, args.json);
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    let model = match load_mission_model(&loaded) {
        Ok(model) => model,
        Err(reports) => {
            for report in &reports {
                report_failure(report, args.json);
            }
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    for warning in &model.warnings {
        eprint!(
            "{}",
            warning.render(&loaded.path.display().to_string(), &loaded.source)
        );
    }
    let report = match plan_report(&model, args) {
        Ok(report) => report,
        Err(error) => {
            eprintln!("error: {error}");
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    if let Some(svg_path) = &args.svg {
        if let Err(error) = write_frontier_svg(&report, &model.config, svg_path) {
            eprintln!("error: {error}");
            return ExitCode::FAILURE;
        }
    }
    crate::output::print_result(args.json, &report, |report| {
        human_report(report, &model.config, &args.file)
    });
    if report.feasible {
        ExitCode::SUCCESS
    } else {
        if !args.json {
            eprintln!(
                "error: no plan fits: even the lowest QoS levels need {:.2} Wh, but only {:.2} Wh are available above the reserve (short by {:.2} Wh)",
                report.energy_wh, report.available_wh, report.energy_wh - report.available_wh
            );
        }
        ExitCode::from(EXIT_INFEASIBLE)
    }
}

/// The plan and everything a person or a program needs to judge it.
#[derive(Debug, Serialize)]
pub struct PlanReport {
    pub mission: String,
    pub feasible: bool,
    /// Σ weight × utility of the chosen levels, and the most any plan could earn.
    pub utility: f64,
    pub max_utility: f64,
    pub energy_wh: f64,
    pub available_wh: f64,
    pub battery_nominal_wh: f64,
    /// What the pack delivers at the mission's power before the cutoff voltage.
    pub battery_usable_wh: f64,
    pub reserve_fraction: f64,
    pub reserve_wh: f64,
    pub margin_wh: f64,
    pub duration_s: f64,
    /// How long the pack would carry the plan's mean power down to the reserve.
    pub endurance_s: f64,
    /// Energy the cheapest plan needs; with `feasible: false`, the shortfall is
    /// `energy_wh − available_wh`.
    pub min_energy_wh: f64,
    pub phases: Vec<PhaseReport>,
    /// Tasks whose power no profile models: their level costs nothing in the plan.
    pub unmodelled_tasks: Vec<String>,
    pub pareto_frontier: Vec<FrontierPoint>,
}

#[derive(Debug, Serialize)]
pub struct PhaseReport {
    pub name: String,
    pub duration_s: f64,
    /// Task name → chosen knob value.
    pub levels: BTreeMap<String, f64>,
    pub companion_power_w: f64,
    pub flight_power_w: f64,
    pub energy_wh: f64,
    pub utility: f64,
}

#[derive(Debug, Serialize)]
pub struct FrontierPoint {
    pub energy_wh: f64,
    pub utility: f64,
}

/// Why no plan report: a bad argument, or the planner's or the battery's error.
#[derive(Debug, thiserror::Error)]
enum PlanReportError {
    #[error("--reserve must be a fraction within [0, 1), found {0}")]
    Reserve(f64),
    #[error("--battery-wh must be a positive energy, found {0}")]
    BatteryWh(f64),
    #[error(transparent)]
    Budget(#[from] BudgetError),
}

fn plan_report(model: &MissionModel, args: &PlanArgs) -> Result<PlanReport, PlanReportError> {
    let config = &model.config;
    let reserve_fraction = args
        .reserve_fraction
        .unwrap_or(config.mission.reserve_fraction);
    if !(0.0..1.0).contains(&reserve_fraction) {
        return Err(PlanReportError::Reserve(reserve_fraction));
    }
    if let Some(wh) = args.battery_wh {
        if !(wh.is_finite() && wh > 0.0) {
            return Err(PlanReportError::BatteryWh(wh));
        }
    }
    let problem = model.plan_problem();
    let frontier = pareto_frontier(&problem).map_err(BudgetError::Plan)?;
    let spec = model
        .battery_spec(args.battery_wh)
        .map_err(BudgetError::Battery)?;
    let budget = energy_budget(&problem, &spec, reserve_fraction)?;
    let usable_wh = budget.usable_wh;
    let available_wh = budget.available_wh;
    let plan = solve(&problem, available_wh).map_err(BudgetError::Plan)?;
    Ok(report_of(
        model,
        &plan,
        &frontier
            .iter()
            .map(|p| FrontierPoint {
                energy_wh: p.energy_wh,
                utility: p.utility,
            })
            .collect::<Vec<_>>(),
        spec.nominal_energy_wh(),
        usable_wh,
        reserve_fraction,
    ))
}

fn report_of(
    model: &MissionModel,
    plan: &Plan,
    frontier: &[FrontierPoint],
    battery_nominal_wh: f64,
    battery_usable_wh: f64,
    reserve_fraction: f64,
) -> PlanReport {
    let config = &model.config;
    let reserve_wh = battery_usable_wh * reserve_fraction;
    let available_wh = battery_usable_wh - reserve_wh;
    let duration_s: f64 = plan.phases.iter().map(|p| p.duration_s).sum();
    let mean_power_w = plan.energy_wh * 3600.0 / duration_s.max(1e-9);
    let max_utility: f64 = config
        .mission
        .phases
        .iter()
        .flat_map(|phase| config.tasks.iter().filter(|t| t.runs_in(&phase.name)))
        .map(|task| task.weight * task.utility.iter().copied().fold(0.0, f64::max))
        .sum();
    let modelled: Vec<&String> = model
        .profiles
        .iter()
        .flat_map(|p| &p.profile.knobs)
        .collect();
    PlanReport {
        mission: config.mission.name.clone(),
        feasible: plan.feasible,
        utility: plan.utility,
        max_utility,
        energy_wh: plan.energy_wh,
        available_wh,
        battery_nominal_wh,
        battery_usable_wh,
        reserve_fraction,
        reserve_wh,
        margin_wh: available_wh - plan.energy_wh,
        duration_s,
        endurance_s: available_wh / mean_power_w * 3600.0,
        min_energy_wh: plan.min_energy_wh,
        phases: plan
            .phases
            .iter()
            .map(|p| phase_report(config, p))
            .collect(),
        unmodelled_tasks: config
            .tasks
            .iter()
            .filter(|task| !modelled.contains(&&task.knob_name()))
            .map(|task| task.name.clone())
            .collect(),
        pareto_frontier: frontier
            .iter()
            .map(|p| FrontierPoint {
                energy_wh: p.energy_wh,
                utility: p.utility,
            })
            .collect(),
    }
}

fn phase_report(config: &MissionConfig, phase: &PhasePlan) -> PhaseReport {
    PhaseReport {
        name: phase.name.clone(),
        duration_s: phase.duration_s,
        levels: phase
            .levels
            .iter()
            .map(|chosen| {
                let task = &config.tasks[chosen.task];
                (task.name.clone(), task.levels[chosen.level])
            })
            .collect(),
        companion_power_w: phase.companion_power_w,
        flight_power_w: phase.flight_power_w,
        energy_wh: phase.energy_wh,
        utility: phase.utility,
    }
}

fn knob_text(knob: Knob, value: f64) -> String {
    let number = format!("{value:.3}");
    let number = number.trim_end_matches('0').trim_end_matches('.');
    match knob {
        Knob::RateFps => format!("{number} fps"),
        Knob::PeriodMs => format!("{number} ms"),
    }
}

fn human_report(report: &PlanReport, config: &MissionConfig, file: &Path) -> String {
    let mut out = format!(
        "plan for mission `{}` ({})\n",
        report.mission,
        file.display()
    );
    out += &format!(
        "battery: {:.1} Wh nominal, {:.1} Wh usable at the mission's power; reserve {:.0} % ({:.1} Wh) → {:.2} Wh available\n\n",
        report.battery_nominal_wh,
        report.battery_usable_wh,
        report.reserve_fraction * 100.0,
        report.reserve_wh,
        report.available_wh
    );
    let mut header = format!("{:<10} {:>8}", "phase", "duration");
    for task in &config.tasks {
        header += &format!(" {:>10}", task.name);
    }
    header += &format!(" {:>10} {:>9} {:>9}", "companion", "flight", "energy");
    out += &header;
    out += "\n";
    for phase in &report.phases {
        let mut row = format!("{:<10} {:>6.0} s", phase.name, phase.duration_s);
        for task in &config.tasks {
            let cell = phase
                .levels
                .get(&task.name)
                .map_or("—".to_string(), |value| knob_text(task.knob, *value));
            row += &format!(" {cell:>10}");
        }
        row += &format!(
            " {:>8.2} W {:>7.1} W {:>6.2} Wh",
            phase.companion_power_w, phase.flight_power_w, phase.energy_wh
        );
        out += &row;
        out += "\n";
    }
    out += &format!(
        "{:<10} {:>6.0} s {:>width$} {:>6.2} Wh\n\n",
        "total",
        report.duration_s,
        "",
        report.energy_wh,
        width = config.tasks.len() * 11 + 21
    );
    if report.feasible {
        out += &format!(
            "utility {:.2} of {:.2} possible; margin {:.2} Wh; endurance {:.0} s at the plan's mean power ({:.0} s planned)\n",
            report.utility, report.max_utility, report.margin_wh, report.endurance_s, report.duration_s
        );
    } else {
        out += "INFEASIBLE: the table shows the cheapest plan\n";
    }
    if !report.unmodelled_tasks.is_empty() {
        out += &format!(
            "not in the power model (their level costs nothing here): {}\n",
            report.unmodelled_tasks.join(", ")
        );
    }
    out
}

fn write_frontier_svg(
    report: &PlanReport,
    config: &MissionConfig,
    path: &Path,
) -> Result<(), PlotError> {
    let frontier: Vec<(f64, f64)> = report
        .pareto_frontier
        .iter()
        .map(|p| (p.energy_wh, p.utility))
        .collect();
    let title = format!(
        "{}: QoS utility against mission energy",
        config.mission.name
    );
    let svg = frontier_svg(&FrontierPlot {
        title: &title,
        frontier: &frontier,
        budget_wh: report.available_wh,
        chosen: report
            .feasible
            .then_some((report.energy_wh, report.utility)),
    })?;
    crate::plot::write_text(path, &svg)
}
