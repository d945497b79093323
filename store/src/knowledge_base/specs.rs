//! AddTransformation, AddTarget, RemoveTransformation, RemoveTarget (seed Ch. 5.3), loading
//! mixed documents, and reading specs back.

use std::collections::BTreeMap;

use dyknow_ontology::vocab::rdfs;
use oxigraph::model::{GraphNameRef, NamedNode, NamedNodeRef, NamedOrBlankNodeRef, Triple};
use oxigraph::store::StorageError;
use serde::Serialize;

use super::KnowledgeBase;
use crate::error::{IngestError, SpecValidationError, Violation};
use crate::graphs::{extension_graph, graph_hash, spec_graph, spec_of_graph, spec_resource};
use crate::rdf_input::{InputFormat, fresh_blank_nodes, parse_triples};
use crate::spec::{ExtractedSpec, Spec, SpecKind, extract_specs, spec_from_graph};

/// What a spec POST did.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct PostReport {
    /// The labels of the specs written, in document order.
    pub labels: Vec<String>,
    /// Those of them that replaced an existing spec.
    pub replaced: Vec<String>,
}

/// What loading a mixed document did (offline `load`, `serve --specs`).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct LoadReport {
    /// Transformation specs written.
    pub transformations: PostReport,
    /// Target specs written.
    pub targets: PostReport,
    /// The extension graph written for the remaining triples, if any.
    pub extension: Option<String>,
}

impl KnowledgeBase {
    /// AddTransformation / AddTarget: writes the specs of `kind` in `body`, atomically. A spec
    /// whose label exists replaces it.
    pub fn post_specs(
        &self,
        body: &[u8],
        format: InputFormat,
        kind: SpecKind,
    ) -> Result<PostReport, IngestError> {
        self.post_specs_checked(body, format, kind, &|_| None)
    }

    /// [`post_specs`](Self::post_specs), refusing the document when `refuse` says why one of
    /// its specs may not be written (the service reserves labels for what it makes itself):
    /// a [`SpecValidationError`] naming every such spec, and nothing written.
    pub fn post_specs_checked(
        &self,
        body: &[u8],
        format: InputFormat,
        kind: SpecKind,
        refuse: &dyn Fn(&Spec) -> Option<String>,
    ) -> Result<PostReport, IngestError> {
        let triples = parse_triples(body, format)?;
        let doc = extract_specs(&triples, &self.classes(), Some(kind))?;
        let refused: Vec<Violation> = doc
            .specs
            .iter()
            .filter_map(|s| refuse(&s.spec).map(|why| Violation::new(why, s.spec.label())))
            .collect();
        if !refused.is_empty() {
            return Err(SpecValidationError(refused).into());
        }
        let mut reasoner = self.lock();
        self.check_identities(&doc.specs)?;
        let graphs: Vec<(&NamedNode, &[Triple])> = doc
            .specs
            .iter()
            .map(|s| (&s.graph, s.triples.as_slice()))
            .collect();
        let replaced = self.commit(&mut reasoner, &graphs, &[])?;
        Ok(PostReport {
            labels: doc
                .specs
                .iter()
                .map(|s| s.spec.label().to_owned())
                .collect(),
            replaced: doc
                .specs
                .iter()
                .zip(replaced)
                .filter(|(_, r)| *r)
                .map(|(s, _)| s.spec.label().to_owned())
                .collect(),
        })
    }

    /// Loads a document holding any mix of transformation specs, target specs and vocabulary
    /// (the latter becomes one ontology extension), atomically.
    pub fn load_document(
        &self,
        body: &[u8],
        format: InputFormat,
    ) -> Result<LoadReport, IngestError> {
        let triples = parse_triples(body, format)?;
        // What becomes an extension is not checked as `POST /ontology` checks an extension
        // (`check_vocabulary`): this is the offline, trusted path, and a model export (which
        // restates the built-in ontologies and describes the service's resources) loads back
        // whole.
        let doc = extract_specs(&triples, &self.classes(), None)?;
        // Hashed before the lock: a long list takes a round of refinement per member.
        let extension = (!doc.rest.is_empty()).then(|| {
            (
                extension_graph(graph_hash(&doc.rest)),
                fresh_blank_nodes(&doc.rest),
            )
        });
        let mut reasoner = self.lock();
        self.check_identities(&doc.specs)?;
        let mut graphs: Vec<(&NamedNode, &[Triple])> = doc
            .specs
            .iter()
            .map(|s| (&s.graph, s.triples.as_slice()))
            .collect();
        if let Some((graph, triples)) = &extension {
            graphs.push((graph, triples.as_slice()));
        }
        let replaced = self.commit(&mut reasoner, &graphs, &[])?;
        let mut report = LoadReport {
            extension: extension.as_ref().map(|(g, _)| g.as_str().to_owned()),
            ..LoadReport::default()
        };
        for (spec, replaced) in doc.specs.iter().zip(replaced) {
            let part = match spec.spec.kind() {
                SpecKind::Transformation => &mut report.transformations,
                SpecKind::Target => &mut report.targets,
            };
            part.labels.push(spec.spec.label().to_owned());
            if replaced {
                part.replaced.push(spec.spec.label().to_owned());
            }
        }
        drop(reasoner);
        if report.extension.is_some() {
            self.refresh_classes()?;
        }
        Ok(report)
    }

    /// A spec's resource (the IRI the document gave, or the one minted for its label) is its
    /// own: not the resource of another spec, stored or in the same document (a spec given
    /// `<urn:dyknow:transformation:zz>` labelled "yy", then a blank node labelled "zz", made
    /// two specs of one resource, whose export did not load back: a user audit). An IRI the
    /// document gives is not one of the service's own (`urn:dyknow:…`: CUs, channels, change
    /// sets, another label's minted IRI) other than the one minted for the spec's own label
    /// (an export loads back), nor a term of the built-in vocabularies (`dyknow:`, `dkros:`,
    /// RDF, RDFS, OWL, XSD).
    pub(super) fn check_identities(&self, specs: &[ExtractedSpec]) -> Result<(), IngestError> {
        const BUILT_IN: [&str; 6] = [
            dyknow_ontology::vocab::dyknow::NAMESPACE,
            dyknow_ontology::vocab::dkros::NAMESPACE,
            "http://www.w3.org/1999/02/22-rdf-syntax-ns#",
            "http://www.w3.org/2000/01/rdf-schema#",
            "http://www.w3.org/2002/07/owl#",
            "http://www.w3.org/2001/XMLSchema#",
        ];
        let mut violations = Vec::new();
        let mut in_document: BTreeMap<String, (SpecKind, &str)> = BTreeMap::new();
        // The specs the document replaces: a stored spec of theirs gives its resource up (a
        // rename or a swap of IRIs in one document is consistent once written).
        let replaced: std::collections::BTreeSet<(&str, &str)> = specs
            .iter()
            .map(|s| (s.spec.kind().name(), s.spec.label()))
            .collect();
        for spec in specs {
            let (kind, label) = (spec.spec.kind(), spec.spec.label());
            let minted = spec_resource(kind, label);
            let resource = spec
                .given_iri
                .as_ref()
                .map_or_else(|| minted.clone(), |iri| iri.as_str().to_owned());
            if spec.given_iri.is_some() {
                if resource.starts_with("urn:dyknow:") && resource != minted {
                    violations.push(Violation::new(
                        format!(
                            "<{resource}> is an IRI of the service's own (urn:dyknow:…): a {} \
                             labelled {label:?} given an IRI of that namespace must be <{minted}> \
                             (or give it a blank node, or an IRI of your own)",
                            kind.name()
                        ),
                        label,
                    ));
                    continue;
                }
                if let Some(ns) = BUILT_IN.iter().find(|ns| resource.starts_with(**ns)) {
                    violations.push(Violation::new(
                        format!(
                            "<{resource}> is a term of a built-in vocabulary ({ns}), not a \
                             {}'s resource",
                            kind.name()
                        ),
                        label,
                    ));
                    continue;
                }
            }
            match in_document.insert(resource.clone(), (kind, label)) {
                Some((other_kind, other)) if (other_kind, other) != (kind, label) => {
                    violations.push(Violation::new(
                        format!(
                            "one resource describes one spec: <{resource}> is the {} labelled \
                             {other:?} in this document too",
                            other_kind.name()
                        ),
                        label,
                    ));
                    continue;
                }
                _ => {}
            }
            let node = NamedNode::new_unchecked(resource.as_str());
            for quad in self.store.quads_for_pattern(
                Some(NamedOrBlankNodeRef::from(node.as_ref())),
                Some(rdfs::LABEL),
                None,
                None,
            ) {
                let quad = quad?;
                let oxigraph::model::GraphName::NamedNode(g) = &quad.graph_name else {
                    continue;
                };
                if let Some((other_kind, other)) = spec_of_graph(g.as_str())
                    && (other_kind != kind || other != label)
                    && !replaced.contains(&(other_kind.name(), other.as_str()))
                {
                    violations.push(Violation::new(
                        format!(
                            "one resource describes one spec: <{resource}> is already the {} \
                             labelled {other:?}",
                            other_kind.name()
                        ),
                        label,
                    ));
                }
            }
        }
        if violations.is_empty() {
            Ok(())
        } else {
            Err(SpecValidationError(violations).into())
        }
    }

    /// RemoveTransformation / RemoveTarget.
    pub fn remove_spec(&self, kind: SpecKind, label: &str) -> Result<(), IngestError> {
        let graph = spec_graph(kind, label);
        let mut reasoner = self.lock();
        if !self.store.contains_named_graph(&graph)? {
            return Err(IngestError::NotFound(format!(
                "no {} labelled {label:?}",
                kind.name()
            )));
        }
        self.commit(&mut reasoner, &[], &[&graph])?;
        Ok(())
    }

    /// The triples of a named graph.
    pub fn graph_triples(&self, graph: NamedNodeRef<'_>) -> Result<Vec<Triple>, StorageError> {
        self.store
            .quads_for_pattern(None, None, None, Some(GraphNameRef::from(graph)))
            .map(|q| q.map(Triple::from))
            .collect()
    }

    /// The spec of `kind` labelled `label`.
    pub fn spec(&self, kind: SpecKind, label: &str) -> Result<Option<Spec>, StorageError> {
        let graph = spec_graph(kind, label);
        let triples = self.graph_triples(graph.as_ref())?;
        Ok(if triples.is_empty() {
            None
        } else {
            spec_from_graph(&triples, kind)
        })
    }

    /// The names of the graphs holding specs of `kind`, with their labels, sorted by label.
    pub fn spec_graphs(&self, kind: SpecKind) -> Result<Vec<(String, NamedNode)>, StorageError> {
        let mut out = BTreeMap::new();
        for graph in self.store.named_graphs() {
            if let oxigraph::model::NamedOrBlankNode::NamedNode(g) = graph?
                && let Some((k, label)) = spec_of_graph(g.as_str())
                && k == kind
            {
                out.insert(label, g);
            }
        }
        Ok(out.into_iter().collect())
    }

    /// All specs of `kind`, sorted by label.
    pub fn specs(&self, kind: SpecKind) -> Result<Vec<Spec>, StorageError> {
        let mut out = Vec::new();
        for (_, graph) in self.spec_graphs(kind)? {
            if let Some(spec) = spec_from_graph(&self.graph_triples(graph.as_ref())?, kind) {
                out.push(spec);
            }
        }
        Ok(out)
    }
}
