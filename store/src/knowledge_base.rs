//! The knowledge base: the environment as a live DyKnow ontology in an Oxigraph store.
//!
//! Every write goes through one lock and one Oxigraph transaction: a request is applied whole or
//! not at all, and concurrent writers never interleave (Oxigraph 0.5 does not detect all
//! write-write conflicts, so the service serialises them).
//!
//! The lock guards the [`Reasoner`] too: each write first updates the materialisation
//! (incrementally; from scratch when an ontology extension changes the schema), refuses the
//! request if it violates a consistency rule, and writes the change of the inferred graph in the
//! same Oxigraph write as the explicit change.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, RwLock};

use dyknow_ontology::BUILTIN_ONTOLOGIES;
use dyknow_ontology::vocab::{dyknow, owl, rdf, rdfs};
use oxigraph::model::{GraphNameRef, NamedNode, NamedNodeRef, NamedOrBlankNodeRef, Term, Triple};
use oxigraph::sparql::{QueryResults, SparqlEvaluator};
use oxigraph::store::{StorageError, Store};
use serde::Serialize;

use dyknow_reasoner::{Reasoner, TBox};

use crate::error::{IngestError, SpecValidationError, StoreOpenError, Violation};
use crate::export::INFERRED_GRAPH;
use crate::graphs::{
    environment_graph, extension_graph, fnv1a, is_environment_graph, is_extension_graph,
    spec_graph, spec_of_graph,
};
use crate::rdf_input::{InputFormat, fresh_blank_nodes, parse_triples};
use crate::spec::{ExtractedSpec, Spec, SpecClasses, SpecKind, extract_specs, spec_from_graph};

/// The knowledge base. Cheap to share behind an `Arc`; all methods take `&self`.
pub struct KnowledgeBase {
    store: Store,
    location: Option<PathBuf>,
    /// The write lock; it owns the reasoner, whose materialisation matches the store.
    write_lock: Mutex<Reasoner>,
    classes: RwLock<SpecClasses>,
    /// Bumped by every write that touches a graph other than the environment's (specs,
    /// extensions): lets readers cache what they derive from specs.
    spec_generation: std::sync::atomic::AtomicU64,
}

/// What a spec POST did.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct PostReport {
    /// The labels of the specs written, in document order.
    pub labels: Vec<String>,
    /// Those of them that replaced an existing spec.
    pub replaced: Vec<String>,
}

/// What an ontology extension POST did.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ExtensionReport {
    /// The named graph holding the extension.
    pub graph: String,
    /// Whether the same extension was there already (and was replaced).
    pub replaced: bool,
}

/// An ontology extension in the store.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ExtensionInfo {
    /// Its named graph.
    pub graph: String,
    /// The `owl:Ontology` it declares, if any.
    pub ontology: Option<String>,
    /// How many triples it holds.
    pub triples: usize,
}

/// What loading a mixed document did (offline `load`, `serve --specs`).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct LoadReport {
    /// Transformation specs written.
    pub transformations: PostReport,
    /// Target specs written.
    pub targets: PostReport,
    /// The extension graph written for the remaining triples, if any.
    pub extension: Option<String>,
}

/// Triples by the name of the graph that holds them.
type NamedSources = Vec<(String, Vec<Triple>)>;

/// From this many new triples on, a write is one SST ingestion rather than a write batch.
const BULK_LOAD_THRESHOLD: usize = 50_000;

/// Counts for monitoring.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct StoreStatistics {
    /// Quads in the store.
    pub quads: usize,
    /// Transformation specs.
    pub transformations: usize,
    /// Target specs.
    pub targets: usize,
    /// Ontology extensions.
    pub extensions: usize,
}

impl KnowledgeBase {
    /// Opens (or creates) the on-disk knowledge base in `path`.
    #[cfg(feature = "rocksdb")]
    pub fn open(path: impl AsRef<Path>) -> Result<Self, StoreOpenError> {
        let path = path.as_ref();
        std::fs::create_dir_all(path).map_err(|source| StoreOpenError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::with_store(Store::open(path)?, Some(path.to_path_buf()))
    }

    /// Opens the on-disk knowledge base in `path` read-only (e.g. to export while a server runs).
    #[cfg(feature = "rocksdb")]
    pub fn open_read_only(path: impl AsRef<Path>) -> Result<Self, StoreOpenError> {
        let path = path.as_ref();
        let store = Store::open_read_only(path)?;
        let kb = Self {
            store,
            location: Some(path.to_path_buf()),
            write_lock: Mutex::new(Reasoner::new(TBox::default())),
            classes: RwLock::new(SpecClasses::default()),
            spec_generation: std::sync::atomic::AtomicU64::new(0),
        };
        kb.refresh_classes()?;
        let reasoner = kb.materialise_at_open()?;
        *kb.lock() = reasoner;
        Ok(kb)
    }

    /// A knowledge base in memory (tests, demos, `--in-memory`).
    pub fn in_memory() -> Result<Self, StoreOpenError> {
        Self::with_store(Store::new()?, None)
    }

    fn with_store(store: Store, location: Option<PathBuf>) -> Result<Self, StoreOpenError> {
        let kb = Self {
            store,
            location,
            write_lock: Mutex::new(Reasoner::new(TBox::default())),
            classes: RwLock::new(SpecClasses::default()),
            spec_generation: std::sync::atomic::AtomicU64::new(0),
        };
        kb.install_builtin_ontologies()?;
        kb.refresh_classes()?;
        kb.install_materialisation()?;
        Ok(kb)
    }

    /// The underlying Oxigraph store (reads only: writes must go through the knowledge base).
    pub fn store(&self) -> &Store {
        &self.store
    }

    /// The directory of an on-disk knowledge base.
    pub fn location(&self) -> Option<&Path> {
        self.location.as_deref()
    }

    fn lock(&self) -> MutexGuard<'_, Reasoner> {
        // A panic while holding the lock cannot leave a half-written transaction (it is dropped,
        // i.e. rolled back), so the poison flag carries no information.
        self.write_lock
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// (Re)writes the built-in ontology graphs, so a new release's ontology replaces the old one.
    fn install_builtin_ontologies(&self) -> Result<(), StoreOpenError> {
        let _guard = self.lock();
        let mut transaction = self.store.start_transaction()?;
        for (iri, ttl) in BUILTIN_ONTOLOGIES {
            let triples = parse_triples(ttl.as_bytes(), InputFormat::Turtle)
                .map_err(|e| StoreOpenError::Ontology(format!("{iri}: {e}")))?;
            let graph = NamedNodeRef::new_unchecked(iri);
            transaction.clear_graph(graph)?;
            for t in &triples {
                transaction.insert(t.as_ref().in_graph(graph));
            }
        }
        transaction.commit()?;
        Ok(())
    }

    /// Recomputes the classes whose instances are spec roots (sub-classes may come from
    /// extensions).
    fn refresh_classes(&self) -> Result<(), StorageError> {
        let mut classes = SpecClasses::default();
        for (base, set) in [
            (dyknow::TRANSFORMATION, &mut classes.transformation),
            (dyknow::TARGET, &mut classes.target),
        ] {
            let query = format!(
                "SELECT DISTINCT ?c WHERE {{ ?c (<{sub}>|<{eq}>|^<{eq}>)* <{base}> FILTER(isIRI(?c)) }}",
                sub = rdfs::SUB_CLASS_OF.as_str(),
                eq = owl::EQUIVALENT_CLASS.as_str(),
                base = base.as_str()
            );
            let mut prepared = SparqlEvaluator::new()
                .parse_query(&query)
                .map_err(|e| StorageError::Other(Box::new(e)))?;
            prepared.dataset_mut().set_default_graph_as_union();
            let results = prepared
                .on_store(&self.store)
                .execute()
                .map_err(|e| StorageError::Other(Box::new(e)))?;
            if let QueryResults::Solutions(solutions) = results {
                for solution in solutions {
                    let solution = solution.map_err(|e| StorageError::Other(Box::new(e)))?;
                    if let Some(Term::NamedNode(c)) = solution.get("c") {
                        set.insert(c.clone());
                    }
                }
            }
        }
        *self
            .classes
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = classes;
        Ok(())
    }

    fn classes(&self) -> SpecClasses {
        self.classes
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// AddTransformation / AddTarget: writes the specs of `kind` in `body`, atomically. A spec
    /// whose label exists replaces it.
    pub fn post_specs(
        &self,
        body: &[u8],
        format: InputFormat,
        kind: SpecKind,
    ) -> Result<PostReport, IngestError> {
        let triples = parse_triples(body, format)?;
        let doc = extract_specs(&triples, &self.classes(), Some(kind))?;
        let mut reasoner = self.lock();
        self.check_identities(&doc.specs)?;
        let graphs: Vec<(&NamedNode, &[Triple])> = doc
            .specs
            .iter()
            .map(|s| (&s.graph, s.triples.as_slice()))
            .collect();
        let replaced = self.commit(&mut reasoner, &graphs, &[])?;
        Ok(PostReport {
            labels: doc
                .specs
                .iter()
                .map(|s| s.spec.label().to_owned())
                .collect(),
            replaced: doc
                .specs
                .iter()
                .zip(replaced)
                .filter(|(_, r)| *r)
                .map(|(s, _)| s.spec.label().to_owned())
                .collect(),
        })
    }

    /// Loads a document holding any mix of transformation specs, target specs and vocabulary
    /// (the latter becomes one ontology extension), atomically.
    pub fn load_document(
        &self,
        body: &[u8],
        format: InputFormat,
    ) -> Result<LoadReport, IngestError> {
        let triples = parse_triples(body, format)?;
        let doc = extract_specs(&triples, &self.classes(), None)?;
        let mut reasoner = self.lock();
        self.check_identities(&doc.specs)?;
        let extension = (!doc.rest.is_empty())
            .then(|| (extension_graph(fnv1a(body)), fresh_blank_nodes(&doc.rest)));
        let mut graphs: Vec<(&NamedNode, &[Triple])> = doc
            .specs
            .iter()
            .map(|s| (&s.graph, s.triples.as_slice()))
            .collect();
        if let Some((graph, triples)) = &extension {
            graphs.push((graph, triples.as_slice()));
        }
        let replaced = self.commit(&mut reasoner, &graphs, &[])?;
        let mut report = LoadReport {
            extension: extension.as_ref().map(|(g, _)| g.as_str().to_owned()),
            ..LoadReport::default()
        };
        for (spec, replaced) in doc.specs.iter().zip(replaced) {
            let part = match spec.spec.kind() {
                SpecKind::Transformation => &mut report.transformations,
                SpecKind::Target => &mut report.targets,
            };
            part.labels.push(spec.spec.label().to_owned());
            if replaced {
                part.replaced.push(spec.spec.label().to_owned());
            }
        }
        drop(reasoner);
        if report.extension.is_some() {
            self.refresh_classes()?;
        }
        Ok(report)
    }

    /// Replaces each graph of `writes` by its triples and removes the graphs of `removes`,
    /// atomically, with the matching change of the inferred graph; tells which graphs of
    /// `writes` existed. The caller holds the write lock (`reasoner`).
    ///
    /// The materialisation is updated incrementally, or recomputed when an ontology extension
    /// changes the schema. A request that violates a consistency rule the store did not violate
    /// already is refused (422) and nothing is written; the reasoner is left as it was.
    fn commit(
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

    fn commit_inner(
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
    fn write(
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
    fn schema_and_data(
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
    fn materialise(
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

    fn materialise_at_open(&self) -> Result<Reasoner, StoreOpenError> {
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
    fn install_materialisation(&self) -> Result<(), StoreOpenError> {
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

    /// Sets parts of the running environment (computation units with their subscriptions and
    /// publications; the reconfiguration engine and executors write them): each `(name,
    /// triples)` replaces the graph of that part, an empty list removes it. One atomic write,
    /// reasoned incrementally like a spec; a change that violates the ontology is refused (422)
    /// and nothing is written.
    pub fn set_environment(&self, parts: &[(String, Vec<Triple>)]) -> Result<(), IngestError> {
        let graphs: Vec<(NamedNode, &[Triple])> = parts
            .iter()
            .map(|(name, triples)| (environment_graph(name), triples.as_slice()))
            .collect();
        let mut reasoner = self.lock();
        let mut removes = Vec::new();
        for (g, triples) in &graphs {
            if triples.is_empty() && self.store.contains_named_graph(g)? {
                removes.push(g);
            }
        }
        let writes: Vec<(&NamedNode, &[Triple])> = graphs
            .iter()
            .filter(|(_, t)| !t.is_empty())
            .map(|(g, t)| (g, *t))
            .collect();
        self.commit(&mut reasoner, &writes, &removes)?;
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

    /// A spec given by IRI must not be the resource of another spec already.
    fn check_identities(&self, specs: &[ExtractedSpec]) -> Result<(), IngestError> {
        let mut violations = Vec::new();
        for spec in specs {
            let Some(iri) = &spec.given_iri else { continue };
            for quad in self.store.quads_for_pattern(
                Some(NamedOrBlankNodeRef::from(iri.as_ref())),
                Some(rdfs::LABEL),
                None,
                None,
            ) {
                let quad = quad?;
                let oxigraph::model::GraphName::NamedNode(g) = &quad.graph_name else {
                    continue;
                };
                if let Some((kind, label)) = spec_of_graph(g.as_str())
                    && (kind != spec.spec.kind() || label != spec.spec.label())
                {
                    violations.push(Violation::new(
                        format!(
                            "one resource describes one spec: <{}> is already the {} labelled {label:?}",
                            iri.as_str(),
                            kind.name()
                        ),
                        spec.spec.label(),
                    ));
                }
            }
        }
        if violations.is_empty() {
            Ok(())
        } else {
            Err(SpecValidationError(violations).into())
        }
    }

    /// RemoveTransformation / RemoveTarget.
    pub fn remove_spec(&self, kind: SpecKind, label: &str) -> Result<(), IngestError> {
        let graph = spec_graph(kind, label);
        let mut reasoner = self.lock();
        if !self.store.contains_named_graph(&graph)? {
            return Err(IngestError::NotFound(format!(
                "no {} labelled {label:?}",
                kind.name()
            )));
        }
        self.commit(&mut reasoner, &[], &[&graph])?;
        Ok(())
    }

    /// The triples of a named graph.
    pub fn graph_triples(&self, graph: NamedNodeRef<'_>) -> Result<Vec<Triple>, StorageError> {
        self.store
            .quads_for_pattern(None, None, None, Some(GraphNameRef::from(graph)))
            .map(|q| q.map(Triple::from))
            .collect()
    }

    /// The spec of `kind` labelled `label`.
    pub fn spec(&self, kind: SpecKind, label: &str) -> Result<Option<Spec>, StorageError> {
        let graph = spec_graph(kind, label);
        let triples = self.graph_triples(graph.as_ref())?;
        Ok(if triples.is_empty() {
            None
        } else {
            spec_from_graph(&triples, kind)
        })
    }

    /// The names of the graphs holding specs of `kind`, with their labels, sorted by label.
    pub fn spec_graphs(&self, kind: SpecKind) -> Result<Vec<(String, NamedNode)>, StorageError> {
        let mut out = BTreeMap::new();
        for graph in self.store.named_graphs() {
            if let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph?
                && let Some((k, label)) = spec_of_graph(g.as_str())
                && k == kind
            {
                out.insert(label, g);
            }
        }
        Ok(out.into_iter().collect())
    }

    /// All specs of `kind`, sorted by label.
    pub fn specs(&self, kind: SpecKind) -> Result<Vec<Spec>, StorageError> {
        let mut out = Vec::new();
        for (_, graph) in self.spec_graphs(kind)? {
            if let Some(spec) = spec_from_graph(&self.graph_triples(graph.as_ref())?, kind) {
                out.push(spec);
            }
        }
        Ok(out)
    }

    /// Posts an ontology extension (tag vocabularies, sub-concepts, `dyknow:similarTo`, domain
    /// classes). The graph is named after the body's content, so re-posting it replaces it.
    pub fn post_extension(
        &self,
        body: &[u8],
        format: InputFormat,
    ) -> Result<ExtensionReport, IngestError> {
        let triples = parse_triples(body, format)?;
        let doc = extract_specs(&triples, &self.classes(), None)?;
        if !doc.specs.is_empty() {
            let violations = doc
                .specs
                .iter()
                .map(|s| {
                    Violation::new(
                        format!(
                            "ontology extensions hold vocabularies; post {} specs to /{}s",
                            s.spec.kind().name(),
                            s.spec.kind().name()
                        ),
                        s.spec.label(),
                    )
                })
                .collect();
            return Err(SpecValidationError(violations).into());
        }
        if triples.is_empty() {
            return Err(SpecValidationError(vec![Violation::new(
                "an ontology extension has at least one statement",
                "the request body",
            )])
            .into());
        }
        let graph = extension_graph(fnv1a(body));
        let mut reasoner = self.lock();
        let triples = fresh_blank_nodes(&triples);
        let replaced = self.commit(&mut reasoner, &[(&graph, &triples)], &[])?[0];
        drop(reasoner);
        self.refresh_classes()?;
        Ok(ExtensionReport {
            graph: graph.into_string(),
            replaced,
        })
    }

    /// The ontology extensions, sorted by graph name.
    pub fn extensions(&self) -> Result<Vec<ExtensionInfo>, StorageError> {
        let mut out = Vec::new();
        for graph in self.store.named_graphs() {
            let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph? else {
                continue;
            };
            if !is_extension_graph(g.as_str()) {
                continue;
            }
            let triples = self.graph_triples(g.as_ref())?;
            let ontology = triples
                .iter()
                .find(|t| t.predicate == rdf::TYPE && t.object == Term::from(owl::ONTOLOGY))
                .map(|t| t.subject.to_string().trim_matches(['<', '>']).to_owned());
            out.push(ExtensionInfo {
                graph: g.into_string(),
                ontology,
                triples: triples.len(),
            });
        }
        out.sort_by(|a, b| a.graph.cmp(&b.graph));
        Ok(out)
    }

    /// Removes an ontology extension.
    pub fn remove_extension(&self, graph: &str) -> Result<(), IngestError> {
        if BUILTIN_ONTOLOGIES.iter().any(|(iri, _)| *iri == graph) {
            return Err(IngestError::Conflict(format!(
                "<{graph}> is a built-in ontology and cannot be removed"
            )));
        }
        if !is_extension_graph(graph) {
            return Err(IngestError::NotFound(format!(
                "<{graph}> is not an ontology extension"
            )));
        }
        let graph = NamedNode::new_unchecked(graph);
        let mut reasoner = self.lock();
        if !self.store.contains_named_graph(&graph)? {
            return Err(IngestError::NotFound(format!(
                "no ontology extension <{}>",
                graph.as_str()
            )));
        }
        self.commit(&mut reasoner, &[], &[&graph])?;
        drop(reasoner);
        self.refresh_classes()?;
        Ok(())
    }

    /// The channels named in the model, sorted, with the targets that name them.
    pub fn channels(&self) -> Result<Vec<(String, Vec<String>)>, StorageError> {
        let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
        for spec in self.specs(SpecKind::Target)? {
            if let Spec::Target(t) = spec {
                out.entry(t.channel).or_default().push(t.label);
            }
        }
        Ok(out.into_iter().collect())
    }

    /// The name of the computation unit that publishes on the channel named `channel`, if one
    /// does (a CU with a `dkros:hasPublication` whose `dkros:onChannel` has that name).
    pub fn channel_producer(&self, channel: &str) -> Result<Option<String>, StorageError> {
        let query = format!(
            "PREFIX dyknow: <{}> PREFIX dkros: <{}> \
             SELECT ?name WHERE {{ ?cu dkros:hasPublication ?p . ?p dkros:onChannel ?c . \
             ?c dyknow:hasChannelName {} . ?cu dyknow:hasName ?name }} ORDER BY ?name LIMIT 1",
            dyknow::NAMESPACE,
            dyknow_ontology::vocab::dkros::NAMESPACE,
            oxigraph::model::Literal::new_simple_literal(channel)
        );
        let mut prepared = SparqlEvaluator::new()
            .parse_query(&query)
            .map_err(|e| StorageError::Other(Box::new(e)))?;
        prepared.dataset_mut().set_default_graph_as_union();
        let results = prepared
            .on_store(&self.store)
            .execute()
            .map_err(|e| StorageError::Other(Box::new(e)))?;
        if let QueryResults::Solutions(mut solutions) = results
            && let Some(solution) = solutions.next()
        {
            let solution = solution.map_err(|e| StorageError::Other(Box::new(e)))?;
            if let Some(Term::Literal(name)) = solution.get("name") {
                return Ok(Some(name.value().to_owned()));
            }
        }
        Ok(None)
    }

    /// Counts for monitoring.
    pub fn statistics(&self) -> Result<StoreStatistics, StorageError> {
        let mut stats = StoreStatistics {
            quads: self.store.len()?,
            ..StoreStatistics::default()
        };
        for graph in self.store.named_graphs() {
            if let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph? {
                match spec_of_graph(g.as_str()) {
                    Some((SpecKind::Transformation, _)) => stats.transformations += 1,
                    Some((SpecKind::Target, _)) => stats.targets += 1,
                    None if is_extension_graph(g.as_str()) => stats.extensions += 1,
                    None => {}
                }
            }
        }
        Ok(stats)
    }

    /// Flushes buffered writes to disk (a no-op in memory).
    pub fn flush(&self) -> Result<(), StorageError> {
        #[cfg(feature = "rocksdb")]
        if self.location.is_some() {
            self.store.flush()?;
        }
        Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;
    use dyknow_ontology::vocab::dkros;

    const PREFIXES: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
@prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
@prefix owl: <http://www.w3.org/2002/07/owl#> .
@prefix ex: <http://example.org/ex#> .
";

    fn ttl(body: &str) -> Vec<u8> {
        format!("{PREFIXES}{body}").into_bytes()
    }

    fn kb() -> KnowledgeBase {
        KnowledgeBase::in_memory().expect("in memory")
    }

    fn ex(local: &str) -> NamedNode {
        NamedNode::new_unchecked(format!("http://example.org/ex#{local}"))
    }

    #[test]
    fn a_new_knowledge_base_holds_the_built_in_ontologies_and_nothing_else() {
        let kb = kb();
        assert_eq!(kb.location(), None);
        for (iri, _) in BUILTIN_ONTOLOGIES {
            let graph = NamedNodeRef::new_unchecked(iri);
            assert!(
                !kb.graph_triples(graph).expect("storage").is_empty(),
                "{iri}"
            );
        }
        let stats = kb.statistics().expect("storage");
        assert_eq!(
            (stats.transformations, stats.targets, stats.extensions),
            (0, 0, 0)
        );
        assert!(stats.quads > 100, "{stats:?}");
        // The built-in ontologies, and the inferred graph with their schema closure (e.g. scm-rng1:
        // the range of hasInPort is InPort, so it is Port too).
        assert_eq!(
            kb.store().named_graphs().count(),
            BUILTIN_ONTOLOGIES.len() + 1
        );
        let inferred = kb
            .graph_triples(NamedNodeRef::new_unchecked(INFERRED_GRAPH))
            .expect("storage");
        assert!(inferred.contains(&Triple::new(
            dyknow::HAS_IN_PORT,
            oxigraph::model::vocab::rdfs::RANGE,
            dyknow::PORT
        )));
        kb.flush().expect("a no-op in memory");
        // Re-installing the ontologies (as on every open) does not duplicate them.
        let before = kb.store().len().expect("storage");
        kb.install_builtin_ontologies().expect("install");
        assert_eq!(kb.store().len().expect("storage"), before);
    }

    #[test]
    fn the_spec_classes_come_from_the_ontology() {
        let kb = kb();
        let classes = kb.classes();
        for c in [
            dyknow::TRANSFORMATION,
            dyknow::SOURCE,
            dyknow::SINK,
            dkros::ROS_TRANSFORMATION,
        ] {
            assert!(classes.transformation.contains(&c.into_owned()), "{c}");
        }
        for c in [dyknow::TARGET, dkros::ROS_TARGET] {
            assert!(classes.target.contains(&c.into_owned()), "{c}");
        }
        assert!(
            !classes
                .transformation
                .contains(&dyknow::IN_PORT.into_owned())
        );
        assert!(
            !classes
                .transformation
                .contains(&dyknow::TARGET.into_owned())
        );
        assert!(
            !classes
                .target
                .contains(&dyknow::TRANSFORMATION.into_owned())
        );
    }

    #[test]
    fn extensions_add_spec_classes_through_sub_class_and_equivalence() {
        let kb = kb();
        let report = kb
            .post_extension(
                &ttl("ex:Camera rdfs:subClassOf ex:Sensor . ex:Sensor rdfs:subClassOf dkros:ROSTransformation .
                      ex:Job owl:equivalentClass dyknow:Transformation .
                      ex:Query rdfs:subClassOf dyknow:Target .
                      ex:Unrelated rdfs:subClassOf ex:Sensorless ."),
                InputFormat::Turtle,
            )
            .expect("valid extension");
        let classes = kb.classes();
        for c in ["Camera", "Sensor", "Job"] {
            assert!(classes.transformation.contains(&ex(c)), "{c}");
        }
        assert!(classes.target.contains(&ex("Query")));
        assert!(!classes.transformation.contains(&ex("Unrelated")));
        assert!(!classes.target.contains(&ex("Camera")));

        kb.remove_extension(&report.graph).expect("present");
        let classes = kb.classes();
        assert!(!classes.transformation.contains(&ex("Camera")));
        assert!(!classes.target.contains(&ex("Query")));
        assert!(
            classes
                .transformation
                .contains(&dkros::ROS_TRANSFORMATION.into_owned())
        );
    }

    /// `owl:equivalentClass` is symmetric: `dyknow:Transformation owl:equivalentClass ex:Job`
    /// says the same as `ex:Job owl:equivalentClass dyknow:Transformation`, but the class query
    /// in `refresh_classes` follows the property one way only.
    #[test]
    fn equivalence_is_symmetric() {
        let kb = kb();
        kb.post_extension(
            &ttl("dyknow:Transformation owl:equivalentClass ex:Job ."),
            InputFormat::Turtle,
        )
        .expect("valid extension");
        assert!(kb.classes().transformation.contains(&ex("Job")));
    }

    #[test]
    fn load_document_refreshes_the_classes_of_its_vocabulary() {
        let kb = kb();
        let report = kb
            .load_document(
                &ttl("ex:Camera rdfs:subClassOf dyknow:Transformation ."),
                InputFormat::Turtle,
            )
            .expect("vocabulary only");
        assert!(report.extension.is_some());
        assert!(report.transformations.labels.is_empty());
        assert!(kb.classes().transformation.contains(&ex("Camera")));
    }

    #[test]
    fn identities_are_checked_against_the_stored_specs() {
        let kb = kb();
        let spec = |label: &str, class: &str| {
            ttl(&format!(
                "ex:thing a {class} ; rdfs:label \"{label}\" ;
                   dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"X\" ] ] ;
                   dyknow:hasChannel [ dyknow:hasChannelName \"/c\" ] ; dyknow:hasTag [ dyknow:hasValue \"X\" ] ."
            ))
        };
        let extracted = |body: &[u8]| {
            let triples = parse_triples(body, InputFormat::Turtle).expect("Turtle");
            extract_specs(&triples, &kb.classes(), None)
                .expect("valid")
                .specs
        };
        let first = extracted(&spec("a", "dyknow:Transformation"));
        assert_eq!(first[0].given_iri, Some(ex("thing")));
        kb.check_identities(&first).expect("nothing stored yet");
        kb.post_specs(
            &spec("a", "dyknow:Transformation"),
            InputFormat::Turtle,
            SpecKind::Transformation,
        )
        .expect("valid");
        kb.check_identities(&first)
            .expect("the same spec may be re-posted");
        let other_label = extracted(&spec("b", "dyknow:Transformation"));
        let Err(IngestError::Invalid(SpecValidationError(v))) = kb.check_identities(&other_label)
        else {
            panic!("another label on the same IRI")
        };
        assert_eq!(v.len(), 1);
        assert!(
            v[0].constraint.contains(
                "<http://example.org/ex#thing> is already the transformation labelled \"a\""
            ),
            "{v:?}"
        );
        assert_eq!(v[0].subject, "b");
        let other_kind = extracted(&spec("a", "dyknow:Target"));
        assert!(matches!(
            kb.check_identities(&other_kind),
            Err(IngestError::Invalid(_))
        ));
    }

    #[test]
    fn write_graphs_reports_replacements_and_replaces() {
        let kb = kb();
        let body = ttl(
            "[] a dyknow:Transformation ; rdfs:label \"a\" ;
            dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"X\" ] ] .",
        );
        let triples = parse_triples(&body, InputFormat::Turtle).expect("Turtle");
        let specs = extract_specs(&triples, &kb.classes(), None)
            .expect("valid")
            .specs;
        let graphs: Vec<(&NamedNode, &[Triple])> = specs
            .iter()
            .map(|s| (&s.graph, s.triples.as_slice()))
            .collect();
        let inferred = NamedNodeRef::new_unchecked(INFERRED_GRAPH);
        let mut reasoner = kb.lock();
        assert_eq!(
            kb.commit(&mut reasoner, &graphs, &[]).expect("write"),
            [false]
        );
        let first = kb.graph_triples(inferred).expect("storage");
        assert_eq!(
            kb.commit(&mut reasoner, &graphs, &[]).expect("write"),
            [true]
        );
        let graph = spec_graph(SpecKind::Transformation, "a");
        assert_eq!(
            kb.graph_triples(graph.as_ref()).expect("storage").len(),
            specs[0].triples.len()
        );
        // The inferred graph holds what the spec entails (the port's inverse link) once.
        let port = NamedNode::new_unchecked("urn:dyknow:transformation:a/port/o");
        let resource = NamedNode::new_unchecked("urn:dyknow:transformation:a");
        let is_out_port = Triple::new(port, dyknow::IS_OUT_PORT, resource);
        assert!(first.contains(&is_out_port), "{first:?}");
        assert_eq!(kb.graph_triples(inferred).expect("storage"), first);
        // Removing the graph removes its inferences.
        kb.commit(&mut reasoner, &[], &[&graph]).expect("remove");
        assert!(
            !kb.graph_triples(inferred)
                .expect("storage")
                .contains(&is_out_port)
        );
    }

    #[test]
    fn extension_graphs_are_named_by_the_hash_of_the_body() {
        let kb = kb();
        let body = ttl("ex:A dyknow:similarTo ex:B .");
        let report = kb
            .post_extension(&body, InputFormat::Turtle)
            .expect("valid");
        assert_eq!(report.graph, extension_graph(fnv1a(&body)).into_string());
        let info = kb.extensions().expect("storage");
        assert_eq!(
            info,
            [ExtensionInfo {
                graph: report.graph.clone(),
                ontology: None,
                triples: 1
            }]
        );
        assert!(matches!(
            kb.remove_extension("urn:dyknow:graph:transformation:a"),
            Err(IngestError::NotFound(_))
        ));
    }
}
