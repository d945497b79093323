//! `dyknow group`: formula groups over the HTTP API (contract `groups.md`).

use std::io::{BufRead, BufReader, Write};
use std::time::Duration;

use serde_json::{Map, Value, json};

/// Where the service is.
#[derive(Debug, clap::Args)]
pub struct HttpArgs {
    /// The service's URL.
    #[arg(
        long,
        value_name = "URL",
        env = "DYKNOW_URL",
        default_value = "http://127.0.0.1:7878",
        global = true
    )]
    pub url: String,
    /// The bearer token for changes.
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

/// A failure: exit status and message.
pub struct Failure(pub u8, pub String);

/// Writes `text` to standard output: a closed pipe is an error to report (exit 2), not a
/// panic as `print!` makes it.
fn write_stdout(text: &str) -> Result<(), Failure> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .map_err(|e| Failure(2, format!("writing the output: {e}")))
}

fn agent(timeout: Option<Duration>) -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(timeout)
        .build()
        .into()
}

fn enc(s: &str) -> String {
    percent_encoding::utf8_percent_encode(s, percent_encoding::NON_ALPHANUMERIC).to_string()
}

struct Client<'a> {
    http: &'a HttpArgs,
    agent: ureq::Agent,
}

impl Client<'_> {
    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.http.url.trim_end_matches('/'))
    }

    fn answer(
        &self,
        r: Result<ureq::http::Response<ureq::Body>, ureq::Error>,
    ) -> Result<Value, Failure> {
        let mut r = r.map_err(|e| {
            Failure(
                2,
                format!(
                    "cannot reach {} ({e}); is `dyknow serve` running?",
                    self.http.url
                ),
            )
        })?;
        let status = r.status().as_u16();
        let text = r.body_mut().read_to_string().unwrap_or_default();
        if status >= 400 {
            return Err(http_failure(status, &text));
        }
        Ok(serde_json::from_str(&text).unwrap_or(Value::Null))
    }

    fn get(&self, path: &str) -> Result<Value, Failure> {
        self.answer(self.agent.get(self.url(path)).call())
    }

    fn send(&self, method: &str, path: &str, body: Option<Value>) -> Result<Value, Failure> {
        let mut req = ureq::http::Request::builder()
            .method(method)
            .uri(self.url(path));
        if let Some(t) = &self.http.token {
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
        self.answer(r)
    }
}

/// An HTTP error as the exit status and the service's message (`{"error", "details"}`, or the
/// body as it is): 1 for a 5xx, else 2.
fn http_failure(status: u16, body: &str) -> Failure {
    let v: Value = serde_json::from_str(body).unwrap_or(Value::Null);
    let mut msg = v["error"].as_str().unwrap_or(body).to_owned();
    if let Some(d) = v["details"].as_array().filter(|d| !d.is_empty()) {
        msg.push_str(&format!(" {}", Value::Array(d.clone())));
    }
    Failure(
        if status >= 500 { 1 } else { 2 },
        format!("{status}: {msg}"),
    )
}

fn print(v: &Value) -> Result<(), Failure> {
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "{}",
        serde_json::to_string_pretty(v).unwrap_or_default()
    )
    .map_err(|e| Failure(1, e.to_string()))
}

/// Runs `dyknow group ...`.
pub fn run(http: &HttpArgs, cmd: GroupCommand) -> Result<(), Failure> {
    let client = Client {
        http,
        agent: agent(Some(Duration::from_secs(120))),
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
            print(&client.send("POST", "/groups", Some(Value::Object(body)))?)
        }
        GroupCommand::List => {
            let list = client.get("/groups")?;
            let mut out = std::io::stdout().lock();
            for g in list.as_array().into_iter().flatten() {
                let formulas = g["formulas"].as_array().map_or(0, Vec::len);
                let decided = g["formulas"]
                    .as_array()
                    .map_or(0, |f| f.iter().filter(|f| !f["verdict"].is_null()).count());
                writeln!(
                    out,
                    "{}\t{}\t{} states\t{decided}/{formulas} decided",
                    g["label"].as_str().unwrap_or_default(),
                    g["state"].as_str().unwrap_or_default(),
                    g["states"]
                )
                .map_err(|e| Failure(1, e.to_string()))?;
            }
            Ok(())
        }
        GroupCommand::Show { label } => print(&client.get(&format!("/groups/{}", enc(&label)))?),
        GroupCommand::Start { label } => {
            print(&client.send("POST", &format!("/groups/{}/start", enc(&label)), None)?)
        }
        GroupCommand::Stop { label } => {
            print(&client.send("POST", &format!("/groups/{}/stop", enc(&label)), None)?)
        }
        GroupCommand::Destroy { label } => {
            client.send("DELETE", &format!("/groups/{}", enc(&label)), None)?;
            Ok(())
        }
        GroupCommand::Add { label, formula } => {
            let v = client.send(
                "POST",
                &format!("/groups/{}/formulas", enc(&label)),
                Some(json!({"formula": formula})),
            )?;
            write_stdout(&format!("{}\n", v["index"]))?;
            Ok(())
        }
        GroupCommand::Remove { label, index } => {
            client.send(
                "DELETE",
                &format!("/groups/{}/formulas/{index}", enc(&label)),
                None,
            )?;
            Ok(())
        }
        GroupCommand::Trace { label } => {
            let mut r = agent(Some(Duration::from_secs(120)))
                .get(client.url(&format!("/groups/{}/trace", enc(&label))))
                .call()
                .map_err(|e| {
                    Failure(
                        2,
                        format!(
                            "cannot reach {} ({e}); is `dyknow serve` running?",
                            client.http.url
                        ),
                    )
                })?;
            let text = r
                .body_mut()
                .with_config()
                .limit(u64::MAX)
                .read_to_string()
                .map_err(|e| Failure(1, e.to_string()))?;
            if r.status().as_u16() >= 400 {
                return Err(http_failure(r.status().as_u16(), &text));
            }
            write_stdout(&text)?;
            Ok(())
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
            let mut r = agent(None)
                .get(client.url(&path))
                .call()
                .map_err(|e| Failure(2, format!("cannot reach {} ({e})", http.url)))?;
            if r.status().as_u16() >= 400 {
                let text = r.body_mut().read_to_string().unwrap_or_default();
                return Err(http_failure(r.status().as_u16(), &text));
            }
            let reader = BufReader::new(r.into_body().into_reader());
            let mut seen = 0;
            let out = std::io::stdout();
            for line in reader.lines() {
                let line = line.map_err(|e| Failure(1, e.to_string()))?;
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
