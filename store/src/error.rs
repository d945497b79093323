//! Errors of the knowledge base, one type per stage.

use oxigraph::store::StorageError;

/// A position and message of a syntax error (1-based line and column).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct SyntaxErrorDetail {
    /// 1-based line.
    pub line: u64,
    /// 1-based column (in characters).
    pub column: u64,
    /// What the parser said.
    pub message: String,
}

/// An RDF document could not be parsed.
#[derive(Debug, Clone, thiserror::Error)]
#[error("syntax error at line {}, column {}: {}", .0.line, .0.column, .0.message)]
pub struct SpecParseError(pub SyntaxErrorDetail);

/// One violated constraint of the ontology or the DyKnow model, and the node that violates it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Violation {
    /// The constraint, in the words of the ontology (`"Source has exactly 0 InPort"`).
    pub constraint: String,
    /// The offending node: a label, an IRI or a description of a blank node.
    pub subject: String,
    /// Every node a violated ontology axiom involves (the subject first); empty for structural
    /// constraints.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub nodes: Vec<String>,
}

impl Violation {
    pub(crate) fn new(constraint: impl Into<String>, subject: impl Into<String>) -> Self {
        Self {
            constraint: constraint.into(),
            subject: subject.into(),
            nodes: Vec::new(),
        }
    }
}

/// A well-formed document that violates the ontology or the DyKnow model.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{} constraint violation(s), first: {}", .0.len(), .0.first().map_or("", |v| v.constraint.as_str()))]
pub struct SpecValidationError(pub Vec<Violation>);

/// A request to change the knowledge base was rejected or failed. Nothing was written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IngestError {
    /// The body is not valid RDF in its format.
    #[error(transparent)]
    Parse(#[from] SpecParseError),
    /// The body is valid RDF but violates the ontology or the DyKnow model.
    #[error(transparent)]
    Invalid(#[from] SpecValidationError),
    /// The named spec or graph does not exist.
    #[error("{0}")]
    NotFound(String),
    /// The request conflicts with the state of the knowledge base (e.g. removing a built-in ontology).
    #[error("{0}")]
    Conflict(String),
    /// The storage failed.
    #[error(transparent)]
    Storage(#[from] StorageError),
}

/// Opening or reading the knowledge base failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreOpenError {
    /// The storage failed (e.g. the directory is locked by another process).
    #[error(transparent)]
    Storage(#[from] StorageError),
    /// The directory could not be created.
    #[error("cannot create {path}: {source}")]
    Io {
        /// The directory.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A built-in ontology failed to load (a bug).
    #[error("built-in ontology failed to load: {0}")]
    Ontology(String),
}

/// A SPARQL request was rejected or failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SparqlQueryError {
    /// The query does not parse.
    #[error("SPARQL syntax error: {}", .0.message)]
    Syntax(SyntaxErrorDetail),
    /// The request is a SPARQL update; the query endpoint refuses updates.
    #[error("SPARQL updates are not accepted by the query endpoint")]
    UpdateRefused,
    /// The query ran longer than the configured timeout.
    #[error("the query did not finish within the {0:?} timeout")]
    Timeout(std::time::Duration),
    /// The query held more memory than its limit (in bytes) allows
    /// ([`ParsedQuery::with_memory_limit`](crate::ParsedQuery::with_memory_limit)).
    #[error("the query held more than its {0} bytes of memory")]
    MemoryLimit(usize),
    /// The requested result format does not fit the query form.
    #[error("{0}")]
    UnsupportedFormat(String),
    /// The query uses a feature the service does not offer (e.g. federated `SERVICE` calls, or a
    /// custom function).
    #[error("{0}")]
    Unsupported(String),
    /// Evaluation failed.
    #[error("query evaluation failed: {0}")]
    Evaluation(String),
    /// The query nests deeper than the service parses or evaluates (its parser and evaluator
    /// recurse once per level: past the limits they would overflow their thread's stack).
    #[error("{0}")]
    TooDeep(String),
}

/// Serialising the model failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExportError {
    /// The storage failed.
    #[error(transparent)]
    Storage(#[from] StorageError),
    /// Converting to an OWL syntax failed.
    #[error(transparent)]
    Owl(#[from] dyknow_ontology::OwlConversionError),
    /// Writing failed.
    #[error("serialisation failed: {0}")]
    Io(#[from] std::io::Error),
}

/// Reading the DyKnow model (environment, candidate table, estimates, change sets) from the
/// knowledge base failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelReadError {
    /// The storage failed.
    #[error(transparent)]
    Storage(#[from] StorageError),
    /// One of the model's queries failed.
    #[error(transparent)]
    Query(#[from] SparqlQueryError),
}
