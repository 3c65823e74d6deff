//! What the crates' tests share: a global allocator that counts the allocations of each
//! thread, for the tests that check a control-path call never touches the heap; and
//! [`json_schema::validate`], the check that a recording's data and schemas agree.
//!
//! A test binary installs it, then counts what a closure allocates on the test's own thread
//! (other threads, the test harness's included, do not disturb the count):
//!
//! ```
//! #[global_allocator]
//! static ALLOCATOR: test_support::CountingAllocator = test_support::CountingAllocator;
//!
//! fn main() {
//!     let n = test_support::count_allocations(|| {
//!         drop(std::hint::black_box(Vec::<u64>::with_capacity(4)));
//!     });
//!     assert_eq!(n, 1);
//!     assert_eq!(test_support::count_allocations(|| 1 + 1), 0);
//! }
//! ```
//!
//! Without the `#[global_allocator]` line nothing is counted (every count is 0), so each test
//! file should also check that the counter sees one allocation, as above.

pub mod json_schema;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn note() {
    // `try_with`: the allocator may run while the thread's locals are being torn down.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
}

/// The system allocator, counting every allocation (`alloc`, `alloc_zeroed`, `realloc`; not
/// `dealloc`) of the calling thread. Install it with `#[global_allocator]` in a test binary.
#[derive(Debug, Clone, Copy, Default)]
pub struct CountingAllocator;

// SAFETY: every call is forwarded unchanged to the system allocator; the bookkeeping only
// touches a const-initialised thread-local `Cell<usize>`, which never allocates.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: same contract as ours.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as ours.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: same contract as ours.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        // SAFETY: same contract as ours.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Allocations made so far on this thread (0 unless [`CountingAllocator`] is installed).
pub fn thread_allocations() -> usize {
    ALLOCATIONS.try_with(Cell::get).unwrap_or(0)
}

/// Allocations `f` makes on this thread.
pub fn count_allocations<R>(f: impl FnOnce() -> R) -> usize {
    let before = thread_allocations();
    std::hint::black_box(f());
    thread_allocations() - before
}
