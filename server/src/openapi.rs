//! The OpenAPI description, generated from the handlers' annotations.

use utoipa::OpenApi;

use crate::error::ErrorBody;
use crate::routes::{executors, groups, model, ontology, ops, reconfig, sparql, specs};

/// The API description served at `/openapi.json`.
#[derive(OpenApi)]
#[openapi(
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
        ops::Health,
        reconfig::CuJson,
        reconfig::SpawnJson,
        reconfig::PerturbationJson,
        reconfig::StatisticsJson,
        reconfig::EnvironmentJson,
        reconfig::EnvironmentCostJson,
        groups::FormulaJson,
    ))
)]
pub struct ApiDoc;
