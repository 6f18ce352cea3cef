//! vlsyncd library: the logic behind the `vlsyncd` commands, testable without processes.
#![forbid(unsafe_code)]

pub mod bench;
pub mod check;
pub mod compare;
pub mod harness;
pub mod plot;
pub mod record;
pub mod replay;
pub mod runtime;
pub mod state;
