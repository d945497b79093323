//! COMPILE (seed Algorithm 6): the change set that turns the environment into the plan's
//! computation graph: spawns and connections for new nodes, rewiring of kept CUs, and the
//! destruction of every CU the plan does not use (unless protected).

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

use crate::explore::{Exploration, ExploreOptions, NodeKind, Plan};
use crate::ids::{Channel, Cid, Ids, Qid};
use crate::model::{Action, Environment};

/// The estimated cost of a change set (Def. 34), as change set JSON gives it: in JSON each
/// number to 12 significant digits, so that sums of estimates such as 10 × 0.1 show as the
/// `1.0` they stand for, not `1.0000000000000002` (the value itself is kept exact).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CostSummary {
    /// labour + horizon × upkeep.
    #[serde(serialize_with = "significant")]
    pub total: f64,
    /// The labour of the spawned CUs (Def. 31).
    #[serde(serialize_with = "significant")]
    pub labour: f64,
    /// The upkeep of the resulting environment for one time unit (Def. 32).
    #[serde(serialize_with = "significant")]
    pub upkeep_per_time_unit: f64,
    /// The horizon H.
    #[serde(serialize_with = "significant")]
    pub horizon: f64,
}

/// `x` to 12 significant digits (far below any estimate's own precision, far above the
/// rounding errors of summing a few thousand of them).
#[must_use]
pub fn to_significant_digits(x: f64) -> f64 {
    if !x.is_finite() || x == 0.0 {
        return x;
    }
    format!("{x:.11e}").parse().unwrap_or(x)
}

fn significant<S: serde::Serializer>(x: &f64, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_f64(to_significant_digits(*x))
}

/// What COMPILE produces: the actions, their cost, and what the search could not do.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Compiled {
    /// The actions, in order: per plan node its spawn and connections, then destructions.
    pub actions: Vec<Action>,
    /// The estimated cost of the update.
    pub cost: CostSummary,
    /// Targets no valid configuration satisfies (the relaxation); empty when valid.
    pub unsatisfied_targets: Vec<Qid>,
    /// Whether the search proved this change set optimal (false after an any-time timeout).
    pub optimal: bool,
}

/// COMPILE(trace, ε) (Algorithm 6), for the best plan of `exploration`. Without a plan (no
/// valid configuration, relaxation off), nothing changes and every target is unsatisfied.
pub fn compile(
    env: &Environment,
    exploration: &Exploration,
    options: &ExploreOptions,
    ids: &mut Ids,
) -> Compiled {
    ids.observe(env);
    let Some(plan) = &exploration.plan else {
        return Compiled {
            actions: Vec::new(),
            cost: summary(env, options.horizon, 0.0),
            unsatisfied_targets: env.targets.keys().cloned().collect(),
            optimal: exploration.proven_optimal,
        };
    };
    let mut actions = Vec::new();
    // Line 3: every CU is to be removed unless the plan keeps it.
    let mut removal: BTreeSet<&Cid> = env.cus.keys().collect();
    // Line 5: the CU each node becomes.
    let mut cid_of: Vec<Cid> = Vec::with_capacity(plan.nodes.len());
    for node in &plan.nodes {
        cid_of.push(match &node.kind {
            NodeKind::Root => Cid::default(),
            NodeKind::Existing(cid) => {
                removal.remove(cid); // Lines 7–9.
                cid.clone()
            }
            NodeKind::Spawn => ids.cu(), // Line 13.
        });
    }
    let channels = assign_channels(env, plan, &cid_of, ids);
    let mut labour = 0.0;
    for (n, node) in plan.nodes.iter().enumerate().skip(1) {
        let Some(tf) = env.library.get(&node.tid) else {
            continue;
        };
        let cid = &cid_of[n];
        let current = env.cus.get(cid);
        if node.kind == NodeKind::Spawn {
            // Line 15: spawn.
            labour += tf.labour;
            actions.push(Action::Spawn {
                cu: cid.clone(),
                transformation: node.tid.clone(),
            });
        }
        // Line 15: connect↑ (a new channel, or the target's).
        for (j, port) in tf.outputs.iter().enumerate() {
            let want = channels.get(&(n, j)).cloned();
            let have = current.and_then(|c| c.outputs.get(port).cloned().flatten());
            match (want, have) {
                (Some(w), h) if Some(&w) != h.as_ref() => actions.push(Action::ConnectOut {
                    cu: cid.clone(),
                    port: port.clone(),
                    channel: w,
                }),
                (None, Some(h)) if taken_by_other(&channels, &h, (n, j)) => {
                    actions.push(Action::DisconnectOut {
                        cu: cid.clone(),
                        port: port.clone(),
                    });
                }
                _ => {}
            }
        }
        // Lines 15–18: connect↓ to the channel of the provider.
        for (i, port) in tf.inputs.iter().enumerate() {
            let Some(link) = node.inputs.get(i).copied().flatten() else {
                continue;
            };
            let Some(channel) = channels.get(&(link.node, link.port)) else {
                continue;
            };
            let have = current.and_then(|c| c.inputs.get(port).cloned().flatten());
            if have.as_ref() != Some(channel) {
                actions.push(Action::ConnectIn {
                    cu: cid.clone(),
                    port: port.clone(),
                    channel: channel.clone(),
                });
            }
        }
    }
    // Lines 21–23: destroy what the plan does not use; protected CUs stay.
    for cid in removal {
        if !env.cus[cid].protected {
            actions.push(Action::Destroy { cu: cid.clone() });
        }
    }
    let mut after = env.clone();
    after.apply(&actions);
    Compiled {
        actions,
        cost: summary(&after, options.horizon, labour),
        unsatisfied_targets: plan.unsatisfied(),
        optimal: exploration.proven_optimal,
    }
}

/// Whether `channel`, which out port `port` (node, index) publishes on now, is given to another
/// out port by the plan (so this one must stop publishing on it).
fn taken_by_other(
    channels: &BTreeMap<(usize, usize), Channel>,
    channel: &str,
    port: (usize, usize),
) -> bool {
    channels.iter().any(|(k, c)| c == channel && *k != port)
}

/// The channel of every out port the plan uses: the target's channel for ports feeding a
/// target; otherwise the port's current channel when it has one no other port needs, or a
/// fresh one (Alg. 6 line 11).
fn assign_channels(
    env: &Environment,
    plan: &Plan,
    cid_of: &[Cid],
    ids: &mut Ids,
) -> BTreeMap<(usize, usize), Channel> {
    let mut channels: BTreeMap<(usize, usize), Channel> = BTreeMap::new();
    for (q, link) in plan.nodes[0].inputs.iter().enumerate() {
        if let Some(l) = link {
            channels.insert(
                (l.node, l.port),
                env.targets[&plan.targets[q]].channel.clone(),
            );
        }
    }
    let taken: BTreeSet<Channel> = channels.values().cloned().collect();
    let mut used: BTreeSet<(usize, usize)> = BTreeSet::new();
    for node in plan.nodes.iter().skip(1) {
        used.extend(node.inputs.iter().flatten().map(|l| (l.node, l.port)));
    }
    for (n, j) in used {
        if channels.contains_key(&(n, j)) {
            continue;
        }
        let node = &plan.nodes[n];
        let current = env.cus.get(&cid_of[n]).and_then(|cu| {
            let port = env.library.get(&node.tid)?.outputs.get(j)?;
            cu.outputs.get(port).cloned().flatten()
        });
        let channel = match current {
            Some(c) if !taken.contains(&c) => c,
            _ => ids.channel(),
        };
        channels.insert((n, j), channel);
    }
    channels
}

fn summary(after: &Environment, horizon: f64, labour: f64) -> CostSummary {
    CostSummary::of(after, horizon, labour)
}

impl CostSummary {
    /// The estimated cost (Def. 34) of an update that spends `labour` and results in `after`:
    /// labour + horizon × the upkeep of `after`.
    pub fn of(after: &Environment, horizon: f64, labour: f64) -> Self {
        let upkeep = after.upkeep();
        Self {
            total: labour + horizon * upkeep,
            labour,
            upkeep_per_time_unit: upkeep,
            horizon,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn change_set_costs_show_without_the_noise_of_summing() {
        let cost = CostSummary {
            // The Ch. 6 ceiling switch: 10 × 0.1 and Puff's 1.0 summed in the order of the
            // CUs' names, 1.0 first (as a run with a crash before it names them).
            total: 30.000_000_000_000_007,
            labour: 0.1 + 0.2,
            upkeep_per_time_unit: 2.000_000_000_000_001,
            horizon: 10.0,
        };
        assert_ne!(cost.labour, 0.3, "the sum carries a rounding error");
        assert_eq!(
            serde_json::to_string(&cost).unwrap(),
            r#"{"total":30.0,"labour":0.3,"upkeep_per_time_unit":2.0,"horizon":10.0}"#
        );
        // Every other value keeps its first 12 significant digits, and only those.
        let mut x = 1.234_567_890_123_456_7e-7;
        for _ in 0..40 {
            let y = to_significant_digits(x);
            assert!((y - x).abs() <= 5e-12 * x.abs(), "{x} became {y}");
            assert_eq!(to_significant_digits(y), y);
            x *= 7.3;
        }
        for exact in [0.0, -0.0, 1.0, 43.0, 411.6, 1e300, -2.5] {
            assert_eq!(to_significant_digits(exact), exact);
        }
        assert!(to_significant_digits(f64::NAN).is_nan());
        assert_eq!(to_significant_digits(f64::INFINITY), f64::INFINITY);
    }
}
