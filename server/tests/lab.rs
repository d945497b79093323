//! The whole of the thesis' Chapter 6 with running components: the simulated humanoid lab
//! (`dyknow-lab`) on three stand-alone executors, `piff`, `puff` and `lab`, driven over HTTP.
//! Every step checks the CUs that run, the values that flow, `dependsOn` in the store against
//! the running configuration, and the change sets' causes and costs; the outage of each repair
//! and the cost of each configuration are printed (`docs/lab.md` reports a run).
#![cfg(feature = "rocksdb")]
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;
use std::time::{Duration, Instant};

use dyknow_cu::Sample;
use dyknow_lab::World;
use dyknow_lab::world::inside_circle;
use serde_json::Value;

mod support;

use support::*;

/// The running CUs: name → CU.
fn cus(service: &Service) -> BTreeMap<String, Value> {
    service
        .get("/cus")
        .as_array()
        .unwrap()
        .iter()
        .map(|c| (c["name"].as_str().unwrap().to_owned(), c.clone()))
        .collect()
}

/// The running CUs once their transformations are exactly `transformations`, all running. On a
/// timeout the panic says what was last seen (each CU's transformation, state and executor),
/// the last change sets, and the service's last lines.
fn settled(service: &Service, transformations: &[&str]) -> BTreeMap<String, Value> {
    let want: BTreeSet<&str> = transformations.iter().copied().collect();
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let cus = cus(service);
        let have: BTreeSet<&str> = cus
            .values()
            .map(|c| c["transformation"].as_str().unwrap())
            .collect();
        if have == want && cus.values().all(|c| c["state"] == "running") {
            return cus;
        }
        if Instant::now() >= deadline {
            let seen: Vec<String> = cus
                .values()
                .map(|c| {
                    format!(
                        "{} {} on {}",
                        c["transformation"], c["state"], c["executor"]
                    )
                })
                .collect();
            let change_sets = service.change_sets();
            let last: Vec<String> = change_sets
                .iter()
                .rev()
                .take(3)
                .map(|c| format!("{} {} {}", c["cause"], c["status"], c["cost"]))
                .collect();
            service.failed(
                "timed out waiting for the configuration",
                format!(
                    "want {want:?}; last seen {seen:?}; executors {}; last change sets (newest first) {last:?}",
                    service.get("/executors")
                ),
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// `dependsOn` in the store (SPARQL over the materialised graph) by CU name.
fn depends_on(service: &Service) -> BTreeSet<(String, String)> {
    let q = "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> SELECT ?a ?b WHERE { ?x dyknow:dependsOn ?y . ?x dyknow:hasName ?a . ?y dyknow:hasName ?b }";
    let mut r = agent()
        .post(&format!("{}/sparql", service.url))
        .header("Content-Type", "application/sparql-query")
        .send(q.as_bytes())
        .unwrap();
    let answer: Value = serde_json::from_str(&r.body_mut().read_to_string().unwrap()).unwrap();
    answer["results"]["bindings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            (
                b["a"]["value"].as_str().unwrap().to_owned(),
                b["b"]["value"].as_str().unwrap().to_owned(),
            )
        })
        .collect()
}

/// `dependsOn` of a configuration: the transitive closure of "subscribes to a channel the
/// other publishes on".
fn implied_depends_on(cus: &BTreeMap<String, Value>) -> BTreeSet<(String, String)> {
    let mut publisher = BTreeMap::new();
    for (name, cu) in cus {
        for channel in cu["outputs"].as_object().unwrap().values() {
            publisher.insert(channel.as_str().unwrap().to_owned(), name.clone());
        }
    }
    let mut pairs = BTreeSet::new();
    for (name, cu) in cus {
        for channel in cu["inputs"].as_object().unwrap().values() {
            if let Some(p) = channel.as_str().and_then(|c| publisher.get(c)) {
                pairs.insert((name.clone(), p.clone()));
            }
        }
    }
    loop {
        let more: Vec<(String, String)> = pairs
            .iter()
            .flat_map(|(a, b)| {
                pairs
                    .iter()
                    .filter(move |(c, _)| c == b)
                    .map(move |(_, d)| (a.clone(), d.clone()))
            })
            .filter(|p| !pairs.contains(p))
            .collect();
        if more.is_empty() {
            return pairs;
        }
        pairs.extend(more);
    }
}

fn assert_depends_on_matches(service: &Service, cus: &BTreeMap<String, Value>, step: &str) {
    let implied = implied_depends_on(cus);
    let stored = eventually("dependsOn to match", Duration::from_secs(10), || {
        let stored = depends_on(service);
        (stored == implied).then_some(stored)
    });
    assert!(!stored.is_empty() || cus.is_empty(), "{step}");
}

/// The CU of a transformation in a configuration.
fn of<'a>(cus: &'a BTreeMap<String, Value>, transformation: &str) -> &'a Value {
    cus.values()
        .find(|c| c["transformation"] == transformation)
        .unwrap_or_else(|| panic!("no CU of {transformation}"))
}

/// Position samples on `channel`: each within the tolerance of the truth at its time.
fn positions_are_true(service: &Service, channel: &str, n: usize, step: &str) {
    let session = service.session();
    let listener = Listener::new(&session, channel);
    let world = World::default();
    let mut worst = 0.0f64;
    for _ in 0..n {
        let (_, s) = listener.next();
        let (x, y) = (
            s.value["x"].as_f64().unwrap(),
            s.value["y"].as_f64().unwrap(),
        );
        let (bx, by) = world.ball_at(s.t);
        let error = (x - bx).hypot(y - by);
        worst = worst.max(error);
        assert!(
            error < dyknow_lab::POSITION_TOLERANCE,
            "{step}: ({x:.3}, {y:.3}) at {} but the ball is at ({bx:.3}, {by:.3})",
            s.t
        );
    }
    eprintln!("{step}: {n} positions, worst error {worst:.3} m");
}

/// Ports' statistics as the CU's executor counts them, from one report: (samples, `t` of the
/// last one) per port.
fn ports<const N: usize>(
    service: &Service,
    cus: &BTreeMap<String, Value>,
    transformation: &str,
    ports: [&str; N],
) -> [(i64, i64); N] {
    let name = of(cus, transformation)["name"].as_str().unwrap().to_owned();
    let statistics = service.get(&format!("/cus/{name}"))["statistics"]["ports"].clone();
    ports.map(|port| {
        (
            statistics[port]["messages"].as_i64().unwrap_or(0),
            statistics[port]["last_t"].as_i64().unwrap_or(i64::MIN),
        )
    })
}

/// Over `seconds` of Piff's pipeline, as its executor counts them (no network between): the
/// pose publishes every tick, and every pixel the localisation receives becomes a position
/// (`docs/lab.md`, "No sample is lost to the host's timing": a pose whose timer fired late,
/// and a pixel that arrived before its poses, were lost).
fn nothing_lost_between_stages(service: &Service, cus: &BTreeMap<String, Value>, seconds: i64) {
    const POSE_PERIOD_MS: i64 = 20; // nao/pose at its default 50 Hz (the spec sets no fps)
    let counts = || {
        let [pose] = ports(service, cus, "pose(piff)", ["pose"]);
        let [pixels, positions] = ports(
            service,
            cus,
            "ball_localization(piff)",
            ["pixelPos", "position"],
        );
        // A pixel waiting for its pose when the counts are read is not lost.
        let waiting = i64::from(pixels.1 > positions.1);
        (pose, pixels.0 - positions.0 - waiting, pixels.0)
    };
    let (pose, lost, pixels) =
        eventually("Piff's first positions", Duration::from_secs(30), || {
            let c = counts();
            (c.2 > 0).then_some(c)
        });
    let (pose_after, lost_after, pixels_after) =
        eventually("Piff's pipeline to run on", Duration::from_secs(30), || {
            let c = counts();
            (c.0.1 >= pose.1 + seconds * 1_000).then_some(c)
        });
    let ticks = (pose_after.1 - pose.1) / POSE_PERIOD_MS;
    assert_eq!(
        pose_after.0 - pose.0,
        ticks,
        "pose samples published from t = {} to {}",
        pose.1,
        pose_after.1
    );
    let received = pixels_after - pixels;
    assert_eq!(
        lost_after - lost,
        0,
        "of {received} pixels, {} not localised",
        lost_after - lost
    );
    eprintln!("Piff over {seconds} s: {ticks} pose ticks and {received} pixels, none lost");
}

/// How late samples arrive on `channels` over `seconds`: from the time a sample stands for
/// (its `t`) to its arrival here, in ms. A source stamps its samples with the tick of its
/// clock nearest to when its timer fires, so the lateness is offset by the phase between
/// timer and clock (up to half a period either way); its spread, the jitter, is not.
/// Printed, not asserted: it measures the host's timing (`docs/lab.md`, "Timers").
fn lateness(session: &dyknow_cu::zenoh::Session, channels: &[(&str, &str)], seconds: u64) {
    let listeners: Vec<(&str, Listener)> = channels
        .iter()
        .map(|(what, channel)| (*what, Listener::new(session, channel)))
        .collect();
    let (start, start_ms) = now();
    // A window of measurement, not a wait for a condition.
    std::thread::sleep(Duration::from_secs(seconds));
    for (what, listener) in listeners {
        let mut late: Vec<i64> = listener
            .drain()
            .into_iter()
            .map(|(arrived, s)| {
                let arrived_ms = start_ms
                    + i64::try_from(arrived.saturating_duration_since(start).as_millis()).unwrap();
                arrived_ms - s.t
            })
            .collect();
        late.sort_unstable();
        if let (Some(min), Some(median), Some(max)) =
            (late.first(), late.get(late.len() / 2), late.last())
        {
            eprintln!(
                "{what}: {} samples in {seconds} s, late by {min} / {median} / {max} ms (min / median / max), jitter {} ms",
                late.len(),
                max - min
            );
        }
    }
}

/// How long the target's stream was interrupted by something at `at_ms`: from then to the
/// first sample computed from a frame after it.
fn outage(target: &Listener, (at, at_ms): (Instant, i64)) -> u128 {
    loop {
        let (arrived, s): (Instant, Sample) = target.next();
        if s.t > at_ms {
            return arrived.saturating_duration_since(at).as_millis();
        }
    }
}

/// The longest time between two samples arriving from `from` to `until` (make before break:
/// a switch should not interrupt the stream).
fn longest_gap(target: &Listener, from: Instant, until: Instant) -> u128 {
    let mut last = from;
    let mut longest = 0;
    loop {
        let (arrived, _) = target.next();
        if arrived < from {
            continue;
        }
        longest = longest.max(arrived.duration_since(last).as_millis());
        last = arrived;
        if arrived > until {
            return longest;
        }
    }
}

fn now() -> (Instant, i64) {
    (Instant::now(), dyknow_cu::now_ms())
}

fn change_sets_after(service: &Service, seen: usize) -> Vec<Value> {
    service.change_sets().into_iter().skip(seen).collect()
}

fn spawned(change_set: &Value) -> Vec<String> {
    change_set["actions"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == "spawn")
        .map(|a| a["transformation"].as_str().unwrap().to_owned())
        .collect()
}

fn destroyed(change_set: &Value) -> usize {
    change_set["actions"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == "destroy")
        .count()
}

/// The learned upkeep of transformations, once each has `min` observations.
fn measured(service: &Service, transformations: &[&str], min: u64) -> f64 {
    eventually("measured upkeep", Duration::from_secs(60), || {
        let stats = service.get("/statistics");
        let mut sum = 0.0;
        for t in transformations {
            let learned = &stats["transformations"][*t]["learned_upkeep"];
            if learned["observations"].as_u64().unwrap_or(0) < min {
                return None;
            }
            sum += learned["average"].as_f64().unwrap();
        }
        Some(sum)
    })
}

/// The specs' estimates of `transformations`, summed: (labour, upkeep per second).
fn budgets(service: &Service, transformations: &[&str]) -> (f64, f64) {
    transformations
        .iter()
        .fold((0.0, 0.0), |(labour, upkeep), t| {
            let spec = service.get(&format!("/transformations/{t}"));
            (
                labour + spec["labour"].as_f64().unwrap(),
                upkeep + spec["upkeep"].as_f64().unwrap(),
            )
        })
}

const PIFF: [&str; 7] = [
    "pose(piff)",
    "bottom_cam(piff)",
    "subsampler(piff)",
    "segmenter(piff)",
    "ball_detector(piff)",
    "ball_localization(piff)",
    "circle_monitor(ball)",
];
const PUFF: [&str; 7] = [
    "pose(puff)",
    "bottom_cam(puff)",
    "subsampler(puff)",
    "segmenter(puff)",
    "ball_detector(puff)",
    "ball_localization(puff)",
    "circle_monitor(ball,puff)",
];
const CEILING: [&str; 10] = [
    "ceiling_cam(cam_1)",
    "undistort(cam_1)",
    "ceiling_cam(cam_2)",
    "undistort(cam_2)",
    "ceiling_cam(cam_3)",
    "undistort(cam_3)",
    "ceiling_cam(cam_4)",
    "undistort(cam_4)",
    "stitch(field)",
    "ball_detector(field)",
];

#[test]
fn chapter_6_runs_live_on_three_executors() {
    // Each step's start, printed: a slow run shows where its time went.
    let began = Instant::now();
    let step = |what: &str| eprintln!("[{:5.1} s] {what}", began.elapsed().as_secs_f64());
    let service = Service::start(&["--no-executor"]);
    step("(6.2): the target first; nothing can produce it");
    service.post("/targets", &spec("ch6-target.ttl"));
    for f in [
        "ch6-live-piff.ttl",
        "ch6-live-puff.ttl",
        "ch6-live-ceiling.ttl",
    ] {
        service.post("/transformations", &spec(f));
    }
    assert!(cus(&service).is_empty());
    assert_eq!(service.get("/environment")["valid"], false);
    let session = service.session();
    let target = Listener::new(&session, "/target_1");

    step("(6.3)–(6.4): Piff's executor joins; its seven CUs run and compute");
    let seen = service.change_sets().len();
    let mut piff = executor(&service, "piff");
    let config = settled(&service, &PIFF);
    assert!(config.values().all(|c| c["executor"] == "piff"));
    let started = change_sets_after(&service, seen)
        .into_iter()
        .find(|c| spawned(c).len() == 7)
        .expect("a change set spawning Piff's pipeline");
    assert_eq!(started["cause"]["kind"], "review", "{started}");
    // Its cost is the specs' estimates (nothing measured yet): 6 × 0.1 + 16 labour, the
    // budgets' 411.6 upkeep per second.
    assert!(
        (started["cost"]["labour"].as_f64().unwrap() - 16.6).abs() < 1e-9,
        "{started}"
    );
    assert!(
        (started["cost"]["upkeep_per_time_unit"].as_f64().unwrap() - 411.6).abs() < 1e-9,
        "{started}"
    );
    eprintln!("Piff's pipeline: {}", started["cost"]);
    assert_depends_on_matches(&service, &config, "Piff");
    let position = of(&config, "circle_monitor(ball)")["inputs"]["position"]
        .as_str()
        .unwrap()
        .to_owned();
    positions_are_true(&service, &position, 20, "Piff");
    nothing_lost_between_stages(&service, &config, 3);
    let pose = of(&config, "pose(piff)")["outputs"]["pose"]
        .as_str()
        .unwrap()
        .to_owned();
    lateness(
        &session,
        &[
            ("pose", &pose),
            ("position", &position),
            ("target", "/target_1"),
        ],
        3,
    );
    for _ in 0..10 {
        let (_, s) = target.next();
        let (x, y) = World::default().ball_at(s.t);
        assert_eq!(
            s.value,
            Value::Bool(inside_circle(x, y)),
            "InsideCircle at {}",
            s.t
        );
    }

    step("(6.5)–(6.6): kill -9 of the segmenter");
    // (6.5)–(6.6): kill -9 of the segmenter, a process CU; a new one is wired to the running
    // subsampler.
    let segmenter = of(&config, "segmenter(piff)").clone();
    let name = segmenter["name"].as_str().unwrap().to_owned();
    let pid = service.get(&format!("/cus/{name}"))["pid"]
        .as_u64()
        .unwrap();
    let killed_at = now();
    Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .unwrap();
    let repair = crash_change_set(&service, &name);
    let gap = outage(&target, killed_at);
    assert_eq!(repair["status"], "applied", "{repair}");
    assert_eq!(spawned(&repair), ["segmenter(piff)"], "{repair}");
    assert_eq!(destroyed(&repair), 0, "{repair}");
    let config = settled(&service, &PIFF);
    let subsampler = of(&config, "subsampler(piff)");
    assert_eq!(subsampler["name"], of(&config, "subsampler(piff)")["name"]);
    let new_segmenter = of(&config, "segmenter(piff)");
    assert_ne!(new_segmenter["name"], segmenter["name"]);
    assert_eq!(
        new_segmenter["inputs"]["pyramid"], subsampler["outputs"]["pyramid"],
        "the new segmenter reads the running subsampler's pyramid"
    );
    for t in PIFF.iter().filter(|t| **t != "segmenter(piff)") {
        assert!(
            config.contains_key(of(&config, t)["name"].as_str().unwrap()),
            "{t} kept"
        );
    }
    eprintln!(
        "segmenter killed: target stream back after {gap} ms; repair {}",
        repair["cost"]
    );
    assert_depends_on_matches(&service, &config, "segmenter replaced");
    let before_puff: BTreeSet<String> = config.keys().cloned().collect();

    step("(6.7): Puff joins; nothing changes, also after a review");
    // Piff's running pipeline is measured before Puff's budget is compared with it.
    measured(&service, &PIFF, 5);
    let mut puff = executor(&service, "puff");
    eventually("Puff's executor", Duration::from_secs(30), || {
        service
            .get("/executors")
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["name"] == "puff" && e["present"] == true)
            .then_some(())
    });
    let seen = service.change_sets().len();
    let mut r = agent()
        .post(&format!("{}/review", service.url))
        .send_empty()
        .unwrap();
    assert!(
        r.status().is_success(),
        "{}",
        r.body_mut().read_to_string().unwrap()
    );
    let piff_upkeep = measured(&service, &PIFF, 2);
    for c in change_sets_after(&service, seen) {
        assert!(
            c["actions"].as_array().unwrap().is_empty(),
            "Puff joining changed something: {c}"
        );
    }
    assert_eq!(
        cus(&service).keys().cloned().collect::<BTreeSet<_>>(),
        before_puff
    );
    eprintln!(
        "Puff joined: nothing changed (Piff's pipeline measured at {piff_upkeep:.1} CPU ms/s)"
    );

    step("(6.7)–(6.10): Piff leaves (its executor killed); Puff's pipeline takes over");
    let left_at = now();
    piff.0.kill().unwrap();
    piff.0.wait().unwrap();
    let config = settled(&service, &PUFF);
    let gap = outage(&target, left_at);
    assert!(config.values().all(|c| c["executor"] == "puff"));
    let takeover = service
        .change_sets()
        .into_iter()
        .rev()
        .find(|c| spawned(c).len() == 7)
        .unwrap();
    eprintln!(
        "Piff left: target stream back after {gap} ms; Puff's pipeline {}",
        takeover["cost"]
    );
    assert_depends_on_matches(&service, &config, "Puff");
    let position = of(&config, "circle_monitor(ball,puff)")["inputs"]["position"]
        .as_str()
        .unwrap()
        .to_owned();
    positions_are_true(&service, &position, 20, "Puff");
    let monitor = of(&config, "circle_monitor(ball,puff)")["name"].clone();

    step("(6.11)–(6.14): the lab joins; the ceiling cameras take over");
    // (6.11)–(6.14): the lab joins; once Puff's upkeep is measured, the next review switches
    // to the ceiling cameras, keeping Puff's circle monitor.
    let puff_upkeep = measured(&service, &PUFF, 2);
    // The premise of eqs. 6.12–6.14, checked first so that a machine where it does not hold
    // says so rather than waiting for a switch that no review makes: the ceiling's estimated
    // cost over the horizon (its labour, H × its budgets and Puff's monitor, which it keeps)
    // is below H × Puff's measured upkeep.
    let horizon = service.get("/environment")["cost"]["horizon"]
        .as_f64()
        .unwrap();
    let (ceiling_labour, ceiling_budget) = budgets(&service, &CEILING);
    let monitor_upkeep = measured(&service, &["circle_monitor(ball,puff)"], 2);
    let switch_cost = ceiling_labour + horizon * (ceiling_budget + monitor_upkeep);
    eprintln!(
        "before the lab joins: Puff measured {puff_upkeep:.1} CPU ms/s, so keeping it costs {:.1}; the switch is estimated at {ceiling_labour:.1} + {horizon} × ({ceiling_budget:.1} + {monitor_upkeep:.2}) = {switch_cost:.1}",
        horizon * puff_upkeep
    );
    assert!(
        switch_cost < horizon * puff_upkeep,
        "the ceiling's budgets are not below Puff's measured upkeep on this machine, so no review would switch: remeasure them (docs/lab.md, \"Estimates\")"
    );
    let seen = service.change_sets().len();
    let switch_from = now();
    let mut lab = executor(&service, "lab");
    let mut want: Vec<&str> = CEILING.to_vec();
    want.push("circle_monitor(ball,puff)");
    let config = settled(&service, &want);
    let switch = change_sets_after(&service, seen)
        .into_iter()
        .find(|c| spawned(c).len() == 10)
        .expect("the switch");
    assert_eq!(switch["cause"]["kind"], "review", "{switch}");
    assert_eq!(destroyed(&switch), 6, "Puff's six other CUs go: {switch}");
    assert_eq!(
        of(&config, "circle_monitor(ball,puff)")["name"],
        monitor,
        "cid9 is reused"
    );
    let gap = longest_gap(
        &target,
        switch_from.0,
        Instant::now() + Duration::from_secs(1),
    );
    eprintln!(
        "lab joined: switched; longest gap in the target stream {gap} ms; {}",
        switch["cost"]
    );
    assert_depends_on_matches(&service, &config, "ceiling");
    let position = of(&config, "circle_monitor(ball,puff)")["inputs"]["position"]
        .as_str()
        .unwrap()
        .to_owned();
    positions_are_true(&service, &position, 20, "ceiling");
    // The measurement confirms the choice: the ceiling pipeline with Puff's monitor costs
    // less per second than Puff's pipeline did.
    let mut ceiling_and_monitor: Vec<&str> = CEILING.to_vec();
    ceiling_and_monitor.push("circle_monitor(ball,puff)");
    let ceiling_upkeep = measured(&service, &ceiling_and_monitor, 2);
    eprintln!(
        "measured upkeep, CPU ms/s: Piff {piff_upkeep:.1}, Puff {puff_upkeep:.1}, ceiling + Puff's monitor {ceiling_upkeep:.1}"
    );
    assert!(
        ceiling_upkeep < puff_upkeep,
        "{ceiling_upkeep} ≥ {puff_upkeep}"
    );

    step("(6.15)–(6.16): the target is released; every CU stops, no process is left");
    let r = agent()
        .delete(&format!("{}/targets/target1", service.url))
        .call()
        .unwrap();
    assert!(r.status().is_success());
    eventually("every CU to stop", Duration::from_secs(30), || {
        cus(&service).is_empty().then_some(())
    });
    let released = service.change_sets().into_iter().last().unwrap();
    assert_eq!(released["cause"]["kind"], "target-released", "{released}");
    assert_eq!(destroyed(&released), 11, "{released}");
    assert!(depends_on(&service).is_empty());
    eventually("no CU process left", Duration::from_secs(10), || {
        (children(puff.0.id()).is_empty() && children(lab.0.id()).is_empty()).then_some(())
    });
    assert!(!alive(pid), "the killed segmenter");
    for executor in [&mut puff, &mut lab] {
        sigterm(&executor.0);
        assert!(wait_exit(&mut executor.0).success());
    }
}
