//! The counter counts this thread's allocations and nothing else.
#![allow(missing_docs, clippy::unwrap_used)]

use test_support::{CountingAllocator, count_allocations, thread_allocations};

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

#[test]
fn counts_this_threads_allocations_only() {
    assert_eq!(count_allocations(|| Vec::<u8>::with_capacity(8)), 1);
    assert_eq!(
        count_allocations(|| {
            let mut v = vec![0u8; 8];
            v.reserve(1024);
            v
        }),
        2
    );
    assert_eq!(count_allocations(|| [0u64; 64].iter().sum::<u64>()), 0);
    // Another thread's allocations count there, not here.
    let other = std::thread::spawn(|| {
        let before = thread_allocations();
        drop(std::hint::black_box(Box::new(1u8)));
        thread_allocations() - before
    });
    let here = count_allocations(|| 0);
    assert_eq!((other.join().unwrap(), here), (1, 0));
}
