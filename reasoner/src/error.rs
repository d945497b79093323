//! Errors of the reasoner.

/// The schema could not be read (horned-owl refused the RDF).
#[derive(Debug, thiserror::Error)]
#[error("the ontology could not be read as OWL 2: {0}")]
pub struct SchemaError(pub String);
