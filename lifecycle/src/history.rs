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

    /// The change sets after `since` (all when `None` or unknown), oldest first.
    pub(crate) fn since(&self, since: Option<&str>) -> Vec<Arc<ChangeSet>> {
        let start = since
            .and_then(|s| self.change_sets.iter().position(|c| c.id == s))
            .map_or(0, |i| i + 1);
        self.change_sets[start..].to_vec()
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
