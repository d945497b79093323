//! The layout of the store: which named graph holds what, and the IRIs the service mints.
//!
//! | graph | holds |
//! | --- | --- |
//! | `http://www.dyknow.eu/ontology/dyknow`, `…/dyknow-ros` | the built-in ontologies |
//! | `urn:dyknow:graph:transformation:<label>` | one transformation spec |
//! | `urn:dyknow:graph:target:<label>` | one target spec |
//! | `urn:dyknow:graph:extension:<hash>` | one posted ontology extension |
//! | `urn:dyknow:graph:environment:cu:<name>` | one computation unit ([`EnvironmentPart::Cu`]) |
//! | `urn:dyknow:graph:environment:changeset:<id>` | one change set's record |
//! | `urn:dyknow:graph:environment:statistics` | the learned cost estimates |
//! | `urn:dyknow:graph:environment:imported` | CUs read from files (`dyknow explore`) |
//!
//! Labels are percent-encoded (every byte outside `A–Z a–z 0–9 - . _ ~`). Blank nodes of a
//! spec are replaced by IRIs under `urn:dyknow:<kind>:<label>` (ports by name) so that every
//! part of the model can be named in SPARQL and in OWL; computation units are
//! `urn:dyknow:cu:<name>`, channels `urn:dyknow:channel:<name>`, change sets
//! `urn:dyknow:changeset:<id>`.

use dyknow_engine::{ChangeSetId, Cid};
use oxigraph::model::NamedNode;
use percent_encoding::{AsciiSet, NON_ALPHANUMERIC, percent_decode_str, utf8_percent_encode};

use crate::spec::SpecKind;

const UNRESERVED: &AsciiSet = &NON_ALPHANUMERIC
    .remove(b'-')
    .remove(b'.')
    .remove(b'_')
    .remove(b'~');

/// Prefix of the graphs holding transformation specs.
pub const TRANSFORMATION_GRAPH_PREFIX: &str = "urn:dyknow:graph:transformation:";
/// Prefix of the graphs holding target specs.
pub const TARGET_GRAPH_PREFIX: &str = "urn:dyknow:graph:target:";
/// Prefix of the graphs holding ontology extensions.
pub const EXTENSION_GRAPH_PREFIX: &str = "urn:dyknow:graph:extension:";
/// Prefix of the graphs holding parts of the running environment (computation units, their
/// subscriptions and publications), one graph per part.
pub const ENVIRONMENT_GRAPH_PREFIX: &str = "urn:dyknow:graph:environment:";

/// Percent-encodes a label or name for use in an IRI.
pub fn encode(label: &str) -> String {
    utf8_percent_encode(label, UNRESERVED).to_string()
}

fn graph_prefix(kind: SpecKind) -> &'static str {
    match kind {
        SpecKind::Transformation => TRANSFORMATION_GRAPH_PREFIX,
        SpecKind::Target => TARGET_GRAPH_PREFIX,
    }
}

/// The named graph holding the spec of `kind` labelled `label`.
pub fn spec_graph(kind: SpecKind, label: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{}{}", graph_prefix(kind), encode(label)))
}

/// The IRI minted for the spec resource when the document gave a blank node.
pub fn spec_resource(kind: SpecKind, label: &str) -> String {
    format!("urn:dyknow:{}:{}", kind.name(), encode(label))
}

/// Prefix of the IRIs of channels.
pub const CHANNEL_PREFIX: &str = "urn:dyknow:channel:";
/// Prefix of the IRIs of computation units.
pub const CU_PREFIX: &str = "urn:dyknow:cu:";
/// Prefix of the IRIs of change sets.
pub const CHANGE_SET_PREFIX: &str = "urn:dyknow:changeset:";

/// The IRI of a channel (minted for a channel given as a blank node, and for the channels of
/// change sets): channels are identified by name.
pub fn channel_resource(name: &str) -> String {
    format!("{CHANNEL_PREFIX}{}", encode(name))
}

/// The IRI of computation unit `cid`.
pub fn cu_resource(cid: &Cid) -> NamedNode {
    NamedNode::new_unchecked(format!("{CU_PREFIX}{}", encode(cid.as_str())))
}

/// The IRI of change set `id`.
pub fn change_set_resource(id: &ChangeSetId) -> NamedNode {
    NamedNode::new_unchecked(format!("{CHANGE_SET_PREFIX}{}", encode(id.as_str())))
}

/// The kind and label of a spec graph, if `graph` is one.
pub fn spec_of_graph(graph: &str) -> Option<(SpecKind, String)> {
    let (kind, rest) = if let Some(rest) = graph.strip_prefix(TRANSFORMATION_GRAPH_PREFIX) {
        (SpecKind::Transformation, rest)
    } else {
        (SpecKind::Target, graph.strip_prefix(TARGET_GRAPH_PREFIX)?)
    };
    Some((
        kind,
        percent_decode_str(rest).decode_utf8().ok()?.into_owned(),
    ))
}

/// Whether `graph` holds an ontology extension.
pub fn is_extension_graph(graph: &str) -> bool {
    graph.starts_with(EXTENSION_GRAPH_PREFIX)
}

/// The graph for an extension whose statements hash to `hash` ([`graph_hash`]: re-posting the
/// same statements replaces it, however the document is written).
pub fn extension_graph(hash: u64) -> NamedNode {
    NamedNode::new_unchecked(format!("{EXTENSION_GRAPH_PREFIX}{hash:016x}"))
}

/// A hash of a graph's statements that does not depend on how its document is written: not on
/// comments, prefixes, layout, the order of statements, repeated statements, nor on blank node
/// labels. Blank nodes are told apart by colour refinement (1-dimensional Weisfeiler–Leman):
/// each starts with one colour, and each round a blank node's colour becomes a hash of its
/// colour and of the statements it is in, written with the colours of the blank nodes there,
/// until a round splits no colour class. Isomorphic graphs get the same hash; graphs that the
/// refinement cannot tell apart (regular structures of blank nodes alike in every statement)
/// would share one, which ontology extensions, whose blank nodes are restrictions and lists
/// hanging from named terms, do not have in practice.
pub(crate) fn graph_hash(triples: &[oxigraph::model::Triple]) -> u64 {
    use oxigraph::model::{BlankNode, NamedOrBlankNode, Term};
    use std::collections::{HashMap, HashSet};
    let triples: HashSet<&oxigraph::model::Triple> = triples.iter().collect();
    let mut colour: HashMap<&BlankNode, u64> = HashMap::new();
    for t in &triples {
        if let NamedOrBlankNode::BlankNode(b) = &t.subject {
            colour.insert(b, 0);
        }
        if let Term::BlankNode(b) = &t.object {
            colour.insert(b, 0);
        }
    }
    let subject = |s: &NamedOrBlankNode, colour: &HashMap<&BlankNode, u64>| match s {
        NamedOrBlankNode::BlankNode(b) => format!("_:{:016x}", colour[b]),
        NamedOrBlankNode::NamedNode(n) => n.to_string(),
    };
    let object = |o: &Term, colour: &HashMap<&BlankNode, u64>| match o {
        Term::BlankNode(b) => format!("_:{:016x}", colour[b]),
        other => other.to_string(),
    };
    let mut classes = usize::from(!colour.is_empty());
    loop {
        let mut seen: HashMap<&BlankNode, Vec<String>> = HashMap::new();
        for t in &triples {
            let (s, o) = (subject(&t.subject, &colour), object(&t.object, &colour));
            if let NamedOrBlankNode::BlankNode(b) = &t.subject {
                seen.entry(b)
                    .or_default()
                    .push(format!("s {} {o}", t.predicate));
            }
            if let Term::BlankNode(b) = &t.object {
                seen.entry(b)
                    .or_default()
                    .push(format!("o {s} {}", t.predicate));
            }
        }
        let refined: HashMap<&BlankNode, u64> = seen
            .into_iter()
            .map(|(b, mut statements)| {
                statements.sort_unstable();
                let text = format!("{:016x}\n{}", colour[b], statements.join("\n"));
                (b, fnv1a(text.as_bytes()))
            })
            .collect();
        let refined_classes = refined.values().collect::<HashSet<_>>().len();
        colour = refined;
        if refined_classes <= classes {
            break;
        }
        classes = refined_classes;
    }
    let mut lines: Vec<String> = triples
        .iter()
        .map(|t| {
            format!(
                "{} {} {}",
                subject(&t.subject, &colour),
                t.predicate,
                object(&t.object, &colour)
            )
        })
        .collect();
    lines.sort_unstable();
    fnv1a(lines.join("\n").as_bytes())
}

/// FNV-1a, 64 bits: a stable content hash (unlike `DefaultHasher`, fixed across Rust releases).
pub(crate) fn fnv1a(bytes: &[u8]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        hash ^= u64::from(*b);
        hash = hash.wrapping_mul(0x0100_0000_01b3);
    }
    hash
}

/// A part of the running environment, each in its own graph, so that a change set rewrites
/// only the parts it changes (and `dependsOn` follows, reasoned incrementally).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum EnvironmentPart {
    /// One computation unit: its types, name, transformation, upkeep, protection, its
    /// subscriptions and publications with their channels.
    Cu(Cid),
    /// The record of one change set (`dyknow:ChangeSet`).
    ChangeSet(ChangeSetId),
    /// The learned cost estimates.
    Statistics,
    /// What the change sets pruned from the history leave behind: the names they used, which
    /// are never handed out again.
    History,
    /// Computation units read from files as one part (`dyknow explore --environment`).
    Imported,
}

impl EnvironmentPart {
    /// The part's named graph: `urn:dyknow:graph:environment:cu:<name>`,
    /// `…:changeset:<id>`, `…:statistics`, `…:history`, `…:imported`.
    pub fn graph(&self) -> NamedNode {
        NamedNode::new_unchecked(match self {
            Self::Cu(cid) => format!("{ENVIRONMENT_GRAPH_PREFIX}cu:{}", encode(cid.as_str())),
            Self::ChangeSet(id) => {
                format!(
                    "{ENVIRONMENT_GRAPH_PREFIX}changeset:{}",
                    encode(id.as_str())
                )
            }
            Self::Statistics => format!("{ENVIRONMENT_GRAPH_PREFIX}statistics"),
            Self::History => format!("{ENVIRONMENT_GRAPH_PREFIX}history"),
            Self::Imported => format!("{ENVIRONMENT_GRAPH_PREFIX}imported"),
        })
    }

    /// The part a graph holds, if it is an environment graph.
    pub fn of_graph(graph: &str) -> Option<Self> {
        let rest = graph.strip_prefix(ENVIRONMENT_GRAPH_PREFIX)?;
        let decode = |s: &str| Some(percent_decode_str(s).decode_utf8().ok()?.into_owned());
        if let Some(name) = rest.strip_prefix("cu:") {
            return Some(Self::Cu(Cid::new(decode(name)?)));
        }
        if let Some(id) = rest.strip_prefix("changeset:") {
            return Some(Self::ChangeSet(ChangeSetId::new(decode(id)?)));
        }
        match rest {
            "statistics" => Some(Self::Statistics),
            "history" => Some(Self::History),
            "imported" => Some(Self::Imported),
            _ => None,
        }
    }
}

/// The new name of an environment graph written by earlier releases, which percent-encoded
/// the whole part name (`…environment:cu%3Acu-1` for `…environment:cu:cu-1`); `None` for
/// any other graph. The name after the colon was encoded the same way in both layouts.
pub(crate) fn renamed_environment_graph(graph: &str) -> Option<NamedNode> {
    let rest = graph.strip_prefix(ENVIRONMENT_GRAPH_PREFIX)?;
    ["cu", "changeset"].iter().find_map(|kind| {
        let name = rest.strip_prefix(kind)?.strip_prefix("%3A")?;
        Some(NamedNode::new_unchecked(format!(
            "{ENVIRONMENT_GRAPH_PREFIX}{kind}:{name}"
        )))
    })
}

/// Whether `graph` holds a part of the running environment.
pub fn is_environment_graph(graph: &str) -> bool {
    graph.starts_with(ENVIRONMENT_GRAPH_PREFIX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_round_trip_through_graph_names() {
        for label in [
            "Undistort(cam1)",
            "a b/c?d#e",
            "ünï",
            "convHull(piff, field)",
            "",
        ] {
            for kind in [SpecKind::Transformation, SpecKind::Target] {
                let g = spec_graph(kind, label);
                assert_eq!(spec_of_graph(g.as_str()), Some((kind, label.to_owned())));
            }
        }
        assert_eq!(
            spec_graph(SpecKind::Transformation, "Undistort(cam1)").as_str(),
            "urn:dyknow:graph:transformation:Undistort%28cam1%29"
        );
        assert_eq!(spec_of_graph("urn:dyknow:graph:extension:00"), None);
    }

    #[test]
    fn environment_parts_round_trip_through_graph_names() {
        for part in [
            EnvironmentPart::Cu("cu-1".into()),
            EnvironmentPart::Cu("a b:c/ü".into()),
            EnvironmentPart::ChangeSet(ChangeSetId::numbered(7)),
            EnvironmentPart::Statistics,
            EnvironmentPart::History,
            EnvironmentPart::Imported,
        ] {
            let g = part.graph();
            assert!(is_environment_graph(g.as_str()));
            assert_eq!(EnvironmentPart::of_graph(g.as_str()), Some(part));
        }
        assert_eq!(
            EnvironmentPart::Cu("cu-1".into()).graph().as_str(),
            "urn:dyknow:graph:environment:cu:cu-1"
        );
        assert_eq!(
            EnvironmentPart::of_graph("urn:dyknow:graph:environment:x"),
            None
        );
    }

    #[test]
    fn environment_graphs_of_the_old_layout_are_renamed() {
        let old = format!("{ENVIRONMENT_GRAPH_PREFIX}{}", encode("cu:a b"));
        assert_eq!(
            renamed_environment_graph(&old),
            Some(EnvironmentPart::Cu("a b".into()).graph())
        );
        let old = format!("{ENVIRONMENT_GRAPH_PREFIX}{}", encode("changeset:cs-2"));
        assert_eq!(
            renamed_environment_graph(&old),
            Some(EnvironmentPart::ChangeSet(ChangeSetId::numbered(2)).graph())
        );
        for current in [
            EnvironmentPart::Cu("cu-1".into()).graph(),
            EnvironmentPart::Statistics.graph(),
        ] {
            assert_eq!(renamed_environment_graph(current.as_str()), None);
        }
    }

    #[test]
    fn fnv_is_stable() {
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
    }

    /// [`graph_hash`] is a function of the graph, not of its document: blank node labels,
    /// statement order, repeats and syntax do not change it; a blank node's statements do.
    #[test]
    fn graph_hash_is_invariant_under_rewriting_and_tells_structures_apart() {
        let parse = |text: &str| -> Vec<oxigraph::model::Triple> {
            crate::rdf_input::parse_triples(
                format!(
                    "@prefix owl: <http://www.w3.org/2002/07/owl#> .
                     @prefix ex: <http://example.org/> .
                     {text}"
                )
                .as_bytes(),
                crate::InputFormat::Turtle,
            )
            .expect("valid Turtle")
        };
        // Two restrictions: onProperty p with A and q with B.
        let one = parse(
            "ex:C owl:equivalentClass [ owl:onProperty ex:p ; owl:someValuesFrom ex:A ] .
             ex:D owl:equivalentClass [ owl:onProperty ex:q ; owl:someValuesFrom ex:B ] .",
        );
        let relabelled = parse(
            "# a comment
             _:y owl:someValuesFrom ex:B . _:x owl:onProperty ex:p .
             ex:D owl:equivalentClass _:y . _:y owl:onProperty ex:q .
             ex:C owl:equivalentClass _:x . _:x owl:someValuesFrom ex:A . ex:C owl:equivalentClass _:x .",
        );
        assert_eq!(graph_hash(&one), graph_hash(&relabelled));
        // The same statements with blank nodes erased, but p with B and q with A.
        let swapped = parse(
            "ex:C owl:equivalentClass [ owl:onProperty ex:p ; owl:someValuesFrom ex:B ] .
             ex:D owl:equivalentClass [ owl:onProperty ex:q ; owl:someValuesFrom ex:A ] .",
        );
        assert_ne!(graph_hash(&one), graph_hash(&swapped));
        // A list whose order differs only deep inside blank nodes.
        let list = |a: &str, b: &str| {
            graph_hash(&parse(&format!(
                "ex:C owl:unionOf ( ex:{a} ex:{b} ex:E ) ."
            )))
        };
        assert_eq!(list("A", "B"), list("A", "B"));
        assert_ne!(list("A", "B"), list("B", "A"));
        assert_ne!(graph_hash(&one), graph_hash(&[]));
    }
}
