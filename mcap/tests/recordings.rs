//! Recordings written with `McapWriter` and read back through the sources:
//! exact round trips, file order, and hostile files (truncated, corrupted
//! chunk, wrong schema, CDR lengths past the buffer, arbitrary bytes).

use proptest::prelude::*;
use std::path::PathBuf;
use vlsync_mcap::cdr::{CdrMessage, CompressedImage, Image, LaserScan};
use vlsync_mcap::scan::f32_as_decimal;
use vlsync_mcap::{
    ImageSourceOptions, McapImageSource, McapReader, McapScanSource, McapWriter, ScanSourceOptions,
    Select, StampSource, IMAGE_SCHEMAS,
};
use vlsync_signature_cam::{FrameSource, FrameTime, GrayFrame};
use vlsync_signature_lidar::scan::wrap_pi;
use vlsync_signature_lidar::{Ray, Rotation, Scan, ScanTiming};

/// A temporary file removed on drop.
struct Tmp(PathBuf);

impl Tmp {
    fn new(name: &str) -> Self {
        Self(std::env::temp_dir().join(format!("vlsync-mcap-{}-{name}.mcap", std::process::id())))
    }
}

impl Drop for Tmp {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn frame(k: u8, w: usize, h: usize) -> GrayFrame<'static, u8> {
    let px = (0..w * h)
        .map(|i| (i as u8).wrapping_mul(7).wrapping_add(k))
        .collect();
    GrayFrame::owned(w, h, px).unwrap()
}

/// A 360-ray CCW scan whose times lie on the grid a reader reproduces exactly.
fn scan(k: i64) -> Scan {
    let n = 360;
    let t0 = 1_700_000_000_123_456_789 + k * 100_000_000;
    let ti = f32_as_decimal((0.1f64 / n as f64) as f32) * 1e9;
    let a0 = f64::from(-3.0f32);
    let da = f64::from((std::f64::consts::TAU / n as f64) as f32);
    let rays = (0..n)
        .map(|i| {
            let range = 1.0 + 0.01 * ((i as i64 + k) % 50) as f32;
            Ray::timed(
                wrap_pi(a0 + i as f64 * da),
                f64::from(range),
                (i % 7) as f32,
                i % 10 != 3,
                t0 + (i as f64 * ti).round() as i64,
            )
        })
        .collect();
    let timing = ScanTiming {
        start_ns: t0,
        period_ns: 100_000_000,
        rotation: Rotation::Ccw,
        start_bearing_rad: a0,
    };
    Scan::from_timed(timing, rays)
}

#[test]
fn images_round_trip_exactly() {
    let tmp = Tmp::new("images");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    w.set_log_delay_ns(3_000_000);
    let stamps: Vec<i64> = (0..5)
        .map(|k| 1_700_000_000_000_000_000 + k * 33_333_333)
        .collect();
    for (k, &t) in stamps.iter().enumerate() {
        w.write_image("/cam/image_raw", t, &frame(k as u8, 64, 48))
            .unwrap();
        w.write_compressed_png("/cam/image_raw/compressed", t, &frame(k as u8, 64, 48))
            .unwrap();
    }
    w.finish().unwrap();

    for topic in ["/cam/image_raw", "/cam/image_raw/compressed"] {
        let mut src = McapImageSource::open(&tmp.0, ImageSourceOptions::topic(topic)).unwrap();
        assert!(src.reader().is_indexed());
        assert_eq!(src.topic().message_count, Some(5));
        let mut k = 0;
        while let Some((f, t)) = src.next_frame().unwrap() {
            assert_eq!(f, frame(k as u8, 64, 48).view(), "{topic} #{k}");
            assert_eq!(t, FrameTime::Instant(stamps[k]));
            k += 1;
        }
        assert_eq!(k, 5);
        // the log time instead of the stamp
        let opts = ImageSourceOptions {
            stamp: StampSource::LogTime,
            ..ImageSourceOptions::topic(topic)
        };
        let mut src = McapImageSource::open(&tmp.0, opts).unwrap();
        let f = src.next_image().unwrap().unwrap();
        assert_eq!(f.time, FrameTime::Instant(stamps[0] + 3_000_000));
        assert_eq!((f.stamp_ns, f.index), (stamps[0], 0));
    }
}

#[test]
fn images_over_the_pixel_limit_are_refused_raw_and_compressed() {
    // 64x48 = 3072 pixels against a limit of 3000: one frame's error naming the size
    // (raw images were not bounded), before any buffer of that size is made
    let tmp = Tmp::new("images-limit");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    w.write_image("/raw", 1, &frame(0, 64, 48)).unwrap();
    w.write_image("/raw", 2, &frame(1, 32, 24)).unwrap();
    w.write_compressed_png("/png", 1, &frame(0, 64, 48))
        .unwrap();
    w.write_compressed_png("/png", 2, &frame(1, 32, 24))
        .unwrap();
    w.finish().unwrap();
    for topic in ["/raw", "/png"] {
        let opts = ImageSourceOptions {
            max_pixels: 3000,
            ..ImageSourceOptions::topic(topic)
        };
        let mut src = McapImageSource::open(&tmp.0, opts).unwrap();
        let e = src.next_frame().map(|_| ()).unwrap_err();
        assert!(e.is_one_frame(), "{topic}: {e}");
        let text = e.to_string();
        assert!(
            text.contains("image 64x48 is empty or exceeds the limit of 3000 pixels"),
            "{topic}: {text}"
        );
        // the next frame is read
        let (f, _) = src.next_frame().unwrap().unwrap();
        assert_eq!(f, frame(1, 32, 24).view(), "{topic}");
    }
}

#[test]
fn scans_round_trip_exactly() {
    let tmp = Tmp::new("scans");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    w.set_frame_id("laser");
    let scans: Vec<Scan> = (0..4).map(scan).collect();
    for s in &scans {
        w.write_scan("/scan", s).unwrap();
    }
    // an image topic beside it does not disturb schema auto-detection
    w.write_image("/cam", 1, &frame(0, 4, 4)).unwrap();
    w.finish().unwrap();

    let mut src = McapScanSource::open(&tmp.0, ScanSourceOptions::default()).unwrap();
    assert_eq!(src.topic().topic, "/scan");
    for want in &scans {
        let got = src.next_scan().unwrap().unwrap();
        assert_eq!(got.len(), want.len());
        assert_eq!(got.timing().start_ns, want.timing().start_ns);
        assert_eq!(got.timing().period_ns, 100_000_000);
        assert_eq!(got.timing().rotation, Rotation::Ccw);
        for (g, e) in got.rays().iter().zip(want.rays()) {
            assert_eq!(g.t_ns, e.t_ns);
            assert!(wrap_pi(g.bearing_rad - e.bearing_rad).abs() < 1e-9);
            assert_eq!(g.valid, e.valid);
            if e.valid {
                assert_eq!(g.range_m, e.range_m);
            }
            assert_eq!(g.intensity, e.intensity);
        }
    }
    assert!(src.next_scan().unwrap().is_none());
    assert!(src.next_scan().unwrap().is_none());
}

/// `time_increment = 0` says the rays were not spread in time, whatever `scan_time`:
/// a depth camera turned into scans (`pointcloud_to_laserscan`: `scan_time` its
/// period) and a Gazebo scan (both 0) have every ray at the stamp the source takes,
/// and the source says so; a scan with an increment is dated by it.
#[test]
fn scans_without_a_time_increment_have_every_ray_at_the_stamp() {
    use vlsync_mcap::scan::RayTiming;
    let tmp = Tmp::new("simultaneous");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    let ranges = [2.0f32; 100];
    // (time_increment, scan_time): pointcloud_to_laserscan, Gazebo, a spinning scanner
    let kinds = [(0.0f32, 1.0f32 / 30.0), (0.0, 0.0), (0.001, 0.1)];
    let mut buf = Vec::new();
    for (k, &(time_increment, scan_time)) in kinds.iter().enumerate() {
        LaserScan {
            header: vlsync_mcap::cdr::Header {
                stamp: vlsync_mcap::cdr::Time {
                    sec: 10 + k as i32,
                    nanosec: 0,
                },
                frame_id: "laser",
            },
            angle_min: -0.8,
            angle_increment: 0.016,
            time_increment,
            scan_time,
            range_max: 10.0,
            ranges: vlsync_mcap::cdr::F32Seq::from_slice(&ranges),
            ..LaserScan::default()
        }
        .encode(&mut buf)
        .unwrap();
        w.write_serialized::<LaserScan>("/scan", 20_000_000_000 + k as u64, &buf)
            .unwrap();
    }
    w.finish().unwrap();
    for stamp in [StampSource::Header, StampSource::LogTime] {
        let mut src = McapScanSource::open(
            &tmp.0,
            ScanSourceOptions {
                stamp,
                ..ScanSourceOptions::default()
            },
        )
        .unwrap();
        assert_eq!(src.ray_timing(), None);
        for (k, &(time_increment, _)) in kinds.iter().enumerate() {
            let t0 = match stamp {
                StampSource::Header => 10_000_000_000 + k as i64 * 1_000_000_000,
                StampSource::LogTime => 20_000_000_000 + k as i64,
            };
            let s = src.next_scan().unwrap().unwrap();
            assert_eq!(s.timing().start_ns, t0);
            let times: Vec<i64> = s.rays().iter().map(|r| r.t_ns).collect();
            let how = if time_increment == 0.0 {
                assert!(times.iter().all(|&t| t == t0), "{stamp:?} {k}: {times:?}");
                RayTiming::Simultaneous
            } else {
                let want: Vec<i64> = (0..100).map(|i| t0 + i * 1_000_000).collect();
                assert_eq!(times, want);
                RayTiming::Increment
            };
            assert_eq!(src.ray_timing(), Some(how), "{stamp:?} {k}");
        }
        assert_eq!(src.simultaneous_scans(), 2);
        assert!(src.next_scan().unwrap().is_none());
        assert_eq!(src.ray_timing(), None);
    }
}

#[test]
fn scans_feed_the_lidar_signature() {
    use vlsync_signature_lidar::{SignatureConfig, SignatureProcessor};
    // a flat wall ahead (normal at bearing 0) receding at 0.5 m/s, 10 scans per second
    let tmp = Tmp::new("wall");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    let n = 360usize;
    let ti = f32_as_decimal((0.1f64 / n as f64) as f32) * 1e9;
    let da = f64::from((std::f64::consts::TAU / n as f64) as f32);
    for k in 0..30i64 {
        let t0 = k * 100_000_000;
        let rays = (0..n)
            .map(|i| {
                let t = t0 + (i as f64 * ti).round() as i64;
                let b = wrap_pi(i as f64 * da);
                let r = if b.abs() < 0.6 {
                    (2.0 + 0.5 * t as f64 * 1e-9) / b.cos()
                } else {
                    6.0
                };
                Ray::timed(b, f64::from(r as f32), 0.0, true, t)
            })
            .collect();
        let timing = ScanTiming {
            start_ns: t0,
            period_ns: 100_000_000,
            rotation: Rotation::Ccw,
            start_bearing_rad: 0.0,
        };
        w.write_scan("/scan", &Scan::from_timed(timing, rays))
            .unwrap();
    }
    w.finish().unwrap();
    let mut src = McapScanSource::open(&tmp.0, ScanSourceOptions::topic("/scan")).unwrap();
    let mut sig = SignatureProcessor::new(SignatureConfig::default()).unwrap();
    let mut samples = Vec::new();
    while let Some(s) = src.next_scan().unwrap() {
        sig.push_scan(s, |x| samples.push(x));
    }
    assert!(samples.len() >= 20, "{}", samples.len());
    assert!(
        samples.iter().all(|s| (s.value - 0.5).abs() < 0.02),
        "{samples:?}"
    );
}

/// Messages come in the order they were written, indexed or not: their log times
/// going back are counted, not sorted (sorting held every chunk whose declared time
/// range had begun, which a hostile index made every chunk of the file).
#[test]
fn messages_come_in_file_order_and_log_times_going_back_are_counted() {
    let tmp = Tmp::new("order");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    for t in [30, 10, 20] {
        w.write_image("/cam", t, &frame(t as u8, 4, 4)).unwrap();
    }
    w.finish().unwrap();
    let mut r =
        McapReader::open(&tmp.0, &Select::Schema, &IMAGE_SCHEMAS, Default::default()).unwrap();
    let mut times = Vec::new();
    assert!(r.is_indexed());
    while let Some(m) = r.next_message().unwrap() {
        times.push(m.log_time);
    }
    assert_eq!(times, [30, 10, 20]);
    assert_eq!(r.out_of_order(), 1);
    // the image source says so once, for the driver's log
    let mut src = McapImageSource::open(&tmp.0, ImageSourceOptions::default()).unwrap();
    src.next_frame().unwrap().unwrap();
    assert_eq!(src.take_note(), None);
    src.next_frame().unwrap().unwrap();
    let note = src.take_note().unwrap();
    assert!(
        note.starts_with("the log times of topic `/cam` go back (message #1)"),
        "{note}"
    );
    while src.next_frame().unwrap().is_some() {}
    assert_eq!(src.take_note(), None);
}

fn err_text(r: Result<impl std::fmt::Debug, vlsync_mcap::Error>) -> String {
    r.unwrap_err().to_string()
}

/// A file of many topics (or long names) gives an error of bounded length: the list
/// stops at twenty, each name clipped.
#[test]
fn errors_list_at_most_twenty_topics_each_clipped() {
    let tmp = Tmp::new("manytopics");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    let long = "x".repeat(100_000);
    for k in 0..25 {
        w.write_image(&format!("/cam{k:02}{long}"), 1, &frame(0, 4, 4))
            .unwrap();
    }
    w.finish().unwrap();
    let e = err_text(McapImageSource::open(&tmp.0, ImageSourceOptions::default()));
    assert!(
        e.contains("several topics") && e.ends_with(" and 5 more; name one"),
        "{e}"
    );
    assert!(e.len() < 20 * 300, "{} bytes", e.len());
    let e = err_text(McapImageSource::open(
        &tmp.0,
        ImageSourceOptions::topic("/nope"),
    ));
    assert!(
        e.contains("no topic `/nope`") && e.ends_with(" and 5 more"),
        "{e}"
    );
    assert!(e.len() < 20 * 300, "{} bytes", e.len());
}

#[test]
fn wrong_topic_or_schema_is_a_clear_error() {
    let tmp = Tmp::new("schema");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    w.write_scan("/scan", &scan(0)).unwrap();
    w.write_image("/a", 1, &frame(0, 4, 4)).unwrap();
    w.write_image("/b", 1, &frame(0, 4, 4)).unwrap();
    w.finish().unwrap();
    let path = tmp.0.display().to_string();
    let e = err_text(McapImageSource::open(
        &tmp.0,
        ImageSourceOptions::topic("/scan"),
    ));
    assert!(e.starts_with(&path), "{e}");
    assert!(
        e.contains("topic `/scan` has schema `sensor_msgs/msg/LaserScan`"),
        "{e}"
    );
    let e = err_text(McapImageSource::open(&tmp.0, ImageSourceOptions::default()));
    assert!(e.contains("several topics") && e.contains("/a, /b"), "{e}");
    let e = err_text(McapScanSource::open(
        &tmp.0,
        ScanSourceOptions::topic("/nope"),
    ));
    assert!(
        e.contains("no topic `/nope`") && e.contains("`/scan` (sensor_msgs/msg/LaserScan)"),
        "{e}"
    );
    let e = err_text(McapImageSource::open(
        "/nonexistent/x.mcap",
        ImageSourceOptions::default(),
    ));
    assert!(e.starts_with("/nonexistent/x.mcap: opening"), "{e}");
}

/// A merged file with `Image` and `CompressedImage` channels on one topic: refused
/// at the start, naming both schemas (the messages were decoded as the first
/// channel's type, and each of the other's failed on its own).
#[test]
fn one_topic_of_two_schemas_is_refused() {
    use std::collections::BTreeMap;
    let tmp = Tmp::new("two-schemas");
    {
        let file = std::io::BufWriter::new(std::fs::File::create(&tmp.0).unwrap());
        let mut w = mcap::Writer::new(file).unwrap();
        for (name, text) in [
            (Image::SCHEMA_NAME, Image::SCHEMA_TEXT),
            (CompressedImage::SCHEMA_NAME, CompressedImage::SCHEMA_TEXT),
        ] {
            let schema = w.add_schema(name, "ros2msg", text.as_bytes()).unwrap();
            w.add_channel(schema, "/cam", "cdr", &BTreeMap::new())
                .unwrap();
        }
        w.finish().unwrap();
    }
    let e = err_text(McapImageSource::open(
        &tmp.0,
        ImageSourceOptions::topic("/cam"),
    ));
    assert!(
        e.contains("topic `/cam` has channels of two schemas, `sensor_msgs/msg/Image` and `sensor_msgs/msg/CompressedImage`"),
        "{e}"
    );
}

#[test]
fn bad_cdr_and_bad_encodings_name_topic_index_and_log_time() {
    let tmp = Tmp::new("badcdr");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    w.write_image("/cam", 100, &frame(0, 4, 4)).unwrap();
    // an Image whose data length claims far more than the message holds
    let mut buf = Vec::new();
    let img = Image {
        height: 4,
        width: 4,
        encoding: "mono8",
        step: 4,
        data: &[1, 2, 3],
        ..Image::default()
    };
    img.encode(&mut buf).unwrap();
    let n = buf.len();
    buf[n - 7..n - 3].copy_from_slice(&0x7fff_fff0u32.to_le_bytes());
    w.write_serialized::<Image>("/cam", 200, &buf).unwrap();
    w.finish().unwrap();
    let mut src = McapImageSource::open(&tmp.0, ImageSourceOptions::topic("/cam")).unwrap();
    assert!(src.next_frame().unwrap().is_some());
    let e = src.next_frame().unwrap_err().to_string();
    assert!(
        e.contains("topic `/cam` message #1 (log time 200 ns)")
            && e.contains("CDR field `data`")
            && e.contains(&tmp.0.display().to_string()),
        "{e}"
    );

    let tmp = Tmp::new("badenc");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    let bayer = Image {
        height: 2,
        width: 2,
        encoding: "bayer_rggb8",
        step: 2,
        data: &[0; 4],
        ..Image::default()
    };
    w.write_message("/cam", 7, &bayer).unwrap();
    let jpeg_lie = CompressedImage {
        format: "jpeg",
        data: &[0xFF, 0xD8, 0xFF, 0, 1, 2],
        ..CompressedImage::default()
    };
    w.write_message("/jpg", 8, &jpeg_lie).unwrap();
    w.finish().unwrap();
    let mut src = McapImageSource::open(&tmp.0, ImageSourceOptions::topic("/cam")).unwrap();
    let e = src.next_frame().unwrap_err().to_string();
    assert!(
        e.contains(
            "topic `/cam` message #0 (log time 7 ns): unsupported image encoding `bayer_rggb8`"
        ),
        "{e}"
    );
    let mut src = McapImageSource::open(&tmp.0, ImageSourceOptions::topic("/jpg")).unwrap();
    let e = src.next_frame().unwrap_err().to_string();
    assert!(e.contains("cannot decode `jpeg` image"), "{e}");
    // a LaserScan with a truncated ranges array
    let tmp = Tmp::new("badscan");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    let mut buf = Vec::new();
    let r = [1.0f32; 4];
    LaserScan {
        ranges: vlsync_mcap::cdr::F32Seq::from_slice(&r),
        ..LaserScan::default()
    }
    .encode(&mut buf)
    .unwrap();
    buf.truncate(buf.len() - 6);
    w.write_serialized::<LaserScan>("/scan", 5, &buf).unwrap();
    w.finish().unwrap();
    let mut src = McapScanSource::open(&tmp.0, ScanSourceOptions::default()).unwrap();
    let e = err_text(src.next_scan().map(|s| s.map(|s| s.len())));
    assert!(
        e.contains("message #0 (log time 5 ns): CDR field `ranges`"),
        "{e}"
    );
}

fn recording(name: &str) -> (Tmp, Vec<u8>) {
    let tmp = Tmp::new(name);
    let mut w = McapWriter::create(&tmp.0).unwrap();
    for k in 0..6 {
        w.write_image("/cam", 1_000 + k, &frame(k as u8, 32, 24))
            .unwrap();
        w.write_scan("/scan", &scan(k)).unwrap();
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&tmp.0).unwrap();
    (tmp, bytes)
}

/// Reads everything of both kinds; returns the frames read and the first error.
fn drain(path: &std::path::Path) -> (usize, Option<String>) {
    let mut n = 0;
    let mut first_err = None;
    match McapImageSource::open(path, ImageSourceOptions::default()) {
        Ok(mut s) => loop {
            match s.next_frame() {
                Ok(Some(_)) => n += 1,
                Ok(None) => break,
                Err(e) => {
                    first_err.get_or_insert(e.to_string());
                    break;
                }
            }
        },
        Err(e) => {
            first_err.get_or_insert(e.to_string());
        }
    }
    if let Ok(mut s) = McapScanSource::open(path, ScanSourceOptions::default()) {
        while let Ok(Some(_)) = s.next_scan() {}
    }
    let _ = McapReader::topics(path);
    (n, first_err)
}

#[test]
fn truncated_recording_yields_what_it_has_then_says_so() {
    let (tmp, bytes) = recording("trunc-src");
    let cut = Tmp::new("trunc");
    // cut inside the data section: no summary, read linearly up to the cut
    std::fs::write(&cut.0, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let mut src = McapImageSource::open(&cut.0, ImageSourceOptions::topic("/cam")).unwrap();
    assert!(!src.reader().is_indexed());
    let mut n = 0;
    let err = loop {
        match src.next_frame() {
            Ok(Some((f, _))) => {
                assert_eq!(f, frame(n as u8, 32, 24).view());
                n += 1;
            }
            Ok(None) => panic!("a truncated file must end in an error"),
            Err(e) => break e.to_string(),
        }
    };
    assert!(n >= 1, "{n}");
    assert!(err.contains(&cut.0.display().to_string()), "{err}");
    assert!(err.contains("truncated"), "{err}");
    eprintln!("truncated: {err}");
    assert!(
        err.contains(&format!("after message #{} of topic `/cam`", n - 1)),
        "{err}"
    );
    // every cut: no panic, never more frames than written
    for len in (0..bytes.len()).step_by(61) {
        std::fs::write(&cut.0, &bytes[..len]).unwrap();
        let (n, _) = drain(&cut.0);
        assert!(n <= 6);
    }
    drop(tmp);
}

#[test]
fn a_topic_missing_from_a_cut_file_is_blamed_on_the_cut() {
    // the scans come after the images: a cut early in the file has seen only the camera
    let tmp = Tmp::new("cut-topic-src");
    let mut w = McapWriter::create(&tmp.0).unwrap();
    for k in 0..6 {
        w.write_image("/cam", 1_000 + k, &frame(k as u8, 32, 24))
            .unwrap();
    }
    for k in 0..6 {
        w.write_scan("/scan", &scan(k)).unwrap();
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&tmp.0).unwrap();
    let e = McapScanSource::open(&tmp.0, ScanSourceOptions::topic("/nope"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no topic `/nope`") && !e.contains("truncated"),
        "{e}"
    );
    let cut = Tmp::new("cut-topic");
    // just before the record of the LiDAR channel
    let len = bytes.windows(5).position(|w| w == b"/scan").unwrap() - 8;
    std::fs::write(&cut.0, &bytes[..len]).unwrap();
    let e = McapScanSource::open(&cut.0, ScanSourceOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no topic with schema"), "{e}");
    assert!(
        e.ends_with(&format!(
            "the file ends at byte {len} before its footer: truncated?"
        )),
        "{e}"
    );
    // the camera reads up to the cut; the error is the file's, not an image's
    let mut src = McapImageSource::open(&cut.0, ImageSourceOptions::default()).unwrap();
    let e = loop {
        match src.next_frame() {
            Ok(Some(_)) => {}
            Ok(None) => panic!("a truncated file must end in an error"),
            Err(e) => break e,
        }
    };
    assert!(
        matches!(e, vlsync_signature_cam::Error::Read { .. }),
        "{e:?}"
    );
    let e = e.to_string();
    assert!(
        e.contains("truncated") && !e.contains("cannot decode"),
        "{e}"
    );
}

#[test]
fn a_named_pipe_is_refused_not_waited_for() {
    let dir = std::env::temp_dir().join(format!("vlsync-mcap-fifo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("run.mcap");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status();
    assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
    let e = McapImageSource::open(&fifo, ImageSourceOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("not a regular file") && e.path() == fifo,
        "{e}"
    );
    let e = McapReader::topics(&fifo).unwrap_err();
    assert!(e.to_string().contains("not a regular file"), "{e}");
    let e = McapReader::topics(&dir).unwrap_err();
    assert!(e.to_string().contains("not a regular file"), "{e}");
    // a 0-byte file is said to be empty, not a truncated recording
    let empty = dir.join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    for e in [
        McapReader::topics(&empty).unwrap_err(),
        McapImageSource::open(&empty, ImageSourceOptions::default()).unwrap_err(),
    ] {
        let t = e.to_string();
        assert!(
            t.contains("empty (0 bytes)") && !t.contains("truncated"),
            "{t}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn corrupted_chunk_is_detected() {
    let (_tmp, mut bytes) = recording("crc-src");
    // the pixels of the first frame: 0, 7, 14, ...
    let pat: Vec<u8> = frame(0, 32, 24).pixels()[..16].to_vec();
    let at = bytes
        .windows(pat.len())
        .position(|w| w == pat.as_slice())
        .unwrap();
    bytes[at + 5] ^= 0xFF;
    let bad = Tmp::new("crc");
    std::fs::write(&bad.0, &bytes).unwrap();
    let (n, err) = drain(&bad.0);
    assert_eq!(n, 0);
    let err = err.unwrap();
    assert!(
        err.contains("CRC") && err.contains(&bad.0.display().to_string()),
        "{err}"
    );
    eprintln!("corrupted: {err}");
    // without a summary the file is read from the start: a topic list that finds no
    // channel (they are in the chunk whose CRC is wrong) says why, as the reader does,
    // instead of listing none (tests/data/bad-crc-no-summary.mcap: one LaserScan
    // chunk, its CRC 1234, no summary; 328 bytes)
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bad-crc-no-summary.mcap");
    let e = McapReader::topics(&path).unwrap_err();
    assert!(e.to_string().contains("CRC"), "{e}");
    // a chunk index declaring 2^63 uncompressed bytes is named with its size and
    // chunk (tests/data/huge-chunk-index.mcap, 489 bytes; the `mcap` crate's own
    // refusal quoted the compressed size and no chunk)
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/huge-chunk-index.mcap");
    let e = McapScanSource::open(&path, ScanSourceOptions::default())
        .map(drop)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("in the summary's chunk indexes")
            && e.contains("the chunk at byte ")
            && e.contains("9223372036854775808 uncompressed"),
        "{e}"
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(data in proptest::collection::vec(any::<u8>(), 0..400),
                                   magic in any::<bool>()) {
        let tmp = Tmp::new(&format!("arb-{}", data.len()));
        let mut bytes = if magic { mcap::MAGIC.to_vec() } else { Vec::new() };
        bytes.extend_from_slice(&data);
        std::fs::write(&tmp.0, &bytes).unwrap();
        let _ = drain(&tmp.0);
    }

    #[test]
    fn corrupted_recordings_never_panic(flips in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)) {
        let (tmp, mut bytes) = recording(&format!("flip-src-{}", flips.len()));
        for (i, v) in &flips {
            let i = i.index(bytes.len());
            bytes[i] = *v;
        }
        let bad = Tmp::new(&format!("flip-{}", flips.len()));
        std::fs::write(&bad.0, &bytes).unwrap();
        let (n, _) = drain(&bad.0);
        prop_assert!(n <= 6);
        drop(tmp);
    }
}

/// The recordings with compressed chunks (`tests/data/{zstd,lz4}-chunks.mcap`):
/// 8 frames and 8 scans written by the `mcap` crate's reference (C library)
/// encoders, with small chunks so that there are many. They are checked in, so the
/// suite does not build the C libraries (zstd-sys, lz4-sys) for one test;
/// `cargo test -p vlsync-mcap --features c-encoders --test recordings -- --ignored`
/// writes them again.
#[cfg(feature = "c-encoders")]
#[test]
#[ignore = "writes the checked-in fixtures"]
fn regenerate_compressed_fixtures() {
    for (name, c) in [
        ("zstd", mcap::Compression::Zstd),
        ("lz4", mcap::Compression::Lz4),
    ] {
        write_compressed_recording(&fixture(name), c);
    }
}

/// Path of the checked-in recording with `name` chunks.
fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(format!("{name}-chunks.mcap"))
}

#[cfg(feature = "c-encoders")]
fn write_compressed_recording(path: &std::path::Path, compression: mcap::Compression) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .compression(Some(compression))
        .chunk_size(Some(4096))
        .profile("ros2")
        .create(file)
        .unwrap();
    let img_schema = w
        .add_schema(Image::SCHEMA_NAME, "ros2msg", Image::SCHEMA_TEXT.as_bytes())
        .unwrap();
    let scan_schema = w
        .add_schema(
            LaserScan::SCHEMA_NAME,
            "ros2msg",
            LaserScan::SCHEMA_TEXT.as_bytes(),
        )
        .unwrap();
    let cam = w
        .add_channel(img_schema, "/cam", "cdr", &Default::default())
        .unwrap();
    let lidar = w
        .add_channel(scan_schema, "/scan", "cdr", &Default::default())
        .unwrap();
    let mut buf = Vec::new();
    for k in 0..8u32 {
        let f = frame(k as u8, 32, 24);
        Image {
            header: vlsync_mcap::cdr::Header {
                stamp: vlsync_mcap::cdr::Time { sec: 1, nanosec: k },
                frame_id: "cam",
            },
            height: 24,
            width: 32,
            encoding: "mono8",
            step: 32,
            data: f.pixels(),
            ..Image::default()
        }
        .encode(&mut buf)
        .unwrap();
        let header = |channel_id| mcap::records::MessageHeader {
            channel_id,
            sequence: k,
            log_time: 1_000_000_000 + u64::from(k),
            publish_time: 0,
        };
        w.write_to_known_channel(&header(cam), &buf).unwrap();
        let ranges = vec![1.5f32 + k as f32; 360];
        LaserScan {
            angle_increment: 0.0174,
            time_increment: 0.0001,
            range_max: 10.0,
            ranges: vlsync_mcap::cdr::F32Seq::from_slice(&ranges),
            ..LaserScan::default()
        }
        .encode(&mut buf)
        .unwrap();
        w.write_to_known_channel(&header(lidar), &buf).unwrap();
    }
    w.finish().unwrap();
}

/// The CRC in a compressed chunk's header is checked, read through the index (the
/// `mcap` crate's indexed reader checks none) and linearly.
#[test]
fn a_compressed_chunk_with_a_wrong_crc_is_refused() {
    for name in ["zstd", "lz4"] {
        let mut bytes = std::fs::read(fixture(name)).unwrap();
        // the first chunk record at the top level (after the 8-byte magic)
        let mut at = 8;
        while bytes[at] != 0x06 {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
            at += 9 + len as usize;
        }
        // opcode, length, start, end, uncompressed size, then the CRC
        bytes[at + 33] ^= 0x5A;
        let bad = Tmp::new(&format!("{name}-crc"));
        std::fs::write(&bad.0, &bytes).unwrap();
        let cut = Tmp::new(&format!("{name}-crc-cut"));
        std::fs::write(&cut.0, &bytes[..bytes.len() - 200]).unwrap();
        for (path, indexed) in [(&bad.0, true), (&cut.0, false)] {
            let (n, err) = drain(path);
            let err =
                err.unwrap_or_else(|| panic!("{name} indexed {indexed}: no error, {n} frames"));
            assert!(
                err.contains("Chunk CRC failed"),
                "{name} indexed {indexed}: {err}"
            );
            assert!(n < 8, "{name} {n}");
        }
    }
}

/// A summary with two indexes of one chunk that disagree (the first, earliest in log
/// time, declaring just under the 256 MiB limit uncompressed) is refused at open: the size check must see
/// the index the reader uses.
#[test]
fn conflicting_indexes_of_one_chunk_are_refused() {
    for name in ["zstd", "lz4"] {
        let bytes = std::fs::read(fixture(name)).unwrap();
        // the top-level records after the magic, up to the end magic
        let mut recs: Vec<(u8, Vec<u8>)> = vec![];
        let mut at = 8;
        while at + 9 <= bytes.len() - 8 {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            recs.push((bytes[at], bytes[at + 9..at + 9 + len].to_vec()));
            at += 9 + len;
        }
        let mut out = mcap::MAGIC.to_vec();
        let mut lied = false;
        for (op, mut body) in recs {
            if op == 0x08 && !lied {
                // chunk index: message start time first, uncompressed size last
                let mut liar = body.clone();
                liar[..8].copy_from_slice(&0u64.to_le_bytes());
                let n = liar.len();
                liar[n - 8..].copy_from_slice(&((256u64 << 20) - 1).to_le_bytes());
                out.push(0x08);
                out.extend_from_slice(&(liar.len() as u64).to_le_bytes());
                out.extend_from_slice(&liar);
                lied = true;
            }
            if op == 0x02 {
                // footer: no summary offsets, no summary CRC (the summary moved)
                body[8..20].fill(0);
            }
            out.push(op);
            out.extend_from_slice(&(body.len() as u64).to_le_bytes());
            out.extend_from_slice(&body);
        }
        out.extend_from_slice(mcap::MAGIC);
        assert!(lied);
        let bad = Tmp::new(&format!("{name}-dup-index"));
        std::fs::write(&bad.0, &out).unwrap();
        let e = McapImageSource::open(&bad.0, ImageSourceOptions::topic("/cam"))
            .err()
            .unwrap_or_else(|| panic!("{name}: opened"))
            .to_string();
        assert!(
            e.contains("two indexes of the chunk at byte")
                && e.contains("uncompressed size 268435455 and"),
            "{name}: {e}"
        );
    }
}

#[test]
fn zstd_and_lz4_chunks_are_read_indexed_and_linearly() {
    for name in ["zstd", "lz4"] {
        let tmp = Tmp::new(name);
        let bytes = std::fs::read(fixture(name))
            .unwrap_or_else(|e| panic!("{}: {e}", fixture(name).display()));
        std::fs::write(&tmp.0, &bytes).unwrap();
        assert!(bytes.windows(name.len()).any(|w| w == name.as_bytes()));
        let cut = Tmp::new(&format!("{name}-cut"));
        std::fs::write(&cut.0, &bytes[..bytes.len() - 200]).unwrap();
        for (path, indexed) in [(&tmp.0, true), (&cut.0, false)] {
            reads_as_the_fixture(path, indexed, name);
        }
        // an unknown compression name: patch "zstd"/"lz4" in place
        let mut patched = bytes.clone();
        let needle = name.as_bytes();
        let mut i = 0;
        while i + needle.len() <= patched.len() {
            if &patched[i..i + needle.len()] == needle {
                patched[i] = b'x';
            }
            i += 1;
        }
        let bad = Tmp::new(&format!("{name}-unknown"));
        std::fs::write(&bad.0, &patched).unwrap();
        let (n, err) = drain(&bad.0);
        assert_eq!(n, 0);
        let err = err.unwrap();
        assert!(
            err.contains("Unsupported compression format")
                && err.contains("supported chunk compressions: none, zstd, lz4"),
            "{err}"
        );
    }
}

/// Reads `path`, a compressed fixture (or one rewritten from it), through the index
/// or linearly as `indexed` says, and checks it holds what the fixture was written
/// with.
fn reads_as_the_fixture(path: &std::path::Path, indexed: bool, what: &str) {
    let mut src = McapImageSource::open(path, ImageSourceOptions::topic("/cam")).unwrap();
    assert_eq!(src.reader().is_indexed(), indexed, "{what}");
    for k in 0..8u32 {
        let (f, t) = src
            .next_frame()
            .unwrap_or_else(|e| panic!("{what} indexed {indexed}: {e}"))
            .unwrap();
        assert_eq!(f, frame(k as u8, 32, 24).view(), "{what} {k}");
        assert_eq!(t, FrameTime::Instant(1_000_000_000 + i64::from(k)));
    }
    // (a cut file ends in an error after its last whole chunk)
    if indexed {
        assert!(src.next_frame().unwrap().is_none());
    }
    let mut scans = McapScanSource::open(path, ScanSourceOptions::default()).unwrap();
    for k in 0..8 {
        let s = scans.next_scan().unwrap().unwrap();
        assert_eq!(s.len(), 360);
        assert_eq!(s.rays()[359].range_m, f64::from(1.5f32 + k as f32));
        assert_eq!(s.rays()[10].t_ns, 1_000_000); // stamp 0 + 10 x 0.1 ms
    }
    if indexed {
        assert!(scans.next_scan().unwrap().is_none());
    }
}

/// The lz4 fixture with each chunk's records compressed again as a skippable frame
/// and two LZ4 frames (the records split in the middle), as the LZ4 frame format
/// allows and the reference MCAP readers read; the chunk indexes, summary offsets
/// and footer moved to match, the data section and summary CRCs left out.
fn lz4_fixture_in_several_frames() -> Vec<u8> {
    use std::io::{Read, Write};
    let bytes = std::fs::read(fixture("lz4")).unwrap();
    let u64_at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let u32_at = |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    let lz4 = |data: &[u8]| {
        let mut e = lz4_flex::frame::FrameEncoder::new(Vec::new());
        e.write_all(data).unwrap();
        e.finish().unwrap()
    };
    // the top-level records after the magic, up to the end magic, rewritten; where
    // each old record now starts
    let mut out = mcap::MAGIC.to_vec();
    let mut moved = std::collections::HashMap::new();
    let mut recs = vec![];
    let mut at = 8;
    let mut chunks = 0;
    while at + 9 <= bytes.len() - 8 {
        let (op, len) = (bytes[at], u64_at(&bytes, at + 1) as usize);
        let mut body = bytes[at + 9..at + 9 + len].to_vec();
        if op == 0x06 {
            // start, end, uncompressed size, CRC, compression, then the records
            let c = u32_at(&body, 28) as usize;
            assert_eq!(&body[32..32 + c], b"lz4");
            let records_at = 32 + c + 8;
            let mut records = Vec::new();
            lz4_flex::frame::FrameDecoder::new(&body[records_at..])
                .read_to_end(&mut records)
                .unwrap();
            assert_eq!(records.len() as u64, u64_at(&body, 16));
            let half = records.len() / 2;
            let mut frames = 0x184D_2A53u32.to_le_bytes().to_vec();
            frames.extend_from_slice(&4u32.to_le_bytes());
            frames.extend_from_slice(b"skip");
            frames.extend_from_slice(&lz4(&records[..half]));
            frames.extend_from_slice(&lz4(&records[half..]));
            body.truncate(32 + c);
            body.extend_from_slice(&(frames.len() as u64).to_le_bytes());
            body.extend_from_slice(&frames);
            chunks += 1;
        }
        if op == 0x0F {
            // data end: its CRC covered the old chunks
            body[..4].fill(0);
        }
        moved.insert(at as u64, out.len() as u64);
        recs.push((out.len(), op));
        out.push(op);
        out.extend_from_slice(&(body.len() as u64).to_le_bytes());
        out.extend_from_slice(&body);
        at += 9 + len;
    }
    out.extend_from_slice(mcap::MAGIC);
    assert!(chunks > 1);
    let to = |old: u64| {
        *moved
            .get(&old)
            .unwrap_or_else(|| panic!("no record at {old}"))
    };
    let put = |b: &mut Vec<u8>, at: usize, v: u64| b[at..at + 8].copy_from_slice(&v.to_le_bytes());
    for (rec_at, op) in recs {
        let body_at = rec_at + 9;
        match op {
            0x08 => {
                // chunk index: start, end, chunk offset, chunk length, message index
                // offsets (u32 byte length, then channel u16 + offset u64 each),
                // message index length, compression, compressed size, uncompressed size
                let chunk = to(u64_at(&out, body_at + 16));
                put(&mut out, body_at + 16, chunk);
                let chunk_len = 9 + u64_at(&out, chunk as usize + 1);
                put(&mut out, body_at + 24, chunk_len);
                let map_len = u32_at(&out, body_at + 32) as usize;
                let mut e = body_at + 36;
                while e < body_at + 36 + map_len {
                    let index_at = to(u64_at(&out, e + 2));
                    put(&mut out, e + 2, index_at);
                    e += 10;
                }
                let c = u32_at(&out, e + 8) as usize;
                let chunk_body = chunk as usize + 9;
                let records_len = u64_at(&out, chunk_body + 32 + c);
                put(&mut out, e + 12 + c, records_len);
            }
            0x0E => {
                // summary offset: group opcode, group start, group length
                let start = to(u64_at(&out, body_at + 1));
                put(&mut out, body_at + 1, start);
            }
            0x02 => {
                // footer: summary start, summary offset start, summary CRC
                for f in [body_at, body_at + 8] {
                    let v = to(u64_at(&out, f));
                    put(&mut out, f, v);
                }
                out[body_at + 16..body_at + 20].fill(0);
            }
            _ => {}
        }
    }
    out
}

/// A chunk may hold several LZ4 frames and skippable frames (the LZ4 frame format
/// allows both, the reference MCAP readers read them): read through the index and
/// linearly as the one-frame chunk is.
#[test]
fn lz4_chunks_of_several_frames_read_indexed_and_linearly() {
    let bytes = lz4_fixture_in_several_frames();
    let tmp = Tmp::new("lz4-frames");
    std::fs::write(&tmp.0, &bytes).unwrap();
    let cut = Tmp::new("lz4-frames-cut");
    std::fs::write(&cut.0, &bytes[..bytes.len() - 200]).unwrap();
    for (path, indexed) in [(&tmp.0, true), (&cut.0, false)] {
        reads_as_the_fixture(path, indexed, "lz4 in several frames");
    }
}

/// A writer of raw `sensor_msgs/Image` messages into `path` with `options`, and the
/// image schema's id.
fn image_writer(
    path: &std::path::Path,
    options: mcap::WriteOptions,
) -> (mcap::Writer<std::io::BufWriter<std::fs::File>>, u16) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = options.create(file).unwrap();
    let schema = w
        .add_schema(Image::SCHEMA_NAME, "ros2msg", Image::SCHEMA_TEXT.as_bytes())
        .unwrap();
    (w, schema)
}

/// [`frame`] `k` of 8x2 pixels as a raw mono8 `Image` message, into `buf`.
fn small_image(k: u8, buf: &mut Vec<u8>) {
    let f = frame(k, 8, 2);
    Image {
        height: 2,
        width: 8,
        encoding: "mono8",
        step: 8,
        data: f.pixels(),
        ..Image::default()
    }
    .encode(buf)
    .unwrap();
}

#[test]
fn unchunked_recordings_are_read_linearly() {
    let tmp = Tmp::new("unchunked");
    let (mut w, schema) = image_writer(
        &tmp.0,
        mcap::WriteOptions::new()
            .use_chunks(false)
            .compression(None),
    );
    let ch = w
        .add_channel(schema, "/cam", "cdr", &Default::default())
        .unwrap();
    let mut buf = Vec::new();
    for k in 0..3u32 {
        small_image(k as u8, &mut buf);
        let header = mcap::records::MessageHeader {
            channel_id: ch,
            sequence: k,
            log_time: u64::from(3 - k), // backwards: counted, yielded in file order
            publish_time: 0,
        };
        w.write_to_known_channel(&header, &buf).unwrap();
    }
    w.finish().unwrap();
    drop(w);
    let mut src = McapImageSource::open(&tmp.0, ImageSourceOptions::default()).unwrap();
    assert!(!src.reader().is_indexed());
    for k in 0..3u8 {
        let (f, _) = src.next_frame().unwrap().unwrap();
        assert_eq!(f, frame(k, 8, 2).view());
    }
    assert!(src.next_frame().unwrap().is_none());
    assert_eq!(src.reader().out_of_order(), 2);
}

/// A chunk over the size limit matters only to the topics it holds: another topic's
/// (a point cloud beside the scans) does not refuse the file.
#[test]
fn an_oversized_chunk_of_another_topic_does_not_refuse_the_file() {
    let tmp = Tmp::new("bigother");
    {
        let (mut w, schema) = image_writer(&tmp.0, mcap::WriteOptions::new().compression(None));
        let cam = w
            .add_channel(schema, "/cam", "cdr", &Default::default())
            .unwrap();
        let blob = w
            .add_channel(schema, "/blob", "cdr", &Default::default())
            .unwrap();
        let header = |channel_id, t| mcap::records::MessageHeader {
            channel_id,
            sequence: 0,
            log_time: t,
            publish_time: t,
        };
        let mut buf = Vec::new();
        for k in 0..3u8 {
            small_image(k, &mut buf);
            w.write_to_known_channel(&header(cam, u64::from(k)), &buf)
                .unwrap();
        }
        // the camera's chunk ends here; the next holds only the 2 MiB blob
        w.flush().unwrap();
        w.write_to_known_channel(&header(blob, 10), &vec![0u8; 2 << 20])
            .unwrap();
        w.finish().unwrap();
    }
    let opts = vlsync_mcap::ReaderOptions {
        max_record_bytes: 1 << 20,
    };
    let mut r = McapReader::open(
        &tmp.0,
        &Select::Topic("/cam".into()),
        &vlsync_mcap::IMAGE_SCHEMAS,
        opts,
    )
    .unwrap();
    assert!(r.is_indexed());
    let mut n = 0;
    while r.next_message().unwrap().is_some() {
        n += 1;
    }
    assert_eq!(n, 3);
    let e = McapReader::open(
        &tmp.0,
        &Select::Topic("/blob".into()),
        &vlsync_mcap::IMAGE_SCHEMAS,
        opts,
    )
    .map(drop)
    .unwrap_err()
    .to_string();
    assert!(e.contains("over the limit of 1048576"), "{e}");
}
