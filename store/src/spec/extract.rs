//! From a posted RDF document to specs: find the spec roots, give every triple to the spec that
//! reaches it, mint IRIs for blank nodes, normalise the two ways of writing ports, and check the
//! structural constraints of the ontology (seed Appendix A; DyKnow-ROS Ch. 5.3.1) before anything
//! is written.

use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet};

use dyknow_ontology::vocab::{dkros, dyknow, rdf, rdfs, xsd};
use oxigraph::model::{Literal, NamedNode, NamedNodeRef, NamedOrBlankNode, Term, Triple};

use super::model::{
    Param, Port, PortDirection, Spec, SpecKind, Tag, TargetSpec, TransformationSpec,
};
use crate::error::{SpecValidationError, Violation};
use crate::graphs::{channel_resource, encode, spec_graph, spec_resource};

/// The most ports a transformation may have.
pub const MAX_PORTS: usize = 256;
/// The most tags a port or target may have.
pub const MAX_TAGS: usize = 64;
/// The labour and upkeep estimate of a spec that gives none (contract `specs.md`).
pub const DEFAULT_COST: f64 = 1.0;

/// The most bytes of a spec's label: it names the spec in URLs (`GET /targets/{label}`),
/// percent-encoded up to three times as long, and servers refuse URLs past 64 KiB.
pub const MAX_LABEL_BYTES: usize = 4096;

/// What a posted document is checked against: the classes whose instances are spec roots
/// (the transformation and target classes of the ontology, including sub-classes declared by
/// extensions), and the terms of the `dyknow:` and `dkros:` namespaces that exist.
#[derive(Debug, Clone)]
pub struct SpecClasses {
    /// Classes whose instances are transformations.
    pub transformation: HashSet<NamedNode>,
    /// Classes whose instances are targets.
    pub target: HashSet<NamedNode>,
    /// The terms of the `dyknow:` and `dkros:` namespaces the service knows: its vocabulary,
    /// what the built-in ontologies and the extensions declare. A posted document using
    /// another one as a property or a class has misspelt it (`dyknow:hasInPorts`), and is
    /// refused: kept, it would change nothing and say nothing (a transformation whose in
    /// port is written so would be a source).
    pub vocabulary: HashSet<NamedNode>,
    /// The built-in terms: the service's vocabulary and what the built-in ontologies declare
    /// (no extension's). An extension may not restate them (`dyknow:dependsOn a
    /// owl:SymmetricProperty` made every CU depend on itself).
    pub builtin: HashSet<NamedNode>,
}

impl Default for SpecClasses {
    fn default() -> Self {
        Self {
            transformation: [
                dyknow::TRANSFORMATION,
                dyknow::SOURCE,
                dyknow::SINK,
                dkros::ROS_TRANSFORMATION,
            ]
            .into_iter()
            .map(NamedNodeRef::into_owned)
            .collect(),
            target: [dyknow::TARGET, dkros::ROS_TARGET]
                .into_iter()
                .map(NamedNodeRef::into_owned)
                .collect(),
            vocabulary: dyknow::ALL
                .iter()
                .chain(dkros::ALL)
                .map(|t| t.into_owned())
                .collect(),
            builtin: dyknow::ALL
                .iter()
                .chain(dkros::ALL)
                .map(|t| t.into_owned())
                .collect(),
        }
    }
}

/// Whether `iri` is in the `dyknow:` or `dkros:` namespace.
pub fn in_dyknow_namespaces(iri: &str) -> bool {
    iri.starts_with(dyknow::NAMESPACE) || iri.starts_with(dkros::NAMESPACE)
}

/// Whether XML 1.0 can carry `text` (RDF/XML, OWL/XML and SPARQL's XML results): no control
/// character but tab, line feed and carriage return, and neither U+FFFE nor U+FFFF.
pub fn xml_safe(text: &str) -> bool {
    text.chars().all(|c| {
        matches!(c, '\t' | '\n' | '\r') || (c >= ' ' && c != '\u{FFFE}' && c != '\u{FFFF}')
    })
}

/// Whether RDF/XML can write `iri` as a property: it must end with an XML name (a letter or
/// `_`, then letters, digits, `-`, `.`, `_`), which becomes the element's local name. A
/// property such as `<http://example.org/rel/>` or `<urn:p:1>` has none, and the export wrote
/// an element no XML parser reads. (The split is Oxigraph's RDF/XML writer's.)
pub fn has_xml_local_name(iri: &str) -> bool {
    fn start(c: char) -> bool {
        matches!(c,
            'A'..='Z' | '_' | 'a'..='z'
            | '\u{00C0}'..='\u{00D6}' | '\u{00D8}'..='\u{00F6}' | '\u{00F8}'..='\u{02FF}'
            | '\u{0370}'..='\u{037D}' | '\u{037F}'..='\u{1FFF}' | '\u{200C}'..='\u{200D}'
            | '\u{2070}'..='\u{218F}' | '\u{2C00}'..='\u{2FEF}' | '\u{3001}'..='\u{D7FF}'
            | '\u{F900}'..='\u{FDCF}' | '\u{FDF0}'..='\u{FFFD}' | '\u{10000}'..='\u{EFFFF}')
    }
    fn name(c: char) -> bool {
        start(c)
            || matches!(c, '-' | '.' | '0'..='9' | '\u{B7}' | '\u{0300}'..='\u{036F}' | '\u{203F}'..='\u{2040}')
    }
    let tail = iri.rfind(|c: char| !name(c)).map_or(iri, |i| &iri[i..]);
    tail.chars().any(start)
}

/// The character XML cannot carry, as `U+0001`.
fn first_xml_unsafe(text: &str) -> String {
    text.chars()
        .find(|c| !xml_safe(c.encode_utf8(&mut [0; 4])))
        .map_or_else(String::new, |c| format!("U+{:04X}", u32::from(c)))
}

/// The term of the vocabulary closest to a misspelt one, if one is close (at most two edits
/// in its local name, same namespace).
fn closest_term<'a>(term: &str, vocabulary: &'a HashSet<NamedNode>) -> Option<&'a NamedNode> {
    let (ns, local) = term.split_at(term.rfind(['#', '/'])? + 1);
    vocabulary
        .iter()
        .filter_map(|v| {
            let l = v.as_str().strip_prefix(ns)?;
            let d = edit_distance(&local.to_lowercase(), &l.to_lowercase());
            (d <= 2).then_some((d, v))
        })
        .min_by(|a, b| a.0.cmp(&b.0).then_with(|| a.1.as_str().cmp(b.1.as_str())))
        .map(|(_, v)| v)
}

/// Levenshtein's distance between two short names, by characters.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let above = row[j + 1];
            row[j + 1] = (above + 1)
                .min(row[j] + 1)
                .min(diagonal + usize::from(ca != *cb));
            diagonal = above;
        }
    }
    row[b.len()]
}

/// What a posted document is checked for as a whole (not a stored graph read back: what was
/// accepted once reads back whatever the rules became): terms of the DyKnow namespaces that
/// nothing declares, and literals no XML export could carry.
fn check_document(triples: &[Triple], classes: &SpecClasses, violations: &mut Vec<Violation>) {
    // Terms the document declares itself (an extension's new property).
    let declared_here: HashSet<&NamedNode> = triples
        .iter()
        .filter(|t| t.predicate == rdf::TYPE)
        .filter_map(|t| match &t.subject {
            NamedOrBlankNode::NamedNode(n) => Some(n),
            NamedOrBlankNode::BlankNode(_) => None,
        })
        .collect();
    let mut undeclared: Vec<&NamedNode> = Vec::new();
    let mut unsafe_subjects: Vec<String> = Vec::new();
    let mut unwritable: Vec<&NamedNode> = Vec::new();
    for t in triples {
        if !has_xml_local_name(t.predicate.as_str()) && !unwritable.contains(&&t.predicate) {
            unwritable.push(&t.predicate);
        }
        let class = match &t.object {
            Term::NamedNode(c) if t.predicate == rdf::TYPE => Some(c),
            _ => None,
        };
        for term in std::iter::once(&t.predicate).chain(class) {
            if in_dyknow_namespaces(term.as_str())
                && !classes.vocabulary.contains(term)
                && !declared_here.contains(term)
                && !undeclared.contains(&term)
            {
                undeclared.push(term);
            }
        }
        if let Term::Literal(l) = &t.object
            && !xml_safe(l.value())
        {
            let d = format!(
                "{} (a value of <{}> holds {})",
                describe(&t.subject, &HashMap::default()),
                t.predicate.as_str(),
                first_xml_unsafe(l.value())
            );
            if !unsafe_subjects.contains(&d) {
                unsafe_subjects.push(d);
            }
        }
    }
    for term in undeclared.into_iter().take(10) {
        let hint = closest_term(term.as_str(), &classes.vocabulary).map_or_else(String::new, |c| {
            format!(" (did you mean <{}>?)", c.as_str())
        });
        violations.push(Violation::new(
            format!(
                "the dyknow: and dkros: terms are those the ontology and its extensions declare; \
                 this one is declared nowhere{hint}"
            ),
            term.as_str(),
        ));
    }
    for property in unwritable.into_iter().take(10) {
        violations.push(Violation::new(
            "a property's IRI ends with an XML name (a letter or '_', then letters, digits, \
             '-', '.', '_'): the model is exported as RDF/XML, which writes a property as an \
             element named so",
            property.as_str(),
        ));
    }
    for subject in unsafe_subjects.into_iter().take(10) {
        violations.push(Violation::new(
            "literals hold no control character but tab, line feed and carriage return: XML \
             1.0 (RDF/XML, OWL/XML, SPARQL's XML results) cannot carry one",
            subject,
        ));
    }
}

/// A spec found in a document, with the normalised triples of its graph.
#[derive(Debug, Clone)]
pub struct ExtractedSpec {
    /// What the spec says.
    pub spec: Spec,
    /// The named graph it goes to.
    pub graph: NamedNode,
    /// The IRI of the spec resource if the document named it (rather than a blank node).
    pub given_iri: Option<NamedNode>,
    /// The normalised triples of its graph.
    pub triples: Vec<Triple>,
}

/// The result of [`extract_specs`].
#[derive(Debug, Clone, Default)]
pub struct ExtractedDocument {
    /// The specs, in document order.
    pub specs: Vec<ExtractedSpec>,
    /// Triples that belong to no spec (vocabulary: classes, `similarTo`, ...).
    pub rest: Vec<Triple>,
}

/// Predicates along which a spec owns the nodes it points to (even when they are IRIs).
const STRUCTURAL: [NamedNodeRef<'static>; 7] = [
    dkros::HAS_PORT,
    dyknow::HAS_IN_PORT,
    dyknow::HAS_OUT_PORT,
    dyknow::HAS_TAG,
    dyknow::HAS_COST_MODEL,
    dkros::HAS_PARAM,
    dyknow::HAS_CHANNEL,
];

type Node = NamedOrBlankNode;

/// Whether a channel name maps to a key expression on the data plane (`executors.md`): after
/// one leading '/', non-empty chunks without Zenoh's reserved characters or DyKnow's hermetic
/// '@' prefix. (The same rule as `dyknow_cu::keys::check_channel`, which the store does not
/// depend on.)
fn is_key_expression(name: &str) -> bool {
    let chunks = name.strip_prefix('/').unwrap_or(name);
    !chunks.is_empty()
        && chunks
            .split('/')
            .all(|c| !c.is_empty() && !c.starts_with('@') && !c.contains(['*', '$', '?', '#']))
}

fn term_node(term: &Term) -> Option<Node> {
    match term {
        Term::NamedNode(n) => Some(n.clone().into()),
        Term::BlankNode(b) => Some(b.clone().into()),
        _ => None,
    }
}

/// Subject-indexed view of a document.
struct Index<'a> {
    by_subject: HashMap<&'a Node, Vec<&'a Triple>>,
}

impl<'a> Index<'a> {
    fn new(triples: &'a [Triple]) -> Self {
        let mut by_subject: HashMap<&Node, Vec<&Triple>> = HashMap::default();
        for t in triples {
            by_subject.entry(&t.subject).or_default().push(t);
        }
        Self { by_subject }
    }
    fn about(&self, node: &Node) -> &[&'a Triple] {
        self.by_subject.get(node).map_or(&[], Vec::as_slice)
    }
    fn objects(&self, node: &Node, predicate: NamedNodeRef<'_>) -> Vec<&'a Term> {
        self.about(node)
            .iter()
            .filter(|t| t.predicate == predicate)
            .map(|t| &t.object)
            .collect()
    }
    fn has_type(&self, node: &Node, class: NamedNodeRef<'_>) -> bool {
        self.about(node)
            .iter()
            .any(|t| t.predicate == rdf::TYPE && t.object == Term::from(class))
    }
    /// Distinct literal values of `predicate`s on `node`; non-literals are reported separately.
    fn literals(&self, node: &Node, predicates: &[NamedNodeRef<'_>]) -> (Vec<&'a Literal>, bool) {
        let mut out: Vec<&Literal> = Vec::new();
        let mut non_literal = false;
        for t in self.about(node) {
            if predicates.contains(&t.predicate.as_ref()) {
                match &t.object {
                    Term::Literal(l) => {
                        if !out.iter().any(|o| o.value() == l.value()) {
                            out.push(l);
                        }
                    }
                    _ => non_literal = true,
                }
            }
        }
        (out, non_literal)
    }
}

/// Describes a node for error messages.
fn describe(node: &Node, names: &HashMap<Node, String>) -> String {
    if let Some(name) = names.get(node) {
        return name.clone();
    }
    match node {
        NamedOrBlankNode::NamedNode(n) => n.as_str().to_owned(),
        NamedOrBlankNode::BlankNode(_) => "a blank node".to_owned(),
    }
}

/// Finds the specs of a document, mints IRIs for their blank nodes, normalises and validates
/// them. With `expected = Some(kind)` the document must consist of specs of that kind only (the
/// HTTP endpoints); with `None` specs of both kinds are taken and the remaining triples are
/// returned as [`ExtractedDocument::rest`] (the offline loader).
///
/// All violations of the whole document are reported at once.
pub fn extract_specs(
    triples: &[Triple],
    classes: &SpecClasses,
    expected: Option<SpecKind>,
) -> Result<ExtractedDocument, SpecValidationError> {
    extract(triples, classes, expected, true)
}

fn extract(
    triples: &[Triple],
    classes: &SpecClasses,
    expected: Option<SpecKind>,
    reject_rest: bool,
) -> Result<ExtractedDocument, SpecValidationError> {
    let index = Index::new(triples);
    let mut violations = Vec::new();
    if reject_rest {
        check_document(triples, classes, &mut violations);
    }

    // Roots, in document order.
    let mut roots: Vec<(Node, SpecKind)> = Vec::new();
    let mut seen_roots = HashSet::default();
    for t in triples {
        if t.predicate != rdf::TYPE {
            continue;
        }
        let Term::NamedNode(class) = &t.object else {
            continue;
        };
        let kind = if classes.transformation.contains(class) {
            SpecKind::Transformation
        } else if classes.target.contains(class) {
            SpecKind::Target
        } else {
            continue;
        };
        if seen_roots.insert(t.subject.clone()) {
            roots.push((t.subject.clone(), kind));
        } else if roots.iter().any(|(r, k)| *r == t.subject && *k != kind) {
            violations.push(Violation::new(
                "Transformation DisjointWith Target",
                describe(&t.subject, &HashMap::default()),
            ));
        }
    }
    let root_set: HashSet<&Node> = roots.iter().map(|(r, _)| r).collect();

    // Blank roots are named after their label, also where another spec points at them.
    let mut root_iris: HashMap<Node, NamedNode> = HashMap::default();
    for (root, kind) in &roots {
        let (labels, not_literal) = index.literals(root, &[rdfs::LABEL]);
        if let (NamedOrBlankNode::BlankNode(_), [label], false) =
            (root, labels.as_slice(), not_literal)
        {
            root_iris.insert(
                root.clone(),
                NamedNode::new_unchecked(spec_resource(*kind, label.value())),
            );
        }
    }
    let mut claimed: HashSet<&Node> = HashSet::default();
    let mut specs = Vec::new();
    let mut labels_seen: HashSet<(SpecKind, String)> = HashSet::default();
    for (root, kind) in &roots {
        let owned = owned_nodes(&index, &root_set, root);
        for node in &owned {
            if let Some((k, _)) = index.by_subject.get_key_value(node) {
                claimed.insert(*k);
            }
        }
        if let Some(expected) = expected
            && expected != *kind
        {
            violations.push(Violation::new(
                format!(
                    "this endpoint accepts {} specs only; post {} specs to /{}s",
                    expected.name(),
                    kind.name(),
                    kind.name()
                ),
                // A blank node is told by its label, when it has one.
                match index.literals(root, &[rdfs::LABEL]).0.as_slice() {
                    [label] if matches!(root, NamedOrBlankNode::BlankNode(_)) => {
                        format!("the {} spec {:?}", kind.name(), label.value())
                    }
                    _ => describe(root, &HashMap::default()),
                },
            ));
            continue;
        }
        let (labels, label_not_literal) = index.literals(root, &[rdfs::LABEL]);
        let label = match labels.as_slice() {
            [one] if !label_not_literal => one.value().to_owned(),
            _ => {
                violations.push(Violation::new(
                    format!(
                        "{} has exactly 1 rdfs:label (a literal): it identifies the spec",
                        capitalised(kind.name())
                    ),
                    describe(root, &HashMap::default()),
                ));
                continue;
            }
        };
        if label.trim().is_empty() || label.chars().any(char::is_control) {
            // It names the spec in URLs (`DELETE /targets/{label}`): an empty one could never
            // be read or removed again.
            violations.push(Violation::new(
                format!(
                    "a {} spec's rdfs:label is not empty or blank and holds no control \
                     character: it names the spec",
                    kind.name()
                ),
                describe(root, &HashMap::default()),
            ));
            continue;
        }
        if reject_rest && label.len() > MAX_LABEL_BYTES {
            violations.push(Violation::new(
                format!(
                    "a {} spec's rdfs:label is at most {MAX_LABEL_BYTES} bytes: it names the \
                     spec in URLs",
                    kind.name()
                ),
                format!("{}…", label.chars().take(40).collect::<String>()),
            ));
            continue;
        }
        if !labels_seen.insert((*kind, label.clone())) {
            violations.push(Violation::new(
                format!(
                    "labels are unique: the document has two {} specs with this label",
                    kind.name()
                ),
                label.clone(),
            ));
            continue;
        }
        let spec = SpecBuilder::new(&index, &root_iris, root.clone(), *kind, label);
        let (extracted, mut found) = spec.build(owned);
        violations.append(&mut found);
        if let Some(e) = extracted {
            specs.push(e);
        }
    }

    let rest: Vec<Triple> = triples
        .iter()
        .filter(|t| !claimed.contains(&t.subject) && !root_set.contains(&t.subject))
        .cloned()
        .collect();
    if let Some(kind) = expected {
        if roots.is_empty() {
            violations.push(Violation::new(
                format!(
                    "the document describes no {} (a node typed {} or a sub-class)",
                    kind.name(),
                    match kind {
                        SpecKind::Transformation => "dyknow:Transformation",
                        SpecKind::Target => "dyknow:Target",
                    }
                ),
                "the request body",
            ));
        }
        let mut subjects: Vec<String> = Vec::new();
        for t in &rest {
            let d = describe(&t.subject, &HashMap::default());
            if !subjects.contains(&d) {
                subjects.push(d);
            }
        }
        for s in subjects.into_iter().take(if reject_rest { 10 } else { 0 }) {
            violations.push(Violation::new(
                "every statement belongs to a spec (post vocabularies to /ontology)",
                s,
            ));
        }
    }
    // An empty program or kind is no implementation: stored, it stayed "not runnable: the
    // command line is empty" for ever. Refused when posted; one stored before reads back.
    if reject_rest {
        for s in &specs {
            if let Spec::Transformation(t) = &s.spec
                && [&t.source, &t.exec_type]
                    .into_iter()
                    .any(|v| v.as_deref().is_some_and(|v| v.trim().is_empty()))
            {
                violations.push(Violation::new(
                    "dkros:hasSource and dkros:hasType are not empty (the program or builtin \
                     an executor runs, and its kind)",
                    t.label.clone(),
                ));
            }
        }
    }
    if violations.is_empty() {
        Ok(ExtractedDocument { specs, rest })
    } else {
        Err(SpecValidationError(violations))
    }
}

/// Walks every node a spec owns (structural links, and blank nodes along any link) and returns
/// them in walk order, the root first.
fn owned_nodes(index: &Index<'_>, roots: &HashSet<&Node>, root: &Node) -> Vec<Node> {
    let mut order = vec![root.clone()];
    let mut seen: HashSet<Node> = order.iter().cloned().collect();
    let mut i = 0;
    while i < order.len() {
        let node = order[i].clone();
        i += 1;
        for t in index.about(&node) {
            let Some(obj) = term_node(&t.object) else {
                continue;
            };
            let follow = match &obj {
                NamedOrBlankNode::BlankNode(_) => true,
                // IRIs along structural links, and IRIs the service minted for a spec's blank
                // nodes (so a stored spec posted again owns the same nodes).
                NamedOrBlankNode::NamedNode(n) => {
                    (STRUCTURAL.contains(&t.predicate.as_ref()) || is_minted(n.as_str()))
                        && !index.about(&obj).is_empty()
                }
            };
            if follow && !roots.contains(&obj) && seen.insert(obj.clone()) {
                order.push(obj);
            }
        }
    }
    order
}

/// Whether an IRI is one the service mints for the parts of a spec.
fn is_minted(iri: &str) -> bool {
    ["urn:dyknow:transformation:", "urn:dyknow:target:"]
        .iter()
        .any(|prefix| {
            iri.strip_prefix(prefix)
                .is_some_and(|rest| rest.contains('/'))
        })
}

fn capitalised(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map(|f| f.to_uppercase().chain(c).collect())
        .unwrap_or_default()
}

/// Builds one spec: walks the nodes it owns, names them, normalises and validates.
struct SpecBuilder<'a, 'i> {
    index: &'i Index<'a>,
    /// The IRIs of the blank roots of the document (links between specs).
    root_iris: &'i HashMap<Node, NamedNode>,
    root: Node,
    kind: SpecKind,
    label: String,
    base: String,
    /// Minted IRIs for blank nodes, and given IRIs kept as they are.
    iris: HashMap<Node, NamedNode>,
    /// The IRIs minted so far (to keep minted IRIs unique in constant time).
    minted: HashSet<String>,
    /// Human-readable names of nodes for violations.
    names: HashMap<Node, String>,
    violations: Vec<Violation>,
    out: Vec<Triple>,
    out_set: HashSet<Triple>,
}

impl<'a, 'i> SpecBuilder<'a, 'i> {
    fn new(
        index: &'i Index<'a>,
        root_iris: &'i HashMap<Node, NamedNode>,
        root: Node,
        kind: SpecKind,
        label: String,
    ) -> Self {
        let base = spec_resource(kind, &label);
        let mut names = HashMap::default();
        names.insert(root.clone(), label.clone());
        Self {
            index,
            root_iris,
            root,
            kind,
            label,
            base,
            iris: HashMap::default(),
            minted: HashSet::default(),
            names,
            violations: Vec::new(),
            out: Vec::new(),
            out_set: HashSet::default(),
        }
    }

    fn violation(&mut self, constraint: impl Into<String>, node: &Node) {
        let subject = describe(node, &self.names);
        self.violations.push(Violation::new(constraint, subject));
    }

    /// The IRI of `node` in the stored model: given IRIs stay, blank nodes get `minted`.
    fn name_node(&mut self, node: &Node, minted: impl FnOnce() -> String) -> NamedNode {
        if let Some(iri) = self.iris.get(node) {
            return iri.clone();
        }
        let iri = match node {
            NamedOrBlankNode::NamedNode(n) => n.clone(),
            NamedOrBlankNode::BlankNode(_) => {
                let mut candidate = minted();
                if self.minted.contains(&candidate) {
                    candidate = format!("{candidate}-{}", self.iris.len());
                }
                self.minted.insert(candidate.clone());
                NamedNode::new_unchecked(candidate)
            }
        };
        self.iris.insert(node.clone(), iri.clone());
        iri
    }

    fn emit(&mut self, s: &NamedNode, p: NamedNodeRef<'_>, o: impl Into<Term>) {
        let t = Triple::new(s.clone(), p, o);
        if self.out_set.insert(t.clone()) {
            self.out.push(t);
        }
    }

    fn build(mut self, owned: Vec<Node>) -> (Option<ExtractedSpec>, Vec<Violation>) {
        let owned_set: HashSet<&Node> = owned.iter().collect();
        let root = self.root.clone();
        let base = self.base.clone();
        let root_iri = self.name_node(&root, || base.clone());
        let given_iri = match &root {
            NamedOrBlankNode::NamedNode(n) => Some(n.clone()),
            NamedOrBlankNode::BlankNode(_) => None,
        };
        let spec = match self.kind {
            SpecKind::Transformation => self.transformation(&root_iri).map(Spec::Transformation),
            SpecKind::Target => self.target(&root_iri).map(Spec::Target),
        };
        if spec.is_none() || !self.violations.is_empty() {
            // Rejected: no triples to write, so no need to copy the rest.
            return (None, std::mem::take(&mut self.violations));
        }
        // Copy the remaining statements of every owned node, renamed; structural links were
        // already written in normal form above.
        for node in &owned {
            let subject = self.name_node(node, || format!("{base}/node/{}", encode_id(node)));
            let index = self.index;
            for t in index.about(node) {
                if self.skip_copy(node, t) {
                    continue;
                }
                let object = match &t.object {
                    Term::BlankNode(b) => {
                        let n: Node = b.clone().into();
                        if owned_set.contains(&n) {
                            Term::from(self.name_node(&n, || format!("{base}/node/{}", b.as_str())))
                        } else if let Some(iri) = self.root_iris.get(&n) {
                            Term::from(iri.clone())
                        } else {
                            t.object.clone()
                        }
                    }
                    other => other.clone(),
                };
                let predicate = if t.predicate == dyknow::HAS_PORT_NAME {
                    dyknow::HAS_NAME.into_owned()
                } else {
                    t.predicate.clone()
                };
                self.emit(&subject, predicate.as_ref(), object);
            }
        }
        let violations = std::mem::take(&mut self.violations);
        let extracted = match spec {
            Some(spec) if violations.is_empty() => Some(ExtractedSpec {
                graph: spec_graph(self.kind, &self.label),
                spec,
                given_iri,
                triples: self.out,
            }),
            _ => None,
        };
        (extracted, violations)
    }

    /// Statements rewritten by normalisation rather than copied.
    fn skip_copy(&self, node: &Node, t: &Triple) -> bool {
        if t.predicate == dkros::HAS_INDEX {
            // Positions are written by normalisation (the document order).
            return true;
        }
        if *node == self.root {
            return [dkros::HAS_PORT, dyknow::HAS_IN_PORT, dyknow::HAS_OUT_PORT]
                .contains(&t.predicate.as_ref());
        }
        false
    }

    /// The recorded position of a port or tag (`dkros:hasIndex`), if any.
    fn position(&self, node: &Node) -> Option<u64> {
        let (values, _) = self.index.literals(node, &[dkros::HAS_INDEX]);
        values.first().and_then(|l| l.value().parse().ok())
    }

    fn tags(&mut self, owner: &Node, owner_iri: &NamedNode) -> Vec<Tag> {
        let mut tag_nodes: Vec<Term> = self
            .index
            .objects(owner, dyknow::HAS_TAG)
            .into_iter()
            .cloned()
            .collect();
        // A stored spec records the document order of its tags (`dkros:hasIndex`).
        tag_nodes.sort_by_key(|t| term_node(t).and_then(|n| self.position(&n)));
        if tag_nodes.len() > MAX_TAGS {
            self.violation(format!("at most {MAX_TAGS} tags per port or target"), owner);
            return Vec::new();
        }
        let mut tags = Vec::new();
        for (i, term) in tag_nodes.iter().enumerate() {
            let Some(node) = term_node(term) else {
                self.violation("dyknow:hasTag links to a Tag node, not a literal", owner);
                continue;
            };
            let owner_str = owner_iri.as_str().to_owned();
            let iri = self.name_node(&node, || format!("{owner_str}/tag/{i}"));
            let owner_name = describe(owner, &self.names);
            self.names
                .entry(node.clone())
                .or_insert_with(|| format!("{owner_name}/tag {i}"));
            let (values, value_not_literal) = self.index.literals(&node, &[dyknow::HAS_VALUE]);
            let descriptions = self.index.objects(&node, dyknow::HAS_TAG_DESCRIPTION);
            if value_not_literal || values.len() > 1 {
                self.violation(
                    "a Tag has at most 1 dyknow:hasValue, a literal (functional)",
                    &node,
                );
            }
            let description = match descriptions.as_slice() {
                [] => None,
                [Term::NamedNode(d)] => Some(d.as_str().to_owned()),
                _ => {
                    self.violation(
                        "a Tag has at most 1 dyknow:hasTagDescription, an IRI naming a concept (functional)",
                        &node,
                    );
                    None
                }
            };
            let value = values.first().map(|l| l.value().to_owned());
            if value.is_none() && description.is_none() && !value_not_literal {
                self.violation(
                    "a Tag has a dyknow:hasValue or a dyknow:hasTagDescription",
                    &node,
                );
            }
            self.emit(owner_iri, dyknow::HAS_TAG, iri.clone());
            self.emit(&iri, rdf::TYPE, dyknow::TAG);
            self.emit(&iri, dkros::HAS_INDEX, index_literal(tags.len()));
            tags.push(Tag { value, description });
        }
        tags
    }

    fn transformation(&mut self, root_iri: &NamedNode) -> Option<TransformationSpec> {
        let root = self.root.clone();
        self.emit(root_iri, rdf::TYPE, dyknow::TRANSFORMATION);
        // Ports: (node, direction as stated by the predicate).
        let mut links: Vec<(Node, Option<PortDirection>)> = Vec::new();
        let index = self.index;
        for t in index.about(&root) {
            let direction = if t.predicate == dyknow::HAS_IN_PORT {
                Some(PortDirection::In)
            } else if t.predicate == dyknow::HAS_OUT_PORT {
                Some(PortDirection::Out)
            } else if t.predicate == dkros::HAS_PORT {
                None
            } else {
                continue;
            };
            match term_node(&t.object) {
                Some(n) => links.push((n, direction)),
                None => self.violation("a port link points to a Port node, not a literal", &root),
            }
        }
        if links.len() > MAX_PORTS {
            self.violation(
                format!("a transformation has at most {MAX_PORTS} ports"),
                &root,
            );
            return None;
        }
        // A stored spec records the document order of its ports (`dkros:hasIndex`).
        links.sort_by_key(|(n, _)| self.position(n));
        let mut ports: Vec<(Node, Port)> = Vec::new();
        let mut port_names: HashSet<String> = HashSet::default();
        for (node, stated) in links {
            let is_in = self.index.has_type(&node, dyknow::IN_PORT);
            let is_out = self.index.has_type(&node, dyknow::OUT_PORT);
            let (names, name_not_literal) = self
                .index
                .literals(&node, &[dyknow::HAS_NAME, dyknow::HAS_PORT_NAME]);
            let name = match names.as_slice() {
                [one] if !name_not_literal => Some(one.value().to_owned()),
                _ => None,
            };
            self.names.insert(
                node.clone(),
                format!(
                    "{}/port {}",
                    self.label,
                    name.as_deref().unwrap_or("(unnamed)")
                ),
            );
            let Some(name) = name else {
                self.violation(
                    "a Port has exactly 1 name (dyknow:hasName), a literal",
                    &node,
                );
                continue;
            };
            let direction = match (stated, is_in, is_out) {
                (_, true, true)
                | (Some(PortDirection::In), _, true)
                | (Some(PortDirection::Out), true, _) => {
                    self.violation("InPort DisjointWith OutPort", &node);
                    continue;
                }
                (Some(d), _, _) => d,
                (None, true, false) => PortDirection::In,
                (None, false, true) => PortDirection::Out,
                (None, false, false) => {
                    self.violation(
                        "a port linked by dkros:hasPort is typed dyknow:InPort or dyknow:OutPort",
                        &node,
                    );
                    continue;
                }
            };
            if let Some((_, other)) = ports.iter().find(|(n, _)| *n == node) {
                if other.direction != direction {
                    self.violation("InPort DisjointWith OutPort", &node);
                }
                continue;
            }
            if !port_names.insert(name.clone()) {
                self.violation("port names are unique within a transformation", &node);
                continue;
            }
            let base = self.base.clone();
            let iri = self.name_node(&node, || format!("{base}/port/{}", encode(&name)));
            let (link, class) = match direction {
                PortDirection::In => (dyknow::HAS_IN_PORT, dyknow::IN_PORT),
                PortDirection::Out => (dyknow::HAS_OUT_PORT, dyknow::OUT_PORT),
            };
            self.emit(root_iri, link, iri.clone());
            self.emit(&iri, rdf::TYPE, class);
            self.emit(&iri, dkros::HAS_INDEX, index_literal(ports.len()));
            let tags = self.tags(&node, &iri);
            if tags.is_empty() && self.index.objects(&node, dyknow::HAS_TAG).is_empty() {
                self.violation("a Port has some Tag (dyknow:hasTag)", &node);
            }
            ports.push((
                node,
                Port {
                    name,
                    direction,
                    tags,
                },
            ));
        }
        let inputs: Vec<Port> = ports
            .iter()
            .filter(|(_, p)| p.direction == PortDirection::In)
            .map(|(_, p)| p.clone())
            .collect();
        let outputs: Vec<Port> = ports
            .iter()
            .filter(|(_, p)| p.direction == PortDirection::Out)
            .map(|(_, p)| p.clone())
            .collect();
        if self.index.has_type(&root, dyknow::SOURCE) && !inputs.is_empty() {
            self.violation(
                "Source has exactly 0 InPort (hasInPort exactly 0 InPort)",
                &root,
            );
        }
        if self.index.has_type(&root, dyknow::SINK) && !outputs.is_empty() {
            self.violation(
                "Sink has exactly 0 OutPort (hasOutPort exactly 0 OutPort)",
                &root,
            );
        }
        let (labour, upkeep) = self.costs(&root, root_iri);
        let (sources, _) = self.index.literals(&root, &[dkros::HAS_SOURCE]);
        if sources.len() > 1 {
            self.violation("a transformation has at most 1 dkros:hasSource", &root);
        }
        let (types, _) = self.index.literals(&root, &[dkros::HAS_TYPE]);
        if types.len() > 1 {
            // One was picked silently: which implementation runs must not be a guess.
            self.violation("a transformation has at most 1 dkros:hasType", &root);
        }
        let (executors, _) = self.index.literals(&root, &[dkros::HAS_EXECUTOR]);
        if executors.len() > 1 {
            self.violation("a transformation has at most 1 dkros:hasExecutor", &root);
        }
        let params = self.params(&root);
        Some(TransformationSpec {
            label: self.label.clone(),
            iri: root_iri.as_str().to_owned(),
            inputs,
            outputs,
            labour,
            upkeep,
            exec_type: types.first().map(|l| l.value().to_owned()),
            source: sources.first().map(|l| l.value().to_owned()),
            params,
            executor: executors.first().map(|l| l.value().to_owned()),
        })
    }

    /// The `dkros:hasParam` nodes of `root`: each names one parameter with one value.
    fn params(&mut self, root: &Node) -> Vec<Param> {
        let nodes: Vec<Term> = self
            .index
            .objects(root, dkros::HAS_PARAM)
            .into_iter()
            .cloned()
            .collect();
        let mut params: Vec<Param> = Vec::new();
        for term in nodes {
            let Some(node) = term_node(&term) else {
                self.violation(
                    "dkros:hasParam links to a Parameter node, not a literal",
                    root,
                );
                continue;
            };
            let (names, _) = self.index.literals(&node, &[dyknow::HAS_NAME]);
            let (values, _) = self.index.literals(&node, &[dyknow::HAS_VALUE]);
            let (types, _) = self.index.literals(&node, &[dkros::HAS_TYPE]);
            let (name, value) = match (names.as_slice(), values.as_slice()) {
                ([name], [value]) => ((*name).clone(), (*value).clone()),
                _ => {
                    self.names
                        .insert(node.clone(), format!("{}/parameter", self.label));
                    self.violation(
                        "a parameter has exactly 1 dyknow:hasName and exactly 1 dyknow:hasValue",
                        &node,
                    );
                    continue;
                }
            };
            if params.iter().any(|p| p.name == name.value()) {
                self.names
                    .insert(node.clone(), format!("{}/parameter", self.label));
                self.violation("parameter names are unique within a transformation", &node);
                continue;
            }
            let datatype = value.datatype().as_str();
            params.push(Param {
                name: name.value().to_owned(),
                value: value.value().to_owned(),
                datatype: datatype
                    .rsplit_once('#')
                    .map_or(datatype, |(_, local)| local)
                    .to_owned(),
                param_type: types.first().map(|l| l.value().to_owned()),
            });
        }
        params
    }

    fn costs(&mut self, root: &Node, root_iri: &NamedNode) -> (f64, f64) {
        let mut labour = None;
        let mut upkeep = None;
        let models: Vec<Term> = self
            .index
            .objects(root, dyknow::HAS_COST_MODEL)
            .into_iter()
            .cloned()
            .collect();
        for term in models {
            let Some(node) = term_node(&term) else {
                self.violation(
                    "dyknow:hasCostModel links to a CostModel node, not a literal",
                    root,
                );
                continue;
            };
            let is_labour = self.index.has_type(&node, dyknow::LABOUR_COST_MODEL);
            let is_upkeep = self.index.has_type(&node, dyknow::UPKEEP_COST_MODEL);
            let (slot, which) = match (is_labour, is_upkeep) {
                (true, false) => (&mut labour, "labour"),
                (false, true) => (&mut upkeep, "upkeep"),
                _ => {
                    self.names
                        .insert(node.clone(), format!("{}/cost model", self.label));
                    self.violation(
                        "a cost model is either a dyknow:LabourCostModel or a dyknow:UpkeepCostModel",
                        &node,
                    );
                    continue;
                }
            };
            self.names
                .insert(node.clone(), format!("{}/{which} cost", self.label));
            if slot.is_some() {
                self.violation(
                    format!("a transformation has at most 1 {which} cost model"),
                    &node,
                );
                continue;
            }
            let (values, not_literal) = self.index.literals(&node, &[dyknow::HAS_VALUE]);
            match (values.as_slice(), not_literal) {
                ([v], false) => match cost_value(v) {
                    Some(x) => *slot = Some(x),
                    None => {
                        self.violation(
                            format!("a {which} cost is a non-negative number up to 1e12 (dyknow:hasValue), not {v}"),
                            &node,
                        );
                        *slot = Some(DEFAULT_COST);
                    }
                },
                _ => {
                    self.violation(
                        format!("a {which} cost model has exactly 1 dyknow:hasValue, a non-negative number"),
                        &node,
                    );
                    *slot = Some(DEFAULT_COST);
                }
            }
            let base = self.base.clone();
            let iri = self.name_node(&node, || format!("{base}/cost/{which}"));
            self.emit(root_iri, dyknow::HAS_COST_MODEL, iri);
        }
        // Missing estimates default to 1.0 and are written, so the model is complete.
        for (slot, which, class) in [
            (&mut labour, "labour", dyknow::LABOUR_COST_MODEL),
            (&mut upkeep, "upkeep", dyknow::UPKEEP_COST_MODEL),
        ] {
            if slot.is_none() {
                *slot = Some(DEFAULT_COST);
                let iri = NamedNode::new_unchecked(format!("{}/cost/{which}", self.base));
                let t1 = Triple::new(root_iri.clone(), dyknow::HAS_COST_MODEL, iri.clone());
                let t2 = Triple::new(iri.clone(), rdf::TYPE, class);
                let t3 = Triple::new(
                    iri,
                    dyknow::HAS_VALUE,
                    Literal::new_typed_literal("1.0", xsd::DOUBLE),
                );
                for t in [t1, t2, t3] {
                    if self.out_set.insert(t.clone()) {
                        self.out.push(t);
                    }
                }
            }
        }
        (
            labour.unwrap_or(DEFAULT_COST),
            upkeep.unwrap_or(DEFAULT_COST),
        )
    }

    fn target(&mut self, root_iri: &NamedNode) -> Option<TargetSpec> {
        let root = self.root.clone();
        self.emit(root_iri, rdf::TYPE, dyknow::TARGET);
        let channels: Vec<Term> = self
            .index
            .objects(&root, dyknow::HAS_CHANNEL)
            .into_iter()
            .cloned()
            .collect();
        let mut channel = None;
        match channels.as_slice() {
            [term] => match term_node(term) {
                Some(node) => {
                    self.names
                        .insert(node.clone(), format!("{}/channel", self.label));
                    let (names, not_literal) =
                        self.index.literals(&node, &[dyknow::HAS_CHANNEL_NAME]);
                    match names.as_slice() {
                        [name] if !not_literal => {
                            let name = name.value().to_owned();
                            if !is_key_expression(&name) {
                                // `executors.md`: the channel is a Zenoh key expression.
                                self.violation(
                                    "a channel name maps to a key expression: non-empty '/'-separated chunks without '*', '$', '?', '#' or a leading '@'",
                                    &node,
                                );
                            }
                            let iri = self.name_node(&node, || channel_resource(&name));
                            self.emit(root_iri, dyknow::HAS_CHANNEL, iri.clone());
                            self.emit(&iri, rdf::TYPE, dyknow::CHANNEL);
                            channel = Some(name);
                        }
                        _ => self.violation(
                            "a Channel has exactly 1 dyknow:hasChannelName, a literal",
                            &node,
                        ),
                    }
                }
                None => self.violation(
                    "dyknow:hasChannel links to a Channel node, not a literal",
                    &root,
                ),
            },
            _ => self.violation("a Target has exactly 1 Channel (dyknow:hasChannel)", &root),
        }
        let tags = self.tags(&root, root_iri);
        if self.index.objects(&root, dyknow::HAS_TAG).is_empty() {
            self.violation("a Target has some Tag (dyknow:hasTag)", &root);
        }
        Some(TargetSpec {
            label: self.label.clone(),
            iri: root_iri.as_str().to_owned(),
            channel: channel?,
            tags,
        })
    }
}

fn index_literal(position: usize) -> Literal {
    Literal::new_typed_literal(position.to_string(), xsd::NON_NEGATIVE_INTEGER)
}

fn encode_id(node: &Node) -> String {
    match node {
        NamedOrBlankNode::BlankNode(b) => encode(b.as_str()),
        NamedOrBlankNode::NamedNode(n) => encode(n.as_str()),
    }
}

/// A cost: a non-negative number up to [`dyknow_engine::MAX_COST`] given as an XSD numeric
/// literal.
fn cost_value(literal: &Literal) -> Option<f64> {
    const NUMERIC: [&str; 13] = [
        "double",
        "float",
        "decimal",
        "integer",
        "int",
        "long",
        "short",
        "byte",
        "nonNegativeInteger",
        "positiveInteger",
        "unsignedInt",
        "unsignedLong",
        "unsignedShort",
    ];
    let datatype = literal.datatype();
    let local = datatype.as_str().strip_prefix(xsd::NAMESPACE)?;
    if !NUMERIC.contains(&local) {
        return None;
    }
    let x: f64 = literal.value().trim().parse().ok()?;
    dyknow_engine::valid_cost(x).then_some(x)
}

/// Rebuilds the spec held in a spec graph (the graph is in normal form).
pub(crate) fn spec_from_graph(triples: &[Triple], kind: SpecKind) -> Option<Spec> {
    let doc = extract(triples, &SpecClasses::default(), Some(kind), false).ok()?;
    doc.specs.into_iter().next().map(|s| s.spec)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rdf_input::{InputFormat, parse_triples};

    const PREFIXES: &str = "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
@prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
@prefix xsd: <http://www.w3.org/2001/XMLSchema#> .
@prefix ex: <http://example.org/ex#> .
";

    fn doc(body: &str) -> Vec<Triple> {
        parse_triples(format!("{PREFIXES}{body}").as_bytes(), InputFormat::Turtle)
            .expect("valid Turtle")
    }

    fn typed(value: &str, datatype: &str) -> Literal {
        Literal::new_typed_literal(
            value,
            NamedNode::new_unchecked(format!("{}{datatype}", xsd::NAMESPACE)),
        )
    }

    fn is_blank_free(t: &Triple) -> bool {
        !matches!(t.subject, NamedOrBlankNode::BlankNode(_))
            && !matches!(t.object, Term::BlankNode(_))
    }

    #[test]
    fn costs_are_finite_non_negative_xsd_numbers() {
        for (value, datatype, expected) in [
            ("1.0", "double", Some(1.0)),
            ("1.5E2", "double", Some(150.0)),
            ("0", "integer", Some(0.0)),
            (" 2.5 ", "decimal", Some(2.5)),
            ("3", "nonNegativeInteger", Some(3.0)),
            ("0.25", "float", Some(0.25)),
            ("7", "unsignedShort", Some(7.0)),
            ("-1", "integer", None),
            ("-0.001", "decimal", None),
            ("NaN", "double", None),
            ("INF", "double", None),
            ("-INF", "float", None),
            ("1e400", "double", None),
            ("abc", "double", None),
            ("1.0", "string", None),
            ("true", "boolean", None),
            ("1", "dateTime", None),
        ] {
            assert_eq!(
                cost_value(&typed(value, datatype)),
                expected,
                "{value:?}^^xsd:{datatype}"
            );
        }
        // Negative zero is not below zero.
        assert_eq!(cost_value(&typed("-0", "decimal")), Some(0.0));
        assert_eq!(cost_value(&Literal::new_simple_literal("1.0")), None);
        assert_eq!(
            cost_value(&Literal::new_language_tagged_literal_unchecked("1.0", "en")),
            None
        );
        assert_eq!(
            cost_value(&Literal::new_typed_literal(
                "1.0",
                NamedNode::new_unchecked("http://example.org/double")
            )),
            None,
            "only XSD datatypes"
        );
    }

    #[test]
    fn the_default_spec_classes_are_the_ontology_classes() {
        let classes = SpecClasses::default();
        for c in [
            dyknow::TRANSFORMATION,
            dyknow::SOURCE,
            dyknow::SINK,
            dkros::ROS_TRANSFORMATION,
        ] {
            assert!(classes.transformation.contains(&c.into_owned()), "{c}");
            assert!(!classes.target.contains(&c.into_owned()), "{c}");
        }
        for c in [dyknow::TARGET, dkros::ROS_TARGET] {
            assert!(classes.target.contains(&c.into_owned()), "{c}");
        }
        assert_eq!((classes.transformation.len(), classes.target.len()), (4, 2));
    }

    #[test]
    fn a_mixed_document_yields_both_kinds_in_order_and_the_rest() {
        let triples = doc(r#"
[] a dkros:ROSTarget ; rdfs:label "q" ;
   dyknow:hasChannel [ a dkros:Topic ; dyknow:hasChannelName "/c" ] ; dyknow:hasTag [ dyknow:hasValue "T" ] .
ex:A dyknow:similarTo ex:B .
[] a dyknow:Transformation ; rdfs:label "t" ;
   dyknow:hasOutPort [ dyknow:hasName "o" ; dyknow:hasTag [ dyknow:hasValue "T" ] ] .
"#);
        let extracted = extract_specs(&triples, &SpecClasses::default(), None).expect("valid");
        let kinds: Vec<(SpecKind, &str)> = extracted
            .specs
            .iter()
            .map(|s| (s.spec.kind(), s.spec.label()))
            .collect();
        assert_eq!(
            kinds,
            [(SpecKind::Target, "q"), (SpecKind::Transformation, "t")]
        );
        assert_eq!(extracted.rest.len(), 1);
        assert_eq!(extracted.rest[0].predicate, dyknow::SIMILAR_TO);
        for spec in &extracted.specs {
            assert_eq!(spec.given_iri, None);
            assert_eq!(spec.graph, spec_graph(spec.spec.kind(), spec.spec.label()));
            assert!(
                spec.triples.iter().all(is_blank_free),
                "{:#?}",
                spec.triples
            );
            let base = spec_resource(spec.spec.kind(), spec.spec.label());
            assert!(
                spec.triples
                    .iter()
                    .all(|t| t.subject.to_string().starts_with(&format!("<{base}"))
                        || t.subject.to_string().starts_with("<urn:dyknow:channel:")),
                "every minted IRI is under the spec's resource: {:#?}",
                spec.triples
            );
        }
        // The channel is named by its name, so targets naming one channel share it.
        let target = &extracted.specs[0];
        assert!(
            target
                .triples
                .iter()
                .any(|t| t.predicate == dyknow::HAS_CHANNEL
                    && t.object == Term::from(NamedNode::new_unchecked("urn:dyknow:channel:%2Fc")))
        );

        // The endpoints take one kind, and no vocabulary.
        let err = extract_specs(
            &triples,
            &SpecClasses::default(),
            Some(SpecKind::Transformation),
        )
        .expect_err("a target and vocabulary");
        assert!(
            err.0
                .iter()
                .any(|v| v.constraint.contains("accepts transformation specs only"))
        );
        assert!(err.0.iter().any(
            |v| v.constraint.contains("every statement belongs to a spec")
                && v.subject == "http://example.org/ex#A"
        ));
    }

    #[test]
    fn specs_own_blank_nodes_and_iris_along_structural_links_only() {
        let triples = doc(r#"
[] a dyknow:Transformation ; rdfs:label "t" ;
   dyknow:hasOutPort ex:port ;
   rdfs:seeAlso ex:elsewhere ;
   ex:note [ ex:text "owned, as a blank node" ] .
ex:port dyknow:hasName "o" ; dyknow:hasTag [ dyknow:hasValue "T" ] .
ex:elsewhere rdfs:label "not owned" .
"#);
        let extracted = extract_specs(&triples, &SpecClasses::default(), None).expect("valid");
        assert_eq!(extracted.specs.len(), 1);
        let spec = &extracted.specs[0];
        let Spec::Transformation(t) = &spec.spec else {
            panic!("a transformation")
        };
        assert_eq!(t.outputs.len(), 1);
        assert_eq!(t.outputs[0].name, "o");
        let port = NamedNode::new_unchecked("http://example.org/ex#port");
        assert!(
            spec.triples.iter().any(
                |t| t.predicate == dyknow::HAS_OUT_PORT && t.object == Term::from(port.clone())
            ),
            "a port given by IRI keeps its IRI"
        );
        assert!(
            spec.triples
                .iter()
                .any(|t| t.object
                    == Term::from(Literal::new_simple_literal("owned, as a blank node")))
        );
        assert!(
            spec.triples
                .iter()
                .any(|t| t.predicate == rdfs::LABEL.into_owned()
                    && t.object == Term::from(Literal::new_simple_literal("t")))
        );
        assert!(
            !spec
                .triples
                .iter()
                .any(|t| t.object == Term::from(Literal::new_simple_literal("not owned")))
        );
        assert_eq!(extracted.rest.len(), 1, "{:#?}", extracted.rest);
        assert_eq!(
            extracted.rest[0].subject.to_string(),
            "<http://example.org/ex#elsewhere>"
        );
    }

    #[test]
    fn a_spec_does_not_swallow_another_spec_it_links_to() {
        let triples = doc(r#"
_:a a dyknow:Transformation ; rdfs:label "a" ; ex:next _:b ;
   dyknow:hasOutPort [ dyknow:hasName "o" ; dyknow:hasTag [ dyknow:hasValue "T" ] ] .
_:b a dyknow:Transformation ; rdfs:label "b" ;
   dyknow:hasOutPort [ dyknow:hasName "o" ; dyknow:hasTag [ dyknow:hasValue "U" ] ] .
"#);
        let extracted = extract_specs(
            &triples,
            &SpecClasses::default(),
            Some(SpecKind::Transformation),
        )
        .expect("valid");
        assert_eq!(extracted.specs.len(), 2);
        let a = &extracted.specs[0];
        assert_eq!(a.spec.label(), "a");
        assert!(
            !a.triples
                .iter()
                .any(|t| t.object == Term::from(Literal::new_simple_literal("b"))
                    || t.object == Term::from(Literal::new_simple_literal("U"))),
            "b's statements are b's: {:#?}",
            a.triples
        );
        assert!(extracted.rest.is_empty());
    }

    #[test]
    fn every_violation_of_a_document_is_reported_at_once() {
        let triples = doc(r#"
[] a dyknow:Transformation ; rdfs:label "a" ;
   dyknow:hasOutPort [ dyknow:hasName "o" ] .
[] a dyknow:Source ; rdfs:label "b" ;
   dyknow:hasInPort [ dyknow:hasName "i" ; dyknow:hasTag [ dyknow:hasValue "T" ] ] ;
   dyknow:hasCostModel [ a dyknow:UpkeepCostModel ; dyknow:hasValue -1 ] .
[] a dyknow:Transformation .
"#);
        let err = extract_specs(
            &triples,
            &SpecClasses::default(),
            Some(SpecKind::Transformation),
        )
        .expect_err("invalid");
        let found: Vec<(&str, &str)> = err
            .0
            .iter()
            .map(|v| (v.constraint.as_str(), v.subject.as_str()))
            .collect();
        assert!(
            found
                .iter()
                .any(|(c, s)| c.starts_with("a Port has some Tag") && *s == "a/port o"),
            "{found:#?}"
        );
        assert!(
            found
                .iter()
                .any(|(c, s)| c.starts_with("Source has exactly 0 InPort") && *s == "b"),
            "{found:#?}"
        );
        assert!(
            found
                .iter()
                .any(|(c, s)| c.contains("upkeep cost is a non-negative number")
                    && *s == "b/upkeep cost"),
            "{found:#?}"
        );
        assert!(
            found
                .iter()
                .any(|(c, s)| c.contains("exactly 1 rdfs:label") && *s == "a blank node"),
            "{found:#?}"
        );
        assert_eq!(found.len(), 4, "{found:#?}");
    }

    #[test]
    fn a_stored_graph_reads_back_as_the_posted_spec() {
        let triples = doc(r#"
[] a dkros:ROSTransformation ; rdfs:label "Undistort(cam1)" ;
   dkros:hasType "nodelet" ; dkros:hasSource "package/Undistort" ;
   dkros:hasParam [ a dyknow:Parameter ; dyknow:hasName "configPath" ; dyknow:hasValue "/p/" ] ;
   dkros:hasPort [ a dyknow:InPort ; dyknow:hasPortName "raw" ; dyknow:hasTag [ dyknow:hasValue "A" ] ] ;
   dkros:hasPort [ a dyknow:OutPort ; dyknow:hasName "undist" ; dyknow:hasTag [ dyknow:hasTagDescription ex:B ] ] ;
   dyknow:hasCostModel [ a dyknow:UpkeepCostModel ; dyknow:hasValue 0.5 ] .
"#);
        let extracted = extract_specs(
            &triples,
            &SpecClasses::default(),
            Some(SpecKind::Transformation),
        )
        .expect("valid");
        let spec = &extracted.specs[0];
        let Spec::Transformation(t) = &spec.spec else {
            panic!("a transformation")
        };
        assert_eq!((t.labour, t.upkeep), (DEFAULT_COST, 0.5));
        assert_eq!(t.inputs[0].name, "raw");
        assert_eq!(
            t.outputs[0].tags,
            [Tag {
                value: None,
                description: Some("http://example.org/ex#B".into())
            }]
        );
        // The normal form: hasPortName becomes hasName, hasPort becomes hasIn/OutPort, the
        // missing labour estimate is written.
        assert!(
            !spec
                .triples
                .iter()
                .any(|t| t.predicate == dyknow::HAS_PORT_NAME || t.predicate == dkros::HAS_PORT)
        );
        assert!(
            spec.triples
                .iter()
                .any(|t| t.predicate == rdf::TYPE
                    && t.object == Term::from(dyknow::LABOUR_COST_MODEL))
        );
        assert_eq!(
            spec_from_graph(&spec.triples, SpecKind::Transformation),
            Some(spec.spec.clone())
        );
        assert_eq!(spec_from_graph(&spec.triples, SpecKind::Target), None);
        assert_eq!(spec_from_graph(&[], SpecKind::Transformation), None);
        // Normalising is idempotent.
        let again = extract_specs(
            &spec.triples,
            &SpecClasses::default(),
            Some(SpecKind::Transformation),
        )
        .expect("the normal form is valid");
        let mut first: Vec<String> = spec.triples.iter().map(ToString::to_string).collect();
        let mut second: Vec<String> = again.specs[0]
            .triples
            .iter()
            .map(ToString::to_string)
            .collect();
        first.sort();
        second.sort();
        assert_eq!(first, second);
    }

    #[test]
    fn capitalised_and_describe() {
        assert_eq!(capitalised("transformation"), "Transformation");
        assert_eq!(capitalised(""), "");
        let iri: Node = NamedNode::new_unchecked("http://example.org/x").into();
        let blank: Node = oxigraph::model::BlankNode::default().into();
        assert_eq!(describe(&iri, &HashMap::default()), "http://example.org/x");
        assert_eq!(describe(&blank, &HashMap::default()), "a blank node");
        let names: HashMap<_, _> = [(blank.clone(), "t/port o".to_owned())]
            .into_iter()
            .collect();
        assert_eq!(describe(&blank, &names), "t/port o");
    }
}
