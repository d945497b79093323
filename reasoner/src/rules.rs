//! The compiled schema, integer-encoded and indexed the two ways the engine needs: forward (a
//! fact matches a rule body) and backward (which rules can produce a fact, for re-derivation).

use oxrdf::vocab::rdf;
use rustc_hash::{FxHashMap, FxHashSet};

use crate::dictionary::{Dictionary, Id};
use crate::tbox::{Prop, TBox};

/// A property link of a rule body: `(x P y)` read forward, or backward when `inverse`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) struct Link {
    pub(crate) prop: Id,
    pub(crate) inverse: bool,
}

/// `P1 ∘ … ∘ Pn ⊑ Q` (prp-spo2), `Q` read backward when `head.inverse`.
#[derive(Debug, Clone)]
pub(crate) struct Chain {
    pub(crate) body: Vec<Link>,
    pub(crate) head: Link,
}

/// `C ⊑ ≤ 0 P.D`, encoded.
#[derive(Debug, Clone)]
pub(crate) struct MaxZeroRule {
    pub(crate) class: Id,
    pub(crate) link: Link,
    pub(crate) filler: Option<Id>,
    pub(crate) axiom: usize,
}

/// `∃ P.D ⊑ C`, encoded.
#[derive(Debug, Clone)]
pub(crate) struct SomeValuesRule {
    pub(crate) link: Link,
    pub(crate) filler: Option<Id>,
    pub(crate) class: Id,
}

/// The rules, encoded.
#[derive(Debug, Clone, Default)]
pub(crate) struct Rules {
    pub(crate) rdf_type: Id,
    /// cax-sco: class → direct super-classes.
    pub(crate) supers: FxHashMap<Id, Vec<Id>>,
    /// class → direct sub-classes (re-derivation).
    pub(crate) subs: FxHashMap<Id, Vec<Id>>,
    /// prp-spo1/eqp/inv/symp: body property → (head property, flip).
    pub(crate) prop_heads: FxHashMap<Id, Vec<(Id, bool)>>,
    /// head property → (body property, flip) (re-derivation).
    pub(crate) prop_bodies: FxHashMap<Id, Vec<(Id, bool)>>,
    /// prp-dom/rng: property → (class, whether the class applies to the object).
    pub(crate) domains: FxHashMap<Id, Vec<(Id, bool)>>,
    /// class → (property, object side) (re-derivation).
    pub(crate) typed_by: FxHashMap<Id, Vec<(Id, bool)>>,
    /// prp-trp.
    pub(crate) transitive: FxHashSet<Id>,
    /// prp-spo2.
    pub(crate) chains: Vec<Chain>,
    /// property → (chain, position) where it occurs in a chain body.
    pub(crate) chain_by_prop: FxHashMap<Id, Vec<(usize, usize)>>,
    /// head property → chains producing it.
    pub(crate) chain_by_head: FxHashMap<Id, Vec<usize>>,
    /// cls-svf1/2 indexed by property, by filler class, and by head class.
    pub(crate) svf: Vec<SomeValuesRule>,
    pub(crate) svf_by_prop: FxHashMap<Id, Vec<usize>>,
    pub(crate) svf_by_filler: FxHashMap<Id, Vec<usize>>,
    pub(crate) svf_by_class: FxHashMap<Id, Vec<usize>>,
    /// The text of every axiom a constraint comes from.
    pub(crate) axioms: Vec<String>,
    /// cax-dw: class → (disjoint class, axiom).
    pub(crate) disjoint_classes: FxHashMap<Id, Vec<(Id, usize)>>,
    /// prp-pdw: property → (disjoint property, flip, axiom).
    pub(crate) disjoint_props: FxHashMap<Id, Vec<(Id, bool, usize)>>,
    /// prp-irp.
    pub(crate) irreflexive: FxHashMap<Id, usize>,
    /// prp-asyp.
    pub(crate) asymmetric: FxHashMap<Id, usize>,
    /// cls-maxqc1/2, cls-maxc1, indexed by class, by property and by filler.
    pub(crate) max_zero: Vec<MaxZeroRule>,
    pub(crate) max_zero_by_class: FxHashMap<Id, Vec<usize>>,
    pub(crate) max_zero_by_prop: FxHashMap<Id, Vec<usize>>,
    pub(crate) max_zero_by_filler: FxHashMap<Id, Vec<usize>>,
    /// prp-fp on data properties.
    pub(crate) functional_data: FxHashMap<Id, usize>,
}

impl Rules {
    pub(crate) fn compile(tbox: &TBox, dict: &mut Dictionary) -> Self {
        let mut rules = Self {
            rdf_type: dict.encode(rdf::TYPE),
            ..Self::default()
        };
        let link = |p: &Prop, dict: &mut Dictionary| Link {
            prop: dict.encode(p.iri.clone()),
            inverse: p.inverse,
        };
        for (sub, sup) in &tbox.sub_class {
            let (a, b) = (dict.encode(sub.clone()), dict.encode(sup.clone()));
            if a != b {
                rules.supers.entry(a).or_default().push(b);
                rules.subs.entry(b).or_default().push(a);
            }
        }
        for (sub, sup) in &tbox.sub_prop {
            let (a, b) = (link(sub, dict), link(sup, dict));
            let flip = a.inverse != b.inverse;
            if a.prop == b.prop && !flip {
                continue;
            }
            rules
                .prop_heads
                .entry(a.prop)
                .or_default()
                .push((b.prop, flip));
            rules
                .prop_bodies
                .entry(b.prop)
                .or_default()
                .push((a.prop, flip));
        }
        for (p, c) in &tbox.domain {
            let (l, c) = (link(p, dict), dict.encode(c.clone()));
            rules
                .domains
                .entry(l.prop)
                .or_default()
                .push((c, l.inverse));
            rules
                .typed_by
                .entry(c)
                .or_default()
                .push((l.prop, l.inverse));
        }
        for p in &tbox.transitive {
            rules.transitive.insert(dict.encode(p.clone()));
        }
        for (body, head) in &tbox.chains {
            let chain = Chain {
                body: body.iter().map(|p| link(p, dict)).collect(),
                head: link(head, dict),
            };
            let index = rules.chains.len();
            for (position, l) in chain.body.iter().enumerate() {
                rules
                    .chain_by_prop
                    .entry(l.prop)
                    .or_default()
                    .push((index, position));
            }
            rules
                .chain_by_head
                .entry(chain.head.prop)
                .or_default()
                .push(index);
            rules.chains.push(chain);
        }
        for sv in &tbox.some_values {
            let rule = SomeValuesRule {
                link: link(&sv.prop, dict),
                filler: sv.filler.as_ref().map(|f| dict.encode(f.clone())),
                class: dict.encode(sv.class.clone()),
            };
            let index = rules.svf.len();
            rules
                .svf_by_prop
                .entry(rule.link.prop)
                .or_default()
                .push(index);
            if let Some(f) = rule.filler {
                rules.svf_by_filler.entry(f).or_default().push(index);
            }
            rules
                .svf_by_class
                .entry(rule.class)
                .or_default()
                .push(index);
            rules.svf.push(rule);
        }
        let axiom = |rules: &mut Self, text: &str| {
            rules.axioms.push(text.to_owned());
            rules.axioms.len() - 1
        };
        // `DisjointClasses(A B)` and `DisjointClasses(B A)` (two `owl:disjointWith` triples, one
        // each way) are one constraint: a pair stated again is left out, so that an individual in
        // both classes is one violation, reported with the first axiom that states it.
        let mut pairs: FxHashSet<(Id, Id, bool)> = FxHashSet::default();
        let unordered = |a: Id, b: Id, flip: bool| (a.min(b), a.max(b), flip);
        for (a, b, text) in &tbox.disjoint_classes {
            let (a, b) = (dict.encode(a.clone()), dict.encode(b.clone()));
            if !pairs.insert(unordered(a, b, false)) {
                continue;
            }
            let ax = axiom(&mut rules, text);
            rules.disjoint_classes.entry(a).or_default().push((b, ax));
            rules.disjoint_classes.entry(b).or_default().push((a, ax));
        }
        pairs.clear();
        for (a, b, text) in &tbox.disjoint_props {
            let (a, b) = (link(a, dict), link(b, dict));
            let flip = a.inverse != b.inverse;
            if !pairs.insert(unordered(a.prop, b.prop, flip)) {
                continue;
            }
            let ax = axiom(&mut rules, text);
            rules
                .disjoint_props
                .entry(a.prop)
                .or_default()
                .push((b.prop, flip, ax));
            rules
                .disjoint_props
                .entry(b.prop)
                .or_default()
                .push((a.prop, flip, ax));
        }
        for (p, text) in &tbox.irreflexive {
            let ax = axiom(&mut rules, text);
            rules.irreflexive.insert(dict.encode(p.clone()), ax);
        }
        for (p, text) in &tbox.asymmetric {
            let ax = axiom(&mut rules, text);
            rules.asymmetric.insert(dict.encode(p.clone()), ax);
        }
        for mz in &tbox.max_zero {
            let ax = axiom(&mut rules, &mz.axiom);
            let rule = MaxZeroRule {
                class: dict.encode(mz.class.clone()),
                link: link(&mz.prop, dict),
                filler: mz.filler.as_ref().map(|f| dict.encode(f.clone())),
                axiom: ax,
            };
            let index = rules.max_zero.len();
            rules
                .max_zero_by_class
                .entry(rule.class)
                .or_default()
                .push(index);
            rules
                .max_zero_by_prop
                .entry(rule.link.prop)
                .or_default()
                .push(index);
            if let Some(f) = rule.filler {
                rules.max_zero_by_filler.entry(f).or_default().push(index);
            }
            rules.max_zero.push(rule);
        }
        for (p, text) in &tbox.functional_data {
            let ax = axiom(&mut rules, text);
            rules.functional_data.insert(dict.encode(p.clone()), ax);
        }
        rules
    }
}
