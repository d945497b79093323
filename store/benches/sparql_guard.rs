//! The cost of the SPARQL cancellation guard (`store/src/sparql/guard.rs`):
//! `cargo bench --workspace --bench sparql_guard`.
//!
//! An on-disk knowledge base of 10,000 transformations (as `knowledge_service` loads them:
//! a parameter, an in and an out port with tags). Each query runs guarded, as the service runs
//! it (`ParsedQuery` and `KnowledgeBase::run_query`, JSON results), and unchanged through
//! oxigraph's own evaluator over the same store with the same serialisation, interleaved,
//! median of `REPS` runs (default 41). The table gives both and their ratio; the rows count
//! must agree or the bench aborts.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::time::{Duration, Instant};

use dyknow_store::oxigraph::sparql::results::{QueryResultsFormat, QueryResultsSerializer};
use dyknow_store::oxigraph::sparql::{QueryResults, SparqlEvaluator};
use dyknow_store::spec::SpecKind;
use dyknow_store::{InputFormat, KnowledgeBase, ParsedQuery, ResultFormat};

const P: &str = "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> \
                 PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#> ";

fn specs(n: usize) -> String {
    let mut doc = String::from(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n",
    );
    for i in 0..n {
        doc.push_str(&format!(
            "[] a dyknow:Transformation ; rdfs:label \"tf-{i:05}\" ;\n\
             <http://www.dyknow.eu/ontology/dyknow-ros#hasParam> [ dyknow:hasName \"p\" ; dyknow:hasValue \"1\" ] ;\n\
             dyknow:hasInPort [ dyknow:hasName \"in\" ; dyknow:hasTag [ dyknow:hasValue \"In{}\" ] ] ;\n\
             dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"Out{i}\" ] ] .\n",
            i % 50
        ));
    }
    doc
}

fn guarded(kb: &KnowledgeBase, query: &str) -> Vec<u8> {
    let parsed = ParsedQuery::parse(query).unwrap();
    kb.run_query(
        parsed,
        ResultFormat::Results(QueryResultsFormat::Json),
        Duration::from_secs(600),
    )
    .unwrap()
    .body
}

fn unguarded(kb: &KnowledgeBase, query: &str) -> Vec<u8> {
    let mut prepared = SparqlEvaluator::new().parse_query(query).unwrap();
    prepared.dataset_mut().set_default_graph_as_union();
    let QueryResults::Solutions(solutions) = prepared.on_store(kb.store()).execute().unwrap()
    else {
        panic!("a SELECT")
    };
    let mut body = Vec::new();
    let mut w = QueryResultsSerializer::from_format(QueryResultsFormat::Json)
        .serialize_solutions_to_writer(&mut body, solutions.variables().to_vec())
        .unwrap();
    for s in solutions {
        w.serialize(&s.unwrap()).unwrap();
    }
    w.finish().unwrap();
    body
}

fn rows(body: &[u8]) -> usize {
    let v: serde_json::Value = serde_json::from_slice(body).unwrap();
    v["results"]["bindings"].as_array().unwrap().len()
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn main() {
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(41);
    let dir = tempfile::tempdir().unwrap();
    let kb = KnowledgeBase::open(dir.path().join("store")).unwrap();
    kb.post_specs(
        specs(10_000).as_bytes(),
        InputFormat::Turtle,
        SpecKind::Transformation,
    )
    .unwrap();
    let queries = [
        (
            "lookup by label (1 pattern: not guarded)",
            format!("{P} SELECT ?t WHERE {{ ?t rdfs:label \"tf-05000\" }}"),
        ),
        (
            "count (1 pattern: not guarded)",
            format!("{P} SELECT (COUNT(?t) AS ?n) WHERE {{ ?t a dyknow:Transformation }}"),
        ),
        (
            "ports and tags of all transformations",
            format!(
                "{P} SELECT ?label ?port ?tag WHERE {{ ?t a dyknow:Transformation ; rdfs:label ?label ; \
                 (dyknow:hasInPort|dyknow:hasOutPort) ?p . ?p dyknow:hasName ?port ; dyknow:hasTag/dyknow:hasValue ?tag }}"
            ),
        ),
        (
            "labels and in tags (a 4-pattern join)",
            format!(
                "{P} SELECT ?label ?tag WHERE {{ ?t rdfs:label ?label ; dyknow:hasInPort ?p . \
                 ?p dyknow:hasTag ?g . ?g dyknow:hasValue ?tag }}"
            ),
        ),
        (
            "count of a 4-pattern join",
            format!(
                "{P} SELECT (COUNT(*) AS ?n) WHERE {{ ?t rdfs:label ?label ; dyknow:hasInPort ?p . \
                 ?p dyknow:hasTag ?g . ?g dyknow:hasValue ?tag }}"
            ),
        ),
    ];
    println!(
        "# SPARQL cancellation guard: 10,000 transformations, on-disk store, median of {reps} runs, interleaved\n"
    );
    println!("| query | rows | guarded (the service) | oxigraph, unchanged | ratio |");
    println!("| --- | --- | --- | --- | --- |");
    for (name, query) in &queries {
        let (a, b) = (guarded(&kb, query), unguarded(&kb, query));
        let n = rows(&a);
        assert_eq!(n, rows(&b), "{name}: the answers differ");
        let (mut g, mut u) = (Vec::new(), Vec::new());
        for i in 0..reps {
            let one = |guard: bool| {
                let started = Instant::now();
                let body = if guard {
                    guarded(&kb, query)
                } else {
                    unguarded(&kb, query)
                };
                std::hint::black_box(body);
                started.elapsed()
            };
            if i % 2 == 0 {
                g.push(one(true));
                u.push(one(false));
            } else {
                u.push(one(false));
                g.push(one(true));
            }
        }
        let (g, u) = (median(g), median(u));
        println!(
            "| {name} | {n} | {:.3} ms | {:.3} ms | {:.3} |",
            g.as_secs_f64() * 1e3,
            u.as_secs_f64() * 1e3,
            g.as_secs_f64() / u.as_secs_f64()
        );
    }
}
