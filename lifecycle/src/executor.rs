//! The seam between the life-cycle and the running system: an [`Executor`] applies the change
//! sets the life-cycle decides to real computation units (the seed's nodelet proxy, Ch.
//! 5.2.1–5.3) and says which actions it could not apply.

use dyknow_engine::{ActionFailure, ChangeSet};

/// What an executor did with a change set.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Applied {
    /// The actions that failed, with their CU and why; empty when every action was applied.
    pub failures: Vec<ActionFailure>,
}

impl Applied {
    /// Every action was applied.
    pub fn all() -> Self {
        Self::default()
    }
}

/// Applies change sets to the running system. The life-cycle calls [`Executor::apply`] for
/// every change set it makes (reviews, Spawn, Destroy), one at a time, holding its
/// configuration lock; then it writes the model and records the change set with its status.
/// The CU of a failed action is treated as crashed: it leaves the model and a review repairs
/// the configuration.
pub trait Executor: Send + Sync {
    /// Applies the actions of `change_set` in order (each CU reconfigured make before break)
    /// and reports those that failed.
    fn apply(&self, change_set: &ChangeSet) -> Applied;
}

/// The executor of a service that runs no computation units (`dyknow serve --model-only`):
/// change sets change the model only, which the life-cycle writes for every executor, so
/// there is nothing more to apply and nothing fails.
#[derive(Debug, Clone, Copy, Default)]
pub struct ModelOnly;

impl Executor for ModelOnly {
    fn apply(&self, _change_set: &ChangeSet) -> Applied {
        Applied::all()
    }
}
