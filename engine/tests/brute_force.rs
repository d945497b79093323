//! Property test: on random environments of at most 9 transformations and 3 targets (with
//! existing and protected CUs), EXPLORE's cost equals a brute-force optimum over every set of
//! transformations that admits an acyclic valid configuration, with further CUs of them for
//! targets that need one (a transformation may run more than once), targets left unsatisfied
//! counted first (the relaxation; one out port publishes on one channel, so targets on distinct
//! channels need distinct out ports); applying the change set yields an environment whose only
//! invalidities are the targets reported unsatisfied.
#![expect(clippy::unwrap_used, reason = "tests")]

use dyknow_engine::{
    Candidates, Cid, ComputationUnit, Environment, ExploreOptions, Ids, Invalidity, ProbeOptions,
    Target, Tid, Transformation, compile, explore, lower_bound,
};
use proptest::prelude::*;

const H: f64 = 10.0;

#[derive(Debug, Clone)]
struct Tf {
    inputs: Vec<u8>,
    outputs: Vec<u8>,
    labour: f64,
    upkeep: f64,
    existing: u8,
    protected: bool,
}

fn tf() -> impl Strategy<Value = Tf> {
    (
        prop::collection::vec(0u8..4, 0..3),
        prop::collection::vec(0u8..4, 1..3),
        prop::sample::select(vec![0.0, 0.5, 1.0, 2.0, 3.0]),
        prop::sample::select(vec![0.0, 0.5, 1.0, 2.0]),
        prop::sample::select(vec![0u8, 0, 0, 1, 2]),
        prop::bool::weighted(0.1),
    )
        .prop_map(
            |(inputs, outputs, labour, upkeep, existing, protected)| Tf {
                inputs,
                outputs,
                labour,
                upkeep,
                existing,
                protected,
            },
        )
}

fn case() -> impl Strategy<Value = (Vec<Tf>, Vec<u8>)> {
    (
        prop::collection::vec(tf(), 1..10),
        prop::collection::vec(0u8..4, 1..4),
    )
}

/// Tags are letters; `i ~ o` when equal, or for the pairs (0, 1) and (2, 3).
fn similar(i: &u8, o: &u8) -> bool {
    i == o || (*i, *o) == (0, 1) || (*i, *o) == (2, 3)
}

fn build(tfs: &[Tf], targets: &[u8]) -> (Environment, Candidates) {
    let mut env = Environment::default();
    for (k, t) in tfs.iter().enumerate() {
        let tid = Tid::new(format!("t{k}"));
        let inputs: Vec<String> = (0..t.inputs.len()).map(|i| format!("i{i}")).collect();
        let outputs: Vec<String> = (0..t.outputs.len()).map(|j| format!("o{j}")).collect();
        for c in 0..t.existing {
            let cid = Cid::new(format!("old-{k}-{c}"));
            env.cus.insert(
                cid.clone(),
                ComputationUnit {
                    cid,
                    tid: tid.clone(),
                    inputs: inputs.iter().map(|p| (p.clone(), None)).collect(),
                    outputs: outputs.iter().map(|p| (p.clone(), None)).collect(),
                    protected: t.protected && c == 0,
                },
            );
        }
        env.library.insert(
            tid.clone(),
            Transformation {
                tid,
                inputs,
                outputs,
                labour: t.labour,
                upkeep: t.upkeep,
            },
        );
    }
    for (q, _) in targets.iter().enumerate() {
        env.targets.insert(
            format!("q{q}").into(),
            Target {
                qid: format!("q{q}").into(),
                channel: format!("/target{q}").into(),
            },
        );
    }
    let index = |tid: &str| tid[1..].parse::<usize>().unwrap();
    let candidates = Candidates::from_tags(
        &env,
        |tid, i| vec![tfs[index(tid)].inputs[i]],
        |tid, j| vec![tfs[index(tid)].outputs[j]],
        |qid| vec![targets[qid[1..].parse::<usize>().unwrap()]],
        similar,
    );
    (env, candidates)
}

/// The brute-force optimum: (targets unsatisfied, cost), or `None` when protected CUs cannot
/// be fed whatever is chosen.
fn brute_force(tfs: &[Tf], targets: &[u8]) -> Option<(u32, f64)> {
    let n = tfs.len();
    let protected_upkeep: f64 = tfs
        .iter()
        .filter(|t| t.protected && t.existing > 0)
        .map(|t| H * t.upkeep)
        .sum();
    let mut best: Option<(u32, f64)> = None;
    for set in 0u32..(1 << n) {
        let chosen = |k: usize| set & (1 << k) != 0;
        // Protected CUs stay: their transformations are in every configuration.
        if (0..n).any(|k| tfs[k].protected && tfs[k].existing > 0 && !chosen(k)) {
            continue;
        }
        // Producible nodes: the least fixpoint of "every input has a producible provider".
        let mut producible = vec![false; n];
        loop {
            let mut changed = false;
            for k in 0..n {
                if chosen(k) && !producible[k] {
                    let fed = tfs[k].inputs.iter().all(|i| {
                        (0..n)
                            .any(|p| producible[p] && tfs[p].outputs.iter().any(|o| similar(i, o)))
                    });
                    if fed {
                        producible[k] = true;
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        if (0..n).any(|k| chosen(k) && !producible[k]) {
            continue;
        }
        let cost: f64 = (0..n)
            .filter(|k| chosen(*k))
            .map(|k| instance_cost(&tfs[k], 0))
            .sum::<f64>()
            + protected_upkeep;
        // A chosen transformation may run more than once: a further CU publishes its out ports
        // on further channels (docs/engine.md). Any acyclic wiring of the set feeds a further
        // CU's inputs too, so only targets need one, and at most one per target beyond the
        // first: every way to add up to `targets - 1` further CUs.
        let producers: Vec<usize> = (0..n)
            .filter(|k| {
                producible[*k]
                    && targets
                        .iter()
                        .any(|q| tfs[*k].outputs.iter().any(|o| similar(q, o)))
            })
            .collect();
        let mut extras: Vec<Vec<usize>> = vec![Vec::new()];
        let mut last: Vec<Vec<usize>> = vec![Vec::new()];
        for _ in 1..targets.len() {
            // The multisets one longer: non-decreasing sequences.
            last = last
                .iter()
                .flat_map(|e| {
                    producers
                        .iter()
                        .filter(|p| e.last().is_none_or(|l| *p >= l))
                        .map(|p| [e.as_slice(), &[*p]].concat())
                        .collect::<Vec<_>>()
                })
                .collect();
            extras.extend(last.iter().cloned());
        }
        for extra in extras {
            // One out port publishes on one channel, and targets have distinct channels: the
            // satisfied targets are a maximum matching of targets to the out ports of every CU.
            let mut ports: Vec<(usize, usize)> = (0..n)
                .filter(|p| producible[*p])
                .flat_map(|p| (0..tfs[p].outputs.len()).map(move |j| (p, j)))
                .collect();
            let mut more = 0.0;
            for (k, p) in extra.iter().enumerate() {
                let before = extra[..k].iter().filter(|e| *e == p).count();
                more += instance_cost(&tfs[*p], before + 1);
                ports.extend((0..tfs[*p].outputs.len()).map(|j| (*p, j)));
            }
            let edges: Vec<Vec<usize>> = targets
                .iter()
                .map(|q| {
                    (0..ports.len())
                        .filter(|k| similar(q, &tfs[ports[*k].0].outputs[ports[*k].1]))
                        .collect()
                })
                .collect();
            let unsatisfied = (targets.len() - matching(&edges, ports.len())) as u32;
            let cost = cost + more;
            let better = match best {
                None => true,
                Some((u, c)) => {
                    (unsatisfied, cost) < (u, c) && (unsatisfied < u || cost < c - 1e-9)
                }
            };
            if better {
                best = Some((unsatisfied, cost));
            }
        }
    }
    best
}

/// What the `k`-th CU (from 0) of a transformation costs: its existing CUs first (the protected
/// one's upkeep is a constant), then spawns.
fn instance_cost(t: &Tf, k: usize) -> f64 {
    if t.protected && k == 0 && t.existing > 0 {
        0.0
    } else if k < usize::from(t.existing) {
        H * t.upkeep
    } else {
        t.labour + H * t.upkeep
    }
}

/// The size of a maximum matching (Kuhn's augmenting paths) of left nodes to right nodes.
fn matching(edges: &[Vec<usize>], right: usize) -> usize {
    fn augment(
        u: usize,
        edges: &[Vec<usize>],
        seen: &mut [bool],
        owner: &mut [Option<usize>],
    ) -> bool {
        for &v in &edges[u] {
            if !std::mem::replace(&mut seen[v], true)
                && (owner[v].is_none_or(|w| augment(w, edges, seen, owner)))
            {
                owner[v] = Some(u);
                return true;
            }
        }
        false
    }
    let mut owner = vec![None; right];
    (0..edges.len())
        .filter(|u| augment(*u, edges, &mut vec![false; right], &mut owner))
        .count()
}

proptest! {
    // 1000 cases by default; `PROPTEST_CASES=N` runs more (a soak) or fewer.
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|n| n.parse().ok()).unwrap_or(1000),
        ..ProptestConfig::default()
    })]

    #[test]
    fn explore_is_optimal_and_its_change_set_valid((tfs, targets) in case()) {
        let (env, candidates) = build(&tfs, &targets);
        let options = ExploreOptions { horizon: H, ..ExploreOptions::default() };
        let exploration = explore(&env, &candidates, &options);
        let expected = brute_force(&tfs, &targets);
        prop_assert!(exploration.proven_optimal);
        // The bound EXPLORE prunes with is admissible: never above the optimum.
        let bound = lower_bound(&env, &candidates, &options);
        if let Some((unsatisfied, cost)) = expected {
            prop_assert!(
                bound.unsatisfied < unsatisfied
                    || (bound.unsatisfied == unsatisfied && bound.value <= cost + 1e-9),
                "bound {:?} above the optimum ({}, {})", bound, unsatisfied, cost
            );
            prop_assert!((exploration.bound.value - cost).abs() < 1e-9);
        }
        if let Some(after) = optimal_and_valid(&env, &candidates, &options, &exploration, expected)? {
            // Protected CUs are never destroyed.
            for cu in env.cus.values().filter(|c| c.protected) {
                prop_assert!(after.cus.contains_key(&cu.cid));
            }
            // A second review from the result changes nothing.
            let again = explore(&after, &candidates, &options);
            let recompiled = compile(&after, &again, &options, &mut Ids::after(&after));
            prop_assert!(recompiled.actions.is_empty(), "{:?}", recompiled.actions);
        }
    }

    /// With a timeout of 1 to 50 ms the any-time probes search beside the main search, here
    /// from its first backtrack, taking turns every 1 to 3 of its backtracks, in rounds of 1 to
    /// 5 backtracks, with 0 to 2 further probes on threads of their own, which help with the
    /// main search's proof after 0 to 3 rounds without a cheaper graph (subtrees of it split
    /// between the threads). Proven or not, the plan is valid and never cheaper than the
    /// optimum; when the search says it proved the optimum, it is the optimum.
    #[test]
    fn explore_with_probes_is_optimal_when_proven(
        (tfs, targets) in case(), every in 1u64..4, limit in 1u64..6, ms in 1u64..50,
        threads in 0usize..3, help_after in 0u64..4,
    ) {
        let (env, candidates) = build(&tfs, &targets);
        let options = ExploreOptions {
            horizon: H,
            timeout: Some(std::time::Duration::from_millis(ms)),
            probes: Some(ProbeOptions { after: 0, every, threads, limit, help_after }),
            ..ExploreOptions::default()
        };
        let exploration = explore(&env, &candidates, &options);
        let expected = brute_force(&tfs, &targets);
        if exploration.proven_optimal {
            optimal_and_valid(&env, &candidates, &options, &exploration, expected)?;
        } else if let Some((unsatisfied, cost)) = expected {
            // Any-time: a valid plan, not better than the optimum.
            prop_assert!(
                exploration.cost.unsatisfied > unsatisfied
                    || (exploration.cost.unsatisfied == unsatisfied
                        && exploration.cost.value >= cost - 1e-9),
                "any-time {:?} below the optimum ({}, {})", exploration.cost, unsatisfied, cost
            );
            valid_change_set(&env, &candidates, &options, &exploration)?;
        }
    }
}

/// Checks `exploration` against the brute-force optimum `expected`: no plan when there is none,
/// else the optimum's cost and unsatisfied targets, and a compiled change set whose result's only
/// invalidities are those targets. Returns that result.
fn optimal_and_valid(
    env: &Environment,
    candidates: &Candidates,
    options: &ExploreOptions,
    exploration: &dyknow_engine::Exploration,
    expected: Option<(u32, f64)>,
) -> Result<Option<Environment>, TestCaseError> {
    let Some((unsatisfied, cost)) = expected else {
        prop_assert!(exploration.plan.is_none());
        return Ok(None);
    };
    let plan = exploration.plan.clone().unwrap();
    prop_assert_eq!(plan.unsatisfied().len() as u32, unsatisfied);
    prop_assert!(
        (exploration.cost.value - cost).abs() < 1e-9,
        "explore {} brute force {}",
        exploration.cost.value,
        cost
    );
    let (compiled_cost, after) = valid_change_set(env, candidates, options, exploration)?;
    prop_assert!(
        (compiled_cost - cost).abs() < 1e-9,
        "compiled {} brute force {}",
        compiled_cost,
        cost
    );
    Ok(Some(after))
}

/// Compiles `exploration` and applies it: the result's only invalidities are the targets the
/// change set reports unsatisfied. Returns the change set's cost and the result.
fn valid_change_set(
    env: &Environment,
    candidates: &Candidates,
    options: &ExploreOptions,
    exploration: &dyknow_engine::Exploration,
) -> Result<(f64, Environment), TestCaseError> {
    let compiled = compile(env, exploration, options, &mut Ids::after(env));
    let mut after = env.clone();
    after.apply(&compiled.actions);
    let expected_invalid: Vec<Invalidity> = compiled
        .unsatisfied_targets
        .iter()
        .map(|q| Invalidity::UnsatisfiedTarget { target: q.clone() })
        .collect();
    prop_assert_eq!(after.invalidities(candidates), expected_invalid);
    Ok((compiled.cost.total, after))
}
