//! SPARQL 1.1 queries over the union of every graph (ontology, specs, extensions, and later the
//! inferred triples), with cancellation and result serialisation.

use std::io::Write;

use oxigraph::io::{RdfFormat, RdfSerializer};
use oxigraph::sparql::results::{QueryResultsFormat, QueryResultsSerializer};
use oxigraph::sparql::{CancellationToken, QueryEvaluationError, QueryResults, SparqlEvaluator};

use crate::error::{SparqlQueryError, SyntaxErrorDetail};
use crate::knowledge_base::KnowledgeBase;

/// The form of a query, which decides the result formats on offer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QueryForm {
    /// SELECT or ASK: SPARQL results formats.
    Solutions,
    /// CONSTRUCT or DESCRIBE: RDF formats.
    Graph,
}

/// A result format chosen by content negotiation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ResultFormat {
    /// A SPARQL results format (JSON, XML, CSV, TSV).
    Results(QueryResultsFormat),
    /// An RDF format.
    Rdf(RdfFormat),
}

/// The serialised answer to a query.
#[derive(Debug, Clone)]
pub struct QueryAnswer {
    /// The media type of `body`.
    pub media_type: &'static str,
    /// The serialised results.
    pub body: Vec<u8>,
}

/// A parsed query ready to run.
pub struct ParsedQuery {
    prepared: oxigraph::sparql::PreparedSparqlQuery,
    form: QueryForm,
    cancel: CancellationToken,
}

impl ParsedQuery {
    /// Parses `query`. Updates are recognised and refused; syntax errors carry line and column.
    pub fn parse(query: &str) -> Result<Self, SparqlQueryError> {
        let cancel = CancellationToken::new();
        // One parse: the form is read from the algebra, which is then handed to the evaluator.
        match spargebra::SparqlParser::new().parse_query(query) {
            Ok(algebra) => {
                let form = match algebra {
                    spargebra::Query::Construct { .. } | spargebra::Query::Describe { .. } => {
                        QueryForm::Graph
                    }
                    _ => QueryForm::Solutions,
                };
                let mut prepared = SparqlEvaluator::new()
                    .with_cancellation_token(cancel.clone())
                    .for_query(algebra);
                if prepared.dataset().is_default_dataset() {
                    prepared.dataset_mut().set_default_graph_as_union();
                }
                Ok(Self {
                    prepared,
                    form,
                    cancel,
                })
            }
            Err(query_error) => {
                // An update is refused (403); an empty one is just no query (400).
                if spargebra::SparqlParser::new()
                    .parse_update(query)
                    .is_ok_and(|u| !u.operations.is_empty())
                {
                    return Err(SparqlQueryError::UpdateRefused);
                }
                Err(SparqlQueryError::Syntax(syntax_detail(
                    &query_error.to_string(),
                )))
            }
        }
    }

    /// Whether the query returns solutions (SELECT, ASK) or a graph (CONSTRUCT, DESCRIBE).
    pub fn form(&self) -> QueryForm {
        self.form
    }

    /// The token that cancels the query's evaluation (e.g. when its time is up).
    pub fn cancellation_token(&self) -> CancellationToken {
        self.cancel.clone()
    }
}

/// Extracts `line:column` from a peg error message such as `error at 1:8: expected ...`.
fn syntax_detail(message: &str) -> SyntaxErrorDetail {
    let mut line = 1;
    let mut column = 1;
    if let Some(rest) = message.split("at ").nth(1) {
        let mut parts = rest.split(|c: char| !c.is_ascii_digit());
        if let (Some(l), Some(c)) = (parts.next(), parts.next())
            && let (Ok(l), Ok(c)) = (l.parse(), c.parse())
        {
            line = l;
            column = c;
        }
    }
    SyntaxErrorDetail {
        line,
        column,
        message: message.to_owned(),
    }
}

impl KnowledgeBase {
    /// Runs a SELECT query over the union of every graph and returns its rows, each the values
    /// of the projected variables in order (for clients inside the service, e.g. the engine).
    pub fn select(
        &self,
        query: &str,
    ) -> Result<Vec<Vec<Option<oxigraph::model::Term>>>, SparqlQueryError> {
        let parsed = ParsedQuery::parse(query)?;
        let results = parsed
            .prepared
            .on_store(self.store())
            .execute()
            .map_err(|e| SparqlQueryError::Evaluation(e.to_string()))?;
        let QueryResults::Solutions(solutions) = results else {
            return Err(SparqlQueryError::Evaluation(
                "not a SELECT query".to_owned(),
            ));
        };
        let mut rows = Vec::new();
        for solution in solutions {
            let solution = solution.map_err(|e| SparqlQueryError::Evaluation(e.to_string()))?;
            rows.push(solution.values().to_vec());
        }
        Ok(rows)
    }

    /// Runs a parsed query and serialises the whole answer into memory (so that a timeout never
    /// produces a truncated 200 response). The query's cancellation token is checked throughout
    /// evaluation; `timeout` is what a cancellation is reported as.
    pub fn run_query(
        &self,
        query: ParsedQuery,
        format: ResultFormat,
        timeout: std::time::Duration,
    ) -> Result<QueryAnswer, SparqlQueryError> {
        let cancel = query.cancel.clone();
        let map = |e: QueryEvaluationError| match e {
            QueryEvaluationError::Cancelled => SparqlQueryError::Timeout(timeout),
            e @ (QueryEvaluationError::UnsupportedService(_)
            | QueryEvaluationError::UnboundService
            | QueryEvaluationError::InvalidServiceName(_)
            | QueryEvaluationError::Service(_)) => SparqlQueryError::Unsupported(format!(
                "{e}: this endpoint answers from its own store and makes no federated SERVICE calls"
            )),
            e @ (QueryEvaluationError::UnsupportedCustomFunction(_)
            | QueryEvaluationError::UnsupportedCustomFunctionArity { .. }
            | QueryEvaluationError::NotExistingSubstitutedVariable(_)) => {
                SparqlQueryError::Unsupported(e.to_string())
            }
            other => SparqlQueryError::Evaluation(other.to_string()),
        };
        let results = query
            .prepared
            .on_store(self.store())
            .execute()
            .map_err(map)?;
        let io = |e: std::io::Error| SparqlQueryError::Evaluation(e.to_string());
        let mut body = Vec::new();
        let media_type = match (results, format) {
            (QueryResults::Boolean(value), ResultFormat::Results(f)) => {
                QueryResultsSerializer::from_format(f)
                    .serialize_boolean_to_writer(&mut body, value)
                    .map_err(io)?;
                f.media_type()
            }
            (QueryResults::Solutions(solutions), ResultFormat::Results(f)) => {
                let mut serializer = QueryResultsSerializer::from_format(f)
                    .serialize_solutions_to_writer(&mut body, solutions.variables().to_vec())
                    .map_err(io)?;
                for solution in solutions {
                    serializer.serialize(&solution.map_err(map)?).map_err(io)?;
                }
                serializer.finish().map_err(io)?;
                f.media_type()
            }
            (QueryResults::Graph(triples), ResultFormat::Rdf(f)) => {
                let mut serializer = prefixed(RdfSerializer::from_format(f)).for_writer(&mut body);
                for triple in triples {
                    serializer
                        .serialize_triple(&triple.map_err(map)?)
                        .map_err(io)?;
                }
                serializer.finish().map_err(io)?;
                f.media_type()
            }
            (QueryResults::Graph(_), ResultFormat::Results(_)) => {
                return Err(SparqlQueryError::UnsupportedFormat(
                    "CONSTRUCT and DESCRIBE answer in an RDF format".into(),
                ));
            }
            (_, ResultFormat::Rdf(_)) => {
                return Err(SparqlQueryError::UnsupportedFormat(
                    "SELECT and ASK answer in a SPARQL results format".into(),
                ));
            }
        };
        if cancel.is_cancelled() {
            return Err(SparqlQueryError::Timeout(timeout));
        }
        body.flush().map_err(io)?;
        Ok(QueryAnswer { media_type, body })
    }
}

/// Adds the DyKnow prefixes to a serializer (ignored by formats without prefixes).
pub(crate) fn prefixed(mut serializer: RdfSerializer) -> RdfSerializer {
    for (prefix, namespace) in dyknow_ontology::vocab::PREFIXES {
        serializer = match serializer.clone().with_prefix(prefix, namespace) {
            Ok(s) => s,
            Err(_) => serializer,
        };
    }
    serializer
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forms_are_recognised() {
        let form = |q: &str| ParsedQuery::parse(q).map(|p| p.form()).ok();
        assert_eq!(
            form("SELECT * WHERE { ?s ?p ?o }"),
            Some(QueryForm::Solutions)
        );
        assert_eq!(form("ask { ?s ?p ?o }"), Some(QueryForm::Solutions));
        assert_eq!(
            form("PREFIX construct: <http://e/> CONSTRUCT { ?s ?p ?o } WHERE { ?s ?p ?o }"),
            Some(QueryForm::Graph)
        );
        assert_eq!(form("DESCRIBE <http://e/>"), Some(QueryForm::Graph));
        assert_eq!(
            form("SELECT ?describe WHERE { ?describe ?p ?o }"),
            Some(QueryForm::Solutions)
        );
    }

    #[test]
    fn syntax_errors_carry_a_position() {
        let Err(SparqlQueryError::Syntax(d)) = ParsedQuery::parse("SELECT * WHERE { ?s ?p }")
        else {
            panic!("expected a syntax error")
        };
        assert_eq!(d.line, 1);
        assert!(d.column > 1, "{d:?}");
        assert!(matches!(
            ParsedQuery::parse("INSERT DATA { <http://a> <http://b> <http://c> }"),
            Err(SparqlQueryError::UpdateRefused)
        ));
    }
}
