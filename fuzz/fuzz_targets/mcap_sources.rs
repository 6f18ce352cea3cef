//! An MCAP recording from arbitrary bytes: the topic listing, then both sources
//! (LaserScan and Image/CompressedImage) read to their end or first error.
//! Nothing may panic, and reading must end (every error is final).
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::io::Write;
use vlsync_mcap::{
    ImageSourceOptions, McapImageSource, McapReader, McapScanSource, ScanSourceOptions,
};

fuzz_target!(|data: &[u8]| {
    // the readers take a path: one scratch file per fuzzing process, in the temp directory
    let path = std::env::temp_dir().join(format!("vlsync-fuzz-{}.mcap", std::process::id()));
    {
        let mut f = std::fs::File::create(&path).expect("scratch file");
        f.write_all(data).expect("write scratch file");
    }
    let _ = McapReader::topics(&path);
    if let Ok(mut s) = McapScanSource::open(&path, ScanSourceOptions::default()) {
        for _ in 0..10_000 {
            match s.next_scan() {
                Ok(Some(_)) => {}
                _ => break,
            }
        }
    }
    let opts = ImageSourceOptions {
        max_pixels: 1 << 16,
        ..ImageSourceOptions::default()
    };
    if let Ok(mut s) = McapImageSource::open(&path, opts) {
        for _ in 0..1_000 {
            match s.next_image() {
                Ok(Some(_)) => {}
                _ => break,
            }
        }
    }
});
