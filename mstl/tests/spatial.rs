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
    let truth = truths(
        &[
            "next^2 EQ(prev^2 a, a)",
            "next^2 NTPP(a, b)",
            "next^2 DC(prev^2 x, x)",
            "next^2 EQ(prev^2 x, x)",
            "next^2 DC(prev x, x)",
        ],
        trace,
    );
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

/// A state that gives a spatial atom directly as a key (`"PO(a,b)": true`) says the same of
/// its converse: `PO(b,a)`, and `TPPI(b,a)` for `TPP(a,b)`.
#[test]
fn a_spatial_key_answers_for_the_converse_atom_too() {
    let trace =
        "{\"t\": 0, \"state\": {\"PO(a,b)\": true, \"TPP(c,d)\": true, \"DC(e,f)\": false}}\n";
    let truth = truths(
        &[
            "PO(a, b)",
            "PO(b, a)",
            "TPPI(d, c)",
            "TPP^-1(d, c)",
            "TPP(d, c)",
            "DC(f, e)",
            "EC(b, a)",
        ],
        trace,
    );
    use Truth::{False, True, Unknown};
    // TPP(d, c) is not the converse of TPP(c, d): the key says nothing of it.
    assert_eq!(truth, [True, True, True, True, Unknown, False, Unknown]);
}

/// Bad traces and domains are refused with where and why: bytes that are not UTF-8 name their
/// line and column, a domain constant that would make state keys ambiguous is refused, and so
/// is a formula whose quantifiers expand it past `MAX_GROUND_ATOMS` (before any is expanded:
/// this one would be 10⁸ atoms).
#[test]
fn bad_input_is_refused_with_where_and_why() {
    use dyknow_mstl::trace::CheckError;
    use dyknow_mstl::{CompileError, MAX_GROUND_ATOMS};
    let p = [parse("p").unwrap()];
    let trace = b"{\"t\": 0}\n{\"t\": 1, \"state\": {\"p\xff\": true}}\n";
    match check(&p, &trace[..], Header::default(), &mut Vec::new()) {
        Err(CheckError::Trace {
            line,
            column,
            message,
        }) => {
            assert_eq!((line, column), (2, Some(22)), "{message}");
            assert!(message.contains("UTF-8"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    let domain = |constants: &[&str]| Header {
        domains: [(
            "D".to_owned(),
            constants.iter().map(|c| (*c).to_owned()).collect(),
        )]
        .into(),
        ..Header::default()
    };
    let unary = [parse("forall x in D: P(x)").unwrap()];
    for bad in ["a,b", "a b", "f(a)", ""] {
        match check(
            &unary,
            &b"{\"t\": 0}\n"[..],
            domain(&[bad]),
            &mut Vec::new(),
        ) {
            Err(CheckError::Compile {
                formula: 0,
                source: CompileError::BadConstant(c),
            }) => assert_eq!(c, bad),
            other => panic!("{bad:?}: {other:?}"),
        }
    }
    // Names a formula cannot write are still constants: keys stay unambiguous.
    for good in ["uav-1", "next", "é"] {
        check(
            &unary,
            &b"{\"t\": 0}\n"[..],
            domain(&[good]),
            &mut Vec::new(),
        )
        .unwrap();
    }
    let ten: Vec<String> = (0..10).map(|i| format!("a{i}")).collect();
    let ten: Vec<&str> = ten.iter().map(String::as_str).collect();
    let huge = [parse(
        "forall a in D: forall b in D: forall c in D: forall d in D: forall e in D: \
         forall f in D: forall g in D: forall h in D: P(a, b, c, d, e, f, g, h)",
    )
    .unwrap()];
    match check(&huge, &b"{\"t\": 0}\n"[..], domain(&ten), &mut Vec::new()) {
        Err(CheckError::Compile {
            source: CompileError::TooLarge(instances),
            ..
        }) => assert_eq!(instances, 111_111_111, "10⁸ atoms, 10⁷ … 1 bodies"),
        other => panic!("{other:?}"),
    }
    // Quantifiers whose variables the body does not use do not multiply: 10 instances of
    // P(x), however deep the others nest.
    let idle = [parse(
        "forall a in D: forall b in D: forall c in D: forall d in D: forall e in D: \
         forall f in D: forall g in D: forall x in D: P(x)",
    )
    .unwrap()];
    let ten = domain(&ten);
    assert_eq!(
        dyknow_mstl::ground_atoms(&idle[0], &ten.domains),
        100_000_000
    );
    assert_eq!(dyknow_mstl::ground_instances(&idle[0], &ten.domains), 18);
    check(&idle, &b"{\"t\": 0}\n"[..], ten, &mut Vec::new()).unwrap();
    assert_eq!(MAX_GROUND_ATOMS, 1_000_000);
}

/// Each formula's verdict over `trace` (a `dyknow check` trace), in the formulas' order.
#[expect(
    clippy::unwrap_used,
    reason = "test helper: a formula or trace that fails is a failed test"
)]
fn truths(formulas: &[&str], trace: &str) -> Vec<Truth> {
    let formulas: Vec<_> = formulas.iter().map(|f| parse(f).unwrap()).collect();
    let mut out = Vec::new();
    let verdicts = check(&formulas, trace.as_bytes(), Header::default(), &mut out).unwrap();
    (0..formulas.len())
        .map(|i| verdicts.iter().find(|v| v.formula == i).unwrap().truth)
        .collect()
}
