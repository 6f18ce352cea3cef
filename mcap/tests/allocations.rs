//! After warm-up, reading raw frames and scans allocates nothing per message
//! (PNG/JPEG decoding does; see the `image` module docs). Counted with a
//! global allocator, in its own test binary so nothing else runs beside it.

use vlsync_mcap::{
    ImageSourceOptions, McapImageSource, McapScanSource, McapWriter, ScanSourceOptions,
};
use vlsync_signature_cam::{FrameSource, GrayFrame};
use vlsync_signature_lidar::{Ray, Rotation, Scan, ScanTiming};

#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

#[test]
fn raw_frames_and_small_scans_allocate_nothing_per_message() {
    let path = std::env::temp_dir().join(format!("vlsync-mcap-alloc-{}.mcap", std::process::id()));
    let mut w = McapWriter::create(&path).unwrap();
    let px: Vec<u8> = (0..64 * 48).map(|i| i as u8).collect();
    let f = GrayFrame::owned(64, 48, px).unwrap();
    // 100 rays: below the size where the stable sort in Scan::from_timed needs a heap buffer
    let rays = |t0: i64| -> Vec<Ray> {
        (0..100)
            .map(|i| {
                Ray::timed(
                    0.01 * f64::from(i),
                    2.0,
                    0.0,
                    true,
                    t0 + i64::from(i) * 100_000,
                )
            })
            .collect()
    };
    for k in 0..200i64 {
        w.write_image("/cam", 1_000 + k * 33_000_000, &f).unwrap();
        let timing = ScanTiming {
            start_ns: k * 10_000_000,
            period_ns: 10_000_000,
            rotation: Rotation::Ccw,
            start_bearing_rad: 0.0,
        };
        w.write_scan("/scan", &Scan::from_timed(timing, rays(k * 10_000_000)))
            .unwrap();
    }
    w.finish().unwrap();

    let mut src = McapImageSource::open(&path, ImageSourceOptions::topic("/cam")).unwrap();
    for _ in 0..20 {
        src.next_frame().unwrap().unwrap();
    }
    let before = vlsync_alloc_count::this_thread();
    let mut n = 0;
    while src.next_frame().unwrap().is_some() {
        n += 1;
    }
    let frames = vlsync_alloc_count::this_thread() - before;

    let mut scans = McapScanSource::open(&path, ScanSourceOptions::topic("/scan")).unwrap();
    for _ in 0..20 {
        scans.next_scan().unwrap().unwrap();
    }
    let before = vlsync_alloc_count::this_thread();
    let mut m = 0;
    while scans.next_scan().unwrap().is_some() {
        m += 1;
    }
    let scan_allocs = vlsync_alloc_count::this_thread() - before;
    vlsync_alloc_count::assert_counting();
    // every message after the warm-up was read while counting
    assert_eq!((n, m), (180, 180));
    std::fs::remove_file(&path).unwrap();
    eprintln!("{n} frames: {frames} allocations; 180 scans: {scan_allocs} allocations");
    // chunks (768 KiB by default) are loaded and indexed as the reader reaches them;
    // that is per chunk, not per message
    assert!(frames <= n / 10, "{frames} allocations for {n} frames");
    assert!(scan_allocs <= 18, "{scan_allocs} allocations for 180 scans");
}
