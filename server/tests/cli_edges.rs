//! Edges of the `dyknow` command line (contract `cli.md`, docs/cli.md): the `group` client
//! against services that answer something else, or nothing; closed output pipes; empty tokens
//! and URLs; horizons whose costs would overflow; usage errors of `cu` and `listen`.
#![expect(
    clippy::unwrap_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

/// How a [`Fake`] service answers every request.
#[derive(Clone)]
enum Answer {
    /// This status, content type and body.
    With(u16, &'static str, String),
    /// Accepts the connection, reads the request, never answers.
    Never,
}

/// An HTTP service on 127.0.0.1 (an ephemeral port) that is not DyKnow; stopped on drop.
struct Fake {
    url: String,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Fake {
    fn start(answer: Answer) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::spawn(move || {
            // Connections kept open (`Answer::Never`) until the fake stops.
            let mut held = Vec::new();
            for stream in listener.incoming() {
                if stopping.load(Ordering::SeqCst) {
                    break;
                }
                let Ok(mut stream) = stream else { continue };
                let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
                read_request(&mut stream);
                match &answer {
                    Answer::With(status, content_type, body) => {
                        let _ = write!(
                            stream,
                            "HTTP/1.1 {status} Whatever\r\nContent-Type: {content_type}\r\n\
                             Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
                            body.len()
                        );
                        // Closed with bytes of the client's still unread, the connection is
                        // reset, and the client may see the reset before the answer (a CI
                        // run: "Connection reset by peer"): the answer is ended, and what
                        // the client sends is read until it closes.
                        let _ = stream.shutdown(std::net::Shutdown::Write);
                        let _ = std::io::copy(&mut stream, &mut std::io::sink());
                    }
                    Answer::Never => held.push(stream),
                }
            }
        });
        Self {
            url,
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Fake {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Wakes the accepting thread up.
        let _ = TcpStream::connect(self.url.trim_start_matches("http://"));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Reads a request's head and body (by its Content-Length).
fn read_request(stream: &mut TcpStream) {
    let mut reader = BufReader::new(stream);
    let mut length = 0;
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line).unwrap_or(0) == 0 || line == "\r\n" {
            break;
        }
        if let Some((name, value)) = line.split_once(':')
            && name.eq_ignore_ascii_case("content-length")
        {
            length = value.trim().parse().unwrap_or(0);
        }
    }
    let mut body = vec![0; length];
    let _ = reader.read_exact(&mut body);
}

/// `dyknow ARGS`, its exit status, stdout and stderr; killed (and the test failed) if it runs
/// past `limit`.
fn run(args: &[&str], env: &[(&str, &str)], limit: Duration) -> (i32, String, String) {
    let mut command = Command::new(BIN);
    command
        .args(args)
        .env_remove("DYKNOW_URL")
        .env_remove("DYKNOW_TOKEN")
        .env_remove("DYKNOW_CLIENT_TIMEOUT_S")
        .env_remove("DYKNOW_CU")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (name, value) in env {
        command.env(name, value);
    }
    let mut child = command.spawn().unwrap();
    // Drained as it runs: a full pipe would stall it.
    let drain = |mut from: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut text = Vec::new();
            let _ = from.read_to_end(&mut text);
            String::from_utf8_lossy(&text).into_owned()
        })
    };
    let stdout = drain(Box::new(child.stdout.take().unwrap()));
    let stderr = drain(Box::new(child.stderr.take().unwrap()));
    let deadline = Instant::now() + limit;
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "dyknow {args:?} still ran after {limit:?}; stderr: {}",
                stderr.join().unwrap()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    (
        status.code().unwrap_or(-1),
        stdout.join().unwrap(),
        stderr.join().unwrap(),
    )
}

const QUICK: Duration = Duration::from_secs(60);

/// Every `group` subcommand, with a label where it takes one.
const GROUP_COMMANDS: [&[&str]; 10] = [
    &["list"],
    &["show", "g"],
    &["create", "--label", "g", "--formula", "p"],
    &["start", "g"],
    &["stop", "g"],
    &["destroy", "g"],
    &["add", "g", "p"],
    &["remove", "g", "0"],
    &["trace", "g"],
    &["watch", "g"],
];

fn group(command: &[&str], url: &str, env: &[(&str, &str)]) -> (i32, String, String) {
    let mut args = vec!["group"];
    args.extend_from_slice(command);
    args.extend_from_slice(&["--url", url]);
    run(&args, env, QUICK)
}

/// A `--url` that leads to another HTTP service (200, `text/html`), to a truncated or
/// ill-shaped JSON answer: no `group` subcommand takes that for success (they printed `null`
/// or nothing, exit 0); each exits 2 with one line naming the URL and what came back.
#[test]
fn the_group_client_refuses_answers_that_are_not_a_services() {
    let html = Fake::start(Answer::With(200, "text/html", "<html>hi</html>".into()));
    for command in GROUP_COMMANDS {
        let (code, out, err) = group(command, &html.url, &[]);
        assert_eq!((code, out.as_str()), (2, ""), "{command:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{command:?}: {err}");
        assert!(
            err.contains(&format!("unexpected answer from {}/groups", html.url))
                && err.contains("text/html"),
            "{command:?}: {err}"
        );
    }
    // JSON, but not a list of groups.
    let shapeless = Fake::start(Answer::With(
        200,
        "application/json",
        r#"[{"weird": 1}]"#.into(),
    ));
    for command in [&["list"][..], &["show", "g"], &["add", "g", "p"]] {
        let (code, out, err) = group(command, &shapeless.url, &[]);
        assert_eq!((code, out.as_str()), (2, ""), "{command:?}: {err}");
        assert!(err.contains("unexpected answer"), "{command:?}: {err}");
    }
    // A group cut short.
    let truncated = Fake::start(Answer::With(
        200,
        "application/json",
        r#"{"label": "#.into(),
    ));
    let (code, out, err) = group(&["show", "g"], &truncated.url, &[]);
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    assert!(err.contains("not JSON"), "{err}");
    // An error page of many lines is one line of message.
    let error_page = Fake::start(Answer::With(
        404,
        "text/html",
        "<html>\n<body>\nnot here\n</body>\n</html>\n".into(),
    ));
    let (code, _, err) = group(&["show", "g"], &error_page.url, &[]);
    assert_eq!((code, err.lines().count()), (2, 1), "{err}");
}

/// A service that accepts the connection and never answers: the one-shot subcommands give up
/// after `DYKNOW_CLIENT_TIMEOUT_S` (they waited forever) with a message saying so, exit 2.
#[test]
fn a_client_request_that_gets_no_answer_times_out() {
    let silent = Fake::start(Answer::Never);
    for command in GROUP_COMMANDS.iter().filter(|c| c[0] != "watch") {
        let started = Instant::now();
        let (code, out, err) = group(command, &silent.url, &[("DYKNOW_CLIENT_TIMEOUT_S", "0.5")]);
        assert_eq!((code, out.as_str()), (2, ""), "{command:?}: {err}");
        assert!(
            err.contains(&format!("no answer from {} within 0.5 s", silent.url)),
            "{command:?}: {err}"
        );
        assert!(started.elapsed() < Duration::from_secs(20), "{command:?}");
    }
    for bad in ["0", "-1", "soon", "inf"] {
        let (code, _, err) = group(&["list"], &silent.url, &[("DYKNOW_CLIENT_TIMEOUT_S", bad)]);
        assert_eq!(code, 2, "{bad}: {err}");
        assert!(err.contains("DYKNOW_CLIENT_TIMEOUT_S"), "{bad}: {err}");
    }
}

/// An empty `DYKNOW_URL` is unset (it was "bad uri: /groups is missing scheme"); a malformed
/// URL is called malformed, with the form expected, not "is `dyknow serve` running?".
#[test]
fn empty_and_malformed_urls() {
    let (code, _, err) = run(&["group", "list"], &[("DYKNOW_URL", "")], QUICK);
    assert!(!err.contains("scheme"), "{err}");
    // The default URL: refused, or (a service on the default port) answered.
    assert!(
        code == 0 || err.contains("http://127.0.0.1:7878"),
        "{code}: {err}"
    );
    for url in [
        "127.0.0.1:47301",
        "ftp://127.0.0.1/",
        "http://[::1",
        "http://",
    ] {
        for (args, env) in [
            (vec!["group", "list", "--url", url], vec![]),
            (vec!["group", "list"], vec![("DYKNOW_URL", url)]),
        ] {
            let (code, _, err) = run(&args, &env, QUICK);
            assert_eq!(code, 2, "{url}: {err}");
            assert!(
                err.contains("is malformed") && err.contains("http://HOST:PORT"),
                "{url}: {err}"
            );
            assert!(!err.contains("running"), "{url}: {err}");
        }
    }
}

/// An empty token would lock every mutating request of the service for good (`Bearer ` is
/// no token): `serve` refuses it at start-up (it started), the client refuses it too; exit 2.
#[test]
fn an_empty_token_is_refused() {
    let serve = [
        "serve",
        "--in-memory",
        "--model-only",
        "--bind",
        "127.0.0.1:0",
    ];
    let mut with_flag = serve.to_vec();
    with_flag.extend(["--token", ""]);
    for (args, env) in [
        (with_flag, vec![]),
        (serve.to_vec(), vec![("DYKNOW_TOKEN", "")]),
        (serve.to_vec(), vec![("DYKNOW_TOKEN", "  ")]),
    ] {
        let (code, _, err) = run(&args, &env, QUICK);
        assert_eq!(code, 2, "{args:?} {env:?}: {err}");
        assert!(
            err.contains("token") && err.contains("empty"),
            "{args:?}: {err}"
        );
    }
    let fake = Fake::start(Answer::With(204, "text/plain", String::new()));
    for (args, env) in [
        (
            vec!["group", "destroy", "g", "--url", &fake.url, "--token", ""],
            vec![],
        ),
        (
            vec!["group", "destroy", "g", "--url", &fake.url],
            vec![("DYKNOW_TOKEN", "")],
        ),
    ] {
        let (code, _, err) = run(&args, &env, QUICK);
        assert_eq!(code, 2, "{env:?}: {err}");
        assert!(err.contains("token") && err.contains("empty"), "{err}");
    }
    // With a token, the same request is sent.
    let (code, _, err) = run(
        &["group", "destroy", "g", "--url", &fake.url, "--token", "t"],
        &[],
        QUICK,
    );
    assert_eq!(code, 0, "{err}");
}

fn spec(file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../specs/turtle")
        .join(file)
}

fn explore(extra: &[&str]) -> (i32, String, String) {
    let files: Vec<String> = [
        "example-12.ttl",
        "example-12-targets.ttl",
        "example-12-similarity.ttl",
    ]
    .iter()
    .map(|f| spec(f).display().to_string())
    .collect();
    let mut args = vec!["explore"];
    args.extend_from_slice(extra);
    args.extend(files.iter().map(String::as_str));
    run(&args, &[], QUICK)
}

/// `dyknow serve --in-memory --model-only` on a free port with `extra`, as far as it gets
/// within `QUICK`: its exit code and stderr.
fn serve_with(extra: &[&str]) -> (i32, String) {
    let mut args = vec![
        "serve",
        "--in-memory",
        "--model-only",
        "--bind",
        "127.0.0.1:0",
    ];
    args.extend_from_slice(extra);
    let (code, _, err) = run(&args, &[], QUICK);
    (code, err)
}

/// A horizon whose costs would overflow (H × upkeep past `f64::MAX`: `"total": null` at 6e307,
/// "no valid configuration" at 1e308) or that is not positive (`explore` took 0, `serve` did
/// not) is bad usage, exit 2, in `explore` and `serve` alike; up to 1e12 it is taken.
#[test]
fn horizons_past_the_bound_or_not_positive_are_refused() {
    for h in ["6e307", "1e308", "1e13", "0", "-1", "inf", "NaN"] {
        let flag = format!("--horizon={h}");
        let (code, out, err) = explore(&[&flag]);
        assert_eq!(
            (code, out.as_str()),
            (2, ""),
            "explore --horizon {h}: {err}"
        );
        assert!(err.contains("--horizon"), "{h}: {err}");
        let (code, err) = serve_with(&[&flag]);
        assert_eq!(code, 2, "serve --horizon {h}: {err}");
        assert!(err.contains("--horizon"), "{h}: {err}");
    }
    // The stable interval H × time unit is bounded too (a larger one made `serve` panic).
    let (code, err) = serve_with(&["--horizon", "1e11", "--time-unit", "100"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("stable interval"), "{err}");
    let (code, out, err) = explore(&["--horizon", "1e12"]);
    assert_eq!(code, 0, "{err}");
    let cs: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(cs["cost"]["total"].as_f64(), Some(3e12), "{out}");
}

/// `serve`'s durations in seconds refuse what is not a non-negative finite number, with a
/// message naming the flag, before anything starts.
#[test]
fn serve_durations_that_are_not_seconds_are_refused() {
    for flag in ["--reconcile-grace", "--forget-executors-after"] {
        for value in ["-1", "inf", "NaN", "1e300"] {
            let arg = format!("{flag}={value}");
            let (code, err) = serve_with(&[&arg]);
            assert_eq!(code, 2, "serve {arg}: {err}");
            assert!(err.contains(flag), "{arg}: {err}");
        }
    }
}

/// `explore --timeout-ms 0` is no limit, as `serve --explore-timeout-ms 0` is (it returned at
/// once with a change set that was not optimal).
#[test]
fn explore_timeout_0_is_no_limit() {
    let (code, out, err) = explore(&["--timeout-ms", "0"]);
    assert_eq!(code, 0, "{err}");
    let cs: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        (cs["optimal"].as_bool(), cs["cost"]["total"].as_f64()),
        (Some(true), Some(33.0)),
        "{out}"
    );
}

/// `dyknow cu` run by hand, outside an executor, is a usage error (exit 64, the CU
/// protocol's usage status; it was 1, which the protocol reads as a crash); `listen --count 0` is one too, as `group watch
/// --count 0` is (it exited 0 at once).
#[test]
fn usage_errors_of_cu_and_listen() {
    let (code, _, err) = run(&["cu", "dyknow/relay"], &[], QUICK);
    assert_eq!(code, 64, "{err}");
    assert!(
        err.contains("DYKNOW_CU") && err.contains("executor"),
        "{err}"
    );
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let (code, out, err) = run(
        &[
            "listen",
            "ch",
            "--count",
            "0",
            "--connect",
            &format!("tcp/127.0.0.1:{port}"),
        ],
        &[],
        QUICK,
    );
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    assert!(err.contains("--count"), "{err}");
}

/// A closed output pipe (`dyknow group show g | head -c 10`, with `2>&1`) stops the client
/// quietly, exit 0: it panicked (exit 101) printing the error on the closed stderr.
#[test]
fn a_closed_output_pipe_stops_the_group_client_quietly() {
    let formulas: Vec<Value> = (0..2000)
        .map(|i| serde_json::json!({"index": i, "formula": "p", "verdict": null, "t": null}))
        .collect();
    let body = serde_json::json!({"label": "g", "state": "created", "formulas": formulas});
    let service = Fake::start(Answer::With(200, "application/json", body.to_string()));
    for stderr_closed in [false, true] {
        let mut child = Command::new(BIN)
            .args(["group", "show", "g", "--url", &service.url])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        if stderr_closed {
            drop(child.stderr.take());
        }
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(
            (out.status.code(), stderr.as_ref()),
            (Some(0), ""),
            "stderr closed: {stderr_closed}"
        );
    }
}

/// `load` with its output pipe closed still loads every file (its lines only report) and exits
/// 0: stopping quietly at the first line would have left the later files out.
#[cfg(feature = "rocksdb")]
#[test]
fn load_with_a_closed_output_pipe_loads_every_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("store");
    let mut child = Command::new(BIN)
        .args(["load", "--data"])
        .arg(&data)
        .arg(spec("example-12.ttl"))
        .arg(spec("example-12-targets.ttl"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!((out.status.code(), stderr.as_ref()), (Some(0), ""));
    let data = data.display().to_string();
    let (code, model, err) = run(
        &["export", "--data", &data, "--format", "ntriples"],
        &[],
        QUICK,
    );
    assert_eq!(code, 0, "{err}");
    assert!(model.contains("qid1"), "the second file was not loaded");
}
