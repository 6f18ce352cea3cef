//! Time per 640x480 frame with the default configuration (ROI x 25-75 %, y 55-90 %,
//! 16x8 grid, 3 levels, 9x9 window). Target: <= 3 ms per frame in release.
//!
//! `cargo bench -p vlsync-signature-cam --bench flow`

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use vlsync_signature_cam::{
    FrameTime, GrayFrame, PixelFormat, PyrLk, RawFrame, SignatureConfig, SignatureProcessor,
};

const W: usize = 640;
const H: usize = 480;

/// A textured 640x480 gray frame shifted by `(sx, sy)` px.
fn gray(sx: f32, sy: f32) -> Vec<u8> {
    (0..W * H)
        .map(|i| {
            let (x, y) = ((i % W) as f32 - sx, (i / W) as f32 - sy);
            let g = 128.0
                + 45.0 * (0.21 * x + 0.07 * y).sin()
                + 35.0 * (0.13 * y - 0.17 * x).cos()
                + 25.0 * (0.41 * x - 0.33 * y + 1.0).sin();
            g.clamp(0.0, 255.0) as u8
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let frames: Vec<Vec<u8>> = (0..8)
        .map(|k| gray(1.7 * k as f32, 2.3 * k as f32))
        .collect();

    c.bench_function("signature 640x480 default (gray u8)", |b| {
        let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
        let mut k = 0usize;
        b.iter(|| {
            let f = GrayFrame::borrowed(W, H, &frames[k % frames.len()]).unwrap();
            // contiguous 30 Hz stamps; every 8th frame jumps back 7 shifts (a big
            // motion), which LK still handles; that is fine for timing
            let step = p.process(&f, FrameTime::Instant(k as i64 * 33_333_333));
            k += 1;
            black_box(step).unwrap()
        })
    });

    c.bench_function("flow only 640x480 default", |b| {
        let mut lk = PyrLk::new(SignatureConfig::default().flow).unwrap();
        let mut k = 0usize;
        b.iter(|| {
            let f = GrayFrame::borrowed(W, H, &frames[k % 2]).unwrap();
            k += 1;
            black_box(lk.push(&f)).unwrap()
        })
    });

    // the first pair of a start or a restart: no point has a flow to start
    // from, so the coarse search runs (predict on, the default); with predict
    // off the points search from zero and nothing else runs. The difference is
    // the search's cost, paid once per start
    for (name, predict) in [
        ("first pair after a reset 640x480, coarse search", true),
        ("first pair after a reset 640x480, from zero", false),
    ] {
        let big: Vec<Vec<u8>> = [0.0, 30.0].iter().map(|&d| gray(0.0, d)).collect();
        c.bench_function(name, |b| {
            let cfg = vlsync_signature_cam::FlowConfig {
                predict,
                ..SignatureConfig::default().flow
            };
            let mut lk = PyrLk::new(cfg).unwrap();
            b.iter(|| {
                lk.reset();
                for f in &big {
                    let f = GrayFrame::borrowed(W, H, f).unwrap();
                    black_box(lk.push(&f)).unwrap();
                }
            })
        });
    }

    let yuyv: Vec<u8> = frames[0].iter().flat_map(|&g| [g, 128]).collect();
    c.bench_function("yuyv to gray 640x480", |b| {
        let mut out = Vec::new();
        b.iter(|| {
            RawFrame::new(black_box(&yuyv), W, H, PixelFormat::Yuyv)
                .to_gray_into(&mut out)
                .unwrap()
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(50).measurement_time(std::time::Duration::from_secs(4));
    targets = bench
}
criterion_main!(benches);
