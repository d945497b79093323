//! The SPARQL 1.1 Protocol query endpoint (<https://www.w3.org/TR/sparql11-protocol/>) over the
//! union of ontology, environment and inferred triples. Updates are refused.

use std::sync::Arc;
use std::time::Instant;

use axum::Router;
use axum::body::Bytes;
use axum::extract::{RawQuery, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::Response;
use axum::routing::get;
use dyknow_ontology::OwlSyntax;
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
    /// The protocol's `default-graph-uri` (repeatable): the graphs whose merge is the
    /// default graph.
    #[serde(rename = "default-graph-uri", default)]
    #[param(rename = "default-graph-uri")]
    #[schema(rename = "default-graph-uri")]
    pub default_graph_uri: Vec<String>,
    /// The protocol's `named-graph-uri` (repeatable): the named graphs.
    #[serde(rename = "named-graph-uri", default)]
    #[param(rename = "named-graph-uri")]
    #[schema(rename = "named-graph-uri")]
    pub named_graph_uri: Vec<String>,
}

/// A part of a query string or form body decoded strictly: `+` is a space, and a part that is
/// not UTF-8 once percent-decoded is 400 (form decoding would make `%FF` U+FFFD and act on
/// another value than the one sent).
pub(crate) fn decode_strictly(part: &str) -> Result<String, ApiError> {
    percent_encoding::percent_decode_str(&part.replace('+', " "))
        .decode_utf8()
        .map(std::borrow::Cow::into_owned)
        .map_err(|_| ApiError::bad_request("a parameter is not UTF-8 once percent-decoded"))
}

impl SparqlParams {
    /// Reads the protocol's parameters from a query string or a form body, taking every
    /// `default-graph-uri` and `named-graph-uri` (they repeat) and ignoring unknown ones.
    fn from_pairs(text: &[u8]) -> Result<Self, ApiError> {
        let text = std::str::from_utf8(text)
            .map_err(|_| ApiError::bad_request("the parameters are not UTF-8"))?;
        let mut params = Self::default();
        for pair in text.split('&').filter(|p| !p.is_empty()) {
            let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
            let (key, value) = (decode_strictly(key)?, decode_strictly(value)?);
            // The protocol allows one query (or update) per request: a second would silently
            // win over the first.
            let once = |slot: &mut Option<String>, value: String| {
                if slot.replace(value).is_some() {
                    return Err(ApiError::bad_request(format!(
                        "more than one {key:?} parameter: a request carries one"
                    )));
                }
                Ok(())
            };
            match key.as_str() {
                "query" => once(&mut params.query, value)?,
                "update" => once(&mut params.update, value)?,
                "default-graph-uri" => params.default_graph_uri.push(value),
                "named-graph-uri" => params.named_graph_uri.push(value),
                _ => {}
            }
        }
        Ok(params)
    }

    /// The dataset's graphs as IRIs; one that is no IRI is 400.
    fn graphs(
        uris: &[String],
        what: &str,
    ) -> Result<Vec<dyknow_store::oxigraph::model::NamedNode>, ApiError> {
        uris.iter()
            .map(|u| {
                dyknow_store::oxigraph::model::NamedNode::new(u.as_str())
                    .map_err(|e| ApiError::bad_request(format!("{what} {u:?} is not an IRI: {e}")))
            })
            .collect()
    }
}

const SOLUTION_TYPES: [&str; 6] = [
    "application/sparql-results+json",
    "application/sparql-results+xml",
    "text/csv",
    "text/tab-separated-values",
    "application/json",
    "application/xml",
];
/// The model's formats (`GET /model`): RDF, and OWL through horned-owl.
const GRAPH_TYPES: [&str; 6] = [
    "text/turtle",
    "application/n-triples",
    "application/rdf+xml",
    "application/ld+json",
    "application/owl+xml",
    "text/owl-functional",
];

/// The OWL syntax a graph query's answer is asked in, if any (then the query is run as
/// N-Triples and converted).
fn owl_syntax(form: QueryForm, headers: &HeaderMap) -> Result<Option<OwlSyntax>, ApiError> {
    Ok(match form {
        QueryForm::Graph => match negotiate(headers, &GRAPH_TYPES)? {
            "application/owl+xml" => Some(OwlSyntax::OwlXml),
            "text/owl-functional" => Some(OwlSyntax::Functional),
            _ => None,
        },
        QueryForm::Solutions => None,
    })
}

/// A graph query's triples (N-Triples) as one OWL ontology: horned-owl reads axioms and facts
/// of an ontology, so the triples get one (`urn:dyknow:sparql`), as `GET /model` gets
/// `urn:dyknow:model`. Triples that are no OWL construct are counted, not shown.
fn to_owl(ntriples: &[u8], syntax: OwlSyntax) -> Result<(Vec<u8>, usize), ApiError> {
    let mut document = b"<urn:dyknow:sparql> <http://www.w3.org/1999/02/22-rdf-syntax-ns#type> <http://www.w3.org/2002/07/owl#Ontology> .\n".to_vec();
    document.extend_from_slice(ntriples);
    let owl = dyknow_ontology::rdf_to_owl(&document, RdfFormat::NTriples, syntax)
        .map_err(ApiError::internal)?;
    Ok((owl.text.into_bytes(), owl.unparsed_triples))
}

/// The answer's format, and the media type to label it with when the client asked for plain
/// `application/json` or `application/xml` (the results are JSON or XML, and the label is
/// what it accepts); else the format's own.
fn result_format(
    form: QueryForm,
    headers: &HeaderMap,
) -> Result<(ResultFormat, Option<&'static str>), ApiError> {
    Ok(match form {
        QueryForm::Solutions => {
            let asked = negotiate(headers, &SOLUTION_TYPES)?;
            let format = match asked {
                "application/sparql-results+xml" | "application/xml" => QueryResultsFormat::Xml,
                "text/csv" => QueryResultsFormat::Csv,
                "text/tab-separated-values" => QueryResultsFormat::Tsv,
                _ => QueryResultsFormat::Json,
            };
            let plain = matches!(asked, "application/json" | "application/xml").then_some(asked);
            (ResultFormat::Results(format), plain)
        }
        QueryForm::Graph => (
            ResultFormat::Rdf(match negotiate(headers, &GRAPH_TYPES)? {
                "application/n-triples" => RdfFormat::NTriples,
                "application/rdf+xml" => RdfFormat::RdfXml,
                "application/ld+json" => RdfFormat::JsonLd {
                    profile: Default::default(),
                },
                _ => RdfFormat::Turtle,
            }),
            None,
        ),
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
    let default = SparqlParams::graphs(&params.default_graph_uri, "default-graph-uri")?;
    let named = SparqlParams::graphs(&params.named_graph_uri, "named-graph-uri")?;
    let mut parsed = ParsedQuery::parse(&query)?.with_protocol_dataset(default, named);
    if let Some(bytes) = state.config.query_memory {
        parsed = parsed.with_memory_limit(bytes);
    }
    let owl = owl_syntax(parsed.form(), &headers)?;
    let (format, label) = match owl {
        Some(_) => (ResultFormat::Rdf(RdfFormat::NTriples), None),
        None => result_format(parsed.form(), &headers)?,
    };
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
    let memory = state.config.query_memory;
    let metrics = state.metrics.clone();
    let answer = in_turn(&state, move || {
        let answer = kb
            .run_query(parsed, format, timeout)
            .inspect_err(|e| metrics.sparql_failed(e))?;
        Ok(match owl {
            Some(syntax) => {
                // Reading the answer as OWL holds memory too: counted against what the limit
                // leaves beside the answer (horned-owl cannot be stopped midway, so this is
                // checked once it ends; what it reads is within the limit).
                let budget = memory.map(|limit| {
                    let left = limit.saturating_sub(answer.body.len());
                    (limit, dyknow_meter::Budget::start(left))
                });
                let (body, unparsed) = to_owl(&answer.body, syntax)?;
                if let Some((limit, budget)) = budget
                    && budget.tripped()
                {
                    let error = SparqlQueryError::MemoryLimit(limit);
                    metrics.sparql_failed(&error);
                    return Err(error.into());
                }
                (syntax.media_type(), body, Some(unparsed))
            }
            None => (answer.media_type, answer.body, None),
        })
    })
    .await?;
    drop(cancel);
    let (media_type, body, unparsed) = answer;
    let mut response = typed(StatusCode::OK, label.unwrap_or(media_type), body);
    if let Some(n) = unparsed {
        // As `GET /model` says it: triples no OWL construct holds.
        response.headers_mut().insert(
            "x-dyknow-unparsed-triples",
            axum::http::HeaderValue::from(n),
        );
    }
    Ok(response)
}

/// A query as `?query=`.
#[utoipa::path(get, path = "/sparql", tag = "sparql", params(SparqlParams),
    responses((status = 200, description = "results, negotiated by Accept"), (status = 400, body = ErrorBody),
              (status = 403, body = ErrorBody), (status = 406, body = ErrorBody), (status = 503, body = ErrorBody)))]
pub async fn sparql_get(
    State(state): State<AppState>,
    headers: HeaderMap,
    RawQuery(raw): RawQuery,
) -> Result<Response, ApiError> {
    let params = SparqlParams::from_pairs(raw.unwrap_or_default().as_bytes())?;
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
    RawQuery(raw): RawQuery,
    body: Bytes,
) -> Result<Response, ApiError> {
    let media = content_type(&headers);
    let params = match media.as_deref() {
        Some("application/x-www-form-urlencoded") => SparqlParams::from_pairs(&body)?,
        // The query is the body; the dataset's graphs come in the URL (the protocol's
        // "query via POST directly").
        Some("application/sparql-query") => SparqlParams {
            query: Some(
                String::from_utf8(body.to_vec())
                    .map_err(|_| ApiError::bad_request("the query is not UTF-8"))?,
            ),
            ..SparqlParams::from_pairs(raw.unwrap_or_default().as_bytes())?
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
