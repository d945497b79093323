//! The change-set history: the change sets the life-cycle recorded, oldest first, read back
//! from the knowledge base at start-up; the last `--history-limit` of them (older ones are
//! pruned from the store and from memory, the names they used stay reserved).

use std::sync::Arc;

use dyknow_engine::{ChangeSet, ChangeSetId, Ids};

/// The recorded change sets, oldest first.
///
/// Invariant: ids are distinct, and [`History::next_id`] is above every `cs-N` recorded.
#[derive(Debug, Default)]
pub(crate) struct History {
    change_sets: Vec<Arc<ChangeSet>>,
    next: u64,
}

impl History {
    /// The history of these change sets (oldest first); `unreadable` are the ids of records
    /// that could not be read, whose numbers are not given again either.
    pub(crate) fn new(change_sets: Vec<ChangeSet>, unreadable: &[ChangeSetId]) -> Self {
        let next = change_sets
            .iter()
            .map(|cs| &cs.id)
            .chain(unreadable)
            .filter_map(ChangeSetId::number)
            .max()
            .unwrap_or(0)
            + 1;
        Self {
            change_sets: change_sets.into_iter().map(Arc::new).collect(),
            next,
        }
    }

    /// The id of the next change set, never given again (even if it is never recorded).
    pub(crate) fn take_id(&mut self) -> ChangeSetId {
        let id = ChangeSetId::numbered(self.next);
        self.next += 1;
        id
    }

    /// Records a change set (with an id [`History::take_id`] gave).
    pub(crate) fn push(&mut self, change_set: Arc<ChangeSet>) {
        self.next = self.next.max(change_set.id.number().unwrap_or(0) + 1);
        self.change_sets.push(change_set);
    }

    /// The change sets after `since` (all when `None`), oldest first. A `cs-N` no longer
    /// kept (pruned), or never recorded, counts by its number: the kept ones numbered above
    /// N (all of them after a pruned one, none after one not given yet). Any other id: all.
    pub(crate) fn since(&self, since: Option<&str>) -> Vec<Arc<ChangeSet>> {
        let Some(since) = since else {
            return self.change_sets.clone();
        };
        if let Some(i) = self.change_sets.iter().position(|c| c.id == since) {
            return self.change_sets[i + 1..].to_vec();
        }
        match ChangeSetId::new(since).number() {
            Some(n) => self
                .change_sets
                .iter()
                .filter(|c| c.id.number().is_none_or(|m| m > n))
                .cloned()
                .collect(),
            None => self.change_sets.clone(),
        }
    }

    /// The ids of the oldest change sets to prune so that, with one more recorded, at most
    /// `limit` remain (none when `limit` is 0: no limit).
    pub(crate) fn beyond(&self, limit: usize) -> Vec<ChangeSetId> {
        if limit == 0 {
            return Vec::new();
        }
        let excess = (self.change_sets.len() + 1).saturating_sub(limit);
        self.change_sets[..excess.min(self.change_sets.len())]
            .iter()
            .map(|c| c.id.clone())
            .collect()
    }

    /// Forgets the `n` oldest change sets (their records were removed from the store).
    pub(crate) fn prune(&mut self, n: usize) {
        self.change_sets.drain(..n.min(self.change_sets.len()));
    }

    /// The number of change sets held.
    pub(crate) fn len(&self) -> usize {
        self.change_sets.len()
    }

    /// The change set `id`.
    pub(crate) fn get(&self, id: &str) -> Option<Arc<ChangeSet>> {
        self.change_sets.iter().find(|c| c.id == id).cloned()
    }

    /// Reserves every name a recorded change set used, so none is handed out again.
    pub(crate) fn reserve_names(&self, ids: &mut Ids) {
        for cs in &self.change_sets {
            ids.observe_actions(&cs.actions);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dyknow_engine::{Cause, Compiled, CostSummary};

    fn change_set(n: u64) -> ChangeSet {
        ChangeSet::new(
            ChangeSetId::numbered(n),
            Cause::Review,
            Compiled {
                actions: Vec::new(),
                cost: CostSummary {
                    total: 0.0,
                    labour: 0.0,
                    upkeep_per_time_unit: 0.0,
                    horizon: 10.0,
                },
                unsatisfied_targets: Vec::new(),
                optimal: true,
            },
            Default::default(),
        )
    }

    fn ids(v: &[Arc<ChangeSet>]) -> Vec<u64> {
        v.iter().filter_map(|c| c.id.number()).collect()
    }

    #[test]
    fn since_counts_an_id_no_longer_kept_or_not_given_yet_by_its_number() {
        // cs-1 and cs-2 pruned, cs-5 taken but never recorded.
        let history = History::new(vec![change_set(3), change_set(4), change_set(6)], &[]);
        assert_eq!(ids(&history.since(None)), [3, 4, 6]);
        assert_eq!(ids(&history.since(Some("cs-3"))), [4, 6]);
        assert_eq!(ids(&history.since(Some("cs-6"))), [] as [u64; 0]);
        assert_eq!(ids(&history.since(Some("cs-1"))), [3, 4, 6]);
        assert_eq!(ids(&history.since(Some("cs-5"))), [6]);
        assert_eq!(ids(&history.since(Some("cs-9"))), [] as [u64; 0]);
        assert_eq!(ids(&history.since(Some("bogus"))), [3, 4, 6]);
    }
}
