//! Choosing the combinations of levels to sweep.

use super::*;

/// `--levels task.knob=a,b,…`: the levels of one knob to sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelChoice {
    pub knob: String,
    pub values: Vec<f64>,
}

impl FromStr for LevelChoice {
    type Err = SweepError;

    fn from_str(text: &str) -> Result<Self, SweepError> {
        let bad = |message: &str| SweepError::BadLevels {
            text: text.to_string(),
            message: message.to_string(),
        };
        let (knob, values) = text
            .split_once('=')
            .ok_or_else(|| bad("expected TASK.KNOB=VALUE,VALUE,… e.g. hazard.rate_fps=4,1"))?;
        let knob = knob.trim();
        if !knob.contains('.') {
            return Err(bad("the knob is named TASK.KNOB, e.g. detection.rate_fps"));
        }
        let mut parsed = Vec::new();
        for cell in values.split(',') {
            let cell = cell.trim();
            let value: f64 = cell
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or_else(|| bad(&format!("`{cell}` is not a number")))?;
            if parsed.contains(&value) {
                return Err(bad(&format!("{cell} is given twice")));
            }
            parsed.push(value);
        }
        Ok(LevelChoice {
            knob: knob.to_string(),
            values: parsed,
        })
    }
}

/// One task's knob in the sweep: the levels it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct SweptKnob {
    /// Index of the task in the config.
    pub task: usize,
    /// `task.knob`.
    pub name: String,
    /// Level indices into the task's levels, lowest QoS first.
    pub levels: Vec<usize>,
    /// The knob values of those levels.
    pub values: Vec<f64>,
}

/// A task of the phase that does not run: its plugin is not in this binary.
#[derive(Debug, Clone, PartialEq)]
pub struct SkippedTask {
    pub task: String,
    pub plugin: String,
}

/// What the sweep runs.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    pub phase: String,
    /// Indices of the tasks that run.
    pub tasks: Vec<usize>,
    /// Knobs that take several levels: the profile's axes.
    pub axes: Vec<SweptKnob>,
    /// Knobs held at one level throughout (they are no axis of the profile).
    pub held: Vec<SweptKnob>,
    pub skipped: Vec<SkippedTask>,
}

impl SweepPlan {
    /// Every combination of the axes' levels, as positions into each axis's `levels`; the
    /// first axis changes slowest.
    pub fn combinations(&self) -> Vec<Vec<usize>> {
        let mut out = vec![Vec::new()];
        for axis in &self.axes {
            out = out
                .into_iter()
                .flat_map(|prefix| {
                    (0..axis.levels.len()).map(move |i| {
                        let mut next = prefix.clone();
                        next.push(i);
                        next
                    })
                })
                .collect();
        }
        out
    }

    /// `hazard.rate_fps=4, detection.rate_fps=10` for a combination.
    pub fn label(&self, combination: &[usize]) -> String {
        if self.axes.is_empty() {
            return "the held levels".to_string();
        }
        self.axes
            .iter()
            .zip(combination)
            .map(|(axis, &i)| format!("{}={}", axis.name, axis.values[i]))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Chooses the phase (by name, or the one with the most runnable tasks), its runnable tasks
/// (`can_run(plugin)`) and each knob's levels: those of `--levels`, else all the task's levels.
pub fn plan_sweep(
    config: &MissionConfig,
    can_run: &dyn Fn(&str) -> bool,
    phase: Option<&str>,
    choices: &[LevelChoice],
) -> Result<SweepPlan, SweepError> {
    let phases = &config.mission.phases;
    let phase = match phase {
        Some(name) => phases
            .iter()
            .find(|p| p.name == name)
            .ok_or_else(|| SweepError::UnknownPhase {
                phase: name.to_string(),
                known: phases
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?
            .name
            .clone(),
        None => {
            let runnable = |name: &str| {
                config
                    .tasks
                    .iter()
                    .filter(|t| t.runs_in(name) && can_run(&t.plugin))
                    .count()
            };
            // Most runnable tasks; the earliest phase on a tie.
            let mut best: Option<(&str, usize)> = None;
            for p in phases {
                let n = runnable(&p.name);
                if best.is_none_or(|(_, m)| n > m) {
                    best = Some((&p.name, n));
                }
            }
            best.map(|(name, _)| name.to_string()).unwrap_or_default()
        }
    };
    let in_phase: Vec<usize> = (0..config.tasks.len())
        .filter(|&i| config.tasks[i].runs_in(&phase))
        .collect();
    let (tasks, skipped_idx): (Vec<usize>, Vec<usize>) = in_phase
        .iter()
        .partition(|&&i| can_run(&config.tasks[i].plugin));
    let skipped: Vec<SkippedTask> = skipped_idx
        .iter()
        .map(|&i| SkippedTask {
            task: config.tasks[i].name.clone(),
            plugin: config.tasks[i].plugin.clone(),
        })
        .collect();
    for (n, choice) in choices.iter().enumerate() {
        if choices[..n].iter().any(|c| c.knob == choice.knob) {
            return Err(SweepError::KnobTwice {
                knob: choice.knob.clone(),
            });
        }
        if let Some(&i) = skipped_idx
            .iter()
            .find(|&&i| config.tasks[i].knob_name() == choice.knob)
        {
            return Err(SweepError::KnobOfSkippedTask {
                knob: choice.knob.clone(),
                task: config.tasks[i].name.clone(),
                plugin: config.tasks[i].plugin.clone(),
            });
        }
        if !tasks
            .iter()
            .any(|&i| config.tasks[i].knob_name() == choice.knob)
        {
            return Err(SweepError::UnknownKnob {
                knob: choice.knob.clone(),
                phase: phase.clone(),
                known: tasks
                    .iter()
                    .map(|&i| config.tasks[i].knob_name())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
    }
    if tasks.is_empty() {
        let skipped = if skipped.is_empty() {
            String::new()
        } else {
            format!(
                " (not built in: {})",
                skipped
                    .iter()
                    .map(|s| format!("task `{}` plugin `{}`", s.task, s.plugin))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        return Err(SweepError::NothingToRun { phase, skipped });
    }

    let (mut axes, mut held) = (Vec::new(), Vec::new());
    for &i in &tasks {
        let task = &config.tasks[i];
        let name = task.knob_name();
        let levels: Vec<usize> = match choices.iter().find(|c| c.knob == name) {
            None => (0..task.levels.len()).collect(),
            Some(choice) => {
                let mut levels = Vec::new();
                for &value in &choice.values {
                    let level = task
                        .levels
                        .iter()
                        .position(|&l| (l - value).abs() <= 1e-9 * l.abs().max(1.0))
                        .ok_or_else(|| SweepError::NotALevel {
                            knob: name.clone(),
                            value,
                            levels: task
                                .levels
                                .iter()
                                .map(f64::to_string)
                                .collect::<Vec<_>>()
                                .join(", "),
                        })?;
                    levels.push(level);
                }
                // Lowest QoS first, as the config lists them.
                levels.sort_unstable();
                levels
            }
        };
        let knob = SweptKnob {
            task: i,
            values: levels.iter().map(|&l| task.levels[l]).collect(),
            levels,
            name,
        };
        if knob.levels.len() > 1 {
            axes.push(knob);
        } else {
            held.push(knob);
        }
    }
    Ok(SweepPlan {
        phase,
        tasks,
        axes,
        held,
        skipped,
    })
}
