//! Process CUs: one child process per CU, speaking the CU protocol over Zenoh
//! (`dyknow_cu::run_process`, `docs/executors.md`). Its exit or `kill -9` is seen at
//! once twice over: the waiter thread returns and its liveliness token vanishes.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError, mpsc};
use std::time::{Duration, Instant};

use dyknow_cu::protocol::{ControlReply, ControlRequest, CuReport, CuState, CuStatistics};
use dyknow_cu::zenoh::Wait;
use dyknow_cu::zenoh::pubsub::Subscriber;
use dyknow_cu::zenoh::sample::SampleKind;
use dyknow_cu::{CuError, Namespace, UnitSpec};

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Finds a program: a path with a '/' as it is, otherwise on `PATH`.
pub fn resolve(program: &str) -> Result<PathBuf, String> {
    let executable = |p: &Path| {
        use std::os::unix::fs::PermissionsExt;
        p.metadata()
            .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
    };
    if program.is_empty() {
        return Err("the command line is empty".into());
    }
    if program.contains('/') {
        let p = PathBuf::from(program);
        return if executable(&p) {
            Ok(p)
        } else {
            Err(format!("{program} is not an executable file"))
        };
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .map(|dir| dir.join(program))
        .find(|p| executable(p))
        .ok_or_else(|| format!("{program} is not on PATH"))
}

/// The CPU time of a process so far: the sum over its threads of
/// `/proc/<pid>/task/*/schedstat` (nanoseconds), falling back to `/proc/<pid>/stat`
/// (10 ms ticks).
pub fn process_cpu(pid: u32) -> Option<Duration> {
    let mut total = 0u64;
    let mut any = false;
    if let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) {
        for task in tasks.flatten() {
            if let Ok(text) = std::fs::read_to_string(task.path().join("schedstat"))
                && let Some(ns) = text
                    .split_whitespace()
                    .next()
                    .and_then(|s| s.parse::<u64>().ok())
            {
                total += ns;
                any = true;
            }
        }
    }
    if any {
        return Some(Duration::from_nanos(total));
    }
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let after = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks = fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?;
    Some(Duration::from_millis(ticks * 10))
}

/// The CPU time of a process and of what it started: [`process_cpu`] of `pid`, the CPU time of
/// its children that exited and were waited for (cutime + cstime of `/proc/<pid>/stat`, 10 ms
/// ticks), and [`process_cpu`] of its live descendants (`/proc/<pid>/task/*/children`, down to
/// `depth` levels). A CU started through a wrapper (a shell that did not `exec`) does its work
/// in a child: measured alone, the wrapper cost nothing, and so did the CU.
pub fn process_tree_cpu(pid: u32, depth: u32) -> Option<Duration> {
    let own = process_cpu(pid)?;
    let waited = std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|stat| {
            let after = stat.rsplit_once(')')?.1.to_owned();
            let fields: Vec<&str> = after.split_whitespace().collect();
            Some(fields.get(13)?.parse::<u64>().ok()? + fields.get(14)?.parse::<u64>().ok()?)
        })
        .map_or(Duration::ZERO, |ticks| Duration::from_millis(ticks * 10));
    let mut children = Duration::ZERO;
    if depth > 0
        && let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task"))
    {
        for task in tasks.flatten() {
            let Ok(list) = std::fs::read_to_string(task.path().join("children")) else {
                continue;
            };
            for child in list
                .split_whitespace()
                .filter_map(|c| c.parse::<u32>().ok())
            {
                children += process_tree_cpu(child, depth - 1).unwrap_or_default();
            }
        }
    }
    Some(own + waited + children)
}

/// The CPU time of a whole process, its exited threads included: utime + stime of
/// `/proc/<pid>/stat`, at 10 ms resolution (USER_HZ 100).
pub fn process_cpu_total(pid: u32) -> Option<Duration> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let after = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks = fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?;
    Some(Duration::from_millis(ticks * 10))
}

/// How an executor starts process CUs.
#[derive(Debug, Clone)]
pub struct Launch {
    /// The executor's name.
    pub executor: String,
    /// The namespace.
    pub namespace: Namespace,
    /// Endpoints the child connects to.
    pub connect: Vec<String>,
    /// How long a child may take to announce itself.
    pub start_timeout: Duration,
    /// Zenoh's own configuration file, handed to the child (`DYKNOW_ZENOH_CONFIG`).
    pub zenoh_config: Option<std::path::PathBuf>,
    /// Zenoh's link lease the child declares (`DYKNOW_ZENOH_LEASE_MS`), if set.
    pub lease_ms: Option<u64>,
}

struct Life {
    state: CuState,
    reason: Option<String>,
    running_since: Option<Instant>,
}

/// A process CU.
pub struct ProcessCu {
    spec: UnitSpec,
    pid: u32,
    namespace: Namespace,
    session: dyknow_cu::zenoh::Session,
    life: Mutex<Life>,
    /// Set before the executor stops or kills it: an exit then is no crash.
    stopping: AtomicBool,
    exited: AtomicBool,
    inputs: Mutex<BTreeMap<String, Option<String>>>,
    outputs: Mutex<BTreeMap<String, Option<String>>>,
    reconfigurations: std::sync::atomic::AtomicU64,
    labour_ns: std::sync::atomic::AtomicU64,
    /// What its last answer to a statistics request said.
    last_statistics: Mutex<CuStatistics>,
    /// The most CPU time measured so far, in nanoseconds ([`ProcessCu::cpu`]).
    cpu_ns: std::sync::atomic::AtomicU64,
    _watch: Mutex<Option<Subscriber<()>>>,
}

/// How long a report waits for a process CU's statistics before it shows the last ones.
const STATISTICS_WAIT: Duration = Duration::from_millis(500);

impl std::fmt::Debug for ProcessCu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProcessCu")
            .field("name", &self.spec.name)
            .field("pid", &self.pid)
            .finish_non_exhaustive()
    }
}

/// Called once when a process CU crashes.
pub type OnCrash = Arc<dyn Fn(&str, &str) + Send + Sync>;

impl ProcessCu {
    /// Starts `command` as CU `spec` and waits until it announces itself (its liveliness
    /// token). Returns it and its labour (the process's CPU time until then).
    pub fn start(
        session: &dyknow_cu::zenoh::Session,
        launch: &Launch,
        spec: UnitSpec,
        command: &[String],
        on_crash: OnCrash,
    ) -> Result<Arc<Self>, CuError> {
        let program =
            resolve(command.first().map_or("", String::as_str)).map_err(CuError::Failed)?;
        let (up_tx, up_rx) = mpsc::channel::<bool>();
        let watch = session
            .liveliness()
            .declare_subscriber(launch.namespace.cu_token(&spec.name))
            .callback(move |sample| {
                let _ = up_tx.send(sample.kind() == SampleKind::Put);
            })
            .wait()?;
        let mut child = Command::new(&program);
        if let Some(file) = &launch.zenoh_config {
            child.env("DYKNOW_ZENOH_CONFIG", file);
        }
        if let Some(lease) = launch.lease_ms {
            child.env("DYKNOW_ZENOH_LEASE_MS", lease.to_string());
        }
        // A process group of its own: stopping it stops what it started too.
        std::os::unix::process::CommandExt::process_group(&mut child, 0);
        let mut child = child
            .args(&command[1..])
            .env("DYKNOW_CU", &spec.name)
            .env("DYKNOW_TRANSFORMATION", &spec.transformation)
            .env("DYKNOW_NAMESPACE", launch.namespace.as_str())
            .env("DYKNOW_CONNECT", launch.connect.join(","))
            .env("DYKNOW_EXECUTOR", &launch.executor)
            .env("DYKNOW_EXECUTOR_PROCESS", executor_identity())
            .env("DYKNOW_INPUTS", spec.inputs.join(","))
            .env("DYKNOW_OUTPUTS", spec.outputs.join(","))
            .env(
                "DYKNOW_PARAMS",
                serde_json::to_string(&spec.params).unwrap_or_default(),
            )
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| CuError::failed(format!("cannot start {}: {e}", program.display())))?;
        let pid = child.id();
        if let Some(stderr) = child.stderr.take() {
            let name = spec.name.clone();
            let _ = std::thread::Builder::new()
                .name(format!("{name}-stderr"))
                .spawn(move || copy_stderr(&name, stderr));
        }
        let cu = Arc::new(Self {
            spec,
            pid,
            namespace: launch.namespace.clone(),
            session: session.clone(),
            life: Mutex::new(Life {
                state: CuState::Starting,
                reason: None,
                running_since: None,
            }),
            stopping: AtomicBool::new(false),
            exited: AtomicBool::new(false),
            inputs: Mutex::default(),
            outputs: Mutex::default(),
            reconfigurations: std::sync::atomic::AtomicU64::new(0),
            labour_ns: std::sync::atomic::AtomicU64::new(0),
            last_statistics: Mutex::default(),
            cpu_ns: std::sync::atomic::AtomicU64::new(0),
            _watch: Mutex::new(None),
        });
        {
            let mut inputs = lock(&cu.inputs);
            for p in &cu.spec.inputs {
                inputs.insert(p.clone(), None);
            }
            let mut outputs = lock(&cu.outputs);
            for p in &cu.spec.outputs {
                outputs.insert(p.clone(), None);
            }
        }
        // The waiter: an exit is a crash unless the executor asked for it.
        let (exit_tx, exit_rx) = mpsc::channel::<String>();
        let waiter = cu.clone();
        let crash = on_crash.clone();
        let _ = std::thread::Builder::new()
            .name(format!("{}-wait", cu.spec.name))
            .spawn(move || {
                let status = wait(&mut child);
                waiter.exited.store(true, Ordering::SeqCst);
                let _ = exit_tx.send(status.clone());
                if !waiter.stopping.load(Ordering::SeqCst) && waiter.crashed(&status) {
                    crash(&waiter.spec.name, &status);
                }
            });
        // Wait for its token (or its exit, or the timeout).
        let deadline = Instant::now() + launch.start_timeout;
        loop {
            if let Ok(status) = exit_rx.try_recv() {
                return Err(CuError::failed(format!("{status} before it ran")));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                cu.kill();
                return Err(CuError::failed(format!(
                    "did not announce itself within {} ms",
                    launch.start_timeout.as_millis()
                )));
            }
            match up_rx.recv_timeout(left.min(Duration::from_millis(20))) {
                Ok(true) => break,
                Ok(false) | Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(CuError::failed("lost its liveliness subscription"));
                }
            }
        }
        // What it and what it started used (a wrapper that did not `exec` starts the CU in a
        // child: measured alone, its labour was the wrapper's, next to nothing).
        let labour = process_tree_cpu(pid, 4).unwrap_or_default();
        // Its token vanishing is a crash too (seen before the waiter when the process is
        // killed, and the only sign when it hangs up from another machine).
        let vanished = cu.clone();
        let crash = on_crash;
        let watch_after = std::thread::Builder::new()
            .name(format!("{}-token", cu.spec.name))
            .spawn(move || {
                while let Ok(up) = up_rx.recv() {
                    if !up && !vanished.stopping.load(Ordering::SeqCst) {
                        if vanished.crashed("its liveliness token vanished") {
                            crash(&vanished.spec.name, "its liveliness token vanished");
                        }
                        return;
                    }
                }
            });
        drop(watch_after);
        *lock(&cu._watch) = Some(watch);
        {
            let mut life = lock(&cu.life);
            if life.state == CuState::Starting {
                life.state = CuState::Running;
                life.running_since = Some(Instant::now());
            }
        }
        cu.labour_ns.store(
            u64::try_from(labour.as_nanos()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
        Ok(cu)
    }

    /// Marks it crashed; false if it already was, or was stopped.
    fn crashed(&self, reason: &str) -> bool {
        let mut life = lock(&self.life);
        if matches!(life.state, CuState::Crashed | CuState::Stopped) {
            return false;
        }
        life.state = CuState::Crashed;
        life.reason = Some(reason.to_owned());
        life.running_since = None;
        true
    }

    /// Its name.
    pub fn name(&self) -> &str {
        &self.spec.name
    }

    /// Its transformation's label.
    pub fn spec_transformation(&self) -> String {
        self.spec.transformation.clone()
    }

    /// Its pid.
    pub fn pid(&self) -> u32 {
        self.pid
    }

    /// Its labour.
    pub fn labour(&self) -> Duration {
        Duration::from_nanos(self.labour_ns.load(Ordering::Relaxed))
    }

    /// Its state.
    pub fn state(&self) -> CuState {
        lock(&self.life).state
    }

    /// Its CPU time so far, with that of the processes it started ([`process_tree_cpu`]),
    /// never less than it said before (a descendant that exits without being waited for takes
    /// its time with it).
    pub fn cpu(&self) -> Duration {
        let now = process_tree_cpu(self.pid, 4).unwrap_or_default();
        let now = u64::try_from(now.as_nanos()).unwrap_or(u64::MAX);
        Duration::from_nanos(self.cpu_ns.fetch_max(now, Ordering::Relaxed).max(now))
    }

    fn control(&self, request: &ControlRequest) -> Result<ControlReply, CuError> {
        self.control_within(request, Duration::from_secs(5))
    }

    fn control_within(
        &self,
        request: &ControlRequest,
        timeout: Duration,
    ) -> Result<ControlReply, CuError> {
        let payload = serde_json::to_vec(request).unwrap_or_default();
        let replies = self
            .session
            .get(self.namespace.cu_control(&self.spec.name))
            .payload(payload)
            .timeout(timeout)
            .wait()?;
        match replies.recv() {
            Ok(reply) => match reply.result() {
                Ok(sample) => serde_json::from_slice(&sample.payload().to_bytes()).map_err(|e| {
                    CuError::failed(format!("a control reply that does not parse: {e}"))
                }),
                Err(e) => Err(CuError::failed(format!(
                    "control error: {}",
                    String::from_utf8_lossy(&e.payload().to_bytes())
                ))),
            },
            Err(_) => Err(CuError::failed(
                "the process did not answer its control request",
            )),
        }
    }

    /// Binds a port (make before break in the process).
    pub fn bind(&self, input: bool, port: &str, channel: Option<&str>) -> Result<(), CuError> {
        let key = channel.map(|c| self.namespace.channel(c)).transpose()?;
        let request = if input {
            ControlRequest::BindIn {
                port: port.to_owned(),
                channel: channel.map(str::to_owned),
                key,
            }
        } else {
            ControlRequest::BindOut {
                port: port.to_owned(),
                channel: channel.map(str::to_owned),
                key,
            }
        };
        let reply = self.control(&request)?;
        if !reply.ok {
            return Err(CuError::failed(
                reply.error.unwrap_or_else(|| "refused".into()),
            ));
        }
        let map = if input { &self.inputs } else { &self.outputs };
        lock(map).insert(port.to_owned(), channel.map(str::to_owned));
        self.reconfigurations.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }

    /// Its report; statistics from the process when it answers within the timeout.
    pub fn report(&self) -> CuReport {
        self.report_asking(true)
    }

    /// Its report with the statistics it gave last, asking the process nothing.
    pub fn report_last(&self) -> CuReport {
        self.report_asking(false)
    }

    fn report_asking(&self, ask: bool) -> CuReport {
        // A process that does not answer within STATISTICS_WAIT (hung, stopped) is shown with
        // the statistics it last gave: the executor's `info` reports every CU it hosts, and
        // one hung process held it up for the control timeout (5 s), so that every CU of the
        // executor was shown as last heard, without statistics.
        let mut statistics = match self.state() {
            CuState::Running if !ask => lock(&self.last_statistics).clone(),
            CuState::Running => {
                let asked = self
                    .control_within(&ControlRequest::Statistics, STATISTICS_WAIT)
                    .ok()
                    .and_then(|r| r.statistics);
                let mut last = lock(&self.last_statistics);
                match asked {
                    Some(s) => {
                        *last = s.clone();
                        s
                    }
                    None => last.clone(),
                }
            }
            _ => CuStatistics::default(),
        };
        let life = lock(&self.life);
        statistics.uptime_ms = life.running_since.map_or(0, |s| {
            u64::try_from(s.elapsed().as_millis()).unwrap_or(u64::MAX)
        });
        let (state, reason) = (life.state, life.reason.clone());
        drop(life);
        statistics.cpu_ms = self.cpu().as_secs_f64() * 1e3;
        statistics.reconfigurations = self.reconfigurations.load(Ordering::Relaxed);
        CuReport {
            cu: self.spec.name.clone(),
            transformation: self.spec.transformation.clone(),
            state,
            inputs: lock(&self.inputs).clone(),
            outputs: lock(&self.outputs).clone(),
            statistics,
            reason,
            pid: Some(self.pid),
            generation: 0,
        }
    }

    /// Stops it: asks it to exit, and kills it if it has not within `grace`.
    pub fn stop(&self, grace: Duration) {
        self.stopping.store(true, Ordering::SeqCst);
        {
            let mut life = lock(&self.life);
            if life.state != CuState::Crashed {
                life.state = CuState::Stopped;
            }
            life.running_since = None;
        }
        if !self.exited.load(Ordering::SeqCst) {
            let _ = self.control_quick(&ControlRequest::Stop, grace);
            let deadline = Instant::now() + grace;
            while !self.exited.load(Ordering::SeqCst) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        self.kill();
        *lock(&self._watch) = None;
    }

    fn control_quick(&self, request: &ControlRequest, timeout: Duration) -> Result<(), CuError> {
        let payload = serde_json::to_vec(request).unwrap_or_default();
        let replies = self
            .session
            .get(self.namespace.cu_control(&self.spec.name))
            .payload(payload)
            .timeout(timeout)
            .wait()?;
        let _ = replies.recv_timeout(timeout);
        Ok(())
    }

    /// `kill -9` of its process group: whatever it started (a wrapper's children, which
    /// outlived it before), also once it has exited (the group outlives its leader while a
    /// member runs); it runs in a process group of its own ([`ProcessCu::start`]). The process
    /// itself only while it has not exited and been reaped (its pid may be another's then).
    /// (The group's id is the leader's pid too: Linux hands out pids in turn, so another
    /// group of that id in the moments after the leader's exit is not to be met in practice.)
    pub fn kill(&self) {
        self.stopping.store(true, Ordering::SeqCst);
        let pid = i32::try_from(self.pid).unwrap_or(i32::MAX);
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(-pid),
            nix::sys::signal::Signal::SIGKILL,
        );
        if !self.exited.load(Ordering::SeqCst) {
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(pid),
                nix::sys::signal::Signal::SIGKILL,
            );
        }
    }
}

fn wait(child: &mut Child) -> String {
    match child.wait() {
        Ok(status) => match (
            status.code(),
            std::os::unix::process::ExitStatusExt::signal(&status),
        ) {
            (Some(code), _) => format!("exited with status {code}"),
            (None, Some(signal)) => format!("killed by signal {signal}"),
            _ => "exited".to_owned(),
        },
        Err(e) => format!("cannot be waited for: {e}"),
    }
}

/// This executor's process ([`dyknow_cu::process_identity`]), read once.
fn executor_identity() -> &'static str {
    static IDENTITY: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    IDENTITY.get_or_init(|| dyknow_cu::process_identity(std::process::id()).unwrap_or_default())
}

/// How many lines of a process CU's standard error the executor logs per second at most (a
/// burst of as many may come at once); the lines past it are counted, and the count is logged
/// once a second later.
pub const STDERR_LINES_PER_SECOND: u32 = 100;

/// How many bytes of one line of a process CU's standard error are logged.
pub const STDERR_LINE_BYTES: usize = 4096;

/// At most [`STDERR_LINES_PER_SECOND`] lines in each second, counting the others.
struct LineBudget {
    window: std::time::Instant,
    logged: u32,
    dropped: u64,
}

impl LineBudget {
    fn new(now: std::time::Instant) -> Self {
        Self {
            window: now,
            logged: 0,
            dropped: 0,
        }
    }

    /// Whether a line coming at `now` is logged, and how many were not in the second that
    /// ended before it (when that second ended with some not logged).
    fn admit(&mut self, now: std::time::Instant) -> (bool, Option<u64>) {
        let mut report = None;
        if now.duration_since(self.window) >= std::time::Duration::from_secs(1) {
            report = (self.dropped > 0).then_some(self.dropped);
            *self = Self::new(now);
        }
        if self.logged >= STDERR_LINES_PER_SECOND {
            self.dropped += 1;
            return (false, report);
        }
        self.logged += 1;
        (true, report)
    }
}

fn report_dropped(name: &str, dropped: u64) {
    tracing::warn!(
        target: "dyknow::cu",
        "{name}: {dropped} lines of standard error not logged (at most \
         {STDERR_LINES_PER_SECOND} a second)"
    );
}

/// Copies a process CU's standard error into the executor's log, line by line, as long as the
/// process writes: at most [`STDERR_LINES_PER_SECOND`] lines a second (a CU writing errors in
/// a loop filled the executor's log at 15 MB a second), each cut at [`STDERR_LINE_BYTES`],
/// bytes that are not UTF-8 replaced. The pipe is always read, so the process never blocks on
/// it (before, a line that was not UTF-8 ended the reading).
fn copy_stderr(name: &str, stderr: impl std::io::Read) {
    use std::io::{BufRead, Read};
    let mut reader = std::io::BufReader::new(stderr);
    let mut line = Vec::new();
    let mut budget = LineBudget::new(std::time::Instant::now());
    loop {
        line.clear();
        match reader
            .by_ref()
            .take(STDERR_LINE_BYTES as u64)
            .read_until(b'\n', &mut line)
        {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        let mut cut = line.last() != Some(&b'\n') && line.len() >= STDERR_LINE_BYTES;
        if cut && matches!(reader.fill_buf(), Ok(next) if next.first() == Some(&b'\n')) {
            // Exactly the limit, then its newline: nothing is cut.
            reader.consume(1);
            cut = false;
        }
        if cut && skip_line(&mut reader).is_err() {
            break;
        }
        let (log, dropped) = budget.admit(std::time::Instant::now());
        if let Some(dropped) = dropped {
            report_dropped(name, dropped);
        }
        if log {
            let text = String::from_utf8_lossy(&line);
            // Control characters (a NUL, a carriage return inside the line, escape sequences)
            // are shown escaped, so that a CU cannot rewrite the log's lines.
            let text: String = text
                .trim_end_matches(['\n', '\r'])
                .chars()
                .flat_map(|c| {
                    // Line and paragraph separators and bidirectional overrides too: they
                    // break or reorder what a log viewer shows.
                    let escaped = (c.is_control() && c != '\t')
                        || matches!(c, '\u{2028}' | '\u{2029}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}');
                    let (plain, code) = if escaped {
                        (None, Some(c.escape_default()))
                    } else {
                        (Some(c), None)
                    };
                    plain.into_iter().chain(code.into_iter().flatten())
                })
                .collect();
            let more = if cut { " [cut]" } else { "" };
            tracing::info!(target: "dyknow::cu", "{name}: {text}{more}");
        }
    }
    if budget.dropped > 0 {
        report_dropped(name, budget.dropped);
    }
}

/// Reads and drops the rest of a line, to its newline or the end of the stream, holding no
/// more of it than the reader's buffer: a CU may write gigabytes without a newline.
fn skip_line(reader: &mut impl std::io::BufRead) -> std::io::Result<()> {
    loop {
        let buf = reader.fill_buf()?;
        if buf.is_empty() {
            return Ok(());
        }
        match buf.iter().position(|b| *b == b'\n') {
            Some(at) => {
                reader.consume(at + 1);
                return Ok(());
            }
            None => {
                let len = buf.len();
                reader.consume(len);
            }
        }
    }
}

#[cfg(test)]
mod stderr_tests {
    use super::*;

    /// A reader that counts what was read from it.
    struct Counted<R>(R, std::sync::Arc<std::sync::atomic::AtomicUsize>);

    impl<R: std::io::Read> std::io::Read for Counted<R> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = self.0.read(buf)?;
            self.1.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
            Ok(n)
        }
    }

    #[test]
    fn standard_error_is_read_to_its_end_whatever_it_holds() {
        // A flood, a line that is not UTF-8 and a very long line: all of it is read (the
        // process never blocks on a full pipe), and the copy ends with the stream.
        let mut input = Vec::new();
        for i in 0..10_000 {
            input.extend_from_slice(format!("error line {i}\n").as_bytes());
        }
        input.extend_from_slice(b"\xff\xfe not UTF-8\n");
        input.extend(std::iter::repeat_n(b'x', 3 * STDERR_LINE_BYTES));
        input.extend_from_slice(b"\nlast\n");
        let read = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        copy_stderr("cu-1", Counted(&input[..], read.clone()));
        assert_eq!(read.load(std::sync::atomic::Ordering::Relaxed), input.len());
    }

    /// The peak resident memory of this process, in KiB (Linux's `VmHWM`).
    fn peak_kib() -> u64 {
        std::fs::read_to_string("/proc/self/status")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find_map(|l| l.strip_prefix("VmHWM:"))
                    .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            })
            .unwrap_or(0)
    }

    /// A line of 256 MiB without a newline is read through, not held: the copy's peak memory
    /// stays well below the line (a user audit saw the service grow by 400 MB and stay there).
    #[test]
    fn a_huge_line_is_skipped_without_holding_it() {
        use std::io::Read;
        let before = peak_kib();
        let line = std::io::repeat(b'a').take(256 << 20);
        let read = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        copy_stderr("cu-1", Counted(line.chain(&b"\nlast\n"[..]), read.clone()));
        assert_eq!(
            read.load(std::sync::atomic::Ordering::Relaxed),
            (256 << 20) + 6
        );
        let grown = peak_kib().saturating_sub(before);
        // Other tests of this binary running beside it add up to ~80 MiB; holding the line would
        // add at least its 256 MiB.
        assert!(grown < 200 << 10, "the peak grew by {grown} KiB");
    }

    #[test]
    fn at_most_the_budget_of_lines_is_logged_each_second() {
        let start = std::time::Instant::now();
        let mut budget = LineBudget::new(start);
        let admitted = (0..250).filter(|_| budget.admit(start).0).count();
        assert_eq!(admitted, STDERR_LINES_PER_SECOND as usize);
        let later = start + std::time::Duration::from_millis(999);
        assert_eq!(budget.admit(later), (false, None), "the same second");
        let next = start + std::time::Duration::from_secs(1);
        assert_eq!(
            budget.admit(next),
            (true, Some(151)),
            "the count, then a new second"
        );
        assert_eq!(
            budget.admit(next + std::time::Duration::from_secs(1)),
            (true, None)
        );
    }
}

#[cfg(test)]
mod cpu_tests {
    use super::*;

    /// A wrapper that does its work in a child (`sh -c 'loop & wait'`, a shell that does not
    /// `exec`) is charged with the child's CPU time: measured alone, the wrapper costs nothing
    /// (a user audit's wrapped CU at 87 % CPU was learned at upkeep 0).
    #[test]
    fn a_wrappers_cpu_time_includes_its_childrens() {
        let mut child = std::process::Command::new("sh")
            .args(["-c", "while :; do :; done & wait"])
            .spawn()
            .expect("sh starts");
        let pid = child.id();
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut tree = Duration::ZERO;
        while tree < Duration::from_millis(200) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
            tree = process_tree_cpu(pid, 4).unwrap_or_default();
        }
        let own = process_cpu(pid).unwrap_or_default();
        // The busy child is the shell's only child: stop it, then the shell.
        let children =
            std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children")).unwrap_or_default();
        for c in children.split_whitespace() {
            let _ = std::process::Command::new("kill").args(["-9", c]).status();
        }
        let _ = child.kill();
        let _ = child.wait();
        assert!(
            tree >= Duration::from_millis(200),
            "the tree's CPU time: {tree:?}"
        );
        assert!(
            own < Duration::from_millis(100),
            "the wrapper's own: {own:?}"
        );
    }
}
