//! The monitor: a group of formulas progressed over one state stream (issue 5, item 3). Each
//! formula's verdict is reported at the first state after which it can no longer change
//! (contract `mstl.md`, Verdicts), and the group's formulas share one DAG, so common
//! subformulas are progressed once per state.

use crate::Truth;
use crate::atom::Valuation;
use crate::compile::{CompileError, Domains, compile, history};
use crate::dag::{FALSE, NodeId, TRUE, UNKNOWN};
use crate::progress::Progress;
use crate::syntax::Formula;

/// A decided formula: its position in the group, its truth value, and the timestamp of the
/// state at which it was decided (or the last state, for `unknown` at the end).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Verdict {
    /// The formula's index (the order of [`Monitor::add`]).
    pub formula: usize,
    /// True or false; unknown only from [`Monitor::finish`].
    pub truth: Truth,
    /// The timestamp (ms) of the state that decided it.
    pub t: u64,
}

/// Why a state cannot be taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StepError {
    /// Timestamps must strictly increase.
    #[error("timestamp {t} does not follow {previous} (timestamps must strictly increase)")]
    NotIncreasing {
        /// The previous state's timestamp.
        previous: u64,
        /// The rejected timestamp.
        t: u64,
    },
    /// The monitor was finished.
    #[error("the monitor has finished")]
    Finished,
}

#[derive(Debug, Clone, Copy)]
struct Entry {
    /// The formula as added (kept for [`Monitor::restart`]).
    initial: NodeId,
    /// What must hold from the next state on; a constant once decided.
    current: NodeId,
    decided: bool,
    removed: bool,
}

/// Progresses a group of MSTL formulas over one state stream.
///
/// ```
/// use dyknow_mstl::{Monitor, Truth, Value, Valuation, parse};
/// struct P(bool);
/// impl Valuation for P {
///     fn value(&self, key: &str) -> Option<Value<'_>> {
///         (key == "p").then_some(Value::Bool(self.0))
///     }
/// }
/// let mut m = Monitor::new();
/// m.add(&parse("eventually[0,250] p").unwrap()).unwrap();
/// assert!(m.step(0, &P(false)).unwrap().is_empty());
/// let verdicts = m.step(200, &P(true)).unwrap();
/// assert_eq!((verdicts[0].truth, verdicts[0].t), (Truth::True, 200));
/// ```
#[derive(Debug, Default)]
pub struct Monitor {
    progress: Progress,
    entries: Vec<Entry>,
    domains: Domains,
    last_t: Option<u64>,
    finished: bool,
    verdicts: Vec<Verdict>,
    history: u32,
}

impl Monitor {
    /// A monitor with no formulas and no named domains.
    pub fn new() -> Self {
        Self::default()
    }

    /// A monitor whose quantifiers may range over `domains`.
    pub fn with_domains(domains: Domains) -> Self {
        let mut monitor = Self {
            domains,
            ..Self::default()
        };
        let constants: Vec<String> = monitor.domains.values().flatten().cloned().collect();
        monitor.progress.dag.add_constants(constants);
        monitor
    }

    /// Adds a formula, evaluated from the next state on. Returns its index. The constants of
    /// the sets it quantifies over are constants for every formula of the monitor from now on
    /// (a name without arguments that is no constant is a symbol: unknown in a state that
    /// does not give it, `docs/mstl.md`).
    pub fn add(&mut self, formula: &Formula) -> Result<usize, CompileError> {
        let root = compile(&mut self.progress.dag, formula, &self.domains)?;
        let mut constants = std::collections::BTreeSet::new();
        crate::ground::collect_set_constants(formula, &mut constants);
        self.progress.dag.add_constants(constants);
        self.history = self.history.max(history(formula));
        self.entries.push(Entry {
            initial: root,
            current: root,
            decided: false,
            removed: false,
        });
        Ok(self.entries.len() - 1)
    }

    /// Stops monitoring a formula (its index stays taken).
    pub fn remove(&mut self, formula: usize) {
        if let Some(e) = self.entries.get_mut(formula) {
            e.removed = true;
            e.current = UNKNOWN;
            e.initial = UNKNOWN;
        }
    }

    /// Monitors a formula afresh from the next state on, as if just added: execution
    /// monitoring that reports a violation and goes on watching. Does nothing for a removed
    /// formula.
    pub fn restart(&mut self, formula: usize) {
        if let Some(e) = self.entries.get_mut(formula)
            && !e.removed
        {
            e.current = e.initial;
            e.decided = false;
        }
    }

    /// The number of formulas added.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no formula was added.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The verdict of a formula so far: true or false once decided, unknown before.
    pub fn truth(&self, formula: usize) -> Truth {
        match self.entries.get(formula).map(|e| e.current) {
            Some(TRUE) => Truth::True,
            Some(FALSE) => Truth::False,
            _ => Truth::Unknown,
        }
    }

    /// The formula that must hold from the next state on, as DAG nodes reachable from it.
    pub fn size(&self, formula: usize) -> usize {
        self.entries
            .get(formula)
            .map_or(0, |e| self.progress.dag.size(e.current))
    }

    /// How many states before the current one a [`Valuation`] may be asked about: spatial
    /// atoms over `prev` region terms (after Theorems 4–5 turned every `next` into `prev`)
    /// relate regions at earlier states, so a valuation must remember that many.
    pub fn history(&self) -> u32 {
        self.history
    }

    /// DAG nodes in use (live or awaiting collection); stays bounded on endless streams.
    pub fn nodes(&self) -> usize {
        self.progress.dag.allocated()
    }

    /// Progresses every undecided formula through the state at `t` (ms) and returns the
    /// verdicts it decided.
    pub fn step<V: Valuation + ?Sized>(
        &mut self,
        t: u64,
        state: &V,
    ) -> Result<&[Verdict], StepError> {
        if self.finished {
            return Err(StepError::Finished);
        }
        if let Some(previous) = self.last_t
            && t <= previous
        {
            return Err(StepError::NotIncreasing { previous, t });
        }
        self.last_t = Some(t);
        self.verdicts.clear();
        self.progress.begin_step(t);
        for (i, e) in self.entries.iter_mut().enumerate() {
            if e.decided || e.removed {
                continue;
            }
            e.current = self.progress.step(e.current, state);
            let truth = match e.current {
                TRUE => Truth::True,
                FALSE => Truth::False,
                _ => continue,
            };
            e.decided = true;
            self.verdicts.push(Verdict {
                formula: i,
                truth,
                t,
            });
        }
        self.progress
            .maybe_collect(self.entries.iter().flat_map(|e| [e.current, e.initial]));
        Ok(&self.verdicts)
    }

    /// Ends the stream: every formula still undecided is unknown at the last state's
    /// timestamp (0 if there was none). Later steps are refused.
    pub fn finish(&mut self) -> Vec<Verdict> {
        self.finished = true;
        let t = self.last_t.unwrap_or(0);
        self.entries
            .iter()
            .enumerate()
            .filter(|(_, e)| !e.decided && !e.removed)
            .map(|(formula, _)| Verdict {
                formula,
                truth: Truth::Unknown,
                t,
            })
            .collect()
    }
}
