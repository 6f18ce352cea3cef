//! Frame sources: a directory of PNG/JPEG frames with a timestamps file, and
//! (behind the `v4l2` feature) a V4L2 camera, see [`crate::v4l2`].
//!
//! # The timestamps file `frames.csv`
//!
//! One frame per line, in capture order:
//!
//! ```text
//! # comment lines and blank lines are ignored; the header line is optional
//! file,t_s,exposure_start_s,exposure_s
//! frame_000000.png,1700000000.000012345
//! frame_000001.png,1700000000.033345678,1700000000.030000000,0.004
//! ```
//!
//! * `file`: frame file name, relative to the directory of `frames.csv`
//!   (absolute paths are allowed). PNG or JPEG (format from the content).
//!   No commas in names; surrounding spaces are trimmed.
//! * `t_s`: the frame's time in seconds on the camera clock, a plain decimal
//!   (`-`/`+` sign allowed, no exponent). Up to 9 fraction digits are exact
//!   (nanoseconds); further digits are rounded.
//! * `exposure_start_s,exposure_s` (optional, both or neither): start and
//!   duration of the exposure, seconds. When present the frame's instant is
//!   mid-exposure (`FrameTime::Exposure`) and `t_s` is only checked for syntax.
//!
//! [`DirSource::open`] reads and checks the whole file and that every listed
//! frame file exists, so a bad line or a missing frame fails before any work;
//! errors name the file and the line.
//!
//! ```
//! use vlsync_signature_cam::source::parse_seconds;
//! assert_eq!(parse_seconds("12.5"), Ok(12_500_000_000));
//! assert_eq!(parse_seconds("-0.000000001"), Ok(-1));
//! assert!(parse_seconds("1e3").is_err());
//! ```

use crate::image::GrayFrame;
use crate::signature::FrameTime;
use crate::Error;
use std::path::{Path, PathBuf};
use vlsync_common::text::clip;
use vlsync_common::Nanos;

/// A source of gray frames with their times.
pub trait FrameSource {
    /// The next frame, `Ok(None)` at the end of the stream. The frame borrows the
    /// source's buffer until the next call.
    fn next_frame(&mut self) -> Result<Option<(GrayFrame<'_, u8>, FrameTime)>, Error>;

    /// Frames the source received but skipped as unusable (a live camera's corrupt
    /// or short buffer), and the last one's reason; `None` while there were none.
    fn unusable(&self) -> Option<(u64, &str)> {
        None
    }

    /// A one-time remark on how the stream is timed, for the driver's log (a live
    /// camera whose buffer stamps are not on `CLOCK_MONOTONIC`); each remark is
    /// handed out once.
    fn take_note(&mut self) -> Option<String> {
        None
    }
}

/// Unusable frames in a row after which a stream ends with an error (a second at
/// 30 Hz).
pub const MAX_UNUSABLE_IN_ROW: u32 = 30;

/// Bytes kept for the last unusable frame's reason from the start, so that
/// [`UnusableFrames::skip_fmt`] on a live stream's per-frame path writes it without
/// allocating (a longer reason grows the room once).
pub const REASON_ROOM: usize = 256;

/// Counts the frames of a stream that could not be used (a live camera's corrupt
/// buffer, a recording's undecodable image, a recording's malformed scan) and ends
/// the stream after [`MAX_UNUSABLE_IN_ROW`] of them in a row: sporadic bad frames
/// are dropped frames, a stream of nothing but bad frames is a fault.
///
/// ```
/// use vlsync_signature_cam::source::UnusableFrames;
/// let mut u = UnusableFrames::named("buffers");
/// u.skip("buffer 3 flagged corrupt".into()).unwrap();
/// u.used();
/// assert_eq!(u.counts(), Some((1, "buffer 3 flagged corrupt")));
/// // on a live stream's per-frame path: the reason written into the room kept
/// u.skip_fmt(format_args!("buffer {} flagged corrupt", 9)).unwrap();
/// assert_eq!(u.counts(), Some((2, "buffer 9 flagged corrupt")));
/// ```
#[derive(Debug, Clone)]
pub struct UnusableFrames {
    unit: &'static str,
    total: u64,
    in_row: u32,
    last: String,
}

impl Default for UnusableFrames {
    fn default() -> Self {
        Self::named("frames")
    }
}

impl UnusableFrames {
    /// A counter whose error calls the stream's units `unit` (`frames`, `buffers`,
    /// `scans`).
    pub fn named(unit: &'static str) -> Self {
        Self {
            unit,
            total: 0,
            in_row: 0,
            last: String::with_capacity(REASON_ROOM),
        }
    }

    /// A frame that could not be used, and why: `Ok` to go on with the next one;
    /// once [`MAX_UNUSABLE_IN_ROW`] came in a row, `Err` with the message that ends
    /// the stream (how many, and the last reason).
    pub fn skip(&mut self, reason: String) -> Result<(), String> {
        self.last = reason;
        self.count_skip()
    }

    /// As [`UnusableFrames::skip`], the reason written over the last one in place:
    /// no allocation while it fits the room kept ([`REASON_ROOM`]), for a stream
    /// that skips frames on its per-frame path (a USB camera's cut transfers). The
    /// message that ends the stream is the one string made.
    pub fn skip_fmt(&mut self, reason: std::fmt::Arguments<'_>) -> Result<(), String> {
        use std::fmt::Write;
        self.last.clear();
        // writing into a String fails only if a Display impl does; the reason is
        // then what was written of it
        let _ = self.last.write_fmt(reason);
        self.count_skip()
    }

    fn count_skip(&mut self) -> Result<(), String> {
        self.total = self.total.saturating_add(1);
        self.in_row = self.in_row.saturating_add(1);
        if self.in_row >= MAX_UNUSABLE_IN_ROW {
            return Err(format!(
                "{} {} in a row unusable, the last: {}",
                self.in_row, self.unit, self.last
            ));
        }
        Ok(())
    }

    /// A frame that was used.
    pub fn used(&mut self) {
        self.in_row = 0;
    }

    /// Frames skipped so far and the last one's reason (`None` before the first).
    pub fn counts(&self) -> Option<(u64, &str)> {
        (self.total > 0).then_some((self.total, self.last.as_str()))
    }
}

/// Parses a decimal number of seconds exactly into nanoseconds.
///
/// Accepts an optional sign, digits, and an optional `.` with digits (at least one
/// digit in all). Fraction digits past the ninth round half away from zero.
pub fn parse_seconds(s: &str) -> Result<Nanos, String> {
    let t = s.trim();
    let (neg, body) = match t.as_bytes().first() {
        Some(b'-') => (true, &t[1..]),
        Some(b'+') => (false, &t[1..]),
        _ => (false, t),
    };
    let (int, frac) = match body.split_once('.') {
        Some((i, f)) => (i, f),
        None => (body, ""),
    };
    let digits = |p: &str| p.bytes().all(|b| b.is_ascii_digit());
    if int.is_empty() && frac.is_empty() || !digits(int) || !digits(frac) {
        return Err(format!("`{}` is not a decimal number of seconds", clip(s)));
    }
    let overflow = || format!("`{}` seconds is out of range", clip(s));
    let mut ns: i128 = 0;
    for b in int.bytes() {
        ns = ns * 10 + i128::from(b - b'0');
        if ns > i128::from(i64::MAX) / 1_000_000_000 + 1 {
            return Err(overflow());
        }
    }
    ns *= 1_000_000_000;
    let mut scale: i128 = 100_000_000;
    let fb = frac.as_bytes();
    for &b in fb.iter().take(9) {
        ns += i128::from(b - b'0') * scale;
        scale /= 10;
    }
    if fb.len() > 9 && fb[9] >= b'5' {
        ns += 1;
    }
    if neg {
        ns = -ns;
    }
    Nanos::try_from(ns).map_err(|_| overflow())
}

/// One line of the timestamps file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameEntry {
    /// Frame file, resolved against the timestamps file's directory.
    pub path: PathBuf,
    /// Frame time.
    pub time: FrameTime,
    /// 1-based line in the timestamps file.
    pub line: usize,
}

/// The text of a timestamps file's bytes; bytes that are not UTF-8 are an error naming
/// their line and byte, as every CSV reader of vlsync names them.
fn frames_csv_text<'a>(bytes: &'a [u8], csv: &Path) -> Result<&'a str, Error> {
    std::str::from_utf8(bytes).map_err(|e| {
        let good = &bytes[..e.valid_up_to()];
        let line_start = good.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        Error::Parse {
            path: csv.to_path_buf(),
            line: good.iter().filter(|&&b| b == b'\n').count() + 1,
            reason: format!(
                "not UTF-8 (byte {} of the line)",
                good.len() - line_start + 1
            ),
        }
    })
}

/// Parses the text of a timestamps file (see the module docs). `csv` names the
/// file in errors and is the base for relative frame paths.
pub fn parse_frames_csv(text: &str, csv: &Path) -> Result<Vec<FrameEntry>, Error> {
    let base = csv.parent().unwrap_or(Path::new(""));
    let mut out = Vec::new();
    let mut seen_data = false;
    // a byte-order mark (as some spreadsheet exports write) is not part of the header
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        let err = |reason: String| Error::Parse {
            path: csv.to_path_buf(),
            line,
            reason,
        };
        if l.contains('\r') {
            return Err(err(vlsync_common::text::CR_INSIDE_LINE.into()));
        }
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = l.split(',').map(str::trim).collect();
        if !seen_data && fields[0] == "file" {
            seen_data = true;
            continue; // header
        }
        seen_data = true;
        if fields.len() != 2 && fields.len() != 4 {
            return Err(err(format!(
                "expected 2 or 4 fields (file,t_s[,exposure_start_s,exposure_s]), found {}",
                fields.len()
            )));
        }
        if fields[0].is_empty() {
            return Err(err("empty file name".into()));
        }
        let secs = |k: usize, name: &str| {
            parse_seconds(fields[k]).map_err(|r| err(format!("field {} ({name}): {r}", k + 1)))
        };
        let t = secs(1, "t_s")?;
        let time = if fields.len() == 4 {
            let start_ns = secs(2, "exposure_start_s")?;
            let duration_ns = secs(3, "exposure_s")?;
            if duration_ns < 0 {
                return Err(err(format!(
                    "field 4 (exposure_s): negative duration `{}`",
                    clip(fields[3])
                )));
            }
            FrameTime::Exposure {
                start_ns,
                duration_ns,
            }
        } else {
            FrameTime::Instant(t)
        };
        out.push(FrameEntry {
            path: base.join(fields[0]),
            time,
            line,
        });
    }
    Ok(out)
}

/// Largest frame decoded from a file, pixels (64 Mpx, as for the images of a recording).
pub const MAX_FRAME_PIXELS: u64 = 64 << 20;
/// Largest width or height of a frame decoded from a file, pixels.
pub const MAX_FRAME_SIDE: u32 = 1 << 15;

/// Frames from a directory of PNG/JPEG files listed in a timestamps file.
/// Frames larger than [`MAX_FRAME_PIXELS`] or [`MAX_FRAME_SIDE`] are errors naming
/// the file, found from the image header before the pixels are decoded.
#[derive(Debug)]
pub struct DirSource {
    csv: PathBuf,
    entries: Vec<FrameEntry>,
    next: usize,
    buf: Vec<u8>,
}

impl DirSource {
    /// Name of the timestamps file inside a frame directory.
    pub const TIMESTAMPS_FILE: &'static str = "frames.csv";

    /// Opens `dir/frames.csv`.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self, Error> {
        Self::from_csv(dir.as_ref().join(Self::TIMESTAMPS_FILE))
    }

    /// Opens a timestamps file; frame paths are relative to its directory.
    /// Fails if the file is malformed or any listed frame file is missing.
    pub fn from_csv(csv: impl AsRef<Path>) -> Result<Self, Error> {
        let csv = csv.as_ref().to_path_buf();
        // regular files only: a named pipe would block the open
        let bytes = vlsync_common::file::read_regular(&csv).map_err(|source| Error::Io {
            path: csv.clone(),
            source,
        })?;
        let text = frames_csv_text(&bytes, &csv)?;
        let entries = parse_frames_csv(text, &csv)?;
        for e in &entries {
            match vlsync_common::file::check_regular(&e.path) {
                Ok(()) => {}
                Err(err) if err.kind() == std::io::ErrorKind::NotFound => {
                    return Err(Error::MissingFrame {
                        path: e.path.clone(),
                        listed_in: csv,
                        line: e.line,
                    })
                }
                Err(source) => {
                    return Err(Error::Io {
                        path: e.path.clone(),
                        source,
                    })
                }
            }
        }
        Ok(Self {
            csv,
            entries,
            next: 0,
            buf: Vec::new(),
        })
    }

    /// All frames listed.
    pub fn entries(&self) -> &[FrameEntry] {
        &self.entries
    }

    /// The timestamps file.
    pub fn csv_path(&self) -> &Path {
        &self.csv
    }

    /// Decodes one frame file to gray.
    fn decode(&mut self, idx: usize) -> Result<(usize, usize), Error> {
        let e = &self.entries[idx];
        let decode_err = |reason: String| Error::Decode {
            path: e.path.clone(),
            reason,
        };
        let file = vlsync_common::file::open_regular(&e.path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::NotFound {
                Error::MissingFrame {
                    path: e.path.clone(),
                    listed_in: self.csv.clone(),
                    line: e.line,
                }
            } else {
                Error::Io {
                    path: e.path.clone(),
                    source,
                }
            }
        })?;
        let mut reader = ::image::ImageReader::new(std::io::BufReader::new(file))
            .with_guessed_format()
            .map_err(|err| decode_err(err.to_string()))?;
        // a small file can declare a huge image: bound the decode as MCAP images are
        let mut limits = ::image::Limits::default();
        limits.max_image_width = Some(MAX_FRAME_SIDE);
        limits.max_image_height = Some(MAX_FRAME_SIDE);
        limits.max_alloc = Some(MAX_FRAME_PIXELS.saturating_mul(8));
        reader.limits(limits);
        let decoder = reader
            .into_decoder()
            .map_err(|err| decode_err(err.to_string()))?;
        let (w, h) = ::image::ImageDecoder::dimensions(&decoder);
        if u64::from(w) * u64::from(h) > MAX_FRAME_PIXELS {
            return Err(decode_err(format!(
                "image {w}x{h} exceeds the limit of {MAX_FRAME_PIXELS} pixels"
            )));
        }
        let img = ::image::DynamicImage::from_decoder(decoder)
            .map_err(|err| decode_err(err.to_string()))?;
        let gray = img.into_luma8();
        let (w, h) = (gray.width() as usize, gray.height() as usize);
        self.buf = gray.into_raw();
        Ok((w, h))
    }
}

impl FrameSource for DirSource {
    fn next_frame(&mut self) -> Result<Option<(GrayFrame<'_, u8>, FrameTime)>, Error> {
        let idx = self.next;
        if idx >= self.entries.len() {
            return Ok(None);
        }
        self.next += 1;
        let (w, h) = self.decode(idx)?;
        let time = self.entries[idx].time;
        let frame = GrayFrame::borrowed(w, h, &self.buf).map_err(|e| Error::Decode {
            path: self.entries[idx].path.clone(),
            reason: e.to_string(),
        })?;
        Ok(Some((frame, time)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn seconds_parse_exactly() {
        assert_eq!(
            parse_seconds("1700000000.123456789"),
            Ok(1_700_000_000_123_456_789)
        );
        assert_eq!(parse_seconds(" 3 "), Ok(3_000_000_000));
        assert_eq!(parse_seconds(".5"), Ok(500_000_000));
        assert_eq!(parse_seconds("5."), Ok(5_000_000_000));
        assert_eq!(parse_seconds("0.0000000015"), Ok(2));
        assert_eq!(parse_seconds("-0.0000000015"), Ok(-2));
        assert_eq!(parse_seconds("0.0000000014999"), Ok(1));
        for bad in [
            "",
            ".",
            "-",
            "1.2.3",
            "1e5",
            "abc",
            "1,5",
            "9300000000",
            "--1",
            "+-1",
            "1 2",
        ] {
            assert!(parse_seconds(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn csv_lines_and_errors() {
        let csv = Path::new("/data/run1/frames.csv");
        let text = "# a comment\n\nfile,t_s\na.png, 1.5\nsub/b.jpg,2.0,1.99,0.004\r\n";
        let e = parse_frames_csv(text, csv).unwrap();
        assert_eq!(e.len(), 2);
        assert_eq!(e[0].path, PathBuf::from("/data/run1/a.png"));
        assert_eq!(e[0].time, FrameTime::Instant(1_500_000_000));
        assert_eq!(e[0].line, 4);
        assert_eq!(
            e[1].time,
            FrameTime::Exposure {
                start_ns: 1_990_000_000,
                duration_ns: 4_000_000
            }
        );
        let cases = [
            ("a.png,1.0\nb.png\n", 2, "found 1"),
            ("a.png,1.0,2.0\n", 1, "found 3"),
            ("a.png,x\n", 1, "t_s"),
            ("a.png,1,1,-0.1\n", 1, "negative"),
            ("a.png,1,x,0.1\n", 1, "exposure_start_s"),
            (",1\n", 1, "empty file name"),
            ("a.png,1\nfile,t_s\n", 2, "t_s"),
            ("file,t_s\ra.png,1\r", 1, "CR-only line endings?"),
        ];
        // a byte-order mark is not part of the header; a long value is quoted clipped
        let e = parse_frames_csv("\u{feff}file,t_s\r\na.png,1.5\r\n", csv).unwrap();
        assert_eq!(e.len(), 1);
        assert_eq!(e[0].time, FrameTime::Instant(1_500_000_000));
        let long = format!("a.png,{}\n", "7x".repeat(30_000));
        let msg = parse_frames_csv(&long, csv).unwrap_err().to_string();
        assert!(msg.len() < 200, "{} bytes", msg.len());
        for (text, line, what) in cases {
            let err = parse_frames_csv(text, csv).unwrap_err();
            let msg = err.to_string();
            assert!(
                msg.starts_with(&format!("/data/run1/frames.csv:{line}:")) && msg.contains(what),
                "{text:?}: {msg}"
            );
        }
    }

    #[test]
    fn bytes_that_are_not_utf8_are_named_by_line_and_byte() {
        let csv = Path::new("/data/run1/frames.csv");
        assert_eq!(frames_csv_text(b"file,t_s\n", csv).unwrap(), "file,t_s\n");
        let msg = frames_csv_text(b"file,t_s\na.png,1\nb\xffc.png,2\n", csv)
            .unwrap_err()
            .to_string();
        assert_eq!(
            msg,
            "/data/run1/frames.csv:3: not UTF-8 (byte 2 of the line)"
        );
        // and through the file itself
        let dir = std::env::temp_dir().join(format!("vlsync-frames-utf8-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("frames.csv"), b"file,t_s\n\xfe.png,1\n").unwrap();
        let Err(e) = DirSource::open(&dir) else {
            panic!("accepted")
        };
        let msg = e.to_string();
        assert!(
            msg.ends_with("frames.csv:2: not UTF-8 (byte 1 of the line)"),
            "{msg}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn unusable_frames_are_skipped_until_a_second_of_them_in_a_row() {
        let mut u = UnusableFrames::named("buffers");
        assert_eq!(u.counts(), None);
        // sporadic bad frames never end the stream
        for k in 0..1000 {
            if k % 7 == 0 {
                u.skip(format!("buffer {k} flagged corrupt by the driver"))
                    .unwrap();
            } else {
                u.used();
            }
        }
        let (n, last) = u.counts().unwrap();
        assert_eq!(n, 143);
        assert_eq!(last, "buffer 994 flagged corrupt by the driver");
        // a stream of nothing usable does, naming why
        for k in 1..MAX_UNUSABLE_IN_ROW {
            u.skip(format!("short {k}")).unwrap();
        }
        let e = u.skip("buffer 9: too short".into()).unwrap_err();
        assert_eq!(
            e,
            "30 buffers in a row unusable, the last: buffer 9: too short"
        );
        assert_eq!(u.counts().unwrap().0, 173);
        // the default unit
        let mut f = UnusableFrames::default();
        for _ in 1..MAX_UNUSABLE_IN_ROW {
            f.skip("x".into()).unwrap();
        }
        assert!(f
            .skip("y".into())
            .unwrap_err()
            .starts_with("30 frames in a row"));
    }

    proptest! {
        #[test]
        fn seconds_roundtrip(ns in any::<i64>()) {
            let sign = if ns < 0 { "-" } else { "" };
            let a = ns.unsigned_abs();
            let s = format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000);
            prop_assert_eq!(parse_seconds(&s), Ok(ns));
        }

        #[test]
        fn parsers_never_panic(s in "\\PC{0,40}") {
            let _ = parse_seconds(&s);
            let _ = parse_frames_csv(&s, Path::new("x/frames.csv"));
        }
    }
}
