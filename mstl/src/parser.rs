//! The MSTL parser (contract `mstl.md`): a lexer and a recursive-descent parser following the
//! grammar's rules one function each. Errors name the column (1-based, in characters).
//! Nesting deeper than [`MAX_DEPTH`] and inputs longer than [`MAX_LEN`] are refused with an
//! error, never a stack overflow.

use crate::syntax::{Atom, Cmp, Domain, Formula, Interval, Rcc8, Region, Term};

/// The deepest recursion of the parser accepted. It is far above what any tree of
/// [`MAX_TREE_DEPTH`] needs when printed (at most about six levels per operator, with the
/// printer's parentheses), so every accepted formula's printed text is accepted too; it only
/// stops absurd nesting of parentheses (some 2,600 levels).
pub const MAX_DEPTH: usize = 8 * MAX_TREE_DEPTH;
/// The longest formula accepted, in bytes.
pub const MAX_LEN: usize = 1 << 20;
/// The deepest syntax tree accepted, counting chains such as `a && b && c` one level per
/// operator: deeper trees would make every recursive walk (printing, dropping, progression) a
/// stack risk for callers.
pub const MAX_TREE_DEPTH: usize = 1000;

/// A syntax error at a column.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("column {column}: {message}")]
pub struct ParseError {
    /// 1-based column (in characters) where the error is.
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Ident(String),
    Number(f64),
    Str(String),
    LParen,
    RParen,
    LBracket,
    RBracket,
    LBrace,
    RBrace,
    Comma,
    Colon,
    Caret,
    Bang,
    And,
    Or,
    Arrow,
    Iff,
    Box,
    Diamond,
    Minus,
    Cmp(Cmp),
    End,
}

fn describe(t: &Tok) -> String {
    match t {
        Tok::Ident(s) => format!("'{s}'"),
        Tok::Number(n) => format!("number {n}"),
        Tok::Str(_) => "a string".to_owned(),
        Tok::End => "the end of the formula".to_owned(),
        other => format!("'{}'", symbol(other)),
    }
}

fn symbol(t: &Tok) -> &'static str {
    match t {
        Tok::LParen => "(",
        Tok::RParen => ")",
        Tok::LBracket => "[",
        Tok::RBracket => "]",
        Tok::LBrace => "{",
        Tok::RBrace => "}",
        Tok::Comma => ",",
        Tok::Colon => ":",
        Tok::Caret => "^",
        Tok::Bang => "!",
        Tok::And => "&&",
        Tok::Or => "||",
        Tok::Arrow => "->",
        Tok::Iff => "<->",
        Tok::Box => "[]",
        Tok::Diamond => "<>",
        Tok::Minus => "-",
        Tok::Cmp(c) => c.symbol(),
        _ => "?",
    }
}

const KEYWORDS: &[&str] = &[
    "always",
    "G",
    "eventually",
    "F",
    "next",
    "X",
    "not",
    "and",
    "or",
    "forall",
    "exists",
    "in",
    "true",
    "false",
    "U",
    "inf",
    "prev",
];

/// Whether `name` is a keyword (and so cannot name a predicate, constant or variable).
pub fn is_keyword(name: &str) -> bool {
    KEYWORDS.contains(&name)
}

fn lex(input: &str) -> Result<Vec<(Tok, usize)>, ParseError> {
    let chars: Vec<char> = input.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    let err = |column: usize, message: String| ParseError { column, message };
    while i < chars.len() {
        let c = chars[i];
        let col = i + 1;
        let peek = |k: usize| chars.get(i + k).copied();
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let (tok, len) = match c {
            '(' => (Tok::LParen, 1),
            ')' => (Tok::RParen, 1),
            '[' if peek(1) == Some(']') => (Tok::Box, 2),
            '[' => (Tok::LBracket, 1),
            ']' => (Tok::RBracket, 1),
            '{' => (Tok::LBrace, 1),
            '}' => (Tok::RBrace, 1),
            ',' => (Tok::Comma, 1),
            ':' => (Tok::Colon, 1),
            '^' => (Tok::Caret, 1),
            '!' if peek(1) == Some('=') => (Tok::Cmp(Cmp::Ne), 2),
            '!' => (Tok::Bang, 1),
            '&' if peek(1) == Some('&') => (Tok::And, 2),
            '|' if peek(1) == Some('|') => (Tok::Or, 2),
            '-' if peek(1) == Some('>') => (Tok::Arrow, 2),
            '-' => (Tok::Minus, 1),
            '<' if peek(1) == Some('-') && peek(2) == Some('>') => (Tok::Iff, 3),
            '<' if peek(1) == Some('>') => (Tok::Diamond, 2),
            '<' if peek(1) == Some('=') => (Tok::Cmp(Cmp::Le), 2),
            '<' => (Tok::Cmp(Cmp::Lt), 1),
            '>' if peek(1) == Some('=') => (Tok::Cmp(Cmp::Ge), 2),
            '>' => (Tok::Cmp(Cmp::Gt), 1),
            '=' => (Tok::Cmp(Cmp::Eq), 1),
            '"' => {
                let mut s = String::new();
                let mut j = i + 1;
                loop {
                    match chars.get(j) {
                        None => return Err(err(col, "unterminated string".to_owned())),
                        Some('"') => break,
                        Some('\\') => match chars.get(j + 1) {
                            Some(e @ ('"' | '\\')) => {
                                s.push(*e);
                                j += 2;
                            }
                            _ => {
                                return Err(err(
                                    j + 1,
                                    "only \\\" and \\\\ may be escaped in a string".to_owned(),
                                ));
                            }
                        },
                        Some(ch) => {
                            s.push(*ch);
                            j += 1;
                        }
                    }
                }
                (Tok::Str(s), j + 1 - i)
            }
            d if d.is_ascii_digit() => {
                let mut j = i;
                while chars.get(j).is_some_and(char::is_ascii_digit) {
                    j += 1;
                }
                if chars.get(j) == Some(&'.') && chars.get(j + 1).is_some_and(char::is_ascii_digit)
                {
                    j += 1;
                    while chars.get(j).is_some_and(char::is_ascii_digit) {
                        j += 1;
                    }
                }
                if matches!(chars.get(j), Some('e' | 'E'))
                    && (chars.get(j + 1).is_some_and(char::is_ascii_digit)
                        || (matches!(chars.get(j + 1), Some('-' | '+'))
                            && chars.get(j + 2).is_some_and(char::is_ascii_digit)))
                {
                    j += 2;
                    while chars.get(j).is_some_and(char::is_ascii_digit) {
                        j += 1;
                    }
                }
                let text: String = chars[i..j].iter().collect();
                let n: f64 = text
                    .parse()
                    .map_err(|_| err(col, format!("bad number {text}")))?;
                if !n.is_finite() {
                    return Err(err(col, format!("number {text} is out of range")));
                }
                // Numbers compare as doubles: an integer literal no double holds exactly
                // (beyond 2^53) would compare as another number, and decide atoms wrongly.
                if text.bytes().all(|b| b.is_ascii_digit())
                    && text
                        .parse::<u128>()
                        .ok()
                        .is_none_or(|exact| n as u128 != exact)
                {
                    return Err(err(
                        col,
                        format!(
                            "the integer {text} is beyond what a double holds exactly (2^53 = \
                             9007199254740992): numbers compare as doubles"
                        ),
                    ));
                }
                (Tok::Number(n), j - i)
            }
            a if a.is_alphabetic() || a == '_' => {
                let mut j = i;
                while chars
                    .get(j)
                    .is_some_and(|ch| ch.is_alphanumeric() || *ch == '_')
                {
                    j += 1;
                }
                (Tok::Ident(chars[i..j].iter().collect()), j - i)
            }
            other => return Err(err(col, format!("unexpected character '{other}'"))),
        };
        out.push((tok, col));
        i += len;
    }
    out.push((Tok::End, chars.len() + 1));
    Ok(out)
}

struct Parser {
    toks: Vec<(Tok, usize)>,
    pos: usize,
    depth: usize,
}

/// The stack the parser runs on: enough for [`MAX_DEPTH`] levels of recursion in any build
/// profile (unoptimised frames are a few kilobytes), reserved, not committed.
const PARSER_STACK: usize = 128 << 20;

/// Parses an MSTL formula. The recursive descent runs on a thread of its own with a stack
/// sized for [`MAX_DEPTH`], so no input overflows the caller's stack.
pub fn parse(input: &str) -> Result<Formula, ParseError> {
    std::thread::scope(|scope| {
        match std::thread::Builder::new()
            .name("mstl-parser".to_owned())
            .stack_size(PARSER_STACK)
            .spawn_scoped(scope, || parse_here(input))
        {
            Ok(handle) => handle
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic)),
            // No thread to be had: parse here (the depth bound still holds).
            Err(_) => parse_here(input),
        }
    })
}

fn parse_here(input: &str) -> Result<Formula, ParseError> {
    if input.len() > MAX_LEN {
        return Err(ParseError {
            column: 1,
            message: format!("the formula is longer than {MAX_LEN} bytes"),
        });
    }
    let mut p = Parser {
        toks: lex(input)?,
        pos: 0,
        depth: 0,
    };
    let f = p.formula()?;
    if p.peek() != &Tok::End {
        return Err(p.error(format!(
            "expected the end of the formula, found {}",
            describe(p.peek())
        )));
    }
    if tree_depth(&f) > MAX_TREE_DEPTH {
        // Dropped here, on the parser's large stack.
        return Err(ParseError {
            column: 1,
            message: format!(
                "the formula nests deeper than {MAX_TREE_DEPTH} levels (each operator and the atom under it count one; chains such as a && b && ... count one level per operator)"
            ),
        });
    }
    Ok(f)
}

/// The depth of a syntax tree, without recursion.
fn tree_depth(f: &Formula) -> usize {
    let mut deepest = 0;
    let mut stack = vec![(f, 1)];
    while let Some((g, d)) = stack.pop() {
        deepest = deepest.max(d);
        match g {
            Formula::True | Formula::False | Formula::Atom(_) => {}
            Formula::Not(a)
            | Formula::Always(_, a)
            | Formula::Eventually(_, a)
            | Formula::Next(_, a)
            | Formula::Forall(_, _, a)
            | Formula::Exists(_, _, a) => stack.push((a, d + 1)),
            Formula::And(a, b)
            | Formula::Or(a, b)
            | Formula::Implies(a, b)
            | Formula::Iff(a, b)
            | Formula::Until(_, a, b) => {
                stack.push((a, d + 1));
                stack.push((b, d + 1));
            }
        }
    }
    deepest
}

impl Parser {
    fn peek(&self) -> &Tok {
        &self.toks[self.pos].0
    }

    fn peek_at(&self, k: usize) -> &Tok {
        &self.toks[(self.pos + k).min(self.toks.len() - 1)].0
    }

    fn column(&self) -> usize {
        self.toks[self.pos].1
    }

    fn error(&self, message: String) -> ParseError {
        ParseError {
            column: self.column(),
            message,
        }
    }

    fn bump(&mut self) -> Tok {
        let t = self.toks[self.pos].0.clone();
        if self.pos < self.toks.len() - 1 {
            self.pos += 1;
        }
        t
    }

    fn expect(&mut self, want: &Tok) -> Result<(), ParseError> {
        if self.peek() == want {
            self.bump();
            Ok(())
        } else {
            Err(self.error(format!(
                "expected '{}', found {}",
                symbol(want),
                describe(self.peek())
            )))
        }
    }

    fn keyword(&self, words: &[&str]) -> bool {
        matches!(self.peek(), Tok::Ident(s) if words.contains(&s.as_str()))
    }

    fn enter(&mut self) -> Result<(), ParseError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(self.error(format!("the formula nests deeper than {MAX_DEPTH} levels")));
        }
        Ok(())
    }

    /// `formula := iff`; `iff := implies ( "<->" implies )*`.
    fn formula(&mut self) -> Result<Formula, ParseError> {
        self.enter()?;
        let mut f = self.implies()?;
        while self.peek() == &Tok::Iff {
            self.bump();
            let g = self.implies()?;
            f = Formula::Iff(Box::new(f), Box::new(g));
        }
        self.depth -= 1;
        Ok(f)
    }

    /// `implies := or ( "->" implies )?`, right-associative.
    fn implies(&mut self) -> Result<Formula, ParseError> {
        self.enter()?;
        let f = self.or()?;
        let f = if self.peek() == &Tok::Arrow {
            self.bump();
            let g = self.implies()?;
            Formula::Implies(Box::new(f), Box::new(g))
        } else {
            f
        };
        self.depth -= 1;
        Ok(f)
    }

    /// `or := and ( ("||" | "or") and )*`.
    fn or(&mut self) -> Result<Formula, ParseError> {
        let mut f = self.and()?;
        while self.peek() == &Tok::Or || self.keyword(&["or"]) {
            self.bump();
            let g = self.and()?;
            f = Formula::Or(Box::new(f), Box::new(g));
        }
        Ok(f)
    }

    /// `and := until ( ("&&" | "and") until )*`.
    fn and(&mut self) -> Result<Formula, ParseError> {
        let mut f = self.until()?;
        while self.peek() == &Tok::And || self.keyword(&["and"]) {
            self.bump();
            let g = self.until()?;
            f = Formula::And(Box::new(f), Box::new(g));
        }
        Ok(f)
    }

    /// `until := unary ( "U" interval? until )?`, right-associative.
    fn until(&mut self) -> Result<Formula, ParseError> {
        self.enter()?;
        let f = self.unary()?;
        let f = if self.keyword(&["U"]) {
            self.bump();
            let interval = self.interval_opt()?;
            let g = self.until()?;
            Formula::Until(interval, Box::new(f), Box::new(g))
        } else {
            f
        };
        self.depth -= 1;
        Ok(f)
    }

    /// `unary`: negation, temporal operators, quantifiers, parentheses, constants, atoms.
    fn unary(&mut self) -> Result<Formula, ParseError> {
        self.enter()?;
        let f = self.unary_inner()?;
        self.depth -= 1;
        Ok(f)
    }

    fn unary_inner(&mut self) -> Result<Formula, ParseError> {
        match self.peek().clone() {
            Tok::Bang => {
                self.bump();
                Ok(Formula::Not(Box::new(self.unary()?)))
            }
            Tok::Box => {
                self.bump();
                let i = self.interval_opt()?;
                Ok(Formula::Always(i, Box::new(self.unary()?)))
            }
            Tok::Diamond => {
                self.bump();
                let i = self.interval_opt()?;
                Ok(Formula::Eventually(i, Box::new(self.unary()?)))
            }
            Tok::LParen => {
                self.bump();
                let f = self.formula()?;
                self.expect(&Tok::RParen)?;
                Ok(f)
            }
            Tok::Ident(word) => match word.as_str() {
                "not" => {
                    self.bump();
                    Ok(Formula::Not(Box::new(self.unary()?)))
                }
                "always" | "G" => {
                    self.bump();
                    let i = self.interval_opt()?;
                    Ok(Formula::Always(i, Box::new(self.unary()?)))
                }
                "eventually" | "F" => {
                    self.bump();
                    let i = self.interval_opt()?;
                    Ok(Formula::Eventually(i, Box::new(self.unary()?)))
                }
                "next" | "X" => {
                    self.bump();
                    let k = self.power()?;
                    let body = self.unary()?;
                    Ok(if k == 0 {
                        body
                    } else {
                        Formula::Next(k, Box::new(body))
                    })
                }
                "forall" | "exists" => {
                    self.bump();
                    let var = self.name("a variable")?;
                    if !self.keyword(&["in"]) {
                        return Err(
                            self.error(format!("expected 'in', found {}", describe(self.peek())))
                        );
                    }
                    self.bump();
                    let domain = self.domain()?;
                    self.expect(&Tok::Colon)?;
                    let body = Box::new(self.formula()?);
                    Ok(if word == "forall" {
                        Formula::Forall(var, domain, body)
                    } else {
                        Formula::Exists(var, domain, body)
                    })
                }
                "true" => {
                    self.bump();
                    Ok(Formula::True)
                }
                "false" => {
                    self.bump();
                    Ok(Formula::False)
                }
                _ => Ok(Formula::Atom(self.atom()?)),
            },
            Tok::Number(_) | Tok::Str(_) | Tok::Minus => Ok(Formula::Atom(self.atom()?)),
            t => Err(self.error(format!("expected a formula, found {}", describe(&t)))),
        }
    }

    /// `("^" INT)?` after `next`/`prev`: k ≥ 0, default 1. The seed writes τ for ○⁰τ: `next^0`
    /// is no step at all.
    fn power(&mut self) -> Result<u32, ParseError> {
        if self.peek() != &Tok::Caret {
            return Ok(1);
        }
        self.bump();
        match self.peek().clone() {
            Tok::Number(n) if n.fract() == 0.0 && (0.0..=1e6).contains(&n) => {
                self.bump();
                Ok(n as u32)
            }
            t => Err(self.error(format!(
                "expected a whole number from 0 to 1000000 after '^', found {}",
                describe(&t)
            ))),
        }
    }

    /// A name that is not a keyword.
    fn name(&mut self, what: &str) -> Result<String, ParseError> {
        match self.peek().clone() {
            Tok::Ident(s) if !is_keyword(&s) => {
                self.bump();
                Ok(s)
            }
            t => Err(self.error(format!("expected {what}, found {}", describe(&t)))),
        }
    }

    /// `domain := NAME | "{" NAME ("," NAME)* "}"`.
    fn domain(&mut self) -> Result<Domain, ParseError> {
        if self.peek() != &Tok::LBrace {
            return Ok(Domain::Named(self.name("a domain")?));
        }
        self.bump();
        let mut names = vec![self.name("a constant")?];
        while self.peek() == &Tok::Comma {
            self.bump();
            names.push(self.name("a constant")?);
        }
        self.expect(&Tok::RBrace)?;
        Ok(Domain::Set(names))
    }

    /// `interval?` where `interval := "[" time "," (time | "inf") "]"`.
    fn interval_opt(&mut self) -> Result<Interval, ParseError> {
        if self.peek() != &Tok::LBracket {
            return Ok(Interval::UNBOUNDED);
        }
        self.bump();
        let lo = self.time()?;
        self.expect(&Tok::Comma)?;
        let hi = if self.keyword(&["inf"]) {
            self.bump();
            None
        } else {
            Some(self.time()?)
        };
        if hi.is_some_and(|h| h < lo) {
            return Err(self.error(format!(
                "the interval's upper bound is below its lower bound {lo} ms"
            )));
        }
        self.expect(&Tok::RBracket)?;
        Ok(Interval { lo, hi })
    }

    /// `time := NUMBER UNIT?`, in whole milliseconds.
    fn time(&mut self) -> Result<u64, ParseError> {
        let column = self.column();
        let Tok::Number(n) = self.peek().clone() else {
            return Err(self.error(format!("expected a time, found {}", describe(self.peek()))));
        };
        self.bump();
        let scale = match self.peek() {
            Tok::Ident(u) if u == "ms" => 1.0,
            Tok::Ident(u) if u == "s" => 1e3,
            Tok::Ident(u) if u == "min" => 6e4,
            Tok::Ident(u) if u == "h" => 3.6e6,
            _ => 0.0,
        };
        let ms = if scale == 0.0 {
            n
        } else {
            self.bump();
            n * scale
        };
        if ms.fract() != 0.0 || ms > 9.0e15 {
            return Err(ParseError {
                column,
                message: format!(
                    "a time must be a whole number of milliseconds up to 9e15, not {ms} ms"
                ),
            });
        }
        Ok(ms as u64)
    }

    /// `atom := RCC8 "(" region "," region ")" | term CMP term | NAME ( "(" term ("," term)* ")" )?`.
    fn atom(&mut self) -> Result<Atom, ParseError> {
        if let Some((tokens, relation)) = self.relation_name()
            && self.peek_at(tokens) == &Tok::LParen
        {
            for _ in 0..=tokens {
                self.bump();
            }
            let left = self.region()?;
            self.expect(&Tok::Comma)?;
            let right = self.region()?;
            self.expect(&Tok::RParen)?;
            return Ok(Atom::Spatial {
                relation,
                left,
                right,
            });
        }
        let column = self.column();
        let left = self.term()?;
        if let Tok::Cmp(op) = self.peek().clone() {
            self.bump();
            let right = self.term()?;
            return Ok(Atom::Compare { left, op, right });
        }
        match left {
            Term::Name { name, args } => Ok(Atom::Predicate { name, args }),
            _ => Err(ParseError {
                column,
                message: "a number or string must be compared (= != < > <= >=)".to_owned(),
            }),
        }
    }

    /// An RCC-8 relation name at the current token, and how many tokens it takes: one, or
    /// four for `TPP^-1` and `NTPP^-1` (rcc8.md's spellings of TPPI and NTPPI), which must be
    /// written without spaces.
    fn relation_name(&self) -> Option<(usize, Rcc8)> {
        let Tok::Ident(word) = self.peek() else {
            return None;
        };
        let converse = match word.as_str() {
            "TPP" => Rcc8::Tppi,
            // `NTTP`: the seed's own spelling of NTPP (rcc8.md), whose converse it writes
            // `NTTP⁻¹` (Ch. 3.3.1).
            "NTPP" | "NTTP" => Rcc8::Ntppi,
            _ => return Rcc8::from_name(word).map(|r| (1, r)),
        };
        let column = |k: usize| self.toks.get(self.pos + k).map(|t| t.1);
        let end = self.column() + word.chars().count();
        let written = self.peek_at(1) == &Tok::Caret
            && self.peek_at(2) == &Tok::Minus
            && self.peek_at(3) == &Tok::Number(1.0)
            && (1..=3).all(|k| column(k) == Some(end + k - 1))
            && self.peek_at(4) == &Tok::LParen
            && column(4) == Some(end + 3);
        Some(if written {
            (4, converse)
        } else {
            (1, Rcc8::from_name(word)?)
        })
    }

    /// `term := NUMBER | STRING | NAME ( "(" term ("," term)* ")" )?` (a number may be negative).
    fn term(&mut self) -> Result<Term, ParseError> {
        self.enter()?;
        let t = match self.peek().clone() {
            Tok::Number(n) => {
                self.bump();
                Term::Number(n)
            }
            Tok::Minus => {
                self.bump();
                match self.peek().clone() {
                    Tok::Number(n) => {
                        self.bump();
                        Term::Number(-n)
                    }
                    t => {
                        return Err(self.error(format!(
                            "expected a number after '-', found {}",
                            describe(&t)
                        )));
                    }
                }
            }
            Tok::Str(s) => {
                self.bump();
                Term::Str(s)
            }
            _ => {
                let name = self.name("a term")?;
                let mut args = Vec::new();
                if self.peek() == &Tok::LParen {
                    self.bump();
                    args.push(self.term()?);
                    while self.peek() == &Tok::Comma {
                        self.bump();
                        args.push(self.term()?);
                    }
                    self.expect(&Tok::RParen)?;
                }
                Term::Name { name, args }
            }
        };
        self.depth -= 1;
        Ok(t)
    }

    /// `region := ("next" | "prev") ("^" INT)? region | NAME`; offsets add up.
    fn region(&mut self) -> Result<Region, ParseError> {
        let mut offset: i64 = 0;
        loop {
            if self.keyword(&["next"]) {
                self.bump();
                offset += i64::from(self.power()?);
            } else if self.keyword(&["prev"]) {
                self.bump();
                offset -= i64::from(self.power()?);
            } else {
                break;
            }
            if offset.abs() > 1_000_000 {
                return Err(self.error("a region offset beyond 1000000 states".to_owned()));
            }
        }
        let name = self.name("a region")?;
        Ok(Region {
            offset: offset as i32,
            name,
        })
    }
}
