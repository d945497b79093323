//! In-process breakdown of batch ingestion (the `docs/benchmarks.md` "Where the batch time goes"
//! table): `cargo build --release --locked --workspace --examples`, then
//! `$CARGO_TARGET_DIR/release/examples/ingest_breakdown [specs]` (`cargo run` takes no
//! `--workspace`, and `-p dyknow-store --features rocksdb` would build RocksDB a second time).
#![expect(clippy::unwrap_used, reason = "a measurement tool")]

use dyknow_store::oxigraph::model::Quad;
use dyknow_store::oxigraph::store::Store;
use dyknow_store::spec::{SpecClasses, SpecKind, extract_specs};
use dyknow_store::{InputFormat, KnowledgeBase, parse_triples};
use std::time::Instant;

#[path = "../../benches/bench_specs.rs"]
mod bench_specs;
use bench_specs::{PREFIXES, spec};

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .map_or(10_000, |s| s.parse().unwrap());
    let mut body = String::from(PREFIXES);
    for i in 0..n {
        body.push_str(&spec(i));
    }
    println!("{n} specs, {} bytes", body.len());
    for round in 0..3 {
        let t = Instant::now();
        let triples = parse_triples(body.as_bytes(), InputFormat::Turtle).unwrap();
        let parse = t.elapsed();
        let t = Instant::now();
        let doc = extract_specs(
            &triples,
            &SpecClasses::default(),
            Some(SpecKind::Transformation),
        )
        .unwrap();
        let extract = t.elapsed();
        let quads: Vec<Quad> = doc
            .specs
            .iter()
            .flat_map(|s| {
                s.triples
                    .iter()
                    .map(|t| t.as_ref().in_graph(s.graph.as_ref()).into_owned())
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let t = Instant::now();
        let mut loader = store.bulk_loader();
        loader.load_quads(quads.iter().cloned()).unwrap();
        loader.commit().unwrap();
        let bulk = t.elapsed();
        drop(store);
        let mem = Store::new().unwrap();
        let t = Instant::now();
        mem.extend(quads.iter().cloned()).unwrap();
        let mem_extend = t.elapsed();
        let dir2 = tempfile::tempdir().unwrap();
        let kb = KnowledgeBase::open(dir2.path()).unwrap();
        let t = Instant::now();
        kb.post_specs(
            body.as_bytes(),
            InputFormat::Turtle,
            SpecKind::Transformation,
        )
        .unwrap();
        let post = t.elapsed();
        println!(
            "round {round}: parse {parse:?} ({} triples), extract {extract:?} ({} quads), \
             raw bulk load {bulk:?}, raw in-memory extend {mem_extend:?}, whole on-disk post {post:?} ({:.0} specs/s)",
            triples.len(),
            quads.len(),
            n as f64 / post.as_secs_f64()
        );
    }
}
