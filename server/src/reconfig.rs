//! The configuration life-cycle (seed Ch. 4.3, Def. 36): reviews run EXPLORE on the live
//! environment and apply the change set they choose. Short-term negative perturbations (a
//! target added or released, a transformation in use deregistered, a CU destroyed or crashed)
//! start a review at once, and so does a registration while some target is unsatisfied;
//! other perturbations wait for the end of the stable interval (the horizon). Perturbations
//! arriving during a review are queued: another review follows.
//!
//! Until executors exist, change sets are applied to the model directly (a model-only
//! executor): the CU graphs are rewritten, so `dependsOn` follows.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime};

use dyknow_engine::knowledge::{self, Learned};
use dyknow_engine::{Cause, ChangeSet, EngineError, ExploreOptions, Ids};
use dyknow_store::KnowledgeBase;
use serde::Serialize;
use tokio::sync::{Notify, broadcast};

/// A perturbation the service saw (seed Def. 36).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Perturbation {
    /// A target was posted.
    TargetAdded(String),
    /// A target was removed.
    TargetReleased(String),
    /// Transformations were registered.
    Registered,
    /// A transformation was deregistered; `in_use` when a CU instantiated it.
    Deregistered {
        /// Whether a CU instantiated it.
        in_use: bool,
    },
    /// A CU was destroyed (the Destroy call) or crashed (`POST /perturbations`).
    CuLost {
        /// The CU.
        cu: String,
        /// Its transformation, tried first when replanning (Ch. 4.3.3).
        transformation: String,
        /// Whether it crashed (rather than being destroyed on request).
        crashed: bool,
    },
    /// `POST /review`.
    ReviewRequested,
}

/// Which interval of the life-cycle the service is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Streams flow; the next review is scheduled.
    Stable,
    /// A review is running.
    Review,
}

#[derive(Debug)]
struct State {
    history: Vec<serde_json::Value>,
    next_id: u64,
    ids: Ids,
    phase: Phase,
    next_review_at: SystemTime,
    /// A review is due at once.
    urgent: bool,
    /// What perturbed the environment since the last review.
    causes: Vec<Cause>,
    /// Transformations of lost CUs, tried first.
    prefer: Vec<String>,
    /// Targets the last review left unsatisfied (or `true` before any review).
    unsatisfied: bool,
    learned: Learned,
    /// Reviews completed since start.
    reviews: u64,
    /// Why the last review failed, if it did.
    last_error: Option<String>,
}

/// Where the life-cycle is.
#[derive(Debug, Clone)]
pub struct LifeCycle {
    /// Stable or review.
    pub phase: Phase,
    /// When the next scheduled review starts.
    pub next_review_at: SystemTime,
    /// A review is due at once (queued behind a running one, or about to start).
    pub review_pending: bool,
    /// Reviews completed since the service started.
    pub reviews: u64,
    /// Why the last review failed, if it did.
    pub last_error: Option<String>,
}

/// The life-cycle manager: owned by the server state, driven by [`Reconfigurator::run`].
pub struct Reconfigurator {
    kb: Arc<KnowledgeBase>,
    horizon: f64,
    time_unit: Duration,
    state: Mutex<State>,
    /// The spec-derived part of the environment, cached between reviews.
    specs: knowledge::SpecCache,
    /// Serialises reviews.
    review_lock: Mutex<()>,
    wake: Notify,
    events: broadcast::Sender<serde_json::Value>,
}

impl std::fmt::Debug for Reconfigurator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reconfigurator")
            .field("horizon", &self.horizon)
            .field("time_unit", &self.time_unit)
            .finish_non_exhaustive()
    }
}

impl Reconfigurator {
    /// A manager over `kb`, with the recorded change sets and learned estimates.
    pub fn new(
        kb: Arc<KnowledgeBase>,
        horizon: f64,
        time_unit: Duration,
    ) -> Result<Self, EngineError> {
        let history = knowledge::change_sets(&kb)?;
        let next_id = history.len() as u64 + 1;
        let learned = knowledge::learned(&kb)?;
        let loaded = knowledge::load(&kb)?;
        let mut ids = Ids::after(&loaded.env);
        // Never reuse a name an earlier change set gave out.
        for cs in &history {
            for a in cs
                .get("actions")
                .and_then(|a| a.as_array())
                .into_iter()
                .flatten()
            {
                if let Some(cu) = a.get("cu").and_then(|c| c.as_str())
                    && let Some(n) = cu.strip_prefix("cu-").and_then(|n| n.parse::<u64>().ok())
                {
                    ids.next_cu = ids.next_cu.max(n);
                }
                if let Some(ch) = a.get("channel").and_then(|c| c.as_str())
                    && let Some(n) = ch.strip_prefix("ch-").and_then(|n| n.parse::<u64>().ok())
                {
                    ids.next_channel = ids.next_channel.max(n);
                }
            }
        }
        let (events, _) = broadcast::channel(256);
        Ok(Self {
            kb,
            horizon,
            time_unit,
            state: Mutex::new(State {
                history,
                next_id,
                ids,
                phase: Phase::Stable,
                next_review_at: SystemTime::now() + time_unit.mul_f64(horizon),
                urgent: false,
                causes: Vec::new(),
                prefer: Vec::new(),
                unsatisfied: !loaded.env.targets.is_empty(),
                learned,
                reviews: 0,
                last_error: None,
            }),
            specs: knowledge::SpecCache::default(),
            review_lock: Mutex::new(()),
            wake: Notify::new(),
            events,
        })
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The environment, candidate table and IRIs now (specs cached while unchanged).
    pub fn load(&self) -> Result<knowledge::Loaded, EngineError> {
        let learned = self.lock().learned.clone();
        self.specs.load_with(&self.kb, Some(&learned))
    }

    /// The horizon H.
    pub fn horizon(&self) -> f64 {
        self.horizon
    }

    /// Records a perturbation; a short-term negative one starts a review at once.
    pub fn perturbed(&self, perturbation: Perturbation) {
        let mut state = self.lock();
        let (urgent, cause) = match perturbation {
            Perturbation::TargetAdded(target) => (true, Some(Cause::TargetAdded { target })),
            Perturbation::TargetReleased(target) => (true, Some(Cause::TargetReleased { target })),
            Perturbation::Registered => (state.unsatisfied, None),
            Perturbation::Deregistered { in_use } => (in_use, None),
            Perturbation::CuLost {
                cu,
                transformation,
                crashed,
            } => {
                state.prefer.push(transformation);
                (true, crashed.then_some(Cause::CuCrashed { cu }))
            }
            Perturbation::ReviewRequested => (true, Some(Cause::Review)),
        };
        if let Some(c) = cause {
            state.causes.push(c);
        }
        if urgent {
            state.urgent = true;
            drop(state);
            self.wake.notify_one();
        }
    }

    /// The life-cycle loop: waits for an urgent perturbation or the end of the stable
    /// interval, then reviews. Runs until the process ends.
    pub async fn run(self: Arc<Self>) {
        loop {
            let wait = {
                let state = self.lock();
                if state.urgent {
                    Duration::ZERO
                } else {
                    state
                        .next_review_at
                        .duration_since(SystemTime::now())
                        .unwrap_or(Duration::ZERO)
                }
            };
            tokio::select! {
                () = self.wake.notified() => {}
                () = tokio::time::sleep(wait) => {}
            }
            let due = {
                let state = self.lock();
                state.urgent || SystemTime::now() >= state.next_review_at
            };
            if !due {
                continue;
            }
            let me = self.clone();
            match tokio::task::spawn_blocking(move || me.review()).await {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => tracing::error!("review failed: {e}"),
                Err(e) => tracing::error!("review panicked: {e}"),
            }
        }
    }

    /// One review interval: EXPLORE on the current environment, COMPILE, and the change set
    /// applied to the model and recorded. Returns the change set, if it changed anything.
    pub fn review(&self) -> Result<Option<serde_json::Value>, EngineError> {
        let _one_at_a_time = self
            .review_lock
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let (causes, prefer, learned) = {
            let mut state = self.lock();
            state.urgent = false;
            state.phase = Phase::Review;
            (
                std::mem::take(&mut state.causes),
                std::mem::take(&mut state.prefer),
                state.learned.clone(),
            )
        };
        let result = self.review_with(&causes, prefer, &learned);
        let mut state = self.lock();
        state.phase = Phase::Stable;
        state.reviews += 1;
        state.next_review_at = SystemTime::now() + self.time_unit.mul_f64(self.horizon);
        state.last_error = result.as_ref().err().map(ToString::to_string);
        if result.is_err() {
            // Keep what perturbed the environment for the next attempt.
            let mut kept = causes;
            kept.append(&mut state.causes);
            state.causes = kept;
        }
        result
    }

    fn review_with(
        &self,
        causes: &[Cause],
        prefer: Vec<String>,
        learned: &Learned,
    ) -> Result<Option<serde_json::Value>, EngineError> {
        let loaded = self.specs.load_with(&self.kb, Some(learned))?;
        let options = ExploreOptions {
            horizon: self.horizon,
            prefer,
            ..ExploreOptions::default()
        };
        let mut ids = self.lock().ids.clone();
        let knowledge::Reviewed {
            compiled, delta, ..
        } = knowledge::review(&loaded, &options, &mut ids);
        let unsatisfied = !compiled.unsatisfied_targets.is_empty();
        if compiled.actions.is_empty() {
            let mut state = self.lock();
            state.unsatisfied = unsatisfied;
            return Ok(None);
        }
        let id = format!("cs-{}", self.lock().next_id);
        let cause = causes.first().cloned().unwrap_or(Cause::Review);
        let change_set = ChangeSet::new(id.clone(), cause, compiled, &delta);
        let mut parts = delta.parts.clone();
        parts.push((
            knowledge::change_set_part(&id),
            knowledge::change_set_triples(&change_set),
        ));
        // One atomic write: the new configuration and its record.
        self.kb.set_environment(&parts)?;
        let json = serde_json::to_value(&change_set).unwrap_or(serde_json::Value::Null);
        let mut state = self.lock();
        state.ids = ids;
        state.next_id += 1;
        state.unsatisfied = unsatisfied;
        state.history.push(json.clone());
        drop(state);
        let _ = self.events.send(json.clone());
        Ok(Some(json))
    }

    /// The recorded change sets, oldest first; after `since` when given.
    pub fn change_sets(&self, since: Option<&str>) -> Vec<serde_json::Value> {
        let state = self.lock();
        let start = since
            .and_then(|s| {
                state
                    .history
                    .iter()
                    .position(|c| c.get("id").and_then(|i| i.as_str()) == Some(s))
            })
            .map_or(0, |i| i + 1);
        state.history[start..].to_vec()
    }

    /// A change set by id.
    pub fn change_set(&self, id: &str) -> Option<serde_json::Value> {
        self.lock()
            .history
            .iter()
            .find(|c| c.get("id").and_then(|i| i.as_str()) == Some(id))
            .cloned()
    }

    /// New change sets, as they are made.
    pub fn subscribe(&self) -> broadcast::Receiver<serde_json::Value> {
        self.events.subscribe()
    }

    /// The life-cycle's state now.
    pub fn status(&self) -> LifeCycle {
        let state = self.lock();
        LifeCycle {
            phase: state.phase,
            next_review_at: state.next_review_at,
            review_pending: state.urgent,
            reviews: state.reviews,
            last_error: state.last_error.clone(),
        }
    }

    /// The number the next fresh CU name counts from.
    pub fn peek_next_cu(&self) -> u64 {
        self.lock().ids.next_cu
    }

    /// Makes sure no change set gives out `name` (a CU spawned on request).
    pub fn reserve_cu(&self, name: &str) {
        self.lock().ids.reserve(name);
    }

    /// The learned estimates.
    pub fn learned(&self) -> Learned {
        self.lock().learned.clone()
    }

    /// Records an observed cost and writes the updated estimates into the store.
    pub fn observe(&self, update: impl FnOnce(&mut Learned)) -> Result<(), EngineError> {
        let _writes = self
            .review_lock
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut learned = self.lock().learned.clone();
        update(&mut learned);
        let loaded = self.load()?;
        let triples = knowledge::statistics_triples(&self.kb, &learned, &loaded.iris)?;
        self.kb
            .set_environment(&[(knowledge::STATISTICS_PART.to_owned(), triples)])?;
        self.lock().learned = learned;
        Ok(())
    }
}
