//! Crash to flowing again: how long after a CU of a running pipeline crashes its target's
//! stream carries samples again, with nobody reporting the crash (the executor detects it, the
//! life-cycle reviews, the executor spawns and wires the replacement). A `dyknow serve`
//! process with its embedded executor; a source publishing every 2 ms through a guard CU to
//! the target's channel; the guard crashed 50 times: a builtin by a panic on command, a
//! process CU by `kill -9`.
//!
//! Each kind twice: *isolated*, each crash 250 ms after its replacement appeared (more than
//! the default `--review-spacing-ms`, 100, after the review that made it), and *back to
//! back*, each crash as soon as the replacement flows, which the manager holds back for the
//! rest of the spacing since the last review (a crash storm is coalesced into one review
//! per spacing, `docs/reliability.md`).
//!
//! `cargo bench -p dyknow-server --bench recovery -- [--crashes N]`

#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use dyknow_cu::zenoh::{self, Wait};
use dyknow_cu::{Namespace, Sample};
use serde_json::{Value, json};

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

struct Service {
    child: Child,
    url: String,
    zenoh: String,
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let _ = self.child.wait();
    }
}

fn start() -> Service {
    let zenoh = format!("tcp/127.0.0.1:{}", free_port());
    let mut child = Command::new(BIN)
        .args([
            "serve",
            "--in-memory",
            "--bind",
            "127.0.0.1:0",
            "--zenoh-listen",
            &zenoh,
        ])
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let url = loop {
        let line = lines.next().expect("the service exited").unwrap();
        if let Some(rest) = line.split("listening on ").nth(1) {
            break rest.split_whitespace().next().unwrap().to_owned();
        }
    };
    // The service's log, for a look after a run.
    let log = std::env::temp_dir().join("dyknow-recovery-bench.log");
    std::thread::spawn(move || {
        let mut file = std::fs::File::create(log).ok();
        for line in lines.map_while(Result::ok) {
            if let Some(f) = file.as_mut() {
                let _ = writeln!(f, "{line}");
            }
        }
    });
    Service { child, url, zenoh }
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into()
}

fn get(s: &Service, path: &str) -> Value {
    let mut r = agent().get(&format!("{}{path}", s.url)).call().unwrap();
    serde_json::from_str(&r.body_mut().read_to_string().unwrap()).unwrap()
}

fn post(s: &Service, path: &str, body: &str) {
    let r = agent()
        .post(&format!("{}{path}", s.url))
        .header("Content-Type", "text/turtle")
        .send(body.as_bytes())
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
}

const PREFIXES: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
    @prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .\n\
    @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n";

fn specs(guard_type: &str, guard_source: &str, tag: &str, channel: &str) -> (String, String) {
    (
        format!(
            "{PREFIXES}[] a dkros:ROSTransformation ; rdfs:label \"source-{tag}\" ; dkros:hasType \"builtin\" ; dkros:hasSource \"dyknow/signal\" ;\n\
             dkros:hasParam [ dyknow:hasName \"period_ms\" ; dyknow:hasValue 2 ] ;\n\
             dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"Raw{tag}\" ] ] .\n\
             [] a dkros:ROSTransformation ; rdfs:label \"guard-{tag}\" ; dkros:hasType \"{guard_type}\" ; dkros:hasSource \"{guard_source}\" ;\n\
             dyknow:hasInPort [ dyknow:hasName \"in\" ; dyknow:hasTag [ dyknow:hasValue \"Raw{tag}\" ] ] ;\n\
             dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"Guarded{tag}\" ] ] .\n"
        ),
        format!(
            "{PREFIXES}[] a dyknow:Target ; rdfs:label \"q-{tag}\" ; dyknow:hasChannel [ dyknow:hasChannelName \"{channel}\" ] ;\n\
             dyknow:hasTag [ dyknow:hasValue \"Guarded{tag}\" ] .\n"
        ),
    )
}

/// The guard CU with its executor's view, if the model has one now.
fn guard(s: &Service, tag: &str) -> Option<Value> {
    let cus = get(s, "/cus");
    let cu = cus
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["transformation"] == format!("guard-{tag}"))
        .cloned()?;
    // Gone between the two requests (a 404): none.
    Some(get(s, &format!("/cus/{}", cu["name"].as_str().unwrap())))
        .filter(|d| d["name"].is_string())
}

/// Crashes the guard `crashes` times with `crash` and times each outage: from the crash to the
/// first sample on the target's channel from the replacement.
fn run(
    s: &Service,
    session: &zenoh::Session,
    tag: &str,
    crashes: usize,
    idle: Duration,
    crash: &dyn Fn(&Value),
) -> Vec<Duration> {
    let channel = format!("/out-{tag}");
    let (turtle, target) = specs(
        if tag.starts_with("builtin") {
            "builtin"
        } else {
            "process"
        },
        &if tag.starts_with("builtin") {
            "dyknow/fault".to_owned()
        } else {
            format!("{BIN} cu dyknow/relay")
        },
        tag,
        &channel,
    );
    post(s, "/transformations", &turtle);
    // Each sample's arrival, and when the source published it (its `t`).
    let (tx, rx) = mpsc::channel::<(Instant, i64)>();
    let _sub = session
        .declare_subscriber(Namespace::default().channel(&channel).unwrap())
        .callback(move |s| {
            let at = Instant::now();
            if let Ok(sample) = Sample::from_slice(&s.payload().to_bytes()) {
                let _ = tx.send((at, sample.t));
            }
        })
        .wait()
        .unwrap();
    post(s, "/targets", &target);
    rx.recv_timeout(Duration::from_secs(30))
        .expect("the pipeline flows");
    let mut outages = Vec::new();
    for _ in 0..crashes {
        // The pace of the crashes is what is measured: isolated or back to back.
        std::thread::sleep(idle);
        let Some(before) = guard(s, tag) else {
            let sets = get(s, "/changesets");
            let last: Vec<String> = sets
                .as_array()
                .unwrap()
                .iter()
                .rev()
                .take(3)
                .map(|c| {
                    format!(
                        "{} {} {} {} {}",
                        c["id"], c["cause"], c["status"], c["actions"], c["failures"]
                    )
                })
                .collect();
            panic!("no guard CU: {}\n{}", get(s, "/cus"), last.join("\n"));
        };
        // Flowing: a fresh sample.
        while rx.try_recv().is_ok() {}
        rx.recv_timeout(Duration::from_secs(30))
            .expect("flowing before the crash");
        let known = get(s, "/changesets").as_array().map_or(0, Vec::len);
        // The crash: a fault command on its way, or `kill -9` delivered (`kill` has returned).
        crash(&before);
        let crashed_at = Instant::now();
        let crashed_ms = dyknow_cu::now_ms();
        // Samples the old guard forwarded before it crashed may still be on the wire: only a
        // sample the source published after the crash (its `t`, in ms, is later) can have come
        // through the replacement.
        let flowing = loop {
            let (at, t) = rx
                .recv_timeout(Duration::from_secs(30))
                .expect("flowing again");
            if t > crashed_ms {
                break at;
            }
        };
        let outage = flowing - crashed_at;
        outages.push(outage);
        // The replacement is in the model before the next round.
        let deadline = Instant::now() + Duration::from_secs(30);
        while guard(s, tag).is_none_or(|g| g["name"] == before["name"]) {
            assert!(Instant::now() < deadline, "no replacement");
            std::thread::sleep(Duration::from_millis(5));
        }
        // An outlier says what the service did meanwhile.
        if outage > Duration::from_millis(50) {
            let sets = get(s, "/changesets");
            let after: Vec<String> = sets
                .as_array()
                .unwrap()
                .iter()
                .skip(known)
                .map(|c| {
                    format!(
                        "  {} {} {} {} {}",
                        c["id"], c["cause"], c["status"], c["actions"], c["failures"]
                    )
                })
                .collect();
            eprintln!(
                "{tag}: outage {outage:?}; the change sets since the crash:\n{}",
                after.join("\n")
            );
        }
    }
    // Released: its pipeline stops, so the next runs measure without it.
    let r = agent()
        .delete(&format!("{}/targets/q-{tag}", s.url))
        .call()
        .unwrap();
    assert!(r.status().is_success(), "{}", r.status());
    outages
}

fn report(what: &str, mut t: Vec<Duration>) {
    t.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let mean = t.iter().map(|d| ms(*d)).sum::<f64>() / t.len() as f64;
    println!(
        "{what:<34} {:>4} {:>9.1} {:>9.1} {:>9.1} {:>9.1}",
        t.len(),
        mean,
        ms(t[t.len() / 2]),
        ms(t[(t.len() * 9 / 10).min(t.len() - 1)]),
        ms(t[t.len() - 1])
    );
}

fn main() {
    let argv: Vec<String> = std::env::args().collect();
    let crashes = argv
        .iter()
        .position(|a| a == "--crashes")
        .and_then(|i| argv.get(i + 1))
        .map_or(50, |n| n.parse().unwrap());
    let s = start();
    let session = zenoh::open(dyknow_cu::client_config(std::slice::from_ref(&s.zenoh)).unwrap())
        .wait()
        .unwrap();
    let mut rows = Vec::new();
    for (pace, idle) in [
        ("isolated", Duration::from_millis(250)),
        ("back to back", Duration::ZERO),
    ] {
        let publisher = session.clone();
        let tag = format!("builtin{}", rows.len());
        let builtin = run(&s, &session, &tag, crashes, idle, &|guard| {
            let channel = guard["inputs"]["in"].as_str().unwrap();
            publisher
                .put(
                    Namespace::default().channel(channel).unwrap(),
                    Sample::now(json!({"fault": "panic"})).to_bytes(),
                )
                .wait()
                .unwrap();
        });
        rows.push((format!("builtin CU panics, {pace}"), builtin));
        let tag = format!("process{}", rows.len());
        let process = run(&s, &session, &tag, crashes, idle, &|guard| {
            let pid = guard["pid"].as_u64().expect("a process CU has a pid");
            Command::new("kill")
                .args(["-9", &pid.to_string()])
                .status()
                .unwrap();
        });
        rows.push((format!("process CU kill -9, {pace}"), process));
    }
    println!("crash → target stream flowing again, ms (no client reports the crash)");
    println!(
        "{:<34} {:>4} {:>9} {:>9} {:>9} {:>9}",
        "crash", "n", "mean", "p50", "p90", "max"
    );
    for (what, outages) in rows {
        report(&what, outages);
    }
}
