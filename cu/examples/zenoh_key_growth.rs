//! What two connected Zenoh routers keep for liveliness tokens declared and undeclared again
//! (docs/reliability.md, guarantee 3): `cargo run --release --example zenoh_key_growth --
//! MODE N` declares and undeclares N tokens in one router while another one, linked to it
//! over loopback TCP, sees them, and prints the process's resident memory before and after.
//!
//! MODE is how the keys are made: `unique` (a new key per token, as a CU's token was when
//! every CU got a name of its own), `reused` (16 keys taken in turn), `scoped` (a new key per
//! token under a wildcard chunk, so the routers' key-expression mapping is the shared prefix).
#![expect(
    clippy::unwrap_used,
    reason = "an experiment: a failed set-up is a failed run"
)]

use std::time::{Duration, Instant};

use dyknow_cu::zenoh::{self, Wait};

fn rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

fn router(listen: &[String], connect: &[String]) -> zenoh::Session {
    zenoh::open(dyknow_cu::router_config(listen, connect).unwrap())
        .wait()
        .unwrap()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mode = args.get(1).map_or("unique", String::as_str).to_owned();
    let n: usize = args.get(2).and_then(|n| n.parse().ok()).unwrap_or(20_000);
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let manager = router(std::slice::from_ref(&endpoint), &[]);
    let executor = router(&[], std::slice::from_ref(&endpoint));
    // The manager watches something, as the fleet watches the executors' tokens.
    let seen = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counter = seen.clone();
    let _watch = manager
        .liveliness()
        .declare_subscriber("exp/@dyknow/cu/**")
        .callback(move |_| {
            counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        })
        .wait()
        .unwrap();
    let key = |i: usize| match mode.as_str() {
        "reused" => format!("exp/@dyknow/cu/cu-{}", i % 16),
        "scoped" => format!("exp/@dyknow/cu/*/cu-{i}"),
        _ => format!("exp/@dyknow/cu/cu-{i}"),
    };
    // Warm-up: the first thousand.
    for i in 0..1_000 {
        drop(executor.liveliness().declare_token(key(i)).wait().unwrap());
    }
    std::thread::sleep(Duration::from_millis(500));
    let before = rss_kb();
    let started = Instant::now();
    for i in 1_000..1_000 + n {
        let token = executor.liveliness().declare_token(key(i)).wait().unwrap();
        token.undeclare().wait().unwrap();
    }
    // Let the manager catch up with what was sent.
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut last = usize::MAX;
    while Instant::now() < deadline {
        let now = seen.load(std::sync::atomic::Ordering::Relaxed);
        if now == last {
            break;
        }
        last = now;
        std::thread::sleep(Duration::from_millis(300));
    }
    let after = rss_kb();
    println!(
        "{mode}: {n} tokens in {:.1} s, {last} liveliness samples seen, RSS {before} -> {after} kB ({:.2} kB per token)",
        started.elapsed().as_secs_f64(),
        (after.saturating_sub(before)) as f64 / n as f64
    );
}
