//! The catalogue of built-in task plugins: the names `qos.toml` may use in `plugin = "…"`, the
//! resources each can run on and the QoS knobs each understands. The config is checked against it
//! before anything runs, so a typo in a plugin name is caught at `qosrt check`, not in flight.

use crate::config::{Knob, Resource};

#[derive(Debug, Clone, PartialEq)]
pub struct PluginInfo {
    pub name: &'static str,
    pub summary: &'static str,
    pub resources: &'static [Resource],
    pub knobs: &'static [Knob],
}

/// The plugins that ship with qosrt.
pub const BUILTIN_PLUGINS: &[PluginInfo] = &[
    PluginInfo {
        name: "landing_marker",
        summary: "n-fold + ArUco landing-marker detector (CPU, keeps the GPU free)",
        resources: &[Resource::Cpu],
        knobs: &[Knob::RateFps, Knob::PeriodMs],
    },
    PluginInfo {
        name: "kalman_tracker",
        summary:
            "Kalman filter of the UAV's position relative to the platform, with platform velocity",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
    },
    PluginInfo {
        name: "landing_guidance",
        summary: "landing state machine and controller producing setpoints for the autopilot",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
    },
    PluginInfo {
        name: "hazard_cnn",
        summary: "CNN hazard detector (people, animals, vehicles); GPU, or CPU fallback",
        resources: &[Resource::Gpu, Resource::Cpu],
        knobs: &[Knob::RateFps, Knob::PeriodMs],
    },
    PluginInfo {
        name: "ground_stereo",
        summary: "ground-based PTU stereo (seed 001): the aircraft's runway position from two PTUs",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
    },
    PluginInfo {
        name: "hybrid_tracking",
        summary: "seed 000's UGV state estimation: tracking by detection, stereo altitude, \
                  homography motion compensation, velocity observer",
        resources: &[Resource::Cpu],
        knobs: &[Knob::PeriodMs, Knob::RateFps],
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
}
