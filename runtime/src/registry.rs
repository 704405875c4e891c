//! Task plugins by name: `plugin = "…"` in qos.toml picks the factory registered under that
//! name. The runtime's own plugins and a user's (registered from their crate) live side by side:
//!
//! ```
//! use runtime::registry::PluginRegistry;
//! use runtime::task::{Task, TaskContext, TaskError};
//!
//! struct Blink { count: u64 }
//! impl Task for Blink {
//!     fn step(&mut self, _ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
//!         self.count += 1;
//!         Ok(())
//!     }
//! }
//!
//! let mut registry = PluginRegistry::new();
//! registry
//!     .register("blink", |_build| Ok(Box::new(Blink { count: 0 })))
//!     .unwrap();
//! assert!(registry.catalog().get("blink").is_some());
//! ```

use crate::bus::Bus;
use crate::catalog::{PluginCatalog, PluginInfo};
use crate::config::suggest::closest;
use crate::config::{Knob, Resource, TaskConfig};
use crate::task::{panic_as_failure, Task, TaskBuild, TaskError};
use std::fmt;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

/// Builds a task instance from its params, config and ports. Called again for every restart,
/// possibly on the task's worker thread.
type MakeTask = dyn Fn(&TaskBuild<'_>) -> Result<Box<dyn Task>, TaskError> + Send + Sync;

/// A registered plugin's factory with its catalogue entry (which bounds the ports it may take).
#[derive(Clone)]
pub struct TaskFactory {
    info: PluginInfo,
    make: Arc<MakeTask>,
}

impl TaskFactory {
    pub fn info(&self) -> &PluginInfo {
        &self.info
    }

    /// A new instance of `task` from `params` (its `[task.params]` less the scheduler's own
    /// keys), with its ports on `bus`. An error or a panic is a [`RegistryError::Create`].
    pub fn create(
        &self,
        params: &toml::Table,
        task: &TaskConfig,
        bus: &Bus,
    ) -> Result<Box<dyn Task>, RegistryError> {
        let build = TaskBuild::new(params, task, &self.info, bus);
        let created = panic_as_failure(catch_unwind(AssertUnwindSafe(|| (self.make)(&build))));
        created.map_err(|source| RegistryError::Create {
            task: task.name.clone(),
            plugin: task.plugin.clone(),
            source,
        })
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RegistryError {
    #[error("a plugin name must not be empty")]
    EmptyName,
    #[error("plugin `{plugin}` is already registered")]
    Duplicate { plugin: String },
    #[error("task `{task}`: unknown plugin `{plugin}`{}; registered plugins: {known}", suggestion.as_ref().map(|s| format!(" (did you mean `{s}`?)")).unwrap_or_default())]
    UnknownPlugin {
        task: String,
        plugin: String,
        suggestion: Option<String>,
        known: String,
    },
    #[error(
        "task `{task}`: plugin `{plugin}` cannot run on the {resource}; it runs on: {supported}"
    )]
    UnsupportedResource {
        task: String,
        plugin: String,
        resource: Resource,
        supported: String,
    },
    #[error(
        "task `{task}`: plugin `{plugin}` has no QoS knob `{knob}`; it understands: {supported}"
    )]
    UnsupportedKnob {
        task: String,
        plugin: String,
        knob: Knob,
        supported: String,
    },
    #[error("task `{task}`: plugin `{plugin}` could not be created: {source}")]
    Create {
        task: String,
        plugin: String,
        #[source]
        source: TaskError,
    },
}

/// Factories by plugin name. Not global: the binary (or a user's) builds one and hands it to
/// the scheduler.
#[derive(Default)]
pub struct PluginRegistry {
    // Registration order, so the catalogue lists plugins as they were registered.
    plugins: Vec<TaskFactory>,
}

impl fmt::Debug for PluginRegistry {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.names()).finish()
    }
}

impl PluginRegistry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers `factory` under `name`; the plugin may run on any resource with either knob,
    /// and touches no topic (declare its ports with [`PluginRegistry::register_plugin`]).
    pub fn register<F>(
        &mut self,
        name: &'static str,
        factory: F,
    ) -> Result<&mut Self, RegistryError>
    where
        F: Fn(&TaskBuild<'_>) -> Result<Box<dyn Task>, TaskError> + Send + Sync + 'static,
    {
        self.register_plugin(PluginInfo::user(name), factory)
    }

    /// Registers `factory` with its catalogue entry (summary, resources, knobs, ports), which the
    /// config check enforces.
    pub fn register_plugin<F>(
        &mut self,
        info: PluginInfo,
        factory: F,
    ) -> Result<&mut Self, RegistryError>
    where
        F: Fn(&TaskBuild<'_>) -> Result<Box<dyn Task>, TaskError> + Send + Sync + 'static,
    {
        if info.name.trim().is_empty() {
            return Err(RegistryError::EmptyName);
        }
        if self.contains(info.name) {
            return Err(RegistryError::Duplicate {
                plugin: info.name.to_string(),
            });
        }
        self.plugins.push(TaskFactory {
            info,
            make: Arc::new(factory),
        });
        Ok(self)
    }

    pub fn contains(&self, name: &str) -> bool {
        self.find(name).is_some()
    }

    pub fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.plugins.iter().map(|plugin| plugin.info.name)
    }

    /// Whether `task`'s plugin is registered and reads `topic` (its declared inputs say).
    pub fn reads(&self, task: &TaskConfig, topic: &str) -> bool {
        self.info(&task.plugin)
            .is_some_and(|info| info.reads(topic))
    }

    pub fn info(&self, name: &str) -> Option<&PluginInfo> {
        self.find(name).map(|plugin| &plugin.info)
    }

    /// The catalogue the config is checked against: exactly the registered plugins.
    pub fn catalog(&self) -> PluginCatalog {
        PluginCatalog::from_plugins(self.plugins.iter().map(|plugin| plugin.info.clone()))
    }

    /// The factory for `task`'s plugin, after checking the plugin exists and supports the task's
    /// resource and knob.
    pub fn resolve(&self, task: &TaskConfig) -> Result<TaskFactory, RegistryError> {
        let Some(plugin) = self.find(&task.plugin) else {
            return Err(RegistryError::UnknownPlugin {
                task: task.name.clone(),
                plugin: task.plugin.clone(),
                suggestion: closest(&task.plugin, self.names()).map(str::to_string),
                known: self.names().collect::<Vec<_>>().join(", "),
            });
        };
        if !plugin.info.resources.contains(&task.resource) {
            return Err(RegistryError::UnsupportedResource {
                task: task.name.clone(),
                plugin: task.plugin.clone(),
                resource: task.resource,
                supported: join(plugin.info.resources),
            });
        }
        if !plugin.info.knobs.contains(&task.knob) {
            return Err(RegistryError::UnsupportedKnob {
                task: task.name.clone(),
                plugin: task.plugin.clone(),
                knob: task.knob,
                supported: join(plugin.info.knobs),
            });
        }
        Ok(plugin.clone())
    }

    /// A new instance of `task`'s plugin from `task.params`, with its ports on `bus`. A factory
    /// that panics is reported as a creation error.
    pub fn create(&self, task: &TaskConfig, bus: &Bus) -> Result<Box<dyn Task>, RegistryError> {
        self.resolve(task)?.create(&task.params, task, bus)
    }

    fn find(&self, name: &str) -> Option<&TaskFactory> {
        self.plugins.iter().find(|plugin| plugin.info.name == name)
    }
}

fn join<T: fmt::Display>(items: &[T]) -> String {
    items
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::{Port, BUILTIN_PLUGINS};
    use crate::task::TaskContext;
    use crate::topics::{LANDING_MARKER, RELATIVE_STATE, VEHICLE_STATE};

    struct Counter {
        step_by: u64,
        total: u64,
    }

    impl Task for Counter {
        fn step(&mut self, _ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
            self.total += self.step_by;
            Ok(())
        }
    }

    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct CounterParams {
        step_by: u64,
    }

    fn counter_factory(build: &TaskBuild<'_>) -> Result<Box<dyn Task>, TaskError> {
        let params: CounterParams = build.parse_params()?;
        Ok(Box::new(Counter {
            step_by: params.step_by,
            total: 0,
        }))
    }

    fn task(plugin: &str, resource: Resource, params: &str) -> TaskConfig {
        TaskConfig {
            name: "counting".into(),
            plugin: plugin.into(),
            resource,
            cores: vec![],
            phases: vec!["tracking".into()],
            weight: 1.0,
            knob: Knob::PeriodMs,
            levels: vec![10.0],
            utility: vec![1.0],
            restart: None,
            params: toml::from_str(params).unwrap(),
            trigger: Default::default(),
            max_idle_ms: None,
            config_dir: None,
            camera: Default::default(),
        }
    }

    #[test]
    fn the_config_picks_the_factory_by_name() {
        let mut registry = PluginRegistry::new();
        registry.register("counter", counter_factory).unwrap();
        registry
            .register("fails", |_| Err(TaskError::failed("no camera")))
            .unwrap();
        assert!(registry
            .create(&task("counter", Resource::Cpu, "step_by = 3"), &Bus::new())
            .is_ok());
        let error = registry
            .create(&task("fails", Resource::Cpu, ""), &Bus::new())
            .err()
            .unwrap();
        assert!(matches!(&error, RegistryError::Create { plugin, .. } if plugin == "fails"));
        assert!(error.to_string().contains("no camera"), "{error}");
        // The plugin's own params type rejects a misspelt key, through the registry.
        let error = registry
            .create(&task("counter", Resource::Cpu, "stepby = 3"), &Bus::new())
            .err()
            .unwrap();
        assert!(error.to_string().contains("stepby"), "{error}");
    }

    #[test]
    fn unknown_plugin_is_named_with_a_suggestion() {
        let mut registry = PluginRegistry::new();
        registry.register("counter", counter_factory).unwrap();
        registry
            .register("landing_marker", counter_factory)
            .unwrap();
        let error = registry
            .create(&task("countr", Resource::Cpu, ""), &Bus::new())
            .err()
            .unwrap();
        match &error {
            RegistryError::UnknownPlugin {
                task,
                plugin,
                suggestion,
                known,
            } => {
                assert_eq!(task, "counting");
                assert_eq!(plugin, "countr");
                assert_eq!(suggestion.as_deref(), Some("counter"));
                assert_eq!(known, "counter, landing_marker");
            }
            other => panic!("expected UnknownPlugin, got {other:?}"),
        }
        assert!(
            error.to_string().contains("did you mean `counter`"),
            "{error}"
        );
    }

    #[test]
    fn duplicates_and_empty_names_are_refused() {
        let mut registry = PluginRegistry::new();
        registry.register("counter", counter_factory).unwrap();
        assert!(matches!(
            registry.register("counter", counter_factory),
            Err(RegistryError::Duplicate { plugin }) if plugin == "counter"
        ));
        assert!(matches!(
            registry.register(" ", counter_factory),
            Err(RegistryError::EmptyName)
        ));
    }

    #[test]
    fn plugin_info_limits_resources_and_knobs() {
        let mut registry = PluginRegistry::new();
        let landing_marker = BUILTIN_PLUGINS
            .iter()
            .find(|plugin| plugin.name == "landing_marker")
            .unwrap()
            .clone();
        registry
            .register_plugin(landing_marker, counter_factory)
            .unwrap();
        assert!(matches!(
            registry.resolve(&task("landing_marker", Resource::Gpu, "")),
            Err(RegistryError::UnsupportedResource {
                resource: Resource::Gpu,
                ..
            })
        ));
        assert!(registry
            .resolve(&task("landing_marker", Resource::Cpu, ""))
            .is_ok());
    }

    #[test]
    fn a_panicking_factory_is_a_creation_error() {
        let mut registry = PluginRegistry::new();
        registry
            .register("bad", |_| panic!("factory exploded"))
            .unwrap();
        let error = registry
            .create(&task("bad", Resource::Cpu, ""), &Bus::new())
            .err()
            .unwrap();
        assert!(error.to_string().contains("factory exploded"), "{error}");
    }

    /// A factory takes the ports its catalogue entry declares, and no other: the dataflow
    /// `qosrt check` draws is the one that runs.
    #[test]
    fn a_factory_gets_only_the_ports_it_declares() {
        let info = PluginInfo {
            inputs: const { &[Port::of(LANDING_MARKER)] },
            outputs: const { &[Port::of(RELATIVE_STATE)] },
            ..PluginInfo::user("tracker")
        };
        let mut registry = PluginRegistry::new();
        registry
            .register_plugin(info, |build| {
                build.input(LANDING_MARKER)?;
                build.output(RELATIVE_STATE)?;
                if build.params().contains_key("sneak") {
                    build.input(VEHICLE_STATE)?;
                }
                Ok(Box::new(Counter {
                    step_by: 1,
                    total: 0,
                }))
            })
            .unwrap();
        let bus = Bus::new();
        registry
            .create(&task("tracker", Resource::Cpu, ""), &bus)
            .unwrap();
        let names: Vec<String> = bus.topics().into_iter().map(|t| t.name).collect();
        assert_eq!(names, ["tracking/relative_state", "vision/landing_marker"]);
        let error = registry
            .create(&task("tracker", Resource::Cpu, "sneak = true"), &bus)
            .err()
            .unwrap();
        assert!(
            matches!(
                &error,
                RegistryError::Create {
                    source: TaskError::UndeclaredPort {
                        topic: "vehicle/state",
                        direction: "input",
                        ..
                    },
                    ..
                }
            ),
            "{error:?}"
        );
        assert!(
            error
                .to_string()
                .contains("does not declare input `vehicle/state`"),
            "{error}"
        );
    }

    /// A user's plugin passes `qosrt check`'s loader once registered, and is refused before.
    #[test]
    fn the_catalogue_from_the_registry_admits_user_plugins_to_the_config() {
        let reference = include_str!("../../qos.toml");
        let text = reference.replace("plugin = \"kalman_tracker\"", "plugin = \"my_tracker\"");
        assert!(crate::config::load_str(&text, None, &PluginCatalog::builtin()).is_err());

        let mut registry = PluginRegistry::new();
        for info in BUILTIN_PLUGINS {
            registry
                .register_plugin(info.clone(), counter_factory)
                .unwrap();
        }
        let my_tracker = PluginInfo {
            inputs: const { &[Port::of(VEHICLE_STATE), Port::of(LANDING_MARKER)] },
            outputs: const { &[Port::of(RELATIVE_STATE)] },
            ..PluginInfo::user("my_tracker")
        };
        registry
            .register_plugin(my_tracker, counter_factory)
            .unwrap();
        let config = crate::config::load_str(&text, None, &registry.catalog())
            .expect("the user's plugin is known");
        assert_eq!(config.task("tracking").unwrap().plugin, "my_tracker");
        assert_eq!(
            registry.catalog().names().count(),
            BUILTIN_PLUGINS.len() + 1
        );
    }
}
