//! Reasoning benchmark (issue: reasoner): `cargo bench -p dyknow-store --bench reasoning`
//! (`./dev bench-reasoner` installs the peers and runs it).
//!
//! Environments: (a) 10,000 CUs in 500 pipelines of depth 20 with fan-in (CU i of a pipeline
//! subscribes to CUs i-1 and i-2); (b) one chain of 1,000 CUs. Each CU is one environment graph
//! (its type, its subscriptions and their `fromCU`). Measured: full materialisation (the
//! reasoner alone, and the whole write into a fresh on-disk store), adding one CU with its
//! subscription, and removing one CU from the middle of a pipeline / of the chain, on the
//! on-disk store (median of several runs, each on a different CU, the store restored between
//! runs and not timed). The peers (`owlrl`, `reasonable`, PyPI) materialise the same graphs in
//! the same run, as N-Triples files with the DyKnow ontology.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::io::Write;
use std::process::Command;
use std::time::{Duration, Instant};

use dyknow_reasoner::{Reasoner, TBox, builtin_ontology_triples};
use dyknow_store::oxigraph::model::vocab::rdf;
use dyknow_store::oxigraph::model::{NamedNode, Triple};
use dyknow_store::{EnvironmentPart, KnowledgeBase};

const DK: &str = "http://www.dyknow.eu/ontology/dyknow#";

fn dk(local: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("{DK}{local}"))
}

fn node(name: &str) -> NamedNode {
    NamedNode::new_unchecked(format!("urn:dyknow:bench:{name}"))
}

/// One CU's graph: its type, and a subscription from each upstream CU. With `direct`, the
/// upstream links are asserted `dependsOn` edges instead (the closure every peer computes).
/// The environment part of the CU named `name`.
fn cu_part(name: &str) -> EnvironmentPart {
    EnvironmentPart::Cu(name.into())
}

/// The parts of an environment given by CU name.
fn parts(env: &[(String, Vec<Triple>)]) -> Vec<(EnvironmentPart, Vec<Triple>)> {
    env.iter()
        .map(|(name, triples)| (cu_part(name), triples.clone()))
        .collect()
}

fn cu(name: &str, upstream: &[String], direct: bool) -> Vec<Triple> {
    let me = node(name);
    let mut out = vec![Triple::new(me.clone(), rdf::TYPE, dk("ComputationUnit"))];
    for (i, up) in upstream.iter().enumerate() {
        if direct {
            out.push(Triple::new(me.clone(), dk("dependsOn"), node(up)));
            continue;
        }
        let sub = node(&format!("{name}/sub/{i}"));
        out.push(Triple::new(me.clone(), dk("hasSubscription"), sub.clone()));
        out.push(Triple::new(sub.clone(), rdf::TYPE, dk("Subscription")));
        out.push(Triple::new(sub, dk("fromCU"), node(up)));
    }
    out
}

fn pipelines(count: usize, depth: usize, direct: bool) -> Vec<(String, Vec<Triple>)> {
    let mut out = Vec::new();
    for p in 0..count {
        for i in 0..depth {
            let name = format!("p{p}-cu{i}");
            let upstream: Vec<String> = [i.checked_sub(1), i.checked_sub(2)]
                .into_iter()
                .flatten()
                .map(|j| format!("p{p}-cu{j}"))
                .collect();
            out.push((name.clone(), cu(&name, &upstream, direct)));
        }
    }
    out
}

fn chain(length: usize) -> Vec<(String, Vec<Triple>)> {
    (0..length)
        .map(|i| {
            let name = format!("c{i}");
            let upstream: Vec<String> = i
                .checked_sub(1)
                .map(|j| format!("c{j}"))
                .into_iter()
                .collect();
            (name.clone(), cu(&name, &upstream, false))
        })
        .collect()
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn ms(d: Duration) -> String {
    format!("{:.3} ms", d.as_secs_f64() * 1e3)
}

fn peak_rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// Full materialisation by our reasoner alone: (time, facts in the materialisation).
fn ours_in_memory(env: &[(String, Vec<Triple>)]) -> (Duration, usize) {
    let start = Instant::now();
    let tbox = TBox::from_triples(&builtin_ontology_triples()).unwrap();
    let mut reasoner = Reasoner::new(tbox);
    reasoner.set_graphs(env);
    (start.elapsed(), reasoner.len())
}

fn write_ntriples(path: &std::path::Path, env: &[(String, Vec<Triple>)]) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    for t in builtin_ontology_triples()
        .iter()
        .chain(env.iter().flat_map(|(_, t)| t))
    {
        writeln!(f, "{t} .").unwrap();
    }
}

/// A peer's full materialisation: "seconds triples" or why not.
fn peer(python: &str, script: &str, which: &str, file: &std::path::Path, timeout: u64) -> String {
    let out = Command::new("timeout")
        .arg(timeout.to_string())
        .arg(python)
        .arg(script)
        .arg(which)
        .arg(file)
        .output();
    match out {
        Ok(o) if o.status.success() => {
            let s = String::from_utf8_lossy(&o.stdout);
            let mut parts = s.split_whitespace();
            let secs: f64 = parts
                .next()
                .and_then(|x| x.parse().ok())
                .unwrap_or(f64::NAN);
            let triples = parts.next().unwrap_or("?");
            format!("{:.1} ms ({triples} triples)", secs * 1e3)
        }
        Ok(o) if o.status.code() == Some(124) => format!("> {timeout} s (stopped)"),
        Ok(o) => format!(
            "failed: {}",
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .last()
                .unwrap_or("")
        ),
        Err(e) => format!("not run: {e}"),
    }
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok();
    let python = std::env::var("PEER_PYTHON").ok();
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../benches/peers/owl_rl_peers.py"
    );
    let peer_timeout: u64 = std::env::var("PEER_TIMEOUT_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(900);
    let (count, depth, chain_len, reps) = if quick {
        (50, 20, 200, 5)
    } else {
        (500, 20, 1000, 21)
    };
    let dir = tempfile::tempdir().unwrap();
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "# DyKnow reasoning benchmark: (a) {} CUs in {count} pipelines of depth {depth} with fan-in; (b) a chain of {chain_len} CUs\n",
        count * depth
    );

    let env_a = pipelines(count, depth, false);
    let env_a_direct = pipelines(count, depth, true);
    let env_b = chain(chain_len);

    // --- Full materialisation, reasoner alone, and peers ---------------------------------
    let _ = writeln!(out, "## Full materialisation (in memory)\n");
    let _ = writeln!(
        out,
        "| environment | explicit triples | dyknow | facts | owlrl | reasonable | owlrl / dyknow | reasonable / dyknow |"
    );
    let _ = writeln!(out, "| --- | --- | --- | --- | --- | --- | --- | --- |");
    for (label, env, peers) in [
        (
            "(a) subscriptions (dependsOn via the property chain)",
            &env_a,
            true,
        ),
        (
            "(a') the same pipelines as direct dependsOn edges (transitivity only: the closure every peer computes)",
            &env_a_direct,
            true,
        ),
        ("(b) chain of subscriptions", &env_b, false),
    ] {
        let explicit: usize = env.iter().map(|(_, t)| t.len()).sum();
        let runs: Vec<(Duration, usize)> = (0..3).map(|_| ours_in_memory(env)).collect();
        let facts = runs[0].1;
        let ours = median(runs.into_iter().map(|r| r.0).collect());
        let (mut o, mut r) = ("not run".to_owned(), "not run".to_owned());
        let (mut ro, mut rr) = ("".to_owned(), "".to_owned());
        if peers && let Some(py) = &python {
            let file = dir.path().join("env.ttl"); // N-Triples is Turtle; reasonable reads .ttl only
            write_ntriples(&file, env);
            o = peer(py, script, "owlrl", &file, peer_timeout);
            r = peer(py, script, "reasonable", &file, peer_timeout);
            let ratio = |s: &str| {
                s.split(' ')
                    .next()
                    .and_then(|x| x.parse::<f64>().ok())
                    .map(|p| format!("{:.1}×", p / (ours.as_secs_f64() * 1e3)))
                    .unwrap_or_default()
            };
            ro = ratio(&o);
            rr = ratio(&r);
        }
        let _ = writeln!(
            out,
            "| {label} | {explicit} | {} | {facts} | {o} | {r} | {ro} | {rr} |",
            ms(ours)
        );
        let _ = out.flush();
    }
    let _ = writeln!(out, "\npeak RSS so far: {:.0} MB\n", peak_rss_mb());

    // --- On the on-disk store ---------------------------------------------------------------
    let _ = writeln!(out, "## On the on-disk store (RocksDB)\n");
    let _ = writeln!(
        out,
        "| environment | full materialisation (one write of every CU) | add one CU with its subscription (median) | remove one CU from the middle (median) |"
    );
    let _ = writeln!(out, "| --- | --- | --- | --- |");
    for (label, env, middle, runs) in [
        (
            "(a)",
            &env_a,
            (0..reps)
                .map(|k| format!("p{}-cu{}", k % count, depth / 2))
                .collect::<Vec<_>>(),
            reps,
        ),
        ("(b)", &env_b, vec![format!("c{}", chain_len / 2); 5], 5),
    ] {
        let kb = KnowledgeBase::open(dir.path().join(format!("store-{label}"))).unwrap();
        let all = parts(env);
        let start = Instant::now();
        kb.set_environment(&all).unwrap();
        let full = start.elapsed();
        // Add: a new CU subscribing to the last CU of a pipeline (of the chain).
        let mut adds = Vec::new();
        for k in 0..runs {
            let name = format!("new{k}");
            let up = if label == "(a)" {
                format!("p{}-cu{}", k % count, depth - 1)
            } else {
                format!("c{}", chain_len - 1)
            };
            let part = vec![(cu_part(&name), cu(&name, &[up], false))];
            let start = Instant::now();
            kb.set_environment(&part).unwrap();
            adds.push(start.elapsed());
            kb.set_environment(&[(cu_part(&name), Vec::new())]).unwrap();
        }
        // Remove a CU from the middle (and restore it, untimed).
        let mut removes = Vec::new();
        for name in middle.iter().take(runs) {
            let (_, triples) = env.iter().find(|(n, _)| n == name).unwrap().clone();
            let start = Instant::now();
            kb.set_environment(&[(cu_part(name), Vec::new())]).unwrap();
            removes.push(start.elapsed());
            kb.set_environment(&[(cu_part(name), triples)]).unwrap();
        }
        let _ = writeln!(
            out,
            "| {label} | {} | {} | {} |",
            ms(full),
            ms(median(adds)),
            ms(median(removes))
        );
        let _ = out.flush();
    }
    let _ = writeln!(
        out,
        "\npeak RSS of the benchmark process: {:.0} MB\n",
        peak_rss_mb()
    );

    // --- Where the removal time goes --------------------------------------------------------
    let _ = writeln!(
        out,
        "## Where the removal time goes
"
    );
    let _ = writeln!(
        out,
        "| environment | inferred triples removed | reasoner alone (in memory, median) | Oxigraph alone: the same write on disk (median) |"
    );
    let _ = writeln!(out, "| --- | --- | --- | --- |");
    for (label, env, middle) in [
        ("(a)", &env_a, format!("p0-cu{}", depth / 2)),
        ("(b)", &env_b, format!("c{}", chain_len / 2)),
    ] {
        let (reasoner_time, removed, store_time) = removal_breakdown(env, &middle, 5, dir.path());
        let _ = writeln!(
            out,
            "| {label} | {removed} | {} | {} |",
            ms(reasoner_time),
            ms(store_time)
        );
        let _ = out.flush();
    }
}

/// Removing CU `name` of `env`: the reasoner's own update (in memory), and Oxigraph applying
/// the write that update needs (the CU graph and the inferred triples that vanish) on a fresh
/// on-disk store holding the same quads, as one transaction. Medians over `runs`, each undone
/// untimed.
fn removal_breakdown(
    env: &[(String, Vec<Triple>)],
    name: &str,
    runs: usize,
    dir: &std::path::Path,
) -> (Duration, usize, Duration) {
    use dyknow_store::INFERRED_GRAPH;
    use dyknow_store::oxigraph::model::{GraphName, Quad};
    use dyknow_store::oxigraph::store::Store;

    let tbox = TBox::from_triples(&builtin_ontology_triples()).unwrap();
    let mut reasoner = Reasoner::new(tbox);
    reasoner.set_graphs(env);
    let mut times = Vec::new();
    let mut inferred_removed = Vec::new();
    for _ in 0..runs {
        let start = Instant::now();
        let (update, previous) = reasoner.set_graphs(&[(name.to_owned(), Vec::new())]);
        times.push(start.elapsed());
        reasoner.set_graphs(&previous);
        inferred_removed = update.inferred_removed;
    }

    let graph = |g: &str| GraphName::from(NamedNode::new_unchecked(g));
    let inferred = graph(INFERRED_GRAPH);
    let cu_graph = GraphName::from(cu_part(name).graph());
    let store = Store::open(dir.join(format!("oxigraph-{name}"))).unwrap();
    let mut loader = store.bulk_loader();
    loader
        .load_quads(
            env.iter()
                .flat_map(|(n, ts)| {
                    let g = GraphName::from(cu_part(n).graph());
                    ts.iter().map(move |t| t.clone().in_graph(g.clone()))
                })
                .chain(
                    reasoner
                        .inferred()
                        .into_iter()
                        .map(|t| t.in_graph(inferred.clone())),
                ),
        )
        .unwrap();
    loader.commit().unwrap();
    let cu: Vec<Quad> = env
        .iter()
        .find(|(n, _)| n == name)
        .unwrap()
        .1
        .iter()
        .map(|t| t.clone().in_graph(cu_graph.clone()))
        .collect();
    let gone: Vec<Quad> = inferred_removed
        .iter()
        .map(|t| t.clone().in_graph(inferred.clone()))
        .collect();
    let mut store_times = Vec::new();
    for _ in 0..runs {
        let start = Instant::now();
        let mut transaction = store.start_transaction().unwrap();
        for q in cu.iter().chain(&gone) {
            transaction.remove(q);
        }
        transaction.commit().unwrap();
        store_times.push(start.elapsed());
        store.extend(cu.iter().chain(&gone).cloned()).unwrap();
    }
    (median(times), gone.len(), median(store_times))
}
