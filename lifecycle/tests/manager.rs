//! The life-cycle without HTTP: change sets through the `Executor` seam (an executor that fails
//! an action, one that records what it is given), and names never handed out twice across a
//! restart of the manager.
#![expect(clippy::unwrap_used, reason = "tests")]

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use dyknow_engine::{
    Action, ActionFailure, Cause, ChangeSet, ChangeSetStatus, Cid, CuOutcome, CuOutcomeState,
};
use dyknow_lifecycle::{
    Applied, Executor, FleetEvent, LifecycleError, Manager, ModelOnly, Perturbation, Settings,
    SpawnRequest,
};
use dyknow_store::spec::{Spec, SpecKind};
use dyknow_store::{InputFormat, KnowledgeBase};

fn example_12() -> Arc<KnowledgeBase> {
    let kb = KnowledgeBase::in_memory().unwrap();
    for f in [
        "example-12-similarity.ttl",
        "example-12.ttl",
        "example-12-targets.ttl",
    ] {
        let path = format!("{}/../specs/turtle/{f}", env!("CARGO_MANIFEST_DIR"));
        kb.load_document(&std::fs::read(path).unwrap(), InputFormat::Turtle)
            .unwrap();
    }
    Arc::new(kb)
}

/// Records every change set it is given; fails the first spawn of `fail_once`, if any.
#[derive(Default)]
struct Recording {
    seen: Mutex<Vec<ChangeSet>>,
    fail_once: Mutex<Option<String>>,
}

impl Executor for Recording {
    fn apply(
        &self,
        change_set: &ChangeSet,
        _: &std::collections::BTreeMap<dyknow_engine::Tid, dyknow_store::spec::TransformationSpec>,
    ) -> Applied {
        self.seen.lock().unwrap().push(change_set.clone());
        let mut fail = self.fail_once.lock().unwrap();
        let failures: Vec<ActionFailure> = change_set
            .actions
            .iter()
            .enumerate()
            .filter_map(|(k, a)| match a {
                Action::Spawn { cu, transformation }
                    if fail.as_deref() == Some(transformation.as_str()) =>
                {
                    Some(ActionFailure {
                        action: k,
                        cu: cu.clone(),
                        reason: "the test executor refuses it".to_owned(),
                    })
                }
                _ => None,
            })
            .collect();
        if !failures.is_empty() {
            *fail = None;
        }
        // What became of each CU, as a real executor reports it.
        let cus = change_set
            .actions
            .iter()
            .filter_map(|a| a.cu())
            .map(|cu| {
                let state = if failures.iter().any(|f| &f.cu == cu) {
                    CuOutcomeState::Crashed
                } else {
                    CuOutcomeState::Running
                };
                let executor = Some("test".to_owned());
                (cu.clone(), CuOutcome { executor, state })
            })
            .collect();
        Applied { failures, cus }
    }
}

fn cu_of(manager: &Manager, tid: &str) -> Option<Cid> {
    manager
        .load()
        .unwrap()
        .env
        .cus
        .values()
        .find(|c| c.tid == tid)
        .map(|c| c.cid.clone())
}

#[test]
fn a_failed_action_is_recorded_and_its_cu_is_repaired_by_the_next_review() {
    let executor = Arc::new(Recording {
        fail_once: Mutex::new(Some("tid2".to_owned())),
        ..Recording::default()
    });
    let manager = Manager::new(example_12(), executor.clone(), Settings::default()).unwrap();
    manager
        .report(Perturbation::TargetAdded {
            target: "qid1".into(),
        })
        .unwrap();
    let first = manager.review().unwrap().expect("a change set");
    assert_eq!(first.status, ChangeSetStatus::Failed);
    assert_eq!(first.failures.len(), 1);
    let failed = &first.failures[0];
    assert!(
        matches!(&first.actions[failed.action], Action::Spawn { cu, transformation } if *cu == failed.cu && transformation == "tid2")
    );
    // The record says what the executor said became of each CU.
    assert_eq!(first.cus[&failed.cu].state, CuOutcomeState::Crashed);
    assert_eq!(first.cus.len(), 3, "{:?}", first.cus);
    assert!(
        first
            .cus
            .iter()
            .all(|(cu, o)| *cu == failed.cu || o.state == CuOutcomeState::Running)
    );
    assert_eq!(manager.change_sets(None)[0].cus, first.cus);
    // The failed CU is not in the model; the others are; a review is due at once, as after a
    // crash, with the crash as its cause.
    assert_eq!(cu_of(&manager, "tid2"), None);
    assert!(cu_of(&manager, "tid1").is_some() && cu_of(&manager, "tid4").is_some());
    // The review that repairs it is scheduled soon (the failure back-off starts at 100 ms),
    // not at the end of the 10 s stable interval.
    assert!(
        manager.status().next_review_at <= SystemTime::now() + Duration::from_millis(100),
        "{:?}",
        manager.status()
    );
    let repair = manager.review().unwrap().expect("a repair");
    assert_eq!(repair.status, ChangeSetStatus::Applied);
    assert_eq!(
        repair.cause,
        Cause::CuCrashed {
            cu: failed.cu.clone(),
            also: Vec::new(),
        }
    );
    let loaded = manager.load().unwrap();
    assert!(loaded.env.invalidities(&loaded.candidates).is_empty());
    // The repair spawned a new tid2 CU under a fresh name.
    let repaired = cu_of(&manager, "tid2").expect("tid2 runs again");
    assert_ne!(repaired, failed.cu);
    // The executor saw both change sets, the history holds both, the record reads back.
    let seen: Vec<_> = executor
        .seen
        .lock()
        .unwrap()
        .iter()
        .map(|c| c.id.clone())
        .collect();
    assert_eq!(seen, [first.id.clone(), repair.id.clone()]);
    let recorded = dyknow_store::model::change_sets(manager.knowledge_base())
        .unwrap()
        .change_sets;
    assert_eq!(recorded[0], *first);
    assert_eq!(recorded[1], *repair);
}

#[test]
fn spawn_and_destroy_are_change_sets_the_executor_applies() {
    let executor = Arc::new(Recording::default());
    let manager = Manager::new(example_12(), executor.clone(), Settings::default()).unwrap();
    let cu = manager.spawn(SpawnRequest::new("tid3")).unwrap();
    assert_eq!(cu.tid, "tid3");
    manager.destroy(&cu.cid).unwrap();
    let seen = executor.seen.lock().unwrap().clone();
    assert_eq!(seen.len(), 2);
    assert_eq!(seen[0].cause, Cause::Manual);
    assert_eq!(
        seen[0].actions,
        [Action::Spawn {
            cu: cu.cid.clone(),
            transformation: "tid3".into()
        }]
    );
    assert_eq!(seen[1].actions, [Action::Destroy { cu: cu.cid.clone() }]);
    assert_eq!(manager.change_sets(None).len(), 2);
    // Bad requests change nothing.
    let before = manager.change_sets(None).len();
    assert!(matches!(
        manager.destroy(&cu.cid),
        Err(LifecycleError::UnknownCu(_))
    ));
    assert!(matches!(
        manager.spawn(SpawnRequest::new("nope")),
        Err(LifecycleError::UnknownTransformation(_))
    ));
    assert!(matches!(
        manager.spawn(SpawnRequest::new("tid3").named(" ")),
        Err(LifecycleError::EmptyName)
    ));
    assert!(matches!(
        manager.report(Perturbation::CuCrashed { cu: "nope".into() }),
        Err(LifecycleError::UnknownCu(_))
    ));
    assert_eq!(manager.change_sets(None).len(), before);
    assert_eq!(executor.seen.lock().unwrap().len(), 2);
}

#[test]
fn a_spawn_the_executor_refuses_is_an_error_and_recorded() {
    let executor = Arc::new(Recording {
        fail_once: Mutex::new(Some("tid3".to_owned())),
        ..Recording::default()
    });
    let manager = Manager::new(example_12(), executor, Settings::default()).unwrap();
    let refused = manager.spawn(SpawnRequest::new("tid3").named("camera").protected(true));
    let Err(LifecycleError::NotApplied { change_set, cu, .. }) = refused else {
        panic!("{refused:?}");
    };
    assert_eq!(cu, "camera");
    let recorded = manager.change_set(&change_set).expect("recorded");
    assert_eq!(recorded.status, ChangeSetStatus::Failed);
    assert_eq!(cu_of(&manager, "tid3"), None);
    // The executor fails only once: asking again with the same name works, the CU never ran.
    let again = manager
        .spawn(SpawnRequest::new("tid3").named("camera").protected(true))
        .unwrap();
    assert_eq!(again.cid, "camera");
    assert!(again.protected);
    let statuses: Vec<_> = manager.change_sets(None).iter().map(|c| c.status).collect();
    assert_eq!(
        statuses,
        [ChangeSetStatus::Failed, ChangeSetStatus::Applied]
    );
}

#[test]
fn names_are_never_handed_out_twice_across_a_restart() {
    let kb = example_12();
    let manager = Manager::new(kb.clone(), Arc::new(ModelOnly), Settings::default()).unwrap();
    manager
        .report(Perturbation::TargetAdded {
            target: "qid1".into(),
        })
        .unwrap();
    manager.review().unwrap().expect("a change set");
    // A CU crashes and is replaced: its name is gone from the model, not from the history.
    let crashed = cu_of(&manager, "tid2").unwrap();
    manager
        .report(Perturbation::CuCrashed {
            cu: crashed.clone(),
        })
        .unwrap();
    manager.review().unwrap().expect("a repair");
    // The newest CU is destroyed: no CU in the model has its number any more.
    let newest = manager
        .load()
        .unwrap()
        .env
        .cus
        .keys()
        .max_by_key(|c| c.minted_number())
        .unwrap()
        .clone();
    manager.destroy(&newest).unwrap();
    let used: BTreeSet<Cid> = manager
        .change_sets(None)
        .iter()
        .flat_map(|cs| cs.actions.iter().filter_map(|a| a.cu().cloned()))
        .collect();
    assert!(used.contains(&crashed) && used.contains(&newest));
    let highest_used = used.iter().filter_map(Cid::minted_number).max().unwrap();
    assert_eq!(newest.minted_number(), Some(highest_used));
    drop(manager);
    // A new manager over the same knowledge base (a restart) reads the history back.
    let restarted = Manager::new(kb, Arc::new(ModelOnly), Settings::default()).unwrap();
    assert_eq!(restarted.change_sets(None).len(), 3);
    let cu = restarted
        .spawn(SpawnRequest::new("tid3").protected(true))
        .unwrap();
    assert!(!used.contains(&cu.cid), "{} was handed out before", cu.cid);
    assert!(cu.cid.minted_number().unwrap() > highest_used);
    assert_eq!(
        restarted.change_sets(None).last().unwrap().id.number(),
        Some(4)
    );
}

/// Fails every destroy.
struct RefusesDestroy;

impl Executor for RefusesDestroy {
    fn apply(
        &self,
        change_set: &ChangeSet,
        _: &std::collections::BTreeMap<dyknow_engine::Tid, dyknow_store::spec::TransformationSpec>,
    ) -> Applied {
        Applied {
            failures: change_set
                .actions
                .iter()
                .enumerate()
                .filter_map(|(k, a)| match a {
                    Action::Destroy { cu } => Some(ActionFailure {
                        action: k,
                        cu: cu.clone(),
                        reason: "the CU does not answer".to_owned(),
                    }),
                    _ => None,
                })
                .collect(),
            cus: Default::default(),
        }
    }
}

#[test]
fn a_destroy_the_executor_refuses_is_an_error_and_recorded() {
    let manager =
        Manager::new(example_12(), Arc::new(RefusesDestroy), Settings::default()).unwrap();
    let cu = manager.spawn(SpawnRequest::new("tid3")).unwrap();
    let refused = manager.destroy(&cu.cid);
    assert!(
        matches!(&refused, Err(LifecycleError::NotApplied { cu: c, .. }) if *c == cu.cid),
        "{refused:?}"
    );
    // Recorded as failed; the CU is treated as crashed (out of the model), and the next
    // review has the crash as its cause.
    let last = manager.change_sets(None).last().cloned().unwrap();
    assert_eq!(last.status, ChangeSetStatus::Failed);
    assert_eq!(cu_of(&manager, "tid3"), None);
    assert!(manager.status().next_review_at <= SystemTime::now() + Duration::from_millis(100));
}

#[test]
fn an_unreadable_change_set_record_is_left_out_and_its_number_kept() {
    let kb = example_12();
    // A record that a later release (or damage) made unreadable: cs-7.
    let bad = dyknow_store::parse_triples(
        br#"<urn:dyknow:changeset:cs-7> a <http://www.dyknow.eu/ontology/dyknow#ChangeSet> ;
              <http://www.w3.org/2000/01/rdf-schema#label> "cs-7" ;
              <http://www.dyknow.eu/ontology/dyknow-ros#changeSetJson> "{\"id\": \"cs-7\", \"cause\": {\"kind\": \"meteor\"}}" ."#,
        InputFormat::Turtle,
    )
    .unwrap();
    kb.set_environment(&[(dyknow_store::EnvironmentPart::ChangeSet("cs-7".into()), bad)])
        .unwrap();
    let records = dyknow_store::model::change_sets(&kb).unwrap();
    assert!(records.change_sets.is_empty());
    assert_eq!(records.unreadable.len(), 1);
    assert_eq!(records.unreadable[0].id, Some("cs-7".into()));
    // The service starts, and never numbers a change set cs-7 again.
    let manager = Manager::new(kb, Arc::new(ModelOnly), Settings::default()).unwrap();
    assert!(manager.change_sets(None).is_empty());
    let cu = manager.spawn(SpawnRequest::new("tid3")).unwrap();
    assert_eq!(cu.tid, "tid3");
    assert_eq!(manager.change_sets(None)[0].id, "cs-8");
}

/// An executor that places every spawned CU on executor `x` and can adopt and stop CUs, as
/// the fleet does.
#[derive(Default)]
struct Placing {
    placement: Mutex<std::collections::BTreeMap<Cid, String>>,
    applied: Mutex<Vec<ChangeSet>>,
    stopped: Mutex<Vec<(String, Cid, u64)>>,
}

impl Executor for Placing {
    fn apply(
        &self,
        change_set: &ChangeSet,
        _: &std::collections::BTreeMap<dyknow_engine::Tid, dyknow_store::spec::TransformationSpec>,
    ) -> Applied {
        self.applied.lock().unwrap().push(change_set.clone());
        let mut placement = self.placement.lock().unwrap();
        for action in &change_set.actions {
            match action {
                Action::Spawn { cu, .. } => {
                    placement.insert(cu.clone(), "x".to_owned());
                }
                Action::Destroy { cu } => {
                    placement.remove(cu);
                }
                _ => {}
            }
        }
        Applied::all()
    }

    fn placed(&self, cu: &Cid) -> Option<String> {
        self.placement.lock().unwrap().get(cu).cloned()
    }

    /// As the fleet says: running where placed, else `crashed` with no executor.
    fn describe(&self, cu: &Cid) -> Option<dyknow_lifecycle::CuView> {
        let executor = self.placed(cu);
        Some(dyknow_lifecycle::CuView {
            state: if executor.is_some() {
                "running"
            } else {
                "crashed"
            }
            .to_owned(),
            executor,
            statistics: serde_json::json!({}),
            pid: None,
        })
    }

    fn adopt(&self, executor: &str, cus: &[Cid]) {
        let mut placement = self.placement.lock().unwrap();
        for cu in cus {
            placement.insert(cu.clone(), executor.to_owned());
        }
    }

    fn stop(&self, executor: &str, cus: &[Cid], generation: u64) -> Vec<(Cid, String)> {
        let mut stopped = self.stopped.lock().unwrap();
        for cu in cus {
            stopped.push((executor.to_owned(), cu.clone(), generation));
        }
        Vec::new()
    }
}

#[test]
fn a_restarted_manager_adopts_stops_and_respawns() {
    let kb = example_12();
    let first = Manager::new(
        kb.clone(),
        Arc::new(Placing::default()),
        Settings::default(),
    )
    .unwrap();
    let kept = first.spawn(SpawnRequest::new("tid3")).unwrap();
    let rewired = first.spawn(SpawnRequest::new("tid3")).unwrap();
    let lost = first.spawn(SpawnRequest::new("tid3")).unwrap();
    let model_before = first.load().unwrap().env.cus;
    drop(first);

    // The restart: nothing is placed until the executors report.
    let executor = Arc::new(Placing::default());
    let manager = Manager::new(kb, executor.clone(), Settings::default()).unwrap();
    manager.hold_reviews();
    assert!(manager.starting());
    assert!(!manager.all_placed().unwrap());
    // Not yet reported is not crashed: until the start-up pass, such a CU is `starting`.
    let unreported = |manager: &Manager| {
        let views = manager.last_heard(std::slice::from_ref(&lost.cid));
        assert_eq!(views.get(&lost.cid), manager.describe(&lost.cid).as_ref());
        let view = manager.describe(&lost.cid).unwrap();
        assert_eq!(view.executor, None);
        view.state
    };
    assert_eq!(unreported(&manager), "starting");
    let report = |cu: &dyknow_engine::ComputationUnit| dyknow_lifecycle::ReportedCu {
        cu: cu.cid.clone(),
        transformation: cu.tid.clone(),
        inputs: cu.inputs.clone(),
        outputs: cu.outputs.clone(),
        generation: 1,
    };
    // Executor x runs `kept` as the model has it, `rewired` with an output bound elsewhere,
    // and `ghost`, which the model never had (a change set the old manager did not record).
    let mut wrong = report(&rewired);
    let port = wrong.outputs.keys().next().unwrap().clone();
    wrong.outputs.insert(port.clone(), Some("elsewhere".into()));
    let ghost = dyknow_lifecycle::ReportedCu {
        cu: "ghost".into(),
        transformation: "tid3".into(),
        inputs: Default::default(),
        outputs: Default::default(),
        generation: 9,
    };
    let change_set = manager
        .reconcile(Some("x"), vec![report(&kept), wrong, ghost], false)
        .unwrap()
        .expect("a reconcile change set");
    assert_eq!(
        change_set.cause,
        Cause::Reconcile {
            executor: Some("x".to_owned())
        }
    );
    assert_eq!(change_set.status, ChangeSetStatus::Applied);
    assert_eq!(
        change_set.actions,
        [
            Action::Destroy { cu: "ghost".into() },
            Action::DisconnectOut {
                cu: rewired.cid.clone(),
                port
            },
        ]
    );
    let generation = change_set.id.number().unwrap();
    assert_eq!(
        *executor.stopped.lock().unwrap(),
        [("x".to_owned(), Cid::from("ghost"), generation)]
    );
    // The executor was given only the correction: the stop was carried out directly.
    assert_eq!(
        executor.applied.lock().unwrap().last().unwrap().actions,
        change_set.actions[1..]
    );
    let running = CuOutcome {
        executor: Some("x".to_owned()),
        state: CuOutcomeState::Running,
    };
    assert_eq!(change_set.cus[&kept.cid], running);
    assert_eq!(change_set.cus[&rewired.cid], running);
    assert_eq!(
        change_set.cus[&Cid::from("ghost")].state,
        CuOutcomeState::Stopped
    );
    assert_eq!(manager.describe(&kept.cid).unwrap().state, "running");
    assert_eq!(executor.placed(&kept.cid).as_deref(), Some("x"));
    assert!(manager.starting(), "only the start-up pass ends the hold");
    assert_eq!(unreported(&manager), "starting");

    // The start-up pass: `lost` runs nowhere and is spawned again under its name.
    let respawn = manager
        .reconcile(None, Vec::new(), true)
        .unwrap()
        .expect("a respawn");
    assert_eq!(respawn.cause, Cause::Reconcile { executor: None });
    assert_eq!(
        respawn.actions,
        [Action::Spawn {
            cu: lost.cid.clone(),
            transformation: "tid3".into()
        }]
    );
    assert!(!manager.starting());
    assert!(manager.all_placed().unwrap());
    // After it, a CU no executor hosts is `crashed` again.
    executor.placement.lock().unwrap().remove(&lost.cid);
    assert_eq!(unreported(&manager), "crashed");
    executor
        .placement
        .lock()
        .unwrap()
        .insert(lost.cid.clone(), "x".into());
    // The model is what it was, the history has no gap, and "ghost" is never handed out.
    assert_eq!(manager.load().unwrap().env.cus, model_before);
    let ids: Vec<u64> = manager
        .change_sets(None)
        .iter()
        .map(|c| c.id.number().unwrap())
        .collect();
    assert_eq!(ids, (1..=ids.len() as u64).collect::<Vec<_>>());
    // Nothing left to reconcile: no change set.
    assert!(
        manager
            .reconcile(Some("x"), vec![report(&kept)], true)
            .unwrap()
            .is_none()
    );
}

#[test]
fn an_event_about_a_cu_on_another_executor_is_ignored() {
    use dyknow_cu::protocol::Event;
    use dyknow_lifecycle::{FleetEvent, executor_event};
    let crash = || Event::CuCrashed {
        cu: "cu-1".into(),
        transformation: "t".into(),
        reason: "boom".into(),
    };
    let upkeep = || Event::Upkeep {
        cu: "cu-1".into(),
        transformation: "t".into(),
        cpu_ms: 1e9,
        over_ms: 1.0,
    };
    // A peer that does not host the CU can neither crash it nor skew its costs.
    assert_eq!(executor_event("rogue", Some("a"), crash()), None);
    assert_eq!(executor_event("rogue", Some("a"), upkeep()), None);
    let crashed = FleetEvent::Crashed {
        cu: "cu-1".into(),
        reason: "boom".into(),
    };
    assert_eq!(executor_event("a", Some("a"), crash()), Some(crashed));
    // A CU placed nowhere (not spawned by this manager, or before reconciliation): ignored.
    assert_eq!(executor_event("a", None, crash()), None);
    assert_eq!(executor_event("a", None, upkeep()), None);
}

#[test]
fn the_cus_of_a_vanished_executor_crash_together_and_one_review_names_them_all() {
    let manager = Manager::new(example_12(), Arc::new(ModelOnly), Settings::default()).unwrap();
    manager.review().unwrap();
    let cus: Vec<Cid> = manager.load().unwrap().env.cus.keys().cloned().collect();
    assert!(cus.len() >= 2, "{cus:?}");
    let lost = cus[..2].to_vec();
    // One event for every CU placed on the executor (one the model lacks is skipped).
    let mut placed = lost.clone();
    placed.push("no-such-cu".into());
    let vanished = FleetEvent::Vanished {
        executor: "x".into(),
        cus: placed,
    };
    assert_eq!(manager.handle(vanished).unwrap(), None);
    // Both left the model at once: a review that starts now sees every crash, and is due.
    let env = manager.load().unwrap().env;
    assert!(lost.iter().all(|cu| !env.cus.contains_key(cu)), "{env:?}");
    assert!(manager.status().review_pending);
    // A target reported before the review began is a cause of it too, named after the crashes.
    add_qid1(&manager);
    let repair = manager.review().unwrap().expect("a repair");
    let Cause::CuCrashed { cu, also } = &repair.cause else {
        panic!("{:?}", repair.cause);
    };
    let named: BTreeSet<&Cid> = std::iter::once(cu).chain(also).collect();
    assert_eq!(named, lost.iter().collect(), "{:?}", repair.cause);
    assert_eq!(
        repair.other_causes,
        [Cause::TargetAdded {
            target: "qid1".into()
        }]
    );
    let loaded = manager.load().unwrap();
    assert!(loaded.env.invalidities(&loaded.candidates).is_empty());
    // Nothing the model lacks: nothing happens.
    let unknown = FleetEvent::Vanished {
        executor: "x".into(),
        cus: vec!["no-such-cu".into()],
    };
    let before = manager.change_sets(None).len();
    assert_eq!(manager.handle(unknown).unwrap(), None);
    assert!(manager.review().unwrap().is_none());
    assert_eq!(manager.change_sets(None).len(), before);
}

/// Applying every change set's delta in turn gives the model, crashes included: the CUs a
/// crash (or a spec change) removed, outside any change set, leave with the next change set's
/// delta (a client mirroring the model from the change sets kept crashed CUs for ever).
#[test]
fn the_change_sets_deltas_in_turn_give_the_model_crashes_included() {
    let manager = Manager::new(example_12(), Arc::new(ModelOnly), Settings::default()).unwrap();
    manager.review().unwrap();
    let cus: Vec<Cid> = manager.load().unwrap().env.cus.keys().cloned().collect();
    assert!(cus.len() >= 2, "{cus:?}");
    let vanished = FleetEvent::Vanished {
        executor: "x".into(),
        cus: cus[..1].to_vec(),
    };
    manager.handle(vanished).unwrap();
    manager.review().unwrap().expect("a repair");
    manager
        .report(Perturbation::CuCrashed { cu: cus[1].clone() })
        .unwrap();
    let repair = manager.review().unwrap().expect("a repair");
    assert!(
        repair.delta.delete.contains(cus[1].as_str()),
        "the repair's delta deletes the crashed CU: {}",
        repair.delta.delete
    );
    let mut mirror: BTreeSet<String> = BTreeSet::new();
    for cs in manager.change_sets(None) {
        for line in cs.delta.delete.lines() {
            mirror.remove(line);
        }
        mirror.extend(cs.delta.insert.lines().map(str::to_owned));
    }
    let loaded = manager.load().unwrap();
    let model: BTreeSet<String> = dyknow_store::model::delta(
        &dyknow_engine::Environment::default(),
        &loaded.env,
        &loaded.iris,
    )
    .ntriples()
    .insert
    .lines()
    .map(str::to_owned)
    .collect();
    assert!(!model.is_empty());
    assert_eq!(mirror, model);
}

#[test]
fn what_executors_send_is_handled_without_trusting_it() {
    use dyknow_lifecycle::{FleetEvent, Observation};
    let manager = Manager::new(example_12(), Arc::new(ModelOnly), Settings::default()).unwrap();
    manager.review().unwrap();
    let before = manager.change_sets(None).len();
    // The crash of a CU the model does not have: nothing happens.
    let unknown = FleetEvent::Crashed {
        cu: "no-such-cu".into(),
        reason: "rogue".into(),
    };
    assert_eq!(manager.handle(unknown).unwrap(), None);
    // Upkeep over an interval that is not positive gives no observation.
    for over_ms in [0.0, -5.0] {
        let upkeep = FleetEvent::Upkeep {
            cu: "no-such-cu".into(),
            cpu_ms: 1.0,
            over_ms,
        };
        assert_eq!(manager.handle(upkeep).unwrap(), None);
    }
    // Observations that are not finite and non-negative are not recorded.
    let hostile = [f64::INFINITY, -1.0, f64::NAN].map(|value| Observation::Labour {
        transformation: "tid3".into(),
        value,
    });
    assert_eq!(manager.observe_all(hostile.to_vec()).unwrap(), 0);
    // An unknown executor claiming CUs the model does not have: they are stopped (ModelOnly
    // has nothing to stop) and nothing in the model changes.
    let cus = manager.load().unwrap().env.cus.len();
    let appeared = FleetEvent::Appeared {
        executor: "rogue".into(),
        cus: vec![dyknow_lifecycle::ReportedCu {
            cu: "stray".into(),
            transformation: "tid3".into(),
            inputs: Default::default(),
            outputs: Default::default(),
            generation: u64::MAX,
        }],
    };
    manager.handle(appeared).unwrap();
    assert_eq!(manager.load().unwrap().env.cus.len(), cus);
    let history = manager.change_sets(None);
    assert!(history.len() <= before + 1);
    for (i, c) in history.iter().enumerate() {
        assert_eq!(c.id.number(), Some(i as u64 + 1));
    }
}

/// The ids of the change sets the history keeps, oldest first.
fn history_ids(manager: &Manager) -> Vec<String> {
    manager
        .change_sets(None)
        .iter()
        .map(|c| c.id.to_string())
        .collect()
}

/// The change-set graphs in the store.
fn recorded_graphs(kb: &KnowledgeBase) -> usize {
    kb.store()
        .named_graphs()
        .filter(|g| {
            g.as_ref()
                .is_ok_and(|g| g.to_string().contains("environment:changeset:"))
        })
        .count()
}

#[test]
fn the_history_keeps_the_last_change_sets_and_the_names_they_used_stay_reserved() {
    let kb = example_12();
    let unlimited = Settings {
        history_limit: 0,
        ..Settings::default()
    };
    let manager = Manager::new(kb.clone(), Arc::new(ModelOnly), unlimited).unwrap();
    let first = manager.spawn(SpawnRequest::new("tid3")).unwrap();
    manager.destroy(&first.cid).unwrap();
    manager
        .spawn(SpawnRequest::new("tid3").named("camera"))
        .unwrap();
    assert_eq!(manager.change_sets(None).len(), 3);
    drop(manager);
    // Restarted with a limit of 1: the two oldest are pruned at start-up, from the store too,
    // and the one left names only `camera`; the minted name of the pruned ones stays taken.
    let limited = Settings {
        history_limit: 1,
        ..Settings::default()
    };
    let manager = Manager::new(kb.clone(), Arc::new(ModelOnly), limited).unwrap();
    let ids = history_ids(&manager);
    assert_eq!(ids, ["cs-3"]);
    assert_eq!(recorded_graphs(&kb), 1);
    assert_eq!(
        dyknow_store::model::reserved_names(&kb).unwrap(),
        [first.cid.to_string()]
    );
    let second = manager.spawn(SpawnRequest::new("tid3")).unwrap();
    assert!(
        second.cid.minted_number() > first.cid.minted_number(),
        "{} after {}",
        second.cid,
        first.cid
    );
    // Recording prunes in the same write: still one record, numbers go on.
    manager.destroy(&second.cid).unwrap();
    let ids = history_ids(&manager);
    assert_eq!(ids, ["cs-5"]);
    assert_eq!(recorded_graphs(&kb), 1);
    // `since` an id pruned meanwhile gives what is kept.
    assert_eq!(manager.change_sets(Some("cs-1")).len(), 1);
    assert!(manager.change_set("cs-1").is_none());
    drop(manager);
    let manager = Manager::new(kb.clone(), Arc::new(ModelOnly), limited).unwrap();
    let third = manager.spawn(SpawnRequest::new("tid3")).unwrap();
    assert!(third.cid.minted_number() > second.cid.minted_number());
    assert_eq!(
        manager.change_sets(None).last().unwrap().id.to_string(),
        "cs-6"
    );
    // Pruned records leave no trace in the inferred graph either.
    let (extra, missing) = kb.materialisation_drift().unwrap();
    assert!(
        extra.is_empty() && missing.is_empty(),
        "{extra:?} {missing:?}"
    );
}

/// An executor whose transformations can all run, or none but `except`.
#[derive(Default)]
struct Switchable {
    down: std::sync::atomic::AtomicBool,
    except: Option<&'static str>,
}

impl Executor for Switchable {
    fn apply(
        &self,
        change_set: &ChangeSet,
        specs: &std::collections::BTreeMap<
            dyknow_engine::Tid,
            dyknow_store::spec::TransformationSpec,
        >,
    ) -> Applied {
        ModelOnly.apply(change_set, specs)
    }

    fn runnable(&self, spec: &dyknow_store::spec::TransformationSpec) -> Result<(), String> {
        if self.down.load(std::sync::atomic::Ordering::SeqCst)
            && self.except != Some(spec.label.as_str())
        {
            Err("no executor is present".into())
        } else {
            Ok(())
        }
    }
}

/// Configures the environment, then loses every CU with the only executor, whose
/// transformations then cannot run: the review finds nothing to do. Returns the lost CUs.
fn lose_everything(manager: &Manager, executor: &Switchable) -> Vec<Cid> {
    use std::sync::atomic::Ordering;
    assert!(
        manager.review().unwrap().is_some(),
        "the first configuration"
    );
    let lost: Vec<Cid> = manager.load().unwrap().env.cus.keys().cloned().collect();
    executor.down.store(true, Ordering::SeqCst);
    manager.executors_changed().unwrap();
    let vanished = FleetEvent::Vanished {
        executor: "x".into(),
        cus: lost.clone(),
    };
    assert_eq!(manager.handle(vanished).unwrap(), None);
    assert!(manager.review().unwrap().is_none(), "nothing can run");
    lost
}

/// Brings the executor back: the review that follows repairs every CU of `lost`, and its
/// cause names each.
fn repaired_when_back(manager: &Manager, executor: &Switchable, lost: &[Cid]) {
    executor
        .down
        .store(false, std::sync::atomic::Ordering::SeqCst);
    manager.executors_changed().unwrap();
    let repair = manager.review().unwrap().unwrap();
    let Cause::CuCrashed { cu, also } = &repair.cause else {
        panic!("{:?}", repair.cause);
    };
    let named: BTreeSet<&Cid> = std::iter::once(cu).chain(also).collect();
    assert_eq!(named, lost.iter().collect(), "{:?}", repair.cause);
}

/// CUs lost with the only executor cannot be repaired until one is back: the reviews that
/// find nothing to do meanwhile keep the crashes, and the review that repairs them names
/// them (before, it said only "review").
#[test]
fn crashes_no_review_could_repair_are_the_cause_of_the_review_that_does() {
    let executor = Arc::new(Switchable::default());
    let manager = Manager::new(example_12(), executor.clone(), Settings::default()).unwrap();
    let lost = lose_everything(&manager, &executor);
    assert!(manager.review().unwrap().is_none(), "still nothing");
    repaired_when_back(&manager, &executor, &lost);
    // Repaired: the next review has nothing to do, and no cause left over.
    assert!(manager.review().unwrap().is_none());
}

/// A kept crash is the cause only of the change set that repairs it: a target added while the
/// crashed CUs cannot run gets its own change set, caused by the target (before, it was named
/// after a crash it did not repair, and the repair that came later said "review").
#[test]
fn a_change_set_that_repairs_no_kept_crash_is_not_named_after_one() {
    let executor = Arc::new(Switchable {
        except: Some("fresh"),
        ..Switchable::default()
    });
    let kb = example_12();
    let manager = Manager::new(kb.clone(), executor.clone(), Settings::default()).unwrap();
    let lost = lose_everything(&manager, &executor);
    // A source that can run, and a target it satisfies.
    let fresh = r#"
        @prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
        @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
        @prefix ex: <http://example.org/ex12#> .
        [] a dyknow:Transformation ; rdfs:label "fresh" ;
           dyknow:hasOutPort [ a dyknow:OutPort ; dyknow:hasName "out" ;
                               dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription ex:Z ] ] .
        [] a dyknow:Target ; rdfs:label "qz" ;
           dyknow:hasChannel [ a dyknow:Channel ; dyknow:hasChannelName "109" ] ;
           dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription ex:Z ] .
    "#;
    kb.load_document(fresh.as_bytes(), InputFormat::Turtle)
        .unwrap();
    manager.executors_changed().unwrap();
    manager
        .report(Perturbation::TargetAdded {
            target: "qz".into(),
        })
        .unwrap();
    let added = manager.review().unwrap().expect("qz is satisfied");
    assert_eq!(
        added.cause,
        Cause::TargetAdded {
            target: "qz".into()
        },
        "{added:?}"
    );
    repaired_when_back(&manager, &executor, &lost);
    assert!(manager.review().unwrap().is_none());
}

/// Reports target qid1 added.
fn add_qid1(manager: &Manager) {
    manager
        .report(Perturbation::TargetAdded {
            target: "qid1".into(),
        })
        .unwrap();
}

/// Every CU graph of `kb` (`cus` of them) says what the model says of its CU: nothing left
/// for the start-up pass to rewrite.
fn assert_in_step(kb: &KnowledgeBase, cus: usize) {
    let loaded = dyknow_store::model::load(kb).unwrap();
    assert_eq!(loaded.env.cus.len(), cus);
    let stale = dyknow_store::model::resync(kb, &loaded.env, &loaded.iris, None).unwrap();
    for (part, should) in &stale {
        let stored = kb.graph_triples(part.graph().as_ref()).unwrap();
        let extra: Vec<_> = stored.iter().filter(|t| !should.contains(t)).collect();
        let missing: Vec<_> = should.iter().filter(|t| !stored.contains(t)).collect();
        eprintln!("{part:?}: extra {extra:#?} missing {missing:#?}");
    }
    assert!(stale.is_empty(), "{stale:?}");
}

/// tid4 (a source, `f4()`) posted again with a parameter: another implementation.
const TID4_WITH_A_PARAMETER: &str = r#"
@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
@prefix dkros:  <http://www.dyknow.eu/ontology/dyknow-ros#> .
@prefix rdfs:   <http://www.w3.org/2000/01/rdf-schema#> .
@prefix ex:     <http://example.org/ex12#> .
[] a dyknow:Transformation ;
   rdfs:label "tid4" ;
   dyknow:hasOutPort [ a dyknow:OutPort ; dyknow:hasName "out" ;
                       dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription ex:F ] ] ;
   dkros:hasParam [ a dyknow:Parameter ; dyknow:hasName "rate" ; dyknow:hasValue 5 ] ;
   dyknow:hasCostModel [ a dyknow:LabourCostModel ; dyknow:hasValue 1.0 ] ,
                       [ a dyknow:UpkeepCostModel ; dyknow:hasValue 1.0 ] .
"#;

fn post_tid4_with_a_parameter(kb: &KnowledgeBase) {
    kb.post_specs(
        TID4_WITH_A_PARAMETER.as_bytes(),
        InputFormat::Turtle,
        SpecKind::Transformation,
    )
    .unwrap();
}

/// Posts `spec` while it applies the first change set that spawns `on`: a spec written
/// between a review's read of the specs and its record. Records the number of parameters each
/// spawn of `on` was given.
struct RespecifiesWhileSpawning {
    kb: Arc<KnowledgeBase>,
    on: &'static str,
    spec: &'static str,
    posted: std::sync::atomic::AtomicBool,
    spawns: Mutex<Vec<(Cid, usize)>>,
}

impl RespecifiesWhileSpawning {
    fn new(kb: &Arc<KnowledgeBase>, on: &'static str, spec: &'static str) -> Arc<Self> {
        Arc::new(Self {
            kb: kb.clone(),
            on,
            spec,
            posted: false.into(),
            spawns: Mutex::default(),
        })
    }
}

impl Executor for RespecifiesWhileSpawning {
    fn apply(
        &self,
        change_set: &ChangeSet,
        specs: &std::collections::BTreeMap<
            dyknow_engine::Tid,
            dyknow_store::spec::TransformationSpec,
        >,
    ) -> Applied {
        for action in &change_set.actions {
            if let Action::Spawn { cu, transformation } = action
                && transformation == self.on
            {
                let params = specs[transformation].params.len();
                self.spawns.lock().unwrap().push((cu.clone(), params));
                if !self.posted.swap(true, std::sync::atomic::Ordering::SeqCst) {
                    self.kb
                        .post_specs(
                            self.spec.as_bytes(),
                            InputFormat::Turtle,
                            SpecKind::Transformation,
                        )
                        .unwrap();
                }
            }
        }
        Applied::default()
    }
}

#[test]
fn a_cu_spawned_from_a_spec_replaced_meanwhile_is_replaced() {
    let kb = example_12();
    let executor = RespecifiesWhileSpawning::new(&kb, "tid4", TID4_WITH_A_PARAMETER);
    let manager = Manager::new(kb, executor.clone(), Settings::default()).unwrap();
    add_qid1(&manager);
    let first = manager.review().unwrap().expect("a change set");
    assert_eq!(first.status, ChangeSetStatus::Applied);
    let spawns = executor.spawns.lock().unwrap().clone();
    assert_eq!(spawns.len(), 1, "{spawns:?}");
    let (old, params) = &spawns[0];
    assert_eq!(*params, 0, "spawned from the spec read before the write");
    // The spec changed while it was spawned: it left the model, and the next review is due
    // at once, with the spec change as the cause (not a crash: none is counted).
    assert_eq!(cu_of(&manager, "tid4"), None);
    assert!(manager.status().review_pending, "{:?}", manager.status());
    assert_eq!(manager.status().crashes, 0);
    let repair = manager.review().unwrap().expect("a repair");
    assert!(
        matches!(&repair.cause, Cause::SpecChanged { cus } if cus == std::slice::from_ref(old)),
        "{:?}",
        repair.cause
    );
    let spawns = executor.spawns.lock().unwrap().clone();
    assert_eq!(spawns.len(), 2, "{spawns:?}");
    assert_eq!(spawns[1].1, 1, "spawned from the new spec");
    assert_eq!(cu_of(&manager, "tid4"), Some(spawns[1].0.clone()));
    assert_eq!(manager.review().unwrap(), None, "nothing more to do");
}

#[test]
fn a_spec_posted_after_a_spawn_names_the_cus_it_makes_stale() {
    let kb = example_12();
    let manager = Manager::new(kb.clone(), Arc::new(ModelOnly), Settings::default()).unwrap();
    add_qid1(&manager);
    manager.review().unwrap().expect("a change set");
    let cu = cu_of(&manager, "tid4").expect("tid4 runs");
    let spec = |kb: &KnowledgeBase| match kb.spec(SpecKind::Transformation, "tid4").unwrap() {
        Some(Spec::Transformation(t)) => t,
        other => panic!("{other:?}"),
    };
    let none = BTreeSet::new();
    // The same implementation (costs aside): nothing stale.
    let same = spec(&kb).implementation();
    assert!(
        manager
            .stale_after_post(&[("tid4".into(), same.clone())], &none)
            .is_empty()
    );
    post_tid4_with_a_parameter(&kb);
    let other = spec(&kb).implementation();
    // Compared with what it was started with, not with the stored spec (the caller's
    // comparison with the stored one, `changed`, is for CUs from before start-up).
    assert_eq!(
        manager.stale_after_post(&[("tid4".into(), other.clone())], &none),
        vec![cu.clone()]
    );
    assert!(
        manager
            .stale_after_post(&[("tid1".into(), same)], &none)
            .is_empty(),
        "tid1 runs the implementation it was started with"
    );
    // After a restart, the CU is from before start-up: only `changed` names it.
    let restarted = Manager::new(kb, Arc::new(ModelOnly), Settings::default()).unwrap();
    assert!(
        restarted
            .stale_after_post(&[("tid4".into(), other.clone())], &none)
            .is_empty()
    );
    let changed: BTreeSet<dyknow_engine::Tid> = ["tid4".into()].into();
    assert_eq!(
        restarted.stale_after_post(&[("tid4".into(), other)], &changed),
        vec![cu.clone()]
    );
    restarted.replace_stale(std::slice::from_ref(&cu)).unwrap();
    assert_eq!(cu_of(&restarted, "tid4"), None);
    let repair = restarted.review().unwrap().expect("a repair");
    assert!(matches!(&repair.cause, Cause::SpecChanged { cus } if *cus == [cu.clone()]));
    assert!(cu_of(&restarted, "tid4").is_some_and(|new| new != cu));
}

#[test]
fn a_cu_spawned_from_a_spec_whose_port_was_renamed_meanwhile_is_brought_in_step() {
    // tid1 posted again with its in port renamed: the same implementation, so the CU stays,
    // but its subscription, written from the spec read before, names a port that is gone.
    const TID1_RENAMED: &str = r#"
    @prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
    @prefix rdfs:   <http://www.w3.org/2000/01/rdf-schema#> .
    @prefix ex:     <http://example.org/ex12#> .
    [] a dyknow:Transformation ;
       rdfs:label "tid1" ;
       dyknow:hasInPort  [ a dyknow:InPort ;  dyknow:hasName "input" ;
                           dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription ex:A ] ] ;
       dyknow:hasOutPort [ a dyknow:OutPort ; dyknow:hasName "out" ;
                           dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription ex:B ] ] ;
       dyknow:hasCostModel [ a dyknow:LabourCostModel ; dyknow:hasValue 1.0 ] ,
                           [ a dyknow:UpkeepCostModel ; dyknow:hasValue 1.0 ] .
    "#;
    let kb = example_12();
    let executor = RespecifiesWhileSpawning::new(&kb, "tid1", TID1_RENAMED);
    let manager = Manager::new(kb.clone(), executor.clone(), Settings::default()).unwrap();
    add_qid1(&manager);
    let first = manager.review().unwrap().expect("a change set");
    assert_eq!(first.status, ChangeSetStatus::Applied);
    assert!(executor.posted.load(std::sync::atomic::Ordering::SeqCst));
    let cu = cu_of(&manager, "tid1").expect("tid1 stays: its implementation is the same");
    assert_eq!(executor.spawns.lock().unwrap()[0].0, cu);
    // Every CU graph says what the model says of its CU: nothing left for a repair.
    assert_in_step(&kb, 3);
}

#[test]
fn the_cu_graphs_a_review_writes_read_back_as_written() {
    // A CU graph compared with what the store holds (at every start-up, after every spec
    // write) differs only where the model does: the store gives an `xsd:double` back by
    // value (`"1"`), so one written as `"1.0"` read as changed, and every CU graph was
    // rewritten at every start.
    let kb = example_12();
    let manager = Manager::new(kb.clone(), Arc::new(ModelOnly), Settings::default()).unwrap();
    add_qid1(&manager);
    manager.review().unwrap().expect("a change set");
    assert_in_step(&kb, 3);
}

#[test]
fn a_protected_cu_is_never_stale_whatever_its_name_ran_before() {
    // A CU spawned, crashed, and its name spawned again, protected, of another transformation:
    // a spec posted for the first one's transformation names nothing (the record of the first
    // stayed and removed the protected CU: a code review).
    let kb = example_12();
    let manager = Manager::new(kb.clone(), Arc::new(ModelOnly), Settings::default()).unwrap();
    let foo = manager
        .spawn(SpawnRequest::new("tid4").named("foo"))
        .unwrap()
        .cid;
    manager
        .report(Perturbation::CuCrashed { cu: foo.clone() })
        .unwrap();
    manager
        .spawn(SpawnRequest::new("tid3").named("foo").protected(true))
        .unwrap();
    post_tid4_with_a_parameter(&kb);
    let other = match kb.spec(SpecKind::Transformation, "tid4").unwrap() {
        Some(Spec::Transformation(t)) => t.implementation(),
        other => panic!("{other:?}"),
    };
    let none = BTreeSet::new();
    assert!(
        manager
            .stale_after_post(&[("tid4".into(), other.clone())], &none)
            .is_empty()
    );
    // Nor is a protected CU of the transformation itself.
    let kept = manager
        .spawn(SpawnRequest::new("tid4").named("kept").protected(true))
        .unwrap()
        .cid;
    let changed: BTreeSet<dyknow_engine::Tid> = ["tid4".into()].into();
    assert!(
        !manager
            .stale_after_post(&[("tid4".into(), other)], &changed)
            .contains(&kept)
    );
}
