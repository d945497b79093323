//! Differential property test: after every random batch of additions and removals, the
//! incrementally maintained materialisation equals a from-scratch materialisation of the same
//! explicit triples (and so do the violations).
#![expect(clippy::unwrap_used, reason = "tests")]

use std::collections::{BTreeMap, BTreeSet};

use dyknow_reasoner::{Reasoner, TBox, builtin_ontology_triples};
use oxrdf::{Literal, NamedNode, Term, Triple};
use proptest::prelude::*;

const DK: &str = "http://www.dyknow.eu/ontology/dyknow#";
const EX: &str = "http://example.org/test#";

fn dk(l: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{DK}{l}"))
}
fn ex(l: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{EX}{l}"))
}

/// The built-in ontologies plus an extension exercising what DyKnow's own ontology does not:
/// a chain of length 3 with an inverse link, sub-properties, an equivalence cycle of classes,
/// an existential on the left, a range, an asymmetric property, and transitive properties fed
/// by other rules (a symmetric one, sub-properties, an inverse, a chain `w ∘ w ⊑ w`), whose
/// closures the engine maintains apart from the other rules.
fn tbox() -> TBox {
    let extension = format!(
        "@prefix ex: <{EX}> . @prefix dyknow: <{DK}> .
         @prefix owl: <http://www.w3.org/2002/07/owl#> .
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
         ex:r a owl:ObjectProperty ; owl:propertyChainAxiom ( dyknow:dependsOn [ owl:inverseOf ex:q ] dyknow:dependsOn ) .
         ex:q a owl:ObjectProperty ; rdfs:subPropertyOf ex:r ; rdfs:range ex:B .
         ex:A a owl:Class ; rdfs:subClassOf ex:B . ex:B a owl:Class ; rdfs:subClassOf ex:A .
         ex:C a owl:Class ; owl:equivalentClass [ a owl:Restriction ; owl:onProperty ex:q ; owl:someValuesFrom ex:A ] .
         ex:t a owl:ObjectProperty , owl:TransitiveProperty , owl:AsymmetricProperty ; rdfs:domain ex:C .
         ex:u a owl:ObjectProperty , owl:TransitiveProperty , owl:SymmetricProperty ; owl:inverseOf ex:w .
         ex:v a owl:ObjectProperty ; rdfs:subPropertyOf ex:t , ex:u .
         ex:w a owl:ObjectProperty ; owl:propertyChainAxiom ( ex:w ex:w ) .
         "
    );
    let mut triples = builtin_ontology_triples();
    triples.extend(
        oxttl::TurtleParser::new()
            .for_slice(extension.as_bytes())
            .map(Result::unwrap),
    );
    TBox::from_triples(&triples).unwrap()
}

/// The pool of triples batches draw from: over 6 nodes, every property and class above.
fn pool() -> Vec<Triple> {
    let nodes: Vec<NamedNode> = (0..6).map(|i| ex(&format!("n{i}"))).collect();
    let props = [
        dk("hasSubscription"),
        dk("fromCU"),
        dk("toCU"),
        dk("dependsOn"),
        dk("similarTo"),
        dk("hasInPort"),
        dk("isOutPort"),
        ex("q"),
        ex("t"),
        ex("v"),
        ex("w"),
    ];
    let classes = [
        dk("Source"),
        dk("InPort"),
        dk("OutPort"),
        dk("Transformation"),
        ex("A"),
        ex("C"),
    ];
    let mut out = Vec::new();
    for s in &nodes {
        for p in &props {
            for o in &nodes {
                out.push(Triple::new(s.clone(), p.clone(), o.clone()));
            }
        }
        for c in &classes {
            out.push(Triple::new(s.clone(), oxrdf::vocab::rdf::TYPE, c.clone()));
        }
        for v in ["a", "b"] {
            out.push(Triple::new(
                s.clone(),
                dk("hasValue"),
                Term::from(Literal::new_simple_literal(v)),
            ));
        }
    }
    out
}

#[derive(Debug, Clone)]
enum Op {
    Add(usize),
    Remove(usize),
}

fn batches() -> impl Strategy<Value = Vec<Vec<Op>>> {
    let n: usize = 6 * (11 * 6 + 6 + 2);
    let op = prop_oneof![
        3 => (0..n).prop_map(Op::Add),
        2 => (0..n).prop_map(Op::Remove),
    ];
    prop::collection::vec(prop::collection::vec(op, 1..12), 1..10)
}

fn violations(r: &Reasoner) -> BTreeSet<String> {
    r.violations().iter().map(ToString::to_string).collect()
}

proptest! {
    // 512 cases by default; `PROPTEST_CASES=N` runs more (a soak run before a release).
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|n| n.parse().ok()).unwrap_or(512),
        ..ProptestConfig::default()
    })]

    #[test]
    fn incremental_equals_from_scratch(batches in batches()) {
        let tbox = tbox();
        let pool = pool();
        let mut incremental = Reasoner::new(tbox.clone());
        let mut explicit: BTreeMap<usize, u32> = BTreeMap::new();
        let mut graph: BTreeSet<String> = incremental.inferred().iter().map(ToString::to_string).collect();
        for batch in batches {
            // `update` removes first (what is asserted), then adds: model it the same way.
            let (mut removed, mut added) = (Vec::new(), Vec::new());
            for op in &batch {
                if let Op::Remove(i) = op
                    && let Some(n) = explicit.get_mut(i)
                {
                    *n -= 1;
                    if *n == 0 {
                        explicit.remove(i);
                    }
                    removed.push(pool[*i].clone());
                }
            }
            for op in &batch {
                if let Op::Add(i) = op {
                    *explicit.entry(*i).or_insert(0) += 1;
                    added.push(pool[*i].clone());
                }
            }
            let update = incremental.update(&removed, &added);
            // The update applied to the previous inferred graph gives the new one.
            for t in &update.inferred_removed {
                prop_assert!(graph.remove(&t.to_string()), "removed {t} was not inferred");
            }
            for t in &update.inferred_added {
                prop_assert!(graph.insert(t.to_string()), "added {t} was inferred already");
            }
            let mut scratch = Reasoner::new(tbox.clone());
            let all: Vec<Triple> = explicit
                .iter()
                .flat_map(|(i, n)| std::iter::repeat_n(pool[*i].clone(), *n as usize))
                .collect();
            scratch.update(&[], &all);
            let expected: BTreeSet<String> = scratch.inferred().iter().map(ToString::to_string).collect();
            let actual: BTreeSet<String> = incremental.inferred().iter().map(ToString::to_string).collect();
            prop_assert_eq!(&actual, &expected);
            prop_assert_eq!(&graph, &expected);
            prop_assert_eq!(violations(&incremental), violations(&scratch));
            // Terms no explicit triple uses any more are released: the dictionary holds what a
            // fresh reasoner of the same triples holds, whatever the history.
            prop_assert_eq!(incremental.terms(), scratch.terms());
        }
    }
}

/// The case CI's run of the property test found (seed in `differential.proptest-regressions`):
/// a closure fact that DRed over-deletes and re-derives by prp-trp alone must not become a base
/// fact, or it outlives the base facts it came from.
#[test]
fn closure_fact_rederived_by_transitivity_is_not_a_base_fact() {
    let t = |s: &str, p: NamedNode, o: &str| Triple::new(ex(s), p, ex(o));
    let mut incremental = Reasoner::new(tbox());
    incremental.update(&[], &[t("n2", ex("v"), "n1")]);
    incremental.update(&[], &[t("n5", ex("t"), "n2"), t("n1", ex("t"), "n5")]);
    incremental.update(&[t("n1", ex("t"), "n5")], &[]);
    incremental.update(&[t("n5", ex("t"), "n2")], &[]);
    let mut scratch = Reasoner::new(tbox());
    scratch.update(&[], &[t("n2", ex("v"), "n1")]);
    assert!(!incremental.entails(&t("n5", ex("t"), "n1")));
    assert_eq!(incremental.inferred(), scratch.inferred());
}
