//! Reconfiguration (contract `http-api.md`): computation units (Spawn, Destroy), change sets
//! (+ a Server-Sent Events stream), perturbations, statistics, reviews, the environment.

use std::collections::BTreeMap;
use std::convert::Infallible;

use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use dyknow_engine::{ChangeSet, ChangeSetId, Cid, ComputationUnit, Invalidity};
use dyknow_lifecycle::{CuView, Observation, Perturbation, Phase, SpawnRequest};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::app::{AppState, blocking, in_turn, typed};
use crate::error::ApiError;
use crate::json_body::{JsonBody, JsonObject};
use crate::negotiate::negotiate;

pub(crate) fn router() -> Router<AppState> {
    Router::new()
        .route("/cus", get(list_cus).post(spawn_cu))
        .route(
            "/cus/{name}",
            get(crate::routes::executors::get_cu).delete(destroy_cu),
        )
        .route("/changesets", get(list_change_sets))
        .route("/changesets/stream", get(change_set_stream))
        .route("/changesets/{id}", get(get_change_set))
        .route("/perturbations", post(post_perturbation))
        .route("/statistics", get(get_statistics).post(post_statistics))
        .route("/review", post(post_review))
        .route("/environment", get(get_environment))
}

/// A computation unit.
#[derive(Debug, Serialize, ToSchema)]
pub struct CuJson {
    /// Its name.
    pub name: String,
    /// The label of its transformation.
    pub transformation: String,
    /// In port → channel (null when unbound).
    pub inputs: BTreeMap<String, Option<String>>,
    /// Out port → channel (null when unbound).
    pub outputs: BTreeMap<String, Option<String>>,
    /// Protected CUs are never destroyed by a change set.
    pub protected: bool,
    /// The upkeep estimate of one time unit (learned, or the spec's).
    pub upkeep: f64,
    /// The executor hosting it (null in model-only mode, or when no executor hosts it).
    pub executor: Option<String>,
    /// `starting`, `running`, `crashed`, `stopped`, or `model` in model-only mode.
    pub state: String,
}

/// The JSON of a CU, with the upkeep estimate of its transformation in `env` and what the
/// running system says of it (`None` in model-only mode).
pub(crate) fn cu_json(
    cu: &ComputationUnit,
    env: &dyknow_engine::Environment,
    view: Option<&CuView>,
) -> CuJson {
    let channels = |ports: &BTreeMap<String, Option<dyknow_engine::Channel>>| {
        ports
            .iter()
            .map(|(p, c)| (p.clone(), c.as_ref().map(ToString::to_string)))
            .collect()
    };
    CuJson {
        name: cu.cid.to_string(),
        transformation: cu.tid.to_string(),
        inputs: channels(&cu.inputs),
        outputs: channels(&cu.outputs),
        protected: cu.protected,
        upkeep: env.library.get(&cu.tid).map_or(0.0, |t| t.upkeep),
        executor: view.and_then(|v| v.executor.clone()),
        state: view.map_or_else(|| "model".to_owned(), |v| v.state.clone()),
    }
}

/// The computation units of `env`, sorted by name, with where and how they run as the
/// manager last heard it (no executor is asked: a read never waits behind a change set being
/// applied).
pub(crate) fn cus_json(state: &AppState, env: &dyknow_engine::Environment) -> Vec<CuJson> {
    let names: Vec<Cid> = env.cus.keys().cloned().collect();
    let views = state.lifecycle.last_heard(&names);
    env.cus
        .values()
        .map(|cu| cu_json(cu, env, views.get(&cu.cid)))
        .collect()
}

/// One CU of `env` as [`cus_json`] gives it.
pub(crate) fn one_cu_json(
    state: &AppState,
    cu: &ComputationUnit,
    env: &dyknow_engine::Environment,
) -> CuJson {
    cu_json(cu, env, state.lifecycle.describe(&cu.cid).as_ref())
}

/// The computation units, sorted by name (`GET /cus`).
pub(crate) fn cus(state: &AppState) -> Result<Vec<CuJson>, ApiError> {
    Ok(cus_json(state, &state.lifecycle.cus()?))
}

/// `GET /cus`'s query.
#[derive(Debug, Default, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct CusQuery {
    /// With `true`, every CU carries its `statistics` and `pid` as `GET /cus/{name}` gives
    /// them (one question per executor, as without it): the web view's one poll.
    #[serde(default)]
    pub statistics: bool,
}

/// The computation units, sorted by name; `?statistics=true` adds each one's statistics.
#[utoipa::path(get, path = "/cus", tag = "reconfiguration", params(CusQuery),
    responses((status = 200, body = [CuJson]), (status = 400, body = crate::error::ErrorBody)))]
pub async fn list_cus(
    State(state): State<AppState>,
    query: Result<Query<CusQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) = query.map_err(|e| ApiError::bad_request(e.body_text()))?;
    if !query.statistics {
        // Nothing written since the CUs were last published: answered from memory, on the
        // runtime's thread. Otherwise read without a turn as well: one reader at a time
        // refreshes the snapshot, the others get the last one at once (`SpecCache::cus_now`).
        if let Some(env) = state.lifecycle.cus_published() {
            return Ok(Json(cus_json(&state, &env)).into_response());
        }
        let s = state.clone();
        return Ok(Json(blocking(move || cus(&s)).await?).into_response());
    }
    let s = state.clone();
    let detailed = blocking(move || {
        let env = s.lifecycle.cus()?;
        let names: Vec<Cid> = env.cus.keys().cloned().collect();
        let views = s.lifecycle.describe_all(&names);
        Ok(env
            .cus
            .values()
            .map(|cu| crate::routes::executors::cu_detail(cu, &env, views.get(&cu.cid)))
            .collect::<Vec<_>>())
    })
    .await?;
    Ok(Json(detailed).into_response())
}

/// The Spawn call's body.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SpawnJson {
    /// The transformation to instantiate.
    pub transformation: String,
    /// The CU's name (a fresh `cu-N` when absent).
    pub name: Option<String>,
    /// Whether change sets may destroy it.
    #[serde(default)]
    pub protected: bool,
}

/// Spawn: a CU of a transformation, ports unbound. Reviews may wire it (or destroy it, unless
/// protected).
#[utoipa::path(post, path = "/cus", tag = "reconfiguration", request_body = SpawnJson,
    responses((status = 201, body = CuJson), (status = 404, body = crate::error::ErrorBody),
              (status = 409, body = crate::error::ErrorBody), (status = 422, body = crate::error::ErrorBody)))]
pub async fn spawn_cu(
    State(state): State<AppState>,
    JsonBody(body): JsonBody<SpawnJson>,
) -> Result<Response, ApiError> {
    let s = state.clone();
    // Life-cycle calls take no turn: they wait for the configuration lock (a review holds it
    // through its search and its application by the executors) and must not keep the store's
    // turns from reads and writes meanwhile.
    let cu = blocking(move || {
        let cu = s.lifecycle.spawn(SpawnRequest {
            transformation: body.transformation.into(),
            name: body.name.map(Into::into),
            protected: body.protected,
        })?;
        Ok(one_cu_json(&s, &cu, &s.lifecycle.cus()?))
    })
    .await?;
    Ok((StatusCode::CREATED, Json(cu)).into_response())
}

/// Destroy: removes a CU (409 if protected). A perturbation: a review starts at once.
#[utoipa::path(delete, path = "/cus/{name}", tag = "reconfiguration",
    params(("name" = String, Path, description = "the CU's name")),
    responses((status = 204), (status = 404, body = crate::error::ErrorBody), (status = 409, body = crate::error::ErrorBody)))]
pub async fn destroy_cu(
    State(state): State<AppState>,
    Path(name): Path<String>,
) -> Result<StatusCode, ApiError> {
    let s = state.clone();
    blocking(move || Ok(s.lifecycle.destroy(&name.into())?)).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// `?since=`.
#[derive(Debug, Deserialize)]
pub struct Since {
    since: Option<String>,
}

/// The change sets, oldest first (`?since=<id>`: those after it).
#[utoipa::path(get, path = "/changesets", tag = "reconfiguration",
    params(("since" = Option<String>, Query, description = "only change sets after this id")),
    responses((status = 200, description = "change set JSON list (see docs/cli.md)"), (status = 400, body = crate::error::ErrorBody)))]
pub async fn list_change_sets(State(state): State<AppState>, Query(q): Query<Since>) -> Response {
    // Change set ids are `cs-N`: anything else is a mistake, not "from the start".
    if let Some(since) = q
        .since
        .as_deref()
        .filter(|s| ChangeSetId::new(*s).number().is_none())
    {
        return ApiError::bad_request(format!("since={since:?} is not a change set id (cs-N)"))
            .into_response();
    }
    let change_sets = state.lifecycle.change_sets(q.since.as_deref());
    Json(
        change_sets
            .iter()
            .map(|cs| &**cs)
            .collect::<Vec<&ChangeSet>>(),
    )
    .into_response()
}

/// One change set; `Accept: application/n-triples` or `text/turtle` gives its RDF delta.
#[utoipa::path(get, path = "/changesets/{id}", tag = "reconfiguration",
    params(("id" = String, Path, description = "cs-N")),
    responses((status = 200, description = "change set JSON, or its delta as RDF (`docs/http-api.md`)",
                content((serde_json::Value = "application/json"), (String = "application/n-triples"), (String = "text/turtle"))),
              (status = 404, body = crate::error::ErrorBody)))]
pub async fn get_change_set(
    State(state): State<AppState>,
    headers: HeaderMap,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let media = negotiate(
        &headers,
        &["application/json", "application/n-triples", "text/turtle"],
    )?;
    let cs = state
        .lifecycle
        .change_set(&id)
        .ok_or_else(|| ApiError::not_found(format!("no change set {id:?}")))?;
    if media == "application/json" {
        return Ok(Json(&*cs).into_response());
    }
    // The delta as RDF: the inserted triples, and the deleted ones in a comment block (N-Triples
    // and Turtle have no syntax for removals).
    let deleted: String = cs
        .delta
        .delete
        .lines()
        .map(|l| format!("# delete: {l}\n"))
        .collect();
    Ok(typed(
        StatusCode::OK,
        media,
        format!("{deleted}{}", cs.delta.insert),
    ))
}

/// Server-Sent Events: one `changeset` event per new change set.
#[utoipa::path(get, path = "/changesets/stream", tag = "reconfiguration",
    responses((status = 200, content_type = "text/event-stream", description = "changeset events")))]
pub async fn change_set_stream(
    State(state): State<AppState>,
) -> Sse<impl futures_core::Stream<Item = Result<Event, Infallible>>> {
    let mut rx = state.lifecycle.subscribe();
    let stream = async_stream_lite(move |tx| async move {
        loop {
            match rx.recv().await {
                Ok(cs) => {
                    let Ok(json) = serde_json::to_string(&*cs) else {
                        continue;
                    };
                    let event = Event::default().event("changeset").data(json);
                    if tx.send(Ok(event)).await.is_err() {
                        return;
                    }
                }
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(tokio::sync::broadcast::error::RecvError::Closed) => return,
            }
        }
    });
    Sse::new(stream).keep_alive(KeepAlive::default())
}

/// A stream fed by a task through a channel.
pub(crate) fn async_stream_lite<F, Fut>(
    f: F,
) -> impl futures_core::Stream<Item = Result<Event, Infallible>>
where
    F: FnOnce(tokio::sync::mpsc::Sender<Result<Event, Infallible>>) -> Fut,
    Fut: std::future::Future<Output = ()> + Send + 'static,
{
    let (tx, rx) = tokio::sync::mpsc::channel(16);
    tokio::spawn(f(tx));
    tokio_stream_lite::ReceiverStream(rx)
}

mod tokio_stream_lite {
    use std::pin::Pin;
    use std::task::{Context, Poll};

    /// A `Stream` over an mpsc receiver.
    pub struct ReceiverStream<T>(pub tokio::sync::mpsc::Receiver<T>);

    impl<T> futures_core::Stream for ReceiverStream<T> {
        type Item = T;
        fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<T>> {
            self.0.poll_recv(cx)
        }
    }
}

/// A perturbation report: `{"kind": "cu-crashed", "cu": "<name>"}`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PerturbationJson {
    /// The kind: `cu-crashed` is the one clients report (the others are the service's own:
    /// 422).
    pub kind: PerturbationKind,
    /// The CU.
    pub cu: String,
}

/// The perturbation kinds clients report.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(rename_all = "kebab-case")]
pub enum PerturbationKind {
    /// A CU crashed: it is removed from the model and a review starts at once.
    CuCrashed,
}

/// A perturbation: `{"kind": "cu-crashed", "cu": "<name>"}` removes the CU from the model and
/// starts a review at once. 202.
#[utoipa::path(post, path = "/perturbations", tag = "reconfiguration", request_body = PerturbationJson,
    responses((status = 202), (status = 400, body = crate::error::ErrorBody), (status = 404, body = crate::error::ErrorBody), (status = 422, body = crate::error::ErrorBody)))]
pub async fn post_perturbation(
    State(state): State<AppState>,
    body: JsonObject,
) -> Result<StatusCode, ApiError> {
    let kind = body
        .value
        .get("kind")
        .and_then(serde_json::Value::as_str)
        .unwrap_or_default();
    if !kind.is_empty() && !Perturbation::KINDS.contains(&kind) {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("unknown perturbation kind {kind:?} (known: cu-crashed)"),
        ));
    }
    if !kind.is_empty() && !Perturbation::EXTERNAL_KINDS.contains(&kind) {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!(
                "perturbations of kind {kind:?} are the service's own (known from outside: cu-crashed)"
            ),
        ));
    }
    let perturbation: Perturbation = body.read()?;
    let s = state.clone();
    blocking(move || Ok(s.lifecycle.report(perturbation)?)).await?;
    Ok(StatusCode::ACCEPTED)
}

/// Observed costs.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StatisticsJson {
    /// A CU whose upkeep was observed.
    pub cu: Option<String>,
    /// The upkeep observed for one time unit.
    pub upkeep: Option<f64>,
    /// A transformation whose labour was observed.
    pub transformation: Option<String>,
    /// The labour observed for one spawn.
    pub labour: Option<f64>,
}

/// `POST /statistics`'s body as the OpenAPI description gives it: one of two shapes.
#[derive(ToSchema)]
#[serde(untagged)]
#[allow(dead_code, reason = "the schema of the body only")]
pub enum ObservationJson {
    /// The upkeep of a CU observed for one time unit.
    #[serde(deny_unknown_fields)]
    Upkeep {
        /// The CU (404 if absent).
        cu: String,
        /// Finite and not negative (422 otherwise).
        #[schema(minimum = 0.0)]
        upkeep: f64,
    },
    /// The labour of one spawn of a transformation.
    #[serde(deny_unknown_fields)]
    Labour {
        /// The transformation (404 if absent).
        transformation: String,
        /// Finite and not negative (422 otherwise).
        #[schema(minimum = 0.0)]
        labour: f64,
    },
}

/// Statistics: `{"cu", "upkeep"}` or `{"transformation", "labour"}` update the historical
/// averages per transformation (seed Ch. 5.3.2). Does not start a review. 202.
#[utoipa::path(post, path = "/statistics", tag = "reconfiguration", request_body = ObservationJson,
    responses((status = 202), (status = 400, body = crate::error::ErrorBody), (status = 404, body = crate::error::ErrorBody), (status = 422, body = crate::error::ErrorBody)))]
pub async fn post_statistics(
    State(state): State<AppState>,
    JsonBody(body): JsonBody<StatisticsJson>,
) -> Result<StatusCode, ApiError> {
    let observation = match body {
        StatisticsJson {
            cu: Some(cu),
            upkeep: Some(value),
            transformation: None,
            labour: None,
        } => Observation::Upkeep {
            cu: cu.into(),
            value,
        },
        StatisticsJson {
            cu: None,
            upkeep: None,
            transformation: Some(t),
            labour: Some(value),
        } => Observation::Labour {
            transformation: t.into(),
            value,
        },
        _ => {
            return Err(ApiError::bad_request(
                "give {\"cu\", \"upkeep\"} or {\"transformation\", \"labour\"}",
            ));
        }
    };
    let s = state.clone();
    blocking(move || Ok(s.lifecycle.observe(observation)?)).await?;
    Ok(StatusCode::ACCEPTED)
}

/// One learned estimate.
#[derive(Debug, Serialize, ToSchema)]
pub struct EstimateJson {
    /// The historical average of the observations (seed Eqs. 5.8–5.9).
    pub average: f64,
    /// How many observations it averages.
    pub observations: u64,
}

/// The estimates of one transformation: what the next review uses.
#[derive(Debug, Serialize, ToSchema)]
pub struct TransformationStatisticsJson {
    /// The labour estimate in use (learned, or the spec's).
    pub labour: f64,
    /// The upkeep estimate in use per time unit (learned, or the spec's).
    pub upkeep: f64,
    /// The learned labour, if anything was observed.
    pub learned_labour: Option<EstimateJson>,
    /// The learned upkeep, if anything was observed.
    pub learned_upkeep: Option<EstimateJson>,
}

/// The cost statistics (seed Ch. 5.3.2).
#[derive(Debug, Serialize, ToSchema)]
pub struct StatisticsListJson {
    /// The unit of the estimates.
    pub unit: String,
    /// The length of one time unit, in seconds.
    pub time_unit_seconds: f64,
    /// By transformation label.
    pub transformations: BTreeMap<String, TransformationStatisticsJson>,
}

/// The cost estimates per transformation: learned from the executors' measurements (CPU
/// milliseconds) and `POST /statistics`, or the specs' own.
#[utoipa::path(get, path = "/statistics", tag = "reconfiguration", responses((status = 200, body = StatisticsListJson)))]
pub async fn get_statistics(
    State(state): State<AppState>,
) -> Result<Json<StatisticsListJson>, ApiError> {
    let s = state.clone();
    in_turn(&state, move || {
        let learned = s.lifecycle.learned();
        let loaded = s.lifecycle.load()?;
        let estimate = |e: Option<&dyknow_engine::Estimate>| {
            e.map(|e| EstimateJson {
                average: e.average,
                observations: e.count,
            })
        };
        let transformations = loaded
            .specs
            .keys()
            .map(|tid| {
                let (labour, upkeep) = loaded.env.library.get(tid).map_or_else(
                    || {
                        let spec = &loaded.specs[tid];
                        (spec.labour, spec.upkeep)
                    },
                    |t| (t.labour, t.upkeep),
                );
                (
                    tid.to_string(),
                    TransformationStatisticsJson {
                        labour: learned.labour.get(tid).map_or(labour, |e| e.average),
                        upkeep: learned.upkeep.get(tid).map_or(upkeep, |e| e.average),
                        learned_labour: estimate(learned.labour.get(tid)),
                        learned_upkeep: estimate(learned.upkeep.get(tid)),
                    },
                )
            })
            .collect();
        Ok(Json(StatisticsListJson {
            unit: if s.fleet.is_some() {
                "CPU milliseconds as the executors measure them (labour per spawn, upkeep per time unit); posted observations and spec estimates in their own unit".into()
            } else {
                "as posted (model-only mode: nothing is measured)".into()
            },
            time_unit_seconds: s.lifecycle.settings().time_unit.as_secs_f64(),
            transformations,
        }))
    })
    .await
}

/// Starts a review interval now. 202.
#[utoipa::path(post, path = "/review", tag = "reconfiguration", responses((status = 202)))]
pub async fn post_review(State(state): State<AppState>) -> Result<StatusCode, ApiError> {
    state.lifecycle.report(Perturbation::ReviewRequested)?;
    Ok(StatusCode::ACCEPTED)
}

/// The environment's cost.
#[derive(Debug, Serialize, ToSchema)]
pub struct EnvironmentCostJson {
    /// The upkeep of one time unit.
    pub upkeep_per_time_unit: f64,
    /// The horizon H.
    pub horizon: f64,
}

/// The state of the environment and of the life-cycle.
#[derive(Debug, Serialize, ToSchema)]
pub struct EnvironmentJson {
    /// Whether the environment is valid (Def. 33, plus acyclicity).
    pub valid: bool,
    /// The targets no CU satisfies now.
    pub unsatisfied_targets: Vec<String>,
    /// Its cost.
    pub cost: EnvironmentCostJson,
    /// `stable` or `review`.
    #[schema(value_type = String)]
    pub phase: Phase,
    /// When the next scheduled review starts (RFC 3339).
    pub next_review_at: String,
    /// A review is due at once (queued behind a running one, or about to start).
    pub review_pending: bool,
    /// Reviews completed since the service started.
    pub reviews: u64,
    /// CU crashes recorded since the service started (each one a perturbation).
    pub crashes: u64,
    /// Why the last review failed (its change set was not applied), if it did.
    pub last_review_error: Option<String>,
    /// Every reason the environment is invalid.
    #[schema(value_type = Vec<Object>)]
    pub invalidities: Vec<Invalidity>,
}

/// The environment: validity, unsatisfied targets, cost, life-cycle phase.
#[utoipa::path(get, path = "/environment", tag = "reconfiguration", responses((status = 200, body = EnvironmentJson)))]
pub async fn get_environment(
    State(state): State<AppState>,
) -> Result<Json<EnvironmentJson>, ApiError> {
    // The life-cycle's state first: the environment read after it is at least as new, so a
    // client that sees a review counted also sees its change set applied.
    let life = state.lifecycle.status();
    let s = state.clone();
    // Never waits for a review or spec write under way (the last published snapshot then).
    let loaded = in_turn(&state, move || Ok(s.lifecycle.load_now()?)).await?;
    let horizon = state.lifecycle.settings().horizon;
    let invalidities = loaded.env.invalidities(&loaded.candidates);
    let unsatisfied_targets = invalidities
        .iter()
        .filter_map(|i| match i {
            Invalidity::UnsatisfiedTarget { target } => Some(target.to_string()),
            _ => None,
        })
        .collect();
    Ok(Json(EnvironmentJson {
        valid: invalidities.is_empty(),
        unsatisfied_targets,
        cost: EnvironmentCostJson {
            upkeep_per_time_unit: loaded.env.upkeep(),
            horizon,
        },
        phase: life.phase,
        next_review_at: dyknow_engine::rfc3339(life.next_review_at),
        review_pending: life.review_pending,
        reviews: life.reviews,
        crashes: life.crashes,
        last_review_error: life.last_error,
        invalidities,
    }))
}
