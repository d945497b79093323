//! The timer threads of a host: one thread keeps every CU's timers in a queue and fires the
//! quick ones itself; a timer whose last firing took longer than [`Timers::INLINE_BELOW`]
//! (or that never fired yet) goes to a small pool of workers. So idle CUs cost no thread and
//! no CPU, a quick timer costs no hand-off between threads, and one CU's slow callback (a
//! camera rendering its frame) does not hold up the others' timers.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex, PoisonError, Weak};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

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
    /// How long its last firing took; `None` before the first.
    took: Option<Duration>,
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

type Shared = Arc<(Mutex<Queue>, Condvar)>;

/// The timer threads of a host. Dropping the last handle stops them.
#[derive(Clone)]
pub struct Timers {
    shared: Shared,
    _stop: Arc<Stop>,
}

impl std::fmt::Debug for Timers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Timers").finish_non_exhaustive()
    }
}

struct Stop(Shared);

impl Drop for Stop {
    fn drop(&mut self) {
        let (queue, signal) = &*self.0;
        queue.lock().unwrap_or_else(PoisonError::into_inner).stopped = true;
        signal.notify_all();
    }
}

impl Timers {
    /// How many workers [`Timers::start`] gives a host: as many callbacks as this can be slow
    /// at once before the others' timers wait.
    pub const WORKERS: usize = 4;

    /// A timer whose last firing took less than this fires on the queue's thread; a slower
    /// one, on a worker.
    pub const INLINE_BELOW: Duration = Duration::from_micros(500);

    /// Starts the queue's thread and [`Timers::WORKERS`] workers.
    pub fn start() -> Self {
        Self::with_workers(Self::WORKERS)
    }

    /// Starts the queue's thread and `workers` workers. With none, the queue's thread fires
    /// every timer itself, one after another (enough for a process that hosts one CU: its
    /// callbacks run one at a time anyway).
    pub fn with_workers(workers: usize) -> Self {
        let shared: Shared = Arc::default();
        let (to_workers, from_queue) = mpsc::channel::<Entry>();
        let from_queue = Arc::new(Mutex::new(from_queue));
        let mut started = 0;
        for i in 0..workers {
            let (shared, from_queue) = (shared.clone(), from_queue.clone());
            match std::thread::Builder::new()
                .name(format!("dyknow-timer-{i}"))
                .spawn(move || work(&shared, &from_queue))
            {
                Ok(_) => started += 1,
                Err(e) => tracing::error!("cannot start a timer worker: {e}"),
            }
        }
        // Without a worker (none asked for, or none could start) the queue fires them itself.
        let to_workers = (started > 0).then_some(to_workers);
        let worker = shared.clone();
        let spawned = std::thread::Builder::new()
            .name("dyknow-timers".into())
            .spawn(move || run(&worker, to_workers.as_ref()));
        if let Err(e) = spawned {
            tracing::error!("cannot start the timer thread: {e}");
        }
        Self {
            _stop: Arc::new(Stop(shared.clone())),
            shared,
        }
    }

    /// Fires `timer` of `target` every `period` while `target` lives and wants it, on the
    /// wall clock's grid: at the multiples of `period` since the Unix epoch, the first within
    /// one period. So the timers of one period tick together, on every host whose clock
    /// agrees, and a source that stamps its samples with its clock's ticks publishes each at
    /// its time rather than up to half a period before or after it. One timer never fires twice
    /// at once: it is out of the queue while it fires.
    pub fn every(&self, target: Weak<dyn Fire>, timer: usize, period: Duration) {
        let since_epoch = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or_default();
        let due = first_due(Instant::now(), since_epoch, period);
        let (queue, signal) = &*self.shared;
        let mut queue = queue.lock().unwrap_or_else(PoisonError::into_inner);
        queue.seq += 1;
        let seq = queue.seq;
        queue.heap.push(Reverse(Entry {
            due,
            seq,
            period,
            timer,
            target,
            took: None,
        }));
        signal.notify_one();
    }
}

/// When a timer of `period` armed at `now` (`since_epoch` on the wall clock) first fires: at
/// the next multiple of `period` since the epoch, now if `now` is one.
fn first_due(now: Instant, since_epoch: Duration, period: Duration) -> Instant {
    let period = period.as_nanos().max(1);
    let into = since_epoch.as_nanos() % period;
    now + nanos((period - into) % period)
}

/// The tick after `due`, a timer of `period` that fired at `due`, seen at `now`: one period
/// later (a fixed rate), or, if that has passed (the firing, or the wait for a worker, took
/// longer than a period), the first tick of the same grid from `now` on: the missed ticks are
/// skipped, not fired in a burst.
fn next_due(due: Instant, period: Duration, now: Instant) -> Instant {
    let next = due + period;
    if next >= now {
        return next;
    }
    let period = period.as_nanos().max(1);
    let behind = (now - next).as_nanos();
    next + nanos(behind.div_ceil(period) * period)
}

fn nanos(n: u128) -> Duration {
    Duration::from_nanos(u64::try_from(n).unwrap_or(u64::MAX))
}

/// The queue's thread: waits for the earliest timer, fires it if it was quick last time (or
/// there is no worker), else hands it to a worker.
fn run(shared: &(Mutex<Queue>, Condvar), workers: Option<&mpsc::Sender<Entry>>) {
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
                let Some(Reverse(entry)) = guard.heap.pop() else {
                    continue;
                };
                drop(guard);
                let quick = entry.took.is_some_and(|d| d < Timers::INLINE_BELOW);
                let unsent = match workers {
                    Some(workers) if !quick => workers.send(entry).err().map(|e| e.0),
                    _ => Some(entry),
                };
                if let Some(entry) = unsent {
                    fire(shared, entry);
                }
                guard = queue.lock().unwrap_or_else(PoisonError::into_inner);
            }
        }
    }
}

/// A worker: fires the timers the queue hands it until the queue's thread stops.
fn work(shared: &(Mutex<Queue>, Condvar), from_queue: &Mutex<mpsc::Receiver<Entry>>) {
    loop {
        let next = from_queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .recv();
        match next {
            Ok(entry) => fire(shared, entry),
            Err(_) => return,
        }
    }
}

/// Fires `entry` and, if its target wants it again, puts it back in the queue.
fn fire(shared: &(Mutex<Queue>, Condvar), mut entry: Entry) {
    let clock = Instant::now();
    let again = entry.target.upgrade().is_some_and(|t| t.fire(entry.timer));
    if !again {
        return;
    }
    entry.took = Some(clock.elapsed());
    let (queue, signal) = shared;
    let mut guard = queue.lock().unwrap_or_else(PoisonError::into_inner);
    entry.due = next_due(entry.due, entry.period, Instant::now());
    guard.heap.push(Reverse(entry));
    // The queue's thread may be asleep until a later timer.
    signal.notify_one();
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

    /// Polls until `count` reaches `n`, for at most 10 s.
    fn wait_for(count: &AtomicUsize, n: usize, what: &str) {
        let deadline = Instant::now() + Duration::from_secs(10);
        while count.load(Ordering::SeqCst) < n {
            assert!(Instant::now() < deadline, "{what}");
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    fn timers_fire_until_their_target_says_stop_or_is_gone(timers: &Timers) {
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
        wait_for(&three.0, 3, "the timer never fired three times");
        // It said stop on the third firing: forty more periods bring no fourth.
        std::thread::sleep(Duration::from_millis(80));
        assert_eq!(three.0.load(Ordering::SeqCst), 3);
    }

    #[test]
    fn timers_fire_until_their_target_says_stop_or_is_gone_with_workers() {
        timers_fire_until_their_target_says_stop_or_is_gone(&Timers::start());
    }

    #[test]
    fn timers_fire_until_their_target_says_stop_or_is_gone_without_workers() {
        timers_fire_until_their_target_says_stop_or_is_gone(&Timers::with_workers(0));
    }

    /// Blocks in its first firing until the test releases it.
    struct Slow {
        entered: Mutex<mpsc::Sender<()>>,
        release: Mutex<mpsc::Receiver<()>>,
    }
    impl Fire for Slow {
        fn fire(&self, _timer: usize) -> bool {
            let _ = self.entered.lock().unwrap().send(());
            let _ = self.release.lock().unwrap().recv();
            false
        }
    }

    #[test]
    fn a_slow_callback_does_not_hold_up_the_other_timers() {
        let timers = Timers::start();
        let (entered, in_slow) = mpsc::channel();
        let (release, released) = mpsc::channel();
        let slow: Arc<dyn Fire> = Arc::new(Slow {
            entered: Mutex::new(entered),
            release: Mutex::new(released),
        });
        timers.every(Arc::downgrade(&slow), 0, Duration::from_millis(1));
        in_slow
            .recv_timeout(Duration::from_secs(10))
            .expect("the slow timer fired");
        // With one thread firing every timer, this one would wait until the slow one returns.
        let fast = Arc::new(Count(AtomicUsize::new(0), usize::MAX));
        let fast_fire: Arc<dyn Fire> = fast.clone();
        timers.every(Arc::downgrade(&fast_fire), 0, Duration::from_millis(1));
        wait_for(&fast.0, 3, "the other timer waited for the slow callback");
        release.send(()).unwrap();
    }

    /// Counts how many of its firings overlap.
    #[derive(Default)]
    struct Overlap {
        inside: AtomicUsize,
        most: AtomicUsize,
        fired: AtomicUsize,
    }
    impl Fire for Overlap {
        fn fire(&self, _timer: usize) -> bool {
            let inside = self.inside.fetch_add(1, Ordering::SeqCst) + 1;
            self.most.fetch_max(inside, Ordering::SeqCst);
            // Longer than the period: the next tick is due before this one returns.
            std::thread::sleep(Duration::from_millis(3));
            self.inside.fetch_sub(1, Ordering::SeqCst);
            self.fired.fetch_add(1, Ordering::SeqCst);
            true
        }
    }

    /// Fires `target` every millisecond, with workers, until `fired(target)` reaches `n`.
    fn fire_until<T: Fire + 'static>(target: &Arc<T>, fired: fn(&T) -> &AtomicUsize, n: usize) {
        let timers = Timers::start();
        let as_fire: Arc<dyn Fire> = target.clone();
        timers.every(Arc::downgrade(&as_fire), 0, Duration::from_millis(1));
        wait_for(fired(target), n, "the timer never fired often enough");
    }

    #[test]
    fn a_timer_never_fires_twice_at_once() {
        let overlap = Arc::new(Overlap::default());
        fire_until(&overlap, |o| &o.fired, 20);
        assert_eq!(overlap.most.load(Ordering::SeqCst), 1);
    }

    /// Records the name of the thread of each firing.
    #[derive(Default)]
    struct Where(Mutex<Vec<String>>, AtomicUsize);
    impl Fire for Where {
        fn fire(&self, _timer: usize) -> bool {
            let name = std::thread::current().name().unwrap_or("").to_owned();
            self.0.lock().unwrap().push(name);
            self.1.fetch_add(1, Ordering::SeqCst);
            true
        }
    }

    #[test]
    fn a_quick_timer_fires_on_the_queues_thread_after_its_first_firing() {
        let at = Arc::new(Where::default());
        fire_until(&at, |w| &w.1, 20);
        let names = at.0.lock().unwrap().clone();
        // Not known to be quick yet: a worker.
        assert!(names[0].starts_with("dyknow-timer-"), "{names:?}");
        // Then on the queue's thread, unless a firing was preempted for longer than
        // INLINE_BELOW (then the next goes to a worker again).
        assert!(names.iter().any(|n| n == "dyknow-timers"), "{names:?}");
    }

    #[test]
    fn a_timer_first_fires_on_the_wall_clocks_grid_of_its_period() {
        let now = Instant::now();
        let ms = Duration::from_millis;
        // 1,000,007 ms since the epoch, 20 ms period: the next multiple is 1,000,020.
        assert_eq!(first_due(now, ms(1_000_007), ms(20)), now + ms(13));
        // On a multiple: now.
        assert_eq!(first_due(now, ms(1_000_000), ms(20)), now);
        // Sub-millisecond remainders count.
        let at = ms(1_000_000) + Duration::from_micros(250);
        assert_eq!(
            first_due(now, at, ms(100)),
            now + ms(100) - Duration::from_micros(250)
        );
    }

    #[test]
    fn a_late_timer_keeps_its_rate_and_after_a_stall_skips_to_its_grid() {
        let start = Instant::now();
        let ms = Duration::from_millis;
        // On time, or late by less than a period: one period after the tick it was due at.
        assert_eq!(next_due(start, ms(20), start + ms(1)), start + ms(20));
        assert_eq!(next_due(start, ms(20), start + ms(19)), start + ms(20));
        assert_eq!(next_due(start, ms(20), start + ms(20)), start + ms(20));
        // Fired 47 ms late: the ticks at 20 and 40 are skipped; the next is at 60, on the grid.
        assert_eq!(next_due(start, ms(20), start + ms(47)), start + ms(60));
        // Exactly on a later tick: that tick.
        assert_eq!(next_due(start, ms(20), start + ms(80)), start + ms(80));
    }
}
