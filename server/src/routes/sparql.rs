//! The SPARQL 1.1 Protocol query endpoint (<https://www.w3.org/TR/sparql11-protocol/>) over the
//! union of ontology, environment and inferred triples. Updates are refused.

use std::sync::Arc;
use std::time::Instant;

use axum::Router;
use axum::body::Bytes;
use axum::extract::{Query, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::Response;
use axum::routing::get;
use dyknow_store::oxigraph::io::RdfFormat;
use dyknow_store::oxigraph::sparql::results::QueryResultsFormat;
use dyknow_store::{ParsedQuery, QueryForm, ResultFormat, SparqlQueryError};
use serde::Deserialize;

use crate::app::{AppState, in_turn, typed};
use crate::error::{ApiError, ErrorBody};
use crate::negotiate::{content_type, negotiate};

pub(crate) fn router() -> Router<AppState> {
    Router::new().route("/sparql", get(sparql_get).post(sparql_post))
}

/// The protocol's parameters, as `?query=` or as a form body. A schema cannot state SPARQL's
/// grammar: a query that does not parse is 400 (with its line and column).
#[derive(Debug, Default, Deserialize, utoipa::IntoParams, utoipa::ToSchema)]
pub struct SparqlParams {
    /// The query (400 without it, unless `update` is given).
    #[param(required = true)]
    #[schema(required = true)]
    pub query: Option<String>,
    /// An update: always refused here (403).
    pub update: Option<String>,
}

const SOLUTION_TYPES: [&str; 6] = [
    "application/sparql-results+json",
    "application/sparql-results+xml",
    "text/csv",
    "text/tab-separated-values",
    "application/json",
    "application/xml",
];
const GRAPH_TYPES: [&str; 4] = [
    "text/turtle",
    "application/n-triples",
    "application/rdf+xml",
    "application/ld+json",
];

fn result_format(form: QueryForm, headers: &HeaderMap) -> Result<ResultFormat, ApiError> {
    Ok(match form {
        QueryForm::Solutions => ResultFormat::Results(match negotiate(headers, &SOLUTION_TYPES)? {
            "application/sparql-results+xml" | "application/xml" => QueryResultsFormat::Xml,
            "text/csv" => QueryResultsFormat::Csv,
            "text/tab-separated-values" => QueryResultsFormat::Tsv,
            _ => QueryResultsFormat::Json,
        }),
        QueryForm::Graph => ResultFormat::Rdf(match negotiate(headers, &GRAPH_TYPES)? {
            "application/n-triples" => RdfFormat::NTriples,
            "application/rdf+xml" => RdfFormat::RdfXml,
            "application/ld+json" => RdfFormat::JsonLd {
                profile: Default::default(),
            },
            _ => RdfFormat::Turtle,
        }),
    })
}

async fn answer(
    state: AppState,
    headers: HeaderMap,
    params: SparqlParams,
) -> Result<Response, ApiError> {
    if params.update.is_some() {
        return Err(SparqlQueryError::UpdateRefused.into());
    }
    let query = params
        .query
        .ok_or_else(|| ApiError::bad_request("no query: pass it as ?query=, as form field query=, or as an application/sparql-query body"))?;
    let parsed = ParsedQuery::parse(&query)?;
    let format = result_format(parsed.form(), &headers)?;
    let timeout = state.config.query_timeout;
    // The watchdog cancels the evaluation when its time is up (the time waiting for a turn
    // included); oxigraph notices between solutions, the serialisation between rows, and the
    // client is answered 503. It watches the query while `cancel` lives: until the answer is
    // made, or the request is dropped.
    let cancel = Arc::new(parsed.cancellation_token());
    if let Some(deadline) = Instant::now().checked_add(timeout) {
        state
            .watchdog
            .watch(deadline, &cancel)
            .map_err(ApiError::internal)?;
    }
    let kb = state.kb.clone();
    let answer = in_turn(&state, move || Ok(kb.run_query(parsed, format, timeout)?)).await?;
    drop(cancel);
    Ok(typed(StatusCode::OK, answer.media_type, answer.body))
}

/// A query as `?query=`.
#[utoipa::path(get, path = "/sparql", tag = "sparql", params(SparqlParams),
    responses((status = 200, description = "results, negotiated by Accept"), (status = 400, body = ErrorBody),
              (status = 403, body = ErrorBody), (status = 406, body = ErrorBody), (status = 503, body = ErrorBody)))]
pub async fn sparql_get(
    State(state): State<AppState>,
    headers: HeaderMap,
    Query(params): Query<SparqlParams>,
) -> Result<Response, ApiError> {
    answer(state, headers, params).await
}

/// A query as a form (`query=`) or directly (`application/sparql-query`).
#[utoipa::path(post, path = "/sparql", tag = "sparql",
    request_body(description = "A SPARQL 1.1 query, directly or as a form (`query=`). A schema cannot state SPARQL's grammar: a query that does not parse is 400 (with its line and column); an update (`application/sparql-update`, or a form's `update=`) is 403.",
        content((String = "application/sparql-query"), (SparqlParams = "application/x-www-form-urlencoded"))),
    responses((status = 200, description = "results, negotiated by Accept"), (status = 400, body = ErrorBody),
              (status = 403, body = ErrorBody), (status = 406, body = ErrorBody), (status = 415, body = ErrorBody),
              (status = 503, body = ErrorBody)))]
pub async fn sparql_post(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    let media = content_type(&headers);
    let params = match media.as_deref() {
        Some("application/x-www-form-urlencoded") => serde_urlencoded::from_bytes(&body)
            .map_err(|e| ApiError::bad_request(format!("malformed form body: {e}")))?,
        Some("application/sparql-query") => SparqlParams {
            query: Some(
                String::from_utf8(body.to_vec())
                    .map_err(|_| ApiError::bad_request("the query is not UTF-8"))?,
            ),
            update: None,
        },
        Some("application/sparql-update") => return Err(SparqlQueryError::UpdateRefused.into()),
        other => {
            return Err(ApiError::unsupported_media_type(
                other,
                &[
                    "application/x-www-form-urlencoded",
                    "application/sparql-query",
                ],
            ));
        }
    };
    answer(state, headers, params).await
}
