//! Fuzz target: the MSTL parser. Invariants: no panic, no stack overflow; a formula that
//! parses prints to text that parses back to the same formula.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(formula) = dyknow_mstl::parse(text) {
        let printed = formula.to_string();
        assert_eq!(
            dyknow_mstl::parse(&printed).as_ref(),
            Ok(&formula),
            "{text:?} printed as {printed:?}"
        );
    }
});
