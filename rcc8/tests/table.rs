//! The composition table stated in the code against an independent published one: GQR's
//! `rcc8.comp` and `rcc8.conv` (tests/data, GPL-2.0-or-later, see tests/data/SOURCE.md).
#![expect(clippy::unwrap_used, reason = "tests")]

use dyknow_rcc8::Relation;

fn set(names: &str) -> Relation {
    names
        .trim()
        .trim_start_matches('(')
        .trim_end_matches(')')
        .split_whitespace()
        .map(|n| Relation::from_name(n).unwrap())
        .fold(Relation::EMPTY, Relation::or)
}

#[test]
fn base_composition_equals_gqr() {
    let text = include_str!("data/rcc8.comp");
    let mut seen = 0;
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let (pair, result) = line.split_once("::").unwrap();
        let (a, b) = pair.split_once(':').unwrap();
        let (a, b) = (set(a), set(b));
        assert!(a.is_base() && b.is_base(), "{line}");
        assert_eq!(a.compose(b), set(result), "{line}");
        seen += 1;
    }
    assert_eq!(seen, 64);
}

#[test]
fn converse_equals_gqr() {
    let text = include_str!("data/rcc8.conv");
    let mut seen = 0;
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let (a, b) = line.split_once("::").unwrap();
        assert_eq!(set(a).converse(), set(b), "{line}");
        seen += 1;
    }
    assert_eq!(seen, 8);
}

/// The precomputed tables for all 256 × 256 sets are the unions over their base relations,
/// and composition commutes with converse as the algebra requires: (R ∘ S)⁻¹ = S⁻¹ ∘ R⁻¹.
#[test]
fn full_tables_agree_with_the_base_table() {
    for a in 0..=255u8 {
        let ra = Relation(a);
        assert_eq!(ra.converse().converse(), ra);
        for b in 0..=255u8 {
            let rb = Relation(b);
            let expected = ra
                .bases()
                .flat_map(|x| rb.bases().map(move |y| x.compose(y)))
                .fold(Relation::EMPTY, Relation::or);
            assert_eq!(ra.compose(rb), expected);
            assert_eq!(
                ra.compose(rb).converse(),
                rb.converse().compose(ra.converse())
            );
        }
    }
}

#[test]
fn names_and_display() {
    for (i, name) in Relation::NAMES.iter().enumerate() {
        assert_eq!(Relation::from_name(name), Some(Relation::BASE[i]));
    }
    assert_eq!(Relation::from_name("NTTP"), Some(Relation::NTPP));
    assert_eq!(Relation::from_name("TPPi"), Some(Relation::TPPI));
    assert_eq!(Relation::from_name("NTPP^-1"), Some(Relation::NTPPI));
    assert_eq!(Relation::from_name("XX"), None);
    assert_eq!(Relation::DC.or(Relation::NTPPI).to_string(), "( DC NTPPI )");
    assert_eq!(
        Relation::UNIVERSAL.to_string(),
        "( DC EC PO EQ TPP NTPP TPPI NTPPI )"
    );
}
