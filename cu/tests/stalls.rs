//! A CU whose callback stalls holds up only itself: not Zenoh's receiving thread (whose stall
//! past the lease took the executor's link and every CU on it down), not a CU publishing to
//! it, not a thread putting to it while it is busy, not the timer thread, and not the other
//! CUs' timers. Samples keep their order, and a busy CU keeps at most `INBOX_CAPACITY`
//! waiting, the newest.

#![expect(clippy::unwrap_used, reason = "a test")]

use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dyknow_cu::zenoh::{self, Wait};
use dyknow_cu::{
    CuError, INBOX_CAPACITY, Namespace, NodeHandle, Sample, Timers, Transformation, Unit, UnitSpec,
};

/// Records every `t` it is given; with `release`, blocks in its first callback until the test
/// says so.
struct Stalls {
    release: Option<Receiver<()>>,
    stalled: Sender<()>,
    seen: Arc<Mutex<Vec<i64>>>,
}

impl Transformation for Stalls {
    fn on_sample(
        &mut self,
        _: &mut NodeHandle<'_>,
        _: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        self.seen.lock().unwrap().push(sample.t);
        if let Some(release) = self.release.take() {
            let _ = self.stalled.send(());
            let _ = release.recv();
        }
        Ok(())
    }
}

/// Publishes a counter on `out` every 5 ms.
struct Ticks(i64);

impl Transformation for Ticks {
    fn start(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        cu.every(Duration::from_millis(5));
        Ok(())
    }

    fn on_sample(&mut self, _: &mut NodeHandle<'_>, _: &str, _: Sample) -> Result<(), CuError> {
        Ok(())
    }

    fn on_timer(&mut self, cu: &mut NodeHandle<'_>, _: usize) -> Result<(), CuError> {
        self.0 += 1;
        cu.publish("out", self.0, self.0)
    }
}

#[path = "support/port.rs"]
mod port;

/// Two routers linked over loopback TCP: the CUs' (an executor's) and a remote one whose
/// samples Zenoh's receiving threads deliver.
fn sessions() -> (zenoh::Session, zenoh::Session) {
    let port = port::free_port();
    let listen = format!("tcp/127.0.0.1:{port}");
    let local = zenoh::open(dyknow_cu::router_config(std::slice::from_ref(&listen), &[]).unwrap())
        .wait()
        .unwrap();
    let remote = zenoh::open(
        dyknow_cu::router_config(&[format!("tcp/127.0.0.1:{}", port::free_port())], &[listen])
            .unwrap(),
    )
    .wait()
    .unwrap();
    (local, remote)
}

/// Puts `t` on `channel` from `session`.
fn put(session: &zenoh::Session, channel: &str, t: i64) {
    let key = Namespace::default().channel(channel).unwrap();
    session
        .put(&key, Sample::new(t, t).to_bytes())
        .wait()
        .unwrap();
}

/// Puts on `channel` from the remote session until the CU recording into `seen` has a sample
/// (the link is up and the subscription known there); then forgets it.
fn linked(remote: &zenoh::Session, channel: &str, seen: &Arc<Mutex<Vec<i64>>>) {
    until("the remote session reaches the CU", || {
        put(remote, channel, -1);
        std::thread::sleep(Duration::from_millis(20));
        !seen.lock().unwrap().is_empty()
    });
    std::thread::sleep(Duration::from_millis(50));
    seen.lock().unwrap().clear();
}

/// A [`Stalls`] CU reading `channel`: the CU, the receiver told when it stalls, and the `t`s it
/// took.
fn stalls(
    session: &zenoh::Session,
    timers: &Timers,
    name: &str,
    channel: &str,
    release: Option<Receiver<()>>,
) -> (Unit, Receiver<()>, Arc<Mutex<Vec<i64>>>) {
    let (stalled_tx, stalled) = mpsc::channel();
    let seen = Arc::new(Mutex::new(Vec::new()));
    let transformation = Stalls {
        release,
        stalled: stalled_tx,
        seen: seen.clone(),
    };
    let unit = start(session, timers, name, transformation, Some(channel), None);
    (unit, stalled, seen)
}

/// A CU recording what it takes on `channel`, which the remote session reaches.
fn recording(
    session: &zenoh::Session,
    remote: &zenoh::Session,
    timers: &Timers,
    name: &str,
    channel: &str,
) -> (Unit, Arc<Mutex<Vec<i64>>>) {
    let (unit, _, seen) = stalls(session, timers, name, channel, None);
    linked(remote, channel, &seen);
    (unit, seen)
}

fn start(
    session: &zenoh::Session,
    timers: &Timers,
    name: &str,
    transformation: impl Transformation,
    input: Option<&str>,
    output: Option<&str>,
) -> Unit {
    let unit = Unit::start(
        session,
        &Namespace::default(),
        UnitSpec {
            name: name.into(),
            transformation: name.into(),
            inputs: input.iter().map(|_| "in".to_owned()).collect(),
            outputs: output.iter().map(|_| "out".to_owned()).collect(),
            params: Default::default(),
        },
        Box::new(transformation),
        timers,
        Box::new(|_| {}),
    )
    .unwrap()
    .unit;
    if let Some(channel) = input {
        unit.bind_in("in", Some(channel)).unwrap();
    }
    if let Some(channel) = output {
        unit.bind_out("out", Some(channel)).unwrap();
    }
    unit
}

/// Puts `t` on `channel` from a thread of its own; whether the put returned within 5 s.
fn put_returns(session: &zenoh::Session, channel: &str, t: i64) -> bool {
    let key = Namespace::default().channel(channel).unwrap();
    let session = session.clone();
    let (done, returned) = mpsc::channel();
    std::thread::spawn(move || {
        session
            .put(&key, Sample::new(t, t).to_bytes())
            .wait()
            .unwrap();
        let _ = done.send(());
    });
    returned.recv_timeout(Duration::from_secs(5)).is_ok()
}

/// The messages `unit` published so far on its out port.
fn published(unit: &Unit) -> u64 {
    unit.statistics().ports["out"].messages
}

/// Waits (polling, 10 s at most) until `done` holds.
fn until(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while !done() {
        assert!(Instant::now() < deadline, "{what} within 10 s");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A CU on channel `c` of `session` stalled in its first callback by a sample `t0` from
/// `remote`: the CU, the sender that releases it, and the `t`s it took.
fn stalled_cu(
    session: &zenoh::Session,
    remote: &zenoh::Session,
    timers: &Timers,
    name: &str,
    t0: i64,
) -> (Unit, Sender<()>, Arc<Mutex<Vec<i64>>>) {
    let (release_tx, release) = mpsc::channel();
    let (unit, stalled, seen) = stalls(session, timers, name, "c", Some(release));
    until("the stalling sample is taken", || {
        put(remote, "c", t0);
        stalled.recv_timeout(Duration::from_millis(50)).is_ok()
    });
    (unit, release_tx, seen)
}

#[test]
fn a_stalled_cu_holds_up_nothing_but_itself() {
    let (session, remote) = sessions();
    let timers = Timers::start();
    let (echo, echoed) = recording(&session, &remote, &timers, "echo", "e");
    // Stalled by a sample from the other process: Zenoh's receiving thread goes on, and the
    // samples after it on the same link reach the other CU.
    let (stall, release_tx, seen) = stalled_cu(&session, &remote, &timers, "stall", 1);
    for t in 1..=20 {
        put(&remote, "e", t);
    }
    until("the 20 samples after the stalling one arrive", || {
        echoed.lock().unwrap().len() == 20
    });
    // A CU publishing into the stalled one, and another on the same timers: both keep
    // ticking (the publisher's put finds the receiver busy and leaves the sample in its
    // inbox instead of waiting on the timer thread, which would stop every timer).
    let feeder = start(&session, &timers, "feeder", Ticks(1), None, Some("c"));
    let other = start(&session, &timers, "other", Ticks(0), None, Some("d"));
    until("the feeder and the other CU tick 50 times", || {
        published(&feeder) >= 50 && published(&other) >= 50
    });
    // A thread of this process putting to the busy CU does not wait either.
    assert!(
        put_returns(&session, "c", 1_000_000),
        "the put waited for the stalled callback"
    );
    feeder.stop();
    let fed = published(&feeder);
    let taken = seen.lock().unwrap().clone();
    assert!(
        taken.iter().all(|t| *t == 1),
        "only the stalling sample was taken: {taken:?}"
    );
    // Released, it takes what waited, in order.
    release_tx.send(()).unwrap();
    until("the waiting samples are taken", || {
        seen.lock().unwrap().last() == Some(&1_000_000)
    });
    let seen = seen.lock().unwrap().clone();
    assert!(seen.is_sorted(), "out of order: {seen:?}");
    let stalling = taken.len() as u64;
    assert_eq!(
        seen.len() as u64,
        stalling + (fed + 1).min(INBOX_CAPACITY as u64),
        "{seen:?}"
    );
    for unit in [stall, other, echo] {
        unit.stop();
    }
}

#[test]
fn a_busy_cu_keeps_the_newest_samples_in_their_order() {
    let (session, remote) = sessions();
    let timers = Timers::start();
    let (stall, release_tx, seen) = stalled_cu(&session, &remote, &timers, "busy", 0);
    let sent = 3 * INBOX_CAPACITY as i64;
    for t in 1..=sent {
        put(&session, "c", t);
    }
    release_tx.send(()).unwrap();
    until("the newest sample is taken", || {
        seen.lock().unwrap().last() == Some(&sent)
    });
    let seen = seen.lock().unwrap().clone();
    let newest: Vec<i64> = (sent + 1 - INBOX_CAPACITY as i64..=sent).collect();
    let first = seen.iter().position(|t| *t > 0).unwrap();
    assert!(seen[..first].iter().all(|t| *t == 0), "{seen:?}");
    assert_eq!(
        seen[first..],
        newest[..],
        "the newest {INBOX_CAPACITY}, in order"
    );
    stall.stop();
}

#[test]
fn samples_from_another_process_keep_their_order() {
    let (session, remote) = sessions();
    let timers = Timers::start();
    let (unit, seen) = recording(&session, &remote, &timers, "order", "c");
    for t in 1..=500 {
        put(&remote, "c", t);
    }
    until("500 samples are taken", || {
        seen.lock().unwrap().len() == 500
    });
    assert_eq!(*seen.lock().unwrap(), (1..=500).collect::<Vec<i64>>());
    unit.stop();
}

/// Stalls in its first callback until released, then publishes `t` = 42 on `out` and says so.
struct StallsThenPublishes {
    release: Receiver<()>,
    stalled: Sender<()>,
    returned: Sender<()>,
}

impl Transformation for StallsThenPublishes {
    fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _: &str, _: Sample) -> Result<(), CuError> {
        let _ = self.stalled.send(());
        let _ = self.release.recv();
        let published = cu.publish("out", 42, 42);
        let _ = self.returned.send(());
        published
    }
}

/// Stopping a CU whose callback is stalled returns at once (a user audit saw an executor's
/// every later change set time out, and its shutdown take minutes, behind one builtin CU stalled
/// in a callback: the stop waited for it); its statistics and bindings answer meanwhile; and
/// what the callback publishes once it returns does not go out.
#[test]
fn a_stalled_cu_stops_without_waiting_and_publishes_nothing_after() {
    let (session, remote) = sessions();
    let timers = Timers::start();
    let (watch, watched) = recording(&session, &remote, &timers, "watch", "o");
    let (release_tx, release) = mpsc::channel();
    let (stalled_tx, stalled) = mpsc::channel();
    let (returned_tx, returned) = mpsc::channel();
    let unit = start(
        &session,
        &timers,
        "stuck",
        StallsThenPublishes {
            release,
            stalled: stalled_tx,
            returned: returned_tx,
        },
        Some("c"),
        Some("o"),
    );
    until("the stalling sample is taken", || {
        put(&remote, "c", 1);
        stalled.recv_timeout(Duration::from_millis(50)).is_ok()
    });
    let asked = Instant::now();
    let statistics = unit.statistics();
    assert!(
        asked.elapsed() < Duration::from_secs(1),
        "statistics waited"
    );
    assert!(statistics.ports.is_empty(), "{statistics:?}");
    assert_eq!(unit.bindings().1["out"].as_deref(), Some("o"));
    let stopping = Instant::now();
    unit.stop();
    assert!(
        stopping.elapsed() < Duration::from_secs(1),
        "stop waited {:?} for the stalled callback",
        stopping.elapsed()
    );
    assert_eq!(unit.bindings().1["out"], None);
    release_tx.send(()).unwrap();
    returned
        .recv_timeout(Duration::from_secs(10))
        .expect("the callback returns once released");
    // A marker put on the same channel after the callback returned arrives; the callback's
    // sample, had it gone out, would be there too.
    until("the marker arrives", || {
        put(&session, "o", 7);
        std::thread::sleep(Duration::from_millis(20));
        watched.lock().unwrap().contains(&7)
    });
    assert!(
        !watched.lock().unwrap().contains(&42),
        "the stopped CU published: {:?}",
        watched.lock().unwrap()
    );
    watch.stop();
}
