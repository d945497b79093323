//! The manager's daemon of DyKnow (seed Ch. 4.3 and 5.3.2): the configuration life-cycle.
//! [`Manager`] owns the configuration of one knowledge base: it takes [`Perturbation`]s,
//! runs reviews (EXPLORE/COMPILE of `dyknow-engine`) at the end of stable intervals and after
//! short-term negative perturbations, takes Spawn and Destroy requests, keeps the change-set
//! history and the learned cost estimates, and hands every change set to an [`Executor`],
//! which applies it to the running system ([`ModelOnly`]: none). Every path that changes the
//! configuration holds one lock from reading the environment to recording the outcome.
//!
//! ```
//! use std::sync::Arc;
//! use dyknow_lifecycle::{Manager, ModelOnly, Perturbation, Settings};
//! use dyknow_store::{InputFormat, KnowledgeBase};
//!
//! let kb = Arc::new(KnowledgeBase::in_memory()?);
//! kb.load_document(br#"
//!   @prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .
//!   @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
//!   [] a dyknow:Transformation ; rdfs:label "camera" ;
//!      dyknow:hasOutPort [ dyknow:hasName "image" ; dyknow:hasTag [ dyknow:hasValue "Image" ] ] .
//!   [] a dyknow:Target ; rdfs:label "q" ; dyknow:hasChannel [ dyknow:hasChannelName "/image" ] ;
//!      dyknow:hasTag [ dyknow:hasValue "Image" ] .
//! "#, InputFormat::Turtle)?;
//! let manager = Manager::new(kb, Arc::new(ModelOnly), Settings::default())?;
//! manager.report(Perturbation::TargetAdded { target: "q".into() })?;
//! let change_set = manager.review()?.expect("a camera CU for q");
//! assert_eq!(change_set.cost.total, 11.0); // labour 1 + horizon 10 × upkeep 1
//! assert_eq!(manager.load()?.env.cus.len(), 1);
//! # Ok::<_, Box<dyn std::error::Error>>(())
//! ```

mod error;
mod executor;
pub mod fleet;
mod history;
mod manager;
mod perturbation;
mod schedule;

pub use error::LifecycleError;
pub use executor::{Applied, CuView, Executor, ModelOnly, ReportedCu};
pub use fleet::{ExecutorSummary, Fleet, FleetEvent, appeared, executor_event};
pub use manager::{DEFAULT_HISTORY_LIMIT, Manager, Observation, Settings, SpawnRequest};
pub use perturbation::Perturbation;
pub use schedule::{Phase, Status};
