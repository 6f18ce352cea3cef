//! Serial bytes from arbitrary input, cut where the input says, through the LD06
//! and RPLIDAR parsers and the wall-distance signature of the scans they make.
//! Nothing may panic; every byte is counted.
#![no_main]
use libfuzzer_sys::fuzz_target;
use vlsync_signature_lidar::ld06::{Ld06Config, Ld06Parser};
use vlsync_signature_lidar::rplidar::{RplidarConfig, RplidarParser};
use vlsync_signature_lidar::{SignatureConfig, SignatureProcessor};

fuzz_target!(|data: &[u8]| {
    if data.is_empty() {
        return;
    }
    // the first byte sets the chunk length (how the serial port hands the bytes over)
    let chunk = usize::from(data[0]).max(1);
    let bytes = &data[1..];
    let mut sig = SignatureProcessor::new(SignatureConfig::default()).expect("default config");
    let mut ld = Ld06Parser::new(Ld06Config::default());
    let mut rp = RplidarParser::new(RplidarConfig::default());
    let mut t = 0i64;
    for c in bytes.chunks(chunk) {
        t += 1_000_000;
        ld.push(c, t, |s| {
            sig.push_scan(s, |_| {});
        });
        rp.push(c, t, |s| {
            sig.push_scan(s, |_| {});
        });
    }
    ld.finish(|s| {
        sig.push_scan(s, |_| {});
    });
    rp.finish(|s| {
        sig.push_scan(s, |_| {});
    });
    assert_eq!(ld.stats().bytes, bytes.len() as u64);
    assert_eq!(rp.stats().bytes, bytes.len() as u64);
});
