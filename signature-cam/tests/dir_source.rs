//! A directory of PNG/JPEG frames with `frames.csv`, end to end through the
//! signature processor, and the error paths of the directory source.

use std::fs;
use std::path::{Path, PathBuf};
use vlsync_signature_cam::{
    DirSource, Error, FrameSource, SignatureConfig, SignatureProcessor, Step,
};

/// A fresh scratch directory under the system temp dir.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vlsync-sigcam-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    fs::create_dir_all(&d).unwrap();
    d
}

/// A 320x240 textured gray image moved down by `dy` px.
fn texture(dy: f32) -> image::GrayImage {
    image::GrayImage::from_fn(320, 240, |x, y| {
        let (u, v) = (x as f32, y as f32 - dy);
        let g = 128.0 + 50.0 * (0.21 * u + 0.07 * v).sin() + 40.0 * (0.13 * v - 0.17 * u).cos();
        image::Luma([g.clamp(0.0, 255.0).round() as u8])
    })
}

#[test]
fn png_and_jpeg_frames_give_midpoint_samples() {
    let dir = scratch("ok");
    // 3 px per frame down; frames 33 ms apart, exposure 4 ms starting 2 ms before t_s
    let mut csv = String::from("# test frames\nfile,t_s,exposure_start_s,exposure_s\n");
    for k in 0..4 {
        let name = if k == 2 {
            format!("f{k}.jpg")
        } else {
            format!("f{k}.png")
        };
        let img = texture(3.0 * k as f32);
        if k == 2 {
            let rgb = image::DynamicImage::ImageLuma8(img).to_rgb8();
            let mut out = fs::File::create(dir.join(&name)).unwrap();
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
                .encode_image(&rgb)
                .unwrap();
        } else {
            img.save(dir.join(&name)).unwrap();
        }
        let t = 100.0 + 0.033 * k as f64;
        csv += &format!("{name},{t:.9},{:.9},0.004\n", t - 0.002);
    }
    fs::write(dir.join("frames.csv"), csv).unwrap();

    let mut src = DirSource::open(&dir).unwrap();
    assert_eq!(src.entries().len(), 4);
    let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
    let mut samples = Vec::new();
    while let Some((frame, time)) = src.next_frame().unwrap() {
        assert_eq!((frame.width(), frame.height()), (320, 240));
        if let Step::Sample(s) = p.process(&frame, time).unwrap() {
            samples.push(s);
        }
    }
    assert_eq!(samples.len(), 3);
    for (k, s) in samples.iter().enumerate() {
        // mid-exposure of frame k is t_k exactly; the sample sits between k and k+1
        let expect_t = 100_000_000_000 + 33_000_000 * k as i64 + 16_500_000;
        assert_eq!(s.sample.t_ns, expect_t);
        // 3 px / 33 ms = 90.9 px/s (JPEG frames a bit noisier)
        assert!((s.sample.value - 90.909).abs() < 3.0, "{s:?}");
        assert!(!s.low_texture());
    }
    fs::remove_dir_all(&dir).unwrap();
}

fn err_of(dir: &Path) -> Error {
    DirSource::open(dir).unwrap_err()
}

#[test]
fn errors_name_file_and_line() {
    let dir = scratch("err");
    // no frames.csv
    let e = err_of(&dir);
    assert!(e.to_string().contains("frames.csv"), "{e}");

    // a missing frame
    texture(0.0).save(dir.join("a.png")).unwrap();
    fs::write(dir.join("frames.csv"), "a.png,1.0\nmissing.png,1.1\n").unwrap();
    let e = err_of(&dir);
    let msg = e.to_string();
    assert!(matches!(e, Error::MissingFrame { line: 2, .. }), "{msg}");
    assert!(
        msg.contains("missing.png") && msg.contains("frames.csv:2"),
        "{msg}"
    );

    // a bad time
    fs::write(dir.join("frames.csv"), "a.png,1.0\na.png,1.1s\n").unwrap();
    let msg = err_of(&dir).to_string();
    assert!(
        msg.contains("frames.csv:2:") && msg.contains("1.1s"),
        "{msg}"
    );

    // a file that is not an image: the error comes when it is read, naming it
    fs::write(dir.join("junk.png"), b"not an image").unwrap();
    fs::write(dir.join("frames.csv"), "a.png,1.0\njunk.png,1.1\n").unwrap();
    let mut src = DirSource::open(&dir).unwrap();
    assert!(src.next_frame().unwrap().is_some());
    let e = src.next_frame().unwrap_err();
    assert!(matches!(e, Error::Decode { .. }), "{e}");
    assert!(e.to_string().contains("junk.png"), "{e}");
    // the stream goes on after a bad frame, then ends
    assert!(src.next_frame().unwrap().is_none());
    fs::remove_dir_all(&dir).unwrap();
}

/// CRC-32 (IEEE) of PNG chunks.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 == 1 {
                (c >> 1) ^ 0xEDB8_8320
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A PNG of a few dozen bytes whose header declares a `w`x`h` 8-bit gray image
/// (the pixel data is a valid but empty zlib stream).
fn huge_png(w: u32, h: u32) -> Vec<u8> {
    let chunk = |kind: &[u8], data: &[u8]| -> Vec<u8> {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        let body = [kind, data].concat();
        c.extend_from_slice(&body);
        c.extend_from_slice(&crc32(&body).to_be_bytes());
        c
    };
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]); // 8-bit gray, deflate, no filter, no interlace
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    png.extend(chunk(
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    ));
    png.extend(chunk(b"IEND", &[]));
    png
}

#[test]
fn huge_declared_images_are_refused_before_decoding() {
    let dir = scratch("huge");
    texture(0.0).save(dir.join("a.png")).unwrap();
    // 22000x22000 (484 Mpx: 1.5 GB resident before the limit) and a 40000 px wide strip
    fs::write(dir.join("big.png"), huge_png(22_000, 22_000)).unwrap();
    fs::write(dir.join("wide.png"), huge_png(40_000, 10)).unwrap();
    fs::write(
        dir.join("frames.csv"),
        "a.png,1.0\nbig.png,1.1\nwide.png,1.2\na.png,1.3\n",
    )
    .unwrap();
    let mut src = DirSource::open(&dir).unwrap();
    assert!(src.next_frame().unwrap().is_some());
    let e = src.next_frame().unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, Error::Decode { .. }), "{msg}");
    assert!(
        msg.contains("big.png") && msg.contains("22000x22000 exceeds the limit"),
        "{msg}"
    );
    let e = src.next_frame().unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("wide.png") && msg.contains("limit"), "{msg}");
    // nothing accepted is lost: the next frame decodes
    let (f, _) = src.next_frame().unwrap().unwrap();
    assert_eq!((f.width(), f.height()), (320, 240));
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn named_pipes_are_refused_not_waited_for() {
    let dir = scratch("fifo");
    let made = |p: &Path| {
        std::process::Command::new("mkfifo")
            .arg(p)
            .status()
            .is_ok_and(|s| s.success())
    };
    // frames.csv itself a FIFO without a writer: an error at once, not a hang
    assert!(made(&dir.join("frames.csv")), "mkfifo");
    let msg = err_of(&dir).to_string();
    assert!(
        msg.contains("frames.csv") && msg.contains("not a regular file"),
        "{msg}"
    );
    // a FIFO listed as a frame
    fs::remove_file(dir.join("frames.csv")).unwrap();
    assert!(made(&dir.join("pipe.png")));
    fs::write(dir.join("frames.csv"), "pipe.png,1.0\n").unwrap();
    let msg = err_of(&dir).to_string();
    assert!(
        msg.contains("pipe.png") && msg.contains("not a regular file"),
        "{msg}"
    );
    fs::remove_dir_all(&dir).unwrap();
}
