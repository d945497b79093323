//! Parsing request bodies (Turtle, N-Triples, JSON-LD) into triples.

use oxigraph::io::{RdfFormat, RdfParser};
use std::collections::HashMap;

use oxigraph::model::{BlankNode, GraphName, NamedOrBlankNode, Term, Triple};

use crate::error::{SpecParseError, SyntaxErrorDetail};

/// The RDF syntaxes accepted for specs and ontology extensions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputFormat {
    /// `text/turtle`.
    Turtle,
    /// `application/n-triples`.
    NTriples,
    /// `application/ld+json`.
    JsonLd,
}

impl InputFormat {
    /// The format for a `Content-Type` value (parameters such as `charset` are ignored).
    pub fn from_media_type(media_type: &str) -> Option<Self> {
        let essence = media_type.split(';').next()?.trim().to_ascii_lowercase();
        match essence.as_str() {
            "text/turtle" | "application/x-turtle" => Some(Self::Turtle),
            "application/n-triples" | "text/plain" => Some(Self::NTriples),
            "application/ld+json" => Some(Self::JsonLd),
            _ => None,
        }
    }

    /// The format for a file name, by extension (`.ttl`, `.nt`, `.jsonld`).
    pub fn from_path(path: &std::path::Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "ttl" | "turtle" => Some(Self::Turtle),
            "nt" => Some(Self::NTriples),
            "jsonld" | "json" => Some(Self::JsonLd),
            _ => None,
        }
    }

    pub(crate) fn rdf_format(self) -> RdfFormat {
        match self {
            Self::Turtle => RdfFormat::Turtle,
            Self::NTriples => RdfFormat::NTriples,
            Self::JsonLd => RdfFormat::JsonLd {
                profile: Default::default(),
            },
        }
    }
}

/// Parses `body` into triples, keeping the document's blank node labels (specs replace their
/// blank nodes by IRIs; vocabulary goes through [`fresh_blank_nodes`] before it is stored).
/// Quads in named graphs are refused: specs are graphs of their own.
pub fn parse_triples(body: &[u8], format: InputFormat) -> Result<Vec<Triple>, SpecParseError> {
    // A UTF-8 byte order mark (editors on Windows write one) is no syntax error: RFC 3629 lets a
    // reader drop it, and line and column positions are unchanged by it.
    let body = body.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(body);
    let parser = RdfParser::from_format(format.rdf_format()).rename_blank_nodes();
    let mut triples = Vec::new();
    for quad in parser.for_slice(body) {
        let quad = quad.map_err(|e| {
            let (line, column) = e
                .location()
                .map_or((1, 1), |l| (l.start.line + 1, l.start.column + 1));
            let mut message = e.to_string();
            // A relative IRI is resolved against the document's base, and a posted body has
            // none: the parser only says the IRI lacks a scheme.
            if message.contains("No scheme found") {
                message.push_str(
                    " (a relative IRI such as <thing>: a posted body has no base IRI; write \
                     absolute IRIs, or declare one with @base)",
                );
            }
            syntax(line, column, message)
        })?;
        if quad.graph_name != GraphName::DefaultGraph {
            return Err(syntax(1, 1, "named graphs are not accepted here".into()));
        }
        triples.push(Triple::from(quad));
    }
    Ok(triples)
}

fn syntax(line: u64, column: u64, message: String) -> SpecParseError {
    SpecParseError(SyntaxErrorDetail {
        line,
        column,
        message,
    })
}

/// Gives every blank node of `triples` a new, store-wide unique label, so that two documents
/// never share a blank node once stored.
pub(crate) fn fresh_blank_nodes(triples: &[Triple]) -> Vec<Triple> {
    let mut fresh: HashMap<&BlankNode, BlankNode> = HashMap::new();
    let mut rename = |b| fresh.entry(b).or_default().clone();
    triples
        .iter()
        .map(|t| {
            let subject = match &t.subject {
                NamedOrBlankNode::BlankNode(b) => NamedOrBlankNode::from(rename(b)),
                other => other.clone(),
            };
            let object = match &t.object {
                Term::BlankNode(b) => Term::from(rename(b)),
                other => other.clone(),
            };
            Triple::new(subject, t.predicate.clone(), object)
        })
        .collect()
}
