//! MSTL, the seed's Metric Spatio-Temporal Logic (Ch. 3.2): its syntax ([`syntax`]), parser
//! ([`parse`]) and printer (`Display`), as `../shared/contract/mstl.md` fixes them. Knows
//! nothing of RDF.
//!
//! ```
//! let f = dyknow_mstl::parse("forall x in UAV: always (altitude(x) > 50)").unwrap();
//! assert_eq!(f.to_string(), "forall x in UAV: (always altitude(x) > 50)");
//! assert_eq!(dyknow_mstl::parse(&f.to_string()).unwrap(), f);
//! ```

mod parser;
mod printer;
pub mod syntax;

pub use parser::{MAX_DEPTH, MAX_LEN, MAX_TREE_DEPTH, ParseError, is_keyword, parse};
pub use syntax::{Atom, Cmp, Domain, Formula, Interval, Rcc8, Region, Term};
