//! vlsyncd library: the logic behind the `vlsyncd` commands, testable without processes.
#![forbid(unsafe_code)]

// the unit tests count allocations (`runtime::rt`'s work for the real-time thread)
#[cfg(test)]
#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

pub mod bench;
pub mod check;
pub mod compare;
pub mod harness;
pub mod plot;
pub mod record;
pub mod replay;
pub mod runtime;
pub mod state;
