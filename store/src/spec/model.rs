//! The specs as plain Rust types: what a transformation or target spec says (seed Defs. 17, 19;
//! DyKnow-ROS Ch. 5.3.1).

use serde::Serialize;

/// The two kinds of spec the knowledge service stores, one named graph each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SpecKind {
    /// A transformation spec (the seed's AddTransformation).
    Transformation,
    /// A target spec (the seed's AddTarget).
    Target,
}

impl SpecKind {
    /// `"transformation"` or `"target"`.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Transformation => "transformation",
            Self::Target => "target",
        }
    }
}

/// A tag: a value in the seed's simple tag language and/or a concept IRI describing it.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub struct Tag {
    /// `dyknow:hasValue`, e.g. `"pose(piff)"`.
    pub value: Option<String>,
    /// `dyknow:hasTagDescription`, a concept IRI.
    pub description: Option<String>,
}

impl Tag {
    /// The tag as one string: its value, or else its description IRI in angle brackets.
    pub fn display(&self) -> String {
        match (&self.value, &self.description) {
            (Some(v), _) => v.clone(),
            (None, Some(d)) => format!("<{d}>"),
            (None, None) => String::new(),
        }
    }
}

/// Whether a port receives or transmits a stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum PortDirection {
    /// `dyknow:InPort`.
    In,
    /// `dyknow:OutPort`.
    Out,
}

/// A port of a transformation, identified by its name within the transformation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Port {
    /// The port's name (`dyknow:hasName` / `dyknow:hasPortName`).
    pub name: String,
    /// In or out.
    pub direction: PortDirection,
    /// The port's tags (at least one).
    pub tags: Vec<Tag>,
}

/// A transformation spec (seed Def. 17; DyKnow-ROS Listing 5.3).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TransformationSpec {
    /// The label, the seed's *tid*; identity of the spec.
    pub label: String,
    /// The IRI of the transformation resource in the model.
    pub iri: String,
    /// In ports, in document order.
    pub inputs: Vec<Port>,
    /// Out ports, in document order.
    pub outputs: Vec<Port>,
    /// Estimated labour: the cost of one spawn (default 1.0).
    pub labour: f64,
    /// Estimated upkeep: the cost per time unit of one running CU (default 1.0).
    pub upkeep: f64,
    /// `dkros:hasType`, what kind of program an executor runs (e.g. `"nodelet"`).
    pub exec_type: Option<String>,
    /// `dkros:hasSource`, the program an executor runs.
    pub source: Option<String>,
    /// `dkros:hasParam`, in document order.
    pub params: Vec<Param>,
    /// `dkros:hasExecutor`, the executor the transformation is pinned to.
    pub executor: Option<String>,
}

impl TransformationSpec {
    /// What an executor runs for it: type, source, parameters (in any order) and pinned
    /// executor. Two specs with equal implementations run the same program the same way;
    /// costs, ports and tags are not part of it.
    pub fn implementation(&self) -> Implementation {
        let mut params: Vec<Param> = self.params.clone();
        params.sort_by(|a, b| {
            (&a.name, &a.value, &a.datatype, &a.param_type).cmp(&(
                &b.name,
                &b.value,
                &b.datatype,
                &b.param_type,
            ))
        });
        Implementation {
            exec_type: self.exec_type.clone(),
            source: self.source.clone(),
            params,
            executor: self.executor.clone(),
        }
    }
}

/// What an executor runs for a transformation ([`TransformationSpec::implementation`]): a
/// CU started from one implementation does not run another (the seed, Ch. 4: a CU whose
/// transformation changed behaves in no defined way and requires removal).
#[derive(Debug, Clone, PartialEq)]
pub struct Implementation {
    exec_type: Option<String>,
    source: Option<String>,
    params: Vec<Param>,
    executor: Option<String>,
}

/// A parameter of a transformation (`dkros:hasParam`: `dyknow:hasName`, `dyknow:hasValue`,
/// optional `dkros:hasType`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Param {
    /// Its name.
    pub name: String,
    /// The lexical form of its value.
    pub value: String,
    /// The local name of the value's XSD datatype (`integer`, `boolean`, `string`, …).
    pub datatype: String,
    /// Its `dkros:hasType`, if given.
    #[serde(rename = "type")]
    pub param_type: Option<String>,
}

/// A target spec (seed Def. 19; DyKnow-ROS Listing 5.4).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetSpec {
    /// The label, the seed's *qid*; identity of the spec.
    pub label: String,
    /// The IRI of the target resource in the model.
    pub iri: String,
    /// The name of the channel on which the described stream must appear.
    pub channel: String,
    /// The tags describing the stream.
    pub tags: Vec<Tag>,
}

/// A spec of either kind.
#[derive(Debug, Clone, PartialEq)]
pub enum Spec {
    /// A transformation.
    Transformation(TransformationSpec),
    /// A target.
    Target(TargetSpec),
}

impl Spec {
    /// The spec's label.
    pub fn label(&self) -> &str {
        match self {
            Self::Transformation(t) => &t.label,
            Self::Target(t) => &t.label,
        }
    }
    /// The spec's kind.
    pub fn kind(&self) -> SpecKind {
        match self {
            Self::Transformation(_) => SpecKind::Transformation,
            Self::Target(_) => SpecKind::Target,
        }
    }
}
