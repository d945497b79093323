//! Formula groups (contract `groups.md`): CreateGroup, DestroyGroup, StartGroup, StopGroup,
//! AddFormula, RemoveFormula, their status, verdicts as Server-Sent Events, and the recorded
//! trace.

use std::collections::BTreeSet;
use std::convert::Infallible;

use axum::body::Bytes;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, post};
use axum::{Json, Router};
use dyknow_group::{GroupSpec, SpecError};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use tokio::sync::broadcast::error::RecvError;
use utoipa::ToSchema;

use crate::app::{AppState, in_turn, typed};
use crate::error::ApiError;
use crate::groups::{GroupError, status};
use crate::negotiate::content_type;
use crate::routes::reconfig::async_stream_lite;

pub(crate) fn router() -> Router<AppState> {
    Router::new()
        .route("/groups", get(list_groups).post(create_group))
        .route("/groups/{label}", get(get_group).delete(destroy_group))
        .route("/groups/{label}/start", post(start_group))
        .route("/groups/{label}/stop", post(stop_group))
        .route("/groups/{label}/formulas", post(add_formula))
        .route("/groups/{label}/formulas/{index}", delete(remove_formula))
        .route("/groups/{label}/verdicts", get(verdicts))
        .route("/groups/{label}/trace", get(trace))
}

impl From<GroupError> for ApiError {
    fn from(e: GroupError) -> Self {
        let message = e.to_string();
        match e {
            GroupError::Spec(SpecError::Syntax {
                index,
                column,
                message: m,
            }) => ApiError::bad_request(message).with_details(vec![
                json!({"formula": index, "column": column, "message": m}),
            ]),
            GroupError::Spec(SpecError::Grounding {
                index,
                column,
                message: m,
            }) => ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, message).with_details(vec![
                json!({"formula": index, "column": column, "message": m}),
            ]),
            GroupError::Spec(SpecError::Invalid(_)) => {
                ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, message)
            }
            GroupError::NotFound(_) | GroupError::NoFormula { .. } => ApiError::not_found(message),
            GroupError::Exists(_) | GroupError::Conflict(_) => {
                ApiError::new(StatusCode::CONFLICT, message)
            }
            GroupError::Internal(cause) => ApiError::internal(cause),
        }
    }
}

/// A JSON body: 415 unless it is declared as JSON (`application/json` or
/// `application/*+json`, as the other JSON endpoints take it; a body with no `Content-Type` is
/// not declared), 400 if it is not JSON, 422 if it does not fit.
fn json_body<T: serde::de::DeserializeOwned>(
    headers: &HeaderMap,
    body: &[u8],
) -> Result<T, ApiError> {
    let media = content_type(headers);
    if !media.as_deref().is_some_and(crate::json_body::is_json) {
        return Err(ApiError::unsupported_media_type(
            media.as_deref(),
            &["application/json"],
        ));
    }
    let value: Value = serde_json::from_slice(body)
        .map_err(|e| crate::json_body::at(&e, format!("the body is not JSON: {e}")))?;
    // serde reads a JSON array as a struct, field by field: refuse it.
    if !value.is_object() {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "the body does not fit: it must be a JSON object",
        ));
    }
    serde_json::from_value(value).map_err(|e| {
        ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("the body does not fit: {e}"),
        )
    })
}

/// `POST /groups`'s body as the OpenAPI description gives it (the service reads it as
/// `dyknow_group::GroupSpec`; `groups.md`). Formulas are MSTL text (`mstl.md`), which a
/// schema cannot state: one that does not parse is 400, one that does not ground is 422.
#[derive(ToSchema)]
#[serde(deny_unknown_fields)]
#[allow(dead_code, reason = "the schema of the body only")]
pub struct GroupSpecJson {
    /// The label (`g-N` when absent): 1 to 200 characters, no control character, no '/'.
    #[schema(pattern = "^[^/\\u0000-\\u001F\\u007F-\\u009F]{1,200}$")]
    label: Option<String>,
    /// Where verdicts are published (`/dyknow/verdicts/<label>` when absent).
    #[schema(pattern = "^[^\\u0000-\\u001F\\u007F-\\u009F]{1,200}$")]
    result_channel: Option<String>,
    /// The formulas (MSTL).
    #[serde(default)]
    formulas: Vec<String>,
    /// Named domains for quantifiers: name → constants.
    #[serde(default)]
    domains: std::collections::BTreeMap<String, Vec<String>>,
    /// Landmark regions.
    #[serde(default)]
    landmarks: Vec<String>,
    /// Static regions.
    #[serde(default, rename = "static")]
    static_regions: Vec<String>,
    /// Symbol → the tag its target asks for.
    #[serde(default)]
    grounding: std::collections::BTreeMap<String, GroundingJson>,
    /// The synchronisation policy (`wait`, P = 100 ms, D = 500 ms when absent; not null).
    #[serde(default)]
    sync: SyncJson,
    /// Start at once.
    #[serde(default)]
    start: bool,
}

/// The tag a symbol's target asks for: a tag value, or a tag description concept (an
/// absolute IRI).
#[derive(ToSchema)]
#[serde(untagged)]
#[allow(dead_code, reason = "the schema of the body only")]
pub enum GroundingJson {
    /// A tag value (`dyknow:hasValue`).
    #[serde(deny_unknown_fields)]
    Tag {
        /// The value.
        tag: String,
    },
    /// A tag description concept (`dyknow:hasTagDescription`).
    #[serde(deny_unknown_fields)]
    Description {
        /// The concept's IRI.
        description: String,
    },
}

/// A synchronisation policy (`groups.md`): times in milliseconds; periods from 1 ms to an
/// hour, `wait`'s and `hold`'s other times at most a day, `event`'s delay at most an hour.
#[derive(ToSchema)]
#[serde(tag = "policy", rename_all = "lowercase")]
#[allow(dead_code, reason = "the schema of the body only")]
pub enum SyncJson {
    /// A state every `period_ms` once every stream has a sample valid at its time, or
    /// `max_delay_ms` after it.
    #[serde(deny_unknown_fields)]
    Wait {
        /// `P` (default 100).
        #[schema(minimum = 1, maximum = 3_600_000)]
        period_ms: Option<u64>,
        /// `D` (default `5 P`).
        #[schema(maximum = 86_400_000)]
        max_delay_ms: Option<u64>,
    },
    /// A state every `period_ms`; values held while younger than `max_age_ms`.
    #[serde(deny_unknown_fields)]
    Hold {
        /// `P` (default 100).
        #[schema(minimum = 1, maximum = 3_600_000)]
        period_ms: Option<u64>,
        /// `A` (default 1,000).
        #[schema(maximum = 86_400_000)]
        max_age_ms: Option<u64>,
        /// `D` (default `P`).
        #[schema(maximum = 86_400_000)]
        max_delay_ms: Option<u64>,
    },
    /// A state at every sample's time.
    #[serde(deny_unknown_fields)]
    Event {
        /// `D` (default 2).
        #[schema(maximum = 3_600_000)]
        max_delay_ms: Option<u64>,
    },
}

/// CreateGroup: `{"label"?, "result_channel"?, "formulas"?, "domains"?, "landmarks"?,
/// "static"?, "grounding"?, "sync"?, "start"?}`. Every symbol becomes a target at once.
#[utoipa::path(post, path = "/groups", tag = "groups",
    request_body(content = GroupSpecJson, content_type = "application/json", description = "the group (groups.md)"),
    responses((status = 201, body = Object), (status = 400, body = crate::error::ErrorBody),
              (status = 409, body = crate::error::ErrorBody), (status = 415, body = crate::error::ErrorBody),
              (status = 422, body = crate::error::ErrorBody)))]
pub async fn create_group(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let spec: GroupSpec = json_body(&headers, &body)?;
    let groups = state.groups.clone();
    let value = in_turn(&state, move || {
        let g = groups.create(spec)?;
        Ok(status(&groups, &g))
    })
    .await?;
    Ok((StatusCode::CREATED, Json(value)).into_response())
}

/// Every group's status.
#[utoipa::path(get, path = "/groups", tag = "groups", responses((status = 200, body = [Object])))]
pub async fn list_groups(State(state): State<AppState>) -> Result<Json<Vec<Value>>, ApiError> {
    let groups = state.groups.clone();
    let list = in_turn(&state, move || {
        Ok(groups.list().iter().map(|g| status(&groups, g)).collect())
    })
    .await?;
    Ok(Json(list))
}

/// A group's status: state, formulas with verdicts, symbols with their targets and counts.
#[utoipa::path(get, path = "/groups/{label}", tag = "groups",
    params(("label" = String, Path, description = "the group's label")),
    responses((status = 200, body = Object), (status = 404, body = crate::error::ErrorBody)))]
pub async fn get_group(
    State(state): State<AppState>,
    Path(label): Path<String>,
) -> Result<Json<Value>, ApiError> {
    let groups = state.groups.clone();
    let v = in_turn(&state, move || {
        let g = groups.get(&label)?;
        Ok(status(&groups, &g))
    })
    .await?;
    Ok(Json(v))
}

/// StartGroup: progression begins with the next state (409 once stopped).
#[utoipa::path(post, path = "/groups/{label}/start", tag = "groups",
    params(("label" = String, Path, description = "the group's label")),
    responses((status = 200, body = Object), (status = 404, body = crate::error::ErrorBody), (status = 409, body = crate::error::ErrorBody)))]
pub async fn start_group(
    State(state): State<AppState>,
    Path(label): Path<String>,
) -> Result<Json<Value>, ApiError> {
    let groups = state.groups.clone();
    let v = in_turn(&state, move || {
        groups.start(&label)?;
        let g = groups.get(&label)?;
        Ok(status(&groups, &g))
    })
    .await?;
    Ok(Json(v))
}

/// StopGroup: progression ends for good; undecided formulas get `unknown`.
#[utoipa::path(post, path = "/groups/{label}/stop", tag = "groups",
    params(("label" = String, Path, description = "the group's label")),
    responses((status = 200, body = Object), (status = 404, body = crate::error::ErrorBody)))]
pub async fn stop_group(
    State(state): State<AppState>,
    Path(label): Path<String>,
) -> Result<Json<Value>, ApiError> {
    let groups = state.groups.clone();
    let v = in_turn(&state, move || {
        groups.stop(&label)?;
        let g = groups.get(&label)?;
        Ok(status(&groups, &g))
    })
    .await?;
    Ok(Json(v))
}

/// DestroyGroup: stops it; targets no other group uses are released.
#[utoipa::path(delete, path = "/groups/{label}", tag = "groups",
    params(("label" = String, Path, description = "the group's label")),
    responses((status = 204), (status = 404, body = crate::error::ErrorBody)))]
pub async fn destroy_group(
    State(state): State<AppState>,
    Path(label): Path<String>,
) -> Result<StatusCode, ApiError> {
    let groups = state.groups.clone();
    in_turn(&state, move || Ok(groups.destroy(&label)?)).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// AddFormula's body.
#[derive(Debug, Deserialize, Serialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct FormulaJson {
    /// The formula (MSTL).
    pub formula: String,
}

/// AddFormula: also while running (evaluated from the next state on).
#[utoipa::path(post, path = "/groups/{label}/formulas", tag = "groups",
    params(("label" = String, Path, description = "the group's label")),
    request_body = FormulaJson,
    responses((status = 201, body = Object), (status = 400, body = crate::error::ErrorBody),
              (status = 404, body = crate::error::ErrorBody), (status = 409, body = crate::error::ErrorBody),
              (status = 415, body = crate::error::ErrorBody), (status = 422, body = crate::error::ErrorBody)))]
pub async fn add_formula(
    State(state): State<AppState>,
    Path(label): Path<String>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let f: FormulaJson = json_body(&headers, &body)?;
    let groups = state.groups.clone();
    let index = in_turn(&state, move || Ok(groups.add_formula(&label, &f.formula)?)).await?;
    Ok((StatusCode::CREATED, Json(json!({"index": index}))).into_response())
}

/// RemoveFormula: also while running; indices are never reused.
#[utoipa::path(delete, path = "/groups/{label}/formulas/{index}", tag = "groups",
    params(("label" = String, Path, description = "the group's label"), ("index" = usize, Path, description = "the formula's index")),
    responses((status = 204), (status = 404, body = crate::error::ErrorBody)))]
pub async fn remove_formula(
    State(state): State<AppState>,
    Path((label, index)): Path<(String, String)>,
) -> Result<StatusCode, ApiError> {
    let index: usize = index
        .parse()
        .map_err(|_| ApiError::not_found(format!("no formula {index:?} (indices are integers)")))?;
    let groups = state.groups.clone();
    in_turn(&state, move || Ok(groups.remove_formula(&label, index)?)).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// `?since=<t>`.
#[derive(Debug, Deserialize)]
pub struct Since {
    /// Replay recorded verdicts with `t` at or after this first.
    pub since: Option<u64>,
}

/// Verdicts as Server-Sent Events (`event: verdict`, data `{"formula", "verdict", "t"}`);
/// `?since=<t>` replays the recorded ones from `t` on first.
#[utoipa::path(get, path = "/groups/{label}/verdicts", tag = "groups",
    params(("label" = String, Path, description = "the group's label"), ("since" = Option<u64>, Query, description = "replay recorded verdicts from this t on")),
    responses((status = 200, content_type = "text/event-stream", body = String), (status = 400, body = crate::error::ErrorBody), (status = 404, body = crate::error::ErrorBody)))]
pub async fn verdicts(
    State(state): State<AppState>,
    Path(label): Path<String>,
    query: Result<Query<Since>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(since) = query.map_err(|e| ApiError::bad_request(e.body_text()))?;
    // Times are milliseconds since the epoch; the API describes them as 64-bit signed integers.
    if let Some(t) = since.since.filter(|&t| i64::try_from(t).is_err()) {
        return Err(ApiError::bad_request(format!(
            "since={t} is beyond the largest time ({})",
            i64::MAX
        )));
    }
    let group = state.groups.get(&label)?;
    let (recorded, mut rx, mut stopped) = group.watch();
    let stream = async_stream_lite(move |tx| async move {
        let mut seen = BTreeSet::new();
        let event = |v: &dyknow_group::VerdictLine| {
            Event::default()
                .event("verdict")
                .data(serde_json::to_string(v).unwrap_or_default())
        };
        for v in &recorded {
            seen.insert(v.formula);
            if since.since.is_some_and(|s| v.t >= s)
                && tx.send(Ok::<_, Infallible>(event(v))).await.is_err()
            {
                return;
            }
        }
        // Verdicts until the group stops (or is destroyed): a stopped group's last verdicts
        // were sent before its flag was set, so they are drained, then the stream ends.
        let mut ending = false;
        loop {
            let next = if ending {
                match rx.try_recv() {
                    Ok(v) => Ok(v),
                    Err(tokio::sync::broadcast::error::TryRecvError::Lagged(n)) => {
                        Err(RecvError::Lagged(n))
                    }
                    Err(_) => return,
                }
            } else {
                tokio::select! {
                    biased;
                    next = rx.recv() => next,
                    _ = stopped.wait_for(|s| *s) => {
                        ending = true;
                        continue;
                    }
                }
            };
            match next {
                Ok(v) => {
                    if !seen.insert(v.formula) {
                        continue;
                    }
                    if tx.send(Ok(event(&v))).await.is_err() {
                        return;
                    }
                }
                Err(RecvError::Lagged(n)) => {
                    tracing::warn!("a verdict watcher of group {label} lagged by {n}");
                }
                Err(RecvError::Closed) => return,
            }
        }
    });
    Ok(Sse::new(stream)
        .keep_alive(KeepAlive::default())
        .into_response())
}

/// The synchronised state stream so far as a `dyknow check` trace (JSON lines: the header
/// with domains, landmarks and static regions, then one state per line).
#[utoipa::path(get, path = "/groups/{label}/trace", tag = "groups",
    params(("label" = String, Path, description = "the group's label")),
    responses((status = 200, content_type = "application/x-ndjson", body = String), (status = 404, body = crate::error::ErrorBody)))]
pub async fn trace(
    State(state): State<AppState>,
    Path(label): Path<String>,
) -> Result<Response, ApiError> {
    let groups = state.groups.clone();
    let text = in_turn(&state, move || Ok(groups.get(&label)?.trace(&groups)?)).await?;
    Ok(typed(StatusCode::OK, "application/x-ndjson", text))
}
