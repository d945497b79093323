//! DyKnow's engine (seed Ch. 4), free of RDF: the DyKnow model ([`model`]: transformations,
//! computation units, targets, environments, actions, validity), typed identities and the
//! minting of fresh names ([`Ids`]), the candidate table ([`candidates`]), EXPLORE/EXPAND
//! ([`explore()`], Algorithms 4–5), COMPILE ([`compile()`], Algorithm 6), one [`review()`],
//! change sets ([`ChangeSet`], the contract's change set JSON both ways) and learned cost
//! estimates ([`Learned`], Ch. 5.3.2). The knowledge base (`dyknow-store`) reads and writes
//! these types as RDF; the life-cycle (`dyknow-lifecycle`) runs reviews; an executor needs
//! nothing else from DyKnow to apply a change set.
//!
//! ```
//! use dyknow_engine::{Candidates, Environment, ExploreOptions, Ids, Provider, Target, Transformation, review};
//!
//! let mut env = Environment::default();
//! env.library.insert("camera".into(), Transformation {
//!     tid: "camera".into(), inputs: vec![], outputs: vec!["image".into()], labour: 1.0, upkeep: 1.0,
//! });
//! env.targets.insert("q".into(), Target { qid: "q".into(), channel: "/image".into() });
//! let mut candidates = Candidates::default();
//! candidates.add_target("q", Provider { tid: "camera".into(), port: 0 });
//! let reviewed = review(&env, &candidates, &ExploreOptions::default(), &mut Ids::after(&env));
//! assert_eq!(reviewed.compiled.cost.total, 11.0); // labour 1 + horizon 10 × upkeep 1
//! assert!(reviewed.after.invalidities(&candidates).is_empty());
//! ```

pub mod candidates;
mod change_set;
mod compile;
mod estimate;
pub mod explore;
mod ids;
pub mod model;
mod review;

pub use candidates::{Candidates, Provider};
pub use change_set::{
    ActionFailure, Cause, ChangeSet, ChangeSetStatus, CuOutcome, CuOutcomeState, NTriplesDelta,
    rfc3339,
};
pub use compile::{Compiled, CostSummary, compile};
pub use estimate::{CostKind, Estimate, Learned, MAX_COST, valid_cost};
pub use explore::{Cost, Exploration, ExploreOptions, Plan, ProbeOptions, explore, lower_bound};
pub use ids::{ChangeSetId, Channel, Cid, Ids, Qid, Tid};
pub use model::{Action, ComputationUnit, Environment, Invalidity, Target, Transformation};
pub use review::{Reviewed, review};
