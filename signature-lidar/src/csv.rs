//! Scans as CSV: one row per ray.
//!
//! # Format
//!
//! * UTF-8 text, comma separated, no quoting. Blank lines and lines starting
//!   with `#` are ignored.
//! * The first other line is the header; columns are found by name, in any
//!   order. Required: `scan_start_s`, `period_s`, `bearing_deg`, `range_m`.
//!   Optional: `rotation` (`ccw` or `cw`, default `ccw`), `start_bearing_deg`
//!   (bearing at the scan start, default 0), `intensity` (default 0), `valid`
//!   (`1`/`0`/`true`/`false`, default 1), `t_s` (the ray's own measurement
//!   time; an empty cell or a missing column means "derive it from the scan
//!   timing"). Unknown columns are an error (a typo would silently drop data).
//! * Times are decimal seconds (`-?digits[.digits]`, at most 9 decimals) and
//!   are converted to integer nanoseconds exactly, so epoch times keep
//!   nanosecond precision.
//! * `bearing_deg` uses the crate's convention (CCW positive, see
//!   [`crate::scan`]); `range_m` is metres (0, `nan`, `inf` mean no return).
//! * Consecutive rows with the same `scan_start_s` form one scan; scan starts
//!   must increase from one scan to the next. `period_s`, `rotation` and
//!   `start_bearing_deg` must not change within a scan.
//!
//! ```text
//! # one scan of a 10 Hz scanner turning counter-clockwise
//! scan_start_s,period_s,rotation,bearing_deg,range_m
//! 1700000000.000000000,0.1,ccw,0,2.50
//! 1700000000.000000000,0.1,ccw,1,2.51
//! ```
//!
//! Every error names the source (file name), the 1-based line and the column.
//!
//! ```
//! use vlsync_signature_lidar::csv::CsvScanReader;
//! let text = "scan_start_s,period_s,bearing_deg,range_m\n0.0,0.1,90,2.0\n0.1,0.1,90,2.1\n";
//! let scans: Vec<_> = CsvScanReader::new(text.as_bytes(), "inline.csv").unwrap()
//!     .collect::<Result<_, _>>().unwrap();
//! assert_eq!(scans.len(), 2);
//! assert_eq!(scans[1].rays()[0].t_ns, 125_000_000);
//! let err = CsvScanReader::new("scan_start_s,period_s,bearing_deg,range_m\n0,0.1,x,1\n".as_bytes(), "bad.csv")
//!     .unwrap().next().unwrap().unwrap_err();
//! assert_eq!(err.to_string(), "bad.csv:2: column `bearing_deg`: not a number: \"x\"");
//! ```

use crate::scan::{Ray, Rotation, Scan, ScanTiming};
use std::fmt;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::path::Path;
use vlsync_common::text::{clip, CR_INSIDE_LINE};
use vlsync_common::Nanos;

/// Longest accepted line, bytes.
pub const MAX_LINE_BYTES: usize = 64 * 1024;
/// Most rays accepted in one scan.
pub const MAX_RAYS_PER_SCAN: usize = 1 << 20;

/// Header written by [`write_scan`].
pub const CSV_HEADER: &str =
    "scan_start_s,period_s,rotation,start_bearing_deg,bearing_deg,range_m,intensity,valid,t_s";

/// A CSV problem, located.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CsvError {
    /// File name or other source label.
    pub source: String,
    /// 1-based line number (0 when not tied to a line, e.g. opening the file).
    pub line: usize,
    /// Column concerned, if any.
    pub column: Option<String>,
    /// What was wrong.
    pub message: String,
}

impl fmt::Display for CsvError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.source)?;
        if self.line > 0 {
            write!(f, ":{}", self.line)?;
        }
        if let Some(c) = &self.column {
            write!(f, ": column `{c}`")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for CsvError {}

/// Parses decimal seconds (`-?digits[.digits]`, ≤ 9 decimals) into exact nanoseconds.
pub fn parse_seconds(s: &str) -> Result<Nanos, String> {
    let t = s.trim();
    let (neg, body) = match t.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, t.strip_prefix('+').unwrap_or(t)),
    };
    let (int, frac) = match body.split_once('.') {
        Some((i, f)) => (i, f),
        None => (body, ""),
    };
    let digits = |x: &str| x.bytes().all(|c| c.is_ascii_digit());
    if (int.is_empty() && frac.is_empty()) || !digits(int) || !digits(frac) {
        return Err(format!("not a decimal number of seconds: {:?}", clip(t)));
    }
    if frac.len() > 9 {
        return Err(format!(
            "more than 9 decimals (finer than 1 ns) in {:?}",
            clip(t)
        ));
    }
    let too_large = || format!("out of range for i64 nanoseconds: {:?}", clip(t));
    // the magnitude in i128, so that i64::MIN (one more than i64::MAX) reads back
    let mut ns: i128 = 0;
    for c in int.bytes() {
        ns = ns * 10 + i128::from(c - b'0');
        if ns > i128::from(i64::MAX) / 1_000_000_000 + 1 {
            return Err(too_large());
        }
    }
    ns *= 1_000_000_000;
    let mut f: i128 = 0;
    for i in 0..9 {
        let d = frac.as_bytes().get(i).map_or(0, |c| i128::from(c - b'0'));
        f = f * 10 + d;
    }
    ns += f;
    Nanos::try_from(if neg { -ns } else { ns }).map_err(|_| too_large())
}

/// Formats nanoseconds as decimal seconds with 9 decimals (exact inverse of [`parse_seconds`]).
pub fn format_seconds(ns: Nanos) -> String {
    let sign = if ns < 0 { "-" } else { "" };
    let a = ns.unsigned_abs();
    format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000)
}

#[derive(Debug, Clone, Copy, Default)]
struct Columns {
    scan_start: usize,
    period: usize,
    bearing: usize,
    range: usize,
    rotation: Option<usize>,
    start_bearing: Option<usize>,
    intensity: Option<usize>,
    valid: Option<usize>,
    t: Option<usize>,
    count: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct ScanKey {
    start_ns: Nanos,
    period_ns: Nanos,
    rotation: Rotation,
    start_bearing_rad: f64,
}

/// Streaming reader: an iterator of scans. An error ends it; the scan collected
/// before the error's line (rows already read, with their start) is given first,
/// and the error on the next call.
#[derive(Debug)]
pub struct CsvScanReader<R> {
    reader: R,
    source: String,
    line_no: usize,
    cols: Columns,
    /// scan being collected, with a per-ray flag "time given"
    key: Option<ScanKey>,
    rays: Vec<(Ray, bool)>,
    last_start: Option<Nanos>,
    done: bool,
    /// an error found after a scan had been collected: given after that scan
    error: Option<CsvError>,
    buf: Vec<u8>,
}

impl CsvScanReader<BufReader<File>> {
    /// Opens a file (a regular file only: a named pipe would block the open); the
    /// file name is used in errors.
    pub fn open(path: &Path) -> Result<Self, CsvError> {
        let source = path.display().to_string();
        let f = vlsync_common::file::open_regular(path).map_err(|e| CsvError {
            source: source.clone(),
            line: 0,
            column: None,
            message: format!("cannot open: {e}"),
        })?;
        Self::new(BufReader::new(f), source)
    }
}

impl<R: BufRead> CsvScanReader<R> {
    /// Reads the header from `reader`; `source` names it in errors.
    pub fn new(reader: R, source: impl Into<String>) -> Result<Self, CsvError> {
        let mut me = Self {
            reader,
            source: source.into(),
            line_no: 0,
            cols: Columns::default(),
            key: None,
            rays: Vec::new(),
            last_start: None,
            done: false,
            error: None,
            buf: Vec::new(),
        };
        let header = match me.next_line()? {
            Some(h) => h,
            None => return Err(me.err(None, "empty file: no header line".into())),
        };
        me.cols = me.parse_header(&header)?;
        Ok(me)
    }

    fn err(&self, column: Option<&str>, message: String) -> CsvError {
        CsvError {
            source: self.source.clone(),
            line: self.line_no,
            column: column.map(clip),
            message,
        }
    }

    /// Next non-blank, non-comment line, or None at end of input.
    fn next_line(&mut self) -> Result<Option<String>, CsvError> {
        loop {
            self.buf.clear();
            self.line_no += 1;
            let n = (&mut self.reader)
                .take(MAX_LINE_BYTES as u64 + 1)
                .read_until(b'\n', &mut self.buf)
                .map_err(|e| self.err(None, format!("read error: {e}")))?;
            if n == 0 {
                return Ok(None);
            }
            if self.buf.len() > MAX_LINE_BYTES {
                // a CR-only file is one long line: say so
                let why = if self.buf.contains(&b'\r') {
                    format!(": {CR_INSIDE_LINE}")
                } else {
                    String::new()
                };
                return Err(self.err(
                    None,
                    format!("line longer than {MAX_LINE_BYTES} bytes{why}"),
                ));
            }
            let line = std::str::from_utf8(&self.buf).map_err(|e| {
                self.err(
                    None,
                    format!("not UTF-8 (byte {} of the line)", e.valid_up_to() + 1),
                )
            })?;
            // a byte-order mark (as some spreadsheet exports write) is not part of the header
            let line = match self.line_no {
                1 => line.strip_prefix('\u{feff}').unwrap_or(line),
                _ => line,
            };
            let line = line.trim();
            if line.contains('\r') {
                return Err(self.err(None, CR_INSIDE_LINE.into()));
            }
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            return Ok(Some(line.to_string()));
        }
    }

    fn parse_header(&self, line: &str) -> Result<Columns, CsvError> {
        let mut c = Columns::default();
        let mut req: [Option<usize>; 4] = [None; 4];
        let names: Vec<&str> = line.split(',').map(str::trim).collect();
        for (i, name) in names.iter().enumerate() {
            let slot = match *name {
                "scan_start_s" => &mut req[0],
                "period_s" => &mut req[1],
                "bearing_deg" => &mut req[2],
                "range_m" => &mut req[3],
                "rotation" => &mut c.rotation,
                "start_bearing_deg" => &mut c.start_bearing,
                "intensity" => &mut c.intensity,
                "valid" => &mut c.valid,
                "t_s" => &mut c.t,
                other => {
                    return Err(
                        self.err(Some(other), format!("unknown column (known: {CSV_HEADER})"))
                    )
                }
            };
            if slot.is_some() {
                return Err(self.err(Some(name), "column appears twice".into()));
            }
            *slot = Some(i);
        }
        let required = ["scan_start_s", "period_s", "bearing_deg", "range_m"];
        for (r, name) in req.iter().zip(required) {
            if r.is_none() {
                return Err(self.err(Some(name), "required column missing from header".into()));
            }
        }
        c.scan_start = req[0].unwrap_or(0);
        c.period = req[1].unwrap_or(0);
        c.bearing = req[2].unwrap_or(0);
        c.range = req[3].unwrap_or(0);
        c.count = names.len();
        Ok(c)
    }

    fn parse_row(&self, line: &str) -> Result<(ScanKey, Ray, bool), CsvError> {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != self.cols.count {
            return Err(self.err(
                None,
                format!("{} cells, the header has {}", cells.len(), self.cols.count),
            ));
        }
        let seconds =
            |i: usize, name: &str| parse_seconds(cells[i]).map_err(|m| self.err(Some(name), m));
        let number = |i: usize, name: &str| {
            cells[i]
                .parse::<f64>()
                .map_err(|_| self.err(Some(name), format!("not a number: {:?}", clip(cells[i]))))
        };
        let start_ns = seconds(self.cols.scan_start, "scan_start_s")?;
        let period_ns = seconds(self.cols.period, "period_s")?;
        if period_ns <= 0 {
            return Err(self.err(
                Some("period_s"),
                format!("must be > 0, got {:?}", clip(cells[self.cols.period])),
            ));
        }
        let bearing_deg = number(self.cols.bearing, "bearing_deg")?;
        if !bearing_deg.is_finite() {
            return Err(self.err(
                Some("bearing_deg"),
                format!("must be finite, got {:?}", clip(cells[self.cols.bearing])),
            ));
        }
        let range_m = number(self.cols.range, "range_m")?;
        let rotation = match self.cols.rotation {
            Some(i) => Rotation::from_name(cells[i]).ok_or_else(|| {
                self.err(
                    Some("rotation"),
                    format!("expected `cw` or `ccw`, got {:?}", clip(cells[i])),
                )
            })?,
            None => Rotation::Ccw,
        };
        let start_bearing_deg = match self.cols.start_bearing {
            Some(i) => {
                let v = number(i, "start_bearing_deg")?;
                if !v.is_finite() {
                    return Err(self.err(
                        Some("start_bearing_deg"),
                        format!("must be finite, got {:?}", clip(cells[i])),
                    ));
                }
                v
            }
            None => 0.0,
        };
        let intensity = match self.cols.intensity {
            Some(i) if !cells[i].is_empty() => number(i, "intensity")? as f32,
            _ => 0.0,
        };
        let valid = match self.cols.valid {
            Some(i) => match cells[i] {
                "1" | "true" | "" => true,
                "0" | "false" => false,
                other => {
                    return Err(self.err(
                        Some("valid"),
                        format!("expected 1, 0, true or false, got {:?}", clip(other)),
                    ))
                }
            },
            None => true,
        };
        let (t_ns, timed) = match self.cols.t {
            Some(i) if !cells[i].is_empty() => (seconds(i, "t_s")?, true),
            _ => (0, false),
        };
        let key = ScanKey {
            start_ns,
            period_ns,
            rotation,
            start_bearing_rad: start_bearing_deg.to_radians(),
        };
        let ray = Ray::timed(bearing_deg.to_radians(), range_m, intensity, valid, t_ns);
        Ok((key, ray, timed))
    }

    fn build(&mut self) -> Option<Scan> {
        let key = self.key.take()?;
        let timing = ScanTiming {
            start_ns: key.start_ns,
            period_ns: key.period_ns,
            rotation: key.rotation,
            start_bearing_rad: key.start_bearing_rad,
        };
        let rays = self
            .rays
            .drain(..)
            .map(|(r, timed)| {
                if timed {
                    r
                } else {
                    Ray {
                        t_ns: timing.time_at_bearing(r.bearing_rad),
                        ..r
                    }
                }
            })
            .collect();
        Some(Scan::from_timed(timing, rays))
    }

    fn next_scan(&mut self) -> Result<Option<Scan>, CsvError> {
        loop {
            let Some(line) = self.next_line()? else {
                return Ok(self.build());
            };
            let (key, ray, timed) = self.parse_row(&line)?;
            match self.key {
                Some(k) if k.start_ns == key.start_ns => {
                    if k != key {
                        return Err(self.err(
                            None,
                            "period_s, rotation or start_bearing_deg changes within a scan".into(),
                        ));
                    }
                    if self.rays.len() >= MAX_RAYS_PER_SCAN {
                        return Err(self.err(
                            None,
                            format!("more than {MAX_RAYS_PER_SCAN} rays in one scan"),
                        ));
                    }
                    self.rays.push((ray, timed));
                }
                _ => {
                    if let Some(prev) = self.last_start {
                        if key.start_ns <= prev {
                            return Err(self.err(
                                Some("scan_start_s"),
                                format!(
                                    "scan start {} is not after the previous scan start {}",
                                    format_seconds(key.start_ns),
                                    format_seconds(prev)
                                ),
                            ));
                        }
                    }
                    self.last_start = Some(key.start_ns);
                    let done = self.build();
                    self.key = Some(key);
                    self.rays.push((ray, timed));
                    if done.is_some() {
                        return Ok(done);
                    }
                }
            }
        }
    }
}

impl<R: BufRead> Iterator for CsvScanReader<R> {
    type Item = Result<Scan, CsvError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        if let Some(e) = self.error.take() {
            self.done = true;
            return Some(Err(e));
        }
        match self.next_scan() {
            Ok(Some(s)) => Some(Ok(s)),
            Ok(None) => {
                self.done = true;
                None
            }
            Err(e) => match self.build() {
                // the rows before the bad one are a scan: not lost with it
                Some(s) => {
                    self.error = Some(e);
                    Some(Ok(s))
                }
                None => {
                    self.done = true;
                    Some(Err(e))
                }
            },
        }
    }
}

/// Writes [`CSV_HEADER`] and a newline.
pub fn write_header(w: &mut impl Write) -> io::Result<()> {
    writeln!(w, "{CSV_HEADER}")
}

/// Writes one scan's rays (with their exact times in `t_s`).
pub fn write_scan(w: &mut impl Write, scan: &Scan) -> io::Result<()> {
    let t = scan.timing();
    let start = format_seconds(t.start_ns);
    let period = format_seconds(t.period_ns);
    for r in scan.rays() {
        writeln!(
            w,
            "{start},{period},{},{},{},{},{},{},{}",
            t.rotation.name(),
            t.start_bearing_rad.to_degrees(),
            r.bearing_rad.to_degrees(),
            r.range_m,
            r.intensity,
            if r.valid { 1 } else { 0 },
            format_seconds(r.t_ns)
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn read(text: &str) -> Result<Vec<Scan>, CsvError> {
        CsvScanReader::new(text.as_bytes(), "t.csv")?.collect()
    }

    #[test]
    fn seconds_parse_exactly() {
        assert_eq!(
            parse_seconds("1700000000.123456789"),
            Ok(1_700_000_000_123_456_789)
        );
        assert_eq!(parse_seconds("-0.5"), Ok(-500_000_000));
        assert_eq!(parse_seconds(".25"), Ok(250_000_000));
        assert_eq!(parse_seconds("3"), Ok(3_000_000_000));
        assert!(parse_seconds("1e3").is_err());
        assert!(parse_seconds("0.1234567891").is_err());
        assert!(parse_seconds("99999999999999999999").is_err());
        assert!(parse_seconds("").is_err());
        assert!(parse_seconds(".").is_err());
    }

    #[test]
    fn rows_group_into_scans_with_derived_times() {
        let text = "# test\n\nscan_start_s,period_s,rotation,bearing_deg,range_m\n\
                    10.0,0.1,cw,-90,1\n10.0,0.1,cw,0,nan\n10.1,0.1,cw,-90,2\n";
        let s = read(text).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].len(), 2);
        assert_eq!(s[0].rays()[0].t_ns, 10_000_000_000);
        assert_eq!(s[0].rays()[1].t_ns, 10_025_000_000);
        assert!(s[0].rays()[0].range_m.is_nan());
        assert_eq!(s[1].timing().rotation, Rotation::Cw);
    }

    #[test]
    fn given_times_are_kept() {
        let text =
            "scan_start_s,period_s,bearing_deg,range_m,t_s\n0,0.1,0,1,0.000000007\n0,0.1,10,1,\n";
        let s = read(text).unwrap();
        let t: Vec<_> = s[0].rays().iter().map(|r| r.t_ns).collect();
        assert_eq!(t, vec![7, 2_777_778]);
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let cases = [
            ("", "t.csv:1: empty file: no header line"),
            (
                "scan_start_s,period_s,bearing_deg\n",
                "t.csv:1: column `range_m`: required column missing from header",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m,foo\n",
                "t.csv:1: column `foo`: unknown column",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m\n0,0.1,0\n",
                "t.csv:2: 3 cells, the header has 4",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m\n0,0,0,1\n",
                "t.csv:2: column `period_s`: must be > 0",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m\n# c\n1,0.1,0,1\n0,0.1,0,1\n",
                "t.csv:4: column `scan_start_s`: scan start 0.000000000 is not after",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m\n0,0.1,0,1\n0,0.2,0,1\n",
                "t.csv:3: period_s, rotation",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m,rotation\n0,0.1,0,1,left\n",
                "t.csv:2: column `rotation`: expected `cw` or `ccw`",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m,valid\n0,0.1,0,1,yes\n",
                "t.csv:2: column `valid`",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m\n0,0.1,inf,1\n",
                "t.csv:2: column `bearing_deg`: must be finite",
            ),
            (
                "scan_start_s,period_s,bearing_deg,range_m\r0,0.1,0,1\r",
                "t.csv:1: a carriage return inside the line: CR-only line endings?",
            ),
        ];
        for (text, want) in cases {
            let e = read(text).unwrap_err().to_string();
            assert!(e.starts_with(want), "{e:?} does not start with {want:?}");
        }
        let mut bad = b"scan_start_s,period_s,bearing_deg,range_m\n0,0.1,".to_vec();
        bad.extend_from_slice(&[0xFF, b',', b'1', b'\n']);
        let e = CsvScanReader::new(&bad[..], "b.csv")
            .unwrap()
            .next()
            .unwrap()
            .unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("UTF-8"));
    }

    #[test]
    fn the_scan_collected_before_an_error_is_given_before_the_error() {
        // a file cut inside its last row: the third scan's two rows come first
        let text = "scan_start_s,period_s,bearing_deg,range_m\n0.0,0.1,0,2\n0.0,0.1,90,2\n\
                    0.1,0.1,0,2\n0.1,0.1,90,2\n0.2,0.1,0,2\n0.2,0.1,90,2\n0.2,0.1,4";
        let got: Vec<_> = CsvScanReader::new(text.as_bytes(), "cut.csv")
            .unwrap()
            .collect();
        let starts: Vec<_> = got
            .iter()
            .filter_map(|r| r.as_ref().ok())
            .map(|s| (s.timing().start_ns, s.len()))
            .collect();
        assert_eq!(
            starts,
            [(0, 2), (100_000_000, 2), (200_000_000, 2)],
            "{got:?}"
        );
        assert_eq!(got.len(), 4);
        let e = got[3].as_ref().unwrap_err();
        assert_eq!(e.to_string(), "cut.csv:8: 3 cells, the header has 4");
        // an error in the first row: no scan, the error
        let mut r = CsvScanReader::new(
            "scan_start_s,period_s,bearing_deg,range_m\nx\n".as_bytes(),
            "e",
        )
        .unwrap();
        assert!(r.next().unwrap().is_err());
        assert!(r.next().is_none());
        // a scan start going back: the scan before it, then the error
        let text = "scan_start_s,period_s,bearing_deg,range_m\n1,0.1,0,1\n0,0.1,0,1\n";
        let mut r = CsvScanReader::new(text.as_bytes(), "back").unwrap();
        assert_eq!(r.next().unwrap().unwrap().timing().start_ns, 1_000_000_000);
        assert!(r
            .next()
            .unwrap()
            .unwrap_err()
            .to_string()
            .contains("not after"));
        assert!(r.next().is_none());
    }

    #[test]
    fn a_byte_order_mark_is_no_part_of_the_header_and_quoted_values_are_clipped() {
        let text = "\u{feff}scan_start_s,period_s,bearing_deg,range_m\r\n0,0.1,0,1\r\n";
        let scans: Vec<_> = read(text).unwrap();
        assert_eq!(scans.len(), 1);
        let long = "9x".repeat(30_000);
        let e = read(&format!(
            "scan_start_s,period_s,bearing_deg,range_m\n0,0.1,{long},1\n"
        ))
        .unwrap_err()
        .to_string();
        assert!(e.len() < 200, "{} bytes: {}", e.len(), &e[..200]);
        let e = read(&format!(
            "scan_start_s,period_s,bearing_deg,range_m,{long}\n"
        ))
        .unwrap_err()
        .to_string();
        assert!(
            e.len() < 300 && e.contains("unknown column"),
            "{}",
            &e[..300]
        );
    }

    #[test]
    fn open_missing_file_names_it() {
        let e = CsvScanReader::open(Path::new("/nonexistent/scans.csv")).unwrap_err();
        assert!(e
            .to_string()
            .starts_with("/nonexistent/scans.csv: cannot open"));
    }

    #[test]
    fn open_refuses_anything_but_a_regular_file() {
        let dir = std::env::temp_dir().join(format!("vlsync-lidar-csv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let e = CsvScanReader::open(&dir).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        // a named pipe without a writer would block the open forever
        let fifo = dir.join("scans.csv");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        let e = CsvScanReader::open(&fifo).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "{}: cannot open: not a regular file (a named pipe)",
                fifo.display()
            )
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_read_roundtrip() {
        let timing = ScanTiming {
            start_ns: 1_700_000_000_123_456_789,
            period_ns: 100_000_000,
            rotation: Rotation::Cw,
            start_bearing_rad: 0.0,
        };
        let rays = (0..36)
            .map(|i| {
                Ray::new(
                    (i as f64 * 10.0).to_radians(),
                    1.0 + i as f64 * 0.01,
                    7.0,
                    i % 5 != 0,
                )
            })
            .collect();
        let scan = Scan::from_uniform(timing, rays);
        let mut out = Vec::new();
        write_header(&mut out).unwrap();
        write_scan(&mut out, &scan).unwrap();
        let back = CsvScanReader::new(&out[..], "rt")
            .unwrap()
            .next()
            .unwrap()
            .unwrap();
        assert_eq!(back.timing().start_ns, timing.start_ns);
        assert_eq!(back.len(), 36);
        for (a, b) in scan.rays().iter().zip(back.rays()) {
            assert_eq!(a.t_ns, b.t_ns);
            assert_eq!(a.valid, b.valid);
            assert!((a.bearing_rad - b.bearing_rad).abs() < 1e-12);
            assert_eq!(a.range_m, b.range_m);
        }
    }

    proptest! {
        #[test]
        fn seconds_roundtrip(ns in any::<i64>()) {
            prop_assert_eq!(parse_seconds(&format_seconds(ns)), Ok(ns));
            prop_assert_eq!(parse_seconds(&format_seconds(i64::MIN)), Ok(i64::MIN));
            prop_assert_eq!(parse_seconds(&format_seconds(i64::MAX)), Ok(i64::MAX));
        }

        #[test]
        fn arbitrary_text_never_panics(body in "[0-9a-z.,#\\-\n ]{0,400}") {
            let text = format!("scan_start_s,period_s,bearing_deg,range_m\n{body}");
            for r in CsvScanReader::new(text.as_bytes(), "p").unwrap() {
                let _ = r;
            }
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            if let Ok(r) = CsvScanReader::new(&bytes[..], "p") {
                for x in r { let _ = x; }
            }
        }
    }
}
