//! Fuzz target: the reader of GQR's CSP files (`dyknow-rcc8`, `gqr::parse`, what
//! `dyknow rcc8` reads). Invariants: no panic, no unbounded allocation (at most
//! `MAX_VARIABLES` variables an instance); every instance that parses is written by
//! `gqr::write` as text that parses back to the same instance; the algebraic closure of an
//! instance that parses does not panic either.
#![no_main]

use dyknow_rcc8::gqr;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(networks) = gqr::parse(text) else {
        return;
    };
    for network in networks {
        assert!(network.len() <= gqr::MAX_VARIABLES);
        let mut printed = String::new();
        gqr::write(&network, &mut printed).expect("writing to a String cannot fail");
        assert_eq!(
            gqr::parse(&printed).as_ref(),
            Ok(&vec![network.clone()]),
            "{text:?} printed as {printed:?}"
        );
        // Small instances only: the closure is cubic.
        if network.len() <= 64 {
            let mut closed = network;
            let _ = closed.algebraic_closure();
        }
    }
});
