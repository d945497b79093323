//! The reasoned write path: every write is validated, reasoned incrementally (from scratch
//! when an ontology extension changes the schema) and applied as one atomic Oxigraph write
//! under the write lock, which owns the reasoner.

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
        if writes
            .iter()
            .map(|(g, _)| *g)
            .chain(removes.iter().copied())
            .any(|g| !is_environment_graph(g.as_str()))
        {
            self.spec_generation
                .fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        }
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
            }
            return Ok(());
        }
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

    /// A number that changes whenever a spec, an extension or an ontology graph is written or
    /// removed (not for environment graphs): what is derived from specs alone may be cached
    /// against it.
    pub fn spec_generation(&self) -> u64 {
        self.spec_generation
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
fn inconsistency(violations: &[dyknow_reasoner::Violation]) -> IngestError {
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
