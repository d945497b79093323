//! Reconfiguration over HTTP with the life-cycle running: the seed's Example 12, the
//! Chapter 6 case study, and bad input.

use std::collections::BTreeSet;
use std::time::Duration;

use dyknow_acceptance::{Api, spec};
use dyknow_server::ServerConfig;
use serde_json::{Value, json};

/// A service whose scheduled reviews never fire during a test (time unit of an hour): only
/// perturbations and `POST /review` start reviews.
fn api() -> Api {
    Api::with_life_cycle(ServerConfig {
        lifecycle: dyknow_lifecycle::Settings {
            time_unit: Duration::from_secs(3600),
            ..dyknow_lifecycle::Settings::default()
        },
        ..ServerConfig::default()
    })
}

async fn environment(api: &Api) -> Value {
    api.get("/environment").await.expect(200).json()
}

/// Waits until at least `reviews` reviews are done and none is running or pending.
async fn settle(api: &Api, reviews: u64) -> Value {
    for _ in 0..2000 {
        let env = environment(api).await;
        if env["reviews"].as_u64().unwrap_or(0) >= reviews
            && env["phase"] == "stable"
            && env["review_pending"] == false
        {
            return env;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("no review settled: {}", environment(api).await);
}

async fn reviews(api: &Api) -> u64 {
    environment(api).await["reviews"].as_u64().unwrap_or(0)
}

async fn change_sets(api: &Api) -> Vec<Value> {
    api.get("/changesets")
        .await
        .expect(200)
        .json()
        .as_array()
        .cloned()
        .unwrap_or_default()
}

async fn cus(api: &Api) -> Vec<Value> {
    api.get("/cus")
        .await
        .expect(200)
        .json()
        .as_array()
        .cloned()
        .unwrap_or_default()
}

async fn cu_transformations(api: &Api) -> BTreeSet<String> {
    cus(api)
        .await
        .iter()
        .map(|c| c["transformation"].as_str().unwrap_or("").to_owned())
        .collect()
}

/// One field of the actions of one kind, in order (e.g. the transformations spawned).
fn action_field(cs: &Value, kind: &str, field: &str) -> Vec<String> {
    cs["actions"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|a| a["action"] == kind)
        .map(|a| a[field].as_str().unwrap_or("").to_owned())
        .collect()
}

fn spawned(cs: &Value) -> Vec<String> {
    action_field(cs, "spawn", "transformation")
}

fn destroyed(cs: &Value) -> Vec<String> {
    action_field(cs, "destroy", "cu")
}

async fn cu_of(api: &Api, transformation: &str) -> String {
    cus(api)
        .await
        .iter()
        .find(|c| c["transformation"] == transformation)
        .and_then(|c| c["name"].as_str())
        .unwrap_or_else(|| panic!("no CU of {transformation}"))
        .to_owned()
}

/// The `dependsOn` pairs by CU name, from SPARQL.
async fn depends_on(api: &Api) -> BTreeSet<(String, String)> {
    let q = "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> SELECT ?a ?b WHERE { ?x dyknow:dependsOn ?y . ?x dyknow:hasName ?a . ?y dyknow:hasName ?b }";
    let answer = api
        .post("/sparql", "application/sparql-query", q.to_owned())
        .await
        .expect(200)
        .json();
    answer["results"]["bindings"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|b| {
            (
                b["a"]["value"].as_str().unwrap_or("").to_owned(),
                b["b"]["value"].as_str().unwrap_or("").to_owned(),
            )
        })
        .collect()
}

/// A service with Example 12's similarity, transformations and targets, after the review the
/// targets started; returns it with the environment then.
async fn example_12() -> (Api, Value) {
    let api = api();
    api.post_turtle("/ontology", spec("example-12-similarity.ttl"))
        .await
        .expect(201);
    api.post_turtle("/transformations", spec("example-12.ttl"))
        .await
        .expect(201);
    let before = reviews(&api).await;
    api.post_turtle("/targets", spec("example-12-targets.ttl"))
        .await
        .expect(201);
    let env = settle(&api, before + 1).await;
    (api, env)
}

/// A target is satisfied when a CU publishes on its channel what it asks for, as `GET
/// /environment` judges it: a CU publishing something else on the channel is its producer
/// but does not satisfy it (before, `GET /targets` said satisfied for any publisher).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_target_is_satisfied_by_what_its_channel_carries_not_by_a_publisher_alone() {
    let (api, env) = example_12().await;
    assert_eq!(env["valid"], true, "{env}");
    let targets = api.get("/targets").await.expect(200).json();
    for t in targets.as_array().unwrap() {
        assert_eq!(t["satisfied"], true, "{t}");
    }
    let n = reviews(&api).await;
    api.post_turtle(
        "/targets",
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
         [] a dyknow:Target ; rdfs:label \"zzz\" ;
            dyknow:hasChannel [ a dyknow:Channel ; dyknow:hasChannelName \"101\" ] ;
            dyknow:hasTag [ a dyknow:Tag ; dyknow:hasTagDescription <http://example.org/ex12#Zzz> ] .",
    )
    .await
    .expect(201);
    let env = settle(&api, n + 1).await;
    assert_eq!(env["unsatisfied_targets"], json!(["zzz"]), "{env}");
    let zzz = api.get("/targets/zzz").await.expect(200).json();
    assert!(zzz["producer"].is_string(), "{zzz}");
    assert_eq!(zzz["satisfied"], false, "{zzz}");
    let qid1 = api.get("/targets/qid1").await.expect(200).json();
    assert_eq!(qid1["producer"], zzz["producer"]);
    assert_eq!(qid1["satisfied"], true, "{qid1}");
    // The model's JSON says the same.
    let model = api.get("/model?format=dyknow").await.expect(200).json();
    let satisfied: Vec<(Value, Value)> = (model["targets"].as_array().unwrap().iter())
        .map(|t| (t["label"].clone(), t["satisfied"].clone()))
        .collect();
    assert_eq!(
        satisfied,
        [
            (json!("qid1"), json!(true)),
            (json!("qid2"), json!(true)),
            (json!("zzz"), json!(false))
        ]
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn example_12_over_http() {
    let (api, env) = example_12().await;
    assert_eq!(env["valid"], true, "{env}");
    let sets = change_sets(&api).await;
    assert_eq!(sets.len(), 1);
    assert_eq!(sets[0]["cost"]["total"], 33.0);
    assert_eq!(
        sets[0]["cause"],
        json!({"kind": "target-added", "target": "qid1"})
    );
    assert_eq!(spawned(&sets[0]), ["tid1", "tid4", "tid2"]);
    // The JSON model lists the CUs as `GET /cus` does, and every channel with its producer
    // and subscribers: the targets' and the one between the CUs (tid4 feeds tid1 and tid2).
    let model = api.get("/model?format=dyknow").await.expect(200).json();
    assert_eq!(model["cus"].as_array().map(Vec::len), Some(3));
    assert_eq!(model["cus"], api.get("/cus").await.expect(200).json());
    let (c1, c2, c4) = (
        cu_of(&api, "tid1").await,
        cu_of(&api, "tid2").await,
        cu_of(&api, "tid4").await,
    );
    let channels = model["channels"].as_array().cloned().unwrap_or_default();
    let producers: BTreeSet<String> = channels
        .iter()
        .filter_map(|c| c["producer"].as_str().map(str::to_owned))
        .collect();
    assert_eq!(
        producers,
        BTreeSet::from([c1.clone(), c2.clone(), c4.clone()])
    );
    let fed = channels
        .iter()
        .find(|c| c["producer"] == c4.as_str())
        .expect("tid4's channel");
    let subscribers: BTreeSet<&str> = fed["subscribers"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    assert_eq!(subscribers, BTreeSet::from([c1.as_str(), c2.as_str()]));
    assert_eq!(fed["targets"], json!([]));
    assert_eq!(
        depends_on(&api).await,
        BTreeSet::from([(c1.clone(), c4.clone()), (c2.clone(), c4.clone())])
    );

    // tid4's upkeep is observed as 3.0; statistics start no review.
    let n = reviews(&api).await;
    api.post(
        "/statistics",
        "application/json",
        json!({"cu": c4, "upkeep": 3.0}).to_string(),
    )
    .await
    .expect(202);
    assert_eq!(reviews(&api).await, n);
    // tid2's CU crashes: a review at once.
    api.post(
        "/perturbations",
        "application/json",
        json!({"kind": "cu-crashed", "cu": c2}).to_string(),
    )
    .await
    .expect(202);
    settle(&api, n + 1).await;
    let sets = change_sets(&api).await;
    assert_eq!(sets.len(), 2);
    let second = &sets[1];
    assert_eq!(second["cost"]["total"], 43.0);
    assert_eq!(second["cause"], json!({"kind": "cu-crashed", "cu": c2}));
    assert_eq!(spawned(second), ["tid3", "tid2", "tid5"]);
    assert_eq!(destroyed(second), std::slice::from_ref(&c4));
    assert_eq!(
        cu_transformations(&api).await,
        BTreeSet::from(["tid1", "tid2", "tid3", "tid5"].map(String::from))
    );
    assert!(
        cus(&api).await.iter().any(|c| c["name"] == c1),
        "tid1's CU is kept"
    );
    let (n2, n3, n5) = (
        cu_of(&api, "tid2").await,
        cu_of(&api, "tid3").await,
        cu_of(&api, "tid5").await,
    );
    assert_eq!(depends_on(&api).await, BTreeSet::from([(c1, n3), (n2, n5)]));
    // History: `?since`, one by id, its RDF delta, and SPARQL sees the records.
    let since = api.get("/changesets?since=cs-1").await.expect(200).json();
    assert_eq!(since.as_array().map(Vec::len), Some(1));
    // By number when not kept: none after one not given yet; a non-id is a mistake.
    let after = api.get("/changesets?since=cs-99").await.expect(200).json();
    assert_eq!(after, json!([]));
    api.get("/changesets?since=bogus").await.expect(400);
    api.get("/changesets/cs-2").await.expect(200);
    let nt = api
        .get_accept("/changesets/cs-2", "application/n-triples")
        .await
        .expect(200)
        .text();
    assert!(nt.contains("# delete: "), "{nt}");
    api.get("/changesets/cs-9").await.expect(404);
    let q = "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> SELECT (COUNT(?c) AS ?n) WHERE { ?c a dyknow:ChangeSet }";
    let count = api
        .post("/sparql", "application/sparql-query", q.to_owned())
        .await
        .expect(200)
        .json();
    assert_eq!(count["results"]["bindings"][0]["n"]["value"], "2");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn chapter_6_case_study() {
    let api = api();
    // 6.2: the target first; nothing can satisfy it.
    let n = reviews(&api).await;
    api.post_turtle("/targets", spec("ch6-target.ttl"))
        .await
        .expect(201);
    let env = settle(&api, n + 1).await;
    assert_eq!(env["unsatisfied_targets"], json!(["target1"]));
    assert!(change_sets(&api).await.is_empty());

    // 6.3–6.4: Piff registers; the target is unsatisfied, so a review runs at once.
    let n = reviews(&api).await;
    api.post_turtle("/transformations", spec("ch6-piff.ttl"))
        .await
        .expect(201);
    let env = settle(&api, n + 1).await;
    assert_eq!(env["valid"], true, "{env}");
    let piff: BTreeSet<String> = [
        "pose(piff)",
        "bottom_cam(piff)",
        "subsampler(piff)",
        "segmenter(piff)",
        "ball_detector(piff)",
        "ball_localization(piff)",
        "circle_monitor(ball)",
    ]
    .map(String::from)
    .into();
    assert_eq!(cu_transformations(&api).await, piff);
    assert_eq!(change_sets(&api).await.len(), 1);

    // 6.6: the segmenter crashes; only a new segmenter, wired to the existing subsampler.
    let segmenter = cu_of(&api, "segmenter(piff)").await;
    let subsampler = cu_of(&api, "subsampler(piff)").await;
    let n = reviews(&api).await;
    api.post(
        "/perturbations",
        "application/json",
        json!({"kind": "cu-crashed", "cu": segmenter}).to_string(),
    )
    .await
    .expect(202);
    settle(&api, n + 1).await;
    let sets = change_sets(&api).await;
    let repair = sets.last().expect("a change set");
    assert_eq!(spawned(repair), ["segmenter(piff)"]);
    assert!(destroyed(repair).is_empty());
    let new_segmenter = cu_of(&api, "segmenter(piff)").await;
    assert!(
        depends_on(&api)
            .await
            .contains(&(new_segmenter, subsampler))
    );

    // 6.7: Puff registers: no change, also after a review.
    let before = change_sets(&api).await.len();
    api.post_turtle("/transformations", spec("ch6-puff.ttl"))
        .await
        .expect(201);
    let n = reviews(&api).await;
    api.post("/review", "application/json", "")
        .await
        .expect(202);
    settle(&api, n + 1).await;
    assert_eq!(change_sets(&api).await.len(), before);
    assert_eq!(cu_transformations(&api).await, piff);

    // 6.8–6.10: Piff deregisters; Puff's pipeline replaces Piff's.
    // Deregistering a transformation in use starts a review at once; one no CU uses (after an
    // earlier review replaced it) waits for the next scheduled review.
    let n = reviews(&api).await;
    for label in &piff {
        let path = format!("/transformations/{}", percent(label));
        api.delete(&path).await.expect(204);
    }
    settle(&api, n + 1).await;
    let puff: BTreeSet<String> = [
        "pose(puff)",
        "bottom_cam(puff)",
        "subsampler(puff)",
        "segmenter(puff)",
        "ball_detector(puff)",
        "ball_localization(puff)",
        "circle_monitor(ball,puff)",
    ]
    .map(String::from)
    .into();
    assert_eq!(cu_transformations(&api).await, puff);
    assert_eq!(environment(&api).await["valid"], true);

    // 6.11–6.14: the ceiling cameras register (not urgent: nothing at once); at the next
    // review the ceiling pipeline plus Puff's circle monitor.
    let before = change_sets(&api).await.len();
    let n = reviews(&api).await;
    api.post_turtle("/transformations", spec("ch6-ceiling.ttl"))
        .await
        .expect(201);
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(reviews(&api).await, n);
    assert_eq!(change_sets(&api).await.len(), before);
    api.post("/review", "application/json", "")
        .await
        .expect(202);
    settle(&api, n + 1).await;
    let sets = change_sets(&api).await;
    assert_eq!(sets.len(), before + 1);
    // Keeping Puff's pipeline costs 70; switching 10 labour + 10 × 2.0 upkeep.
    let total = sets.last().expect("cs")["cost"]["total"]
        .as_f64()
        .unwrap_or(f64::NAN);
    assert!((total - 30.0).abs() < 1e-9, "{total}");
    let mut ceiling: BTreeSet<String> = (1..=4)
        .flat_map(|i| {
            [
                format!("ceiling_cam(cam_{i})"),
                format!("undistort(cam_{i})"),
            ]
        })
        .collect();
    ceiling.insert("stitch(field)".into());
    ceiling.insert("ball_detector(field)".into());
    ceiling.insert("circle_monitor(ball,puff)".into());
    assert_eq!(cu_transformations(&api).await, ceiling);

    // 6.15–6.16: the target is released; every CU is destroyed.
    let n = reviews(&api).await;
    api.delete("/targets/target1").await.expect(204);
    settle(&api, n + 1).await;
    assert!(cus(&api).await.is_empty());
    assert!(depends_on(&api).await.is_empty());
}

fn percent(label: &str) -> String {
    label
        .bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect()
}

#[tokio::test]
async fn bad_input_changes_nothing() {
    let api = api();
    api.post_turtle("/transformations", spec("example-12.ttl"))
        .await
        .expect(201);
    let snapshot = api.snapshot().await;
    api.post(
        "/perturbations",
        "application/json",
        json!({"kind": "cu-crashed", "cu": "nope"}).to_string(),
    )
    .await
    .expect_error(404);
    api.post(
        "/statistics",
        "application/json",
        json!({"cu": "nope", "upkeep": 1.0}).to_string(),
    )
    .await
    .expect_error(404);
    api.post(
        "/statistics",
        "application/json",
        json!({"transformation": "nope", "labour": 1.0}).to_string(),
    )
    .await
    .expect_error(404);
    // 1.7e308 is finite, but sums of it overflow (the change set's cost was written as null
    // and its record lost at the next start).
    for bad in ["-1.0", "1e999", "1.7e308", "1e13"] {
        api.post(
            "/statistics",
            "application/json",
            format!("{{\"transformation\": \"tid1\", \"labour\": {bad}}}"),
        )
        .await
        .expect_error(if bad == "1e999" { 400 } else { 422 });
    }
    api.post(
        "/statistics",
        "application/json",
        "{\"transformation\": \"tid1\", \"labour\": NaN}",
    )
    .await
    .expect_error(400);
    api.post(
        "/statistics",
        "application/json",
        json!({"transformation": "tid1"}).to_string(),
    )
    .await
    .expect_error(400);
    api.post(
        "/perturbations",
        "application/json",
        json!({"kind": "meteor", "cu": "x"}).to_string(),
    )
    .await
    .expect_error(422);
    // A field that does not fit is named with its line and column, as on every JSON endpoint
    // (the body was read as a value first, and the position was lost).
    for (body, message) in [
        (
            "{\"kind\": \"cu-crashed\",\n \"cu\": 5}",
            "expected a string",
        ),
        ("{\"kind\": \"cu-crashed\"}", "missing field `cu`"),
        (
            "{\"kind\": \"cu-crashed\", \"cu\": \"x\", \"y\": 1}",
            "unknown field `y`",
        ),
    ] {
        let details = api
            .post("/perturbations", "application/json", body.to_owned())
            .await
            .expect_error(400);
        assert_eq!(details.len(), 1, "{body}: {details:?}");
        assert!(
            details[0]["line"].as_u64().is_some_and(|l| l >= 1),
            "{details:?}"
        );
        assert!(
            details[0]["column"].as_u64().is_some_and(|c| c >= 1),
            "{details:?}"
        );
        assert!(
            details[0]["message"]
                .as_str()
                .is_some_and(|m| m.contains(message)),
            "{body}: {details:?}"
        );
    }
    api.post(
        "/cus",
        "application/json",
        json!({"transformation": "nope"}).to_string(),
    )
    .await
    .expect_error(404);
    api.delete("/cus/nope").await.expect_error(404);
    // A name executors cannot address on the data plane (one key chunk) is the client's
    // error, found before any change set is made.
    let long = "n".repeat(201);
    for name in [
        "a/b",
        "x*",
        "@x",
        "what?",
        "a\u{0}b",
        "tab\there",
        "line\n",
        long.as_str(),
        // Path segments clients resolve away: such a CU could not be read or destroyed.
        ".",
        "..",
    ] {
        let answer = api
            .post(
                "/cus",
                "application/json",
                json!({"transformation": "tid3", "name": name}).to_string(),
            )
            .await;
        let body = answer.json();
        answer.expect_error(422);
        assert!(
            body["error"].as_str().unwrap_or("").contains("CU name"),
            "{name}: {body}"
        );
    }
    assert_eq!(api.snapshot().await, snapshot);

    // Spawn and Destroy; a protected CU cannot be destroyed.
    let cu = api
        .post(
            "/cus",
            "application/json",
            json!({"transformation": "tid3", "protected": true}).to_string(),
        )
        .await
        .expect(201)
        .json();
    assert_eq!(cu["transformation"], "tid3");
    assert_eq!(cu["protected"], true);
    let name = cu["name"].as_str().unwrap_or("").to_owned();
    api.post(
        "/cus",
        "application/json",
        json!({"transformation": "tid3", "name": name}).to_string(),
    )
    .await
    .expect_error(409);
    api.delete(&format!("/cus/{name}")).await.expect_error(409);
    assert_eq!(cus(&api).await.len(), 1);
    // Nor is its transformation's spec removed under it (it read as an instance of an unknown
    // transformation, lost its bindings, and the environment stayed invalid).
    let refused = api.delete("/transformations/tid3").await;
    let body = refused.json();
    refused.expect_error(409);
    assert!(
        body["error"].as_str().unwrap_or("").contains(&name),
        "{body}"
    );
    api.get("/transformations/tid3").await.expect(200);
    // One CU takes no query parameter (it was ignored): 400, as on the list.
    api.get(&format!("/cus/{name}")).await.expect(200);
    for query in ["?statistics=true", "?foo=1"] {
        api.get(&format!("/cus/{name}{query}"))
            .await
            .expect_error(400);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn change_sets_are_streamed_as_server_sent_events() {
    use http_body_util::BodyExt;
    use tower::ServiceExt;
    let api = api();
    let request = axum::http::Request::get("/changesets/stream")
        .body(axum::body::Body::empty())
        .expect("request");
    let response = api.router.clone().oneshot(request).await.expect("response");
    assert_eq!(response.status(), 200);
    assert!(
        response
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .is_some_and(|v| v.starts_with("text/event-stream"))
    );
    let mut body = response.into_body();
    api.post_turtle("/ontology", spec("example-12-similarity.ttl"))
        .await
        .expect(201);
    api.post_turtle("/transformations", spec("example-12.ttl"))
        .await
        .expect(201);
    api.post_turtle("/targets", spec("example-12-targets.ttl"))
        .await
        .expect(201);
    let mut text = String::new();
    while !text.contains("\n\n") {
        let frame = tokio::time::timeout(Duration::from_secs(30), body.frame())
            .await
            .expect("an event within 30 s")
            .expect("the stream stays open")
            .expect("a frame");
        if let Ok(data) = frame.into_data() {
            text.push_str(&String::from_utf8_lossy(&data));
        }
    }
    assert!(text.contains("event: changeset\ndata: "), "{text}");
    let data = text
        .lines()
        .find_map(|l| l.strip_prefix("data: "))
        .expect("data");
    let cs: Value = serde_json::from_str(data).expect("change set JSON");
    assert_eq!(cs["id"], "cs-1");
    assert_eq!(cs["cost"]["total"], 33.0);
}

/// Spawn racing reviews (issue 12): while crashes make reviews spawn replacements, many
/// concurrent `POST /cus` ask for CUs. Every name is handed out once, no spawned CU is lost
/// (they are protected, so no review may destroy them), and the model stays valid.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn spawns_racing_reviews_get_unique_names_and_no_cu_is_lost() {
    let (api, _) = example_12().await;
    let mut manual: Vec<String> = Vec::new();
    for _round in 0..8 {
        let victim = cus(&api)
            .await
            .iter()
            .find(|c| c["protected"] == false && c["transformation"] != "tid3")
            .and_then(|c| c["name"].as_str().map(str::to_owned))
            .expect("an unprotected CU to crash");
        let n = reviews(&api).await;
        let crash = {
            let api = api.clone();
            tokio::spawn(async move {
                api.post(
                    "/perturbations",
                    "application/json",
                    json!({"kind": "cu-crashed", "cu": victim}).to_string(),
                )
                .await
                .status
            })
        };
        let spawns: Vec<_> = (0..6)
            .map(|_| {
                let api = api.clone();
                tokio::spawn(async move {
                    api.post(
                        "/cus",
                        "application/json",
                        json!({"transformation": "tid3", "protected": true}).to_string(),
                    )
                    .await
                })
            })
            .collect();
        for spawn in spawns {
            let answer = spawn.await.expect("the spawn task");
            answer.expect(201);
            manual.push(answer.json()["name"].as_str().expect("a name").to_owned());
        }
        assert_eq!(crash.await.expect("the crash task"), 202);
        settle(&api, n + 1).await;
    }
    let names: BTreeSet<&String> = manual.iter().collect();
    assert_eq!(
        names.len(),
        manual.len(),
        "a name handed out twice: {manual:?}"
    );
    let now = cus(&api).await;
    for name in &manual {
        let cu = now
            .iter()
            .find(|c| c["name"] == name.as_str())
            .unwrap_or_else(|| panic!("spawned CU {name} is lost: {now:?}"));
        assert_eq!(cu["transformation"], "tid3", "{cu}");
        assert_eq!(cu["protected"], true, "{cu}");
    }
    // No change set of a review hands out a name a Spawn got, and none twice.
    let mut by_reviews = BTreeSet::new();
    for cs in change_sets(&api).await {
        if cs["cause"]["kind"] == "manual" {
            continue;
        }
        for cu in action_field(&cs, "spawn", "cu") {
            assert!(
                !names.contains(&cu),
                "{cu} was spawned on request and by {}",
                cs["id"]
            );
            assert!(by_reviews.insert(cu.clone()), "{cu} spawned twice");
        }
    }
    let n = reviews(&api).await;
    api.post("/review", "application/json", "")
        .await
        .expect(202);
    let env = settle(&api, n + 1).await;
    assert_eq!(env["valid"], true, "{env}");
}

/// SetConfig keeps one publisher per channel within a CU too: two out ports of one CU bound
/// to one channel is 422, nothing changed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn set_config_refuses_two_out_ports_of_one_cu_on_one_channel() {
    let api = api();
    api.post_turtle(
        "/transformations",
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
         [] a dyknow:Transformation ; rdfs:label \"split\" ;
            dyknow:hasOutPort [ dyknow:hasName \"a\" ; dyknow:hasTag [ dyknow:hasValue \"A\" ] ] ;
            dyknow:hasOutPort [ dyknow:hasName \"b\" ; dyknow:hasTag [ dyknow:hasValue \"B\" ] ] .",
    )
    .await
    .expect(201);
    let cu = api
        .post(
            "/cus",
            "application/json",
            json!({"transformation": "split", "protected": true}).to_string(),
        )
        .await
        .expect(201)
        .json();
    let name = cu["name"].as_str().unwrap_or("").to_owned();
    let put = |body: Value| put_config(&api, &name, body);
    let snapshot = api.snapshot().await;
    for body in [
        json!({"outputs": {"a": "x", "b": "x"}}),
        json!({"outputs": {"a": "y"}}),
    ] {
        if body["outputs"]["a"] == "y" {
            // First bind b to y alone (accepted), then a to y too (refused).
            put(json!({"outputs": {"b": "y"}})).await.expect(200);
        }
        let answer = put(body.clone()).await;
        let error = answer.json();
        answer.expect_error(422);
        assert!(
            error["error"]
                .as_str()
                .unwrap_or("")
                .contains("one publisher per channel"),
            "{body}: {error}"
        );
        if body["outputs"]["a"] == "x" {
            assert_eq!(api.snapshot().await, snapshot, "nothing changed");
        }
    }
    // Different channels are fine.
    put(json!({"outputs": {"a": "x", "b": "z"}}))
        .await
        .expect(200);
}

/// SetConfig: `PUT /cus/{cu}/config` with `body`.
async fn put_config(api: &Api, cu: &str, body: Value) -> dyknow_acceptance::Answer {
    api.send(dyknow_acceptance::request(
        axum::http::Method::PUT,
        &format!("/cus/{cu}/config"),
        &[("content-type", "application/json")],
        body.to_string().into(),
    ))
    .await
}

/// Waits until no review runs or is pending.
async fn quiet(api: &Api) {
    let reviews = reviews(api).await;
    settle(api, reviews).await;
}

/// `dependsOn` as the CUs' bindings say it (`GET /cus`): `a` depends on `b` when `a` reads a
/// channel `b` publishes on, directly or through other CUs.
async fn depends_on_by_bindings(api: &Api) -> BTreeSet<(String, String)> {
    let cus = cus(api).await;
    let bound = |cu: &Value, ports: &str| -> Vec<String> {
        cu[ports]
            .as_object()
            .into_iter()
            .flatten()
            .filter_map(|(_, c)| c.as_str().map(str::to_owned))
            .collect()
    };
    let mut pairs = BTreeSet::new();
    for a in &cus {
        for b in &cus {
            let reads = bound(a, "inputs");
            if bound(b, "outputs").iter().any(|c| reads.contains(c)) {
                pairs.insert((
                    a["name"].as_str().unwrap_or("").to_owned(),
                    b["name"].as_str().unwrap_or("").to_owned(),
                ));
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

/// A spec posted again with its ports renamed leaves no subscription of the old ports behind:
/// after every step the store's `dependsOn` is what the bindings of `GET /cus` say, and no
/// subscription names a port that is gone (a user audit found the old subscription kept with
/// its `fromCU`, so `mid dependsOn src` stayed derived, and came back with the old port).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_spec_posted_again_with_a_port_renamed_leaves_no_stale_subscription() {
    let api = api();
    // Tags no port produces: no review binds anything, only SetConfig does.
    let spec = |label: &str, port: &str, direction: &str| {
        format!(
            "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
             @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
             [] a dyknow:Transformation ; rdfs:label \"{label}\" ;
                dyknow:{direction} [ dyknow:hasName \"{port}\" ;
                                     dyknow:hasTag [ dyknow:hasValue \"{label}-{port}\" ] ] ."
        )
    };
    api.post_turtle("/transformations", spec("src", "out", "hasOutPort"))
        .await
        .expect(201);
    api.post_turtle("/transformations", spec("mid", "in", "hasInPort"))
        .await
        .expect(201);
    for (transformation, name) in [("src", "src"), ("mid", "mid")] {
        api.post(
            "/cus",
            "application/json",
            json!({"transformation": transformation, "name": name, "protected": true}).to_string(),
        )
        .await
        .expect(201);
    }
    let put = |cu: &'static str, body: Value| {
        let api = &api;
        async move {
            put_config(api, cu, body).await.expect(200);
        }
    };
    let dangling = "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> \
                    ASK { ?s dyknow:toPort|dyknow:fromPort ?port \
                          FILTER NOT EXISTS { ?port dyknow:hasName ?name } }";
    let check = |step: &'static str| {
        let api = &api;
        async move {
            quiet(api).await;
            let by_bindings = depends_on_by_bindings(api).await;
            assert_eq!(
                depends_on(api).await,
                by_bindings,
                "{step}: {:?}",
                cus(api).await
            );
            let answer = api
                .post("/sparql", "application/sparql-query", dangling.to_owned())
                .await
                .expect(200)
                .json();
            assert_eq!(
                answer["boolean"], false,
                "{step}: a binding names a port that is gone"
            );
            by_bindings
        }
    };
    let pair = BTreeSet::from([("mid".to_owned(), "src".to_owned())]);
    put("src", json!({"outputs": {"out": "c1"}})).await;
    put("mid", json!({"inputs": {"in": "c1"}})).await;
    assert_eq!(check("bound").await, pair);
    api.post_turtle("/transformations", spec("mid", "in2", "hasInPort"))
        .await
        .expect(201);
    assert_eq!(check("in port renamed").await, BTreeSet::new());
    put("src", json!({"outputs": {"out": "c2"}})).await;
    check("producer moved").await;
    api.post_turtle("/transformations", spec("mid", "in", "hasInPort"))
        .await
        .expect(201);
    check("old in port back").await;
    put("mid", json!({"inputs": {"in": "c2"}})).await;
    assert_eq!(check("bound again").await, pair);
    api.post_turtle("/transformations", spec("src", "out2", "hasOutPort"))
        .await
        .expect(201);
    assert_eq!(check("out port renamed").await, BTreeSet::new());
    api.post_turtle("/transformations", spec("src", "out", "hasOutPort"))
        .await
        .expect(201);
    check("old out port back").await;
}

/// A spec posted again with another implementation (here a parameter) replaces the CUs of the
/// transformation: the seed (Ch. 4) says the behaviour of such CUs "becomes undefined, and they
/// therefore require removal" (a user audit saw the old CU compute with the old factor on and
/// on). The same spec posted again, or one changing only costs, leaves them; a protected CU is
/// left as it runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_spec_posted_again_with_another_implementation_replaces_its_cus() {
    let api = api();
    let source = |period: u32, upkeep: f64| {
        format!(
            "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
             @prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .
             @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
             [] a dkros:ROSTransformation ; rdfs:label \"src\" ;
                dkros:hasType \"builtin\" ; dkros:hasSource \"dyknow/signal\" ;
                dkros:hasParam [ dyknow:hasName \"zeta\" ;
                                 dyknow:hasValue \"1.0\"^^<http://www.w3.org/2001/XMLSchema#double> ] ,
                               [ dyknow:hasName \"period_ms\" ; dyknow:hasValue {period} ] ,
                               [ dyknow:hasName \"alpha\" ; dyknow:hasValue 2 ] ;
                dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"S\" ] ] ;
                dyknow:hasCostModel [ a dyknow:UpkeepCostModel ; dyknow:hasValue {upkeep:?} ] ."
        )
    };
    api.post_turtle("/transformations", source(100, 1.0))
        .await
        .expect(201);
    let before = reviews(&api).await;
    api.post_turtle(
        "/targets",
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
         [] a dyknow:Target ; rdfs:label \"t\" ;
            dyknow:hasChannel [ dyknow:hasChannelName \"/t\" ] ;
            dyknow:hasTag [ dyknow:hasValue \"S\" ] ."
            .to_owned(),
    )
    .await
    .expect(201);
    settle(&api, before + 1).await;
    let first = cu_of(&api, "src").await;
    // The same implementation (the same spec, three parameters whose stored order is not the
    // document's, one typed whose stored form is not the document's, `1` for `"1.0"`; other
    // costs): the CU stays.
    for (period, upkeep) in [(100, 1.0), (100, 1.0), (100, 1.0), (100, 2.0)] {
        api.post_turtle("/transformations", source(period, upkeep))
            .await
            .expect(201);
        quiet(&api).await;
        assert_eq!(
            cu_of(&api, "src").await,
            first,
            "period {period}, upkeep {upkeep}"
        );
    }
    let sets = change_sets(&api).await.len();
    // Another parameter: the CU is replaced, by a review caused by the spec change (not a
    // crash: the crash count does not move).
    let before = reviews(&api).await;
    let crashes = environment(&api).await["crashes"].clone();
    api.post_turtle("/transformations", source(250, 2.0))
        .await
        .expect(201);
    settle(&api, before + 1).await;
    let second = cu_of(&api, "src").await;
    assert_ne!(second, first);
    assert_eq!(cus(&api).await.len(), 1, "{:?}", cus(&api).await);
    let all = change_sets(&api).await;
    assert_eq!(all.len(), sets + 1, "{all:?}");
    let last = all.last().expect("a change set");
    assert_eq!(last["cause"]["kind"], "spec-changed", "{last}");
    assert_eq!(last["cause"]["cus"], json!([first.as_str()]), "{last}");
    assert_eq!(spawned(last), ["src"], "{last}");
    assert_eq!(environment(&api).await["crashes"], crashes);
    // A protected CU of it is left as it runs.
    api.post(
        "/cus",
        "application/json",
        json!({"transformation": "src", "name": "kept", "protected": true}).to_string(),
    )
    .await
    .expect(201);
    api.post_turtle("/transformations", source(300, 2.0))
        .await
        .expect(201);
    quiet(&api).await;
    assert!(
        cus(&api).await.iter().any(|c| c["name"] == "kept"),
        "{:?}",
        cus(&api).await
    );
}
