#![doc = include_str!("../README.md")]

mod error;
mod export;
pub mod graphs;
mod knowledge_base;
pub mod model;
mod rdf_input;
mod sparql;
pub mod spec;

pub use error::{
    ExportError, IngestError, ModelReadError, SparqlQueryError, SpecParseError,
    SpecValidationError, StoreOpenError, SyntaxErrorDetail, Violation,
};
pub use export::{ExportedModel, INFERRED_GRAPH, MODEL_ONTOLOGY_IRI, ModelFormat, serialize};
pub use graphs::EnvironmentPart;
pub use knowledge_base::{
    ExtensionInfo, ExtensionReport, KnowledgeBase, LoadReport, PostReport, StoreStatistics,
};
pub use oxigraph;
pub use rdf_input::{InputFormat, parse_triples};
pub use sparql::{
    MAX_QUERY_DEPTH, MAX_QUERY_NESTING, MAX_QUERY_OPERATORS, MAX_QUERY_PATTERNS, ParsedQuery,
    QueryAnswer, QueryForm, ResultFormat,
};
