//! Reading the DyKnow model from the knowledge base: the environment ⟨CU, F, T⟩ with the
//! candidate table, the learned estimates and the recorded change sets.

use std::collections::BTreeMap;
use std::sync::{Mutex, PoisonError};

use dyknow_engine::{
    Candidates, ChangeSet, ChangeSetId, Cid, ComputationUnit, CostKind, Environment, Estimate,
    Learned, Provider, Target, Tid, Transformation,
};
use oxigraph::model::{NamedNode, Term};

use super::queries;
use crate::error::ModelReadError;
use crate::knowledge_base::KnowledgeBase;
use crate::spec::{Spec, SpecKind, TransformationSpec};

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

/// What the engine needs from the knowledge base.
#[derive(Debug, Clone, Default)]
pub struct Loaded {
    /// The environment ⟨CU, F, T⟩, with the learned estimates in the library.
    pub env: Environment,
    /// The candidate table (~).
    pub candidates: Candidates,
    /// The IRIs of transformations and ports.
    pub iris: Iris,
    /// The transformation specs, for what the engine does not need (implementations,
    /// parameters).
    pub specs: BTreeMap<Tid, TransformationSpec>,
}

pub(crate) fn literal(term: &Option<Term>) -> Option<String> {
    match term {
        Some(Term::Literal(l)) => Some(l.value().to_owned()),
        _ => None,
    }
}

pub(crate) fn named(term: &Option<Term>) -> Option<NamedNode> {
    match term {
        Some(Term::NamedNode(n)) => Some(n.clone()),
        _ => None,
    }
}

/// Reads the environment, the candidate table and the library's IRIs.
pub fn load(kb: &KnowledgeBase) -> Result<Loaded, ModelReadError> {
    SpecCache::default().load(kb, None)
}

/// What is derived from specs alone (library with the specs' estimates, targets, IRIs, the
/// candidate table), cached against [`KnowledgeBase::spec_generation`]: a review after a CU
/// crash reads only the CUs again.
#[derive(Debug, Default)]
pub struct SpecCache {
    cached: Mutex<Option<(u64, Loaded)>>,
}

impl SpecCache {
    /// [`load`], reusing the spec-derived part while no spec or extension changed. With
    /// `learned`, those estimates replace the specs' (the caller keeps them); without, they
    /// are read from the store.
    pub fn load(
        &self,
        kb: &KnowledgeBase,
        learned: Option<&Learned>,
    ) -> Result<Loaded, ModelReadError> {
        let generation = kb.spec_generation();
        let hit = self
            .cached
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .as_ref()
            .filter(|(g, _)| *g == generation)
            .map(|(_, l)| l.clone());
        let mut loaded = match hit {
            Some(l) => l,
            None => {
                let l = load_specs(kb)?;
                *self.cached.lock().unwrap_or_else(PoisonError::into_inner) =
                    Some((generation, l.clone()));
                l
            }
        };
        match learned {
            Some(l) => l.apply(&mut loaded.env),
            None => self::learned(kb)?.apply(&mut loaded.env),
        }
        load_cus(kb, &mut loaded)?;
        Ok(loaded)
    }
}

/// The spec-derived part of [`Loaded`] (no CUs, the specs' own estimates).
fn load_specs(kb: &KnowledgeBase) -> Result<Loaded, ModelReadError> {
    let mut loaded = Loaded::default();
    for spec in kb.specs(SpecKind::Transformation)? {
        let Spec::Transformation(t) = spec else {
            continue;
        };
        let tid = Tid::new(t.label.clone());
        loaded.specs.insert(tid.clone(), t.clone());
        loaded
            .iris
            .transformations
            .insert(tid.clone(), NamedNode::new_unchecked(t.iri));
        loaded.env.library.insert(
            tid.clone(),
            Transformation {
                tid,
                inputs: t.inputs.into_iter().map(|p| p.name).collect(),
                outputs: t.outputs.into_iter().map(|p| p.name).collect(),
                labour: t.labour,
                upkeep: t.upkeep,
            },
        );
    }
    for spec in kb.specs(SpecKind::Target)? {
        let Spec::Target(t) = spec else {
            continue;
        };
        let qid = dyknow_engine::Qid::new(t.label);
        loaded.env.targets.insert(
            qid.clone(),
            Target {
                qid,
                channel: t.channel.into(),
            },
        );
    }
    for row in kb.select(&queries::PORTS)? {
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
        map.insert((Tid::new(tid), name), port);
    }
    loaded.candidates = candidates(kb, &loaded.env)?;
    Ok(loaded)
}

/// Reads the CUs into `loaded`.
fn load_cus(kb: &KnowledgeBase, loaded: &mut Loaded) -> Result<(), ModelReadError> {
    for row in kb.select(&queries::CUS)? {
        let (Some(name), Some(tid)) = (literal(&row[0]), literal(&row[1])) else {
            continue;
        };
        let protected = literal(&row[2]).is_some_and(|v| v == "true" || v == "1");
        let cid = Cid::new(name);
        let cu = loaded
            .env
            .cus
            .entry(cid.clone())
            .or_insert_with(|| ComputationUnit {
                cid,
                tid: Tid::new(tid),
                inputs: BTreeMap::new(),
                outputs: BTreeMap::new(),
                protected,
            });
        if let (Some(dir), Some(port)) = (literal(&row[3]), literal(&row[4])) {
            let channel = literal(&row[5]).map(Into::into);
            if dir == "in" {
                cu.inputs.insert(port, channel);
            } else {
                cu.outputs.insert(port, channel);
            }
        }
    }
    // Every port of a CU's transformation is listed, bound or not.
    let Loaded { env, .. } = loaded;
    for cu in env.cus.values_mut() {
        if let Some(tf) = env.library.get(&cu.tid) {
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

/// The candidate table of `env`'s library and targets ([`queries::CANDIDATES`]).
pub fn candidates(kb: &KnowledgeBase, env: &Environment) -> Result<Candidates, ModelReadError> {
    let mut table = Candidates::default();
    let index = |tid: &str, name: &str, outputs: bool| {
        env.library.get(tid).and_then(|t| {
            let ports = if outputs { &t.outputs } else { &t.inputs };
            ports.iter().position(|p| p == name)
        })
    };
    for row in kb.select(&queries::CANDIDATES)? {
        let (Some(producer), Some(out_port)) = (literal(&row[3]), literal(&row[4])) else {
            continue;
        };
        let Some(port) = index(&producer, &out_port, true) else {
            continue;
        };
        let provider = Provider {
            tid: producer.into(),
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

/// Reads the learned estimates.
pub fn learned(kb: &KnowledgeBase) -> Result<Learned, ModelReadError> {
    let mut out = Learned::default();
    for r in kb.select(&queries::LEARNED)? {
        let (Some(tid), Some(kind), Some(average), Some(count)) = (
            literal(&r[0]),
            literal(&r[1]),
            literal(&r[2]).and_then(|v| v.parse::<f64>().ok()),
            literal(&r[3]).and_then(|v| v.parse::<u64>().ok()),
        ) else {
            continue;
        };
        let map = match cost_kind(&kind) {
            CostKind::Labour => &mut out.labour,
            CostKind::Upkeep => &mut out.upkeep,
        };
        map.insert(Tid::new(tid), Estimate { average, count });
    }
    Ok(out)
}

/// The kind column of [`queries::COST_MODELS`] and [`queries::LEARNED`].
pub(crate) fn cost_kind(kind: &str) -> CostKind {
    if kind == "labour" {
        CostKind::Labour
    } else {
        CostKind::Upkeep
    }
}

/// A change-set record that does not read back as a change set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnreadableRecord {
    /// Its id (`rdfs:label`), when it has one.
    pub id: Option<ChangeSetId>,
    /// Why it does not read.
    pub error: String,
}

/// The change sets recorded in the knowledge base.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ChangeSetRecords {
    /// Those that read back, oldest first.
    pub change_sets: Vec<ChangeSet>,
    /// Those that do not (written by a later release, or damaged): the service starts without
    /// them, but their numbers stay taken.
    pub unreadable: Vec<UnreadableRecord>,
}

/// The change sets recorded in the knowledge base, oldest first, and the records that do not
/// read back as change sets.
pub fn change_sets(kb: &KnowledgeBase) -> Result<ChangeSetRecords, ModelReadError> {
    let mut out = ChangeSetRecords::default();
    for row in kb.select(&queries::CHANGE_SETS)? {
        let id = literal(&row[0]).map(ChangeSetId::new);
        let read = literal(&row[1])
            .ok_or_else(|| "it has no dkros:changeSetJson".to_owned())
            .and_then(|json| serde_json::from_str::<ChangeSet>(&json).map_err(|e| e.to_string()));
        match read {
            Ok(change_set) => out.change_sets.push(change_set),
            Err(error) => out.unreadable.push(UnreadableRecord { id, error }),
        }
    }
    out.change_sets
        .sort_by_key(|cs| (cs.id.number().unwrap_or(0), cs.id.clone()));
    Ok(out)
}

/// The names the history part reserves (`dkros:reservesName`): names pruned change sets used,
/// never handed out again.
pub fn reserved_names(kb: &KnowledgeBase) -> Result<Vec<String>, ModelReadError> {
    let graph = crate::graphs::EnvironmentPart::History.graph();
    let mut out = Vec::new();
    for quad in kb.store().quads_for_pattern(
        None,
        Some(dyknow_ontology::vocab::dkros::RESERVES_NAME),
        None,
        Some(graph.as_ref().into()),
    ) {
        let quad = quad?;
        if let Term::Literal(l) = quad.object {
            out.push(l.value().to_owned());
        }
    }
    out.sort();
    Ok(out)
}
