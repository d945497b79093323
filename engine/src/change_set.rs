//! Change sets as the change set JSON of the contract (`cli.md`): what a review (or a manual
//! request) decided, why, at what cost, as actions and as the RDF delta of the environment
//! graph; and whether the executors applied it. Serialises and deserialises, so the history
//! read back from the knowledge base is typed.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use crate::compile::{Compiled, CostSummary};
use crate::ids::{ChangeSetId, Cid, Qid};
use crate::model::Action;

/// Why a change set was made.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Cause {
    /// `dyknow explore`, offline.
    Explore,
    /// A review started on demand (`POST /review`), at the end of a stable interval, or after
    /// a perturbation that names no target or CU.
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
        /// The CU (the first, when one review repairs several crashes).
        cu: Cid,
        /// The other CUs that crashed before the review began (a burst of crashes is
        /// repaired by one review, `--review-spacing-ms`).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        also: Vec<Cid>,
    },
    /// A client asked for it (Spawn, Destroy).
    Manual,
    /// Transformation specs were posted again with another implementation (type, source,
    /// parameters or executor): the CUs running the old one left the model (they "require
    /// removal", seed Ch. 4), and this change set replaces them. Not a crash.
    SpecChanged {
        /// The CUs that were removed.
        cus: Vec<Cid>,
    },
    /// The manager reconciled its model with what the executors report (at start-up, or when
    /// an executor reappears): CUs it knows adopted, CUs it does not know stopped, CUs that
    /// should run and run nowhere respawned.
    Reconcile {
        /// The executor that reappeared; absent for the start-up pass over every executor.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        executor: Option<String>,
    },
}

impl Cause {
    /// The cause's `kind` in change set JSON (`target-added`, `cu-crashed`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Explore => "explore",
            Self::Review => "review",
            Self::TargetAdded { .. } => "target-added",
            Self::TargetReleased { .. } => "target-released",
            Self::CuCrashed { .. } => "cu-crashed",
            Self::Manual => "manual",
            Self::SpecChanged { .. } => "spec-changed",
            Self::Reconcile { .. } => "reconcile",
        }
    }

    /// The causes of one review, merged: one `cu-crashed` naming every crashed CU (the first
    /// as `cu`, the others in `also`, in the order they came), one `spec-changed` naming every
    /// replaced CU, each other cause once; in the order of their first appearance. The first
    /// is the change set's [`ChangeSet::cause`], the others its
    /// [`ChangeSet::other_causes`]. Empty when `causes` is.
    pub fn merged(causes: &[Self]) -> Vec<Self> {
        let mut merged: Vec<Self> = Vec::new();
        for cause in causes {
            if merged.contains(cause) {
                continue;
            }
            // The first of a kind that merges starts empty, so that it is merged into as the
            // later ones are (a CU it names twice is named once).
            match cause {
                Self::CuCrashed { cu, .. } if !merged.iter().any(|m| m.kind() == cause.kind()) => {
                    merged.push(Self::CuCrashed {
                        cu: cu.clone(),
                        also: Vec::new(),
                    });
                }
                Self::SpecChanged { .. } if !merged.iter().any(|m| m.kind() == cause.kind()) => {
                    merged.push(Self::SpecChanged { cus: Vec::new() });
                }
                _ => {}
            }
            let same_kind = merged.iter_mut().find(|m| {
                m.kind() == cause.kind()
                    && matches!(m, Self::CuCrashed { .. } | Self::SpecChanged { .. })
            });
            match (same_kind, cause) {
                (
                    Some(Self::CuCrashed { cu: first, also }),
                    Self::CuCrashed {
                        cu: more,
                        also: yet_more,
                    },
                ) => {
                    for cu in std::iter::once(more).chain(yet_more) {
                        if cu != first && !also.contains(cu) {
                            also.push(cu.clone());
                        }
                    }
                }
                (Some(Self::SpecChanged { cus }), Self::SpecChanged { cus: more }) => {
                    for cu in more {
                        if !cus.contains(cu) {
                            cus.push(cu.clone());
                        }
                    }
                }
                _ => merged.push(cause.clone()),
            }
        }
        merged
    }
}

/// The RDF delta of a change set, as N-Triples.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct NTriplesDelta {
    /// Triples to insert.
    pub insert: String,
    /// Triples to delete.
    pub delete: String,
}

impl NTriplesDelta {
    /// This delta, then `later`, as one: applied as every delta is (its deletions, then its
    /// insertions), it gives what applying the two in turn gives. Lines are whole N-Triples
    /// statements, one per line; the result's are sorted and distinct.
    #[must_use]
    pub fn then(&self, later: &Self) -> Self {
        let lines = |text: &str| -> BTreeSet<String> {
            text.lines()
                .filter(|l| !l.trim().is_empty())
                .map(str::to_owned)
                .collect()
        };
        let later_deleted = lines(&later.delete);
        let mut delete = lines(&self.delete);
        delete.extend(later_deleted.iter().cloned());
        let mut insert: BTreeSet<String> = lines(&self.insert)
            .into_iter()
            .filter(|l| !later_deleted.contains(l))
            .collect();
        insert.extend(lines(&later.insert));
        let text = |set: BTreeSet<String>| set.into_iter().map(|l| l + "\n").collect();
        Self {
            insert: text(insert),
            delete: text(delete),
        }
    }

    /// Whether it changes nothing.
    pub fn is_empty(&self) -> bool {
        self.insert.trim().is_empty() && self.delete.trim().is_empty()
    }
}

/// Where a change set is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChangeSetStatus {
    /// Decided, not applied (`dyknow explore`).
    Planned,
    /// Every executor involved applied its actions.
    Applied,
    /// Some action failed (see [`ChangeSet::failures`]); its CU is treated as crashed.
    Failed,
}

impl ChangeSetStatus {
    /// Records written before change sets had a status were applied (to the model).
    fn recorded_before_statuses() -> Self {
        Self::Applied
    }
}

/// An action an executor could not apply, and why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ActionFailure {
    /// The index of the action in [`ChangeSet::actions`].
    pub action: usize,
    /// Its CU.
    pub cu: Cid,
    /// Why it failed.
    pub reason: String,
}

/// A CU's life after a change set touched it, as its executor acknowledged it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CuOutcomeState {
    /// Spawned or rewired, and running.
    Running,
    /// Destroyed.
    Stopped,
    /// An action on it failed (or its executor vanished): treated as crashed.
    Crashed,
}

/// What became of a CU a change set touched: the executor hosting it and its state.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CuOutcome {
    /// The executor that applied its actions (none when no executor could take it).
    pub executor: Option<String>,
    /// Its state once the change set was applied.
    pub state: CuOutcomeState,
}

/// A change set as the contract's change set JSON gives it, plus what the search could not do
/// and how its application went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChangeSet {
    /// `cs-N`.
    pub id: ChangeSetId,
    /// When it was made (RFC 3339, UTC).
    pub at: String,
    /// Why: the first of the causes the review served ([`Cause::merged`]).
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
    /// the search short, and for change sets no search made).
    pub optimal: bool,
    /// Planned, applied, or failed.
    #[serde(default = "ChangeSetStatus::recorded_before_statuses")]
    pub status: ChangeSetStatus,
    /// The actions that failed, when the status is `failed`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub failures: Vec<ActionFailure>,
    /// The CUs its actions touched, with their executor and state once applied (empty in
    /// model-only mode, where nothing runs).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub cus: BTreeMap<Cid, CuOutcome>,
    /// The other causes the same review served, merged ([`Cause::merged`]): a target added
    /// while crashes were being repaired, say. Absent from JSON when there are none; last in
    /// it, so that a change set's `cause` is followed by its `cost` as before (the README's
    /// tour reads the two together with `grep`, and failed when a review served two targets).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub other_causes: Vec<Cause>,
}

impl ChangeSet {
    /// A planned change set from COMPILE's result and its RDF delta, made now.
    pub fn new(id: ChangeSetId, cause: Cause, compiled: Compiled, delta: NTriplesDelta) -> Self {
        Self {
            id,
            at: rfc3339(SystemTime::now()),
            cause,
            cost: compiled.cost,
            actions: compiled.actions,
            delta,
            unsatisfied_targets: compiled.unsatisfied_targets,
            optimal: compiled.optimal,
            status: ChangeSetStatus::Planned,
            failures: Vec::new(),
            cus: BTreeMap::new(),
            other_causes: Vec::new(),
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

    /// `then` composes: applying `a.then(b)` is applying `a`, then `b`, whatever the model and
    /// the deltas (a triple deleted and inserted by one delta stays).
    mod then {
        use super::*;
        use proptest::prelude::*;

        fn apply(model: &BTreeSet<String>, delta: &NTriplesDelta) -> BTreeSet<String> {
            let mut out = model.clone();
            for l in delta.delete.lines() {
                out.remove(l);
            }
            out.extend(delta.insert.lines().map(str::to_owned));
            out
        }

        fn delta() -> impl Strategy<Value = NTriplesDelta> {
            let lines = proptest::collection::btree_set(0u8..8, 0..6).prop_map(|s| {
                s.into_iter()
                    .map(|n| format!("<urn:s> <urn:p> <urn:o{n}> .\n"))
                    .collect::<String>()
            });
            (lines.clone(), lines).prop_map(|(insert, delete)| NTriplesDelta { insert, delete })
        }

        proptest! {
            #[test]
            fn applying_the_composition_is_applying_both_in_turn(
                model in proptest::collection::btree_set(0u8..8, 0..8),
                a in delta(),
                b in delta(),
            ) {
                let model: BTreeSet<String> = model
                    .into_iter()
                    .map(|n| format!("<urn:s> <urn:p> <urn:o{n}> ."))
                    .collect();
                prop_assert_eq!(apply(&apply(&model, &a), &b), apply(&model, &a.then(&b)));
            }
        }
    }
    /// `Cause::merged` names every CU and target it was given, once, in one cause per kind
    /// for crashes and replacements, leads with the first cause's kind, and is idempotent.
    mod merged {
        use super::*;
        use proptest::prelude::*;

        fn cause() -> impl Strategy<Value = Cause> {
            let cu = (0u8..6).prop_map(|n| Cid::from(format!("cu-{n}")));
            prop_oneof![
                Just(Cause::Review),
                Just(Cause::Manual),
                (0u8..3).prop_map(|n| Cause::TargetAdded {
                    target: format!("q{n}").into()
                }),
                (0u8..3).prop_map(|n| Cause::TargetReleased {
                    target: format!("q{n}").into()
                }),
                (cu.clone(), proptest::collection::vec(cu.clone(), 0..3))
                    .prop_map(|(cu, also)| Cause::CuCrashed { cu, also }),
                proptest::collection::vec(cu, 1..3).prop_map(|cus| Cause::SpecChanged { cus }),
            ]
        }

        fn crashed(causes: &[Cause]) -> BTreeSet<Cid> {
            causes
                .iter()
                .flat_map(|c| match c {
                    Cause::CuCrashed { cu, also } => {
                        std::iter::once(cu).chain(also).cloned().collect()
                    }
                    _ => Vec::new(),
                })
                .collect()
        }

        fn replaced(causes: &[Cause]) -> BTreeSet<Cid> {
            causes
                .iter()
                .flat_map(|c| match c {
                    Cause::SpecChanged { cus } => cus.clone(),
                    _ => Vec::new(),
                })
                .collect()
        }

        proptest! {
            #[test]
            fn every_cu_and_target_is_named_once(causes in proptest::collection::vec(cause(), 0..10)) {
                let merged = Cause::merged(&causes);
                prop_assert_eq!(merged.first().map(Cause::kind), causes.first().map(Cause::kind));
                prop_assert_eq!(crashed(&merged), crashed(&causes));
                prop_assert_eq!(replaced(&merged), replaced(&causes));
                for kind in ["cu-crashed", "spec-changed"] {
                    prop_assert!(merged.iter().filter(|c| c.kind() == kind).count() <= 1);
                }
                for cause in &merged {
                    match cause {
                        Cause::CuCrashed { cu, also } => {
                            let mut named: Vec<&Cid> = also.iter().collect();
                            named.push(cu);
                            let distinct: BTreeSet<&Cid> = named.iter().copied().collect();
                            prop_assert_eq!(distinct.len(), named.len(), "{:?}", cause);
                        }
                        Cause::SpecChanged { cus } => {
                            let distinct: BTreeSet<&Cid> = cus.iter().collect();
                            prop_assert_eq!(distinct.len(), cus.len(), "{:?}", cause);
                        }
                        other => {
                            prop_assert!(causes.contains(other));
                            prop_assert_eq!(merged.iter().filter(|c| *c == other).count(), 1);
                        }
                    }
                }
                for cause in &causes {
                    if !matches!(cause, Cause::CuCrashed { .. } | Cause::SpecChanged { .. }) {
                        prop_assert!(merged.contains(cause), "{:?} lost", cause);
                    }
                }
                prop_assert_eq!(Cause::merged(&merged), merged);
            }
        }

        #[test]
        fn crashes_and_a_target_make_a_crash_cause_and_another() {
            let crash = |cu: &str| Cause::CuCrashed {
                cu: cu.into(),
                also: Vec::new(),
            };
            let target = Cause::TargetAdded {
                target: "q1".into(),
            };
            assert_eq!(
                Cause::merged(&[crash("cu-1"), target.clone(), crash("cu-2"), crash("cu-1")]),
                [
                    Cause::CuCrashed {
                        cu: "cu-1".into(),
                        also: vec!["cu-2".into()]
                    },
                    target
                ]
            );
        }
    }

    use std::time::Duration;

    #[test]
    fn a_change_set_round_trips_through_json() {
        let change_set = ChangeSet {
            id: ChangeSetId::numbered(2),
            at: "2026-11-21T12:00:00Z".to_owned(),
            cause: Cause::CuCrashed {
                cu: "cu-3".into(),
                also: vec!["cu-4".into()],
            },
            other_causes: vec![Cause::TargetAdded {
                target: "qid9".into(),
            }],
            cost: CostSummary {
                total: 31.0,
                labour: 1.0,
                upkeep_per_time_unit: 3.0,
                horizon: 10.0,
            },
            actions: vec![
                Action::Spawn {
                    cu: "cu-4".into(),
                    transformation: "tid2".into(),
                },
                Action::ConnectIn {
                    cu: "cu-4".into(),
                    port: "in".to_owned(),
                    channel: "ch-1".into(),
                },
                Action::DisconnectOut {
                    cu: "cu-2".into(),
                    port: "out".to_owned(),
                },
                Action::Destroy { cu: "cu-1".into() },
            ],
            delta: NTriplesDelta {
                insert: "<urn:a> <urn:b> <urn:c> .\n".to_owned(),
                delete: String::new(),
            },
            unsatisfied_targets: vec!["qid9".into()],
            optimal: true,
            status: ChangeSetStatus::Failed,
            failures: vec![ActionFailure {
                action: 0,
                cu: "cu-4".into(),
                reason: "no executor runs tid2".to_owned(),
            }],
            cus: BTreeMap::from([
                (
                    "cu-4".into(),
                    CuOutcome {
                        executor: None,
                        state: CuOutcomeState::Crashed,
                    },
                ),
                (
                    "cu-2".into(),
                    CuOutcome {
                        executor: Some("local".to_owned()),
                        state: CuOutcomeState::Running,
                    },
                ),
            ]),
        };
        let json = serde_json::to_value(&change_set).expect("serialise");
        // The contract's field names and spellings.
        assert_eq!(json["id"], "cs-2");
        assert_eq!(
            json["cause"],
            serde_json::json!({"kind": "cu-crashed", "cu": "cu-3", "also": ["cu-4"]})
        );
        assert_eq!(
            json["other_causes"],
            serde_json::json!([{"kind": "target-added", "target": "qid9"}])
        );
        assert_eq!(
            json["actions"][1],
            serde_json::json!({"action": "connect-in", "cu": "cu-4", "port": "in", "channel": "ch-1"})
        );
        assert_eq!(json["status"], "failed");
        assert_eq!(
            json["cus"],
            serde_json::json!({
                "cu-2": {"executor": "local", "state": "running"},
                "cu-4": {"executor": null, "state": "crashed"}
            })
        );
        assert_eq!(json["cause"]["kind"], change_set.cause.kind());
        let back: ChangeSet = serde_json::from_value(json).expect("deserialise");
        assert_eq!(back, change_set);
        // A record from before statuses existed reads as applied, without failures.
        let mut old = serde_json::to_value(&change_set).expect("serialise");
        let fields = old.as_object_mut().expect("an object");
        fields.remove("status");
        fields.remove("failures");
        fields.remove("cus");
        fields.remove("other_causes");
        let old: ChangeSet = serde_json::from_value(old).expect("deserialise");
        assert_eq!(old.status, ChangeSetStatus::Applied);
        assert!(old.failures.is_empty());
        assert!(old.cus.is_empty());
        assert!(old.other_causes.is_empty());
    }

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
