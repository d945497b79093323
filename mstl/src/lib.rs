//! MSTL, the seed's Metric Spatio-Temporal Logic (Ch. 3.2), as `../shared/contract/mstl.md`
//! fixes it: its syntax ([`syntax`]), parser ([`parse`]) and printer (`Display`); progression
//! of formulas over state streams (seed Algorithm 3, extended) by a [`Monitor`]; the spatial
//! state of a stream taken one state at a time ([`StateStream`]: RCC-8 closure, static regions,
//! landmarks); and the trace files of `dyknow check` ([`trace`]). Knows nothing of RDF.
//!
//! ```
//! let f = dyknow_mstl::parse("forall x in UAV: always (altitude(x) > 50)").unwrap();
//! assert_eq!(f.to_string(), "forall x in UAV: (always altitude(x) > 50)");
//! assert_eq!(dyknow_mstl::parse(&f.to_string()).unwrap(), f);
//! ```
//!
//! Layout: `syntax`, `parser`, `printer` (the language); `dag` (hash-consed formula nodes
//! with simplification and reclamation); `compile` (syntax to nodes, the `next` rewritings);
//! `ground` (the ground symbols a group's streams must carry, [`ground_symbols`]);
//! `atom` (atoms against a state's [`Valuation`]); `progress` (Algorithm 3); `monitor` (a
//! group of formulas over one stream, verdicts); `stream` (a state stream's spatial state,
//! one [`State`] at a time: each state's algebraic closure, the static/dynamic split of
//! Ch. 3.4.2, the landmarks and extended matrices of Ch. 3.3.3 for atoms over `prev` regions,
//! [`StreamError`]); `trace` (JSON-lines traces and verdicts, a thin adapter over `stream`).

mod atom;
mod compile;
mod dag;
mod ground;
mod monitor;
mod parser;
mod printer;
mod progress;
mod stream;
pub mod syntax;
pub mod trace;

pub use atom::{Valuation, Value};
pub use compile::{
    CompileError, Domains, MAX_GROUND_ATOMS, check_constant, ground_atoms, ground_instances,
};
pub use ground::{Symbol, ground_symbols};
pub use monitor::{Monitor, StepError, Verdict};
pub use parser::{MAX_DEPTH, MAX_LEN, MAX_TREE_DEPTH, ParseError, is_keyword, parse};
pub use stream::{SpatialConstraints, State, StateStream, StateValue, StreamError};
pub use syntax::{Atom, Cmp, Domain, Formula, Interval, Rcc8, Region, Term};

/// A truth value of Kleene's strong three-valued logic.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Truth {
    /// False.
    False,
    /// Unknown: the states so far (or a missing value) do not decide it.
    Unknown,
    /// True.
    True,
}

impl Truth {
    /// `"true"`, `"false"` or `"unknown"`, as verdict lines spell it.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::False => "false",
            Self::Unknown => "unknown",
            Self::True => "true",
        }
    }
}

impl std::fmt::Display for Truth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}
