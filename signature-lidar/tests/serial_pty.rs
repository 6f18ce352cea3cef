//! Reads a synthesised LD06 byte stream through a pseudo-terminal with the
//! serial API and checks the decoded scans match a direct decode.
#![cfg(unix)]

use serialport::{SerialPort, TTYPort};
use std::io::Write;
use std::time::{Duration, Instant};
use vlsync_signature_lidar::ld06::{Ld06Clock, Ld06Config, Ld06Encoder, Ld06Parser, BAUD};
use vlsync_signature_lidar::serial::{ScanParser, SerialLidar};
use vlsync_signature_lidar::Scan;

fn stream() -> Vec<u8> {
    let mut enc = Ld06Encoder::new(3600, 0);
    let mut v = Vec::new();
    // 5.5 revolutions at 37.5 packets per revolution
    for _ in 0..206 {
        v.extend_from_slice(&enc.next_packet(|a| (1500.0 + 2.0 * a) as u16));
    }
    v
}

fn device_clock_parser() -> Ld06Parser {
    Ld06Parser::new(Ld06Config {
        clock: Ld06Clock::Device,
        ..Default::default()
    })
}

#[test]
fn ld06_through_pty() {
    let bytes = stream();
    let mut expected: Vec<Scan> = Vec::new();
    device_clock_parser().push(&bytes, 0, |s| expected.push(s.clone()));
    assert_eq!(expected.len(), 5);

    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    let path = slave.name().expect("slave has a path");
    let mut port = SerialLidar::open(&path, BAUD, Duration::from_millis(20)).expect("open slave");
    drop(slave);

    // the reader says when it is done (or, dropping the sender, that it failed):
    // closing the master before would fail its reads
    let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
    let writer = std::thread::spawn(move || {
        for chunk in bytes.chunks(333) {
            master.write_all(chunk).expect("write to pty master");
            master.flush().ok();
            // the bytes arrive in pieces, as from a serial line
            std::thread::sleep(Duration::from_millis(2));
        }
        // keep the master open until the reader is done
        let _ = done_rx.recv_timeout(Duration::from_secs(10));
        drop(master);
    });

    let mut parser = device_clock_parser();
    let mut got: Vec<Scan> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(10);
    while got.len() < expected.len() && Instant::now() < deadline {
        let (chunk, t) = port.read_chunk(&|| 0).expect("read");
        let chunk = chunk.to_vec();
        parser.push_bytes(&chunk, t, &mut |s| got.push(s.clone()));
    }
    let _ = done_tx.send(());
    writer.join().expect("writer thread");
    assert_eq!(got.len(), expected.len(), "stats {:?}", parser.stats());
    assert_eq!(got, expected);
    assert_eq!(parser.stats().crc_errors, 0);
}

#[test]
fn pump_reads_for_a_duration() {
    let bytes = stream();
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    let path = slave.name().expect("slave has a path");
    let mut port = SerialLidar::open(&path, BAUD, Duration::from_millis(20)).expect("open slave");
    drop(slave);
    master.write_all(&bytes[..47 * 80]).expect("write");
    let mut parser = device_clock_parser();
    let mut scans = 0;
    let n = port
        .pump(&mut parser, Duration::from_millis(300), &|| 0, &mut |_| {
            scans += 1
        })
        .expect("pump");
    assert_eq!(n, 47 * 80);
    assert_eq!(scans, 2);
    assert_eq!(parser.stats().packets, 80);
}
