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
//! EXPLORE has no published peer to run side by side (the thesis' implementation is not
//! available); the brute-force optimum of `engine/tests/brute_force.rs` is the reference for
//! correctness on small environments, and the best known cost is the reference here.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::io::Write;
use std::time::{Duration, Instant};

use dyknow_engine::{
    Candidates, Environment, ExploreOptions, Ids, Target, Transformation, explore,
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
    let mut target_tags = Vec::new();
    for q in 0..targets {
        let qid = format!("q{q}");
        env.targets.insert(
            qid.as_str().into(),
            Target {
                qid: qid.as_str().into(),
                channel: format!("/target{q}").into(),
            },
        );
        target_tags.push((qid, format!("L{top_level}-{}", rng.below(per_level))));
    }
    let ins: std::collections::HashMap<String, Vec<String>> = in_tags.into_iter().collect();
    let outs: std::collections::HashMap<String, String> = out_tags.into_iter().collect();
    let tq: std::collections::HashMap<String, String> = target_tags.into_iter().collect();
    let candidates = Candidates::from_tags(
        &env,
        |tid, i| vec![ins[tid][i].clone()],
        |tid, _| vec![outs[tid].clone()],
        |qid| vec![tq[qid].clone()],
        |a: &String, b: &String| a == b,
    );
    (env, candidates)
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok();
    let cap = Duration::from_secs(if quick { 2 } else { 10 });
    let dir = tempfile::tempdir().unwrap();
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "# DyKnow reconfiguration benchmark\n");
    let _ = writeln!(
        out,
        "| case | EXPLORE (median) | whole review on the on-disk store (median) |"
    );
    let _ = writeln!(out, "| --- | --- | --- |");
    segmenter_crash(&mut out, dir.path(), if quick { 5 } else { 51 });

    let _ = writeln!(
        out,
        "\n## Generated environments (horizon 10; proof capped at {} s)\n",
        cap.as_secs()
    );
    let _ = writeln!(
        out,
        "| transformations | targets | first solution | proven optimum | cost after the capped search | best known | gap at 10 ms | gap at 100 ms | gap at 1,000 ms |"
    );
    let _ = writeln!(
        out,
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    let sizes: &[(usize, usize)] = if quick {
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
    for &(n, q) in sizes {
        let (env, candidates) = generated(n, q, 0x5eed + n as u64);
        let run = |timeout: Option<Duration>| {
            explore(
                &env,
                &candidates,
                &ExploreOptions {
                    timeout,
                    ..ExploreOptions::default()
                },
            )
        };
        // First solution: the smallest timeout (backtracking stops as soon as one exists).
        let first = run(Some(Duration::ZERO));
        let full = run(Some(cap));
        let at: Vec<_> = [10u64, 100, 1000]
            .iter()
            .map(|t| run(Some(Duration::from_millis(*t))))
            .collect();
        let best = at
            .iter()
            .chain([&full, &first])
            .filter(|e| e.plan.is_some())
            .map(|e| e.cost)
            .fold(None, |b: Option<dyknow_engine::Cost>, c| match b {
                Some(b) if !c.below(b) => Some(b),
                _ => Some(c),
            });
        let gap = |e: &dyknow_engine::Exploration| match (&e.plan, best) {
            (Some(_), Some(b)) if b.unsatisfied == e.cost.unsatisfied => {
                format!(
                    "{:.2} %",
                    100.0 * (e.cost.value - b.value) / b.value.max(1e-12)
                )
            }
            (Some(_), Some(_)) => format!("{} unsatisfied more", e.cost.unsatisfied),
            _ => "none".to_owned(),
        };
        let proven = if full.proven_optimal {
            ms(full.elapsed)
        } else {
            format!("not within {} s", cap.as_secs())
        };
        let cost = |e: &dyknow_engine::Exploration| {
            if e.cost.unsatisfied > 0 {
                format!("{:.2} ({} unsatisfied)", e.cost.value, e.cost.unsatisfied)
            } else {
                format!("{:.2}", e.cost.value)
            }
        };
        let _ = writeln!(
            out,
            "| {n} | {q} | {} | {proven} | {} | {} | {} | {} | {} |",
            ms(first.elapsed),
            cost(&full),
            best.map_or("none".to_owned(), |b| format!("{:.2}", b.value)),
            gap(&at[0]),
            gap(&at[1]),
            gap(&at[2]),
        );
        let _ = out.flush();
    }
}
