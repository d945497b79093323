//! From the syntax tree to DAG nodes: `->` and `<->` in terms of `!`, `&&`, `||` (Kleene), named
//! domains resolved, and region offsets rewritten by Theorems 4–5 so that no atom looks ahead:
//! `R(next^i x, next^j y)` with `m = max(i, j) > 0` becomes `next^m R(next^(i-m) x, next^(j-m) y)`
//! (so `R(x, next y)` becomes `next R(prev x, y)`), and evaluation only ever needs the current
//! and earlier states. Bound variables are renamed apart (`x` becomes `x\0<n>`, a name no formula
//! or domain can hold), so substituting a constant never captures an inner variable of the same
//! name: `forall x in {y, z}: exists y in {y, z}: x != y` stays true.

use std::collections::BTreeMap;

use crate::dag::{Dag, FALSE, NodeId, TRUE, Window};
use crate::syntax::{Atom, Domain, Formula, Region, Term};

/// Named domains: a name and its constants.
pub type Domains = BTreeMap<String, Vec<String>>;

/// Why a formula cannot be monitored.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CompileError {
    /// A quantifier ranges over a named domain nobody gave.
    #[error("unknown domain '{0}' (give it in the trace header or with --domain {0}=a,b)")]
    UnknownDomain(String),
    /// A domain constant that would make state keys ambiguous: empty, or holding whitespace,
    /// a control character (NUL is reserved for renamed variables), `,`, `(` or `)`.
    #[error(
        "the domain constant {0:?} cannot be used: a constant is not empty and holds no \
         whitespace, control character, ',', '(' or ')' (state keys such as P(a,b) would be \
         ambiguous)"
    )]
    BadConstant(String),
    /// Quantifiers would expand the formula to more ground instances than
    /// [`MAX_GROUND_ATOMS`] ([`ground_instances`]; [`ground_atoms`] for
    /// [`crate::ground_symbols`]).
    #[error(
        "the formula grounds to {0} instances over its domains; at most {MAX_GROUND_ATOMS} are \
         taken"
    )]
    TooLarge(u64),
}

/// The most ground instances a formula may expand to before it is refused
/// ([`ground_instances`]): quantifiers multiply, and eight nested ones over ten constants are
/// 10⁸ atoms, which took 3.7 GB within 7.5 s and then aborted `dyknow check` before it was
/// bounded (a million took 1.1 GB). A formula group takes fewer (`dyknow-group`'s own bound,
/// on [`ground_atoms`]).
pub const MAX_GROUND_ATOMS: u64 = 1_000_000;

/// Whether `c` can be a domain constant: [`CompileError::BadConstant`] says what it cannot be.
pub fn check_constant(c: &str) -> Result<(), CompileError> {
    if c.is_empty()
        || c.chars()
            .any(|ch| ch.is_whitespace() || ch.is_control() || matches!(ch, ',' | '(' | ')'))
    {
        return Err(CompileError::BadConstant(c.to_owned()));
    }
    Ok(())
}

/// How many distinct ground instances of its subformulas `f` can expand to over `domains`:
/// each subformula counts the product of the domain sizes of the quantifiers whose variables
/// occur free in it (the substitutions that give it different instances). Progression
/// hash-conses instances and memoises substitution, so this, not [`ground_atoms`], bounds its
/// work: `exists x in {a, b}: (r || exists x in {a, b}: P(x))` nested 245 deep is a few
/// hundred instances, though 2²⁴⁵ by [`ground_atoms`]; `forall a in D: … forall h in D:
/// P(a, …, h)` over ten constants is 10⁸ either way. Saturates rather than overflows.
pub fn ground_instances(f: &Formula, domains: &Domains) -> u64 {
    instances(f, domains, &mut Vec::new()).0
}

/// The quantifiers in scope: the variable and its domain's size, innermost last.
type Binders = Vec<(String, u64)>;

/// The instances of `f` and the binders (indices into `scope`) of its free variables.
fn instances(
    f: &Formula,
    domains: &Domains,
    scope: &mut Binders,
) -> (u64, std::collections::BTreeSet<usize>) {
    let product = |scope: &Binders, free: &std::collections::BTreeSet<usize>| {
        free.iter().fold(1u64, |n, &i| n.saturating_mul(scope[i].1))
    };
    crate::progress::deep(|| match f {
        Formula::True | Formula::False => (0, Default::default()),
        Formula::Atom(a) => {
            let mut free = std::collections::BTreeSet::new();
            let mut name = |n: &str| {
                if let Some(i) = scope.iter().rposition(|(v, _)| v == n) {
                    free.insert(i);
                }
            };
            atom_names(a, &mut name);
            (product(scope, &free), free)
        }
        Formula::Not(a)
        | Formula::Always(_, a)
        | Formula::Eventually(_, a)
        | Formula::Next(_, a) => {
            let (n, free) = instances(a, domains, scope);
            (n.saturating_add(product(scope, &free)), free)
        }
        Formula::And(a, b)
        | Formula::Or(a, b)
        | Formula::Implies(a, b)
        | Formula::Iff(a, b)
        | Formula::Until(_, a, b) => {
            let (n, mut free) = instances(a, domains, scope);
            let (m, other) = instances(b, domains, scope);
            free.extend(other);
            (
                n.saturating_add(m).saturating_add(product(scope, &free)),
                free,
            )
        }
        Formula::Forall(x, d, body) | Formula::Exists(x, d, body) => {
            let size = match d {
                Domain::Named(n) => domains.get(n).map_or(1, Vec::len),
                Domain::Set(cs) => cs.len(),
            } as u64;
            scope.push((x.clone(), size));
            let (n, mut free) = instances(body, domains, scope);
            scope.pop();
            free.remove(&scope.len());
            (n.saturating_add(product(scope, &free)), free)
        }
    })
}

/// Every name an atom's terms and regions use (a variable's among them).
fn atom_names(a: &Atom, out: &mut impl FnMut(&str)) {
    fn term(t: &Term, out: &mut impl FnMut(&str)) {
        if let Term::Name { name, args } = t {
            out(name);
            for a in args {
                term(a, out);
            }
        }
    }
    match a {
        Atom::Spatial { left, right, .. } => {
            out(&left.name);
            out(&right.name);
        }
        Atom::Compare { left, right, .. } => {
            term(left, out);
            term(right, out);
        }
        Atom::Predicate { args, .. } => {
            for t in args {
                term(t, out);
            }
        }
    }
}

/// How many ground atoms `f` expands to over `domains`, every quantifier multiplying its
/// body's count by its domain's size whether or not the body uses its variable (an unknown
/// domain counts one; compiling refuses it with its own error): the work of expanding the
/// formula naively, as [`crate::ground_symbols`] does. Saturates rather than overflows.
pub fn ground_atoms(f: &Formula, domains: &Domains) -> u64 {
    let size = |d: &Domain| match d {
        Domain::Named(n) => domains.get(n).map_or(1, Vec::len),
        Domain::Set(cs) => cs.len(),
    } as u64;
    crate::progress::deep(|| match f {
        Formula::True | Formula::False => 0,
        Formula::Atom(_) => 1,
        Formula::Not(a)
        | Formula::Always(_, a)
        | Formula::Eventually(_, a)
        | Formula::Next(_, a) => ground_atoms(a, domains),
        Formula::And(a, b)
        | Formula::Or(a, b)
        | Formula::Implies(a, b)
        | Formula::Iff(a, b)
        | Formula::Until(_, a, b) => {
            ground_atoms(a, domains).saturating_add(ground_atoms(b, domains))
        }
        Formula::Forall(_, d, body) | Formula::Exists(_, d, body) => {
            size(d).saturating_mul(ground_atoms(body, domains))
        }
    })
}

/// Bound variables in scope: the name written and the name it was renamed to.
type Scope = Vec<(String, String)>;

pub(crate) fn compile(
    dag: &mut Dag,
    f: &Formula,
    domains: &Domains,
) -> Result<NodeId, CompileError> {
    let instances = ground_instances(f, domains);
    if instances > MAX_GROUND_ATOMS {
        return Err(CompileError::TooLarge(instances));
    }
    compile_in(dag, f, domains, &mut Scope::new())
}

fn compile_in(
    dag: &mut Dag,
    f: &Formula,
    domains: &Domains,
    scope: &mut Scope,
) -> Result<NodeId, CompileError> {
    crate::progress::deep(|| compile_node(dag, f, domains, scope))
}

fn compile_node(
    dag: &mut Dag,
    f: &Formula,
    domains: &Domains,
    scope: &mut Scope,
) -> Result<NodeId, CompileError> {
    if let Formula::Forall(x, d, body) | Formula::Exists(x, d, body) = f {
        let constants: Vec<String> = match d {
            Domain::Named(name) => domains
                .get(name)
                .cloned()
                .ok_or_else(|| CompileError::UnknownDomain(name.clone()))?,
            Domain::Set(cs) => cs.clone(),
        };
        for c in &constants {
            check_constant(c)?;
        }
        let fresh = format!("{x}\0{}", dag.fresh_variable());
        scope.push((x.clone(), fresh.clone()));
        let body = compile_in(dag, body, domains, scope);
        scope.pop();
        let body = body?;
        let mut syms: Vec<_> = constants.iter().map(|k| dag.sym(k)).collect();
        syms.sort_unstable();
        syms.dedup();
        let var = dag.sym(&fresh);
        return Ok(dag.quantifier(matches!(f, Formula::Forall(..)), var, syms.into(), body));
    }
    let mut c = |g: &Formula| compile_in(dag, g, domains, scope);
    Ok(match f {
        Formula::True => TRUE,
        Formula::False => FALSE,
        Formula::Atom(a) => {
            let (delay, atom) = look_back(&rename(a, scope));
            let n = dag.atom(atom);
            if delay > 0 { dag.next(delay, n) } else { n }
        }
        Formula::Not(a) => {
            let a = c(a)?;
            dag.not(a)
        }
        Formula::And(a, b) => {
            let (a, b) = (c(a)?, c(b)?);
            dag.and2(a, b)
        }
        Formula::Or(a, b) => {
            let (a, b) = (c(a)?, c(b)?);
            dag.or2(a, b)
        }
        Formula::Implies(a, b) => {
            let (a, b) = (c(a)?, c(b)?);
            let na = dag.not(a);
            dag.or2(na, b)
        }
        Formula::Iff(a, b) => {
            let (a, b) = (c(a)?, c(b)?);
            let (na, nb) = (dag.not(a), dag.not(b));
            let l = dag.or2(na, b);
            let r = dag.or2(a, nb);
            dag.and2(l, r)
        }
        Formula::Always(iv, a) => {
            let a = c(a)?;
            dag.always(Window::Rel(*iv), a)
        }
        Formula::Eventually(iv, a) => {
            let a = c(a)?;
            dag.eventually(Window::Rel(*iv), a)
        }
        Formula::Until(iv, a, b) => {
            let (a, b) = (c(a)?, c(b)?);
            dag.until(Window::Rel(*iv), a, b)
        }
        Formula::Next(k, a) => {
            let a = c(a)?;
            dag.next(*k, a)
        }
        Formula::Forall(..) | Formula::Exists(..) => unreachable!("handled above"),
    })
}

/// The atom with its bound variables renamed (the innermost binding of a name wins); names
/// with arguments are functions, never variables.
fn rename(a: &Atom, scope: &Scope) -> Atom {
    let bound = |name: &str| {
        scope
            .iter()
            .rev()
            .find(|(x, _)| x == name)
            .map(|(_, fresh)| fresh.clone())
    };
    fn term(t: &Term, bound: &dyn Fn(&str) -> Option<String>) -> Term {
        match t {
            Term::Name { name, args } if args.is_empty() => Term::Name {
                name: bound(name).unwrap_or_else(|| name.clone()),
                args: Vec::new(),
            },
            Term::Name { name, args } => Term::Name {
                name: name.clone(),
                args: args.iter().map(|a| term(a, bound)).collect(),
            },
            other => other.clone(),
        }
    }
    let region = |r: &Region| Region {
        offset: r.offset,
        name: bound(&r.name).unwrap_or_else(|| r.name.clone()),
    };
    match a {
        Atom::Predicate { name, args } => Atom::Predicate {
            name: name.clone(),
            args: args.iter().map(|t| term(t, &bound)).collect(),
        },
        Atom::Compare { left, op, right } => Atom::Compare {
            left: term(left, &bound),
            op: *op,
            right: term(right, &bound),
        },
        Atom::Spatial {
            relation,
            left,
            right,
        } => Atom::Spatial {
            relation: *relation,
            left: region(left),
            right: region(right),
        },
    }
}

/// How many states before the current one the spatial atoms of `f` refer to once Theorems 4–5
/// have removed every look-ahead: `R(next^i x, next^j y)` looks `max(i, j, 0) - min(i, j)`
/// states back (`EQ(r, next r)` becomes `next EQ(prev r, r)`: one).
pub(crate) fn history(f: &Formula) -> u32 {
    crate::progress::deep(|| match f {
        Formula::True | Formula::False => 0,
        Formula::Atom(Atom::Spatial { left, right, .. }) => {
            let (a, b) = (i64::from(left.offset), i64::from(right.offset));
            u32::try_from(a.max(b).max(0) - a.min(b)).unwrap_or(u32::MAX)
        }
        Formula::Atom(_) => 0,
        Formula::Not(a)
        | Formula::Always(_, a)
        | Formula::Eventually(_, a)
        | Formula::Next(_, a)
        | Formula::Forall(_, _, a)
        | Formula::Exists(_, _, a) => history(a),
        Formula::And(a, b)
        | Formula::Or(a, b)
        | Formula::Implies(a, b)
        | Formula::Iff(a, b)
        | Formula::Until(_, a, b) => history(a).max(history(b)),
    })
}

/// Theorems 4–5: the delay `m` and the atom whose region offsets are all ≤ 0.
fn look_back(a: &Atom) -> (u32, Atom) {
    match a {
        Atom::Spatial {
            relation,
            left,
            right,
        } if left.offset > 0 || right.offset > 0 => {
            let m = left.offset.max(right.offset);
            let back = |r: &Region| Region {
                offset: r.offset.saturating_sub(m),
                name: r.name.clone(),
            };
            (
                m.unsigned_abs(),
                Atom::Spatial {
                    relation: *relation,
                    left: back(left),
                    right: back(right),
                },
            )
        }
        other => (0, other.clone()),
    }
}
