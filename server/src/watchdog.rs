//! The SPARQL timeout: one thread cancels every query whose time is up.
//!
//! A timer task per query cost a spawn, a wake of another worker and an abort on every request
//! (a few microseconds of a 0.2 ms lookup, `docs/benchmarks.md`, "Per-request cost"). Here a
//! query costs one lock and one push: deadlines come in order (one timeout per service), the
//! thread sleeps until the earliest and is woken only when a query's deadline comes before the
//! one it sleeps until (in practice: when it slept with nothing to watch). A query that ended
//! is dropped from the queue when it reaches the front, or by the next query's push.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, PoisonError, Weak};
use std::time::Instant;

use dyknow_store::oxigraph::sparql::CancellationToken;

/// Cancels the queries it watches at their deadlines; its thread ends when it is dropped.
#[derive(Default)]
pub struct Watchdog {
    inner: Arc<Inner>,
}

#[derive(Default)]
struct Inner {
    state: Mutex<State>,
    wake: Condvar,
}

#[derive(Default)]
struct State {
    /// Deadlines in order, each with the token of a query still running (or ended: `Weak`).
    queue: VecDeque<(Instant, Weak<CancellationToken>)>,
    sleep: Sleep,
    started: bool,
    closed: bool,
}

#[derive(Default, Clone, Copy, PartialEq, Debug)]
enum Sleep {
    /// Running, or not started.
    #[default]
    Awake,
    /// Until this deadline.
    Until(Instant),
    /// Until woken: nothing to watch.
    Forever,
}

impl Watchdog {
    /// Cancels `token` at `deadline` unless every `Arc` of it was dropped (the query ended).
    /// Fails only when the watchdog's thread cannot be started (the system is out of threads);
    /// a later call tries again.
    pub fn watch(&self, deadline: Instant, token: &Arc<CancellationToken>) -> std::io::Result<()> {
        let mut state = lock(&self.inner.state);
        while state
            .queue
            .front()
            .is_some_and(|(_, t)| t.strong_count() == 0)
        {
            state.queue.pop_front();
        }
        let at = state.queue.partition_point(|(d, _)| *d <= deadline);
        state.queue.insert(at, (deadline, Arc::downgrade(token)));
        if !state.started {
            let inner = Arc::clone(&self.inner);
            if let Err(e) = std::thread::Builder::new()
                .name("sparql-timeout".into())
                .spawn(move || inner.run())
            {
                state.queue.remove(at);
                return Err(e);
            }
            state.started = true;
        }
        let wake = match state.sleep {
            Sleep::Awake => false,
            Sleep::Until(t) => deadline < t,
            Sleep::Forever => true,
        };
        drop(state);
        if wake {
            self.inner.wake.notify_one();
        }
        Ok(())
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        lock(&self.inner.state).closed = true;
        self.inner.wake.notify_one();
    }
}

impl Inner {
    fn run(&self) {
        let mut state = lock(&self.state);
        loop {
            if state.closed {
                return;
            }
            let now = Instant::now();
            while let Some((deadline, token)) = state.queue.front() {
                if token.strong_count() == 0 {
                    state.queue.pop_front();
                } else if *deadline <= now {
                    if let Some(token) = token.upgrade() {
                        token.cancel();
                    }
                    state.queue.pop_front();
                } else {
                    break;
                }
            }
            state = match state.queue.front().map(|(d, _)| *d) {
                None => {
                    state.sleep = Sleep::Forever;
                    self.wake
                        .wait(state)
                        .unwrap_or_else(PoisonError::into_inner)
                }
                Some(deadline) => {
                    state.sleep = Sleep::Until(deadline);
                    self.wake
                        .wait_timeout(state, deadline.saturating_duration_since(now))
                        .unwrap_or_else(PoisonError::into_inner)
                        .0
                }
            };
            state.sleep = Sleep::Awake;
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    fn token() -> Arc<CancellationToken> {
        Arc::new(CancellationToken::new())
    }

    /// Polls until `f` holds (at most 30 s).
    fn eventually(f: impl Fn() -> bool) -> bool {
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(30) {
            if f() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        false
    }

    /// Polls until the watchdog's thread sleeps as `sleep` says.
    fn sleeps(dog: &Watchdog, sleep: fn(Sleep) -> bool) -> bool {
        eventually(|| sleep(lock(&dog.inner.state).sleep))
    }

    #[test]
    fn a_query_is_cancelled_at_its_deadline_and_not_before() {
        let dog = Watchdog::default();
        // Woken from a sleep with nothing to watch.
        let first = token();
        dog.watch(Instant::now() + Duration::from_secs(3600), &first)
            .unwrap();
        drop(first);
        let late = token();
        dog.watch(Instant::now() + Duration::from_secs(3600), &late)
            .unwrap();
        assert!(sleeps(&dog, |s| matches!(s, Sleep::Until(_))));
        // Earlier than the deadline the thread sleeps until: it is woken.
        let now = Instant::now();
        let soon = token();
        dog.watch(now + Duration::from_millis(20), &soon).unwrap();
        assert!(eventually(|| soon.is_cancelled()));
        assert!(Instant::now() >= now + Duration::from_millis(20));
        assert!(!late.is_cancelled());
        // With nothing left to watch the thread sleeps until woken; a new query wakes it.
        drop(late);
        let prune = token();
        dog.watch(Instant::now(), &prune).unwrap();
        assert!(eventually(|| prune.is_cancelled()));
        drop(prune);
        assert!(sleeps(&dog, |s| s == Sleep::Forever));
        let again = token();
        dog.watch(Instant::now() + Duration::from_millis(5), &again)
            .unwrap();
        assert!(eventually(|| again.is_cancelled()));
    }

    #[test]
    fn deadlines_out_of_order_are_kept_in_order() {
        let dog = Watchdog::default();
        let now = Instant::now();
        let tokens: Vec<_> = [50u64, 10, 30, 3600, 40]
            .iter()
            .map(|s| {
                let t = token();
                dog.watch(now + Duration::from_secs(3600 + s), &t).unwrap();
                t
            })
            .collect();
        {
            let state = lock(&dog.inner.state);
            let deadlines: Vec<Instant> = state.queue.iter().map(|(d, _)| *d).collect();
            assert!(deadlines.is_sorted(), "{deadlines:?}");
            assert_eq!(deadlines.len(), tokens.len());
        }
        // Cancelled in the order of their deadlines, the far one not at all.
        let soon = token();
        dog.watch(now + Duration::from_millis(10), &soon).unwrap();
        assert!(eventually(|| soon.is_cancelled()));
        assert!(tokens.iter().all(|t| !t.is_cancelled()));
    }

    #[test]
    fn ended_queries_leave_the_queue() {
        let dog = Watchdog::default();
        let now = Instant::now();
        for _ in 0..1000 {
            let t = token();
            dog.watch(now + Duration::from_secs(3600), &t).unwrap();
            // The query ends: its token is dropped.
        }
        assert!(lock(&dog.inner.state).queue.len() <= 1);
    }

    #[test]
    fn the_thread_ends_with_the_watchdog() {
        let dog = Watchdog::default();
        let t = token();
        dog.watch(Instant::now() + Duration::from_secs(3600), &t)
            .unwrap();
        let inner = Arc::downgrade(&dog.inner);
        drop(dog);
        // The thread held the last other reference.
        assert!(eventually(|| inner.strong_count() == 0));
        assert!(!t.is_cancelled());
    }
}
