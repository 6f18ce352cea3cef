//! Camera frames from `sensor_msgs/msg/Image` or `sensor_msgs/msg/CompressedImage`
//! messages, as a [`FrameSource`] for the camera front-end.
//!
//! # Frame time
//!
//! By default a frame's time is its `header.stamp` ([`StampSource::Header`]):
//! `Image.msg` asks for the acquisition time there, and ROS camera drivers
//! usually stamp the capture (or the driver's receive) time. With
//! [`StampSource::LogTime`] the MCAP log time (when the recorder received the
//! message) is used instead, for drivers whose stamps are unusable; it includes
//! the transport latency.
//!
//! # Encodings
//!
//! `Image`: `mono8` (also `8UC1`), `rgb8`, `bgr8`, `rgba8`, `yuv422_yuy2` /
//! `yuyv` (Y0 U Y1 V) and `yuv422` / `uyvy` (U Y0 V Y1, what ROS calls
//! `yuv422`), with any row `step` at least the packed row. Colour is reduced to
//! BT.601 luma by `vlsync_signature_cam::RawFrame`. Any other encoding (16-bit,
//! Bayer, `bgra8`, float) is an error naming the topic, the message index and
//! the encoding.
//!
//! `CompressedImage`: PNG and JPEG, recognised by their signature bytes (the
//! `format` field, e.g. `bgr8; jpeg compressed bgr8`, is only used in error
//! messages); `compressedDepth` and other codecs are errors. Both kinds are
//! bounded by [`ImageSourceOptions::max_pixels`] (decoding also by bytes: 4 per
//! pixel of that limit).
//!
//! Raw images allocate nothing per message after the first (buffers are
//! reused); PNG/JPEG decoders allocate their own working memory per image.

use crate::cdr::{CdrMessage, CompressedImage, Image};
use crate::error::Error;
use crate::read::{McapReader, ReaderOptions, Select, TopicInfo};
use image::{ColorType, ImageDecoder};
use std::path::Path;
use vlsync_signature_cam::{FrameSource, FrameTime, GrayFrame, PixelFormat, RawFrame};

/// Which time stands for a message's instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StampSource {
    /// `header.stamp` (default).
    #[default]
    Header,
    /// The MCAP log time (receive time of the recorder).
    LogTime,
}

/// The schemas an image topic may have.
pub const IMAGE_SCHEMAS: [&str; 2] = [Image::SCHEMA_NAME, CompressedImage::SCHEMA_NAME];

/// Options of [`McapImageSource`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ImageSourceOptions {
    /// Topic, or [`Select::Schema`] for the only image topic.
    pub select: Select,
    /// Frame time.
    pub stamp: StampSource,
    /// Reader limits.
    pub reader: ReaderOptions,
    /// Largest image, raw or decoded PNG/JPEG, pixels (default 64 Mpx); a decoded
    /// image may take at most 4 bytes per pixel of that (16-bit or alpha images
    /// accordingly fewer pixels).
    pub max_pixels: u64,
}

impl Default for ImageSourceOptions {
    fn default() -> Self {
        Self {
            select: Select::Schema,
            stamp: StampSource::Header,
            reader: ReaderOptions::default(),
            max_pixels: 64 << 20,
        }
    }
}

impl ImageSourceOptions {
    /// Options reading `topic`.
    pub fn topic(topic: impl Into<String>) -> Self {
        Self {
            select: Select::Topic(topic.into()),
            ..Self::default()
        }
    }
}

/// One decoded frame with where it came from.
#[derive(Debug)]
pub struct ImageFrame<'a> {
    /// The gray frame (borrows the source's buffer).
    pub frame: GrayFrame<'a, u8>,
    /// Its time (see the module docs).
    pub time: FrameTime,
    /// `header.stamp`, ns.
    pub stamp_ns: i64,
    /// MCAP log time, ns.
    pub log_time: u64,
    /// 0-based index of the message on the topic.
    pub index: u64,
}

/// Gray frames from an image topic of an MCAP file (see the module docs).
///
/// ```
/// use vlsync_mcap::{ImageSourceOptions, McapImageSource, McapWriter};
/// use vlsync_signature_cam::{FrameSource, FrameTime, GrayFrame};
/// let path = std::env::temp_dir().join(format!("vlsync-mcap-doc-img-{}.mcap", std::process::id()));
/// let mut w = McapWriter::create(&path).unwrap();
/// let f = GrayFrame::owned(4, 2, (0..8).collect()).unwrap();
/// w.write_image("/cam/image_raw", 1_000_000_007, &f).unwrap();
/// w.write_compressed_png("/cam/png", 2_000_000_000, &f).unwrap();
/// w.finish().unwrap();
/// let mut src = McapImageSource::open(&path, ImageSourceOptions::topic("/cam/image_raw")).unwrap();
/// let (frame, time) = src.next_frame().unwrap().unwrap();
/// assert_eq!(frame, f.view());
/// assert_eq!(time, FrameTime::Instant(1_000_000_007));
/// assert!(src.next_frame().unwrap().is_none());
/// // two image topics: naming none is an error that lists them
/// let e = McapImageSource::open(&path, ImageSourceOptions::default()).unwrap_err();
/// assert!(e.to_string().contains("/cam/png"), "{e}");
/// # std::fs::remove_file(&path).unwrap();
/// ```
#[derive(Debug)]
pub struct McapImageSource {
    reader: McapReader,
    compressed: bool,
    stamp: StampSource,
    max_pixels: u64,
    gray: Vec<u8>,
    scratch: Vec<u8>,
    /// Whether [`FrameSource::take_note`] said that log times went back.
    told_back: bool,
}

impl McapImageSource {
    /// Opens a recording and selects the image topic.
    pub fn open(path: impl AsRef<Path>, options: ImageSourceOptions) -> Result<Self, Error> {
        let reader = McapReader::open(path, &options.select, &IMAGE_SCHEMAS, options.reader)?;
        let compressed = reader.topic().schema_name == CompressedImage::SCHEMA_NAME;
        Ok(Self {
            reader,
            compressed,
            stamp: options.stamp,
            max_pixels: options.max_pixels,
            gray: Vec::new(),
            scratch: Vec::new(),
            told_back: false,
        })
    }

    /// The topic read.
    pub fn topic(&self) -> &TopicInfo {
        self.reader.topic()
    }

    /// The underlying reader (order, counters).
    pub fn reader(&self) -> &McapReader {
        &self.reader
    }

    /// The next frame, `Ok(None)` at the end of the topic.
    pub fn next_image(&mut self) -> Result<Option<ImageFrame<'_>>, Error> {
        let Self {
            reader,
            compressed,
            stamp,
            max_pixels,
            gray,
            scratch,
            ..
        } = self;
        let Some(msg) = reader.next_message()? else {
            return Ok(None);
        };
        let (index, log_time) = (msg.index, msg.log_time);
        let result = if *compressed {
            CompressedImage::decode(msg.data)
                .map_err(|e| e.to_string())
                .and_then(|m| {
                    decode_compressed(&m, *max_pixels, gray, scratch).map(|wh| (wh, m.header.stamp))
                })
        } else {
            Image::decode(msg.data)
                .map_err(|e| e.to_string())
                .and_then(|m| {
                    within_pixels(m.width, m.height, *max_pixels)?;
                    raw_to_gray(&m, gray).map(|wh| (wh, m.header.stamp))
                })
        };
        let fail = |reason: String| Error::Message {
            path: reader.path().to_path_buf(),
            at: crate::error::MessageAt {
                topic: reader.topic().topic.clone(),
                index,
                log_time,
            },
            reason,
        };
        let ((w, h), header_stamp) = result.map_err(fail)?;
        let stamp_ns = header_stamp.to_nanos();
        let time = match stamp {
            StampSource::Header => stamp_ns,
            StampSource::LogTime => i64::try_from(log_time)
                .map_err(|_| fail(format!("log time {log_time} ns does not fit i64")))?,
        };
        let frame = GrayFrame::borrowed(w, h, gray).map_err(|e| fail(e.to_string()))?;
        Ok(Some(ImageFrame {
            frame,
            time: FrameTime::Instant(time),
            stamp_ns,
            log_time,
            index,
        }))
    }
}

impl FrameSource for McapImageSource {
    /// An image that cannot be used becomes `vlsync_signature_cam::Error::Decode`
    /// (one frame's error, `is_one_frame`: the next call reads the next message),
    /// an error of the file itself (malformed, truncated) `Error::Read`; both name
    /// the file, with the topic, message index and log time in the reason.
    fn next_frame(
        &mut self,
    ) -> Result<Option<(GrayFrame<'_, u8>, FrameTime)>, vlsync_signature_cam::Error> {
        match self.next_image() {
            Ok(Some(f)) => Ok(Some((f.frame, f.time))),
            Ok(None) => Ok(None),
            Err(e @ Error::Message { .. }) => Err(vlsync_signature_cam::Error::Decode {
                path: e.path().to_path_buf(),
                reason: e.detail(),
            }),
            Err(e) => Err(vlsync_signature_cam::Error::Read {
                path: e.path().to_path_buf(),
                reason: e.detail(),
            }),
        }
    }

    /// Once, when the recording's log times first go back: its messages come in file
    /// order, not sorted ([`crate::read`]).
    fn take_note(&mut self) -> Option<String> {
        let back = self.reader.out_of_order();
        if back == 0 || self.told_back {
            return None;
        }
        self.told_back = true;
        Some(format!(
            "the log times of topic `{}` go back (message #{}): its frames come in the \
             order the recording holds them, not sorted; a frame stamped before the one \
             before it is refused as going backwards",
            vlsync_common::text::clip(&self.reader.topic().topic),
            self.reader.messages_read().saturating_sub(1)
        ))
    }
}

/// Converts a raw `Image` to gray in `out`; returns width and height.
pub fn raw_to_gray(m: &Image<'_>, out: &mut Vec<u8>) -> Result<(usize, usize), String> {
    let (w, h) = (m.width as usize, m.height as usize);
    let stride = m.step as usize;
    let format = match m.encoding {
        "mono8" | "8UC1" => PixelFormat::Gray8,
        "rgb8" => PixelFormat::Rgb8,
        "bgr8" => PixelFormat::Bgr8,
        "rgba8" => PixelFormat::Rgba8,
        "yuv422_yuy2" | "yuyv" => PixelFormat::Yuyv,
        "yuv422" | "uyvy" => return uyvy_to_gray(m.data, w, h, stride, out).map(|()| (w, h)),
        other => {
            return Err(format!(
                "unsupported image encoding `{}` (supported: mono8, 8UC1, rgb8, bgr8, rgba8, \
                 yuv422_yuy2/yuyv, yuv422/uyvy)",
                vlsync_common::text::clip(other)
            ))
        }
    };
    RawFrame::new(m.data, w, h, format)
        .with_stride(stride)
        .to_gray_into(out)
        .map_err(|e| e.to_string())?;
    Ok((w, h))
}

/// UYVY (U Y0 V Y1): luma is every odd byte.
fn uyvy_to_gray(
    data: &[u8],
    w: usize,
    h: usize,
    stride: usize,
    out: &mut Vec<u8>,
) -> Result<(), String> {
    if w == 0 || h == 0 || !w.is_multiple_of(2) {
        return Err(format!(
            "UYVY {w}x{h}: needs a non-zero size and an even width"
        ));
    }
    let row = w * 2;
    let need = (h - 1)
        .checked_mul(stride)
        .and_then(|v| v.checked_add(row))
        .ok_or_else(|| format!("UYVY {w}x{h} (step {stride}): size overflows"))?;
    if stride < row || data.len() < need {
        return Err(format!(
            "UYVY {w}x{h} (step {stride}): needs a step of at least {row} and {need} bytes, has {}",
            data.len()
        ));
    }
    out.resize(w * h, 0);
    for (y, dst) in out.chunks_exact_mut(w).enumerate() {
        let src = &data[y * stride..y * stride + row];
        for (d, s) in dst.iter_mut().zip(src.iter().skip(1).step_by(2)) {
            *d = *s;
        }
    }
    Ok(())
}

/// Decodes a PNG or JPEG `CompressedImage` to gray in `gray`; returns width and height.
pub fn decode_compressed(
    m: &CompressedImage<'_>,
    max_pixels: u64,
    gray: &mut Vec<u8>,
    scratch: &mut Vec<u8>,
) -> Result<(usize, usize), String> {
    let cursor = std::io::Cursor::new(m.data);
    let what = |e: image::ImageError| {
        format!(
            "cannot decode `{}` image: {e}",
            vlsync_common::text::clip(m.format)
        )
    };
    if m.data.starts_with(b"\x89PNG\r\n\x1a\n") {
        let d = image::codecs::png::PngDecoder::new(cursor).map_err(what)?;
        decode_with(d, max_pixels, gray, scratch).map_err(what)
    } else if m.data.starts_with(&[0xFF, 0xD8, 0xFF]) {
        let d = image::codecs::jpeg::JpegDecoder::new(cursor).map_err(what)?;
        decode_with(d, max_pixels, gray, scratch).map_err(what)
    } else {
        Err(format!(
            "unsupported compressed image format `{}` (supported: png, jpeg; the data starts with \
             neither signature)",
            vlsync_common::text::clip(m.format)
        ))
    }
}

/// Refuses an image of no pixels or of more than `max_pixels`.
fn within_pixels(w: u32, h: u32, max_pixels: u64) -> Result<(), String> {
    let pixels = u64::from(w) * u64::from(h);
    if pixels == 0 || pixels > max_pixels {
        return Err(format!(
            "image {w}x{h} is empty or exceeds the limit of {max_pixels} pixels"
        ));
    }
    Ok(())
}

/// Bytes a decoded image may take: 4 per pixel of the limit (an 8-bit RGBA image
/// at the limit; 16-bit or alpha images accordingly fewer pixels).
fn decoded_bytes_limit(max_pixels: u64) -> u64 {
    max_pixels.saturating_mul(4)
}

fn decode_with(
    mut d: impl ImageDecoder,
    max_pixels: u64,
    gray: &mut Vec<u8>,
    scratch: &mut Vec<u8>,
) -> image::ImageResult<(usize, usize)> {
    let other = |e: String| image::ImageError::IoError(std::io::Error::other(e));
    let (w, h) = d.dimensions();
    within_pixels(w, h, max_pixels).map_err(other)?;
    let bytes = decoded_bytes_limit(max_pixels);
    if d.total_bytes() > bytes {
        return Err(other(format!(
            "image {w}x{h} ({:?}) decodes to {} bytes, over the limit of {bytes}",
            d.color_type(),
            d.total_bytes()
        )));
    }
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(bytes);
    d.set_limits(limits)?;
    let (w, h) = (w as usize, h as usize);
    let total = usize::try_from(d.total_bytes()).unwrap_or(usize::MAX);
    let format = match d.color_type() {
        ColorType::L8 => {
            gray.resize(total, 0);
            d.read_image(gray)?;
            return Ok((w, h));
        }
        ColorType::Rgb8 => PixelFormat::Rgb8,
        ColorType::Rgba8 => PixelFormat::Rgba8,
        _ => {
            // the gray image's own buffer becomes the frame's (no third copy)
            *gray = image::DynamicImage::from_decoder(d)?
                .into_luma8()
                .into_raw();
            return Ok((w, h));
        }
    };
    scratch.resize(total, 0);
    d.read_image(scratch)?;
    RawFrame::new(scratch, w, h, format)
        .to_gray_into(gray)
        .map_err(|e| image::ImageError::IoError(std::io::Error::other(e.to_string())))?;
    Ok((w, h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::Header;
    use proptest::prelude::*;

    fn img<'a>(enc: &'a str, w: u32, h: u32, step: u32, data: &'a [u8]) -> Image<'a> {
        Image {
            header: Header::default(),
            height: h,
            width: w,
            encoding: enc,
            is_bigendian: 0,
            step,
            data,
        }
    }

    #[test]
    fn encodings_to_gray() {
        let mut out = Vec::new();
        assert_eq!(
            raw_to_gray(&img("mono8", 2, 1, 3, &[5, 6, 99]), &mut out),
            Ok((2, 1))
        );
        assert_eq!(out, [5, 6]);
        raw_to_gray(&img("bgr8", 1, 1, 3, &[0, 0, 255]), &mut out).unwrap();
        assert_eq!(out, [77]);
        raw_to_gray(&img("rgb8", 1, 1, 3, &[255, 0, 0]), &mut out).unwrap();
        assert_eq!(out, [77]);
        raw_to_gray(&img("rgba8", 1, 1, 4, &[255, 0, 0, 1]), &mut out).unwrap();
        assert_eq!(out, [77]);
        raw_to_gray(&img("yuv422_yuy2", 2, 1, 4, &[10, 1, 20, 2]), &mut out).unwrap();
        assert_eq!(out, [10, 20]);
        // UYVY with a padded row
        let uyvy = [1, 10, 2, 20, 0, 3, 30, 4, 40];
        raw_to_gray(&img("yuv422", 2, 2, 5, &uyvy), &mut out).unwrap();
        assert_eq!(out, [10, 20, 30, 40]);
        let e = raw_to_gray(&img("bayer_rggb8", 2, 2, 2, &[0; 4]), &mut out).unwrap_err();
        assert!(e.contains("`bayer_rggb8`"), "{e}");
        assert!(raw_to_gray(&img("mono8", 4, 4, 4, &[0; 15]), &mut out).is_err());
        assert!(raw_to_gray(&img("uyvy", 2, 2, 4, &[0; 7]), &mut out).is_err());
        assert!(raw_to_gray(&img("uyvy", 3, 1, 6, &[0; 6]), &mut out).is_err());
    }

    /// `img` as PNG bytes.
    fn png_of<P, C>(img: &image::ImageBuffer<P, C>) -> Vec<u8>
    where
        P: image::PixelWithColorType,
        [P::Subpixel]: image::EncodableLayout,
        C: std::ops::Deref<Target = [P::Subpixel]>,
    {
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        png
    }

    /// A `CompressedImage` of PNG bytes.
    fn png_message(png: &[u8]) -> CompressedImage<'_> {
        CompressedImage {
            header: Header::default(),
            format: "png",
            data: png,
        }
    }

    #[test]
    fn compressed_png_and_garbage() {
        let png = png_of(&image::GrayImage::from_raw(3, 2, vec![1, 2, 3, 4, 5, 6]).unwrap());
        let m = png_message(&png);
        let (mut gray, mut scratch) = (Vec::new(), Vec::new());
        assert_eq!(
            decode_compressed(&m, 100, &mut gray, &mut scratch),
            Ok((3, 2))
        );
        assert_eq!(gray, [1, 2, 3, 4, 5, 6]);
        assert!(decode_compressed(&m, 5, &mut gray, &mut scratch)
            .unwrap_err()
            .contains("limit of 5 pixels"));
        let bad = CompressedImage {
            data: &png[..20],
            ..m
        };
        assert!(decode_compressed(&bad, 100, &mut gray, &mut scratch).is_err());
        let tiff = CompressedImage {
            format: "tiff",
            data: b"II*\0",
            ..m
        };
        let e = decode_compressed(&tiff, 100, &mut gray, &mut scratch).unwrap_err();
        assert!(e.contains("`tiff`"), "{e}");
    }

    #[test]
    fn a_decoded_image_is_bounded_by_bytes_too() {
        // 16-bit RGBA, 4x2: 64 bytes decoded. A limit of 10 pixels allows 40 bytes:
        // refused before decoding (such an image at the pixel limit took 8 bytes a
        // pixel, twice over); at 16 pixels (64 bytes) it decodes to its luma
        let px: Vec<u16> = (0..8)
            .flat_map(|i| [i * 8000, i * 8000, i * 8000, 65535])
            .collect();
        let png = png_of(&image::ImageBuffer::<image::Rgba<u16>, _>::from_raw(4, 2, px).unwrap());
        let m = png_message(&png);
        let (mut gray, mut scratch) = (Vec::new(), Vec::new());
        let e = decode_compressed(&m, 10, &mut gray, &mut scratch).unwrap_err();
        assert!(
            e.contains("image 4x2 (Rgba16) decodes to 64 bytes, over the limit of 40"),
            "{e}"
        );
        assert_eq!(
            decode_compressed(&m, 16, &mut gray, &mut scratch),
            Ok((4, 2))
        );
        let want: Vec<u8> = (0..8u32)
            .map(|i| ((i * 8000) as f64 / 257.0).round() as u8)
            .collect();
        assert_eq!(gray, want);
    }

    #[test]
    fn colour_png_and_jpeg() {
        let (mut gray, mut scratch) = (Vec::new(), Vec::new());
        // RGB PNG: luma of pure red, green, blue, white
        let rgb =
            image::RgbImage::from_raw(4, 1, vec![255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255])
                .unwrap();
        let mut png = Vec::new();
        rgb.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let m = CompressedImage {
            header: Header::default(),
            format: "rgb8; png compressed rgb8",
            data: &png,
        };
        assert_eq!(
            decode_compressed(&m, 100, &mut gray, &mut scratch),
            Ok((4, 1))
        );
        assert_eq!(gray, [77, 149, 29, 255]);
        // gray JPEG: lossy, but a flat image stays flat
        let flat = image::GrayImage::from_pixel(16, 8, image::Luma([100]));
        let mut jpg = Vec::new();
        flat.write_to(
            &mut std::io::Cursor::new(&mut jpg),
            image::ImageFormat::Jpeg,
        )
        .unwrap();
        let m = CompressedImage {
            format: "jpeg",
            data: &jpg,
            ..m
        };
        assert_eq!(
            decode_compressed(&m, 1000, &mut gray, &mut scratch),
            Ok((16, 8))
        );
        assert!(gray.iter().all(|&v| v.abs_diff(100) <= 2), "{gray:?}");
    }

    proptest! {
        #[test]
        fn hostile_images_never_panic(
            enc in prop_oneof![Just("mono8"), Just("rgb8"), Just("bgr8"), Just("rgba8"),
                Just("yuyv"), Just("yuv422"), Just("16UC1")],
            w in any::<u32>(), h in any::<u32>(), step in any::<u32>(),
            data in proptest::collection::vec(any::<u8>(), 0..64),
            small in any::<bool>(),
        ) {
            let (w, h, step) = if small { (w % 9, h % 9, step % 40) } else { (w, h, step) };
            let mut out = Vec::new();
            if let Ok((w, h)) = raw_to_gray(&img(enc, w, h, step, &data), &mut out) {
                prop_assert_eq!(out.len(), w * h);
            }
            let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
            png.extend_from_slice(&data);
            let mut jpg = vec![0xFF, 0xD8, 0xFF];
            jpg.extend_from_slice(&data);
            for d in [&png, &jpg, &data] {
                let m = CompressedImage { header: Header::default(), format: "", data: d };
                let _ = decode_compressed(&m, 1 << 20, &mut out, &mut Vec::new());
            }
        }
    }
}
