//! Formula groups (the DyKnow thesis, Ch. 5.4; contract `groups.md`): a set of MSTL formulas
//! progressed together over one state stream that the environment produces. This crate is the
//! part that knows neither RDF nor Zenoh:
//! - [`spec`]: a group's definition as posted, its validation, the ground symbols of its
//!   formulas and the targets they become (label, channel, tag);
//! - [`sync`]: the symbol streams synchronised into states (`wait`, `hold`, `event`), driven by
//!   a clock the caller passes, so crafted streams test it exactly;
//! - [`progression`]: the formulas progressed over those states with `dyknow-mstl`'s monitor
//!   and state-stream core, and each state recorded as a `dyknow check` trace line.
//!
//! The service (`dyknow-server`, `server/src/groups/`) subscribes to the target channels,
//! persists groups and serves them over HTTP.

pub mod progression;
pub mod spec;
pub mod sync;

pub use progression::{Progression, StreamKind, Taken, TraceHeader, VerdictLine};
pub use spec::{Grounding, GroupSpec, SpecError, TargetTag};
pub use sync::{Policy, PolicyFields, StreamStats, SyncState, Synchroniser};
