//! Live equals offline, in process: random groups of formulas over simulated symbol streams
//! with random gaps, jitter, duplicates, out-of-order samples and crashes (a stream silent for
//! a while), synchronised by a random policy and progressed; the verdicts given (and the final
//! `unknown`s) must equal `dyknow check`'s on the recorded trace, verdict for verdict and
//! timestamp for timestamp. (`server/tests/groups.rs` checks the same through the service.)

use dyknow_group::progression::TraceHeader;
use dyknow_group::{Policy, Progression, StreamKind, Synchroniser, VerdictLine};
use dyknow_mstl::{parse, trace};
use proptest::prelude::*;
use serde_json::{Value, json};

const KINDS: [&str; 5] = ["p", "q", "x", "f(a)", "f(b)"];

fn formula(kind: u8, a: u64, c: i64) -> String {
    match kind % 9 {
        0 => format!("always[0,{a}] p"),
        1 => format!("eventually[0,{a}] q"),
        2 => format!("always (p -> eventually[0,{a}] q)"),
        3 => format!("x > {c}"),
        4 => format!("always[0,{a}] (x > {c} || q)"),
        5 => format!("p U[0,{a}] q"),
        6 => format!("forall v in D: always[0,{a}] f(v) > {c}"),
        7 => format!("exists v in D: eventually[{},{a}] f(v) < {c}", a / 2),
        _ => format!("!q -> next (x <= {c} && p)"),
    }
}

#[derive(Debug, Clone)]
struct Sample {
    stream: usize,
    t: u64,
    arrival: u64,
    value: Value,
}

fn value(stream: usize, r: u64) -> Value {
    match stream {
        0 | 1 => json!(!r.is_multiple_of(3)),
        2 => json!((r % 20) as i64 - 5),
        _ => json!((r % 10) as i64),
    }
}

fn samples_strategy() -> impl Strategy<Value = Vec<Sample>> {
    // Per stream: a period, jitter, a crash window, and a seed for values and gaps.
    prop::collection::vec(
        (20u64..120, 0u64..80, 0u64..1500, 0u64..600, any::<u64>()),
        5,
    )
    .prop_map(|streams| {
        let mut out = Vec::new();
        for (i, (period, jitter, crash_at, crash_len, seed)) in streams.into_iter().enumerate() {
            let mut r = seed | 1;
            let mut t = 1_000 + (r % period);
            while t < 3_000 {
                r ^= r << 13;
                r ^= r >> 7;
                r ^= r << 17;
                let crashed = t >= 1_000 + crash_at && t < 1_000 + crash_at + crash_len;
                let gap = r % 11 == 0;
                if !crashed && !gap {
                    let delay = r % (jitter + 1);
                    out.push(Sample {
                        stream: i,
                        t,
                        arrival: t + delay,
                        value: value(i, r >> 8),
                    });
                    if r % 17 == 0 {
                        // A duplicate, arriving later.
                        out.push(Sample {
                            stream: i,
                            t,
                            arrival: t + delay + 30,
                            value: value(i, r >> 9),
                        });
                    }
                }
                t += period;
            }
        }
        out.sort_by_key(|s| (s.arrival, s.stream, s.t));
        out
    })
}

fn policy_strategy() -> impl Strategy<Value = Policy> {
    prop_oneof![
        (10u64..200, 0u64..150).prop_map(|(p, d)| Policy::Wait {
            period_ms: p,
            max_delay_ms: d
        }),
        (10u64..200, 1u64..400, prop::option::of(0u64..150)).prop_map(|(p, a, d)| Policy::Hold {
            period_ms: p,
            max_age_ms: a,
            max_delay_ms: d
        }),
        prop::option::of(0u64..40).prop_map(|d| Policy::Event { max_delay_ms: d }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES").ok().and_then(|c| c.parse().ok()).unwrap_or(300)
    ))]

    #[test]
    fn the_published_verdicts_equal_dyknow_check_on_the_recorded_trace(
        formulas in prop::collection::vec((any::<u8>(), 50u64..1500, -3i64..12), 1..7),
        samples in samples_strategy(),
        policy in policy_strategy(),
        stop_at in 1_500u64..3_200,
    ) {
        let texts: Vec<String> = formulas.iter().map(|&(k, a, c)| formula(k, a, c)).collect();
        let parsed: Vec<_> = texts.iter().map(|t| parse(t).unwrap()).collect();
        let header = TraceHeader {
            domains: [("D".to_owned(), vec!["a".to_owned(), "b".to_owned()])].into(),
            ..TraceHeader::default()
        };
        let mut prog = Progression::new(header.clone());
        for f in &parsed {
            prog.add(f).unwrap();
        }
        let kinds: Vec<StreamKind> = KINDS.iter().map(|k| StreamKind::Value((*k).to_owned())).collect();
        let mut sync = Synchroniser::new(policy, kinds.len());
        sync.start(1_000);
        let mut lines = vec![header.line()];
        let mut live: Vec<VerdictLine> = Vec::new();
        let take = |states: Vec<dyknow_group::SyncState<Value>>, prog: &mut Progression, lines: &mut Vec<String>, live: &mut Vec<VerdictLine>| {
            for s in states {
                let taken = prog.take(&kinds, &s);
                lines.extend(taken.line);
                live.extend(taken.verdicts);
            }
        };
        let mut clock = 1_000;
        for s in samples.iter().filter(|s| s.arrival < stop_at) {
            // The deadlines that pass before this sample arrives.
            while clock < s.arrival {
                clock = (clock + 7).min(s.arrival);
                let due = sync.poll(clock);
                take(due, &mut prog, &mut lines, &mut live);
            }
            let states = sync.offer(s.stream, s.t, s.value.clone(), s.arrival);
            take(states, &mut prog, &mut lines, &mut live);
        }
        live.extend(prog.finish());

        let text = lines.join("\n");
        let mut out = Vec::new();
        let offline = trace::check(&parsed, text.as_bytes(), trace::Header::default(), &mut out).unwrap();
        let offline: Vec<VerdictLine> = offline.into_iter().map(Into::into).collect();
        let key = |v: &VerdictLine| (v.formula, v.t, v.verdict);
        let mut a: Vec<_> = live.iter().map(key).collect();
        let mut b: Vec<_> = offline.iter().map(key).collect();
        a.sort();
        b.sort();
        prop_assert_eq!(a, b, "trace:\n{}", text);
        // States strictly increase.
        let ts: Vec<u64> = lines[1..].iter().map(|l| serde_json::from_str::<Value>(l).unwrap()["t"].as_u64().unwrap()).collect();
        prop_assert!(ts.windows(2).all(|w| w[0] < w[1]));
    }
}
