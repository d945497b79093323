use std::fmt;

/// Converting RDF into an OWL syntax (or reading one back) failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OwlConversionError {
    /// horned-owl rejected the input.
    #[error("OWL parsing failed: {0}")]
    Parse(String),
    /// Writing the OWL document failed.
    #[error("OWL writing failed: {0}")]
    Write(String),
}

impl OwlConversionError {
    pub(crate) fn parse(e: impl fmt::Display) -> Self {
        Self::Parse(e.to_string())
    }
    pub(crate) fn write(e: impl fmt::Display) -> Self {
        Self::Write(e.to_string())
    }
}
