//! Intertemporal inference through landmarks (seed Ch. 3.3.3, Definitions 11–15).
//!
//! Relations between regions at two different time-points cannot be observed (the rigid space
//! assumption: a region symbol may denote different points at different times). Landmarks fix
//! a frame of reference: a landmark `r` is rigid, `EQ(r, ○r)` (Def. 14). The
//! [`Extended`] spatial relation matrix `M^{t1 ∪ t2}` (Def. 13) is a network in which every
//! region appears twice, once per time-point, linked only by the landmarks' `EQ`; its
//! algebraic closure infers the intertemporal relations `M^{t1,t2}` through them.
//!
//! Landmarks can contradict the observations: `PO(r1, r2)` at `t1` and `DC(r1, r2)` at `t2`
//! cannot both hold if `r1` and `r2` are both rigid (the seed's (3.26)). [`Extended::new`]
//! then reports a minimal set of landmarks that cannot all be rigid ([`LandmarkConflict`]).

use crate::network::Network;
use crate::relation::Relation;

/// An extended spatial relation matrix `M^{t1 ∪ t2}` (Def. 13), algebraically closed: the
/// region variables `0..n` at `t1` are the network's variables `0..n`, and at `t2` the
/// variables `n..2n`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Extended {
    network: Network,
    n: usize,
}

/// The landmarks cannot all be rigid between the two time-points: no scenario of the two
/// networks keeps every one of them `EQ` to itself (detected by algebraic closure).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("landmarks {landmarks:?} cannot all be rigid between the two time-points")]
pub struct LandmarkConflict {
    /// A minimal set of landmarks (by index) that is inconsistent with the observations:
    /// dropping any one of them makes the rest consistent as far as closure can tell. Empty
    /// when a time-point's own network is inconsistent, whatever the landmarks ([`Extended::new`]).
    pub landmarks: Vec<usize>,
}

impl Extended {
    /// The extended matrix of two time-points' networks over the same `n` region variables,
    /// with the given landmarks rigid between them, closed. The two networks need not be
    /// closed; when they are, [`Extended::of_closed`] does the same work faster.
    ///
    /// # Panics
    /// If the networks differ in size or a landmark is not one of their variables.
    pub fn new(
        before: &Network,
        after: &Network,
        landmarks: &[usize],
    ) -> Result<Self, LandmarkConflict> {
        let mut before = before.clone();
        let mut after = after.clone();
        if before.algebraic_closure().is_err() || after.algebraic_closure().is_err() {
            return Err(LandmarkConflict {
                landmarks: Vec::new(),
            });
        }
        Self::of_closed(&before, &after, landmarks)
    }

    /// [`Extended::new`] for networks that are already algebraically closed. Only paths
    /// through a landmark's link can then refine anything (within a time-point every triangle
    /// is closed, and a path across time-points needs a non-universal intertemporal edge,
    /// which at first only the links are), so the closure starts from the links alone: the
    /// incremental closure of Ch. 3.4.2.
    ///
    /// # Panics
    /// If the networks differ in size or a landmark is not one of their variables.
    pub fn of_closed(
        before: &Network,
        after: &Network,
        landmarks: &[usize],
    ) -> Result<Self, LandmarkConflict> {
        match Self::link(before, after, landmarks) {
            Some(extended) => Ok(extended),
            None => Err(LandmarkConflict {
                landmarks: Self::minimal_conflict(before, after, landmarks),
            }),
        }
    }

    /// The closed extended matrix, or `None` when it is inconsistent.
    fn link(before: &Network, after: &Network, landmarks: &[usize]) -> Option<Self> {
        let n = before.len();
        assert_eq!(
            n,
            after.len(),
            "both time-points have the same region variables"
        );
        let mut network = Network::new(2 * n);
        for i in 0..n {
            for j in i + 1..n {
                network.set(i, j, before.get(i, j));
                network.set(n + i, n + j, after.get(i, j));
            }
        }
        let mut links = Vec::with_capacity(landmarks.len());
        for &l in landmarks {
            assert!(l < n, "landmark {l} is not one of the {n} region variables");
            network.set(l, n + l, Relation::EQ);
            links.push((l, n + l));
        }
        network.close_from(&links).ok()?;
        Some(Self { network, n })
    }

    /// A deletion filter: drop each landmark whose removal keeps the set inconsistent.
    /// Inconsistency only grows with more links (closure is monotone), so the result is
    /// minimal: dropping any one of its landmarks makes the rest consistent.
    fn minimal_conflict(before: &Network, after: &Network, landmarks: &[usize]) -> Vec<usize> {
        let mut set: Vec<usize> = landmarks.to_vec();
        set.sort_unstable();
        set.dedup();
        let mut k = 0;
        while k < set.len() {
            let mut without = set.clone();
            without.remove(k);
            if Self::link(before, after, &without).is_none() {
                set = without;
            } else {
                k += 1;
            }
        }
        set
    }

    /// The number of region variables per time-point.
    pub fn regions(&self) -> usize {
        self.n
    }

    /// `M^{t1,t2}`: region `i` at the first time-point to region `j` at the second (so
    /// `EQ(r, ○r)` is `across(r, r) == EQ`).
    pub fn across(&self, i: usize, j: usize) -> Relation {
        self.network.get(i, self.n + j)
    }

    /// `M^{t1,t1}`: the first time-point's relations, refined by what the landmarks carry over
    /// from the second.
    pub fn before(&self, i: usize, j: usize) -> Relation {
        self.network.get(i, j)
    }

    /// `M^{t2,t2}`: the second time-point's relations, refined likewise.
    pub fn after(&self, i: usize, j: usize) -> Relation {
        self.network.get(self.n + i, self.n + j)
    }

    /// The whole closed network over `2n` variables.
    pub fn network(&self) -> &Network {
        &self.network
    }
}
