//! scratch
use dyknow_store::{InputFormat, KnowledgeBase, spec::SpecKind};
#[test]
fn explore() {
    let kb = KnowledgeBase::in_memory().unwrap();
    for n in [1000usize, 2000, 4000, 8000] {
        let ports: Vec<String> = (0..n).map(|i| format!("dyknow:hasOutPort [ dyknow:hasName \"p{i}\" ; dyknow:hasTag [ dyknow:hasValue \"T\" ] ]")).collect();
        let body = format!("@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n[] a dyknow:Transformation ; rdfs:label \"x\" ;\n{} .\n", ports.join(" ;\n"));
        let t = std::time::Instant::now();
        let _ = dyknow_store::parse_triples(body.as_bytes(), InputFormat::Turtle).unwrap();
        let p = t.elapsed();
        let r = kb.post_specs(body.as_bytes(), InputFormat::Turtle, SpecKind::Transformation);
        println!("ports {n}: parse {p:?} total {:?} ok={}", t.elapsed(), r.is_ok());
    }
    for n in [1000usize, 2000, 4000, 8000] {
        let params: Vec<String> = (0..n).map(|i| format!("dkros:hasParam [ dyknow:hasName \"p{i}\" ; dyknow:hasValue \"v\" ]")).collect();
        let body = format!("@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n@prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .\n@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n[] a dyknow:Transformation ; rdfs:label \"x\" ; dyknow:hasOutPort [ dyknow:hasName \"o\" ; dyknow:hasTag [ dyknow:hasValue \"T\" ] ] ;\n{} .\n", params.join(" ;\n"));
        let t = std::time::Instant::now();
        let r = kb.post_specs(body.as_bytes(), InputFormat::Turtle, SpecKind::Transformation);
        println!("params {n}: total {:?} ok={}", t.elapsed(), r.is_ok());
    }
}
