//! The `dyknow` binary.

fn main() -> std::process::ExitCode {
    dyknow_server::cli::main()
}
