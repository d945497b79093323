//! The synchronisation policies on crafted streams (contract `groups.md`): late, missing,
//! out-of-order and bursty samples give exactly the states and unknowns the contract says.

use dyknow_group::{Policy, SyncState, Synchroniser};

fn st(t: u64, values: &[Option<i32>]) -> SyncState<i32> {
    SyncState {
        t,
        values: values.to_vec(),
    }
}

fn wait(p: u64, d: u64) -> Policy {
    Policy::Wait {
        period_ms: p,
        max_delay_ms: d,
    }
}

#[test]
fn wait_emits_a_state_once_every_stream_has_a_sample_valid_at_its_time() {
    let mut s = Synchroniser::new(wait(100, 50), 2);
    s.start(1_000); // the first state is at 1100
    assert!(
        s.offer(0, 1_050, 1, 1_060).is_empty(),
        "1050 is valid at 1100, stream 1 missing"
    );
    assert!(s.offer(0, 1_090, 2, 1_095).is_empty());
    // Not before the wall clock reaches the state's time.
    assert!(s.offer(1, 1_099, 7, 1_099).is_empty());
    assert_eq!(
        s.poll(1_100),
        vec![st(1_100, &[Some(2), Some(7)])],
        "the latest valid sample is used"
    );
    assert_eq!(s.last_t(), Some(1_100));
}

#[test]
fn wait_gives_up_after_the_maximum_delay_and_the_missing_stream_is_unknown() {
    let mut s = Synchroniser::new(wait(100, 50), 2);
    s.start(1_000);
    assert!(s.offer(0, 1_100, 1, 1_110).is_empty());
    assert!(s.poll(1_149).is_empty(), "stream 1 still has time");
    assert_eq!(s.poll(1_150), vec![st(1_100, &[Some(1), None])]);
    assert_eq!(s.stats(1).missing_states, 1);
    assert_eq!(s.stats(0).missing_states, 0);
    // A sample older than the period is not valid at the next state.
    assert_eq!(s.next_deadline(), Some(1_250));
    assert_eq!(
        s.poll(1_250),
        vec![st(1_200, &[None, None])],
        "nothing valid in (1100, 1200]"
    );
}

#[test]
fn a_sample_after_its_state_was_emitted_is_late_counted_and_dropped() {
    let mut s = Synchroniser::new(wait(100, 0), 1);
    s.start(1_000);
    assert_eq!(s.offer(0, 1_100, 1, 1_100), vec![st(1_100, &[Some(1)])]);
    assert!(
        s.offer(0, 1_080, 9, 1_120).is_empty(),
        "out of order, its state is gone"
    );
    assert!(
        s.offer(0, 1_100, 9, 1_120).is_empty(),
        "the same time again"
    );
    assert_eq!(s.stats(0).late, 2);
    assert_eq!(s.stats(0).samples, 3);
    assert_eq!(s.offer(0, 1_200, 3, 1_200), vec![st(1_200, &[Some(3)])]);
}

#[test]
fn out_of_order_samples_before_their_state_still_count_and_the_latest_wins() {
    let mut s = Synchroniser::new(wait(100, 1_000), 1);
    s.start(1_000);
    assert!(s.offer(0, 1_090, 2, 1_095).is_empty()); // not yet 1100 on the wall clock
    assert!(
        s.offer(0, 1_020, 1, 1_096).is_empty(),
        "older, arrives later"
    );
    assert_eq!(s.poll(1_100), vec![st(1_100, &[Some(2)])]);
    assert_eq!(s.stats(0).late, 0);
}

#[test]
fn a_burst_after_a_gap_emits_the_missed_states_in_order_with_unknowns() {
    let mut s = Synchroniser::new(wait(100, 100), 1);
    s.start(1_000);
    // Nothing until 1450 on the wall clock: states 1100..1300 are due (deadline t + 100).
    let due = s.poll(1_450);
    assert_eq!(
        due,
        vec![st(1_100, &[None]), st(1_200, &[None]), st(1_300, &[None])]
    );
    // A burst: samples for 1330..1390 and 1420 arrive at once.
    let mut got = Vec::new();
    for (t, v) in [(1_330, 1), (1_360, 2), (1_390, 3), (1_420, 4)] {
        got.extend(s.offer(0, t, v, 1_460));
    }
    // The first sample valid at 1400 completes its state (the wall clock is past 1400); the
    // two that follow in the same window come after it was emitted: late.
    assert_eq!(got, vec![st(1_400, &[Some(1)])]);
    assert_eq!(s.stats(0).late, 2);
    assert_eq!(s.stats(0).missing_states, 3);
    assert_eq!(
        s.poll(1_500),
        vec![st(1_500, &[Some(4)])],
        "1420 waited for its state"
    );
    let ts: Vec<u64> = got.iter().map(|s| s.t).collect();
    assert!(ts.windows(2).all(|w| w[0] < w[1]));
}

#[test]
fn hold_keeps_a_value_while_it_is_younger_than_the_maximum_age() {
    let mut s = Synchroniser::new(
        Policy::Hold {
            period_ms: 100,
            max_age_ms: 250,
            max_delay_ms: Some(0),
        },
        2,
    );
    s.start(1_000);
    assert!(s.offer(0, 1_050, 5, 1_060).is_empty());
    assert_eq!(s.poll(1_100), vec![st(1_100, &[Some(5), None])]);
    assert_eq!(s.poll(1_200), vec![st(1_200, &[Some(5), None])]);
    assert_eq!(
        s.poll(1_300),
        vec![st(1_300, &[None, None])],
        "1300 - 1050 = 250 is not younger than 250"
    );
    assert_eq!(s.stats(1).missing_states, 3);
}

#[test]
fn hold_emits_early_once_every_stream_has_passed_the_state() {
    let mut s = Synchroniser::new(
        Policy::Hold {
            period_ms: 100,
            max_age_ms: 1_000,
            max_delay_ms: None,
        },
        1,
    );
    s.start(1_000);
    assert!(s.offer(0, 1_080, 1, 1_090).is_empty());
    assert!(
        s.poll(1_150).is_empty(),
        "the stream may still send a sample at or before 1100"
    );
    assert_eq!(s.offer(0, 1_130, 2, 1_160), vec![st(1_100, &[Some(1)])]);
}

#[test]
fn a_fresh_hold_start_begins_with_the_first_sample_not_an_unknown_state() {
    let mut s = Synchroniser::new(
        Policy::Hold {
            period_ms: 100,
            max_age_ms: 1_000,
            max_delay_ms: None,
        },
        1,
    );
    // Started at 1000; the first sample comes at 1130 (a new subscription, a slow stream):
    // the first state is 1200, holding it, not an unknown state at 1100.
    s.start(1_000);
    assert_eq!(
        s.next_deadline(),
        Some(2_000),
        "waits max(A, D) for a sample"
    );
    assert!(s.offer(0, 1_130, 1, 1_140).is_empty());
    assert_eq!(s.next_deadline(), Some(1_300));
    assert_eq!(s.poll(1_300), vec![st(1_200, &[Some(1)])]);
    assert_eq!(s.stats(0).missing_states, 0);
    // A resumed group goes on after its trace, without waiting.
    let mut r = Synchroniser::<i32>::new(
        Policy::Hold {
            period_ms: 100,
            max_age_ms: 1_000,
            max_delay_ms: None,
        },
        1,
    );
    r.resume_after(Some(5_000));
    r.start(5_050);
    assert_eq!(r.next_deadline(), Some(5_200));
}

#[test]
fn a_fresh_hold_start_without_samples_begins_unknown_after_the_maximum_age() {
    let mut s = Synchroniser::<i32>::new(
        Policy::Hold {
            period_ms: 100,
            max_age_ms: 250,
            max_delay_ms: None,
        },
        1,
    );
    s.start(1_000);
    assert!(s.poll(1_249).is_empty());
    assert_eq!(s.poll(1_250), vec![st(1_100, &[None])]);
    assert_eq!(s.poll(1_300), vec![st(1_200, &[None])]);
    assert_eq!(s.stats(0).missing_states, 2);
}

#[test]
fn event_makes_a_state_at_every_sample_time_with_the_latest_of_every_stream() {
    let mut s = Synchroniser::new(
        Policy::Event {
            max_delay_ms: Some(5),
        },
        2,
    );
    s.start(0);
    assert!(
        s.offer(0, 10, 1, 10).is_empty(),
        "stream 1 may still sample at 10"
    );
    assert_eq!(
        s.offer(1, 10, 7, 11),
        vec![st(10, &[Some(1), Some(7)])],
        "one state for both"
    );
    assert!(s.offer(0, 15, 2, 15).is_empty());
    assert_eq!(s.next_deadline(), Some(20));
    assert!(s.poll(19).is_empty());
    assert_eq!(
        s.poll(20),
        vec![st(15, &[Some(2), Some(7)])],
        "stream 1 held"
    );
    assert!(
        s.offer(1, 15, 8, 21).is_empty(),
        "the same time as the last state: late"
    );
    assert!(s.offer(1, 11, 8, 21).is_empty(), "out of order: late");
    assert_eq!(s.stats(1).late, 2);
    // A burst, out of order across streams: states in time order.
    assert!(s.offer(1, 30, 9, 30).is_empty());
    assert_eq!(s.offer(0, 25, 3, 31), vec![st(25, &[Some(3), Some(7)])]);
    assert_eq!(s.poll(35), vec![st(30, &[Some(3), Some(9)])]);
    assert_eq!(s.stats(1).missing_states, 0);
}

#[test]
fn event_emits_no_state_before_its_time_and_a_sample_from_the_future_stops_nothing() {
    // One stream, as a group over one symbol: a sample stamped ten years ahead (a robot whose
    // clock runs fast) was a state at once; every later sample was late and no state came
    // again.
    let mut s = Synchroniser::new(Policy::Event { max_delay_ms: None }, 1);
    s.start(1_000);
    assert_eq!(s.offer(0, 1_000, 1, 1_000), vec![st(1_000, &[Some(1)])]);
    let ahead = 1_000 + 315_360_000_000;
    assert!(
        s.offer(0, ahead, 0, 1_005).is_empty(),
        "not before its time"
    );
    assert_eq!(s.offer(0, 1_100, 2, 1_100), vec![st(1_100, &[Some(2)])]);
    assert_eq!(s.offer(0, 1_200, 3, 1_200), vec![st(1_200, &[Some(3)])]);
    assert_eq!(s.stats(0).late, 0);
    assert!(s.poll(ahead - 1).is_empty());
    assert_eq!(s.poll(ahead), vec![st(ahead, &[Some(0)])], "at its time");
    // Two streams: a state whose samples are all in is still not emitted early.
    let mut s = Synchroniser::new(Policy::Event { max_delay_ms: None }, 2);
    s.start(0);
    assert!(s.offer(0, 500, 1, 100).is_empty());
    assert!(s.offer(1, 500, 2, 101).is_empty());
    assert_eq!(s.poll(500), vec![st(500, &[Some(1), Some(2)])]);
}

#[test]
fn event_counts_a_stream_without_a_value_yet_as_missing() {
    let mut s = Synchroniser::new(Policy::Event { max_delay_ms: None }, 2);
    s.start(0);
    assert!(s.offer(0, 10, 1, 10).is_empty());
    assert_eq!(
        s.poll(12),
        vec![st(10, &[Some(1), None])],
        "the default delay is 2 ms"
    );
    assert_eq!(s.stats(1).missing_states, 1);
}

#[test]
fn samples_before_the_start_and_of_removed_streams_are_not_used() {
    let mut s = Synchroniser::new(Policy::Event { max_delay_ms: None }, 2);
    assert!(s.offer(0, 10, 1, 10).is_empty());
    s.start(0);
    s.remove_stream(1);
    assert!(s.offer(1, 20, 1, 20).is_empty());
    assert_eq!(
        s.offer(0, 30, 3, 30),
        vec![st(30, &[Some(3), None])],
        "a removed stream is not waited for"
    );
    assert_eq!(
        s.stats(1).missing_states,
        0,
        "a removed stream is not missing"
    );
}

#[test]
fn a_resumed_synchroniser_goes_on_after_the_recorded_states() {
    let mut s = Synchroniser::<i32>::new(wait(100, 0), 1);
    s.resume_after(Some(5_000));
    s.start(1_000);
    assert!(
        s.offer(0, 4_900, 1, 5_010).is_empty(),
        "before the recorded states: late"
    );
    assert_eq!(s.offer(0, 5_100, 2, 5_100), vec![st(5_100, &[Some(2)])]);
}

/// A group resumed after time down goes on with the grid after its last state: the states of
/// that time are due at once, without samples (unknown), so a window that fell in it has
/// states in it; at most `MAX_CATCH_UP` of them (beyond, the time is skipped).
#[test]
fn a_resumed_synchroniser_makes_up_the_states_of_its_time_down() {
    use dyknow_group::sync::{MAX_CATCH_UP, MAX_STATES_PER_POLL};
    for policy in [
        wait(100, 0),
        Policy::Hold {
            period_ms: 100,
            max_age_ms: 1_000,
            max_delay_ms: Some(0),
        },
    ] {
        let mut s = Synchroniser::<i32>::new(policy, 1);
        s.resume_after(Some(5_000));
        s.start(8_050);
        let states = s.poll(8_050);
        let times: Vec<u64> = states.iter().map(|s| s.t).collect();
        assert_eq!(
            times,
            (51..=80).map(|k| k * 100).collect::<Vec<_>>(),
            "{policy:?}"
        );
        assert!(states.iter().all(|s| s.values == [None]), "{states:?}");
        assert_eq!(s.stats(0).missing_states, 30, "{policy:?}");
        // A sample now is on time for the next state.
        assert_eq!(s.offer(0, 8_100, 7, 8_100), vec![st(8_100, &[Some(7)])]);
    }
    let mut s = Synchroniser::<i32>::new(wait(100, 0), 1);
    s.resume_after(Some(0));
    let now = (MAX_CATCH_UP + 1_000) * 100;
    s.start(now);
    // A poll returns at most MAX_STATES_PER_POLL of them; the next ones follow.
    let mut states = Vec::new();
    loop {
        let batch = s.poll(now);
        assert!(batch.len() <= MAX_STATES_PER_POLL);
        if batch.is_empty() {
            break;
        }
        states.extend(batch);
    }
    assert_eq!(states.len() as u64, MAX_CATCH_UP);
    assert_eq!(states[0].t, 1_000 * 100 + 100);
    assert!(states.windows(2).all(|w| w[1].t == w[0].t + 100));
}

#[test]
fn policies_are_validated() {
    assert!(wait(0, 1).validate().is_err());
    assert!(wait(100, 100).validate().is_ok());
    let p: Policy =
        serde_json::from_str(r#"{"policy": "hold", "period_ms": 100, "max_age_ms": 300}"#).unwrap();
    assert_eq!(
        p,
        Policy::Hold {
            period_ms: 100,
            max_age_ms: 300,
            max_delay_ms: None
        }
    );
    // A parameter left out takes its default (`wait`'s D is 5 P).
    assert_eq!(
        serde_json::from_str::<Policy>(r#"{"policy": "wait", "period_ms": 100}"#).unwrap(),
        wait(100, 500)
    );
    assert!(serde_json::from_str::<Policy>(r#"{"policy": "sometimes"}"#).is_err());
    assert_eq!(
        serde_json::from_str::<Policy>(r#"{"policy": "event"}"#).unwrap(),
        Policy::Event { max_delay_ms: None }
    );
}
