//! The executors and the CU services (`executors.md`, *CU services*): `GET /executors`,
//! `GET /cus/{name}` with the CU's executor, state and statistics.

use axum::Json;
use axum::Router;
use axum::extract::{Path, Query, State};
use axum::routing::get;
use dyknow_engine::Cid;
use dyknow_lifecycle::ExecutorSummary;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::app::{AppState, blocking, in_turn};
use crate::error::ApiError;
use crate::json_body::JsonBody;
use crate::routes::reconfig::{CuJson, cu_json};

/// The routes.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/executors", get(list_executors))
        .route("/cus/{name}/config", axum::routing::put(set_config))
}

/// An executor.
#[derive(Debug, Serialize, ToSchema)]
pub struct ExecutorJson {
    /// Its name.
    pub name: String,
    /// Whether its liveliness token is present.
    pub present: bool,
    /// The labels of the transformations it can run.
    pub transformations: Vec<String>,
    /// The CUs it hosts.
    pub cus: Vec<String>,
    /// The instance of the name the manager follows (`<start ms, 13 digits>-<Zenoh id>`,
    /// docs/executors.md); null while it is absent, or for an executor that does not say.
    pub instance: Option<String>,
}

impl From<ExecutorSummary> for ExecutorJson {
    fn from(e: ExecutorSummary) -> Self {
        Self {
            name: e.name,
            present: e.present,
            transformations: e.transformations,
            cus: e.cus,
            instance: e.instance.map(|i| i.to_string()),
        }
    }
}

/// The executors the service has seen (none in model-only mode): an absent one stays listed
/// for `serve --forget-executors-after` seconds (default 600).
#[utoipa::path(get, path = "/executors", tag = "executors", responses((status = 200, body = [ExecutorJson])))]
pub async fn list_executors(
    State(state): State<AppState>,
) -> Result<Json<Vec<ExecutorJson>>, ApiError> {
    let Some(fleet) = state.fleet.clone() else {
        return Ok(Json(Vec::new()));
    };
    let lifecycle = state.lifecycle.clone();
    let list = in_turn(&state, move || {
        let loaded = lifecycle.load()?;
        Ok(fleet.executors(&loaded.specs))
    })
    .await?;
    Ok(Json(list.into_iter().map(ExecutorJson::from).collect()))
}

/// SetConfig's body: ports to bind (a channel) or unbind (null); ports not named keep their
/// binding.
#[derive(Debug, serde::Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SetConfigJson {
    /// In port → channel or null.
    #[serde(default)]
    pub inputs: std::collections::BTreeMap<String, Option<String>>,
    /// Out port → channel or null.
    #[serde(default)]
    pub outputs: std::collections::BTreeMap<String, Option<String>>,
}

/// SetConfig: rebinds a CU's ports, recorded as a change set with cause `manual` and applied
/// make before break. 200 with the CU; 404 unknown CU; 422 unknown port, a channel another CU
/// publishes on, or a channel name that is not a key expression (nothing changed).
#[utoipa::path(put, path = "/cus/{name}/config", tag = "reconfiguration",
    params(("name" = String, Path, description = "the CU's name")),
    request_body = SetConfigJson,
    responses((status = 200, body = CuJson), (status = 404, body = crate::error::ErrorBody),
              (status = 422, body = crate::error::ErrorBody)))]
pub async fn set_config(
    State(state): State<AppState>,
    Path(name): Path<String>,
    JsonBody(body): JsonBody<SetConfigJson>,
) -> Result<Json<CuJson>, ApiError> {
    let s = state.clone();
    blocking(move || {
        let channels = |m: std::collections::BTreeMap<String, Option<String>>| {
            m.into_iter()
                .map(|(p, c)| (p, c.map(dyknow_engine::Channel::from)))
                .collect()
        };
        let cu = s.lifecycle.set_config(
            &name.as_str().into(),
            &channels(body.inputs),
            &channels(body.outputs),
        )?;
        let env = s.lifecycle.cus()?;
        Ok(Json(crate::routes::reconfig::one_cu_json(&s, &cu, &env)))
    })
    .await
}

/// A CU with what its executor says of it (GetConfig + GetStatistics).
#[derive(Debug, Serialize, ToSchema)]
pub struct CuDetailJson {
    /// The CU as `GET /cus` lists it, with its executor and state.
    #[serde(flatten)]
    pub cu: CuJson,
    /// `{"uptime_ms", "reconfigurations", "cpu_ms", "ports": {"<port>": {"messages", "bytes", "last_t"}}}`.
    #[schema(value_type = Object)]
    pub statistics: serde_json::Value,
    /// The process id of a process CU.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pid: Option<u32>,
}

/// `GET /cus/{name}` takes no query parameter: one is 400, as on `GET /cus` (a client asking
/// `?statistics=true` here, where statistics always come, learns it at once).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoQuery {}

/// One computation unit, with its executor, state and statistics.
#[utoipa::path(get, path = "/cus/{name}", tag = "reconfiguration",
    params(("name" = String, Path, description = "the CU's name")),
    responses((status = 200, body = CuDetailJson), (status = 400, body = crate::error::ErrorBody),
              (status = 404, body = crate::error::ErrorBody)))]
pub async fn get_cu(
    State(state): State<AppState>,
    Path(name): Path<String>,
    query: Result<Query<NoQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<CuDetailJson>, ApiError> {
    query.map_err(|e| ApiError::bad_request(e.body_text()))?;
    let s = state.clone();
    blocking(move || {
        let env = s.lifecycle.cus()?;
        let Some(cu) = env.cus.get(&Cid::from(name.as_str())) else {
            return Err(ApiError::not_found(format!(
                "no computation unit named {name:?}"
            )));
        };
        let view = s.lifecycle.describe(&cu.cid);
        Ok(Json(cu_detail(cu, &env, view.as_ref())))
    })
    .await
}

/// A CU of `env` with what its executor said of it (`view`; zero statistics when none did).
pub(crate) fn cu_detail(
    cu: &dyknow_engine::ComputationUnit,
    env: &dyknow_engine::Environment,
    view: Option<&dyknow_lifecycle::CuView>,
) -> CuDetailJson {
    let (statistics, pid) = match view {
        Some(view) => (view.statistics.clone(), view.pid),
        None => (
            serde_json::json!({
                "uptime_ms": 0, "reconfigurations": 0, "cpu_ms": 0.0, "ports": {}
            }),
            None,
        ),
    };
    CuDetailJson {
        cu: cu_json(cu, env, view),
        statistics,
        pid,
    }
}
