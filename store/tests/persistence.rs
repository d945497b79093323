//! The on-disk knowledge base (RocksDB): specs, extensions and the spec classes they declare
//! survive a restart, and a read-only instance sees them.
#![cfg(feature = "rocksdb")]
// Helpers outside `#[test]` functions are test code too.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeSet;
use std::path::Path;

use dyknow_store::oxigraph::model::{NamedOrBlankNode, Term, Triple};
use dyknow_store::spec::{Spec, SpecKind};
use dyknow_store::{IngestError, InputFormat, KnowledgeBase, StoreOpenError};

const LISTING_5_3: &str = include_str!("../../specs/turtle/listing-5.3-undistort.ttl");
const LISTING_5_4: &str = include_str!("../../specs/turtle/listing-5.4-target.ttl");
const EXAMPLE_12: &str = include_str!("../../specs/turtle/example-12.ttl");
const EXAMPLE_12_SIMILARITY: &str = include_str!("../../specs/turtle/example-12-similarity.ttl");

const CAMERA_CLASS: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
@prefix ex: <http://example.org/ex#> .
ex:Camera rdfs:subClassOf dyknow:Transformation .
";

fn camera(label: &str) -> String {
    format!(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
@prefix ex: <http://example.org/ex#> .
[] a ex:Camera ; rdfs:label \"{label}\" ;
   dyknow:hasOutPort [ dyknow:hasName \"image\" ; dyknow:hasTag [ dyknow:hasValue \"rgb\" ] ] .
"
    )
}

fn open_rw(path: &Path) -> Result<KnowledgeBase, StoreOpenError> {
    KnowledgeBase::open(path)
}

fn open_ro(path: &Path) -> Result<KnowledgeBase, StoreOpenError> {
    KnowledgeBase::open_read_only(path)
}

fn labels(kb: &KnowledgeBase, kind: SpecKind) -> Vec<String> {
    kb.specs(kind)
        .expect("storage")
        .iter()
        .map(|s| s.label().to_owned())
        .collect()
}

/// The model's triples without blank nodes (the built-in ontologies' blank nodes are renamed
/// each time they are installed).
fn ground(kb: &KnowledgeBase) -> BTreeSet<String> {
    kb.model_triples(true)
        .expect("storage")
        .iter()
        .filter(|t: &&Triple| {
            !matches!(t.subject, NamedOrBlankNode::BlankNode(_))
                && !matches!(t.object, Term::BlankNode(_))
        })
        .map(ToString::to_string)
        .collect()
}

fn post(kb: &KnowledgeBase, body: &str, kind: SpecKind) {
    kb.post_specs(body.as_bytes(), InputFormat::Turtle, kind)
        .unwrap_or_else(|e| panic!("post failed: {e}"));
}

#[test]
fn specs_and_extensions_survive_a_restart() {
    let dir = tempfile::tempdir().expect("temporary directory");
    // A directory that does not exist yet: open creates it.
    let path = dir.path().join("kb");

    let (undistort, target, extensions, model, model_len) = {
        let kb = open_rw(&path).expect("open");
        assert_eq!(kb.location(), Some(path.as_path()));
        post(&kb, LISTING_5_3, SpecKind::Transformation);
        post(&kb, EXAMPLE_12, SpecKind::Transformation);
        post(&kb, LISTING_5_4, SpecKind::Target);
        kb.post_extension(EXAMPLE_12_SIMILARITY.as_bytes(), InputFormat::Turtle)
            .expect("extension");
        kb.post_extension(CAMERA_CLASS.as_bytes(), InputFormat::Turtle)
            .expect("class extension");
        post(&kb, &camera("cam"), SpecKind::Transformation);
        // A rejected request writes nothing, on disk either.
        let bad = LISTING_5_3.replace(
            "dyknow:UpkeepCostModel ; dyknow:hasValue 1.0",
            "dyknow:UpkeepCostModel ; dyknow:hasValue -1.0",
        );
        assert_ne!(bad, LISTING_5_3);
        assert!(matches!(
            kb.post_specs(
                format!("{bad}\n{}", camera("never")).as_bytes(),
                InputFormat::Turtle,
                SpecKind::Transformation
            ),
            Err(IngestError::Invalid(_))
        ));
        kb.flush().expect("flush");

        // Only one read-write instance at a time.
        assert!(
            open_rw(&path).is_err(),
            "the directory is locked while open"
        );

        let undistort = kb
            .spec(SpecKind::Transformation, "Undistort(cam1)")
            .expect("storage")
            .expect("present");
        let target = kb
            .spec(SpecKind::Target, "undistortSub")
            .expect("storage")
            .expect("present");
        let model = ground(&kb);
        let model_len = kb.model_triples(true).expect("storage").len();
        (
            undistort,
            target,
            kb.extensions().expect("storage"),
            model,
            model_len,
        )
    };
    assert_eq!(extensions.len(), 2);
    let Spec::Transformation(t) = &undistort else {
        panic!("a transformation")
    };
    assert_eq!(t.inputs.len(), 1);
    assert_eq!(t.source.as_deref(), Some("package/Undistort"));

    // Reopen read-write: everything is there, and the extension's class is a spec class again.
    {
        let kb = open_rw(&path).expect("reopen");
        assert_eq!(
            labels(&kb, SpecKind::Transformation),
            [
                "Undistort(cam1)",
                "cam",
                "tid1",
                "tid2",
                "tid3",
                "tid4",
                "tid5"
            ]
        );
        assert_eq!(labels(&kb, SpecKind::Target), ["undistortSub"]);
        assert!(
            kb.spec(SpecKind::Transformation, "never")
                .expect("storage")
                .is_none()
        );
        assert_eq!(
            kb.spec(SpecKind::Transformation, "Undistort(cam1)")
                .expect("storage"),
            Some(undistort.clone())
        );
        assert_eq!(
            kb.spec(SpecKind::Target, "undistortSub").expect("storage"),
            Some(target.clone())
        );
        assert_eq!(kb.extensions().expect("storage"), extensions);
        assert_eq!(ground(&kb), model);
        assert_eq!(
            kb.model_triples(true).expect("storage").len(),
            model_len,
            "re-installing the built-in ontologies does not duplicate them"
        );
        let stats = kb.statistics().expect("storage");
        assert_eq!(
            (stats.transformations, stats.targets, stats.extensions),
            (7, 1, 2)
        );

        post(&kb, &camera("cam2"), SpecKind::Transformation);
        kb.remove_spec(SpecKind::Transformation, "tid5")
            .expect("present");
        kb.flush().expect("flush");
    }

    // Read-only: sees the second session's writes, refuses writes.
    {
        let kb = open_ro(&path).expect("open read-only");
        assert_eq!(kb.location(), Some(path.as_path()));
        assert_eq!(
            labels(&kb, SpecKind::Transformation),
            [
                "Undistort(cam1)",
                "cam",
                "cam2",
                "tid1",
                "tid2",
                "tid3",
                "tid4"
            ]
        );
        assert_eq!(
            kb.spec(SpecKind::Target, "undistortSub").expect("storage"),
            Some(target)
        );
        assert_eq!(
            kb.spec(SpecKind::Transformation, "Undistort(cam1)")
                .expect("storage"),
            Some(undistort)
        );
        assert_eq!(kb.extensions().expect("storage"), extensions);
        let answer = kb
            .run_query(
                dyknow_store::ParsedQuery::parse(
                    "SELECT ?t WHERE { ?t <http://www.w3.org/2000/01/rdf-schema#label> \"cam2\" }",
                )
                .expect("parses"),
                dyknow_store::ResultFormat::Results(
                    dyknow_store::oxigraph::sparql::results::QueryResultsFormat::Csv,
                ),
                std::time::Duration::from_secs(10),
            )
            .expect("runs");
        assert_eq!(
            String::from_utf8(answer.body).expect("UTF-8"),
            "t\r\nurn:dyknow:transformation:cam2\r\n"
        );
        assert!(matches!(
            kb.post_specs(
                camera("ro").as_bytes(),
                InputFormat::Turtle,
                SpecKind::Transformation
            ),
            Err(IngestError::Storage(_))
        ));
        assert!(
            kb.spec(SpecKind::Transformation, "ro")
                .expect("storage")
                .is_none()
        );
    }
}

#[test]
fn read_only_opening_of_a_missing_store_fails() {
    let dir = tempfile::tempdir().expect("temporary directory");
    assert!(open_ro(&dir.path().join("absent")).is_err());
}

/// The inferred graph survives a restart unchanged, and a store whose inferred graph was lost or
/// is stale (an older release) is corrected at open.
#[test]
fn the_inferred_graph_survives_a_restart_and_is_repaired_at_open() {
    use dyknow_store::INFERRED_GRAPH;
    use dyknow_store::oxigraph::model::NamedNodeRef;
    let dir = tempfile::tempdir().expect("tempdir");
    let inferred = NamedNodeRef::new_unchecked(INFERRED_GRAPH);
    let expected = {
        let kb = open_rw(dir.path()).expect("open");
        kb.post_specs(
            LISTING_5_3.as_bytes(),
            InputFormat::Turtle,
            SpecKind::Transformation,
        )
        .expect("post");
        let triples: BTreeSet<String> = kb
            .graph_triples(inferred)
            .expect("storage")
            .iter()
            .map(ToString::to_string)
            .collect();
        assert!(
            triples.iter().any(|t| t.contains("dyknow#isOutPort")),
            "{triples:?}"
        );
        // Damage the inferred graph behind the knowledge base's back.
        kb.store().clear_graph(inferred).expect("clear");
        kb.flush().expect("flush");
        triples
    };
    let kb = open_rw(dir.path()).expect("reopen");
    let repaired: BTreeSet<String> = kb
        .graph_triples(inferred)
        .expect("storage")
        .iter()
        .map(ToString::to_string)
        .collect();
    assert_eq!(repaired, expected);
    assert!(kb.violations().is_empty());
}
