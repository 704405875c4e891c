//! The catalogue of built-in task plugins: the names `qos.toml` may use in `plugin = "…"`, the
//! resources each can run on, the QoS knobs each understands and the topics each reads and
//! writes. The config is checked against it before anything runs, so a typo in a plugin name, or
//! a task whose input nobody produces, is caught at `qosrt check`, not in flight.

mod rules;

use crate::bus::Topic;
use crate::config::{Knob, Resource};
use crate::topics::{
    CAMERA_FRAME, DEPTH_FRAME, GROUND_STEREO_FIX, HAZARDS, HYBRID_TRACKING_STATUS, LANDING_MARKER,
    LANDING_SETPOINT, MISSION_PHASE, PTU_PAIR, RELATIVE_STATE, VEHICLE_STATE,
};

#[derive(Debug, Clone, PartialEq)]
pub struct PluginInfo {
    pub name: &'static str,
    pub summary: &'static str,
    pub resources: &'static [Resource],
    pub knobs: &'static [Knob],
    /// The topics a task of this plugin reads; the only ones its factory can subscribe to.
    pub inputs: &'static [Port],
    /// The topics it publishes; the only ones its factory can publish on.
    pub outputs: &'static [Port],
}

impl PluginInfo {
    /// Whether the plugin reads `topic` (one of its declared inputs).
    pub fn reads(&self, topic: &str) -> bool {
        self.inputs.iter().any(|port| port.topic == topic)
    }

    /// Whether the plugin publishes `topic` (one of its declared outputs).
    pub fn writes(&self, topic: &str) -> bool {
        self.outputs.iter().any(|port| port.topic == topic)
    }

    /// A user's plugin registered by name alone: it may run anywhere, with either knob, and
    /// declares no ports (set `inputs` and `outputs` to give it some).
    pub const fn user(name: &'static str) -> Self {
        PluginInfo {
            name,
            summary: "user plugin",
            resources: &[Resource::Cpu, Resource::Gpu],
            knobs: &[Knob::RateFps, Knob::PeriodMs],
            inputs: &[],
            outputs: &[],
        }
    }
}

/// A topic a plugin reads or writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Port {
    pub topic: &'static str,
    /// The message type's name.
    pub message: &'static str,
    /// An input the task works without: it uses the topic when something publishes it.
    pub optional: bool,
}

impl Port {
    pub const fn of<T>(topic: Topic<T>) -> Port {
        Port {
            topic: topic.name(),
            message: topic.message(),
            optional: false,
        }
    }

    pub const fn optional<T>(topic: Topic<T>) -> Port {
        Port {
            optional: true,
            ..Port::of(topic)
        }
    }
}

/// A topic the mission itself connects to its tasks, whatever the config: what feeds them (the
/// autopilot, the camera, the mission runner) or what their output drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct MissionPort {
    pub port: Port,
    /// Who publishes it (an input) or reads it (an output), for people.
    pub endpoint: &'static str,
}

/// What `qosrt run` and `qosrt sim` publish for the tasks.
pub const MISSION_INPUTS: &[MissionPort] = &[
    MissionPort {
        port: Port::of(VEHICLE_STATE),
        endpoint: "autopilot",
    },
    MissionPort {
        port: Port::of(CAMERA_FRAME),
        endpoint: "camera",
    },
    MissionPort {
        port: Port::of(MISSION_PHASE),
        endpoint: "mission",
    },
    // Only `qosrt sim` has one (seed 000's hybrid camera array, simulated).
    MissionPort {
        port: Port::of(DEPTH_FRAME),
        endpoint: "depth camera (sim)",
    },
];

/// What the mission runner takes from the tasks.
pub const MISSION_OUTPUTS: &[MissionPort] = &[
    MissionPort {
        port: Port::of(LANDING_SETPOINT),
        endpoint: "autopilot",
    },
    MissionPort {
        port: Port::of(RELATIVE_STATE),
        endpoint: "mission",
    },
];

/// The plugins that ship with qosrt.
pub const BUILTIN_PLUGINS: &[PluginInfo] = &[
    PluginInfo {
        name: "landing_marker",
        summary: "n-fold + ArUco landing-marker detector (CPU, keeps the GPU free)",
        resources: &[Resource::Cpu],
        knobs: &[Knob::RateFps, Knob::PeriodMs],
        inputs: &[Port::of(CAMERA_FRAME)],
        outputs: &[Port::of(LANDING_MARKER)],
    },
    PluginInfo {
        name: "kalman_tracker",
        summary:
            "Kalman filter of the UAV's position relative to the platform, with platform velocity",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
        inputs: &[Port::of(VEHICLE_STATE), Port::of(LANDING_MARKER)],
        outputs: &[Port::of(RELATIVE_STATE)],
    },
    PluginInfo {
        name: "landing_guidance",
        summary: "landing state machine and controller producing setpoints for the autopilot",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
        inputs: &[
            Port::of(VEHICLE_STATE),
            Port::optional(MISSION_PHASE),
            Port::of(RELATIVE_STATE),
        ],
        outputs: &[Port::of(LANDING_SETPOINT)],
    },
    PluginInfo {
        name: "hazard_cnn",
        summary: "CNN hazard detector (people, animals, vehicles); GPU, or CPU fallback",
        resources: &[Resource::Gpu, Resource::Cpu],
        knobs: &[Knob::RateFps, Knob::PeriodMs],
        inputs: &[
            Port::of(CAMERA_FRAME),
            Port::of(VEHICLE_STATE),
            Port::optional(RELATIVE_STATE),
        ],
        outputs: &[Port::of(HAZARDS)],
    },
    PluginInfo {
        name: "ground_stereo",
        summary: "ground-based PTU stereo (seed 001): the aircraft's runway position from two PTUs",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
        inputs: &[Port::of(PTU_PAIR)],
        outputs: &[Port::of(GROUND_STEREO_FIX)],
    },
    PluginInfo {
        name: "hybrid_tracking",
        summary: "seed 000's UGV state estimation: tracking by detection, stereo altitude, \
                  homography motion compensation, velocity observer",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
        inputs: &[
            Port::of(VEHICLE_STATE),
            Port::of(CAMERA_FRAME),
            Port::optional(DEPTH_FRAME),
            Port::of(LANDING_MARKER),
        ],
        outputs: &[Port::of(RELATIVE_STATE), Port::of(HYBRID_TRACKING_STATUS)],
    },
];

/// A set of plugins the config may name.
#[derive(Debug, Clone)]
pub struct PluginCatalog {
    plugins: Vec<PluginInfo>,
}

impl Default for PluginCatalog {
    fn default() -> Self {
        Self::builtin()
    }
}

impl PluginCatalog {
    pub fn builtin() -> Self {
        Self {
            plugins: BUILTIN_PLUGINS.to_vec(),
        }
    }

    /// A catalogue of exactly these plugins (a registry's, with its users' own plugins).
    pub fn from_plugins(plugins: impl IntoIterator<Item = PluginInfo>) -> Self {
        Self {
            plugins: plugins.into_iter().collect(),
        }
    }

    pub fn get(&self, name: &str) -> Option<&PluginInfo> {
        self.plugins.iter().find(|plugin| plugin.name == name)
    }

    pub fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.plugins.iter().map(|plugin| plugin.name)
    }

    /// The plugins that publish `topic`.
    pub fn producers_of<'a>(&'a self, topic: &'a str) -> impl Iterator<Item = &'static str> + 'a {
        self.plugins
            .iter()
            .filter(move |plugin| plugin.writes(topic))
            .map(|plugin| plugin.name)
    }
}
