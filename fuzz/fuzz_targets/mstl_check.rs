//! Fuzz target: `dyknow check`'s pipeline, the trace reader and progression together. The first
//! line of the input is a formula, the rest a trace (JSON lines). Invariants: no panic, no
//! stack overflow; when the trace is accepted, the formula gets exactly one verdict line.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let (formula, trace) = text.split_once('\n').unwrap_or((text, ""));
    let Ok(formula) = dyknow_mstl::parse(formula) else {
        return;
    };
    let mut out = Vec::new();
    let header = dyknow_mstl::trace::Header {
        domains: [("D".to_owned(), vec!["a".to_owned(), "b".to_owned()])].into(),
        ..Default::default()
    };
    if let Ok(verdicts) = dyknow_mstl::trace::check(
        std::slice::from_ref(&formula),
        trace.as_bytes(),
        header,
        &mut out,
    ) {
        assert_eq!(verdicts.len(), 1, "{formula}: {verdicts:?}");
        assert_eq!(String::from_utf8(out).unwrap().lines().count(), 1);
    }
});
