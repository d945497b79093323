//! The ground symbols of a formula (contract `groups.md`, "Grounding symbols in targets"): after
//! quantifiers are expanded over their domains, every atom that a state must give a value for —
//! a predicate `InsideCircle(ball)`, a function term compared by a comparator
//! `altitude(uav1)`, a spatial relation `PO(a,b)` — written as the state keys it
//! ([`crate::Valuation`]). A formula group asks the environment for one stream per symbol.

use std::collections::{BTreeMap, BTreeSet};

use crate::compile::{CompileError, Domains};
use crate::syntax::{Atom, Domain, Formula, Rcc8, Term};

/// A ground symbol a state stream must carry.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Symbol {
    /// A predicate (a boolean), keyed like `InsideCircle(ball)` or `p`.
    Predicate(String),
    /// A function term compared by a comparator (a number or a string), keyed like
    /// `altitude(uav1)`; also a name without arguments that is no domain constant (`speed`).
    Function(String),
    /// A spatial relation between two regions (offsets dropped: the stream observes the
    /// regions, `next`/`prev` only say at which state).
    Spatial {
        /// The relation.
        relation: Rcc8,
        /// The left region.
        x: String,
        /// The right region.
        y: String,
    },
}

impl Symbol {
    /// The symbol written without spaces, as a state keys it: `altitude(uav1)`, `PO(a,b)`.
    pub fn key(&self) -> String {
        match self {
            Self::Predicate(k) | Self::Function(k) => k.clone(),
            Self::Spatial { relation, x, y } => format!("{}({x},{y})", relation.name()),
        }
    }

    /// Whether the symbol's stream carries RCC-8 constraints.
    pub fn is_spatial(&self) -> bool {
        matches!(self, Self::Spatial { .. })
    }
}

impl std::fmt::Display for Symbol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.key())
    }
}

/// The ground symbols of `formula`, quantifiers expanded over `domains` (named) or their
/// sets. A name without arguments is a constant (never a symbol) when it is bound by a
/// quantifier, a constant of some domain of `domains` or of the formula, or a region; in a
/// comparison any other such name is a symbol (`speed > 50`).
///
/// ```
/// use dyknow_mstl::{Symbol, ground_symbols, parse};
/// let f = parse("forall x in UAV: always (altitude(x) > 50)").unwrap();
/// let domains = [("UAV".to_owned(), vec!["uav1".to_owned(), "uav2".to_owned()])].into();
/// let symbols: Vec<String> = ground_symbols(&f, &domains).unwrap().iter().map(Symbol::key).collect();
/// assert_eq!(symbols, ["altitude(uav1)", "altitude(uav2)"]);
/// ```
pub fn ground_symbols(
    formula: &Formula,
    domains: &Domains,
) -> Result<BTreeSet<Symbol>, CompileError> {
    let atoms = crate::compile::ground_atoms(formula, domains);
    if atoms > crate::compile::MAX_GROUND_ATOMS {
        return Err(CompileError::TooLarge(atoms));
    }
    let mut constants: BTreeSet<String> = domains.values().flatten().cloned().collect();
    collect_set_constants(formula, &mut constants);
    let mut out = BTreeSet::new();
    walk(formula, domains, &constants, &mut BTreeMap::new(), &mut out)?;
    Ok(out)
}

/// The constants of the sets `f` quantifies over (`forall x in {a, b}`), into `out`.
pub(crate) fn collect_set_constants(f: &Formula, out: &mut BTreeSet<String>) {
    crate::progress::deep(|| match f {
        Formula::True | Formula::False | Formula::Atom(_) => {}
        Formula::Not(a)
        | Formula::Always(_, a)
        | Formula::Eventually(_, a)
        | Formula::Next(_, a) => collect_set_constants(a, out),
        Formula::And(a, b)
        | Formula::Or(a, b)
        | Formula::Implies(a, b)
        | Formula::Iff(a, b)
        | Formula::Until(_, a, b) => {
            collect_set_constants(a, out);
            collect_set_constants(b, out);
        }
        Formula::Forall(_, d, body) | Formula::Exists(_, d, body) => {
            if let Domain::Set(cs) = d {
                out.extend(cs.iter().cloned());
            }
            collect_set_constants(body, out);
        }
    });
}

/// Bound variables in scope: name → the constant substituted (innermost binding wins).
type Scope = BTreeMap<String, Vec<String>>;

fn walk(
    f: &Formula,
    domains: &Domains,
    constants: &BTreeSet<String>,
    scope: &mut Scope,
    out: &mut BTreeSet<Symbol>,
) -> Result<(), CompileError> {
    crate::progress::deep(|| match f {
        Formula::True | Formula::False => Ok(()),
        Formula::Atom(a) => {
            atom(a, constants, scope, out);
            Ok(())
        }
        Formula::Not(a)
        | Formula::Always(_, a)
        | Formula::Eventually(_, a)
        | Formula::Next(_, a) => walk(a, domains, constants, scope, out),
        Formula::And(a, b)
        | Formula::Or(a, b)
        | Formula::Implies(a, b)
        | Formula::Iff(a, b)
        | Formula::Until(_, a, b) => {
            walk(a, domains, constants, scope, out)?;
            walk(b, domains, constants, scope, out)
        }
        Formula::Forall(x, d, body) | Formula::Exists(x, d, body) => {
            let values: Vec<String> = match d {
                Domain::Named(name) => domains
                    .get(name)
                    .cloned()
                    .ok_or_else(|| CompileError::UnknownDomain(name.clone()))?,
                Domain::Set(cs) => cs.clone(),
            };
            for v in &values {
                crate::compile::check_constant(v)?;
            }
            if values.is_empty() {
                // The body still names domains that must exist.
                check_domains(body, domains)?;
            }
            for v in values {
                scope.entry(x.clone()).or_default().push(v);
                let r = walk(body, domains, constants, scope, out);
                if let Some(stack) = scope.get_mut(x) {
                    stack.pop();
                    if stack.is_empty() {
                        scope.remove(x);
                    }
                }
                r?;
            }
            Ok(())
        }
    })
}

fn check_domains(f: &Formula, domains: &Domains) -> Result<(), CompileError> {
    crate::progress::deep(|| match f {
        Formula::True | Formula::False | Formula::Atom(_) => Ok(()),
        Formula::Not(a)
        | Formula::Always(_, a)
        | Formula::Eventually(_, a)
        | Formula::Next(_, a) => check_domains(a, domains),
        Formula::And(a, b)
        | Formula::Or(a, b)
        | Formula::Implies(a, b)
        | Formula::Iff(a, b)
        | Formula::Until(_, a, b) => {
            check_domains(a, domains)?;
            check_domains(b, domains)
        }
        Formula::Forall(_, d, body) | Formula::Exists(_, d, body) => {
            if let Domain::Named(name) = d
                && !domains.contains_key(name)
            {
                return Err(CompileError::UnknownDomain(name.clone()));
            }
            check_domains(body, domains)
        }
    })
}

fn bound<'s>(scope: &'s Scope, name: &str) -> Option<&'s str> {
    scope.get(name).and_then(|s| s.last()).map(String::as_str)
}

fn atom(a: &Atom, constants: &BTreeSet<String>, scope: &Scope, out: &mut BTreeSet<Symbol>) {
    match a {
        Atom::Predicate { name, args } => {
            out.insert(Symbol::Predicate(app_key(name, args, scope)));
        }
        Atom::Compare { left, right, .. } => {
            for t in [left, right] {
                if let Term::Name { name, args } = t {
                    if args.is_empty() && (bound(scope, name).is_some() || constants.contains(name))
                    {
                        continue;
                    }
                    out.insert(Symbol::Function(app_key(name, args, scope)));
                }
            }
        }
        Atom::Spatial {
            relation,
            left,
            right,
        } => {
            let region = |n: &str| bound(scope, n).unwrap_or(n).to_owned();
            out.insert(Symbol::Spatial {
                relation: *relation,
                x: region(&left.name),
                y: region(&right.name),
            });
        }
    }
}

/// The key of `name(args)` with bound variables substituted, as [`crate::Valuation`] keys it.
fn app_key(name: &str, args: &[Term], scope: &Scope) -> String {
    let substituted: Vec<Term> = args.iter().map(|t| substitute(t, scope)).collect();
    crate::atom::term_key(&Term::Name {
        name: name.to_owned(),
        args: substituted,
    })
}

fn substitute(t: &Term, scope: &Scope) -> Term {
    match t {
        Term::Name { name, args } if args.is_empty() => Term::Name {
            name: bound(scope, name).unwrap_or(name).to_owned(),
            args: Vec::new(),
        },
        Term::Name { name, args } => Term::Name {
            name: name.clone(),
            args: args.iter().map(|a| substitute(a, scope)).collect(),
        },
        other => other.clone(),
    }
}
