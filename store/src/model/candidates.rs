//! The candidate table kept up to date by patching (issue 18): when a spec changes, only the
//! in ports and targets its tags reach are computed again; when the schema changes (an
//! extension), only those whose description tags gained or lost a match.
//!
//! The relation is [`queries::CANDIDATES`]'s (`specs.md`, "Tags"): an out port satisfies an in
//! port or a target when one of its tags and one of theirs have equal values, or the out tag's
//! description is the other's or a sub-concept of it after reasoning, or the two descriptions
//! are `dyknow:similarTo` either way. Values are matched here by an index; which descriptions
//! an out description satisfies ([`queries::description_matches`]) is asked of the store once
//! per description, and again only when the schema changes. The global query stays the
//! reference: `store/tests/candidates.rs` checks that the patched table equals it after random
//! sequences of spec posts, deletes and extension changes.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::sync::Arc;

use dyknow_engine::{Candidates, Provider, Qid, Tid};

use super::queries;
use super::read::named;
use crate::error::ModelReadError;
use crate::knowledge_base::KnowledgeBase;
use crate::spec::{Tag, TargetSpec, TransformationSpec};

/// What a tag can be matched on.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Key {
    /// `dyknow:hasValue`.
    Value(String),
    /// `dyknow:hasTagDescription`.
    Description(String),
}

fn keys(tags: &[Tag]) -> Vec<Key> {
    let mut out: Vec<Key> = tags
        .iter()
        .flat_map(|t| {
            t.value
                .iter()
                .map(|v| Key::Value(v.clone()))
                .chain(t.description.iter().map(|d| Key::Description(d.clone())))
        })
        .collect();
    out.sort();
    out.dedup();
    out
}

/// An entry of the table: an in port of a transformation, or a target.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Consumer {
    Input(Tid, usize),
    Target(Qid),
}

/// The keys of a transformation's ports, in port order.
#[derive(Debug, Clone, Default)]
struct Ports {
    inputs: Vec<Vec<Key>>,
    outputs: Vec<Vec<Key>>,
}

impl Ports {
    fn of(spec: &TransformationSpec) -> Self {
        Self {
            inputs: spec.inputs.iter().map(|p| keys(&p.tags)).collect(),
            outputs: spec.outputs.iter().map(|p| keys(&p.tags)).collect(),
        }
    }
}

/// The candidate table with the indexes that let it be patched.
#[derive(Debug, Clone, Default)]
pub(crate) struct CandidateIndex {
    transformations: HashMap<Tid, Ports>,
    targets: HashMap<Qid, Vec<Key>>,
    /// Key → the in ports and targets carrying it.
    consumers: HashMap<Key, BTreeSet<Consumer>>,
    /// Key → the out ports carrying it.
    producers: HashMap<Key, BTreeSet<Provider>>,
    /// Out description → the descriptions it satisfies (itself included).
    matches: HashMap<String, BTreeSet<String>>,
    /// Description → the out descriptions that satisfy it.
    matched_by: HashMap<String, BTreeSet<String>>,
    /// Shared with the [`super::Loaded`]s handed out; copied on write only while one is held.
    table: Arc<Candidates>,
}

/// A batch of spec changes: the new version of each spec named (`None`: removed).
#[derive(Debug, Default)]
pub(crate) struct SpecChanges {
    pub(crate) transformations: BTreeMap<Tid, Option<TransformationSpec>>,
    pub(crate) targets: BTreeMap<Qid, Option<TargetSpec>>,
}

impl CandidateIndex {
    /// The table now.
    pub(crate) fn table(&self) -> Arc<Candidates> {
        Arc::clone(&self.table)
    }

    /// Applies `changes`; with `schema_changed`, asks again which descriptions every out
    /// description satisfies. Only the entries the changes reach are computed again.
    pub(crate) fn apply(
        &mut self,
        kb: &KnowledgeBase,
        changes: SpecChanges,
        schema_changed: bool,
    ) -> Result<(), ModelReadError> {
        let mut affected = BTreeSet::new();
        if schema_changed {
            let descriptions: Vec<String> = self.matches.keys().cloned().collect();
            let now = description_matches(kb, &descriptions)?;
            for (e, new) in now {
                let old = self.matches.get(&e).cloned().unwrap_or_default();
                if old != new {
                    for d in old.symmetric_difference(&new) {
                        self.reach_description(d, &mut affected);
                    }
                    self.set_matches(e, new);
                }
            }
        }
        // The out descriptions the changes bring that were not asked about yet.
        let fresh: BTreeSet<String> = changes
            .transformations
            .values()
            .flatten()
            .flat_map(|t| t.outputs.iter().flat_map(|p| p.tags.iter()))
            .filter_map(|t| t.description.clone())
            .filter(|d| !self.matches.contains_key(d))
            .collect();
        if !fresh.is_empty() {
            for (e, m) in description_matches(kb, &fresh.into_iter().collect::<Vec<_>>())? {
                self.set_matches(e, m);
            }
        }
        for (tid, spec) in changes.transformations {
            if let Some(old) = self.transformations.remove(&tid) {
                self.unindex_transformation(&tid, &old, &mut affected);
            }
            if let Some(spec) = spec {
                let ports = Ports::of(&spec);
                self.index_transformation(&tid, &ports, &mut affected);
                self.transformations.insert(tid, ports);
            }
        }
        for (qid, spec) in changes.targets {
            if let Some(old) = self.targets.remove(&qid) {
                for key in &old {
                    remove_from(&mut self.consumers, key, &Consumer::Target(qid.clone()));
                }
            }
            if let Some(spec) = spec {
                let keys = keys(&spec.tags);
                for key in &keys {
                    self.consumers
                        .entry(key.clone())
                        .or_default()
                        .insert(Consumer::Target(qid.clone()));
                }
                self.targets.insert(qid.clone(), keys);
            }
            affected.insert(Consumer::Target(qid));
        }
        for consumer in &affected {
            self.recompute(consumer);
        }
        self.forget_unused_descriptions();
        Ok(())
    }

    fn set_matches(&mut self, e: String, new: BTreeSet<String>) {
        if let Some(old) = self.matches.get(&e) {
            for d in old {
                if let Some(set) = self.matched_by.get_mut(d) {
                    set.remove(&e);
                    if set.is_empty() {
                        self.matched_by.remove(d);
                    }
                }
            }
        }
        for d in &new {
            self.matched_by
                .entry(d.clone())
                .or_default()
                .insert(e.clone());
        }
        self.matches.insert(e, new);
    }

    /// Out descriptions no out port carries any more are forgotten (asked again if one
    /// comes back), so the index does not grow with what was once posted.
    fn forget_unused_descriptions(&mut self) {
        let unused: Vec<String> = self
            .matches
            .keys()
            .filter(|e| !self.producers.contains_key(&Key::Description((*e).clone())))
            .cloned()
            .collect();
        for e in unused {
            self.set_matches(e.clone(), BTreeSet::new());
            self.matches.remove(&e);
        }
    }

    /// The consumers carrying description `d`.
    fn reach_description(&self, d: &str, affected: &mut BTreeSet<Consumer>) {
        if let Some(c) = self.consumers.get(&Key::Description(d.to_owned())) {
            affected.extend(c.iter().cloned());
        }
    }

    /// The consumers an out port with `keys` can satisfy.
    fn reach(&self, keys: &[Key], affected: &mut BTreeSet<Consumer>) {
        for key in keys {
            match key {
                Key::Value(_) => {
                    if let Some(c) = self.consumers.get(key) {
                        affected.extend(c.iter().cloned());
                    }
                }
                Key::Description(e) => {
                    for d in self.matches.get(e).into_iter().flatten() {
                        self.reach_description(d, affected);
                    }
                }
            }
        }
    }

    fn unindex_transformation(
        &mut self,
        tid: &Tid,
        ports: &Ports,
        affected: &mut BTreeSet<Consumer>,
    ) {
        for (j, keys) in ports.outputs.iter().enumerate() {
            self.reach(keys, affected);
            let provider = Provider {
                tid: tid.clone(),
                port: j,
            };
            for key in keys {
                remove_from(&mut self.producers, key, &provider);
            }
        }
        for (i, keys) in ports.inputs.iter().enumerate() {
            let consumer = Consumer::Input(tid.clone(), i);
            for key in keys {
                remove_from(&mut self.consumers, key, &consumer);
            }
            affected.insert(consumer);
        }
    }

    fn index_transformation(
        &mut self,
        tid: &Tid,
        ports: &Ports,
        affected: &mut BTreeSet<Consumer>,
    ) {
        for (i, keys) in ports.inputs.iter().enumerate() {
            let consumer = Consumer::Input(tid.clone(), i);
            for key in keys {
                self.consumers
                    .entry(key.clone())
                    .or_default()
                    .insert(consumer.clone());
            }
            affected.insert(consumer);
        }
        for (j, keys) in ports.outputs.iter().enumerate() {
            let provider = Provider {
                tid: tid.clone(),
                port: j,
            };
            for key in keys {
                self.producers
                    .entry(key.clone())
                    .or_default()
                    .insert(provider.clone());
            }
            self.reach(keys, affected);
        }
    }

    /// Computes the providers of `consumer` from the indexes (none when it is gone).
    fn recompute(&mut self, consumer: &Consumer) {
        let keys: &[Key] = match consumer {
            Consumer::Input(tid, i) => self
                .transformations
                .get(tid)
                .and_then(|p| p.inputs.get(*i))
                .map_or(&[], Vec::as_slice),
            Consumer::Target(qid) => self.targets.get(qid).map_or(&[], Vec::as_slice),
        };
        let mut providers = BTreeSet::new();
        for key in keys {
            match key {
                Key::Value(_) => providers.extend(self.producers.get(key).into_iter().flatten()),
                Key::Description(d) => {
                    for e in self.matched_by.get(d).into_iter().flatten() {
                        providers.extend(
                            self.producers
                                .get(&Key::Description(e.clone()))
                                .into_iter()
                                .flatten(),
                        );
                    }
                }
            }
        }
        let providers: Vec<Provider> = providers.into_iter().cloned().collect();
        let table = Arc::make_mut(&mut self.table);
        match consumer {
            Consumer::Input(tid, i) => table.set_input(tid, *i, providers),
            Consumer::Target(qid) => table.set_target(qid, providers),
        }
    }
}

fn remove_from<T: Ord>(map: &mut HashMap<Key, BTreeSet<T>>, key: &Key, item: &T) {
    if let Some(set) = map.get_mut(key) {
        set.remove(item);
        if set.is_empty() {
            map.remove(key);
        }
    }
}

/// How many descriptions one query asks about.
const DESCRIPTIONS_PER_QUERY: usize = 256;

/// For each out description `e` of `descriptions`, the descriptions it satisfies: itself, its
/// super-concepts after reasoning, and those `dyknow:similarTo` it either way.
fn description_matches(
    kb: &KnowledgeBase,
    descriptions: &[String],
) -> Result<BTreeMap<String, BTreeSet<String>>, ModelReadError> {
    let mut out: BTreeMap<String, BTreeSet<String>> = descriptions
        .iter()
        .map(|e| (e.clone(), BTreeSet::from([e.clone()])))
        .collect();
    for chunk in descriptions.chunks(DESCRIPTIONS_PER_QUERY) {
        let Some(query) = queries::description_matches(chunk) else {
            // A description that is not an IRI matches only itself.
            continue;
        };
        for row in kb.select(&query)? {
            if let (Some(e), Some(d)) = (named(&row[0]), named(&row[1])) {
                out.entry(e.into_string())
                    .or_default()
                    .insert(d.into_string());
            }
        }
    }
    Ok(out)
}
