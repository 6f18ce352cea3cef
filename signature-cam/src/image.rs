//! Grayscale frames and conversion of raw camera buffers (gray, RGB, BGR, RGBA, YUYV,
//! UYVY, and the planar 4:2:0 NV12, NV21, YU12, YV12 by their luma plane) to gray.
//!
//! A [`GrayFrame`] is a `width x height` row-major array of `u8` or `f32` pixels,
//! borrowed from a caller's buffer or owned. Pixel values are on the 0..=255 gray
//! scale for both pixel types (the flow thresholds assume that scale).
//!
//! ```
//! use vlsync_signature_cam::image::{GrayFrame, PixelFormat, RawFrame};
//! // 2x1 YUYV: Y0 U Y1 V
//! let yuyv = [10u8, 128, 200, 128];
//! let gray = RawFrame::new(&yuyv, 2, 1, PixelFormat::Yuyv).to_gray().unwrap();
//! assert_eq!(gray.pixels(), &[10, 200]);
//! let view = GrayFrame::borrowed(2, 1, gray.pixels()).unwrap();
//! assert_eq!(view.get(1, 0), Some(200));
//! ```

use crate::Error;
use std::borrow::Cow;

/// A gray pixel type: `u8` or `f32`, on the 0..=255 scale.
pub trait Pixel: Copy + Send + Sync + 'static {
    /// The value as `f32`.
    fn to_f32(self) -> f32;
}

impl Pixel for u8 {
    #[inline]
    fn to_f32(self) -> f32 {
        f32::from(self)
    }
}

impl Pixel for f32 {
    #[inline]
    fn to_f32(self) -> f32 {
        self
    }
}

/// A grayscale frame, row-major, no padding between rows.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayFrame<'a, T: Pixel> {
    width: usize,
    height: usize,
    data: Cow<'a, [T]>,
}

/// Checks `width * height` without overflow and rejects empty frames.
pub(crate) fn pixel_count(width: usize, height: usize) -> Result<usize, Error> {
    if width == 0 || height == 0 {
        return Err(Error::BadDimensions {
            width,
            height,
            reason: "width and height must be positive",
        });
    }
    width.checked_mul(height).ok_or(Error::BadDimensions {
        width,
        height,
        reason: "width * height overflows",
    })
}

impl<'a, T: Pixel> GrayFrame<'a, T> {
    /// Wraps pixel data; `data.len()` must be exactly `width * height`.
    pub fn new(width: usize, height: usize, data: impl Into<Cow<'a, [T]>>) -> Result<Self, Error> {
        let data = data.into();
        let n = pixel_count(width, height)?;
        if data.len() != n {
            return Err(Error::BufferSize {
                what: format!("gray {width}x{height}"),
                expected: n,
                actual: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Borrows a caller's buffer (no copy).
    pub fn borrowed(width: usize, height: usize, data: &'a [T]) -> Result<Self, Error> {
        Self::new(width, height, data)
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// All pixels, row-major.
    pub fn pixels(&self) -> &[T] {
        &self.data
    }

    /// One row, `None` past the last.
    pub fn row(&self, y: usize) -> Option<&[T]> {
        if y >= self.height {
            return None;
        }
        self.data.get(y * self.width..(y + 1) * self.width)
    }

    /// The pixel at `(x, y)`, `None` outside the frame.
    pub fn get(&self, x: usize, y: usize) -> Option<T> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.data.get(y * self.width + x).copied()
    }

    /// A borrowed view of this frame.
    pub fn view(&self) -> GrayFrame<'_, T> {
        GrayFrame {
            width: self.width,
            height: self.height,
            data: Cow::Borrowed(&self.data),
        }
    }

    /// An owned copy (no copy if already owned).
    pub fn into_owned(self) -> GrayFrame<'static, T> {
        GrayFrame {
            width: self.width,
            height: self.height,
            data: Cow::Owned(self.data.into_owned()),
        }
    }
}

impl GrayFrame<'static, u8> {
    /// Takes ownership of a buffer; `data.len()` must be `width * height`.
    pub fn owned(width: usize, height: usize, data: Vec<u8>) -> Result<Self, Error> {
        Self::new(width, height, data)
    }
}

impl GrayFrame<'static, f32> {
    /// Takes ownership of an `f32` buffer; `data.len()` must be `width * height`.
    pub fn owned_f32(width: usize, height: usize, data: Vec<f32>) -> Result<Self, Error> {
        Self::new(width, height, data)
    }
}

/// Layout of a raw camera buffer.
///
/// The planar 4:2:0 formats (`Nv12`, `Nv21`, `Yu12`, `Yv12`) start with their luma
/// plane, `height` rows `stride` bytes apart; gray is that plane, and the chroma
/// planes after it are not read (nor required to be in the buffer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    /// 8-bit gray, 1 byte per pixel (V4L2 `GREY`).
    Gray8,
    /// 8-bit R, G, B: 3 bytes per pixel (V4L2 `RGB3`).
    Rgb8,
    /// 8-bit B, G, R: 3 bytes per pixel (V4L2 `BGR3`).
    Bgr8,
    /// 8-bit R, G, B, A: 4 bytes per pixel.
    Rgba8,
    /// Packed YUV 4:2:2, `Y0 U Y1 V` (V4L2 `YUYV`): 2 bytes per pixel, even width.
    Yuyv,
    /// Packed YUV 4:2:2, `U Y0 V Y1` (V4L2 `UYVY`): 2 bytes per pixel, even width.
    Uyvy,
    /// Planar YUV 4:2:0, a luma plane then one plane of interleaved Cb Cr (V4L2 `NV12`).
    Nv12,
    /// Planar YUV 4:2:0, a luma plane then one plane of interleaved Cr Cb (V4L2 `NV21`).
    Nv21,
    /// Planar YUV 4:2:0, a luma plane then a Cb and a Cr plane (V4L2 `YU12`, I420).
    Yu12,
    /// Planar YUV 4:2:0, a luma plane then a Cr and a Cb plane (V4L2 `YV12`).
    Yv12,
}

impl PixelFormat {
    /// Every layout, for tests and listings.
    pub const ALL: [PixelFormat; 10] = [
        PixelFormat::Gray8,
        PixelFormat::Rgb8,
        PixelFormat::Bgr8,
        PixelFormat::Rgba8,
        PixelFormat::Yuyv,
        PixelFormat::Uyvy,
        PixelFormat::Nv12,
        PixelFormat::Nv21,
        PixelFormat::Yu12,
        PixelFormat::Yv12,
    ];

    /// Bytes per pixel of a row of the buffer's first plane, the one `stride` steps
    /// through (YUYV and UYVY: 2, averaged over a pixel pair; the planar 4:2:0
    /// formats: 1, their luma plane).
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Gray8
            | PixelFormat::Nv12
            | PixelFormat::Nv21
            | PixelFormat::Yu12
            | PixelFormat::Yv12 => 1,
            PixelFormat::Yuyv | PixelFormat::Uyvy => 2,
            PixelFormat::Rgb8 | PixelFormat::Bgr8 => 3,
            PixelFormat::Rgba8 => 4,
        }
    }

    /// Whether a row holds pixel pairs (YUYV, UYVY): the width must be even.
    pub fn packed_pairs(self) -> bool {
        matches!(self, PixelFormat::Yuyv | PixelFormat::Uyvy)
    }

    /// The V4L2 four-character code of the layout (`None`: RGBA, which the V4L2
    /// source does not ask for).
    pub fn fourcc(self) -> Option<[u8; 4]> {
        Some(match self {
            PixelFormat::Gray8 => *b"GREY",
            PixelFormat::Rgb8 => *b"RGB3",
            PixelFormat::Bgr8 => *b"BGR3",
            PixelFormat::Rgba8 => return None,
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Uyvy => *b"UYVY",
            PixelFormat::Nv12 => *b"NV12",
            PixelFormat::Nv21 => *b"NV21",
            PixelFormat::Yu12 => *b"YU12",
            PixelFormat::Yv12 => *b"YV12",
        })
    }

    /// The layout of a V4L2 four-character code, if it is one of these.
    ///
    /// ```
    /// use vlsync_signature_cam::PixelFormat;
    /// assert_eq!(PixelFormat::from_fourcc(b"NV12"), Some(PixelFormat::Nv12));
    /// assert_eq!(PixelFormat::from_fourcc(b"MJPG"), None);
    /// ```
    pub fn from_fourcc(code: &[u8; 4]) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|f| f.fourcc().as_ref() == Some(code))
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            PixelFormat::Gray8 => "GRAY8",
            PixelFormat::Rgb8 => "RGB8",
            PixelFormat::Bgr8 => "BGR8",
            PixelFormat::Rgba8 => "RGBA8",
            PixelFormat::Yuyv => "YUYV",
            PixelFormat::Uyvy => "UYVY",
            PixelFormat::Nv12 => "NV12",
            PixelFormat::Nv21 => "NV21",
            PixelFormat::Yu12 => "YU12",
            PixelFormat::Yv12 => "YV12",
        }
    }
}

/// A raw camera buffer: bytes, geometry, layout and row stride.
#[derive(Debug, Clone, Copy)]
pub struct RawFrame<'a> {
    /// The bytes.
    pub data: &'a [u8],
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Bytes from one row to the next (V4L2 `bytesperline`; of the luma plane for
    /// the planar formats); at least `width * bytes_per_pixel`.
    pub stride: usize,
    /// Layout.
    pub format: PixelFormat,
}

/// BT.601 luma with 8-bit fixed-point weights (77, 150, 29) / 256.
#[inline]
fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((77 * u32::from(r) + 150 * u32::from(g) + 29 * u32::from(b) + 128) >> 8) as u8
}

impl<'a> RawFrame<'a> {
    /// A tightly packed buffer (stride = `width * bytes_per_pixel`, saturating).
    pub fn new(data: &'a [u8], width: usize, height: usize, format: PixelFormat) -> Self {
        Self {
            data,
            width,
            height,
            stride: width.saturating_mul(format.bytes_per_pixel()),
            format,
        }
    }

    /// Sets the row stride in bytes.
    pub fn with_stride(mut self, stride: usize) -> Self {
        self.stride = stride;
        self
    }

    /// The bytes the conversion reads, `(height - 1) * stride + width * bytes per
    /// pixel` (a buffer at least this long converts), or the error of a geometry no
    /// buffer converts with. Checks nothing of the buffer itself, and allocates only
    /// for that error: a live source checks each buffer's length against it first
    /// and skips a short one without making an error.
    pub fn bytes_needed(&self) -> Result<usize, Error> {
        let (w, h) = (self.width, self.height);
        pixel_count(w, h)?;
        if self.format.packed_pairs() && !w.is_multiple_of(2) {
            return Err(Error::BadDimensions {
                width: w,
                height: h,
                reason: match self.format {
                    PixelFormat::Uyvy => "UYVY needs an even width",
                    _ => "YUYV needs an even width",
                },
            });
        }
        let row = w
            .checked_mul(self.format.bytes_per_pixel())
            .ok_or(Error::BadDimensions {
                width: w,
                height: h,
                reason: "row size overflows",
            })?;
        if self.stride < row {
            return Err(Error::BufferSize {
                what: self.described(),
                expected: row,
                actual: self.stride,
            });
        }
        // the last row needs only `row` bytes, not a full stride (and a planar
        // format's chroma planes after the luma are not read)
        (h - 1)
            .checked_mul(self.stride)
            .and_then(|v| v.checked_add(row))
            .ok_or(Error::BadDimensions {
                width: w,
                height: h,
                reason: "buffer size overflows",
            })
    }

    /// The buffer as an error names it, e.g. `YUYV 640x480 (stride 1280)`.
    fn described(&self) -> String {
        let (w, h) = (self.width, self.height);
        format!("{} {w}x{h} (stride {})", self.format.name(), self.stride)
    }

    /// Checks geometry against the buffer; returns the number of gray pixels.
    fn check(&self) -> Result<usize, Error> {
        let need = self.bytes_needed()?;
        if self.data.len() < need {
            return Err(Error::BufferSize {
                what: self.described(),
                expected: need,
                actual: self.data.len(),
            });
        }
        pixel_count(self.width, self.height)
    }

    /// Converts to gray into `out` (resized to `width * height`; reuses its capacity,
    /// so a steady stream of same-size frames allocates nothing).
    pub fn to_gray_into(&self, out: &mut Vec<u8>) -> Result<(), Error> {
        let n = self.check()?;
        out.resize(n, 0);
        let w = self.width;
        let bpp = self.format.bytes_per_pixel();
        for (y, dst) in out.chunks_exact_mut(w).enumerate() {
            let start = y * self.stride;
            let src = &self.data[start..start + w * bpp];
            match self.format {
                // the planar formats' luma plane is a gray image
                PixelFormat::Gray8
                | PixelFormat::Nv12
                | PixelFormat::Nv21
                | PixelFormat::Yu12
                | PixelFormat::Yv12 => dst.copy_from_slice(src),
                PixelFormat::Rgb8 => {
                    for (d, s) in dst.iter_mut().zip(src.chunks_exact(3)) {
                        *d = luma(s[0], s[1], s[2]);
                    }
                }
                PixelFormat::Bgr8 => {
                    for (d, s) in dst.iter_mut().zip(src.chunks_exact(3)) {
                        *d = luma(s[2], s[1], s[0]);
                    }
                }
                PixelFormat::Rgba8 => {
                    for (d, s) in dst.iter_mut().zip(src.chunks_exact(4)) {
                        *d = luma(s[0], s[1], s[2]);
                    }
                }
                PixelFormat::Yuyv => {
                    // luma is every other byte
                    for (d, s) in dst.iter_mut().zip(src.iter().step_by(2)) {
                        *d = *s;
                    }
                }
                PixelFormat::Uyvy => {
                    // luma is every other byte, from the second
                    for (d, s) in dst.iter_mut().zip(src.iter().skip(1).step_by(2)) {
                        *d = *s;
                    }
                }
            }
        }
        Ok(())
    }

    /// Converts to an owned gray frame.
    pub fn to_gray(&self) -> Result<GrayFrame<'static, u8>, Error> {
        let mut out = Vec::new();
        self.to_gray_into(&mut out)?;
        GrayFrame::owned(self.width, self.height, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn frame_rejects_wrong_length_and_zero_size() {
        assert!(matches!(
            GrayFrame::borrowed(3, 2, &[0u8; 5]),
            Err(Error::BufferSize {
                expected: 6,
                actual: 5,
                ..
            })
        ));
        assert!(matches!(
            GrayFrame::<u8>::borrowed(0, 2, &[]),
            Err(Error::BadDimensions { .. })
        ));
        assert!(matches!(
            GrayFrame::<u8>::borrowed(usize::MAX, 2, &[]),
            Err(Error::BadDimensions { .. })
        ));
    }

    #[test]
    fn accessors() {
        let f = GrayFrame::owned_f32(2, 2, vec![1.0, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(f.row(1), Some(&[3.0f32, 4.0][..]));
        assert_eq!(f.row(2), None);
        assert_eq!(f.get(2, 0), None);
        assert_eq!(f.view().get(1, 1), Some(4.0));
        assert_eq!(f.into_owned().width(), 2);
    }

    #[test]
    fn rgb_variants_agree() {
        let rgb = [255u8, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255];
        let bgr = [0u8, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 255];
        let rgba = [255u8, 0, 0, 9, 0, 255, 0, 9, 0, 0, 255, 9, 255, 255, 255, 9];
        let a = RawFrame::new(&rgb, 4, 1, PixelFormat::Rgb8)
            .to_gray()
            .unwrap();
        let b = RawFrame::new(&bgr, 4, 1, PixelFormat::Bgr8)
            .to_gray()
            .unwrap();
        let c = RawFrame::new(&rgba, 4, 1, PixelFormat::Rgba8)
            .to_gray()
            .unwrap();
        assert_eq!(a.pixels(), &[77, 149, 29, 255]);
        assert_eq!(a, b);
        assert_eq!(a, c);
    }

    #[test]
    fn stride_is_honoured() {
        // 2x2 gray with 3 bytes per row, last row unpadded
        let buf = [1u8, 2, 99, 3, 4];
        let g = RawFrame::new(&buf, 2, 2, PixelFormat::Gray8)
            .with_stride(3)
            .to_gray()
            .unwrap();
        assert_eq!(g.pixels(), &[1, 2, 3, 4]);
        let short = RawFrame::new(&buf, 2, 2, PixelFormat::Gray8).with_stride(1);
        assert!(matches!(short.to_gray(), Err(Error::BufferSize { .. })));
    }

    #[test]
    fn yuyv_errors() {
        let buf = [0u8; 12];
        assert!(matches!(
            RawFrame::new(&buf, 3, 2, PixelFormat::Yuyv).to_gray(),
            Err(Error::BadDimensions { .. })
        ));
        let e = RawFrame::new(&buf, 4, 2, PixelFormat::Yuyv)
            .to_gray()
            .unwrap_err();
        assert!(e.to_string().contains("YUYV 4x2"), "{e}");
    }

    /// 4x2 frames with 2 bytes of padding per row (stride > row), the padding and
    /// the chroma filled with 0xEE, which must never reach the gray image.
    #[test]
    fn every_format_converts_a_padded_frame() {
        const P: u8 = 0xEE;
        let want = [10u8, 20, 30, 40, 50, 60, 70, 80];
        // YUYV: Y0 U Y1 V; the last row without its padding
        let yuyv = [
            10, P, 20, P, 30, P, 40, P, /* pad */ P, P, //
            50, P, 60, P, 70, P, 80, P,
        ];
        // UYVY: U Y0 V Y1
        let uyvy = [
            P, 10, P, 20, P, 30, P, 40, P, P, //
            P, 50, P, 60, P, 70, P, 80,
        ];
        for (fmt, buf, stride) in [
            (PixelFormat::Yuyv, &yuyv[..], 10),
            (PixelFormat::Uyvy, &uyvy[..], 10),
        ] {
            let g = RawFrame::new(buf, 4, 2, fmt)
                .with_stride(stride)
                .to_gray()
                .unwrap();
            assert_eq!(g.pixels(), &want, "{fmt:?}");
        }
        // the planar 4:2:0 formats: a luma plane of 2 rows, stride 6, then chroma
        // (NV12/NV21: one 2x1 plane of pairs, stride 6; YU12/YV12: two 2x1 planes,
        // stride 3) that is not read
        let mut planar = vec![10, 20, 30, 40, P, P, 50, 60, 70, 80, P, P];
        planar.extend([P; 6]);
        for fmt in [
            PixelFormat::Nv12,
            PixelFormat::Nv21,
            PixelFormat::Yu12,
            PixelFormat::Yv12,
        ] {
            let g = RawFrame::new(&planar, 4, 2, fmt)
                .with_stride(6)
                .to_gray()
                .unwrap();
            assert_eq!(g.pixels(), &want, "{fmt:?}");
            // a buffer cut after the luma plane still holds the whole gray image...
            let luma_only = RawFrame::new(&planar[..10], 4, 2, fmt).with_stride(6);
            assert_eq!(luma_only.to_gray().unwrap().pixels(), &want, "{fmt:?}");
            // ...one cut inside it does not: a short buffer, skippable
            let cut = RawFrame::new(&planar[..9], 4, 2, fmt).with_stride(6);
            assert!(
                matches!(
                    cut.to_gray(),
                    Err(Error::BufferSize {
                        expected: 10,
                        actual: 9,
                        ..
                    })
                ),
                "{fmt:?}"
            );
        }
        // gray, RGB and BGR with padding
        let grey = [10u8, 20, 30, 40, P, 50, 60, 70, 80];
        let g = RawFrame::new(&grey, 4, 2, PixelFormat::Gray8)
            .with_stride(5)
            .to_gray()
            .unwrap();
        assert_eq!(g.pixels(), &want);
        let rgb: Vec<u8> = [10u8, 20, 30, 40]
            .iter()
            .flat_map(|&v| [v, v, v])
            .chain([P, P])
            .chain([50u8, 60, 70, 80].iter().flat_map(|&v| [v, v, v]))
            .collect();
        for fmt in [PixelFormat::Rgb8, PixelFormat::Bgr8] {
            let g = RawFrame::new(&rgb, 4, 2, fmt)
                .with_stride(14)
                .to_gray()
                .unwrap();
            assert_eq!(g.pixels(), &want, "{fmt:?}");
        }
    }

    #[test]
    fn a_stride_shorter_than_a_row_and_short_buffers_are_errors() {
        for fmt in PixelFormat::ALL {
            let row = 4 * fmt.bytes_per_pixel();
            let buf = vec![0u8; 4 * row];
            // a stride one byte short of a row
            let e = RawFrame::new(&buf, 4, 2, fmt)
                .with_stride(row - 1)
                .to_gray()
                .unwrap_err();
            assert!(matches!(e, Error::BufferSize { .. }), "{fmt:?}: {e}");
            // exactly enough: one stride and a row
            assert!(RawFrame::new(&buf[..2 * row + row], 4, 2, fmt)
                .with_stride(2 * row)
                .to_gray()
                .is_ok());
            // one byte less
            let e = RawFrame::new(&buf[..3 * row - 1], 4, 2, fmt)
                .with_stride(2 * row)
                .to_gray()
                .unwrap_err();
            assert!(
                matches!(e, Error::BufferSize { expected, actual, .. }
                    if expected == 3 * row && actual == 3 * row - 1),
                "{fmt:?}: {e}"
            );
            // the length a live source checks a buffer against before converting it,
            // whatever the buffer holds
            let frame = |data| RawFrame::new(data, 4, 2, fmt).with_stride(2 * row);
            assert_eq!(frame(&[]).bytes_needed().unwrap(), 3 * row, "{fmt:?}");
            assert_eq!(frame(&buf).bytes_needed().unwrap(), 3 * row, "{fmt:?}");
            assert!(matches!(
                RawFrame::new(&buf, 4, 2, fmt)
                    .with_stride(row - 1)
                    .bytes_needed(),
                Err(Error::BufferSize { .. })
            ));
        }
        // UYVY, as YUYV, needs pixel pairs
        let e = RawFrame::new(&[0u8; 12], 3, 2, PixelFormat::Uyvy)
            .to_gray()
            .unwrap_err();
        assert!(e.to_string().contains("UYVY needs an even width"), "{e}");
        // the planar formats read their luma plane at any width
        assert!(RawFrame::new(&[0u8; 6], 3, 2, PixelFormat::Nv12)
            .to_gray()
            .is_ok());
    }

    #[test]
    fn fourcc_codes_round_trip() {
        for fmt in PixelFormat::ALL {
            match fmt.fourcc() {
                Some(code) => assert_eq!(PixelFormat::from_fourcc(&code), Some(fmt)),
                None => assert_eq!(fmt, PixelFormat::Rgba8),
            }
        }
        for code in [b"MJPG", b"H264", b"BA81", b"NM12", b"\0\0\0\0"] {
            assert_eq!(PixelFormat::from_fourcc(code), None);
        }
    }

    proptest! {
        /// Any buffer length, stride, size and layout: an error or a gray image of
        /// `w * h` pixels, never a panic or a slice out of bounds.
        #[test]
        fn conversion_never_panics(
            data in proptest::collection::vec(any::<u8>(), 0..400),
            w in 0usize..24, h in 0usize..24,
            stride in prop_oneof![0usize..120, any::<usize>()],
            f in 0usize..PixelFormat::ALL.len(),
        ) {
            let fmt = PixelFormat::ALL[f];
            let raw = RawFrame::new(&data, w, h, fmt).with_stride(stride);
            if let Ok(g) = raw.to_gray() {
                prop_assert_eq!(g.pixels().len(), w * h);
            }
        }

        /// Huge dimensions (a hostile driver's) are errors, not overflows.
        #[test]
        fn huge_geometry_is_an_error(
            w in any::<usize>(), h in any::<usize>(), stride in any::<usize>(),
            f in 0usize..PixelFormat::ALL.len(),
        ) {
            let raw = RawFrame::new(&[0u8; 64], w, h, PixelFormat::ALL[f]).with_stride(stride);
            if let Ok(g) = raw.to_gray() {
                prop_assert_eq!(g.pixels().len(), w * h);
                prop_assert!(w * h <= 64);
            }
        }

        /// Padding after each row changes nothing: the gray image of a padded
        /// buffer is the tight one's.
        #[test]
        fn padding_is_skipped(
            seed in proptest::collection::vec(any::<u8>(), 1..200),
            half_w in 1usize..6, h in 1usize..6, pad in 0usize..7,
            f in 0usize..PixelFormat::ALL.len(),
        ) {
            let fmt = PixelFormat::ALL[f];
            let w = 2 * half_w;
            let row = w * fmt.bytes_per_pixel();
            let tight: Vec<u8> = (0..row * h).map(|i| seed[i % seed.len()]).collect();
            let mut padded = Vec::new();
            for r in tight.chunks(row) {
                padded.extend_from_slice(r);
                padded.extend(std::iter::repeat_n(0xEEu8, pad));
            }
            let a = RawFrame::new(&tight, w, h, fmt).to_gray().unwrap();
            let b = RawFrame::new(&padded, w, h, fmt).with_stride(row + pad).to_gray().unwrap();
            prop_assert_eq!(a, b);
        }

        #[test]
        fn gray_of_gray_rgb_is_identity(v in proptest::collection::vec(any::<u8>(), 1..64)) {
            let rgb: Vec<u8> = v.iter().flat_map(|&x| [x, x, x]).collect();
            let g = RawFrame::new(&rgb, v.len(), 1, PixelFormat::Rgb8).to_gray().unwrap();
            prop_assert_eq!(g.pixels(), &v[..]);
        }
    }
}
