//! The built-in ontologies are complete OWL (every triple has an OWL reading), round-trip through
//! both OWL syntaxes, and say what the seed says.

use std::collections::HashSet;

use dyknow_ontology::{
    BUILTIN_ONTOLOGIES, DYKNOW_ROS_TTL, DYKNOW_TTL, OwlSyntax, rdf_owl_components, rdf_to_owl,
    read_owl,
};
use horned_owl::model::{AnnotatedComponent, ArcStr, Component};
use oxrdfio::RdfFormat;

#[expect(clippy::unwrap_used, reason = "test helper")]
fn components(ttl: &str) -> HashSet<AnnotatedComponent<ArcStr>> {
    rdf_owl_components(ttl.as_bytes(), RdfFormat::Turtle).unwrap()
}

#[test]
fn every_triple_has_an_owl_reading() {
    for (iri, ttl) in BUILTIN_ONTOLOGIES {
        for syntax in [OwlSyntax::Functional, OwlSyntax::OwlXml] {
            let doc = rdf_to_owl(ttl.as_bytes(), RdfFormat::Turtle, syntax).unwrap();
            assert_eq!(
                doc.unparsed_triples, 0,
                "{iri}: triples without an OWL reading"
            );
        }
    }
}

#[test]
fn both_owl_syntaxes_round_trip_to_the_same_components() {
    for (iri, ttl) in BUILTIN_ONTOLOGIES {
        let from_rdf = components(ttl);
        assert!(
            from_rdf.len() > 50,
            "{iri}: only {} components",
            from_rdf.len()
        );
        for syntax in [OwlSyntax::Functional, OwlSyntax::OwlXml] {
            let text = rdf_to_owl(ttl.as_bytes(), RdfFormat::Turtle, syntax)
                .unwrap()
                .text;
            let back = read_owl(&text, syntax).unwrap();
            let missing: Vec<_> = from_rdf.difference(&back).collect();
            let extra: Vec<_> = back.difference(&from_rdf).collect();
            assert!(
                missing.is_empty() && extra.is_empty(),
                "{iri} through {syntax:?}: missing {missing:#?}, extra {extra:#?}"
            );
        }
    }
}

#[test]
fn the_core_says_what_the_seed_says() {
    let ofn = rdf_to_owl(
        DYKNOW_TTL.as_bytes(),
        RdfFormat::Turtle,
        OwlSyntax::Functional,
    )
    .unwrap()
    .text;
    for axiom in [
        // (4.63) dependsOn ⊑ hasSubscription ∘ fromCU, transitive.
        "SubObjectPropertyOf(ObjectPropertyChain(dyknow:hasSubscription dyknow:fromCU) dyknow:dependsOn)",
        "TransitiveObjectProperty(dyknow:dependsOn)",
        // Appendix A characteristics and disjointness.
        "FunctionalObjectProperty(dyknow:toCU)",
        "FunctionalObjectProperty(dyknow:fromCU)",
        "DisjointObjectProperties(dyknow:fromCU dyknow:toCU)",
        "DisjointClasses(dyknow:InPort dyknow:OutPort)",
        "IrreflexiveObjectProperty(dyknow:nextState)",
        "InverseObjectProperties(dyknow:hasInPort dyknow:isInPort)",
        "FunctionalDataProperty(dyknow:hasValue)",
        // Source ⊑ hasInPort exactly 0 InPort; Sink likewise.
        "SubClassOf(dyknow:Source ObjectExactCardinality(0 dyknow:hasInPort dyknow:InPort))",
        "SubClassOf(dyknow:Sink ObjectExactCardinality(0 dyknow:hasOutPort dyknow:OutPort))",
        // This project's addition.
        "SymmetricObjectProperty(dyknow:similarTo)",
    ] {
        assert!(ofn.contains(axiom), "missing {axiom}");
    }
    // hasCostModel is deliberately not functional (docs/ontology.md).
    assert!(!ofn.contains("FunctionalObjectProperty(dyknow:hasCostModel)"));
}

#[test]
fn dyknow_ros_extends_the_core() {
    let ofn = rdf_to_owl(
        DYKNOW_ROS_TTL.as_bytes(),
        RdfFormat::Turtle,
        OwlSyntax::Functional,
    )
    .unwrap()
    .text;
    for axiom in [
        "SubClassOf(dkros:ROSTransformation dyknow:Transformation)",
        "SubObjectPropertyOf(dyknow:hasInPort dkros:hasPort)",
        "SubObjectPropertyOf(dyknow:hasOutPort dkros:hasPort)",
        "SubClassOf(dkros:Topic dyknow:Channel)",
        "SubClassOf(dkros:ROSTarget dyknow:Target)",
        "SubClassOf(dkros:Nodelet dyknow:ComputationUnit)",
        "FunctionalDataProperty(dkros:hasIndex)",
    ] {
        assert!(ofn.contains(axiom), "missing {axiom}");
    }
    let imports = components(DYKNOW_ROS_TTL)
        .into_iter()
        .filter(|c| matches!(&c.component, Component::Import(i) if i.0.as_ref() == dyknow_ontology::DYKNOW_ONTOLOGY_IRI))
        .count();
    assert_eq!(imports, 1);
}

#[test]
fn the_ontologies_use_only_declared_vocabulary() {
    // Every dyknow:/dkros: IRI used in either file is declared in one of them.
    let all: String = BUILTIN_ONTOLOGIES.iter().map(|(_, t)| *t).collect();
    let declared: HashSet<String> = BUILTIN_ONTOLOGIES
        .iter()
        .flat_map(|(_, ttl)| components(ttl))
        .filter_map(|c| match c.component {
            Component::DeclareClass(d) => Some(d.0.0.to_string()),
            Component::DeclareObjectProperty(d) => Some(d.0.0.to_string()),
            Component::DeclareDataProperty(d) => Some(d.0.0.to_string()),
            Component::DeclareAnnotationProperty(d) => Some(d.0.0.to_string()),
            _ => None,
        })
        .collect();
    for (prefix, ns) in [
        ("dyknow:", dyknow_ontology::vocab::dyknow::NAMESPACE),
        ("dkros:", dyknow_ontology::vocab::dkros::NAMESPACE),
    ] {
        for word in
            all.split(|c: char| c.is_whitespace() || c == ';' || c == ',' || c == '(' || c == ')')
        {
            if let Some(local) = word.strip_prefix(prefix) {
                let local = local.trim_end_matches(|c: char| !c.is_alphanumeric());
                if !local.is_empty() {
                    assert!(
                        declared.contains(&format!("{ns}{local}")),
                        "{prefix}{local} is not declared"
                    );
                }
            }
        }
    }
}

/// OWL/XML keeps prefixed names out of `IRI` attributes (they belong in `abbreviatedIRI`): a
/// conforming reader takes `IRI="dyknow:ChangeSet"` for an IRI of scheme `dyknow`.
#[test]
fn owl_xml_iri_attributes_hold_full_iris() {
    for (iri, ttl) in BUILTIN_ONTOLOGIES {
        let text = rdf_to_owl(ttl.as_bytes(), RdfFormat::Turtle, OwlSyntax::OwlXml)
            .unwrap()
            .text;
        let values: Vec<&str> = text
            .split(" IRI=\"")
            .skip(1)
            .filter_map(|rest| rest.split('"').next())
            .collect();
        assert!(values.len() > 50, "{iri}: only {} IRIs", values.len());
        for value in values {
            assert!(
                value.starts_with("http://") || value.starts_with("https://"),
                "{iri}: IRI={value:?} is not a full IRI"
            );
        }
    }
}
