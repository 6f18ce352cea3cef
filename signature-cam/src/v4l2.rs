//! V4L2 camera source (Linux), behind the cargo feature `v4l2`.
//!
//! The feature pulls the `v4l` crate, whose `v4l2-sys-mit` dependency generates
//! its bindings with bindgen at build time and so **needs libclang** on the build
//! machine (Debian: `apt-get install libclang-dev`). Without the feature the type
//! still exists and [`V4l2Source::open`] returns an error saying so (after
//! reporting a missing device as `/dev/video0: no such device`).
//!
//! An opening ([`V4l2Source::open`]; every decision is a function of the driver's
//! answers in [`negotiate`], tested without a camera):
//!
//! * checks the node's capabilities (`VIDIOC_QUERYCAP`): single-planar video capture
//!   with streaming I/O, else an error naming the device, its card and driver and
//!   what is missing (a UVC camera's metadata node; a multi-planar CSI node, as the
//!   Raspberry Pi camera modules', which need libcamera);
//! * lists the node's formats (`VIDIOC_ENUM_FMT`) and asks for the cheapest to
//!   reduce to gray ([`negotiate::PREFERENCE`]: GREY, NV12, NV21, YU12, YV12 by
//!   their luma plane, YUYV, UYVY, RGB3, BGR3) of those that list the size asked at
//!   the rate asked (`VIDIOC_ENUM_FRAMESIZES`, `VIDIOC_ENUM_FRAMEINTERVALS`:
//!   [`negotiate::choose_format_for`]; one passed over is said with why); a camera
//!   offering none of them (MJPEG only, say) is an error listing what it offers. The
//!   negotiated stride (`bytesperline`) and image size are checked against the
//!   geometry before any frame is read;
//! * sets the frame rate asked ([`V4l2Config::fps`], `VIDIOC_S_PARM`) and reads back
//!   what the camera granted (`VIDIOC_G_PARM`), or the camera's own rate;
//! * reads the exposure controls, and warns when the exposure is automatic (it
//!   moves the stamps by up to half its range);
//! * maps the buffers, queues every one the driver granted ([`negotiate::queue_all`]:
//!   a driver may start streaming only with all of them queued) and starts the
//!   stream, so that the usual refusals come here, each labelled with its step and
//!   the way out: `EBUSY` (another process holds the camera), `ENOSPC` at
//!   `VIDIOC_STREAMON` (not enough USB bandwidth for the format, size and rate). The
//!   stream's first frame is dropped unread (the `v4l` crate hands out a buffer's
//!   contents only as it queues the one it handed out before);
//! * says what it negotiated in one line (device, card, driver, format, size, stride,
//!   frame rate, exposure, buffers, where the stamps come from) through
//!   [`FrameSource::take_note`], with the exposure warning after it.
//!
//! The `v4l` crate panics on some answers of a driver (an unknown colorspace or
//! field in `Format::from`, a card name cut inside a UTF-8 character, a failed
//! `VIDIOC_STREAMOFF` when its stream is dropped): every call into it is made through
//! [`negotiate::guarded`], which turns such a panic into an error naming the device
//! (the workspace's profiles unwind on panic; none sets `panic = "abort"`), and the
//! stream is stopped before it is dropped, so that its `Drop` never meets a failing
//! `VIDIOC_STREAMOFF`.
//!
//! Each frame is stamped with the driver's buffer timestamp
//! ([`FrameTime::Instant`]), normally `CLOCK_MONOTONIC`; whether that is the
//! start of exposure or the end of the frame depends on the driver
//! (`V4L2_BUF_FLAG_TSTAMP_SRC_*`), so the constant part of that difference shows
//! up in the estimated offset. A driver whose stamps are on another clock (flagged
//! `V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN`, or all zero, or on the wall clock, which NTP
//! steps) would otherwise give the daemon stamps that repeat or jump: an opening
//! checks its first frames' stamps against `CLOCK_MONOTONIC` read at their dequeue
//! ([`StampCheck`]), and stamps that cannot be on that clock make the stream stamp
//! its frames at dequeue instead, said once ([`FrameSource::take_note`]); a reopen
//! keeps the earlier opening's choice ([`V4l2Config::stamps`]). A dequeue time is
//! late by the driver's delivery latency, whose variable part bunches frames a
//! held-up driver hands over together: the buffers' sequence numbers put each
//! frame back on its line ([`crate::sequence_clock`]).
//!
//! A buffer the driver flags as corrupt (`V4L2_BUF_FLAG_ERROR`, as USB cameras do
//! when a transfer is cut) or one too short for its frame is skipped and counted
//! ([`FrameSource::unusable`]; without an allocation: [`BufferFault`]); the
//! signature then treats it as a dropped frame: the next frame pairs with the last
//! good one over their true interval, or, past the signature's gap limit
//! (`SignatureProcessor::gap_limit_ns`: `max_gap_ns`, or more periods of a slow
//! camera), restarts the pair (a counted gap). Only
//! [`MAX_UNUSABLE_IN_ROW`](crate::source::MAX_UNUSABLE_IN_ROW) such buffers in a
//! row (a second at 30 Hz: a device that delivers nothing usable) end the stream
//! with an error saying why; a geometry the converter cannot read at all (a stride
//! shorter than a row, an odd width of pixel pairs, an image size smaller than the
//! rows read) is refused at [`V4l2Source::open`].
//!
//! A camera that stops delivering without an error (a hung USB link) does not hang
//! the driver: the wait for a buffer (a `poll` of the device before each dequeue, so a
//! camera slower than the slice loses no frame) wakes every [`POLL_SLICE`], checks the stop
//! function ([`V4l2Source::set_stop`]: a stop ends the stream, `Ok(None)`), and after
//! [`V4l2Config::stall`] without a frame the stream ends with [`Error::Stalled`]
//! naming the device (`vlsync-cam` then reopens the device and waits on, saying so
//! once and every 10 minutes). A signal that interrupts the wait is a wake-up like a timeout.
//!
//! ```
//! use vlsync_signature_cam::v4l2::{V4l2Config, V4l2Source};
//! let cfg = V4l2Config { device: "/dev/video-does-not-exist".into(), ..V4l2Config::default() };
//! let err = V4l2Source::open(&cfg).unwrap_err();
//! assert_eq!(err.to_string(), "/dev/video-does-not-exist: no such device");
//! ```

pub mod negotiate;

use crate::image::GrayFrame;
#[cfg(feature = "v4l2")]
use crate::image::{PixelFormat, RawFrame};
use crate::signature::FrameTime;
use crate::source::{FrameSource, UnusableFrames};
use crate::Error;
use std::path::PathBuf;
use vlsync_common::Nanos;

/// What to open and how.
#[derive(Debug, Clone, PartialEq)]
pub struct V4l2Config {
    /// Device node (default `/dev/video0`).
    pub device: PathBuf,
    /// Requested width (default 640); the driver may pick another.
    pub width: u32,
    /// Requested height (default 480); the driver may pick another.
    pub height: u32,
    /// Driver buffers (default 4; at least 2 are asked for).
    pub buffers: u32,
    /// Frame rate to ask the camera for, Hz, within [`negotiate::FPS_RANGE`]
    /// (`VIDIOC_S_PARM`; the rate granted is read back and said). `None` (the
    /// default): the camera's own rate is kept.
    pub fps: Option<f64>,
    /// No frame for this long is an error, [`Error::Stalled`] (default 10 s, as the
    /// serial LiDARs' silence).
    pub stall: std::time::Duration,
    /// Where the frames' times come from, as an earlier opening of the same device
    /// found ([`V4l2Source::stamp_choice`]): kept, so a reopen after a stall does not
    /// switch clocks mid-run. `None` (the default): decided within the first frames
    /// ([`StampCheck`]).
    pub stamps: Option<FrameStamps>,
}

/// The longest single wait for a buffer: the stop function is checked this often.
pub const POLL_SLICE: std::time::Duration = std::time::Duration::from_millis(500);

impl Default for V4l2Config {
    fn default() -> Self {
        Self {
            device: PathBuf::from("/dev/video0"),
            width: 640,
            height: 480,
            buffers: 4,
            fps: None,
            stall: std::time::Duration::from_secs(10),
            stamps: None,
        }
    }
}

/// Whether a conversion error is one buffer's (a short transfer), to be skipped,
/// rather than the stream's format, which every frame would repeat.
pub fn skippable(e: &Error) -> bool {
    matches!(e, Error::BufferSize { .. })
}

/// Why a dequeued buffer is skipped, found before conversion: a USB camera flags
/// cut transfers routinely, so a skipped buffer is a per-frame event and makes no
/// error value (its reason is written into [`UnusableFrames`]' room in place).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BufferFault {
    /// Flagged `V4L2_BUF_FLAG_ERROR` by the driver.
    Corrupt,
    /// Fewer bytes used than the frame's geometry reads
    /// ([`RawFrame::bytes_needed`](crate::image::RawFrame::bytes_needed)).
    Short {
        /// Bytes the driver filled.
        used: usize,
        /// Bytes the conversion reads.
        need: usize,
    },
}

impl BufferFault {
    /// Counts buffer `sequence` as skipped for this fault, without allocating;
    /// `Err` with the message that ends the stream once
    /// [`MAX_UNUSABLE_IN_ROW`](crate::source::MAX_UNUSABLE_IN_ROW) came in a row.
    pub fn skip(self, sequence: u32, unusable: &mut UnusableFrames) -> Result<(), String> {
        match self {
            Self::Corrupt => unusable.skip_fmt(format_args!(
                "buffer {sequence} flagged corrupt by the driver"
            )),
            Self::Short { used, need } => unusable.skip_fmt(format_args!(
                "buffer {sequence} too short: {used} bytes of the {need} its frame reads"
            )),
        }
    }
}

/// A conversion error of the stream's format (every frame would repeat it), as an
/// error naming the device: the bare error (e.g. bad frame dimensions) does not.
#[cfg_attr(not(feature = "v4l2"), allow(dead_code))]
fn stream_format_error(path: &std::path::Path, e: Error) -> Error {
    Error::Device {
        path: path.to_path_buf(),
        reason: format!("its frames cannot be converted: {e}"),
    }
}

/// The clock a V4L2 driver says its buffer stamps are on
/// (`V4L2_BUF_FLAG_TIMESTAMP_*`, bits 13-15 of a buffer's flags).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampClock {
    /// `V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN`: older drivers, often the wall clock.
    Unknown,
    /// `V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC`: `CLOCK_MONOTONIC`, as the daemon uses.
    Monotonic,
    /// `V4L2_BUF_FLAG_TIMESTAMP_COPY`: copied from an output buffer (memory-to-memory
    /// devices), whatever clock its writer used.
    Copied,
}

impl StampClock {
    /// The clock named by a buffer's flags.
    pub fn from_flags(flags: u32) -> Self {
        match flags & 0xe000 {
            0x2000 => Self::Monotonic,
            0x4000 => Self::Copied,
            _ => Self::Unknown,
        }
    }

    /// The kernel's name of the flag.
    pub fn name(self) -> &'static str {
        match self {
            Self::Unknown => "V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN",
            Self::Monotonic => "V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC",
            Self::Copied => "V4L2_BUF_FLAG_TIMESTAMP_COPY",
        }
    }
}

/// Where a stream's frame times come from, decided at its first frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameStamps {
    /// The driver's buffer stamps.
    Driver,
    /// `CLOCK_MONOTONIC` read when each buffer is dequeued: later than the frame by
    /// the driver's delivery latency (its constant part shows up in the offset) and
    /// with its jitter.
    Dequeue,
}

/// The oldest stamp taken as `CLOCK_MONOTONIC`: one second before the clock's
/// reading at the frame's dequeue (a frame is stamped when it is exposed or read
/// out, and delivered a frame or two later).
pub const MAX_STAMP_AGE_NS: Nanos = 1_000_000_000;

/// How far a stamp may lie after the clock's reading at its dequeue and still be
/// taken as `CLOCK_MONOTONIC` (a driver's stamp is never later than its delivery;
/// this margin only covers rounding to microseconds).
pub const MAX_STAMP_AHEAD_NS: Nanos = 1_000_000;

/// Frames beyond the buffers the driver granted (every one queued at the opening,
/// [`negotiate::queue_all`]; a driver may grant more than requested) that a
/// stream's stamps get to show they are on `CLOCK_MONOTONIC`: a driver held up
/// between the stream's start and its first read finds every queued buffer
/// filled, each with an old stamp, and only the frames after them are fresh (the
/// first of them, dropped unread at every opening, counts as one of the frames,
/// [`StampCheck::unread`]); the extra frames are a margin for those filled while
/// the first were read. Only a stream whose stamps are not on that clock waits out
/// all of them (8 frames at the default 4 buffers: a quarter of a second at 30 Hz).
pub const DECIDE_EXTRA_FRAMES: u32 = 4;

/// The frames a stream's stamps get to show they are on `CLOCK_MONOTONIC`
/// ([`StampCheck::new`]), for `granted` buffers queued at its opening: all of
/// them and [`DECIDE_EXTRA_FRAMES`] more (saturating). The count the driver
/// granted, not the one asked for: a driver granting 8 when asked for 4 fills 8
/// with old stamps while the first read is late, and a window of 4 + 4 frames
/// would see none fresh and stamp a `CLOCK_MONOTONIC` camera at dequeue all run.
///
/// ```
/// use vlsync_signature_cam::v4l2::decide_frames;
/// assert_eq!(decide_frames(4), 8);
/// assert_eq!(decide_frames(8), 12);
/// assert_eq!(decide_frames(u32::MAX), u32::MAX);
/// ```
pub fn decide_frames(granted: u32) -> u32 {
    granted.saturating_add(DECIDE_EXTRA_FRAMES)
}

/// Decides, at a stream's first frames, whether the driver's buffer stamps are on
/// `CLOCK_MONOTONIC`, whatever the flags say. The first stamp found from
/// [`MAX_STAMP_AGE_NS`] before the clock's reading at its dequeue to
/// [`MAX_STAMP_AHEAD_NS`] after it, within the first `decide_frames` (an
/// opening's: [`decide_frames`] of the buffers granted), makes the
/// stream keep the driver's stamps from that frame on; none such (stamps at zero, on
/// the wall clock, a device's own counter) makes every frame from the last of them on
/// stamped at dequeue. The frames before the decision are dropped, not published on
/// a clock that might not be the stream's: a stream's times never switch clocks.
///
/// ```
/// use vlsync_signature_cam::v4l2::{FrameStamps, StampCheck, StampClock};
/// let mut check = StampCheck::new(4);
/// // a driver that leaves its stamps at zero: three frames dropped, then the
/// // dequeue's time
/// for i in 0..3 {
///     assert_eq!(check.stamp(StampClock::Unknown, 0, 5_000_000_000 + i * 33_000_000), None);
/// }
/// assert_eq!(check.stamp(StampClock::Unknown, 0, 5_100_000_000), Some(5_100_000_000));
/// assert_eq!(check.chosen(), Some(FrameStamps::Dequeue));
/// assert!(check.take_note().unwrap().contains("stamped at dequeue"));
/// assert_eq!(check.take_note(), None);
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StampCheck {
    decide_frames: u32,
    chosen: Option<FrameStamps>,
    /// Frames seen while undecided, those dropped unread included: the number of the
    /// stream's frame at hand.
    seen: u32,
    /// Of them, those dropped unread ([`StampCheck::unread`]).
    unread: u32,
    /// The first of them read: its stamp's age at its dequeue, ns.
    first_age: Option<Nanos>,
    note: Option<String>,
}

impl StampCheck {
    /// Decides within the first `decide_frames` frames (at least 1).
    pub fn new(decide_frames: u32) -> Self {
        Self {
            decide_frames: decide_frames.max(1),
            chosen: None,
            seen: 0,
            unread: 0,
            first_age: None,
            note: None,
        }
    }

    /// The choice an earlier opening of the same device made: kept, said nothing of.
    pub fn decided(choice: FrameStamps) -> Self {
        Self {
            chosen: Some(choice),
            ..Self::new(1)
        }
    }

    /// A frame dropped before its stamp was read: the first of every opening, which
    /// queues all its buffers before the stream starts and so takes the first
    /// filled one without its contents (the `v4l` crate hands a buffer's bytes and
    /// stamp out only as it queues the one handed out before). Counted among the
    /// first frames, so that the frames named are the stream's and the decision
    /// falls within the first `decide_frames` as the opening's line says; it cannot
    /// decide, and it alone is not worth a note. Nothing once decided.
    pub fn unread(&mut self) {
        if self.chosen.is_none() {
            self.seen = self.seen.saturating_add(1);
            self.unread = self.unread.saturating_add(1);
        }
    }

    /// The time of a frame whose buffer carried `driver_ns` and the flags' `clock`,
    /// dequeued when `CLOCK_MONOTONIC` read `now_ns`; `None`: drop the frame (the
    /// stamps' clock is not decided yet).
    pub fn stamp(&mut self, clock: StampClock, driver_ns: Nanos, now_ns: Nanos) -> Option<Nanos> {
        if self.chosen.is_none() {
            self.decide(clock, driver_ns, now_ns);
        }
        match self.chosen? {
            FrameStamps::Driver => Some(driver_ns),
            FrameStamps::Dequeue => Some(now_ns),
        }
    }

    fn decide(&mut self, clock: StampClock, driver_ns: Nanos, now_ns: Nanos) {
        let age = now_ns.saturating_sub(driver_ns);
        self.seen = self.seen.saturating_add(1);
        let first_age = *self.first_age.get_or_insert(age);
        let dropped = self.seen - 1;
        let unread = self.unread;
        // the frames dropped that were read (their stamps were not in the window)
        let dropped_read = dropped.saturating_sub(unread);
        let first_s = first_age as f64 * 1e-9;
        let dropped_text = match (dropped, unread) {
            (0, _) => String::new(),
            (1, 0) => format!(
                "; the frame before it, {first_s:.3} s old at its dequeue, was \
                 dropped"
            ),
            (1, _) => "; the frame before it was dropped unread".to_string(),
            (n, 0) => format!(
                "; the {n} frames before it, the first {first_s:.3} s old at its dequeue, were dropped"
            ),
            (n, u) if u == n => format!("; the {n} frames before it were dropped unread"),
            (n, u) => format!(
                "; the {n} frames before it were dropped ({u} unread; the first read {first_s:.3} s \
                 old at its dequeue)"
            ),
        };
        if (-MAX_STAMP_AHEAD_NS..=MAX_STAMP_AGE_NS).contains(&age) {
            self.chosen = Some(FrameStamps::Driver);
            // a frame dropped unread (every opening's first) is no news
            self.note = (clock != StampClock::Monotonic || dropped_read > 0).then(|| {
                let when = if age >= 0 {
                    format!("{:.1} ms before", age as f64 * 1e-6)
                } else {
                    format!("{:.3} ms after", -(age as f64) * 1e-6)
                };
                format!(
                    "the driver's buffer stamps ({}) are on CLOCK_MONOTONIC: frame {}'s is \
                     {when} its dequeue; its stamps are used{dropped_text}",
                    clock.name(),
                    self.seen,
                )
            });
        } else if self.seen >= self.decide_frames {
            self.chosen = Some(FrameStamps::Dequeue);
            let (read, first) = match unread {
                0 => (String::new(), "first"),
                _ => (
                    format!(" ({} of them read)", self.seen.saturating_sub(unread)),
                    "first read",
                ),
            };
            let when = if first_age > 0 {
                format!("{:.3} s before", first_age as f64 * 1e-9)
            } else {
                format!("{:.3} s after", -(first_age as f64) * 1e-9)
            };
            let looks = if driver_ns == 0 {
                " (zero)"
            } else if driver_ns > 946_684_800 * 1_000_000_000 {
                // after 2000-01-01 as a date: a system up for 30 years is not likely
                " (the wall clock, CLOCK_REALTIME, as it looks)"
            } else {
                ""
            };
            self.note = Some(format!(
                "the driver's buffer stamps ({}) are not on CLOCK_MONOTONIC: none of the \
                 first {} frames' stamps{read} is within {:.0} s before its dequeue (the \
                 {first} was {when} it; the last stamp {:.6} s{looks}); from frame {} on, frames \
                 are stamped at dequeue instead, later by the driver's delivery latency \
                 (its constant part shows up in the offset), each put back on the line its \
                 buffer sequence numbers and the measured frame period draw through the \
                 earliest of the last dequeues, so that frames delivered together keep \
                 their own times{}",
                clock.name(),
                self.seen,
                MAX_STAMP_AGE_NS as f64 * 1e-9,
                driver_ns as f64 * 1e-9,
                self.seen,
                match (dropped, unread) {
                    (0, _) => String::new(),
                    (1, 0) => "; the frame before it was dropped".to_string(),
                    (1, _) => "; the frame before it was dropped unread".to_string(),
                    (n, 0) => format!("; the {n} frames before it were dropped"),
                    (n, u) => format!("; the {n} frames before it were dropped ({u} unread)"),
                }
            ));
        }
    }

    /// The choice, once the first frames made it.
    pub fn chosen(&self) -> Option<FrameStamps> {
        self.chosen
    }

    /// The remark on the choice, once: why the frames are stamped at dequeue, or that
    /// stamps flagged as another clock, or first frames dequeued late, were found on
    /// `CLOCK_MONOTONIC`.
    pub fn take_note(&mut self) -> Option<String> {
        self.note.take()
    }
}

/// A V4L2 capture stream converted to gray.
pub struct V4l2Source {
    #[cfg(feature = "v4l2")]
    inner: imp::Inner,
    #[cfg(not(feature = "v4l2"))]
    _never: std::convert::Infallible,
}

impl std::fmt::Debug for V4l2Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4l2Source").finish_non_exhaustive()
    }
}

impl V4l2Source {
    /// Opens and starts the device. A missing device node gives
    /// [`Error::NoDevice`]; without the `v4l2` feature an existing node gives
    /// [`Error::Device`] saying support was not built.
    pub fn open(cfg: &V4l2Config) -> Result<Self, Error> {
        if !cfg.device.exists() {
            return Err(Error::NoDevice {
                path: cfg.device.clone(),
            });
        }
        #[cfg(feature = "v4l2")]
        {
            Ok(Self {
                inner: imp::Inner::open(cfg)?,
            })
        }
        #[cfg(not(feature = "v4l2"))]
        {
            Err(Error::Device {
                path: cfg.device.clone(),
                reason: "V4L2 support not built: enable the `v4l2` cargo feature \
                         of vlsync-signature-cam"
                    .into(),
            })
        }
    }

    /// Checked while waiting for a frame: `true` ends the stream (`Ok(None)`), e.g.
    /// the driver's SIGINT/SIGTERM flag. Without one only a frame or the stall
    /// limit ends a wait.
    pub fn set_stop(&mut self, stop: fn() -> bool) {
        #[cfg(feature = "v4l2")]
        {
            self.inner.stop = stop;
        }
        #[cfg(not(feature = "v4l2"))]
        {
            let _ = stop;
            match self._never {}
        }
    }

    /// Where the frames' times come from, once the first frames decided it (for
    /// [`V4l2Config::stamps`] of a reopen).
    pub fn stamp_choice(&self) -> Option<FrameStamps> {
        #[cfg(feature = "v4l2")]
        {
            self.inner.stamps.chosen()
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }

    /// What the opening negotiated (device, format, size, stride, frame rate,
    /// exposure), as its first note says.
    pub fn negotiated(&self) -> &negotiate::Negotiated {
        #[cfg(feature = "v4l2")]
        {
            &self.inner.negotiated
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }

    /// Drops the opening's notes not yet taken (the line of what was negotiated and
    /// the exposure warning): for a reopen that negotiated what the last opening
    /// said, which a stalled camera would otherwise repeat at every reopen.
    pub fn skip_opening_notes(&mut self) {
        #[cfg(feature = "v4l2")]
        {
            self.inner.notes.clear();
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }

    /// The frame size delivered, (width, height).
    pub fn frame_size(&self) -> (usize, usize) {
        #[cfg(feature = "v4l2")]
        {
            (self.inner.width, self.inner.height)
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }
}

impl FrameSource for V4l2Source {
    fn next_frame(&mut self) -> Result<Option<(GrayFrame<'_, u8>, FrameTime)>, Error> {
        #[cfg(feature = "v4l2")]
        {
            self.inner.next()
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }

    fn unusable(&self) -> Option<(u64, &str)> {
        #[cfg(feature = "v4l2")]
        {
            self.inner.unusable.counts()
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }

    /// The opening's line of what it negotiated, then its exposure warning (if the
    /// exposure is automatic), then the remark on the stamps' clock once the first
    /// frames decided it.
    fn take_note(&mut self) -> Option<String> {
        #[cfg(feature = "v4l2")]
        {
            self.inner
                .notes
                .pop_front()
                .or_else(|| self.inner.stamps.take_note())
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }
}

#[cfg(feature = "v4l2")]
mod imp {
    use super::negotiate::{
        self, caught, guarded, io_reason, DeviceId, Exposure, Modes, Negotiated, Offered, Rate,
        SizeOffered, StampPlan,
    };
    use super::*;
    use crate::sequence_clock::{Restart, SequenceClock};
    use std::collections::VecDeque;
    use std::path::Path;
    use v4l::buffer::Type;
    use v4l::control::Value;
    use v4l::frameinterval::FrameIntervalEnum;
    use v4l::framesize::FrameSizeEnum;
    use v4l::io::mmap::Stream;
    use v4l::io::traits::{CaptureStream, Stream as StreamTrait};
    use v4l::video::capture::Parameters;
    use v4l::video::Capture;
    use v4l::{Device, Format, FourCC, Fraction};

    /// The device and its stream, closed in that order when dropped. The stream is
    /// stopped first (`VIDIOC_STREAMOFF`, whose failure the `v4l` crate's `Drop`
    /// would turn into a panic, and its arena's `Drop` into a second one, an abort):
    /// a stream that stopped, or whose device is gone (`ENODEV`, which the crate
    /// ignores), is dropped with any panic caught; one that cannot be stopped is
    /// leaked (its buffers and file stay until the process ends) rather than dropped.
    /// Either is said on stderr, naming the device.
    struct Live {
        path: PathBuf,
        stream: Option<Stream<'static>>,
        dev: Option<Device>,
    }

    impl Drop for Live {
        fn drop(&mut self) {
            let say = |what: String| {
                vlsync_common::console::print_err(&format!(
                    "{}: closing the stream: {what}\n",
                    self.path.display()
                ))
            };
            if let Some(mut stream) = self.stream.take() {
                match stream.stop() {
                    Err(e) if e.raw_os_error() != Some(negotiate::errno::ENODEV) => {
                        say(format!(
                            "VIDIOC_STREAMOFF: {e}; the stream is left as it is (its buffers \
                             mapped, the device open until the driver ends: a reopen may find \
                             it busy)"
                        ));
                        std::mem::forget(stream);
                    }
                    _ => {
                        if let Err(e) = caught(&self.path, "release the buffers", move || {
                            drop(stream);
                            Ok(())
                        }) {
                            say(reason_of(e));
                        }
                    }
                }
            }
            if let Some(dev) = self.dev.take() {
                if let Err(e) = caught(&self.path, "close the device", move || {
                    drop(dev);
                    Ok(())
                }) {
                    say(reason_of(e));
                }
            }
        }
    }

    pub(super) struct Inner {
        path: PathBuf,
        live: Live,
        pub(super) width: usize,
        pub(super) height: usize,
        stride: usize,
        format: PixelFormat,
        gray: Vec<u8>,
        pub(super) unusable: UnusableFrames,
        pub(super) stop: fn() -> bool,
        stall: std::time::Duration,
        /// Whose stamps the frames carry (decided within the first frames).
        pub(super) stamps: StampCheck,
        /// Frames stamped at dequeue: their times from the buffers' sequence numbers.
        sequence: SequenceClock,
        /// A restart of `sequence` for this reason was said already.
        said_restart: [bool; 3],
        /// What the opening negotiated.
        pub(super) negotiated: Negotiated,
        /// The opening's notes not yet taken.
        pub(super) notes: VecDeque<String>,
        /// Every buffer is queued and none is ours: the next filled buffer is taken
        /// with a plain dequeue (the crate's `dequeue`, after which its `next` hands
        /// that buffer back first) and dropped unread: its bytes are reachable only
        /// through `next`, and a `next` now would queue again a buffer already
        /// queued, which the driver refuses. So at every opening, which queues all
        /// its buffers before the stream starts: its first frame is dropped (and
        /// counted among the frames that decide the stamps' clock,
        /// [`StampCheck::unread`]), every later one is read. So too after a `next`
        /// whose wait timed out (or was interrupted) once it had handed its buffer
        /// back, which the poll before each `next` makes unlikely.
        waiting: bool,
    }

    /// `POLLIN` (Linux): a filled buffer is ready to dequeue.
    const POLLIN: i16 = 0x001;

    fn transient(e: &std::io::Error) -> bool {
        matches!(
            e.kind(),
            std::io::ErrorKind::TimedOut
                | std::io::ErrorKind::Interrupted
                | std::io::ErrorKind::WouldBlock
        )
    }

    fn never() -> bool {
        false
    }

    /// `CLOCK_MONOTONIC` now, ns.
    fn monotonic_ns() -> Nanos {
        let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
        // tv_nsec is a C long: i32 on 32-bit ARM
        #[allow(clippy::useless_conversion)]
        t.tv_sec
            .saturating_mul(1_000_000_000)
            .saturating_add(i64::from(t.tv_nsec))
    }

    fn device_error(path: &Path, reason: String) -> Error {
        Error::Device {
            path: path.to_path_buf(),
            reason,
        }
    }

    /// The reason of a [`guarded`] call's error (for a line that names the device
    /// already).
    fn reason_of(e: Error) -> String {
        match e {
            Error::Device { reason, .. } => reason,
            e => e.to_string(),
        }
    }

    /// An integer control's value (`None`: no such control, or unreadable).
    fn control(path: &Path, dev: &Device, id: u32) -> Option<i64> {
        match guarded(path, "read a control (VIDIOC_G_EXT_CTRLS)", || {
            dev.control(id)
        }) {
            Ok(c) => match c.value {
                Value::Integer(v) => Some(v),
                Value::Boolean(b) => Some(i64::from(b)),
                _ => None,
            },
            Err(_) => None,
        }
    }

    impl Inner {
        pub(super) fn open(cfg: &V4l2Config) -> Result<Self, Error> {
            let path = cfg.device.clone();
            let p = path.as_path();
            let interval =
                match cfg.fps {
                    None => None,
                    Some(fps) => Some(negotiate::interval_for_fps(fps).ok_or_else(|| {
                        Error::InvalidConfig {
                            field: "V4l2Config::fps",
                            reason: format!(
                                "{fps} Hz is out of range: allowed {} ..= {} Hz",
                                negotiate::FPS_RANGE.start(),
                                negotiate::FPS_RANGE.end()
                            ),
                        }
                    })?),
                };
            // from here on, whatever returns early drops the device through `Live`
            let mut live = Live {
                path: path.clone(),
                stream: None,
                dev: None,
            };
            let dev: &Device = live
                .dev
                .insert(guarded(p, "open", || Device::with_path(p))?);
            let caps = guarded(p, "query capabilities (VIDIOC_QUERYCAP)", || {
                dev.query_caps()
            })?;
            let id = DeviceId {
                card: caps.card,
                driver: caps.driver,
                bus: caps.bus,
            };
            negotiate::check_caps(p, &id, caps.capabilities.bits())?;
            let id_err = |reason: String| device_error(p, format!("{id} {reason}"));
            let offered: Vec<Offered> =
                guarded(p, "list formats (VIDIOC_ENUM_FMT)", || dev.enum_formats())?
                    .into_iter()
                    .map(|d| Offered {
                        fourcc: d.fourcc.repr,
                        description: d.description,
                        compressed: d
                            .flags
                            .contains(v4l::format::description::Flags::COMPRESSED),
                    })
                    .collect();
            // each format's sizes and rates, asked only as far as the choice needs; a
            // driver that lists none (or whose answer the crate cannot read) lists
            // nothing, and the preference decides
            let modes = |f: PixelFormat| {
                let Some(code) = f.fourcc() else {
                    return Modes::default();
                };
                let fourcc = FourCC::new(&code);
                let sizes =
                    match caught(p, "VIDIOC_ENUM_FRAMESIZES", || dev.enum_framesizes(fourcc)) {
                        Ok(Ok(list)) => list.into_iter().map(|s| size_offered(s.size)).collect(),
                        _ => Vec::new(),
                    };
                let max_fps = match caught(p, "VIDIOC_ENUM_FRAMEINTERVALS", || {
                    dev.enum_frameintervals(fourcc, cfg.width, cfg.height)
                }) {
                    Ok(Ok(list)) => list
                        .iter()
                        .filter_map(|i| {
                            let fastest = match &i.interval {
                                FrameIntervalEnum::Discrete(f) => f,
                                FrameIntervalEnum::Stepwise(s) => &s.min,
                            };
                            negotiate::fps_of_interval(fastest.numerator, fastest.denominator)
                        })
                        .reduce(f64::max),
                    _ => None,
                };
                Modes { sizes, max_fps }
            };
            let (want, passed_over) =
                negotiate::choose_format_for(&offered, cfg.width, cfg.height, cfg.fps, modes)
                    .map_err(id_err)?;
            let code = want
                .fourcc()
                .ok_or_else(|| id_err(format!("{} has no V4L2 code", want.name())))?;
            let asked = Format::new(cfg.width, cfg.height, FourCC::new(&code));
            let got = guarded(p, "set format (VIDIOC_S_FMT)", || dev.set_format(&asked))?;
            // the driver may answer with another format than the one asked for
            let format = PixelFormat::from_fourcc(&got.fourcc.repr).ok_or_else(|| {
                id_err(format!(
                    "answered the format {} asked for with {}, which this source cannot read",
                    negotiate::fourcc_text(code),
                    negotiate::fourcc_text(got.fourcc.repr)
                ))
            })?;
            let stride =
                negotiate::check_geometry(format, got.width, got.height, got.stride, got.size)
                    .map_err(|r| id_err(format!("at {}: {r}", negotiate::fourcc_text(code))))?;
            // the frame rate after the format: the rates offered depend on the format and
            // size, and a format change may change the rate (uvcvideo fits it to the new
            // frame's)
            let rate = match (cfg.fps, interval) {
                (Some(fps), Some((num, den))) => {
                    let now = guarded(p, "get streaming parameters (VIDIOC_G_PARM)", || {
                        dev.params()
                    })
                    .map_err(|e| {
                        id_err(format!(
                            "cannot be asked for {}: {}",
                            negotiate::hz(fps),
                            reason_of(e)
                        ))
                    })?;
                    if !now
                        .capabilities
                        .contains(v4l::parameters::Capabilities::TIME_PER_FRAME)
                    {
                        return Err(id_err(format!(
                            "cannot set its frame rate (VIDIOC_G_PARM reports no \
                             V4L2_CAP_TIMEPERFRAME), so {} cannot be asked for: leave the rate \
                             to the camera (no --fps, camera.v4l2_fps = 0)",
                            negotiate::hz(fps)
                        )));
                    }
                    let set = guarded(p, "set the frame rate (VIDIOC_S_PARM)", || {
                        dev.set_params(&Parameters::new(Fraction::new(num, den)))
                    })?;
                    Rate {
                        asked: Some(fps),
                        granted: interval_rate(set.interval),
                    }
                }
                _ => Rate {
                    asked: None,
                    granted: match guarded(p, "VIDIOC_G_PARM", || dev.params()) {
                        Ok(now) => interval_rate(now.interval),
                        Err(e) => Err(reason_of(e)),
                    },
                },
            };
            let exposure = Exposure {
                mode: control(p, dev, negotiate::CID_EXPOSURE_AUTO),
                time_100us: control(p, dev, negotiate::CID_EXPOSURE_ABSOLUTE),
                dynamic_framerate: control(p, dev, negotiate::CID_EXPOSURE_AUTO_PRIORITY)
                    .map(|v| v != 0),
            };
            // two at least: one the driver fills while the other is read
            let asked_buffers = cfg.buffers.max(2);
            let stream: &mut Stream<'static> = live.stream.insert(guarded(
                p,
                "request buffers (VIDIOC_REQBUFS, VIDIOC_QUERYBUF, mmap)",
                || Stream::with_buffers(dev, Type::VideoCapture, asked_buffers),
            )?);
            stream.set_timeout(POLL_SLICE);
            // every buffer granted is queued here, buffer 0 included, and then the
            // stream started, so that a refusal to start (EBUSY, ENOSPC: USB bandwidth)
            // comes from its own step, named. None is left for the crate's first `next`
            // to queue: a vb2 driver starts streaming only once its
            // `min_buffers_needed` are queued, which may be every buffer granted (4 of
            // 4), and `Inner::next` polls for a filled buffer before it calls the
            // crate's `next`, so a buffer held back would stall every opening before
            // its first frame. With all of them queued the first frame is taken by a
            // plain dequeue and dropped unread (see `waiting`). Buffers the driver
            // did not grant end the queueing (EINVAL: an index beyond them; the crate
            // does not say how many it mapped), and the count queued is the one said.
            let buffers = negotiate::queue_all(asked_buffers, |i| {
                CaptureStream::queue(&mut *stream, i as usize)
            })
            .map_err(|reason| device_error(p, reason))?;
            guarded(p, "start streaming (VIDIOC_STREAMON)", || stream.start())?;
            // the buffers granted, all queued: each may hold an old stamp
            let decide_frames = decide_frames(buffers);
            let plan = match cfg.stamps {
                Some(c) => StampPlan::Kept(c),
                None => StampPlan::Check(decide_frames),
            };
            let negotiated = Negotiated {
                path: path.clone(),
                id,
                format,
                width: got.width,
                height: got.height,
                stride,
                rate,
                exposure,
                buffers,
            };
            let mut notes = VecDeque::from([format!("{negotiated}; {plan}")]);
            notes.extend(passed_over.map(|why| format!("{}: {why}", path.display())));
            notes.extend(exposure.warning(p));
            Ok(Self {
                path,
                live,
                width: got.width as usize,
                height: got.height as usize,
                stride,
                format,
                gray: Vec::new(),
                unusable: UnusableFrames::named("buffers"),
                stop: never,
                stall: cfg.stall,
                stamps: match cfg.stamps {
                    Some(c) => StampCheck::decided(c),
                    None => StampCheck::new(decide_frames),
                },
                sequence: SequenceClock::with_buffers(buffers),
                said_restart: [false; 3],
                negotiated,
                notes,
                // all queued above: the first frame is dequeued unread
                waiting: true,
            })
        }

        pub(super) fn next(&mut self) -> Result<Option<(GrayFrame<'_, u8>, FrameTime)>, Error> {
            let path = self.path.as_path();
            let Some(stream) = self.live.stream.as_mut() else {
                return Err(device_error(path, "the stream is closed".into()));
            };
            let mut since = std::time::Instant::now();
            let t_ns = loop {
                if (self.stop)() {
                    return Ok(None);
                }
                if since.elapsed() >= self.stall {
                    return Err(Error::Stalled {
                        path: path.to_path_buf(),
                        after: self.stall,
                    });
                }
                // wait here, a slice at a time, for a filled buffer: the others are
                // queued, so `next` below (which hands the last one back and dequeues)
                // finds one at once and never times out with a buffer of ours queued
                // unread; a slow camera's frames are all read
                let slice = POLL_SLICE.as_millis() as i32;
                match stream.handle().poll(POLLIN, slice) {
                    Ok(0) => continue,
                    Ok(_) => {}
                    Err(e) if transient(&e) => continue,
                    Err(e) => {
                        return Err(device_error(
                            path,
                            io_reason("wait for a buffer (poll)", &e),
                        ))
                    }
                }
                if self.waiting {
                    // every buffer queued (the opening's first frame, or a `next` gave
                    // up): take this buffer with a plain dequeue; the next `next` hands
                    // it back (unread: its bytes are reachable only through `next`) and
                    // reads the frame after it. A timeout here (the crate's dequeue
                    // polls for one slice) is a wake-up like the poll's.
                    let s = &mut *stream;
                    match caught(path, "dequeue buffer (VIDIOC_DQBUF)", move || {
                        CaptureStream::dequeue(s)
                    })? {
                        Ok(_) => {
                            self.waiting = false;
                            // dropped, and counted among the frames that decide the
                            // stamps' clock; the camera delivers, so the stall limit
                            // counts from here
                            self.stamps.unread();
                            since = std::time::Instant::now();
                        }
                        Err(e) if transient(&e) => {}
                        Err(e) => {
                            return Err(device_error(
                                path,
                                io_reason("dequeue buffer (VIDIOC_DQBUF)", &e),
                            ))
                        }
                    }
                    continue;
                }
                const NEXT: &str = "hand the last buffer back and dequeue the next \
                                    (VIDIOC_QBUF, VIDIOC_DQBUF)";
                let s = &mut *stream;
                let (buf, meta) = match caught(path, NEXT, move || s.next())? {
                    Ok(x) => x,
                    Err(e) if transient(&e) => {
                        self.waiting = true;
                        continue;
                    }
                    Err(e) => return Err(device_error(path, io_reason(NEXT, &e))),
                };
                // the clock read at once: a dequeue stamp carries no conversion time
                let now_ns = monotonic_ns();
                if meta.flags.contains(v4l::buffer::Flags::ERROR) {
                    BufferFault::Corrupt
                        .skip(meta.sequence, &mut self.unusable)
                        .map_err(|reason| device_error(path, reason))?;
                    continue;
                }
                // time_t is i32 on 32-bit ARM (32-bit Raspberry Pi OS), i64 elsewhere
                #[allow(clippy::unnecessary_cast)]
                let driver_ns = (meta.timestamp.sec as i64)
                    .saturating_mul(1_000_000_000)
                    .saturating_add((meta.timestamp.usec as i64).saturating_mul(1_000));
                let clock = StampClock::from_flags(u32::from(meta.flags));
                let Some(mut t_ns) = self.stamps.stamp(clock, driver_ns, now_ns) else {
                    // the stamps' clock is not decided yet: dropped, not converted; the
                    // camera delivers, so the stall limit counts from here (a slow
                    // camera must not stall out before its decision)
                    since = std::time::Instant::now();
                    continue;
                };
                if self.stamps.chosen() == Some(FrameStamps::Dequeue) {
                    t_ns = self.sequence.stamp(meta.sequence, now_ns);
                    if let Some(text) = self.sequence.take_restart().and_then(|why| {
                        let limit = self.sequence.behind_limit();
                        restart_note(path, why, meta.sequence, limit, &mut self.said_restart)
                    }) {
                        self.notes.push_back(text);
                    }
                }
                let used = (meta.bytesused as usize).min(buf.len());
                let raw = RawFrame::new(&buf[..used], self.width, self.height, self.format)
                    .with_stride(self.stride);
                // a short buffer (a cut transfer) is skipped on its length, before the
                // conversion makes an error value of it; a geometry no buffer converts
                // with is the conversion's error below
                if let Ok(need) = raw.bytes_needed() {
                    if used < need {
                        BufferFault::Short { used, need }
                            .skip(meta.sequence, &mut self.unusable)
                            .map_err(|reason| device_error(path, reason))?;
                        continue;
                    }
                }
                match raw.to_gray_into(&mut self.gray) {
                    Ok(()) => {
                        self.unusable.used();
                        break t_ns;
                    }
                    Err(e) if skippable(&e) => {
                        self.unusable
                            .skip_fmt(format_args!("buffer {}: {e}", meta.sequence))
                            .map_err(|reason| device_error(path, reason))?;
                    }
                    // the frame's geometry, not one buffer: every frame would fail
                    Err(e) => return Err(stream_format_error(path, e)),
                }
            };
            let frame = GrayFrame::borrowed(self.width, self.height, &self.gray)
                .map_err(|e| stream_format_error(path, e))?;
            Ok(Some((frame, FrameTime::Instant(t_ns))))
        }
    }

    /// The line on a restart of the dequeue stamps' line, the first of its kind
    /// (`said`, `Inner::said_restart`: each kind is said once, and made only then:
    /// a driver that does not count restarts at every frame); none for a pause or a
    /// long jump (the camera stopped delivering: said by the stall, if it lasts).
    /// `behind_limit`: the run of late frames that restarts the line
    /// ([`SequenceClock::behind_limit`]).
    pub(in crate::v4l2) fn restart_note(
        path: &Path,
        why: Restart,
        sequence: u32,
        behind_limit: usize,
        said: &mut [bool; 3],
    ) -> Option<String> {
        let slot = match why {
            Restart::Repeated => 0,
            Restart::Behind => 1,
            Restart::Slower => 2,
            Restart::Jump | Restart::Pause => return None,
        };
        if std::mem::replace(&mut said[slot], true) {
            return None;
        }
        let path = path.display();
        Some(match why {
            Restart::Repeated => format!(
                "{path}: the buffers' sequence numbers do not count up (buffer {sequence} \
                 came after one numbered the same or higher): frames are stamped at \
                 their dequeue times as they are until they do (said once)"
            ),
            Restart::Behind => format!(
                "{path}: {behind_limit} frames in a row came more than half a frame period \
                 after their line (the camera slowed down, or delivers later for good): \
                 the frame period is measured again from buffer {sequence} (said once)"
            ),
            // Restart::Slower (the others returned above)
            _ => format!(
                "{path}: {} frame intervals in a row were more than half a frame period \
                 longer than their sequence numbers say (the camera slowed down): the frame \
                 period is measured again from buffer {sequence} (said once)",
                crate::sequence_clock::SLOW_RUN
            ),
        })
    }

    /// A size the `v4l` crate lists, as the pure choice takes it.
    fn size_offered(s: FrameSizeEnum) -> SizeOffered {
        match s {
            FrameSizeEnum::Discrete(d) => SizeOffered::Discrete {
                width: d.width,
                height: d.height,
            },
            FrameSizeEnum::Stepwise(s) => SizeOffered::Stepwise {
                min: (s.min_width, s.min_height),
                max: (s.max_width, s.max_height),
                step: (s.step_width, s.step_height),
            },
        }
    }

    /// The rate of an interval the driver reports, or why it is none.
    fn interval_rate(i: Fraction) -> Result<f64, String> {
        negotiate::fps_of_interval(i.numerator, i.denominator).ok_or_else(|| {
            format!(
                "VIDIOC_G_PARM gave the frame interval {}/{}",
                i.numerator, i.denominator
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_device_is_named() {
        let cfg = V4l2Config {
            device: "/dev/video-vlsync-test-missing".into(),
            ..V4l2Config::default()
        };
        let e = V4l2Source::open(&cfg).unwrap_err();
        assert!(matches!(e, Error::NoDevice { .. }));
        assert_eq!(
            e.to_string(),
            "/dev/video-vlsync-test-missing: no such device"
        );
    }

    #[test]
    fn a_frame_format_error_names_the_device() {
        use crate::image::{PixelFormat, RawFrame};
        // an odd YUYV width: bad dimensions, which say nothing of the device
        let odd = RawFrame::new(&[0u8; 15 * 2 * 8], 15, 8, PixelFormat::Yuyv)
            .to_gray_into(&mut Vec::new())
            .unwrap_err();
        assert!(matches!(odd, Error::BadDimensions { .. }), "{odd}");
        let e = stream_format_error(std::path::Path::new("/dev/video7"), odd).to_string();
        assert!(
            e.starts_with("/dev/video7: its frames cannot be converted: bad frame dimensions 15x8"),
            "{e}"
        );
    }

    #[test]
    fn only_a_short_buffer_is_skippable() {
        use crate::image::{PixelFormat, RawFrame};
        // a short transfer: one buffer's fault
        let short = RawFrame::new(&[0u8; 100], 16, 8, PixelFormat::Yuyv)
            .to_gray_into(&mut Vec::new())
            .unwrap_err();
        assert!(skippable(&short), "{short}");
        // an odd YUYV width: the stream's format, every frame would fail
        let odd = RawFrame::new(&[0u8; 15 * 2 * 8], 15, 8, PixelFormat::Yuyv)
            .to_gray_into(&mut Vec::new())
            .unwrap_err();
        assert!(!skippable(&odd), "{odd}");
    }

    #[cfg(not(feature = "v4l2"))]
    #[test]
    fn without_feature_an_existing_node_says_so() {
        // any existing path stands in for a device node
        let cfg = V4l2Config {
            device: std::env::temp_dir(),
            ..V4l2Config::default()
        };
        let e = V4l2Source::open(&cfg).unwrap_err();
        assert!(e.to_string().contains("`v4l2` cargo feature"), "{e}");
    }

    #[cfg(feature = "v4l2")]
    #[test]
    fn a_non_device_is_an_error_not_a_panic() {
        let dir = std::env::temp_dir();
        let cfg = V4l2Config {
            device: dir.clone(),
            ..V4l2Config::default()
        };
        let e = V4l2Source::open(&cfg).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: open: ", dir.display())), "{e}");
        // a regular file opens, and is no V4L2 node: the first ioctl says so, named
        let file = dir.join(format!("vlsync-v4l2-not-a-device-{}", std::process::id()));
        std::fs::write(&file, b"").unwrap();
        let cfg = V4l2Config {
            device: file.clone(),
            ..V4l2Config::default()
        };
        let e = V4l2Source::open(&cfg).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!(
                "{}: query capabilities (VIDIOC_QUERYCAP): ",
                file.display()
            )),
            "{e}"
        );
        // a frame rate out of range is refused before the device is touched
        for fps in [0.5, 1e4, f64::NAN] {
            let e = V4l2Source::open(&V4l2Config {
                fps: Some(fps),
                ..cfg.clone()
            })
            .unwrap_err();
            assert!(
                matches!(&e, Error::InvalidConfig { field: "V4l2Config::fps", reason }
                    if reason.ends_with("allowed 1 ..= 1000 Hz")),
                "{e}"
            );
        }
        std::fs::remove_file(&file).unwrap();
    }

    const S: Nanos = 1_000_000_000;
    const MS: Nanos = 1_000_000;

    #[cfg(feature = "v4l2")]
    #[test]
    fn a_restart_is_said_once_a_kind_with_the_run_that_made_it() {
        use crate::sequence_clock::{Restart, SequenceClock};
        let path = std::path::Path::new("/dev/video2");
        let mut said = [false; 3];
        // 12 buffers: the line restarts after 24 late frames, not BEHIND_RUN's 8
        let limit = SequenceClock::with_buffers(12).behind_limit();
        let note = imp::restart_note(path, Restart::Behind, 77, limit, &mut said).unwrap();
        assert!(
            note.starts_with("/dev/video2: 24 frames in a row came more than half"),
            "{note}"
        );
        assert!(note.contains("from buffer 77"), "{note}");
        assert_eq!(
            imp::restart_note(path, Restart::Behind, 78, limit, &mut said),
            None
        );
        let note = imp::restart_note(path, Restart::Slower, 90, limit, &mut said).unwrap();
        assert!(note.contains("(the camera slowed down)"), "{note}");
        assert!(imp::restart_note(path, Restart::Repeated, 3, limit, &mut said).is_some());
        for why in [
            Restart::Repeated,
            Restart::Slower,
            Restart::Jump,
            Restart::Pause,
        ] {
            assert_eq!(imp::restart_note(path, why, 5, limit, &mut said), None);
        }
    }

    #[test]
    fn the_flags_name_the_clock() {
        assert_eq!(StampClock::from_flags(0x2000), StampClock::Monotonic);
        // with other bits set (MAPPED, DONE, TSTAMP_SRC_SOE)
        assert_eq!(StampClock::from_flags(0x1_2005), StampClock::Monotonic);
        assert_eq!(StampClock::from_flags(0x4000), StampClock::Copied);
        assert_eq!(StampClock::from_flags(0), StampClock::Unknown);
        assert_eq!(StampClock::from_flags(0xe000), StampClock::Unknown);
    }

    /// Frames to decide in (the default 4 buffers and the extra 4).
    const N: u32 = 8;

    #[test]
    fn monotonic_stamps_are_used_as_they_are_and_said_nothing_of() {
        let mut c = StampCheck::new(N);
        // exposed 40 ms before the dequeue
        assert_eq!(
            c.stamp(StampClock::Monotonic, 100 * S, 100 * S + 40 * MS),
            Some(100 * S)
        );
        assert_eq!(c.chosen(), Some(FrameStamps::Driver));
        assert_eq!(c.take_note(), None);
        // later frames keep the driver's stamps, even one dequeued late
        assert_eq!(
            c.stamp(StampClock::Monotonic, 101 * S, 103 * S),
            Some(101 * S)
        );
    }

    #[test]
    fn unflagged_stamps_on_the_monotonic_clock_are_used_and_said_so() {
        let mut c = StampCheck::new(N);
        assert_eq!(
            c.stamp(StampClock::Unknown, 50 * S, 50 * S + 33 * MS),
            Some(50 * S)
        );
        assert_eq!(c.chosen(), Some(FrameStamps::Driver));
        let note = c.take_note().unwrap();
        assert_eq!(
            note,
            "the driver's buffer stamps (V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN) are on \
             CLOCK_MONOTONIC: frame 1's is 33.0 ms before its dequeue; its stamps are used"
        );
        assert_eq!(c.take_note(), None);
    }

    #[test]
    fn frames_queued_while_the_driver_was_held_up_are_dropped_not_mixed() {
        // held up 3 s before the first read: the 4 queued buffers are old, the
        // frame after them fresh
        let mut c = StampCheck::new(N);
        for i in 0..4 {
            assert_eq!(
                c.stamp(StampClock::Monotonic, 10 * S + i * 33 * MS, 13 * S),
                None
            );
            assert_eq!(c.chosen(), None);
        }
        assert_eq!(c.take_note(), None);
        let t = 13 * S - 5 * MS;
        assert_eq!(c.stamp(StampClock::Monotonic, t, 13 * S), Some(t));
        assert_eq!(c.chosen(), Some(FrameStamps::Driver));
        let note = c.take_note().unwrap();
        assert!(
            note.contains("frame 5's is 5.0 ms before its dequeue"),
            "{note}"
        );
        assert!(
            note.ends_with(
                "the 4 frames before it, the first 3.000 s old at its dequeue, were dropped"
            ),
            "{note}"
        );
        // from then on the driver's stamps, whatever their age
        assert_eq!(c.stamp(StampClock::Monotonic, 14 * S, 20 * S), Some(14 * S));
    }

    #[test]
    fn stamps_off_the_monotonic_clock_give_way_to_the_dequeue_time() {
        // zero stamps: every frame would repeat the last one's time
        let mut c = StampCheck::new(N);
        for i in 0..N as i64 {
            let now = 7 * S + i * 33 * MS;
            let last = i + 1 == N as i64;
            assert_eq!(c.stamp(StampClock::Monotonic, 0, now), last.then_some(now));
            assert_eq!(c.chosen().is_some(), last);
            assert_eq!(c.take_note().is_some(), last);
        }
        assert_eq!(c.chosen(), Some(FrameStamps::Dequeue));
        // the wall clock: decades after the monotonic clock's reading
        let mut c = StampCheck::new(N);
        let wall = 1_796_000_000 * S;
        for i in 0..N as i64 {
            c.stamp(StampClock::Unknown, wall + i * S, 9 * S + i * S);
        }
        let note = c.take_note().unwrap();
        assert!(
            note.starts_with("the driver's buffer stamps (V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN) are not on CLOCK_MONOTONIC: none of the first 8 frames' stamps is within 1 s before its dequeue"),
            "{note}"
        );
        assert!(
            note.contains("s after it; the last stamp 1796000007.000000 s (the wall clock"),
            "{note}"
        );
        assert!(
            note.contains("from frame 8 on, frames are stamped at dequeue instead"),
            "{note}"
        );
        assert!(
            note.ends_with("the 7 frames before it were dropped"),
            "{note}"
        );
        // the choice holds: a later stamp that would pass is not switched to
        assert_eq!(
            c.stamp(StampClock::Unknown, 20 * S, 20 * S + MS),
            Some(20 * S + MS)
        );
        // the margins, exactly
        let mut c = StampCheck::new(N);
        assert_eq!(
            c.stamp(StampClock::Monotonic, S + MAX_STAMP_AHEAD_NS + 1, S),
            None
        );
        let mut c = StampCheck::new(N);
        c.stamp(StampClock::Unknown, S + MAX_STAMP_AHEAD_NS, S);
        assert_eq!(c.chosen(), Some(FrameStamps::Driver));
        let note = c.take_note().unwrap();
        assert!(
            note.contains("frame 1's is 1.000 ms after its dequeue"),
            "{note}"
        );
        let mut c = StampCheck::new(N);
        c.stamp(StampClock::Monotonic, S, S + MAX_STAMP_AGE_NS);
        assert_eq!(c.chosen(), Some(FrameStamps::Driver));
    }

    #[test]
    fn the_first_frame_dropped_unread_counts_among_the_first_frames() {
        // an opening's first frame is taken unread: a camera on the monotonic clock
        // is still said nothing of, its second frame decides
        let mut c = StampCheck::new(N);
        c.unread();
        assert_eq!(c.chosen(), None);
        let t = 100 * S;
        assert_eq!(c.stamp(StampClock::Monotonic, t, t + 40 * MS), Some(t));
        assert_eq!(c.chosen(), Some(FrameStamps::Driver));
        assert_eq!(c.take_note(), None);
        // flagged as another clock: the note names the stream's frame
        let mut c = StampCheck::new(N);
        c.unread();
        c.stamp(StampClock::Unknown, t, t + 33 * MS);
        assert_eq!(
            c.take_note().unwrap(),
            "the driver's buffer stamps (V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN) are on \
             CLOCK_MONOTONIC: frame 2's is 33.0 ms before its dequeue; its stamps are used; \
             the frame before it was dropped unread"
        );
        // held up 3 s before the first read: 4 queued buffers filled, the first
        // dropped unread, the 3 others read and dropped, frame 5 fresh (as before the
        // opening queued them all: the same frame decides)
        let mut c = StampCheck::new(N);
        c.unread();
        for i in 1..4 {
            assert_eq!(
                c.stamp(StampClock::Monotonic, 10 * S + i * 33 * MS, 13 * S),
                None
            );
        }
        let t = 13 * S - 5 * MS;
        assert_eq!(c.stamp(StampClock::Monotonic, t, 13 * S), Some(t));
        let note = c.take_note().unwrap();
        assert!(
            note.contains("frame 5's is 5.0 ms before its dequeue"),
            "{note}"
        );
        assert!(
            note.ends_with(
                "the 4 frames before it were dropped (1 unread; the first read 2.967 s old \
                 at its dequeue)"
            ),
            "{note}"
        );
        // stamps off the clock: the unread frame counts, so the decision comes at the
        // N-th frame of the stream, as the opening's line says
        let mut c = StampCheck::new(N);
        c.unread();
        for i in 1..N as i64 {
            let now = 7 * S + i * 33 * MS;
            let last = i + 1 == N as i64;
            assert_eq!(c.stamp(StampClock::Monotonic, 0, now), last.then_some(now));
        }
        let note = c.take_note().unwrap();
        assert!(
            note.contains(
                "none of the first 8 frames' stamps (7 of them read) is within 1 s before its \
                 dequeue (the first read was 7.033 s before it; the last stamp 0.000000 s (zero))"
            ),
            "{note}"
        );
        assert!(note.contains("from frame 8 on"), "{note}");
        assert!(
            note.ends_with("the 7 frames before it were dropped (1 unread)"),
            "{note}"
        );
        // once decided (a reopen keeps the choice), an unread frame changes nothing
        let mut c = StampCheck::decided(FrameStamps::Driver);
        c.unread();
        assert_eq!(c.stamp(StampClock::Monotonic, 5 * S, 6 * S), Some(5 * S));
        assert_eq!(c.take_note(), None);
    }

    #[test]
    fn the_decision_waits_out_every_buffer_the_driver_granted() {
        // asked for 4, granted 8, the first read 3 s after the stream's start:
        // all 8 queued buffers hold old stamps (the first dropped unread), the
        // frame after them is fresh. A window of the 4 asked for and 4 more
        // ends with the 8th frame, old, and would stamp this CLOCK_MONOTONIC
        // camera at dequeue for the whole run; one of the 8 granted and 4 more
        // reaches the fresh frame
        let (asked, granted) = (4u32, 8u32);
        assert_eq!(decide_frames(granted), 12);
        let run = |window: u32| {
            let mut c = StampCheck::new(window);
            c.unread();
            for i in 1..granted as i64 {
                if let Some(t) = c.stamp(StampClock::Monotonic, 10 * S + i * 33 * MS, 13 * S) {
                    return (i + 1, t, c.chosen());
                }
            }
            let fresh = 13 * S + 30 * MS;
            let t = c
                .stamp(StampClock::Monotonic, fresh - 5 * MS, fresh)
                .unwrap();
            (granted as i64 + 1, t, c.chosen())
        };
        assert_eq!(run(asked + 4), (8, 13 * S, Some(FrameStamps::Dequeue)));
        assert_eq!(
            run(decide_frames(granted)),
            (9, 13 * S + 25 * MS, Some(FrameStamps::Driver))
        );
        // a count near the top does not wrap
        assert_eq!(decide_frames(u32::MAX - 1), u32::MAX);
    }

    #[test]
    fn a_reopen_keeps_the_earlier_choice_and_says_nothing() {
        for choice in [FrameStamps::Driver, FrameStamps::Dequeue] {
            let mut c = StampCheck::decided(choice);
            // a zero stamp, and one the window would take: the choice holds for both
            let first = c.stamp(StampClock::Monotonic, 0, 5 * S);
            let second = c.stamp(StampClock::Monotonic, 6 * S, 6 * S + MS);
            match choice {
                FrameStamps::Driver => assert_eq!((first, second), (Some(0), Some(6 * S))),
                FrameStamps::Dequeue => {
                    assert_eq!((first, second), (Some(5 * S), Some(6 * S + MS)))
                }
            }
            assert_eq!(c.take_note(), None);
        }
        assert_eq!(V4l2Config::default().stamps, None);
    }

    proptest::proptest! {
        /// Any flags and times: no panic; the first frame within the window among the
        /// first `n` decides for the driver from that frame on, without one the
        /// n-th frame decides for the dequeue time; frames before the decision are
        /// dropped.
        #[test]
        fn the_first_frames_decide_for_the_stream(
            flags in proptest::prelude::any::<u32>(),
            n in 1u32..8,
            // about half of the frames within the window or near its edges
            frames in proptest::collection::vec(
                (
                    proptest::prelude::any::<i64>(),
                    proptest::prop_oneof![
                        -2 * MAX_STAMP_AHEAD_NS..2 * MAX_STAMP_AGE_NS,
                        proptest::prelude::any::<i64>(),
                    ],
                ),
                1..12,
            ),
        ) {
            let mut c = StampCheck::new(n);
            let clock = StampClock::from_flags(flags);
            // the window, stated apart from the implementation's expression: a
            // stamp from 1 s before the clock's reading at its dequeue to 1 ms
            // after it, the difference taken exactly
            let in_window = |d: i64, now: i64| {
                (-1_000_000i128..=1_000_000_000).contains(&(i128::from(now) - i128::from(d)))
            };
            let first_in = frames
                .iter()
                .take(n as usize)
                .position(|&(d, age)| in_window(d, d.saturating_add(age)));
            for (i, &(d, age)) in frames.iter().enumerate() {
                let now = d.saturating_add(age);
                let expect = match first_in {
                    Some(k) if i >= k => Some(d),
                    Some(_) => None,
                    None if i + 1 >= n as usize => Some(now),
                    None => None,
                };
                proptest::prop_assert_eq!(c.stamp(clock, d, now), expect);
            }
            let decided = first_in.is_some() || frames.len() >= n as usize;
            proptest::prop_assert_eq!(c.chosen().is_some(), decided);
            let expect_note = match first_in {
                Some(k) => k > 0 || clock != StampClock::Monotonic,
                None => decided,
            };
            proptest::prop_assert_eq!(c.take_note().is_some(), expect_note);
        }
    }
}
