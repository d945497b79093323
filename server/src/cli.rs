//! The `dyknow` command line (contract `cli.md`). Exit status: 0 success, 1 a negative answer
//! where a subcommand says so, 2 bad usage or bad input (one line on stderr naming the file, line
//! and column where there is one).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use std::sync::Arc;

use clap::{Parser, Subcommand};

use crate::dataplane;
use dyknow_store::{IngestError, InputFormat, KnowledgeBase, ModelFormat};

use crate::app::{AppState, ServerConfig, app};

/// DyKnow: a stream reasoning knowledge service.
#[derive(Debug, Parser)]
#[command(name = "dyknow", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Runs the knowledge service (HTTP API, see docs/http-api.md).
    Serve(ServeArgs),
    /// Runs a stand-alone executor hosting CUs for the manager at --connect, until
    /// SIGTERM/SIGINT; then stops its CUs.
    Executor(ExecutorArgs),
    /// Runs one of the executors' builtins as a process CU (`dkros:hasType "process"`,
    /// `dkros:hasSource "dyknow cu dyknow/relay"`); started by an executor, which sets its
    /// environment (docs/executors.md).
    Cu {
        /// The builtin (`dyknow/relay`, `dyknow/map`, ...).
        builtin: String,
    },
    /// Prints the samples of a channel as JSON lines (`{"t", "value"}`).
    Listen {
        /// The channel's name (`/ball/position`, `101`).
        channel: String,
        /// Where the data plane is.
        #[command(flatten)]
        client: ClientArgs,
        /// Stop after this many samples (at least 1).
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
        count: Option<u64>,
        /// Print only each sample's value.
        #[arg(long)]
        values: bool,
    },
    /// Publishes one sample on a channel: `{"t": now, "value": VALUE}` (VALUE is JSON, or
    /// taken as a string).
    Publish {
        /// The channel's name.
        channel: String,
        /// The value.
        value: String,
        /// Where the data plane is.
        #[command(flatten)]
        client: ClientArgs,
    },
    /// Formula groups over the HTTP API of a running service (docs/groups.md):
    /// create, list, show, start, stop, destroy, add, remove, watch, trace.
    Group {
        /// Where the service is.
        #[command(flatten)]
        http: crate::group_cli::HttpArgs,
        /// What to do.
        #[command(subcommand)]
        command: crate::group_cli::GroupCommand,
    },
    /// Loads Turtle specs and ontology extensions into a store offline.
    Load {
        /// The store directory.
        #[arg(long, value_name = "DIR")]
        data: PathBuf,
        /// Files to load (`.ttl`, `.nt`, `.jsonld`), or directories (their files of those
        /// kinds, in name order); each file is loaded atomically.
        #[arg(required = true, value_name = "FILE_OR_DIR")]
        files: Vec<PathBuf>,
    },
    /// Writes the model of a store (GetModel) to standard output.
    Export {
        /// The store directory (opened read-only, so a running server may hold it).
        #[arg(long, value_name = "DIR")]
        data: PathBuf,
        /// turtle, rdfxml, owx, ofn, ntriples, jsonld or dyknow (JSON).
        #[arg(long, value_name = "F", default_value = "turtle")]
        format: String,
        /// Leave out inferred triples.
        #[arg(long)]
        no_inferred: bool,
    },
    /// Materialises the OWL 2 RL inferences for the given data and prints the inferred triples
    /// (not the asserted ones) as sorted N-Triples; with --check prints the ontology violations
    /// instead, one per line, and exits 1 if there is any.
    Reason {
        /// An ontology file (Turtle, N-Triples, JSON-LD) to add to the built-in DyKnow and
        /// DyKnow-ROS ontologies; repeat the flag for several. (One file a flag, so that
        /// `--ontology o.ttl data.ttl` leaves data.ttl a data file.)
        #[arg(long, value_name = "FILE")]
        ontology: Vec<PathBuf>,
        /// Print the violations of the consistency rules instead of the inferences.
        #[arg(long, conflicts_with = "unsupported")]
        check: bool,
        /// Print the axioms of the schema that lie outside OWL 2 RL (no rule applies them), in
        /// the OWL functional syntax, one per line, instead of the inferences; FILEs are
        /// optional then (without any: those of the built-in ontologies).
        #[arg(long)]
        unsupported: bool,
        /// Data files (Turtle, N-Triples, JSON-LD). Their axioms join the schema too.
        #[arg(required_unless_present = "unsupported", value_name = "FILE")]
        files: Vec<PathBuf>,
    },
    /// Loads specs, ontology extensions and (optionally) an existing environment (computation
    /// units, e.g. from a model exported by `GET /model`) and prints the change set EXPLORE
    /// chooses, as change set JSON. Exits 1 if no valid configuration exists (the change set
    /// then satisfies as many targets as possible and lists the others).
    Explore {
        /// The horizon H in time units (seed Def. 34): positive, at most 1e12.
        #[arg(long, value_name = "H", default_value_t = 10.0)]
        horizon: f64,
        /// Stop the search after this many milliseconds and print the best change set found
        /// (the any-time extension; `"optimal": false` unless the search had finished). 0, as
        /// no flag: search until optimality is proven.
        #[arg(long, value_name = "T")]
        timeout_ms: Option<u64>,
        /// A model exported by `GET /model` (or `dyknow export`), to replan a live situation
        /// offline; read like the FILEs (same as giving it as a FILE).
        #[arg(long, value_name = "FILE")]
        environment: Vec<PathBuf>,
        /// Files (Turtle, N-Triples, JSON-LD).
        #[arg(required_unless_present = "environment", value_name = "FILE")]
        files: Vec<PathBuf>,
    },
    /// Progresses MSTL formulas over a state trace (JSON lines, docs/mstl.md) and prints one
    /// verdict line per formula as soon as it is decided, then `unknown` for those the trace
    /// leaves undecided.
    Check {
        /// A formula (repeat for several; verdicts name them by position, from 0). Without
        /// one, the formulas the trace's header lists are replayed (a formula group's trace,
        /// `dyknow group trace`), each over the states the group progressed it over.
        #[arg(long = "formula", value_name = "F")]
        formulas: Vec<String>,
        /// The trace file; `-` reads standard input (verdicts are printed as states arrive).
        #[arg(long, value_name = "FILE")]
        trace: PathBuf,
        /// Landmark regions, added to the trace header's.
        #[arg(long, value_name = "a,b", value_delimiter = ',')]
        landmarks: Vec<String>,
        /// Static regions, added to the trace header's.
        #[arg(long = "static", value_name = "r1,r2", value_delimiter = ',')]
        static_regions: Vec<String>,
        /// A named domain for quantifiers, `NAME=a,b` (repeatable; added to the header's: a
        /// domain of the same name gets these constants too).
        #[arg(long = "domain", value_name = "NAME=a,b")]
        domains: Vec<String>,
    },
    /// The algebraic closure of RCC-8 networks in GQR's CSP format (docs/rcc8.md): for each
    /// instance `consistent` and the refined network, or `inconsistent`. Exits 1 if any
    /// instance is inconsistent.
    Rcc8 {
        /// Decide consistency exactly (backtracking over the tractable subclass B̂8 with path
        /// consistency, as GQR does), not only by path consistency.
        #[arg(long)]
        exact: bool,
        /// With --exact: how long the search may take for one instance, in seconds. An
        /// instance it has not decided by then is answered `unknown`, followed by its algebraic
        /// closure (it is path consistent); the exit status counts only `inconsistent` ones.
        #[arg(long, value_name = "SECONDS", requires = "exact", value_parser = seconds)]
        timeout: Option<std::time::Duration>,
        /// The network file (several instances, each ended by `.`); `-` reads standard input.
        #[arg(value_name = "FILE")]
        file: PathBuf,
    },
}

/// Options of `dyknow serve`.
#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// The store directory (created if missing).
    #[arg(
        long,
        value_name = "DIR",
        default_value = "./dyknow-data",
        conflicts_with = "in_memory"
    )]
    pub data: PathBuf,
    /// Keep the store in memory only (tests, demos).
    #[arg(long)]
    pub in_memory: bool,
    /// The address to listen on. A non-loopback address requires a token.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7878")]
    pub bind: SocketAddr,
    /// Bearer token required by mutating requests (not empty: an empty one is refused).
    #[arg(long, value_name = "T", env = "DYKNOW_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// The review horizon H in time units (seed Def. 34), used by the reconfiguration engine:
    /// positive, at most 1e12, and H × --time-unit at most 1e12 seconds.
    #[arg(long, value_name = "H", default_value_t = 10.0)]
    pub horizon: f64,
    /// The length of one time unit in seconds; the stable interval lasts H time units.
    #[arg(long, value_name = "SECONDS", default_value_t = 1.0)]
    pub time_unit: f64,
    /// How long a review's search may run, in milliseconds, before it settles for the best
    /// change set found (the any-time extension; `"optimal": false` then); 0 searches until
    /// optimality is proven. Spawn, Destroy and crash reports wait for a running review.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    pub explore_timeout_ms: u64,
    /// Further threads a review's search runs beside its own while it has time left (more
    /// any-time search in the same timeout; docs/engine.md, "Any-time probes"). 0: one thread
    /// per review. At most 64.
    #[arg(long, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u8).range(0..=64))]
    pub explore_threads: u8,
    /// Crashes the executors detect start a review at once, but not sooner than this many
    /// milliseconds after the last review started: a crash storm is repaired by one review per
    /// interval, not one per crash (docs/reliability.md). 0: a review per crash. At most 10 s.
    #[arg(long, value_name = "MS", default_value_t = 100)]
    pub review_spacing_ms: u64,
    /// How many change sets the history keeps: recording one more prunes the oldest from the
    /// store and from memory (the names they used stay reserved), so memory and start-up time
    /// do not grow with the service's age. 0 keeps every change set.
    #[arg(long, value_name = "N", default_value_t = dyknow_lifecycle::DEFAULT_HISTORY_LIMIT)]
    pub history_limit: usize,
    /// Turtle specs and ontology extensions (files or directories) to load at start-up.
    #[arg(long, value_name = "FILE_OR_DIR", num_args = 1..)]
    pub specs: Vec<PathBuf>,
    /// How long a SPARQL query may run, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 30.0)]
    pub query_timeout: f64,
    /// How much memory a SPARQL query may hold (the solutions it joins, sorts or groups, and
    /// its answer), in MiB; past it the query is cancelled (503). 0: no limit.
    #[arg(long, value_name = "MIB", default_value_t = crate::app::DEFAULT_QUERY_MEMORY_MIB)]
    pub query_memory: usize,
    /// How many requests do work on the store at once (SPARQL queries, spec, model and
    /// environment reads and writes); more wait their turn, first come first served. Default:
    /// twice the cores. 0: no limit (every request at work holds a thread; on a small machine
    /// under many clients every answer, and the reviews, then wait for the scheduler).
    #[arg(long, value_name = "N", env = "DYKNOW_STORE_CONCURRENCY")]
    pub store_concurrency: Option<usize>,
    /// The largest accepted request body, in bytes.
    #[arg(long, value_name = "BYTES", default_value_t = 16 * 1024 * 1024)]
    pub max_body: usize,
    /// The Zenoh endpoints the service's router listens on (executors and process CUs connect
    /// here); repeat it or separate endpoints with commas to listen on several. Default: the
    /// `--zenoh-config` file's `listen/endpoints`, else tcp/127.0.0.1:7447. An endpoint other
    /// machines can reach needs access control or mutual TLS (docs/reliability.md).
    #[arg(
        long,
        value_name = "ENDPOINT",
        env = "DYKNOW_ZENOH",
        value_delimiter = ','
    )]
    pub zenoh_listen: Vec<String>,
    /// Zenoh's own configuration file (JSON5; TLS and mutual TLS certificates, access control);
    /// the flags override what it says about endpoints and the lease. Process CUs read it too.
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
    /// The key namespace of channels and control keys.
    #[arg(long, value_name = "NS", default_value = "dyknow")]
    pub namespace: String,
    /// Run no embedded executor: only stand-alone `dyknow executor`s run CUs.
    #[arg(long, conflicts_with = "model_only")]
    pub no_executor: bool,
    /// Run no executor and no data plane: plan with every transformation and apply change sets
    /// to the model only.
    #[arg(long)]
    pub model_only: bool,
    /// At start-up, how long to wait for executors to come back before CUs of the model that
    /// run nowhere are respawned (the start-up reconciliation; docs/reliability.md). Ends
    /// earlier once every CU of the model is accounted for.
    #[arg(long, value_name = "SECONDS", default_value_t = 5.0)]
    pub reconcile_grace: f64,
    /// How long an executor that went away stays in `GET /executors` (listed absent) before
    /// the manager forgets it; it is listed again if it comes back.
    #[arg(long, value_name = "SECONDS", default_value_t = 600.0)]
    pub forget_executors_after: f64,
    /// Zenoh's link lease in milliseconds: a peer silent this long (a cut link, a hung
    /// process) is declared gone, and so are its executor's CUs (docs/reliability.md).
    /// Default: the `--zenoh-config` file's, else 10000.
    #[arg(long, value_name = "MS")]
    pub zenoh_lease_ms: Option<u64>,
}

/// How `dyknow listen` and `dyknow publish` reach the data plane.
#[derive(Debug, clap::Args)]
pub struct ClientArgs {
    /// The service's Zenoh endpoint.
    #[arg(
        long,
        value_name = "ENDPOINT",
        env = "DYKNOW_ZENOH",
        default_value = "tcp/127.0.0.1:7447"
    )]
    pub connect: String,
    /// The key namespace.
    #[arg(long, value_name = "NS", default_value = "dyknow")]
    pub namespace: String,
    /// Zenoh's own configuration file (TLS certificates for a tls/ endpoint).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

impl ClientArgs {
    /// A client session and the key of `channel`.
    fn open(&self, channel: &str) -> Result<(dyknow_cu::zenoh::Session, String), Failure> {
        let namespace = dyknow_cu::Namespace::new(self.namespace.clone())
            .map_err(|e| Failure(2, format!("--namespace: {e}")))?;
        let key = namespace
            .channel(channel)
            .map_err(|e| Failure(2, e.to_string()))?;
        let session = dataplane::open(
            dataplane::client_config(
                self.zenoh_config.as_deref(),
                std::slice::from_ref(&self.connect),
            )
            .map_err(|e| Failure(2, e))?,
        )
        .map_err(|e| {
            Failure(
                2,
                format!("{e} (is `dyknow serve` running at {}?)", self.connect),
            )
        })?;
        Ok((session, key))
    }
}

/// Options of `dyknow executor`.
#[derive(Debug, clap::Args)]
pub struct ExecutorArgs {
    /// The executor's name (one key chunk: no '/', '*', '$', '?', '#').
    #[arg(long, value_name = "NAME")]
    pub name: String,
    /// The manager's Zenoh endpoint (e.g. tcp/127.0.0.1:7447); several may follow, or be
    /// separated by commas, as for `serve --zenoh-listen`.
    #[arg(
        long,
        value_name = "ENDPOINT",
        required = true,
        num_args = 1..,
        value_delimiter = ','
    )]
    pub connect: Vec<String>,
    /// An endpoint to listen on (its process CUs then connect here).
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Option<String>,
    /// The key namespace.
    #[arg(long, value_name = "NS", default_value = "dyknow")]
    pub namespace: String,
    /// Zenoh's link lease in milliseconds (see `dyknow serve --zenoh-lease-ms`).
    #[arg(long, value_name = "MS")]
    pub zenoh_lease_ms: Option<u64>,
    /// Zenoh's own configuration file (see `dyknow serve --zenoh-config`); its process CUs
    /// read it too.
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

/// A failure of a subcommand: the exit status and the one-line message. Status 0 with no
/// message is [`Failure::CLOSED_OUTPUT`].
struct Failure(u8, String);

impl Failure {
    /// Standard output is a closed pipe (`dyknow rcc8 f | head -1`): the reader has what it
    /// wanted, so the subcommand stops quietly, exit 0, as a tool killed by SIGPIPE would
    /// (without SIGPIPE's status, and without touching the signal, which `serve` ignores).
    const CLOSED_OUTPUT: Self = Self(0, String::new());

    /// A failure to write standard output: [`Failure::CLOSED_OUTPUT`] for a closed pipe, else
    /// exit 2.
    fn output(e: &std::io::Error) -> Self {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            Self::CLOSED_OUTPUT
        } else {
            Self(2, format!("writing the output: {e}"))
        }
    }
}

/// Writes `text` to standard output: a closed pipe stops quietly ([`Failure::output`]), not
/// with a panic as `print!` does.
fn write_stdout(text: &str) -> Result<(), Failure> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .map_err(|e| Failure::output(&e))
}

/// Writes a line to standard error, which may be a closed pipe too (`2>&1 | head`): then the
/// line is lost, never a panic as `eprintln!` makes it.
fn warn(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

impl<E: std::fmt::Display> From<E> for Failure {
    fn from(e: E) -> Self {
        Self(2, e.to_string())
    }
}

/// Runs the command line.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    if matches!(cli.command, Command::Serve(_) | Command::Executor(_)) {
        // The long-running processes: glibc's allocator tuned (docs/reliability.md, guarantee 5).
        crate::allocator::tune();
    }
    let result = match cli.command {
        Command::Serve(args) => serve(args),
        Command::Executor(args) => executor(&args),
        Command::Cu { builtin } => return cu(&builtin),
        Command::Group { http, command } => crate::group_cli::run(&http, command)
            .map_err(|crate::group_cli::Failure(code, msg)| Failure(code, msg)),
        Command::Listen {
            channel,
            client,
            count,
            values,
        } => listen(&channel, &client, count, values),
        Command::Publish {
            channel,
            value,
            client,
        } => publish(&channel, &value, &client),
        Command::Load { data, files } => load(&data, &files),
        Command::Export {
            data,
            format,
            no_inferred,
        } => export(&data, &format, !no_inferred),
        Command::Reason {
            ontology,
            check,
            unsupported,
            files,
        } => {
            if unsupported {
                reason_unsupported(&ontology, &files)
            } else {
                reason(&ontology, &files, check)
            }
        }
        Command::Explore {
            horizon,
            timeout_ms,
            environment,
            mut files,
        } => {
            files.extend(environment);
            explore(horizon, timeout_ms, &files)
        }
        Command::Check {
            formulas,
            trace,
            landmarks,
            static_regions,
            domains,
        } => check(&formulas, &trace, landmarks, static_regions, &domains),
        Command::Rcc8 {
            exact,
            timeout,
            file,
        } => rcc8(&file, exact, timeout),
    };
    match result {
        // Standard output was closed by its reader ([`Failure::CLOSED_OUTPUT`]).
        Ok(()) | Err(Failure(0, _)) => ExitCode::SUCCESS,
        Err(Failure(code, message)) => {
            warn(&format!("dyknow: {message}"));
            ExitCode::from(code)
        }
    }
}

fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // Colours only on a terminal: a pipe or a log file gets plain text.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        // A closed standard error loses the log lines; the default reports that with
        // `eprintln!`, which panics on the same closed stream.
        .log_internal_errors(false)
        .try_init();
}

/// Expands directories into their RDF files (sorted), keeping files as given.
fn rdf_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>, Failure> {
    let mut out = Vec::new();
    for path in paths {
        if path.is_dir() {
            let mut entries: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|e| Failure(2, format!("{}: {e}", path.display())))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| InputFormat::from_path(p).is_some())
                .collect();
            entries.sort();
            out.extend(entries);
        } else {
            out.push(path.clone());
        }
    }
    Ok(out)
}

/// Loads one file; errors name the file, and the line and column of syntax errors.
fn load_file(kb: &KnowledgeBase, path: &Path) -> Result<String, Failure> {
    let (format, body) = read_input(path)?;
    match kb.load_document(&body, format) {
        Ok(report) => Ok(format!(
            "{}: {} transformation(s), {} target(s){}",
            path.display(),
            report.transformations.labels.len(),
            report.targets.labels.len(),
            report
                .extension
                .map(|g| format!(", ontology extension <{g}>"))
                .unwrap_or_default()
        )),
        Err(IngestError::Parse(e)) => Err(syntax_failure(path, &e)),
        Err(IngestError::Invalid(v)) => Err(Failure(
            2,
            format!(
                "{}: {}",
                path.display(),
                v.0.iter()
                    .map(|x| format!("{} ({})", x.constraint, x.subject))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        )),
        Err(e) => Err(Failure(2, format!("{}: {e}", path.display()))),
    }
}

#[cfg(feature = "rocksdb")]
fn open_store(data: &Path) -> Result<KnowledgeBase, Failure> {
    KnowledgeBase::open(data).map_err(|e| {
        let e = e.to_string();
        // RocksDB's lock: one process at a time opens a store for writing.
        let hint = if e.contains("lock file") {
            " (another process has this store open: is a `dyknow serve` running on it? \
             `dyknow export` reads a store a server holds)"
        } else {
            ""
        };
        Failure(2, format!("{}: {e}{hint}", data.display()))
    })
}

#[cfg(not(feature = "rocksdb"))]
fn open_store(data: &Path) -> Result<KnowledgeBase, Failure> {
    Err(Failure(
        2,
        format!(
            "{}: this build has no on-disk store (feature rocksdb); use --in-memory",
            data.display()
        ),
    ))
}

/// Reads an RDF file, its format told by its extension.
fn read_input(path: &Path) -> Result<(InputFormat, Vec<u8>), Failure> {
    let format = InputFormat::from_path(path).ok_or_else(|| {
        Failure(
            2,
            format!(
                "{}: unknown file type (use .ttl or .turtle, .nt, .jsonld or .json)",
                path.display()
            ),
        )
    })?;
    let body = std::fs::read(path).map_err(|e| Failure(2, format!("{}: {e}", path.display())))?;
    Ok((format, body))
}

/// A syntax error as `file:line:column: message`.
fn syntax_failure(path: &Path, e: &dyknow_store::SpecParseError) -> Failure {
    Failure(
        2,
        format!(
            "{}:{}:{}: {}",
            path.display(),
            e.0.line,
            e.0.column,
            e.0.message
        ),
    )
}

/// Reads an RDF file into triples; errors name the file, line and column.
fn read_triples(path: &Path) -> Result<Vec<dyknow_store::oxigraph::model::Triple>, Failure> {
    let (format, body) = read_input(path)?;
    dyknow_store::parse_triples(&body, format).map_err(|e| syntax_failure(path, &e))
}

/// `dyknow reason --unsupported`: the axioms of the schema (built-in ontologies, `--ontology`
/// files and the files' axioms) that no OWL 2 RL rule applies.
fn reason_unsupported(ontology: &[PathBuf], files: &[PathBuf]) -> Result<(), Failure> {
    use std::io::Write;
    let mut schema = dyknow_reasoner::builtin_ontology_triples();
    for path in ontology.iter().chain(files) {
        schema.extend(read_triples(path)?);
    }
    let tbox = dyknow_reasoner::TBox::from_triples(&schema)?;
    let mut out = std::io::stdout().lock();
    for axiom in tbox.unsupported_axioms() {
        writeln!(out, "{axiom}").map_err(|e| Failure::output(&e))?;
    }
    out.flush().map_err(|e| Failure::output(&e))?;
    Ok(())
}

/// `dyknow reason`: the schema is the built-in ontologies, the `--ontology` files and the
/// axioms of the data files; the data is every triple of the given files.
fn reason(ontology: &[PathBuf], files: &[PathBuf], check: bool) -> Result<(), Failure> {
    use std::io::Write;
    let mut data = Vec::new();
    for path in ontology.iter().chain(files) {
        data.extend(read_triples(path)?);
    }
    let data = stable_blank_nodes(data);
    let builtin = dyknow_reasoner::builtin_ontology_triples();
    // What the built-in ontologies entail on their own holds for any input: it is not an
    // inference for the given data, and their axioms outside OWL 2 RL are known
    // (`--unsupported` lists them). Only the files' own are reported.
    let mut alone = dyknow_reasoner::Reasoner::new(dyknow_reasoner::TBox::from_triples(&builtin)?);
    alone.update(&[], &[]);
    let given_anyway: std::collections::BTreeSet<String> =
        alone.inferred().iter().map(ToString::to_string).collect();
    let builtin_unsupported: std::collections::BTreeSet<&String> =
        alone.tbox().unsupported_axioms().iter().collect();
    let mut schema = builtin.clone();
    schema.extend(data.iter().cloned());
    let tbox = dyknow_reasoner::TBox::from_triples(&schema)?;
    for axiom in tbox.unsupported_axioms() {
        if !builtin_unsupported.contains(axiom) {
            warn(&format!("dyknow: unsupported axiom (ignored): {axiom}"));
        }
    }
    let mut reasoner = dyknow_reasoner::Reasoner::new(tbox);
    reasoner.update(&[], &data);
    let mut out = std::io::stdout().lock();
    if check {
        let violations = reasoner.violations();
        for v in &violations {
            writeln!(out, "{v}").map_err(|e| Failure::output(&e))?;
        }
        out.flush().map_err(|e| Failure::output(&e))?;
        return if violations.is_empty() {
            Ok(())
        } else {
            Err(Failure(
                1,
                format!("{} ontology violation(s)", violations.len()),
            ))
        };
    }
    let mut lines: Vec<String> = reasoner
        .inferred()
        .iter()
        .map(ToString::to_string)
        .filter(|t| !given_anyway.contains(t))
        .map(|t| format!("{t} ."))
        .collect();
    lines.sort();
    for line in lines {
        writeln!(out, "{line}").map_err(|e| Failure::output(&e))?;
    }
    out.flush().map_err(|e| Failure::output(&e))?;
    Ok(())
}

/// The triples with their blank nodes named `b0`, `b1`, … in the order they first occur: the
/// parser names them at random, so the same input would print differently on every run.
fn stable_blank_nodes(
    triples: Vec<dyknow_store::oxigraph::model::Triple>,
) -> Vec<dyknow_store::oxigraph::model::Triple> {
    use dyknow_store::oxigraph::model::{BlankNode, NamedOrBlankNode, Term};
    let mut names: std::collections::HashMap<BlankNode, BlankNode> = Default::default();
    let mut rename = |b: BlankNode| {
        let next = names.len();
        names
            .entry(b)
            .or_insert_with(|| BlankNode::new_unchecked(format!("b{next}")))
            .clone()
    };
    triples
        .into_iter()
        .map(|mut t| {
            if let NamedOrBlankNode::BlankNode(b) = t.subject {
                t.subject = rename(b).into();
            }
            if let Term::BlankNode(b) = t.object {
                t.object = rename(b).into();
            }
            t
        })
        .collect()
}

/// The largest horizon `serve` and `explore` take, in time units; `serve` takes a stable
/// interval (H × time unit) of at most this many seconds too. Costs are at most
/// [`dyknow_engine::MAX_COST`] each, so a change set's total (labour plus H × upkeep) stays
/// far below `f64::MAX` (with H = 6e307 it was infinite, written `null`).
const MAX_HORIZON: f64 = 1e12;

/// `--horizon` of `serve` and `explore`: positive (H = 0 would make the stable interval 0,
/// reviews back to back, and the upkeep worthless) and at most [`MAX_HORIZON`].
fn check_horizon(horizon: f64) -> Result<(), Failure> {
    if horizon.is_finite() && horizon > MAX_HORIZON {
        return Err(Failure(
            2,
            format!(
                "--horizon {horizon:e} is too large: at most {MAX_HORIZON:e} time units (costs \
                 multiplied by it must stay representable)"
            ),
        ));
    }
    if !(horizon.is_finite() && horizon > 0.0) {
        return Err(Failure(
            2,
            format!(
                "--horizon must be a positive number of time units, at most {MAX_HORIZON:e} \
                 (the stable interval between scheduled reviews lasts H time units), not {horizon}"
            ),
        ));
    }
    Ok(())
}

/// `dyknow explore`: everything but computation units goes into an in-memory knowledge base
/// like `dyknow load` would put it; CUs (and their subscriptions, publications and cost
/// models) become the environment; then one review.
fn explore(horizon: f64, timeout_ms: Option<u64>, files: &[PathBuf]) -> Result<(), Failure> {
    use dyknow_engine::{Cause, ChangeSet, ChangeSetId, ExploreOptions, Ids};
    use dyknow_store::{EnvironmentPart, model};
    check_horizon(horizon)?;
    let kb = KnowledgeBase::in_memory()?;
    let mut environment = Vec::new();
    for path in files {
        let triples = read_triples(path)?;
        let (cus, rest) = model::split_environment(triples);
        environment.extend(cus);
        if rest.is_empty() {
            continue;
        }
        let body: String = rest.iter().map(|t| format!("{t} .\n")).collect();
        kb.load_document(body.as_bytes(), InputFormat::NTriples)
            .map_err(|e| Failure(2, format!("{}: {e}", path.display())))?;
    }
    if !environment.is_empty() {
        kb.set_environment(&[(EnvironmentPart::Imported, environment)])?;
    }
    let loaded = model::load(&kb)?;
    let options = ExploreOptions {
        horizon,
        // 0 is no limit, as `serve --explore-timeout-ms 0` is.
        timeout: timeout_ms.filter(|ms| *ms > 0).map(Duration::from_millis),
        ..ExploreOptions::default()
    };
    let reviewed = dyknow_engine::review(
        &loaded.env,
        &loaded.candidates,
        &options,
        &mut Ids::after(&loaded.env),
    );
    let delta = model::delta(&loaded.env, &reviewed.after, &loaded.iris);
    let change_set = ChangeSet::new(
        ChangeSetId::numbered(1),
        Cause::Explore,
        reviewed.compiled,
        delta.ntriples(),
    );
    write_stdout(&format!("{}\n", serde_json::to_string_pretty(&change_set)?))?;
    if change_set.unsatisfied_targets.is_empty() {
        Ok(())
    } else {
        Err(Failure(
            1,
            format!(
                "no valid configuration: unsatisfied targets {}",
                change_set
                    .unsatisfied_targets
                    .iter()
                    .map(|q| q.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ))
    }
}

/// `dyknow check`: parse every formula first (a bad one is a usage error naming its column),
/// then stream the trace through a monitor.
fn check(
    formulas: &[String],
    trace: &Path,
    landmarks: Vec<String>,
    static_regions: Vec<String>,
    domains: &[String],
) -> Result<(), Failure> {
    use dyknow_mstl::trace::{CheckError, Header, check, parse_domain, quoted};
    let parsed = formulas
        .iter()
        .enumerate()
        .map(|(i, f)| {
            dyknow_mstl::parse(f)
                .map_err(|e| Failure(2, format!("--formula {i} {}: {e}", quoted(f))))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut extra = Header {
        landmarks: landmarks.into_iter().collect(),
        static_regions: static_regions.into_iter().collect(),
        ..Header::default()
    };
    for d in domains {
        let (name, constants) = parse_domain(d).map_err(|e| Failure(2, e))?;
        extra.extend(Header {
            domains: [(name, constants)].into(),
            ..Header::default()
        });
    }
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let name = trace.display().to_string();
    let result = if name == "-" {
        check(&parsed, std::io::stdin().lock(), extra, &mut out)
    } else {
        let file = std::fs::File::open(trace).map_err(|e| Failure(2, format!("{name}: {e}")))?;
        check(&parsed, std::io::BufReader::new(file), extra, &mut out)
    };
    match result {
        Ok(_) => Ok(()),
        Err(CheckError::Compile { formula, source }) => Err(Failure(
            2,
            match formulas.get(formula) {
                Some(text) => format!("--formula {formula} {}: {source}", quoted(text)),
                None => format!("{name}: formula {formula} of the header: {source}"),
            },
        )),
        Err(CheckError::Output(e)) => Err(Failure::output(&e)),
        Err(e) => Err(Failure(2, format!("{name}: {e}"))),
    }
}

/// A positive number of seconds, at most what a `Duration` holds (`u64::MAX` seconds).
fn seconds(text: &str) -> Result<std::time::Duration, String> {
    let value: f64 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a number of seconds"))?;
    if value > 0.0 && std::time::Duration::try_from_secs_f64(value).is_err() {
        return Err(format!(
            "'{text}': too large; a time limit is at most {} seconds",
            u64::MAX
        ));
    }
    std::time::Duration::try_from_secs_f64(value)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| format!("'{text}': a time limit is a positive number of seconds"))
}

/// `dyknow rcc8`: every instance closed (and, with `--exact`, solved); answers in input order,
/// each written as soon as it is decided.
fn rcc8(file: &Path, exact: bool, timeout: Option<std::time::Duration>) -> Result<(), Failure> {
    use std::io::Read;
    let name = file.display().to_string();
    let mut bytes = Vec::new();
    let read = if name == "-" {
        std::io::stdin().read_to_end(&mut bytes)
    } else {
        std::fs::File::open(file).and_then(|mut f| f.read_to_end(&mut bytes))
    };
    read.map_err(|e| Failure(2, format!("{name}: {e}")))?;
    let text = String::from_utf8(bytes).map_err(|e| {
        let valid = &e.as_bytes()[..e.utf8_error().valid_up_to()];
        let valid = std::str::from_utf8(valid).unwrap_or_default();
        let line = valid.matches('\n').count() + 1;
        let column = valid
            .rsplit('\n')
            .next()
            .unwrap_or_default()
            .chars()
            .count()
            + 1;
        Failure(
            2,
            format!("{name}: line {line}, column {column}: not UTF-8"),
        )
    })?;
    // A byte order mark (editors on Windows write one) is no part of the network.
    let networks = dyknow_rcc8::gqr::parse(text.strip_prefix('\u{feff}').unwrap_or(&text))
        .map_err(|e| Failure(2, format!("{name}: {e}")))?;
    // Nothing to answer is no answer: an empty file (or comments only) printed nothing and
    // exited 0, as if every instance were consistent.
    if networks.is_empty() {
        return Err(Failure(
            2,
            format!(
                "{name}: no RCC-8 instance (GQR's format: the largest region index, then \
                 constraints `i j ( R ... )`, then `.`; docs/rcc8.md)"
            ),
        ));
    }
    let (mut inconsistent, mut unknown) = (0, 0);
    for mut network in networks {
        let mut out = String::new();
        // With --exact the search closes the network first and leaves it closed (one closure,
        // not two); a deadline past what an Instant holds is none.
        let answer = if exact {
            network.consistent_until(timeout.and_then(|t| std::time::Instant::now().checked_add(t)))
        } else {
            Some(network.algebraic_closure().is_ok())
        };
        match answer {
            Some(true) | None => {
                out.push_str(if answer.is_some() {
                    "consistent\n"
                } else {
                    unknown += 1;
                    "unknown\n"
                });
                dyknow_rcc8::gqr::write(&network, &mut out)?;
            }
            Some(false) => {
                out.push_str("inconsistent\n");
                inconsistent += 1;
            }
        }
        write_stdout(&out)?;
    }
    if unknown > 0 {
        warn(&format!(
            "dyknow: {unknown} instance(s) undecided within the time limit"
        ));
    }
    if inconsistent > 0 {
        return Err(Failure(
            1,
            format!("{inconsistent} inconsistent instance(s)"),
        ));
    }
    Ok(())
}

fn load(data: &Path, files: &[PathBuf]) -> Result<(), Failure> {
    // A file that is not there, or of no known type, is refused before a store is created.
    let files = rdf_files(files)?;
    for file in &files {
        std::fs::File::open(file).map_err(|e| Failure(2, format!("{}: {e}", file.display())))?;
        if InputFormat::from_path(file).is_none() {
            return Err(Failure(
                2,
                format!(
                    "{}: unknown file type (use .ttl or .turtle, .nt, .jsonld or .json)",
                    file.display()
                ),
            ));
        }
    }
    let kb = open_store(data)?;
    for file in files {
        let line = load_file(&kb, &file)?;
        // The lines only report: a reader that closed the pipe (`| head -1`) does not stop
        // the load halfway.
        match write_stdout(&format!("{line}\n")) {
            Err(Failure(0, _)) | Ok(()) => {}
            Err(e) => return Err(e),
        }
    }
    kb.flush()?;
    Ok(())
}

fn export(data: &Path, format: &str, inferred: bool) -> Result<(), Failure> {
    if !data.join("CURRENT").exists() {
        return Err(Failure(
            2,
            format!("{}: no DyKnow store here", data.display()),
        ));
    }
    #[cfg(feature = "rocksdb")]
    let kb = KnowledgeBase::open_read_only(data)
        .map_err(|e| Failure(2, format!("{}: {e}", data.display())))?;
    #[cfg(not(feature = "rocksdb"))]
    let kb = open_store(data)?;
    use std::io::Write;
    let body = if format == "dyknow" || format == "json" {
        let json = crate::routes::model::model_json(&kb, &|_| Ok(()), &|_| Default::default())
            .map_err(|e| Failure(2, e.message))?;
        serde_json::to_vec_pretty(&json)?
    } else {
        let format = ModelFormat::from_name(format).ok_or_else(|| {
            Failure(
                2,
                format!("unknown format {format:?}; use turtle, rdfxml, owx, ofn, ntriples, jsonld or dyknow"),
            )
        })?;
        kb.export(format, inferred)?.body
    };
    let mut out = std::io::stdout().lock();
    out.write_all(&body)
        .and_then(|()| out.flush())
        .map_err(|e| Failure::output(&e))
}

fn serve(args: ServeArgs) -> Result<(), Failure> {
    init_logging();
    // An empty token (`DYKNOW_TOKEN=$UNSET`) would lock every mutating request for good.
    if args.token.as_deref().is_some_and(|t| t.trim().is_empty()) {
        return Err(Failure(
            2,
            "the token (--token or DYKNOW_TOKEN) is empty, which no request could give: give a \
             token, or unset DYKNOW_TOKEN to run without one (loopback --bind only)"
                .into(),
        ));
    }
    if !args.bind.ip().is_loopback() && args.token.is_none() {
        return Err(Failure(
            2,
            format!(
                "refusing to listen on the non-loopback address {} without a token (--token or DYKNOW_TOKEN)",
                args.bind
            ),
        ));
    }
    let zenoh_file = args
        .zenoh_config
        .as_deref()
        .map(dataplane::ZenohFile::read)
        .transpose()
        .map_err(|e| Failure(2, e))?;
    let listen = if !args.zenoh_listen.is_empty() {
        args.zenoh_listen.clone()
    } else if let Some(listen) = zenoh_file.as_ref().and_then(dataplane::ZenohFile::listen) {
        listen.to_vec()
    } else {
        vec![dataplane::DEFAULT_LISTEN.to_owned()]
    };
    if !args.model_only {
        dataplane::check_access(&listen, zenoh_file.as_ref()).map_err(|e| Failure(2, e))?;
    }
    if args.review_spacing_ms > 10_000 {
        return Err(Failure(
            2,
            "--review-spacing-ms must be at most 10 s (10000)".into(),
        ));
    }
    check_horizon(args.horizon)?;
    if !(args.time_unit.is_finite() && args.time_unit > 0.0 && args.time_unit < 1e9) {
        return Err(Failure(
            2,
            "--time-unit must be a positive number of seconds".into(),
        ));
    }
    // The stable interval is a `Duration` and a time to come: past what they hold the
    // service would panic.
    if args.horizon * args.time_unit > MAX_HORIZON {
        return Err(Failure(
            2,
            format!(
                "--horizon {:e} × --time-unit {}: the stable interval between scheduled reviews \
                 must be at most {MAX_HORIZON:e} seconds",
                args.horizon, args.time_unit
            ),
        ));
    }
    if !(args.reconcile_grace.is_finite() && (0.0..1e6).contains(&args.reconcile_grace)) {
        return Err(Failure(
            2,
            "--reconcile-grace must be a non-negative number of seconds".into(),
        ));
    }
    if !(args.forget_executors_after.is_finite()
        && (0.0..1e9).contains(&args.forget_executors_after))
    {
        return Err(Failure(
            2,
            "--forget-executors-after must be a non-negative number of seconds below 1e9".into(),
        ));
    }
    if !(args.query_timeout.is_finite() && args.query_timeout > 0.0) {
        return Err(Failure(
            2,
            "--query-timeout must be a positive number of seconds".into(),
        ));
    }
    // The HTTP port first: taken, it is the one error, before the store, the Zenoh router
    // and the embedded executor start (and stop again). Served once all is up.
    let listener = std::net::TcpListener::bind(args.bind)
        .and_then(|l| l.set_nonblocking(true).map(|()| l))
        .map_err(|e| Failure(2, format!("cannot listen on {}: {e}", args.bind)))?;
    let kb = if args.in_memory {
        KnowledgeBase::in_memory()?
    } else {
        open_store(&args.data)?
    };
    // Axioms the reasoner does not support are named, never dropped silently: counted at
    // start-up, each one at debug level.
    let unsupported = kb.unsupported_axioms();
    if !unsupported.is_empty() {
        tracing::info!(
            "reasoner: {} axioms of the ontology lie outside OWL 2 RL and are not applied \
             (`dyknow reason --unsupported` lists those of the built-in ontologies; \
             RUST_LOG=dyknow_server=debug logs each)",
            unsupported.len()
        );
    }
    for axiom in &unsupported {
        tracing::debug!("reasoner: unsupported axiom (no rule applies it): {axiom}");
    }
    for file in rdf_files(&args.specs)? {
        tracing::info!("{}", load_file(&kb, &file)?);
    }
    let config = ServerConfig {
        token: args.token,
        max_body_bytes: args.max_body,
        query_timeout: Duration::from_secs_f64(args.query_timeout),
        query_memory: match args.query_memory {
            0 => None,
            mib => Some(mib.saturating_mul(1 << 20)),
        },
        store_concurrency: args
            .store_concurrency
            .unwrap_or_else(crate::app::default_store_concurrency),
        lifecycle: dyknow_lifecycle::Settings {
            horizon: args.horizon,
            time_unit: Duration::from_secs_f64(args.time_unit),
            explore_timeout: (args.explore_timeout_ms > 0)
                .then(|| Duration::from_millis(args.explore_timeout_ms)),
            explore_threads: usize::from(args.explore_threads),
            review_spacing: Duration::from_millis(args.review_spacing_ms),
            history_limit: args.history_limit,
        },
    };
    let namespace = dyknow_cu::Namespace::new(args.namespace.clone())
        .map_err(|e| Failure(2, format!("--namespace: {e}")))?;
    let mut plane = None;
    let group_store =
        (!args.in_memory).then(|| crate::groups::GroupStore::new(args.data.join("groups")));
    let state = if args.model_only {
        tracing::info!("model-only mode: no executor, change sets change the model only");
        AppState::new(kb, config)
            .map_err(|e| Failure(2, format!("engine: {e}")))?
            .with_groups(None, group_store)
            .map_err(|e| Failure(2, format!("groups: {e}")))?
    } else {
        let session = dataplane::open(
            dataplane::router_config(zenoh_file.as_ref(), &listen, &[], args.zenoh_lease_ms)
                .map_err(|e| Failure(2, e))?,
        )
        .map_err(|e| Failure(2, format!("{e} (listening on {})", listen.join(", "))))?;
        let (fleet, events) = dyknow_lifecycle::Fleet::start(&session, namespace.clone())
            .map_err(|e| Failure(2, format!("zenoh: {}", dyknow_cu::zenoh_message(&e))))?;
        fleet.forget_absent_after(Duration::from_secs_f64(args.forget_executors_after));
        let fleet = Arc::new(fleet);
        let fleet_handle = fleet.clone();
        let local = if args.no_executor {
            None
        } else {
            let mut config =
                dyknow_executor::ExecutorConfig::new("local", namespace.clone(), listen.clone());
            config.zenoh_config = zenoh_file.as_ref().map(|f| f.path.clone());
            config.zenoh_lease_ms = args.zenoh_lease_ms;
            let executor = dyknow_executor::Executor::start(&session, config)
                .map_err(|e| Failure(2, format!("executor: {e}")))?;
            if !fleet.wait_for("local", Duration::from_secs(10)) {
                tracing::warn!("the embedded executor did not show up within 10 s");
            }
            Some(executor)
        };
        tracing::info!(
            "data plane: Zenoh router on {}, namespace {}, {}",
            listen.join(", "),
            namespace,
            if local.is_some() {
                "embedded executor local"
            } else {
                "no embedded executor"
            }
        );
        let state = AppState::with_fleet(kb, config, fleet)
            .map_err(|e| Failure(2, format!("engine: {e}")))?
            .with_groups(
                Some(crate::groups::Plane {
                    session: session.clone(),
                    namespace: namespace.clone(),
                }),
                group_store,
            )
            .map_err(|e| Failure(2, format!("groups: {e}")))?;
        plane = Some((session, local, events, fleet_handle));
        state
    };
    let kb = state.kb.clone();
    let groups = state.groups.clone();
    // Large stacks (virtual memory, touched only as used): SPARQL's parser and evaluator
    // recurse along a query's nesting and chains, which `ParsedQuery::parse` bounds to what
    // this holds (`dyknow_store::MAX_QUERY_OPERATORS`).
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_stack_size(64 << 20)
        .build()?;
    let (session, local, events, fleet) = match plane {
        Some((session, local, events, fleet)) => (Some(session), local, Some(events), Some(fleet)),
        None => (None, None, None, None),
    };
    runtime.block_on(async move {
        let mut forward = None;
        if let Some(events) = events {
            // No review before the start-up reconciliation: a restarted manager first learns
            // what its executors still run.
            state.lifecycle.hold_reviews();
            let (stop, stopping) = tokio::sync::oneshot::channel();
            let forwarding = tokio::spawn(dataplane::forward(
                events,
                state.lifecycle.clone(),
                Duration::from_secs(1),
                Duration::from_secs_f64(args.reconcile_grace),
                stopping,
            ));
            forward = Some((stop, forwarding));
        }
        let listener = tokio::net::TcpListener::from_std(listener)
            .map_err(|e| Failure(2, format!("cannot listen on {}: {e}", args.bind)))?;
        tracing::info!(
            "DyKnow knowledge service listening on http://{} ({})",
            listener.local_addr()?,
            if args.in_memory {
                "in memory".to_owned()
            } else {
                format!("store in {}", args.data.display())
            }
        );
        state.start_life_cycle();
        // No Nagle (axum::serve leaves it on): a response written in more than one segment
        // (a streamed body) must not wait for the client's delayed acknowledgement.
        let listener = axum::serve::ListenerExt::tap_io(listener, |tcp| {
            if let Err(e) = tcp.set_nodelay(true) {
                tracing::debug!("TCP_NODELAY not set on a connection: {e}");
            }
        });
        // A graceful shutdown waits for every connection to close, and event streams
        // (`/changesets/stream`, a group's verdicts) never do on their own: with a client
        // watching, the service did not stop. Connections still open `CLOSE_GRACE` after the
        // signal are closed.
        const CLOSE_GRACE: Duration = Duration::from_secs(2);
        let (signalled, on_signal) = tokio::sync::oneshot::channel::<()>();
        let serve = axum::serve(listener, app(state))
            .with_graceful_shutdown(async move {
                shutdown_signal().await;
                let _ = signalled.send(());
            })
            .into_future();
        tokio::pin!(serve);
        tokio::select! {
            served = &mut serve => served?,
            () = async move {
                match on_signal.await {
                    Ok(()) => tokio::time::sleep(CLOSE_GRACE).await,
                    Err(_) => std::future::pending().await,
                }
            } => {
                tracing::info!(
                    "closing the connections still open {} s after the signal (event streams)",
                    CLOSE_GRACE.as_secs()
                );
            }
        }
        // The costs the executors measured since the last batch are written before the
        // runtime (and with it the forwarding) stops.
        if let Some((stop, forwarding)) = forward {
            let _ = stop.send(());
            if tokio::time::timeout(Duration::from_secs(5), forwarding)
                .await
                .is_err()
            {
                tracing::warn!("the last measured costs were not written within 5 s");
            }
        }
        Ok::<(), Failure>(())
    })?;
    // The life-cycle and the forwarding of executor events stop first: the embedded
    // executor's CUs stop below with the service, and its going is no crash to record (the
    // model keeps them; the next start respawns them under their names).
    runtime.shutdown_timeout(Duration::from_secs(10));
    if let Some(fleet) = fleet {
        fleet.stop_watching();
    }
    // Running groups stay running on disk and resume at the next start.
    groups.shutdown();
    if let Some(local) = local {
        // Every CU and child process stops with the service.
        local.shutdown();
    }
    if let Some(session) = session {
        let _ = dyknow_cu::zenoh::Wait::wait(session.close());
    }
    kb.flush()?;
    tracing::info!("stopped");
    Ok(())
}

/// `dyknow executor`.
fn executor(args: &ExecutorArgs) -> Result<(), Failure> {
    init_logging();
    let namespace = dyknow_cu::Namespace::new(args.namespace.clone())
        .map_err(|e| Failure(2, format!("--namespace: {e}")))?;
    let zenoh_file = args
        .zenoh_config
        .as_deref()
        .map(dataplane::ZenohFile::read)
        .transpose()
        .map_err(|e| Failure(2, e))?;
    let listen: Vec<String> = match (&args.listen, &zenoh_file) {
        (Some(listen), _) => vec![listen.clone()],
        (None, Some(file)) => file.listen().map(<[String]>::to_vec).unwrap_or_default(),
        (None, None) => Vec::new(),
    };
    dataplane::check_access(&listen, zenoh_file.as_ref()).map_err(|e| Failure(2, e))?;
    let session = dataplane::open(
        dataplane::router_config(
            zenoh_file.as_ref(),
            &listen,
            &args.connect,
            args.zenoh_lease_ms,
        )
        .map_err(|e| Failure(2, e))?,
    )
    .map_err(|e| Failure(2, e))?;
    let process_connect = if listen.is_empty() {
        args.connect.clone()
    } else {
        listen
    };
    let mut config =
        dyknow_executor::ExecutorConfig::new(args.name.clone(), namespace, process_connect);
    config.zenoh_config = zenoh_file.map(|f| f.path);
    config.zenoh_lease_ms = args.zenoh_lease_ms;
    // Stepping down for an earlier executor of the name ends the process (exit 2), as being
    // refused at start would have.
    let (stepped_down, mut step_down) = tokio::sync::mpsc::unbounded_channel();
    config.on_step_down = Some(dyknow_executor::OnStepDown(Arc::new(
        move |earlier: &dyknow_cu::keys::InstanceId| {
            let _ = stepped_down.send(earlier.clone());
        },
    )));
    let executor = dyknow_executor::Executor::start(&session, config)
        .map_err(|e| Failure(2, format!("executor: {e}")))?;
    // Zenoh keeps trying an endpoint that does not answer yet: say which it is, and say
    // when the links come and go (a manager restarting, a partition).
    let endpoints = args.connect.join(", ");
    let said = |linked: usize, before: Option<usize>| {
        if before.is_some_and(|b| b > 0) && linked == 0 {
            tracing::warn!(
                "executor {} lost its links to the data plane; Zenoh keeps trying {endpoints} (its CUs run on)",
                args.name
            );
        } else if linked > 0 {
            tracing::info!(
                "executor {} connected to the data plane ({linked} link{}; its endpoints: {endpoints})",
                args.name,
                if linked == 1 { "" } else { "s" }
            );
        } else {
            tracing::warn!(
                "executor {} is up, but {endpoints} does not answer yet (Zenoh keeps trying)",
                args.name
            );
        }
    };
    let mut linked = links(&session);
    said(linked, None);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let earlier = runtime.block_on(async {
        let watch = async {
            let mut every = tokio::time::interval(Duration::from_millis(500));
            loop {
                every.tick().await;
                let now = links(&session);
                if (now > 0) != (linked > 0) {
                    said(now, Some(linked));
                }
                linked = now;
            }
        };
        tokio::select! {
            () = shutdown_signal() => None,
            earlier = step_down.recv() => earlier,
            () = watch => None,
        }
    });
    executor.shutdown();
    let _ = dyknow_cu::zenoh::Wait::wait(session.close());
    if let Some(earlier) = earlier {
        return Err(Failure(
            2,
            format!(
                "executor: stepped down: another executor named {} (instance {earlier}) \
                 started before this one and is on this data plane now; names must be unique",
                args.name
            ),
        ));
    }
    tracing::info!("stopped");
    Ok(())
}

/// How many Zenoh nodes (routers and peers) `session` is linked to.
fn links(session: &dyknow_cu::zenoh::Session) -> usize {
    let info = session.info();
    dyknow_cu::zenoh::Wait::wait(info.routers_zid()).count()
        + dyknow_cu::zenoh::Wait::wait(info.peers_zid()).count()
}

/// `dyknow cu`: a builtin as a process CU; its exit status is the CU protocol's (0 stopped,
/// 1 crashed, 2 orphaned, 64 usage: an unknown builtin, or run by hand outside an executor,
/// without `DYKNOW_CU`, which an executor always sets).
fn cu(builtin: &str) -> ExitCode {
    let Some(factory) = dyknow_executor::builtins::builtin(builtin) else {
        warn(&format!(
            "dyknow cu: no builtin {builtin:?} (one of: {})",
            dyknow_executor::builtins::names().join(", ")
        ));
        return ExitCode::from(dyknow_cu::USAGE_EXIT);
    };
    // Without an executor's `DYKNOW_CU`, `run_process` says so and exits 64.
    dyknow_cu::run_process(|spec| factory.build(spec, dyknow_executor::builtins::Host::Process))
}

/// `dyknow publish`.
fn publish(channel: &str, value: &str, client: &ClientArgs) -> Result<(), Failure> {
    let value: serde_json::Value =
        serde_json::from_str(value).unwrap_or_else(|_| serde_json::Value::String(value.to_owned()));
    let (session, key) = client.open(channel)?;
    let payload = dyknow_cu::Sample::now(value).to_bytes();
    dyknow_cu::zenoh::Wait::wait(
        session
            .put(key, payload)
            .encoding(dyknow_cu::zenoh::bytes::Encoding::APPLICATION_JSON),
    )
    .map_err(|e| {
        Failure(
            2,
            format!("cannot publish: {}", dyknow_cu::zenoh_message(&e)),
        )
    })?;
    let _ = dyknow_cu::zenoh::Wait::wait(session.close());
    Ok(())
}

/// How often `dyknow listen` looks whether it is still linked to the service's router.
const LINK_CHECK: Duration = Duration::from_millis(500);

/// `dyknow listen`.
fn listen(
    channel: &str,
    client: &ClientArgs,
    count: Option<u64>,
    values: bool,
) -> Result<(), Failure> {
    use std::io::Write as _;
    let (session, key) = client.open(channel)?;
    let subscriber =
        dyknow_cu::zenoh::Wait::wait(session.declare_subscriber(key)).map_err(|e| {
            Failure(
                2,
                format!("cannot subscribe: {}", dyknow_cu::zenoh_message(&e)),
            )
        })?;
    let mut seen = 0u64;
    let stdout = std::io::stdout();
    // The service's router going away is said on standard error, and so is its return (the
    // client session reconnects by itself): samples published meanwhile are not received, and
    // a listener that waited in silence looked like a quiet channel.
    let mut linked = true;
    let mut checked = Instant::now();
    while count.is_none_or(|n| seen < n) {
        let sample = match subscriber.recv_timeout(LINK_CHECK) {
            Ok(Some(sample)) => sample,
            Ok(None) => {
                if checked.elapsed() >= LINK_CHECK {
                    checked = Instant::now();
                    let now = links(&session) > 0;
                    if now != linked {
                        linked = now;
                        warn(&if now {
                            format!("dyknow listen: linked to {} again", client.connect)
                        } else {
                            format!(
                                "dyknow listen: lost the link to {} (is `dyknow serve` still \
                                 running?); waiting for it to come back, samples published \
                                 meanwhile are not received",
                                client.connect
                            )
                        });
                    }
                }
                continue;
            }
            Err(_) => break,
        };
        let payload = sample.payload().to_bytes();
        let line = match dyknow_cu::Sample::from_slice(&payload) {
            Ok(s) if values => serde_json::to_string(&s.value).unwrap_or_default(),
            Ok(s) => serde_json::to_string(&s).unwrap_or_default(),
            Err(e) => {
                warn(&format!(
                    "not a sample ({e}): {}",
                    String::from_utf8_lossy(&payload)
                ));
                continue;
            }
        };
        let mut out = stdout.lock();
        if writeln!(out, "{line}").and_then(|()| out.flush()).is_err() {
            break;
        }
        seen += 1;
    }
    Ok(())
}

async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = terminate => {},
    }
    tracing::info!("shutting down");
}
