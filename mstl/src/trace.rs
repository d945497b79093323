//! Trace files and verdict lines (contract `mstl.md`): JSON lines, an optional header
//! (`domains`, `landmarks`, `static`), then one state per line; [`check`] progresses formulas
//! over them and writes a verdict line as soon as each formula is decided.
//!
//! A thin adapter over the state-stream core ([`StateStream`]): each line is decoded into a
//! [`State`] and taken by the stream, which decides spatial atoms from each state's
//! algebraic closure (`dyknow-rcc8`), with the static regions (the split of Ch. 3.4.2) and the
//! landmarks (Ch. 3.3.3, Defs. 13–15, for atoms over `prev` regions after Theorems 4–5). Its
//! [`StreamError`]s become [`CheckError::Trace`] with the line; a landmark conflict names the
//! later state's line and the earlier state's (the seed's (3.26)). A state may also give a
//! spatial atom directly as a key (`"PO(a,b)": true`), which is read when reasoning leaves the
//! atom undecided.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::io::{BufRead, Write};

use dyknow_rcc8::Relation;
use serde_json::Value as Json;

use crate::Truth;
use crate::compile::{CompileError, Domains};
use crate::monitor::{Monitor, Verdict};
use crate::stream::{SpatialConstraints, State, StateStream, StateValue, StreamError};
use crate::syntax::Formula;

/// What a trace's header (and the command line) declare.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Header {
    /// Named domains for quantifiers.
    pub domains: Domains,
    /// Landmark regions (rigid between consecutive states).
    pub landmarks: BTreeSet<String>,
    /// Static regions (relations among them, once observed, hold in every later state).
    pub static_regions: BTreeSet<String>,
    /// The formulas a formula group progressed over the trace, with the states each was
    /// progressed over (`GET /groups/{label}/trace`): what [`check`] replays when it is given
    /// no formula.
    pub formulas: Vec<HeaderFormula>,
}

/// A formula a trace's header lists: a group's formula, added and perhaps removed while the
/// group ran.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HeaderFormula {
    /// Its index in the group (the verdicts' `formula`).
    pub index: usize,
    /// Its text.
    pub formula: String,
    /// The first state it was progressed over (states are numbered from 0).
    pub from_state: u64,
    /// The first state it was no longer progressed over (it was removed), if any.
    pub until_state: Option<u64>,
}

impl Header {
    /// Adds what `other` declares (`mstl.md`: the flags "add to the header"): a domain of a
    /// name this one has gets the constants it lacks, after its own.
    pub fn extend(&mut self, other: Self) {
        for (name, constants) in other.domains {
            let domain = self.domains.entry(name).or_default();
            for c in constants {
                if !domain.contains(&c) {
                    domain.push(c);
                }
            }
        }
        self.landmarks.extend(other.landmarks);
        self.static_regions.extend(other.static_regions);
        self.formulas.extend(other.formulas);
    }
}

/// A problem with a trace or a formula, located where possible.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// A line of the trace is not valid.
    #[error("line {line}{}: {message}", column.map(|c| format!(", column {c}")).unwrap_or_default())]
    Trace {
        /// 1-based line.
        line: usize,
        /// 1-based column, for JSON syntax errors.
        column: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// A formula cannot be monitored.
    #[error("formula {formula}: {source}")]
    Compile {
        /// The formula's index.
        formula: usize,
        /// Why.
        source: CompileError,
    },
    /// Reading the trace failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// Writing the verdicts failed.
    #[error("writing verdicts: {0}")]
    Output(std::io::Error),
}

/// A line of the trace: its number and its JSON object.
type Line = (usize, serde_json::Map<String, Json>);

/// Reads a trace line by line.
struct Reader<R> {
    input: R,
    line: usize,
    buf: Vec<u8>,
}

/// The most lines one state may span (a pretty-printed state, as the contract's own example
/// wraps one over two lines).
const MAX_LINES_PER_STATE: usize = 1024;

impl<R: BufRead> Reader<R> {
    /// The next line read, as text; `None` at the end of the input.
    fn read_line(&mut self) -> Result<Option<String>, CheckError> {
        self.buf.clear();
        if self.input.read_until(b'\n', &mut self.buf)? == 0 {
            return Ok(None);
        }
        self.line += 1;
        match std::str::from_utf8(&self.buf) {
            Ok(text) => Ok(Some(text.to_owned())),
            Err(e) => {
                let valid = std::str::from_utf8(&self.buf[..e.valid_up_to()]).unwrap_or("");
                Err(CheckError::Trace {
                    line: self.line,
                    column: Some(valid.chars().count() + 1),
                    message: "not UTF-8".to_owned(),
                })
            }
        }
    }

    /// The next JSON object with the number of the line it begins on. One object per line
    /// (JSON lines); one that a line leaves unfinished continues on the next lines (the
    /// contract's example wraps a state over two), up to [`MAX_LINES_PER_STATE`].
    fn next(&mut self) -> Result<Option<Line>, CheckError> {
        let first = loop {
            match self.read_line()? {
                None => return Ok(None),
                Some(text) if text.trim().is_empty() => continue,
                Some(text) => break text,
            }
        };
        let start = self.line;
        let mut text = first.trim_end().to_owned();
        let mut lines = 1;
        loop {
            let error = match serde_json::from_str::<Json>(&text) {
                Ok(Json::Object(map)) => return Ok(Some((start, map))),
                Ok(_) => return Err(trace_error(start, "expected a JSON object")),
                Err(e) => e,
            };
            if error.is_eof()
                && lines < MAX_LINES_PER_STATE
                && let Some(more) = self.read_line()?
            {
                text.push('\n');
                text.push_str(more.trim_end());
                lines += 1;
                continue;
            }
            // serde_json's message ends with its own " at line L column N".
            let message = error.to_string();
            let message = message
                .rfind(" at line ")
                .map_or(&*message, |i| &message[..i]);
            let message = if error.is_eof() && lines > 1 {
                format!("not JSON: {message} (a state spans at most {MAX_LINES_PER_STATE} lines)")
            } else {
                format!("not JSON: {message}")
            };
            return Err(CheckError::Trace {
                line: start + error.line().saturating_sub(1),
                column: Some(error.column()),
                message,
            });
        }
    }
}

/// A formula quoted in a message: at most its first 80 characters (a 25 KB formula was
/// echoed whole in a one-line error).
pub fn quoted(formula: &str) -> String {
    if formula.chars().count() <= 80 {
        format!("{formula:?}")
    } else {
        let head: String = formula.chars().take(80).collect();
        format!("{head:?}…")
    }
}

fn trace_error(line: usize, message: impl Into<String>) -> CheckError {
    CheckError::Trace {
        line,
        column: None,
        message: message.into(),
    }
}

fn strings(line: usize, what: &str, v: &Json) -> Result<Vec<String>, CheckError> {
    let Json::Array(items) = v else {
        return Err(trace_error(
            line,
            format!("{what} must be an array of strings"),
        ));
    };
    items
        .iter()
        .map(|i| {
            i.as_str()
                .map(str::to_owned)
                .ok_or_else(|| trace_error(line, format!("{what} must be an array of strings")))
        })
        .collect()
}

fn header(line: usize, map: &serde_json::Map<String, Json>) -> Result<Header, CheckError> {
    let mut h = Header::default();
    for (k, v) in map {
        match k.as_str() {
            "domains" => {
                let Json::Object(ds) = v else {
                    return Err(trace_error(line, "domains must be an object of arrays"));
                };
                for (name, cs) in ds {
                    h.domains
                        .insert(name.clone(), strings(line, &format!("domain {name}"), cs)?);
                }
            }
            "landmarks" => h.landmarks.extend(strings(line, "landmarks", v)?),
            "static" => h.static_regions.extend(strings(line, "static", v)?),
            "formulas" => h.formulas = header_formulas(line, v)?,
            other => {
                return Err(trace_error(
                    line,
                    format!(
                        "unknown header key '{other}' (expected domains, landmarks, static, \
                         formulas)"
                    ),
                ));
            }
        }
    }
    Ok(h)
}

/// The header's `formulas`: `[{"index", "formula", "from_state"?, "until_state"?}]`.
fn header_formulas(line: usize, v: &Json) -> Result<Vec<HeaderFormula>, CheckError> {
    const SHAPE: &str = "formulas must be an array of {\"index\", \"formula\", \"from_state\"?, \
                         \"until_state\"?} (whole numbers and a string)";
    let Json::Array(items) = v else {
        return Err(trace_error(line, SHAPE));
    };
    let mut out: Vec<HeaderFormula> = Vec::new();
    for item in items {
        let Json::Object(o) = item else {
            return Err(trace_error(line, SHAPE));
        };
        let number = |key: &str| match o.get(key) {
            None | Some(Json::Null) => Ok(None),
            Some(n) => n.as_u64().map(Some).ok_or_else(|| trace_error(line, SHAPE)),
        };
        let (Some(index), Some(Json::String(formula))) = (number("index")?, o.get("formula"))
        else {
            return Err(trace_error(line, SHAPE));
        };
        if let Some(key) = o
            .keys()
            .find(|k| !["index", "formula", "from_state", "until_state"].contains(&k.as_str()))
        {
            return Err(trace_error(line, format!("{SHAPE}; unknown key '{key}'")));
        }
        let index = usize::try_from(index).map_err(|_| trace_error(line, SHAPE))?;
        let from_state = number("from_state")?.unwrap_or(0);
        let until_state = number("until_state")?;
        if until_state.is_some_and(|u| u < from_state) {
            return Err(trace_error(
                line,
                format!("formula {index}: until_state comes before from_state"),
            ));
        }
        if out.iter().any(|f| f.index == index) {
            return Err(trace_error(line, format!("formula index {index} twice")));
        }
        out.push(HeaderFormula {
            index,
            formula: formula.clone(),
            from_state,
            until_state,
        });
    }
    Ok(out)
}

/// A formula [`check`] progresses: its index in the output and the states it is progressed
/// over.
struct Planned {
    id: usize,
    formula: Formula,
    from: u64,
    until: Option<u64>,
}

/// A state line as a [`State`]: its timestamp, values and spatial constraints. Keys are read
/// in the order the line gives them, and the first problem met is reported.
fn state(line: usize, map: serde_json::Map<String, Json>) -> Result<State, CheckError> {
    let mut t = None;
    let mut values = BTreeMap::new();
    let mut spatial = SpatialConstraints::new();
    for (k, v) in map {
        match k.as_str() {
            "t" => {
                // Integers, or floats that hold an integer exactly (below 2^53).
                let n = v.as_u64().or_else(|| {
                    v.as_f64()
                        .filter(|f| f.fract() == 0.0 && *f >= 0.0 && *f < 9_007_199_254_740_992.0)
                        .map(|f| f as u64)
                });
                t = Some(n.ok_or_else(|| {
                    trace_error(line, "t must be a non-negative integer (milliseconds)")
                })?);
            }
            "state" => {
                let Json::Object(items) = v else {
                    return Err(trace_error(line, "state must be an object"));
                };
                for (key, value) in items {
                    let value = match value {
                        Json::Bool(b) => StateValue::Bool(b),
                        Json::Number(n) => {
                            StateValue::Number(exact_number(&n).ok_or_else(|| {
                                trace_error(
                                    line,
                                    format!(
                                        "the value of '{key}', {n}, is an integer no double holds \
                                     exactly (beyond 2^53): numbers compare as doubles; give it \
                                     as a string"
                                    ),
                                )
                            })?)
                        }
                        Json::String(s) => StateValue::Text(s),
                        // Null: unknown, as if absent.
                        Json::Null => continue,
                        _ => {
                            return Err(trace_error(
                                line,
                                format!(
                                    "the value of '{key}' must be a boolean, a number, a string or null"
                                ),
                            ));
                        }
                    };
                    values.insert(key, value);
                }
            }
            "spatial" => {
                let Json::Array(items) = v else {
                    return Err(trace_error(line, "spatial must be an array"));
                };
                for item in items {
                    constraint(line, &item, &mut spatial)?;
                }
            }
            other => {
                return Err(trace_error(
                    line,
                    format!("unknown key '{other}' (a state has t, state, spatial)"),
                ));
            }
        }
    }
    let t = t.ok_or_else(|| trace_error(line, "a state needs t (its timestamp in ms)"))?;
    Ok(State { t, values, spatial })
}

/// A spatial constraint `[x, y, [relations]]`, added to the state's.
fn constraint(
    line: usize,
    item: &Json,
    spatial: &mut SpatialConstraints,
) -> Result<(), CheckError> {
    let bad = || {
        trace_error(
            line,
            format!("a spatial constraint must be [x, y, [relations]], not {item}"),
        )
    };
    let Json::Array(parts) = item else {
        return Err(bad());
    };
    let [Json::String(x), Json::String(y), Json::Array(names)] = parts.as_slice() else {
        return Err(bad());
    };
    let mut relation = Relation::EMPTY;
    for n in names {
        let r = n
            .as_str()
            .and_then(Relation::from_name)
            .ok_or_else(|| trace_error(line, format!("{n} is not an RCC-8 relation")))?;
        relation = relation.or(r);
    }
    spatial
        .add(x.as_str(), y.as_str(), relation)
        .map_err(|e| match e {
            StreamError::NoRelation { .. } => trace_error(
                line,
                format!("{item}: no relation is possible (a region is EQ to itself)"),
            ),
            e => trace_error(line, e.to_string()),
        })
}

/// Whether a line is a header: it has no `t` and only header keys.
fn is_header(map: &serde_json::Map<String, Json>) -> bool {
    !map.contains_key("t")
        && !map.contains_key("state")
        && !map.contains_key("spatial")
        && !map.is_empty()
}

/// Progresses `formulas` over the trace read from `input` and writes one verdict line per
/// formula as soon as it is decided (flushed at once, so a piped stream sees it), then an
/// `unknown` line at the end for each formula still undecided. `extra` adds to the trace's
/// header (the command line's `--domain`, `--landmarks`, `--static`). Stops reading once every
/// formula is decided. Returns the verdicts in the order written.
///
/// Given no formula, it replays those the header lists (a formula group's trace), each over
/// the states the group progressed it over and with the group's index, so the verdicts are
/// the group's (`groups.md`); a trace whose header lists none is an error.
pub fn check<R: BufRead, W: Write>(
    formulas: &[Formula],
    input: R,
    extra: Header,
    out: &mut W,
) -> Result<Vec<Verdict>, CheckError> {
    let mut reader = Reader {
        input,
        line: 0,
        buf: Vec::new(),
    };
    let mut first = reader.next()?;
    let mut h = Header::default();
    let mut header_line = 1;
    if let Some((line, map)) = &first
        && is_header(map)
    {
        h = header(*line, map)?;
        header_line = *line;
        first = reader.next()?;
    }
    h.extend(extra);
    let mut planned: Vec<Planned> = if formulas.is_empty() {
        if h.formulas.is_empty() {
            return Err(trace_error(
                header_line,
                "no formula to check: give some, or a trace whose header lists formulas (a \
                 formula group's trace)",
            ));
        }
        h.formulas
            .iter()
            .map(|f| {
                crate::parse(&f.formula)
                    .map(|formula| Planned {
                        id: f.index,
                        formula,
                        from: f.from_state,
                        until: f.until_state,
                    })
                    .map_err(|e| {
                        trace_error(
                            header_line,
                            format!(
                                "formula {} of the header, {}: {e}",
                                f.index,
                                quoted(&f.formula)
                            ),
                        )
                    })
            })
            .collect::<Result<_, _>>()?
    } else {
        formulas
            .iter()
            .enumerate()
            .map(|(id, f)| Planned {
                id,
                formula: f.clone(),
                from: 0,
                until: None,
            })
            .collect()
    };
    // Added in the order the group added them (its indices grow with time).
    planned.sort_by_key(|p| (p.from, p.id));
    let mut monitor = Monitor::with_domains(h.domains.clone());
    // The output index of each formula the monitor has, by its own index.
    let mut ids: Vec<usize> = Vec::new();
    let mut added = 0;
    let mut add_due = |monitor: &mut Monitor, ids: &mut Vec<usize>, k: u64| {
        while let Some(p) = planned.get(added).filter(|p| p.from <= k) {
            monitor
                .add(&p.formula)
                .map_err(|source| CheckError::Compile {
                    formula: p.id,
                    source,
                })?;
            ids.push(p.id);
            added += 1;
        }
        Ok::<_, CheckError>(())
    };
    add_due(&mut monitor, &mut ids, 0)?;
    // Output indices by the state they are removed before.
    let mut removals: BTreeMap<u64, Vec<usize>> = BTreeMap::new();
    for p in &planned {
        if let Some(u) = p.until {
            removals.entry(u).or_default().push(p.id);
        }
    }
    // Stops progressing formula `id` unless it was decided (or removed) already.
    let remove = |monitor: &mut Monitor, ids: &[usize], done: &mut BTreeSet<usize>, id: usize| {
        if let Some(m) = ids.iter().position(|i| *i == id)
            && done.insert(id)
        {
            monitor.remove(m);
        }
    };
    let total = planned.len();
    let mut stream = StateStream::new(&h.landmarks, &h.static_regions, monitor.history());
    // The lines of the states the stream keeps, by state number: a landmark conflict names
    // the earlier state's line.
    let mut lines = Lines::default();
    let mut all = Vec::new();
    // Formulas decided or removed.
    let mut done: BTreeSet<usize> = BTreeSet::new();
    let mut next = first;
    let mut k: u64 = 0;
    while let Some((line, map)) = next {
        add_due(&mut monitor, &mut ids, k)?;
        for id in removals.get(&k).into_iter().flatten() {
            remove(&mut monitor, &ids, &mut done, *id);
        }
        let s = state(line, map)?;
        lines.push(stream.states(), line, stream.keep());
        let verdicts = stream
            .step(&mut monitor, s)
            .map_err(|e| lines.error(line, e))?;
        for v in verdicts {
            let v = Verdict {
                formula: ids[v.formula],
                ..*v
            };
            write_verdict(out, &v).map_err(CheckError::Output)?;
            done.insert(v.formula);
            all.push(v);
        }
        if !verdicts.is_empty() {
            out.flush().map_err(CheckError::Output)?;
        }
        if done.len() == total {
            // Every formula is decided: read no further (a live stream may never end).
            break;
        }
        k += 1;
        next = reader.next()?;
    }
    // Formulas added after the last state (and not removed) are undecided too.
    add_due(&mut monitor, &mut ids, u64::MAX)?;
    for id in removals.range(..=k).flat_map(|(_, ids)| ids) {
        remove(&mut monitor, &ids, &mut done, *id);
    }
    for v in monitor.finish() {
        let v = Verdict {
            formula: ids[v.formula],
            ..v
        };
        write_verdict(out, &v).map_err(CheckError::Output)?;
        all.push(v);
    }
    out.flush().map_err(CheckError::Output)?;
    Ok(all)
}

/// The lines of the last states taken, by state number.
#[derive(Debug, Default)]
struct Lines {
    /// `(state number, line)`, oldest first.
    kept: VecDeque<(u64, usize)>,
}

impl Lines {
    /// Records that state number `k` is on `line`, keeping as many as the stream does (and
    /// the state being taken).
    fn push(&mut self, k: u64, line: usize, keep: usize) {
        self.kept.push_back((k, line));
        while self.kept.len() > keep.saturating_add(1) {
            self.kept.pop_front();
        }
    }

    /// The line of state number `k`.
    fn line(&self, k: u64) -> Option<usize> {
        self.kept.iter().find(|(n, _)| *n == k).map(|(_, l)| *l)
    }

    /// A stream error on the state at `line` as a trace error: a landmark conflict is
    /// reported at the later state's line and names the earlier state's line.
    fn error(&self, line: usize, e: StreamError) -> CheckError {
        match e {
            StreamError::LandmarkConflict {
                landmarks,
                earlier_t,
                later_t,
                earlier_state,
                later_state,
            } => {
                let at = |k| {
                    self.line(k)
                        .map_or_else(|| "?".to_owned(), |l| l.to_string())
                };
                trace_error(
                    self.line(later_state).unwrap_or(line),
                    format!(
                        "the landmarks {} cannot all be rigid between t={earlier_t} (line {}) and t={later_t}: \
                         the observations contradict it (seed (3.26)); declare fewer landmarks",
                        landmarks.join(", "),
                        at(earlier_state),
                    ),
                )
            }
            e => trace_error(line, e.to_string()),
        }
    }
}

fn write_verdict<W: Write>(out: &mut W, v: &Verdict) -> std::io::Result<()> {
    writeln!(
        out,
        "{{\"formula\": {}, \"verdict\": \"{}\", \"t\": {}}}",
        v.formula, v.truth, v.t
    )
}

/// A JSON number as the double it is compared as; `None` for an integer no double holds
/// exactly (beyond 2^53), which would compare as another number.
pub fn exact_number(n: &serde_json::Number) -> Option<f64> {
    if let Some(u) = n.as_u64() {
        let f = u as f64;
        return (f as u128 == u128::from(u)).then_some(f);
    }
    if let Some(i) = n.as_i64() {
        let f = i as f64;
        return (f as i128 == i128::from(i)).then_some(f);
    }
    n.as_f64()
}

/// Parses `NAME=a,b` (the command line's `--domain`).
pub fn parse_domain(arg: &str) -> Result<(String, Vec<String>), String> {
    let (name, constants) = arg
        .split_once('=')
        .ok_or_else(|| format!("--domain {arg}: expected NAME=a,b,..."))?;
    if name.trim().is_empty() {
        return Err(format!("--domain {arg}: the domain needs a name"));
    }
    // `NAME=` is the empty domain; otherwise no constant is empty (`E=a,,b`, `E=,a` name a
    // constant "", which the header refuses too: `mstl.md`).
    if constants.trim().is_empty() {
        return Ok((name.trim().to_owned(), Vec::new()));
    }
    let constants: Vec<String> = constants
        .split(',')
        .map(str::trim)
        .map(str::to_owned)
        .collect();
    if let Some(k) = constants.iter().position(String::is_empty) {
        return Err(format!(
            "--domain {arg}: constant {} is empty (a constant is not empty)",
            k + 1
        ));
    }
    Ok((name.trim().to_owned(), constants))
}

/// The verdicts as a map from formula index to (truth, t), for tests and tools.
pub fn by_formula(verdicts: &[Verdict]) -> BTreeMap<usize, (Truth, u64)> {
    verdicts
        .iter()
        .map(|v| (v.formula, (v.truth, v.t)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::parse_domain;

    #[test]
    fn integers_beyond_what_a_double_holds_are_not_numbers() {
        use super::exact_number;
        let n = |text: &str| -> serde_json::Number { serde_json::from_str(text).unwrap() };
        assert_eq!(
            exact_number(&n("9007199254740992")),
            Some(9_007_199_254_740_992.0)
        );
        assert_eq!(exact_number(&n("1152921504606846976")), Some(2f64.powi(60)));
        assert_eq!(exact_number(&n("-42")), Some(-42.0));
        assert_eq!(exact_number(&n("0.5")), Some(0.5));
        for text in [
            "9007199254740993",
            "18446744073709551615",
            "-9007199254740993",
        ] {
            assert_eq!(exact_number(&n(text)), None, "{text}");
        }
    }

    /// The contract's own example wraps a state over two lines: read as one state. A state
    /// left unfinished at the end is an error at the line where the input ran out.
    #[test]
    fn a_state_may_span_lines() {
        use super::{CheckError, Header, check};
        let run = |trace: &str, formula: &str| {
            let f = crate::parse(formula).unwrap();
            let mut out = Vec::new();
            check(&[f], trace.as_bytes(), Header::default(), &mut out)
                .map(|_| String::from_utf8(out).unwrap())
        };
        let contract = r#"{"domains": {"UAV": ["uav1", "uav2"]}, "landmarks": ["office"], "static": ["office", "canteen", "desk"]}
{"t": 0,   "state": {"p": true, "altitude(uav1)": 52.5, "InsideCircle(ball)": true},
           "spatial": [["student", "office", ["NTPP"]], ["canteen", "office", ["DC"]]]}
{"t": 100, "state": {"p": false}}
"#;
        assert_eq!(
            run(contract, "always p").unwrap(),
            "{\"formula\": 0, \"verdict\": \"false\", \"t\": 100}\n"
        );
        assert_eq!(
            run(contract, "NTPP(student, office) && altitude(uav1) > 50").unwrap(),
            "{\"formula\": 0, \"verdict\": \"true\", \"t\": 0}\n"
        );
        // The error is where the JSON goes wrong, counted in lines of the whole input.
        let error = |trace: &str| match run(trace, "always p") {
            Err(CheckError::Trace { line, column, .. }) => (line, column),
            other => panic!("{other:?}"),
        };
        assert_eq!(
            error("{\"t\": 0, \"state\": {\"p\": true}\n{\"t\": 1}\n"),
            (2, Some(1))
        );
        assert_eq!(
            error("{\"t\": 0, \"state\": {\"p\": true}}\n\n{\"t\": 5, \"state\":\n"),
            (3, Some(17))
        );
    }

    /// Given no formula, the header's formulas are replayed, each over the states it lists,
    /// with its own index: a group's formula added or removed while it ran decides as it did.
    #[test]
    fn the_formulas_of_the_header_are_replayed_over_their_states() {
        use super::{CheckError, Header, check};
        let run = |trace: &str| {
            let mut out = Vec::new();
            check(&[], trace.as_bytes(), Header::default(), &mut out)
                .map(|_| String::from_utf8(out).unwrap())
        };
        let states = "{\"t\":0,\"state\":{\"p\":true,\"q\":true}}
{\"t\":10,\"state\":{\"p\":true,\"q\":false}}
{\"t\":20,\"state\":{\"p\":true,\"q\":false}}
{\"t\":30,\"state\":{\"p\":false,\"q\":true}}
";
        let header = r#"{"formulas": [{"index": 0, "formula": "always p"},
            {"index": 4, "formula": "p && !q", "from_state": 2},
            {"index": 5, "formula": "eventually q", "from_state": 1, "until_state": 3},
            {"index": 6, "formula": "q", "from_state": 4}]}"#
            .replace('\n', " ");
        assert_eq!(
            run(&format!("{header}\n{states}")).unwrap(),
            // 4 from the third state on: true at once (from the first: false). 5 was removed
            // before it could see q (from the first state it is true at once): no verdict. 6
            // was added after the last state: unknown at the end.
            "{\"formula\": 4, \"verdict\": \"true\", \"t\": 20}\n\
             {\"formula\": 0, \"verdict\": \"false\", \"t\": 30}\n\
             {\"formula\": 6, \"verdict\": \"unknown\", \"t\": 30}\n"
        );
        // No formula anywhere, or a header that is not of that shape: errors.
        assert!(matches!(
            run(states),
            Err(CheckError::Trace { line: 1, .. })
        ));
        for bad in [
            r#"{"formulas": [{"index": 0}]}"#,
            r#"{"formulas": [{"index": 0, "formula": "p", "from_state": 3, "until_state": 1}]}"#,
            r#"{"formulas": [{"index": 0, "formula": "p"}, {"index": 0, "formula": "q"}]}"#,
            r#"{"formulas": [{"index": 0, "formula": "p", "since": 1}]}"#,
            r#"{"formulas": [{"index": 0, "formula": "p &&"}]}"#,
        ] {
            assert!(
                matches!(
                    run(&format!("{bad}\n{states}")),
                    Err(CheckError::Trace { line: 1, .. })
                ),
                "{bad}"
            );
        }
    }

    #[test]
    fn a_domain_argument_names_no_empty_constant() {
        assert_eq!(
            parse_domain("UAV=uav1, uav2"),
            Ok(("UAV".to_owned(), vec!["uav1".to_owned(), "uav2".to_owned()]))
        );
        assert_eq!(parse_domain("E="), Ok(("E".to_owned(), Vec::new())));
        for arg in ["E=,", "E=a,,b", "E=,a", "E=a,"] {
            let error = parse_domain(arg).unwrap_err();
            assert!(error.contains("is empty"), "{arg}: {error}");
        }
        assert!(parse_domain("=a").is_err());
        assert!(parse_domain("E").is_err());
    }
}
