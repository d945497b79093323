use dyknow_store::{InputFormat, KnowledgeBase, ModelFormat, spec::SpecKind, ParsedQuery, MODEL_ONTOLOGY_IRI};
use dyknow_store::oxigraph::io::RdfFormat;

fn unparsed(nt: &[u8]) -> usize {
    dyknow_ontology::rdf_to_owl(nt, RdfFormat::NTriples, dyknow_ontology::OwlSyntax::Functional).unwrap().unparsed_triples
}

#[test]
fn explore() {
    let kb = KnowledgeBase::in_memory().unwrap();
    let base = kb.export(ModelFormat::OwlFunctional, true).unwrap().unparsed_triples;
    println!("empty unparsed {base}");
    kb.post_specs(include_bytes!("../../specs/turtle/listing-5.3-undistort.ttl"), InputFormat::Turtle, SpecKind::Transformation).unwrap();
    let e = kb.export(ModelFormat::OwlFunctional, true).unwrap();
    println!("5.3 unparsed {}", e.unparsed_triples);
    let ex = kb.export(ModelFormat::OwlXml, true).unwrap();
    println!("5.3 owx unparsed {}", ex.unparsed_triples);
    // find the culprit triples
    let all = kb.model_triples(true).unwrap();
    let spec: Vec<_> = kb.graph_triples(dyknow_store::graphs::spec_graph(SpecKind::Transformation, "Undistort(cam1)").as_ref()).unwrap();
    let onto: Vec<_> = all.iter().filter(|t| !spec.contains(t)).cloned().collect();
    let mut hdr = vec![dyknow_store::oxigraph::model::Triple::new(dyknow_store::oxigraph::model::NamedNode::new_unchecked(MODEL_ONTOLOGY_IRI), dyknow_store::oxigraph::model::NamedNode::new_unchecked("http://www.w3.org/1999/02/22-rdf-syntax-ns#type"), dyknow_store::oxigraph::model::NamedNode::new_unchecked("http://www.w3.org/2002/07/owl#Ontology"))];
    hdr.extend(onto.iter().filter(|t| !t.to_string().contains("owl#Ontology>")).cloned());
    let base_nt = dyknow_store::serialize(&hdr, RdfFormat::NTriples).unwrap();
    let b = unparsed(&base_nt);
    println!("onto only {b}");
    for t in &spec {
        let mut v = hdr.clone(); v.push(t.clone());
        let u = unparsed(&dyknow_store::serialize(&v, RdfFormat::NTriples).unwrap());
        if u != b { println!("UNPARSED {u}: {t}"); }
    }
    for t in &spec { println!("SPEC {t}"); }
    for q in ["SELECT ?x WHERE {\n  ?x ?y ?z .\n  FILTER(?x = )\n}", "SELEC * WHERE { ?s ?p ?o }", "SELECT * WHERE { ?s ?p ?o"] {
        println!("{:?}", ParsedQuery::parse(q).err());
    }
}
