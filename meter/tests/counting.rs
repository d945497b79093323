//! The counting allocator installed, as `dyknow serve` installs it.

use dyknow_meter::{Budget, Counting, held, installed, over_budget};
use proptest::prelude::*;

#[global_allocator]
static ALLOCATOR: Counting = Counting;

#[test]
fn the_allocator_is_seen_as_installed() {
    assert!(installed());
}

#[test]
fn a_budget_is_exceeded_once_its_thread_holds_more_and_no_longer_once_it_frees_it() {
    let budget = Budget::start(1 << 20);
    assert!(!budget.exceeded());
    assert!(!over_budget());
    let mut kept: Vec<Box<[u8; 4096]>> = Vec::new();
    while !over_budget() {
        kept.push(Box::new([1; 4096]));
        assert!(
            kept.len() < 1 << 12,
            "never over budget: nothing is counted"
        );
    }
    assert!(budget.exceeded());
    // Passed by less than one box and the vector's last doubling.
    assert!(budget.held() > 1 << 20);
    assert!(budget.held() < (1 << 20) + 4096 + 8 * kept.len() as isize + 64 * 1024);
    let peak = budget.peak();
    drop(kept);
    assert!(!budget.exceeded(), "held {} after freeing", budget.held());
    assert!(budget.held() < 64 * 1024);
    assert_eq!(budget.peak(), peak, "the peak stays");
}

thread_local! {
    static HOOKED: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

fn hook() {
    HOOKED.with(|h| h.set(h.get() + 1));
}

#[test]
fn the_hook_is_called_once_on_the_thread_that_passes_the_ceiling() {
    let budget = Budget::start_with(1 << 16, hook);
    let small = std::hint::black_box(vec![0u8; 1 << 10]);
    assert_eq!(HOOKED.with(std::cell::Cell::get), 0);
    assert!(!budget.tripped());
    // Another thread passing as much is not this budget's concern.
    std::thread::spawn(|| std::hint::black_box(vec![0u8; 1 << 20]).len())
        .join()
        .unwrap();
    assert_eq!(HOOKED.with(std::cell::Cell::get), 0);
    let big = std::hint::black_box(vec![0u8; 1 << 17]);
    assert_eq!(HOOKED.with(std::cell::Cell::get), 1);
    let bigger = std::hint::black_box(vec![0u8; 1 << 18]);
    assert_eq!(HOOKED.with(std::cell::Cell::get), 1, "once");
    drop((big, bigger));
    assert!(!budget.exceeded());
    assert!(budget.tripped(), "tripped stays");
    drop(small);
    drop(budget);
    // A new budget starts untripped.
    let again = Budget::start_with(1 << 16, hook);
    assert!(!again.tripped());
}

#[test]
fn budgets_nest_and_the_innermost_is_checked() {
    let outer = Budget::start(1 << 30);
    let kept = vec![0u8; 1 << 16];
    {
        let inner = Budget::start(1 << 10);
        let more = vec![1u8; 1 << 12];
        assert!(inner.exceeded());
        assert!(over_budget());
        drop(more);
    }
    assert!(!over_budget(), "the outer budget is back");
    assert!(outer.held() >= 1 << 16);
    assert!(outer.peak() >= (1 << 16) + (1 << 12));
    drop(kept);
}

#[test]
fn an_outer_budget_passed_while_an_inner_one_lived_trips_when_it_ends() {
    let outer = Budget::start_with(1 << 16, hook);
    {
        let _inner = Budget::start(1 << 30);
        let big = std::hint::black_box(vec![0u8; 1 << 18]);
        drop(big);
        assert_eq!(
            HOOKED.with(std::cell::Cell::get),
            0,
            "the inner budget is checked"
        );
    }
    assert!(outer.tripped());
    assert_eq!(HOOKED.with(std::cell::Cell::get), 1);
    assert!(!outer.exceeded(), "freed meanwhile");
}

#[test]
fn each_thread_counts_its_own() {
    let budget = Budget::start(1 << 16);
    let before = held();
    let other = std::thread::spawn(|| {
        let big = std::hint::black_box(vec![0u8; 1 << 22]);
        (held(), big.len())
    })
    .join()
    .expect("the thread ends");
    // Net of what it freed for the spawning thread (its closure, its packet).
    assert!(
        other.0 > (1 << 22) - 4096,
        "the other thread held {}",
        other.0
    );
    assert!(
        held() - before < 1 << 16,
        "another thread's memory is not this one's"
    );
    assert!(!budget.exceeded());
}

#[test]
fn without_a_budget_nothing_is_over() {
    let big = std::hint::black_box(vec![0u8; 1 << 24]);
    assert!(!over_budget());
    drop(big);
}

/// An allocation the model keeps: its size.
#[derive(Debug, Clone)]
enum Step {
    Allocate(usize),
    Grow(usize, usize),
    Free(usize),
}

fn steps() -> impl Strategy<Value = Vec<Step>> {
    prop::collection::vec(
        prop_oneof![
            (1usize..100_000).prop_map(Step::Allocate),
            (any::<usize>(), 1usize..100_000).prop_map(|(i, n)| Step::Grow(i, n)),
            any::<usize>().prop_map(Step::Free),
        ],
        1..60,
    )
}

proptest! {
    /// Differential: what a budget says its thread holds is the sum of the sizes the thread
    /// holds, as a model that keeps the sizes counts it.
    #[test]
    fn held_is_the_sum_of_the_live_sizes(steps in steps()) {
        let mut live: Vec<Vec<u8>> = Vec::new();
        let mut model: Vec<usize> = Vec::new();
        // Room for the bookkeeping vectors first, so that only the allocations count.
        live.reserve(steps.len());
        model.reserve(steps.len());
        let budget = Budget::start(usize::MAX);
        for step in steps {
            match step {
                Step::Allocate(n) => {
                    live.push(Vec::with_capacity(n));
                    model.push(n);
                }
                Step::Grow(i, n) if !live.is_empty() => {
                    let i = i % live.len();
                    let target = model[i] + n;
                    live[i].reserve_exact(target);
                    model[i] = live[i].capacity();
                }
                Step::Free(i) if !live.is_empty() => {
                    let i = i % live.len();
                    live.swap_remove(i);
                    model.swap_remove(i);
                }
                _ => {}
            }
            prop_assert_eq!(budget.held(), model.iter().sum::<usize>() as isize);
        }
        prop_assert!(budget.peak() >= budget.held());
    }
}

#[test]
fn a_reservation_past_the_ceiling_trips_the_budget_without_allocating() {
    // No budget: anything may be reserved.
    assert!(dyknow_meter::reserve(usize::MAX));
    let budget = Budget::start_with(1 << 16, hook);
    let before = HOOKED.with(std::cell::Cell::get);
    assert!(dyknow_meter::reserve(1 << 10));
    assert!(!budget.tripped());
    assert!(!dyknow_meter::reserve(1 << 17));
    assert!(budget.tripped(), "a refused reservation trips the budget");
    assert_eq!(
        HOOKED.with(std::cell::Cell::get),
        before + 1,
        "and calls its hook"
    );
    assert!(!dyknow_meter::reserve(1 << 17));
    assert_eq!(HOOKED.with(std::cell::Cell::get), before + 1, "once");
    assert!(budget.held() < 1 << 12, "nothing was allocated");
}
