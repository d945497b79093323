//! SPARQL 1.1 queries over the union of every graph (ontology, specs, extensions, and later the
//! inferred triples), with cancellation and result serialisation.

use std::io::Write;

use oxigraph::io::{RdfFormat, RdfSerializer};
use oxigraph::sparql::results::{QueryResultsFormat, QueryResultsSerializer};
use oxigraph::sparql::{CancellationToken, QueryEvaluationError, QueryResults};

use crate::error::{SparqlQueryError, SyntaxErrorDetail};
use crate::knowledge_base::KnowledgeBase;

mod guard;
mod strings;

thread_local! {
    /// The token of the query with a memory budget running on this thread, for
    /// [`cancel_running`]. Set before the budget starts, so that the allocator, which reads it,
    /// never initialises it.
    static RUNNING: std::cell::RefCell<Option<CancellationToken>> =
        const { std::cell::RefCell::new(None) };
}

/// The budget's hook: cancels the running query. Called from inside the allocator, so it only
/// reads the thread-local (never borrowed mutably while a budget with this hook lives) and sets
/// the token's flag: no allocation, no panic.
fn cancel_running() {
    let _ = RUNNING.try_with(|running| {
        if let Ok(token) = running.try_borrow()
            && let Some(token) = token.as_ref()
        {
            token.cancel();
        }
    });
}

/// A query's memory budget, and its token where the budget's hook finds it.
struct Metered {
    budget: dyknow_meter::Budget,
    /// The token of a query metered around this one on the thread (none today), put back.
    outer: Option<CancellationToken>,
}

impl Metered {
    fn start(limit: usize, cancel: &CancellationToken) -> Self {
        let outer = RUNNING.with(|running| running.borrow_mut().replace(cancel.clone()));
        Self {
            budget: dyknow_meter::Budget::start_with(limit, cancel_running),
            outer,
        }
    }
}

impl Drop for Metered {
    fn drop(&mut self) {
        // The outer token is back, then the budget ends (fields drop after this body); in
        // between, a hook would cancel the outer query, whose budget this one's usage counts
        // towards too.
        let outer = self.outer.take();
        let _ = RUNNING.try_with(|running| {
            if let Ok(mut token) = running.try_borrow_mut() {
                *token = outer;
            }
        });
    }
}

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
    memory: Option<usize>,
}

/// How deep a query may nest brackets (`(`, `{`, `[`, `<<`): the parser recurses once per
/// level, and a 2 KB query of 1,000 nested parentheses overflowed a worker's stack (the whole
/// service aborted).
pub const MAX_QUERY_NESTING: usize = 128;

/// How deep a query's algebra may be: the evaluator recurses once per operator, and a chain
/// (`{…} UNION {…} UNION …`, `a || b || …`, one OPTIONAL after another) is a tree as deep as it
/// is long; 1,000 UNION branches overflowed a worker's stack.
pub const MAX_QUERY_DEPTH: usize = 256;

/// How many triple patterns a query may join in all, each IRI step of a property path
/// counting one. Planning the join order takes time cubic in their number and cannot be
/// cancelled (`--query-timeout` stops evaluation, not planning): 300 took 0.8 s, 1,000 (an
/// 8 KB query) 92 s, and 7,000 kept a core busy for more than 11 minutes and held up the
/// service's shutdown. 256 plan within about half a second.
pub const MAX_QUERY_PATTERNS: usize = 256;

/// How many operators that chain (`UNION`, `MINUS`, `OPTIONAL`, `||`, `&&`, `|`, `/`, `+`, `-`,
/// `*`, `^`, `!`) a query may hold in all: the parser recurses along a chain as it does into
/// brackets (1,000 UNION branches overflowed a 2 MiB stack in the parser itself), so their
/// number bounds its recursion too; the service's threads have the stack for this many
/// (`dyknow serve`: 64 MiB). Counted lexically, so a hyphen in a prefixed name counts as well:
/// the bound is far above what a query of the configuration holds.
pub const MAX_QUERY_OPERATORS: usize = 8_000;

/// What is wrong with `query`'s shape, if anything, before it is parsed: brackets nested
/// deeper than `limit`, or more than [`MAX_QUERY_OPERATORS`] chaining operators. Strings, IRIs
/// and comments are skipped. One pass over the text (every query pays it).
fn shape_error(query: &str, limit: usize) -> Option<String> {
    let (nesting, operators) = shape(query, limit);
    if let Some((line, column)) = nesting {
        return Some(format!(
            "the query nests brackets deeper than {limit} levels (line {line}, column {column})"
        ));
    }
    (operators > MAX_QUERY_OPERATORS).then(|| {
        format!(
            "the query chains {operators} operators (UNION, OPTIONAL, ||, +, …); at most \
             {MAX_QUERY_OPERATORS} are taken"
        )
    })
}

/// The first place `query` nests brackets (`(`, `{`, `[`, `<<`) deeper than `limit`, as
/// (line, column) (a lexical bound on the parser's recursion), and the number of chaining
/// operators outside strings, IRIs and comments.
fn shape(query: &str, limit: usize) -> (Option<(usize, usize)>, usize) {
    let (mut depth, mut previous, mut found) = (0usize, ' ', None);
    let (mut operators, mut word) = (0usize, String::new());
    // `||` and `&&` are one operator each (they counted twice, and a refusal said so).
    let mut paired = false;
    scan(query, |c, at| {
        let before = previous;
        match (previous, c) {
            ('<', '<') => {
                depth += 1;
                previous = ' ';
            }
            ('>', '>') => {
                depth = depth.saturating_sub(1);
                previous = ' ';
            }
            (_, '(' | '{' | '[') => {
                depth += 1;
                previous = c;
            }
            (_, ')' | '}' | ']') => {
                depth = depth.saturating_sub(1);
                previous = c;
            }
            _ => previous = c,
        }
        if depth > limit && found.is_none() {
            found = Some(at);
        }
        if c.is_alphanumeric() || c == '_' || c == ':' {
            word.push(c);
            return;
        }
        if ["UNION", "MINUS", "OPTIONAL"]
            .iter()
            .any(|k| word.eq_ignore_ascii_case(k))
        {
            operators += 1;
        }
        word.clear();
        if "|&/+-*^!".contains(c) {
            if matches!(c, '|' | '&') && before == c && !paired {
                paired = true;
            } else {
                operators += 1;
                paired = false;
            }
        }
    });
    (found, operators)
}

/// Calls `f` with every character of `query` outside strings, IRIs and comments (a space for
/// each of those), and its (line, column).
fn scan(query: &str, mut f: impl FnMut(char, (usize, usize))) {
    let chars: Vec<char> = query.chars().collect();
    let (mut line, mut line_start) = (1usize, 0usize);
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        match c {
            '#' => {
                while i + 1 < chars.len() && chars[i + 1] != '\n' {
                    i += 1;
                }
                f(' ', (line, i - line_start + 1));
            }
            '"' | '\'' => {
                let long = chars.get(i + 1) == Some(&c) && chars.get(i + 2) == Some(&c);
                i += if long { 3 } else { 1 };
                while i < chars.len() {
                    if chars[i] == '\\' {
                        i += 2;
                        continue;
                    }
                    if chars[i] == '\n' {
                        line += 1;
                        line_start = i + 1;
                    }
                    if chars[i] == c
                        && (!long || (chars.get(i + 1) == Some(&c) && chars.get(i + 2) == Some(&c)))
                    {
                        i += if long { 2 } else { 0 };
                        break;
                    }
                    i += 1;
                }
                f(' ', (line, i.saturating_sub(line_start) + 1));
            }
            '<' if chars.get(i + 1) != Some(&'<') => {
                // An IRI runs to `>` through no forbidden character; otherwise it is `<`.
                let end = chars[i + 1..]
                    .iter()
                    .position(|&d| d == '>' || d <= ' ' || "<\"{}|^`\\".contains(d));
                match end.filter(|&n| chars[i + 1 + n] == '>') {
                    Some(n) => {
                        i += n + 1;
                        f(' ', (line, i - line_start + 1));
                    }
                    None => f(c, (line, i - line_start + 1)),
                }
            }
            '\n' => {
                f(c, (line, i - line_start + 1));
                line += 1;
                line_start = i + 1;
            }
            _ => f(c, (line, i - line_start + 1)),
        }
        i += 1;
    }
}

/// Whether `query`'s algebra is deeper than `limit` (walked with a stack of its own, so the
/// walk itself never recurses).
/// Whether `query`'s algebra is deeper than `limit` operators, and how many triple patterns it
/// joins (each IRI step of a property path counts one: `?s <p>/<p> ?o` is two).
fn algebra_shape(query: &spargebra::Query, limit: usize) -> (bool, usize) {
    let mut patterns = 0usize;
    let deeper = deeper_than(query, limit, &mut patterns);
    (deeper, patterns)
}

fn deeper_than(query: &spargebra::Query, limit: usize, patterns: &mut usize) -> bool {
    use spargebra::algebra::PropertyPathExpression as Path;
    use spargebra::algebra::{AggregateExpression, Expression, GraphPattern, OrderExpression};
    enum Node<'a> {
        Pattern(&'a GraphPattern),
        Expr(&'a Expression),
        Path(&'a Path),
    }
    let pattern = match query {
        spargebra::Query::Select { pattern, .. }
        | spargebra::Query::Construct { pattern, .. }
        | spargebra::Query::Describe { pattern, .. }
        | spargebra::Query::Ask { pattern, .. } => pattern,
    };
    let mut stack = vec![(Node::Pattern(pattern), 1usize)];
    while let Some((node, depth)) = stack.pop() {
        if depth > limit {
            return true;
        }
        let d = depth + 1;
        match node {
            Node::Pattern(p) => match p {
                GraphPattern::Bgp { patterns: bgp } => *patterns += bgp.len(),
                GraphPattern::Values { .. } => {}
                GraphPattern::Path { path, .. } => stack.push((Node::Path(path), d)),
                GraphPattern::Join { left, right }
                | GraphPattern::Lateral { left, right }
                | GraphPattern::Union { left, right }
                | GraphPattern::Minus { left, right } => {
                    stack.push((Node::Pattern(left), d));
                    stack.push((Node::Pattern(right), d));
                }
                GraphPattern::LeftJoin {
                    left,
                    right,
                    expression,
                } => {
                    stack.push((Node::Pattern(left), d));
                    stack.push((Node::Pattern(right), d));
                    if let Some(e) = expression {
                        stack.push((Node::Expr(e), d));
                    }
                }
                GraphPattern::Filter { expr, inner } => {
                    stack.push((Node::Expr(expr), d));
                    stack.push((Node::Pattern(inner), d));
                }
                GraphPattern::Extend {
                    inner, expression, ..
                } => {
                    stack.push((Node::Expr(expression), d));
                    stack.push((Node::Pattern(inner), d));
                }
                GraphPattern::OrderBy { inner, expression } => {
                    stack.push((Node::Pattern(inner), d));
                    for o in expression {
                        let (OrderExpression::Asc(e) | OrderExpression::Desc(e)) = o;
                        stack.push((Node::Expr(e), d));
                    }
                }
                GraphPattern::Group {
                    inner, aggregates, ..
                } => {
                    stack.push((Node::Pattern(inner), d));
                    for (_, a) in aggregates {
                        if let AggregateExpression::FunctionCall { expr, .. } = a {
                            stack.push((Node::Expr(expr), d));
                        }
                    }
                }
                GraphPattern::Graph { inner, .. }
                | GraphPattern::Project { inner, .. }
                | GraphPattern::Distinct { inner }
                | GraphPattern::Reduced { inner }
                | GraphPattern::Slice { inner, .. }
                | GraphPattern::Service { inner, .. } => stack.push((Node::Pattern(inner), d)),
            },
            Node::Expr(Expression::Exists(p)) => stack.push((Node::Pattern(p), d)),
            Node::Expr(e) => {
                stack.extend(sub_expressions(e).into_iter().map(|e| (Node::Expr(e), d)))
            }
            Node::Path(p) => match p {
                Path::NamedNode(_) | Path::NegatedPropertySet(_) => *patterns += 1,
                Path::Reverse(a)
                | Path::ZeroOrMore(a)
                | Path::OneOrMore(a)
                | Path::ZeroOrOne(a) => {
                    stack.push((Node::Path(a), d));
                }
                Path::Sequence(a, b) | Path::Alternative(a, b) => {
                    stack.push((Node::Path(a), d));
                    stack.push((Node::Path(b), d));
                }
            },
        }
    }
    false
}

/// The operands of an expression, by shared or by mutable reference (`mut`): one match for
/// both [`sub_expressions`] and [`sub_expressions_mut`].
macro_rules! operands {
    ($expression:expr $(, $mutable:tt)?) => {{
        use spargebra::algebra::Expression as E;
        match $expression {
            E::NamedNode(_) | E::Literal(_) | E::Variable(_) | E::Bound(_) | E::Exists(_) => {
                Vec::new()
            }
            E::Or(a, b)
            | E::And(a, b)
            | E::Equal(a, b)
            | E::SameTerm(a, b)
            | E::Greater(a, b)
            | E::GreaterOrEqual(a, b)
            | E::Less(a, b)
            | E::LessOrEqual(a, b)
            | E::Add(a, b)
            | E::Subtract(a, b)
            | E::Multiply(a, b)
            | E::Divide(a, b) => vec![a, b],
            E::In(a, list) => std::iter::once(&$($mutable)? **a).chain(list).collect(),
            E::UnaryPlus(a) | E::UnaryMinus(a) | E::Not(a) => vec![a],
            E::If(a, b, c) => vec![a, b, c],
            E::Coalesce(list) | E::FunctionCall(_, list) => list.into_iter().collect(),
        }
    }};
}

/// The operands of `expression` (not the pattern of an `EXISTS`).
pub(crate) fn sub_expressions(
    expression: &spargebra::algebra::Expression,
) -> Vec<&spargebra::algebra::Expression> {
    operands!(expression)
}

/// The operands of `expression`, to change (not the pattern of an `EXISTS`).
pub(crate) fn sub_expressions_mut(
    expression: &mut spargebra::algebra::Expression,
) -> Vec<&mut spargebra::algebra::Expression> {
    operands!(expression, mut)
}

impl ParsedQuery {
    /// Parses `query`. Updates are recognised and refused; syntax errors carry line and column;
    /// a query nested deeper than [`MAX_QUERY_NESTING`] brackets or [`MAX_QUERY_DEPTH`]
    /// operators is refused ([`SparqlQueryError::TooDeep`]).
    pub fn parse(query: &str) -> Result<Self, SparqlQueryError> {
        if let Some(message) = shape_error(query, MAX_QUERY_NESTING) {
            return Err(SparqlQueryError::TooDeep(message));
        }
        let cancel = CancellationToken::new();
        // One parse: the form is read from the algebra, which is then handed to the evaluator.
        let parsed = spargebra::SparqlParser::new().parse_query(query);
        let shape = parsed
            .as_ref()
            .map(|algebra| algebra_shape(algebra, MAX_QUERY_DEPTH));
        match parsed {
            Ok(_) if matches!(shape, Ok((true, _))) => Err(SparqlQueryError::TooDeep(format!(
                "the query's algebra is deeper than {MAX_QUERY_DEPTH} operators (a chain of \
                 UNION, OPTIONAL, ||, && or + of that length, or nesting)"
            ))),
            Ok(_) if shape.as_ref().is_ok_and(|(_, n)| *n > MAX_QUERY_PATTERNS) => {
                let n = shape.as_ref().map_or(0, |(_, n)| *n);
                Err(SparqlQueryError::TooDeep(format!(
                    "the query joins {n} triple patterns (property path steps included); at most \
                     {MAX_QUERY_PATTERNS} are taken"
                )))
            }
            Ok(algebra) => {
                let form = match algebra {
                    spargebra::Query::Construct { .. } | spargebra::Query::Describe { .. } => {
                        QueryForm::Graph
                    }
                    _ => QueryForm::Solutions,
                };
                let mut prepared = guard::prepare(algebra, &cancel);
                if prepared.dataset().is_default_dataset() {
                    prepared.dataset_mut().set_default_graph_as_union();
                }
                Ok(Self {
                    prepared,
                    form,
                    cancel,
                    memory: None,
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

    /// Bounds the memory the query's evaluation may hold (its solutions in joins, sorts and
    /// groups, and the serialised answer) to `bytes`: past it, [`KnowledgeBase::run_query`]
    /// stops the evaluation and answers [`SparqlQueryError::MemoryLimit`]. Memory is counted by
    /// `dyknow_meter::Counting`, which the program must install as its global allocator (as
    /// `dyknow serve` does); without it the bound is reached only by a `CONCAT`, `REPLACE` or
    /// `ENCODE_FOR_URI` that would build more than all of it (`strings`, which ask for their
    /// room first and so stop before they build past it). The allocation that passes
    /// it cancels the query's token, and the query stops where it checks the token: at every
    /// quad read, once per solution of a join or path (`guard`), once per row written. So it
    /// can be passed by one growth of a buffer (a doubling) and by what is made between two
    /// checks (one probe row's matches in a join, the end of a sort or aggregate over
    /// solutions already made).
    #[must_use]
    pub fn with_memory_limit(mut self, bytes: usize) -> Self {
        self.memory = Some(bytes);
        self
    }

    /// The dataset the SPARQL 1.1 Protocol's `default-graph-uri` and `named-graph-uri` give:
    /// when either is given, the default graph is the merge of the `default` graphs (empty
    /// if none) and the named graphs are the `named` ones (none if none), whatever the query's
    /// `FROM` and `FROM NAMED` say (the protocol's parameters win). Neither given: the
    /// query's own dataset, else the union of every graph.
    #[must_use]
    pub fn with_protocol_dataset(
        mut self,
        default: Vec<oxigraph::model::NamedNode>,
        named: Vec<oxigraph::model::NamedNode>,
    ) -> Self {
        if default.is_empty() && named.is_empty() {
            return self;
        }
        let dataset = self.prepared.dataset_mut();
        dataset.set_default_graph(default.into_iter().map(Into::into).collect());
        dataset.set_available_named_graphs(named.into_iter().map(Into::into).collect());
        self
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
        // The memory budget counts what this thread holds from here on (the evaluation is an
        // iterator pulled here); the allocation that passes it cancels the token, which the
        // evaluation notices where it notices a timeout: the query's error is then the limit.
        let budget = query.memory.map(|limit| Metered::start(limit, &cancel));
        let answered = self.evaluate(query.prepared, format, timeout, &cancel, map);
        match budget {
            Some(budget) if budget.budget.tripped() => {
                Err(SparqlQueryError::MemoryLimit(budget.budget.limit()))
            }
            _ => answered,
        }
    }

    /// [`KnowledgeBase::run_query`]'s evaluation, serialisation included (solutions are
    /// computed as they are written), inside `guard::evaluate`, which turns an evaluation the
    /// guard unwinds into a timeout. The token is checked once per row written too: the
    /// solutions of a sort or a group, made before it was cancelled, are not all written.
    fn evaluate(
        &self,
        prepared: oxigraph::sparql::PreparedSparqlQuery,
        format: ResultFormat,
        timeout: std::time::Duration,
        cancel: &CancellationToken,
        map: impl Fn(QueryEvaluationError) -> SparqlQueryError + Copy,
    ) -> Result<QueryAnswer, SparqlQueryError> {
        let alive = || {
            if cancel.is_cancelled() {
                Err(SparqlQueryError::Timeout(timeout))
            } else {
                Ok(())
            }
        };
        let (media_type, mut body) = guard::evaluate(timeout, || {
            let results = prepared.on_store(self.store()).execute().map_err(map)?;
            serialize(results, format, map, alive)
        })?;
        alive()?;
        body.flush()
            .map_err(|e| SparqlQueryError::Evaluation(e.to_string()))?;
        Ok(QueryAnswer { media_type, body })
    }
}

/// Writes `results` in `format`; `map` reports evaluation errors met on the way, and `alive`,
/// checked before each row, stops the writing (a cancellation).
fn serialize(
    results: QueryResults<'_>,
    format: ResultFormat,
    map: impl Fn(QueryEvaluationError) -> SparqlQueryError + Copy,
    alive: impl Fn() -> Result<(), SparqlQueryError>,
) -> Result<(&'static str, Vec<u8>), SparqlQueryError> {
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
                alive()?;
                serializer.serialize(&solution.map_err(map)?).map_err(io)?;
            }
            serializer.finish().map_err(io)?;
            f.media_type()
        }
        (QueryResults::Graph(triples), ResultFormat::Rdf(f)) => {
            let mut serializer = prefixed(RdfSerializer::from_format(f)).for_writer(&mut body);
            for triple in triples {
                alive()?;
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
    Ok((media_type, body))
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

    fn too_deep(q: &str) -> bool {
        matches!(ParsedQuery::parse(q), Err(SparqlQueryError::TooDeep(_)))
    }

    /// A long chain of joins is refused before its join order is planned (planning is cubic
    /// in the patterns and cannot be cancelled); up to the bound it is taken, written as
    /// patterns or as a property path.
    #[test]
    fn queries_joining_too_many_patterns_are_refused_before_they_are_planned() {
        // On a stack as large as the service's threads have (`dyknow serve`): the parser
        // recurses along a path.
        std::thread::Builder::new()
            .stack_size(64 << 20)
            .spawn(|| {
                let path = |n: usize| {
                    format!(
                        "SELECT * WHERE {{ ?s {} ?o }}",
                        vec!["<urn:p>"; n].join("/")
                    )
                };
                let chain = |n: usize| {
                    let patterns: Vec<String> = (0..n)
                        .map(|i| format!("?v{i} <urn:p> ?v{}", i + 1))
                        .collect();
                    format!("SELECT * WHERE {{ {} }}", patterns.join(" . "))
                };
                assert!(ParsedQuery::parse(&path(MAX_QUERY_PATTERNS)).is_ok());
                assert!(ParsedQuery::parse(&chain(MAX_QUERY_PATTERNS)).is_ok());
                for q in [
                    path(MAX_QUERY_PATTERNS + 1),
                    chain(MAX_QUERY_PATTERNS + 1),
                    path(7_000),
                ] {
                    match ParsedQuery::parse(&q) {
                        Err(SparqlQueryError::TooDeep(m)) => {
                            assert!(m.contains("triple patterns"), "{m}")
                        }
                        other => panic!("{}", other.is_ok()),
                    }
                }
                // Spread over UNION branches, or as a path alternative, they count all the same.
                let union = format!(
                    "SELECT * WHERE {{ {{ {} }} UNION {{ ?a <urn:p>|<urn:q> ?b }} }}",
                    (0..MAX_QUERY_PATTERNS - 1)
                        .map(|i| format!("?v{i} <urn:p> ?v{}", i + 1))
                        .collect::<Vec<_>>()
                        .join(" . ")
                );
                assert!(too_deep(&union));
            })
            .unwrap()
            .join()
            .unwrap();
    }

    #[test]
    fn queries_nested_deeper_than_the_limits_are_refused_before_they_recurse() {
        // On a stack as large as the service's threads have (`dyknow serve`).
        std::thread::Builder::new()
            .stack_size(64 << 20)
            .spawn(deep_queries)
            .unwrap()
            .join()
            .unwrap();
    }

    #[test]
    fn the_shape_check_takes_any_text() {
        // Random texts over the characters the scanner treats specially (quotes, escapes,
        // IRIs, comments, brackets, newlines): it never panics, and counts no more brackets
        // or operators than there are characters.
        let alphabet: Vec<char> = "()[]{}<>\"'\\#\n |&/+-*^!aU:?.é".chars().collect();
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..2_000 {
            let mut next = || {
                state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
                let mut z = state;
                z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
                z ^ (z >> 31)
            };
            let len = (next() % 64) as usize;
            let text: String = (0..len)
                .map(|_| alphabet[(next() % alphabet.len() as u64) as usize])
                .collect();
            let (nesting, operators) = shape(&text, 2);
            assert!(operators <= text.chars().count(), "{text:?}");
            if let Some((line, column)) = nesting {
                assert!(line >= 1 && column >= 1, "{text:?}");
            }
            let _ = shape_error(&text, 2);
        }
        // `||` and `&&` are one operator; `|` (a path) is one too.
        let chained = |op: &str| shape(&format!("ASK {{ FILTER(?a{op}?b{op}?c) }}"), 128).1;
        assert_eq!((chained("||"), chained("&&"), chained("|")), (2, 2, 2));
    }

    fn deep_queries() {
        let parens = |n: usize| {
            format!(
                "SELECT * WHERE {{ FILTER({}1{}) }}",
                "(".repeat(n),
                ")".repeat(n)
            )
        };
        assert!(ParsedQuery::parse(&parens(100)).is_ok());
        assert!(too_deep(&parens(1_000)));
        assert!(too_deep(&parens(100_000)));
        match ParsedQuery::parse(&format!("SELECT * WHERE {{\n  {}", "[".repeat(200))) {
            Err(SparqlQueryError::TooDeep(m)) => {
                assert!(m.contains("line 2, column"), "{m}");
            }
            other => panic!("{:?}", other.err()),
        }
        // Brackets in strings, IRIs and comments are not nesting.
        let quoted = format!(
            "SELECT * WHERE {{ ?s ?p \"{0}\" . ?s <urn:x:{0}> '''{0}''' # {0}\n }}",
            "(".repeat(500)
        );
        assert!(ParsedQuery::parse(&quoted).is_ok(), "{quoted}");
        assert!(ParsedQuery::parse("SELECT * WHERE { ?s ?p ?o FILTER(?o < 3 && ?o > 1) }").is_ok());
        // Chains: a tree as deep as the chain is long.
        let unions = |n: usize| {
            format!(
                "SELECT * WHERE {{ {} }}",
                vec!["{ ?s <urn:p> ?o }"; n].join(" UNION ")
            )
        };
        assert!(ParsedQuery::parse(&unions(200)).is_ok());
        assert!(too_deep(&unions(1_000)));
        assert!(too_deep(&unions(20_000)));
        let ors = |n: usize| format!("ASK {{ FILTER({}) }}", vec!["?x"; n].join(" || "));
        assert!(ParsedQuery::parse(&ors(200)).is_ok());
        assert!(too_deep(&ors(5_000)));
        let optionals = |n: usize| {
            format!(
                "SELECT * WHERE {{ ?s ?p ?o {} }}",
                "OPTIONAL { ?s <urn:q> ?v } ".repeat(n)
            )
        };
        assert!(ParsedQuery::parse(&optionals(100)).is_ok());
        assert!(too_deep(&optionals(1_000)));
        let path = |n: usize| format!("ASK {{ ?s {} ?o }}", vec!["<urn:p>"; n].join("|"));
        assert!(ParsedQuery::parse(&path(100)).is_ok());
        assert!(too_deep(&path(1_000)));
        // The longest chain the lexical bound lets through parses on this stack, and is then
        // refused for its depth.
        assert!(too_deep(&unions(MAX_QUERY_OPERATORS)));
        assert!(too_deep(&unions(MAX_QUERY_OPERATORS + 2)));
        // Hyphens of prefixed names and IRIs with operators in them count only outside IRIs.
        let flat = format!(
            "PREFIX dyknow-ros: <http://e/a/b-c+d*e> SELECT * WHERE {{ {} }}",
            "?s dyknow-ros:has-port ?o . ".repeat(200)
        );
        assert!(ParsedQuery::parse(&flat).is_ok());
    }

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
