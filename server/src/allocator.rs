//! The C allocator of the long-running processes (`dyknow serve`, `dyknow executor`).
//!
//! glibc's `malloc` gives every thread that contends an arena of its own, up to eight per core.
//! Under the service's load (a thread per blocking request in flight, RocksDB's and Zenoh's
//! threads: ~100 threads) the manager's resident memory grew from 39 to 541 MB in 5 minutes
//! while a heap profile saw ~70 MB live (docs/reliability.md, guarantee 5). With as many arenas
//! as cores it grew to 229 MB in the same 5 minutes, and answered faster. (A fixed 128 KiB
//! `mmap` and trim threshold on top gained little memory and made one large spec POST 41 %
//! slower, so it is not set.)
//!
//! Tunables are read once when the process starts, so they cannot be set from inside it
//! without `unsafe` (`mallopt`), which the workspace forbids. Instead the process re-executes
//! itself, once, with `GLIBC_TUNABLES` set ([`tune`]). Whoever already set `GLIBC_TUNABLES`
//! (even to the empty string) keeps their own.

/// The variable glibc reads its tunables from.
pub const VAR: &str = "GLIBC_TUNABLES";

/// The tunables for a machine with `cores` cores: as many malloc arenas as cores, at least 2.
#[must_use]
pub fn tunables(cores: usize) -> String {
    format!("glibc.malloc.arena_max={}", cores.max(2))
}

/// Re-executes this process with [`tunables`] in `GLIBC_TUNABLES` unless the variable is set
/// already (by the user, or by the first execution). Returns only when nothing was done or the
/// execution failed (then the process goes on with glibc's defaults, with a warning).
pub fn tune() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::process::CommandExt;
        if std::env::var_os(VAR).is_some() {
            return;
        }
        let cores = std::thread::available_parallelism().map_or(2, std::num::NonZeroUsize::get);
        let mut args = std::env::args_os();
        let arg0 = args.next().unwrap_or_default();
        let error = std::process::Command::new(this_binary())
            .arg0(arg0)
            .args(args)
            .env(VAR, tunables(cores))
            .exec();
        eprintln!("warning: cannot re-execute with {VAR} set, keeping glibc's defaults: {error}");
    }
}

/// The path to execute this very binary again: its own path when that still names it, so the
/// process keeps its name (the kernel names a process after the file it executes: `ps`,
/// `pgrep dyknow` and `ss -p` would see `exe`), else `/proc/self/exe`, which names this binary
/// even when its path was replaced since it started (a rebuild, an upgrade).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn this_binary() -> std::path::PathBuf {
    use std::os::unix::fs::MetadataExt;
    let proc = std::path::PathBuf::from("/proc/self/exe");
    let identity = |p: &std::path::Path| std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
    match (std::env::current_exe(), identity(&proc)) {
        (Ok(path), Some(this)) if identity(&path) == Some(this) => path,
        _ => proc,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn there_are_as_many_arenas_as_cores_and_at_least_two() {
        assert_eq!(tunables(1), "glibc.malloc.arena_max=2");
        assert_eq!(tunables(2), "glibc.malloc.arena_max=2");
        assert_eq!(tunables(16), "glibc.malloc.arena_max=16");
    }
}
