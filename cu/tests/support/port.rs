//! A free loopback port for a test's listener, shared by the test binaries of the data plane
//! (`cu`, `executor`, `lifecycle`, `server`: `#[path]`-included, as each is its own crate).
#![allow(
    clippy::expect_used,
    reason = "test support: a failed set-up is a failed test"
)]

/// A loopback port nothing listens on, for a process to listen on next. Taken below Linux's
/// ephemeral range (32768 and up), where the kernel picks the local ports of outgoing
/// connections: a port 0 gives is free only until some client's connection takes it, which
/// may happen before the process listens. Each test binary walks its own stretch (by process
/// id) and never hands a port out twice.
pub fn free_port() -> u16 {
    use std::sync::atomic::{AtomicU32, Ordering};
    const FIRST: u32 = 12_000;
    const SPAN: u32 = 20_000;
    static NEXT: AtomicU32 = AtomicU32::new(u32::MAX);
    let _ = NEXT.compare_exchange(
        u32::MAX,
        (std::process::id() * 97) % SPAN,
        Ordering::SeqCst,
        Ordering::SeqCst,
    );
    for _ in 0..SPAN {
        let port = u16::try_from(FIRST + NEXT.fetch_add(1, Ordering::SeqCst) % SPAN)
            .expect("a port below 32768");
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
    panic!("no free loopback port between {FIRST} and {}", FIRST + SPAN)
}
