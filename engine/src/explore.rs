//! EXPLORE (seed Algorithm 4) and EXPAND (Algorithm 5): a depth-first branch-and-bound search
//! for the cheapest valid computation graph, built from the root node whose inputs are the
//! targets. Nodes are CUs-to-be, one per transformation (the seed's *registry* maps tids to
//! nodes): an existing CU of the transformation (no labour), or a CU to spawn. A *job* is a node
//! with one of its in ports to satisfy; the *trace* records every choice so the search can
//! backtrack.
//!
//! Deviations from the pseudo-code, all from the issue and DyKnow-ROS:
//! - transformations may have several out ports: a choice is a (node, out port);
//! - protected CUs are never destroyed: they are nodes from the start, their inputs jobs;
//! - reusing a plan node (a *virtual* connection, `⇝`) never closes a cycle;
//! - two targets on one channel need the same out port, and one out port feeds one channel;
//! - the any-time extension (Ch. 4.3.3): past the timeout, backtracking stops once a solution
//!   exists, and the result says whether optimality was proven;
//! - the pragmatic relaxation (Def. 33): when enabled, a target may be left unsatisfied, at a
//!   cost that exceeds every real cost (lexicographically), so all targets are satisfied
//!   whenever that is possible, and as many as possible otherwise.

use std::cmp::Ordering;
use std::time::{Duration, Instant};

use rustc_hash::FxHashMap;

use crate::candidates::Candidates;
use crate::ids::{Channel, Cid, Qid, Tid};
use crate::model::Environment;

/// An estimated cost (Def. 34): targets left unsatisfied first (the relaxation), then the
/// labour plus horizon × upkeep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cost {
    /// Targets left unsatisfied.
    pub unsatisfied: u32,
    /// Labour plus horizon × upkeep.
    pub value: f64,
}

impl Cost {
    /// Nothing.
    pub const ZERO: Self = Self {
        unsatisfied: 0,
        value: 0.0,
    };
    /// More than any cost (the seed's ∞).
    pub const INFINITE: Self = Self {
        unsatisfied: u32::MAX,
        value: f64::INFINITY,
    };

    /// Whether `self` is strictly below `bound` (the order is total: unsatisfied targets,
    /// then `f64::total_cmp`).
    pub fn below(self, bound: Self) -> bool {
        self.unsatisfied
            .cmp(&bound.unsatisfied)
            .then(self.value.total_cmp(&bound.value))
            .is_lt()
    }

    fn plus(self, other: Self) -> Self {
        Self {
            unsatisfied: self.unsatisfied.saturating_add(other.unsatisfied),
            value: self.value + other.value,
        }
    }
}

impl PartialOrd for Cost {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(
            self.unsatisfied
                .cmp(&other.unsatisfied)
                .then(self.value.total_cmp(&other.value)),
        )
    }
}

/// How to explore.
#[derive(Debug, Clone)]
pub struct ExploreOptions {
    /// The horizon H, in time units.
    pub horizon: f64,
    /// The any-time extension: stop backtracking after this long (once a solution exists).
    pub timeout: Option<Duration>,
    /// The pragmatic relaxation: satisfy as many targets as possible when not all can be.
    pub relax: bool,
    /// Transformations to try first among spawns (those of crashed CUs, Ch. 4.3.3).
    pub prefer: Vec<Tid>,
}

impl Default for ExploreOptions {
    fn default() -> Self {
        Self {
            horizon: 10.0,
            timeout: None,
            relax: true,
            prefer: Vec::new(),
        }
    }
}

/// What a plan node stands for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NodeKind {
    /// The placeholder whose inputs are the targets (Alg. 4 line 7).
    Root,
    /// An existing CU, kept.
    Existing(Cid),
    /// A CU to spawn.
    Spawn,
}

/// A link to an out port of a plan node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Link {
    /// The index of the producing node in [`Plan::nodes`].
    pub node: usize,
    /// The index of its out port.
    pub port: usize,
}

/// A node of the exploration graph.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanNode {
    /// The transformation (empty for the root).
    pub tid: Tid,
    /// What the node stands for.
    pub kind: NodeKind,
    /// Each input's provider (`None` while open, or for a target left unsatisfied).
    pub inputs: Vec<Option<Link>>,
}

/// A computation graph EXPLORE chose: node 0 is the root, whose inputs are
/// [`Plan::targets`] in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The nodes, in the order the search created them.
    pub nodes: Vec<PlanNode>,
    /// The targets, in the order of the root's inputs.
    pub targets: Vec<Qid>,
}

impl Plan {
    /// The targets the plan leaves unsatisfied (the relaxation).
    pub fn unsatisfied(&self) -> Vec<Qid> {
        self.targets
            .iter()
            .zip(&self.nodes[0].inputs)
            .filter(|(_, link)| link.is_none())
            .map(|(q, _)| q.clone())
            .collect()
    }
}

/// The result of EXPLORE.
#[derive(Debug, Clone)]
pub struct Exploration {
    /// The cheapest plan found, if any.
    pub plan: Option<Plan>,
    /// Its cost (protected CUs' upkeep included).
    pub cost: Cost,
    /// Whether the search was exhaustive (the any-time extension may stop it early).
    pub proven_optimal: bool,
    /// Successful expansions (EXPAND calls that returned true).
    pub expansions: u64,
    /// Time spent.
    pub elapsed: Duration,
}

/// A job: input `input` of node `node` (Alg. 4 line 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Job {
    node: usize,
    input: usize,
}

/// A trace entry (Alg. 4 line 4): the job, which of its choices was taken, whether that
/// created a node (`→`) or reused one (`⇝`), and the cost before and after.
#[derive(Debug, Clone, Copy)]
struct Entry {
    job: Job,
    choice: usize,
    created: bool,
    before: Cost,
    after: Cost,
}

/// A choice for a job. Order: the current provider first (a review keeps what works at equal
/// cost); then reuse of a plan node (free, Ch. 4.3.3); then new nodes, those of crashed CUs'
/// transformations first (Ch. 4.3.3), then by the estimated cost of their whole subtree.
#[derive(Debug, Clone, Copy)]
enum Choice {
    Reuse(Link),
    New {
        tid: usize,
        port: usize,
        existing: Option<usize>,
        cost: f64,
    },
    Unsatisfied,
}

/// A static candidate of a job: a provider, as an existing CU or a spawn.
#[derive(Debug, Clone, Copy)]
struct Static {
    tid: usize,
    port: usize,
    existing: Option<usize>,
    cost: f64,
}

struct Search<'a> {
    options: &'a ExploreOptions,
    tids: Vec<Tid>,
    in_counts: Vec<usize>,
    cus: Vec<Cid>,
    targets: Vec<Qid>,
    target_channels: Vec<Channel>,
    /// Static candidates per (tid, input), and per target.
    for_input: Vec<Vec<Vec<Static>>>,
    for_target: Vec<Vec<Static>>,
    nodes: Vec<PlanNode>,
    node_tids: Vec<usize>,
    /// tid → node (Alg. 4 line 2).
    registry: FxHashMap<usize, usize>,
    /// What feeds each input of each existing CU now: (CU, out port).
    current_in: FxHashMap<(Cid, usize), (Cid, usize)>,
    /// What feeds each target now.
    current_target: Vec<Option<(Cid, usize)>>,
}

/// EXPLORE(ε, δp) (Algorithm 4): the cheapest plan for the targets of `env`, reusing its CUs
/// where that pays. `env` is the environment after the perturbation (ε ⊗ δp).
pub fn explore(
    env: &Environment,
    candidates: &Candidates,
    options: &ExploreOptions,
) -> Exploration {
    let start = Instant::now();
    let mut search = Search::new(env, candidates, options);
    // Protected CUs are paid for whatever the plan: a constant.
    let constant = options.horizon
        * env
            .cus
            .values()
            .filter(|c| c.protected)
            .map(|c| env.library.get(&c.tid).map_or(0.0, |t| t.upkeep))
            .sum::<f64>();

    // Lines 2–7: registry, open jobs, trace, best trace, best cost, root.
    let mut jobs: Vec<Job> = Vec::new();
    for (n, node) in search.nodes.iter().enumerate().rev() {
        for i in (0..node.inputs.len()).rev() {
            jobs.push(Job { node: n, input: i });
        }
    }
    let mut trace: Vec<Entry> = Vec::new();
    let mut best: Option<Vec<PlanNode>> = None;
    let mut best_cost = Cost::INFINITE;
    let mut sum = Cost::ZERO;
    let mut from = 0;
    let mut expansions = 0u64;
    let mut proven_optimal = true;
    let mut steps = 0u64;
    let deadline = options.timeout.map(|t| start + t);
    // Lines 9–40.
    loop {
        // Lines 11–23: expand open jobs until one fails or none is left.
        if let Some(job) = jobs.pop() {
            if let Some(entry) = search.expand(job, from, sum, best_cost) {
                // Lines 15–18: a new node's inputs become open jobs; candidate indices of
                // the jobs now on top start from the first candidate again.
                expansions += 1;
                if entry.created {
                    let n = search.nodes.len() - 1;
                    for i in (0..search.nodes[n].inputs.len()).rev() {
                        jobs.push(Job { node: n, input: i });
                    }
                }
                sum = entry.after;
                trace.push(entry);
                from = 0;
                continue;
            }
            // Lines 20–21: expansion failure.
            jobs.push(job);
        } else if sum.below(best_cost) {
            // Lines 26–28: a complete graph, better than the best so far.
            best_cost = sum;
            best = Some(search.nodes.clone());
        }
        // Line 24, with the any-time guard of Ch. 4.3.3.
        steps += 1;
        if steps.is_multiple_of(256)
            && best.is_some()
            && deadline.is_some_and(|d| Instant::now() >= d)
        {
            proven_optimal = trace.is_empty();
            break;
        }
        // Lines 25–36: undo the last choice and retry its job from the next candidate.
        let Some(entry) = trace.pop() else {
            break; // Line 38.
        };
        if entry.created {
            // Lines 32–34: drop the node and its (now invalidated) jobs.
            let n = search.nodes.len() - 1;
            let inputs = search.nodes[n].inputs.len();
            jobs.truncate(jobs.len() - inputs);
            let tid = search.node_tids[n];
            search.registry.remove(&tid);
            search.nodes.pop();
            search.node_tids.pop();
        }
        // Lines 30–31.
        search.nodes[entry.job.node].inputs[entry.job.input] = None;
        jobs.push(entry.job); // Line 36.
        from = entry.choice + 1;
        sum = entry.before;
    }
    let plan = best.map(|nodes| Plan {
        nodes,
        targets: search.targets.clone(),
    });
    Exploration {
        cost: if plan.is_some() {
            best_cost.plus(Cost {
                unsatisfied: 0,
                value: constant,
            })
        } else {
            Cost::INFINITE
        },
        plan,
        proven_optimal,
        expansions,
        elapsed: start.elapsed(),
    }
}

impl<'a> Search<'a> {
    fn new(env: &Environment, candidates: &Candidates, options: &'a ExploreOptions) -> Self {
        let tids: Vec<Tid> = env.library.keys().cloned().collect();
        let tid_index: FxHashMap<Tid, usize> = tids
            .iter()
            .enumerate()
            .map(|(i, t)| (t.clone(), i))
            .collect();
        let cus: Vec<Cid> = env.cus.keys().cloned().collect();
        // Existing CUs of each transformation (valid ones: the transformation exists).
        let mut existing: Vec<Vec<usize>> = vec![Vec::new(); tids.len()];
        for (c, cid) in cus.iter().enumerate() {
            if let Some(t) = tid_index.get(env.cus[cid].tid.as_str()) {
                existing[*t].push(c);
            }
        }
        let h = options.horizon;
        // Ordering heuristic (Ch. 4.3.3 leaves it open): the estimated cost of a transformation's
        // whole subtree, its own cost plus the cheapest subtree for each input, ignoring sharing
        // (so not a bound, only an order). Computed by relaxation; cycles stay unbounded.
        let own: Vec<f64> = tids
            .iter()
            .enumerate()
            .map(|(t, tid)| {
                let tf = &env.library[tid];
                if existing[t].iter().any(|c| env.cus[&cus[*c]].protected) {
                    0.0
                } else if existing[t].is_empty() {
                    tf.labour + h * tf.upkeep
                } else {
                    h * tf.upkeep
                }
            })
            .collect();
        let inputs_of: Vec<Vec<Vec<usize>>> = tids
            .iter()
            .map(|t| {
                (0..env.library[t].inputs.len())
                    .map(|i| {
                        candidates
                            .for_input(t, i)
                            .iter()
                            .filter_map(|p| tid_index.get(p.tid.as_str()).copied())
                            .collect()
                    })
                    .collect()
            })
            .collect();
        let mut subtree = vec![f64::INFINITY; tids.len()];
        for _ in 0..=tids.len() {
            let mut changed = false;
            for t in 0..tids.len() {
                let below: f64 = inputs_of[t]
                    .iter()
                    .map(|ps| ps.iter().map(|p| subtree[*p]).fold(f64::INFINITY, f64::min))
                    .sum();
                let estimate = own[t] + below;
                if estimate < subtree[t] {
                    subtree[t] = estimate;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        let statics = |providers: &[crate::candidates::Provider]| -> Vec<Static> {
            let mut out = Vec::new();
            for p in providers {
                let Some(&t) = tid_index.get(p.tid.as_str()) else {
                    continue;
                };
                // A transformation whose inputs can never be fed from sources (the subtree
                // estimate stayed infinite: the least fixpoint of "every input has a feedable
                // provider") is in no valid plan; offering it would only make the search
                // thrash through dead ends.
                if !subtree[t].is_finite() {
                    continue;
                }
                let tf = &env.library[&p.tid];
                if p.port >= tf.outputs.len() {
                    continue;
                }
                if existing[t].is_empty() {
                    out.push(Static {
                        tid: t,
                        port: p.port,
                        existing: None,
                        cost: tf.labour + h * tf.upkeep,
                    });
                } else {
                    for c in &existing[t] {
                        let protected = env.cus[&cus[*c]].protected;
                        out.push(Static {
                            tid: t,
                            port: p.port,
                            existing: Some(*c),
                            cost: if protected { 0.0 } else { h * tf.upkeep },
                        });
                    }
                }
            }
            let preferred = |s: &Static| {
                s.existing.is_none() && options.prefer.iter().any(|p| *p == tids[s.tid])
            };
            // Preferred transformations (those of crashed CUs) first, then the cheapest
            // estimated subtree, then the cheapest node, existing CUs before spawns.
            out.sort_by(|a, b| {
                preferred(b)
                    .cmp(&preferred(a))
                    .then(subtree[a.tid].total_cmp(&subtree[b.tid]))
                    .then(a.cost.total_cmp(&b.cost))
                    .then(a.existing.is_none().cmp(&b.existing.is_none()))
                    .then(a.tid.cmp(&b.tid))
                    .then(a.existing.cmp(&b.existing))
                    .then(a.port.cmp(&b.port))
            });
            out
        };
        let for_input = tids
            .iter()
            .map(|t| {
                (0..env.library[t].inputs.len())
                    .map(|i| statics(candidates.for_input(t, i)))
                    .collect()
            })
            .collect();
        let targets: Vec<Qid> = env.targets.keys().cloned().collect();
        let for_target = targets
            .iter()
            .map(|q| statics(candidates.for_target(q)))
            .collect();
        let target_channels = targets
            .iter()
            .map(|q| env.targets[q].channel.clone())
            .collect();
        let in_counts = tids.iter().map(|t| env.library[t].inputs.len()).collect();
        // The current wiring, tried first so that a review keeps what works at equal cost.
        let publishers = env.publishers();
        let provider_of = |channel: Option<&str>| -> Option<(Cid, usize)> {
            let (cid, port) = publishers.get(channel?)?.first()?;
            let tf = env.library.get(&env.cus.get(*cid)?.tid)?;
            Some((Cid::from(*cid), tf.outputs.iter().position(|p| p == port)?))
        };
        let mut current_in = FxHashMap::default();
        for cu in env.cus.values() {
            if let Some(tf) = env.library.get(&cu.tid) {
                for (i, port) in tf.inputs.iter().enumerate() {
                    let bound = cu.inputs.get(port).and_then(|c| c.as_deref());
                    if let Some(p) = provider_of(bound) {
                        current_in.insert((cu.cid.clone(), i), p);
                    }
                }
            }
        }
        let current_target = targets
            .iter()
            .map(|q| provider_of(Some(env.targets[q].channel.as_str())))
            .collect();
        let mut search = Self {
            options,
            tids,
            in_counts,
            cus,
            targets,
            target_channels,
            for_input,
            for_target,
            nodes: Vec::new(),
            node_tids: Vec::new(),
            registry: FxHashMap::default(),
            current_in,
            current_target,
        };
        // Line 7: the root; then protected CUs, which stay whatever the plan.
        search.nodes.push(PlanNode {
            tid: Tid::default(),
            kind: NodeKind::Root,
            inputs: vec![None; search.targets.len()],
        });
        search.node_tids.push(usize::MAX);
        for cid in &search.cus.clone() {
            let cu = &env.cus[cid];
            if !cu.protected {
                continue;
            }
            let Some(&t) = tid_index.get(cu.tid.as_str()) else {
                continue;
            };
            search.registry.entry(t).or_insert(search.nodes.len());
            search.nodes.push(PlanNode {
                tid: cu.tid.clone(),
                kind: NodeKind::Existing(cid.clone()),
                inputs: vec![None; search.in_counts[t]],
            });
            search.node_tids.push(t);
        }
        search
    }

    /// The choices of a job, in order (the seed's getCandidate, Alg. 5 line 6).
    fn choices(&self, job: Job) -> Vec<Choice> {
        let statics = if job.node == 0 {
            &self.for_target[job.input]
        } else {
            &self.for_input[self.node_tids[job.node]][job.input]
        };
        let mut out = Vec::with_capacity(statics.len() + 1);
        // Plan nodes first (free), once per (node, port).
        for s in statics {
            if let Some(&n) = self.registry.get(&s.tid)
                && !out
                    .iter()
                    .any(|c| matches!(c, Choice::Reuse(l) if l.node == n && l.port == s.port))
            {
                out.push(Choice::Reuse(Link {
                    node: n,
                    port: s.port,
                }));
            }
        }
        for s in statics {
            if !self.registry.contains_key(&s.tid) {
                out.push(Choice::New {
                    tid: s.tid,
                    port: s.port,
                    existing: s.existing,
                    cost: s.cost,
                });
            }
        }
        // The current provider first.
        let current = match &self.nodes[job.node].kind {
            NodeKind::Root => self.current_target[job.input].as_ref(),
            NodeKind::Existing(cid) => self.current_in.get(&(cid.clone(), job.input)),
            NodeKind::Spawn => None,
        };
        if let Some((cid, port)) = current {
            let is_current = |c: &Choice| match c {
                Choice::Reuse(l) => {
                    l.port == *port
                        && matches!(&self.nodes[l.node].kind, NodeKind::Existing(e) if e == cid)
                }
                Choice::New {
                    existing: Some(e),
                    port: p,
                    ..
                } => p == port && self.cus[*e] == *cid,
                _ => false,
            };
            if let Some(k) = out.iter().position(is_current) {
                let c = out.remove(k);
                out.insert(0, c);
            }
        }
        if job.node == 0 && self.options.relax {
            out.push(Choice::Unsatisfied);
        }
        out
    }

    /// Whether `to` is reachable from `from` along inputs (so linking `to` to read from
    /// `from` would close a cycle).
    fn reaches(&self, from: usize, to: usize) -> bool {
        let mut stack = vec![from];
        let mut seen = vec![false; self.nodes.len()];
        while let Some(n) = stack.pop() {
            if n == to {
                return true;
            }
            if std::mem::replace(&mut seen[n], true) {
                continue;
            }
            stack.extend(self.nodes[n].inputs.iter().flatten().map(|l| l.node));
        }
        false
    }

    /// Whether feeding target `q` from `link` clashes with another target's channel: two
    /// targets on one channel need the same out port, one out port feeds one channel. A new
    /// node (`link == None`) clashes with any target already fed on the same channel.
    fn channel_clash(&self, q: usize, link: Option<Link>) -> bool {
        self.nodes[0]
            .inputs
            .iter()
            .enumerate()
            .any(|(other, fed)| match fed {
                Some(l) if other != q => {
                    let same_channel = self.target_channels[other] == self.target_channels[q];
                    let same_port = Some(*l) == link;
                    same_channel != same_port
                }
                _ => false,
            })
    }

    /// EXPAND(node, i, …) (Algorithm 5): tries the choices of `job` from index `from` and
    /// takes the first that keeps the cost under `best` (line 10) and the graph acyclic.
    fn expand(&mut self, job: Job, from: usize, sum: Cost, best: Cost) -> Option<Entry> {
        let choices = self.choices(job);
        // Lines 5–26.
        for (k, choice) in choices.iter().enumerate().skip(from) {
            match *choice {
                Choice::Reuse(link) => {
                    // Lines 19–23: a virtual connection, free, unless it closes a cycle.
                    if !sum.below(best)
                        || self.reaches(link.node, job.node)
                        || (job.node == 0 && self.channel_clash(job.input, Some(link)))
                    {
                        continue;
                    }
                    self.nodes[job.node].inputs[job.input] = Some(link);
                    return Some(Entry {
                        job,
                        choice: k,
                        created: false,
                        before: sum,
                        after: sum,
                    });
                }
                Choice::New {
                    tid,
                    port,
                    existing,
                    cost,
                } => {
                    // Lines 9–18: a new node, if the cost stays under the best.
                    let after = sum.plus(Cost {
                        unsatisfied: 0,
                        value: cost,
                    });
                    if !after.below(best) || (job.node == 0 && self.channel_clash(job.input, None))
                    {
                        continue;
                    }
                    let n = self.nodes.len();
                    self.nodes.push(PlanNode {
                        tid: self.tids[tid].clone(),
                        kind: match existing {
                            Some(c) => NodeKind::Existing(self.cus[c].clone()),
                            None => NodeKind::Spawn,
                        },
                        inputs: vec![None; self.in_counts[tid]],
                    });
                    self.node_tids.push(tid);
                    self.registry.insert(tid, n);
                    self.nodes[job.node].inputs[job.input] = Some(Link { node: n, port });
                    return Some(Entry {
                        job,
                        choice: k,
                        created: true,
                        before: sum,
                        after,
                    });
                }
                Choice::Unsatisfied => {
                    let after = sum.plus(Cost {
                        unsatisfied: 1,
                        value: 0.0,
                    });
                    if !after.below(best) {
                        continue;
                    }
                    return Some(Entry {
                        job,
                        choice: k,
                        created: false,
                        before: sum,
                        after,
                    });
                }
            }
        }
        None // Line 27.
    }
}
