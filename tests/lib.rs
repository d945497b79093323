#![expect(
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]
//! Helpers shared by DyKnow's end-to-end tests: an in-process service driven without a socket.

use axum::Router;
use axum::body::Body;
use axum::http::{Request, StatusCode};
use dyknow_server::{AppState, ServerConfig, app};
use dyknow_store::KnowledgeBase;
use http_body_util::BodyExt;
use tower::ServiceExt;

/// The example specs of `specs/turtle/` and the endpoint each is posted to.
pub const EXAMPLE_SPECS: [(&str, &str); 9] = [
    ("listing-5.3-undistort.ttl", "/transformations"),
    ("listing-5.4-target.ttl", "/targets"),
    ("example-12-similarity.ttl", "/ontology"),
    ("example-12.ttl", "/transformations"),
    ("example-12-targets.ttl", "/targets"),
    ("ch6-target.ttl", "/targets"),
    ("ch6-piff.ttl", "/transformations"),
    ("ch6-puff.ttl", "/transformations"),
    ("ch6-ceiling.ttl", "/transformations"),
];

/// The directory of the example specs.
pub fn specs_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/turtle")
}

/// A service over a fresh in-memory knowledge base.
pub fn service() -> Router {
    app(AppState::new(
        KnowledgeBase::in_memory().expect("in-memory store"),
        ServerConfig::default(),
    )
    .expect("state"))
}

/// Sends one request; returns status, content type and body.
pub async fn send(
    router: &Router,
    method: &str,
    uri: &str,
    content_type: Option<&str>,
    accept: Option<&str>,
    body: Vec<u8>,
) -> (StatusCode, String, Vec<u8>) {
    let mut request = Request::builder().method(method).uri(uri);
    if let Some(ct) = content_type {
        request = request.header("content-type", ct);
    }
    if let Some(a) = accept {
        request = request.header("accept", a);
    }
    let response = router
        .clone()
        .oneshot(request.body(Body::from(body)).expect("request"))
        .await
        .expect("infallible");
    let status = response.status();
    let ct = response
        .headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_owned();
    let bytes = response
        .into_body()
        .collect()
        .await
        .expect("body")
        .to_bytes()
        .to_vec();
    (status, ct, bytes)
}

/// Posts every example spec to its endpoint and asserts each is accepted.
pub async fn load_examples(router: &Router) {
    for (file, endpoint) in EXAMPLE_SPECS {
        let body = std::fs::read(specs_dir().join(file)).expect("example spec");
        let (status, _, answer) =
            send(router, "POST", endpoint, Some("text/turtle"), None, body).await;
        assert_eq!(
            status,
            StatusCode::CREATED,
            "{file} → {endpoint}: {}",
            String::from_utf8_lossy(&answer)
        );
    }
}
