//! One state of a state stream as plain owned data (contract `mstl.md`, Traces): a timestamp,
//! values per key, and RCC-8 constraints between regions. A trace line, or a live
//! synchroniser's state, becomes a [`State`] before a [`StateStream`](super::StateStream)
//! takes it.

use std::collections::BTreeMap;
use std::collections::hash_map::Entry;

use dyknow_rcc8::Relation;
use rustc_hash::FxHashMap;

use super::StreamError;
use crate::atom::Value;

/// A value in a [`State`], owned: a predicate's truth, or a function term's number or string
/// (the borrowed form is [`Value`]).
#[derive(Debug, Clone, PartialEq)]
pub enum StateValue {
    /// A predicate's truth.
    Bool(bool),
    /// A number.
    Number(f64),
    /// A string.
    Text(String),
}

impl StateValue {
    /// The value as atoms read it.
    pub fn as_value(&self) -> Value<'_> {
        match self {
            Self::Bool(b) => Value::Bool(*b),
            Self::Number(n) => Value::Number(*n),
            Self::Text(s) => Value::Text(s),
        }
    }
}

impl From<bool> for StateValue {
    fn from(b: bool) -> Self {
        Self::Bool(b)
    }
}

impl From<f64> for StateValue {
    fn from(n: f64) -> Self {
        Self::Number(n)
    }
}

impl From<String> for StateValue {
    fn from(s: String) -> Self {
        Self::Text(s)
    }
}

impl From<&str> for StateValue {
    fn from(s: &str) -> Self {
        Self::Text(s.to_owned())
    }
}

/// The RCC-8 constraints one state observes, at most one per pair of regions.
///
/// Invariant: each pair is stored once, the name that sorts first as its first region, with
/// a non-empty relation; the relations given for a pair in either order are converted (the
/// converse) and intersected as they are added, so a contradiction is refused at once.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SpatialConstraints {
    /// Keyed by the ordered pair (the smaller name first). The map's iteration order is the
    /// order in which the reasoner meets the constraints, and so decides which pair an
    /// inconsistency names; it depends on the keys and on how they were inserted (through
    /// the entry API, as `dyknow check` always did, so its messages stay the same).
    pairs: FxHashMap<(String, String), Relation>,
}

impl SpatialConstraints {
    /// No constraint.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `relation(x, y)`: a set of base relations, one of which holds. Refuses a set that
    /// allows nothing (empty, or without `EQ` between a region and itself:
    /// [`StreamError::NoRelation`]) and one that leaves nothing possible with what was added
    /// for the pair before ([`StreamError::Contradictory`]); on `Err` nothing changes.
    pub fn add(
        &mut self,
        x: impl Into<String>,
        y: impl Into<String>,
        relation: Relation,
    ) -> Result<(), StreamError> {
        let (x, y) = (x.into(), y.into());
        if relation.is_empty() || x == y && !relation.contains(Relation::EQ) {
            return Err(StreamError::NoRelation { x, y, relation });
        }
        let (pair, relation) = if x <= y {
            ((x, y), relation)
        } else {
            ((y, x), relation.converse())
        };
        // Through the entry API, as the map's order (which fixes the order the reasoner meets
        // the constraints in) depends on how keys are inserted.
        match self.pairs.entry(pair) {
            Entry::Occupied(mut known) => {
                let both = known.get().and(relation);
                if both.is_empty() {
                    let (x, y) = known.key().clone();
                    return Err(StreamError::Contradictory { x, y });
                }
                *known.get_mut() = both;
            }
            Entry::Vacant(new) => {
                new.insert(relation);
            }
        }
        Ok(())
    }

    /// What was added between `x` and `y` (in that direction), `None` if nothing was.
    pub fn get(&self, x: &str, y: &str) -> Option<Relation> {
        if x <= y {
            self.pairs.get(&(x.to_owned(), y.to_owned())).copied()
        } else {
            self.pairs
                .get(&(y.to_owned(), x.to_owned()))
                .map(|r| r.converse())
        }
    }

    /// The number of pairs constrained.
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    /// Whether nothing was added.
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// The constraints `(x, y, relation)`, one per pair, `x` the name that sorts first.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &str, Relation)> {
        self.pairs
            .iter()
            .map(|((x, y), r)| (x.as_str(), y.as_str(), *r))
    }
}

/// One state of a stream: its timestamp, its values, and the spatial constraints it
/// observes. A key that is absent (or a region pair not constrained) is unknown in the state,
/// never guessed (Kleene's logic, contract `mstl.md`).
///
/// ```
/// use dyknow_mstl::{State, StateValue};
/// use dyknow_rcc8::Relation;
/// let state = State::new(100)
///     .with_value("altitude(uav1)", 52.5)
///     .with_value("InsideCircle(ball)", true)
///     .with_relation("student", "office", Relation::NTPP.or(Relation::TPP))?;
/// assert_eq!(state.values["InsideCircle(ball)"], StateValue::Bool(true));
/// assert_eq!(state.spatial.get("office", "student"), Some(Relation::NTPPI.or(Relation::TPPI)));
/// # Ok::<(), dyknow_mstl::StreamError>(())
/// ```
#[derive(Debug, Clone, Default, PartialEq)]
pub struct State {
    /// The timestamp (ms); a stream's timestamps strictly increase.
    pub t: u64,
    /// The values of ground atoms and function terms, keyed as [`crate::Valuation`] says
    /// (`P(a,b)`, `f(a)`: written without spaces).
    pub values: BTreeMap<String, StateValue>,
    /// The observed RCC-8 constraints.
    pub spatial: SpatialConstraints,
}

impl State {
    /// A state at `t` (ms) that tells nothing yet.
    pub fn new(t: u64) -> Self {
        Self {
            t,
            ..Self::default()
        }
    }

    /// Sets the value of `key` (replacing an earlier one).
    #[must_use]
    pub fn with_value(mut self, key: impl Into<String>, value: impl Into<StateValue>) -> Self {
        self.values.insert(key.into(), value.into());
        self
    }

    /// Adds the constraint `relation(x, y)` ([`SpatialConstraints::add`]).
    pub fn with_relation(
        mut self,
        x: impl Into<String>,
        y: impl Into<String>,
        relation: Relation,
    ) -> Result<Self, StreamError> {
        self.spatial.add(x, y, relation)?;
        Ok(self)
    }
}
