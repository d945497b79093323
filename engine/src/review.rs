//! One review (seed Ch. 4.3, Def. 36): EXPLORE on the environment, COMPILE the best plan into
//! a change set, and the environment after it (ε ⊗ δ, Def. 22). Writes nothing: the
//! life-cycle records and applies the change set.

use crate::candidates::Candidates;
use crate::compile::{Compiled, compile};
use crate::explore::{ExploreOptions, explore};
use crate::ids::Ids;
use crate::model::Environment;

/// What one review decides.
#[derive(Debug, Clone)]
pub struct Reviewed {
    /// The change set's actions, cost and what could not be satisfied.
    pub compiled: Compiled,
    /// The environment after the change set (ε ⊗ δ).
    pub after: Environment,
}

/// EXPLORE (Algorithms 4–5), COMPILE (Algorithm 6) and update ⊗ on `env`, minting fresh names
/// from `ids`.
pub fn review(
    env: &Environment,
    candidates: &Candidates,
    options: &ExploreOptions,
    ids: &mut Ids,
) -> Reviewed {
    let exploration = explore(env, candidates, options);
    let compiled = compile(env, &exploration, options, ids);
    let mut after = env.clone();
    after.apply(&compiled.actions);
    Reviewed { compiled, after }
}
