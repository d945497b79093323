//! End-to-end: the example specs through the HTTP API, GetModel round trips.

use std::collections::HashSet;

use dyknow_acceptance::{Api, EXAMPLE_SPECS, specs_dir};
use dyknow_ontology::{OwlSyntax, read_owl};
use horned_owl::model::Component;
use sophia::api::parser::TripleParser;
use sophia::api::source::TripleSource;
use sophia::inmem::graph::LightGraph;
use sophia::isomorphism::isomorphic_graphs;
use sophia::turtle::parser::{nt::NTriplesParser, turtle::TurtleParser};

#[tokio::test]
async fn every_example_spec_loads_through_the_api() {
    // Every file of specs/turtle is covered by the table.
    let mut files: Vec<String> = std::fs::read_dir(specs_dir())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".ttl"))
        .collect();
    files.sort();
    let mut covered: Vec<String> = EXAMPLE_SPECS.iter().map(|(f, _)| (*f).to_owned()).collect();
    covered.sort();
    assert_eq!(files, covered);

    let api = Api::new();
    api.load_examples().await;
    let list = api.get("/transformations").await.expect(200).json();
    // Listing 5.3 (1) + Example 12 (5) + Piff (7) + Puff (7) + ceiling (10) + live (2).
    assert_eq!(list.as_array().unwrap().len(), 32);
    let targets = api.get("/targets").await.expect(200).json();
    let labels: Vec<&str> = targets
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["label"].as_str().unwrap())
        .collect();
    assert_eq!(
        labels,
        ["greetings", "qid1", "qid2", "target1", "undistortSub"]
    );
}

#[expect(clippy::expect_used, reason = "test helper")]
fn turtle_graph(text: &str) -> LightGraph {
    TurtleParser::new()
        .parse_str(text)
        .collect_triples()
        .expect("valid Turtle")
}

#[expect(clippy::expect_used, reason = "test helper")]
fn nt_graph(text: &str) -> LightGraph {
    NTriplesParser::new()
        .parse_str(text)
        .collect_triples()
        .expect("valid N-Triples")
}

#[tokio::test]
async fn model_turtle_reimported_into_an_empty_store_is_isomorphic() {
    let api = Api::new();
    api.load_examples().await;
    let answer = api.get("/model?format=turtle").await;
    answer.expect(200);
    assert_eq!(answer.media_type(), "text/turtle");
    let turtle = answer.text();

    // Re-import into an empty Oxigraph store and dump it again.
    let store = dyknow_store::oxigraph::store::Store::new().unwrap();
    store
        .load_from_slice(
            dyknow_store::oxigraph::io::RdfFormat::Turtle,
            turtle.as_bytes(),
        )
        .unwrap();
    let mut dumped = Vec::new();
    store
        .dump_graph_to_writer(
            dyknow_store::oxigraph::model::GraphNameRef::DefaultGraph,
            dyknow_store::oxigraph::io::RdfFormat::NTriples,
            &mut dumped,
        )
        .unwrap();
    let original = turtle_graph(&turtle);
    let reimported = nt_graph(&String::from_utf8(dumped).unwrap());
    assert!(isomorphic_graphs(&original, &reimported).unwrap());

    // And the N-Triples export is the same graph.
    let nt = api.get("/model?format=ntriples").await.expect(200).text();
    assert!(isomorphic_graphs(&original, &nt_graph(&nt)).unwrap());

    // A graph that lost one triple is not isomorphic (the check can fail).
    let lines: Vec<&str> = nt.lines().collect();
    let truncated = lines[1..].join("\n");
    assert!(!isomorphic_graphs(&original, &nt_graph(&truncated)).unwrap());
}

/// The logical content of an OWL document: everything but ontology headers and annotations.
fn axioms(
    components: HashSet<horned_owl::model::AnnotatedComponent<horned_owl::model::ArcStr>>,
) -> HashSet<horned_owl::model::AnnotatedComponent<horned_owl::model::ArcStr>> {
    components
        .into_iter()
        .filter(|c| {
            !matches!(
                c.component,
                Component::OntologyID(_)
                    | Component::DocIRI(_)
                    | Component::Import(_)
                    | Component::OntologyAnnotation(_)
            )
        })
        .collect()
}

type Components = HashSet<horned_owl::model::AnnotatedComponent<horned_owl::model::ArcStr>>;

fn assert_same(a: &Components, b: &Components, an: &str, bn: &str) {
    let only_a: Vec<_> = a.difference(b).take(5).collect();
    let only_b: Vec<_> = b.difference(a).take(5).collect();
    assert!(
        only_a.is_empty() && only_b.is_empty(),
        "{} only in {an}, {} only in {bn}; e.g. only in {an}: {only_a:#?}\nonly in {bn}: {only_b:#?}",
        a.difference(b).count(),
        b.difference(a).count()
    );
}

#[tokio::test]
async fn owl_exports_read_back_into_the_same_axioms() {
    let api = Api::new();
    api.load_examples().await;
    let answer = api.get_accept("/model", "text/owl-functional").await;
    answer.expect(200);
    assert_eq!(answer.media_type(), "text/owl-functional");
    let ofn = answer.text();
    let answer = api.get("/model?format=owx").await;
    answer.expect(200);
    assert_eq!(answer.media_type(), "application/owl+xml");
    let from_ofn = axioms(read_owl(&ofn, OwlSyntax::Functional).unwrap());
    let from_owx = axioms(read_owl(&answer.text(), OwlSyntax::OwlXml).unwrap());
    assert_same(&from_ofn, &from_owx, "OFN", "OWX");

    // The same axioms horned-owl reads from the RDF form of the model.
    let nt = api.get("/model?format=ntriples").await.expect(200).text();
    // The RDF form keeps both built-in ontology headers; the OWL export declares one ontology,
    // so the second header's own annotations are the one expected difference.
    let from_rdf: Components = axioms(
        dyknow_ontology::rdf_owl_components(
            nt.as_bytes(),
            dyknow_store::oxigraph::io::RdfFormat::NTriples,
        )
        .unwrap(),
    )
    .into_iter()
    .filter(|c| {
        !matches!(&c.component, Component::AnnotationAssertion(a)
            if matches!(&a.subject, horned_owl::model::AnnotationSubject::IRI(iri)
                if iri.as_ref() == dyknow_ontology::DYKNOW_ROS_ONTOLOGY_IRI
                    || iri.as_ref() == dyknow_ontology::DYKNOW_ONTOLOGY_IRI))
    })
    .collect();
    assert_same(&from_ofn, &from_rdf, "OFN", "RDF");

    // The core's characteristic axioms and the environment's facts are there.
    assert!(
        ofn.contains("TransitiveObjectProperty(dyknow:dependsOn)"),
        "{ofn:.2000}"
    );
    assert!(ofn.contains("ObjectPropertyChain(dyknow:hasSubscription dyknow:fromCU)"));
    assert!(ofn.contains(
        "ClassAssertion(dkros:ROSTransformation <urn:dyknow:transformation:Undistort%28cam1%29>)"
    ));
}
