//! V4L2 camera source (Linux), behind the cargo feature `v4l2`.
//!
//! The feature pulls the `v4l` crate, whose `v4l2-sys-mit` dependency generates
//! its bindings with bindgen at build time and so **needs libclang** on the build
//! machine (Debian: `apt-get install libclang-dev`). Without the feature the type
//! still exists and [`V4l2Source::open`] returns an error saying so (after
//! reporting a missing device as `/dev/video0: no such device`).
//!
//! Frames are requested as YUYV (the usual format of the Pi camera stack and of
//! USB cameras); GREY, RGB3 and BGR3 are accepted if the driver insists on one of
//! them. Each frame is stamped with the driver's buffer timestamp
//! ([`FrameTime::Instant`]), normally `CLOCK_MONOTONIC`; whether that is the
//! start of exposure or the end of the frame depends on the driver
//! (`V4L2_BUF_FLAG_TSTAMP_SRC_*`), so the constant part of that difference shows
//! up in the estimated offset. A driver whose stamps are on another clock (flagged
//! `V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN`, or all zero, or on the wall clock, which NTP
//! steps) would otherwise give the daemon stamps that repeat or jump: an opening
//! checks its first frames' stamps against `CLOCK_MONOTONIC` read at their dequeue
//! ([`StampCheck`]), and stamps that cannot be on that clock make the stream stamp
//! its frames at dequeue instead, said once ([`FrameSource::take_note`]); a reopen
//! keeps the earlier opening's choice ([`V4l2Config::stamps`]).
//!
//! A buffer the driver flags as corrupt (`V4L2_BUF_FLAG_ERROR`, as USB cameras do
//! when a transfer is cut) or one too short for its frame is skipped and counted
//! ([`FrameSource::unusable`]); the signature then treats it as a dropped frame: the
//! next frame pairs with the last good one over their true interval, or, past the
//! signature's `max_gap_ns`, restarts the pair (a counted gap). Only
//! [`MAX_UNUSABLE_IN_ROW`](crate::source::MAX_UNUSABLE_IN_ROW) such buffers in a
//! row (a second at 30 Hz: a device that delivers nothing usable) end the stream
//! with an error saying why; a frame format the converter cannot read at all (an
//! odd YUYV width) ends it at the first frame, and a negotiated stride shorter than
//! a row is refused at [`V4l2Source::open`].
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

use crate::image::GrayFrame;
#[cfg(feature = "v4l2")]
use crate::image::{PixelFormat, RawFrame};
use crate::signature::FrameTime;
use crate::source::FrameSource;
use crate::Error;
use std::path::PathBuf;
use vlsync_common::Nanos;

/// What to open and how.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct V4l2Config {
    /// Device node (default `/dev/video0`).
    pub device: PathBuf,
    /// Requested width (default 640); the driver may pick another.
    pub width: u32,
    /// Requested height (default 480); the driver may pick another.
    pub height: u32,
    /// Driver buffers (default 4).
    pub buffers: u32,
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

/// Frames beyond the buffers requested that a stream's stamps get to show they are
/// on `CLOCK_MONOTONIC`: a driver held up between the stream's start and its first
/// read finds every queued buffer filled, each with an old stamp, and only the
/// frames after them are fresh; a V4L2 driver may also grant a few more buffers than
/// requested. Only a stream whose stamps are not on that clock waits out all of them
/// (8 frames at the default 4 buffers: a quarter of a second at 30 Hz).
pub const DECIDE_EXTRA_FRAMES: u32 = 4;

/// Decides, at a stream's first frames, whether the driver's buffer stamps are on
/// `CLOCK_MONOTONIC`, whatever the flags say. The first stamp found from
/// [`MAX_STAMP_AGE_NS`] before the clock's reading at its dequeue to
/// [`MAX_STAMP_AHEAD_NS`] after it, within the first `decide_frames`, makes the
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
    /// Frames seen while undecided.
    seen: u32,
    /// The first of them: its stamp's age at its dequeue, ns.
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
        self.seen += 1;
        let first_age = *self.first_age.get_or_insert(age);
        let dropped = self.seen - 1;
        let dropped_text = match dropped {
            0 => String::new(),
            1 => format!(
                "; the frame before it, {:.3} s old at its dequeue, was dropped",
                first_age as f64 * 1e-9
            ),
            n => format!(
                "; the {n} frames before it, the first {:.3} s old at its dequeue, were dropped",
                first_age as f64 * 1e-9
            ),
        };
        if (-MAX_STAMP_AHEAD_NS..=MAX_STAMP_AGE_NS).contains(&age) {
            self.chosen = Some(FrameStamps::Driver);
            self.note = (clock != StampClock::Monotonic || dropped > 0).then(|| {
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
                 first {} frames' stamps is within {:.0} s before its dequeue (the first \
                 was {when} it; the last stamp {:.6} s{looks}); from frame {} on, frames \
                 are stamped at dequeue instead, later by the driver's delivery latency \
                 (its constant part shows up in the offset) and with its jitter, and \
                 frames queued while the driver falls behind get bunched times{}",
                clock.name(),
                self.seen,
                MAX_STAMP_AGE_NS as f64 * 1e-9,
                driver_ns as f64 * 1e-9,
                self.seen,
                match dropped {
                    0 => String::new(),
                    1 => "; the frame before it was dropped".to_string(),
                    n => format!("; the {n} frames before it were dropped"),
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

    fn take_note(&mut self) -> Option<String> {
        #[cfg(feature = "v4l2")]
        {
            self.inner.stamps.take_note()
        }
        #[cfg(not(feature = "v4l2"))]
        {
            match self._never {}
        }
    }
}

#[cfg(feature = "v4l2")]
mod imp {
    use super::*;
    use crate::source::UnusableFrames;
    use v4l::buffer::Type;
    use v4l::io::mmap::Stream;
    use v4l::io::traits::CaptureStream;
    use v4l::video::Capture;
    use v4l::{Device, FourCC};

    pub(super) struct Inner {
        path: PathBuf,
        // the stream keeps its own handle to the device
        stream: Stream<'static>,
        _dev: Device,
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
        /// The stream runs (the first `next` queued every buffer and started it).
        started: bool,
        /// A `next` whose wait for a buffer timed out (or was interrupted) left the
        /// buffer it handed back queued, and holds none: the next filled buffer is
        /// taken with a plain dequeue and handed back unread (a second `next` would
        /// queue that buffer again, which the driver refuses). Only the first frame
        /// can end so: later waits poll before `next`, which then does not wait.
        waiting: bool,
    }

    /// `POLLIN` (Linux): a filled buffer is ready to dequeue.
    const POLLIN: i16 = 0x001;

    fn transient(e: &std::io::Error) -> bool {
        matches!(
            e.kind(),
            std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted
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

    impl Inner {
        pub(super) fn open(cfg: &V4l2Config) -> Result<Self, Error> {
            let path = cfg.device.clone();
            let dev_err = |what: &str, e: std::io::Error| Error::Device {
                path: path.clone(),
                reason: format!("{what}: {e}"),
            };
            let dev = Device::with_path(&path).map_err(|e| dev_err("open", e))?;
            let mut fmt = dev.format().map_err(|e| dev_err("get format", e))?;
            fmt.width = cfg.width;
            fmt.height = cfg.height;
            fmt.fourcc = FourCC::new(b"YUYV");
            let fmt = dev.set_format(&fmt).map_err(|e| dev_err("set format", e))?;
            let format = match &fmt.fourcc.repr {
                b"YUYV" => PixelFormat::Yuyv,
                b"GREY" => PixelFormat::Gray8,
                b"RGB3" => PixelFormat::Rgb8,
                b"BGR3" => PixelFormat::Bgr8,
                other => {
                    return Err(Error::Device {
                        path,
                        reason: format!(
                            "unsupported pixel format {} (need YUYV, GREY, RGB3 or BGR3)",
                            String::from_utf8_lossy(other)
                        ),
                    })
                }
            };
            let row = (fmt.width as usize).saturating_mul(format.bytes_per_pixel());
            if fmt.stride != 0 && (fmt.stride as usize) < row {
                return Err(Error::Device {
                    path,
                    reason: format!(
                        "the driver's stride {} is shorter than a {}x{} {} row ({row} bytes)",
                        fmt.stride,
                        fmt.width,
                        fmt.height,
                        format.name()
                    ),
                });
            }
            // two at least: one the driver fills while the other is read
            let mut stream = Stream::with_buffers(&dev, Type::VideoCapture, cfg.buffers.max(2))
                .map_err(|e| dev_err("start mmap stream", e))?;
            stream.set_timeout(POLL_SLICE);
            Ok(Self {
                path,
                stream,
                _dev: dev,
                width: fmt.width as usize,
                height: fmt.height as usize,
                stride: fmt.stride as usize,
                format,
                gray: Vec::new(),
                unusable: UnusableFrames::named("buffers"),
                stop: never,
                stall: cfg.stall,
                stamps: match cfg.stamps {
                    Some(c) => StampCheck::decided(c),
                    None => StampCheck::new(cfg.buffers.max(2).saturating_add(DECIDE_EXTRA_FRAMES)),
                },
                started: false,
                waiting: false,
            })
        }

        fn device_error(&self, reason: String) -> Error {
            Error::Device {
                path: self.path.clone(),
                reason,
            }
        }

        pub(super) fn next(&mut self) -> Result<Option<(GrayFrame<'_, u8>, FrameTime)>, Error> {
            let stride = if self.stride == 0 {
                self.width.saturating_mul(self.format.bytes_per_pixel())
            } else {
                self.stride
            };
            let mut since = std::time::Instant::now();
            let t_ns = loop {
                if (self.stop)() {
                    return Ok(None);
                }
                if since.elapsed() >= self.stall {
                    return Err(Error::Stalled {
                        path: self.path.clone(),
                        after: self.stall,
                    });
                }
                if self.started {
                    // wait here, a slice at a time, for a filled buffer: the others
                    // are queued, so `next` below (which hands the last one back and
                    // dequeues) finds one at once and never times out with a buffer
                    // of ours queued unread; a slow camera's frames are all read
                    let slice = POLL_SLICE.as_millis() as i32;
                    match self.stream.handle().poll(POLLIN, slice) {
                        Ok(0) => continue,
                        Ok(_) => {}
                        Err(e) if transient(&e) => continue,
                        Err(e) => return Err(self.device_error(format!("wait for a buffer: {e}"))),
                    }
                    if self.waiting {
                        // the first `next` gave up: take this buffer with a plain
                        // dequeue; the next `next` hands it back (unread: its bytes are
                        // reachable only through `next`) and reads the frame after it
                        match CaptureStream::dequeue(&mut self.stream) {
                            Ok(_) => self.waiting = false,
                            Err(e) if transient(&e) => {}
                            Err(e) => return Err(self.device_error(format!("dequeue buffer: {e}"))),
                        }
                        continue;
                    }
                }
                let result = self.stream.next();
                // the first call queued every buffer and started the stream, whether
                // or not its wait then timed out
                self.started = true;
                let (buf, meta) = match result {
                    Ok(x) => x,
                    Err(e) if transient(&e) => {
                        self.waiting = true;
                        continue;
                    }
                    Err(e) => {
                        return Err(Error::Device {
                            path: self.path.clone(),
                            reason: format!("dequeue buffer: {e}"),
                        })
                    }
                };
                // the clock read at once: a dequeue stamp carries no conversion time
                let now_ns = monotonic_ns();
                if meta.flags.contains(v4l::buffer::Flags::ERROR) {
                    let why = format!("buffer {} flagged corrupt by the driver", meta.sequence);
                    self.unusable
                        .skip(why)
                        .map_err(|reason| self.device_error(reason))?;
                    continue;
                }
                // time_t is i32 on 32-bit ARM (32-bit Raspberry Pi OS), i64 elsewhere
                #[allow(clippy::unnecessary_cast)]
                let driver_ns = (meta.timestamp.sec as i64)
                    .saturating_mul(1_000_000_000)
                    .saturating_add((meta.timestamp.usec as i64).saturating_mul(1_000));
                let clock = StampClock::from_flags(u32::from(meta.flags));
                let Some(t_ns) = self.stamps.stamp(clock, driver_ns, now_ns) else {
                    // the stamps' clock is not decided yet: dropped, not converted; the
                    // camera delivers, so the stall limit counts from here (a slow
                    // camera must not stall out before its decision)
                    since = std::time::Instant::now();
                    continue;
                };
                let used = (meta.bytesused as usize).min(buf.len());
                let raw = RawFrame::new(&buf[..used], self.width, self.height, self.format)
                    .with_stride(stride);
                match raw.to_gray_into(&mut self.gray) {
                    Ok(()) => {
                        self.unusable.used();
                        break t_ns;
                    }
                    Err(e) if skippable(&e) => {
                        let why = format!("buffer {}: {e}", meta.sequence);
                        self.unusable
                            .skip(why)
                            .map_err(|reason| self.device_error(reason))?;
                    }
                    // the frame's geometry, not one buffer: every frame would fail
                    Err(e) => return Err(e),
                }
            };
            let frame = GrayFrame::borrowed(self.width, self.height, &self.gray)?;
            Ok(Some((frame, FrameTime::Instant(t_ns))))
        }
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
        let cfg = V4l2Config {
            device: std::env::temp_dir(),
            ..V4l2Config::default()
        };
        assert!(V4l2Source::open(&cfg).is_err());
    }

    const S: Nanos = 1_000_000_000;
    const MS: Nanos = 1_000_000;

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
            let window = -MAX_STAMP_AHEAD_NS..=MAX_STAMP_AGE_NS;
            let first_in = frames
                .iter()
                .take(n as usize)
                .position(|&(d, age)| window.contains(&d.saturating_add(age).saturating_sub(d)));
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
