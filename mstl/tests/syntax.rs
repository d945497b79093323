//! The MSTL syntax: the contract's examples, precedence, errors with columns, limits, and a
//! print/parse round-trip property test.

use dyknow_mstl::{
    Atom, Cmp, Domain, Formula, Interval, MAX_DEPTH, MAX_TREE_DEPTH, Rcc8, Region, Term,
    is_keyword, parse,
};
use proptest::prelude::*;

fn p(name: &str) -> Formula {
    Formula::Atom(Atom::Predicate {
        name: name.into(),
        args: vec![],
    })
}

fn b(f: Formula) -> Box<Formula> {
    Box::new(f)
}

#[test]
fn the_contracts_examples_parse_and_round_trip() {
    for text in [
        "inRoom -> always (poorLight -> eventually[0,10s] goodLight)",
        "forall c1 in Car: forall c2 in Car: always ((!(c1 = c2) && DC(c1, c2) && Speeding(c1)) -> eventually PO(c1, c2))",
        "forall x in NAO: always (batteryLevel(x) < 0.1 -> eventually[0,60s] Charging(x))",
        "forall x in UAV: always (altitude(x) > 50)",
        "always[0,1440min] InsideCircle(ball)",
        "always EQ(r1, next r1)",
        "always eventually[0,1000] p",
        "always !p -> eventually[0,1000] always[0,999] p",
    ] {
        let f = parse(text).unwrap();
        assert_eq!(parse(&f.to_string()).unwrap(), f, "{text} printed as {f}");
    }
}

#[test]
fn operators_bind_as_the_grammar_says() {
    // implies is right-associative and binds looser than or/and.
    assert_eq!(
        parse("a -> b -> c").unwrap(),
        Formula::Implies(b(p("a")), b(Formula::Implies(b(p("b")), b(p("c")))))
    );
    assert_eq!(
        parse("a || b && c").unwrap(),
        Formula::Or(b(p("a")), b(Formula::And(b(p("b")), b(p("c")))))
    );
    // Unary operators bind tighter than U; U is right-associative.
    assert_eq!(
        parse("always a U b U c").unwrap(),
        Formula::Until(
            Interval::UNBOUNDED,
            b(Formula::Always(Interval::UNBOUNDED, b(p("a")))),
            b(Formula::Until(Interval::UNBOUNDED, b(p("b")), b(p("c"))))
        )
    );
    // Synonyms.
    assert_eq!(
        parse("G F p").unwrap(),
        parse("always eventually p").unwrap()
    );
    assert_eq!(parse("[] <> p").unwrap(), parse("G F p").unwrap());
    assert_eq!(
        parse("not p and q or r").unwrap(),
        parse("!p && q || r").unwrap()
    );
    assert_eq!(parse("X^3 p").unwrap(), Formula::Next(3, b(p("p"))));
    // A quantifier's body extends as far right as possible.
    assert_eq!(
        parse("exists x in {a, b}: P(x) && Q").unwrap(),
        Formula::Exists(
            "x".into(),
            Domain::Set(vec!["a".into(), "b".into()]),
            b(Formula::And(
                b(Formula::Atom(Atom::Predicate {
                    name: "P".into(),
                    args: vec![Term::Name {
                        name: "x".into(),
                        args: vec![]
                    }]
                })),
                b(p("Q"))
            ))
        )
    );
}

#[test]
fn intervals_units_regions_and_comparisons() {
    let Formula::Always(i, _) = parse("always[1.5s,2min] p").unwrap() else {
        panic!()
    };
    assert_eq!(
        i,
        Interval {
            lo: 1500,
            hi: Some(120_000)
        }
    );
    let Formula::Eventually(i, _) = parse("eventually[2h, inf] p").unwrap() else {
        panic!()
    };
    assert_eq!(
        i,
        Interval {
            lo: 7_200_000,
            hi: None
        }
    );
    assert_eq!(
        parse("NTTP(next^2 prev a, prev b)").unwrap(),
        Formula::Atom(Atom::Spatial {
            relation: Rcc8::Ntpp,
            left: Region {
                offset: 1,
                name: "a".into()
            },
            right: Region {
                offset: -1,
                name: "b".into()
            },
        })
    );
    assert_eq!(
        parse("name(x) != \"a \\\"b\\\"\"").unwrap(),
        Formula::Atom(Atom::Compare {
            left: Term::Name {
                name: "name".into(),
                args: vec![Term::Name {
                    name: "x".into(),
                    args: vec![]
                }]
            },
            op: Cmp::Ne,
            right: Term::Str("a \"b\"".into()),
        })
    );
    assert_eq!(
        parse("t >= -2.5").unwrap(),
        Formula::Atom(Atom::Compare {
            left: Term::Name {
                name: "t".into(),
                args: vec![]
            },
            op: Cmp::Ge,
            right: Term::Number(-2.5),
        })
    );
}

/// `next^0` is no step (the seed writes τ for ○⁰τ), for formulas and regions alike.
#[test]
fn a_zeroth_power_of_next_is_no_step() {
    assert_eq!(parse("X^0 p").unwrap(), p("p"));
    assert_eq!(parse("next^0 (p && q)").unwrap(), parse("p && q").unwrap());
    assert_eq!(
        parse("always X^0 X^2 p").unwrap(),
        parse("always X^2 p").unwrap()
    );
    assert_eq!(
        parse("EQ(next^0 r, prev^0 s)").unwrap(),
        parse("EQ(r, s)").unwrap()
    );
    assert!(parse("X^-1 p").is_err());
}

/// rcc8.md's spellings `TPP^-1` and `NTPP^-1` name TPPI and NTPPI in formulas too, written
/// as one word; `TPP` alone and `^` elsewhere keep their meaning.
#[test]
fn converse_spellings_name_the_inverse_relations() {
    let spatial = |relation, left: &str, right: &str| {
        Formula::Atom(Atom::Spatial {
            relation,
            left: Region {
                offset: 0,
                name: left.into(),
            },
            right: Region {
                offset: 0,
                name: right.into(),
            },
        })
    };
    assert_eq!(
        parse("TPP^-1(a, b)").unwrap(),
        spatial(Rcc8::Tppi, "a", "b")
    );
    assert_eq!(
        parse("NTPP^-1(a,b)").unwrap(),
        spatial(Rcc8::Ntppi, "a", "b")
    );
    assert_eq!(parse("TPP(a, b)").unwrap(), spatial(Rcc8::Tpp, "a", "b"));
    assert_eq!(
        parse("always TPP^-1(a, b) && next^2 p").unwrap(),
        parse("always TPPI(a, b) && next^2 p").unwrap()
    );
    // The seed's own spelling, `NTTP` and its converse `NTTP^-1` (Ch. 3.3.1).
    assert_eq!(parse("NTTP(a, b)").unwrap(), spatial(Rcc8::Ntpp, "a", "b"));
    for text in ["NTTP^-1(a, b)", "NTTPI(a, b)", "NTTPi(a, b)"] {
        assert_eq!(
            parse(text).unwrap(),
            spatial(Rcc8::Ntppi, "a", "b"),
            "{text}"
        );
    }
    // Printed in the canonical spelling, which reads back the same.
    assert_eq!(parse("NTPP^-1(a, b)").unwrap().to_string(), "NTPPI(a, b)");
    for (text, column) in [
        ("TPP ^-1(a, b)", 5),
        ("TPP^-2(a, b)", 4),
        ("DC^-1(a, b)", 3),
    ] {
        let e = parse(text).unwrap_err();
        assert_eq!(e.column, column, "{text}: {e}");
    }
}

#[test]
fn errors_name_the_column() {
    for (text, column) in [
        ("always (p && )", 14),
        ("p &&", 5),
        ("always[10,5] p", 12),
        ("eventually[0,1.5ms] p", 14),
        ("forall x UAV: p", 10),
        ("p # q", 3),
        ("5", 1),
        ("\"open", 1),
        ("next^1.5 p", 6),
        ("(p", 3),
        ("p q", 3),
        // Beyond what a double holds exactly: it would compare as 9007199254740992.
        ("f(a) > 9007199254740993", 8),
        ("f(a) = -18446744073709551615", 9),
    ] {
        let e = parse(text).unwrap_err();
        assert_eq!(e.column, column, "{text}: {e}");
    }
    assert!(parse("f(a) > 9007199254740992").is_ok());
}

#[test]
fn deep_or_huge_formulas_are_refused_not_overflowed() {
    let deep = format!("{}p{}", "(".repeat(100_000), ")".repeat(100_000));
    let e = parse(&deep).unwrap_err();
    assert!(e.message.contains("nests deeper"), "{e}");
    let negations = format!("{}p", "!".repeat(100_000));
    assert!(parse(&negations).is_err());
    let ok = format!(
        "{}p{}",
        "(".repeat(MAX_DEPTH / 8),
        ")".repeat(MAX_DEPTH / 8)
    );
    assert!(parse(&ok).is_ok(), "{:?}", parse(&ok));
    let huge = "p && ".repeat(300_000) + "p";
    assert!(parse(&huge).unwrap_err().message.contains("longer than"));
    // A flat conjunction parses without recursion per operand, but its tree is as deep as it
    // is long: up to the tree limit it is accepted, beyond it refused.
    let long = "p && ".repeat(MAX_TREE_DEPTH - 1) + "p";
    assert!(parse(&long).is_ok());
    let longer = "p && ".repeat(10_000) + "p";
    assert!(parse(&longer).unwrap_err().message.contains("1000 levels"));
}

// --- Round trip --------------------------------------------------------------------------

fn name() -> impl Strategy<Value = String> + Clone {
    "[a-zA-Z_][a-zA-Z0-9_]{0,6}".prop_filter("not a keyword or relation", |s| {
        !is_keyword(s)
            && Rcc8::from_name(s).is_none()
            && !matches!(s.as_str(), "ms" | "s" | "min" | "h")
    })
}

fn term() -> impl Strategy<Value = Term> {
    let leaf = prop_oneof![
        (-1e9f64..1e9).prop_map(Term::Number),
        "[a-z \"\\\\]{0,5}".prop_map(Term::Str),
        name().prop_map(|name| Term::Name { name, args: vec![] }),
    ];
    leaf.prop_recursive(2, 8, 3, |inner| {
        (name(), prop::collection::vec(inner, 1..3))
            .prop_map(|(name, args)| Term::Name { name, args })
    })
}

fn interval() -> impl Strategy<Value = Interval> {
    (0u64..100_000, prop::option::of(0u64..100_000)).prop_map(|(a, b)| match b {
        Some(b) => Interval {
            lo: a.min(b),
            hi: Some(a.max(b)),
        },
        None => Interval { lo: a, hi: None },
    })
}

fn atom() -> impl Strategy<Value = Atom> {
    let cmp = prop::sample::select(vec![Cmp::Eq, Cmp::Ne, Cmp::Lt, Cmp::Gt, Cmp::Le, Cmp::Ge]);
    let rel = prop::sample::select(vec![
        Rcc8::Dc,
        Rcc8::Ec,
        Rcc8::Po,
        Rcc8::Eq,
        Rcc8::Tpp,
        Rcc8::Ntpp,
        Rcc8::Tppi,
        Rcc8::Ntppi,
    ]);
    let region = || (-3i32..4, name()).prop_map(|(offset, name)| Region { offset, name });
    prop_oneof![
        (name(), prop::collection::vec(term(), 0..3))
            .prop_map(|(name, args)| Atom::Predicate { name, args }),
        (term(), cmp, term()).prop_map(|(left, op, right)| Atom::Compare { left, op, right }),
        (rel, region(), region()).prop_map(|(relation, left, right)| Atom::Spatial {
            relation,
            left,
            right
        }),
    ]
}

fn formula() -> impl Strategy<Value = Formula> {
    let leaf = prop_oneof![
        Just(Formula::True),
        Just(Formula::False),
        atom().prop_map(Formula::Atom),
    ];
    leaf.prop_recursive(6, 64, 2, |inner| {
        let domain = prop_oneof![
            name().prop_map(Domain::Named),
            prop::collection::vec(name(), 1..3).prop_map(Domain::Set),
        ];
        prop_oneof![
            inner.clone().prop_map(|f| Formula::Not(Box::new(f))),
            (inner.clone(), inner.clone())
                .prop_map(|(a, b)| Formula::And(Box::new(a), Box::new(b))),
            (inner.clone(), inner.clone()).prop_map(|(a, b)| Formula::Or(Box::new(a), Box::new(b))),
            (inner.clone(), inner.clone())
                .prop_map(|(a, b)| Formula::Implies(Box::new(a), Box::new(b))),
            (inner.clone(), inner.clone())
                .prop_map(|(a, b)| Formula::Iff(Box::new(a), Box::new(b))),
            (interval(), inner.clone()).prop_map(|(i, f)| Formula::Always(i, Box::new(f))),
            (interval(), inner.clone()).prop_map(|(i, f)| Formula::Eventually(i, Box::new(f))),
            (interval(), inner.clone(), inner.clone()).prop_map(|(i, a, b)| Formula::Until(
                i,
                Box::new(a),
                Box::new(b)
            )),
            (1u32..4, inner.clone()).prop_map(|(k, f)| Formula::Next(k, Box::new(f))),
            (name(), domain.clone(), inner.clone()).prop_map(|(x, d, f)| Formula::Forall(
                x,
                d,
                Box::new(f)
            )),
            (name(), domain, inner).prop_map(|(x, d, f)| Formula::Exists(x, d, Box::new(f))),
        ]
    })
}

proptest! {
    // 2000 cases by default; `PROPTEST_CASES=N` runs more (a soak) or fewer.
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|n| n.parse().ok()).unwrap_or(2000),
        ..ProptestConfig::default()
    })]

    #[test]
    fn printing_then_parsing_gives_the_same_formula(f in formula()) {
        let text = f.to_string();
        let back = parse(&text);
        prop_assert_eq!(back.as_ref(), Ok(&f), "printed as {}", text);
    }

    #[test]
    fn the_parser_never_panics(text in "[ -~]{0,60}") {
        let _ = parse(&text);
    }
}

#[test]
fn printing_adds_no_nesting() {
    // Found by fuzzing: 130 negations parse, and must print to something that parses.
    let negations = format!("{}z", "!".repeat(130));
    let f = parse(&negations).unwrap();
    assert_eq!(f.to_string(), negations);
    // A long flat conjunction prints flat.
    let long = "p && ".repeat(999) + "p";
    let f = parse(&long).unwrap();
    assert_eq!(f.to_string(), long);
    assert_eq!(
        parse("a -> b -> c U d U e").unwrap().to_string(),
        "a -> b -> (c U d U e)"
    );
}

#[test]
fn near_the_limits_printing_still_parses_back() {
    // Found by fuzzing: a formula near the recursion limit, printed with the parentheses the
    // printer adds, must still parse.
    let bangs = "!".repeat(450);
    let text =
        format!("{bangs}\"q\" = 1 U[5,inf] exists x in {{a, b}}: exists x in {{a, b}}: {bangs}kyw");
    let f = parse(&text).unwrap();
    assert_eq!(parse(&f.to_string()).unwrap(), f);
    // The deepest tree accepted, printed, parses back.
    let deep = format!("{}p", "!".repeat(MAX_TREE_DEPTH - 1));
    let f = parse(&deep).unwrap();
    assert_eq!(parse(&f.to_string()).unwrap(), f);
    let nested_ands =
        (0..MAX_TREE_DEPTH / 2).fold("p".to_owned(), |acc, _| format!("q && ({acc})"));
    let f = parse(&nested_ands).unwrap();
    assert_eq!(parse(&f.to_string()).unwrap(), f);
}
