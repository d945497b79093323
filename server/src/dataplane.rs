//! The service's data plane (`executors.md`): its Zenoh router, the embedded executor `local`,
//! and the task that hands what the executors report to the life-cycle (crashes as
//! perturbations, measured CPU costs as observations, executors coming and going as
//! registrations and deregistrations).

use std::sync::Arc;
use std::time::Duration;

use dyknow_cu::zenoh::{self, Wait};
use dyknow_lifecycle::{FleetEvent, LifecycleError, Manager, Observation};
use tokio::sync::mpsc::UnboundedReceiver;
use tokio::time::Instant;

/// Zenoh's default link lease, in milliseconds.
pub const DEFAULT_LEASE_MS: u64 = 10_000;

/// Where the manager's Zenoh router listens unless told otherwise: loopback only.
pub const DEFAULT_LISTEN: &str = "tcp/127.0.0.1:7447";

/// Zenoh's own configuration, read from `--zenoh-config FILE` (JSON5, JSON or YAML, Zenoh's
/// format: TLS certificates, access control, buffers…). DyKnow then sets what its flags say.
#[derive(Debug, Clone)]
pub struct ZenohFile {
    /// The file.
    pub path: std::path::PathBuf,
    config: zenoh::Config,
    /// The endpoints the file lists under `listen/endpoints`, when it lists any.
    listen: Option<Vec<String>>,
    /// What the file itself says of scouting.
    scouting: Scouting,
}

/// What a Zenoh configuration file says of scouting, where it says anything (Zenoh's own
/// defaults turn both on; DyKnow turns off what the file does not ask for).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Scouting {
    /// `scouting/multicast/enabled`.
    pub multicast: Option<bool>,
    /// `scouting/gossip/enabled`.
    pub gossip: Option<bool>,
    /// Whether it sets `scouting/multicast/autoconnect`.
    pub autoconnect: bool,
}

impl Scouting {
    /// What a configuration file, read as JSON, sets (`None`: a YAML file, which Zenoh reads
    /// and in which DyKnow sees no request: scouting stays off).
    fn of(file: Option<&serde_json::Value>) -> Self {
        let Some(file) = file else {
            return Self::default();
        };
        let at = |path: &str| file.pointer(path);
        Self {
            multicast: at("/scouting/multicast/enabled").and_then(serde_json::Value::as_bool),
            gossip: at("/scouting/gossip/enabled").and_then(serde_json::Value::as_bool),
            autoconnect: at("/scouting/multicast/autoconnect").is_some(),
        }
    }
}

/// A JSON5 syntax error in `path` as `path:line:column: message` (one line).
fn json5_error(path: &std::path::Path, error: &json5::Error) -> String {
    match error {
        json5::Error::Message { msg, location } => {
            // The parser's own report draws the line; its last `= ` part says what is wrong.
            let said = msg.rsplit_once("= ").map_or(msg.as_str(), |(_, said)| said);
            let message = said.split_whitespace().collect::<Vec<_>>().join(" ");
            match location {
                Some(at) => format!("{}:{}:{}: {message}", path.display(), at.line, at.column),
                None => format!("{}: {message}", path.display()),
            }
        }
    }
}

/// Zenoh's refusal of a configuration file in one line: `path:line:column: message` when it
/// says where (`JSON error: Message { msg: "…", location: Some(Location { line: 1, column:
/// 28 }) }`, an unknown or mistyped field), else `the Zenoh configuration path: message`.
fn zenoh_file_error(path: &std::path::Path, message: &str) -> String {
    let between = |start: &str, end: &str| {
        let from = message.find(start)? + start.len();
        let to = message[from..].find(end)? + from;
        Some(&message[from..to])
    };
    let said = between("msg: \"", "\", location");
    let line = between("line: ", ",");
    let column = between("column: ", " ");
    match (said, line, column) {
        (Some(said), Some(line), Some(column)) => {
            format!("{}:{line}:{column}: {said}", path.display())
        }
        _ => format!(
            "the Zenoh configuration {}: {}",
            path.display(),
            message.split_whitespace().collect::<Vec<_>>().join(" ")
        ),
    }
}

impl ZenohFile {
    /// Reads `path`.
    pub fn read(path: &std::path::Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            format!(
                "cannot read the Zenoh configuration {}: {e}",
                path.display()
            )
        })?;
        // A JSON5 file that does not parse is said as `file:line:column: message`, not as
        // Zenoh's parser trace.
        let yaml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("yaml") || e.eq_ignore_ascii_case("yml"));
        let json = (!yaml)
            .then(|| json5::from_str::<serde_json::Value>(&text))
            .transpose()
            .map_err(|e| json5_error(path, &e))?;
        let config = zenoh::Config::from_file(path)
            .map_err(|e| zenoh_file_error(path, &dyknow_cu::zenoh_message(&e)))?;
        let endpoints = |c: &zenoh::Config| c.get_json("listen/endpoints").unwrap_or_default();
        // Zenoh's default (`tcp/[::]:7447` for a router: every interface) is never used: a
        // file that does not list endpoints leaves them to the flags and their defaults.
        let listen = (endpoints(&config) != endpoints(&zenoh::Config::default()))
            .then(|| router_endpoints(&endpoints(&config)))
            .filter(|listen| !listen.is_empty());
        let scouting = Scouting::of(json.as_ref());
        Ok(Self {
            path: path.to_owned(),
            config,
            listen,
            scouting,
        })
    }

    /// What the file says of scouting.
    pub fn scouting(&self) -> Scouting {
        self.scouting
    }

    /// The endpoints the file lists under `listen/endpoints`, if it lists any.
    pub fn listen(&self) -> Option<&[String]> {
        self.listen.as_deref()
    }

    /// Whether the file turns on Zenoh's access control denying by default (rules then say
    /// who may do what); access control that allows by default restricts nothing.
    pub fn access_control(&self) -> bool {
        self.config
            .get_json("access_control/enabled")
            .is_ok_and(|v| v == "true")
            && self
                .config
                .get_json("access_control/default_permission")
                .is_ok_and(|v| v == "\"deny\"")
    }

    /// Whether TLS links require client certificates (mutual TLS).
    pub fn mutual_tls(&self) -> bool {
        self.config
            .get_json("transport/link/tls/enable_mtls")
            .is_ok_and(|v| v == "true")
    }
}

/// The router's endpoints in a `listen/endpoints` value: a list, or one list per mode.
fn router_endpoints(json: &str) -> Vec<String> {
    let value: serde_json::Value = serde_json::from_str(json).unwrap_or_default();
    let list = match &value {
        serde_json::Value::Object(per_mode) => per_mode.get("router").cloned().unwrap_or_default(),
        v => v.clone(),
    };
    serde_json::from_value(list).unwrap_or_default()
}

/// Whether `endpoint` (`proto/address[?metadata][#config]`) can only be reached from this
/// machine: a Unix socket, or an IP address or `localhost` that is loopback.
pub fn is_local(endpoint: &str) -> bool {
    let Some((proto, rest)) = endpoint.split_once('/') else {
        return false;
    };
    if matches!(proto, "unixsock-stream" | "unixpipe") {
        return true;
    }
    let address = rest.split(['?', '#']).next().unwrap_or_default();
    let host = address.rsplit_once(':').map_or(address, |(host, _)| host);
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// A setting of an endpoint's configuration part (`proto/address#key=value;key=value`).
fn endpoint_setting<'a>(endpoint: &'a str, key: &str) -> Option<&'a str> {
    endpoint
        .split_once('#')?
        .1
        .split(';')
        .filter_map(|kv| kv.split_once('='))
        .find(|(k, _)| k.trim() == key)
        .map(|(_, v)| v.trim())
}

/// `endpoint` parses as a Zenoh endpoint, or the error says what it is not.
fn well_formed(endpoint: &str) -> Result<(), String> {
    let parsed = endpoint.parse::<zenoh::config::EndPoint>().map_err(|e| {
        format!(
            "{endpoint:?} is not a Zenoh endpoint ({}); e.g. tcp/127.0.0.1:7447",
            dyknow_cu::zenoh_message(&e)
        )
    })?;
    // An IP endpoint without a port parses, and is then retried for ever (connect) or fails
    // deep in Zenoh (listen): say so here.
    let ip = ["tcp", "udp", "tls", "quic", "ws"].contains(&parsed.protocol().as_str());
    let port = parsed
        .address()
        .as_str()
        .rsplit_once(':')
        .is_some_and(|(_, port)| port.parse::<u16>().is_ok());
    if ip && !port {
        return Err(format!(
            "{endpoint:?} is not a Zenoh endpoint (no port after the address); e.g. tcp/127.0.0.1:7447"
        ));
    }
    Ok(())
}

/// The access rule (`docs/reliability.md`): the data plane carries every stream and lets any
/// peer that reaches it host CUs, so a Zenoh endpoint that other machines can reach is only
/// opened with access control denying by default (`access_control` in `--zenoh-config`) or,
/// for `tls/` and `quic/` endpoints, mutual TLS (client certificates; the endpoint's own
/// `#enable_mtls=` wins over the file's). TLS without client certificates encrypts but lets
/// anyone in.
/// A malformed endpoint is refused as such first.
pub fn check_access(listen: &[String], file: Option<&ZenohFile>) -> Result<(), String> {
    if file.is_some_and(ZenohFile::access_control) {
        return Ok(());
    }
    let mutual_tls = file.is_some_and(ZenohFile::mutual_tls);
    for endpoint in listen {
        // A malformed endpoint is that, not a non-loopback one.
        well_formed(endpoint)?;
        let tls = endpoint.starts_with("tls/") || endpoint.starts_with("quic/");
        // An endpoint's own `#enable_mtls=…` overrides the file's.
        let mutual = endpoint_setting(endpoint, "enable_mtls").map_or(mutual_tls, |v| v == "true");
        let protected = is_local(endpoint) || (tls && mutual);
        if !protected {
            return Err(format!(
                "refusing to listen on the non-loopback Zenoh endpoint {endpoint} without access \
                 control: use a tls/ endpoint with client certificates \
                 (transport/link/tls/enable_mtls) or turn on access_control with \
                 default_permission \"deny\", in a --zenoh-config \
                 file (docs/reliability.md)"
            ));
        }
    }
    Ok(())
}

/// A Zenoh router configuration: Zenoh's own configuration `file` if any, then listening on
/// `listen`, connecting to `connect`, links declared gone after `lease_ms` of silence (the
/// file's lease, or Zenoh's 10 s, when `None`). Scouting is off unless the file asks for it
/// (`scouting/multicast/enabled` or `scouting/gossip/enabled` set to `true` in it): then
/// it is as the file says, and a router that finds another by multicast connects to it
/// unless the file sets `scouting/multicast/autoconnect` itself (Zenoh's default for a router
/// is never): so an executor finds the manager without `--connect`.
pub fn router_config(
    file: Option<&ZenohFile>,
    listen: &[String],
    connect: &[String],
    lease_ms: Option<u64>,
) -> Result<zenoh::Config, String> {
    if let Some(lease_ms) = lease_ms.filter(|l| !(100..=3_600_000).contains(l)) {
        return Err(format!(
            "the Zenoh lease must be between 100 ms and one hour, not {lease_ms} ms"
        ));
    }
    for endpoint in listen.iter().chain(connect) {
        well_formed(endpoint)?;
    }
    let json = |v: &[String]| serde_json::to_string(v).unwrap_or_default();
    let mut config = file.map_or_else(zenoh::Config::default, |f| f.config.clone());
    let set = |config: &mut zenoh::Config, key: &str, value: &str| {
        config.insert_json5(key, value).map_err(|e| {
            format!(
                "zenoh configuration {key}: {}",
                dyknow_cu::zenoh_message(&e)
            )
        })
    };
    set(&mut config, "mode", "\"router\"")?;
    set(&mut config, "listen/endpoints", &json(listen))?;
    set(&mut config, "connect/endpoints", &json(connect))?;
    let asked = file.map(ZenohFile::scouting).unwrap_or_default();
    if asked.multicast.is_none() {
        set(&mut config, "scouting/multicast/enabled", "false")?;
    }
    if asked.gossip.is_none() {
        set(&mut config, "scouting/gossip/enabled", "false")?;
    }
    if asked.multicast == Some(true) && !asked.autoconnect {
        set(
            &mut config,
            "scouting/multicast/autoconnect",
            r#"{ router: ["router"], peer: ["router", "peer"], client: ["router"] }"#,
        )?;
    }
    if let Some(lease_ms) = lease_ms {
        set(
            &mut config,
            "transport/link/tx/lease",
            &lease_ms.to_string(),
        )?;
    }
    // A lost link to a configured endpoint (the manager restarting) is retried every 250 ms
    // at first and at least once a second, not with Zenoh's default back-off up to 4 s: an
    // executor is back well within the manager's start-up grace.
    set(
        &mut config,
        "connect/retry",
        r#"{"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}"#,
    )?;
    Ok(config)
}

/// A Zenoh client configuration connecting to `connect` (for `dyknow listen` and
/// `dyknow publish`), on Zenoh's own configuration `file` if any.
pub fn client_config(
    file: Option<&std::path::Path>,
    connect: &[String],
) -> Result<zenoh::Config, String> {
    for endpoint in connect {
        well_formed(endpoint)?;
    }
    dyknow_cu::client_config_file(file, connect).map_err(|e| e.to_string())
}

/// Opens a session.
pub fn open(config: zenoh::Config) -> Result<zenoh::Session, String> {
    zenoh::open(config).wait().map_err(|e| {
        format!(
            "cannot open the Zenoh session: {}",
            dyknow_cu::zenoh_message(&e)
        )
    })
}

/// Hands the fleet's events to the manager until the fleet is gone or `stop` is said (or
/// dropped). Measured costs are batched: one store write per `flush` interval, and a last one
/// when it ends, with the costs already received (so a graceful stop loses none). Upkeep is
/// converted to CPU ms per time unit. An executor that appears is reconciled with the model;
/// `grace` after the start (or as soon as every CU of the model runs somewhere) the start-up
/// reconciliation respawns what runs nowhere and lets reviews run.
pub async fn forward(
    mut events: UnboundedReceiver<FleetEvent>,
    manager: Arc<Manager>,
    flush: Duration,
    grace: Duration,
    mut stop: tokio::sync::oneshot::Receiver<()>,
) {
    let mut pending: Vec<Observation> = Vec::new();
    let mut tick = tokio::time::interval(flush);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let start_up = tokio::time::sleep_until(Instant::now() + grace);
    tokio::pin!(start_up);
    let mut starting = manager.starting();
    if starting && all_placed(&manager).await {
        starting = false;
        start_up_reconcile(&manager).await;
    }
    loop {
        tokio::select! {
            // A stop comes first: after it, only measured costs are taken.
            biased;
            _ = &mut stop => {
                // The measured costs that came before the stop are kept; nothing else is
                // handled (an executor stopping with the service is no crash).
                while let Ok(event) = events.try_recv() {
                    if matches!(event, FleetEvent::Labour { .. } | FleetEvent::Upkeep { .. })
                        && let Ok(Some(observation)) = manager.handle(event)
                    {
                        pending.push(observation);
                    }
                }
                break;
            }
            () = &mut start_up, if starting => {
                starting = false;
                start_up_reconcile(&manager).await;
            }
            event = events.recv() => {
                let Some(event) = event else { break };
                let appeared = matches!(event, FleetEvent::Appeared { .. });
                let m = manager.clone();
                match tokio::task::spawn_blocking(move || m.handle(event)).await {
                    Ok(Ok(Some(observation))) => pending.push(observation),
                    Ok(Ok(None)) => {}
                    Ok(Err(e)) => tracing::error!("data plane: {e}"),
                    Err(e) => tracing::error!("data plane: {e}"),
                }
                if appeared && starting && all_placed(&manager).await {
                    starting = false;
                    start_up_reconcile(&manager).await;
                }
            }
            _ = tick.tick() => {
                if !pending.is_empty() {
                    let batch = std::mem::take(&mut pending);
                    let m = manager.clone();
                    run(move || m.observe_all(batch).map(|_| ())).await;
                }
            }
        }
    }
    if !pending.is_empty() {
        run(move || manager.observe_all(pending).map(|_| ())).await;
    }
}

/// Whether every CU of the model runs on some executor.
async fn all_placed(manager: &Arc<Manager>) -> bool {
    let m = manager.clone();
    matches!(
        tokio::task::spawn_blocking(move || m.all_placed()).await,
        Ok(Ok(true))
    )
}

/// The start-up pass of reconciliation: respawns what runs nowhere, then reviews may run.
async fn start_up_reconcile(manager: &Arc<Manager>) {
    let m = manager.clone();
    run(move || m.reconcile(None, Vec::new(), true).map(|_| ())).await;
}

async fn run(f: impl FnOnce() -> Result<(), LifecycleError> + Send + 'static) {
    match tokio::task::spawn_blocking(f).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => tracing::error!("data plane: {e}"),
        Err(e) => tracing::error!("data plane: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `text` read as a Zenoh configuration file; the file is removed once read (the tests
    /// left a directory of them in the temporary directory at every run).
    fn file(text: &str) -> ZenohFile {
        let dir = std::env::temp_dir().join(format!("dyknow-zenoh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{:x}.json5", fxhash(text)));
        std::fs::write(&path, text).unwrap();
        let read = ZenohFile::read(&path);
        let _ = std::fs::remove_file(&path);
        // Only once empty: tests on other threads may be writing theirs.
        let _ = std::fs::remove_dir(&dir);
        read.unwrap()
    }

    fn fxhash(text: &str) -> u64 {
        text.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
        })
    }

    /// The costs measured since the last batch are written when the forwarding stops (a
    /// graceful stop of the service): before, they were dropped with the task, up to a
    /// `flush` interval of them.
    #[tokio::test]
    async fn a_stop_writes_the_costs_measured_since_the_last_batch() {
        let kb = dyknow_store::KnowledgeBase::in_memory().unwrap();
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../specs/turtle/example-12.ttl"
        );
        kb.load_document(
            &std::fs::read(path).unwrap(),
            dyknow_store::InputFormat::Turtle,
        )
        .unwrap();
        let manager = Arc::new(
            Manager::new(
                Arc::new(kb),
                Arc::new(dyknow_lifecycle::ModelOnly),
                dyknow_lifecycle::Settings::default(),
            )
            .unwrap(),
        );
        let (events, received) = tokio::sync::mpsc::unbounded_channel();
        let (stop, stopping) = tokio::sync::oneshot::channel();
        // A batch a day: only the stop writes.
        let forwarding = tokio::spawn(forward(
            received,
            manager.clone(),
            Duration::from_secs(86_400),
            Duration::from_secs(86_400),
            stopping,
        ));
        let labour = |cpu_ms: f64| FleetEvent::Labour {
            transformation: "tid1".into(),
            cpu_ms,
        };
        events.send(labour(4.0)).unwrap();
        tokio::task::yield_now().await;
        events.send(labour(6.0)).unwrap();
        stop.send(()).unwrap();
        tokio::time::timeout(Duration::from_secs(30), forwarding)
            .await
            .expect("the forwarding ends at the stop")
            .unwrap();
        let learned = manager.learned();
        let estimate =
            (learned.labour.get(&dyknow_engine::Tid::from("tid1"))).expect("tid1's labour");
        assert_eq!((estimate.count, estimate.average), (2, 5.0));
    }

    /// Scouting stays off unless the file asks for it; what it asks for is kept, and a
    /// router that scouts by multicast connects to the routers it finds unless the file says
    /// otherwise.
    #[test]
    fn scouting_is_off_unless_the_file_asks_for_it() {
        let scouting = |file: Option<&ZenohFile>| {
            let config = router_config(file, &[], &[], None).unwrap();
            let get = |key: &str| config.get_json(key).unwrap();
            (
                get("scouting/multicast/enabled"),
                get("scouting/gossip/enabled"),
                get("scouting/multicast/autoconnect"),
            )
        };
        let off = ("false".to_owned(), "false".to_owned());
        let (multicast, gossip, _) = scouting(None);
        assert_eq!((multicast, gossip), off.clone());
        let (multicast, gossip, _) = scouting(Some(&file("{ mode: \"router\" }")));
        assert_eq!(
            (multicast, gossip),
            off.clone(),
            "a file that says nothing of it"
        );
        let (multicast, gossip, autoconnect) = scouting(Some(&file(
            "{ scouting: { multicast: { enabled: true, interface: \"lo\" } } }",
        )));
        assert_eq!((multicast.as_str(), gossip.as_str()), ("true", "false"));
        assert!(
            autoconnect.contains(r#""router":["router"]"#),
            "{autoconnect}"
        );
        let (multicast, gossip, autoconnect) = scouting(Some(&file(
            "{ scouting: { multicast: { enabled: true, autoconnect: { router: [] } }, gossip: { enabled: true } } }",
        )));
        assert_eq!((multicast.as_str(), gossip.as_str()), ("true", "true"));
        assert!(
            autoconnect.contains(r#""router":[]"#),
            "the file's own: {autoconnect}"
        );
        let (multicast, gossip, _) = scouting(Some(&file(
            "{ scouting: { multicast: { enabled: false }, gossip: { enabled: true } } }",
        )));
        assert_eq!((multicast.as_str(), gossip.as_str()), ("false", "true"));
    }

    /// A configuration file Zenoh or JSON5 refuses is said in one line, with where.
    #[test]
    fn a_bad_configuration_file_is_said_in_one_line() {
        let dir = std::env::temp_dir().join(format!("dyknow-zenoh-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let read = |name: &str, text: &str| {
            let path = dir.join(name);
            std::fs::write(&path, text).unwrap();
            ZenohFile::read(&path).unwrap_err()
        };
        let e = read(
            "syntax.json5",
            "{ scouting: { multicast: { enabled: true, }\n",
        );
        assert!(
            e.ends_with("syntax.json5:1:43: expected identifier or string"),
            "{e}"
        );
        let e = read(
            "typo.json5",
            "{ scouting: { multicast: { enabeld: true } } }\n",
        );
        assert!(
            e.contains("typo.json5:1:28: unknown field `enabeld`, expected one of `enabled`"),
            "{e}"
        );
        let missing = ZenohFile::read(&dir.join("missing.json5")).unwrap_err();
        for e in [e.as_str(), &missing] {
            assert!(!e.contains('\n') && !e.contains(".rs:"), "{e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_malformed_endpoint_is_called_malformed() {
        let e = check_access(&["garbage".to_owned()], None).unwrap_err();
        assert!(
            e.starts_with("\"garbage\" is not a Zenoh endpoint ("),
            "{e}"
        );
        assert!(!e.contains(".rs:"), "{e}");
        assert!(check_access(&["tcp/127.0.0.1:7447".to_owned()], None).is_ok());
        for portless in [
            "tcp/127.0.0.1",
            "tls/localhost",
            "tcp/[::1]",
            "tcp/127.0.0.1:x",
        ] {
            let e = router_config(None, &[], &[portless.to_owned()], None).unwrap_err();
            assert!(e.contains("no port after the address"), "{portless}: {e}");
        }
        assert!(
            router_config(
                None,
                &[],
                &["unixsock-stream//tmp/dyknow.sock".to_owned()],
                None
            )
            .is_ok()
        );
        let e = check_access(&["tcp/0.0.0.0:7447".to_owned()], None).unwrap_err();
        assert!(
            e.starts_with("refusing to listen on the non-loopback"),
            "{e}"
        );
    }

    #[test]
    fn loopback_and_unix_sockets_are_local() {
        for e in [
            "tcp/127.0.0.1:7447",
            "tcp/127.0.0.2:1",
            "tcp/[::1]:7447",
            "tcp/localhost:7447",
            "tls/localhost:7447",
            "tcp/127.0.0.1:7447#iface=lo",
            "unixsock-stream//tmp/dyknow.sock",
        ] {
            assert!(is_local(e), "{e}");
        }
        for e in [
            "tcp/0.0.0.0:7447",
            "tcp/[::]:7447",
            "tcp/10.0.0.1:7447",
            "tcp/robot.local:7447",
            "tls/192.168.1.2:7447",
            "nonsense",
        ] {
            assert!(!is_local(e), "{e}");
        }
    }

    #[test]
    fn exposed_endpoints_need_mutual_tls_or_access_control() {
        let exposed = ["tcp/0.0.0.0:7447".to_owned()];
        let exposed_tls = ["tls/0.0.0.0:7447".to_owned()];
        assert!(check_access(&[DEFAULT_LISTEN.to_owned()], None).is_ok());
        assert!(check_access(&exposed, None).is_err());
        assert!(check_access(&exposed_tls, None).is_err());
        let tls_only = file(r#"{transport: {link: {tls: {enable_mtls: false}}}}"#);
        assert!(check_access(&exposed_tls, Some(&tls_only)).is_err());
        let mtls = file(r#"{transport: {link: {tls: {enable_mtls: true}}}}"#);
        assert!(check_access(&exposed_tls, Some(&mtls)).is_ok());
        // Mutual TLS protects the TLS endpoint only, not a plain TCP one next to it.
        let both = ["tls/0.0.0.0:7447".to_owned(), "tcp/0.0.0.0:7448".to_owned()];
        let error = check_access(&both, Some(&mtls)).unwrap_err();
        assert!(error.contains("tcp/0.0.0.0:7448"), "{error}");
        let acl = file(r#"{access_control: {enabled: true, default_permission: "deny"}}"#);
        assert!(check_access(&both, Some(&acl)).is_ok());
        // Access control that allows by default restricts nothing.
        let allow = file(r#"{access_control: {enabled: true, default_permission: "allow"}}"#);
        assert!(check_access(&both, Some(&allow)).is_err());
        // An endpoint that turns client certificates off is not protected by the file's.
        let off = ["tls/0.0.0.0:7447#enable_mtls=false".to_owned()];
        assert!(check_access(&off, Some(&mtls)).is_err());
        let on = ["tls/0.0.0.0:7447#enable_mtls=true".to_owned()];
        assert!(check_access(&on, Some(&tls_only)).is_ok());
    }

    #[test]
    fn a_file_gives_its_endpoints_and_zenohs_default_is_never_used() {
        assert_eq!(file("{}").listen(), None);
        // Endpoints for other modes only: none for the router.
        assert_eq!(
            file(r#"{listen: {endpoints: {peer: ["tcp/127.0.0.1:7502"]}}}"#).listen(),
            None
        );
        let f = file(r#"{listen: {endpoints: ["tcp/127.0.0.1:7500"]}}"#);
        assert_eq!(f.listen(), Some(&["tcp/127.0.0.1:7500".to_owned()][..]));
        let f = file(r#"{listen: {endpoints: {router: ["tcp/127.0.0.1:7501"], peer: []}}}"#);
        assert_eq!(f.listen(), Some(&["tcp/127.0.0.1:7501".to_owned()][..]));
        // The flags win over the file.
        let config = router_config(Some(&f), &[DEFAULT_LISTEN.to_owned()], &[], None).unwrap();
        assert_eq!(
            router_endpoints(&config.get_json("listen/endpoints").unwrap()),
            vec![DEFAULT_LISTEN.to_owned()]
        );
        let lease = file("{transport: {link: {tx: {lease: 2500}}}}");
        let config = router_config(Some(&lease), &[], &[], None).unwrap();
        assert_eq!(config.get_json("transport/link/tx/lease").unwrap(), "2500");
        let config = router_config(Some(&lease), &[], &[], Some(700)).unwrap();
        assert_eq!(config.get_json("transport/link/tx/lease").unwrap(), "700");
        assert!(router_config(None, &[], &[], Some(5)).is_err());
    }
}
