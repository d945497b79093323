//! Progression (seed Algorithm 3, extended): a formula and a state give the formula that must
//! hold from the next state on.
//!
//! Time. Algorithm 3 takes Δ, the time to the *next* state, which a stream does not know when a
//! state arrives. Here the windows of a formula as written are relative (`Window::Rel`), and
//! progression at the state at `t` anchors them there (`Window::Abs`, timestamps): a pending
//! obligation such as `eventually[0,1000] p` then stays the same node from state to state until
//! it is met or its window passes, so a formula waiting on it progresses to itself. A window
//! whose end is reached exactly at a state closes at that state (the next one is strictly
//! later), so a verdict comes at the first state that decides it and never waits for the next
//! timestamp.
//!
//! Memoisation. Within one step each node is progressed once (the DAG shares subformulas
//! across formulas; a table indexed by node id and stamped with the step's epoch holds the
//! results), so 1,000 copies of a formula cost one progression.

use rustc_hash::FxHashMap;
use smallvec::SmallVec;

use crate::Truth;
use crate::atom::Valuation;
use crate::dag::{Dag, FALSE, Node, NodeId, Sym, TRUE, Window};
use crate::syntax::{Atom, Region, Term};

/// The progression state shared by a monitor's formulas.
#[derive(Debug, Default)]
pub(crate) struct Progress {
    pub(crate) dag: Dag,
    /// Per node: (epoch, result) of its progression in the current step.
    memo: Vec<(u32, NodeId)>,
    epoch: u32,
    /// Substitutions done: (node, variable, constant) → node. Cleared on collection.
    substituted: FxHashMap<(NodeId, Sym, Sym), NodeId>,
}

impl Progress {
    /// Starts the step of the state at `t`: memo entries of earlier steps no longer count.
    pub(crate) fn begin_step(&mut self, t: u64) {
        self.dag.now = Some(t);
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            // After 2³² steps, forget every entry rather than trust a wrapped stamp.
            self.memo.iter_mut().for_each(|m| *m = (0, FALSE));
            self.epoch = 1;
        }
    }

    /// Collects unreachable nodes when the store has doubled; drops the memo tables then.
    pub(crate) fn maybe_collect(&mut self, roots: impl Iterator<Item = NodeId>) {
        if self.dag.maybe_collect(roots) {
            self.memo.iter_mut().for_each(|m| *m = (0, FALSE));
            self.substituted.clear();
        }
    }

    /// PROGRESS(φ, s): the formula that holds from the next state on iff `n` holds at the
    /// current state (at `dag.now`), whose valuation is `v`.
    pub(crate) fn step<V: Valuation + ?Sized>(&mut self, n: NodeId, v: &V) -> NodeId {
        let i = n.0 as usize;
        if let Some((epoch, result)) = self.memo.get(i)
            && *epoch == self.epoch
        {
            return *result;
        }
        let result = deep(|| self.progress(n, v));
        if i >= self.memo.len() {
            self.memo.resize(self.dag.capacity().max(i + 1), (0, FALSE));
        }
        self.memo[i] = (self.epoch, result);
        result
    }

    /// A member of a conjunction (`conj`) or disjunction progressed as two members of the
    /// result: `G[I] φ` in a conjunction gives φ now and the pending `G` (and `F[I] φ` in a
    /// disjunction, dually), without building the junction of the two that the parent would
    /// flatten at once; any other member gives its progression and the neutral constant.
    fn parts<V: Valuation + ?Sized>(&mut self, x: NodeId, conj: bool, v: &V) -> (NodeId, NodeId) {
        let neutral = if conj { TRUE } else { FALSE };
        if let Some((epoch, result)) = self.memo.get(x.0 as usize)
            && *epoch == self.epoch
        {
            return (*result, neutral);
        }
        match (self.dag.node(x), conj) {
            (Node::Always(w, a), true) | (Node::Eventually(w, a), false) => {
                let (w, a) = (*w, *a);
                self.window(x, w, a, conj, v)
            }
            _ => (self.step(x, v), neutral),
        }
    }

    /// Lines 6–13 for `G[I] φ` (`always`) and `F[I] φ`: the part the current state decides and
    /// the pending rest, whose conjunction (disjunction for `F`) is the progression. A window
    /// that has passed or cannot be reached gives the neutral constant for both; one that ends
    /// now leaves no rest.
    fn window<V: Valuation + ?Sized>(
        &mut self,
        n: NodeId,
        w: Window,
        a: NodeId,
        always: bool,
        v: &V,
    ) -> (NodeId, NodeId) {
        let (neutral, absorbing) = if always { (TRUE, FALSE) } else { (FALSE, TRUE) };
        let t = self.dag.now.unwrap_or(0);
        let Some((lo, hi, anchored)) = anchor(w, t, n) else {
            return (neutral, neutral);
        };
        if hi.is_some_and(|h| h < t) {
            return (neutral, neutral);
        }
        let now = if lo <= t { self.step(a, v) } else { neutral };
        if now == absorbing || hi == Some(t) {
            return (now, neutral);
        }
        let rest = anchored.unwrap_or_else(|| {
            let w = Window::Abs { lo, hi };
            if always {
                self.dag.always(w, a)
            } else {
                self.dag.eventually(w, a)
            }
        });
        (now, rest)
    }

    fn progress<V: Valuation + ?Sized>(&mut self, n: NodeId, v: &V) -> NodeId {
        let t = self.dag.now.unwrap_or(0);
        match self.dag.node(n).clone() {
            Node::False | Node::True | Node::Unknown | Node::Free => n,
            // Lines 22–28: the state decides the atom, or it is unknown.
            Node::Atom(a) => {
                let truth = self.dag.atoms[a.0 as usize].1.eval(v);
                Dag::constant(truth)
            }
            // Lines 4–5.
            Node::Not(a) => {
                let a = self.step(a, v);
                self.dag.not(a)
            }
            // Lines 2–3, short-circuiting on the absorbing constant.
            Node::And(xs) | Node::Or(xs) => {
                let conj = matches!(self.dag.node(n), Node::And(_));
                let absorbing = if conj { FALSE } else { TRUE };
                let mut out: SmallVec<[NodeId; 8]> = SmallVec::new();
                for x in xs.iter() {
                    let (r, rest) = self.parts(*x, conj, v);
                    if r == absorbing || rest == absorbing {
                        return absorbing;
                    }
                    out.push(r);
                    out.push(rest);
                }
                self.dag.junction(&out, conj)
            }
            // Lines 18–19: `next^k φ` becomes `next^(k-1) φ`; `next^0 φ` is φ, progressed
            // here (its windows anchored at this state).
            Node::Next(0, a) => self.step(a, v),
            Node::Next(k, a) => self.dag.next(k - 1, a),
            // Lines 6–13, with `eventually[I] φ = true U[I] φ` and `always = ¬eventually¬`
            // written out. `Some(n)` when the node is anchored already (its own residual).
            Node::Eventually(w, a) => {
                let (now, rest) = self.window(n, w, a, false, v);
                self.dag.or2(now, rest)
            }
            Node::Always(w, a) => {
                let (now, rest) = self.window(n, w, a, true, v);
                self.dag.and2(now, rest)
            }
            Node::Until(w, a, b) => {
                let Some((lo, hi, anchored)) = anchor(w, t, n) else {
                    return FALSE;
                };
                if hi.is_some_and(|h| h < t) {
                    return FALSE;
                }
                let goal = if lo <= t { self.step(b, v) } else { FALSE };
                if goal == TRUE {
                    return TRUE;
                }
                let hold = self.step(a, v);
                let rest = if hi == Some(t) || hold == FALSE {
                    FALSE
                } else {
                    let rest =
                        anchored.unwrap_or_else(|| self.dag.until(Window::Abs { lo, hi }, a, b));
                    self.dag.and2(hold, rest)
                };
                self.dag.or2(goal, rest)
            }
            // Lines 14–17: quantifiers expand over the domain's constants.
            Node::Forall(x, domain, body) | Node::Exists(x, domain, body) => {
                let forall = matches!(self.dag.node(n), Node::Forall(..));
                let mut out: SmallVec<[NodeId; 8]> = SmallVec::new();
                for c in domain.iter() {
                    let instance = self.substitute(body, x, *c);
                    let r = self.step(instance, v);
                    if r == if forall { FALSE } else { TRUE } {
                        return r;
                    }
                    out.push(r);
                }
                if forall {
                    self.dag.and(&out)
                } else {
                    self.dag.or(&out)
                }
            }
        }
    }

    /// φ(x/c): the variable `x` replaced by the constant `c` in terms and regions, except
    /// under a quantifier that binds `x` again.
    pub(crate) fn substitute(&mut self, n: NodeId, x: Sym, c: Sym) -> NodeId {
        if let Some(r) = self.substituted.get(&(n, x, c)) {
            return *r;
        }
        let r = deep(|| self.substitute_node(n, x, c));
        self.substituted.insert((n, x, c), r);
        r
    }

    fn substitute_node(&mut self, n: NodeId, x: Sym, c: Sym) -> NodeId {
        match self.dag.node(n).clone() {
            Node::False | Node::True | Node::Unknown | Node::Free => n,
            Node::Atom(a) => {
                let atom = &self.dag.atoms[a.0 as usize].0;
                let (var, constant) = (&self.dag.syms[x.0 as usize], &self.dag.syms[c.0 as usize]);
                match substitute_atom(atom, var, constant) {
                    Some(atom) => self.dag.atom(atom),
                    None => n,
                }
            }
            Node::Not(a) => {
                let a = self.substitute(a, x, c);
                self.dag.not(a)
            }
            Node::And(xs) | Node::Or(xs) => {
                let conj = matches!(self.dag.node(n), Node::And(_));
                let items: SmallVec<[NodeId; 8]> =
                    xs.iter().map(|i| self.substitute(*i, x, c)).collect();
                if conj {
                    self.dag.and(&items)
                } else {
                    self.dag.or(&items)
                }
            }
            Node::Next(k, a) => {
                let a = self.substitute(a, x, c);
                self.dag.next(k, a)
            }
            Node::Always(iv, a) => {
                let a = self.substitute(a, x, c);
                self.dag.always(iv, a)
            }
            Node::Eventually(iv, a) => {
                let a = self.substitute(a, x, c);
                self.dag.eventually(iv, a)
            }
            Node::Until(iv, a, b) => {
                let a = self.substitute(a, x, c);
                let b = self.substitute(b, x, c);
                self.dag.until(iv, a, b)
            }
            Node::Forall(y, _, _) | Node::Exists(y, _, _) if y == x => n,
            Node::Forall(y, domain, body) | Node::Exists(y, domain, body) => {
                let forall = matches!(self.dag.node(n), Node::Forall(..));
                let body = self.substitute(body, x, c);
                self.dag.quantifier(forall, y, domain, body)
            }
        }
    }
}

/// Runs `f` with at least 64 KiB of stack left, continuing on a new 1 MiB segment when the
/// thread's stack runs low: formulas nest up to `MAX_TREE_DEPTH` deep, and a caller's thread
/// (a Tokio worker has 2 MiB) must not overflow, even in an unoptimised build.
pub(crate) fn deep<R>(f: impl FnOnce() -> R) -> R {
    stacker::maybe_grow(64 * 1024, 1024 * 1024, f)
}

/// The window in timestamps: a relative one anchored at `t`, the node itself when anchored
/// already. `None` when it starts beyond the last timestamp there can be (no state can fall in
/// it); an end beyond it is no end.
///
/// A window that has begun by `t` begins before every later state, so its start no longer
/// matters: it is written `0`. The obligations over one body that end together are then one
/// node whenever they were anchored (`always eventually (next r)` waits on one `eventually`,
/// not on one per state: the disjunctions holding them would not merge otherwise), and the
/// node stays its own residual from then on.
fn anchor(w: Window, t: u64, n: NodeId) -> Option<(u64, Option<u64>, Option<NodeId>)> {
    let (lo, hi, own) = match w {
        Window::Rel(iv) => (
            t.checked_add(iv.lo)?,
            iv.hi.and_then(|h| t.checked_add(h)),
            None,
        ),
        Window::Abs { lo, hi } => (lo, hi, Some(n)),
    };
    if lo <= t && lo != 0 {
        return Some((0, hi, None));
    }
    Some((lo, hi, own))
}

/// The atom with `var` replaced by `constant`; `None` when it does not mention `var`.
fn substitute_atom(atom: &Atom, var: &str, constant: &str) -> Option<Atom> {
    let mut changed = false;
    let mut term = |t: &Term| substitute_term(t, var, constant, &mut changed);
    let out = match atom {
        Atom::Predicate { name, args } => Atom::Predicate {
            name: name.clone(),
            args: args.iter().map(&mut term).collect(),
        },
        Atom::Compare { left, op, right } => Atom::Compare {
            left: term(left),
            op: *op,
            right: term(right),
        },
        Atom::Spatial {
            relation,
            left,
            right,
        } => {
            let mut region = |r: &Region| {
                if r.name == var {
                    changed = true;
                    Region {
                        offset: r.offset,
                        name: constant.to_owned(),
                    }
                } else {
                    r.clone()
                }
            };
            Atom::Spatial {
                relation: *relation,
                left: region(left),
                right: region(right),
            }
        }
    };
    changed.then_some(out)
}

fn substitute_term(t: &Term, var: &str, constant: &str, changed: &mut bool) -> Term {
    match t {
        Term::Name { name, args } if args.is_empty() && name == var => {
            *changed = true;
            Term::Name {
                name: constant.to_owned(),
                args: Vec::new(),
            }
        }
        Term::Name { name, args } => Term::Name {
            name: name.clone(),
            args: args
                .iter()
                .map(|a| substitute_term(a, var, constant, changed))
                .collect(),
        },
        other => other.clone(),
    }
}

impl From<bool> for Truth {
    fn from(b: bool) -> Self {
        if b { Self::True } else { Self::False }
    }
}
