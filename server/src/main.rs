//! The `dyknow` binary.

/// The system allocator, counting what each thread holds: SPARQL queries are bounded in memory
/// (`--query-memory`).
#[global_allocator]
static ALLOCATOR: dyknow_meter::Counting = dyknow_meter::Counting;

fn main() -> std::process::ExitCode {
    dyknow_server::cli::main()
}
