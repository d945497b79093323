//! The seam between the life-cycle and the running system: an [`Executor`] applies the change
//! sets the life-cycle decides to real computation units (the seed's nodelet proxy, Ch.
//! 5.2.1–5.3), says which actions it could not apply, and says which transformations it can
//! run at all (a transformation no executor can run is never planned).

use std::collections::BTreeMap;

use dyknow_engine::{ActionFailure, ChangeSet, Channel, Cid, CuOutcome, Tid};
use dyknow_store::spec::TransformationSpec;
use serde::Serialize;

/// What an executor did with a change set.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Applied {
    /// The actions that failed, with their CU and why; empty when every action was applied.
    pub failures: Vec<ActionFailure>,
    /// The CUs its actions touched, with the executor hosting each and its state after it
    /// (empty when nothing runs).
    pub cus: BTreeMap<Cid, CuOutcome>,
}

impl Applied {
    /// Every action was applied.
    pub fn all() -> Self {
        Self::default()
    }
}

/// A CU as the running system sees it (`GET /cus/{name}`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CuView {
    /// The executor hosting it.
    pub executor: Option<String>,
    /// `starting`, `running`, `crashed`, `stopped`, or `model` in model-only mode.
    pub state: String,
    /// Its statistics (`uptime_ms`, `reconfigurations`, `cpu_ms`, `ports`).
    pub statistics: serde_json::Value,
    /// The process id of a process CU.
    pub pid: Option<u32>,
}

/// A CU an executor says it runs (its `info`), as reconciliation sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReportedCu {
    /// The CU.
    pub cu: Cid,
    /// Its transformation.
    pub transformation: Tid,
    /// In port → channel, as bound.
    pub inputs: BTreeMap<String, Option<Channel>>,
    /// Out port → channel, as bound.
    pub outputs: BTreeMap<String, Option<Channel>>,
    /// The generation of the last change set that configured it (0: unknown).
    pub generation: u64,
}

/// Applies change sets to the running system. The life-cycle calls [`Executor::apply`] for
/// every change set it makes (reviews, Spawn, Destroy, SetConfig), one at a time, holding its
/// configuration lock, and counts it applied when the call returns (every executor involved
/// acknowledged it); then it writes the model and records the change set with its status.
/// The CU of a failed action is treated as crashed: it leaves the model and a review repairs
/// the configuration.
pub trait Executor: Send + Sync {
    /// Applies the actions of `change_set` in order (each CU reconfigured make before break)
    /// and reports those that failed. `specs` gives the implementation of every
    /// transformation.
    fn apply(&self, change_set: &ChangeSet, specs: &BTreeMap<Tid, TransformationSpec>) -> Applied;

    /// Whether some present executor can run the transformation; why not otherwise.
    fn runnable(&self, spec: &TransformationSpec) -> Result<(), String> {
        let _ = spec;
        Ok(())
    }

    /// What the running system says of a CU; `None` when nothing runs (model-only mode).
    fn describe(&self, cu: &Cid) -> Option<CuView> {
        let _ = cu;
        None
    }

    /// Whether executors that vanished while the manager itself did not run may still come
    /// back (their CUs kept running): reviews wait until they are back or counted lost, so
    /// that none places work on them meanwhile.
    fn settling(&self) -> bool {
        false
    }

    /// The executor a CU runs on, if any (`None` in model-only mode).
    fn placed(&self, cu: &Cid) -> Option<String> {
        let _ = cu;
        None
    }

    /// Reconciliation: `executor` runs these CUs of the model, which are now placed there.
    fn adopt(&self, executor: &str, cus: &[Cid]) {
        let _ = (executor, cus);
    }

    /// Reconciliation: stops CUs `executor` runs that the model does not want there
    /// (`generation` is the reconciling change set's). Returns those it could not stop, with
    /// why.
    fn stop(&self, executor: &str, cus: &[Cid], generation: u64) -> Vec<(Cid, String)> {
        let _ = (executor, generation);
        cus.iter()
            .map(|cu| (cu.clone(), "nothing runs".to_owned()))
            .collect()
    }

    /// The model dropped these CUs though their executors did not say they ended (a client
    /// reported them crashed, or an action on them failed or was not acknowledged): they are
    /// forgotten and, where they may still run, stopped in the background, so that no orphan
    /// keeps publishing beside its replacement. Best effort: an executor that cannot be
    /// reached stops them when it reconciles.
    fn abandon(&self, cus: &[Cid]) {
        let _ = cus;
    }

    /// What the running system says of several CUs (`GET /cus?statistics=true`); those it
    /// says nothing of are missing. Executors that can answer for many CUs at once override
    /// it.
    fn describe_all(&self, cus: &[Cid]) -> BTreeMap<Cid, CuView> {
        cus.iter()
            .filter_map(|cu| Some((cu.clone(), self.describe(cu)?)))
            .collect()
    }

    /// Where several CUs run and in what state, as the manager last heard it (the
    /// acknowledgements of its change sets, the executors' events, reconciliation), without
    /// asking anyone: `GET /cus`, which must not wait behind an executor busy applying a
    /// change set. The views carry no statistics. By default what [`Executor::describe_all`]
    /// says.
    fn last_heard(&self, cus: &[Cid]) -> BTreeMap<Cid, CuView> {
        self.describe_all(cus)
    }
}

/// The executor of a service that runs no computation units (`dyknow serve --model-only`):
/// change sets change the model only, which the life-cycle writes for every executor, so
/// there is nothing more to apply, nothing fails and every transformation is runnable.
#[derive(Debug, Clone, Copy, Default)]
pub struct ModelOnly;

impl Executor for ModelOnly {
    fn apply(&self, _: &ChangeSet, _: &BTreeMap<Tid, TransformationSpec>) -> Applied {
        Applied::all()
    }
}
