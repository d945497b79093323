//! The one harness of DyKnow's HTTP tests: an in-process service (`dyknow_server::app` over an
//! in-memory knowledge base) driven without a socket, answers read whole, the contract's error
//! shape checked, and the example specs of `specs/turtle/`.

#![allow(
    missing_docs,
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a test harness: a failed set-up is a failed test"
)]

use std::time::Duration;

use axum::Router;
use axum::body::{Body, Bytes};
use axum::http::{HeaderMap, Method, Request, StatusCode, header};
use dyknow_server::{AppState, ServerConfig, app};
use dyknow_store::KnowledgeBase;
pub use dyknow_store::oxigraph;
use http_body_util::BodyExt;
use serde_json::Value;
use tower::{Service, ServiceExt};

/// The example specs of `specs/turtle/` and the endpoint each is posted to.
/// `example-12-builtin.ttl` comes before `example-12.ttl`, which replaces its five
/// transformations (same labels), so the examples load into the model-level Example 12.
pub const EXAMPLE_SPECS: [(&str, &str); 15] = [
    ("listing-5.3-undistort.ttl", "/transformations"),
    ("listing-5.4-target.ttl", "/targets"),
    ("example-12-similarity.ttl", "/ontology"),
    ("example-12-builtin.ttl", "/transformations"),
    ("example-12.ttl", "/transformations"),
    ("example-12-targets.ttl", "/targets"),
    ("ch6-target.ttl", "/targets"),
    // The live variants first: the model-level specs (same labels) replace them.
    ("ch6-live-piff.ttl", "/transformations"),
    ("ch6-live-puff.ttl", "/transformations"),
    ("ch6-live-ceiling.ttl", "/transformations"),
    ("ch6-piff.ttl", "/transformations"),
    ("ch6-puff.ttl", "/transformations"),
    ("ch6-ceiling.ttl", "/transformations"),
    ("live-pipeline.ttl", "/transformations"),
    ("live-target.ttl", "/targets"),
];

/// The directory of the example specs.
pub fn specs_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../specs/turtle")
}

/// The text of the example spec `file` of `specs/turtle/`.
pub fn spec(file: &str) -> String {
    std::fs::read_to_string(specs_dir().join(file))
        .unwrap_or_else(|e| panic!("example spec {file}: {e}"))
}

/// Listing 5.3 (one transformation, `Undistort(cam1)`).
pub const UNDISTORT: &str = include_str!("../specs/turtle/listing-5.3-undistort.ttl");
/// Listing 5.4 (one target, `undistortSub`).
pub const UNDISTORT_TARGET: &str = include_str!("../specs/turtle/listing-5.4-target.ttl");
/// Example 12: five transformations `tid1`..`tid5`.
pub const EX12: &str = include_str!("../specs/turtle/example-12.ttl");
/// Example 12: two targets `qid1`, `qid2`.
pub const EX12_TARGETS: &str = include_str!("../specs/turtle/example-12-targets.ttl");
/// Example 12: the similarity extension.
pub const EX12_SIMILARITY: &str = include_str!("../specs/turtle/example-12-similarity.ttl");
/// Ch. 6: Piff's seven transformations.
pub const PIFF: &str = include_str!("../specs/turtle/ch6-piff.ttl");

pub const TURTLE: &str = "text/turtle";
pub const NTRIPLES: &str = "application/n-triples";
pub const JSONLD: &str = "application/ld+json";

/// The prefixes spec snippets in the tests use.
pub const PREFIXES: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
@prefix dkros:  <http://www.dyknow.eu/ontology/dyknow-ros#> .\n\
@prefix rdfs:   <http://www.w3.org/2000/01/rdf-schema#> .\n";

/// An answer, fully read.
#[derive(Debug)]
pub struct Answer {
    pub status: StatusCode,
    pub headers: HeaderMap,
    pub body: Bytes,
}

impl Answer {
    /// Reads a response whole.
    async fn read(response: axum::response::Response) -> Self {
        let (parts, body) = response.into_parts();
        let body = body
            .collect()
            .await
            .expect("the body can be read")
            .to_bytes();
        Self {
            status: parts.status,
            headers: parts.headers,
            body,
        }
    }
}

impl Answer {
    pub fn text(&self) -> String {
        String::from_utf8(self.body.to_vec()).expect("the body is UTF-8")
    }

    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| {
            panic!(
                "the body is not JSON ({e}): {}",
                String::from_utf8_lossy(&self.body)
            )
        })
    }

    pub fn header(&self, name: impl header::AsHeaderName) -> Option<&str> {
        self.headers.get(name).and_then(|v| v.to_str().ok())
    }

    /// The media type without parameters.
    pub fn media_type(&self) -> String {
        self.header(header::CONTENT_TYPE)
            .unwrap_or("")
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase()
    }

    /// Asserts the status, with the body in the message.
    pub fn expect(&self, status: u16) -> &Self {
        assert_eq!(
            self.status.as_u16(),
            status,
            "unexpected status; body: {}",
            String::from_utf8_lossy(&self.body)
        );
        self
    }

    /// Asserts the contract's error shape: the status, `application/json`,
    /// `{"error": "<non-empty>", "details": [...]}`. Returns the details.
    pub fn expect_error(&self, status: u16) -> Vec<Value> {
        self.expect(status);
        assert_eq!(
            self.media_type(),
            "application/json",
            "error answers are JSON: {self:?}"
        );
        let body = self.json();
        let object = body.as_object().expect("an error body is an object");
        let error = object
            .get("error")
            .and_then(Value::as_str)
            .unwrap_or_else(|| panic!("no \"error\" string: {body}"));
        assert!(!error.trim().is_empty(), "empty error message: {body}");
        object
            .get("details")
            .and_then(Value::as_array)
            .unwrap_or_else(|| panic!("no \"details\" array: {body}"))
            .clone()
    }
}

/// A running app over one state; every call goes to the same knowledge base.
#[derive(Clone)]
pub struct Api {
    pub router: Router,
}

impl Default for Api {
    fn default() -> Self {
        Self::new()
    }
}

impl Api {
    pub fn new() -> Self {
        Self::with_config(ServerConfig::default())
    }

    pub fn with_config(config: ServerConfig) -> Self {
        let kb = KnowledgeBase::in_memory().expect("in-memory knowledge base");
        Self {
            router: app(AppState::new(kb, config).expect("state")),
        }
    }

    /// An app whose configuration life-cycle runs (reviews after perturbations); needs a Tokio
    /// runtime.
    pub fn with_life_cycle(config: ServerConfig) -> Self {
        let kb = KnowledgeBase::in_memory().expect("in-memory knowledge base");
        let state = AppState::new(kb, config).expect("state");
        state.start_life_cycle();
        Self { router: app(state) }
    }

    pub fn with_token(token: &str) -> Self {
        Self::with_config(ServerConfig {
            token: Some(token.to_owned()),
            ..ServerConfig::default()
        })
    }

    pub fn with_query_timeout(timeout: Duration) -> Self {
        Self::with_config(ServerConfig {
            query_timeout: timeout,
            ..ServerConfig::default()
        })
    }

    pub fn with_max_body(bytes: usize) -> Self {
        Self::with_config(ServerConfig {
            max_body_bytes: bytes,
            ..ServerConfig::default()
        })
    }

    /// Sends one request to the shared state (`ready().call()` on a clone of the router).
    pub async fn send(&self, request: Request<Body>) -> Answer {
        let mut router = self.router.clone();
        let response = ServiceExt::<Request<Body>>::ready(&mut router)
            .await
            .expect("the router is always ready")
            .call(request)
            .await
            .expect("the router is infallible");
        Answer::read(response).await
    }

    /// Sends one request with `oneshot` on a clone of the router.
    pub async fn oneshot(&self, request: Request<Body>) -> Answer {
        let response = self
            .router
            .clone()
            .oneshot(request)
            .await
            .expect("the router is infallible");
        Answer::read(response).await
    }

    pub async fn get(&self, uri: &str) -> Answer {
        self.send(request(Method::GET, uri, &[], Body::empty()))
            .await
    }

    pub async fn get_accept(&self, uri: &str, accept: &str) -> Answer {
        self.send(request(
            Method::GET,
            uri,
            &[(header::ACCEPT.as_str(), accept)],
            Body::empty(),
        ))
        .await
    }

    pub async fn post(&self, uri: &str, content_type: &str, body: impl Into<Body>) -> Answer {
        self.send(request(
            Method::POST,
            uri,
            &[(header::CONTENT_TYPE.as_str(), content_type)],
            body.into(),
        ))
        .await
    }

    pub async fn post_turtle(&self, uri: &str, body: impl Into<Body>) -> Answer {
        self.post(uri, TURTLE, body).await
    }

    pub async fn delete(&self, uri: &str) -> Answer {
        self.send(request(Method::DELETE, uri, &[], Body::empty()))
            .await
    }

    /// The whole model as N-Triples (sorted by the server, so comparable).
    pub async fn snapshot(&self) -> String {
        let answer = self.get("/model?format=ntriples&inferred=true").await;
        answer.expect(200);
        answer.text()
    }

    /// The server still answers.
    pub async fn assert_healthy(&self) {
        let answer = self.get("/health").await;
        answer.expect(200);
        assert_eq!(answer.json(), serde_json::json!({"status": "ok"}));
    }

    /// Posts every example spec to its endpoint and asserts each is accepted.
    pub async fn load_examples(&self) {
        for (file, endpoint) in EXAMPLE_SPECS {
            self.post_turtle(endpoint, spec(file)).await.expect(201);
        }
    }

    /// The labels of `GET {path}` (a JSON list of specs).
    pub async fn labels(&self, path: &str) -> Vec<String> {
        let answer = self.get(path).await;
        answer.expect(200);
        answer
            .json()
            .as_array()
            .expect("a JSON list")
            .iter()
            .map(|s| s["label"].as_str().expect("a label").to_owned())
            .collect()
    }
}

/// A request with headers.
pub fn request(method: Method, uri: &str, headers: &[(&str, &str)], body: Body) -> Request<Body> {
    let mut builder = Request::builder().method(method).uri(uri);
    for (name, value) in headers {
        builder = builder.header(*name, *value);
    }
    builder.body(body).expect("a valid request")
}

/// Percent-encodes a query-string value (RFC 3986 unreserved characters kept).
pub fn encode(value: &str) -> String {
    let mut out = String::new();
    for b in value.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Parses an RDF document with Oxigraph; panics with the document on a syntax error.
pub fn parse_rdf(body: &[u8], format: oxigraph::io::RdfFormat) -> Vec<oxigraph::model::Quad> {
    oxigraph::io::RdfParser::from_format(format)
        .for_slice(body)
        .collect::<Result<Vec<_>, _>>()
        .unwrap_or_else(|e| panic!("not valid {format}: {e}\n{}", String::from_utf8_lossy(body)))
}

/// Whether some parsed triple has `rdfs:label` `label`.
pub fn has_label(quads: &[oxigraph::model::Quad], label: &str) -> bool {
    quads.iter().any(|q| {
        q.predicate.as_str() == "http://www.w3.org/2000/01/rdf-schema#label"
            && matches!(&q.object, oxigraph::model::Term::Literal(l) if l.value() == label)
    })
}

/// A minimal valid transformation spec (a source with one out port).
pub fn source_spec(label: &str) -> String {
    format!(
        "{PREFIXES}[] a dyknow:Transformation ; rdfs:label \"{label}\" ;\n\
         dyknow:hasOutPort [ a dyknow:OutPort ; dyknow:hasName \"out\" ;\n\
           dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"T({label})\" ] ] .\n"
    )
}
