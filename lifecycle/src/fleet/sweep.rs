//! The sweep: every [`SWEEP`], each present executor is asked what it hosts (its `info`
//! without statistics, [`InfoRequest`]), and the CUs the manager placed there and knows to run
//! are compared with it. A crash is an event of its executor's, sent once: one that did not
//! arrive (a crash storm audit lost 6 of 13,000) left the crashed CU in the model as running,
//! its target satisfied and silent, until a restart of the manager. A CU missing from two
//! answers in a row, placed on that executor and known to run all along, and touched by no
//! change set being applied, crashed unseen: it is reported as crashed, as its lost event
//! would have (the manager removes it and a review repairs it). The same thread forgets the
//! executors absent for long ([`Inner::forget_absent`]).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Duration;

use dyknow_cu::protocol::{CuState, ExecutorInfo, InfoRequest};
use dyknow_engine::Cid;

use super::{FleetEvent, Inner, QUERY_TIMEOUT, lock};

/// How often the executors are asked.
pub(super) const SWEEP: Duration = Duration::from_secs(2);

/// Starts the sweep's thread; it ends with the fleet.
pub(super) fn start(inner: &Arc<Inner>) {
    let weak = Arc::downgrade(inner);
    let _ = std::thread::Builder::new()
        .name("fleet-sweep".into())
        .spawn(move || {
            let mut suspects = BTreeMap::new();
            loop {
                std::thread::sleep(SWEEP);
                let Some(inner) = weak.upgrade() else { return };
                if inner.swept.load(std::sync::atomic::Ordering::SeqCst) {
                    return;
                }
                inner.forget_absent();
                suspects = inner.sweep(&suspects);
            }
        });
}

impl Inner {
    /// One sweep. `suspects` are the CUs the last sweep found missing, with their executor;
    /// returns those this one found missing for the first time.
    pub(super) fn sweep(&self, suspects: &BTreeMap<Cid, String>) -> BTreeMap<Cid, String> {
        // A stalled manager hears late: nothing is concluded from what it asks now.
        if self.pulse.stalled_recently() {
            return BTreeMap::new();
        }
        let mut by_executor: BTreeMap<String, Vec<Cid>> = BTreeMap::new();
        {
            let placement = lock(&self.placement);
            let running = lock(&self.running);
            let applying = lock(&self.applying);
            for cu in running.iter().filter(|cu| !applying.contains(*cu)) {
                if let Some(executor) = placement.get(cu) {
                    by_executor
                        .entry(executor.clone())
                        .or_default()
                        .push(cu.clone());
                }
            }
        }
        let mut missing = BTreeMap::new();
        let request = serde_json::to_vec(&InfoRequest { statistics: false }).unwrap_or_default();
        for (executor, cus) in by_executor {
            let present = lock(&self.executors)
                .get(&executor)
                .is_some_and(|k| k.present);
            if !present {
                continue;
            }
            let Ok(info) = self.query_where::<ExecutorInfo>(
                &executor,
                "info",
                request.clone(),
                QUERY_TIMEOUT,
                |info| self.answered_by_holder(&executor, info),
            ) else {
                continue;
            };
            let hosted: BTreeSet<&str> = info
                .cus
                .iter()
                .filter(|c| matches!(c.state, CuState::Running | CuState::Starting))
                .map(|c| c.cu.as_str())
                .collect();
            for cu in cus {
                if !hosted.contains(cu.as_str()) {
                    missing.insert(cu, executor.clone());
                }
            }
        }
        let mut first = BTreeMap::new();
        for (cu, executor) in missing {
            if suspects.get(&cu) != Some(&executor) {
                first.insert(cu, executor);
                continue;
            }
            let confirmed = {
                let mut placement = lock(&self.placement);
                let mut running = lock(&self.running);
                let applying = lock(&self.applying);
                let still = placement.get(&cu) == Some(&executor)
                    && running.contains(&cu)
                    && !applying.contains(&cu);
                if still {
                    placement.remove(&cu);
                    running.remove(&cu);
                }
                still
            };
            if confirmed {
                let reason = format!(
                    "its executor {executor} no longer hosts it, in two answers {} s apart, and \
                     said nothing of it (a lost crash event)",
                    SWEEP.as_secs()
                );
                tracing::warn!("{cu} crashed unseen: {reason}");
                let _ = self.events.send(FleetEvent::Crashed { cu, reason });
            }
        }
        first
    }
}
