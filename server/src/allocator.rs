//! The C allocator of the long-running processes (`dyknow serve`, `dyknow executor`).
//!
//! glibc's `malloc` gives every thread that contends an arena of its own (up to eight per core)
//! and raises its `mmap` threshold each time a large block is freed, so large buffers end up
//! inside arenas that it can only trim from the top. Under the service's load (a thread per
//! blocking request, RocksDB's and Zenoh's threads: ~100 threads) the manager's resident memory
//! grew from 39 to 589 MB in 10 minutes while a heap profile saw ~70 MB live
//! (docs/reliability.md, guarantee 5). With as many arenas as cores and a fixed threshold it
//! grew to 293 MB in the same run, and answered faster.
//!
//! These settings are glibc *tunables*, read once when the process starts, so they cannot be set
//! from inside it without `unsafe` (`mallopt`), which the workspace forbids. Instead the process
//! re-executes itself, once, with `GLIBC_TUNABLES` set ([`tune`]). Whoever already set
//! `GLIBC_TUNABLES` (even to the empty string) keeps their own.

/// The variable glibc reads its tunables from.
pub const VAR: &str = "GLIBC_TUNABLES";

/// The tunables for a machine with `cores` cores: as many arenas as cores (at least 2), and
/// allocations from 128 KiB up served by `mmap` and returned on `free` (the fixed threshold turns
/// glibc's dynamic raise off), with the heap trimmed above 128 KiB free.
#[must_use]
pub fn tunables(cores: usize) -> String {
    format!(
        "glibc.malloc.arena_max={}:glibc.malloc.mmap_threshold=131072:glibc.malloc.trim_threshold=131072",
        cores.max(2)
    )
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
        // `/proc/self/exe` is this very binary, even if its path was replaced since it started.
        let error = std::process::Command::new("/proc/self/exe")
            .arg0(arg0)
            .args(args)
            .env(VAR, tunables(cores))
            .exec();
        eprintln!("warning: cannot re-execute with {VAR} set, keeping glibc's defaults: {error}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn there_are_as_many_arenas_as_cores_and_at_least_two() {
        assert!(tunables(1).starts_with("glibc.malloc.arena_max=2:"));
        assert!(tunables(2).starts_with("glibc.malloc.arena_max=2:"));
        assert!(tunables(16).starts_with("glibc.malloc.arena_max=16:"));
        assert!(tunables(4).contains(":glibc.malloc.mmap_threshold=131072:"));
    }
}
