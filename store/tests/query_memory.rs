//! SPARQL queries bounded in memory (`ParsedQuery::with_memory_limit`), with the counting
//! allocator installed as `dyknow serve` installs it.
// Helpers outside `#[test]` functions are test code too.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::Duration;

use dyknow_meter::{Budget, Counting};
use dyknow_store::oxigraph::io::RdfFormat;
use dyknow_store::oxigraph::sparql::results::QueryResultsFormat;
use dyknow_store::{KnowledgeBase, ParsedQuery, QueryAnswer, ResultFormat, SparqlQueryError};

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const JSON: ResultFormat = ResultFormat::Results(QueryResultsFormat::Json);
const MIB: usize = 1 << 20;

/// Runs `query` with a memory limit of `limit` bytes (none: `None`); cancelled after 5 s so
/// that a bound that does not hold fails the test as a timeout rather than exhausting the
/// machine (the limits here are passed within milliseconds). Returns the answer and the most
/// the running thread held meanwhile.
fn run(
    kb: &KnowledgeBase,
    query: &str,
    format: ResultFormat,
    limit: Option<usize>,
) -> (Result<QueryAnswer, SparqlQueryError>, isize) {
    let mut parsed = ParsedQuery::parse(query).expect("parses");
    if let Some(bytes) = limit {
        parsed = parsed.with_memory_limit(bytes);
    }
    let token = parsed.cancellation_token();
    let (stop, stopped) = std::sync::mpsc::channel::<()>();
    let watchdog = std::thread::spawn(move || {
        if stopped.recv_timeout(Duration::from_secs(5)).is_err() {
            token.cancel();
        }
    });
    let outer = Budget::start(usize::MAX);
    let answer = kb.run_query(parsed, format, Duration::from_secs(5));
    let peak = outer.peak();
    drop(outer);
    let _ = stop.send(());
    watchdog.join().unwrap();
    (answer, peak)
}

#[test]
fn queries_that_keep_or_write_more_than_their_limit_are_stopped_near_it() {
    let kb = KnowledgeBase::in_memory().unwrap();
    let limit = 16 * MIB;
    let cases = [
        // The solutions of a sorted product, kept for the sort (750 MB a second unbounded).
        (
            "SELECT ?a ?d ?g WHERE { ?a ?b ?c . ?d ?e ?f . ?g ?h ?i } ORDER BY ?c ?f ?i LIMIT 1",
            JSON,
        ),
        // The distinct solutions of a product, kept in a set.
        (
            "SELECT DISTINCT ?c ?f ?i WHERE { ?a ?b ?c . ?d ?e ?f . ?g ?h ?i }",
            JSON,
        ),
        // An OPTIONAL whose side is a product, built before the first solution is made (the
        // allocation that passes the limit cancels the query; its reads notice).
        (
            "SELECT ?s WHERE { ?s a ?k OPTIONAL { ?a ?b ?c . ?d ?e ?f } } LIMIT 1",
            JSON,
        ),
        // A product written out: the answer itself grows.
        ("SELECT * WHERE { ?a ?b ?c . ?d ?e ?f }", JSON),
        (
            "CONSTRUCT { ?a ?b ?f } WHERE { ?a ?b ?c . ?d ?e ?f }",
            ResultFormat::Rdf(RdfFormat::NTriples),
        ),
        // One pattern, no join: only the answer grows (the guard is not there).
        (
            "SELECT * WHERE { ?s ?p ?o } ORDER BY ?o",
            ResultFormat::Results(QueryResultsFormat::Xml),
        ),
    ];
    for (query, format) in cases {
        // Small enough for the last case to pass the limit.
        let limit = if query.contains("?d") {
            limit
        } else {
            32 * 1024
        };
        let (answer, peak) = run(&kb, query, format, Some(limit));
        match answer {
            Err(SparqlQueryError::MemoryLimit(bytes)) => assert_eq!(bytes, limit),
            other => panic!(
                "expected the memory limit, got {:?}: {query}",
                other.map(|a| a.body.len())
            ),
        }
        // Passed by at most one growth of a buffer (a doubling) and what one solution holds.
        let bound = 2 * limit as isize + 4 * MIB as isize;
        assert!(
            peak <= bound,
            "held {peak} bytes, more than {bound}: {query}"
        );
    }
    // Nothing is left poisoned: the store answers on.
    let (answer, _) = run(&kb, "ASK { ?s ?p ?o }", JSON, Some(limit));
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
