//! The state-stream core (issue 12, item 4): the spatial state of a stream of states, taken
//! one at a time, as a [`Valuation`] a [`Monitor`] progresses its formulas over. Trace files
//! ([`crate::trace`]) and live streams share it.
//!
//! - `state`: one state as plain owned data ([`State`], [`StateValue`],
//!   [`SpatialConstraints`]);
//! - `closure`: a state's algebraic closure and the static/dynamic split (Ch. 3.4.2);
//! - `timeline`: the states kept and the extended matrices between them (Ch. 3.3.3,
//!   Defs. 13–15);
//! - `error`: [`StreamError`].

mod closure;
mod error;
mod state;
mod timeline;

use std::collections::{BTreeMap, BTreeSet};

use dyknow_rcc8::Relation;

pub use error::StreamError;
pub use state::{SpatialConstraints, State, StateValue};

use crate::Truth;
use crate::atom::{Valuation, Value};
use crate::monitor::{Monitor, Verdict};
use crate::syntax::{Rcc8, Region};
use closure::Statics;
use timeline::Timeline;

/// The spatial state of a stream of states, taken one at a time ([`StateStream::push`]),
/// which answers for the current state as a [`Valuation`].
///
/// - Each state's spatial constraints are closed by the RCC-8 reasoner (seed Ch. 3.3, the
///   contract's "exactly `{R}` after algebraic closure"): `R(x, y)` is true when the closure
///   leaves exactly `R`, false when it leaves a set without `R`.
/// - Relations between **static regions** never change: they are closed once and refined by
///   every later observation or inference between them (the static/dynamic split of
///   Ch. 3.4.2, `dyknow_rcc8::Split`); each state copies that closure, adds its other
///   constraints and re-closes from the edges they changed.
/// - Atoms over `prev` regions (what Theorems 4–5 make of `next`) relate regions at two
///   states through the **extended spatial relation matrix** of those states (seed Def. 13,
///   `dyknow_rcc8::Extended`) with the **landmarks** rigid between them (Defs. 14–15); without
///   landmarks nothing is known across time ((3.29)). Each state is linked to the previous one
///   as it is taken and refined by it, so what held between landmarks still holds; landmarks
///   the two states' observations contradict refuse the state ((3.26),
///   [`StreamError::LandmarkConflict`]).
/// - A value or region pair the state does not give is unknown; a spatial atom the reasoning
///   leaves undecided falls back to the state's value for the atom's key (`"PO(a,b)"`).
///
/// **How many states to keep.** An atom `R(prev^k x, y)` asks about the state `k` before the
/// current one, so the stream keeps `history + 1` states, where `history` is
/// [`Monitor::history`] (the largest such `k` over the formulas), and at least two when there
/// are landmarks (each state is checked against the previous one). Pass the monitor's
/// `history()` once its formulas are added; [`StateStream::step`] grows it when formulas added
/// later look further back (states already forgotten stay forgotten: atoms over them are
/// unknown).
///
/// ```
/// use dyknow_mstl::{Monitor, State, StateStream, StreamError, Truth, parse};
/// use dyknow_rcc8::Relation;
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// // The seed's (3.26)–(3.31): r1 and r2 overlap, then are disconnected.
/// let observed = [(0, Relation::PO), (100, Relation::DC)];
/// let mut monitor = Monitor::new();
/// monitor.add(&parse("always[0,50] EQ(r1, next r1)")?)?;
/// monitor.add(&parse("always[0,50] EQ(r2, next r2)")?)?;
/// // With r1 as the frame of reference, r1 stayed put and r2 moved.
/// let mut stream = StateStream::new(["r1"], [""; 0], monitor.history());
/// let mut verdicts = Vec::new();
/// for (t, r) in observed {
///     let state = State::new(t).with_relation("r1", "r2", r)?;
///     verdicts.extend_from_slice(stream.step(&mut monitor, state)?);
/// }
/// let decided: Vec<_> = verdicts.iter().map(|v| (v.formula, v.truth, v.t)).collect();
/// assert_eq!(decided, [(0, Truth::True, 100), (1, Truth::False, 100)]);
///
/// // Both cannot be rigid: the second state is refused, naming the landmarks.
/// let mut both = StateStream::new(["r1", "r2"], [""; 0], 0);
/// both.push(State::new(0).with_relation("r1", "r2", Relation::PO)?)?;
/// let refused = both.push(State::new(100).with_relation("r1", "r2", Relation::DC)?);
/// assert!(matches!(
///     refused,
///     Err(StreamError::LandmarkConflict { ref landmarks, earlier_t: 0, later_t: 100, .. })
///         if landmarks == &["r1", "r2"]
/// ));
/// assert_eq!(both.states(), 1);
/// # Ok(())
/// # }
/// ```
#[derive(Debug)]
pub struct StateStream {
    statics: Statics,
    timeline: Timeline,
    /// The current state's values.
    values: BTreeMap<String, StateValue>,
    /// The current state's timestamp.
    last_t: Option<u64>,
}

impl StateStream {
    /// A stream with the given landmarks (rigid between states, Def. 14) and static regions
    /// (whose relations never change, Ch. 3.4.2), keeping what atoms looking `history` states
    /// back need (pass [`Monitor::history`]; see the type's documentation). Names may repeat.
    pub fn new<L, S>(landmarks: L, static_regions: S, history: u32) -> Self
    where
        L: IntoIterator,
        L::Item: Into<String>,
        S: IntoIterator,
        S::Item: Into<String>,
    {
        let landmarks: BTreeSet<String> = landmarks.into_iter().map(Into::into).collect();
        let statics: BTreeSet<String> = static_regions.into_iter().map(Into::into).collect();
        Self {
            statics: Statics::new(&statics),
            timeline: Timeline::new(landmarks.into_iter().collect(), history),
            values: BTreeMap::new(),
            last_t: None,
        }
    }

    /// Takes the next state, which becomes the current one. Checks, in this order: the
    /// relations between static regions ([`StreamError::StaticConflict`]), the closure of the
    /// state's constraints ([`StreamError::Inconsistent`]), the timestamp
    /// ([`StreamError::NotIncreasing`]), the landmarks against the previous state
    /// ([`StreamError::LandmarkConflict`]). A refused state changes nothing.
    pub fn push(&mut self, state: State) -> Result<(), StreamError> {
        let State { t, values, spatial } = state;
        let (closure, split) = self.statics.close(&spatial)?;
        if let Some(previous) = self.last_t
            && t <= previous
        {
            return Err(StreamError::NotIncreasing { previous, t });
        }
        self.timeline.push(t, closure)?;
        self.statics.commit(split);
        self.values = values;
        self.last_t = Some(t);
        Ok(())
    }

    /// Takes the next state and progresses `monitor`'s formulas through it: [`push`], then
    /// [`Monitor::step`] over the stream, then [`take_conflict`]. Returns the verdicts the
    /// state decided. Grows the history kept to `monitor.history()` first.
    ///
    /// A landmark conflict found while deciding an atom over states further apart than
    /// consecutive ones is an error after the monitor has stepped (its verdicts are lost,
    /// as `dyknow check` stops there). When the monitor refuses the step
    /// ([`StreamError::Monitor`]) the stream has taken the state.
    ///
    /// [`push`]: StateStream::push
    /// [`take_conflict`]: StateStream::take_conflict
    pub fn step<'m>(
        &mut self,
        monitor: &'m mut Monitor,
        state: State,
    ) -> Result<&'m [Verdict], StreamError> {
        self.timeline.grow(monitor.history());
        let t = state.t;
        self.push(state)?;
        let verdicts = monitor.step(t, &*self)?;
        match self.take_conflict() {
            Some(e) => Err(e),
            None => Ok(verdicts),
        }
    }

    /// A landmark conflict found while deciding atoms over `prev` regions since the last call
    /// ([`Valuation::spatial`] cannot return errors: the atom is unknown and the conflict kept
    /// here). [`StateStream::step`] reports it.
    pub fn take_conflict(&mut self) -> Option<StreamError> {
        self.timeline.take_conflict()
    }

    /// The RCC-8 relations possible between two region terms at the current state (offsets
    /// ≤ 0 relate it to earlier states through the landmarks), `None` when nothing is known:
    /// a region not mentioned, a state not taken or no longer kept, two states without
    /// landmarks.
    pub fn relation(&self, left: &Region, right: &Region) -> Result<Option<Relation>, StreamError> {
        self.timeline.relation(left, right)
    }

    /// The current state's timestamp, `None` before the first state.
    pub fn t(&self) -> Option<u64> {
        self.last_t
    }

    /// The number of states taken; the current state is number `states() - 1`.
    pub fn states(&self) -> u64 {
        self.timeline.count()
    }

    /// How many states are kept (the current one included).
    pub fn keep(&self) -> usize {
        self.timeline.keep()
    }

    /// The landmarks, sorted.
    pub fn landmarks(&self) -> &[String] {
        self.timeline.landmarks()
    }

    /// The static regions, sorted.
    pub fn static_regions(&self) -> &[String] {
        &self.statics.names
    }
}

/// No landmarks, no static regions, only the current state kept.
impl Default for StateStream {
    fn default() -> Self {
        Self::new([""; 0], [""; 0], 0)
    }
}

/// The current state: its values, and spatial atoms decided by the reasoner (falling back to
/// the atom's key when it leaves them undecided). Before the first state everything is
/// unknown.
impl Valuation for StateStream {
    fn value(&self, key: &str) -> Option<Value<'_>> {
        self.values.get(key).map(StateValue::as_value)
    }

    fn spatial(&self, relation: Rcc8, left: &Region, right: &Region, key: &str) -> Truth {
        if let Some(possible) = self.timeline.relation_or_note(left, right) {
            let r = base(relation);
            if possible == r {
                return Truth::True;
            }
            if !possible.contains(r) {
                return Truth::False;
            }
        }
        match self.value(key) {
            Some(Value::Bool(b)) => Truth::from(b),
            _ => Truth::Unknown,
        }
    }
}

/// An atom's relation as the reasoner's base relation.
fn base(relation: Rcc8) -> Relation {
    match relation {
        Rcc8::Dc => Relation::DC,
        Rcc8::Ec => Relation::EC,
        Rcc8::Po => Relation::PO,
        Rcc8::Eq => Relation::EQ,
        Rcc8::Tpp => Relation::TPP,
        Rcc8::Ntpp => Relation::NTPP,
        Rcc8::Tppi => Relation::TPPI,
        Rcc8::Ntppi => Relation::NTPPI,
    }
}
