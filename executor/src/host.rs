//! The executor (`executors.md`, *Executors*): hosts builtin CUs as [`Unit`]s on its Zenoh
//! session and process CUs as children, applies the actions of change sets to them in order
//! and acknowledges them, reports crashes and measured costs as [`Event`]s, and holds a
//! liveliness token while it runs. Its services answer on Zenoh queryables
//! (`docs/executors.md`); requests are carried out one at a time on a worker thread,
//! never on a Zenoh callback thread.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError, mpsc};
use std::time::{Duration, Instant};

use dyknow_cu::keys::{InstanceId, InstanceKey};
use dyknow_cu::protocol::{
    ApplyReply, ApplyRequest, CheckReply, CuAction, CuReport, Event, ExecutorInfo, Failure,
    Implementation, InfoRequest, Kind,
};
use dyknow_cu::zenoh::bytes::Encoding;
use dyknow_cu::zenoh::liveliness::LivelinessToken;
use dyknow_cu::zenoh::pubsub::{Publisher, Subscriber};
use dyknow_cu::zenoh::query::{Query, Queryable};
use dyknow_cu::zenoh::sample::SampleKind;
use dyknow_cu::zenoh::{self, Wait};
use dyknow_cu::{CuError, Namespace, Timers, Unit, UnitSpec};

use crate::builtins::{self, Host};
use crate::process::{Launch, OnCrash, ProcessCu, resolve};

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// An executor's settings.
#[derive(Debug, Clone)]
pub struct ExecutorConfig {
    /// Its name (one key-expression chunk).
    pub name: String,
    /// The key namespace.
    pub namespace: Namespace,
    /// Endpoints its process CUs connect to.
    pub process_connect: Vec<String>,
    /// How often it reports the upkeep of its CUs.
    pub report_interval: Duration,
    /// How long a process CU may take to announce itself.
    pub start_timeout: Duration,
    /// Zenoh's own configuration file its process CUs read too (`DYKNOW_ZENOH_CONFIG`: the
    /// TLS certificates for `tls/` endpoints), if any.
    pub zenoh_config: Option<std::path::PathBuf>,
    /// Zenoh's link lease its process CUs declare (`DYKNOW_ZENOH_LEASE_MS`), in milliseconds:
    /// the executor's own `--zenoh-lease-ms`, so that a hung process CU is noticed as soon as
    /// a hung executor is. `None`: the configuration file's, else Zenoh's 10 s.
    pub zenoh_lease_ms: Option<u64>,
    /// Called once if the executor steps down for an earlier executor of its name
    /// ([`Executor::start`]), after it stopped, with that executor's instance.
    pub on_step_down: Option<OnStepDown>,
}

/// What to do when an executor steps down ([`ExecutorConfig::on_step_down`]).
#[derive(Clone)]
pub struct OnStepDown(pub Arc<dyn Fn(&InstanceId) + Send + Sync>);

impl std::fmt::Debug for OnStepDown {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("OnStepDown")
    }
}

impl ExecutorConfig {
    /// Settings with defaults: upkeep reported every second, 10 s for a process to start.
    pub fn new(
        name: impl Into<String>,
        namespace: Namespace,
        process_connect: Vec<String>,
    ) -> Self {
        Self {
            name: name.into(),
            namespace,
            process_connect,
            report_interval: Duration::from_secs(1),
            start_timeout: Duration::from_secs(10),
            zenoh_config: None,
            zenoh_lease_ms: None,
            on_step_down: None,
        }
    }
}

#[derive(Clone)]
enum Hosted {
    Builtin(Unit),
    Process(Arc<ProcessCu>),
}

impl Hosted {
    fn report(&self) -> CuReport {
        match self {
            Self::Builtin(u) => u.report(),
            Self::Process(p) => p.report(),
        }
    }

    fn stop(&self) {
        match self {
            Self::Builtin(u) => u.stop(),
            Self::Process(p) => p.stop(Duration::from_millis(500)),
        }
    }

    fn cpu(&self) -> Duration {
        match self {
            Self::Builtin(u) => u.cpu(),
            Self::Process(p) => p.cpu().saturating_sub(p.labour()),
        }
    }

    fn transformation(&self) -> String {
        match self {
            Self::Builtin(u) => u.spec().transformation.clone(),
            Self::Process(p) => p.report_transformation(),
        }
    }
}

impl ProcessCu {
    fn report_transformation(&self) -> String {
        // Cheap: no statistics request.
        self.spec_transformation()
    }
}

struct Inner {
    config: ExecutorConfig,
    /// This run of the executor.
    instance: InstanceId,
    session: zenoh::Session,
    timers: Timers,
    cus: Mutex<BTreeMap<String, Hosted>>,
    /// Per CU, the generation of the last change set that configured it
    /// ([`ApplyRequest::generation`]).
    generations: Mutex<BTreeMap<String, u64>>,
    /// CPU time at the last upkeep report, per CU.
    reported: Mutex<BTreeMap<String, (Duration, Instant)>>,
    events: Publisher<'static>,
    /// The same key, for measured costs (`Upkeep`), which may be dropped when the link is
    /// congested.
    costs: Publisher<'static>,
    jobs: mpsc::Sender<Job>,
}

enum Job {
    Query(Query, &'static str),
    Crashed { cu: String, reason: String },
    Report,
    Stop(mpsc::Sender<()>),
}

/// A running executor. [`Executor::shutdown`] (or dropping the last handle) stops its CUs and
/// withdraws its token.
pub struct Executor {
    parts: Arc<Parts>,
}

/// What an executor holds, shared with the watch on its name (which may stop it).
struct Parts {
    inner: Arc<Inner>,
    /// Its instance token, then its name's token.
    tokens: Mutex<Vec<LivelinessToken>>,
    /// The watch on the instance tokens of its name.
    watch: Mutex<Option<Subscriber<()>>>,
    /// The instances of its name that started before it and whose tokens are up.
    earlier: Arc<Mutex<Earlier>>,
    queryables: Mutex<Vec<Queryable<()>>>,
    worker: Mutex<Option<std::thread::JoinHandle<()>>>,
    /// Held while it stops: a second caller waits until its CUs are stopped.
    stopping: Mutex<()>,
    /// The earlier instance it stepped down for, once it has.
    stepped_down: Mutex<Option<InstanceId>>,
}

/// The earlier instances of an executor's name on the data plane, as its watch saw them.
#[derive(Default)]
struct Earlier {
    live: std::collections::BTreeSet<InstanceId>,
    /// A thread is checking whether they answer.
    checking: bool,
}

impl std::fmt::Debug for Executor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Executor")
            .field("name", &self.parts.inner.config.name)
            .field("instance", &self.parts.inner.instance)
            .finish_non_exhaustive()
    }
}

impl Executor {
    /// Starts an executor on `session`: its services, its worker, its upkeep reports, then
    /// its token (so whoever sees the token can use the services).
    ///
    /// Names are unique on a data plane: the manager knows an executor by its name, so a
    /// second executor of a name that is present is refused (an error, before anything is
    /// declared). Were it let in, its leaving would make the first one look gone.
    ///
    /// Two executors of one name can still meet: one started while cut off from the other
    /// (before its link came up, or across a partition) is not refused. Each instance holds a
    /// token of its own under its name ([`Namespace::executor_instance`]) and watches the
    /// others': the one that started later steps down when it sees the other, as it would
    /// have been refused had it seen it at its start. It first asks for the `info` of its
    /// name, and steps down only once the earlier one answers: a token can outlive its
    /// executor until Zenoh's lease expires (a host gone without closing its link), and an executor restarted under
    /// its name must not give way to its own ghost. Stepping down, it stops its CUs, withdraws
    /// its tokens and services, logs why, and calls [`ExecutorConfig::on_step_down`].
    /// Meanwhile it answers no request addressed to the other instance.
    pub fn start(session: &zenoh::Session, config: ExecutorConfig) -> Result<Self, CuError> {
        dyknow_cu::keys::check_name("executor name", &config.name)?;
        let ns = config.namespace.clone();
        let present = session
            .liveliness()
            .get(ns.executor_token(&config.name))
            .timeout(Duration::from_secs(2))
            .wait()?;
        while let Ok(reply) = present.recv() {
            if reply.result().is_ok() {
                return Err(CuError::failed(format!(
                    "an executor named {} is present already on this data plane; names must be \
                     unique (one cut off without its link closing counts until its Zenoh lease \
                     expires)",
                    config.name
                )));
            }
        }
        // A CU's start and crash wait for room rather than being dropped (Zenoh's default for
        // a put): a lost crash event left a crashed CU in the model as running (the manager's
        // sweep finds such a CU, seconds later; `docs/reliability.md`, crash storms). Measured
        // costs, sent every interval, may be dropped: the next interval's comes.
        let events = session
            .declare_publisher(ns.executor_events(&config.name))
            .encoding(Encoding::APPLICATION_JSON)
            .congestion_control(zenoh::qos::CongestionControl::Block)
            .wait()?;
        let costs = session
            .declare_publisher(ns.executor_events(&config.name))
            .encoding(Encoding::APPLICATION_JSON)
            .congestion_control(zenoh::qos::CongestionControl::Drop)
            .wait()?;
        let (jobs, rx) = mpsc::channel::<Job>();
        let inner = Arc::new(Inner {
            config: config.clone(),
            instance: InstanceId::now(session.zid().to_string()),
            session: session.clone(),
            timers: Timers::start(),
            cus: Mutex::default(),
            generations: Mutex::default(),
            reported: Mutex::default(),
            events,
            costs,
            jobs,
        });
        let worker_inner = inner.clone();
        let worker = std::thread::Builder::new()
            .name(format!("executor-{}", config.name))
            .spawn(move || worker_inner.work(&rx))
            .map_err(|e| CuError::failed(format!("cannot start the worker: {e}")))?;
        let parts = Arc::new(Parts {
            inner: inner.clone(),
            tokens: Mutex::default(),
            watch: Mutex::default(),
            earlier: Arc::default(),
            queryables: Mutex::default(),
            worker: Mutex::new(Some(worker)),
            stopping: Mutex::default(),
            stepped_down: Mutex::default(),
        });
        // What fails from here on stops what started.
        if let Err(e) = Self::declare(&parts, session) {
            parts.shutdown();
            return Err(e);
        }
        tracing::info!(
            "executor {} is up (instance {})",
            config.name,
            inner.instance
        );
        Ok(Self { parts })
    }

    /// [`Executor::start`]'s declarations: its services, its upkeep reports, its instance's
    /// token, the watch on its name's other instances, then its name's token.
    fn declare(parts: &Arc<Parts>, session: &zenoh::Session) -> Result<(), CuError> {
        let inner = &parts.inner;
        let (config, ns) = (&inner.config, &inner.config.namespace);
        // `info` and `check` are answered on a thread of their own: they only read, and a
        // change set that starts processes keeps the worker for seconds, longer than the
        // manager waits for an answer (it would take every CU here for crashed).
        let (reads, reads_rx) = mpsc::channel::<Job>();
        let reader_inner = inner.clone();
        std::thread::Builder::new()
            .name(format!("executor-{}-reads", config.name))
            .spawn(move || {
                while let Ok(job) = reads_rx.recv() {
                    if let Job::Query(query, service) = job {
                        reader_inner.answer(&query, service);
                    }
                }
            })
            .map_err(|e| CuError::failed(format!("cannot start the reader: {e}")))?;
        for service in ["apply", "info", "check"] {
            let jobs = if service == "apply" {
                inner.jobs.clone()
            } else {
                reads.clone()
            };
            let queryable = session
                .declare_queryable(ns.executor_service(&config.name, service))
                .callback(move |query| {
                    let _ = jobs.send(Job::Query(query, service));
                })
                .wait()?;
            lock(&parts.queryables).push(queryable);
        }
        let ticker = inner.jobs.clone();
        let interval = config.report_interval;
        let _ = std::thread::Builder::new()
            .name(format!("executor-{}-upkeep", config.name))
            .spawn(move || {
                loop {
                    std::thread::sleep(interval);
                    if ticker.send(Job::Report).is_err() {
                        return;
                    }
                }
            });
        let token = session
            .liveliness()
            .declare_token(ns.executor_instance(&config.name, &inner.instance))
            .wait()?;
        lock(&parts.tokens).push(token);
        // The callback holds what it tracks, and the executor only weakly: it never drops
        // the executor on a Zenoh thread.
        let (earlier, executor) = (parts.earlier.clone(), Arc::downgrade(parts));
        let own = inner.instance.clone();
        let watch = session
            .liveliness()
            .declare_subscriber(ns.executor_instances(&config.name))
            .history(true)
            .callback(move |sample| {
                let Some(key) = InstanceKey::parse(sample.key_expr().as_str()) else {
                    return;
                };
                if key.instance >= own {
                    return;
                }
                let mut tracked = lock(&earlier);
                if sample.kind() == SampleKind::Delete {
                    tracked.live.remove(&key.instance);
                    return;
                }
                tracked.live.insert(key.instance);
                if !std::mem::replace(&mut tracked.checking, true) {
                    let executor = executor.clone();
                    // It asks, and stopping undeclares this very subscriber: not from its
                    // callback.
                    let started = std::thread::Builder::new()
                        .name("executor-step-down".into())
                        .spawn(move || Parts::check_earlier(&executor));
                    tracked.checking = started.is_ok();
                }
            })
            .wait()?;
        *lock(&parts.watch) = Some(watch);
        let token = session
            .liveliness()
            .declare_token(ns.executor_token(&config.name))
            .wait()?;
        lock(&parts.tokens).push(token);
        Ok(())
    }

    /// Its name.
    pub fn name(&self) -> &str {
        &self.parts.inner.config.name
    }

    /// This run of it.
    pub fn instance(&self) -> &InstanceId {
        &self.parts.inner.instance
    }

    /// The instance of its name it stepped down for, if it did ([`Executor::start`]).
    pub fn stepped_down(&self) -> Option<InstanceId> {
        lock(&self.parts.stepped_down).clone()
    }

    /// Its description now.
    pub fn info(&self) -> ExecutorInfo {
        self.parts.inner.info()
    }

    /// Applies a request directly (what its `apply` service does).
    pub fn apply(&self, request: &ApplyRequest) -> ApplyReply {
        self.parts.inner.apply(request)
    }

    /// The pids of its process CUs.
    pub fn pids(&self) -> Vec<(String, u32)> {
        lock(&self.parts.inner.cus)
            .iter()
            .filter_map(|(n, h)| match h {
                Hosted::Process(p) => Some((n.clone(), p.pid())),
                Hosted::Builtin(_) => None,
            })
            .collect()
    }

    /// Stops every CU (children are asked to exit, then killed), withdraws the token and the
    /// services, and ends the worker. Idempotent.
    pub fn shutdown(&self) {
        self.parts.shutdown();
    }
}

impl Parts {
    fn shutdown(&self) {
        let _stopping = lock(&self.stopping);
        lock(&self.watch).take();
        lock(&self.queryables).clear();
        let worker = lock(&self.worker).take();
        if let Some(worker) = worker {
            let (done, wait) = mpsc::channel();
            if self.inner.jobs.send(Job::Stop(done)).is_ok() {
                let _ = wait.recv_timeout(Duration::from_secs(30));
            }
            let _ = worker.join();
        }
        lock(&self.tokens).clear();
    }

    /// Instances of its name that started earlier are on the data plane: while their tokens
    /// stay up, they are asked for their `info` (a query of up to 2 s, then a pause of 1 s);
    /// once one answers, this one
    /// steps down for it. Ends when none is left, or this executor stopped.
    fn check_earlier(parts: &std::sync::Weak<Self>) {
        loop {
            let Some(this) = parts.upgrade() else {
                return;
            };
            {
                let mut earlier = lock(&this.earlier);
                if earlier.live.is_empty() || lock(&this.worker).is_none() {
                    earlier.checking = false;
                    return;
                }
            }
            let answering = this.answering();
            let alive = lock(&this.earlier)
                .live
                .iter()
                .find(|i| answering.contains(*i))
                .cloned();
            if let Some(alive) = alive {
                this.step_down(&alive);
                return;
            }
            drop(this);
            std::thread::sleep(Duration::from_secs(1));
        }
    }

    /// The instances of its name that answer its `info` service now.
    fn answering(&self) -> std::collections::BTreeSet<InstanceId> {
        let key = self
            .inner
            .config
            .namespace
            .executor_service(&self.inner.config.name, "info");
        // Every reply, not Zenoh's default of the latest per key: each instance answers on
        // the same key.
        let Ok(replies) = self
            .inner
            .session
            .get(key)
            .consolidation(zenoh::query::ConsolidationMode::None)
            .timeout(Duration::from_secs(2))
            .wait()
        else {
            return std::collections::BTreeSet::new();
        };
        replies
            .iter()
            .filter_map(|reply| {
                let sample = reply.result().ok()?;
                serde_json::from_slice::<ExecutorInfo>(&sample.payload().to_bytes())
                    .ok()?
                    .instance
            })
            .collect()
    }

    /// The earlier instance `earlier` of its name answers: it gives the name up (once).
    fn step_down(&self, earlier: &InstanceId) {
        {
            let mut stepped_down = lock(&self.stepped_down);
            if stepped_down.is_some() || lock(&self.worker).is_none() {
                return;
            }
            *stepped_down = Some(earlier.clone());
        }
        let name = &self.inner.config.name;
        tracing::error!(
            "executor {name} steps down: another executor named {name} (instance {earlier}) \
             started before this one (instance {}) and is on this data plane now; names must \
             be unique. Its CUs stop; the manager replans them",
            self.inner.instance
        );
        self.shutdown();
        if let Some(OnStepDown(hook)) = &self.inner.config.on_step_down {
            hook(earlier);
        }
    }
}

impl Drop for Executor {
    fn drop(&mut self) {
        self.shutdown();
    }
}

impl Inner {
    fn work(self: &Arc<Self>, jobs: &mpsc::Receiver<Job>) {
        while let Ok(job) = jobs.recv() {
            match job {
                Job::Query(query, service) => self.answer(&query, service),
                Job::Crashed { cu, reason } => self.crashed(&cu, &reason),
                Job::Report => self.report_upkeep(),
                Job::Stop(done) => {
                    let cus = std::mem::take(&mut *lock(&self.cus));
                    for (_, hosted) in cus {
                        hosted.stop();
                    }
                    let _ = done.send(());
                    return;
                }
            }
        }
    }

    fn answer(self: &Arc<Self>, query: &Query, service: &str) {
        let payload = query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let reply: Result<Vec<u8>, String> = match service {
            "apply" => match serde_json::from_slice::<ApplyRequest>(&payload) {
                Err(e) => Err(format!("not an apply request: {e}")),
                // For the other instance of the name, which answers it: not a word from here.
                Ok(r) if r.instance.as_ref().is_some_and(|i| *i != self.instance) => {
                    tracing::debug!(
                        "executor {}: {} is for instance {:?}, not this one ({})",
                        self.config.name,
                        r.change_set,
                        r.instance,
                        self.instance
                    );
                    return;
                }
                Ok(r) => Ok(serde_json::to_vec(&self.apply(&r)).unwrap_or_default()),
            },
            "check" => serde_json::from_slice::<Implementation>(&payload)
                .map_err(|e| format!("not an implementation: {e}"))
                .map(|i| serde_json::to_vec(&check(&i)).unwrap_or_default()),
            _ => {
                let statistics =
                    serde_json::from_slice::<InfoRequest>(&payload).map_or(true, |r| r.statistics);
                Ok(serde_json::to_vec(&self.info_with(statistics)).unwrap_or_default())
            }
        };
        let sent = match reply {
            Ok(bytes) => query.reply(query.key_expr().clone(), bytes).wait(),
            Err(e) => query.reply_err(e.into_bytes()).wait(),
        };
        if let Err(e) = sent {
            tracing::warn!(
                "executor {}: cannot answer {service}: {e}",
                self.config.name
            );
        }
    }

    fn info(&self) -> ExecutorInfo {
        self.info_with(true)
    }

    /// The `info` answer; without `statistics`, process CUs are not asked (reported with the
    /// statistics they gave last).
    fn info_with(&self, statistics: bool) -> ExecutorInfo {
        ExecutorInfo {
            name: self.config.name.clone(),
            builtins: builtins::names(),
            processes: true,
            cus: {
                let generations = lock(&self.generations).clone();
                // Reported outside the lock: a process CU's report asks the process, and a
                // change set being applied meanwhile must not wait for that.
                let hosted: Vec<Hosted> = lock(&self.cus).values().cloned().collect();
                // Process CUs are asked at once, each on a thread of its own: a hung one waits
                // out its 500 ms, not one after another (ten hung CUs took 5 s, the manager's
                // timeout for the whole answer).
                let reports: Vec<CuReport> = std::thread::scope(|scope| {
                    let asked: Vec<_> = hosted
                        .iter()
                        .map(|hosted| match hosted {
                            Hosted::Process(_) if statistics => {
                                Err(scope.spawn(|| hosted.report()))
                            }
                            Hosted::Process(p) => Ok(p.report_last()),
                            Hosted::Builtin(_) => Ok(hosted.report()),
                        })
                        .collect();
                    asked
                        .into_iter()
                        .filter_map(|a| match a {
                            Ok(report) => Some(report),
                            Err(thread) => thread.join().ok(),
                        })
                        .collect()
                });
                reports
                    .into_iter()
                    .map(|mut report| {
                        report.generation = generations.get(&report.cu).copied().unwrap_or(0);
                        report
                    })
                    .collect()
            },
            instance: Some(self.instance.clone()),
        }
    }

    fn publish(&self, event: &Event) {
        let payload = serde_json::to_vec(event).unwrap_or_default();
        let publisher = match event {
            Event::Upkeep { .. } => &self.costs,
            _ => &self.events,
        };
        if let Err(e) = publisher.put(payload).wait() {
            tracing::warn!(
                "executor {}: cannot publish an event: {e}",
                self.config.name
            );
        }
    }

    fn on_crash(self: &Arc<Self>) -> OnCrash {
        let jobs = self.jobs.clone();
        Arc::new(move |cu: &str, reason: &str| {
            let _ = jobs.send(Job::Crashed {
                cu: cu.to_owned(),
                reason: reason.to_owned(),
            });
        })
    }

    fn crashed(&self, cu: &str, reason: &str) {
        let Some(hosted) = lock(&self.cus).remove(cu) else {
            return;
        };
        lock(&self.reported).remove(cu);
        lock(&self.generations).remove(cu);
        let transformation = hosted.transformation();
        match &hosted {
            Hosted::Builtin(unit) => unit.release(),
            Hosted::Process(p) => p.kill(),
        }
        tracing::warn!("executor {}: {cu} crashed: {reason}", self.config.name);
        self.publish(&Event::CuCrashed {
            cu: cu.to_owned(),
            transformation,
            reason: reason.to_owned(),
        });
    }

    fn report_upkeep(&self) {
        let now = Instant::now();
        let cpus: Vec<(String, String, Duration)> = lock(&self.cus)
            .iter()
            .map(|(n, h)| (n.clone(), h.transformation(), h.cpu()))
            .collect();
        let mut reported = lock(&self.reported);
        for (cu, transformation, cpu) in cpus {
            let (last_cpu, last_at) = reported.get(&cu).copied().unwrap_or((Duration::ZERO, now));
            reported.insert(cu.clone(), (cpu, now));
            let over = now.duration_since(last_at);
            if over.is_zero() {
                continue;
            }
            self.publish(&Event::Upkeep {
                cu,
                transformation,
                cpu_ms: cpu.saturating_sub(last_cpu).as_secs_f64() * 1e3,
                over_ms: over.as_secs_f64() * 1e3,
            });
        }
    }

    /// Applies the actions in order; after a failure, the later actions of that CU are
    /// skipped. An action other than destroy on a CU a newer change set configured (a higher
    /// generation) is refused: the request is stale.
    fn apply(self: &Arc<Self>, request: &ApplyRequest) -> ApplyReply {
        if let Some(other) = request.instance.as_ref().filter(|i| **i != self.instance) {
            let reason = format!(
                "{} is for instance {other} of executor {}, not for this one ({})",
                request.change_set, self.config.name, self.instance
            );
            return ApplyReply {
                failures: (request.actions.iter().enumerate())
                    .map(|(index, action)| Failure {
                        index,
                        cu: action.cu().to_owned(),
                        reason: reason.clone(),
                    })
                    .collect(),
            };
        }
        let mut failures: Vec<Failure> = Vec::new();
        for (index, action) in request.actions.iter().enumerate() {
            if failures.iter().any(|f| f.cu == action.cu()) {
                continue;
            }
            let newest = lock(&self.generations).get(action.cu()).copied();
            let result = match newest {
                Some(newer)
                    if newer > request.generation
                        && !matches!(action, CuAction::Destroy { .. }) =>
                {
                    Err(CuError::failed(format!(
                        "stale change set: {} (generation {}) is older than generation {newer}, which last configured {}",
                        request.change_set,
                        request.generation,
                        action.cu()
                    )))
                }
                _ => {
                    if let CuAction::Spawn { cu, .. } = action {
                        self.replace_stale(cu, request);
                    }
                    self.act(action)
                }
            };
            match &result {
                Ok(()) if matches!(action, CuAction::Destroy { .. }) => {
                    lock(&self.generations).remove(action.cu());
                }
                Ok(()) => {
                    let mut generations = lock(&self.generations);
                    let g = generations.entry(action.cu().to_owned()).or_default();
                    *g = (*g).max(request.generation);
                }
                Err(_) => {}
            }
            if let Err(e) = result {
                tracing::warn!(
                    "executor {}: {} {} of {}: {e}",
                    self.config.name,
                    action.kind(),
                    action.cu(),
                    request.change_set
                );
                failures.push(Failure {
                    index,
                    cu: action.cu().to_owned(),
                    reason: e.to_string(),
                });
            }
        }
        ApplyReply { failures }
    }

    /// A spawn of a CU that already runs here from an older (or the same) generation: a
    /// restarted manager that never recorded the change set which spawned it gives the name
    /// again. The newer change set wins: the stale CU stops first.
    fn replace_stale(&self, cu: &str, request: &ApplyRequest) {
        if request.generation == 0 {
            return;
        }
        let stale = lock(&self.generations)
            .get(cu)
            .is_some_and(|g| *g <= request.generation);
        if !stale {
            return;
        }
        let hosted = lock(&self.cus).remove(cu);
        lock(&self.reported).remove(cu);
        lock(&self.generations).remove(cu);
        if let Some(hosted) = hosted {
            tracing::warn!(
                "executor {}: {cu} runs from an older change set; {} replaces it",
                self.config.name,
                request.change_set
            );
            hosted.stop();
        }
    }

    fn act(self: &Arc<Self>, action: &CuAction) -> Result<(), CuError> {
        match action {
            CuAction::Spawn {
                cu,
                transformation,
                implementation,
            } => self.spawn(cu, transformation, implementation),
            CuAction::Destroy { cu } => {
                let hosted = lock(&self.cus).remove(cu);
                lock(&self.reported).remove(cu);
                if let Some(hosted) = hosted {
                    hosted.stop();
                }
                Ok(())
            }
            CuAction::ConnectIn { cu, port, channel } => self.bind(cu, true, port, Some(channel)),
            CuAction::ConnectOut { cu, port, channel } => self.bind(cu, false, port, Some(channel)),
            CuAction::DisconnectIn { cu, port } => self.bind(cu, true, port, None),
            CuAction::DisconnectOut { cu, port } => self.bind(cu, false, port, None),
        }
    }

    fn bind(
        &self,
        cu: &str,
        input: bool,
        port: &str,
        channel: Option<&str>,
    ) -> Result<(), CuError> {
        let cus = lock(&self.cus);
        match cus.get(cu) {
            None => Err(CuError::failed(format!("{cu} does not run here"))),
            Some(Hosted::Builtin(unit)) => {
                let unit = unit.clone();
                drop(cus);
                if input {
                    unit.bind_in(port, channel)
                } else {
                    unit.bind_out(port, channel)
                }
            }
            Some(Hosted::Process(p)) => {
                let p = p.clone();
                drop(cus);
                p.bind(input, port, channel)
            }
        }
    }

    fn spawn(
        self: &Arc<Self>,
        cu: &str,
        transformation: &str,
        implementation: &Implementation,
    ) -> Result<(), CuError> {
        dyknow_cu::keys::check_name("CU name", cu)?;
        if lock(&self.cus).contains_key(cu) {
            return Err(CuError::failed(format!("{cu} already runs here")));
        }
        let spec = UnitSpec {
            name: cu.to_owned(),
            transformation: transformation.to_owned(),
            inputs: implementation.inputs.clone(),
            outputs: implementation.outputs.clone(),
            params: implementation.params.clone(),
        };
        let (hosted, labour) = match implementation.kind().map_err(CuError::Failed)? {
            Kind::Builtin => {
                let Some(factory) = builtins::builtin(&implementation.source) else {
                    return Err(CuError::failed(format!(
                        "no builtin {:?} in this executor",
                        implementation.source
                    )));
                };
                let clock = cpu_time::ThreadTime::now();
                let made = factory.build(&spec, Host::Thread)?;
                let made_cpu = clock.elapsed();
                let on_crash = self.on_crash();
                let name = cu.to_owned();
                let started = Unit::start(
                    &self.session,
                    &self.config.namespace,
                    spec,
                    made,
                    &self.timers,
                    Box::new(move |reason| on_crash(&name, reason)),
                )?;
                (Hosted::Builtin(started.unit), made_cpu + started.labour)
            }
            Kind::Process => {
                let command = implementation.command();
                let launch = Launch {
                    executor: self.config.name.clone(),
                    namespace: self.config.namespace.clone(),
                    connect: self.config.process_connect.clone(),
                    start_timeout: self.config.start_timeout,
                    zenoh_config: self.config.zenoh_config.clone(),
                    lease_ms: self.config.zenoh_lease_ms,
                };
                let p = ProcessCu::start(&self.session, &launch, spec, &command, self.on_crash())?;
                let labour = p.labour();
                (Hosted::Process(p), labour)
            }
        };
        lock(&self.reported).insert(cu.to_owned(), (hosted.cpu(), Instant::now()));
        lock(&self.cus).insert(cu.to_owned(), hosted);
        self.publish(&Event::Running {
            cu: cu.to_owned(),
            transformation: transformation.to_owned(),
            labour_cpu_ms: labour.as_secs_f64() * 1e3,
        });
        Ok(())
    }
}

/// What a command line that names no program may have meant: quotes of a shell
/// (`dkros:hasSource` quotes with double quotes only), or a path holding spaces.
fn quoting_hint(source: &str, command: &[String]) -> &'static str {
    if source.contains(['\'', '\\']) {
        " (dkros:hasSource quotes with double quotes only: single quotes and backslashes are \
         taken as they are)"
    } else if command.len() > 1 && command[0].contains('/') && !source.contains('"') {
        " (a path holding spaces is written in double quotes: \"/opt/my cus/cu.py\")"
    } else {
        ""
    }
}

/// Whether this executor can run an implementation, and why not.
pub fn check(implementation: &Implementation) -> CheckReply {
    let why = match implementation.kind() {
        Err(why) => Some(why),
        Ok(Kind::Builtin) => (builtins::builtin(&implementation.source).is_none())
            .then(|| format!("no executor has the builtin {:?}", implementation.source)),
        Ok(Kind::Process) => {
            let command = implementation.command();
            resolve(command.first().map_or("", String::as_str))
                .err()
                .map(|why| why + quoting_hint(&implementation.source, &command))
        }
    };
    CheckReply {
        runnable: why.is_none(),
        why,
    }
}
