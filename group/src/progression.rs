//! Progression of a group's formulas over the synchronised state stream, with the existing
//! monitor and state-stream core of `dyknow-mstl` (no second implementation of the logic), and
//! the recorded trace: every state taken is written as a `dyknow check` trace line, so
//! `dyknow check` on the recorded trace gives the verdicts the group gave.

use dyknow_mstl::{Domains, Formula, Monitor, State, StateStream, StateValue, Truth, Verdict};
use dyknow_rcc8::Relation;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value as Json, json};

use crate::sync::SyncState;

/// What a trace's header declares (the group's domains, landmarks and static regions).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TraceHeader {
    /// Named domains for quantifiers.
    #[serde(default)]
    pub domains: Domains,
    /// Landmark regions.
    #[serde(default)]
    pub landmarks: Vec<String>,
    /// Static regions.
    #[serde(default, rename = "static")]
    pub static_regions: Vec<String>,
}

impl TraceHeader {
    /// The header line of the trace (always written, even when empty).
    pub fn line(&self) -> String {
        json!({"domains": self.domains, "landmarks": self.landmarks, "static": self.static_regions})
            .to_string()
    }
}

/// What a stream of a group carries.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StreamKind {
    /// The values of one state key (a predicate's booleans, a function term's numbers or
    /// strings).
    Value(String),
    /// RCC-8 constraints `[["a", "b", ["PO", "EC"]], ...]`.
    Spatial,
}

/// A decided formula as `dyknow check` prints it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct VerdictLine {
    /// The formula's index in the group.
    pub formula: usize,
    /// `true`, `false` or `unknown`.
    #[serde(with = "truth")]
    pub verdict: Truth,
    /// The timestamp of the state that decided it.
    pub t: u64,
}

impl From<Verdict> for VerdictLine {
    fn from(v: Verdict) -> Self {
        Self {
            formula: v.formula,
            verdict: v.truth,
            t: v.t,
        }
    }
}

mod truth {
    use dyknow_mstl::Truth;
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(t: &Truth, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(t.as_str())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Truth, D::Error> {
        match String::deserialize(d)?.as_str() {
            "true" => Ok(Truth::True),
            "false" => Ok(Truth::False),
            "unknown" => Ok(Truth::Unknown),
            other => Err(serde::de::Error::custom(format!("not a verdict: {other}"))),
        }
    }
}

/// What taking one synchronised state gave.
#[derive(Debug, Clone)]
pub struct Taken {
    /// The verdicts the state decided.
    pub verdicts: Vec<VerdictLine>,
    /// The state's trace line (`None` if the state was not taken: its time does not follow
    /// the last one).
    pub line: Option<String>,
    /// Why the state's spatial constraints were dropped (contradictory, or refused by the
    /// landmarks or static regions): the state was taken without them, its spatial atoms
    /// unknown.
    pub dropped_spatial: Option<String>,
}

/// A group's formulas progressed over its state stream.
#[derive(Debug)]
pub struct Progression {
    header: TraceHeader,
    monitor: Monitor,
    stream: StateStream,
    states: u64,
    finished: bool,
}

impl Progression {
    /// Progression over a stream with `header`'s domains, landmarks and static regions.
    pub fn new(header: TraceHeader) -> Self {
        Self {
            monitor: Monitor::with_domains(header.domains.clone()),
            stream: StateStream::new(header.landmarks.clone(), header.static_regions.clone(), 0),
            header,
            states: 0,
            finished: false,
        }
    }

    /// The header.
    pub fn header(&self) -> &TraceHeader {
        &self.header
    }

    /// Adds a formula (parsed and grounded before), evaluated from the next state on; its
    /// index is the number of formulas added before.
    pub fn add(&mut self, formula: &Formula) -> Result<usize, dyknow_mstl::CompileError> {
        self.monitor.add(formula)
    }

    /// Stops progressing formula `i`.
    pub fn remove(&mut self, i: usize) {
        self.monitor.remove(i);
    }

    /// How many formulas were added.
    pub fn len(&self) -> usize {
        self.monitor.len()
    }

    /// Whether no formula was added.
    pub fn is_empty(&self) -> bool {
        self.monitor.is_empty()
    }

    /// States taken.
    pub fn states(&self) -> u64 {
        self.states
    }

    /// The last state's time.
    pub fn last_t(&self) -> Option<u64> {
        self.stream.t()
    }

    /// Formula `i`'s current truth value (unknown until decided).
    pub fn truth(&self, i: usize) -> Truth {
        self.monitor.truth(i)
    }

    /// The DAG's node count (memory watch).
    pub fn nodes(&self) -> usize {
        self.monitor.nodes()
    }

    /// Takes a synchronised state: `kinds[i]` says what stream `i` carries.
    pub fn take(&mut self, kinds: &[StreamKind], s: &SyncState<Json>) -> Taken {
        let (state, mut dropped) = build_state(kinds, s);
        self.take_state(state, &mut dropped)
    }

    /// Takes a state read back from a recorded trace.
    pub fn take_recorded(&mut self, state: State) -> Taken {
        self.take_state(state, &mut None)
    }

    fn take_state(&mut self, state: State, dropped: &mut Option<String>) -> Taken {
        if self.finished || self.stream.t().is_some_and(|l| state.t <= l) {
            return Taken {
                verdicts: Vec::new(),
                line: None,
                dropped_spatial: dropped.take(),
            };
        }
        let attempt = state.clone();
        let (taken, result) = match self.stream.step(&mut self.monitor, attempt) {
            Ok(v) => (state, Ok(v)),
            Err(e) => {
                // Only the spatial part can be refused here (the time follows): take the
                // state without it, its spatial atoms unknown.
                *dropped = Some(e.to_string());
                let mut plain = state;
                plain.spatial = dyknow_mstl::SpatialConstraints::new();
                let r = self.stream.step(&mut self.monitor, plain.clone());
                (plain, r)
            }
        };
        match result {
            Ok(verdicts) => {
                self.states += 1;
                Taken {
                    verdicts: verdicts.iter().map(|v| VerdictLine::from(*v)).collect(),
                    line: Some(state_line(&taken)),
                    dropped_spatial: dropped.take(),
                }
            }
            Err(e) => Taken {
                verdicts: Vec::new(),
                line: None,
                dropped_spatial: Some(e.to_string()),
            },
        }
    }

    /// Ends progression: every formula still undecided gets `unknown` at the last state's
    /// time (0 without states), as `dyknow check` does at the end of a trace.
    pub fn finish(&mut self) -> Vec<VerdictLine> {
        if self.finished {
            return Vec::new();
        }
        self.finished = true;
        self.monitor.finish().into_iter().map(Into::into).collect()
    }
}

/// The state of a synchronised sample set: values for value streams, constraints from the
/// spatial ones. A value that is not a boolean, number or string, or constraints that are not
/// valid, leave the stream unknown in that state; contradictory constraints drop the state's
/// spatial part (returned as the reason).
pub fn build_state(kinds: &[StreamKind], s: &SyncState<Json>) -> (State, Option<String>) {
    let mut state = State::new(s.t);
    let mut spatial = dyknow_mstl::SpatialConstraints::new();
    let mut problem = None;
    for (kind, value) in kinds.iter().zip(&s.values) {
        let Some(value) = value else { continue };
        match kind {
            StreamKind::Value(key) => {
                if let Some(v) = state_value(value) {
                    state.values.insert(key.clone(), v);
                }
            }
            StreamKind::Spatial => {
                let Some(constraints) = constraints(value) else {
                    continue;
                };
                for (x, y, r) in constraints {
                    if let Err(e) = spatial.add(x, y, r) {
                        problem = Some(e.to_string());
                    }
                }
            }
        }
    }
    if problem.is_none() {
        state.spatial = spatial;
    }
    (state, problem)
}

/// A sample's value as a state value: booleans, numbers, strings; anything else is unknown.
pub fn state_value(v: &Json) -> Option<StateValue> {
    match v {
        Json::Bool(b) => Some(StateValue::Bool(*b)),
        // An integer no double holds exactly is unknown: compared, it would decide wrongly.
        Json::Number(n) => dyknow_mstl::trace::exact_number(n).map(StateValue::Number),
        Json::String(s) => Some(StateValue::Text(s.clone())),
        _ => None,
    }
}

/// `[["a", "b", ["PO", "EC"]], ...]` as constraints (relation names as in `rcc8.md`); `None`
/// if it is not that.
pub fn constraints(v: &Json) -> Option<Vec<(String, String, Relation)>> {
    v.as_array()?
        .iter()
        .map(|c| {
            let c = c.as_array()?;
            let [x, y, rels] = c.as_slice() else {
                return None;
            };
            let mut r = Relation::EMPTY;
            for name in rels.as_array()? {
                r = r.or(Relation::from_name(name.as_str()?)?);
            }
            Some((x.as_str()?.to_owned(), y.as_str()?.to_owned(), r))
        })
        .collect()
}

/// A state as a trace line (`{"t", "state", "spatial"}`), keys sorted.
pub fn state_line(state: &State) -> String {
    let mut values = Map::new();
    for (k, v) in &state.values {
        values.insert(
            k.clone(),
            match v {
                StateValue::Bool(b) => Json::Bool(*b),
                StateValue::Number(n) => {
                    serde_json::Number::from_f64(*n).map_or(Json::Null, Json::Number)
                }
                StateValue::Text(s) => Json::String(s.clone()),
            },
        );
    }
    let spatial: Vec<Json> = state
        .spatial
        .iter()
        .map(|(x, y, r)| json!([x, y, relation_names(r)]))
        .collect();
    let mut line = Map::new();
    line.insert("t".into(), json!(state.t));
    line.insert("state".into(), Json::Object(values));
    if !spatial.is_empty() {
        line.insert("spatial".into(), Json::Array(spatial));
    }
    Json::Object(line).to_string()
}

/// The base relations of `r` by name.
pub fn relation_names(r: Relation) -> Vec<&'static str> {
    Relation::BASE
        .iter()
        .zip(Relation::NAMES)
        .filter(|(b, _)| r.contains(**b))
        .map(|(_, n)| n)
        .collect()
}

/// A trace line written by [`state_line`] read back.
pub fn read_state_line(line: &str) -> Result<State, String> {
    let v: Json = serde_json::from_str(line).map_err(|e| e.to_string())?;
    let t = v.get("t").and_then(Json::as_u64).ok_or("no integer t")?;
    let mut state = State::new(t);
    if let Some(values) = v.get("state").and_then(Json::as_object) {
        for (k, value) in values {
            if let Some(sv) = state_value(value) {
                state.values.insert(k.clone(), sv);
            }
        }
    }
    if let Some(spatial) = v.get("spatial") {
        for (x, y, r) in constraints(spatial).ok_or("bad spatial constraints")? {
            state.spatial.add(x, y, r).map_err(|e| e.to_string())?;
        }
    }
    Ok(state)
}
