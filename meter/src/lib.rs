//! Counts the heap bytes each thread holds, so that one piece of work can be bounded in memory.
//!
//! [`Counting`] is a global allocator that forwards every call to the system allocator and adds
//! the size of each allocation to a counter of the calling thread (and takes the size of each
//! deallocation off it). A [`Budget`] started on a thread sets a ceiling on what the thread may
//! hold more than when it started; [`over_budget`] tells, from anywhere on that thread (a
//! SPARQL custom function, a serialisation loop), whether the ceiling is passed.
//!
//! The count is net and per thread: memory freed on another thread than the one that allocated
//! it lowers the freeing thread's count. A budget measures against its start, so counts that
//! drift that way do not matter to it; the work it bounds must run on its thread (an iterator
//! pulled there, as oxigraph's evaluation is). Without [`Counting`] installed as the global
//! allocator nothing is counted and no budget is ever passed: [`installed`] tells. A budget
//! can be given a hook ([`Budget::start_with`]) that the allocator calls once, from the
//! allocation that passes the ceiling, so that the work is stopped where it next checks for
//! cancellation rather than where it next asks [`over_budget`].
//!
//! The cost is one thread-local addition per deallocation, and per allocation an addition and
//! two comparisons (the peak, the ceiling) (`docs/benchmarks.md`, "Query memory"). The counter
//! lives in a native thread-local (Linux and the other targets with `#[thread_local]`; where
//! std emulates thread-locals with allocations, this crate would recurse into itself).

#![deny(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::marker::PhantomData;

/// What the calling thread has counted, and its innermost budget.
struct State {
    /// Bytes this thread has allocated and not freed (net of what it freed for others).
    held: Cell<isize>,
    /// The most `held` has been since the innermost budget started (or the thread began).
    peak: Cell<isize>,
    /// The innermost budget's ceiling on `held`; `isize::MAX` without a budget.
    ceiling: Cell<isize>,
    /// Whether `held` passed `ceiling` since the innermost budget started.
    tripped: Cell<bool>,
    /// Called once, on the allocating thread, when `held` first passes `ceiling`.
    hook: Cell<Option<fn()>>,
}

thread_local! {
    // Const-initialised, and nothing in it needs dropping: reading it never allocates and
    // never fails, on a thread's first access or while it is torn down, as an allocator needs.
    static STATE: State = const {
        State {
            held: Cell::new(0),
            peak: Cell::new(0),
            ceiling: Cell::new(isize::MAX),
            tripped: Cell::new(false),
            hook: Cell::new(None),
        }
    };
}

/// Counts `bytes` (negative: freed) for the calling thread.
#[inline]
fn count(bytes: isize) {
    // `try_with` although it cannot fail: an allocator must not panic.
    let _ = STATE.try_with(|state| {
        let now = state.held.get().wrapping_add(bytes);
        state.held.set(now);
        if bytes > 0 {
            if now > state.peak.get() {
                state.peak.set(now);
            }
            if now > state.ceiling.get()
                && !state.tripped.replace(true)
                && let Some(hook) = state.hook.get()
            {
                hook();
            }
        }
    });
}

/// `size` as a count: sizes of live allocations never exceed `isize::MAX` (`Layout` ensures it).
#[inline]
fn signed(size: usize) -> isize {
    isize::try_from(size).unwrap_or(isize::MAX)
}

/// The system allocator, counting per thread what each thread holds.
///
/// ```ignore
/// #[global_allocator]
/// static ALLOCATOR: dyknow_meter::Counting = dyknow_meter::Counting;
/// ```
#[derive(Debug, Default, Clone, Copy)]
pub struct Counting;

// SAFETY: every method forwards its arguments unchanged to `System`, which upholds
// `GlobalAlloc`'s contract, and returns `System`'s result unchanged; the counting around it
// touches only const-initialised thread-locals without destructors (no allocation, no
// unwinding).
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    #[inline]
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees (a non-zero-sized layout).
        let ptr = unsafe { System.alloc(layout) };
        if !ptr.is_null() {
            count(signed(layout.size()));
        }
        ptr
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as for `alloc`.
        let ptr = unsafe { System.alloc_zeroed(layout) };
        if !ptr.is_null() {
            count(signed(layout.size()));
        }
        ptr
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller guarantees `ptr` was allocated by this allocator, i.e. by
        // `System`, with `layout`.
        unsafe { System.dealloc(ptr, layout) };
        count(-signed(layout.size()));
    }

    #[inline]
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: the caller guarantees `ptr` is `System`'s, allocated with `layout`, and
        // `new_size` valid for `layout`'s alignment.
        let new = unsafe { System.realloc(ptr, layout, new_size) };
        if !new.is_null() {
            count(signed(new_size).wrapping_sub(signed(layout.size())));
        }
        new
    }
}

/// Bytes the calling thread holds, as counted since it began (0 without [`Counting`]).
#[must_use]
pub fn held() -> isize {
    STATE.try_with(|s| s.held.get()).unwrap_or(0)
}

/// Whether [`Counting`] is the global allocator (whether anything is counted).
#[must_use]
pub fn installed() -> bool {
    let before = held();
    let probe = std::hint::black_box(Box::new([0u8; 64]));
    let after = held();
    drop(probe);
    after.wrapping_sub(before) >= 64
}

/// Whether the calling thread holds more than its innermost [`Budget`] allows (false without
/// a budget, or without [`Counting`]).
#[inline]
#[must_use]
pub fn over_budget() -> bool {
    STATE
        .try_with(|s| s.held.get() > s.ceiling.get())
        .unwrap_or(false)
}

/// Whether the calling thread may hold `bytes` more without passing its innermost [`Budget`]
/// (true without a budget; without [`Counting`] nothing is counted as held, so only a
/// reservation larger than the budget's whole limit is refused). When it may not, the budget trips as an
/// allocation passing it would (its hook called, once): for work that can tell what it is
/// about to allocate (a string function that would build a string of gigabytes from a few
/// megabytes) and stop before rather than after.
#[must_use]
pub fn reserve(bytes: usize) -> bool {
    STATE
        .try_with(|state| {
            let ceiling = state.ceiling.get();
            if ceiling == isize::MAX || state.held.get().saturating_add(signed(bytes)) <= ceiling {
                return true;
            }
            if !state.tripped.replace(true)
                && let Some(hook) = state.hook.get()
            {
                hook();
            }
            false
        })
        .unwrap_or(true)
}

/// A ceiling on the bytes the calling thread may hold more than when the budget started, until
/// it is dropped. Budgets nest: the innermost one is checked, and dropping it restores the one
/// around it, which trips then (its hook called) if the thread passed its ceiling meanwhile
/// (while an inner budget lives, an outer one's [`Budget::peak`] counts from the inner one's
/// start). Budgets must end in the reverse order of their start (as scopes do); one that is
/// leaked (`mem::forget`) leaves its ceiling and hook on the thread. A budget belongs to its
/// thread (it is neither `Send` nor `Sync`).
#[derive(Debug)]
pub struct Budget {
    start: isize,
    limit: usize,
    outer: (isize, isize, bool, Option<fn()>),
    _thread_bound: PhantomData<*const ()>,
}

impl Budget {
    /// Starts a budget of `limit` bytes on the calling thread.
    #[must_use]
    pub fn start(limit: usize) -> Self {
        Self::begin(limit, None)
    }

    /// Starts a budget of `limit` bytes on the calling thread that calls `hook` once, on this
    /// thread, from inside the allocation that first passes it: to stop the work it bounds
    /// (e.g. cancel a query, which the work then notices). Being called from inside the
    /// allocator, `hook` must not allocate, free, block or panic: set a flag, and read only
    /// thread-locals that were initialised before the budget started.
    #[must_use]
    pub fn start_with(limit: usize, hook: fn()) -> Self {
        Self::begin(limit, Some(hook))
    }

    fn begin(limit: usize, hook: Option<fn()>) -> Self {
        let start = held();
        let ceiling = start.saturating_add(signed(limit));
        let outer = STATE
            .try_with(|s| {
                (
                    s.ceiling.replace(ceiling),
                    s.peak.replace(start),
                    s.tripped.replace(false),
                    s.hook.replace(hook),
                )
            })
            .unwrap_or((isize::MAX, 0, false, None));
        Self {
            start,
            limit,
            outer,
            _thread_bound: PhantomData,
        }
    }

    /// The bytes allowed.
    #[must_use]
    pub fn limit(&self) -> usize {
        self.limit
    }

    /// The bytes the thread holds more than when the budget started (negative when it holds
    /// less).
    #[must_use]
    pub fn held(&self) -> isize {
        held().wrapping_sub(self.start)
    }

    /// The most [`Budget::held`] has been since the budget started.
    #[must_use]
    pub fn peak(&self) -> isize {
        STATE
            .try_with(|s| s.peak.get())
            .unwrap_or(0)
            .wrapping_sub(self.start)
    }

    /// Whether the thread holds more than the budget allows now.
    #[must_use]
    pub fn exceeded(&self) -> bool {
        self.held() > signed(self.limit)
    }

    /// Whether the thread held more than the budget allows at some time since it started
    /// (and its hook, if it has one, was called).
    #[must_use]
    pub fn tripped(&self) -> bool {
        STATE.try_with(|s| s.tripped.get()).unwrap_or(false)
    }
}

impl Drop for Budget {
    fn drop(&mut self) {
        let (ceiling, peak, tripped, hook) = self.outer;
        let passed = STATE
            .try_with(|s| {
                s.ceiling.set(ceiling);
                s.peak.set(s.peak.get().max(peak));
                s.hook.set(hook);
                // The outer budget was passed while this one lived: it trips now.
                let passed = !tripped && s.peak.get() > ceiling;
                s.tripped.set(tripped || passed);
                passed
            })
            .unwrap_or(false);
        // Outside the allocator here, the hook may do as it likes.
        if passed && let Some(hook) = hook {
            hook();
        }
    }
}
