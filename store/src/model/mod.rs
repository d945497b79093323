//! The DyKnow model (`dyknow-engine`'s types) in the knowledge base: the environment ⟨CU, F,
//! T⟩ and the candidate table read with SPARQL ([`load`], [`SpecCache`]), computation units
//! written as one graph each ([`cu_triples`], [`delta`]) so `dependsOn` follows every change
//! set, change-set records ([`change_set_triples`], [`change_sets`]) and learned cost
//! estimates ([`statistics_triples`], [`learned`]). Every SPARQL query of the domain is in
//! [`queries`].

mod candidates;
pub(crate) mod queries;
mod read;
mod triples;

pub use read::{
    ChangeSetRecords, CuSnapshot, Iris, Loaded, SpecCache, UnreadableRecord, candidates,
    change_sets, cus_by_query, learned, load, reserved_names,
};
pub use triples::{
    Delta, HISTORY_RESOURCE, change_set_triples, cu_triples, delta, history_triples, resync,
    split_environment, statistics_triples,
};
