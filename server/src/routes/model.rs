//! GetModel (seed Ch. 5.3): the ontology and the environment, for other agents.

use std::collections::BTreeMap;

use axum::extract::{Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode};
use axum::response::Response;
use axum::routing::get;
use axum::{Json, Router};
use dyknow_engine::Cid;
use dyknow_lifecycle::CuView;
use dyknow_store::spec::SpecKind;
use dyknow_store::{KnowledgeBase, ModelFormat};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::app::{AppState, in_turn, typed};
use crate::error::{ApiError, ErrorBody};
use crate::negotiate::negotiate;
use crate::routes::reconfig::{CuJson, cu_json};
use crate::routes::specs::spec_json;

pub(crate) fn router() -> Router<AppState> {
    Router::new().route("/model", get(get_model))
}

/// Parameters of GetModel.
#[derive(Debug, Default, Deserialize, utoipa::IntoParams)]
pub struct ModelParams {
    /// `turtle`, `rdfxml`, `owx`, `ofn`, `ntriples`, `jsonld` or `dyknow`; overrides `Accept`.
    #[param(value_type = Option<ModelFormatName>)]
    pub format: Option<String>,
    /// `false` leaves out inferred triples.
    pub inferred: Option<bool>,
}

/// The names `?format=` accepts (the schema of the parameter; anything else is 400).
#[derive(ToSchema)]
#[serde(rename_all = "lowercase")]
#[allow(dead_code, reason = "the schema of the parameter only")]
pub enum ModelFormatName {
    /// `text/turtle`.
    Turtle,
    /// `application/rdf+xml`.
    Rdfxml,
    /// `application/owl+xml`.
    Owx,
    /// `text/owl-functional`.
    Ofn,
    /// `application/n-triples`.
    Ntriples,
    /// `application/ld+json`.
    Jsonld,
    /// `application/json`.
    Dyknow,
}

/// A channel of the model.
#[derive(Debug, Serialize, ToSchema)]
pub struct ChannelJson {
    /// The channel's name.
    pub name: String,
    /// Targets that want a stream on it.
    pub targets: Vec<String>,
    /// The CU publishing on it, if any.
    pub producer: Option<String>,
    /// The CUs subscribed to it.
    pub subscribers: Vec<String>,
}

/// The DyKnow JSON form of the model.
#[derive(Debug, Serialize, ToSchema)]
pub struct ModelJson {
    /// Transformation specs (as `GET /transformations`).
    pub transformations: Vec<serde_json::Value>,
    /// Target specs (as `GET /targets`).
    pub targets: Vec<serde_json::Value>,
    /// Computation units (as `GET /cus`).
    pub cus: Vec<CuJson>,
    /// Channels.
    pub channels: Vec<ChannelJson>,
}

pub(crate) const OFFERS: [&str; 7] = [
    "text/turtle",
    "application/rdf+xml",
    "application/owl+xml",
    "text/owl-functional",
    "application/n-triples",
    "application/ld+json",
    "application/json",
];

/// Builds the DyKnow JSON model.
pub fn model_json(
    kb: &KnowledgeBase,
    runnable: &dyn Fn(&dyknow_store::spec::TransformationSpec) -> Result<(), String>,
    describe: &dyn Fn(&[Cid]) -> BTreeMap<Cid, CuView>,
) -> Result<ModelJson, ApiError> {
    let loaded = dyknow_store::model::load(kb)?;
    let names: Vec<Cid> = loaded.env.cus.keys().cloned().collect();
    let views = describe(&names);
    let unsatisfied = super::specs::unsatisfied_targets(&loaded);
    // Every channel of the model: those targets name and those CUs are bound to.
    let mut by_name: BTreeMap<String, ChannelJson> = BTreeMap::new();
    fn channel<'a>(
        by_name: &'a mut BTreeMap<String, ChannelJson>,
        name: &str,
    ) -> &'a mut ChannelJson {
        by_name
            .entry(name.to_owned())
            .or_insert_with(|| ChannelJson {
                name: name.to_owned(),
                targets: Vec::new(),
                producer: None,
                subscribers: Vec::new(),
            })
    }
    for (name, targets) in kb.channels()? {
        channel(&mut by_name, &name).targets = targets;
    }
    for cu in loaded.env.cus.values() {
        for bound in cu.inputs.values().flatten() {
            let subscribers = &mut channel(&mut by_name, bound.as_str()).subscribers;
            if !subscribers.contains(&cu.cid.to_string()) {
                subscribers.push(cu.cid.to_string());
            }
        }
    }
    for (name, publishers) in loaded.env.publishers() {
        // The first by name if, invalidly, several publish.
        channel(&mut by_name, name).producer =
            publishers.iter().map(|(c, _)| (*c).to_owned()).min();
    }
    let channels: Vec<ChannelJson> = by_name.into_values().collect();
    Ok(ModelJson {
        transformations: kb
            .specs(SpecKind::Transformation)?
            .into_iter()
            .map(|s| spec_json(kb, runnable, &unsatisfied, s))
            .collect::<Result<_, _>>()?,
        targets: kb
            .specs(SpecKind::Target)?
            .into_iter()
            .map(|s| spec_json(kb, runnable, &unsatisfied, s))
            .collect::<Result<_, _>>()?,
        cus: loaded
            .env
            .cus
            .values()
            .map(|cu| cu_json(cu, &loaded.env, views.get(&cu.cid)))
            .collect(),
        channels,
    })
}

/// GetModel: negotiated by `Accept` or `?format=`.
#[utoipa::path(get, path = "/model", tag = "model", params(ModelParams),
    responses((status = 200, description = "the model in the negotiated format",
                content((String = "text/turtle"), (String = "application/rdf+xml"), (String = "application/owl+xml"),
                        (String = "text/owl-functional"), (String = "application/n-triples"), (serde_json::Value = "application/ld+json"),
                        (ModelJson = "application/json"))),
              (status = 400, body = ErrorBody), (status = 406, body = ErrorBody)))]
pub async fn get_model(
    State(state): State<AppState>,
    headers: HeaderMap,
    Query(params): Query<ModelParams>,
) -> Result<Response, ApiError> {
    let format = match params.format.as_deref() {
        Some("dyknow" | "json") => None,
        Some(name) => Some(ModelFormat::from_name(name).ok_or_else(|| {
            ApiError::bad_request(format!(
                "unknown format {name:?}; use turtle, rdfxml, owx, ofn, ntriples, jsonld or dyknow"
            ))
        })?),
        None => match negotiate(&headers, &OFFERS)? {
            "application/json" => None,
            media => ModelFormat::ALL
                .into_iter()
                .find(|f| f.media_type() == media),
        },
    };
    let inferred = params.inferred.unwrap_or(true);
    let kb = state.kb.clone();
    let Some(format) = format else {
        let lifecycle = state.lifecycle.clone();
        let json = in_turn(&state, move || {
            model_json(&kb, &|t| lifecycle.runnable(t), &|c| {
                lifecycle.last_heard(c)
            })
        })
        .await?;
        return Ok(axum::response::IntoResponse::into_response(Json(json)));
    };
    let exported = in_turn(&state, move || Ok(kb.export(format, inferred)?)).await?;
    let mut response = typed(StatusCode::OK, format.media_type(), exported.body);
    if let Ok(v) = HeaderValue::from_str(&exported.unparsed_triples.to_string()) {
        response
            .headers_mut()
            .insert("x-dyknow-unparsed-triples", v);
    }
    Ok(response)
}
