//! A governor decision as the mission logs and records it: the current phase's level moves in
//! the config's knob values, and why.

use super::GovernorEvent;
use crate::config::TaskConfig;
use serde::Serialize;

/// One task's move in a governor decision, in the config's knob values.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LevelMove {
    pub task: String,
    pub knob: String,
    pub from: f64,
    pub to: f64,
}

/// One governor decision.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GovernorDecision {
    pub time_s: f64,
    /// `levels_changed`, `land_now` or `replan_failed`.
    pub kind: &'static str,
    /// The current phase's tasks that changed level (empty when only later phases changed).
    pub moves: Vec<LevelMove>,
    pub reason: String,
    pub description: String,
}

impl GovernorDecision {
    pub fn from_event(
        time_s: f64,
        event: &GovernorEvent,
        tasks: &[TaskConfig],
        description: String,
    ) -> Self {
        let (kind, moves, reason) = match event {
            GovernorEvent::LevelsChanged(change) => {
                let old = change.old_levels.first().map(Vec::as_slice).unwrap_or(&[]);
                let new = change.new_levels.first().map(Vec::as_slice).unwrap_or(&[]);
                let moves = new
                    .iter()
                    .filter_map(|after| {
                        let before = old.iter().find(|b| b.task == after.task)?;
                        let task = tasks.get(after.task)?;
                        (before.level != after.level).then(|| LevelMove {
                            task: task.name.clone(),
                            knob: task.knob.to_string(),
                            from: task.levels[before.level],
                            to: task.levels[after.level],
                        })
                    })
                    .collect();
                ("levels_changed", moves, change.reason.to_string())
            }
            GovernorEvent::LandNow(_) => (
                "land_now",
                Vec::new(),
                "even the lowest levels do not fit: land now".to_string(),
            ),
            GovernorEvent::ReplanFailed { error, .. } => {
                ("replan_failed", Vec::new(), error.to_string())
            }
        };
        Self {
            time_s,
            kind,
            moves,
            reason,
            description,
        }
    }
}
