//! The manager's view of its executors on Zenoh (`executors.md`): which are present (their
//! liveliness tokens), what each can run, which CU runs where. [`Fleet`] is the
//! [`Executor`] of a service with real executors: it places spawned CUs, sends each executor
//! the actions for its CUs in order and waits for the acknowledgements, and turns what
//! executors report (crashes, measured costs, executors coming and going) into
//! [`FleetEvent`]s for the service to hand to the [`crate::Manager`].

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use dyknow_cu::Namespace;
use dyknow_cu::keys::InstanceId;
use dyknow_cu::protocol::{
    ApplyReply, ApplyRequest, CheckReply, CuAction, CuReport, Event, ExecutorInfo, Implementation,
    Kind, param_value,
};
use dyknow_cu::zenoh::pubsub::Subscriber;
use dyknow_cu::zenoh::{self, Wait};
use dyknow_engine::{Action, ActionFailure, ChangeSet, Cid, CuOutcome, CuOutcomeState, Tid};
use dyknow_store::spec::TransformationSpec;
use serde::Serialize;
use tokio::sync::mpsc;

use crate::executor::{Applied, CuView, Executor, ReportedCu};

mod membership;
mod sweep;
use membership::Token;

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// What the fleet tells the service.
#[derive(Debug, Clone, PartialEq)]
pub enum FleetEvent {
    /// An executor appeared or vanished: what is runnable may have changed.
    ExecutorsChanged,
    /// An executor appeared, running these CUs (none for a fresh one; those it kept running
    /// while the manager was away or cut off from it): the manager reconciles them with its
    /// model (adopts, stops).
    Appeared {
        /// The executor.
        executor: String,
        /// The CUs it runs.
        cus: Vec<ReportedCu>,
    },
    /// A CU crashed (reported by its executor).
    Crashed {
        /// The CU.
        cu: Cid,
        /// Why.
        reason: String,
    },
    /// An executor vanished: the CUs placed on it crashed, all at once. One event, so that
    /// the manager records every crash before a review can start, and one review repairs
    /// them all, its cause naming each.
    Vanished {
        /// The executor.
        executor: String,
        /// The CUs placed on it.
        cus: Vec<Cid>,
    },
    /// The labour of a CU that now runs, in CPU ms.
    Labour {
        /// Its transformation.
        transformation: Tid,
        /// CPU ms.
        cpu_ms: f64,
    },
    /// The CPU time a CU's callbacks used over an interval.
    Upkeep {
        /// The CU.
        cu: Cid,
        /// CPU ms used.
        cpu_ms: f64,
        /// Over this many wall ms.
        over_ms: f64,
    },
}

#[derive(Debug, Default)]
struct Known {
    present: bool,
    /// Since when it is absent (its token went down), while it is.
    absent_since: Option<Instant>,
    builtins: BTreeSet<String>,
    processes: bool,
    /// Answers of its `check` service, by command line, and when they came: a refusal is
    /// asked again after [`REFUSAL_KEPT`] (the program may be installed since).
    checks: BTreeMap<String, (Result<(), String>, Instant)>,
}

/// How long an executor's answer that it cannot run a command line is kept before it is asked
/// again. A yes is kept until the executor reappears.
pub const REFUSAL_KEPT: Duration = Duration::from_secs(5);

struct Inner {
    session: zenoh::Session,
    namespace: Namespace,
    executors: Mutex<BTreeMap<String, Known>>,
    placement: Mutex<BTreeMap<Cid, String>>,
    /// The placed CUs known to run: their spawn was acknowledged, their executor said they
    /// run, or reconciliation adopted them. A placed CU not in it is starting. Locked after
    /// `placement` when both are.
    running: Mutex<BTreeSet<Cid>>,
    /// Each executor's token as the liveliness subscriber last said: whether it is up, and
    /// its epoch (how many times it went up or down), which dates an executor's answers.
    tokens: Mutex<BTreeMap<String, Token>>,
    /// The live instances of each executor name ([`Namespace::executor_instance`]); the
    /// first (the earliest started) holds the name, the others are stepping down. Locked
    /// after `tokens` when both are.
    instances: Mutex<BTreeMap<String, BTreeSet<InstanceId>>>,
    events: mpsc::UnboundedSender<FleetEvent>,
    /// Whether the manager itself ran of late ([`membership::Pulse`]).
    pulse: membership::Pulse,
    /// Executors whose token went down during a stall of the manager, with the instance
    /// they were and the CUs placed on them then ([`membership::Grace`]). Locked after
    /// `tokens`, before `executors`, `placement` and `running`.
    graces: Mutex<BTreeMap<String, membership::Grace>>,
    /// The CUs the change set being applied acts on: the sweep leaves them alone
    /// ([`sweep`]). Locked after `placement` and `running`.
    applying: Mutex<BTreeSet<Cid>>,
    /// Set by [`Fleet::stop_watching`]: the sweep ends.
    swept: std::sync::atomic::AtomicBool,
    /// How long an absent executor stays listed, in ms ([`Fleet::forget_absent_after`]).
    forget_after_ms: std::sync::atomic::AtomicU64,
}

/// How long an absent executor stays in `GET /executors` unless
/// [`Fleet::forget_absent_after`] says otherwise.
pub const FORGET_ABSENT_AFTER: Duration = Duration::from_secs(600);

/// The executors as the manager sees them.
pub struct Fleet {
    inner: Arc<Inner>,
    /// The token and event subscribers, until [`Fleet::stop_watching`].
    subscribers: Mutex<Vec<Subscriber<()>>>,
}

impl std::fmt::Debug for Fleet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fleet").finish_non_exhaustive()
    }
}

/// An executor as `GET /executors` lists it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ExecutorSummary {
    /// Its name.
    pub name: String,
    /// Whether its token is present.
    pub present: bool,
    /// The labels of the transformations it can run.
    pub transformations: Vec<String>,
    /// The CUs it hosts.
    pub cus: Vec<String>,
    /// The instance the manager took its `info` from, while present (`None` for an executor
    /// that does not say which it is).
    pub instance: Option<InstanceId>,
}

/// The implementation a spec names.
pub fn implementation(spec: &TransformationSpec) -> Implementation {
    Implementation {
        kind: spec.exec_type.clone().unwrap_or_default(),
        source: spec.source.clone().unwrap_or_default(),
        params: spec
            .params
            .iter()
            .map(|p| (p.name.clone(), param_value(&p.value, Some(&p.datatype))))
            .collect(),
        executor: spec.executor.clone(),
        inputs: spec.inputs.iter().map(|p| p.name.clone()).collect(),
        outputs: spec.outputs.iter().map(|p| p.name.clone()).collect(),
    }
}

const QUERY_TIMEOUT: Duration = Duration::from_secs(5);

impl Fleet {
    /// Watches the executors of `namespace` on `session`. The receiver gets the events.
    pub fn start(
        session: &zenoh::Session,
        namespace: Namespace,
    ) -> Result<(Self, mpsc::UnboundedReceiver<FleetEvent>), zenoh::Error> {
        let (tx, rx) = mpsc::unbounded_channel();
        let inner = Arc::new(Inner {
            session: session.clone(),
            namespace: namespace.clone(),
            executors: Mutex::default(),
            placement: Mutex::default(),
            running: Mutex::default(),
            tokens: Mutex::default(),
            instances: Mutex::default(),
            events: tx,
            pulse: membership::Pulse::default(),
            graces: Mutex::default(),
            applying: Mutex::default(),
            swept: std::sync::atomic::AtomicBool::new(false),
            forget_after_ms: std::sync::atomic::AtomicU64::new(
                u64::try_from(FORGET_ABSENT_AFTER.as_millis()).unwrap_or(u64::MAX),
            ),
        });
        membership::Pulse::start(&inner);
        sweep::start(&inner);
        let [instances, tokens] = membership::watch(&inner, session, &namespace)?;
        let reporter = inner.clone();
        let events = session
            .declare_subscriber(namespace.all_executor_events())
            .callback(move |sample| {
                // `<ns>/@dyknow/events/<executor>`: who says it.
                let Some(executor) = sample.key_expr().as_str().rsplit('/').next() else {
                    return;
                };
                match serde_json::from_slice::<Event>(&sample.payload().to_bytes()) {
                    Ok(event) => reporter.event(executor, event),
                    Err(e) => tracing::debug!("an event of {executor} that does not parse: {e}"),
                }
            })
            .wait()?;
        Ok((
            Self {
                inner,
                subscribers: Mutex::new(vec![tokens, instances, events]),
            },
            rx,
        ))
    }

    /// The executors, with what each can run of `specs`.
    pub fn executors(&self, specs: &BTreeMap<Tid, TransformationSpec>) -> Vec<ExecutorSummary> {
        let names: Vec<String> = lock(&self.inner.executors).keys().cloned().collect();
        let placement = lock(&self.inner.placement).clone();
        names
            .into_iter()
            .map(|name| {
                let present = lock(&self.inner.executors)
                    .get(&name)
                    .is_some_and(|k| k.present);
                ExecutorSummary {
                    transformations: specs
                        .iter()
                        .filter(|(_, s)| {
                            present
                                && s.executor.as_ref().is_none_or(|e| *e == name)
                                && self.inner.can_run(&name, s).is_ok()
                        })
                        .map(|(t, _)| t.to_string())
                        .collect(),
                    cus: placement
                        .iter()
                        .filter(|(_, e)| **e == name)
                        .map(|(c, _)| c.to_string())
                        .collect(),
                    present,
                    instance: self.inner.taken(&name),
                    name,
                }
            })
            .collect()
    }

    /// How long an executor that went away stays listed (absent) by [`Fleet::executors`]
    /// before the fleet forgets it ([`FORGET_ABSENT_AFTER`] unless set): executors named
    /// afresh on every start (after a container's host name, say) would otherwise pile up.
    /// One that comes back after is listed again, as any executor that appears.
    pub fn forget_absent_after(&self, after: Duration) {
        let ms = u64::try_from(after.as_millis()).unwrap_or(u64::MAX);
        (self.inner.forget_after_ms).store(ms, std::sync::atomic::Ordering::SeqCst);
    }

    /// Stops watching the executors' tokens and events (the service is stopping): its own
    /// executor stopping next is not an executor vanishing.
    pub fn stop_watching(&self) {
        (self.inner.swept).store(true, std::sync::atomic::Ordering::SeqCst);
        for subscriber in std::mem::take(&mut *lock(&self.subscribers)) {
            let _ = subscriber.undeclare().wait();
        }
    }

    /// Waits until an executor named `name` is present (for start-up and tests).
    pub fn wait_for(&self, name: &str, timeout: Duration) -> bool {
        let deadline = std::time::Instant::now() + timeout;
        while std::time::Instant::now() < deadline {
            if lock(&self.inner.executors)
                .get(name)
                .is_some_and(|k| k.present)
            {
                return true;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        false
    }
}

impl Inner {
    fn event(&self, executor: &str, event: Event) {
        let out = {
            let mut placement = lock(&self.placement);
            let cu = Cid::from(event_cu(&event));
            let runs = matches!(event, Event::Running { .. });
            let placed = placement.get(&cu).map(String::as_str);
            let out = executor_event(executor, placed, event);
            match &out {
                Some(FleetEvent::Crashed { cu, .. }) => {
                    placement.remove(cu);
                    lock(&self.running).remove(cu);
                }
                Some(_) if runs => {
                    lock(&self.running).insert(cu);
                }
                _ => {}
            }
            out
        };
        if let Some(out) = out {
            let _ = self.events.send(out);
        }
    }

    /// Asks executor `name`'s `service`; `None` when it does not answer in time.
    fn query<T: serde::de::DeserializeOwned>(
        &self,
        name: &str,
        service: &str,
        payload: Vec<u8>,
    ) -> Option<T> {
        self.query_for(name, service, payload, QUERY_TIMEOUT).ok()
    }

    /// Asks `executor` to destroy `cus` (one request, labelled `what`); those it could not
    /// destroy, with why.
    fn destroy(
        &self,
        executor: &str,
        cus: &[Cid],
        what: &str,
        generation: u64,
    ) -> Vec<(Cid, String)> {
        if cus.is_empty() {
            return Vec::new();
        }
        let request = ApplyRequest {
            change_set: what.to_owned(),
            generation,
            instance: self.holder(executor),
            actions: cus
                .iter()
                .map(|cu| CuAction::Destroy { cu: cu.to_string() })
                .collect(),
        };
        let payload = serde_json::to_vec(&request).unwrap_or_default();
        match self.query_for::<ApplyReply>(executor, "apply", payload, QUERY_TIMEOUT) {
            Ok(reply) => reply
                .failures
                .into_iter()
                .map(|f| (f.cu.into(), f.reason))
                .collect(),
            Err(why) => cus.iter().map(|cu| (cu.clone(), why.clone())).collect(),
        }
    }

    /// [`Inner::destroy`] of CUs the model dropped, on a thread of its own: the caller (a
    /// review, a request) does not wait for an executor that may not answer. One that does
    /// not runs them until it reconciles, which stops what the model lacks.
    fn stop_in_background(inner: &Arc<Self>, orphans: BTreeMap<String, Vec<Cid>>, generation: u64) {
        if orphans.is_empty() {
            return;
        }
        let inner = inner.clone();
        let _ = std::thread::Builder::new()
            .name("fleet-orphans".into())
            .spawn(move || {
                for (executor, cus) in orphans {
                    let failed = inner.destroy(&executor, &cus, "orphans", generation);
                    for cu in cus.iter().filter(|c| !failed.iter().any(|(f, _)| f == *c)) {
                        tracing::info!(
                            "stopped {cu} on {executor}: the model dropped it (crash reported or action failed)"
                        );
                    }
                    for (cu, why) in failed {
                        tracing::debug!("could not stop {cu} on {executor} (it may be gone): {why}");
                    }
                }
            });
    }

    fn query_for<T: serde::de::DeserializeOwned>(
        &self,
        name: &str,
        service: &str,
        payload: Vec<u8>,
        timeout: Duration,
    ) -> Result<T, String> {
        self.query_where(name, service, payload, timeout, |_| true)
    }

    /// Asks executor `name`'s `service`; the first answer that parses and that `accept`s.
    /// (Two instances of one name answer while the later steps down.)
    fn query_where<T: serde::de::DeserializeOwned>(
        &self,
        name: &str,
        service: &str,
        payload: Vec<u8>,
        timeout: Duration,
        accept: impl Fn(&T) -> bool,
    ) -> Result<T, String> {
        // Every reply, not Zenoh's default of the latest per key: two instances of one name
        // answer on the same key.
        let asked = Instant::now();
        let replies = self
            .session
            .get(self.namespace.executor_service(name, service))
            .payload(payload)
            .consolidation(zenoh::query::ConsolidationMode::None)
            .timeout(timeout)
            .wait()
            .map_err(|e| e.to_string())?;
        // Why nothing counted: the first error, else that only another instance answered.
        let (mut error, mut other) = (None, false);
        while let Ok(reply) = replies.recv() {
            match reply.result() {
                Ok(sample) => match serde_json::from_slice::<T>(&sample.payload().to_bytes()) {
                    Ok(answer) if accept(&answer) => return Ok(answer),
                    Ok(_) => other = true,
                    Err(e) => {
                        error.get_or_insert_with(|| {
                            format!("executor {name} answered nonsense: {e}")
                        });
                    }
                },
                Err(e) => {
                    error.get_or_insert_with(|| {
                        format!(
                            "executor {name}: {}",
                            String::from_utf8_lossy(&e.payload().to_bytes())
                        )
                    });
                }
            }
        }
        Err(error.unwrap_or_else(|| {
            let waited = asked.elapsed();
            if other {
                format!("executor {name}: only another instance of the name answered")
            } else if waited + Duration::from_millis(50) < timeout {
                // Zenoh ended the request early: the executor's queryable went away (it
                // vanished, or left the network) before it answered.
                format!(
                    "executor {name} went away before it answered (the request ended after \
                     {:.1} s of the {:.1} s it had)",
                    waited.as_secs_f64(),
                    timeout.as_secs_f64()
                )
            } else {
                format!(
                    "executor {name} did not answer within {:.1} s",
                    timeout.as_secs_f64()
                )
            }
        }))
    }

    /// Whether executor `name` (present) can run `spec`.
    fn can_run(&self, name: &str, spec: &TransformationSpec) -> Result<(), String> {
        let implementation = implementation(spec);
        let kind = implementation.kind()?;
        let executors = lock(&self.executors);
        let Some(known) = executors.get(name).filter(|k| k.present) else {
            return Err(format!("executor {name} is not present"));
        };
        match kind {
            Kind::Builtin => {
                if known.builtins.contains(&implementation.source) {
                    Ok(())
                } else {
                    Err(format!(
                        "no present executor has the builtin {:?}",
                        implementation.source
                    ))
                }
            }
            Kind::Process => {
                if !known.processes {
                    return Err(format!("executor {name} runs no processes"));
                }
                if let Some((answer, at)) = known.checks.get(&implementation.source)
                    && (answer.is_ok() || at.elapsed() < REFUSAL_KEPT)
                {
                    return answer.clone();
                }
                drop(executors);
                let payload = serde_json::to_vec(&implementation).unwrap_or_default();
                let answer = match self.query::<CheckReply>(name, "check", payload) {
                    Some(CheckReply { runnable: true, .. }) => Ok(()),
                    Some(CheckReply { why, .. }) => {
                        Err(why.unwrap_or_else(|| "the executor cannot run it".into()))
                    }
                    None => return Err(format!("executor {name} did not answer")),
                };
                // Not while two instances share the name: the answer may be the one's that
                // steps down (another host, other programs).
                let shared = lock(&self.instances).get(name).is_some_and(|l| l.len() > 1);
                if !shared && let Some(known) = lock(&self.executors).get_mut(name) {
                    known.checks.insert(
                        implementation.source.clone(),
                        (answer.clone(), Instant::now()),
                    );
                }
                answer
            }
        }
    }

    /// The executors that could run `spec`, fewest CUs first.
    fn candidates(&self, spec: &TransformationSpec) -> Result<Vec<String>, String> {
        if spec.exec_type.is_none() {
            return Err("it names no implementation (no dkros:hasType): an abstract transformation no executor runs".into());
        }
        let names: Vec<String> = lock(&self.executors)
            .iter()
            .filter(|(n, k)| k.present && spec.executor.as_ref().is_none_or(|e| e == *n))
            .map(|(n, _)| n.clone())
            .collect();
        if names.is_empty() {
            return Err(match &spec.executor {
                Some(e) => format!("it is pinned to executor {e}, which is not present"),
                None => "no executor is present".into(),
            });
        }
        let mut why = None;
        let mut able = Vec::new();
        for name in names {
            match self.can_run(&name, spec) {
                Ok(()) => able.push(name),
                Err(e) => why = Some(e),
            }
        }
        if able.is_empty() {
            return Err(why.unwrap_or_else(|| "no executor can run it".into()));
        }
        let placement = lock(&self.placement);
        able.sort_by_key(|n| placement.values().filter(|e| *e == n).count());
        Ok(able)
    }
}

impl Executor for Fleet {
    fn runnable(&self, spec: &TransformationSpec) -> Result<(), String> {
        self.inner.candidates(spec).map(|_| ())
    }

    fn apply(&self, change_set: &ChangeSet, specs: &BTreeMap<Tid, TransformationSpec>) -> Applied {
        let inner = &self.inner;
        // The sweep leaves the CUs it acts on alone until it is done.
        *lock(&inner.applying) = change_set
            .actions
            .iter()
            .filter_map(Action::cu)
            .cloned()
            .collect();
        let _applying = Cleared(&inner.applying);
        let mut failures: Vec<ActionFailure> = Vec::new();
        // Per executor, in order of first appearance: (index in the change set, action). The
        // destroys come after every other batch: a change set makes before it breaks (COMPILE
        // puts destroys last), and across executors too, so a producer on one executor is not
        // stopped before its replacement on another runs. (A CU's destroy is its last action:
        // its order with its own actions stays.)
        let mut batches: Vec<(String, Vec<(usize, CuAction)>)> = Vec::new();
        let mut destroys: Vec<(String, Vec<(usize, CuAction)>)> = Vec::new();
        let last_action: BTreeMap<&Cid, usize> = change_set
            .actions
            .iter()
            .enumerate()
            .filter_map(|(i, a)| Some((a.cu()?, i)))
            .collect();
        let mut placed: BTreeMap<Cid, String> = lock(&inner.placement).clone();
        let mut spawned_processes: BTreeMap<String, u32> = BTreeMap::new();
        let mut spawned: Vec<(Cid, String)> = Vec::new();
        for (index, action) in change_set.actions.iter().enumerate() {
            let Some(cu) = action.cu() else { continue };
            if failures.iter().any(|f| &f.cu == cu) {
                continue;
            }
            let fail = |reason: String| ActionFailure {
                action: index,
                cu: cu.clone(),
                reason,
            };
            let (executor, cu_action) = match action {
                Action::Spawn { transformation, .. } => {
                    let Some(spec) = specs.get(transformation) else {
                        failures.push(fail(format!("no transformation {transformation}")));
                        continue;
                    };
                    // The fewest CUs counts this change set's spawns so far: its CUs are
                    // spread, not all put where there were fewest before it.
                    let executor = match inner.candidates(spec) {
                        Ok(able) => able
                            .iter()
                            .min_by_key(|n| placed.values().filter(|e| e == n).count())
                            .unwrap_or(&able[0])
                            .clone(),
                        Err(why) => {
                            failures.push(fail(why));
                            continue;
                        }
                    };
                    let implementation = implementation(spec);
                    if implementation.kind() == Ok(Kind::Process) {
                        *spawned_processes.entry(executor.clone()).or_default() += 1;
                    }
                    placed.insert(cu.clone(), executor.clone());
                    spawned.push((cu.clone(), executor.clone()));
                    (
                        executor,
                        CuAction::Spawn {
                            cu: cu.to_string(),
                            transformation: transformation.to_string(),
                            implementation,
                        },
                    )
                }
                other => {
                    let Some(executor) = placed.get(cu).cloned() else {
                        if matches!(other, Action::Destroy { .. }) {
                            // Not running anywhere: already gone.
                            continue;
                        }
                        failures.push(fail(format!("{cu} runs on no executor")));
                        continue;
                    };
                    let cu_action = match other {
                        Action::Destroy { cu } => CuAction::Destroy { cu: cu.to_string() },
                        Action::ConnectIn { cu, port, channel } => CuAction::ConnectIn {
                            cu: cu.to_string(),
                            port: port.clone(),
                            channel: channel.to_string(),
                        },
                        Action::ConnectOut { cu, port, channel } => CuAction::ConnectOut {
                            cu: cu.to_string(),
                            port: port.clone(),
                            channel: channel.to_string(),
                        },
                        Action::DisconnectIn { cu, port } => CuAction::DisconnectIn {
                            cu: cu.to_string(),
                            port: port.clone(),
                        },
                        Action::DisconnectOut { cu, port } => CuAction::DisconnectOut {
                            cu: cu.to_string(),
                            port: port.clone(),
                        },
                        _ => continue,
                    };
                    (executor, cu_action)
                }
            };
            let batches = if matches!(cu_action, CuAction::Destroy { .. })
                && last_action.get(cu) == Some(&index)
            {
                &mut destroys
            } else {
                &mut batches
            };
            match batches.iter_mut().find(|(e, _)| *e == executor) {
                Some((_, actions)) => actions.push((index, cu_action)),
                None => batches.push((executor, vec![(index, cu_action)])),
            }
        }
        // A CU is placed on its executor from the moment its spawn is sent: what that
        // executor reports about it while the change set is applied (it runs, it crashed) is
        // taken, what others report is not (`executor_event`).
        {
            let mut placement = lock(&inner.placement);
            let mut running = lock(&inner.running);
            for (cu, executor) in spawned {
                running.remove(&cu);
                placement.insert(cu, executor);
            }
        }
        // The last executor's destroys can ride with its other actions: every other executor
        // has had its turn by then (one request, not two, when a single executor is involved).
        if let Some((last, actions)) = batches.last_mut()
            && let Some(k) = destroys.iter().position(|(e, _)| e == last)
        {
            actions.extend(destroys.remove(k).1);
        }
        let destroying = batches.len();
        batches.extend(destroys);
        for (batch, (executor, actions)) in batches.into_iter().enumerate() {
            let indices: Vec<usize> = actions.iter().map(|(i, _)| *i).collect();
            let request = ApplyRequest {
                change_set: change_set.id.to_string(),
                generation: change_set.id.number().unwrap_or(0),
                instance: inner.holder(&executor),
                actions: actions.into_iter().map(|(_, a)| a).collect(),
            };
            let processes = if batch < destroying {
                spawned_processes.get(&executor).copied().unwrap_or(0)
            } else {
                0
            };
            let timeout = QUERY_TIMEOUT + Duration::from_secs(10) * processes;
            let payload = serde_json::to_vec(&request).unwrap_or_default();
            match inner.query_for::<ApplyReply>(&executor, "apply", payload, timeout) {
                Ok(reply) => {
                    for f in reply.failures {
                        if let Some(&index) = indices.get(f.index) {
                            failures.push(ActionFailure {
                                action: index,
                                cu: f.cu.into(),
                                reason: f.reason,
                            });
                        }
                    }
                }
                Err(why) => {
                    // Unacknowledged: every CU it touched is treated as lost.
                    for (k, action) in request.actions.iter().enumerate() {
                        let cu: Cid = action.cu().into();
                        if !failures.iter().any(|f| f.cu == cu) {
                            failures.push(ActionFailure {
                                action: indices[k],
                                cu,
                                reason: why.clone(),
                            });
                        }
                    }
                }
            }
        }
        // A process an executor failed to start: its cached yes for that command line goes,
        // so the next question asks it again (a program deleted since was tried by every
        // review, each change set failing, while the transformation showed runnable).
        for failure in &failures {
            if let Some(Action::Spawn { transformation, .. }) =
                change_set.actions.get(failure.action)
                && let Some(spec) = specs.get(transformation)
                && spec.exec_type.as_deref() == Some("process")
                && let Some(executor) = placed.get(&failure.cu)
                && let Some(known) = lock(&inner.executors).get_mut(executor)
            {
                known
                    .checks
                    .remove(spec.source.as_deref().unwrap_or_default());
            }
        }
        // What became of each CU it touched, before the placement forgets the lost ones.
        let mut cus = BTreeMap::new();
        for action in &change_set.actions {
            let Some(cu) = action.cu() else { continue };
            let state = if failures.iter().any(|f| &f.cu == cu) {
                CuOutcomeState::Crashed
            } else if matches!(action, Action::Destroy { .. }) {
                CuOutcomeState::Stopped
            } else if cus.contains_key(cu) {
                continue;
            } else {
                CuOutcomeState::Running
            };
            let executor = placed.get(cu).cloned();
            cus.insert(cu.clone(), CuOutcome { executor, state });
        }
        // Only what this change set changed: a crash reported while it was applied has
        // removed its CU already, and stays removed.
        let mut placement = lock(&inner.placement);
        let mut running = lock(&inner.running);
        for action in &change_set.actions {
            if let Action::Destroy { cu } = action {
                placement.remove(cu);
                running.remove(cu);
            }
        }
        let orphans = forget(&mut placement, &mut running, failures.iter().map(|f| &f.cu));
        // Acknowledged: a spawned CU runs once its executor answered (it waits for it).
        for (cu, outcome) in &cus {
            if outcome.state == CuOutcomeState::Running
                && outcome.executor.is_some()
                && placement.get(cu) == outcome.executor.as_ref()
            {
                running.insert(cu.clone());
            }
        }
        drop(running);
        drop(placement);
        // The model drops them: where one may still run (a rewiring failed, the executor did
        // not answer in time), it is stopped, not left publishing beside its replacement.
        Inner::stop_in_background(inner, orphans, change_set.id.number().unwrap_or(0));
        failures.sort_by_key(|f| f.action);
        Applied { failures, cus }
    }

    fn abandon(&self, cus: &[Cid]) {
        let orphans = forget(
            &mut lock(&self.inner.placement),
            &mut lock(&self.inner.running),
            cus,
        );
        Inner::stop_in_background(&self.inner, orphans, 0);
    }

    fn describe(&self, cu: &Cid) -> Option<CuView> {
        self.describe_all(std::slice::from_ref(cu)).remove(cu)
    }

    fn settling(&self) -> bool {
        !lock(&self.inner.graces).is_empty()
    }

    fn placed(&self, cu: &Cid) -> Option<String> {
        lock(&self.inner.placement).get(cu).cloned()
    }

    fn adopt(&self, executor: &str, cus: &[Cid]) {
        let mut placement = lock(&self.inner.placement);
        let mut running = lock(&self.inner.running);
        for cu in cus {
            placement.insert(cu.clone(), executor.to_owned());
            running.insert(cu.clone());
        }
    }

    fn stop(&self, executor: &str, cus: &[Cid], generation: u64) -> Vec<(Cid, String)> {
        self.inner.destroy(
            executor,
            cus,
            &format!("reconcile@{generation}"),
            generation,
        )
    }

    /// The placement and what the acknowledgements and events said: no query.
    fn last_heard(&self, cus: &[Cid]) -> BTreeMap<Cid, CuView> {
        let placement = lock(&self.inner.placement);
        let running = lock(&self.inner.running);
        cus.iter()
            .map(|cu| {
                let view = match placement.get(cu) {
                    Some(executor) => CuView {
                        executor: Some(executor.clone()),
                        state: if running.contains(cu) {
                            "running"
                        } else {
                            "starting"
                        }
                        .to_owned(),
                        statistics: serde_json::json!({}),
                        pid: None,
                    },
                    None => lost_view(None),
                };
                (cu.clone(), view)
            })
            .collect()
    }

    /// One `info` query per executor involved, however many CUs it hosts.
    fn describe_all(&self, cus: &[Cid]) -> BTreeMap<Cid, CuView> {
        let placement = lock(&self.inner.placement).clone();
        let mut by_executor: BTreeMap<&str, Vec<&Cid>> = BTreeMap::new();
        let mut views = BTreeMap::new();
        for cu in cus {
            match placement.get(cu) {
                Some(executor) => by_executor.entry(executor).or_default().push(cu),
                // Planned, but no executor hosts it (lost with its executor, or failed).
                None => {
                    views.insert(cu.clone(), lost_view(None));
                }
            }
        }
        for (executor, hosted) in by_executor {
            let info: Option<ExecutorInfo> = (self.inner)
                .query_where(executor, "info", Vec::new(), QUERY_TIMEOUT, |info| {
                    self.inner.answered_by_holder(executor, info)
                })
                .ok();
            // No answer in time (a busy or cut-off executor): what was last heard of its CUs,
            // not a crash nobody saw (a crash is an event of its own, or the executor's token
            // going).
            let Some(info) = info else {
                let cus: Vec<Cid> = hosted.into_iter().cloned().collect();
                views.extend(self.last_heard(&cus));
                continue;
            };
            let mut reports: BTreeMap<String, CuReport> =
                info.cus.into_iter().map(|c| (c.cu.clone(), c)).collect();
            for cu in hosted {
                let view = match reports.remove(cu.as_str()) {
                    Some(report) => CuView {
                        executor: Some(executor.to_owned()),
                        state: serde_json::to_value(report.state)
                            .ok()
                            .and_then(|v| v.as_str().map(str::to_owned))
                            .unwrap_or_default(),
                        statistics: serde_json::to_value(report.statistics).unwrap_or_default(),
                        pid: report.pid,
                    },
                    None => lost_view(Some(executor.to_owned())),
                };
                views.insert(cu.clone(), view);
            }
        }
        views
    }
}

/// Empties [`Inner::applying`] when a change set's application ends.
struct Cleared<'a>(&'a Mutex<BTreeSet<Cid>>);

impl Drop for Cleared<'_> {
    fn drop(&mut self) {
        lock(self.0).clear();
    }
}

/// Forgets where `cus` run: those that were placed, by executor (to be stopped there).
fn forget<'a>(
    placement: &mut BTreeMap<Cid, String>,
    running: &mut BTreeSet<Cid>,
    cus: impl IntoIterator<Item = &'a Cid>,
) -> BTreeMap<String, Vec<Cid>> {
    let mut orphans: BTreeMap<String, Vec<Cid>> = BTreeMap::new();
    for cu in cus {
        running.remove(cu);
        if let Some(executor) = placement.remove(cu) {
            orphans.entry(executor).or_default().push(cu.clone());
        }
    }
    orphans
}

/// The CU an executor's event is about.
fn event_cu(event: &Event) -> &str {
    match event {
        Event::Running { cu, .. } | Event::CuCrashed { cu, .. } | Event::Upkeep { cu, .. } => cu,
    }
}

/// What the manager makes of an event `executor` published on its key
/// (`<ns>/@dyknow/events/<executor>`), given where the fleet places its CU (`placed`; a CU is
/// placed from the moment its spawn is sent). Only events about a CU placed on the sender are
/// taken: a stale or confused peer cannot crash, or skew the costs of, a CU it does not host.
/// (The sender is named by the key: telling an impostor from the real executor is the job of
/// Zenoh's access control, docs/reliability.md.) A CU placed nowhere is not running for the
/// manager; after a restart, reconciliation finds out what runs.
pub fn executor_event(executor: &str, placed: Option<&str>, event: Event) -> Option<FleetEvent> {
    if placed != Some(executor) {
        tracing::debug!(
            "ignoring an event of {executor} about {}, which runs {}",
            event_cu(&event),
            placed.map_or_else(|| "nowhere".to_owned(), |host| format!("on {host}"))
        );
        return None;
    }
    Some(match event {
        Event::Running {
            transformation,
            labour_cpu_ms,
            ..
        } => FleetEvent::Labour {
            transformation: transformation.into(),
            cpu_ms: labour_cpu_ms,
        },
        Event::CuCrashed { cu, reason, .. } => FleetEvent::Crashed {
            cu: cu.into(),
            reason,
        },
        Event::Upkeep {
            cu,
            cpu_ms,
            over_ms,
            ..
        } => FleetEvent::Upkeep {
            cu: cu.into(),
            cpu_ms,
            over_ms,
        },
    })
}

/// The event of an executor that appeared and described itself (its `info`).
pub fn appeared(executor: &str, info: ExecutorInfo) -> FleetEvent {
    FleetEvent::Appeared {
        executor: executor.to_owned(),
        cus: info.cus.into_iter().map(reported).collect(),
    }
}

/// A CU report as reconciliation reads it.
fn reported(report: CuReport) -> ReportedCu {
    let channels = |ports: BTreeMap<String, Option<String>>| {
        ports
            .into_iter()
            .map(|(port, channel)| (port, channel.map(Into::into)))
            .collect()
    };
    ReportedCu {
        cu: report.cu.into(),
        transformation: report.transformation.into(),
        inputs: channels(report.inputs),
        outputs: channels(report.outputs),
        generation: report.generation,
    }
}

/// A CU the model has and no executor reports: crashed, until a review repairs it.
fn lost_view(executor: Option<String>) -> CuView {
    CuView {
        executor,
        state: "crashed".into(),
        statistics: serde_json::json!({}),
        pid: None,
    }
}
