//! Seed Chapter 6: Piff's seven-CU pipeline (`specs/environments/ch6-piff-cus.ttl`). Every CU
//! `dependsOn` exactly the CUs upstream of it; removing the segmenter removes exactly the
//! `dependsOn` triples that ran through it.
#![expect(clippy::expect_used, reason = "tests")]

use std::collections::BTreeSet;

use dyknow_reasoner::{Reasoner, TBox, builtin_ontology_triples};
use oxrdf::{NamedNode, NamedOrBlankNode, Term, Triple};

const DEPENDS_ON: &str = "http://www.dyknow.eu/ontology/dyknow#dependsOn";

fn cu(i: u32) -> String {
    format!("urn:dyknow:example:piff:cu{i}")
}

fn environment() -> Vec<Triple> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../specs/environments/ch6-piff-cus.ttl"
    );
    let data = std::fs::read(path).expect("the Piff environment");
    oxttl::TurtleParser::new()
        .for_slice(&data)
        .map(|t| t.expect("valid Turtle"))
        .collect()
}

fn depends_on(reasoner: &Reasoner) -> BTreeSet<(String, String)> {
    let predicate = NamedNode::new_unchecked(DEPENDS_ON);
    (1..=7)
        .flat_map(|i| {
            reasoner
                .objects(
                    &Term::NamedNode(NamedNode::new_unchecked(cu(i))),
                    &predicate,
                )
                .into_iter()
                .map(move |o| (cu(i), o.to_string().trim_matches(['<', '>']).to_owned()))
        })
        .collect()
}

fn expected(upstream: &[(u32, &[u32])]) -> BTreeSet<(String, String)> {
    upstream
        .iter()
        .flat_map(|(c, ups)| ups.iter().map(move |u| (cu(*c), cu(*u))))
        .collect()
}

#[test]
fn every_cu_depends_on_exactly_its_upstream_cus() {
    let mut reasoner = Reasoner::new(TBox::from_triples(&builtin_ontology_triples()).unwrap());
    let env = environment();
    let update = reasoner.update(&[], &env);
    assert!(update.violations.is_empty(), "{:?}", update.violations);
    assert_eq!(
        depends_on(&reasoner),
        expected(&[
            (1, &[]),
            (2, &[]),
            (3, &[2]),
            (4, &[3, 2]),
            (5, &[4, 3, 2]),
            (6, &[5, 4, 3, 2, 1]),
            (7, &[6, 5, 4, 3, 2, 1]),
        ])
    );

    // Remove the segmenter (cu4): its own triples and the subscription of cu5 from it.
    let segmenter = [
        cu(4),
        "urn:dyknow:example:piff:s4".into(),
        "urn:dyknow:example:piff:s5hull".into(),
    ];
    let removed: Vec<Triple> = env
        .iter()
        .filter(|t| {
            let s = match &t.subject {
                NamedOrBlankNode::NamedNode(n) => n.as_str(),
                NamedOrBlankNode::BlankNode(_) => "",
            };
            let o = match &t.object {
                Term::NamedNode(n) => n.as_str(),
                _ => "",
            };
            segmenter.iter().any(|x| x == s || x == o)
        })
        .cloned()
        .collect();
    let before = depends_on(&reasoner);
    let update = reasoner.update(&removed, &[]);
    let after = depends_on(&reasoner);
    let gone: BTreeSet<(String, String)> = before.difference(&after).cloned().collect();
    // Exactly the dependencies that ran through cu4: cu4's own, and those on cu4.
    assert_eq!(
        gone,
        expected(&[(4, &[3, 2]), (5, &[4]), (6, &[4]), (7, &[4])])
    );
    assert!(after.is_subset(&before));
    let reported: BTreeSet<(String, String)> = update
        .inferred_removed
        .iter()
        .filter(|t| t.predicate.as_str() == DEPENDS_ON)
        .map(|t| {
            (
                t.subject.to_string().trim_matches(['<', '>']).to_owned(),
                t.object.to_string().trim_matches(['<', '>']).to_owned(),
            )
        })
        .collect();
    assert_eq!(reported, gone);
    assert!(
        update
            .inferred_added
            .iter()
            .all(|t| t.predicate.as_str() != DEPENDS_ON)
    );
}

/// prp-fp on a functional data property: two literals of one value are one value, not a
/// violation (a user audit got one for `"1"^^xsd:integer` and `"1.0"^^xsd:decimal`); two
/// values are.
#[test]
fn a_functional_data_property_is_violated_by_two_values_not_two_spellings() {
    let turtle = |body: &str| -> Vec<Triple> {
        let text = format!(
            "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
             @prefix xsd: <http://www.w3.org/2001/XMLSchema#> .
             @prefix ex: <http://example.org/> .
             {body}"
        );
        oxttl::TurtleParser::new()
            .for_slice(text.as_bytes())
            .map(|t| t.expect("valid Turtle"))
            .collect()
    };
    let violations = |body: &str| {
        let mut reasoner =
            Reasoner::new(TBox::from_triples(&builtin_ontology_triples()).expect("the TBox"));
        reasoner.update(&[], &turtle(body)).violations
    };
    for same in [
        r#"ex:w dyknow:hasValue "1"^^xsd:integer, "1.0"^^xsd:decimal ."#,
        r#"ex:w dyknow:hasValue "1"^^xsd:integer, "01"^^xsd:integer ."#,
        r#"ex:w dyknow:hasValue "-0.50"^^xsd:decimal, "-.5"^^xsd:decimal ."#,
        r#"ex:w dyknow:hasValue "1E0"^^xsd:double, "1.0"^^xsd:double ."#,
        r#"ex:w dyknow:hasValue "a", "a"^^xsd:string ."#,
        r#"ex:w dyknow:hasValue "true"^^xsd:boolean, "1"^^xsd:boolean ."#,
        r#"ex:w dyknow:hasValue "0.1"^^xsd:float, "0.100000001"^^xsd:float ."#,
    ] {
        assert!(
            violations(same).is_empty(),
            "{same}: {:?}",
            violations(same)
        );
    }
    for different in [
        r#"ex:w dyknow:hasValue "1"^^xsd:integer, "2"^^xsd:integer ."#,
        r#"ex:w dyknow:hasValue "1"^^xsd:integer, "1"^^xsd:double ."#,
        r#"ex:w dyknow:hasValue "a", "b" ."#,
        r#"ex:w dyknow:hasValue "0"^^xsd:decimal, "0.01"^^xsd:decimal ."#,
    ] {
        let found = violations(different);
        assert!(
            found.iter().any(|v| v.rule == "prp-fp"),
            "{different}: {found:?}"
        );
    }
}

/// `A owl:disjointWith B` and `B owl:disjointWith A` state one constraint (OWL's
/// `DisjointClasses` is a set): an individual in both classes is one violation, not two (a user
/// audit found it reported once per direction). Likewise for disjoint properties, including
/// one stated against the other's inverse. Two different pairs stay two violations.
#[test]
fn a_disjointness_stated_both_ways_is_violated_once() {
    let triples = |text: &str| -> Vec<Triple> {
        oxttl::TurtleParser::new()
            .for_slice(
                format!(
                    "@prefix owl: <http://www.w3.org/2002/07/owl#> .
                     @prefix ex: <http://example.org/> .
                     ex:A a owl:Class . ex:B a owl:Class . ex:C a owl:Class .
                     ex:p a owl:ObjectProperty . ex:q a owl:ObjectProperty .
                     ex:r a owl:ObjectProperty . ex:s a owl:ObjectProperty .
                     {text}"
                )
                .as_bytes(),
            )
            .map(|t| t.expect("valid Turtle"))
            .collect()
    };
    let schema = triples(
        "ex:A owl:disjointWith ex:B . ex:B owl:disjointWith ex:A . ex:C owl:disjointWith ex:A .
         ex:p owl:propertyDisjointWith ex:q . ex:q owl:propertyDisjointWith ex:p .
         ex:r owl:propertyDisjointWith [ owl:inverseOf ex:s ] .
         ex:s owl:propertyDisjointWith [ owl:inverseOf ex:r ] .",
    );
    let mut all = builtin_ontology_triples();
    all.extend(schema);
    let mut reasoner = Reasoner::new(TBox::from_triples(&all).expect("the TBox"));
    let found = reasoner
        .update(
            &[],
            &triples("ex:x a ex:A, ex:B . ex:x ex:p ex:y ; ex:q ex:y . ex:u ex:r ex:v . ex:v ex:s ex:u ."),
        )
        .violations;
    let mut rules: Vec<&str> = found.iter().map(|v| v.rule).collect();
    rules.sort_unstable();
    assert_eq!(rules, ["cax-dw", "prp-pdw", "prp-pdw"], "{found:?}");
    let found = reasoner
        .update(&[], &triples("ex:z a ex:A, ex:B, ex:C ."))
        .violations;
    assert_eq!(
        found.iter().filter(|v| v.rule == "cax-dw").count(),
        2,
        "A–B and A–C: {found:?}"
    );
}
