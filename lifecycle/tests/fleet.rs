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
use dyknow_cu::keys::InstanceId;
use dyknow_cu::protocol::{CuReport, CuState, CuStatistics, ExecutorInfo};
use dyknow_cu::zenoh::{self, Wait};
use dyknow_lifecycle::{Executor, Fleet, FleetEvent};
use tokio::sync::mpsc::UnboundedReceiver;

/// Answers a query with `value` as JSON, as an executor's services do.
fn reply_json(query: &zenoh::query::Query, value: &impl serde::Serialize) {
    let _ = query
        .reply(
            query.key_expr().clone(),
            serde_json::to_vec(value).expect("json"),
        )
        .wait();
}

#[path = "../../cu/tests/support/port.rs"]
mod port;
use port::free_port;

/// The manager's router session and an executor's client session connected to it.
fn sessions() -> (zenoh::Session, zenoh::Session) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router =
        dyknow_cu::router_config(std::slice::from_ref(&endpoint), &[]).expect("a router config");
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

/// Executor `x`'s `info`: `instance` (if it says), no builtins, `cus` running CUs.
fn info_of_x(instance: Option<InstanceId>, cus: u64) -> ExecutorInfo {
    ExecutorInfo {
        instance,
        name: "x".into(),
        builtins: Vec::new(),
        processes: false,
        cus: (0..cus)
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
            let info = info_of_x(None, n);
            reply_json(&query, &info);
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

/// A one-transformation spec of the builtin `dyknow/relay`.
fn relay_spec() -> dyknow_store::spec::TransformationSpec {
    dyknow_store::spec::TransformationSpec {
        label: "t".into(),
        iri: "urn:t".into(),
        inputs: Vec::new(),
        outputs: Vec::new(),
        labour: 1.0,
        upkeep: 1.0,
        exec_type: Some("builtin".into()),
        source: Some("dyknow/relay".into()),
        params: Vec::new(),
        executor: None,
    }
}

/// A change set of `actions`, numbered `n`.
fn change_set(n: u64, actions: Vec<dyknow_engine::Action>) -> dyknow_engine::ChangeSet {
    dyknow_engine::ChangeSet::new(
        dyknow_engine::ChangeSetId::numbered(n),
        dyknow_engine::Cause::Review,
        dyknow_engine::Compiled {
            actions,
            cost: dyknow_engine::CostSummary {
                total: 0.0,
                labour: 0.0,
                upkeep_per_time_unit: 0.0,
                horizon: 1.0,
            },
            unsatisfied_targets: Vec::new(),
            optimal: true,
        },
        dyknow_engine::NTriplesDelta::default(),
    )
}

/// Polls `fleet`'s last-heard view of `cu` until it is `(executor, state)`.
fn until_heard(fleet: &Fleet, cu: &str, executor: Option<&str>, state: &str) {
    let cu = dyknow_engine::Cid::from(cu);
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let view = fleet
            .last_heard(std::slice::from_ref(&cu))
            .remove(&cu)
            .expect("a view of every CU asked for");
        if view.executor.as_deref() == executor && view.state == state {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "{cu} stays {view:?}, not {state} on {executor:?}"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// `GET /cus` reads the fleet's last-heard view, which asks no executor: an executor busy
/// applying a change set (here: one that never answers `info` after its appearance) does not
/// hold the read up, and the view follows acknowledgements, events, adoption and vanishing.
#[test]
fn the_last_heard_view_follows_acknowledgements_and_events_without_asking() {
    use dyknow_cu::protocol::{ApplyReply, Event};
    use dyknow_engine::{Action, Cid};

    let (router, client) = sessions();
    let namespace = Namespace::new("heard").expect("a namespace");
    let (fleet, mut events) = Fleet::start(&router, namespace.clone()).expect("a fleet");
    // `info` answers once (the appearance), then never: the view must not need it.
    let infos = Arc::new(AtomicU64::new(0));
    let counted = infos.clone();
    let _info = client
        .declare_queryable(namespace.executor_service("x", "info"))
        .callback(move |query| {
            if counted.fetch_add(1, Ordering::SeqCst) > 0 {
                return;
            }
            let info = ExecutorInfo {
                instance: None,
                name: "x".into(),
                builtins: vec!["dyknow/relay".into()],
                processes: false,
                cus: Vec::new(),
            };
            reply_json(&query, &info);
        })
        .wait()
        .expect("a queryable");
    // `apply` acknowledges once the test releases it.
    let (release, released) = std::sync::mpsc::channel::<()>();
    let released = std::sync::Mutex::new(released);
    let _apply = client
        .declare_queryable(namespace.executor_service("x", "apply"))
        .callback(move |query| {
            let _ = released
                .lock()
                .expect("the apply lock")
                .recv_timeout(Duration::from_secs(30));
            let reply = ApplyReply {
                failures: Vec::new(),
            };
            reply_json(&query, &reply);
        })
        .wait()
        .expect("a queryable");
    let publisher = client
        .declare_publisher(namespace.executor_events("x"))
        .wait()
        .expect("a publisher");
    let token = client
        .liveliness()
        .declare_token(namespace.executor_token("x"))
        .wait()
        .expect("a token");
    until_appeared(&mut events, "x", 0);
    let fleet = Arc::new(fleet);
    let specs = BTreeMap::from([(dyknow_engine::Tid::from("t"), relay_spec())]);

    // A spawn being applied is starting on its executor; acknowledged, it runs.
    let spawn = change_set(
        1,
        vec![Action::Spawn {
            cu: "c1".into(),
            transformation: "t".into(),
        }],
    );
    let applying = {
        let (fleet, specs) = (fleet.clone(), specs.clone());
        std::thread::spawn(move || fleet.apply(&spawn, &specs))
    };
    until_heard(&fleet, "c1", Some("x"), "starting");
    release.send(()).expect("the apply queryable waits");
    let applied = applying.join().expect("apply returns");
    assert!(applied.failures.is_empty(), "{applied:?}");
    until_heard(&fleet, "c1", Some("x"), "running");
    // Asking the executor gets no answer: what was last heard, not a crash nobody saw.
    let c1 = Cid::from("c1");
    let asked = fleet.describe_all(std::slice::from_ref(&c1))[&c1].clone();
    assert_eq!(
        (asked.executor.as_deref(), asked.state.as_str()),
        (Some("x"), "running")
    );
    assert_eq!(asked.statistics, serde_json::json!({}));

    // Its executor says it crashed: crashed, hosted nowhere.
    let crashed = Event::CuCrashed {
        cu: "c1".into(),
        transformation: "t".into(),
        reason: "a test".into(),
    };
    publisher
        .put(serde_json::to_vec(&crashed).expect("json"))
        .wait()
        .expect("a put");
    until_heard(&fleet, "c1", None, "crashed");

    // Reconciliation adopts what a returning executor reports: running; when the executor
    // vanishes, crashed.
    fleet.adopt("x", &[Cid::from("c2")]);
    until_heard(&fleet, "c2", Some("x"), "running");
    drop(token);
    until_heard(&fleet, "c2", None, "crashed");
    assert!(
        infos.load(Ordering::SeqCst) >= 2,
        "describe_all asked x's info"
    );
}

/// What the fake executors were asked to apply: (executor, "action cu" of each action), in
/// the order the requests arrived.
type ApplyLog = Arc<std::sync::Mutex<Vec<(String, Vec<String>)>>>;

/// An executor's fake services: `info` (a relay builtin, no CUs) and `apply`, which records
/// each request's actions, in the order requests arrive, and acknowledges them.
struct FakeExecutor {
    _queryables: Vec<zenoh::query::Queryable<()>>,
    _token: zenoh::liveliness::LivelinessToken,
}

fn fake_executor(
    client: &zenoh::Session,
    namespace: &Namespace,
    name: &'static str,
    log: &ApplyLog,
) -> FakeExecutor {
    use dyknow_cu::protocol::{ApplyReply, ApplyRequest};
    let info = client
        .declare_queryable(namespace.executor_service(name, "info"))
        .callback(move |query| {
            // The sweep's question (no statistics) goes unanswered: this fake hosts nothing,
            // and its CUs, adopted or acknowledged, must not be swept as crashed while a test
            // runs.
            if query.payload().is_some_and(|p| !p.to_bytes().is_empty()) {
                return;
            }
            let info = ExecutorInfo {
                instance: None,
                name: name.into(),
                builtins: vec!["dyknow/relay".into()],
                processes: false,
                cus: Vec::new(),
            };
            reply_json(&query, &info);
        })
        .wait()
        .expect("a queryable");
    let log = log.clone();
    let apply = client
        .declare_queryable(namespace.executor_service(name, "apply"))
        .callback(move |query| {
            let request: ApplyRequest =
                serde_json::from_slice(&query.payload().expect("a payload").to_bytes())
                    .expect("an apply request");
            let actions = request
                .actions
                .iter()
                .map(|a| {
                    serde_json::to_value(a).expect("json")["action"]
                        .as_str()
                        .unwrap_or("?")
                        .to_owned()
                        + " "
                        + a.cu()
                })
                .collect();
            log.lock()
                .expect("the log")
                .push((name.to_owned(), actions));
            reply_json(
                &query,
                &ApplyReply {
                    failures: Vec::new(),
                },
            );
        })
        .wait()
        .expect("a queryable");
    let token = client
        .liveliness()
        .declare_token(namespace.executor_token(name))
        .wait()
        .expect("a token");
    FakeExecutor {
        _queryables: vec![info, apply],
        _token: token,
    }
}

/// What a [`fleet_of`] needs kept alive: the sessions and the fake executors.
type Kept = (zenoh::Session, zenoh::Session, Vec<FakeExecutor>);

/// A fleet on a fresh router session in `namespace`, with fake executors `names` (each present
/// before this returns), all logging what they are sent into one log.
fn fleet_of(namespace: &str, names: &[&'static str]) -> (Fleet, ApplyLog, Kept) {
    let (router, client) = sessions();
    let namespace = Namespace::new(namespace).expect("a namespace");
    let (fleet, mut events) = Fleet::start(&router, namespace.clone()).expect("a fleet");
    let log = Arc::new(std::sync::Mutex::new(Vec::new()));
    let executors = names
        .iter()
        .map(|&name| {
            let executor = fake_executor(&client, &namespace, name, &log);
            until_appeared(&mut events, name, 0);
            executor
        })
        .collect();
    (fleet, log, (router, client, executors))
}

/// A change set across executors makes before it breaks: a destroy on one executor is sent
/// after the spawns on every other (before, each executor got its actions in one request, in
/// order of its first action: x's destroy went before y's spawn, and the stream stopped
/// before its new producer ran).
#[test]
fn destroys_are_sent_after_every_executors_other_actions() {
    use dyknow_engine::{Action, Cid};
    let (fleet, log, _executors) = fleet_of("order", &["x", "y"]);
    let mut on_y = relay_spec();
    on_y.label = "u".into();
    on_y.iri = "urn:u".into();
    on_y.executor = Some("y".into());
    let mut on_x = relay_spec();
    on_x.executor = Some("x".into());
    let specs = BTreeMap::from([
        (dyknow_engine::Tid::from("t"), on_x),
        (dyknow_engine::Tid::from("u"), on_y),
    ]);
    // Applies change set `n` of spawns (cu, transformation) and destroys; returns what the
    // executors were sent, in order, as (executor, ["action cu", ...]).
    let apply = |n: u64, spawns: &[(&str, &str)], destroys: &[&str]| {
        log.lock().expect("the log").clear();
        let actions = spawns
            .iter()
            .map(|(cu, t)| Action::Spawn {
                cu: (*cu).into(),
                transformation: (*t).into(),
            })
            .chain(
                destroys
                    .iter()
                    .map(|cu| Action::Destroy { cu: (*cu).into() }),
            )
            .collect();
        let applied = fleet.apply(&change_set(n, actions), &specs);
        assert!(applied.failures.is_empty(), "{applied:?}");
        log.lock().expect("the log").clone()
    };
    let sent = |requests: &[(&str, &[&str])]| -> Vec<(String, Vec<String>)> {
        requests
            .iter()
            .map(|(e, a)| ((*e).to_owned(), a.iter().map(|s| (*s).to_owned()).collect()))
            .collect()
    };
    fleet.adopt("x", &[Cid::from("old")]);
    assert_eq!(
        apply(1, &[("a", "t"), ("new", "u")], &["old"]),
        sent(&[
            ("x", &["spawn a"]),
            ("y", &["spawn new"]),
            ("x", &["destroy old"]),
        ])
    );
    // The last executor's destroys ride with its other actions: one request each.
    fleet.adopt("y", &[Cid::from("older")]);
    assert_eq!(
        apply(2, &[("b", "t"), ("newer", "u")], &["a", "older"]),
        sent(&[
            ("x", &["spawn b"]),
            ("y", &["spawn newer", "destroy older"]),
            ("x", &["destroy a"]),
        ])
    );
}

/// A change set's spawns are spread over the executors that can run them, each going where the
/// fewest CUs are, counting those the change set placed before it (a user audit saw a chain of
/// four CUs all go to one executor while two others stood idle: the count read only the
/// placement from before the change set). Ties go by name.
#[test]
fn a_change_sets_spawns_are_spread_over_the_executors() {
    use dyknow_engine::Action;
    let (fleet, log, _executors) = fleet_of("spread", &["x", "y", "z"]);
    let specs = BTreeMap::from([(dyknow_engine::Tid::from("t"), relay_spec())]);
    let spawns = |names: &[&str]| {
        names
            .iter()
            .map(|cu| Action::Spawn {
                cu: (*cu).into(),
                transformation: "t".into(),
            })
            .collect()
    };
    let applied = fleet.apply(&change_set(1, spawns(&["a", "b", "c", "d"])), &specs);
    assert!(applied.failures.is_empty(), "{applied:?}");
    let mut sent: Vec<(String, Vec<String>)> = log.lock().expect("the log").clone();
    sent.sort();
    assert_eq!(
        sent,
        [
            (
                "x".to_owned(),
                vec!["spawn a".to_owned(), "spawn d".to_owned()]
            ),
            ("y".to_owned(), vec!["spawn b".to_owned()]),
            ("z".to_owned(), vec!["spawn c".to_owned()]),
        ]
    );
    // The next change set starts from where they are: y and z have fewest.
    log.lock().expect("the log").clear();
    let applied = fleet.apply(&change_set(2, spawns(&["e", "f"])), &specs);
    assert!(applied.failures.is_empty(), "{applied:?}");
    let mut sent: Vec<(String, Vec<String>)> = log.lock().expect("the log").clone();
    sent.sort();
    assert_eq!(
        sent,
        [
            ("y".to_owned(), vec!["spawn e".to_owned()]),
            ("z".to_owned(), vec!["spawn f".to_owned()]),
        ]
    );
}

/// An instance of executor `x` as a fake: its instance token, its name's token, and an
/// `info` that says which instance answers and that it runs `cus` CUs, `delay` after it is
/// asked.
struct Instance {
    _info: zenoh::query::Queryable<()>,
    _tokens: [zenoh::liveliness::LivelinessToken; 2],
}

fn instance(
    client: &zenoh::Session,
    namespace: &Namespace,
    id: &str,
    cus: u64,
    delay: Duration,
) -> Instance {
    let id: InstanceId = id.parse().expect("an instance id");
    let said = id.clone();
    let info = client
        .declare_queryable(namespace.executor_service("x", "info"))
        .callback(move |query| {
            let info = info_of_x(Some(said.clone()), cus);
            std::thread::spawn(move || {
                std::thread::sleep(delay);
                reply_json(&query, &info);
            });
        })
        .wait()
        .expect("a queryable");
    let token = |key: String| {
        client
            .liveliness()
            .declare_token(key)
            .wait()
            .expect("a token")
    };
    Instance {
        _info: info,
        _tokens: [
            token(namespace.executor_instance("x", &id)),
            token(namespace.executor_token("x")),
        ],
    }
}

/// Two executors of one name meet: the name's token never goes down (Zenoh announces it
/// once), yet the fleet sees the earlier instance take the name over. It counts the name as
/// gone and back (without that, no second appearance comes at all), and takes `info` only
/// from the instance holding the name, not from the later one still answering, first, while
/// it steps down (its CUs are about to stop).
#[test]
fn an_earlier_instance_takes_the_name_and_only_its_answer_counts() {
    let (router, client) = sessions();
    let namespace = Namespace::new("twins").expect("a namespace");
    let (fleet, mut events) = Fleet::start(&router, namespace.clone()).expect("a fleet");
    let later = instance(&client, &namespace, "0000000002000-b", 1, Duration::ZERO);
    until_appeared(&mut events, "x", 1);
    // The earlier instance answers 100 ms after the later one.
    let earlier = instance(
        &client,
        &namespace,
        "0000000001000-a",
        0,
        Duration::from_millis(100),
    );
    // It steps down half a second later (a real one does once the earlier one answers it).
    let stepping_down = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(500));
        drop(later);
    });
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut seen = Vec::new();
    loop {
        match events.try_recv() {
            Ok(FleetEvent::Appeared { executor, cus }) if executor == "x" => {
                assert!(
                    cus.is_empty(),
                    "the later instance's answer was taken: {cus:?} after {seen:?}"
                );
                break;
            }
            Ok(event) => seen.push(event),
            Err(_) => {
                assert!(Instant::now() < deadline, "x never reappeared: {seen:?}");
                std::thread::sleep(Duration::from_millis(5));
            }
        }
    }
    stepping_down.join().expect("stepped down");
    assert!(present(&fleet, "x"), "the earlier instance holds the name");
    drop(earlier);
    let deadline = Instant::now() + Duration::from_secs(30);
    while present(&fleet, "x") {
        assert!(
            Instant::now() < deadline,
            "x stays present without an instance"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// The crashes a fleet reports within `wait`.
fn crashes_within(events: &mut UnboundedReceiver<FleetEvent>, wait: Duration) -> Vec<String> {
    let started = Instant::now();
    let mut seen = Vec::new();
    while started.elapsed() < wait {
        match events.try_recv() {
            Ok(FleetEvent::Crashed { cu, .. }) => seen.push(cu.to_string()),
            Ok(_) => {}
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
    seen
}

/// A crash whose event never arrives (an executor's event is sent once) is found by the
/// sweep: a CU placed on an executor and known to run that the executor no longer hosts, in two
/// answers in a row (so not before a sweep interval has passed), is reported crashed. One it
/// hosts is not, however long it runs, and neither is one a change set being applied destroys.
/// (A crash storm audit saw such a CU stay `running` in the model, its target satisfied and
/// silent.)
#[test]
fn a_crash_whose_event_was_lost_is_found_by_the_sweep() {
    use dyknow_cu::protocol::{ApplyReply, ApplyRequest, CuAction, InfoRequest};
    use dyknow_engine::Action;

    let (router, client) = sessions();
    let namespace = Namespace::new("sweep").expect("a namespace");
    let (fleet, mut events) = Fleet::start(&router, namespace.clone()).expect("a fleet");
    // What x hosts, as its `info` says; and whether the sweep asked without statistics.
    let hosted = Arc::new(std::sync::Mutex::new(Vec::<String>::new()));
    let quick = Arc::new(AtomicU64::new(0));
    let (listed, asked_quick) = (hosted.clone(), quick.clone());
    let _info = client
        .declare_queryable(namespace.executor_service("x", "info"))
        .callback(move |query| {
            let payload = query.payload().map(|p| p.to_bytes().into_owned());
            if payload
                .and_then(|p| serde_json::from_slice::<InfoRequest>(&p).ok())
                .is_some_and(|r| !r.statistics)
            {
                asked_quick.fetch_add(1, Ordering::SeqCst);
            }
            let mut info = info_of_x(None, 0);
            info.builtins = vec!["dyknow/relay".into()];
            info.cus = (listed.lock().expect("the list").iter())
                .map(|cu| {
                    let mut report = info_of_x(None, 1).cus.remove(0);
                    report.cu.clone_from(cu);
                    report
                })
                .collect();
            reply_json(&query, &info);
        })
        .wait()
        .expect("a queryable");
    // `apply` carries out spawns and destroys on the list at once, and answers after the
    // delay the test set (none by default).
    let delay = Arc::new(AtomicU64::new(0));
    let (applied_to, held) = (hosted.clone(), delay.clone());
    let _apply = client
        .declare_queryable(namespace.executor_service("x", "apply"))
        .callback(move |query| {
            let payload = query.payload().map(|p| p.to_bytes().into_owned());
            let request: ApplyRequest =
                serde_json::from_slice(&payload.unwrap_or_default()).expect("a request");
            {
                let mut list = applied_to.lock().expect("the list");
                for action in &request.actions {
                    match action {
                        CuAction::Spawn { cu, .. } => list.push(cu.clone()),
                        CuAction::Destroy { cu } => list.retain(|c| c != cu),
                        _ => {}
                    }
                }
            }
            // Answered from a thread of its own: a callback that waited would hold up the
            // session's other answers (the sweep's `info`).
            let wait = Duration::from_millis(held.load(Ordering::SeqCst));
            std::thread::spawn(move || {
                std::thread::sleep(wait);
                let reply = ApplyReply {
                    failures: Vec::new(),
                };
                reply_json(&query, &reply);
            });
        })
        .wait()
        .expect("a queryable");
    let _token = client
        .liveliness()
        .declare_token(namespace.executor_token("x"))
        .wait()
        .expect("a token");
    until_appeared(&mut events, "x", 0);
    let specs = BTreeMap::from([(dyknow_engine::Tid::from("t"), relay_spec())]);
    let spawn = change_set(
        1,
        ["c1", "c2"]
            .into_iter()
            .map(|cu| Action::Spawn {
                cu: cu.into(),
                transformation: "t".into(),
            })
            .collect(),
    );
    assert!(fleet.apply(&spawn, &specs).failures.is_empty());
    until_heard(&fleet, "c1", Some("x"), "running");
    // Hosted: three sweeps and more, no crash.
    assert_eq!(
        crashes_within(&mut events, Duration::from_secs(7)),
        Vec::<String>::new()
    );
    assert!(
        quick.load(Ordering::SeqCst) >= 2,
        "the sweep asks without statistics"
    );
    // Destroyed by a change set that takes 4.5 s to be acknowledged (two sweeps and more; the
    // fleet waits 5 s): gone from x at once, but the change set acts on it: no crash, then or
    // after.
    delay.store(4_500, Ordering::SeqCst);
    let destroy = change_set(2, vec![Action::Destroy { cu: "c2".into() }]);
    let fleet = Arc::new(fleet);
    let destroying = {
        let (fleet, specs) = (fleet.clone(), specs.clone());
        std::thread::spawn(move || fleet.apply(&destroy, &specs))
    };
    assert_eq!(
        crashes_within(&mut events, Duration::from_secs(4)),
        Vec::<String>::new()
    );
    assert!(
        destroying
            .join()
            .expect("apply returns")
            .failures
            .is_empty()
    );
    delay.store(0, Ordering::SeqCst);
    assert_eq!(
        crashes_within(&mut events, Duration::from_secs(5)),
        Vec::<String>::new()
    );
    // Gone without a word: crashed, after two answers, so not before a sweep interval.
    hosted.lock().expect("the list").clear();
    let gone = Instant::now();
    let reason = loop {
        match events.try_recv() {
            Ok(FleetEvent::Crashed { cu, reason }) => {
                assert_eq!(cu.as_str(), "c1");
                break reason;
            }
            Ok(_) => {}
            Err(_) => {
                assert!(
                    gone.elapsed() < Duration::from_secs(30),
                    "the lost crash was never found"
                );
                std::thread::sleep(Duration::from_millis(20));
            }
        }
    };
    assert!(
        gone.elapsed() >= Duration::from_millis(1_900),
        "concluded from one answer: {:?}",
        gone.elapsed()
    );
    assert!(reason.contains("no longer hosts it"), "{reason}");
    until_heard(&fleet, "c1", None, "crashed");
}

/// An executor absent for longer than `forget_absent_after` leaves `GET /executors`'s list
/// (executors named afresh on every start would otherwise pile up in it); before, it is listed
/// absent; one present is never forgotten, and one that comes back is listed again.
#[test]
fn executors_absent_for_long_are_forgotten_and_listed_again_when_back() {
    let (router, client) = sessions();
    let namespace = Namespace::new("forget").expect("a namespace");
    let (fleet, mut events) = Fleet::start(&router, namespace.clone()).expect("a fleet");
    let _info = client
        .declare_queryable(namespace.executor_service("x", "info"))
        .callback(move |query| reply_json(&query, &info_of_x(None, 0)))
        .wait()
        .expect("a queryable");
    let mut stays = info_of_x(None, 0);
    stays.name = "y".into();
    let _info_y = client
        .declare_queryable(namespace.executor_service("y", "info"))
        .callback(move |query| reply_json(&query, &stays))
        .wait()
        .expect("a queryable");
    let declare = |name: &str| {
        client
            .liveliness()
            .declare_token(namespace.executor_token(name))
            .wait()
            .expect("a token")
    };
    let listed = |name: &str| {
        fleet
            .executors(&BTreeMap::new())
            .into_iter()
            .find(|e| e.name == name)
            .map(|e| e.present)
    };
    let _y = declare("y");
    assert!(fleet.wait_for("y", Duration::from_secs(30)));
    let x = declare("x");
    until_appeared(&mut events, "x", 0);
    drop(x);
    let deadline = Instant::now() + Duration::from_secs(30);
    while listed("x") != Some(false) {
        assert!(Instant::now() < deadline, "x is never listed absent");
        std::thread::sleep(Duration::from_millis(5));
    }
    // Within the default retention: listed absent through sweeps.
    let since = Instant::now();
    while since.elapsed() < Duration::from_secs(5) {
        assert_eq!(listed("x"), Some(false), "x was forgotten too soon");
        std::thread::sleep(Duration::from_millis(50));
    }
    // Past a retention of none: forgotten at the next sweep; y, present, stays.
    fleet.forget_absent_after(Duration::ZERO);
    let deadline = Instant::now() + Duration::from_secs(30);
    while listed("x").is_some() {
        assert!(Instant::now() < deadline, "x is never forgotten");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(listed("y"), Some(true));
    // Back: listed present again.
    let _x = declare("x");
    until_appeared(&mut events, "x", 0);
    assert_eq!(listed("x"), Some(true));
    let since = Instant::now();
    while since.elapsed() < Duration::from_secs(5) {
        assert_eq!(listed("y"), Some(true), "y, present, was forgotten");
        assert_eq!(listed("x"), Some(true), "x, present, was forgotten");
        std::thread::sleep(Duration::from_millis(50));
    }
}
