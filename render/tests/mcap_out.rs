//! The MCAP recording `vlsync-render --mcap` writes, read back through the
//! drivers' MCAP sources (`vlsync_mcap::McapImageSource`, `McapScanSource`),
//! against the frame directory and scan CSV of the same run.

use std::path::{Path, PathBuf};
use std::process::Command;
use vlsync_common::secs_to_nanos;
use vlsync_mcap::{
    ImageSourceOptions, McapImageSource, McapReader, McapScanSource, ScanSourceOptions, StampSource,
};
use vlsync_render::output::{
    write_run_with, McapOutput, MCAP_IMAGE_TOPIC, MCAP_PNG_TOPIC, MCAP_SCAN_TOPIC,
};
use vlsync_render::{RenderConfig, Renderer};
use vlsync_signature_cam::{DirSource, FrameSource};
use vlsync_signature_lidar::csv::CsvScanReader;

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vlsync-render-mcap-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Every frame of `mcap` (topic `topic`) against `dir`'s frames: same count,
/// same pixels, the same instant to the nanosecond. Returns the frame count.
fn frames_match(dir: &Path, mcap: &Path, topic: &str) -> usize {
    let mut d = DirSource::open(dir).unwrap();
    let mut m = McapImageSource::open(mcap, ImageSourceOptions::topic(topic)).unwrap();
    let mut n = 0;
    loop {
        match (d.next_frame().unwrap(), m.next_frame().unwrap()) {
            (Some((a, ta)), Some((b, tb))) => {
                assert_eq!(a, b, "frame {n}: pixels");
                // frames.csv: exposure start and duration; MCAP: the mid-exposure stamp
                assert_eq!(
                    ta.instant_ns().unwrap(),
                    tb.instant_ns().unwrap(),
                    "frame {n}"
                );
                n += 1;
            }
            (None, None) => return n,
            (a, b) => panic!(
                "frame {n}: directory has {}, MCAP has {}",
                a.is_some(),
                b.is_some()
            ),
        }
    }
}

#[test]
fn mcap_recording_matches_the_directory_and_csv() {
    let dir = temp_dir("lib");
    let mut cfg = RenderConfig::from_seed(4, 3.0);
    cfg.camera.width = 64;
    cfg.camera.height = 48;
    // a camera clock 0.25 s behind: the first frames have negative stamps
    cfg.clock.offset0_s = 0.25;
    let exposure_ns = secs_to_nanos(cfg.camera.exposure_s);
    let mut r = Renderer::new(cfg).unwrap();
    let path = dir.join("run.mcap");
    let out = McapOutput {
        path: path.clone(),
        png: false,
    };
    let s = write_run_with(&mut r, &dir, true, Some(&out)).unwrap();
    assert!(s.frames > 70 && s.scans >= 28, "{s:?}");

    // two topics, one message per frame and per scan
    let topics = McapReader::topics(&path).unwrap();
    let listed: Vec<(&str, &str, Option<u64>)> = topics
        .iter()
        .map(|t| (t.topic.as_str(), t.schema_name.as_str(), t.message_count))
        .collect();
    assert_eq!(listed.len(), 2, "{listed:?}");
    assert!(listed.contains(&(
        MCAP_IMAGE_TOPIC,
        "sensor_msgs/msg/Image",
        Some(s.frames as u64)
    )));
    assert!(listed.contains(&(
        MCAP_SCAN_TOPIC,
        "sensor_msgs/msg/LaserScan",
        Some(s.scans as u64)
    )));

    assert_eq!(frames_match(&dir, &path, MCAP_IMAGE_TOPIC), s.frames);

    // header stamps are frames.csv's t_s (negative ones too); log times the
    // true end of exposure
    let mut m = McapImageSource::open(&path, ImageSourceOptions::default()).unwrap();
    let mut negative = 0;
    for info in r.frame_schedule() {
        let f = m.next_image().unwrap().unwrap();
        assert_eq!(f.stamp_ns, info.stamp_ns);
        assert_eq!(f.log_time as i64, info.tau_mid_ns + exposure_ns / 2);
        negative += usize::from(f.stamp_ns < 0);
    }
    assert!(m.next_image().unwrap().is_none());
    assert!(negative > 0, "no negative camera stamp");

    // scans: the CSV's rays, times within the float32 time_increment's rounding
    let csv = CsvScanReader::open(&dir.join("scans.csv")).unwrap();
    let mut m = McapScanSource::open(&path, ScanSourceOptions::default()).unwrap();
    let mut log = McapScanSource::open(
        &path,
        ScanSourceOptions {
            stamp: StampSource::LogTime,
            ..ScanSourceOptions::default()
        },
    )
    .unwrap();
    let (mut n, mut worst_ns, mut valid) = (0, 0i64, 0usize);
    let period_ns = r.config().lidar.period_ns();
    for a in csv {
        let a = a.unwrap();
        let b = m.next_scan().unwrap().expect("as many scans in the MCAP");
        assert_eq!(b.len(), a.len(), "scan {n}: rays");
        assert_eq!(b.len(), r.config().lidar.rays_per_turn);
        assert_eq!(b.rays()[0].t_ns, a.rays()[0].t_ns, "scan {n}: stamp");
        assert_eq!(b.timing().period_ns, a.timing().period_ns);
        assert_eq!(b.timing().rotation, a.timing().rotation);
        for (i, (x, y)) in a.rays().iter().zip(b.rays()).enumerate() {
            worst_ns = worst_ns.max((x.t_ns - y.t_ns).abs());
            assert!(
                (vlsync_signature_lidar::scan::wrap_pi(x.bearing_rad - y.bearing_rad)).abs() < 1e-5,
                "scan {n} ray {i}: bearing {} vs {}",
                x.bearing_rad,
                y.bearing_rad
            );
            assert_eq!(x.valid, y.valid, "scan {n} ray {i}: validity");
            if x.valid {
                assert_eq!(y.range_m, f64::from(x.range_m as f32), "scan {n} ray {i}");
                valid += 1;
            }
        }
        // log time: the true end of the revolution
        let info = r.scan_schedule()[n];
        let l = log.next_scan().unwrap().unwrap();
        assert_eq!(l.rays()[0].t_ns, info.tau_start_ns + period_ns);
        n += 1;
    }
    assert!(m.next_scan().unwrap().is_none());
    assert_eq!(n, s.scans);
    assert!(valid > n * 300, "{valid} valid rays in {n} scans");
    // 450 rays floor(k · 100 ms / 450) ns after the stamp; read back as
    // round(k · 222222.22 ns), the float32 increment's decimal
    assert!(worst_ns <= 1, "ray times up to {worst_ns} ns off scans.csv");
    std::fs::remove_dir_all(&dir).unwrap();
}

fn render_bin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_vlsync-render"))
        .args(args)
        .output()
        .expect("run vlsync-render")
}

#[test]
fn binary_writes_png_mcap_by_default_in_the_output_directory_and_names_bad_paths() {
    let dir = temp_dir("bin");
    let d = dir.to_str().unwrap();
    let common = [
        "--seed",
        "3",
        "--duration",
        "1",
        "--width",
        "32",
        "--height",
        "24",
        "--out",
        d,
    ];
    let out = render_bin(&[&common[..], &["--mcap", "--mcap-png"]].concat());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let path = dir.join("run.mcap");
    assert!(stdout.contains(&path.display().to_string()), "{stdout}");
    assert!(stdout.contains(MCAP_PNG_TOPIC), "{stdout}");
    let n = frames_match(&dir, &path, MCAP_PNG_TOPIC);
    assert!(n > 20, "{n} frames");
    assert_eq!(
        McapReader::topics(&path).unwrap()[0].schema_name,
        "sensor_msgs/msg/CompressedImage"
    );

    // an explicit FILE that cannot be created: a clear error naming it, no panic,
    // and the run already in the directory left as it was (its CSVs used to be cut
    // to their headers before the recording failed to open)
    let before = [
        std::fs::read(dir.join("frames.csv")).unwrap(),
        std::fs::read(dir.join("scans.csv")).unwrap(),
    ];
    let bad = "/proc/no/such/dir/run.mcap";
    let out = render_bin(&[&common[..], &["--mcap", bad]].concat());
    let stderr = String::from_utf8_lossy(&out.stderr);
    // refused as an option, before the run (since 2026-12-07)
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.starts_with(&format!(
            "vlsync-render: error: --mcap {bad}: directory /proc/no/such/dir does not exist"
        )),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    // the library, given such a FILE, opens it before it touches the directory's files
    let mut r = Renderer::new(RenderConfig::from_seed(3, 1.0)).unwrap();
    let m = McapOutput {
        path: PathBuf::from(bad),
        png: false,
    };
    let e = write_run_with(&mut r, &dir, false, Some(&m)).unwrap_err();
    assert!(
        e.to_string().starts_with(&format!("{bad}: creating")),
        "{e}"
    );
    let after = [
        std::fs::read(dir.join("frames.csv")).unwrap(),
        std::fs::read(dir.join("scans.csv")).unwrap(),
    ];
    assert!(before == after, "the earlier run's CSVs were rewritten");

    // --mcap-png alone is a usage error
    let out = render_bin(&[&common[..], &["--mcap-png"]].concat());
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--mcap"));
    std::fs::remove_dir_all(&dir).unwrap();
}
