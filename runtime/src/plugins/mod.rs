//! The task plugins built into qosrt, and the registry that holds them.

pub mod landing_marker;

use crate::registry::{PluginRegistry, RegistryError};

/// A registry with every built-in plugin; users add their own to it.
pub fn builtin_registry() -> Result<PluginRegistry, RegistryError> {
    let mut registry = PluginRegistry::new();
    landing_marker::register(&mut registry)?;
    Ok(registry)
}
