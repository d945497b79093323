//! A formula group at scale (issue 15's performance bar, `docs/benchmarks.md`): one group of
//! 1,000 formulas over 100 symbols, fed by 100 `dyknow/signal` sources at 100 Hz each on a
//! stand-alone executor, synchronised with the `event` policy (a state per sample: 10,000
//! states per second). Measured: sample-to-verdict latency (from a sample's publication, its
//! `t`, to the verdict it decides arriving on the result channel), sustained states per
//! second, the service's CPU per state and its RSS over the run; then the recorded trace is
//! replayed through `dyknow check` with the same formulas, against real time.
//!
//! `cargo bench -p dyknow-server --bench groups -- [--seconds S] [--symbols N] [--hz H]`
//! (or `-- --create 5,10,15,21`: the time `POST /groups` takes for large groups, see `create`;
//! `DYKNOW_BIN` runs another build of the service)
//! (`./dev bench groups` runs it for 180 s: about 100,000 states); `--baseline 1` runs the same
//! sources and CUs with the group never started.

#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use dyknow_cu::zenoh::{self, Wait};
use serde_json::{Value, json};

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .status();
        let _ = self.0.wait();
    }
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(300)))
        .build()
        .into()
}

fn get(url: &str, path: &str) -> Value {
    let mut r = agent().get(&format!("{url}{path}")).call().unwrap();
    serde_json::from_str(
        &r.body_mut()
            .with_config()
            .limit(u64::MAX)
            .read_to_string()
            .unwrap(),
    )
    .unwrap()
}

fn post(url: &str, path: &str, media: &str, body: &str) -> Value {
    let mut r = agent()
        .post(&format!("{url}{path}"))
        .header("Content-Type", media)
        .send(body.as_bytes())
        .unwrap();
    let status = r.status().as_u16();
    let text = r.body_mut().read_to_string().unwrap();
    assert!(status < 300, "POST {path}: {status} {text}");
    serde_json::from_str(&text).unwrap_or(Value::Null)
}

fn arg(name: &str, default: u64) -> u64 {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn now_ms_f() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
        * 1e3
}

/// utime + stime of a process, in seconds.
fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let rest = stat.rsplit(')').next().unwrap_or_default();
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11).and_then(|v| v.parse().ok()).unwrap_or(0.0)
        + f.get(12).and_then(|v| v.parse().ok()).unwrap_or(0.0);
    ticks / 100.0
}

fn rss_mib(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(0.0)
        / 1024.0
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// The formulas: per symbol, five that a sample decides during the run (staggered thresholds
/// on the counter each source publishes) and five of the seed's Figure 3.6/3.7 patterns
/// (invariant, response, bounded invariant, until, next) that stay open.
fn formulas(symbols: usize, hz: u64) -> Vec<String> {
    let mut out = Vec::new();
    for i in 0..symbols {
        let j = (i + 1) % symbols;
        for k in 0..5 {
            // Thresholds 10 s to 20 s of counting after the source starts.
            let threshold = hz * 10 + k as u64 * hz * 2 + (i as u64 % 10) * hz / 5;
            out.push(format!("eventually x{i} > {threshold}"));
        }
        out.push(format!("always x{i} >= 0"));
        out.push(format!(
            "always (x{i} >= 0 -> eventually[0,100ms] x{j} >= 0)"
        ));
        out.push(format!("always[0,600s] x{i} < 100000000"));
        out.push(format!("x{i} >= 0 U[0,600s] x{j} < 0"));
        out.push(format!("always (x{i} > 10 -> next x{i} >= 0)"));
    }
    out
}

/// `dyknow serve` on the on-disk store `data` with its Zenoh router on `zenoh` and `extra`
/// arguments, bound to a free port; returns it (stopped when dropped) and its URL. Its
/// standard error is drained. `DYKNOW_BIN` runs another build of `dyknow` (an earlier
/// commit's, to compare).
fn serve(data: &std::path::Path, zenoh: &str, extra: &[&str]) -> (Proc, String) {
    let bin = std::env::var("DYKNOW_BIN").unwrap_or_else(|_| BIN.to_owned());
    let mut child = Command::new(bin)
        .arg("serve")
        .arg("--data")
        .arg(data)
        .args(["--bind", "127.0.0.1:0", "--zenoh-listen", zenoh])
        .args(extra)
        .env("RUST_LOG", "warn,dyknow_server=info")
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
    std::thread::spawn(move || for _ in lines.map_while(Result::ok) {});
    (Proc(child), url)
}

/// `--create N,N,..`: how long `POST /groups` takes to answer for a group of one formula whose
/// three nested `forall` over a domain of `N` constants ground `N`³ symbols, each a target
/// (the groups' limit is 10,000 ground atoms: 21³ = 9,261 is the largest cube under it). On
/// disk with the embedded executor, as `./dev serve` runs; each group is deleted before the
/// next (its targets released), and each uses a predicate of its own.
fn create(sizes: &str) {
    let zenoh_ep = format!("tcp/127.0.0.1:{}", free_port());
    let data = std::env::temp_dir().join(format!("dyknow-groups-create-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data);
    let (service, url) = serve(&data, &zenoh_ep, &[]);
    println!("| domain | symbols (targets) | POST /groups answered in | DELETE answered in |");
    println!("| ---: | ---: | ---: | ---: |");
    for (k, n) in sizes
        .split(',')
        .filter_map(|n| n.trim().parse::<usize>().ok())
        .enumerate()
    {
        let domain: Vec<String> = (0..n).map(|i| format!("c{i}")).collect();
        let body = json!({
            "label": format!("create{k}"),
            "domains": {"D": domain},
            "formulas": [format!("forall x in D: forall y in D: forall z in D: always[0,1s] P{k}(x,y,z)")],
            "start": true,
        });
        let started = Instant::now();
        let group = post(&url, "/groups", "application/json", &body.to_string());
        let took = started.elapsed();
        assert_eq!(group["symbols"].as_array().map_or(0, Vec::len), n * n * n);
        let started = Instant::now();
        let status = agent()
            .delete(&format!("{url}/groups/create{k}"))
            .call()
            .unwrap()
            .status()
            .as_u16();
        assert_eq!(status, 204);
        println!(
            "| {n} | {} | {:.2} s | {:.2} s |",
            n * n * n,
            took.as_secs_f64(),
            started.elapsed().as_secs_f64()
        );
    }
    drop(service);
    let _ = std::fs::remove_dir_all(&data);
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Some(sizes) = args
        .iter()
        .position(|a| a == "--create")
        .and_then(|i| args.get(i + 1))
    {
        create(sizes);
        return;
    }
    let seconds = arg("--seconds", 25);
    let symbols = arg("--symbols", 100) as usize;
    let hz = arg("--hz", 100);
    let zenoh_ep = format!("tcp/127.0.0.1:{}", free_port());
    // On disk, as a deployment runs: the trace goes to a file, not to memory.
    let data = std::env::temp_dir().join(format!("dyknow-groups-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data);
    let (service, url) = serve(&data, &zenoh_ep, &["--no-executor"]);
    let pid = service.0.id();
    let mut exec = Command::new(BIN)
        .args(["executor", "--name", "bench", "--connect", &zenoh_ep])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let _ = &mut exec;
    let executor = Proc(exec);

    // 100 sources, one per symbol, tagged with the symbol.
    let mut ttl = String::from(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n@prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .\n@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n",
    );
    for i in 0..symbols {
        ttl.push_str(&format!(
            "[] a dkros:ROSTransformation ; rdfs:label \"src{i}\" ; dkros:hasType \"builtin\" ; dkros:hasSource \"dyknow/signal\" ;\n\
             dkros:hasParam [ a dyknow:Parameter ; dyknow:hasName \"period_ms\" ; dyknow:hasValue {} ] ;\n\
             dkros:hasPort [ a dyknow:OutPort ; dyknow:hasName \"out\" ; dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"x{i}\" ] ] .\n",
            1000 / hz
        ));
    }
    // Wait for the executor.
    let deadline = Instant::now() + Duration::from_secs(30);
    while get(&url, "/executors")
        .as_array()
        .is_none_or(|e| e.is_empty())
    {
        assert!(Instant::now() < deadline, "the executor did not join");
        std::thread::sleep(Duration::from_millis(50));
    }
    post(&url, "/transformations", "text/turtle", &ttl);
    let fs = formulas(symbols, hz);
    let created = post(
        &url,
        "/groups",
        "application/json",
        &json!({"label": "bench", "formulas": fs, "sync": {"policy": "event"}}).to_string(),
    );
    assert_eq!(created["symbols"].as_array().unwrap().len(), symbols);
    let t0 = Instant::now();
    loop {
        let satisfied = get(&url, "/targets")
            .as_array()
            .unwrap()
            .iter()
            .filter(|t| t["satisfied"] == true)
            .count();
        if satisfied == symbols {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "{satisfied} of {symbols} targets satisfied"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    println!(
        "setup: {symbols} sources at {hz} Hz, {} formulas, targets satisfied after {:.1} s",
        fs.len(),
        t0.elapsed().as_secs_f64()
    );

    // Verdicts on the result channel: latency from the deciding sample's t.
    let session = zenoh::open(dyknow_cu::client_config(std::slice::from_ref(&zenoh_ep)).unwrap())
        .wait()
        .unwrap();
    let latencies = Arc::new(Mutex::new(Vec::<f64>::new()));
    let l2 = latencies.clone();
    let key = dyknow_cu::Namespace::new("dyknow".to_owned())
        .unwrap()
        .channel("/dyknow/verdicts/bench")
        .unwrap();
    let _sub = session
        .declare_subscriber(key)
        .callback(move |s| {
            let now = now_ms_f();
            if let Ok(sample) = dyknow_cu::Sample::from_slice(&s.payload().to_bytes())
                && sample.value["verdict"] != "unknown"
            {
                l2.lock().unwrap().push(now - sample.t as f64);
            }
        })
        .wait()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    // `--baseline 1`: the same sources and CUs, the group never started (what the service
    // costs without progression).
    let baseline = arg("--baseline", 0) == 1;
    if !baseline {
        post(&url, "/groups/bench/start", "application/json", "");
    }
    let start = Instant::now();
    let (cpu0, states0) = (cpu_s(pid), 0u64);
    let mut rss = Vec::new();
    let mut last = (start, cpu0, states0);
    println!(
        "{:>6} {:>10} {:>12} {:>14} {:>9} {:>9}",
        "t (s)", "states", "states/s", "CPU µs/state", "RSS MiB", "verdicts"
    );
    while start.elapsed() < Duration::from_secs(seconds) {
        std::thread::sleep(Duration::from_secs(5));
        let g = get(&url, "/groups/bench");
        let states = g["states"].as_u64().unwrap();
        let cpu = cpu_s(pid);
        let dt = last.0.elapsed().as_secs_f64();
        let ds = (states - last.2) as f64;
        let r = rss_mib(pid);
        rss.push(r);
        println!(
            "{:>6.0} {:>10} {:>12.0} {:>14.1} {:>9.1} {:>9}",
            start.elapsed().as_secs_f64(),
            states,
            ds / dt,
            if ds > 0.0 {
                (cpu - last.1) / ds * 1e6
            } else {
                f64::NAN
            },
            r,
            latencies.lock().unwrap().len()
        );
        last = (Instant::now(), cpu, states);
    }
    if baseline {
        println!(
            "baseline: service RSS {:.1} → {:.1} MiB, CPU {:.0} % of one core",
            rss.first().copied().unwrap_or(0.0),
            rss.last().copied().unwrap_or(0.0),
            (cpu_s(pid) - cpu0) / start.elapsed().as_secs_f64() * 100.0
        );
        return;
    }
    let g = get(&url, "/groups/bench");
    let states = g["states"].as_u64().unwrap();
    let elapsed = start.elapsed().as_secs_f64();
    let cpu = cpu_s(pid) - cpu0;
    let samples: u64 = g["symbols"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["samples"].as_u64().unwrap())
        .sum();
    let late: u64 = g["symbols"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["late"].as_u64().unwrap())
        .sum();
    post(&url, "/groups/bench/stop", "application/json", "");
    let mut lat = latencies.lock().unwrap().clone();
    lat.sort_by(f64::total_cmp);
    println!();
    println!("| measure | value |");
    println!("| --- | --- |");
    println!("| samples received / s | {:.0} |", samples as f64 / elapsed);
    println!(
        "| states / s (event policy) | {:.0} |",
        states as f64 / elapsed
    );
    println!(
        "| late samples (same ms as the state before) | {late} ({:.2} %) |",
        late as f64 * 100.0 / samples.max(1) as f64
    );
    println!(
        "| service CPU per state | {:.1} µs ({:.0} % of one core) |",
        cpu / states.max(1) as f64 * 1e6,
        cpu / elapsed * 100.0
    );
    println!(
        "| sample-to-verdict latency p50 / p99 / max ({} verdicts) | {:.2} / {:.2} / {:.2} ms |",
        lat.len(),
        percentile(&lat, 0.5),
        percentile(&lat, 0.99),
        lat.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "| service RSS first / last sample | {:.1} / {:.1} MiB |",
        rss.first().copied().unwrap_or(0.0),
        rss.last().copied().unwrap_or(0.0)
    );

    // Replay the recorded trace through `dyknow check`.
    let mut r = agent()
        .get(&format!("{url}/groups/bench/trace"))
        .call()
        .unwrap();
    let text = r
        .body_mut()
        .with_config()
        .limit(u64::MAX)
        .read_to_string()
        .unwrap();
    let mut file = tempfile::Builder::new()
        .prefix("dyknow-groups-bench-trace")
        .suffix(".jsonl")
        .tempfile()
        .unwrap();
    file.write_all(text.as_bytes()).unwrap();
    file.flush().unwrap();
    let ts: Vec<u64> = text
        .lines()
        .skip(1)
        .filter_map(|l| serde_json::from_str::<Value>(l).ok()?["t"].as_u64())
        .collect();
    let span_s = (ts.last().unwrap() - ts.first().unwrap()) as f64 / 1e3;
    let mut cmd = Command::new(BIN);
    cmd.arg("check");
    for f in &fs {
        cmd.args(["--formula", f]);
    }
    let t = Instant::now();
    let out = cmd.arg("--trace").arg(file.path()).output().unwrap();
    let replay = t.elapsed().as_secs_f64();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let verdict_lines = String::from_utf8_lossy(&out.stdout).lines().count();
    println!(
        "| replay of the recorded trace ({} states over {span_s:.1} s) through `dyknow check` | {replay:.2} s: {:.1}× real time, {:.0} states/s ({verdict_lines} verdict lines) |",
        ts.len(),
        span_s / replay,
        ts.len() as f64 / replay
    );
    drop(executor);
    drop(service);
    let _ = std::fs::remove_dir_all(&data);
}
