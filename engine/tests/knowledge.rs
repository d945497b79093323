//! The engine over the knowledge base: Example 12 from the Turtle specs of `specs/turtle/`,
//! the candidate table by SPARQL, change sets written back as graph deltas, and `dependsOn`
//! in the store matching the engine's configuration after every change set.
#![expect(clippy::unwrap_used, reason = "tests")]

use std::collections::BTreeSet;

use dyknow_engine::knowledge::{self, Loaded};
use dyknow_engine::{Environment, ExploreOptions, Ids, Provider};
use dyknow_store::{InputFormat, KnowledgeBase};

fn load_specs(kb: &KnowledgeBase, files: &[&str]) {
    for f in files {
        let path = format!("{}/../specs/turtle/{f}", env!("CARGO_MANIFEST_DIR"));
        kb.load_document(&std::fs::read(&path).unwrap(), InputFormat::Turtle)
            .unwrap();
    }
}

/// The `dependsOn` pairs in the store, by CU name.
fn depends_on(kb: &KnowledgeBase) -> BTreeSet<(String, String)> {
    kb.select(
        "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#>
         SELECT ?a ?b WHERE { ?x dyknow:dependsOn ?y . ?x dyknow:hasName ?a . ?y dyknow:hasName ?b }",
    )
    .unwrap()
    .into_iter()
    .map(|row| {
        let name = |t: &Option<dyknow_store::oxigraph::model::Term>| match t {
            Some(dyknow_store::oxigraph::model::Term::Literal(l)) => l.value().to_owned(),
            other => panic!("{other:?}"),
        };
        (name(&row[0]), name(&row[1]))
    })
    .collect()
}

/// The `dependsOn` pairs the engine's configuration implies (transitively).
fn expected_depends_on(env: &Environment) -> BTreeSet<(String, String)> {
    let publishers = env.publishers();
    let direct: BTreeSet<(String, String)> = env
        .cus
        .values()
        .flat_map(|cu| {
            cu.inputs
                .values()
                .flatten()
                .filter_map(|ch| publishers.get(ch.as_str()))
                .flat_map(|p| {
                    p.iter()
                        .map(|(from, _)| ((cu.cid.clone()), (*from).to_owned()))
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let mut closure = direct.clone();
    loop {
        let next: BTreeSet<(String, String)> = closure
            .iter()
            .flat_map(|(a, b)| {
                direct
                    .iter()
                    .filter(move |(c, _)| c == b)
                    .map(move |(_, d)| (a.clone(), d.clone()))
            })
            .collect();
        let before = closure.len();
        closure.extend(next);
        if closure.len() == before {
            return closure;
        }
    }
}

fn review(kb: &KnowledgeBase, loaded: &Loaded, options: &ExploreOptions, ids: &mut Ids) -> f64 {
    let knowledge::Reviewed {
        compiled,
        after,
        delta,
    } = knowledge::review(loaded, options, ids);
    knowledge::write(kb, &delta).unwrap();
    let (extra, missing) = kb.materialisation_drift().unwrap();
    assert!(
        extra.is_empty() && missing.is_empty(),
        "extra {extra:?}\nmissing {missing:?}"
    );
    // What the store says now is what the engine chose.
    let reloaded = knowledge::load(kb).unwrap();
    assert_eq!(reloaded.env.cus, after.cus);
    assert_eq!(depends_on(kb), expected_depends_on(&after));
    compiled.cost.total
}

#[test]
fn example_12_through_the_knowledge_base() {
    let kb = KnowledgeBase::in_memory().unwrap();
    load_specs(
        &kb,
        &[
            "example-12.ttl",
            "example-12-similarity.ttl",
            "example-12-targets.ttl",
        ],
    );
    let loaded = knowledge::load(&kb).unwrap();
    assert_eq!(loaded.env.library.len(), 5);
    assert_eq!(loaded.env.targets.len(), 2);
    let p = |tid: &str| Provider {
        tid: tid.into(),
        port: 0,
    };
    assert_eq!(
        loaded.candidates.for_input("tid1", 0),
        [p("tid3"), p("tid4")]
    );
    assert_eq!(
        loaded.candidates.for_input("tid2", 0),
        [p("tid4"), p("tid5")]
    );
    assert_eq!(loaded.candidates.for_target("qid1"), [p("tid1")]);
    assert_eq!(loaded.candidates.for_target("qid2"), [p("tid2")]);

    let options = ExploreOptions::default();
    let mut ids = Ids::default();
    assert_eq!(review(&kb, &loaded, &options, &mut ids), 33.0);

    // tid2's CU crashes; tid4's upkeep is observed as 3.0.
    let mut loaded = knowledge::load(&kb).unwrap();
    let crashed = loaded
        .env
        .cus
        .values()
        .find(|c| c.tid == "tid2")
        .unwrap()
        .cid
        .clone();
    kb.set_environment(&[(knowledge::cu_part(&crashed), Vec::new())])
        .unwrap();
    let mut reloaded = knowledge::load(&kb).unwrap();
    assert!(!reloaded.env.cus.contains_key(&crashed));
    reloaded.env.library.get_mut("tid4").unwrap().upkeep = 3.0;
    loaded = reloaded;
    let options = ExploreOptions {
        prefer: vec!["tid2".into()],
        ..ExploreOptions::default()
    };
    assert_eq!(review(&kb, &loaded, &options, &mut ids), 43.0);
    let now = knowledge::load(&kb).unwrap();
    let tids: BTreeSet<&str> = now.env.cus.values().map(|c| c.tid.as_str()).collect();
    assert_eq!(tids, BTreeSet::from(["tid1", "tid2", "tid3", "tid5"]));
}

#[test]
fn chapter_6_through_the_knowledge_base() {
    use dyknow_store::spec::SpecKind;
    let kb = KnowledgeBase::in_memory().unwrap();
    load_specs(&kb, &["ch6-target.ttl", "ch6-piff.ttl"]);
    let options = ExploreOptions::default();
    let mut ids = Ids::default();
    review(&kb, &knowledge::load(&kb).unwrap(), &options, &mut ids);
    load_specs(&kb, &["ch6-puff.ttl"]);
    review(&kb, &knowledge::load(&kb).unwrap(), &options, &mut ids);
    for label in [
        "pose(piff)",
        "bottom_cam(piff)",
        "subsampler(piff)",
        "segmenter(piff)",
        "ball_detector(piff)",
        "ball_localization(piff)",
        "circle_monitor(ball)",
    ] {
        kb.remove_spec(SpecKind::Transformation, label).unwrap();
        review(&kb, &knowledge::load(&kb).unwrap(), &options, &mut ids);
    }
    kb.remove_spec(SpecKind::Target, "target1").unwrap();
    review(&kb, &knowledge::load(&kb).unwrap(), &options, &mut ids);
    assert!(depends_on(&kb).is_empty());
}
