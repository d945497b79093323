//! The manager's daemon (seed Ch. 4.3 and 5.3.2, Def. 36): reviews run EXPLORE on the live
//! environment and apply the change set they choose through the [`Executor`]; Spawn, Destroy
//! and crashes change the configuration too. All of them go through one lock, the
//! *configuration lock*, held from reading the environment to recording the outcome, so two
//! of them never hand out the same name or undo each other.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, RwLock};
use std::time::{Duration, Instant};

use dyknow_engine::{
    Action, Cause, ChangeSet, ChangeSetStatus, Channel, Cid, Compiled, ComputationUnit, CostKind,
    CostSummary, CuOutcome, CuOutcomeState, Environment, ExploreOptions, Ids, Invalidity, Learned,
    NTriplesDelta, ProbeOptions, Tid, Transformation,
};
use dyknow_store::model::{self, CuSnapshot, Loaded, SpecCache};
use dyknow_store::spec::{Implementation, SpecKind, TransformationSpec};
use dyknow_store::{EnvironmentPart, KnowledgeBase};
use tokio::sync::{Notify, broadcast};

use crate::error::LifecycleError;
use crate::executor::{CuView, Executor, ReportedCu};
use crate::fleet::FleetEvent;
use crate::history::History;
use crate::perturbation::Perturbation;
use crate::schedule::{Schedule, Status};

/// The longest CU name `POST /cus` takes, in characters (as a group label).
pub const MAX_CU_NAME: usize = 200;

/// The life-cycle's settings.
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// The horizon H (seed Def. 34), in time units.
    pub horizon: f64,
    /// The length of one time unit; the stable interval lasts H time units.
    pub time_unit: Duration,
    /// How long a review's EXPLORE may search before it settles for the best change set found
    /// (the any-time extension, Ch. 4.3.3; `"optimal": false` then). A review holds the
    /// configuration lock, so this also bounds how long Spawn, Destroy and crash reports wait.
    /// `None`: until optimality is proven.
    pub explore_timeout: Option<Duration>,
    /// Further any-time probes a review's EXPLORE runs on threads of their own beside the
    /// main search (`ProbeOptions::threads`; with a timeout only). 0: one thread per review.
    pub explore_threads: usize,
    /// Crashes the executors detect start a review at once, but not sooner than this after the
    /// last review started: a burst of crashes (a crash storm) is repaired by one review per
    /// spacing, not one per crash. Other perturbations, and crashes clients report, are not
    /// held back. Zero: one review per crash.
    pub review_spacing: Duration,
    /// How many change sets the history keeps (in the store and in memory): recording one
    /// more prunes the oldest, whose names stay reserved. 0: every change set is kept (memory
    /// and start-up time then grow with the history).
    pub history_limit: usize,
}

/// The default of [`Settings::history_limit`].
pub const DEFAULT_HISTORY_LIMIT: usize = 1000;

impl Default for Settings {
    fn default() -> Self {
        Self {
            horizon: 10.0,
            time_unit: Duration::from_secs(1),
            explore_timeout: Some(Duration::from_secs(1)),
            explore_threads: ProbeOptions::default().threads,
            review_spacing: Duration::from_millis(100),
            history_limit: DEFAULT_HISTORY_LIMIT,
        }
    }
}

/// A Spawn request: a CU of `transformation`, ports unbound.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpawnRequest {
    /// The transformation to instantiate.
    pub transformation: Tid,
    /// The CU's name; a fresh `cu-N` when absent.
    pub name: Option<Cid>,
    /// Whether change sets may destroy it.
    pub protected: bool,
}

impl SpawnRequest {
    /// A CU of `transformation`, named by the service, not protected.
    pub fn new(transformation: impl Into<Tid>) -> Self {
        Self {
            transformation: transformation.into(),
            name: None,
            protected: false,
        }
    }

    /// The same, named `name`.
    #[must_use]
    pub fn named(self, name: impl Into<Cid>) -> Self {
        Self {
            name: Some(name.into()),
            ..self
        }
    }

    /// The same, protected or not.
    #[must_use]
    pub fn protected(self, protected: bool) -> Self {
        Self { protected, ..self }
    }
}

/// An observed cost (seed Ch. 5.3.2), in the unit of the estimates.
#[derive(Debug, Clone, PartialEq)]
pub enum Observation {
    /// The upkeep of a running CU for one time unit (attributed to its transformation).
    Upkeep {
        /// The CU.
        cu: Cid,
        /// The upkeep observed.
        value: f64,
    },
    /// The labour of spawning one CU of a transformation.
    Labour {
        /// The transformation.
        transformation: Tid,
        /// The labour observed.
        value: f64,
    },
}

/// What the configuration lock guards: the minting of names. (The history is appended under
/// it too, but kept apart so that reads never wait for a review.)
#[derive(Debug)]
struct Configuration {
    ids: Ids,
}

/// A recorded change set and the environment it left in the model.
struct Committed {
    change_set: Arc<ChangeSet>,
    after: Environment,
}

impl Committed {
    /// The error for a request whose change set an executor could not apply in full.
    fn applied(&self) -> Result<(), LifecycleError> {
        match self.change_set.failures.first() {
            None => Ok(()),
            Some(failure) => Err(LifecycleError::NotApplied {
                change_set: self.change_set.id.clone(),
                cu: failure.cu.clone(),
                reason: failure.reason.clone(),
            }),
        }
    }
}

/// What reconciliation did before its change set is committed: the change set's id (taken
/// already: its number is the generation the stops carried), how many of its first actions
/// it carried out itself, and the CUs it adopted or stopped.
#[derive(Default)]
struct Reconciled {
    id: Option<dyknow_engine::ChangeSetId>,
    done: usize,
    outcomes: BTreeMap<Cid, CuOutcome>,
}

/// The life-cycle manager: owns the configuration of one knowledge base, driven by
/// [`Manager::run`] and by the service's requests.
pub struct Manager {
    kb: Arc<KnowledgeBase>,
    executor: Arc<dyn Executor>,
    settings: Settings,
    /// The spec-derived part of the environment, cached between reads.
    specs: SpecCache,
    /// The configuration lock (see the module documentation).
    configuration: Mutex<Configuration>,
    history: RwLock<History>,
    learned: RwLock<Learned>,
    schedule: Mutex<Schedule>,
    /// The transformations the executors could run when last asked
    /// ([`Manager::executors_changed`]).
    runnable: Mutex<BTreeSet<Tid>>,
    wake: Notify,
    events: broadcast::Sender<Arc<ChangeSet>>,
    /// Set from [`Manager::hold_reviews`] until the start-up reconciliation
    /// ([`Manager::reconcile`] with `respawn`): no review runs before it.
    starting: std::sync::atomic::AtomicBool,
    started: Notify,
    /// The unprotected CUs spawned since start-up, with their transformation and the
    /// implementation they were started with: what a spec posted meanwhile is compared with
    /// ([`Manager::stale_after_post`]), whether or not the spawn's write has been published.
    spawned_with: Mutex<BTreeMap<Cid, (Tid, Implementation)>>,
    /// The CUs the change set being applied spawns, from the moment the executors are asked
    /// until its write is published: [`Manager::cus`] shows them, `starting` until their
    /// executor says they run (a process CU can take seconds to start, and was missing from
    /// every read meanwhile).
    applying: Mutex<Arc<Spawning>>,
    /// What was written to the model outside change sets since the last one was recorded
    /// (CUs removed because they crashed or their spec changed): the next change set's delta
    /// begins with it, so that applying every change set's delta in turn gives the model.
    unrecorded: Mutex<NTriplesDelta>,
}

/// The CUs a change set spawns, with their transformation as the change set was planned with
/// (its learned estimates).
type Spawning = BTreeMap<Cid, (ComputationUnit, Option<Transformation>)>;

/// Clears [`Manager::applying`] when a change set's application ends, however it ends.
struct Applying<'a>(&'a Mutex<Arc<Spawning>>);

impl Drop for Applying<'_> {
    fn drop(&mut self) {
        *lock(self.0) = Arc::default();
    }
}

impl std::fmt::Debug for Manager {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Manager")
            .field("settings", &self.settings)
            .finish_non_exhaustive()
    }
}

/// The parts of a write that prunes change sets `pruned` from the history: their records
/// removed, and the history part reserving the highest names `ids` handed out (above every name
/// the pruned change sets used).
fn pruning(
    pruned: &[dyknow_engine::ChangeSetId],
    ids: &Ids,
) -> Vec<(EnvironmentPart, Vec<dyknow_store::oxigraph::model::Triple>)> {
    let mut parts: Vec<_> = pruned
        .iter()
        .map(|id| (EnvironmentPart::ChangeSet(id.clone()), Vec::new()))
        .collect();
    parts.push((
        EnvironmentPart::History,
        model::history_triples(ids.highest_minted().iter().map(String::as_str)),
    ));
    parts
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock leaves no half-done write behind (the knowledge base
    // writes atomically), so poisoning carries no information.
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Manager {
    /// A manager over `kb`, reading the recorded change sets and learned estimates; change
    /// sets are applied through `executor`. The loop starts with [`Manager::run`].
    pub fn new(
        kb: Arc<KnowledgeBase>,
        executor: Arc<dyn Executor>,
        settings: Settings,
    ) -> Result<Self, LifecycleError> {
        let records = model::change_sets(&kb)?;
        let mut unreadable = Vec::new();
        for record in records.unreadable {
            tracing::warn!(
                "change set {} is recorded but does not read back, so the history leaves it out: {}",
                record.id.as_ref().map_or("without an id", |id| id.as_str()),
                record.error
            );
            unreadable.extend(record.id);
        }
        let mut history = History::new(records.change_sets, &unreadable);
        let learned = model::learned(&kb)?;
        let specs = SpecCache::default();
        let loaded = specs.load(&kb, Some(&learned))?;
        let mut ids = Ids::after(&loaded.env);
        history.reserve_names(&mut ids);
        for name in model::reserved_names(&kb)? {
            ids.reserve_name(&name);
        }
        // A history longer than the limit (the limit was lowered): pruned now.
        let excess = history.len().saturating_sub(settings.history_limit);
        if settings.history_limit > 0 && excess > 0 {
            kb.set_environment(&pruning(&history.beyond(settings.history_limit + 1), &ids))?;
            history.prune(excess);
            tracing::info!(
                "pruned the {excess} oldest change sets (--history-limit {})",
                settings.history_limit
            );
        }
        let (events, _) = broadcast::channel(256);
        let manager = Self {
            executor,
            settings,
            specs,
            configuration: Mutex::new(Configuration { ids }),
            history: RwLock::new(history),
            learned: RwLock::new(learned),
            schedule: Mutex::new(Schedule::new(settings)),
            runnable: Mutex::default(),
            wake: Notify::new(),
            events,
            starting: std::sync::atomic::AtomicBool::new(false),
            started: Notify::new(),
            spawned_with: Mutex::default(),
            applying: Mutex::default(),
            unrecorded: Mutex::default(),
            kb,
        };
        // A store written before CU graphs were kept in step with spec writes may hold
        // subscriptions to ports that are gone: repaired once, here.
        manager.resync(None)?;
        Ok(manager)
    }

    /// The knowledge base.
    pub fn knowledge_base(&self) -> &Arc<KnowledgeBase> {
        &self.kb
    }

    /// The settings.
    pub fn settings(&self) -> Settings {
        self.settings
    }

    /// The environment, candidate table and IRIs now, with the learned estimates. The
    /// library holds only the transformations the executors can run (seed Def. 33.1: a CU of
    /// another is invalid, and the search never plans one).
    pub fn load(&self) -> Result<Loaded, LifecycleError> {
        let learned = self.learned();
        Ok(self.runnable_only(self.specs.load(&self.kb, Some(&learned))?))
    }

    /// `loaded` with only the transformations the executors can run in its library.
    fn runnable_only(&self, mut loaded: Loaded) -> Loaded {
        let executor = &self.executor;
        let specs = &loaded.specs;
        loaded
            .env
            .library
            .retain(|tid, _| specs.get(tid).is_some_and(|s| executor.runnable(s).is_ok()));
        loaded
    }

    /// [`Manager::load`] without waiting for a review or a spec write under way: their
    /// spec-derived part may be the last one published then, with the CUs as
    /// [`Manager::cus`] has them ([`SpecCache::load_now`]). For reads (`GET /environment`).
    pub fn load_now(&self) -> Result<Loaded, LifecycleError> {
        let learned = self.learned();
        Ok(self.runnable_only(self.specs.load_now(&self.kb, Some(&learned))?))
    }

    /// The CUs now, with only the transformations they instantiate in the library (learned
    /// estimates applied; those the executors cannot run left out, as [`Manager::load`] does)
    /// and no targets: what reads of the CUs need, without copying the library or the
    /// candidate table. An environment nothing wrote to since the last read costs a copy of
    /// its CUs.
    ///
    /// It never waits for a review or a spec write under way (they may be patching the
    /// candidate table): it gives the last published snapshot then ([`SpecCache::cus_now`]).
    /// The life-cycle publishes after each of its environment writes, before it answers, so
    /// every CU write that has answered (Spawn, Destroy, SetConfig, a change set applied) is
    /// in it; a transformation spec written meanwhile (its `upkeep`, its ports) shows once a
    /// refresh has run: the next read that finds nobody refreshing, or the review it causes.
    pub fn cus(&self) -> Result<Environment, LifecycleError> {
        Ok(self.cus_of(&*self.specs.cus_now(&self.kb)?))
    }

    /// [`Manager::cus`] when it needs no read of the store (nothing was written since the CUs
    /// were last published), so that a caller on an async runtime can answer at once; `None`
    /// otherwise.
    pub fn cus_published(&self) -> Option<Environment> {
        Some(self.cus_of(&*self.specs.cus_published(&self.kb)?))
    }

    fn cus_of(&self, snapshot: &CuSnapshot) -> Environment {
        let executor = &self.executor;
        let mut env = Environment {
            library: snapshot
                .library
                .iter()
                .filter(|(tid, _)| {
                    snapshot
                        .specs
                        .get(*tid)
                        .is_some_and(|s| executor.runnable(s).is_ok())
                })
                .map(|(tid, t)| (tid.clone(), t.clone()))
                .collect(),
            ..Environment::default()
        };
        self.learned().apply(&mut env);
        env.cus = snapshot.cus.clone();
        // The CUs a change set is spawning, not in the model yet (an applied change set's
        // write is published before they are cleared: never both, never neither).
        let applying = lock(&self.applying).clone();
        for (cid, (cu, transformation)) in applying.iter() {
            env.cus.entry(cid.clone()).or_insert_with(|| cu.clone());
            if let Some(t) = transformation {
                env.library
                    .entry(cu.tid.clone())
                    .or_insert_with(|| t.clone());
            }
        }
        env
    }

    /// Writes environment graphs and publishes the CUs for reads.
    fn set_environment(
        &self,
        parts: &[(EnvironmentPart, Vec<dyknow_store::oxigraph::model::Triple>)],
    ) -> Result<(), LifecycleError> {
        self.kb.set_environment(parts)?;
        if let Err(e) = self.specs.publish(&self.kb) {
            // Written: a read refreshes the snapshot itself once nobody else is.
            tracing::warn!("the CUs written could not be read back: {e}");
        }
        Ok(())
    }

    /// Whether the executors can run a transformation, and why not.
    pub fn runnable(&self, spec: &TransformationSpec) -> Result<(), String> {
        self.executor.runnable(spec)
    }

    /// What the running system says of a CU (`None` in model-only mode).
    pub fn describe(&self, cu: &Cid) -> Option<CuView> {
        let view = self.executor.describe(cu)?;
        self.until_reconciled(BTreeMap::from([(cu.clone(), view)]))
            .into_values()
            .next()
    }

    /// What the running system says of several CUs (empty in model-only mode).
    pub fn describe_all(&self, cus: &[Cid]) -> BTreeMap<Cid, CuView> {
        self.until_reconciled(self.executor.describe_all(cus))
    }

    /// Where several CUs run and in what state, as last heard, asking no executor (empty in
    /// model-only mode): [`Executor::last_heard`].
    pub fn last_heard(&self, cus: &[Cid]) -> BTreeMap<Cid, CuView> {
        self.until_reconciled(self.executor.last_heard(cus))
    }

    /// Until the start-up reconciliation, a CU of the model that no executor hosts is not
    /// known to have crashed: its executor may not have reported yet, and if none does the
    /// reconciliation respawns it. It is `starting` (with no executor), not `crashed`.
    ///
    /// A CU that the change set being applied spawns is `starting` until that change set is
    /// recorded, whatever its executor says meanwhile (it may not host it yet, or already run
    /// it): a CU read as `running` belongs to a recorded change set, as before CUs were listed
    /// while being spawned (a client that saw the configuration running and then read the
    /// change sets found none that made it).
    fn until_reconciled(&self, mut views: BTreeMap<Cid, CuView>) -> BTreeMap<Cid, CuView> {
        let starting = self.starting();
        let applying = lock(&self.applying).clone();
        for (cid, view) in &mut views {
            if applying.contains_key(cid)
                || (starting && view.executor.is_none() && view.state == "crashed")
            {
                "starting".clone_into(&mut view.state);
            }
        }
        views
    }

    /// The executors changed (one appeared or vanished): the transformations that became
    /// runnable are a registration, those that no longer are a deregistration (seed Def. 36),
    /// so a review replans when the environment is no longer valid.
    pub fn executors_changed(&self) -> Result<(), LifecycleError> {
        let loaded = self.specs.spec_part(&self.kb)?;
        let now: BTreeSet<Tid> = loaded
            .specs
            .iter()
            .filter(|(_, s)| self.executor.runnable(s).is_ok())
            .map(|(t, _)| t.clone())
            .collect();
        let before = std::mem::replace(&mut *lock(&self.runnable), now.clone());
        let registered: Vec<Tid> = now.difference(&before).cloned().collect();
        let mut schedule = lock(&self.schedule);
        if !registered.is_empty() {
            schedule.perturbed(&Perturbation::Registered {
                transformations: registered,
            });
        }
        for transformation in before.difference(&now) {
            schedule.perturbed(&Perturbation::Deregistered {
                transformation: transformation.clone(),
            });
        }
        drop(schedule);
        self.wake.notify_one();
        Ok(())
    }

    /// The learned estimates.
    pub fn learned(&self) -> Learned {
        self.learned
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// The recorded change sets, oldest first; those after `since` when given.
    pub fn change_sets(&self, since: Option<&str>) -> Vec<Arc<ChangeSet>> {
        self.history
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .since(since)
    }

    /// A recorded change set by id.
    pub fn change_set(&self, id: &str) -> Option<Arc<ChangeSet>> {
        self.history
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .get(id)
    }

    /// New change sets, as they are recorded.
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<ChangeSet>> {
        self.events.subscribe()
    }

    /// The life-cycle's state now.
    pub fn status(&self) -> Status {
        lock(&self.schedule).status()
    }

    /// Records a perturbation. A crash removes the CU from the model first (an error if no
    /// CU has that name) and stops it where it may still run (hung, not crashed: the
    /// client saw what its executor did not); a short-term negative perturbation starts a
    /// review at once.
    pub fn report(&self, perturbation: Perturbation) -> Result<(), LifecycleError> {
        // The spec is written whatever happens here: a failure to bring the CU graphs in step
        // is logged, and the validity check below is asked for all the same.
        let resynced = match &perturbation {
            Perturbation::Registered { transformations } => self.resync(Some(transformations)),
            Perturbation::Deregistered { transformation } => {
                self.resync(Some(std::slice::from_ref(transformation)))
            }
            _ => Ok(()),
        };
        if let Err(e) = resynced {
            tracing::warn!("the CU graphs could not be brought in step with the specs: {e}");
        }

        if let Perturbation::CuCrashed { cu } = &perturbation {
            self.remove_crashed(cu)?;
            self.executor.abandon(std::slice::from_ref(cu));
            // A crash a client reports is reviewed at once (`POST /perturbations`); those the
            // executors detect are spaced (`Manager::handle`, `Settings::review_spacing`).
            lock(&self.schedule).urgent();
        } else {
            lock(&self.schedule).perturbed(&perturbation);
        }
        self.wake.notify_one();
        Ok(())
    }

    /// The transformations with unprotected CUs running now (as last published) or being
    /// spawned (recorded, their change set not yet written): those a new spec has CUs to
    /// replace for when its implementation changes ([`Manager::stale_after_post`]). No read
    /// of the store.
    pub fn transformations_with_cus(&self) -> BTreeSet<Tid> {
        let mut tids: BTreeSet<Tid> = self
            .specs
            .last_published()
            .map(|last| {
                last.cus
                    .values()
                    .filter(|cu| !cu.protected)
                    .map(|cu| cu.tid.clone())
                    .collect()
            })
            .unwrap_or_default();
        // Those of CUs spawned whose change set is being recorded.
        tids.extend(
            lock(&self.spawned_with)
                .values()
                .map(|(tid, _)| tid.clone()),
        );
        tids
    }

    /// The protected CUs of `transformation` running now (as last published): a client
    /// spawned them and only a client destroys them, so their transformation's spec may not
    /// be removed under them. No read of the store.
    pub fn protected_cus_of(&self, transformation: &Tid) -> Vec<Cid> {
        self.specs
            .last_published()
            .map(|last| {
                last.cus
                    .values()
                    .filter(|cu| cu.protected && cu.tid == *transformation)
                    .map(|cu| cu.cid.clone())
                    .collect()
            })
            .unwrap_or_default()
    }

    /// The unprotected CUs that run an implementation the transformation specs just
    /// `posted` no longer have (type, source, parameters or pinned executor): those spawned
    /// since start-up are compared with the implementation they were started with, the others
    /// (running before start-up) are stale when their transformation is in `changed` (the
    /// caller compared the stored spec before writing). Call it after the write: a spawn
    /// whose spec was read before the write is either recorded here by then, or its review
    /// sees the write and replaces it itself ([`Manager::commit`]). No read of the store.
    pub fn stale_after_post(
        &self,
        posted: &[(Tid, Implementation)],
        changed: &BTreeSet<Tid>,
    ) -> Vec<Cid> {
        if posted.is_empty() {
            return Vec::new();
        }
        let posted: BTreeMap<&Tid, &Implementation> = posted.iter().map(|(t, i)| (t, i)).collect();
        let last = self.specs.last_published();
        let spawned = lock(&self.spawned_with);
        let mut stale: BTreeSet<Cid> = spawned
            .iter()
            .filter(|(cid, (tid, was))| {
                // Not yet published (its change set is being recorded), or published as the
                // unprotected CU of that transformation it was spawned as.
                let as_spawned = last.as_ref().is_none_or(|last| {
                    last.cus
                        .get(*cid)
                        .is_none_or(|cu| !cu.protected && cu.tid == *tid)
                });
                as_spawned && posted.get(tid).is_some_and(|now| *now != was)
            })
            .map(|(cid, _)| cid.clone())
            .collect();
        if !changed.is_empty()
            && let Some(last) = last
        {
            stale.extend(
                last.cus
                    .values()
                    .filter(|cu| {
                        !cu.protected && changed.contains(&cu.tid) && !spawned.contains_key(&cu.cid)
                    })
                    .map(|cu| cu.cid.clone()),
            );
        }
        stale.into_iter().collect()
    }

    /// Replaces CUs that run an implementation their transformation's spec no longer has
    /// ([`Manager::stale_after_post`]). The seed (Ch. 4): a CU whose transformation changed
    /// behaves in no defined way and requires removal. They leave the model as crashed CUs
    /// do, are stopped where they run, and the review this starts replaces them with CUs of
    /// the new spec, wired as they were (their transformations tried first). Protected CUs
    /// are left as they run. Report [`Perturbation::Registered`] as well.
    pub fn replace_stale(&self, stale: &[Cid]) -> Result<(), LifecycleError> {
        if stale.is_empty() {
            return Ok(());
        }
        let _configuration = lock(&self.configuration);
        self.replace_stale_locked(stale)
    }

    /// [`Manager::replace_stale`] under the configuration lock.
    fn replace_stale_locked(&self, stale: &[Cid]) -> Result<(), LifecycleError> {
        let removed = self.remove_from_model_locked(stale)?;
        // Replaced already (a spec write and a change set may both find them).
        if removed.is_empty() {
            return Ok(());
        }
        let names: Vec<&str> = removed.iter().map(|(cid, _)| cid.as_str()).collect();
        tracing::info!(
            "{} run an implementation (type, source, parameters or executor) their \
             transformation's new spec no longer has: replaced",
            names.join(", ")
        );
        self.executor.abandon(stale);
        {
            let mut schedule = lock(&self.schedule);
            for (_, tid) in &removed {
                schedule.prefer(tid.clone());
            }
            schedule.spec_changed(removed.into_iter().map(|(cid, _)| cid).collect());
        }
        self.wake.notify_one();
        Ok(())
    }

    /// A crashed CU leaves the model (not a change set: nobody decided it), and the next
    /// review, with the crash as its cause, tries its transformation first. The schedule learns
    /// of it under the configuration lock, so a review waiting for the lock sees it.
    fn remove_crashed(&self, cid: &Cid) -> Result<(), LifecycleError> {
        if self.remove_all_crashed(std::slice::from_ref(cid))? == 0 {
            return Err(LifecycleError::UnknownCu(cid.clone()));
        }
        Ok(())
    }

    /// Rewrites the CU graphs that no longer say what the model says of their CU
    /// ([`model::resync`]): after the specs of `changed` were written or removed (a port
    /// renamed or dropped), or, with `None`, every CU's (at start-up). Not a change set: no CU
    /// changed, only what the store said of them.
    fn resync(&self, changed: Option<&[Tid]>) -> Result<(), LifecycleError> {
        // No CU of a changed transformation, no graph to look at (and no stored subscription
        // can name one): a new spec, the common case, costs no read of the model and does not
        // wait for the configuration lock (a review may hold it: single spec POSTs went from
        // about 960/s to 690/s waiting for it). The CUs are those of the last publication,
        // which every CU write makes before it answers. A Spawn of the transformation under
        // way (it read the spec before this write) is not seen here: its change set sees the
        // spec generation move and brings its CUs in step itself ([`Manager::commit`]).
        if let (Some(tids), Some(last)) = (changed, self.specs.last_published())
            && !last.cus.values().any(|cu| tids.contains(&cu.tid))
        {
            return Ok(());
        }
        let _configuration = lock(&self.configuration);
        self.resync_locked(changed)
    }

    /// [`Manager::resync`] under the configuration lock.
    fn resync_locked(&self, changed: Option<&[Tid]>) -> Result<(), LifecycleError> {
        // The whole library (not only what the executors run now): a CU graph writes its
        // transformation's upkeep whatever runs it.
        let loaded = self.specs.load(&self.kb, Some(&self.learned()))?;
        let parts = model::resync(&self.kb, &loaded.env, &loaded.iris, changed)?;
        if !parts.is_empty() {
            tracing::info!(
                "rewrote {} CU graph(s) that no longer matched the specs",
                parts.len()
            );
            self.set_environment(&parts)?;
        } else if changed.is_none() {
            // At start-up: published, so that a spec write finds the CUs without a read.
            self.specs.publish(&self.kb)?;
        }
        Ok(())
    }

    /// [`Manager::remove_crashed`] for CUs that crashed together (their executor vanished):
    /// one write, and every crash recorded before a review can take the configuration lock,
    /// so that one review repairs them all and its cause names each. Those the model does not
    /// have are skipped; returns how many it had.
    fn remove_all_crashed(&self, cids: &[Cid]) -> Result<usize, LifecycleError> {
        let _configuration = lock(&self.configuration);
        self.remove_all_crashed_locked(cids)
    }

    /// [`Manager::remove_all_crashed`] under the configuration lock.
    fn remove_all_crashed_locked(&self, cids: &[Cid]) -> Result<usize, LifecycleError> {
        let removed = self.remove_from_model_locked(cids)?;
        let mut schedule = lock(&self.schedule);
        for (cid, tid) in &removed {
            schedule.prefer(tid.clone());
            schedule.perturbed(&Perturbation::CuCrashed { cu: cid.clone() });
        }
        Ok(removed.len())
    }

    /// Removes the CUs `cids` the model has from it, in one write, and forgets what they were
    /// started with; returns them with their transformations.
    fn remove_from_model_locked(&self, cids: &[Cid]) -> Result<Vec<(Cid, Tid)>, LifecycleError> {
        let loaded = self.load()?;
        let mut after = loaded.env.clone();
        let removed: Vec<(Cid, Tid)> = cids
            .iter()
            .filter_map(|cid| after.cus.remove(cid).map(|cu| (cid.clone(), cu.tid)))
            .collect();
        if removed.is_empty() {
            return Ok(removed);
        }
        let delta = model::delta(&loaded.env, &after, &loaded.iris);
        self.set_environment(&delta.parts)?;
        {
            let mut unrecorded = lock(&self.unrecorded);
            *unrecorded = unrecorded.then(&delta.ntriples());
        }
        // Their records go once they are gone from the model (kept, should the write fail:
        // a spec posted again would still find them stale).
        {
            let mut recorded = lock(&self.spawned_with);
            for (cid, _) in &removed {
                recorded.remove(cid);
            }
        }
        Ok(removed)
    }

    /// Spawn: a CU of a transformation with its ports unbound, recorded as a change set
    /// (cause `manual`) and applied by the executor. Reviews may wire it, or destroy it unless
    /// it is protected. Returns the CU as the model has it now.
    pub fn spawn(&self, request: SpawnRequest) -> Result<ComputationUnit, LifecycleError> {
        let mut configuration = lock(&self.configuration);
        let loaded = self.load()?;
        let Some(tf) = loaded.env.library.get(&request.transformation) else {
            // Registered but left out of the library: no executor can run it now.
            if let Some(spec) = loaded.specs.get(&request.transformation) {
                let why = self
                    .executor
                    .runnable(spec)
                    .err()
                    .unwrap_or_else(|| "no executor can run it now".to_owned());
                return Err(LifecycleError::NotRunnable {
                    transformation: request.transformation,
                    why,
                });
            }
            return Err(LifecycleError::UnknownTransformation(
                request.transformation,
            ));
        };
        let mut ids = configuration.ids.clone();
        let cid = match request.name {
            Some(name) if name.trim().is_empty() => return Err(LifecycleError::EmptyName),
            Some(name) if loaded.env.cus.contains_key(&name) => {
                return Err(LifecycleError::NameTaken(name));
            }
            Some(name) => {
                // Refused here, not by the executor after a failed change set; and names go
                // into every export of the model, where a control character breaks XML.
                dyknow_cu::keys::check_name("CU name", &name)
                    .map_err(|e| LifecycleError::InvalidName(e.to_string()))?;
                if name.chars().count() > MAX_CU_NAME || name.chars().any(char::is_control) {
                    return Err(LifecycleError::InvalidName(format!(
                        "a CU name is 1 to {MAX_CU_NAME} characters without control characters"
                    )));
                }
                // A path segment clients resolve away (`/cus/..` is sent as `/`): such a CU
                // could not be read or destroyed by name (a user audit), as a group of that
                // label could not, which is refused too.
                if name == "." || name == ".." {
                    return Err(LifecycleError::InvalidName(format!(
                        "a CU name cannot be {name:?} (URLs resolve it away)"
                    )));
                }
                ids.reserve_cu(&name);
                name
            }
            None => ids.cu(),
        };
        let actions = vec![Action::Spawn {
            cu: cid.clone(),
            transformation: tf.tid.clone(),
        }];
        let committed = self.commit_manual(
            &mut configuration,
            ids,
            &loaded,
            actions,
            tf.labour,
            |after| {
                if let Some(cu) = after.cus.get_mut(&cid) {
                    cu.protected = request.protected;
                }
            },
        )?;
        committed.applied()?;
        committed
            .after
            .cus
            .get(&cid)
            .cloned()
            .ok_or(LifecycleError::UnknownCu(cid))
    }

    /// SetConfig (the proxy's service, seed Ch. 5.2.1): binds the given ports of a CU to the
    /// given channels (`None`: unbound), as a change set (cause `manual`) the executor applies
    /// make before break. Ports not named keep their binding. Refused, with nothing changed:
    /// an unknown CU or port, a channel name that is not a key expression, a channel another
    /// CU publishes on. Returns the CU as the model has it now.
    pub fn set_config(
        &self,
        cid: &Cid,
        inputs: &BTreeMap<String, Option<Channel>>,
        outputs: &BTreeMap<String, Option<Channel>>,
    ) -> Result<ComputationUnit, LifecycleError> {
        let mut configuration = lock(&self.configuration);
        let loaded = self.load()?;
        let Some(cu) = loaded.env.cus.get(cid) else {
            return Err(LifecycleError::UnknownCu(cid.clone()));
        };
        let mut actions = Vec::new();
        let mut ids = configuration.ids.clone();
        for (direction, wanted, current) in
            [("in", inputs, &cu.inputs), ("out", outputs, &cu.outputs)]
        {
            for (port, channel) in wanted {
                let Some(now) = current.get(port) else {
                    return Err(LifecycleError::UnknownPort {
                        cu: cid.clone(),
                        direction,
                        port: port.clone(),
                    });
                };
                if let Some(channel) = channel {
                    dyknow_cu::keys::check_channel(channel)
                        .map_err(|e| LifecycleError::InvalidChannel(e.to_string()))?;
                    ids.reserve_channel(channel);
                }
                if now == channel {
                    continue;
                }
                let (cu, port) = (cid.clone(), port.clone());
                actions.push(match (direction, channel.clone()) {
                    ("in", Some(channel)) => Action::ConnectIn { cu, port, channel },
                    ("in", None) => Action::DisconnectIn { cu, port },
                    (_, Some(channel)) => Action::ConnectOut { cu, port, channel },
                    (_, None) => Action::DisconnectOut { cu, port },
                });
            }
        }
        for channel in outputs.values().flatten() {
            if let Some(other) = loaded
                .env
                .publishers()
                .get(channel.as_str())
                .and_then(|p| p.iter().find(|(c, _)| *c != cid.as_str()))
            {
                return Err(LifecycleError::SharedChannel {
                    channel: channel.to_string(),
                    publisher: other.0.into(),
                });
            }
        }
        // Nor two out ports of this CU on one channel, as bound after the change.
        let mut bound: BTreeMap<&Channel, &String> = BTreeMap::new();
        for (port, now) in &cu.outputs {
            let channel = outputs.get(port).unwrap_or(now);
            if let Some(channel) = channel
                && let Some(first) = bound.insert(channel, port)
            {
                return Err(LifecycleError::SharedChannel {
                    channel: channel.to_string(),
                    publisher: format!("{cid}, out port {first:?}").into(),
                });
            }
        }
        if actions.is_empty() {
            return Ok(cu.clone());
        }
        let committed =
            self.commit_manual(&mut configuration, ids, &loaded, actions, 0.0, |_| {})?;
        committed.applied()?;
        committed
            .after
            .cus
            .get(cid)
            .cloned()
            .ok_or_else(|| LifecycleError::UnknownCu(cid.clone()))
    }

    /// Destroy: removes a CU, as a change set (cause `manual`) the executor applies; protected
    /// CUs are refused. A perturbation: a review starts at once, trying the CU's
    /// transformation first.
    pub fn destroy(&self, cid: &Cid) -> Result<(), LifecycleError> {
        let mut configuration = lock(&self.configuration);
        let loaded = self.load()?;
        let Some(cu) = loaded.env.cus.get(cid) else {
            return Err(LifecycleError::UnknownCu(cid.clone()));
        };
        if cu.protected {
            return Err(LifecycleError::Protected(cid.clone()));
        }
        let actions = vec![Action::Destroy { cu: cid.clone() }];
        let ids = configuration.ids.clone();
        let committed =
            self.commit_manual(&mut configuration, ids, &loaded, actions, 0.0, |_| {})?;
        // A failed action: treated as crashed by the commit, gone from the model, a review
        // follows.
        committed.applied()?;
        // Under the configuration lock, so a review waiting for it replans with it.
        let mut schedule = lock(&self.schedule);
        schedule.prefer(cu.tid.clone());
        schedule.urgent();
        drop(schedule);
        drop(configuration);
        self.wake.notify_one();
        Ok(())
    }

    /// Commits a change set no search made (cause `manual`): `actions` applied to the
    /// environment, then `adjust`ed (what no action says, such as protection); its cost spends
    /// `labour`, and it lists the targets the result leaves unsatisfied.
    fn commit_manual(
        &self,
        configuration: &mut Configuration,
        ids: Ids,
        loaded: &Loaded,
        actions: Vec<Action>,
        labour: f64,
        adjust: impl FnOnce(&mut Environment),
    ) -> Result<Committed, LifecycleError> {
        let mut after = loaded.env.clone();
        after.apply(&actions);
        adjust(&mut after);
        let compiled = Compiled {
            actions,
            cost: CostSummary::of(&after, self.settings.horizon, labour),
            unsatisfied_targets: after
                .invalidities(&loaded.candidates)
                .into_iter()
                .filter_map(|i| match i {
                    Invalidity::UnsatisfiedTarget { target } => Some(target),
                    _ => None,
                })
                .collect(),
            optimal: false,
        };
        self.commit(
            configuration,
            ids,
            loaded,
            (Cause::Manual, Vec::new()),
            compiled,
            after,
            Reconciled::default(),
        )
    }

    /// One review interval: EXPLORE on the current environment, COMPILE, and the change set
    /// applied by the executor, written to the model and recorded. Returns the change set,
    /// if there was anything to change.
    pub fn review(&self) -> Result<Option<Arc<ChangeSet>>, LifecycleError> {
        let mut configuration = lock(&self.configuration);
        let (causes, prefer) = lock(&self.schedule).review_starts();
        let result = self.review_locked(&mut configuration, &causes, prefer);
        drop(configuration);
        lock(&self.schedule).review_ends(causes, result.as_ref().err().map(ToString::to_string));
        result
    }

    /// The review, under the configuration lock.
    fn review_locked(
        &self,
        configuration: &mut Configuration,
        causes: &[Cause],
        prefer: Vec<Tid>,
    ) -> Result<Option<Arc<ChangeSet>>, LifecycleError> {
        let started = Instant::now();
        let loaded = self.load()?;
        let loaded_at = Instant::now();
        let options = ExploreOptions {
            horizon: self.settings.horizon,
            timeout: self.settings.explore_timeout,
            prefer,
            probes: Some(ProbeOptions {
                threads: self.settings.explore_threads,
                ..ProbeOptions::default()
            }),
            ..ExploreOptions::default()
        };
        let mut ids = configuration.ids.clone();
        let reviewed = dyknow_engine::review(&loaded.env, &loaded.candidates, &options, &mut ids);
        let searched_at = Instant::now();
        if reviewed.compiled.actions.is_empty() {
            // Crashes no review could repair yet (their transformations run nowhere now) are
            // the cause of the review that will: it names them.
            if !reviewed.compiled.unsatisfied_targets.is_empty() {
                lock(&self.schedule).keep_crashes(causes, &reviewed.compiled.unsatisfied_targets);
            }
            return Ok(None);
        }
        // Crashes kept from earlier that this change set does not repair stay kept: it is
        // not theirs (a target added meanwhile is its cause).
        let unsatisfied = &reviewed.compiled.unsatisfied_targets;
        let unrepaired = {
            let mut schedule = lock(&self.schedule);
            let unrepaired = schedule.unrepaired(causes, unsatisfied);
            schedule.keep_crashes(&unrepaired, unsatisfied);
            unrepaired
        };
        let causes: Vec<Cause> = causes
            .iter()
            .filter(|c| !unrepaired.contains(c))
            .cloned()
            .collect();
        // One review for a burst of crashes: its cause names every CU it repairs; and every
        // other cause it served, merged by kind.
        let mut causes = Cause::merged(&causes).into_iter();
        let cause = causes.next().unwrap_or(Cause::Review);
        let other_causes: Vec<Cause> = causes.collect();
        let committed = self.commit(
            configuration,
            ids,
            &loaded,
            (cause, other_causes),
            reviewed.compiled,
            reviewed.after,
            Reconciled::default(),
        )?;
        let ms = |from: Instant, to: Instant| to.duration_since(from).as_secs_f64() * 1e3;
        tracing::debug!(
            "{}: read {:.1} ms, search {:.1} ms, applied and recorded {:.1} ms",
            committed.change_set.id,
            ms(started, loaded_at),
            ms(loaded_at, searched_at),
            ms(searched_at, Instant::now()),
        );
        Ok(Some(committed.change_set))
    }

    /// Applies a change set from `loaded.env` to `after` through the executor, then writes the
    /// model and the change set's record in one atomic write and records it (history, event).
    /// The CUs of failed actions are treated as crashed: they are not written to the model (the
    /// record's delta is what was written), and a review follows once the failure back-off
    /// allows. The names minted for it (`ids`) and its number are the configuration's from
    /// the moment the executor is asked, so a write that fails after it never hands them out
    /// again.
    #[expect(
        clippy::too_many_arguments,
        reason = "the one path every change set takes; each argument is a distinct input"
    )]
    fn commit(
        &self,
        configuration: &mut Configuration,
        ids: Ids,
        loaded: &Loaded,
        (cause, other_causes): (Cause, Vec<Cause>),
        compiled: Compiled,
        mut after: Environment,
        reconciled: Reconciled,
    ) -> Result<Committed, LifecycleError> {
        let planned = model::delta(&loaded.env, &after, &loaded.iris);
        // A change set the model would refuse (an ontology violation: a CU subscribing to
        // the channel it publishes on) is refused before any executor carries it out, and
        // takes no number: applied first, it rewired the live CU while the model kept the old
        // binding, and nothing repaired the difference.
        self.kb.check_environment(&planned.parts)?;
        let id = match reconciled.id {
            Some(id) => id,
            None => self
                .history
                .write()
                .unwrap_or_else(PoisonError::into_inner)
                .take_id(),
        };
        configuration.ids = ids;
        let mut change_set = ChangeSet::new(id.clone(), cause, compiled, planned.ntriples());
        change_set.other_causes = other_causes;
        let spawning: Spawning = change_set
            .actions
            .iter()
            .skip(reconciled.done)
            .filter_map(|action| match action {
                Action::Spawn { cu, transformation } => Some((
                    cu.clone(),
                    (
                        after.cus.get(cu)?.clone(),
                        loaded.env.library.get(transformation).cloned(),
                    ),
                )),
                _ => None,
            })
            .collect();
        let applying = (!spawning.is_empty()).then(|| {
            *lock(&self.applying) = Arc::new(spawning);
            Applying(&self.applying)
        });
        // The first `reconciled.done` actions (reconciliation's stops) were carried out
        // already; the executor applies the rest.
        let mut applied = if reconciled.done == 0 {
            self.executor.apply(&change_set, &loaded.specs)
        } else {
            let mut rest = change_set.clone();
            rest.actions
                .drain(..reconciled.done.min(rest.actions.len()));
            let mut applied = self.executor.apply(&rest, &loaded.specs);
            for failure in &mut applied.failures {
                failure.action += reconciled.done;
            }
            applied
        };
        change_set.cus = reconciled.outcomes;
        change_set.cus.append(&mut applied.cus);
        // The unprotected CUs it started, with the implementation they were started with:
        // recorded before the spec generation is read again below, so that a spec written
        // meanwhile is either seen moving here or finds them recorded
        // ([`Manager::stale_after_post`]).
        let started: Vec<(&Cid, &Tid)> = change_set
            .actions
            .iter()
            .enumerate()
            .filter_map(|(i, action)| match action {
                Action::Spawn { cu, transformation }
                    if !applied.failures.iter().any(|f| f.action == i) =>
                {
                    Some((cu, transformation))
                }
                _ => None,
            })
            .collect();
        let mut spawned: Vec<(Cid, Tid)> = Vec::new();
        {
            let mut recorded = lock(&self.spawned_with);
            recorded.retain(|cid, _| after.cus.contains_key(cid));
            for (cid, tid) in started {
                // A protected CU is never replaced: no record (nor an older one of its name).
                match (after.cus.get(cid), loaded.specs.get(tid)) {
                    (Some(cu), Some(spec)) if !cu.protected => {
                        recorded.insert(cid.clone(), (tid.clone(), spec.implementation()));
                        spawned.push((cid.clone(), tid.clone()));
                    }
                    _ => {
                        recorded.remove(cid);
                    }
                }
            }
        }
        let mut crashed: Vec<Cid> = Vec::new();
        let written = if applied.failures.is_empty() {
            change_set.status = ChangeSetStatus::Applied;
            planned
        } else {
            change_set.status = ChangeSetStatus::Failed;
            for failure in &applied.failures {
                tracing::warn!(
                    "{}: action {} on {} failed: {}",
                    change_set.id,
                    failure.action,
                    failure.cu,
                    failure.reason
                );
                // Gone from the model whether the action spawned, rewired or destroyed it.
                after.cus.remove(&failure.cu);
                crashed.push(failure.cu.clone());
            }
            change_set.failures = applied.failures;
            let written = model::delta(&loaded.env, &after, &loaded.iris);
            change_set.delta = written.ntriples();
            written
        };
        // The model's changes since the last change set that no change set made (crashes,
        // replaced specs) come first in its delta: a client applying the deltas in turn (the
        // SSE stream) gets the model, CUs that crashed included.
        let unrecorded = std::mem::take(&mut *lock(&self.unrecorded));
        if !unrecorded.is_empty() {
            change_set.delta = unrecorded.then(&change_set.delta);
        }
        let mut parts = written.parts;
        parts.push((
            EnvironmentPart::ChangeSet(id),
            model::change_set_triples(&change_set),
        ));
        // The oldest records beyond the history limit go in the same write; the names they
        // used stay reserved (the configuration's counters are above all of them).
        let pruned = self
            .history
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .beyond(self.settings.history_limit);
        if !pruned.is_empty() {
            parts.extend(pruning(&pruned, &configuration.ids));
        }
        // A spawn that failed cost labour and gave nothing: its transformation's labour
        // estimate doubles (as an observation), so a transformation that keeps failing to
        // start loses to its alternatives instead of crash-looping.
        let mut learned = None;
        for failure in &change_set.failures {
            if let Some(Action::Spawn { transformation, .. }) =
                change_set.actions.get(failure.action)
                && let Some(tf) = loaded.env.library.get(transformation)
            {
                let learned = learned.get_or_insert_with(|| self.learned());
                learned.observe(
                    transformation.clone(),
                    CostKind::Labour,
                    (2.0 * tf.labour).max(1.0),
                );
            }
        }
        if let Some(learned) = &learned {
            parts.push((
                EnvironmentPart::Statistics,
                model::statistics_triples(&self.kb, learned, &loaded.iris)?,
            ));
        }
        if let Err(e) = self.set_environment(&parts) {
            // Not recorded: what came before it is the next one's to tell.
            {
                let mut pending = lock(&self.unrecorded);
                *pending = unrecorded.then(&pending);
            }
            // The executor may have applied what the model now lacks: replan from the model.
            tracing::error!("{}: applied but not recorded: {e}", change_set.id);
            lock(&self.schedule).urgent();
            self.wake.notify_one();
            return Err(e);
        }
        if let Some(learned) = learned {
            *self.learned.write().unwrap_or_else(PoisonError::into_inner) = learned;
        }
        let change_set = Arc::new(change_set);
        {
            let mut history = self.history.write().unwrap_or_else(PoisonError::into_inner);
            history.push(change_set.clone());
            history.prune(pruned.len());
        }
        // Written, published and recorded: its CUs are read from the model now, as the
        // executors last said (and those that failed, or, below, were found stale, no longer).
        drop(applying);
        let _ = self.events.send(change_set.clone());
        {
            let mut schedule = lock(&self.schedule);
            if crashed.is_empty() {
                schedule.applied();
            } else {
                // Not their transformations first: they may fail again. A repeated failure
                // waits longer (the back-off), so an executor that cannot run something is
                // not asked again and again.
                for cu in crashed {
                    schedule.failed(cu);
                }
                drop(schedule);
                self.wake.notify_one();
            }
        }
        // A spec written while this change set was planned and applied: what it spawned from
        // the spec read before is brought in step (ports renamed) or, run from another
        // implementation, replaced. Read after the write above published the CUs, so that a
        // spec write this does not see finds them published (its own `resync`), and after
        // they were recorded (`stale_after_post`). Best effort: the change set is recorded.
        let respec = if spawned.is_empty() || self.kb.spec_generation() == loaded.spec_generation {
            None
        } else {
            match self.respecified(loaded, &spawned) {
                Ok(respec) => Some(respec),
                Err(e) => {
                    tracing::warn!(
                        "{}: specs written meanwhile not compared with what it spawned: {e}",
                        change_set.id
                    );
                    None
                }
            }
        };
        // No spec of what it spawned written meanwhile (another was): nothing to bring in step.
        if let Some((stale, tids)) = respec.filter(|(_, tids)| !tids.is_empty()) {
            if let Err(e) = self.resync_locked(Some(&tids)) {
                tracing::warn!(
                    "{}: CU graphs not brought in step with specs written meanwhile: {e}",
                    change_set.id
                );
            }
            if !stale.is_empty()
                && let Err(e) = self.replace_stale_locked(&stale)
            {
                tracing::warn!(
                    "{}: CUs of a replaced implementation not replaced: {e}",
                    change_set.id
                );
            }
        }
        Ok(Committed { change_set, after })
    }

    /// Of the CUs a change set `spawned` from the specs in `loaded`, those whose
    /// transformation's spec now names another implementation (read from the store), with the
    /// transformations spawned: a spec was written since `loaded` was read.
    fn respecified(
        &self,
        loaded: &Loaded,
        spawned: &[(Cid, Tid)],
    ) -> Result<(Vec<Cid>, Vec<Tid>), LifecycleError> {
        // The transformations spawned whose spec graphs were written since (all of them when
        // the log no longer reaches back that far).
        let (_, written) = self.kb.spec_changes_since(loaded.spec_generation);
        let tids: BTreeSet<Tid> = spawned
            .iter()
            .map(|(_, tid)| tid)
            .filter(|tid| {
                written.as_ref().is_none_or(|graphs| {
                    graphs.contains(&dyknow_store::graphs::spec_graph(
                        SpecKind::Transformation,
                        tid.as_str(),
                    ))
                })
            })
            .cloned()
            .collect();
        let mut changed = BTreeSet::new();
        for tid in &tids {
            let now = match self
                .kb
                .spec(SpecKind::Transformation, tid.as_str())
                .map_err(dyknow_store::ModelReadError::from)?
            {
                Some(dyknow_store::spec::Spec::Transformation(t)) => Some(t.implementation()),
                _ => None,
            };
            let then = loaded
                .specs
                .get(tid)
                .map(TransformationSpec::implementation);
            // A spec removed meanwhile: the review its removal starts takes its CUs.
            if now.is_some() && now != then {
                changed.insert(tid.clone());
            }
        }
        let stale = spawned
            .iter()
            .filter(|(_, tid)| changed.contains(tid))
            .map(|(cid, _)| cid.clone())
            .collect();
        Ok((stale, tids.into_iter().collect()))
    }

    /// Holds reviews until the start-up reconciliation ([`Manager::reconcile`] with
    /// `respawn`): a restarted manager first learns what its executors still run, so no
    /// review replans CUs that are running but not yet reported.
    pub fn hold_reviews(&self) {
        self.starting
            .store(true, std::sync::atomic::Ordering::SeqCst);
    }

    /// Whether the start-up reconciliation is still to come.
    pub fn starting(&self) -> bool {
        self.starting.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Whether every CU of the model runs on some executor (start-up need wait no longer).
    pub fn all_placed(&self) -> Result<bool, LifecycleError> {
        let loaded = self.specs.load(&self.kb, Some(&self.learned()))?;
        Ok(loaded
            .env
            .cus
            .keys()
            .all(|cu| self.executor.placed(cu).is_some()))
    }

    /// Reconciliation, Kubernetes-style: the model says what should run, the executors'
    /// reports what does. When a restarted manager sees its executors again, or an executor
    /// comes back from a partition, the CUs `executor` reports are compared with the model:
    /// a CU the model has (same transformation, running on no other executor) is *adopted*
    /// and its bindings corrected to the model's; any other is *stopped* (the model replanned
    /// it away, or it was spawned by a change set the manager never recorded). With `respawn`
    /// (the start-up pass, once executors had time to come back), every CU of the model that
    /// runs nowhere is spawned again under its name and bound as the model says. What it did
    /// is recorded as one change set with cause `reconcile` (none when nothing was to do); the
    /// model does not change. The start-up pass also ends [`Manager::hold_reviews`].
    pub fn reconcile(
        &self,
        executor: Option<&str>,
        reported: Vec<ReportedCu>,
        respawn: bool,
    ) -> Result<Option<Arc<ChangeSet>>, LifecycleError> {
        let result = self.reconcile_locked(executor, reported, respawn);
        if respawn
            && self
                .starting
                .swap(false, std::sync::atomic::Ordering::SeqCst)
        {
            tracing::info!("start-up reconciliation done: reviews may run");
            self.started.notify_waiters();
            self.wake.notify_one();
        }
        result
    }

    fn reconcile_locked(
        &self,
        executor: Option<&str>,
        reported: Vec<ReportedCu>,
        respawn: bool,
    ) -> Result<Option<Arc<ChangeSet>>, LifecycleError> {
        let mut configuration = lock(&self.configuration);
        let loaded = self.load()?;
        let name = executor.unwrap_or_default();
        let mut stops: Vec<Cid> = Vec::new();
        let mut adopted: Vec<Cid> = Vec::new();
        let mut fixes: Vec<Action> = Vec::new();
        let mut outcomes: BTreeMap<Cid, CuOutcome> = BTreeMap::new();
        let mut newly_adopted = 0;
        for report in reported {
            let wanted = loaded.env.cus.get(&report.cu).filter(|cu| {
                cu.tid == report.transformation
                    && self
                        .executor
                        .placed(&report.cu)
                        .is_none_or(|placed| placed == name)
            });
            let Some(cu) = wanted else {
                stops.push(report.cu);
                continue;
            };
            if self.executor.placed(&report.cu).is_none() {
                newly_adopted += 1;
            }
            fixes.extend(corrections(cu, &report));
            outcomes.insert(
                report.cu.clone(),
                CuOutcome {
                    executor: Some(name.to_owned()),
                    state: CuOutcomeState::Running,
                },
            );
            adopted.push(report.cu);
        }
        let mut respawns: Vec<Action> = Vec::new();
        let mut labour = 0.0;
        if respawn {
            for (cid, cu) in &loaded.env.cus {
                if adopted.contains(cid) || self.executor.placed(cid).is_some() {
                    continue;
                }
                labour += loaded.env.library.get(&cu.tid).map_or(0.0, |tf| tf.labour);
                respawns.push(Action::Spawn {
                    cu: cid.clone(),
                    transformation: cu.tid.clone(),
                });
                respawns.extend(bindings(cu));
            }
        }
        // CUs it already knew ran there, as the model has them: nothing happened.
        if stops.is_empty() && newly_adopted == 0 && fixes.is_empty() && respawns.is_empty() {
            return Ok(None);
        }
        let id = self
            .history
            .write()
            .unwrap_or_else(PoisonError::into_inner)
            .take_id();
        let generation = id.number().unwrap_or(0);
        let failed = self.executor.stop(name, &stops, generation);
        for cu in &stops {
            match failed.iter().find(|(c, _)| c == cu) {
                Some((_, why)) => {
                    tracing::warn!("reconcile: cannot stop {cu} on {name}: {why}");
                }
                None => {
                    tracing::info!(
                        "reconcile: stopped {cu} on {name}, which the model does not run there"
                    );
                    outcomes.insert(
                        cu.clone(),
                        CuOutcome {
                            executor: Some(name.to_owned()),
                            state: CuOutcomeState::Stopped,
                        },
                    );
                }
            }
        }
        self.executor.adopt(name, &adopted);
        if !adopted.is_empty() {
            tracing::info!("reconcile: adopted {} CUs running on {name}", adopted.len());
        }
        let mut ids = configuration.ids.clone();
        for cu in &stops {
            // It ran: its name is never handed out again.
            ids.reserve_cu(cu);
        }
        let done = stops.len();
        let mut actions: Vec<Action> = stops.into_iter().map(|cu| Action::Destroy { cu }).collect();
        actions.extend(fixes);
        actions.extend(respawns);
        let after = loaded.env.clone();
        let compiled = Compiled {
            actions,
            cost: CostSummary::of(&after, self.settings.horizon, labour),
            unsatisfied_targets: unsatisfied(&after, &loaded),
            optimal: false,
        };
        let committed = self.commit(
            &mut configuration,
            ids,
            &loaded,
            (
                Cause::Reconcile {
                    executor: executor.map(str::to_owned),
                },
                Vec::new(),
            ),
            compiled,
            after,
            Reconciled {
                id: Some(id),
                done,
                outcomes,
            },
        )?;
        Ok(Some(committed.change_set))
    }

    /// What the manager does with one event of its fleet (the executors' protocol, from
    /// [`crate::Fleet`]): an executor that appeared is reconciled, a change in the executors
    /// present starts a review, a crash is a perturbation (that of a CU the model does not
    /// have is ignored; the CUs of a vanished executor crash together, in one write), and a
    /// measured cost comes back as an observation, to be recorded in
    /// batches with [`Manager::observe_all`] (upkeep as CPU ms per time unit; none for an
    /// interval that is not positive). Nothing an executor sends makes it panic.
    pub fn handle(&self, event: FleetEvent) -> Result<Option<Observation>, LifecycleError> {
        match event {
            FleetEvent::Appeared { executor, cus } => {
                self.reconcile(Some(&executor), cus, false)?;
            }
            FleetEvent::ExecutorsChanged => self.executors_changed()?,
            FleetEvent::Crashed { cu, reason } => {
                tracing::warn!("{cu} crashed: {reason}");
                if self.remove_all_crashed(&[cu])? > 0 {
                    self.wake.notify_one();
                }
            }
            FleetEvent::Vanished { executor, cus } => {
                for cu in &cus {
                    tracing::warn!("{cu} crashed: its executor {executor} vanished");
                }
                if self.remove_all_crashed(&cus)? > 0 {
                    self.wake.notify_one();
                }
            }
            FleetEvent::Labour {
                transformation,
                cpu_ms,
            } => {
                return Ok(Some(Observation::Labour {
                    transformation,
                    value: cpu_ms,
                }));
            }
            FleetEvent::Upkeep {
                cu,
                cpu_ms,
                over_ms,
            } => {
                let time_unit_ms = self.settings().time_unit.as_secs_f64() * 1e3;
                return Ok((over_ms > 0.0).then(|| Observation::Upkeep {
                    cu,
                    value: cpu_ms * time_unit_ms / over_ms,
                }));
            }
        }
        Ok(None)
    }

    /// Records observed costs in one write (what executors report every interval); those of
    /// CUs that are gone or invalid values are skipped. Returns how many were recorded.
    pub fn observe_all(&self, observations: Vec<Observation>) -> Result<usize, LifecycleError> {
        let _configuration = lock(&self.configuration);
        let loaded = self.load()?;
        let mut learned = self.learned();
        let mut recorded = 0;
        for observation in observations {
            let (tid, kind, value) = match observation {
                Observation::Upkeep { cu, value } => match loaded.env.cus.get(&cu) {
                    Some(cu) => (cu.tid.clone(), CostKind::Upkeep, value),
                    None => continue,
                },
                Observation::Labour {
                    transformation,
                    value,
                } => (transformation, CostKind::Labour, value),
            };
            if !(dyknow_engine::valid_cost(value) && loaded.specs.contains_key(&tid)) {
                continue;
            }
            learned.observe(tid, kind, value);
            recorded += 1;
        }
        if recorded > 0 {
            let triples = model::statistics_triples(&self.kb, &learned, &loaded.iris)?;
            self.kb
                .set_environment(&[(EnvironmentPart::Statistics, triples)])?;
            *self.learned.write().unwrap_or_else(PoisonError::into_inner) = learned;
        }
        Ok(recorded)
    }

    /// Records an observed cost: the historical average of its transformation is updated and
    /// written into the store (the next review uses it). Starts no review.
    pub fn observe(&self, observation: Observation) -> Result<(), LifecycleError> {
        let (kind, value) = match &observation {
            Observation::Upkeep { value, .. } => (CostKind::Upkeep, *value),
            Observation::Labour { value, .. } => (CostKind::Labour, *value),
        };
        if !dyknow_engine::valid_cost(value) {
            return Err(LifecycleError::InvalidCost {
                what: match kind {
                    CostKind::Labour => "labour",
                    CostKind::Upkeep => "upkeep",
                },
                value,
            });
        }
        let _configuration = lock(&self.configuration);
        let loaded = self.load()?;
        let tid = match observation {
            Observation::Upkeep { cu, .. } => match loaded.env.cus.get(&cu) {
                Some(cu) => cu.tid.clone(),
                None => return Err(LifecycleError::UnknownCu(cu)),
            },
            Observation::Labour { transformation, .. } => {
                if !loaded.env.library.contains_key(&transformation) {
                    return Err(LifecycleError::UnknownTransformation(transformation));
                }
                transformation
            }
        };
        let mut learned = self.learned();
        learned.observe(tid, kind, value);
        let triples = model::statistics_triples(&self.kb, &learned, &loaded.iris)?;
        self.kb
            .set_environment(&[(EnvironmentPart::Statistics, triples)])?;
        *self.learned.write().unwrap_or_else(PoisonError::into_inner) = learned;
        Ok(())
    }

    /// Whether a review is due now because a registration or deregistration left the
    /// environment invalid (a CU of a deregistered transformation, a target a new
    /// transformation could satisfy).
    fn invalid_now(&self) -> Result<bool, LifecycleError> {
        let loaded = self.load()?;
        Ok(!loaded.env.invalidities(&loaded.candidates).is_empty())
    }

    /// The life-cycle loop: waits for an urgent perturbation or the end of the stable
    /// interval, then reviews. Runs until the task is dropped.
    pub async fn run(self: Arc<Self>) {
        loop {
            let started = self.started.notified();
            if !self.starting() {
                break;
            }
            started.await;
        }
        loop {
            let wait = lock(&self.schedule).wait();
            tokio::select! {
                () = self.wake.notified() => {}
                () = tokio::time::sleep(wait) => {}
            }
            // Executors lost to a stall of the manager itself may be coming back (at most
            // the fleet's grace): no review until they are, or are counted lost.
            if self.executor.settling() {
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
            let (due, check) = lock(&self.schedule).due();
            if !due && check.is_none() {
                continue;
            }
            tracing::debug!("review loop: due {due}, check {check:?}");
            let me = self.clone();
            let result = tokio::task::spawn_blocking(move || {
                // A check that cannot read the environment reviews (which records the error),
                // so the loop never spins on it.
                if let (false, Some(upto)) = (due, check)
                    && matches!(me.invalid_now(), Ok(false))
                {
                    lock(&me.schedule).checked(upto);
                    return Ok(None);
                }
                me.review()
            })
            .await;
            match result {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => tracing::error!("review failed: {e}"),
                Err(e) => tracing::error!("review panicked: {e}"),
            }
        }
    }
}

/// The actions that bind a CU's ports as the model has them (a respawned CU).
fn bindings(cu: &ComputationUnit) -> Vec<Action> {
    let mut actions = Vec::new();
    for (port, channel) in &cu.inputs {
        if let Some(channel) = channel {
            actions.push(Action::ConnectIn {
                cu: cu.cid.clone(),
                port: port.clone(),
                channel: channel.clone(),
            });
        }
    }
    for (port, channel) in &cu.outputs {
        if let Some(channel) = channel {
            actions.push(Action::ConnectOut {
                cu: cu.cid.clone(),
                port: port.clone(),
                channel: channel.clone(),
            });
        }
    }
    actions
}

/// The actions that bring an adopted CU's bindings (as its executor reports them) to the
/// model's.
fn corrections(cu: &ComputationUnit, report: &ReportedCu) -> Vec<Action> {
    let mut actions = Vec::new();
    for (port, wanted) in &cu.inputs {
        if report.inputs.get(port).cloned().flatten() == *wanted {
            continue;
        }
        let (cu, port) = (cu.cid.clone(), port.clone());
        actions.push(match wanted.clone() {
            Some(channel) => Action::ConnectIn { cu, port, channel },
            None => Action::DisconnectIn { cu, port },
        });
    }
    for (port, wanted) in &cu.outputs {
        if report.outputs.get(port).cloned().flatten() == *wanted {
            continue;
        }
        let (cu, port) = (cu.cid.clone(), port.clone());
        actions.push(match wanted.clone() {
            Some(channel) => Action::ConnectOut { cu, port, channel },
            None => Action::DisconnectOut { cu, port },
        });
    }
    actions
}

/// The targets `env` leaves unsatisfied.
fn unsatisfied(env: &Environment, loaded: &Loaded) -> Vec<dyknow_engine::Qid> {
    env.invalidities(&loaded.candidates)
        .into_iter()
        .filter_map(|i| match i {
            Invalidity::UnsatisfiedTarget { target } => Some(target),
            _ => None,
        })
        .collect()
}
