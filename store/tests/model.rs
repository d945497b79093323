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

/// The environment log lists the environment graphs each write touched, never a spec's, and
/// the spec log never an environment graph.
#[test]
fn the_environment_log_lists_the_environment_graphs_written_since_a_generation() {
    let kb = example_12();
    let (start, none) = kb.environment_changes_since(kb.environment_generation());
    assert_eq!(none, Some(BTreeSet::new()));
    let cu = EnvironmentPart::Cu(dyknow_engine::Cid::new("c"));
    let history = EnvironmentPart::History;
    let triple = |s: &str| {
        oxigraph::model::Triple::new(
            oxigraph::model::NamedNode::new_unchecked(format!("urn:test:{s}")),
            oxigraph::model::NamedNode::new_unchecked("urn:test:p"),
            oxigraph::model::Literal::new_simple_literal("o"),
        )
    };
    kb.set_environment(&[(history.clone(), vec![triple("h")])])
        .unwrap();
    let spec_generation = kb.spec_generation();
    kb.set_environment(&[(cu.clone(), vec![triple("c")])])
        .unwrap();
    load_specs(&kb, &["example-12.ttl"]);
    let (now, since_start) = kb.environment_changes_since(start);
    assert_eq!(now, start + 2, "the spec write is not an environment write");
    assert_eq!(
        since_start,
        Some(BTreeSet::from([history.graph(), cu.graph()]))
    );
    assert_eq!(
        kb.environment_changes_since(start + 1).1,
        Some(BTreeSet::from([cu.graph()]))
    );
    let (_, specs) = kb.spec_changes_since(spec_generation);
    assert!(
        specs
            .unwrap()
            .iter()
            .all(|g| !g.as_str().contains("environment")),
        "environment graphs are not in the spec log"
    );
}

/// The kept cache's CUs are patched, not read again: after any sequence of writes (CUs
/// written, rewritten and removed, other environment graphs written, transformation specs
/// removed, posted back, and re-posted under another IRI), read at random points in between,
/// it gives the CUs a fresh read gives.
mod patched_cus {
    use super::*;
    use dyknow_engine::{Cid, ComputationUnit, Tid};
    use dyknow_store::spec::SpecKind;
    use proptest::prelude::*;

    #[derive(Debug, Clone)]
    enum Op {
        /// A CU `cu{name}` of `tid{tid}`, its ports bound to channels from `bind`.
        Write {
            name: u8,
            tid: u8,
            bind: u8,
        },
        Remove {
            name: u8,
        },
        /// An environment graph with no CU in it.
        History {
            n: u8,
        },
        /// An environment graph (the imported one) naming the in port of `tid{tid}`.
        NamePort {
            tid: u8,
            n: u8,
        },
        RemoveSpec {
            tid: u8,
        },
        /// Example 12's specs posted again (blank-node transformations: new IRIs).
        PostAll,
        /// `tid{tid}` posted under a named IRI, `ex:named{tid}-{variant}`.
        PostNamed {
            tid: u8,
            variant: u8,
        },
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            4 => (0..5u8, 1..6u8, any::<u8>()).prop_map(|(name, tid, bind)| Op::Write { name, tid, bind }),
            2 => (0..5u8).prop_map(|name| Op::Remove { name }),
            1 => any::<u8>().prop_map(|n| Op::History { n }),
            2 => (1..3u8, 0..3u8).prop_map(|(tid, n)| Op::NamePort { tid, n }),
            1 => (1..6u8).prop_map(|tid| Op::RemoveSpec { tid }),
            1 => Just(Op::PostAll),
            1 => (1..6u8, 0..2u8).prop_map(|(tid, variant)| Op::PostNamed { tid, variant }),
        ]
    }

    fn named_spec(tid: u8, variant: u8) -> String {
        let (inputs, tag) = if tid <= 2 {
            (
                "dyknow:hasInPort [ a dyknow:InPort ; dyknow:hasName \"in\" ;
                    dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription ex:A ] ] ;",
                "B",
            )
        } else {
            ("", "E")
        };
        format!(
            "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
             @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
             @prefix ex: <http://example.org/ex12#> .
             ex:named{tid}-{variant} a dyknow:Transformation ; rdfs:label \"tid{tid}\" ; {inputs}
               dyknow:hasOutPort [ a dyknow:OutPort ; dyknow:hasName \"out\" ;
                 dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription ex:{tag} ] ] ;
               dyknow:hasCostModel [ a dyknow:LabourCostModel ; dyknow:hasValue 1.0 ] ,
                 [ a dyknow:UpkeepCostModel ; dyknow:hasValue 2.0 ] ."
        )
    }

    fn apply(kb: &KnowledgeBase, op: &Op) {
        match op {
            Op::Write { name, tid, bind } => {
                let loaded = model::load(kb).unwrap();
                let mut env = loaded.env.clone();
                let Some(cu) = cu(&env, *name, *tid, *bind) else {
                    return;
                };
                env.cus.insert(cu.cid.clone(), cu.clone());
                let triples = model::cu_triples(&cu, &env, &loaded.iris);
                // A CU subscribed to its own channel is refused (nothing written): the cache
                // must not change either.
                let _ = kb.set_environment(&[(EnvironmentPart::Cu(cu.cid.clone()), triples)]);
            }
            Op::Remove { name } => kb
                .set_environment(&[(
                    EnvironmentPart::Cu(Cid::new(format!("cu{name}"))),
                    Vec::new(),
                )])
                .unwrap(),
            Op::History { n } => kb
                .set_environment(&[(
                    EnvironmentPart::History,
                    model::history_triples([format!("name{n}").as_str()]),
                )])
                .unwrap(),
            Op::NamePort { tid, n } => {
                // The in port's IRI as the spec writes it: named here, it is refused while the
                // spec names it too (a port has one name), and taken once the spec is gone.
                let port = oxigraph::model::NamedNode::new_unchecked(format!(
                    "urn:dyknow:transformation:tid{tid}/port/in"
                ));
                let triple = oxigraph::model::Triple::new(
                    port,
                    dyknow_ontology::vocab::dyknow::HAS_NAME,
                    oxigraph::model::Literal::new_simple_literal(format!("named{n}")),
                );
                let _ = kb.set_environment(&[(EnvironmentPart::Imported, vec![triple])]);
            }
            Op::RemoveSpec { tid } => {
                let _ = kb.remove_spec(SpecKind::Transformation, &format!("tid{tid}"));
            }
            // Refused while the imported graph names a port the specs name otherwise.
            Op::PostAll => {
                let path = format!(
                    "{}/../specs/turtle/example-12.ttl",
                    env!("CARGO_MANIFEST_DIR")
                );
                let _ = kb.load_document(&std::fs::read(&path).unwrap(), InputFormat::Turtle);
            }
            Op::PostNamed { tid, variant } => {
                let _ =
                    kb.load_document(named_spec(*tid, *variant).as_bytes(), InputFormat::Turtle);
            }
        }
    }

    /// A CU `cu{name}` of `tid{tid}` of `env`'s library, its ports bound as `bind` says.
    fn cu(env: &Environment, name: u8, tid: u8, bind: u8) -> Option<ComputationUnit> {
        let tid = Tid::new(format!("tid{tid}"));
        let tf = env.library.get(&tid)?;
        let channel = |i: u8| !(bind >> i).is_multiple_of(4);
        Some(ComputationUnit {
            cid: Cid::new(format!("cu{name}")),
            tid,
            inputs: tf
                .inputs
                .iter()
                .map(|p| {
                    (
                        p.clone(),
                        channel(0).then(|| format!("ch{}", bind % 3).into()),
                    )
                })
                .collect(),
            outputs: tf
                .outputs
                .iter()
                .map(|p| (p.clone(), channel(2).then(|| format!("ch{name}").into())))
                .collect(),
            protected: bind.is_multiple_of(5),
        })
    }

    type Cus = Vec<(u8, Option<(u8, u8)>)>;

    fn cus(most: usize) -> impl Strategy<Value = Cus> {
        proptest::collection::vec((0..5u8, proptest::option::of((1..6u8, 0..16u8))), 0..most)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// `model::delta` skips the CUs whose triples cannot have changed: it writes what
        /// comparing every CU's triples in both environments (`cu_triples`) finds.
        #[test]
        fn the_delta_is_what_comparing_every_cus_triples_gives(
            before in cus(6), changes in cus(3), upkeep in proptest::option::of(1..6u8)
        ) {
            let loaded = model::load(&example_12()).unwrap();
            let env = |cus: &Cus| {
                let mut env = loaded.env.clone();
                for (name, spec) in cus {
                    match spec.and_then(|(tid, bind)| cu(&env, *name, tid, bind)) {
                        Some(cu) => env.cus.insert(cu.cid.clone(), cu),
                        None => env.cus.remove(format!("cu{name}").as_str()),
                    };
                }
                env
            };
            // The CUs after: those before, a few of them changed, added or removed.
            let mut after = env(&[before.clone(), changes].concat());
            let before = env(&before);
            // A transformation's upkeep estimate moved (learned): its CUs' cost triples change.
            if let Some(tid) = upkeep
                && let Some(tf) = after.library.get_mut(format!("tid{tid}").as_str())
            {
                tf.upkeep += 1.0;
            }
            let delta = model::delta(&before, &after, &loaded.iris);
            let names: BTreeSet<_> = before.cus.keys().chain(after.cus.keys()).collect();
            let (mut insert, mut delete, mut parts) = (BTreeSet::new(), BTreeSet::new(), Vec::new());
            for name in names {
                let triples = |env: &Environment| -> BTreeSet<String> {
                    env.cus
                        .get(name)
                        .map(|c| model::cu_triples(c, env, &loaded.iris))
                        .unwrap_or_default()
                        .iter()
                        .map(ToString::to_string)
                        .collect()
                };
                let (old, new) = (triples(&before), triples(&after));
                if old != new {
                    insert.extend(new.difference(&old).cloned());
                    delete.extend(old.difference(&new).cloned());
                    parts.push(EnvironmentPart::Cu(name.clone()));
                }
            }
            let strings = |t: &[oxigraph::model::Triple]| -> BTreeSet<String> {
                t.iter().map(ToString::to_string).collect()
            };
            prop_assert_eq!(strings(&delta.insert), insert);
            prop_assert_eq!(strings(&delta.delete), delete);
            prop_assert_eq!(delta.parts.into_iter().map(|(p, _)| p).collect::<Vec<_>>(), parts);
        }

        #[test]
        fn a_kept_cache_reads_only_what_changed_and_gives_what_a_fresh_read_does(
            ops in proptest::collection::vec((op(), any::<bool>()), 1..16)
        ) {
            let kb = example_12();
            let cache = model::SpecCache::default();
            let _ = cache.load(&kb, None).unwrap();
            for (op, read) in &ops {
                apply(&kb, op);
                if *read {
                    let fresh = model::load(&kb).unwrap();
                    prop_assert_eq!(&cache.load(&kb, None).unwrap().env.cus, &fresh.env.cus);
                    prop_assert_eq!(&cache.cus_now(&kb).unwrap().cus, &fresh.env.cus);
                }
            }
            let fresh = model::load(&kb).unwrap();
            prop_assert_eq!(&cache.load(&kb, None).unwrap().env.cus, &fresh.env.cus);
            prop_assert_eq!(
                &fresh.env.cus,
                &model::cus_by_query(&kb, &fresh.env.library).unwrap()
            );
        }
    }
}
