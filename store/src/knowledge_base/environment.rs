//! The running environment: its parts (computation units, change-set records, learned
//! statistics) written as graphs, and the channel questions the service asks about the model
//! (their SPARQL sits with the others in [`crate::model`]).

use std::collections::BTreeMap;

use oxigraph::model::{Literal, NamedNode, Term, Triple};
use oxigraph::store::StorageError;

use super::KnowledgeBase;
use crate::error::{IngestError, SparqlQueryError};
use crate::graphs::EnvironmentPart;
use crate::model::queries;
use crate::spec::{Spec, SpecKind};

impl KnowledgeBase {
    /// Sets parts of the running environment (computation units with their subscriptions and
    /// publications, change-set records, statistics; the life-cycle writes them): each
    /// `(part, triples)` replaces the graph of that part, an empty list removes it. One atomic
    /// write, reasoned incrementally like a spec; a change that violates the ontology is
    /// refused (422) and nothing is written.
    pub fn set_environment(
        &self,
        parts: &[(EnvironmentPart, Vec<Triple>)],
    ) -> Result<(), IngestError> {
        let graphs: Vec<(NamedNode, &[Triple])> = parts
            .iter()
            .map(|(part, triples)| (part.graph(), triples.as_slice()))
            .collect();
        let mut reasoner = self.lock();
        let mut removes = Vec::new();
        for (g, triples) in &graphs {
            if triples.is_empty() && self.store.contains_named_graph(g)? {
                removes.push(g);
            }
        }
        let writes: Vec<(&NamedNode, &[Triple])> = graphs
            .iter()
            .filter(|(_, t)| !t.is_empty())
            .map(|(g, t)| (g, *t))
            .collect();
        self.commit(&mut reasoner, &writes, &removes)?;
        Ok(())
    }

    /// Whether [`KnowledgeBase::set_environment`] of `parts` would be refused for violating
    /// the ontology, as it is now, writing nothing: the life-cycle asks before an executor
    /// carries a change set out, so that one the model cannot take never runs. (A write made
    /// in between can still make the write itself fail; it is checked again then.)
    pub fn check_environment(
        &self,
        parts: &[(EnvironmentPart, Vec<Triple>)],
    ) -> Result<(), IngestError> {
        let changes: Vec<(String, Vec<Triple>)> = parts
            .iter()
            .map(|(part, triples)| (part.graph().as_str().to_owned(), triples.clone()))
            .collect();
        let mut reasoner = self.lock();
        let (update, previous) = reasoner.set_graphs(&changes);
        reasoner.set_graphs(&previous);
        if update.violations.is_empty() {
            Ok(())
        } else {
            Err(super::write::inconsistency(&update.violations))
        }
    }

    /// The channels named in the model, sorted, with the targets that name them.
    pub fn channels(&self) -> Result<Vec<(String, Vec<String>)>, StorageError> {
        let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
        for spec in self.specs(SpecKind::Target)? {
            if let Spec::Target(t) = spec {
                out.entry(t.channel).or_default().push(t.label);
            }
        }
        Ok(out.into_iter().collect())
    }

    /// The name of the computation unit that publishes on the channel named `channel`, if one
    /// does (the first by name if, invalidly, several do).
    pub fn channel_producer(&self, channel: &str) -> Result<Option<String>, SparqlQueryError> {
        let rows = self.select(&queries::channel_producer(&Literal::new_simple_literal(
            channel,
        )))?;
        Ok(rows
            .into_iter()
            .find_map(|row| match row.into_iter().next() {
                Some(Some(Term::Literal(name))) => Some(name.value().to_owned()),
                _ => None,
            }))
    }
}
