//! The mission's QoS configuration (`qos.toml`): the schema, its loading with located
//! diagnostics, and the rules beyond types.
//!
//! Keys carry their units (`duration_s`, `hover_power_w`, `capacity_mah`); unknown keys are
//! rejected so a misspelt key is an error, not a silently ignored setting.

mod governor;
mod load;
mod plan;
pub(crate) mod suggest;
mod validate;

pub use governor::{BadGovernorConfig, GovernorConfig};
pub use load::{load_file, load_str, span_at, ConfigFailure, LoadedConfig};
pub use plan::{LandingBy, MissionPlan};
pub use validate::{validate, ConfigIssue, IssuePath, Issues, PathSegment, PluginRules};

use algorithms::camera::{CameraError, PinholeCamera};
use algorithms::estimation::camera_mount::CameraMount;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;

/// Nominal LiPo cell voltage, used when a battery is given in mAh without a voltage.
pub const DEFAULT_NOMINAL_CELL_VOLTAGE_V: f64 = 3.7;

/// Internal resistance of one cell of a healthy drone LiPo (a few mΩ) plus its share of
/// wiring and connectors, used when the config gives no pack resistance.
pub const DEFAULT_CELL_RESISTANCE_OHM: f64 = 0.006;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissionConfig {
    pub mission: Mission,
    pub battery: Battery,
    pub flight: Flight,
    pub power_model: PowerModelConfig,
    #[serde(rename = "task")]
    pub tasks: Vec<TaskConfig>,
    /// In-flight re-planning; every key has a default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub governor: Option<GovernorConfig>,
    /// The MAVLink link to the autopilot (`qosrt run`); every key has a default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub link: Option<LinkSettings>,
    /// The camera the tasks read; every key is optional.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraSettings>,
    /// What a recording keeps; every key has a default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub record: Option<RecordSettings>,
}

/// `[camera]`: the one downward camera of the mission. The camera source checks its frames
/// against it, the plugins project with it, the planner prices triggered tasks at its rate
/// and the simulator renders it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSettings {
    /// Frames a second the camera delivers. A task triggered by `camera/frame` runs no
    /// faster, whatever its level, and the planner prices it at the rate it runs at; the
    /// simulator's camera runs at it (10 fps without it). In flight the measured rate takes
    /// over.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_fps: Option<f64>,
    /// Horizontal field of view, degrees.
    #[serde(default = "default_horizontal_fov_deg")]
    pub horizontal_fov_deg: f64,
    /// Image size, pixels.
    #[serde(default = "default_width_px")]
    pub width_px: usize,
    #[serde(default = "default_height_px")]
    pub height_px: usize,
    /// "body" (fixed to the body, looking along its down axis) or "gimbal" (held looking down
    /// by a gimbal that reports its attitude: frames are projected with that).
    #[serde(default)]
    pub mount: CameraMount,
}

fn default_horizontal_fov_deg() -> f64 {
    60.0
}
fn default_width_px() -> usize {
    640
}
fn default_height_px() -> usize {
    480
}

impl Default for CameraSettings {
    /// A body-fixed 640×480 camera with a 60° horizontal field of view, at no declared rate.
    fn default() -> Self {
        Self {
            rate_fps: None,
            horizontal_fov_deg: default_horizontal_fov_deg(),
            width_px: default_width_px(),
            height_px: default_height_px(),
            mount: CameraMount::default(),
        }
    }
}

impl CameraSettings {
    /// The pinhole model the plugins project with.
    pub fn pinhole(&self) -> Result<PinholeCamera, CameraError> {
        PinholeCamera::from_fov(
            self.width_px,
            self.height_px,
            self.horizontal_fov_deg.to_radians(),
        )
    }
}

/// Task params that were per-task copies of the camera before `[camera]` held it: each with
/// the `[camera]` key that replaced it.
pub const MOVED_CAMERA_PARAMS: [(&str, &str); 4] = [
    ("camera_horizontal_fov_deg", "horizontal_fov_deg"),
    ("image_width_px", "width_px"),
    ("image_height_px", "height_px"),
    ("camera_mount", "mount"),
];

/// `[record]`: what `--record` keeps (the command line's `--record-frames` overrides it).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordSettings {
    /// "every" (the default), "consumed" or "none".
    #[serde(default)]
    pub frames: FramePolicy,
    /// Each file's size budget in MB (`--record-max-mb`); none by default.
    #[serde(default)]
    pub max_mb: Option<std::num::NonZeroU64>,
    /// How kept frames are stored: "compact" (the default), "png" or "raw"
    /// (`--record-codec`).
    #[serde(default)]
    pub codec: FrameCodec,
}

/// How a recording's camera frames are stored, each a lossless `foxglove.CompressedImage` or
/// `RawImage` (the recording's header says which).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameCodec {
    /// `foxglove.RawImage`, mono8: the recordings made before frames were compressed (a
    /// header without a codec means this).
    Raw,
    /// A lossless 8-bit grey PNG, which Foxglove shows: about 0.56 of the raw bytes.
    Png,
    /// qosrt's own lossless codec (`record::gray_codec`), what a recording uses unless told
    /// otherwise: about 0.48 of the raw bytes; the live view and `qosrt replay` read it,
    /// Foxglove does not.
    #[default]
    Compact,
}

impl FrameCodec {
    /// What a recording's header without a codec means: made before frames were compressed.
    pub fn before_compression() -> Self {
        Self::Raw
    }
}

impl std::str::FromStr for FrameCodec {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        match text {
            "compact" => Ok(Self::Compact),
            "png" => Ok(Self::Png),
            "raw" => Ok(Self::Raw),
            _ => Err(format!(
                "expected compact (qosrt's lossless codec, the smallest), png (lossless, \
                 shown by Foxglove) or raw, found `{text}`"
            )),
        }
    }
}

/// Which camera frames a recording keeps. Frames are nearly all of a recording's size (a
/// 640×480 frame is 300 kB; the rest of a second of flight, a few kB).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FramePolicy {
    /// Every frame the runner delivered, and every depth frame: the whole mission replays.
    #[default]
    Every,
    /// Only the frames a task read (most, where the camera is faster than the tasks that
    /// look); each other frame as its size alone. The whole mission replays.
    Consumed,
    /// No frames: telemetry, decisions and every task's outputs only. The tasks that read
    /// frames see none in a replay, so their outputs (and what follows from them) differ; the
    /// rest replays as flown.
    None,
}

impl std::str::FromStr for FramePolicy {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        match text {
            "every" => Ok(Self::Every),
            "consumed" => Ok(Self::Consumed),
            "none" => Ok(Self::None),
            _ => Err(format!(
                "expected every (each frame delivered), consumed (the frames a task read) or none \
                 (telemetry and outputs only), found `{text}`"
            )),
        }
    }
}

/// The topic a camera's frames arrive on.
pub const CAMERA_FRAME_TOPIC: &str = "camera/frame";

/// `[link]`: how `qosrt run` speaks to the autopilot.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkSettings {
    /// MAVLink 2 signing key: a file of 32 bytes, raw or as 64 hex digits (relative to the
    /// config's folder). With it, unsigned messages are refused and what qosrt sends is signed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub signing_key_file: Option<std::path::PathBuf>,
    /// Send LANDING_TARGET from the tracker for the autopilot's own precision landing.
    #[serde(default)]
    pub landing_target: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mission {
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Fraction of the usable battery energy that must remain at touchdown, in [0, 1).
    pub reserve_fraction: f64,
    #[serde(rename = "phase")]
    pub phases: Vec<Phase>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Phase {
    pub name: String,
    /// What the phase is: `transit` (fly out to the meeting point), `track` (follow the
    /// tractor for `duration_s`) or `land` (land on it). Without it, by position: the first of
    /// several phases is the transit, the last the landing, those between track.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<PhaseKind>,
    /// Expected duration at the task levels that do not change it.
    pub duration_s: f64,
    /// When one task's QoS changes how long the phase lasts (a faster marker detector lands
    /// sooner), the duration at each of that task's levels, lowest QoS first.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_by_level: Option<DurationByLevel>,
}

/// What a phase is, which says how it ends and who steers in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PhaseKind {
    /// Fly out to the tractor's meeting point at the follow height; ends on arrival.
    Transit,
    /// Follow the tractor; ends after the phase's duration.
    Track,
    /// Descend onto the pad; ends at touchdown.
    Land,
}

impl PhaseKind {
    /// The kind of phase `index` of `count` where the config names none: the first of several
    /// is the transit, the last the landing, those between track (a single phase lands).
    pub fn by_position(index: usize, count: usize) -> PhaseKind {
        if index + 1 >= count {
            PhaseKind::Land
        } else if index == 0 {
            PhaseKind::Transit
        } else {
            PhaseKind::Track
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            PhaseKind::Transit => "transit",
            PhaseKind::Track => "track",
            PhaseKind::Land => "land",
        }
    }
}

impl fmt::Display for PhaseKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.pad(self.as_str())
    }
}

impl Mission {
    /// Every phase's kind, in flight order: as the config names it, else by position.
    pub fn phase_kinds(&self) -> Vec<PhaseKind> {
        let count = self.phases.len();
        self.phases
            .iter()
            .enumerate()
            .map(|(index, phase)| {
                phase
                    .kind
                    .unwrap_or_else(|| PhaseKind::by_position(index, count))
            })
            .collect()
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DurationByLevel {
    pub task: String,
    pub duration_s: Vec<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Battery {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capacity_wh: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capacity_mah: Option<f64>,
    pub cell_count: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nominal_cell_voltage_v: Option<f64>,
    /// Pack internal resistance (cells, wiring, connectors); default
    /// [`DEFAULT_CELL_RESISTANCE_OHM`] per cell.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub internal_resistance_ohm: Option<f64>,
    /// Cell voltage under load at which the flight must end; default 3.5 V.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub empty_cell_voltage_v: Option<f64>,
}

impl Battery {
    pub fn nominal_voltage_v(&self) -> f64 {
        self.nominal_cell_voltage_v
            .unwrap_or(DEFAULT_NOMINAL_CELL_VOLTAGE_V)
            * f64::from(self.cell_count)
    }

    pub fn internal_resistance_ohm(&self) -> f64 {
        self.internal_resistance_ohm
            .unwrap_or(DEFAULT_CELL_RESISTANCE_OHM * f64::from(self.cell_count))
    }

    /// Nominal charge: `capacity_mah`, or `capacity_wh` ÷ nominal pack voltage.
    pub fn capacity_ah(&self) -> Option<f64> {
        match (self.capacity_wh, self.capacity_mah) {
            (None, Some(mah)) => Some(mah / 1000.0),
            (Some(wh), None) => Some(wh / self.nominal_voltage_v()),
            _ => None,
        }
    }

    /// Nominal energy content: `capacity_wh`, or `capacity_mah` × nominal pack voltage.
    pub fn capacity_wh(&self) -> Option<f64> {
        match (self.capacity_wh, self.capacity_mah) {
            (Some(wh), None) => Some(wh),
            (None, Some(mah)) => Some(mah / 1000.0 * self.nominal_voltage_v()),
            _ => None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Flight {
    /// Electrical power to hover, used for every phase not listed in `phase_power_w`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hover_power_w: Option<f64>,
    /// Flight power per phase, by phase name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub phase_power_w: BTreeMap<String, f64>,
}

impl Flight {
    pub fn power_w(&self, phase: &str) -> Option<f64> {
        self.phase_power_w
            .get(phase)
            .copied()
            .or(self.hover_power_w)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PowerModelConfig {
    /// The board's power with none of the tasks running. Needed where a phase is modelled by
    /// several profiles: each then counts only its power above idle (an additive model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub idle_power_w: Option<f64>,
    /// Interpolation between a profile's grid points: on "log" or "linear" knob axes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis_scale: Option<AxisScaleConfig>,
    #[serde(rename = "profile")]
    pub profiles: Vec<ProfileRef>,
}

impl PowerModelConfig {
    /// The profiles that model `phase`, with their index in `profiles`.
    pub fn profiles_for<'a>(
        &'a self,
        phase: &'a str,
    ) -> impl Iterator<Item = (usize, &'a ProfileRef)> {
        self.profiles
            .iter()
            .enumerate()
            .filter(move |(_, profile)| profile.phases.iter().any(|p| p == phase))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AxisScaleConfig {
    Linear,
    Log,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileRef {
    /// Path of the profile, relative to the config file.
    pub path: String,
    /// The phases whose companion-computer power this profile models.
    pub phases: Vec<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Resource {
    Cpu,
    Gpu,
}

impl fmt::Display for Resource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Resource::Cpu => "cpu",
            Resource::Gpu => "gpu",
        })
    }
}

/// What a task's QoS levels set: a rate (higher is better) or a period (shorter is better).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Knob {
    RateFps,
    PeriodMs,
}

impl Knob {
    pub fn as_str(self) -> &'static str {
        match self {
            Knob::RateFps => "rate_fps",
            Knob::PeriodMs => "period_ms",
        }
    }

    /// Activation period in milliseconds for a level value of this knob.
    pub fn period_ms(self, value: f64) -> f64 {
        match self {
            Knob::RateFps => 1000.0 / value,
            Knob::PeriodMs => value,
        }
    }
}

impl fmt::Display for Knob {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What activates a task: its period (the default), or the arrival of a message on one of its
/// inputs (`trigger = "input:vision/landing_marker"`), its QoS level then being its rate cap.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum TaskTrigger {
    #[default]
    Period,
    Input(String),
}

impl TaskTrigger {
    pub fn is_period(&self) -> bool {
        *self == TaskTrigger::Period
    }

    /// The input topic that triggers the task, if one does.
    pub fn input(&self) -> Option<&str> {
        match self {
            TaskTrigger::Period => None,
            TaskTrigger::Input(topic) => Some(topic),
        }
    }
}

impl TryFrom<String> for TaskTrigger {
    type Error = String;

    fn try_from(text: String) -> Result<Self, Self::Error> {
        match text.strip_prefix("input:") {
            _ if text == "period" => Ok(TaskTrigger::Period),
            Some(topic) if !topic.trim().is_empty() => Ok(TaskTrigger::Input(topic.to_string())),
            _ => Err(format!(
                "trigger `{text}`: expected `period` or `input:TOPIC` (one of the task's inputs, e.g. `input:camera/frame`)"
            )),
        }
    }
}

impl From<TaskTrigger> for String {
    fn from(trigger: TaskTrigger) -> Self {
        match trigger {
            TaskTrigger::Period => "period".to_string(),
            TaskTrigger::Input(topic) => format!("input:{topic}"),
        }
    }
}

impl fmt::Display for TaskTrigger {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&String::from(self.clone()))
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskConfig {
    pub name: String,
    pub plugin: String,
    pub resource: Resource,
    /// CPU cores the task's worker may be pinned to (CPU tasks only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cores: Vec<usize>,
    pub phases: Vec<String>,
    pub weight: f64,
    pub knob: Knob,
    /// Knob values, lowest QoS first.
    pub levels: Vec<f64>,
    /// Utility of each level in [0, 1], non-decreasing.
    pub utility: Vec<f64>,
    /// What the scheduler does when the task fails: `{ policy = "never" }` or
    /// `{ policy = "on_failure", max_restarts = 3 }` (the default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub restart: Option<RestartPolicy>,
    /// What activates the task: `"period"` (the default) or `"input:TOPIC"`.
    #[serde(default, skip_serializing_if = "TaskTrigger::is_period")]
    pub trigger: TaskTrigger,
    /// An input-triggered task also runs after this long without running (never more often
    /// than its level's period): a tracker predicting between fixes, guidance streaming while
    /// the camera is slow. Without it the task runs only on its input.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_idle_ms: Option<f64>,
    /// Free settings handed to the plugin.
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub params: toml::Table,
    /// Folder of the config file the task came from: plugins resolve relative paths in their
    /// params (a model file) against it. `None` for config text parsed without a file.
    #[serde(skip)]
    pub config_dir: Option<std::path::PathBuf>,
    /// The mission's `[camera]` (its defaults without one), filled in at load: the plugins
    /// that project frames read the one camera here, not params of their own.
    #[serde(skip)]
    pub camera: CameraSettings,
}

impl TaskConfig {
    pub fn runs_in(&self, phase: &str) -> bool {
        self.phases.iter().any(|p| p == phase)
    }

    /// The profile knob name of this task's QoS knob (`TASK.KNOB`, e.g. `hazard.rate_fps`).
    pub fn knob_name(&self) -> String {
        format!("{}.{}", self.name, self.knob)
    }

    /// The knob value the task actually runs at on a level of knob value `level_value`, when
    /// its trigger's topic delivers `input_rate_hz` messages a second (`None`: not known). A
    /// periodic task runs at its level. A triggered one runs on each input, at most at its
    /// level's rate, and at least every `max_idle_ms`: min(level, max(input, idle)).
    pub fn running_knob_value(&self, level_value: f64, input_rate_hz: Option<f64>) -> f64 {
        let (TaskTrigger::Input(_), Some(input_rate_hz)) = (&self.trigger, input_rate_hz) else {
            return level_value;
        };
        let idle_rate_hz = self.max_idle_ms.map_or(0.0, |ms| 1000.0 / ms);
        let floor_hz = input_rate_hz.max(idle_rate_hz);
        match self.knob {
            Knob::RateFps => level_value.min(floor_hz),
            // 1000 / 0 is an infinite period: a task that never runs.
            Knob::PeriodMs => level_value.max(1000.0 / floor_hz),
        }
    }
}

impl MissionConfig {
    /// The mission's camera: its `[camera]`, or that section's defaults.
    pub fn camera_settings(&self) -> CameraSettings {
        self.camera.clone().unwrap_or_default()
    }

    /// A number from the `[task.params]` of the first task running `plugin`; TOML integers
    /// count, as they do for the plugins' own parsing.
    pub fn plugin_number(&self, plugin: &str, key: &str) -> Option<f64> {
        let task = self.tasks.iter().find(|t| t.plugin == plugin)?;
        let value = task.params.get(key)?;
        value.as_float().or(value.as_integer().map(|i| i as f64))
    }

    pub fn task(&self, name: &str) -> Option<&TaskConfig> {
        self.tasks.iter().find(|task| task.name == name)
    }

    pub fn phase(&self, name: &str) -> Option<&Phase> {
        self.mission.phases.iter().find(|phase| phase.name == name)
    }
}

/// What to do when a task fails. In TOML: `{ policy = "never" }` or
/// `{ policy = "on_failure", max_restarts = 3 }`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "policy", rename_all = "snake_case", deny_unknown_fields)]
pub enum RestartPolicy {
    /// The first failure is final.
    Never,
    /// Build a fresh instance at the next activation, at most `max_restarts` times in the run.
    OnFailure { max_restarts: u32 },
}

impl Default for RestartPolicy {
    /// A few restarts ride out a transient fault (a dropped camera frame buffer) without
    /// letting a task that always fails burn CPU forever.
    fn default() -> Self {
        RestartPolicy::OnFailure { max_restarts: 3 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::catalog::PluginCatalog;

    const REFERENCE: &str = include_str!("../../../qos.toml");

    #[test]
    fn a_triggered_task_runs_at_its_level_its_input_or_its_idle_rate() {
        let config = load_str(REFERENCE, None, &PluginCatalog::builtin()).unwrap();
        let task = |name: &str| config.task(name).unwrap().clone();
        // Detection, on camera frames, no idle runs: min(level, camera).
        let detection = task("detection");
        assert_eq!(detection.running_knob_value(10.0, Some(4.0)), 4.0);
        assert_eq!(detection.running_knob_value(2.0, Some(4.0)), 2.0);
        assert_eq!(detection.running_knob_value(10.0, None), 10.0);
        assert_eq!(detection.running_knob_value(10.0, Some(0.0)), 0.0);
        // Tracking, period knob, on fixes with a 20 ms idle bound: never slower than 20 ms
        // apart, never faster than its level.
        let tracking = task("tracking");
        assert_eq!(tracking.running_knob_value(20.0, Some(2.0)), 20.0);
        assert_eq!(tracking.running_knob_value(100.0, Some(2.0)), 100.0);
        let mut no_idle = tracking.clone();
        no_idle.max_idle_ms = None;
        assert_eq!(no_idle.running_knob_value(20.0, Some(2.0)), 500.0);
        assert_eq!(no_idle.running_knob_value(20.0, Some(0.0)), f64::INFINITY);
        // A periodic task runs at its level whatever comes in.
        let mut periodic = detection.clone();
        periodic.trigger = TaskTrigger::Period;
        assert_eq!(periodic.running_knob_value(10.0, Some(4.0)), 10.0);
    }

    /// Old configs name no kinds: the first of several phases is the transit, the last the
    /// landing, those between track, as the reference mission names them.
    #[test]
    fn phases_without_a_kind_take_it_from_their_position() {
        let named = reference().mission.phase_kinds();
        assert_eq!(
            named,
            [PhaseKind::Transit, PhaseKind::Track, PhaseKind::Land]
        );
        let unnamed: String = REFERENCE
            .lines()
            .filter(|line| !line.starts_with("kind = "))
            .map(|line| format!("{line}\n"))
            .collect();
        let config = load_str(&unnamed, None, &PluginCatalog::builtin()).unwrap();
        assert!(config.mission.phases.iter().all(|p| p.kind.is_none()));
        assert_eq!(config.mission.phase_kinds(), named);
        let kinds = |count| {
            (0..count)
                .map(|index| PhaseKind::by_position(index, count))
                .collect::<Vec<_>>()
        };
        assert_eq!(kinds(1), [PhaseKind::Land]);
        assert_eq!(kinds(2), [PhaseKind::Transit, PhaseKind::Land]);
        assert_eq!(
            kinds(4),
            [
                PhaseKind::Transit,
                PhaseKind::Track,
                PhaseKind::Track,
                PhaseKind::Land
            ]
        );
    }

    /// Kinds that name a mission the sequencer can fly: tracking straight from take-off (no
    /// transit) is one; a transit after tracking, or a mission that never lands, is not.
    #[test]
    fn phase_kinds_must_fly_in_order() {
        let with_kinds = |kinds: [&str; 3]| {
            let mut text = REFERENCE.to_string();
            for (index, from) in ["transit", "track", "land"].iter().enumerate() {
                text = text.replacen(&format!("kind = \"{from}\""), &format!("kind = {index}"), 1);
            }
            for (index, to) in kinds.iter().enumerate() {
                text = text.replacen(&format!("kind = {index}"), &format!("kind = \"{to}\""), 1);
            }
            load_str(&text, None, &PluginCatalog::builtin())
        };
        assert!(with_kinds(["track", "track", "land"]).is_ok());
        for bad in [
            ["track", "transit", "land"],
            ["transit", "track", "track"],
            ["transit", "land", "land"],
        ] {
            let failure = with_kinds(bad).expect_err(&format!("{bad:?} is refused"));
            assert!(
                format!("{failure:?}").contains("is of kind"),
                "{bad:?}: {failure:?}"
            );
        }
    }

    fn reference() -> MissionConfig {
        load_str(REFERENCE, None, &PluginCatalog::builtin())
            .expect("the reference mission is valid")
    }

    #[test]
    fn serialised_config_parses_back_equal() {
        let config = reference();
        let text = toml::to_string(&config).expect("serialises");
        let again = load_str(&text, None, &PluginCatalog::builtin())
            .unwrap_or_else(|diagnostics| panic!("{diagnostics:?}\n{text}"));
        assert_eq!(config, again);
    }

    #[test]
    fn capacity_from_mah_uses_the_nominal_pack_voltage() {
        let battery = Battery {
            capacity_wh: None,
            capacity_mah: Some(5000.0),
            cell_count: 4,
            nominal_cell_voltage_v: None,
            internal_resistance_ohm: None,
            empty_cell_voltage_v: None,
        };
        // 5 Ah × 4 × 3.7 V
        assert!((battery.capacity_wh().unwrap() - 74.0).abs() < 1e-12);
    }

    #[test]
    fn phase_flight_power_overrides_hover() {
        let config = reference();
        assert_eq!(config.flight.power_w("transit"), Some(190.0));
        let hover_only = Flight {
            hover_power_w: Some(150.0),
            phase_power_w: BTreeMap::new(),
        };
        assert_eq!(hover_only.power_w("anything"), Some(150.0));
    }

    /// Any damage to the text gives a config or located errors, never a panic.
    #[test]
    fn damaged_text_never_panics() {
        let bytes = REFERENCE.as_bytes();
        let mut state: u64 = 12345;
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as usize
        };
        for _ in 0..2000 {
            let mut damaged = bytes.to_vec();
            let bytes_in: &[u8] = b"[]{}=\"'.,#\n 0-1";
            for _ in 0..1 + next() % 4 {
                let at = next() % damaged.len();
                let byte = bytes_in[next() % bytes_in.len()];
                match next() % 3 {
                    0 => damaged[at] = byte,
                    1 => {
                        damaged.remove(at);
                    }
                    _ => damaged.insert(at, byte),
                }
            }
            let text = String::from_utf8_lossy(&damaged);
            if let Err(diagnostics) = load_str(&text, None, &PluginCatalog::builtin()) {
                assert!(!diagnostics.is_empty());
                for diagnostic in diagnostics {
                    assert!(diagnostic.span.is_some(), "{diagnostic:?}");
                }
            }
        }
    }
}
