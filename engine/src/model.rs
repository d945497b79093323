//! The DyKnow model (seed Ch. 4.2, Table 4.1): transformations, computation units, targets and
//! environments, the actions of Defs. 23–30, update ⊗ (Def. 22) and validity (Def. 33).

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

use crate::candidates::Candidates;
pub use crate::ids::{Channel, Cid, Qid, Tid};

/// A transformation (Def. 17), with the DyKnow-ROS deviation of several out ports. The
/// function itself is an executor's business; the engine needs the ports and the cost
/// estimates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Transformation {
    /// The seed's *tid*.
    pub tid: Tid,
    /// In port names, in order (`[itag1, …, itagn]`).
    pub inputs: Vec<String>,
    /// Out port names, in order.
    pub outputs: Vec<String>,
    /// Estimated labour: the cost of spawning one CU of it (Def. 31).
    pub labour: f64,
    /// Estimated upkeep: the cost of one running CU of it per time unit (Def. 32).
    pub upkeep: f64,
}

/// A computation unit (Def. 18): an instance of a transformation with its channel bindings.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ComputationUnit {
    /// The seed's *cid*.
    pub cid: Cid,
    /// The transformation it instantiates.
    pub tid: Tid,
    /// In port → channel (`none` when unbound).
    pub inputs: BTreeMap<String, Option<Channel>>,
    /// Out port → channel (`none` when unbound).
    pub outputs: BTreeMap<String, Option<Channel>>,
    /// Protected CUs are never destroyed by a change set (DyKnow-ROS).
    pub protected: bool,
}

/// A target (Def. 19): a desired stream, described by tags, expected on a channel.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Target {
    /// The seed's *qid*.
    pub qid: Qid,
    /// The channel the described stream must appear on.
    pub channel: Channel,
}

/// An environment ⟨CU, F, T, ~⟩ (Def. 20). The similarity relation ~ lives in
/// [`Candidates`], which says for every in port and target which out ports satisfy it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Environment {
    /// The computation graph CU.
    pub cus: BTreeMap<Cid, ComputationUnit>,
    /// The library F.
    pub library: BTreeMap<Tid, Transformation>,
    /// The goal T.
    pub targets: BTreeMap<Qid, Target>,
}

/// One action (Defs. 23–30), as change sets list them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "action", rename_all = "kebab-case")]
pub enum Action {
    /// register (Def. 23).
    Register {
        /// The transformation.
        transformation: Tid,
    },
    /// deregister (Def. 24).
    Deregister {
        /// The transformation.
        transformation: Tid,
    },
    /// query (Def. 25).
    Query {
        /// The target.
        target: Qid,
    },
    /// release (Def. 26).
    Release {
        /// The target.
        target: Qid,
    },
    /// spawn (Def. 27): a CU with every port unbound.
    Spawn {
        /// The new CU.
        cu: Cid,
        /// Its transformation.
        transformation: Tid,
    },
    /// destroy (Def. 28).
    Destroy {
        /// The CU.
        cu: Cid,
    },
    /// connect↓ (Def. 29): an in port to a channel.
    ConnectIn {
        /// The CU.
        cu: Cid,
        /// Its in port.
        port: String,
        /// The channel.
        channel: Channel,
    },
    /// connect↑ (Def. 29): an out port to a channel.
    ConnectOut {
        /// The CU.
        cu: Cid,
        /// Its out port.
        port: String,
        /// The channel.
        channel: Channel,
    },
    /// disconnect↓ (Def. 30).
    DisconnectIn {
        /// The CU.
        cu: Cid,
        /// Its in port.
        port: String,
    },
    /// disconnect↑ (Def. 30).
    DisconnectOut {
        /// The CU.
        cu: Cid,
        /// Its out port.
        port: String,
    },
}

/// Why an environment is not valid (Def. 33, plus acyclicity).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Invalidity {
    /// 33.1: the CU's transformation is not in the library.
    UnknownTransformation {
        /// The CU.
        cu: Cid,
    },
    /// 33.2: an in port is bound to none, or to a channel no CU publishes on.
    UnfedInput {
        /// The CU.
        cu: Cid,
        /// The port.
        port: String,
    },
    /// 33.4: an in port's channel carries a stream whose tag does not satisfy it.
    Dissimilar {
        /// The CU.
        cu: Cid,
        /// The port.
        port: String,
    },
    /// 33.3: no CU publishes a stream satisfying the target on its channel.
    UnsatisfiedTarget {
        /// The target.
        target: Qid,
    },
    /// Several CUs publish on one channel.
    SharedChannel {
        /// The channel.
        channel: Channel,
    },
    /// The CU consumes, directly or not, its own output: a stream that never traces back to
    /// sources.
    Cycle {
        /// A CU on the cycle.
        cu: Cid,
    },
}

impl Action {
    /// The CU the action is about, if any.
    pub fn cu(&self) -> Option<&Cid> {
        match self {
            Self::Spawn { cu, .. }
            | Self::Destroy { cu }
            | Self::ConnectIn { cu, .. }
            | Self::ConnectOut { cu, .. }
            | Self::DisconnectIn { cu, .. }
            | Self::DisconnectOut { cu, .. } => Some(cu),
            Self::Register { .. }
            | Self::Deregister { .. }
            | Self::Query { .. }
            | Self::Release { .. } => None,
        }
    }

    /// The channel the action connects a port to, if any.
    pub fn channel(&self) -> Option<&Channel> {
        match self {
            Self::ConnectIn { channel, .. } | Self::ConnectOut { channel, .. } => Some(channel),
            _ => None,
        }
    }

    /// The action's name in change set JSON (`spawn`, `connect-in`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Register { .. } => "register",
            Self::Deregister { .. } => "deregister",
            Self::Query { .. } => "query",
            Self::Release { .. } => "release",
            Self::Spawn { .. } => "spawn",
            Self::Destroy { .. } => "destroy",
            Self::ConnectIn { .. } => "connect-in",
            Self::ConnectOut { .. } => "connect-out",
            Self::DisconnectIn { .. } => "disconnect-in",
            Self::DisconnectOut { .. } => "disconnect-out",
        }
    }
}

impl Environment {
    /// Update ε ⊗ δ (Def. 22) for a change set given as actions, applied in order. Actions
    /// on absent CUs are ignored, as the set semantics of ⊗ would.
    pub fn apply(&mut self, actions: &[Action]) {
        for action in actions {
            match action {
                Action::Spawn { cu, transformation } => {
                    let (inputs, outputs) = self
                        .library
                        .get(transformation)
                        .map(|t| {
                            (
                                t.inputs.iter().map(|p| (p.clone(), None)).collect(),
                                t.outputs.iter().map(|p| (p.clone(), None)).collect(),
                            )
                        })
                        .unwrap_or_default();
                    self.cus.insert(
                        cu.clone(),
                        ComputationUnit {
                            cid: cu.clone(),
                            tid: transformation.clone(),
                            inputs,
                            outputs,
                            protected: false,
                        },
                    );
                }
                Action::Destroy { cu } => {
                    self.cus.remove(cu);
                }
                Action::ConnectIn { cu, port, channel } => {
                    if let Some(c) = self.cus.get_mut(cu) {
                        c.inputs.insert(port.clone(), Some(channel.clone()));
                    }
                }
                Action::ConnectOut { cu, port, channel } => {
                    if let Some(c) = self.cus.get_mut(cu) {
                        c.outputs.insert(port.clone(), Some(channel.clone()));
                    }
                }
                Action::DisconnectIn { cu, port } => {
                    if let Some(c) = self.cus.get_mut(cu) {
                        c.inputs.insert(port.clone(), None);
                    }
                }
                Action::DisconnectOut { cu, port } => {
                    if let Some(c) = self.cus.get_mut(cu) {
                        c.outputs.insert(port.clone(), None);
                    }
                }
                Action::Deregister { transformation } => {
                    self.library.remove(transformation);
                }
                Action::Release { target } => {
                    self.targets.remove(target);
                }
                // Registering and querying carry their specs elsewhere (the knowledge base).
                Action::Register { .. } | Action::Query { .. } => {}
            }
        }
    }

    /// The producers of each channel: (CU, out port).
    pub fn publishers(&self) -> BTreeMap<&str, Vec<(&str, &str)>> {
        let mut out: BTreeMap<&str, Vec<(&str, &str)>> = BTreeMap::new();
        for cu in self.cus.values() {
            for (port, channel) in &cu.outputs {
                if let Some(channel) = channel {
                    out.entry(channel).or_default().push((&cu.cid, port));
                }
            }
        }
        out
    }

    /// Everything that makes the environment invalid (Def. 33, plus acyclicity), sorted;
    /// empty when it is valid.
    pub fn invalidities(&self, candidates: &Candidates) -> Vec<Invalidity> {
        let mut out = BTreeSet::new();
        let publishers = self.publishers();
        for (channel, producers) in &publishers {
            if producers.len() > 1 {
                out.insert(Invalidity::SharedChannel {
                    channel: Channel::from(*channel),
                });
            }
        }
        let producer = |channel: &Option<Channel>| {
            channel
                .as_deref()
                .and_then(|c| publishers.get(c))
                .and_then(|p| p.first().copied())
        };
        for cu in self.cus.values() {
            let Some(tf) = self.library.get(&cu.tid) else {
                out.insert(Invalidity::UnknownTransformation { cu: cu.cid.clone() });
                continue;
            };
            for (i, port) in tf.inputs.iter().enumerate() {
                let bound = cu.inputs.get(port).cloned().flatten();
                match producer(&bound) {
                    None => {
                        out.insert(Invalidity::UnfedInput {
                            cu: cu.cid.clone(),
                            port: port.clone(),
                        });
                    }
                    Some((from, from_port)) => {
                        if !self.satisfies(candidates.for_input(&cu.tid, i), from, from_port) {
                            out.insert(Invalidity::Dissimilar {
                                cu: cu.cid.clone(),
                                port: port.clone(),
                            });
                        }
                    }
                }
            }
        }
        for target in self.targets.values() {
            let ok = producer(&Some(target.channel.clone())).is_some_and(|(from, from_port)| {
                self.satisfies(candidates.for_target(&target.qid), from, from_port)
            });
            if !ok {
                out.insert(Invalidity::UnsatisfiedTarget {
                    target: target.qid.clone(),
                });
            }
        }
        // Acyclicity: a depth-first search over "consumes from".
        let mut state: BTreeMap<&str, u8> = BTreeMap::new();
        for start in self.cus.keys() {
            self.visit(start, &publishers, &mut state, &mut out);
        }
        out.into_iter().collect()
    }

    fn visit<'a>(
        &'a self,
        cid: &'a str,
        publishers: &BTreeMap<&'a str, Vec<(&'a str, &'a str)>>,
        state: &mut BTreeMap<&'a str, u8>,
        out: &mut BTreeSet<Invalidity>,
    ) {
        // Iterative DFS: 1 = on the stack, 2 = done.
        let mut stack: Vec<(&str, Vec<&str>)> = Vec::new();
        if state.contains_key(cid) {
            return;
        }
        let upstream = |c: &str| -> Vec<&'a str> {
            self.cus
                .get(c)
                .map(|cu| {
                    cu.inputs
                        .values()
                        .flatten()
                        .filter_map(|ch| publishers.get(ch.as_str()))
                        .flat_map(|p| p.iter().map(|(from, _)| *from))
                        .collect()
                })
                .unwrap_or_default()
        };
        state.insert(cid, 1);
        stack.push((cid, upstream(cid)));
        while let Some((node, next)) = stack.last_mut() {
            let node = *node;
            match next.pop() {
                Some(up) => match state.get(up) {
                    Some(1) => {
                        out.insert(Invalidity::Cycle { cu: Cid::from(up) });
                    }
                    Some(_) => {}
                    None => {
                        state.insert(up, 1);
                        let ups = upstream(up);
                        stack.push((up, ups));
                    }
                },
                None => {
                    state.insert(node, 2);
                    stack.pop();
                }
            }
        }
    }

    fn satisfies(&self, providers: &[crate::candidates::Provider], cu: &str, port: &str) -> bool {
        let Some(cu) = self.cus.get(cu) else {
            return false;
        };
        let Some(tf) = self.library.get(&cu.tid) else {
            return false;
        };
        providers
            .iter()
            .any(|p| p.tid == cu.tid && tf.outputs.get(p.port).is_some_and(|o| o == port))
    }

    /// Upkeep (Def. 32) per time unit, from the transformations' estimates.
    pub fn upkeep(&self) -> f64 {
        self.cus
            .values()
            .map(|cu| self.library.get(&cu.tid).map_or(0.0, |t| t.upkeep))
            .fold(0.0, |a, b| a + b)
    }
}
