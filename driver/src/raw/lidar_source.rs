//! The LiDAR sources: LD06/LD19 and RPLIDAR on a serial port, scan CSVs, MCAP
//! LaserScans and the rendering simulator, through the wall-distance front-end.

use super::*;

/// Which serial LiDAR.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SerialKind {
    /// LDROBOT LD06 / LD19 (230400 baud, streams on power-up).
    Ld06,
    /// Slamtec RPLIDAR standard scan (115200 baud by default; the scan request is sent).
    Rplidar,
}

impl SerialKind {
    /// The usual baud rate.
    pub fn default_baud(self) -> u32 {
        match self {
            SerialKind::Ld06 => lidar::ld06::BAUD,
            SerialKind::Rplidar => RplidarConfig::default().baud,
        }
    }

    fn flag(self) -> &'static str {
        match self {
            SerialKind::Ld06 => "--ld06",
            SerialKind::Rplidar => "--rplidar",
        }
    }
}

enum Parser {
    Ld06(Ld06Parser),
    Rplidar(RplidarParser),
}

/// A live serial LiDAR.
struct Serial {
    /// `None` only after a reopen failed (the source has then ended with an error).
    port: Option<SerialLidar>,
    parser: Parser,
    stop: StopFn,
    kind: SerialKind,
    path: String,
    baud: u32,
    /// No bytes (or no complete scan) for this long reopens the port.
    silence: Duration,
    last_bytes: Instant,
    last_scan: Instant,
    scans: u64,
    /// The silence going on, if any.
    quiet: Option<Silence>,
    /// Reopens of the port over the run.
    reopens: u64,
}

/// How long the RPLIDAR's start sequence waits for each answer.
const RPLIDAR_ANSWER_WAIT: Duration = Duration::from_millis(500);

/// Opens the serial port of a `kind` LiDAR at `baud`; an RPLIDAR is started as
/// Slamtec's SDK starts it (`rplidar_start`: stop, health and a reset after a
/// protection stop, the A2's motor PWM, scan), and what that found is returned
/// for the log.
fn open_serial(
    kind: SerialKind,
    path: &str,
    baud: u32,
) -> Result<(SerialLidar, Option<StartReport>), SourceError> {
    let flag = kind.flag();
    let mut port = SerialLidar::open(path, baud, Duration::from_millis(50))
        .map_err(|e| SourceError(format!("{flag}: {e}")))?;
    let mut report = None;
    if kind == SerialKind::Rplidar {
        // the A1/A2 USB adapter runs the motor while DTR is released, and Linux
        // asserted it on open; a C1 or a port without modem lines ignores or refuses
        // this, which does not matter to the scan
        let _ = port.set_dtr(false);
        report = Some(
            lidar::rplidar_start::start_scan(&mut port, RPLIDAR_ANSWER_WAIT)
                .map_err(|e| SourceError(format!("{flag}: starting the scan: {e}")))?,
        );
    }
    Ok((port, report))
}

/// How the LiDAR driver names a silent port.
pub(super) const LIDAR_SILENCE: SilenceWords = SilenceWords {
    program: "vlsync-lidar",
    unit: "port",
    reopening: "reopening",
    reopens: "reopens",
    reopened: "reopened",
    still: "still silent",
    again: "scans again",
    kind: "silence",
};

impl Serial {
    /// After `silence` without bytes or without a complete scan: says so (once, then
    /// every [`SILENCE_REPEAT`]) and reopens the port, instead of ending the driver
    /// (whose unit would restart it every few seconds for as long as a parked robot's
    /// LiDAR is off). A port that cannot be reopened (the adapter unplugged) is an
    /// error.
    fn on_silence(&mut self, what: &str, now: Instant, why: &str) -> Result<(), SourceError> {
        Silence::say(
            &mut self.quiet,
            now,
            self.silence,
            &LIDAR_SILENCE,
            what,
            &why,
        );
        // closed first: a port is opened exclusively
        self.port = None;
        let (port, report) = open_serial(self.kind, &self.path, self.baud).map_err(|e| {
            SourceError(format!(
                "{what}: reopening the port after {:.1} s of silence: {e}",
                self.silence.as_secs_f64()
            ))
        })?;
        self.port = Some(port);
        if let Some(r) = report.filter(StartReport::is_remarkable) {
            vlsync_common::console::print_err(&format!("vlsync-lidar: {what}: reopened: {r}\n"));
        }
        self.reopens += 1;
        Silence::reopened(&mut self.quiet);
        (self.last_bytes, self.last_scan) = (now, now);
        Ok(())
    }

    /// A complete scan came: ends a silence, saying how long it lasted.
    fn on_scan(&mut self, what: &str) {
        Silence::say_end(&mut self.quiet, &LIDAR_SILENCE, what);
    }
}

impl Drop for Serial {
    fn drop(&mut self) {
        if matches!(self.parser, Parser::Rplidar(_)) {
            // stop the scan stream; nothing to do if the device is gone. The A1/A2
            // motor keeps spinning: asserting DTR here would not outlast the close,
            // whose hang-up (HUPCL, which serialport leaves set) releases it again
            if let Some(port) = &mut self.port {
                let _ = port.write_request(&lidar::rplidar::stop_request());
            }
        }
    }
}

/// Nodes per second an RPLIDAR sends in standard scan mode at `baud`, assumed when
/// it does not answer `GET_SAMPLERATE` (firmware before 1.17): the C1
/// (460800 baud) 5000, the A1/A2 (115200) 2000. It dates a revolution's start from
/// the bytes that came after its start node in the same read, so a wrong rate
/// biases every stamp by up to a read's worth of bytes (tens of ms at 460800).
pub fn rplidar_node_rate_hz(baud: u32) -> u32 {
    if baud >= 460_800 {
        5000
    } else {
        2000
    }
}

/// The rotation period an RPLIDAR's first revolution is checked against at `baud`
/// (the parser drops a first revolution outside 2/3 to 1.5 times it, and keeps the
/// second only if the two agree): 100 ms (10 Hz, the C1's, S1's and A2M12's typical
/// rate) at 256000 baud and over, the A1's 5.5 Hz at 115200. An A2M8 at 115200
/// spins at about 10 Hz and so loses its first revolution, as every model did
/// before: the rate is not known until the device has turned twice.
pub fn rplidar_nominal_period_ns(baud: u32) -> Nanos {
    if baud >= 256_000 {
        100_000_000
    } else {
        RplidarConfig::default().nominal_period_ns
    }
}

/// The parser settings `vlsync-lidar --rplidar` runs with at `baud`: the node rate
/// from the device's own answer (`GET_SAMPLERATE`) where it gave one, else
/// [`rplidar_node_rate_hz`]; the first revolution's period from
/// [`rplidar_nominal_period_ns`].
pub fn rplidar_config(baud: u32, report: Option<&StartReport>) -> RplidarConfig {
    RplidarConfig {
        baud,
        sample_rate_hz: report
            .and_then(StartReport::standard_rate_hz)
            .unwrap_or_else(|| rplidar_node_rate_hz(baud)),
        nominal_period_ns: rplidar_nominal_period_ns(baud),
        ..RplidarConfig::default()
    }
}

enum ScanInput {
    Csv(lidar::csv::CsvScanReader<std::io::BufReader<std::fs::File>>),
    Mcap(vlsync_mcap::McapScanSource),
    Render {
        r: Box<vlsync_render::Renderer>,
        next: usize,
        shift: Nanos,
        /// `(first-ray stamp, stamp - true time)` of the last scans: the jitter to undo.
        recent: VecDeque<(Nanos, Nanos)>,
    },
    Serial(Box<Serial>),
}

/// LiDAR scans through `SignatureProcessor::push_scan`.
pub struct LidarSource {
    input: ScanInput,
    proc: lidar::WallFront,
    queue: VecDeque<(Sample, Option<SampleTruth>)>,
    what: String,
    scans: u64,
    last_truth: Option<SampleTruth>,
    /// Scans of a recording that could not be used (a malformed `LaserScan`):
    /// skipped as missed revolutions, until too many come in a row.
    skipped: cam::UnusableFrames,
    /// Ends the source once true (checked before each read of input).
    stop: StopFn,
    /// How long [`Source::next_event`] goes without a sample before it returns
    /// [`Next::Idle`].
    idle_every: Duration,
}

impl std::fmt::Debug for LidarSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LidarSource")
            .field("what", &self.what)
            .field("scans", &self.scans)
            .finish_non_exhaustive()
    }
}

impl LidarSource {
    fn new(input: ScanInput, what: String) -> Result<Self, SourceError> {
        let proc = lidar::SignatureProcessor::new(lidar::SignatureConfig::default())
            .map_err(|e| SourceError(format!("{what}: {e}")))?;
        Ok(Self {
            input,
            proc: lidar::WallFront::One(Box::new(proc)),
            queue: VecDeque::new(),
            what,
            scans: 0,
            last_truth: None,
            skipped: cam::UnusableFrames::named("scans"),
            stop: never,
            idle_every: crate::IDLE_EVERY,
        })
    }

    /// Makes the source end (`Ok(None)`) once `stop` returns true, checked before
    /// each read of its input: a recording or a rendered run read ahead of real time
    /// stops at a SIGTERM as a serial LiDAR does.
    pub fn with_stop(mut self, stop: StopFn) -> Self {
        self.stop = stop;
        self
    }

    /// Fits the wall in the bearing window(s) `f` gives (the `[lidar]` section of
    /// the configuration) instead of the default window.
    pub fn with_front(mut self, f: &vlsync_config::LidarConfig) -> Result<Self, SourceError> {
        let cfg = lidar::SignatureConfig {
            window_centre_rad: lidar::scan::wrap_pi(f.window_centre_deg.to_radians()),
            window_half_width_rad: f.window_half_width_deg.to_radians(),
            ..lidar::SignatureConfig::default()
        };
        let err = |e: lidar::ConfigError| SourceError(format!("{}: {e}", self.what));
        self.proc = lidar::WallFront::new(cfg, f.opposite_window).map_err(err)?;
        self.what = format!(
            "{}; wall window {:.1}° ± {:.1}°{}",
            self.what,
            f.window_centre_deg,
            f.window_half_width_deg,
            if f.opposite_window {
                " and the opposite one"
            } else {
                ""
            }
        );
        Ok(self)
    }

    /// A scan CSV (`vlsync_signature_lidar::csv`'s format).
    pub fn scans_csv(path: &Path) -> Result<Self, SourceError> {
        let r = lidar::csv::CsvScanReader::open(path)
            .map_err(|e| SourceError(format!("--scans: {e}")))?;
        Self::new(ScanInput::Csv(r), format!("scans {}", path.display()))
    }

    /// The `LaserScan` topic of a recording (`topic`, or the only one).
    pub fn mcap(path: &Path, topic: Option<&str>) -> Result<Self, SourceError> {
        let opts = match topic {
            Some(t) => vlsync_mcap::ScanSourceOptions::topic(t),
            None => vlsync_mcap::ScanSourceOptions::default(),
        };
        let src = vlsync_mcap::McapScanSource::open(path, opts)
            .map_err(|e| SourceError(format!("--mcap: {e}")))?;
        let what = format!(
            "mcap {} topic {}",
            path.display(),
            vlsync_common::text::clip(&src.topic().topic)
        );
        Self::new(ScanInput::Mcap(src), what)
    }

    /// The scans of a rendered run on the rendered LiDAR clock (see [`renderer`]).
    pub fn render(r: vlsync_render::Renderer) -> Result<Self, SourceError> {
        Self::render_with(r, RenderStamp::Sensor)
    }

    /// The scans of a rendered run, stamped as `stamp` says (`Software` is a
    /// camera mode and is refused).
    pub fn render_with(
        r: vlsync_render::Renderer,
        stamp: RenderStamp,
    ) -> Result<Self, SourceError> {
        let what = format!(
            "render seed {} ({} s, {} scans{})",
            r.config().seed,
            r.config().duration_s,
            r.scan_schedule().len(),
            match stamp {
                RenderStamp::Sensor => "",
                RenderStamp::Mono { .. } => ", sensor stamps on CLOCK_MONOTONIC",
                RenderStamp::Software { .. } => {
                    return Err(SourceError(format!(
                        "render seed {}: software stamping is a camera mode; the LiDAR \
                         stamps like its sensor (--stamp sensor or mono)",
                        r.config().seed
                    )));
                }
            }
        );
        Self::new(
            ScanInput::Render {
                r: Box::new(r),
                next: 0,
                shift: stamp.shift_ns(),
                recent: VecDeque::new(),
            },
            what,
        )
    }

    /// A serial LiDAR at `path`; `baud` defaults to the device's usual rate.
    /// Rays are stamped on arrival with `CLOCK_MONOTONIC`. No bytes (or no complete
    /// scan) for `silence` is said (once, then every [`SILENCE_REPEAT`] while it
    /// lasts) and the port is reopened, and so on until scans come again; a port
    /// that cannot be reopened (the adapter unplugged) is an error naming the
    /// device. The source ends (`Ok(None)`) once `stop` returns true.
    pub fn serial(
        kind: SerialKind,
        path: &str,
        baud: Option<u32>,
        silence: Duration,
        stop: StopFn,
    ) -> Result<Self, SourceError> {
        let baud = baud.unwrap_or(kind.default_baud());
        let (port, report) = open_serial(kind, path, baud)?;
        let what = format!("{} {path} at {baud} baud", &kind.flag()[2..]);
        if let Some(r) = &report {
            vlsync_common::console::print_err(&format!("vlsync-lidar: {what}: {r}\n"));
        }
        // one parser for the whole run, across reopens of the port: both find their
        // packets (the RPLIDAR's response descriptor too) anywhere in the stream
        let parser = match kind {
            SerialKind::Ld06 => Parser::Ld06(Ld06Parser::new(Ld06Config {
                baud,
                ..Ld06Config::default()
            })),
            SerialKind::Rplidar => {
                Parser::Rplidar(RplidarParser::new(rplidar_config(baud, report.as_ref())))
            }
        };
        let now = Instant::now();
        let me = Self::new(
            ScanInput::Serial(Box::new(Serial {
                port: Some(port),
                parser,
                stop,
                kind,
                path: path.to_string(),
                baud,
                silence,
                last_bytes: now,
                last_scan: now,
                scans: 0,
                quiet: None,
                reopens: 0,
            })),
            what,
        )?;
        Ok(me.with_stop(stop))
    }

    /// Scans read so far.
    pub fn scans(&self) -> u64 {
        self.scans
    }

    /// The front-end's counters.
    pub fn counters(&self) -> lidar::Counters {
        *self.proc.ahead().counters()
    }

    /// Reads more input into the queue; false at the end of the input.
    fn fill(&mut self) -> Result<bool, SourceError> {
        let Self {
            input,
            proc,
            queue,
            what,
            scans,
            skipped,
            ..
        } = self;
        // returns how many samples were queued
        let mut push = |scan: &lidar::Scan| {
            *scans += 1;
            let mut n = 0;
            proc.push_scan(scan, |s| {
                if s.value.is_finite() {
                    queue.push_back((s, None));
                    n += 1;
                }
            });
            n
        };
        match input {
            ScanInput::Csv(r) => match r.next() {
                None => Ok(false),
                Some(Err(e)) => Err(SourceError(format!("--scans: {e}"))),
                Some(Ok(scan)) => {
                    push(&scan);
                    Ok(true)
                }
            },
            ScanInput::Mcap(m) => match m.next_scan() {
                Ok(None) => Ok(false),
                // one malformed message is a missed revolution, not the end of the recording
                Err(e @ vlsync_mcap::Error::Message { .. }) => {
                    skipped
                        .skip(e.to_string())
                        .map_err(|m| SourceError(format!("--mcap: {m}")))?;
                    Ok(true)
                }
                Err(e) => Err(SourceError(format!("--mcap: {e}"))),
                Ok(Some(scan)) => {
                    skipped.used();
                    push(scan);
                    Ok(true)
                }
            },
            ScanInput::Render {
                r,
                next,
                shift,
                recent,
            } => match r.render_scan(*next) {
                None => Ok(false),
                Some(s) => {
                    *next += 1;
                    let start = s.scan.timing().start_ns;
                    recent.push_back((start, start - s.tau_start_ns));
                    if recent.len() > 8 {
                        recent.pop_front();
                    }
                    let n = push(&s.scan);
                    let period = s.scan.timing().period_ns;
                    let before = queue.len() - n;
                    for (sample, truth) in queue.iter_mut().skip(before) {
                        *truth = Some(SampleTruth {
                            event_ns: lidar_event_ns(recent, sample.t_ns, period) + *shift,
                            ..SampleTruth::default()
                        });
                        sample.t_ns += *shift;
                    }
                    Ok(true)
                }
            },
            ScanInput::Serial(s) => {
                if (s.stop)() {
                    return Ok(false);
                }
                let Serial {
                    port,
                    parser,
                    last_bytes,
                    last_scan,
                    scans: serial_scans,
                    ..
                } = &mut **s;
                let Some(port) = port.as_mut() else {
                    return Err(SourceError(format!(
                        "{what}: the port is closed (its reopening failed)"
                    )));
                };
                let (chunk, t) = port
                    .read_chunk(&vlsync_ipc::monotonic_ns)
                    .map_err(|e| SourceError(format!("{what}: {e}")))?;
                let now = Instant::now();
                if !chunk.is_empty() {
                    *last_bytes = now;
                }
                let before = *serial_scans;
                let mut on_scan = |scan: &lidar::Scan| {
                    *serial_scans += 1;
                    push(scan);
                };
                match parser {
                    Parser::Ld06(p) => p.push(chunk, t, &mut on_scan),
                    Parser::Rplidar(p) => p.push(chunk, t, &mut on_scan),
                }
                if *serial_scans != before {
                    *last_scan = now;
                    s.on_scan(what);
                }
                let silence = s.silence;
                if now.duration_since(s.last_bytes) > silence {
                    let why = format!(
                        "no data for {:.1} s (is the LiDAR powered and the baud rate right?)",
                        silence.as_secs_f64()
                    );
                    s.on_silence(what, now, &why)?;
                } else if now.duration_since(s.last_scan) > silence {
                    let why = format!(
                        "bytes but no complete scan for {:.1} s (wrong device type or baud rate?)",
                        silence.as_secs_f64()
                    );
                    s.on_silence(what, now, &why)?;
                }
                Ok(true)
            }
        }
    }
}

/// True time of a LiDAR sample stamped `t` (the midpoint of two passes over the
/// bearing window, one revolution apart): `t` minus the mean stamp jitter of the
/// scans holding `t - period/2` and `t + period/2`. Exact unless a pass's median
/// ray lies within the jitter of a scan boundary.
fn lidar_event_ns(recent: &VecDeque<(Nanos, Nanos)>, t: Nanos, period: Nanos) -> Nanos {
    let jitter_at = |x: Nanos| {
        recent
            .iter()
            .rev()
            .find(|(start, _)| *start <= x)
            .or(recent.front())
            .map_or(0, |(_, j)| *j)
    };
    t - mid(jitter_at(t - period / 2), jitter_at(t + period / 2))
}

impl Source for LidarSource {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        crate::sample_of_events(|| self.next_event())
    }

    fn next_event(&mut self) -> Result<Next, SourceError> {
        let called = Instant::now();
        loop {
            if let Some((s, truth)) = self.queue.pop_front() {
                self.last_truth = truth;
                return Ok(Next::Sample(s));
            }
            if (self.stop)() || !self.fill()? {
                return Ok(Next::End);
            }
            // scans without a sample, a silent port: give the driver its periodic
            // work after about a second
            if self.queue.is_empty() && called.elapsed() >= self.idle_every {
                return Ok(Next::Idle);
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
        let c = self.proc.ahead().counters();
        let mut s = format!(
            "{} scans, {} passes, {} samples; dropped:",
            self.scans, c.passes, c.samples
        );
        for r in lidar::DropReason::ALL {
            s.push_str(&format!(" {} {},", r.name(), c.dropped(r)));
        }
        s.push_str(&format!(" invalid returns {}", c.invalid_returns));
        s.push_str(&wall_text("wall", self.proc.ahead().last_measurement()));
        if let Some((n, last)) = self.skipped.counts() {
            s.push_str(&format!("; {n} unusable scans skipped (last: {last})"));
        }
        if let Some(w) = self.proc.opposite() {
            let c = w.behind().counters();
            s.push_str(&format!(
                "; opposite window: {} passes, {} samples, {} dropped out of time order",
                c.passes,
                c.samples,
                w.out_of_order()
            ));
            s.push_str(&wall_text("opposite wall", w.behind().last_measurement()));
        }
        if let ScanInput::Mcap(m) = &self.input {
            let back = m.reader().out_of_order();
            if back > 0 {
                s.push_str(&format!(
                    "; {back} scans whose log time went back (read in the recording's order, \
                     not sorted)"
                ));
            }
            let same = m.simultaneous_scans();
            if same > 0 {
                s.push_str(&format!(
                    "; {same} scans with time_increment 0: their rays taken as simultaneous, \
                     at the stamp (a spinning scanner's driver should fill it in)"
                ));
            }
        }
        if let ScanInput::Serial(ser) = &self.input {
            match &ser.parser {
                Parser::Ld06(p) => {
                    let st = p.stats();
                    s.push_str(&format!(
                        "; LD06: {} bytes, {} packets, {} CRC errors, {} skipped bytes, {} invalid packets",
                        st.bytes, st.packets, st.crc_errors, st.skipped_bytes, st.invalid_packets
                    ));
                }
                Parser::Rplidar(p) => {
                    let st = p.stats();
                    s.push_str(&format!(
                        "; RPLIDAR: {} bytes, {} nodes, {} skipped bytes, {} false starts, {} \
                         starts made up for lost flags, {} stray angles, {} revolutions dropped \
                         for their period, {} for their sweep (not one turn)",
                        st.bytes,
                        st.nodes,
                        st.skipped_bytes,
                        st.false_starts,
                        st.implicit_starts,
                        st.stray_nodes,
                        st.implausible_periods,
                        st.wrong_turns
                    ));
                }
            }
            if ser.reopens > 0 {
                s.push_str(&format!(
                    "; the port reopened {} times after silences of {:.1} s",
                    ser.reopens,
                    ser.silence.as_secs_f64()
                ));
            }
            if let Some(lasted) = Silence::lasted(&ser.quiet) {
                s.push_str(&format!("; silent for {:.0} s now", lasted.as_secs_f64()));
            }
        }
        Some(s)
    }
}

/// What a window's front-end measured last, for the progress line: the fitted wall's
/// distance, the bearing of its normal and the returns on it (what an installer aiming
/// the window wants to see), or the median range when that is the distance used.
fn wall_text(which: &str, m: Option<lidar::Measurement>) -> String {
    match m {
        None => format!("; {which}: none measured yet (since the start or the last gap)"),
        Some(m) if m.normal_rad.is_finite() => format!(
            "; {which}: {:.3} m, normal at {:+.1}°, {} returns",
            m.distance_m,
            m.normal_rad.to_degrees(),
            m.rays_used
        ),
        Some(m) => format!(
            "; {which}: median range {:.3} m of {} returns",
            m.distance_m, m.rays_used
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rendered(seconds: f64) -> LidarSource {
        LidarSource::render(renderer(3, seconds).unwrap()).unwrap()
    }

    #[test]
    fn scans_without_a_sample_return_idle_and_the_samples_are_those_of_next_sample() {
        let mut all = rendered(3.0);
        let want: Vec<Sample> = std::iter::from_fn(|| all.next_sample().unwrap()).collect();
        assert!(!want.is_empty());
        // every fill that gives no sample is an idle return when the period is 0
        let mut src = rendered(3.0);
        src.idle_every = Duration::ZERO;
        let (mut got, mut idle) = (vec![], 0);
        loop {
            match src.next_event().unwrap() {
                Next::Sample(s) => got.push(s),
                Next::Idle => idle += 1,
                Next::End => break,
            }
        }
        assert_eq!(got, want);
        // the first scans give none (a sample spans two passes over the window)
        assert!(idle > 0);
    }

    /// `(distance m, normal °, returns)` of the report's `{which}: ...` part.
    fn wall(report: &str, which: &str) -> (f64, f64, usize) {
        let key = format!("; {which}: ");
        let part = report
            .split(key.as_str())
            .nth(1)
            .and_then(|p| p.split(" returns").next())
            .unwrap_or_else(|| panic!("no `{key}` in {report}"));
        // "7.145 m, normal at +0.1°, 49"
        let f: Vec<&str> = part.split(", ").collect();
        let num = |x: &str| {
            x.parse::<f64>()
                .unwrap_or_else(|e| panic!("`{x}` in {part}: {e}"))
        };
        (
            num(f[0].trim_end_matches(" m")),
            num(f[1].trim_start_matches("normal at ").trim_end_matches('°')),
            num(f[2]) as usize,
        )
    }

    #[test]
    fn the_report_says_where_the_wall_is() {
        let front = vlsync_config::LidarConfig {
            opposite_window: true,
            ..vlsync_config::LidarConfig::default()
        };
        let mut src = rendered(3.0).with_front(&front).unwrap();
        let report = src.report().unwrap();
        assert!(
            report.contains("; wall: none measured yet")
                && report.contains("; opposite wall: none measured yet"),
            "{report}"
        );
        while src.next_sample().unwrap().is_some() {}
        let report = src.report().unwrap();
        // the rendered room is 8 m long and the robot drives along it: the walls
        // ahead and behind are 8 m apart, each seen square on by some 50 returns
        let (ahead, normal, rays) = wall(&report, "wall");
        let (behind, back, rays_back) = wall(&report, "opposite wall");
        assert!((ahead + behind - 8.0).abs() < 0.08, "{report}");
        assert!(
            normal.abs() < 3.0 && (back.abs() - 180.0).abs() < 3.0,
            "{report}"
        );
        assert!(rays >= 30 && rays_back >= 30, "{report}");
    }

    fn yes() -> bool {
        true
    }

    #[test]
    fn a_stop_ends_a_recorded_or_rendered_source() {
        let mut src = rendered(3.0).with_stop(yes);
        assert_eq!(src.next_event().unwrap(), Next::End);
        assert_eq!(src.scans(), 0);
        // read ahead to anchor the pacing: nothing, at once
        let p = Prefetched::new(Box::new(rendered(3.0).with_stop(yes))).unwrap();
        assert_eq!(p.first_t_ns(), None);
    }
}
