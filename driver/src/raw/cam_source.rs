//! The camera sources: frame files, MCAP images, V4L2 and the rendering simulator,
//! through the optical-flow front-end.

use super::*;
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// What the driver knows about a rendered frame beyond its image and time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct FrameTruth {
    /// Frame number counting dropped frames (a V4L2 buffer's `sequence`).
    sequence: u64,
    /// The camera's nominal frame period, ns.
    period_ns: Nanos,
    /// True mid-exposure, on the run's time base.
    event_ns: Nanos,
    /// Delivered this late after the end of exposure (software stamping).
    late_ns: Nanos,
    /// Rendered this late after the end of exposure (software stamping).
    render_late_ns: Nanos,
}

/// A frame, its time and its truth.
type TimedFrame<'a> = (cam::GrayFrame<'a, u8>, cam::FrameTime, Option<FrameTruth>);

/// Frames with their truth when the source knows it.
trait Frames {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error>;
    /// Real-time delivery counts and the render thread's priority (live rendering only).
    fn live(&self) -> Option<(LiveCounts, String)> {
        None
    }
    /// Frames the source skipped as unusable, and the last one's reason.
    fn unusable(&self) -> Option<(u64, &str)> {
        None
    }
    /// A one-time remark on how the frames are timed ([`FrameSource::take_note`]).
    fn take_note(&mut self) -> Option<String> {
        None
    }
}

/// A front-end frame source: no truth.
struct Plain(Box<dyn FrameSource>);

/// A V4L2 camera that shares, once its first frames decided it, where its frames'
/// times come from, for its reopening after a stall.
struct V4l2Frames {
    src: cam::V4l2Source,
    choice: Rc<Cell<Option<cam::FrameStamps>>>,
}

impl FrameSource for V4l2Frames {
    fn next_frame(
        &mut self,
    ) -> Result<Option<(cam::GrayFrame<'_, u8>, cam::FrameTime)>, cam::Error> {
        // the previous frames' decision (this frame borrows the source)
        if self.choice.get().is_none() {
            self.choice.set(self.src.stamp_choice());
        }
        self.src.next_frame()
    }
    fn unusable(&self) -> Option<(u64, &str)> {
        self.src.unusable()
    }
    fn take_note(&mut self) -> Option<String> {
        self.src.take_note()
    }
}

/// Where a pipe's raw frames come from (`vlsync-cam --pipe`, `--pipe-cmd`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PipeInput {
    /// The driver's standard input (`--pipe -`: `rpicam-vid ... -o - | vlsync-cam`).
    Stdin,
    /// A named FIFO (or a file), opened for reading without waiting for a writer
    /// (one that does not come is a stall, which ends the driver: reopening a FIFO
    /// would close it under a writer that hung, and kill it).
    Path(PathBuf),
    /// A command run with `sh -c` in a process group of its own, its standard output
    /// read; the whole group is killed when the driver ends, and started again when
    /// it stalls.
    Command(String),
}

impl std::fmt::Display for PipeInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PipeInput::Stdin => f.write_str("stdin"),
            PipeInput::Path(p) => write!(f, "{}", p.display()),
            PipeInput::Command(c) => write!(f, "`{c}`"),
        }
    }
}

/// The read end of a pipe, read unbuffered (the source's `poll` must see every byte
/// not yet read: `std::io::Stdin` buffers, so standard input is read through a
/// duplicate of its descriptor).
enum PipeEnd {
    File(std::fs::File),
    Command(std::process::ChildStdout),
}

impl std::io::Read for PipeEnd {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Self::File(f) => f.read(buf),
            Self::Command(out) => out.read(buf),
        }
    }
}

impl std::os::fd::AsFd for PipeEnd {
    fn as_fd(&self) -> std::os::fd::BorrowedFd<'_> {
        match self {
            Self::File(f) => f.as_fd(),
            Self::Command(out) => out.as_fd(),
        }
    }
}

/// A [`PipeEnd`] that counts the bytes read from it, for [`PipeFrames`] to tell an
/// input that never gave anything from one that ended (the frame source borrows
/// its reader whole).
struct CountedEnd {
    end: PipeEnd,
    read: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl std::io::Read for CountedEnd {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.end.read(buf)?;
        self.read
            .fetch_add(n as u64, std::sync::atomic::Ordering::Relaxed);
        Ok(n)
    }
}

impl std::os::fd::AsFd for CountedEnd {
    fn as_fd(&self) -> std::os::fd::BorrowedFd<'_> {
        self.end.as_fd()
    }
}

/// How long a pipe may stay without a frame before it is a stall (a command is
/// then started again): `rpicam-vid` takes a second or two to give its first.
pub const PIPE_SILENCE: Duration = Duration::from_secs(10);

/// Raw frames from a pipe. A command is killed when this is dropped, and one that
/// ends is an error naming how it ended (a live camera's stream does not end by
/// itself).
struct PipeFrames {
    src: cam::pipe::PipeSource<CountedEnd>,
    stop: StopFn,
    child: Option<std::process::Child>,
    /// The input as named on the command line (`-`, the FIFO's path).
    name: String,
    /// Bytes read from the input so far.
    read: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl PipeFrames {
    fn open(
        input: &PipeInput,
        cfg: cam::pipe::PipeConfig,
        stop: StopFn,
    ) -> Result<Self, cam::Error> {
        let err = |reason: String| cam::Error::Device {
            path: input.to_string().into(),
            reason,
        };
        let (end, child) = match input {
            PipeInput::Stdin => {
                use std::os::fd::AsFd;
                let fd = std::io::stdin()
                    .as_fd()
                    .try_clone_to_owned()
                    .map_err(|e| err(format!("duplicating the standard input: {e}")))?;
                (PipeEnd::File(std::fs::File::from(fd)), None)
            }
            PipeInput::Path(p) => {
                // O_NONBLOCK: a FIFO's open would otherwise wait for a writer, deaf to
                // a stop; cleared at once, so reads wait as usual (and poll watches)
                use std::os::unix::fs::OpenOptionsExt;
                let f = std::fs::OpenOptions::new()
                    .read(true)
                    .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
                    .open(p)
                    .map_err(|e| err(format!("cannot open: {e}")))?;
                rustix::fs::fcntl_setfl(&f, rustix::fs::OFlags::empty())
                    .map_err(|e| err(format!("cannot make it blocking: {e}")))?;
                (PipeEnd::File(f), None)
            }
            PipeInput::Command(c) => {
                use std::os::unix::process::CommandExt;
                // earlier programs SIGKILL could not end still there: no new one
                // until one of them exits (else a hung camera driver or USB link
                // would gain one every restart, 8600 a day)
                wait_for_fewer_left(&LEFT, MAX_LEFT, stop, Duration::from_millis(100))
                    .map_err(err)?;
                let mut child = std::process::Command::new("sh")
                    .arg("-c")
                    .arg(c)
                    .stdin(std::process::Stdio::null())
                    .stdout(std::process::Stdio::piped())
                    // its own group: a pipeline or a script's children go with it
                    .process_group(0)
                    .spawn()
                    .map_err(|e| err(format!("cannot start it with sh -c: {e}")))?;
                let Some(out) = child.stdout.take() else {
                    kill_group(child, stop);
                    return Err(err("its standard output is not a pipe".into()));
                };
                (PipeEnd::Command(out), Some(child))
            }
        };
        let name = input.to_string();
        let read = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        let end = CountedEnd {
            end,
            read: read.clone(),
        };
        let mut src = match cam::pipe::PipeSource::new(end, name.clone(), cfg, monotonic_ns) {
            Ok(s) => s,
            Err(e) => {
                if let Some(c) = child {
                    kill_group(c, stop);
                }
                return Err(e);
            }
        };
        src.set_stop(stop);
        if child.is_some() {
            // a stall names the program this driver started (stdin and a FIFO keep
            // the source's own name for their writer)
            src.set_writer_name("camera program");
        }
        Ok(Self {
            src,
            stop,
            child,
            name,
            read,
        })
    }
}

/// Camera programs SIGKILL has not ended yet, each waited for by a reaper thread
/// ([`reap_or_leave`]).
static LEFT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// The most camera programs left to reaper threads before no new one is started
/// ([`wait_for_fewer_left`]).
const MAX_LEFT: usize = 3;

/// Returns once fewer than `max` programs are `left` (at once when they are), polling
/// every `poll`; says once on stderr that it waits. A stop while it waits is an error.
fn wait_for_fewer_left(
    left: &std::sync::atomic::AtomicUsize,
    max: usize,
    stop: StopFn,
    poll: Duration,
) -> Result<(), String> {
    let mut said = false;
    while left.load(std::sync::atomic::Ordering::Acquire) >= max {
        if stop() {
            return Err(format!(
                "stopped while {max} earlier camera programs were still there after SIGKILL"
            ));
        }
        if !said {
            said = true;
            vlsync_common::console::print_err_at(
                vlsync_common::console::Priority::Warning,
                &format!(
                    "vlsync-cam: {max} earlier camera programs are still there after SIGKILL \
                     (uninterruptible sleep: a hung camera driver or USB link?): no new one is \
                     started until one of them exits (a reboot may be needed)\n"
                ),
            );
        }
        std::thread::sleep(poll);
    }
    Ok(())
}

/// How long a killed camera program is waited for before a thread is left to reap
/// it ([`reap_or_leave`]).
const REAP_WAIT: Duration = Duration::from_secs(2);

/// [`REAP_WAIT`] once a stop was asked for: the driver is on its way out.
const REAP_WAIT_STOPPING: Duration = Duration::from_millis(200);

/// Kills a camera program's whole process group (`sh` and what it started: a
/// pipeline's other programs, a script's children) and reaps `sh`, waiting for it
/// [`REAP_WAIT`] at most ([`reap_or_leave`]).
fn kill_group(mut child: std::process::Child, stop: StopFn) {
    let _ = rustix::process::kill_process_group(
        rustix::process::Pid::from_child(&child),
        rustix::process::Signal::KILL,
    );
    let _ = child.kill();
    reap_or_leave(child, REAP_WAIT, stop);
}

/// Reaps `child` once it exited, polling for up to `limit` ([`REAP_WAIT_STOPPING`]
/// at most once `stop` asks). One still there then (SIGKILL waits while a process
/// sleeps uninterruptibly: a hung camera driver or USB link) is handed to a
/// detached thread that reaps it whenever it exits, and the driver goes on: a
/// blocking wait would hang it for as long. Said once per process. True when it
/// was reaped here.
fn reap_or_leave(mut child: std::process::Child, limit: Duration, stop: StopFn) -> bool {
    static SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let t0 = Instant::now();
    loop {
        match child.try_wait() {
            // an error (no such child) leaves nothing to reap
            Ok(Some(_)) | Err(_) => return true,
            Ok(None) => {}
        }
        let waited = t0.elapsed();
        if waited >= limit || (waited >= REAP_WAIT_STOPPING && stop()) {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let pid = child.id();
    if !SAID.swap(true, std::sync::atomic::Ordering::Relaxed) {
        vlsync_common::console::print_err_at(
            vlsync_common::console::Priority::Warning,
            &format!(
                "vlsync-cam: camera program (process {pid}) still there {:.1} s after SIGKILL \
                 (in uninterruptible sleep: a hung camera driver or USB link?); a thread reaps \
                 it when it exits, the driver goes on (said once)\n",
                t0.elapsed().as_secs_f64()
            ),
        );
    }
    // a thread that cannot start leaves a zombie until the driver exits
    LEFT.fetch_add(1, std::sync::atomic::Ordering::AcqRel);
    let reaper = std::thread::Builder::new()
        .name("vlsync-reap".into())
        .spawn(move || {
            let _ = child.wait();
            LEFT.fetch_sub(1, std::sync::atomic::Ordering::AcqRel);
        });
    if reaper.is_err() {
        // no thread to count it down: not counted (it would block new programs for
        // good once it exits)
        LEFT.fetch_sub(1, std::sync::atomic::Ordering::AcqRel);
    }
    false
}

impl Drop for PipeFrames {
    fn drop(&mut self) {
        if let Some(c) = self.child.take() {
            kill_group(c, self.stop);
        }
    }
}

/// The camera program's exit status once it has ended, waiting up to half a
/// second for it (`None`: still running).
fn exit_within_half_a_second(child: &mut std::process::Child) -> Option<std::process::ExitStatus> {
    for _ in 0..50 {
        if let Ok(Some(st)) = child.try_wait() {
            return Some(st);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    None
}

impl FrameSource for PipeFrames {
    fn next_frame(
        &mut self,
    ) -> Result<Option<(cam::GrayFrame<'_, u8>, cam::FrameTime)>, cam::Error> {
        let frames = self.src.counts().0;
        match self.src.next_frame() {
            // the program is taken here, so that its group is killed now, while its
            // id is surely still its own, not on a drop perhaps long after it was reaped
            Ok(None) if !(self.stop)() => match self.child.take() {
                Some(mut child) => {
                    // it closed its output: give it a moment to exit
                    let how = exit_within_half_a_second(&mut child).map_or_else(
                        || "closed its output".to_string(),
                        |st| format!("ended ({st})"),
                    );
                    kill_group(child, self.stop);
                    // the driver's error names the command already
                    Err(cam::Error::Device {
                        path: "camera program".into(),
                        reason: format!("the command {how} after {frames} frames"),
                    })
                }
                // standard input or a FIFO: an end before any frame is no camera
                // at all (under systemd standard input is /dev/null), and exiting 0
                // with nothing published would be restarted without a word
                None if self.read.load(std::sync::atomic::Ordering::Relaxed) == 0 => {
                    Err(cam::Error::Device {
                        path: self.name.clone().into(),
                        reason: "the input ended before any frame: nothing writes to it (standard input is /dev/null under systemd: give --pipe a FIFO or use --pipe-cmd)".into(),
                    })
                }
                // a finite stream's end (a recording piped in), or a writer that quit
                None => {
                    vlsync_common::console::print_err(&format!(
                        "vlsync-cam: {}: the writer closed the pipe after {} bytes\n",
                        self.name,
                        self.read.load(std::sync::atomic::Ordering::Relaxed)
                    ));
                    Ok(None)
                }
            },
            // the pipe closed inside a frame: a program that crashed or was killed
            // mid-frame says so with its status, rather than only "a wrong size?"
            Err(cam::Error::Read { path, reason }) if self.child.is_some() => {
                let mut how = String::new();
                if let Some(mut child) = self.child.take() {
                    if let Some(st) = exit_within_half_a_second(&mut child) {
                        how = format!("; the command ended ({st})");
                    }
                    kill_group(child, self.stop);
                }
                Err(cam::Error::Read {
                    path,
                    reason: format!("{reason}{how}"),
                })
            }
            other => other,
        }
    }
    fn unusable(&self) -> Option<(u64, &str)> {
        self.src.unusable()
    }
}

/// Opens a live camera again after it stalled.
type Reopen = Box<dyn FnMut() -> Result<Box<dyn FrameSource>, cam::Error>>;

/// What stands for a camera between its close and its reopen (and after a reopen
/// that failed: the source has then ended with that error).
struct Closed;

impl FrameSource for Closed {
    fn next_frame(
        &mut self,
    ) -> Result<Option<(cam::GrayFrame<'_, u8>, cam::FrameTime)>, cam::Error> {
        Err(cam::Error::Device {
            path: "camera".into(),
            reason: "closed (its reopening failed)".into(),
        })
    }
}

/// How the camera driver names a stalled camera's silence.
pub(super) const CAM_STALL: SilenceWords = SilenceWords {
    program: "vlsync-cam",
    unit: "device",
    reopening: "reopening",
    reopens: "reopens",
    reopened: "reopened",
    still: "still no frame",
    again: "frames again",
    kind: "stall",
};

/// How the camera driver names the silence of a camera program it runs
/// (`--pipe-cmd`): the program is started again, no device reopened.
pub(super) const PROGRAM_STALL: SilenceWords = SilenceWords {
    program: "vlsync-cam",
    unit: "camera program",
    reopening: "restarting",
    reopens: "restarts",
    reopened: "restarted",
    still: "still no frame",
    again: "frames again",
    kind: "stall",
};

impl Frames for Plain {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error> {
        Ok(self.0.next_frame()?.map(|(f, t)| (f, t, None)))
    }
    fn unusable(&self) -> Option<(u64, &str)> {
        self.0.unusable()
    }
    fn take_note(&mut self) -> Option<String> {
        self.0.take_note()
    }
}

fn render_error(seed: u64, i: u64, e: &vlsync_render::RenderError) -> cam::Error {
    cam::Error::Decode {
        path: PathBuf::from(format!("render seed {seed} frame {i}")),
        reason: e.to_string(),
    }
}

/// Rendered frames on the rendered camera clock (shifted by `shift` ns), in turn.
struct RenderFrames {
    r: vlsync_render::Renderer,
    next: usize,
    shift: Nanos,
    period_ns: Nanos,
    cur: Option<vlsync_render::RenderedFrame>,
}

/// The nominal frame period of a rendered run, ns.
fn frame_period_ns(r: &vlsync_render::Renderer) -> Nanos {
    (1e9 / r.config().camera.fps).round() as Nanos
}

impl Frames for RenderFrames {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error> {
        let i = self.next;
        match self.r.render_frame(i) {
            None => Ok(None),
            // a frame that failed is skipped like one the camera dropped: the
            // next call renders the frame after it, not this one again
            Some(Err(e)) => {
                self.next += 1;
                Err(render_error(self.r.config().seed, i as u64, &e))
            }
            Some(Ok(f)) => {
                self.next += 1;
                let time = match f.time {
                    cam::FrameTime::Instant(t) => cam::FrameTime::Instant(t + self.shift),
                    cam::FrameTime::Exposure {
                        start_ns,
                        duration_ns,
                    } => cam::FrameTime::Exposure {
                        start_ns: start_ns + self.shift,
                        duration_ns,
                    },
                };
                let truth = FrameTruth {
                    sequence: f.index,
                    period_ns: self.period_ns,
                    event_ns: f.tau_mid_ns + self.shift,
                    ..FrameTruth::default()
                };
                let f = self.cur.insert(f);
                Ok(Some((f.image.view(), time, Some(truth))))
            }
        }
    }
}

/// Frames rendered ahead of time on a thread ("the camera hardware").
pub const RENDER_AHEAD_FRAMES: usize = 30;
/// Nice value asked for the render thread, so host load does not slow the
/// simulated camera hardware (refusal is reported, not fatal).
pub const RENDER_THREAD_NICE: i32 = -10;

struct Rendered {
    /// The frame's index in the run (named by an error).
    index: usize,
    frame: Result<vlsync_render::RenderedFrame, vlsync_render::RenderError>,
    /// `CLOCK_MONOTONIC` when rendering finished.
    done_ns: Nanos,
}

/// Rendered frames delivered in real time for software stamping.
struct LiveRender {
    rx: Receiver<Rendered>,
    seed: u64,
    shift: Nanos,
    period_ns: Nanos,
    stop: StopFn,
    /// Frames whose exposure ended before this were skipped (a restarted driver).
    skip_before: Nanos,
    cur: Option<vlsync_render::RenderedFrame>,
    nice: std::sync::Arc<std::sync::Mutex<Option<String>>>,
    live: LiveCounts,
}

/// What the real-time delivery of rendered frames saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LiveCounts {
    /// Frames delivered.
    pub delivered: u64,
    /// Frames skipped because their time passed before the driver started.
    pub skipped: u64,
    /// Frames the renderer finished after their exposure ended.
    pub render_late: u64,
    /// Largest render lateness, ns.
    pub max_render_late_ns: Nanos,
    /// Largest delivery lateness (end of exposure to front-end), ns.
    pub max_late_ns: Nanos,
}

impl LiveRender {
    fn start(r: vlsync_render::Renderer, shift: Nanos, stop: StopFn) -> Result<Self, SourceError> {
        let seed = r.config().seed;
        let period_ns = frame_period_ns(&r);
        let now = monotonic_ns();
        let exp_half = vlsync_common::secs_to_nanos(r.config().camera.exposure_s) / 2;
        // a driver restarted mid-run (start_at in the past) resumes at the current frame
        let skip_before = if shift + render_anchor_ns(&r) < now {
            now
        } else {
            Nanos::MIN
        };
        let first = r
            .frame_schedule()
            .iter()
            .position(|f| f.tau_mid_ns + exp_half + shift >= skip_before)
            .unwrap_or(r.frame_schedule().len());
        let (tx, rx) = sync_channel(RENDER_AHEAD_FRAMES);
        let nice = std::sync::Arc::new(std::sync::Mutex::new(None));
        let nice_t = nice.clone();
        let mut r = r;
        std::thread::Builder::new()
            .name("vlsync-render".into())
            .spawn(move || {
                let got = vlsync_ipc::rt::set_current_thread_nice(
                    RENDER_THREAD_NICE,
                    &format!("render thread nice {RENDER_THREAD_NICE}"),
                );
                if let Ok(mut n) = nice_t.lock() {
                    *n = Some(match got {
                        Ok(()) => format!("render thread at nice {RENDER_THREAD_NICE}"),
                        Err(e) => format!("{e}; render thread at the default priority"),
                    });
                }
                let mut i = first;
                while let Some(frame) = r.render_frame(i) {
                    let index = i;
                    i += 1;
                    let done_ns = monotonic_ns();
                    if tx
                        .send(Rendered {
                            index,
                            frame,
                            done_ns,
                        })
                        .is_err()
                    {
                        break; // the driver is gone
                    }
                }
            })
            .map_err(|e| {
                SourceError(format!(
                    "render seed {seed}: cannot start the render thread: {e}"
                ))
            })?;
        Ok(Self {
            rx,
            seed,
            shift,
            period_ns,
            stop,
            skip_before,
            cur: None,
            nice,
            live: LiveCounts {
                skipped: first as u64,
                ..LiveCounts::default()
            },
        })
    }
}

impl Frames for LiveRender {
    fn next(&mut self) -> Result<Option<TimedFrame<'_>>, cam::Error> {
        let f = loop {
            if (self.stop)() {
                return Ok(None);
            }
            let r = match self.rx.recv_timeout(MAX_WAIT) {
                Ok(r) => r,
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => return Ok(None),
            };
            let f = r
                .frame
                .map_err(|e| render_error(self.seed, r.index as u64, &e))?;
            let due = f.tau_available_ns + self.shift;
            if due < self.skip_before {
                self.live.skipped += 1;
                continue;
            }
            let render_late = (r.done_ns - due).max(0);
            if render_late > 0 {
                self.live.render_late += 1;
                self.live.max_render_late_ns = self.live.max_render_late_ns.max(render_late);
            }
            // the exposure ends at `due`: the frame exists from then on
            loop {
                let now = monotonic_ns();
                if now >= due {
                    break;
                }
                if (self.stop)() {
                    return Ok(None);
                }
                std::thread::sleep(Duration::from_nanos((due - now) as u64).min(MAX_WAIT));
            }
            break (f, render_late, due);
        };
        let (f, render_late_ns, due) = f;
        let now = monotonic_ns();
        let late_ns = now - due;
        self.live.delivered += 1;
        self.live.max_late_ns = self.live.max_late_ns.max(late_ns);
        let truth = FrameTruth {
            sequence: f.index,
            period_ns: self.period_ns,
            event_ns: f.tau_mid_ns + self.shift,
            late_ns,
            render_late_ns,
        };
        let f = self.cur.insert(f);
        Ok(Some((
            f.image.view(),
            cam::FrameTime::Instant(now),
            Some(truth),
        )))
    }

    fn live(&self) -> Option<(LiveCounts, String)> {
        let nice = self
            .nice
            .lock()
            .ok()
            .and_then(|n| n.clone())
            .unwrap_or_else(|| "render thread priority unknown".into());
        Some((self.live, nice))
    }
}

/// Longest single wait of the live render source, so a stop request is seen.
const MAX_WAIT: Duration = Duration::from_millis(50);

/// What the camera front-end did with the frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CamCounts {
    /// Frames read.
    pub frames: u64,
    /// Samples published.
    pub samples: u64,
    /// Samples dropped for low texture (too few tracked points).
    pub low_texture: u64,
    /// Samples dropped because no point was tracked or the value was not finite.
    pub no_flow: u64,
    /// Sequences restarted by a gap: an interval longer than the processor's gap
    /// limit (`max_gap_ns`, 250 ms, or 4.5 frame periods of a camera slower than
    /// 18 Hz; `SignatureProcessor::gap_limit_ns`). A camera slower than 4 Hz also
    /// counts its first two intervals here, and one that slows down to that its first
    /// slow intervals, until its new period is confirmed (a slow-down to a whole
    /// fraction of the rate, 30 to 15 or 7.5 Hz, keeps the old period, and its
    /// limit follows once 8 intervals have spanned several periods each).
    pub gaps: u64,
    /// Frames whose time was not after the previous one (sequence restarted).
    pub not_increasing: u64,
    /// Frames whose time came less than a quarter of the confirmed frame period
    /// after the previous one (two frames held up and delivered together: no
    /// interval to scale the flow by; sequence restarted).
    pub bunched: u64,
    /// Frames whose size changed (sequence restarted).
    pub size_changed: u64,
    /// Frames the processor refused (bad exposure time, unusable size).
    pub refused: u64,
    /// The point counts of the last frame pair compared (its sample published or
    /// not): what an installer aiming the camera wants to see.
    pub last_flow: Option<cam::FlowStats>,
}

/// Camera frames through `SignatureProcessor`.
pub struct CamSource {
    frames: Box<dyn Frames>,
    proc: cam::SignatureProcessor,
    what: String,
    stop: StopFn,
    counts: CamCounts,
    last_refusal: Option<String>,
    /// Frames refused in a row as too small for the flow's region, margin and
    /// pyramid: a stream of one size refuses every frame, and ends the source
    /// at [`TOO_SMALL_IN_A_ROW`] instead of running on without a sample.
    too_small: u32,
    /// Stamp each frame with `CLOCK_MONOTONIC` after processing it.
    software: bool,
    /// Software stamp and truth of the previous frame the processor kept.
    prev: Option<(Nanos, Option<FrameTruth>)>,
    last_truth: Option<SampleTruth>,
    /// CPU time each frame costs before it is stamped, ns (0: the front-end's own).
    frame_cpu_ns: Nanos,
    /// Frames of a recording that could not be read (an undecodable or missing
    /// image): skipped as dropped frames, until too many come in a row.
    skipped: cam::UnusableFrames,
    /// A live camera: how to open it again after it stalled ([`cam::Error::Stalled`]).
    reopen: Option<Reopen>,
    /// The stall going on, if any.
    stall: Option<Silence>,
    /// Reopens after stalls over the run.
    reopens: u64,
    /// How a stall and its reopens are said: a device reopened, a camera program
    /// restarted.
    words: &'static SilenceWords,
    /// How long [`Source::next_event`] goes without a sample before it returns
    /// [`Next::Idle`].
    idle_every: Duration,
}

/// Frames refused in a row as too small that end a camera source (a size
/// change mid-stream refuses a few at most; a stream of one too small size all).
const TOO_SMALL_IN_A_ROW: u32 = 10;

impl std::fmt::Debug for CamSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CamSource")
            .field("what", &self.what)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

impl CamSource {
    fn new(frames: Box<dyn FrameSource>, what: String, stop: StopFn) -> Result<Self, SourceError> {
        Self::with_frames(Box::new(Plain(frames)), what, stop, false)
    }

    fn with_frames(
        frames: Box<dyn Frames>,
        what: String,
        stop: StopFn,
        software: bool,
    ) -> Result<Self, SourceError> {
        let proc = cam::SignatureProcessor::new(cam::SignatureConfig::default())
            .map_err(|e| SourceError(format!("{what}: camera signature config: {e}")))?;
        Ok(Self {
            frames,
            proc,
            what,
            stop,
            counts: CamCounts::default(),
            last_refusal: None,
            too_small: 0,
            software,
            prev: None,
            last_truth: None,
            frame_cpu_ns: 0,
            skipped: cam::UnusableFrames::default(),
            reopen: None,
            stall: None,
            reopens: 0,
            words: &CAM_STALL,
            idle_every: crate::IDLE_EVERY,
        })
    }

    /// Makes the source end (`Ok(None)`) once `stop` returns true, checked before
    /// each frame: a recording or a rendered run read ahead of real time (up to its
    /// first usable sample when the driver anchors its pacing) stops at a SIGTERM
    /// as a live camera does.
    pub fn with_stop(mut self, stop: StopFn) -> Self {
        self.stop = stop;
        self
    }

    /// A live camera that stalled ([`cam::Error::Stalled`]): says so (once, then every
    /// [`SILENCE_REPEAT`]) and opens it again with `self.reopen`, instead of ending the
    /// driver, whose unit would restart it every few seconds for as long as the
    /// camera hangs. A camera that cannot be opened again (unplugged) is an error.
    fn on_stall(&mut self, e: &cam::Error) -> Result<(), SourceError> {
        let what = &self.what;
        if self.reopen.is_none() {
            return Err(SourceError(format!("{what}: {e}")));
        }
        let so_far = match e {
            cam::Error::Stalled { after, .. } => *after,
            _ => Duration::ZERO,
        };
        Silence::say(&mut self.stall, Instant::now(), so_far, self.words, what, e);
        // closed first: a device that streams to one handle refuses another's format
        self.frames = Box::new(Plain(Box::new(Closed)));
        if let Some(reopen) = self.reopen.as_mut() {
            let src = reopen().map_err(|e| {
                SourceError(format!(
                    "{}: {} after a stall: {e}",
                    self.what, self.words.reopening
                ))
            })?;
            self.frames = Box::new(Plain(src));
        }
        self.reopens += 1;
        Silence::reopened(&mut self.stall);
        Ok(())
    }

    /// With software stamping: keep each frame's thread busy until it has spent
    /// `ns` of CPU on the frame (front-end included) before stamping it; stands in
    /// for a heavier front-end, whose stamps CPU contention delays accordingly.
    pub fn set_frame_cpu_ns(&mut self, ns: Nanos) {
        self.frame_cpu_ns = ns.max(0);
    }

    /// A directory of frames with `frames.csv` (see `vlsync_signature_cam::source`).
    pub fn frames_dir(dir: &Path) -> Result<Self, SourceError> {
        let src = cam::DirSource::open(dir).map_err(|e| SourceError(format!("--frames: {e}")))?;
        let n = src.entries().len();
        Self::new(
            Box::new(src),
            format!("frames {} ({n} frames)", dir.display()),
            never,
        )
    }

    /// The image topic of a recording (`topic`, or the only image topic).
    pub fn mcap(path: &Path, topic: Option<&str>) -> Result<Self, SourceError> {
        let opts = match topic {
            Some(t) => vlsync_mcap::ImageSourceOptions::topic(t),
            None => vlsync_mcap::ImageSourceOptions::default(),
        };
        let src = vlsync_mcap::McapImageSource::open(path, opts)
            .map_err(|e| SourceError(format!("--mcap: {e}")))?;
        let what = format!(
            "mcap {} topic {}",
            path.display(),
            vlsync_common::text::clip(&src.topic().topic)
        );
        Self::new(Box::new(src), what, never)
    }

    /// Raw frames of `cfg`'s layout from a pipe (see `vlsync_signature_cam::pipe`),
    /// stamped on `CLOCK_MONOTONIC` as they arrive. A command is started again after
    /// `cfg.silence` without a frame (the driver's [`PIPE_SILENCE`]); standard input
    /// or a FIFO that goes silent is an error.
    pub fn pipe(
        input: PipeInput,
        cfg: cam::pipe::PipeConfig,
        stop: StopFn,
    ) -> Result<Self, SourceError> {
        let flag = match input {
            PipeInput::Command(_) => "--pipe-cmd",
            _ => "--pipe",
        };
        let frames =
            PipeFrames::open(&input, cfg, stop).map_err(|e| SourceError(format!("{flag}: {e}")))?;
        let what = format!("pipe {}", frames.src.describe());
        let mut me = Self::new(Box::new(frames), what, stop)?;
        if matches!(input, PipeInput::Command(_)) {
            me.words = &PROGRAM_STALL;
            me.reopen = Some(Box::new(move || {
                PipeFrames::open(&input, cfg, stop).map(|f| Box::new(f) as Box<dyn FrameSource>)
            }));
        }
        Ok(me)
    }

    /// A V4L2 camera (`/dev/videoN`) at its own frame rate; needs the `v4l2` cargo
    /// feature.
    pub fn v4l2(device: &Path, stop: StopFn) -> Result<Self, SourceError> {
        Self::v4l2_at(device, None, stop)
    }

    /// A V4L2 camera asked for frame rate `fps` (Hz, `None`: its own); needs the
    /// `v4l2` cargo feature. The opening's line of what it negotiated (and its
    /// exposure warning) is printed at the start, and again at a reopen after a stall
    /// only when the camera negotiated something else.
    pub fn v4l2_at(device: &Path, fps: Option<f64>, stop: StopFn) -> Result<Self, SourceError> {
        if !cfg!(feature = "v4l2") {
            return Err(SourceError(format!(
                "--v4l2 {}: built without V4L2 support; rebuild with --features vlsync-driver/v4l2",
                device.display()
            )));
        }
        let cfg = cam::V4l2Config {
            device: device.to_path_buf(),
            fps,
            ..cam::V4l2Config::default()
        };
        // where the frames' times come from, once an opening's first frames decided
        // it: a reopen keeps it (the stamps' clock does not change with a stall)
        let choice = Rc::new(Cell::new(None));
        // what the last opening said it negotiated: a stalled camera reopened every
        // 10 s says it again only when it changed
        let said: Rc<RefCell<Option<cam::v4l2::negotiate::Negotiated>>> = Rc::default();
        // a stalled camera's wait wakes to check the stop (and ends in
        // `Error::Stalled` after `V4l2Config::stall`, on which the device is opened
        // again), instead of blocking the driver for good
        let open = move |stamps: Option<cam::FrameStamps>| -> Result<cam::V4l2Source, cam::Error> {
            let mut src = cam::V4l2Source::open(&cam::V4l2Config {
                stamps,
                ..cfg.clone()
            })?;
            src.set_stop(stop);
            let mut said = said.borrow_mut();
            match said.as_ref() {
                Some(last) if last.same_setup(src.negotiated()) => src.skip_opening_notes(),
                _ => *said = Some(src.negotiated().clone()),
            }
            Ok(src)
        };
        let src = open(None).map_err(|e| SourceError(format!("--v4l2: {e}")))?;
        let (w, h) = src.frame_size();
        let mut me = Self::new(
            Box::new(V4l2Frames {
                src,
                choice: choice.clone(),
            }),
            format!("v4l2 {} ({w}x{h})", device.display()),
            stop,
        )?;
        me.reopen = Some(Box::new(move || {
            open(choice.get()).map(|src| {
                Box::new(V4l2Frames {
                    src,
                    choice: choice.clone(),
                }) as Box<dyn FrameSource>
            })
        }));
        Ok(me)
    }

    /// The frames of rendered run `seed` on the rendered camera clock (see [`renderer`]).
    pub fn render(r: vlsync_render::Renderer) -> Result<Self, SourceError> {
        Self::render_with(r, RenderStamp::Sensor, never)
    }

    /// The frames of a rendered run, stamped as `stamp` says. `Software`
    /// renders on a thread and delivers each frame at the end of its exposure
    /// (`stop` is polled while waiting); the others render on demand. The source
    /// ends once `stop` returns true (checked before each frame).
    pub fn render_with(
        r: vlsync_render::Renderer,
        stamp: RenderStamp,
        stop: StopFn,
    ) -> Result<Self, SourceError> {
        let what = format!(
            "render seed {} ({} s, {} frames{})",
            r.config().seed,
            r.config().duration_s,
            r.frame_schedule().len(),
            match stamp {
                RenderStamp::Sensor => "",
                RenderStamp::Mono { .. } => ", sensor stamps on CLOCK_MONOTONIC",
                RenderStamp::Software { .. } =>
                    ", real time, stamped on CLOCK_MONOTONIC after processing",
            }
        );
        match stamp {
            RenderStamp::Software { shift_ns } => Self::with_frames(
                Box::new(LiveRender::start(r, shift_ns, stop)?),
                what,
                stop,
                true,
            ),
            _ => Self::with_frames(
                Box::new(RenderFrames {
                    period_ns: frame_period_ns(&r),
                    r,
                    next: 0,
                    shift: stamp.shift_ns(),
                    cur: None,
                }),
                what,
                stop,
                false,
            ),
        }
    }

    /// The counts so far.
    pub fn counts(&self) -> CamCounts {
        self.counts
    }

    /// Real-time delivery counts of a software-stamped render.
    pub fn live_counts(&self) -> Option<LiveCounts> {
        self.frames.live().map(|l| l.0)
    }
}

impl Source for CamSource {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        crate::sample_of_events(|| self.next_event())
    }

    fn next_event(&mut self) -> Result<Next, SourceError> {
        let called = Instant::now();
        let mut first = true;
        loop {
            // frames without a sample (low texture, no flow), a stall: give the
            // driver its periodic work after about a second (never before a frame)
            if !std::mem::take(&mut first) && called.elapsed() >= self.idle_every {
                return Ok(Next::Idle);
            }
            // the source's remark on the previous frame (a live camera's first frames
            // decide whose clock stamps its frames)
            if let Some(note) = self.frames.take_note() {
                vlsync_common::console::print_err(&format!("vlsync-cam: {}: {note}\n", self.what));
            }
            if (self.stop)() {
                return Ok(Next::End);
            }
            let Self {
                frames,
                proc,
                what,
                counts,
                last_refusal,
                too_small,
                software,
                prev,
                last_truth,
                frame_cpu_ns,
                skipped,
                stall,
                words,
                ..
            } = self;
            let next = match frames.next() {
                Ok(next) => next,
                // a live camera that hung is opened again
                Err(e @ cam::Error::Stalled { .. }) => {
                    self.on_stall(&e)?;
                    continue;
                }
                // one bad image of a recording is a dropped frame, not the end of it
                Err(e) if e.is_one_frame() => {
                    skipped
                        .skip(e.to_string())
                        .map_err(|m| SourceError(format!("{what}: {m}")))?;
                    continue;
                }
                Err(e) => return Err(SourceError(format!("{what}: {e}"))),
            };
            let Some((frame, time, truth)) = next else {
                return Ok(Next::End);
            };
            skipped.used();
            Silence::say_end(stall, words, what);
            counts.frames += 1;
            let t_in = monotonic_ns();
            let cpu_in = (*frame_cpu_ns > 0)
                .then(vlsync_ipc::rt::thread_cpu_ns)
                .flatten();
            let step = proc.process(&frame, time);
            if let Some(c0) = cpu_in {
                burn_cpu_until(c0.saturating_add(*frame_cpu_ns));
            }
            // software stamping: the clock is read once the front-end is done
            let t_done = monotonic_ns();
            let this = (t_done, truth);
            *too_small = match &step {
                Err(cam::Error::FrameTooSmall { .. }) => too_small.saturating_add(1),
                _ => 0,
            };
            match step {
                Err(e) if *too_small >= TOO_SMALL_IN_A_ROW => {
                    return Err(SourceError(format!(
                        "{what}: {e} ({TOO_SMALL_IN_A_ROW} frames in a row): no sample can \
                         come from this stream; give the camera a larger size (--size for \
                         a pipe)"
                    )));
                }
                Err(e) => {
                    counts.refused += 1;
                    *last_refusal = Some(e.to_string());
                    *prev = None;
                }
                Ok(cam::Step::Started(r)) => {
                    *prev = Some(this);
                    match r {
                        cam::StartReason::First => {}
                        cam::StartReason::Gap { .. } => counts.gaps += 1,
                        cam::StartReason::NotIncreasing { .. } => counts.not_increasing += 1,
                        cam::StartReason::Bunched { .. } => counts.bunched += 1,
                        cam::StartReason::SizeChanged { .. } => counts.size_changed += 1,
                    }
                }
                Ok(cam::Step::Sample(s)) => {
                    counts.last_flow = Some(s.stats);
                    let before = prev.replace(this);
                    let mut sample = s.sample;
                    if *software {
                        // stamped at the midpoint of the two software stamps; the
                        // flow is over the frames' own interval: the frame numbers
                        // times the nominal period when known (software stamps
                        // jitter by tens of ms under load, the sensor's clock does
                        // not), else the software interval
                        let p_sw = before.map_or(t_done, |b| b.0);
                        let dt = t_done - p_sw;
                        if dt <= 0 {
                            counts.not_increasing += 1;
                            continue;
                        }
                        let interval = match (before.and_then(|b| b.1), truth) {
                            (Some(a), Some(b)) if b.sequence > a.sequence && b.period_ns > 0 => {
                                (b.sequence - a.sequence) as f64 * b.period_ns as f64
                            }
                            _ => dt as f64,
                        };
                        sample = Sample::new(
                            mid(p_sw, t_done),
                            s.flow_px * vlsync_common::NANOS_PER_SEC as f64 / interval,
                        );
                    }
                    if !sample.value.is_finite() {
                        counts.no_flow += 1;
                    } else if s.low_texture() {
                        counts.low_texture += 1;
                    } else {
                        counts.samples += 1;
                        *last_truth = match (before.and_then(|b| b.1), truth) {
                            (Some(a), Some(b)) => Some(SampleTruth {
                                event_ns: mid(a.event_ns, b.event_ns),
                                late_ns: b.late_ns,
                                process_ns: t_done - t_in,
                                render_late_ns: b.render_late_ns,
                            }),
                            _ => None,
                        };
                        return Ok(Next::Sample(sample));
                    }
                }
            }
        }
    }

    fn describe(&self) -> String {
        self.what.clone()
    }

    fn truth(&self) -> Option<SampleTruth> {
        self.last_truth
    }

    fn report(&self) -> Option<String> {
        let c = &self.counts;
        let mut s = format!(
            "{} frames, {} samples; dropped: {} low texture, {} no flow; restarts: {} gaps, \
             {} non-increasing times, {} bunched times, {} size changes; {} frames refused",
            c.frames,
            c.samples,
            c.low_texture,
            c.no_flow,
            c.gaps,
            c.not_increasing,
            c.bunched,
            c.size_changed,
            c.refused
        );
        if let Some(r) = &self.last_refusal {
            s.push_str(&format!(" (last: {r})"));
        }
        match c.last_flow {
            Some(f) => {
                let few = if f.low_texture {
                    "; too few: low texture"
                } else {
                    ""
                };
                s.push_str(&format!(
                    "; last frame pair: {} of {} grid points tracked \
                     ({} textured, {} inconsistent{few})",
                    f.tracked, f.points, f.textured, f.inconsistent
                ));
            }
            None => s.push_str("; no frame pair compared yet"),
        }
        // a live camera's bad buffers (its source counts them), a recording's bad images
        for (n, last) in [self.frames.unusable(), self.skipped.counts()]
            .into_iter()
            .flatten()
        {
            s.push_str(&format!("; {n} unusable frames skipped (last: {last})"));
        }
        if self.reopens > 0 {
            s.push_str(&format!(
                "; the {} {} {} times after stalls",
                self.words.unit, self.words.reopened, self.reopens
            ));
        }
        if let Some(lasted) = Silence::lasted(&self.stall) {
            s.push_str(&format!("; stalled for {:.0} s now", lasted.as_secs_f64()));
        }
        if let Some((l, nice)) = self.frames.live() {
            s.push_str(&format!(
                "; real time: {} frames delivered, {} skipped (before a restart), {} rendered late \
                 (worst {:.1} ms), worst delivery {:.1} ms after exposure end; {nice}",
                l.delivered,
                l.skipped,
                l.render_late,
                l.max_render_late_ns as f64 / 1e6,
                l.max_late_ns as f64 / 1e6
            ));
        }
        Some(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At most [`MAX_LEFT`] unkillable camera programs: the next one waits until one of
    /// them exits, and a stop ends the wait.
    #[test]
    fn no_new_camera_program_while_too_many_are_left() {
        use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
        static LEFT_HERE: AtomicUsize = AtomicUsize::new(0);
        static STOP_HERE: AtomicBool = AtomicBool::new(false);
        fn never() -> bool {
            false
        }
        fn stop() -> bool {
            STOP_HERE.load(Ordering::Relaxed)
        }
        let poll = Duration::from_millis(1);
        LEFT_HERE.store(2, Ordering::Relaxed);
        assert_eq!(wait_for_fewer_left(&LEFT_HERE, 3, never, poll), Ok(()));
        // at the limit: returns only once one of them was reaped
        LEFT_HERE.store(3, Ordering::Relaxed);
        let reaper = std::thread::spawn(|| {
            std::thread::sleep(Duration::from_millis(30));
            LEFT_HERE.fetch_sub(1, Ordering::AcqRel);
        });
        assert_eq!(wait_for_fewer_left(&LEFT_HERE, 3, never, poll), Ok(()));
        assert_eq!(LEFT_HERE.load(Ordering::Relaxed), 2);
        reaper.join().unwrap();
        LEFT_HERE.store(3, Ordering::Relaxed);
        STOP_HERE.store(true, Ordering::Relaxed);
        assert_eq!(
            wait_for_fewer_left(&LEFT_HERE, 3, stop, poll),
            Err("stopped while 3 earlier camera programs were still there after SIGKILL".into())
        );
    }

    /// A camera that stalls `stalls` times, then delivers `frames` flat frames and ends.
    struct Fake {
        stalls: u32,
        frames: u32,
        t: Nanos,
        buf: Vec<u8>,
    }

    impl FrameSource for Fake {
        fn next_frame(
            &mut self,
        ) -> Result<Option<(cam::GrayFrame<'_, u8>, cam::FrameTime)>, cam::Error> {
            if self.stalls > 0 {
                self.stalls -= 1;
                return Err(cam::Error::Stalled {
                    path: "/dev/video-fake".into(),
                    after: Duration::from_secs(10),
                });
            }
            if self.frames == 0 {
                return Ok(None);
            }
            self.frames -= 1;
            self.t += 33_333_333;
            let f = cam::GrayFrame::borrowed(64, 48, &self.buf)?;
            Ok(Some((f, cam::FrameTime::Instant(self.t))))
        }
    }

    /// A camera with a remark on its timing after its first frame, counting the
    /// times the remark was asked for and handed out.
    struct Noting {
        inner: Fake,
        asked: Rc<Cell<(u32, u32)>>,
    }

    impl FrameSource for Noting {
        fn next_frame(
            &mut self,
        ) -> Result<Option<(cam::GrayFrame<'_, u8>, cam::FrameTime)>, cam::Error> {
            self.inner.next_frame()
        }
        fn take_note(&mut self) -> Option<String> {
            let (asked, given) = self.asked.get();
            let give = self.inner.frames < 5 && given == 0;
            self.asked.set((asked + 1, given + u32::from(give)));
            give.then(|| "stamped at dequeue (test)".to_string())
        }
    }

    #[test]
    fn the_sources_timing_remark_is_taken_after_each_frame() {
        let asked = Rc::new(Cell::new((0, 0)));
        let src = Noting {
            inner: Fake {
                stalls: 0,
                frames: 5,
                t: 0,
                buf: vec![128; 64 * 48],
            },
            asked: asked.clone(),
        };
        let mut src = CamSource::new(Box::new(src), "v4l2 fake".into(), never).unwrap();
        assert_eq!(src.next_sample().unwrap(), None);
        // once before each of the 5 frames and before the end: handed out once
        assert_eq!(asked.get(), (6, 1));
    }

    fn fake(stalls: u32, frames: u32) -> Box<dyn FrameSource> {
        Box::new(Fake {
            stalls,
            frames,
            t: 0,
            buf: vec![128; 64 * 48],
        })
    }

    #[test]
    fn frames_without_a_sample_return_idle_between_frames() {
        // flat frames give no sample: with a period of 0, each call reads one frame
        // and returns idle, then the end
        let mut src = CamSource::new(fake(0, 5), "fake".into(), never).unwrap();
        src.idle_every = Duration::ZERO;
        let events: Vec<Next> = std::iter::from_fn(|| match src.next_event().unwrap() {
            Next::End => None,
            e => Some(e),
        })
        .collect();
        assert_eq!(events, vec![Next::Idle; 5]);
        assert_eq!(src.counts().frames, 5);
        // with the default period, next_sample (which skips them) as before
        let mut src = CamSource::new(fake(0, 5), "fake".into(), never).unwrap();
        assert_eq!(src.next_event().unwrap(), Next::End);
        assert_eq!(src.counts().frames, 5);
    }

    fn yes() -> bool {
        true
    }

    #[test]
    fn a_camera_program_that_will_not_die_is_left_to_a_thread_not_waited_for() {
        let alive = |pid: u32| {
            std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .ok()
                .and_then(|st| st.rsplit(") ").next().map(|r| !r.starts_with('Z')))
                .unwrap_or(false)
        };
        let gone = |pid: u32| !std::path::Path::new(&format!("/proc/{pid}")).exists();
        // a child that exits is reaped here
        let child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        assert!(reap_or_leave(child, Duration::from_secs(5), never));
        assert!(gone(pid) || !alive(pid));
        // one that does not exit in time (standing in for a program in
        // uninterruptible sleep, which SIGKILL does not end): the driver goes on.
        // The program lives 30 s: a reaper that waited for it to exit (the bug), or
        // a stop that did not cut the 30 s limit short, takes 30 s, twice the bound
        // below; the lower bound is the wait the code guarantees first.
        for (limit, stop, at_least) in [
            (
                Duration::from_millis(300),
                never as StopFn,
                Duration::from_millis(300),
            ),
            // a stop shortens a long wait
            (Duration::from_secs(30), yes as StopFn, REAP_WAIT_STOPPING),
        ] {
            let child = std::process::Command::new("sleep")
                .arg("30")
                .spawn()
                .unwrap();
            let pid = child.id();
            let t0 = Instant::now();
            assert!(!reap_or_leave(child, limit, stop));
            let took = t0.elapsed();
            assert!(
                took >= at_least && took < Duration::from_secs(15),
                "{took:?} (limit {limit:?})"
            );
            assert!(alive(pid));
            // once it exits, the thread reaps it: no zombie left behind
            // kill(2) itself: procps's `kill` is not on every minimal system
            let raw = rustix::process::Pid::from_raw(pid as i32).unwrap();
            rustix::process::kill_process(raw, rustix::process::Signal::KILL).unwrap();
            let deadline = Instant::now() + Duration::from_secs(5);
            while !gone(pid) {
                assert!(Instant::now() < deadline, "{pid} not reaped");
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }

    #[test]
    fn the_report_says_how_many_points_the_last_frame_pair_tracked() {
        let mut src = CamSource::render(renderer(2, 1.0).unwrap()).unwrap();
        let report = src.report().unwrap();
        assert!(report.contains("; no frame pair compared yet"), "{report}");
        while src.next_sample().unwrap().is_some() {}
        let report = src.report().unwrap();
        let tracked = report
            .split("last frame pair: ")
            .nth(1)
            .and_then(|r| r.split(" of 128 grid points tracked").next())
            .and_then(|n| n.parse::<usize>().ok())
            .unwrap_or_else(|| panic!("no tracked count in {report}"));
        // the rendered floor is textured everywhere
        assert!(tracked >= 100, "{report}");
        assert!(!report.contains("low texture)"), "{report}");
        // flat frames: nothing tracked, and the report says why no sample came
        let mut src = CamSource::new(fake(0, 5), "v4l2 fake".into(), never).unwrap();
        assert_eq!(src.next_sample().unwrap(), None);
        let report = src.report().unwrap();
        assert!(
            report.contains("last frame pair: 0 of 128 grid points tracked (0 textured, 0 inconsistent; too few: low texture)"),
            "{report}"
        );
    }

    #[test]
    fn a_stalled_live_camera_is_opened_again_and_read_on() {
        // stalls at once; the first reopen stalls again, the second delivers
        let opened = Rc::new(Cell::new(0));
        let mut src = CamSource::new(fake(1, 0), "v4l2 fake".into(), never).unwrap();
        let n = opened.clone();
        src.reopen = Some(Box::new(move || {
            n.set(n.get() + 1);
            Ok(if n.get() == 1 { fake(1, 0) } else { fake(0, 5) })
        }));
        // flat frames give no sample: the stream's end after them
        assert_eq!(src.next_sample().unwrap(), None);
        assert_eq!(opened.get(), 2);
        let report = src.report().unwrap();
        assert!(
            report.starts_with("5 frames,")
                && report.contains("the device reopened 2 times after stalls"),
            "{report}"
        );
        assert!(!report.contains("stalled for"), "{report}");
        // a camera that cannot be opened again (unplugged): an error naming both
        let mut src = CamSource::new(fake(1, 0), "v4l2 fake".into(), never).unwrap();
        src.reopen = Some(Box::new(|| {
            Err(cam::Error::NoDevice {
                path: "/dev/video-fake".into(),
            })
        }));
        let e = src.next_sample().unwrap_err().to_string();
        assert_eq!(
            e,
            "v4l2 fake: reopening after a stall: /dev/video-fake: no such device"
        );
        // sources that are not live cameras end on a stall, as before
        let mut src = CamSource::new(fake(1, 0), "fake".into(), never).unwrap();
        let e = src.next_sample().unwrap_err().to_string();
        assert!(
            e.starts_with("fake: /dev/video-fake: no frame for 10.0 s"),
            "{e}"
        );
    }
}
