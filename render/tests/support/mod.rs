//! Shared by the end-to-end test and the accuracy example.
pub mod pipeline;
