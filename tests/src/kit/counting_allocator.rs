//! A global allocator that counts the allocations of the thread under measurement, for
//! the zero-allocation tests (the dsp hot path, the chatter monitor). It wraps the
//! system allocator; only the measuring thread is counted, since the test harness
//! allocates on its own threads.
//!
//! A test binary installs it and measures a closure:
//!
//! ```ignore
//! use millgate_tests::kit::counting_allocator::{allocations_during, CountingAllocator};
//!
//! #[global_allocator]
//! static GLOBAL: CountingAllocator = CountingAllocator;
//!
//! let (sum, allocations) = allocations_during(|| (0..10u64).sum::<u64>());
//! assert_eq!(allocations, 0);
//! ```
//!
//! Without it installed as the global allocator every count is 0, so each test also
//! checks that an allocation made while measuring is seen
//! ([`allocations_during`] of a `Vec::with_capacity`).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    /// True while this thread is under measurement (const-initialised: no allocation).
    static MEASURING: Cell<bool> = const { Cell::new(false) };
    /// Allocations made by this thread while measuring.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

/// The system allocator, counting `alloc` and `realloc` calls of a measuring thread.
#[derive(Debug, Clone, Copy, Default)]
pub struct CountingAllocator;

fn count() {
    if MEASURING.try_with(Cell::get).unwrap_or(false) {
        let _ = ALLOCATIONS.try_with(|a| a.set(a.get() + 1));
    }
}

// The one `unsafe` of the tests: a global allocator must implement an unsafe trait.
// SAFETY: forwards every call unchanged to `System`, only counting them.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by `System` with `layout`.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Runs `work` on this thread and returns its result with the number of allocations
/// it made (0 unless [`CountingAllocator`] is the global allocator).
pub fn allocations_during<T>(work: impl FnOnce() -> T) -> (T, usize) {
    let before = ALLOCATIONS.with(Cell::get);
    MEASURING.with(|m| m.set(true));
    let result = work();
    MEASURING.with(|m| m.set(false));
    (result, ALLOCATIONS.with(Cell::get) - before)
}
