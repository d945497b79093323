//! Without the counting allocator nothing is counted and no budget is passed.

use dyknow_meter::{Budget, held, installed, over_budget};

#[test]
fn nothing_is_counted_and_no_budget_is_passed() {
    assert!(!installed());
    let budget = Budget::start(16);
    let big = std::hint::black_box(vec![0u8; 1 << 20]);
    assert_eq!(held(), 0);
    assert!(!budget.exceeded());
    assert!(!over_budget());
    drop(big);
}
