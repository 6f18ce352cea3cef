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
//! up in the estimated offset.
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
        }
    }
}

/// Whether a conversion error is one buffer's (a short transfer), to be skipped,
/// rather than the stream's format, which every frame would repeat.
pub fn skippable(e: &Error) -> bool {
    matches!(e, Error::BufferSize { .. })
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
            let since = std::time::Instant::now();
            let ts = loop {
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
                if meta.flags.contains(v4l::buffer::Flags::ERROR) {
                    let why = format!("buffer {} flagged corrupt by the driver", meta.sequence);
                    self.unusable
                        .skip(why)
                        .map_err(|reason| self.device_error(reason))?;
                    continue;
                }
                let used = (meta.bytesused as usize).min(buf.len());
                let raw = RawFrame::new(&buf[..used], self.width, self.height, self.format)
                    .with_stride(stride);
                match raw.to_gray_into(&mut self.gray) {
                    Ok(()) => {
                        self.unusable.used();
                        break meta.timestamp;
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
            // time_t is i32 on 32-bit ARM (32-bit Raspberry Pi OS), i64 elsewhere
            #[allow(clippy::unnecessary_cast)]
            let t_ns = (ts.sec as i64)
                .saturating_mul(1_000_000_000)
                .saturating_add((ts.usec as i64).saturating_mul(1_000));
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
}
