//! Formulas as hash-consed DAG nodes (issue 5, item 1): every distinct formula exists once, so
//! progression of many formulas over one stream shares their common subformulas, and a formula
//! that progresses to itself costs a table lookup. The smart constructors simplify as they build
//! (constant folding in Kleene's logic, flattening, idempotence, absorption, and interval
//! subsumption of `eventually`/`always` over the same body); [`Dag::collect`] reclaims nodes no
//! live formula reaches, so memory stays bounded on endless streams.
//!
//! Every simplification is an identity of Kleene's strong three-valued logic (a distributive
//! lattice with an involution, without excluded middle), so it never changes a verdict.

use std::hash::BuildHasher;
use std::sync::Arc;

use hashbrown::HashTable;
use rustc_hash::{FxBuildHasher, FxHashMap, FxHashSet};
use smallvec::SmallVec;

use crate::atom::AtomPlan;
use crate::syntax::{Atom, Interval};

/// A node of the DAG.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct NodeId(pub(crate) u32);

/// An interned ground (or open, under a quantifier) atom.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) struct AtomId(pub(crate) u32);

/// An interned name (a quantified variable, a constant of a domain).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct Sym(pub(crate) u32);

/// `false`, `true` and `unknown` have fixed ids.
pub(crate) const FALSE: NodeId = NodeId(0);
pub(crate) const TRUE: NodeId = NodeId(1);
pub(crate) const UNKNOWN: NodeId = NodeId(2);

/// The window of a temporal node. In a formula as written (a *template*) it is relative to the
/// state the formula is first progressed at; progression anchors it there, so a pending
/// obligation keeps the same node from state to state (see `progress.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Window {
    /// `[lo, hi]` after the state the formula starts at.
    Rel(Interval),
    /// The timestamps `[lo, hi]` (`hi = None`: no end).
    Abs { lo: u64, hi: Option<u64> },
}

/// A formula node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Node {
    False,
    True,
    Unknown,
    Atom(AtomId),
    Not(NodeId),
    /// At least two conjuncts, sorted, distinct, none a constant but `Unknown`, none an `And`.
    And(Arc<[NodeId]>),
    /// At least two disjuncts, as `And`.
    Or(Arc<[NodeId]>),
    /// `next^k φ`. `Next(0, φ)` occurs only in progressed formulas: φ from the state it is
    /// progressed at, with φ's windows anchored at that state.
    Next(u32, NodeId),
    Always(Window, NodeId),
    Eventually(Window, NodeId),
    Until(Window, NodeId, NodeId),
    /// `forall x in D: φ`, with D's constants.
    Forall(Sym, Arc<[Sym]>, NodeId),
    /// `exists x in D: φ`.
    Exists(Sym, Arc<[Sym]>, NodeId),
    /// A reclaimed slot.
    Free,
}

/// The node store.
#[derive(Debug)]
pub(crate) struct Dag {
    nodes: Vec<Node>,
    /// The hash-consing index: ids, hashed and compared by their node (stored once, in
    /// `nodes`).
    index: HashTable<NodeId>,
    free: Vec<NodeId>,
    /// Atoms by id, with how to evaluate them, and their index by printed form; atoms are few
    /// (the formulas' atoms, grounded over finite domains) and never reclaimed.
    pub(crate) atoms: Vec<(Atom, AtomPlan)>,
    atom_index: FxHashMap<String, AtomId>,
    /// The names without arguments that are constants, not symbols: the monitor's domains'
    /// constants and those of the sets in its formulas ([`Dag::add_constants`]). A bound
    /// variable's fresh name (`x\0<n>`) counts as one: a constant replaces it.
    constants: FxHashSet<String>,
    /// Interned names.
    pub(crate) syms: Vec<String>,
    sym_index: FxHashMap<String, Sym>,
    /// Live nodes after the last collection (the next one runs when twice as many exist).
    live_after_collect: usize,
    /// The timestamp of the state being progressed: anchored windows are compared from the
    /// next state on.
    pub(crate) now: Option<u64>,
    /// Bound variables renamed so far (for fresh names).
    variables: u64,
}

impl Default for Dag {
    fn default() -> Self {
        let mut dag = Self {
            nodes: Vec::new(),
            index: HashTable::new(),
            free: Vec::new(),
            atoms: Vec::new(),
            atom_index: FxHashMap::default(),
            constants: FxHashSet::default(),
            syms: Vec::new(),
            sym_index: FxHashMap::default(),
            live_after_collect: 0,
            now: None,
            variables: 0,
        };
        for n in [Node::False, Node::True, Node::Unknown] {
            dag.intern(n);
        }
        dag
    }
}

/// The members of a junction being built (no allocation for up to 8).
type Members = SmallVec<[NodeId; 8]>;

/// The kind of a temporal node whose window a conjunction or disjunction may merge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Kind {
    Always,
    Eventually,
    Until,
}

/// A member window: kind, anchored, body (for `until`, its left operand, with its right
/// operand next; for the others the body twice), the interval it still covers, and its node
/// (`None` once merged into a new one).
type Member = (Kind, bool, NodeId, NodeId, Interval, Option<NodeId>);

impl Dag {
    pub(crate) fn node(&self, id: NodeId) -> &Node {
        &self.nodes[id.0 as usize]
    }

    /// The number of node slots in use (live or not yet collected).
    pub(crate) fn allocated(&self) -> usize {
        self.nodes.len() - self.free.len()
    }

    /// The number of slots (the store's high-water mark).
    pub(crate) fn capacity(&self) -> usize {
        self.nodes.len()
    }

    fn intern(&mut self, node: Node) -> NodeId {
        let hash = node_hash(&node);
        let nodes = &self.nodes;
        if let Some(id) = self.index.find(hash, |id| nodes[id.0 as usize] == node) {
            return *id;
        }
        let id = if let Some(id) = self.free.pop() {
            self.nodes[id.0 as usize] = node;
            id
        } else {
            let id = NodeId(u32::try_from(self.nodes.len()).unwrap_or(u32::MAX));
            self.nodes.push(node);
            id
        };
        let nodes = &self.nodes;
        self.index
            .insert_unique(hash, id, |id| node_hash(&nodes[id.0 as usize]));
        id
    }

    /// A number for a fresh variable name.
    pub(crate) fn fresh_variable(&mut self) -> u64 {
        self.variables += 1;
        self.variables
    }

    pub(crate) fn sym(&mut self, name: &str) -> Sym {
        if let Some(s) = self.sym_index.get(name) {
            return *s;
        }
        let s = Sym(u32::try_from(self.syms.len()).unwrap_or(u32::MAX));
        self.syms.push(name.to_owned());
        self.sym_index.insert(name.to_owned(), s);
        s
    }

    /// Whether `name` (without arguments) is a constant ([`Dag::constants`]).
    fn is_constant(constants: &FxHashSet<String>, name: &str) -> bool {
        name.contains('\0') || constants.contains(name)
    }

    /// Makes `names` constants; the atoms already made are planned again if one is new (a
    /// formula added later may declare a constant an earlier one uses).
    pub(crate) fn add_constants(&mut self, names: impl IntoIterator<Item = String>) {
        let mut new = false;
        for name in names {
            new |= self.constants.insert(name);
        }
        if new {
            let constants = &self.constants;
            for (atom, plan) in &mut self.atoms {
                *plan = AtomPlan::new(atom, &|n| Self::is_constant(constants, n));
            }
        }
    }

    pub(crate) fn atom(&mut self, atom: Atom) -> NodeId {
        let printed = atom.to_string();
        let id = if let Some(id) = self.atom_index.get(&printed) {
            *id
        } else {
            let id = AtomId(u32::try_from(self.atoms.len()).unwrap_or(u32::MAX));
            let constants = &self.constants;
            let plan = AtomPlan::new(&atom, &|n| Self::is_constant(constants, n));
            self.atoms.push((atom, plan));
            self.atom_index.insert(printed, id);
            id
        };
        self.intern(Node::Atom(id))
    }

    pub(crate) fn constant(truth: crate::Truth) -> NodeId {
        match truth {
            crate::Truth::False => FALSE,
            crate::Truth::True => TRUE,
            crate::Truth::Unknown => UNKNOWN,
        }
    }

    /// `¬a`: Kleene negation, `¬¬a = a`, and `¬ next φ = next ¬φ` (Theorem 1), so negated
    /// and unnegated delays share their node.
    pub(crate) fn not(&mut self, a: NodeId) -> NodeId {
        match *self.node(a) {
            Node::False => TRUE,
            Node::True => FALSE,
            Node::Unknown => UNKNOWN,
            Node::Not(b) => b,
            Node::Next(k, b) => {
                let nb = self.not(b);
                self.next(k, nb)
            }
            _ => self.intern(Node::Not(a)),
        }
    }

    /// `a ∧ b`, without allocating when either is a constant.
    pub(crate) fn and2(&mut self, a: NodeId, b: NodeId) -> NodeId {
        match (a, b) {
            (FALSE, _) | (_, FALSE) => FALSE,
            (TRUE, x) | (x, TRUE) => x,
            _ if a == b => a,
            _ => self.junction(&[a, b], true),
        }
    }

    /// `a ∨ b`, without allocating when either is a constant.
    pub(crate) fn or2(&mut self, a: NodeId, b: NodeId) -> NodeId {
        match (a, b) {
            (TRUE, _) | (_, TRUE) => TRUE,
            (FALSE, x) | (x, FALSE) => x,
            _ if a == b => a,
            _ => self.junction(&[a, b], false),
        }
    }

    /// The conjunction of `items`.
    pub(crate) fn and(&mut self, items: &[NodeId]) -> NodeId {
        self.junction(items, true)
    }

    /// The disjunction of `items`.
    pub(crate) fn or(&mut self, items: &[NodeId]) -> NodeId {
        self.junction(items, false)
    }

    /// A conjunction (`conj`) or disjunction, simplified: the absorbing constant wins, the
    /// neutral one goes, nested junctions of the same kind are flattened, duplicates merged
    /// (idempotence), a member absorbs a junction of the other kind containing it
    /// (`a ∧ (a ∨ b) = a`), and windows over the same body are merged (`merge_windows`).
    pub(crate) fn junction(&mut self, items: &[NodeId], conj: bool) -> NodeId {
        let (absorbing, neutral) = if conj { (FALSE, TRUE) } else { (TRUE, FALSE) };
        let mut flat: Members = SmallVec::new();
        for &i in items {
            if i == absorbing {
                return absorbing;
            }
            if i == neutral {
                continue;
            }
            match (&self.nodes[i.0 as usize], conj) {
                (Node::And(xs), true) | (Node::Or(xs), false) => flat.extend(xs.iter().copied()),
                _ => flat.push(i),
            }
        }
        flat.sort_unstable();
        flat.dedup();
        if flat.len() > 1 {
            self.merge_windows(&mut flat, conj);
        }
        if flat.len() > 1
            && flat.iter().any(|i| {
                matches!(
                    (self.node(*i), conj),
                    (Node::Or(_), true) | (Node::And(_), false)
                )
            })
        {
            // Absorption: drop a member junction of the other kind that shares a member.
            let absorbed: Members = flat
                .iter()
                .copied()
                .filter(|i| match (self.node(*i), conj) {
                    (Node::Or(xs), true) | (Node::And(xs), false) => {
                        xs.iter().any(|x| flat.binary_search(x).is_ok())
                    }
                    _ => false,
                })
                .collect();
            flat.retain(|i| !absorbed.contains(i));
        }
        match flat.len() {
            0 => neutral,
            1 => flat[0],
            _ => {
                // Look the junction up by its members before allocating its node.
                let hash = junction_hash(conj, &flat);
                let nodes = &self.nodes;
                let found = self
                    .index
                    .find(hash, |id| match (&nodes[id.0 as usize], conj) {
                        (Node::And(xs), true) | (Node::Or(xs), false) => **xs == *flat,
                        _ => false,
                    });
                if let Some(id) = found {
                    return *id;
                }
                let items: Arc<[NodeId]> = Arc::from(flat.as_slice());
                self.intern(if conj {
                    Node::And(items)
                } else {
                    Node::Or(items)
                })
            }
        }
    }

    /// Interval subsumption among the members over the same body. In a conjunction,
    /// `F[I] φ ∧ F[J] φ = F[I] φ` when `I ⊆ J`, and `G[I] φ ∧ G[J] φ = G[I ∪ J] φ` when the
    /// intervals overlap or touch (timestamps are integers); in a disjunction the duals.
    /// `until` is `eventually` with a condition on the states before its witness, the same
    /// for both windows, so it merges as `eventually` does: `ψ U[I] φ ∧ ψ U[J] φ = ψ U[I] φ`
    /// when `I ⊆ J` (a witness in `I` is one in `J`), and `ψ U[I] φ ∨ ψ U[J] φ = ψ U[I ∪ J]
    /// φ`. Without it, `always (p -> (q U r))` kept one obligation per state until `r`: time
    /// and memory grew with the square of the wait.
    /// Anchored windows are compared on what they still cover, from the state after `now`
    /// (a progressed formula holds from there on); a member kept whole keeps its node.
    fn merge_windows(&mut self, items: &mut Members, conj: bool) {
        let after = self.now.map_or(0, |t| t.saturating_add(1));
        let member = |n: &Node, id: NodeId| -> Option<Member> {
            let (kind, w, a, b) = match n {
                Node::Always(w, a) => (Kind::Always, *w, *a, *a),
                Node::Eventually(w, a) => (Kind::Eventually, *w, *a, *a),
                Node::Until(w, a, b) => (Kind::Until, *w, *a, *b),
                _ => return None,
            };
            Some(match w {
                Window::Rel(iv) => (kind, false, a, b, iv, Some(id)),
                Window::Abs { lo, hi } => (
                    kind,
                    true,
                    a,
                    b,
                    Interval {
                        lo: lo.max(after),
                        hi,
                    },
                    Some(id),
                ),
            })
        };
        let mut windows: SmallVec<[Member; 4]> = items
            .iter()
            .filter_map(|i| member(self.node(*i), *i))
            .collect();
        if windows.len() < 2 {
            return;
        }
        let group = |m: &Member| (m.0, m.1, m.2, m.3);
        windows.sort_unstable_by_key(|m| (group(m), m.4.lo, m.4.hi.map_or(u64::MAX, |h| h)));
        let same_group = windows.windows(2).any(|p| group(&p[0]) == group(&p[1]));
        let across = windows.iter().any(|u| {
            u.0 == Kind::Until
                && windows
                    .iter()
                    .any(|f| f.0 == Kind::Eventually && f.1 == u.1 && f.2 == u.3)
        });
        if !same_group && !across {
            return;
        }
        let mut out: SmallVec<[Member; 4]> = SmallVec::new();
        for w in windows {
            if let Some(last) = out.last_mut()
                && group(last) == group(&w)
            {
                // `union` merges (G in ∧, F and U in ∨); otherwise keep the narrower when
                // nested.
                let union = (w.0 == Kind::Always) == conj;
                if union {
                    if contains(last.4, w.4) {
                        continue;
                    }
                    if contains(w.4, last.4) {
                        *last = w;
                        continue;
                    }
                    if touches(last.4, w.4) {
                        last.4 = Interval {
                            lo: last.4.lo,
                            hi: max_hi(last.4.hi, w.4.hi),
                        };
                        last.5 = None;
                        continue;
                    }
                } else if contains(w.4, last.4) {
                    continue;
                } else if contains(last.4, w.4) {
                    *last = w;
                    continue;
                }
            }
            out.push(w);
        }
        // Across kinds: `ψ U[I] φ` implies `F[J] φ` when `I ⊆ J` (same anchoring), so a
        // conjunction keeps the `until` and a disjunction the `eventually`.
        let implies = |u: &Member, f: &Member| {
            u.0 == Kind::Until
                && f.0 == Kind::Eventually
                && u.1 == f.1
                && u.3 == f.2
                && contains(f.4, u.4)
        };
        let dropped: SmallVec<[usize; 4]> = (0..out.len())
            .filter(|&k| {
                out.iter().any(|o| {
                    if conj {
                        implies(o, &out[k])
                    } else {
                        implies(&out[k], o)
                    }
                })
            })
            .collect();
        for k in dropped.into_iter().rev() {
            out.remove(k);
        }
        items.retain(|i| {
            !matches!(
                self.node(*i),
                Node::Always(..) | Node::Eventually(..) | Node::Until(..)
            )
        });
        for (kind, anchored, a, b, iv, id) in out {
            let id = id.unwrap_or_else(|| {
                let w = if anchored {
                    Window::Abs {
                        lo: iv.lo,
                        hi: iv.hi,
                    }
                } else {
                    Window::Rel(iv)
                };
                match kind {
                    Kind::Always => self.intern(Node::Always(w, a)),
                    Kind::Eventually => self.intern(Node::Eventually(w, a)),
                    Kind::Until => self.intern(Node::Until(w, a, b)),
                }
            });
            items.push(id);
        }
        items.sort_unstable();
        items.dedup();
    }

    /// `next^k a`; `next^k next^j a = next^(k+j) a`.
    pub(crate) fn next(&mut self, k: u32, a: NodeId) -> NodeId {
        match *self.node(a) {
            Node::False | Node::True | Node::Unknown => a,
            Node::Next(j, b) => self.intern(Node::Next(k.saturating_add(j), b)),
            _ => self.intern(Node::Next(k, a)),
        }
    }

    /// Temporal constructors fold exactly when the operator has the same value whatever the
    /// states hold (atoms unknown), so a progressed formula is a constant iff the states so far
    /// decide it operator by operator in Kleene's logic: `G[I] true = true`, `F[I] false = false`, `φ U[I] false = false`,
    /// and, for a formula as written whose window starts at 0 (the current state lies in it),
    /// `G[0,b] c = F[0,b] c = φ U[0,b] c = c` for a constant `c`, `false U[0,b] ψ = ψ`,
    /// `false U[a,b] ψ = false` for `a > 0`, and `true U[I] ψ = F[I] ψ`. Anchored windows
    /// (pending obligations, whose bodies are never constant) only take the first three.
    pub(crate) fn always(&mut self, w: Window, a: NodeId) -> NodeId {
        if a == TRUE || starts_now(w) && is_constant(a) {
            return a;
        }
        self.intern(Node::Always(w, a))
    }

    pub(crate) fn eventually(&mut self, w: Window, a: NodeId) -> NodeId {
        if a == FALSE || starts_now(w) && is_constant(a) {
            return a;
        }
        self.intern(Node::Eventually(w, a))
    }

    pub(crate) fn until(&mut self, w: Window, a: NodeId, b: NodeId) -> NodeId {
        if b == FALSE || starts_now(w) && is_constant(b) {
            return b;
        }
        if let Window::Rel(iv) = w {
            if a == FALSE {
                return if iv.lo == 0 { b } else { FALSE };
            }
            if a == TRUE {
                return self.eventually(w, b);
            }
        }
        self.intern(Node::Until(w, a, b))
    }

    pub(crate) fn quantifier(
        &mut self,
        forall: bool,
        var: Sym,
        domain: Arc<[Sym]>,
        body: NodeId,
    ) -> NodeId {
        if domain.is_empty() {
            // ∀ over nothing is true, ∃ over nothing false.
            return if forall { TRUE } else { FALSE };
        }
        if is_constant(body) {
            return body;
        }
        self.intern(if forall {
            Node::Forall(var, domain, body)
        } else {
            Node::Exists(var, domain, body)
        })
    }

    /// Reclaims every node no root reaches when the store has grown to twice what was live
    /// after the previous collection (amortised constant time per node). Returns whether it
    /// collected (ids of reclaimed nodes are reused afterwards, so callers drop memo tables).
    pub(crate) fn maybe_collect(&mut self, roots: impl Iterator<Item = NodeId>) -> bool {
        if self.allocated() < 2 * self.live_after_collect.max(4096) {
            return false;
        }
        self.collect(roots);
        true
    }

    /// Mark and sweep from `roots`.
    pub(crate) fn collect(&mut self, roots: impl Iterator<Item = NodeId>) {
        let mut marked = vec![false; self.nodes.len()];
        for c in [FALSE, TRUE, UNKNOWN] {
            marked[c.0 as usize] = true;
        }
        let mut stack: Vec<NodeId> = roots.collect();
        while let Some(n) = stack.pop() {
            let m = &mut marked[n.0 as usize];
            if *m {
                continue;
            }
            *m = true;
            match &self.nodes[n.0 as usize] {
                Node::False | Node::True | Node::Unknown | Node::Atom(_) | Node::Free => {}
                Node::Not(a)
                | Node::Next(_, a)
                | Node::Always(_, a)
                | Node::Eventually(_, a)
                | Node::Forall(_, _, a)
                | Node::Exists(_, _, a) => stack.push(*a),
                Node::Until(_, a, b) => {
                    stack.push(*a);
                    stack.push(*b);
                }
                Node::And(xs) | Node::Or(xs) => stack.extend(xs.iter().copied()),
            }
        }
        let mut live = 0;
        for (i, m) in marked.iter().enumerate() {
            if *m {
                live += 1;
                continue;
            }
            if matches!(self.nodes[i], Node::Free) {
                continue;
            }
            let id = NodeId(u32::try_from(i).unwrap_or(u32::MAX));
            let hash = node_hash(&self.nodes[i]);
            if let Ok(entry) = self.index.find_entry(hash, |x| *x == id) {
                entry.remove();
            }
            self.nodes[i] = Node::Free;
            self.free.push(id);
        }
        self.live_after_collect = live;
    }

    /// The number of distinct nodes reachable from `root` (a formula's size).
    pub(crate) fn size(&self, root: NodeId) -> usize {
        let mut seen = rustc_hash::FxHashSet::default();
        let mut stack = vec![root];
        while let Some(n) = stack.pop() {
            if !seen.insert(n) {
                continue;
            }
            match self.node(n) {
                Node::Not(a)
                | Node::Next(_, a)
                | Node::Always(_, a)
                | Node::Eventually(_, a)
                | Node::Forall(_, _, a)
                | Node::Exists(_, _, a) => stack.push(*a),
                Node::Until(_, a, b) => stack.extend([*a, *b]),
                Node::And(xs) | Node::Or(xs) => stack.extend(xs.iter().copied()),
                _ => {}
            }
        }
        seen.len()
    }
}

/// A node's hash for the hash-consing index; a junction hashes as its kind and members, so
/// [`Dag::junction`] can look one up without building it ([`junction_hash`]).
fn node_hash(n: &Node) -> u64 {
    let h = FxBuildHasher;
    match n {
        Node::False => h.hash_one(0u8),
        Node::True => h.hash_one(1u8),
        Node::Unknown => h.hash_one(2u8),
        Node::Atom(a) => h.hash_one((3u8, a)),
        Node::Not(a) => h.hash_one((4u8, a)),
        Node::And(xs) => junction_hash(true, xs),
        Node::Or(xs) => junction_hash(false, xs),
        Node::Next(k, a) => h.hash_one((7u8, k, a)),
        Node::Always(w, a) => h.hash_one((8u8, w, a)),
        Node::Eventually(w, a) => h.hash_one((9u8, w, a)),
        Node::Until(w, a, b) => h.hash_one((10u8, w, a, b)),
        Node::Forall(x, d, a) => h.hash_one((11u8, x, &**d, a)),
        Node::Exists(x, d, a) => h.hash_one((12u8, x, &**d, a)),
        Node::Free => h.hash_one(13u8),
    }
}

fn junction_hash(conj: bool, members: &[NodeId]) -> u64 {
    FxBuildHasher.hash_one((if conj { 5u8 } else { 6u8 }, members))
}

/// Whether a window of a formula as written starts at the state it is progressed at.
fn starts_now(w: Window) -> bool {
    matches!(w, Window::Rel(iv) if iv.lo == 0)
}

/// Whether `n` is `true`, `false` or `unknown`.
pub(crate) fn is_constant(n: NodeId) -> bool {
    n.0 <= UNKNOWN.0
}

fn max_hi(a: Option<u64>, b: Option<u64>) -> Option<u64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.max(b)),
        _ => None,
    }
}

/// Whether `outer ⊇ inner`.
fn contains(outer: Interval, inner: Interval) -> bool {
    outer.lo <= inner.lo
        && match (outer.hi, inner.hi) {
            (None, _) => true,
            (Some(_), None) => false,
            (Some(o), Some(i)) => i <= o,
        }
}

/// Whether `b` (with `b.lo ≥ a.lo`) overlaps `a` or starts right after it.
fn touches(a: Interval, b: Interval) -> bool {
    a.hi.is_none_or(|h| b.lo <= h.saturating_add(1))
}
