//! Trace files and verdict lines (contract `mstl.md`): JSON lines, an optional header
//! (`domains`, `landmarks`, `static`), then one state per line; [`check`] progresses formulas
//! over them and writes a verdict line as soon as each formula is decided.
//!
//! Spatial atoms are decided from the algebraic closure (`dyknow-rcc8`) of what the state
//! observes: the relations listed in `spatial`, with those observed earlier between two
//! `static` regions carried forward. Exactly `{R}` makes `R(x, y)` true, a set without `R`
//! makes it false. A state may also give a spatial atom directly as a key (`"PO(a,b)": true`).
//! Relations across states through landmarks are still to come: such atoms are unknown unless
//! given as keys, which is sound.

use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, Write};

use dyknow_rcc8::Relation;
use rustc_hash::FxHashMap;
use serde_json::Value as Json;

use crate::Truth;
use crate::atom::{Valuation, Value};
use crate::compile::{CompileError, Domains};
use crate::monitor::{Monitor, StepError, Verdict};
use crate::syntax::{Formula, Rcc8, Region};

/// What a trace's header (and the command line) declare.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Header {
    /// Named domains for quantifiers.
    pub domains: Domains,
    /// Landmark regions (rigid between consecutive states).
    pub landmarks: BTreeSet<String>,
    /// Static regions (relations among them, once observed, hold in every later state).
    pub static_regions: BTreeSet<String>,
}

impl Header {
    /// Adds what `other` declares (domains of the same name are replaced).
    pub fn extend(&mut self, other: Self) {
        self.domains.extend(other.domains);
        self.landmarks.extend(other.landmarks);
        self.static_regions.extend(other.static_regions);
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

/// A set of RCC-8 relations as `dyknow_rcc8::Relation`'s bits (in `Rcc8`'s variant order).
type Rels = u8;

fn bit(r: Rcc8) -> Rels {
    Relation::BASE[r as usize].0
}

/// A state of a trace, as a [`Valuation`].
#[derive(Debug, Default)]
pub struct TraceState {
    values: FxHashMap<String, Owned>,
    /// Observed relations, keyed by the ordered pair (the smaller name first).
    spatial: FxHashMap<(String, String), Rels>,
    /// The algebraic closure of the observed relations, over the regions they mention.
    closure: Option<(FxHashMap<String, usize>, dyknow_rcc8::Network)>,
}

#[derive(Debug, Clone)]
enum Owned {
    Bool(bool),
    Number(f64),
    Text(String),
}

impl TraceState {
    fn relations(&self, x: &str, y: &str) -> Option<Rels> {
        if x == y {
            return Some(bit(Rcc8::Eq));
        }
        // Every observed pair is in the closure; a region never observed has no relation.
        let (index, network) = self.closure.as_ref()?;
        let r = network.get(*index.get(x)?, *index.get(y)?);
        (r != Relation::UNIVERSAL).then_some(r.0)
    }
}

impl Valuation for TraceState {
    fn value(&self, key: &str) -> Option<Value<'_>> {
        self.values.get(key).map(|v| match v {
            Owned::Bool(b) => Value::Bool(*b),
            Owned::Number(n) => Value::Number(*n),
            Owned::Text(s) => Value::Text(s),
        })
    }

    fn spatial(&self, relation: Rcc8, left: &Region, right: &Region, key: &str) -> Truth {
        if left.offset == 0
            && right.offset == 0
            && let Some(rels) = self.relations(&left.name, &right.name)
        {
            if rels == bit(relation) {
                return Truth::True;
            }
            if rels & bit(relation) == 0 {
                return Truth::False;
            }
        }
        match self.value(key) {
            Some(Value::Bool(b)) => Truth::from(b),
            _ => Truth::Unknown,
        }
    }
}

/// A line of the trace: its number and its JSON object.
type Line = (usize, serde_json::Map<String, Json>);

/// Reads a trace line by line.
struct Reader<R> {
    input: R,
    line: usize,
    buf: String,
}

impl<R: BufRead> Reader<R> {
    /// The next non-blank line as JSON, with its number.
    fn next(&mut self) -> Result<Option<Line>, CheckError> {
        loop {
            self.buf.clear();
            if self.input.read_line(&mut self.buf)? == 0 {
                return Ok(None);
            }
            self.line += 1;
            if self.buf.trim().is_empty() {
                continue;
            }
            let line = self.line;
            return match serde_json::from_str::<Json>(self.buf.trim_end()) {
                Ok(Json::Object(map)) => Ok(Some((line, map))),
                Ok(_) => Err(trace_error(line, "expected a JSON object")),
                Err(e) => {
                    // serde_json's message ends with its own " at line 1 column N".
                    let text = e.to_string();
                    let text = text.rfind(" at line ").map_or(&*text, |i| &text[..i]);
                    Err(CheckError::Trace {
                        line,
                        column: Some(e.column()),
                        message: format!("not JSON: {text}"),
                    })
                }
            };
        }
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
            other => {
                return Err(trace_error(
                    line,
                    format!("unknown header key '{other}' (expected domains, landmarks, static)"),
                ));
            }
        }
    }
    Ok(h)
}

/// A state line: its timestamp, values and spatial observations.
fn state(
    line: usize,
    map: serde_json::Map<String, Json>,
    statics: &BTreeSet<String>,
    carried: &mut FxHashMap<(String, String), Rels>,
) -> Result<(u64, TraceState), CheckError> {
    let mut t = None;
    let mut out = TraceState::default();
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
                let Json::Object(values) = v else {
                    return Err(trace_error(line, "state must be an object"));
                };
                for (key, value) in values {
                    let owned = match value {
                        Json::Bool(b) => Owned::Bool(b),
                        Json::Number(n) => Owned::Number(n.as_f64().unwrap_or(f64::NAN)),
                        Json::String(s) => Owned::Text(s),
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
                    out.values.insert(key, owned);
                }
            }
            "spatial" => {
                let Json::Array(items) = v else {
                    return Err(trace_error(line, "spatial must be an array"));
                };
                for item in items {
                    let bad = || {
                        trace_error(
                            line,
                            format!("a spatial constraint must be [x, y, [relations]], not {item}"),
                        )
                    };
                    let Json::Array(parts) = &item else {
                        return Err(bad());
                    };
                    let [Json::String(x), Json::String(y), Json::Array(names)] = parts.as_slice()
                    else {
                        return Err(bad());
                    };
                    let mut rels: Rels = 0;
                    for n in names {
                        let r = n.as_str().and_then(Relation::from_name).ok_or_else(|| {
                            trace_error(line, format!("{n} is not an RCC-8 relation"))
                        })?;
                        rels |= r.0;
                    }
                    if x == y && rels & bit(Rcc8::Eq) == 0 || rels == 0 {
                        return Err(trace_error(
                            line,
                            format!("{item}: no relation is possible (a region is EQ to itself)"),
                        ));
                    }
                    let (pair, rels) = if x <= y {
                        ((x.clone(), y.clone()), rels)
                    } else {
                        ((y.clone(), x.clone()), Relation(rels).converse().0)
                    };
                    let entry = out.spatial.entry(pair.clone()).or_insert(Rels::MAX);
                    *entry &= rels;
                    if *entry == 0 {
                        return Err(trace_error(
                            line,
                            format!(
                                "the constraints between {} and {} contradict each other",
                                pair.0, pair.1
                            ),
                        ));
                    }
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
    // Static regions: what was observed between two of them holds from then on.
    for (pair, rels) in &out.spatial {
        if statics.contains(&pair.0) && statics.contains(&pair.1) {
            let held = carried.entry(pair.clone()).or_insert(Rels::MAX);
            if *held & *rels == 0 {
                return Err(trace_error(
                    line,
                    format!(
                        "{} and {} are static, and this contradicts what was observed between them before",
                        pair.0, pair.1
                    ),
                ));
            }
            *held &= *rels;
        }
    }
    for (pair, rels) in carried.iter() {
        *out.spatial.entry(pair.clone()).or_insert(Rels::MAX) &= *rels;
    }
    // The closure infers what was not observed (seed Ch. 3.3): the contract's "exactly {R}
    // after algebraic closure". The bit order of both crates is DC, EC, PO, EQ, TPP, NTPP,
    // TPPI, NTPPI.
    if !out.spatial.is_empty() {
        let mut index: FxHashMap<String, usize> = FxHashMap::default();
        for (a, b) in out.spatial.keys() {
            for r in [a, b] {
                let next = index.len();
                index.entry(r.clone()).or_insert(next);
            }
        }
        let mut network = dyknow_rcc8::Network::new(index.len());
        for ((a, b), rels) in &out.spatial {
            network.constrain(index[a], index[b], Relation(*rels));
        }
        if let Err(e) = network.algebraic_closure() {
            let name = |k: usize| {
                index
                    .iter()
                    .find(|(_, v)| **v == k)
                    .map_or("?", |(n, _)| n.as_str())
                    .to_owned()
            };
            return Err(trace_error(
                line,
                format!(
                    "the spatial constraints are inconsistent: no relation is possible between {} and {}",
                    name(e.0),
                    name(e.1)
                ),
            ));
        }
        out.closure = Some((index, network));
    }
    Ok((t, out))
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
pub fn check<R: BufRead, W: Write>(
    formulas: &[Formula],
    input: R,
    extra: Header,
    out: &mut W,
) -> Result<Vec<Verdict>, CheckError> {
    let mut reader = Reader {
        input,
        line: 0,
        buf: String::new(),
    };
    let mut first = reader.next()?;
    let mut h = Header::default();
    if let Some((line, map)) = &first
        && is_header(map)
    {
        h = header(*line, map)?;
        first = reader.next()?;
    }
    h.extend(extra);
    let mut monitor = Monitor::with_domains(h.domains.clone());
    for (i, f) in formulas.iter().enumerate() {
        monitor
            .add(f)
            .map_err(|source| CheckError::Compile { formula: i, source })?;
    }
    let mut carried = FxHashMap::default();
    let mut all = Vec::new();
    let mut pending = formulas.len();
    let mut next = first;
    while let Some((line, map)) = next {
        let (t, s) = state(line, map, &h.static_regions, &mut carried)?;
        let verdicts = monitor.step(t, &s).map_err(|e| match e {
            StepError::NotIncreasing { .. } | StepError::Finished => {
                trace_error(line, e.to_string())
            }
        })?;
        for v in verdicts {
            write_verdict(out, v).map_err(CheckError::Output)?;
            all.push(*v);
        }
        if !verdicts.is_empty() {
            pending -= verdicts.len();
            out.flush().map_err(CheckError::Output)?;
        }
        if pending == 0 {
            // Every formula is decided: read no further (a live stream may never end).
            break;
        }
        next = reader.next()?;
    }
    for v in monitor.finish() {
        write_verdict(out, &v).map_err(CheckError::Output)?;
        all.push(v);
    }
    out.flush().map_err(CheckError::Output)?;
    Ok(all)
}

fn write_verdict<W: Write>(out: &mut W, v: &Verdict) -> std::io::Result<()> {
    writeln!(
        out,
        "{{\"formula\": {}, \"verdict\": \"{}\", \"t\": {}}}",
        v.formula, v.truth, v.t
    )
}

/// Parses `NAME=a,b` (the command line's `--domain`).
pub fn parse_domain(arg: &str) -> Result<(String, Vec<String>), String> {
    let (name, constants) = arg
        .split_once('=')
        .ok_or_else(|| format!("--domain {arg}: expected NAME=a,b,..."))?;
    if name.trim().is_empty() {
        return Err(format!("--domain {arg}: the domain needs a name"));
    }
    let constants: Vec<String> = constants
        .split(',')
        .map(str::trim)
        .filter(|c| !c.is_empty())
        .map(str::to_owned)
        .collect();
    Ok((name.trim().to_owned(), constants))
}

/// The verdicts as a map from formula index to (truth, t), for tests and tools.
pub fn by_formula(verdicts: &[Verdict]) -> BTreeMap<usize, (Truth, u64)> {
    verdicts
        .iter()
        .map(|v| (v.formula, (v.truth, v.t)))
        .collect()
}
