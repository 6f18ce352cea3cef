//! `vlsync-cam`: publishes the camera signature stream (signature CSV, the live
//! simulator, or raw frames through `vlsync-signature-cam`; see `--help`).
#![forbid(unsafe_code)]

fn main() -> std::process::ExitCode {
    vlsync_driver::cli::main(vlsync_common::Stream::Cam)
}
