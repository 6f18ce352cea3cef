//! Raw frames from a pipe: what a camera program writes to its standard output,
//! one uncompressed frame after another (`rpicam-vid --codec yuv420 -o -` for a
//! Raspberry Pi camera module, `gst-launch-1.0 ... ! fdsink`, `ffmpeg -f rawvideo`).
//!
//! The frames carry no stamps: each is stamped with the caller's clock (the
//! driver's `CLOCK_MONOTONIC`) when its first byte arrives, i.e. when the writer
//! began to write it. What lies before that (exposure, the camera's and the
//! writer's pipeline) is a delay vlsync measures like any other, as long as it
//! stays constant.
//!
//! A frame's first bytes are seen arrive when the source was waiting for them:
//! at the start of the frame, or at the end of the frame before, whose last
//! bytes came in the same write (a writer that buffers its output, as
//! `rpicam-vid -o -` does without `--flush`, sends each frame's tail with the
//! next frame's head). A frame already waiting when the source asks for it
//! otherwise (the reader was held up: its stamp would be late by an unknown
//! amount) is read and dropped, counted as *queued*; reading it takes
//! microseconds, so the frame after it is waited for and stamped on time again.
//!
//! Both inferences need the wait to tell the writer's own time: a frame larger
//! than the pipe's buffer (64 KiB on Linux; 320x240 I420 is 115,200 bytes) keeps
//! a writer that fell behind blocked inside it, and each read lets it write on
//! within microseconds, the frames it owes right behind. So a frame's tail
//! brings the next frame's head only when it was waited for long (a quarter of
//! the frames' interval, at least [`LONG_WAIT_MIN`]: a buffering writer's tail
//! waits about a frame period), and a frame whose first bytes came within that
//! of the last frame's end, which itself came without such a wait, is a
//! writer's that had fallen behind: dropped as queued too, never stamped at its
//! late write.
//!
//! The source waits with `poll`, inside a frame too, so it notices a stop request
//! and a writer that went silent, or hung halfway through a frame.
//!
//! Formats: `gray` (8-bit luma), `i420` (planar YUV 4:2:0, what `rpicam-vid
//! --codec yuv420` writes), `nv12` (luma plane, then interleaved chroma) and
//! `yuyv` (packed 4:2:2). Only the luma is used. Rows may be padded to a stride
//! (`rpicam-vid` pads rows to its buffer's stride, 64-byte aligned on a Pi: use a
//! width that is a multiple of 64, or give the stride).
//!
//! ```
//! use vlsync_signature_cam::pipe::PipeFormat;
//! // 320x240 I420: 76800 bytes of luma, two 160x120 chroma planes
//! assert_eq!(PipeFormat::parse("i420").unwrap().frame_bytes(320, 240, 320), Some(115_200));
//! assert_eq!(PipeFormat::Yuyv.frame_bytes(320, 240, 640), Some(153_600));
//! assert!(PipeFormat::parse("mjpeg").unwrap_err().contains("gray, i420, nv12, yuyv"));
//! ```

use crate::image::GrayFrame;
use crate::signature::FrameTime;
use crate::source::{FrameSource, MAX_UNUSABLE_IN_ROW};
use crate::Error;
use std::io::{ErrorKind, Read};
use std::os::fd::AsFd;
use std::path::PathBuf;
use std::time::Duration;
use vlsync_common::Nanos;

/// The layout of the frames in the pipe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PipeFormat {
    /// 8-bit luma, `stride` bytes a row.
    Gray,
    /// Planar YUV 4:2:0: luma rows of `stride` bytes, then the U and V planes,
    /// each `height / 2` (rounded up) rows of `stride / 2` (rounded up) bytes.
    I420,
    /// Luma rows of `stride` bytes, then `height / 2` (rounded up) rows of
    /// interleaved chroma of `stride` bytes.
    Nv12,
    /// Packed 4:2:2, `Y0 U Y1 V`: rows of `stride` (at least `2 × width`) bytes.
    Yuyv,
}

impl PipeFormat {
    /// The names [`PipeFormat::parse`] takes.
    pub const NAMES: &'static str = "gray, i420, nv12, yuyv";

    /// A format from its name (`yuv420` is `i420`, `grey`/`y8` are `gray`).
    pub fn parse(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "gray" | "grey" | "y8" => Ok(Self::Gray),
            "i420" | "yuv420" | "yu12" => Ok(Self::I420),
            "nv12" => Ok(Self::Nv12),
            "yuyv" | "yuy2" => Ok(Self::Yuyv),
            _ => Err(format!(
                "`{}` is not a raw frame format this source reads (one of: {})",
                vlsync_common::text::clip(s),
                Self::NAMES
            )),
        }
    }

    /// The smallest stride of a `width`-pixel row.
    pub fn min_stride(self, width: usize) -> Option<usize> {
        match self {
            Self::Yuyv => width.checked_mul(2),
            _ => Some(width),
        }
    }

    /// Bytes of one frame; `None` on overflow.
    pub fn frame_bytes(self, width: usize, height: usize, stride: usize) -> Option<usize> {
        let luma = stride.checked_mul(height)?;
        let half_h = height.div_ceil(2);
        match self {
            Self::Gray | Self::Yuyv => Some(luma),
            Self::I420 => luma.checked_add(stride.div_ceil(2).checked_mul(half_h)?.checked_mul(2)?),
            Self::Nv12 => luma.checked_add(stride.checked_mul(half_h)?),
        }
        .filter(|_| width > 0)
    }
}

impl std::fmt::Display for PipeFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Gray => "gray",
            Self::I420 => "i420",
            Self::Nv12 => "nv12",
            Self::Yuyv => "yuyv",
        })
    }
}

/// What the pipe holds and how long it may stay silent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PipeConfig {
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Bytes per row of the luma plane (`None`: the format's smallest).
    pub stride: Option<usize>,
    /// The frames' layout.
    pub format: PipeFormat,
    /// No frame for this long is an error ([`Error::Stalled`]); `Duration::MAX`
    /// (or anything over about 292 years) is never.
    pub silence: Duration,
}

impl PipeConfig {
    /// The luma stride and the bytes of one frame; an error naming what is wrong
    /// with the geometry (a zero size, an odd YUYV width, a stride short of a row,
    /// a frame over 256 MiB).
    ///
    /// ```
    /// use vlsync_signature_cam::pipe::{PipeConfig, PipeFormat};
    /// use std::time::Duration;
    /// let cfg = PipeConfig {
    ///     width: 320, height: 240, stride: Some(384), format: PipeFormat::I420,
    ///     silence: Duration::from_secs(10),
    /// };
    /// assert_eq!(cfg.layout().unwrap(), (384, 384 * 240 + 2 * 192 * 120));
    /// ```
    pub fn layout(&self) -> Result<(usize, usize), Error> {
        let bad = |reason: &'static str| Error::BadDimensions {
            width: self.width,
            height: self.height,
            reason,
        };
        if self.width == 0 || self.height == 0 {
            return Err(bad("zero width or height"));
        }
        if self.format == PipeFormat::Yuyv && self.width % 2 == 1 {
            return Err(bad("YUYV needs an even width"));
        }
        let min = self
            .format
            .min_stride(self.width)
            .ok_or_else(|| bad("row size overflows"))?;
        let stride = self.stride.unwrap_or(min);
        if stride < min {
            return Err(Error::InvalidConfig {
                field: "stride",
                reason: format!(
                    "{stride} bytes is less than a {} row of {} pixels ({min} bytes)",
                    self.format, self.width
                ),
            });
        }
        let bytes = self
            .format
            .frame_bytes(self.width, self.height, stride)
            .filter(|&b| b <= 1 << 28)
            .ok_or_else(|| bad("a frame over 256 MiB"))?;
        Ok((stride, bytes))
    }
}

/// Frames read from a pipe (module docs). `R` is the pipe's read end (stdin, a
/// named FIFO, [`std::io::PipeReader`]); the clock stamps frames.
pub struct PipeSource<R: Read + AsFd> {
    reader: R,
    name: PathBuf,
    cfg: PipeConfig,
    stride: usize,
    clock: fn() -> Nanos,
    stop: fn() -> bool,
    /// How a stall names the pipe's writer ([`PipeSource::set_writer_name`]).
    writer: PathBuf,
    frame: Vec<u8>,
    gray: Vec<u8>,
    frames: u64,
    queued: u64,
    queued_in_row: u32,
    /// When the next frame's first bytes came, if known already.
    head_at: Option<Nanos>,
    /// How the last frame read ended (`None` before the first).
    tail: Option<TailEnd>,
    /// The last intervals between the ends of frames read one after the other,
    /// dropped ones too, ns (a ring; 0: not yet filled).
    intervals: [Nanos; INTERVALS],
    interval_pos: usize,
    ended: bool,
}

/// A wait for the pipe that ended when bytes came.
#[derive(Debug, Clone, Copy)]
struct Wake {
    /// When it ended (the caller's clock).
    at: Nanos,
    /// How long it waited, ns.
    waited: Nanos,
}

/// How the last frame read ended.
#[derive(Debug, Clone, Copy)]
struct TailEnd {
    /// When its last bytes had been read (the caller's clock).
    read_at: Nanos,
    /// They came after a long wait ([`PipeSource::long_wait_ns`]).
    long: bool,
}

/// How a frame's reading ended.
enum FrameRead {
    /// Read whole: the wake-up before its first bytes and before its last
    /// (`None`: they were already there).
    Frame {
        first: Option<Wake>,
        last: Option<Wake>,
    },
    /// The writer closed the pipe between frames.
    End,
    /// A stop was asked for.
    Stopped,
}

/// How often a wait for the next frame checks the stop request.
const STOP_CHECK: Duration = Duration::from_millis(100);

/// The shortest wait for bytes that shows the writer's own time (module docs):
/// a quarter of the frames' interval, and at least this (before any interval is
/// known, this). The interval is the median (the upper of the middle two) of the
/// last 8 between the ends of frames read one after the other, those dropped
/// too: a writer that sped up is followed, its frames dropped meanwhile counting
/// as much as those stamped, and up to four of a backlog's frames come within
/// microseconds of each other without moving it.
///
/// A writer blocked on a full pipe writes on within microseconds of a read, but
/// a loaded machine's scheduler may hold it, or this reader, for milliseconds; a
/// quarter of a period stays above that, and below what a writer's own time
/// gives: a buffering writer's tail waits a period less the reader's work on a
/// frame (that work may take up to three quarters of a period: 25 ms at 30 Hz),
/// and a frame written whole on time comes a period after the last one's end,
/// less its transfer. Bunched stamps a wait of this length lets through are the
/// signature's to refuse ([`crate::SignatureConfig::SHORT_PERIODS`]).
pub const LONG_WAIT_MIN: Duration = Duration::from_millis(2);
const LONG_WAIT_MIN_NS: Nanos = LONG_WAIT_MIN.as_nanos() as Nanos;

/// Intervals between frames' ends whose median sets the long wait
/// ([`LONG_WAIT_MIN`]).
const INTERVALS: usize = 8;

impl<R: Read + AsFd> PipeSource<R> {
    /// A source reading `cfg`'s frames from `reader`, called `name` in messages
    /// (`stdin`, the FIFO's path). The buffers are made here; reading frames
    /// allocates nothing.
    pub fn new(
        reader: R,
        name: impl Into<PathBuf>,
        cfg: PipeConfig,
        clock: fn() -> Nanos,
    ) -> Result<Self, Error> {
        let name = name.into();
        let (stride, bytes) = cfg.layout()?;
        let gray_len = if cfg.format == PipeFormat::Yuyv || stride != cfg.width {
            cfg.width * cfg.height
        } else {
            0 // the luma plane is used where it lies
        };
        Ok(Self {
            reader,
            writer: PathBuf::from(format!("writer of {}", name.display())),
            name,
            cfg,
            stride,
            clock,
            stop: || false,
            frame: vec![0; bytes],
            gray: vec![0; gray_len],
            frames: 0,
            queued: 0,
            queued_in_row: 0,
            head_at: None,
            tail: None,
            intervals: [0; INTERVALS],
            interval_pos: 0,
            ended: false,
        })
    }

    /// Makes waits end (`Ok(None)`) once `stop` returns true (a signal handler's
    /// flag); checked every 100 ms while no frame comes.
    pub fn set_stop(&mut self, stop: fn() -> bool) {
        self.stop = stop;
    }

    /// How a stall ([`Error::Stalled`]) names the pipe's writer: by default
    /// `writer of NAME` (standard input, a FIFO: whoever writes there); a caller
    /// that started the writer itself names it (`camera program`).
    pub fn set_writer_name(&mut self, writer: impl Into<PathBuf>) {
        self.writer = writer.into();
    }

    /// Frames read, and of them dropped as queued (stamp unknown).
    pub fn counts(&self) -> (u64, u64) {
        (self.frames, self.queued)
    }

    /// One line on what the source reads.
    pub fn describe(&self) -> String {
        format!(
            "raw {} frames {}x{} (stride {}, {} bytes each) from {}",
            self.cfg.format,
            self.cfg.width,
            self.cfg.height,
            self.stride,
            self.frame.len(),
            self.name.display()
        )
    }

    fn read_error(&self, reason: String) -> Error {
        Error::Read {
            path: self.name.clone(),
            reason,
        }
    }

    /// How long a wait must last to be the writer's own time ([`LONG_WAIT_MIN`]).
    fn long_wait_ns(&self) -> Nanos {
        let mut v = self.intervals;
        v.sort_unstable();
        let known = v.iter().filter(|&&d| d > 0).count();
        if known == 0 {
            return LONG_WAIT_MIN_NS;
        }
        // the zeros sort first: the median of the known ones (the upper of two)
        let median = v[INTERVALS - known + known / 2];
        (median / 4).max(LONG_WAIT_MIN_NS)
    }

    /// Waits up to `d` for the pipe to be readable (data or the writer's end). A
    /// signal that interrupts a wait ends it early (`false`); one that interrupts
    /// the zero-time look is looked again, which must not read as "nothing there".
    fn readable_within(&self, d: Duration) -> Result<bool, Error> {
        let ts = rustix::event::Timespec {
            tv_sec: d.as_secs() as _,
            tv_nsec: d.subsec_nanos() as _,
        };
        loop {
            let mut fds = [rustix::event::PollFd::new(
                &self.reader,
                rustix::event::PollFlags::IN,
            )];
            match rustix::event::poll(&mut fds, Some(&ts)) {
                Ok(n) => return Ok(n > 0),
                Err(rustix::io::Errno::INTR) if d.is_zero() => continue,
                Err(rustix::io::Errno::INTR) => return Ok(false),
                Err(e) => return Err(self.read_error(format!("waiting for a frame: {e}"))),
            }
        }
    }

    /// Waits until the pipe is readable. `Some(None)`: it already was;
    /// `Some(Some(wake))`: a wait that ended when bytes came; `None`: a stop
    /// was asked for. No bytes for the configured silence is [`Error::Stalled`],
    /// inside a frame too (a writer that hung halfway).
    fn wait_readable(&mut self) -> Result<Option<Option<Wake>>, Error> {
        if self.readable_within(Duration::ZERO)? {
            return Ok(Some(None));
        }
        let asked = (self.clock)();
        // saturating: a silence beyond i64 ns (about 292 years, e.g.
        // `Duration::MAX` for "never") must not wrap to a negative limit
        let silence = Nanos::try_from(self.cfg.silence.as_nanos()).unwrap_or(Nanos::MAX);
        loop {
            if (self.stop)() {
                return Ok(None);
            }
            if self.readable_within(STOP_CHECK)? {
                let at = (self.clock)();
                return Ok(Some(Some(Wake {
                    at,
                    waited: at.saturating_sub(asked),
                })));
            }
            let quiet = (self.clock)().saturating_sub(asked);
            if quiet >= silence {
                // the caller's messages name the source already: this names who
                // fell silent
                return Err(Error::Stalled {
                    path: self.writer.clone(),
                    after: Duration::from_nanos(quiet.max(0) as u64),
                });
            }
        }
    }

    /// Reads one whole frame into the buffer, waiting for its bytes as they come.
    fn read_frame(&mut self) -> Result<FrameRead, Error> {
        let mut got = 0;
        let (mut first, mut last) = (None, None);
        while got < self.frame.len() {
            let Some(woke) = self.wait_readable()? else {
                return Ok(FrameRead::Stopped);
            };
            if got == 0 {
                first = woke;
            }
            last = woke;
            match self.reader.read(&mut self.frame[got..]) {
                Ok(0) if got == 0 => return Ok(FrameRead::End),
                Ok(0) => {
                    return Err(self.read_error(format!(
                        "the writer closed the pipe inside frame {} ({got} of its {} bytes): \
                         a wrong size, stride or format?",
                        self.frames + 1,
                        self.frame.len()
                    )))
                }
                Ok(n) => got += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                // a non-blocking descriptor (a FIFO opened so) with nothing after all
                Err(e) if e.kind() == ErrorKind::WouldBlock => {}
                Err(e) => {
                    return Err(self.read_error(format!("reading frame {}: {e}", self.frames + 1)))
                }
            }
        }
        self.frames += 1;
        Ok(FrameRead::Frame { first, last })
    }

    /// The luma of the frame in the buffer.
    fn luma(&mut self) -> Result<GrayFrame<'_, u8>, Error> {
        let (w, h, stride) = (self.cfg.width, self.cfg.height, self.stride);
        if self.gray.is_empty() {
            return GrayFrame::borrowed(w, h, &self.frame[..w * h]);
        }
        for (y, out) in self.gray.chunks_exact_mut(w).enumerate() {
            let row = &self.frame[y * stride..];
            match self.cfg.format {
                PipeFormat::Yuyv => {
                    for (o, px) in out.iter_mut().zip(row.chunks_exact(2)) {
                        *o = px[0];
                    }
                }
                _ => out.copy_from_slice(&row[..w]),
            }
        }
        GrayFrame::borrowed(w, h, &self.gray)
    }
}

impl<R: Read + AsFd> FrameSource for PipeSource<R> {
    fn next_frame(&mut self) -> Result<Option<(GrayFrame<'_, u8>, FrameTime)>, Error> {
        if self.ended {
            return Ok(None);
        }
        loop {
            // this frame's first bytes came with the last one's end (module docs)
            let head = self.head_at.take();
            let before = self.tail.take();
            let (first, last) = match self.read_frame()? {
                FrameRead::Frame { first, last } => (first, last),
                FrameRead::End => {
                    self.ended = true;
                    return Ok(None);
                }
                FrameRead::Stopped => return Ok(None),
            };
            let read_at = (self.clock)();
            if let Some(b) = before {
                if read_at > b.read_at {
                    self.intervals[self.interval_pos] = read_at - b.read_at;
                    self.interval_pos = (self.interval_pos + 1) % INTERVALS;
                }
            }
            let long = self.long_wait_ns();
            let long_tail = last.is_some_and(|w| w.waited >= long);
            self.tail = Some(TailEnd {
                read_at,
                long: long_tail,
            });
            // the next frame's first bytes already here, when this one's last bytes
            // were waited for long: they came in that same write, at that wake-up
            // (after a short wait they may be a blocked writer's, behind: module docs)
            self.head_at = match last {
                Some(w) if long_tail && self.readable_within(Duration::ZERO)? => Some(w.at),
                _ => None,
            };
            // a frame waited for, but come right behind the last one's end, which came
            // without a long wait: written by a writer that fell behind, blocked in
            // the last frame, as soon as it could (a buffering writer's head right
            // behind the tail it waited long for is on time)
            let first = first.filter(|w| {
                before.is_none_or(|b| b.long || w.at.saturating_sub(b.read_at) >= long)
            });
            let Some(t) = head.or(first.map(|w| w.at)) else {
                // it was already waiting when asked for, or written right behind the
                // last frame by a writer behind: held up by this reader (or, the first
                // one, written before it started), its stamp unknown
                self.queued += 1;
                self.queued_in_row += 1;
                if self.queued_in_row >= MAX_UNUSABLE_IN_ROW {
                    return Err(self.read_error(format!(
                        "{} frames in a row were already waiting in the pipe (or came right \
                         behind the last one from a writer that fell behind): its writer runs \
                         ahead of real time (a file?), or this reader cannot keep up",
                        self.queued_in_row
                    )));
                }
                continue;
            };
            self.queued_in_row = 0;
            let frame = self.luma()?;
            return Ok(Some((frame, FrameTime::Instant(t))));
        }
    }

    fn unusable(&self) -> Option<(u64, &str)> {
        (self.queued > 0).then_some((
            self.queued,
            "already waiting in the pipe when asked for, or written right behind the frame \
             before by a writer that fell behind (its stamp would be late)",
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::io::Write;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::OnceLock;
    use std::time::Instant;

    /// Nanoseconds since the first call: a clock a `fn` pointer can be.
    fn clock() -> Nanos {
        static START: OnceLock<Instant> = OnceLock::new();
        START.get_or_init(Instant::now).elapsed().as_nanos() as Nanos
    }

    fn cfg(format: PipeFormat, width: usize, height: usize, stride: Option<usize>) -> PipeConfig {
        PipeConfig {
            width,
            height,
            stride,
            format,
            silence: Duration::from_secs(5),
        }
    }

    /// A `w`×`h` frame of `format` whose luma at (x, y) is `x + 10 y + k`, padding
    /// and chroma 0xEE (never a luma value here).
    fn frame(format: PipeFormat, w: usize, h: usize, stride: usize, k: u8) -> Vec<u8> {
        let mut out = vec![0xEE; format.frame_bytes(w, h, stride).unwrap()];
        for y in 0..h {
            for x in 0..w {
                let v = (x + 10 * y) as u8 + k;
                match format {
                    PipeFormat::Yuyv => out[y * stride + 2 * x] = v,
                    _ => out[y * stride + x] = v,
                }
            }
        }
        out
    }

    /// The writers' time between frames: a reader held up for less than this (a busy
    /// machine's scheduler may take tens of ms) still waits for every frame, and a
    /// stamp must come before the next frame is written, within this of its own.
    const INTERVAL: Duration = Duration::from_millis(100);
    const INTERVAL_NS: Nanos = INTERVAL.as_nanos() as Nanos;

    fn luma_ok(f: &GrayFrame<'_, u8>, w: usize, h: usize, k: u8) -> bool {
        (f.width(), f.height()) == (w, h)
            && (0..h).all(|y| (0..w).all(|x| f.get(x, y) == Some((x + 10 * y) as u8 + k)))
    }

    #[test]
    fn each_format_gives_its_luma_stamped_when_the_frame_arrives() {
        for (format, stride) in [
            (PipeFormat::Gray, None),
            (PipeFormat::Gray, Some(9)),
            (PipeFormat::I420, None),
            (PipeFormat::I420, Some(8)),
            (PipeFormat::Nv12, Some(7)),
            (PipeFormat::Yuyv, None),
            (PipeFormat::Yuyv, Some(14)),
        ] {
            let (w, h) = (6, 5);
            let (r, mut wr) = std::io::pipe().unwrap();
            let mut src =
                PipeSource::new(r, "test pipe", cfg(format, w, h, stride), clock).unwrap();
            let st = stride.unwrap_or(format.min_stride(w).unwrap());
            let writer = std::thread::spawn(move || {
                let mut sent = vec![];
                for k in 0..3u8 {
                    std::thread::sleep(INTERVAL);
                    sent.push(clock());
                    wr.write_all(&frame(format, w, h, st, k)).unwrap();
                }
                sent
            });
            let mut got = vec![];
            for k in 0..3u8 {
                let (f, t) = src.next_frame().unwrap().expect("a frame");
                assert!(luma_ok(&f, w, h, k), "{format} stride {stride:?} frame {k}");
                got.push(t.instant_ns().unwrap());
            }
            let sent = writer.join().unwrap();
            // the writer closed its end: the stream ends
            assert!(src.next_frame().unwrap().is_none());
            assert!(src.next_frame().unwrap().is_none());
            for (s, g) in sent.iter().zip(&got) {
                // stamped after the write began, and before the next one
                assert!(*g >= *s && *g < *s + INTERVAL_NS, "sent {s}, stamped {g}");
            }
            assert_eq!(src.counts(), (3, 0));
            assert_eq!(src.unusable(), None);
        }
    }

    #[test]
    fn frames_that_waited_in_the_pipe_are_dropped_not_stamped_late() {
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut src = PipeSource::new(r, "p", cfg(PipeFormat::Gray, 4, 4, None), clock).unwrap();
        // two frames there before the first ask, a third written while it waits
        wr.write_all(&frame(PipeFormat::Gray, 4, 4, 4, 0)).unwrap();
        wr.write_all(&frame(PipeFormat::Gray, 4, 4, 4, 1)).unwrap();
        let writer = std::thread::spawn(move || {
            std::thread::sleep(INTERVAL);
            let t = clock();
            wr.write_all(&frame(PipeFormat::Gray, 4, 4, 4, 2)).unwrap();
            (t, wr)
        });
        let (f, t) = src.next_frame().unwrap().unwrap();
        assert!(luma_ok(&f, 4, 4, 2));
        let (sent, _wr) = writer.join().unwrap();
        assert!(t.instant_ns().unwrap() >= sent);
        assert_eq!(src.counts(), (3, 2));
        let (n, why) = src.unusable().unwrap();
        assert_eq!(n, 2);
        assert!(why.contains("already waiting"), "{why}");
    }

    #[test]
    fn a_buffering_writer_s_frames_are_all_stamped_at_their_head() {
        // as rpicam-vid without --flush: each write carries the last frame's tail
        // (here 10 bytes) and the next frame's head
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut src = PipeSource::new(r, "p", cfg(PipeFormat::Gray, 8, 8, None), clock).unwrap();
        let writer = std::thread::spawn(move || {
            let mut heads = vec![];
            let mut tail: Vec<u8> = vec![];
            for k in 0..6u8 {
                std::thread::sleep(INTERVAL);
                let f = frame(PipeFormat::Gray, 8, 8, 8, k);
                let mut chunk = std::mem::take(&mut tail);
                chunk.extend_from_slice(&f[..54]);
                heads.push(clock());
                wr.write_all(&chunk).unwrap();
                tail = f[54..].to_vec();
            }
            std::thread::sleep(INTERVAL);
            wr.write_all(&tail).unwrap();
            heads
        });
        let mut stamps = vec![];
        while let Some((f, t)) = src.next_frame().unwrap() {
            assert!(luma_ok(&f, 8, 8, stamps.len() as u8));
            stamps.push(t.instant_ns().unwrap());
        }
        let heads = writer.join().unwrap();
        assert_eq!(src.counts(), (6, 0), "none dropped as queued");
        for (h, t) in heads.iter().zip(&stamps) {
            assert!(
                *t >= *h && *t < *h + INTERVAL_NS,
                "head written {h}, stamped {t}"
            );
        }
    }

    #[test]
    fn a_writer_behind_with_frames_over_the_pipe_s_buffer_is_dropped_not_bunched() {
        // 320x240 I420 (115,200 bytes, over the 64 KiB a pipe holds), a frame due
        // every INTERVAL; the reader held up 3.5 intervals after its fourth frame,
        // so the writer, blocked inside the fifth, is three frames behind when it
        // goes on and writes each as soon as the last is read. Those frames must
        // not be stamped at their late writes, bunched within microseconds (one
        // frame's flow over such an interval is a value tens of times too large):
        // every frame handed on is stamped within a quarter interval of its due
        // time, none within half an interval of the one before, and the frames
        // after the hold-up are handed on again. Both for a writer that writes
        // each frame whole and for one that buffers (each write the last frame's
        // 1000-byte tail and the next one's head)
        let (w, h) = (320, 240);
        let bytes = PipeFormat::I420.frame_bytes(w, h, w).unwrap();
        assert!(bytes > 1 << 16);
        for buffered in [false, true] {
            let (r, mut wr) = std::io::pipe().unwrap();
            let mut src =
                PipeSource::new(r, "p", cfg(PipeFormat::I420, w, h, None), clock).unwrap();
            let frames = 12u8;
            let t0 = clock() + INTERVAL_NS / 2;
            let due = move |k: u8| t0 + Nanos::from(k) * INTERVAL_NS;
            let writer = std::thread::spawn(move || {
                let mut tail = vec![];
                for k in 0..frames {
                    let wait = due(k) - clock();
                    if wait > 0 {
                        std::thread::sleep(Duration::from_nanos(wait as u64));
                    }
                    // every byte k: the frame's luma says which it is
                    let f = vec![k; bytes];
                    if buffered {
                        let mut chunk = std::mem::take(&mut tail);
                        chunk.extend_from_slice(&f[..bytes - 1000]);
                        wr.write_all(&chunk).unwrap();
                        tail = f[bytes - 1000..].to_vec();
                    } else {
                        wr.write_all(&f).unwrap();
                    }
                }
                std::thread::sleep(INTERVAL);
                wr.write_all(&tail).unwrap();
            });
            let mut got = vec![];
            while let Some((f, t)) = src.next_frame().unwrap() {
                let k = f.get(0, 0).unwrap();
                assert!(f.pixels().iter().all(|&v| v == k));
                got.push((k, t.instant_ns().unwrap()));
                if got.len() == 4 {
                    std::thread::sleep(INTERVAL * 7 / 2);
                }
            }
            writer.join().unwrap();
            let what = if buffered { "buffering" } else { "flushing" };
            for &(k, t) in &got {
                let late = t - due(k);
                assert!(
                    // (half an interval: a shared machine may hold either
                    // thread for milliseconds; the old stamps were 150-250 ms late)
                    (0..INTERVAL_NS / 2).contains(&late),
                    "{what}: frame {k} stamped {:.3} ms after its due time: {:?}",
                    late as f64 * 1e-6,
                    got.iter()
                        .map(|&(k, t)| (k, (t - due(k)) as f64 * 1e-6))
                        .collect::<Vec<_>>()
                );
            }
            for pair in got.windows(2) {
                assert!(pair[1].1 - pair[0].1 >= INTERVAL_NS / 2, "{what}: {got:?}");
            }
            // the frames owed were dropped; from frame 9 on, all handed on again
            let (read, queued) = src.counts();
            assert_eq!(read, u64::from(frames), "{what}");
            assert!(queued >= 2, "{what}: {queued} dropped: {got:?}");
            let ks: Vec<u8> = got.iter().map(|&(k, _)| k).collect();
            assert!(ks.starts_with(&[0, 1, 2, 3]), "{what}: {ks:?}");
            assert!(ks.ends_with(&[9, 10, 11]), "{what}: {ks:?}");
        }
    }

    #[test]
    fn a_writer_that_speeds_up_is_stamped_again_within_a_few_frames() {
        // 150 ms between frames, then 15 ms: a frame coming 15 ms after the last
        // one's end is within a quarter of the interval learnt (37.5 ms) and
        // dropped, but those dropped count in the interval too, so the new rate
        // is learnt within five frames, never 30 dropped in a row
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut src = PipeSource::new(r, "p", cfg(PipeFormat::Gray, 8, 8, None), clock).unwrap();
        let (slow, fast) = (8u8, 40u8);
        let writer = std::thread::spawn(move || {
            let mut sent = vec![];
            for k in 0..slow + fast {
                let ms = if k < slow { 150 } else { 15 };
                std::thread::sleep(Duration::from_millis(ms));
                sent.push(clock());
                wr.write_all(&[k; 64]).unwrap();
            }
            sent
        });
        let mut got = vec![];
        while let Some((f, t)) = src.next_frame().unwrap() {
            got.push((f.get(0, 0).unwrap(), t.instant_ns().unwrap()));
        }
        let sent = writer.join().unwrap();
        let (read, queued) = src.counts();
        assert_eq!(read, u64::from(slow + fast));
        // (a loaded machine that holds the reader drops a few more, rightly)
        assert!(queued <= 20, "{queued} dropped: {got:?}");
        for &(k, t) in &got {
            let s = sent[usize::from(k)];
            assert!(
                t >= s && t < s + 50_000_000,
                "frame {k} written {s}, stamped {t}"
            );
        }
        // the fast frames are stamped again (most of them: never 30 dropped in a row)
        let fast_got = got.iter().filter(|&&(k, _)| k >= slow + 5).count();
        assert!(
            fast_got >= usize::from(fast - 5) / 2,
            "{fast_got} of the fast frames stamped: {got:?}"
        );
    }

    #[test]
    fn a_writer_that_hangs_inside_a_frame_is_a_stall_and_a_stop_ends_a_wait_there() {
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut c = cfg(PipeFormat::Gray, 8, 8, None);
        c.silence = Duration::from_millis(250);
        let mut src = PipeSource::new(r, "p", c, clock).unwrap();
        wr.write_all(&[7; 20]).unwrap();
        assert!(matches!(src.next_frame(), Err(Error::Stalled { .. })));
        // half a frame there: the stop ends the wait for the rest
        stop_ends_the_wait_with(&[7; 20]);
    }

    /// A source waiting with `written` in its pipe (a writer that went quiet)
    /// returns `None` once a stop is asked for.
    fn stop_ends_the_wait_with(written: &[u8]) {
        static STOP: AtomicBool = AtomicBool::new(false);
        static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
        let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
        STOP.store(false, Ordering::Relaxed);
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut src = PipeSource::new(r, "p", cfg(PipeFormat::Gray, 8, 8, None), clock).unwrap();
        src.set_stop(|| STOP.load(Ordering::Relaxed));
        wr.write_all(written).unwrap();
        let stopper = std::thread::spawn(|| {
            std::thread::sleep(Duration::from_millis(150));
            STOP.store(true, Ordering::Relaxed);
        });
        assert!(src.next_frame().unwrap().is_none());
        stopper.join().unwrap();
    }

    #[test]
    fn a_writer_always_ahead_is_an_error_not_a_silent_spin() {
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut src =
            PipeSource::new(r, "fast.yuv", cfg(PipeFormat::Gray, 4, 4, None), clock).unwrap();
        for k in 0..40 {
            wr.write_all(&frame(PipeFormat::Gray, 4, 4, 4, k)).unwrap();
        }
        let e = src.next_frame().expect_err("an error").to_string();
        assert!(
            e.starts_with("fast.yuv: 30 frames in a row were already waiting in the pipe"),
            "{e}"
        );
    }

    #[test]
    fn a_frame_cut_short_names_the_bytes_and_silence_is_a_stall() {
        let (r, mut wr) = std::io::pipe().unwrap();
        let mut src =
            PipeSource::new(r, "stdin", cfg(PipeFormat::I420, 4, 4, None), clock).unwrap();
        let writer = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            wr.write_all(&[1; 10]).unwrap();
        });
        let e = src.next_frame().expect_err("an error").to_string();
        writer.join().unwrap();
        assert_eq!(
            e,
            "stdin: the writer closed the pipe inside frame 1 (10 of its 24 bytes): a wrong \
             size, stride or format?"
        );
        let (r, _wr) = std::io::pipe().unwrap();
        let mut c = cfg(PipeFormat::Gray, 4, 4, None);
        c.silence = Duration::from_millis(250);
        let mut src = PipeSource::new(r, "stdin", c, clock).unwrap();
        match src.next_frame() {
            Err(Error::Stalled { path, after }) => {
                // standard input has no program behind it that this source knows of
                assert_eq!(path, PathBuf::from("writer of stdin"));
                assert!(after >= Duration::from_millis(250), "{after:?}");
            }
            other => panic!("{:?}", other.map(|o| o.is_some())),
        }
        // a caller that started the writer names it
        let (r, _wr) = std::io::pipe().unwrap();
        let mut src = PipeSource::new(r, "`rpicam-vid -o -`", c, clock).unwrap();
        src.set_writer_name("camera program");
        match src.next_frame() {
            Err(e @ Error::Stalled { .. }) => assert!(
                e.to_string().starts_with("camera program: no frame for 0."),
                "{e}"
            ),
            other => panic!("{:?}", other.map(|o| o.is_some())),
        }
    }

    #[test]
    fn an_endless_silence_never_stalls() {
        // Duration::MAX (about 5.8e11 years) does not fit i64 nanoseconds: it
        // must saturate, not wrap to a negative limit that every wait exceeds
        static STOP: AtomicBool = AtomicBool::new(false);
        let (r, _wr) = std::io::pipe().unwrap();
        let mut c = cfg(PipeFormat::Gray, 4, 4, None);
        c.silence = Duration::MAX;
        let mut src = PipeSource::new(r, "p", c, clock).unwrap();
        src.set_stop(|| STOP.load(Ordering::Relaxed));
        // before the stopper starts: the stop comes 350 ms after this at the earliest,
        // so a wait that ended only on it took that long
        let t0 = Instant::now();
        let stopper = std::thread::spawn(|| {
            std::thread::sleep(Duration::from_millis(350));
            STOP.store(true, Ordering::Relaxed);
        });
        let r = src.next_frame().map(|o| o.is_some());
        stopper.join().unwrap();
        assert_eq!(r.map_err(|e| e.to_string()), Ok(false));
        assert!(
            t0.elapsed() >= Duration::from_millis(350),
            "{:?}",
            t0.elapsed()
        );
    }

    #[test]
    fn a_stop_request_ends_a_wait() {
        stop_ends_the_wait_with(&[]);
    }

    #[test]
    fn bad_geometry_is_refused_naming_what() {
        let (r, _w) = std::io::pipe().unwrap();
        let e = PipeSource::new(r, "p", cfg(PipeFormat::Yuyv, 5, 4, None), clock)
            .err()
            .unwrap();
        assert!(e.to_string().contains("YUYV needs an even width"), "{e}");
        let (r, _w) = std::io::pipe().unwrap();
        let e = PipeSource::new(r, "p", cfg(PipeFormat::Yuyv, 6, 4, Some(10)), clock)
            .err()
            .unwrap();
        assert_eq!(
            e.to_string(),
            "invalid configuration `stride`: 10 bytes is less than a yuyv row of 6 pixels (12 bytes)"
        );
        let (r, _w) = std::io::pipe().unwrap();
        assert!(PipeSource::new(r, "p", cfg(PipeFormat::Gray, 0, 4, None), clock).is_err());
        assert_eq!(PipeFormat::parse(" YUV420 "), Ok(PipeFormat::I420));
    }

    proptest! {
        #[test]
        fn any_geometry_is_accepted_or_refused_never_panics(
            w in 0usize..100_000, h in 0usize..100_000, stride in proptest::option::of(0usize..300_000),
            f in 0usize..4,
        ) {
            let format = [PipeFormat::Gray, PipeFormat::I420, PipeFormat::Nv12, PipeFormat::Yuyv][f];
            let (r, _w) = std::io::pipe().unwrap();
            if let Ok(src) = PipeSource::new(r, "p", cfg(format, w, h, stride), clock) {
                // an accepted geometry holds its luma within the frame
                let st = src.stride;
                prop_assert!(st >= format.min_stride(w).unwrap());
                prop_assert!(src.frame.len() >= st * (h - 1) + format.min_stride(w).unwrap());
            }
        }
    }
}
