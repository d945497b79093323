//! What counting costs (`dyknow_meter::Counting`, the `dyknow` binary's allocator):
//! `cargo bench --workspace --bench counting`.
//!
//! The knowledge base's own work, allocation-heavy as the service does it: opening an
//! in-memory knowledge base (the ontologies parsed and materialised), 200 specs posted one by
//! one, a document of 2,000 specs posted at once, and SPARQL queries answered with a memory
//! budget (as `dyknow serve` answers them). Each runs with the global allocator counting and
//! with it forwarding straight to the system allocator, switched at run time in this one
//! process, interleaved, median of `REPS` runs (default 15). Both sides pay the switch (one
//! relaxed atomic load per call); the ratio is the cost of counting.
#![expect(clippy::unwrap_used, reason = "a benchmark binary")]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use dyknow_meter::Counting;
use dyknow_store::oxigraph::sparql::results::QueryResultsFormat;
use dyknow_store::spec::SpecKind;
use dyknow_store::{InputFormat, KnowledgeBase, ParsedQuery, ResultFormat};

/// Whether [`Switch`] counts.
static COUNTING: AtomicBool = AtomicBool::new(true);

/// [`Counting`] or [`System`], as [`COUNTING`] says. Memory allocated by one and freed by the
/// other is fine: `Counting` allocates with `System`.
struct Switch;

// SAFETY: every call forwards its arguments unchanged to `Counting` or `System`, both of which
// uphold `GlobalAlloc`'s contract and allocate from the same system allocator.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Switch {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        unsafe {
            if COUNTING.load(Ordering::Relaxed) {
                Counting.alloc(layout)
            } else {
                System.alloc(layout)
            }
        }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        unsafe {
            if COUNTING.load(Ordering::Relaxed) {
                Counting.alloc_zeroed(layout)
            } else {
                System.alloc_zeroed(layout)
            }
        }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded with the caller's guarantees; both free with `System`.
        unsafe {
            if COUNTING.load(Ordering::Relaxed) {
                Counting.dealloc(ptr, layout);
            } else {
                System.dealloc(ptr, layout);
            }
        }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees; both reallocate with `System`.
        unsafe {
            if COUNTING.load(Ordering::Relaxed) {
                Counting.realloc(ptr, layout, new_size)
            } else {
                System.realloc(ptr, layout, new_size)
            }
        }
    }
}

#[global_allocator]
static ALLOCATOR: Switch = Switch;

const P: &str = "PREFIX dyknow: <http://www.dyknow.eu/ontology/dyknow#> \
                 PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#> ";

fn spec(i: usize) -> String {
    format!(
        "[] a dyknow:Transformation ; rdfs:label \"tf-{i:05}\" ;\n\
         <http://www.dyknow.eu/ontology/dyknow-ros#hasParam> [ dyknow:hasName \"p\" ; dyknow:hasValue \"1\" ] ;\n\
         dyknow:hasInPort [ dyknow:hasName \"in\" ; dyknow:hasTag [ dyknow:hasValue \"In{}\" ] ] ;\n\
         dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"Out{i}\" ] ] .\n",
        i % 50
    )
}

fn document(specs: std::ops::Range<usize>) -> String {
    let mut doc = String::from(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n",
    );
    for i in specs {
        doc.push_str(&spec(i));
    }
    doc
}

fn post(kb: &KnowledgeBase, doc: &str) {
    kb.post_specs(
        doc.as_bytes(),
        InputFormat::Turtle,
        SpecKind::Transformation,
    )
    .unwrap();
}

fn query(kb: &KnowledgeBase, query: &str) -> usize {
    let parsed = ParsedQuery::parse(query)
        .unwrap()
        .with_memory_limit(1 << 30);
    kb.run_query(
        parsed,
        ResultFormat::Results(QueryResultsFormat::Json),
        Duration::from_secs(600),
    )
    .unwrap()
    .body
    .len()
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn main() {
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(15);
    let singles: Vec<String> = (0..200).map(|i| document(i..i + 1)).collect();
    let thousands = document(0..2_000);
    let queried = KnowledgeBase::in_memory().unwrap();
    post(&queried, &thousands);
    let join = format!(
        "{P} SELECT ?label ?tag WHERE {{ ?t rdfs:label ?label ; dyknow:hasInPort ?p . \
         ?p dyknow:hasTag ?g . ?g dyknow:hasValue ?tag }}"
    );
    let sorted = format!(
        "{P} SELECT ?label ?port ?tag WHERE {{ ?t a dyknow:Transformation ; rdfs:label ?label ; \
         (dyknow:hasInPort|dyknow:hasOutPort) ?p . ?p dyknow:hasName ?port ; \
         dyknow:hasTag/dyknow:hasValue ?tag }} ORDER BY ?tag ?label"
    );
    type Work<'a> = Box<dyn Fn() + 'a>;
    let work: [(&str, Work<'_>); 5] = [
        (
            "open an in-memory knowledge base",
            Box::new(|| drop(KnowledgeBase::in_memory().unwrap())),
        ),
        (
            "200 specs posted one by one",
            Box::new(|| {
                let kb = KnowledgeBase::in_memory().unwrap();
                for doc in &singles {
                    post(&kb, doc);
                }
            }),
        ),
        (
            "2,000 specs posted in one document",
            Box::new(|| post(&KnowledgeBase::in_memory().unwrap(), &thousands)),
        ),
        (
            "SPARQL: a 4-pattern join, 2,000 rows (x20)",
            Box::new(|| {
                for _ in 0..20 {
                    std::hint::black_box(query(&queried, &join));
                }
            }),
        ),
        (
            "SPARQL: a sorted join with paths, 4,000 rows (x5)",
            Box::new(|| {
                for _ in 0..5 {
                    std::hint::black_box(query(&queried, &sorted));
                }
            }),
        ),
    ];
    println!("# The counting allocator: median of {reps} runs, interleaved, in one process\n");
    println!("| work | counting (the service) | system allocator | ratio |");
    println!("| --- | --- | --- | --- |");
    for (name, run) in &work {
        let (mut on, mut off) = (Vec::new(), Vec::new());
        for i in 0..reps {
            let mut one = |counting: bool| {
                COUNTING.store(counting, Ordering::SeqCst);
                let started = Instant::now();
                run();
                let took = started.elapsed();
                if counting {
                    on.push(took);
                } else {
                    off.push(took);
                }
            };
            if i % 2 == 0 {
                one(true);
                one(false);
            } else {
                one(false);
                one(true);
            }
        }
        COUNTING.store(true, Ordering::SeqCst);
        let (on, off) = (median(on), median(off));
        println!(
            "| {name} | {:.2} ms | {:.2} ms | {:.3} |",
            on.as_secs_f64() * 1e3,
            off.as_secs_f64() * 1e3,
            on.as_secs_f64() / off.as_secs_f64()
        );
    }
}
