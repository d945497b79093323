//! Load (docs/reliability.md, guarantee 5): 64 concurrent HTTP clients on loopback against
//! `dyknow serve` (on-disk store) while the Chapter 6 pipeline runs live on a stand-alone
//! executor `piff`. Mixed reads (SPARQL, the spec list, `/cus`, the model export, the
//! environment) and writes (spec post and delete, group create and destroy) for
//! `--secs` seconds (default 600), and once per rotation in five `GET /health`, a handler that
//! does nothing: the latency floor of this machine under this load. Prints, per route: requests, unexpected answers (any
//! status but the expected one, or no answer within 30 s), p50, p99 and max latency; and the
//! manager's resident memory every 10 s.
//!
//! Then the peer, side by side: the same SPARQL query from 64 clients for `--peer-secs`
//! (default 30) against `dyknow serve` (Chapter 6 still running) and against `oxigraph serve`
//! (`OXIGRAPH_BIN`, as `benches/run.sh` installs it) loaded with the same triples, as a ratio.
//!
//! `cargo bench -p dyknow-server --bench load -- [--secs N] [--clients N] [--peer-secs N]`
//! (`DYKNOW_BIN` names another `dyknow` binary to measure, e.g. the `dist` build).

#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

/// The `dyknow` binary: `DYKNOW_BIN` (as `benches/run.sh` sets it, the `dist` build) or the
/// one Cargo built for this bench.
static BIN: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    std::env::var("DYKNOW_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_dyknow").to_owned())
});

/// The query of the SPARQL route (and of the peer).
const QUERY: &str = "SELECT ?s ?label WHERE { ?s <http://www.w3.org/2000/01/rdf-schema#label> ?label } ORDER BY ?label LIMIT 100";

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A child process stopped (SIGTERM, then SIGKILL) when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .status();
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Waits for a line containing `needle` on the child's standard error, then keeps draining it.
fn wait_for_line(child: &mut Child, needle: &str) -> String {
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let line = loop {
        let line = lines.next().expect("the process exited").unwrap();
        if line.contains(needle) {
            break line;
        }
    };
    std::thread::spawn(move || for _ in lines.map_while(Result::ok) {});
    line
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(30)))
        .build()
        .into()
}

fn spec(name: &str) -> String {
    std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../specs/turtle")
            .join(name),
    )
    .unwrap()
}

fn rss_kb(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.split_whitespace().next())
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

/// One request: its status (`None`: no answer) and latency.
fn request(
    agent: &ureq::Agent,
    method: &str,
    url: &str,
    body: Option<(&str, String)>,
) -> (Option<u16>, Duration) {
    let started = Instant::now();
    let req = ureq::http::Request::builder().method(method).uri(url);
    let answer = match body {
        Some((content_type, body)) => {
            agent.run(req.header("Content-Type", content_type).body(body).unwrap())
        }
        None => agent.run(req.body(()).unwrap()),
    };
    let status = answer.ok().and_then(|mut a| {
        let status = a.status().as_u16();
        a.body_mut()
            .with_config()
            .limit(256 * 1024 * 1024)
            .read_to_vec()
            .ok()
            .map(|_| status)
    });
    (status, started.elapsed())
}

#[derive(Default)]
struct Route {
    latencies: Vec<Duration>,
    unexpected: u64,
    examples: Vec<String>,
}

type Routes = Mutex<BTreeMap<&'static str, Route>>;

fn record(routes: &Routes, route: &'static str, expected: &[u16], answer: (Option<u16>, Duration)) {
    let mut routes = routes.lock().unwrap();
    let r = routes.entry(route).or_default();
    r.latencies.push(answer.1);
    if !answer.0.is_some_and(|s| expected.contains(&s)) {
        r.unexpected += 1;
        if r.examples.len() < 3 {
            r.examples
                .push(format!("{:?} after {:?}", answer.0, answer.1));
        }
    }
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

fn ms(d: Duration) -> String {
    format!("{:.1}", d.as_secs_f64() * 1e3)
}

/// One client's loop: a fixed rotation of operations until `stop`.
fn client(id: usize, url: &str, routes: &Routes, stop: &AtomicBool) {
    let agent = agent();
    let sparql = format!("{url}/sparql?query={}", url_encode(QUERY));
    let mut k = 0usize;
    while !stop.load(Ordering::Relaxed) {
        match (id + k) % 10 {
            0 | 5 => {
                record(
                    routes,
                    "GET /cus",
                    &[200],
                    request(&agent, "GET", &format!("{url}/cus"), None),
                );
                if (id + k).is_multiple_of(10) {
                    // The floor: a handler that does nothing, under the same load.
                    record(
                        routes,
                        "GET /health (no-op: the floor)",
                        &[200],
                        request(&agent, "GET", &format!("{url}/health"), None),
                    );
                }
            }
            1 => record(
                routes,
                "GET /sparql",
                &[200],
                request(&agent, "GET", &sparql, None),
            ),
            2 => record(
                routes,
                "GET /transformations",
                &[200],
                request(&agent, "GET", &format!("{url}/transformations"), None),
            ),
            3 => record(
                routes,
                "GET /model (turtle)",
                &[200],
                request(&agent, "GET", &format!("{url}/model?format=turtle"), None),
            ),
            4 => record(
                routes,
                "GET /environment",
                &[200],
                request(&agent, "GET", &format!("{url}/environment"), None),
            ),
            6 => {
                let label = format!("load-{id}-{k}");
                let turtle = format!(
                    "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
                     @prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .\n\
                     @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n\
                     [] a dkros:ROSTransformation ; rdfs:label \"{label}\" ; dkros:hasType \"builtin\" ; dkros:hasSource \"dyknow/relay\" ;\n\
                        dyknow:hasInPort [ dyknow:hasName \"in\" ; dyknow:hasTag [ dyknow:hasValue \"Load{id}\" ] ] ;\n\
                        dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"Loaded{id}\" ] ] .\n"
                );
                record(
                    routes,
                    "POST /transformations",
                    &[201],
                    request(
                        &agent,
                        "POST",
                        &format!("{url}/transformations"),
                        Some(("text/turtle", turtle)),
                    ),
                );
                record(
                    routes,
                    "DELETE /transformations/{label}",
                    &[200, 204],
                    request(
                        &agent,
                        "DELETE",
                        &format!("{url}/transformations/{label}"),
                        None,
                    ),
                );
            }
            7 => {
                let label = format!("load-{id}-{k}");
                let body =
                    json!({"label": label, "formulas": ["always InsideCircle(ball)"]}).to_string();
                record(
                    routes,
                    "POST /groups",
                    &[201],
                    request(
                        &agent,
                        "POST",
                        &format!("{url}/groups"),
                        Some(("application/json", body)),
                    ),
                );
                record(
                    routes,
                    "DELETE /groups/{label}",
                    &[200, 204],
                    request(&agent, "DELETE", &format!("{url}/groups/{label}"), None),
                );
            }
            8 => record(
                routes,
                "GET /targets",
                &[200],
                request(&agent, "GET", &format!("{url}/targets"), None),
            ),
            _ => record(
                routes,
                "GET /changesets",
                &[200],
                request(&agent, "GET", &format!("{url}/changesets"), None),
            ),
        }
        k += 1;
    }
}

fn url_encode(s: &str) -> String {
    s.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"-_.~".contains(&b) {
                char::from(b).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

/// `clients` clients running `one` until `secs` have passed.
fn run_clients(clients: usize, secs: u64, one: impl Fn(usize, &AtomicBool) + Sync) {
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        for id in 0..clients {
            let one = &one;
            let stop = &stop;
            std::thread::Builder::new()
                .stack_size(256 * 1024)
                .spawn_scoped(s, move || one(id, stop))
                .unwrap();
        }
        std::thread::sleep(Duration::from_secs(secs));
        stop.store(true, Ordering::SeqCst);
    });
}

fn table(routes: &Routes, secs: u64) -> u64 {
    let routes = routes.lock().unwrap();
    println!("| route | requests | per s | unexpected | p50 ms | p99 ms | max ms |");
    println!("| --- | --- | --- | --- | --- | --- | --- |");
    let mut unexpected = 0;
    for (name, r) in routes.iter() {
        let mut sorted = r.latencies.clone();
        sorted.sort_unstable();
        unexpected += r.unexpected;
        println!(
            "| {name} | {} | {:.1} | {}{} | {} | {} | {} |",
            sorted.len(),
            sorted.len() as f64 / secs as f64,
            r.unexpected,
            if r.examples.is_empty() {
                String::new()
            } else {
                format!(" (e.g. {})", r.examples.join("; "))
            },
            ms(percentile(&sorted, 0.5)),
            ms(percentile(&sorted, 0.99)),
            ms(sorted.last().copied().unwrap_or_default()),
        );
    }
    unexpected
}

fn arg(args: &[String], name: &str, default: u64) -> u64 {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let secs = arg(&args, "--secs", 600);
    let clients = arg(&args, "--clients", 64) as usize;
    let peer_secs = arg(&args, "--peer-secs", 30);
    let dir = tempfile::tempdir().unwrap();
    let zenoh = format!("tcp/127.0.0.1:{}", free_port());
    let mut child = Command::new(&*BIN)
        .args(["serve", "--data"])
        .arg(dir.path().join("store"))
        .args([
            "--bind",
            "127.0.0.1:0",
            "--zenoh-listen",
            &zenoh,
            "--no-executor",
        ])
        .env("RUST_LOG", "warn,dyknow_server=info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let line = wait_for_line(&mut child, "listening on ");
    let service = Process(child);
    let url = line
        .split("listening on ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .unwrap()
        .to_owned();
    let pid = service.0.id();
    let a = agent();
    for (path, file) in [
        ("/targets", "ch6-target.ttl"),
        ("/transformations", "ch6-live-piff.ttl"),
    ] {
        let (status, _) = request(
            &a,
            "POST",
            &format!("{url}{path}"),
            Some(("text/turtle", spec(file))),
        );
        assert_eq!(status, Some(201), "POST {path} {file}");
    }
    // Piff's executor; its PATH finds `dyknow` (the segmenter is a process CU).
    let dir_of_bin = std::path::Path::new(&*BIN).parent().unwrap();
    let mut piff = Command::new(&*BIN)
        .args(["executor", "--name", "piff", "--connect", &zenoh])
        .env(
            "PATH",
            format!(
                "{}:{}",
                dir_of_bin.display(),
                std::env::var("PATH").unwrap_or_default()
            ),
        )
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::spawn({
        let stderr = piff.stderr.take().unwrap();
        move || for _ in BufReader::new(stderr).lines().map_while(Result::ok) {}
    });
    let _piff = Process(piff);
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let mut r = a.get(&format!("{url}/environment")).call().unwrap();
        let env: Value = serde_json::from_str(&r.body_mut().read_to_string().unwrap()).unwrap();
        if env["valid"] == true {
            break;
        }
        assert!(Instant::now() < deadline, "Chapter 6 did not run: {env}");
        std::thread::sleep(Duration::from_millis(100));
    }
    println!(
        "Chapter 6 running on piff; {clients} clients for {secs} s against {url} (manager RSS {} kB)",
        rss_kb(pid)
    );

    let routes: Routes = Mutex::default();
    let rss = Arc::new(Mutex::new(Vec::new()));
    let sampling = Arc::new(AtomicBool::new(true));
    let sampler = {
        let rss = rss.clone();
        let sampling = sampling.clone();
        std::thread::spawn(move || {
            let start = Instant::now();
            while sampling.load(Ordering::SeqCst) {
                rss.lock()
                    .unwrap()
                    .push((start.elapsed().as_secs(), rss_kb(pid)));
                let next = Duration::from_secs(rss.lock().unwrap().len() as u64 * 10);
                while sampling.load(Ordering::SeqCst) && start.elapsed() < next {
                    std::thread::sleep(Duration::from_millis(100));
                }
            }
        })
    };
    run_clients(clients, secs, |id, stop| client(id, &url, &routes, stop));
    sampling.store(false, Ordering::SeqCst);
    sampler.join().unwrap();
    println!();
    let unexpected = table(&routes, secs);
    let rss = rss.lock().unwrap();
    println!(
        "\nunexpected answers: {unexpected}; manager RSS every 10 s (kB): {:?}",
        rss.iter().map(|r| r.1).collect::<Vec<_>>()
    );
    let env: Value = {
        let mut r = a.get(&format!("{url}/environment")).call().unwrap();
        serde_json::from_str(&r.body_mut().read_to_string().unwrap()).unwrap()
    };
    println!(
        "after the load: environment valid {}, {} reviews, {} crashes",
        env["valid"], env["reviews"], env["crashes"]
    );

    // The peer: SPARQL only, the same query, against dyknow and against oxigraph serve.
    let Ok(oxigraph) = std::env::var("OXIGRAPH_BIN") else {
        println!("\nOXIGRAPH_BIN is not set: no peer (benches/run.sh load sets it)");
        return;
    };
    let mut r = a
        .get(&format!("{url}/model?format=ntriples"))
        .call()
        .unwrap();
    let ntriples = r
        .body_mut()
        .with_config()
        .limit(1 << 30)
        .read_to_vec()
        .unwrap();
    let nt = dir.path().join("model.nt");
    std::fs::write(&nt, &ntriples).unwrap();
    let location = dir.path().join("peer");
    let status = Command::new(&oxigraph)
        .args(["load", "--location"])
        .arg(&location)
        .arg("--file")
        .arg(&nt)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .unwrap();
    assert!(status.success(), "oxigraph load");
    let peer_port = free_port();
    let peer = Process(
        Command::new(&oxigraph)
            .args(["serve", "--location"])
            .arg(&location)
            .args(["--bind", &format!("127.0.0.1:{peer_port}")])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let peer_url = format!("http://127.0.0.1:{peer_port}");
    let deadline = Instant::now() + Duration::from_secs(30);
    while request(
        &a,
        "GET",
        &format!("{peer_url}/query?query={}", url_encode(QUERY)),
        None,
    )
    .0 != Some(200)
    {
        assert!(Instant::now() < deadline, "oxigraph serve did not start");
        std::thread::sleep(Duration::from_millis(100));
    }
    let sparql_only = |endpoint: String| {
        let routes: Routes = Mutex::default();
        run_clients(clients, peer_secs, |_, stop| {
            let agent = agent();
            while !stop.load(Ordering::Relaxed) {
                record(
                    &routes,
                    "sparql",
                    &[200],
                    request(&agent, "GET", &endpoint, None),
                );
            }
        });
        let r = routes.lock().unwrap();
        let mut sorted = r
            .get("sparql")
            .map(|r| r.latencies.clone())
            .unwrap_or_default();
        sorted.sort_unstable();
        let unexpected = r.get("sparql").map_or(0, |r| r.unexpected);
        (sorted, unexpected)
    };
    let (ours, our_bad) = sparql_only(format!("{url}/sparql?query={}", url_encode(QUERY)));
    let (theirs, their_bad) = sparql_only(format!("{peer_url}/query?query={}", url_encode(QUERY)));
    drop(peer);
    println!(
        "\nSPARQL only ({clients} clients, {peer_secs} s each, the same query, Chapter 6 still running on dyknow):"
    );
    println!("| server | requests per s | unexpected | p50 ms | p99 ms | ratio p50 | ratio p99 |");
    println!("| --- | --- | --- | --- | --- | --- | --- |");
    let ratio = |a: Duration, b: Duration| a.as_secs_f64() / b.as_secs_f64().max(1e-9);
    println!(
        "| dyknow serve | {:.0} | {our_bad} | {} | {} | {:.2} | {:.2} |",
        ours.len() as f64 / peer_secs as f64,
        ms(percentile(&ours, 0.5)),
        ms(percentile(&ours, 0.99)),
        ratio(percentile(&ours, 0.5), percentile(&theirs, 0.5)),
        ratio(percentile(&ours, 0.99), percentile(&theirs, 0.99)),
    );
    println!(
        "| oxigraph serve (same triples, default graph) | {:.0} | {their_bad} | {} | {} | 1 | 1 |",
        theirs.len() as f64 / peer_secs as f64,
        ms(percentile(&theirs, 0.5)),
        ms(percentile(&theirs, 0.99)),
    );
}
