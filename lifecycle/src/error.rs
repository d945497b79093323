//! The life-cycle's errors.

use dyknow_engine::{ChangeSetId, Cid, Tid};
use dyknow_store::{IngestError, ModelReadError};

/// A request to change the configuration was refused, or the knowledge base failed. Nothing
/// was applied or recorded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LifecycleError {
    /// No computation unit has this name.
    #[error("no computation unit named {0:?}")]
    UnknownCu(Cid),
    /// No transformation has this label.
    #[error("no transformation labelled {0:?}")]
    UnknownTransformation(Tid),
    /// The transformation is registered, but no executor can run it now (Spawn).
    #[error("transformation {transformation:?} cannot run now: {why}")]
    NotRunnable {
        /// The transformation.
        transformation: Tid,
        /// Why not, as the executors say (`GET /transformations/{label}`'s `why`).
        why: String,
    },
    /// A computation unit of this name exists.
    #[error("a computation unit named {0:?} exists")]
    NameTaken(Cid),
    /// Protected computation units are never destroyed on request.
    #[error("computation unit {0:?} is protected")]
    Protected(Cid),
    /// A computation unit's name must not be empty (or blank).
    #[error("a computation unit's name must not be empty")]
    EmptyName,
    /// A computation unit's name must be one key chunk (`executors.md`: executors address
    /// CUs by name on the data plane).
    #[error("{0}")]
    InvalidName(String),
    /// An observed cost must be a non-negative number up to [`dyknow_engine::MAX_COST`].
    #[error("{what} must be a non-negative number up to 1e12, not {value}")]
    InvalidCost {
        /// `labour` or `upkeep`.
        what: &'static str,
        /// The value given.
        value: f64,
    },
    /// The executor could not apply the change set made for the request; the change set is
    /// recorded as failed and the CU treated as crashed.
    #[error("{change_set}: the executor could not apply the action on {cu:?}: {reason}")]
    NotApplied {
        /// The change set, recorded with its failure.
        change_set: ChangeSetId,
        /// The CU of the failed action.
        cu: Cid,
        /// The executor's reason.
        reason: String,
    },
    /// SetConfig named a port the CU's transformation does not have.
    #[error("computation unit {cu:?} has no {direction} port {port:?}")]
    UnknownPort {
        /// The CU.
        cu: Cid,
        /// `in` or `out`.
        direction: &'static str,
        /// The port.
        port: String,
    },
    /// SetConfig would make a second CU publish on a channel.
    #[error(
        "channel {channel:?} has a publisher already ({publisher:?}): one publisher per channel"
    )]
    SharedChannel {
        /// The channel.
        channel: String,
        /// The CU publishing on it.
        publisher: Cid,
    },
    /// A channel name that is not a key expression on the data plane.
    #[error("{0}")]
    InvalidChannel(String),
    /// Reading the model from the knowledge base failed.
    #[error(transparent)]
    Read(#[from] ModelReadError),
    /// Writing the model was refused or failed.
    #[error(transparent)]
    Write(#[from] IngestError),
}
