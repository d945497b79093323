//! The OpenAPI description, generated from the handlers' annotations.

use utoipa::openapi::content::ContentBuilder;
use utoipa::openapi::path::Operation;
use utoipa::openapi::{Ref, ResponseBuilder};
use utoipa::{Modify, OpenApi};

use crate::error::ErrorBody;
use crate::routes::{executors, groups, model, ontology, ops, reconfig, sparql, specs, ui};

/// The API description served at `/openapi.json`.
#[derive(OpenApi)]
#[openapi(
    modifiers(&CommonResponses),
    info(
        title = "DyKnow knowledge service",
        description = "Stream reasoning knowledge service: the DyKnow model as a live ontology."
    ),
    paths(
        specs::post_transformations,
        specs::list_transformations,
        specs::get_transformation,
        specs::delete_transformation,
        specs::post_targets,
        specs::list_targets,
        specs::get_target,
        specs::delete_target,
        ontology::post_extension,
        ontology::list_extensions,
        ontology::delete_extension,
        sparql::sparql_get,
        sparql::sparql_post,
        model::get_model,
        reconfig::list_cus,
        executors::get_cu,
        executors::list_executors,
        executors::set_config,
        reconfig::spawn_cu,
        reconfig::destroy_cu,
        reconfig::list_change_sets,
        reconfig::get_change_set,
        reconfig::change_set_stream,
        reconfig::post_perturbation,
        reconfig::post_statistics,
        reconfig::get_statistics,
        reconfig::post_review,
        reconfig::get_environment,
        groups::create_group,
        groups::list_groups,
        groups::get_group,
        groups::start_group,
        groups::stop_group,
        groups::destroy_group,
        groups::add_formula,
        groups::remove_formula,
        groups::verdicts,
        groups::trace,
        ops::health,
        ops::metrics,
        ops::openapi,
        ui::root,
        ui::ui_bare,
        ui::page,
        ui::file,
    ),
    components(schemas(
        ErrorBody,
        specs::TransformationJson,
        specs::TargetJson,
        specs::PortJson,
        specs::TagJson,
        specs::PostedJson,
        ontology::ExtensionJson,
        ontology::ExtensionPostedJson,
        model::ModelJson,
        model::ChannelJson,
        model::ModelFormatName,
        ops::Health,
        reconfig::CuJson,
        reconfig::SpawnJson,
        reconfig::PerturbationJson,
        reconfig::ObservationJson,
        reconfig::EnvironmentJson,
        reconfig::EnvironmentCostJson,
        groups::FormulaJson,
        groups::GroupSpecJson,
    ))
)]
pub struct ApiDoc;

/// The answers every operation of a kind can give, whatever its handler does: an operation
/// with a body can answer 400 (malformed), 413 (over `--max-body`) and 415 (another
/// `Content-Type`); a mutating one (every POST, PUT and DELETE but `POST /sparql`) 401 when
/// the server has a token; every read 406 (its `Accept` excludes the answer).
struct CommonResponses;

impl Modify for CommonResponses {
    fn modify(&self, api: &mut utoipa::openapi::OpenApi) {
        for (path, item) in &mut api.paths.paths {
            let operations = [
                (true, &mut item.post),
                (true, &mut item.put),
                (true, &mut item.delete),
                (false, &mut item.get),
            ];
            for (writes, operation) in operations {
                let Some(operation) = operation else {
                    continue;
                };
                if operation.request_body.is_some() {
                    add(operation, "400", "The body is malformed.");
                    add(
                        operation,
                        "413",
                        &format!(
                            "The body is larger than `--max-body`. The service reads and discards up to {} MiB of it within {} s first, so that a client that writes its whole body before reading reads this answer.",
                            crate::app::LINGER_BYTES / (1024 * 1024),
                            crate::app::LINGER_TIME.as_secs()
                        ),
                    );
                    add(
                        operation,
                        "415",
                        "The body's `Content-Type` is not one of those listed.",
                    );
                }
                if !writes {
                    add(
                        operation,
                        "406",
                        "The `Accept` header excludes every media type this answer comes in.",
                    );
                }
                if writes && path != "/sparql" {
                    add(
                        operation,
                        "401",
                        "The server has a token and the request does not carry it (`Authorization: Bearer <token>`).",
                    );
                }
            }
        }
    }
}

/// Adds an error answer with the contract's JSON body, unless the operation lists the status.
fn add(operation: &mut Operation, status: &str, description: &str) {
    operation
        .responses
        .responses
        .entry(status.to_owned())
        .or_insert_with(|| {
            ResponseBuilder::new()
                .description(description)
                .content(
                    "application/json",
                    ContentBuilder::new()
                        .schema(Some(Ref::from_schema_name("ErrorBody")))
                        .build(),
                )
                .build()
                .into()
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paths the routers register, read from their source: `.route("/path", ...)`.
    fn routed() -> Vec<String> {
        let sources = [
            include_str!("routes/executors.rs"),
            include_str!("routes/groups.rs"),
            include_str!("routes/model.rs"),
            include_str!("routes/ontology.rs"),
            include_str!("routes/ops.rs"),
            include_str!("routes/reconfig.rs"),
            include_str!("routes/sparql.rs"),
            include_str!("routes/specs.rs"),
            include_str!("routes/ui.rs"),
            include_str!("routes/mod.rs"),
            include_str!("app.rs"),
        ];
        let mut out = Vec::new();
        for source in sources {
            for part in source.split(".route(").skip(1) {
                let part = part.trim_start();
                let Some(rest) = part.strip_prefix('"') else {
                    continue;
                };
                let path = &rest[..rest.find('"').expect("a closing quote")];
                // axum's catch-all `{*file}` is OpenAPI's `{file}`.
                out.push(path.replace("{*", "{"));
            }
        }
        out
    }

    #[test]
    fn every_route_is_described() {
        let doc = ApiDoc::openapi();
        let routed = routed();
        assert!(routed.len() > 30, "{routed:?}");
        let missing: Vec<&String> = routed
            .iter()
            .filter(|p| !doc.paths.paths.contains_key(p.as_str()))
            .collect();
        assert!(
            missing.is_empty(),
            "routes without a description: {missing:?}"
        );
    }

    #[test]
    fn negotiated_reads_list_each_media_type() {
        let doc = ApiDoc::openapi();
        for (path, types) in [
            ("/transformations", &["application/json", "text/turtle"][..]),
            (
                "/transformations/{label}",
                &["application/json", "text/turtle"],
            ),
            ("/targets", &["application/json", "text/turtle"]),
            ("/targets/{label}", &["application/json", "text/turtle"]),
            ("/model", &crate::routes::model::OFFERS[..]),
            (
                "/changesets/{id}",
                &["application/json", "application/n-triples", "text/turtle"],
            ),
        ] {
            let get = doc.paths.paths[path].get.as_ref().expect("a GET");
            let utoipa::openapi::RefOr::T(ok) = &get.responses.responses["200"] else {
                panic!("{path}: 200 is a reference")
            };
            for t in types {
                assert!(ok.content.contains_key(*t), "GET {path}: {t}");
            }
        }
    }

    #[test]
    fn every_read_lists_406() {
        let doc = ApiDoc::openapi();
        for (path, item) in &doc.paths.paths {
            if let Some(get) = &item.get {
                assert!(get.responses.responses.contains_key("406"), "GET {path}");
            }
        }
    }
}
