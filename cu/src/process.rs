//! A CU in its own process (`dkros:hasType "process"`): what the executor hands the process
//! and how it drives it (`docs/executors.md`). [`run_process`] is the whole `main` of
//! a process CU written with this SDK.
//!
//! The executor starts the program with these environment variables:
//!
//! | variable | value |
//! | --- | --- |
//! | `DYKNOW_CU` | the CU's name |
//! | `DYKNOW_TRANSFORMATION` | its transformation's label |
//! | `DYKNOW_NAMESPACE` | the key namespace (`dyknow`) |
//! | `DYKNOW_CONNECT` | Zenoh endpoints to connect to, comma-separated |
//! | `DYKNOW_EXECUTOR` | the executor's name (the CU exits when its parent, the executor, dies) |
//! | `DYKNOW_INPUTS`, `DYKNOW_OUTPUTS` | port names, comma-separated |
//! | `DYKNOW_PARAMS` | the parameters, a JSON object |
//! | `DYKNOW_ZENOH_CONFIG` | optional: a Zenoh configuration file (TLS certificates), the executor's `--zenoh-config` |
//! | `DYKNOW_ZENOH_LEASE_MS` | optional: Zenoh's link lease to declare (`transport/link/tx/lease`), the executor's `--zenoh-lease-ms`, so that a hung CU is noticed as soon as a hung executor |
//!
//! The CU then declares its liveliness token and its control queryable (which answers
//! [`ControlRequest`]s with [`ControlReply`]s), and runs until told to stop, until it
//! crashes (exit status 1) or until its executor's token vanishes.

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::sync::{Arc, Condvar, Mutex, PoisonError, mpsc};
use std::time::Duration;

use zenoh::Wait;

use crate::error::CuError;
use crate::keys::Namespace;
use crate::protocol::{ControlReply, ControlRequest};
use crate::timers::Timers;
use crate::transformation::Transformation;
use crate::unit::{Unit, UnitSpec};

/// What the executor said in the environment.
#[derive(Debug, Clone)]
pub struct ProcessEnv {
    /// The CU.
    pub spec: UnitSpec,
    /// The namespace.
    pub namespace: Namespace,
    /// Endpoints to connect to.
    pub connect: Vec<String>,
    /// The executor's name.
    pub executor: Option<String>,
    /// The executor's process ([`process_identity`]), when the executor said it
    /// (`DYKNOW_EXECUTOR_PROCESS`): the CU exits when that process is gone, even when its
    /// parent is a wrapper (a shell that started it) that outlives the executor.
    pub executor_process: Option<String>,
    /// Zenoh's own configuration file the executor runs with, if any (TLS certificates).
    pub zenoh_config: Option<std::path::PathBuf>,
    /// Zenoh's link lease to declare, in milliseconds (`DYKNOW_ZENOH_LEASE_MS`), if set.
    pub lease_ms: Option<u64>,
}

/// A process's identity on this host, `<pid>:<start time>` (field 22 of `/proc/<pid>/stat`,
/// clock ticks since boot): unlike the pid alone, it is never another process's after this one
/// is gone. `None` without `/proc` or when no such process runs.
pub fn process_identity(pid: u32) -> Option<String> {
    stat(pid).map(|(_, start)| format!("{pid}:{start}"))
}

/// The state (field 3) and start time (field 22) of process `pid`, from one read of
/// `/proc/<pid>/stat`.
fn stat(pid: u32) -> Option<(char, String)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command (field 2) is in parentheses and may hold anything: count after the last ')'
    // (the state, field 3, comes first).
    let mut fields = stat.rsplit_once(')')?.1.split_whitespace();
    let state = fields.next()?.chars().next()?;
    let start = fields.nth(18)?.to_owned();
    Some((state, start))
}

/// How long a control request that arrives while the CU is starting waits for it.
const START_WAIT: Duration = Duration::from_secs(5);

/// The running unit, once [`Unit::start`] has returned it, for the control service (which is
/// declared before it).
struct StartSlot<U = Unit> {
    unit: Mutex<Option<U>>,
    set: Condvar,
}

impl<U> Default for StartSlot<U> {
    fn default() -> Self {
        Self {
            unit: Mutex::new(None),
            set: Condvar::new(),
        }
    }
}

impl<U: Clone> StartSlot<U> {
    fn set(&self, unit: U) {
        *self.unit.lock().unwrap_or_else(PoisonError::into_inner) = Some(unit);
        self.set.notify_all();
    }

    /// The unit, waiting at most `limit` for it.
    fn wait(&self, limit: Duration) -> Option<U> {
        let guard = self.unit.lock().unwrap_or_else(PoisonError::into_inner);
        let (guard, _) = self
            .set
            .wait_timeout_while(guard, limit, |u| u.is_none())
            .unwrap_or_else(PoisonError::into_inner);
        guard.clone()
    }
}

/// Whether the process `identity` ([`process_identity`]) still runs; a zombie (exited, not
/// yet reaped) does not.
fn still_runs(identity: &str) -> bool {
    let Some((pid, start)) = identity
        .split_once(':')
        .and_then(|(p, s)| Some((p.parse().ok()?, s)))
    else {
        return true;
    };
    stat(pid).is_some_and(|(state, now)| state != 'Z' && now == start)
}

fn list(var: &str) -> Vec<String> {
    std::env::var(var)
        .unwrap_or_default()
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(str::to_owned)
        .collect()
}

impl ProcessEnv {
    /// Reads the environment.
    pub fn from_env() -> Result<Self, CuError> {
        let name = std::env::var("DYKNOW_CU")
            .map_err(|_| CuError::failed("DYKNOW_CU is not set: run me from a DyKnow executor"))?;
        let params = match std::env::var("DYKNOW_PARAMS") {
            Ok(text) if !text.trim().is_empty() => serde_json::from_str(&text)
                .map_err(|e| CuError::failed(format!("DYKNOW_PARAMS is not a JSON object: {e}")))?,
            _ => BTreeMap::new(),
        };
        Ok(Self {
            spec: UnitSpec {
                name,
                transformation: std::env::var("DYKNOW_TRANSFORMATION").unwrap_or_default(),
                inputs: list("DYKNOW_INPUTS"),
                outputs: list("DYKNOW_OUTPUTS"),
                params,
            },
            namespace: Namespace::new(
                std::env::var("DYKNOW_NAMESPACE").unwrap_or_else(|_| "dyknow".into()),
            )?,
            connect: list("DYKNOW_CONNECT"),
            executor: std::env::var("DYKNOW_EXECUTOR").ok(),
            executor_process: std::env::var("DYKNOW_EXECUTOR_PROCESS")
                .ok()
                .filter(|v| !v.is_empty()),
            zenoh_config: std::env::var_os("DYKNOW_ZENOH_CONFIG")
                .filter(|v| !v.is_empty())
                .map(Into::into),
            lease_ms: match std::env::var("DYKNOW_ZENOH_LEASE_MS") {
                Ok(v) if !v.is_empty() => Some(v.parse().map_err(|_| {
                    CuError::failed(format!(
                        "DYKNOW_ZENOH_LEASE_MS={v:?} is not a number of milliseconds"
                    ))
                })?),
                _ => None,
            },
        })
    }
}

/// A Zenoh client configuration connecting to `endpoints` (scouting off).
pub fn client_config(endpoints: &[String]) -> Result<zenoh::Config, CuError> {
    client_config_from(zenoh::Config::default(), endpoints)
}

/// A Zenoh client configuration connecting to `endpoints`, on top of Zenoh's own
/// configuration file `file` when there is one (its TLS certificates, for `tls/` endpoints):
/// client mode, scouting off, `endpoints` as the only ones.
pub fn client_config_file(
    file: Option<&std::path::Path>,
    endpoints: &[String],
) -> Result<zenoh::Config, CuError> {
    let base = match file {
        Some(path) => zenoh::Config::from_file(path).map_err(|e| {
            CuError::failed(format!(
                "cannot read the Zenoh configuration {}: {e}",
                path.display()
            ))
        })?,
        None => zenoh::Config::default(),
    };
    client_config_from(base, endpoints)
}

/// A Zenoh router configuration listening on `listen` and connecting to `connect`, scouting
/// off: a router of its own on loopback, as tests, benchmarks and examples start one.
pub fn router_config(listen: &[String], connect: &[String]) -> Result<zenoh::Config, CuError> {
    let json = |v: &dyn erased::Json| v.json();
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", &json(&"router"))?;
    config.insert_json5("listen/endpoints", &json(&listen))?;
    config.insert_json5("connect/endpoints", &json(&connect))?;
    config.insert_json5("scouting/multicast/enabled", "false")?;
    config.insert_json5("scouting/gossip/enabled", "false")?;
    Ok(config)
}

fn client_config_from(
    mut config: zenoh::Config,
    endpoints: &[String],
) -> Result<zenoh::Config, CuError> {
    let json = |v: &dyn erased::Json| v.json();
    config.insert_json5("mode", &json(&"client"))?;
    config.insert_json5("connect/endpoints", &json(&endpoints))?;
    config.insert_json5("listen/endpoints", "[]")?;
    config.insert_json5("scouting/multicast/enabled", "false")?;
    config.insert_json5("scouting/gossip/enabled", "false")?;
    Ok(config)
}

mod erased {
    pub trait Json {
        fn json(&self) -> String;
    }
    impl<T: serde::Serialize + ?Sized> Json for T {
        fn json(&self) -> String {
            serde_json::to_string(self).unwrap_or_default()
        }
    }
}

/// The exit status of a process CU run wrongly (by hand, without the environment an executor
/// always sets): a usage error (`EX_USAGE`), not the protocol's 1 for a crash.
pub const USAGE_EXIT: u8 = 64;

enum Exit {
    Stop,
    Crash(String),
    Orphaned,
}

/// The `main` of a process CU: reads [`ProcessEnv`], connects, starts the transformation
/// `make` builds and serves the executor until stopped (exit 0), crashed (exit 1) or orphaned
/// (exit 2). Run by hand, without the `DYKNOW_CU` an executor always sets, it is a usage error
/// (exit 64, [`USAGE_EXIT`]): not a crash.
pub fn run_process<T: Transformation>(
    make: impl FnOnce(&UnitSpec) -> Result<T, CuError>,
) -> ExitCode {
    if std::env::var_os("DYKNOW_CU").is_none_or(|v| v.is_empty()) {
        eprintln!(
            "DYKNOW_CU is not set: a process CU is started by a DyKnow executor, which sets its \
             environment (dkros:hasSource, docs/executors.md); it is not run by hand"
        );
        return ExitCode::from(USAGE_EXIT);
    }
    match serve(make) {
        Ok(Exit::Stop) => ExitCode::SUCCESS,
        Ok(Exit::Crash(reason)) => {
            eprintln!("crashed: {reason}");
            ExitCode::from(1)
        }
        Ok(Exit::Orphaned) => {
            eprintln!("the executor is gone: exiting");
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("cannot run: {e}");
            ExitCode::from(1)
        }
    }
}

fn serve<T: Transformation>(
    make: impl FnOnce(&UnitSpec) -> Result<T, CuError>,
) -> Result<Exit, CuError> {
    let env = ProcessEnv::from_env()?;
    if env
        .executor_process
        .as_deref()
        .is_some_and(|e| !still_runs(e))
    {
        // Started after the executor died (a wrapper that took its time): never run.
        return Ok(Exit::Orphaned);
    }
    let mut config = client_config_file(env.zenoh_config.as_deref(), &env.connect)?;
    if let Some(lease) = env.lease_ms {
        config.insert_json5("transport/link/tx/lease", &lease.to_string())?;
    }
    let session = zenoh::open(config).wait()?;
    let transformation = make(&env.spec)?;
    let (exit_tx, exit_rx) = mpsc::channel::<Exit>();
    // One CU: its callbacks run one at a time anyway, so the queue's thread fires them.
    let timers = Timers::with_workers(0);
    // The control service first, then the CU (whose liveliness token tells the executor it
    // may send requests): a request never finds the service missing. The token is declared
    // inside `Unit::start`, a moment before the unit is in the slot; a request arriving in
    // that moment (the executor binds ports as soon as it sees the token) waits for the slot
    // rather than being refused: refused, the executor took the CU for failed and a spawn
    // or a restart's respawn failed now and then.
    let slot: Arc<StartSlot> = Arc::default();
    let control_slot = slot.clone();
    let stop_tx = exit_tx.clone();
    let _queryable = session
        .declare_queryable(env.namespace.cu_control(&env.spec.name))
        .callback(move |query| {
            let request: Result<ControlRequest, _> = query
                .payload()
                .map(|p| serde_json::from_slice(&p.to_bytes()))
                .unwrap_or_else(|| serde_json::from_slice(b"null"));
            let reply = match (request, control_slot.wait(START_WAIT)) {
                (Err(e), _) => ControlReply {
                    ok: false,
                    error: Some(format!("not a control request: {e}")),
                    statistics: None,
                },
                (Ok(_), None) => ControlReply {
                    ok: false,
                    error: Some("still starting".into()),
                    statistics: None,
                },
                (Ok(request), Some(unit)) => control(&unit, request, &stop_tx),
            };
            let payload = serde_json::to_vec(&reply).unwrap_or_default();
            if let Err(e) = query.reply(query.key_expr().clone(), payload).wait() {
                tracing::warn!("cannot answer the executor: {e}");
            }
        })
        .wait()?;
    let crash_tx = exit_tx.clone();
    crate::unit::one_cu_process();
    let started = Unit::start(
        &session,
        &env.namespace,
        env.spec.clone(),
        Box::new(transformation),
        &timers,
        Box::new(move |reason| {
            let _ = crash_tx.send(Exit::Crash(reason.to_owned()));
        }),
    )?;
    let unit = started.unit;
    slot.set(unit.clone());
    // Orphaned when the executor is gone: its process is our parent, so a new parent (init or
    // a subreaper) means it died; and when the executor said which process it is, that
    // process being gone (a wrapper between it and us, a shell that did not `exec`, outlives
    // it and stays our parent). This needs no Zenoh at all, so it works whatever the state
    // of the connection.
    let parent = std::os::unix::process::parent_id();
    let orphan_tx = exit_tx.clone();
    let executor_process = env.executor_process.clone();
    let _ = std::thread::Builder::new()
        .name("dyknow-parent-watch".into())
        .spawn(move || {
            loop {
                std::thread::sleep(std::time::Duration::from_millis(200));
                if std::os::unix::process::parent_id() != parent
                    || executor_process.as_deref().is_some_and(|e| !still_runs(e))
                {
                    let _ = orphan_tx.send(Exit::Orphaned);
                    return;
                }
            }
        });
    drop(exit_tx);
    let exit = exit_rx.recv().unwrap_or(Exit::Orphaned);
    unit.stop();
    let _ = session.close().wait();
    Ok(exit)
}

fn control(unit: &Unit, request: ControlRequest, stop: &mpsc::Sender<Exit>) -> ControlReply {
    let result = match request {
        ControlRequest::BindIn { port, channel, .. } => unit.bind_in(&port, channel.as_deref()),
        ControlRequest::BindOut { port, channel, .. } => unit.bind_out(&port, channel.as_deref()),
        ControlRequest::Statistics => {
            return ControlReply {
                ok: true,
                error: None,
                statistics: Some(unit.statistics()),
            };
        }
        ControlRequest::Stop => {
            let _ = stop.send(Exit::Stop);
            Ok(())
        }
    };
    match result {
        Ok(()) => ControlReply {
            ok: true,
            error: None,
            statistics: None,
        },
        Err(e) => ControlReply {
            ok: false,
            error: Some(e.to_string()),
            statistics: None,
        },
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    use super::StartSlot;

    #[test]
    fn a_request_waits_for_the_unit_and_gives_up_after_its_limit() {
        let slot: Arc<StartSlot<u32>> = Arc::default();
        let started = Instant::now();
        assert_eq!(slot.wait(Duration::from_millis(50)), None);
        assert!(started.elapsed() >= Duration::from_millis(50));
        let setter = slot.clone();
        let set = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(100));
            setter.set(7);
        });
        // Asked before it is set, answered once it is (well before the limit).
        assert_eq!(slot.wait(Duration::from_secs(30)), Some(7));
        set.join().unwrap();
        assert_eq!(slot.wait(Duration::ZERO), Some(7));
    }
}
