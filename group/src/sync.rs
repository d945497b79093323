//! Synchronisation of the symbol streams into one state stream (contract `groups.md`,
//! "Synchronisation into a state stream"). Pure and clock-free: the caller passes the wall
//! clock (`now`, ms since the Unix epoch) with every sample and poll, so crafted streams test
//! it exactly.
//!
//! - `wait` (the seed's synchronisation after Heintz): a state every `P` ms of valid time, at
//!   the multiples of `P`; the state for `t` is emitted once every stream has a sample valid at
//!   `t` (its timestamp in `(t - P, t]`; the latest such is used) or `D` ms of wall time after
//!   `t`; a stream without one is unknown in it.
//! - `hold`: a state every `P` ms; each stream keeps its last value while it is younger than
//!   `A` (`t - t_sample < A`), then is unknown. The state for `t` is emitted once every stream
//!   has a sample at or after `t` (nothing older can come from an in-order stream) or `D` ms of
//!   wall time after `t` (`max_delay_ms`, default `P`: this project's addition). A fresh
//!   start waits for the streams: the first state is at the first multiple of `P` at or after
//!   the first sample that arrives (one that came before the start is not seen), so a group
//!   started over a flowing stream begins with its value rather than with a state that no
//!   sample could reach yet; if none arrives within `max(A, D)` ms, states begin at the next
//!   multiple of `P`, unknown.
//! - `event`: a state at every sample's `t` holding the latest value of every stream
//!   (sample and hold without ageing). Samples of several streams with the same `t` make one
//!   state: the state for `t` is emitted once every stream has a sample at or after `t`, or
//!   `D` ms of wall time after `t` (`max_delay_ms`, default 2: this project's addition, so
//!   that sources ticking together do not make each other late).
//!
//! In every policy a sample at or before the last emitted state's `t` is *late*: counted and
//! dropped. States have strictly increasing timestamps, and none is emitted before the wall
//! clock reaches its time.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// How samples become states. Read with its defaults filled in ([`Policy::from`] a
/// [`PolicyFields`]), written with every field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "policy", rename_all = "lowercase", from = "PolicyFields")]
pub enum Policy {
    /// A state every `period_ms` once every stream has a sample valid at its time, or
    /// `max_delay_ms` after it.
    Wait {
        /// `P`.
        period_ms: u64,
        /// `D`.
        max_delay_ms: u64,
    },
    /// A state every `period_ms`; values held while younger than `max_age_ms`.
    Hold {
        /// `P`.
        period_ms: u64,
        /// `A`.
        max_age_ms: u64,
        /// `D` (default `P`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        max_delay_ms: Option<u64>,
    },
    /// A state at every sample's time.
    Event {
        /// `D` (default 2).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        max_delay_ms: Option<u64>,
    },
}

/// A policy as written, every parameter optional: `wait`'s `P` defaults to 100 ms and its `D`
/// to `5 P` (the default policy is `wait` with 100 and 500); `hold`'s `P` to 100 ms and its `A`
/// to 1,000 ms (`D` stays optional: `P`); `event`'s `D` stays optional (2 ms). The CLI's
/// defaults are the same.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(tag = "policy", rename_all = "lowercase", deny_unknown_fields)]
pub enum PolicyFields {
    /// `wait`.
    Wait {
        /// `P`.
        period_ms: Option<u64>,
        /// `D`.
        max_delay_ms: Option<u64>,
    },
    /// `hold`.
    Hold {
        /// `P`.
        period_ms: Option<u64>,
        /// `A`.
        max_age_ms: Option<u64>,
        /// `D`.
        max_delay_ms: Option<u64>,
    },
    /// `event`.
    Event {
        /// `D`.
        max_delay_ms: Option<u64>,
    },
}

/// `wait`'s and `hold`'s period when none is given (ms).
pub const DEFAULT_PERIOD_MS: u64 = 100;
/// `hold`'s maximum age when none is given (ms).
pub const DEFAULT_MAX_AGE_MS: u64 = 1_000;

impl From<PolicyFields> for Policy {
    fn from(f: PolicyFields) -> Self {
        match f {
            PolicyFields::Wait {
                period_ms,
                max_delay_ms,
            } => {
                let period_ms = period_ms.unwrap_or(DEFAULT_PERIOD_MS);
                Self::Wait {
                    period_ms,
                    max_delay_ms: max_delay_ms.unwrap_or(period_ms.saturating_mul(5)),
                }
            }
            PolicyFields::Hold {
                period_ms,
                max_age_ms,
                max_delay_ms,
            } => Self::Hold {
                period_ms: period_ms.unwrap_or(DEFAULT_PERIOD_MS),
                max_age_ms: max_age_ms.unwrap_or(DEFAULT_MAX_AGE_MS),
                max_delay_ms,
            },
            PolicyFields::Event { max_delay_ms } => Self::Event { max_delay_ms },
        }
    }
}

impl Default for Policy {
    /// `wait` with `P` = 100 ms and `D` = 500 ms.
    fn default() -> Self {
        Self::Wait {
            period_ms: 100,
            max_delay_ms: 500,
        }
    }
}

impl Policy {
    /// Checks the parameters: periods are positive; at most an hour.
    pub fn validate(&self) -> Result<(), String> {
        const HOUR: u64 = 3_600_000;
        let (p, others) = match *self {
            Self::Wait {
                period_ms,
                max_delay_ms,
            } => (period_ms, vec![("max_delay_ms", max_delay_ms)]),
            Self::Hold {
                period_ms,
                max_age_ms,
                max_delay_ms,
            } => (
                period_ms,
                vec![
                    ("max_age_ms", max_age_ms),
                    ("max_delay_ms", max_delay_ms.unwrap_or(period_ms)),
                ],
            ),
            Self::Event { max_delay_ms } => {
                let d = max_delay_ms.unwrap_or(2);
                if d > HOUR {
                    return Err(format!(
                        "sync: max_delay_ms must be at most {HOUR} ms, not {d}"
                    ));
                }
                return Ok(());
            }
        };
        if p == 0 || p > HOUR {
            return Err(format!(
                "sync: period_ms must be between 1 and {HOUR}, not {p}"
            ));
        }
        for (name, v) in others {
            if v > 24 * HOUR {
                return Err(format!(
                    "sync: {name} must be at most {} ms, not {v}",
                    24 * HOUR
                ));
            }
        }
        Ok(())
    }

    /// The policy with its optional values filled in as they apply (`hold`'s `D` is `P`,
    /// `event`'s 2), as `GET /groups/{label}` shows it.
    #[must_use]
    pub fn filled(self) -> Self {
        match self {
            Self::Wait { .. } => self,
            Self::Hold {
                period_ms,
                max_age_ms,
                ..
            } => Self::Hold {
                period_ms,
                max_age_ms,
                max_delay_ms: Some(self.max_delay()),
            },
            Self::Event { .. } => Self::Event {
                max_delay_ms: Some(self.max_delay()),
            },
        }
    }

    fn period(&self) -> Option<u64> {
        match *self {
            Self::Wait { period_ms, .. } | Self::Hold { period_ms, .. } => Some(period_ms),
            Self::Event { .. } => None,
        }
    }

    fn max_delay(&self) -> u64 {
        match *self {
            Self::Wait { max_delay_ms, .. } => max_delay_ms,
            Self::Hold {
                period_ms,
                max_delay_ms,
                ..
            } => max_delay_ms.unwrap_or(period_ms),
            Self::Event { max_delay_ms } => max_delay_ms.unwrap_or(2),
        }
    }
}

/// One synchronised state: its time and each stream's value (`None`: unknown).
#[derive(Debug, Clone, PartialEq)]
pub struct SyncState<V> {
    /// The state's timestamp (ms).
    pub t: u64,
    /// One value per stream, in stream order; removed streams are `None`.
    pub values: Vec<Option<V>>,
}

/// What a stream saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StreamStats {
    /// Samples received (late ones included).
    pub samples: u64,
    /// Samples that came after the state of their time was emitted (dropped).
    pub late: u64,
    /// Emitted states in which the stream had no value.
    pub missing_states: u64,
}

/// At most this many states of the time a resumed group was down are made up ([`Synchroniser::start`]).
pub const MAX_CATCH_UP: u64 = 100_000;

/// At most this many states one [`Synchroniser::poll`] returns: after a long stall or a
/// resume, the rest are due at the next poll at once (the group's thread lets go of its lock
/// between them, so its status and changes are not held up for the whole catch-up).
pub const MAX_STATES_PER_POLL: usize = 1_000;

/// At most this many samples wait per stream; older ones are dropped as late.
pub const MAX_PENDING: usize = 65_536;

#[derive(Debug)]
struct Stream<V> {
    /// Samples after the last emitted state, by time (a repeated time replaces).
    pending: BTreeMap<u64, V>,
    /// The latest sample taken into a state (hold and event).
    last: Option<(u64, V)>,
    stats: StreamStats,
    active: bool,
}

/// Turns samples of several streams into states (see the module documentation).
#[derive(Debug)]
pub struct Synchroniser<V> {
    policy: Policy,
    streams: Vec<Stream<V>>,
    /// The next state's time (wait, hold), once started.
    next_t: Option<u64>,
    /// The last emitted state's time.
    last_t: Option<u64>,
    /// `hold` after a fresh start: when it was started, until the first sample fixes the first
    /// state's time (or `max(A, D)` passes).
    armed_at: Option<u64>,
}

impl<V: Clone> Synchroniser<V> {
    /// A synchroniser of `streams` streams, not started.
    pub fn new(policy: Policy, streams: usize) -> Self {
        let mut s = Self {
            policy,
            streams: Vec::new(),
            next_t: None,
            last_t: None,
            armed_at: None,
        };
        for _ in 0..streams {
            s.add_stream();
        }
        s
    }

    /// The policy.
    pub fn policy(&self) -> Policy {
        self.policy
    }

    /// Starts emitting states: the first is the first multiple of the period after `now`. A
    /// resumed group (after [`Synchroniser::resume_after`]) goes on with the multiple after its
    /// last state, as after a stall: the states of the time it was down are due at once, each
    /// without samples (unknown), so that a window that fell in that time is not decided
    /// without a state in it (an `always` over it was true, an `eventually` false: a user
    /// audit). At most [`MAX_CATCH_UP`] of them: a longer time down is skipped beyond.
    pub fn start(&mut self, now: u64) {
        if matches!(self.policy, Policy::Hold { .. }) && self.last_t.is_none() {
            // A fresh `hold` start waits for the first sample (module documentation).
            self.armed_at = Some(now);
            return;
        }
        if let Some(p) = self.policy.period() {
            let from = self.last_t.map_or(now, |l| {
                l.max(now.saturating_sub(MAX_CATCH_UP.saturating_mul(p)))
            });
            self.next_t = Some((from / p + 1) * p);
        } else {
            self.next_t = Some(0);
        }
    }

    /// Sets the last emitted state's time (resuming after a restart): samples at or before it
    /// are late.
    pub fn resume_after(&mut self, last_t: Option<u64>) {
        self.last_t = last_t;
    }

    /// Whether [`Synchroniser::start`] was called.
    pub fn started(&self) -> bool {
        self.next_t.is_some() || self.armed_at.is_some()
    }

    /// How long a fresh `hold` start waits for a first sample: `max(A, D)`.
    fn arming_wait(&self) -> u64 {
        match self.policy {
            Policy::Hold { max_age_ms, .. } => max_age_ms.max(self.policy.max_delay()),
            _ => 0,
        }
    }

    /// The first state's time after a fresh `hold` start: the first multiple of `P` at or
    /// after the first sample `t`, but not before the last multiple of `P` at or before the
    /// start.
    fn fix_first_state(&mut self, t: u64) {
        if let (Some(armed), Some(p)) = (self.armed_at.take(), self.policy.period()) {
            self.next_t = Some(t.div_ceil(p).max(armed / p) * p);
        }
    }

    /// Adds a stream (a symbol added while running); returns its index.
    pub fn add_stream(&mut self) -> usize {
        self.streams.push(Stream {
            pending: BTreeMap::new(),
            last: None,
            stats: StreamStats::default(),
            active: true,
        });
        self.streams.len() - 1
    }

    /// Stops waiting for a stream: it is unknown in later states and never waited for.
    pub fn remove_stream(&mut self, stream: usize) {
        if let Some(s) = self.streams.get_mut(stream) {
            s.active = false;
            s.pending.clear();
            s.last = None;
        }
    }

    /// Takes a stream back (a symbol needed again).
    pub fn reactivate_stream(&mut self, stream: usize) {
        if let Some(s) = self.streams.get_mut(stream) {
            s.active = true;
        }
    }

    /// What stream `i` saw.
    pub fn stats(&self, stream: usize) -> StreamStats {
        self.streams
            .get(stream)
            .map(|s| s.stats)
            .unwrap_or_default()
    }

    /// The last emitted state's time.
    pub fn last_t(&self) -> Option<u64> {
        self.last_t
    }

    /// When (wall clock, ms) [`Synchroniser::poll`] may emit the next state even if samples
    /// are missing; `None` when no state is due (before the start; `event` with nothing
    /// pending).
    pub fn next_deadline(&self) -> Option<u64> {
        if let Some(armed) = self.armed_at {
            return Some(armed.saturating_add(self.arming_wait()));
        }
        let d = self.policy.max_delay();
        match (self.policy.period(), self.next_t) {
            (Some(_), Some(t)) => Some(t.saturating_add(d)),
            (None, Some(_)) => self.first_pending().map(|t| t.saturating_add(d)),
            _ => None,
        }
    }

    fn first_pending(&self) -> Option<u64> {
        self.streams
            .iter()
            .filter_map(|s| s.pending.first_key_value().map(|(t, _)| *t))
            .min()
    }

    /// Takes a sample of stream `stream` holding at `t`; returns the states it completes.
    /// Samples before the start, of a removed stream, or late are counted and dropped.
    pub fn offer(&mut self, stream: usize, t: u64, value: V, now: u64) -> Vec<SyncState<V>> {
        let started = self.started();
        let last_t = self.last_t;
        let Some(s) = self.streams.get_mut(stream) else {
            return Vec::new();
        };
        s.stats.samples += 1;
        if !s.active || !started {
            return Vec::new();
        }
        if last_t.is_some_and(|l| t <= l) {
            s.stats.late += 1;
            return Vec::new();
        }
        s.pending.insert(t, value);
        if s.pending.len() > MAX_PENDING {
            s.pending.pop_first();
            s.stats.late += 1;
        }
        if self.armed_at.is_some() {
            self.fix_first_state(t);
        }
        self.poll(now)
    }

    /// Emits the states that are due at `now`.
    pub fn poll(&mut self, now: u64) -> Vec<SyncState<V>> {
        let mut out = Vec::new();
        if matches!(self.policy, Policy::Event { .. }) {
            let d = self.policy.max_delay();
            while let Some(t) = self.first_pending() {
                // Not before the wall clock reaches t (a sample stamped ahead of it, by a
                // clock that runs fast, waits: emitted at once, its state would make every
                // sample up to that time late and stop the group); then once every stream
                // has shown a sample at or after t (t is the earliest pending), or the delay
                // is over.
                let all = self
                    .streams
                    .iter()
                    .filter(|s| s.active)
                    .all(|s| !s.pending.is_empty());
                if now < t || !(all || now >= t.saturating_add(d)) {
                    break;
                }
                out.push(self.emit_event(t));
            }
            return out;
        }
        if let (Some(armed), Some(p)) = (self.armed_at, self.policy.period())
            && now >= armed.saturating_add(self.arming_wait())
        {
            // No sample came: states begin at the next multiple of P, unknown.
            self.armed_at = None;
            self.next_t = Some((armed / p + 1) * p);
        }
        let (Some(p), Some(mut t)) = (self.policy.period(), self.next_t) else {
            return out;
        };
        let d = self.policy.max_delay();
        while now >= t
            && (now >= t.saturating_add(d) || self.complete(t, p))
            && out.len() < MAX_STATES_PER_POLL
        {
            out.push(self.emit_periodic(t, p));
            t += p;
            self.next_t = Some(t);
        }
        out
    }

    fn complete(&self, t: u64, p: u64) -> bool {
        let wait = matches!(self.policy, Policy::Wait { .. });
        self.streams.iter().filter(|s| s.active).all(|s| {
            if wait {
                s.pending
                    .range(t.saturating_sub(p - 1)..=t)
                    .next()
                    .is_some()
            } else {
                s.pending.range(t..).next().is_some()
            }
        })
    }

    fn emit_periodic(&mut self, t: u64, p: u64) -> SyncState<V> {
        let policy = self.policy;
        let values = self
            .streams
            .iter_mut()
            .map(|s| {
                if !s.active {
                    return None;
                }
                let upto = s
                    .pending
                    .range(..=t)
                    .next_back()
                    .map(|(k, v)| (*k, v.clone()));
                // Everything at or before t is taken (or superseded).
                let later = s.pending.split_off(&(t + 1));
                s.pending = later;
                let value = match policy {
                    Policy::Wait { .. } => upto.filter(|(k, _)| *k + p > t).map(|(_, v)| v),
                    Policy::Hold { max_age_ms, .. } => {
                        if upto.is_some() {
                            s.last = upto;
                        }
                        s.last
                            .as_ref()
                            .filter(|(k, _)| t - k < max_age_ms)
                            .map(|(_, v)| v.clone())
                    }
                    Policy::Event { .. } => None,
                };
                if value.is_none() {
                    s.stats.missing_states += 1;
                }
                value
            })
            .collect();
        self.last_t = Some(t);
        SyncState { t, values }
    }

    fn emit_event(&mut self, t: u64) -> SyncState<V> {
        let values = self
            .streams
            .iter_mut()
            .map(|s| {
                if !s.active {
                    return None;
                }
                if let Some(v) = s.pending.remove(&t) {
                    s.last = Some((t, v));
                }
                let v = s.last.as_ref().map(|(_, v)| v.clone());
                if v.is_none() {
                    s.stats.missing_states += 1;
                }
                v
            })
            .collect();
        self.last_t = Some(t);
        SyncState { t, values }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<Policy, String> {
        serde_json::from_str(text).map_err(|e| e.to_string())
    }

    #[test]
    fn left_out_parameters_take_their_defaults() {
        assert_eq!(read(r#"{"policy": "wait"}"#), Ok(Policy::default()));
        assert_eq!(
            read(r#"{"policy": "wait", "period_ms": 30}"#),
            Ok(Policy::Wait {
                period_ms: 30,
                max_delay_ms: 150
            })
        );
        assert_eq!(
            read(r#"{"policy": "wait", "max_delay_ms": 0}"#),
            Ok(Policy::Wait {
                period_ms: 100,
                max_delay_ms: 0
            })
        );
        assert_eq!(
            read(r#"{"policy": "hold"}"#),
            Ok(Policy::Hold {
                period_ms: 100,
                max_age_ms: 1000,
                max_delay_ms: None
            })
        );
        assert_eq!(
            read(r#"{"policy": "event"}"#),
            Ok(Policy::Event { max_delay_ms: None })
        );
    }

    #[test]
    fn filled_shows_the_delays_that_apply() {
        let hold = read(r#"{"policy": "hold", "period_ms": 40}"#).unwrap();
        assert_eq!(
            hold.filled(),
            Policy::Hold {
                period_ms: 40,
                max_age_ms: 1000,
                max_delay_ms: Some(40)
            }
        );
        assert_eq!(
            Policy::Event { max_delay_ms: None }.filled(),
            Policy::Event {
                max_delay_ms: Some(2)
            }
        );
        assert_eq!(Policy::default().filled(), Policy::default());
        // Filling changes nothing the synchroniser does.
        for p in [hold, Policy::Event { max_delay_ms: None }] {
            assert_eq!(p.filled().max_delay(), p.max_delay());
        }
    }

    #[test]
    fn what_is_written_reads_back_the_same() {
        for p in [
            Policy::default(),
            Policy::Hold {
                period_ms: 7,
                max_age_ms: 9,
                max_delay_ms: Some(3),
            },
            Policy::Event {
                max_delay_ms: Some(0),
            },
        ] {
            let text = serde_json::to_string(&p).unwrap();
            assert_eq!(read(&text), Ok(p), "{text}");
        }
    }

    #[test]
    fn unknown_fields_and_policies_are_refused() {
        for text in [
            r#"{"policy": "event", "period_ms": 5}"#,
            r#"{"policy": "wait", "max_age_ms": 5}"#,
            r#"{"period_ms": 5}"#,
            r#"{"policy": "often"}"#,
            r#"{"policy": "wait", "period_ms": -1}"#,
        ] {
            assert!(read(text).is_err(), "{text}");
        }
    }
}
