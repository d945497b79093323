//! The patched candidate table (issue 18) against the one global SPARQL query: after random
//! sequences of spec posts, replacements and deletes and of ontology extensions posted and
//! removed (sub-concepts, `dyknow:similarTo`), a [`SpecCache`] kept across the sequence gives
//! the same table, library, targets and IRIs as deriving everything from scratch, and the same
//! table as [`model::candidates`] (the reference, [`queries::CANDIDATES`]).
#![expect(clippy::unwrap_used, reason = "tests")]

use dyknow_store::model::{self, SpecCache};
use dyknow_store::spec::SpecKind;
use dyknow_store::{InputFormat, KnowledgeBase};
use proptest::prelude::*;

const PREFIXES: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
    @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n\
    @prefix ex: <http://example.org/ex#> .\n";

/// A tag: a value, a description, or both.
#[derive(Debug, Clone)]
struct TagSpec {
    value: Option<u8>,
    description: Option<u8>,
}

impl TagSpec {
    fn turtle(&self) -> String {
        let mut out = "[ a dyknow:Tag".to_owned();
        if let Some(v) = self.value {
            out.push_str(&format!(" ; dyknow:hasValue \"v{v}\""));
        }
        if let Some(d) = self.description {
            out.push_str(&format!(" ; dyknow:hasTagDescription ex:D{d}"));
        }
        out.push_str(" ]");
        out
    }
}

#[derive(Debug, Clone)]
enum Op {
    Transformation {
        label: u8,
        inputs: Vec<Vec<TagSpec>>,
        outputs: Vec<Vec<TagSpec>>,
    },
    Target {
        label: u8,
        tags: Vec<TagSpec>,
    },
    Remove {
        kind: SpecKind,
        label: u8,
    },
    /// Statements `(a, similar, b)`: `ex:Da dyknow:similarTo ex:Db` or `ex:Da rdfs:subClassOf
    /// ex:Db`.
    Extension(Vec<(u8, bool, u8)>),
    /// Removes the extension posted `n` extensions ago (modulo how many there are).
    RemoveExtension(usize),
}

fn tag() -> impl Strategy<Value = TagSpec> {
    prop_oneof![
        (0u8..4).prop_map(|v| TagSpec {
            value: Some(v),
            description: None
        }),
        (0u8..6).prop_map(|d| TagSpec {
            value: None,
            description: Some(d)
        }),
        (0u8..4, 0u8..6).prop_map(|(v, d)| TagSpec {
            value: Some(v),
            description: Some(d)
        }),
    ]
}

fn tags() -> impl Strategy<Value = Vec<TagSpec>> {
    prop::collection::vec(tag(), 1..3)
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        4 => (0u8..7, prop::collection::vec(tags(), 0..3), prop::collection::vec(tags(), 1..3))
            .prop_map(|(label, inputs, outputs)| Op::Transformation { label, inputs, outputs }),
        2 => (0u8..3, tags()).prop_map(|(label, tags)| Op::Target { label, tags }),
        2 => (prop_oneof![Just(SpecKind::Transformation), Just(SpecKind::Target)], 0u8..7)
            .prop_map(|(kind, label)| Op::Remove { kind, label }),
        2 => prop::collection::vec((0u8..6, any::<bool>(), 0u8..6), 1..4).prop_map(Op::Extension),
        1 => (0usize..4).prop_map(Op::RemoveExtension),
    ]
}

fn ports(direction: &str, ports: &[Vec<TagSpec>]) -> String {
    let (predicate, class) = if direction == "in" {
        ("dyknow:hasInPort", "dyknow:InPort")
    } else {
        ("dyknow:hasOutPort", "dyknow:OutPort")
    };
    ports
        .iter()
        .enumerate()
        .map(|(i, tags)| {
            let tags: Vec<String> = tags.iter().map(TagSpec::turtle).collect();
            format!(
                " ; {predicate} [ a {class} ; dyknow:hasName \"{direction}{i}\" ; dyknow:hasTag {} ]",
                tags.join(" , ")
            )
        })
        .collect()
}

/// Applies `op`; refusals (a consistency rule an extension breaks, a missing spec) change
/// nothing and are part of what is tested.
fn apply(kb: &KnowledgeBase, op: &Op, extensions: &mut Vec<String>) {
    match op {
        Op::Transformation {
            label,
            inputs,
            outputs,
        } => {
            let body = format!(
                "{PREFIXES}[] a dyknow:Transformation ; rdfs:label \"t{label}\"{}{} .",
                ports("in", inputs),
                ports("out", outputs)
            );
            kb.post_specs(
                body.as_bytes(),
                InputFormat::Turtle,
                SpecKind::Transformation,
            )
            .unwrap();
        }
        Op::Target { label, tags } => {
            let tags: Vec<String> = tags.iter().map(TagSpec::turtle).collect();
            let body = format!(
                "{PREFIXES}[] a dyknow:Target ; rdfs:label \"q{label}\" ; \
                 dyknow:hasChannel [ a dyknow:Channel ; dyknow:hasChannelName \"c{label}\" ] ; \
                 dyknow:hasTag {} .",
                tags.join(" , ")
            );
            kb.post_specs(body.as_bytes(), InputFormat::Turtle, SpecKind::Target)
                .unwrap();
        }
        Op::Remove { kind, label } => {
            let label = match kind {
                SpecKind::Transformation => format!("t{label}"),
                SpecKind::Target => format!("q{label}"),
            };
            let _ = kb.remove_spec(*kind, &label);
        }
        Op::Extension(statements) => {
            let body: String = statements
                .iter()
                .map(|(a, similar, b)| {
                    let p = if *similar {
                        "dyknow:similarTo"
                    } else {
                        "rdfs:subClassOf"
                    };
                    format!("ex:D{a} {p} ex:D{b} .\n")
                })
                .collect();
            if let Ok(report) =
                kb.post_extension(format!("{PREFIXES}{body}").as_bytes(), InputFormat::Turtle)
                // The same content is the same graph (`replaced`): listed once.
                && !extensions.contains(&report.graph)
            {
                extensions.push(report.graph);
            }
        }
        Op::RemoveExtension(n) => {
            if !extensions.is_empty() {
                let i = extensions.len() - 1 - n % extensions.len();
                let graph = extensions.remove(i);
                kb.remove_extension(&graph).unwrap();
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn the_patched_table_equals_the_one_computed_from_scratch(
        ops in prop::collection::vec(op(), 1..24)
    ) {
        let kb = KnowledgeBase::in_memory().unwrap();
        let cache = SpecCache::default();
        let mut extensions = Vec::new();
        for (step, op) in ops.iter().enumerate() {
            apply(&kb, op, &mut extensions);
            // Not every step is read: a patch then covers several changes at once.
            if step % 3 == 1 && step + 1 != ops.len() {
                continue;
            }
            let patched = cache.spec_part(&kb).unwrap();
            let fresh = SpecCache::default().spec_part(&kb).unwrap();
            let reference = model::candidates(&kb, &fresh.env).unwrap();
            prop_assert_eq!(&patched.env, &fresh.env, "after step {}: {:?}", step, op);
            prop_assert_eq!(&patched.iris, &fresh.iris);
            prop_assert_eq!(&patched.specs, &fresh.specs);
            prop_assert_eq!(&*fresh.candidates, &reference, "built from scratch, step {}", step);
            prop_assert_eq!(&*patched.candidates, &reference, "patched, after step {}: {:?}", step, op);
        }
    }
}

/// A table that patching got wrong would be caught: the reference differs from the table of a
/// library without the spec that was just posted.
#[test]
fn the_comparison_sees_a_missing_provider() {
    let kb = KnowledgeBase::in_memory().unwrap();
    let mut extensions = Vec::new();
    let target = Op::Target {
        label: 0,
        tags: vec![TagSpec {
            value: Some(1),
            description: None,
        }],
    };
    apply(&kb, &target, &mut extensions);
    let before = SpecCache::default().spec_part(&kb).unwrap();
    let producer = Op::Transformation {
        label: 0,
        inputs: vec![],
        outputs: vec![vec![TagSpec {
            value: Some(1),
            description: None,
        }]],
    };
    apply(&kb, &producer, &mut extensions);
    let after = SpecCache::default().spec_part(&kb).unwrap();
    assert_ne!(
        *before.candidates,
        model::candidates(&kb, &after.env).unwrap()
    );
    assert_eq!(after.candidates.for_target("q0").len(), 1);
}
