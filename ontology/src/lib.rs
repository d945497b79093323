#![doc = include_str!("../README.md")]

mod error;
mod owl;
pub mod vocab;

pub use error::OwlConversionError;
pub use owl::{
    OwlDocument, OwlSyntax, prefix_mapping, rdf_owl_components, rdf_owl_components_detailed,
    rdf_to_owl, read_owl,
};

/// The DyKnow core ontology (seed, Appendix A) in Turtle.
pub const DYKNOW_TTL: &str = include_str!("../dyknow.ttl");
/// The DyKnow-ROS extension (seed, Ch. 5.3.1) in Turtle.
pub const DYKNOW_ROS_TTL: &str = include_str!("../dyknow-ros.ttl");

/// The IRI of the DyKnow core ontology (also the name of the graph that holds it in the store).
pub const DYKNOW_ONTOLOGY_IRI: &str = "http://www.dyknow.eu/ontology/dyknow";
/// The IRI of the DyKnow-ROS ontology (also the name of the graph that holds it in the store).
pub const DYKNOW_ROS_ONTOLOGY_IRI: &str = "http://www.dyknow.eu/ontology/dyknow-ros";

/// The built-in ontologies as `(ontology IRI, Turtle text)`, core first.
pub const BUILTIN_ONTOLOGIES: [(&str, &str); 2] = [
    (DYKNOW_ONTOLOGY_IRI, DYKNOW_TTL),
    (DYKNOW_ROS_ONTOLOGY_IRI, DYKNOW_ROS_TTL),
];
