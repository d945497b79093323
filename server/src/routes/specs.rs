//! AddTransformation, RemoveTransformation, AddTarget, RemoveTarget (seed Ch. 5.3) and their
//! listings: `/transformations`, `/targets`.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::PoisonError;

use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use dyknow_engine::{Cid, Tid};
use dyknow_lifecycle::Perturbation;
use dyknow_store::oxigraph::io::RdfFormat;
use dyknow_store::spec::{Implementation, Port, Spec, SpecKind, Tag};
use dyknow_store::{InputFormat, KnowledgeBase, serialize};
use serde::Serialize;
use utoipa::ToSchema;

use crate::app::{AppState, in_turn, typed};
use crate::error::{ApiError, ErrorBody};
use crate::negotiate::{content_type, negotiate};

/// The RDF media types accepted in request bodies.
pub const RDF_INPUTS: [&str; 3] = [
    "text/turtle",
    "application/n-triples",
    "application/ld+json",
];

pub(crate) fn router() -> Router<AppState> {
    Router::new()
        .route(
            "/transformations",
            get(list_transformations).post(post_transformations),
        )
        .route(
            "/transformations/{label}",
            get(get_transformation).delete(delete_transformation),
        )
        .route("/targets", get(list_targets).post(post_targets))
        .route("/targets/{label}", get(get_target).delete(delete_target))
}

/// A tag in full: its value and/or its description concept.
#[derive(Debug, Serialize, ToSchema)]
pub struct TagJson {
    /// `dyknow:hasValue`.
    pub value: Option<String>,
    /// `dyknow:hasTagDescription` (an IRI).
    pub description: Option<String>,
}

/// A port of a transformation.
#[derive(Debug, Serialize, ToSchema)]
pub struct PortJson {
    /// The port's name.
    pub port: String,
    /// The tags as strings: the value, or `<iri>` of the description when there is no value.
    pub tags: Vec<String>,
    /// The tags in full.
    pub tag_details: Vec<TagJson>,
}

/// A transformation spec.
#[derive(Debug, Serialize, ToSchema)]
pub struct TransformationJson {
    /// The label (*tid*).
    pub label: String,
    /// In ports.
    pub inputs: Vec<PortJson>,
    /// Out ports.
    pub outputs: Vec<PortJson>,
    /// Labour estimate: the cost of one spawn.
    pub labour: f64,
    /// Upkeep estimate: cost per time unit of one running CU.
    pub upkeep: f64,
    /// The IRI of the transformation in the model.
    pub iri: String,
    /// `dkros:hasType`.
    #[serde(rename = "type")]
    pub exec_type: Option<String>,
    /// `dkros:hasSource`.
    pub source: Option<String>,
    /// `dkros:hasParam`: name → value as executors read it (`executors.md`).
    #[schema(value_type = Object)]
    pub params: serde_json::Map<String, serde_json::Value>,
    /// `dkros:hasExecutor`.
    pub executor: Option<String>,
    /// Whether some present executor can run it (always, in model-only mode); a
    /// transformation that is not is never planned.
    pub runnable: bool,
    /// Why not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
}

/// A target spec.
#[derive(Debug, Serialize, ToSchema)]
pub struct TargetJson {
    /// The label (*qid*).
    pub label: String,
    /// The channel the stream must appear on.
    pub channel: String,
    /// The tags as strings (see `PortJson::tags`).
    pub tags: Vec<String>,
    /// The tags in full.
    pub tag_details: Vec<TagJson>,
    /// Whether a CU currently produces the stream on the channel: it publishes there, with
    /// the target's tags (as `GET /environment` judges it).
    pub satisfied: bool,
    /// The name of the CU publishing on the channel (whatever its tags).
    pub producer: Option<String>,
    /// The IRI of the target in the model.
    pub iri: String,
    /// The formula groups whose symbols this target grounds (targets groups create,
    /// `groups.md`); absent for targets posted by clients.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub groups: Vec<String>,
}

/// The answer to a spec POST.
#[derive(Debug, Serialize, ToSchema)]
pub struct PostedJson {
    /// Labels written, in document order.
    pub labels: Vec<String>,
    /// Those that replaced an existing spec.
    pub replaced: Vec<String>,
}

fn tags_json(tags: &[Tag]) -> (Vec<String>, Vec<TagJson>) {
    (
        tags.iter().map(Tag::display).collect(),
        tags.iter()
            .map(|t| TagJson {
                value: t.value.clone(),
                description: t.description.clone(),
            })
            .collect(),
    )
}

fn port_json(port: &Port) -> PortJson {
    let (tags, tag_details) = tags_json(&port.tags);
    PortJson {
        port: port.name.clone(),
        tags,
        tag_details,
    }
}

/// The labels of the targets the environment leaves unsatisfied (`GET /environment`'s
/// `unsatisfied_targets`): no CU publishes on the channel, or what it publishes lacks the
/// target's tags.
pub(crate) fn unsatisfied_targets(
    loaded: &dyknow_store::model::Loaded,
) -> std::collections::BTreeSet<String> {
    (loaded.env.invalidities(&loaded.candidates).into_iter())
        .filter_map(|i| match i {
            dyknow_engine::Invalidity::UnsatisfiedTarget { target } => Some(target.to_string()),
            _ => None,
        })
        .collect()
}

/// The JSON of a spec (targets look up their producer in the model; `unsatisfied` are the
/// targets [`unsatisfied_targets`] names, so `satisfied` agrees with `GET /environment`).
pub(crate) fn spec_json(
    kb: &KnowledgeBase,
    runnable: &dyn Fn(&dyknow_store::spec::TransformationSpec) -> Result<(), String>,
    unsatisfied: &std::collections::BTreeSet<String>,
    spec: Spec,
) -> Result<serde_json::Value, ApiError> {
    let value = match spec {
        Spec::Transformation(t) => {
            let why = runnable(&t).err();
            serde_json::to_value(TransformationJson {
                params: dyknow_lifecycle::fleet::implementation(&t)
                    .params
                    .into_iter()
                    .collect(),
                executor: t.executor.clone(),
                runnable: why.is_none(),
                why,
                inputs: t.inputs.iter().map(port_json).collect(),
                outputs: t.outputs.iter().map(port_json).collect(),
                label: t.label,
                labour: t.labour,
                upkeep: t.upkeep,
                iri: t.iri,
                exec_type: t.exec_type,
                source: t.source,
            })
        }
        Spec::Target(t) => {
            let producer = kb.channel_producer(&t.channel)?;
            let satisfied = producer.is_some() && !unsatisfied.contains(&t.label);
            let (tags, tag_details) = tags_json(&t.tags);
            serde_json::to_value(TargetJson {
                label: t.label,
                channel: t.channel,
                tags,
                tag_details,
                satisfied,
                producer,
                iri: t.iri,
                groups: Vec::new(),
            })
        }
    };
    value.map_err(ApiError::internal)
}

/// A target's JSON with the groups that use it.
fn with_groups(
    mut v: serde_json::Value,
    users: &std::collections::BTreeMap<String, Vec<String>>,
) -> serde_json::Value {
    if let Some(groups) = v["label"].as_str().and_then(|l| users.get(l))
        && v.get("channel").is_some()
    {
        v["groups"] = serde_json::json!(groups);
    }
    v
}

/// The format of a request body from its `Content-Type`, or a 415.
pub(crate) fn input_format(headers: &HeaderMap) -> Result<InputFormat, ApiError> {
    let media = content_type(headers);
    media
        .as_deref()
        .and_then(InputFormat::from_media_type)
        .ok_or_else(|| ApiError::unsupported_media_type(media.as_deref(), &RDF_INPUTS))
}

async fn post_specs(
    state: AppState,
    headers: HeaderMap,
    body: Bytes,
    kind: SpecKind,
) -> Result<Response, ApiError> {
    let format = input_format(&headers)?;
    let kb = state.kb.clone();
    let groups = state.groups.clone();
    let lifecycle = state.lifecycle.clone();
    let (report, stale) = in_turn(&state, move || {
        // The CUs of a posted transformation whose implementation changed are replaced. What
        // is compared is the stored spec (read back, with values in the store's canonical
        // form: a parameter posted as `"1.0"^^xsd:double` reads back as `1`), before the write
        // for CUs running from before start-up, after it for all (`stale_after_post`). Only
        // transformations with CUs are read.
        let before = std::sync::Mutex::new(BTreeMap::<Tid, Option<Implementation>>::new());
        let posted = std::sync::Mutex::new(Vec::<Tid>::new());
        let with_cus = lifecycle.transformations_with_cus();
        let stored = |label: &str| match kb.spec(SpecKind::Transformation, label) {
            Ok(Some(Spec::Transformation(t))) => Some(t.implementation()),
            _ => None,
        };
        let refused = |spec: &Spec| {
            if let Spec::Transformation(t) = spec {
                let tid = Tid::from(t.label.as_str());
                if with_cus.contains(&tid) {
                    before
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .insert(tid.clone(), stored(&t.label));
                }
                posted
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .push(tid);
            }
            reserved_label(spec).or_else(|| match spec {
                Spec::Target(t) => groups.result_channel_user(&t.channel).map(|group| {
                    format!(
                        "channel {:?} carries the verdicts of formula group {group:?} (its \
                         result_channel): a stream there would be mixed with verdict lines; \
                         choose another channel, or stop the group",
                        t.channel
                    )
                }),
                Spec::Transformation(_) => None,
            })
        };
        let report = kb.post_specs_checked(&body, format, kind, &refused)?;
        // After the write: a CU spawned meanwhile is either among these now, or its change
        // set sees the write (`Manager::commit`).
        let with_cus = lifecycle.transformations_with_cus();
        let before = before.into_inner().unwrap_or_else(PoisonError::into_inner);
        let mut changed = BTreeSet::new();
        let mut now = Vec::new();
        for tid in posted.into_inner().unwrap_or_else(PoisonError::into_inner) {
            if !with_cus.contains(&tid) {
                continue;
            }
            let Some(implementation) = stored(tid.as_str()) else {
                continue;
            };
            if before
                .get(&tid)
                .is_some_and(|old| old.as_ref() != Some(&implementation))
            {
                changed.insert(tid.clone());
            }
            now.push((tid, implementation));
        }
        let stale = lifecycle.stale_after_post(&now, &changed);
        Ok((report, stale))
    })
    .await?;
    if !stale.is_empty() {
        // The spec is written: a failure to replace the CUs is logged, and the registration
        // below is reported all the same (a review follows the new spec).
        let s = state.clone();
        let cus = stale.clone();
        if let Err(e) = crate::app::blocking(move || Ok(s.lifecycle.replace_stale(&cus)?)).await {
            let names: Vec<&str> = stale.iter().map(Cid::as_str).collect();
            tracing::warn!(
                "{} could not be replaced after their implementation changed: {}",
                names.join(", "),
                e.message
            );
        }
    }
    match kind {
        SpecKind::Target => {
            for label in &report.labels {
                state.lifecycle.report(Perturbation::TargetAdded {
                    target: label.into(),
                })?;
            }
        }
        SpecKind::Transformation => {
            // Off the async workers: with CUs of a replaced transformation, the life-cycle
            // rewrites their graphs under the configuration lock, which a review may hold.
            let s = state.clone();
            let transformations = report.labels.iter().map(Into::into).collect();
            crate::app::blocking(move || {
                Ok(s.lifecycle
                    .report(Perturbation::Registered { transformations })?)
            })
            .await?;
        }
    }
    // Sorted by label, as every list of the API (http-api.md), whatever the document's order.
    let (mut labels, mut replaced) = (report.labels, report.replaced);
    labels.sort();
    replaced.sort();
    Ok((StatusCode::CREATED, Json(PostedJson { labels, replaced })).into_response())
}

async fn list_specs(
    state: AppState,
    headers: HeaderMap,
    kind: SpecKind,
) -> Result<Response, ApiError> {
    let media = negotiate(&headers, &["application/json", "text/turtle"])?;
    let kb = state.kb.clone();
    let lifecycle = state.lifecycle.clone();
    if media == "text/turtle" {
        let body = in_turn(&state, move || {
            let mut triples = Vec::new();
            for (_, graph) in kb.spec_graphs(kind)? {
                triples.extend(kb.graph_triples(graph.as_ref())?);
            }
            serialize(&triples, RdfFormat::Turtle).map_err(ApiError::internal)
        })
        .await?;
        return Ok(typed(StatusCode::OK, "text/turtle", body));
    }
    let groups = state.groups.clone();
    let list = in_turn(&state, move || {
        let users = groups.target_users();
        let unsatisfied = match kind {
            SpecKind::Target => unsatisfied_targets(&lifecycle.load_now()?),
            SpecKind::Transformation => Default::default(),
        };
        kb.specs(kind)?
            .into_iter()
            .map(|s| {
                spec_json(&kb, &|t| lifecycle.runnable(t), &unsatisfied, s)
                    .map(|v| with_groups(v, &users))
            })
            .collect::<Result<Vec<_>, _>>()
    })
    .await?;
    Ok(Json(list).into_response())
}

async fn get_spec(
    state: AppState,
    headers: HeaderMap,
    kind: SpecKind,
    label: String,
) -> Result<Response, ApiError> {
    let media = negotiate(&headers, &["application/json", "text/turtle"])?;
    let kb = state.kb.clone();
    let lifecycle = state.lifecycle.clone();
    let missing = || ApiError::not_found(format!("no {} labelled {label:?}", kind.name()));
    if media == "text/turtle" {
        let graph = dyknow_store::graphs::spec_graph(kind, &label);
        let triples = in_turn(&state, move || Ok(kb.graph_triples(graph.as_ref())?)).await?;
        if triples.is_empty() {
            return Err(missing());
        }
        let body = serialize(&triples, RdfFormat::Turtle).map_err(ApiError::internal)?;
        return Ok(typed(StatusCode::OK, "text/turtle", body));
    }
    let label2 = label.clone();
    let groups = state.groups.clone();
    let value = in_turn(&state, move || match kb.spec(kind, &label2)? {
        Some(spec) => {
            let unsatisfied = match kind {
                SpecKind::Target => unsatisfied_targets(&lifecycle.load_now()?),
                SpecKind::Transformation => Default::default(),
            };
            spec_json(&kb, &|t| lifecycle.runnable(t), &unsatisfied, spec)
                .map(|v| Some(with_groups(v, &groups.target_users())))
        }
        None => Ok(None),
    })
    .await?
    .ok_or_else(missing)?;
    Ok(Json(value).into_response())
}

/// Why a posted spec may not be written: the labels of group targets (`symbol:…`) are the
/// service's. A client's target of that name would be replaced or released behind its back
/// whenever the groups' needs change.
fn reserved_label(spec: &Spec) -> Option<String> {
    match spec {
        Spec::Target(t) if t.label.starts_with(crate::groups::TARGET_PREFIX) => Some(format!(
            "target labels beginning with {:?} are reserved for the targets formula groups make \
             (groups.md); choose another label",
            crate::groups::TARGET_PREFIX
        )),
        _ => None,
    }
}

async fn delete_spec(
    state: AppState,
    kind: SpecKind,
    label: String,
) -> Result<StatusCode, ApiError> {
    let kb = state.kb.clone();
    let label2 = label.clone();
    let groups = state.groups.clone();
    let lifecycle = state.lifecycle.clone();
    in_turn(&state, move || {
        // A protected CU is never destroyed (`DELETE /cus` is 409): its transformation's spec
        // stays while it runs (removed, the CU would read as an instance of an unknown transformation, lose
        // its bindings, and leave the environment invalid with nothing allowed to repair it).
        if kind == SpecKind::Transformation {
            let protected = lifecycle.protected_cus_of(&Tid::from(label2.as_str()));
            if !protected.is_empty() {
                let names: Vec<&str> = protected.iter().map(Cid::as_str).collect();
                return Err(ApiError::new(
                    StatusCode::CONFLICT,
                    format!(
                        "transformation {label2:?} has protected CU(s) running: {}; a protected \
                         CU leaves only when it ends (or is reported crashed: POST \
                         /perturbations), and its spec stays until then",
                        names.join(", ")
                    ),
                ));
            }
        }
        // A group's target goes when its groups no longer need it, not before.
        if kind == SpecKind::Target
            && let Some(users) = groups.target_users().get(&label2)
        {
            return Err(ApiError::new(
                StatusCode::CONFLICT,
                format!(
                    "target {label2:?} is the stream of formula group(s) {}: stop or delete them, \
                     or remove their formulas, and it is released",
                    users.join(", ")
                ),
            ));
        }
        Ok(kb.remove_spec(kind, &label2)?)
    })
    .await?;
    // Whether a review follows at once is the life-cycle's call: a released target always, a
    // deregistered transformation when CUs of it are left invalid.
    let perturbation = match kind {
        SpecKind::Target => Perturbation::TargetReleased {
            target: label.into(),
        },
        SpecKind::Transformation => Perturbation::Deregistered {
            transformation: label.into(),
        },
    };
    // Off the async workers (see `post_specs`).
    let s = state.clone();
    crate::app::blocking(move || Ok(s.lifecycle.report(perturbation)?)).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// AddTransformation: one or more transformation specs (Turtle, N-Triples or JSON-LD); a label
/// that exists is replaced. Atomic.
#[utoipa::path(post, path = "/transformations", tag = "specs",
    request_body(description = "One or more transformation specs (specs.md) as RDF. A schema cannot state RDF's grammar: a syntax error is 400 (with its line and column); a document that describes no transformation, or violates the ontology or the DyKnow model, is 422.",
        content((String = "text/turtle"), (String = "application/n-triples"), (serde_json::Value = "application/ld+json"))),
    responses((status = 201, body = PostedJson), (status = 400, body = ErrorBody),
              (status = 413, body = ErrorBody), (status = 415, body = ErrorBody), (status = 422, body = ErrorBody)))]
pub async fn post_transformations(
    State(s): State<AppState>,
    h: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    post_specs(s, h, body, SpecKind::Transformation).await
}

/// The transformation specs, sorted by label (`Accept: text/turtle` gives them as Turtle).
#[utoipa::path(get, path = "/transformations", tag = "specs",
    responses((status = 200, description = "the specs; `Accept: text/turtle` gives them as Turtle",
                content((Vec<TransformationJson> = "application/json"), (String = "text/turtle"))),
              (status = 406, body = ErrorBody)))]
pub async fn list_transformations(
    State(s): State<AppState>,
    h: HeaderMap,
) -> Result<Response, ApiError> {
    list_specs(s, h, SpecKind::Transformation).await
}

/// One transformation spec.
#[utoipa::path(get, path = "/transformations/{label}", tag = "specs",
    params(("label" = String, Path, description = "the label, percent-encoded")),
    responses((status = 200, description = "the spec; `Accept: text/turtle` gives it as Turtle",
                content((TransformationJson = "application/json"), (String = "text/turtle"))),
              (status = 404, body = ErrorBody), (status = 406, body = ErrorBody)))]
pub async fn get_transformation(
    State(s): State<AppState>,
    h: HeaderMap,
    Path(label): Path<String>,
) -> Result<Response, ApiError> {
    get_spec(s, h, SpecKind::Transformation, label).await
}

/// RemoveTransformation (a perturbation: deregister).
#[utoipa::path(delete, path = "/transformations/{label}", tag = "specs",
    params(("label" = String, Path, description = "the label, percent-encoded")),
    responses((status = 204), (status = 404, body = ErrorBody), (status = 409, body = ErrorBody)))]
pub async fn delete_transformation(
    State(s): State<AppState>,
    Path(label): Path<String>,
) -> Result<StatusCode, ApiError> {
    delete_spec(s, SpecKind::Transformation, label).await
}

/// AddTarget: one or more target specs; a label that exists is replaced. Atomic.
#[utoipa::path(post, path = "/targets", tag = "specs",
    request_body(description = "One or more target specs (specs.md) as RDF. A schema cannot state RDF's grammar: a syntax error is 400 (with its line and column); a document that describes no target, or violates the ontology or the DyKnow model, is 422.",
        content((String = "text/turtle"), (String = "application/n-triples"), (serde_json::Value = "application/ld+json"))),
    responses((status = 201, body = PostedJson), (status = 400, body = ErrorBody),
              (status = 413, body = ErrorBody), (status = 415, body = ErrorBody), (status = 422, body = ErrorBody)))]
pub async fn post_targets(
    State(s): State<AppState>,
    h: HeaderMap,
    body: Bytes,
) -> Result<Response, ApiError> {
    post_specs(s, h, body, SpecKind::Target).await
}

/// The target specs, sorted by label.
#[utoipa::path(get, path = "/targets", tag = "specs",
    responses((status = 200, description = "the specs; `Accept: text/turtle` gives them as Turtle",
                content((Vec<TargetJson> = "application/json"), (String = "text/turtle"))),
              (status = 406, body = ErrorBody)))]
pub async fn list_targets(State(s): State<AppState>, h: HeaderMap) -> Result<Response, ApiError> {
    list_specs(s, h, SpecKind::Target).await
}

/// One target spec.
#[utoipa::path(get, path = "/targets/{label}", tag = "specs",
    params(("label" = String, Path, description = "the label, percent-encoded")),
    responses((status = 200, description = "the spec; `Accept: text/turtle` gives it as Turtle",
                content((TargetJson = "application/json"), (String = "text/turtle"))),
              (status = 404, body = ErrorBody), (status = 406, body = ErrorBody)))]
pub async fn get_target(
    State(s): State<AppState>,
    h: HeaderMap,
    Path(label): Path<String>,
) -> Result<Response, ApiError> {
    get_spec(s, h, SpecKind::Target, label).await
}

/// RemoveTarget (a perturbation: release).
#[utoipa::path(delete, path = "/targets/{label}", tag = "specs",
    params(("label" = String, Path, description = "the label, percent-encoded")),
    responses((status = 204), (status = 404, body = ErrorBody), (status = 409, body = ErrorBody)))]
pub async fn delete_target(
    State(s): State<AppState>,
    Path(label): Path<String>,
) -> Result<StatusCode, ApiError> {
    delete_spec(s, SpecKind::Target, label).await
}
