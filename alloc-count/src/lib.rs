//! A counting global allocator for the "allocates nothing after start-up" tests.
//!
//! Each test binary that needs it installs it once and reads the counters
//! around the code under test:
//!
//! ```
//! #[global_allocator]
//! static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;
//!
//! fn main() {
//!     let mut buf = Vec::with_capacity(64); // set-up may allocate
//!     let before = vlsync_alloc_count::this_thread();
//!     for i in 0..64 {
//!         buf.push(i); // the hot path must not
//!     }
//!     assert_eq!(vlsync_alloc_count::this_thread(), before);
//!     buf.push(64); // past the capacity: one reallocation
//!     assert_eq!(vlsync_alloc_count::this_thread(), before + 1);
//! }
//! ```
//!
//! The counters:
//!
//! * [`this_thread`]: allocations (and reallocations) made by the calling
//!   thread; other threads of the test harness do not disturb it.
//! * [`total`]: allocations made by every thread of the process.
//! * [`watch_thread`] / [`watched`]: allocations made by threads with one name
//!   (the daemon's real-time thread, `vlsync-rt`, spawned by library code).
//!
//! Deallocations are not counted: freeing is never the question.
//!
//! This is the workspace's only `unsafe impl GlobalAlloc`; it forwards every
//! call unchanged to [`std::alloc::System`]. Without the allocator installed
//! the counters stay at zero, so a test must also check that what it measured
//! did run (e.g. that estimates came out).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::OnceLock;

/// The counting allocator: install with `#[global_allocator]`.
pub struct Counting;

static TOTAL: AtomicU64 = AtomicU64::new(0);
static WATCHED: AtomicU64 = AtomicU64::new(0);
static WATCH: OnceLock<(&'static str, bool)> = OnceLock::new();
static WATCH_ON: AtomicBool = AtomicBool::new(false);

thread_local! {
    static THIS: Cell<u64> = const { Cell::new(0) };
    static IN_HOOK: Cell<bool> = const { Cell::new(false) };
}

fn count() {
    TOTAL.fetch_add(1, Ordering::Relaxed);
    let _ = THIS.try_with(|c| c.set(c.get() + 1));
    if !WATCH_ON.load(Ordering::Relaxed) {
        return;
    }
    // naming the current thread may allocate: the guard keeps that from recursing
    let _ = IN_HOOK.try_with(|h| {
        if h.get() {
            return;
        }
        h.set(true);
        if let Some(&(name, backtrace)) = WATCH.get() {
            if std::thread::current().name() == Some(name) {
                WATCHED.fetch_add(1, Ordering::Relaxed);
                if backtrace {
                    eprintln!("{}", std::backtrace::Backtrace::force_capture());
                }
            }
        }
        h.set(false);
    });
}

// SAFETY: every method forwards its arguments unchanged to `System`, which
// upholds the `GlobalAlloc` contract; `count` touches only atomics and
// const-initialised thread-locals without destructors (no allocation, no
// recursion), except while a watched thread name is compared, which the
// `IN_HOOK` guard keeps from recursing.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller's contract is `System.alloc`'s.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller's contract is `System.alloc_zeroed`'s.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: `ptr` came from this allocator, i.e. from `System`, with `layout`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator, i.e. from `System`, with `layout`.
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// Allocations made so far by the calling thread.
pub fn this_thread() -> u64 {
    THIS.with(Cell::get)
}

/// Panics unless this allocator is the process's global allocator: a test that
/// finds zero allocations proves nothing when nothing is counted.
pub fn assert_counting() {
    let probe = this_thread();
    std::hint::black_box(vec![0u8; 16]);
    assert_eq!(
        this_thread(),
        probe + 1,
        "the counting allocator is not installed (#[global_allocator])"
    );
}

/// Allocations made so far by every thread.
pub fn total() -> u64 {
    TOTAL.load(Ordering::Relaxed)
}

/// Starts counting the allocations of threads named `name` (see [`watched`]);
/// with `backtrace`, prints a backtrace for each. The name is set once per
/// process; later calls only switch counting on again.
pub fn watch_thread(name: &'static str, backtrace: bool) {
    let _ = WATCH.set((name, backtrace));
    WATCH_ON.store(true, Ordering::Relaxed);
}

/// Stops counting the watched thread's allocations.
pub fn unwatch_thread() {
    WATCH_ON.store(false, Ordering::Relaxed);
}

/// Allocations counted on the watched thread while watching was on.
pub fn watched() -> u64 {
    WATCHED.load(Ordering::Relaxed)
}
