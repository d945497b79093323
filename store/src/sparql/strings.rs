//! The SPARQL string functions that multiply what they are given, with a memory check before
//! they build.
//!
//! A query's memory budget (`--query-memory`) is checked where the evaluation next looks for
//! cancellation: after the allocation that passes it. One call of `CONCAT` with 512 arguments
//! of 4 MiB builds 2 GiB before anything looks (a user audit: a 2.5 KB query took the service
//! to 4.2 GB under a 16 MiB limit, and a longer one would take the machine). `CONCAT`,
//! `REPLACE` and `ENCODE_FOR_URI` are the functions whose result can be many times their
//! arguments (`CONCAT` of n arguments; a `REPLACE` by `$0$0$0$0` quadruples, at each level of
//! a nesting; `ENCODE_FOR_URI` triples), so [`super::guard`] rewrites each call of them into a call of the
//! custom function of the same semantics here, which asks [`dyknow_meter::reserve`] for the
//! bytes it is about to build first (`REPLACE`, as it goes) and, refused, stops the query as
//! its budget does. Every other function's result is at most a few times one argument's size.
//!
//! The semantics are oxigraph's (spareval 0.2, `expression.rs`): arguments must be string
//! literals (simple, `xsd:string` or language-tagged), anything else is an error (unbound);
//! `CONCAT` keeps a language tag all its arguments share; `REPLACE` compiles its pattern with
//! the same `regex` options (flags `s`, `m`, `i`, `x`, `q`; a 1,000,000-byte size limit) and
//! expands the replacement as `regex` does. A property test compares them with oxigraph's own.

use std::borrow::Cow;

use oxigraph::model::vocab::xsd;
use oxigraph::model::{Literal, Term};
use regex::{Regex, RegexBuilder};

/// The custom functions' IRIs.
pub(crate) const CONCAT: &str = "urn:dyknow:sparql:concat";
/// See [`CONCAT`].
pub(crate) const REPLACE: &str = "urn:dyknow:sparql:replace";
/// See [`CONCAT`].
pub(crate) const ENCODE_FOR_URI: &str = "urn:dyknow:sparql:encode-for-uri";

/// What a refused reservation does: stop the query (the guard unwinds it). Should it return,
/// the function's result is an error (unbound).
pub(crate) type Refused<'a> = &'a dyn Fn();

/// A string literal's value and language tag; `None` for any other term.
fn string_and_language(term: &Term) -> Option<(&str, Option<&str>)> {
    let Term::Literal(literal) = term else {
        return None;
    };
    match literal.language() {
        Some(language) => Some((literal.value(), Some(language))),
        None if literal.datatype() == xsd::STRING => Some((literal.value(), None)),
        None => None,
    }
}

/// A simple or language-tagged literal.
fn plain(value: String, language: Option<&str>) -> Option<Term> {
    Some(Term::Literal(match language {
        Some(language) => Literal::new_language_tagged_literal_unchecked(value, language),
        None => Literal::new_simple_literal(value),
    }))
}

/// Room for `bytes` more, or `refused` is called and `None` returned. The result is built
/// once and copied once more when the evaluator takes it in: twice its size is asked for.
fn reserve(bytes: usize, refused: Refused<'_>) -> Option<()> {
    if dyknow_meter::reserve(bytes.saturating_mul(2)) {
        Some(())
    } else {
        refused();
        None
    }
}

/// `CONCAT(args…)`.
pub(crate) fn concat(args: &[Term], refused: Refused<'_>) -> Option<Term> {
    let mut parts = Vec::with_capacity(args.len());
    let mut language: Option<Option<&str>> = None;
    for arg in args {
        let (value, tag) = string_and_language(arg)?;
        language = match language {
            Some(shared) if shared != tag => Some(None),
            Some(shared) => Some(shared),
            None => Some(tag),
        };
        parts.push(value);
    }
    let length = parts
        .iter()
        .map(|p| p.len())
        .fold(0usize, usize::saturating_add);
    reserve(length, refused)?;
    let mut result = String::with_capacity(length);
    for part in parts {
        result.push_str(part);
    }
    plain(result, language.flatten())
}

/// The size limit oxigraph compiles patterns with.
const REGEX_SIZE_LIMIT: usize = 1_000_000;

/// A pattern, its flags, and what they compile to (`None`: they do not).
type Compiled = (String, Option<String>, Option<Regex>);

thread_local! {
    /// The last pattern compiled on this thread, with its flags: a query's evaluation runs on
    /// one thread, and a constant pattern is compiled once, as oxigraph compiles it once for
    /// the query (compiled per row, a `REPLACE` over 100,000 rows took as many compilations).
    static LAST: std::cell::RefCell<Option<Compiled>> = const { std::cell::RefCell::new(None) };
}

/// [`compile`], the last pattern remembered.
fn compiled(pattern: &str, flags: Option<&str>) -> Option<Regex> {
    LAST.with(|last| {
        let mut last = last.borrow_mut();
        if let Some((p, f, regex)) = &*last
            && p == pattern
            && f.as_deref() == flags
        {
            return regex.clone();
        }
        let regex = compile(pattern, flags);
        *last = Some((pattern.to_owned(), flags.map(str::to_owned), regex.clone()));
        regex
    })
}

/// A pattern as oxigraph compiles it; `None` for an invalid pattern or flag.
fn compile(pattern: &str, flags: Option<&str>) -> Option<Regex> {
    let flags = flags.unwrap_or_default();
    let pattern: Cow<'_, str> = if flags.contains('q') {
        regex::escape(pattern).into()
    } else {
        pattern.into()
    };
    let mut builder = RegexBuilder::new(&pattern);
    builder.size_limit(REGEX_SIZE_LIMIT);
    for flag in flags.chars() {
        match flag {
            's' => {
                builder.dot_matches_new_line(true);
            }
            'm' => {
                builder.multi_line(true);
            }
            'i' => {
                builder.case_insensitive(true);
            }
            'x' => {
                builder.ignore_whitespace(true);
            }
            'q' => {}
            _ => return None,
        }
    }
    builder.build().ok()
}

/// A plain string argument (no language tag), as `REPLACE` takes its pattern, replacement and
/// flags.
fn simple(term: &Term) -> Option<&str> {
    match string_and_language(term)? {
        (value, None) => Some(value),
        _ => None,
    }
}

/// `REPLACE(text, pattern, replacement[, flags])`: built as `Regex::replace_all` builds it,
/// asking for room before each piece.
pub(crate) fn replace(args: &[Term], refused: Refused<'_>) -> Option<Term> {
    let [text, pattern, replacement, rest @ ..] = args else {
        return None;
    };
    let flags = match rest {
        [] => None,
        [flags] => Some(simple(flags)?),
        _ => return None,
    };
    let regex = compiled(simple(pattern)?, flags)?;
    let (text, language) = string_and_language(text)?;
    let replacement = simple(replacement)?;
    let mut matches = regex.captures_iter(text).peekable();
    if matches.peek().is_none() {
        return plain(text.to_owned(), language);
    }
    let references = references(replacement);
    let mut out = String::with_capacity(text.len());
    let mut last = 0;
    for captures in matches {
        let Some(whole) = captures.get(0) else {
            continue;
        };
        // The piece before the match and the expansion: at most the replacement with every
        // group reference the whole match (`regex` has no look-around: every group lies in
        // the match); the buffer may double to take them.
        let piece = (whole.start() - last)
            .saturating_add(replacement.len())
            .saturating_add(references.saturating_mul(whole.len()));
        if out.len().saturating_add(piece) > out.capacity() {
            reserve(out.capacity().max(piece), refused)?;
        }
        out.push_str(&text[last..whole.start()]);
        captures.expand(replacement, &mut out);
        last = whole.end();
    }
    out.push_str(&text[last..]);
    plain(out, language)
}

/// How many group references (`$1`, `${name}`) `replacement` holds: every `$` but those of
/// `$$` (a `$` itself).
fn references(replacement: &str) -> usize {
    let mut count = 0;
    let mut chars = replacement.chars().peekable();
    while let Some(c) = chars.next() {
        if c == '$' {
            if chars.peek() == Some(&'$') {
                chars.next();
            } else {
                count += 1;
            }
        }
    }
    count
}

/// `ENCODE_FOR_URI(text)`: at most three bytes for each.
pub(crate) fn encode_for_uri(args: &[Term], refused: Refused<'_>) -> Option<Term> {
    let [text] = args else {
        return None;
    };
    let (text, _) = string_and_language(text)?;
    reserve(text.len().saturating_mul(3), refused)?;
    let mut out = String::with_capacity(text.len());
    for byte in text.bytes() {
        match byte {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                out.push(char::from(byte));
            }
            _ => {
                const HEX: &[u8; 16] = b"0123456789ABCDEF";
                out.push('%');
                out.push(char::from(HEX[usize::from(byte / 16)]));
                out.push(char::from(HEX[usize::from(byte % 16)]));
            }
        }
    }
    plain(out, None)
}

#[cfg(test)]
mod tests {
    use oxigraph::model::Term;
    use oxigraph::sparql::{CancellationToken, QueryResults, SparqlEvaluator};
    use oxigraph::store::Store;
    use proptest::prelude::*;

    /// The values `?r` takes, by oxigraph's own functions and by the rewritten query.
    fn both(query: &str) -> (Vec<Option<Term>>, Vec<Option<Term>>) {
        let store = Store::new().expect("a store");
        let rows = |results: QueryResults<'_>| -> Vec<Option<Term>> {
            let QueryResults::Solutions(solutions) = results else {
                panic!("not solutions")
            };
            solutions
                .map(|s| s.expect("a solution").get("r").cloned())
                .collect()
        };
        let reference = SparqlEvaluator::new()
            .parse_query(query)
            .expect("a query")
            .on_store(&store)
            .execute()
            .expect("evaluated");
        let algebra = spargebra::SparqlParser::new()
            .parse_query(query)
            .expect("a query");
        let ours = super::super::guard::prepare(algebra, &CancellationToken::new())
            .on_store(&store)
            .execute()
            .expect("evaluated");
        (rows(reference), rows(ours))
    }

    fn literal() -> impl Strategy<Value = String> {
        let text = proptest::collection::vec(
            prop::sample::select(vec!["a", "b", "A", "ß", "é", "$", "1", " ", "\\n", "%"]),
            0..6,
        )
        .prop_map(|parts| parts.concat());
        (text, 0u8..5).prop_map(|(text, kind)| match kind {
            0 => format!("\"{text}\"@en"),
            1 => format!("\"{text}\"@fr"),
            2 => format!("\"{text}\"^^<http://www.w3.org/2001/XMLSchema#string>"),
            3 => "1".to_owned(),
            _ => format!("\"{text}\""),
        })
    }

    fn quoted(options: Vec<&'static str>) -> impl Strategy<Value = String> {
        prop::sample::select(options).prop_map(|s| format!("\"{s}\""))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]

        #[test]
        fn concat_is_oxigraphs(args in proptest::collection::vec(literal(), 0..9)) {
            let query = format!("SELECT ?r WHERE {{ BIND(CONCAT({}) AS ?r) }}", args.join(", "));
            let (reference, ours) = both(&query);
            prop_assert_eq!(reference, ours, "{}", query);
        }

        #[test]
        fn replace_is_oxigraphs(
            text in literal(),
            pattern in quoted(vec!["a", "(a)", "(?P<x>b)", "", "[", "a*", ".", "^", "é", "\\\\d", "A"]),
            replacement in prop_oneof![
                quoted(vec!["", "x", "$0", "$1", "${x}", "$$", "[$0]", "$2", "\\\\", "$x$0"]),
                Just("\"y\"@en".to_owned()),
            ],
            flags in prop::sample::select(vec!["", ", \"\"", ", \"i\"", ", \"q\"", ", \"smx\"", ", \"z\"", ", 1"]),
            inline in any::<bool>(),
        ) {
            // Constant patterns and flags take oxigraph's compiled-once path; variables, the
            // other.
            let query = if inline {
                format!("SELECT ?r WHERE {{ BIND(REPLACE({text}, {pattern}, {replacement}{flags}) AS ?r) }}")
            } else {
                format!(
                    "SELECT ?r WHERE {{ VALUES (?t ?p ?s) {{ ({text} {pattern} {replacement}) }} \
                     BIND(REPLACE(?t, ?p, ?s{flags}) AS ?r) }}"
                )
            };
            let (reference, ours) = both(&query);
            prop_assert_eq!(reference, ours, "{}", query);
        }

        #[test]
        fn encode_for_uri_is_oxigraphs(text in literal()) {
            let query = format!("SELECT ?r WHERE {{ BIND(ENCODE_FOR_URI({text}) AS ?r) }}");
            let (reference, ours) = both(&query);
            prop_assert_eq!(reference, ours, "{}", query);
        }
    }

    /// Under a budget, a `REPLACE` whose result stays small is not refused however large its
    /// text (a group reference was counted as the whole text: `$1` over 5 MiB asked for
    /// 20 MiB), and one that would pass it is.
    #[test]
    fn replace_asks_for_what_it_may_build() {
        let stop = std::cell::Cell::new(false);
        let refused = || stop.set(true);
        let text = Term::Literal(oxigraph::model::Literal::new_simple_literal(
            "a".repeat(1 << 20),
        ));
        let lit = |s: &str| Term::Literal(oxigraph::model::Literal::new_simple_literal(s));
        // Without the counting allocator nothing counts as held: each request is compared
        // with the whole budget.
        let budget = dyknow_meter::Budget::start(3 << 20);
        // One match in 1 MiB: the result is 1 MiB and 3 bytes.
        let once = lit(&format!("a{}", "x".repeat(1 << 20)));
        let small = super::replace(&[once, lit("(a)"), lit("$1$1$1$1")], &refused);
        assert!(
            !stop.get() && small.is_some(),
            "refused a result of the text's size"
        );
        let large = super::replace(&[text, lit("(a)"), lit("$1$1$1$1$1$1$1$1")], &refused);
        assert!(
            stop.get() && large.is_none(),
            "built 8 MiB under a 3 MiB budget"
        );
        drop(budget);
        assert_eq!(super::references("$1$$${x}$$"), 2);
    }

    /// The rewritten query calls the custom functions (so the tests above compare them, not
    /// oxigraph's with themselves).
    #[test]
    fn the_functions_are_rewritten() {
        let algebra = spargebra::SparqlParser::new()
            .parse_query(
                "SELECT ?r WHERE { BIND(CONCAT(REPLACE(\"a\", \"a\", \"b\"), ENCODE_FOR_URI(\" \")) AS ?r) }",
            )
            .expect("a query");
        let rewritten = super::super::guard::rewritten(algebra).to_string();
        for iri in [super::CONCAT, super::REPLACE, super::ENCODE_FOR_URI] {
            assert!(rewritten.contains(iri), "{rewritten}");
        }
    }
}
