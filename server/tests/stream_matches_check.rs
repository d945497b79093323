//! Acceptance (issue 12, item 4): the mstl stream type gives the same verdicts as `dyknow check`
//! on every trace in `specs/traces/`.
//!
//! Every `*.jsonl` in `specs/traces/` is found by listing the directory, so a new trace is
//! covered at once. Each is checked with the formulas the CLI tests and the README tour use for
//! it (`check_cli.rs`), alone and together with generic formulas over the keys and regions the
//! trace contains (the only ones for a trace not named here), under the command-line flags
//! those tests use (`--landmarks`, `--domain`) and, for spatial traces, a landmark and static
//! regions of its own. Both paths run: `dyknow check` as a process, and a direct path that
//! decodes the trace lines with `serde_json` into `State`s itself and drives the public
//! `StateStream` + `Monitor` API (never `trace::check`). The verdict lines must be equal, and
//! when `dyknow check` refuses a trace the direct path must refuse it at the same point for
//! the same reason.
#![expect(
    clippy::unwrap_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

use dyknow_mstl::{Monitor, State, StateStream, StateValue, StreamError, parse};
use dyknow_rcc8::Relation;
use serde_json::{Map, Value as Json};

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

// The seed's formulas as `check_cli.rs` and the README tour use them.
const F3_2: &str = "inRoom -> always (poorLight -> eventually[0,10s] goodLight)";
const F4_5: &str =
    "forall x in NAO: always (batteryLevel(x) < 0.1 -> eventually[0,60s] Charging(x))";
const F5_12: &str = "forall x in UAV: always (altitude(x) > 50)";
const F6_1: &str = "always[0,1440min] InsideCircle(ball)";
const EQ1: &str = "always[0,150] EQ(r1, next r1)";
const EQ2: &str = "always[0,150] EQ(r2, next r2)";

/// The formulas and extra flag sets the CLI tests use for a trace (by file stem); the run
/// without flags is always added.
fn known(stem: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let strings = |v: &[&str]| v.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
    let (formulas, flags): (Vec<String>, Vec<Vec<&str>>) = match stem {
        s if s.starts_with("office-light") => (strings(&[F3_2]), vec![]),
        s if s.starts_with("nao-battery") => (strings(&[F4_5]), vec![]),
        s if s.starts_with("uav-altitude") => (
            strings(&[
                F5_12,
                "eventually[0,150] altitude(uav2) < 79.5",
                "always altitude(uav2) > 0",
            ]),
            vec![vec!["--domain", "UAV="]],
        ),
        s if s.starts_with("ball-circle") => (strings(&[F6_1]), vec![]),
        "figure-3.5" => (
            strings(&[
                "PO(a,b)",
                "next DC(a,b)",
                "next next DC(a,b)",
                "always (PO(a,b) -> eventually DC(a,b))",
            ]),
            vec![],
        ),
        "busy-student" => (
            strings(&[
                "DC(student, canteen)",
                "DC(desk, canteen)",
                "next DC(student, office)",
            ]),
            vec![],
        ),
        "landmarks-3.26" => (
            vec![
                EQ1.to_owned(),
                EQ2.to_owned(),
                format!("{EQ1} && !{EQ2}"),
                format!("{EQ2} && !{EQ1}"),
            ],
            vec![
                vec!["--landmarks", "r1"],
                vec!["--landmarks", "r2"],
                vec!["--landmarks", "r1,r2"],
            ],
        ),
        "landmarks-hidden-conflict" => (strings(&["always DC(house, lake)"]), vec![]),
        _ => (vec![], vec![]),
    };
    (formulas, flags.into_iter().map(|f| strings(&f)).collect())
}

/// What a trace contains: its keys with a value each (the first seen), and its regions.
#[derive(Debug, Default)]
struct Contents {
    values: BTreeMap<String, Json>,
    regions: BTreeSet<String>,
    pairs: BTreeSet<(String, String)>,
}

fn contents(text: &str) -> Contents {
    let mut c = Contents::default();
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let Ok(Json::Object(map)) = serde_json::from_str::<Json>(line) else {
            continue;
        };
        if let Some(Json::Object(values)) = map.get("state") {
            for (k, v) in values {
                if !v.is_null() {
                    c.values.entry(k.clone()).or_insert_with(|| v.clone());
                }
            }
        }
        if let Some(Json::Array(items)) = map.get("spatial") {
            for item in items {
                if let Some([Json::String(x), Json::String(y), _]) =
                    item.as_array().map(Vec::as_slice)
                {
                    c.regions.extend([x.clone(), y.clone()]);
                    c.pairs.insert((x.clone(), y.clone()));
                }
            }
        }
    }
    c
}

/// Generic formulas over what a trace contains: its predicates and function terms over time,
/// and spatial atoms over its regions, at the same state and across states. Only those that
/// parse (a key need not be a formula's term).
fn generic(c: &Contents) -> Vec<String> {
    let mut out = Vec::new();
    for (k, v) in &c.values {
        match v {
            Json::Bool(_) => out.extend([
                format!("always {k}"),
                format!("eventually {k}"),
                format!("{k} U[0,1min] !{k}"),
                format!("always[0,1s] ({k} -> next !{k})"),
            ]),
            Json::Number(n) => out.extend([
                format!("always {k} >= {n}"),
                format!("eventually[0,100] {k} < {n}"),
                format!("next ({k} = {n})"),
            ]),
            Json::String(s) => out.push(format!("always {k} = {}", Json::String(s.clone()))),
            _ => {}
        }
    }
    for (x, y) in &c.pairs {
        out.extend([
            format!("always[0,1h] (PO({x}, {y}) || DC({x}, {y}))"),
            format!("eventually EC({x}, {y})"),
            format!("next NTPP({y}, {x})"),
            format!("next EQ(prev {x}, {y})"),
            format!("next^2 DC(prev^2 {x}, prev {y})"),
        ]);
    }
    for x in &c.regions {
        out.extend([
            format!("next EQ(prev {x}, {x})"),
            format!("always[0,1h] next !DC({x}, prev {x})"),
        ]);
    }
    out.retain(|f| parse(f).is_ok());
    out
}

/// A verdict line: formula, verdict, t.
type Line = (usize, String, u64);

/// `dyknow check`'s exit code, verdict lines and standard error.
fn check(trace: &Path, formulas: &[String], flags: &[String]) -> (i32, Vec<Line>, String) {
    let mut cmd = Command::new(BIN);
    cmd.arg("check");
    for f in formulas {
        cmd.args(["--formula", f]);
    }
    let out = cmd.arg("--trace").arg(trace).args(flags).output().unwrap();
    let lines = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            let v: Json = serde_json::from_str(l).unwrap();
            (
                usize::try_from(v["formula"].as_u64().unwrap()).unwrap(),
                v["verdict"].as_str().unwrap().to_owned(),
                v["t"].as_u64().unwrap(),
            )
        })
        .collect();
    (
        out.status.code().unwrap_or(-1),
        lines,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Why the direct path stopped.
#[derive(Debug)]
enum Refusal {
    /// A formula does not compile (an unknown domain).
    Compile(String),
    /// The stream refused a state or a constraint.
    Stream(StreamError),
    /// A line this test cannot decode.
    Decode(String),
}

/// The direct path: the trace decoded here with `serde_json`, then `StateStream` +
/// `Monitor`. The verdict lines written, and why it stopped early, if it did.
fn direct(text: &str, formulas: &[String], flags: &[String]) -> (Vec<Line>, Option<Refusal>) {
    let mut out = Vec::new();
    let refusal = drive(text, formulas, flags, &mut out).err();
    (out, refusal)
}

fn drive(
    text: &str,
    formulas: &[String],
    flags: &[String],
    out: &mut Vec<Line>,
) -> Result<(), Refusal> {
    let mut lines = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| match serde_json::from_str::<Json>(l) {
            Ok(Json::Object(map)) => Ok(map),
            _ => Err(Refusal::Decode(l.to_owned())),
        })
        .peekable();
    let mut domains = BTreeMap::new();
    let mut landmarks = BTreeSet::new();
    let mut statics = BTreeSet::new();
    if let Some(Ok(first)) = lines.peek()
        && !first.is_empty()
        && !["t", "state", "spatial"]
            .iter()
            .any(|k| first.contains_key(*k))
    {
        for (k, v) in first {
            let names = |v: &Json| -> Vec<String> {
                v.as_array()
                    .unwrap()
                    .iter()
                    .map(|s| s.as_str().unwrap().to_owned())
                    .collect()
            };
            match k.as_str() {
                "domains" => {
                    for (d, cs) in v.as_object().unwrap() {
                        domains.insert(d.clone(), names(cs));
                    }
                }
                "landmarks" => landmarks.extend(names(v)),
                "static" => statics.extend(names(v)),
                other => return Err(Refusal::Decode(format!("header key {other}"))),
            }
        }
        lines.next();
    }
    for pair in flags.chunks(2) {
        let [flag, value] = pair else {
            unreachable!("flags come in pairs")
        };
        let list = || {
            value
                .split(',')
                .filter(|s| !s.is_empty())
                .map(str::to_owned)
        };
        match flag.as_str() {
            "--landmarks" => landmarks.extend(list()),
            "--static" => statics.extend(list()),
            "--domain" => {
                // Added to the header's (`mstl.md`): a domain of that name gets the constants
                // it lacks.
                let (name, constants) = value.split_once('=').unwrap();
                let domain: &mut Vec<String> = domains.entry(name.to_owned()).or_default();
                for c in constants.split(',').filter(|c| !c.is_empty()) {
                    if !domain.iter().any(|d| d == c) {
                        domain.push(c.to_owned());
                    }
                }
            }
            other => unreachable!("flag {other}"),
        }
    }
    let mut monitor = Monitor::with_domains(domains);
    for f in formulas {
        monitor
            .add(&parse(f).unwrap())
            .map_err(|e| Refusal::Compile(e.to_string()))?;
    }
    let mut stream = StateStream::new(&landmarks, &statics, monitor.history());
    let mut pending = formulas.len();
    for line in lines {
        let state = decode(line?)?;
        let verdicts = stream.step(&mut monitor, state).map_err(Refusal::Stream)?;
        for v in verdicts {
            out.push((v.formula, v.truth.to_string(), v.t));
        }
        pending -= verdicts.len();
        if pending == 0 {
            break;
        }
    }
    for v in monitor.finish() {
        out.push((v.formula, v.truth.to_string(), v.t));
    }
    Ok(())
}

/// A state line as a `State`.
fn decode(map: Map<String, Json>) -> Result<State, Refusal> {
    let t = map
        .get("t")
        .and_then(|t| {
            t.as_u64()
                .or_else(|| t.as_f64().filter(|f| f.fract() == 0.0).map(|f| f as u64))
        })
        .ok_or_else(|| Refusal::Decode(format!("no t in {map:?}")))?;
    let mut state = State::new(t);
    if let Some(values) = map.get("state") {
        for (k, v) in values.as_object().unwrap() {
            let value = match v {
                Json::Bool(b) => StateValue::Bool(*b),
                Json::Number(n) => StateValue::Number(n.as_f64().unwrap()),
                Json::String(s) => StateValue::Text(s.clone()),
                Json::Null => continue,
                other => return Err(Refusal::Decode(format!("value {other}"))),
            };
            state.values.insert(k.clone(), value);
        }
    }
    if let Some(items) = map.get("spatial") {
        for item in items.as_array().unwrap() {
            let [Json::String(x), Json::String(y), Json::Array(names)] =
                item.as_array().unwrap().as_slice()
            else {
                return Err(Refusal::Decode(format!("constraint {item}")));
            };
            let relation = names
                .iter()
                .map(|n| Relation::from_name(n.as_str().unwrap()).unwrap())
                .fold(Relation::EMPTY, Relation::or);
            state
                .spatial
                .add(x.as_str(), y.as_str(), relation)
                .map_err(Refusal::Stream)?;
        }
    }
    Ok(state)
}

/// Compares the two paths on one trace, formulas and flags: whether both refused the trace,
/// or the mismatch.
fn compare(trace: &Path, formulas: &[String], flags: &[String]) -> Result<bool, String> {
    let text = std::fs::read_to_string(trace).unwrap();
    let (code, checked, stderr) = check(trace, formulas, flags);
    let (lines, refusal) = direct(&text, formulas, flags);
    let place = format!("{} {flags:?} {formulas:?}", trace.display());
    if checked != lines {
        return Err(format!(
            "{place}: dyknow check wrote {checked:?}, the stream gave {lines:?} ({refusal:?})"
        ));
    }
    match (code, refusal) {
        (0, None) => Ok(false),
        (2, Some(Refusal::Stream(e))) => {
            let said = match &e {
                // `dyknow check` adds the lines of the two states.
                StreamError::LandmarkConflict {
                    landmarks,
                    earlier_t,
                    later_t,
                    ..
                } => {
                    stderr.contains(&format!("the landmarks {} ", landmarks.join(", ")))
                        && stderr.contains(&format!("between t={earlier_t} (line "))
                        && stderr.contains(&format!("and t={later_t}: "))
                }
                e => stderr.contains(&e.to_string()),
            };
            said.then_some(true)
                .ok_or_else(|| format!("{place}: dyknow check said {stderr:?}, the stream {e}"))
        }
        (2, Some(Refusal::Compile(e))) if stderr.contains(&e) => Ok(true),
        (_, Some(Refusal::Decode(what))) => Err(format!(
            "{place}: this test cannot decode {what} (dyknow check said {stderr:?})"
        )),
        (code, refusal) => Err(format!(
            "{place}: dyknow check exited {code} ({stderr:?}), the stream stopped with {refusal:?}"
        )),
    }
}

#[test]
fn the_stream_gives_the_same_verdicts_as_dyknow_check_on_every_trace() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../specs/traces");
    let mut traces: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "jsonl"))
        .collect();
    traces.sort();
    assert!(traces.len() >= 16, "{traces:?}");
    let mut failures = Vec::new();
    let (mut runs, mut refused, mut spatial) = (0, 0, 0);
    for trace in &traces {
        let stem = trace.file_stem().unwrap().to_string_lossy().into_owned();
        let text = std::fs::read_to_string(trace).unwrap();
        let contents = contents(&text);
        let (formulas, mut flag_sets) = known(&stem);
        flag_sets.insert(0, vec![]);
        // A landmark and static regions of the trace's own, for spatial traces.
        let regions: Vec<&String> = contents.regions.iter().collect();
        if let [first, second, ..] = regions.as_slice() {
            spatial += 1;
            for flags in [
                vec!["--landmarks".to_owned(), (*first).clone()],
                vec!["--static".to_owned(), format!("{first},{second}")],
            ] {
                if !flag_sets.contains(&flags) {
                    flag_sets.push(flags);
                }
            }
        }
        let mut groups = Vec::new();
        if !formulas.is_empty() {
            groups.push(formulas.clone());
        }
        let mut all = formulas;
        all.extend(generic(&contents));
        groups.push(all);
        for flags in &flag_sets {
            for formulas in &groups {
                runs += 1;
                match compare(trace, formulas, flags) {
                    Ok(both_refused) => refused += usize::from(both_refused),
                    Err(e) => failures.push(e),
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    // The comparison covered refusals (landmark conflicts, an unknown domain) and spatial
    // traces, not only verdicts.
    assert!(
        refused >= 3 && spatial >= 4,
        "{runs} runs, {refused} refused, {spatial} spatial"
    );
}
