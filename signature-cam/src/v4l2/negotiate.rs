//! What an opening of a V4L2 device decides from the driver's answers, as plain
//! functions of those answers, so that every decision and every message is tested
//! without a camera: whether the node is a single-planar streaming capture node
//! ([`check_caps`]), which of its formats to read ([`choose_format`]), whether the
//! negotiated geometry can be read ([`check_geometry`]), the frame interval for a
//! rate ([`interval_for_fps`]), the exposure's verdict ([`Exposure`]), the hint an
//! error number gives ([`io_reason`]), the buffers queued before the stream starts
//! ([`queue_all`]), the one line that says what was negotiated
//! ([`Negotiated`]), and the guard that turns a panic of the `v4l` crate on a
//! driver's answer into an error naming the device ([`guarded`]).

use super::FrameStamps;
use crate::image::{pixel_count, PixelFormat};
use crate::Error;
use std::fmt;
use std::path::{Path, PathBuf};

/// `V4L2_CAP_*` bits of `VIDIOC_QUERYCAP` (`linux/videodev2.h`).
pub mod cap {
    /// `V4L2_CAP_VIDEO_CAPTURE`: single-planar video capture.
    pub const VIDEO_CAPTURE: u32 = 0x0000_0001;
    /// `V4L2_CAP_VIDEO_OUTPUT`.
    pub const VIDEO_OUTPUT: u32 = 0x0000_0002;
    /// `V4L2_CAP_VIDEO_OVERLAY`.
    pub const VIDEO_OVERLAY: u32 = 0x0000_0004;
    /// `V4L2_CAP_VBI_CAPTURE`.
    pub const VBI_CAPTURE: u32 = 0x0000_0010;
    /// `V4L2_CAP_VIDEO_CAPTURE_MPLANE`: multi-planar video capture (CSI receivers,
    /// ISPs: the Raspberry Pi's camera nodes).
    pub const VIDEO_CAPTURE_MPLANE: u32 = 0x0000_1000;
    /// `V4L2_CAP_VIDEO_OUTPUT_MPLANE`.
    pub const VIDEO_OUTPUT_MPLANE: u32 = 0x0000_2000;
    /// `V4L2_CAP_VIDEO_M2M_MPLANE`: a memory-to-memory device (codec, scaler).
    pub const VIDEO_M2M_MPLANE: u32 = 0x0000_4000;
    /// `V4L2_CAP_VIDEO_M2M`.
    pub const VIDEO_M2M: u32 = 0x0000_8000;
    /// `V4L2_CAP_TUNER`.
    pub const TUNER: u32 = 0x0001_0000;
    /// `V4L2_CAP_RADIO`.
    pub const RADIO: u32 = 0x0004_0000;
    /// `V4L2_CAP_SDR_CAPTURE`.
    pub const SDR_CAPTURE: u32 = 0x0010_0000;
    /// `V4L2_CAP_META_CAPTURE`: metadata capture (a UVC camera's second node).
    pub const META_CAPTURE: u32 = 0x0080_0000;
    /// `V4L2_CAP_READWRITE`: `read()` I/O.
    pub const READWRITE: u32 = 0x0100_0000;
    /// `V4L2_CAP_STREAMING`: streaming I/O (mapped buffers), what this source uses.
    pub const STREAMING: u32 = 0x0400_0000;
    /// `V4L2_CAP_META_OUTPUT`.
    pub const META_OUTPUT: u32 = 0x0800_0000;
    /// `V4L2_CAP_TOUCH`.
    pub const TOUCH: u32 = 0x1000_0000;
    /// `V4L2_CAP_DEVICE_CAPS`: `device_caps` holds the node's own capabilities.
    pub const DEVICE_CAPS: u32 = 0x8000_0000;

    /// Names of the bits above, for messages.
    pub const NAMES: [(u32, &str); 18] = [
        (VIDEO_CAPTURE, "VIDEO_CAPTURE"),
        (VIDEO_OUTPUT, "VIDEO_OUTPUT"),
        (VIDEO_OVERLAY, "VIDEO_OVERLAY"),
        (VBI_CAPTURE, "VBI_CAPTURE"),
        (VIDEO_CAPTURE_MPLANE, "VIDEO_CAPTURE_MPLANE"),
        (VIDEO_OUTPUT_MPLANE, "VIDEO_OUTPUT_MPLANE"),
        (VIDEO_M2M_MPLANE, "VIDEO_M2M_MPLANE"),
        (VIDEO_M2M, "VIDEO_M2M"),
        (TUNER, "TUNER"),
        (RADIO, "RADIO"),
        (SDR_CAPTURE, "SDR_CAPTURE"),
        (META_CAPTURE, "META_CAPTURE"),
        (READWRITE, "READWRITE"),
        (STREAMING, "STREAMING"),
        (META_OUTPUT, "META_OUTPUT"),
        (TOUCH, "TOUCH"),
        (DEVICE_CAPS, "DEVICE_CAPS"),
        (0x0020_0000, "EXT_PIX_FORMAT"),
    ];
}

/// Capability bits as names (`VIDEO_CAPTURE | STREAMING`), unknown bits in hex.
pub fn cap_names(caps: u32) -> String {
    let mut names: Vec<String> = cap::NAMES
        .iter()
        .filter(|(bit, _)| caps & bit != 0)
        .map(|(_, n)| (*n).to_string())
        .collect();
    let known = cap::NAMES.iter().fold(0, |a, (bit, _)| a | bit);
    if caps & !known != 0 {
        names.push(format!("{:#010x}", caps & !known));
    }
    if names.is_empty() {
        "none".into()
    } else {
        names.join(" | ")
    }
}

/// Who the device says it is (`VIDEO_QUERYCAP`'s `card`, `driver`, `bus_info`).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct DeviceId {
    /// The card's name, e.g. `HD Pro Webcam C920` (a UVC camera's USB product string).
    pub card: String,
    /// The kernel driver, e.g. `uvcvideo`.
    pub driver: String,
    /// Where it is attached, e.g. `usb-0000:00:14.0-2`.
    pub bus: String,
}

impl fmt::Display for DeviceId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?} (driver {}", self.card, self.driver)?;
        if !self.bus.is_empty() {
            write!(f, ", {}", self.bus)?;
        }
        write!(f, ")")
    }
}

fn device_error(path: &Path, reason: String) -> Error {
    Error::Device {
        path: path.to_path_buf(),
        reason,
    }
}

/// Checks that a node can be read by this source: single-planar video capture
/// (`V4L2_CAP_VIDEO_CAPTURE`) with streaming I/O (`V4L2_CAP_STREAMING`) among
/// `caps`, the node's own capabilities (`device_caps`, which every driver fills since
/// Linux 3.3, and without which newer kernels do not register a video node; the
/// `v4l` crate reports only them, not `capabilities` nor its `V4L2_CAP_DEVICE_CAPS`
/// flag). The error names the device, its card and
/// driver, and what is missing, with the way out for the usual cases: a UVC
/// camera's metadata node, a multi-planar CSI node (a Raspberry Pi camera module,
/// which needs libcamera).
///
/// ```
/// use vlsync_signature_cam::v4l2::negotiate::{cap, check_caps, DeviceId};
/// let id = DeviceId { card: "USB Camera".into(), driver: "uvcvideo".into(), bus: String::new() };
/// let path = std::path::Path::new("/dev/video1");
/// assert!(check_caps(path, &id, cap::VIDEO_CAPTURE | cap::STREAMING).is_ok());
/// let e = check_caps(path, &id, cap::META_CAPTURE | cap::STREAMING).unwrap_err();
/// assert!(e.to_string().starts_with("/dev/video1: \"USB Camera\" (driver uvcvideo) is a metadata node"));
/// ```
pub fn check_caps(path: &Path, id: &DeviceId, caps: u32) -> Result<(), Error> {
    let err = |what: String| Err(device_error(path, format!("{id} {what}")));
    if caps == 0 {
        return err(
            "reports no capabilities (VIDIOC_QUERYCAP's device_caps is 0, as no driver since \
             Linux 3.3 leaves it), so it cannot be checked to be a video capture node"
                .into(),
        );
    }
    if caps & cap::VIDEO_CAPTURE == 0 {
        if caps & cap::META_CAPTURE != 0 {
            return err(format!(
                "is a metadata node (V4L2_CAP_META_CAPTURE), not a video capture node: point \
                 --v4l2 at the camera's capture node (a UVC camera's first node, e.g. \
                 /dev/video0, or its /dev/v4l/by-id/...-video-index0 link); capabilities: {}",
                cap_names(caps)
            ));
        }
        if caps & cap::VIDEO_CAPTURE_MPLANE != 0 {
            return err(format!(
                "is a multi-planar capture node (V4L2_CAP_VIDEO_CAPTURE_MPLANE), which this \
                 source does not read: a Raspberry Pi camera module (CSI) needs libcamera, and \
                 can reach vlsync through a ROS 2 recording (--mcap) for now; capabilities: {}",
                cap_names(caps)
            ));
        }
        return err(format!(
            "has no single-planar video capture (V4L2_CAP_VIDEO_CAPTURE): not a camera's \
             capture node; capabilities: {}",
            cap_names(caps)
        ));
    }
    if caps & cap::STREAMING == 0 {
        return err(format!(
            "captures video but without streaming I/O (V4L2_CAP_STREAMING), which this source \
             needs (it maps the driver's buffers; read() I/O is not supported); capabilities: {}",
            cap_names(caps)
        ));
    }
    Ok(())
}

/// A four-character code as text: its characters when printable, else hex (and
/// `-BE` for the big-endian flag, bit 31).
pub fn fourcc_text(code: [u8; 4]) -> String {
    let mut c = code;
    let be = c[3] & 0x80 != 0;
    c[3] &= 0x7f;
    if c.iter().all(|b| b.is_ascii_graphic() || *b == b' ') {
        let s: String = c.iter().map(|&b| char::from(b)).collect();
        let s = s.trim_end().to_string();
        if be {
            format!("{s}-BE")
        } else {
            s
        }
    } else {
        format!("{:#010x}", u32::from_le_bytes(code))
    }
}

/// One format `VIDIOC_ENUM_FMT` lists.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Offered {
    /// Its four-character code.
    pub fourcc: [u8; 4],
    /// The driver's description, e.g. `Motion-JPEG`.
    pub description: String,
    /// `V4L2_FMT_FLAG_COMPRESSED`.
    pub compressed: bool,
}

impl fmt::Display for Offered {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", fourcc_text(self.fourcc))?;
        let d = self.description.trim();
        if !d.is_empty() {
            write!(f, " ({d})")?;
        }
        Ok(())
    }
}

/// The formats this source reads, best first: the cheapest to reduce to gray, which
/// also take the least USB bandwidth (GREY: 1 byte a pixel, copied; the planar 4:2:0
/// formats: 1.5, their luma plane copied; YUYV, UYVY: 2, every other byte; RGB3,
/// BGR3: 3, a weighted sum).
pub const PREFERENCE: [PixelFormat; 9] = [
    PixelFormat::Gray8,
    PixelFormat::Nv12,
    PixelFormat::Nv21,
    PixelFormat::Yu12,
    PixelFormat::Yv12,
    PixelFormat::Yuyv,
    PixelFormat::Uyvy,
    PixelFormat::Rgb8,
    PixelFormat::Bgr8,
];

/// The four-character codes of [`PREFERENCE`], for messages.
pub fn readable_codes() -> String {
    PREFERENCE
        .iter()
        .filter_map(|f| f.fourcc())
        .map(fourcc_text)
        .collect::<Vec<_>>()
        .join(", ")
}

fn is_mjpeg(code: &[u8; 4]) -> bool {
    matches!(code, b"MJPG" | b"JPEG" | b"PJPG")
}

/// The best format of those offered, in [`PREFERENCE`] order; the error (for
/// [`Error::Device`], after the device's name) says what the camera offers and what
/// this source reads, and that MJPEG is not supported when it is among them.
///
/// ```
/// use vlsync_signature_cam::v4l2::negotiate::{choose_format, Offered};
/// use vlsync_signature_cam::PixelFormat;
/// let f = |c: &[u8; 4], d: &str| Offered { fourcc: *c, description: d.into(), compressed: false };
/// assert_eq!(choose_format(&[f(b"MJPG", "Motion-JPEG"), f(b"YUYV", "YUYV 4:2:2")]), Ok(PixelFormat::Yuyv));
/// let e = choose_format(&[f(b"MJPG", "Motion-JPEG")]).unwrap_err();
/// assert!(e.contains("MJPEG is not supported") && e.contains("offers only MJPG (Motion-JPEG)"), "{e}");
/// ```
pub fn choose_format(offered: &[Offered]) -> Result<PixelFormat, String> {
    if let Some(f) = PREFERENCE
        .iter()
        .find(|p| offered.iter().any(|o| p.fourcc() == Some(o.fourcc)))
    {
        return Ok(*f);
    }
    if offered.is_empty() {
        return Err("lists no capture formats (VIDIOC_ENUM_FMT gave none)".into());
    }
    let list = offered
        .iter()
        .map(|o| o.to_string())
        .collect::<Vec<_>>()
        .join(", ");
    let why = if offered.iter().any(|o| is_mjpeg(&o.fourcc)) {
        "MJPEG is not supported (this source decodes no JPEG): pick a camera with an \
         uncompressed format"
    } else if offered.iter().all(|o| o.compressed) {
        "compressed formats are not supported"
    } else {
        "none of them can be reduced to gray cheaply (raw Bayer, for one, needs an ISP)"
    };
    Err(format!(
        "offers only {list}; {why}; this source reads {}",
        readable_codes()
    ))
}

/// A frame size one format lists (`VIDIOC_ENUM_FRAMESIZES`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SizeOffered {
    /// One size.
    Discrete {
        /// Width, px.
        width: u32,
        /// Height, px.
        height: u32,
    },
    /// Every size from `min` to `max` in steps of `step` (a continuous range has steps
    /// of 1), each as (width, height).
    Stepwise {
        /// The smallest size.
        min: (u32, u32),
        /// The largest size.
        max: (u32, u32),
        /// The steps (0 taken as 1).
        step: (u32, u32),
    },
}

impl SizeOffered {
    /// Whether `width`x`height` is among these sizes.
    pub fn holds(&self, width: u32, height: u32) -> bool {
        let on = |v: u32, lo: u32, hi: u32, step: u32| {
            (lo..=hi).contains(&v) && (v - lo).is_multiple_of(step.max(1))
        };
        match *self {
            SizeOffered::Discrete {
                width: w,
                height: h,
            } => (w, h) == (width, height),
            SizeOffered::Stepwise { min, max, step } => {
                on(width, min.0, max.0, step.0) && on(height, min.1, max.1, step.1)
            }
        }
    }
}

impl fmt::Display for SizeOffered {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            SizeOffered::Discrete { width, height } => write!(f, "{width}x{height}"),
            SizeOffered::Stepwise { min, max, .. } => {
                write!(f, "{}x{} to {}x{}", min.0, min.1, max.0, max.1)
            }
        }
    }
}

/// What one format lists for the size asked: its sizes, and its fastest rate at that
/// size (`VIDIOC_ENUM_FRAMEINTERVALS`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Modes {
    /// The sizes listed; empty when the driver lists none.
    pub sizes: Vec<SizeOffered>,
    /// The fastest rate listed at the size asked, Hz; `None` when none is listed.
    pub max_fps: Option<f64>,
}

impl Modes {
    /// Whether the size asked is listed; `None` when no size is listed at all.
    fn has(&self, width: u32, height: u32) -> Option<bool> {
        (!self.sizes.is_empty()).then(|| self.sizes.iter().any(|s| s.holds(width, height)))
    }

    /// Why these modes do not serve `width`x`height` at `fps`, or `None` when they
    /// may (what the driver does not list is taken as possible).
    fn shortfall(&self, width: u32, height: u32, fps: Option<f64>) -> Option<String> {
        if self.has(width, height) == Some(false) {
            const SHOWN: usize = 6;
            let mut list = self
                .sizes
                .iter()
                .take(SHOWN)
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ");
            if self.sizes.len() > SHOWN {
                list.push_str(", ...");
            }
            return Some(format!("lists no {width}x{height} (it lists {list})"));
        }
        match (fps, self.max_fps) {
            // a rate within 1 % of the one asked serves (29.97 for 30)
            (Some(asked), Some(best)) if best < asked * 0.99 => Some(format!(
                "lists {width}x{height} at up to {}, not {}",
                hz(best),
                hz(asked)
            )),
            _ => None,
        }
    }
}

/// The format to ask for: the first of those offered, in [`PREFERENCE`] order, that
/// lists `width`x`height` at `fps` (when asked), else the first that lists the size,
/// else the first ([`choose_format`]'s). `modes` lists one format's sizes and rates;
/// it is called for the formats in order until one serves. Besides the format, the
/// reason when a format earlier in the order was passed over, for the opening's
/// notes. A camera that lists nothing (no `VIDIOC_ENUM_FRAMESIZES`) gets the first.
///
/// ```
/// use vlsync_signature_cam::v4l2::negotiate::{choose_format_for, Modes, Offered, SizeOffered};
/// use vlsync_signature_cam::PixelFormat;
/// let f = |c: &[u8; 4]| Offered { fourcc: *c, description: String::new(), compressed: false };
/// let size = |width, height| SizeOffered::Discrete { width, height };
/// // GREY only at the sensor's full size; YUYV at 640x480 too
/// let (chosen, why) = choose_format_for(&[f(b"YUYV"), f(b"GREY")], 640, 480, None, |p| match p {
///     PixelFormat::Gray8 => Modes { sizes: vec![size(1280, 800)], max_fps: None },
///     _ => Modes { sizes: vec![size(1280, 800), size(640, 480)], max_fps: Some(30.0) },
/// })
/// .unwrap();
/// assert_eq!(chosen, PixelFormat::Yuyv);
/// assert!(why.unwrap().contains("GREY lists no 640x480 (it lists 1280x800)"));
/// ```
pub fn choose_format_for(
    offered: &[Offered],
    width: u32,
    height: u32,
    fps: Option<f64>,
    mut modes: impl FnMut(PixelFormat) -> Modes,
) -> Result<(PixelFormat, Option<String>), String> {
    let first = choose_format(offered)?;
    let candidates = PREFERENCE
        .iter()
        .copied()
        .filter(|p| offered.iter().any(|o| p.fourcc() == Some(o.fourcc)));
    let mut passed: Vec<(PixelFormat, String)> = Vec::new();
    let mut sized: Option<PixelFormat> = None;
    for p in candidates {
        let m = modes(p);
        match m.shortfall(width, height, fps) {
            None => {
                let why = (!passed.is_empty()).then(|| passed_over(&passed, p));
                return Ok((p, why));
            }
            Some(why) => {
                if sized.is_none() && m.has(width, height) != Some(false) {
                    sized = Some(p);
                }
                passed.push((p, why));
            }
        }
    }
    // none serves both: the size before the rate, else the order's first
    let chosen = sized.unwrap_or(first);
    let earlier: Vec<_> = passed
        .into_iter()
        .take_while(|(p, _)| *p != chosen)
        .collect();
    let why = (!earlier.is_empty()).then(|| passed_over(&earlier, chosen));
    Ok((chosen, why))
}

/// "GREY lists no 640x480 (...); YUYV asked for instead"
fn passed_over(passed: &[(PixelFormat, String)], chosen: PixelFormat) -> String {
    let code = |p: PixelFormat| p.fourcc().map_or_else(|| p.name().to_string(), fourcc_text);
    let reasons = passed
        .iter()
        .map(|(p, why)| format!("{} {why}", code(*p)))
        .collect::<Vec<_>>()
        .join("; ");
    format!("{reasons}; {} asked for instead", code(chosen))
}

/// Frames above this many pixels are refused at open (as images from files are).
pub const MAX_PIXELS: usize = 64 << 20;

/// The row stride to read a negotiated `width`x`height` frame of `format` with
/// (`bytesperline`, or a tight row when the driver leaves it 0), after checking that
/// such a frame can be read: not empty nor above [`MAX_PIXELS`], pixel pairs at an
/// even width, a stride no shorter than a row, and an image size (`sizeimage`,
/// when the driver gives one) that holds what is read of a frame.
pub fn check_geometry(
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: u32,
    size_image: u32,
) -> Result<usize, String> {
    let (w, h) = (width as usize, height as usize);
    let what = || {
        format!(
            "a {w}x{h} {} frame",
            fourcc_text(format.fourcc().unwrap_or(*b"????"))
        )
    };
    let n =
        pixel_count(w, h).map_err(|e| format!("the driver negotiated an unusable frame: {e}"))?;
    if n > MAX_PIXELS {
        return Err(format!(
            "the driver negotiated {}, above {} Mpx",
            what(),
            MAX_PIXELS >> 20
        ));
    }
    if format.packed_pairs() && !w.is_multiple_of(2) {
        return Err(format!(
            "the driver negotiated {} at an odd width, which holds no whole pixel pairs",
            what()
        ));
    }
    // below MAX_PIXELS, none of these overflow
    let row = w * format.bytes_per_pixel();
    let stride = match stride as usize {
        0 => row,
        s if s < row => {
            return Err(format!(
                "the driver's stride {s} is shorter than a row of {} ({row} bytes)",
                what()
            ))
        }
        s => s,
    };
    let need = (h - 1)
        .checked_mul(stride)
        .and_then(|v| v.checked_add(row))
        .ok_or_else(|| format!("{} with stride {stride} overflows", what()))?;
    if size_image != 0 && (size_image as usize) < need {
        return Err(format!(
            "the driver's image size {size_image} bytes is smaller than {} with stride {stride} \
             needs ({need} bytes)",
            what()
        ));
    }
    Ok(stride)
}

/// Frame rates that can be asked for, Hz (as `camera.v4l2_fps` of vlsync-config).
pub const FPS_RANGE: std::ops::RangeInclusive<f64> = 1.0..=1000.0;

fn gcd(a: u32, b: u32) -> u32 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// The frame interval (`timeperframe`, numerator / denominator seconds) for a rate
/// in [`FPS_RANGE`], to a thousandth of a hertz; `None` outside it.
///
/// ```
/// use vlsync_signature_cam::v4l2::negotiate::interval_for_fps;
/// assert_eq!(interval_for_fps(30.0), Some((1, 30)));
/// assert_eq!(interval_for_fps(7.5), Some((2, 15)));
/// assert_eq!(interval_for_fps(0.5), None);
/// ```
pub fn interval_for_fps(fps: f64) -> Option<(u32, u32)> {
    if !(fps.is_finite() && FPS_RANGE.contains(&fps)) {
        return None;
    }
    let den = (fps * 1000.0).round() as u32;
    let g = gcd(1000, den);
    Some((1000 / g, den / g))
}

/// The rate of a frame interval, Hz; `None` for an interval with a zero part.
pub fn fps_of_interval(numerator: u32, denominator: u32) -> Option<f64> {
    (numerator != 0 && denominator != 0).then(|| f64::from(denominator) / f64::from(numerator))
}

/// A rate for messages: at most three decimals, no trailing zeros (`30`, `7.5`, `29.97`).
pub fn hz(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    format!("{s} Hz")
}

/// The frame rate an opening ended with.
#[derive(Debug, Clone, PartialEq)]
pub struct Rate {
    /// What was asked (`None`: the camera's own rate was kept).
    pub asked: Option<f64>,
    /// What the driver reports after it (`VIDIOC_G_PARM`), or why it reports none.
    pub granted: Result<f64, String>,
}

impl Rate {
    /// Whether the rate granted differs from the one asked by more than 1 %.
    pub fn missed(&self) -> bool {
        match (self.asked, &self.granted) {
            (Some(a), Ok(g)) => (g - a).abs() > 0.01 * a,
            _ => false,
        }
    }
}

impl fmt::Display for Rate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (&self.granted, self.asked) {
            (Ok(g), Some(a)) if self.missed() => write!(
                f,
                "{} granted, not the {} asked (the camera's nearest at this format and size)",
                hz(*g),
                hz(a)
            ),
            (Ok(g), Some(_)) => write!(f, "{} granted as asked", hz(*g)),
            (Ok(g), None) => write!(f, "{} (the camera's setting)", hz(*g)),
            (Err(why), _) => write!(f, "frame rate not reported ({why})"),
        }
    }
}

/// `V4L2_CID_EXPOSURE_AUTO`: the exposure mode (a menu).
pub const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
/// `V4L2_CID_EXPOSURE_ABSOLUTE`: the exposure time, in 100 µs units.
pub const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
/// `V4L2_CID_EXPOSURE_AUTO_PRIORITY`: an automatic exposure may lower the frame rate.
pub const CID_EXPOSURE_AUTO_PRIORITY: u32 = 0x009a_0903;

/// The exposure controls read at open (`None`: the driver has no such control, or
/// it could not be read).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Exposure {
    /// `V4L2_CID_EXPOSURE_AUTO`: 0 auto, 1 manual, 2 shutter priority, 3 aperture
    /// priority (the automatic mode of UVC cameras).
    pub mode: Option<i64>,
    /// `V4L2_CID_EXPOSURE_ABSOLUTE`, 100 µs units.
    pub time_100us: Option<i64>,
    /// `V4L2_CID_EXPOSURE_AUTO_PRIORITY` (`exposure_dynamic_framerate`).
    pub dynamic_framerate: Option<bool>,
}

impl Exposure {
    fn mode_name(mode: i64) -> &'static str {
        match mode {
            0 => "automatic",
            1 => "manual",
            2 => "shutter priority (the exposure time fixed)",
            3 => "aperture priority (automatic)",
            _ => "of an unknown mode",
        }
    }

    /// Whether the exposure time is automatic (modes 0 and 3), so that it moves with
    /// the light.
    pub fn is_auto(&self) -> bool {
        matches!(self.mode, Some(0 | 3))
    }

    /// Why automatic exposure moves the stamps, and how to lock it (`None`: it is not
    /// automatic, or the camera has no exposure control).
    pub fn warning(&self, path: &Path) -> Option<String> {
        if !self.is_auto() {
            return None;
        }
        let mode = self.mode.unwrap_or_default();
        let p = path.display();
        Some(format!(
            "automatic exposure is on (V4L2_CID_EXPOSURE_AUTO = {mode}, {}){}: the driver \
             stamps a frame at a fixed point of its transfer (uvcvideo: its first USB packet), \
             so the stamp trails mid-exposure by half the exposure, and an exposure that moves \
             between 1 and 33 ms moves the stamps by up to 16 ms, which the estimator takes for \
             offset steps or drift. Lock it before starting the driver, e.g. `v4l2-ctl -d {p} \
             -c auto_exposure=1 -c exposure_time_absolute=100 -c \
             exposure_dynamic_framerate=0` (control names differ between cameras and kernels: \
             `v4l2-ctl -d {p} -L`)",
            Self::mode_name(mode),
            if self.dynamic_framerate == Some(true) {
                ", and it may lower the frame rate in the dark (exposure_dynamic_framerate = 1)"
            } else {
                ""
            }
        ))
    }
}

impl fmt::Display for Exposure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.mode {
            None => write!(f, "exposure mode not reported")?,
            Some(m) => write!(f, "exposure {}", Self::mode_name(m))?,
        }
        if let Some(t) = self.time_100us {
            write!(f, ", {:.1} ms", t as f64 / 10.0)?;
        }
        Ok(())
    }
}

/// Where an opening's frame times will come from, for its line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampPlan {
    /// Decided within the first this many frames ([`super::StampCheck`]).
    Check(u32),
    /// An earlier opening's decision, kept.
    Kept(FrameStamps),
}

impl fmt::Display for StampPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StampPlan::Check(n) => write!(
                f,
                "stamps: the driver's buffer stamps if one of the first {n} frames shows them \
                 on CLOCK_MONOTONIC, else CLOCK_MONOTONIC at dequeue"
            ),
            StampPlan::Kept(FrameStamps::Driver) => write!(
                f,
                "stamps: the driver's buffer stamps (on CLOCK_MONOTONIC, as the first opening found)"
            ),
            StampPlan::Kept(FrameStamps::Dequeue) => write!(
                f,
                "stamps: CLOCK_MONOTONIC at dequeue (the driver's are not on it, as the first \
                 opening found)"
            ),
        }
    }
}

/// What an opening negotiated: said in one line when the stream starts.
#[derive(Debug, Clone, PartialEq)]
pub struct Negotiated {
    /// The device node.
    pub path: PathBuf,
    /// Card, driver and bus.
    pub id: DeviceId,
    /// The pixel format read.
    pub format: PixelFormat,
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Bytes from one row to the next (of the luma plane for the planar formats).
    pub stride: usize,
    /// The frame rate asked and granted.
    pub rate: Rate,
    /// The exposure controls.
    pub exposure: Exposure,
    /// Driver buffers in the stream.
    pub buffers: u32,
}

impl Negotiated {
    /// Whether another opening negotiated the same: all the same but the current
    /// time of an automatic exposure, which follows the light (for a reopen, which
    /// need not say it all again).
    pub fn same_setup(&self, other: &Negotiated) -> bool {
        let mut a = self.exposure;
        let mut b = other.exposure;
        if a.is_auto() && b.is_auto() {
            a.time_100us = None;
            b.time_100us = None;
        }
        Negotiated {
            exposure: a,
            ..self.clone()
        } == Negotiated {
            exposure: b,
            ..other.clone()
        }
    }
}

impl fmt::Display for Negotiated {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "opened {}: {}, {} {}x{}, stride {} bytes, {}, {}, {} buffers",
            self.path.display(),
            self.id,
            fourcc_text(self.format.fourcc().unwrap_or(*b"????")),
            self.width,
            self.height,
            self.stride,
            self.rate,
            self.exposure,
            self.buffers
        )
    }
}

/// The errno values (`asm-generic/errno-base.h`, the same on every Linux
/// architecture) the hints of [`io_reason`] and the V4L2 source know.
pub mod errno {
    /// Operation not permitted.
    pub const EPERM: i32 = 1;
    /// I/O error.
    pub const EIO: i32 = 5;
    /// Out of memory.
    pub const ENOMEM: i32 = 12;
    /// Permission denied.
    pub const EACCES: i32 = 13;
    /// Device or resource busy.
    pub const EBUSY: i32 = 16;
    /// No such device.
    pub const ENODEV: i32 = 19;
    /// Invalid argument.
    pub const EINVAL: i32 = 22;
    /// No space left on device (uvcvideo: not enough USB bandwidth).
    pub const ENOSPC: i32 = 28;
}

/// The reason an ioctl of step `what` failed with `e`, with the way out when the
/// error number has a usual cause: `EBUSY` (another process holds the camera),
/// `ENOSPC` (not enough USB bandwidth left on the host controller for the format,
/// size and rate, at `VIDIOC_STREAMON`), `EIO` (there, uvcvideo's answer when no
/// alternate setting of the camera is fast enough), `ENODEV` (unplugged),
/// `EACCES`/`EPERM`, `ENOMEM`.
///
/// ```
/// use vlsync_signature_cam::v4l2::negotiate::io_reason;
/// let e = std::io::Error::from_raw_os_error(28);
/// let r = io_reason("start streaming (VIDIOC_STREAMON)", &e);
/// assert!(r.starts_with("start streaming (VIDIOC_STREAMON): "), "{r}");
/// assert!(r.contains("USB bandwidth"), "{r}");
/// ```
pub fn io_reason(what: &str, e: &std::io::Error) -> String {
    let hint = match e.raw_os_error() {
        Some(errno::EBUSY) => {
            "the camera is busy: another process streams from it or holds its buffers \
             (`fuser -v` on the device names it), or it is still being released"
        }
        Some(errno::ENOSPC) => {
            "not enough USB bandwidth left for this format, size and frame rate (the host \
             controller's refusal of the camera's isochronous transfers): lower the resolution \
             or the rate (--fps, camera.v4l2_fps), or plug the camera into another USB port or \
             controller (a camera sharing the bus takes its bandwidth)"
        }
        Some(errno::ENODEV) => "the device is gone (unplugged?)",
        Some(errno::EACCES | errno::EPERM) => {
            "no permission: the user needs read and write access to the node (the `video` group)"
        }
        Some(errno::ENOMEM) => {
            "the driver could not allocate its buffers (fewer buffers, a smaller size)"
        }
        Some(errno::EIO) => {
            "the device failed the request: when the stream starts, uvcvideo's answer when none \
             of the camera's USB alternate settings is fast enough for this format, size and \
             rate (lower them); else a USB link problem (cable, hub, power); the kernel log \
             (dmesg) says which"
        }
        _ => "",
    };
    if hint.is_empty() {
        format!("{what}: {e}")
    } else {
        format!("{what}: {e}: {hint}")
    }
}

/// The text of a panic's payload.
fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "no message".into()
    }
}

/// Runs one call into the `v4l` crate for step `what` of device `path`: its I/O
/// error becomes [`Error::Device`] through [`io_reason`], and so does a panic, which
/// the crate raises on answers it does not expect (a format's colorspace, field,
/// quantization or transfer function it does not know, a card or format name that
/// is not UTF-8 after the kernel cut it at 32 bytes, a control type it does not
/// know, a failed `VIDIOC_STREAMOFF` or `munmap` when a stream is dropped). The
/// workspace builds with unwinding panics (no `panic = "abort"` in any profile), so
/// the panic is caught here; Rust's panic hook has printed the crate's own message
/// on stderr before.
///
/// ```
/// use vlsync_signature_cam::v4l2::negotiate::guarded;
/// let p = std::path::Path::new("/dev/video0");
/// let e = guarded(p, "get format (VIDIOC_G_FMT)", || -> std::io::Result<()> {
///     panic!("Invalid colorspace")
/// })
/// .unwrap_err();
/// assert!(e.to_string().starts_with("/dev/video0: get format (VIDIOC_G_FMT): the driver's answer"));
/// ```
pub fn guarded<T>(
    path: &Path,
    what: &str,
    f: impl FnOnce() -> std::io::Result<T>,
) -> Result<T, Error> {
    caught(path, what, f)?.map_err(|e| device_error(path, io_reason(what, &e)))
}

/// As [`guarded`], but the call's I/O error is handed back as it is (for the
/// caller to tell a timeout from a fault); only a panic becomes the error.
pub fn caught<T>(
    path: &Path,
    what: &str,
    f: impl FnOnce() -> std::io::Result<T>,
) -> Result<std::io::Result<T>, Error> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|payload| {
        device_error(
            path,
            format!(
                "{what}: the driver's answer made the `v4l` crate panic (\"{}\"): an unusual or \
                 faulty driver, which this source cannot read",
                panic_text(payload.as_ref())
            ),
        )
    })
}

/// `VIDEO_MAX_FRAME` (`linux/videodev2.h`): the most buffers a queue usually has.
pub const VIDEO_MAX_FRAME: u32 = 32;

/// Queues every buffer the driver granted before the stream starts, `queue(0)`,
/// `queue(1)`, and so on, and returns how many were queued. The `v4l` crate does not
/// say how many buffers it mapped, so the first index refused with `EINVAL` (beyond
/// the buffers granted, which may be fewer or more than `asked`) ends the queueing;
/// past `asked` and [`VIDEO_MAX_FRAME`] no more are tried. Every granted buffer goes
/// in, none held back: a vb2 driver starts streaming only once its
/// `min_buffers_needed` are queued, which may be all of them (a driver raises the
/// count asked to that minimum), and without a started stream no frame comes, so no
/// buffer could be handed back. Buffer 0 refused, or any other error, is the
/// error's reason, labelled with the buffer.
///
/// ```
/// use vlsync_signature_cam::v4l2::negotiate::queue_all;
/// // a driver that granted 3 buffers
/// let granted = |i: u32| if i < 3 { Ok(()) } else { Err(std::io::Error::from_raw_os_error(22)) };
/// assert_eq!(queue_all(2, granted), Ok(3));
/// ```
pub fn queue_all(
    asked: u32,
    mut queue: impl FnMut(u32) -> std::io::Result<()>,
) -> Result<u32, String> {
    let limit = asked.max(VIDEO_MAX_FRAME);
    for i in 0..limit {
        match queue(i) {
            Ok(()) => {}
            Err(e) if i > 0 && e.raw_os_error() == Some(errno::EINVAL) => return Ok(i),
            Err(e) => return Err(io_reason(&format!("queue buffer {i} (VIDIOC_QBUF)"), &e)),
        }
    }
    Ok(limit)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_granted_buffer_is_queued() {
        let einval = || std::io::Error::from_raw_os_error(errno::EINVAL);
        // granted as asked, fewer, and more (a driver's minimum above the count asked):
        // each index is tried once, in order, up to the first refused
        for granted in [4, 2, 6, 1] {
            let mut tried = Vec::new();
            let n = queue_all(4, |i| {
                tried.push(i);
                if i < granted {
                    Ok(())
                } else {
                    Err(einval())
                }
            });
            assert_eq!(n, Ok(granted));
            assert_eq!(tried, (0..=granted).collect::<Vec<_>>());
        }
        // buffer 0 refused: not a count, an error
        assert_eq!(
            queue_all(4, |_| Err(einval())),
            Err(format!("queue buffer 0 (VIDIOC_QBUF): {}", einval()))
        );
        // another error, at any buffer, is the opening's, with its hint
        let e = queue_all(4, |i| {
            if i < 2 {
                Ok(())
            } else {
                Err(std::io::Error::from_raw_os_error(errno::ENODEV))
            }
        })
        .unwrap_err();
        assert!(e.starts_with("queue buffer 2 (VIDIOC_QBUF): "), "{e}");
        assert!(e.ends_with("unplugged?)"), "{e}");
        // a driver that never refuses: the limit, or the count asked above it
        assert_eq!(queue_all(4, |_| Ok(())), Ok(VIDEO_MAX_FRAME));
        assert_eq!(queue_all(40, |_| Ok(())), Ok(40));
    }

    fn id() -> DeviceId {
        DeviceId {
            card: "HD Webcam".into(),
            driver: "uvcvideo".into(),
            bus: "usb-0000:00:14.0-2".into(),
        }
    }

    #[test]
    fn a_streaming_capture_node_passes_and_others_say_what_is_missing() {
        let p = Path::new("/dev/video7");
        let ok = cap::VIDEO_CAPTURE | cap::STREAMING | cap::READWRITE | cap::DEVICE_CAPS;
        check_caps(p, &id(), ok).unwrap();
        let msg = |caps| check_caps(p, &id(), caps).unwrap_err().to_string();
        // a UVC camera's metadata node
        let e = msg(cap::META_CAPTURE | cap::STREAMING);
        assert!(
            e.starts_with(
                "/dev/video7: \"HD Webcam\" (driver uvcvideo, usb-0000:00:14.0-2) is a metadata node"
            ),
            "{e}"
        );
        assert!(e.contains("-video-index0"), "{e}");
        // a CSI receiver's multi-planar node
        let e = msg(cap::VIDEO_CAPTURE_MPLANE | cap::STREAMING);
        assert!(e.contains("multi-planar") && e.contains("libcamera"), "{e}");
        assert!(
            e.ends_with("capabilities: VIDEO_CAPTURE_MPLANE | STREAMING"),
            "{e}"
        );
        // a codec
        let e = msg(cap::VIDEO_M2M_MPLANE | cap::STREAMING);
        assert!(e.contains("has no single-planar video capture"), "{e}");
        // capture without streaming
        let e = msg(cap::VIDEO_CAPTURE | cap::READWRITE);
        assert!(
            e.contains("without streaming I/O (V4L2_CAP_STREAMING)"),
            "{e}"
        );
        assert!(
            e.ends_with("capabilities: VIDEO_CAPTURE | READWRITE"),
            "{e}"
        );
        // nothing reported
        let e = msg(0);
        assert!(e.contains("reports no capabilities"), "{e}");
        // unknown bits are shown in hex
        assert_eq!(cap_names(0x4000_0001), "VIDEO_CAPTURE | 0x40000000");
    }

    fn offered(code: &[u8; 4], desc: &str, compressed: bool) -> Offered {
        Offered {
            fourcc: *code,
            description: desc.into(),
            compressed,
        }
    }

    #[test]
    fn a_format_is_passed_over_for_the_size_or_rate_it_does_not_list() {
        let (yuyv, nv12, grey) = (
            offered(b"YUYV", "", false),
            offered(b"NV12", "", false),
            offered(b"GREY", "", false),
        );
        let size = |width, height| SizeOffered::Discrete { width, height };
        let vga = || vec![size(320, 240), size(640, 480)];
        // NV12 lists VGA only up to 15 Hz (USB bandwidth), YUYV at 30
        let modes = |p: PixelFormat| match p {
            PixelFormat::Nv12 => Modes {
                sizes: vga(),
                max_fps: Some(15.0),
            },
            _ => Modes {
                sizes: vga(),
                max_fps: Some(30.0),
            },
        };
        let both = [yuyv.clone(), nv12.clone()];
        let (p, why) = choose_format_for(&both, 640, 480, Some(30.0), modes).unwrap();
        assert_eq!(p, PixelFormat::Yuyv);
        assert_eq!(
            why.unwrap(),
            "NV12 lists 640x480 at up to 15 Hz, not 30 Hz; YUYV asked for instead"
        );
        // no rate asked: the cheaper one
        assert_eq!(
            choose_format_for(&both, 640, 480, None, modes).unwrap(),
            (PixelFormat::Nv12, None)
        );
        // 29.97 serves 30
        let ntsc = |_| Modes {
            sizes: vga(),
            max_fps: Some(29.97),
        };
        assert_eq!(
            choose_format_for(&both, 640, 480, Some(30.0), ntsc).unwrap(),
            (PixelFormat::Nv12, None)
        );
        // nothing listed (a driver without VIDIOC_ENUM_FRAMESIZES): the order's first
        assert_eq!(
            choose_format_for(&both, 640, 480, Some(30.0), |_| Modes::default()).unwrap(),
            (PixelFormat::Nv12, None)
        );
        // none lists the size: the order's first, nothing passed over
        let big = |_| Modes {
            sizes: vec![size(1920, 1080)],
            max_fps: None,
        };
        assert_eq!(
            choose_format_for(&both, 640, 480, None, big).unwrap(),
            (PixelFormat::Nv12, None)
        );
        // none serves size and rate: the first with the size, said why
        let three = [grey.clone(), nv12.clone(), yuyv.clone()];
        let slow = |p: PixelFormat| match p {
            PixelFormat::Gray8 => Modes {
                sizes: vec![SizeOffered::Stepwise {
                    min: (1280, 800),
                    max: (1280, 800),
                    step: (0, 0),
                }],
                max_fps: None,
            },
            _ => Modes {
                sizes: vga(),
                max_fps: Some(10.0),
            },
        };
        let (p, why) = choose_format_for(&three, 640, 480, Some(30.0), slow).unwrap();
        assert_eq!(p, PixelFormat::Nv12);
        assert_eq!(
            why.unwrap(),
            "GREY lists no 640x480 (it lists 1280x800 to 1280x800); NV12 asked for instead"
        );
        // the formats are asked in order, and no further than the one that serves
        let mut asked = Vec::new();
        choose_format_for(&three, 640, 480, None, |p| {
            asked.push(p);
            Modes::default()
        })
        .unwrap();
        assert_eq!(asked, [PixelFormat::Gray8]);
        // MJPEG only: choose_format's error
        let mjpg = offered(b"MJPG", "Motion-JPEG", true);
        assert!(
            choose_format_for(&[mjpg], 640, 480, None, |_| Modes::default())
                .unwrap_err()
                .contains("MJPEG is not supported")
        );
    }

    #[test]
    fn stepwise_sizes_hold_the_sizes_on_their_steps() {
        let s = SizeOffered::Stepwise {
            min: (16, 16),
            max: (1920, 1080),
            step: (16, 8),
        };
        assert!(s.holds(640, 480));
        assert!(s.holds(16, 16) && s.holds(1920, 1080));
        assert!(!s.holds(642, 480) && !s.holds(640, 482) && !s.holds(1936, 480));
        assert!(!s.holds(0, 480));
        let continuous = SizeOffered::Stepwise {
            min: (1, 1),
            max: (4096, 4096),
            step: (1, 1),
        };
        assert!(continuous.holds(641, 479));
        assert_eq!(s.to_string(), "16x16 to 1920x1080");
    }

    proptest::proptest! {
        #[test]
        fn sizes_never_panic(lo in proptest::array::uniform2(0u32..5000), hi in proptest::array::uniform2(0u32..5000),
                             step in proptest::array::uniform2(0u32..64), w in 0u32..6000, h in 0u32..6000) {
            let s = SizeOffered::Stepwise { min: (lo[0], lo[1]), max: (hi[0], hi[1]), step: (step[0], step[1]) };
            let held = s.holds(w, h);
            proptest::prop_assert!(!held || (lo[0]..=hi[0]).contains(&w) && (lo[1]..=hi[1]).contains(&h));
        }
    }

    #[test]
    fn the_cheapest_format_is_chosen_and_mjpeg_only_is_refused_with_the_list() {
        let yuyv = offered(b"YUYV", "YUYV 4:2:2", false);
        let nv12 = offered(b"NV12", "Y/UV 4:2:0", false);
        let mjpg = offered(b"MJPG", "Motion-JPEG", true);
        let grey = offered(b"GREY", "8-bit Greyscale", false);
        let rgb3 = offered(b"RGB3", "24-bit RGB 8-8-8", false);
        let uyvy = offered(b"UYVY", "UYVY 4:2:2", false);
        // a usual UVC camera: MJPEG and YUYV
        assert_eq!(
            choose_format(&[mjpg.clone(), yuyv.clone()]),
            Ok(PixelFormat::Yuyv)
        );
        // NV12 beside YUYV: the luma plane, and less bandwidth
        assert_eq!(
            choose_format(&[yuyv.clone(), nv12.clone()]),
            Ok(PixelFormat::Nv12)
        );
        assert_eq!(
            choose_format(&[rgb3.clone(), yuyv.clone(), grey.clone()]),
            Ok(PixelFormat::Gray8)
        );
        assert_eq!(
            choose_format(&[rgb3.clone(), uyvy.clone()]),
            Ok(PixelFormat::Uyvy)
        );
        assert_eq!(
            choose_format(std::slice::from_ref(&rgb3)),
            Ok(PixelFormat::Rgb8)
        );
        for f in PREFERENCE {
            let code = f.fourcc().unwrap();
            assert_eq!(
                choose_format(&[mjpg.clone(), offered(&code, "", false)]),
                Ok(f)
            );
        }
        // MJPEG and H.264 only
        let e = choose_format(&[mjpg, offered(b"H264", "H.264", true)]).unwrap_err();
        assert_eq!(
            e,
            "offers only MJPG (Motion-JPEG), H264 (H.264); MJPEG is not supported (this source \
             decodes no JPEG): pick a camera with an uncompressed format; this source reads \
             GREY, NV12, NV21, YU12, YV12, YUYV, UYVY, RGB3, BGR3"
        );
        let e = choose_format(&[offered(b"H264", "H.264", true)]).unwrap_err();
        assert!(e.contains("compressed formats are not supported"), "{e}");
        // raw Bayer (a bare CSI sensor)
        let e =
            choose_format(&[offered(b"pRAA", "10-bit Bayer RGRG/GBGB Packed", false)]).unwrap_err();
        assert!(e.starts_with("offers only pRAA (10-bit Bayer"), "{e}");
        assert!(e.contains("raw Bayer"), "{e}");
        let e = choose_format(&[]).unwrap_err();
        assert!(e.contains("no capture formats"), "{e}");
    }

    #[test]
    fn fourcc_codes_print_readably() {
        assert_eq!(fourcc_text(*b"YUYV"), "YUYV");
        assert_eq!(fourcc_text(*b"Y8  "), "Y8");
        // the big-endian flag of e.g. RGB565X variants
        assert_eq!(fourcc_text([b'R', b'G', b'B', b'R' | 0x80]), "RGBR-BE");
        assert_eq!(fourcc_text([1, 2, 3, 4]), "0x04030201");
    }

    #[test]
    fn the_geometry_is_checked_at_open() {
        use PixelFormat::*;
        // YUYV 640x480: tight, padded, and the stride left 0
        assert_eq!(check_geometry(Yuyv, 640, 480, 1280, 614_400), Ok(1280));
        assert_eq!(check_geometry(Yuyv, 640, 480, 1344, 0), Ok(1344));
        assert_eq!(check_geometry(Yuyv, 640, 480, 0, 614_400), Ok(1280));
        // NV12: the luma stride; its image size holds the chroma too
        assert_eq!(check_geometry(Nv12, 640, 480, 640, 460_800), Ok(640));
        // a stride shorter than a row
        let e = check_geometry(Rgb8, 640, 480, 1280, 0).unwrap_err();
        assert_eq!(
            e,
            "the driver's stride 1280 is shorter than a row of a 640x480 RGB3 frame (1920 bytes)"
        );
        // an image size smaller than the rows read
        let e = check_geometry(Gray8, 640, 480, 640, 640 * 479).unwrap_err();
        assert!(e.contains("image size 306560 bytes is smaller"), "{e}");
        assert!(e.contains("(307200 bytes)"), "{e}");
        // odd pixel pairs, empty and huge frames
        assert!(check_geometry(Uyvy, 641, 480, 0, 0)
            .unwrap_err()
            .contains("odd width"));
        assert!(check_geometry(Nv12, 641, 481, 641, 0).is_ok());
        assert!(check_geometry(Gray8, 0, 480, 0, 0)
            .unwrap_err()
            .contains("unusable frame"));
        assert!(check_geometry(Gray8, 65_535, 65_535, 0, 0)
            .unwrap_err()
            .contains("above 64 Mpx"));
        // the largest strides cannot overflow the size needed (an error where usize
        // has 32 bits)
        let huge = check_geometry(Gray8, 8, 8, u32::MAX, 0);
        if cfg!(target_pointer_width = "64") {
            assert_eq!(huge, Ok(u32::MAX as usize));
        } else {
            assert!(huge.unwrap_err().contains("overflows"));
        }
    }

    #[test]
    fn rates_and_intervals() {
        assert_eq!(interval_for_fps(30.0), Some((1, 30)));
        assert_eq!(interval_for_fps(29.97), Some((100, 2997)));
        assert_eq!(interval_for_fps(1000.0), Some((1, 1000)));
        assert_eq!(interval_for_fps(1.0), Some((1, 1)));
        for bad in [0.0, 0.999, 1000.5, -30.0, f64::NAN, f64::INFINITY] {
            assert_eq!(interval_for_fps(bad), None, "{bad}");
        }
        assert_eq!(fps_of_interval(1, 30), Some(30.0));
        assert_eq!(fps_of_interval(2, 15), Some(7.5));
        assert_eq!(fps_of_interval(0, 30), None);
        assert_eq!(fps_of_interval(1, 0), None);
        assert_eq!(hz(30.0), "30 Hz");
        assert_eq!(hz(7.5), "7.5 Hz");
        assert_eq!(hz(2997.0 / 100.0), "29.97 Hz");
        let r = |asked, granted| Rate { asked, granted };
        assert_eq!(
            r(Some(30.0), Ok(30.0)).to_string(),
            "30 Hz granted as asked"
        );
        let missed = r(Some(60.0), Ok(30.0));
        assert!(missed.missed());
        assert_eq!(
            missed.to_string(),
            "30 Hz granted, not the 60 Hz asked (the camera's nearest at this format and size)"
        );
        assert!(!r(Some(30.0), Ok(29.97)).missed());
        assert_eq!(
            r(None, Ok(15.0)).to_string(),
            "15 Hz (the camera's setting)"
        );
        assert_eq!(
            r(
                None,
                Err("VIDIOC_G_PARM: Inappropriate ioctl for device".into())
            )
            .to_string(),
            "frame rate not reported (VIDIOC_G_PARM: Inappropriate ioctl for device)"
        );
    }

    proptest::proptest! {
        /// Every rate in range gives an interval whose rate is the one asked, to a
        /// thousandth of a hertz.
        #[test]
        fn an_interval_gives_back_its_rate(fps in 1.0f64..=1000.0) {
            let (n, d) = interval_for_fps(fps).unwrap();
            let back = fps_of_interval(n, d).unwrap();
            proptest::prop_assert!((back - fps).abs() <= 0.0005 + 1e-9, "{fps} -> {n}/{d} -> {back}");
        }
    }

    #[test]
    fn automatic_exposure_is_warned_of_and_a_locked_one_is_not() {
        let p = Path::new("/dev/video0");
        let manual = Exposure {
            mode: Some(1),
            time_100us: Some(100),
            dynamic_framerate: Some(false),
        };
        assert!(!manual.is_auto());
        assert_eq!(manual.warning(p), None);
        assert_eq!(manual.to_string(), "exposure manual, 10.0 ms");
        // shutter priority fixes the exposure time: no warning
        let shutter = Exposure {
            mode: Some(2),
            ..manual
        };
        assert_eq!(shutter.warning(p), None);
        for mode in [0, 3] {
            let auto = Exposure {
                mode: Some(mode),
                time_100us: Some(156),
                dynamic_framerate: Some(true),
            };
            let w = auto.warning(p).unwrap();
            assert!(
                w.starts_with(&format!(
                    "automatic exposure is on (V4L2_CID_EXPOSURE_AUTO = {mode}, "
                )),
                "{w}"
            );
            assert!(w.contains("up to 16 ms"), "{w}");
            assert!(w.contains("exposure_dynamic_framerate = 1"), "{w}");
            assert!(
                w.contains("v4l2-ctl -d /dev/video0 -c auto_exposure=1"),
                "{w}"
            );
        }
        assert_eq!(
            Exposure {
                mode: Some(3),
                time_100us: Some(156),
                dynamic_framerate: None
            }
            .to_string(),
            "exposure aperture priority (automatic), 15.6 ms"
        );
        // a camera without exposure controls
        let none = Exposure::default();
        assert_eq!(none.warning(p), None);
        assert_eq!(none.to_string(), "exposure mode not reported");
    }

    #[test]
    fn the_opening_line_says_everything_negotiated() {
        let n = Negotiated {
            path: "/dev/video0".into(),
            id: id(),
            format: PixelFormat::Yuyv,
            width: 640,
            height: 480,
            stride: 1280,
            rate: Rate {
                asked: Some(30.0),
                granted: Ok(30.0),
            },
            exposure: Exposure {
                mode: Some(1),
                time_100us: Some(100),
                dynamic_framerate: Some(false),
            },
            buffers: 4,
        };
        assert_eq!(
            n.to_string(),
            "opened /dev/video0: \"HD Webcam\" (driver uvcvideo, usb-0000:00:14.0-2), YUYV \
             640x480, stride 1280 bytes, 30 Hz granted as asked, exposure manual, 10.0 ms, 4 buffers"
        );
        assert_eq!(
            StampPlan::Check(8).to_string(),
            "stamps: the driver's buffer stamps if one of the first 8 frames shows them on \
             CLOCK_MONOTONIC, else CLOCK_MONOTONIC at dequeue"
        );
        // a reopen that negotiated the same, but for an automatic exposure's time
        let mut again = n.clone();
        assert!(again.same_setup(&n));
        again.exposure.time_100us = Some(200);
        assert!(!again.same_setup(&n), "a manual exposure changed");
        let mut auto = n.clone();
        auto.exposure.mode = Some(3);
        let mut auto_later = auto.clone();
        auto_later.exposure.time_100us = Some(331);
        assert!(auto_later.same_setup(&auto));
        auto_later.rate.granted = Ok(15.0);
        assert!(!auto_later.same_setup(&auto), "the rate changed");
        assert!(StampPlan::Kept(FrameStamps::Dequeue)
            .to_string()
            .starts_with("stamps: CLOCK_MONOTONIC at dequeue"));
    }

    #[test]
    fn errors_are_labelled_and_hinted() {
        let e = |n| std::io::Error::from_raw_os_error(n);
        let r = io_reason("start streaming (VIDIOC_STREAMON)", &e(28));
        assert!(r.contains("another USB port"), "{r}");
        let r = io_reason("set format (VIDIOC_S_FMT)", &e(16));
        assert!(r.starts_with("set format (VIDIOC_S_FMT): "), "{r}");
        assert!(r.contains("another process streams from it"), "{r}");
        assert!(io_reason("open", &e(13)).contains("`video` group"));
        assert!(io_reason("dequeue", &e(19)).contains("unplugged"));
        // uvcvideo's own answer when no alternate setting is fast enough
        let r = io_reason("start streaming (VIDIOC_STREAMON)", &e(5));
        assert!(r.contains("alternate settings is fast enough"), "{r}");
        // no hint for the others
        let r = io_reason("get format (VIDIOC_G_FMT)", &e(22));
        assert_eq!(r, format!("get format (VIDIOC_G_FMT): {}", e(22)));
    }

    #[test]
    fn a_panic_in_the_crate_becomes_an_error_naming_the_device() {
        let p = Path::new("/dev/video3");
        let e = guarded(p, "get format (VIDIOC_G_FMT)", || -> std::io::Result<u8> {
            // as `Format::from` does on a colorspace it does not know
            let unknown: Result<u8, ()> = std::hint::black_box(Err(()));
            Ok(unknown.expect("Invalid colorspace"))
        })
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "/dev/video3: get format (VIDIOC_G_FMT): the driver's answer made the `v4l` crate \
             panic (\"Invalid colorspace: ()\"): an unusual or faulty driver, which this source \
             cannot read"
        );
        let owned = guarded(p, "drop", || -> std::io::Result<()> {
            panic!("{:?}", std::io::Error::from_raw_os_error(5))
        })
        .unwrap_err();
        assert!(owned.to_string().contains("(\"Os { code: 5"), "{owned}");
        // errors and values pass through
        assert_eq!(guarded(p, "x", || Ok(7)).unwrap(), 7);
        let e = guarded(p, "open", || -> std::io::Result<()> {
            Err(std::io::Error::from_raw_os_error(16))
        })
        .unwrap_err();
        assert!(e.to_string().starts_with("/dev/video3: open: "), "{e}");
    }
}
