//! RCC-8 qualitative spatial reasoning (seed Ch. 3.1.1, 3.3): relations as 8-bit sets with
//! precomputed composition and converse ([`Relation`]), constraint networks with their
//! algebraic closure and exact consistency ([`Network`]), the static/dynamic split of
//! Ch. 3.4.2 ([`Split`]), intertemporal inference through
//! landmarks in extended spatial relation matrices ([`Extended`], Ch. 3.3.3), GQR's CSP file
//! format ([`gqr`]), and seeded random instances ([`generate`]). Knows nothing of RDF.
//!
//! ```
//! use dyknow_rcc8::{Network, Relation};
//! // The seed's Example 7, busy student: NTPP(student, office), DC(canteen, office).
//! let (student, office, canteen) = (0, 1, 2);
//! let mut n = Network::new(3);
//! n.set(student, office, Relation::NTPP);
//! n.set(canteen, office, Relation::DC);
//! n.algebraic_closure().unwrap();
//! assert_eq!(n.get(student, canteen), Relation::DC);
//! ```

pub mod generate;
pub mod gqr;
mod landmark;
mod network;
mod relation;
mod split;

pub use landmark::{Extended, LandmarkConflict};
pub use network::{Inconsistent, Network};
pub use relation::{BASE_COMPOSITION, Relation};
pub use split::Split;
