//! Ontology extensions: tag vocabularies, sub-concepts, `dyknow:similarTo`, domain classes.
//! Sub-classes of the spec classes may come from extensions, so the classes whose instances
//! are spec roots are recomputed after each extension write.

use dyknow_ontology::BUILTIN_ONTOLOGIES;
use dyknow_ontology::vocab::{dyknow, owl, rdf, rdfs};
use oxigraph::model::{NamedNode, Term, Triple};
use oxigraph::sparql::{QueryResults, SparqlEvaluator};
use oxigraph::store::StorageError;
use serde::Serialize;

use super::KnowledgeBase;
use crate::error::{IngestError, SpecValidationError, Violation};
use crate::graphs::{extension_graph, graph_hash, is_extension_graph};
use crate::rdf_input::{InputFormat, fresh_blank_nodes, parse_triples};
use crate::spec::{SpecClasses, extract_specs};

/// What an ontology extension POST did.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ExtensionReport {
    /// The named graph holding the extension.
    pub graph: String,
    /// Whether the same extension was there already (and was replaced).
    pub replaced: bool,
}

/// An ontology extension in the store.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ExtensionInfo {
    /// Its named graph.
    pub graph: String,
    /// The `owl:Ontology` it declares, if any.
    pub ontology: Option<String>,
    /// How many triples it holds.
    pub triples: usize,
}

/// What an ontology extension may say, whether posted (`POST /ontology`) or loaded with specs
/// (`dyknow load`, `serve --specs`). It adds vocabulary: it does not restate the built-in
/// terms (their axioms are the seed's, and `dyknow:dependsOn a owl:SymmetricProperty` made
/// every CU depend on itself), nor describe the service's own resources (`urn:dyknow:`: CUs,
/// channels, specs, change sets; a stated `dependsOn` between two CUs read as a real one).
/// Only what is said *of* those terms is refused (equivalences, labels and comments aside): an
/// axiom of the extension's own terms that entails something of them (`ex:p
/// owl:equivalentProperty dyknow:dependsOn ; a owl:SymmetricProperty`) is the reasoner's to
/// check for consistency, and is not refused here. And `dyknow:similarTo` relates tag concepts:
/// a literal is no concept, and the candidate table would have ignored the statement.
pub(super) fn check_vocabulary(
    triples: &[Triple],
    classes: &SpecClasses,
) -> Result<(), SpecValidationError> {
    let mut violations: Vec<Violation> = Vec::new();
    for t in triples {
        let oxigraph::model::NamedOrBlankNode::NamedNode(subject) = &t.subject else {
            continue;
        };
        // Equivalences read the same either way round (`dyknow:Transformation
        // owl:equivalentClass ex:Job` defines `ex:Job`), and labels and comments say nothing
        // of meaning: those are taken of built-in terms.
        let harmless = [
            owl::EQUIVALENT_CLASS,
            owl::EQUIVALENT_PROPERTY,
            rdfs::LABEL,
            rdfs::COMMENT,
        ]
        .contains(&t.predicate.as_ref());
        let why = if classes.builtin.contains(subject) && !harmless {
            "ontology extensions add terms; they do not restate the built-in ones (the seed's \
             axioms): state a sub-class or sub-property of your own instead"
        } else if subject.as_str().starts_with("urn:dyknow:") {
            "ontology extensions hold vocabularies; the service's own resources (urn:dyknow: CUs, \
             channels, specs, change sets) are described by the service"
        } else {
            continue;
        };
        if !violations.iter().any(|v| v.subject == subject.as_str()) {
            violations.push(Violation::new(why, subject.as_str()));
        }
    }
    violations.truncate(10);
    violations.extend(
        triples
            .iter()
            .filter(|t| {
                t.predicate.as_ref() == dyknow::SIMILAR_TO && matches!(t.object, Term::Literal(_))
            })
            .map(|t| {
                Violation::new(
                    "dyknow:similarTo relates tag concepts (IRIs), not literals",
                    t.to_string(),
                )
            })
            .take(10),
    );
    if violations.is_empty() {
        Ok(())
    } else {
        Err(SpecValidationError(violations))
    }
}

impl KnowledgeBase {
    /// Recomputes the classes whose instances are spec roots (sub-classes may come from
    /// extensions).
    pub(super) fn refresh_classes(&self) -> Result<(), StorageError> {
        let mut classes = SpecClasses::default();
        for (base, set) in [
            (dyknow::TRANSFORMATION, &mut classes.transformation),
            (dyknow::TARGET, &mut classes.target),
        ] {
            let query = format!(
                "SELECT DISTINCT ?c WHERE {{ ?c (<{sub}>|<{eq}>|^<{eq}>)* <{base}> FILTER(isIRI(?c)) }}",
                sub = rdfs::SUB_CLASS_OF.as_str(),
                eq = owl::EQUIVALENT_CLASS.as_str(),
                base = base.as_str()
            );
            let mut prepared = SparqlEvaluator::new()
                .parse_query(&query)
                .map_err(|e| StorageError::Other(Box::new(e)))?;
            prepared.dataset_mut().set_default_graph_as_union();
            let results = prepared
                .on_store(&self.store)
                .execute()
                .map_err(|e| StorageError::Other(Box::new(e)))?;
            if let QueryResults::Solutions(solutions) = results {
                for solution in solutions {
                    let solution = solution.map_err(|e| StorageError::Other(Box::new(e)))?;
                    if let Some(Term::NamedNode(c)) = solution.get("c") {
                        set.insert(c.clone());
                    }
                }
            }
        }
        // The terms of the DyKnow namespaces the built-in ontologies and the extensions
        // declare (subjects of their statements), beside the service's own vocabulary.
        for graph in self.store.named_graphs() {
            let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph? else {
                continue;
            };
            if !is_extension_graph(g.as_str())
                && !BUILTIN_ONTOLOGIES.iter().any(|(iri, _)| *iri == g.as_str())
            {
                continue;
            }
            for quad in self
                .store
                .quads_for_pattern(None, None, None, Some(g.as_ref().into()))
            {
                if let oxigraph::model::NamedOrBlankNode::NamedNode(s) = quad?.subject
                    && crate::spec::in_dyknow_namespaces(s.as_str())
                {
                    if !is_extension_graph(g.as_str()) {
                        classes.builtin.insert(s.clone());
                    }
                    classes.vocabulary.insert(s);
                }
            }
        }
        *self
            .classes
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = classes;
        Ok(())
    }

    pub(super) fn classes(&self) -> SpecClasses {
        self.classes
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Posts an ontology extension (tag vocabularies, sub-concepts, `dyknow:similarTo`, domain
    /// classes). The graph is named after the body's content, so re-posting it replaces it.
    pub fn post_extension(
        &self,
        body: &[u8],
        format: InputFormat,
    ) -> Result<ExtensionReport, IngestError> {
        let triples = parse_triples(body, format)?;
        let classes = self.classes();
        let doc = extract_specs(&triples, &classes, None)?;
        check_vocabulary(&triples, &classes)?;
        if !doc.specs.is_empty() {
            let violations = doc
                .specs
                .iter()
                .map(|s| {
                    Violation::new(
                        format!(
                            "ontology extensions hold vocabularies; post {} specs to /{}s",
                            s.spec.kind().name(),
                            s.spec.kind().name()
                        ),
                        s.spec.label(),
                    )
                })
                .collect();
            return Err(SpecValidationError(violations).into());
        }
        if triples.is_empty() {
            return Err(SpecValidationError(vec![Violation::new(
                "an ontology extension has at least one statement",
                "the request body",
            )])
            .into());
        }
        let graph = extension_graph(graph_hash(&triples));
        let mut reasoner = self.lock();
        let triples = fresh_blank_nodes(&triples);
        let replaced = self.commit(&mut reasoner, &[(&graph, &triples)], &[])?[0];
        drop(reasoner);
        self.refresh_classes()?;
        Ok(ExtensionReport {
            graph: graph.into_string(),
            replaced,
        })
    }

    /// The ontology extensions, sorted by graph name.
    pub fn extensions(&self) -> Result<Vec<ExtensionInfo>, StorageError> {
        let mut out = Vec::new();
        for graph in self.store.named_graphs() {
            let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph? else {
                continue;
            };
            if !is_extension_graph(g.as_str()) {
                continue;
            }
            let triples = self.graph_triples(g.as_ref())?;
            let ontology = triples
                .iter()
                .find(|t| t.predicate == rdf::TYPE && t.object == Term::from(owl::ONTOLOGY))
                .map(|t| t.subject.to_string().trim_matches(['<', '>']).to_owned());
            out.push(ExtensionInfo {
                graph: g.into_string(),
                ontology,
                triples: triples.len(),
            });
        }
        out.sort_by(|a, b| a.graph.cmp(&b.graph));
        Ok(out)
    }

    /// Removes an ontology extension.
    pub fn remove_extension(&self, graph: &str) -> Result<(), IngestError> {
        if BUILTIN_ONTOLOGIES.iter().any(|(iri, _)| *iri == graph) {
            return Err(IngestError::Conflict(format!(
                "<{graph}> is a built-in ontology and cannot be removed"
            )));
        }
        if !is_extension_graph(graph) {
            return Err(IngestError::NotFound(format!(
                "<{graph}> is not an ontology extension"
            )));
        }
        let graph = NamedNode::new_unchecked(graph);
        let mut reasoner = self.lock();
        if !self.store.contains_named_graph(&graph)? {
            return Err(IngestError::NotFound(format!(
                "no ontology extension <{}>",
                graph.as_str()
            )));
        }
        self.commit(&mut reasoner, &[], &[&graph])?;
        drop(reasoner);
        self.refresh_classes()?;
        Ok(())
    }
}
