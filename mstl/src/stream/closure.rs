//! A state's spatial knowledge: the algebraic closure (seed Ch. 3.3) of what it observes,
//! with what is known between static regions (the static/dynamic split of Ch. 3.4.2).

use std::collections::BTreeSet;

use dyknow_rcc8::{Network, Relation, Split};
use rustc_hash::FxHashMap;

use super::{SpatialConstraints, StreamError};

/// A state's spatial knowledge: the algebraic closure of its constraints (observed, and what
/// is known between static regions), over the static regions and those it mentions (and,
/// once refined through the previous state, the landmarks).
///
/// Invariant: `index` numbers the network's variables `0..index.len()`.
#[derive(Debug)]
pub(super) struct Closure {
    pub(super) index: FxHashMap<String, usize>,
    pub(super) network: Network,
}

impl Closure {
    /// The relation between two regions, `None` when one of them is not mentioned.
    pub(super) fn get(&self, x: &str, y: &str) -> Option<Relation> {
        if x == y {
            return Some(Relation::EQ);
        }
        Some(self.network.get(*self.index.get(x)?, *self.index.get(y)?))
    }
}

/// The static regions, variables `0..s` of every state's network in the order of `names`,
/// and the closure of what is known between them.
#[derive(Debug)]
pub(super) struct Statics {
    index: FxHashMap<String, usize>,
    pub(super) names: Vec<String>,
    split: Split,
}

impl Statics {
    pub(super) fn new(regions: &BTreeSet<String>) -> Self {
        let names: Vec<String> = regions.iter().cloned().collect();
        Self {
            index: names
                .iter()
                .enumerate()
                .map(|(i, n)| (n.clone(), i))
                .collect(),
            split: Split::new(names.len()),
            names,
        }
    }

    /// The closure of a state's constraints (`None` when it has none and there are no static
    /// regions), and the static part refined by them, to keep once the state is taken. Nothing
    /// changes here, so a refused state leaves no trace.
    ///
    /// The closure infers what was not observed (seed Ch. 3.3): the contract's "exactly {R}
    /// after algebraic closure". Relations between two static regions never change, so theirs
    /// is closed once and refined as states tell more (Ch. 3.4.2's split); each state adds its
    /// other constraints to a copy and re-closes from them.
    pub(super) fn close(
        &self,
        spatial: &SpatialConstraints,
    ) -> Result<(Option<Closure>, Split), StreamError> {
        let mut fixed = Vec::new();
        let mut moving = Vec::new();
        for (x, y, r) in spatial.iter() {
            match (self.index.get(x), self.index.get(y)) {
                (Some(&i), Some(&j)) => fixed.push((i, j, r)),
                _ => moving.push((x, y, r)),
            }
        }
        let mut split = self.split.clone();
        split
            .constrain(&fixed)
            .map_err(|e| StreamError::StaticConflict {
                x: self.names[e.0].clone(),
                y: self.names[e.1].clone(),
            })?;
        if spatial.is_empty() && self.names.is_empty() {
            return Ok((None, split));
        }
        let mut index = self.index.clone();
        number(&mut index, moving.iter().flat_map(|&(x, y, _)| [x, y]));
        let dynamic: Vec<(usize, usize, Relation)> = moving
            .iter()
            .map(|&(x, y, r)| (index[x], index[y], r))
            .collect();
        let network =
            split
                .state(index.len(), &dynamic)
                .map_err(|e| StreamError::Inconsistent {
                    x: name_of(&index, e.0).to_owned(),
                    y: name_of(&index, e.1).to_owned(),
                })?;
        // What this state inferred between static regions holds from now on.
        let s = self.names.len();
        let learnt: Vec<(usize, usize, Relation)> = (0..s)
            .flat_map(|i| (i + 1..s).map(move |j| (i, j)))
            .filter(|&(i, j)| network.get(i, j) != split.get(i, j))
            .map(|(i, j)| (i, j, network.get(i, j)))
            .collect();
        split.constrain(&learnt).unwrap_or_else(|_| {
            unreachable!("a consistent state's closure refines the static part consistently")
        });
        Ok((Some(Closure { index, network }), split))
    }

    /// Keeps what a taken state told about the static regions ([`Statics::close`]).
    pub(super) fn commit(&mut self, split: Split) {
        self.split = split;
    }
}

/// Gives each name not yet in `index` the next number.
pub(super) fn number<'a>(
    index: &mut FxHashMap<String, usize>,
    names: impl Iterator<Item = &'a str>,
) {
    for name in names {
        let next = index.len();
        index.entry(name.to_owned()).or_insert(next);
    }
}

/// The name numbered `k` (for error messages).
pub(super) fn name_of(index: &FxHashMap<String, usize>, k: usize) -> &str {
    index
        .iter()
        .find(|(_, v)| **v == k)
        .map_or("?", |(n, _)| n.as_str())
}
