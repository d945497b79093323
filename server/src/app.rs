//! The router: `app(state)` joins the route modules and the middleware.

use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::{Body, BodyDataStream, Bytes, HttpBody, to_bytes};
use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::http::{HeaderMap, Method, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use dyknow_lifecycle::{Executor, Fleet, LifecycleError, Manager, ModelOnly, Settings};
use dyknow_store::KnowledgeBase;

use crate::error::ApiError;
use crate::groups::{GroupError, GroupStore, Groups, Plane};
use crate::metrics::Metrics;
use crate::routes;

/// Settings of a running service.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    /// The bearer token mutating requests must carry, if any.
    pub token: Option<String>,
    /// The largest accepted request body, in bytes.
    pub max_body_bytes: usize,
    /// How long a SPARQL query may run.
    pub query_timeout: Duration,
    /// How much memory a SPARQL query may hold, in bytes (`None`: no limit). Counted by
    /// `dyknow_meter::Counting`, which the program must install as its global allocator (the
    /// `dyknow` binary does); without it the limit is never reached.
    pub query_memory: Option<usize>,
    /// How many requests do work on the store at once; more wait their turn, in order (0: no
    /// limit). See [`in_turn`].
    pub store_concurrency: usize,
    /// The configuration life-cycle's settings: the horizon H, the time unit, how long a
    /// review's search may run.
    pub lifecycle: Settings,
}

/// The default of `--query-memory`, in MiB: far above what a query of the configuration holds
/// (a CONSTRUCT of every triple of 10,000 specs: a 48 MB answer, 230 MB at its peak), far below
/// the machine (a store turn per query, `--store-concurrency` of them at once).
pub const DEFAULT_QUERY_MEMORY_MIB: usize = 1024;

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            token: None,
            max_body_bytes: 16 * 1024 * 1024,
            query_timeout: Duration::from_secs(30),
            query_memory: Some(DEFAULT_QUERY_MEMORY_MIB << 20),
            store_concurrency: default_store_concurrency(),
            lifecycle: Settings::default(),
        }
    }
}

/// A write probe of `GET /health`: when, and the storage error it met, if any.
pub(crate) type WriteProbe = (std::time::Instant, Option<String>);

/// Shared state of the handlers: cheap to clone.
#[derive(Clone)]
pub struct AppState {
    /// The knowledge base.
    pub kb: Arc<KnowledgeBase>,
    /// Settings.
    pub config: Arc<ServerConfig>,
    /// Request metrics.
    pub metrics: Arc<Metrics>,
    /// The configuration life-cycle (reviews, Spawn, Destroy, change sets, estimators).
    pub lifecycle: Arc<Manager>,
    /// The executors on Zenoh, unless the service runs in model-only mode.
    pub fleet: Option<Arc<Fleet>>,
    /// The formula groups.
    pub groups: Arc<Groups>,
    /// The turns of [`in_turn`] (`store_concurrency` permits).
    turns: Arc<tokio::sync::Semaphore>,
    /// Cancels SPARQL queries at `query_timeout`.
    pub(crate) watchdog: Arc<crate::watchdog::Watchdog>,
    /// The last write probe of `GET /health`.
    pub(crate) write_probe: Arc<std::sync::Mutex<Option<WriteProbe>>>,
}

impl AppState {
    /// State over a knowledge base with the given settings (reading the recorded change sets
    /// and learned estimates), applying change sets to the model only. The life-cycle loop
    /// starts with [`AppState::start_life_cycle`].
    pub fn new(kb: KnowledgeBase, config: ServerConfig) -> Result<Self, LifecycleError> {
        Self::with_executor(kb, config, Arc::new(ModelOnly))
    }

    /// [`AppState::new`] with change sets applied by `executor`.
    pub fn with_executor(
        kb: KnowledgeBase,
        config: ServerConfig,
        executor: Arc<dyn Executor>,
    ) -> Result<Self, LifecycleError> {
        if config.query_memory.is_some() && !dyknow_meter::installed() {
            tracing::warn!(
                "SPARQL queries are not bounded in memory: install dyknow_meter::Counting as \
                 the global allocator to count what they hold"
            );
        }
        let kb = Arc::new(kb);
        let lifecycle = Arc::new(Manager::new(kb.clone(), executor, config.lifecycle)?);
        let groups = Groups::empty(kb.clone(), lifecycle.clone());
        let permits = match config.store_concurrency {
            0 => tokio::sync::Semaphore::MAX_PERMITS,
            n => n.min(tokio::sync::Semaphore::MAX_PERMITS),
        };
        Ok(Self {
            turns: Arc::new(tokio::sync::Semaphore::new(permits)),
            watchdog: Arc::default(),
            write_probe: Arc::default(),
            groups,
            kb,
            config: Arc::new(config),
            metrics: Arc::new(Metrics::default()),
            lifecycle,
            fleet: None,
        })
    }

    /// [`AppState::new`] with change sets applied by the executors of `fleet`.
    pub fn with_fleet(
        kb: KnowledgeBase,
        config: ServerConfig,
        fleet: Arc<Fleet>,
    ) -> Result<Self, LifecycleError> {
        let mut state = Self::with_executor(kb, config, fleet.clone())?;
        state.fleet = Some(fleet);
        Ok(state)
    }

    /// Replaces the groups with those of `store` (loaded, replayed, running ones resumed),
    /// reading from and publishing to `plane`.
    pub fn with_groups(
        mut self,
        plane: Option<Plane>,
        store: Option<GroupStore>,
    ) -> Result<Self, GroupError> {
        self.groups = Groups::new(self.kb.clone(), self.lifecycle.clone(), plane, store)?;
        Ok(self)
    }

    /// Spawns the life-cycle loop on the current Tokio runtime.
    pub fn start_life_cycle(&self) {
        tokio::spawn(self.lifecycle.clone().run());
    }
}

/// Runs blocking knowledge-base work without stalling the async runtime.
///
/// On a multi-threaded runtime (the service's) the work runs on the request's own thread,
/// which hands its other tasks to another thread first ([`tokio::task::block_in_place`]): no
/// hop to the blocking pool and back on the request's path (measured: ~30 µs of a 0.23 ms
/// SPARQL lookup; `docs/benchmarks.md`, "Per-request cost"). On a current-thread runtime
/// (where that is not possible) it goes to the blocking pool.
pub(crate) async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
) -> Result<T, ApiError> {
    if multi_threaded() {
        tokio::task::block_in_place(f)
    } else {
        tokio::task::spawn_blocking(f)
            .await
            .map_err(ApiError::internal)?
    }
}

/// [`blocking`] in turn: at most `--store-concurrency` requests do work on the store at once,
/// the others wait, first come first served, without holding a thread.
///
/// Why: every request at work holds a thread, and on a small machine with tens of runnable
/// threads every thread waits its turn of the scheduler: the cheapest answers
/// (`GET /health`, `GET /cus`) and the life-cycle's reviews too, which then starve. Under the
/// load bench's 64 clients on 2 cores, 4 turns took `GET /health`'s p99 from 56 to 9 ms
/// (`docs/benchmarks.md`, "Work in turn"). What takes no turn: reads that answer from memory
/// (`GET /health`, `GET /changesets`, `GET /cus` when nothing was written since its snapshot);
/// `GET /cus`'s own refresh of the snapshot (one reader at a time, the others get the last
/// snapshot at once); calls that ask executors (`GET /cus/{name}`, `GET /cus?statistics=true`);
/// and the life-cycle's calls (Spawn, Destroy, a CU's configuration, perturbations, observed
/// costs), which wait for the configuration lock that a review holds through its search and
/// its application by the executors, and must not keep the turns from everything else
/// meanwhile. Reviews themselves run on the life-cycle's own threads.
pub(crate) async fn in_turn<T: Send + 'static>(
    state: &AppState,
    f: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
) -> Result<T, ApiError> {
    let _turn = state.turns.acquire().await.map_err(ApiError::internal)?;
    blocking(f).await
}

/// Twice the cores: as many requests as cores at work while as many again finish theirs.
pub fn default_store_concurrency() -> usize {
    2 * std::thread::available_parallelism().map_or(1, usize::from)
}

/// Whether the current runtime can run blocking work in place.
pub(crate) fn multi_threaded() -> bool {
    tokio::runtime::Handle::try_current()
        .is_ok_and(|h| h.runtime_flavor() == tokio::runtime::RuntimeFlavor::MultiThread)
}

/// The HTTP API of `dyknow serve` (contract `http-api.md`).
pub fn app(state: AppState) -> Router {
    let max_body = state.config.max_body_bytes;
    Router::new()
        .merge(routes::specs::router())
        .merge(routes::ontology::router())
        .merge(routes::sparql::router())
        .merge(routes::model::router())
        .merge(routes::ops::router())
        .merge(routes::reconfig::router())
        .merge(routes::executors::router())
        .merge(routes::groups::router())
        .merge(routes::ui::router())
        .route_layer(middleware::from_fn_with_state(state.clone(), authorize))
        .route_layer(middleware::from_fn(acceptable))
        .route_layer(middleware::from_fn(known_parameters))
        .fallback(not_found)
        .layer(DefaultBodyLimit::max(max_body))
        .layer(middleware::from_fn_with_state(state.clone(), linger))
        .layer(middleware::from_fn(json_errors))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            record_metrics,
        ))
        .with_state(state)
}

async fn not_found(method: Method, uri: axum::http::Uri) -> ApiError {
    ApiError::not_found(format!("no resource at {method} {}", uri.path()))
}

/// The query parameters a route takes, by method (`None`: not checked here). The SPARQL
/// endpoint's belong to the SPARQL protocol, and the web view's files take none that matter.
fn parameters(method: &Method, route: &str) -> Option<&'static [&'static str]> {
    if !matches!(*method, Method::GET | Method::HEAD | Method::DELETE) {
        return None;
    }
    Some(match route {
        "/sparql" | "/" | "/ui" | "/ui/" | "/ui/{*file}" => return None,
        "/changesets" | "/groups/{label}/verdicts" => &["since"],
        "/model" => &["format", "inferred"],
        "/cus" => &["statistics"],
        "/ontology" if method == Method::DELETE => &["graph"],
        _ => &[],
    })
}

/// A query parameter a read (or a DELETE) does not take is 400, naming it and those it takes:
/// a misspelt one was ignored, and the answer was not what was asked (`/changesets?sinc=cs-12`
/// gave the whole history, `/model?fromat=nt` Turtle).
async fn known_parameters(request: Request, next: Next) -> Response {
    let route = request.extensions().get::<MatchedPath>().cloned();
    let (Some(route), Some(query)) = (route, request.uri().query()) else {
        return next.run(request).await;
    };
    let Some(known) = parameters(request.method(), route.as_str()) else {
        return next.run(request).await;
    };
    let unknown = query
        .split('&')
        .filter(|p| !p.is_empty())
        .map(|p| p.split('=').next().unwrap_or(p))
        .find(|name| !known.contains(name));
    match unknown {
        Some(name) => {
            let takes = if known.is_empty() {
                "takes no query parameter".to_owned()
            } else {
                format!("takes {}", known.join(", "))
            };
            ApiError::bad_request(format!(
                "unknown query parameter {name:?}: {} {} {takes}",
                request.method(),
                route.as_str()
            ))
            .into_response()
        }
        None => next.run(request).await,
    }
}

/// A read whose answer the client's `Accept` excludes is 406 (`http-api.md`), also where the
/// endpoint has one representation (JSON, an event stream, a trace) and so does not
/// negotiate: its answer's type is checked here. Reads only: a write is done before its
/// answer's type is known, and a refused request must change nothing. A `?format=` the client
/// names (`GET /model`) overrides its `Accept`.
async fn acceptable(request: Request, next: Next) -> Response {
    if !matches!(*request.method(), Method::GET | Method::HEAD) {
        return next.run(request).await;
    }
    let named = request
        .uri()
        .query()
        .is_some_and(|q| q.split('&').any(|p| p.split('=').next() == Some("format")));
    let accept = (!named)
        .then(|| request.headers().get(header::ACCEPT).cloned())
        .flatten();
    let response = next.run(request).await;
    let Some(accept) = accept else {
        return response;
    };
    if !response.status().is_success() {
        return response;
    }
    let Some(media) = crate::negotiate::content_type(response.headers()) else {
        return response;
    };
    let mut asked = HeaderMap::new();
    asked.insert(header::ACCEPT, accept);
    match crate::negotiate::negotiate(&asked, &[media.as_str()]) {
        Ok(_) => response,
        Err(refused) => refused.into_response(),
    }
}

/// Mutating requests need the bearer token when one is configured; reads (including SPARQL
/// queries sent with POST) never do.
async fn authorize(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let mutating = matches!(
        *request.method(),
        Method::POST | Method::PUT | Method::DELETE | Method::PATCH
    ) && request.uri().path() != "/sparql";
    if let (true, Some(token)) = (mutating, &state.config.token) {
        let given = request
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(bearer_credentials);
        if !given.is_some_and(|g| constant_time_eq(g.as_bytes(), token.as_bytes())) {
            return ApiError::new(
                StatusCode::UNAUTHORIZED,
                "this request changes the model and needs 'Authorization: Bearer <token>'",
            )
            .into_response();
        }
    }
    next.run(request).await
}

/// The credentials of an `Authorization: Bearer <token>` value. The scheme's name is
/// case-insensitive (RFC 9110, 11.1), so `bearer` and `BEARER` are the same scheme.
fn bearer_credentials(value: &str) -> Option<&str> {
    let (scheme, credentials) = value.trim_start().split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then(|| credentials.trim())
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// At most this much of a request body the handler left unread is read and discarded before
/// the answer goes out (a "lingering close"), so that a client that writes its whole body
/// before reading (Python's `urllib`, most blocking clients) reads the answer instead of a
/// connection reset.
pub const LINGER_BYTES: u64 = 64 * 1024 * 1024;
/// And for at most this long.
pub const LINGER_TIME: Duration = Duration::from_secs(5);

/// The body limit and the lingering close. A body whose `Content-Length` exceeds
/// `--max-body` is answered 413 at once, without calling the handler; a body the handler
/// left unread (a 413 of a streamed body over the limit, a 401, any early error) is drained
/// after it answered. Both drain at most [`LINGER_BYTES`] within [`LINGER_TIME`]: a body
/// drained to its end leaves the connection open, one that is not closes it
/// (`Connection: close`). A client waiting for `100 Continue` is answered without draining:
/// it sends no body unless asked.
async fn linger(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let (parts, body) = request.into_parts();
    if body.is_end_stream() {
        return next.run(Request::from_parts(parts, body)).await;
    }
    let expects_continue = parts
        .headers
        .get(header::EXPECT)
        .is_some_and(|v| v.as_bytes().eq_ignore_ascii_case(b"100-continue"));
    let declared = body.size_hint().exact();
    let max = state.config.max_body_bytes as u64;
    if let Some(declared) = declared.filter(|&n| n > max) {
        let drained =
            !expects_continue && declared <= LINGER_BYTES && drain(body.into_data_stream()).await;
        let mut response = ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!(
                "the request body ({declared} bytes) is larger than the server accepts \
                 ({max} bytes, --max-body)"
            ),
        )
        .into_response();
        if !drained {
            close(&mut response);
        }
        return response;
    }
    if expects_continue {
        // Draining would ask for the body the client held back: hyper closes instead.
        return next.run(Request::from_parts(parts, body)).await;
    }
    let shared = SharedBody(Arc::new(Mutex::new(body.into_data_stream())));
    let mut response = next
        .run(Request::from_parts(
            parts,
            Body::from_stream(shared.clone()),
        ))
        .await;
    if !drain(shared).await {
        close(&mut response);
    }
    response
}

/// Marks the connection to be closed after `response`.
fn close(response: &mut Response) {
    response.headers_mut().insert(
        header::CONNECTION,
        axum::http::HeaderValue::from_static("close"),
    );
}

/// Reads and discards the rest of a body, up to [`LINGER_BYTES`] and [`LINGER_TIME`]; whether
/// it reached the end.
async fn drain(
    mut body: impl futures_core::Stream<Item = Result<Bytes, axum::Error>> + Unpin,
) -> bool {
    let read_all = async {
        let mut read = 0u64;
        while let Some(chunk) = std::future::poll_fn(|cx| Pin::new(&mut body).poll_next(cx)).await {
            let Ok(chunk) = chunk else {
                return false;
            };
            read += chunk.len() as u64;
            if read > LINGER_BYTES {
                return false;
            }
        }
        true
    };
    tokio::time::timeout(LINGER_TIME, read_all)
        .await
        .unwrap_or(false)
}

/// A request body shared by the handler and [`linger`], which drains what the handler left.
#[derive(Clone)]
struct SharedBody(Arc<Mutex<BodyDataStream>>);

impl futures_core::Stream for SharedBody {
    type Item = Result<Bytes, axum::Error>;

    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        match self.0.lock() {
            Ok(mut body) => Pin::new(&mut *body).poll_next(cx),
            // A handler panicked while reading: nothing more is read.
            Err(_) => Poll::Ready(None),
        }
    }
}

/// Every error answer is the contract's JSON, including those axum produces itself (405 from
/// the method router, 413 from the body limit, 400 from extractors).
async fn json_errors(request: Request, next: Next) -> Response {
    let response = next.run(request).await;
    let status = response.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return response;
    }
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if is_json {
        return response;
    }
    let (parts, body) = response.into_parts();
    let text = to_bytes(body, 64 * 1024)
        .await
        .map(|b| String::from_utf8_lossy(&b).trim().to_owned())
        .unwrap_or_default();
    let message = match status {
        StatusCode::METHOD_NOT_ALLOWED => {
            "this method is not allowed on this resource (see the Allow header)".to_owned()
        }
        StatusCode::PAYLOAD_TOO_LARGE => {
            "the request body is larger than the server accepts".to_owned()
        }
        _ if !text.is_empty() => text,
        _ => status
            .canonical_reason()
            .unwrap_or("request failed")
            .to_owned(),
    };
    let mut rebuilt = ApiError::new(status, message).into_response();
    for (name, value) in &parts.headers {
        if name != header::CONTENT_TYPE && name != header::CONTENT_LENGTH {
            rebuilt.headers_mut().insert(name, value.clone());
        }
    }
    rebuilt
}

async fn record_metrics(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let start = Instant::now();
    let method = request.method().clone();
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_owned(), |p| p.as_str().to_owned());
    let response = next.run(request).await;
    // A client may send any token as a method: the label takes the standard ones and
    // "other", so random methods cannot grow `/metrics` without bound (2,000 of them made it
    // 38 KB → 3 MB).
    let method = match method {
        Method::GET
        | Method::HEAD
        | Method::POST
        | Method::PUT
        | Method::DELETE
        | Method::PATCH
        | Method::OPTIONS
        | Method::CONNECT
        | Method::TRACE => method.as_str(),
        _ => "other",
    };
    state
        .metrics
        .record(method, &route, response.status().as_u16(), start.elapsed());
    response
}

/// A response with a body and a content type.
pub(crate) fn typed(status: StatusCode, media_type: &str, body: impl Into<Body>) -> Response {
    (
        status,
        [(header::CONTENT_TYPE, media_type.to_owned())],
        body.into(),
    )
        .into_response()
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::mpsc;

    use axum::body::Body;
    use axum::http::Request;
    use tower::ServiceExt;

    use super::*;

    #[test]
    fn the_bearer_scheme_is_case_insensitive_and_the_token_is_not() {
        for value in ["Bearer t0k", "bearer t0k", "BEARER  t0k ", " Bearer t0k"] {
            assert_eq!(bearer_credentials(value), Some("t0k"), "{value:?}");
        }
        for value in ["Basic dDBr", "Bearert0k", "Bearer", "t0k", ""] {
            assert_eq!(bearer_credentials(value), None, "{value:?}");
        }
        assert_eq!(bearer_credentials("Bearer T0K"), Some("T0K"));
    }

    fn state(store_concurrency: usize) -> AppState {
        let kb = KnowledgeBase::in_memory().expect("in-memory knowledge base");
        AppState::new(
            kb,
            ServerConfig {
                store_concurrency,
                ..ServerConfig::default()
            },
        )
        .expect("state")
    }

    async fn status(state: &AppState, uri: &str) -> StatusCode {
        app(state.clone())
            .oneshot(Request::get(uri).body(Body::empty()).unwrap())
            .await
            .unwrap()
            .status()
    }

    /// Holds the state's turns until the returned sender is dropped or sent to.
    async fn hold_turns(
        state: &AppState,
        n: usize,
    ) -> Vec<(mpsc::Sender<()>, tokio::task::JoinHandle<()>)> {
        let mut held = Vec::new();
        for _ in 0..n {
            let (release, wait) = mpsc::channel::<()>();
            let (started, running) = tokio::sync::oneshot::channel();
            let s = state.clone();
            let task = tokio::spawn(async move {
                in_turn(&s, move || {
                    started.send(()).unwrap();
                    let _ = wait.recv();
                    Ok(())
                })
                .await
                .unwrap();
            });
            running.await.unwrap();
            held.push((release, task));
        }
        held
    }

    /// Queues `in_turn` work `i` (polled once, so it is in the queue before the next one),
    /// recording when it runs and how many ran at once.
    async fn queue(
        state: &AppState,
        i: usize,
        order: &Arc<Mutex<Vec<usize>>>,
        running: &Arc<AtomicUsize>,
    ) -> tokio::task::JoinHandle<usize> {
        let (s, order, running) = (state.clone(), order.clone(), running.clone());
        let mut work = Box::pin(async move {
            in_turn(&s, move || {
                order.lock().unwrap().push(i);
                let now = running.fetch_add(1, Ordering::SeqCst) + 1;
                std::thread::sleep(Duration::from_millis(5));
                running.fetch_sub(1, Ordering::SeqCst);
                Ok(now)
            })
            .await
            .unwrap()
        });
        std::future::poll_fn(|cx| {
            assert!(work.as_mut().poll(cx).is_pending(), "ran without a turn");
            Poll::Ready(())
        })
        .await;
        tokio::spawn(work)
    }

    /// With `turns` turns held, queues `n` pieces of work in order, then releases the turns:
    /// the order they ran in and the most at work at once.
    async fn queued(turns: usize, n: usize) -> (Vec<usize>, usize) {
        let state = state(turns);
        let held = hold_turns(&state, turns).await;
        let order = Arc::new(Mutex::new(Vec::new()));
        let running = Arc::new(AtomicUsize::new(0));
        let mut waiting = Vec::new();
        for i in 0..n {
            waiting.push(queue(&state, i, &order, &running).await);
        }
        assert!(
            order.lock().unwrap().is_empty(),
            "work started without a turn"
        );
        for (release, task) in held {
            release.send(()).unwrap();
            task.await.unwrap();
        }
        let mut most = 0;
        for w in waiting {
            most = most.max(w.await.unwrap());
        }
        let order = order.lock().unwrap().clone();
        (order, most)
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn work_waits_for_a_turn_first_come_first_served() {
        let (order, most) = queued(1, 3).await;
        assert_eq!(most, 1, "two at work with one turn");
        assert_eq!(order, vec![0, 1, 2], "not first come, first served");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn no_more_than_the_turns_work_at_once() {
        let (order, most) = queued(2, 6).await;
        assert!(most <= 2, "{most} at work at once with 2 turns");
        assert_eq!(order.len(), 6);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn health_and_the_cus_answer_while_every_turn_is_held() {
        let state = state(1);
        // The CUs' snapshot is published (the first read makes it).
        assert_eq!(status(&state, "/cus").await, StatusCode::OK);
        assert!(
            state.lifecycle.cus_published().is_some(),
            "no snapshot to answer from"
        );
        let held = hold_turns(&state, 1).await;
        let answers = async {
            (
                status(&state, "/health").await,
                status(&state, "/cus").await,
                status(&state, "/changesets").await,
            )
        };
        let answers = tokio::time::timeout(Duration::from_secs(10), answers)
            .await
            .expect("an answer from memory waited for a turn");
        assert_eq!(answers, (StatusCode::OK, StatusCode::OK, StatusCode::OK));
        // A query of the store waits for the turn.
        let s = state.clone();
        let mut query = tokio::spawn(async move { status(&s, "/sparql?query=ASK%7B%7D").await });
        assert!(
            tokio::time::timeout(Duration::from_millis(200), &mut query)
                .await
                .is_err(),
            "a query of the store ran without a turn"
        );
        for (release, task) in held {
            release.send(()).unwrap();
            task.await.unwrap();
        }
        assert_eq!(query.await.unwrap(), StatusCode::OK);
    }
}
