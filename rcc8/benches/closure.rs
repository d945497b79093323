//! RCC-8 closure benchmark (issue 6; seed Figures 3.10–3.11 as tables):
//! `cargo bench -p dyknow-rcc8 --bench closure` (`./dev bench rcc8`).
//!
//! Random instances of Renz and Nebel's model A(n, d, l = 4): n variables; each of the
//! n(n-1)/2 pairs is constrained with probability d / (n - 1), so the average degree is d; a
//! constraint holds each base relation with probability l / 8 (an empty draw is drawn again).
//! 1. Mean closure time against d at n = 64 (the phase transition is near d ≈ 9), and at
//!    n = 20, 100, 200, 500 around it.
//! 2. The static/dynamic split of Ch. 3.4.2 at r = 0.25 (a quarter of the variables dynamic):
//!    close the static part once ([`Split`]), then per state copy it, add the dynamic
//!    constraints and re-close from the edges they changed (`Split::state`, the copy timed),
//!    against closing the whole network each state.
//! 3. Side by side with a Python RCC-8 reasoner (`benches/peers/rcc8_peers.py`) on the same
//!    instances when `PEER_PYTHON` is set, and with GQR when `GQR_BIN` is set
//!    (`benches/peers/build_gqr.sh` builds it from a checkout; never committed).
//!
//! 4. Exact consistency (`dyknow rcc8 --exact`): splitting over the tractable subclass `B̂8`
//!    (`consistent_until`) against backtracking to a scenario (`solve_until`, what `--exact`
//!    ran before 2026-11-29), same instances, answers compared where both decide.
//!
//! The landmark experiment (Figures 3.8–3.9) is `benches/landmarks.rs`.
//! `BENCH_QUICK=1`: fewer instances.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::io::Write;
use std::time::Instant;

use dyknow_rcc8::generate::{Rng, discs, model_a as instance, relation, scenario};
use dyknow_rcc8::{Network, Relation, Split, gqr};

/// Mean closure time (µs) and the share of instances found path-consistent.
fn mean_closure(nets: &[Network]) -> (f64, f64) {
    let mut total = 0.0;
    let mut consistent = 0;
    for net in nets {
        let mut net = net.clone();
        let start = Instant::now();
        let ok = net.algebraic_closure().is_ok();
        total += start.elapsed().as_secs_f64();
        consistent += usize::from(ok);
    }
    (
        total / nets.len() as f64 * 1e6,
        consistent as f64 / nets.len() as f64,
    )
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok();
    let mut out = std::io::stdout().lock();
    let mut rng = Rng(0x5eed);
    writeln!(out, "# RCC-8 algebraic closure, model A(n, d, l = 4)\n").unwrap();
    writeln!(
        out,
        "| n | d | instances | mean closure | path-consistent |"
    )
    .unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- |").unwrap();
    let mut sets: Vec<(usize, f64, Vec<Network>)> = Vec::new();
    for (n, ds, count) in [
        (
            64,
            (1..=20).map(f64::from).collect::<Vec<_>>(),
            if quick { 20 } else { 200 },
        ),
        (20, vec![5.0, 9.0, 12.0], if quick { 20 } else { 200 }),
        (100, vec![5.0, 9.0, 12.0], if quick { 10 } else { 100 }),
        (200, vec![5.0, 9.0, 12.0], if quick { 5 } else { 50 }),
        (500, vec![5.0, 9.0, 12.0], if quick { 3 } else { 20 }),
    ] {
        for d in ds {
            let nets: Vec<Network> = (0..count).map(|_| instance(&mut rng, n, d, 4.0)).collect();
            let (mean, share) = mean_closure(&nets);
            writeln!(
                out,
                "| {n} | {d} | {count} | {mean:.1} µs | {:.0} % |",
                share * 100.0
            )
            .unwrap();
            out.flush().unwrap();
            if (n == 64 || n == 500 || n == 20) && d == 9.0 {
                sets.push((n, d, nets));
            }
        }
    }

    // The static/dynamic split at r = 0.25.
    writeln!(
        out,
        "\n## Static/dynamic split, r = 0.25 (d = 9, l = 4; per state)\n"
    )
    .unwrap();
    writeln!(out, "| n | states | whole network closed per state | static part closed once, dynamic re-closed | speed-up |").unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- |").unwrap();
    for n in [64usize, 200, 500] {
        let states = if quick { 5 } else { 50 };
        // A consistent scenario: the RCC-8 relations of random discs on a small integer grid
        // (so tangencies occur); the static part is the first 3n/4 variables.
        let dynamic = n / 4;
        let stat = n - dynamic;
        let base = scenario(&discs(&mut rng, n));
        let weaken = |rng: &mut Rng, r: Relation| r.or(relation(rng, 1.0));
        let mut static_net = Network::new(n);
        let p = 9.0 / (n - 1) as f64;
        for i in 0..stat {
            for j in i + 1..stat {
                if rng.chance(p) {
                    static_net.set(i, j, weaken(&mut rng, base.get(i, j)));
                }
            }
        }
        let static_constraints: Vec<(usize, usize, Relation)> = (0..stat)
            .flat_map(|i| (i + 1..stat).map(move |j| (i, j)))
            .filter(|&(i, j)| static_net.get(i, j) != Relation::UNIVERSAL)
            .map(|(i, j)| (i, j, static_net.get(i, j)))
            .collect();
        let mut split = Split::new(stat);
        split.constrain(&static_constraints).unwrap();
        let mut full_time = 0.0;
        let mut split_time = 0.0;
        for _ in 0..states {
            // This state's dynamic constraints (the same scenario, weakened differently).
            let mut dynamic_constraints = Vec::new();
            for i in 0..n {
                for j in (i + 1).max(stat)..n {
                    if rng.chance(p) {
                        dynamic_constraints.push((i, j, weaken(&mut rng, base.get(i, j))));
                    }
                }
            }
            let mut full = static_net.clone();
            for (i, j, r) in &dynamic_constraints {
                full.constrain(*i, *j, *r);
            }
            let start = Instant::now();
            full.algebraic_closure().unwrap();
            full_time += start.elapsed().as_secs_f64();
            let start = Instant::now();
            let state = split.state(n, &dynamic_constraints).unwrap();
            split_time += start.elapsed().as_secs_f64();
            assert_eq!(state, full, "the split must reach the same closure");
        }
        writeln!(
            out,
            "| {n} | {states} | {:.1} µs | {:.1} µs | {:.1}× |",
            full_time / states as f64 * 1e6,
            split_time / states as f64 * 1e6,
            full_time / split_time
        )
        .unwrap();
        out.flush().unwrap();
    }

    exact_side_by_side(&mut rng, quick, &mut out);
    gqr_side_by_side(&sets, &mut out);

    let Ok(python) = std::env::var("PEER_PYTHON") else {
        writeln!(
            out,
            "\n(PEER_PYTHON not set: peer not run; `./dev bench rcc8` sets it)"
        )
        .unwrap();
        return;
    };
    writeln!(
        out,
        "\n## Side by side with the Python peer (same instances, d = 9)\n"
    )
    .unwrap();
    writeln!(
        out,
        "| n | instances | DyKnow mean | peer mean | peer ÷ DyKnow | same answers |"
    )
    .unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- | --- |").unwrap();
    let script = format!(
        "{}/../benches/peers/rcc8_peers.py",
        env!("CARGO_MANIFEST_DIR")
    );
    let dir = std::env::temp_dir().join(format!("dyknow-rcc8-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (n, _d, nets) in &sets {
        let nets: Vec<Network> = nets
            .iter()
            .take(if *n == 500 { 5 } else { 50 })
            .cloned()
            .collect();
        let (file, ours, answers) = for_peer(&dir, *n, &nets);
        let timeout = std::env::var("PEER_TIMEOUT_S").unwrap_or_else(|_| "600".to_owned());
        let run = std::process::Command::new("timeout")
            .arg(timeout)
            .arg(&python)
            .arg(&script)
            .arg(&file)
            .output()
            .unwrap();
        let line = String::from_utf8_lossy(&run.stdout);
        let peer: Option<serde_json::Value> = line
            .lines()
            .last()
            .and_then(|l| serde_json::from_str(l).ok());
        match peer {
            Some(v) if v.get("mean_us").is_some() => {
                let theirs = v["mean_us"].as_f64().unwrap_or(f64::NAN);
                let same = v["per_instance_consistent"].as_array().map(|a| {
                    a.iter()
                        .map(|b| b.as_bool().unwrap_or(false))
                        .collect::<Vec<_>>()
                        == answers
                });
                writeln!(
                    out,
                    "| {n} | {} | {ours:.1} µs | {theirs:.1} µs ({} {}) | {:.0}× | {} |",
                    nets.len(),
                    v["peer"].as_str().unwrap_or("?"),
                    v["version"].as_str().unwrap_or("?"),
                    theirs / ours,
                    match same {
                        Some(true) => "yes",
                        Some(false) => "NO",
                        None => "?",
                    }
                )
                .unwrap();
            }
            _ => writeln!(
                out,
                "| {n} | {} | {ours:.1} µs | did not run | - | - |",
                nets.len()
            )
            .unwrap(),
        }
        out.flush().unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The instances written in GQR's format for a peer, with our mean closure time (µs) and our
/// answers (path-consistent or not) on them.
fn for_peer(
    dir: &std::path::Path,
    n: usize,
    nets: &[Network],
) -> (std::path::PathBuf, f64, Vec<bool>) {
    let mut text = String::new();
    for net in nets {
        gqr::write(net, &mut text).unwrap();
    }
    let file = dir.join(format!("a-{n}.csp"));
    std::fs::write(&file, text).unwrap();
    let (ours, _) = mean_closure(nets);
    let answers = nets
        .iter()
        .map(|n| n.clone().algebraic_closure().is_ok())
        .collect();
    (file, ours, answers)
}

/// GQR (`gqr pc -C rcc8`) on every instance of each set, in one file: its own
/// "CSPs processing time" (after reading the calculus and the file) against our closure of the
/// same instances, with the answers compared. GQR prints that time in milliseconds, so the
/// sets are large.
fn gqr_side_by_side(sets: &[(usize, f64, Vec<Network>)], out: &mut impl Write) {
    let Ok(gqr) = std::env::var("GQR_BIN") else {
        writeln!(
            out,
            "\n(GQR_BIN not set: GQR not run; see benches/peers/build_gqr.sh)"
        )
        .unwrap();
        return;
    };
    writeln!(out, "\n## Side by side with GQR (same instances, d = 9)\n").unwrap();
    writeln!(
        out,
        "| n | instances | DyKnow mean | GQR mean | GQR ÷ DyKnow | same answers |"
    )
    .unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- | --- |").unwrap();
    let dir = std::env::temp_dir().join(format!("dyknow-gqr-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (n, _d, nets) in sets {
        let (file, ours, answers) = for_peer(&dir, *n, nets);
        let run = std::process::Command::new(&gqr)
            .args(["pc", "-C", "rcc8"])
            .arg(&file)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&run.stdout);
        let theirs: Vec<bool> = text
            .lines()
            .filter_map(|l| l.strip_prefix(": "))
            .map(|v| v.trim() == "1")
            .collect();
        let seconds = text
            .lines()
            .find_map(|l| l.strip_prefix("CSPs processing time: "))
            .and_then(|l| l.split_whitespace().next())
            .and_then(|v| v.parse::<f64>().ok());
        match seconds {
            Some(sec) => {
                let mean = sec / nets.len() as f64 * 1e6;
                writeln!(
                    out,
                    "| {n} | {} | {ours:.1} µs | {mean:.1} µs | {:.2}× | {} |",
                    nets.len(),
                    mean / ours,
                    if theirs == answers { "yes" } else { "NO" }
                )
                .unwrap();
            }
            None => writeln!(
                out,
                "| {n} | {} | {ours:.1} µs | did not run ({}) | - | - |",
                nets.len(),
                String::from_utf8_lossy(&run.stderr)
                    .lines()
                    .next()
                    .unwrap_or("")
            )
            .unwrap(),
        }
        out.flush().unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Exact consistency, `B̂8` splitting against scenario search, on model A(n, d, l = 5) networks
/// (path consistent at these degrees, so the search has to run). Scenario search is cut off at
/// 10 s an instance.
fn exact_side_by_side(rng: &mut Rng, quick: bool, out: &mut impl Write) {
    writeln!(
        out,
        "\n## Exact consistency: splitting over B̂8 against backtracking to a scenario (l = 5)\n"
    )
    .unwrap();
    writeln!(
        out,
        "| n | d | instances | consistent | B̂8 splitting, mean | scenario search, mean (cut off at 10 s) | ratio |"
    )
    .unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- | --- | --- |").unwrap();
    let cap = std::time::Duration::from_secs(10);
    for (n, count) in [(100usize, 5usize), (300, 3), (600, 2)] {
        for d in [9.0, 11.0] {
            let count = if quick { 1 } else { count };
            let (mut ours, mut theirs, mut consistent, mut cut) = (0.0, 0.0, 0, 0);
            for _ in 0..count {
                let net = instance(rng, n, d, 5.0);
                let start = Instant::now();
                let answer = net.clone().consistent_until(None).unwrap();
                ours += start.elapsed().as_secs_f64();
                let start = Instant::now();
                let scenario = net.clone().solve_until(Some(start + cap));
                theirs += start.elapsed().as_secs_f64();
                match scenario {
                    Some(s) => assert_eq!(s, answer, "the two searches must agree"),
                    None => cut += 1,
                }
                consistent += usize::from(answer);
            }
            let (ours, theirs) = (ours / count as f64, theirs / count as f64);
            let over = if cut > 0 {
                format!(" ({cut} cut off: more)")
            } else {
                String::new()
            };
            writeln!(
                out,
                "| {n} | {d} | {count} | {consistent} | {:.1} ms | {:.1} ms{over} | {:.0}× |",
                ours * 1e3,
                theirs * 1e3,
                theirs / ours
            )
            .unwrap();
            out.flush().unwrap();
        }
    }
}
