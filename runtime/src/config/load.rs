//! Loading `qos.toml`: text → spanned TOML → typed config → rules, with every mistake reported
//! as a located diagnostic. Each top-level section and each `[[task]]` is deserialised on its own
//! so that mistakes in several of them are all reported in one run.

use super::suggest::did_you_mean;
use super::validate::{validate, PathSegment, PluginRules};
use super::GovernorConfig;
use super::{Battery, Flight, Mission, MissionConfig, PowerModelConfig, TaskConfig};
use super::{CameraSettings, LinkSettings, RecordSettings};
use crate::diagnostic::{Diagnostic, FileReport};
use serde::de::DeserializeOwned;
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::de::{DeTable, DeValue, ValueDeserializer};
use toml::Spanned;

const SECTIONS: [&str; 9] = [
    "mission",
    "battery",
    "flight",
    "power_model",
    "task",
    "governor",
    "link",
    "camera",
    "record",
];

/// A config that passed every check.
#[derive(Debug, Clone)]
pub struct LoadedConfig {
    pub path: PathBuf,
    pub source: String,
    pub config: MissionConfig,
}

impl LoadedConfig {
    /// Folder that relative paths in the config (profiles) are resolved against.
    pub fn base_dir(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new("."))
    }
}

/// A config that did not load: every diagnostic found, with the text they point into.
pub type ConfigFailure = FileReport;

/// Reads, parses and checks a config file; relative profile paths resolve against its folder.
pub fn load_file(path: &Path, plugins: &dyn PluginRules) -> Result<LoadedConfig, ConfigFailure> {
    let failure = |source: String, diagnostics| ConfigFailure {
        path: path.to_path_buf(),
        source,
        diagnostics,
    };
    let bytes = match std::fs::read(path) {
        Ok(bytes) => bytes,
        Err(error) => {
            let message = format!("cannot read the config file: {error}");
            return Err(failure(
                String::new(),
                vec![Diagnostic::error(None, message)],
            ));
        }
    };
    let source = match String::from_utf8(bytes) {
        Ok(text) => text,
        Err(error) => {
            let offset = error.utf8_error().valid_up_to();
            let text = String::from_utf8_lossy(error.as_bytes()).into_owned();
            let message = "the file is not UTF-8 text (TOML must be UTF-8): invalid byte here";
            return Err(failure(
                text,
                vec![Diagnostic::error(Some(offset..offset + 1), message)],
            ));
        }
    };
    let base_dir = path.parent().unwrap_or(Path::new("."));
    match load_str(&source, Some(base_dir), plugins) {
        Ok(config) => Ok(LoadedConfig {
            path: path.to_path_buf(),
            source,
            config,
        }),
        Err(diagnostics) => Err(failure(source, diagnostics)),
    }
}

/// Parses and checks config text. With `base_dir`, profile paths must exist under it.
pub fn load_str(
    text: &str,
    base_dir: Option<&Path>,
    plugins: &dyn PluginRules,
) -> Result<MissionConfig, Vec<Diagnostic>> {
    let (root, syntax_errors) = DeTable::parse_recoverable(text);
    if syntax_errors.is_empty() && root.get_ref().is_empty() {
        return Err(vec![Diagnostic::error(
            Some(0..0),
            "the file is empty: expected a mission config with [mission], [battery], [flight], [power_model] and [[task]] sections",
        )]);
    }
    if !syntax_errors.is_empty() {
        let mut diagnostics: Vec<Diagnostic> = syntax_errors
            .iter()
            .map(|error| {
                Diagnostic::error(
                    error.span(),
                    format!("invalid TOML: {}", error.message().trim()),
                )
            })
            .collect();
        sort_by_position(&mut diagnostics);
        return Err(diagnostics);
    }

    let mut diagnostics = Vec::new();
    let mut config = deserialize_sections(root.get_ref(), &mut diagnostics);
    if let Some(config) = config.as_mut() {
        let camera = config.camera_settings();
        for task in &mut config.tasks {
            task.config_dir = base_dir.map(Path::to_path_buf);
            task.camera = camera.clone();
        }
    }
    if let Some(config) = &config {
        for issue in validate(config, plugins) {
            let span = span_of(&root, &issue.path);
            diagnostics.push(Diagnostic::error(Some(span), issue.message));
        }
        if let Some(base_dir) = base_dir {
            check_profile_files(config, &root, base_dir, &mut diagnostics);
        }
    }
    if diagnostics.is_empty() {
        config.ok_or_else(Vec::new)
    } else {
        sort_by_position(&mut diagnostics);
        Err(diagnostics)
    }
}

fn sort_by_position(diagnostics: &mut [Diagnostic]) {
    diagnostics.sort_by_key(|d| d.span.as_ref().map_or(0, |span| span.start));
}

fn check_profile_files(
    config: &MissionConfig,
    root: &Spanned<DeTable<'_>>,
    base_dir: &Path,
    diagnostics: &mut Vec<Diagnostic>,
) {
    for (index, profile) in config.power_model.profiles.iter().enumerate() {
        let resolved = base_dir.join(&profile.path);
        if !resolved.is_file() {
            let path = [
                PathSegment::Key("power_model".into()),
                PathSegment::Key("profile".into()),
                PathSegment::Index(index),
                PathSegment::Key("path".into()),
            ];
            diagnostics.push(Diagnostic::error(
                Some(span_of(root, &path)),
                format!(
                    "power-model profile `{}` not found (looked for {}); profiles live under profiles/",
                    profile.path,
                    resolved.display()
                ),
            ));
        }
    }
}

/// Deserialises each section on its own; `None` when any failed (their errors are pushed).
fn deserialize_sections(
    root: &DeTable<'_>,
    diagnostics: &mut Vec<Diagnostic>,
) -> Option<MissionConfig> {
    for (key, _) in root.iter() {
        let key_name: &str = key.get_ref();
        if !SECTIONS.contains(&key_name) {
            diagnostics.push(Diagnostic::error(
                Some(key.span()),
                format!(
                    "unknown section `{key_name}`{}; expected one of: [mission], [battery], [flight], [power_model], [[task]], [governor], [link], [camera], [record]",
                    did_you_mean(key_name, SECTIONS)
                ),
            ));
        }
    }
    let mission = section::<Mission>(root, "mission", diagnostics);
    let battery = section::<Battery>(root, "battery", diagnostics);
    let flight = section::<Flight>(root, "flight", diagnostics);
    let power_model = section::<PowerModelConfig>(root, "power_model", diagnostics);
    let tasks = tasks(root, diagnostics);
    // The optional sections: absent means their defaults (the governor's tuning, no signing and
    // the default streams, the default camera, every frame recorded).
    let governor = optional_section::<GovernorConfig>(root, "governor", diagnostics);
    let link = optional_section::<LinkSettings>(root, "link", diagnostics);
    let camera = optional_section::<CameraSettings>(root, "camera", diagnostics);
    let record = optional_section::<RecordSettings>(root, "record", diagnostics);
    Some(MissionConfig {
        mission: mission?,
        battery: battery?,
        flight: flight?,
        power_model: power_model?,
        tasks: tasks?,
        governor: governor?,
        link: link?,
        camera: camera?,
        record: record?,
    })
}

/// An optional section: `Some(None)` when absent, `None` when present and broken.
fn optional_section<T: DeserializeOwned>(
    root: &DeTable<'_>,
    name: &str,
    diagnostics: &mut Vec<Diagnostic>,
) -> Option<Option<T>> {
    match root.get(name) {
        None => Some(None),
        Some(_) => section::<T>(root, name, diagnostics).map(Some),
    }
}

fn section<T: DeserializeOwned>(
    root: &DeTable<'_>,
    name: &str,
    diagnostics: &mut Vec<Diagnostic>,
) -> Option<T> {
    let Some(value) = root.get(name) else {
        diagnostics.push(Diagnostic::error(
            Some(0..0),
            format!("missing section [{name}]"),
        ));
        return None;
    };
    if !value.get_ref().is_table() {
        diagnostics.push(Diagnostic::error(
            Some(value.span()),
            format!(
                "`{name}` must be a table ([{name}]), found {}",
                value.get_ref().type_str()
            ),
        ));
        return None;
    }
    deserialize_value(value, &format!("[{name}]"), diagnostics)
}

fn tasks(root: &DeTable<'_>, diagnostics: &mut Vec<Diagnostic>) -> Option<Vec<TaskConfig>> {
    let Some(value) = root.get("task") else {
        diagnostics.push(Diagnostic::error(
            Some(0..0),
            "missing [[task]] sections: the mission needs at least one task",
        ));
        return None;
    };
    let DeValue::Array(array) = value.get_ref() else {
        diagnostics.push(Diagnostic::error(
            Some(value.span()),
            "tasks are an array of tables: write each as [[task]], not [task]",
        ));
        return None;
    };
    let mut tasks = Some(Vec::with_capacity(array.len()));
    for element in array.iter() {
        let task = if element.get_ref().is_table() {
            deserialize_value::<TaskConfig>(element, "[[task]]", diagnostics)
        } else {
            diagnostics.push(Diagnostic::error(
                Some(element.span()),
                format!(
                    "a task must be a table, found {}",
                    element.get_ref().type_str()
                ),
            ));
            None
        };
        match (task, tasks.as_mut()) {
            (Some(task), Some(list)) => list.push(task),
            _ => tasks = None,
        }
    }
    tasks
}

fn deserialize_value<T: DeserializeOwned>(
    value: &Spanned<DeValue<'_>>,
    context: &str,
    diagnostics: &mut Vec<Diagnostic>,
) -> Option<T> {
    match T::deserialize(ValueDeserializer::from(value.clone())) {
        Ok(parsed) => Some(parsed),
        Err(error) => {
            let span = error.span().unwrap_or_else(|| value.span());
            diagnostics.push(Diagnostic::error(
                Some(span),
                explain_serde_message(error.message(), context),
            ));
            None
        }
    }
}

/// Rewrites serde's messages in a drone engineer's words, with a suggestion for unknown keys.
fn explain_serde_message(message: &str, context: &str) -> String {
    let message = message.trim();
    if let Some(rest) = message.strip_prefix("unknown field `") {
        if let Some((field, expected)) = rest.split_once('`') {
            let candidates: Vec<&str> = expected.split('`').skip(1).step_by(2).collect();
            return format!(
                "unknown key `{field}` in {context}{}; expected one of: {}",
                did_you_mean(field, candidates.iter().copied()),
                candidates.join(", ")
            );
        }
    }
    if let Some(rest) = message.strip_prefix("missing field `") {
        let field = rest.trim_end_matches('`');
        return format!("missing key `{field}` in {context}");
    }
    if let Some(rest) = message.strip_prefix("unknown variant `") {
        if let Some((variant, expected)) = rest.split_once('`') {
            let candidates: Vec<&str> = expected.split('`').skip(1).step_by(2).collect();
            return format!(
                "unknown value `{variant}`{}; expected one of: {}",
                did_you_mean(variant, candidates.iter().copied()),
                candidates.join(", ")
            );
        }
    }
    // serde names Rust types; say what the file should hold instead.
    message
        .replace("expected f64", "expected a number")
        .replace("expected u32", "expected a whole number ≥ 0")
        .replace("expected usize", "expected a whole number ≥ 0")
        .replace("expected a sequence", "expected an array")
        .replace("invalid value: integer", "invalid value")
        .replace("invalid type", "wrong type")
}

/// Span in config text of the value at `path` (see [`span_of`]), for checks made after loading.
pub fn span_at(source: &str, path: &[PathSegment]) -> Range<usize> {
    let (root, _) = DeTable::parse_recoverable(source);
    span_of(&root, path)
}

/// Span of the value at `path`; where the path stops existing, the span of its deepest parent.
fn span_of(root: &Spanned<DeTable<'_>>, path: &[PathSegment]) -> Range<usize> {
    let mut span = root.span();
    let mut table = Some(root.get_ref());
    let mut array: Option<&[Spanned<DeValue<'_>>]> = None;
    for segment in path {
        let next = match (segment, table, array) {
            (PathSegment::Key(key), Some(t), _) => t.get(key.as_str()),
            (PathSegment::Index(index), _, Some(a)) => a.get(*index),
            _ => None,
        };
        let Some(next) = next else { break };
        span = next.span();
        table = next.get_ref().as_table();
        array = next.get_ref().as_array().map(|a| a.as_ref());
    }
    span
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serde_messages_become_readable_with_suggestions() {
        let message = explain_serde_message(
            "unknown field `naem`, expected one of `name`, `description`, `reserve_fraction`, `phase`",
            "[mission]",
        );
        assert_eq!(
            message,
            "unknown key `naem` in [mission]; did you mean `name`?; expected one of: name, description, reserve_fraction, phase"
        );
        assert_eq!(
            explain_serde_message("missing field `cell_count`", "[battery]"),
            "missing key `cell_count` in [battery]"
        );
    }

    #[test]
    fn span_of_walks_tables_and_arrays_and_stops_at_the_deepest_existing_parent() {
        let text = "[[task]]\nname = \"a\"\n[[task]]\nname = \"b\"\nlevels = [1, 2]\n";
        let (root, errors) = DeTable::parse_recoverable(text);
        assert!(errors.is_empty());
        let key = |k: &str| PathSegment::Key(k.to_string());
        let levels = span_of(
            &root,
            &[
                key("task"),
                PathSegment::Index(1),
                key("levels"),
                PathSegment::Index(1),
            ],
        );
        assert_eq!(&text[levels], "2");
        let name = span_of(&root, &[key("task"), PathSegment::Index(0), key("name")]);
        assert_eq!(&text[name], "\"a\"");
        // A missing key falls back to its table, located by the table's header.
        let missing = span_of(&root, &[key("task"), PathSegment::Index(1), key("weight")]);
        assert_eq!(missing.start, text.rfind("[[task]]").unwrap());
    }
}
