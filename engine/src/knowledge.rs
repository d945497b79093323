//! The engine over the knowledge base: the environment and the candidate table read with
//! SPARQL, and change sets written back as graph deltas on the environment graphs (one graph
//! per CU), so `dependsOn` follows every change set.

use std::collections::{BTreeMap, BTreeSet, HashSet};

use dyknow_store::KnowledgeBase;
use dyknow_store::graphs::encode;
use dyknow_store::oxigraph::model::vocab::{rdf, xsd};
use dyknow_store::oxigraph::model::{Literal, NamedNode, Term, Triple};
use dyknow_store::spec::{Spec, SpecKind};

use crate::candidates::{Candidates, Provider};
use crate::error::EngineError;
use crate::model::{ComputationUnit, Environment, Target, Tid, Transformation};

const DYKNOW: &str = "http://www.dyknow.eu/ontology/dyknow#";
const DKROS: &str = "http://www.dyknow.eu/ontology/dyknow-ros#";
/// The prefix of CU resources.
pub const CU_PREFIX: &str = "urn:dyknow:cu:";
/// The prefix of channel resources.
pub const CHANNEL_PREFIX: &str = "urn:dyknow:channel:";
/// The environment part (graph name) of a CU: `cu:<name>`.
pub fn cu_part(cid: &str) -> String {
    format!("cu:{cid}")
}

fn dk(local: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{DYKNOW}{local}"))
}
fn dkros(local: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{DKROS}{local}"))
}
fn cu_iri(cid: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{CU_PREFIX}{}", encode(cid)))
}
/// The IRI of channel `name`.
pub fn channel_iri(name: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{CHANNEL_PREFIX}{}", encode(name)))
}

/// The IRIs of the library's resources, for writing CUs.
#[derive(Debug, Clone, Default)]
pub struct Iris {
    /// tid → transformation IRI.
    pub transformations: BTreeMap<Tid, NamedNode>,
    /// (tid, port name) → in port IRI.
    pub in_ports: BTreeMap<(Tid, String), NamedNode>,
    /// (tid, port name) → out port IRI.
    pub out_ports: BTreeMap<(Tid, String), NamedNode>,
}

/// What the engine reads from the knowledge base.
#[derive(Debug, Clone, Default)]
pub struct Loaded {
    /// The environment ⟨CU, F, T⟩.
    pub env: Environment,
    /// The candidate table (~).
    pub candidates: Candidates,
    /// The IRIs of transformations and ports.
    pub iris: Iris,
}

fn literal(term: &Option<Term>) -> Option<String> {
    match term {
        Some(Term::Literal(l)) => Some(l.value().to_owned()),
        _ => None,
    }
}

fn named(term: &Option<Term>) -> Option<NamedNode> {
    match term {
        Some(Term::NamedNode(n)) => Some(n.clone()),
        _ => None,
    }
}

/// The candidate table in one SPARQL query: every (consumer in port or target, producer out
/// port) pair whose tags satisfy `i ~ o` (`specs.md`: equal values; the out description is
/// the in description or a sub-concept of it after reasoning; `dyknow:similarTo` either way).
pub const CANDIDATE_QUERY: &str = r#"PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#>
PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>
SELECT DISTINCT ?consumer ?inPort ?target ?producer ?outPort WHERE {
  {
    GRAPH ?cg { ?ctf rdfs:label ?consumer ; dyknow:hasInPort ?ip . ?ip dyknow:hasName ?inPort ; dyknow:hasTag ?it . }
    FILTER(STRSTARTS(STR(?cg), "urn:dyknow:graph:transformation:"))
  } UNION {
    GRAPH ?qg { ?q rdfs:label ?target ; dyknow:hasTag ?it . }
    FILTER(STRSTARTS(STR(?qg), "urn:dyknow:graph:target:"))
  }
  GRAPH ?pg { ?ptf rdfs:label ?producer ; dyknow:hasOutPort ?op . ?op dyknow:hasName ?outPort ; dyknow:hasTag ?ot . }
  FILTER(STRSTARTS(STR(?pg), "urn:dyknow:graph:transformation:"))
  {
    ?it dyknow:hasValue ?v . ?ot dyknow:hasValue ?v .
  } UNION {
    ?it dyknow:hasTagDescription ?d . ?ot dyknow:hasTagDescription ?e . ?e rdfs:subClassOf* ?d .
  } UNION {
    ?it dyknow:hasTagDescription ?d . ?ot dyknow:hasTagDescription ?e .
    { ?d dyknow:similarTo ?e } UNION { ?e dyknow:similarTo ?d }
  }
}"#;

/// The CUs of the environment graphs, one row per port binding. A CU whose transformation was
/// deregistered keeps the transformation's IRI as its tid (not in the library: invalid, so the
/// next review destroys it unless it is protected).
const CU_QUERY: &str = r#"PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#>
PREFIX dkros: <http://www.dyknow.eu/ontology/dyknow-ros#>
PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>
SELECT ?name ?tid ?protected ?dir ?port ?channel WHERE {
  GRAPH ?g {
    ?cu a dyknow:ComputationUnit ; dyknow:hasName ?name ; dyknow:instanceOf ?tf .
    OPTIONAL { ?cu dkros:isProtected ?protected }
  }
  FILTER(STRSTARTS(STR(?g), "urn:dyknow:graph:environment:"))
  OPTIONAL { ?tf rdfs:label ?label }
  BIND(COALESCE(?label, STR(?tf)) AS ?tid)
  OPTIONAL {
    GRAPH ?g {
      {
        ?cu dyknow:hasSubscription ?s . ?s dyknow:toPort ?p .
        OPTIONAL { ?s dyknow:hasChannel ?ch . ?ch dyknow:hasChannelName ?channel }
        BIND("in" AS ?dir)
      } UNION {
        ?cu dkros:hasPublication ?s . ?s dkros:publishesPort ?p .
        OPTIONAL { ?s dkros:onChannel ?ch . ?ch dyknow:hasChannelName ?channel }
        BIND("out" AS ?dir)
      }
    }
    ?p dyknow:hasName ?port .
  }
}"#;

/// Reads the environment, the candidate table and the library's IRIs.
pub fn load(kb: &KnowledgeBase) -> Result<Loaded, EngineError> {
    SpecCache::default().load(kb)
}

/// What is derived from specs alone (library with the specs' estimates, targets, IRIs, the
/// candidate table), cached against [`KnowledgeBase::spec_generation`]: a review after a CU
/// crash reads only the CUs and the learned estimates again.
#[derive(Debug, Default)]
pub struct SpecCache {
    cached: std::sync::Mutex<Option<(u64, Loaded)>>,
}

impl SpecCache {
    /// [`load`], reusing the spec-derived part while no spec or extension changed.
    pub fn load(&self, kb: &KnowledgeBase) -> Result<Loaded, EngineError> {
        self.load_with(kb, None)
    }

    /// [`SpecCache::load`] with the learned estimates given (the caller keeps them), instead
    /// of read from the store.
    pub fn load_with(
        &self,
        kb: &KnowledgeBase,
        known: Option<&Learned>,
    ) -> Result<Loaded, EngineError> {
        let generation = kb.spec_generation();
        let hit = self
            .cached
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .as_ref()
            .filter(|(g, _)| *g == generation)
            .map(|(_, l)| l.clone());
        let mut loaded = match hit {
            Some(l) => l,
            None => {
                let l = load_specs(kb)?;
                *self
                    .cached
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner) =
                    Some((generation, l.clone()));
                l
            }
        };
        match known {
            Some(l) => l.apply(&mut loaded.env),
            None => learned(kb)?.apply(&mut loaded.env),
        }
        load_cus(kb, &mut loaded)?;
        Ok(loaded)
    }
}

/// The spec-derived part of [`Loaded`] (no CUs, the specs' own estimates).
fn load_specs(kb: &KnowledgeBase) -> Result<Loaded, EngineError> {
    let mut loaded = Loaded::default();
    for spec in kb.specs(SpecKind::Transformation)? {
        let Spec::Transformation(t) = spec else {
            continue;
        };
        loaded
            .iris
            .transformations
            .insert(t.label.clone(), NamedNode::new_unchecked(t.iri.clone()));
        loaded.env.library.insert(
            t.label.clone(),
            Transformation {
                tid: t.label.clone(),
                inputs: t.inputs.iter().map(|p| p.name.clone()).collect(),
                outputs: t.outputs.iter().map(|p| p.name.clone()).collect(),
                labour: t.labour,
                upkeep: t.upkeep,
            },
        );
    }
    for spec in kb.specs(SpecKind::Target)? {
        let Spec::Target(t) = spec else {
            continue;
        };
        loaded.env.targets.insert(
            t.label.clone(),
            Target {
                qid: t.label.clone(),
                channel: t.channel.clone(),
            },
        );
    }
    // Port IRIs.
    let ports = kb.select(
        r#"PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#>
PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>
SELECT ?tid ?dir ?name ?port WHERE {
  GRAPH ?g {
    ?tf rdfs:label ?tid .
    { ?tf dyknow:hasInPort ?port BIND("in" AS ?dir) } UNION { ?tf dyknow:hasOutPort ?port BIND("out" AS ?dir) }
    ?port dyknow:hasName ?name .
  }
  FILTER(STRSTARTS(STR(?g), "urn:dyknow:graph:transformation:"))
}"#,
    )?;
    for row in ports {
        let (Some(tid), Some(dir), Some(name), Some(port)) = (
            literal(&row[0]),
            literal(&row[1]),
            literal(&row[2]),
            named(&row[3]),
        ) else {
            continue;
        };
        let map = if dir == "in" {
            &mut loaded.iris.in_ports
        } else {
            &mut loaded.iris.out_ports
        };
        map.insert((tid, name), port);
    }
    loaded.candidates = candidates(kb, &loaded.env)?;
    Ok(loaded)
}

/// Reads the CUs into `loaded`.
fn load_cus(kb: &KnowledgeBase, loaded: &mut Loaded) -> Result<(), EngineError> {
    for row in kb.select(CU_QUERY)? {
        let (Some(name), Some(tid)) = (literal(&row[0]), literal(&row[1])) else {
            continue;
        };
        let protected = literal(&row[2]).is_some_and(|v| v == "true" || v == "1");
        let cu = loaded
            .env
            .cus
            .entry(name.clone())
            .or_insert_with(|| ComputationUnit {
                cid: name.clone(),
                tid: tid.clone(),
                inputs: BTreeMap::new(),
                outputs: BTreeMap::new(),
                protected,
            });
        if let (Some(dir), Some(port)) = (literal(&row[3]), literal(&row[4])) {
            let channel = literal(&row[5]);
            if dir == "in" {
                cu.inputs.insert(port, channel);
            } else {
                cu.outputs.insert(port, channel);
            }
        }
    }
    // Every port of a CU's transformation is listed, bound or not.
    let library = loaded.env.library.clone();
    for cu in loaded.env.cus.values_mut() {
        if let Some(tf) = library.get(&cu.tid) {
            for p in &tf.inputs {
                cu.inputs.entry(p.clone()).or_insert(None);
            }
            for p in &tf.outputs {
                cu.outputs.entry(p.clone()).or_insert(None);
            }
        }
    }
    Ok(())
}

/// The candidate table of `env`'s library and targets ([`CANDIDATE_QUERY`]).
pub fn candidates(kb: &KnowledgeBase, env: &Environment) -> Result<Candidates, EngineError> {
    let mut table = Candidates::default();
    let index = |tid: &str, name: &str, outputs: bool| {
        env.library.get(tid).and_then(|t| {
            let ports = if outputs { &t.outputs } else { &t.inputs };
            ports.iter().position(|p| p == name)
        })
    };
    for row in kb.select(CANDIDATE_QUERY)? {
        let (Some(producer), Some(out_port)) = (literal(&row[3]), literal(&row[4])) else {
            continue;
        };
        let Some(port) = index(&producer, &out_port, true) else {
            continue;
        };
        let provider = Provider {
            tid: producer,
            port,
        };
        match (literal(&row[0]), literal(&row[1]), literal(&row[2])) {
            (Some(consumer), Some(in_port), _) => {
                if let Some(i) = index(&consumer, &in_port, false) {
                    table.add_input(&consumer, i, provider);
                }
            }
            (_, _, Some(target)) => table.add_target(&target, provider),
            _ => {}
        }
    }
    Ok(table)
}

/// The triples of one CU (`specs.md`, "Computation units in the model"): its types, name,
/// transformation, upkeep, protection, one subscription per bound in port (with the CU and
/// out port that publish on the channel) and one publication per bound out port.
pub fn cu_triples(cu: &ComputationUnit, env: &Environment, iris: &Iris) -> Vec<Triple> {
    let me = cu_iri(&cu.cid);
    let mut out = vec![
        Triple::new(me.clone(), rdf::TYPE, dk("ComputationUnit")),
        Triple::new(me.clone(), rdf::TYPE, dkros("Nodelet")),
        Triple::new(
            me.clone(),
            dk("hasName"),
            Literal::new_simple_literal(&cu.cid),
        ),
    ];
    if let Some(tf) = iris.transformations.get(&cu.tid) {
        out.push(Triple::new(me.clone(), dk("instanceOf"), tf.clone()));
    }
    if cu.protected {
        out.push(Triple::new(
            me.clone(),
            dkros("isProtected"),
            Literal::new_typed_literal("true", xsd::BOOLEAN),
        ));
    }
    if let Some(tf) = env.library.get(&cu.tid) {
        let cost = NamedNode::new_unchecked(format!("{}/upkeep", me.as_str()));
        out.push(Triple::new(me.clone(), dk("hasCostModel"), cost.clone()));
        out.push(Triple::new(cost.clone(), rdf::TYPE, dk("UpkeepCostModel")));
        out.push(Triple::new(
            cost,
            dk("hasValue"),
            Literal::new_typed_literal(format!("{:?}", tf.upkeep), xsd::DOUBLE),
        ));
    }
    let publishers = env.publishers();
    let base = format!("{CU_PREFIX}{}", encode(&cu.cid));
    for (port, channel) in &cu.inputs {
        let Some(channel) = channel else { continue };
        let s = NamedNode::new_unchecked(format!("{base}/in/{}", encode(port)));
        out.push(Triple::new(me.clone(), dk("hasSubscription"), s.clone()));
        out.push(Triple::new(s.clone(), rdf::TYPE, dk("Subscription")));
        out.push(Triple::new(s.clone(), dk("toCU"), me.clone()));
        if let Some(p) = iris.in_ports.get(&(cu.tid.clone(), port.clone())) {
            out.push(Triple::new(s.clone(), dk("toPort"), p.clone()));
        }
        out.push(Triple::new(
            s.clone(),
            dk("hasChannel"),
            channel_iri(channel),
        ));
        out.extend(channel_triples(channel));
        if let Some((from, from_port)) = publishers.get(channel.as_str()).and_then(|p| p.first()) {
            out.push(Triple::new(s.clone(), dk("fromCU"), cu_iri(from)));
            let from_tid = &env.cus[*from].tid;
            if let Some(p) = iris
                .out_ports
                .get(&(from_tid.clone(), (*from_port).to_owned()))
            {
                out.push(Triple::new(s.clone(), dk("fromPort"), p.clone()));
            }
        }
    }
    for (port, channel) in &cu.outputs {
        let Some(channel) = channel else { continue };
        let p = NamedNode::new_unchecked(format!("{base}/out/{}", encode(port)));
        out.push(Triple::new(me.clone(), dkros("hasPublication"), p.clone()));
        out.push(Triple::new(p.clone(), rdf::TYPE, dkros("Publication")));
        if let Some(port) = iris.out_ports.get(&(cu.tid.clone(), port.clone())) {
            out.push(Triple::new(p.clone(), dkros("publishesPort"), port.clone()));
        }
        out.push(Triple::new(p, dkros("onChannel"), channel_iri(channel)));
        out.extend(channel_triples(channel));
    }
    out.sort_by_cached_key(ToString::to_string);
    out.dedup();
    out
}

fn channel_triples(channel: &str) -> [Triple; 2] {
    let c = channel_iri(channel);
    [
        Triple::new(c.clone(), rdf::TYPE, dk("Channel")),
        Triple::new(
            c,
            dk("hasChannelName"),
            Literal::new_simple_literal(channel),
        ),
    ]
}

/// The RDF delta between two environments: the triples of every CU graph that differ.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Delta {
    /// Triples to insert.
    pub insert: Vec<Triple>,
    /// Triples to delete.
    pub delete: Vec<Triple>,
    /// The CU graphs to write: (part, triples), an empty list removing the part.
    pub parts: Vec<(String, Vec<Triple>)>,
}

impl Delta {
    /// Whether nothing changes.
    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }

    /// The triples to insert, as sorted N-Triples.
    pub fn insert_ntriples(&self) -> String {
        ntriples(&self.insert)
    }

    /// The triples to delete, as sorted N-Triples.
    pub fn delete_ntriples(&self) -> String {
        ntriples(&self.delete)
    }
}

fn ntriples(triples: &[Triple]) -> String {
    let mut lines: Vec<String> = triples.iter().map(|t| format!("{t} .\n")).collect();
    lines.sort();
    lines.dedup();
    lines.concat()
}

/// The delta from `before` to `after` (every CU graph whose triples differ).
pub fn delta(before: &Environment, after: &Environment, iris: &Iris) -> Delta {
    let mut out = Delta::default();
    let names: BTreeSet<&String> = before.cus.keys().chain(after.cus.keys()).collect();
    for name in names {
        let old: HashSet<Triple> = before
            .cus
            .get(name)
            .map(|c| cu_triples(c, before, iris))
            .unwrap_or_default()
            .into_iter()
            .collect();
        let new: Vec<Triple> = after
            .cus
            .get(name)
            .map(|c| cu_triples(c, after, iris))
            .unwrap_or_default();
        let new_set: HashSet<Triple> = new.iter().cloned().collect();
        if old == new_set {
            continue;
        }
        out.delete.extend(old.difference(&new_set).cloned());
        out.insert.extend(new_set.difference(&old).cloned());
        out.delete.sort_by_cached_key(ToString::to_string);
        out.insert.sort_by_cached_key(ToString::to_string);
        out.parts.push((cu_part(name), new));
    }
    out
}

/// Writes the delta into the knowledge base, as one atomic, reasoned write.
pub fn write(kb: &KnowledgeBase, delta: &Delta) -> Result<(), EngineError> {
    if !delta.is_empty() {
        kb.set_environment(&delta.parts)?;
    }
    Ok(())
}

/// Splits triples into those describing computation units (each CU, its subscriptions,
/// publications and cost models, and the engine's channel resources) and the rest (specs,
/// vocabulary). Derived `dependsOn` links are dropped: the reasoner derives them again.
pub fn split_environment(triples: Vec<Triple>) -> (Vec<Triple>, Vec<Triple>) {
    let cu_types = [dk("ComputationUnit"), dkros("Nodelet")];
    let mut owned: HashSet<Term> = triples
        .iter()
        .filter(|t| {
            t.predicate == rdf::TYPE && cu_types.iter().any(|c| t.object == Term::from(c.clone()))
        })
        .map(|t| Term::from(t.subject.clone()))
        .collect();
    let links = [
        dk("hasSubscription"),
        dkros("hasPublication"),
        dk("hasCostModel"),
    ];
    let cus = owned.clone();
    for t in &triples {
        if cus.contains(&Term::from(t.subject.clone())) && links.contains(&t.predicate) {
            owned.insert(t.object.clone());
        }
    }
    let depends_on = dk("dependsOn");
    let (mut env, mut rest) = (Vec::new(), Vec::new());
    for t in triples {
        let subject = Term::from(t.subject.clone());
        let channel = matches!(&t.subject, dyknow_store::oxigraph::model::NamedOrBlankNode::NamedNode(n) if n.as_str().starts_with(CHANNEL_PREFIX));
        if t.predicate == depends_on {
            continue;
        }
        if channel {
            // Channels are shared: a target's spec names its channel too.
            env.push(t.clone());
            rest.push(t);
        } else if owned.contains(&subject) {
            env.push(t);
        } else {
            rest.push(t);
        }
    }
    (env, rest)
}

/// A learned estimate: the historical average of the observations so far (seed Ch. 5.3.2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// The average.
    pub average: f64,
    /// How many observations it averages.
    pub count: u64,
}

impl Estimate {
    /// The estimate after one more observation.
    pub fn observe(self, value: f64) -> Self {
        let count = self.count + 1;
        Self {
            average: self.average + (value - self.average) / count as f64,
            count,
        }
    }
}

/// Learned labour and upkeep estimates per transformation.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Learned {
    /// Labour (cost of one spawn).
    pub labour: BTreeMap<Tid, Estimate>,
    /// Upkeep (cost per time unit of one running CU).
    pub upkeep: BTreeMap<Tid, Estimate>,
}

impl Learned {
    /// Replaces the initial estimates of `env`'s library with the learned ones.
    pub fn apply(&self, env: &mut Environment) {
        for (tid, tf) in &mut env.library {
            if let Some(e) = self.labour.get(tid).filter(|e| e.count > 0) {
                tf.labour = e.average;
            }
            if let Some(e) = self.upkeep.get(tid).filter(|e| e.count > 0) {
                tf.upkeep = e.average;
            }
        }
    }
}

/// The environment part holding the learned estimates.
pub const STATISTICS_PART: &str = "statistics";

/// The cost models' IRIs: (tid, "labour" | "upkeep") → the spec's cost model, if it has one.
fn cost_models(kb: &KnowledgeBase) -> Result<BTreeMap<(Tid, String), NamedNode>, EngineError> {
    let rows = kb.select(
        r#"PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#>
PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>
SELECT ?tid ?kind ?m WHERE {
  ?tf rdfs:label ?tid ; dyknow:hasCostModel ?m .
  { ?m a dyknow:LabourCostModel BIND("labour" AS ?kind) } UNION { ?m a dyknow:UpkeepCostModel BIND("upkeep" AS ?kind) }
}"#,
    )?;
    Ok(rows
        .into_iter()
        .filter_map(|r| Some(((literal(&r[0])?, literal(&r[1])?), named(&r[2])?)))
        .collect())
}

/// Reads the learned estimates.
pub fn learned(kb: &KnowledgeBase) -> Result<Learned, EngineError> {
    let rows = kb.select(
        r#"PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#>
PREFIX dkros: <http://www.dyknow.eu/ontology/dyknow-ros#>
PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>
SELECT ?tid ?kind ?avg ?n WHERE {
  ?tf rdfs:label ?tid ; dyknow:hasCostModel ?m .
  ?m dkros:observationCount ?n .
  { ?m dkros:historicalAverageLabour ?avg BIND("labour" AS ?kind) }
  UNION { ?m dkros:historicalAverageUpkeep ?avg BIND("upkeep" AS ?kind) }
}"#,
    )?;
    let mut out = Learned::default();
    for r in rows {
        let (Some(tid), Some(kind), Some(avg), Some(n)) = (
            literal(&r[0]),
            literal(&r[1]),
            literal(&r[2]).and_then(|v| v.parse::<f64>().ok()),
            literal(&r[3]).and_then(|v| v.parse::<u64>().ok()),
        ) else {
            continue;
        };
        let e = Estimate {
            average: avg,
            count: n,
        };
        if kind == "labour" {
            out.labour.insert(tid, e);
        } else {
            out.upkeep.insert(tid, e);
        }
    }
    Ok(out)
}

/// The triples of the statistics part: each learned estimate on the transformation's cost
/// model (`dkros:historicalAverage*`, `dkros:observationCount`), with a cost model minted for
/// a spec that gave none.
pub fn statistics_triples(
    kb: &KnowledgeBase,
    learned: &Learned,
    iris: &Iris,
) -> Result<Vec<Triple>, EngineError> {
    let models = cost_models(kb)?;
    let mut out = Vec::new();
    for (kind, map, class, property) in [
        (
            "labour",
            &learned.labour,
            "LabourCostModel",
            "historicalAverageLabour",
        ),
        (
            "upkeep",
            &learned.upkeep,
            "UpkeepCostModel",
            "historicalAverageUpkeep",
        ),
    ] {
        for (tid, e) in map {
            let Some(tf) = iris.transformations.get(tid) else {
                continue;
            };
            let model = match models.get(&(tid.clone(), kind.to_owned())) {
                Some(m) => m.clone(),
                None => {
                    let m = NamedNode::new_unchecked(format!("{}/learned/{kind}", tf.as_str()));
                    out.push(Triple::new(tf.clone(), dk("hasCostModel"), m.clone()));
                    out.push(Triple::new(m.clone(), rdf::TYPE, dk(class)));
                    m
                }
            };
            out.push(Triple::new(
                model.clone(),
                dkros(property),
                Literal::new_typed_literal(format!("{:?}", e.average), xsd::DOUBLE),
            ));
            out.push(Triple::new(
                model,
                dkros("observationCount"),
                Literal::new_typed_literal(e.count.to_string(), xsd::NON_NEGATIVE_INTEGER),
            ));
        }
    }
    Ok(out)
}

/// The environment part recording change set `id`.
pub fn change_set_part(id: &str) -> String {
    format!("changeset:{id}")
}

/// The triples recording a change set as a `dyknow:ChangeSet` resource: id, time, cause, cost,
/// each action, and the whole change set JSON.
pub fn change_set_triples(change_set: &crate::ChangeSet) -> Vec<Triple> {
    let me = NamedNode::new_unchecked(format!("urn:dyknow:changeset:{}", encode(&change_set.id)));
    let string = |v: &str| Literal::new_simple_literal(v);
    let mut out = vec![
        Triple::new(me.clone(), rdf::TYPE, dk("ChangeSet")),
        Triple::new(
            me.clone(),
            NamedNode::new_unchecked("http://www.w3.org/2000/01/rdf-schema#label"),
            string(&change_set.id),
        ),
        Triple::new(
            me.clone(),
            dkros("atTime"),
            Literal::new_typed_literal(&change_set.at, xsd::DATE_TIME),
        ),
        Triple::new(
            me.clone(),
            dkros("totalCost"),
            Literal::new_typed_literal(format!("{:?}", change_set.cost.total), xsd::DOUBLE),
        ),
    ];
    if let Ok(serde_json::Value::Object(cause)) = serde_json::to_value(&change_set.cause)
        && let Some(serde_json::Value::String(kind)) = cause.get("kind")
    {
        out.push(Triple::new(me.clone(), dkros("cause"), string(kind)));
    }
    if let Ok(json) = serde_json::to_string(change_set) {
        out.push(Triple::new(
            me.clone(),
            dkros("changeSetJson"),
            string(&json),
        ));
    }
    for (k, action) in change_set.actions.iter().enumerate() {
        let a = NamedNode::new_unchecked(format!("{}/action/{k}", me.as_str()));
        out.push(Triple::new(me.clone(), dkros("hasAction"), a.clone()));
        out.push(Triple::new(a.clone(), rdf::TYPE, dkros("Action")));
        out.push(Triple::new(
            a.clone(),
            dkros("hasIndex"),
            Literal::new_typed_literal(k.to_string(), xsd::NON_NEGATIVE_INTEGER),
        ));
        let Ok(serde_json::Value::Object(fields)) = serde_json::to_value(action) else {
            continue;
        };
        for (field, property) in [
            ("action", "actionKind"),
            ("cu", "cuName"),
            ("transformation", "transformationLabel"),
            ("port", "portName"),
            ("channel", "channelName"),
        ] {
            if let Some(serde_json::Value::String(v)) = fields.get(field) {
                out.push(Triple::new(a.clone(), dkros(property), string(v)));
            }
        }
    }
    out
}

/// The change sets recorded in the knowledge base, oldest first.
pub fn change_sets(kb: &KnowledgeBase) -> Result<Vec<serde_json::Value>, EngineError> {
    let rows = kb.select(
        r#"PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#>
PREFIX dkros: <http://www.dyknow.eu/ontology/dyknow-ros#>
SELECT ?json WHERE { ?cs a dyknow:ChangeSet ; dkros:changeSetJson ?json }"#,
    )?;
    let mut out: Vec<serde_json::Value> = rows
        .iter()
        .filter_map(|r| literal(&r[0]))
        .filter_map(|j| serde_json::from_str(&j).ok())
        .collect();
    let number = |v: &serde_json::Value| {
        v.get("id")
            .and_then(|i| i.as_str())
            .and_then(|i| i.strip_prefix("cs-"))
            .and_then(|n| n.parse::<u64>().ok())
            .unwrap_or(0)
    };
    out.sort_by_key(number);
    Ok(out)
}

/// What one review decides: COMPILE's change set, the environment after it, and its delta.
#[derive(Debug, Clone)]
pub struct Reviewed {
    /// The change set's actions, cost and what could not be satisfied.
    pub compiled: crate::Compiled,
    /// The environment after the change set (ε ⊗ δ).
    pub after: Environment,
    /// The graph delta that takes the knowledge base there.
    pub delta: Delta,
}

/// One review on a loaded environment: EXPLORE, COMPILE, update ⊗ and the graph delta. Writes
/// nothing ([`write`] does).
pub fn review(loaded: &Loaded, options: &crate::ExploreOptions, ids: &mut crate::Ids) -> Reviewed {
    let exploration = crate::explore(&loaded.env, &loaded.candidates, options);
    let compiled = crate::compile(&loaded.env, &exploration, options, ids);
    let mut after = loaded.env.clone();
    after.apply(&compiled.actions);
    let delta = delta(&loaded.env, &after, &loaded.iris);
    Reviewed {
        compiled,
        after,
        delta,
    }
}
