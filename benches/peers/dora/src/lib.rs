//! What the two nodes share.

use tracing_subscriber::filter::LevelFilter;

/// Prints dora-node-api's log lines at `BENCH_LOG` (default `warn`; `debug` tells which path,
/// direct Zenoh or through the daemon, each output takes) on stderr, which dora collects.
pub fn init_log() {
    let level = std::env::var("BENCH_LOG")
        .ok()
        .and_then(|l| l.parse().ok())
        .unwrap_or(LevelFilter::WARN);
    tracing_subscriber::fmt()
        .with_max_level(level)
        .with_writer(std::io::stderr)
        .init();
}
