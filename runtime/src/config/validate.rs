//! The rules of a mission config beyond its types. Pure: each broken rule is an issue located by
//! the key path of the value that breaks it, which the loader turns into a line and column.

use super::suggest::did_you_mean;
use super::{
    CameraSettings, Knob, Mission, MissionConfig, PhaseKind, Resource, TaskConfig,
    MOVED_CAMERA_PARAMS,
};
use std::collections::HashSet;
use std::fmt;

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PathSegment {
    Key(String),
    Index(usize),
}

impl fmt::Display for PathSegment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PathSegment::Key(key) => f.write_str(key),
            PathSegment::Index(index) => write!(f, "[{index}]"),
        }
    }
}

/// A broken rule: where (key path from the document root) and what.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigIssue {
    pub path: Vec<PathSegment>,
    pub message: String,
}

/// A key path under construction, extended one key or array index at a time.
#[derive(Clone)]
pub struct IssuePath(Vec<PathSegment>);

impl IssuePath {
    pub fn root() -> Self {
        IssuePath(Vec::new())
    }
    pub fn key(&self, key: &str) -> Self {
        let mut path = self.0.clone();
        path.push(PathSegment::Key(key.to_string()));
        IssuePath(path)
    }
    pub fn index(&self, index: usize) -> Self {
        let mut path = self.0.clone();
        path.push(PathSegment::Index(index));
        IssuePath(path)
    }
}

/// The broken rules found so far.
pub struct Issues(Vec<ConfigIssue>);

impl Issues {
    pub fn push(&mut self, path: &IssuePath, message: impl Into<String>) {
        self.0.push(ConfigIssue {
            path: path.0.clone(),
            message: message.into(),
        });
    }
}

/// The rules that need the plugins a mission runs (their resources, knobs and ports): the
/// catalogue keeps them (`crate::catalog`), so the config knows nothing of the runtime.
pub trait PluginRules {
    /// The task's plugin exists and takes its resource, knob and trigger.
    fn check_task(&self, task: &TaskConfig, path: &IssuePath, issues: &mut Issues);
    /// Every task's inputs are published by the mission or another task (`path`: the tasks).
    fn check_dataflow(&self, config: &MissionConfig, path: &IssuePath, issues: &mut Issues);
}

/// Checks every rule and returns every broken one (empty when the config is valid).
pub fn validate(config: &MissionConfig, plugins: &dyn PluginRules) -> Vec<ConfigIssue> {
    let mut issues = Issues(Vec::new());
    let root = IssuePath::root();
    check_mission(config, &root.key("mission"), &mut issues);
    check_battery(config, &root.key("battery"), &mut issues);
    check_battery_model(config, &root.key("battery"), &mut issues);
    check_flight(config, &root.key("flight"), &mut issues);
    if let Some(camera) = &config.camera {
        check_camera(camera, &root.key("camera"), &mut issues);
    }
    check_power_model(config, &root.key("power_model"), &mut issues);
    check_tasks(config, plugins, &root.key("task"), &mut issues);
    plugins.check_dataflow(config, &root.key("task"), &mut issues);
    if let Some(governor) = &config.governor {
        if let Err(error) = governor.validate() {
            issues.push(&root.key("governor").key(error.field), error.to_string());
        }
    }
    issues.0
}

fn phase_names(config: &MissionConfig) -> Vec<&str> {
    config
        .mission
        .phases
        .iter()
        .map(|phase| phase.name.as_str())
        .collect()
}

/// Reports a phase name that is not one of `[[mission.phase]]`.
fn check_phase_exists(config: &MissionConfig, name: &str, path: &IssuePath, issues: &mut Issues) {
    if config.phase(name).is_none() {
        let names = phase_names(config);
        issues.push(
            path,
            format!(
                "unknown phase `{name}`{}; the mission's phases are: {}",
                did_you_mean(name, names.iter().copied()),
                names.join(", ")
            ),
        );
    }
}

fn check_positive(value: f64, what: &str, path: &IssuePath, issues: &mut Issues) {
    if !(value.is_finite() && value > 0.0) {
        issues.push(
            path,
            format!("{what} must be a finite number > 0, found {value}"),
        );
    }
}

/// The phases fly in the order the sequencer knows: at most one transit, first; then the
/// tracking phases; one landing, last (the mission ends at touchdown).
fn check_phase_kinds(mission: &Mission, path: &IssuePath, issues: &mut Issues) {
    let kinds = mission.phase_kinds();
    let count = kinds.len();
    for (index, kind) in kinds.iter().enumerate() {
        // Located at the phase's `kind` where it names one, else at the phase.
        let at = {
            let phase = path.key("phase").index(index);
            if mission.phases[index].kind.is_some() {
                phase.key("kind")
            } else {
                phase
            }
        };
        let name = &mission.phases[index].name;
        let misplaced = match kind {
            PhaseKind::Transit if index > 0 => Some("a transit phase must come first"),
            PhaseKind::Land if index + 1 < count => {
                Some("a land phase must come last (the mission ends at touchdown)")
            }
            PhaseKind::Track | PhaseKind::Transit if index + 1 == count => {
                Some("the last phase must be of kind `land` (the mission ends at touchdown)")
            }
            _ => None,
        };
        if let Some(why) = misplaced {
            issues.push(
                &at,
                format!("phase `{name}` is of kind `{kind}`, but {why}; the kinds by position are transit, track…, land"),
            );
        }
    }
}

fn check_mission(config: &MissionConfig, path: &IssuePath, issues: &mut Issues) {
    let mission = &config.mission;
    if mission.name.trim().is_empty() {
        issues.push(&path.key("name"), "the mission name must not be empty");
    }
    if !(0.0..1.0).contains(&mission.reserve_fraction) {
        issues.push(
            &path.key("reserve_fraction"),
            format!(
                "reserve_fraction must be within [0, 1) (a fraction of the battery, e.g. 0.2), found {}",
                mission.reserve_fraction
            ),
        );
    }
    if mission.phases.is_empty() {
        issues.push(
            &path.key("phase"),
            "the mission needs at least one [[mission.phase]]",
        );
    }
    check_phase_kinds(mission, path, issues);
    let mut seen = HashSet::new();
    for (index, phase) in mission.phases.iter().enumerate() {
        let phase_path = path.key("phase").index(index);
        if phase.name.trim().is_empty() {
            issues.push(&phase_path.key("name"), "a phase name must not be empty");
        } else if !seen.insert(phase.name.as_str()) {
            issues.push(
                &phase_path.key("name"),
                format!("phase `{}` is defined twice", phase.name),
            );
        }
        check_positive(
            phase.duration_s,
            "duration_s",
            &phase_path.key("duration_s"),
            issues,
        );
        if let Some(by_level) = &phase.duration_by_level {
            let by_path = phase_path.key("duration_by_level");
            match config.task(&by_level.task) {
                None => issues.push(
                    &by_path.key("task"),
                    format!(
                        "unknown task `{}`{}",
                        by_level.task,
                        did_you_mean(&by_level.task, config.tasks.iter().map(|t| t.name.as_str()))
                    ),
                ),
                Some(task) => {
                    if !task.runs_in(&phase.name) {
                        issues.push(
                            &by_path.key("task"),
                            format!(
                                "task `{}` does not run in phase `{}`, so its level cannot change the phase's duration",
                                task.name, phase.name
                            ),
                        );
                    }
                    if by_level.duration_s.len() != task.levels.len() {
                        issues.push(
                            &by_path.key("duration_s"),
                            format!(
                                "expected {} durations, one per level of task `{}`, found {}",
                                task.levels.len(),
                                task.name,
                                by_level.duration_s.len()
                            ),
                        );
                    }
                }
            }
            for (index, duration_s) in by_level.duration_s.iter().enumerate() {
                check_positive(
                    *duration_s,
                    "a phase duration",
                    &by_path.key("duration_s").index(index),
                    issues,
                );
            }
        }
    }
}

fn check_battery(config: &MissionConfig, path: &IssuePath, issues: &mut Issues) {
    let battery = &config.battery;
    match (battery.capacity_wh, battery.capacity_mah) {
        (None, None) => issues.push(
            path,
            "the battery needs its capacity: `capacity_wh`, or `capacity_mah` (with `nominal_cell_voltage_v`, default 3.7 V)",
        ),
        (Some(_), Some(_)) => issues.push(
            &path.key("capacity_mah"),
            "give the capacity once: either `capacity_wh` or `capacity_mah`, not both",
        ),
        (Some(wh), None) => check_positive(wh, "capacity_wh", &path.key("capacity_wh"), issues),
        (None, Some(mah)) => {
            check_positive(mah, "capacity_mah", &path.key("capacity_mah"), issues)
        }
    }
    if !(1..=24).contains(&battery.cell_count) {
        issues.push(
            &path.key("cell_count"),
            format!(
                "cell_count must be between 1 and 24 (cells in series, e.g. 4 for a 4S pack), found {}",
                battery.cell_count
            ),
        );
    }
    if let Some(voltage_v) = battery.nominal_cell_voltage_v {
        // Every lithium chemistry flown on drones has a nominal cell voltage in this range.
        if !(2.0..=4.5).contains(&voltage_v) {
            issues.push(
                &path.key("nominal_cell_voltage_v"),
                format!(
                    "nominal_cell_voltage_v is per cell and must be within [2.0, 4.5] V (3.7 for LiPo, 3.6 for Li-ion), found {voltage_v}"
                ),
            );
        }
    }
}

fn check_battery_model(config: &MissionConfig, path: &IssuePath, issues: &mut Issues) {
    let battery = &config.battery;
    if let Some(resistance_ohm) = battery.internal_resistance_ohm {
        if !(resistance_ohm.is_finite() && (0.0..1.0).contains(&resistance_ohm)) {
            issues.push(
                &path.key("internal_resistance_ohm"),
                format!(
                    "internal_resistance_ohm is the whole pack's, in ohms, within [0, 1) (a 4S drone pack is about 0.02), found {resistance_ohm}"
                ),
            );
        }
    }
    if let Some(empty_v) = battery.empty_cell_voltage_v {
        // Below 3.0 V a LiPo cell is damaged; above 4.0 V little charge would be usable.
        if !(3.0..=4.0).contains(&empty_v) {
            issues.push(
                &path.key("empty_cell_voltage_v"),
                format!(
                    "empty_cell_voltage_v is per cell, under load, within [3.0, 4.0] V (3.5 is usual for LiPo), found {empty_v}"
                ),
            );
        }
    }
}

fn check_flight(config: &MissionConfig, path: &IssuePath, issues: &mut Issues) {
    let flight = &config.flight;
    if let Some(hover_w) = flight.hover_power_w {
        check_positive(hover_w, "hover_power_w", &path.key("hover_power_w"), issues);
    }
    for (phase, power_w) in &flight.phase_power_w {
        let entry = path.key("phase_power_w").key(phase);
        check_phase_exists(config, phase, &entry, issues);
        check_positive(*power_w, "a flight power", &entry, issues);
    }
    if flight.hover_power_w.is_none() {
        let missing: Vec<&str> = config
            .mission
            .phases
            .iter()
            .map(|phase| phase.name.as_str())
            .filter(|name| !flight.phase_power_w.contains_key(*name))
            .collect();
        if !missing.is_empty() {
            issues.push(
                path,
                format!(
                    "no flight power for phase(s) {}: set `hover_power_w` or list them in `[flight.phase_power_w]`",
                    missing.join(", ")
                ),
            );
        }
    }
}

fn check_power_model(config: &MissionConfig, path: &IssuePath, issues: &mut Issues) {
    let profiles = &config.power_model.profiles;
    if profiles.is_empty() {
        issues.push(
            &path.key("profile"),
            "the power model needs at least one [[power_model.profile]]",
        );
    }
    if let Some(idle_w) = config.power_model.idle_power_w {
        check_positive(idle_w, "idle_power_w", &path.key("idle_power_w"), issues);
    }
    for phase in &config.mission.phases {
        let count = config.power_model.profiles_for(&phase.name).count();
        if count == 0 && !profiles.is_empty() {
            issues.push(
                &path.key("profile"),
                format!(
                    "no profile models phase `{}`: add it to the `phases` of a [[power_model.profile]]",
                    phase.name
                ),
            );
        } else if count > 1 && config.power_model.idle_power_w.is_none() {
            issues.push(
                path,
                format!(
                    "phase `{}` is modelled by {count} profiles, which add up only above the board's idle power: set `idle_power_w`",
                    phase.name
                ),
            );
        }
    }
    for (index, profile) in profiles.iter().enumerate() {
        let profile_path = path.key("profile").index(index);
        if profile.path.trim().is_empty() {
            issues.push(
                &profile_path.key("path"),
                "the profile path must not be empty",
            );
        }
        if profile.phases.is_empty() {
            issues.push(
                &profile_path.key("phases"),
                "list the phases this profile models",
            );
        }
        for (phase_index, phase) in profile.phases.iter().enumerate() {
            check_phase_exists(
                config,
                phase,
                &profile_path.key("phases").index(phase_index),
                issues,
            );
        }
    }
}

/// `[camera]`: a rate above 0, a field of view a pinhole camera can have, an image.
fn check_camera(camera: &CameraSettings, path: &IssuePath, issues: &mut Issues) {
    if let Some(rate_fps) = camera.rate_fps {
        check_positive(
            rate_fps,
            "the camera's rate_fps",
            &path.key("rate_fps"),
            issues,
        );
    }
    let fov_deg = camera.horizontal_fov_deg;
    if !(fov_deg > 0.0 && fov_deg < 180.0) {
        issues.push(
            &path.key("horizontal_fov_deg"),
            format!("the camera's horizontal_fov_deg must be within (0, 180), found {fov_deg}"),
        );
    }
    for (key, value) in [
        ("width_px", camera.width_px),
        ("height_px", camera.height_px),
    ] {
        if value == 0 {
            issues.push(
                &path.key(key),
                format!("the camera's {key} must be at least 1"),
            );
        }
    }
}

/// The camera is `[camera]`'s: a task that still describes it in its params is told where
/// the key went.
fn check_no_camera_params(task: &TaskConfig, path: &IssuePath, issues: &mut Issues) {
    for (old, new) in MOVED_CAMERA_PARAMS {
        if task.params.contains_key(old) {
            issues.push(
                &path.key(old),
                format!(
                    "the camera is described once, in [camera]: write `{new} = …` there instead \
                     of `{old}` in task `{}`'s params",
                    task.name
                ),
            );
        }
    }
}

fn check_tasks(
    config: &MissionConfig,
    plugins: &dyn PluginRules,
    path: &IssuePath,
    issues: &mut Issues,
) {
    if config.tasks.is_empty() {
        issues.push(path, "the mission needs at least one [[task]]");
    }
    let mut seen = HashSet::new();
    let mut gpu_holder: Option<&str> = None;
    for (index, task) in config.tasks.iter().enumerate() {
        let task_path = path.index(index);
        if task.name.trim().is_empty() {
            issues.push(&task_path.key("name"), "a task name must not be empty");
        } else if task.name.contains('.') {
            issues.push(
                &task_path.key("name"),
                format!(
                    "task name `{}` must not contain `.` (profiles name knobs TASK.KNOB)",
                    task.name
                ),
            );
        } else if !seen.insert(task.name.as_str()) {
            issues.push(
                &task_path.key("name"),
                format!("task `{}` is defined twice", task.name),
            );
        }
        check_no_camera_params(task, &task_path.key("params"), issues);
        plugins.check_task(task, &task_path, issues);
        if task.resource == Resource::Gpu {
            // A GPU runs one of these networks at a time: a second claimant would stall both.
            match gpu_holder {
                Some(holder) => issues.push(
                    &task_path.key("resource"),
                    format!(
                        "task `{}` claims the GPU, but task `{holder}` already holds it; the GPU is exclusive: put one of them on `cpu`",
                        task.name
                    ),
                ),
                None => gpu_holder = Some(task.name.as_str()),
            }
            if !task.cores.is_empty() {
                issues.push(
                    &task_path.key("cores"),
                    "`cores` pins CPU tasks; a GPU task takes none",
                );
            }
        }
        let mut cores_seen = HashSet::new();
        for (core_index, core) in task.cores.iter().enumerate() {
            if !cores_seen.insert(core) {
                issues.push(
                    &task_path.key("cores").index(core_index),
                    format!("core {core} is listed twice"),
                );
            }
        }
        if task.phases.is_empty() {
            issues.push(&task_path.key("phases"), "list the phases the task runs in");
        }
        for (phase_index, phase) in task.phases.iter().enumerate() {
            check_phase_exists(
                config,
                phase,
                &task_path.key("phases").index(phase_index),
                issues,
            );
        }
        if !(task.weight.is_finite() && task.weight >= 0.0) {
            issues.push(
                &task_path.key("weight"),
                format!("weight must be a finite number ≥ 0, found {}", task.weight),
            );
        }
        check_levels(task, &task_path, issues);
        check_trigger(task, &task_path, issues);
    }
}

/// `max_idle_ms` belongs to a triggered task (the trigger's topic is the plugin's to check).
fn check_trigger(task: &TaskConfig, path: &IssuePath, issues: &mut Issues) {
    if let Some(max_idle_ms) = task.max_idle_ms {
        if task.trigger.input().is_none() {
            issues.push(
                &path.key("max_idle_ms"),
                format!(
                    "task `{}` runs on its period; `max_idle_ms` only applies with `trigger = \"input:TOPIC\"`",
                    task.name
                ),
            );
        } else if !(max_idle_ms.is_finite() && max_idle_ms > 0.0) {
            issues.push(
                &path.key("max_idle_ms"),
                format!("max_idle_ms must be a finite number > 0, found {max_idle_ms}"),
            );
        }
    }
}

fn check_levels(task: &TaskConfig, path: &IssuePath, issues: &mut Issues) {
    let levels_path = path.key("levels");
    if task.levels.is_empty() {
        issues.push(&levels_path, "a task needs at least one QoS level");
    }
    for (index, value) in task.levels.iter().enumerate() {
        check_positive(
            *value,
            task.knob.as_str(),
            &levels_path.index(index),
            issues,
        );
    }
    // Lowest QoS first: rates increase, periods decrease.
    let (order, relation) = match task.knob {
        Knob::RateFps => ("increasing", "greater than"),
        Knob::PeriodMs => ("decreasing", "less than"),
    };
    for index in 1..task.levels.len() {
        let (previous, value) = (task.levels[index - 1], task.levels[index]);
        if !(previous.is_finite() && value.is_finite()) {
            continue;
        }
        let in_order = match task.knob {
            Knob::RateFps => value > previous,
            Knob::PeriodMs => value < previous,
        };
        if value == previous {
            issues.push(
                &levels_path.index(index),
                format!(
                    "level {value} {} is listed twice; levels must be unique",
                    task.knob
                ),
            );
        } else if !in_order {
            issues.push(
                &levels_path.index(index),
                format!(
                    "levels go from lowest to highest QoS, so {} must be strictly {order}: {value} is not {relation} {previous}",
                    task.knob
                ),
            );
        }
    }
    let utility_path = path.key("utility");
    if task.utility.len() != task.levels.len() {
        issues.push(
            &utility_path,
            format!(
                "expected one utility per level ({}), found {}",
                task.levels.len(),
                task.utility.len()
            ),
        );
    }
    for (index, utility) in task.utility.iter().enumerate() {
        if !(0.0..=1.0).contains(utility) {
            issues.push(
                &utility_path.index(index),
                format!("a utility must be within [0, 1], found {utility}"),
            );
        } else if index > 0 && *utility < task.utility[index - 1] {
            issues.push(
                &utility_path.index(index),
                format!(
                    "utilities must not decrease with QoS: {utility} follows {}",
                    task.utility[index - 1]
                ),
            );
        }
    }
}
