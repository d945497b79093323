//! The host's timers with workers against one thread firing every timer (`Timers::with_workers(0)`,
//! the design before, and still a process CU's), side by side in the same run.
//!
//! `cargo bench --locked -p dyknow-cu --bench timers` (~20 s). Two loads, each for 2 s:
//! - `many`: 200 timers every 5 ms (40,000 firings a second) with trivial callbacks, which
//!   measures the cost of a firing (quick timers fire on the queue's thread, without a
//!   hand-off to a worker);
//! - `camera`: 20 timers every 20 ms (a 50 Hz pose) beside one callback that works for 30 ms
//!   every 100 ms (a camera rendering its frame), which measures how long the others wait.
//!
//! Per load and design: firings a second, the process' CPU time per firing, and the longest
//! interval between two firings of one of the fast timers (its period when nothing holds it).

#![allow(clippy::unwrap_used, missing_docs)]

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cpu_time::{ProcessTime, ThreadTime};
use dyknow_cu::{Fire, Timers};

/// Counts its firings and keeps the longest interval between two.
struct Probe {
    fired: AtomicU64,
    last: Mutex<Option<Instant>>,
    longest_ns: AtomicU64,
    /// Busy for this long in every firing (a camera).
    work: Duration,
    /// The thread CPU time that busy work took, ns (not the timers' cost).
    worked_ns: AtomicU64,
}

impl Probe {
    fn new(work: Duration) -> Arc<Self> {
        Arc::new(Self {
            fired: AtomicU64::new(0),
            last: Mutex::new(None),
            longest_ns: AtomicU64::new(0),
            work,
            worked_ns: AtomicU64::new(0),
        })
    }
}

impl Fire for Probe {
    fn fire(&self, _timer: usize) -> bool {
        let now = Instant::now();
        if let Some(last) = self.last.lock().unwrap().replace(now) {
            let ns = u64::try_from((now - last).as_nanos()).unwrap_or(u64::MAX);
            self.longest_ns.fetch_max(ns, Ordering::Relaxed);
        }
        self.fired.fetch_add(1, Ordering::Relaxed);
        if !self.work.is_zero() {
            let cpu = ThreadTime::now();
            let until = now + self.work;
            while Instant::now() < until {
                std::hint::spin_loop();
            }
            let ns = u64::try_from(cpu.elapsed().as_nanos()).unwrap_or(u64::MAX);
            self.worked_ns.fetch_add(ns, Ordering::Relaxed);
        }
        true
    }
}

struct Row {
    firings_per_s: f64,
    cpu_us_per_firing: f64,
    longest_ms: f64,
}

/// Runs `fast` timers every `period` (and, if `camera`, one 30 ms callback every 100 ms) for
/// 2 s on `workers` workers.
fn run(workers: usize, fast: usize, period: Duration, camera: bool) -> Row {
    let timers = Timers::with_workers(workers);
    let probes: Vec<Arc<Probe>> = (0..fast).map(|_| Probe::new(Duration::ZERO)).collect();
    let mut held: Vec<Arc<dyn Fire>> = Vec::new();
    for p in &probes {
        let as_fire: Arc<dyn Fire> = p.clone();
        timers.every(Arc::downgrade(&as_fire), 0, period);
        held.push(as_fire);
    }
    let cam = Probe::new(Duration::from_millis(30));
    if camera {
        let as_fire: Arc<dyn Fire> = cam.clone();
        timers.every(Arc::downgrade(&as_fire), 0, Duration::from_millis(100));
        held.push(as_fire);
    }
    // Half a second to settle, then 2 s measured.
    std::thread::sleep(Duration::from_millis(500));
    for p in &probes {
        p.longest_ns.store(0, Ordering::Relaxed);
    }
    let before: u64 = probes.iter().map(|p| p.fired.load(Ordering::Relaxed)).sum();
    let worked_before = cam.worked_ns.load(Ordering::Relaxed);
    let (clock, cpu) = (Instant::now(), ProcessTime::now());
    std::thread::sleep(Duration::from_secs(2));
    let (elapsed, used) = (clock.elapsed(), cpu.elapsed());
    let worked = cam.worked_ns.load(Ordering::Relaxed) - worked_before;
    let after: u64 = probes.iter().map(|p| p.fired.load(Ordering::Relaxed)).sum();
    let longest = probes
        .iter()
        .map(|p| p.longest_ns.load(Ordering::Relaxed))
        .max()
        .unwrap_or(0);
    drop(held);
    let firings = (after - before) as f64;
    // The camera's own busy time is not the timers' cost (a firing in progress at either end
    // of the window makes this approximate, by up to one firing's work).
    Row {
        firings_per_s: firings / elapsed.as_secs_f64(),
        cpu_us_per_firing: (used.as_secs_f64() - worked as f64 / 1e9).max(0.0) * 1e6 / firings,
        longest_ms: longest as f64 / 1e6,
    }
}

fn main() {
    println!(
        "| load | design | firings/s | CPU µs per firing | longest interval of a fast timer (period) |"
    );
    println!("| --- | --- | ---: | ---: | ---: |");
    for (load, fast, period, camera) in [
        ("many", 200, Duration::from_millis(5), false),
        ("camera", 20, Duration::from_millis(20), true),
    ] {
        let one = run(0, fast, period, camera);
        let pool = run(Timers::WORKERS, fast, period, camera);
        for (design, row) in [
            ("one thread", &one),
            ("queue + 4 workers, quick timers inline", &pool),
        ] {
            println!(
                "| {load} | {design} | {:.0} | {:.2} | {:.1} ms ({} ms) |",
                row.firings_per_s,
                row.cpu_us_per_firing,
                row.longest_ms,
                period.as_millis()
            );
        }
        println!(
            "| {load} | workers / one thread | {:.2} | {:.2} | {:.2} |",
            pool.firings_per_s / one.firings_per_s,
            pool.cpu_us_per_firing / one.cpu_us_per_firing,
            pool.longest_ms / one.longest_ms
        );
    }
}
