//! The layout of the store: which named graph holds what, and the IRIs the service mints.
//!
//! | graph | holds |
//! | --- | --- |
//! | `http://www.dyknow.eu/ontology/dyknow`, `…/dyknow-ros` | the built-in ontologies |
//! | `urn:dyknow:graph:transformation:<label>` | one transformation spec |
//! | `urn:dyknow:graph:target:<label>` | one target spec |
//! | `urn:dyknow:graph:extension:<hash>` | one posted ontology extension |
//!
//! Labels are percent-encoded (every byte outside `A–Z a–z 0–9 - . _ ~`). Blank nodes of a
//! spec are replaced by IRIs under `urn:dyknow:<kind>:<label>` (ports by name) so that every
//! part of the model can be named in SPARQL and in OWL.

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

/// The IRI minted for a channel given as a blank node: channels are identified by name.
pub fn channel_resource(name: &str) -> String {
    format!("urn:dyknow:channel:{}", encode(name))
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

/// The graph for an extension whose body hashes to `hash` (re-posting the same body replaces it).
pub fn extension_graph(hash: u64) -> NamedNode {
    NamedNode::new_unchecked(format!("{EXTENSION_GRAPH_PREFIX}{hash:016x}"))
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

/// The graph of the environment part named `name` (e.g. a computation unit).
pub fn environment_graph(name: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{ENVIRONMENT_GRAPH_PREFIX}{}", encode(name)))
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
    fn fnv_is_stable() {
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
    }
}
