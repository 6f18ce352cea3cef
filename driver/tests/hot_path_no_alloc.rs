//! The LiDAR driver's per-scan path allocates nothing after start-up, over
//! thousands of scans: raw RPLIDAR bytes through a pseudo-terminal into the source
//! `vlsync-lidar --rplidar` selects (its start-up exchange with the device, then
//! the serial port's reads, the parser, the wall front-end, the source's queue)
//! and `run`'s publish loop as the binary runs it (live pacing, the progress check,
//! `SignaturePublisher::publish` to a subscriber that, like a slow daemon, lets its
//! buffer overflow).
//!
//! The parsers and the front-end alone are counted on 3000 scans of LD06 and
//! RPLIDAR bytes in `vlsync-signature-lidar`'s `tests/no_alloc/serial.rs`; this adds the
//! driver's glue and its publishing. The bytes come far faster than a device sends
//! them (3000 revolutions take 9 minutes at 5.5 Hz), which an RPLIDAR's stamping
//! follows (a revolution's rays are timed from the measured period between its
//! starts; an LD06's are 0.22 ms apart on the host clock whatever the byte rate,
//! so a fast feed would only give rays out of order): 120 nodes a revolution, its
//! start node the last of a write, the wall moving 1 mm a revolution or less.
//!
//! Two allocations remain, neither the driver's own, and the test pins them where
//! they are: iceoryx2 0.10 allocates in every `Publisher::loan_uninit`, one per
//! published sample (`SignaturePublisher::send`, as for the daemon's estimates in
//! `tests/tests/ipc_rt_alloc.rs`); serialport 4.10 builds a boxed `io::Error`
//! ("Operation timed out", 3 allocations) for every read that times out, i.e. for
//! every 50 ms the device sends nothing (`SerialLidar::read_chunk` takes it for an
//! empty read), none while it streams. Calls of the source shorter than the read
//! timeout cannot contain one, and must allocate nothing.
//!
//! Uses iceoryx2: run under the suite's lock (`flock /tmp/vlsync-ipc.lock`).
//! This file is its own crate: it installs `vlsync-alloc-count`'s allocator.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use vlsync_common::wire::SignatureSample;
use vlsync_common::{Sample, Stream};
use vlsync_driver::cli::{select_source, DriverArgs};
use vlsync_driver::{run, Pacing, Progress, SampleTruth, Source, SourceError};
use vlsync_ipc::{create_node, open_or_create_pubsub, subscriber, Qos, ServiceNames};

#[global_allocator]
static GLOBAL: vlsync_alloc_count::Counting = vlsync_alloc_count::Counting;

use vlsync_alloc_count::this_thread as allocs;

/// Revolutions fed.
const SCANS: usize = 3000;
/// Samples of start-up, during which buffers may still grow.
const WARM_UP: u64 = 100;

/// Set once every byte is written: the source's stop request, its end.
static FED: AtomicBool = AtomicBool::new(false);

/// The driver's serial read timeout (`SerialLidar::open` in `LidarSource::serial`).
const READ_TIMEOUT: Duration = Duration::from_millis(50);

/// The source under test, counting this thread's allocations from its `WARM_UP`th
/// sample to its end: in all (everything `run` does meanwhile runs in there: its
/// loop, the publishing) and inside the source's own `next_sample` (the port's
/// reads, the parser, the front-end, the queue), there apart for calls too short to
/// have waited out a read timeout (none can end sooner than the timeout; a loaded
/// machine only makes calls longer) and the others.
struct Counted {
    inner: Box<dyn Source>,
    samples: u64,
    at_warm_up: Option<u64>,
    at_end: Option<u64>,
    /// Allocations in calls shorter than [`READ_TIMEOUT`]: no read timed out.
    in_source: u64,
    /// Allocations in calls that returned a sample after what may have been read
    /// timeouts, and how many those calls could hold at most (their lengths in
    /// [`READ_TIMEOUT`]s).
    at_timeouts: (u64, u64),
    /// Allocations in the long calls that ended the stream.
    at_end_call: u64,
}

impl Source for Counted {
    fn next_sample(&mut self) -> Result<Option<Sample>, SourceError> {
        let (t0, before) = (Instant::now(), allocs());
        let s = self.inner.next_sample()?;
        let (took, n) = (t0.elapsed(), allocs() - before);
        if self.at_warm_up.is_some() {
            if took < READ_TIMEOUT {
                self.in_source += n;
            } else if s.is_some() {
                self.at_timeouts.0 += n;
                self.at_timeouts.1 += (took.as_nanos() / READ_TIMEOUT.as_nanos()) as u64;
            } else {
                // the end of the stream (the device gone quiet for good): its
                // report and the port's closing, not the per-scan path
                self.at_end_call += n;
            }
        }
        match s {
            Some(_) => {
                self.samples += 1;
                if self.samples == WARM_UP {
                    self.at_warm_up = Some(allocs());
                }
            }
            None => self.at_end = Some(allocs()),
        }
        Ok(s)
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn truth(&self) -> Option<SampleTruth> {
        self.inner.truth()
    }

    fn report(&self) -> Option<String> {
        self.inner.report()
    }
}

/// Plays an RPLIDAR A1 on the pty `master`: answers the driver's start-up (health
/// good) until it asks for a scan, then sends `pieces` (the response descriptor and
/// the nodes), one write each, a few tens of microseconds apart; sets [`FED`] when
/// done and hands the port back.
fn rplidar_device(
    mut master: serialport::TTYPort,
    pieces: Vec<Vec<u8>>,
) -> std::thread::JoinHandle<serialport::TTYPort> {
    use serialport::SerialPort;
    use std::io::Read;
    use vlsync_signature_lidar::rplidar_start::{answer, parse_request, ANS_HEALTH};
    master.set_timeout(Duration::from_millis(50)).unwrap();
    std::thread::spawn(move || {
        let mut inbox = Vec::new();
        let deadline = std::time::Instant::now() + Duration::from_secs(20);
        'start: loop {
            let mut buf = [0u8; 64];
            if let Ok(n) = master.read(&mut buf) {
                inbox.extend_from_slice(&buf[..n]);
            }
            while let Some((cmd, _, used)) = parse_request(&inbox) {
                inbox.drain(..used);
                match cmd {
                    0x52 => write_patiently(&mut master, &answer(ANS_HEALTH, &[0, 0, 0])),
                    0x20 => break 'start,
                    _ => {}
                }
            }
            if inbox.first().is_some_and(|&b| b != 0xA5) {
                inbox.remove(0);
            }
            assert!(std::time::Instant::now() < deadline, "no scan request");
        }
        for p in &pieces {
            write_patiently(&mut master, p);
            std::thread::sleep(Duration::from_micros(20));
        }
        // time for a late reader to catch up before the stop
        std::thread::sleep(Duration::from_secs(1));
        FED.store(true, Ordering::Relaxed);
        // the port stays open until the driver has stopped (a closed one is an error)
        master
    })
}

/// Writes all of `bytes` to the pty `master`, waiting while its buffer is full: the
/// port's 50 ms timeout is for the start-up's reads, and a driver descheduled for
/// longer on a loaded machine (the test suite runs beside it) lets the pty's buffer
/// fill, which is no failure of the path under test (`write_all` would give up at the
/// first timed-out write, not knowing how much of it went out).
fn write_patiently(master: &mut serialport::TTYPort, bytes: &[u8]) {
    use std::io::{ErrorKind, Write};
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let mut sent = 0;
    while sent < bytes.len() {
        match master.write(&bytes[sent..]) {
            Ok(n) => sent += n,
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                ) && std::time::Instant::now() < deadline => {}
            Err(e) => panic!(
                "write to the pty ({sent} of {} bytes sent): {e}",
                bytes.len()
            ),
        }
    }
}

/// The response descriptor and `SCANS` revolutions of 120 nodes of a wall ahead
/// moving at most 1 mm a revolution, 3.6 m at the sides, cut into writes of at most
/// 35 bytes: each revolution's start node is the last bytes of its write, so the
/// driver reads it with nothing after it and dates it on arrival.
fn rplidar_writes() -> Vec<Vec<u8>> {
    use vlsync_signature_lidar::encode::{rplidar_revolution, SCAN_DESCRIPTOR};
    let mut pieces = vec![];
    let mut piece = SCAN_DESCRIPTOR.to_vec();
    for k in 0..SCANS {
        let wall = 2.0 + 0.2 * (0.005 * k as f64).sin();
        let rev = rplidar_revolution(120, 0.0, 1.0 / 5.5, |_, b| {
            if b.abs() < 0.4 {
                wall / b.cos()
            } else {
                3.6
            }
        });
        // the start node closes the write before it
        piece.extend_from_slice(&rev[..5]);
        pieces.push(std::mem::take(&mut piece));
        let mut rest: Vec<Vec<u8>> = rev[5..].chunks(30).map(<[u8]>::to_vec).collect();
        // the revolution's last chunk waits for the next start node
        piece = rest.pop().unwrap();
        pieces.extend(rest);
    }
    pieces.push(piece);
    pieces
}

#[test]
fn the_lidar_drivers_scan_to_publish_path_allocates_nothing_after_start_up() {
    use serialport::SerialPort;
    let (master, slave) = serialport::TTYPort::pair().expect("pty pair");
    let path = slave.name().expect("slave path");
    let device = rplidar_device(master, rplidar_writes());
    let args = {
        use clap::Parser;
        DriverArgs::try_parse_from(["vlsync-lidar", "--rplidar", &path, "--baud", "460800"])
            .expect("args")
    };
    let selected = select_source(&args, Stream::Lidar, || FED.load(Ordering::Relaxed))
        .expect("the --rplidar source");
    assert_eq!(
        selected.anchor_ns, None,
        "a live device: published as it comes"
    );
    drop(slave);

    let names = ServiceNames::new(&format!("vlsync-test/hot-path-{}", std::process::id())).unwrap();
    let node = create_node("hot-path-test", false).unwrap();
    let svc = open_or_create_pubsub::<SignatureSample>(
        &node,
        &names.signature(Stream::Lidar),
        Qos::signature(256),
    )
    .unwrap();
    // the daemon's seat, never read: its buffer overflows as a slow daemon's would
    let (sub, _) = subscriber(&svc, 256, "lidar").unwrap();
    let mut publisher = vlsync_ipc::SignaturePublisher::open(&node, &names, Stream::Lidar).unwrap();
    let mut source = Counted {
        inner: selected.source,
        samples: 0,
        at_warm_up: None,
        at_end: None,
        in_source: 0,
        at_timeouts: (0, 0),
        at_end_call: 0,
    };
    let (mut reports, mut notices) = (0, 0);
    let sum = run(
        &mut source,
        &mut publisher,
        Pacing::Fast,
        &|| false,
        None,
        // as the binary: a progress line every 10 minutes
        Some(Progress {
            every: Duration::from_secs(600),
            report: &mut |_, _, _| reports += 1,
            notice: &mut |_| notices += 1,
        }),
    )
    .expect("the run");
    drop(device.join().unwrap());
    let report = source.report().unwrap_or_default();
    eprintln!("{sum:?}; {report}");
    let warm = source
        .at_warm_up
        .unwrap_or_else(|| panic!("fewer than {WARM_UP} samples: {sum:?}; {report}"));
    let end = source.at_end.expect("the source ended");
    // a zero below means none only if the allocator counts
    vlsync_alloc_count::assert_counting();
    // samples published from the warm-up's last one on
    let published = source.samples - WARM_UP + 1;
    let publishing = end - warm - source.in_source - source.at_timeouts.0 - source.at_end_call;
    eprintln!(
        "after the warm-up, {published} samples published: {} allocations in all, {} in the source's calls that did not wait for a read timeout, {} in calls that may have held up to {} read timeouts, {} in the call that ended the stream; {publishing} in run's loop and publishing",
        end - warm,
        source.in_source,
        source.at_timeouts.0,
        source.at_timeouts.1,
        source.at_end_call
    );
    // the port's reads, the parser, the front-end and the queue: nothing per scan
    assert_eq!(
        source.in_source,
        0,
        "allocations in the source over {} samples after the warm-up: {sum:?}; {report}",
        source.samples - WARM_UP
    );
    // a read that times out: serialport's poll allocates three times, nothing else
    assert!(
        source.at_timeouts.0 <= 3 * source.at_timeouts.1,
        "{} allocations in source calls long enough for at most {} read timeouts: {sum:?}; {report}",
        source.at_timeouts.0,
        source.at_timeouts.1
    );
    // run's loop and SignaturePublisher::publish: nothing but iceoryx2 0.10's own
    // allocation in every Publisher::loan_uninit (as in the daemon's
    // ipc_rt_alloc.rs), one per sample published
    assert!(
        publishing <= published,
        "{publishing} allocations in run's loop and publishing for {published} samples after the warm-up: {sum:?}; {report}"
    );
    // it ran: thousands of revolutions read, every sample published (a loaded
    // machine's late reads make uneven periods, whose revolutions the parser drops:
    // half is a generous floor, 2540 to 2990 came here also with the test's core
    // loaded by three other processes)
    let scans: u64 = report
        .split(" scans,")
        .next()
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("no scan count in {report:?}"));
    assert!(scans as usize >= SCANS / 2, "{scans} scans: {report}");
    assert_eq!(sum.published, source.samples, "{sum:?}");
    assert!(
        sum.published >= 1000 && sum.failed == 0 && sum.unreached == 0,
        "{sum:?}; {report}"
    );
    assert_eq!((reports, notices), (0, 0));
    drop(sub);
}
