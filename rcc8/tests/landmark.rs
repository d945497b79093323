//! Intertemporal inference through landmarks (issue 6, item 4; seed Ch. 3.3.3): the seed's
//! (3.26)–(3.31) example, soundness against regions that actually move (discs in the plane),
//! the incremental closure from the links against closing the whole extended matrix, and the
//! minimality of reported landmark conflicts.

use dyknow_rcc8::generate::{Disc, Rng, relation, scenario};
use dyknow_rcc8::{Extended, Network, Relation};
use proptest::prelude::*;

fn two(r: Relation) -> Network {
    let mut n = Network::new(2);
    n.set(0, 1, r);
    n
}

/// (3.26): `PO(r1, r2)` at t, `DC(r1, r2)` at t + 1.
#[test]
fn the_landmark_choice_decides_eq_r_next_r() {
    let (r1, r2) = (0, 1);
    let (t1, t2) = (two(Relation::PO), two(Relation::DC));
    // LM = {r1, r2} is inconsistent: r1 and r2 would be PO and DC at once.
    let e = Extended::new(&t1, &t2, &[r1, r2]).unwrap_err();
    assert_eq!(e.landmarks, vec![r1, r2]);
    // LM = {r1}: EQ(r1, ○r1) holds and EQ(r2, ○r2) does not ((3.27), (3.30)); r2 moved away.
    let m = Extended::new(&t1, &t2, &[r1]).unwrap();
    assert_eq!(m.across(r1, r1), Relation::EQ);
    assert!(!m.across(r2, r2).contains(Relation::EQ));
    assert_eq!(m.across(r2, r2), Relation::PO.compose(Relation::DC));
    // LM = {r2}: the converse ((3.28), (3.31)).
    let m = Extended::new(&t1, &t2, &[r2]).unwrap();
    assert_eq!(m.across(r2, r2), Relation::EQ);
    assert!(!m.across(r1, r1).contains(Relation::EQ));
    // No landmark: nothing is known across time ((3.29)).
    let m = Extended::new(&t1, &t2, &[]).unwrap();
    for i in 0..2 {
        for j in 0..2 {
            assert_eq!(m.across(i, j), Relation::UNIVERSAL);
        }
    }
    // Within each time-point, what was observed stays.
    assert_eq!(
        (m.before(r1, r2), m.after(r1, r2)),
        (Relation::PO, Relation::DC)
    );
}

/// A time-point whose own observations are inconsistent is reported with no landmark to blame.
#[test]
fn an_inconsistent_time_point_blames_no_landmark() {
    let mut bad = Network::new(3);
    bad.set(0, 1, Relation::NTPP);
    bad.set(1, 2, Relation::NTPP);
    bad.set(0, 2, Relation::DC);
    let e = Extended::new(&bad, &Network::new(3), &[0]).unwrap_err();
    assert!(e.landmarks.is_empty());
}

/// Landmarks carry relations between landmarks across time: what one time-point observes
/// about two rigid regions refines the other's.
#[test]
fn landmarks_carry_their_relations() {
    let t1 = two(Relation::NTPP.or(Relation::TPP));
    let t2 = two(Relation::TPP.or(Relation::EQ));
    let m = Extended::new(&t1, &t2, &[0, 1]).unwrap();
    assert_eq!(m.before(0, 1), Relation::TPP);
    assert_eq!(m.after(0, 1), Relation::TPP);
    assert_eq!(m.across(0, 1), Relation::TPP);
}

/// Two time-points of regions that really exist: discs, where the landmarks stay put and the
/// other regions move (or not) at random; each time-point's observations are the true
/// relations, weakened at random.
#[derive(Debug, Clone)]
struct Moving {
    before: Vec<Disc>,
    after: Vec<Disc>,
    landmarks: Vec<usize>,
    seed: u64,
}

fn moving() -> impl Strategy<Value = Moving> {
    (2usize..=9, any::<u64>(), 0.0f64..=1.0, 0.0f64..=1.0).prop_map(|(n, seed, share, stay)| {
        let mut rng = Rng(seed);
        // A small grid, so tangencies and equal regions are common.
        let before: Vec<Disc> = (0..n).map(|_| Disc::random(&mut rng, 12, 5)).collect();
        let mut landmarks = Vec::new();
        let after = before
            .iter()
            .enumerate()
            .map(|(i, d)| {
                if rng.chance(share) {
                    landmarks.push(i);
                    *d
                } else if rng.chance(stay) {
                    *d
                } else {
                    Disc::random(&mut rng, 12, 5)
                }
            })
            .collect();
        Moving {
            before,
            after,
            landmarks,
            seed,
        }
    })
}

/// The observations of one time-point: each true relation kept with probability 0.6, widened
/// by random extra relations, otherwise left universal.
fn observe(rng: &mut Rng, discs: &[Disc]) -> Network {
    let truth = scenario(discs);
    let mut net = Network::new(discs.len());
    for i in 0..discs.len() {
        for j in i + 1..discs.len() {
            if rng.chance(0.6) {
                net.set(i, j, truth.get(i, j).or(relation(rng, 1.0)));
            }
        }
    }
    net
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|n| n.parse().ok()).unwrap_or(400),
        ..ProptestConfig::default()
    })]

    /// Soundness: true landmarks are never reported as a conflict, and every inferred
    /// relation, within and across time, keeps the relation the regions actually have.
    #[test]
    fn inference_through_landmarks_is_sound(m in moving()) {
        let mut rng = Rng(m.seed ^ 0xabcd);
        let t1 = observe(&mut rng, &m.before);
        let t2 = observe(&mut rng, &m.after);
        let e = Extended::new(&t1, &t2, &m.landmarks);
        prop_assert!(e.is_ok(), "rigid landmarks reported as a conflict: {:?}", e);
        let Ok(e) = e else { unreachable!() };
        for (i, a) in m.before.iter().enumerate() {
            for (j, b) in m.after.iter().enumerate() {
                prop_assert!(e.across(i, j).contains(a.relation(*b)), "across({i}, {j})");
                prop_assert!(e.before(i, j).contains(a.relation(m.before[j])));
                prop_assert!(e.after(i, j).contains(m.after[i].relation(*b)));
            }
        }
        for &l in &m.landmarks {
            prop_assert_eq!(e.across(l, l), Relation::EQ);
        }
    }

    /// The closure from the links alone equals closing the whole extended matrix, and a
    /// reported conflict is minimal: it is inconsistent, and dropping any one of its
    /// landmarks is not.
    #[test]
    fn incremental_closure_and_minimal_conflicts(
        n in 2usize..=6,
        seed in any::<u64>(),
        mask in any::<u8>(),
    ) {
        let mut rng = Rng(seed);
        let random = |rng: &mut Rng| {
            let mut net = Network::new(n);
            for i in 0..n {
                for j in i + 1..n {
                    if rng.chance(0.7) {
                        net.set(i, j, relation(rng, 2.5));
                    }
                }
            }
            net
        };
        let (t1, t2) = (random(&mut rng), random(&mut rng));
        let landmarks: Vec<usize> = (0..n).filter(|i| mask & (1 << i) != 0).collect();
        // The whole extended matrix, built and closed from scratch.
        let mut whole = Network::new(2 * n);
        for i in 0..n {
            for j in i + 1..n {
                whole.set(i, j, t1.get(i, j));
                whole.set(n + i, n + j, t2.get(i, j));
            }
        }
        for &l in &landmarks {
            whole.set(l, n + l, Relation::EQ);
        }
        let whole_ok = whole.algebraic_closure().is_ok();
        match Extended::new(&t1, &t2, &landmarks) {
            Ok(e) => {
                prop_assert!(whole_ok);
                prop_assert_eq!(e.network(), &whole);
            }
            Err(conflict) => {
                prop_assert!(!whole_ok);
                let (mut c1, mut c2) = (t1.clone(), t2.clone());
                if c1.algebraic_closure().is_ok() && c2.algebraic_closure().is_ok() {
                    let set = &conflict.landmarks;
                    prop_assert!(!set.is_empty());
                    prop_assert!(set.iter().all(|l| landmarks.contains(l)));
                    prop_assert!(Extended::of_closed(&c1, &c2, set).is_err());
                    for k in 0..set.len() {
                        let mut fewer = set.clone();
                        fewer.remove(k);
                        prop_assert!(Extended::of_closed(&c1, &c2, &fewer).is_ok());
                    }
                } else {
                    prop_assert!(conflict.landmarks.is_empty());
                }
            }
        }
    }
}
