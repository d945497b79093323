//! Declarations the RDF leaves implicit. horned-owl maps an axiom to OWL only when it knows what
//! kind of entity each IRI is; ontology extensions (and the W3C RDF-based test cases) often use
//! classes and properties without declaring them. Each IRI that is used as a class or a property
//! and has no declaration gets one: a property is a data property if it is used with a literal
//! value, an object property otherwise.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

use oxrdf::vocab::{rdf, rdfs};
use oxrdf::{NamedNode, NamedNodeRef, NamedOrBlankNode, Term, Triple};

const OWL: &str = "http://www.w3.org/2002/07/owl#";

fn owl(local: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{OWL}{local}"))
}

fn is_builtin(iri: &str) -> bool {
    iri.starts_with(OWL)
        || iri.starts_with(rdf::TYPE.as_str().trim_end_matches("type"))
        || iri.starts_with("http://www.w3.org/2000/01/rdf-schema#")
        || iri.starts_with("http://www.w3.org/2001/XMLSchema#")
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Kind {
    Class,
    Property,
}

/// The `rdf:first`/`rdf:rest` structure of a set of triples, to read RDF lists.
struct RdfLists<'a> {
    firsts: HashMap<&'a NamedOrBlankNode, &'a Term>,
    rests: HashMap<&'a NamedOrBlankNode, &'a Term>,
}

impl<'a> RdfLists<'a> {
    fn new(triples: &'a [Triple]) -> Self {
        let mut lists = Self {
            firsts: HashMap::new(),
            rests: HashMap::new(),
        };
        for t in triples {
            if t.predicate == rdf::FIRST {
                lists.firsts.insert(&t.subject, &t.object);
            } else if t.predicate == rdf::REST {
                lists.rests.insert(&t.subject, &t.object);
            }
        }
        lists
    }

    /// The IRI members of the list starting at `head` (at most 10,000: a cyclic list ends).
    fn members(&self, head: &Term) -> Vec<NamedNode> {
        let mut members = Vec::new();
        let mut node: Option<NamedOrBlankNode> = match head {
            Term::NamedNode(n) if NamedNodeRef::from(n) != rdf::NIL => Some(n.clone().into()),
            Term::BlankNode(b) => Some(b.clone().into()),
            _ => None,
        };
        let mut steps = 0;
        while let Some(n) = node.take() {
            steps += 1;
            if steps > 10_000 {
                break;
            }
            if let Some(Term::NamedNode(m)) = self.firsts.get(&n) {
                members.push(m.clone());
            }
            node = match self.rests.get(&n) {
                Some(Term::BlankNode(b)) => Some(b.clone().into()),
                Some(Term::NamedNode(r)) if NamedNodeRef::from(r) != rdf::NIL => {
                    Some(r.clone().into())
                }
                _ => None,
            };
        }
        members
    }
}

/// The declarations missing from `triples`.
pub(crate) fn missing_declarations(triples: &[Triple]) -> Vec<Triple> {
    let mut declared: BTreeSet<&str> = BTreeSet::new();
    let declaring: BTreeSet<String> = [
        "Class",
        "ObjectProperty",
        "DatatypeProperty",
        "AnnotationProperty",
        "NamedIndividual",
        "Restriction",
    ]
    .iter()
    .map(|l| format!("{OWL}{l}"))
    .chain([rdfs::DATATYPE.as_str().to_owned()])
    .collect();
    for t in triples {
        if t.predicate == rdf::TYPE
            && let (NamedOrBlankNode::NamedNode(s), Term::NamedNode(c)) = (&t.subject, &t.object)
            && declaring.contains(c.as_str())
        {
            declared.insert(s.as_str());
        }
    }
    let mut used: BTreeMap<&str, Kind> = BTreeMap::new();
    let mut literal_valued: BTreeSet<&str> = BTreeSet::new();
    let class_predicates = [
        rdfs::SUB_CLASS_OF.as_str(),
        "http://www.w3.org/2002/07/owl#equivalentClass",
        "http://www.w3.org/2002/07/owl#disjointWith",
    ];
    let property_predicates = [
        rdfs::SUB_PROPERTY_OF.as_str(),
        "http://www.w3.org/2002/07/owl#equivalentProperty",
        "http://www.w3.org/2002/07/owl#inverseOf",
        "http://www.w3.org/2002/07/owl#propertyDisjointWith",
    ];
    let property_classes = [
        "TransitiveProperty",
        "SymmetricProperty",
        "AsymmetricProperty",
        "IrreflexiveProperty",
        "ReflexiveProperty",
        "FunctionalProperty",
        "InverseFunctionalProperty",
    ];
    // Heads of the RDF lists whose members are properties (chains, disjoint properties) or
    // classes (disjoint classes).
    let lists = RdfLists::new(triples);
    let mut property_lists: Vec<&Term> = Vec::new();
    let mut class_lists: Vec<&Term> = Vec::new();
    let all_disjoint_classes: HashSet<&NamedOrBlankNode> = triples
        .iter()
        .filter(|t| {
            t.predicate == rdf::TYPE
                && matches!(&t.object, Term::NamedNode(c) if c.as_str() == format!("{OWL}AllDisjointClasses"))
        })
        .map(|t| &t.subject)
        .collect();
    for t in triples {
        let p = t.predicate.as_str();
        let subject = match &t.subject {
            NamedOrBlankNode::NamedNode(n) => Some(n.as_str()),
            NamedOrBlankNode::BlankNode(_) => None,
        };
        let object = match &t.object {
            Term::NamedNode(n) => Some(n.as_str()),
            _ => None,
        };
        if class_predicates.contains(&p) {
            for n in [subject, object].into_iter().flatten() {
                used.entry(n).or_insert(Kind::Class);
            }
        } else if property_predicates.contains(&p) {
            for n in [subject, object].into_iter().flatten() {
                used.entry(n).or_insert(Kind::Property);
            }
        } else if t.predicate == rdfs::DOMAIN || t.predicate == rdfs::RANGE {
            if let Some(s) = subject {
                used.entry(s).or_insert(Kind::Property);
            }
            if let Some(o) = object
                && !o.starts_with("http://www.w3.org/2001/XMLSchema#")
                && o != rdfs::LITERAL.as_str()
            {
                used.entry(o).or_insert(Kind::Class);
            } else if object.is_some() {
                // A datatype range makes a data property.
                if let Some(s) = subject {
                    literal_valued.insert(s);
                }
            }
        } else if p == format!("{OWL}members") {
            if all_disjoint_classes.contains(&t.subject) {
                class_lists.push(&t.object);
            } else {
                property_lists.push(&t.object);
            }
        } else if p == format!("{OWL}propertyChainAxiom") {
            if let Some(s) = subject {
                used.entry(s).or_insert(Kind::Property);
            }
            property_lists.push(&t.object);
        } else if t.predicate == rdf::TYPE {
            if let Some(c) = object {
                if let Some(local) = c.strip_prefix(OWL)
                    && property_classes.contains(&local)
                {
                    if let Some(s) = subject {
                        used.entry(s).or_insert(Kind::Property);
                    }
                } else if !is_builtin(c) {
                    used.entry(c).or_insert(Kind::Class);
                }
            }
        } else if !is_builtin(p) {
            used.entry(p).or_insert(Kind::Property);
            if matches!(t.object, Term::Literal(_)) {
                literal_valued.insert(p);
            }
        }
    }
    let members: Vec<(NamedNode, Kind)> = property_lists
        .iter()
        .map(|h| (h, Kind::Property))
        .chain(class_lists.iter().map(|h| (h, Kind::Class)))
        .flat_map(|(h, kind)| lists.members(h).into_iter().map(move |m| (m, kind)))
        .collect();
    for (member, kind) in &members {
        used.entry(member.as_str()).or_insert(*kind);
    }
    used.into_iter()
        .filter(|(iri, _)| !declared.contains(iri) && !is_builtin(iri))
        .map(|(iri, kind)| {
            let class = match kind {
                Kind::Class => owl("Class"),
                Kind::Property if literal_valued.contains(iri) => owl("DatatypeProperty"),
                Kind::Property => owl("ObjectProperty"),
            };
            Triple::new(NamedNode::new_unchecked(iri), rdf::TYPE, class)
        })
        .collect()
}

/// Rewrites what horned-owl 4.0's RDF reader does not map into what it does:
/// `owl:AllDisjointClasses` and `owl:AllDisjointProperties` become pairwise `owl:disjointWith` and
/// `owl:propertyDisjointWith` (the same axioms, OWL 2 Mapping to RDF, Table 16), and an anonymous
/// ontology header is dropped (it carries no axiom).
pub(crate) fn rewrite_for_horned_owl(triples: &[Triple]) -> Vec<Triple> {
    let typed = |t: &Triple, local: &str| {
        t.predicate == rdf::TYPE
            && matches!(&t.object, Term::NamedNode(c) if c.as_str().strip_prefix(OWL) == Some(local))
    };
    let mut all_disjoint: HashMap<&NamedOrBlankNode, &str> = HashMap::new();
    for t in triples {
        if typed(t, "AllDisjointClasses") {
            all_disjoint.insert(&t.subject, "disjointWith");
        } else if typed(t, "AllDisjointProperties") {
            all_disjoint.insert(&t.subject, "propertyDisjointWith");
        }
    }
    let lists = RdfLists::new(triples);
    let mut out: Vec<Triple> = Vec::new();
    let mut consumed: HashSet<&NamedOrBlankNode> = HashSet::new();
    for t in triples {
        let Some(relation) = all_disjoint.get(&t.subject) else {
            continue;
        };
        if t.predicate.as_str() != format!("{OWL}members") {
            continue;
        }
        let members = lists.members(&t.object);
        for (i, a) in members.iter().enumerate() {
            for b in &members[i + 1..] {
                out.push(Triple::new(a.clone(), owl(relation), b.clone()));
            }
        }
        consumed.insert(&t.subject);
    }
    out.extend(
        triples
            .iter()
            .filter(|t| !consumed.contains(&t.subject))
            .filter(|t| {
                !(matches!(t.subject, NamedOrBlankNode::BlankNode(_)) && typed(t, "Ontology"))
            })
            .cloned(),
    );
    out
}
