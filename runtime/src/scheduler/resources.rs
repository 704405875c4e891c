//! Exclusive resources. The GPU runs one network at a time, so one task holds it: a second
//! claimant is refused with a named error (the config check refuses such a config earlier; this
//! is the run-time guarantee, also across schedulers sharing one [`Resources`]).

use crate::config::Resource;
use std::fmt;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ResourceError {
    #[error("task `{claimant}` cannot claim the {resource}: task `{holder}` holds it, and the {resource} is exclusive")]
    Busy {
        resource: Resource,
        holder: String,
        claimant: String,
    },
}

/// A resource at most one task holds at a time. Clones share it.
#[derive(Clone)]
pub struct ExclusiveResource {
    resource: Resource,
    holder: Arc<Mutex<Option<String>>>,
}

impl fmt::Debug for ExclusiveResource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ExclusiveResource")
            .field("resource", &self.resource)
            .field("holder", &self.holder())
            .finish()
    }
}

impl ExclusiveResource {
    pub fn new(resource: Resource) -> Self {
        ExclusiveResource {
            resource,
            holder: Arc::new(Mutex::new(None)),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Option<String>> {
        self.holder.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Claims the resource for `claimant` until the lease is dropped.
    pub fn claim(&self, claimant: &str) -> Result<ResourceLease, ResourceError> {
        let mut holder = self.lock();
        if let Some(existing) = holder.as_ref() {
            return Err(ResourceError::Busy {
                resource: self.resource,
                holder: existing.clone(),
                claimant: claimant.to_string(),
            });
        }
        *holder = Some(claimant.to_string());
        Ok(ResourceLease {
            resource: self.clone(),
        })
    }

    /// The task holding it now.
    pub fn holder(&self) -> Option<String> {
        self.lock().clone()
    }
}

/// Holds an [`ExclusiveResource`]; dropping it releases the resource.
pub struct ResourceLease {
    resource: ExclusiveResource,
}

impl fmt::Debug for ResourceLease {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ResourceLease")
            .field("resource", &self.resource.resource)
            .finish()
    }
}

impl Drop for ResourceLease {
    fn drop(&mut self) {
        *self.resource.lock() = None;
    }
}

/// The board's exclusive resources, shared by everything that runs tasks on it.
#[derive(Debug, Clone)]
pub struct Resources {
    gpu: ExclusiveResource,
}

impl Default for Resources {
    fn default() -> Self {
        Resources {
            gpu: ExclusiveResource::new(Resource::Gpu),
        }
    }
}

impl Resources {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn gpu(&self) -> &ExclusiveResource {
        &self.gpu
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_holder_at_a_time_released_on_drop() {
        let resources = Resources::new();
        let lease = resources.gpu().claim("hazard").unwrap();
        assert_eq!(resources.gpu().holder().as_deref(), Some("hazard"));
        let shared = resources.clone();
        assert_eq!(
            shared.gpu().claim("detection").unwrap_err(),
            ResourceError::Busy {
                resource: Resource::Gpu,
                holder: "hazard".into(),
                claimant: "detection".into(),
            }
        );
        drop(lease);
        assert_eq!(resources.gpu().holder(), None);
        let _lease = shared.gpu().claim("detection").unwrap();
    }
}
