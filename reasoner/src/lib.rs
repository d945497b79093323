//! Incremental OWL 2 RL reasoning for DyKnow environments.
//!
//! The schema (the DyKnow and DyKnow-ROS ontologies and posted extensions) is read with
//! horned-owl and compiled into OWL 2 RL rules ([`TBox`]); a [`Reasoner`] keeps the
//! materialisation of a set of explicit triples up to date as triples are added (semi-naive
//! evaluation from the delta) and removed (DRed: over-delete, re-derive), and reports the
//! consistency rules the data violates ([`Violation`]). Above all it maintains the seed's
//! `dependsOn ⊑ hasSubscription ∘ fromCU` (transitive, seed 4.63) through any change, cycles
//! included.
//!
//! ```
//! use dyknow_reasoner::{Reasoner, TBox};
//! use oxrdf::{NamedNode, Triple};
//!
//! let tbox = TBox::from_triples(&dyknow_reasoner::builtin_ontology_triples()).unwrap();
//! let mut reasoner = Reasoner::new(tbox);
//! let dk = |l: &str| NamedNode::new_unchecked(format!("http://www.dyknow.eu/ontology/dyknow#{l}"));
//! let ex = |l: &str| NamedNode::new_unchecked(format!("http://example.org/{l}"));
//! let data = [
//!     Triple::new(ex("cu2"), dk("hasSubscription"), ex("s1")),
//!     Triple::new(ex("s1"), dk("fromCU"), ex("cu1")),
//!     Triple::new(ex("cu3"), dk("hasSubscription"), ex("s2")),
//!     Triple::new(ex("s2"), dk("fromCU"), ex("cu2")),
//! ];
//! reasoner.update(&[], &data);
//! assert!(reasoner.entails(&Triple::new(ex("cu3"), dk("dependsOn"), ex("cu1"))));
//! // Removing cu2's subscription breaks the dependencies that ran through it.
//! let update = reasoner.update(&data[..2], &[]);
//! assert!(!reasoner.entails(&Triple::new(ex("cu3"), dk("dependsOn"), ex("cu1"))));
//! assert!(update.inferred_removed.contains(&Triple::new(ex("cu2"), dk("dependsOn"), ex("cu1"))));
//! ```

mod declarations;
mod dictionary;
mod error;
mod facts;
mod reasoner;
mod rules;
mod tbox;

pub use error::SchemaError;
pub use reasoner::{NamedTriples, Reasoner, Update, Violation};
pub use tbox::TBox;

use oxrdf::Triple;

/// The triples of the built-in ontologies (DyKnow core and DyKnow-ROS).
pub fn builtin_ontology_triples() -> Vec<Triple> {
    let mut out = Vec::new();
    for (_, ttl) in dyknow_ontology::BUILTIN_ONTOLOGIES {
        for t in oxttl::TurtleParser::new()
            .for_slice(ttl.as_bytes())
            .flatten()
        {
            out.push(t);
        }
    }
    out
}

impl TBox {
    /// Compiles the schema in `triples` (all ontologies in one set: core, DyKnow-ROS and
    /// extensions). Undeclared classes and properties get a declaration first, so horned-owl
    /// maps every axiom that uses them.
    pub fn from_triples(triples: &[Triple]) -> Result<Self, SchemaError> {
        let mut document = Vec::new();
        let schema = declarations::rewrite_for_horned_owl(triples);
        let declarations = declarations::missing_declarations(&schema);
        for t in schema.iter().chain(&declarations) {
            document.extend_from_slice(t.to_string().as_bytes());
            document.extend_from_slice(b" .\n");
        }
        Self::from_rdf(&document, oxrdfio::RdfFormat::NTriples, triples)
    }
}
