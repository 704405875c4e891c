//! `qosrt check`: validate a config, then summarise it for a person or as JSON.

use crate::output::print_json;
use runtime::catalog::PluginCatalog;
use runtime::config::{load_file, ConfigFailure, LoadedConfig, MissionConfig, PhaseKind};
use runtime::dataflow::{task_graph, TaskGraph};
use serde::Serialize;
use std::path::Path;
use std::process::ExitCode;

/// Exit status for a config with mistakes.
pub const EXIT_INVALID_CONFIG: u8 = 2;

/// How `--graph` prints the task graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum GraphFormat {
    Text,
    Dot,
}

pub fn run(file: &Path, json: bool, graph: Option<GraphFormat>) -> ExitCode {
    let catalog = PluginCatalog::builtin();
    match load_file(file, &catalog) {
        Ok(loaded) => {
            let tasks = task_graph(&loaded.config, &catalog);
            match (graph, json) {
                (Some(GraphFormat::Dot), _) => {
                    print!("{}", tasks.render_dot(&loaded.config.mission.name))
                }
                (Some(GraphFormat::Text), true) => print_json(&tasks),
                (Some(GraphFormat::Text), false) => print!("{}", tasks.render_text()),
                (None, true) => print_json(&Summary::of(&loaded, tasks)),
                (None, false) => print!("{}", human_summary(&loaded, tasks)),
            }
            ExitCode::SUCCESS
        }
        Err(failure) => {
            report_failure(&failure, json);
            ExitCode::from(EXIT_INVALID_CONFIG)
        }
    }
}

/// Prints a config's diagnostics: located text on stderr, or JSON on stdout.
pub fn report_failure(failure: &ConfigFailure, json: bool) {
    if json {
        let file = failure.path.display().to_string();
        let errors: Vec<_> = failure
            .diagnostics
            .iter()
            .map(|d| d.to_record(&file, &failure.source))
            .collect();
        print_json(&serde_json::json!({ "valid": false, "errors": errors }));
    } else {
        eprint!("{}", failure.render());
        eprintln!(
            "{}: {} error(s)",
            failure.path.display(),
            failure.diagnostics.len()
        );
    }
}

#[derive(Serialize)]
struct Summary<'a> {
    valid: bool,
    file: String,
    mission: MissionSummary<'a>,
    battery: BatterySummary,
    phases: Vec<PhaseSummary<'a>>,
    power_model: &'a runtime::config::PowerModelConfig,
    tasks: Vec<TaskSummary<'a>>,
    /// Who feeds whom over the bus.
    graph: TaskGraph,
}

#[derive(Serialize)]
struct MissionSummary<'a> {
    name: &'a str,
    description: Option<&'a str>,
    reserve_fraction: f64,
}

#[derive(Serialize)]
struct BatterySummary {
    cell_count: u32,
    capacity_mah: Option<f64>,
    nominal_voltage_v: f64,
    capacity_wh: f64,
}

#[derive(Serialize)]
struct PhaseSummary<'a> {
    name: &'a str,
    /// As the file names it, else by position.
    kind: PhaseKind,
    duration_s: f64,
    duration_by_level: Option<&'a runtime::config::DurationByLevel>,
    flight_power_w: f64,
    tasks: Vec<&'a str>,
}

#[derive(Serialize)]
struct TaskSummary<'a> {
    name: &'a str,
    plugin: &'a str,
    resource: runtime::config::Resource,
    cores: &'a [usize],
    phases: &'a [String],
    weight: f64,
    knob: runtime::config::Knob,
    levels: Vec<LevelSummary>,
    /// `period`, or `input:TOPIC` with the levels as its rate cap.
    trigger: &'a runtime::config::TaskTrigger,
    max_idle_ms: Option<f64>,
    params: &'a toml::Table,
}

#[derive(Serialize)]
struct LevelSummary {
    value: f64,
    period_ms: f64,
    utility: f64,
}

impl<'a> Summary<'a> {
    fn of(loaded: &'a LoadedConfig, graph: TaskGraph) -> Self {
        let config: &MissionConfig = &loaded.config;
        let battery = &config.battery;
        Summary {
            valid: true,
            file: loaded.path.display().to_string(),
            mission: MissionSummary {
                name: &config.mission.name,
                description: config.mission.description.as_deref(),
                reserve_fraction: config.mission.reserve_fraction,
            },
            battery: BatterySummary {
                cell_count: battery.cell_count,
                capacity_mah: battery.capacity_mah,
                nominal_voltage_v: battery.nominal_voltage_v(),
                // A loaded config has passed validation, which requires a capacity.
                capacity_wh: battery.capacity_wh().unwrap_or(f64::NAN),
            },
            phases: config
                .mission
                .phases
                .iter()
                .zip(config.mission.phase_kinds())
                .map(|(phase, kind)| PhaseSummary {
                    name: &phase.name,
                    kind,
                    duration_s: phase.duration_s,
                    duration_by_level: phase.duration_by_level.as_ref(),
                    flight_power_w: config.flight.power_w(&phase.name).unwrap_or(f64::NAN),
                    tasks: config
                        .tasks
                        .iter()
                        .filter(|task| task.runs_in(&phase.name))
                        .map(|task| task.name.as_str())
                        .collect(),
                })
                .collect(),
            power_model: &config.power_model,
            tasks: config
                .tasks
                .iter()
                .map(|task| TaskSummary {
                    name: &task.name,
                    plugin: &task.plugin,
                    resource: task.resource,
                    cores: &task.cores,
                    phases: &task.phases,
                    weight: task.weight,
                    knob: task.knob,
                    trigger: &task.trigger,
                    max_idle_ms: task.max_idle_ms,
                    levels: task
                        .levels
                        .iter()
                        .zip(&task.utility)
                        .map(|(value, utility)| LevelSummary {
                            value: *value,
                            period_ms: task.knob.period_ms(*value),
                            utility: *utility,
                        })
                        .collect(),
                    params: &task.params,
                })
                .collect(),
            graph,
        }
    }
}

fn human_summary(loaded: &LoadedConfig, graph: TaskGraph) -> String {
    let summary = Summary::of(loaded, graph);
    let mut out = format!(
        "{}: valid\nmission `{}`{}\n  reserve at touchdown: {:.0} % of usable energy\n",
        summary.file,
        summary.mission.name,
        summary
            .mission
            .description
            .map(|d| format!(": {d}"))
            .unwrap_or_default(),
        summary.mission.reserve_fraction * 100.0
    );
    let battery = &summary.battery;
    out += &format!(
        "battery: {}S, {}{:.1} V nominal, {:.1} Wh\n",
        battery.cell_count,
        battery
            .capacity_mah
            .map(|mah| format!("{mah:.0} mAh, "))
            .unwrap_or_default(),
        battery.nominal_voltage_v,
        battery.capacity_wh
    );
    out += "phases:\n";
    for phase in &summary.phases {
        let duration = match phase.duration_by_level {
            Some(by_level) => format!(
                "{}–{} s by `{}` level",
                fmt_number(
                    by_level
                        .duration_s
                        .iter()
                        .copied()
                        .fold(f64::INFINITY, f64::min)
                ),
                fmt_number(by_level.duration_s.iter().copied().fold(0.0, f64::max)),
                by_level.task
            ),
            None => format!("{} s", fmt_number(phase.duration_s)),
        };
        out += &format!(
            "  {:<10} {:<8} {:<30} flight {:>6.1} W   tasks: {}\n",
            phase.name,
            phase.kind,
            duration,
            phase.flight_power_w,
            phase.tasks.join(", ")
        );
    }
    out += "power model:\n";
    for profile in &summary.power_model.profiles {
        out += &format!(
            "  {}  (phases: {})\n",
            profile.path,
            profile.phases.join(", ")
        );
    }
    out += "tasks:\n";
    for task in &summary.tasks {
        let resource = if task.cores.is_empty() {
            task.resource.to_string()
        } else {
            format!(
                "{} cores {}",
                task.resource,
                task.cores
                    .iter()
                    .map(|c| c.to_string())
                    .collect::<Vec<_>>()
                    .join(",")
            )
        };
        let levels: Vec<String> = task
            .levels
            .iter()
            .map(|level| format!("{} (u={})", fmt_number(level.value), level.utility))
            .collect();
        out += &format!(
            "  {:<10} plugin {:<17} {:<12} weight {:<4} phases: {}\n             {}: {}\n",
            task.name,
            task.plugin,
            resource,
            task.weight,
            task.phases.join(", "),
            task.knob,
            levels.join(" → ")
        );
        if let Some(topic) = task.trigger.input() {
            let idle = task.max_idle_ms.map_or_else(String::new, |ms| {
                format!(", on its own after {} ms idle", fmt_number(ms))
            });
            out += &format!("             runs on `{topic}` (the levels cap its rate){idle}\n");
        }
    }
    out
}

/// A number without trailing zeros: 0.5, 10, 0.25.
fn fmt_number(value: f64) -> String {
    let text = format!("{value:.3}");
    text.trim_end_matches('0').trim_end_matches('.').to_string()
}
