//! `ApiError`: every error answer of the HTTP API, as the contract's JSON
//! (`{"error": "<one sentence>", "details": [...]}`) with the right status.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use dyknow_lifecycle::LifecycleError;
use dyknow_store::{ExportError, IngestError, ModelReadError, SparqlQueryError};
use serde::Serialize;
use serde_json::Value;

/// An error answer. 4xx bodies say exactly what was wrong; 5xx bodies say little and the cause
/// is logged.
#[derive(Debug)]
pub struct ApiError {
    /// The status.
    pub status: StatusCode,
    /// One sentence.
    pub message: String,
    /// Structured details (syntax positions, violated constraints).
    pub details: Vec<Value>,
}

/// The JSON body of an error answer.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ErrorBody {
    /// One sentence saying what was wrong.
    pub error: String,
    /// Syntax errors: `{"line", "column", "message"}`; violations: `{"constraint", "subject"}`.
    pub details: Vec<Value>,
}

impl ApiError {
    /// An error with no details.
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
            details: Vec::new(),
        }
    }
    /// 400.
    pub fn bad_request(message: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, message)
    }
    /// 404.
    pub fn not_found(message: impl Into<String>) -> Self {
        Self::new(StatusCode::NOT_FOUND, message)
    }
    /// 415.
    pub fn unsupported_media_type(got: Option<&str>, accepted: &[&str]) -> Self {
        Self::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            format!(
                "unsupported Content-Type {}; use one of: {}",
                got.map_or_else(|| "(none)".to_owned(), |g| format!("{g:?}")),
                accepted.join(", ")
            ),
        )
    }
    /// 406.
    pub fn not_acceptable(accepted: &[&str]) -> Self {
        Self::new(
            StatusCode::NOT_ACCEPTABLE,
            format!(
                "none of the accepted media types is offered; offered: {}",
                accepted.join(", ")
            ),
        )
    }
    /// 500: the cause is logged, the body says little.
    pub fn internal(cause: impl std::fmt::Display) -> Self {
        tracing::error!("internal error: {cause}");
        Self::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "internal error; see the server log",
        )
    }
    /// With details.
    pub fn with_details(mut self, details: Vec<Value>) -> Self {
        self.details = details;
        self
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: self.message,
            details: self.details,
        };
        let mut response = (self.status, axum::Json(body)).into_response();
        if self.status == StatusCode::UNAUTHORIZED {
            response
                .headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        response
    }
}

impl From<IngestError> for ApiError {
    fn from(e: IngestError) -> Self {
        match e {
            IngestError::Parse(p) => Self::bad_request(format!(
                "the body is not valid RDF: syntax error at line {}, column {}",
                p.0.line, p.0.column
            ))
            .with_details(vec![serde_json::to_value(&p.0).unwrap_or(Value::Null)]),
            IngestError::Invalid(v) => {
                let n = v.0.len();
                Self::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    format!(
                        "the body violates {n} constraint{} of the ontology or the DyKnow model",
                        if n == 1 { "" } else { "s" }
                    ),
                )
                .with_details(
                    v.0.iter()
                        .map(|x| serde_json::to_value(x).unwrap_or(Value::Null))
                        .collect(),
                )
            }
            IngestError::NotFound(m) => Self::not_found(m),
            IngestError::Conflict(m) => Self::new(StatusCode::CONFLICT, m),
            IngestError::Storage(s) => {
                STORAGE_FAILED.store(true, std::sync::atomic::Ordering::Relaxed);
                tracing::error!("storage error: {s}");
                Self::new(
                    StatusCode::INTERNAL_SERVER_ERROR,
                    "the store could not complete the write, and nothing of it was written; \
                     see the server log (GET /health says whether the store still takes writes)",
                )
            }
            other => Self::internal(other),
        }
    }
}

impl From<SparqlQueryError> for ApiError {
    fn from(e: SparqlQueryError) -> Self {
        match e {
            SparqlQueryError::Syntax(d) => Self::bad_request(format!(
                "SPARQL syntax error at line {}, column {}",
                d.line, d.column
            ))
            .with_details(vec![serde_json::to_value(&d).unwrap_or(Value::Null)]),
            SparqlQueryError::UpdateRefused => Self::new(
                StatusCode::FORBIDDEN,
                "SPARQL updates are refused: change the model through the spec endpoints",
            ),
            SparqlQueryError::Timeout(t) => Self::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "the query was cancelled after the {} s query timeout",
                    t.as_secs_f64()
                ),
            ),
            SparqlQueryError::MemoryLimit(bytes) => Self::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "the query was cancelled when it held more than its {} of memory \
                     (--query-memory): narrow it, or ask for fewer solutions at once",
                    size(bytes)
                ),
            ),
            SparqlQueryError::UnsupportedFormat(m) => Self::new(StatusCode::NOT_ACCEPTABLE, m),
            SparqlQueryError::Unsupported(m) | SparqlQueryError::TooDeep(m) => Self::bad_request(m),
            other => Self::internal(other),
        }
    }
}

impl From<ExportError> for ApiError {
    fn from(e: ExportError) -> Self {
        Self::internal(e)
    }
}

impl From<dyknow_store::oxigraph::store::StorageError> for ApiError {
    fn from(e: dyknow_store::oxigraph::store::StorageError) -> Self {
        STORAGE_FAILED.store(true, std::sync::atomic::Ordering::Relaxed);
        Self::internal(e)
    }
}

/// Set when a request met a storage error: `GET /health` then probes whether the store still
/// takes writes (and clears it when it does). Not probed otherwise: on a disk that is full for
/// a moment, the probe's own write could be the one that makes RocksDB refuse every write.
pub(crate) static STORAGE_FAILED: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

impl From<ModelReadError> for ApiError {
    fn from(e: ModelReadError) -> Self {
        Self::internal(e)
    }
}

impl From<LifecycleError> for ApiError {
    fn from(e: LifecycleError) -> Self {
        match e {
            LifecycleError::UnknownCu(_) | LifecycleError::UnknownTransformation(_) => {
                Self::not_found(e.to_string())
            }
            LifecycleError::NameTaken(_) | LifecycleError::Protected(_) => {
                Self::new(StatusCode::CONFLICT, e.to_string())
            }
            LifecycleError::EmptyName
            | LifecycleError::InvalidName(_)
            | LifecycleError::NotRunnable { .. }
            | LifecycleError::InvalidCost { .. }
            | LifecycleError::UnknownPort { .. }
            | LifecycleError::SharedChannel { .. }
            | LifecycleError::InvalidChannel(_) => {
                Self::new(StatusCode::UNPROCESSABLE_ENTITY, e.to_string())
            }
            // A real fault, but the client needs to know what is recorded: say it.
            LifecycleError::NotApplied { .. } => {
                Self::new(StatusCode::INTERNAL_SERVER_ERROR, e.to_string())
            }
            LifecycleError::Write(w) => w.into(),
            other => Self::internal(other),
        }
    }
}

/// `bytes` for people: whole MiB as MiB (as `--query-memory` takes them), else bytes.
fn size(bytes: usize) -> String {
    if bytes >= 1 << 20 && bytes.is_multiple_of(1 << 20) {
        format!("{} MiB", bytes >> 20)
    } else {
        format!("{bytes} bytes")
    }
}

#[cfg(test)]
mod tests {
    use super::size;

    #[test]
    fn sizes_read_as_the_flag_takes_them() {
        assert_eq!(size(16 << 20), "16 MiB");
        assert_eq!(size(1 << 30), "1024 MiB");
        assert_eq!(size(1000), "1000 bytes");
        assert_eq!(size((1 << 20) + 1), "1048577 bytes");
    }
}
