//! A running CU (the seed's nodelet behind its proxy, Ch. 5.2.1): a [`Transformation`] whose
//! named ports are bound to channels on a Zenoh session. Bindings change while it runs, make
//! before break; it keeps per-port statistics, its uptime, its reconfigurations and the CPU
//! time of its callbacks (the thread CPU clock around each callback, less the time of the
//! callbacks its publications ran in turn); a panic or an `Err` from a callback crashes it.
//! While it runs it holds a liveliness token.

use std::cell::RefCell;
use std::collections::{BTreeMap, VecDeque};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError, TryLockError, Weak};
use std::time::{Duration, Instant};

use cpu_time::ThreadTime;
use serde_json::Value;
use zenoh::Wait;
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};

use crate::error::CuError;
use crate::keys::Namespace;
use crate::protocol::{CuReport, CuState, CuStatistics, PortStatistics};
use crate::sample::Sample;
use crate::timers::{Fire, Timers};
use crate::transformation::{NodeHandle, Outputs, Transformation};

/// What a CU is: its name, its transformation's label, ports and parameters.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UnitSpec {
    /// The CU's name.
    pub name: String,
    /// Its transformation's label.
    pub transformation: String,
    /// In port names.
    pub inputs: Vec<String>,
    /// Out port names.
    pub outputs: Vec<String>,
    /// Parameters.
    pub params: BTreeMap<String, Value>,
}

/// Called once when a CU crashes, with the reason, on the thread that saw it.
pub type CrashHook = Box<dyn Fn(&str) + Send + Sync>;

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// How long a release or a statistics read waits for a running callback to leave the core.
const CORE_WAIT: Duration = Duration::from_millis(50);

/// The lock of `m` if it comes free within `wait` (polled), else `None`.
fn lock_within<T>(m: &Mutex<T>, wait: Duration) -> Option<MutexGuard<'_, T>> {
    let deadline = Instant::now() + wait;
    loop {
        match m.try_lock() {
            Ok(guard) => return Some(guard),
            Err(std::sync::TryLockError::Poisoned(p)) => return Some(p.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) if Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(1));
            }
            Err(std::sync::TryLockError::WouldBlock) => return None,
        }
    }
}

static NEXT_ID: AtomicUsize = AtomicUsize::new(1);

/// Set in a process CU ([`crate::run_process`]): the process holds one CU, whose stalled
/// callback can hold up nothing but that CU, so Zenoh's threads deliver to it at once too (a
/// hand-off to the CU's thread cost 4–32 µs per hop in a chain of process CUs).
static ONE_CU: AtomicBool = AtomicBool::new(false);

/// Says this process holds one CU ([`ONE_CU`]).
pub(crate) fn one_cu_process() {
    ONE_CU.store(true, Ordering::Relaxed);
}

thread_local! {
    /// The CUs whose callbacks run on this thread now, innermost last, with the CPU time
    /// of the callbacks nested in each.
    static ACTIVE: RefCell<Vec<(usize, Duration)>> = const { RefCell::new(Vec::new()) };
}

struct OutBinding {
    publisher: Option<Publisher<'static>>,
    stats: PortStatistics,
}

struct OutPorts {
    cu: String,
    ports: BTreeMap<String, OutBinding>,
    /// Set when the CU is released while a callback runs: its publishers are dropped when
    /// the callback returns, and nothing it publishes until then goes out.
    released: Arc<AtomicBool>,
    /// The payload of the sample the running callback received, for [`Outputs::forward`].
    received: Option<ZBytes>,
}

impl OutBinding {
    /// Puts `payload` (a sample holding at `t`) on its channel, counted in its statistics.
    fn send(&mut self, payload: ZBytes, t: i64) -> Result<(), CuError> {
        let Some(publisher) = &self.publisher else {
            return Ok(());
        };
        self.stats.messages += 1;
        self.stats.bytes += payload.len() as u64;
        self.stats.last_t = Some(t);
        publisher.put(payload).wait()?;
        Ok(())
    }
}

impl OutPorts {
    /// Out port `port` while it is bound; `None` while it is not.
    fn bound(&mut self, port: &str) -> Result<Option<&mut OutBinding>, CuError> {
        let released = self.released.load(Ordering::Acquire);
        match self.ports.get_mut(port) {
            Some(out) => Ok((out.publisher.is_some() && !released).then_some(out)),
            None => Err(CuError::UnknownPort {
                cu: self.cu.clone(),
                direction: "out",
                port: port.to_owned(),
            }),
        }
    }
}

impl Outputs for OutPorts {
    fn publish(&mut self, port: &str, sample: &Sample) -> Result<(), CuError> {
        match self.bound(port)? {
            Some(out) => out.send(sample.to_bytes().into(), sample.t),
            None => Ok(()),
        }
    }

    fn forward(&mut self, port: &str, sample: &Sample) -> Result<(), CuError> {
        let Some(payload) = self.received.clone() else {
            return self.publish(port, sample);
        };
        match self.bound(port)? {
            Some(out) => out.send(payload, sample.t),
            None => Ok(()),
        }
    }

    fn is_bound(&self, port: &str) -> bool {
        self.ports.get(port).is_some_and(|o| o.publisher.is_some())
    }
}

struct Core {
    transformation: Box<dyn Transformation>,
    outputs: OutPorts,
    in_stats: BTreeMap<String, PortStatistics>,
    timers: Vec<Duration>,
}

struct InBinding {
    channel: String,
    _subscriber: Subscriber<()>,
}

struct Life {
    state: CuState,
    reason: Option<String>,
    running_since: Option<Instant>,
}

/// What a CU's own thread has to do: a sample on an in port, or a due timer.
enum Work {
    Sample(Arc<str>, ZBytes),
    Timer(usize),
}

/// The work a CU could not take on the thread that brought it, in arrival order, for the CU's
/// own thread (`cu:<name>`). A sample Zenoh's threads deliver (from another process) always
/// goes here: a callback that stalls then holds up its own thread only, never Zenoh's
/// receiving threads (whose stall past the lease would take the executor's link, and with it
/// every CU of the executor, down). A sample put in this process (one CU publishing to
/// another) is delivered at once on the putting thread (the fast hop) unless the receiver is
/// busy or has work waiting; then it waits here too, so a stalled receiver never holds up its
/// publisher (nor the timer thread that fired it).
struct Inbox {
    queue: Mutex<Queue>,
    ready: Condvar,
}

#[derive(Default)]
struct Queue {
    work: VecDeque<Work>,
    /// The CU's thread took work and has not finished it: work arriving meanwhile queues
    /// behind it (the order of a port's samples is kept).
    draining: bool,
    closed: bool,
    /// Samples dropped (the oldest first) since the queue was last full.
    dropped: u64,
}

/// How many samples and timer firings wait for a busy CU at most; past it the oldest sample is
/// dropped (a stream reasoner wants the newest).
pub const INBOX_CAPACITY: usize = 1024;

impl Inbox {
    fn close(&self) {
        let mut queue = lock(&self.queue);
        queue.closed = true;
        queue.work.clear();
        drop(queue);
        self.ready.notify_all();
    }
}

struct Shared {
    id: usize,
    inbox: Arc<Inbox>,
    spec: UnitSpec,
    namespace: Namespace,
    session: zenoh::Session,
    core: Mutex<Core>,
    /// The core's [`OutPorts::released`].
    released: Arc<AtomicBool>,
    /// The out ports' channels, as bound last: read without the core, which a running
    /// callback holds.
    out_channels: Mutex<BTreeMap<String, String>>,
    inputs: Mutex<BTreeMap<String, InBinding>>,
    life: Mutex<Life>,
    token: Mutex<Option<LivelinessToken>>,
    reconfigurations: AtomicU64,
    cpu_ns: AtomicU64,
    on_crash: CrashHook,
}

/// A running CU. Cloning gives another handle to the same CU.
#[derive(Clone)]
pub struct Unit {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for Unit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Unit")
            .field("name", &self.shared.spec.name)
            .field("state", &self.state())
            .finish_non_exhaustive()
    }
}

/// A started CU and the CPU time its start took (its labour).
#[derive(Debug)]
pub struct Started {
    /// The CU.
    pub unit: Unit,
    /// The CPU time of creating and starting it.
    pub labour: Duration,
}

impl Unit {
    /// Starts a CU of `transformation` on `session`, every port unbound: calls
    /// [`Transformation::start`], arms its timers on `timers` and declares its liveliness
    /// token. `on_crash` is called once if it crashes later.
    pub fn start(
        session: &zenoh::Session,
        namespace: &Namespace,
        spec: UnitSpec,
        transformation: Box<dyn Transformation>,
        timers: &Timers,
        on_crash: CrashHook,
    ) -> Result<Started, CuError> {
        crate::keys::check_name("CU name", &spec.name)?;
        quiet_callback_panics();
        let clock = ThreadTime::now();
        let outputs = OutPorts {
            cu: spec.name.clone(),
            ports: spec
                .outputs
                .iter()
                .map(|p| {
                    (
                        p.clone(),
                        OutBinding {
                            publisher: None,
                            stats: PortStatistics::default(),
                        },
                    )
                })
                .collect(),
            received: None,
            released: Arc::new(AtomicBool::new(false)),
        };
        let released = outputs.released.clone();
        let mut core = Core {
            transformation,
            outputs,
            in_stats: spec
                .inputs
                .iter()
                .map(|p| (p.clone(), PortStatistics::default()))
                .collect(),
            timers: Vec::new(),
        };
        {
            let Core {
                transformation,
                outputs,
                timers,
                ..
            } = &mut core;
            let mut handle = NodeHandle::new(
                &spec.name,
                &spec.params,
                &spec.inputs,
                &spec.outputs,
                outputs,
                timers,
            );
            match catch_unwind(AssertUnwindSafe(|| transformation.start(&mut handle))) {
                Ok(Ok(())) => {}
                Ok(Err(e)) => return Err(e),
                Err(panic) => return Err(CuError::Failed(panic_message(&*panic))),
            }
        }
        let token = session
            .liveliness()
            .declare_token(namespace.cu_token(&spec.name))
            .wait()?;
        let periods = core.timers.clone();
        let inbox = Arc::new(Inbox {
            queue: Mutex::new(Queue::default()),
            ready: Condvar::new(),
        });
        let shared = Arc::new(Shared {
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            inbox: inbox.clone(),
            spec,
            namespace: namespace.clone(),
            session: session.clone(),
            core: Mutex::new(core),
            released,
            out_channels: Mutex::new(BTreeMap::new()),
            inputs: Mutex::new(BTreeMap::new()),
            life: Mutex::new(Life {
                state: CuState::Running,
                reason: None,
                running_since: Some(Instant::now()),
            }),
            token: Mutex::new(Some(token)),
            reconfigurations: AtomicU64::new(0),
            cpu_ns: AtomicU64::new(0),
            on_crash,
        });
        let weak = Arc::downgrade(&shared);
        if let Err(e) = std::thread::Builder::new()
            .name(format!("cu:{}", shared.spec.name))
            .spawn(move || work(&inbox, &weak))
        {
            shared.inbox.close();
            return Err(CuError::Failed(format!("could not start its thread: {e}")));
        }
        let fire: Arc<dyn Fire> = shared.clone();
        for (timer, period) in periods.into_iter().enumerate() {
            timers.every(Arc::downgrade(&fire), timer, period);
        }
        let labour = clock.elapsed();
        Ok(Started {
            unit: Unit { shared },
            labour,
        })
    }

    /// The CU's name.
    pub fn name(&self) -> &str {
        &self.shared.spec.name
    }

    /// Its spec.
    pub fn spec(&self) -> &UnitSpec {
        &self.shared.spec
    }

    /// Its state.
    pub fn state(&self) -> CuState {
        lock(&self.shared.life).state
    }

    /// Binds in port `port` to `channel` (make before break: the new subscription is
    /// declared before the old one is undeclared), or unbinds it (`None`).
    pub fn bind_in(&self, port: &str, channel: Option<&str>) -> Result<(), CuError> {
        let shared = &self.shared;
        if !shared.spec.inputs.iter().any(|p| p == port) {
            return Err(CuError::UnknownPort {
                cu: shared.spec.name.clone(),
                direction: "in",
                port: port.to_owned(),
            });
        }
        self.running()?;
        let mut inputs = lock(&shared.inputs);
        match channel {
            Some(channel) => {
                if inputs.get(port).is_some_and(|b| b.channel == channel) {
                    return Ok(());
                }
                let key = crate::pins::pinned_key(
                    &shared.session,
                    zenoh::key_expr::KeyExpr::try_from(shared.namespace.channel(channel)?)?,
                )?;
                let weak: Weak<Shared> = Arc::downgrade(shared);
                let name: Arc<str> = Arc::from(port);
                let subscriber = shared
                    .session
                    .declare_subscriber(key)
                    .callback(move |sample| {
                        if let Some(shared) = weak.upgrade() {
                            shared.arrive(Work::Sample(name.clone(), sample.payload().clone()));
                        }
                    })
                    .wait()?;
                // The old binding is dropped (undeclared) only now: make before break.
                inputs.insert(
                    port.to_owned(),
                    InBinding {
                        channel: channel.to_owned(),
                        _subscriber: subscriber,
                    },
                );
            }
            None => {
                if inputs.remove(port).is_none() {
                    return Ok(());
                }
            }
        }
        drop(inputs);
        self.reconfigured();
        Ok(())
    }

    /// Binds out port `port` to `channel`, or unbinds it (`None`).
    pub fn bind_out(&self, port: &str, channel: Option<&str>) -> Result<(), CuError> {
        let shared = &self.shared;
        if !shared.spec.outputs.iter().any(|p| p == port) {
            return Err(CuError::UnknownPort {
                cu: shared.spec.name.clone(),
                direction: "out",
                port: port.to_owned(),
            });
        }
        self.running()?;
        let publisher = match channel {
            Some(channel) => {
                if lock(&shared.out_channels).get(port).map(String::as_str) == Some(channel) {
                    return Ok(());
                }
                let key = crate::pins::pinned_key(
                    &shared.session,
                    zenoh::key_expr::KeyExpr::try_from(shared.namespace.channel(channel)?)?,
                )?;
                Some(
                    shared
                        .session
                        .declare_publisher(key)
                        .encoding(Encoding::APPLICATION_JSON)
                        .express(true)
                        .wait()?,
                )
            }
            None => None,
        };
        let old = {
            let mut core = lock(&shared.core);
            let Some(out) = core.outputs.ports.get_mut(port) else {
                return Ok(());
            };
            let mut channels = lock(&shared.out_channels);
            match channel {
                Some(c) => channels.insert(port.to_owned(), c.to_owned()),
                None => channels.remove(port),
            };
            drop(channels);
            std::mem::replace(&mut out.publisher, publisher)
        };
        drop(old);
        self.reconfigured();
        Ok(())
    }

    fn running(&self) -> Result<(), CuError> {
        match self.state() {
            CuState::Running | CuState::Starting => Ok(()),
            _ => Err(CuError::NotRunning(self.shared.spec.name.clone())),
        }
    }

    fn reconfigured(&self) {
        self.shared.reconfigurations.fetch_add(1, Ordering::Relaxed);
        let core = lock(&self.shared.core);
        self.shared.guarded(core, None, |transformation, handle| {
            transformation.on_reconfigure(&mut handle.node)
        });
    }

    /// The in and out bindings now.
    pub fn bindings(
        &self,
    ) -> (
        BTreeMap<String, Option<String>>,
        BTreeMap<String, Option<String>>,
    ) {
        let inputs = lock(&self.shared.inputs);
        let ins = self
            .shared
            .spec
            .inputs
            .iter()
            .map(|p| (p.clone(), inputs.get(p).map(|b| b.channel.clone())))
            .collect();
        drop(inputs);
        let channels = lock(&self.shared.out_channels);
        let outs = self
            .shared
            .spec
            .outputs
            .iter()
            .map(|p| (p.clone(), channels.get(p).cloned()))
            .collect();
        (ins, outs)
    }

    /// The CPU time its callbacks used so far.
    pub fn cpu(&self) -> Duration {
        Duration::from_nanos(self.shared.cpu_ns.load(Ordering::Relaxed))
    }

    /// Its statistics now (GetStatistics).
    pub fn statistics(&self) -> CuStatistics {
        let life = lock(&self.shared.life);
        let uptime_ms = match (life.state, life.running_since) {
            (CuState::Running, Some(since)) => {
                u64::try_from(since.elapsed().as_millis()).unwrap_or(u64::MAX)
            }
            _ => 0,
        };
        drop(life);
        // A callback running long (stalled) holds the core: its port statistics are then left
        // out rather than waited for, so that an executor's `info` answers for its other CUs.
        let mut ports = BTreeMap::new();
        if let Some(core) = lock_within(&self.shared.core, CORE_WAIT) {
            ports = core.in_stats.clone();
            for (port, out) in &core.outputs.ports {
                ports.insert(port.clone(), out.stats.clone());
            }
        }
        CuStatistics {
            uptime_ms,
            reconfigurations: self.shared.reconfigurations.load(Ordering::Relaxed),
            cpu_ms: self.cpu().as_secs_f64() * 1e3,
            ports,
        }
    }

    /// Its report: state, bindings, statistics.
    pub fn report(&self) -> CuReport {
        let (inputs, outputs) = self.bindings();
        let life = lock(&self.shared.life);
        let (state, reason) = (life.state, life.reason.clone());
        drop(life);
        CuReport {
            cu: self.shared.spec.name.clone(),
            transformation: self.shared.spec.transformation.clone(),
            state,
            inputs,
            outputs,
            statistics: self.statistics(),
            reason,
            pid: None,
            generation: 0,
        }
    }

    /// Crashes it from outside (a fault, a lost process): as if a callback had failed.
    pub fn crash(&self, reason: &str) {
        self.shared.crash(reason);
    }

    /// Stops it (destroy): no callback starts after this returns, its bindings and token are
    /// gone; a callback running on (stalled) is not waited for, and nothing it publishes goes
    /// out. A crashed CU keeps its crashed state.
    pub fn stop(&self) {
        {
            let mut life = lock(&self.shared.life);
            if life.state != CuState::Crashed {
                life.state = CuState::Stopped;
            }
            life.running_since = None;
        }
        self.shared.inbox.close();
        self.release();
    }

    /// Undeclares its subscriptions, publishers and token (after a crash: the executor calls
    /// this from its own thread, never from inside a callback). It does not wait for a
    /// callback that runs on (stalled): nothing that callback publishes afterwards goes out
    /// (but a sample it was sending at that moment), and its publishers are dropped when it
    /// returns, so that one stalled CU never holds up its executor's other actions or its
    /// shutdown.
    pub fn release(&self) {
        let inputs = std::mem::take(&mut *lock(&self.shared.inputs));
        drop(inputs);
        self.shared.released.store(true, Ordering::Release);
        lock(&self.shared.out_channels).clear();
        if let Some(mut core) = lock_within(&self.shared.core, CORE_WAIT) {
            let publishers: Vec<_> = core
                .outputs
                .ports
                .values_mut()
                .filter_map(|o| o.publisher.take())
                .collect();
            drop(core);
            drop(publishers);
        }
        let token = lock(&self.shared.token).take();
        drop(token);
    }
}

/// A CU's own thread: does the work its inbox holds, in order, until the CU stops or is gone.
fn work(inbox: &Inbox, shared: &Weak<Shared>) {
    loop {
        let mut queue = lock(&inbox.queue);
        while queue.work.is_empty() && !queue.closed {
            queue.draining = false;
            queue = inbox
                .ready
                .wait(queue)
                .unwrap_or_else(PoisonError::into_inner);
        }
        if queue.closed {
            return;
        }
        let Some(work) = queue.work.pop_front() else {
            continue;
        };
        queue.draining = true;
        drop(queue);
        let Some(shared) = shared.upgrade() else {
            return;
        };
        let core = lock(&shared.core);
        shared.run(core, work);
    }
}

impl Drop for Shared {
    fn drop(&mut self) {
        self.inbox.close();
    }
}

impl Shared {
    /// A sample arriving for this CU: done at once on this thread (the fast hop) when this CU
    /// is free with nothing waiting and the thread is not one of Zenoh's (a CU's callback
    /// published it, or a thread of the application put it); queued for the CU's own thread
    /// otherwise ([`Inbox`]). Zenoh's threads are those of its Tokio runtimes.
    fn arrive(&self, work: Work) {
        let (in_callback, reentered) = ACTIVE.with(|a| {
            let a = a.borrow();
            (!a.is_empty(), a.iter().any(|(id, _)| *id == self.id))
        });
        let here = in_callback
            || ONE_CU.load(Ordering::Relaxed)
            || tokio::runtime::Handle::try_current().is_err();
        self.take(work, here, reentered);
    }

    /// Timer `timer` is due: fired at once on the timer's thread when the CU is free with
    /// nothing waiting, queued for its own thread otherwise.
    fn fire_timer(&self, timer: usize) {
        self.take(Work::Timer(timer), true, false);
    }

    /// Does `work` on this thread if `here` allows and the CU is free, or queues it.
    fn take(&self, work: Work, here: bool, reentered: bool) {
        if reentered {
            tracing::warn!(
                "{} would consume its own output on one thread (a cycle): sample dropped",
                self.spec.name
            );
            return;
        }
        let mut queue = lock(&self.inbox.queue);
        if queue.closed {
            return;
        }
        if here && queue.work.is_empty() && !queue.draining {
            let core = match self.core.try_lock() {
                Ok(core) => Some(core),
                Err(TryLockError::Poisoned(e)) => Some(e.into_inner()),
                Err(TryLockError::WouldBlock) => None,
            };
            if let Some(core) = core {
                drop(queue);
                self.run(core, work);
                return;
            }
        }
        if let Work::Timer(timer) = work {
            // A firing already waiting is enough: a late timer skips, it does not catch up.
            if queue
                .work
                .iter()
                .any(|w| matches!(w, Work::Timer(t) if *t == timer))
            {
                return;
            }
        }
        if queue.work.len() >= INBOX_CAPACITY {
            if let Some(oldest) = queue
                .work
                .iter()
                .position(|w| matches!(w, Work::Sample(..)))
            {
                queue.work.remove(oldest);
            }
            queue.dropped += 1;
            if queue.dropped.is_power_of_two() {
                tracing::warn!(
                    "{} is busy: {} samples dropped, the oldest first ({INBOX_CAPACITY} wait)",
                    self.spec.name,
                    queue.dropped
                );
            }
        } else if queue.work.is_empty() {
            queue.dropped = 0;
        }
        queue.work.push_back(work);
        drop(queue);
        self.inbox.ready.notify_one();
    }

    /// Does `work` holding the core.
    fn run(&self, core: MutexGuard<'_, Core>, work: Work) {
        match work {
            Work::Sample(port, payload) => self.deliver(core, &port, &payload),
            Work::Timer(timer) => self.guarded(core, None, |transformation, handle| {
                transformation.on_timer(&mut handle.node, timer)
            }),
        }
    }

    /// A sample on in port `port`.
    fn deliver(&self, core: MutexGuard<'_, Core>, port: &str, payload: &ZBytes) {
        let sample = match Sample::from_slice(&payload.to_bytes()) {
            Ok(s) => s,
            Err(e) => {
                tracing::debug!("{} drops a sample on {port}: {e}", self.spec.name);
                return;
            }
        };
        let bytes = payload.len() as u64;
        self.guarded(core, Some(payload), |transformation, handle| {
            transformation_sample(transformation, handle, port, sample, bytes)
        });
    }

    /// Runs a callback: only while running, never re-entered on one thread (a cycle of CUs
    /// drops the sample instead of deadlocking), a panic or `Err` crashes the CU, and the
    /// thread CPU time is charged to this CU less that of the callbacks nested in it.
    fn guarded(
        &self,
        mut core: MutexGuard<'_, Core>,
        received: Option<&ZBytes>,
        callback: impl FnOnce(&mut dyn Transformation, &mut Handle<'_>) -> Result<(), CuError>,
    ) {
        if lock(&self.life).state != CuState::Running {
            return;
        }
        let reentered = ACTIVE.with(|a| a.borrow().iter().any(|(id, _)| *id == self.id));
        if reentered {
            tracing::warn!(
                "{} would consume its own output on one thread (a cycle): sample dropped",
                self.spec.name
            );
            return;
        }
        ACTIVE.with(|a| a.borrow_mut().push((self.id, Duration::ZERO)));
        let clock = ThreadTime::now();
        core.outputs.received = received.cloned();
        let result = {
            let Core {
                transformation,
                outputs,
                in_stats,
                timers,
            } = &mut *core;
            let mut handle = Handle {
                node: NodeHandle::new(
                    &self.spec.name,
                    &self.spec.params,
                    &self.spec.inputs,
                    &self.spec.outputs,
                    outputs,
                    timers,
                ),
                in_stats,
            };
            catch_unwind(AssertUnwindSafe(|| {
                callback(transformation.as_mut(), &mut handle)
            }))
        };
        core.outputs.received = None;
        if self.released.load(Ordering::Acquire) {
            // Released while this callback ran: its publishers go now.
            for out in core.outputs.ports.values_mut() {
                out.publisher = None;
            }
        }
        drop(core);
        let total = clock.elapsed();
        let nested = ACTIVE.with(|a| {
            let mut a = a.borrow_mut();
            let (_, nested) = a.pop().unwrap_or_default();
            if let Some((_, parent)) = a.last_mut() {
                *parent += total;
            }
            nested
        });
        let own = total.saturating_sub(nested);
        self.cpu_ns.fetch_add(
            u64::try_from(own.as_nanos()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
        match result {
            Ok(Ok(())) => {}
            Ok(Err(e)) => self.crash(&e.to_string()),
            Err(panic) => self.crash(&format!("panicked: {}", panic_message(&*panic))),
        }
    }

    fn crash(&self, reason: &str) {
        {
            let mut life = lock(&self.life);
            if life.state != CuState::Running && life.state != CuState::Starting {
                return;
            }
            life.state = CuState::Crashed;
            life.reason = Some(reason.to_owned());
            life.running_since = None;
        }
        tracing::warn!("{} crashed: {reason}", self.spec.name);
        (self.on_crash)(reason);
    }
}

/// The handle a callback gets, with the in-port statistics beside it.
struct Handle<'a> {
    node: NodeHandle<'a>,
    in_stats: &'a mut BTreeMap<String, PortStatistics>,
}

fn transformation_sample(
    transformation: &mut dyn Transformation,
    handle: &mut Handle<'_>,
    port: &str,
    sample: Sample,
    bytes: u64,
) -> Result<(), CuError> {
    if let Some(stats) = handle.in_stats.get_mut(port) {
        stats.messages += 1;
        stats.bytes += bytes;
        stats.last_t = Some(sample.t);
    }
    transformation.on_sample(&mut handle.node, port, sample)
}

impl Fire for Shared {
    fn fire(&self, timer: usize) -> bool {
        // On the timer's thread when the CU is free; queued for its own thread when it is busy
        // (a stalled CU never holds up the timer thread, and with it the other CUs' timers).
        self.fire_timer(timer);
        lock(&self.life).state == CuState::Running
    }
}

/// A panic in a CU's callback is a crash the executor handles and reports (with its message);
/// the process-wide panic hook would print it again and, with `RUST_BACKTRACE` set, resolve and
/// print a backtrace, which takes hundreds of milliseconds the first time (loading the debug
/// information) and delays the crash report by as much. So, once per process, the hook is
/// wrapped: inside a CU callback it logs one line, unless `DYKNOW_CU_BACKTRACE` is set; every
/// other panic goes to the previous hook unchanged.
fn quiet_callback_panics() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if std::env::var_os("DYKNOW_CU_BACKTRACE").is_some() {
            return;
        }
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_callback = ACTIVE
                .try_with(|a| a.try_borrow().is_ok_and(|a| !a.is_empty()))
                .unwrap_or(false);
            if in_callback {
                let location = info
                    .location()
                    .map_or_else(String::new, |l| format!(" at {l}"));
                tracing::debug!(
                    "a CU callback panicked{location}: {}",
                    panic_message(info.payload())
                );
            } else {
                previous(info);
            }
        }));
    });
}

/// The text of a panic's payload.
pub fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = panic.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = panic.downcast_ref::<String>() {
        s.clone()
    } else {
        "a panic without a message".to_owned()
    }
}
