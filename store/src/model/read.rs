//! Reading the DyKnow model from the knowledge base: the environment ⟨CU, F, T⟩ with the
//! candidate table, the learned estimates and the recorded change sets.

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::sync::{Arc, Mutex, PoisonError, RwLock, TryLockError};

use dyknow_engine::{
    Candidates, ChangeSet, ChangeSetId, Cid, ComputationUnit, CostKind, Environment, Estimate,
    Learned, Provider, Target, Tid, Transformation,
};
use oxigraph::model::{NamedNode, NamedOrBlankNode, Term};

use super::candidates::{CandidateIndex, SpecChanges};
use super::queries;
use crate::error::ModelReadError;
use crate::knowledge_base::KnowledgeBase;
use crate::spec::{Spec, SpecKind, TransformationSpec};

/// The IRIs of the library's resources, for writing CUs.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Iris {
    /// tid → transformation IRI.
    pub transformations: BTreeMap<Tid, NamedNode>,
    /// (tid, port name) → in port IRI.
    pub in_ports: BTreeMap<(Tid, String), NamedNode>,
    /// (tid, port name) → out port IRI.
    pub out_ports: BTreeMap<(Tid, String), NamedNode>,
}

/// What the engine needs from the knowledge base.
#[derive(Debug, Clone, Default)]
pub struct Loaded {
    /// The environment ⟨CU, F, T⟩, with the learned estimates in the library.
    pub env: Environment,
    /// The candidate table (~), shared with the cache that patches it.
    pub candidates: Arc<Candidates>,
    /// The IRIs of transformations and ports.
    pub iris: Arc<Iris>,
    /// The transformation specs, for what the engine does not need (implementations,
    /// parameters).
    pub specs: Arc<BTreeMap<Tid, TransformationSpec>>,
    /// [`KnowledgeBase::spec_generation`] read before the specs were: when it has moved
    /// since, a spec may have changed after this was read.
    pub spec_generation: u64,
}

pub(crate) fn literal(term: &Option<Term>) -> Option<String> {
    match term {
        Some(Term::Literal(l)) => Some(l.value().to_owned()),
        _ => None,
    }
}

pub(crate) fn named(term: &Option<Term>) -> Option<NamedNode> {
    match term {
        Some(Term::NamedNode(n)) => Some(n.clone()),
        _ => None,
    }
}

/// Reads the environment, the candidate table and the library's IRIs.
pub fn load(kb: &KnowledgeBase) -> Result<Loaded, ModelReadError> {
    SpecCache::default().load(kb, None)
}

/// What is derived from specs alone (library with the specs' estimates, targets, IRIs, the
/// candidate table), kept against [`KnowledgeBase::spec_generation`] and **patched** when
/// specs or extensions change ([`KnowledgeBase::spec_changes_since`]): only the specs written
/// or removed are read again, and only the candidate-table entries their tags reach are
/// computed again ([`super::candidates`]). A review after a CU crash reads only the CUs again.
///
/// One reader at a time brings the cache up to date; the others wait for it rather than
/// derive the same thing again.
///
/// The CUs are cached too, against the spec and environment generations together: reads of
/// an environment nothing wrote to since (`GET /cus`, `/environment`) cost a copy, not a
/// query.
///
/// Reads that must not wait ([`SpecCache::cus_now`], `GET /cus`) are served the last
/// published [`CuSnapshot`]: a read that finds the snapshot behind the store and nobody
/// refreshing brings it up to date itself; one that finds a refresh under way (a review
/// patching the candidate table) does not wait for it. Writers of CUs publish a new snapshot
/// before they answer ([`SpecCache::publish`]), so that their clients read their writes.
#[derive(Debug, Default)]
pub struct SpecCache {
    state: Mutex<Option<SpecState>>,
    cus: Mutex<Option<CachedCus>>,
    published: RwLock<Option<Arc<CuSnapshot>>>,
    /// The spec-derived part last read by [`SpecCache::load_now`], at its spec generation.
    published_base: RwLock<Option<Arc<(u64, Loaded)>>>,
}

/// The CUs at a (spec generation, environment generation), with what reads of them need of
/// the specs.
#[derive(Debug, Clone, Default)]
pub struct CuSnapshot {
    /// The spec and environment generations it was read at (or after).
    pub key: (u64, u64),
    /// The CUs.
    pub cus: BTreeMap<Cid, ComputationUnit>,
    /// The transformations the CUs instantiate, with the specs' estimates.
    pub library: BTreeMap<Tid, Transformation>,
    /// Every transformation spec (shared).
    pub specs: Arc<BTreeMap<Tid, TransformationSpec>>,
}

/// Whether `a` is at least as new as `b` in both generations.
fn at_least(a: (u64, u64), b: (u64, u64)) -> bool {
    a.0 >= b.0 && a.1 >= b.1
}

/// The CUs read at a (spec generation, environment generation): the rows of each
/// environment graph that holds any, and the CUs they make. Patched when the generations
/// move: only the graphs [`stale_graphs`] names are read again ([`cus_at`]).
#[derive(Debug)]
struct CachedCus {
    key: (u64, u64),
    graphs: BTreeMap<NamedNode, CuGraph>,
    cus: BTreeMap<Cid, ComputationUnit>,
}

/// The CU rows of one environment graph, with what they looked up outside it: the rows
/// depend on the labels of the transformations their CUs instantiate and on the names of the
/// ports they bind, found in spec graphs (what a spec change is matched against).
#[derive(Debug, Default, Clone, PartialEq, Eq)]
struct CuGraph {
    rows: Vec<CuRow>,
    /// The nodes looked up in any graph (transformations, ports), found there or not.
    foreign: HashSet<NamedOrBlankNode>,
    /// The spec graphs that answered those lookups.
    sources: BTreeSet<NamedNode>,
    /// Whether a graph other than a spec's answered one (the inferred graph, an
    /// extension): read again whenever anything changed.
    volatile: bool,
}

/// The cache's content: the spec-derived part of [`Loaded`] at `generation`, and the index
/// that patches its candidate table.
#[derive(Debug)]
struct SpecState {
    generation: u64,
    base: Loaded,
    index: CandidateIndex,
}

impl SpecCache {
    /// [`load`], reusing the spec-derived part while no spec or extension changed, patching
    /// it when some did. With `learned`, those estimates replace the specs' (the caller keeps
    /// them); without, they are read from the store.
    pub fn load(
        &self,
        kb: &KnowledgeBase,
        learned: Option<&Learned>,
    ) -> Result<Loaded, ModelReadError> {
        // Read before what they key: a write after this is seen as a new key next time.
        let key = (kb.spec_generation(), kb.environment_generation());
        let mut loaded = self.spec_part(kb)?;
        match learned {
            Some(l) => l.apply(&mut loaded.env),
            None => self::learned(kb)?.apply(&mut loaded.env),
        }
        loaded.env.cus = self.cached_cus(kb, key, &loaded.env.library)?;
        loaded.spec_generation = key.0;
        Ok(loaded)
    }

    /// [`SpecCache::load`] for reads that must not wait for a review or a spec write patching
    /// the candidate table (`GET /environment`). When nobody holds the cache, it is brought up
    /// to date as `load` does and its spec-derived part published. Otherwise the last
    /// published spec-derived part is used, with the CUs of [`SpecCache::cus_now`] (which hold
    /// every CU write whose writer has answered). The transformations of those CUs that the
    /// older part lacks come from the CU snapshot, so a CU never reads as an instance of an
    /// unknown transformation. Only before any publication does it wait.
    pub fn load_now(
        &self,
        kb: &KnowledgeBase,
        learned: Option<&Learned>,
    ) -> Result<Loaded, ModelReadError> {
        let free = match self.state.try_lock() {
            Ok(g) => Some(g),
            Err(TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(TryLockError::WouldBlock) => None,
        };
        let last = self
            .published_base
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .clone();
        let base = match (free, last) {
            (None, Some(last)) => last,
            (Some(guard), _) => self.publish_base(Self::up_to_date(guard, kb)?),
            (None, None) => self.publish_base(self.refreshed(kb)?),
        };
        let mut loaded = base.1.clone();
        let snapshot = self.cus_now(kb)?;
        for (tid, tf) in &snapshot.library {
            if !loaded.env.library.contains_key(tid) {
                loaded.env.library.insert(tid.clone(), tf.clone());
            }
        }
        match learned {
            Some(l) => l.apply(&mut loaded.env),
            None => self::learned(kb)?.apply(&mut loaded.env),
        }
        loaded.env.cus = snapshot.cus.clone();
        Ok(loaded)
    }

    /// Publishes the spec-derived part of the locked, up-to-date cache for
    /// [`SpecCache::load_now`] (never over a newer one), and returns it.
    fn publish_base(
        &self,
        guard: std::sync::MutexGuard<'_, Option<SpecState>>,
    ) -> Arc<(u64, Loaded)> {
        let mut published = self
            .published_base
            .write()
            .unwrap_or_else(PoisonError::into_inner);
        let generation = guard.as_ref().map_or(0, |s| s.generation);
        // Nothing changed since the last one: no copy of the library.
        if let Some(p) = published.as_ref()
            && guard.is_some()
            && p.0 == generation
        {
            return Arc::clone(p);
        }
        let base = Arc::new(
            guard
                .as_ref()
                .map(|s| (s.generation, s.base.clone()))
                .unwrap_or_default(),
        );
        drop(guard);
        if published.as_ref().is_none_or(|p| p.0 <= base.0) {
            *published = Some(Arc::clone(&base));
        }
        base
    }

    /// The spec-derived part now (no CUs, the specs' own estimates).
    pub fn spec_part(&self, kb: &KnowledgeBase) -> Result<Loaded, ModelReadError> {
        let guard = self.refreshed(kb)?;
        Ok(guard.as_ref().map(|s| s.base.clone()).unwrap_or_default())
    }

    /// The CUs as the last published [`CuSnapshot`] has them, without waiting for a refresh
    /// another thread has under way: up to date when nothing was written since, or when no
    /// refresh is under way (this read then makes one); otherwise the last snapshot
    /// published, which holds every write whose writer published before it answered.
    pub fn cus_now(&self, kb: &KnowledgeBase) -> Result<Arc<CuSnapshot>, ModelReadError> {
        let key = (kb.spec_generation(), kb.environment_generation());
        let last = self
            .published
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .clone();
        match last {
            Some(last) if at_least(last.key, key) => Ok(last),
            Some(last) => Ok(self.refresh(kb, false)?.unwrap_or(last)),
            None => Ok(self.refresh(kb, true)?.unwrap_or_default()),
        }
    }

    /// The last published snapshot when it is up to date: what [`SpecCache::cus_now`] answers
    /// without reading the store; `None` when it would read it (something was written since).
    pub fn cus_published(&self, kb: &KnowledgeBase) -> Option<Arc<CuSnapshot>> {
        let key = (kb.spec_generation(), kb.environment_generation());
        self.published
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .as_ref()
            .filter(|last| at_least(last.key, key))
            .cloned()
    }

    /// The last published snapshot, however old: its CUs are those of the last CU write
    /// (every writer publishes before it answers), though a spec written since may have
    /// changed their ports. `None` before the first publication.
    pub fn last_published(&self) -> Option<Arc<CuSnapshot>> {
        self.published
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// Brings the cache up to date and publishes the CUs for [`SpecCache::cus_now`]: what a
    /// writer that changed CUs or specs calls before it answers.
    pub fn publish(&self, kb: &KnowledgeBase) -> Result<Arc<CuSnapshot>, ModelReadError> {
        Ok(self.refresh(kb, true)?.unwrap_or_default())
    }

    /// Reads and publishes a snapshot; `None` without `wait` when another thread holds the
    /// cache.
    fn refresh(
        &self,
        kb: &KnowledgeBase,
        wait: bool,
    ) -> Result<Option<Arc<CuSnapshot>>, ModelReadError> {
        let key = (kb.spec_generation(), kb.environment_generation());
        let locked = if wait {
            (
                self.state.lock().unwrap_or_else(PoisonError::into_inner),
                self.cus.lock().unwrap_or_else(PoisonError::into_inner),
            )
        } else {
            // Someone is refreshing: not waiting for them.
            let state = match self.state.try_lock() {
                Ok(g) => g,
                Err(TryLockError::Poisoned(p)) => p.into_inner(),
                Err(TryLockError::WouldBlock) => return Ok(None),
            };
            let cus = match self.cus.try_lock() {
                Ok(g) => g,
                Err(TryLockError::Poisoned(p)) => p.into_inner(),
                Err(TryLockError::WouldBlock) => return Ok(None),
            };
            (state, cus)
        };
        let (state, mut cached) = locked;
        let guard = Self::up_to_date(state, kb)?;
        let empty = BTreeMap::new();
        let (library, specs) = guard.as_ref().map_or((&empty, Arc::default()), |s| {
            (&s.base.env.library, Arc::clone(&s.base.specs))
        });
        let cus = cus_at(&mut cached, kb, key, library)?;
        drop(cached);
        let library = cus
            .values()
            .filter_map(|cu| Some((cu.tid.clone(), library.get(&cu.tid)?.clone())))
            .collect();
        drop(guard);
        let snapshot = Arc::new(CuSnapshot {
            key,
            cus,
            library,
            specs,
        });
        let mut published = self
            .published
            .write()
            .unwrap_or_else(PoisonError::into_inner);
        // Never an older read over a newer one (a reader that began before a writer and
        // ends after it).
        if published
            .as_ref()
            .is_none_or(|p| at_least(snapshot.key, p.key))
        {
            *published = Some(Arc::clone(&snapshot));
        }
        Ok(Some(snapshot))
    }

    /// The CUs cached at `key` (spec generation, environment generation), read again (their
    /// unbound ports from `library`) when the key changed.
    fn cached_cus(
        &self,
        kb: &KnowledgeBase,
        key: (u64, u64),
        library: &BTreeMap<Tid, Transformation>,
    ) -> Result<BTreeMap<Cid, ComputationUnit>, ModelReadError> {
        let mut cached = self.cus.lock().unwrap_or_else(PoisonError::into_inner);
        cus_at(&mut cached, kb, key, library)
    }

    /// The cache brought up to date (patched, or derived anew), locked.
    fn refreshed(
        &self,
        kb: &KnowledgeBase,
    ) -> Result<std::sync::MutexGuard<'_, Option<SpecState>>, ModelReadError> {
        Self::up_to_date(
            self.state.lock().unwrap_or_else(PoisonError::into_inner),
            kb,
        )
    }

    /// The locked cache brought up to date (patched, or derived anew).
    fn up_to_date<'a>(
        mut guard: std::sync::MutexGuard<'a, Option<SpecState>>,
        kb: &KnowledgeBase,
    ) -> Result<std::sync::MutexGuard<'a, Option<SpecState>>, ModelReadError> {
        let changes = guard
            .as_ref()
            .map(|state| kb.spec_changes_since(state.generation));
        match (guard.as_mut(), changes) {
            (Some(state), Some((now, Some(graphs)))) => {
                if !graphs.is_empty() {
                    // Whatever happens, the state is rebuilt next time unless patched whole.
                    let patched = state.patch(kb, &graphs);
                    if let Err(e) = patched {
                        *guard = None;
                        return Err(e);
                    }
                }
                state.generation = now;
            }
            _ => *guard = Some(SpecState::build(kb)?),
        }
        Ok(guard)
    }
}

/// The CUs cached in `cached` at `key` (spec generation, environment generation), their
/// unbound ports from `library`. When the key moved, the cache is patched: only the graphs
/// [`stale_graphs`] names are read again (from the logs of
/// [`KnowledgeBase::environment_changes_since`] and [`KnowledgeBase::spec_changes_since`]);
/// everything is, when a log no longer reaches back or an extension or ontology changed.
fn cus_at(
    cached: &mut Option<CachedCus>,
    kb: &KnowledgeBase,
    key: (u64, u64),
    library: &BTreeMap<Tid, Transformation>,
) -> Result<BTreeMap<Cid, ComputationUnit>, ModelReadError> {
    if let Some(c) = cached.as_ref()
        && c.key == key
    {
        return Ok(c.cus.clone());
    }
    let graphs = match cached.take() {
        Some(mut old) => match stale_graphs(kb, &old)? {
            Some(stale) => {
                for g in stale {
                    match cu_graph(kb, &g)? {
                        Some(read) => old.graphs.insert(g, read),
                        None => old.graphs.remove(&g),
                    };
                }
                old.graphs
            }
            None => cu_graphs(kb)?,
        },
        None => cu_graphs(kb)?,
    };
    let cus = cus_of(graphs.values().flat_map(|g| &g.rows), library);
    *cached = Some(CachedCus {
        key,
        graphs,
        cus: cus.clone(),
    });
    Ok(cus)
}

/// The graphs of `old` to read again: those written since; those whose CUs looked something
/// up in a spec graph written since, or looked up a node that a graph written since (a
/// spec's, or the environment's) describes now; and those with a volatile lookup. `None` when
/// everything must be read again.
fn stale_graphs(
    kb: &KnowledgeBase,
    old: &CachedCus,
) -> Result<Option<BTreeSet<NamedNode>>, ModelReadError> {
    let Some(mut stale) = kb.environment_changes_since(old.key.1).1 else {
        return Ok(None);
    };
    let Some(graphs) = kb.spec_changes_since(old.key.0).1 else {
        return Ok(None);
    };
    let mut specs = BTreeSet::new();
    for graph in graphs {
        if crate::graphs::spec_of_graph(graph.as_str()).is_some() {
            specs.insert(graph);
        } else if !crate::graphs::is_environment_graph(graph.as_str()) {
            // An extension or ontology: what a CU reads may have changed anywhere.
            return Ok(None);
        }
    }
    // What the graphs written describe now (a removed one, nothing). An environment graph
    // may describe a node a CU looked up elsewhere: its triples, and what the reasoner infers
    // from them about the same subject (a `hasName` from a sub-property).
    let mut described = HashSet::new();
    for graph in specs.iter().chain(&stale) {
        for quad in kb
            .store()
            .quads_for_pattern(None, None, None, Some(graph.as_ref().into()))
        {
            described.insert(quad?.subject);
        }
    }
    for (g, read) in &old.graphs {
        if read.volatile
            || read.sources.iter().any(|s| specs.contains(s))
            || read.foreign.iter().any(|n| described.contains(n))
        {
            stale.insert(g.clone());
        }
    }
    Ok(Some(stale))
}

/// A port of a transformation: in (or out), its name, its IRI.
type PortIri = (bool, String, NamedNode);

/// A spec as stored, with the IRIs of a transformation's ports (direction `"in"`/`"out"`,
/// name, IRI).
fn read_spec(
    kb: &KnowledgeBase,
    kind: SpecKind,
    label: &str,
) -> Result<Option<(Spec, Vec<PortIri>)>, ModelReadError> {
    let graph = crate::graphs::spec_graph(kind, label);
    let triples = kb.graph_triples(graph.as_ref())?;
    if triples.is_empty() {
        return Ok(None);
    }
    let Some(spec) = crate::spec::spec_from_graph(&triples, kind) else {
        return Ok(None);
    };
    let mut ports = Vec::new();
    if kind == SpecKind::Transformation {
        use dyknow_ontology::vocab::dyknow;
        let names: std::collections::HashMap<&str, &str> = triples
            .iter()
            .filter(|t| t.predicate == dyknow::HAS_NAME)
            .filter_map(|t| match (&t.subject, &t.object) {
                (oxigraph::model::NamedOrBlankNode::NamedNode(s), Term::Literal(l)) => {
                    Some((s.as_str(), l.value()))
                }
                _ => None,
            })
            .collect();
        for t in &triples {
            let input = if t.predicate == dyknow::HAS_IN_PORT {
                true
            } else if t.predicate == dyknow::HAS_OUT_PORT {
                false
            } else {
                continue;
            };
            if let Term::NamedNode(port) = &t.object
                && let Some(name) = names.get(port.as_str())
            {
                ports.push((input, (*name).to_owned(), port.clone()));
            }
        }
    }
    Ok(Some((spec, ports)))
}

impl SpecState {
    /// Derives everything from the store.
    fn build(kb: &KnowledgeBase) -> Result<Self, ModelReadError> {
        // Read before the specs: a write after this is seen again at the next patch.
        let generation = kb.spec_generation();
        let mut state = Self {
            generation,
            base: Loaded::default(),
            index: CandidateIndex::default(),
        };
        let graphs: BTreeSet<NamedNode> = [SpecKind::Transformation, SpecKind::Target]
            .into_iter()
            .map(|kind| kb.spec_graphs(kind))
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .flatten()
            .map(|(_, graph)| graph)
            .collect();
        state.patch(kb, &graphs)?;
        Ok(state)
    }

    /// Reads again the specs of `graphs` (removed ones leave) and patches the candidate
    /// table; a graph that is not a spec's or the environment's is a schema change.
    fn patch(
        &mut self,
        kb: &KnowledgeBase,
        graphs: &BTreeSet<NamedNode>,
    ) -> Result<(), ModelReadError> {
        let mut changes = SpecChanges::default();
        let mut schema_changed = false;
        let base = &mut self.base;
        let iris = Arc::make_mut(&mut base.iris);
        let specs = Arc::make_mut(&mut base.specs);
        for graph in graphs {
            let Some((kind, label)) = crate::graphs::spec_of_graph(graph.as_str()) else {
                schema_changed |= !crate::graphs::is_environment_graph(graph.as_str());
                continue;
            };
            let read = read_spec(kb, kind, &label)?;
            match kind {
                SpecKind::Transformation => {
                    let tid = Tid::new(label);
                    base.env.library.remove(&tid);
                    specs.remove(&tid);
                    iris.transformations.remove(&tid);
                    remove_ports(&mut iris.in_ports, &tid);
                    remove_ports(&mut iris.out_ports, &tid);
                    let spec = match read {
                        Some((Spec::Transformation(t), ports)) => {
                            insert_transformation(&mut base.env, specs, iris, &t, ports);
                            Some(t)
                        }
                        _ => None,
                    };
                    changes.transformations.insert(tid, spec);
                }
                SpecKind::Target => {
                    let qid = dyknow_engine::Qid::new(label);
                    base.env.targets.remove(&qid);
                    let spec = match read {
                        Some((Spec::Target(t), _)) => {
                            base.env.targets.insert(
                                qid.clone(),
                                Target {
                                    qid: qid.clone(),
                                    channel: t.channel.clone().into(),
                                },
                            );
                            Some(t)
                        }
                        _ => None,
                    };
                    changes.targets.insert(qid, spec);
                }
            }
        }
        self.index.apply(kb, changes, schema_changed)?;
        base.candidates = self.index.table();
        Ok(())
    }
}

/// Removes the port IRIs of transformation `tid`: a range of the map (keys start with the tid),
/// not a scan of every port (which made reading 10,000 specs quadratic).
fn remove_ports(map: &mut BTreeMap<(Tid, String), NamedNode>, tid: &Tid) {
    let keys: Vec<(Tid, String)> = map
        .range((tid.clone(), String::new())..)
        .take_while(|((t, _), _)| t == tid)
        .map(|(k, _)| k.clone())
        .collect();
    for k in keys {
        map.remove(&k);
    }
}

/// Adds transformation spec `t` (with its port IRIs) to the library, the specs and the IRIs.
fn insert_transformation(
    env: &mut Environment,
    specs: &mut BTreeMap<Tid, TransformationSpec>,
    iris: &mut Iris,
    t: &TransformationSpec,
    ports: Vec<PortIri>,
) {
    let tid = Tid::new(t.label.clone());
    specs.insert(tid.clone(), t.clone());
    iris.transformations
        .insert(tid.clone(), NamedNode::new_unchecked(t.iri.clone()));
    for (input, name, port) in ports {
        let map = if input {
            &mut iris.in_ports
        } else {
            &mut iris.out_ports
        };
        map.insert((tid.clone(), name), port);
    }
    env.library.insert(
        tid.clone(),
        Transformation {
            tid,
            inputs: t.inputs.iter().map(|p| p.name.clone()).collect(),
            outputs: t.outputs.iter().map(|p| p.name.clone()).collect(),
            labour: t.labour,
            upkeep: t.upkeep,
        },
    );
}

/// One CU port binding as [`queries::CUS`] gives it: the CU's name, tid, protection, and a
/// port (in or out, its name, its channel) if it has one.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct CuRow {
    name: String,
    tid: String,
    protected: bool,
    port: Option<(bool, String, Option<String>)>,
}

/// The CU rows of every environment graph, read straight from the store's indexes: per CU
/// (found through the `rdf:type dyknow:ComputationUnit` index), its own triples, and the
/// names of its ports and transformation looked up by subject. What [`queries::CUS`] answers,
/// without the joins over every graph that made it grow with the library (115 ms at 800
/// transformations and 4 CUs).
fn cu_graphs(kb: &KnowledgeBase) -> Result<BTreeMap<NamedNode, CuGraph>, ModelReadError> {
    use dyknow_ontology::vocab::dyknow;
    use oxigraph::model::GraphName;
    use oxigraph::model::vocab::rdf;

    let mut graphs: BTreeMap<NamedNode, CuGraph> = BTreeMap::new();
    for quad in kb.store().quads_for_pattern(
        None,
        Some(rdf::TYPE),
        Some(dyknow::COMPUTATION_UNIT.into()),
        None,
    ) {
        let quad = quad?;
        let GraphName::NamedNode(g) = quad.graph_name else {
            continue;
        };
        if !crate::graphs::is_environment_graph(g.as_str()) {
            continue;
        }
        let read = graphs.entry(g.clone()).or_default();
        read_cu(kb, &quad.subject, &g, read)?;
    }
    Ok(graphs)
}

/// The CU rows of environment graph `graph`, `None` when it holds no CU.
fn cu_graph(kb: &KnowledgeBase, graph: &NamedNode) -> Result<Option<CuGraph>, ModelReadError> {
    use dyknow_ontology::vocab::dyknow;
    use oxigraph::model::vocab::rdf;

    if !crate::graphs::is_environment_graph(graph.as_str()) {
        return Ok(None);
    }
    let mut read = None;
    for quad in kb.store().quads_for_pattern(
        None,
        Some(rdf::TYPE),
        Some(dyknow::COMPUTATION_UNIT.into()),
        Some(graph.as_ref().into()),
    ) {
        read_cu(
            kb,
            &quad?.subject,
            graph,
            read.get_or_insert_with(CuGraph::default),
        )?;
    }
    Ok(read)
}

/// Adds the rows of CU `cu`, described in `graph`, to `read`.
fn read_cu(
    kb: &KnowledgeBase,
    cu: &oxigraph::model::NamedOrBlankNode,
    graph: &NamedNode,
    read: &mut CuGraph,
) -> Result<(), ModelReadError> {
    use dyknow_ontology::vocab::{dkros, dyknow};
    use oxigraph::model::vocab::rdfs;
    use oxigraph::model::{GraphName, GraphNameRef, NamedNodeRef};

    let store = kb.store();
    // The objects of (subject, predicate) in `graph` (any graph when `None`).
    let objects = |subject: &NamedOrBlankNode,
                   predicate: NamedNodeRef<'_>,
                   graph: Option<GraphNameRef<'_>>|
     -> Result<Vec<Term>, ModelReadError> {
        Ok(store
            .quads_for_pattern(Some(subject.as_ref()), Some(predicate), None, graph)
            .map(|q| q.map(|q| q.object))
            .collect::<Result<Vec<_>, _>>()?)
    };
    let literals = |terms: Vec<Term>| -> Vec<String> {
        terms
            .into_iter()
            .filter_map(|t| match t {
                Term::Literal(l) => Some(l.value().to_owned()),
                _ => None,
            })
            .collect()
    };
    let node = |t: Term| match t {
        Term::NamedNode(n) => Some(NamedOrBlankNode::NamedNode(n)),
        Term::BlankNode(b) => Some(NamedOrBlankNode::BlankNode(b)),
        Term::Literal(_) => None,
    };
    // The objects of (subject, predicate) in any graph, noted as looked up outside the CU's
    // graph, with the graphs that answered.
    let mut foreign = |subject: &NamedOrBlankNode,
                       predicate: NamedNodeRef<'_>|
     -> Result<Vec<Term>, ModelReadError> {
        read.foreign.insert(subject.clone());
        let mut out = Vec::new();
        for quad in store.quads_for_pattern(Some(subject.as_ref()), Some(predicate), None, None) {
            let quad = quad?;
            match quad.graph_name {
                GraphName::NamedNode(g) if crate::graphs::spec_of_graph(g.as_str()).is_some() => {
                    read.sources.insert(g);
                }
                _ => read.volatile = true,
            }
            out.push(quad.object);
        }
        Ok(out)
    };
    let graph = Some(GraphNameRef::NamedNode(graph.as_ref()));
    let names = literals(objects(cu, dyknow::HAS_NAME, graph)?);
    let protected = literals(objects(cu, dkros::IS_PROTECTED, graph)?)
        .first()
        .is_some_and(|v| v == "true" || v == "1");
    // The CU's port bindings: (in, port node, binding node) per subscription/publication.
    let mut ports = Vec::new();
    for (input, link, to_port, on_channel) in [
        (
            true,
            dyknow::HAS_SUBSCRIPTION,
            dyknow::TO_PORT,
            dyknow::HAS_CHANNEL,
        ),
        (
            false,
            dkros::HAS_PUBLICATION,
            dkros::PUBLISHES_PORT,
            dkros::ON_CHANNEL,
        ),
    ] {
        for binding in objects(cu, link, graph)?.into_iter().filter_map(node) {
            let mut channels = Vec::new();
            for ch in objects(&binding, on_channel, graph)?
                .into_iter()
                .filter_map(node)
            {
                channels.extend(literals(objects(&ch, dyknow::HAS_CHANNEL_NAME, graph)?));
            }
            for port in objects(&binding, to_port, graph)?
                .into_iter()
                .filter_map(node)
            {
                for name in literals(foreign(&port, dyknow::HAS_NAME)?) {
                    if channels.is_empty() {
                        ports.push((input, name.clone(), None));
                    }
                    for channel in &channels {
                        ports.push((input, name.clone(), Some(channel.clone())));
                    }
                }
            }
        }
    }
    for tf in objects(cu, dyknow::INSTANCE_OF, graph)? {
        let label = node(tf.clone())
            .map(|n| foreign(&n, rdfs::LABEL).map(literals))
            .transpose()?
            .unwrap_or_default();
        let tids = if label.is_empty() {
            match &tf {
                Term::NamedNode(n) => vec![n.as_str().to_owned()],
                Term::Literal(l) => vec![l.value().to_owned()],
                Term::BlankNode(_) => Vec::new(),
            }
        } else {
            label
        };
        for name in &names {
            for tid in &tids {
                let row = |port| CuRow {
                    name: name.clone(),
                    tid: tid.clone(),
                    protected,
                    port,
                };
                if ports.is_empty() {
                    read.rows.push(row(None));
                }
                read.rows
                    .extend(ports.iter().cloned().map(|p| row(Some(p))));
            }
        }
    }
    Ok(())
}

/// The CU rows [`queries::CUS`] answers.
fn cu_rows_by_query(kb: &KnowledgeBase) -> Result<Vec<CuRow>, ModelReadError> {
    let mut rows = Vec::new();
    for row in kb.select(&queries::CUS)? {
        let (Some(name), Some(tid)) = (literal(&row[0]), literal(&row[1])) else {
            continue;
        };
        let port = match (literal(&row[3]), literal(&row[4])) {
            (Some(dir), Some(port)) => Some((dir == "in", port, literal(&row[5]))),
            _ => None,
        };
        rows.push(CuRow {
            name,
            tid,
            protected: literal(&row[2]).is_some_and(|v| v == "true" || v == "1"),
            port,
        });
    }
    Ok(rows)
}

/// The CUs of `rows`, each port of its transformation in `library` listed, bound or not.
fn cus_of<'a>(
    rows: impl IntoIterator<Item = &'a CuRow>,
    library: &BTreeMap<Tid, Transformation>,
) -> BTreeMap<Cid, ComputationUnit> {
    let mut cus = BTreeMap::new();
    for row in rows {
        let cid = Cid::new(row.name.clone());
        let cu = cus.entry(cid.clone()).or_insert_with(|| ComputationUnit {
            cid,
            tid: Tid::new(row.tid.clone()),
            inputs: BTreeMap::new(),
            outputs: BTreeMap::new(),
            protected: row.protected,
        });
        if let Some((input, port, channel)) = &row.port {
            let channel = channel.clone().map(Into::into);
            if *input {
                cu.inputs.insert(port.clone(), channel);
            } else {
                cu.outputs.insert(port.clone(), channel);
            }
        }
    }
    for cu in cus.values_mut() {
        if let Some(tf) = library.get(&cu.tid) {
            for p in &tf.inputs {
                cu.inputs.entry(p.clone()).or_insert(None);
            }
            for p in &tf.outputs {
                cu.outputs.entry(p.clone()).or_insert(None);
            }
        }
    }
    cus
}

/// The CUs as [`queries::CUS`] reads them: the reference the service's direct read is tested
/// against (`store/tests/model.rs`), not used by the service.
pub fn cus_by_query(
    kb: &KnowledgeBase,
    library: &BTreeMap<Tid, Transformation>,
) -> Result<BTreeMap<Cid, ComputationUnit>, ModelReadError> {
    Ok(cus_of(&cu_rows_by_query(kb)?, library))
}

/// The candidate table of `env`'s library and targets ([`queries::CANDIDATES`]).
pub fn candidates(kb: &KnowledgeBase, env: &Environment) -> Result<Candidates, ModelReadError> {
    let mut table = Candidates::default();
    let index = |tid: &str, name: &str, outputs: bool| {
        env.library.get(tid).and_then(|t| {
            let ports = if outputs { &t.outputs } else { &t.inputs };
            ports.iter().position(|p| p == name)
        })
    };
    for row in kb.select(&queries::CANDIDATES)? {
        let (Some(producer), Some(out_port)) = (literal(&row[3]), literal(&row[4])) else {
            continue;
        };
        let Some(port) = index(&producer, &out_port, true) else {
            continue;
        };
        let provider = Provider {
            tid: producer.into(),
            port,
        };
        match (literal(&row[0]), literal(&row[1]), literal(&row[2])) {
            (Some(consumer), Some(in_port), _) => {
                if let Some(i) = index(&consumer, &in_port, false) {
                    table.add_input(&consumer, i, provider);
                }
            }
            (_, _, Some(target)) => table.add_target(&target, provider),
            _ => {}
        }
    }
    Ok(table)
}

/// Reads the learned estimates.
pub fn learned(kb: &KnowledgeBase) -> Result<Learned, ModelReadError> {
    let mut out = Learned::default();
    for r in kb.select(&queries::LEARNED)? {
        let (Some(tid), Some(kind), Some(average), Some(count)) = (
            literal(&r[0]),
            literal(&r[1]),
            literal(&r[2]).and_then(|v| v.parse::<f64>().ok()),
            literal(&r[3]).and_then(|v| v.parse::<u64>().ok()),
        ) else {
            continue;
        };
        let map = match cost_kind(&kind) {
            CostKind::Labour => &mut out.labour,
            CostKind::Upkeep => &mut out.upkeep,
        };
        map.insert(Tid::new(tid), Estimate { average, count });
    }
    Ok(out)
}

/// The kind column of [`queries::COST_MODELS`] and [`queries::LEARNED`].
pub(crate) fn cost_kind(kind: &str) -> CostKind {
    if kind == "labour" {
        CostKind::Labour
    } else {
        CostKind::Upkeep
    }
}

/// A change-set record that does not read back as a change set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnreadableRecord {
    /// Its id (`rdfs:label`), when it has one.
    pub id: Option<ChangeSetId>,
    /// Why it does not read.
    pub error: String,
}

/// The change sets recorded in the knowledge base.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ChangeSetRecords {
    /// Those that read back, oldest first.
    pub change_sets: Vec<ChangeSet>,
    /// Those that do not (written by a later release, or damaged): the service starts without
    /// them, but their numbers stay taken.
    pub unreadable: Vec<UnreadableRecord>,
}

/// The change sets recorded in the knowledge base, oldest first, and the records that do not
/// read back as change sets.
pub fn change_sets(kb: &KnowledgeBase) -> Result<ChangeSetRecords, ModelReadError> {
    let mut out = ChangeSetRecords::default();
    for row in kb.select(&queries::CHANGE_SETS)? {
        let id = literal(&row[0]).map(ChangeSetId::new);
        let read = literal(&row[1])
            .ok_or_else(|| "it has no dkros:changeSetJson".to_owned())
            .and_then(|json| serde_json::from_str::<ChangeSet>(&json).map_err(|e| e.to_string()));
        match read {
            Ok(change_set) => out.change_sets.push(change_set),
            Err(error) => out.unreadable.push(UnreadableRecord { id, error }),
        }
    }
    out.change_sets
        .sort_by_key(|cs| (cs.id.number().unwrap_or(0), cs.id.clone()));
    Ok(out)
}

/// The names the history part reserves (`dkros:reservesName`): names pruned change sets used,
/// never handed out again.
pub fn reserved_names(kb: &KnowledgeBase) -> Result<Vec<String>, ModelReadError> {
    let graph = crate::graphs::EnvironmentPart::History.graph();
    let mut out = Vec::new();
    for quad in kb.store().quads_for_pattern(
        None,
        Some(dyknow_ontology::vocab::dkros::RESERVES_NAME),
        None,
        Some(graph.as_ref().into()),
    ) {
        let quad = quad?;
        if let Term::Literal(l) = quad.object {
            out.push(l.value().to_owned());
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {

    use std::sync::mpsc;
    use std::time::Duration;

    use super::*;
    use crate::InputFormat;

    fn example_12() -> KnowledgeBase {
        let kb = KnowledgeBase::in_memory().unwrap();
        for f in ["example-12.ttl", "example-12-targets.ttl"] {
            let path = format!("{}/../specs/turtle/{f}", env!("CARGO_MANIFEST_DIR"));
            kb.load_document(&std::fs::read(&path).unwrap(), InputFormat::Turtle)
                .unwrap();
        }
        kb
    }

    /// `GET /cus` never waits for a refresh another thread has under way (a review patching
    /// the candidate table): it is served the last published snapshot; once nobody refreshes,
    /// a read brings the snapshot up to date itself; with nothing written, no read again.
    #[test]
    fn a_read_under_a_refresh_gets_the_last_snapshot_without_waiting() {
        let kb = example_12();
        let cache = SpecCache::default();
        assert!(cache.cus_published(&kb).is_none(), "nothing published yet");
        let first = cache.publish(&kb).unwrap();
        assert!(first.specs.contains_key("tid4"));
        assert!(Arc::ptr_eq(&cache.cus_now(&kb).unwrap(), &first));
        assert!(Arc::ptr_eq(&cache.cus_published(&kb).unwrap(), &first));
        kb.remove_spec(SpecKind::Transformation, "tid4").unwrap();
        assert!(
            cache.cus_published(&kb).is_none(),
            "a snapshot older than a write is not served from memory"
        );
        for lock in ["state", "cus"] {
            std::thread::scope(|s| {
                // A refresh under way holds one of the cache's locks.
                let held_state = (lock == "state").then(|| cache.state.lock().unwrap());
                let held_cus = (lock == "cus").then(|| cache.cus.lock().unwrap());
                let (tx, rx) = mpsc::channel();
                let (cache, kb) = (&cache, &kb);
                s.spawn(move || {
                    let _ = tx.send(cache.cus_now(kb).unwrap());
                });
                let got = rx
                    .recv_timeout(Duration::from_secs(30))
                    .expect("the read waited for the refresh under way");
                assert!(Arc::ptr_eq(&got, &first), "{lock}: {got:?}");
                drop((held_state, held_cus));
            });
        }
        let now = cache.cus_now(&kb).unwrap();
        assert!(!now.specs.contains_key("tid4"));
        assert!(Arc::ptr_eq(&cache.cus_published(&kb).unwrap(), &now));
        assert!(at_least(
            now.key,
            (kb.spec_generation(), kb.environment_generation())
        ));
    }

    /// `GET /environment` never waits for a refresh under way either: it gets the last
    /// published spec-derived part (here still with `tid4`) and the CUs as `cus_now` has them;
    /// once nobody refreshes it is up to date again, and equal to `load`.
    #[test]
    fn an_environment_read_under_a_refresh_gets_the_last_spec_part_without_waiting() {
        let kb = example_12();
        let cache = SpecCache::default();
        let first = cache.load_now(&kb, None).unwrap();
        assert!(first.env.library.contains_key("tid4"));
        assert_eq!(
            first.env,
            cache.load(&kb, None).unwrap().env,
            "load_now is load when nobody refreshes"
        );
        kb.remove_spec(SpecKind::Transformation, "tid4").unwrap();
        std::thread::scope(|s| {
            let held = cache.state.lock().unwrap();
            let (tx, rx) = mpsc::channel();
            let (cache, kb) = (&cache, &kb);
            s.spawn(move || {
                let _ = tx.send(cache.load_now(kb, None).unwrap());
            });
            let got = rx
                .recv_timeout(Duration::from_secs(30))
                .expect("the read waited for the refresh under way");
            assert!(
                got.env.library.contains_key("tid4"),
                "the last published part"
            );
            drop(held);
        });
        let now = cache.load_now(&kb, None).unwrap();
        assert!(!now.env.library.contains_key("tid4"));
        assert_eq!(now.env, cache.load(&kb, None).unwrap().env);
    }
}
