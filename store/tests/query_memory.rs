//! SPARQL queries bounded in memory (`ParsedQuery::with_memory_limit`), with the counting
//! allocator installed as `dyknow serve` installs it.
// Helpers outside `#[test]` functions are test code too.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::Duration;

use dyknow_meter::{Budget, Counting};
use dyknow_store::oxigraph::io::RdfFormat;
use dyknow_store::oxigraph::sparql::results::QueryResultsFormat;
use dyknow_store::spec::SpecKind;
use dyknow_store::{
    InputFormat, KnowledgeBase, ParsedQuery, QueryAnswer, ResultFormat, SparqlQueryError,
};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const JSON: ResultFormat = ResultFormat::Results(QueryResultsFormat::Json);
const MIB: usize = 1 << 20;

/// `n` transformations, as the benchmarks post them.
fn specs(n: usize) -> String {
    let mut doc = String::from(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n",
    );
    for i in 0..n {
        doc.push_str(&format!(
            "[] a dyknow:Transformation ; rdfs:label \"tf-{i:05}\" ;\n\
             dyknow:hasInPort [ dyknow:hasName \"in\" ; dyknow:hasTag [ dyknow:hasValue \"In{}\" ] ] ;\n\
             dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"Out{i}\" ] ] .\n",
            i % 50
        ));
    }
    doc
}

/// Runs `query` with a memory limit of `limit` bytes (none: `None`), cancelled after 5 s (a
/// bound that does not hold fails a test as a timeout rather than exhausting the machine: the
/// limits here are passed within milliseconds). Returns the answer and the most the running
/// thread held meanwhile.
fn run(
    kb: &KnowledgeBase,
    query: &str,
    format: ResultFormat,
    limit: Option<usize>,
) -> (Result<QueryAnswer, SparqlQueryError>, isize) {
    let stop = Duration::from_secs(5);
    let mut parsed = ParsedQuery::parse(query).expect("parses");
    if let Some(bytes) = limit {
        parsed = parsed.with_memory_limit(bytes);
    }
    let token = parsed.cancellation_token();
    let (done, finished) = std::sync::mpsc::channel::<()>();
    let watchdog = std::thread::spawn(move || {
        if finished.recv_timeout(stop).is_err() {
            token.cancel();
        }
    });
    let outer = Budget::start(usize::MAX);
    let answer = kb.run_query(parsed, format, stop);
    let peak = outer.peak();
    drop(outer);
    let _ = done.send(());
    watchdog.join().unwrap();
    (answer, peak)
}

#[test]
fn queries_that_keep_or_write_more_than_their_limit_are_stopped_near_it() {
    // The products over the ontology alone (the matches of one probe row, which a join
    // buffers between two checks, grow with the store); one pattern over 2,000 specs.
    let ontology = KnowledgeBase::in_memory().unwrap();
    let library = KnowledgeBase::in_memory().unwrap();
    library
        .post_specs(
            specs(2_000).as_bytes(),
            InputFormat::Turtle,
            SpecKind::Transformation,
        )
        .unwrap();
    let cases = [
        // The solutions of a sorted product, kept for the sort (750 MB a second unbounded).
        (
            "SELECT ?a ?d ?g WHERE { ?a ?b ?c . ?d ?e ?f . ?g ?h ?i } ORDER BY ?c ?f ?i LIMIT 1",
            JSON,
            16 * MIB,
        ),
        // The distinct solutions of a product, kept in a set.
        (
            "SELECT DISTINCT ?c ?f ?i WHERE { ?a ?b ?c . ?d ?e ?f . ?g ?h ?i }",
            JSON,
            16 * MIB,
        ),
        // An OPTIONAL whose side is a product, built before the first solution is made (the
        // allocation that passes the limit cancels the query; its reads notice).
        (
            "SELECT ?s WHERE { ?s a ?k OPTIONAL { ?a ?b ?c . ?d ?e ?f } } LIMIT 1",
            JSON,
            16 * MIB,
        ),
        // A product written out: the answer itself grows.
        ("SELECT * WHERE { ?a ?b ?c . ?d ?e ?f }", JSON, 16 * MIB),
        (
            "CONSTRUCT { ?a ?b ?f } WHERE { ?a ?b ?c . ?d ?e ?f }",
            ResultFormat::Rdf(RdfFormat::NTriples),
            16 * MIB,
        ),
        // One pattern, no join (no guard): stopped at its reads, and the answer.
        (
            "SELECT * WHERE { ?s ?p ?o } ORDER BY ?o",
            ResultFormat::Results(QueryResultsFormat::Xml),
            MIB,
        ),
    ];
    for (query, format, limit) in cases {
        let kb = if limit < 16 * MIB {
            &library
        } else {
            &ontology
        };
        // Passed by at most one growth of a buffer (a doubling) and what one solution holds.
        let bound = 2 * limit as isize + 4 * MIB as isize;
        // The case can fail: under a limit twice the bound (which stops it without a race
        // against the clock), the query holds more than the bound.
        let (_, free) = run(kb, query, format, Some(2 * bound as usize));
        assert!(
            free > bound,
            "held only {free} bytes under a larger limit: {query}"
        );
        let (answer, peak) = run(kb, query, format, Some(limit));
        match answer {
            Err(SparqlQueryError::MemoryLimit(bytes)) => assert_eq!(bytes, limit),
            other => panic!(
                "expected the memory limit, got {:?}: {query}",
                other.map(|a| a.body.len())
            ),
        }
        assert!(
            peak <= bound,
            "held {peak} bytes, more than {bound}: {query}"
        );
    }
    // Nothing is left poisoned: the store answers on.
    let (answer, _) = run(&ontology, "ASK { ?s ?p ?o }", JSON, Some(16 * MIB));
    assert!(answer.is_ok());
}

#[test]
fn a_query_within_its_limit_answers_as_without_one() {
    let kb = KnowledgeBase::in_memory().unwrap();
    for (query, format) in [
        (
            "CONSTRUCT WHERE { ?s ?p ?o }",
            ResultFormat::Rdf(RdfFormat::NTriples),
        ),
        (
            "SELECT ?s (COUNT(*) AS ?n) WHERE { ?s ?p ?o . ?o ?q ?r } GROUP BY ?s ORDER BY ?s",
            JSON,
        ),
        (
            "SELECT * WHERE { ?s ?p ?o OPTIONAL { ?o ?q ?r } } ORDER BY ?s ?p ?o ?q ?r",
            ResultFormat::Results(QueryResultsFormat::Csv),
        ),
    ] {
        let (bounded, _) = run(&kb, query, format, Some(64 * MIB));
        let (free, _) = run(&kb, query, format, None);
        assert_eq!(
            bounded.expect("within the limit").body,
            free.expect("no limit").body,
            "{query}"
        );
    }
}

#[test]
fn without_a_limit_a_query_holds_what_it_needs() {
    let kb = KnowledgeBase::in_memory().unwrap();
    let query = "CONSTRUCT WHERE { ?s ?p ?o }";
    let ntriples = ResultFormat::Rdf(RdfFormat::NTriples);
    let (free, peak) = run(&kb, query, ntriples, None);
    let body = free.expect("no limit").body;
    assert!(peak >= body.len() as isize, "the answer is counted: {peak}");
    // The same answer does not fit a limit below its size.
    let (bounded, _) = run(&kb, query, ntriples, Some(body.len() / 2));
    assert!(matches!(bounded, Err(SparqlQueryError::MemoryLimit(_))));
}
