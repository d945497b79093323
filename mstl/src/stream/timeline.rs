//! The states a stream keeps and what relates them: the extended spatial relation matrix of
//! two states (seed Def. 13) with the landmarks rigid between them (Defs. 14–15, Ch. 3.3.3),
//! what atoms over `prev` regions (Theorems 4–5) are decided from.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::sync::Arc;

use dyknow_rcc8::{Extended, Network, Relation};
use rustc_hash::FxHashMap;

use super::StreamError;
use super::closure::{Closure, name_of, number};
use crate::syntax::Region;

/// A state kept for atoms over `prev` regions and for the landmarks: its timestamp and its
/// spatial knowledge.
#[derive(Debug)]
struct Kept {
    t: u64,
    closure: Option<Arc<Closure>>,
}

/// The extended spatial relation matrix of two states, over the regions either mentions and
/// the landmarks.
#[derive(Debug)]
struct Linked {
    index: FxHashMap<String, usize>,
    matrix: Extended,
}

/// The current state and earlier states' spatial knowledge, with the extended matrices
/// between them.
///
/// Invariant: `states` holds the last `min(count, keep)` states taken, oldest first, the
/// current one (number `count - 1`) last; `linked` holds matrices only between kept states.
#[derive(Debug, Default)]
pub(super) struct Timeline {
    states: VecDeque<Kept>,
    keep: usize,
    /// States taken so far.
    count: u64,
    /// Sorted by name.
    landmarks: Vec<String>,
    /// Extended matrices between two states (by number), built on demand.
    linked: RefCell<FxHashMap<(u64, u64), Arc<Linked>>>,
    /// A landmark conflict found while deciding an atom, reported after the step.
    conflict: RefCell<Option<StreamError>>,
}

impl Timeline {
    /// A timeline over `landmarks` (sorted, without repetition) that keeps what atoms looking
    /// `history` states back need.
    pub(super) fn new(landmarks: Vec<String>, history: u32) -> Self {
        let mut timeline = Self {
            landmarks,
            ..Self::default()
        };
        timeline.grow(history);
        timeline
    }

    /// Keeps at least what atoms looking `history` states back need: the current state, that
    /// many before it, and the previous state when there are landmarks to check against the
    /// observations.
    pub(super) fn grow(&mut self, history: u32) {
        let keep = usize::try_from(history)
            .unwrap_or(usize::MAX)
            .max(usize::from(!self.landmarks.is_empty()))
            .saturating_add(1);
        self.keep = self.keep.max(keep);
    }

    pub(super) fn keep(&self) -> usize {
        self.keep
    }

    pub(super) fn count(&self) -> u64 {
        self.count
    }

    pub(super) fn landmarks(&self) -> &[String] {
        &self.landmarks
    }

    /// Takes the next state, forgetting what lies beyond the history kept. With landmarks,
    /// first links it to the previous state (a conflict refuses it and changes nothing), then
    /// replaces its closure by the extended matrix's second block over its regions and the
    /// landmarks: what rigid landmarks carry over from earlier states (the relations between
    /// them, observed or inferred) refines the present.
    pub(super) fn push(&mut self, t: u64, closure: Option<Closure>) -> Result<(), StreamError> {
        let mut late = Kept {
            t,
            closure: closure.map(Arc::new),
        };
        let linked = match self.states.back() {
            Some(early) if !self.landmarks.is_empty() => {
                let (p, q) = (self.count - 1, self.count);
                Some(Arc::new(self.extend(early, &late, p, q)?))
            }
            _ => None,
        };
        if let Some(linked) = &linked {
            let mut index = FxHashMap::default();
            number(
                &mut index,
                late.closure
                    .iter()
                    .flat_map(|c| c.index.keys())
                    .chain(&self.landmarks)
                    .map(String::as_str),
            );
            let mut network = Network::new(index.len());
            for (a, &i) in &index {
                for (b, &j) in &index {
                    if i < j {
                        network.set(i, j, linked.matrix.after(linked.index[a], linked.index[b]));
                    }
                }
            }
            late.closure = Some(Arc::new(Closure { index, network }));
        }
        self.states.push_back(late);
        self.count += 1;
        while self.states.len() > self.keep {
            self.states.pop_front();
        }
        let oldest = self.oldest();
        let cache = self.linked.get_mut();
        cache.retain(|(p, _), _| *p >= oldest);
        if let Some(linked) = linked {
            cache.insert((self.count - 2, self.count - 1), linked);
        }
        Ok(())
    }

    /// The number of the oldest state kept.
    fn oldest(&self) -> u64 {
        self.count - self.states.len() as u64
    }

    /// State number `k`, if still kept.
    fn at(&self, k: u64) -> Option<&Kept> {
        let i = usize::try_from(k.checked_sub(self.oldest())?).ok()?;
        self.states.get(i)
    }

    /// The number of the state at `offset` from the current one; `None` for a state not
    /// taken yet (Theorems 4–5 leave atoms no look-ahead: offsets are ≤ 0).
    fn back(&self, offset: i32) -> Option<u64> {
        if offset > 0 {
            return None;
        }
        (self.count.checked_sub(1)?).checked_sub(u64::from(offset.unsigned_abs()))
    }

    /// The relation between two region terms, `None` when unknown; a landmark conflict found
    /// on the way is kept for [`Timeline::take_conflict`].
    pub(super) fn relation_or_note(&self, left: &Region, right: &Region) -> Option<Relation> {
        match self.relation(left, right) {
            Ok(r) => r,
            Err(e) => {
                self.conflict.borrow_mut().get_or_insert(e);
                None
            }
        }
    }

    /// The landmark conflict found while deciding atoms since the last call.
    pub(super) fn take_conflict(&mut self) -> Option<StreamError> {
        self.conflict.get_mut().take()
    }

    /// The relation between two region terms (offsets ≤ 0), `None` when unknown.
    pub(super) fn relation(
        &self,
        left: &Region,
        right: &Region,
    ) -> Result<Option<Relation>, StreamError> {
        let (Some(p), Some(q)) = (self.back(left.offset), self.back(right.offset)) else {
            return Ok(None);
        };
        if p == q {
            let closure = self.at(p).and_then(|k| k.closure.as_ref());
            return Ok(closure.and_then(|c| c.get(&left.name, &right.name)));
        }
        // M^{p,q} relates the earlier state's region to the later one's.
        let (early, late, x, y) = if p < q {
            (p, q, left, right)
        } else {
            (q, p, right, left)
        };
        if self.landmarks.is_empty() {
            // No frame of reference: nothing relates two states ((3.29)).
            return Ok(None);
        }
        let Some(linked) = self.link(early, late)? else {
            return Ok(None);
        };
        let (Some(&i), Some(&j)) = (linked.index.get(&x.name), linked.index.get(&y.name)) else {
            return Ok(None);
        };
        let r = linked.matrix.across(i, j);
        Ok(Some(if p < q { r } else { r.converse() }))
    }

    /// The extended matrix of states `p < q` with the landmarks rigid between them (built
    /// once), `Ok(None)` when a state is no longer kept.
    fn link(&self, p: u64, q: u64) -> Result<Option<Arc<Linked>>, StreamError> {
        if let Some(done) = self.linked.borrow().get(&(p, q)) {
            return Ok(Some(done.clone()));
        }
        let (Some(early), Some(late)) = (self.at(p), self.at(q)) else {
            return Ok(None);
        };
        let linked = Arc::new(self.extend(early, late, p, q)?);
        self.linked.borrow_mut().insert((p, q), linked.clone());
        Ok(Some(linked))
    }

    /// The extended matrix `M^{t_p ∪ t_q}` (Def. 13) of two states' closures over the regions
    /// either mentions and the landmarks, each landmark `EQ` to itself across (Defs. 14–15),
    /// closed; a conflict names a minimal set of landmarks (the seed's (3.26)).
    fn extend(&self, early: &Kept, late: &Kept, p: u64, q: u64) -> Result<Linked, StreamError> {
        let mut index = FxHashMap::default();
        number(
            &mut index,
            [&early.closure, &late.closure]
                .into_iter()
                .flatten()
                .flat_map(|c| c.index.keys())
                .chain(&self.landmarks)
                .map(String::as_str),
        );
        let block = |closure: &Option<Arc<Closure>>| {
            let mut net = Network::new(index.len());
            if let Some(c) = closure {
                for (a, &i) in &c.index {
                    for (b, &j) in &c.index {
                        if i < j {
                            net.set(index[a], index[b], c.network.get(i, j));
                        }
                    }
                }
            }
            net
        };
        let landmarks: Vec<usize> = self.landmarks.iter().map(|l| index[l]).collect();
        match Extended::of_closed(&block(&early.closure), &block(&late.closure), &landmarks) {
            Ok(matrix) => Ok(Linked { index, matrix }),
            Err(conflict) => {
                let mut names: Vec<String> = conflict
                    .landmarks
                    .iter()
                    .map(|&k| name_of(&index, k).to_owned())
                    .collect();
                names.sort_unstable();
                Err(StreamError::LandmarkConflict {
                    landmarks: names,
                    earlier_t: early.t,
                    later_t: late.t,
                    earlier_state: p,
                    later_state: q,
                })
            }
        }
    }
}
