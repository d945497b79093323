//! Spatial atoms through traces (issue 6, item 6), against regions that exist: discs in the
//! plane that move from state to state while the landmarks stay put. Each state observes the
//! true relations, weakened at random. Every verdict on an atom `R(x, y)` with `next`/`prev`
//! offsets, at any state, must agree with the discs: reasoning may leave an atom unknown, but
//! true must be true and false false. This runs the whole pipeline: parsing, the rewriting of
//! Theorems 4–5, the history of states, the extended matrices and the landmarks.

use dyknow_mstl::trace::{Header, check};
use dyknow_mstl::{Truth, parse};
use dyknow_rcc8::Relation;
use dyknow_rcc8::generate::{Disc, Rng, relation};
use proptest::prelude::*;

#[derive(Debug, Clone)]
struct Case {
    /// `discs[k][i]`: region `i` at state `k`.
    discs: Vec<Vec<Disc>>,
    landmarks: Vec<usize>,
    trace: String,
    /// Atoms: relation, state, offsets of the two regions, the two regions.
    atoms: Vec<(usize, usize, i32, i32, usize, usize)>,
}

fn region(i: usize) -> String {
    format!("g{i}")
}

fn offset(o: i32) -> String {
    match o {
        0 => String::new(),
        o if o > 0 => format!("next^{o} "),
        o => format!("prev^{} ", -o),
    }
}

fn case() -> impl Strategy<Value = Case> {
    (
        2usize..=6,
        2usize..=5,
        any::<u64>(),
        0.0f64..=1.0,
        any::<bool>(),
    )
        .prop_map(|(n, states, seed, share, statics)| {
            let mut rng = Rng(seed);
            let first: Vec<Disc> = (0..n).map(|_| Disc::random(&mut rng, 12, 5)).collect();
            let landmarks: Vec<usize> = (0..n).filter(|_| rng.chance(share)).collect();
            let mut discs = vec![first];
            for _ in 1..states {
                let last = discs.last().cloned().unwrap_or_default();
                let next = last
                    .iter()
                    .enumerate()
                    .map(|(i, d)| {
                        if landmarks.contains(&i) || rng.chance(0.3) {
                            *d
                        } else {
                            Disc::random(&mut rng, 12, 5)
                        }
                    })
                    .collect();
                discs.push(next);
            }
            // Landmarks are also declared static half the time: their relations never change.
            let mut trace = String::new();
            let names: Vec<String> = landmarks
                .iter()
                .map(|&i| format!("\"{}\"", region(i)))
                .collect();
            trace.push_str(&format!("{{\"landmarks\": [{}]", names.join(", ")));
            if statics {
                trace.push_str(&format!(", \"static\": [{}]", names.join(", ")));
            }
            trace.push_str("}\n");
            for (k, state) in discs.iter().enumerate() {
                let mut observed = Vec::new();
                for i in 0..n {
                    for j in i + 1..n {
                        if rng.chance(0.5) {
                            let r = state[i].relation(state[j]).or(relation(&mut rng, 1.0));
                            let names: Vec<String> = (0..8)
                                .filter(|b| r.0 & (1 << b) != 0)
                                .map(|b| format!("\"{}\"", Relation::NAMES[b]))
                                .collect();
                            observed.push(format!(
                                "[\"{}\", \"{}\", [{}]]",
                                region(i),
                                region(j),
                                names.join(", ")
                            ));
                        }
                    }
                }
                trace.push_str(&format!(
                    "{{\"t\": {}, \"spatial\": [{}]}}\n",
                    k * 100,
                    observed.join(", ")
                ));
            }
            let mut atoms = Vec::new();
            for _ in 0..12 {
                let r = rng.below(8) as usize;
                let k = rng.below(states as u64) as i32;
                // Offsets that stay inside the trace.
                let a = rng.below(states as u64) as i32 - k;
                let b = rng.below(states as u64) as i32 - k;
                let (x, y) = (rng.below(n as u64) as usize, rng.below(n as u64) as usize);
                atoms.push((r, k as usize, a, b, x, y));
            }
            Case {
                discs,
                landmarks,
                trace,
                atoms,
            }
        })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|n| n.parse().ok()).unwrap_or(300),
        ..ProptestConfig::default()
    })]

    #[test]
    fn spatial_verdicts_agree_with_moving_regions(c in case()) {
        let formulas: Vec<_> = c
            .atoms
            .iter()
            .map(|&(r, k, a, b, x, y)| {
                let text = format!(
                    "{}{}({}{}, {}{})",
                    if k > 0 { format!("next^{k} ") } else { String::new() },
                    Relation::NAMES[r],
                    offset(a),
                    region(x),
                    offset(b),
                    region(y)
                );
                parse(&text).unwrap()
            })
            .collect();
        let mut out = Vec::new();
        let verdicts = check(&formulas, c.trace.as_bytes(), Header::default(), &mut out);
        prop_assert!(verdicts.is_ok(), "{:?}\n{}", verdicts.err(), c.trace);
        let Ok(verdicts) = verdicts else { unreachable!() };
        for v in verdicts {
            let (r, k, a, b, x, y) = c.atoms[v.formula];
            let ka = (k as i32 + a) as usize;
            let kb = (k as i32 + b) as usize;
            let truth = c.discs[ka][x].relation(c.discs[kb][y]) == Relation::BASE[r];
            match v.truth {
                Truth::True => prop_assert!(truth, "atom {:?} true, discs say false\n{}", c.atoms[v.formula], c.trace),
                Truth::False => prop_assert!(!truth, "atom {:?} false, discs say true\n{}", c.atoms[v.formula], c.trace),
                Truth::Unknown => continue,
            }
            // A landmark is EQ to itself at any two states.
            if x == y && c.landmarks.contains(&x) && r == 3 {
                prop_assert_eq!(v.truth, Truth::True);
            }
        }
    }
}

/// Without landmarks nothing relates two states; with them, a landmark is EQ to itself across
/// any distance and the relations between landmarks observed once are known later.
#[test]
fn landmarks_relate_states_any_distance_apart() {
    let trace = concat!(
        "{\"landmarks\": [\"a\", \"b\"]}\n",
        "{\"t\": 0, \"spatial\": [[\"a\", \"b\", [\"NTPP\"]], [\"x\", \"b\", [\"DC\"]]]}\n",
        "{\"t\": 1}\n",
        "{\"t\": 2, \"spatial\": [[\"x\", \"a\", [\"NTPP\"]]]}\n",
    );
    let formulas: Vec<_> = [
        "next^2 EQ(prev^2 a, a)",
        "next^2 NTPP(a, b)",
        "next^2 DC(prev^2 x, x)",
        "next^2 EQ(prev^2 x, x)",
        "next^2 DC(prev x, x)",
    ]
    .iter()
    .map(|f| parse(f).unwrap())
    .collect();
    let mut out = Vec::new();
    let verdicts = check(&formulas, trace.as_bytes(), Header::default(), &mut out).unwrap();
    let truth: Vec<Truth> = (0..formulas.len())
        .map(|i| verdicts.iter().find(|v| v.formula == i).unwrap().truth)
        .collect();
    // x was outside b and is now inside a, which is inside b: it moved, DC to where it was.
    assert_eq!(
        truth,
        vec![
            Truth::True,
            Truth::True,
            Truth::True,
            Truth::False,
            Truth::Unknown
        ]
    );
}
