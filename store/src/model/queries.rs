//! Every SPARQL query the service asks about the DyKnow model, in one place. Prefixes come
//! from [`dyknow_ontology::vocab`], graph names from [`crate::graphs`].

use std::sync::LazyLock;

use dyknow_ontology::vocab::PREFIXES;
use oxigraph::model::Literal;

use crate::graphs::{ENVIRONMENT_GRAPH_PREFIX, TARGET_GRAPH_PREFIX, TRANSFORMATION_GRAPH_PREFIX};

/// `body` with the vocabulary's `PREFIX` declarations.
fn prefixed(body: &str) -> String {
    let mut out: String = PREFIXES
        .iter()
        .map(|(prefix, namespace)| format!("PREFIX {prefix}: <{namespace}>\n"))
        .collect();
    out.push_str(body);
    out
}

/// The candidate table (the seed's validity matrix) in one query: every (consumer in port or
/// target, producer out port) pair whose tags satisfy `i ~ o` (`specs.md`: equal values; the
/// out description is the in description or a sub-concept of it after reasoning;
/// `dyknow:similarTo` either way). Columns: consumer, inPort, target, producer, outPort.
pub static CANDIDATES: LazyLock<String> = LazyLock::new(|| {
    prefixed(&format!(
        r#"SELECT DISTINCT ?consumer ?inPort ?target ?producer ?outPort WHERE {{
  {{
    GRAPH ?cg {{ ?ctf rdfs:label ?consumer ; dyknow:hasInPort ?ip . ?ip dyknow:hasName ?inPort ; dyknow:hasTag ?it . }}
    FILTER(STRSTARTS(STR(?cg), "{TRANSFORMATION_GRAPH_PREFIX}"))
  }} UNION {{
    GRAPH ?qg {{ ?q rdfs:label ?target ; dyknow:hasTag ?it . }}
    FILTER(STRSTARTS(STR(?qg), "{TARGET_GRAPH_PREFIX}"))
  }}
  GRAPH ?pg {{ ?ptf rdfs:label ?producer ; dyknow:hasOutPort ?op . ?op dyknow:hasName ?outPort ; dyknow:hasTag ?ot . }}
  FILTER(STRSTARTS(STR(?pg), "{TRANSFORMATION_GRAPH_PREFIX}"))
  {{
    ?it dyknow:hasValue ?v . ?ot dyknow:hasValue ?v .
  }} UNION {{
    ?it dyknow:hasTagDescription ?d . ?ot dyknow:hasTagDescription ?e . ?e rdfs:subClassOf* ?d .
  }} UNION {{
    ?it dyknow:hasTagDescription ?d . ?ot dyknow:hasTagDescription ?e .
    {{ ?d dyknow:similarTo ?e }} UNION {{ ?e dyknow:similarTo ?d }}
  }}
}}"#
    ))
});

/// For each out description of `descriptions` (IRIs; others are left out), the descriptions
/// it satisfies under [`CANDIDATES`]' relation besides itself: its super-concepts after
/// reasoning and those `dyknow:similarTo` it either way. `None` when no description is an
/// IRI. Columns: e, d.
pub fn description_matches(descriptions: &[String]) -> Option<String> {
    let values: Vec<String> = descriptions
        .iter()
        .filter_map(|d| oxigraph::model::NamedNode::new(d.as_str()).ok())
        .map(|d| d.to_string())
        .collect();
    if values.is_empty() {
        return None;
    }
    Some(prefixed(&format!(
        "SELECT DISTINCT ?e ?d WHERE {{ VALUES ?e {{ {} }} \
         {{ ?e rdfs:subClassOf+ ?d }} UNION {{ ?e dyknow:similarTo ?d }} UNION {{ ?d dyknow:similarTo ?e }} }}",
        values.join(" ")
    )))
}

/// The CUs of the environment graphs, one row per port binding. A CU whose transformation was
/// deregistered keeps the transformation's IRI as its tid (not in the library: invalid, so the
/// next review destroys it unless it is protected). Columns: name, tid, protected, dir
/// (`"in"`/`"out"`), port, channel.
pub static CUS: LazyLock<String> = LazyLock::new(|| {
    prefixed(&format!(
        r#"SELECT ?name ?tid ?protected ?dir ?port ?channel WHERE {{
  GRAPH ?g {{
    ?cu a dyknow:ComputationUnit ; dyknow:hasName ?name ; dyknow:instanceOf ?tf .
    OPTIONAL {{ ?cu dkros:isProtected ?protected }}
  }}
  FILTER(STRSTARTS(STR(?g), "{ENVIRONMENT_GRAPH_PREFIX}"))
  OPTIONAL {{ ?tf rdfs:label ?label }}
  BIND(COALESCE(?label, STR(?tf)) AS ?tid)
  OPTIONAL {{
    GRAPH ?g {{
      {{
        ?cu dyknow:hasSubscription ?s . ?s dyknow:toPort ?p .
        OPTIONAL {{ ?s dyknow:hasChannel ?ch . ?ch dyknow:hasChannelName ?channel }}
        BIND("in" AS ?dir)
      }} UNION {{
        ?cu dkros:hasPublication ?s . ?s dkros:publishesPort ?p .
        OPTIONAL {{ ?s dkros:onChannel ?ch . ?ch dyknow:hasChannelName ?channel }}
        BIND("out" AS ?dir)
      }}
    }}
    ?p dyknow:hasName ?port .
  }}
}}"#
    ))
});

/// The cost models of the transformations. Columns: tid, kind (`"labour"`/`"upkeep"`), model.
pub static COST_MODELS: LazyLock<String> = LazyLock::new(|| {
    prefixed(
        r#"SELECT ?tid ?kind ?m WHERE {
  ?tf rdfs:label ?tid ; dyknow:hasCostModel ?m .
  { ?m a dyknow:LabourCostModel BIND("labour" AS ?kind) } UNION { ?m a dyknow:UpkeepCostModel BIND("upkeep" AS ?kind) }
}"#,
    )
});

/// The learned estimates (seed Ch. 5.3.2). Columns: tid, kind, average, observation count.
pub static LEARNED: LazyLock<String> = LazyLock::new(|| {
    prefixed(
        r#"SELECT ?tid ?kind ?avg ?n WHERE {
  ?tf rdfs:label ?tid ; dyknow:hasCostModel ?m .
  ?m dkros:observationCount ?n .
  { ?m dkros:historicalAverageLabour ?avg BIND("labour" AS ?kind) }
  UNION { ?m dkros:historicalAverageUpkeep ?avg BIND("upkeep" AS ?kind) }
}"#,
    )
});

/// The recorded change sets: their id and their JSON. Columns: label, json.
pub static CHANGE_SETS: LazyLock<String> = LazyLock::new(|| {
    prefixed(
        "SELECT ?label ?json WHERE { ?cs a dyknow:ChangeSet . \
         OPTIONAL { ?cs rdfs:label ?label } OPTIONAL { ?cs dkros:changeSetJson ?json } }",
    )
});

/// The CU publishing on the channel named `channel`, first by name. Column: name.
pub fn channel_producer(channel: &Literal) -> String {
    prefixed(&format!(
        "SELECT ?name WHERE {{ ?cu dkros:hasPublication ?p . ?p dkros:onChannel ?c . \
         ?c dyknow:hasChannelName {channel} . ?cu dyknow:hasName ?name }} ORDER BY ?name LIMIT 1"
    ))
}
