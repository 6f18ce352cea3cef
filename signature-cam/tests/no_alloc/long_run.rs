//! The camera signature allocates nothing per frame over a long run, not only over
//! the few frames of `no_alloc.rs`: 3000 YUYV frames converted to gray and processed
//! as a camera driver does, through what a live camera brings (speed changes and
//! stops, stretches without texture, dropped frames, gaps that restart the
//! sequence, a stamp stepping back, exposure times and plain stamps).
//!
//! A module of `no_alloc.rs`, whose crate installs `vlsync-alloc-count`'s allocator
//! (one test binary for the three, one link less each).

use vlsync_signature_cam::{
    FrameTime, GrayFrame, PixelFormat, RawFrame, Reduction, SignatureConfig, SignatureProcessor,
    StartReason, Step,
};

use vlsync_alloc_count::this_thread as allocs;

const W: usize = 320;
const H: usize = 240;
const FRAMES: usize = 3000;
/// Frames of start-up, whose processing may still set up buffers.
const WARM_UP: usize = 10;
const PERIOD_NS: i64 = 33_333_333;

/// A texture larger than any frame, drawn once: the frames are windows into it.
struct Canvas {
    w: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn new(w: usize, h: usize) -> Self {
        let mut px = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f32, y as f32);
                let g = 128.0
                    + 45.0 * (0.21 * u + 0.07 * v).sin()
                    + 35.0 * (0.13 * v - 0.17 * u).cos()
                    + 20.0 * (0.031 * u + 0.043 * v + 0.0007 * u * v).sin();
                px[y * w + x] = g.clamp(0.0, 255.0) as u8;
            }
        }
        Self { w, px }
    }
}

/// Writes into `out` (YUYV) frame `k`: the texture moving down and sideways
/// (whole pixels) at a speed that varies and stops now and then, flat (no texture)
/// for 12 frames every 400.
fn yuyv_into(out: &mut [u8], k: usize, canvas: &Canvas, offset: &mut (f32, f32)) {
    let speed = if k % 500 < 40 {
        0.0
    } else {
        1.5 + 1.2 * (k as f32 * 0.01).sin()
    };
    offset.0 += 0.3 * speed;
    offset.1 += speed;
    let (ox, oy) = (offset.0 as usize, offset.1 as usize);
    let flat = k % 400 >= 200 && k % 400 < 212;
    for y in 0..H {
        for x in 0..W {
            out[(y * W + x) * 2] = if flat {
                120
            } else {
                canvas.px[(y + oy) * canvas.w + x + ox]
            };
            out[(y * W + x) * 2 + 1] = 128;
        }
    }
}

/// The time of frame `k`: 30 Hz with a dropped frame every 97, a 0.5 s gap at
/// frame 1000 and 2200 (the sequence restarts), and a stamp 10 ms back at 1500.
fn frame_time(k: usize) -> FrameTime {
    let mut t = k as i64 * PERIOD_NS + (k as i64 / 97) * PERIOD_NS;
    if k >= 1000 {
        t += 500_000_000;
    }
    if k >= 2200 {
        t += 500_000_000;
    }
    if k == 1500 {
        // this frame's stamp lies before the previous one's
        t -= PERIOD_NS + 10_000_000;
    } else if k > 1500 {
        t += 50_000_000;
    }
    if k.is_multiple_of(2) {
        FrameTime::Exposure {
            start_ns: t - 4_000_000,
            duration_ns: 8_000_000,
        }
    } else {
        FrameTime::Instant(t)
    }
}

#[test]
fn thousands_of_frames_allocate_nothing_after_start_up() {
    // the texture moves at most 2.7 px a frame down, 0.3 of that sideways
    let canvas = Canvas::new(W + 3 * FRAMES / 10, H + 3 * FRAMES);
    for (reduction, normalise) in [
        (Reduction::default(), true),
        (Reduction::MedianMagnitude, false),
    ] {
        let cfg = SignatureConfig {
            reduction,
            normalise,
            ..SignatureConfig::default()
        };
        let mut p = SignatureProcessor::new(cfg).unwrap();
        let mut raw = vec![0u8; W * H * 2];
        let mut gray = Vec::new();
        let mut offset = (0.0, 0.0);
        let (mut samples, mut low_texture, mut gaps, mut back, mut after_warm_up) = (0, 0, 0, 0, 0);
        for k in 0..FRAMES {
            yuyv_into(&mut raw, k, &canvas, &mut offset);
            let before = allocs();
            RawFrame::new(&raw, W, H, PixelFormat::Yuyv)
                .to_gray_into(&mut gray)
                .unwrap();
            let frame = GrayFrame::borrowed(W, H, &gray).unwrap();
            let step = p.process(&frame, frame_time(k)).unwrap();
            if k >= WARM_UP {
                after_warm_up += allocs() - before;
            }
            match step {
                Step::Sample(s) => {
                    samples += 1;
                    low_texture += usize::from(s.low_texture());
                }
                Step::Started(StartReason::Gap { .. }) => gaps += 1,
                Step::Started(StartReason::NotIncreasing { .. }) => back += 1,
                Step::Started(r) => assert!(k == 0, "frame {k}: {r:?}"),
            }
        }
        eprintln!(
            "{reduction:?}: {samples} samples ({low_texture} low texture), {gaps} gaps, {back} steps back; {after_warm_up} allocations"
        );
        // a zero below means none only if the allocator counts
        vlsync_alloc_count::assert_counting();
        assert_eq!(
            after_warm_up,
            0,
            "{reduction:?}: allocations over {} frames after the warm-up",
            FRAMES - WARM_UP
        );
        // every kind of frame came: samples, textureless ones, restarts
        assert!(samples > FRAMES * 9 / 10, "{samples} samples");
        assert!(low_texture >= 50, "{low_texture} low-texture samples");
        assert_eq!((gaps, back), (2, 1), "restarts");
    }
}
