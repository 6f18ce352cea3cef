//! Cost of the signature processor per 360-ray scan (wall fit, the default;
//! target <= 20 µs), and parser throughput.

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use std::f64::consts::PI;
use vlsync_signature_lidar::encode::{ld06_stream, rplidar_revolution, SCAN_DESCRIPTOR};
use vlsync_signature_lidar::ld06::{Ld06Config, Ld06Parser};
use vlsync_signature_lidar::rplidar::{RplidarConfig, RplidarParser};
use vlsync_signature_lidar::{
    Ray, Rotation, Scan, ScanTiming, SignatureConfig, SignatureProcessor,
};

const PERIOD: i64 = 100_000_000;

fn scans(n: usize) -> Vec<Scan> {
    (0..n)
        .map(|k| {
            let rays = (0..360)
                .map(|i| {
                    // a flat wall on the left (normal at bearing 90°), 2 m away and
                    // receding, with centimetre texture; farther surfaces elsewhere
                    let b = (i as f64).to_radians();
                    let off = b - PI / 2.0;
                    let r = if off.abs() < 1.2 {
                        (2.0 + 0.001 * k as f64) / off.cos() + 0.01 * (b * 37.0).sin()
                    } else {
                        6.0
                    };
                    Ray::new(b, r, 100.0, true)
                })
                .collect();
            Scan::from_uniform(
                ScanTiming {
                    start_ns: k as i64 * PERIOD,
                    period_ns: PERIOD,
                    rotation: Rotation::Ccw,
                    start_bearing_rad: 0.0,
                },
                rays,
            )
        })
        .collect()
}

fn bench_signature(c: &mut Criterion) {
    let data = scans(64);
    let mut g = c.benchmark_group("signature");
    for (name, hw_deg) in [
        ("360_rays_window_5deg", 5.0),
        ("360_rays_window_20deg_default", 20.0),
        ("360_rays_window_45deg", 45.0),
    ] {
        g.throughput(Throughput::Elements(1));
        g.bench_function(name, |b| {
            let mut p = SignatureProcessor::new(SignatureConfig {
                window_centre_rad: PI / 2.0,
                window_half_width_rad: f64::to_radians(hw_deg),
                max_gap_ns: i64::MAX / 4,
                ..Default::default()
            })
            .unwrap();
            let mut k = 0usize;
            b.iter(|| {
                // time goes back when the data set wraps: restart the stream
                let s = &data[k % data.len()];
                if k.is_multiple_of(data.len()) {
                    p.reset();
                }
                let n = p.push_scan(black_box(s), |x| {
                    black_box(x);
                });
                k += 1;
                n
            });
        });
    }
    g.finish();
}

fn bench_parsers(c: &mut Criterion) {
    let ld = ld06_stream(3600, 0, 2.0, |_, _| 2.5);
    let mut rp = SCAN_DESCRIPTOR.to_vec();
    for k in 0..11 {
        rp.extend(rplidar_revolution(
            360,
            k as f64 / 5.5,
            1.0 / 5.5,
            |_, _| 2.5,
        ));
    }
    let mut g = c.benchmark_group("parse");
    g.throughput(Throughput::Bytes(ld.len() as u64));
    g.bench_function("ld06_2s_stream", |b| {
        b.iter(|| {
            let mut p = Ld06Parser::new(Ld06Config::default());
            let mut rays = 0;
            for chunk in ld.chunks(256) {
                p.push(black_box(chunk), 0, |s| rays += s.len());
            }
            rays
        })
    });
    g.throughput(Throughput::Bytes(rp.len() as u64));
    g.bench_function("rplidar_2s_stream", |b| {
        b.iter(|| {
            let mut p = RplidarParser::new(RplidarConfig::default());
            let mut rays = 0;
            for chunk in rp.chunks(256) {
                p.push(black_box(chunk), 0, |s| rays += s.len());
            }
            rays
        })
    });
    g.finish();
}

criterion_group!(benches, bench_signature, bench_parsers);
criterion_main!(benches);
