//! EXPLORE (seed Algorithm 4) and EXPAND (Algorithm 5): a depth-first branch-and-bound search
//! for the cheapest valid computation graph, built from the root node whose inputs are the
//! targets. Nodes are CUs-to-be, one per transformation (the seed's *registry* maps tids to
//! nodes) unless a target needs a further one: an existing CU of the transformation (no
//! labour), or a CU to spawn. A *job* is a node
//! with one of its in ports to satisfy; the *trace* records every choice so the search can
//! backtrack.
//!
//! Deviations from the pseudo-code, all from the issue and DyKnow-ROS:
//! - transformations may have several out ports: a choice is a (node, out port);
//! - protected CUs are never destroyed: they are nodes from the start, their inputs jobs;
//! - reusing a plan node (a *virtual* connection, `⇝`) never closes a cycle;
//! - two targets on one channel need the same out port, and one out port feeds one channel;
//! - a transformation may run more than once: a target whose stream every node of its
//!   transformation already publishes on another target's channel may get a further CU of it
//!   ([`Search::further_choices`]);
//! - the any-time extension (Ch. 4.3.3): past the timeout, backtracking stops once a solution
//!   exists, and the result says whether optimality was proven; with a timeout, *probes*
//!   (a large-neighbourhood search around the best graph, taking turns with the main search,
//!   and a second one on a thread of its own, all sharing one best graph) look for cheaper
//!   graphs outside its first top-level decisions ([`ProbeOptions`]; the main search stays
//!   exhaustive);
//! - the pragmatic relaxation (Def. 33): when enabled, a target may be left unsatisfied, at a
//!   cost that exceeds every real cost (lexicographically), so all targets are satisfied
//!   whenever that is possible, and as many as possible otherwise;
//! - line 10's test `cost < bestCost` is strengthened with an admissible lower bound on what the
//!   open jobs still cost ([`Search::lower_bound`]): a partial graph is abandoned as soon as its
//!   cost *plus the bound* reaches the best cost. The bound never exceeds the cheapest
//!   completion, so the optimum is never pruned (the brute-force property test checks both).

use std::cmp::Ordering;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering as AtomicOrdering};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use rustc_hash::FxHashMap;

use crate::candidates::Candidates;
use crate::ids::{Channel, Cid, Qid, Tid};
use crate::model::Environment;

mod reroute;
use reroute::Reroute;

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
    /// The any-time probes (with a timeout only; see [`explore`]); `None` turns them off.
    pub probes: Option<ProbeOptions>,
}

/// When and how long the any-time probes search (see [`explore`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProbeOptions {
    /// Backtracks of the main search before the first probe (so a search that ends at once,
    /// e.g. for its first solution, never copies its state for one).
    pub after: u64,
    /// The main search and the probes on its thread take turns: the main search for this many
    /// backtracks, then the probes: up to three times the main search's time in all while
    /// they keep finding cheaper graphs, an eighth of it once they stop.
    pub every: u64,
    /// Further probes, each on a thread of its own beside the main search, with seeds of its
    /// own, from the time the probes start until the main search ends or the deadline passes.
    pub threads: usize,
    /// Backtracks of one probe round before the next round (another neighbourhood).
    pub limit: u64,
    /// Rounds without a cheaper graph after which the further probes help the main search
    /// with its proof instead (a subtree of it at a time).
    pub help_after: u64,
}

impl Default for ProbeOptions {
    fn default() -> Self {
        Self {
            after: 16,
            every: 16,
            threads: 1,
            limit: 64,
            help_after: GAIN_WINDOW,
        }
    }
}

impl Default for ExploreOptions {
    fn default() -> Self {
        Self {
            horizon: 10.0,
            timeout: None,
            relax: true,
            prefer: Vec::new(),
            probes: Some(ProbeOptions::default()),
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
    /// A proven lower bound on the optimum: the cost itself when optimality was proven,
    /// otherwise the admissible bound at the root (so `cost - bound` bounds the any-time gap).
    pub bound: Cost,
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
    /// The job's later choices were given to another thread ([`Dfs::give`]): undoing this
    /// entry leaves the job without choices.
    given: bool,
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

#[derive(Clone)]
struct Search<'a> {
    options: &'a ExploreOptions,
    /// The probes' reordering of new-node choices (none in the main search).
    perturbation: Option<Perturbation>,
    /// The probes' neighbourhood: providers their jobs keep (none in the main search).
    guide: Option<Guide>,
    tids: Vec<Tid>,
    /// Each transformation's position in the whole library: what the probes' random draws
    /// are keyed by (the search leaves out what no plan can use, see [`relevant`]).
    keys: Arc<[u64]>,
    in_counts: Vec<usize>,
    cus: Vec<Cid>,
    targets: Vec<Qid>,
    target_channels: Vec<Channel>,
    /// Static candidates per (tid, input), and per target.
    for_input: Vec<Vec<Vec<Static>>>,
    for_target: Vec<Vec<Static>>,
    nodes: Vec<PlanNode>,
    node_tids: Vec<usize>,
    /// tid → its nodes, in creation order (Alg. 4 line 2; more than one when a transformation
    /// runs twice to publish on a second target channel, or has several protected CUs).
    registry: Vec<Vec<usize>>,
    /// The existing CUs of each transformation.
    existing_of: Vec<Vec<usize>>,
    /// What a further CU of each transformation costs: an existing one kept (horizon ×
    /// upkeep), or a spawn (labour + horizon × upkeep).
    keep_cost: Vec<f64>,
    spawn_cost: Vec<f64>,
    /// A lower bound on what a CU of a transformation costs beyond its first one: `keep_cost`
    /// when it has two existing CUs or more, else `spawn_cost`.
    further_cost: Vec<f64>,
    /// What feeds each input of each existing CU now: (CU, out port).
    current_in: FxHashMap<(Cid, usize), (Cid, usize)>,
    /// What feeds each target now.
    current_target: Vec<Option<(Cid, usize)>>,
    /// The cheapest node of each transformation (an existing CU's upkeep, or a spawn's labour
    /// and upkeep; 0 for protected CUs).
    own: Vec<f64>,
    /// The distinct transformations that may feed each (tid, input), and each target.
    /// Identical lists are one shared slice, so jobs wanting the same providers are grouped.
    providers_input: Vec<Vec<Arc<[usize]>>>,
    providers_target: Vec<Arc<[usize]>>,
    /// Whether a transformation has a node in the plan (the registry as a bitmap).
    in_plan: Vec<bool>,
    /// Each target's channel, as an index (equal for targets on one channel).
    channel_of: Vec<usize>,
    /// The distinct (tid, out port) pairs that may feed each target.
    ports_target: Vec<Vec<(usize, usize)>>,
    /// The static subtree estimate of each transformation (an order, not a bound), and whether
    /// it is preferred (a crashed CU's).
    subtree: Vec<f64>,
    preferred: Vec<bool>,
    /// Whether a transformation may feed a target, and its number of out ports.
    feeds_targets: Vec<bool>,
    out_counts: Vec<usize>,
    /// Scratch space of [`Search::lower_bound`].
    scratch: Scratch,
}

/// Epoch-stamped scratch arrays of [`Search::lower_bound`] (no clearing between bounds).
#[derive(Default, Clone)]
struct Scratch {
    epoch: u32,
    /// Open jobs whose reach contains each transformation, valid when `counted == epoch`.
    reach_count: Vec<u32>,
    counted: Vec<u32>,
    /// Consumer slots that may read from each transformation, valid when `slotted == epoch`.
    slots: Vec<u32>,
    slotted: Vec<u32>,
    /// Whether a transformation is in the union of the reaches (`== epoch`).
    in_union: Vec<u32>,
    /// The job whose reach last visited each transformation.
    visited_by: Vec<u32>,
    job_epoch: u32,
    /// The chain (0), flow (1) and chain below target providers (2) values.
    memo: [Memo; 3],
    stack: Vec<(usize, bool)>,
}

/// Memoised values: `valued == epoch` when done, `entered == epoch` once entered (in progress
/// until valued).
#[derive(Default, Clone)]
struct Memo {
    value: Vec<f64>,
    valued: Vec<u32>,
    entered: Vec<u32>,
}

impl Memo {
    fn new(n: usize) -> Self {
        Self {
            value: vec![0.0; n],
            valued: vec![0; n],
            entered: vec![0; n],
        }
    }
}

impl Scratch {
    fn new(n: usize) -> Self {
        Self {
            reach_count: vec![0; n],
            counted: vec![0; n],
            slots: vec![0; n],
            slotted: vec![0; n],
            in_union: vec![0; n],
            visited_by: vec![0; n],
            memo: [Memo::new(n), Memo::new(n), Memo::new(n)],
            ..Self::default()
        }
    }

    fn add_slots(&mut self, t: usize, epoch: u32, count: u32) {
        if self.slotted[t] == epoch {
            self.slots[t] += count;
        } else {
            self.slotted[t] = epoch;
            self.slots[t] = count;
        }
    }
}

/// A minimum-cost assignment of rows to distinct columns, as many rows as possible first:
/// (rows left unassigned, total cost). `rows[r]` lists the (column, cost) pairs row `r` may
/// take.
///
/// Rows that share no column, directly or through other rows, do not compete: the problem
/// splits into the connected components of the rows (union-find over the columns they list).
/// A row alone in its component takes its cheapest column, or stays unassigned if it lists
/// none; larger components go to [`hungarian`]. The optimum is the sum of the components'
/// optima (first fewest unassigned, then least cost, both additive). Without the split, the
/// dense method took O(n² m) time and n·m cells for n rows: a formula group's thousands of
/// symbol targets, each with a channel of its own and no producer, made it allocate
/// gigabytes and take seconds per bound.
fn assignment(rows: &[Vec<(usize, f64)>], columns: usize) -> (usize, f64) {
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    // Union-find over the rows: each column joins the first row that lists it with the rest.
    let mut parent: Vec<usize> = (0..rows.len()).collect();
    let mut first_row = vec![usize::MAX; columns];
    for (r, row) in rows.iter().enumerate() {
        for &(c, _) in row {
            if first_row[c] == usize::MAX {
                first_row[c] = r;
            } else {
                let (a, b) = (find(&mut parent, first_row[c]), find(&mut parent, r));
                if a != b {
                    parent[a.max(b)] = a.min(b);
                }
            }
        }
    }
    let mut members: FxHashMap<usize, Vec<usize>> = FxHashMap::default();
    let mut order = Vec::new();
    for r in 0..rows.len() {
        let root = find(&mut parent, r);
        members
            .entry(root)
            .or_insert_with(|| {
                order.push(root);
                Vec::new()
            })
            .push(r);
    }
    let mut unassigned = 0;
    let mut cost = 0.0;
    for root in order {
        let component = &members[&root];
        if let [r] = component.as_slice() {
            match rows[*r].iter().map(|(_, c)| *c).reduce(f64::min) {
                Some(c) => cost += c,
                None => unassigned += 1,
            }
            continue;
        }
        // Renumber the component's columns densely.
        let mut local: FxHashMap<usize, usize> = FxHashMap::default();
        let sub: Vec<Vec<(usize, f64)>> = component
            .iter()
            .map(|r| {
                rows[*r]
                    .iter()
                    .map(|&(c, w)| {
                        let next = local.len();
                        (*local.entry(c).or_insert(next), w)
                    })
                    .collect()
            })
            .collect();
        let (u, c) = hungarian(&sub, local.len());
        unassigned += u;
        cost += c;
    }
    (unassigned, cost)
}

/// [`assignment`] by the Hungarian method (shortest augmenting paths with potentials,
/// O(n² m)), with one dummy column per row at a cost above every real assignment.
fn hungarian(rows: &[Vec<(usize, f64)>], columns: usize) -> (usize, f64) {
    let n = rows.len();
    if n == 0 {
        return (0, 0.0);
    }
    let real: f64 = rows.iter().flatten().map(|(_, c)| c.abs()).sum::<f64>() + 1.0;
    let dummy = real * (n as f64 + 1.0);
    let forbidden = dummy * (n as f64 + 1.0);
    let m = columns + n;
    let mut dense = vec![forbidden; n * m];
    for (r, row) in rows.iter().enumerate() {
        for &(c, cost) in row {
            let cell = &mut dense[r * m + c];
            *cell = cell.min(cost);
        }
        for c in columns..m {
            dense[r * m + c] = dummy;
        }
    }
    // 1-based potentials and matches (e-maxx's formulation); column 0 is the virtual start.
    let mut u = vec![0.0f64; n + 1];
    let mut v = vec![0.0f64; m + 1];
    let mut owner = vec![0usize; m + 1];
    let mut way = vec![0usize; m + 1];
    let mut min_to = vec![0.0f64; m + 1];
    let mut used = vec![false; m + 1];
    for i in 1..=n {
        owner[0] = i;
        let mut j0 = 0;
        min_to.fill(f64::INFINITY);
        used.fill(false);
        loop {
            used[j0] = true;
            let i0 = owner[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0;
            for j in 1..=m {
                if !used[j] {
                    let cur = dense[(i0 - 1) * m + (j - 1)] - u[i0] - v[j];
                    if cur < min_to[j] {
                        min_to[j] = cur;
                        way[j] = j0;
                    }
                    if min_to[j] < delta {
                        delta = min_to[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[owner[j]] += delta;
                    v[j] -= delta;
                } else {
                    min_to[j] -= delta;
                }
            }
            j0 = j1;
            if owner[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            owner[j0] = owner[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut unassigned = 0;
    let mut cost = 0.0;
    for j in 1..=m {
        let r = owner[j];
        if r == 0 {
            continue;
        }
        if j > columns {
            unassigned += 1;
        } else {
            cost += dense[(r - 1) * m + (j - 1)];
        }
    }
    (unassigned, cost)
}

/// The size of a maximum matching of left nodes to right nodes (Kuhn's augmenting paths): the
/// reference the assignment's property test compares with.
#[cfg(test)]
fn matching(edges: &[Vec<usize>], right: usize) -> usize {
    fn augment(u: usize, edges: &[Vec<usize>], seen: &mut [bool], owner: &mut [usize]) -> bool {
        for &v in &edges[u] {
            if !std::mem::replace(&mut seen[v], true)
                && (owner[v] == usize::MAX || augment(owner[v], edges, seen, owner))
            {
                owner[v] = u;
                return true;
            }
        }
        false
    }
    let mut owner = vec![usize::MAX; right];
    let mut seen = vec![false; right];
    (0..edges.len())
        .filter(|u| {
            seen.fill(false);
            augment(*u, edges, &mut seen, &mut owner)
        })
        .count()
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
    let constant = protected_upkeep(env, options);
    let deadline = options.timeout.map(|t| start + t);
    // Any-time mode only: the probes, and further probes on threads of their own.
    let probing = options.probes.filter(|_| deadline.is_some());
    // Lines 2–7: registry, open jobs, trace, best trace, best cost, root.
    let mut main = Dfs::root(&search);
    let mut best = Best::NONE;
    let mut expansions = 0u64;
    let mut proven_optimal = true;
    let mut steps = 0u64;
    let root_bound = search.lower_bound(&main.jobs, Cost::INFINITE);
    let shared = Shared::default();
    let split = Split::default();
    // Lines 9–40.
    std::thread::scope(|scope| {
        let mut probes: Option<Probes<'_>> = None;
        let mut beside: Vec<std::thread::ScopedJoinHandle<'_, u64>> = Vec::new();
        let mut seen = 0u64;
        let mut since = Instant::now();
        let (mut main_time, mut probe_time) = (Duration::ZERO, Duration::ZERO);
        let mut last_gain = 0u64;
        let halt = || deadline.is_some_and(|d| Instant::now() >= d);
        // From this moment on, the probes' share while they find cheaper graphs grows.
        let late = options.timeout.map(|t| start + t.mul_f64(LATE_AFTER));
        loop {
            let before = best.cost;
            match main.step(&mut search, &mut best) {
                Step::Expanded => {
                    expansions += 1;
                    // A dive through a large graph takes milliseconds: the deadline is
                    // looked at during it too.
                    if best.nodes.is_some() && halt() {
                        proven_optimal = false;
                        break;
                    }
                    continue;
                }
                Step::Exhausted => {
                    // Line 38, once the subtrees given away are exhausted too.
                    if !beside.is_empty() {
                        shared.exchange(before, &mut best, &mut seen);
                        proven_optimal =
                            split.settle(&shared, &mut best, &mut seen, &mut expansions, &halt);
                    }
                    break;
                }
                Step::Backtracked => {}
            }
            // The other threads' cheaper graphs prune the main search; its own go to them, and
            // so does a part of it when one of them asks.
            if !beside.is_empty() {
                shared.exchange(before, &mut best, &mut seen);
                split.serve(&mut main, &search);
            }
            // Line 24, with the any-time guard of Ch. 4.3.3.
            steps += 1;
            if steps.is_multiple_of(16) && best.nodes.is_some() && halt() {
                // `step` has undone a choice already: even with the trace empty, the root's
                // job has choices left (an exhausted search ended above, with its proof).
                proven_optimal = false;
                break;
            }
            if let Some(p) = probing
                && best.nodes.is_some()
                && steps >= p.after
                && steps.is_multiple_of(p.every.max(1))
            {
                // The probes run while they have had less time in all than their share of
                // the main search's (one dive may overshoot; the next turn then waits), and
                // never past the deadline.
                main_time += since.elapsed();
                // At the first turn, further probes start too, each with seeds of its own, on
                // threads of their own. One that cannot start leaves the others to it.
                if probes.is_none() {
                    if p.threads > 0 {
                        shared.publish(&best, &mut seen);
                    }
                    for k in 1..=p.threads as u64 {
                        let (shared, split) = (&shared, &split);
                        let (copy, dfs) = (search.clone(), main.clone());
                        let theirs = move || {
                            Probes::of(copy, dfs, p.limit, k).search(
                                shared,
                                split,
                                p.help_after,
                                deadline,
                            )
                        };
                        beside.extend(
                            std::thread::Builder::new()
                                .name(format!("explore-probes-{k}"))
                                .spawn_scoped(scope, theirs)
                                .ok(),
                        );
                    }
                }
                let probes = probes.get_or_insert_with(|| Probes::new(&search, &main, p.limit, 0));
                // While they keep finding cheaper graphs the probes take three parts of the
                // time to the main search's one, twenty after the first tenth of the timeout;
                // once they stop an eighth (the main search's proof then comes sooner).
                let fresh = probes.round < last_gain + GAIN_WINDOW;
                let share = match (fresh, late.is_some_and(|l| Instant::now() >= l)) {
                    (false, _) => SHARE_STALE,
                    (true, false) => SHARE_FRESH,
                    (true, true) => SHARE_LATE,
                };
                while probe_time.as_secs_f64() < share * main_time.as_secs_f64() && !halt() {
                    let turn = Instant::now();
                    let before = best.cost;
                    probes.run(&mut best, &mut expansions, &halt);
                    probe_time += turn.elapsed();
                    if best.cost.below(before) {
                        last_gain = probes.round;
                    }
                    if !beside.is_empty() {
                        shared.exchange(before, &mut best, &mut seen);
                    }
                }
                // The probes' turn ended at the deadline: so does the search (the main
                // search's own check may be 16 slow backtracks away).
                if halt() {
                    proven_optimal = false;
                    break;
                }
                since = Instant::now();
            }
        }
        shared.stop.store(true, AtomicOrdering::Relaxed);
        for handle in beside.drain(..) {
            match handle.join() {
                Ok(theirs) => expansions += theirs,
                Err(panic) => std::panic::resume_unwind(panic),
            }
            // The cheapest of the bests (the main search's proof covers them all).
            shared.refresh(&mut best, &mut seen);
        }
    });
    let plan = best.nodes.map(|nodes| Plan {
        nodes,
        targets: search.targets.clone(),
    });
    let constant_cost = Cost {
        unsatisfied: 0,
        value: constant,
    };
    let bound = match (&plan, proven_optimal) {
        (Some(_), true) => best.cost.plus(constant_cost),
        (None, true) => Cost::INFINITE,
        _ => root_bound.plus(constant_cost),
    };
    Exploration {
        bound,
        cost: if plan.is_some() {
            best.cost.plus(constant_cost)
        } else {
            Cost::INFINITE
        },
        plan,
        proven_optimal,
        expansions,
        elapsed: start.elapsed(),
    }
}

/// The cheapest complete graph found so far (Alg. 4's best trace and best cost).
#[derive(Clone)]
struct Best {
    cost: Cost,
    nodes: Option<Vec<PlanNode>>,
    /// The transformation (index) of each of its nodes (`usize::MAX` for the root).
    node_tids: Vec<usize>,
}

/// The best graph the main search's thread and the probes' threads share.
struct Shared {
    best: Mutex<Best>,
    /// Bumped, under the lock, on every cheaper graph published: a thread copies `best` only
    /// when it changed since it last looked (an atomic load per backtrack otherwise).
    version: AtomicU64,
    /// Set when the main search ends (its proof or the deadline): the probes stop.
    stop: AtomicBool,
}

impl Best {
    /// No graph yet, at the seed's ∞.
    const NONE: Self = Self {
        cost: Cost::INFINITE,
        nodes: None,
        node_tids: Vec::new(),
    };
}

impl Default for Shared {
    fn default() -> Self {
        Self {
            best: Mutex::new(Best::NONE),
            version: AtomicU64::new(0),
            stop: AtomicBool::new(false),
        }
    }
}

impl Shared {
    fn lock(&self) -> std::sync::MutexGuard<'_, Best> {
        // A panicking thread is resumed by `explore`; the graph it left is whole.
        self.best.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Publishes `best` when it is cheaper than the shared one; `seen` is the caller's view.
    fn publish(&self, best: &Best, seen: &mut u64) {
        let mut shared = self.lock();
        if best.cost.below(shared.cost) {
            shared.clone_from(best);
            *seen = self.version.fetch_add(1, AtomicOrdering::AcqRel) + 1;
        }
    }

    /// After a step that began at cost `before`: publishes `best` if the step made it cheaper,
    /// else takes the shared graph if it is cheaper.
    fn exchange(&self, before: Cost, best: &mut Best, seen: &mut u64) {
        if best.cost.below(before) {
            self.publish(best, seen);
        } else {
            self.refresh(best, seen);
        }
    }

    /// Takes the shared graph into `best` when another thread published a cheaper one since
    /// the caller last looked.
    fn refresh(&self, best: &mut Best, seen: &mut u64) {
        if self.version.load(AtomicOrdering::Acquire) == *seen {
            return;
        }
        let shared = self.lock();
        *seen = self.version.load(AtomicOrdering::Acquire);
        if shared.cost.below(best.cost) {
            best.clone_from(&shared);
        }
    }
}

/// The main search split between threads (our extension: the proof on both cores). A thread
/// whose probes stopped finding cheaper graphs, or the main search's once its own tree is
/// exhausted, asks for work; a thread running a depth-first search gives it, at its next
/// backtrack, the later choices of its shallowest job ([`Dfs::give`]). The optimum is proven
/// when the main search's tree is exhausted and so is every subtree given away.
#[derive(Default)]
struct Split<'a> {
    state: Mutex<SplitState<'a>>,
    changed: Condvar,
    /// Whether a thread waits for a subtree (read at every backtrack without the lock).
    wanted: AtomicBool,
}

#[derive(Default)]
struct SplitState<'a> {
    /// A subtree given and not taken yet.
    gift: Option<(Search<'a>, Dfs)>,
    /// Subtrees given and not exhausted yet (taken or not).
    open: usize,
    /// Whether a subtree was left unexhausted (the deadline): then nothing is proven.
    abandoned: bool,
}

impl<'a> Split<'a> {
    fn lock(&self) -> std::sync::MutexGuard<'_, SplitState<'a>> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// At a backtrack of `dfs`: gives a subtree if a thread waits for one.
    fn serve(&self, dfs: &mut Dfs, search: &Search<'a>) {
        if !self.wanted.load(AtomicOrdering::Relaxed) {
            return;
        }
        let mut state = self.lock();
        // (Asked again under the lock: a thread that stopped waiting withdrew its request.)
        if self.wanted.load(AtomicOrdering::Relaxed)
            && state.gift.is_none()
            && let Some(gift) = dfs.give(search)
        {
            state.gift = Some(gift);
            state.open += 1;
        }
        self.wanted.store(false, AtomicOrdering::Relaxed);
        drop(state);
        self.changed.notify_all();
    }

    /// Waits for a subtree, up to `patience` (or until `halt`); none when the others had
    /// none to give.
    fn take(&self, patience: Duration, halt: &dyn Fn() -> bool) -> Option<(Search<'a>, Dfs)> {
        let until = Instant::now() + patience;
        let mut state = self.lock();
        loop {
            if let Some(gift) = state.gift.take() {
                return Some(gift);
            }
            let now = Instant::now();
            if now >= until || halt() {
                // No subtree is given that nobody takes.
                self.wanted.store(false, AtomicOrdering::Relaxed);
                return None;
            }
            self.wanted.store(true, AtomicOrdering::Relaxed);
            state = self
                .changed
                .wait_timeout(state, (until - now).min(Duration::from_millis(1)))
                .unwrap_or_else(PoisonError::into_inner)
                .0;
            if state.gift.is_none() && !self.wanted.load(AtomicOrdering::Relaxed) {
                // Asked and answered: nothing to give.
                return None;
            }
        }
    }

    /// A subtree taken from [`Split::take`] ended: exhausted, or `abandoned` at the deadline.
    fn finish(&self, abandoned: bool) {
        let mut state = self.lock();
        state.open -= 1;
        state.abandoned |= abandoned;
        drop(state);
        self.changed.notify_all();
    }

    /// Whether every subtree given away was exhausted (working on those still open, taking
    /// them as they are given back, until `halt`).
    fn settle(
        &self,
        shared: &Shared,
        best: &mut Best,
        seen: &mut u64,
        expansions: &mut u64,
        halt: &dyn Fn() -> bool,
    ) -> bool {
        loop {
            {
                let state = self.lock();
                if state.open == 0 {
                    return !state.abandoned;
                }
            }
            if halt() {
                return false;
            }
            if let Some(mut gift) = self.take(Duration::from_millis(1), halt) {
                let ended = self.work(&mut gift, shared, best, seen, expansions, halt, None);
                self.finish(ended.unwrap_or(true));
            }
        }
    }

    /// Works on a subtree given by [`Split::take`], giving parts of it to threads that ask,
    /// until it ends or `until` passes: whether it ended abandoned at the deadline (`true`) or
    /// exhausted (`false`), or `None` when it has not ended.
    #[allow(clippy::too_many_arguments)]
    fn work(
        &self,
        (search, dfs): &mut (Search<'a>, Dfs),
        shared: &Shared,
        best: &mut Best,
        seen: &mut u64,
        expansions: &mut u64,
        halt: &dyn Fn() -> bool,
        until: Option<Instant>,
    ) -> Option<bool> {
        shared.refresh(best, seen);
        loop {
            let before = best.cost;
            match dfs.step(search, best) {
                Step::Expanded => {
                    *expansions += 1;
                    if halt() {
                        return Some(true);
                    }
                }
                Step::Backtracked => {
                    shared.exchange(before, best, seen);
                    self.serve(dfs, search);
                    if halt() {
                        return Some(true);
                    }
                    if until.is_some_and(|u| Instant::now() >= u) {
                        return None;
                    }
                }
                Step::Exhausted => {
                    shared.exchange(before, best, seen);
                    return Some(false);
                }
            }
        }
    }
}

/// What one step of the depth-first search did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// A job was closed (lines 11–18).
    Expanded,
    /// A job failed or the graph was complete, and the last choice was undone (lines 19–36).
    Backtracked,
    /// Nothing is left to undo: the search is complete (line 38).
    Exhausted,
}

/// The state of one depth-first search (Alg. 4 lines 3–8) over a [`Search`]'s plan.
#[derive(Clone)]
struct Dfs {
    jobs: Vec<Job>,
    trace: Vec<Entry>,
    sum: Cost,
    from: usize,
}

impl Dfs {
    /// The root: every input of the root and of the protected CUs is an open job.
    fn root(search: &Search<'_>) -> Self {
        let mut jobs: Vec<Job> = Vec::new();
        for (n, node) in search.nodes.iter().enumerate().rev() {
            for i in (0..node.inputs.len()).rev() {
                jobs.push(Job { node: n, input: i });
            }
        }
        Self {
            jobs,
            trace: Vec::new(),
            sum: Cost::ZERO,
            from: 0,
        }
    }

    /// Lines 10–36, once: expands the open job on top, or records a complete graph and
    /// backtracks, or backtracks from a job that failed.
    fn step(&mut self, search: &mut Search<'_>, best: &mut Best) -> Step {
        // Lines 11–23: expand open jobs until one fails or none is left.
        if let Some(job) = self.jobs.pop() {
            // Line 10, strengthened: once a best graph exists, a partial graph whose cost plus
            // the admissible bound of its open jobs reaches the best cost cannot lead to a
            // better one (the job fails, as when no choice stays under the best).
            self.jobs.push(job);
            // A probe's round prunes by cost alone: in its small neighbourhood the bound costs
            // more time than it saves (docs/engine.md).
            let hopeless = best.nodes.is_some() && search.guide.is_none() && {
                let enough = Cost {
                    unsatisfied: best.cost.unsatisfied.saturating_sub(self.sum.unsatisfied),
                    value: best.cost.value - self.sum.value,
                };
                !self
                    .sum
                    .plus(search.lower_bound(&self.jobs, enough))
                    .below(best.cost)
            };
            self.jobs.pop();
            if hopeless {
                self.jobs.push(job);
            } else if let Some(entry) = search.expand(job, self.from, self.sum, best.cost) {
                // Lines 15–18: a new node's inputs become open jobs; candidate indices of
                // the jobs now on top start from the first candidate again.
                if entry.created {
                    let n = search.nodes.len() - 1;
                    for i in (0..search.nodes[n].inputs.len()).rev() {
                        self.jobs.push(Job { node: n, input: i });
                    }
                }
                self.sum = entry.after;
                self.trace.push(entry);
                self.from = 0;
                return Step::Expanded;
            } else {
                // Lines 20–21: expansion failure.
                self.jobs.push(job);
            }
        } else if self.sum.below(best.cost) {
            // Lines 26–28: a complete graph, better than the best so far.
            best.cost = self.sum;
            best.nodes = Some(search.nodes.clone());
            best.node_tids.clone_from(&search.node_tids);
        }
        // Lines 25–36: undo the last choice and retry its job from the next candidate.
        if self.undo(search) {
            Step::Backtracked
        } else {
            Step::Exhausted
        }
    }

    /// Undoes the last choice (lines 29–36); false when there is none.
    fn undo(&mut self, search: &mut Search<'_>) -> bool {
        let Some(entry) = self.trace.pop() else {
            return false;
        };
        if entry.created {
            // Lines 32–34: drop the node and its (now invalidated) jobs.
            let n = search.nodes.len() - 1;
            let inputs = search.nodes[n].inputs.len();
            self.jobs.truncate(self.jobs.len() - inputs);
            let tid = search.node_tids[n];
            debug_assert_eq!(search.registry[tid].last(), Some(&n));
            search.registry[tid].pop();
            search.in_plan[tid] = !search.registry[tid].is_empty();
            search.nodes.pop();
            search.node_tids.pop();
        }
        // Lines 30–31.
        search.nodes[entry.job.node].inputs[entry.job.input] = None;
        self.jobs.push(entry.job); // Line 36.
        // A job whose later choices were given away has none left here.
        self.from = if entry.given {
            usize::MAX
        } else {
            entry.choice + 1
        };
        self.sum = entry.before;
        true
    }

    /// Gives another thread the later choices of this search's shallowest job that still has
    /// its own (the largest subtree left), as a search of their own: a copy of the plan and
    /// of this search taken back to that job, its next choice first. This search skips those
    /// choices when it gets back to the job. The jobs below it in the trace have none of their
    /// own left (they were given away before: it is the shallowest), so the copy, when it gets
    /// back to them, finds no choice left and ends. Together the two explore exactly the
    /// subtrees this one would have explored alone. None when every job of the trace was given
    /// already.
    fn give<'a>(&mut self, search: &Search<'a>) -> Option<(Search<'a>, Dfs)> {
        let depth = self.trace.iter().position(|e| !e.given)?;
        let mut theirs = (search.clone(), self.clone());
        while theirs.1.trace.len() > depth {
            theirs.1.undo(&mut theirs.0);
        }
        self.trace[depth].given = true;
        Some(theirs)
    }
}

/// Any-time probes (our extension of Ch. 4.3.3's any-time search): a large-neighbourhood
/// search around the best graph. The depth-first search stays inside its first top-level
/// decisions for as long as it cannot prove them optimal, so on large libraries its any-time
/// cost stops improving. In any-time mode, once the main search has backtracked
/// [`ProbeOptions::after`] times, a second search on its own copy of the plan takes turns with
/// it: after every [`ProbeOptions::every`] backtracks of the main search, the probes run until
/// their time in all is three times the main search's while they keep finding cheaper graphs
/// (within the last [`GAIN_WINDOW`] rounds), an eighth of it once they stop. From then on,
/// [`ProbeOptions::threads`] further probes, with seeds of their own, also run on threads of
/// their own until the main search ends or the deadline passes; all share one best graph
/// ([`Shared`]), each taking the others' cheaper graphs at its next backtrack or turn. Each
/// round frees a few targets chosen from a seed: the jobs of
/// the best graph that serve only other targets keep their provider ([`Guide`]), the freed ones
/// choose among all theirs (in an order perturbed by the seed), and Algorithm 4 searches that
/// neighbourhood, pruning by cost against the one best cost, for at most
/// [`ProbeOptions::limit`] backtracks. A cheaper graph it finds prunes the main
/// search too, which stays exhaustive: when it ends, its proof is Algorithm 4's. A round's
/// own end proves nothing (its neighbourhood is not the whole space).
struct Probes<'a> {
    search: Search<'a>,
    /// Rerouting's local search, which proposes every other round's neighbourhood.
    reroute: Reroute,
    dfs: Dfs,
    backtracks: u64,
    limit: u64,
    round: u64,
    /// The nodes at the root (the root and the protected CUs).
    roots: usize,
    /// Added to the round to seed it (see `run`).
    salt: u64,
}

impl<'a> Probes<'a> {
    /// The probes' copy of the search, taken back to the root from the main search's state.
    /// Probes `k` (0 on the main search's thread) take seeds of their own.
    fn new(search: &Search<'a>, main: &Dfs, limit: u64, k: u64) -> Self {
        Self::of(search.clone(), main.clone(), limit, k)
    }

    /// [`Probes::new`] from copies of the search and of the main search's state (taken on the
    /// main search's thread; the rest, rerouting's first graph above all, is built on the
    /// probes' own).
    fn of(mut search: Search<'a>, mut dfs: Dfs, limit: u64, k: u64) -> Self {
        while dfs.undo(&mut search) {}
        let roots = search.nodes.len();
        let reroute = Reroute::new(
            search.own.clone(),
            search.further_cost.clone(),
            search
                .for_input
                .iter()
                .map(|inputs| {
                    inputs
                        .iter()
                        .map(|statics| statics.iter().map(|s| (s.tid, s.port)).collect())
                        .collect()
                })
                .collect(),
            search.ports_target.clone(),
            search.channel_of.clone(),
            search.node_tids[1..roots].to_vec(),
        );
        let salt = k.wrapping_mul(12 << 32);
        Self {
            reroute: reroute.keyed(search.keys.to_vec()).reseeded(salt),
            salt,
            dfs: Dfs::root(&search),
            roots: search.nodes.len(),
            search,
            backtracks: 0,
            limit,
            round: 0,
        }
    }

    /// Further probes' thread: turns until the main search ends or the deadline passes, taking
    /// the others' cheaper graphs and publishing their own after each; returns their
    /// expansions.
    ///
    /// Once their rounds have found nothing cheaper for `help_after` rounds, they help the
    /// main search instead (`split`): they ask for a subtree of it and exhaust it, then ask
    /// again; when none is to be had they go back to their rounds for as many again.
    fn search(
        mut self,
        shared: &Shared,
        split: &Split<'a>,
        help_after: u64,
        deadline: Option<Instant>,
    ) -> u64 {
        let (mut best, mut seen) = {
            let best = shared.lock();
            (best.clone(), shared.version.load(AtomicOrdering::Acquire))
        };
        let halt = || {
            shared.stop.load(AtomicOrdering::Relaxed)
                || deadline.is_some_and(|d| Instant::now() >= d)
        };
        let mut expansions = 0;
        // The round from which they help, the subtree they help with, and the time given to
        // it and to the rounds since they began to help.
        let mut help_from = help_after;
        let mut gift: Option<(Search<'a>, Dfs)> = None;
        let (mut helping, mut probing) = (Duration::ZERO, Duration::ZERO);
        while !halt() {
            if gift.is_none() && self.round >= help_from {
                gift = split.take(Duration::from_millis(1), &halt);
                if gift.is_none() {
                    help_from = self.round + help_after.max(1);
                }
            }
            if let Some(g) = gift.as_mut()
                && helping.as_secs_f64() <= HELP_SHARE * probing.as_secs_f64()
            {
                let turn = Instant::now();
                let until = turn + HELP_TURN;
                let ended = split.work(
                    g,
                    shared,
                    &mut best,
                    &mut seen,
                    &mut expansions,
                    &halt,
                    Some(until),
                );
                helping += turn.elapsed();
                if let Some(abandoned) = ended {
                    split.finish(abandoned);
                    gift = None;
                }
                continue;
            }
            let turn = Instant::now();
            let before = best.cost;
            self.run(&mut best, &mut expansions, &halt);
            if gift.is_some() {
                probing += turn.elapsed();
            }
            if best.cost.below(before) {
                help_from = help_from.max(self.round + help_after);
            }
            shared.exchange(before, &mut best, &mut seen);
        }
        if gift.is_some() {
            split.finish(true);
        }
        expansions
    }

    /// One turn: steps up to the next backtrack, starting a round when none is under way.
    fn run(&mut self, best: &mut Best, expansions: &mut u64, halt: &dyn Fn() -> bool) {
        if self.search.guide.is_none() {
            self.round += 1;
            // Odd rounds reroute first: a cheaper whole graph, when rerouting finds one, is
            // the round's neighbourhood (built as it is); else the round frees a few targets.
            let rerouted = if self.round % 2 == 1 {
                if let Some(nodes) = best.nodes.as_deref() {
                    self.reroute.adopt(best.cost, nodes, &best.node_tids);
                }
                self.reroute.improve(REROUTE_MOVES, best.cost, halt)
            } else {
                None
            };
            // The seeds of probes k are offset by k × 12 × 2³²: the round's parity, and its
            // residues modulo 3 and 4, choose what the round does, and stay the same.
            let seed = self.round.wrapping_add(self.salt);
            self.search.perturbation = rerouted.is_none().then(|| Perturbation::new(seed));
            self.search.guide = rerouted.or_else(|| {
                best.nodes
                    .as_deref()
                    .map(|nodes| Guide::around(nodes, &best.node_tids, self.roots, seed))
            });
        }
        let ended = loop {
            match self.dfs.step(&mut self.search, best) {
                Step::Expanded => {
                    *expansions += 1;
                    // A guided dive builds a whole graph, milliseconds at 2,000
                    // transformations: the deadline is looked at during it too.
                    if halt() {
                        break false;
                    }
                }
                Step::Backtracked => break false,
                Step::Exhausted => break true,
            }
        };
        self.backtracks += 1;
        if ended || self.backtracks >= self.limit {
            while self.dfs.undo(&mut self.search) {}
            self.dfs = Dfs::root(&self.search);
            self.backtracks = 0;
            self.search.guide = None;
        }
    }
}

/// The further probes' time helping with the main search's proof, as a multiple of their
/// own rounds' while they help (three quarters of their thread). Measured on the bench's
/// generated instances (docs/benchmarks.md, "The proof on both cores"): 200 × 10 proven
/// within 1 s on 3 of 8 seeds in each of five runs with 3 or with all the thread, 2–3 with 1,
/// 1 without help; at 100 ms 4.27 instances of 24 more than 1 % above the reference with 3,
/// 4.60 with all the thread, 3.80 with 1, 4.40 without help (15 samples each).
const HELP_SHARE: f64 = 3.0;

/// How long the further probes work on a subtree of the main search before they look at the
/// time shares again.
const HELP_TURN: Duration = Duration::from_millis(1);

/// How recently (probe rounds) the probes must have found a cheaper graph to keep the larger
/// share of the time.
const GAIN_WINDOW: u64 = 64;

/// The probes' time on the main search's thread, as a multiple of the main search's, while
/// they keep finding cheaper graphs (within [`GAIN_WINDOW`] rounds), in the first
/// [`LATE_AFTER`] of the timeout: the main search's proof, when one comes soon, keeps a
/// quarter of the thread. A review at 2,000 × 50 (1 s timeout) proves its change set optimal
/// in 25–45 ms warm (p50) so; with [`SHARE_LATE`] from the start it took 105 ms
/// (docs/benchmarks.md, "Searches that end on time").
const SHARE_FRESH: f64 = 3.0;

/// The probes' share while they keep finding cheaper graphs after [`LATE_AFTER`] of the
/// timeout, when a proof has become unlikely and the cost at the deadline is what is left to
/// win. Measured on the bench's 24 generated instances at 100 ms once searches ended on
/// time (docs/benchmarks.md, "Searches that end on time"), instances more than 1 % above the
/// reference on average (interleaved batches): 20 throughout 3.8 (mean gap 0.42 %) against
/// 4.75 (0.59 %) with 3 throughout, 24 samples each; 20 after 10 % of the timeout 4.1
/// (0.48 %), the same as 20 throughout in that batch (0.44 %), 18 samples each; 20 after 30 %
/// 4.4 (0.51 %).
const SHARE_LATE: f64 = 20.0;

/// The share of the timeout after which [`SHARE_LATE`] replaces [`SHARE_FRESH`].
const LATE_AFTER: f64 = 0.1;

/// The probes' share once they stop finding cheaper graphs: a ninth of the time, so that a
/// proof the main search can give comes sooner. With the proof on both cores, 200 × 10 was
/// proven within 1 s on 3 of 8 seeds in each of five runs with it, on 3, 2, 2, 2 and 2 with a
/// third (a quarter of the time), and the any-time cost was the same within the runs' spread
/// (docs/benchmarks.md, "The proof on both cores").
const SHARE_STALE: f64 = 1.0 / 8.0;

/// Rerouting moves per odd probe round (each reroutes one to a few targets; a move takes
/// ~25 µs at 2,000 transformations × 50 targets, so a round ~6 ms unless the deadline ends it).
const REROUTE_MOVES: u32 = 256;

/// A neighbourhood of a graph (one probe round): the provider each job keeps, keyed by the
/// consumer (a target, or a transformation's input); jobs not listed choose freely.
#[derive(Debug, Clone, Default)]
struct Guide {
    /// (target index, input) for targets as `(usize::MAX, q)`, else (consumer tid, input) →
    /// the provider (tid, out port), or `None` for a target left unsatisfied.
    kept: FxHashMap<(usize, usize), Option<(usize, usize)>>,
}

impl Guide {
    /// Frees 1 to 3 targets of `nodes` (chosen from `round`) and whatever of the graph only
    /// they use, and in even rounds one in ten of the other jobs; everything else keeps its
    /// provider. Nodes `1..protected` are the protected CUs (nodes from the start).
    fn around(nodes: &[PlanNode], node_tids: &[usize], protected: usize, round: u64) -> Self {
        let targets = nodes.first().map_or(0, |root| root.inputs.len());
        let mut kept = FxHashMap::default();
        if targets == 0 {
            return Self { kept };
        }
        let mut random = splitmix(round);
        let mut freed = vec![false; targets];
        for _ in 0..=(round % 3) {
            random = splitmix(random);
            freed[(random % targets as u64) as usize] = true;
        }
        // The nodes each kept target reaches keep their inputs' providers.
        let mut reached = vec![false; nodes.len()];
        let mut stack: Vec<usize> = Vec::new();
        for (q, link) in nodes[0].inputs.iter().enumerate() {
            if freed[q] {
                continue;
            }
            kept.insert((usize::MAX, q), link.map(|l| (node_tids[l.node], l.port)));
            stack.extend(link.map(|l| l.node));
        }
        // Protected CUs' inputs are jobs from the start: kept as well.
        stack.extend(1..protected.min(nodes.len()));
        while let Some(n) = stack.pop() {
            if std::mem::replace(&mut reached[n], true) {
                continue;
            }
            for (i, link) in nodes[n].inputs.iter().enumerate() {
                if let Some(l) = link {
                    kept.entry((node_tids[n], i))
                        .or_insert(Some((node_tids[l.node], l.port)));
                    stack.push(l.node);
                }
            }
        }
        // Every other round also frees one kept job in ten, anywhere in the graph: the shared
        // part the held targets use changes too.
        if round.is_multiple_of(2) {
            kept.retain(|_, _| {
                random = splitmix(random);
                !random.is_multiple_of(10)
            });
        }
        Self { kept }
    }

    /// The provider a job keeps, if it is kept.
    fn kept(&self, consumer: usize, input: usize) -> Option<Option<(usize, usize)>> {
        self.kept.get(&(consumer, input)).copied()
    }
}

/// SplitMix64's step: a well-mixed 64-bit value from `z`.
fn splitmix(z: u64) -> u64 {
    let mut z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A seeded reordering of new-node choices: each estimate is scaled by a factor in
/// `[1, 1 + amplitude)` drawn from the seed, the job and the choice (the same for the same
/// job in the same state, so a job's choice indices stay valid while it is retried).
#[derive(Debug, Clone, Copy)]
struct Perturbation {
    seed: u64,
    amplitude: f64,
}

impl Perturbation {
    fn new(seed: u64) -> Self {
        // Cycles through gentle to strong reorderings.
        const AMPLITUDES: [f64; 4] = [0.1, 0.25, 0.5, 1.0];
        Self {
            seed,
            amplitude: AMPLITUDES[(seed % 4) as usize],
        }
    }

    /// The factor for choosing transformation `key` (its [`Search::keys`] entry) for `job`.
    fn factor(self, job: Job, key: u64) -> f64 {
        let z = splitmix(splitmix(self.seed ^ ((job.node as u64) << 32 | job.input as u64)) ^ key);
        1.0 + self.amplitude * (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The admissible lower bound EXPLORE starts from (protected CUs' upkeep included): no
/// configuration of `env`'s targets costs less. See [`Search::lower_bound`].
pub fn lower_bound(env: &Environment, candidates: &Candidates, options: &ExploreOptions) -> Cost {
    let mut search = Search::new(env, candidates, options);
    let jobs: Vec<Job> = search
        .nodes
        .iter()
        .enumerate()
        .flat_map(|(n, node)| (0..node.inputs.len()).map(move |i| Job { node: n, input: i }))
        .collect();
    search.lower_bound(&jobs, Cost::INFINITE).plus(Cost {
        unsatisfied: 0,
        value: protected_upkeep(env, options),
    })
}

/// The transformations a plan of `env` can use, in library order: those that can feed a
/// target, or an input of a CU (the candidate table's closure backwards from them), with
/// those of the CUs. A plan's nodes feed the root or the protected CUs, so no other
/// transformation can be in one: with a library of thousands and a few targets, leaving them
/// out of the search saves the set-up work that grows with the library, and changes nothing
/// it finds.
fn relevant<'e>(
    env: &'e Environment,
    candidates: &Candidates,
) -> (Vec<(&'e Tid, &'e crate::model::Transformation)>, Vec<u64>) {
    // Each transformation's position in the library, which is also its key: what the
    // probes' random draws are keyed by, so that they do not depend on what was left out.
    let library: Vec<(&Tid, &crate::model::Transformation)> = env.library.iter().collect();
    let position: FxHashMap<&str, usize> = library
        .iter()
        .enumerate()
        .map(|(k, (tid, _))| (tid.as_str(), k))
        .collect();
    let mut seen = vec![false; library.len()];
    let mut stack = Vec::new();
    let mut reach = |tid: &str, stack: &mut Vec<usize>| {
        if let Some(&k) = position.get(tid)
            && !std::mem::replace(&mut seen[k], true)
        {
            stack.push(k);
        }
    };
    for q in env.targets.keys() {
        for p in candidates.for_target(q) {
            reach(&p.tid, &mut stack);
        }
    }
    for cu in env.cus.values() {
        reach(&cu.tid, &mut stack);
    }
    while let Some(k) = stack.pop() {
        let (tid, tf) = library[k];
        for i in 0..tf.inputs.len() {
            for p in candidates.for_input(tid, i) {
                reach(&p.tid, &mut stack);
            }
        }
    }
    // In the library's order (by name), as before.
    (0..library.len())
        .filter(|k| seen[*k])
        .map(|k| (library[k], k as u64))
        .unzip()
}

/// The upkeep of protected CUs over the horizon: paid whatever the plan.
fn protected_upkeep(env: &Environment, options: &ExploreOptions) -> f64 {
    options.horizon
        * env
            .cus
            .values()
            .filter(|c| c.protected)
            .map(|c| env.library.get(&c.tid).map_or(0.0, |t| t.upkeep))
            .sum::<f64>()
}

impl<'a> Search<'a> {
    fn new(env: &Environment, candidates: &Candidates, options: &'a ExploreOptions) -> Self {
        let (relevant, keys) = relevant(env, candidates);
        let tid_index: FxHashMap<&str, usize> = relevant
            .iter()
            .enumerate()
            .map(|(i, (t, _))| (t.as_str(), i))
            .collect();
        let (tids, lib): (Vec<Tid>, Vec<&crate::model::Transformation>) =
            relevant.into_iter().map(|(t, tf)| (t.clone(), tf)).unzip();
        let cus: Vec<Cid> = env.cus.keys().cloned().collect();
        // Existing CUs of each transformation (valid ones: the transformation exists).
        let mut existing: Vec<Vec<usize>> = vec![Vec::new(); tids.len()];
        for (c, cid) in cus.iter().enumerate() {
            if let Some(t) = tid_index.get(env.cus[cid].tid.as_str()) {
                existing[*t].push(c);
            }
        }
        let h = options.horizon;
        // A node's cost over the horizon: an existing CU's upkeep, a new one's labour too.
        let keep_cost: Vec<f64> = lib.iter().map(|tf| h * tf.upkeep).collect();
        let spawn_cost: Vec<f64> = lib.iter().map(|tf| tf.labour + h * tf.upkeep).collect();
        // Ordering heuristic (Ch. 4.3.3 leaves it open): the estimated cost of a transformation's
        // whole subtree, its own cost plus the cheapest subtree for each input, ignoring sharing
        // (so not a bound, only an order). Computed by relaxation; cycles stay unbounded.
        let own: Vec<f64> = (0..tids.len())
            .map(|t| {
                if existing[t].iter().any(|c| env.cus[&cus[*c]].protected) {
                    0.0
                } else if existing[t].is_empty() {
                    spawn_cost[t]
                } else {
                    keep_cost[t]
                }
            })
            .collect();
        let inputs_of: Vec<Vec<Vec<usize>>> = tids
            .iter()
            .zip(&lib)
            .map(|(t, tf)| {
                (0..tf.inputs.len())
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
                if p.port >= lib[t].outputs.len() {
                    continue;
                }
                if existing[t].is_empty() {
                    out.push(Static {
                        tid: t,
                        port: p.port,
                        existing: None,
                        cost: spawn_cost[t],
                    });
                } else {
                    for c in &existing[t] {
                        let protected = env.cus[&cus[*c]].protected;
                        out.push(Static {
                            tid: t,
                            port: p.port,
                            existing: Some(*c),
                            cost: if protected { 0.0 } else { keep_cost[t] },
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
        let for_input: Vec<Vec<Vec<Static>>> = tids
            .iter()
            .zip(&lib)
            .map(|(t, tf)| {
                (0..tf.inputs.len())
                    .map(|i| statics(candidates.for_input(t, i)))
                    .collect()
            })
            .collect();
        let targets: Vec<Qid> = env.targets.keys().cloned().collect();
        let for_target: Vec<Vec<Static>> = targets
            .iter()
            .map(|q| statics(candidates.for_target(q)))
            .collect();
        let target_channels = targets
            .iter()
            .map(|q| env.targets[q].channel.clone())
            .collect();
        let in_counts = lib.iter().map(|tf| tf.inputs.len()).collect();
        let mut interned: FxHashMap<Vec<usize>, Arc<[usize]>> = FxHashMap::default();
        let mut distinct = |statics: &[Static]| -> Arc<[usize]> {
            let mut v: Vec<usize> = statics.iter().map(|s| s.tid).collect();
            v.sort_unstable();
            v.dedup();
            interned
                .entry(v)
                .or_insert_with_key(|v| v.as_slice().into())
                .clone()
        };
        let providers_input: Vec<Vec<Arc<[usize]>>> = for_input
            .iter()
            .map(|inputs: &Vec<Vec<Static>>| inputs.iter().map(|s| distinct(s)).collect())
            .collect();
        let providers_target: Vec<Arc<[usize]>> = for_target.iter().map(|s| distinct(s)).collect();
        let n = tids.len();
        let ports_target: Vec<Vec<(usize, usize)>> = for_target
            .iter()
            .map(|statics| {
                let mut v: Vec<(usize, usize)> = statics.iter().map(|s| (s.tid, s.port)).collect();
                v.sort_unstable();
                v.dedup();
                v
            })
            .collect();
        let preferred: Vec<bool> = tids
            .iter()
            .map(|t| options.prefer.iter().any(|p| p == t))
            .collect();
        let mut feeds_targets = vec![false; n];
        for (t, _) in ports_target.iter().flatten() {
            feeds_targets[*t] = true;
        }
        let out_counts: Vec<usize> = lib.iter().map(|tf| tf.outputs.len()).collect();
        let further_cost: Vec<f64> = (0..n)
            .map(|t| {
                if existing[t].len() >= 2 {
                    keep_cost[t]
                } else {
                    spawn_cost[t]
                }
            })
            .collect();
        // Each target's channel, as the position of the first target on it (one map, not a
        // scan per target: thousands of targets come with a formula group's symbols).
        let mut first_on: FxHashMap<&Channel, usize> = FxHashMap::default();
        let channel_of: Vec<usize> = targets
            .iter()
            .enumerate()
            .map(|(k, q)| *first_on.entry(&env.targets[q].channel).or_insert(k))
            .collect();
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
            perturbation: None,
            guide: None,
            tids,
            keys: keys.into(),
            in_counts,
            cus,
            targets,
            target_channels,
            for_input,
            for_target,
            nodes: Vec::new(),
            node_tids: Vec::new(),
            registry: vec![Vec::new(); n],
            existing_of: existing,
            keep_cost,
            spawn_cost,
            further_cost,
            current_in,
            current_target,
            own,
            providers_input,
            providers_target,
            in_plan: vec![false; n],
            channel_of,
            subtree,
            preferred,
            feeds_targets,
            out_counts,
            ports_target,
            scratch: Scratch::new(n),
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
            search.registry[t].push(search.nodes.len());
            search.in_plan[t] = true;
            search.nodes.push(PlanNode {
                tid: cu.tid.clone(),
                kind: NodeKind::Existing(cid.clone()),
                inputs: vec![None; search.in_counts[t]],
            });
            search.node_tids.push(t);
        }
        search
    }

    /// The transformations that may feed `job`, and whether one of them is in the plan (then
    /// the job may be closed for free by a virtual connection).
    fn job_providers(&self, job: Job) -> (&[usize], bool) {
        let providers: &[usize] = if job.node == 0 {
            &self.providers_target[job.input]
        } else {
            &self.providers_input[self.node_tids[job.node]][job.input]
        };
        (providers, providers.iter().any(|t| self.in_plan[*t]))
    }

    /// The providers of `job`, shared.
    fn job_arc(&self, job: Job) -> Arc<[usize]> {
        if job.node == 0 {
            self.providers_target[job.input].clone()
        } else {
            self.providers_input[self.node_tids[job.node]][job.input].clone()
        }
    }

    /// Whether input `inputs` (its providers) may be fed by a plan node, for free.
    fn free(&self, inputs: &[usize]) -> bool {
        inputs.iter().any(|p| self.in_plan[*p])
    }

    /// An admissible lower bound on what completing the open `jobs` costs: never more than
    /// the cheapest completion (new nodes feeding every open job and every new node's inputs).
    ///
    /// A completion can be rewired, at no cost, so that every input a plan node may feed reads
    /// from it (a free virtual connection); what remains of it lies in the open jobs' *reach*:
    /// the transformations not in the plan that may feed a job, and recursively those that may
    /// feed their inputs, stopping at inputs a plan node may feed. Three bounds on that graph,
    /// each admissible, so the largest is (the later ones only when the earlier do not already
    /// reach `enough`, the best cost less the partial graph's; flow only for a bound to report,
    /// when `enough` is infinite):
    ///
    /// - **chains**: each transformation's cost is shared among the `r` open jobs whose reach
    ///   contains it; a job costs at least its cheapest chain, `chain(t) = own(t)/r(t) + max
    ///   over t's inputs of the cheapest provider's chain`. A job's feeding graph contains such
    ///   a path, and a node is charged `own/r` by at most the `r` jobs that can reach it;
    /// - **flow**: a completion's cost flows up its (acyclic) wiring, each node passing its own
    ///   cost plus what its inputs bring, split equally among its `k` consumers; the jobs
    ///   receive the whole cost. With `K(t) ≥ k` the consumer slots that may read from `t` (open
    ///   jobs, inputs of transformations in the reach), `flow(t) = (own(t) + Σ over inputs of
    ///   the cheapest provider's flow) / K(t)` never exceeds what `t` passes up.
    ///
    /// - **assignment**: targets on distinct channels need distinct out ports of one CU, so the
    ///   open target channels are assigned out ports at least cost (a minimum-cost assignment,
    ///   as many channels as possible first): a port of a transformation's first CU costs its
    ///   own cost (divided among its out ports) plus the cheapest chain below it, the other
    ///   jobs their cheapest chain; in these chains transformations that may feed a target
    ///   cost nothing (they are paid by the assignment), so no node is charged more than its
    ///   cost. A channel may instead be fed by a *further* CU (a private column of its own):
    ///   at least `further_cost` divided among the out ports, plus the chain below when the
    ///   transformation is not in the plan (shared like the others'). The cheapest completion
    ///   maps each channel to a first CU's port (distinct columns) or a further CU's (its own
    ///   column), an assignment that costs no more than it.
    ///
    /// Targets: with the relaxation, a target may be left unsatisfied. Those that no chain can
    /// feed must be: they count in `unsatisfied`. Any completion leaving more targets
    /// unsatisfied costs more (lexicographically) than the bound. Cycles count as 0; an open
    /// input no chain can feed makes the partial graph infeasible ([`Cost::INFINITE`]).
    fn lower_bound(&mut self, jobs: &[Job], enough: Cost) -> Cost {
        let epoch = self.reach(jobs);
        let mut bound = self.measure_bound(jobs, epoch, 0);
        if bound.below(enough) && jobs.iter().any(|j| j.node == 0) {
            let assigned = self.assignment_bound(jobs, epoch);
            if bound.below(assigned) {
                bound = assigned;
            }
        }
        // The flow bound only for a bound to report (no `enough`): in the search it pruned
        // nothing the other two did not on the benchmark's instances, and cost a fifth of the
        // time (docs/engine.md).
        if enough == Cost::INFINITE {
            let flow = self.measure_bound(jobs, epoch, 1);
            if bound.below(flow) {
                bound = flow;
            }
        }
        bound
    }

    /// A new epoch, and the reaches of the open `jobs` (see [`Search::lower_bound`]): per
    /// transformation, the jobs reaching it and the consumer slots that may read from it.
    fn reach(&mut self, jobs: &[Job]) -> u32 {
        let sc = &mut self.scratch;
        sc.epoch = sc.epoch.wrapping_add(1);
        if sc.epoch == 0 {
            // Wrapped: every stamp may collide, start over.
            sc.counted.fill(0);
            sc.slotted.fill(0);
            sc.in_union.fill(0);
            for m in &mut sc.memo {
                m.valued.fill(0);
                m.entered.fill(0);
            }
            sc.epoch = 1;
        }
        let epoch = self.scratch.epoch;
        // The reach of each open job: per transformation, the jobs reaching it and the
        // consumer slots that may read from it.
        // Jobs wanting the same providers have the same reach: walk it once, count it for each.
        let mut groups: Vec<(Arc<[usize]>, u32)> = Vec::new();
        // Providers are interned: the same list is the same `Arc`, found by its address.
        let mut group_of: FxHashMap<*const usize, usize> = FxHashMap::default();
        for &job in jobs {
            let providers = self.job_arc(job);
            // A free target still counts: the assignment bound may give it another port.
            if job.node != 0 && self.free(&providers) {
                continue;
            }
            match group_of.entry(providers.as_ptr()) {
                std::collections::hash_map::Entry::Occupied(g) => groups[*g.get()].1 += 1,
                std::collections::hash_map::Entry::Vacant(g) => {
                    g.insert(groups.len());
                    groups.push((providers, 1));
                }
            }
        }
        let mut stack: Vec<usize> = Vec::new();
        for (providers, count) in &groups {
            let count = *count;
            stack.extend(providers.iter().filter(|t| !self.in_plan[**t]));
            let Self {
                providers_input,
                in_plan,
                scratch: sc,
                ..
            } = self;
            for &p in &stack {
                sc.add_slots(p, epoch, count);
            }
            sc.job_epoch = sc.job_epoch.wrapping_add(1);
            if sc.job_epoch == 0 {
                sc.visited_by.fill(0);
                sc.job_epoch = 1;
            }
            let mark = sc.job_epoch;
            while let Some(t) = stack.pop() {
                if sc.visited_by[t] == mark {
                    continue;
                }
                sc.visited_by[t] = mark;
                if sc.counted[t] == epoch {
                    sc.reach_count[t] += count;
                } else {
                    sc.counted[t] = epoch;
                    sc.reach_count[t] = count;
                }
                let first = sc.in_union[t] != epoch;
                sc.in_union[t] = epoch;
                for inputs in &providers_input[t] {
                    if !inputs.iter().any(|p| in_plan[*p]) {
                        stack.extend_from_slice(inputs);
                        if first {
                            for &p in inputs.iter() {
                                sc.add_slots(p, epoch, 1);
                            }
                        }
                    }
                }
            }
        }
        epoch
    }

    /// The chain (`measure` 0) or flow (1) bound of [`Search::lower_bound`], with the reaches
    /// of [`Search::reach`] (`epoch`).
    fn measure_bound(&mut self, jobs: &[Job], epoch: u32, measure: usize) -> Cost {
        let mut other = 0.0f64;
        let mut targets = 0.0f64;
        let mut unfeedable = 0u32;
        for &job in jobs {
            let (providers, free) = self.job_providers(job);
            let value = if free {
                0.0
            } else {
                let providers = providers.to_vec();
                providers
                    .iter()
                    .map(|t| self.value(*t, epoch, measure))
                    .fold(f64::INFINITY, f64::min)
            };
            if job.node == 0 {
                if value.is_finite() {
                    targets += value;
                } else if self.options.relax {
                    unfeedable += 1;
                } else {
                    return Cost::INFINITE;
                }
            } else if value.is_finite() {
                other += value;
            } else {
                return Cost::INFINITE;
            }
        }
        Cost {
            unsatisfied: unfeedable,
            value: other + targets,
        }
    }

    /// The assignment bound of [`Search::lower_bound`] (see there), with the reaches of
    /// [`Search::reach`] (`epoch`).
    fn assignment_bound(&mut self, jobs: &[Job], epoch: u32) -> Cost {
        let mut value = 0.0;
        for &job in jobs.iter().filter(|j| j.node != 0) {
            let (providers, free) = self.job_providers(job);
            if free {
                continue;
            }
            let providers = providers.to_vec();
            let cheapest = providers
                .iter()
                .map(|t| self.value(*t, epoch, 2))
                .fold(f64::INFINITY, f64::min);
            if !cheapest.is_finite() {
                return Cost::INFINITE;
            }
            value += cheapest;
        }
        let (channels, taken) = self.open_channels(jobs);
        if channels.is_empty() {
            return Cost {
                unsatisfied: 0,
                value,
            };
        }
        let mut columns: Vec<(usize, usize)> = Vec::new();
        // Each column's index, and each open channel's candidate ports: built in one pass
        // (a scan of the jobs per channel was quadratic in the targets: thousands of them
        // come with a formula group's symbols).
        let mut column_of: FxHashMap<(usize, usize), usize> = FxHashMap::default();
        let mut ports_of: FxHashMap<usize, Vec<(usize, usize)>> = FxHashMap::default();
        for j in jobs.iter().filter(|j| j.node == 0) {
            ports_of
                .entry(self.channel_of[j.input])
                .or_default()
                .extend(self.ports_target[j.input].iter().copied());
        }
        let mut rows: Vec<Vec<(usize, f64)>> = Vec::with_capacity(channels.len());
        let mut private: Vec<f64> = Vec::with_capacity(channels.len());
        for c in &channels {
            let mut ports = ports_of.remove(c).unwrap_or_default();
            ports.sort_unstable();
            ports.dedup();
            let mut row = Vec::with_capacity(ports.len() + 1);
            // The cheapest further CU for this channel (a private column).
            let mut further = f64::INFINITY;
            for (t, port) in ports {
                let below = if self.in_plan[t] {
                    0.0
                } else {
                    let mut below = 0.0f64;
                    for i in 0..self.providers_input[t].len() {
                        if self.free(&self.providers_input[t][i]) {
                            continue;
                        }
                        let inputs = self.providers_input[t][i].clone();
                        let cheapest = inputs
                            .iter()
                            .map(|p| self.value(*p, epoch, 2))
                            .fold(f64::INFINITY, f64::min);
                        below = below.max(cheapest);
                    }
                    below
                };
                if !below.is_finite() {
                    continue;
                }
                let share = |cost: f64| cost / self.out_counts[t].max(1) as f64;
                further = further.min(share(self.further_cost[t]) + below);
                if taken.binary_search(&(t, port)).is_ok() {
                    continue;
                }
                let weight = if self.in_plan[t] {
                    0.0
                } else {
                    share(self.own[t]) + below
                };
                let col = *column_of.entry((t, port)).or_insert_with(|| {
                    columns.push((t, port));
                    columns.len() - 1
                });
                row.push((col, weight));
            }
            rows.push(row);
            private.push(further);
        }
        for (r, further) in private.into_iter().enumerate() {
            if further.is_finite() {
                columns.push((usize::MAX, r));
                rows[r].push((columns.len() - 1, further));
            }
        }
        let (unassigned, cost) = assignment(&rows, columns.len());
        if unassigned > 0 && !self.options.relax {
            return Cost::INFINITE;
        }
        Cost {
            unsatisfied: unassigned as u32,
            value: value + cost,
        }
    }

    /// The channels of open targets with no target fed yet, and the out ports already feeding
    /// a target, as (tid, port).
    fn open_channels(&self, jobs: &[Job]) -> (Vec<usize>, Vec<(usize, usize)>) {
        let fed: Vec<(usize, Link)> = self.nodes[0]
            .inputs
            .iter()
            .enumerate()
            .filter_map(|(q, l)| l.map(|l| (q, l)))
            .collect();
        // Sets, not scans of `fed` per job: linear in the targets, however many there are.
        let fed_channels: rustc_hash::FxHashSet<usize> =
            fed.iter().map(|(q, _)| self.channel_of[*q]).collect();
        let fed_ports: rustc_hash::FxHashSet<(usize, usize)> =
            fed.iter().map(|(_, l)| (l.node, l.port)).collect();
        let mut channels: Vec<usize> = jobs
            .iter()
            .filter(|j| j.node == 0)
            .map(|j| self.channel_of[j.input])
            .filter(|c| !fed_channels.contains(c))
            .collect();
        channels.sort_unstable();
        channels.dedup();
        // An out port of a transformation is taken when every node of it publishes it for a
        // target already.
        let mut taken: Vec<(usize, usize)> = fed
            .iter()
            .map(|(_, l)| (self.node_tids[l.node], l.port))
            .filter(|(t, port)| {
                self.registry[*t]
                    .iter()
                    .all(|&node| fed_ports.contains(&(node, *port)))
            })
            .collect();
        taken.sort_unstable();
        taken.dedup();
        (channels, taken)
    }

    /// `chain(t)` (`measure` 0), `flow(t)` (1) or `chain'(t)` (2) of [`Search::lower_bound`],
    /// memoised for this `epoch`; iterative (libraries may be deep). A provider still being
    /// valued (a cycle) counts as 0.
    fn value(&mut self, root: usize, epoch: u32, measure: usize) -> f64 {
        let mut stack = std::mem::take(&mut self.scratch.stack);
        stack.push((root, false));
        while let Some((t, done)) = stack.pop() {
            let memo = &mut self.scratch.memo[measure];
            if memo.valued[t] == epoch {
                continue;
            }
            if !done {
                if memo.entered[t] == epoch {
                    continue;
                }
                memo.entered[t] = epoch;
                stack.push((t, true));
                for inputs in &self.providers_input[t] {
                    if !self.free(inputs) {
                        let memo = &self.scratch.memo[measure];
                        stack.extend(
                            inputs
                                .iter()
                                .filter(|p| memo.entered[**p] != epoch)
                                .map(|p| (*p, false)),
                        );
                    }
                }
                continue;
            }
            let mut below = 0.0f64;
            for inputs in &self.providers_input[t] {
                if self.free(inputs) {
                    continue;
                }
                let memo = &self.scratch.memo[measure];
                let cheapest = inputs
                    .iter()
                    .map(|p| {
                        if memo.valued[*p] == epoch {
                            memo.value[*p]
                        } else {
                            0.0 // On the path being valued: a cycle.
                        }
                    })
                    .fold(f64::INFINITY, f64::min);
                below = if measure == 1 {
                    below + cheapest
                } else {
                    below.max(cheapest)
                };
            }
            let sc = &mut self.scratch;
            let value = match measure {
                0 => self.own[t] / f64::from(sc.reach_count[t].max(1)) + below,
                1 => {
                    let slots = if sc.slotted[t] == epoch {
                        sc.slots[t]
                    } else {
                        1
                    };
                    (self.own[t] + below) / f64::from(slots.max(1))
                }
                _ if self.feeds_targets[t] => below,
                _ => self.own[t] / f64::from(sc.reach_count[t].max(1)) + below,
            };
            let memo = &mut sc.memo[measure];
            memo.value[t] = value;
            memo.valued[t] = epoch;
        }
        self.scratch.stack = stack;
        self.scratch.memo[measure].value[root]
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
            for &n in &self.registry[s.tid] {
                if !out
                    .iter()
                    .any(|c| matches!(c, Choice::Reuse(l) if l.node == n && l.port == s.port))
                {
                    out.push(Choice::Reuse(Link {
                        node: n,
                        port: s.port,
                    }));
                }
            }
        }
        // New nodes: preferred ones first, then by their estimated subtree *given the plan*:
        // their cost plus, per input, nothing when a plan node may feed it, else the cheapest
        // provider's static subtree estimate (so sharing with the plan counts).
        let reused = out.len();
        for s in statics {
            if self.registry[s.tid].is_empty() {
                out.push(Choice::New {
                    tid: s.tid,
                    port: s.port,
                    existing: s.existing,
                    cost: s.cost,
                });
            }
        }
        if job.node == 0 {
            self.further_choices(job, statics, &mut out);
        }
        let estimate = |c: &Choice| -> (bool, f64) {
            let Choice::New {
                tid,
                existing,
                cost,
                ..
            } = *c
            else {
                return (false, 0.0);
            };
            let below: f64 = self.providers_input[tid]
                .iter()
                .map(|ps| {
                    if self.free(ps) {
                        0.0
                    } else {
                        ps.iter()
                            .map(|p| self.subtree[*p])
                            .fold(f64::INFINITY, f64::min)
                    }
                })
                .sum();
            let estimate = cost + below;
            let estimate = self
                .perturbation
                .map_or(estimate, |p| estimate * p.factor(job, self.keys[tid]));
            (existing.is_none() && self.preferred[tid], estimate)
        };
        out[reused..].sort_by(|a, b| {
            let (pa, ea) = estimate(a);
            let (pb, eb) = estimate(b);
            pb.cmp(&pa).then(ea.total_cmp(&eb))
        });
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
        // A probe's neighbourhood: a kept job offers only its provider in the best graph.
        let consumer = if job.node == 0 {
            usize::MAX
        } else {
            self.node_tids[job.node]
        };
        if let Some(kept) = self
            .guide
            .as_ref()
            .and_then(|g| g.kept(consumer, job.input))
        {
            out.retain(|c| match *c {
                Choice::Reuse(l) => kept == Some((self.node_tids[l.node], l.port)),
                Choice::New { tid, port, .. } => kept == Some((tid, port)),
                Choice::Unsatisfied => kept.is_none(),
            });
        }
        out
    }

    /// A further CU of a transformation already in the plan, for target `job`, when every plan
    /// node of it publishes the wanted out port on another target's channel (one out port
    /// feeds one channel): each existing CU of it the plan does not use yet, else a spawn.
    /// Only targets need one: a further CU's out ports could feed no in port that the
    /// transformation's first node could not feed as well (docs/engine.md).
    fn further_choices(&self, job: Job, statics: &[Static], out: &mut Vec<Choice>) {
        let mut seen: Vec<(usize, usize)> = Vec::new();
        for s in statics {
            let nodes = &self.registry[s.tid];
            if nodes.is_empty() || seen.contains(&(s.tid, s.port)) {
                continue;
            }
            seen.push((s.tid, s.port));
            let busy = nodes
                .iter()
                .all(|&node| self.channel_clash(job.input, Some(Link { node, port: s.port })));
            if !busy {
                continue;
            }
            let before = out.len();
            for &c in &self.existing_of[s.tid] {
                let used = nodes.iter().any(
                    |&n| matches!(&self.nodes[n].kind, NodeKind::Existing(e) if *e == self.cus[c]),
                );
                if !used {
                    out.push(Choice::New {
                        tid: s.tid,
                        port: s.port,
                        existing: Some(c),
                        cost: self.keep_cost[s.tid],
                    });
                }
            }
            if out.len() == before {
                out.push(Choice::New {
                    tid: s.tid,
                    port: s.port,
                    existing: None,
                    cost: self.spawn_cost[s.tid],
                });
            }
        }
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
                        given: false,
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
                    self.registry[tid].push(n);
                    self.in_plan[tid] = true;
                    self.nodes[job.node].inputs[job.input] = Some(Link { node: n, port });
                    return Some(Entry {
                        job,
                        choice: k,
                        created: true,
                        before: sum,
                        after,
                        given: false,
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
                        given: false,
                    });
                }
            }
        }
        None // Line 27.
    }
}

#[cfg(test)]
mod tests {
    use super::{
        Best, Cost, Guide, Link, NodeKind, PlanNode, Shared, assignment, hungarian, matching,
    };

    /// The search's universe: what can feed a target, or an input of a CU, backwards through
    /// the candidate table, and the CUs' transformations; keyed by library position.
    #[test]
    fn the_search_leaves_out_what_no_plan_can_use() {
        use crate::{Candidates, ComputationUnit, Environment, Target, Transformation};
        // (tid, in tag, out tag): a chain s → m feeds the target (tag B); x feeds only
        // `orphan`, which nothing wants; `kept` has a CU, and y feeds its input.
        let library = [
            ("kept", Some("Y"), "W"),
            ("m", Some("A"), "B"),
            ("orphan", Some("X"), "Z"),
            ("s", None, "A"),
            ("x", None, "X"),
            ("y", None, "Y"),
        ];
        let mut env = Environment::default();
        for (tid, input, _) in library {
            env.library.insert(
                tid.into(),
                Transformation {
                    tid: tid.into(),
                    inputs: input.iter().map(|_| "in".to_owned()).collect(),
                    outputs: vec!["out".into()],
                    labour: 1.0,
                    upkeep: 1.0,
                },
            );
        }
        env.targets.insert(
            "q".into(),
            Target {
                qid: "q".into(),
                channel: "/q".into(),
            },
        );
        env.cus.insert(
            "c".into(),
            ComputationUnit {
                cid: "c".into(),
                tid: "kept".into(),
                inputs: [("in".to_owned(), None)].into(),
                outputs: [("out".to_owned(), None)].into(),
                protected: false,
            },
        );
        let tag = |tid: &str, input: bool| {
            let (_, i, o) = library.iter().find(|(t, _, _)| *t == tid).unwrap();
            if input { i.unwrap() } else { o }
        };
        let candidates = Candidates::from_tags(
            &env,
            |tid, _| vec![tag(tid, true)],
            |tid, _| vec![tag(tid, false)],
            |_| vec!["B"],
            |i: &&str, o: &&str| i == o,
        );
        let (tids, keys) = super::relevant(&env, &candidates);
        let tids: Vec<&str> = tids.iter().map(|(t, _)| t.as_str()).collect();
        assert_eq!(tids, ["kept", "m", "s", "y"]);
        assert_eq!(keys, [0, 1, 3, 5], "positions in the whole library");
    }

    /// A library where each target has several feeding graphs: sources of A, transformations
    /// of A (one or two inputs) into B and of B into C; targets want B and C on two channels.
    fn split_instance() -> (crate::Environment, crate::Candidates) {
        use crate::{Candidates, Environment, Target, Transformation};
        let library: [(&str, &[&str], &str); 9] = [
            ("a1", &[], "A"),
            ("a2", &[], "A"),
            ("a3", &[], "A"),
            ("b1", &["A"], "B"),
            ("b2", &["A", "A"], "B"),
            ("b3", &["A"], "B"),
            ("c1", &["B"], "C"),
            ("c2", &["B", "A"], "C"),
            ("c3", &["B", "B"], "C"),
        ];
        let mut env = Environment::default();
        for (k, (tid, inputs, _)) in library.iter().enumerate() {
            env.library.insert(
                (*tid).into(),
                Transformation {
                    tid: (*tid).into(),
                    inputs: inputs.iter().map(|_| "in".to_owned()).collect(),
                    outputs: vec!["out".into()],
                    labour: 1.0 + (k % 4) as f64,
                    upkeep: 0.5 + (k % 3) as f64,
                },
            );
        }
        for (qid, channel) in [("qb", "/b"), ("qc", "/c")] {
            env.targets.insert(
                qid.into(),
                Target {
                    qid: qid.into(),
                    channel: channel.into(),
                },
            );
        }
        let row = |tid: &str| library.iter().find(|(t, _, _)| *t == tid).unwrap();
        let candidates = Candidates::from_tags(
            &env,
            |tid, i| vec![row(tid).1[i]],
            |tid, _| vec![row(tid).2],
            |qid| vec![if qid == "qb" { "B" } else { "C" }],
            |i: &&str, o: &&str| i == o,
        );
        (env, candidates)
    }

    /// Steps a depth-first search without pruning (the best is forgotten after each graph), at
    /// most `steps` times or to its end: the costs of the complete graphs it reached, the
    /// steps taken, and whether it ended.
    fn walk(
        search: &mut super::Search<'_>,
        dfs: &mut super::Dfs,
        steps: usize,
    ) -> (Vec<f64>, usize, bool) {
        let mut found = Vec::new();
        let mut best = Best::NONE;
        for taken in 0..steps {
            let step = dfs.step(search, &mut best);
            if best.nodes.is_some() {
                found.push(best.cost.value);
                best = Best::NONE;
            }
            if step == super::Step::Exhausted {
                return (found, taken, true);
            }
        }
        (found, steps, false)
    }

    /// The complete graphs a search reaches from its state to its end, as their costs, sorted.
    fn leaves(search: &mut super::Search<'_>, dfs: &mut super::Dfs) -> Vec<f64> {
        let mut found = walk(search, dfs, usize::MAX).0;
        found.sort_by(f64::total_cmp);
        found
    }

    /// Splitting a search between threads explores exactly what the search alone explores:
    /// after any number of steps, the subtree given away and what the search keeps reach,
    /// together, the complete graphs the undivided search reaches, each once; and a search
    /// that gives twice keeps only what it gave neither time.
    #[test]
    fn a_search_split_in_two_reaches_each_graph_once() {
        let (env, candidates) = split_instance();
        let options = super::ExploreOptions::default();
        let fresh = || {
            let search = super::Search::new(&env, &candidates, &options);
            let dfs = super::Dfs::root(&search);
            (search, dfs)
        };
        let (mut search, mut dfs) = fresh();
        let (mut all, total, _) = walk(&mut search, &mut dfs, usize::MAX);
        all.sort_by(f64::total_cmp);
        assert!(
            all.len() > 50,
            "a tree worth splitting: {} graphs",
            all.len()
        );
        // Splits at about 80 points spread over the undivided search's steps.
        let mut splits = 0;
        for steps in (0..total).step_by(total / 80 + 1) {
            let (mut search, mut dfs) = fresh();
            // The graphs reached before the split.
            let (before, _, ended) = walk(&mut search, &mut dfs, steps);
            if ended {
                break;
            }
            let mut parts = before;
            let gifts: Vec<_> = (0..=steps % 2).filter_map(|_| dfs.give(&search)).collect();
            for (mut s, mut d) in gifts {
                splits += 1;
                parts.extend(leaves(&mut s, &mut d));
            }
            parts.extend(leaves(&mut search, &mut dfs));
            parts.sort_by(f64::total_cmp);
            assert_eq!(parts, all, "split after {steps} steps");
        }
        assert!(splits > 60, "{splits} splits");
    }

    /// A graph of three targets: target q is fed by a chain of its own (tids 2q, 2q + 1), and
    /// targets 1 and 2 share a source (tid 6).
    fn graph() -> (Vec<PlanNode>, Vec<usize>) {
        let node = |inputs: Vec<Option<Link>>| PlanNode {
            tid: "t".into(),
            kind: NodeKind::Spawn,
            inputs,
        };
        let link = |node: usize| Some(Link { node, port: 0 });
        let nodes = vec![
            PlanNode {
                tid: Default::default(),
                kind: NodeKind::Root,
                inputs: vec![link(1), link(3), link(5)],
            },
            node(vec![link(2)]),
            node(vec![]),
            node(vec![link(4), link(7)]),
            node(vec![]),
            node(vec![link(6), link(7)]),
            node(vec![]),
            node(vec![]),
        ];
        (nodes, vec![usize::MAX, 0, 1, 2, 3, 4, 5, 6])
    }

    #[test]
    fn a_probe_round_keeps_what_the_targets_it_holds_use() {
        let (nodes, tids) = graph();
        let mut freed_counts = std::collections::BTreeSet::new();
        for round in 1..64 {
            let guide = Guide::around(&nodes, &tids, 1, round);
            // Whatever is kept is the graph's own provider.
            for (&(consumer, input), &provider) in &guide.kept {
                let n = tids.iter().position(|&t| t == consumer).unwrap_or(0);
                let link = nodes[n].inputs[input].map(|l| (tids[l.node], l.port));
                assert_eq!(provider, link, "round {round}");
            }
            if round % 2 == 0 {
                continue; // Even rounds also free jobs at random: checked above only.
            }
            let held: Vec<usize> = (0..3)
                .filter(|&q| guide.kept(usize::MAX, q).is_some())
                .collect();
            freed_counts.insert(3 - held.len());
            assert!(held.len() < 3, "round {round} frees no target");
            for &q in &held {
                let chain = nodes[0].inputs[q].unwrap().node;
                assert_eq!(guide.kept(usize::MAX, q), Some(Some((tids[chain], 0))));
                // The chain's inputs keep their providers, the shared source included.
                for (i, link) in nodes[chain].inputs.iter().enumerate() {
                    let provider = link.unwrap().node;
                    assert_eq!(guide.kept(tids[chain], i), Some(Some((tids[provider], 0))));
                }
            }
            // A freed target's own chain is free, unless a held target uses it.
            for q in (0..3).filter(|q| !held.contains(q)) {
                let chain = nodes[0].inputs[q].unwrap().node;
                assert_eq!(
                    guide.kept(tids[chain], 0),
                    None,
                    "round {round}, target {q}"
                );
            }
        }
        assert!(
            freed_counts.len() > 1,
            "rounds free different numbers of targets"
        );
    }

    #[test]
    fn the_shared_best_takes_only_cheaper_graphs_and_each_thread_sees_them_once() {
        let (nodes, tids) = graph();
        let graph_at = |value: f64| Best {
            cost: Cost {
                unsatisfied: 0,
                value,
            },
            nodes: Some(nodes.clone()),
            node_tids: tids.clone(),
        };
        let shared = Shared::default();
        let (mut main_seen, mut probes_seen) = (0, 0);
        let mut main = graph_at(10.0);
        shared.publish(&main, &mut main_seen);
        assert_eq!(main_seen, 1, "its own graph is seen already");
        let mut probes = graph_at(12.0);
        shared.refresh(&mut probes, &mut probes_seen);
        assert_eq!((probes.cost.value, probes_seen), (10.0, 1));
        // A dearer graph is not published; a cheaper one is, and reaches the other thread.
        shared.publish(&graph_at(11.0), &mut probes_seen);
        assert_eq!((shared.lock().cost.value, probes_seen), (10.0, 1));
        probes.cost.value = 9.0;
        probes.node_tids = vec![7];
        shared.publish(&probes, &mut probes_seen);
        assert_eq!(probes_seen, 2);
        shared.refresh(&mut main, &mut main_seen);
        assert_eq!(
            (main.cost.value, main.node_tids.as_slice(), main_seen),
            (9.0, &[7][..], 2)
        );
        // A thread cheaper than what was published keeps its own.
        let mut cheaper = graph_at(8.0);
        let mut cheaper_seen = 0;
        shared.refresh(&mut cheaper, &mut cheaper_seen);
        assert_eq!((cheaper.cost.value, cheaper_seen), (8.0, 2));
    }
    use proptest::prelude::*;

    /// Every way of giving rows distinct columns or none: (most rows assigned, least cost).
    fn brute(rows: &[Vec<(usize, f64)>], taken: &mut Vec<bool>, r: usize) -> (usize, f64) {
        if r == rows.len() {
            return (0, 0.0);
        }
        let (mut best_n, mut best_c) = brute(rows, taken, r + 1);
        for &(c, cost) in &rows[r] {
            if !taken[c] {
                taken[c] = true;
                let (n, sub) = brute(rows, taken, r + 1);
                taken[c] = false;
                if n + 1 > best_n || (n + 1 == best_n && sub + cost < best_c) {
                    (best_n, best_c) = (n + 1, sub + cost);
                }
            }
        }
        (best_n, best_c)
    }

    /// Rows over up to 8 columns, each listing at most 3 of them (so that rows often fall
    /// into several components) or, with `dense`, any number.
    fn rows() -> impl Strategy<Value = (Vec<Vec<(usize, f64)>>, usize)> {
        (1usize..9, any::<bool>()).prop_flat_map(|(columns, dense)| {
            let per_row = if dense { columns } else { columns.min(3) };
            (
                prop::collection::vec(
                    prop::collection::btree_map(0..columns, 0u8..20, 0..=per_row)
                        .prop_map(|m| m.into_iter().map(|(c, w)| (c, f64::from(w))).collect()),
                    0..7,
                ),
                Just(columns),
            )
        })
    }

    proptest! {
        #[test]
        fn the_assignment_is_a_maximum_matching_of_least_cost((rows, columns) in rows()) {
            let (unassigned, cost) = assignment(&rows, columns);
            let (assigned, best) = brute(&rows, &mut vec![false; columns], 0);
            prop_assert_eq!(rows.len() - unassigned, assigned);
            prop_assert!((cost - best).abs() < 1e-9, "split {} brute force {}", cost, best);
            // The split into components agrees with the dense method on the whole.
            let (whole_unassigned, whole_cost) = hungarian(&rows, columns);
            prop_assert_eq!(unassigned, whole_unassigned);
            prop_assert!((cost - whole_cost).abs() < 1e-9, "split {} whole {}", cost, whole_cost);
            let edges: Vec<Vec<usize>> =
                rows.iter().map(|r| r.iter().map(|(c, _)| *c).collect()).collect();
            prop_assert_eq!(matching(&edges, columns), assigned);
        }
    }
}
