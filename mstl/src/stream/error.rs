//! Why a state cannot be taken into a [`StateStream`](super::StateStream), with the regions,
//! landmarks and timestamps involved.

use dyknow_rcc8::Relation;

use crate::monitor::StepError;

/// Why a state (or one of its spatial constraints) is refused. A refused state leaves the
/// stream as it was; a landmark conflict found while deciding an atom
/// ([`StateStream::take_conflict`](super::StateStream::take_conflict)) comes after the step.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum StreamError {
    /// Timestamps must strictly increase.
    #[error("timestamp {t} does not follow {previous} (timestamps must strictly increase)")]
    NotIncreasing {
        /// The previous state's timestamp (ms).
        previous: u64,
        /// The refused timestamp (ms).
        t: u64,
    },
    /// A constraint that allows no relation: the empty set, or a set without `EQ` between a
    /// region and itself.
    #[error("{relation} between {x} and {y}: no relation is possible (a region is EQ to itself)")]
    NoRelation {
        /// The first region, as given.
        x: String,
        /// The second region, as given.
        y: String,
        /// The relations given.
        relation: Relation,
    },
    /// The constraints given for one pair of regions within a state have no relation in
    /// common.
    #[error("the constraints between {x} and {y} contradict each other")]
    Contradictory {
        /// The region whose name sorts first.
        x: String,
        /// The other region.
        y: String,
    },
    /// The relations between static regions contradict each other or what earlier states
    /// observed or inferred between them (the split of Ch. 3.4.2: they never change).
    #[error(
        "the relations between static regions contradict each other or what held between them before: no relation is possible between {x} and {y}"
    )]
    StaticConflict {
        /// A static region.
        x: String,
        /// Another static region, between which and `x` closure left no relation.
        y: String,
    },
    /// A state's spatial constraints (with what is known between static regions) are
    /// inconsistent: their algebraic closure leaves no relation between two regions.
    #[error(
        "the spatial constraints are inconsistent: no relation is possible between {x} and {y}"
    )]
    Inconsistent {
        /// A region.
        x: String,
        /// Another region, between which and `x` closure left no relation.
        y: String,
    },
    /// Landmarks that cannot all be rigid between two states (the seed's (3.26)): the
    /// extended spatial relation matrix of the two states (Def. 13) with every one of them
    /// `EQ` to itself (Defs. 14–15) is inconsistent.
    #[error(
        "the landmarks {} cannot all be rigid between t={earlier_t} and t={later_t}: the observations contradict it (seed (3.26)); declare fewer landmarks",
        landmarks.join(", ")
    )]
    LandmarkConflict {
        /// A minimal set of landmarks that cannot all be rigid (dropping any one of them is
        /// consistent as far as closure can tell), sorted by name.
        landmarks: Vec<String>,
        /// The earlier state's timestamp (ms).
        earlier_t: u64,
        /// The later state's timestamp (ms).
        later_t: u64,
        /// The earlier state's number (0 for the first state the stream took).
        earlier_state: u64,
        /// The later state's number (the refused state's would-be number when pushing it).
        later_state: u64,
    },
    /// The monitor refused the step ([`StateStream::step`](super::StateStream::step)).
    #[error(transparent)]
    Monitor(#[from] StepError),
}
