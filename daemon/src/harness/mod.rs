//! Live runs of the whole pipeline, shared by `vlsync-demo` and
//! `vlsync-loadtest`: [`session`] starts `vlsyncd run` and both drivers on a
//! unique prefix and records what the daemon publishes; [`truth`] is what the
//! estimates are scored against (a known model, or the offset the drivers
//! measured); [`load`] injects CPU load, memory pressure and driver stalls by
//! phase; [`report`] turns a load run into tables, JSON and a plot; [`stats`]
//! holds the small statistics they share; [`console`] is their standard output,
//! which a reader that goes away does not turn into a panic.

pub mod console;
pub mod load;
pub mod report;
pub mod session;
pub mod stats;
pub mod truth;
