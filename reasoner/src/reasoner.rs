//! The engine: semi-naive materialisation, DRed maintenance under deletions, and the
//! consistency rules.

use std::collections::BTreeSet;

use oxrdf::{Term, Triple};
use rustc_hash::{FxHashMap, FxHashSet};

use crate::dictionary::{Dictionary, Fact, Id};
use crate::facts::FactSet;
use crate::rules::{Link, Rules};
use crate::tbox::TBox;

/// A violated consistency rule: the rule (OWL 2 RL name), the axiom it checks (OWL functional
/// syntax) and the nodes involved.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Violation {
    /// The OWL 2 RL rule, e.g. `cax-dw`.
    pub rule: &'static str,
    /// The violated axiom, in OWL functional syntax.
    pub axiom: String,
    /// The nodes the violation is about (the subject first).
    pub nodes: Vec<Term>,
}

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}:", self.rule, self.axiom)?;
        for n in &self.nodes {
            write!(f, " {n}")?;
        }
        Ok(())
    }
}

/// What an update changed in the inferred triples (the materialisation less the explicit
/// triples), and the violations it introduced.
#[derive(Debug, Clone, Default)]
pub struct Update {
    /// Triples that became inferred.
    pub inferred_added: Vec<Triple>,
    /// Triples that are no longer inferred (no longer entailed, or now explicit).
    pub inferred_removed: Vec<Triple>,
    /// Violations that involve a triple the update made true.
    pub violations: Vec<Violation>,
}

impl Update {
    /// Whether the update changed no inferred triple.
    pub fn is_empty(&self) -> bool {
        self.inferred_added.is_empty() && self.inferred_removed.is_empty()
    }
}

/// An incremental OWL 2 RL reasoner over one set of explicit triples (a multiset: the same
/// triple may be asserted by several graphs).
#[derive(Debug, Clone)]
pub struct Reasoner {
    tbox: TBox,
    dict: Dictionary,
    rules: Rules,
    /// Explicit facts with the number of times they are asserted.
    explicit: FxHashMap<Fact, u32>,
    /// The schema closure: facts that hold whatever the data.
    axiomatic: FxHashSet<Fact>,
    /// The materialisation: explicit, axiomatic and derived facts.
    facts: FactSet,
    /// The *base* facts of transitive properties: explicit, axiomatic, or derived by a rule
    /// other than prp-trp. Every fact of a transitive property is in the transitive closure of
    /// its base facts, which the engine derives left-linearly (see [`Event`]).
    base: FactSet,
    /// The explicit facts of each named source (graph), for [`Reasoner::set_graphs`].
    graphs: FxHashMap<String, Vec<Fact>>,
}

type Violations = BTreeSet<(&'static str, usize, Vec<Id>)>;

/// What the semi-naive loop and DRed's over-deletion propagate: a fact entering (or leaving)
/// the materialisation, or a fact of a transitive property entering (or leaving) its base.
#[derive(Debug, Clone, Copy)]
enum Event {
    Fact(Fact),
    Base(Fact),
}

/// The triples of a named source (a graph), by name.
pub type NamedTriples = (String, Vec<Triple>);

impl Reasoner {
    /// A reasoner for `tbox` with no explicit triples (the schema closure holds already).
    pub fn new(tbox: TBox) -> Self {
        let mut dict = Dictionary::default();
        let rules = Rules::compile(&tbox, &mut dict);
        let mut reasoner = Self {
            tbox,
            dict,
            rules,
            explicit: FxHashMap::default(),
            axiomatic: FxHashSet::default(),
            facts: FactSet::default(),
            base: FactSet::default(),
            graphs: FxHashMap::default(),
        };
        let closure: Vec<Fact> = reasoner
            .tbox
            .schema_closure()
            .to_vec()
            .iter()
            .map(|t| reasoner.encode(t))
            .collect();
        let mut queue = Vec::new();
        for f in closure {
            reasoner.axiomatic.insert(f);
            reasoner.assert_fact(f, &mut queue);
        }
        reasoner.saturate(queue);
        reasoner.dict.pin();
        reasoner
    }

    /// The compiled schema.
    pub fn tbox(&self) -> &TBox {
        &self.tbox
    }

    /// The number of facts in the materialisation (explicit, schema closure and inferred).
    pub fn len(&self) -> usize {
        self.facts.len()
    }

    /// Whether the materialisation is empty.
    pub fn is_empty(&self) -> bool {
        self.facts.len() == 0
    }

    /// The number of terms the reasoner holds: the schema's and those of the explicit triples
    /// (terms no triple uses any more are released).
    pub fn terms(&self) -> usize {
        self.dict.len()
    }

    /// The number of distinct explicit triples.
    pub fn explicit_len(&self) -> usize {
        self.explicit.len()
    }

    fn encode(&mut self, t: &Triple) -> Fact {
        [
            self.dict.encode(t.subject.clone()),
            self.dict.encode(t.predicate.clone()),
            self.dict.encode(t.object.clone()),
        ]
    }

    fn decode(&self, [s, p, o]: Fact) -> Option<Triple> {
        let subject = match self.dict.decode(s) {
            Term::NamedNode(n) => oxrdf::NamedOrBlankNode::from(n.clone()),
            Term::BlankNode(b) => oxrdf::NamedOrBlankNode::from(b.clone()),
            Term::Literal(_) => return None,
            #[allow(unreachable_patterns)]
            _ => return None,
        };
        let Term::NamedNode(predicate) = self.dict.decode(p) else {
            return None;
        };
        Some(Triple::new(
            subject,
            predicate.clone(),
            self.dict.decode(o).clone(),
        ))
    }

    fn is_explicit(&self, f: &Fact) -> bool {
        self.explicit.contains_key(f)
    }

    /// The triples that are entailed and not explicit (the inferred graph), sorted.
    pub fn inferred(&self) -> Vec<Triple> {
        let mut out: Vec<Triple> = self
            .facts
            .iter()
            .filter(|f| !self.is_explicit(f))
            .filter_map(|f| self.decode(*f))
            .collect();
        out.sort_by_cached_key(ToString::to_string);
        out
    }

    /// Whether the materialisation holds `triple`.
    pub fn entails(&self, triple: &Triple) -> bool {
        let enc = |t: Term| self.dict.get(&t);
        match (
            enc(triple.subject.clone().into()),
            enc(triple.predicate.clone().into()),
            enc(triple.object.clone()),
        ) {
            (Some(s), Some(p), Some(o)) => self.facts.contains(&[s, p, o]),
            _ => false,
        }
    }

    /// The objects `o` of the entailed triples `(subject, predicate, o)`.
    pub fn objects(&self, subject: &Term, predicate: &oxrdf::NamedNode) -> Vec<Term> {
        let (Some(s), Some(p)) = (
            self.dict.get(subject),
            self.dict.get(&Term::from(predicate.clone())),
        ) else {
            return Vec::new();
        };
        self.facts
            .objects(p, s)
            .iter()
            .map(|o| self.dict.decode(*o).clone())
            .collect()
    }

    /// Removes one assertion of each triple of `removed` and adds one of each of `added`, and
    /// brings the materialisation up to date: DRed for what lost support, semi-naive
    /// evaluation from the delta for what was added.
    pub fn update(&mut self, removed: &[Triple], added: &[Triple]) -> Update {
        let removed: Vec<Fact> = removed.iter().map(|t| self.encode(t)).collect();
        let added: Vec<Fact> = added.iter().map(|t| self.encode(t)).collect();
        self.update_facts(&removed, &added)
    }

    /// Sets the explicit triples of named sources (graphs): each `(name, triples)` replaces what
    /// the source held (an empty list removes it), as one update. Returns the update and the
    /// previous contents, which given back to `set_graphs` undo it. Removing a source removes
    /// exactly the facts it added, whatever form a store later gives its terms back in.
    pub fn set_graphs(
        &mut self,
        changes: &[(String, Vec<Triple>)],
    ) -> (Update, Vec<(String, Vec<Triple>)>) {
        let mut removed = Vec::new();
        let mut added = Vec::new();
        let mut previous = Vec::new();
        for (name, triples) in changes {
            let old = self.graphs.remove(name).unwrap_or_default();
            previous.push((
                name.clone(),
                old.iter().filter_map(|f| self.decode(*f)).collect(),
            ));
            removed.extend(old);
            let new: Vec<Fact> = triples.iter().map(|t| self.encode(t)).collect();
            added.extend(new.iter().copied());
            if !new.is_empty() {
                self.graphs.insert(name.clone(), new);
            }
        }
        (self.update_facts(&removed, &added), previous)
    }

    /// The explicit triples of a named source.
    pub fn graph(&self, name: &str) -> Vec<Triple> {
        self.graphs
            .get(name)
            .into_iter()
            .flatten()
            .filter_map(|f| self.decode(*f))
            .collect()
    }

    fn update_facts(&mut self, removed: &[Fact], added: &[Fact]) -> Update {
        // Explicitness before and after, for every touched fact.
        let mut touched: FxHashMap<Fact, bool> = FxHashMap::default();
        for f in removed.iter().chain(added) {
            let before = self.facts.contains(f) && !self.is_explicit(f);
            touched.entry(*f).or_insert(before);
        }
        for f in removed {
            if let Some(n) = self.explicit.get_mut(f) {
                *n -= 1;
                if *n == 0 {
                    self.explicit.remove(f);
                    for id in f {
                        self.dict.remove_use(*id);
                    }
                }
            }
        }
        for f in added {
            let n = self.explicit.entry(*f).or_insert(0);
            *n += 1;
            if *n == 1 {
                for id in f {
                    self.dict.add_use(*id);
                }
            }
        }
        let gone: Vec<Fact> = touched
            .keys()
            .filter(|f| self.facts.contains(f) && !self.is_explicit(f))
            .copied()
            .collect();
        let appeared: Vec<Fact> = touched
            .keys()
            .filter(|f| self.is_explicit(f))
            .copied()
            .collect();

        let (over_deleted, rederived) = self.delete(&gone);
        let mut queue = Vec::new();
        for f in appeared {
            self.assert_fact(f, &mut queue);
        }
        let mut new_facts = rederived;
        new_facts.extend(self.saturate(queue));

        // Inferred before: touched facts as recorded; over-deleted facts were inferred (DRed
        // never deletes an explicit fact) unless they were explicit before; new facts were
        // absent unless DRed had deleted them.
        for f in &over_deleted {
            touched.entry(*f).or_insert(true);
        }
        for f in &new_facts {
            touched.entry(*f).or_insert(false);
        }
        let mut update = Update::default();
        for (f, before) in &touched {
            let after = self.facts.contains(f) && !self.is_explicit(f);
            if before != &after
                && let Some(t) = self.decode(*f)
            {
                if after {
                    update.inferred_added.push(t);
                } else {
                    update.inferred_removed.push(t);
                }
            }
        }
        let mut found = Violations::new();
        for f in &new_facts {
            self.check_fact(*f, &mut found);
        }
        update.violations = self.violations_of(found);
        // Every fact is up to date: terms no explicit fact uses are in no fact any more.
        self.dict.release_unused();
        update
    }

    /// Every violation in the current materialisation.
    pub fn violations(&self) -> Vec<Violation> {
        let mut found = Violations::new();
        for f in self.facts.iter() {
            self.check_fact(*f, &mut found);
        }
        self.violations_of(found)
    }

    fn violations_of(&self, found: Violations) -> Vec<Violation> {
        let mut out: Vec<Violation> = found
            .into_iter()
            .map(|(rule, axiom, nodes)| {
                let mut nodes: Vec<Term> =
                    nodes.iter().map(|n| self.dict.decode(*n).clone()).collect();
                // Rules whose nodes have no inherent order list them sorted, so the same
                // violation reads the same whichever fact revealed it.
                match rule {
                    "prp-asyp" | "prp-pdw" => nodes.sort_by_cached_key(ToString::to_string),
                    "prp-fp" => nodes[1..].sort_by_cached_key(ToString::to_string),
                    _ => {}
                }
                Violation {
                    rule,
                    axiom: self.rules.axioms[axiom].clone(),
                    nodes,
                }
            })
            .collect();
        out.sort_by_cached_key(ToString::to_string);
        out.dedup();
        out
    }

    /// Puts a fact that holds by itself or by a rule other than prp-trp (explicit, axiomatic,
    /// or a rule head) into the materialisation, and into the base facts when its property is
    /// transitive, queueing what changed.
    fn assert_fact(&mut self, f: Fact, queue: &mut Vec<Event>) {
        if self.rules.transitive.contains(&f[1]) && self.base.insert(f) {
            queue.push(Event::Base(f));
        }
        if self.facts.insert(f) {
            queue.push(Event::Fact(f));
        }
    }

    /// Semi-naive evaluation: every event of `queue` is in the materialisation already; each
    /// fact derived is inserted once and joined once with everything present. prp-trp is
    /// evaluated left-linearly, `T(x, z) ← B(x, y) ∧ T(y, z)` with `B` the base facts and `T`
    /// all facts of the property, so each fact of the closure is derived once per base edge
    /// into its subject (a chain of n nodes costs O(n²), where the symmetric rule costs O(n³)).
    /// Returns every fact inserted, those of `queue` included.
    fn saturate(&mut self, mut queue: Vec<Event>) -> Vec<Fact> {
        let mut inserted = Vec::new();
        let mut heads = Vec::new();
        while let Some(event) = queue.pop() {
            match event {
                Event::Fact(f) => {
                    inserted.push(f);
                    self.consequences(f, &mut heads);
                    for h in heads.drain(..) {
                        self.assert_fact(h, &mut queue);
                    }
                    let [s, p, o] = f;
                    if self.rules.transitive.contains(&p) {
                        // A new T(s, o) joins every B(x, s).
                        for x in self.base.subjects(p, s) {
                            if self.facts.insert([*x, p, o]) {
                                queue.push(Event::Fact([*x, p, o]));
                            }
                        }
                    }
                }
                Event::Base([s, p, o]) => {
                    // A new B(s, o) joins every T(o, z).
                    let reached: Vec<Id> = self.facts.objects(p, o).iter().copied().collect();
                    for z in reached {
                        if self.facts.insert([s, p, z]) {
                            queue.push(Event::Fact([s, p, z]));
                        }
                    }
                }
            }
        }
        inserted
    }

    /// Whether DRed may over-delete `f`: explicit and axiomatic facts hold whatever else goes.
    fn removable(&self, f: &Fact) -> bool {
        !self.is_explicit(f) && !self.axiomatic.contains(f)
    }

    /// DRed: over-deletes everything with a derivation through a `gone` fact, then re-derives
    /// what still has one and saturates from there. Base facts of transitive properties are
    /// over-deleted and re-derived as a relation of their own, so removing an edge from the
    /// middle of a chain over-deletes exactly the pairs that ran through it. Returns the facts
    /// over-deleted and those re-derived.
    fn delete(&mut self, gone: &[Fact]) -> (Vec<Fact>, Vec<Fact>) {
        let mut over: FxHashSet<Fact> = FxHashSet::default();
        let mut over_base: FxHashSet<Fact> = FxHashSet::default();
        let mut queue: Vec<Event> = gone
            .iter()
            .map(|f| {
                if self.base.contains(f) {
                    Event::Base(*f)
                } else {
                    Event::Fact(*f)
                }
            })
            .collect();
        let mut heads = Vec::new();
        while let Some(event) = queue.pop() {
            match event {
                Event::Fact(f) => {
                    if !over.insert(f) {
                        continue;
                    }
                    self.consequences(f, &mut heads);
                    for h in heads.drain(..) {
                        if !self.removable(&h) {
                            continue;
                        }
                        if self.base.contains(&h) {
                            if !over_base.contains(&h) {
                                queue.push(Event::Base(h));
                            }
                        } else if self.facts.contains(&h) && !over.contains(&h) {
                            queue.push(Event::Fact(h));
                        }
                    }
                    let [s, p, o] = f;
                    if self.rules.transitive.contains(&p) {
                        for x in self.base.subjects(p, s) {
                            let h = [*x, p, o];
                            if self.facts.contains(&h) && !over.contains(&h) && self.removable(&h) {
                                queue.push(Event::Fact(h));
                            }
                        }
                    }
                }
                Event::Base(f) => {
                    if !over_base.insert(f) {
                        continue;
                    }
                    let [s, p, o] = f;
                    if !over.contains(&f) {
                        queue.push(Event::Fact(f));
                    }
                    for z in self.facts.objects(p, o) {
                        let h = [s, p, *z];
                        if self.facts.contains(&h) && !over.contains(&h) && self.removable(&h) {
                            queue.push(Event::Fact(h));
                        }
                    }
                }
            }
        }
        for f in &over {
            self.facts.remove(*f);
        }
        for f in &over_base {
            self.base.remove(*f);
        }
        // Re-derivation: base facts by a rule other than prp-trp, then the rest by any rule.
        let mut queue = Vec::new();
        for f in &over_base {
            if !self.removable(f) || self.derivable(*f) {
                self.assert_fact(*f, &mut queue);
            }
        }
        for f in &over {
            if !self.removable(f) || self.base.contains(f) || self.derivable(*f) {
                self.assert_fact(*f, &mut queue);
            } else if self.derivable_by_trp(*f) && self.facts.insert(*f) {
                // Only prp-trp derives it: a fact of the closure, not a base fact (putting it
                // into the base would let it outlive the base facts it was derived from).
                queue.push(Event::Fact(*f));
            }
        }
        let rederived = self.saturate(queue);
        (over.into_iter().collect(), rederived)
    }

    /// Pushes the head of every rule instance with `f` in its body and the rest of the body in
    /// the materialisation, for every rule but prp-trp (which [`Reasoner::saturate`] and
    /// [`Reasoner::delete`] evaluate left-linearly).
    fn consequences(&self, [s, p, o]: Fact, out: &mut Vec<Fact>) {
        let r = &self.rules;
        let facts = &self.facts;
        let mut emit = |f: Fact| {
            if !self.dict.is_literal(f[0]) {
                out.push(f);
            }
        };
        if p == r.rdf_type {
            // cax-sco, cax-eqc1/2.
            for d in r.supers.get(&o).into_iter().flatten() {
                emit([s, p, *d]);
            }
            // cls-svf1: the typed node is the filler.
            for i in r.svf_by_filler.get(&o).into_iter().flatten() {
                let rule = &r.svf[*i];
                for x in facts.along(rule.link.prop, !rule.link.inverse, s) {
                    emit([*x, r.rdf_type, rule.class]);
                }
            }
            return;
        }
        // prp-spo1, prp-eqp1/2, prp-inv1/2, prp-symp.
        for (q, flip) in r.prop_heads.get(&p).into_iter().flatten() {
            emit(if *flip { [o, *q, s] } else { [s, *q, o] });
        }
        // prp-dom, prp-rng.
        for (c, object_side) in r.domains.get(&p).into_iter().flatten() {
            emit([if *object_side { o } else { s }, r.rdf_type, *c]);
        }
        // prp-spo2.
        for (ci, pos) in r.chain_by_prop.get(&p).into_iter().flatten() {
            let chain = &r.chains[*ci];
            let link = chain.body[*pos];
            let (u, v) = if link.inverse { (o, s) } else { (s, o) };
            let mut left: FxHashSet<Id> = FxHashSet::from_iter([u]);
            for l in chain.body[..*pos].iter().rev() {
                left = step(
                    facts,
                    &left,
                    Link {
                        prop: l.prop,
                        inverse: !l.inverse,
                    },
                );
            }
            let mut right: FxHashSet<Id> = FxHashSet::from_iter([v]);
            for l in &chain.body[*pos + 1..] {
                right = step(facts, &right, *l);
            }
            for x in &left {
                for z in &right {
                    emit(if chain.head.inverse {
                        [*z, chain.head.prop, *x]
                    } else {
                        [*x, chain.head.prop, *z]
                    });
                }
            }
        }
        // cls-svf1/2: the fact is the property link.
        for i in r.svf_by_prop.get(&p).into_iter().flatten() {
            let rule = &r.svf[*i];
            let (x, y) = if rule.link.inverse { (o, s) } else { (s, o) };
            if rule
                .filler
                .is_none_or(|d| facts.contains(&[y, r.rdf_type, d]))
            {
                emit([x, r.rdf_type, rule.class]);
            }
        }
    }

    /// Whether prp-trp, left-linear, derives `f` in one step: `B(s, y) ∧ T(y, o)`.
    fn derivable_by_trp(&self, [s, p, o]: Fact) -> bool {
        self.rules.transitive.contains(&p)
            && self
                .base
                .objects(p, s)
                .iter()
                .any(|y| self.facts.contains(&[*y, p, o]))
    }

    /// Whether a rule other than prp-trp derives `f` in one step from the materialisation
    /// (re-derivation).
    fn derivable(&self, [s, p, o]: Fact) -> bool {
        let r = &self.rules;
        let facts = &self.facts;
        if p == r.rdf_type {
            return r
                .subs
                .get(&o)
                .into_iter()
                .flatten()
                .any(|b| facts.contains(&[s, p, *b]))
                || r.typed_by
                    .get(&o)
                    .into_iter()
                    .flatten()
                    .any(|(q, object_side)| !facts.along(*q, *object_side, s).is_empty())
                || r.svf_by_class.get(&o).into_iter().flatten().any(|i| {
                    let rule = &r.svf[*i];
                    facts
                        .along(rule.link.prop, rule.link.inverse, s)
                        .iter()
                        .any(|y| {
                            rule.filler
                                .is_none_or(|d| facts.contains(&[*y, r.rdf_type, d]))
                        })
                });
        }
        if r.prop_bodies
            .get(&p)
            .into_iter()
            .flatten()
            .any(|(q, flip)| facts.contains(&if *flip { [o, *q, s] } else { [s, *q, o] }))
        {
            return true;
        }
        r.chain_by_head.get(&p).into_iter().flatten().any(|ci| {
            let chain = &r.chains[*ci];
            let (x, z) = if chain.head.inverse { (o, s) } else { (s, o) };
            let mut reach: FxHashSet<Id> = FxHashSet::from_iter([x]);
            for l in &chain.body {
                reach = step(facts, &reach, *l);
                if reach.is_empty() {
                    return false;
                }
            }
            reach.contains(&z)
        })
    }

    /// Records the violations `f` takes part in.
    fn check_fact(&self, [s, p, o]: Fact, found: &mut Violations) {
        let r = &self.rules;
        let facts = &self.facts;
        if p == r.rdf_type {
            for (d, ax) in r.disjoint_classes.get(&o).into_iter().flatten() {
                if facts.contains(&[s, p, *d]) {
                    found.insert(("cax-dw", *ax, vec![s]));
                }
            }
            for i in r.max_zero_by_class.get(&o).into_iter().flatten() {
                let mz = &r.max_zero[*i];
                for y in facts.along(mz.link.prop, mz.link.inverse, s) {
                    if mz.filler.is_none_or(|d| facts.contains(&[*y, p, d])) {
                        found.insert((max_zero_name(mz.filler), mz.axiom, vec![s, *y]));
                    }
                }
            }
            for i in r.max_zero_by_filler.get(&o).into_iter().flatten() {
                let mz = &r.max_zero[*i];
                for x in facts.along(mz.link.prop, !mz.link.inverse, s) {
                    if facts.contains(&[*x, p, mz.class]) {
                        found.insert((max_zero_name(mz.filler), mz.axiom, vec![*x, s]));
                    }
                }
            }
            return;
        }
        for (q, flip, ax) in r.disjoint_props.get(&p).into_iter().flatten() {
            if facts.contains(&if *flip { [o, *q, s] } else { [s, *q, o] }) {
                found.insert(("prp-pdw", *ax, vec![s, o]));
            }
        }
        if let Some(ax) = r.irreflexive.get(&p)
            && s == o
        {
            found.insert(("prp-irp", *ax, vec![s]));
        }
        if let Some(ax) = r.asymmetric.get(&p)
            && facts.contains(&[o, p, s])
        {
            let pair = if s <= o { vec![s, o] } else { vec![o, s] };
            found.insert(("prp-asyp", *ax, pair));
        }
        for i in r.max_zero_by_prop.get(&p).into_iter().flatten() {
            let mz = &r.max_zero[*i];
            let (x, y) = if mz.link.inverse { (o, s) } else { (s, o) };
            if facts.contains(&[x, r.rdf_type, mz.class])
                && mz
                    .filler
                    .is_none_or(|d| facts.contains(&[y, r.rdf_type, d]))
            {
                found.insert((max_zero_name(mz.filler), mz.axiom, vec![x, y]));
            }
        }
        if let Some(ax) = r.functional_data.get(&p)
            && self.dict.is_literal(o)
        {
            let mut values: Vec<Id> = facts
                .objects(p, s)
                .iter()
                .copied()
                .filter(|v| self.dict.is_literal(*v))
                .collect();
            // Two literals of one value (`"1"^^xsd:integer` and `"1.0"^^xsd:decimal`) are
            // one value: only distinct values violate (a user audit got a violation for those).
            let distinct: FxHashSet<String> = values
                .iter()
                .map(|v| literal_value(self.dict.decode(*v)))
                .collect();
            if distinct.len() > 1 {
                values.sort_unstable();
                let mut nodes = vec![s];
                nodes.extend(values);
                found.insert(("prp-fp", *ax, nodes));
            }
        }
    }
}

/// A literal's value, as a key equal for literals of one value in OWL 2's datatype map:
/// `xsd:decimal`, `xsd:integer` and its derived types share one value space (`owl:real`:
/// `"1"`, `"01"`, `"1.0"` are one value), as `xsd:boolean`'s `"1"` and `"true"` do, and
/// `xsd:double`'s (and `xsd:float`'s) `"1E0"` and `"1.0"`; a plain literal is an `xsd:string`.
/// Other literals are their lexical form and datatype. Value spaces stay apart: `"1"^^xsd:integer`
/// and `"1"^^xsd:double` are distinct values in OWL 2.
fn literal_value(term: &Term) -> String {
    let Term::Literal(l) = term else {
        return term.to_string();
    };
    const XSD: &str = "http://www.w3.org/2001/XMLSchema#";
    let datatype = l.datatype().as_str();
    let local = datatype.strip_prefix(XSD).unwrap_or("");
    let lexical = l.value().trim();
    let real = matches!(
        local,
        "decimal"
            | "integer"
            | "nonPositiveInteger"
            | "negativeInteger"
            | "long"
            | "int"
            | "short"
            | "byte"
            | "nonNegativeInteger"
            | "unsignedLong"
            | "unsignedInt"
            | "unsignedShort"
            | "unsignedByte"
            | "positiveInteger"
    );
    if real && let Some(key) = decimal_key(lexical) {
        return format!("real:{key}");
    }
    if local == "boolean" {
        match lexical {
            "1" | "true" => return "boolean:true".to_owned(),
            "0" | "false" => return "boolean:false".to_owned(),
            _ => {}
        }
    }
    // `-0` and `0` are equal; the two types share no values with each other either, and a
    // float is parsed as one (`"0.1"` and `"0.100000001"` are one float).
    if local == "double"
        && let Ok(v) = lexical.parse::<f64>()
        && !v.is_nan()
    {
        let v = if v == 0.0 { 0.0 } else { v };
        return format!("double:{v:?}");
    }
    if local == "float"
        && let Ok(v) = lexical.parse::<f32>()
        && !v.is_nan()
    {
        let v = if v == 0.0 { 0.0 } else { v };
        return format!("float:{v:?}");
    }
    if local == "string" && l.language().is_none() {
        return format!("string:{}", l.value());
    }
    term.to_string()
}

/// A decimal numeral in a canonical form (no sign for zero, no leading zeros, no trailing
/// fractional zeros), or `None` if it is not one.
fn decimal_key(text: &str) -> Option<String> {
    let (negative, digits) = match text.as_bytes().first()? {
        b'-' => (true, &text[1..]),
        b'+' => (false, &text[1..]),
        _ => (false, text),
    };
    let (whole, fraction) = digits.split_once('.').unwrap_or((digits, ""));
    if whole.is_empty() && fraction.is_empty()
        || !whole
            .bytes()
            .chain(fraction.bytes())
            .all(|b| b.is_ascii_digit())
    {
        return None;
    }
    let whole = whole.trim_start_matches('0');
    let fraction = fraction.trim_end_matches('0');
    let zero = whole.is_empty() && fraction.is_empty();
    let sign = if negative && !zero { "-" } else { "" };
    let whole = if whole.is_empty() { "0" } else { whole };
    Some(if fraction.is_empty() {
        format!("{sign}{whole}")
    } else {
        format!("{sign}{whole}.{fraction}")
    })
}

fn max_zero_name(filler: Option<Id>) -> &'static str {
    if filler.is_some() {
        "cls-maxqc1"
    } else {
        "cls-maxqc2"
    }
}

/// The nodes reached from `from` along one link.
fn step(facts: &FactSet, from: &FxHashSet<Id>, link: Link) -> FxHashSet<Id> {
    let mut next = FxHashSet::default();
    for n in from {
        next.extend(facts.along(link.prop, link.inverse, *n).iter().copied());
    }
    next
}
