//! Steady-state frame processing allocates nothing: a counting global allocator
//! (thread-local counts, so the test harness's other threads do not interfere)
//! watches frames 2..N of a stream of same-size frames.
//!
//! This file is its own crate: it installs `vlsync-alloc-count`'s allocator.

use vlsync_signature_cam::{
    FrameTime, GrayFrame, PixelFormat, RawFrame, Reduction, SignatureConfig, SignatureProcessor,
    Step,
};

#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

use vlsync_alloc_count::this_thread as allocs;

#[path = "no_alloc/long_run.rs"]
mod long_run;
#[path = "no_alloc/pipe.rs"]
mod pipe;

/// A 640x480 YUYV frame of a smooth texture shifted by `(sx, sy)`.
fn yuyv(sx: f32, sy: f32) -> Vec<u8> {
    let (w, h) = (640usize, 480usize);
    let mut out = vec![128u8; w * h * 2];
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f32 - sx, y as f32 - sy);
            let g = 128.0 + 50.0 * (0.21 * u + 0.07 * v).sin() + 40.0 * (0.13 * v - 0.17 * u).cos();
            out[(y * w + x) * 2] = g.clamp(0.0, 255.0) as u8;
        }
    }
    out
}

#[test]
fn steady_state_processing_allocates_nothing() {
    let raws: Vec<Vec<u8>> = (0..6)
        .map(|k| yuyv(1.3 * k as f32, 0.7 * k as f32))
        .collect();
    for reduction in [
        Reduction::default(),
        Reduction::MeanMagnitude,
        Reduction::MedianMagnitude,
        Reduction::Divergence { focus: [0.5, 0.6] },
    ] {
        let cfg = SignatureConfig {
            reduction,
            ..SignatureConfig::default()
        };
        let mut p = SignatureProcessor::new(cfg).unwrap();
        let mut gray = Vec::new();
        let mut samples = 0;
        let mut after_first = 0;
        for (k, raw) in raws.iter().enumerate() {
            let before = allocs();
            RawFrame::new(raw, 640, 480, PixelFormat::Yuyv)
                .to_gray_into(&mut gray)
                .unwrap();
            let frame = GrayFrame::borrowed(640, 480, &gray).unwrap();
            let step = p
                .process(&frame, FrameTime::Instant(k as i64 * 33_000_000))
                .unwrap();
            let n = allocs() - before;
            if k > 0 {
                after_first += n;
            } else {
                assert!(n > 0, "the first frame sets up the buffers");
            }
            if let Step::Sample(s) = step {
                samples += 1;
                assert!(!s.low_texture(), "{s:?}");
            }
        }
        assert_eq!(samples, raws.len() - 1);
        assert_eq!(
            after_first, 0,
            "{reduction:?}: allocations after the first frame"
        );
    }
}

#[test]
fn skipped_camera_buffers_allocate_nothing() {
    use vlsync_signature_cam::v4l2::BufferFault;
    use vlsync_signature_cam::UnusableFrames;
    // a USB camera flags cut transfers routinely: each skipped buffer is a
    // per-frame event (the longest reasons: every number at its widest)
    let mut u = UnusableFrames::named("buffers");
    let before = allocs();
    for k in 0..1000u32 {
        let fault = if k % 2 == 0 {
            BufferFault::Corrupt
        } else {
            BufferFault::Short {
                used: usize::MAX - 1,
                need: usize::MAX,
            }
        };
        fault.skip(u32::MAX - k, &mut u).unwrap();
        if k % 10 == 9 {
            u.used();
        }
    }
    assert_eq!(allocs() - before, 0, "allocations for 1000 skipped buffers");
    let (n, last) = u.counts().unwrap();
    assert_eq!(n, 1000);
    assert!(
        last.starts_with(&format!("buffer {} too short: ", u32::MAX - 999)),
        "{last}"
    );
    // the error that ends the stream names the last reason
    let e = (0..30)
        .map(|k| BufferFault::Corrupt.skip(k, &mut u))
        .find_map(Result::err)
        .unwrap();
    assert_eq!(
        e,
        "30 buffers in a row unusable, the last: buffer 29 flagged corrupt by the driver"
    );
}
