//! Atoms against a state: the [`Valuation`] a state offers, and how each ground atom is looked
//! up in it (Algorithm 3, lines 22–28: true, false, or unknown when the state cannot tell).

use crate::Truth;
use crate::syntax::{Atom, Cmp, Rcc8, Region, Term};

/// A value in a state: a predicate's truth, or a function term's number or string.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value<'a> {
    /// A predicate's truth.
    Bool(bool),
    /// A number.
    Number(f64),
    /// A string (constants compare as their names).
    Text(&'a str),
}

/// What a state tells about ground atoms and function terms. Keys are the ground atom or term
/// written without spaces: `P`, `P(a,b)`, `f(a)`, `f(g(a),3)`, `P("a b")`.
pub trait Valuation {
    /// The value of a ground predicate or function term, `None` when the state does not say.
    fn value(&self, key: &str) -> Option<Value<'_>>;

    /// The truth of the spatial relation `relation(left, right)` at this state (region
    /// offsets are ≤ 0 here: the rewriting of Theorems 4–5 leaves only the current and earlier
    /// states). `key` is the atom's key (`PO(a,b)`, `EQ(prev r1,r1)`). The default reads the
    /// key as a predicate; the RCC-8 reasoner decides it from the state's spatial constraints.
    fn spatial(&self, relation: Rcc8, left: &Region, right: &Region, key: &str) -> Truth {
        let _ = (relation, left, right);
        match self.value(key) {
            Some(Value::Bool(b)) => Truth::from(b),
            _ => Truth::Unknown,
        }
    }
}

/// A valuation that knows nothing: every atom is unknown.
impl Valuation for () {
    fn value(&self, _key: &str) -> Option<Value<'_>> {
        None
    }
}

/// How a ground atom is evaluated.
#[derive(Debug, Clone)]
pub(crate) enum AtomPlan {
    Predicate {
        key: String,
    },
    Compare {
        left: TermPlan,
        op: Cmp,
        right: TermPlan,
    },
    Spatial {
        relation: Rcc8,
        left: Region,
        right: Region,
        key: String,
        /// The key of the converse atom (`PO(b,a)` for `PO(a,b)`, `TPPI(b,a)` for
        /// `TPP(a,b)`): a state that gives that key says the same.
        converse: String,
    },
}

/// How a ground term is evaluated.
#[derive(Debug, Clone)]
pub(crate) enum TermPlan {
    Number(f64),
    Text(String),
    /// A state lookup; a constant (a name without arguments that `is_constant` says is one)
    /// that the state does not give denotes itself (an object, compared by name). Any other
    /// name the state does not give, `mode` as much as `altitude(uav1)`, is unknown: a formula
    /// group makes it a symbol with a stream of its own (`ground_symbols`), and a state
    /// without its sample must not guess it.
    Lookup {
        key: String,
        constant: bool,
    },
}

impl AtomPlan {
    /// How `atom` is evaluated; `is_constant` tells the names without arguments that are
    /// constants (a domain's, a set's, or a bound variable) from symbols.
    pub(crate) fn new(atom: &Atom, is_constant: &dyn Fn(&str) -> bool) -> Self {
        match atom {
            Atom::Predicate { name, args } => Self::Predicate {
                key: app_key(name, args),
            },
            Atom::Compare { left, op, right } => Self::Compare {
                left: TermPlan::new(left, is_constant),
                op: *op,
                right: TermPlan::new(right, is_constant),
            },
            Atom::Spatial {
                relation,
                left,
                right,
            } => Self::Spatial {
                relation: *relation,
                left: left.clone(),
                right: right.clone(),
                key: format!(
                    "{}({},{})",
                    relation.name(),
                    region_key(left),
                    region_key(right)
                ),
                converse: format!(
                    "{}({},{})",
                    relation.converse().name(),
                    region_key(right),
                    region_key(left)
                ),
            },
        }
    }

    pub(crate) fn eval<V: Valuation + ?Sized>(&self, v: &V) -> Truth {
        match self {
            Self::Predicate { key } => match v.value(key) {
                Some(Value::Bool(b)) => Truth::from(b),
                _ => Truth::Unknown,
            },
            Self::Compare { left, op, right } => match (left.eval(v), right.eval(v)) {
                (Some(l), Some(r)) => compare(l, *op, r),
                _ => Truth::Unknown,
            },
            Self::Spatial {
                relation,
                left,
                right,
                key,
                converse,
            } => match v.spatial(*relation, left, right, key) {
                Truth::Unknown => v.spatial(relation.converse(), right, left, converse),
                known => known,
            },
        }
    }
}

impl TermPlan {
    fn new(term: &Term, is_constant: &dyn Fn(&str) -> bool) -> Self {
        match term {
            Term::Number(n) => Self::Number(*n),
            Term::Str(s) => Self::Text(s.clone()),
            Term::Name { name, args } => Self::Lookup {
                key: app_key(name, args),
                constant: args.is_empty() && is_constant(name),
            },
        }
    }

    fn eval<'a, V: Valuation + ?Sized>(&'a self, v: &'a V) -> Option<Value<'a>> {
        match self {
            Self::Number(n) => Some(Value::Number(*n)),
            Self::Text(s) => Some(Value::Text(s)),
            Self::Lookup { key, constant } => match v.value(key) {
                Some(value) => Some(value),
                None if *constant => Some(Value::Text(key)),
                None => None,
            },
        }
    }
}

/// `l op r`: numbers by value, strings by their characters (lexicographic order), truths by
/// equality only; other combinations (a number against a string, say) are unknown.
fn compare(l: Value<'_>, op: Cmp, r: Value<'_>) -> Truth {
    let ordering = match (l, r) {
        (Value::Number(a), Value::Number(b)) => a.partial_cmp(&b),
        (Value::Text(a), Value::Text(b)) => Some(a.cmp(b)),
        (Value::Bool(a), Value::Bool(b)) => {
            return match op {
                Cmp::Eq => Truth::from(a == b),
                Cmp::Ne => Truth::from(a != b),
                _ => Truth::Unknown,
            };
        }
        _ => None,
    };
    let Some(o) = ordering else {
        return Truth::Unknown;
    };
    Truth::from(match op {
        Cmp::Eq => o.is_eq(),
        Cmp::Ne => o.is_ne(),
        Cmp::Lt => o.is_lt(),
        Cmp::Gt => o.is_gt(),
        Cmp::Le => o.is_le(),
        Cmp::Ge => o.is_ge(),
    })
}

/// The key of a ground term: as printed, without spaces.
pub(crate) fn term_key(term: &Term) -> String {
    match term {
        Term::Number(n) => n.to_string(),
        Term::Str(_) => term.to_string(),
        Term::Name { name, args } => app_key(name, args),
    }
}

fn app_key(name: &str, args: &[Term]) -> String {
    if args.is_empty() {
        return name.to_owned();
    }
    let args: Vec<String> = args.iter().map(term_key).collect();
    format!("{name}({})", args.join(","))
}

fn region_key(r: &Region) -> String {
    r.to_string()
}
