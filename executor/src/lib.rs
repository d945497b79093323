//! A DyKnow executor (`executors.md`): hosts computation units — builtin transformations as
//! threads of the executor (the seed's nodelets) and process CUs as children — on a Zenoh
//! data plane, and applies the manager's change sets to them. Embedded in `dyknow serve` as
//! `local`, stand-alone as `dyknow executor`. Needs neither Oxigraph nor RocksDB.

pub mod builtins;
mod host;
pub mod process;

pub use host::{Executor, ExecutorConfig, OnStepDown, check};
