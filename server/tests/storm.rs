//! Crash storms (docs/reliability.md, guarantee 3): a fault injector crashes CUs at 100 per
//! second while ten pipelines run on a stand-alone executor. Reviews coalesce (far fewer
//! reviews than crashes), no crash is lost (the manager records every crash the executor
//! reported), and after the storm every target is satisfied again within one review. What the
//! manager holds is bounded and its live heap levels off once RocksDB's block caches are full,
//! but glibc's resident memory still creeps (the guarantee is partly met; the figures are
//! printed, and bounds on the manager's and the executor's growth guard against a leak). After
//! the storm every target channel must deliver again; a storm past ~65,500 crashes
//! (`DYKNOW_STORM_SECS=1200`) checks that restarted CUs no longer use up Zenoh's key numbers
//! (`dyknow_cu::pinned_key`). The storm lasts 5 s by default; `DYKNOW_STORM_SECS=60` runs the
//! full minute the issue asks for, and the test prints its figures either way.
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use dyknow_cu::protocol::Event;
use dyknow_cu::zenoh::Wait;
use dyknow_cu::{Namespace, Sample};
use serde_json::{Value, json};

mod support;

use support::*;

const PIPELINES: usize = 10;
const CRASHES_PER_SECOND: u64 = 100;

/// The service's resident memory, in kB.
fn rss_kb(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap()
}

/// The change sets recorded since a point, read incrementally with `?since=`.
struct Recorded {
    last: Option<String>,
    count: usize,
    failed_cus: std::collections::BTreeSet<String>,
}

impl Recorded {
    fn after(service: &Service) -> Self {
        let last = service
            .change_sets()
            .last()
            .and_then(|c| c["id"].as_str().map(str::to_owned));
        Self {
            last,
            count: 0,
            failed_cus: Default::default(),
        }
    }

    fn read(&mut self, service: &Service) {
        let path = match &self.last {
            Some(id) => format!("/changesets?since={id}"),
            None => "/changesets".to_owned(),
        };
        let new = service.get(&path);
        for c in new.as_array().unwrap() {
            self.count += 1;
            self.last = c["id"].as_str().map(str::to_owned);
            for f in c["failures"].as_array().cloned().unwrap_or_default() {
                if let Some(cu) = f["cu"].as_str() {
                    self.failed_cus.insert(cu.to_owned());
                }
            }
        }
    }
}

#[test]
fn a_crash_storm_is_coalesced_and_repaired_within_one_review() {
    let seconds: u64 = std::env::var("DYKNOW_STORM_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    // The on-disk store, as `dyknow serve` runs by default.
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("store");
    // `DYKNOW_STORM_HISTORY_LIMIT` sets `--history-limit` (default 1000): the history is the
    // one thing the manager holds that grows with a storm until it is full.
    let history_limit =
        std::env::var("DYKNOW_STORM_HISTORY_LIMIT").unwrap_or_else(|_| "1000".to_owned());
    let service = Service::start_with(
        &["--data", data.to_str().unwrap()],
        &format!("tcp/127.0.0.1:{}", free_port()),
        &["--no-executor", "--history-limit", &history_limit],
    );
    // A stand-alone executor: the memory of the manager and of the executor apart.
    let (executor, executor_tail) = executor_keeping(&service.zenoh, "storm", &[]);
    let pid = service.child.id();
    let executor_pid = executor.0.id();
    let tags: Vec<(String, String)> = (0..PIPELINES)
        .map(|i| (format!("Count{i}"), format!("Guarded{i}")))
        .collect();
    for (i, (count, guarded)) in tags.iter().enumerate() {
        let counter = format!("counter{i}");
        let guard = format!("guard{i}");
        for spec in [
            tf(
                &counter,
                "builtin",
                "dyknow/signal",
                &[("period_ms", "50")],
                &[],
                &[("out", count)],
            ),
            tf(
                &guard,
                "builtin",
                "dyknow/fault",
                &[],
                &[("in", count)],
                &[("out", guarded)],
            ),
        ] {
            service.post("/transformations", &spec.turtle());
        }
        service.post(
            "/targets",
            &target(&format!("storm-{i}"), &format!("/storm{i}"), guarded),
        );
    }
    let satisfied = |environment: &Value| {
        environment["unsatisfied_targets"]
            .as_array()
            .unwrap()
            .is_empty()
            && environment["valid"] == true
    };
    eventually("every target satisfied", Duration::from_secs(60), || {
        satisfied(&service.get("/environment")).then_some(())
    });
    // The guards' in channels (their counters never crash, so these stay).
    let channels: Vec<String> = (0..PIPELINES)
        .map(|i| {
            let guard = service.cu_of(&format!("guard{i}")).unwrap();
            guard["inputs"]["in"].as_str().unwrap().to_owned()
        })
        .collect();

    // The crashes the executor reports, counted where the manager hears them.
    let session = service.session();
    let reported = Arc::new(AtomicU64::new(0));
    let counted = reported.clone();
    let _events = session
        .declare_subscriber(Namespace::default().executor_events("storm"))
        .callback(move |sample| {
            if let Ok(Event::CuCrashed { .. }) =
                serde_json::from_slice::<Event>(&sample.payload().to_bytes())
            {
                counted.fetch_add(1, Ordering::SeqCst);
            }
        })
        .wait()
        .unwrap();
    let before = service.get("/environment");
    let crashes_before = before["crashes"].as_u64().unwrap();
    let reviews_before = before["reviews"].as_u64().unwrap();
    // The change sets recorded from here on, read as they come (`?since=`): the history keeps
    // the last 1,000 only (`--history-limit`), and a long storm records more.
    let mut recorded_sets = Recorded::after(&service);
    let publishers: Vec<_> = channels
        .iter()
        .map(|c| {
            session
                .declare_publisher(Namespace::default().channel(c).unwrap())
                .wait()
                .unwrap()
        })
        .collect();

    // The storm: one fault command every 10 ms, round robin over the guards.
    let start = Instant::now();
    let end = start + Duration::from_secs(seconds);
    let period = Duration::from_nanos(1_000_000_000 / CRASHES_PER_SECOND);
    let mut next = start;
    let mut injected = 0u64;
    let mut rss: Vec<(Duration, u64)> = vec![(Duration::ZERO, rss_kb(pid))];
    let mut executor_rss = vec![rss_kb(executor_pid)];
    let mut next_sample = start + Duration::from_secs(1);
    while Instant::now() < end {
        let i = (injected as usize) % PIPELINES;
        publishers[i]
            .put(Sample::now(json!({"fault": "panic"})).to_bytes())
            .wait()
            .unwrap();
        injected += 1;
        if Instant::now() >= next_sample {
            rss.push((start.elapsed(), rss_kb(pid)));
            executor_rss.push(rss_kb(executor_pid));
            recorded_sets.read(&service);
            next_sample += Duration::from_secs(1);
        }
        next += period;
        if let Some(wait) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    let storm = start.elapsed();

    // After the storm: every crash accounted for, every target satisfied again. A crash is
    // recorded as one (`crashes`), or, when the CU crashed while its change set was still
    // being applied, as that change set's failed action (the model drops the CU then, and the
    // crash report finds it gone).
    // The last fault commands may still be on their way when the storm ends, so a crash can be
    // reported after the manager has accounted for every earlier one: "the last crash" is the
    // last one reported before every target is satisfied, and the reviews are counted from
    // the moment the manager had accounted for it (a later report moves that moment).
    let mut accounted: Option<(u64, u64, bool)> = None;
    let (recorded, failed, crashed, reviews_at_end, in_flight, repaired) = eventually(
        "the manager to account for every reported crash and every target to be satisfied",
        Duration::from_secs(60),
        || {
            let crashed = reported.load(Ordering::SeqCst);
            let environment = service.get("/environment");
            let recorded = environment["crashes"].as_u64().unwrap() - crashes_before;
            recorded_sets.read(&service);
            let failed = recorded_sets.failed_cus.len() as u64;
            if recorded + failed < crashed {
                return None;
            }
            if accounted.is_none_or(|(seen, _, _)| seen != crashed) {
                accounted = Some((
                    crashed,
                    environment["reviews"].as_u64().unwrap(),
                    environment["phase"] == "review",
                ));
            }
            let (_, reviews_at_end, in_flight) = accounted.unwrap();
            satisfied(&environment).then_some((
                recorded,
                failed,
                crashed,
                reviews_at_end,
                in_flight,
                environment,
            ))
        },
    );
    let repaired_after = start.elapsed() - storm;
    let reviews_to_repair = repaired["reviews"].as_u64().unwrap() - reviews_at_end;
    let reviews = repaired["reviews"].as_u64().unwrap() - reviews_before;
    let rss_after = rss_kb(pid);
    let half = rss.len() / 2;
    let first_half = rss[..half.max(1)].iter().map(|r| r.1).max().unwrap();
    let second_half = rss[half..].iter().map(|r| r.1).max().unwrap();
    recorded_sets.read(&service);
    let history = recorded_sets.count;
    println!(
        "storm: {seconds} s, {injected} fault commands ({:.0}/s), {crashed} crashes reported, \
         {recorded} recorded as crashes and {failed} as failed actions; {reviews} reviews ({:.1} crashes per review); RSS max first half \
         {first_half} kB, second half {second_half} kB, after {rss_after} kB \
         (samples: {:?}; the executor's: {executor_rss:?}); satisfied again {} ms after the storm, {reviews_to_repair} review(s) \
         after the last crash was recorded; {history} change sets recorded",
        injected as f64 / storm.as_secs_f64(),
        crashed as f64 / reviews.max(1) as f64,
        rss.iter().map(|r| r.1).collect::<Vec<_>>(),
        repaired_after.as_millis(),
    );
    // The streams flow again: a sample on every target channel. When one does not, what the
    // manager, the data plane and the executor say about that pipeline.
    for i in 0..PIPELINES {
        let out = Listener::new(&session, &format!("/storm{i}"));
        if let Some((_, sample)) = out.within(Duration::from_secs(30)) {
            assert!(sample.value.is_number(), "{sample:?}");
            continue;
        }
        let fresh = service.session();
        let again = Listener::new(&fresh, &format!("/storm{i}"));
        let guard = service.cu_of(&format!("guard{i}"));
        let guard_in = guard
            .as_ref()
            .and_then(|g| g["inputs"]["in"].as_str().map(str::to_owned));
        let upstream = guard_in.as_deref().map(|c| Listener::new(&fresh, c));
        let on_target = again.within(Duration::from_secs(10)).is_some();
        let on_input = upstream.is_some_and(|u| u.within(Duration::from_secs(10)).is_some());
        panic!(
            "no sample on /storm{i} for 30 s after the storm; a fresh session's subscriber got \
             one: {on_target}; on the guard's input ({guard_in:?}): {on_input}; the guard: {guard:?}; \
             the counter: {:?}; the environment: {}; the executor's last lines: {:?}",
            service.cu_of(&format!("counter{i}")),
            service.get("/environment"),
            executor_tail.lock().unwrap(),
        );
    }
    assert!(crashed > 0, "the injector crashed nothing");
    assert!(
        recorded <= crashed && recorded + failed >= crashed,
        "crashes: {crashed} reported, {recorded} recorded, {failed} failed actions"
    );
    assert!(
        reviews < crashed,
        "{reviews} reviews for {crashed} crashes: reviews did not coalesce"
    );
    // "Within one review": the review that starts after the last crash; one already running
    // then (it began before that crash) may finish first.
    let allowed = 1 + u64::from(in_flight);
    assert!(
        reviews_to_repair <= allowed,
        "{reviews_to_repair} reviews after the last crash was recorded before every target was \
         satisfied (a review in flight then: {in_flight})"
    );
    // What grows in the manager over a storm is RocksDB's block caches filling up to the
    // size Oxigraph gives them (128 MB for the strings, 32 MB shared by the indexes) before
    // they level off (docs/reliability.md, guarantee 3: heap profiles from the start); what
    // DyKnow holds is bounded (history, terms, memtables). This bound guards against a leak
    // coming back, over a minute or more, per crash recorded: measured 41 kB per crash (60 s,
    // 2026-11-23), 25 kB (60 s) and 16 kB (240 s) with the tuned allocator. A short storm is
    // mostly warm-up: there, at most 1 MB per review.
    let manager_first = rss[0].1;
    let manager_last = rss.last().unwrap().1;
    let grown = manager_last.saturating_sub(manager_first);
    let (per, bound, unit) = if seconds >= 60 {
        (grown / recorded.max(1), 45, "crash recorded")
    } else {
        (grown / reviews.max(1), 1024, "review")
    };
    assert!(
        per <= bound,
        "the manager grew {per} kB per {unit} ({manager_first} → {manager_last} kB)"
    );
    // The executor holds nothing per crash: since CU keys share their non-wild prefix (`cu/*/`,
    // `Namespace::cu_token`), Zenoh keeps no mapping per CU ever started. It grew ~2.3 kB per
    // crash with a key of its own per CU (2026-11-24), ~0.1 kB since (180 s: 29.4 → 31.0 MB
    // for 17,532 crashes). Over a minute or more: at most 0.5 kB per crash, after warm-up.
    if seconds >= 60 {
        let warm = executor_rss[executor_rss.len().min(10) - 1];
        let grown = executor_rss.last().unwrap().saturating_sub(warm);
        assert!(
            grown * 1000 <= 500 * crashed,
            "the executor grew {grown} kB over {crashed} crashes ({warm} → {} kB)",
            executor_rss.last().unwrap()
        );
    }
}
