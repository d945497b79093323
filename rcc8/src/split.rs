//! The static/dynamic split of Ch. 3.4.2 (issue 6, item 3): relations between static regions
//! never change, so their closure is computed once (and refined as more is learnt); each state
//! then adds its dynamic constraints to a copy and re-closes only from the edges they changed.

use crate::network::{Inconsistent, Network};
use crate::relation::Relation;

/// The closed network of the static regions, variables `0..s`; a state's network puts its
/// dynamic regions after them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Split {
    statics: Network,
}

impl Split {
    /// `s` static regions, nothing known between them yet.
    pub fn new(s: usize) -> Self {
        Self {
            statics: Network::new(s),
        }
    }

    /// The number of static regions.
    pub fn len(&self) -> usize {
        self.statics.len()
    }

    /// Whether there are no static regions.
    pub fn is_empty(&self) -> bool {
        self.statics.is_empty()
    }

    /// The closed relation between static regions `i` and `j`.
    pub fn get(&self, i: usize, j: usize) -> Relation {
        self.statics.get(i, j)
    }

    /// The closed static network.
    pub fn network(&self) -> &Network {
        &self.statics
    }

    /// Adds constraints between static regions and re-closes from them. On `Err` nothing
    /// changes: the constraints contradict what was known.
    pub fn constrain(
        &mut self,
        constraints: &[(usize, usize, Relation)],
    ) -> Result<(), Inconsistent> {
        let mut next = self.statics.clone();
        let changed = add(&mut next, constraints);
        if changed.is_empty() {
            return Ok(());
        }
        next.close_from(&changed)?;
        self.statics = next;
        Ok(())
    }

    /// A state's closed network over `n ≥ s` variables: the static closure, plus `dynamic`
    /// constraints (each with at least one variable `≥ s`, or between static ones), re-closed
    /// only from the edges they changed. Equal to closing the whole network from scratch.
    ///
    /// # Panics
    /// If `n` is smaller than the number of static regions.
    pub fn state(
        &self,
        n: usize,
        dynamic: &[(usize, usize, Relation)],
    ) -> Result<Network, Inconsistent> {
        let s = self.statics.len();
        assert!(n >= s, "a state has at least the static regions");
        let mut net = Network::new(n);
        for i in 0..s {
            for j in i + 1..s {
                let r = self.statics.get(i, j);
                if r != Relation::UNIVERSAL {
                    net.set(i, j, r);
                }
            }
        }
        let changed = add(&mut net, dynamic);
        net.close_from(&changed)?;
        Ok(net)
    }
}

/// Intersects each constraint into `net`; returns the edges whose relation changed.
fn add(net: &mut Network, constraints: &[(usize, usize, Relation)]) -> Vec<(usize, usize)> {
    let mut changed = Vec::with_capacity(constraints.len());
    for &(i, j, r) in constraints {
        let before = net.get(i, j);
        if net.constrain(i, j, r) != before {
            changed.push((i, j));
        }
    }
    changed
}
