//! Operations: health, Prometheus metrics, the OpenAPI description.

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde::Serialize;
use utoipa::{OpenApi, ToSchema};

use crate::app::{AppState, in_turn, typed};
use crate::error::ApiError;

pub(crate) fn router() -> Router<AppState> {
    Router::new()
        .route("/health", get(health))
        .route("/metrics", get(metrics))
        .route("/openapi.json", get(openapi))
}

/// The health answer.
#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    /// `"ok"`, or `"storage-failed"` when the store refuses writes.
    pub status: &'static str,
    /// Why the store refuses writes (with `"storage-failed"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// How long a write probe's answer stands.
const PROBE_INTERVAL: std::time::Duration = std::time::Duration::from_secs(1);

/// Liveness, and whether the store takes writes: 200 `{"status": "ok"}`, or 503
/// `{"status": "storage-failed", "error"}` once a write of the storage failed (a full disk:
/// RocksDB then refuses every write until the service is restarted, even once space is back).
/// After a request met a storage error, the store is probed with a write that changes
/// nothing, at most once a second, until a probe succeeds; the probe takes no turn, so health
/// answers while every turn is held.
#[utoipa::path(get, path = "/health", tag = "operations",
    responses((status = 200, body = Health), (status = 503, body = Health)))]
pub async fn health(State(state): State<AppState>) -> Response {
    use std::sync::atomic::Ordering;
    if !crate::error::STORAGE_FAILED.load(Ordering::Relaxed) {
        return Json(Health {
            status: "ok",
            error: None,
        })
        .into_response();
    }
    let cached = state
        .write_probe
        .lock()
        .ok()
        .and_then(|p| p.clone())
        .filter(|(at, _)| at.elapsed() < PROBE_INTERVAL);
    let failure = match cached {
        Some((_, failure)) => failure,
        None => {
            let kb = state.kb.clone();
            let failure = tokio::task::spawn_blocking(move || kb.probe_write().err())
                .await
                .ok()
                .flatten()
                .map(|e| e.to_string());
            if let Ok(mut probe) = state.write_probe.lock() {
                *probe = Some((std::time::Instant::now(), failure.clone()));
            }
            if failure.is_none() {
                crate::error::STORAGE_FAILED.store(false, Ordering::Relaxed);
            }
            failure
        }
    };
    match failure {
        None => Json(Health {
            status: "ok",
            error: None,
        })
        .into_response(),
        Some(error) => (
            StatusCode::SERVICE_UNAVAILABLE,
            Json(Health {
                status: "storage-failed",
                error: Some(format!(
                    "the store refuses writes ({error}); free the disk and restart the service"
                )),
            }),
        )
            .into_response(),
    }
}

/// Prometheus metrics: request counts and latencies by route and status, the store's size.
#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, content_type = "text/plain", description = "Prometheus text format")))]
pub async fn metrics(State(state): State<AppState>) -> Result<Response, ApiError> {
    let kb = state.kb.clone();
    let stats = in_turn(&state, move || Ok(kb.statistics()?)).await?;
    Ok(typed(
        StatusCode::OK,
        "text/plain; version=0.0.4",
        state.metrics.render(&stats),
    ))
}

/// This API's OpenAPI 3 description, generated from the handlers.
#[utoipa::path(get, path = "/openapi.json", tag = "operations",
    responses((status = 200, description = "OpenAPI 3.1")))]
pub async fn openapi() -> Json<utoipa::openapi::OpenApi> {
    Json(crate::openapi::ApiDoc::openapi())
}
