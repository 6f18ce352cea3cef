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
//! counted.

use crate::{RenderError, Renderer};
use std::io::Write;
use vlsync_common::Nanos;

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

/// Writes every frame of `r` to `out` in real time from `start_at` (module docs),
/// sleeping with `sleep_until` (absolute, `CLOCK_MONOTONIC` ns) and reading the
/// time with `now`.
pub fn stream_raw(
    r: &mut Renderer,
    out: &mut dyn Write,
    layout: RawLayout,
    start_at: Nanos,
    now: &dyn Fn() -> Nanos,
    sleep_until: &dyn Fn(Nanos),
) -> Result<StreamSummary, StreamError> {
    let shift = start_at.saturating_sub(r.anchor_ns());
    let (w, h) = (r.config().camera.width, r.config().camera.height);
    let chroma = vec![0x80u8; 2 * w.div_ceil(2) * h.div_ceil(2)];
    let mut s = StreamSummary::default();
    for i in 0.. {
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
            &|| clock.get(),
            &|t| {
                sleeps.borrow_mut().push(t);
                clock.set(t);
            },
        )
        .unwrap();
        assert_eq!(s.frames as usize, schedule.len());
        assert_eq!((s.late, s.max_late_ns), (0, 0));
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
}
