//! Formula groups through the service (issue 15, contract `groups.md`): the Chapter 6 formula
//! over the live simulated lab with a crash, (5.12), (4.5) and a spatial formula over simulated
//! sources, live equals `dyknow check` on the recorded trace, restarts, bad input, the CLI.
#![cfg(feature = "rocksdb")]
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

mod support;

use support::*;

fn read(dir: &str, name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../specs")
        .join(dir)
        .join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn send(service: &Service, method: &str, path: &str, body: Option<Value>) -> (u16, Value) {
    let req = ureq::http::Request::builder()
        .method(method)
        .uri(format!("{}{path}", service.url));
    let r = match body {
        Some(b) => agent().run(
            req.header("Content-Type", "application/json")
                .body(b.to_string())
                .unwrap(),
        ),
        None => agent().run(req.body(()).unwrap()),
    };
    let mut r = r.unwrap();
    let status = r.status().as_u16();
    let text = r.body_mut().read_to_string().unwrap_or_default();
    (status, serde_json::from_str(&text).unwrap_or(Value::Null))
}

fn trace(service: &Service, label: &str) -> String {
    let mut r = agent()
        .get(&format!("{}/groups/{label}/trace", service.url))
        .call()
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    r.body_mut()
        .with_config()
        .limit(u64::MAX)
        .read_to_string()
        .unwrap()
}

/// How many verdict streams the service has answered (`GET /metrics`).
fn verdict_streams(service: &Service) -> u64 {
    let mut r = agent()
        .get(&format!("{}/metrics", service.url))
        .call()
        .unwrap();
    r.body_mut()
        .read_to_string()
        .unwrap()
        .lines()
        .filter(|l| {
            l.starts_with("dyknow_http_requests_total{")
                && l.contains("route=\"/groups/{label}/verdicts\"")
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<u64>().ok())
        .sum()
}

/// `dyknow check` on the group's recorded trace: (formula, verdict, t) per line.
fn check(formulas: &[&str], trace_text: &str) -> BTreeSet<(u64, String, u64)> {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("trace.jsonl");
    std::fs::write(&file, trace_text).unwrap();
    let mut cmd = Command::new(BIN);
    cmd.arg("check");
    for f in formulas {
        cmd.args(["--formula", f]);
    }
    let out = cmd.arg("--trace").arg(&file).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            let v: Value = serde_json::from_str(l).unwrap();
            (
                v["formula"].as_u64().unwrap(),
                v["verdict"].as_str().unwrap().to_owned(),
                v["t"].as_u64().unwrap(),
            )
        })
        .collect()
}

/// The verdicts a group shows: (formula, verdict, t) for decided formulas.
fn verdicts(group: &Value) -> BTreeSet<(u64, String, u64)> {
    group["formulas"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| !f["verdict"].is_null())
        .map(|f| {
            (
                f["index"].as_u64().unwrap(),
                f["verdict"].as_str().unwrap().to_owned(),
                f["t"].as_u64().unwrap(),
            )
        })
        .collect()
}

/// A service on an on-disk store under `dir`: the store's directory, and a start that each
/// call makes on the same store and Zenoh endpoint.
fn on_disk(dir: &Path) -> (std::path::PathBuf, impl Fn() -> Service) {
    let data = dir.join("data");
    let zenoh = format!("tcp/127.0.0.1:{}", free_port());
    let store = data.to_str().unwrap().to_owned();
    (data, move || {
        Service::start_with(&["--data", &store], &zenoh, &[])
    })
}

/// `POST /groups` of `body`, which must be 201.
fn create(service: &Service, body: Value) {
    let (status, g) = send(service, "POST", "/groups", Some(body));
    assert_eq!(status, 201, "{g}");
}

fn group(service: &Service, label: &str) -> Value {
    service.get(&format!("/groups/{label}"))
}

fn verdict_of(service: &Service, label: &str, index: usize, timeout: Duration) -> (String, u64) {
    let deadline = std::time::Instant::now() + timeout;
    let mut last = Value::Null;
    eventually(
        &format!("a verdict of formula {index} of {label}"),
        timeout + Duration::from_secs(1),
        || {
            let g = group(service, label);
            // On a timeout, say where the group was (states, last_t, the symbol's counts).
            assert!(
                std::time::Instant::now() < deadline,
                "no verdict of formula {index} of {label} in {timeout:?}; the group: {last}"
            );
            last = g.clone();
            let f = g["formulas"]
                .as_array()
                .unwrap()
                .iter()
                .find(|f| f["index"] == index)?
                .clone();
            Some((f["verdict"].as_str()?.to_owned(), f["t"].as_u64()?))
        },
    )
}

/// The states of a recorded trace: (t, state object).
fn states(trace_text: &str) -> Vec<(u64, Value)> {
    trace_text
        .lines()
        .skip(1)
        .map(|l| {
            let v: Value = serde_json::from_str(l).unwrap();
            (v["t"].as_u64().unwrap(), v["state"].clone())
        })
        .collect()
}

fn targets(service: &Service) -> BTreeMap<String, Value> {
    service
        .get("/targets")
        .as_array()
        .unwrap()
        .iter()
        .map(|t| (t["label"].as_str().unwrap().to_owned(), t.clone()))
        .collect()
}

fn now_ms() -> u64 {
    u64::try_from(dyknow_cu::now_ms()).unwrap()
}

/// The thesis' (6.1) on a compressed time scale over the live simulated lab, with two groups
/// sharing the symbol's target: `hold` (values held up to 3 s: robust to the camera's missed
/// frames and to the repair's gap, even on a loaded machine) decides `always[0,20s] InsideCircle(ball)` true at 20 s of states; `wait` (no value
/// is ever guessed) shows the symbol unknown during the repair after the segmenter is killed
/// mid-run, goes on progressing, and decides `always InsideCircle(ball)` false at the state
/// where the ball leaves the circle. The recorded traces give the same verdicts through
/// `dyknow check`; destroying the groups releases the target and every CU goes.
#[test]
fn chapter_6_formula_over_the_live_lab() {
    let service = Service::start(&["--no-executor"]);
    let _piff = executor(&service, "piff");
    let start = now_ms();
    let leave_at = start + 26_000;
    // The world's scenario on both sources that render it.
    let world = format!(
        "dkros:hasParam [ a dyknow:Parameter ; dyknow:hasName \"scenario\" ; dyknow:hasValue \"leave\" ] , \
         [ a dyknow:Parameter ; dyknow:hasName \"leave_at_ms\" ; dyknow:hasValue {leave_at} ] ;\n   dkros:hasSource"
    );
    let specs = read("turtle", "ch6-live-piff.ttl")
        .replace(
            "dkros:hasSource \"nao/pose\"",
            &format!("{world} \"nao/pose\""),
        )
        .replace(
            "dkros:hasSource \"nao/bottom_cam\"",
            &format!("{world} \"nao/bottom_cam\""),
        );
    service.post("/transformations", &specs);
    let held = ["always[0,20s] InsideCircle(ball)"];
    let strict = [
        "always InsideCircle(ball)",
        "always[0,2s] InsideCircle(ball)",
    ];
    let (status, created) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({
            "label": "held",
            "formulas": held,
            // The held values must bridge the repair after the kill. Its gap is ~20–200 ms here,
            // but the project's CI once ran this binary's five live tests at half this machine's
            // speed and the gap passed 1.2 s (2 states unknown, so `always[0,20s]` could never
            // be true): 3 s leaves room without changing what is tested.
            "sync": {"policy": "hold", "period_ms": 100, "max_age_ms": 3000},
        })),
    );
    assert_eq!(status, 201, "{created}");
    assert_eq!(created["state"], "created");
    assert_eq!(created["result_channel"], "/dyknow/verdicts/held");
    let (status, created) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({
            "label": "strict",
            "formulas": strict,
            "sync": {"policy": "wait", "period_ms": 100, "max_delay_ms": 400},
        })),
    );
    assert_eq!(status, 201, "{created}");
    // One target for both groups, named with them, and Piff's pipeline planned for it.
    let t = eventually(
        "the groups' target satisfied",
        Duration::from_secs(60),
        || {
            let t = targets(&service).get("symbol:InsideCircle(ball)")?.clone();
            (t["satisfied"] == true).then_some(t)
        },
    );
    assert_eq!(t["groups"], json!(["held", "strict"]));
    assert_eq!(t["tags"], json!(["InsideCircle(ball)"]));
    assert_eq!(service.get("/cus").as_array().unwrap().len(), 7);
    let session = service.session();
    let results = Listener::new(&session, "/dyknow/verdicts/held");
    // Start once the symbol's stream flows, so that `always[0,20s]` can be decided true.
    Listener::new(&session, "/dyknow/symbols/InsideCircle(ball)").next();
    for g in ["held", "strict"] {
        let (status, started) = send(&service, "POST", &format!("/groups/{g}/start"), None);
        assert_eq!(status, 200, "{started}");
        assert_eq!(started["state"], "running");
    }
    eventually("8 s of states", Duration::from_secs(30), || {
        (group(&service, "strict")["states"].as_u64()? >= 80).then_some(())
    });

    // Kill -9 the segmenter (a process CU) mid-run.
    let segmenter = service.cu_of("segmenter(piff)").unwrap();
    let name = segmenter["name"].as_str().unwrap().to_owned();
    let pid = service.get(&format!("/cus/{name}"))["pid"]
        .as_u64()
        .unwrap();
    let symbol = Listener::new(&session, "/dyknow/symbols/InsideCircle(ball)");
    let killed_at = now_ms();
    Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .unwrap();
    let repair = crash_change_set(&service, &name);
    assert_eq!(repair["status"], "applied", "{repair}");
    // The groups kept progressing through the repair. In `strict` (wait, P = 100 ms) a state
    // holds the symbol exactly when a sample of its period came: the frames the crash cost
    // (and the camera's missed frames) are unknown states, counted in missing_states.
    let repaired = now_ms();
    eventually("states after the repair", Duration::from_secs(10), || {
        (group(&service, "strict")["last_t"].as_u64()? > repaired + 1_000).then_some(())
    });
    let sampled: BTreeSet<u64> = symbol
        .drain()
        .into_iter()
        .map(|(_, s)| u64::try_from(s.t).unwrap())
        .collect();
    let text = trace(&service, "strict");
    let window: Vec<(u64, Value)> = states(&text)
        .into_iter()
        .filter(|(t, _)| *t >= killed_at + 100 && *t <= repaired + 1_000)
        .collect();
    assert!(window.len() >= 5, "{text}");
    let g = group(&service, "strict");
    let late = g["symbols"][0]["late"].as_u64().unwrap();
    let (mut unknown, mut came_late) = (0, 0);
    for (t, s) in &window {
        let came = sampled.range(t - 99..=*t).next().is_some();
        let known = s.get("InsideCircle(ball)").is_some();
        assert!(
            !known || came,
            "the state at {t} holds a value no sample gave: {sampled:?}"
        );
        unknown += u64::from(!known);
        // A sample of the period that came after the maximum delay (a loaded machine) was
        // counted late, and its state is unknown.
        came_late += u64::from(!known && came);
    }
    assert!(
        came_late <= late,
        "{came_late} states unknown though their sample came; {late} late"
    );
    assert!(
        g["symbols"][0]["missing_states"].as_u64().unwrap() >= unknown,
        "{g}"
    );
    // The symbol's longest silence around the kill (the repair's gap, as a client sees it).
    let gap = sampled
        .iter()
        .zip(sampled.iter().skip(1))
        .map(|(a, b)| b - a)
        .max()
        .unwrap_or(0);
    println!(
        "segmenter killed at {killed_at}, replaced at {repaired}: {unknown} of the {} states after it unknown, the symbol's longest gap {gap} ms",
        window.len()
    );
    // Held values bridged the repair: no state of `held` is unknown (were one, `always[0,20s]`
    // could only end unknown, and the wait below would time out without saying why).
    let held_missing = group(&service, "held")["symbols"][0]["missing_states"].clone();
    assert_eq!(
        held_missing,
        json!(0),
        "the repair's gap passed the held values' 3 s: {}",
        group(&service, "held")
    );

    // `hold`: true at 20 s of states (the held values bridge the repair). That needs the ball
    // inside for the first 20 s of states: the scenario's leave time was fixed before the
    // pipeline was spawned, so a slow start leaves less of the margin (said here rather than
    // as a verdict of false).
    let exits = dyknow_lab::world::World {
        scenario: dyknow_lab::world::Scenario::Leave {
            at_ms: i64::try_from(leave_at).unwrap(),
        },
        seed: 1,
    }
    .exits_at()
    .unwrap();
    let exits = u64::try_from(exits).unwrap();
    let first = states(&trace(&service, "held"))[0].0;
    println!(
        "the first state came {} ms after the test started; the ball leaves the circle {} ms after the first 20 s of states",
        first - start,
        i128::from(exits) - i128::from(first + 20_000)
    );
    assert!(
        first + 20_000 < exits,
        "the groups started too late ({} ms after the test) for 20 s of states before the ball leaves at {exits}: the scenario's margin is too small for this machine",
        first - start
    );
    let (v0, t0) = verdict_of(&service, "held", 0, Duration::from_secs(40));
    let text = trace(&service, "held");
    assert_eq!((v0.as_str(), t0), ("true", first + 20_000), "{text}");
    // The verdict on the result channel.
    let (_, sample) = results.next();
    assert_eq!(
        sample.value,
        json!({"group": "held", "formula": 0, "verdict": "true"})
    );
    assert_eq!(sample.t, i64::try_from(t0).unwrap());

    // The ball leaves: `always` is false at the state where it does.
    let (v1, t1) = verdict_of(&service, "strict", 0, Duration::from_secs(40));
    assert_eq!(v1, "false");
    let text = trace(&service, "strict");
    let first_false = states(&text)
        .into_iter()
        .find(|(_, s)| s["InsideCircle(ball)"] == false)
        .map(|(t, _)| t)
        .unwrap();
    assert_eq!(
        t1, first_false,
        "false at the first state where the ball is out"
    );
    assert!(
        t1 + 600 >= exits && t1 <= exits + 1_000,
        "the verdict at {t1}, the ball left the circle at {exits}"
    );

    // Live equals offline, for both groups.
    for (label, formulas) in [("held", &held[..]), ("strict", &strict[..])] {
        let (status, stopped) = send(&service, "POST", &format!("/groups/{label}/stop"), None);
        assert_eq!(status, 200);
        assert_eq!(
            check(formulas, &trace(&service, label)),
            verdicts(&stopped),
            "{label}"
        );
    }
    assert_eq!(send(&service, "POST", "/groups/held/start", None).0, 409);

    // Destroy: the target is released and every CU goes.
    for g in ["held", "strict"] {
        assert_eq!(
            send(&service, "DELETE", &format!("/groups/{g}"), None).0,
            204
        );
    }
    assert!(!targets(&service).contains_key("symbol:InsideCircle(ball)"));
    eventually("no CU", Duration::from_secs(30), || {
        service.get("/cus").as_array()?.is_empty().then_some(())
    });
    assert_eq!(service.status("/groups/held"), 404);
}

/// (5.12), (4.5) and a spatial formula over simulated sources on the embedded executor;
/// formulas added and removed while running; live equals offline for every group.
#[test]
fn uav_battery_and_spatial_groups() {
    let service = Service::start(&[]);
    for f in ["uav.ttl", "nao-battery.ttl", "regions.ttl"] {
        service.post("/transformations", &read("groups", f));
    }
    let wait = json!({"policy": "wait", "period_ms": 100, "max_delay_ms": 500});
    // A label that makes a default result channel Zenoh refuses: the message is about the
    // label (it named a result_channel the user never gave).
    let (status, answer) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "lx3#", "formulas": ["p"]})),
    );
    assert_eq!(status, 422, "{answer}");
    assert!(
        answer["error"]
            .as_str()
            .unwrap()
            .starts_with("the label \"lx3#\""),
        "{answer}"
    );
    // (5.12) with the UAV domain: two targets.
    let uav = ["forall x in UAV: always (altitude(x) > 50)"];
    let (status, g) = send(
        &service,
        "POST",
        "/groups",
        Some(
            json!({"label": "uav", "formulas": uav, "domains": {"UAV": ["uav1", "uav2"]}, "sync": wait, "start": true}),
        ),
    );
    assert_eq!(status, 201, "{g}");
    let symbols: Vec<&str> = g["symbols"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["symbol"].as_str().unwrap())
        .collect();
    assert_eq!(symbols, ["altitude(uav1)", "altitude(uav2)"]);
    // (4.5), bounded so that a finite run decides it, and a variant that is violated.
    let battery = [
        "forall x in NAO: always[0,6s] (batteryLevel(x) < 0.1 -> eventually[0,4s] Charging(x))",
        "forall x in NAO: always[0,6s] (batteryLevel(x) < 0.1 -> eventually[0,1s] Charging(x))",
    ];
    let (status, g) = send(
        &service,
        "POST",
        "/groups",
        Some(
            json!({"label": "battery", "formulas": battery, "domains": {"NAO": ["piff"]}, "sync": {"policy": "hold", "period_ms": 100, "max_age_ms": 500}, "start": true}),
        ),
    );
    assert_eq!(status, 201, "{g}");
    // A spatial formula with a static region: both spatial symbols ground in one RCC8 target.
    let spatial = [
        "always[0,10s] (PO(a,b) -> eventually[0,4s] DC(a,b))",
        "eventually[0,10s] NTPPI(a,b)",
        "always[0,10s] NTPP(a,field)",
    ];
    let (status, g) = send(
        &service,
        "POST",
        "/groups",
        Some(
            json!({"label": "regions", "formulas": spatial, "static": ["field"], "sync": {"policy": "event"}, "start": true}),
        ),
    );
    assert_eq!(status, 201, "{g}");
    let targets_of: BTreeSet<&str> = g["symbols"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["target"].as_str().unwrap())
        .collect();
    assert_eq!(targets_of, BTreeSet::from(["symbol:RCC8"]));

    // A formula added while running gets its target; removing it releases it.
    let (status, added) = send(
        &service,
        "POST",
        "/groups/uav/formulas",
        Some(json!({"formula": "eventually[0,5s] altitude(uav3) > 0"})),
    );
    assert_eq!(status, 201, "{added}");
    assert_eq!(added["index"], 1);
    assert!(targets(&service).contains_key("symbol:altitude(uav3)"));
    assert_eq!(
        send(&service, "DELETE", "/groups/uav/formulas/1", None).0,
        204
    );
    assert!(!targets(&service).contains_key("symbol:altitude(uav3)"));
    assert_eq!(
        send(&service, "DELETE", "/groups/uav/formulas/1", None).0,
        404,
        "removed already"
    );
    let (_, added) = send(
        &service,
        "POST",
        "/groups/uav/formulas",
        Some(json!({"formula": "always[0,1s] altitude(uav1) > 60"})),
    );
    assert_eq!(added["index"], 2, "indices are never reused");

    // (5.12): false at the state where uav2 drops below 50.
    let (v, t) = verdict_of(&service, "uav", 0, Duration::from_secs(60));
    assert_eq!(v, "false");
    let text = trace(&service, "uav");
    let below = states(&text)
        .into_iter()
        .find(|(_, s)| s["altitude(uav2)"].as_f64().is_some_and(|a| a <= 50.0))
        .unwrap()
        .0;
    assert_eq!(t, below);
    // (4.5): docked within 4 s, not within 1 s.
    assert_eq!(
        verdict_of(&service, "battery", 0, Duration::from_secs(60)).0,
        "true"
    );
    assert_eq!(
        verdict_of(&service, "battery", 1, Duration::from_secs(60)).0,
        "false"
    );
    // The spatial formulas: b crosses a and leaves it within 4 s of overlapping; it is once
    // inside a; a stays inside the static field.
    assert_eq!(
        verdict_of(&service, "regions", 0, Duration::from_secs(60)).0,
        "true"
    );
    assert_eq!(
        verdict_of(&service, "regions", 1, Duration::from_secs(60)).0,
        "true"
    );
    assert_eq!(
        verdict_of(&service, "regions", 2, Duration::from_secs(60)).0,
        "true"
    );

    // Live equals offline, for every group (stopped, so undecided formulas are final).
    for (label, formulas) in [
        ("uav", &uav[..]),
        ("battery", &battery[..]),
        ("regions", &spatial[..]),
    ] {
        let (status, stopped) = send(&service, "POST", &format!("/groups/{label}/stop"), None);
        assert_eq!(status, 200);
        if label == "uav" {
            // Formula 2 was added after the first state (and 1 added and removed): given
            // formulas, `dyknow check` starts each at the first state, so it is compared on
            // formula 0 only; given none, it replays those the trace's header lists, each over
            // the states the group progressed it over, and gives every verdict the group gave.
            let live: BTreeSet<_> = verdicts(&stopped)
                .into_iter()
                .filter(|v| v.0 == 0)
                .collect();
            assert_eq!(check(formulas, &trace(&service, label)), live);
            let all = verdicts(&stopped);
            assert!(all.iter().any(|v| v.0 == 2), "{all:?}");
            assert_eq!(check(&[], &trace(&service, label)), all);
        } else {
            assert_eq!(
                check(formulas, &trace(&service, label)),
                verdicts(&stopped),
                "{label}"
            );
        }
    }
    // Stopped groups need no streams: every group target is released.
    assert!(
        targets(&service).keys().all(|l| !l.starts_with("symbol:")),
        "{:?}",
        targets(&service).keys()
    );
}

/// Bad formulas, unknown domains and invalid groundings are refused naming the formula and
/// the column, and nothing is created.
#[test]
fn bad_groups_are_refused_and_nothing_is_created() {
    let service = Service::start(&["--model-only"]);
    let cases = [
        (
            json!({"formulas": ["always p", "always (p &&"]}),
            400,
            Some((1, 13)),
        ),
        (
            json!({"formulas": ["forall x in UAV: altitude(x) > 1"]}),
            422,
            Some((0, 13)),
        ),
        (
            json!({"formulas": ["p"], "grounding": {"q": {"tag": "Q"}}}),
            422,
            None,
        ),
        (
            json!({"formulas": ["q", "always (q -> p)"], "grounding": {"p": {"description": "not an iri"}}}),
            422,
            Some((1, 14)),
        ),
        (
            json!({"formulas": ["forall x in D: P(x)"], "domains": {"D": ["a,b"]}}),
            422,
            None,
        ),
        (
            json!({"formulas": ["p"], "sync": {"policy": "wait", "period_ms": 0, "max_delay_ms": 1}}),
            422,
            None,
        ),
        (json!({"formulas": ["p"], "label": "a/b"}), 422, None),
        (json!({"formulas": ["p"], "colour": "red"}), 422, None),
        // What no target could be posted with (a tag XML cannot carry, a symbol past a
        // label's length): refused here; accepted, it failed every group's target post.
        (
            json!({"formulas": ["p"], "grounding": {"p": {"tag": "Q\u{ffff}"}}}),
            422,
            None,
        ),
        // Descriptions too: an IRI with a control character or a non-character, or longer
        // than a target's label takes (each was a 500 that left the group, after which every
        // group's targets failed, and an on-disk service no longer started).
        (
            json!({"formulas": ["p"], "grounding": {"p": {"description": "http://example.org/\u{1}x"}}}),
            422,
            Some((0, 1)),
        ),
        (
            json!({"formulas": ["p"], "grounding": {"p": {"description": "http://example.org/\u{ffff}"}}}),
            422,
            Some((0, 1)),
        ),
        (
            json!({"formulas": ["p"], "grounding": {"p": {"description": format!("http://example.org/{}", "x".repeat(5000))}}}),
            422,
            Some((0, 1)),
        ),
        (
            json!({"formulas": [format!("always p({})", vec!["a0000"; 800].join(","))]}),
            422,
            Some((0, 1)),
        ),
    ];
    for (body, status, at) in cases {
        let (got, answer) = send(&service, "POST", "/groups", Some(body.clone()));
        assert_eq!(got, status, "{body}: {answer}");
        if let Some((formula, column)) = at {
            assert_eq!(answer["details"][0]["formula"], formula, "{answer}");
            assert_eq!(answer["details"][0]["column"], column, "{answer}");
            assert!(
                answer["error"]
                    .as_str()
                    .unwrap()
                    .contains(&format!("formula {formula}: column {column}")),
                "{answer}"
            );
        }
    }
    // Regions no formula can name, as domain constants (they were taken).
    for body in [
        json!({"formulas": ["p"], "landmarks": ["a b"]}),
        json!({"formulas": ["p"], "static": ["a,b"]}),
    ] {
        let (got, answer) = send(&service, "POST", "/groups", Some(body.clone()));
        assert_eq!(got, 422, "{body}: {answer}");
        assert!(
            answer["error"]
                .as_str()
                .unwrap()
                .contains("names formulas write"),
            "{answer}"
        );
    }
    // Another group's result channel (two verdict streams mixed on one channel were taken).
    let (got, answer) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "first", "formulas": ["p"]})),
    );
    assert_eq!(got, 201, "{answer}");
    let (got, answer) = send(
        &service,
        "POST",
        "/groups",
        Some(
            json!({"label": "second", "formulas": ["p"], "result_channel": "dyknow/verdicts/first"}),
        ),
    );
    assert_eq!(got, 422, "{answer}");
    assert!(
        answer["error"]
            .as_str()
            .unwrap()
            .contains("is the result channel of group \"first\""),
        "{answer}"
    );
    assert_eq!(send(&service, "DELETE", "/groups/first", None).0, 204);
    // A grounding that is neither a tag nor a description says what a grounding is (it said
    // "data did not match any variant of untagged enum Grounding").
    for (grounding, why) in [
        (json!({}), "neither"),
        (json!({"tag": "x", "description": "http://e/x"}), "both"),
    ] {
        let (got, answer) = send(
            &service,
            "POST",
            "/groups",
            Some(json!({"formulas": ["p"], "grounding": {"p": grounding}})),
        );
        assert_eq!(got, 422, "{answer}");
        let error = answer["error"].as_str().unwrap();
        assert!(
            error.contains(r#"{"tag": "<value>"} or {"description": "<IRI>"}"#)
                && error.contains(why),
            "{answer}"
        );
    }
    // Not JSON, or not declared as JSON (no Content-Type declares nothing).
    for content_type in [Some("text/plain"), None] {
        let mut request = agent().post(&format!("{}/groups", service.url));
        if let Some(t) = content_type {
            request = request.header("Content-Type", t);
        }
        let mut r = request.send("{}").unwrap();
        assert_eq!(
            r.status().as_u16(),
            415,
            "{content_type:?}: {}",
            r.body_mut().read_to_string().unwrap()
        );
    }
    let (got, _) = {
        let mut r = agent()
            .post(&format!("{}/groups", service.url))
            .header("Content-Type", "application/json")
            .send("{\"formulas\": [")
            .unwrap();
        (r.status().as_u16(), r.body_mut().read_to_string().unwrap())
    };
    assert_eq!(got, 400);
    assert_eq!(service.get("/groups"), json!([]));
    assert_eq!(service.get("/targets"), json!([]));
    // A good one, then bad formulas added to it: nothing changes.
    let (status, _) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "g", "formulas": ["p"]})),
    );
    assert_eq!(status, 201);
    let (status, answer) = send(
        &service,
        "POST",
        "/groups/g/formulas",
        Some(json!({"formula": "eventually[5,1] q"})),
    );
    assert_eq!(status, 400, "{answer}");
    assert_eq!(
        send(&service, "POST", "/groups", Some(json!({"label": "g"}))).0,
        409
    );
    assert_eq!(send(&service, "POST", "/groups/none/start", None).0, 404);
    assert_eq!(
        send(&service, "DELETE", "/groups/g/formulas/7", None).0,
        404
    );
    // Once stopped, the formulas and their verdicts are final: no removal (it took the final
    // `unknown` back from replays and restarts).
    let (status, _) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "done", "formulas": ["eventually q"], "start": true})),
    );
    assert_eq!(status, 201);
    assert_eq!(send(&service, "POST", "/groups/done/stop", None).0, 200);
    assert_eq!(
        send(&service, "DELETE", "/groups/done/formulas/0", None).0,
        409
    );
    assert_eq!(send(&service, "DELETE", "/groups/done", None).0, 204);
    assert_eq!(
        group(&service, "g")["formulas"].as_array().unwrap().len(),
        1
    );
    assert_eq!(
        targets(&service).keys().cloned().collect::<Vec<_>>(),
        ["symbol:p"]
    );
    // The `symbol:` labels are the groups': a client may neither post one (which would replace
    // the group's target, or be released behind its back) nor delete one a group needs.
    let mine = |label: &str| {
        format!(
            "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
             @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n\
             [] a dyknow:Target ; rdfs:label {label:?} ;\n\
             dyknow:hasChannel [ a dyknow:Channel ; dyknow:hasChannelName \"/mine\" ] ;\n\
             dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"p\" ] .\n"
        )
    };
    let post_target = |label: &str| {
        let mut r = agent()
            .post(&format!("{}/targets", service.url))
            .header("Content-Type", "text/turtle")
            .send(mine(label))
            .unwrap();
        let status = r.status().as_u16();
        (status, r.body_mut().read_to_string().unwrap())
    };
    for label in ["symbol:p", "symbol:q"] {
        let (status, answer) = post_target(label);
        assert_eq!(status, 422, "{label}: {answer}");
        assert!(answer.contains("reserved"), "{answer}");
    }
    assert_eq!(
        targets(&service).keys().cloned().collect::<Vec<_>>(),
        ["symbol:p"]
    );
    assert_eq!(
        targets(&service)["symbol:p"]["channel"],
        "/dyknow/symbols/p"
    );
    let (status, answer) = send(&service, "DELETE", "/targets/symbol:p", None);
    assert_eq!(status, 409, "{answer}");
    assert!(
        answer["error"].as_str().unwrap().contains("group(s) g:"),
        "{answer}"
    );
    assert!(targets(&service).contains_key("symbol:p"));
    // Another label with the same tag is the client's own.
    assert_eq!(post_target("mine").0, 201);
    // Nor may a target take a group's result channel after the group was made (the group
    // checks targets when it is created; a user audit posted the target after it, and the
    // engine wired a CU's stream onto the verdicts' channel).
    let on_verdicts = |channel: &str| {
        let mut r = agent()
            .post(&format!("{}/targets", service.url))
            .header("Content-Type", "text/turtle")
            .send(mine("late").replace("\"/mine\"", &format!("{channel:?}")))
            .unwrap();
        let status = r.status().as_u16();
        (status, r.body_mut().read_to_string().unwrap())
    };
    for channel in ["/dyknow/verdicts/g", "dyknow/verdicts/g"] {
        let (status, answer) = on_verdicts(channel);
        assert_eq!(status, 422, "{channel}: {answer}");
        assert!(answer.contains("verdicts of formula group"), "{answer}");
    }
    assert!(!targets(&service).contains_key("late"));
    // A result channel that is a stream of the configuration is refused: verdict lines on a
    // CU's input crashed it at every verdict (the engine's `ch-N` channels), and on a target's
    // channel they mix with the target's stream.
    for channel in ["/mine", "mine", "/dyknow/symbols/p", "ch-7", "/ch-1"] {
        let (status, answer) = send(
            &service,
            "POST",
            "/groups",
            Some(json!({"label": "r", "formulas": ["q"], "result_channel": channel})),
        );
        assert_eq!(status, 422, "{channel}: {answer}");
        assert!(
            answer["error"].as_str().unwrap().contains("result_channel"),
            "{answer}"
        );
    }
    // Labels that URLs resolve away could not be reached (`/groups/..` is `/`).
    for label in [".", ".."] {
        let (status, answer) = send(
            &service,
            "POST",
            "/groups",
            Some(json!({"label": label, "formulas": ["q"]})),
        );
        assert_eq!(status, 422, "{label}: {answer}");
    }
    assert_eq!(
        service.get("/groups").as_array().unwrap().len(),
        1,
        "nothing was created"
    );
    assert_eq!(send(&service, "DELETE", "/targets/mine", None).0, 204);
    // Stop then start: 409.
    assert_eq!(send(&service, "POST", "/groups/g/stop", None).0, 200);
    assert!(!targets(&service).contains_key("symbol:p"));
    // A stopped group writes no more verdicts: its channel is free.
    assert_eq!(on_verdicts("/dyknow/verdicts/g").0, 201);
    assert_eq!(send(&service, "POST", "/groups/g/start", None).0, 409);
    assert_eq!(
        send(
            &service,
            "POST",
            "/groups/g/formulas",
            Some(json!({"formula": "q"}))
        )
        .0,
        409
    );
}

/// `sync` parameters left out take the defaults `dyknow group create` has; a field the policy
/// does not take, or no policy, is refused.
#[test]
fn sync_parameters_take_their_defaults() {
    let service = Service::start(&["--model-only"]);
    for (sync, shown) in [
        (
            json!({"policy": "wait"}),
            json!({"policy": "wait", "period_ms": 100, "max_delay_ms": 500}),
        ),
        (
            json!({"policy": "wait", "period_ms": 40}),
            json!({"policy": "wait", "period_ms": 40, "max_delay_ms": 200}),
        ),
        (
            json!({"policy": "hold"}),
            json!({"policy": "hold", "period_ms": 100, "max_age_ms": 1000, "max_delay_ms": 100}),
        ),
        (
            json!({"policy": "hold", "max_age_ms": 250, "max_delay_ms": 7}),
            json!({"policy": "hold", "period_ms": 100, "max_age_ms": 250, "max_delay_ms": 7}),
        ),
        (
            json!({"policy": "event"}),
            json!({"policy": "event", "max_delay_ms": 2}),
        ),
    ] {
        let (status, answer) = send(
            &service,
            "POST",
            "/groups",
            Some(json!({"formulas": ["p"], "sync": sync})),
        );
        assert_eq!(status, 201, "{sync}: {answer}");
        assert_eq!(answer["sync"], shown, "{sync}");
    }
    for sync in [
        json!({"policy": "event", "period_ms": 5}),
        json!({"policy": "wait", "max_age_ms": 5}),
        json!({"period_ms": 5}),
        json!({"policy": "sometimes"}),
        json!({"policy": "hold", "period_ms": 0}),
    ] {
        let (status, answer) = send(
            &service,
            "POST",
            "/groups",
            Some(json!({"formulas": ["p"], "sync": sync})),
        );
        assert_eq!(status, 422, "{sync}: {answer}");
    }
    assert_eq!(service.get("/groups").as_array().unwrap().len(), 5);
}

/// DestroyGroup stops the group as StopGroup does: a watcher gets the undecided formulas'
/// final `unknown` verdicts, then its stream ends. (Before, it ended with nothing.)
#[test]
fn destroying_a_group_gives_its_final_verdicts() {
    let service = Service::start(&["--model-only"]);
    let (status, answer) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "d", "formulas": ["eventually p", "always q"], "start": true})),
    );
    assert_eq!(status, 201, "{answer}");
    let watches = verdict_streams(&service);
    let watcher = Command::new(BIN)
        .args(["group", "watch", "d", "--url", &service.url])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut watcher = Killed(watcher);
    eventually("the watcher's stream", Duration::from_secs(30), || {
        (verdict_streams(&service) > watches).then_some(())
    });
    assert_eq!(send(&service, "DELETE", "/groups/d", None).0, 204);
    let ended = eventually("the watcher to end", Duration::from_secs(30), || {
        watcher.0.try_wait().unwrap()
    });
    assert!(ended.success(), "{ended}");
    let mut out = String::new();
    std::io::Read::read_to_string(&mut watcher.0.stdout.take().unwrap(), &mut out).unwrap();
    let verdicts: BTreeSet<(u64, String)> = out
        .lines()
        .map(|l| {
            let v: Value = serde_json::from_str(l).unwrap();
            (
                v["formula"].as_u64().unwrap(),
                v["verdict"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    assert_eq!(
        verdicts,
        BTreeSet::from([(0, "unknown".to_owned()), (1, "unknown".to_owned())]),
        "{out}"
    );
    assert_eq!(send(&service, "GET", "/groups/d", None).0, 404);
}

/// A service on disk restarted with `kill -9` while a group runs: the definition, the
/// verdicts and the trace survive, the group resumes from the next state and says so, and
/// `dyknow check` on the trace still gives the group's verdicts.
#[test]
fn groups_survive_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let zenoh = format!("tcp/127.0.0.1:{}", free_port());
    let start = |specs: bool| {
        let data = data.to_str().unwrap();
        let uav = Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/groups/uav.ttl");
        let uav = uav.to_str().unwrap();
        let extra: &[&str] = if specs { &["--specs", uav] } else { &[] };
        Service::start_with(&["--data", data], &zenoh, extra)
    };
    let formulas = [
        "forall x in UAV: always (altitude(x) > 50)",
        "always[0,1s] altitude(uav1) > 60",
        "always altitude(uav1) > 0",
    ];
    let service = start(true);
    // A label of 200 characters, each percent-encoded to six bytes, is kept on disk too.
    let long = "é".repeat(200);
    let (status, g) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": long, "formulas": ["TPP^-1(a, b)"]})),
    );
    assert_eq!(status, 201, "{g}");
    let (status, g) = send(
        &service,
        "POST",
        "/groups",
        Some(
            json!({"label": "uav", "formulas": formulas, "domains": {"UAV": ["uav1", "uav2"]}, "sync": {"policy": "wait", "period_ms": 100, "max_delay_ms": 300}, "start": true}),
        ),
    );
    assert_eq!(status, 201, "{g}");
    verdict_of(&service, "uav", 0, Duration::from_secs(60));
    eventually("some states", Duration::from_secs(20), || {
        (group(&service, "uav")["states"].as_u64()? > 20).then_some(())
    });
    let before = group(&service, "uav");
    // kill -9
    let mut service = service;
    Command::new("kill")
        .args(["-9", &service.child.id().to_string()])
        .status()
        .unwrap();
    let _ = service.child.wait();
    std::mem::forget(service);

    let service = start(false);
    let labels: Vec<Value> = (service.get("/groups").as_array().unwrap().iter())
        .map(|g| g["label"].clone())
        .collect();
    assert!(
        labels.len() == 2 && labels.contains(&json!(long)) && labels.contains(&json!("uav")),
        "{labels:?}"
    );
    let after = group(&service, "uav");
    assert_eq!(after["state"], "running");
    assert_eq!(verdicts(&after), verdicts(&before), "verdicts survive");
    assert!(after["states"].as_u64() >= before["states"].as_u64());
    assert_eq!(after["resumed"].as_array().unwrap().len(), 1, "{after}");
    let states_then = after["states"].as_u64().unwrap();
    eventually(
        "progression after the restart",
        Duration::from_secs(20),
        || (group(&service, "uav")["states"].as_u64()? > states_then + 5).then_some(()),
    );
    let all_satisfied = |g: &Value, yes: bool| {
        g["symbols"]
            .as_array()
            .unwrap()
            .iter()
            .all(|s| s["satisfied"] == json!(yes) && s["producer"].is_null() != yes)
    };
    eventually("the symbols' producers", Duration::from_secs(20), || {
        all_satisfied(&group(&service, "uav"), true).then_some(())
    });
    let (status, stopped) = send(&service, "POST", "/groups/uav/stop", None);
    assert_eq!(status, 200);
    // A stopped group reads no stream: its answer does not show the producers that are about
    // to go.
    assert!(all_satisfied(&stopped, false), "{stopped}");
    let text = trace(&service, "uav");
    let ts: Vec<u64> = states(&text).iter().map(|s| s.0).collect();
    assert!(
        ts.windows(2).all(|w| w[0] < w[1]),
        "timestamps strictly increase across the restart"
    );
    // A state every 100 ms, the time the service was down included (unknown states): a
    // window that fell in it is not decided without a state in it.
    let gaps: Vec<&[u64]> = ts.windows(2).filter(|w| w[1] - w[0] != 100).collect();
    assert!(gaps.is_empty(), "the grid has gaps: {gaps:?}");
    assert_eq!(check(&formulas, &text), verdicts(&stopped));
}

/// A crash can leave `group.json` ahead of the trace: the definition is written at once, the
/// trace up to a second later. A formula added, or removed, after the last state the trace kept
/// is restored as added (removed) as of that state; the group shows it, the served trace's
/// header says so, and `dyknow check` on that trace gives the group's verdicts.
#[test]
fn a_formula_changed_after_the_last_state_a_torn_trace_kept_is_restored_as_of_that_state() {
    let dir = tempfile::tempdir().unwrap();
    let (data, start) = on_disk(dir.path());
    let service = start();
    create(
        &service,
        json!({"label": "torn", "formulas": ["always p", "eventually q"]}),
    );
    drop(service);
    // What a crash leaves: three states written whole and a fourth torn, while the definition
    // already holds formula 1's removal at state 5 and formula 2's addition at state 7.
    let record = data.join("groups").join("torn");
    let def_path = record.join("group.json");
    let mut def: Value =
        serde_json::from_str(&std::fs::read_to_string(&def_path).unwrap()).unwrap();
    def["phase"] = json!("stopped");
    def["formulas"][1]["removed_at"] = json!(5);
    def["formulas"]
        .as_array_mut()
        .unwrap()
        .push(json!({"index": 2, "formula": "always (p and not q)", "added_at": 7}));
    std::fs::write(&def_path, def.to_string()).unwrap();
    let trace_path = record.join("trace.jsonl");
    let mut text = std::fs::read_to_string(&trace_path).unwrap();
    for t in [0, 100, 200] {
        text.push_str(&format!(
            "{{\"t\":{t},\"state\":{{\"p\":true,\"q\":false}}}}\n"
        ));
    }
    text.push_str("{\"t\":300,\"state\":{\"p\":fal");
    std::fs::write(&trace_path, text).unwrap();

    let service = start();
    let g = group(&service, "torn");
    assert_eq!(g["state"], "stopped", "{g}");
    assert_eq!(g["states"], 3, "the torn state is cut: {g}");
    let served = trace(&service, "torn");
    let header: Value = serde_json::from_str(served.lines().next().unwrap()).unwrap();
    assert_eq!(
        header["formulas"],
        json!([
            {"index": 0, "formula": "always p", "from_state": 0},
            {"index": 1, "formula": "eventually q", "from_state": 0, "until_state": 3},
            {"index": 2, "formula": "always (p and not q)", "from_state": 3},
        ]),
        "{served}"
    );
    // Formula 2 was added when the group stopped: progressed over no state, it is decided by
    // the end of the trace, as `dyknow check` decides it.
    let shown = verdicts(&g);
    assert!(
        shown.iter().any(|(i, _, _)| *i == 2),
        "formula 2 is decided: {g}"
    );
    assert_eq!(check(&[], &served), shown, "{served}");
    // And the definition on disk now says what was done, so a second restart agrees.
    drop(service);
    let service = start();
    assert_eq!(verdicts(&group(&service, "torn")), shown);
    assert_eq!(trace(&service, "torn"), served);
}

/// A group whose `group.json` cannot be read at start-up is not loaded, and its directory is
/// not overwritten by a new group of its label: that is 409, and the old trace stays (a user
/// audit lost a trace of 9,459 lines this way).
#[test]
fn a_group_that_cannot_be_loaded_is_not_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let (data, start) = on_disk(dir.path());
    let service = start();
    create(&service, json!({"label": "kept", "formulas": ["p"]}));
    drop(service);
    let record = data.join("groups").join("kept");
    let trace_before = std::fs::read_to_string(record.join("trace.jsonl")).unwrap();
    std::fs::write(record.join("group.json"), "{\"broken").unwrap();
    let service = start();
    assert_eq!(
        service.get("/groups"),
        json!([]),
        "the damaged group is not loaded"
    );
    let (status, answer) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "kept", "formulas": ["q"]})),
    );
    assert_eq!(status, 409, "{answer}");
    assert!(
        answer["error"]
            .as_str()
            .unwrap()
            .contains("not loaded at start-up"),
        "{answer}"
    );
    assert_eq!(
        std::fs::read_to_string(record.join("trace.jsonl")).unwrap(),
        trace_before
    );
    assert_eq!(
        std::fs::read_to_string(record.join("group.json")).unwrap(),
        "{\"broken"
    );
    // Other labels are unaffected.
    let (status, g) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "other", "formulas": ["q"]})),
    );
    assert_eq!(status, 201, "{g}");
}

/// A creation cut short by a crash (the trace's header written, `group.json` not yet) leaves
/// remains that start-up removes, saying so: the label can be created again (it was 409 for
/// good, and the log said nothing). A directory without `group.json` that holds recorded
/// states is kept, and the log names it.
#[test]
fn the_remains_of_a_creation_cut_short_are_removed_at_start_up() {
    let dir = tempfile::tempdir().unwrap();
    let (data, start) = on_disk(dir.path());
    let service = start();
    for label in ["cut", "kept"] {
        create(&service, json!({"label": label, "formulas": ["p"]}));
    }
    drop(service);
    let cut = data.join("groups").join("cut");
    std::fs::rename(cut.join("group.json"), cut.join("group.json.tmp")).unwrap();
    let kept = data.join("groups").join("kept");
    std::fs::remove_file(kept.join("group.json")).unwrap();
    let mut trace = std::fs::read_to_string(kept.join("trace.jsonl")).unwrap();
    trace.push_str("{\"t\":0,\"state\":{\"p\":true}}\n");
    std::fs::write(kept.join("trace.jsonl"), &trace).unwrap();

    let service = start();
    assert!(!cut.exists(), "the remains are removed");
    create(&service, json!({"label": "cut", "formulas": ["q"]}));
    let (status, answer) = send(
        &service,
        "POST",
        "/groups",
        Some(json!({"label": "kept", "formulas": ["q"]})),
    );
    assert_eq!(status, 409, "{answer}");
    assert_eq!(
        std::fs::read_to_string(kept.join("trace.jsonl")).unwrap(),
        trace
    );
    let said: Vec<String> = service.tail.lock().unwrap().iter().cloned().collect();
    assert!(
        said.iter()
            .any(|l| l.contains("kept") && l.contains("no group.json")),
        "{said:#?}"
    );
    assert!(
        said.iter()
            .any(|l| l.contains("cut") && l.contains("removed the remains")),
        "{said:#?}"
    );
}

/// `dyknow group`: create, list, show, add, remove, watch, trace, stop, destroy.
#[test]
fn the_group_command_line() {
    let service = Service::start(&[]);
    service.post("/transformations", &read("groups", "uav.ttl"));
    let cli = |args: &[&str]| {
        let out = Command::new(BIN)
            .arg("group")
            .args(args)
            .args(["--url", &service.url])
            .output()
            .unwrap();
        (
            out.status.code().unwrap(),
            String::from_utf8(out.stdout).unwrap(),
            String::from_utf8(out.stderr).unwrap(),
        )
    };
    let (code, out, err) = cli(&[
        "create",
        "--label",
        "cli",
        "--formula",
        "forall x in UAV: always (altitude(x) > 50)",
        // Repeated flags of one domain add up (as `dyknow check`'s do).
        "--domain",
        "UAV=uav1",
        "--domain",
        "UAV=uav2,uav1",
        "--period-ms",
        "100",
        "--max-delay-ms",
        "400",
    ]);
    assert_eq!(code, 0, "{err}");
    let created = serde_json::from_str::<Value>(&out).unwrap();
    assert_eq!(created["state"], "created");
    assert_eq!(
        created["domains"],
        json!({"UAV": ["uav1", "uav2"]}),
        "{created}"
    );
    let (code, out, _) = cli(&["list"]);
    assert_eq!(code, 0);
    assert!(
        out.starts_with("cli\tcreated\t0 states\t0/1 decided"),
        "{out}"
    );
    let (code, out, err) = cli(&["add", "cli", "always[0,1s] altitude(uav1) > 0"]);
    assert_eq!((code, out.trim()), (0, "1"), "{err}");
    let (code, _, err) = cli(&["add", "cli", "always (p"]);
    assert_eq!(code, 2);
    assert!(err.contains("400") && err.contains("column"), "{err}");
    assert_eq!(cli(&["remove", "cli", "1"]).0, 0);
    assert_eq!(cli(&["start", "cli"]).0, 0);
    let started = Instant::now();
    let (code, out, err) = cli(&["watch", "cli", "--count", "1"]);
    assert_eq!(code, 0, "{err}");
    let line: Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(
        (line["formula"].as_u64(), line["verdict"].as_str()),
        (Some(0), Some("false")),
        "{out}"
    );
    assert!(started.elapsed() < Duration::from_secs(60));
    // Replayed with --since.
    let (_, again, _) = cli(&["watch", "cli", "--since", "0", "--count", "1"]);
    assert_eq!(again, out);
    // `--count 0` is a usage error, not a watch that never ends (nor one that prints a line).
    let (code, none, err) = cli(&["watch", "cli", "--since", "0", "--count", "0"]);
    assert_eq!((code, none.as_str()), (2, ""), "{err}");
    let (code, text, _) = cli(&["trace", "cli"]);
    assert_eq!(code, 0);
    assert!(
        text.starts_with("{\"domains\":{\"UAV\":[\"uav1\",\"uav2\"]}"),
        "{text}"
    );
    // A watcher waiting for verdicts ends when the group stops: none can come after.
    let watches = verdict_streams(&service);
    // (Killed on drop, should it hang.)
    let mut watcher = Killed(
        Command::new(BIN)
            .args(["group", "watch", "cli", "--url", &service.url])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    // Its stream is open once the service has answered it (`/metrics` counts the answer).
    eventually("the watcher's stream", Duration::from_secs(30), || {
        (verdict_streams(&service) > watches).then_some(())
    });
    assert_eq!(cli(&["stop", "cli"]).0, 0);
    let ended = eventually("the watcher to end", Duration::from_secs(30), || {
        watcher.0.try_wait().unwrap()
    });
    assert!(ended.success(), "{ended}");
    // And on a stopped group it replays what was recorded and ends.
    let (code, replayed, err) = cli(&["watch", "cli", "--since", "0"]);
    assert_eq!((code, replayed.as_str()), (0, out.as_str()), "{err}");
    let (code, _, err) = cli(&["start", "cli"]);
    assert_eq!(code, 2);
    assert!(err.contains("409"), "{err}");
    let (code, show, _) = cli(&["show", "cli"]);
    assert_eq!(code, 0);
    assert_eq!(
        serde_json::from_str::<Value>(&show).unwrap()["state"],
        "stopped"
    );
    assert_eq!(cli(&["destroy", "cli"]).0, 0);
    assert_eq!(cli(&["show", "cli"]).0, 2);
    // Errors give the service's message, whichever subcommand met them.
    for sub in [
        &["show", "nope"][..],
        &["watch", "nope"],
        &["trace", "nope"],
    ] {
        let (code, _, err) = cli(sub);
        assert_eq!(code, 2, "{sub:?}");
        assert_eq!(
            err.trim(),
            "dyknow: 404: no group labelled \"nope\"",
            "{sub:?}"
        );
    }
    // A flag the policy does not take is refused, as `POST /groups` refuses the field.
    let (code, _, err) = cli(&[
        "create",
        "--formula",
        "p",
        "--sync",
        "event",
        "--period-ms",
        "100",
    ]);
    assert_eq!(code, 2);
    assert!(err.contains("--sync event: takes no --period-ms"), "{err}");
    // One it takes is passed on (`event`'s D), and the policy shows every value.
    let (code, out, err) = cli(&[
        "create",
        "--label",
        "ev",
        "--formula",
        "p",
        "--sync",
        "event",
        "--max-delay-ms",
        "9",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(
        serde_json::from_str::<Value>(&out).unwrap()["sync"],
        json!({"policy": "event", "max_delay_ms": 9})
    );
    assert_eq!(cli(&["destroy", "ev"]).0, 0);
    let (code, _, err) = cli(&["create", "--formula", "p", "--domain", "UAV"]);
    assert_eq!(code, 2);
    assert_eq!(err.trim(), "dyknow: --domain UAV: expected NAME=a,b,...");
    assert_eq!(cli(&["list"]).1, "");
}

/// With no service at the URL, every `dyknow group` subcommand says which URL it could not
/// reach and exits 2 (`group trace` said only "io: Connection refused").
#[test]
fn the_group_command_line_names_a_url_it_cannot_reach() {
    let url = format!("http://127.0.0.1:{}", free_port());
    for args in [
        &["list"][..],
        &["show", "g"],
        &["trace", "g"],
        &["create", "--formula", "p"],
    ] {
        let out = Command::new(BIN)
            .arg("group")
            .args(args)
            .args(["--url", &url])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.contains(&format!("cannot reach {url}")),
            "{args:?}: {stderr}"
        );
    }
}
