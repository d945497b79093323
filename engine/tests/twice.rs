//! A transformation used more than once (issue 18 item 4, docs/engine.md): two targets on
//! different channels want the stream of one transformation. One out port publishes on one
//! channel, so the plan runs a second CU of it, sharing what both read; a review of the result
//! keeps both; when a target goes, its CU goes; a cheaper alternative transformation still
//! wins over a second CU.

use dyknow_engine::{
    Action, Candidates, Environment, ExploreOptions, Ids, Target, Transformation, compile, explore,
};

/// `src` (no input, out `S`, cost 1 + 1/time unit) and `f` (in `S`, out `F`, 2 + 1), plus
/// `g` (in `S`, out `F`, `g_labour` + 1) when `g_labour` is given; targets on `/a` and `/b`
/// both wanting `F`.
fn environment(g_labour: Option<f64>) -> (Environment, Candidates) {
    let mut env = Environment::default();
    let mut add = |tid: &str, input: bool, labour: f64| {
        env.library.insert(
            tid.into(),
            Transformation {
                tid: tid.into(),
                inputs: if input { vec!["in".into()] } else { vec![] },
                outputs: vec!["out".into()],
                labour,
                upkeep: 1.0,
            },
        );
    };
    add("src", false, 1.0);
    add("f", true, 2.0);
    if let Some(labour) = g_labour {
        add("g", true, labour);
    }
    for (qid, channel) in [("qa", "/a"), ("qb", "/b")] {
        env.targets.insert(
            qid.into(),
            Target {
                qid: qid.into(),
                channel: channel.into(),
            },
        );
    }
    let candidates = Candidates::from_tags(
        &env,
        |_, _| vec!["S"],
        |tid, _| vec![if tid == "src" { "S" } else { "F" }],
        |_| vec!["F"],
        |i: &&str, o: &&str| i == o,
    );
    (env, candidates)
}

fn review(env: &Environment, candidates: &Candidates) -> (f64, Vec<Action>) {
    let options = ExploreOptions::default();
    let exploration = explore(env, candidates, &options);
    assert!(exploration.proven_optimal);
    let compiled = compile(env, &exploration, &options, &mut Ids::after(env));
    assert!(compiled.unsatisfied_targets.is_empty(), "{compiled:?}");
    (exploration.cost.value, compiled.actions)
}

fn spawned<'a>(actions: &'a [Action], tid: &str) -> Vec<&'a str> {
    actions
        .iter()
        .filter_map(|a| match a {
            Action::Spawn { cu, transformation } if transformation.as_str() == tid => {
                Some(cu.as_str())
            }
            _ => None,
        })
        .collect()
}

#[test]
fn a_second_channel_for_one_stream_gets_a_second_cu_sharing_its_input() {
    let (mut env, candidates) = environment(None);
    let (cost, actions) = review(&env, &candidates);
    // One src (1 + 10) and two f (2 + 10 each), horizon 10.
    assert!((cost - 35.0).abs() < 1e-9, "{cost}");
    assert_eq!(spawned(&actions, "src").len(), 1);
    let fs = spawned(&actions, "f");
    assert_eq!(fs.len(), 2, "{actions:?}");
    env.apply(&actions);
    assert!(env.invalidities(&candidates).is_empty());
    let src = env.cus.values().find(|c| c.tid.as_str() == "src").unwrap();
    let source = src.outputs["out"].clone().unwrap();
    let mut channels: Vec<String> = fs
        .iter()
        .map(|f| {
            let cu = &env.cus[*f];
            assert_eq!(
                cu.inputs["in"].as_ref(),
                Some(&source),
                "both read the one src"
            );
            cu.outputs["out"].clone().unwrap().to_string()
        })
        .collect();
    channels.sort();
    assert_eq!(channels, ["/a", "/b"]);

    // A review of the result keeps both.
    let (again, actions) = review(&env, &candidates);
    assert!(actions.is_empty(), "{actions:?}");
    assert!((again - 2.0 * 10.0 - 10.0).abs() < 1e-9, "{again}");

    // A target goes: its CU goes, the other stays.
    env.targets.remove("qb");
    let (_, actions) = review(&env, &candidates);
    let on_b = fs
        .iter()
        .find(|f| env.cus[**f].outputs["out"].as_deref() == Some("/b"))
        .unwrap();
    assert_eq!(actions, [Action::Destroy { cu: (*on_b).into() }]);
}

#[test]
fn a_cheaper_alternative_wins_over_a_second_cu() {
    // g costs 1 + 10 against f's 2 + 10: the plan runs g twice (1 + 10 + 2 × 11 = 33).
    let (env, candidates) = environment(Some(1.0));
    let (cost, actions) = review(&env, &candidates);
    assert!((cost - 33.0).abs() < 1e-9, "{cost}");
    assert_eq!(spawned(&actions, "g").len(), 2, "{actions:?}");
    assert!(spawned(&actions, "f").is_empty());
    // With both f already running (two CUs of f, from the plan without g), keeping them
    // (10 each) is cheaper than spawning g (11 each): nothing changes.
    let (without_g, c) = environment(None);
    let (_, first) = review(&without_g, &c);
    let (mut env, candidates) = environment(Some(1.0));
    env.apply(&first);
    let (cost, actions) = review(&env, &candidates);
    assert!((cost - 30.0).abs() < 1e-9, "{cost}");
    assert!(actions.is_empty(), "{actions:?}");
}
