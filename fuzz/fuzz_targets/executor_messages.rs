//! Fuzz target: the manager's handling of what executors send (issue 17, item 6). Any peer
//! on the Zenoh network can publish on an executor's event key and answer an executor's `info`
//! query, so these bytes are hostile input. Each input is lines `<executor> <json>`: JSON that
//! reads as an executor event (`protocol::Event`) goes through `executor_event`, with where
//! the fleet places that CU, then `Manager::handle`; JSON that reads as an `ExecutorInfo` is
//! that executor appearing (`appeared`, then `Manager::handle`: reconciliation). The manager
//! starts each input with Example 12's pipeline running on executor `a`.
//!
//! Invariants: no panic; the change-set history stays numbered without a gap; the model still
//! loads; every learned cost is finite and not negative; a CU runs on one executor at most;
//! and an event about a CU not placed on its sender is dropped.
#![no_main]

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use dyknow_cu::protocol::{Event, ExecutorInfo};
use dyknow_engine::{Action, ChangeSet, Cid, Tid};
use dyknow_lifecycle::{
    Applied, Executor, FleetEvent, Manager, Settings, appeared, executor_event,
};
use dyknow_store::spec::TransformationSpec;
use dyknow_store::{InputFormat, KnowledgeBase};
use libfuzzer_sys::fuzz_target;

/// Places every spawned CU on executor `a`, as a fleet that always succeeds would.
#[derive(Default)]
struct Placing {
    placement: Mutex<BTreeMap<Cid, String>>,
}

impl Executor for Placing {
    fn apply(&self, change_set: &ChangeSet, _: &BTreeMap<Tid, TransformationSpec>) -> Applied {
        let mut placement = self.placement.lock().unwrap();
        for action in &change_set.actions {
            match action {
                Action::Spawn { cu, .. } => {
                    placement.insert(cu.clone(), "a".to_owned());
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

    fn adopt(&self, executor: &str, cus: &[Cid]) {
        let mut placement = self.placement.lock().unwrap();
        for cu in cus {
            placement.insert(cu.clone(), executor.to_owned());
        }
    }

    fn stop(&self, executor: &str, cus: &[Cid], _generation: u64) -> Vec<(Cid, String)> {
        let mut placement = self.placement.lock().unwrap();
        for cu in cus {
            if placement.get(cu).is_some_and(|e| e == executor) {
                placement.remove(cu);
            }
        }
        Vec::new()
    }
}

/// Example 12's library and targets, in memory (parsed once, loaded per input).
fn documents() -> &'static [Vec<u8>] {
    static DOCUMENTS: std::sync::OnceLock<Vec<Vec<u8>>> = std::sync::OnceLock::new();
    DOCUMENTS.get_or_init(|| {
        [
            "example-12-similarity.ttl",
            "example-12.ttl",
            "example-12-targets.ttl",
        ]
        .iter()
        .map(|f| {
            let path = format!("{}/../specs/turtle/{f}", env!("CARGO_MANIFEST_DIR"));
            std::fs::read(path).expect("Example 12's specs")
        })
        .collect()
    })
}

fn manager() -> (Manager, Arc<Placing>) {
    let kb = KnowledgeBase::in_memory().unwrap();
    for document in documents() {
        kb.load_document(document, InputFormat::Turtle).unwrap();
    }
    let placing = Arc::new(Placing::default());
    let manager = Manager::new(Arc::new(kb), placing.clone(), Settings::default()).unwrap();
    manager.review().unwrap();
    (manager, placing)
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let messages: Vec<(&str, &str)> = text
        .lines()
        .filter_map(|line| line.split_once(' '))
        .collect();
    if messages.is_empty() {
        return;
    }
    let (manager, placing) = manager();
    for (executor, json) in messages {
        let event = if let Ok(event) = serde_json::from_str::<Event>(json) {
            let cu = match &event {
                Event::Running { cu, .. }
                | Event::CuCrashed { cu, .. }
                | Event::Upkeep { cu, .. } => cu.clone(),
            };
            let placed = placing.placed(&Cid::from(cu.as_str()));
            let foreign = placed.as_deref() != Some(executor);
            let event = executor_event(executor, placed.as_deref(), event);
            assert_eq!(foreign, event.is_none(), "{executor}: {json}");
            event
        } else if let Ok(info) = serde_json::from_str::<ExecutorInfo>(json) {
            Some(appeared(executor, info))
        } else {
            None
        };
        let Some(event) = event else {
            continue;
        };
        let crashed = match &event {
            FleetEvent::Crashed { cu, .. } => Some(cu.clone()),
            _ => None,
        };
        if let Some(cu) = &crashed {
            placing.placement.lock().unwrap().remove(cu);
        }
        match manager.handle(event) {
            Ok(Some(observation)) => {
                let _ = manager.observe_all(vec![observation]);
            }
            Ok(None) => {}
            // Errors are answers (a store error would be a bug, but not a panic).
            Err(_) => {}
        }
    }
    let history = manager.change_sets(None);
    for (i, change_set) in history.iter().enumerate() {
        assert_eq!(
            change_set.id.number(),
            Some(i as u64 + 1),
            "the history has a gap: {:?}",
            history.iter().map(|c| c.id.to_string()).collect::<Vec<_>>()
        );
    }
    manager.load().expect("the model loads");
    let learned = manager.learned();
    for estimate in learned.labour.values().chain(learned.upkeep.values()) {
        assert!(
            estimate.average.is_finite() && estimate.average >= 0.0,
            "a learned cost {estimate:?}"
        );
    }
});
