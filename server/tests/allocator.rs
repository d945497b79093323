//! The long-running processes tune glibc's allocator (docs/reliability.md, guarantee 5): they
//! re-execute themselves once, in the same process, with `GLIBC_TUNABLES` set, and leave a
//! `GLIBC_TUNABLES` the user set alone.
#![cfg(all(target_os = "linux", target_env = "gnu"))]
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::process::{Command, Stdio};

mod support;

use support::*;

/// `GLIBC_TUNABLES` of the running process `pid`, as the kernel saw it at its last `exec`.
fn tunables_of(pid: u32) -> Option<String> {
    let environ = std::fs::read(format!("/proc/{pid}/environ")).unwrap();
    environ
        .split(|b| *b == 0)
        .filter_map(|v| std::str::from_utf8(v).ok())
        .find_map(|v| v.strip_prefix("GLIBC_TUNABLES="))
        .map(str::to_owned)
}

/// Starts `dyknow <args>` with `GLIBC_TUNABLES` as given (`None`: unset), waits for `marker`
/// on its standard error and returns it with what it runs with.
fn started(args: &[&str], preset: Option<&str>, marker: &str) -> (Killed, Option<String>) {
    let mut command = Command::new(BIN);
    command
        .args(args)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    match preset {
        Some(v) => command.env("GLIBC_TUNABLES", v),
        None => command.env_remove("GLIBC_TUNABLES"),
    };
    let mut child = Killed(command.spawn().unwrap());
    wait_for_line(&mut child.0, marker);
    // The same process (exec keeps the pid) now runs with the tunables, under its own name
    // (re-executed through `/proc/self/exe` it was `exe`, which `pgrep dyknow` misses).
    let tunables = tunables_of(child.0.id());
    let name = std::fs::read_to_string(format!("/proc/{}/comm", child.0.id())).unwrap();
    let expected = std::path::Path::new(BIN)
        .file_name()
        .unwrap()
        .to_str()
        .unwrap();
    assert_eq!(name.trim_end(), &expected[..expected.len().min(15)]);
    (child, tunables)
}

/// `dyknow serve` in memory with its Zenoh router on `zenoh`.
fn serve_on(zenoh: &str) -> [&str; 6] {
    [
        "serve",
        "--in-memory",
        "--bind",
        "127.0.0.1:0",
        "--zenoh-listen",
        zenoh,
    ]
}

#[test]
fn serve_and_executor_run_with_tuned_arenas_unless_the_user_tuned_them() {
    let zenoh = format!("tcp/127.0.0.1:{}", free_port());
    let serve = serve_on(&zenoh);
    let cores = std::thread::available_parallelism().unwrap().get().max(2);
    let (_manager, tuned) = started(&serve, None, "knowledge service listening on ");
    assert_eq!(tuned.unwrap(), format!("glibc.malloc.arena_max={cores}"));
    let other = format!("tcp/127.0.0.1:{}", free_port());
    let serve = serve_on(&other);
    let (_, own) = started(
        &serve,
        Some("glibc.malloc.arena_max=3"),
        "knowledge service listening on ",
    );
    assert_eq!(own.as_deref(), Some("glibc.malloc.arena_max=3"));
    let (_, empty) = started(&serve, Some(""), "knowledge service listening on ");
    assert_eq!(empty.as_deref(), Some(""));

    // An executor too, joining the first manager.
    let executor = ["executor", "--name", "alloc", "--connect", &zenoh];
    let (_executor, tuned) = started(&executor, None, "connected to");
    assert!(
        tuned
            .as_deref()
            .unwrap()
            .starts_with("glibc.malloc.arena_max="),
        "{tuned:?}"
    );
}
