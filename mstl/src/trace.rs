//! Trace files and verdict lines (contract `mstl.md`): JSON lines, an optional header
//! (`domains`, `landmarks`, `static`), then one state per line; [`check`] progresses formulas
//! over them and writes a verdict line as soon as each formula is decided.
//!
//! Spatial atoms are decided from the algebraic closure (`dyknow-rcc8`) of what the state
//! observes: the relations listed in `spatial`, with what earlier states observed or inferred
//! between two `static` regions (closed once and refined, the split of Ch. 3.4.2), and between
//! two landmarks (through the previous state: they are rigid). Exactly `{R}` makes `R(x, y)` true, a set without `R` makes
//! it false. Atoms over `prev` regions (what Theorems 4–5 make of `next`) relate regions at two
//! states through the extended spatial relation matrix of those states (seed Def. 13) with the
//! landmarks rigid between them (Defs. 14–15): without landmarks nothing is known across time.
//! Landmarks that the observations of two consecutive states contradict (the seed's (3.26))
//! are reported as an error naming a minimal set of them; so is a contradiction between states
//! further apart, found when an atom relates them. A state may also give a spatial atom directly as a key
//! (`"PO(a,b)": true`), which is read when reasoning leaves the atom undecided.

use std::cell::RefCell;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::io::{BufRead, Write};
use std::rc::Rc;

use dyknow_rcc8::{Extended, Network, Relation, Split};
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

/// A state's spatial knowledge: the algebraic closure of its constraints (observed, and what
/// is known between static regions), over the static regions and those it mentions (and,
/// once refined through the previous state, the landmarks).
#[derive(Debug)]
struct Closure {
    index: FxHashMap<String, usize>,
    network: Network,
}

impl Closure {
    /// The relation between two regions, `None` when one of them is not mentioned.
    fn get(&self, x: &str, y: &str) -> Option<Relation> {
        if x == y {
            return Some(Relation::EQ);
        }
        Some(self.network.get(*self.index.get(x)?, *self.index.get(y)?))
    }
}

/// A state of a trace: its values and spatial knowledge.
#[derive(Debug, Default)]
struct TraceState {
    values: FxHashMap<String, Owned>,
    /// Observed relations, keyed by the ordered pair (the smaller name first).
    spatial: FxHashMap<(String, String), Rels>,
    closure: Option<Rc<Closure>>,
}

#[derive(Debug, Clone)]
enum Owned {
    Bool(bool),
    Number(f64),
    Text(String),
}

/// The current state and earlier states' spatial knowledge, with the extended matrices
/// between them: what `Valuation::spatial` needs for atoms over `prev` regions.
#[derive(Debug, Default)]
struct Timeline {
    /// The last `keep` states (oldest first; the last is the current one): line, t, closure.
    states: VecDeque<(usize, u64, Option<Rc<Closure>>)>,
    keep: usize,
    /// States taken so far; the current state is number `count - 1`.
    count: u64,
    landmarks: Vec<String>,
    /// Extended matrices between two states (by number), built on demand.
    linked: RefCell<FxHashMap<(u64, u64), Rc<Linked>>>,
    /// A landmark conflict found while deciding an atom, reported after the step.
    conflict: RefCell<Option<CheckError>>,
}

/// The extended spatial relation matrix of two states, over the regions either mentions and
/// the landmarks.
#[derive(Debug)]
struct Linked {
    index: FxHashMap<String, usize>,
    matrix: Extended,
}

impl Timeline {
    fn new(keep: usize, landmarks: &BTreeSet<String>) -> Self {
        Self {
            keep: keep.max(1),
            landmarks: landmarks.iter().cloned().collect(),
            ..Self::default()
        }
    }

    /// Takes the next state, forgetting what lies beyond the history kept.
    fn push(&mut self, line: usize, t: u64, closure: Option<Rc<Closure>>) {
        self.states.push_back((line, t, closure));
        self.count += 1;
        while self.states.len() > self.keep {
            self.states.pop_front();
        }
        let oldest = self.count - self.states.len() as u64;
        self.linked.get_mut().retain(|(p, _), _| *p >= oldest);
    }

    /// With landmarks, links the current state to the previous one (reporting a conflict) and
    /// replaces the current state's closure by the extended matrix's second block over its
    /// regions and the landmarks: what rigid landmarks carry over from earlier states (the
    /// relations between them, observed or inferred) refines the present.
    fn refine(&mut self) -> Result<(), CheckError> {
        if self.landmarks.is_empty() || self.count < 2 {
            return Ok(());
        }
        let Some(linked) = self.link(self.count - 2, self.count - 1)? else {
            return Ok(());
        };
        let Some(current) = self.states.back_mut() else {
            return Ok(());
        };
        let mut index = FxHashMap::default();
        number(
            &mut index,
            current
                .2
                .iter()
                .flat_map(|c| c.index.keys())
                .chain(&self.landmarks),
        );
        let mut network = Network::new(index.len());
        for (a, &i) in &index {
            for (b, &j) in &index {
                if i < j {
                    network.set(i, j, linked.matrix.after(linked.index[a], linked.index[b]));
                }
            }
        }
        current.2 = Some(Rc::new(Closure { index, network }));
        Ok(())
    }

    /// State number `k`, if still kept.
    fn at(&self, k: u64) -> Option<&(usize, u64, Option<Rc<Closure>>)> {
        let oldest = self.count.checked_sub(self.states.len() as u64)?;
        let i = usize::try_from(k.checked_sub(oldest)?).ok()?;
        self.states.get(i)
    }

    /// The number of the state at `offset` (≤ 0: Theorems 4–5 leave no look-ahead) from the
    /// current one.
    fn back(&self, offset: i32) -> Option<u64> {
        debug_assert!(offset <= 0, "atoms never look ahead after Theorems 4–5");
        (self.count.checked_sub(1)?).checked_sub(u64::from(offset.unsigned_abs()))
    }

    /// The relation between two region terms (offsets ≤ 0), `None` when unknown.
    fn relation(&self, left: &Region, right: &Region) -> Option<Relation> {
        let (p, q) = (self.back(left.offset)?, self.back(right.offset)?);
        if p == q {
            let (_, _, closure) = self.at(p)?;
            return closure.as_ref()?.get(&left.name, &right.name);
        }
        // M^{p,q} relates the earlier state's region to the later one's.
        let (early, late, x, y) = if p < q {
            (p, q, left, right)
        } else {
            (q, p, right, left)
        };
        if self.landmarks.is_empty() {
            // No frame of reference: nothing relates two states ((3.29)).
            return None;
        }
        let linked = match self.link(early, late) {
            Ok(linked) => linked?,
            Err(e) => {
                self.conflict.borrow_mut().get_or_insert(e);
                return None;
            }
        };
        let r = linked
            .matrix
            .across(*linked.index.get(&x.name)?, *linked.index.get(&y.name)?);
        Some(if p < q { r } else { r.converse() })
    }

    /// The extended matrix of states `p < q` with the landmarks rigid between them (built
    /// once), `Ok(None)` when a state is no longer kept.
    fn link(&self, p: u64, q: u64) -> Result<Option<Rc<Linked>>, CheckError> {
        if let Some(done) = self.linked.borrow().get(&(p, q)) {
            return Ok(Some(done.clone()));
        }
        let (Some(early), Some(late)) = (self.at(p), self.at(q)) else {
            return Ok(None);
        };
        let mut index = FxHashMap::default();
        number(
            &mut index,
            [&early.2, &late.2]
                .into_iter()
                .flatten()
                .flat_map(|c| c.index.keys())
                .chain(&self.landmarks),
        );
        let block = |closure: &Option<Rc<Closure>>| {
            let mut net = Network::new(index.len());
            if let Some(c) = closure {
                for (a, &i) in &c.index {
                    for (b, &j) in &c.index {
                        if i < j {
                            net.set(index[a], index[b], c.network.get(i, j));
                        }
                    }
                }
            }
            net
        };
        let landmarks: Vec<usize> = self.landmarks.iter().map(|l| index[l]).collect();
        let linked = match Extended::of_closed(&block(&early.2), &block(&late.2), &landmarks) {
            Ok(matrix) => Rc::new(Linked { index, matrix }),
            Err(conflict) => {
                let mut names: Vec<&str> = conflict
                    .landmarks
                    .iter()
                    .map(|&k| name_of(&index, k))
                    .collect();
                names.sort_unstable();
                return Err(trace_error(
                    late.0,
                    format!(
                        "the landmarks {} cannot all be rigid between t={} (line {}) and t={}: \
                         the observations contradict it (seed (3.26)); declare fewer landmarks",
                        names.join(", "),
                        early.1,
                        early.0,
                        late.1
                    ),
                ));
            }
        };
        self.linked.borrow_mut().insert((p, q), linked.clone());
        Ok(Some(linked))
    }
}

/// The current state and the timeline, as a [`Valuation`].
struct Now<'a> {
    state: &'a TraceState,
    timeline: &'a Timeline,
}

impl Valuation for Now<'_> {
    fn value(&self, key: &str) -> Option<Value<'_>> {
        self.state.values.get(key).map(|v| match v {
            Owned::Bool(b) => Value::Bool(*b),
            Owned::Number(n) => Value::Number(*n),
            Owned::Text(s) => Value::Text(s),
        })
    }

    fn spatial(&self, relation: Rcc8, left: &Region, right: &Region, key: &str) -> Truth {
        if let Some(rels) = self.timeline.relation(left, right) {
            if rels.0 == bit(relation) {
                return Truth::True;
            }
            if rels.0 & bit(relation) == 0 {
                return Truth::False;
            }
        }
        match self.value(key) {
            Some(Value::Bool(b)) => Truth::from(b),
            _ => Truth::Unknown,
        }
    }
}

/// The static regions, variables `0..s` of every state's network in the order of `names`,
/// and the closure of what is known between them.
struct Statics {
    index: FxHashMap<String, usize>,
    names: Vec<String>,
    split: Split,
}

impl Statics {
    fn new(regions: &BTreeSet<String>) -> Self {
        let names: Vec<String> = regions.iter().cloned().collect();
        Self {
            index: names
                .iter()
                .enumerate()
                .map(|(i, n)| (n.clone(), i))
                .collect(),
            split: Split::new(names.len()),
            names,
        }
    }
}

/// Gives each name not yet in `index` the next number.
fn number<'a>(index: &mut FxHashMap<String, usize>, names: impl Iterator<Item = &'a String>) {
    for name in names {
        let next = index.len();
        index.entry(name.clone()).or_insert(next);
    }
}

/// The name numbered `k` (for error messages).
fn name_of(index: &FxHashMap<String, usize>, k: usize) -> &str {
    index
        .iter()
        .find(|(_, v)| **v == k)
        .map_or("?", |(n, _)| n.as_str())
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
    statics: &mut Statics,
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
    // The closure infers what was not observed (seed Ch. 3.3): the contract's "exactly {R}
    // after algebraic closure". Relations between two static regions never change, so theirs
    // is closed once and refined as states tell more (Ch. 3.4.2's split: `Statics`); each state
    // adds its other constraints to a copy and re-closes from them. Landmarks carry their
    // relations through the extended matrix with the previous state (`Timeline::refine`).
    let mut fixed = Vec::new();
    let mut moving = Vec::new();
    for (pair, rels) in &out.spatial {
        match (statics.index.get(&pair.0), statics.index.get(&pair.1)) {
            (Some(&i), Some(&j)) => fixed.push((i, j, Relation(*rels))),
            _ => moving.push((pair, Relation(*rels))),
        }
    }
    statics.split.constrain(&fixed).map_err(|e| {
        trace_error(
            line,
            format!(
                "the relations between static regions contradict each other or what held between them before: no relation is possible between {} and {}",
                statics.names[e.0], statics.names[e.1]
            ),
        )
    })?;
    if !out.spatial.is_empty() || !statics.names.is_empty() {
        let mut index: FxHashMap<String, usize> = statics.index.clone();
        number(
            &mut index,
            moving.iter().flat_map(|(pair, _)| [&pair.0, &pair.1]),
        );
        let dynamic: Vec<(usize, usize, Relation)> = moving
            .iter()
            .map(|((a, b), r)| (index[a], index[b], *r))
            .collect();
        let network = statics.split.state(index.len(), &dynamic).map_err(|e| {
            let name = |k| name_of(&index, k);
            trace_error(
                line,
                format!(
                    "the spatial constraints are inconsistent: no relation is possible between {} and {}",
                    name(e.0),
                    name(e.1)
                ),
            )
        })?;
        // What this state inferred between static regions holds from now on.
        let s = statics.names.len();
        let learnt: Vec<(usize, usize, Relation)> = (0..s)
            .flat_map(|i| (i + 1..s).map(move |j| (i, j)))
            .filter(|&(i, j)| network.get(i, j) != statics.split.get(i, j))
            .map(|(i, j)| (i, j, network.get(i, j)))
            .collect();
        statics.split.constrain(&learnt).unwrap_or_else(|_| {
            unreachable!("a consistent state's closure refines the static part consistently")
        });
        out.closure = Some(Rc::new(Closure { index, network }));
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
    let mut statics = Statics::new(&h.static_regions);
    // Keep the states that atoms over `prev` regions look back to, and the previous state when
    // there are landmarks to check against the observations.
    let keep = usize::try_from(monitor.history())
        .unwrap_or(usize::MAX)
        .max(usize::from(!h.landmarks.is_empty()))
        .saturating_add(1);
    let mut timeline = Timeline::new(keep, &h.landmarks);
    let mut last_t = None;
    let mut all = Vec::new();
    let mut pending = formulas.len();
    let mut next = first;
    while let Some((line, map)) = next {
        let (t, s) = state(line, map, &mut statics)?;
        if let Some(previous) = last_t
            && t <= previous
        {
            return Err(trace_error(
                line,
                StepError::NotIncreasing { previous, t }.to_string(),
            ));
        }
        last_t = Some(t);
        timeline.push(line, t, s.closure.clone());
        // Landmarks are checked against each pair of consecutive states as they come.
        timeline.refine()?;
        let now = Now {
            state: &s,
            timeline: &timeline,
        };
        let verdicts = monitor.step(t, &now).map_err(|e| match e {
            StepError::NotIncreasing { .. } | StepError::Finished => {
                trace_error(line, e.to_string())
            }
        })?;
        if let Some(e) = timeline.conflict.take() {
            return Err(e);
        }
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
