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
//!    and the any-time cost gap to the best known cost at 10, 100 and 1,000 ms.
//!
//! Settings for iterating (environment): `EXPLORE_ONLY=layered-2000x50,…` runs only these
//! rows; `EXPLORE_CAP_SECONDS`, `EXPLORE_CPSAT_SECONDS` cap the proof and CP-SAT (10 and 60 s);
//! `EXPLORE_AT=10,100,1000` sets the any-time columns (ms); `EXPLORE_SEED=k` generates the
//! layered instances from another seed (0 is the published one); `EXPLORE_THREADS=n` sets the
//! probes' further threads (1 by default); `EXPLORE_INSTANCES=DIR` keeps each instance as JSON.
//!
//! 3. `EXPLORE_SEEDS=0-7` (or `0,3,5`) runs instead issue 18's any-time and proof bars over
//!    generated instances: for each seed, layered 200 × 10 (time to the proof, capped at
//!    `EXPLORE_CAP_SECONDS`, default 1) and 500 × 20, 1,000 × 30, 2,000 × 50 (absolute costs
//!    at the `EXPLORE_AT` marks, default 100,300,1000, and after the capped search), each
//!    against the cheapest cost known for that instance in `benches/explore-best-known.csv`
//!    (any run's, CP-SAT's included when `PEER_PYTHON` is set, unless `EXPLORE_CPSAT_SECONDS=0`);
//!    then the mean gap and the number of instances more than 1 % above it at each mark, and
//!    for 200 × 10 the root bounds: EXPLORE's and (with `PEER_PYTHON`) the LP relaxation's of
//!    `benches/peers/lp_explore.py`. A cheaper cost than the file's
//!    is marked `new best`; `EXPLORE_BEST_KNOWN=update` writes it to the file.
//!
//! EXPLORE has no published peer to run side by side (the thesis' implementation is not
//! available); the brute-force optimum of `engine/tests/brute_force.rs` is the reference for
//! correctness on small environments, and the best known cost is the reference here.
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
    let script = format!("{}/../benches/peers/{script}", env!("CARGO_MANIFEST_DIR"));
    let mut child = Command::new(python)
        .arg(script)
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
    let failed = || {
        String::from_utf8_lossy(&output.stderr)
            .lines()
            .last()
            .unwrap_or("failed")
            .to_owned()
    };
    if !output.status.success() {
        return Err(failed());
    }
    serde_json::from_slice(&output.stdout).map_err(|_| failed())
}

/// Solves `instance` with the CP-SAT reference (`benches/peers/cpsat_explore.py`), within
/// `seconds`.
fn cpsat(instance: &str, seconds: u64) -> Result<Reference, String> {
    let v = peer("cpsat_explore.py", &[&seconds.to_string(), "2"], instance)?;
    Ok(Reference {
        cost: v["cost"].as_f64().ok_or(format!("no solution: {v}"))?,
        unsatisfied: v["unsatisfied"].as_u64().unwrap_or(0) as u32,
        bound: v["bound"].as_f64(),
        status: v["status"].as_str().unwrap_or("?").to_owned(),
        seconds: v["seconds"].as_f64().unwrap_or(f64::NAN),
    })
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
/// `at_ms`, its root bound) beside CP-SAT's optimum, as a table row.
fn row(
    out: &mut impl Write,
    family: &str,
    (n, q): (usize, usize),
    (env, candidates): (Environment, Candidates),
    cap: Duration,
    cpsat_seconds: u64,
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
    let reference = cpsat(&json, cpsat_seconds);
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
        Ok(r) => format!(
            "{} ({}, {:.2} s{})",
            fmt_cost(dyknow_engine::Cost {
                unsatisfied: r.unsatisfied,
                value: r.cost
            }),
            r.status.to_lowercase(),
            r.seconds,
            match r.bound {
                Some(b) if r.status != "OPTIMAL" => format!(", bound {b:.2}"),
                _ => String::new(),
            }
        ),
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
    // `EXPLORE_CAP_SECONDS=N` caps EXPLORE's proof differently, `EXPLORE_CPSAT_SECONDS=N`
    // CP-SAT (e.g. short, when iterating on EXPLORE with `EXPLORE_ONLY`; the published gaps
    // are against the 60 s reference).
    let cap = Duration::from_secs(number("EXPLORE_CAP_SECONDS", if quick { 2 } else { 10 }));
    let cpsat_seconds = number("EXPLORE_CPSAT_SECONDS", if quick { 10 } else { 60 });
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
        "\n## Generated environments against CP-SAT (horizon 10; EXPLORE's proof capped at {} s, CP-SAT's at {cpsat_seconds} s, 2 workers)\n",
        cap.as_secs()
    );
    let at_ms = any_time_millis();
    let seed = number("EXPLORE_SEED", 0);
    let [a, b, c] = at_ms.map(grouped);
    let _ = writeln!(
        out,
        "| family | transformations | targets | first solution | proven optimum | cost after the capped search | root bound | CP-SAT (status, time) | gap to CP-SAT at {a} ms | at {b} ms | at {c} ms |"
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
        row(
            &mut out,
            "layered",
            (n, q),
            instance,
            cap,
            cpsat_seconds,
            at_ms,
        );
    }
    let trees: &[(usize, usize)] = if quick {
        &[(100, 1), (200, 10)]
    } else {
        &[(100, 1), (200, 10), (2000, 50), (10000, 50)]
    };
    for &(n, q) in trees {
        row(
            &mut out,
            "tree",
            (n, q),
            tree(n, q),
            cap,
            cpsat_seconds,
            at_ms,
        );
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

/// The cheapest cost known for each generated instance: (seed, "NxQ") → (cost, where it came
/// from), from `benches/explore-best-known.csv` (`seed,instance,cost,source`).
struct BestKnown {
    path: std::path::PathBuf,
    costs: std::collections::BTreeMap<(u64, String), (f64, String)>,
}

impl BestKnown {
    fn read() -> Self {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../benches/explore-best-known.csv");
        let text = std::fs::read_to_string(&path).unwrap_or_default();
        let costs = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .filter_map(|l| {
                let mut cells = l.splitn(4, ',');
                let seed = cells.next()?.trim().parse().ok()?;
                let instance = cells.next()?.trim().to_owned();
                let cost = cells.next()?.trim().parse().ok()?;
                let source = cells.next().unwrap_or("").trim().to_owned();
                Some(((seed, instance), (cost, source)))
            })
            .collect();
        Self { path, costs }
    }

    fn get(&self, seed: u64, instance: &str) -> Option<f64> {
        self.costs.get(&(seed, instance.to_owned())).map(|c| c.0)
    }

    /// Keeps `cost` when it is cheaper than the known one; whether it was.
    fn offer(&mut self, seed: u64, instance: &str, cost: f64, source: &str) -> bool {
        let key = (seed, instance.to_owned());
        let cheaper = self.costs.get(&key).is_none_or(|(c, _)| cost < *c - 1e-9);
        if cheaper {
            self.costs.insert(key, (cost, source.to_owned()));
        }
        cheaper
    }

    fn write(&self) {
        let mut text = String::from(
            "# The cheapest cost known for each generated layered instance of\n\
             # lifecycle/benches/explore.rs (EXPLORE_SEED=seed), from any run: the reference of\n\
             # EXPLORE_SEEDS=... (see docs/benchmarks.md). Written by EXPLORE_BEST_KNOWN=update.\n\
             # seed,instance,cost,source\n",
        );
        for ((seed, instance), (cost, source)) in &self.costs {
            text.push_str(&format!("{seed},{instance},{cost:.6},{source}\n"));
        }
        std::fs::write(&self.path, text).unwrap();
    }
}

/// A 200 × 10 instance's proof: its time (`None`: not within the cap), the cost found, and
/// the bounds at the root (EXPLORE's, the LP relaxation's when a peer Python is set).
struct Proof {
    seed: u64,
    proven: Option<Duration>,
    cost: dyknow_engine::Cost,
    root: f64,
    lp: Option<Result<f64, String>>,
}

/// The LP relaxation's bound of `instance` (`benches/peers/lp_explore.py`, OR-Tools' GLOP).
fn lp_bound(instance: &str) -> Result<f64, String> {
    let v = peer("lp_explore.py", &[], instance)?;
    v["bound"].as_f64().ok_or(format!("no bound: {v}"))
}

/// Issue 18's any-time and proof bars over the generated instances of `seeds` (see the module
/// documentation, 3).
fn seeds_table(seeds: &[u64]) {
    let cap = Duration::from_secs(number("EXPLORE_CAP_SECONDS", 1));
    let cpsat_seconds = number("EXPLORE_CPSAT_SECONDS", 60);
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
        if std::env::var("PEER_PYTHON").is_ok() && cpsat_seconds > 0 {
            format!(", CP-SAT at {cpsat_seconds} s")
        } else {
            String::new()
        }
    );
    let _ = writeln!(
        out,
        "| seed | instance | best known | {a} ms | {b} ms | {c} ms | capped search | CP-SAT |"
    );
    let _ = writeln!(out, "| --- | --- | --- | --- | --- | --- | --- | --- |");
    let mut gaps: Vec<[f64; 3]> = Vec::new();
    let mut proofs: Vec<Proof> = Vec::new();
    let mut new_best = 0;
    for &seed in seeds {
        // 200 × 10: the proof.
        let (env, candidates) = generated(200, 10, 0x5eed + 200 + seed);
        let full = run(&env, &candidates, cap);
        let root = dyknow_engine::lower_bound(&env, &candidates, &ExploreOptions::default());
        let lp = std::env::var("PEER_PYTHON")
            .ok()
            .map(|_| lp_bound(&instance(&env, &candidates, &ExploreOptions::default())));
        proofs.push(Proof {
            seed,
            proven: full.proven_optimal.then_some(full.elapsed),
            cost: full.cost,
            root: root.value,
            lp,
        });
        if full.plan.is_some()
            && full.cost.unsatisfied == 0
            && best.offer(seed, "200x10", full.cost.value, "EXPLORE")
        {
            new_best += 1;
        }
        for (n, q) in [(500, 20), (1000, 30), (2000, 50)] {
            let name = format!("{n}x{q}");
            let (env, candidates) = generated(n, q, 0x5eed + n as u64 + seed);
            let at: Vec<_> = at_ms
                .iter()
                .map(|t| run(&env, &candidates, Duration::from_millis(*t)))
                .collect();
            let full = run(&env, &candidates, cap);
            let reference =
                (std::env::var("PEER_PYTHON").is_ok() && cpsat_seconds > 0).then(|| {
                    let json = instance(&env, &candidates, &ExploreOptions::default());
                    cpsat(&json, cpsat_seconds)
                });
            // Every cost of this run that satisfies every target.
            let mut found: Vec<(f64, &str)> = at
                .iter()
                .chain([&full])
                .filter(|e| e.plan.is_some() && e.cost.unsatisfied == 0)
                .map(|e| (e.cost.value, "EXPLORE"))
                .collect();
            if let Some(Ok(r)) = &reference
                && r.unsatisfied == 0
            {
                found.push((r.cost, "CP-SAT"));
            }
            let known = best.get(seed, &name);
            let cheapest = found.iter().min_by(|x, y| x.0.total_cmp(&y.0)).copied();
            let marked =
                cheapest.is_some_and(|(cost, source)| best.offer(seed, &name, cost, source));
            new_best += usize::from(marked);
            // The best known, this run's cheapest included.
            let reference_cost = match (known, cheapest) {
                (Some(k), Some((c, _))) => k.min(c),
                (k, c) => k.or(c.map(|c| c.0)).unwrap_or(f64::NAN),
            };
            // The gap of a graph feeding every target (none otherwise).
            let gap = |e: &dyknow_engine::Exploration| {
                (e.plan.is_some() && e.cost.unsatisfied == 0)
                    .then(|| 100.0 * (e.cost.value / reference_cost - 1.0))
            };
            let cell = |e: &dyknow_engine::Exploration| match gap(e) {
                Some(g) => format!("{:.2} ({g:.2} %)", e.cost.value),
                None => fmt_cost(e.cost),
            };
            let g = |i: usize| gap(&at[i]).unwrap_or(f64::INFINITY);
            gaps.push([g(0), g(1), g(2)]);
            let reference_cell = match &reference {
                None => "not run".to_owned(),
                Some(Ok(r)) => format!(
                    "{} ({})",
                    fmt_cost(dyknow_engine::Cost {
                        unsatisfied: r.unsatisfied,
                        value: r.cost
                    }),
                    r.status.to_lowercase()
                ),
                Some(Err(e)) => format!("n/a ({e})"),
            };
            let _ = writeln!(
                out,
                "| {seed} | {n} × {q} | {}{} | {} | {} | {} | {} | {reference_cell} |",
                known.map_or("none".to_owned(), |k| format!("{k:.2}")),
                if marked { " (new best)" } else { "" },
                cell(&at[0]),
                cell(&at[1]),
                cell(&at[2]),
                cell(&full),
            );
            let _ = out.flush();
        }
    }
    let count = gaps.len() as f64;
    let mean = |i: usize| gaps.iter().map(|g| g[i]).sum::<f64>() / count;
    let over = |i: usize| gaps.iter().filter(|g| g[i] > 1.0).count();
    let _ = writeln!(
        out,
        "\n| | {a} ms | {b} ms | {c} ms |\n| --- | --- | --- | --- |\n| mean gap to the best known | {:.2} % | {:.2} % | {:.2} % |\n| instances more than 1 % above it (of {}) | {} | {} | {} |",
        mean(0),
        mean(1),
        mean(2),
        gaps.len(),
        over(0),
        over(1),
        over(2),
    );
    // The proofs, with how far below the optimum (or the best known) the bounds start.
    let _ = writeln!(
        out,
        "\n| seed | 200 × 10: proven optimal | cost | best known | EXPLORE's root bound | LP bound (`benches/peers/lp_explore.py`) |\n| --- | --- | --- | --- | --- | --- |"
    );
    for p in &proofs {
        let known = best.get(p.seed, "200x10");
        let below = |b: f64| {
            known.map_or(String::new(), |k| {
                format!(" ({:.1} % below)", 100.0 * (1.0 - b / k))
            })
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {:.2}{} | {} |",
            p.seed,
            p.proven
                .map_or(format!("not within {} s", cap.as_secs()), ms),
            fmt_cost(p.cost),
            known.map_or("none".to_owned(), |k| format!("{k:.2}")),
            p.root,
            below(p.root),
            match &p.lp {
                None => "not run".to_owned(),
                Some(Ok(b)) => format!("{b:.2}{}", below(*b)),
                Some(Err(e)) => format!("n/a ({e})"),
            }
        );
    }
    let _ = writeln!(
        out,
        "\n200 × 10 proven optimal within {} s: {} of {}",
        cap.as_secs(),
        proofs.iter().filter(|p| p.proven.is_some()).count(),
        proofs.len(),
    );
    if new_best > 0 {
        if update {
            best.write();
            let _ = writeln!(
                out,
                "\n{new_best} cheaper costs than the best known: written to {}",
                best.path.display()
            );
        } else {
            let _ = writeln!(
                out,
                "\n{new_best} cheaper costs than the best known (EXPLORE_BEST_KNOWN=update writes them)"
            );
        }
    }
}
