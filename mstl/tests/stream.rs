//! The state-stream core through its public API (issue 12, item 4): states built without
//! JSON, one at a time; typed errors naming regions, landmarks and timestamps; static
//! relations carried (Ch. 3.4.2); atoms over `prev` regions through landmarks (Ch. 3.3.3,
//! Defs. 13–15); unknown values; and, as a property, that a refused state leaves no trace.
#![expect(
    clippy::unwrap_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use dyknow_mstl::{
    Monitor, Region, SpatialConstraints, State, StateStream, StreamError, Truth, Valuation, Value,
    Verdict, parse,
};
use dyknow_rcc8::Relation;
use dyknow_rcc8::generate::{Disc, Rng, relation};
use proptest::prelude::*;

fn region(name: &str, offset: i32) -> Region {
    Region {
        offset,
        name: name.to_owned(),
    }
}

fn now(name: &str) -> Region {
    region(name, 0)
}

fn monitor(formulas: &[&str]) -> Monitor {
    let mut m = Monitor::new();
    for f in formulas {
        m.add(&parse(f).unwrap()).unwrap();
    }
    m
}

/// Runs `states` through a monitor of `formulas` and returns every verdict, the final
/// unknowns included.
fn run(stream: &mut StateStream, m: &mut Monitor, states: Vec<State>) -> Vec<Verdict> {
    let mut all = Vec::new();
    for s in states {
        all.extend_from_slice(stream.step(m, s).unwrap());
    }
    all.extend(m.finish());
    all
}

fn truths(verdicts: &[Verdict]) -> Vec<(usize, Truth, u64)> {
    let mut v: Vec<_> = verdicts.iter().map(|v| (v.formula, v.truth, v.t)).collect();
    v.sort_unstable();
    v
}

/// The seed's (3.26): `PO(r1, r2)` then `DC(r1, r2)` cannot both hold with both rigid. The
/// second state is refused with the landmarks and both states, and nothing changes.
#[test]
fn a_landmark_conflict_is_a_typed_error_naming_the_landmarks() {
    let mut stream = StateStream::new(["r2", "r1", "r2"], [""; 0], 0);
    assert_eq!(stream.landmarks(), ["r1", "r2"]);
    assert_eq!(
        stream.keep(),
        2,
        "the previous state, to check the landmarks"
    );
    stream
        .push(
            State::new(0)
                .with_relation("r1", "r2", Relation::PO)
                .unwrap(),
        )
        .unwrap();
    let refused = stream.push(
        State::new(100)
            .with_relation("r2", "r1", Relation::DC)
            .unwrap(),
    );
    assert_eq!(
        refused,
        Err(StreamError::LandmarkConflict {
            landmarks: vec!["r1".into(), "r2".into()],
            earlier_t: 0,
            later_t: 100,
            earlier_state: 0,
            later_state: 1,
        })
    );
    assert_eq!((stream.states(), stream.t()), (1, Some(0)));
    // The stream goes on from where it was.
    stream
        .push(
            State::new(100)
                .with_relation("r1", "r2", Relation::PO)
                .unwrap(),
        )
        .unwrap();
    assert_eq!(
        stream.relation(&region("r1", -1), &now("r1")).unwrap(),
        Some(Relation::EQ)
    );
}

/// A conflict only closure finds: the house inside the garden, the garden touching the lake,
/// so the house is disconnected from the lake; then the house is inside the lake.
#[test]
fn a_conflict_closure_finds_names_a_minimal_set() {
    let mut stream = StateStream::new(["house", "lake"], [""; 0], 0);
    stream
        .push(
            State::new(0)
                .with_relation("house", "garden", Relation::NTPP)
                .unwrap()
                .with_relation("garden", "lake", Relation::EC)
                .unwrap(),
        )
        .unwrap();
    let e = stream
        .push(
            State::new(100)
                .with_relation("house", "lake", Relation::NTPP)
                .unwrap(),
        )
        .unwrap_err();
    assert!(
        matches!(&e, StreamError::LandmarkConflict { landmarks, .. } if landmarks == &["house", "lake"]),
        "{e:?}"
    );
    assert_eq!(
        e.to_string(),
        "the landmarks house, lake cannot all be rigid between t=0 and t=100: the observations \
         contradict it (seed (3.26)); declare fewer landmarks"
    );
}

/// The seed's Example 7 (busy student) with the static/dynamic split of Ch. 3.4.2: what was
/// observed or inferred between static regions holds in later states that say nothing of
/// them; between a static and a moving region it does not.
#[test]
fn static_relations_carry_over_to_later_states() {
    let mut stream = StateStream::new([""; 0], ["office", "canteen", "desk"], 0);
    assert_eq!(stream.static_regions(), ["canteen", "desk", "office"]);
    stream
        .push(
            State::new(0)
                .with_relation("student", "office", Relation::NTPP)
                .unwrap()
                .with_relation("canteen", "office", Relation::DC)
                .unwrap()
                .with_relation("desk", "office", Relation::NTPP)
                .unwrap(),
        )
        .unwrap();
    // Inferred, not observed.
    assert_eq!(
        stream.relation(&now("student"), &now("canteen")).unwrap(),
        Some(Relation::DC)
    );
    stream.push(State::new(60_000)).unwrap();
    assert_eq!(
        stream.relation(&now("office"), &now("canteen")).unwrap(),
        Some(Relation::DC)
    );
    assert_eq!(
        stream.relation(&now("desk"), &now("canteen")).unwrap(),
        Some(Relation::DC),
        "inferred between static regions at t=0, still known"
    );
    assert_eq!(
        stream.relation(&now("student"), &now("office")).unwrap(),
        None
    );
    // A later observation that contradicts what was inferred is refused, naming the pair.
    let e = stream
        .push(
            State::new(70_000)
                .with_relation("desk", "canteen", Relation::PO)
                .unwrap(),
        )
        .unwrap_err();
    assert_eq!(
        e,
        StreamError::StaticConflict {
            x: "canteen".into(),
            y: "desk".into()
        }
    );
}

/// Atoms over `prev` regions (Theorems 4–5) through the extended matrix of two states with
/// the landmarks rigid (Defs. 13–15): the garden touched the lake and now does not, so it
/// moved; the landmarks' relation carries forward. Without landmarks nothing is known across
/// time ((3.29)).
#[test]
fn prev_atoms_relate_states_through_landmarks() {
    let states = || {
        vec![
            State::new(0)
                .with_relation("house", "garden", Relation::NTPP)
                .unwrap()
                .with_relation("garden", "lake", Relation::EC)
                .unwrap(),
            State::new(100)
                .with_relation("garden", "lake", Relation::DC)
                .unwrap(),
        ]
    };
    let formulas = [
        "next DC(house, lake)",
        "next EQ(prev garden, garden)",
        "next EQ(house, prev house)",
        "next DC(house, garden)",
    ];
    let mut m = monitor(&formulas);
    assert_eq!(m.history(), 1);
    let mut stream = StateStream::new(["house", "lake"], [""; 0], m.history());
    let verdicts = run(&mut stream, &mut m, states());
    assert_eq!(
        truths(&verdicts),
        [
            (0, Truth::True, 100),
            (1, Truth::False, 100),
            (2, Truth::True, 100),
            (3, Truth::Unknown, 100)
        ]
    );
    assert!(
        !stream
            .relation(&region("garden", -1), &now("garden"))
            .unwrap()
            .unwrap()
            .contains(Relation::EQ)
    );
    // Looking ahead, or further back than the states taken, knows nothing.
    assert_eq!(
        stream.relation(&region("house", 1), &now("house")).unwrap(),
        None
    );
    assert_eq!(
        stream
            .relation(&region("house", -5), &now("house"))
            .unwrap(),
        None
    );
    // No frame of reference.
    let mut m = monitor(&formulas);
    let mut stream = StateStream::new([""; 0], [""; 0], m.history());
    let verdicts = run(&mut stream, &mut m, states());
    assert_eq!(
        truths(&verdicts),
        [
            (0, Truth::Unknown, 100),
            (1, Truth::Unknown, 100),
            (2, Truth::Unknown, 100),
            (3, Truth::Unknown, 100)
        ]
    );
    assert_eq!(stream.take_conflict(), None);
}

/// A key the state does not give is unknown (Kleene), never the previous state's value; a
/// spatial atom the reasoning leaves open falls back to the state's value for its key.
#[test]
fn absent_values_are_unknown() {
    let mut m = monitor(&["always[0,100] p", "eventually[0,100] !p", "PO(a,b)"]);
    let mut stream = StateStream::default();
    assert_eq!(stream.value("p"), None, "before the first state");
    let first = State::new(0)
        .with_value("p", true)
        .with_value("PO(a,b)", true)
        .with_value("name", "uav1");
    assert!(stream.step(&mut m, first).unwrap()[0].truth == Truth::True);
    assert_eq!(stream.value("p"), Some(Value::Bool(true)));
    assert_eq!(stream.value("name"), Some(Value::Text("uav1")));
    assert!(stream.step(&mut m, State::new(100)).unwrap().is_empty());
    assert_eq!(stream.value("p"), None);
    assert_eq!(
        truths(&m.finish()),
        [(0, Truth::Unknown, 100), (1, Truth::Unknown, 100)]
    );
}

/// A name without arguments that is no constant (of a domain, or of a set a formula
/// quantifies over) is a symbol: a formula group gives it a stream, and a state without its
/// value leaves a comparison with it unknown, not decided as if the name were its value (a
/// user audit: `always (mode = "auto")` was false, and `eventually (mode != "auto")` true, at
/// the first state, with no sample of `mode`). Constants still denote themselves.
#[test]
fn a_symbol_without_a_value_is_unknown_and_a_constant_denotes_itself() {
    let formulas = [
        r#"mode = "auto""#,
        r#"mode != "auto""#,
        "s = s",
        "s = t",
        "exists c in {a, b}: c = b",
        "forall c in {a, b}: c = a",
        "uav1 = uav2",
        "a = b",
    ];
    let domains = [("UAV".to_owned(), vec!["uav1".to_owned(), "uav2".to_owned()])].into();
    let mut m = Monitor::with_domains(domains);
    for f in formulas {
        m.add(&parse(f).unwrap()).unwrap();
    }
    let mut stream = StateStream::default();
    let decided = truths(stream.step(&mut m, State::new(0)).unwrap());
    assert_eq!(
        decided,
        [
            (4, Truth::True, 0),
            (5, Truth::False, 0),
            (6, Truth::False, 0),
            // `a` and `b` are constants of the sets of formulas 4 and 5.
            (7, Truth::False, 0),
        ]
    );
    let given = State::new(100)
        .with_value("mode", "auto")
        .with_value("s", 1.0)
        .with_value("t", 1.0);
    let mut m2 = monitor(&formulas[..4]);
    let decided = truths(stream.step(&mut m2, given).unwrap());
    assert_eq!(
        decided,
        [
            (0, Truth::True, 100),
            (1, Truth::False, 100),
            (2, Truth::True, 100),
            (3, Truth::True, 100),
        ]
    );
    assert_eq!(
        truths(&m.finish()),
        [
            (0, Truth::Unknown, 0),
            (1, Truth::Unknown, 0),
            (2, Truth::Unknown, 0),
            (3, Truth::Unknown, 0),
        ]
    );
}

/// Constraints are converted and intersected per pair as they are added; what allows nothing
/// is refused at once, with the regions.
#[test]
fn constraints_are_normalised_and_checked_as_they_are_added() {
    let mut c = SpatialConstraints::new();
    c.add("office", "student", Relation::NTPPI.or(Relation::TPPI))
        .unwrap();
    c.add("student", "office", Relation::NTPP.or(Relation::PO))
        .unwrap();
    assert_eq!(c.get("student", "office"), Some(Relation::NTPP));
    assert_eq!(c.get("office", "student"), Some(Relation::NTPPI));
    assert_eq!(c.len(), 1);
    assert_eq!(
        c.iter().collect::<Vec<_>>(),
        [("office", "student", Relation::NTPPI)]
    );
    assert_eq!(
        c.add("student", "office", Relation::DC),
        Err(StreamError::Contradictory {
            x: "office".into(),
            y: "student".into()
        })
    );
    assert_eq!(
        c.get("student", "office"),
        Some(Relation::NTPP),
        "unchanged"
    );
    assert!(matches!(
        c.add("a", "b", Relation::EMPTY),
        Err(StreamError::NoRelation { .. })
    ));
    assert_eq!(
        c.add("a", "a", Relation::DC),
        Err(StreamError::NoRelation {
            x: "a".into(),
            y: "a".into(),
            relation: Relation::DC
        })
    );
    c.add("a", "a", Relation::EQ.or(Relation::DC)).unwrap();
}

/// Refused states: timestamps that do not increase, constraints whose closure is
/// inconsistent (naming the pair). The stream is as before and goes on.
#[test]
fn refused_states_change_nothing() {
    let mut m = monitor(&["always[0,1000] PO(a,b)"]);
    let mut stream = StateStream::new([""; 0], ["a", "b"], m.history());
    let po = |t| State::new(t).with_relation("a", "b", Relation::PO).unwrap();
    assert!(stream.step(&mut m, po(10)).unwrap().is_empty());
    assert_eq!(
        stream.step(&mut m, po(10)).unwrap_err(),
        StreamError::NotIncreasing {
            previous: 10,
            t: 10
        }
    );
    let cycle = State::new(20)
        .with_relation("a", "c", Relation::NTPP)
        .unwrap()
        .with_relation("c", "d", Relation::NTPP)
        .unwrap()
        .with_relation("d", "a", Relation::NTPP)
        .unwrap();
    assert!(matches!(
        stream.step(&mut m, cycle).unwrap_err(),
        StreamError::Inconsistent { .. }
    ));
    assert_eq!(
        stream
            .step(
                &mut m,
                State::new(30)
                    .with_relation("a", "b", Relation::DC)
                    .unwrap()
            )
            .unwrap_err(),
        StreamError::StaticConflict {
            x: "a".into(),
            y: "b".into()
        }
    );
    assert_eq!((stream.states(), stream.t()), (1, Some(10)));
    let verdicts = stream.step(&mut m, State::new(2000)).unwrap();
    assert_eq!(
        truths(verdicts),
        [(0, Truth::True, 2000)],
        "PO(a, b) still holds between static regions"
    );
}

/// How many states are kept: the current one, `history` before it, and the previous one when
/// there are landmarks; a formula added later that looks further back grows it.
#[test]
fn the_history_kept_follows_the_monitor() {
    assert_eq!(StateStream::default().keep(), 1);
    assert_eq!(StateStream::new([""; 0], [""; 0], 3).keep(), 4);
    assert_eq!(StateStream::new(["l"], [""; 0], 0).keep(), 2);
    let mut m = Monitor::new();
    let mut stream = StateStream::new(["l"], [""; 0], m.history());
    let s = |t| {
        State::new(t)
            .with_relation("x", "l", Relation::NTPP)
            .unwrap()
    };
    stream.step(&mut m, s(0)).unwrap();
    m.add(&parse("next^3 NTPP(prev^3 x, l)").unwrap()).unwrap();
    // Evaluated from t=1 on: at t=4 it relates x at t=1 to l at t=4, three states back.
    let mut verdicts = Vec::new();
    for t in 1..=4 {
        verdicts.extend_from_slice(stream.step(&mut m, s(t)).unwrap());
    }
    assert_eq!(stream.keep(), 4);
    assert_eq!(truths(&verdicts), [(0, Truth::True, 4)]);
}

#[derive(Debug, Clone)]
struct Case {
    landmarks: Vec<String>,
    statics: Vec<String>,
    states: Vec<State>,
    formulas: Vec<String>,
}

fn name(i: u64) -> String {
    format!("g{i}")
}

/// Random streams over discs in the plane, observed truly or at random (so that some states
/// contradict the landmarks, the static regions or themselves), with timestamps that now and
/// then do not increase.
fn case() -> impl Strategy<Value = Case> {
    (any::<u64>(), 1usize..=6).prop_map(|(seed, n)| {
        let mut rng = Rng(seed);
        let landmarks = (0..4).filter(|_| rng.chance(0.4)).map(name).collect();
        let statics = (0..4).filter(|_| rng.chance(0.6)).map(name).collect();
        let mut discs: Vec<Disc> = (0..4).map(|_| Disc::random(&mut rng, 12, 5)).collect();
        let mut t = 0;
        let mut states = Vec::new();
        for _ in 0..n {
            for d in &mut discs {
                if rng.chance(0.3) {
                    *d = Disc::random(&mut rng, 12, 5);
                }
            }
            t = if rng.chance(0.1) {
                t
            } else {
                t + 1 + rng.below(100)
            };
            let mut s = State::new(t);
            if rng.chance(0.7) {
                s = s.with_value("p", rng.chance(0.5));
            }
            for _ in 0..rng.below(5) {
                let (i, j) = (rng.below(4), rng.below(4));
                let truth = discs[i as usize].relation(discs[j as usize]);
                let r = if rng.chance(0.8) {
                    truth.or(relation(&mut rng, 1.0))
                } else {
                    relation(&mut rng, 1.5)
                };
                // A constraint the state's others contradict is left out.
                let _ = s.spatial.add(name(i), name(j), r);
            }
            states.push(s);
        }
        let offset = |rng: &mut Rng| match rng.below(3) {
            0 => "prev ",
            1 => "prev^2 ",
            _ => "",
        };
        let formulas = (0..10)
            .map(|_| {
                let atom = format!(
                    "{}({}{}, {}{})",
                    Relation::NAMES[rng.below(8) as usize],
                    offset(&mut rng),
                    name(rng.below(4)),
                    offset(&mut rng),
                    name(rng.below(4))
                );
                match rng.below(4) {
                    0 => format!("always[0,150] ({atom} || p)"),
                    1 => format!("eventually[0,150] {atom}"),
                    2 => format!("next^2 {atom}"),
                    _ => format!("p U[0,200] {atom}"),
                }
            })
            .collect();
        Case {
            landmarks,
            statics,
            states,
            formulas,
        }
    })
}

/// What a stream makes of each state of a sequence: whether it took the state, and the
/// verdicts or the error.
type Outcome = Vec<(bool, Result<Vec<Verdict>, StreamError>)>;

fn outcome(c: &Case, states: &[State]) -> Outcome {
    let formulas: Vec<&str> = c.formulas.iter().map(String::as_str).collect();
    let mut m = monitor(&formulas);
    let mut stream = StateStream::new(&c.landmarks, &c.statics, m.history());
    states
        .iter()
        .map(|s| {
            let before = stream.states();
            let r = stream.step(&mut m, s.clone()).map(<[Verdict]>::to_vec);
            (stream.states() > before, r)
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|n| n.parse().ok()).unwrap_or(500),
        ..ProptestConfig::default()
    })]

    /// A refused state leaves no trace: a stream that was offered states it refused gives the
    /// same verdicts as one that only ever saw the states it took (a live synchroniser may
    /// drop a bad state and go on).
    #[test]
    fn a_refused_state_leaves_no_trace(c in case()) {
        let offered = outcome(&c, &c.states);
        let taken: Vec<State> = c
            .states
            .iter()
            .zip(&offered)
            .filter(|(_, (took, _))| *took)
            .map(|(s, _)| s.clone())
            .collect();
        let expected: Outcome = offered.into_iter().filter(|(took, _)| *took).collect();
        prop_assert_eq!(outcome(&c, &taken), expected);
    }
}
