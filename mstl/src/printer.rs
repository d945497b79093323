//! The MSTL printer: `Display` for formulas, in the contract's ASCII syntax. Compound operands
//! are parenthesised, except where the grammar reads them the same without (operands of unary
//! operators that are unary themselves, chains of one operator on the side it associates to),
//! so the output parses back to the same formula and nests no deeper than the input did.

use std::fmt::{self, Display, Formatter};

use crate::syntax::{Atom, Domain, Formula, Interval, Region, Term};

impl Display for Interval {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self.hi {
            Some(hi) => write!(f, "[{},{}]", self.lo, hi),
            None => write!(f, "[{},inf]", self.lo),
        }
    }
}

/// An operator's interval; nothing for `[0, inf]`.
fn interval(i: &Interval) -> String {
    if *i == Interval::UNBOUNDED {
        String::new()
    } else {
        i.to_string()
    }
}

impl Display for Term {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self {
            Self::Number(n) => write!(f, "{n}"),
            Self::Str(s) => write!(f, "\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\"")),
            Self::Name { name, args } => {
                write!(f, "{name}")?;
                if !args.is_empty() {
                    write!(f, "(")?;
                    for (i, a) in args.iter().enumerate() {
                        if i > 0 {
                            write!(f, ", ")?;
                        }
                        write!(f, "{a}")?;
                    }
                    write!(f, ")")?;
                }
                Ok(())
            }
        }
    }
}

impl Display for Region {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        let k = self.offset.unsigned_abs();
        let op = if self.offset > 0 { "next" } else { "prev" };
        match k {
            0 => write!(f, "{}", self.name),
            1 => write!(f, "{op} {}", self.name),
            _ => write!(f, "{op}^{k} {}", self.name),
        }
    }
}

impl Display for Domain {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self {
            Self::Named(n) => write!(f, "{n}"),
            Self::Set(names) => write!(f, "{{{}}}", names.join(", ")),
        }
    }
}

impl Display for Atom {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self {
            Self::Spatial {
                relation,
                left,
                right,
            } => write!(f, "{}({left}, {right})", relation.name()),
            Self::Compare { left, op, right } => write!(f, "{left} {} {right}", op.symbol()),
            Self::Predicate { name, args } => write!(
                f,
                "{}",
                Term::Name {
                    name: name.clone(),
                    args: args.clone()
                }
            ),
        }
    }
}

/// An operand: as it is when it cannot be misread, parenthesised otherwise.
struct Operand<'a>(&'a Formula);

impl Display for Operand<'_> {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self.0 {
            Formula::True
            | Formula::False
            | Formula::Atom(Atom::Predicate { .. } | Atom::Spatial { .. }) => {
                write!(f, "{}", self.0)
            }
            other => write!(f, "({other})"),
        }
    }
}

/// The operand of a unary operator: atoms and unary formulas need no parentheses there
/// (`!!p`, `always !x < 5`), so printing adds no nesting the parser would count.
struct UnaryOperand<'a>(&'a Formula);

impl Display for UnaryOperand<'_> {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self.0 {
            Formula::True
            | Formula::False
            | Formula::Atom(_)
            | Formula::Not(_)
            | Formula::Always(..)
            | Formula::Eventually(..)
            | Formula::Next(..) => write!(f, "{}", self.0),
            other => write!(f, "({other})"),
        }
    }
}

/// A binary operator's operands, a chain of the same operator written without parentheses on
/// the side it associates to (`a && b && c`, `a -> b -> c`).
fn binary(
    f: &mut Formatter<'_>,
    a: &Formula,
    op: &str,
    b: &Formula,
    left_chain: bool,
    right_chain: bool,
) -> fmt::Result {
    if left_chain {
        write!(f, "{a}")?;
    } else {
        write!(f, "{}", Operand(a))?;
    }
    write!(f, " {op} ")?;
    if right_chain {
        write!(f, "{b}")
    } else {
        write!(f, "{}", Operand(b))
    }
}

impl Display for Formula {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self {
            Self::True => write!(f, "true"),
            Self::False => write!(f, "false"),
            Self::Atom(a) => write!(f, "{a}"),
            Self::Not(g) => write!(f, "!{}", UnaryOperand(g)),
            Self::And(a, b) => binary(f, a, "&&", b, matches!(**a, Self::And(..)), false),
            Self::Or(a, b) => binary(f, a, "||", b, matches!(**a, Self::Or(..)), false),
            Self::Implies(a, b) => binary(f, a, "->", b, false, matches!(**b, Self::Implies(..))),
            Self::Iff(a, b) => binary(f, a, "<->", b, matches!(**a, Self::Iff(..)), false),
            Self::Always(i, g) => write!(f, "always{} {}", interval(i), UnaryOperand(g)),
            Self::Eventually(i, g) => write!(f, "eventually{} {}", interval(i), UnaryOperand(g)),
            Self::Until(i, a, b) => {
                let op = format!("U{}", interval(i));
                binary(f, a, &op, b, false, matches!(**b, Self::Until(..)))
            }
            Self::Next(k, g) if *k == 1 => write!(f, "next {}", UnaryOperand(g)),
            Self::Next(k, g) => write!(f, "next^{k} {}", UnaryOperand(g)),
            Self::Forall(x, d, g) => write!(f, "forall {x} in {d}: {}", Operand(g)),
            Self::Exists(x, d, g) => write!(f, "exists {x} in {d}: {}", Operand(g)),
        }
    }
}
