//! The DyKnow model in the knowledge base (`dyknow_store::model`): Example 12 from the Turtle
//! specs of `specs/turtle/`, the candidate table by SPARQL, change sets written back as graph
//! deltas, and `dependsOn` in the store matching the engine's configuration after every change
//! set; change-set records read back as they were written.
#![expect(clippy::unwrap_used, reason = "tests")]

use std::collections::BTreeSet;

use dyknow_engine::{
    Cause, ChangeSet, ChangeSetId, ChangeSetStatus, Environment, ExploreOptions, Ids, Provider,
};
use dyknow_store::model::{self, Loaded};
use dyknow_store::{EnvironmentPart, InputFormat, KnowledgeBase};

fn load_specs(kb: &KnowledgeBase, files: &[&str]) {
    for f in files {
        let path = format!("{}/../specs/turtle/{f}", env!("CARGO_MANIFEST_DIR"));
        kb.load_document(&std::fs::read(&path).unwrap(), InputFormat::Turtle)
            .unwrap();
    }
}

/// A knowledge base with Example 12's transformations, similarity and targets.
fn example_12() -> KnowledgeBase {
    let kb = KnowledgeBase::in_memory().unwrap();
    load_specs(
        &kb,
        &[
            "example-12.ttl",
            "example-12-similarity.ttl",
            "example-12-targets.ttl",
        ],
    );
    kb
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
                        .map(|(from, _)| (cu.cid.to_string(), (*from).to_owned()))
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
    let dyknow_engine::Reviewed { compiled, after } =
        dyknow_engine::review(&loaded.env, &loaded.candidates, options, ids);
    let delta = model::delta(&loaded.env, &after, &loaded.iris);
    kb.set_environment(&delta.parts).unwrap();
    let (extra, missing) = kb.materialisation_drift().unwrap();
    assert!(
        extra.is_empty() && missing.is_empty(),
        "extra {extra:?}\nmissing {missing:?}"
    );
    // What the store says now is what the engine chose.
    let reloaded = model::load(kb).unwrap();
    assert_eq!(reloaded.env.cus, after.cus);
    assert_eq!(depends_on(kb), expected_depends_on(&after));
    compiled.cost.total
}

#[test]
fn example_12_through_the_knowledge_base() {
    let kb = example_12();
    let loaded = model::load(&kb).unwrap();
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
    let mut loaded = model::load(&kb).unwrap();
    let crashed = loaded
        .env
        .cus
        .values()
        .find(|c| c.tid == "tid2")
        .unwrap()
        .cid
        .clone();
    kb.set_environment(&[(EnvironmentPart::Cu(crashed.clone()), Vec::new())])
        .unwrap();
    let mut reloaded = model::load(&kb).unwrap();
    assert!(!reloaded.env.cus.contains_key(&crashed));
    reloaded.env.library.get_mut("tid4").unwrap().upkeep = 3.0;
    loaded = reloaded;
    let options = ExploreOptions {
        prefer: vec!["tid2".into()],
        ..ExploreOptions::default()
    };
    assert_eq!(review(&kb, &loaded, &options, &mut ids), 43.0);
    let now = model::load(&kb).unwrap();
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
    review(&kb, &model::load(&kb).unwrap(), &options, &mut ids);
    load_specs(&kb, &["ch6-puff.ttl"]);
    review(&kb, &model::load(&kb).unwrap(), &options, &mut ids);
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
        review(&kb, &model::load(&kb).unwrap(), &options, &mut ids);
    }
    kb.remove_spec(SpecKind::Target, "target1").unwrap();
    review(&kb, &model::load(&kb).unwrap(), &options, &mut ids);
    assert!(depends_on(&kb).is_empty());
}

#[test]
fn change_set_records_read_back_as_written() {
    let kb = example_12();
    let loaded = model::load(&kb).unwrap();
    let reviewed = dyknow_engine::review(
        &loaded.env,
        &loaded.candidates,
        &ExploreOptions::default(),
        &mut Ids::default(),
    );
    let delta = model::delta(&loaded.env, &reviewed.after, &loaded.iris);
    let mut written = Vec::new();
    for n in [2, 1, 10] {
        let mut cs = ChangeSet::new(
            ChangeSetId::numbered(n),
            Cause::TargetAdded {
                target: "qid1".into(),
            },
            reviewed.compiled.clone(),
            delta.ntriples(),
        );
        cs.status = ChangeSetStatus::Applied;
        kb.set_environment(&[(
            EnvironmentPart::ChangeSet(cs.id.clone()),
            model::change_set_triples(&cs),
        )])
        .unwrap();
        written.push(cs);
    }
    // Oldest first, by number (cs-10 after cs-2), each exactly as written.
    written.sort_by_key(|cs| cs.id.number());
    let records = model::change_sets(&kb).unwrap();
    assert_eq!(records.change_sets, written);
    assert!(records.unreadable.is_empty());
    // The record names each action in RDF too.
    let rows = kb
        .select(
            "PREFIX dkros: <http://www.dyknow.eu/ontology/dyknow-ros#>
             SELECT ?kind WHERE { <urn:dyknow:changeset:cs-1> dkros:hasAction ?a . ?a dkros:actionKind ?kind ; dkros:hasIndex 0 }",
        )
        .unwrap();
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert!(
        matches!(&rows[0][0], Some(dyknow_store::oxigraph::model::Term::Literal(l)) if l.value() == "spawn")
    );
}

/// A `SpecCache` kept across writes (as the manager keeps it) reads what a fresh read gives
/// after every kind of write: CUs written and removed, a spec removed (a CU of it keeps the
/// transformation's IRI as tid), a spec posted back; and its direct read of the CUs gives what
/// the SPARQL query `queries::CUS` does.
#[test]
fn a_kept_cache_follows_every_write() {
    let kb = example_12();
    let cache = model::SpecCache::default();
    let fresh = || model::load(&kb).unwrap();
    let same = |cached: &Loaded, fresh: &Loaded| {
        assert_eq!(cached.env, fresh.env);
        // The direct read of the CUs answers what the SPARQL query does.
        assert_eq!(
            cached.env.cus,
            model::cus_by_query(&kb, &cached.env.library).unwrap()
        );
        assert_eq!(*cached.candidates, *fresh.candidates);
        assert_eq!(cached.iris, fresh.iris);
        // The snapshot reads of `GET /cus` give the same CUs, and their transformations.
        let snapshot = cache.cus_now(&kb).unwrap();
        assert_eq!(snapshot.cus, fresh.env.cus);
        for cu in snapshot.cus.values() {
            assert_eq!(
                snapshot.library.get(&cu.tid),
                fresh.env.library.get(&cu.tid)
            );
        }
        assert_eq!(*snapshot.specs, *fresh.specs);
    };
    let loaded = cache.load(&kb, None).unwrap();
    same(&loaded, &fresh());
    let options = ExploreOptions::default();
    let mut ids = Ids::default();
    review(&kb, &loaded, &options, &mut ids);
    let after_review = cache.load(&kb, None).unwrap();
    assert_eq!(after_review.env.cus.len(), 3, "the review's CUs are read");
    same(&after_review, &fresh());
    let cu = after_review.env.cus.keys().next().unwrap().clone();
    kb.set_environment(&[(EnvironmentPart::Cu(cu.clone()), Vec::new())])
        .unwrap();
    let now = cache.load(&kb, None).unwrap();
    assert!(!now.env.cus.contains_key(&cu));
    same(&now, &fresh());
    kb.remove_spec(dyknow_store::spec::SpecKind::Transformation, "tid4")
        .unwrap();
    let now = cache.load(&kb, None).unwrap();
    assert!(!now.env.library.contains_key("tid4"));
    same(&now, &fresh());
    load_specs(&kb, &["example-12.ttl"]);
    let now = cache.load(&kb, None).unwrap();
    assert!(now.env.library.contains_key("tid4"));
    same(&now, &fresh());
}
