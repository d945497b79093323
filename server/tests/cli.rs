//! The `dyknow` binary as a process: serve on the on-disk store, `kill -9`, restart; load and
//! export offline; start-up refusals; graceful shutdown.
#![cfg(feature = "rocksdb")]
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

fn specs(file: &str) -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../specs/turtle")
            .join(file),
    )
    .unwrap()
}

/// A running `dyknow serve`, its base URL and what it logged before listening.
struct Server {
    child: Child,
    url: String,
    startup: Vec<String>,
}

impl Server {
    fn start(args: &[&str]) -> Self {
        let mut child = Command::new(BIN)
            .arg("serve")
            .args(["--bind", "127.0.0.1:0", "--model-only"])
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stderr = child.stderr.take().unwrap();
        let mut lines = BufReader::new(stderr).lines();
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut startup = Vec::new();
        let url = loop {
            assert!(Instant::now() < deadline, "server did not start");
            let line = lines.next().expect("server exited").unwrap();
            if let Some(rest) = line.split("listening on ").nth(1) {
                break rest.split_whitespace().next().unwrap().to_owned();
            }
            startup.push(line);
        };
        // Keep draining stderr so the server never blocks on a full pipe.
        std::thread::spawn(move || for _ in lines {});
        Self {
            child,
            url,
            startup,
        }
    }

    fn kill9(mut self) {
        self.child.kill().unwrap(); // SIGKILL on Unix
        self.child.wait().unwrap();
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn agent() -> ureq::Agent {
    agent_with_timeout(Duration::from_secs(30))
}

fn agent_with_timeout(timeout: Duration) -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(timeout))
        .build()
        .into()
}

fn post(agent: &ureq::Agent, url: &str, content_type: &str, body: &str) -> (u16, String) {
    let mut r = agent
        .post(url)
        .header("Content-Type", content_type)
        .send(body.as_bytes())
        .unwrap();
    (r.status().as_u16(), r.body_mut().read_to_string().unwrap())
}

fn get(agent: &ureq::Agent, url: &str) -> (u16, String) {
    let mut r = agent.get(url).call().unwrap();
    (r.status().as_u16(), r.body_mut().read_to_string().unwrap())
}

fn spec(label: &str) -> String {
    format!(
        r#"@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
[] a dyknow:Transformation ; rdfs:label "{label}" ;
   dyknow:hasInPort  [ dyknow:hasName "in"  ; dyknow:hasTag [ dyknow:hasValue "A({label})" ] ] ;
   dyknow:hasOutPort [ dyknow:hasName "out" ; dyknow:hasTag [ dyknow:hasValue "B({label})" ] ] ."#
    )
}

fn labels(agent: &ureq::Agent, url: &str) -> Vec<String> {
    let (status, body) = get(agent, &format!("{url}/transformations"));
    assert_eq!(status, 200);
    let list: serde_json::Value = serde_json::from_str(&body).unwrap();
    list.as_array()
        .unwrap()
        .iter()
        .map(|t| {
            // Every listed spec is whole: some port, and every port with its tags.
            let ports: Vec<&serde_json::Value> = ["inputs", "outputs"]
                .iter()
                .flat_map(|d| t[*d].as_array().unwrap())
                .collect();
            assert!(!ports.is_empty(), "{t}");
            for port in ports {
                assert!(!port["tags"].as_array().unwrap().is_empty(), "{t}");
            }
            t["label"].as_str().unwrap().to_owned()
        })
        .collect()
}

#[test]
fn kill_9_loses_no_acknowledged_write() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("nested/store");
    let data = data.to_str().unwrap();
    let agent = agent();

    // Round 1: sequential writes, then SIGKILL right after the last acknowledgement.
    let server = Server::start(&["--data", data]);
    for i in 0..50 {
        let (status, body) = post(
            &agent,
            &format!("{}/transformations", server.url),
            "text/turtle",
            &spec(&format!("t{i:03}")),
        );
        assert_eq!(status, 201, "{body}");
    }
    server.kill9();
    let server = Server::start(&["--data", data]);
    let mut expected: Vec<String> = (0..50).map(|i| format!("t{i:03}")).collect();
    assert_eq!(labels(&agent, &server.url), expected);

    // Round 2: a writer keeps posting while the process is killed at an arbitrary moment.
    let acknowledged = Arc::new(Mutex::new(Vec::new()));
    let stop = Arc::new(AtomicBool::new(false));
    let writer = {
        let (acknowledged, stop, url) = (acknowledged.clone(), stop.clone(), server.url.clone());
        std::thread::spawn(move || {
            let agent = agent_with_timeout(Duration::from_secs(5));
            let mut i = 0;
            while !stop.load(Ordering::Relaxed) {
                let label = format!("u{i:04}");
                let sent = agent
                    .post(&format!("{url}/transformations"))
                    .header("Content-Type", "text/turtle")
                    .send(spec(&label).as_bytes());
                match sent {
                    Ok(r) if r.status().as_u16() == 201 => acknowledged.lock().unwrap().push(label),
                    _ => break,
                }
                i += 1;
            }
        })
    };
    std::thread::sleep(Duration::from_millis(700));
    server.kill9();
    stop.store(true, Ordering::Relaxed);
    writer.join().unwrap();
    let acknowledged = acknowledged.lock().unwrap().clone();
    assert!(!acknowledged.is_empty());

    let server = Server::start(&["--data", data]);
    let after = labels(&agent, &server.url);
    expected.extend(acknowledged.iter().cloned());
    for label in &expected {
        assert!(
            after.contains(label),
            "acknowledged {label} lost after kill -9"
        );
    }
    // At most the one request in flight at the kill may have landed without acknowledgement.
    assert!(
        after.len() <= expected.len() + 1,
        "{} > {} + 1",
        after.len(),
        expected.len()
    );
}

#[test]
fn sigterm_shuts_down_gracefully_and_the_store_reopens() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().to_str().unwrap();
    let agent = agent();
    let mut server = Server::start(&[
        "--data",
        data,
        "--specs",
        &format!(
            "{}/../specs/turtle/ch6-piff.ttl",
            env!("CARGO_MANIFEST_DIR")
        ),
    ]);
    assert_eq!(labels(&agent, &server.url).len(), 7);
    let (status, _) = post(
        &agent,
        &format!("{}/targets", server.url),
        "text/turtle",
        &specs("ch6-target.ttl"),
    );
    assert_eq!(status, 201);
    let pid = server.child.id().to_string();
    assert!(
        Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success()
    );
    let status = server.child.wait().unwrap();
    assert!(status.success(), "exit status {status:?}");
    drop(server);

    // Offline export sees everything, in every format.
    let export = |format: &str| {
        let out = Command::new(BIN)
            .args(["export", "--data", data, "--format", format])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    assert!(export("turtle").contains("\"circle_monitor(ball)\""));
    assert!(export("ofn").contains("ClassAssertion(dkros:ROSTransformation"));
    assert!(export("owx").contains("<ClassAssertion>"));
    let json: serde_json::Value = serde_json::from_str(&export("dyknow")).unwrap();
    assert_eq!(json["transformations"].as_array().unwrap().len(), 7);
    assert_eq!(json["targets"][0]["label"], "target1");
}

#[test]
fn load_and_export_offline() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("store");
    let specs_dir = format!("{}/../specs/turtle", env!("CARGO_MANIFEST_DIR"));
    // A file that is not there: refused before any store is created.
    let missing = dir.path().join("nope.ttl");
    let out = Command::new(BIN)
        .args(["load", "--data", data.to_str().unwrap()])
        .arg(&missing)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("nope.ttl: No such file"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!data.exists(), "a store was created for nothing");
    let out = Command::new(BIN)
        .args(["load", "--data", data.to_str().unwrap(), &specs_dir])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report = String::from_utf8(out.stdout).unwrap();
    assert!(
        report.contains("ch6-piff.ttl: 7 transformation(s), 0 target(s)"),
        "{report}"
    );
    assert!(report.contains("example-12-similarity.ttl: 0 transformation(s), 0 target(s), ontology extension <urn:dyknow:graph:extension:"), "{report}");

    let out = Command::new(BIN)
        .args([
            "export",
            "--data",
            data.to_str().unwrap(),
            "--format",
            "ntriples",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    let nt = String::from_utf8(out.stdout).unwrap();
    assert!(nt.contains("<http://example.org/ex12#A> <http://www.dyknow.eu/ontology/dyknow#similarTo> <http://example.org/ex12#E> ."));

    // A malformed file: exit 2, one line naming file, line and column; nothing written.
    let bad = dir.path().join("bad.ttl");
    std::fs::write(&bad, "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n[] a dyknow:Transformation ;\n   rdfs:label \"x\" .\n").unwrap();
    let out = Command::new(BIN)
        .args([
            "load",
            "--data",
            data.to_str().unwrap(),
            bad.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("bad.ttl:3:"), "{err}");

    // Exporting a directory that holds no store is bad input.
    let out = Command::new(BIN)
        .args([
            "export",
            "--data",
            dir.path().join("nothing").to_str().unwrap(),
            "--format",
            "turtle",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let out = Command::new(BIN)
        .args([
            "export",
            "--data",
            data.to_str().unwrap(),
            "--format",
            "yaml",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn start_up_refusals() {
    // A non-loopback bind without a token.
    let out = Command::new(BIN)
        .args(["serve", "--in-memory", "--bind", "0.0.0.0:0"])
        .env_remove("DYKNOW_TOKEN")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("without a token"));
    // Bad usage.
    for horizon in ["-1", "0"] {
        let out = Command::new(BIN)
            .args(["serve", "--in-memory", &format!("--horizon={horizon}")])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "--horizon {horizon}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--horizon must be a positive"));
    }
    let out = Command::new(BIN).args(["frobnicate"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    for threads in ["65", "-1", "two"] {
        let out = Command::new(BIN)
            .args([
                "serve",
                "--in-memory",
                &format!("--explore-threads={threads}"),
            ])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "--explore-threads {threads}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--explore-threads"));
    }
    for mib in ["-1", "lots", "1.5"] {
        let out = Command::new(BIN)
            .args(["serve", "--in-memory", &format!("--query-memory={mib}")])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "--query-memory {mib}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--query-memory"));
    }
    // A second server on the same store is refused with a clear error.
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().to_str().unwrap();
    let _first = Server::start(&["--data", data]);
    let out = Command::new(BIN)
        .args([
            "serve",
            "--bind",
            "127.0.0.1:0",
            "--model-only",
            "--data",
            data,
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains(data));
}

#[test]
fn token_protects_mutations_of_a_real_server() {
    let agent = agent();
    let server = Server::start(&["--in-memory", "--token", "s3cret"]);
    let url = format!("{}/transformations", server.url);
    let (status, _) = post(&agent, &url, "text/turtle", &spec("x"));
    assert_eq!(status, 401);
    let mut r = agent
        .post(&url)
        .header("Content-Type", "text/turtle")
        .header("Authorization", "Bearer s3cret")
        .send(spec("x").as_bytes())
        .unwrap();
    assert_eq!(
        r.status().as_u16(),
        201,
        "{}",
        r.body_mut().read_to_string().unwrap()
    );
    assert_eq!(get(&agent, &url).0, 200);
}

fn environment(file: &str) -> String {
    format!(
        "{}/../specs/environments/{file}",
        env!("CARGO_MANIFEST_DIR")
    )
}

#[test]
fn reason_prints_the_inferred_triples_sorted() {
    let out = Command::new(BIN)
        .args(["reason", &environment("ch6-piff-cus.ttl")])
        .output()
        .expect("run dyknow reason");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).expect("UTF-8");
    let lines: Vec<&str> = stdout.lines().collect();
    let mut sorted = lines.clone();
    sorted.sort_unstable();
    assert_eq!(lines, sorted, "sorted N-Triples");
    let depends = "<http://www.dyknow.eu/ontology/dyknow#dependsOn>";
    assert!(
        lines.contains(
            &format!("<urn:dyknow:example:piff:cu7> {depends} <urn:dyknow:example:piff:cu1> .")
                .as_str()
        )
    );
    // Seven CUs, 17 upstream pairs (eq. 6.4), nothing else.
    assert_eq!(lines.iter().filter(|l| l.contains(depends)).count(), 17);
    // Asserted triples are not printed.
    assert!(
        !stdout
            .contains("<urn:dyknow:example:piff:s3> <http://www.dyknow.eu/ontology/dyknow#fromCU>")
    );
}

/// What the built-in ontologies entail on their own (the closure of their schema) is no
/// inference for the given data, and their axioms outside OWL 2 RL are not warned of on
/// every run: data that uses no DyKnow term gets no output at all.
#[test]
fn reason_prints_only_what_the_given_data_adds() {
    let dir = tempfile::tempdir().expect("tempdir");
    let unrelated = dir.path().join("unrelated.ttl");
    std::fs::write(
        &unrelated,
        "<http://example.org/a> <http://example.org/p> <http://example.org/b> .\n",
    )
    .unwrap();
    let out = Command::new(BIN)
        .args(["reason", unrelated.to_str().unwrap()])
        .output()
        .expect("run dyknow reason");
    assert!(out.status.success());
    assert_eq!(String::from_utf8_lossy(&out.stdout), "");
    assert_eq!(String::from_utf8_lossy(&out.stderr), "");
    // A file's own axiom outside OWL 2 RL is still reported, and its inferences printed.
    let own = dir.path().join("own.ttl");
    std::fs::write(
        &own,
        "@prefix owl: <http://www.w3.org/2002/07/owl#> .
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
         @prefix ex: <http://example.org/> .
         ex:p a owl:ObjectProperty , owl:FunctionalProperty ; rdfs:subPropertyOf ex:q .
         ex:C owl:equivalentClass [ a owl:Restriction ; owl:onProperty ex:p ; owl:someValuesFrom ex:D ] .
         ex:a ex:p ex:b .\n",
    )
    .unwrap();
    let out = Command::new(BIN)
        .args(["reason", own.to_str().unwrap()])
        .output()
        .expect("run dyknow reason");
    assert!(out.status.success());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("<http://example.org/a> <http://example.org/q> <http://example.org/b> ."),
        "{stdout}"
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("EquivalentClasses(<http://example.org/C>")
            && stderr.contains("FunctionalObjectProperty(<http://example.org/p>)")
            && stderr.lines().all(|l| l.contains("example.org")),
        "{stderr}"
    );
}

/// Blank nodes are named in the order they occur, and what horned-owl cannot map is written
/// as N-Triples in a fixed order: the same input prints the same, run after run.
#[test]
fn reason_prints_the_same_for_the_same_input() {
    let spec = format!(
        "{}/../specs/turtle/listing-5.3-undistort.ttl",
        env!("CARGO_MANIFEST_DIR")
    );
    let run = || {
        let out = Command::new(BIN)
            .args(["reason", &spec])
            .output()
            .expect("run dyknow reason");
        assert!(out.status.success());
        (out.stdout, String::from_utf8(out.stderr).unwrap())
    };
    let (first, warnings) = run();
    assert!(
        String::from_utf8_lossy(&first).contains("_:b0 "),
        "{}",
        String::from_utf8_lossy(&first)
    );
    assert!(
        !warnings.contains("BNode(") && warnings.contains("_:b0 <"),
        "{warnings}"
    );
    for _ in 0..3 {
        assert_eq!(run(), (first.clone(), warnings.clone()));
    }
}

/// The axioms outside OWL 2 RL are counted in one INFO line at start-up (not one WARN line
/// each), and `dyknow reason --unsupported` lists as many.
#[test]
fn start_up_counts_the_unsupported_axioms_that_reason_lists() {
    let out = Command::new(BIN)
        .args(["reason", "--unsupported"])
        .output()
        .expect("run dyknow reason --unsupported");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let listed: Vec<String> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect();
    assert!(!listed.is_empty());
    assert!(
        listed.iter().all(|a| a.contains('(') && a.ends_with(')')),
        "OWL functional syntax, one axiom a line: {listed:?}"
    );
    let server = Server::start(&["--in-memory"]);
    let counted: Vec<&String> = server
        .startup
        .iter()
        .filter(|l| l.contains("outside OWL 2 RL"))
        .collect();
    assert_eq!(counted.len(), 1, "{:#?}", server.startup);
    assert!(counted[0].contains(" INFO "), "{}", counted[0]);
    assert!(
        counted[0].contains(&format!("{} axioms", listed.len())),
        "{}",
        counted[0]
    );
    assert!(
        !server.startup.iter().any(|l| l.contains(" WARN ")),
        "{:#?}",
        server.startup
    );
}

#[test]
fn reason_check_reports_violations_and_exits_1() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("bad.ttl");
    std::fs::write(
        &path,
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
         @prefix ex: <http://example.org/bad#> .
         ex:src a dyknow:Source ; dyknow:hasInPort ex:in .
         ex:in a dyknow:InPort .
         ex:t a dyknow:Transformation ; dyknow:hasOutPort ex:both .
         ex:both a dyknow:InPort , dyknow:OutPort .
         ex:cu a dyknow:ComputationUnit ; dyknow:hasSubscription ex:s .
         ex:s dyknow:fromCU ex:cu .",
    )
    .expect("write");
    let out = Command::new(BIN)
        .args(["reason", "--check"])
        .arg(&path)
        .output()
        .expect("run dyknow reason --check");
    assert_eq!(out.status.code(), Some(1));
    let stdout = String::from_utf8(out.stdout).expect("UTF-8");
    for (rule, node) in [
        ("cls-maxqc1", "bad#src"),
        ("cax-dw", "bad#both"),
        ("prp-pdw", "bad#cu"),
    ] {
        assert!(
            stdout
                .lines()
                .any(|l| l.starts_with(rule) && l.contains(node)),
            "no {rule} line about {node}: {stdout}"
        );
    }
    // A consistent file passes the check.
    let ok = Command::new(BIN)
        .args(["reason", "--check", &environment("ch6-piff-cus.ttl")])
        .output()
        .expect("run");
    assert!(ok.status.success());
    assert!(ok.stdout.is_empty());
    // The contract's form, `--ontology FILE... FILE...`: an ontology file before the data
    // (once read as two ontology files and no data: exit 2), and the flag repeated.
    let ontology = dir.path().join("o.ttl");
    let more = dir.path().join("o2.ttl");
    let data = dir.path().join("d.ttl");
    let owl =
        "@prefix owl: <http://www.w3.org/2002/07/owl#> .\n@prefix ex: <http://example.org/x#> .\n";
    std::fs::write(&ontology, format!("{owl}ex:A owl:disjointWith ex:B .")).expect("write");
    std::fs::write(&more, format!("{owl}ex:C owl:equivalentClass ex:B .")).expect("write");
    std::fs::write(&data, format!("{owl}ex:x a ex:A , ex:C .")).expect("write");
    for args in [
        vec![
            "--ontology",
            ontology.to_str().unwrap(),
            "--ontology",
            more.to_str().unwrap(),
        ],
        vec![
            "--ontology",
            ontology.to_str().unwrap(),
            more.to_str().unwrap(),
        ],
    ] {
        let out = Command::new(BIN)
            .args(["reason", "--check"])
            .args(&args)
            .arg(&data)
            .output()
            .expect("run");
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert_eq!(
            out.status.code(),
            Some(1),
            "{args:?}: {stdout}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            stdout
                .lines()
                .any(|l| l.starts_with("cax-dw") && l.contains("x#x")),
            "{args:?}: {stdout}"
        );
    }
    // Bad input is exit 2 with file, line and column.
    let broken = dir.path().join("broken.ttl");
    std::fs::write(&broken, "@prefix ex: <http://example.org/> .\nex:a ex:b ;;").expect("write");
    let out = Command::new(BIN)
        .args(["reason"])
        .arg(&broken)
        .output()
        .expect("run");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("broken.ttl:2:"), "{stderr}");
}

/// A live situation replanned offline: `dyknow serve` runs Example 12, tid4's upkeep is
/// observed as 3.0, the model is exported (`GET /model`), tid2's CU is taken out of the export
/// (a crash), and `dyknow explore --environment` finds the seed's second change set (43.0).
#[test]
fn explore_replans_an_exported_model_offline() {
    let server = Server::start(&["--in-memory", "--time-unit", "3600"]);
    let agent = agent();
    let base = server.url.clone();
    for (file, path) in [
        ("example-12-similarity.ttl", "/ontology"),
        ("example-12.ttl", "/transformations"),
        ("example-12-targets.ttl", "/targets"),
    ] {
        let (status, _) = post(
            &agent,
            &format!("{base}{path}"),
            "text/turtle",
            &specs(file),
        );
        assert_eq!(status, 201);
    }
    // Settled: cs-1 applied and no review running or due. The posts above may cost two
    // reviews (a registration's validity check can run after the targets are written, and
    // their perturbations then ask for another), and a review that runs after the upkeep
    // observation below replans with it: it swaps tid4 for tid3 and tid5 (cs-2, 42.0), so
    // the offline replan of the export only has tid2 to spawn (41.0). That once failed a
    // clean-clone CI run; a `POST /review` between the observation and the export
    // reproduces it.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let (_, sets) = get(&agent, &format!("{base}/changesets"));
        let (_, env) = get(&agent, &format!("{base}/environment"));
        let env: serde_json::Value = serde_json::from_str(&env).unwrap();
        if sets.contains("cs-1") && env["phase"] == "stable" && env["review_pending"] == false {
            break;
        }
        assert!(Instant::now() < deadline, "no change set settled: {env}");
        std::thread::sleep(Duration::from_millis(20));
    }
    // The CUs by transformation: which CU gets which name follows the order in which the
    // search built the plan, and with its probes on two threads either of two plans of the
    // same cost may be the one applied.
    let (_, cus) = get(&agent, &format!("{base}/cus"));
    let cus: serde_json::Value = serde_json::from_str(&cus).unwrap();
    let cu_of = |tid: &str| -> String {
        let names: Vec<&str> = cus
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| c["transformation"] == tid)
            .map(|c| c["name"].as_str().unwrap())
            .collect();
        assert_eq!(names.len(), 1, "one CU of {tid}: {cus}");
        names[0].to_owned()
    };
    let (tid4, tid2) = (cu_of("tid4"), cu_of("tid2"));
    let (status, _) = post(
        &agent,
        &format!("{base}/statistics"),
        "application/json",
        &format!(r#"{{"cu": "{tid4}", "upkeep": 3.0}}"#),
    );
    assert_eq!(status, 202);
    let (_, model) = get(
        &agent,
        &format!("{base}/model?format=ntriples&inferred=false"),
    );
    let crashed: String = model
        .lines()
        .filter(|l| !l.contains(&format!("<urn:dyknow:cu:{tid2}")))
        .map(|l| format!("{l}\n"))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("model.nt");
    std::fs::write(&file, crashed).unwrap();
    let out = Command::new(BIN)
        .args(["explore", "--environment"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cs: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let (_, sets) = get(&agent, &format!("{base}/changesets"));
    assert_eq!(
        cs["cost"]["total"], 43.0,
        "offline: {cs}\nCUs before the export: {cus}\nchange sets: {sets}"
    );
    let spawned: Vec<&str> = cs["actions"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == "spawn")
        .map(|a| a["transformation"].as_str().unwrap())
        .collect();
    assert_eq!(spawned, ["tid3", "tid2", "tid5"]);
    server.kill9();
}

/// A field of `/proc/{pid}/status` in kB (`VmRSS`, `VmHWM`).
fn status_kb(pid: u32, field: &str) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no {field} for {pid}"))
}

#[test]
fn a_query_over_its_memory_limit_is_cancelled_before_the_service_grows() {
    // 16 MiB are held within milliseconds; a bound that did not hold would be stopped by the
    // timeout (the message tells which) before it took the machine.
    let server = Server::start(&[
        "--in-memory",
        "--query-memory",
        "16",
        "--query-timeout",
        "2",
    ]);
    let agent = agent_with_timeout(Duration::from_secs(60));
    let base = server.url.clone();
    let pid = server.child.id();
    let resident = status_kb(pid, "VmRSS");
    // The peak from here on (start-up's is forgotten; where the kernel refuses, it counts).
    if let Err(e) = std::fs::write(format!("/proc/{pid}/clear_refs"), "5") {
        eprintln!("the peak is not reset ({e}): start-up's counts too");
    }
    // Unbounded, this sorted product over the ontology's triples grew the service by 750 MB
    // a second until its timeout.
    let product = "SELECT ?a ?d ?g WHERE { ?a ?b ?c . ?d ?e ?f . ?g ?h ?i } ORDER BY ?c ?f ?i";
    let (status, body) = post(
        &agent,
        &format!("{base}/sparql"),
        "application/sparql-query",
        product,
    );
    assert_eq!(status, 503, "{body}");
    assert!(
        body.contains("16 MiB") && body.contains("--query-memory"),
        "{body}"
    );
    let grown = status_kb(pid, "VmHWM").saturating_sub(resident);
    assert!(
        grown < 200 * 1024,
        "the service grew by {grown} kB for a query bounded to 16 MiB"
    );
    let (status, body) = post(
        &agent,
        &format!("{base}/sparql"),
        "application/sparql-query",
        "SELECT (COUNT(*) AS ?n) WHERE { ?s ?p ?o }",
    );
    assert_eq!(status, 200, "{body}");

    // One CONCAT of 512 copies of a 4 MiB string builds 2 GiB in one call, before any
    // check of the budget: a user audit saw the service reach 4.2 GB under this 16 MiB limit.
    // The string functions ask for their room first.
    let mut amplify =
        String::from("SELECT (STRLEN(?x) AS ?n) WHERE { BIND(CONCAT(\"a\", \"a\") AS ?x0)");
    for level in 1..=7 {
        let previous = format!("?x{}", level - 1);
        amplify += &format!(
            " BIND(CONCAT({}) AS ?x{level})",
            vec![previous; 8].join(", ")
        );
    }
    amplify += &format!(" BIND(CONCAT({}) AS ?x) }}", vec!["?x7"; 512].join(", "));
    let resident = status_kb(pid, "VmRSS");
    if let Err(e) = std::fs::write(format!("/proc/{pid}/clear_refs"), "5") {
        eprintln!("the peak is not reset ({e}): the earlier one counts too");
    }
    let (status, body) = post(
        &agent,
        &format!("{base}/sparql"),
        "application/sparql-query",
        &amplify,
    );
    assert_eq!(status, 503, "{body}");
    assert!(body.contains("16 MiB"), "{body}");
    let grown = status_kb(pid, "VmHWM").saturating_sub(resident);
    eprintln!("the CONCAT grew the service by {grown} kB: {body}");
    assert!(
        grown < 200 * 1024,
        "the service grew by {grown} kB for a CONCAT bounded to 16 MiB"
    );
    // REPLACE quadruples at each of 20 levels: 4^20 bytes asked for.
    let mut replaced = String::from("\"a\"");
    for _ in 0..20 {
        replaced = format!("REPLACE({replaced}, \"a\", \"$0$0$0$0\")");
    }
    let (status, body) = post(
        &agent,
        &format!("{base}/sparql"),
        "application/sparql-query",
        &format!("SELECT (STRLEN({replaced}) AS ?n) WHERE {{}}"),
    );
    assert_eq!(status, 503, "{body}");
    assert!(body.contains("16 MiB"), "{body}");
    let grown = status_kb(pid, "VmHWM").saturating_sub(resident);
    assert!(grown < 200 * 1024, "the service grew by {grown} kB");
    server.kill9();
}

/// Queries nested or chained deeper than SPARQL's parser and evaluator can recurse are 400,
/// and the service lives on (a 2 KB query of 1,000 nested parentheses, or 1,000 UNION
/// branches, aborted it on a stack overflow).
#[test]
fn deep_sparql_queries_are_refused_and_the_service_lives_on() {
    let server = Server::start(&["--in-memory"]);
    let agent = agent();
    let base = server.url.clone();
    let nested = format!(
        "SELECT * WHERE {{ FILTER({}1{}) }}",
        "(".repeat(1_000),
        ")".repeat(1_000)
    );
    let url = format!(
        "{base}/sparql?query={}",
        nested
            .replace('(', "%28")
            .replace(')', "%29")
            .replace(' ', "%20")
    );
    let (status, body) = get(&agent, &url.replace('{', "%7B").replace('}', "%7D"));
    assert_eq!(status, 400, "{body}");
    assert!(body.contains("nests brackets deeper than"), "{body}");
    for branches in [1_000, 100_000] {
        let unions = format!(
            "SELECT * WHERE {{ {} }}",
            vec!["{ ?s <urn:p> ?o }"; branches].join(" UNION ")
        );
        let (status, body) = post(
            &agent,
            &format!("{base}/sparql"),
            "application/sparql-query",
            &unions,
        );
        assert_eq!(status, 400, "{branches}: {body}");
    }
    // A path of 7,000 steps (56 KB) kept a core busy for more than 11 minutes, planning the
    // join order, and held up the shutdown: refused at once.
    let path = format!(
        "SELECT * WHERE {{ ?s {} ?o }}",
        vec!["<urn:p>"; 7_000].join("/")
    );
    let (status, body) = post(
        &agent,
        &format!("{base}/sparql"),
        "application/sparql-query",
        &path,
    );
    assert_eq!(status, 400, "{body}");
    assert!(body.contains("triple patterns"), "{body}");
    let (status, _) = get(&agent, &format!("{base}/health"));
    assert_eq!(status, 200);
    let ok = "SELECT * WHERE { { ?s <urn:p> ?o } UNION { ?s <urn:q> ?o } }";
    let (status, body) = post(
        &agent,
        &format!("{base}/sparql"),
        "application/sparql-query",
        ok,
    );
    assert_eq!(status, 200, "{body}");
    server.kill9();
}
