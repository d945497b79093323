//! The engine's errors.

/// What can go wrong between the engine and the knowledge base.
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// Reading the store failed.
    #[error("storage: {0}")]
    Storage(#[from] dyknow_store::oxigraph::store::StorageError),
    /// A query of the engine failed.
    #[error("query: {0}")]
    Query(#[from] dyknow_store::SparqlQueryError),
    /// Writing a change set was refused.
    #[error("{0}")]
    Ingest(#[from] dyknow_store::IngestError),
}
