//! DyKnow's engine (seed Ch. 4): the DyKnow model ([`model`]), the candidate table
//! ([`candidates`]), EXPLORE/EXPAND ([`explore()`], Algorithms 4–5) and COMPILE ([`compile()`],
//! Algorithm 6), and the engine over the knowledge base ([`knowledge`]): environments read with
//! SPARQL, change sets written back as graph deltas.
//!
//! ```
//! use dyknow_engine::{Candidates, Environment, ExploreOptions, Ids, Provider, Target, Transformation, compile, explore};
//!
//! let mut env = Environment::default();
//! env.library.insert("camera".into(), Transformation {
//!     tid: "camera".into(), inputs: vec![], outputs: vec!["image".into()], labour: 1.0, upkeep: 1.0,
//! });
//! env.targets.insert("q".into(), Target { qid: "q".into(), channel: "/image".into() });
//! let mut candidates = Candidates::default();
//! candidates.add_target("q", Provider { tid: "camera".into(), port: 0 });
//! let options = ExploreOptions::default();
//! let exploration = explore(&env, &candidates, &options);
//! let change_set = compile(&env, &exploration, &options, &mut Ids::after(&env));
//! assert_eq!(change_set.cost.total, 11.0); // labour 1 + horizon 10 × upkeep 1
//! ```

pub mod candidates;
mod change_set;
mod compile;
mod error;
pub mod explore;
pub mod knowledge;
pub mod model;

pub use candidates::{Candidates, Provider};
pub use change_set::{Cause, ChangeSet, NTriplesDelta, rfc3339};
pub use compile::{Compiled, CostSummary, Ids, compile};
pub use error::EngineError;
pub use explore::{Cost, Exploration, ExploreOptions, Plan, explore};
pub use model::{Action, ComputationUnit, Environment, Invalidity, Target, Transformation};
