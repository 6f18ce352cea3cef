//! `vlsync-lidar`: publishes the LiDAR signature stream (signature CSV, the live
//! simulator, or raw scans through `vlsync-signature-lidar`; see `--help`).
#![forbid(unsafe_code)]

fn main() -> std::process::ExitCode {
    vlsync_driver::cli::main(vlsync_common::Stream::Lidar)
}
