//! `dyknow-cu BUILTIN`: runs one of the executor's builtins as a process CU (`dkros:hasType
//! "process"`, `dkros:hasSource "dyknow-cu dyknow/relay"`) without the knowledge service's
//! binary (`dyknow cu BUILTIN` does the same). It speaks the CU protocol through
//! `dyknow_cu::run_process`.

use std::process::ExitCode;

use dyknow_executor::builtins::{self, Host};

fn usage() -> String {
    format!(
        "usage: dyknow-cu BUILTIN   (one of: {})\n\
         Runs a builtin as a process CU; an executor starts it and sets its environment \
         (DYKNOW_CU, DYKNOW_CONNECT, ...: docs/executors.md)",
        builtins::names().join(", ")
    )
}

fn main() -> ExitCode {
    let Some(name) = std::env::args().nth(1) else {
        eprintln!("{}", usage());
        return ExitCode::from(dyknow_cu::USAGE_EXIT);
    };
    if name == "--help" || name == "-h" {
        println!("{}", usage());
        return ExitCode::SUCCESS;
    }
    let Some(factory) = builtins::builtin(&name) else {
        eprintln!(
            "no builtin {name:?} (one of: {})",
            builtins::names().join(", ")
        );
        return ExitCode::from(dyknow_cu::USAGE_EXIT);
    };
    dyknow_cu::run_process(|spec| factory.build(spec, Host::Process))
}
