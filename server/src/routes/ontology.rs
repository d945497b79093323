//! Ontology extensions: tag vocabularies, sub-concepts, `dyknow:similarTo`, domain classes.

use axum::body::Bytes;
use axum::extract::{RawQuery, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::app::{AppState, in_turn};
use crate::error::{ApiError, ErrorBody};
use crate::routes::sparql::decode_strictly;
use crate::routes::specs::input_format;

pub(crate) fn router() -> Router<AppState> {
    Router::new().route(
        "/ontology",
        get(list_extensions)
            .post(post_extension)
            .delete(delete_extension),
    )
}

/// The answer to an extension POST.
#[derive(Debug, Serialize, ToSchema)]
pub struct ExtensionPostedJson {
    /// The named graph holding the extension (named after its content: re-posting replaces it).
    pub graph: String,
    /// Whether the same extension was there already.
    pub replaced: bool,
}

/// An ontology extension in the model.
#[derive(Debug, Serialize, ToSchema)]
pub struct ExtensionJson {
    /// Its named graph.
    pub graph: String,
    /// The `owl:Ontology` it declares, if any.
    pub ontology: Option<String>,
    /// How many triples it holds.
    pub triples: usize,
}

/// The `graph` query parameter of DELETE.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
pub struct GraphParam {
    /// The graph to remove (400 without it).
    #[param(required = true)]
    pub graph: Option<String>,
}

/// Posts an ontology extension (Turtle, N-Triples or JSON-LD).
#[utoipa::path(post, path = "/ontology", tag = "ontology",
    request_body(description = "An ontology extension as RDF. A schema cannot state RDF's grammar: a syntax error is 400 (with its line and column); an empty extension, or one that holds specs or contradicts the ontology, is 422.",
        content((String = "text/turtle"), (String = "application/n-triples"), (serde_json::Value = "application/ld+json"))),
    responses((status = 201, body = ExtensionPostedJson), (status = 400, body = ErrorBody),
              (status = 415, body = ErrorBody), (status = 422, body = ErrorBody)))]
pub async fn post_extension(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let format = input_format(&headers)?;
    let kb = state.kb.clone();
    let report = in_turn(&state, move || Ok(kb.post_extension(&body, format)?)).await?;
    Ok((
        StatusCode::CREATED,
        Json(ExtensionPostedJson {
            graph: report.graph,
            replaced: report.replaced,
        }),
    )
        .into_response())
}

/// Lists the ontology extensions.
#[utoipa::path(get, path = "/ontology", tag = "ontology",
    responses((status = 200, body = [ExtensionJson])))]
pub async fn list_extensions(
    State(state): State<AppState>,
) -> Result<Json<Vec<ExtensionJson>>, ApiError> {
    let kb = state.kb.clone();
    let list = in_turn(&state, move || Ok(kb.extensions()?)).await?;
    Ok(Json(
        list.into_iter()
            .map(|e| ExtensionJson {
                graph: e.graph,
                ontology: e.ontology,
                triples: e.triples,
            })
            .collect(),
    ))
}

/// Removes an ontology extension.
#[utoipa::path(delete, path = "/ontology", tag = "ontology", params(GraphParam),
    responses((status = 204), (status = 400, body = ErrorBody), (status = 404, body = ErrorBody), (status = 409, body = ErrorBody)))]
pub async fn delete_extension(
    State(state): State<AppState>,
    RawQuery(raw): RawQuery,
) -> Result<StatusCode, ApiError> {
    let graph = graph_param(raw.as_deref().unwrap_or_default())?
        .ok_or_else(|| ApiError::bad_request("DELETE /ontology needs ?graph=<iri>"))?;
    let kb = state.kb.clone();
    in_turn(&state, move || Ok(kb.remove_extension(&graph)?)).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// The `graph` parameter of a query string, decoded strictly: `%FF` is no character (form
/// decoding made it U+FFFD, and the answer a 404 for a graph nobody named), a second `graph`
/// is refused, and the value must be an IRI (`not an iri` was a 404 too: a user audit).
/// (Other parameters are refused before: `known_parameters`.)
fn graph_param(raw: &str) -> Result<Option<String>, ApiError> {
    let mut graph = None;
    for pair in raw.split('&').filter(|p| !p.is_empty()) {
        let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
        if decode_strictly(key)? != "graph" {
            continue;
        }
        if graph.replace(decode_strictly(value)?).is_some() {
            return Err(ApiError::bad_request(
                "more than one \"graph\" parameter: a request removes one extension",
            ));
        }
    }
    if let Some(g) = &graph {
        oxigraph::model::NamedNode::new(g.as_str())
            .map_err(|e| ApiError::bad_request(format!("graph {g:?} is not an IRI: {e}")))?;
    }
    Ok(graph)
}
