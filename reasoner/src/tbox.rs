//! The schema: OWL axioms read with horned-owl, compiled into the OWL 2 RL rules the reasoner
//! runs (<https://www.w3.org/TR/owl2-profiles/#OWL_2_RL>, Tables 4–9), plus the `scm-*` closure
//! of the schema itself.

use std::collections::{BTreeMap, BTreeSet};

use dyknow_ontology::vocab::owl;
use horned_owl::io::ofn::writer::AsFunctional;
use horned_owl::model::{
    AnnotatedComponent, ArcStr, ClassExpression, Component, ObjectPropertyExpression,
    SubObjectPropertyExpression,
};
use oxrdf::vocab::{rdf, rdfs};
use oxrdf::{NamedNode, Triple};
use oxrdfio::RdfFormat;

use crate::error::SchemaError;

/// A property expression: a named property, or its inverse.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) struct Prop {
    pub(crate) iri: NamedNode,
    pub(crate) inverse: bool,
}

impl Prop {
    fn flipped(&self) -> Self {
        Self {
            iri: self.iri.clone(),
            inverse: !self.inverse,
        }
    }
}

/// A class constraint `C ⊑ ≤ 0 P.D` (cls-maxqc1/2, cls-maxc1). `filler: None` is `owl:Thing`.
#[derive(Debug, Clone)]
pub(crate) struct MaxZero {
    pub(crate) class: NamedNode,
    pub(crate) prop: Prop,
    pub(crate) filler: Option<NamedNode>,
    pub(crate) axiom: String,
}

/// `∃ P.D ⊑ C` (cls-svf1, cls-svf2 with `filler: None`).
#[derive(Debug, Clone)]
pub(crate) struct SomeValues {
    pub(crate) prop: Prop,
    pub(crate) filler: Option<NamedNode>,
    pub(crate) class: NamedNode,
}

/// The schema, compiled: every axiom the reasoner supports as a rule or a constraint, and the
/// axioms it does not support, by name.
#[derive(Debug, Clone, Default)]
pub struct TBox {
    /// `sub ⊑ sup` between named classes (cax-sco; cax-eqc1/2 give both directions).
    pub(crate) sub_class: BTreeSet<(NamedNode, NamedNode)>,
    /// `sub ⊑ sup` between property expressions (prp-spo1, prp-eqp1/2, prp-inv1/2, prp-symp).
    pub(crate) sub_prop: BTreeSet<(Prop, Prop)>,
    /// `P1 ∘ … ∘ Pn ⊑ Q` (prp-spo2).
    pub(crate) chains: Vec<(Vec<Prop>, Prop)>,
    /// Transitive properties (prp-trp).
    pub(crate) transitive: BTreeSet<NamedNode>,
    /// Domains (prp-dom) and, as domains of the inverse, ranges (prp-rng).
    pub(crate) domain: BTreeSet<(Prop, NamedNode)>,
    /// Existential restrictions on the sub-class side (cls-svf1/2).
    pub(crate) some_values: Vec<SomeValues>,
    /// Disjoint classes with the axiom that says so (cax-dw).
    pub(crate) disjoint_classes: Vec<(NamedNode, NamedNode, String)>,
    /// Disjoint property expressions (prp-pdw).
    pub(crate) disjoint_props: Vec<(Prop, Prop, String)>,
    /// Irreflexive properties (prp-irp).
    pub(crate) irreflexive: Vec<(NamedNode, String)>,
    /// Asymmetric properties (prp-asyp).
    pub(crate) asymmetric: Vec<(NamedNode, String)>,
    /// Cardinality-0 restrictions (cls-maxqc1/2, cls-maxc1).
    pub(crate) max_zero: Vec<MaxZero>,
    /// Functional data properties (prp-fp on literals: two distinct values are a violation).
    pub(crate) functional_data: Vec<(NamedNode, String)>,
    /// The axioms no supported rule covers, in OWL functional syntax.
    unsupported: Vec<String>,
    /// The `scm-*` closure of the schema, less what the schema asserts.
    schema_closure: Vec<Triple>,
}

impl TBox {
    /// Reads the axioms of one RDF document holding all ontologies (core, DyKnow-ROS, posted
    /// extensions) with horned-owl and compiles them. `asserted` are the same triples, used to
    /// leave asserted schema triples out of the schema closure.
    pub fn from_rdf(
        document: &[u8],
        format: RdfFormat,
        asserted: &[Triple],
    ) -> Result<Self, SchemaError> {
        let (components, unparsed) = dyknow_ontology::rdf_owl_components_detailed(document, format)
            .map_err(|e| SchemaError(e.to_string()))?;
        let mut components: Vec<AnnotatedComponent<ArcStr>> = components.into_iter().collect();
        components.sort();
        let mut tbox = Self::from_components(&components, asserted);
        tbox.unsupported.extend(
            unparsed
                .into_iter()
                .map(|t| format!("triples horned-owl maps to no axiom: {t}")),
        );
        // horned-owl leaves them in hash order: sorted, the same input lists them the same.
        tbox.unsupported.sort();
        Ok(tbox)
    }

    /// Compiles horned-owl components.
    pub fn from_components(components: &[AnnotatedComponent<ArcStr>], asserted: &[Triple]) -> Self {
        let mapping = dyknow_ontology::prefix_mapping();
        let mut tbox = Self::default();
        for ac in components {
            let name = || {
                ac.component
                    .as_functional_with_prefixes(&mapping)
                    .to_string()
            };
            if !tbox.compile(&ac.component, &name) {
                tbox.unsupported.push(name());
            }
        }
        tbox.unsupported.sort();
        tbox.unsupported.dedup();
        tbox.schema_closure = tbox.closure(asserted);
        tbox
    }

    /// The axioms no supported rule covers (OWL functional syntax), sorted. The service logs them
    /// at start-up; they are never dropped silently.
    pub fn unsupported_axioms(&self) -> &[String] {
        &self.unsupported
    }

    /// The schema triples the `scm-*` rules derive that the schema does not assert.
    pub fn schema_closure(&self) -> &[Triple] {
        &self.schema_closure
    }

    /// Compiles one component; `false` if no supported rule covers it.
    fn compile(&mut self, component: &Component<ArcStr>, name: &dyn Fn() -> String) -> bool {
        match component {
            // Declarations, annotations and the ontology header carry no rule.
            Component::OntologyID(_)
            | Component::DocIRI(_)
            | Component::Import(_)
            | Component::OntologyAnnotation(_)
            | Component::DeclareClass(_)
            | Component::DeclareObjectProperty(_)
            | Component::DeclareAnnotationProperty(_)
            | Component::DeclareDataProperty(_)
            | Component::DeclareNamedIndividual(_)
            | Component::DeclareDatatype(_)
            | Component::AnnotationAssertion(_)
            | Component::SubAnnotationPropertyOf(_)
            | Component::AnnotationPropertyDomain(_)
            | Component::AnnotationPropertyRange(_) => true,
            // Assertions are data: the knowledge service hands them to the reasoner as facts.
            Component::ClassAssertion(_)
            | Component::ObjectPropertyAssertion(_)
            | Component::DataPropertyAssertion(_) => true,
            Component::SubClassOf(ax) => self.sub_class_of(&ax.sub, &ax.sup, name),
            Component::EquivalentClasses(ax) => {
                let mut all = true;
                for a in &ax.0 {
                    for b in &ax.0 {
                        if a != b {
                            all &= self.sub_class_of(a, b, name);
                        }
                    }
                }
                all
            }
            Component::DisjointClasses(ax) => {
                let named: Option<Vec<NamedNode>> = ax.0.iter().map(named_class).collect();
                let Some(named) = named else { return false };
                for (i, a) in named.iter().enumerate() {
                    for b in &named[i + 1..] {
                        self.disjoint_classes.push((a.clone(), b.clone(), name()));
                    }
                }
                true
            }
            Component::SubObjectPropertyOf(ax) => {
                let sup = prop(&ax.sup);
                match &ax.sub {
                    SubObjectPropertyExpression::ObjectPropertyExpression(sub) => {
                        self.sub_prop.insert((prop(sub), sup));
                    }
                    SubObjectPropertyExpression::ObjectPropertyChain(chain) => {
                        let chain: Vec<Prop> = chain.iter().map(prop).collect();
                        if let [a, b] = chain.as_slice()
                            && *a == sup
                            && *b == sup
                        {
                            self.transitive.insert(sup.iri.clone());
                        } else {
                            self.chains.push((chain, sup));
                        }
                    }
                }
                true
            }
            Component::EquivalentObjectProperties(ax) => {
                for a in &ax.0 {
                    for b in &ax.0 {
                        if a != b {
                            self.sub_prop.insert((prop(a), prop(b)));
                        }
                    }
                }
                true
            }
            Component::InverseObjectProperties(ax) => {
                let p = named_prop(&ax.0.0);
                let q = named_prop(&ax.1.0);
                self.sub_prop.insert((p.clone(), q.flipped()));
                self.sub_prop.insert((q, p.flipped()));
                true
            }
            Component::SymmetricObjectProperty(ax) => {
                let p = prop(&ax.0);
                self.sub_prop.insert((p.clone(), p.flipped()));
                true
            }
            Component::TransitiveObjectProperty(ax) => {
                self.transitive.insert(prop(&ax.0).iri);
                true
            }
            Component::ObjectPropertyDomain(ax) => match named_class(&ax.ce) {
                Some(c) => {
                    self.domain.insert((prop(&ax.ope), c));
                    true
                }
                None => is_thing(&ax.ce),
            },
            Component::ObjectPropertyRange(ax) => match named_class(&ax.ce) {
                Some(c) => {
                    self.domain.insert((prop(&ax.ope).flipped(), c));
                    true
                }
                None => is_thing(&ax.ce),
            },
            Component::DataPropertyDomain(ax) => match named_class(&ax.ce) {
                Some(c) => {
                    self.domain.insert((named_prop(&ax.dp.0), c));
                    true
                }
                None => is_thing(&ax.ce),
            },
            Component::SubDataPropertyOf(ax) => {
                self.sub_prop
                    .insert((named_prop(&ax.sub.0), named_prop(&ax.sup.0)));
                true
            }
            Component::EquivalentDataProperties(ax) => {
                for a in &ax.0 {
                    for b in &ax.0 {
                        if a != b {
                            self.sub_prop.insert((named_prop(&a.0), named_prop(&b.0)));
                        }
                    }
                }
                true
            }
            Component::DisjointObjectProperties(ax) => {
                for (i, a) in ax.0.iter().enumerate() {
                    for b in &ax.0[i + 1..] {
                        self.disjoint_props.push((prop(a), prop(b), name()));
                    }
                }
                true
            }
            Component::DisjointDataProperties(ax) => {
                for (i, a) in ax.0.iter().enumerate() {
                    for b in &ax.0[i + 1..] {
                        self.disjoint_props
                            .push((named_prop(&a.0), named_prop(&b.0), name()));
                    }
                }
                true
            }
            Component::IrreflexiveObjectProperty(ax) => {
                self.irreflexive.push((prop(&ax.0).iri, name()));
                true
            }
            Component::AsymmetricObjectProperty(ax) => {
                self.asymmetric.push((prop(&ax.0).iri, name()));
                true
            }
            Component::FunctionalDataProperty(ax) => {
                self.functional_data.push((iri_node(&ax.0.0), name()));
                true
            }
            // A data range of a data property types literals, which the reasoner does not do.
            _ => false,
        }
    }

    /// `sub ⊑ sup` for the class expressions OWL 2 RL allows (Table 2: sub-class and
    /// super-class expressions) that the reasoner supports.
    fn sub_class_of(
        &mut self,
        sub: &ClassExpression<ArcStr>,
        sup: &ClassExpression<ArcStr>,
        name: &dyn Fn() -> String,
    ) -> bool {
        if is_thing(sup) {
            return true;
        }
        match sub {
            // cls-uni: a union on the left is a sub-class axiom per member.
            ClassExpression::ObjectUnionOf(members) => {
                let mut all = true;
                for m in members {
                    all &= self.sub_class_of(m, sup, name);
                }
                return all;
            }
            // cls-svf1/2: ∃P.D ⊑ C.
            ClassExpression::ObjectSomeValuesFrom { ope, bce } => {
                let Some(class) = named_class(sup) else {
                    return false;
                };
                let filler = match named_class(bce) {
                    Some(d) => Some(d),
                    None if is_thing(bce) => None,
                    None => return false,
                };
                self.some_values.push(SomeValues {
                    prop: prop(ope),
                    filler,
                    class,
                });
                return true;
            }
            _ => {}
        }
        let Some(sub) = named_class(sub) else {
            return false;
        };
        match sup {
            ClassExpression::Class(_) => {
                if let Some(sup) = named_class(sup) {
                    self.sub_class.insert((sub, sup));
                }
                true
            }
            // cls-int2: C ⊑ A ⊓ B gives C ⊑ A and C ⊑ B.
            ClassExpression::ObjectIntersectionOf(members) => {
                let mut all = true;
                for m in members {
                    all &= self.sub_class_of(&ClassExpression::Class(class_of(&sub)), m, name);
                }
                all
            }
            ClassExpression::ObjectMaxCardinality { n: 0, ope, bce }
            | ClassExpression::ObjectExactCardinality { n: 0, ope, bce } => {
                let filler = match named_class(bce) {
                    Some(d) => Some(d),
                    None if is_thing(bce) => None,
                    None => return false,
                };
                self.max_zero.push(MaxZero {
                    class: sub,
                    prop: prop(ope),
                    filler,
                    axiom: name(),
                });
                true
            }
            _ => false,
        }
    }

    /// The `scm-*` rules over the compiled schema: scm-sco, scm-eqc1/2, scm-spo, scm-eqp1/2,
    /// scm-dom1/2, scm-rng1/2 (the reflexive scm-cls/scm-op/scm-dp triples are left out).
    fn closure(&self, asserted: &[Triple]) -> Vec<Triple> {
        let asserted: std::collections::HashSet<&Triple> = asserted.iter().collect();
        let mut out: std::collections::HashSet<Triple> = std::collections::HashSet::new();
        let class_sup = transitive_closure(self.sub_class.iter().cloned());
        for (c, sups) in &class_sup {
            for d in sups {
                if c == d {
                    continue;
                }
                out.insert(Triple::new(c.clone(), rdfs::SUB_CLASS_OF, d.clone()));
                if class_sup.get(d).is_some_and(|s| s.contains(c)) {
                    out.insert(Triple::new(c.clone(), owl::EQUIVALENT_CLASS, d.clone()));
                }
            }
        }
        let named_sub_prop = self
            .sub_prop
            .iter()
            .filter(|(a, b)| !a.inverse && !b.inverse)
            .map(|(a, b)| (a.iri.clone(), b.iri.clone()));
        let prop_sup = transitive_closure(named_sub_prop);
        for (p, sups) in &prop_sup {
            for q in sups {
                if p == q {
                    continue;
                }
                out.insert(Triple::new(p.clone(), rdfs::SUB_PROPERTY_OF, q.clone()));
                if prop_sup.get(q).is_some_and(|s| s.contains(p)) {
                    out.insert(Triple::new(p.clone(), owl::EQUIVALENT_PROPERTY, q.clone()));
                }
            }
        }
        // A chain P ∘ P ⊑ P is the definition of a transitive P (OWL 2 Structural Spec. 9.2.13).
        for p in &self.transitive {
            out.insert(Triple::new(p.clone(), rdf::TYPE, owl::TRANSITIVE_PROPERTY));
        }
        // scm-dom1/2, scm-rng1/2: a property's domain widens along sub-classes and is inherited
        // by sub-properties.
        for (p, c) in &self.domain {
            let predicate = if p.inverse { rdfs::RANGE } else { rdfs::DOMAIN };
            let mut classes: BTreeSet<&NamedNode> = BTreeSet::from([c]);
            if let Some(sups) = class_sup.get(c) {
                classes.extend(sups);
            }
            let mut props: BTreeSet<&NamedNode> = BTreeSet::from([&p.iri]);
            for (sub, sups) in &prop_sup {
                if sups.contains(&p.iri) {
                    props.insert(sub);
                }
            }
            for q in &props {
                for d in &classes {
                    out.insert(Triple::new((*q).clone(), predicate, (*d).clone()));
                }
            }
        }
        let mut out: Vec<Triple> = out.into_iter().filter(|t| !asserted.contains(t)).collect();
        out.sort_by_cached_key(ToString::to_string);
        out
    }
}

/// The reflexive-transitive closure of a relation, as a map from each node to what it reaches
/// (itself included when it is on a cycle).
fn transitive_closure(
    pairs: impl Iterator<Item = (NamedNode, NamedNode)>,
) -> BTreeMap<NamedNode, BTreeSet<NamedNode>> {
    let mut direct: BTreeMap<NamedNode, BTreeSet<NamedNode>> = BTreeMap::new();
    for (a, b) in pairs {
        direct.entry(a).or_default().insert(b);
    }
    let mut closure = BTreeMap::new();
    for start in direct.keys() {
        let mut seen: BTreeSet<NamedNode> = BTreeSet::new();
        let mut stack: Vec<&NamedNode> = direct[start].iter().collect();
        while let Some(n) = stack.pop() {
            if seen.insert(n.clone())
                && let Some(next) = direct.get(n)
            {
                stack.extend(next);
            }
        }
        closure.insert(start.clone(), seen);
    }
    closure
}

fn iri_node(iri: &horned_owl::model::IRI<ArcStr>) -> NamedNode {
    NamedNode::new_unchecked(iri.as_ref())
}

fn named_prop(iri: &horned_owl::model::IRI<ArcStr>) -> Prop {
    Prop {
        iri: iri_node(iri),
        inverse: false,
    }
}

fn prop(ope: &ObjectPropertyExpression<ArcStr>) -> Prop {
    match ope {
        ObjectPropertyExpression::ObjectProperty(p) => named_prop(&p.0),
        ObjectPropertyExpression::InverseObjectProperty(p) => Prop {
            iri: iri_node(&p.0),
            inverse: true,
        },
    }
}

fn named_class(ce: &ClassExpression<ArcStr>) -> Option<NamedNode> {
    match ce {
        ClassExpression::Class(c) if !is_thing(ce) => Some(iri_node(&c.0)),
        _ => None,
    }
}

fn class_of(node: &NamedNode) -> horned_owl::model::Class<ArcStr> {
    let build: horned_owl::model::Build<ArcStr> = horned_owl::model::Build::new_arc();
    build.class(node.as_str())
}

fn is_thing(ce: &ClassExpression<ArcStr>) -> bool {
    matches!(ce, ClassExpression::Class(c) if c.0.as_ref() == owl::THING.as_str())
}
