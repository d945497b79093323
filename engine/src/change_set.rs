//! Change sets as the change set JSON of the contract (`cli.md`) and as RDF deltas.

use std::time::{SystemTime, UNIX_EPOCH};

use serde::Serialize;

use crate::compile::{Compiled, CostSummary};
use crate::knowledge::Delta;
use crate::model::{Action, Qid};

/// Why a change set was made.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Cause {
    /// `dyknow explore`, offline.
    Explore,
    /// A review started on demand (`POST /review`).
    Review,
    /// A target was added.
    TargetAdded {
        /// The target.
        target: Qid,
    },
    /// A target was released.
    TargetReleased {
        /// The target.
        target: Qid,
    },
    /// A CU crashed.
    CuCrashed {
        /// The CU.
        cu: String,
    },
}

/// The RDF delta of a change set, as N-Triples.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct NTriplesDelta {
    /// Triples to insert.
    pub insert: String,
    /// Triples to delete.
    pub delete: String,
}

/// A change set as the contract's change set JSON gives it, plus what the search could not do.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChangeSet {
    /// `cs-N`.
    pub id: String,
    /// When it was made (RFC 3339, UTC).
    pub at: String,
    /// Why.
    pub cause: Cause,
    /// The estimated cost (Def. 34).
    pub cost: CostSummary,
    /// The actions (Defs. 23–30).
    pub actions: Vec<Action>,
    /// The change to the environment graph.
    pub delta: NTriplesDelta,
    /// Targets left unsatisfied because no valid configuration exists (the relaxation).
    pub unsatisfied_targets: Vec<Qid>,
    /// Whether EXPLORE proved the change set optimal (false when the any-time timeout cut
    /// the search short).
    pub optimal: bool,
}

impl ChangeSet {
    /// A change set from COMPILE's result and its RDF delta.
    pub fn new(id: String, cause: Cause, compiled: Compiled, delta: &Delta) -> Self {
        Self {
            id,
            at: rfc3339(SystemTime::now()),
            cause,
            cost: compiled.cost,
            actions: compiled.actions,
            delta: NTriplesDelta {
                insert: delta.insert_ntriples(),
                delete: delta.delete_ntriples(),
            },
            unsatisfied_targets: compiled.unsatisfied_targets,
            optimal: compiled.optimal,
        }
    }
}

/// `time` as RFC 3339 in UTC, to the second (`2026-11-21T12:00:00Z`).
pub fn rfc3339(time: SystemTime) -> String {
    let secs = time.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let (days, rem) = (secs / 86_400, secs % 86_400);
    // Civil from days (H. Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1_460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rem / 3_600,
        rem % 3_600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn rfc3339_formats_known_instants() {
        assert_eq!(rfc3339(UNIX_EPOCH), "1970-01-01T00:00:00Z");
        assert_eq!(
            rfc3339(UNIX_EPOCH + Duration::from_secs(1_795_262_400)),
            "2026-11-21T12:00:00Z"
        );
        assert_eq!(
            rfc3339(UNIX_EPOCH + Duration::from_secs(951_782_400)),
            "2000-02-29T00:00:00Z"
        );
    }
}
