// The transformation specs the ingestion benchmarks post, shared by
// `server/benches/knowledge_service.rs` and `store/examples/ingest_breakdown.rs` (included with
// `#[path]`, so both measure the same documents).

/// The prefixes a document of [`spec`]s starts with.
pub const PREFIXES: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
@prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .\n\
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n";

/// One transformation in the style of Listing 5.3: a parameter, one in and one out port, costs
/// (31 stored triples after normalisation).
pub fn spec(i: usize) -> String {
    format!(
        "[] a dkros:ROSTransformation ; rdfs:label \"tf-{i:05}\" ; dkros:hasType \"nodelet\" ; \
         dkros:hasSource \"package/Tf{i}\" ;\n\
         dkros:hasParam [ a dyknow:Parameter ; dyknow:hasName \"config\" ; dyknow:hasValue \"/etc/tf/{i}\" ] ;\n\
         dkros:hasPort [ a dyknow:InPort ; dyknow:hasName \"in\" ; dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"stream({})\" ] ] ;\n\
         dkros:hasPort [ a dyknow:OutPort ; dyknow:hasName \"out\" ; dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"stream({i})\" ] ] ;\n\
         dyknow:hasCostModel [ a dyknow:LabourCostModel ; dyknow:hasValue 1.0 ] , [ a dyknow:UpkeepCostModel ; dyknow:hasValue 1.0 ] .\n",
        i.saturating_sub(1)
    )
}
