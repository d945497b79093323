//! Reconfiguration end to end over HTTP (issue: engine): `cargo bench --workspace --bench
//! reconfig_http`. The Chapter 6 case study on the on-disk store with the life-cycle running:
//! Piff's seven CUs, then the segmenter crashes (`POST /perturbations`); measured is the time
//! from sending the perturbation until the review that repairs the pipeline has written its
//! change set (polling `GET /changesets`, an in-memory read), through the in-process router (no
//! socket).
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a benchmark binary"
)]

use std::time::{Duration, Instant};

use axum::body::Body;
use axum::http::Request;
use dyknow_server::{AppState, ServerConfig, app};
use dyknow_store::KnowledgeBase;
use http_body_util::BodyExt;
use tower::ServiceExt;

async fn call(
    router: &axum::Router,
    method: &str,
    uri: &str,
    ct: &str,
    body: String,
) -> (u16, String) {
    let request = Request::builder()
        .method(method)
        .uri(uri)
        .header("content-type", ct)
        .body(Body::from(body))
        .unwrap();
    let response = router.clone().oneshot(request).await.unwrap();
    let status = response.status().as_u16();
    let bytes = response.into_body().collect().await.unwrap().to_bytes();
    (status, String::from_utf8_lossy(&bytes).into_owned())
}

async fn reviews(router: &axum::Router) -> (u64, bool) {
    let (_, body) = call(
        router,
        "GET",
        "/environment",
        "application/json",
        String::new(),
    )
    .await;
    let v: serde_json::Value = serde_json::from_str(&body).unwrap();
    (
        v["reviews"].as_u64().unwrap(),
        v["phase"] == "stable" && v["review_pending"] == false,
    )
}

/// The number of change sets recorded (an in-memory read: polling it does not load the store).
async fn change_sets(router: &axum::Router) -> usize {
    let (_, body) = call(
        router,
        "GET",
        "/changesets",
        "application/json",
        String::new(),
    )
    .await;
    serde_json::from_str::<serde_json::Value>(&body)
        .unwrap()
        .as_array()
        .unwrap()
        .len()
}

async fn settle(router: &axum::Router, at_least: u64) {
    loop {
        let (n, idle) = reviews(router).await;
        if n >= at_least && idle {
            return;
        }
        tokio::task::yield_now().await;
    }
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok();
    let runs = if quick { 5 } else { 51 };
    let dir = tempfile::tempdir().unwrap();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async move {
        let kb = KnowledgeBase::open(dir.path().join("store")).unwrap();
        let state = AppState::new(
            kb,
            ServerConfig {
                lifecycle: dyknow_lifecycle::Settings {
                    time_unit: Duration::from_secs(3600),
                    ..dyknow_lifecycle::Settings::default()
                },
                ..ServerConfig::default()
            },
        )
        .unwrap();
        state.start_life_cycle();
        let router = app(state);
        let spec = |f: &str| {
            std::fs::read_to_string(format!("{}/../specs/turtle/{f}", env!("CARGO_MANIFEST_DIR"))).unwrap()
        };
        call(&router, "POST", "/targets", "text/turtle", spec("ch6-target.ttl")).await;
        call(&router, "POST", "/transformations", "text/turtle", spec("ch6-piff.ttl")).await;
        settle(&router, 2).await;
        let mut times = Vec::new();
        for _ in 0..runs {
            let (_, cus) = call(&router, "GET", "/cus", "application/json", String::new()).await;
            let cus: serde_json::Value = serde_json::from_str(&cus).unwrap();
            let segmenter = cus
                .as_array()
                .unwrap()
                .iter()
                .find(|c| c["transformation"] == "segmenter(piff)")
                .expect("a segmenter")["name"]
                .as_str()
                .unwrap()
                .to_owned();
            let before = change_sets(&router).await;
            let body = serde_json::json!({"kind": "cu-crashed", "cu": segmenter}).to_string();
            let start = Instant::now();
            let (status, _) = call(&router, "POST", "/perturbations", "application/json", body).await;
            assert_eq!(status, 202);
            while change_sets(&router).await == before {
                tokio::task::yield_now().await;
            }
            times.push(start.elapsed());
        }
        times.sort();
        let (_, sets) = call(&router, "GET", "/changesets", "application/json", String::new()).await;
        let sets: serde_json::Value = serde_json::from_str(&sets).unwrap();
        let last = sets.as_array().unwrap().last().unwrap();
        assert_eq!(last["cost"]["total"], 71.0);
        println!("# Reconfiguration over HTTP (in-process router, on-disk store)\n");
        println!("| case | runs | median | p90 |");
        println!("| --- | --- | --- | --- |");
        println!(
            "| Chapter 6 segmenter crash: POST /perturbations until the repair is written | {runs} | {:.3} ms | {:.3} ms |",
            times[runs / 2].as_secs_f64() * 1e3,
            times[runs * 9 / 10].as_secs_f64() * 1e3
        );
    });
}
