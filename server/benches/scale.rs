//! The service at fleet scale (issue 18): `dyknow serve --model-only` on an on-disk store, over
//! HTTP on loopback, with generated libraries of 100 to 10,000 transformations and 1 to 50
//! targets. Per size it prints:
//!
//! - the time from a spec change to its change set being recorded (applied to the model):
//!   **cold**, the first one after the service restarted (nothing derived from specs in
//!   memory yet), and **warm**, later ones (p50 and max over the repetitions). The change is the
//!   deregistration of a transformation the configuration uses (a perturbation that leaves the
//!   environment invalid, so a review runs at once, seed Def. 36) or a target posted;
//! - `GET /cus` latency right after a spec change (the first read after it) and at rest;
//! - start-up: from `dyknow serve` started on the store until it answers;
//! - the growth of each figure per doubling of the library.
//!
//! The library: streams `s0 … s{N/2-1}` in a tree (stream k ≥ 1 is computed from stream
//! (k-1)/4); each stream has two producers, `p{k}a` (upkeep 1) and `p{k}b` (upkeep 2); every tag
//! is distinct (values). Targets want the last streams, so a configuration is a few chains of
//! depth log₄(N/2) sharing their roots.
//!
//! `cargo bench -p dyknow-server --bench scale -- [--sizes 100,200,…] [--targets 1,50] [--repeat N]
//! [--serve-args "--explore-threads 0 …"]` (the last: further flags for `dyknow serve`). With
//! `SCALE_SERVICE_LOG=1` the service's log goes to the bench's stderr: with
//! `RUST_LOG=dyknow_lifecycle=debug,info` it gives each review's read, search and write time.

#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

const PREFIXES: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n";

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `dyknow serve`, stopped (SIGTERM, then SIGKILL) when dropped.
struct Service {
    child: Child,
    base: String,
}

impl Service {
    /// Starts the service on `data` and waits until it answers; returns it and the time that
    /// took.
    fn start(data: &std::path::Path) -> (Self, Duration) {
        let port = free_port();
        let started = Instant::now();
        let mut child = Command::new(BIN)
            .args(["serve", "--model-only", "--bind"])
            .arg(format!("127.0.0.1:{port}"))
            .arg("--data")
            .arg(data)
            .args(
                arg("--serve-args")
                    .iter()
                    .flat_map(|a| a.split_whitespace()),
            )
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let lines = BufReader::new(child.stderr.take().unwrap()).lines();
        let show = std::env::var_os("SCALE_SERVICE_LOG").is_some();
        std::thread::spawn(move || {
            for line in lines.map_while(Result::ok) {
                if show {
                    eprintln!("{line}");
                }
            }
        });
        let base = format!("http://127.0.0.1:{port}");
        let service = Self { child, base };
        let agent = agent();
        let deadline = Instant::now() + Duration::from_secs(600);
        loop {
            if let Some(200) = get(&agent, &format!("{}/environment", service.base)).0 {
                break;
            }
            assert!(Instant::now() < deadline, "the service did not start");
            std::thread::sleep(Duration::from_millis(5));
        }
        (service, started.elapsed())
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let deadline = Instant::now() + Duration::from_secs(30);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(600)))
        .build()
        .into()
}

fn send(
    agent: &ureq::Agent,
    method: &str,
    url: &str,
    body: Option<String>,
) -> (Option<u16>, String) {
    let req = ureq::http::Request::builder().method(method).uri(url);
    let answer = match body {
        Some(body) => agent.run(
            req.header("Content-Type", "text/turtle")
                .body(body)
                .unwrap(),
        ),
        None => agent.run(req.body(()).unwrap()),
    };
    match answer {
        Ok(mut a) => {
            let status = a.status().as_u16();
            let text = a
                .body_mut()
                .with_config()
                .limit(1 << 30)
                .read_to_string()
                .unwrap_or_default();
            (Some(status), text)
        }
        Err(_) => (None, String::new()),
    }
}

fn get(agent: &ureq::Agent, url: &str) -> (Option<u16>, String) {
    send(agent, "GET", url, None)
}

/// Producer `p{k}{variant}` of stream k.
fn transformation(k: usize, variant: char) -> String {
    let upkeep = if variant == 'a' { "1.0" } else { "2.0" };
    let input = if k == 0 {
        String::new()
    } else {
        format!(
            " dyknow:hasInPort [ a dyknow:InPort ; dyknow:hasName \"in\" ; dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"s{}\" ] ] ;",
            (k - 1) / 4
        )
    };
    format!(
        "[] a dyknow:Transformation ; rdfs:label \"p{k}{variant}\" ;{input} \
         dyknow:hasOutPort [ a dyknow:OutPort ; dyknow:hasName \"out\" ; dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"s{k}\" ] ] ; \
         dyknow:hasCostModel [ a dyknow:LabourCostModel ; dyknow:hasValue 1.0 ] , [ a dyknow:UpkeepCostModel ; dyknow:hasValue {upkeep} ] .\n"
    )
}

fn target(j: usize, stream: usize) -> String {
    format!(
        "{PREFIXES}[] a dyknow:Target ; rdfs:label \"q{j}\" ; \
         dyknow:hasChannel [ a dyknow:Channel ; dyknow:hasChannelName \"out{j}\" ] ; \
         dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"s{stream}\" ] .\n"
    )
}

/// The stream target `j` wants in a library of `streams` streams: distinct for `j < streams`
/// (7919 is prime), mostly among the last ones.
fn target_stream(j: usize, streams: usize) -> usize {
    streams - 1 - (j * 7919) % streams
}

/// The number of change sets recorded, and the last one.
fn change_sets(agent: &ureq::Agent, base: &str) -> (usize, Value) {
    let (_, body) = get(agent, &format!("{base}/changesets"));
    let list: Vec<Value> = serde_json::from_str(&body).unwrap();
    (list.len(), list.last().cloned().unwrap_or(Value::Null))
}

/// Sends a spec change and waits for the change set it causes; returns the time and the change
/// set.
fn change(
    agent: &ureq::Agent,
    base: &str,
    method: &str,
    path: &str,
    body: Option<String>,
) -> (Duration, Value) {
    let (before, _) = change_sets(agent, base);
    let started = Instant::now();
    let (status, text) = send(agent, method, &format!("{base}{path}"), body);
    assert!(
        matches!(status, Some(201 | 204)),
        "{method} {path}: {status:?} {text}"
    );
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        let (n, last) = change_sets(agent, base);
        if n > before {
            return (started.elapsed(), last);
        }
        assert!(
            Instant::now() < deadline,
            "no change set after {method} {path}"
        );
        std::thread::sleep(Duration::from_micros(500));
    }
}

/// Starts a review (`POST /review`) and waits until it has run and nothing is pending: the
/// configuration is then optimal again for the library (a transformation posted back is a
/// registration, which by itself starts no review, seed Def. 36).
fn review(agent: &ureq::Agent, base: &str) {
    let reviews = |agent: &ureq::Agent| -> (u64, bool) {
        let (_, body) = get(agent, &format!("{base}/environment"));
        let v: Value = serde_json::from_str(&body).unwrap();
        (
            v["reviews"].as_u64().unwrap(),
            v["phase"] == "stable" && v["review_pending"] == false,
        )
    };
    let (before, _) = reviews(agent);
    let (status, _) = send(agent, "POST", &format!("{base}/review"), None);
    assert_eq!(status, Some(202));
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        let (n, idle) = reviews(agent);
        if n > before && idle {
            return;
        }
        assert!(Instant::now() < deadline, "the review did not run");
        std::thread::sleep(Duration::from_micros(500));
    }
}

/// The transformation of a CU the configuration runs now (the `r`-th, modulo their number,
/// by label), as (stream, variant): deregistering it leaves the environment invalid, so a
/// review runs at once.
fn used(agent: &ureq::Agent, base: &str, r: usize) -> (usize, char) {
    let (_, body) = get(agent, &format!("{base}/cus"));
    let cus: Vec<Value> = serde_json::from_str(&body).unwrap();
    let mut labels: Vec<String> = cus
        .iter()
        .filter_map(|c| c["transformation"].as_str().map(str::to_owned))
        .collect();
    labels.sort();
    labels.dedup();
    let label = &labels[(r * 7) % labels.len()];
    let variant = label.chars().last().unwrap();
    (label[1..label.len() - 1].parse().unwrap(), variant)
}

/// Posts producer `p{k}{v}` back after its deregistration and reviews, so the next change
/// starts from an optimal configuration again.
fn post_back(agent: &ureq::Agent, base: &str, k: usize, v: char) {
    let (status, _) = send(
        agent,
        "POST",
        &format!("{base}/transformations"),
        Some(format!("{PREFIXES}{}", transformation(k, v))),
    );
    assert_eq!(status, Some(201));
    review(agent, base);
}

fn cus_latency(agent: &ureq::Agent, base: &str) -> Duration {
    let started = Instant::now();
    let (status, _) = get(agent, &format!("{base}/cus"));
    assert_eq!(status, Some(200));
    started.elapsed()
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

fn percentile(v: &mut [Duration], p: f64) -> Duration {
    v.sort();
    v[((v.len() - 1) as f64 * p).round() as usize]
}

struct Row {
    size: usize,
    targets: usize,
    startup: Duration,
    cold: Duration,
    warm_p50: Duration,
    warm_max: Duration,
    cus_after_change: Duration,
    cus_rest: Duration,
    optimal: String,
}

fn measure(size: usize, targets: usize, repeat: usize) -> Row {
    let dir = tempfile::tempdir().unwrap();
    let agent = agent();
    let streams = size / 2;
    {
        let (service, _) = Service::start(dir.path());
        let base = &service.base;
        for chunk in (0..streams).collect::<Vec<_>>().chunks(500) {
            let mut doc = PREFIXES.to_owned();
            for &k in chunk {
                doc.push_str(&transformation(k, 'a'));
                doc.push_str(&transformation(k, 'b'));
            }
            let (status, text) = send(
                &agent,
                "POST",
                &format!("{base}/transformations"),
                Some(doc),
            );
            assert_eq!(status, Some(201), "{text}");
        }
        for j in 0..targets {
            let (status, text) = send(
                &agent,
                "POST",
                &format!("{base}/targets"),
                Some(target(j, target_stream(j, streams))),
            );
            assert_eq!(status, Some(201), "{text}");
        }
        // Wait until every target is satisfied.
        let deadline = Instant::now() + Duration::from_secs(600);
        loop {
            let (_, body) = get(&agent, &format!("{base}/environment"));
            let v: Value = serde_json::from_str(&body).unwrap();
            if v["unsatisfied_targets"]
                .as_array()
                .is_some_and(Vec::is_empty)
                && v["phase"] == "stable"
                && v["review_pending"] == false
            {
                break;
            }
            assert!(Instant::now() < deadline, "targets not satisfied: {v}");
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    // Restart: nothing derived from specs is in memory.
    let (service, startup) = Service::start(dir.path());
    let base = &service.base;
    // Cold: the first spec change after the restart, deregistering a transformation in use.
    let (k, v) = used(&agent, base, 0);
    let (cold, first) = change(
        &agent,
        base,
        "DELETE",
        &format!("/transformations/p{k}{v}"),
        None,
    );
    let mut optimal = vec![first["optimal"].as_bool().unwrap_or(false)];
    let cus_after_change = cus_latency(&agent, base);
    post_back(&agent, base, k, v);
    // Warm: deregistrations of transformations in use and target posts, alternately.
    let mut warm = Vec::new();
    let mut after_change = vec![cus_after_change];
    for r in 0..repeat {
        let (d, cs) = if r % 2 == 0 || targets + r >= streams {
            let (k, v) = used(&agent, base, r + 1);
            let out = change(
                &agent,
                base,
                "DELETE",
                &format!("/transformations/p{k}{v}"),
                None,
            );
            after_change.push(cus_latency(&agent, base));
            post_back(&agent, base, k, v);
            out
        } else {
            let j = targets + r;
            let out = change(
                &agent,
                base,
                "POST",
                "/targets",
                Some(target(j, target_stream(j, streams))),
            );
            after_change.push(cus_latency(&agent, base));
            // The release is a perturbation too: its change set is waited for, so that the
            // next deregistration picks a transformation still in use.
            change(&agent, base, "DELETE", &format!("/targets/q{j}"), None);
            out
        };
        warm.push(d);
        optimal.push(cs["optimal"].as_bool().unwrap_or(false));
    }
    let mut rest: Vec<Duration> = (0..20).map(|_| cus_latency(&agent, base)).collect();
    let proven = optimal.iter().filter(|o| **o).count();
    Row {
        size,
        targets,
        startup,
        cold,
        warm_p50: percentile(&mut warm.clone(), 0.5),
        warm_max: *warm.iter().max().unwrap(),
        cus_after_change: percentile(&mut after_change, 0.5),
        cus_rest: percentile(&mut rest, 0.5),
        optimal: format!("{proven}/{}", optimal.len()),
    }
}

fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn list(name: &str, default: &[usize]) -> Vec<usize> {
    arg(name).map_or_else(
        || default.to_vec(),
        |v| v.split(',').map(|x| x.parse().unwrap()).collect(),
    )
}

fn main() {
    let sizes = list(
        "--sizes",
        &[100, 200, 400, 800, 1600, 2000, 3200, 6400, 10000],
    );
    let targets = list("--targets", &[1, 50]);
    let repeat: usize = arg("--repeat").map_or(10, |v| v.parse().unwrap());
    println!(
        "| transformations | targets | start-up ms | spec change → change set, cold ms | warm p50 ms | warm max ms | GET /cus after a change ms | GET /cus at rest ms | proven optimal |"
    );
    println!("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    let mut previous: Option<Row> = None;
    for &t in &targets {
        for &size in &sizes {
            let row = measure(size, t, repeat);
            println!(
                "| {} | {} | {:.0} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} |",
                row.size,
                row.targets,
                ms(row.startup),
                ms(row.cold),
                ms(row.warm_p50),
                ms(row.warm_max),
                ms(row.cus_after_change),
                ms(row.cus_rest),
                row.optimal
            );
            if let Some(p) = previous
                .as_ref()
                .filter(|p| p.targets == t && p.size * 2 == size)
            {
                println!(
                    "|  | growth ×2 | {:.2}× | {:.2}× | {:.2}× | | {:.2}× | {:.2}× | |",
                    row.startup.as_secs_f64() / p.startup.as_secs_f64(),
                    row.cold.as_secs_f64() / p.cold.as_secs_f64(),
                    row.warm_p50.as_secs_f64() / p.warm_p50.as_secs_f64(),
                    row.cus_after_change.as_secs_f64() / p.cus_after_change.as_secs_f64(),
                    row.cus_rest.as_secs_f64() / p.cus_rest.as_secs_f64(),
                );
            }
            previous = Some(row);
        }
    }
}
