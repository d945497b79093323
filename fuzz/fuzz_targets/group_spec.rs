//! Fuzz target: a formula group's definition as `POST /groups` reads it (contract
//! `groups.md`): the JSON body, then what `Groups::create` does before it touches the
//! knowledge base: validation, parsing and grounding of every formula, the groundings no
//! formula uses, progression of the formulas, and the target (label, channel) of every
//! symbol. Invariants: no panic, no stack overflow; a rejected definition is an error value
//! (a syntax error names its formula); a definition that reads serialises and reads back as
//! the same definition; a formula that grounds is accepted by progression (the service would
//! otherwise answer 500).
#![no_main]

use std::collections::BTreeSet;

use dyknow_group::spec::{self, SpecError};
use dyknow_group::{GroupSpec, Progression, TraceHeader};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(group) = serde_json::from_slice::<GroupSpec>(data) else {
        return;
    };
    let text = serde_json::to_string(&group).expect("a definition serialises");
    let back: GroupSpec = serde_json::from_str(&text).expect("a serialised definition reads");
    assert_eq!(back, group, "{text}");
    if spec::validate(&group).is_err() {
        return;
    }
    let mut grounded = Vec::new();
    for (i, f) in group.formulas.iter().enumerate() {
        match spec::ground(i, f, &group.domains) {
            Ok(g) => grounded.push(g),
            Err(SpecError::Syntax { index, .. } | SpecError::Grounding { index, .. }) => {
                assert_eq!(index, i);
                return;
            }
            Err(SpecError::Invalid(m)) => panic!("grounding gave Invalid: {m}"),
        }
    }
    let symbols: BTreeSet<_> = grounded
        .iter()
        .flat_map(|g| g.symbols.iter().cloned())
        .collect();
    let keys: BTreeSet<String> = symbols.iter().map(|s| s.key()).collect();
    let _ = spec::unused_groundings(&group.grounding, &keys);
    let mut progression = Progression::new(TraceHeader {
        domains: group.domains.clone(),
        landmarks: group.landmarks.clone(),
        static_regions: group.static_regions.clone(),
    });
    for g in &grounded {
        if let Err(e) = progression.add(&g.formula) {
            panic!("{} grounds but progression refuses it: {e}", g.formula);
        }
    }
    assert!(progression.finish().len() <= grounded.len());
    for symbol in &symbols {
        for offered in [false, true] {
            let tag = spec::target_tag(symbol, &group.grounding, &|_| offered);
            let channel = tag.channel();
            assert!(channel.starts_with("/dyknow/symbols/"), "{channel}");
            let _ = tag.label();
        }
    }
});
