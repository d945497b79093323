#![doc = include_str!("../README.md")]

pub mod allocator;
mod app;
pub mod cli;
pub mod dataplane;
mod error;
pub mod group_cli;
pub mod groups;
mod json_body;
mod metrics;
mod negotiate;
mod openapi;
pub mod routes;
mod watchdog;

pub use app::{AppState, ServerConfig, app};
pub use error::{ApiError, ErrorBody};
pub use openapi::ApiDoc;
