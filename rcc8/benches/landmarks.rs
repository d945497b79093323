//! The landmark experiment (issue 6; seed Ch. 3.5.2, Figures 3.8–3.9, as tables):
//! `cargo bench -p dyknow-rcc8 --bench landmarks` (`./dev bench rcc8` runs it too).
//!
//! For |R| = 20..200 regions and landmark ratios m/n = 0..0.9 (n + m = |R|):
//! - a *seed* is m landmark regions with their relations fully known (a scenario);
//! - a *CSP* for one time-point adds n regions; every relation but those between landmarks
//!   is a label of expected size l = 4 holding the true one (so every CSP is consistent);
//! - two CSPs of the same seed are two time-points: their extended matrix (Def. 13) with the
//!   landmarks rigid is closed, and the intertemporal relations between non-landmark regions
//!   are measured: the mean disjunction size of those not fully unknown (Figure 3.8) and the
//!   share fully unknown (Figure 3.9).
//!
//! Regions are discs in the plane (so every seed and CSP is consistent by construction; the
//! seed used GQR to find consistent scenarios). The seed used 30 seeds × 20 CSPs (5,700 pairs)
//! per point; here `SEEDS` × `CSPS` (default 3 × 5: 30 pairs per point; `BENCH_QUICK=1`:
//! 1 × 3). Also reported: the mean time to close one extended matrix from its links.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::io::Write;
use std::time::Instant;

use dyknow_rcc8::generate::{Disc, Rng};
use dyknow_rcc8::{Extended, Network, Relation};

/// The observations of one time-point: landmark pairs exact, every other pair its true
/// relation widened to an expected label size of 4.
fn csp(rng: &mut Rng, discs: &[Disc], m: usize) -> Network {
    let mut net = Network::new(discs.len());
    for i in 0..discs.len() {
        for j in i + 1..discs.len() {
            let truth = discs[i].relation(discs[j]);
            let r = if j < m {
                truth
            } else {
                // Each of the 7 other base relations with probability 3/7: 1 + 3 = 4 expected.
                truth.or(widen(rng))
            };
            net.set(i, j, r);
        }
    }
    net
}

fn widen(rng: &mut Rng) -> Relation {
    let mut r = 0u8;
    for b in 0..8 {
        if rng.chance(3.0 / 7.0) {
            r |= 1 << b;
        }
    }
    Relation(r)
}

fn env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok();
    let seeds = env("SEEDS", if quick { 1 } else { 3 });
    let csps = env("CSPS", if quick { 3 } else { 5 });
    let sizes: Vec<usize> = (1..=10).map(|k| 20 * k).collect();
    let ratios: Vec<f64> = (0..=9).map(|k| f64::from(k) / 10.0).collect();
    let mut rng = Rng(0x1a2d_3a4c);
    // (size, ratio) -> (mean size of the known, share unknown, mean closure µs)
    let mut results = Vec::new();
    for &total in &sizes {
        for &ratio in &ratios {
            // n + m = total, m / n = ratio.
            let m = ((total as f64) * ratio / (1.0 + ratio)).round() as usize;
            let n = total - m;
            let (mut known_sum, mut known, mut unknown, mut time, mut instances) =
                (0u64, 0u64, 0u64, 0.0, 0usize);
            let landmarks: Vec<usize> = (0..m).collect();
            for _ in 0..seeds {
                let seed: Vec<Disc> = (0..m).map(|_| Disc::random(&mut rng, 40, 12)).collect();
                let points: Vec<Network> = (0..csps)
                    .map(|_| {
                        let mut discs = seed.clone();
                        discs.extend((0..n).map(|_| Disc::random(&mut rng, 40, 12)));
                        let mut net = csp(&mut rng, &discs, m);
                        net.algebraic_closure().unwrap();
                        net
                    })
                    .collect();
                for a in 0..csps {
                    for b in a + 1..csps {
                        let start = Instant::now();
                        let e = Extended::of_closed(&points[a], &points[b], &landmarks).unwrap();
                        time += start.elapsed().as_secs_f64();
                        instances += 1;
                        for x in m..total {
                            for y in m..total {
                                let r = e.across(x, y);
                                if r == Relation::UNIVERSAL {
                                    unknown += 1;
                                } else {
                                    known += 1;
                                    known_sum += u64::from(r.len());
                                }
                            }
                        }
                    }
                }
            }
            let all = known + unknown;
            results.push((
                total,
                ratio,
                (known > 0).then(|| known_sum as f64 / known as f64),
                unknown as f64 / all.max(1) as f64,
                time / instances.max(1) as f64 * 1e6,
            ));
            eprint!(".");
        }
    }
    eprintln!();
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "# Landmarks: intertemporal relations between non-landmark regions ({seeds} seeds × {} pairs of CSPs per point)\n",
        csps * (csps - 1) / 2
    )
    .unwrap();
    let header = |out: &mut std::io::StdoutLock<'_>, title: &str| {
        writeln!(out, "## {title}\n").unwrap();
        write!(out, "| regions |").unwrap();
        for r in &ratios {
            write!(out, " {r:.1} |").unwrap();
        }
        write!(out, "\n| --- |").unwrap();
        for _ in &ratios {
            write!(out, " --- |").unwrap();
        }
        writeln!(out).unwrap();
    };
    for (title, column) in [
        (
            "Mean disjunction size of those not fully unknown (Figure 3.8), by landmark ratio m/n",
            0,
        ),
        ("Share fully unknown (Figure 3.9), by landmark ratio m/n", 1),
        ("Mean time to close one extended matrix from its links", 2),
    ] {
        header(&mut out, title);
        for &total in &sizes {
            write!(out, "| {total} |").unwrap();
            for (_, _, size, share, micros) in results.iter().filter(|r| r.0 == total) {
                match column {
                    0 => match size {
                        Some(s) => write!(out, " {s:.2} |").unwrap(),
                        None => write!(out, " - |").unwrap(),
                    },
                    1 => write!(out, " {:.0} % |", share * 100.0).unwrap(),
                    _ => {
                        if *micros >= 1000.0 {
                            write!(out, " {:.1} ms |", micros / 1000.0).unwrap();
                        } else {
                            write!(out, " {micros:.0} µs |").unwrap();
                        }
                    }
                }
            }
            writeln!(out).unwrap();
        }
        writeln!(out).unwrap();
    }
}
