//! `dyknow group`: formula groups over the HTTP API (contract `groups.md`).

use std::io::{BufRead, BufReader, Write};
use std::time::Duration;

use serde_json::{Map, Value, json};

/// Where the service is.
#[derive(Debug, clap::Args)]
pub struct HttpArgs {
    /// The service's URL, http://HOST:PORT or https://HOST:PORT (an empty DYKNOW_URL counts
    /// as unset). A request that takes longer than DYKNOW_CLIENT_TIMEOUT_S seconds (default
    /// 60; connecting: at most 10) fails; `watch` waits as long as it takes, and `trace`
    /// reads the trace as long as it takes once its answer begins.
    #[arg(
        long,
        value_name = "URL",
        env = "DYKNOW_URL",
        default_value = DEFAULT_URL,
        global = true
    )]
    pub url: String,
    /// The bearer token for changes (not empty).
    #[arg(
        long,
        value_name = "T",
        env = "DYKNOW_TOKEN",
        hide_env_values = true,
        global = true
    )]
    pub token: Option<String>,
}

/// `dyknow group` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum GroupCommand {
    /// CreateGroup: prints the group as JSON.
    Create {
        /// The label (`g-N` when absent).
        #[arg(long)]
        label: Option<String>,
        /// A formula (repeat for several).
        #[arg(long = "formula", value_name = "F")]
        formulas: Vec<String>,
        /// A named domain, `NAME=a,b` (repeatable).
        #[arg(long = "domain", value_name = "NAME=a,b")]
        domains: Vec<String>,
        /// Landmark regions.
        #[arg(long, value_name = "a,b", value_delimiter = ',')]
        landmarks: Vec<String>,
        /// Static regions.
        #[arg(long = "static", value_name = "r1,r2", value_delimiter = ',')]
        static_regions: Vec<String>,
        /// A symbol's tag instead of the symbol itself, `SYMBOL=TAG` (repeatable); a TAG in
        /// angle brackets is a tag description IRI.
        #[arg(long = "ground", value_name = "SYMBOL=TAG")]
        grounding: Vec<String>,
        /// The synchronisation policy: wait, hold or event.
        #[arg(long, value_name = "POLICY", default_value = "wait")]
        sync: String,
        /// The state period P (wait, hold) [default: 100].
        #[arg(long, value_name = "MS")]
        period_ms: Option<u64>,
        /// The maximum delay D [default: 5 P for wait, P for hold, 2 for event].
        #[arg(long, value_name = "MS")]
        max_delay_ms: Option<u64>,
        /// The maximum age A (hold) [default: 1000].
        #[arg(long, value_name = "MS")]
        max_age_ms: Option<u64>,
        /// The result channel.
        #[arg(long, value_name = "CHANNEL")]
        result_channel: Option<String>,
        /// Start at once.
        #[arg(long)]
        start: bool,
    },
    /// Lists the groups: label, state, states, verdicts.
    List,
    /// Prints a group as JSON.
    Show {
        /// The group.
        label: String,
    },
    /// StartGroup.
    Start {
        /// The group.
        label: String,
    },
    /// StopGroup (for good; undecided formulas become unknown).
    Stop {
        /// The group.
        label: String,
    },
    /// DestroyGroup.
    Destroy {
        /// The group.
        label: String,
    },
    /// AddFormula: prints its index.
    Add {
        /// The group.
        label: String,
        /// The formula.
        formula: String,
    },
    /// RemoveFormula.
    Remove {
        /// The group.
        label: String,
        /// The formula's index.
        index: usize,
    },
    /// Prints verdict lines (`{"formula", "verdict", "t"}`, as `dyknow check`) as they come.
    Watch {
        /// The group.
        label: String,
        /// Replay the recorded verdicts with `t` at or after this first (0: all).
        #[arg(long, value_name = "T")]
        since: Option<u64>,
        /// Exit after this many verdict lines (at least 1).
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
        count: Option<u64>,
    },
    /// Prints the recorded state stream as a `dyknow check` trace.
    Trace {
        /// The group.
        label: String,
    },
}

/// A failure: exit status and message. Status 0 with no message is [`Failure::CLOSED_OUTPUT`].
pub struct Failure(pub u8, pub String);

impl Failure {
    /// Standard output is a closed pipe (`dyknow group show g | head -1`): the reader has what
    /// it wanted, so the command stops quietly with exit 0.
    pub const CLOSED_OUTPUT: Self = Self(0, String::new());

    /// A failure to write standard output: [`Failure::CLOSED_OUTPUT`] for a closed pipe, else
    /// exit 2.
    pub fn output(e: &std::io::Error) -> Self {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            Self::CLOSED_OUTPUT
        } else {
            Self(2, format!("writing the output: {e}"))
        }
    }
}

/// The service's URL when neither `--url` nor `DYKNOW_URL` gives one (an empty one is none).
pub const DEFAULT_URL: &str = "http://127.0.0.1:7878";

/// The environment variable that bounds a one-shot request, in seconds.
pub const TIMEOUT_VARIABLE: &str = "DYKNOW_CLIENT_TIMEOUT_S";

/// How long a one-shot request may take as a whole (connecting, sending, the answer) unless
/// [`TIMEOUT_VARIABLE`] says otherwise.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(60);

/// How long connecting may take (a shorter request time limit shortens it too).
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// Writes `text` to standard output; a closed pipe stops quietly ([`Failure::output`]), never
/// a panic as `print!` makes it.
fn write_stdout(text: &str) -> Result<(), Failure> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .map_err(|e| Failure::output(&e))
}

/// The service's base URL, without a trailing `/`: `given` checked to be an `http` or `https`
/// URL with a host (an empty one is [`DEFAULT_URL`]).
fn service_url(given: &str) -> Result<String, Failure> {
    let given = given.trim();
    if given.is_empty() {
        return Ok(DEFAULT_URL.to_owned());
    }
    let malformed = |why: &str| {
        Failure(
            2,
            format!(
                "the URL {given:?} (--url or DYKNOW_URL) is malformed: {why}; expected \
                 http://HOST:PORT or https://HOST:PORT, e.g. {DEFAULT_URL}"
            ),
        )
    };
    let uri: ureq::http::Uri = given.parse().map_err(|e| malformed(&format!("{e}")))?;
    match uri.scheme_str() {
        Some("http" | "https") => {}
        Some(other) => {
            return Err(malformed(&format!(
                "the scheme {other:?} is not http or https"
            )));
        }
        None => return Err(malformed("no scheme")),
    }
    if uri.host().is_none_or(str::is_empty) {
        return Err(malformed("no host"));
    }
    if uri.query().is_some() {
        return Err(malformed("a query"));
    }
    Ok(given.trim_end_matches('/').to_owned())
}

/// The time limit of a one-shot request: [`TIMEOUT_VARIABLE`] (a positive number of seconds;
/// empty is unset), else [`DEFAULT_TIMEOUT`].
fn request_timeout() -> Result<Duration, Failure> {
    let Some(text) = std::env::var_os(TIMEOUT_VARIABLE) else {
        return Ok(DEFAULT_TIMEOUT);
    };
    let text = text.to_string_lossy();
    if text.trim().is_empty() {
        return Ok(DEFAULT_TIMEOUT);
    }
    text.trim()
        .parse::<f64>()
        .ok()
        .and_then(|s| Duration::try_from_secs_f64(s).ok())
        .filter(|d| !d.is_zero() && *d <= Duration::from_secs(u64::from(u32::MAX)))
        .ok_or_else(|| {
            Failure(
                2,
                format!(
                    "{TIMEOUT_VARIABLE}={text:?}: expected a positive number of seconds (at most {})",
                    u32::MAX
                ),
            )
        })
}

/// An agent that reads error statuses as answers; `whole` bounds a request as a whole (none:
/// a stream), connecting takes at most [`CONNECT_TIMEOUT`] (or `whole`, if shorter).
fn agent(whole: Option<Duration>) -> ureq::Agent {
    let connect = whole.map_or(CONNECT_TIMEOUT, |w| w.min(CONNECT_TIMEOUT));
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_connect(Some(connect))
        .timeout_global(whole)
        .build()
        .into()
}

/// An agent for a download (`trace`): connecting and the answer's head are bounded as a
/// one-shot request is (`head`), the body takes as long as it takes.
fn download_agent(head: Duration) -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_connect(Some(head.min(CONNECT_TIMEOUT)))
        .timeout_send_request(Some(head))
        .timeout_recv_response(Some(head))
        .build()
        .into()
}

fn enc(s: &str) -> String {
    percent_encoding::utf8_percent_encode(s, percent_encoding::NON_ALPHANUMERIC).to_string()
}

/// At most 80 characters of `text`, on one line (control characters escaped), for a message.
fn snippet(text: &str) -> String {
    let mut out = String::new();
    for c in text.trim().chars().take(80) {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    if text.trim().chars().count() > 80 {
        out.push('…');
    }
    if out.is_empty() {
        out.push_str("an empty body");
    }
    out
}

/// What a successful answer must be.
#[derive(Debug, Clone, Copy)]
enum Expect {
    /// A group's status, `{"label", "state", "formulas", ...}`.
    Group,
    /// A list of groups' statuses.
    Groups,
    /// `{"index": N}` (AddFormula).
    Index,
    /// No body (204).
    Nothing,
}

impl Expect {
    fn what(self) -> &'static str {
        match self {
            Self::Group => "a group as JSON",
            Self::Groups => "a JSON list of groups",
            Self::Index => "a formula's index as JSON",
            Self::Nothing => "no content (204)",
        }
    }

    /// Whether `v` has the expected shape.
    fn fits(self, v: &Value) -> bool {
        let group = |g: &Value| {
            g["label"].is_string() && g["state"].is_string() && g["formulas"].is_array()
        };
        match self {
            Self::Group => group(v),
            Self::Groups => v.as_array().is_some_and(|l| l.iter().all(group)),
            Self::Index => v["index"].is_u64(),
            Self::Nothing => true,
        }
    }
}

struct Client {
    /// The base URL, checked ([`service_url`]).
    base: String,
    token: Option<String>,
    /// The time limit of one-shot requests.
    timeout: Duration,
    agent: ureq::Agent,
}

impl Client {
    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    /// A request that failed before an answer came.
    fn unreachable(&self, e: &ureq::Error) -> Failure {
        match e {
            ureq::Error::Timeout(ureq::Timeout::Connect) => Failure(
                2,
                format!(
                    "cannot connect to {} within {} s; is `dyknow serve` running there?",
                    self.base,
                    self.timeout.min(CONNECT_TIMEOUT).as_secs_f64()
                ),
            ),
            ureq::Error::Timeout(_) => Failure(
                2,
                format!(
                    "no answer from {} within {} s ({TIMEOUT_VARIABLE} sets the limit)",
                    self.base,
                    self.timeout.as_secs_f64()
                ),
            ),
            ureq::Error::BadUri(_) | ureq::Error::Http(_) => Failure(
                2,
                format!(
                    "the URL {} (--url or DYKNOW_URL) is malformed: {e}",
                    self.base
                ),
            ),
            _ => Failure(
                2,
                format!(
                    "cannot reach {} ({e}); is `dyknow serve` running?",
                    self.base
                ),
            ),
        }
    }

    /// An answer that is not what a DyKnow service gives.
    fn unusable(
        &self,
        path: &str,
        status: u16,
        content_type: &str,
        detail: &str,
        expected: &str,
    ) -> Failure {
        Failure(
            2,
            format!(
                "unexpected answer from {}: {status} {}: {detail}; expected {expected} \
                 (is {} a DyKnow service?)",
                self.url(path),
                if content_type.is_empty() {
                    "(no content type)"
                } else {
                    content_type
                },
                self.base
            ),
        )
    }

    /// An answer's status, content type and body; a body that cannot be read is a timeout
    /// or an unusable answer (`expected` says what was expected).
    fn read(
        &self,
        path: &str,
        mut r: ureq::http::Response<ureq::Body>,
        expected: &str,
    ) -> Result<(u16, String, String), Failure> {
        let status = r.status().as_u16();
        let content_type = content_type(&r);
        let text = r
            .body_mut()
            .with_config()
            .limit(u64::MAX)
            .read_to_string()
            .map_err(|e| match e {
                ureq::Error::Timeout(_) => self.unreachable(&e),
                e => self.unusable(
                    path,
                    status,
                    &content_type,
                    &format!("reading it: {e}"),
                    expected,
                ),
            })?;
        Ok((status, content_type, text))
    }

    /// Reads an answer: an HTTP error is [`http_failure`]; a success that is not `expect` is an
    /// unusable answer (exit 2).
    fn answer(
        &self,
        path: &str,
        r: Result<ureq::http::Response<ureq::Body>, ureq::Error>,
        expect: Expect,
    ) -> Result<Value, Failure> {
        let r = r.map_err(|e| self.unreachable(&e))?;
        let (status, content_type, text) = self.read(path, r, expect.what())?;
        if status >= 400 {
            return Err(http_failure(status, &text));
        }
        let bad =
            |detail: String| self.unusable(path, status, &content_type, &detail, expect.what());
        if !(200..300).contains(&status) {
            return Err(bad(snippet(&text)));
        }
        if let Expect::Nothing = expect {
            return if status == 204 || text.trim().is_empty() {
                Ok(Value::Null)
            } else {
                Err(bad(snippet(&text)))
            };
        }
        if !content_type.starts_with("application/json") {
            return Err(bad(snippet(&text)));
        }
        let value: Value = serde_json::from_str(&text)
            .map_err(|e| bad(format!("not JSON ({e}): {}", snippet(&text))))?;
        if !expect.fits(&value) {
            return Err(bad(snippet(&text)));
        }
        Ok(value)
    }

    fn get(&self, path: &str, expect: Expect) -> Result<Value, Failure> {
        self.answer(path, self.agent.get(self.url(path)).call(), expect)
    }

    fn send(
        &self,
        method: &str,
        path: &str,
        body: Option<Value>,
        expect: Expect,
    ) -> Result<Value, Failure> {
        let mut req = ureq::http::Request::builder()
            .method(method)
            .uri(self.url(path));
        if let Some(t) = &self.token {
            req = req.header("Authorization", format!("Bearer {t}"));
        }
        let r = match body {
            Some(b) => self.agent.run(
                req.header("Content-Type", "application/json")
                    .body(b.to_string())
                    .map_err(|e| Failure(2, e.to_string()))?,
            ),
            None => self
                .agent
                .run(req.body(()).map_err(|e| Failure(2, e.to_string()))?),
        };
        self.answer(path, r, expect)
    }
}

/// An answer's content type, lower case, without parameters (`""` when there is none).
fn content_type(r: &ureq::http::Response<ureq::Body>) -> String {
    r.headers()
        .get(ureq::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .map(|v| v.trim().to_ascii_lowercase())
        .unwrap_or_default()
}

/// An HTTP error as the exit status and the service's message (`{"error", "details"}`, or the
/// start of the body, on one line): 1 for a 5xx, else 2.
fn http_failure(status: u16, body: &str) -> Failure {
    let v: Value = serde_json::from_str(body).unwrap_or(Value::Null);
    let mut msg = match v["error"].as_str() {
        Some(e) => snippet_long(e),
        None => snippet(body),
    };
    if let Some(d) = v["details"].as_array().filter(|d| !d.is_empty()) {
        msg.push_str(&format!(" {}", Value::Array(d.clone())));
    }
    Failure(
        if status >= 500 { 1 } else { 2 },
        format!("{status}: {msg}"),
    )
}

/// The service's own error message, on one line.
fn snippet_long(text: &str) -> String {
    text.lines().collect::<Vec<_>>().join(" ")
}

fn print(v: &Value) -> Result<(), Failure> {
    write_stdout(&format!(
        "{}\n",
        serde_json::to_string_pretty(v).unwrap_or_default()
    ))
}

/// Runs `dyknow group ...`.
pub fn run(http: &HttpArgs, cmd: GroupCommand) -> Result<(), Failure> {
    // An empty token (`DYKNOW_TOKEN=` by accident) would be sent as `Bearer ` and refused by
    // a service with a token, and means nothing to one without: a usage error.
    if http.token.as_deref().is_some_and(|t| t.trim().is_empty()) {
        return Err(Failure(
            2,
            "the token (--token or DYKNOW_TOKEN) is empty: give the service's token, or unset \
             DYKNOW_TOKEN"
                .into(),
        ));
    }
    let timeout = request_timeout()?;
    let client = Client {
        base: service_url(&http.url)?,
        token: http.token.clone(),
        timeout,
        agent: agent(Some(timeout)),
    };
    match cmd {
        GroupCommand::Create {
            label,
            formulas,
            domains,
            landmarks,
            static_regions,
            grounding,
            sync,
            period_ms,
            max_delay_ms,
            max_age_ms,
            result_channel,
            start,
        } => {
            let mut body = Map::new();
            if let Some(l) = label {
                body.insert("label".into(), json!(l));
            }
            if let Some(c) = result_channel {
                body.insert("result_channel".into(), json!(c));
            }
            body.insert("formulas".into(), json!(formulas));
            // Repeated flags of one domain add up, as `dyknow check --domain` does.
            let mut header = dyknow_mstl::trace::Header::default();
            for arg in &domains {
                // The message names the flag and the argument already.
                let (name, values) =
                    dyknow_mstl::trace::parse_domain(arg).map_err(|e| Failure(2, e))?;
                header.extend(dyknow_mstl::trace::Header {
                    domains: [(name, values)].into(),
                    ..Default::default()
                });
            }
            body.insert("domains".into(), json!(header.domains));
            body.insert("landmarks".into(), json!(landmarks));
            body.insert("static".into(), json!(static_regions));
            let mut g = Map::new();
            for arg in &grounding {
                let (symbol, tag) = arg
                    .split_once('=')
                    .ok_or_else(|| Failure(2, format!("--ground {arg:?}: expected SYMBOL=TAG")))?;
                let value = match tag.strip_prefix('<').and_then(|t| t.strip_suffix('>')) {
                    Some(iri) => json!({"description": iri}),
                    None => json!({"tag": tag}),
                };
                g.insert(symbol.to_owned(), value);
            }
            body.insert("grounding".into(), Value::Object(g));
            // A flag the policy does not take is refused, as `POST /groups` refuses the field.
            let unused = |flag: &str, given: bool| {
                if given {
                    Err(Failure(2, format!("--sync {sync}: takes no {flag}")))
                } else {
                    Ok(())
                }
            };
            let period = period_ms.unwrap_or(100);
            let policy = match sync.as_str() {
                "wait" => {
                    unused("--max-age-ms", max_age_ms.is_some())?;
                    json!({"policy": "wait", "period_ms": period, "max_delay_ms": max_delay_ms.unwrap_or(5 * period)})
                }
                "hold" => {
                    let mut p = json!({"policy": "hold", "period_ms": period, "max_age_ms": max_age_ms.unwrap_or(1000)});
                    if let Some(d) = max_delay_ms {
                        p["max_delay_ms"] = json!(d);
                    }
                    p
                }
                "event" => {
                    unused("--period-ms", period_ms.is_some())?;
                    unused("--max-age-ms", max_age_ms.is_some())?;
                    let mut p = json!({"policy": "event"});
                    if let Some(d) = max_delay_ms {
                        p["max_delay_ms"] = json!(d);
                    }
                    p
                }
                other => {
                    return Err(Failure(
                        2,
                        format!("--sync {other:?}: use wait, hold or event"),
                    ));
                }
            };
            body.insert("sync".into(), policy);
            body.insert("start".into(), json!(start));
            print(&client.send("POST", "/groups", Some(Value::Object(body)), Expect::Group)?)
        }
        GroupCommand::List => {
            let list = client.get("/groups", Expect::Groups)?;
            let mut text = String::new();
            for g in list.as_array().into_iter().flatten() {
                let formulas = g["formulas"].as_array().map_or(0, Vec::len);
                let decided = g["formulas"]
                    .as_array()
                    .map_or(0, |f| f.iter().filter(|f| !f["verdict"].is_null()).count());
                text.push_str(&format!(
                    "{}\t{}\t{} states\t{decided}/{formulas} decided\n",
                    g["label"].as_str().unwrap_or_default(),
                    g["state"].as_str().unwrap_or_default(),
                    g["states"]
                ));
            }
            write_stdout(&text)
        }
        GroupCommand::Show { label } => {
            print(&client.get(&format!("/groups/{}", enc(&label)), Expect::Group)?)
        }
        GroupCommand::Start { label } => print(&client.send(
            "POST",
            &format!("/groups/{}/start", enc(&label)),
            None,
            Expect::Group,
        )?),
        GroupCommand::Stop { label } => print(&client.send(
            "POST",
            &format!("/groups/{}/stop", enc(&label)),
            None,
            Expect::Group,
        )?),
        GroupCommand::Destroy { label } => {
            client.send(
                "DELETE",
                &format!("/groups/{}", enc(&label)),
                None,
                Expect::Nothing,
            )?;
            Ok(())
        }
        GroupCommand::Add { label, formula } => {
            let v = client.send(
                "POST",
                &format!("/groups/{}/formulas", enc(&label)),
                Some(json!({"formula": formula})),
                Expect::Index,
            )?;
            write_stdout(&format!("{}\n", v["index"]))?;
            Ok(())
        }
        GroupCommand::Remove { label, index } => {
            client.send(
                "DELETE",
                &format!("/groups/{}/formulas/{index}", enc(&label)),
                None,
                Expect::Nothing,
            )?;
            Ok(())
        }
        GroupCommand::Trace { label } => {
            let path = format!("/groups/{}/trace", enc(&label));
            // A trace may be long: its answer must begin within the limit, its body may take
            // as long as it takes.
            let r = download_agent(client.timeout)
                .get(client.url(&path))
                .call()
                .map_err(|e| client.unreachable(&e))?;
            let expected = "a trace as JSON lines (application/x-ndjson)";
            let (status, content_type, text) = client.read(&path, r, expected)?;
            if status >= 400 {
                return Err(http_failure(status, &text));
            }
            // A trace starts with its header, a JSON object.
            let header = text.lines().next().unwrap_or_default();
            if !(200..300).contains(&status)
                || content_type != "application/x-ndjson"
                || !serde_json::from_str::<Value>(header).is_ok_and(|h| h.is_object())
            {
                return Err(client.unusable(
                    &path,
                    status,
                    &content_type,
                    &snippet(&text),
                    expected,
                ));
            }
            write_stdout(&text)
        }
        GroupCommand::Watch {
            label,
            since,
            count,
        } => {
            let mut path = format!("/groups/{}/verdicts", enc(&label));
            if let Some(s) = since {
                path.push_str(&format!("?since={s}"));
            }
            // A stream: no time limit but connecting's.
            let mut r = agent(None)
                .get(client.url(&path))
                .call()
                .map_err(|e| client.unreachable(&e))?;
            let status = r.status().as_u16();
            if status >= 400 {
                let text = r.body_mut().read_to_string().unwrap_or_default();
                return Err(http_failure(status, &text));
            }
            let content_type = content_type(&r);
            // (Its body is not read: with no time limit, it might never end.)
            if !(200..300).contains(&status) || content_type != "text/event-stream" {
                return Err(client.unusable(
                    &path,
                    status,
                    &content_type,
                    "not an event stream",
                    "a stream of verdicts (text/event-stream)",
                ));
            }
            let reader = BufReader::new(r.into_body().into_reader());
            let mut seen = 0;
            let out = std::io::stdout();
            for line in reader.lines() {
                // The service went away (or the connection broke): no negative answer.
                let line = line.map_err(|e| {
                    Failure(
                        2,
                        format!("the verdict stream from {} broke off ({e})", client.base),
                    )
                })?;
                let Some(data) = line.strip_prefix("data:") else {
                    continue;
                };
                let Ok(v) = serde_json::from_str::<Value>(data.trim()) else {
                    continue;
                };
                // The `dyknow check` line.
                let text = format!(
                    "{{\"formula\": {}, \"verdict\": {}, \"t\": {}}}",
                    v["formula"], v["verdict"], v["t"]
                );
                let mut o = out.lock();
                if writeln!(o, "{text}").and_then(|()| o.flush()).is_err() {
                    break;
                }
                seen += 1;
                if count.is_some_and(|n| seen >= n) {
                    break;
                }
            }
            Ok(())
        }
    }
}
