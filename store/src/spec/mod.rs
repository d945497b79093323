//! Transformation and target specs: the Rust model, and their extraction from RDF documents.

mod extract;
mod model;

pub(crate) use extract::spec_from_graph;
pub use extract::{
    DEFAULT_COST, ExtractedDocument, ExtractedSpec, MAX_LABEL_BYTES, MAX_PORTS, MAX_TAGS,
    SpecClasses, extract_specs, has_xml_local_name, in_dyknow_namespaces, xml_safe,
};
pub use model::{
    Implementation, Param, Port, PortDirection, Spec, SpecKind, Tag, TargetSpec, TransformationSpec,
};
