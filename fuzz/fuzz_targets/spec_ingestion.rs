//! Spec ingestion: arbitrary bytes as a Turtle transformation or target spec.
//!
//! Invariants: nothing panics; a rejected document leaves the knowledge base unchanged; an
//! accepted spec, printed from the store as N-Triples and posted again, parses back to the same
//! spec (parse → print → reparse).
#![no_main]

use dyknow_store::spec::SpecKind;
use dyknow_store::{InputFormat, KnowledgeBase, graphs::spec_graph, serialize};
use dyknow_store::oxigraph::io::RdfFormat;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&selector, body)) = data.split_first() else {
        return;
    };
    let kind = if selector & 1 == 0 { SpecKind::Transformation } else { SpecKind::Target };
    let format = match selector >> 1 & 3 {
        0 | 1 => InputFormat::Turtle,
        2 => InputFormat::NTriples,
        _ => InputFormat::JsonLd,
    };
    let kb = KnowledgeBase::in_memory().expect("in-memory store");
    let before = kb.model_triples(true).expect("read");
    match kb.post_specs(body, format, kind) {
        Err(_) => assert_eq!(kb.model_triples(true).expect("read"), before, "a rejected post wrote"),
        Ok(report) => {
            for label in &report.labels {
                let spec = kb.spec(kind, label).expect("read").expect("posted spec is there");
                let graph = kb.graph_triples(spec_graph(kind, label).as_ref()).expect("read");
                let printed = serialize(&graph, RdfFormat::NTriples).expect("print");
                let again = KnowledgeBase::in_memory().expect("in-memory store");
                again
                    .post_specs(&printed, InputFormat::NTriples, kind)
                    .expect("a stored spec posts again");
                assert_eq!(again.spec(kind, label).expect("read"), Some(spec), "reparse differs");
            }
        }
    }
});
