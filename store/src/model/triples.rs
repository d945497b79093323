//! Writing the DyKnow model into the knowledge base: the triples of each computation unit
//! (`specs.md`, "Computation units in the model"), the graph delta between two environments,
//! change-set records and the learned statistics.

use std::collections::{BTreeMap, BTreeSet, HashSet};

use dyknow_engine::{
    Action, ChangeSet, ComputationUnit, CostKind, Environment, Learned, NTriplesDelta, Tid,
};
use dyknow_ontology::vocab::{dkros, dyknow, rdf, rdfs, xsd};
use oxigraph::model::{Literal, NamedNode, NamedOrBlankNode, Term, Triple};

use super::queries;
use super::read::{Iris, cost_kind, literal, named};
use crate::error::ModelReadError;
use crate::graphs::{
    CHANNEL_PREFIX, EnvironmentPart, change_set_resource, channel_resource, cu_resource, encode,
};
use crate::knowledge_base::KnowledgeBase;

fn channel_iri(name: &str) -> NamedNode {
    NamedNode::new_unchecked(channel_resource(name))
}

/// An `xsd:double` written as the store gives it back (it keeps a double's value, not its
/// lexical form): `1`, not `1.0`. Graphs compared with what the store holds ([`resync`])
/// then differ only where the values do.
fn double(v: f64) -> Literal {
    Literal::from(v)
}

fn count(n: impl ToString) -> Literal {
    Literal::new_typed_literal(n.to_string(), xsd::NON_NEGATIVE_INTEGER)
}

/// The triples of one CU: its types, name, transformation, upkeep, protection, one
/// subscription per bound in port (with the CU and out port that publish on the channel, so
/// the reasoner derives `dependsOn`) and one publication per bound out port.
pub fn cu_triples(cu: &ComputationUnit, env: &Environment, iris: &Iris) -> Vec<Triple> {
    cu_triples_with(cu, env, &env.publishers(), iris)
}

/// The publishers of each channel in an environment ([`Environment::publishers`]).
type Publishers<'a> = BTreeMap<&'a str, Vec<(&'a str, &'a str)>>;

/// [`cu_triples`] with the environment's publishers computed once for all its CUs.
fn cu_triples_with(
    cu: &ComputationUnit,
    env: &Environment,
    publishers: &Publishers<'_>,
    iris: &Iris,
) -> Vec<Triple> {
    let me = cu_resource(&cu.cid);
    let mut out = vec![
        Triple::new(me.clone(), rdf::TYPE, dyknow::COMPUTATION_UNIT),
        Triple::new(me.clone(), rdf::TYPE, dkros::NODELET),
        Triple::new(
            me.clone(),
            dyknow::HAS_NAME,
            Literal::new_simple_literal(cu.cid.as_str()),
        ),
    ];
    if let Some(tf) = iris.transformations.get(&cu.tid) {
        out.push(Triple::new(me.clone(), dyknow::INSTANCE_OF, tf.clone()));
    }
    if cu.protected {
        out.push(Triple::new(
            me.clone(),
            dkros::IS_PROTECTED,
            Literal::new_typed_literal("true", xsd::BOOLEAN),
        ));
    }
    if let Some(tf) = env.library.get(&cu.tid) {
        let cost = NamedNode::new_unchecked(format!("{}/upkeep", me.as_str()));
        out.push(Triple::new(
            me.clone(),
            dyknow::HAS_COST_MODEL,
            cost.clone(),
        ));
        out.push(Triple::new(
            cost.clone(),
            rdf::TYPE,
            dyknow::UPKEEP_COST_MODEL,
        ));
        out.push(Triple::new(cost, dyknow::HAS_VALUE, double(tf.upkeep)));
    }
    for (port, channel) in &cu.inputs {
        let Some(channel) = channel else { continue };
        let s = NamedNode::new_unchecked(format!("{}/in/{}", me.as_str(), encode(port)));
        out.push(Triple::new(me.clone(), dyknow::HAS_SUBSCRIPTION, s.clone()));
        out.push(Triple::new(s.clone(), rdf::TYPE, dyknow::SUBSCRIPTION));
        out.push(Triple::new(s.clone(), dyknow::TO_CU, me.clone()));
        if let Some(p) = iris.in_ports.get(&(cu.tid.clone(), port.clone())) {
            out.push(Triple::new(s.clone(), dyknow::TO_PORT, p.clone()));
        }
        out.push(Triple::new(
            s.clone(),
            dyknow::HAS_CHANNEL,
            channel_iri(channel.as_str()),
        ));
        out.extend(channel_triples(channel.as_str()));
        if let Some((from_cu, from_port)) = first_publisher(env, publishers, channel.as_str()) {
            out.push(Triple::new(
                s.clone(),
                dyknow::FROM_CU,
                cu_resource(&from_cu.cid),
            ));
            if let Some(p) = iris
                .out_ports
                .get(&(from_cu.tid.clone(), from_port.to_owned()))
            {
                out.push(Triple::new(s.clone(), dyknow::FROM_PORT, p.clone()));
            }
        }
    }
    for (port, channel) in &cu.outputs {
        let Some(channel) = channel else { continue };
        let p = NamedNode::new_unchecked(format!("{}/out/{}", me.as_str(), encode(port)));
        out.push(Triple::new(me.clone(), dkros::HAS_PUBLICATION, p.clone()));
        out.push(Triple::new(p.clone(), rdf::TYPE, dkros::PUBLICATION));
        if let Some(port) = iris.out_ports.get(&(cu.tid.clone(), port.clone())) {
            out.push(Triple::new(p.clone(), dkros::PUBLISHES_PORT, port.clone()));
        }
        out.push(Triple::new(
            p,
            dkros::ON_CHANNEL,
            channel_iri(channel.as_str()),
        ));
        out.extend(channel_triples(channel.as_str()));
    }
    out.sort_by_cached_key(ToString::to_string);
    out.dedup();
    out
}

fn channel_triples(channel: &str) -> [Triple; 2] {
    let c = channel_iri(channel);
    [
        Triple::new(c.clone(), rdf::TYPE, dyknow::CHANNEL),
        Triple::new(
            c,
            dyknow::HAS_CHANNEL_NAME,
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
    pub parts: Vec<(EnvironmentPart, Vec<Triple>)>,
}

impl Delta {
    /// Whether nothing changes.
    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }

    /// The delta as change set JSON gives it: sorted N-Triples.
    pub fn ntriples(&self) -> NTriplesDelta {
        NTriplesDelta {
            insert: ntriples(&self.insert),
            delete: ntriples(&self.delete),
        }
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
    let names: BTreeSet<_> = before.cus.keys().chain(after.cus.keys()).collect();
    let (publishers_before, publishers_after) = (before.publishers(), after.publishers());
    // What `cu_triples_with` reads of a CU's environment: its transformation's upkeep, and
    // the first publisher of each channel it subscribes to.
    let upkeep = |env: &Environment, cu: &ComputationUnit| {
        env.library.get(&cu.tid).map(|t| t.upkeep.to_bits())
    };
    let same = |b: &ComputationUnit, a: &ComputationUnit| {
        b == a
            && upkeep(before, b) == upkeep(after, a)
            && a.inputs.values().flatten().all(|ch| {
                // The publisher's name, port and transformation: what the subscription writes.
                let written = |env, publishers| {
                    first_publisher(env, publishers, ch.as_str())
                        .map(|(cu, port)| (&cu.cid, port, &cu.tid))
                };
                written(before, &publishers_before) == written(after, &publishers_after)
            })
    };
    for name in names {
        // Unchanged, and so is all it reads: the same triples, not worth writing out.
        if let (Some(b), Some(a)) = (before.cus.get(name), after.cus.get(name))
            && same(b, a)
        {
            continue;
        }
        let old: HashSet<Triple> = before
            .cus
            .get(name)
            .map(|c| cu_triples_with(c, before, &publishers_before, iris))
            .unwrap_or_default()
            .into_iter()
            .collect();
        let new: Vec<Triple> = after
            .cus
            .get(name)
            .map(|c| cu_triples_with(c, after, &publishers_after, iris))
            .unwrap_or_default();
        let new_set: HashSet<Triple> = new.iter().cloned().collect();
        if old == new_set {
            continue;
        }
        out.delete.extend(old.difference(&new_set).cloned());
        out.insert.extend(new_set.difference(&old).cloned());
        out.parts.push((EnvironmentPart::Cu(name.clone()), new));
    }
    out.delete.sort_by_cached_key(ToString::to_string);
    out.insert.sort_by_cached_key(ToString::to_string);
    out
}

/// The CU graphs of the knowledge base that no longer say what `env` says of their CU, with
/// what they should hold: the graphs to write so that every CU graph is [`cu_triples`] of its
/// CU again.
///
/// [`delta`] writes what changed between two models, so it relies on each stored graph being
/// the triples of the model it was read as. A spec write breaks that: a port renamed or
/// dropped leaves a CU's subscription in its graph, naming a port that is gone (the model reads
/// the port as unbound) and the channel's publisher (so `dependsOn` stays derived), and when
/// the port comes back the old subscription is read again with a `fromCU` nobody updates.
///
/// `changed`: the transformations whose specs were written or removed; only their CUs, the
/// CUs reading a channel one of them publishes on, and the CUs whose stored subscriptions name
/// one of them are compared. `None` compares every CU (at start-up, to repair a store written
/// before this existed).
pub fn resync(
    kb: &KnowledgeBase,
    env: &Environment,
    iris: &Iris,
    changed: Option<&[Tid]>,
) -> Result<Vec<(EnvironmentPart, Vec<Triple>)>, ModelReadError> {
    let publishers = env.publishers();
    let names: BTreeSet<&dyknow_engine::Cid> = match changed {
        None => env.cus.keys().collect(),
        Some(tids) => {
            let of_changed: BTreeSet<&dyknow_engine::Cid> = env
                .cus
                .values()
                .filter(|cu| tids.contains(&cu.tid))
                .map(|cu| &cu.cid)
                .collect();
            // Every CU of the model graph-named; those whose stored subscriptions come from
            // a CU of a changed transformation.
            let graphs: BTreeMap<String, &dyknow_engine::Cid> = env
                .cus
                .keys()
                .map(|cid| (EnvironmentPart::Cu(cid.clone()).graph().into_string(), cid))
                .collect();
            let mut names = of_changed.clone();
            for cid in &of_changed {
                let from = cu_resource(cid);
                for quad in kb.store().quads_for_pattern(
                    None,
                    Some(dyknow::FROM_CU),
                    Some(from.as_ref().into()),
                    None,
                ) {
                    if let oxigraph::model::GraphName::NamedNode(g) = quad?.graph_name
                        && let Some(cid) = graphs.get(g.as_str())
                    {
                        names.insert(cid);
                    }
                }
            }
            // Those reading a channel a CU of a changed transformation publishes on now.
            let channels: BTreeSet<&str> = of_changed
                .iter()
                .filter_map(|cid| env.cus.get(*cid))
                .flat_map(|cu| cu.outputs.values().flatten().map(|c| c.as_str()))
                .collect();
            names.extend(
                env.cus
                    .values()
                    .filter(|cu| {
                        cu.inputs
                            .values()
                            .flatten()
                            .any(|c| channels.contains(c.as_str()))
                    })
                    .map(|cu| &cu.cid),
            );
            names
        }
    };
    let mut parts = Vec::new();
    for cid in names {
        let Some(cu) = env.cus.get(cid) else { continue };
        // A CU whose transformation has no spec now (removed; the review destroys the CU)
        // reads with the transformation's IRI for a label: written back, it would lose its
        // `instanceOf`, and with it its place in the model. Left to the review.
        if !iris.transformations.contains_key(&cu.tid) || !env.library.contains_key(&cu.tid) {
            continue;
        }
        let part = EnvironmentPart::Cu(cid.clone());
        let stored: HashSet<Triple> = kb
            .graph_triples(part.graph().as_ref())?
            .into_iter()
            .collect();
        let should = cu_triples_with(cu, env, &publishers, iris);
        if should.len() != stored.len() || !should.iter().all(|t| stored.contains(t)) {
            parts.push((part, should));
        }
    }
    Ok(parts)
}

/// The CU that a subscription to `channel` is written as coming from (the first publisher),
/// with its out port.
fn first_publisher<'a>(
    env: &'a Environment,
    publishers: &Publishers<'a>,
    channel: &str,
) -> Option<(&'a ComputationUnit, &'a str)> {
    let &(cu, port) = publishers.get(channel)?.first()?;
    Some((env.cus.get(cu)?, port))
}

/// Splits triples into those describing computation units (each CU, its subscriptions,
/// publications and cost models, and the channel resources) and the rest (specs,
/// vocabulary). Derived `dependsOn` links are dropped: the reasoner derives them again.
pub fn split_environment(triples: Vec<Triple>) -> (Vec<Triple>, Vec<Triple>) {
    let cu_types: [Term; 2] = [dyknow::COMPUTATION_UNIT.into(), dkros::NODELET.into()];
    let mut owned: HashSet<Term> = triples
        .iter()
        .filter(|t| t.predicate == rdf::TYPE && cu_types.contains(&t.object))
        .map(|t| Term::from(t.subject.clone()))
        .collect();
    let links = [
        dyknow::HAS_SUBSCRIPTION,
        dkros::HAS_PUBLICATION,
        dyknow::HAS_COST_MODEL,
    ];
    let cus = owned.clone();
    for t in &triples {
        if cus.contains(&Term::from(t.subject.clone())) && links.contains(&t.predicate.as_ref()) {
            owned.insert(t.object.clone());
        }
    }
    let (mut env, mut rest) = (Vec::new(), Vec::new());
    for t in triples {
        let subject = Term::from(t.subject.clone());
        let channel = matches!(&t.subject, NamedOrBlankNode::NamedNode(n) if n.as_str().starts_with(CHANNEL_PREFIX));
        if t.predicate == dyknow::DEPENDS_ON {
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

/// The triples recording a change set as a `dyknow:ChangeSet` resource: id, time, cause,
/// cost, each action with its fields, and the whole change set JSON (what the history is read
/// back from).
pub fn change_set_triples(change_set: &ChangeSet) -> Vec<Triple> {
    let me = change_set_resource(&change_set.id);
    let string = |v: &str| Literal::new_simple_literal(v);
    let mut out = vec![
        Triple::new(me.clone(), rdf::TYPE, dyknow::CHANGE_SET),
        Triple::new(me.clone(), rdfs::LABEL, string(change_set.id.as_str())),
        Triple::new(
            me.clone(),
            dkros::AT_TIME,
            Literal::new_typed_literal(&change_set.at, xsd::DATE_TIME),
        ),
        Triple::new(me.clone(), dkros::TOTAL_COST, double(change_set.cost.total)),
        Triple::new(me.clone(), dkros::CAUSE, string(change_set.cause.kind())),
    ];
    if let Ok(json) = serde_json::to_string(change_set) {
        out.push(Triple::new(
            me.clone(),
            dkros::CHANGE_SET_JSON,
            string(&json),
        ));
    }
    for (k, action) in change_set.actions.iter().enumerate() {
        let a = NamedNode::new_unchecked(format!("{}/action/{k}", me.as_str()));
        out.push(Triple::new(me.clone(), dkros::HAS_ACTION, a.clone()));
        out.push(Triple::new(a.clone(), rdf::TYPE, dkros::ACTION));
        out.push(Triple::new(a.clone(), dkros::HAS_INDEX, count(k)));
        out.push(Triple::new(
            a.clone(),
            dkros::ACTION_KIND,
            string(action.kind()),
        ));
        let mut field =
            |property, value: &str| out.push(Triple::new(a.clone(), property, string(value)));
        match action {
            Action::Register { transformation } | Action::Deregister { transformation } => {
                field(dkros::TRANSFORMATION_LABEL, transformation.as_str());
            }
            // The target's spec records it; the ontology has no property for its label here.
            Action::Query { .. } | Action::Release { .. } => {}
            Action::Spawn { cu, transformation } => {
                field(dkros::CU_NAME, cu.as_str());
                field(dkros::TRANSFORMATION_LABEL, transformation.as_str());
            }
            Action::Destroy { cu } => field(dkros::CU_NAME, cu.as_str()),
            Action::ConnectIn { cu, port, channel } | Action::ConnectOut { cu, port, channel } => {
                field(dkros::CU_NAME, cu.as_str());
                field(dkros::PORT_NAME, port);
                field(dkros::CHANNEL_NAME, channel.as_str());
            }
            Action::DisconnectIn { cu, port } | Action::DisconnectOut { cu, port } => {
                field(dkros::CU_NAME, cu.as_str());
                field(dkros::PORT_NAME, port);
            }
        }
    }
    out
}

/// The resource the history part describes.
pub const HISTORY_RESOURCE: &str = "urn:dyknow:history";

/// The triples of the history part: the names (of CUs and channels) pruned change sets used,
/// which are never handed out again (`dkros:reservesName`).
pub fn history_triples<'a>(names: impl IntoIterator<Item = &'a str>) -> Vec<Triple> {
    let me = NamedNode::new_unchecked(HISTORY_RESOURCE);
    names
        .into_iter()
        .map(|n| {
            Triple::new(
                me.clone(),
                dkros::RESERVES_NAME,
                Literal::new_simple_literal(n),
            )
        })
        .collect()
}

/// The triples of the statistics part: each learned estimate on the transformation's cost
/// model (`dkros:historicalAverage*`, `dkros:observationCount`), with a cost model minted for
/// a spec that gave none.
pub fn statistics_triples(
    kb: &KnowledgeBase,
    learned: &Learned,
    iris: &Iris,
) -> Result<Vec<Triple>, ModelReadError> {
    let mut models: BTreeMap<(Tid, String), NamedNode> = BTreeMap::new();
    for r in kb.select(&queries::COST_MODELS)? {
        if let (Some(tid), Some(kind), Some(model)) = (literal(&r[0]), literal(&r[1]), named(&r[2]))
        {
            models.insert((Tid::new(tid), kind), model);
        }
    }
    let mut out = Vec::new();
    for (map, kind) in [
        (&learned.labour, CostKind::Labour),
        (&learned.upkeep, CostKind::Upkeep),
    ] {
        let (name, class, property) = match kind {
            CostKind::Labour => (
                "labour",
                dyknow::LABOUR_COST_MODEL,
                dkros::HISTORICAL_AVERAGE_LABOUR,
            ),
            CostKind::Upkeep => (
                "upkeep",
                dyknow::UPKEEP_COST_MODEL,
                dkros::HISTORICAL_AVERAGE_UPKEEP,
            ),
        };
        debug_assert_eq!(cost_kind(name), kind);
        for (tid, e) in map {
            let Some(tf) = iris.transformations.get(tid) else {
                continue;
            };
            let model = match models.get(&(tid.clone(), name.to_owned())) {
                Some(m) => m.clone(),
                None => {
                    let m = NamedNode::new_unchecked(format!("{}/learned/{name}", tf.as_str()));
                    out.push(Triple::new(tf.clone(), dyknow::HAS_COST_MODEL, m.clone()));
                    out.push(Triple::new(m.clone(), rdf::TYPE, class));
                    m
                }
            };
            out.push(Triple::new(model.clone(), property, double(e.average)));
            out.push(Triple::new(model, dkros::OBSERVATION_COUNT, count(e.count)));
        }
    }
    Ok(out)
}
