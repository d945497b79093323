//! Progression benchmark reproducing the seed's Figures 3.6 and 3.7 (issue 5):
//! `cargo bench -p dyknow-mstl --bench progression` (`./dev bench mstl`).
//!
//! 1,000 formulas progressed concurrently over 10,000 states at 100 ms steps, for
//! F1 = `always eventually[0,1000] p` and F2 = `always (!p -> eventually[0,1000] always[0,999] p)`
//! (the seed's (3.48), whose text reads `□¬p → ◇□p` but whose discussion — "this formula only
//! grows whenever p is false" — is that of `□(¬p → ◇□p)`), with p always true (`true`) and p
//! false for 10 steps then true once (`gap`). Two groups:
//! - `same`: 1,000 copies of one formula, as in the seed; the DAG makes them one node, so a
//!   step progresses one formula and finds the 999 others in the memo table;
//! - `distinct`: formula i is over its own proposition `p<i>` (same pattern), so every formula
//!   is progressed on its own: the honest per-formula cost.
//!
//! A formula that is decided (F2 is violated by `gap`) is restarted at once, as an execution
//! monitor that reports a violation and goes on watching, so every step progresses 1,000.
//!
//! Per step the time to progress all formulas is measured; divided by 1,000 it is the time per
//! formula-step (median, p99, max over the steps). Peak RSS is measured in child processes of
//! this binary at 10,000 and 100,000 states. The peers (reelay, mstlo; see
//! `benches/peers/mstl_peers.py`) run on the same patterns when `PEER_PYTHON` is set.
//!
//! Environment: `BENCH_QUICK=1` (1,000 states, no 100k RSS run), `PEER_STATES` (states for the
//! Python peers, default 2,000), `PEER_TIMEOUT_S`.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::io::Write;
use std::time::Instant;

use dyknow_mstl::{Monitor, Valuation, Value, parse};
use rustc_hash::FxHashMap;

const F1: &str = "always eventually[0,1000] p";
const F2: &str = "always (!p -> eventually[0,1000] always[0,999] p)";
const STEP_MS: u64 = 100;

/// The state at step `i`: every proposition has the pattern's value.
struct State {
    values: FxHashMap<String, bool>,
}

impl Valuation for State {
    fn value(&self, key: &str) -> Option<Value<'_>> {
        self.values.get(key).map(|b| Value::Bool(*b))
    }
}

fn p_at(pattern: &str, step: u64) -> bool {
    match pattern {
        "true" => true,
        _ => step % 11 == 10,
    }
}

struct Run {
    per_formula_step_ns: Vec<f64>,
    max_size: usize,
    max_nodes: usize,
    verdicts: usize,
}

/// Runs one scenario; `record` keeps the per-step times (the RSS runs do not, so the
/// measurement buffer does not grow with the stream).
fn run(formula: &str, pattern: &str, group: &str, n: usize, states: u64, record: bool) -> Run {
    let props: Vec<String> = (0..n)
        .map(|i| {
            if group == "same" {
                "p".to_owned()
            } else {
                format!("p{i}")
            }
        })
        .collect();
    let mut monitor = Monitor::new();
    for p in &props {
        let text = formula
            .replace(" p", &format!(" {p}"))
            .replace("!p", &format!("!{p}"));
        monitor.add(&parse(&text).unwrap()).unwrap();
    }
    // The two states of a pattern, built once.
    let mk = |v: bool| State {
        values: props.iter().map(|p| (p.clone(), v)).collect(),
    };
    let (yes, no) = (mk(true), mk(false));
    let mut times = Vec::with_capacity(if record { states as usize } else { 0 });
    let mut decided = Vec::new();
    let mut run = Run {
        per_formula_step_ns: Vec::new(),
        max_size: 0,
        max_nodes: 0,
        verdicts: 0,
    };
    for step in 0..states {
        let state = if p_at(pattern, step) { &yes } else { &no };
        let start = Instant::now();
        let verdicts = monitor.step(step * STEP_MS, state).unwrap();
        let elapsed = start.elapsed();
        decided.clear();
        decided.extend(verdicts.iter().map(|v| v.formula));
        run.verdicts += decided.len();
        for i in &decided {
            monitor.restart(*i);
        }
        if record {
            times.push(elapsed.as_nanos() as f64 / n as f64);
        }
        if step % 97 == 0 {
            run.max_size = run.max_size.max(monitor.size(0));
        }
        run.max_nodes = run.max_nodes.max(monitor.nodes());
    }
    run.per_formula_step_ns = times;
    run
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn peak_rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// Peak RSS of a child process that runs one scenario for `states` states.
fn rss_of(formula: &str, pattern: &str, group: &str, states: u64) -> u64 {
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args(["--rss", formula, pattern, group, &states.to_string()])
        .output()
        .unwrap();
    String::from_utf8_lossy(&out.stdout)
        .trim()
        .parse()
        .unwrap_or(0)
}

/// The peers' figures, from `benches/peers/mstl_peers.py` (one JSON line per run).
fn peer(
    python: &str,
    peer: &str,
    formula: &str,
    pattern: &str,
    states: u64,
) -> Option<serde_json::Value> {
    let script = format!(
        "{}/../benches/peers/mstl_peers.py",
        env!("CARGO_MANIFEST_DIR")
    );
    let timeout = std::env::var("PEER_TIMEOUT_S").unwrap_or_else(|_| "600".to_owned());
    let out = std::process::Command::new("timeout")
        .arg(timeout)
        .arg(python)
        .arg(script)
        .args(["--peer", peer, "--formula", formula, "--pattern", pattern])
        .args(["--formulas", "1000", "--states", &states.to_string()])
        .output()
        .ok()?;
    let line = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(line.lines().last()?).ok()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() == 6 && args[1] == "--rss" {
        let formula = if args[2] == "F1" { F1 } else { F2 };
        run(
            formula,
            &args[3],
            &args[4],
            1000,
            args[5].parse().unwrap(),
            false,
        );
        println!("{}", peak_rss_kb());
        return;
    }
    let quick = std::env::var("BENCH_QUICK").is_ok();
    let states: u64 = if quick { 1_000 } else { 10_000 };
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "# MSTL progression: 1,000 formulas × {states} states, 100 ms steps"
    )
    .unwrap();
    writeln!(out).unwrap();
    writeln!(
        out,
        "| formula | pattern | group | median ns/formula-step | p99 | max | largest formula (nodes) | DAG nodes (max) | verdicts |"
    )
    .unwrap();
    writeln!(
        out,
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    )
    .unwrap();
    let mut medians: FxHashMap<(String, String), f64> = FxHashMap::default();
    for (name, formula) in [("F1", F1), ("F2", F2)] {
        for pattern in ["true", "gap"] {
            for group in ["same", "distinct"] {
                let r = run(formula, pattern, group, 1000, states, true);
                let mut t = r.per_formula_step_ns.clone();
                t.sort_by(f64::total_cmp);
                let (med, p99, max) = (quantile(&t, 0.5), quantile(&t, 0.99), t[t.len() - 1]);
                if group == "distinct" {
                    medians.insert((name.to_owned(), pattern.to_owned()), med);
                }
                writeln!(
                    out,
                    "| {name} | {pattern} | {group} | {med:.1} | {p99:.1} | {max:.1} | {} | {} | {} |",
                    r.max_size, r.max_nodes, r.verdicts
                )
                .unwrap();
                out.flush().unwrap();
            }
        }
    }
    writeln!(out).unwrap();
    writeln!(out, "## Peak RSS (child process per run, `distinct` group)").unwrap();
    writeln!(out).unwrap();
    writeln!(
        out,
        "| formula | pattern | 10,000 states | 100,000 states |"
    )
    .unwrap();
    writeln!(out, "| --- | --- | --- | --- |").unwrap();
    for name in ["F1", "F2"] {
        for pattern in ["true", "gap"] {
            let small = rss_of(name, pattern, "distinct", 10_000);
            let large = if quick {
                "(BENCH_QUICK)".to_owned()
            } else {
                format!("{} KiB", rss_of(name, pattern, "distinct", 100_000))
            };
            writeln!(out, "| {name} | {pattern} | {small} KiB | {large} |").unwrap();
            out.flush().unwrap();
        }
    }
    let Ok(python) = std::env::var("PEER_PYTHON") else {
        writeln!(
            out,
            "\n(PEER_PYTHON not set: peers not run; `./dev bench mstl` sets it)"
        )
        .unwrap();
        return;
    };
    let peer_states: u64 = std::env::var("PEER_STATES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2_000);
    writeln!(out).unwrap();
    writeln!(
        out,
        "## Side by side: time per formula-step (median), DyKnow `distinct` vs peers ({peer_states} states for the peers)"
    )
    .unwrap();
    writeln!(out).unwrap();
    writeln!(
        out,
        "| formula | pattern | DyKnow | reelay | mstlo | faster peer ÷ DyKnow | peer formulas |"
    )
    .unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- | --- | --- |").unwrap();
    for name in ["F1", "F2"] {
        for pattern in ["true", "gap"] {
            let ours = medians[&(name.to_owned(), pattern.to_owned())];
            let mut best: Option<f64> = None;
            let mut cells = Vec::new();
            let mut specs = Vec::new();
            for p in ["reelay", "mstlo"] {
                match peer(&python, p, name, pattern, peer_states) {
                    Some(v) if v.get("median_us").is_some() => {
                        let ns = v["median_us"].as_f64().unwrap_or(f64::NAN) * 1e3;
                        best = Some(best.map_or(ns, |b: f64| b.min(ns)));
                        cells.push(format!("{ns:.1} ns"));
                        specs.push(format!("{p}: `{}`", v["spec"].as_str().unwrap_or("?")));
                    }
                    Some(v) => cells.push(format!("n/a ({})", v["error"].as_str().unwrap_or("?"))),
                    None => cells.push("did not run".to_owned()),
                }
            }
            let ratio = best.map_or("-".to_owned(), |b| format!("{:.1}×", b / ours));
            writeln!(
                out,
                "| {name} | {pattern} | {ours:.1} ns | {} | {} | {ratio} | {} |",
                cells[0],
                cells[1],
                specs.join("; ")
            )
            .unwrap();
            out.flush().unwrap();
        }
    }
}
