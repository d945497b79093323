//! The executor on a real Zenoh session: builtin and process CUs computing, rewired make
//! before break, crashing.
#![expect(
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::sync::mpsc;
use std::time::{Duration, Instant};

use dyknow_cu::keys::InstanceId;
use dyknow_cu::protocol::{ApplyRequest, CuAction, CuState, Event, Implementation};
use dyknow_cu::zenoh::{self, Wait};
use dyknow_cu::{Namespace, Sample};
use dyknow_executor::{Executor, ExecutorConfig};
use serde_json::{Value, json};

#[path = "../../cu/tests/support/port.rs"]
mod port;
use port::free_port;

/// A router session listening on a fresh loopback port; returns it and its endpoint.
fn session() -> (zenoh::Session, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let config = dyknow_cu::router_config(std::slice::from_ref(&endpoint), &[]).expect("a config");
    (zenoh::open(config).wait().expect("a session"), endpoint)
}

fn implementation(
    kind: &str,
    source: &str,
    ins: &[&str],
    outs: &[&str],
    params: Value,
) -> Implementation {
    Implementation {
        kind: kind.into(),
        source: source.into(),
        params: serde_json::from_value(params).expect("params"),
        executor: None,
        inputs: ins.iter().map(|s| (*s).to_owned()).collect(),
        outputs: outs.iter().map(|s| (*s).to_owned()).collect(),
    }
}

fn spawn(cu: &str, implementation: Implementation) -> CuAction {
    CuAction::Spawn {
        cu: cu.into(),
        transformation: format!("t-{cu}"),
        implementation,
    }
}

fn connect(cu: &str, input: bool, port: &str, channel: &str) -> CuAction {
    if input {
        CuAction::ConnectIn {
            cu: cu.into(),
            port: port.into(),
            channel: channel.into(),
        }
    } else {
        CuAction::ConnectOut {
            cu: cu.into(),
            port: port.into(),
            channel: channel.into(),
        }
    }
}

fn listen(session: &zenoh::Session, channel: &str) -> (mpsc::Receiver<Sample>, impl Drop) {
    let (tx, rx) = mpsc::channel();
    let key = Namespace::default().channel(channel).expect("a key");
    let sub = session
        .declare_subscriber(key)
        .callback(move |s| {
            if let Ok(sample) = Sample::from_slice(&s.payload().to_bytes()) {
                let _ = tx.send(sample);
            }
        })
        .wait()
        .expect("subscribe");
    (rx, sub)
}

fn events(session: &zenoh::Session) -> (mpsc::Receiver<Event>, impl Drop) {
    let (tx, rx) = mpsc::channel();
    let sub = session
        .declare_subscriber(Namespace::default().all_executor_events())
        .callback(move |s| {
            if let Ok(e) = serde_json::from_slice::<Event>(&s.payload().to_bytes()) {
                let _ = tx.send(e);
            }
        })
        .wait()
        .expect("subscribe");
    (rx, sub)
}

fn apply(executor: &Executor, actions: Vec<CuAction>) {
    let reply = executor.apply(&ApplyRequest {
        instance: None,
        change_set: "cs-t".into(),
        generation: 0,
        actions,
    });
    assert!(reply.failures.is_empty(), "{:?}", reply.failures);
}

/// An executable script `body` in a directory of its own under the temporary directory (named
/// after `tag` and this process): the directory and the script.
fn script(tag: &str, body: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = std::env::temp_dir().join(format!("dyknow-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a directory");
    let script = dir.join("wrapper.sh");
    std::fs::write(&script, body).expect("the script");
    std::fs::set_permissions(&script, std::os::unix::fs::PermissionsExt::from_mode(0o755))
        .expect("chmod");
    (dir, script)
}

/// Spawns CU `cu` running the command line `source` as a process (in port `i`, out port `o`).
fn spawn_source(executor: &Executor, cu: &str, source: &str) {
    apply(
        executor,
        vec![spawn(
            cu,
            implementation("process", source, &["i"], &["o"], json!({})),
        )],
    );
}

/// Spawns CU `cu` as a process running `dyknow-cu dyknow/relay` (in port `i`, out port `o`) and
/// returns its pid.
fn spawn_process_relay(executor: &Executor, cu: &str) -> u32 {
    let program = env!("CARGO_BIN_EXE_dyknow-cu");
    apply(
        executor,
        vec![spawn(
            cu,
            implementation(
                "process",
                &format!("{program} dyknow/relay"),
                &["i"],
                &["o"],
                json!({}),
            ),
        )],
    );
    executor
        .pids()
        .into_iter()
        .find(|(n, _)| n == cu)
        .expect("a pid")
        .1
}

#[test]
fn a_signal_relay_map_chain_computes_and_a_panic_is_a_crash() {
    let (session, endpoint) = session();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("t1", Namespace::default(), vec![endpoint]),
    )
    .expect("an executor");
    let (crashes, _e) = events(&session);
    let (out, _s) = listen(&session, "/out");
    apply(
        &executor,
        vec![
            spawn(
                "sig",
                implementation(
                    "builtin",
                    "dyknow/signal",
                    &[],
                    &["o"],
                    json!({"period_ms": 5}),
                ),
            ),
            spawn(
                "rel",
                implementation("nodelet", "dyknow/relay", &["i"], &["o"], json!({})),
            ),
            spawn(
                "map",
                implementation(
                    "builtin",
                    "dyknow/map",
                    &["i"],
                    &["o"],
                    json!({"scale": 10}),
                ),
            ),
            connect("map", false, "o", "/out"),
            connect("map", true, "i", "b"),
            connect("rel", false, "o", "b"),
            connect("rel", true, "i", "a"),
            connect("sig", false, "o", "a"),
        ],
    );
    let first = out
        .recv_timeout(Duration::from_secs(10))
        .expect("a sample")
        .value;
    let n = first.as_i64().expect("a number");
    assert_eq!(n % 10, 0, "the counter times ten");
    let next = out
        .recv_timeout(Duration::from_secs(10))
        .expect("a sample")
        .value;
    assert_eq!(next.as_i64(), Some(n + 10), "consecutive counter values");
    let report = executor
        .info()
        .cus
        .into_iter()
        .find(|c| c.cu == "rel")
        .expect("rel");
    assert_eq!(report.state, CuState::Running);
    assert!(report.statistics.ports["i"].messages >= 1);
    assert_eq!(report.inputs["i"].as_deref(), Some("a"));
    // A fault relay that panics on command.
    apply(
        &executor,
        vec![
            spawn(
                "bad",
                implementation("builtin", "dyknow/fault", &["i"], &["o"], json!({})),
            ),
            connect("bad", true, "i", "cmd"),
        ],
    );
    session
        .put(
            Namespace::default().channel("cmd").expect("key"),
            Sample::now(json!({"fault": "panic"})).to_bytes(),
        )
        .wait()
        .expect("put");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match crashes.recv_timeout(left).expect("a crash event") {
            Event::CuCrashed { cu, reason, .. } => {
                assert_eq!(cu, "bad");
                assert!(reason.contains("panic"), "{reason}");
                break;
            }
            _ => continue,
        }
    }
    assert!(
        executor.info().cus.iter().all(|c| c.cu != "bad"),
        "a crashed CU is gone"
    );
    // The crash took the CU's liveliness token, not the executor's or another CU's. (The
    // executor releases a crashed CU on its worker: poll.)
    let tokens = |key: String| {
        session
            .liveliness()
            .get(key)
            .timeout(Duration::from_secs(2))
            .wait()
            .expect("a liveliness query")
            .iter()
            .filter(|r| r.result().is_ok())
            .count()
    };
    let ns = Namespace::default();
    let deadline = Instant::now() + Duration::from_secs(10);
    while tokens(ns.cu_token("bad")) != 0 {
        assert!(Instant::now() < deadline, "the crashed CU's token stays");
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(
        tokens(ns.cu_token("rel")),
        1,
        "a running CU's token is there"
    );
    assert_eq!(
        tokens(ns.executor_token("t1")),
        1,
        "the executor's token is there"
    );
    executor.shutdown();
    assert_eq!(tokens(ns.executor_token("t1")), 0, "shut down: no token");
}

#[test]
fn rebinding_an_input_loses_no_sample_after_the_acknowledgement() {
    let (session, endpoint) = session();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("t2", Namespace::default(), vec![endpoint]),
    )
    .expect("an executor");
    let (out, _s) = listen(&session, "out");
    apply(
        &executor,
        vec![
            spawn(
                "r",
                implementation("builtin", "dyknow/relay", &["i"], &["o"], json!({})),
            ),
            connect("r", false, "o", "out"),
            connect("r", true, "i", "old"),
        ],
    );
    let new_key = Namespace::default().channel("new").expect("key");
    let publisher = session
        .declare_publisher(new_key)
        .wait()
        .expect("publisher");
    for round in 0..20 {
        let channel = if round % 2 == 0 { "new" } else { "old" };
        apply(&executor, vec![connect("r", true, "i", channel)]);
        if channel == "new" {
            publisher
                .put(Sample::new(round, json!(round)).to_bytes())
                .wait()
                .expect("put");
            let got = out
                .recv_timeout(Duration::from_secs(10))
                .expect("no sample lost");
            assert_eq!(got.t, round);
        }
    }
    let report = executor
        .info()
        .cus
        .into_iter()
        .find(|c| c.cu == "r")
        .expect("r");
    assert_eq!(report.statistics.reconfigurations, 22);
}

#[test]
fn process_cus_compute_and_their_death_is_seen_at_once() {
    let (session, endpoint) = session();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("t3", Namespace::default(), vec![endpoint]),
    )
    .expect("an executor");
    let (crashes, _e) = events(&session);
    let (out, _s) = listen(&session, "pout");
    let program = env!("CARGO_BIN_EXE_dyknow-cu");
    apply(
        &executor,
        vec![
            spawn(
                "pm",
                implementation(
                    "process",
                    &format!("{program} dyknow/map"),
                    &["i"],
                    &["o"],
                    json!({"offset": 1}),
                ),
            ),
            connect("pm", false, "o", "pout"),
            connect("pm", true, "i", "pin"),
        ],
    );
    let key = Namespace::default().channel("pin").expect("key");
    let got = (0..100)
        .find_map(|i| {
            session
                .put(&key, Sample::new(i, json!(41)).to_bytes())
                .wait()
                .expect("put");
            out.recv_timeout(Duration::from_millis(100)).ok()
        })
        .expect("the process computes");
    assert_eq!(got.value, json!(42));
    let (_, pid) = executor
        .pids()
        .into_iter()
        .find(|(n, _)| n == "pm")
        .expect("a pid");
    let killed = Instant::now();
    std::process::Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .expect("kill");
    loop {
        match crashes
            .recv_timeout(Duration::from_secs(10))
            .expect("a crash event")
        {
            Event::CuCrashed { cu, .. } if cu == "pm" => break,
            _ => continue,
        }
    }
    assert!(
        killed.elapsed() < Duration::from_secs(2),
        "seen in {:?}",
        killed.elapsed()
    );
    // A program that is not there fails the spawn, with the reason.
    let reply = executor.apply(&ApplyRequest {
        instance: None,
        change_set: "cs".into(),
        generation: 0,
        actions: vec![spawn(
            "gone",
            implementation("process", "/nonexistent/cu", &[], &["o"], json!({})),
        )],
    });
    assert_eq!(reply.failures.len(), 1);
    assert!(
        reply.failures[0].reason.contains("not an executable"),
        "{:?}",
        reply.failures
    );
    // Shutdown leaves no child behind.
    let pid = spawn_process_relay(&executor, "p2");
    executor.shutdown();
    assert!(
        !std::path::Path::new(&format!("/proc/{pid}")).exists() || is_zombie(pid),
        "child {pid} still runs"
    );
}

fn is_zombie(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| s.contains(") Z "))
}

/// The raw payloads arriving on a channel.
fn listen_raw(session: &zenoh::Session, channel: &str) -> (mpsc::Receiver<Vec<u8>>, impl Drop) {
    let (tx, rx) = mpsc::channel();
    let key = Namespace::default().channel(channel).expect("a key");
    let sub = session
        .declare_subscriber(key)
        .callback(move |s| {
            let _ = tx.send(s.payload().to_bytes().into_owned());
        })
        .wait()
        .expect("subscribe");
    (rx, sub)
}

#[test]
fn relays_forward_the_payload_they_got_and_transformations_write_new_samples() {
    let (session, endpoint) = session();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("t5", Namespace::default(), vec![endpoint]),
    )
    .expect("an executor");
    let program = env!("CARGO_BIN_EXE_dyknow-cu");
    // in → builtin relay → mid → process relay → relayed; in → map → mapped.
    apply(
        &executor,
        vec![
            spawn(
                "r1",
                implementation("builtin", "dyknow/relay", &["in"], &["out"], json!({})),
            ),
            connect("r1", false, "out", "mid"),
            connect("r1", true, "in", "in"),
            spawn(
                "r2",
                implementation(
                    "process",
                    &format!("{program} dyknow/relay"),
                    &["in"],
                    &["out"],
                    json!({}),
                ),
            ),
            connect("r2", false, "out", "relayed"),
            connect("r2", true, "in", "mid"),
            spawn(
                "m",
                implementation(
                    "builtin",
                    "dyknow/map",
                    &["in"],
                    &["out"],
                    json!({"scale": 2}),
                ),
            ),
            connect("m", false, "out", "mapped"),
            connect("m", true, "in", "in"),
        ],
    );
    let (relayed, _r) = listen_raw(&session, "relayed");
    let (mapped, _m) = listen_raw(&session, "mapped");
    let key = Namespace::default().channel("in").expect("key");
    // A sample with a field DyKnow does not know and spacing of its own: readers ignore the
    // field, and a relay passes the payload on exactly as it got it.
    let payload = br#"{ "value": 21, "t": 1700000000000, "source": "camera-3" }"#;
    let got = (0..200)
        .find_map(|_| {
            session.put(&key, &payload[..]).wait().expect("put");
            relayed.recv_timeout(Duration::from_millis(50)).ok()
        })
        .expect("the relays to carry the sample");
    assert_eq!(got, payload.to_vec());
    let doubled = mapped
        .recv_timeout(Duration::from_secs(10))
        .expect("a mapped sample");
    let doubled: Value = serde_json::from_slice(&doubled).expect("json");
    assert_eq!(doubled, json!({"t": 1_700_000_000_000_i64, "value": 42}));
    // Forwarded samples count in the out port's statistics like published ones.
    let report = executor
        .info()
        .cus
        .into_iter()
        .find(|c| c.cu == "r1")
        .expect("r1");
    let out = &report.statistics.ports["out"];
    assert!(out.messages >= 1);
    assert_eq!(out.bytes, out.messages * payload.len() as u64);
    assert_eq!(out.last_t, Some(1_700_000_000_000));
    executor.shutdown();
}

/// Change sets carry a generation: an older one cannot rewire a CU a newer one configured,
/// destroying is always allowed, and a spawn from a newer (or the same) generation replaces a
/// CU of that name left by a change set the manager never recorded.
#[test]
fn generations_fence_stale_change_sets() {
    let (session, endpoint) = session();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("t-gen", Namespace::default(), vec![endpoint]),
    )
    .expect("an executor");
    let request = |generation: u64, actions: Vec<CuAction>| ApplyRequest {
        instance: None,
        change_set: format!("cs-{generation}"),
        generation,
        actions,
    };
    let relay = || implementation("builtin", "dyknow/relay", &["i"], &["o"], json!({}));
    let reply = executor.apply(&request(5, vec![spawn("r", relay())]));
    assert!(reply.failures.is_empty(), "{:?}", reply.failures);
    let generation_of = |cu: &str| {
        executor
            .info()
            .cus
            .into_iter()
            .find(|c| c.cu == cu)
            .map(|c| c.generation)
    };
    assert_eq!(generation_of("r"), Some(5));
    // A stale request (generation 4) may not rewire it; a newer one (6) may.
    let stale = executor.apply(&request(4, vec![connect("r", false, "o", "/x")]));
    assert_eq!(stale.failures.len(), 1, "{stale:?}");
    assert!(stale.failures[0].reason.contains("stale"), "{stale:?}");
    let newer = executor.apply(&request(6, vec![connect("r", false, "o", "/y")]));
    assert!(newer.failures.is_empty(), "{newer:?}");
    assert_eq!(generation_of("r"), Some(6));
    let report = executor.info().cus.into_iter().find(|c| c.cu == "r");
    assert_eq!(report.expect("r runs").outputs["o"].as_deref(), Some("/y"));
    // A spawn of the same name from an older generation is refused; from a newer one it
    // replaces the CU (its bindings are gone).
    let old_spawn = executor.apply(&request(3, vec![spawn("r", relay())]));
    assert_eq!(old_spawn.failures.len(), 1, "{old_spawn:?}");
    let new_spawn = executor.apply(&request(7, vec![spawn("r", relay())]));
    assert!(new_spawn.failures.is_empty(), "{new_spawn:?}");
    let report = executor.info().cus.into_iter().find(|c| c.cu == "r");
    assert_eq!(report.expect("r runs").outputs["o"], None);
    // Destroying is allowed from any generation.
    let destroy = executor.apply(&request(1, vec![CuAction::Destroy { cu: "r".into() }]));
    assert!(destroy.failures.is_empty(), "{destroy:?}");
    assert!(executor.info().cus.is_empty());
    executor.shutdown();
}

/// Two executors of one name that could not see each other when they started meet when a
/// link comes up (a partition heals): the one that started later steps down. It stops its
/// CUs, withdraws its tokens and says for whom; the earlier one keeps the name, and refuses
/// requests addressed to the other instance. An earlier instance's token alone (a ghost: its
/// executor gone, its lease not yet expired) makes no one step down.
#[test]
fn a_later_executor_of_a_name_steps_down_when_it_meets_an_earlier_one() {
    // Each connects to an endpoint nothing listens on yet: each starts alone.
    let (near, far) = (
        format!("tcp/127.0.0.1:{}", free_port()),
        format!("tcp/127.0.0.1:{}", free_port()),
    );
    let alone = |endpoint: &String| {
        let config =
            dyknow_cu::router_config(&[], std::slice::from_ref(endpoint)).expect("a config");
        zenoh::open(config).wait().expect("a session")
    };
    let (early_session, late_session) = (alone(&far), alone(&near));
    let ns = Namespace::new("twins").expect("a namespace");
    let early = Executor::start(
        &early_session,
        ExecutorConfig::new("twin", ns.clone(), Vec::new()),
    )
    .expect("the earlier twin starts");
    // Instance ids order by start time in milliseconds: the next one starts a tick later.
    let started = dyknow_cu::now_ms();
    while dyknow_cu::now_ms() == started {
        std::thread::yield_now();
    }
    let (told, stepped) = mpsc::channel();
    let mut config = ExecutorConfig::new("twin", ns.clone(), Vec::new());
    config.on_step_down = Some(dyknow_executor::OnStepDown(std::sync::Arc::new(
        move |earlier: &InstanceId| {
            let _ = told.send(earlier.clone());
        },
    )));
    let late = Executor::start(&late_session, config).expect("the later twin starts, alone");
    assert!(early.instance() < late.instance());
    apply(
        &late,
        vec![spawn(
            "sig",
            implementation(
                "builtin",
                "dyknow/signal",
                &[],
                &["out"],
                json!({"period_ms": 10}),
            ),
        )],
    );
    assert_eq!(late.info().cus.len(), 1);

    // The later twin links to a router holding a ghost's token: an instance earlier than
    // both, which answers nothing.
    let config = dyknow_cu::router_config(std::slice::from_ref(&near), &[]).expect("a config");
    let hub = zenoh::open(config).wait().expect("the hub");
    let ghost: InstanceId = "0000000000001-ab".parse().expect("an instance id");
    let _ghost = hub
        .liveliness()
        .declare_token(ns.executor_instance("twin", &ghost))
        .wait()
        .expect("a token");
    let count = |session: &zenoh::Session, key: String| {
        session
            .liveliness()
            .get(key)
            .timeout(Duration::from_secs(1))
            .wait()
            .expect("a liveliness query")
            .iter()
            .filter(|r| r.result().is_ok())
            .count()
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while count(&late_session, ns.executor_instance("twin", &ghost)) == 0 {
        assert!(
            Instant::now() < deadline,
            "the later twin never sees the ghost"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    // Absence can only be waited for: longer than one round of asking (2 s) and its pause.
    assert!(
        stepped.recv_timeout(Duration::from_secs(4)).is_err(),
        "the later twin stepped down for a ghost"
    );
    assert_eq!(late.info().cus.len(), 1, "its CU runs on");

    // The earlier twin links too: a router on its endpoint, linked to the hub.
    let config = dyknow_cu::router_config(std::slice::from_ref(&far), std::slice::from_ref(&near))
        .expect("a config");
    let _bridge = zenoh::open(config).wait().expect("the bridge");
    let earlier = stepped
        .recv_timeout(Duration::from_secs(30))
        .expect("the later twin steps down once the earlier one answers");
    assert_eq!(&earlier, early.instance());
    assert_eq!(late.stepped_down().as_ref(), Some(early.instance()));
    assert!(late.info().cus.is_empty(), "its CUs stopped");
    assert_eq!(
        early.stepped_down(),
        None,
        "the earlier twin keeps the name"
    );

    // The name and the earlier instance stay on the data plane; the later instance's token
    // goes.
    let deadline = Instant::now() + Duration::from_secs(10);
    while count(&hub, ns.executor_instance("twin", late.instance())) != 0 {
        assert!(Instant::now() < deadline, "the later twin's token stays");
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(
        count(&hub, ns.executor_instance("twin", early.instance())),
        1
    );
    assert_eq!(count(&hub, ns.executor_token("twin")), 1);

    // A request for the other instance is refused, action by action.
    let reply = early.apply(&ApplyRequest {
        instance: Some(late.instance().clone()),
        change_set: "cs-9".into(),
        generation: 9,
        actions: vec![CuAction::Destroy { cu: "x".into() }],
    });
    assert_eq!(reply.failures.len(), 1);
    assert!(
        reply.failures[0].reason.contains("not for this one"),
        "{:?}",
        reply.failures
    );
    assert_eq!(early.info().instance.as_ref(), Some(early.instance()));
}

/// `dyknow-cu --help` prints the usage and succeeds; no builtin, or an unknown one, is a usage
/// error (64), as `dyknow cu` answers.
#[test]
fn dyknow_cu_answers_help_and_usage_errors() {
    let program = env!("CARGO_BIN_EXE_dyknow-cu");
    for flag in ["--help", "-h"] {
        let out = std::process::Command::new(program)
            .arg(flag)
            .output()
            .unwrap();
        assert!(out.status.success(), "{flag}: {out:?}");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains("usage: dyknow-cu BUILTIN") && text.contains("dyknow/relay"),
            "{text}"
        );
    }
    for args in [&[][..], &["--nope"][..], &["dyknow/none"][..]] {
        let out = std::process::Command::new(program)
            .args(args)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(64), "{args:?}: {out:?}");
    }
}

/// A CU started through a wrapper (a shell that does not `exec`) keeps the wrapper as its
/// parent when the executor is `kill -9`ed, so watching its parent never saw the executor go;
/// it kept publishing beside its replacement. The executor names its process
/// (`DYKNOW_EXECUTOR_PROCESS`), and the SDK exits (2, orphaned) once that process is gone, or
/// at once when it is gone before the CU starts.
#[test]
fn a_process_cu_exits_when_its_executor_process_is_gone_whatever_its_parent() {
    let (_session, endpoint) = session();
    let program = env!("CARGO_BIN_EXE_dyknow-cu");
    let run = |executor: &str| {
        std::process::Command::new(program)
            .arg("dyknow/signal")
            .env("DYKNOW_CU", "orphan")
            .env("DYKNOW_CONNECT", &endpoint)
            .env("DYKNOW_OUTPUTS", "out")
            .env("DYKNOW_EXECUTOR_PROCESS", executor)
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("dyknow-cu starts")
    };
    // The "executor": a process that is not the CU's parent (this test is).
    let mut executor = std::process::Command::new("sleep")
        .arg("60")
        .spawn()
        .expect("sleep starts");
    let identity = dyknow_cu::process_identity(executor.id()).expect("/proc");
    let mut cu = run(&identity);
    // It runs while the executor does.
    std::thread::sleep(Duration::from_millis(600));
    assert!(cu.try_wait().expect("wait").is_none(), "exited early");
    executor.kill().expect("kill");
    executor.wait().expect("reaped");
    let deadline = Instant::now() + Duration::from_secs(10);
    let status = loop {
        if let Some(status) = cu.try_wait().expect("wait") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = cu.kill();
            panic!("the CU outlived its executor's process by 10 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(2), "orphaned");
    // Gone before the CU starts: it exits at once.
    let mut late = run(&identity);
    let started = Instant::now();
    let status = loop {
        if let Some(status) = late.try_wait().expect("wait") {
            break status;
        }
        assert!(started.elapsed() < Duration::from_secs(10), "it ran");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(status.code(), Some(2));
}

/// A control request that reaches a process CU the moment its liveliness token appears (as
/// the executor's first bind does) is answered, not refused as "still starting": the token is
/// declared a moment before the CU is ready, and a refused bind failed the spawn (a user
/// audit saw 3 spawns in 30 fail so).
#[test]
fn a_process_cu_answers_a_request_sent_as_soon_as_its_token_appears() {
    use dyknow_cu::protocol::{ControlReply, ControlRequest};
    let (session, endpoint) = session();
    let program = env!("CARGO_BIN_EXE_dyknow-cu");
    let namespace = Namespace::default();
    for round in 0..20 {
        let name = format!("early-{round}");
        let (tx, rx) = mpsc::channel::<Result<ControlReply, String>>();
        let asking = session.clone();
        let control = namespace.cu_control(&name);
        let _watch = session
            .liveliness()
            .declare_subscriber(namespace.cu_token(&name))
            .callback(move |token| {
                if token.kind() != zenoh::sample::SampleKind::Put {
                    return;
                }
                let answer = tx.clone();
                let request = serde_json::to_vec(&ControlRequest::Statistics).unwrap_or_default();
                let sent = asking
                    .get(control.clone())
                    .payload(request)
                    .timeout(Duration::from_secs(10))
                    .callback(move |reply| {
                        let _ = answer.send(match reply.result() {
                            Ok(s) => serde_json::from_slice(&s.payload().to_bytes())
                                .map_err(|e| e.to_string()),
                            Err(e) => {
                                Err(String::from_utf8_lossy(&e.payload().to_bytes()).into_owned())
                            }
                        });
                    })
                    .wait();
                if let Err(e) = sent {
                    let _ = tx.send(Err(e.to_string()));
                }
            })
            .wait()
            .expect("a liveliness subscriber");
        let mut cu = std::process::Command::new(program)
            .arg("dyknow/relay")
            .env("DYKNOW_CU", &name)
            .env("DYKNOW_CONNECT", &endpoint)
            .env("DYKNOW_INPUTS", "i")
            .env("DYKNOW_OUTPUTS", "o")
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("dyknow-cu starts");
        let reply = rx.recv_timeout(Duration::from_secs(20));
        let _ = cu.kill();
        let _ = cu.wait();
        let reply = reply.expect("an answer to the first request");
        let reply = reply.expect("a control reply");
        assert!(reply.ok, "round {round}: refused: {:?}", reply.error);
    }
}

/// A hung process CU (`kill -STOP`) is noticed after the executor's lease, which the executor
/// hands its process CUs (`DYKNOW_ZENOH_LEASE_MS`): its link goes when the lease the CU
/// declared runs out. Before, the CU declared Zenoh's default 10 s whatever the executor's
/// `--zenoh-lease-ms` was (a user audit saw 9.9 s with 2 s).
#[test]
fn a_hung_process_cu_is_noticed_after_the_executors_lease() {
    let (session, endpoint) = session();
    let mut config = ExecutorConfig::new("t-lease", Namespace::default(), vec![endpoint]);
    config.zenoh_lease_ms = Some(1000);
    let executor = Executor::start(&session, config).expect("an executor");
    let (crashes, _e) = events(&session);
    let pid = spawn_process_relay(&executor, "hung");
    let signal = |s: &str| {
        std::process::Command::new("kill")
            .args([s, &pid.to_string()])
            .status()
            .expect("kill");
    };
    // Asked while the process hangs, the executor answers `info` at once with every CU, the
    // hung one with the statistics it gave last (before, the hung process held `info` up for
    // its 5 s control timeout).
    let statistics = |info: &dyknow_cu::protocol::ExecutorInfo| {
        info.cus
            .iter()
            .find(|c| c.cu == "hung")
            .map(|c| c.statistics.ports.len())
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    while statistics(&executor.info()) != Some(2) {
        assert!(
            Instant::now() < deadline,
            "no statistics of the CU's two ports"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    signal("-STOP");
    let stopped = Instant::now();
    let info = executor.info();
    let answered = stopped.elapsed();
    assert!(
        answered < Duration::from_secs(2),
        "info took {answered:?} with one CU hung"
    );
    assert_eq!(statistics(&info), Some(2), "the last statistics: {info:?}");
    let seen = loop {
        match crashes.recv_timeout(Duration::from_secs(20)) {
            Ok(Event::CuCrashed { cu, .. }) if cu == "hung" => break stopped.elapsed(),
            Ok(_) => continue,
            Err(e) => {
                signal("-CONT");
                panic!("no crash event for the hung CU: {e}");
            }
        }
    };
    signal("-CONT");
    signal("-9");
    assert!(
        seen < Duration::from_secs(4),
        "a hung CU was noticed after {seen:?} with a lease of 1 s"
    );
    executor.shutdown();
}

/// A process CU runs in a process group of its own, and stopping it stops what it started: a
/// wrapper script's background child (a user audit found a wrapper's `sleep` running on after
/// its CU was destroyed). The wrapper also makes the CU's work a child's: its CPU time counts.
#[test]
fn stopping_a_process_cu_stops_what_it_started() {
    let (session, endpoint) = session();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("t-group", Namespace::default(), vec![endpoint]),
    )
    .expect("an executor");
    let marker = std::env::temp_dir().join(format!("dyknow-wrapper-{}.pid", std::process::id()));
    let (dir, script) = script(
        "wrapper",
        &format!(
            "#!/bin/sh\nsleep 1000 &\necho $! > {}\nexec {} dyknow/relay\n",
            marker.display(),
            env!("CARGO_BIN_EXE_dyknow-cu")
        ),
    );
    spawn_source(&executor, "wrapped", &script.display().to_string());
    let sleep: u32 = std::fs::read_to_string(&marker)
        .expect("the wrapper wrote its child's pid")
        .trim()
        .parse()
        .expect("a pid");
    let alive = |pid: u32| {
        std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| {
            s.rsplit_once(')')
                .is_some_and(|(_, r)| !r.trim_start().starts_with('Z'))
        })
    };
    assert!(alive(sleep));
    apply(
        &executor,
        vec![CuAction::Destroy {
            cu: "wrapped".into(),
        }],
    );
    let deadline = Instant::now() + Duration::from_secs(10);
    while alive(sleep) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(!alive(sleep), "the wrapper's child {sleep} runs on");
    executor.shutdown();
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_file(&marker);
}

/// `dyknow-cu` run by hand, without the `DYKNOW_CU` an executor sets, is a usage error (exit
/// 64, as `dyknow cu`), not the protocol's crash status 1 it exited with; an unknown builtin
/// and no argument are too.
#[test]
fn dyknow_cu_run_by_hand_is_a_usage_error() {
    let program = env!("CARGO_BIN_EXE_dyknow-cu");
    for (args, says) in [
        (&["dyknow/relay"][..], "DYKNOW_CU"),
        (&["dyknow/nothing"][..], "no builtin"),
        (&[][..], "usage"),
    ] {
        let out = std::process::Command::new(program)
            .args(args)
            .env_remove("DYKNOW_CU")
            .output()
            .expect("dyknow-cu runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(64), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

/// The labour of a process CU started through a wrapper (a shell that does not `exec`) counts
/// what the wrapper's children used before the CU announced itself (a user audit saw a wrapped
/// CU's labour at 0.7 ms against 42 ms for the same CU started directly: the planner took it
/// for about sixty times cheaper to start).
#[test]
fn the_labour_of_a_wrapped_process_cu_counts_its_children() {
    let (session, endpoint) = session();
    let executor = Executor::start(
        &session,
        ExecutorConfig::new("t-labour", Namespace::default(), vec![endpoint]),
    )
    .expect("an executor");
    let (events, _sub) = events(&session);
    // A child that works for a while, then becomes the CU; the wrapper waits for it.
    let (dir, script) = script(
        "labour",
        &format!(
            "#!/bin/sh\n(i=0; while [ $i -lt 300000 ]; do i=$((i+1)); done; exec {} dyknow/relay)\n",
            env!("CARGO_BIN_EXE_dyknow-cu")
        ),
    );
    spawn_source(&executor, "wrapped", &script.display().to_string());
    let labour = loop {
        match events.recv_timeout(Duration::from_secs(30)) {
            Ok(Event::Running {
                cu, labour_cpu_ms, ..
            }) if cu == "wrapped" => break labour_cpu_ms,
            Ok(_) => {}
            Err(e) => panic!("no running event: {e}"),
        }
    };
    assert!(
        labour >= 50.0,
        "the child's counting is labour: {labour} ms"
    );
    executor.shutdown();
    let _ = std::fs::remove_dir_all(&dir);
}

/// A command line that names no program says what may have been meant: shell quotes, which
/// `dkros:hasSource` does not have (single quotes, backslashes), or a path holding spaces
/// written without double quotes.
#[test]
fn a_command_line_that_names_no_program_hints_at_quoting() {
    let why = |source: &str| {
        dyknow_executor::check(&implementation("process", source, &[], &[], json!({})))
            .why
            .unwrap_or_default()
    };
    let single = why("python3x '/tmp/no such dir/cu.py'");
    assert!(
        single.contains("not on PATH") && single.contains("double quotes only"),
        "{single}"
    );
    let single = why("'/tmp/no such dir/cu.py'");
    assert!(single.contains("double quotes only"), "{single}");
    let spaces = why("/tmp/no such dir/cu.py --x");
    assert!(
        spaces.contains("not an executable file") && spaces.contains("written in double quotes"),
        "{spaces}"
    );
    let plain = why("/tmp/no-such-program");
    assert!(!plain.contains("quote"), "{plain}");
    assert!(
        dyknow_executor::check(&implementation(
            "process",
            "sh -c \"exit 0\"",
            &[],
            &[],
            json!({})
        ))
        .runnable
    );
}
