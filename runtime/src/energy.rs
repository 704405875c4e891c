//! The mission's energy model: the config's phases and tasks, the measured power profiles and
//! the battery, assembled into the planner's problem. Used offline by `qosrt plan` and, in
//! flight, by the governor.

use crate::config::{AxisScaleConfig, LoadedConfig, MissionConfig, PathSegment};
use crate::diagnostic::{Diagnostic, FileReport};
use power_models::battery::{BatteryError, BatterySpec};
use power_models::grid::{AxisScale, GridModel};
use power_models::planner::{
    solve, DurationByLevel, PlanError, PlanPhase, PlanProblem, PlanTask, PowerTerm,
};
use power_models::profile::Profile;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Messages a second on the topics that trigger tasks (`camera/frame` → 10.0): what caps a
/// triggered task's rate below its level. Declared (`[camera] rate_fps`) for a plan; measured
/// in flight.
pub type InputRates = BTreeMap<String, f64>;

/// What a mission may spend: the pack's usable energy, rated at the most demanding plan's
/// mean power (a pack delivers less the harder it is driven, so this is on the safe side for
/// every lighter plan), less the reserve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyBudget {
    pub rating_power_w: f64,
    pub usable_wh: f64,
    pub reserve_wh: f64,
    pub available_wh: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BudgetError {
    #[error("cannot plan: {0}")]
    Plan(#[from] PlanError),
    #[error("battery: {0}")]
    Battery(#[from] BatteryError),
}

/// The budget of `problem` on a full `pack` keeping `reserve_fraction` of its usable energy.
pub fn energy_budget(
    problem: &PlanProblem,
    pack: &BatterySpec,
    reserve_fraction: f64,
) -> Result<EnergyBudget, BudgetError> {
    let heaviest = solve(problem, f64::MAX)?;
    let duration_s: f64 = heaviest.phases.iter().map(|p| p.duration_s).sum();
    let rating_power_w = if duration_s > 0.0 {
        heaviest.energy_wh * 3600.0 / duration_s
    } else {
        0.0
    };
    let usable_wh = pack.usable_energy_wh(rating_power_w, 1.0, 0.0)?;
    let reserve_wh = usable_wh * reserve_fraction;
    Ok(EnergyBudget {
        rating_power_w,
        usable_wh,
        reserve_wh,
        available_wh: usable_wh - reserve_wh,
    })
}

/// A profile named by the config, loaded and turned into a grid model.
#[derive(Debug, Clone)]
pub struct LoadedProfile {
    pub path: PathBuf,
    pub profile: Profile,
    pub model: GridModel,
}

/// The config and everything it refers to, ready for planning.
#[derive(Debug, Clone)]
pub struct MissionModel {
    pub config: MissionConfig,
    /// One per `[[power_model.profile]]`, in the config's order.
    pub profiles: Vec<LoadedProfile>,
    /// Located warnings about the config (levels outside a profile's grid, …).
    pub warnings: Vec<Diagnostic>,
}

/// The interpolation scale the config asks for, or the crate's measured default.
pub fn axis_scale(config: &MissionConfig) -> AxisScale {
    match config.power_model.axis_scale {
        Some(AxisScaleConfig::Linear) => AxisScale::Linear,
        Some(AxisScaleConfig::Log) => AxisScale::Log,
        None => AxisScale::default(),
    }
}

/// Loads every profile the config names and checks that they fit the config's tasks. Errors
/// come per file: the profile's own mistakes located in it, mismatches located in the config.
pub fn load_mission_model(loaded: &LoadedConfig) -> Result<MissionModel, Vec<FileReport>> {
    let config = &loaded.config;
    let scale = axis_scale(config);
    let mut reports = Vec::new();
    let mut profiles = Vec::new();
    for profile_ref in &config.power_model.profiles {
        let path = loaded.base_dir().join(&profile_ref.path);
        let report = |source: String, diagnostic: Diagnostic| FileReport {
            path: path.clone(),
            source,
            diagnostics: vec![diagnostic],
        };
        let source = match std::fs::read_to_string(&path) {
            Ok(source) => source,
            Err(error) => {
                let message = format!("cannot read the profile: {error}");
                reports.push(report(String::new(), Diagnostic::error(None, message)));
                continue;
            }
        };
        let profile = match Profile::from_toml_str(&source) {
            Ok(profile) => profile,
            Err(error) => {
                reports.push(report(source, Diagnostic::error(error.span, error.message)));
                continue;
            }
        };
        match GridModel::from_profile(&profile, scale) {
            Ok(model) => profiles.push(LoadedProfile {
                path,
                profile,
                model,
            }),
            Err(error) => reports.push(report(
                source,
                Diagnostic::error(None, format!("cannot build a model from it: {error}")),
            )),
        }
    }
    if !reports.is_empty() {
        return Err(reports);
    }
    let (errors, warnings) = check_coverage(loaded, &profiles);
    if !errors.is_empty() {
        return Err(vec![FileReport {
            path: loaded.path.clone(),
            source: loaded.source.clone(),
            diagnostics: errors,
        }]);
    }
    Ok(MissionModel {
        config: config.clone(),
        profiles,
        warnings,
    })
}

/// Checks the profiles against the tasks: every knob a profile models belongs to a task with
/// that knob, no task is modelled twice in one phase, and levels outside a profile's grid are
/// flagged (the model clamps there). Returns (errors, warnings), located in the config.
fn check_coverage(
    loaded: &LoadedConfig,
    profiles: &[LoadedProfile],
) -> (Vec<Diagnostic>, Vec<Diagnostic>) {
    let config = &loaded.config;
    let root = &loaded.source;
    let mut errors = Vec::new();
    let mut warnings = Vec::new();
    let profile_path = |index: usize| {
        vec![
            PathSegment::Key("power_model".into()),
            PathSegment::Key("profile".into()),
            PathSegment::Index(index),
            PathSegment::Key("path".into()),
        ]
    };
    for (index, loaded_profile) in profiles.iter().enumerate() {
        for (axis, knob) in loaded_profile.profile.knobs.iter().enumerate() {
            let task = config
                .tasks
                .iter()
                .position(|task| &task.knob_name() == knob);
            let Some(task_index) = task else {
                let known: Vec<String> = config.tasks.iter().map(|t| t.knob_name()).collect();
                errors.push(Diagnostic::error(
                    Some(crate::config::span_at(root, &profile_path(index))),
                    format!(
                        "profile `{}` models knob `{knob}`, which no task has; the tasks' knobs are: {}",
                        config.power_model.profiles[index].path,
                        known.join(", ")
                    ),
                ));
                continue;
            };
            let task = &config.tasks[task_index];
            let grid = &loaded_profile.model.axes()[axis];
            let (lo, hi) = (grid[0], grid[grid.len() - 1]);
            for (level, value) in task.levels.iter().enumerate() {
                if *value < lo || *value > hi {
                    let path = vec![
                        PathSegment::Key("task".into()),
                        PathSegment::Index(task_index),
                        PathSegment::Key("levels".into()),
                        PathSegment::Index(level),
                    ];
                    warnings.push(Diagnostic::warning(
                        Some(crate::config::span_at(root, &path)),
                        format!(
                            "{} = {value} lies outside profile `{}`'s measured range [{lo}, {hi}]: its power is clamped to the nearest measured value",
                            task.knob_name(),
                            config.power_model.profiles[index].path
                        ),
                    ));
                }
            }
        }
    }
    for phase in &config.mission.phases {
        let mut seen: Vec<&str> = Vec::new();
        for (index, _) in config.power_model.profiles_for(&phase.name) {
            let Some(loaded_profile) = profiles.get(index) else {
                continue;
            };
            for knob in &loaded_profile.profile.knobs {
                if seen.contains(&knob.as_str()) {
                    errors.push(Diagnostic::error(
                        Some(crate::config::span_at(root, &profile_path(index))),
                        format!(
                            "knob `{knob}` is modelled twice in phase `{}`: an additive model needs each task in one profile",
                            phase.name
                        ),
                    ));
                }
                seen.push(knob);
            }
        }
    }
    (errors, warnings)
}

impl MissionModel {
    /// The planner's problem: tasks with their utilities and weights; per phase the flight
    /// power, the duration (per level where the config says so) and the companion power as
    /// tables over the levels of the tasks each profile models.
    ///
    /// A task that does not run in a phase but appears in its profile is held at the profile's
    /// lowest measured value, the measured state closest to not running. A triggered task is
    /// priced at the rate it runs at with the declared input rates ([`Self::declared_input_rates`]).
    pub fn plan_problem(&self) -> PlanProblem {
        self.plan_problem_at(&self.declared_input_rates())
    }

    /// The input rates the config declares: the camera's `rate_fps` on `camera/frame`.
    pub fn declared_input_rates(&self) -> InputRates {
        let camera_rate = self.config.camera.as_ref().and_then(|c| c.rate_fps);
        camera_rate
            .map(|rate_fps| (crate::config::CAMERA_FRAME_TOPIC.to_string(), rate_fps))
            .into_iter()
            .collect()
    }

    /// [`Self::plan_problem`] with each triggered task priced at the rate it runs at when its
    /// trigger's topic delivers at `input_rates` ([`TaskConfig::running_knob_value`]); a
    /// topic without a rate leaves its tasks at their levels.
    ///
    /// [`TaskConfig::running_knob_value`]: crate::config::TaskConfig::running_knob_value
    pub fn plan_problem_at(&self, input_rates: &InputRates) -> PlanProblem {
        let config = &self.config;
        let tasks = config
            .tasks
            .iter()
            .map(|task| PlanTask {
                name: task.name.clone(),
                utility: task.utility.clone(),
                weight: task.weight,
                allowed_levels: None,
            })
            .collect();
        let phases = config
            .mission
            .phases
            .iter()
            .map(|phase| {
                let active_tasks: Vec<usize> = (0..config.tasks.len())
                    .filter(|&t| config.tasks[t].runs_in(&phase.name))
                    .collect();
                let phase_profiles: Vec<&LoadedProfile> = config
                    .power_model
                    .profiles_for(&phase.name)
                    .filter_map(|(index, _)| self.profiles.get(index))
                    .collect();
                // One profile is the board's whole power; several add up above idle.
                let idle_w = if phase_profiles.len() > 1 {
                    config.power_model.idle_power_w.unwrap_or(0.0)
                } else {
                    0.0
                };
                let mut base_power_w = idle_w;
                let mut terms = Vec::new();
                for loaded_profile in phase_profiles {
                    let (term_tasks, power_w) =
                        self.power_table(loaded_profile, &active_tasks, input_rates);
                    let above_idle = power_w.iter().map(|p| p - idle_w);
                    if term_tasks.is_empty() {
                        base_power_w += above_idle.sum::<f64>();
                    } else {
                        terms.push(PowerTerm {
                            tasks: term_tasks,
                            power_w: above_idle.collect(),
                        });
                    }
                }
                PlanPhase {
                    name: phase.name.clone(),
                    duration_s: phase.duration_s,
                    duration_by_level: phase.duration_by_level.as_ref().and_then(|by_level| {
                        Some(DurationByLevel {
                            task: config.tasks.iter().position(|t| t.name == by_level.task)?,
                            duration_s: by_level.duration_s.clone(),
                        })
                    }),
                    flight_power_w: config.flight.power_w(&phase.name).unwrap_or(0.0),
                    base_power_w,
                    active_tasks,
                    terms,
                }
            })
            .collect();
        PlanProblem { tasks, phases }
    }

    /// The power of every combination of levels of the active tasks a profile models
    /// (row-major, first task slowest), and those tasks' indices.
    fn power_table(
        &self,
        loaded: &LoadedProfile,
        active_tasks: &[usize],
        input_rates: &InputRates,
    ) -> (Vec<usize>, Vec<f64>) {
        let config = &self.config;
        let axes = loaded.model.axes();
        // For each profile knob: the active task that sets it, if any.
        let knob_tasks: Vec<Option<usize>> = loaded
            .profile
            .knobs
            .iter()
            .map(|knob| {
                active_tasks
                    .iter()
                    .copied()
                    .find(|&t| &config.tasks[t].knob_name() == knob)
            })
            .collect();
        let term_tasks: Vec<usize> = knob_tasks.iter().flatten().copied().collect();
        let level_counts: Vec<usize> = term_tasks
            .iter()
            .map(|&t| config.tasks[t].levels.len())
            .collect();
        let combinations: usize = level_counts.iter().product();
        let mut table = Vec::with_capacity(combinations);
        let mut levels = vec![0usize; term_tasks.len()];
        for _ in 0..combinations {
            let point: Vec<f64> = knob_tasks
                .iter()
                .enumerate()
                .map(|(axis, task)| match task {
                    Some(t) => {
                        let position = term_tasks.iter().position(|x| x == t).unwrap_or(0);
                        let task = &config.tasks[*t];
                        let input_rate = task.trigger.input().and_then(|i| input_rates.get(i));
                        let value = task
                            .running_knob_value(task.levels[levels[position]], input_rate.copied());
                        // A task that never runs (no input, no idle runs) costs the axis's
                        // cheapest end, as clamping an infinite period would give.
                        let (low, high) = (axes[axis][0], axes[axis][axes[axis].len() - 1]);
                        value.clamp(low.min(high), low.max(high))
                    }
                    None => axes[axis][0],
                })
                .collect();
            table.push(loaded.model.eval(&point).value);
            // Advance the mixed-radix counter, last task fastest.
            for position in (0..levels.len()).rev() {
                levels[position] += 1;
                if levels[position] < level_counts[position] {
                    break;
                }
                levels[position] = 0;
            }
        }
        (term_tasks, table)
    }

    /// The pack as the config describes it, with `capacity_wh` overriding its capacity. The
    /// error names the bad field of the spec; callers say it is the battery's.
    pub fn battery_spec(&self, capacity_wh: Option<f64>) -> Result<BatterySpec, BatteryError> {
        let battery = &self.config.battery;
        let nominal_v = battery.nominal_voltage_v() / f64::from(battery.cell_count);
        let resistance_ohm = battery.internal_resistance_ohm();
        let spec = match (capacity_wh, battery.capacity_mah) {
            (None, Some(mah)) => {
                BatterySpec::from_capacity_mah(mah, battery.cell_count, nominal_v, resistance_ohm)
            }
            (wh, _) => BatterySpec::from_capacity_wh(
                wh.or(battery.capacity_wh).unwrap_or(0.0),
                battery.cell_count,
                nominal_v,
                resistance_ohm,
            ),
        }?;
        match battery.empty_cell_voltage_v {
            Some(empty_v) => spec.with_empty_cell_voltage_v(empty_v),
            None => Ok(spec),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::PluginCatalog;
    use crate::config::load_file;
    use power_models::planner::solve;
    use std::path::Path;

    fn reference_model() -> MissionModel {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
        let loaded = load_file(&path, &PluginCatalog::builtin()).expect("reference config");
        load_mission_model(&loaded).expect("reference profiles")
    }

    /// Advances a mixed-radix counter (last digit fastest); false once it wraps around.
    fn next_combination(levels: &mut [usize], counts: &[usize]) -> bool {
        for position in (0..levels.len()).rev() {
            levels[position] += 1;
            if levels[position] < counts[position] {
                return true;
            }
            levels[position] = 0;
        }
        false
    }

    /// Every plan of the reference mission by enumeration, each as (energy_wh, utility),
    /// with the companion power read straight from the profiles' models.
    fn brute_force(model: &MissionModel) -> Vec<(f64, f64)> {
        let config = &model.config;
        let mut plans = vec![(0.0, 0.0)];
        for phase in &config.mission.phases {
            let active: Vec<usize> = (0..config.tasks.len())
                .filter(|&t| config.tasks[t].runs_in(&phase.name))
                .collect();
            let counts: Vec<usize> = active
                .iter()
                .map(|&t| config.tasks[t].levels.len())
                .collect();
            let mut options = Vec::new();
            let mut levels = vec![0; active.len()];
            loop {
                let level_of =
                    |task: usize| active.iter().position(|&t| t == task).map(|i| levels[i]);
                let mut companion_w = 0.0;
                for (index, _) in config.power_model.profiles_for(&phase.name) {
                    let loaded = &model.profiles[index];
                    let point: Vec<f64> = loaded
                        .profile
                        .knobs
                        .iter()
                        .enumerate()
                        .map(|(axis, knob)| {
                            let task = config
                                .tasks
                                .iter()
                                .position(|t| &t.knob_name() == knob)
                                .unwrap();
                            match level_of(task) {
                                Some(level) => config.tasks[task].levels[level],
                                None => loaded.model.axes()[axis][0],
                            }
                        })
                        .collect();
                    companion_w += loaded.model.eval(&point).value;
                }
                let duration_s = match &phase.duration_by_level {
                    Some(by_level) => {
                        let task = config
                            .tasks
                            .iter()
                            .position(|t| t.name == by_level.task)
                            .unwrap();
                        by_level.duration_s[level_of(task).unwrap()]
                    }
                    None => phase.duration_s,
                };
                let flight_w = config.flight.power_w(&phase.name).unwrap();
                let utility: f64 = active
                    .iter()
                    .map(|&t| {
                        config.tasks[t].weight * config.tasks[t].utility[level_of(t).unwrap()]
                    })
                    .sum();
                options.push((duration_s * (flight_w + companion_w) / 3600.0, utility));
                if !next_combination(&mut levels, &counts) {
                    break;
                }
            }
            plans = plans
                .iter()
                .flat_map(|&(e, u)| options.iter().map(move |&(oe, ou)| (e + oe, u + ou)))
                .collect();
        }
        plans
    }

    #[test]
    fn the_reference_plan_is_the_brute_force_optimum_at_every_budget() {
        let model = reference_model();
        let problem = model.plan_problem();
        let plans = brute_force(&model);
        let (min_wh, max_wh) = plans.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), p| {
            (lo.min(p.0), hi.max(p.0))
        });
        for step in 0..=40 {
            let budget_wh = min_wh - 0.1 + (max_wh - min_wh + 0.2) * f64::from(step) / 40.0;
            let plan = solve(&problem, budget_wh).unwrap();
            let best = plans
                .iter()
                .filter(|p| p.0 <= budget_wh)
                .map(|p| p.1)
                .fold(None, |best: Option<f64>, u| {
                    Some(best.map_or(u, |b| b.max(u)))
                });
            match best {
                None => assert!(!plan.feasible, "budget {budget_wh}"),
                Some(best) => {
                    assert!(plan.feasible, "budget {budget_wh}");
                    assert!(
                        (plan.utility - best).abs() < 1e-9,
                        "budget {budget_wh}: {} vs {best}",
                        plan.utility
                    );
                }
            }
        }
    }

    #[test]
    fn a_triggered_task_is_priced_at_the_rate_its_input_lets_it_run() {
        let model = reference_model();
        let tasks = &model.config.tasks;
        let index = |name: &str| tasks.iter().position(|t| t.name == name).unwrap();
        let (detection, hazard) = (index("detection"), index("hazard"));
        let phase = |problem: &PlanProblem, name: &str| {
            problem
                .phases
                .iter()
                .find(|p| p.name == name)
                .unwrap()
                .clone()
        };
        let camera_at = |rate_fps: f64| -> InputRates {
            [("camera/frame".to_string(), rate_fps)]
                .into_iter()
                .collect()
        };
        // A 4 fps camera: the landing phase's detector (triggered by frames) runs at most at
        // 4 fps whatever its level; its profile (landing.toml) read at that rate.
        let landing = phase(&model.plan_problem_at(&camera_at(4.0)), "landing");
        assert_eq!(landing.terms[0].tasks, vec![detection]);
        let landing_profile = &model.profiles[1].model;
        for (level, &level_fps) in tasks[detection].levels.iter().enumerate() {
            let runs_at_fps = level_fps.min(4.0);
            let expected = landing_profile.eval(&[runs_at_fps]).value;
            assert_eq!(landing.terms[0].power_w[level], expected, "level {level}");
        }
        // Without a camera rate the top level is priced at its 10 fps, which costs more.
        let unlimited = phase(&model.plan_problem(), "landing");
        assert!(unlimited.terms[0].power_w[3] > landing.terms[0].power_w[3]);
        // A silent camera: the hazard CNN still runs once a second on its own (max_idle_ms
        // 1000), so its top level (4 fps) costs what 1 fps does; in transit the profile's
        // detection knob sits at its lowest, 0.5 fps.
        let transit = phase(&model.plan_problem_at(&camera_at(0.0)), "transit");
        let tracking_profile = &model.profiles[0].model;
        assert_eq!(transit.terms[0].tasks, vec![hazard]);
        assert_eq!(
            transit.terms[0].power_w[3],
            tracking_profile.eval(&[1.0, 0.5]).value
        );
        assert_eq!(
            transit.terms[0].power_w[0],
            tracking_profile.eval(&[0.1, 0.5]).value
        );
        // Declared in the config, the same rate prices the plan `qosrt plan` makes.
        let mut declared = model.clone();
        declared.config.camera = Some(crate::config::CameraSettings {
            rate_fps: Some(4.0),
            ..Default::default()
        });
        assert_eq!(phase(&declared.plan_problem(), "landing"), landing);
    }

    #[test]
    fn inactive_profile_knobs_sit_at_the_lowest_measured_value() {
        let model = reference_model();
        let problem = model.plan_problem();
        // Transit runs only the hazard CNN; its profile also models marker detection, held at
        // the profile's lowest rate (0.5 fps in the seed grid).
        let transit = &problem.phases[0];
        assert_eq!(transit.name, "transit");
        let hazard = model
            .config
            .tasks
            .iter()
            .position(|t| t.name == "hazard")
            .unwrap();
        assert_eq!(transit.terms.len(), 1);
        assert_eq!(transit.terms[0].tasks, vec![hazard]);
        let tracking_profile = &model.profiles[0];
        for (level, value) in model.config.tasks[hazard].levels.iter().enumerate() {
            let expected = tracking_profile.model.eval(&[*value, 0.5]).value;
            assert_eq!(transit.terms[0].power_w[level], expected);
        }
    }

    #[test]
    fn several_profiles_of_one_phase_add_up_above_idle() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let dir = tempfile::tempdir().unwrap();
        let hazard_samples = [(0.1, 3.9), (0.25, 4.2), (1.0, 4.9), (4.0, 6.2)];
        let mut hazard_profile =
            String::from("board = \"b\"\nmeter = \"m\"\nknobs = [\"hazard.rate_fps\"]\n");
        for (rate_fps, power_w) in hazard_samples {
            hazard_profile += &format!("[[sample]]\nknobs = [{rate_fps}]\npower_w = {power_w}\n");
        }
        std::fs::write(dir.path().join("hazard.toml"), hazard_profile).unwrap();
        let landing_path = root.join("profiles/jetson-nano-seed/landing.toml");
        let reference = std::fs::read_to_string(root.join("qos.toml")).unwrap();
        let start = reference.find("[power_model]").unwrap();
        let end = reference.find("# The tasks.").unwrap();
        let power_model = format!(
            "[power_model]\nidle_power_w = 3.0\n[[power_model.profile]]\npath = \"{}\"\nphases = [\"tracking\", \"landing\"]\n[[power_model.profile]]\npath = \"hazard.toml\"\nphases = [\"transit\", \"tracking\"]\n\n",
            landing_path.display()
        );
        let text = format!("{}{power_model}{}", &reference[..start], &reference[end..]);
        let config_path = dir.path().join("qos.toml");
        std::fs::write(&config_path, text).unwrap();
        let loaded = load_file(&config_path, &PluginCatalog::builtin()).expect("valid");
        let model = load_mission_model(&loaded).expect("profiles fit");
        let problem = model.plan_problem();
        let tracking = problem
            .phases
            .iter()
            .find(|p| p.name == "tracking")
            .unwrap();
        assert_eq!(tracking.base_power_w, 3.0);
        assert_eq!(tracking.terms.len(), 2);

        // Expected: idle + (landing profile − idle) + (hazard profile − idle), read from the
        // measured samples themselves (the levels are exactly the measured knob values).
        let landing: toml::Table = std::fs::read_to_string(&landing_path)
            .unwrap()
            .parse()
            .unwrap();
        let measured_landing = |rate_fps: f64| {
            landing["sample"]
                .as_array()
                .unwrap()
                .iter()
                .find(|s| s["knobs"][0].as_float() == Some(rate_fps))
                .unwrap()["power_w"]
                .as_float()
                .unwrap()
        };
        let config = &model.config;
        let detection = config
            .tasks
            .iter()
            .position(|t| t.name == "detection")
            .unwrap();
        let hazard = config
            .tasks
            .iter()
            .position(|t| t.name == "hazard")
            .unwrap();
        let term_of = |task: usize| {
            tracking
                .terms
                .iter()
                .find(|t| t.tasks == vec![task])
                .unwrap()
        };
        for (d, rate_fps) in config.tasks[detection].levels.iter().enumerate() {
            for (h, (_, hazard_w)) in hazard_samples.iter().enumerate() {
                let predicted = tracking.base_power_w
                    + term_of(detection).power_w[d]
                    + term_of(hazard).power_w[h];
                let expected = measured_landing(*rate_fps) + hazard_w - 3.0;
                assert!(
                    (predicted - expected).abs() < 1e-9,
                    "{predicted} vs {expected}"
                );
            }
        }
        // A phase with one profile uses it whole, without subtracting idle.
        let landing_phase = problem.phases.iter().find(|p| p.name == "landing").unwrap();
        assert_eq!(landing_phase.base_power_w, 0.0);
        assert_eq!(landing_phase.terms[0].power_w[3], measured_landing(10.0));
    }
}
