//! `dyknow-cu BUILTIN`: runs one of the executor's builtins as a process CU (`dkros:hasType
//! "process"`, `dkros:hasSource "dyknow-cu dyknow/relay"`), for crash isolation or to measure
//! process hops against thread hops. It speaks the CU protocol through `dyknow_cu::run_process`.

use std::process::ExitCode;

use dyknow_executor::builtins::{self, Host};

fn main() -> ExitCode {
    let Some(name) = std::env::args().nth(1) else {
        eprintln!(
            "usage: dyknow-cu BUILTIN   (one of: {})",
            builtins::names().join(", ")
        );
        return ExitCode::from(64);
    };
    let Some(factory) = builtins::builtin(&name) else {
        eprintln!(
            "no builtin {name:?} (one of: {})",
            builtins::names().join(", ")
        );
        return ExitCode::from(64);
    };
    dyknow_cu::run_process(|spec| factory(spec, Host::Process).map(Boxed))
}

/// A boxed transformation as a transformation.
struct Boxed(Box<dyn dyknow_cu::Transformation>);

impl dyknow_cu::Transformation for Boxed {
    fn start(&mut self, cu: &mut dyknow_cu::NodeHandle<'_>) -> Result<(), dyknow_cu::CuError> {
        self.0.start(cu)
    }
    fn on_sample(
        &mut self,
        cu: &mut dyknow_cu::NodeHandle<'_>,
        port: &str,
        sample: dyknow_cu::Sample,
    ) -> Result<(), dyknow_cu::CuError> {
        self.0.on_sample(cu, port, sample)
    }
    fn on_timer(
        &mut self,
        cu: &mut dyknow_cu::NodeHandle<'_>,
        timer: dyknow_cu::TimerId,
    ) -> Result<(), dyknow_cu::CuError> {
        self.0.on_timer(cu, timer)
    }
    fn on_reconfigure(
        &mut self,
        cu: &mut dyknow_cu::NodeHandle<'_>,
    ) -> Result<(), dyknow_cu::CuError> {
        self.0.on_reconfigure(cu)
    }
}
