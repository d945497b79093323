//! Pipelines that really run (`executors.md`): `dyknow serve` with its embedded executor and
//! stand-alone `dyknow executor` processes, builtin and process CUs (one in Python), crashes
//! detected without any client report and repaired, measured costs steering the next review,
//! and nothing left running after SIGTERM.
#![cfg(feature = "rocksdb")]
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use dyknow_cu::zenoh::Wait;
use dyknow_cu::{Namespace, Sample};
use serde_json::{Value, json};

mod support;

use support::*;

#[test]
fn a_chain_of_builtin_and_process_cus_computes_and_crashes_are_repaired_unreported() {
    let service = Service::start(&[]);
    let process_map = format!("{BIN} cu dyknow/map");
    for spec in [
        counter(&[("period_ms", "20")]),
        tf(
            "guard",
            "nodelet",
            "dyknow/fault",
            &[],
            &[("in", "Count")],
            &[("out", "Guarded")],
        ),
        tf(
            "tenfold",
            "process",
            &process_map,
            &[("scale", "10")],
            &[("in", "Guarded")],
            &[("out", "Tenfold")],
        ),
    ] {
        service.post("/transformations", &spec.turtle());
    }
    let session = service.session();
    let out = Listener::new(&session, "/tenfold");
    service.post("/targets", &target("tenfold-q", "/tenfold", "Tenfold"));
    // The values the chain computes: the counter, times ten, consecutive.
    let (_, first) = out.next();
    let (_, second) = out.next();
    let a = first.value.as_i64().unwrap();
    assert_eq!(a % 10, 0, "{a} is a counter value times ten");
    assert_eq!(second.value.as_i64(), Some(a + 10));
    assert!(second.t >= first.t);

    let guard = service.cu_of("guard").unwrap();
    let tenfold = service.cu_of("tenfold").unwrap();
    let detail = service.get(&format!("/cus/{}", tenfold["name"].as_str().unwrap()));
    assert_eq!(detail["executor"], "local");
    assert_eq!(detail["state"], "running");
    assert!(
        detail["statistics"]["ports"]["in"]["messages"]
            .as_u64()
            .unwrap()
            >= 1
    );
    assert!(
        detail["statistics"]["ports"]["out"]["last_t"]
            .as_i64()
            .is_some()
    );
    let executors = service.get("/executors");
    assert_eq!(executors[0]["name"], "local");
    assert_eq!(executors[0]["present"], true);
    assert_eq!(executors[0]["cus"].as_array().unwrap().len(), 3);
    // The list shows each CU's executor and state too, and so does the change set that
    // spawned them.
    for cu in service.get("/cus").as_array().unwrap() {
        assert_eq!(cu["executor"], "local", "{cu}");
        assert_eq!(cu["state"], "running", "{cu}");
    }
    let spawned = service
        .change_sets()
        .into_iter()
        .find(|c| c["cause"]["kind"] == "target-added")
        .unwrap();
    assert_eq!(spawned["status"], "applied", "{spawned}");
    assert_eq!(
        spawned["cus"][tenfold["name"].as_str().unwrap()],
        json!({"executor": "local", "state": "running"}),
        "{spawned}"
    );

    // A panicking builtin CU: detected by the executor, repaired by a review.
    let guard_name = guard["name"].as_str().unwrap().to_owned();
    let channel = guard["inputs"]["in"].as_str().unwrap();
    let crashed_at = Instant::now();
    session
        .put(
            Namespace::default().channel(channel).unwrap(),
            Sample::now(json!({"fault": "panic"})).to_bytes(),
        )
        .wait()
        .unwrap();
    let repair = crash_change_set(&service, &guard_name);
    assert_eq!(repair["status"], "applied");
    let new_guard = service.cu_of("guard").unwrap();
    assert_ne!(new_guard["name"], guard["name"]);
    assert_eq!(
        repair["cus"][new_guard["name"].as_str().unwrap()]["state"],
        "running",
        "{repair}"
    );
    let flowing = out.first_after(crashed_at);
    eprintln!(
        "panicked builtin CU: stream flowing again after {:?}",
        flowing - crashed_at
    );
    assert_eq!(service.status(&format!("/cus/{guard_name}")), 404);

    // kill -9 of a process CU.
    let tenfold_name = tenfold["name"].as_str().unwrap().to_owned();
    let pid = detail["pid"].as_u64().unwrap();
    let killed_at = kill_and_repair(&service, &tenfold_name, pid);
    let flowing = out.first_after(killed_at);
    eprintln!(
        "kill -9ed process CU: stream flowing again after {:?}",
        flowing - killed_at
    );
    let replacement = service.cu_of("tenfold").unwrap();
    let replacement = service.get(&format!("/cus/{}", replacement["name"].as_str().unwrap()));
    let new_pid = replacement["pid"].as_u64().unwrap();
    assert_ne!(new_pid, pid);
    assert!(alive(new_pid));

    // SIGTERM: the service stops every CU and child process.
    drop(out);
    let status = service.sigterm();
    assert!(status.success(), "{status}");
    assert!(!alive(new_pid), "process CU {new_pid} survived the service");
}

/// A counter (`dyknow/signal` every `period_ms`) and an echo (`dyknow/relay`) of its counts.
fn post_counter_echo(service: &Service, period_ms: &str) {
    for spec in [
        counter(&[("period_ms", period_ms)]),
        tf(
            "echo",
            "builtin",
            "dyknow/relay",
            &[],
            &[("in", "Count")],
            &[("out", "Echoed")],
        ),
    ] {
        service.post("/transformations", &spec.turtle());
    }
}

/// A crash a client reports of a CU its executor still runs (hung, say, or the client is
/// wrong): the model drops it and the executor stops it, so that its replacement is not a
/// second publisher on the channel. (Before, it ran on, unknown to the model, until its
/// executor reconnected.)
#[test]
fn a_cu_a_client_reports_crashed_is_stopped_where_it_still_runs() {
    let service = Service::start(&[]);
    post_counter_echo(&service, "20");
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    let echo = eventually("the echo to run", Duration::from_secs(30), || {
        let cu = service.cu_of("echo")?;
        (cu["state"] == "running").then(|| cu["name"].as_str().unwrap().to_owned())
    });
    // What the executor itself runs (its `info` service), not where the manager thinks CUs
    // are.
    let session = service.session();
    let key = Namespace::default().executor_service("local", "info");
    let hosted = |_: &Service| -> Vec<String> {
        let replies = session.get(&key).wait().unwrap();
        let reply = replies
            .recv_timeout(Duration::from_secs(10))
            .unwrap()
            .expect("an answer");
        let info: Value =
            serde_json::from_slice(&reply.result().unwrap().payload().to_bytes()).unwrap();
        let mut cus: Vec<String> = info["cus"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["cu"].as_str().unwrap().to_owned())
            .collect();
        cus.sort();
        cus
    };
    assert!(hosted(&service).contains(&echo));
    let mut r = agent()
        .post(&format!("{}/perturbations", service.url))
        .header("Content-Type", "application/json")
        .send(json!({"kind": "cu-crashed", "cu": echo}).to_string())
        .unwrap();
    assert_eq!(
        r.status().as_u16(),
        202,
        "{}",
        r.body_mut().read_to_string().unwrap()
    );
    // Repaired by a new echo, and the executor runs what the model has, not the old one too.
    let (model, running) = eventually(
        "the executor to run the model's CUs",
        Duration::from_secs(30),
        || {
            let cus = service.get("/cus");
            let cus = cus.as_array()?;
            let echo_now = cus.iter().find(|c| c["transformation"] == "echo")?;
            if echo_now["name"] == echo.as_str() || echo_now["state"] != "running" {
                return None;
            }
            let mut model: Vec<String> = cus
                .iter()
                .map(|c| c["name"].as_str().unwrap().to_owned())
                .collect();
            model.sort();
            let running = hosted(&service);
            (running == model).then_some((model, running))
        },
    );
    assert!(!running.contains(&echo), "{running:?}");
    assert_eq!(model.len(), 2, "{model:?}");
}

/// Executor names are unique: a second `local` (or any name present) is refused at start,
/// and the first one, with its CUs, stays present. (Before, the second was let in, and its
/// leaving made the service take `local` for gone for good: its CUs crashed in the model,
/// nothing runnable.)
#[test]
fn a_second_executor_of_a_present_name_is_refused() {
    let service = Service::start(&[]);
    post_counter_echo(&service, "20");
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    let before = eventually("two running CUs", Duration::from_secs(30), || {
        let cus = service.get("/cus");
        let running = cus.as_array()?.iter().all(|c| c["state"] == "running");
        (cus.as_array()?.len() == 2 && running).then_some(cus)
    });
    // (Killed on drop: were it let in, it would run until stopped.)
    let mut second = Killed(
        Command::new(BIN)
            .args(["executor", "--name", "local", "--connect", &service.zenoh])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let status = eventually("the second local to exit", Duration::from_secs(30), || {
        second.0.try_wait().unwrap()
    });
    let mut err = String::new();
    std::io::Read::read_to_string(&mut second.0.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(2), "{err}");
    assert!(
        err.contains("an executor named local is present already"),
        "{err}"
    );
    let executors = service.get("/executors");
    assert_eq!(executors[0]["name"], "local", "{executors}");
    assert_eq!(executors[0]["present"], true, "{executors}");
    // The same CUs, where and as they were (their upkeep estimate may have learned a
    // measurement meanwhile).
    let placed = |cus: Value| -> Vec<Value> {
        cus.as_array()
            .unwrap()
            .iter()
            .map(|c| {
                json!([
                    c["name"],
                    c["transformation"],
                    c["inputs"],
                    c["outputs"],
                    c["executor"],
                    c["state"]
                ])
            })
            .collect()
    };
    assert_eq!(placed(service.get("/cus")), placed(before));
    assert!(
        service
            .change_sets()
            .iter()
            .all(|c| c["cause"]["kind"] != "cu-crashed")
    );
}

/// Two executors of one name meet when a link comes up (one started cut off, so its start
/// could not be refused): the one that started later steps down, exits 2 and says why; the
/// manager takes the CUs it ran for lost and replans them on the earlier one, which now holds
/// the name. (Before, both answered to the name: the manager never noticed the second, and a
/// change set could be applied twice.)
#[test]
fn a_later_executor_of_a_present_name_steps_down_and_its_cus_are_replanned() {
    let service = Service::start(&["--no-executor"]);
    post_counter_echo(&service, "20");
    // The earlier twin starts cut off: nothing answers at its endpoint yet.
    let gap = format!("tcp/127.0.0.1:{}", free_port());
    let twin = |connect: &str, marker: &str| {
        let mut child = Command::new(BIN)
            .args(["executor", "--name", "twin", "--connect", connect])
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (_, tail) = wait_for_line_keeping(&mut child, marker);
        (Killed(child), tail)
    };
    let (mut early, _) = twin(&gap, "does not answer yet");
    let (mut late, late_said) = twin(&service.zenoh, "connected to");
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    let session = service.session();
    let out = Listener::new(&session, "/echoed");
    out.next();
    let names = |cus: &Value| -> Vec<String> {
        (cus.as_array().unwrap().iter())
            .map(|c| c["name"].as_str().unwrap().to_owned())
            .collect()
    };
    let before = names(&service.get("/cus"));
    assert_eq!(before.len(), 2, "{before:?}");
    let late_instance = service.get("/executors")[0]["instance"].clone();
    assert!(late_instance.is_string(), "{late_instance}");

    // The link comes up: a router on the earlier twin's endpoint, linked to the manager's.
    let bridge = dyknow_cu::router_config(
        std::slice::from_ref(&gap),
        std::slice::from_ref(&service.zenoh),
    )
    .unwrap();
    let _bridge = dyknow_cu::zenoh::open(bridge).wait().unwrap();
    let status = eventually(
        "the later twin to step down",
        Duration::from_secs(30),
        || late.0.try_wait().unwrap(),
    );
    let said = || {
        late_said
            .lock()
            .unwrap()
            .iter()
            .cloned()
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(status.code(), Some(2), "{}", said());
    eventually(
        "the later twin's last words",
        Duration::from_secs(10),
        || said().contains("(standard error closed)").then_some(()),
    );
    assert!(
        said().contains("stepped down: another executor named twin"),
        "{}",
        said()
    );
    let stepped_down = Instant::now();
    out.first_after(stepped_down);
    let cus = eventually(
        "the CUs replanned on the earlier twin",
        Duration::from_secs(30),
        || {
            let cus = service.get("/cus");
            let all = cus.as_array()?;
            (all.len() == 2 && all.iter().all(|c| c["state"] == "running")).then_some(cus)
        },
    );
    let executors = service.get("/executors");
    assert_eq!(executors.as_array().unwrap().len(), 1, "{executors}");
    assert_eq!(executors[0]["present"], true, "{executors}");
    assert_eq!(
        executors[0]["cus"].as_array().unwrap().len(),
        2,
        "{executors}"
    );
    // The change set that replanned them says why: the CUs the later twin ran crashed.
    let repair = service
        .change_sets()
        .into_iter()
        .find(|c| c["cause"]["kind"] == "cu-crashed")
        .unwrap_or_else(|| panic!("no change set names the crash: {:?}", service.change_sets()));
    let named: Vec<&str> = std::iter::once(&repair["cause"]["cu"])
        .chain(repair["cause"]["also"].as_array().into_iter().flatten())
        .filter_map(Value::as_str)
        .collect();
    assert!(
        before.iter().all(|cu| named.contains(&cu.as_str())),
        "{before:?} are not all named in {}",
        repair["cause"]
    );
    let early_instance = &executors[0]["instance"];
    assert!(
        early_instance.is_string() && *early_instance != late_instance,
        "the manager follows the earlier twin: {early_instance} after {late_instance}"
    );
    assert!(
        names(&cus).iter().all(|cu| !before.contains(cu)),
        "the later twin's CUs stopped with it, so they are replanned, not adopted: {before:?} then {cus}"
    );
    assert!(
        early.0.try_wait().unwrap().is_none(),
        "the earlier twin runs on"
    );
}

#[test]
fn stand_alone_executors_join_and_vanish_and_their_cus_are_replanned() {
    // Executors gone for 3 s are forgotten (checked at the end).
    let service = Service::start(&["--no-executor", "--forget-executors-after", "3"]);
    assert_eq!(service.get("/executors"), json!([]));
    post_counter_echo(&service, "20");
    let echo = service.get("/transformations/echo");
    assert_eq!(echo["runnable"], false);
    assert!(
        echo["why"].as_str().unwrap().contains("no executor"),
        "{echo}"
    );
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    let session = service.session();
    let out = Listener::new(&session, "/echoed");
    let start = |name: &str| executor(&service, name);
    let mut first = start("ext1");
    // The echo relays what the counter counts: consecutive values.
    let (_, a) = out.next();
    let (_, b) = out.next();
    assert_eq!(
        b.value.as_u64(),
        a.value.as_u64().map(|a| a + 1),
        "{a:?} then {b:?}"
    );
    assert!(b.t >= a.t);
    let executors = service.get("/executors");
    assert_eq!(executors[0]["name"], "ext1");
    assert_eq!(executors[0]["cus"].as_array().unwrap().len(), 2);
    assert_eq!(service.get("/transformations/echo")["runnable"], true);

    // kill -9 of the whole executor: its CUs are lost, what only it ran is unavailable.
    first.0.kill().unwrap();
    first.0.wait().unwrap();
    eventually(
        "the executor's CUs to be lost",
        Duration::from_secs(30),
        || (service.get("/cus") == json!([])).then_some(()),
    );
    assert_eq!(service.get("/executors")[0]["present"], false);
    assert_eq!(service.get("/environment")["valid"], false);
    let lost_at = Instant::now();
    let mut second = start("ext2");
    let flowing = out.first_after(lost_at);
    eprintln!(
        "executor replaced: stream flowing again {:?} after the new one started",
        flowing - lost_at
    );
    sigterm(&second.0);
    let status = wait_exit(&mut second.0);
    assert!(status.success(), "{status}");
    eventually("the executor to be gone", Duration::from_secs(30), || {
        (service.get("/cus") == json!([])).then_some(())
    });
    // Both absent, then forgotten.
    eventually(
        "the executors to be forgotten",
        Duration::from_secs(30),
        || (service.get("/executors") == json!([])).then_some(()),
    );
}

#[test]
fn an_executor_that_vanishes_mid_change_set_fails_it_and_its_cus_count_as_crashed() {
    let service = Service::start(&["--no-executor"]);
    post_counter_echo(&service, "20");
    // A process CU that never announces itself: its executor waits for it (up to its start
    // timeout) while applying the change set, and dies meanwhile.
    service.post(
        "/transformations",
        &tf(
            "mute",
            "process",
            "sleep 60",
            &[],
            &[("in", "Count")],
            &[("out", "Muted")],
        )
        .turtle(),
    );
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    let session = service.session();
    let out = Listener::new(&session, "/echoed");
    let mut executor = Command::new(BIN)
        .args(["executor", "--name", "doomed", "--connect", &service.zenoh])
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_line(&mut executor, "connected to");
    let mut executor = Killed(executor);
    out.next();
    // The stream flows as soon as the executor has started the CUs; the model lists them once
    // the manager has heard the executor's answer, a moment later.
    let hosted: Vec<String> = eventually("both CUs in the model", Duration::from_secs(30), || {
        let cus = service.get("/cus");
        let names: Vec<String> = cus
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["name"].as_str().unwrap().to_owned())
            .collect();
        (names.len() == 2).then_some(names)
    });

    // The change set spawning `mute` is under way: the executor has started `sleep`.
    service.post("/targets", &target("muted", "/muted", "Muted"));
    let pid = executor.0.id();
    let sleeper = eventually(
        "the executor to start the process CU",
        Duration::from_secs(30),
        || {
            children(pid).into_iter().find(|c| {
                std::fs::read_to_string(format!("/proc/{c}/comm"))
                    .is_ok_and(|n| n.trim() == "sleep")
            })
        },
    );
    let killed_at = Instant::now();
    executor.0.kill().unwrap();
    executor.0.wait().unwrap();
    // `sleep` knows nothing of DyKnow, so it does not notice its executor died (a CU written
    // with the SDK exits then): the test cleans it up.
    Command::new("kill")
        .args(["-9", &sleeper.to_string()])
        .status()
        .unwrap();

    let failed = eventually(
        "the change set to be reported failed",
        Duration::from_secs(60),
        || {
            service
                .change_sets()
                .into_iter()
                .find(|c| c["cause"]["kind"] == "target-added" && c["cause"]["target"] == "muted")
        },
    );
    eprintln!(
        "executor killed mid-change-set: reported failed after {:?}",
        killed_at.elapsed()
    );
    assert_eq!(failed["status"], "failed", "{failed}");
    let mute = failed["actions"]
        .as_array()
        .unwrap()
        .iter()
        .find_map(|a| (a["action"] == "spawn").then(|| a["cu"].clone()))
        .unwrap();
    assert!(
        failed["failures"]
            .as_array()
            .unwrap()
            .iter()
            .any(|f| f["cu"] == mute),
        "{failed}"
    );
    // The reason says what happened: the executor went away (it said "did not answer within
    // 15 s", a second after the kill).
    assert!(
        failed["failures"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f["reason"]
                .as_str()
                .is_some_and(|r| r.contains("went away before it answered"))),
        "{failed}"
    );
    assert_eq!(failed["cus"][mute.as_str().unwrap()]["state"], "crashed");
    // Its CUs count as crashed: none is left in the model, nothing claims to run them, and
    // with no executor left the environment is invalid until one joins.
    eventually(
        "the executor's CUs to be lost",
        Duration::from_secs(30),
        || (service.get("/cus") == json!([])).then_some(()),
    );
    assert_eq!(service.get("/executors")[0]["present"], false);
    for cu in &hosted {
        assert_eq!(service.status(&format!("/cus/{cu}")), 404);
    }
    assert_eq!(service.get("/environment")["valid"], false);
}

#[test]
fn implementations_that_cannot_run_are_never_planned_and_failed_starts_back_off() {
    let service = Service::start(&[]);
    let fails_at_start = format!("{BIN} cu dyknow/fault");
    for spec in [
        tf(
            "ghost",
            "builtin",
            "dyknow/nope",
            &[],
            &[],
            &[("out", "Ghost")],
        ),
        tf(
            "missing",
            "process",
            "/nonexistent/program --x",
            &[],
            &[],
            &[("out", "Missing")],
        ),
        tf(
            "flaky",
            "process",
            &fails_at_start,
            &[("after", "0")],
            &[],
            &[("out", "Flaky")],
        ),
    ] {
        service.post("/transformations", &spec.turtle());
    }
    let ghost = service.get("/transformations/ghost");
    assert_eq!(ghost["runnable"], false);
    assert!(
        ghost["why"].as_str().unwrap().contains("dyknow/nope"),
        "{ghost}"
    );
    let missing = service.get("/transformations/missing");
    assert_eq!(missing["runnable"], false);
    assert!(
        missing["why"]
            .as_str()
            .unwrap()
            .contains("/nonexistent/program"),
        "{missing}"
    );
    // A Spawn of one says why it cannot run, rather than that it does not exist.
    let mut r = agent()
        .post(&format!("{}/cus", service.url))
        .header("Content-Type", "application/json")
        .send(json!({"transformation": "ghost"}).to_string().as_bytes())
        .unwrap();
    let status = r.status().as_u16();
    let refusal: Value = serde_json::from_str(&r.body_mut().read_to_string().unwrap()).unwrap();
    assert_eq!(status, 422, "{refusal}");
    assert!(
        refusal["error"]
            .as_str()
            .unwrap()
            .contains("cannot run now")
            && refusal["error"].as_str().unwrap().contains("dyknow/nope"),
        "{refusal}"
    );
    service.post("/targets", &target("ghost-q", "/ghost", "Ghost"));
    service.post("/targets", &target("missing-q", "/missing", "Missing"));
    assert_eq!(service.get("/environment")["valid"], false);
    // A process that exits at start: the spawn fails, the change set says so, and the
    // transformation is tried again only after a growing back-off, its labour estimate up.
    service.post("/targets", &target("flaky-q", "/flaky", "Flaky"));
    let failed = eventually("a failed change set", Duration::from_secs(30), || {
        service
            .change_sets()
            .into_iter()
            .find(|c| c["status"] == "failed")
    });
    assert!(
        failed["failures"][0]["reason"]
            .as_str()
            .unwrap()
            .contains("before it ran"),
        "{failed}"
    );
    let window = Instant::now();
    while window.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(100));
    }
    let all = service.change_sets();
    let failures = all.iter().filter(|c| c["status"] == "failed").count();
    assert!(
        all.iter().all(|c| c["actions"]
            .as_array()
            .unwrap()
            .iter()
            .all(|a| { a["transformation"] != "ghost" && a["transformation"] != "missing" })),
        "a transformation no executor can run was planned"
    );
    assert!(
        (1..=8).contains(&failures),
        "{failures} failed starts in about 3 s: a crash loop"
    );
    let statistics = service.get("/statistics");
    let labour = statistics["transformations"]["flaky"]["labour"]
        .as_f64()
        .unwrap();
    assert!(
        labour > 1.0,
        "a failed start raises the labour estimate: {statistics}"
    );
    // A program installed after its spec was posted: the executor's "no" is asked again after
    // 5 s (before, it was kept until the executor reappeared, re-posting the spec or not).
    let dir = std::env::temp_dir().join(format!("dyknow-later-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let program = dir.join("later.sh");
    let later = tf(
        "later",
        "process",
        program.to_str().unwrap(),
        &[],
        &[],
        &[("out", "Later")],
    );
    service.post("/transformations", &later.turtle());
    assert_eq!(service.get("/transformations/later")["runnable"], false);
    std::fs::write(
        &program,
        format!("#!/bin/sh\nexec {BIN} cu dyknow/signal\n"),
    )
    .unwrap();
    std::fs::set_permissions(
        &program,
        std::os::unix::fs::PermissionsExt::from_mode(0o755),
    )
    .unwrap();
    eventually(
        "the installed program to be found",
        Duration::from_secs(20),
        || (service.get("/transformations/later")["runnable"] == true).then_some(()),
    );
    service.post("/transformations", &later.turtle());
    service.post("/targets", &target("later-q", "/later", "Later"));
    eventually("a CU of it to run", Duration::from_secs(30), || {
        service
            .get("/cus")
            .as_array()
            .unwrap()
            .iter()
            .any(|c| c["transformation"] == "later" && c["state"] == "running")
            .then_some(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn measured_costs_make_the_next_review_choose_the_cheaper_transformation() {
    // The stable interval is H × time unit = 8 × 0.25 s = 2 s.
    let service = Service::start(&["--time-unit", "0.25", "--horizon", "8"]);
    let mut heavy = tf(
        "heavy",
        "builtin",
        "dyknow/burn",
        &[("work", "3000000")],
        &[("in", "Count")],
        &[("out", "Echoed")],
    );
    heavy.upkeep = Some(0.01);
    let mut light = tf(
        "light",
        "builtin",
        "dyknow/relay",
        &[],
        &[("in", "Count")],
        &[("out", "Echoed")],
    );
    light.upkeep = Some(0.2);
    for spec in [counter(&[("period_ms", "10")]), heavy, light] {
        service.post("/transformations", &spec.turtle());
    }
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    let first = eventually("the first change set", Duration::from_secs(30), || {
        service.change_sets().into_iter().next()
    });
    let spawns = |c: &Value, t: &str| {
        c["actions"]
            .as_array()
            .unwrap()
            .iter()
            .any(|a| a["action"] == "spawn" && a["transformation"] == t)
    };
    assert!(
        spawns(&first, "heavy"),
        "by its posted cost, heavy is the cheaper: {first}"
    );
    let switch = eventually(
        "a review switching to light",
        Duration::from_secs(60),
        || {
            service
                .change_sets()
                .into_iter()
                .find(|c| spawns(c, "light"))
        },
    );
    assert!(
        switch["actions"]
            .as_array()
            .unwrap()
            .iter()
            .any(|a| a["action"] == "destroy"),
        "{switch}"
    );
    let statistics = service.get("/statistics");
    let measured = &statistics["transformations"]["heavy"]["learned_upkeep"];
    assert!(
        measured["observations"].as_u64().unwrap() >= 1,
        "{statistics}"
    );
    assert!(measured["average"].as_f64().unwrap() > 0.2, "{statistics}");
}

#[test]
fn python_reads_a_channel_and_a_python_cu_computes() {
    let service = Service::start(&[]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/python/scale_cu.py");
    let source = format!("python3 {}", script.display());
    for spec in [
        tf(
            "sevens",
            "builtin",
            "dyknow/signal",
            &[("period_ms", "20"), ("value", "7")],
            &[],
            &[("out", "Seven")],
        ),
        tf(
            "triple",
            "process",
            &source,
            &[("factor", "3")],
            &[("in", "Seven")],
            &[("out", "Tripled")],
        ),
    ] {
        service.post("/transformations", &spec.turtle());
    }
    service.post("/targets", &target("tripled", "/tripled", "Tripled"));
    // A subscriber written with PyPI's eclipse-zenoh parses the samples per the contract.
    // (Undeclared and closed before exit: an open session keeps the interpreter alive.)
    let reader = r#"
import json, sys, threading, zenoh
config = zenoh.Config()
config.insert_json5("mode", '"client"')
config.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
config.insert_json5("scouting/multicast/enabled", "false")
got, done = [], threading.Event()
def on(sample):
    if done.is_set():
        return
    assert str(sample.encoding).startswith("application/json"), sample.encoding
    message = json.loads(sample.payload.to_bytes())
    assert isinstance(message["t"], int)
    got.append(message["value"])
    if len(got) == 3:
        done.set()
session = zenoh.open(config)
sub = session.declare_subscriber("dyknow/channel/tripled", on)
ok = done.wait(60)
sub.undeclare()
session.close()
if not ok:
    sys.exit("no samples")
print("\n".join(json.dumps(v) for v in got[:3]))
"#;
    let out = Command::new("python3")
        .args(["-c", reader, &service.zenoh])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(String::from_utf8(out.stdout).unwrap().trim(), "21\n21\n21");
    let triple = service.cu_of("triple").unwrap();
    let detail = service.get(&format!("/cus/{}", triple["name"].as_str().unwrap()));
    assert_eq!(detail["state"], "running");
    assert!(
        detail["statistics"]["ports"]["in"]["messages"]
            .as_u64()
            .unwrap()
            >= 3,
        "{detail}"
    );
}

#[test]
fn set_config_rewires_make_before_break_and_refuses_what_would_break_the_environment() {
    // A long stable interval: no scheduled review rewires the input SetConfig leaves unfed.
    let service = Service::start(&["--time-unit", "100"]);
    post_counter_echo(&service, "10");
    let session = service.session();
    let out = Listener::new(&session, "/echoed");
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    out.next();
    let echo = service.cu_of("echo").unwrap();
    let name = echo["name"].as_str().unwrap().to_owned();
    let counter_channel = service.cu_of("counter").unwrap()["outputs"]["out"]
        .as_str()
        .unwrap()
        .to_owned();
    let put = |body: Value| {
        let mut r = agent()
            .put(&format!("{}/cus/{name}/config", service.url))
            .header("Content-Type", "application/json")
            .send(body.to_string().as_bytes())
            .unwrap();
        let text = r.body_mut().read_to_string().unwrap();
        (r.status().as_u16(), text)
    };
    // Refused, nothing changed: not the model, not the history, not the running CU (the
    // self-loop, which only the reasoner refuses, was carried out by the executor before the
    // model refused it, and the CU then read its own output while the model said otherwise).
    let reconfigurations = || {
        service.get(&format!("/cus/{name}"))["statistics"]["reconfigurations"]
            .as_u64()
            .unwrap()
    };
    let before = (
        service.get("/cus"),
        service.change_sets().len(),
        reconfigurations(),
    );
    for (body, needle) in [
        (json!({"inputs": {"nope": "x"}}), "no in port"),
        (
            json!({"outputs": {"out": counter_channel}}),
            "has a publisher",
        ),
        (json!({"inputs": {"in": "a*b"}}), "reserve"),
        (json!({"inputs": {"in": "/echoed"}}), "prp-pdw"),
    ] {
        let (status, text) = put(body);
        assert_eq!(status, 422, "{text}");
        assert!(text.contains(needle), "{text}");
    }
    assert_eq!(put(json!({"bogus": {}})).0, 400);
    assert_eq!(
        (
            service.get("/cus"),
            service.change_sets().len(),
            reconfigurations()
        ),
        before
    );
    // Rewired while samples flow: a sample published once the rebinding is acknowledged
    // arrives.
    for round in 0..10 {
        let channel = format!("manual-{}", round % 2);
        let (status, text) = put(json!({"inputs": {"in": channel}}));
        assert_eq!(status, 200, "{text}");
        let cu: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(cu["inputs"]["in"], channel.as_str());
        session
            .put(
                Namespace::default().channel(&channel).unwrap(),
                Sample::new(round, json!({"round": round})).to_bytes(),
            )
            .wait()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            let (_, sample) = out.next();
            if sample.value == json!({"round": round}) {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "round {round}: the sample was lost"
            );
        }
    }
    let last = service.change_sets().pop().unwrap();
    assert_eq!(last["cause"]["kind"], "manual");
    assert_eq!(last["status"], "applied");
    let detail = service.get(&format!("/cus/{name}"));
    assert!(
        detail["statistics"]["reconfigurations"].as_u64().unwrap() >= 11,
        "{detail}"
    );
}

#[test]
fn a_stand_alone_executor_stops_its_process_cus_on_sigterm() {
    let service = Service::start(&["--no-executor"]);
    let process_relay = format!("{BIN} cu dyknow/relay");
    for spec in [
        counter(&[("period_ms", "20")]),
        tf(
            "pecho",
            "process",
            &process_relay,
            &[],
            &[("in", "Count")],
            &[("out", "Echoed")],
        ),
    ] {
        service.post("/transformations", &spec.turtle());
    }
    let session = service.session();
    let out = Listener::new(&session, "/echoed");
    service.post("/targets", &target("echoed", "/echoed", "Echoed"));
    let mut executor = Killed(
        Command::new(BIN)
            .args(["executor", "--name", "ext", "--connect", &service.zenoh])
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    wait_for_line(&mut executor.0, "connected to");
    out.next();
    let pecho = service.cu_of("pecho").unwrap();
    let detail = service.get(&format!("/cus/{}", pecho["name"].as_str().unwrap()));
    assert_eq!(detail["executor"], "ext");
    let pid = detail["pid"].as_u64().unwrap();
    assert!(alive(pid));
    sigterm(&executor.0);
    let status = wait_exit(&mut executor.0);
    assert!(status.success(), "{status}");
    assert!(
        !alive(pid),
        "process CU {pid} survived its executor's SIGTERM"
    );
}

/// Issue 18 item 4: two targets on different channels want the same stream of one
/// transformation. One out port publishes on one channel, so the engine runs a second CU of the
/// transformation; both read the one counter CU (shared, free), and both channels carry the
/// computed values. A `kill -9` of one of them is repaired with both targets satisfied again;
/// when one target goes, its CU goes with it.
#[test]
fn two_channels_wanting_one_stream_get_a_cu_each_of_the_same_transformation() {
    let service = Service::start(&[]);
    let process_map = format!("{BIN} cu dyknow/map");
    for spec in [counter(&[("period_ms", "20")]), tenfold(&process_map)] {
        service.post("/transformations", &spec.turtle());
    }
    let session = service.session();
    let a = Listener::new(&session, "/tenfold-a");
    let b = Listener::new(&session, "/tenfold-b");
    service.post("/targets", &target("tenfold-a", "/tenfold-a", "Tenfold"));
    service.post("/targets", &target("tenfold-b", "/tenfold-b", "Tenfold"));
    // Both channels carry the counts times ten.
    for listener in [&a, &b] {
        let (_, first) = listener.next();
        let (_, second) = listener.next();
        let first = first.value.as_i64().unwrap();
        assert_eq!(first % 10, 0, "{first} is a counter value times ten");
        assert!(second.value.as_i64().unwrap() > first);
    }
    let of = |transformation: &str| -> Vec<Value> {
        service
            .get("/cus")
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| c["transformation"] == transformation)
            .cloned()
            .collect()
    };
    let tenfolds = eventually("two tenfold CUs running", Duration::from_secs(30), || {
        let cus = of("tenfold");
        (cus.len() == 2 && cus.iter().all(|c| c["state"] == "running")).then_some(cus)
    });
    let counters = of("counter");
    assert_eq!(counters.len(), 1, "{counters:?}");
    let counted = counters[0]["outputs"]["out"].as_str().unwrap();
    let mut published: Vec<&str> = tenfolds
        .iter()
        .map(|c| c["outputs"]["out"].as_str().unwrap())
        .collect();
    published.sort_unstable();
    assert_eq!(published, ["/tenfold-a", "/tenfold-b"]);
    for cu in &tenfolds {
        assert_eq!(cu["inputs"]["in"], counted, "{cu}");
    }
    for q in ["tenfold-a", "tenfold-b"] {
        let target = service.get(&format!("/targets/{q}"));
        assert_eq!(target["satisfied"], true, "{target}");
    }

    // kill -9 of the one on /tenfold-b: repaired, both targets satisfied again.
    let on_b = tenfolds
        .iter()
        .find(|c| c["outputs"]["out"] == "/tenfold-b")
        .unwrap()["name"]
        .as_str()
        .unwrap()
        .to_owned();
    let detail = service.get(&format!("/cus/{on_b}"));
    let pid = detail["pid"].as_u64().unwrap();
    let killed_at = kill_and_repair(&service, &on_b, pid);
    b.first_after(killed_at);
    a.first_after(killed_at);
    assert_eq!(of("tenfold").len(), 2);
    for q in ["tenfold-a", "tenfold-b"] {
        let target = service.get(&format!("/targets/{q}"));
        assert_eq!(target["satisfied"], true, "{target}");
    }

    // One target goes: its CU goes with it.
    let response = agent()
        .delete(&format!("{}/targets/tenfold-b", service.url))
        .call()
        .unwrap();
    assert_eq!(response.status(), 204);
    let left = eventually("one tenfold CU left", Duration::from_secs(30), || {
        let cus = of("tenfold");
        (cus.len() == 1).then_some(cus)
    });
    assert_eq!(left[0]["outputs"]["out"], "/tenfold-a");
    assert_eq!(of("counter").len(), 1);
    let status = service.sigterm();
    assert!(status.success(), "{status}");
}

/// A stand-alone executor says when it is linked and when it is not, whenever that changes
/// (before, it said so once, at start); `--connect` takes endpoints separated by commas, as
/// `serve --zenoh-listen` does (before, `a,b` was one endpoint that never answered).
#[test]
fn an_executor_says_when_its_links_come_and_go() {
    let (first, second) = (
        format!("tcp/127.0.0.1:{}", free_port()),
        format!("tcp/127.0.0.1:{}", free_port()),
    );
    let mut child = Command::new(BIN)
        .args(["executor", "--name", "says", "--connect"])
        .arg(format!("{first},{second}"))
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (line, said) = wait_for_line_keeping(&mut child, "does not answer yet");
    let _child = Killed(child);
    assert!(
        line.contains(&format!("{first}, {second} does not answer yet")),
        "{line}"
    );
    let heard = |what: &str| {
        eventually(what, Duration::from_secs(30), || {
            said.lock()
                .unwrap()
                .iter()
                .any(|l| l.contains(what))
                .then_some(())
        });
    };
    // A router comes on the second endpoint only.
    let router = dyknow_cu::router_config(std::slice::from_ref(&second), &[]).unwrap();
    let router = dyknow_cu::zenoh::open(router).wait().unwrap();
    heard("executor says connected to the data plane (1 link;");
    router.close().wait().unwrap();
    heard("executor says lost its links to the data plane");
}

/// `dyknow listen` says on its standard error when the service's router goes away and when it
/// is back, and receives again after (it waited in silence: a quiet channel and a dead service
/// looked the same).
#[test]
fn listen_says_when_the_service_goes_and_when_it_is_back() {
    use std::io::{BufRead, BufReader};
    let zenoh = format!("tcp/127.0.0.1:{}", free_port());
    let start = || Service::start_with(&["--in-memory"], &zenoh, &["--no-executor"]);
    let service = start();
    let mut child = Command::new(BIN)
        .args(["listen", "/x", "--values", "--connect", &zenoh])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lines = |stream: Box<dyn std::io::Read + Send>| {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stream).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        rx
    };
    let out = lines(Box::new(child.stdout.take().unwrap()));
    let err = lines(Box::new(child.stderr.take().unwrap()));
    let _listen = Killed(child);
    // Published until received: the subscription is declared some time after the start.
    let received = |value: &str| {
        eventually(
            &format!("listen receives {value}"),
            Duration::from_secs(30),
            || {
                let status = Command::new(BIN)
                    .args(["publish", "/x", value, "--connect", &zenoh])
                    .status()
                    .unwrap();
                assert!(status.success());
                out.recv_timeout(Duration::from_millis(200))
                    .ok()
                    .filter(|l| l == value)
            },
        )
    };
    received("1");
    drop(service);
    let said = err.recv_timeout(Duration::from_secs(30)).unwrap();
    assert!(
        said.contains("lost the link") && said.contains(&zenoh),
        "{said}"
    );
    let _service = start();
    let said = err.recv_timeout(Duration::from_secs(30)).unwrap();
    assert!(
        said.contains("linked to") && said.contains("again"),
        "{said}"
    );
    received("2");
}

/// A CU that a change set spawns is listed as `starting` while its executor starts it, in
/// `GET /cus` and `GET /cus/{name}`, before the change set is applied (it was missing from
/// every read until its process reported, which takes seconds for some).
#[test]
fn a_cu_being_spawned_is_listed_as_starting() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let gate = dir.path().join("go");
    let script = dir.path().join("slow-map.sh");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\nwhile [ ! -e '{}' ]; do sleep 0.02; done\nexec '{BIN}' cu dyknow/map\n",
            gate.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let service = Service::start(&[]);
    let source = script.to_str().unwrap();
    for spec in [counter(&[("period_ms", "20")]), tenfold(source)] {
        service.post("/transformations", &spec.turtle());
    }
    let session = service.session();
    let out = Listener::new(&session, "/tenfold");
    service.post("/targets", &target("tenfold-q", "/tenfold", "Tenfold"));
    let listed = eventually("the process CU listed", Duration::from_secs(30), || {
        service.cu_of("tenfold")
    });
    assert_eq!(listed["state"], "starting", "{listed}");
    assert_eq!(listed["executor"], "local", "{listed}");
    let name = listed["name"].as_str().unwrap().to_owned();
    let detail = service.get(&format!("/cus/{name}"));
    assert_eq!(detail["state"], "starting", "{detail}");
    let detailed = service.get("/cus?statistics=true");
    let entry = detailed
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == name.as_str())
        .cloned();
    assert_eq!(entry.map(|c| c["state"].clone()), Some(json!("starting")));
    // No change set records it yet: its application is under way.
    assert!(
        !service
            .change_sets()
            .iter()
            .any(|cs| cs.to_string().contains(&name)),
        "{:?}",
        service.change_sets()
    );
    std::fs::write(&gate, "").unwrap();
    let (_, first) = out.next();
    assert_eq!(first.value.as_i64().unwrap() % 10, 0);
    let running = eventually("the CU running", Duration::from_secs(30), || {
        let cu = service.cu_of("tenfold")?;
        (cu["state"] == "running").then_some(cu)
    });
    assert_eq!(running["name"], name.as_str());
    assert!(
        service
            .change_sets()
            .iter()
            .any(|cs| cs.to_string().contains(&name)),
        "recorded once applied"
    );
}

/// A process an executor found runnable and then failed to start (its program was deleted
/// since) is asked about again: the transformation shows not runnable, with the executor's
/// reason, and reviews stop planning it (each review tried it again, every change set failing,
/// while it showed runnable).
#[test]
fn a_program_deleted_after_its_check_is_found_missing_at_the_failed_spawn() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("map.sh");
    std::fs::write(&script, format!("#!/bin/sh\nexec '{BIN}' cu dyknow/map\n")).unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let service = Service::start(&[]);
    for spec in [
        counter(&[("period_ms", "20")]),
        tenfold(script.to_str().unwrap()),
    ] {
        service.post("/transformations", &spec.turtle());
    }
    assert_eq!(service.get("/transformations/tenfold")["runnable"], true);
    std::fs::remove_file(&script).unwrap();
    service.post("/targets", &target("tenfold-q", "/tenfold", "Tenfold"));
    let why = eventually("tenfold not runnable", Duration::from_secs(30), || {
        let t = service.get("/transformations/tenfold");
        (t["runnable"] == false).then(|| t["why"].as_str().unwrap_or_default().to_owned())
    });
    assert!(why.contains("not an executable file"), "{why}");
    // No review plans it again: the failed change sets stop.
    let failed = || {
        service
            .change_sets()
            .iter()
            .filter(|c| c["status"] == "failed")
            .count()
    };
    let after = failed();
    assert!(after >= 1);
    let reviews = service.get("/environment")["reviews"].as_u64().unwrap();
    eventually("two more reviews", Duration::from_secs(30), || {
        agent()
            .post(&format!("{}/review", service.url))
            .send_empty()
            .ok();
        (service.get("/environment")["reviews"].as_u64()? >= reviews + 2).then_some(())
    });
    assert_eq!(failed(), after, "{:?}", service.change_sets());
}
