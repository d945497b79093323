//! The fleet's view of executors coming and going, on a real Zenoh session: a flapping
//! liveliness token (a link that cuts and heals, an executor restarted under its name) ends
//! with the view Zenoh last gave, whatever order the membership threads run in.
#![expect(
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use dyknow_cu::Namespace;
use dyknow_cu::protocol::{CuReport, CuState, CuStatistics, ExecutorInfo};
use dyknow_cu::zenoh::{self, Wait};
use dyknow_lifecycle::{Fleet, FleetEvent};
use tokio::sync::mpsc::UnboundedReceiver;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// The manager's router session and an executor's client session connected to it.
fn sessions() -> (zenoh::Session, zenoh::Session) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut router = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"router\"".to_owned()),
        ("listen/endpoints", format!("[\"{endpoint}\"]")),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("scouting/gossip/enabled", "false".to_owned()),
    ] {
        router.insert_json5(key, &value).expect("a router config");
    }
    let router = zenoh::open(router).wait().expect("a router");
    let client = dyknow_cu::client_config(&[endpoint]).expect("a client config");
    let client = zenoh::open(client).wait().expect("a client");
    (router, client)
}

/// Waits for the `Appeared` event of `executor` that answered under token generation
/// `generation` (see the test), and returns the events received until then.
fn until_appeared(
    events: &mut UnboundedReceiver<FleetEvent>,
    executor: &str,
    generation: usize,
) -> Vec<FleetEvent> {
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut seen = Vec::new();
    loop {
        match events.try_recv() {
            Ok(event) => {
                let done = matches!(
                    &event,
                    FleetEvent::Appeared { executor: e, cus } if e == executor && cus.len() == generation
                );
                seen.push(event);
                if done {
                    return seen;
                }
            }
            Err(_) => {
                assert!(
                    Instant::now() < deadline,
                    "no appearance of {executor} at generation {generation}: {seen:?}"
                );
                std::thread::sleep(Duration::from_millis(5));
            }
        }
    }
}

fn present(fleet: &Fleet, executor: &str) -> bool {
    fleet
        .executors(&BTreeMap::new())
        .iter()
        .any(|e| e.name == executor && e.present)
}

#[test]
fn a_flapping_token_ends_as_zenoh_last_said() {
    let (router, client) = sessions();
    let namespace = Namespace::new("flap").expect("a namespace");
    let (fleet, mut events) = Fleet::start(&router, namespace.clone()).expect("a fleet");
    // The executor answers `info` with as many CUs as the generation of its current token,
    // so that an answer tells which appearance it belongs to.
    let generation = Arc::new(AtomicU64::new(0));
    let answered = generation.clone();
    let _info = client
        .declare_queryable(namespace.executor_service("x", "info"))
        .callback(move |query| {
            let n = answered.load(Ordering::SeqCst);
            let info = ExecutorInfo {
                name: "x".into(),
                builtins: Vec::new(),
                processes: false,
                cus: (0..n)
                    .map(|i| CuReport {
                        cu: format!("cu{i}"),
                        transformation: "t".into(),
                        state: CuState::Running,
                        inputs: BTreeMap::new(),
                        outputs: BTreeMap::new(),
                        statistics: CuStatistics::default(),
                        reason: None,
                        pid: None,
                        generation: 0,
                    })
                    .collect(),
            };
            let _ = query
                .reply(
                    query.key_expr().clone(),
                    serde_json::to_vec(&info).expect("json"),
                )
                .wait();
        })
        .wait()
        .expect("a queryable");
    let token = namespace.executor_token("x");
    let declare = || {
        client
            .liveliness()
            .declare_token(token.clone())
            .wait()
            .expect("a token")
    };
    let first = declare();
    until_appeared(&mut events, "x", 0);
    assert!(present(&fleet, "x"));

    // Cut and heal, fast and often: each pair is one vanishing and one appearance, in that
    // order, for the fleet's liveliness subscriber.
    drop(first);
    for n in 1..=40 {
        generation.store(n, Ordering::SeqCst);
        let up = declare();
        if n % 3 == 0 {
            std::thread::yield_now();
        }
        drop(up);
    }
    generation.store(41, Ordering::SeqCst);
    let last = declare();
    let seen = until_appeared(&mut events, "x", 41);
    assert!(
        present(&fleet, "x"),
        "x's token is up, yet the fleet has it absent after {seen:?}"
    );
    assert!(fleet.wait_for("x", Duration::from_secs(1)));

    // And down for good: absent.
    drop(last);
    let deadline = Instant::now() + Duration::from_secs(30);
    while present(&fleet, "x") {
        assert!(Instant::now() < deadline, "x stays present without a token");
        std::thread::sleep(Duration::from_millis(5));
    }
}
