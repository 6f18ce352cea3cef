//! `vlsync-cam`: publishes the camera signature stream (CSV replay or the live
//! simulator today; a camera front-end implements `vlsync_driver::Source`).
#![forbid(unsafe_code)]

fn main() -> std::process::ExitCode {
    vlsync_driver::cli::main(vlsync_common::Stream::Cam)
}
