//! The seed's Example 12 (4.31–4.50), on the model alone: from the empty environment the
//! change set spawns CUs of tid1, tid4 and tid2 with tid4 shared, cost 33.0; then, with tid4's
//! upkeep observed as 3.0 and tid2's CU crashed, it spawns tid3, tid2 and tid5, destroys tid4's
//! CU and keeps tid1's, cost 43.0.

use dyknow_engine::{
    Action, Candidates, Environment, ExploreOptions, Ids, Provider, Target, Transformation,
    compile, explore,
};

/// Example 12's library, targets and similarity (A ~ E, A ~ F, C ~ F, C ~ G, reflexive).
fn example_12() -> (Environment, Candidates) {
    let mut env = Environment::default();
    for (tid, input) in [
        ("tid1", Some("A")),
        ("tid2", Some("C")),
        ("tid3", None),
        ("tid4", None),
        ("tid5", None),
    ] {
        env.library.insert(
            tid.into(),
            Transformation {
                tid: tid.into(),
                inputs: input.map(|_| "in".to_owned()).into_iter().collect(),
                outputs: vec!["out".into()],
                labour: 1.0,
                upkeep: 1.0,
            },
        );
    }
    for (qid, channel) in [("qid1", "101"), ("qid2", "102")] {
        env.targets.insert(
            qid.into(),
            Target {
                qid: qid.into(),
                channel: channel.into(),
            },
        );
    }
    let out_tag = |tid: &str, _: usize| -> Vec<&'static str> {
        vec![match tid {
            "tid1" => "B",
            "tid2" => "D",
            "tid3" => "E",
            "tid4" => "F",
            _ => "G",
        }]
    };
    let in_tag =
        |tid: &str, _: usize| -> Vec<&'static str> { vec![if tid == "tid1" { "A" } else { "C" }] };
    let target_tag =
        |qid: &str| -> Vec<&'static str> { vec![if qid == "qid1" { "B" } else { "D" }] };
    let similar = |i: &&str, o: &&str| {
        i == o || matches!((*i, *o), ("A", "E") | ("A", "F") | ("C", "F") | ("C", "G"))
    };
    let candidates = Candidates::from_tags(&env, in_tag, out_tag, target_tag, similar);
    (env, candidates)
}

fn spawned(actions: &[Action]) -> Vec<(String, String)> {
    actions
        .iter()
        .filter_map(|a| match a {
            Action::Spawn { cu, transformation } => {
                Some((cu.to_string(), transformation.to_string()))
            }
            _ => None,
        })
        .collect()
}

#[test]
fn example_12_both_reviews() {
    let (mut env, candidates) = example_12();
    assert_eq!(
        candidates.for_input("tid1", 0),
        [
            Provider {
                tid: "tid3".into(),
                port: 0
            },
            Provider {
                tid: "tid4".into(),
                port: 0
            }
        ]
    );
    let options = ExploreOptions::default();
    let mut ids = Ids::default();

    // First review: the targets are registered into the empty environment.
    let exploration = explore(&env, &candidates, &options);
    assert!(exploration.proven_optimal);
    let first = compile(&env, &exploration, &options, &mut ids);
    assert_eq!(first.cost.total, 33.0);
    assert_eq!(first.cost.labour, 3.0);
    assert_eq!(first.cost.upkeep_per_time_unit, 3.0);
    let tids: Vec<String> = spawned(&first.actions)
        .into_iter()
        .map(|(_, t)| t)
        .collect();
    assert_eq!(tids, ["tid1", "tid4", "tid2"]);
    env.apply(&first.actions);
    assert!(
        env.invalidities(&candidates).is_empty(),
        "{:?}",
        env.invalidities(&candidates)
    );
    // tid4 is shared: one channel feeds both tid1 and tid2.
    let cu_of =
        |env: &Environment, tid: &str| env.cus.values().find(|c| c.tid == tid).unwrap().clone();
    let (c1, c2, c4) = (
        cu_of(&env, "tid1"),
        cu_of(&env, "tid2"),
        cu_of(&env, "tid4"),
    );
    assert_eq!(c1.inputs["in"], c4.outputs["out"]);
    assert_eq!(c2.inputs["in"], c4.outputs["out"]);
    assert_eq!(c1.outputs["out"].as_deref(), Some("101"));
    assert_eq!(c2.outputs["out"].as_deref(), Some("102"));

    // Second review: tid4's upkeep is observed as 3.0 and tid2's CU crashes.
    env.library.get_mut("tid4").unwrap().upkeep = 3.0;
    env.cus.remove(&c2.cid);
    let options = ExploreOptions {
        prefer: vec!["tid2".into()],
        ..ExploreOptions::default()
    };
    let exploration = explore(&env, &candidates, &options);
    let second = compile(&env, &exploration, &options, &mut ids);
    assert_eq!(second.cost.total, 43.0);
    let tids: Vec<String> = spawned(&second.actions)
        .into_iter()
        .map(|(_, t)| t)
        .collect();
    assert_eq!(tids, ["tid3", "tid2", "tid5"]);
    assert!(
        second
            .actions
            .contains(&Action::Destroy { cu: c4.cid.clone() })
    );
    assert!(
        !second
            .actions
            .iter()
            .any(|a| matches!(a, Action::Destroy { cu } if *cu == c1.cid))
    );
    env.apply(&second.actions);
    assert!(env.invalidities(&candidates).is_empty());
    assert_eq!(env.cus.len(), 4);

    // Nothing left to improve: a third review changes nothing.
    let exploration = explore(&env, &candidates, &options);
    let third = compile(&env, &exploration, &options, &mut ids);
    assert!(third.actions.is_empty(), "{:?}", third.actions);
    assert_eq!(third.cost.total, 40.0);
}

#[test]
fn no_valid_configuration_relaxes_to_the_satisfiable_targets() {
    let (mut env, mut candidates) = example_12();
    env.targets.insert(
        "qid3".into(),
        Target {
            qid: "qid3".into(),
            channel: "103".into(),
        },
    );
    let options = ExploreOptions::default();
    let exploration = explore(&env, &candidates, &options);
    let compiled = compile(&env, &exploration, &options, &mut Ids::default());
    assert_eq!(compiled.unsatisfied_targets, ["qid3"]);
    assert_eq!(compiled.cost.total, 33.0);
    // Without the relaxation there is no plan at all.
    let strict = ExploreOptions {
        relax: false,
        ..ExploreOptions::default()
    };
    assert!(explore(&env, &candidates, &strict).plan.is_none());
    // A target two transformations feed in a cycle only: nothing traces back to a source.
    candidates.add_target(
        "qid3",
        Provider {
            tid: "loop".into(),
            port: 0,
        },
    );
    env.library.insert(
        "loop".into(),
        Transformation {
            tid: "loop".into(),
            inputs: vec!["in".into()],
            outputs: vec!["out".into()],
            labour: 0.0,
            upkeep: 0.0,
        },
    );
    candidates.add_input(
        "loop",
        0,
        Provider {
            tid: "loop".into(),
            port: 0,
        },
    );
    let exploration = explore(&env, &candidates, &options);
    assert_eq!(exploration.plan.unwrap().unsatisfied(), ["qid3"]);
}
