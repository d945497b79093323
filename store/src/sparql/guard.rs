//! Cancellation where oxigraph does not look for it.
//!
//! Oxigraph's evaluator checks a query's [`CancellationToken`] where it reads quads and
//! internalises terms. A query whose work is in combining what it has read (a cartesian
//! product, a join whose filter rejects nearly everything, the solutions an `ORDER BY` sorts)
//! reads little and runs on: with a 1 s timeout a 4-way cartesian `COUNT(*)` over a few hundred
//! triples ran for 15 s, holding a store turn and a core all along.
//!
//! So every query with a join or a path is rewritten before it runs: below its solution
//! modifiers, and inside every sub-`SELECT` and `GROUP BY`, its pattern is wrapped in
//! `FILTER(IF(<urn:dyknow:sparql:alive>(), true, ?dyknow-guard-unbound))`; a pattern that reads
//! a quad per solution (one triple pattern) is left as it is, oxigraph's own check suffices.
//! `alive()` is a custom function that returns a true literal while the token lives and, once
//! it is cancelled, unwinds the evaluation with the [`Cancelled`] payload, which [`evaluate`]
//! turns into [`SparqlQueryError::Timeout`]. The filter keeps every solution (`IF` never
//! evaluates its `else` branch when the condition is true), so the answer is the same; the
//! `else` branch is there for the optimiser: a filter that names a variable bound nowhere in
//! the pattern is pushed into no part of it, so it stays above the top join and runs once per
//! solution the pattern produces, not once per solution of one of its parts. A user's filter
//! over a join becomes `IF(alive(), c, c)`: the optimiser merges it with the guard into one
//! conjunction in an order of its choosing, and a filter that rejects nearly every solution
//! would otherwise keep the guard from being called. The cost is one function call per
//! solution (`docs/benchmarks.md`, "SPARQL cancellation").
//!
//! The pattern of every `EXISTS` (in a filter, an `OPTIONAL`'s condition, a `BIND`, an
//! `ORDER BY` key or an aggregate) is guarded in the same way: it is evaluated once per
//! solution of the pattern around it, and one evaluation can be a whole join.
//!
//! The same checks stop a query that holds more memory than its budget allows
//! (`ParsedQuery::with_memory_limit`, counted by `dyknow_meter`): the allocation that passes
//! the budget cancels the query's token (`KnowledgeBase::run_query`).
//!
//! Not reached: the rows a join makes for one row of its probe side (buffered before the first
//! is returned), and a sort or aggregate over solutions already made.
//!
//! A panic is the one way out of oxigraph's evaluator that a custom function has: its result
//! is only ever a term or an error that SPARQL turns into "false". It unwinds only the
//! evaluator's frames (iterators over a snapshot, dropped on the way), and its message is kept
//! off stderr by a panic hook that lets every other panic through.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::Once;
use std::time::Duration;

use oxigraph::model::{Literal, NamedNode, Term};
use oxigraph::sparql::{CancellationToken, PreparedSparqlQuery, SparqlEvaluator};
use spargebra::algebra::{
    AggregateExpression, Expression, Function, GraphPattern, OrderExpression,
};
use spargebra::term::Variable;

use super::{strings, sub_expressions, sub_expressions_mut};
use crate::error::SparqlQueryError;

/// The custom function the guard calls once per solution.
pub(crate) const ALIVE: &str = "urn:dyknow:sparql:alive";

/// The variable of the guard's `else` branch: bound nowhere, and no query can name it (`-` is
/// not allowed in a variable's name), so the optimiser keeps the guard out of every part of
/// the pattern (it is not bound in any).
const UNBOUND: &str = "dyknow-guard-unbound";

/// The payload a cancelled evaluation unwinds with.
struct Cancelled;

// A cancelled query unwinds: built to abort on panics, the service would abort on a timeout.
#[cfg(panic = "abort")]
compile_error!("the SPARQL guard unwinds cancelled queries: build with panic = \"unwind\"");

/// `IF(alive(), then, otherwise)`: `then`, once `alive()` has checked the token.
fn checked(then: Expression, otherwise: Expression) -> Expression {
    Expression::If(
        Box::new(Expression::FunctionCall(
            Function::Custom(NamedNode::new_unchecked(ALIVE)),
            Vec::new(),
        )),
        Box::new(then),
        Box::new(otherwise),
    )
}

/// `query` guarded, ready to run with `token`.
pub(crate) fn prepare(query: spargebra::Query, token: &CancellationToken) -> PreparedSparqlQuery {
    evaluator(token).for_query(guard_query(query))
}

/// `query` as [`prepare`] rewrites it (for tests).
#[cfg(test)]
pub(crate) fn rewritten(query: spargebra::Query) -> spargebra::Query {
    guard_query(query)
}

/// `query` with its patterns guarded (see the module's documentation).
fn guard_query(mut query: spargebra::Query) -> spargebra::Query {
    let pattern = match &mut query {
        spargebra::Query::Select { pattern, .. }
        | spargebra::Query::Construct { pattern, .. }
        | spargebra::Query::Describe { pattern, .. }
        | spargebra::Query::Ask { pattern, .. } => pattern,
    };
    *pattern = guard(walk(take(pattern)));
    query
}

/// `pattern`'s value, an empty pattern left in its place.
fn take(pattern: &mut GraphPattern) -> GraphPattern {
    std::mem::replace(
        pattern,
        GraphPattern::Bgp {
            patterns: Vec::new(),
        },
    )
}

/// An evaluator that answers `alive()` for `token`.
fn evaluator(token: &CancellationToken) -> SparqlEvaluator {
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !info.payload().is::<Cancelled>() {
                previous(info);
            }
        }));
    });
    let alive = token.clone();
    let mut evaluator = SparqlEvaluator::new()
        .with_cancellation_token(token.clone())
        .with_custom_function(NamedNode::new_unchecked(ALIVE), move |_| {
            if alive.is_cancelled() {
                std::panic::panic_any(Cancelled);
            }
            // A simple literal: true as an effective boolean value, and the cheapest term
            // for the evaluator to take in (no datatype to read).
            Some(Term::Literal(Literal::new_simple_literal("1")))
        });
    type StringFunction = fn(&[Term], strings::Refused<'_>) -> Option<Term>;
    let functions: [(&str, StringFunction); 3] = [
        (strings::CONCAT, strings::concat),
        (strings::REPLACE, strings::replace),
        (strings::ENCODE_FOR_URI, strings::encode_for_uri),
    ];
    for (iri, function) in functions {
        let token = token.clone();
        evaluator = evaluator.with_custom_function(NamedNode::new_unchecked(iri), move |args| {
            // A refused reservation tripped the budget, whose hook cancelled the token: the
            // query stops here, and is reported as over its memory limit.
            let stop = || std::panic::panic_any(Cancelled);
            if token.is_cancelled() {
                stop();
            }
            function(args, &stop)
        });
    }
    evaluator
}

static HOOK: Once = Once::new();

/// Runs `f`, which evaluates a guarded query: a cancellation that unwinds out of it is
/// [`SparqlQueryError::Timeout`]; any other panic goes on unwinding.
pub(crate) fn evaluate<T>(
    timeout: Duration,
    f: impl FnOnce() -> Result<T, SparqlQueryError>,
) -> Result<T, SparqlQueryError> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(answer) => answer,
        Err(payload) if payload.is::<Cancelled>() => Err(SparqlQueryError::Timeout(timeout)),
        Err(payload) => resume_unwind(payload),
    }
}

/// Guards the pattern of every `EXISTS` in `expression` as a query's pattern is guarded: its
/// solutions, made once per solution of the pattern around it, are checked too (a join inside
/// `FILTER EXISTS` whose filter rejects every row ran unchecked to its end).
///
/// Calls of `CONCAT`, `REPLACE` and `ENCODE_FOR_URI` become calls of the custom functions of
/// the same semantics that check the memory budget before they build ([`super::strings`]).
fn guard_expression(mut expression: Expression) -> Expression {
    fn visit(expression: &mut Expression) {
        if let Expression::Exists(pattern) = expression {
            **pattern = guard(walk(take(pattern)));
        } else {
            if let Expression::FunctionCall(function, _) = expression {
                let custom = match function {
                    Function::Concat => Some(strings::CONCAT),
                    Function::Replace => Some(strings::REPLACE),
                    Function::EncodeForUri => Some(strings::ENCODE_FOR_URI),
                    _ => None,
                };
                if let Some(iri) = custom {
                    *function = Function::Custom(NamedNode::new_unchecked(iri));
                }
            }
            // A custom function's arguments are copied into terms before it runs: a `CONCAT`
            // of many arguments is a balanced tree of `CONCAT`s of two (the same value: it is
            // associative, and keeps a tag only all its arguments share), each of which looks
            // at the budget before the next copies its arguments.
            if let Expression::FunctionCall(Function::Custom(iri), args) = expression
                && iri.as_str() == strings::CONCAT
                && args.len() > 2
            {
                *args = pairs(std::mem::take(args), iri);
            }
            for operand in sub_expressions_mut(expression) {
                visit(operand);
            }
        }
    }
    visit(&mut expression);
    expression
}

/// `args` as two arguments of `concat`: each half of them, itself a call of `concat` when it
/// has more than one.
fn pairs(mut args: Vec<Expression>, concat: &NamedNode) -> Vec<Expression> {
    let right = args.split_off(args.len() / 2);
    [args, right]
        .into_iter()
        .map(|mut half| {
            if half.len() == 1 {
                half.remove(0)
            } else {
                let half = if half.len() > 2 {
                    pairs(half, concat)
                } else {
                    half
                };
                Expression::FunctionCall(Function::Custom(concat.clone()), half)
            }
        })
        .collect()
}

/// Guards the pattern under every sub-`SELECT`, `GROUP BY` and `EXISTS` of `pattern`.
fn walk(pattern: GraphPattern) -> GraphPattern {
    use GraphPattern as G;
    let w = |p: Box<G>| Box::new(walk(*p));
    match pattern {
        p @ (G::Bgp { .. } | G::Path { .. } | G::Values { .. } | G::Service { .. }) => p,
        G::Join { left, right } => G::Join {
            left: w(left),
            right: w(right),
        },
        G::Lateral { left, right } => G::Lateral {
            left: w(left),
            right: w(right),
        },
        G::Union { left, right } => G::Union {
            left: w(left),
            right: w(right),
        },
        G::Minus { left, right } => G::Minus {
            left: w(left),
            right: w(right),
        },
        G::LeftJoin {
            left,
            right,
            expression,
        } => G::LeftJoin {
            left: w(left),
            right: w(right),
            expression: expression.map(guard_expression),
        },
        // A filter over a join may reject nearly every solution, and the optimiser merges it
        // with the guard into one conjunction whose order it chooses: such a filter checks
        // the token itself, `IF(alive(), c, c)` (the same variables, so it is placed where `c`
        // would be; a constant is left for the optimiser to fold).
        G::Filter { expr, inner } => {
            let inner = walk(*inner);
            let expr = guard_expression(expr);
            let expr = if multiplies(&inner) && !constant(&expr) {
                checked(expr.clone(), expr)
            } else {
                expr
            };
            G::Filter {
                expr,
                inner: Box::new(inner),
            }
        }
        G::Graph { name, inner } => G::Graph {
            name,
            inner: w(inner),
        },
        G::Extend {
            inner,
            variable,
            expression,
        } => G::Extend {
            inner: w(inner),
            variable,
            expression: guard_expression(expression),
        },
        G::OrderBy { inner, expression } => G::OrderBy {
            inner: w(inner),
            expression: expression
                .into_iter()
                .map(|order| match order {
                    OrderExpression::Asc(e) => OrderExpression::Asc(guard_expression(e)),
                    OrderExpression::Desc(e) => OrderExpression::Desc(guard_expression(e)),
                })
                .collect(),
        },
        G::Distinct { inner } => G::Distinct { inner: w(inner) },
        G::Reduced { inner } => G::Reduced { inner: w(inner) },
        G::Slice {
            inner,
            start,
            length,
        } => G::Slice {
            inner: w(inner),
            start,
            length,
        },
        G::Project { inner, variables } => {
            let inner = walk(*inner);
            G::Project {
                inner: Box::new(guard(inner)),
                variables,
            }
        }
        G::Group {
            inner,
            variables,
            aggregates,
        } => {
            let inner = walk(*inner);
            let aggregates = aggregates
                .into_iter()
                .map(|(variable, aggregate)| {
                    let aggregate = match aggregate {
                        AggregateExpression::FunctionCall {
                            name,
                            expr,
                            distinct,
                        } => AggregateExpression::FunctionCall {
                            name,
                            expr: guard_expression(expr),
                            distinct,
                        },
                        count @ AggregateExpression::CountSolutions { .. } => count,
                    };
                    (variable, aggregate)
                })
                .collect();
            G::Group {
                inner: Box::new(guard(inner)),
                variables,
                aggregates,
            }
        }
    }
}

/// Wraps `pattern` below its solution modifiers in the `alive()` filter. A sub-`SELECT` or a
/// `GROUP BY` met on the way is left as it is: [`walk`] guarded its inside.
fn guard(pattern: GraphPattern) -> GraphPattern {
    use GraphPattern as G;
    let g = |p: Box<G>| Box::new(guard(*p));
    match pattern {
        G::Slice {
            inner,
            start,
            length,
        } => G::Slice {
            inner: g(inner),
            start,
            length,
        },
        G::Distinct { inner } => G::Distinct { inner: g(inner) },
        G::Reduced { inner } => G::Reduced { inner: g(inner) },
        G::OrderBy { inner, expression } => G::OrderBy {
            inner: g(inner),
            expression,
        },
        G::Extend {
            inner,
            variable,
            expression,
        } => G::Extend {
            inner: g(inner),
            variable,
            expression,
        },
        p @ (G::Project { .. } | G::Group { .. }) => p,
        // Each solution cost a read, where oxigraph checks the token itself: a query of one
        // triple pattern (a lookup, a count) runs as it is written.
        p if !multiplies(&p) => p,
        p => G::Filter {
            expr: checked(
                Expression::Literal(true.into()),
                Expression::Variable(Variable::new_unchecked(UNBOUND)),
            ),
            inner: Box::new(p),
        },
    }
}

/// Whether `pattern` can make more solutions than it reads quads: a join of any kind (a BGP of
/// two triple patterns or more included), or a property path (a closure computed in memory).
fn multiplies(pattern: &GraphPattern) -> bool {
    use GraphPattern as G;
    match pattern {
        G::Bgp { patterns } => patterns.len() > 1,
        G::Path { .. }
        | G::Join { .. }
        | G::LeftJoin { .. }
        | G::Lateral { .. }
        | G::Minus { .. } => true,
        G::Values { .. } | G::Service { .. } => false,
        G::Union { left, right } => multiplies(left) || multiplies(right),
        G::Filter { inner, .. }
        | G::Graph { inner, .. }
        | G::Extend { inner, .. }
        | G::OrderBy { inner, .. }
        | G::Project { inner, .. }
        | G::Distinct { inner }
        | G::Reduced { inner }
        | G::Slice { inner, .. }
        | G::Group { inner, .. } => multiplies(inner),
    }
}

/// Whether `expression` names no variable and no pattern (the optimiser may fold it).
fn constant(expression: &Expression) -> bool {
    match expression {
        Expression::NamedNode(_) | Expression::Literal(_) => true,
        Expression::Variable(_) | Expression::Bound(_) | Expression::Exists(_) => false,
        e => sub_expressions(e).into_iter().all(constant),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// How many guards the rewritten `query` has.
    fn guards(query: &str) -> usize {
        let parsed = spargebra::SparqlParser::new()
            .parse_query(query)
            .expect("parses");
        guard_query(parsed).to_string().matches(ALIVE).count()
    }

    #[test]
    fn patterns_that_read_a_quad_per_solution_are_left_alone() {
        assert_eq!(guards("SELECT * WHERE { ?s ?p ?o }"), 0);
        assert_eq!(guards("SELECT (COUNT(*) AS ?n) WHERE { ?s a ?c }"), 0);
        assert_eq!(guards("ASK { <urn:a> <urn:b> <urn:c> }"), 0);
        assert_eq!(guards("SELECT * WHERE { VALUES ?x { 1 2 } }"), 0);
        assert_eq!(
            guards("SELECT ?s WHERE { { ?s ?p 1 } UNION { ?s ?p 2 } } ORDER BY ?s"),
            0
        );
    }

    #[test]
    fn joins_paths_and_their_modifiers_are_guarded_once_per_select_or_group() {
        assert_eq!(guards("SELECT * WHERE { ?a ?b ?c . ?d ?e ?f }"), 1);
        assert_eq!(guards("SELECT * WHERE { ?a <urn:p>* ?b }"), 1);
        assert_eq!(
            guards("SELECT * WHERE { ?a ?b ?c OPTIONAL { ?c ?d ?e } } ORDER BY ?a LIMIT 3"),
            1
        );
        assert_eq!(guards("CONSTRUCT WHERE { ?a ?b ?c . ?c ?d ?e }"), 1);
        assert_eq!(guards("ASK { ?a ?b ?c MINUS { ?a ?b 1 } }"), 1);
        // A GROUP BY is guarded below itself, and its SELECT above it sees few solutions.
        assert_eq!(
            guards("SELECT ?a (COUNT(*) AS ?n) WHERE { ?a ?b ?c . ?d ?e ?f } GROUP BY ?a"),
            1
        );
        // A sub-SELECT is guarded inside; the join it is part of, outside.
        assert_eq!(
            guards("SELECT * WHERE { ?x ?y ?z { SELECT ?a WHERE { ?a ?b ?c . ?d ?e ?f } } }"),
            2
        );
    }

    #[test]
    fn the_patterns_of_exists_are_guarded_wherever_it_is() {
        let join = "{ ?a ?b ?c . ?d ?e ?f }";
        // In a filter over one pattern: the filter's pattern is not, the EXISTS pattern is.
        assert_eq!(
            guards(&format!(
                "SELECT * WHERE {{ ?s ?p ?o FILTER EXISTS {join} }}"
            )),
            1
        );
        assert_eq!(guards(&format!("ASK {{ FILTER NOT EXISTS {join} }}")), 1);
        // Nested in an expression, in BIND, in ORDER BY, in an aggregate, in OPTIONAL's
        // condition.
        assert_eq!(
            guards(&format!(
                "SELECT * WHERE {{ ?s ?p ?o FILTER(?o = 1 || !EXISTS {join}) }}"
            )),
            1
        );
        assert_eq!(
            guards(&format!(
                "SELECT * WHERE {{ ?s ?p ?o BIND(EXISTS {join} AS ?x) }}"
            )),
            1
        );
        assert_eq!(
            guards(&format!(
                "SELECT * WHERE {{ ?s ?p ?o }} ORDER BY (EXISTS {join})"
            )),
            1
        );
        assert_eq!(
            guards(&format!(
                "SELECT (SUM(IF(EXISTS {join}, 1, 0)) AS ?n) WHERE {{ ?s ?p ?o }}"
            )),
            1
        );
        // An OPTIONAL's filter is its condition; the OPTIONAL, a join, is guarded too.
        assert_eq!(
            guards(&format!(
                "SELECT * WHERE {{ ?s ?p ?o OPTIONAL {{ ?o ?q ?r FILTER EXISTS {join} }} }}"
            )),
            2
        );
        // An EXISTS over one pattern reads a quad per solution: left alone.
        assert_eq!(
            guards("SELECT * WHERE { ?s ?p ?o FILTER EXISTS { ?o ?q ?r } }"),
            0
        );
    }

    #[test]
    fn the_guard_names_a_variable_no_part_binds_so_the_optimiser_keeps_it_above_the_joins() {
        let parsed = spargebra::SparqlParser::new()
            .parse_query("SELECT ?a WHERE { [] a [] . [] a [] . ?a ?b ?c }")
            .expect("parses");
        let text = guard_query(parsed).to_string();
        assert!(text.contains(&format!("?{UNBOUND}")), "{text}");
    }

    #[test]
    fn a_filter_over_a_join_checks_the_token_itself_and_a_constant_one_is_left_to_fold() {
        assert_eq!(
            guards("SELECT * WHERE { ?a ?b ?c . ?d ?e ?f FILTER(?c = ?f) }"),
            2
        );
        assert_eq!(guards("SELECT * WHERE { ?a ?b ?c FILTER(?c = 1) }"), 0);
        assert_eq!(
            guards("SELECT * WHERE { ?a ?b ?c . ?d ?e ?f FILTER(1 = 2) }"),
            1
        );
    }
}
