//! RDF ⇄ OWL exchange syntaxes through horned-owl.
//!
//! The knowledge service keeps its model as RDF; other agents often want OWL/XML or the OWL
//! functional syntax (seed Ch. 4.4: semantic interoperability). horned-owl reads the RDF mapping
//! of OWL 2 (<https://www.w3.org/TR/owl2-mapping-to-rdf/>) and writes both syntaxes.

use std::collections::HashSet;
use std::io::BufReader;

use horned_owl::curie::PrefixMapping;
use horned_owl::io::{ParserConfiguration, RDFParserConfiguration};
use horned_owl::model::{AnnotatedComponent, ArcAnnotatedComponent, ArcStr, Build};
use horned_owl::ontology::component_mapped::ArcComponentMappedOntology;
use horned_owl::ontology::set::SetOntology;
use oxrdfio::RdfFormat;

use crate::error::OwlConversionError;
use crate::vocab::PREFIXES;

/// An OWL 2 exchange syntax horned-owl writes and reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OwlSyntax {
    /// OWL/XML (<https://www.w3.org/TR/owl2-xml-serialization/>), `application/owl+xml`.
    OwlXml,
    /// The functional-style syntax (<https://www.w3.org/TR/owl2-syntax/>), `text/owl-functional`.
    Functional,
}

impl OwlSyntax {
    /// The media type of the syntax.
    pub const fn media_type(self) -> &'static str {
        match self {
            Self::OwlXml => "application/owl+xml",
            Self::Functional => "text/owl-functional",
        }
    }
}

/// The result of [`rdf_to_owl`]: the OWL document and how many RDF triples had no OWL reading.
#[derive(Debug, Clone)]
pub struct OwlDocument {
    /// The document in the requested syntax.
    pub text: String,
    /// Triples of the input that horned-owl could not map to an OWL axiom (e.g. a property used
    /// without a declaration). They are not in `text`.
    pub unparsed_triples: usize,
}

/// The prefixes the service writes OWL with (`dyknow:`, `dkros:`, `owl:`, `rdf:`, `rdfs:`, `xsd:`, …).
pub fn prefix_mapping() -> PrefixMapping {
    let mut mapping = PrefixMapping::default();
    for (prefix, namespace) in PREFIXES {
        // The prefixes are constants known to be valid.
        let _ = mapping.add_prefix(prefix, namespace);
    }
    mapping
}

fn parse_rdf(
    rdf: &[u8],
    format: RdfFormat,
) -> Result<(ArcComponentMappedOntology, usize), OwlConversionError> {
    let (ontology, unparsed) = parse_rdf_detailed(rdf, format)?;
    Ok((ontology, unparsed.len()))
}

fn parse_rdf_detailed(
    rdf: &[u8],
    format: RdfFormat,
) -> Result<(ArcComponentMappedOntology, Vec<String>), OwlConversionError> {
    let build: Build<ArcStr> = Build::new_arc();
    let mut config: RDFParserConfiguration<ArcStr, Build<ArcStr>> =
        ParserConfiguration::new(build).into();
    config.common.local_only = true;
    config.format = Some(format);
    let mut reader = BufReader::new(rdf);
    let (ontology, incomplete) =
        horned_owl::io::rdf::reader::read::<ArcStr, ArcAnnotatedComponent, _, _>(
            &mut reader,
            config,
        )
        .map_err(OwlConversionError::parse)?;
    let mut unparsed: Vec<String> = Vec::new();
    // A document holding several ontologies (the core, DyKnow-ROS, extensions) has several
    // headers, and horned-owl maps one of them, whichever it meets first: the others' version
    // IRIs and imports are header triples, not axioms left out, so they are not reported (they
    // were, one run in two, depending on the order).
    unparsed.extend(
        incomplete
            .simple
            .iter()
            .filter(|t| {
                !matches!(
                    t.triple()[1],
                    horned_owl::io::rdf::reader::Term::OWL(
                        horned_owl::vocab::OWL::VersionIRI | horned_owl::vocab::OWL::Imports
                    )
                )
            })
            .map(|t| triples_text(std::slice::from_ref(t.triple()))),
    );
    unparsed.extend(
        incomplete
            .bnode
            .iter()
            .map(|t| triples_text(t.vec_triple())),
    );
    unparsed.extend(
        incomplete
            .bnode_seq
            .iter()
            .map(|seq| format!("the list {}", terms_text(seq))),
    );
    Ok((ontology.into(), unparsed))
}

type RdfTerm = horned_owl::io::rdf::reader::Term<ArcStr>;

/// Triples horned-owl left unmapped, as N-Triples on one line.
fn triples_text(triples: &[[RdfTerm; 3]]) -> String {
    triples
        .iter()
        .map(|[s, p, o]| format!("{} {} {} .", term_text(s), term_text(p), term_text(o)))
        .collect::<Vec<_>>()
        .join(" ")
}

fn terms_text(terms: &[RdfTerm]) -> String {
    let items: Vec<String> = terms.iter().map(term_text).collect();
    format!("({})", items.join(" "))
}

/// A horned-owl RDF term in N-Triples.
fn term_text(term: &RdfTerm) -> String {
    use horned_owl::io::rdf::reader::Term;
    use horned_owl::model::Literal as L;
    match term {
        Term::OWL(v) => format!("<{}>", v.as_ref()),
        Term::RDF(v) => format!("<{}>", v.as_ref()),
        Term::RDFS(v) => format!("<{}>", v.as_ref()),
        Term::SWRL(v) => format!("<{}>", v.as_ref()),
        Term::FacetTerm(v) => format!("<{}>", v.as_ref()),
        Term::Iri(iri) => format!("<{}>", iri.as_ref()),
        // Its label is only shown by `Debug`: `BNode("b0")`.
        Term::BNode(b) => {
            let debug = format!("{b:?}");
            let label = debug
                .strip_prefix("BNode(\"")
                .and_then(|d| d.strip_suffix("\")"))
                .unwrap_or(&debug);
            format!("_:{label}")
        }
        Term::Literal(l) => match l {
            L::Simple { literal } => oxrdf::Literal::new_simple_literal(literal).to_string(),
            L::Language { literal, lang } => {
                oxrdf::Literal::new_language_tagged_literal_unchecked(literal, lang).to_string()
            }
            L::Datatype {
                literal,
                datatype_iri,
            } => oxrdf::Literal::new_typed_literal(
                literal,
                oxrdf::NamedNode::new_unchecked(datatype_iri.as_ref()),
            )
            .to_string(),
        },
    }
}

/// Converts an RDF document (the RDF mapping of OWL 2) into an OWL exchange syntax.
pub fn rdf_to_owl(
    rdf: &[u8],
    format: RdfFormat,
    syntax: OwlSyntax,
) -> Result<OwlDocument, OwlConversionError> {
    let (ontology, unparsed_triples) = parse_rdf(rdf, format)?;
    let mapping = prefix_mapping();
    let out = match syntax {
        // Full IRIs: horned-owl's OWL/XML writer puts the prefixed names a mapping gives into
        // `IRI` attributes (`IRI="dyknow:ChangeSet"`), where OWL/XML wants an IRI (prefixed
        // names go in `abbreviatedIRI`); conforming readers took them for IRIs of scheme
        // `dyknow`, and owlready2 refused the document.
        OwlSyntax::OwlXml => horned_owl::io::owx::writer::write(
            Vec::new(),
            &ontology,
            Some(&PrefixMapping::default()),
        ),
        OwlSyntax::Functional => {
            horned_owl::io::ofn::writer::write(Vec::new(), &ontology, Some(&mapping))
        }
    }
    .map_err(OwlConversionError::write)?;
    let text = String::from_utf8(out).map_err(OwlConversionError::write)?;
    Ok(OwlDocument {
        text,
        unparsed_triples,
    })
}

/// The OWL components (axioms, declarations, ontology annotations) of an RDF document.
pub fn rdf_owl_components(
    rdf: &[u8],
    format: RdfFormat,
) -> Result<HashSet<AnnotatedComponent<ArcStr>>, OwlConversionError> {
    let (ontology, _) = parse_rdf(rdf, format)?;
    let set: SetOntology<ArcStr> = ontology.into();
    Ok(set.into_iter().collect())
}

/// The OWL components of an RDF document, and a description (horned-owl's debug rendering) of
/// each group of triples horned-owl could not map to an axiom.
pub fn rdf_owl_components_detailed(
    rdf: &[u8],
    format: RdfFormat,
) -> Result<(HashSet<AnnotatedComponent<ArcStr>>, Vec<String>), OwlConversionError> {
    let (ontology, unparsed) = parse_rdf_detailed(rdf, format)?;
    let set: SetOntology<ArcStr> = ontology.into();
    Ok((set.into_iter().collect(), unparsed))
}

/// Reads an OWL document in `syntax` back into its components.
pub fn read_owl(
    text: &str,
    syntax: OwlSyntax,
) -> Result<HashSet<AnnotatedComponent<ArcStr>>, OwlConversionError> {
    let build: Build<ArcStr> = Build::new_arc();
    let config = ParserConfiguration::new(build);
    let mut reader = BufReader::new(text.as_bytes());
    let set: SetOntology<ArcStr> = match syntax {
        OwlSyntax::OwlXml => {
            horned_owl::io::owx::reader::read(&mut reader, config)
                .map_err(OwlConversionError::parse)?
                .0
        }
        OwlSyntax::Functional => {
            horned_owl::io::ofn::reader::read(&mut reader, config)
                .map_err(OwlConversionError::parse)?
                .0
        }
    };
    Ok(set.into_iter().collect())
}
