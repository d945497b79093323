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

//! Layout by concern: this file opens the store (on disk or in memory) and installs the
//! built-in ontologies; `write` is the reasoned write path (validation, the incremental
//! materialisation, one atomic Oxigraph write); `specs` and `extensions` are the writes and
//! reads of specs and of ontology extensions; `environment` writes the parts of the running
//! environment and answers the channel queries of the model.

mod environment;
mod extensions;
mod specs;
mod write;

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, RwLock};

use dyknow_ontology::BUILTIN_ONTOLOGIES;
use dyknow_reasoner::{Reasoner, TBox};
use oxigraph::model::{NamedNodeRef, Quad};
use oxigraph::store::{StorageError, Store};
use serde::Serialize;

use crate::error::StoreOpenError;
use crate::graphs::{is_extension_graph, renamed_environment_graph, spec_of_graph};
use crate::rdf_input::{InputFormat, parse_triples};
use crate::spec::{SpecClasses, SpecKind};

pub use extensions::{ExtensionInfo, ExtensionReport};
pub use specs::{LoadReport, PostReport};

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
    /// Which graphs each recent bump of `spec_generation` was for: lets readers patch what
    /// they derive from specs instead of deriving it again ([`KnowledgeBase::spec_changes_since`]).
    spec_log: Mutex<write::GraphLog>,
    /// Bumped by every write that touches an environment graph (CUs, change sets,
    /// statistics): lets readers cache what they derive from the environment.
    environment_generation: std::sync::atomic::AtomicU64,
    /// Which environment graphs each recent bump of `environment_generation` was for: lets
    /// readers of the CUs read again only those written
    /// ([`KnowledgeBase::environment_changes_since`]).
    environment_log: Mutex<write::GraphLog>,
    /// RocksDB's memtables, bounded: see [`KnowledgeBase::flush_if_due`].
    flusher: write::Flusher,
}

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
            spec_log: Mutex::default(),
            environment_generation: std::sync::atomic::AtomicU64::new(0),
            environment_log: Mutex::default(),
            flusher: write::Flusher::default(),
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

    pub(super) fn with_store(
        store: Store,
        location: Option<PathBuf>,
    ) -> Result<Self, StoreOpenError> {
        let kb = Self {
            store,
            location,
            write_lock: Mutex::new(Reasoner::new(TBox::default())),
            classes: RwLock::new(SpecClasses::default()),
            spec_generation: std::sync::atomic::AtomicU64::new(0),
            spec_log: Mutex::default(),
            environment_generation: std::sync::atomic::AtomicU64::new(0),
            environment_log: Mutex::default(),
            flusher: write::Flusher::default(),
        };
        kb.install_builtin_ontologies()?;
        kb.migrate_environment_graph_names()?;
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

    pub(super) fn lock(&self) -> MutexGuard<'_, Reasoner> {
        // A panic while holding the lock cannot leave a half-written transaction (it is dropped,
        // i.e. rolled back), so the poison flag carries no information.
        self.write_lock
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// (Re)writes the built-in ontology graphs, so a new release's ontology replaces the old one.
    pub(super) fn install_builtin_ontologies(&self) -> Result<(), StoreOpenError> {
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

    /// Whether the store takes writes now: one transaction that adds a statement to the
    /// default graph (which holds nothing of the model) and removes it again, so it changes
    /// nothing readers can see, but goes through the write-ahead log like any write. After a
    /// write of the storage failed (a full disk), RocksDB refuses every later write until the
    /// store is opened again, even once space is back: this finds it (`GET /health`). It does
    /// not take the write lock.
    pub fn probe_write(&self) -> Result<(), StorageError> {
        let probe = NamedNodeRef::new_unchecked("urn:dyknow:health");
        let quad = oxigraph::model::QuadRef::new(
            probe,
            probe,
            probe,
            oxigraph::model::GraphNameRef::DefaultGraph,
        );
        let mut transaction = self.store.start_transaction()?;
        transaction.insert(quad);
        transaction.remove(quad);
        transaction.commit()
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

    /// Renames the environment graphs of earlier releases to the current layout
    /// ([`renamed_environment_graph`]), in one transaction, before anything reads them.
    pub(super) fn migrate_environment_graph_names(&self) -> Result<(), StorageError> {
        let mut renames = Vec::new();
        for graph in self.store.named_graphs() {
            if let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph?
                && let Some(new) = renamed_environment_graph(g.as_str())
            {
                renames.push((g, new));
            }
        }
        if renames.is_empty() {
            return Ok(());
        }
        let mut transaction = self.store.start_transaction()?;
        for (old, new) in &renames {
            let quads: Vec<Quad> = transaction
                .quads_for_pattern(None, None, None, Some(old.as_ref().into()))
                .collect::<Result<_, _>>()?;
            for q in quads {
                transaction.insert(oxigraph::model::QuadRef::new(
                    &q.subject,
                    &q.predicate,
                    &q.object,
                    new,
                ));
            }
            transaction.remove_named_graph(old)?;
        }
        transaction.commit()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::{IngestError, SpecValidationError};
    use crate::export::INFERRED_GRAPH;
    use crate::graphs::{extension_graph, graph_hash, spec_graph};
    use crate::spec::extract_specs;
    use dyknow_ontology::vocab::{dkros, dyknow};
    use oxigraph::model::{NamedNode, Triple};
    use std::collections::BTreeSet;

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
    fn environment_graphs_of_earlier_releases_are_renamed_at_open() {
        // A store as an earlier release left it: a CU and a change-set record under names
        // with the colon percent-encoded.
        let store = Store::new().expect("store");
        let name = |s: &str| oxigraph::model::Literal::new_simple_literal(s);
        let cu = NamedNode::new_unchecked("urn:dyknow:cu:cu-1");
        let cs = NamedNode::new_unchecked("urn:dyknow:changeset:cs-1");
        let old_cu = NamedNode::new_unchecked("urn:dyknow:graph:environment:cu%3Acu-1");
        let old_cs = NamedNode::new_unchecked("urn:dyknow:graph:environment:changeset%3Acs-1");
        for (s, o, g) in [(&cu, name("cu-1"), &old_cu), (&cs, name("cs-1"), &old_cs)] {
            store
                .insert(oxigraph::model::QuadRef::new(s, dyknow::HAS_NAME, &o, g))
                .expect("insert");
        }
        let kb = KnowledgeBase::with_store(store, None).expect("open");
        for (old, new, subject, value) in [
            (
                &old_cu,
                crate::EnvironmentPart::Cu("cu-1".into()),
                &cu,
                "cu-1",
            ),
            (
                &old_cs,
                crate::EnvironmentPart::ChangeSet("cs-1".into()),
                &cs,
                "cs-1",
            ),
        ] {
            assert!(!kb.store().contains_named_graph(old).expect("storage"));
            assert_eq!(
                kb.graph_triples(new.graph().as_ref()).expect("storage"),
                [Triple::new(subject.clone(), dyknow::HAS_NAME, name(value))]
            );
        }
        // Nothing left to rename: a second pass changes nothing.
        let before = kb.store().len().expect("storage");
        kb.migrate_environment_graph_names().expect("migrate");
        assert_eq!(kb.store().len().expect("storage"), before);
    }

    /// The ontologies are read as one document with two headers, and horned-owl maps one of
    /// them, whichever it meets first: the other's version IRI is a header triple, not an
    /// axiom left out. It was counted as unsupported in about one store in two.
    #[test]
    fn the_unsupported_axioms_are_the_same_in_every_new_store() {
        let counts: BTreeSet<usize> = (0..12)
            .map(|_| {
                let unsupported = kb().unsupported_axioms();
                assert!(
                    !unsupported.iter().any(|a| a.contains("no axiom")),
                    "{unsupported:#?}"
                );
                unsupported.len()
            })
            .collect();
        assert_eq!(counts.len(), 1, "{counts:?}");
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
        // The same vocabulary beside a spec, then beside the spec edited: the vocabulary stays
        // one extension (it was named after the whole document's bytes, so each edit of a spec
        // added a copy of it).
        let with_spec = |tag: &str| {
            ttl(&format!(
                "ex:Camera rdfs:subClassOf dyknow:Transformation .
                 ex:cam a ex:Camera ; rdfs:label \"cam\" ;
                   dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"{tag}\" ] ] ."
            ))
        };
        for tag in ["Image", "Frame"] {
            let loaded = kb
                .load_document(&with_spec(tag), InputFormat::Turtle)
                .expect("a spec and its vocabulary");
            assert_eq!(loaded.extension, report.extension, "{tag}");
            assert_eq!(kb.extensions().expect("storage").len(), 1, "{tag}");
        }
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

        // A spec given another label's minted IRI, or any other of the service's own, or a
        // built-in term, is refused; its own minted IRI is taken (an export loads back).
        let named = |iri: &str, label: &str| {
            extracted(
                format!(
                    "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
                     @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
                     {iri} a dyknow:Transformation ; rdfs:label \"{label}\" ;
                       dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"X\" ] ] ."
                )
                .as_bytes(),
            )
        };
        let refused = |specs: &[crate::spec::ExtractedSpec], why: &str| {
            let Err(IngestError::Invalid(SpecValidationError(v))) = kb.check_identities(specs)
            else {
                panic!("{why}: taken")
            };
            v[0].constraint.clone()
        };
        for iri in [
            "<urn:dyknow:transformation:zz>",
            "<urn:dyknow:cu:cu-1>",
            "<urn:dyknow:changeset:cs-1>",
        ] {
            let why = refused(&named(iri, "yy"), iri);
            assert!(why.contains("urn:dyknow:transformation:yy"), "{why}");
        }
        for iri in ["dyknow:Transformation", "rdfs:label"] {
            let why = refused(&named(iri, "yy"), iri);
            assert!(why.contains("built-in vocabulary"), "{why}");
        }
        kb.check_identities(&named("<urn:dyknow:transformation:yy>", "yy"))
            .expect("its own minted IRI");
        kb.post_specs(
            b"@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
              @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
              <urn:dyknow:transformation:zz> a dyknow:Transformation ; rdfs:label \"zz\" ;
                dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"X\" ] ] .",
            InputFormat::Turtle,
            SpecKind::Transformation,
        )
        .expect("zz at its own IRI");
        let mut again = named("<urn:dyknow:transformation:zz>", "zz");
        again[0].given_iri = None;
        kb.check_identities(&again)
            .expect("the same spec, as a blank node");
        // A document that moves "a" off ex:thing and gives ex:thing to "c": consistent once
        // written, so taken; "c" alone at ex:thing is not.
        let mut moved = named("<http://example.org/ex#elsewhere>", "a");
        moved.extend(named("<http://example.org/ex#thing>", "c"));
        kb.check_identities(&moved)
            .expect("a rename in one document");
        refused(&moved[1..], "ex:thing is a's");
        let both = extracted(
            b"@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
              @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
              <urn:dyknow:transformation:q> a dyknow:Transformation ; rdfs:label \"q\" ;
                dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"X\" ] ] .
              [] a dyknow:Transformation ; rdfs:label \"r\" ;
                dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"X\" ] ] .",
        );
        kb.check_identities(&both).expect("two resources");
    }

    #[test]
    fn a_refused_spec_writes_nothing_of_its_document() {
        let kb = kb();
        let doc = ttl(
            "[] a dyknow:Target ; rdfs:label \"mine\" ;
               dyknow:hasChannel [ dyknow:hasChannelName \"/a\" ] ; dyknow:hasTag [ dyknow:hasValue \"X\" ] .
             [] a dyknow:Target ; rdfs:label \"reserved:b\" ;
               dyknow:hasChannel [ dyknow:hasChannelName \"/b\" ] ; dyknow:hasTag [ dyknow:hasValue \"X\" ] .",
        );
        let refuse = |s: &crate::spec::Spec| {
            s.label()
                .starts_with("reserved:")
                .then(|| "reserved".to_owned())
        };
        let before = kb.store.len().expect("len");
        let Err(IngestError::Invalid(SpecValidationError(v))) =
            kb.post_specs_checked(&doc, InputFormat::Turtle, SpecKind::Target, &refuse)
        else {
            panic!("refused")
        };
        assert_eq!(
            v.iter()
                .map(|v| (v.constraint.as_str(), v.subject.as_str()))
                .collect::<Vec<_>>(),
            [("reserved", "reserved:b")]
        );
        assert_eq!(kb.store.len().expect("len"), before);
        let report = kb
            .post_specs_checked(&doc, InputFormat::Turtle, SpecKind::Target, &|_| None)
            .expect("nothing refused");
        assert_eq!(report.labels, ["mine", "reserved:b"]);
    }

    /// A service that keeps writing small environment parts flushes its memtables every
    /// [`write::FLUSH_AFTER_QUADS`] quads (in the background), and loses nothing by it.
    #[cfg(feature = "rocksdb")]
    #[test]
    fn many_small_writes_flush_the_memtables_and_lose_nothing() {
        use crate::graphs::EnvironmentPart;
        let dir = tempfile::tempdir().expect("temporary directory");
        let kb = KnowledgeBase::open(dir.path()).expect("open");
        assert_eq!(kb.flushes_started(), 0);
        let parts = 2 * write::FLUSH_AFTER_QUADS / 100 + 1;
        for i in 0..parts {
            let triples: Vec<Triple> = (0..100)
                .map(|k| {
                    Triple::new(
                        ex(&format!("cu{i}")),
                        ex("p"),
                        oxigraph::model::Literal::from(k),
                    )
                })
                .collect();
            kb.set_environment(&[(EnvironmentPart::Cu(format!("cu-{i}").into()), triples)])
                .expect("write");
        }
        assert!(
            kb.flushes_started() >= 1,
            "{} flushes",
            kb.flushes_started()
        );
        drop(kb);
        let kb = KnowledgeBase::open(dir.path()).expect("reopen");
        for i in [0, parts - 1] {
            let g = EnvironmentPart::Cu(format!("cu-{i}").into()).graph();
            assert_eq!(kb.graph_triples(g.as_ref()).expect("read").len(), 100);
        }
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
    fn extension_graphs_are_named_by_the_hash_of_their_statements() {
        let kb = kb();
        let body = ttl("ex:A dyknow:similarTo ex:B .");
        let report = kb
            .post_extension(&body, InputFormat::Turtle)
            .expect("valid");
        let triples = crate::rdf_input::parse_triples(&body, InputFormat::Turtle).expect("valid");
        assert_eq!(
            report.graph,
            extension_graph(graph_hash(&triples)).into_string()
        );
        assert!(!report.replaced);
        // The same statement written otherwise (a comment, other prefixes and layout, said
        // twice) is the same extension: posting it replaces it (a user audit got a second one).
        let again = kb
            .post_extension(
                b"# edited\n@prefix e: <http://example.org/ex#> .\n\
                  e:A <http://www.dyknow.eu/ontology/dyknow#similarTo> e:B , e:B .",
                InputFormat::Turtle,
            )
            .expect("valid");
        assert_eq!(
            (again.graph.as_str(), again.replaced),
            (report.graph.as_str(), true)
        );
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
