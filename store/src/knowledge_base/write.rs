//! The reasoned write path: every write is validated, reasoned incrementally (from scratch
//! when an ontology extension changes the schema) and applied as one atomic Oxigraph write
//! under the write lock, which owns the reasoner.

use std::collections::BTreeSet;

use dyknow_ontology::BUILTIN_ONTOLOGIES;
use dyknow_reasoner::{Reasoner, TBox};
use oxigraph::model::{NamedNode, NamedNodeRef, Term, Triple};
use oxigraph::store::StorageError;

use super::KnowledgeBase;
use crate::error::{IngestError, SpecValidationError, StoreOpenError, Violation};
use crate::export::INFERRED_GRAPH;
use crate::graphs::{is_environment_graph, is_extension_graph, spec_of_graph};

/// Triples by the name of the graph that holds them.
type NamedSources = Vec<(String, Vec<Triple>)>;

/// From this many new triples on, a write is one SST ingestion rather than a write batch.
const BULK_LOAD_THRESHOLD: usize = 50_000;

/// After this many quads written or removed through memtables, the store is flushed.
///
/// Oxigraph opens RocksDB with a memtable budget of 512 MB (128 MB per column family before
/// a flush), so a service that keeps writing small change sets (a review records one, a crash
/// storm hundreds a minute) would otherwise grow its resident memory by hundreds of megabytes
/// before RocksDB flushes by itself, and replay as much write-ahead log at every restart.
/// A quad costs about 0.6 kB of memtable over its six indexes: this keeps them near 10 MB.
#[cfg_attr(
    not(feature = "rocksdb"),
    expect(dead_code, reason = "only on-disk stores flush")
)]
pub(super) const FLUSH_AFTER_QUADS: usize = 16_384;

/// Background flushes of the store's memtables (on-disk stores only).
#[derive(Debug, Default)]
#[cfg_attr(
    not(feature = "rocksdb"),
    expect(dead_code, reason = "only on-disk stores flush")
)]
pub(super) struct Flusher {
    /// Quads written or removed through memtables since the last flush began.
    unflushed: std::sync::atomic::AtomicUsize,
    /// Whether a flush is running (at most one at a time).
    running: std::sync::Arc<std::sync::atomic::AtomicBool>,
    /// Flushes started, for tests and monitoring.
    started: std::sync::atomic::AtomicU64,
    /// The last flush's thread: it holds the store open until it is done.
    thread: std::sync::Mutex<Option<std::thread::JoinHandle<()>>>,
}

impl Drop for Flusher {
    /// Waits for a running flush, so that a knowledge base dropped is closed (and may be
    /// opened again) once the drop returns.
    fn drop(&mut self) {
        let thread = self
            .thread
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        if let Some(thread) = thread {
            let _ = thread.join();
        }
    }
}

impl KnowledgeBase {
    /// Replaces each graph of `writes` by its triples and removes the graphs of `removes`,
    /// atomically, with the matching change of the inferred graph; tells which graphs of
    /// `writes` existed. The caller holds the write lock (`reasoner`).
    ///
    /// The materialisation is updated incrementally, or recomputed when an ontology extension
    /// changes the schema. A request that violates a consistency rule the store did not violate
    /// already is refused (422) and nothing is written; the reasoner is left as it was.
    pub(super) fn commit(
        &self,
        reasoner: &mut Reasoner,
        writes: &[(&NamedNode, &[Triple])],
        removes: &[&NamedNode],
    ) -> Result<Vec<bool>, IngestError> {
        let result = self.commit_inner(reasoner, writes, removes);
        // A write that may change a spec or the schema invalidates what readers derived from
        // them. Bumped after the write: a reader that read the old number may cache new data
        // under it (and reload needlessly once), but never old data under the new number.
        let (environment, touched): (Vec<NamedNode>, Vec<NamedNode>) = writes
            .iter()
            .map(|(g, _)| *g)
            .chain(removes.iter().copied())
            .cloned()
            .partition(|g| is_environment_graph(g.as_str()));
        bump(
            &self.environment_generation,
            &self.environment_log,
            environment,
        );
        bump(&self.spec_generation, &self.spec_log, touched);
        result
    }

    pub(super) fn commit_inner(
        &self,
        reasoner: &mut Reasoner,
        writes: &[(&NamedNode, &[Triple])],
        removes: &[&NamedNode],
    ) -> Result<Vec<bool>, IngestError> {
        let replaced = writes
            .iter()
            .map(|(g, _)| self.store.contains_named_graph(*g))
            .collect::<Result<Vec<bool>, _>>()?;
        let schema_change = writes
            .iter()
            .map(|(g, _)| *g)
            .chain(removes.iter().copied())
            .any(|g| is_extension_graph(g.as_str()));
        if schema_change {
            let next = self.materialise(writes, removes)?;
            let before: std::collections::HashSet<String> = reasoner
                .violations()
                .iter()
                .map(ToString::to_string)
                .collect();
            let introduced: Vec<dyknow_reasoner::Violation> = next
                .violations()
                .into_iter()
                .filter(|v| !before.contains(&v.to_string()))
                .collect();
            if !introduced.is_empty() {
                return Err(inconsistency(&introduced));
            }
            let old_inferred: std::collections::HashSet<Triple> =
                reasoner.inferred().into_iter().collect();
            let new_inferred: std::collections::HashSet<Triple> =
                next.inferred().into_iter().collect();
            let added: Vec<Triple> = new_inferred.difference(&old_inferred).cloned().collect();
            let removed: Vec<Triple> = old_inferred.difference(&new_inferred).cloned().collect();
            self.write(writes, removes, &replaced, &added, &removed)?;
            *reasoner = next;
            return Ok(replaced);
        }

        let changes: Vec<(String, Vec<Triple>)> = writes
            .iter()
            .map(|(g, t)| (g.as_str().to_owned(), t.to_vec()))
            .chain(removes.iter().map(|g| (g.as_str().to_owned(), Vec::new())))
            .collect();
        let (update, previous) = reasoner.set_graphs(&changes);
        if !update.violations.is_empty() {
            reasoner.set_graphs(&previous);
            return Err(inconsistency(&update.violations));
        }
        if let Err(e) = self.write(
            writes,
            removes,
            &replaced,
            &update.inferred_added,
            &update.inferred_removed,
        ) {
            reasoner.set_graphs(&previous);
            return Err(e.into());
        }
        Ok(replaced)
    }

    /// One atomic write: new graphs take the fast paths (a plain write batch, or SST ingestion
    /// for large batches); replacing or removing graphs, or removing inferred triples, needs an
    /// indexed transaction.
    pub(super) fn write(
        &self,
        writes: &[(&NamedNode, &[Triple])],
        removes: &[&NamedNode],
        replaced: &[bool],
        inferred_added: &[Triple],
        inferred_removed: &[Triple],
    ) -> Result<(), StorageError> {
        let inferred = NamedNodeRef::new_unchecked(INFERRED_GRAPH);
        let quads = writes
            .iter()
            .flat_map(|(g, triples)| {
                triples
                    .iter()
                    .map(|t| t.as_ref().in_graph(g.as_ref()).into_owned())
            })
            .chain(
                inferred_added
                    .iter()
                    .map(|t| t.as_ref().in_graph(inferred).into_owned()),
            );
        if !replaced.contains(&true) && removes.is_empty() && inferred_removed.is_empty() {
            let size: usize =
                writes.iter().map(|(_, t)| t.len()).sum::<usize>() + inferred_added.len();
            if size >= BULK_LOAD_THRESHOLD {
                // One atomic ingestion of sorted SST files.
                let mut loader = self.store.bulk_loader();
                loader.load_quads(quads)?;
                loader.commit()?;
            } else {
                self.store.extend(quads)?;
                self.flush_if_due(size);
            }
            return Ok(());
        }
        let written = writes.iter().map(|(_, t)| t.len()).sum::<usize>()
            + inferred_added.len()
            + inferred_removed.len();
        self.write_transaction(writes, removes, replaced, inferred_removed, quads)?;
        // A replaced or removed graph's old quads are deleted too: count them as about as
        // many as the write (the exact number would need a read).
        self.flush_if_due(written + written.max(removes.len() * 16));
        Ok(())
    }

    fn write_transaction(
        &self,
        writes: &[(&NamedNode, &[Triple])],
        removes: &[&NamedNode],
        replaced: &[bool],
        inferred_removed: &[Triple],
        quads: impl Iterator<Item = oxigraph::model::Quad>,
    ) -> Result<(), StorageError> {
        let inferred = NamedNodeRef::new_unchecked(INFERRED_GRAPH);
        let mut transaction = self.store.start_transaction()?;
        for g in removes {
            transaction.remove_named_graph(*g)?;
        }
        for ((g, _), existed) in writes.iter().zip(replaced) {
            if *existed {
                transaction.clear_graph(*g)?;
            }
        }
        for t in inferred_removed {
            transaction.remove(t.as_ref().in_graph(inferred));
        }
        for quad in quads {
            transaction.insert(&quad);
        }
        transaction.commit()
    }

    /// Counts `quads` written through the memtables and, once [`FLUSH_AFTER_QUADS`] are
    /// pending, flushes the on-disk store in the background (one flush at a time; writes go on
    /// meanwhile). In-memory stores have nothing to flush.
    #[cfg(feature = "rocksdb")]
    pub(super) fn flush_if_due(&self, quads: usize) {
        use std::sync::atomic::Ordering;
        if self.location.is_none() {
            return;
        }
        let flusher = &self.flusher;
        let pending = flusher.unflushed.fetch_add(quads, Ordering::SeqCst) + quads;
        if pending < FLUSH_AFTER_QUADS || flusher.running.swap(true, Ordering::SeqCst) {
            return;
        }
        flusher.unflushed.store(0, Ordering::SeqCst);
        flusher.started.fetch_add(1, Ordering::SeqCst);
        let store = self.store.clone();
        let running = std::sync::Arc::clone(&flusher.running);
        let spawned = std::thread::Builder::new()
            .name("dyknow-flush".into())
            .spawn(move || {
                // A failed flush loses nothing (the write-ahead log holds every write): RocksDB
                // flushes by itself later.
                if let Err(e) = store.flush() {
                    tracing::warn!("flushing the store failed: {e}");
                }
                running.store(false, Ordering::SeqCst);
            });
        match spawned {
            // The previous flush is done (`running` was false): its thread is joined.
            Ok(thread) => {
                let previous = flusher
                    .thread
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .replace(thread);
                if let Some(previous) = previous {
                    let _ = previous.join();
                }
            }
            Err(_) => flusher.running.store(false, Ordering::SeqCst),
        }
    }

    #[cfg(not(feature = "rocksdb"))]
    pub(super) fn flush_if_due(&self, _quads: usize) {}

    /// How many background flushes of the memtables were started since the store was opened.
    pub fn flushes_started(&self) -> u64 {
        self.flusher
            .started
            .load(std::sync::atomic::Ordering::SeqCst)
    }

    /// The triples of the graphs that hold the schema (built-in ontologies and extensions) and
    /// of those that hold data (specs and extensions), as they will be once `writes` and
    /// `removes` are applied.
    pub(super) fn schema_and_data(
        &self,
        writes: &[(&NamedNode, &[Triple])],
        removes: &[&NamedNode],
    ) -> Result<(Vec<Triple>, NamedSources), StorageError> {
        let mut schema = Vec::new();
        let mut data = Vec::new();
        for graph in self.store.named_graphs() {
            let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph? else {
                continue;
            };
            if writes.iter().any(|(w, _)| **w == g) || removes.iter().any(|r| **r == g) {
                continue;
            }
            let builtin = BUILTIN_ONTOLOGIES.iter().any(|(iri, _)| *iri == g.as_str());
            let extension = is_extension_graph(g.as_str());
            let spec = spec_of_graph(g.as_str()).is_some() || is_environment_graph(g.as_str());
            if !(builtin || extension || spec) {
                continue;
            }
            let triples = self.graph_triples(g.as_ref())?;
            if builtin || extension {
                schema.extend(triples.iter().cloned());
            }
            if extension || spec {
                data.push((g.into_string(), triples));
            }
        }
        for (g, triples) in writes {
            if is_extension_graph(g.as_str()) {
                schema.extend(triples.iter().cloned());
            }
            data.push((g.as_str().to_owned(), triples.to_vec()));
        }
        Ok((schema, data))
    }

    /// A reasoner materialising the store as it will be once `writes` and `removes` are
    /// applied, from scratch.
    pub(super) fn materialise(
        &self,
        writes: &[(&NamedNode, &[Triple])],
        removes: &[&NamedNode],
    ) -> Result<Reasoner, IngestError> {
        let (schema, data) = self.schema_and_data(writes, removes)?;
        let tbox = TBox::from_triples(&schema).map_err(|e| {
            IngestError::Invalid(SpecValidationError(vec![Violation::new(
                e.to_string(),
                "the ontology",
            )]))
        })?;
        let mut reasoner = Reasoner::new(tbox);
        reasoner.set_graphs(&data);
        Ok(reasoner)
    }

    pub(super) fn materialise_at_open(&self) -> Result<Reasoner, StoreOpenError> {
        self.materialise(&[], &[]).map_err(|e| match e {
            IngestError::Storage(e) => StoreOpenError::Storage(e),
            other => StoreOpenError::Ontology(other.to_string()),
        })
    }

    /// The generation now and the graphs (specs, extensions, ontologies) written or removed
    /// since generation `since`, or `None` when the log no longer reaches back that far (then
    /// everything derived from specs must be derived again). A graph listed may have been
    /// written back unchanged; its content must be read after this call.
    pub fn spec_changes_since(&self, since: u64) -> (u64, Option<BTreeSet<NamedNode>>) {
        changes_since(&self.spec_generation, &self.spec_log, since)
    }

    /// The environment generation now and the environment graphs (CUs, change-set records,
    /// statistics) written or removed since generation `since`, or `None` when the log no
    /// longer reaches back that far (then everything derived from the environment must be read
    /// again). As [`KnowledgeBase::spec_changes_since`]: a graph listed may have been written
    /// back unchanged, or written after the generation returned; read it after this call.
    pub fn environment_changes_since(&self, since: u64) -> (u64, Option<BTreeSet<NamedNode>>) {
        changes_since(&self.environment_generation, &self.environment_log, since)
    }

    /// A number that changes whenever a spec, an extension or an ontology graph is written or
    /// removed (not for environment graphs): what is derived from specs alone may be cached
    /// against it.
    pub fn spec_generation(&self) -> u64 {
        self.spec_generation
            .load(std::sync::atomic::Ordering::SeqCst)
    }

    /// A number that changes whenever an environment graph (a CU, a change-set record, the
    /// statistics) is written or removed: what is derived from the environment (with the
    /// specs, [`KnowledgeBase::spec_generation`]) may be cached against it.
    pub fn environment_generation(&self) -> u64 {
        self.environment_generation
            .load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Checks the incremental materialisation: the triples of the stored inferred graph that a
    /// from-scratch materialisation of the stored explicit triples does not entail, and those
    /// it entails that are missing. Both empty when all is well (a consistency check for
    /// tests and operators; it reasons over the whole store).
    pub fn materialisation_drift(&self) -> Result<(Vec<Triple>, Vec<Triple>), IngestError> {
        let _guard = self.lock();
        let scratch = self.materialise(&[], &[])?;
        let inferred = NamedNodeRef::new_unchecked(INFERRED_GRAPH);
        let stored: std::collections::HashSet<Triple> =
            self.graph_triples(inferred)?.into_iter().collect();
        let wanted: std::collections::HashSet<Triple> = scratch.inferred().into_iter().collect();
        let mut extra: Vec<Triple> = stored.difference(&wanted).cloned().collect();
        let mut missing: Vec<Triple> = wanted.difference(&stored).cloned().collect();
        extra.sort_by_cached_key(ToString::to_string);
        missing.sort_by_cached_key(ToString::to_string);
        Ok((extra, missing))
    }

    /// At start-up: materialises the store from scratch and makes the inferred graph match
    /// (it differs after an upgrade of the built-in ontologies or of the reasoner).
    pub(super) fn install_materialisation(&self) -> Result<(), StoreOpenError> {
        let reasoner = self.materialise_at_open()?;
        let inferred = NamedNodeRef::new_unchecked(INFERRED_GRAPH);
        let stored: std::collections::HashSet<Triple> =
            self.graph_triples(inferred)?.into_iter().collect();
        let wanted: std::collections::HashSet<Triple> = reasoner.inferred().into_iter().collect();
        let mut guard = self.lock();
        if stored != wanted {
            let mut transaction = self.store.start_transaction()?;
            for t in stored.difference(&wanted) {
                transaction.remove(t.as_ref().in_graph(inferred));
            }
            for t in wanted.difference(&stored) {
                transaction.insert(t.as_ref().in_graph(inferred));
            }
            transaction.commit()?;
        }
        *guard = reasoner;
        Ok(())
    }

    /// The axioms of the schema the reasoner does not support (OWL functional syntax), sorted:
    /// the service logs them at start-up.
    pub fn unsupported_axioms(&self) -> Vec<String> {
        self.lock().tbox().unsupported_axioms().to_vec()
    }

    /// Every consistency rule the stored environment violates (normally none: writes that
    /// would violate one are refused).
    pub fn violations(&self) -> Vec<dyknow_reasoner::Violation> {
        self.lock().violations()
    }
}

/// The 422 answer for violated consistency rules: one detail per violation, naming the rule and
/// the axiom, with the first node as subject and every node involved.
pub(super) fn inconsistency(violations: &[dyknow_reasoner::Violation]) -> IngestError {
    IngestError::Invalid(SpecValidationError(
        violations
            .iter()
            .map(|v| {
                let nodes: Vec<String> = v
                    .nodes
                    .iter()
                    .map(|n| match n {
                        Term::NamedNode(n) => n.as_str().to_owned(),
                        other => other.to_string(),
                    })
                    .collect();
                Violation {
                    constraint: format!("{} ({})", v.axiom, v.rule),
                    subject: nodes.first().cloned().unwrap_or_default(),
                    nodes,
                }
            })
            .collect(),
    ))
}

/// Bumps `generation` and logs `graphs` under it, when there are any. Under the log's lock, so
/// the log's generations increase ([`GraphLog::since`] relies on it).
fn bump(
    generation: &std::sync::atomic::AtomicU64,
    log: &std::sync::Mutex<GraphLog>,
    graphs: Vec<NamedNode>,
) {
    if graphs.is_empty() {
        return;
    }
    let mut log = log
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let now = generation.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
    log.record(now, graphs);
}

/// The generation now and what `log` has since `since`, read under the log's lock (so no bump
/// lands between the two).
fn changes_since(
    generation: &std::sync::atomic::AtomicU64,
    log: &std::sync::Mutex<GraphLog>,
    since: u64,
) -> (u64, Option<BTreeSet<NamedNode>>) {
    let log = log
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let now = generation.load(std::sync::atomic::Ordering::SeqCst);
    (now, log.since(since))
}

/// How many graph names a graph log keeps at most (readers further behind derive anew).
const GRAPH_LOG_NAMES: usize = 1 << 16;

/// The recent bumps of a generation (the specs', the environment's) and the graphs each was
/// for.
#[derive(Debug, Default)]
pub(super) struct GraphLog {
    entries: std::collections::VecDeque<(u64, Vec<NamedNode>)>,
    names: usize,
    /// Generations up to this one are no longer in `entries`.
    floor: u64,
}

impl GraphLog {
    pub(super) fn record(&mut self, generation: u64, graphs: Vec<NamedNode>) {
        self.names += graphs.len();
        self.entries.push_back((generation, graphs));
        while self.names > GRAPH_LOG_NAMES {
            let Some((dropped, graphs)) = self.entries.pop_front() else {
                break;
            };
            self.names -= graphs.len();
            self.floor = dropped;
        }
    }

    pub(super) fn since(&self, since: u64) -> Option<BTreeSet<NamedNode>> {
        (since >= self.floor).then(|| {
            // Recorded in increasing generations: skip the older ones without a scan.
            let first = self.entries.partition_point(|(g, _)| *g <= since);
            self.entries
                .range(first..)
                .flat_map(|(_, graphs)| graphs.iter().cloned())
                .collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(i: usize) -> NamedNode {
        NamedNode::new_unchecked(format!("urn:test:g{i}"))
    }

    #[test]
    fn the_spec_log_answers_since_a_generation_until_it_no_longer_reaches_back() {
        let mut log = GraphLog::default();
        log.record(1, vec![graph(1)]);
        log.record(2, vec![graph(2), graph(1)]);
        assert_eq!(log.since(0), Some(BTreeSet::from([graph(1), graph(2)])));
        assert_eq!(log.since(1), Some(BTreeSet::from([graph(1), graph(2)])));
        assert_eq!(log.since(2), Some(BTreeSet::new()));
        // A write of more names than the log keeps pushes the older entries out.
        log.record(3, (0..GRAPH_LOG_NAMES).map(graph).collect());
        assert_eq!(log.since(0), None);
        assert_eq!(
            log.since(2),
            Some((0..GRAPH_LOG_NAMES).map(graph).collect())
        );
        log.record(4, vec![graph(7)]);
        assert_eq!(log.since(2), None, "generation 3 was pushed out too");
        assert_eq!(log.since(3), Some(BTreeSet::from([graph(7)])));
    }
}
