//! Zenoh 1.10 numbers a session's key-expression declarations with a `u16` that wraps without
//! regard to numbers still in use: after 65,535 declarations, a live publisher's mapping is
//! lost. A CU's channel keys are declared through `dyknow_cu::pinned_key`, so restarting CUs on
//! the same channels takes no new number (docs/reliability.md, guarantee 3).
#![expect(clippy::unwrap_used, reason = "test")]

use std::sync::mpsc;
use std::time::Duration;

use dyknow_cu::zenoh::{self, Wait};

fn router(listen: &str, connect: &[&str]) -> zenoh::Session {
    let connect: Vec<String> = connect.iter().map(|c| (*c).to_owned()).collect();
    let config = dyknow_cu::router_config(&[listen.to_owned()], &connect).unwrap();
    zenoh::open(config).wait().unwrap()
}

#[path = "support/port.rs"]
mod port;
use port::free_port;

/// A long-lived publisher on `a/live`, then `restarts` publishers declared and dropped in turn
/// on `a/restarted` (as a CU restarted on its channel), declared plainly or pinned; whether a
/// subscriber across a router link still receives the long-lived publisher's samples.
fn still_delivered(restarts: usize, pinned: bool) -> bool {
    let (p1, p2) = (free_port(), free_port());
    let manager = router(&format!("tcp/127.0.0.1:{p1}"), &[]);
    let executor = router(
        &format!("tcp/127.0.0.1:{p2}"),
        &[&format!("tcp/127.0.0.1:{p1}")],
    );
    let (tx, rx) = mpsc::channel();
    let _subscriber = manager
        .declare_subscriber("a/live")
        .callback(move |_| {
            let _ = tx.send(());
        })
        .wait()
        .unwrap();
    let live = executor.declare_publisher("a/live").wait().unwrap();
    // The link is up and the subscription known: a first sample arrives.
    let mut arrived = false;
    for _ in 0..100 {
        live.put("x").wait().unwrap();
        if rx.recv_timeout(Duration::from_millis(100)).is_ok() {
            arrived = true;
            break;
        }
    }
    assert!(arrived, "no sample before the restarts");
    for _ in 0..restarts {
        let key = zenoh::key_expr::KeyExpr::try_from("a/restarted").unwrap();
        let key = if pinned {
            dyknow_cu::pinned_key(&executor, key).unwrap()
        } else {
            key
        };
        drop(executor.declare_publisher(key).wait().unwrap());
    }
    while rx.try_recv().is_ok() {}
    for _ in 0..20 {
        live.put("x").wait().unwrap();
        if rx.recv_timeout(Duration::from_millis(100)).is_ok() {
            return true;
        }
    }
    false
}

#[test]
fn restarts_on_a_pinned_key_take_no_key_number() {
    assert!(still_delivered(70_000, true));
}

/// The reproduction of Zenoh's wrap-around: with plain declarations, the long-lived publisher's
/// samples are lost after 65,535 restarts. If a Zenoh upgrade fixes this, the test says so
/// (and the pins may go).
#[test]
fn plain_declarations_lose_a_live_mapping_after_65535() {
    assert!(still_delivered(1_000, false));
    assert!(!still_delivered(70_000, false));
}
