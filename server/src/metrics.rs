//! Request metrics in the Prometheus text exposition format.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use dyknow_store::{SparqlQueryError, StoreStatistics};

/// Upper bounds of the latency histogram buckets, in seconds.
const BUCKETS: [f64; 12] = [
    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 5.0,
];

#[derive(Default)]
struct Histogram {
    counts: [u64; BUCKETS.len()],
    count: u64,
    sum: f64,
}

#[derive(Default)]
struct RouteStats {
    /// status → count.
    requests: BTreeMap<u16, u64>,
    latency: Histogram,
}

#[derive(Default)]
struct Inner {
    /// `"METHOD route"` → counts and latencies (keys are allocated once per route).
    routes: BTreeMap<String, RouteStats>,
}

/// Counts and latencies of requests by route and status.
#[derive(Default)]
pub struct Metrics {
    inner: Mutex<Inner>,
    /// SPARQL queries cancelled at `--query-timeout`.
    sparql_timeouts: AtomicU64,
    /// SPARQL queries cancelled at `--query-memory`.
    sparql_over_memory: AtomicU64,
}

impl Metrics {
    /// Counts a SPARQL query that failed with `error`, if a limit cancelled it.
    pub fn sparql_failed(&self, error: &SparqlQueryError) {
        let counter = match error {
            SparqlQueryError::Timeout(_) => &self.sparql_timeouts,
            SparqlQueryError::MemoryLimit(_) => &self.sparql_over_memory,
            _ => return,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// Records one answered request.
    pub fn record(&self, method: &str, route: &str, status: u16, elapsed: Duration) {
        let mut inner = self
            .inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut key = [0u8; 128];
        let key = route_key(&mut key, method, route);
        if !inner.routes.contains_key(key.as_ref()) {
            inner.routes.insert(key.to_string(), RouteStats::default());
        }
        let Some(stats) = inner.routes.get_mut(key.as_ref()) else {
            return;
        };
        *stats.requests.entry(status).or_default() += 1;
        let h = &mut stats.latency;
        let secs = elapsed.as_secs_f64();
        for (i, bound) in BUCKETS.iter().enumerate() {
            if secs <= *bound {
                h.counts[i] += 1;
            }
        }
        h.count += 1;
        h.sum += secs;
    }

    /// The Prometheus text format, with the store's size.
    pub fn render(&self, stats: &StoreStatistics) -> String {
        let inner = self
            .inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut out = String::new();
        let _ = writeln!(
            out,
            "# HELP dyknow_http_requests_total HTTP requests answered, by route and status."
        );
        let _ = writeln!(out, "# TYPE dyknow_http_requests_total counter");
        for (key, stats) in &inner.routes {
            let (method, route) = key.split_once(' ').unwrap_or((key, ""));
            for (status, n) in &stats.requests {
                let _ = writeln!(
                    out,
                    "dyknow_http_requests_total{{method=\"{method}\",route=\"{}\",status=\"{status}\"}} {n}",
                    escape(route)
                );
            }
        }
        let _ = writeln!(
            out,
            "# HELP dyknow_http_request_duration_seconds Latency of HTTP requests, by route."
        );
        let _ = writeln!(out, "# TYPE dyknow_http_request_duration_seconds histogram");
        for (key, stats) in &inner.routes {
            let (method, route) = key.split_once(' ').unwrap_or((key, ""));
            let h = &stats.latency;
            let labels = format!("method=\"{method}\",route=\"{}\"", escape(route));
            for (bound, count) in BUCKETS.iter().zip(h.counts) {
                let _ = writeln!(
                    out,
                    "dyknow_http_request_duration_seconds_bucket{{{labels},le=\"{bound}\"}} {count}"
                );
            }
            let _ = writeln!(
                out,
                "dyknow_http_request_duration_seconds_bucket{{{labels},le=\"+Inf\"}} {}",
                h.count
            );
            let _ = writeln!(
                out,
                "dyknow_http_request_duration_seconds_sum{{{labels}}} {}",
                h.sum
            );
            let _ = writeln!(
                out,
                "dyknow_http_request_duration_seconds_count{{{labels}}} {}",
                h.count
            );
        }
        let _ = writeln!(
            out,
            "# HELP dyknow_sparql_cancelled_total SPARQL queries cancelled, by the limit they \
             passed (timeout: --query-timeout, memory: --query-memory)."
        );
        let _ = writeln!(out, "# TYPE dyknow_sparql_cancelled_total counter");
        for (limit, counter) in [
            ("timeout", &self.sparql_timeouts),
            ("memory", &self.sparql_over_memory),
        ] {
            let _ = writeln!(
                out,
                "dyknow_sparql_cancelled_total{{limit=\"{limit}\"}} {}",
                counter.load(Ordering::Relaxed)
            );
        }
        for (name, help, value) in [
            ("dyknow_store_quads", "Quads in the store.", stats.quads),
            (
                "dyknow_transformations",
                "Transformation specs in the model.",
                stats.transformations,
            ),
            (
                "dyknow_targets",
                "Target specs in the model.",
                stats.targets,
            ),
            (
                "dyknow_ontology_extensions",
                "Ontology extensions in the model.",
                stats.extensions,
            ),
        ] {
            let _ = writeln!(out, "# HELP {name} {help}");
            let _ = writeln!(out, "# TYPE {name} gauge");
            let _ = writeln!(out, "{name} {value}");
        }
        out
    }
}

/// `"METHOD route"` without allocating for the usual short routes.
fn route_key<'a>(
    buffer: &'a mut [u8; 128],
    method: &str,
    route: &str,
) -> std::borrow::Cow<'a, str> {
    let len = method.len() + 1 + route.len();
    if len > buffer.len() {
        return std::borrow::Cow::Owned(format!("{method} {route}"));
    }
    buffer[..method.len()].copy_from_slice(method.as_bytes());
    buffer[method.len()] = b' ';
    buffer[method.len() + 1..len].copy_from_slice(route.as_bytes());
    match std::str::from_utf8(&buffer[..len]) {
        Ok(key) => std::borrow::Cow::Borrowed(key),
        Err(_) => std::borrow::Cow::Owned(format!("{method} {route}")),
    }
}

fn escape(label: &str) -> String {
    label
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_cumulative() {
        let m = Metrics::default();
        m.record("GET", "/health", 200, Duration::from_micros(300));
        m.record("GET", "/health", 200, Duration::from_millis(30));
        let text = m.render(&StoreStatistics::default());
        assert!(text.contains(
            r#"dyknow_http_requests_total{method="GET",route="/health",status="200"} 2"#
        ));
        assert!(text.contains(r#"dyknow_http_request_duration_seconds_bucket{method="GET",route="/health",le="0.0005"} 1"#));
        assert!(text.contains(r#"dyknow_http_request_duration_seconds_bucket{method="GET",route="/health",le="0.05"} 2"#));
        assert!(text.contains(
            r#"dyknow_http_request_duration_seconds_count{method="GET",route="/health"} 2"#
        ));
    }
}
