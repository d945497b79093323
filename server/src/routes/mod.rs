//! The route modules, one per part of the contract's HTTP API.

pub mod executors;
pub mod groups;
pub mod model;
pub mod ontology;
pub mod ops;
pub mod reconfig;
pub mod sparql;
pub mod specs;
pub mod ui;
