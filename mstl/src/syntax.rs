//! The abstract syntax of MSTL (contract `mstl.md`; seed Ch. 3.2).

/// A formula.
#[derive(Debug, Clone, PartialEq)]
pub enum Formula {
    /// `true`.
    True,
    /// `false`.
    False,
    /// An atom.
    Atom(Atom),
    /// `!φ`.
    Not(Box<Formula>),
    /// `φ && ψ`.
    And(Box<Formula>, Box<Formula>),
    /// `φ || ψ`.
    Or(Box<Formula>, Box<Formula>),
    /// `φ -> ψ`.
    Implies(Box<Formula>, Box<Formula>),
    /// `φ <-> ψ`.
    Iff(Box<Formula>, Box<Formula>),
    /// `always[a,b] φ`.
    Always(Interval, Box<Formula>),
    /// `eventually[a,b] φ`.
    Eventually(Interval, Box<Formula>),
    /// `φ U[a,b] ψ`.
    Until(Interval, Box<Formula>, Box<Formula>),
    /// `next^k φ` (k ≥ 1).
    Next(u32, Box<Formula>),
    /// `forall x in D: φ`.
    Forall(String, Domain, Box<Formula>),
    /// `exists x in D: φ`.
    Exists(String, Domain, Box<Formula>),
}

/// An atom.
#[derive(Debug, Clone, PartialEq)]
pub enum Atom {
    /// `R(x, y)`: an RCC-8 relation between two regions.
    Spatial {
        /// The relation.
        relation: Rcc8,
        /// The first region.
        left: Region,
        /// The second region.
        right: Region,
    },
    /// `t1 op t2`.
    Compare {
        /// The left term.
        left: Term,
        /// The comparator.
        op: Cmp,
        /// The right term.
        right: Term,
    },
    /// `P` or `P(t1, …, tn)`: a predicate.
    Predicate {
        /// The predicate's name.
        name: String,
        /// Its arguments.
        args: Vec<Term>,
    },
}

/// A term.
#[derive(Debug, Clone, PartialEq)]
pub enum Term {
    /// A number.
    Number(f64),
    /// A string.
    Str(String),
    /// A constant, a variable (inside its quantifier), or a function application `f(t, …)`.
    Name {
        /// The name.
        name: String,
        /// The arguments (empty for a constant or a variable).
        args: Vec<Term>,
    },
}

/// A region term: a region name at a state offset (`next^k r` is `offset = k`, `prev^k r` is
/// `offset = -k`).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Region {
    /// States ahead (positive) or back (negative).
    pub offset: i32,
    /// The region's name (a constant or a quantified variable).
    pub name: String,
}

/// A quantifier's domain.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Domain {
    /// A named domain, given by the trace header or `--domain`.
    Named(String),
    /// An explicit set of constants.
    Set(Vec<String>),
}

/// A metric interval `[lo, hi]` in milliseconds; `hi = None` is `inf`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Interval {
    /// The lower bound.
    pub lo: u64,
    /// The upper bound, `None` for `inf`.
    pub hi: Option<u64>,
}

impl Interval {
    /// `[0, inf]`, what an operator without an interval means.
    pub const UNBOUNDED: Self = Self { lo: 0, hi: None };
}

/// A comparator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Cmp {
    /// `=`.
    Eq,
    /// `!=`.
    Ne,
    /// `<`.
    Lt,
    /// `>`.
    Gt,
    /// `<=`.
    Le,
    /// `>=`.
    Ge,
}

impl Cmp {
    /// The comparator's symbol.
    pub const fn symbol(self) -> &'static str {
        match self {
            Self::Eq => "=",
            Self::Ne => "!=",
            Self::Lt => "<",
            Self::Gt => ">",
            Self::Le => "<=",
            Self::Ge => ">=",
        }
    }
}

/// The eight RCC-8 base relations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Rcc8 {
    /// Disconnected.
    Dc,
    /// Externally connected.
    Ec,
    /// Partially overlapping.
    Po,
    /// Equal.
    Eq,
    /// Tangential proper part.
    Tpp,
    /// Non-tangential proper part.
    Ntpp,
    /// Inverse of TPP.
    Tppi,
    /// Inverse of NTPP.
    Ntppi,
}

impl Rcc8 {
    /// The canonical spelling (`rcc8.md`).
    pub const fn name(self) -> &'static str {
        match self {
            Self::Dc => "DC",
            Self::Ec => "EC",
            Self::Po => "PO",
            Self::Eq => "EQ",
            Self::Tpp => "TPP",
            Self::Ntpp => "NTPP",
            Self::Tppi => "TPPI",
            Self::Ntppi => "NTPPI",
        }
    }

    /// The converse relation: `R(a, b)` holds iff `R.converse()(b, a)` does.
    pub const fn converse(self) -> Self {
        match self {
            Self::Tpp => Self::Tppi,
            Self::Ntpp => Self::Ntppi,
            Self::Tppi => Self::Tpp,
            Self::Ntppi => Self::Ntpp,
            symmetric => symmetric,
        }
    }

    /// Reads a relation name: the canonical spellings, `TPPi`, `NTPPi`, and the seed's `NTTP`
    /// (a formula may also write `TPP^-1` and `NTPP^-1`, which the parser reads).
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "DC" => Self::Dc,
            "EC" => Self::Ec,
            "PO" => Self::Po,
            "EQ" => Self::Eq,
            "TPP" => Self::Tpp,
            "NTPP" | "NTTP" => Self::Ntpp,
            "TPPI" | "TPPi" => Self::Tppi,
            "NTPPI" | "NTPPi" | "NTTPI" | "NTTPi" => Self::Ntppi,
            _ => return None,
        })
    }
}
