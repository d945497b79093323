//! Reconfiguration benchmark (issue: engine): `cargo bench --workspace --bench explore`
//! (`./dev bench engine`). It lives with the life-cycle because a review reads and writes the
//! knowledge base; EXPLORE itself is `dyknow-engine`'s.
//!
//! 1. The seed's Chapter 6 segmenter crash (Piff's seven CUs running, the segmenter crashed):
//!    EXPLORE alone (in memory), and a whole review on the on-disk store (read the environment
//!    and candidate table with SPARQL, EXPLORE, COMPILE, write the change set's graph delta).
//! 2. Generated environments of 10 to 2,000 transformations and 1 to 50 targets: layered
//!    pipelines with alternatives (three transformations per tag), fan-in (two inputs) and
//!    fan-out (tags consumed by several transformations). Time to a proven optimum (capped),
//!    and the any-time cost gap to the independent peer's optimum at 10, 100 and 1,000 ms.
//!
//! The independent peer solves the same problem, read from a JSON instance written from the
//! environment and the candidate table (`instance`), not from EXPLORE's structures:
//! `EXPLORE_PEER=milp` (the default) is the mixed-integer programme of
//! `benches/peers/milp_explore.py` solved by HiGHS, which proves optima or gives a proven lower
//! bound; `EXPLORE_PEER=cpsat` is the CP-SAT model of `benches/peers/cpsat_explore.py` (it
//! proves nothing beyond 50 × 5 here: `docs/benchmarks.md`). Both need `PEER_PYTHON` (set by
//! `benches/run.sh`, which installs highspy and OR-Tools).
//!
//! Settings for iterating (environment): `EXPLORE_ONLY=layered-2000x50,…` runs only these
//! rows; `EXPLORE_CAP_SECONDS`, `EXPLORE_PEER_SECONDS` cap the proof and the peer (10 and
//! 60 s; `EXPLORE_CPSAT_SECONDS=N` alone still means CP-SAT for N s);
//! `EXPLORE_AT=10,100,1000` sets the any-time columns (ms); `EXPLORE_SEED=k` generates the
//! layered instances from another seed (0 is the published one); `EXPLORE_THREADS=n` sets the
//! probes' further threads (1 by default); `EXPLORE_INSTANCES=DIR` keeps each instance as JSON.
//!
//! 3. `EXPLORE_SEEDS=0-7` (or `0,3,5`) runs instead issue 18's any-time and proof bars over
//!    generated instances: for each seed, layered 200 × 10 (time to the proof, capped at
//!    `EXPLORE_CAP_SECONDS`, default 1) and 500 × 20, 1,000 × 30, 2,000 × 50 (absolute costs
//!    at the `EXPLORE_AT` marks, default 100,300,1000, and after the capped search), each
//!    against what is known of that instance's optimum in `benches/explore-best-known.csv`:
//!    the cheapest cost any run found and the best lower bound the MILP peer proved (equal:
//!    the optimum). The peer runs beside each instance when `EXPLORE_PEER_SECONDS` is set
//!    (default 0 here: the file holds its results). Then the mean gap to the cheapest known
//!    cost, the instances more than 1 % above it, and those proven within 1 % of the optimum
//!    (at most 1.01 × the proven bound) at each mark; for 200 × 10 the root bounds: EXPLORE's
//!    and (with `PEER_PYTHON`) the LP relaxation's of `benches/peers/lp_explore.py`, and the
//!    peer's own proof. A cheaper cost or a higher bound than the file's is marked `new`;
//!    `EXPLORE_BEST_KNOWN=update` writes it to the file. A cost below a proven bound stops the
//!    bench: one of the two models is wrong.
//!
//! EXPLORE has no published peer to run side by side (the thesis' implementation is not
//! available); the brute-force optimum of `engine/tests/brute_force.rs` is the reference for
//! correctness on small environments, and the MILP peer's proven optima and bounds here.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::io::Write;
use std::time::{Duration, Instant};

use dyknow_engine::{
    Candidates, Environment, ExploreOptions, Ids, ProbeOptions, Target, Transformation, explore,
};
use dyknow_store::model;
use dyknow_store::{EnvironmentPart, InputFormat, KnowledgeBase};

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn ms(d: Duration) -> String {
    format!("{:.3} ms", d.as_secs_f64() * 1e3)
}

fn load_specs(kb: &KnowledgeBase, files: &[&str]) {
    for f in files {
        let path = format!("{}/../specs/turtle/{f}", env!("CARGO_MANIFEST_DIR"));
        kb.load_document(&std::fs::read(&path).unwrap(), InputFormat::Turtle)
            .unwrap();
    }
}

/// One review on the knowledge base: load, EXPLORE, COMPILE, write the graph delta.
fn review(kb: &KnowledgeBase, prefer: Vec<dyknow_engine::Tid>, ids: &mut Ids) -> f64 {
    let loaded = model::load(kb).unwrap();
    let options = ExploreOptions {
        prefer,
        ..ExploreOptions::default()
    };
    let reviewed = dyknow_engine::review(&loaded.env, &loaded.candidates, &options, ids);
    let delta = model::delta(&loaded.env, &reviewed.after, &loaded.iris);
    kb.set_environment(&delta.parts).unwrap();
    reviewed.compiled.cost.total
}

fn segmenter_crash(out: &mut impl Write, dir: &std::path::Path, runs: usize) {
    let kb = KnowledgeBase::open(dir.join("ch6")).unwrap();
    load_specs(&kb, &["ch6-target.ttl", "ch6-piff.ttl"]);
    let mut ids = Ids::default();
    review(&kb, Vec::new(), &mut ids);
    let loaded = model::load(&kb).unwrap();
    let segmenter = loaded
        .env
        .cus
        .values()
        .find(|c| c.tid == "segmenter(piff)")
        .unwrap()
        .clone();
    // EXPLORE alone on the environment after the crash.
    let mut env = loaded.env.clone();
    env.cus.remove(&segmenter.cid);
    let options = ExploreOptions {
        prefer: vec![segmenter.tid.clone()],
        ..ExploreOptions::default()
    };
    let mut times = Vec::new();
    for _ in 0..runs {
        let start = Instant::now();
        let e = explore(&env, &loaded.candidates, &options);
        times.push(start.elapsed());
        assert!(e.proven_optimal);
    }
    let explore_alone = median(times);
    // A whole review on the on-disk store: crash (untimed), review (timed), restore (untimed).
    let mut reviews = Vec::new();
    for _ in 0..runs {
        let now = model::load(&kb).unwrap();
        let seg = now
            .env
            .cus
            .values()
            .find(|c| c.tid == "segmenter(piff)")
            .unwrap()
            .cid
            .clone();
        kb.set_environment(&[(EnvironmentPart::Cu(seg), Vec::new())])
            .unwrap();
        let start = Instant::now();
        let cost = review(&kb, vec!["segmenter(piff)".into()], &mut ids);
        reviews.push(start.elapsed());
        assert_eq!(cost, 71.0, "a new segmenter (11) and six kept CUs (60)");
    }
    let _ = writeln!(
        out,
        "| Chapter 6 segmenter crash | {} | {} |",
        ms(explore_alone),
        ms(median(reviews))
    );
}

/// A deterministic generator (xorshift).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn cost(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() % 1000) as f64 / 1000.0
    }
}

/// Layered pipelines: `levels` levels of tags; every tag is produced by three alternative
/// transformations, each taking one or two tags of the level below (sources at level 0).
fn generated(transformations: usize, targets: usize, seed: u64) -> (Environment, Candidates) {
    let mut rng = Rng(seed);
    let levels = 5;
    let alternatives = 3;
    let per_level = (transformations / (levels * alternatives)).max(1);
    let mut env = Environment::default();
    let mut in_tags: Vec<(String, Vec<String>)> = Vec::new();
    let mut out_tags: Vec<(String, String)> = Vec::new();
    let mut k = 0;
    'outer: for level in 0..levels {
        for t in 0..per_level {
            for a in 0..alternatives {
                if k >= transformations {
                    break 'outer;
                }
                let tid = format!("t{k}");
                k += 1;
                let inputs: Vec<String> = if level == 0 {
                    Vec::new()
                } else {
                    (0..1 + rng.below(2))
                        .map(|_| format!("L{}-{}", level - 1, rng.below(per_level)))
                        .collect()
                };
                env.library.insert(
                    tid.as_str().into(),
                    Transformation {
                        tid: tid.as_str().into(),
                        inputs: (0..inputs.len()).map(|i| format!("in{i}")).collect(),
                        outputs: vec!["out".into()],
                        labour: rng.cost(0.5, 2.0),
                        upkeep: rng.cost(0.1, 1.5) + 0.01 * a as f64,
                    },
                );
                in_tags.push((tid.clone(), inputs));
                out_tags.push((tid, format!("L{level}-{t}")));
            }
        }
    }
    // Targets ask for tags of the highest level whose tags all have producers.
    let top_level = (k / (per_level * alternatives)).clamp(1, levels) - 1;
    let wants = (0..targets)
        .map(|q| {
            let tag = format!("L{top_level}-{}", rng.below(per_level));
            (format!("q{q}"), format!("/target{q}"), tag)
        })
        .collect();
    tagged(
        env,
        &in_tags.into_iter().collect(),
        &out_tags.into_iter().collect(),
        wants,
    )
}

/// `env` with the targets `wants` (qid, channel, wanted tag) and the candidate table of its
/// tags: each transformation's input tags and (single) output tag, each target's wanted tag,
/// matched by equality.
fn tagged(
    mut env: Environment,
    inputs: &std::collections::HashMap<String, Vec<String>>,
    output: &std::collections::HashMap<String, String>,
    wants: Vec<(String, String, String)>,
) -> (Environment, Candidates) {
    let mut tag_of = std::collections::HashMap::new();
    for (qid, channel, tag) in wants {
        env.targets.insert(
            qid.as_str().into(),
            Target {
                qid: qid.as_str().into(),
                channel: channel.into(),
            },
        );
        tag_of.insert(qid, tag);
    }
    let wants = tag_of;
    let candidates = Candidates::from_tags(
        &env,
        |tid, i| vec![inputs[tid][i].clone()],
        |tid, _| vec![output[tid].clone()],
        |qid| vec![wants[qid].clone()],
        |a: &String, b: &String| a == b,
    );
    (env, candidates)
}

/// The scale bench's library (`server/benches/scale.rs`), in memory: streams `s0 … s{N/2-1}`
/// in a tree (stream k ≥ 1 computed from stream (k-1)/4), each with two producers, `p{k}a`
/// (upkeep 1) and `p{k}b` (upkeep 2), labour 1; target j wants stream
/// `N/2 - 1 - (7919 j mod N/2)` on a channel of its own.
fn tree(transformations: usize, targets: usize) -> (Environment, Candidates) {
    let streams = (transformations / 2).max(1);
    let mut env = Environment::default();
    let mut input_of = std::collections::HashMap::new();
    let mut output_of = std::collections::HashMap::new();
    for k in 0..streams {
        for (v, upkeep) in [('a', 1.0), ('b', 2.0)] {
            let tid = format!("p{k}{v}");
            let inputs = if k == 0 {
                Vec::new()
            } else {
                vec![format!("s{}", (k - 1) / 4)]
            };
            env.library.insert(
                tid.as_str().into(),
                Transformation {
                    tid: tid.as_str().into(),
                    inputs: (0..inputs.len()).map(|i| format!("in{i}")).collect(),
                    outputs: vec!["out".into()],
                    labour: 1.0,
                    upkeep,
                },
            );
            input_of.insert(tid.clone(), inputs);
            output_of.insert(tid, format!("s{k}"));
        }
    }
    let wants = (0..targets)
        .map(|j| {
            let tag = format!("s{}", streams - 1 - (j * 7919) % streams);
            (format!("q{j}"), format!("out{j}"), tag)
        })
        .collect();
    tagged(env, &input_of, &output_of, wants)
}

/// The configuration problem of `env` as the CP-SAT reference reads it
/// (`benches/peers/cpsat_explore.py`), derived from the environment and the candidate table
/// alone: per transformation its node cost (an existing CU's upkeep over the horizon, else a
/// spawn's labour and upkeep), its existing CUs (protected and others) and what keeping or
/// spawning a further CU costs, and its inputs' providers; per target its providers and
/// channel.
fn instance(env: &Environment, candidates: &Candidates, options: &ExploreOptions) -> String {
    let h = options.horizon;
    let tids: Vec<&dyknow_engine::Tid> = env.library.keys().collect();
    let index: std::collections::HashMap<&str, usize> = tids
        .iter()
        .enumerate()
        .map(|(i, t)| (t.as_str(), i))
        .collect();
    let providers = |list: &[dyknow_engine::Provider]| -> Vec<(usize, usize)> {
        list.iter()
            .filter_map(|p| {
                let t = *index.get(p.tid.as_str())?;
                (p.port < env.library[&p.tid].outputs.len()).then_some((t, p.port))
            })
            .collect()
    };
    let transformations: Vec<serde_json::Value> = tids
        .iter()
        .map(|tid| {
            let tf = &env.library[*tid];
            let existing: Vec<_> = env.cus.values().filter(|c| c.tid == **tid).collect();
            let cost = if existing.is_empty() {
                tf.labour + h * tf.upkeep
            } else {
                h * tf.upkeep
            };
            let protected = existing.iter().filter(|c| c.protected).count();
            serde_json::json!({
                "tid": tid.as_str(),
                "cost": cost,
                "protected": protected > 0,
                "protected_cus": protected,
                "other_cus": existing.len() - protected,
                "keep": h * tf.upkeep,
                "spawn": tf.labour + h * tf.upkeep,
                "inputs": (0..tf.inputs.len())
                    .map(|i| providers(candidates.for_input(tid, i)))
                    .collect::<Vec<_>>(),
            })
        })
        .collect();
    let targets: Vec<serde_json::Value> = env
        .targets
        .values()
        .map(|q| {
            serde_json::json!({
                "qid": q.qid.as_str(),
                "channel": q.channel.as_str(),
                "providers": providers(candidates.for_target(&q.qid)),
            })
        })
        .collect();
    let constant: f64 = env
        .cus
        .values()
        .filter(|c| c.protected)
        .map(|c| h * env.library.get(&c.tid).map_or(0.0, |t| t.upkeep))
        .sum();
    serde_json::json!({
        "transformations": transformations,
        "targets": targets,
        "relax": options.relax,
        "constant": constant,
    })
    .to_string()
}

/// CP-SAT's answer: (cost, unsatisfied, bound, status, seconds), or why there is none.
struct Reference {
    cost: f64,
    unsatisfied: u32,
    bound: Option<f64>,
    status: String,
    seconds: f64,
}

/// Runs `benches/peers/<script>` with `args` under `PEER_PYTHON` (set by `benches/run.sh`,
/// with OR-Tools installed), `instance` on its standard input; its one JSON line, or why
/// there is none (the last line of its standard error).
fn peer(script: &str, args: &[&str], instance: &str) -> Result<serde_json::Value, String> {
    use std::process::{Command, Stdio};
    let python = std::env::var("PEER_PYTHON").map_err(|_| "PEER_PYTHON unset".to_owned())?;
    let path = format!("{}/../benches/peers/{script}", env!("CARGO_MANIFEST_DIR"));
    let mut child = Command::new(python)
        .arg(&path)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| e.to_string())?;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(instance.as_bytes())
        .map_err(|e| e.to_string())?;
    let output = child.wait_with_output().map_err(|e| e.to_string())?;
    let stderr = String::from_utf8_lossy(&output.stderr);
    let last_error = || {
        stderr
            .lines()
            .rfind(|l| !l.trim().is_empty())
            .unwrap_or("no message")
            .to_owned()
    };
    if !output.status.success() {
        return Err(format!(
            "{script} failed ({}): {}",
            output.status,
            last_error()
        ));
    }
    // The answer is the last line (a solver may print a banner before it).
    let stdout = String::from_utf8_lossy(&output.stdout);
    let last = stdout.lines().rfind(|l| !l.trim().is_empty()).unwrap_or("");
    serde_json::from_str(last)
        .map_err(|e| format!("{script} printed no JSON line ({e}): {last:.80}"))
}

/// The independent exact method the bench compares EXPLORE with: `EXPLORE_PEER=milp` (the
/// default: the mixed-integer programme of `benches/peers/milp_explore.py`, solved by HiGHS)
/// or `cpsat` (`benches/peers/cpsat_explore.py`, OR-Tools' CP-SAT), capped at
/// `EXPLORE_PEER_SECONDS`. `EXPLORE_CPSAT_SECONDS=N` alone, as before, means CP-SAT for N s.
#[derive(Clone, Copy)]
struct Peer {
    milp: bool,
    seconds: u64,
}

impl Peer {
    /// The peer the environment asks for, capped at `default` seconds unless it says.
    fn from_env(default: u64) -> Self {
        let cpsat_seconds = std::env::var("EXPLORE_CPSAT_SECONDS").ok();
        let milp = match std::env::var("EXPLORE_PEER").as_deref() {
            Ok("milp") => true,
            Ok("cpsat") => false,
            Ok(other) => panic!("EXPLORE_PEER is milp or cpsat, not {other}"),
            Err(_) => cpsat_seconds.is_none(),
        };
        let seconds = if milp {
            number("EXPLORE_PEER_SECONDS", default)
        } else {
            number(
                "EXPLORE_PEER_SECONDS",
                number("EXPLORE_CPSAT_SECONDS", default),
            )
        };
        Self { milp, seconds }
    }

    /// Whether it runs: a peer Python is set and the cap is above 0.
    fn runs(self) -> bool {
        std::env::var("PEER_PYTHON").is_ok() && self.seconds > 0
    }

    fn name(self) -> &'static str {
        if self.milp { "MILP (HiGHS)" } else { "CP-SAT" }
    }

    /// The source a reference cost of this peer is recorded with.
    fn source(self) -> &'static str {
        if self.milp { "HiGHS" } else { "CP-SAT" }
    }

    /// Solves `instance` within the cap, on 2 threads.
    fn solve(self, instance: &str) -> Result<Reference, String> {
        let script = if self.milp {
            "milp_explore.py"
        } else {
            "cpsat_explore.py"
        };
        let v = peer(script, &[&self.seconds.to_string(), "2"], instance)?;
        Ok(Reference {
            cost: v["cost"].as_f64().ok_or(format!("no solution: {v}"))?,
            unsatisfied: v["unsatisfied"].as_u64().unwrap_or(0) as u32,
            bound: v["bound"].as_f64(),
            status: v["status"].as_str().unwrap_or("?").to_owned(),
            seconds: v["seconds"].as_f64().unwrap_or(f64::NAN),
        })
    }
}

impl Reference {
    /// Whether the peer proved its cost optimal.
    fn optimal(&self) -> bool {
        self.status.eq_ignore_ascii_case("optimal")
    }

    /// The table cell: cost, status, time, and the bound when not optimal.
    fn cell(&self) -> String {
        format!(
            "{} ({}, {:.2} s{})",
            fmt_cost(dyknow_engine::Cost {
                unsatisfied: self.unsatisfied,
                value: self.cost
            }),
            self.status.to_lowercase(),
            self.seconds,
            match self.bound {
                Some(b) if !self.optimal() => format!(", bound {b:.2}"),
                _ => String::new(),
            }
        )
    }
}

fn fmt_cost(c: dyknow_engine::Cost) -> String {
    if c.unsatisfied > 0 {
        format!("{:.2} ({} unsatisfied)", c.value, c.unsatisfied)
    } else {
        format!("{:.2}", c.value)
    }
}

/// EXPLORE with its any-time probes, within `timeout`; `EXPLORE_THREADS=n` sets the probes'
/// further threads (`ProbeOptions::threads`).
fn explore_within(
    env: &Environment,
    candidates: &Candidates,
    timeout: Option<Duration>,
) -> dyknow_engine::Exploration {
    let threads = number("EXPLORE_THREADS", ProbeOptions::default().threads as u64);
    explore(
        env,
        candidates,
        &ExploreOptions {
            timeout,
            probes: Some(ProbeOptions {
                threads: usize::try_from(threads).unwrap(),
                ..ProbeOptions::default()
            }),
            ..ExploreOptions::default()
        },
    )
}

/// One instance: EXPLORE (first solution, proof capped at `cap`, any-time at the timeouts
/// `at_ms`, its root bound) beside the independent peer's optimum, as a table row.
fn row(
    out: &mut impl Write,
    family: &str,
    (n, q): (usize, usize),
    (env, candidates): (Environment, Candidates),
    cap: Duration,
    peer: Peer,
    at_ms: [u64; 3],
) {
    // `EXPLORE_ONLY=layered-500x20,…` runs only these rows.
    if let Ok(only) = std::env::var("EXPLORE_ONLY")
        && !only.split(',').any(|o| o == format!("{family}-{n}x{q}"))
    {
        return;
    }
    let options = ExploreOptions::default();
    let run = |timeout: Option<Duration>| explore_within(&env, &candidates, timeout);
    // First solution: the smallest timeout (backtracking stops as soon as one exists).
    let first = run(Some(Duration::ZERO));
    let full = run(Some(cap));
    let at: Vec<_> = at_ms
        .iter()
        .map(|t| run(Some(Duration::from_millis(*t))))
        .collect();
    let root = dyknow_engine::lower_bound(&env, &candidates, &options);
    let json = instance(&env, &candidates, &options);
    // `EXPLORE_INSTANCES=DIR` keeps each instance, to rerun the reference by hand.
    if let Ok(keep) = std::env::var("EXPLORE_INSTANCES") {
        let _ = std::fs::write(format!("{keep}/{family}-{n}x{q}.json"), &json);
    }
    let reference = peer.solve(&json);
    let gap = |e: &dyknow_engine::Exploration| match (&e.plan, &reference) {
        (Some(_), Ok(r)) if r.unsatisfied == e.cost.unsatisfied => {
            format!(
                "{:.2} %",
                100.0 * (e.cost.value - r.cost) / r.cost.max(1e-12)
            )
        }
        (Some(_), Ok(r)) => format!(
            "{} unsatisfied {}",
            e.cost.unsatisfied.abs_diff(r.unsatisfied),
            if e.cost.unsatisfied > r.unsatisfied {
                "more"
            } else {
                "fewer"
            }
        ),
        (None, _) => "none".to_owned(),
        (_, Err(_)) => "n/a".to_owned(),
    };
    let proven = if full.proven_optimal {
        ms(full.elapsed)
    } else {
        format!("not within {} s", cap.as_secs())
    };
    let reference_cell = match &reference {
        Ok(r) => r.cell(),
        Err(e) => format!("n/a ({e})"),
    };
    let _ = writeln!(
        out,
        "| {family} | {n} | {q} | {} | {proven} | {} | {} | {reference_cell} | {} | {} | {} |",
        ms(first.elapsed),
        fmt_cost(full.cost),
        fmt_cost(root),
        gap(&at[0]),
        gap(&at[1]),
        gap(&at[2]),
    );
    let _ = out.flush();
}

/// The whole number in environment variable `name`, else `default`.
fn number(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// The any-time columns' timeouts in milliseconds: `EXPLORE_AT=10,100,1000` (the default;
/// other times show how long an instance takes to come within a gap).
fn any_time_millis() -> [u64; 3] {
    match std::env::var("EXPLORE_AT") {
        Err(_) => [10, 100, 1000],
        Ok(v) => {
            let given: Vec<u64> = v.split(',').filter_map(|x| x.trim().parse().ok()).collect();
            given.try_into().unwrap_or_else(|_| {
                panic!("EXPLORE_AT takes three times in milliseconds, e.g. 10,100,1000")
            })
        }
    }
}

/// Milliseconds with a thousands separator.
fn grouped(ms: u64) -> String {
    if ms >= 1000 {
        format!("{},{:03}", ms / 1000, ms % 1000)
    } else {
        ms.to_string()
    }
}

fn main() {
    if let Ok(seeds) = std::env::var("EXPLORE_SEEDS") {
        seeds_table(&parse_seeds(&seeds));
        return;
    }
    let quick = std::env::var("BENCH_QUICK").is_ok();
    // `EXPLORE_CAP_SECONDS=N` caps EXPLORE's proof differently, `EXPLORE_PEER_SECONDS=N` the
    // peer (e.g. short, when iterating on EXPLORE with `EXPLORE_ONLY`; the published gaps
    // are against the 60 s reference).
    let cap = Duration::from_secs(number("EXPLORE_CAP_SECONDS", if quick { 2 } else { 10 }));
    let peer = Peer::from_env(if quick { 10 } else { 60 });
    let dir = tempfile::tempdir().unwrap();
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "# DyKnow reconfiguration benchmark\n");
    let _ = writeln!(
        out,
        "| case | EXPLORE (median) | whole review on the on-disk store (median) |"
    );
    let _ = writeln!(out, "| --- | --- | --- |");
    if std::env::var("EXPLORE_ONLY").is_err() {
        segmenter_crash(&mut out, dir.path(), if quick { 5 } else { 51 });
    }

    let _ = writeln!(
        out,
        "\n## Generated environments against {} (horizon 10; EXPLORE's proof capped at {} s, the peer's at {} s, 2 threads)\n",
        peer.name(),
        cap.as_secs(),
        peer.seconds,
    );
    let at_ms = any_time_millis();
    let seed = number("EXPLORE_SEED", 0);
    let [a, b, c] = at_ms.map(grouped);
    let _ = writeln!(
        out,
        "| family | transformations | targets | first solution | proven optimum | cost after the capped search | root bound | {} (status, time) | gap to it at {a} ms | at {b} ms | at {c} ms |",
        peer.name()
    );
    let _ = writeln!(
        out,
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    let layered: &[(usize, usize)] = if quick {
        &[(10, 1), (50, 5), (200, 10)]
    } else {
        &[
            (10, 1),
            (50, 5),
            (200, 10),
            (500, 20),
            (1000, 30),
            (2000, 50),
        ]
    };
    for &(n, q) in layered {
        let instance = generated(n, q, 0x5eed + n as u64 + seed);
        row(&mut out, "layered", (n, q), instance, cap, peer, at_ms);
    }
    let trees: &[(usize, usize)] = if quick {
        &[(100, 1), (200, 10)]
    } else {
        &[(100, 1), (200, 10), (2000, 50), (10000, 50)]
    };
    for &(n, q) in trees {
        row(&mut out, "tree", (n, q), tree(n, q), cap, peer, at_ms);
    }
}

/// `0-7` or `0,3,5`.
fn parse_seeds(text: &str) -> Vec<u64> {
    let bad = || panic!("EXPLORE_SEEDS takes a range or a list of seeds, e.g. 0-7 or 0,3,5");
    if let Some((a, b)) = text.split_once('-') {
        let (a, b): (u64, u64) = (
            a.trim().parse().unwrap_or_else(|_| bad()),
            b.trim().parse().unwrap_or_else(|_| bad()),
        );
        return (a..=b).collect();
    }
    let seeds: Vec<u64> = text
        .split(',')
        .map(|x| x.trim().parse().unwrap_or_else(|_| bad()))
        .collect();
    if seeds.is_empty() {
        bad();
    }
    seeds
}

/// What is known of each generated instance's optimum: (seed, "NxQ") → the cheapest cost any
/// run found (an upper bound on the optimum), where it came from, and the best proven lower
/// bound (the independent peer's), from `benches/explore-best-known.csv`
/// (`seed,instance,cost,bound,source`; `bound` empty when none is known). A bound equal to the
/// cost proves that cost optimal.
struct BestKnown {
    path: std::path::PathBuf,
    known: std::collections::BTreeMap<(u64, String), Known>,
}

#[derive(Clone, Debug)]
struct Known {
    cost: f64,
    bound: Option<f64>,
    source: String,
}

impl Known {
    /// Whether the cost is proven optimal (up to the solvers' tolerance, 1e-6 relative).
    fn optimal(&self) -> bool {
        self.bound.is_some_and(|b| b >= self.cost * (1.0 - 1e-6))
    }
}

impl BestKnown {
    fn read() -> Self {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../benches/explore-best-known.csv");
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        let known = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .map(|l| {
                let parsed = (|| {
                    let mut cells = l.splitn(5, ',');
                    let seed = cells.next()?.trim().parse().ok()?;
                    let instance = cells.next()?.trim().to_owned();
                    let cost = cells.next()?.trim().parse().ok()?;
                    let bound = match cells.next()?.trim() {
                        "" => None,
                        b => Some(b.parse().ok()?),
                    };
                    let source = cells.next().unwrap_or("").trim().to_owned();
                    Some((
                        (seed, instance),
                        Known {
                            cost,
                            bound,
                            source,
                        },
                    ))
                })();
                parsed.unwrap_or_else(|| {
                    panic!(
                        "{}: not seed,instance,cost,bound,source: {l}",
                        path.display()
                    )
                })
            })
            .collect();
        Self { path, known }
    }

    fn get(&self, seed: u64, instance: &str) -> Option<&Known> {
        self.known.get(&(seed, instance.to_owned()))
    }

    /// Keeps `cost` when it is cheaper than the known one; whether it was. A cost below the
    /// proven bound means that one of the two methods is wrong: the bench stops.
    fn offer(&mut self, seed: u64, instance: &str, cost: f64, source: &str) -> bool {
        let key = (seed, instance.to_owned());
        let entry = self.known.entry(key).or_insert_with(|| Known {
            cost: f64::INFINITY,
            bound: None,
            source: String::new(),
        });
        if let Some(b) = entry.bound {
            assert!(
                cost >= b - 1e-6 * b.abs().max(1.0),
                "seed {seed} {instance}: {source} found {cost}, below the proven bound {b}: \
                 EXPLORE's cost model or the peer's model is wrong"
            );
        }
        let cheaper = cost < entry.cost - 1e-9;
        if cheaper {
            entry.cost = cost;
            entry.source = source.to_owned();
        }
        cheaper
    }

    /// Keeps `bound` when it is above the known one; whether it was. A bound above a known
    /// cost stops the bench, as in `offer`.
    fn offer_bound(&mut self, seed: u64, instance: &str, bound: f64) -> bool {
        let known = self.get(seed, instance).cloned();
        if let Some(k) = &known {
            assert!(
                bound <= k.cost + 1e-6 * k.cost.abs().max(1.0),
                "seed {seed} {instance}: a proven bound {bound} above the cost {} that {} \
                 found: EXPLORE's cost model or the peer's model is wrong",
                k.cost,
                k.source
            );
        }
        let Some(entry) = self.known.get_mut(&(seed, instance.to_owned())) else {
            return false;
        };
        let higher = entry.bound.is_none_or(|b| bound > b + 1e-9);
        if higher {
            // A bound within the tolerance of the cost proves it: recorded as the cost.
            entry.bound = Some(bound.min(entry.cost));
        }
        higher
    }

    fn write(&self) {
        let mut text = String::from(
            "# What is known of the optimum of each generated layered instance of\n\
             # lifecycle/benches/explore.rs (EXPLORE_SEED=seed), from any run: the cheapest cost\n\
             # found and where, and the best lower bound proven by the independent MILP peer\n\
             # (benches/peers/milp_explore.py, HiGHS); cost = bound: proven optimal. The reference\n\
             # of EXPLORE_SEEDS=... (docs/benchmarks.md). Written by EXPLORE_BEST_KNOWN=update.\n\
             # seed,instance,cost,bound,source\n",
        );
        for ((seed, instance), k) in &self.known {
            let bound = k.bound.map_or(String::new(), |b| format!("{b:.6}"));
            text.push_str(&format!(
                "{seed},{instance},{:.6},{bound},{}\n",
                k.cost, k.source
            ));
        }
        std::fs::write(&self.path, text).unwrap();
    }
}

/// A 200 × 10 instance's proof: its time (`None`: not within the cap), the cost found, the
/// bounds at the root (EXPLORE's, the LP relaxation's when a peer Python is set), and the
/// peer's own solve when it ran.
struct Proof {
    seed: u64,
    proven: Option<Duration>,
    cost: dyknow_engine::Cost,
    root: f64,
    lp: Option<Result<f64, String>>,
    peer: Option<Result<Reference, String>>,
}

/// The LP relaxation's bound of `instance` (`benches/peers/lp_explore.py`, OR-Tools' GLOP).
fn lp_bound(instance: &str) -> Result<f64, String> {
    let v = peer("lp_explore.py", &[], instance)?;
    v["bound"].as_f64().ok_or(format!("no bound: {v}"))
}

/// `EXPLORE_INSTANCES=DIR` keeps the instance `json` as `DIR/<name>.json`, for the peers by
/// hand.
fn keep_instance(json: &str, name: &str) {
    if let Ok(dir) = std::env::var("EXPLORE_INSTANCES") {
        let _ = std::fs::write(format!("{dir}/{name}.json"), json);
    }
}

/// Records what the peer found for an instance: its cost (when it feeds every target) and its
/// proven bound; how many of the two were news.
fn offer_reference(
    best: &mut BestKnown,
    seed: u64,
    instance: &str,
    peer: Peer,
    reference: &Result<Reference, String>,
) -> usize {
    let Ok(r) = reference else { return 0 };
    if r.unsatisfied != 0 {
        return 0;
    }
    let cheaper = best.offer(seed, instance, r.cost, peer.source());
    let higher = r.bound.is_some_and(|b| best.offer_bound(seed, instance, b));
    usize::from(cheaper) + usize::from(higher)
}

/// The reference cell of an instance: the cost, and whether it is the proven optimum or how
/// far the proven bound is below it.
fn known_cell(k: Option<&Known>) -> String {
    match k {
        None => "none".to_owned(),
        Some(k) if k.optimal() => format!("{:.2} (optimal)", k.cost),
        Some(Known {
            cost,
            bound: Some(b),
            ..
        }) => format!("{cost:.2} (bound {b:.2})"),
        Some(k) => format!("{:.2}", k.cost),
    }
}

/// Issue 18's any-time and proof bars over the generated instances of `seeds` (see the module
/// documentation, 3).
fn seeds_table(seeds: &[u64]) {
    let cap = Duration::from_secs(number("EXPLORE_CAP_SECONDS", 1));
    let peer = Peer::from_env(0);
    let at_ms = match std::env::var("EXPLORE_AT") {
        Ok(_) => any_time_millis(),
        Err(_) => [100, 300, 1000],
    };
    let update = std::env::var("EXPLORE_BEST_KNOWN").is_ok_and(|v| v == "update");
    let mut best = BestKnown::read();
    let mut out = std::io::stdout().lock();
    let run = |env: &Environment, candidates: &Candidates, timeout: Duration| {
        explore_within(env, candidates, Some(timeout))
    };
    let [a, b, c] = at_ms.map(grouped);
    let _ = writeln!(
        out,
        "# EXPLORE over generated instances (seeds {seeds:?}; proof and search capped at {} s{})\n",
        cap.as_secs(),
        if peer.runs() {
            format!(", {} at {} s", peer.name(), peer.seconds)
        } else {
            String::new()
        }
    );
    let _ = writeln!(
        out,
        "| seed | instance | reference (cheapest known; proven optimal or bound) | {a} ms | {b} ms | {c} ms | capped search | {} |",
        peer.name()
    );
    let _ = writeln!(out, "| --- | --- | --- | --- | --- | --- | --- | --- |");
    // Per instance, at each mark: the gap to the cheapest known cost, and to the proven bound
    // (an upper estimate of the gap to the optimum; infinite without a bound).
    let mut gaps: Vec<[(f64, f64); 3]> = Vec::new();
    // The longest any-time search at each mark: how far past its deadline a search returns.
    let mut longest = [Duration::ZERO; 3];
    let mut optimal = 0;
    let mut proofs: Vec<Proof> = Vec::new();
    let mut news = 0;
    for &seed in seeds {
        // 200 × 10: the proof.
        let (env, candidates) = generated(200, 10, 0x5eed + 200 + seed);
        let json = instance(&env, &candidates, &ExploreOptions::default());
        keep_instance(&json, &format!("layered-200x10-seed{seed}"));
        let full = run(&env, &candidates, cap);
        let root = dyknow_engine::lower_bound(&env, &candidates, &ExploreOptions::default());
        let lp = std::env::var("PEER_PYTHON").ok().map(|_| lp_bound(&json));
        let reference = peer.runs().then(|| peer.solve(&json));
        if full.plan.is_some() && full.cost.unsatisfied == 0 {
            news += usize::from(best.offer(seed, "200x10", full.cost.value, "EXPLORE"));
            if full.proven_optimal {
                news += usize::from(best.offer_bound(seed, "200x10", full.cost.value));
            }
        }
        if let Some(r) = &reference {
            news += offer_reference(&mut best, seed, "200x10", peer, r);
        }
        proofs.push(Proof {
            seed,
            proven: full.proven_optimal.then_some(full.elapsed),
            cost: full.cost,
            root: root.value,
            lp,
            peer: reference,
        });
        for (n, q) in [(500, 20), (1000, 30), (2000, 50)] {
            let name = format!("{n}x{q}");
            let (env, candidates) = generated(n, q, 0x5eed + n as u64 + seed);
            let json = instance(&env, &candidates, &ExploreOptions::default());
            keep_instance(&json, &format!("layered-{name}-seed{seed}"));
            let at: Vec<_> = at_ms
                .iter()
                .map(|t| run(&env, &candidates, Duration::from_millis(*t)))
                .collect();
            let full = run(&env, &candidates, cap);
            let reference = peer.runs().then(|| peer.solve(&json));
            let before = best.get(seed, &name).cloned();
            // Every cost of this run that satisfies every target, and the peer's.
            for e in at.iter().chain([&full]) {
                if e.plan.is_some() && e.cost.unsatisfied == 0 {
                    news += usize::from(best.offer(seed, &name, e.cost.value, "EXPLORE"));
                }
            }
            if let Some(r) = &reference {
                news += offer_reference(&mut best, seed, &name, peer, r);
            }
            let known = best.get(seed, &name).cloned();
            optimal += usize::from(known.as_ref().is_some_and(Known::optimal));
            let reference_cost = known.as_ref().map_or(f64::NAN, |k| k.cost);
            // The gaps of a graph feeding every target (none otherwise).
            let gap = |e: &dyknow_engine::Exploration| {
                (e.plan.is_some() && e.cost.unsatisfied == 0).then(|| {
                    (
                        100.0 * (e.cost.value / reference_cost - 1.0),
                        known
                            .as_ref()
                            .and_then(|k| k.bound)
                            .map_or(f64::INFINITY, |b| 100.0 * (e.cost.value / b - 1.0)),
                    )
                })
            };
            let cell = |e: &dyknow_engine::Exploration| match gap(e) {
                // A cost equal to the reference but summed in another order can fall a
                // few ulps below it: printed as 0.00 %, not -0.00 %.
                Some((g, _)) => format!(
                    "{:.2} ({:.2} %)",
                    e.cost.value,
                    if g.abs() < 0.005 { 0.0 } else { g }
                ),
                None => fmt_cost(e.cost),
            };
            let g = |i: usize| gap(&at[i]).unwrap_or((f64::INFINITY, f64::INFINITY));
            gaps.push([g(0), g(1), g(2)]);
            for (l, e) in longest.iter_mut().zip(&at) {
                *l = (*l).max(e.elapsed);
            }
            let reference_cell = match &reference {
                None => "not run".to_owned(),
                Some(Ok(r)) => r.cell(),
                Some(Err(e)) => format!("n/a ({e})"),
            };
            let changed = match (&before, &known) {
                (Some(b), Some(k)) => b.cost != k.cost || b.bound != k.bound,
                (None, Some(_)) => true,
                _ => false,
            };
            let _ = writeln!(
                out,
                "| {seed} | {n} × {q} | {}{} | {} | {} | {} | {} | {reference_cell} |",
                known_cell(known.as_ref()),
                if changed { " (new)" } else { "" },
                cell(&at[0]),
                cell(&at[1]),
                cell(&at[2]),
                cell(&full),
            );
            let _ = out.flush();
        }
    }
    let count = gaps.len() as f64;
    let mean = |i: usize| gaps.iter().map(|g| g[i].0).sum::<f64>() / count;
    let over = |i: usize| gaps.iter().filter(|g| g[i].0 > 1.0).count();
    let certified = |i: usize| gaps.iter().filter(|g| g[i].1 <= 1.0).count();
    let _ = writeln!(
        out,
        "\n| | {a} ms | {b} ms | {c} ms |\n| --- | --- | --- | --- |\n\
         | mean gap to the cheapest known cost | {:.2} % | {:.2} % | {:.2} % |\n\
         | instances more than 1 % above it (of {}) | {} | {} | {} |\n\
         | instances proven within 1 % of the optimum (cost ≤ 1.01 × the proven bound) | {} | {} | {} |\n\
         | longest search (returned after) | {} | {} | {} |\n\n\
         Cheapest known cost proven optimal on {optimal} of {} instances.",
        mean(0),
        mean(1),
        mean(2),
        gaps.len(),
        over(0),
        over(1),
        over(2),
        certified(0),
        certified(1),
        certified(2),
        ms(longest[0]),
        ms(longest[1]),
        ms(longest[2]),
        gaps.len(),
    );
    // The proofs, with how far below the optimum (or the best known) the bounds start.
    let _ = writeln!(
        out,
        "\n| seed | 200 × 10: EXPLORE proven optimal | cost | reference | EXPLORE's root bound | LP bound (`benches/peers/lp_explore.py`) | {} |\n| --- | --- | --- | --- | --- | --- | --- |",
        peer.name()
    );
    for p in &proofs {
        let known = best.get(p.seed, "200x10");
        let below = |b: f64| {
            known.map_or(String::new(), |k| {
                format!(" ({:.1} % below)", 100.0 * (1.0 - b / k.cost))
            })
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {:.2}{} | {} | {} |",
            p.seed,
            p.proven
                .map_or(format!("not within {} s", cap.as_secs()), ms),
            fmt_cost(p.cost),
            known_cell(known),
            p.root,
            below(p.root),
            match &p.lp {
                None => "not run".to_owned(),
                Some(Ok(b)) => format!("{b:.2}{}", below(*b)),
                Some(Err(e)) => format!("n/a ({e})"),
            },
            match &p.peer {
                None => "not run".to_owned(),
                Some(Ok(r)) => r.cell(),
                Some(Err(e)) => format!("n/a ({e})"),
            }
        );
    }
    let _ = writeln!(
        out,
        "\n200 × 10 proven optimal by EXPLORE within {} s: {} of {}",
        cap.as_secs(),
        proofs.iter().filter(|p| p.proven.is_some()).count(),
        proofs.len(),
    );
    if peer.runs() {
        let _ = writeln!(
            out,
            "200 × 10 proven optimal by {} within {} s: {} of {} (within 1 s: {})",
            peer.name(),
            peer.seconds,
            proofs
                .iter()
                .filter(|p| matches!(&p.peer, Some(Ok(r)) if r.optimal()))
                .count(),
            proofs.len(),
            proofs
                .iter()
                .filter(|p| matches!(&p.peer, Some(Ok(r)) if r.optimal() && r.seconds <= 1.0))
                .count(),
        );
    }
    if news > 0 {
        if update {
            best.write();
            let _ = writeln!(
                out,
                "\n{news} cheaper costs or higher bounds than the reference's: written to {}",
                best.path.display()
            );
        } else {
            let _ = writeln!(
                out,
                "\n{news} cheaper costs or higher bounds than the reference's (EXPLORE_BEST_KNOWN=update writes them)"
            );
        }
    }
}
