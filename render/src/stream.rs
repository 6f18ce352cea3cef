//! A rendered camera as a camera program: raw frames written to a pipe in real
//! time (`vlsync-render --raw-stdout`), what `rpicam-vid --codec yuv420 -o -` does
//! with a Raspberry Pi camera module. It lets `vlsync-cam --pipe-cmd` run, and be
//! tested, with no camera.
//!
//! Frame `i` is written when its exposure ends, at `τ_end + start_at - anchor` on
//! `CLOCK_MONOTONIC` (the drivers' `--stamp mono` mapping, [`Renderer::anchor_ns`]),
//! so a reader that stamps frames as they arrive stamps them `exposure / 2` after
//! their true mid-exposure instant, plus the pipe's own delay. A frame that could
//! not be rendered in time is written late, as a real camera program would, and
//! counted. `anchor` is the earlier of the run's first camera and LiDAR stamps, so
//! the first frames (those whose exposure ends before the anchor) are written
//! slightly before `start_at`.
//!
//! A stream started after `start_at` (a camera program restarted mid-run, as its
//! driver's own `--render` resumes at the current frame) skips the frames already
//! due more than one frame period before it starts ([`first_live_frame`]) instead
//! of writing that backlog at once.

use crate::{FrameInfo, RenderError, Renderer};
use std::io::Write;
use vlsync_common::{secs_to_nanos, Nanos};

/// The layout written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawLayout {
    /// 8-bit luma only.
    Gray,
    /// Planar YUV 4:2:0 with neutral chroma (0x80), what `rpicam-vid --codec
    /// yuv420` writes.
    I420,
}

impl RawLayout {
    /// `gray` or `i420` (`yuv420`).
    pub fn parse(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "gray" | "grey" => Ok(Self::Gray),
            "i420" | "yuv420" => Ok(Self::I420),
            _ => Err(format!("`{s}` is not a raw layout (gray or i420)")),
        }
    }
}

/// What a stream wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamSummary {
    /// Frames written.
    pub frames: u64,
    /// Frames not written because they were already due when the stream started
    /// (the `first` of [`stream_raw`]).
    pub skipped: u64,
    /// Frames written more than 2 ms after their time (rendering fell behind).
    pub late: u64,
    /// The latest write after its time, ns.
    pub max_late_ns: Nanos,
}

/// Why a stream ended early.
#[derive(Debug)]
pub enum StreamError {
    /// A frame could not be rendered.
    Render(RenderError),
    /// The pipe refused a write (the reader went away: `EPIPE`).
    Write(std::io::Error),
}

impl std::fmt::Display for StreamError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StreamError::Render(e) => write!(f, "rendering: {e}"),
            StreamError::Write(e) => write!(f, "writing a frame: {e}"),
        }
    }
}

/// `CLOCK_MONOTONIC` instant at which frame `f` of `r` is due in a stream from
/// `start_at`: the end of its exposure, mapped (module docs).
pub fn frame_due_ns(r: &Renderer, f: &FrameInfo, start_at: Nanos) -> Nanos {
    let shift = start_at.saturating_sub(r.anchor_ns());
    let exp_half = secs_to_nanos(r.config().camera.exposure_s) / 2;
    f.tau_mid_ns.saturating_add(exp_half).saturating_add(shift)
}

/// The first frame (index into [`Renderer::frame_schedule`]) of a stream from
/// `start_at` that starts at `now`: the frames due more than one frame period
/// before `now` are skipped (0 when `start_at` is ahead; the schedule's length
/// when the whole run is past).
pub fn first_live_frame(r: &Renderer, start_at: Nanos, now: Nanos) -> usize {
    let period_ns = (1e9 / r.config().camera.fps).round() as Nanos;
    let oldest = now.saturating_sub(period_ns);
    r.frame_schedule()
        .iter()
        .position(|f| frame_due_ns(r, f, start_at) >= oldest)
        .unwrap_or(r.frame_schedule().len())
}

/// Writes the frames of `r` from entry `first` of its schedule on (0, or
/// [`first_live_frame`] for a stream that starts late) to `out` in real time from
/// `start_at` (module docs), sleeping with `sleep_until` (absolute,
/// `CLOCK_MONOTONIC` ns) and reading the time with `now`.
pub fn stream_raw(
    r: &mut Renderer,
    out: &mut dyn Write,
    layout: RawLayout,
    start_at: Nanos,
    first: usize,
    now: &dyn Fn() -> Nanos,
    sleep_until: &dyn Fn(Nanos),
) -> Result<StreamSummary, StreamError> {
    let shift = start_at.saturating_sub(r.anchor_ns());
    let (w, h) = (r.config().camera.width, r.config().camera.height);
    let chroma = vec![0x80u8; 2 * w.div_ceil(2) * h.div_ceil(2)];
    let mut s = StreamSummary {
        skipped: first.min(r.frame_schedule().len()) as u64,
        ..StreamSummary::default()
    };
    for i in first.. {
        let f = match r.render_frame(i) {
            None => break,
            Some(f) => f.map_err(StreamError::Render)?,
        };
        let due = f.tau_available_ns.saturating_add(shift);
        sleep_until(due);
        let late = now().saturating_sub(due);
        if late > 2_000_000 {
            s.late += 1;
        }
        s.max_late_ns = s.max_late_ns.max(late);
        out.write_all(f.image.pixels())
            .map_err(StreamError::Write)?;
        if layout == RawLayout::I420 {
            out.write_all(&chroma).map_err(StreamError::Write)?;
        }
        out.flush().map_err(StreamError::Write)?;
        s.frames += 1;
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RenderConfig;
    use std::cell::Cell;

    #[test]
    fn frames_are_written_whole_at_their_exposure_end() {
        let mut cfg = RenderConfig::from_seed(3, 1.0);
        cfg.camera.width = 32;
        cfg.camera.height = 24;
        let mut r = Renderer::new(cfg).unwrap();
        let schedule: Vec<_> = r.frame_schedule().to_vec();
        let exposure = (r.config().camera.exposure_s * 1e9).round() as Nanos;
        let anchor = r.anchor_ns();
        let clock = Cell::new(0);
        let sleeps = std::cell::RefCell::new(Vec::new());
        let mut out = Vec::new();
        let s = stream_raw(
            &mut r,
            &mut out,
            RawLayout::I420,
            1_000_000_000,
            0,
            &|| clock.get(),
            &|t| {
                sleeps.borrow_mut().push(t);
                clock.set(t);
            },
        )
        .unwrap();
        assert_eq!(s.frames as usize, schedule.len());
        assert_eq!((s.late, s.max_late_ns, s.skipped), (0, 0, 0));
        assert_eq!(out.len(), schedule.len() * (32 * 24 + 2 * 16 * 12));
        // each frame's write waits for the end of its exposure, mapped from start_at
        for (t, f) in sleeps.borrow().iter().zip(&schedule) {
            assert_eq!(*t - (1_000_000_000 - anchor), f.tau_mid_ns + exposure / 2);
        }
        // neutral chroma after each luma plane
        assert!(out[32 * 24..32 * 24 + 2 * 16 * 12]
            .iter()
            .all(|&b| b == 0x80));
        assert_eq!(RawLayout::parse("YUV420"), Ok(RawLayout::I420));
        assert!(RawLayout::parse("nv12").is_err());
    }

    /// A stream started after `start_at` (a restarted camera program) skips the
    /// frames due more than a frame period ago instead of writing them at once,
    /// and writes the rest at their due times, the first exactly as a stream
    /// from the start would.
    #[test]
    fn a_late_start_skips_the_backlog() {
        let mut cfg = RenderConfig::from_seed(3, 2.0);
        cfg.camera.width = 16;
        cfg.camera.height = 16;
        let mut r = Renderer::new(cfg).unwrap();
        let n = r.frame_schedule().len();
        let start_at = 5_000_000_000;
        let due: Vec<Nanos> = r
            .frame_schedule()
            .iter()
            .map(|f| frame_due_ns(&r, f, start_at))
            .collect();
        let period = 33_333_333;
        // ahead of the start, or within a frame period of the first due: nothing skipped
        assert_eq!(first_live_frame(&r, start_at, 0), 0);
        assert_eq!(first_live_frame(&r, start_at, due[0] + period), 0);
        // 1 s into the run: the frames due before now - period are skipped
        let now = start_at + 1_000_000_000;
        let first = first_live_frame(&r, start_at, now);
        assert!(due[first] >= now - period && due[first - 1] < now - period);
        assert_eq!(first, due.iter().filter(|&&d| d < now - period).count());
        assert!(first > 10 && first < n - 10, "{first} of {n}");
        // past the end: everything
        assert_eq!(first_live_frame(&r, start_at, due[n - 1] + 2 * period), n);

        let clock = Cell::new(now);
        let sleeps = std::cell::RefCell::new(Vec::new());
        let mut out = Vec::new();
        let s = stream_raw(
            &mut r,
            &mut out,
            RawLayout::Gray,
            start_at,
            first,
            &|| clock.get(),
            &|t| {
                sleeps.borrow_mut().push(t);
                clock.set(clock.get().max(t));
            },
        )
        .unwrap();
        assert_eq!((s.frames as usize, s.skipped as usize), (n - first, first));
        assert_eq!(out.len(), (n - first) * 16 * 16);
        assert_eq!(sleeps.borrow()[..], due[first..]);
        // the first frame written is the one a stream from the start writes there
        let whole = r.render_frame(first).unwrap().unwrap();
        assert_eq!(&out[..256], whole.image.pixels());
        // at most one frame period late: no backlog
        assert!(s.max_late_ns <= period, "{}", s.max_late_ns);
    }
}
