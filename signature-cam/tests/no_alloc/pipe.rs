//! Reading frames from a pipe allocates nothing after the source is made: 300
//! I420 frames with padded rows (the luma copied out) and 300 YUYV frames, each
//! waited for and stamped, counted by a thread-local counting allocator.
//!
//! A module of `no_alloc.rs`, whose crate installs `vlsync-alloc-count`'s allocator
//! (one test binary for the three, one link less each).

use std::io::Write;
use std::sync::OnceLock;
use std::time::{Duration, Instant};
use vlsync_signature_cam::pipe::{PipeConfig, PipeFormat, PipeSource};
use vlsync_signature_cam::FrameSource;

fn clock() -> i64 {
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_nanos() as i64
}

#[test]
fn reading_frames_from_a_pipe_allocates_nothing() {
    for (format, stride) in [(PipeFormat::I420, Some(192)), (PipeFormat::Yuyv, None)] {
        let (w, h) = (160, 120);
        let cfg = PipeConfig {
            width: w,
            height: h,
            stride,
            format,
            silence: Duration::from_secs(10),
        };
        let bytes = format
            .frame_bytes(w, h, stride.unwrap_or(format.min_stride(w).unwrap()))
            .unwrap();
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut src = PipeSource::new(r, "pipe", cfg, clock).unwrap();
        let frames = 300;
        let writer = std::thread::spawn(move || {
            let mut f = vec![0u8; bytes];
            for k in 0..frames {
                f[0] = k as u8;
                // paced: each frame is waited for, none queued
                std::thread::sleep(Duration::from_millis(4));
                wr.write_all(&f).unwrap();
            }
        });
        let before = vlsync_alloc_count::this_thread();
        let mut got = 0u32;
        let mut sum = 0u64;
        while let Some((frame, _t)) = src.next_frame().unwrap() {
            got += 1;
            sum += u64::from(frame.pixels()[0]);
        }
        let allocated = vlsync_alloc_count::this_thread() - before;
        vlsync_alloc_count::assert_counting();
        writer.join().unwrap();
        let (read, queued) = src.counts();
        assert_eq!(read, frames as u64, "{format}");
        assert_eq!(u64::from(got) + queued, read, "{format}");
        // most are waited for; a loaded machine may hold the reader up for some
        assert!(
            got >= 30,
            "{format}: only {got} of {frames} frames waited for"
        );
        assert!(sum > 0);
        assert_eq!(allocated, 0, "{format}: allocations over {read} frames");
    }
}
