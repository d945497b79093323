//! The seed's Figure 5.5, on Zenoh: the time a sample takes through a linear chain of n relay
//! CUs, for DyKnow builtin CUs (threads of one executor), DyKnow process CUs (one process
//! each), and, side by side in the same run, plain Zenoh forwarders written directly against
//! the `zenoh` crate (in one process, and one process per hop). Then the steady idle CPU of
//! one executor running 1,000 CUs.
//!
//! `cargo bench -p dyknow-executor --bench chain -- [--messages N] [--rate HZ] [--hops 1,10,25,50]
//! [--idle-cus N] [--in-process-only]`
//! (`--rate 0`, the default, sends back to back: the next sample when the last arrived).

#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use dyknow_cu::protocol::{ApplyRequest, CuAction, Implementation};
use dyknow_cu::zenoh::{self, Wait};
use dyknow_cu::{Namespace, Sample};
use dyknow_executor::{Executor, ExecutorConfig};

const CU_BIN: &str = env!("CARGO_BIN_EXE_dyknow-cu");
const FORWARD_BIN: &str = env!("CARGO_BIN_EXE_dyknow-bench-forward");

struct Args {
    messages: usize,
    rate: f64,
    hops: Vec<usize>,
    idle_cus: usize,
    in_process_only: bool,
}

fn args() -> Args {
    let mut a = Args {
        messages: 1000,
        rate: 0.0,
        hops: vec![1, 10, 25, 50],
        idle_cus: 1000,
        in_process_only: false,
    };
    let argv: Vec<String> = std::env::args().skip(1).collect();
    let mut i = 0;
    while i < argv.len() {
        let value = argv.get(i + 1).cloned().unwrap_or_default();
        match argv[i].as_str() {
            "--messages" => a.messages = value.parse().expect("--messages N"),
            "--rate" => a.rate = value.parse().expect("--rate HZ"),
            "--hops" => {
                a.hops = value
                    .split(',')
                    .map(|h| h.parse().expect("--hops 1,10"))
                    .collect()
            }
            "--idle-cus" => a.idle_cus = value.parse().expect("--idle-cus N"),
            "--in-process-only" => {
                a.in_process_only = true;
                i += 1;
                continue;
            }
            _ => {
                i += 1;
                continue;
            }
        }
        i += 2;
    }
    a
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn router(endpoint: &str) -> zenoh::Session {
    zenoh::open(dyknow_cu::router_config(&[endpoint.to_owned()], &[]).unwrap())
        .wait()
        .unwrap()
}

/// A source and a sink on the ends of one chain.
struct Probe {
    name: &'static str,
    source: zenoh::pubsub::Publisher<'static>,
    arrivals: mpsc::Receiver<(u64, Instant)>,
    _sink: zenoh::pubsub::Subscriber<()>,
    times: Vec<Duration>,
}

impl Probe {
    /// Waits until the chain `first` → `last` carries samples (routes are declared
    /// asynchronously).
    fn new(session: &zenoh::Session, name: &'static str, first: &str, last: &str) -> Self {
        let (tx, arrivals) = mpsc::channel::<(u64, Instant)>();
        let sink = session
            .declare_subscriber(last.to_owned())
            .callback(move |s| {
                let at = Instant::now();
                if let Ok(sample) = Sample::from_slice(&s.payload().to_bytes())
                    && let Some(seq) = sample.value.as_u64()
                {
                    let _ = tx.send((seq, at));
                }
            })
            .wait()
            .unwrap();
        let source = session
            .declare_publisher(first.to_owned())
            .express(true)
            .wait()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            source.put(Sample::now(u64::MAX).to_bytes()).wait().unwrap();
            if arrivals.recv_timeout(Duration::from_millis(50)).is_ok() {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "the chain {first} → {last} carries nothing"
            );
        }
        while arrivals.try_recv().is_ok() {}
        Self {
            name,
            source,
            arrivals,
            _sink: sink,
            times: Vec::new(),
        }
    }

    /// Sends sample `seq` and waits for it at the sink; records the time unless warming up.
    fn once(&mut self, seq: u64, record: bool) {
        let started = Instant::now();
        self.source.put(Sample::now(seq).to_bytes()).wait().unwrap();
        loop {
            let (got, at) = self
                .arrivals
                .recv_timeout(Duration::from_secs(10))
                .expect("a sample through the chain");
            if got == seq {
                if record {
                    self.times.push(at - started);
                }
                return;
            }
        }
    }
}

const WARMUP: u64 = 50;

/// Back to back: each chain in turn gets its samples, the next one sent when the last arrived.
fn back_to_back(probes: &mut [Probe], messages: usize) {
    for probe in probes {
        for seq in 0..WARMUP + messages as u64 {
            probe.once(seq, seq >= WARMUP);
        }
    }
}

/// At `rate` Hz per chain, the chains interleaved: in every period each chain gets one
/// sample, spread evenly over the period, so all variants see the same machine at the same
/// time and none warms the caches for the next.
fn at_rate(probes: &mut [Probe], messages: usize, rate: f64) {
    let slot = Duration::from_secs_f64(1.0 / rate / probes.len() as f64);
    let mut next = Instant::now();
    for seq in 0..WARMUP + messages as u64 {
        for probe in probes.iter_mut() {
            probe.once(seq, seq >= WARMUP);
            next += slot;
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            } else {
                next = now;
            }
        }
    }
}

struct Stats {
    mean: f64,
    p50: f64,
    p99: f64,
}

fn stats(mut t: Vec<Duration>) -> Stats {
    t.sort();
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let mean = t.iter().map(|d| us(*d)).sum::<f64>() / t.len() as f64;
    let pct = |p: f64| us(t[((t.len() as f64 * p) as usize).min(t.len() - 1)]);
    Stats {
        mean,
        p50: pct(0.5),
        p99: pct(0.99),
    }
}

fn relay(kind: &str, source: &str) -> Implementation {
    Implementation {
        kind: kind.into(),
        source: source.into(),
        params: Default::default(),
        executor: None,
        inputs: vec!["in".into()],
        outputs: vec!["out".into()],
    }
}

/// A chain of n relay CUs in `executor`, from channel `{prefix}0` to `{prefix}{n}`.
fn dyknow_chain(
    executor: &Executor,
    prefix: &str,
    n: usize,
    implementation: &Implementation,
) -> Vec<String> {
    let mut actions = Vec::new();
    let mut names = Vec::new();
    for i in 0..n {
        let cu = format!("{prefix}-cu{i}");
        actions.push(CuAction::Spawn {
            cu: cu.clone(),
            transformation: "relay".into(),
            implementation: implementation.clone(),
        });
        actions.push(CuAction::ConnectOut {
            cu: cu.clone(),
            port: "out".into(),
            channel: format!("{prefix}{}", i + 1),
        });
        actions.push(CuAction::ConnectIn {
            cu: cu.clone(),
            port: "in".into(),
            channel: format!("{prefix}{i}"),
        });
        names.push(cu);
    }
    let reply = executor.apply(&ApplyRequest {
        instance: None,
        change_set: "bench".into(),
        generation: 0,
        actions,
    });
    assert!(reply.failures.is_empty(), "{:?}", reply.failures);
    names
}

fn destroy(executor: &Executor, names: Vec<String>) {
    let actions = names
        .into_iter()
        .map(|cu| CuAction::Destroy { cu })
        .collect();
    executor.apply(&ApplyRequest {
        instance: None,
        change_set: "bench".into(),
        generation: 0,
        actions,
    });
}

fn main() {
    let args = args();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let session = router(&endpoint);
    let ns = Namespace::default();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("bench", ns.clone(), vec![endpoint.clone()]),
    )
    .unwrap();
    println!(
        "chain of n relays: {} messages {}, after {WARMUP} to warm up; latency source → sink in µs",
        args.messages,
        if args.rate > 0.0 {
            format!(
                "at {} Hz per chain, the four chains of each n interleaved",
                args.rate
            )
        } else {
            "back to back, one chain after another".into()
        }
    );
    println!(
        "{:<28} {:>4} {:>10} {:>10} {:>10} {:>12} {:>14}",
        "variant", "n", "mean", "p50", "p99", "p50 per hop", "vs plain/hop"
    );
    for &n in &args.hops {
        // Plain Zenoh forwarders in this process (the baseline for builtin CUs).
        let mut forwarders = Vec::new();
        for i in 0..n {
            let publisher = session
                .declare_publisher(format!("bench/plain/{}", i + 1))
                .express(true)
                .wait()
                .unwrap();
            forwarders.push(
                session
                    .declare_subscriber(format!("bench/plain/{i}"))
                    .callback(move |s| {
                        let _ = publisher.put(s.payload().clone()).wait();
                    })
                    .wait()
                    .unwrap(),
            );
        }
        // DyKnow builtin relays in the executor.
        let builtins = dyknow_chain(&executor, "b", n, &relay("builtin", "dyknow/relay"));
        // Plain Zenoh forwarders, one process per hop.
        let per_process = if args.in_process_only { 0 } else { n };
        let mut children: Vec<Child> = (0..per_process)
            .map(|i| {
                Command::new(FORWARD_BIN)
                    .args([
                        &endpoint,
                        &format!("bench/pp/{i}"),
                        &format!("bench/pp/{}", i + 1),
                    ])
                    .stdin(Stdio::piped())
                    .stdout(Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .collect();
        for child in &mut children {
            let mut line = String::new();
            BufReader::new(child.stdout.as_mut().unwrap())
                .read_line(&mut line)
                .unwrap();
            assert_eq!(line.trim(), "ready");
        }
        // DyKnow process CUs.
        let processes = dyknow_chain(
            &executor,
            "p",
            per_process,
            &relay("process", &format!("{CU_BIN} dyknow/relay")),
        );
        let channel = |c: String| ns.channel(&c).unwrap();
        let mut probes = vec![
            Probe::new(
                &session,
                "plain zenoh, in-process",
                "bench/plain/0",
                &format!("bench/plain/{n}"),
            ),
            Probe::new(
                &session,
                "dyknow builtin CUs",
                &channel("b0".into()),
                &channel(format!("b{n}")),
            ),
        ];
        if !args.in_process_only {
            probes.extend([
                Probe::new(
                    &session,
                    "plain zenoh, process/hop",
                    "bench/pp/0",
                    &format!("bench/pp/{n}"),
                ),
                Probe::new(
                    &session,
                    "dyknow process CUs",
                    &channel("p0".into()),
                    &channel(format!("p{n}")),
                ),
            ]);
        }
        if args.rate > 0.0 {
            at_rate(&mut probes, args.messages, args.rate);
        } else {
            back_to_back(&mut probes, args.messages);
        }
        drop(forwarders);
        destroy(&executor, builtins);
        for mut child in children {
            let _ = child.stdin.take().map(|mut s| s.write_all(b"\n"));
            let _ = child.wait();
        }
        destroy(&executor, processes);
        let hop = |s: &Stats| s.p50 / n as f64;
        let mut baseline: Option<Stats> = None;
        for (k, probe) in probes.into_iter().enumerate() {
            let name = probe.name;
            let s = stats(probe.times);
            // Even rows are the plain baselines of the DyKnow rows after them.
            let vs = match (&baseline, k % 2) {
                (Some(b), 1) => format!("{:+.2} µs", hop(&s) - hop(b)),
                _ => String::new(),
            };
            println!(
                "{:<28} {:>4} {:>10.1} {:>10.1} {:>10.1} {:>12.2} {:>14}",
                name,
                n,
                s.mean,
                s.p50,
                s.p99,
                hop(&s),
                vs
            );
            if k % 2 == 0 {
                baseline = Some(s);
            }
        }
    }
    if args.idle_cus == 0 {
        executor.shutdown();
        return;
    }
    // 1,000 CUs idle in one executor.
    let idle: Vec<String> = {
        let mut actions = Vec::new();
        let mut names = Vec::new();
        for i in 0..args.idle_cus {
            let cu = format!("idle{i}");
            actions.push(CuAction::Spawn {
                cu: cu.clone(),
                transformation: "relay".into(),
                implementation: relay("builtin", "dyknow/relay"),
            });
            actions.push(CuAction::ConnectIn {
                cu: cu.clone(),
                port: "in".into(),
                channel: format!("idle/in{i}"),
            });
            actions.push(CuAction::ConnectOut {
                cu: cu.clone(),
                port: "out".into(),
                channel: format!("idle/out{i}"),
            });
            names.push(cu);
        }
        let started = Instant::now();
        let reply = executor.apply(&ApplyRequest {
            instance: None,
            change_set: "idle".into(),
            generation: 0,
            actions,
        });
        assert!(reply.failures.is_empty());
        println!(
            "\n{} builtin CUs spawned and bound in {:?}",
            args.idle_cus,
            started.elapsed()
        );
        names
    };
    std::thread::sleep(Duration::from_secs(2));
    let pid = std::process::id();
    let cpu0 = dyknow_executor::process::process_cpu_total(pid).unwrap();
    let wall0 = Instant::now();
    std::thread::sleep(Duration::from_secs(10));
    let cpu = dyknow_executor::process::process_cpu_total(pid).unwrap() - cpu0;
    let wall = wall0.elapsed();
    println!(
        "idle: {} CUs in one executor (and its Zenoh router): {:.2} % of a core over {:?}",
        args.idle_cus,
        100.0 * cpu.as_secs_f64() / wall.as_secs_f64(),
        wall
    );
    destroy(&executor, idle);
    executor.shutdown();
}
