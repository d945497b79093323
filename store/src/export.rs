//! GetModel (seed Ch. 5.3): the ontology and the environment, as RDF or as OWL for other agents.

use std::collections::{HashMap, HashSet};

use dyknow_ontology::vocab::{owl, rdf};
use dyknow_ontology::{OwlSyntax, rdf_to_owl};
use oxigraph::io::{RdfFormat, RdfSerializer};
use oxigraph::model::{BlankNode, GraphName, NamedNode, NamedOrBlankNode, Term, Triple};
use oxigraph::store::StorageError;

use crate::error::ExportError;
use crate::knowledge_base::KnowledgeBase;
use crate::sparql::prefixed;

/// The name of the graph that will hold materialised inferences (the reasoner issue).
pub const INFERRED_GRAPH: &str = "urn:dyknow:graph:inferred";
/// The IRI of the single ontology an OWL export declares.
pub const MODEL_ONTOLOGY_IRI: &str = "urn:dyknow:model";

/// The serialisations of GetModel the knowledge base writes (the DyKnow JSON is the server's).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ModelFormat {
    /// Turtle.
    Turtle,
    /// RDF/XML, the OWL exchange format.
    RdfXml,
    /// OWL/XML, through horned-owl.
    OwlXml,
    /// OWL functional syntax, through horned-owl.
    OwlFunctional,
    /// N-Triples.
    NTriples,
    /// JSON-LD.
    JsonLd,
}

impl ModelFormat {
    /// The media type.
    pub fn media_type(self) -> &'static str {
        match self {
            Self::Turtle => "text/turtle",
            Self::RdfXml => "application/rdf+xml",
            Self::OwlXml => OwlSyntax::OwlXml.media_type(),
            Self::OwlFunctional => OwlSyntax::Functional.media_type(),
            Self::NTriples => "application/n-triples",
            Self::JsonLd => "application/ld+json",
        }
    }

    /// The format for a `?format=` name (`turtle`, `rdfxml`, `owx`, `ofn`, `ntriples`, `jsonld`).
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "turtle" | "ttl" => Self::Turtle,
            "rdfxml" | "rdf" | "owl" => Self::RdfXml,
            "owx" => Self::OwlXml,
            "ofn" => Self::OwlFunctional,
            "ntriples" | "nt" => Self::NTriples,
            "jsonld" => Self::JsonLd,
            _ => return None,
        })
    }

    /// All formats, in the order the server offers them.
    pub const ALL: [Self; 6] = [
        Self::Turtle,
        Self::RdfXml,
        Self::OwlXml,
        Self::OwlFunctional,
        Self::NTriples,
        Self::JsonLd,
    ];

    fn rdf_format(self) -> Option<RdfFormat> {
        Some(match self {
            Self::Turtle => RdfFormat::Turtle,
            Self::RdfXml => RdfFormat::RdfXml,
            Self::NTriples => RdfFormat::NTriples,
            Self::JsonLd => RdfFormat::JsonLd {
                profile: Default::default(),
            },
            Self::OwlXml | Self::OwlFunctional => return None,
        })
    }
}

/// A serialised model.
#[derive(Debug, Clone)]
pub struct ExportedModel {
    /// The document.
    pub body: Vec<u8>,
    /// For OWL syntaxes: triples horned-owl found no OWL reading for (left out of `body`).
    pub unparsed_triples: usize,
}

impl KnowledgeBase {
    /// The model as a set of triples: the union of every graph, without the inferred graph
    /// unless `inferred`. Sorted, so exports are stable.
    pub fn model_triples(&self, inferred: bool) -> Result<Vec<Triple>, StorageError> {
        let mut keyed = Vec::new();
        for quad in self.store().iter() {
            let quad = quad?;
            if !inferred
                && let GraphName::NamedNode(g) = &quad.graph_name
                && g.as_str() == INFERRED_GRAPH
            {
                continue;
            }
            let triple = Triple::from(quad);
            keyed.push((triple.to_string(), triple));
        }
        // Sorted by their N-Triples form (subject first), duplicates across graphs removed.
        keyed.sort_unstable_by(|a, b| a.0.cmp(&b.0));
        keyed.dedup_by(|a, b| a.0 == b.0);
        Ok(relabel_blank_nodes(keyed.into_iter().map(|(_, t)| t)))
    }

    /// GetModel: serialises the model in `format`.
    pub fn export(
        &self,
        format: ModelFormat,
        inferred: bool,
    ) -> Result<ExportedModel, ExportError> {
        let triples = self.model_triples(inferred)?;
        if let Some(rdf_format) = format.rdf_format() {
            return Ok(ExportedModel {
                body: serialize(&triples, rdf_format)?,
                unparsed_triples: 0,
            });
        }
        let syntax = match format {
            ModelFormat::OwlXml => OwlSyntax::OwlXml,
            _ => OwlSyntax::Functional,
        };
        let owl_triples = as_one_ontology(triples);
        let nt = serialize(&owl_triples, RdfFormat::NTriples)?;
        let doc = rdf_to_owl(&nt, RdfFormat::NTriples, syntax)?;
        Ok(ExportedModel {
            body: doc.text.into_bytes(),
            unparsed_triples: doc.unparsed_triples,
        })
    }
}

/// Serialises triples with the DyKnow prefixes.
pub fn serialize(triples: &[Triple], format: RdfFormat) -> Result<Vec<u8>, std::io::Error> {
    let mut serializer = prefixed(RdfSerializer::from_format(format)).for_writer(Vec::new());
    for t in triples {
        serializer.serialize_triple(t)?;
    }
    serializer.finish()
}

/// Replaces the headers of the built-in ontologies and extensions by one ontology
/// (`urn:dyknow:model`) holding every axiom and fact, so OWL tools see one document.
fn as_one_ontology(triples: Vec<Triple>) -> Vec<Triple> {
    let headers: HashSet<NamedOrBlankNode> = triples
        .iter()
        .filter(|t| t.predicate == rdf::TYPE && t.object == Term::from(owl::ONTOLOGY))
        .map(|t| t.subject.clone())
        .collect();
    let model = NamedNode::new_unchecked(MODEL_ONTOLOGY_IRI);
    let mut out = vec![Triple::new(model, rdf::TYPE, owl::ONTOLOGY)];
    out.extend(
        triples
            .into_iter()
            .filter(|t| !headers.contains(&t.subject)),
    );
    out
}

/// Renames blank nodes `b0`, `b1`, ... in order of appearance: stable, readable output, and
/// labels that every Turtle parser accepts (store-generated labels may start with a digit).
fn relabel_blank_nodes(triples: impl Iterator<Item = Triple>) -> Vec<Triple> {
    let mut names: HashMap<BlankNode, BlankNode> = HashMap::new();
    let mut rename = |b: &BlankNode| {
        let next = names.len();
        names
            .entry(b.clone())
            .or_insert_with(|| BlankNode::new_unchecked(format!("b{next}")))
            .clone()
    };
    triples
        .map(|t| {
            let subject = match t.subject {
                NamedOrBlankNode::BlankNode(b) => NamedOrBlankNode::from(rename(&b)),
                other => other,
            };
            let object = match t.object {
                Term::BlankNode(b) => Term::from(rename(&b)),
                other => other,
            };
            Triple::new(subject, t.predicate, object)
        })
        .collect()
}
