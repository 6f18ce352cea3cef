//! Starting an RPLIDAR standard scan the way Slamtec's SDK does: the requests
//! that carry a payload or get an answer, and the start sequence.
//!
//! The sequence ([`start_scan`]), each step as in Slamtec's `rplidar_sdk`
//! (`RPlidarDriverImplCommon::getHealth`, `checkMotorCtrlSupport`,
//! `startMotor`) and its interface protocol (no code copied):
//!
//! 1. `STOP` (`A5 25`), a short pause, and whatever was still streaming is
//!    discarded (a scan left running by an earlier process).
//! 2. `GET_HEALTH` (`A5 52`), answered by `A5 5A 03 00 00 00 06` and three bytes:
//!    status (0 good, 1 warning, 2 error) and a 16-bit error code. On an error
//!    (e.g. the laser's protection stop) the device takes no `SCAN` until
//!    `RESET` (`A5 40`): it is sent, and after a second the health is asked
//!    again.
//! 3. `GET_SAMPLERATE` (`A5 59`), answered by `A5 5A 04 00 00 00 15` and two
//!    16-bit durations in µs: one sample of the standard scan, one of the
//!    express scan (firmware 1.17 on; older devices do not answer). The
//!    standard one gives the node rate the parser dates revolution starts with
//!    ([`StartReport::standard_rate_hz`]); without an answer the caller assumes
//!    one from the baud rate.
//! 4. `GET_ACC_BOARD_FLAG` (`A5 FF 04 00 00 00 00 5E`), answered by
//!    `A5 5A 04 00 00 00 FF` and a 32-bit flag word. With bit 0 set (an A2/A3 on
//!    Slamtec's accessory board), the motor runs only on `SET_MOTOR_PWM`
//!    (`A5 F0 02 <pwm, little-endian> <checksum>`), sent at the SDK's default
//!    660 with half a second to spin up. An A1 or C1 does not answer; its motor
//!    runs from DTR (released by the caller) or by itself.
//! 5. `SCAN` (`A5 20`).
//!
//! A request with a payload is `A5 <cmd> <len> <payload> <checksum>`, the
//! checksum the XOR of every byte before it. An answer is found anywhere in
//! what the port gives ([`find_answer`]), so leftover scan nodes do not hide
//! it. A device that answers nothing is still asked to scan: the report says so
//! and the caller's silence handling takes over.
//!
//! ```
//! use vlsync_signature_lidar::rplidar_start::{request, CMD_SET_MOTOR_PWM};
//! assert_eq!(request(CMD_SET_MOTOR_PWM, &660u16.to_le_bytes()), [0xA5, 0xF0, 0x02, 0x94, 0x02, 0xC1]);
//! ```

use crate::rplidar::{SCAN_REQUEST, STOP_REQUEST};
use std::fmt;
use std::time::{Duration, Instant};

/// Reset the device (no answer; it restarts).
pub const CMD_RESET: u8 = 0x40;
/// Ask the device's health.
pub const CMD_GET_HEALTH: u8 = 0x52;
/// Ask the durations of one sample in the standard and the express scan.
pub const CMD_GET_SAMPLERATE: u8 = 0x59;
/// Ask whether the accessory board controls the motor (A2/A3).
pub const CMD_GET_ACC_BOARD_FLAG: u8 = 0xFF;
/// Set the motor's PWM duty through the accessory board (0-1023).
pub const CMD_SET_MOTOR_PWM: u8 = 0xF0;
/// Answer type of [`CMD_GET_HEALTH`].
pub const ANS_HEALTH: u8 = 0x06;
/// Answer type of [`CMD_GET_SAMPLERATE`].
pub const ANS_SAMPLE_RATE: u8 = 0x15;
/// Answer type of [`CMD_GET_ACC_BOARD_FLAG`].
pub const ANS_ACC_BOARD_FLAG: u8 = 0xFF;
/// The SDK's motor PWM (`DEFAULT_MOTOR_PWM`).
pub const DEFAULT_MOTOR_PWM: u16 = 660;
/// A request's payload flag (set in the command byte of one with a payload).
const HAS_PAYLOAD: u8 = 0x80;

/// Bytes of request `cmd`, with `payload` (at most 255 bytes; longer is cut).
pub fn request(cmd: u8, payload: &[u8]) -> Vec<u8> {
    if payload.is_empty() {
        return vec![0xA5, cmd];
    }
    let payload = &payload[..payload.len().min(255)];
    let cmd = cmd | HAS_PAYLOAD;
    let mut out = vec![0xA5, cmd, payload.len() as u8];
    out.extend_from_slice(payload);
    let checksum = out.iter().fold(0u8, |c, b| c ^ b);
    out.push(checksum);
    out
}

/// The first complete request at the start of `bytes` (as a device reads it):
/// `(command, payload, bytes used)`, or `None` when `bytes` holds no complete
/// request yet or does not start with `A5`, or its checksum is wrong.
pub fn parse_request(bytes: &[u8]) -> Option<(u8, &[u8], usize)> {
    let (&sync, rest) = bytes.split_first()?;
    let (&cmd, rest) = rest.split_first()?;
    if sync != 0xA5 {
        return None;
    }
    if cmd & HAS_PAYLOAD == 0 {
        return Some((cmd, &[], 2));
    }
    let (&len, rest) = rest.split_first()?;
    let len = len as usize;
    let payload = rest.get(..len)?;
    let &checksum = rest.get(len)?;
    let want = bytes[..3 + len].iter().fold(0u8, |c, b| c ^ b);
    (checksum == want).then_some((cmd, payload, 4 + len))
}

/// The payload of the first complete answer of type `kind` with at least `min_len`
/// payload bytes in `bytes` (its descriptor `A5 5A <size: 30 bits, little-endian,
/// with 2 mode bits> <type>` and `size` bytes), if there is one. A shorter match
/// (leftover scan bytes that happen to look like a descriptor) is passed over, so
/// that it cannot hide the device's real answer after it.
pub fn find_answer(bytes: &[u8], kind: u8, min_len: usize) -> Option<&[u8]> {
    let mut i = 0;
    while i + 7 <= bytes.len() {
        if bytes[i] == 0xA5 && bytes[i + 1] == 0x5A && bytes[i + 6] == kind {
            let size = u32::from_le_bytes([bytes[i + 2], bytes[i + 3], bytes[i + 4], bytes[i + 5]])
                & 0x3FFF_FFFF;
            let start = i + 7;
            if let Some(payload) = start
                .checked_add(size as usize)
                .and_then(|end| bytes.get(start..end))
                .filter(|p| p.len() >= min_len)
            {
                return Some(payload);
            }
        }
        i += 1;
    }
    None
}

/// The bytes of an answer of type `kind` carrying `payload`, as a device sends it.
pub fn answer(kind: u8, payload: &[u8]) -> Vec<u8> {
    let size = (payload.len() as u32).to_le_bytes();
    let mut out = vec![0xA5, 0x5A, size[0], size[1], size[2], size[3], kind];
    out.extend_from_slice(payload);
    out
}

/// What `GET_HEALTH` answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Health {
    /// Status 0.
    Good,
    /// Status 1, with the device's error code.
    Warning(u16),
    /// Status 2 (e.g. protection stop), with the device's error code.
    Error(u16),
    /// A status this parser does not know, with the error code.
    Unknown(u8, u16),
}

impl Health {
    /// Decodes the three bytes of the answer.
    pub fn decode(payload: &[u8]) -> Option<Self> {
        let [status, lo, hi, ..] = *payload else {
            return None;
        };
        let code = u16::from_le_bytes([lo, hi]);
        Some(match status {
            0 => Health::Good,
            1 => Health::Warning(code),
            2 => Health::Error(code),
            s => Health::Unknown(s, code),
        })
    }
}

impl fmt::Display for Health {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Health::Good => write!(f, "good"),
            Health::Warning(c) => write!(f, "warning (error code 0x{c:04x})"),
            Health::Error(c) => write!(f, "error (error code 0x{c:04x})"),
            Health::Unknown(s, c) => write!(f, "unknown status {s} (error code 0x{c:04x})"),
        }
    }
}

/// The port as [`start_scan`] uses it.
pub trait Link {
    /// Writes `bytes`.
    fn send(&mut self, bytes: &[u8]) -> Result<(), String>;
    /// Appends what one read gives to `into` (nothing after the read's timeout).
    fn receive(&mut self, into: &mut Vec<u8>) -> Result<(), String>;
    /// Waits `d`.
    fn pause(&mut self, d: Duration);
}

/// What [`start_scan`] found and did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StartReport {
    /// The health before any reset (`None`: no answer).
    pub health: Option<Health>,
    /// The health after the reset, if one was sent.
    pub after_reset: Option<Option<Health>>,
    /// What `GET_SAMPLERATE` answered: µs per sample of the standard and the
    /// express scan (`None`: no answer).
    pub sample_us: Option<(u16, u16)>,
    /// Whether the accessory board answered, and its flags.
    pub board_flags: Option<u32>,
    /// The PWM the motor was started with (accessory board only).
    pub motor_pwm: Option<u16>,
}

impl StartReport {
    /// True when the log should hear of this start even on a reopen: no health
    /// answer, a health other than good, or a reset.
    pub fn is_remarkable(&self) -> bool {
        self.health != Some(Health::Good) || self.after_reset.is_some()
    }

    /// Nodes per second of the standard scan, from the device's answer; `None`
    /// without an answer or when the duration is outside 25-5000 µs (200-40000
    /// nodes/s: no RPLIDAR's, so a misread).
    pub fn standard_rate_hz(&self) -> Option<u32> {
        let (us, _) = self.sample_us?;
        (25..=5000)
            .contains(&us)
            .then(|| (1_000_000.0 / f64::from(us)).round() as u32)
    }
}

impl fmt::Display for StartReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.health {
            Some(h) => write!(f, "health {h}")?,
            None => write!(
                f,
                "no answer to the health request (not an RPLIDAR, wrong baud rate, or busy)"
            )?,
        }
        if let Some(after) = self.after_reset {
            match after {
                Some(h) => write!(f, "; reset, then health {h}")?,
                None => write!(f, "; reset, then no answer")?,
            }
        }
        match (self.sample_us, self.standard_rate_hz()) {
            (Some(_), Some(hz)) => write!(f, "; standard scan at {hz} nodes/s")?,
            (Some((us, _)), None) => write!(
                f,
                "; implausible sample duration {us} µs (rate assumed from the baud rate)"
            )?,
            (None, _) => write!(
                f,
                "; no sample-rate answer (firmware before 1.17?: rate assumed from the baud rate)"
            )?,
        }
        match (self.board_flags, self.motor_pwm) {
            (_, Some(pwm)) => write!(f, "; motor started by the accessory board at PWM {pwm}"),
            (Some(flags), None) => write!(
                f,
                "; accessory board without motor control (flags 0x{flags:08x}), motor on DTR"
            ),
            (None, None) => write!(f, "; motor on DTR or its own (no accessory board answer)"),
        }
    }
}

/// Reads for up to `wait` until an answer of type `kind` with at least `len`
/// bytes has come; `None` when none did.
fn ask(
    link: &mut dyn Link,
    req: &[u8],
    kind: u8,
    len: usize,
    wait: Duration,
) -> Result<Option<Vec<u8>>, String> {
    link.send(req)?;
    let deadline = Instant::now() + wait;
    let mut got = Vec::new();
    loop {
        if let Some(p) = find_answer(&got, kind, len) {
            return Ok(Some(p.to_vec()));
        }
        if Instant::now() >= deadline || got.len() > 1 << 16 {
            return Ok(None);
        }
        link.receive(&mut got)?;
    }
}

/// Reads and drops what comes for `d`.
fn drain(link: &mut dyn Link, d: Duration) -> Result<(), String> {
    let deadline = Instant::now() + d;
    let mut junk = Vec::new();
    while Instant::now() < deadline {
        junk.clear();
        link.receive(&mut junk)?;
        if junk.is_empty() {
            break;
        }
    }
    Ok(())
}

/// Runs the start sequence (module docs), waiting up to `wait` for each answer,
/// and ends with the scan request. Errors are the link's.
pub fn start_scan(link: &mut dyn Link, wait: Duration) -> Result<StartReport, String> {
    link.send(&STOP_REQUEST)?;
    link.pause(Duration::from_millis(10));
    drain(link, Duration::from_millis(100))?;
    let health_now = |link: &mut dyn Link| -> Result<Option<Health>, String> {
        Ok(
            ask(link, &request(CMD_GET_HEALTH, &[]), ANS_HEALTH, 3, wait)?
                .and_then(|p| Health::decode(&p)),
        )
    };
    let health = health_now(link)?;
    let mut after_reset = None;
    if matches!(health, Some(Health::Error(_))) {
        link.send(&request(CMD_RESET, &[]))?;
        link.pause(Duration::from_secs(1));
        drain(link, Duration::from_millis(200))?;
        after_reset = Some(health_now(link)?);
    }
    let sample_us = ask(
        link,
        &request(CMD_GET_SAMPLERATE, &[]),
        ANS_SAMPLE_RATE,
        4,
        wait,
    )?
    .map(|p| {
        (
            u16::from_le_bytes([p[0], p[1]]),
            u16::from_le_bytes([p[2], p[3]]),
        )
    });
    let board_flags = ask(
        link,
        &request(CMD_GET_ACC_BOARD_FLAG, &[0; 4]),
        ANS_ACC_BOARD_FLAG,
        4,
        wait,
    )?
    .map(|p| u32::from_le_bytes([p[0], p[1], p[2], p[3]]));
    let mut motor_pwm = None;
    if board_flags.is_some_and(|f| f & 1 == 1) {
        link.send(&request(
            CMD_SET_MOTOR_PWM,
            &DEFAULT_MOTOR_PWM.to_le_bytes(),
        ))?;
        link.pause(Duration::from_millis(500));
        motor_pwm = Some(DEFAULT_MOTOR_PWM);
    }
    link.send(&SCAN_REQUEST)?;
    Ok(StartReport {
        health,
        after_reset,
        sample_us,
        board_flags,
        motor_pwm,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A scripted device: answers health with `health` (then `after_reset`
    /// once reset), the board flag with `board` (`None`: no answer), streams a
    /// few nodes of an old scan until stopped, and logs every request.
    struct Device {
        health: Option<[u8; 3]>,
        after_reset: Option<[u8; 3]>,
        board: Option<u32>,
        sample_us: Option<[u16; 2]>,
        streaming: bool,
        pending: Vec<u8>,
        requests: Vec<(u8, Vec<u8>)>,
        inbox: Vec<u8>,
        /// Bytes that read as a zero-size board answer come before the real one.
        lookalike: bool,
    }

    impl Device {
        fn new(health: Option<[u8; 3]>, board: Option<u32>) -> Self {
            Self {
                health,
                after_reset: health,
                board,
                sample_us: Some([500, 250]), // an A1's
                streaming: true,
                pending: Vec::new(),
                requests: Vec::new(),
                inbox: Vec::new(),
                lookalike: false,
            }
        }

        fn commands(&self) -> Vec<u8> {
            self.requests.iter().map(|r| r.0).collect()
        }
    }

    impl Link for Device {
        fn send(&mut self, bytes: &[u8]) -> Result<(), String> {
            self.inbox.extend_from_slice(bytes);
            while let Some((cmd, payload, used)) = parse_request(&self.inbox) {
                let payload = payload.to_vec();
                self.inbox.drain(..used);
                match cmd {
                    0x25 => self.streaming = false,
                    CMD_GET_HEALTH => {
                        if let Some(h) = self.health {
                            self.pending.extend(answer(ANS_HEALTH, &h));
                        }
                    }
                    CMD_RESET => self.health = self.after_reset,
                    CMD_GET_SAMPLERATE => {
                        if let Some([std, exp]) = self.sample_us {
                            let mut p = std.to_le_bytes().to_vec();
                            p.extend(exp.to_le_bytes());
                            self.pending.extend(answer(ANS_SAMPLE_RATE, &p));
                        }
                    }
                    CMD_GET_ACC_BOARD_FLAG => {
                        if let Some(b) = self.board {
                            if self.lookalike {
                                self.pending.extend(answer(ANS_ACC_BOARD_FLAG, &[]));
                            }
                            self.pending
                                .extend(answer(ANS_ACC_BOARD_FLAG, &b.to_le_bytes()));
                        }
                    }
                    _ => {}
                }
                self.requests.push((cmd, payload));
            }
            Ok(())
        }

        fn receive(&mut self, into: &mut Vec<u8>) -> Result<(), String> {
            if self.streaming {
                // old scan nodes, with an A5 5A in a distance field
                into.extend([0x3E, 0x01, 0x10, 0xA5, 0x5A, 0x3C, 0x81, 0x20, 0x10, 0x10]);
            }
            into.append(&mut self.pending);
            if into.is_empty() {
                std::thread::sleep(Duration::from_millis(1));
            }
            Ok(())
        }

        fn pause(&mut self, _: Duration) {}
    }

    const WAIT: Duration = Duration::from_millis(100);

    #[test]
    fn an_a2_on_its_accessory_board_gets_its_motor_started() {
        let mut d = Device::new(Some([0, 0, 0]), Some(1));
        let r = start_scan(&mut d, WAIT).unwrap();
        assert_eq!(d.commands(), [0x25, 0x52, 0x59, 0xFF, 0xF0, 0x20]);
        assert_eq!(d.requests[3].1, [0, 0, 0, 0]);
        assert_eq!(d.requests[4].1, 660u16.to_le_bytes());
        assert_eq!(r.motor_pwm, Some(660));
        assert_eq!(
            (r.sample_us, r.standard_rate_hz()),
            (Some((500, 250)), Some(2000))
        );
        assert!(!r.is_remarkable());
        assert_eq!(
            r.to_string(),
            "health good; standard scan at 2000 nodes/s; motor started by the accessory \
             board at PWM 660"
        );
    }

    #[test]
    fn a_lookalike_before_the_board_answer_does_not_leave_the_motor_off() {
        let mut d = Device::new(Some([0, 0, 0]), Some(1));
        d.lookalike = true;
        let r = start_scan(&mut d, WAIT).unwrap();
        assert_eq!(d.commands(), [0x25, 0x52, 0x59, 0xFF, 0xF0, 0x20]);
        assert_eq!((r.board_flags, r.motor_pwm), (Some(1), Some(660)));
    }

    #[test]
    fn an_a1_without_board_answer_is_asked_to_scan_without_pwm() {
        let mut d = Device::new(Some([0, 0, 0]), None);
        let r = start_scan(&mut d, WAIT).unwrap();
        assert_eq!(d.commands(), [0x25, 0x52, 0x59, 0xFF, 0x20]);
        assert_eq!((r.board_flags, r.motor_pwm), (None, None));
        assert!(r
            .to_string()
            .ends_with("motor on DTR or its own (no accessory board answer)"));
    }

    #[test]
    fn a_protection_stop_is_reset_before_the_scan() {
        let mut d = Device::new(Some([2, 0x34, 0x12]), Some(0));
        d.after_reset = Some([0, 0, 0]);
        let r = start_scan(&mut d, WAIT).unwrap();
        assert_eq!(d.commands(), [0x25, 0x52, 0x40, 0x52, 0x59, 0xFF, 0x20]);
        assert_eq!(r.health, Some(Health::Error(0x1234)));
        assert_eq!(r.after_reset, Some(Some(Health::Good)));
        assert!(r.is_remarkable());
        assert_eq!(
            r.to_string(),
            "health error (error code 0x1234); reset, then health good; standard scan at \
             2000 nodes/s; accessory board without motor control (flags 0x00000000), motor \
             on DTR"
        );
    }

    #[test]
    fn a_silent_device_is_still_asked_to_scan_and_the_report_says_so() {
        let mut d = Device::new(None, None);
        d.streaming = false;
        d.sample_us = None;
        let r = start_scan(&mut d, WAIT).unwrap();
        assert_eq!(d.commands(), [0x25, 0x52, 0x59, 0xFF, 0x20]);
        assert_eq!(r.standard_rate_hz(), None);
        assert!(r.to_string().contains("no sample-rate answer"), "{r}");
        assert!(r.is_remarkable());
        assert!(
            r.to_string().starts_with("no answer to the health request"),
            "{r}"
        );
    }

    #[test]
    fn the_sample_rate_comes_from_the_device_and_a_misread_is_not_used() {
        let mut d = Device::new(Some([0, 0, 0]), None);
        d.sample_us = Some([200, 100]); // a C1's 5000 nodes/s
        let r = start_scan(&mut d, WAIT).unwrap();
        assert_eq!(r.standard_rate_hz(), Some(5000));
        d.sample_us = Some([0, 0]);
        let r = start_scan(&mut d, WAIT).unwrap();
        assert_eq!(r.standard_rate_hz(), None);
        assert!(
            r.to_string().contains("implausible sample duration 0 µs"),
            "{r}"
        );
    }

    #[test]
    fn requests_carry_their_checksum() {
        assert_eq!(request(CMD_GET_HEALTH, &[]), [0xA5, 0x52]);
        assert_eq!(
            request(CMD_GET_ACC_BOARD_FLAG, &[0; 4]),
            [0xA5, 0xFF, 0x04, 0, 0, 0, 0, 0x5E]
        );
        // 0xA5 ^ 0xF0 ^ 0x02 ^ 0x94 ^ 0x02 = 0xC1 (660 = 0x0294)
        assert_eq!(
            request(CMD_SET_MOTOR_PWM, &660u16.to_le_bytes()),
            [0xA5, 0xF0, 0x02, 0x94, 0x02, 0xC1]
        );
        let mut bad = request(CMD_SET_MOTOR_PWM, &[1, 2]);
        *bad.last_mut().unwrap() ^= 1;
        assert_eq!(parse_request(&bad), None);
    }

    #[test]
    fn an_answer_is_found_after_noise_and_only_when_complete() {
        let mut bytes = vec![0x00, 0xA5, 0x5A, 0x01];
        bytes.extend(answer(ANS_HEALTH, &[1, 2, 0]));
        assert_eq!(find_answer(&bytes, ANS_HEALTH, 3), Some(&[1, 2, 0][..]));
        assert_eq!(find_answer(&bytes[..bytes.len() - 1], ANS_HEALTH, 3), None);
        assert_eq!(find_answer(&bytes, ANS_ACC_BOARD_FLAG, 0), None);
        assert_eq!(find_answer(&bytes, ANS_HEALTH, 4), None);
        assert_eq!(Health::decode(&[1, 2, 0]), Some(Health::Warning(2)));
        assert_eq!(Health::decode(&[1, 2]), None);
    }

    /// Leftover bytes that look like a zero-size answer of the same type came first:
    /// the real answer after them is still found (it used to be hidden until the
    /// request's deadline).
    #[test]
    fn a_short_lookalike_does_not_hide_the_answer_after_it() {
        let mut bytes = answer(ANS_ACC_BOARD_FLAG, &[]);
        bytes.extend(answer(ANS_ACC_BOARD_FLAG, &[1, 0, 0, 0]));
        assert_eq!(find_answer(&bytes, ANS_ACC_BOARD_FLAG, 0), Some(&[][..]));
        assert_eq!(
            find_answer(&bytes, ANS_ACC_BOARD_FLAG, 4),
            Some(&[1, 0, 0, 0][..])
        );
    }

    proptest! {
        #[test]
        fn requests_parse_back(cmd in any::<u8>(), payload in proptest::collection::vec(any::<u8>(), 0..40)) {
            // a command with the payload bit always carries a payload
            let cmd = if payload.is_empty() { cmd & 0x7F } else { cmd };
            let bytes = request(cmd, &payload);
            let (c, p, used) = parse_request(&bytes).unwrap();
            prop_assert_eq!(used, bytes.len());
            if payload.is_empty() {
                prop_assert_eq!(c, cmd);
            } else {
                prop_assert_eq!(c, cmd | 0x80);
                prop_assert_eq!(p, &payload[..]);
            }
        }

        #[test]
        fn any_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..64), kind in any::<u8>()) {
            let _ = find_answer(&bytes, kind, 0);
            let _ = find_answer(&bytes, kind, 4);
            let _ = parse_request(&bytes);
            let _ = Health::decode(&bytes);
        }
    }
}
