//! Formula groups in the service (contract `groups.md`; seed Ch. 5.4): the registry, the
//! targets the groups' symbols become, the subscriptions to their channels, one progression
//! thread per running group, the result channel, and persistence.
//!
//! **Persistence.** With an on-disk store, each group lives in `<data>/groups/<label>/`:
//! `group.json` (the definition: formulas with the state at which each was added and
//! removed, domains, landmarks, static regions, grounding, policy, life-cycle state, restarts)
//! written atomically on every change, and `trace.jsonl`, the synchronised state stream as a
//! `dyknow check` trace, appended and flushed after every batch of states (synced to disk at
//! most a second later and when the group stops). Verdicts are not stored: they are what the
//! formulas give on the recorded trace, so on start-up the service replays each trace through
//! a fresh monitor and gets every verdict back exactly (a torn last line from a crash is cut
//! off). A group that was running resumes from the next state and records the restart.
//!
//! **Targets.** Each ground symbol becomes the target `symbol:<tag>` on the channel
//! `/dyknow/symbols/<tag>` ([`dyknow_group::TargetTag`]); groups share them, and a target is
//! released when no created or running group needs it. Stopped groups need no streams.

mod store;

use std::collections::{BTreeMap, BTreeSet};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use dyknow_cu::zenoh::{self, Wait};
use dyknow_engine::Channel;
use dyknow_group::progression::read_state_line;
use dyknow_group::spec::{self, Grounded, target_tag, unused_groundings};
use dyknow_group::{
    Grounding, GroupSpec, Policy, Progression, SpecError, StreamKind, Synchroniser, TargetTag,
    TraceHeader, VerdictLine,
};
use dyknow_lifecycle::{Manager, Perturbation};
use dyknow_mstl::Symbol;
use dyknow_store::KnowledgeBase;
use dyknow_store::spec::{Spec, SpecKind};
use serde::{Deserialize, Serialize};
use serde_json::{Value as Json, json};
use tokio::sync::broadcast;

pub use store::{GroupStore, TraceWriter};

/// The prefix of the labels of targets groups create.
pub const TARGET_PREFIX: &str = "symbol:";

/// A group's life-cycle state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Defined, not progressing; its targets are planned already.
    Created,
    /// Progressing.
    Running,
    /// Ended for good.
    Stopped,
}

/// A formula of a group as persisted.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FormulaDef {
    /// The formula's index (never reused).
    pub index: usize,
    /// Its text as posted.
    pub formula: String,
    /// The number of states taken before it was added.
    pub added_at: u64,
    /// The number of states taken before it was removed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub removed_at: Option<u64>,
}

/// The header of a group's trace as served: domains, landmarks, static regions and the
/// formulas, each with the states it was progressed over (`from_state`, and `until_state`
/// once removed), which `dyknow check` replays when given no formula.
fn replay_header(def: &GroupDef) -> String {
    let formulas: Vec<serde_json::Value> = def
        .formulas
        .iter()
        .map(|f| {
            let mut v = serde_json::json!({
                "index": f.index,
                "formula": f.formula,
                "from_state": f.added_at,
            });
            if let Some(until) = f.removed_at {
                v["until_state"] = until.into();
            }
            v
        })
        .collect();
    serde_json::json!({
        "domains": def.header.domains,
        "landmarks": def.header.landmarks,
        "static": def.header.static_regions,
        "formulas": formulas,
    })
    .to_string()
}

/// A restart of the service while the group ran.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Resumed {
    /// States taken before the restart.
    pub after_state: u64,
    /// The last state's time before it (ms).
    pub last_t: Option<u64>,
    /// When progression resumed (wall clock, ms since the epoch).
    pub at: u64,
}

/// A group's definition and life-cycle state, as persisted in `group.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GroupDef {
    /// The label.
    pub label: String,
    /// Where verdicts are published.
    pub result_channel: String,
    /// Domains, landmarks, static regions: the trace's header.
    pub header: TraceHeader,
    /// Symbol → tag.
    #[serde(default)]
    pub grounding: BTreeMap<String, Grounding>,
    /// The synchronisation policy.
    pub sync: Policy,
    /// The formulas, by index.
    pub formulas: Vec<FormulaDef>,
    /// The life-cycle state.
    pub phase: Phase,
    /// Restarts survived while running.
    #[serde(default)]
    pub resumed: Vec<Resumed>,
}

/// A group-level failure, mapped to HTTP statuses by the routes.
#[derive(Debug, thiserror::Error)]
pub enum GroupError {
    /// A bad definition or formula (400 for syntax, 422 otherwise).
    #[error(transparent)]
    Spec(#[from] SpecError),
    /// No such group (404).
    #[error("no group labelled {0:?}")]
    NotFound(String),
    /// No such formula (404).
    #[error("group {group:?} has no formula {index}")]
    NoFormula {
        /// The group.
        group: String,
        /// The index.
        index: usize,
    },
    /// The label is taken (409).
    #[error("a group labelled {0:?} exists")]
    Exists(String),
    /// The operation does not fit the group's state (409).
    #[error("{0}")]
    Conflict(String),
    /// The store or the data plane failed (500).
    #[error("{0}")]
    Internal(String),
}

/// One stream a group reads: a target's channel, and what it carries.
#[derive(Debug, Clone)]
struct StreamInfo {
    tag: TargetTag,
    kind: StreamKind,
    active: bool,
}

/// What arrives at a group's thread.
enum Input {
    Sample { stream: usize, t: u64, value: Json },
    Stop,
}

/// A running group's thread and subscription.
struct Runner {
    tx: mpsc::Sender<Input>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// One subscriber to every symbol channel (`/dyknow/symbols/**`; `None` without a data
    /// plane), and the active streams by the key expression of their channel. One per stream
    /// cost Zenoh a match against every key it knew at each declaration: starting a group of
    /// 9,261 symbols took 6–7 s in declarations alone.
    subscriber: Option<zenoh::pubsub::Subscriber<()>>,
    routes: Arc<std::sync::RwLock<Routes>>,
}

/// The prefix of every symbol channel ([`dyknow_group::TargetTag::channel`]).
const SYMBOL_CHANNELS: &str = "/dyknow/symbols";

/// The streams a symbol channel's samples go to, by key expression.
type Routes = std::collections::HashMap<String, Vec<usize>>;

/// A group's live state.
struct Core {
    def: GroupDef,
    prog: Progression,
    sync: Synchroniser<Json>,
    streams: Vec<StreamInfo>,
    /// Symbols of the formulas not removed, and the stream each is read from.
    symbols: BTreeMap<Symbol, usize>,
    /// Each formula's symbols (None once removed).
    grounded: Vec<Option<BTreeSet<Symbol>>>,
    verdicts: Vec<VerdictLine>,
    dropped_spatial: u64,
    last_dropped: Option<String>,
    writer: TraceWriter,
}

/// A formula group.
pub struct Group {
    label: String,
    core: Mutex<Core>,
    runner: Mutex<Option<Runner>>,
    events: broadcast::Sender<VerdictLine>,
    /// Set once the group is stopped, after its last verdicts were sent on `events`: no verdict
    /// comes after it, so watchers end their streams.
    stopped: tokio::sync::watch::Sender<bool>,
}

impl Group {
    fn core(&self) -> MutexGuard<'_, Core> {
        self.core
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// The data plane a group reads from and publishes to.
#[derive(Clone)]
pub struct Plane {
    /// The service's Zenoh session.
    pub session: zenoh::Session,
    /// The key namespace.
    pub namespace: dyknow_cu::Namespace,
}

/// Every group of the service.
pub struct Groups {
    kb: Arc<KnowledgeBase>,
    lifecycle: Arc<Manager>,
    plane: Option<Plane>,
    store: Option<GroupStore>,
    groups: Mutex<BTreeMap<String, Arc<Group>>>,
    /// Serialises target changes.
    targets: Mutex<()>,
}

fn now_ms() -> u64 {
    u64::try_from(dyknow_cu::now_ms()).unwrap_or(0)
}

impl Groups {
    /// The registry: with `store`, the groups persisted there are loaded, their traces
    /// replayed, running ones resumed, and the targets made to match.
    pub fn new(
        kb: Arc<KnowledgeBase>,
        lifecycle: Arc<Manager>,
        plane: Option<Plane>,
        store: Option<GroupStore>,
    ) -> Result<Arc<Self>, GroupError> {
        let groups = Arc::new(Self {
            kb,
            lifecycle,
            plane,
            store,
            groups: Mutex::new(BTreeMap::new()),
            targets: Mutex::new(()),
        });
        groups.load()?;
        Ok(groups)
    }

    /// A registry without groups, store or data plane (in-memory services, tests).
    pub fn empty(kb: Arc<KnowledgeBase>, lifecycle: Arc<Manager>) -> Arc<Self> {
        Arc::new(Self {
            kb,
            lifecycle,
            plane: None,
            store: None,
            groups: Mutex::new(BTreeMap::new()),
            targets: Mutex::new(()),
        })
    }

    fn map(&self) -> MutexGuard<'_, BTreeMap<String, Arc<Group>>> {
        self.groups
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn load(self: &Arc<Self>) -> Result<(), GroupError> {
        let Some(store) = &self.store else {
            return Ok(());
        };
        for (def, lines) in store.load_all().map_err(GroupError::Internal)? {
            let label = def.label.clone();
            match self.restore(def, &lines) {
                Ok(group) => {
                    self.map().insert(label, group);
                }
                Err(e) => tracing::error!("group {label}: cannot restore it: {e}"),
            }
        }
        // A group whose targets cannot be written (accepted by an older version) must not keep
        // the service from starting: it runs without them, and says so.
        if let Err(e) = self.sync_targets() {
            tracing::error!("the groups' targets could not be brought in step: {e}");
        }
        let running: Vec<Arc<Group>> = self
            .map()
            .values()
            .filter(|g| g.core().def.phase == Phase::Running)
            .cloned()
            .collect();
        for g in running {
            let mut core = g.core();
            let resumed = Resumed {
                after_state: core.prog.states(),
                last_t: core.prog.last_t(),
                at: now_ms(),
            };
            tracing::info!(
                "group {}: resumed after a restart, from the next state (after {} states{})",
                g.label,
                resumed.after_state,
                resumed
                    .last_t
                    .map_or_else(String::new, |t| format!(", the last at t = {t}"))
            );
            core.def.resumed.push(resumed);
            self.persist(&core)?;
            drop(core);
            self.run(&g)?;
        }
        Ok(())
    }

    /// Rebuilds a group from its definition and recorded trace.
    fn restore(&self, mut def: GroupDef, lines: &[String]) -> Result<Arc<Group>, GroupError> {
        let mut prog = Progression::new(def.header.clone());
        let mut grounded = Vec::new();
        let parsed: Vec<Grounded> = def
            .formulas
            .iter()
            .map(|f| spec::ground(f.index, &f.formula, &def.header.domains))
            .collect::<Result<_, _>>()?;
        let mut verdicts = Vec::new();
        let mut next = 0;
        // Formulas are added in index order; removals by the number of states before them.
        let mut removals: BTreeMap<u64, Vec<usize>> = BTreeMap::new();
        for f in &def.formulas {
            if let Some(r) = f.removed_at {
                removals.entry(r).or_default().push(f.index);
            }
        }
        let apply = |prog: &mut Progression, next: &mut usize| {
            let states = prog.states();
            while *next < parsed.len() && def.formulas[*next].added_at <= states {
                let _ = prog.add(&parsed[*next].formula);
                *next += 1;
            }
            for &i in removals.get(&states).into_iter().flatten() {
                prog.remove(i);
            }
        };
        for line in lines {
            apply(&mut prog, &mut next);
            let state = read_state_line(line).map_err(GroupError::Internal)?;
            verdicts.extend(prog.take_recorded(state).verdicts);
        }
        apply(&mut prog, &mut next);
        // Additions and removals recorded after states a torn trace lost (the definition is
        // written at once, the trace up to a second later): done now, as of the states the
        // trace has, and the definition says so, so that the trace's header tells `dyknow
        // check` what the group did. Added first: a removal needs its formula.
        let states = prog.states();
        while next < parsed.len() {
            let _ = prog.add(&parsed[next].formula);
            next += 1;
        }
        for &i in removals.range(states + 1..).flat_map(|(_, v)| v) {
            prog.remove(i);
        }
        for f in &mut def.formulas {
            f.added_at = f.added_at.min(states);
            f.removed_at = f.removed_at.map(|r| r.min(states));
        }
        if def.phase == Phase::Stopped {
            verdicts.extend(prog.finish());
        }
        for (f, g) in def.formulas.iter().zip(parsed) {
            grounded.push(f.removed_at.is_none().then_some(g.symbols));
        }
        let writer = match &self.store {
            Some(s) => s.writer(&def.label).map_err(GroupError::Internal)?,
            None => TraceWriter::memory(&def.header.line()),
        };
        let mut sync = Synchroniser::new(def.sync, 0);
        sync.resume_after(prog.last_t());
        let mut core = Core {
            def,
            prog,
            sync,
            streams: Vec::new(),
            symbols: BTreeMap::new(),
            grounded,
            verdicts,
            dropped_spatial: 0,
            last_dropped: None,
            writer,
        };
        self.restream(&mut core);
        let stopped = tokio::sync::watch::Sender::new(core.def.phase == Phase::Stopped);
        Ok(Arc::new(Group {
            label: core.def.label.clone(),
            core: Mutex::new(core),
            runner: Mutex::new(None),
            events: broadcast::channel(4096).0,
            stopped,
        }))
    }

    /// CreateGroup. Nothing is created if a formula, domain, grounding or name is refused.
    pub fn create(self: &Arc<Self>, spec: GroupSpec) -> Result<Arc<Group>, GroupError> {
        spec::validate(&spec)?;
        let mut grounded = Vec::new();
        for (i, f) in spec.formulas.iter().enumerate() {
            grounded.push(spec::ground(i, f, &spec.domains)?);
        }
        let all: BTreeSet<String> = grounded
            .iter()
            .flat_map(|g| g.symbols.iter().map(Symbol::key))
            .collect();
        let unused = unused_groundings(&spec.grounding, &all);
        if !unused.is_empty() {
            return Err(SpecError::Invalid(format!(
                "the grounding names symbols no formula has: {} (the symbols are: {})",
                unused.join(", "),
                all.iter().cloned().collect::<Vec<_>>().join(", ")
            ))
            .into());
        }
        spec::check_groundings(&spec.grounding, &spec.formulas, &grounded)?;
        let mut map = self.map();
        let label = match spec.label.clone() {
            Some(l) => {
                if map.contains_key(&l) {
                    return Err(GroupError::Exists(l));
                }
                l
            }
            None => (1..)
                .map(|n| format!("g-{n}"))
                .find(|l| !map.contains_key(l))
                .unwrap_or_default(),
        };
        let result_channel = spec
            .result_channel
            .clone()
            .unwrap_or_else(|| format!("/dyknow/verdicts/{label}"));
        if let Some(plane) = &self.plane {
            plane.namespace.channel(&result_channel).map_err(|e| {
                SpecError::Invalid(if spec.result_channel.is_some() {
                    format!("result_channel {result_channel:?}: {e}")
                } else {
                    // The user gave a label, not a channel: say it is the label.
                    format!(
                        "the label {label:?} makes the result channel {result_channel:?}, which \
                         Zenoh cannot take ({e}): choose another label, or give a result_channel"
                    )
                })
            })?;
        }
        self.check_result_channel(&result_channel)?;
        // Two groups writing verdicts to one channel mix their streams (a user audit): a
        // running or created group's channel is its own. (Under the map's lock, which
        // `result_channel_user` would take again.)
        if let Some(other) = map.values().find(|g| {
            let core = g.core();
            core.def.phase != Phase::Stopped
                && bare(&core.def.result_channel) == bare(&result_channel)
        }) {
            return Err(SpecError::Invalid(format!(
                "result_channel {result_channel:?} is the result channel of group {:?}: \
                 verdicts would be written into that stream; choose another channel",
                other.label
            ))
            .into());
        }
        let header = TraceHeader {
            domains: spec.domains.clone(),
            landmarks: spec.landmarks.clone(),
            static_regions: spec.static_regions.clone(),
        };
        let def = GroupDef {
            label: label.clone(),
            result_channel,
            header: header.clone(),
            grounding: spec.grounding.clone(),
            sync: spec.sync,
            formulas: spec
                .formulas
                .iter()
                .enumerate()
                .map(|(index, f)| FormulaDef {
                    index,
                    formula: f.clone(),
                    added_at: 0,
                    removed_at: None,
                })
                .collect(),
            phase: Phase::Created,
            resumed: Vec::new(),
        };
        let mut prog = Progression::new(header);
        for g in &grounded {
            prog.add(&g.formula)
                .map_err(|e| GroupError::Internal(e.to_string()))?;
        }
        if let Some(dir) = self.store.as_ref().and_then(|s| s.occupied(&def.label)) {
            return Err(GroupError::Conflict(format!(
                "{} holds the record of a group of this label: one that was not loaded at \
                 start-up (its group.json could not be read: see the service's log; repair it \
                 and restart, or move it away), or one being destroyed now (try again)",
                dir.display()
            )));
        }
        let writer = match &self.store {
            Some(s) => s.create(&def).map_err(GroupError::Internal)?,
            None => TraceWriter::memory(&def.header.line()),
        };
        let mut core = Core {
            sync: Synchroniser::new(def.sync, 0),
            def,
            prog,
            streams: Vec::new(),
            symbols: BTreeMap::new(),
            grounded: grounded.into_iter().map(|g| Some(g.symbols)).collect(),
            verdicts: Vec::new(),
            dropped_spatial: 0,
            last_dropped: None,
            writer,
        };
        self.restream(&mut core);
        let stopped = tokio::sync::watch::Sender::new(core.def.phase == Phase::Stopped);
        let group = Arc::new(Group {
            label: label.clone(),
            core: Mutex::new(core),
            runner: Mutex::new(None),
            events: broadcast::channel(4096).0,
            stopped,
        });
        map.insert(label, group.clone());
        drop(map);
        self.sync_targets()?;
        if spec.start {
            self.start(&group.label)?;
        }
        Ok(group)
    }

    /// The group labelled `label`.
    pub fn get(&self, label: &str) -> Result<Arc<Group>, GroupError> {
        self.map()
            .get(label)
            .cloned()
            .ok_or_else(|| GroupError::NotFound(label.to_owned()))
    }

    /// Every group, by label.
    pub fn list(&self) -> Vec<Arc<Group>> {
        self.map().values().cloned().collect()
    }

    /// StartGroup: progression begins with the next state. Idempotent while running; 409 once
    /// stopped.
    pub fn start(self: &Arc<Self>, label: &str) -> Result<(), GroupError> {
        let g = self.get(label)?;
        {
            let mut core = g.core();
            match core.def.phase {
                Phase::Running => return Ok(()),
                Phase::Stopped => {
                    return Err(GroupError::Conflict(format!(
                        "group {label:?} was stopped; a stopped group cannot be started again (create a new one)"
                    )));
                }
                Phase::Created => {}
            }
            core.def.phase = Phase::Running;
            self.persist(&core)?;
        }
        self.run(&g)
    }

    /// Subscribes a running group to its streams and starts its thread.
    fn run(self: &Arc<Self>, g: &Arc<Group>) -> Result<(), GroupError> {
        let (tx, rx) = mpsc::channel();
        let mut runner = g
            .runner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if runner.is_some() {
            return Ok(());
        }
        let routes: Arc<std::sync::RwLock<Routes>> = Arc::default();
        {
            let mut core = g.core();
            core.sync.start(now_ms());
            *routes
                .write()
                .unwrap_or_else(std::sync::PoisonError::into_inner) = self.routes(&core)?;
        }
        let subscriber = self.subscribe(&routes, &tx)?;
        let this = Arc::downgrade(self);
        let group = g.clone();
        let thread = std::thread::Builder::new()
            .name(format!("group {}", g.label))
            .spawn(move || progress(&this, &group, &rx))
            .map_err(|e| GroupError::Internal(e.to_string()))?;
        *runner = Some(Runner {
            tx,
            thread: Some(thread),
            subscriber,
            routes,
        });
        Ok(())
    }

    /// The active streams of `core` by the key expression of their channel (empty without a
    /// data plane: nothing arrives, every symbol is unknown).
    fn routes(&self, core: &Core) -> Result<Routes, GroupError> {
        let mut routes = Routes::new();
        let Some(plane) = &self.plane else {
            return Ok(routes);
        };
        for (i, s) in core.streams.iter().enumerate().filter(|(_, s)| s.active) {
            let key = plane
                .namespace
                .channel(&s.tag.channel())
                .map_err(|e| GroupError::Internal(e.to_string()))?;
            routes.entry(key).or_default().push(i);
        }
        Ok(routes)
    }

    /// The group's subscriber to every symbol channel, sending each sample to the streams
    /// `routes` names for its key.
    fn subscribe(
        &self,
        routes: &Arc<std::sync::RwLock<Routes>>,
        tx: &mpsc::Sender<Input>,
    ) -> Result<Option<zenoh::pubsub::Subscriber<()>>, GroupError> {
        // Without a data plane (model-only mode) nothing arrives: every symbol is unknown.
        let Some(plane) = &self.plane else {
            return Ok(None);
        };
        // Every symbol channel: `<namespace>/channel/dyknow/symbols/**`.
        let key = format!(
            "{}/**",
            plane
                .namespace
                .channel(SYMBOL_CHANNELS)
                .map_err(|e| GroupError::Internal(e.to_string()))?
        );
        let (tx, routes) = (tx.clone(), routes.clone());
        plane
            .session
            .declare_subscriber(key)
            .callback(move |sample| {
                let streams = routes
                    .read()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .get(sample.key_expr().as_str())
                    .cloned();
                let Some(streams) = streams else { return };
                let payload = sample.payload().to_bytes();
                match dyknow_cu::Sample::from_slice(&payload) {
                    Ok(s) => {
                        if let Ok(t) = u64::try_from(s.t) {
                            for stream in streams {
                                let _ = tx.send(Input::Sample {
                                    stream,
                                    t,
                                    value: s.value.clone(),
                                });
                            }
                        }
                    }
                    Err(e) => tracing::debug!("group streams {streams:?}: not a sample: {e}"),
                }
            })
            .wait()
            .map(Some)
            .map_err(|e| GroupError::Internal(format!("cannot subscribe: {e}")))
    }

    fn stop_runner(g: &Group) {
        let runner = g
            .runner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        if let Some(mut r) = runner {
            drop(r.subscriber.take());
            let _ = r.tx.send(Input::Stop);
            if let Some(t) = r.thread.take() {
                let _ = t.join();
            }
        }
    }

    /// StopGroup: progression ends for good; undecided formulas get `unknown`.
    pub fn stop(self: &Arc<Self>, label: &str) -> Result<(), GroupError> {
        let g = self.get(label)?;
        Self::stop_runner(&g);
        {
            let mut core = g.core();
            if !self.end(&g, &mut core) {
                return Ok(());
            }
            core.writer.sync();
            self.persist(&core)?;
        }
        self.sync_targets()
    }

    /// Ends a group's progression for good (its runner stopped): undecided formulas get their
    /// final `unknown`, published before watchers are told it stopped. Whether it was not
    /// stopped already.
    fn end(&self, g: &Group, core: &mut Core) -> bool {
        let ended = core.def.phase != Phase::Stopped;
        if ended {
            core.def.phase = Phase::Stopped;
            let finals = core.prog.finish();
            self.publish(g, core, finals);
        }
        g.stopped.send_replace(true);
        ended
    }

    /// DestroyGroup: stops it (undecided formulas get their final `unknown`, as StopGroup
    /// gives them: watchers see them before their stream ends), forgets it, releases targets
    /// no other group needs.
    pub fn destroy(self: &Arc<Self>, label: &str) -> Result<(), GroupError> {
        let g = self.get(label)?;
        Self::stop_runner(&g);
        self.end(&g, &mut g.core());
        self.map().remove(label);
        if let Some(s) = &self.store {
            s.remove(label).map_err(GroupError::Internal)?;
        }
        self.sync_targets()
    }

    /// AddFormula: evaluated from the next state on; new symbols get targets.
    pub fn add_formula(self: &Arc<Self>, label: &str, text: &str) -> Result<usize, GroupError> {
        let g = self.get(label)?;
        let index;
        {
            let mut core = g.core();
            if core.def.phase == Phase::Stopped {
                return Err(GroupError::Conflict(format!(
                    "group {label:?} was stopped; formulas can no longer be added"
                )));
            }
            index = core.def.formulas.len();
            let grounded = spec::ground(index, text, &core.def.header.domains)?;
            core.prog
                .add(&grounded.formula)
                .map_err(|e| GroupError::Internal(e.to_string()))?;
            let added_at = core.prog.states();
            core.def.formulas.push(FormulaDef {
                index,
                formula: text.to_owned(),
                added_at,
                removed_at: None,
            });
            core.grounded.push(Some(grounded.symbols));
            self.restream(&mut core);
            self.persist(&core)?;
        }
        self.resubscribe(&g)?;
        self.sync_targets()?;
        Ok(index)
    }

    /// RemoveFormula: also while running; targets no other formula needs are released.
    pub fn remove_formula(self: &Arc<Self>, label: &str, index: usize) -> Result<(), GroupError> {
        let g = self.get(label)?;
        {
            let mut core = g.core();
            // A stopped group's verdicts are final (undecided formulas got `unknown`): a removal
            // now would take that verdict back from replays and restarts (a code review).
            if core.def.phase == Phase::Stopped {
                return Err(GroupError::Conflict(format!(
                    "group {label:?} was stopped; its formulas and verdicts are final"
                )));
            }
            let states = core.prog.states();
            let Some(f) = core
                .def
                .formulas
                .get_mut(index)
                .filter(|f| f.removed_at.is_none())
            else {
                return Err(GroupError::NoFormula {
                    group: label.to_owned(),
                    index,
                });
            };
            f.removed_at = Some(states);
            core.prog.remove(index);
            core.grounded[index] = None;
            self.restream(&mut core);
            self.persist(&core)?;
        }
        self.resubscribe(&g)?;
        self.sync_targets()
    }

    /// Subscribes a running group to streams added since it started (and drops removed ones).
    fn resubscribe(&self, g: &Arc<Group>) -> Result<(), GroupError> {
        let mut runner = g
            .runner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let Some(r) = runner.as_mut() else {
            return Ok(());
        };
        let routes = self.routes(&g.core())?;
        *r.routes
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = routes;
        Ok(())
    }

    /// Recomputes a group's symbols and streams from its formulas: one stream per value
    /// symbol, one per spatial target. Streams are only ever appended (their indices are the
    /// synchroniser's); one no formula needs becomes inactive.
    fn restream(&self, core: &mut Core) {
        let symbols: BTreeSet<Symbol> = core.grounded.iter().flatten().flatten().cloned().collect();
        // The library's out tags are read only when a spatial symbol needs them.
        let offered = std::cell::OnceCell::new();
        let has = |t: &str| offered.get_or_init(|| self.out_tags()).contains(t);
        let mut map = BTreeMap::new();
        let mut used = BTreeSet::new();
        for s in symbols {
            let tag = target_tag(&s, &core.def.grounding, &has);
            let kind = if s.is_spatial() {
                StreamKind::Spatial
            } else {
                StreamKind::Value(s.key())
            };
            let found = core
                .streams
                .iter()
                .position(|x| x.tag == tag && x.kind == kind);
            let i = match found {
                Some(i) => {
                    if !core.streams[i].active {
                        core.streams[i].active = true;
                        core.sync.reactivate_stream(i);
                    }
                    i
                }
                None => {
                    let i = core.sync.add_stream();
                    core.streams.push(StreamInfo {
                        tag,
                        kind,
                        active: true,
                    });
                    i
                }
            };
            used.insert(i);
            map.insert(s, i);
        }
        for (i, s) in core.streams.iter_mut().enumerate() {
            if !used.contains(&i) && s.active {
                s.active = false;
                core.sync.remove_stream(i);
            }
        }
        core.symbols = map;
    }

    /// The out-port tag values of the library's transformations.
    fn out_tags(&self) -> BTreeSet<String> {
        let mut out = BTreeSet::new();
        if let Ok(specs) = self.kb.specs(SpecKind::Transformation) {
            for s in specs {
                if let Spec::Transformation(t) = s {
                    for p in &t.outputs {
                        out.extend(p.tags.iter().filter_map(|t| t.value.clone()));
                    }
                }
            }
        }
        out
    }

    fn persist(&self, core: &Core) -> Result<(), GroupError> {
        match &self.store {
            Some(s) => s.save(&core.def).map_err(GroupError::Internal),
            None => Ok(()),
        }
    }

    /// The groups that need each group target: label → group labels.
    pub fn target_users(&self) -> BTreeMap<String, Vec<String>> {
        let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
        for g in self.list() {
            let core = g.core();
            if core.def.phase == Phase::Stopped {
                continue;
            }
            let labels: BTreeSet<String> = core
                .streams
                .iter()
                .filter(|s| s.active)
                .map(|s| s.tag.label())
                .collect();
            for l in labels {
                out.entry(l).or_default().push(g.label.clone());
            }
        }
        out
    }

    /// The group whose verdicts go to `channel` now (one not stopped), if any: a target on
    /// that channel would have its stream mixed with verdict lines.
    pub fn result_channel_user(&self, channel: &str) -> Option<String> {
        let name = bare(channel);
        self.list().into_iter().find_map(|g| {
            let core = g.core();
            (core.def.phase != Phase::Stopped && bare(&core.def.result_channel) == name)
                .then(|| g.label.clone())
        })
    }

    /// Refuses a result channel that is a stream of the configuration: verdict lines written
    /// on a CU's input crash it, and on a target's channel they mix with the stream the
    /// target asked for. So not a channel a CU reads or writes now, nor a target's channel,
    /// nor one of the channels the engine names (`ch-N`: a later review may wire CUs through
    /// it), nor a symbol channel (`/dyknow/symbols/...`, groups' own targets).
    fn check_result_channel(&self, channel: &str) -> Result<(), GroupError> {
        let name = bare(channel);
        let refuse = |why: String| -> Result<(), GroupError> {
            Err(SpecError::Invalid(format!(
                "result_channel {channel:?} {why}: verdicts would be written into that stream; \
                 choose another channel"
            ))
            .into())
        };
        if name.starts_with("dyknow/symbols/") {
            return refuse("is a symbol channel".into());
        }
        if Channel::from(name).minted_number().is_some() {
            return refuse("is a name the engine gives channels between CUs".into());
        }
        let environment = self
            .lifecycle
            .cus()
            .map_err(|e| GroupError::Internal(e.to_string()))?;
        for cu in environment.cus.values() {
            let ports = cu.inputs.iter().chain(&cu.outputs);
            for (port, bound) in ports {
                if bound.as_ref().is_some_and(|c| bare(c.as_str()) == name) {
                    return refuse(format!("is bound to port {port:?} of CU {}", cu.cid));
                }
            }
        }
        let targets = self
            .kb
            .specs(SpecKind::Target)
            .map_err(|e| GroupError::Internal(e.to_string()))?;
        for spec in targets {
            if let Spec::Target(target) = spec
                && bare(&target.channel) == name
            {
                return refuse(format!("is the channel of target {:?}", target.label));
            }
        }
        Ok(())
    }

    /// Makes the group targets in the knowledge base match what the groups need: posts the
    /// missing ones, releases the others.
    pub fn sync_targets(&self) -> Result<(), GroupError> {
        let _guard = self
            .targets
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut needed: BTreeMap<String, TargetTag> = BTreeMap::new();
        for g in self.list() {
            let core = g.core();
            if core.def.phase == Phase::Stopped {
                continue;
            }
            for s in core.streams.iter().filter(|s| s.active) {
                let label = s.tag.label();
                // Restored from before labels told descriptions apart, or too long for a
                // label since: said, and left out (one such target refused the whole post).
                if label.len() > dyknow_store::spec::MAX_LABEL_BYTES {
                    tracing::error!(
                        "group {:?}: the target of {label:.80}… would have a label over {} bytes; \
                         it is not posted",
                        g.label,
                        dyknow_store::spec::MAX_LABEL_BYTES
                    );
                    continue;
                }
                match needed.get(&label) {
                    Some(other) if *other != s.tag => tracing::error!(
                        "group {:?}: {label:?} names two tags ({other:?} and {:?}, a tag value \
                         beginning with '<' restored from before it was refused): the first is \
                         kept",
                        g.label,
                        s.tag
                    ),
                    Some(_) => {}
                    None => {
                        needed.insert(label, s.tag.clone());
                    }
                }
            }
        }
        let internal = |e: &dyn std::fmt::Display| GroupError::Internal(e.to_string());
        // A stored target that asks for something else than its label's tag now does (a
        // description and a value spelled alike shared one until 2026-11-29) is replaced.
        let mut existing: BTreeSet<String> = BTreeSet::new();
        let mut outdated: Vec<String> = Vec::new();
        for spec in self.kb.specs(SpecKind::Target).map_err(|e| internal(&e))? {
            let Spec::Target(t) = spec else { continue };
            if !t.label.starts_with(TARGET_PREFIX) {
                continue;
            }
            if let Some(tag) = needed.get(&t.label)
                && !asks_for(&t, tag)
            {
                outdated.push(t.label.clone());
            }
            existing.insert(t.label);
        }
        for label in &outdated {
            tracing::warn!("target {label:?} asked for another tag or channel: replaced");
            self.kb
                .remove_spec(SpecKind::Target, label)
                .map_err(|e| internal(&e))?;
            existing.remove(label);
            self.lifecycle
                .report(Perturbation::TargetReleased {
                    target: label.clone().into(),
                })
                .map_err(|e| internal(&e))?;
        }
        let missing: Vec<&TargetTag> = needed
            .iter()
            .filter(|(l, _)| !existing.contains(*l))
            .map(|(_, t)| t)
            .collect();
        if !missing.is_empty() {
            let doc = target_turtle(&missing);
            let report = self
                .kb
                .post_specs(
                    doc.as_bytes(),
                    dyknow_store::InputFormat::Turtle,
                    SpecKind::Target,
                )
                .map_err(|e| internal(&e))?;
            for label in report.labels {
                self.lifecycle
                    .report(Perturbation::TargetAdded {
                        target: label.into(),
                    })
                    .map_err(|e| internal(&e))?;
            }
        }
        for label in existing.iter().filter(|l| !needed.contains_key(*l)) {
            self.kb
                .remove_spec(SpecKind::Target, label)
                .map_err(|e| internal(&e))?;
            self.lifecycle
                .report(Perturbation::TargetReleased {
                    target: label.clone().into(),
                })
                .map_err(|e| internal(&e))?;
        }
        Ok(())
    }

    /// Publishes verdicts: recorded, sent to SSE watchers and to the result channel.
    fn publish(&self, g: &Group, core: &mut Core, verdicts: Vec<VerdictLine>) {
        for v in verdicts {
            core.verdicts.push(v);
            let _ = g.events.send(v);
            if let Some(plane) = &self.plane
                && let Ok(key) = plane.namespace.channel(&core.def.result_channel)
            {
                let sample = dyknow_cu::Sample::new(
                    i64::try_from(v.t).unwrap_or(i64::MAX),
                    json!({"group": g.label, "formula": v.formula, "verdict": v.verdict.as_str()}),
                );
                let _ = plane
                    .session
                    .put(key, sample.to_bytes())
                    .encoding(zenoh::bytes::Encoding::APPLICATION_JSON)
                    .wait();
            }
        }
    }

    /// Stops every running group's thread (the service is stopping); they stay `running` on
    /// disk and resume at the next start.
    pub fn shutdown(&self) {
        for g in self.list() {
            Self::stop_runner(&g);
            g.core().writer.sync();
        }
    }
}

/// Whether a stored target asks for `tag` on the channel the service gives it.
fn asks_for(target: &dyknow_store::spec::TargetSpec, tag: &TargetTag) -> bool {
    let asked = match tag {
        TargetTag::Value(v) => dyknow_store::spec::Tag {
            value: Some(v.clone()),
            description: None,
        },
        TargetTag::Description(iri) => dyknow_store::spec::Tag {
            value: None,
            description: Some(iri.clone()),
        },
    };
    target.tags == [asked] && target.channel == tag.channel()
}

/// The Turtle of group targets.
fn target_turtle(tags: &[&TargetTag]) -> String {
    let lit = |s: &str| serde_json::to_string(s).unwrap_or_default();
    let mut doc = String::from(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n",
    );
    for t in tags {
        let tag = match t {
            TargetTag::Value(v) => format!("dyknow:hasValue {}", lit(v)),
            TargetTag::Description(iri) => format!("dyknow:hasTagDescription <{iri}>"),
        };
        doc.push_str(&format!(
            "[] a dyknow:Target ; rdfs:label {} ;\n   dyknow:hasChannel [ a dyknow:Channel ; dyknow:hasChannelName {} ] ;\n   dyknow:hasTag [ a dyknow:Tag ; {tag} ] .\n",
            lit(&t.label()),
            lit(&t.channel())
        ));
    }
    doc
}

/// A channel's name without its leading `/` (`/a` and `a` are one channel).
fn bare(channel: &str) -> &str {
    channel.strip_prefix('/').unwrap_or(channel)
}

/// A running group's thread: samples and deadlines in, states and verdicts out.
fn progress(groups: &std::sync::Weak<Groups>, g: &Arc<Group>, rx: &mpsc::Receiver<Input>) {
    let mut last_sync = Instant::now();
    loop {
        let deadline = g.core().sync.next_deadline();
        let first = match deadline {
            Some(d) => {
                let wait = d.saturating_sub(now_ms());
                match rx.recv_timeout(Duration::from_millis(wait.clamp(1, 1000))) {
                    Ok(i) => Some(i),
                    Err(mpsc::RecvTimeoutError::Timeout) => None,
                    Err(mpsc::RecvTimeoutError::Disconnected) => return,
                }
            }
            None => match rx.recv_timeout(Duration::from_secs(1)) {
                Ok(i) => Some(i),
                Err(mpsc::RecvTimeoutError::Timeout) => None,
                Err(mpsc::RecvTimeoutError::Disconnected) => return,
            },
        };
        let Some(groups) = groups.upgrade() else {
            return;
        };
        let mut core = g.core();
        let mut states = Vec::new();
        let mut input = first;
        let mut taken = 0;
        loop {
            match input {
                Some(Input::Stop) => {
                    core.writer.flush();
                    return;
                }
                Some(Input::Sample { stream, t, value }) => {
                    states.extend(core.sync.offer(stream, t, value, now_ms()));
                }
                None => {}
            }
            taken += 1;
            if taken >= 512 {
                break;
            }
            input = match rx.try_recv() {
                Ok(i) => Some(i),
                Err(_) => break,
            };
        }
        states.extend(core.sync.poll(now_ms()));
        let kinds: Vec<StreamKind> = core.streams.iter().map(|s| s.kind.clone()).collect();
        for s in states {
            let t = core.prog.take(&kinds, &s);
            if let Some(why) = t.dropped_spatial {
                core.dropped_spatial += 1;
                core.last_dropped = Some(format!("t={}: {why}", s.t));
            }
            if let Some(line) = &t.line {
                core.writer.append(line);
            }
            groups.publish(g, &mut core, t.verdicts);
        }
        core.writer.flush();
        if last_sync.elapsed() >= Duration::from_secs(1) {
            core.writer.sync();
            last_sync = Instant::now();
        }
    }
}

/// A group as `GET /groups/{label}` shows it. The targets' producers are looked up after the
/// group's lock is released, so a status read never stalls progression.
pub fn status(groups: &Groups, g: &Group) -> Json {
    let (mut value, channels) = {
        let core = g.core();
        let decided: BTreeMap<usize, VerdictLine> =
            core.verdicts.iter().map(|v| (v.formula, *v)).collect();
        let formulas: Vec<Json> = core
            .def
            .formulas
            .iter()
            .filter(|f| f.removed_at.is_none())
            .map(|f| {
                let v = decided.get(&f.index);
                json!({
                    "index": f.index,
                    "formula": f.formula,
                    "verdict": v.map(|v| v.verdict.as_str()),
                    "t": v.map(|v| v.t),
                })
            })
            .collect();
        let mut channels = Vec::new();
        let symbols: Vec<Json> = core
            .symbols
            .iter()
            .map(|(symbol, &i)| {
                let s = &core.streams[i];
                let stats = core.sync.stats(i);
                let channel = s.tag.channel();
                channels.push(channel.clone());
                json!({
                    "symbol": symbol.key(),
                    "target": s.tag.label(),
                    "channel": channel,
                    "satisfied": false,
                    "producer": null,
                    "samples": stats.samples,
                    "late": stats.late,
                    "missing_states": stats.missing_states,
                })
            })
            .collect();
        let value = json!({
            "label": g.label,
            "state": core.def.phase,
            "result_channel": core.def.result_channel,
            "formulas": formulas,
            "symbols": symbols,
            "states": core.prog.states(),
            "last_t": core.prog.last_t(),
            "sync": core.def.sync.filled(),
            "domains": core.def.header.domains,
            "landmarks": core.def.header.landmarks,
            "static": core.def.header.static_regions,
            "grounding": core.def.grounding,
            "resumed": core.def.resumed,
            "dropped_spatial_states": core.dropped_spatial,
            "last_dropped_spatial": core.last_dropped,
        });
        (value, channels)
    };
    // A stopped group reads no stream and needs no target: its symbols are not satisfied,
    // whatever another group or the engine's next review does with their targets.
    if value["state"] == json!(Phase::Stopped) {
        return value;
    }
    let mut producers: BTreeMap<String, Option<String>> = BTreeMap::new();
    for (i, channel) in channels.iter().enumerate() {
        let producer = producers
            .entry(channel.clone())
            .or_insert_with(|| groups.kb.channel_producer(channel).ok().flatten())
            .clone();
        value["symbols"][i]["satisfied"] = json!(producer.is_some());
        value["symbols"][i]["producer"] = json!(producer);
    }
    value
}

impl Group {
    /// The label.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The verdicts recorded so far, and a receiver of the ones to come (subscribed before
    /// the snapshot, so none is missed; a formula's verdict may then come twice, and
    /// watchers skip formulas they have seen).
    /// The third is set once the group is stopped: every verdict sent before it.
    pub fn watch(
        &self,
    ) -> (
        Vec<VerdictLine>,
        broadcast::Receiver<VerdictLine>,
        tokio::sync::watch::Receiver<bool>,
    ) {
        let rx = self.events.subscribe();
        let stopped = self.stopped.subscribe();
        let recorded = self.core().verdicts.clone();
        (recorded, rx, stopped)
    }

    /// The recorded trace: the header line and one line per state. The header lists the
    /// formulas with the states each was progressed over (added or removed while the group
    /// ran), so `dyknow check` on the trace alone replays the group's verdicts (`groups.md`).
    pub fn trace(&self, groups: &Groups) -> Result<String, GroupError> {
        let mut core = self.core();
        let header = replay_header(&core.def);
        let text = if let Some(text) = core.writer.text() {
            text.to_owned()
        } else {
            core.writer.flush();
            // Read under the lock: the thread appends only whole batches of lines under it.
            match &groups.store {
                Some(s) => s.trace(&self.label).map_err(GroupError::Internal)?,
                None => String::new(),
            }
        };
        // The header as recorded at creation is the first line; the states follow.
        let states = text.split_once('\n').map_or("", |(_, rest)| rest);
        Ok(format!("{header}\n{states}"))
    }
}
