//! Which executors are present (`executors.md`, "The manager's side: the fleet"): their
//! liveliness tokens, by name, and the instances behind each name.
//!
//! Zenoh announces a key once however many sessions hold it, so a name's token says that
//! some executor of the name is up, never which. Each executor also holds a token of its own
//! run, `<name>/<instance>`; the earliest live instance of a name holds it (a later one steps
//! down when it sees an earlier one answer). The fleet takes an executor's `info` only from
//! the holder, remembers whose it took, and handles a change of holder under a name whose
//! token stayed up as the name gone and back.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Duration;

use dyknow_cu::Namespace;
use dyknow_cu::keys::{InstanceId, InstanceKey};
use dyknow_cu::protocol::ExecutorInfo;
use dyknow_cu::zenoh::pubsub::Subscriber;
use dyknow_cu::zenoh::sample::SampleKind;
use dyknow_cu::zenoh::{self, Wait};
use dyknow_engine::Cid;

use super::{FleetEvent, Inner, Known, QUERY_TIMEOUT, appeared, lock};

/// An executor's liveliness token, as last seen.
#[derive(Debug, Default, Clone)]
pub(super) struct Token {
    up: bool,
    epoch: u64,
    /// A membership thread is asking the executor for its `info`.
    probing: bool,
    /// The instance whose `info` was taken since the token last came up (`None`: none yet,
    /// or an executor that does not say which it is).
    instance: Option<InstanceId>,
}

impl Token {
    fn set(&mut self, up: bool) {
        self.up = up;
        self.epoch += 1;
        self.instance = None;
    }
}

/// Subscribes to the executors' instance tokens, then to their names' tokens (so that the
/// holder of a name is known, where it can be, before its executor is first asked).
pub(super) fn watch(
    inner: &Arc<Inner>,
    session: &zenoh::Session,
    namespace: &Namespace,
) -> Result<[Subscriber<()>; 2], zenoh::Error> {
    let watcher = inner.clone();
    let instances = session
        .liveliness()
        .declare_subscriber(namespace.executor_instances("*"))
        .history(true)
        .callback(move |sample| {
            if let Some(key) = InstanceKey::parse(sample.key_expr().as_str()) {
                let put = sample.kind() == SampleKind::Put;
                Inner::instance(&watcher, key.name, key.instance, put);
            }
        })
        .wait()?;
    let watcher = inner.clone();
    let tokens = session
        .liveliness()
        .declare_subscriber(namespace.executor_tokens())
        .history(true)
        .callback(move |sample| {
            let key = sample.key_expr().as_str().to_owned();
            let Some(name) = key.rsplit('/').next().map(str::to_owned) else {
                return;
            };
            if sample.kind() == SampleKind::Put {
                Inner::up(&watcher, name);
            } else {
                // Taken here, in the order Zenoh tells it: a vanishing handled on a
                // thread could otherwise land after the executor's next appearance.
                Inner::token_down(&watcher, &name);
            }
        })
        .wait()?;
    Ok([instances, tokens])
}

impl Inner {
    /// Executor `name`'s token is up: one thread asks it for its [`Inner::appeared`].
    fn up(inner: &Arc<Self>, name: String) {
        let start = Self::mark_up(&mut lock(&inner.tokens), &name);
        if start {
            Self::probe(inner, name);
        }
    }

    /// Marks `name`'s token up (a new epoch); whether a thread must start asking it (one
    /// asking already sees the new epoch).
    fn mark_up(tokens: &mut BTreeMap<String, Token>, name: &str) -> bool {
        let token = tokens.entry(name.to_owned()).or_default();
        token.set(true);
        !std::mem::replace(&mut token.probing, true)
    }

    /// Starts the thread that asks `name` for its `info` ([`Inner::appeared`]): never a
    /// Zenoh callback's own thread, as the query waits.
    fn probe(inner: &Arc<Self>, name: String) {
        let inner = inner.clone();
        let _ = std::thread::Builder::new()
            .name("fleet-membership".into())
            .spawn(move || inner.appeared(&name));
    }

    /// An instance token of executor `name` came (`put`) or went. When the name's token is
    /// up and the instance whose `info` was taken no longer holds the name (an earlier
    /// instance arrived; or it went, and a later one had yet to step down), the executor
    /// behind the name is another one although the name's token never went down: the CUs
    /// placed on the old one are lost (they stop with it) and the holder is asked for its
    /// `info`, as if the name had gone and come back. All under the token lock, as the name's
    /// own coming and going is: a name that goes meanwhile is not marked up.
    fn instance(inner: &Arc<Self>, name: &str, instance: InstanceId, put: bool) {
        let mut tokens = lock(&inner.tokens);
        let holder = {
            let mut instances = lock(&inner.instances);
            let live = instances.entry(name.to_owned()).or_default();
            if put {
                live.insert(instance);
            } else {
                live.remove(&instance);
            }
            let holder = live.first().cloned();
            if live.is_empty() {
                instances.remove(name);
            }
            holder
        };
        let taken = (tokens.get(name))
            .filter(|t| t.up)
            .and_then(|t| t.instance.clone());
        let (Some(taken), Some(holder)) = (taken, holder) else {
            return;
        };
        if taken == holder {
            return;
        }
        tracing::warn!(
            "executor {name}: instance {holder} holds the name now, not {taken} (two executors of one name met; the later steps down)"
        );
        inner.vanished_locked(&mut tokens, name);
        let start = Self::mark_up(&mut tokens, name);
        drop(tokens);
        if start {
            Self::probe(inner, name.to_owned());
        }
    }

    /// The instance whose `info` was taken for `name`, while its token is up.
    pub(super) fn taken(&self, name: &str) -> Option<InstanceId> {
        lock(&self.tokens)
            .get(name)
            .filter(|t| t.up)
            .and_then(|t| t.instance.clone())
    }

    /// The instance holding executor name `name`, if its instances are known.
    pub(super) fn holder(&self, name: &str) -> Option<InstanceId> {
        lock(&self.instances)
            .get(name)
            .and_then(|live| live.first().cloned())
    }

    /// Whether `info` comes from the instance holding `name`, or nothing tells (no instance
    /// token of the name is known: an executor that does not declare one).
    pub(super) fn answered_by_holder(&self, name: &str, info: &ExecutorInfo) -> bool {
        self.holder(name)
            .is_none_or(|holder| info.instance.as_ref() == Some(&holder))
    }

    /// Executor `name`'s token is up: asks it for its `info`, again every 200 ms while it
    /// does not answer and the token stays up, then records it present and reports its CUs
    /// for reconciliation; a token that went down ends the asking. (Right after a link is
    /// cut, Zenoh may announce the token of the executor behind it again although it cannot
    /// be reached; when the link heals, no new announcement comes, so the answer is what
    /// tells.) Only the answer of the instance holding the name counts: another one is
    /// stepping down, and its CUs are about to stop. One thread asks per executor. An answer
    /// counts only if the token did not change while it was asked for (its epoch, checked
    /// under the token lock that [`Inner::token_down`] holds too, as does the callback that
    /// starts this thread unless one is asking already): an executor that went down and up
    /// meanwhile (a flapping link, a restart under the same name) is asked again, so a stale
    /// list of CUs is never reconciled, and no answer is recorded after the token went down.
    fn appeared(&self, name: &str) {
        let mut warned = false;
        loop {
            let asked = lock(&self.tokens).get(name).map_or(0, |t| t.epoch);
            let info = self
                .query_where(name, "info", Vec::new(), QUERY_TIMEOUT, |info| {
                    self.answered_by_holder(name, info)
                })
                .ok();
            let mut tokens = lock(&self.tokens);
            let token = tokens.entry(name.to_owned()).or_default();
            if !token.up {
                token.probing = false;
                return;
            }
            if token.epoch != asked {
                continue;
            }
            // The holder may have changed since the answer was picked.
            let Some(info) = info.filter(|info| self.answered_by_holder(name, info)) else {
                drop(tokens);
                if !warned {
                    tracing::warn!(
                        "executor {name} appeared but does not describe itself; asking again until it does or leaves"
                    );
                    warned = true;
                }
                std::thread::sleep(Duration::from_millis(200));
                continue;
            };
            token.probing = false;
            token.instance.clone_from(&info.instance);
            self.grace_ended(&mut tokens, name, &info);
            tracing::info!(
                "executor {name} is present ({} builtins{})",
                info.builtins.len(),
                info.instance
                    .as_ref()
                    .map_or_else(String::new, |i| format!(", instance {i}"))
            );
            lock(&self.executors).insert(
                name.to_owned(),
                Known {
                    present: true,
                    absent_since: None,
                    builtins: info.builtins.iter().cloned().collect(),
                    processes: info.processes,
                    checks: BTreeMap::new(),
                },
            );
            let _ = self.events.send(appeared(name, info));
            let _ = self.events.send(FleetEvent::ExecutorsChanged);
            return;
        }
    }

    /// Forgets the executors absent for longer than [`Inner::forget_after_ms`]
    /// ([`super::Fleet::forget_absent_after`]): their entry in the listing and their token's.
    /// Not one whose token is up or being asked, nor one in a grace (it may be back as the
    /// same instance), nor one a CU is still placed on; the token lock held throughout, so
    /// one coming back meanwhile is not forgotten. Run by the sweep's thread. Returns the
    /// names forgotten.
    pub(super) fn forget_absent(&self) -> Vec<String> {
        let after = Duration::from_millis(
            self.forget_after_ms
                .load(std::sync::atomic::Ordering::SeqCst),
        );
        let mut tokens = lock(&self.tokens);
        let graces = lock(&self.graces);
        let mut executors = lock(&self.executors);
        let placement = lock(&self.placement);
        let forgotten: Vec<String> = executors
            .iter()
            .filter(|(name, known)| {
                !known.present
                    && known
                        .absent_since
                        .is_some_and(|since| since.elapsed() >= after)
                    && tokens.get(*name).is_none_or(|t| !t.up && !t.probing)
                    && !graces.contains_key(*name)
                    && !placement.values().any(|e| e == *name)
            })
            .map(|(name, _)| name.clone())
            .collect();
        for name in &forgotten {
            executors.remove(name);
            tokens.remove(name);
            tracing::info!(
                "executor {name} forgotten: absent for {} ms or more",
                after.as_millis()
            );
        }
        // A name whose token came and went before its `info` was ever taken has a token and
        // nothing listed: its token goes too (nothing dates an answer of it any more).
        tokens.retain(|name, token| {
            token.up || token.probing || graces.contains_key(name) || executors.contains_key(name)
        });
        forgotten
    }

    /// Executor `name`'s token went down: it vanished ([`Inner::vanished_locked`]), unless
    /// the manager itself has just not run for a while ([`Pulse::stalled_recently`]). Then
    /// it is the manager whose links lapsed (a stopped process, a paused machine, a starved
    /// host), not the executor: the executors kept their CUs running and reconnect within a
    /// moment. Its CUs count as crashed only if it is not back, the same instance, within
    /// [`STALL_GRACE`]; before, every CU was replaced at once, and the originals destroyed
    /// when their executors came back (a user audit, `kill -STOP` of the manager for 5 s
    /// with a 2 s lease).
    fn token_down(inner: &Arc<Self>, name: &str) {
        let mut tokens = lock(&inner.tokens);
        let before = tokens.get(name).and_then(|t| t.instance.clone());
        let Some(before) = before.filter(|_| inner.pulse.stalled_recently()) else {
            inner.vanished_locked(&mut tokens, name);
            return;
        };
        tokens.entry(name.to_owned()).or_default().set(false);
        let placed: Vec<Cid> = lock(&inner.placement)
            .iter()
            .filter(|(_, e)| *e == name)
            .map(|(c, _)| c.clone())
            .collect();
        lock(&inner.graces).insert(
            name.to_owned(),
            Grace {
                instance: before,
                placed,
            },
        );
        tracing::warn!(
            "executor {name} vanished right after the manager itself did not run for a while: \
             waiting up to {} s for it to come back before its CUs count as crashed",
            STALL_GRACE.as_secs()
        );
        let waiter = inner.clone();
        let waited = name.to_owned();
        let spawned = std::thread::Builder::new()
            .name("fleet-stall-grace".into())
            .spawn(move || {
                std::thread::sleep(STALL_GRACE);
                let started = std::time::Instant::now();
                loop {
                    let mut tokens = lock(&waiter.tokens);
                    let probing = tokens.get(&waited).is_some_and(|t| t.up && t.probing);
                    // Up and still being asked who it is: a moment more.
                    if probing && started.elapsed() < Duration::from_secs(2) {
                        drop(tokens);
                        std::thread::sleep(Duration::from_millis(100));
                        continue;
                    }
                    // Not back (or not yet told who it is): its CUs of then are lost. Back,
                    // [`Inner::grace_ended`] took the grace already.
                    let grace = lock(&waiter.graces).remove(&waited);
                    if let Some(grace) = grace {
                        waiter.lost(&mut tokens, &waited, Some(&grace.placed));
                    }
                    return;
                }
            });
        if spawned.is_err() {
            // No thread to wait with: gone now, as without a stall.
            lock(&inner.graces).remove(name);
            inner.lost(&mut tokens, name, None);
        }
    }

    /// Executor `name` described itself (`info`, running `running`) after its token came back
    /// up: if it had a grace ([`Inner::token_down`]), the grace ends. The same instance
    /// kept its CUs, except those it no longer runs (they crashed while the manager could
    /// not hear of it); another instance has none of them. The token lock held.
    fn grace_ended(&self, tokens: &mut BTreeMap<String, Token>, name: &str, info: &ExecutorInfo) {
        let Some(grace) = lock(&self.graces).remove(name) else {
            return;
        };
        let lost: Vec<Cid> = if info.instance.as_ref() == Some(&grace.instance) {
            let running: BTreeSet<&str> = info.cus.iter().map(|c| c.cu.as_str()).collect();
            let lost: Vec<Cid> = grace
                .placed
                .into_iter()
                .filter(|c| !running.contains(c.as_str()))
                .collect();
            tracing::info!(
                "executor {name} is back, the same instance: {} of its CUs crashed meanwhile",
                lost.len()
            );
            lost
        } else {
            tracing::warn!(
                "executor {name} is back as another instance: its CUs of before are lost"
            );
            grace.placed
        };
        if !lost.is_empty() {
            self.lost(tokens, name, Some(&lost));
        }
    }

    /// Executor `name` vanished: its token is down, and [`Inner::lost`]. The token lock held.
    fn vanished_locked(&self, tokens: &mut BTreeMap<String, Token>, name: &str) {
        tokens.entry(name.to_owned()).or_default().set(false);
        // A grace under way ends: everything placed on it is lost now.
        lock(&self.graces).remove(name);
        self.lost(tokens, name, None);
    }

    /// Executor `name` is gone (its token went down, or another instance holds its name):
    /// absent while its token is down, and the CUs placed on it crashed; with `only`, those
    /// of them that are still placed on it. The token lock held.
    fn lost(&self, tokens: &mut BTreeMap<String, Token>, name: &str, only: Option<&[Cid]>) {
        if !tokens.get(name).is_some_and(|t| t.up) {
            tracing::warn!("executor {name} vanished");
            if let Some(known) = lock(&self.executors).get_mut(name) {
                if known.present {
                    known.absent_since = Some(std::time::Instant::now());
                }
                known.present = false;
            }
        }
        let lost: Vec<Cid> = {
            let mut placement = lock(&self.placement);
            let lost: Vec<Cid> = placement
                .iter()
                .filter(|(c, e)| *e == name && only.is_none_or(|only| only.contains(c)))
                .map(|(c, _)| c.clone())
                .collect();
            let mut running = lock(&self.running);
            for cu in &lost {
                placement.remove(cu);
                running.remove(cu);
            }
            lost
        };
        if !lost.is_empty() {
            let _ = self.events.send(FleetEvent::Vanished {
                executor: name.to_owned(),
                cus: lost,
            });
        }
        let _ = self.events.send(FleetEvent::ExecutorsChanged);
    }
}

/// An executor whose token went down during a stall of the manager ([`Inner::token_down`]):
/// the instance it was, and the CUs placed on it then.
#[derive(Debug)]
pub(super) struct Grace {
    instance: InstanceId,
    placed: Vec<Cid>,
}

/// How long an executor that vanished right after the manager stalled has to come back.
pub(super) const STALL_GRACE: Duration = Duration::from_secs(3);

/// The manager's own pulse: a thread ticks every [`Pulse::TICK`]; a gap of more than
/// [`Pulse::STALL`] between ticks means the manager did not run (stopped, paused, starved).
#[derive(Debug)]
pub(super) struct Pulse {
    origin: std::time::Instant,
    /// Milliseconds since `origin` at the last tick.
    last_tick: std::sync::atomic::AtomicU64,
    /// Milliseconds since `origin` when the last stall was seen to end (0: none).
    stall_end: std::sync::atomic::AtomicU64,
}

impl Default for Pulse {
    fn default() -> Self {
        Self {
            origin: std::time::Instant::now(),
            last_tick: std::sync::atomic::AtomicU64::new(0),
            stall_end: std::sync::atomic::AtomicU64::new(0),
        }
    }
}

impl Pulse {
    const TICK: Duration = Duration::from_millis(100);
    const STALL: u64 = 1_000;
    /// How long after a stall an executor's vanishing is put down to it.
    const AFTER: u64 = 3_000;

    fn now(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_millis()).unwrap_or(u64::MAX)
    }

    /// Starts the ticking thread; it ends with the fleet.
    pub(super) fn start(inner: &Arc<Inner>) {
        let weak = Arc::downgrade(inner);
        let _ = std::thread::Builder::new()
            .name("fleet-pulse".into())
            .spawn(move || {
                use std::sync::atomic::Ordering;
                loop {
                    std::thread::sleep(Self::TICK);
                    let Some(inner) = weak.upgrade() else { return };
                    let pulse = &inner.pulse;
                    let now = pulse.now();
                    let before = pulse.last_tick.swap(now, Ordering::SeqCst);
                    if now.saturating_sub(before) > Self::STALL {
                        pulse.stall_end.store(now, Ordering::SeqCst);
                        tracing::warn!(
                            "the manager did not run for {} ms (stopped, paused or starved)",
                            now - before
                        );
                    }
                }
            });
    }

    /// Whether the manager is in a stall its pulse has not seen the end of yet, or saw one
    /// end less than [`Pulse::AFTER`] ago.
    pub(super) fn stalled_recently(&self) -> bool {
        use std::sync::atomic::Ordering;
        let now = self.now();
        let last = self.last_tick.load(Ordering::SeqCst);
        let end = self.stall_end.load(Ordering::SeqCst);
        // Before the first tick `last` is 0: not a stall.
        (last > 0 && now.saturating_sub(last) > Self::STALL)
            || (end > 0 && now.saturating_sub(end) < Self::AFTER)
    }
}
