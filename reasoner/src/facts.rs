//! An indexed set of facts: by (predicate, subject) and by (predicate, object).

use crate::dictionary::{Fact, Id};
use rustc_hash::{FxHashMap, FxHashSet};

/// A set of facts with the two indexes the rules join on.
#[derive(Debug, Default, Clone)]
pub(crate) struct FactSet {
    all: FxHashSet<Fact>,
    by_ps: FxHashMap<(Id, Id), FxHashSet<Id>>,
    by_po: FxHashMap<(Id, Id), FxHashSet<Id>>,
}

static EMPTY: std::sync::LazyLock<FxHashSet<Id>> = std::sync::LazyLock::new(FxHashSet::default);

impl FactSet {
    pub(crate) fn contains(&self, fact: &Fact) -> bool {
        self.all.contains(fact)
    }

    /// Inserts a fact; tells whether it was new.
    pub(crate) fn insert(&mut self, [s, p, o]: Fact) -> bool {
        if !self.all.insert([s, p, o]) {
            return false;
        }
        self.by_ps.entry((p, s)).or_default().insert(o);
        self.by_po.entry((p, o)).or_default().insert(s);
        true
    }

    /// Removes a fact; tells whether it was present.
    pub(crate) fn remove(&mut self, [s, p, o]: Fact) -> bool {
        if !self.all.remove(&[s, p, o]) {
            return false;
        }
        if let Some(set) = self.by_ps.get_mut(&(p, s)) {
            set.remove(&o);
            if set.is_empty() {
                self.by_ps.remove(&(p, s));
            }
        }
        if let Some(set) = self.by_po.get_mut(&(p, o)) {
            set.remove(&s);
            if set.is_empty() {
                self.by_po.remove(&(p, o));
            }
        }
        true
    }

    /// The objects `o` of facts `(s, p, o)`.
    pub(crate) fn objects(&self, p: Id, s: Id) -> &FxHashSet<Id> {
        self.by_ps.get(&(p, s)).unwrap_or(&EMPTY)
    }

    /// The subjects `s` of facts `(s, p, o)`.
    pub(crate) fn subjects(&self, p: Id, o: Id) -> &FxHashSet<Id> {
        self.by_po.get(&(p, o)).unwrap_or(&EMPTY)
    }

    /// The nodes linked to `node` along `p` (forward when `!inverse`, backward otherwise).
    pub(crate) fn along(&self, p: Id, inverse: bool, node: Id) -> &FxHashSet<Id> {
        if inverse {
            self.subjects(p, node)
        } else {
            self.objects(p, node)
        }
    }

    pub(crate) fn len(&self) -> usize {
        self.all.len()
    }

    pub(crate) fn iter(&self) -> impl Iterator<Item = &Fact> {
        self.all.iter()
    }
}
