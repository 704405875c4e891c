//! A mission config checked against the catalogue: each task's plugin exists and takes its
//! resource, knob and trigger, and every task's inputs are published.

use super::PluginCatalog;
use crate::config::suggest::did_you_mean;
use crate::config::{IssuePath, Issues, MissionConfig, PluginRules, TaskConfig};

impl PluginRules for PluginCatalog {
    fn check_task(&self, task: &TaskConfig, path: &IssuePath, issues: &mut Issues) {
        let Some(plugin) = self.get(&task.plugin) else {
            let names: Vec<&str> = self.names().collect();
            issues.push(
                &path.key("plugin"),
                format!(
                    "unknown plugin `{}`{}; available plugins: {}",
                    task.plugin,
                    did_you_mean(&task.plugin, names.iter().copied()),
                    names.join(", ")
                ),
            );
            return;
        };
        if !plugin.resources.contains(&task.resource) {
            issues.push(
                &path.key("resource"),
                format!(
                    "plugin `{}` cannot run on `{}`; it runs on: {}",
                    plugin.name,
                    task.resource,
                    plugin
                        .resources
                        .iter()
                        .map(|r| r.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            );
        }
        if !plugin.knobs.contains(&task.knob) {
            issues.push(
                &path.key("knob"),
                format!("plugin `{}` has no QoS knob `{}`", plugin.name, task.knob),
            );
        }
        check_trigger_topic(self, task, path, issues);
    }

    /// A task whose input nothing publishes would wait for it the whole mission: named at the
    /// task, with the plugins that could feed it.
    fn check_dataflow(&self, config: &MissionConfig, path: &IssuePath, issues: &mut Issues) {
        if config
            .tasks
            .iter()
            .any(|task| self.get(&task.plugin).is_none())
        {
            // An unknown plugin is reported as such; its ports would only add noise.
            return;
        }
        let graph = crate::dataflow::task_graph(config, self);
        for unfed in graph.missing_inputs() {
            let task = &config.tasks[unfed.task];
            let add = if unfed.producers.is_empty() {
                "no plugin in the catalogue publishes it".to_string()
            } else {
                format!(
                    "add a task with plugin {}",
                    unfed
                        .producers
                        .iter()
                        .map(|plugin| format!("`{plugin}`"))
                        .collect::<Vec<_>>()
                        .join(" or ")
                )
            };
            issues.push(
                &path.index(unfed.task).key("plugin"),
                format!(
                    "task `{}` reads `{}` ({}), which no task in this mission publishes; {add}",
                    task.name, unfed.port.topic, unfed.port.message
                ),
            );
        }
    }
}

/// A trigger names one of the task's own inputs.
fn check_trigger_topic(
    plugins: &PluginCatalog,
    task: &TaskConfig,
    path: &IssuePath,
    issues: &mut Issues,
) {
    let (Some(topic), Some(plugin)) = (task.trigger.input(), plugins.get(&task.plugin)) else {
        // An unknown plugin is reported as such.
        return;
    };
    if plugin.reads(topic) {
        return;
    }
    let inputs: Vec<&str> = plugin.inputs.iter().map(|port| port.topic).collect();
    let read = if inputs.is_empty() {
        format!("; plugin `{}` reads no input", plugin.name)
    } else {
        format!(
            "{}; its inputs: {}",
            did_you_mean(topic, inputs.iter().copied()),
            inputs.join(", ")
        )
    };
    issues.push(
        &path.key("trigger"),
        format!(
            "task `{}` is triggered by `{topic}`, which it does not read{read}",
            task.name
        ),
    );
}
