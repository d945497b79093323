//! One thread that fires the timers of every CU of a host, so idle CUs cost no thread and
//! no CPU.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::{Arc, Condvar, Mutex, PoisonError, Weak};
use std::time::{Duration, Instant};

/// Something with timers: a running CU.
pub trait Fire: Send + Sync {
    /// Timer `timer` is due; returns whether it should fire again.
    fn fire(&self, timer: usize) -> bool;
}

struct Entry {
    due: Instant,
    seq: u64,
    period: Duration,
    timer: usize,
    target: Weak<dyn Fire>,
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        (self.due, self.seq) == (other.due, other.seq)
    }
}
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.due, self.seq).cmp(&(other.due, other.seq))
    }
}

#[derive(Default)]
struct Queue {
    heap: BinaryHeap<Reverse<Entry>>,
    seq: u64,
    stopped: bool,
}

/// The timer thread of a host. Dropping the last handle stops it.
#[derive(Clone)]
pub struct Timers {
    shared: Arc<(Mutex<Queue>, Condvar)>,
    _stop: Arc<Stop>,
}

impl std::fmt::Debug for Timers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Timers").finish_non_exhaustive()
    }
}

struct Stop(Arc<(Mutex<Queue>, Condvar)>);

impl Drop for Stop {
    fn drop(&mut self) {
        let (queue, signal) = &*self.0;
        queue.lock().unwrap_or_else(PoisonError::into_inner).stopped = true;
        signal.notify_all();
    }
}

impl Timers {
    /// Starts the timer thread.
    pub fn start() -> Self {
        let shared: Arc<(Mutex<Queue>, Condvar)> = Arc::default();
        let worker = shared.clone();
        let spawned = std::thread::Builder::new()
            .name("dyknow-timers".into())
            .spawn(move || run(&worker));
        if let Err(e) = spawned {
            tracing::error!("cannot start the timer thread: {e}");
        }
        Self {
            _stop: Arc::new(Stop(shared.clone())),
            shared,
        }
    }

    /// Fires `timer` of `target` every `period`, first after one period, while `target`
    /// lives and wants it.
    pub fn every(&self, target: Weak<dyn Fire>, timer: usize, period: Duration) {
        let (queue, signal) = &*self.shared;
        let mut queue = queue.lock().unwrap_or_else(PoisonError::into_inner);
        queue.seq += 1;
        let seq = queue.seq;
        queue.heap.push(Reverse(Entry {
            due: Instant::now() + period,
            seq,
            period,
            timer,
            target,
        }));
        signal.notify_one();
    }
}

fn run(shared: &(Mutex<Queue>, Condvar)) {
    let (queue, signal) = shared;
    let mut guard = queue.lock().unwrap_or_else(PoisonError::into_inner);
    loop {
        if guard.stopped {
            return;
        }
        let now = Instant::now();
        let wait = match guard.heap.peek() {
            None => None,
            Some(Reverse(entry)) if entry.due <= now => Some(Duration::ZERO),
            Some(Reverse(entry)) => Some(entry.due - now),
        };
        match wait {
            None => {
                guard = signal.wait(guard).unwrap_or_else(PoisonError::into_inner);
            }
            Some(d) if d > Duration::ZERO => {
                guard = signal
                    .wait_timeout(guard, d)
                    .unwrap_or_else(PoisonError::into_inner)
                    .0;
            }
            Some(_) => {
                let Some(Reverse(mut entry)) = guard.heap.pop() else {
                    continue;
                };
                drop(guard);
                let again = entry.target.upgrade().is_some_and(|t| t.fire(entry.timer));
                guard = queue.lock().unwrap_or_else(PoisonError::into_inner);
                if again {
                    // Fixed rate; after a long stall, the next tick is one period from now.
                    entry.due += entry.period;
                    let now = Instant::now();
                    if entry.due < now {
                        entry.due = now + entry.period;
                    }
                    guard.heap.push(Reverse(entry));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    struct Count(AtomicUsize, usize);
    impl Fire for Count {
        fn fire(&self, _timer: usize) -> bool {
            self.0.fetch_add(1, Ordering::SeqCst) + 1 < self.1
        }
    }

    #[test]
    fn timers_fire_until_their_target_says_stop_or_is_gone() {
        let timers = Timers::start();
        let three = Arc::new(Count(AtomicUsize::new(0), 3));
        let as_fire: Arc<dyn Fire> = three.clone();
        timers.every(Arc::downgrade(&as_fire), 0, Duration::from_millis(2));
        let gone = Arc::new(Count(AtomicUsize::new(0), usize::MAX));
        let gone_fire: Arc<dyn Fire> = gone.clone();
        timers.every(Arc::downgrade(&gone_fire), 0, Duration::from_millis(1));
        drop(gone_fire);
        let weak_gone = Arc::downgrade(&gone);
        drop(gone);
        assert!(weak_gone.upgrade().is_none());
        let deadline = Instant::now() + Duration::from_secs(10);
        while three.0.load(Ordering::SeqCst) < 3 {
            assert!(
                Instant::now() < deadline,
                "the timer never fired three times"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
        // It said stop on the third firing: forty more periods bring no fourth.
        std::thread::sleep(Duration::from_millis(80));
        assert_eq!(three.0.load(Ordering::SeqCst), 3);
    }
}
