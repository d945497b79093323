//! The DyKnow CU SDK: write a transformation once, run it as a computation unit on a
//! **Zenoh** data plane (seed Ch. 5.2: the `dyknow::NodeHandle` of Listings 5.1–5.2).
//!
//! A [`Transformation`] gets samples on named in ports, publishes on named out ports
//! ([`NodeHandle::publish`]), reads its parameters and sets timers; it never sees a channel.
//! The executor (crate `dyknow-executor`) binds its ports to channels while it runs — make
//! before break — through a [`Unit`]; a process CU is a program whose `main` is
//! [`run_process`]. [`keys`] says where channels and control keys live; [`protocol`] holds
//! the messages between the manager, its executors and process CUs. Neither Oxigraph nor
//! RocksDB is needed.
//!
//! ```no_run
//! use dyknow_cu::{CuError, NodeHandle, Sample, Transformation, run_process};
//!
//! /// The seed's echo unit (Example 13).
//! struct Echo;
//!
//! impl Transformation for Echo {
//!     fn on_sample(&mut self, cu: &mut NodeHandle<'_>, _port: &str, sample: Sample)
//!         -> Result<(), CuError> {
//!         // The sample as it came: the payload goes out without being written again.
//!         cu.forward_all(&sample)
//!     }
//! }
//!
//! fn main() -> std::process::ExitCode {
//!     run_process(|_spec| Ok(Echo))
//! }
//! ```

mod error;
pub mod keys;
mod pins;
mod process;
pub mod protocol;
mod sample;
mod timers;
mod transformation;
mod unit;

pub use error::{CuError, KeyError, zenoh_message};
pub use keys::Namespace;
pub use pins::{KEPT as KEPT_KEYS, pinned_key};
pub use process::{
    ProcessEnv, USAGE_EXIT, client_config, client_config_file, process_identity, router_config,
    run_process,
};
pub use sample::{Sample, SampleError, now_ms};
pub use timers::{Fire, Timers};
pub use transformation::{Collect, NodeHandle, Outputs, TimerId, Transformation};
pub use unit::{CrashHook, INBOX_CAPACITY, Started, Unit, UnitSpec, panic_message};

pub use zenoh;
