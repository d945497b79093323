#![expect(
    clippy::expect_used,
    reason = "a benchmark harness: a failed set-up aborts the run"
)]
//! Knowledge-service benchmark (issue: knowledge service core). Prints a table.
//!
//! * Ingestion on the on-disk store: 1,000 single-spec POSTs in sequence, and one POST of a
//!   batch of 10,000 specs.
//! * SPARQL: three queries over 10,000 transformations, against `dyknow serve` and, side by side
//!   in the same run, `oxigraph serve` (PyPI package `oxigraph`) loaded with the same quads
//!   (`--union-default-graph`, so both answer over the same union).
//!
//! Both servers run as child processes on loopback and are driven by the same HTTP client.
//! `OXIGRAPH_BIN` names the peer's binary (`./dev bench` installs it); without it the peer's
//! column is left empty. `BENCH_QUICK=1` shrinks the sizes for a smoke run.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

struct Server {
    child: Child,
    url: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .unwrap_or(17878)
}

fn start_dyknow(data: &std::path::Path) -> Server {
    // `DYKNOW_BIN` (as `benches/run.sh` sets it: the `dist` build, optimised as the peer's
    // release is) or the binary Cargo built for this bench.
    let bin =
        std::env::var("DYKNOW_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_dyknow").to_owned());
    let mut child = Command::new(bin)
        .args(["serve", "--bind", "127.0.0.1:0", "--data"])
        .arg(data)
        .env("RUST_LOG", "warn,dyknow_server=info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("dyknow binary");
    let mut lines = BufReader::new(child.stderr.take().expect("stderr")).lines();
    let url = loop {
        let line = lines.next().expect("dyknow exited").expect("stderr line");
        if let Some(rest) = line.split("listening on ").nth(1) {
            break rest.split_whitespace().next().expect("address").to_owned();
        }
    };
    std::thread::spawn(move || for _ in lines {});
    Server { child, url }
}

fn start_oxigraph(bin: &str, location: &std::path::Path) -> Server {
    let port = free_port();
    let child = Command::new(bin)
        .args(["serve", "--union-default-graph", "--bind"])
        .arg(format!("127.0.0.1:{port}"))
        .arg("--location")
        .arg(location)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("oxigraph binary");
    let url = format!("http://127.0.0.1:{port}");
    let deadline = Instant::now() + Duration::from_secs(30);
    while agent().get(&url).call().is_err() {
        assert!(Instant::now() < deadline, "oxigraph serve did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    Server { child, url }
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(600)))
        .build()
        .into()
}

#[path = "../../benches/bench_specs.rs"]
mod bench_specs;
use bench_specs::{PREFIXES, spec};

fn post(agent: &ureq::Agent, url: &str, content_type: &str, body: &[u8]) -> u16 {
    let mut r = agent
        .post(url)
        .header("Content-Type", content_type)
        .send(body)
        .expect("request");
    let _ = r.body_mut().read_to_vec();
    r.status().as_u16()
}

fn query(agent: &ureq::Agent, endpoint: &str, q: &str) -> (Duration, Vec<u8>) {
    let start = Instant::now();
    let mut r = agent
        .post(endpoint)
        .header("Content-Type", "application/sparql-query")
        .header("Accept", "application/sparql-results+json")
        .send(q.as_bytes())
        .expect("query");
    let body = r.body_mut().read_to_vec().expect("body");
    let elapsed = start.elapsed();
    assert_eq!(
        r.status().as_u16(),
        200,
        "{}",
        String::from_utf8_lossy(&body)
    );
    (elapsed, body)
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn rows_of(json: &[u8]) -> usize {
    serde_json::from_slice::<serde_json::Value>(json)
        .ok()
        .and_then(|v| v["results"]["bindings"].as_array().map(Vec::len))
        .unwrap_or(0)
}

fn main() {
    // `cargo bench` passes --bench; a filter argument is not supported by this harness.
    let quick = std::env::var("BENCH_QUICK").is_ok();
    // `BENCH_ONLY=sparql` skips the ingestion half (the queries load their own store).
    let sparql_only = std::env::var("BENCH_ONLY").is_ok_and(|v| v == "sparql");
    let (singles, batch, reps) = if quick {
        (100, 1_000, 11)
    } else {
        (1_000, 10_000, 101)
    };
    let peer = std::env::var("OXIGRAPH_BIN")
        .ok()
        .filter(|p| std::path::Path::new(p).exists());
    let dir = tempfile::tempdir().expect("tempdir");
    let agent = agent();
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "# DyKnow knowledge service benchmark ({singles} single POSTs, batch of {batch}, {reps} runs per query)"
    );

    if !sparql_only {
        ingestion(
            &agent,
            &mut out,
            dir.path(),
            peer.as_deref(),
            singles,
            batch,
        );
    }
    sparql(&agent, &mut out, dir.path(), peer.as_deref(), batch, reps);
}

/// Single POSTs and one batch POST, against the peer's loads of the same data.
fn ingestion(
    agent: &ureq::Agent,
    out: &mut impl Write,
    dir: &std::path::Path,
    peer: Option<&str>,
    singles: usize,
    batch: usize,
) {
    // --- Ingestion -----------------------------------------------------------------------
    let server = start_dyknow(&dir.join("ingest"));
    let url = format!("{}/transformations", server.url);
    let bodies: Vec<String> = (0..singles)
        .map(|i| format!("{PREFIXES}{}", spec(i)))
        .collect();
    let start = Instant::now();
    for body in &bodies {
        assert_eq!(post(agent, &url, "text/turtle", body.as_bytes()), 201);
    }
    let single_rate = singles as f64 / start.elapsed().as_secs_f64();
    let mut doc = String::from(PREFIXES);
    for i in singles..singles + batch {
        doc.push_str(&spec(i));
    }
    let start = Instant::now();
    assert_eq!(post(agent, &url, "text/turtle", doc.as_bytes()), 201);
    let batch_elapsed = start.elapsed();
    let batch_rate = batch as f64 / batch_elapsed.as_secs_f64();
    drop(server);

    // Peer ingestion of the same specs as N-Triples graphs (no validation), for scale.
    let mut peer_single_rate = None;
    if let Some(bin) = peer {
        let p = start_oxigraph(bin, &dir.join("peer-ingest"));
        let nt: Vec<Vec<u8>> = bodies.iter().map(|b| turtle_to_ntriples(b)).collect();
        let start = Instant::now();
        for (i, body) in nt.iter().enumerate() {
            let status = post(
                agent,
                &format!("{}/store?graph=urn:bench:{i}", p.url),
                "application/n-triples",
                body,
            );
            assert!(status == 201 || status == 204, "oxigraph answered {status}");
        }
        peer_single_rate = Some(singles as f64 / start.elapsed().as_secs_f64());
    }

    // Peer batch ingestion of the same 10,000 specs: the same Turtle document into its default
    // graph, and the same quads DyKnow stores (after normalisation) into the same named graphs,
    // transactionally and with its bulk loader. Each on a fresh on-disk store.
    let mut peer_batch: Vec<(&str, Duration)> = Vec::new();
    if let Some(bin) = peer {
        let nquads = spec_quads(&doc);
        for (i, (what, path, content_type, body)) in [
            (
                "same Turtle document, default graph (`POST /store?default`)",
                "/store?default",
                "text/turtle",
                doc.as_bytes(),
            ),
            (
                "same quads in the same named graphs (`POST /store`, N-Quads)",
                "/store",
                "application/n-quads",
                nquads.as_slice(),
            ),
            (
                "same quads, bulk loader (`POST /store?no_transaction`)",
                "/store?no_transaction",
                "application/n-quads",
                nquads.as_slice(),
            ),
        ]
        .into_iter()
        .enumerate()
        {
            let p = start_oxigraph(bin, &dir.join(format!("peer-batch-{i}")));
            let start = Instant::now();
            let status = post(agent, &format!("{}{path}", p.url), content_type, body);
            assert!(status == 201 || status == 204, "oxigraph answered {status}");
            peer_batch.push((what, start.elapsed()));
        }
    }

    let _ = writeln!(out, "\n## Ingestion (on-disk store, HTTP on loopback)\n");
    let _ = writeln!(
        out,
        "| measure | dyknow | oxigraph serve (POST /store, no validation) | bar |"
    );
    let _ = writeln!(out, "| --- | --- | --- | --- |");
    let _ = writeln!(
        out,
        "| {singles} single-spec POSTs, sequential | {single_rate:.0} POSTs/s | {} | ≥ 500 POSTs/s |",
        peer_single_rate.map_or("n/a".into(), |r| format!("{r:.0} POSTs/s"))
    );
    let _ = writeln!(
        out,
        "| one POST of {batch} specs ({:.1} MB Turtle) | {batch_rate:.0} specs/s ({:.0} ms) | | ≥ 20,000 specs/s |",
        doc.len() as f64 / 1e6,
        batch_elapsed.as_secs_f64() * 1e3
    );
    if !peer_batch.is_empty() {
        let _ = writeln!(
            out,
            "\nThe same {batch} specs loaded by the peer in one POST (fresh on-disk store each):\n"
        );
        let _ = writeln!(
            out,
            "| oxigraph serve | time | specs/s equivalent | dyknow time / peer time |"
        );
        let _ = writeln!(out, "| --- | --- | --- | --- |");
        for (what, elapsed) in &peer_batch {
            let _ = writeln!(
                out,
                "| {what} | {:.0} ms | {:.0} | {:.2} |",
                elapsed.as_secs_f64() * 1e3,
                batch as f64 / elapsed.as_secs_f64(),
                batch_elapsed.as_secs_f64() / elapsed.as_secs_f64()
            );
        }
    }
}

/// The three queries, against the peer's two layouts of the same data.
fn sparql(
    agent: &ureq::Agent,
    out: &mut impl Write,
    dir: &std::path::Path,
    peer: Option<&str>,
    batch: usize,
    reps: usize,
) {
    // --- SPARQL ---------------------------------------------------------------------------
    let data = dir.join("sparql");
    let server = start_dyknow(&data);
    let mut doc = String::from(PREFIXES);
    for i in 0..batch {
        doc.push_str(&spec(i));
    }
    assert_eq!(
        post(
            agent,
            &format!("{}/transformations", server.url),
            "text/turtle",
            doc.as_bytes()
        ),
        201
    );
    // Two peers: the same quads in the same named graphs (answering over their union, as we
    // do), and the same triples in the default graph (no union to compute).
    let mut peers: Vec<Server> = Vec::new();
    if let Some(bin) = peer {
        let kb = dyknow_store::KnowledgeBase::in_memory().expect("store");
        kb.post_specs(
            doc.as_bytes(),
            dyknow_store::InputFormat::Turtle,
            dyknow_store::spec::SpecKind::Transformation,
        )
        .expect("batch");
        let mut nquads = Vec::new();
        kb.store()
            .dump_to_writer(dyknow_store::oxigraph::io::RdfFormat::NQuads, &mut nquads)
            .expect("dump quads");
        let triples = kb.model_triples(true).expect("triples");
        let ntriples =
            dyknow_store::serialize(&triples, dyknow_store::oxigraph::io::RdfFormat::NTriples)
                .expect("dump triples");
        for (file, body) in [("model.nq", nquads), ("model.nt", ntriples)] {
            let path = dir.join(file);
            std::fs::write(&path, &body).expect("write dump");
            let location = dir.join(format!("peer-{file}"));
            let status = Command::new(bin)
                .args(["load", "--location"])
                .arg(&location)
                .arg("--file")
                .arg(&path)
                .stderr(Stdio::null())
                .status()
                .expect("oxigraph load");
            assert!(status.success());
            peers.push(start_oxigraph(bin, &location));
        }
    }
    let queries = [
        (
            "lookup by label",
            "PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#> SELECT ?t WHERE { ?t rdfs:label \"tf-05000\" }",
        ),
        (
            "ports and tags of all transformations",
            "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#> \
             SELECT ?label ?port ?tag WHERE { ?t a dyknow:Transformation ; rdfs:label ?label ; \
             (dyknow:hasInPort|dyknow:hasOutPort) ?p . ?p dyknow:hasName ?port ; dyknow:hasTag/dyknow:hasValue ?tag }",
        ),
        (
            "count",
            "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> SELECT (COUNT(?t) AS ?n) WHERE { ?t a dyknow:Transformation }",
        ),
    ];
    let _ = writeln!(
        out,
        "\n## SPARQL over {batch} transformations (median of {reps} runs, same client, interleaved)\n"
    );
    let _ = writeln!(
        out,
        "| query | rows | dyknow | oxigraph: same quads, named graphs, union | ratio | oxigraph: same triples, default graph | ratio | bar |"
    );
    let _ = writeln!(out, "| --- | --- | --- | --- | --- | --- | --- | --- |");
    for (name, q) in queries {
        let ours_endpoint = format!("{}/sparql", server.url);
        let peer_endpoints: Vec<String> =
            peers.iter().map(|p| format!("{}/query", p.url)).collect();
        // Warm-up, and a check that every server answers the same number of rows.
        let (_, ours_body) = query(agent, &ours_endpoint, q);
        let rows = rows_of(&ours_body);
        for pe in &peer_endpoints {
            let (_, peer_body) = query(agent, pe, q);
            assert_eq!(rows, rows_of(&peer_body), "{name}: {pe} disagrees");
        }
        let mut ours = Vec::new();
        let mut theirs: Vec<Vec<Duration>> = vec![Vec::new(); peer_endpoints.len()];
        for _ in 0..reps {
            ours.push(query(agent, &ours_endpoint, q).0);
            for (i, pe) in peer_endpoints.iter().enumerate() {
                theirs[i].push(query(agent, pe, q).0);
            }
        }
        let ours = median(ours);
        let mut cells = String::new();
        for i in 0..2 {
            match theirs.get(i).filter(|t| !t.is_empty()) {
                Some(t) => {
                    let t = median(t.clone());
                    cells.push_str(&format!(
                        " {:.3} ms | {:.2} |",
                        t.as_secs_f64() * 1e3,
                        ours.as_secs_f64() / t.as_secs_f64()
                    ));
                }
                None => cells.push_str(" n/a | n/a |"),
            }
        }
        let _ = writeln!(
            out,
            "| {name} | {rows} | {:.3} ms |{cells} ≤ 1.2 |",
            ours.as_secs_f64() * 1e3
        );
    }
}

/// The quads DyKnow stores for a document of transformation specs (its spec graphs, after
/// normalisation and skolemisation), as N-Quads.
fn spec_quads(turtle: &str) -> Vec<u8> {
    let kb = dyknow_store::KnowledgeBase::in_memory().expect("store");
    kb.post_specs(
        turtle.as_bytes(),
        dyknow_store::InputFormat::Turtle,
        dyknow_store::spec::SpecKind::Transformation,
    )
    .expect("batch");
    let quads: Vec<dyknow_store::oxigraph::model::Quad> = kb
        .store()
        .iter()
        .map(|q| q.expect("quad"))
        .filter(|q| {
            matches!(&q.graph_name, dyknow_store::oxigraph::model::GraphName::NamedNode(g)
                if g.as_str().starts_with("urn:dyknow:graph:transformation:"))
        })
        .collect();
    let mut out = Vec::new();
    let mut writer = dyknow_store::oxigraph::io::RdfSerializer::from_format(
        dyknow_store::oxigraph::io::RdfFormat::NQuads,
    )
    .for_writer(&mut out);
    for q in &quads {
        writer.serialize_quad(q).expect("serialise");
    }
    writer.finish().expect("serialise");
    out
}

/// Converts a Turtle document to N-Triples (for the peer, which gets plain graphs).
fn turtle_to_ntriples(turtle: &str) -> Vec<u8> {
    let triples = dyknow_store::parse_triples(turtle.as_bytes(), dyknow_store::InputFormat::Turtle)
        .expect("valid Turtle");
    dyknow_store::serialize(&triples, dyknow_store::oxigraph::io::RdfFormat::NTriples)
        .expect("serialise")
}
