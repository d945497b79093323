//! The change-set history: every change set the life-cycle recorded, oldest first, read back
//! from the knowledge base at start-up.

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
    /// The history of these change sets (oldest first).
    pub(crate) fn new(change_sets: Vec<ChangeSet>) -> Self {
        let next = change_sets
            .iter()
            .filter_map(|cs| cs.id.number())
            .max()
            .unwrap_or(0)
            + 1;
        Self {
            change_sets: change_sets.into_iter().map(Arc::new).collect(),
            next,
        }
    }

    /// The id the next change set gets.
    pub(crate) fn next_id(&self) -> ChangeSetId {
        ChangeSetId::numbered(self.next)
    }

    /// Records a change set (with the id [`History::next_id`] gave).
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
