//! Spec ingestion: arbitrary bytes as a Turtle, N-Triples or JSON-LD transformation or target
//! spec.
//!
//! Invariants: nothing panics; a rejected document leaves the knowledge base unchanged; an
//! accepted spec, printed from the store as N-Triples and posted again, parses back to the same
//! spec (parse → print → reparse). The knowledge bases are built once and brought back to their
//! initial state after every input.
#![no_main]

use std::sync::OnceLock;

use dyknow_store::oxigraph::io::RdfFormat;
use dyknow_store::spec::SpecKind;
use dyknow_store::{InputFormat, KnowledgeBase, graphs::spec_graph, serialize};
use libfuzzer_sys::fuzz_target;

struct State {
    kb: KnowledgeBase,
    again: KnowledgeBase,
    baseline: usize,
}

fn state() -> &'static State {
    static STATE: OnceLock<State> = OnceLock::new();
    STATE.get_or_init(|| {
        let kb = KnowledgeBase::in_memory().expect("in-memory store");
        let baseline = kb.store().len().expect("len");
        let again = KnowledgeBase::in_memory().expect("in-memory store");
        State {
            kb,
            again,
            baseline,
        }
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&selector, body)) = data.split_first() else {
        return;
    };
    let kind = if selector & 1 == 0 {
        SpecKind::Transformation
    } else {
        SpecKind::Target
    };
    let format = match selector >> 1 & 3 {
        0 | 1 => InputFormat::Turtle,
        2 => InputFormat::NTriples,
        _ => InputFormat::JsonLd,
    };
    let State {
        kb,
        again,
        baseline,
    } = state();
    match kb.post_specs(body, format, kind) {
        Err(_) => assert_eq!(
            kb.store().len().expect("len"),
            *baseline,
            "a rejected post wrote"
        ),
        Ok(report) => {
            for label in &report.labels {
                let spec = kb
                    .spec(kind, label)
                    .expect("read")
                    .expect("posted spec is there");
                let graph = kb
                    .graph_triples(spec_graph(kind, label).as_ref())
                    .expect("read");
                let printed = serialize(&graph, RdfFormat::NTriples).expect("print");
                again
                    .post_specs(&printed, InputFormat::NTriples, kind)
                    .expect("a stored spec posts again");
                assert_eq!(
                    again.spec(kind, label).expect("read"),
                    Some(spec),
                    "reparse differs"
                );
                again.remove_spec(kind, label).expect("remove");
            }
            for label in &report.labels {
                kb.remove_spec(kind, label).expect("remove");
            }
            assert_eq!(
                kb.store().len().expect("len"),
                *baseline,
                "removal left triples"
            );
        }
    }
});
