//! What the data-plane tests share: a real `dyknow serve` on ports of its own, stand-alone
//! executors, listeners on channels, polling, and specs written on the fly.
#![allow(dead_code, reason = "each test binary uses a part")]

pub mod browser;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use dyknow_cu::zenoh::{self, Wait};
use dyknow_cu::{Namespace, Sample};
use rcgen::{
    BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair,
};
use serde_json::Value;

pub const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

#[path = "../../../cu/tests/support/port.rs"]
mod port;
pub use port::free_port;

/// Reads a child's stderr until a line contains `marker` (returned), then drains it.
pub fn wait_for_line(child: &mut Child, marker: &str) -> String {
    wait_for_line_keeping(child, marker).0
}

/// The last lines a child wrote on its standard error.
pub type Tail = std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<String>>>;

/// [`wait_for_line`], keeping the last 40 lines the child writes (shown when a request to it
/// fails: why a service went away).
pub fn wait_for_line_keeping(child: &mut Child, marker: &str) -> (String, Tail) {
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = mpsc::channel();
    let marker = marker.to_owned();
    let tail = Tail::default();
    let kept = tail.clone();
    std::thread::spawn(move || {
        let mut sent = false;
        let verbose = std::env::var_os("DYKNOW_TEST_VERBOSE").is_some();
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if verbose {
                eprintln!("| {line}");
            }
            if !sent && line.contains(&marker) {
                let _ = tx.send(line.clone());
                sent = true;
            }
            let mut kept = kept.lock().unwrap();
            if kept.len() == 40 {
                kept.pop_front();
            }
            kept.push_back(line);
        }
        kept.lock()
            .unwrap()
            .push_back("(standard error closed)".into());
    });
    let line = match rx.recv_timeout(Duration::from_secs(60)) {
        Ok(line) => line,
        // What it said before it went (or hung) tells why.
        Err(e) => {
            let said: Vec<String> = tail.lock().unwrap().iter().cloned().collect();
            panic!(
                "the process did not start ({e}); its last lines:\n{}",
                said.join("\n")
            )
        }
    };
    (line, tail)
}

/// A running `dyknow serve` with its data plane on a port of its own.
pub struct Service {
    pub child: Child,
    pub url: String,
    pub zenoh: String,
    /// The last lines of its standard error.
    pub tail: Tail,
}

impl Service {
    /// `dyknow serve --in-memory` with `args`.
    pub fn start(args: &[&str]) -> Self {
        Self::start_with(
            &["--in-memory"],
            &format!("tcp/127.0.0.1:{}", free_port()),
            args,
        )
    }

    /// `dyknow serve` with `store` (`--in-memory` or `--data DIR`), its Zenoh router on
    /// `zenoh`, and `args`.
    pub fn start_with(store: &[&str], zenoh: &str, args: &[&str]) -> Self {
        let zenoh = zenoh.to_owned();
        let mut child = Command::new(BIN)
            .arg("serve")
            .args(store)
            .args(["--bind", "127.0.0.1:0", "--zenoh-listen", &zenoh])
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (line, tail) = wait_for_line_keeping(&mut child, "knowledge service listening on ");
        let url = line
            .split("listening on ")
            .nth(1)
            .and_then(|r| r.split_whitespace().next())
            .unwrap()
            .to_owned();
        Self {
            child,
            url,
            zenoh,
            tail,
        }
    }

    /// Panics with `what` went wrong and the service's last lines of standard error.
    pub fn failed(&self, what: &str, error: impl std::fmt::Display) -> ! {
        let tail = self
            .tail
            .lock()
            .unwrap()
            .iter()
            .cloned()
            .collect::<Vec<_>>();
        panic!(
            "{what}: {error}; the service's last lines:\n{}",
            tail.join("\n")
        )
    }

    /// `GET path`, whatever its status.
    fn call(&self, path: &str) -> ureq::http::Response<ureq::Body> {
        agent()
            .get(&format!("{}{path}", self.url))
            .call()
            .unwrap_or_else(|e| self.failed(&format!("GET {path}"), e))
    }

    pub fn get(&self, path: &str) -> Value {
        let mut r = self.call(path);
        assert_eq!(r.status().as_u16(), 200, "GET {path}");
        serde_json::from_str(&r.body_mut().read_to_string().unwrap()).unwrap()
    }

    pub fn status(&self, path: &str) -> u16 {
        self.call(path).status().as_u16()
    }

    pub fn post(&self, path: &str, turtle: &str) {
        let mut r = agent()
            .post(&format!("{}{path}", self.url))
            .header("Content-Type", "text/turtle")
            .send(turtle.as_bytes())
            .unwrap_or_else(|e| self.failed(&format!("POST {path}"), e));
        let body = r.body_mut().read_to_string().unwrap();
        assert_eq!(r.status().as_u16(), 201, "POST {path}: {body}");
    }

    /// A Zenoh client of the service's data plane.
    pub fn session(&self) -> zenoh::Session {
        zenoh::open(dyknow_cu::client_config(std::slice::from_ref(&self.zenoh)).unwrap())
            .wait()
            .unwrap()
    }

    pub fn change_sets(&self) -> Vec<Value> {
        self.get("/changesets").as_array().unwrap().clone()
    }

    pub fn cu_of(&self, transformation: &str) -> Option<Value> {
        self.get("/cus")
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["transformation"] == transformation)
            .cloned()
    }

    pub fn sigterm(mut self) -> std::process::ExitStatus {
        sigterm(&self.child);
        let status = wait_exit(&mut self.child);
        std::mem::forget(self);
        status
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        sigterm(&self.child);
        let _ = wait_exit(&mut self.child);
    }
}

/// A child process killed when dropped: a failed assertion leaves nothing running.
pub struct Killed(pub Child);

/// A stand-alone `dyknow executor` named `name` connected to the service; its PATH finds
/// `dyknow` (the command of process CUs such as the lab's segmenters).
pub fn executor(service: &Service, name: &str) -> Killed {
    executor_with(&service.zenoh, name, &[])
}

/// A stand-alone executor connected to the Zenoh endpoint `connect`, with `args`.
pub fn executor_with(connect: &str, name: &str, args: &[&str]) -> Killed {
    executor_keeping(connect, name, args).0
}

/// [`executor_with`], keeping the last lines the executor writes (for a failure's message).
pub fn executor_keeping(connect: &str, name: &str, args: &[&str]) -> (Killed, Tail) {
    let dir = std::path::Path::new(BIN).parent().unwrap();
    let path = format!(
        "{}:{}",
        dir.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut child = Command::new(BIN)
        .args(["executor", "--name", name, "--connect", connect])
        .args(args)
        .env("PATH", path)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (_, tail) = wait_for_line_keeping(&mut child, "connected to");
    (Killed(child), tail)
}

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub fn sigterm(child: &Child) {
    Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
}

pub fn wait_exit(child: &mut Child) -> std::process::ExitStatus {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            return child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A spec of `specs/turtle/`.
pub fn spec(name: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../specs/turtle")
        .join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

pub fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(60)))
        .build()
        .into()
}

/// Polls `f` until it gives something, for at most `timeout`.
pub fn eventually<T>(what: &str, timeout: Duration, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A transformation spec. `kind`/`source` name its implementation; `params` are
/// (name, Turtle literal) pairs; ports are (name, tag).
pub struct Tf<'a> {
    pub label: &'a str,
    pub kind: &'a str,
    pub source: &'a str,
    pub params: &'a [(&'a str, &'a str)],
    pub ins: &'a [(&'a str, &'a str)],
    pub outs: &'a [(&'a str, &'a str)],
    pub upkeep: Option<f64>,
    pub executor: Option<&'a str>,
}

impl Tf<'_> {
    pub fn turtle(&self) -> String {
        let mut t = format!(
            "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
             @prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .\n\
             @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n\
             [] a dkros:ROSTransformation ; rdfs:label \"{}\" ;\n   dkros:hasType \"{}\" ; dkros:hasSource \"{}\" ",
            self.label, self.kind, self.source
        );
        for (name, value) in self.params {
            t.push_str(&format!(
                ";\n   dkros:hasParam [ a dyknow:Parameter ; dyknow:hasName \"{name}\" ; dyknow:hasValue {value} ] "
            ));
        }
        for (name, tag) in self.ins {
            t.push_str(&format!(
                ";\n   dyknow:hasInPort [ dyknow:hasName \"{name}\" ; dyknow:hasTag [ dyknow:hasValue \"{tag}\" ] ] "
            ));
        }
        for (name, tag) in self.outs {
            t.push_str(&format!(
                ";\n   dyknow:hasOutPort [ dyknow:hasName \"{name}\" ; dyknow:hasTag [ dyknow:hasValue \"{tag}\" ] ] "
            ));
        }
        if let Some(u) = self.upkeep {
            t.push_str(&format!(
                ";\n   dyknow:hasCostModel [ a dyknow:UpkeepCostModel ; dyknow:hasValue {u:?} ] "
            ));
        }
        if let Some(e) = self.executor {
            t.push_str(&format!(";\n   dkros:hasExecutor \"{e}\" "));
        }
        t.push_str(".\n");
        t
    }
}

pub fn tf<'a>(
    label: &'a str,
    kind: &'a str,
    source: &'a str,
    params: &'a [(&'a str, &'a str)],
    ins: &'a [(&'a str, &'a str)],
    outs: &'a [(&'a str, &'a str)],
) -> Tf<'a> {
    Tf {
        label,
        kind,
        source,
        params,
        ins,
        outs,
        upkeep: None,
        executor: None,
    }
}

/// `counter`: a `dyknow/signal` counting 0, 1, 2, … on out port `out` (tag `Count`), with
/// `params` (`period_ms`).
pub fn counter<'a>(params: &'a [(&'a str, &'a str)]) -> Tf<'a> {
    tf(
        "counter",
        "builtin",
        "dyknow/signal",
        params,
        &[],
        &[("out", "Count")],
    )
}

/// `tenfold`: a process CU (`process_map`, the `dyknow cu dyknow/map` command line) that
/// multiplies the counts it reads (`Count`) by ten (`Tenfold`).
pub fn tenfold(process_map: &str) -> Tf<'_> {
    tf(
        "tenfold",
        "process",
        process_map,
        &[("scale", "10")],
        &[("in", "Count")],
        &[("out", "Tenfold")],
    )
}

pub fn target(label: &str, channel: &str, tag: &str) -> String {
    format!(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n\
         [] a dyknow:Target ; rdfs:label \"{label}\" ;\n\
            dyknow:hasChannel [ dyknow:hasChannelName \"{channel}\" ] ;\n\
            dyknow:hasTag [ dyknow:hasValue \"{tag}\" ] .\n"
    )
}

/// Samples arriving on a channel, with their arrival times.
pub struct Listener {
    rx: mpsc::Receiver<(Instant, Sample)>,
    _subscriber: zenoh::pubsub::Subscriber<()>,
}

impl Listener {
    pub fn new(session: &zenoh::Session, channel: &str) -> Self {
        let (tx, rx) = mpsc::channel();
        let subscriber = session
            .declare_subscriber(Namespace::default().channel(channel).unwrap())
            .callback(move |s| {
                if let Ok(sample) = Sample::from_slice(&s.payload().to_bytes()) {
                    let _ = tx.send((Instant::now(), sample));
                }
            })
            .wait()
            .unwrap();
        Self {
            rx,
            _subscriber: subscriber,
        }
    }

    /// The next sample, if one arrives within `wait`.
    pub fn within(&self, wait: Duration) -> Option<(Instant, Sample)> {
        self.rx.recv_timeout(wait).ok()
    }

    /// The samples that arrived and were not taken yet, without waiting.
    pub fn drain(&self) -> Vec<(Instant, Sample)> {
        self.rx.try_iter().collect()
    }

    pub fn next(&self) -> (Instant, Sample) {
        self.rx
            .recv_timeout(Duration::from_secs(30))
            .expect("a sample on the channel")
    }

    /// The first sample that arrives after `t`.
    pub fn first_after(&self, t: Instant) -> Instant {
        loop {
            let (at, _) = self.next();
            if at > t {
                return at;
            }
        }
    }
}

pub fn alive(pid: u64) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .is_ok_and(|s| !s.contains(") Z ") && !s.contains(") X "))
}

/// `kill -9` of CU `cu` (process `pid`), and the change set that repairs it; returns when the
/// kill was sent.
pub fn kill_and_repair(service: &Service, cu: &str, pid: u64) -> Instant {
    let killed_at = Instant::now();
    let status = Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success(), "kill -9 {pid}: {status}");
    crash_change_set(service, cu);
    killed_at
}

pub fn crash_change_set(service: &Service, cu: &str) -> Value {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let all = service.change_sets();
        if let Some(c) = all.iter().find(|c| {
            c["cause"]["kind"] == "cu-crashed"
                && (c["cause"]["cu"] == cu
                    || c["cause"]["also"]
                        .as_array()
                        .is_some_and(|also| also.iter().any(|a| a == cu)))
        }) {
            return c.clone();
        }
        // On a timeout, say what was recorded instead (each change set's id, cause, actions).
        assert!(
            Instant::now() < deadline,
            "timed out waiting for a change set repairing the crash of {cu}; recorded: {}",
            all.iter()
                .map(|c| format!("{} {} {}", c["id"], c["cause"], c["actions"]))
                .collect::<Vec<_>>()
                .join("; ")
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// The direct children of a process.
pub fn children(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    for task in std::fs::read_dir(format!("/proc/{pid}/task"))
        .into_iter()
        .flatten()
    {
        let Ok(task) = task else { continue };
        if let Ok(list) = std::fs::read_to_string(task.path().join("children")) {
            out.extend(
                list.split_whitespace()
                    .filter_map(|p| p.parse::<u32>().ok()),
            );
        }
    }
    out
}

/// A certificate authority and one certificate it signed (server and client use), written as
/// PEM files in a directory (the TLS tests: access.rs, reliability.rs).
pub struct Certificates {
    pub ca: PathBuf,
    pub certificate: PathBuf,
    pub key: PathBuf,
}

/// A certificate authority that signs certificates for peers, each with a common name of its
/// own (what Zenoh's access control tells subjects by).
pub struct Authority {
    dir: PathBuf,
    ca: PathBuf,
    issuer: Issuer<'static, KeyPair>,
}

impl Authority {
    /// A new authority, its certificate written as `ca.pem` in `dir`.
    pub fn new(dir: &Path) -> Self {
        let ca_key = KeyPair::generate().unwrap();
        let mut ca_params = CertificateParams::new(Vec::<String>::new()).unwrap();
        ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        ca_params
            .distinguished_name
            .push(DnType::CommonName, "DyKnow test authority");
        let ca = ca_params.self_signed(&ca_key).unwrap();
        let path = dir.join("ca.pem");
        std::fs::write(&path, ca.pem()).unwrap();
        Self {
            dir: dir.to_owned(),
            ca: path,
            issuer: Issuer::new(ca_params, ca_key),
        }
    }

    /// A certificate with the common name `cn` for these names and addresses (server and
    /// client use), written as `<cn>.pem` and `<cn>-key.pem`.
    pub fn issue(&self, cn: &str, names: &[&str]) -> Certificates {
        let key = KeyPair::generate().unwrap();
        let mut params =
            CertificateParams::new(names.iter().map(|n| (*n).to_owned()).collect::<Vec<_>>())
                .unwrap();
        params.distinguished_name.push(DnType::CommonName, cn);
        params.extended_key_usages = vec![
            ExtendedKeyUsagePurpose::ServerAuth,
            ExtendedKeyUsagePurpose::ClientAuth,
        ];
        let certificate = params.signed_by(&key, &self.issuer).unwrap();
        let write = |name: String, pem: String| {
            let path = self.dir.join(name);
            std::fs::write(&path, pem).unwrap();
            path
        };
        Certificates {
            ca: self.ca.clone(),
            certificate: write(format!("{cn}.pem"), certificate.pem()),
            key: write(format!("{cn}-key.pem"), key.serialize_pem()),
        }
    }
}

impl Certificates {
    pub fn generate(dir: &Path) -> Self {
        Self::generate_for(dir, &["localhost", "127.0.0.1"])
    }

    /// A certificate for these names and addresses.
    pub fn generate_for(dir: &Path, names: &[&str]) -> Self {
        Authority::new(dir).issue("dyknow-test-peer", names)
    }

    /// A Zenoh configuration file: TLS with these certificates, mutual or not.
    pub fn config(&self, dir: &Path, name: &str, mutual: bool) -> PathBuf {
        self.config_with(dir, name, mutual, "")
    }

    /// [`Self::config`] with more of Zenoh's configuration (`extra`: top-level fields, each
    /// followed by a comma), e.g. `access_control`.
    pub fn config_with(&self, dir: &Path, name: &str, mutual: bool, extra: &str) -> PathBuf {
        let text = format!(
            r#"{{ {extra} transport: {{ link: {{ tls: {{
                root_ca_certificate: {ca:?},
                listen_certificate: {cert:?}, listen_private_key: {key:?},
                connect_certificate: {cert:?}, connect_private_key: {key:?},
                enable_mtls: {mutual}, verify_name_on_connect: true }} }} }} }}"#,
            ca = self.ca,
            cert = self.certificate,
            key = self.key,
        );
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    /// A client configuration that trusts the authority but has no certificate of its own.
    pub fn anonymous_config(&self, dir: &Path) -> PathBuf {
        let path = dir.join("anonymous.json5");
        let text = format!(
            "{{ transport: {{ link: {{ tls: {{ root_ca_certificate: {:?} }} }} }} }}",
            self.ca
        );
        std::fs::write(&path, text).unwrap();
        path
    }
}
