//! CSV files of signature streams and of the truth.
//!
//! * Signature CSV: header `t,value`, then one row per sample; `t` in seconds on the
//!   producing sensor's clock, written with exactly nine decimals (nanoseconds), the
//!   value in Rust's shortest round-trip notation (so `NaN`/`inf` are written as such).
//! * Truth CSV: header `t,offset`, `t` in seconds on the LiDAR clock, offset `t_L - t_C`
//!   in seconds.
//!
//! The signature reader is strict about structure and lenient about values: a malformed
//! row is an error naming the file, the 1-based line number and what was wrong, while
//! NaN and infinite *values* are passed through (the estimator rejects and counts them).
//! The truth reader is strict about values too: every offset finite, times strictly
//! increasing, at least one row (errors the same way). Timestamps are parsed exactly
//! from their decimal text, so epoch-sized stamps keep nanosecond precision. Only
//! regular files are read (a named pipe would block the open; see
//! [`vlsync_common::file`]).
//!
//! ```
//! use vlsync_common::Sample;
//! use vlsync_sim::io::{parse_signature_csv, signature_csv_string};
//! let samples = vec![Sample::new(1_700_000_000_123_456_789, 0.5), Sample::new(1_700_000_000_223_456_789, f64::NAN)];
//! let text = signature_csv_string(&samples);
//! assert!(text.starts_with("t,value\n1700000000.123456789,0.5\n"));
//! let (back, stats) = parse_signature_csv(text.as_bytes(), "inline").unwrap();
//! assert_eq!(back[0], samples[0]);
//! assert!(back[1].value.is_nan());
//! assert_eq!(stats.non_finite_values, 1);
//! let err = parse_signature_csv(b"t,value\n0.1,1.0\n0.2\n", "cam.csv").unwrap_err();
//! assert_eq!(err.to_string(), "cam.csv:3: missing column 2 (value)");
//! ```

use crate::families::Truth;
use std::fmt;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use vlsync_common::text::clip;
use vlsync_common::{Nanos, Sample, NANOS_PER_SEC};

/// A CSV error: which file, which line (1-based, when the error is about one line), what.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CsvError {
    /// The file (or other source name) being read or written.
    pub path: PathBuf,
    /// 1-based line number, when the error concerns one line.
    pub line: Option<usize>,
    /// What was wrong.
    pub message: String,
}

impl fmt::Display for CsvError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(l) => write!(f, "{}:{}: {}", self.path.display(), l, self.message),
            None => write!(f, "{}: {}", self.path.display(), self.message),
        }
    }
}

impl std::error::Error for CsvError {}

/// What the reader saw besides the samples it returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CsvStats {
    /// Data rows read (= samples returned).
    pub rows: usize,
    /// Blank (empty or whitespace-only) lines skipped.
    pub blank_lines: usize,
    /// Rows whose value is NaN or infinite (passed through).
    pub non_finite_values: usize,
    /// Rows that had more than two columns (the extra ones are ignored).
    pub extra_column_rows: usize,
}

/// Formats nanoseconds as seconds with exactly nine decimals, without rounding error.
///
/// ```
/// assert_eq!(vlsync_sim::io::format_secs(-1_500_000_001), "-1.500000001");
/// ```
pub fn format_secs(ns: Nanos) -> String {
    let mut s = String::new();
    write_secs(&mut s, ns);
    s
}

/// [`format_secs`] appended to `out` (no allocation of its own: for writers that
/// reuse one line buffer).
///
/// ```
/// let mut line = String::from("t=");
/// vlsync_sim::io::write_secs(&mut line, i64::MIN);
/// assert_eq!(line, "t=-9223372036.854775808");
/// ```
pub fn write_secs(out: &mut impl std::fmt::Write, ns: Nanos) {
    let v = ns as i128;
    let sign = if v < 0 { "-" } else { "" };
    let a = v.unsigned_abs();
    let per = NANOS_PER_SEC as u128;
    // writing into a String cannot fail
    let _ = write!(out, "{}{}.{:09}", sign, a / per, a % per);
}

/// Parses a time in seconds (decimal text, optionally with an exponent) to nanoseconds.
/// Both forms are converted exactly (rounded half away from zero at the nanosecond), so
/// they accept the same range, the whole of `i64` nanoseconds (about ±292 years): `1e9`
/// and `1000000000` are the same time, and so are `9.2e9` and `9200000000`. Errors on
/// non-finite or out-of-range times.
///
/// ```
/// use vlsync_sim::io::parse_secs;
/// assert_eq!(parse_secs("1700000000.123456789"), Ok(1_700_000_000_123_456_789));
/// assert_eq!(parse_secs("-0.5"), Ok(-500_000_000));
/// assert_eq!(parse_secs("2.5e-3"), Ok(2_500_000));
/// assert_eq!(parse_secs("9.223372036854775807E9"), Ok(i64::MAX));
/// assert!(parse_secs("abc").is_err());
/// ```
pub fn parse_secs(text: &str) -> Result<Nanos, String> {
    let s = text.trim();
    if let Some(ns) = parse_exact_decimal(s) {
        return ns;
    }
    // what Rust's float syntax accepts beyond ours is `inf`, `infinity` and `NaN`
    match s.parse::<f64>() {
        Ok(v) if !v.is_finite() => Err(format!("time `{}` is not finite", clip(s))),
        _ => Err(format!("time `{}` is not a number", clip(s))),
    }
}

/// `None` when `s` is not of the form `[+-]digits[.digits][e[+-]digits]` (digits on
/// at least one side of the point; `E` too); else its value in nanoseconds, computed
/// on the digits (no `f64` rounding), or the out-of-range error.
fn parse_exact_decimal(s: &str) -> Option<Result<Nanos, String>> {
    let (neg, body) = match s.as_bytes().first() {
        Some(b'-') => (true, &s[1..]),
        Some(b'+') => (false, &s[1..]),
        _ => (false, s),
    };
    let (mantissa, exponent) = match body.find(['e', 'E']) {
        Some(i) => (&body[..i], Some(&body[i + 1..])),
        None => (body, None),
    };
    let (int_part, frac_part) = match mantissa.find('.') {
        Some(i) => (&mantissa[..i], &mantissa[i + 1..]),
        None => (mantissa, ""),
    };
    let all_digits = |p: &str| p.bytes().all(|b| b.is_ascii_digit());
    if (int_part.is_empty() && frac_part.is_empty())
        || !all_digits(int_part)
        || !all_digits(frac_part)
    {
        return None;
    }
    // beyond ±10^6 every mantissa with a non-zero digit is out of range or rounds to 0
    let exp: i64 = match exponent {
        None => 0,
        Some(e) => {
            let (e_neg, e_digits) = match e.as_bytes().first() {
                Some(b'-') => (true, &e[1..]),
                Some(b'+') => (false, &e[1..]),
                _ => (false, e),
            };
            if e_digits.is_empty() || !all_digits(e_digits) {
                return None;
            }
            let mag = e_digits
                .bytes()
                .fold(0i64, |m, b| (m * 10 + i64::from(b - b'0')).min(1_000_000));
            if e_neg {
                -mag
            } else {
                mag
            }
        }
    };
    let out_of_range = || {
        Err(format!(
            "time `{}` s is out of the nanosecond range",
            clip(s)
        ))
    };
    // the mantissa's digits without the point and the leading zeros: the nanoseconds
    // are the first `whole` of them (zeros past their end), rounded by the next one
    let lead = int_part
        .bytes()
        .chain(frac_part.bytes())
        .take_while(|&b| b == b'0')
        .count();
    let mut digits = int_part.bytes().chain(frac_part.bytes()).skip(lead);
    let whole = int_part.len() as i64 - lead as i64 + exp + 9;
    let mut digit = || digits.next().map_or(0, |b| i128::from(b - b'0'));
    let mut ns: i128 = 0;
    if int_part.len() + frac_part.len() > lead {
        // a non-zero digit leads: past 19 digits the value is out of range
        if whole > 19 {
            return Some(out_of_range());
        }
        for _ in 0..whole.max(0) {
            ns = ns * 10 + digit();
        }
        if whole >= 0 && digit() >= 5 {
            ns += 1;
        }
    }
    if neg {
        ns = -ns;
    }
    Some(i64::try_from(ns).or_else(|_| out_of_range()))
}

/// Parses a signature CSV from bytes; `source` names it in errors.
/// See [the module docs](self) for the format and the error policy.
pub fn parse_signature_csv(
    bytes: &[u8],
    source: &str,
) -> Result<(Vec<Sample>, CsvStats), CsvError> {
    let mut out = Vec::new();
    let stats = parse_rows(bytes, source, "value", |s| {
        out.push(s);
        Ok(())
    })?;
    Ok((out, stats))
}

/// Parses a two-column CSV (`t,<value_name>`), handing each data row to `row`; an
/// `Err` from `row` becomes the error of that row's line.
/// Columns only an estimates file has: a truth file holding one of them is refused.
const ESTIMATE_ONLY_COLUMNS: [&str; 4] = ["offset_std", "drift_std", "state", "polarity"];

fn parse_rows(
    bytes: &[u8],
    source: &str,
    value_name: &str,
    mut row: impl FnMut(Sample) -> Result<(), String>,
) -> Result<CsvStats, CsvError> {
    let err = |line: Option<usize>, message: String| CsvError {
        path: PathBuf::from(source),
        line,
        message,
    };
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    if bytes.is_empty() {
        return Err(err(
            None,
            format!("empty file: expected a header line such as `t,{value_name}`"),
        ));
    }
    let mut stats = CsvStats::default();
    // the newline ending the last line ends it, and starts no blank line after it
    let lines = bytes.strip_suffix(b"\n").unwrap_or(bytes);
    for (idx, raw) in lines.split(|&b| b == b'\n').enumerate() {
        let lineno = idx + 1;
        let line = std::str::from_utf8(raw).map_err(|e| {
            err(
                Some(lineno),
                format!("invalid UTF-8 at byte {}", e.valid_up_to()),
            )
        })?;
        let line = line.strip_suffix('\r').unwrap_or(line);
        if line.contains('\r') {
            return Err(err(
                Some(lineno),
                vlsync_common::text::CR_INSIDE_LINE.into(),
            ));
        }
        if idx == 0 {
            let first = line.split(',').next().unwrap_or("").trim();
            if first.is_empty() {
                return Err(err(
                    Some(1),
                    format!("expected a header line such as `t,{value_name}`, found an empty line"),
                ));
            }
            if first.parse::<f64>().is_ok() {
                return Err(err(
                    Some(1),
                    format!(
                        "expected a header line such as `t,{value_name}`, found data `{}`",
                        clip(line)
                    ),
                ));
            }
            // the columns are read by position: a header that names them the other
            // way round would be read swapped, without a word
            let name = |c: Option<&str>| {
                c.unwrap_or("")
                    .trim()
                    .trim_matches('"')
                    .to_ascii_lowercase()
            };
            let mut names = line.split(',');
            let (c1, c2) = (name(names.next()), name(names.next()));
            // a signature file where a truth file belongs, or the other way round
            let other = if value_name == "offset" {
                "value"
            } else {
                "offset"
            };
            if c1 == "t" && c2 == other {
                return Err(err(
                    Some(1),
                    format!(
                        "the header `{}` names a `{other}` column: {}, not a {} file \
                         (expected `t,{value_name}`)",
                        clip(line),
                        if other == "value" {
                            "a signature file"
                        } else {
                            "a truth or estimates file"
                        },
                        if other == "value" {
                            "truth"
                        } else {
                            "signature"
                        }
                    ),
                ));
            }
            // an estimates file (`vlsyncd replay --out`, `vlsyncd record`'s est.csv) begins
            // `t,offset` too: scored as the truth, it would grade a run against itself
            if value_name == "offset" {
                if let Some(col) = line
                    .split(',')
                    .skip(2)
                    .map(|c| name(Some(c)))
                    .find(|c| ESTIMATE_ONLY_COLUMNS.contains(&c.as_str()))
                {
                    return Err(err(
                        Some(1),
                        format!(
                            "the header has a column `{col}`: an estimates file, not a truth \
                             file (expected `t,offset`, as the simulator writes it)"
                        ),
                    ));
                }
            }
            if c1 == value_name || c2 == "t" {
                return Err(err(
                    Some(1),
                    format!(
                        "the header `{}` names the columns in another order: they are read \
                         by position, `t` (seconds) first, then `{value_name}`",
                        clip(line)
                    ),
                ));
            }
            continue;
        }
        if line.trim().is_empty() {
            stats.blank_lines += 1;
            continue;
        }
        let mut cols = line.split(',');
        let t_txt = cols.next().unwrap_or("");
        if t_txt.trim().is_empty() {
            return Err(err(Some(lineno), "missing column 1 (t)".into()));
        }
        let t_ns =
            parse_secs(t_txt).map_err(|m| err(Some(lineno), format!("column 1 (t): {m}")))?;
        let v_txt = match cols.next() {
            Some(v) if !v.trim().is_empty() => v.trim(),
            _ => {
                return Err(err(
                    Some(lineno),
                    format!("missing column 2 ({value_name})"),
                ))
            }
        };
        let value: f64 = v_txt.parse().map_err(|_| {
            err(
                Some(lineno),
                format!("column 2 ({value_name}): `{}` is not a number", clip(v_txt)),
            )
        })?;
        if cols.next().is_some() {
            stats.extra_column_rows += 1;
        }
        if !value.is_finite() {
            stats.non_finite_values += 1;
        }
        stats.rows += 1;
        row(Sample::new(t_ns, value)).map_err(|m| err(Some(lineno), m))?;
    }
    Ok(stats)
}

/// Reads a whole input file (a regular file only: a named pipe would block).
fn read_input(path: &Path) -> Result<Vec<u8>, CsvError> {
    vlsync_common::file::read_regular(path).map_err(|e| CsvError {
        path: path.to_path_buf(),
        line: None,
        message: format!("cannot read: {e}"),
    })
}

/// Reads a signature CSV file (header line, then `t,value` rows; extra columns ignored,
/// blank lines skipped, NaN/inf values passed through).
pub fn read_signature_csv(path: impl AsRef<Path>) -> Result<(Vec<Sample>, CsvStats), CsvError> {
    let path = path.as_ref();
    let bytes = read_input(path)?;
    parse_signature_csv(&bytes, &path.display().to_string())
}

/// The publish times of a signature CSV whose header names a fourth column `publish`
/// (what `vlsyncd record` writes: `t,value,seq,publish,flags`, the driver's
/// `CLOCK_MONOTONIC` publish time in seconds), one per data row of
/// [`parse_signature_csv`] in the same order; `Ok(None)` when the header names no such
/// column. Call it on bytes [`parse_signature_csv`] accepted: a row without a valid
/// fourth column is an error naming the file and line.
///
/// ```
/// use vlsync_sim::io::parse_publish_column;
/// let text = b"t,value,seq,publish,flags\n0.1,1.5,0,7.25,1\n\n0.2,1.0,1,7.5,0\n";
/// assert_eq!(parse_publish_column(text, "cam.csv"), Ok(Some(vec![7_250_000_000, 7_500_000_000])));
/// assert_eq!(parse_publish_column(b"t,value\n0.1,1.5\n", "cam.csv"), Ok(None));
/// let err = parse_publish_column(b"t,value,seq,publish\n0.1,1.5,0\n", "cam.csv").unwrap_err();
/// assert_eq!(err.to_string(), "cam.csv:2: missing column 4 (publish)");
/// ```
pub fn parse_publish_column(bytes: &[u8], source: &str) -> Result<Option<Vec<Nanos>>, CsvError> {
    let err = |line: usize, message: String| CsvError {
        path: PathBuf::from(source),
        line: Some(line),
        message,
    };
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let mut lines = bytes.split(|&b| b == b'\n').enumerate();
    let header = lines.next().map_or(&b""[..], |(_, l)| l);
    let named = String::from_utf8_lossy(header)
        .split(',')
        .nth(3)
        .is_some_and(|c| c.trim().trim_matches('"').eq_ignore_ascii_case("publish"));
    if !named {
        return Ok(None);
    }
    let mut out = Vec::new();
    for (idx, raw) in lines {
        let line = String::from_utf8_lossy(raw);
        let line = line.strip_suffix('\r').unwrap_or(&line);
        if line.trim().is_empty() {
            continue;
        }
        let col = line
            .split(',')
            .nth(3)
            .filter(|c| !c.trim().is_empty())
            .ok_or_else(|| err(idx + 1, "missing column 4 (publish)".into()))?;
        out.push(parse_secs(col).map_err(|m| err(idx + 1, format!("column 4 (publish): {m}")))?);
    }
    Ok(Some(out))
}

/// A signature CSV with the publish times `vlsyncd record` writes beside the samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Recorded {
    /// The samples ([`parse_signature_csv`]).
    pub samples: Vec<Sample>,
    /// Their publish times, when the file has the column ([`parse_publish_column`]).
    pub publish: Option<Vec<Nanos>>,
    /// What the reader saw besides.
    pub stats: CsvStats,
}

/// [`read_signature_csv`] and [`parse_publish_column`] of one file, read once.
pub fn read_recorded_csv(path: impl AsRef<Path>) -> Result<Recorded, CsvError> {
    let path = path.as_ref();
    let bytes = read_input(path)?;
    let source = path.display().to_string();
    let (samples, stats) = parse_signature_csv(&bytes, &source)?;
    let publish = parse_publish_column(&bytes, &source)?;
    Ok(Recorded {
        samples,
        publish,
        stats,
    })
}

/// Renders samples as a signature CSV (header `t,value`).
pub fn signature_csv_string(samples: &[Sample]) -> String {
    let mut s = String::with_capacity(24 * samples.len() + 8);
    s.push_str("t,value\n");
    for x in samples {
        let _ = writeln!(s, "{},{}", format_secs(x.t_ns), x.value);
    }
    s
}

fn write_file(path: &Path, text: &str) -> Result<(), CsvError> {
    // whole or not at all: a failed write leaves no file cut mid-row
    vlsync_common::file::write_atomically(path, text.as_bytes()).map_err(|m| CsvError {
        path: path.to_path_buf(),
        line: None,
        // the path is the error's own prefix
        message: match m.strip_prefix(&format!("cannot write {}: ", path.display())) {
            Some(why) => format!("cannot write: {why}"),
            None => m,
        },
    })
}

/// Writes a signature CSV file.
pub fn write_signature_csv(path: impl AsRef<Path>, samples: &[Sample]) -> Result<(), CsvError> {
    write_file(path.as_ref(), &signature_csv_string(samples))
}

/// Most rows [`truth_csv_string`] writes.
pub const MAX_TRUTH_ROWS: i64 = 10_000_000;

/// Renders the truth as CSV `t,offset` every `step_ns` from 0 to `truth.end_ns` inclusive
/// (seconds, LiDAR clock). A non-positive step is replaced by 10 ms, and the step is
/// enlarged when it would give more than [`MAX_TRUTH_ROWS`] rows.
pub fn truth_csv_string(truth: &Truth, step_ns: Nanos) -> String {
    let step = if step_ns > 0 { step_ns } else { 10_000_000 };
    let step = step.max(truth.end_ns / MAX_TRUTH_ROWS + 1);
    let mut s = String::from("t,offset\n");
    let mut t: Nanos = 0;
    while t <= truth.end_ns {
        let _ = writeln!(s, "{},{:.9}", format_secs(t), truth.offset_at(t));
        t = match t.checked_add(step) {
            Some(n) => n,
            None => break,
        };
    }
    s
}

/// Writes the truth CSV (`t,offset`, every 10 ms).
pub fn write_truth_csv(path: impl AsRef<Path>, truth: &Truth) -> Result<(), CsvError> {
    write_file(path.as_ref(), &truth_csv_string(truth, 10_000_000))
}

/// Parses a truth CSV (`t,offset`) as `(t_lidar_ns, offset_s)` pairs; `source` names
/// it in errors. The structure rules of [`parse_signature_csv`], and besides: every
/// offset finite, times strictly increasing, at least one row.
///
/// ```
/// use vlsync_sim::io::parse_truth_csv;
/// assert_eq!(parse_truth_csv(b"t,offset\n0,0.02\n1,0.02\n", "t.csv").unwrap().len(), 2);
/// let e = parse_truth_csv(b"t,offset\n0,0.02\n1,nan\n", "t.csv").unwrap_err();
/// assert_eq!(e.to_string(), "t.csv:3: column 2 (offset): NaN is not a finite number");
/// ```
pub fn parse_truth_csv(bytes: &[u8], source: &str) -> Result<Vec<(Nanos, f64)>, CsvError> {
    let mut out: Vec<(Nanos, f64)> = Vec::new();
    parse_rows(bytes, source, "offset", |s| {
        if !s.value.is_finite() {
            return Err(format!(
                "column 2 (offset): {} is not a finite number",
                s.value
            ));
        }
        if let Some(&(prev, _)) = out.last() {
            if s.t_ns <= prev {
                return Err(format!(
                    "column 1 (t): time {} s is not after the previous row's {} s (truth rows must be in increasing time)",
                    format_secs(s.t_ns),
                    format_secs(prev)
                ));
            }
        }
        out.push((s.t_ns, s.value));
        Ok(())
    })?;
    if out.is_empty() {
        return Err(CsvError {
            path: PathBuf::from(source),
            line: None,
            message: "no data rows: expected `t,offset` rows after the header".into(),
        });
    }
    Ok(out)
}

/// Reads a truth CSV (`t,offset`) as `(t_lidar_ns, offset_s)` pairs; see
/// [`parse_truth_csv`].
pub fn read_truth_csv(path: impl AsRef<Path>) -> Result<Vec<(Nanos, f64)>, CsvError> {
    let path = path.as_ref();
    let bytes = read_input(path)?;
    parse_truth_csv(&bytes, &path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_signature_file_is_no_truth_file_and_the_other_way_round() {
        let e = parse_truth_csv(b"t,value\n0.1,1.0\n", "f").unwrap_err();
        assert_eq!(
            e.to_string(),
            "f:1: the header `t,value` names a `value` column: a signature file, not a truth \
             file (expected `t,offset`)"
        );
        let e = parse_signature_csv(b"t,offset,drift\n0.1,1.0,0\n", "g").unwrap_err();
        assert!(
            e.to_string().contains(
                "names a `offset` column: a truth or estimates file, not a signature file"
            ),
            "{e}"
        );
        assert!(parse_truth_csv(b"t,offset\n0.1,0.01\n", "f").is_ok());
        let e = parse_truth_csv(
            b"t,offset,drift,offset_std,drift_std,state\n0.1,0.01,0,0.001,0,tracking\n",
            "est.csv",
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "est.csv:1: the header has a column `offset_std`: an estimates file, not a truth \
             file (expected `t,offset`, as the simulator writes it)"
        );
        // other extra columns stay ignored, as documented
        assert!(parse_truth_csv(b"t,offset,note\n0.1,0.01,x\n", "f").is_ok());
    }

    #[test]
    fn errors_name_line_and_problem() {
        let cases: [(&[u8], &str); 7] = [
            (
                b"t,value\r0.1,1.0\r0.2,1.5\r",
                "f:1: a carriage return inside the line: CR-only line endings? (lines must end \
                 in LF or CRLF)",
            ),
            (
                b"t,value\n0.1,x\n",
                "f:2: column 2 (value): `x` is not a number",
            ),
            (b"t,value\n\n0.1\n", "f:3: missing column 2 (value)"),
            (b"t,value\n,1\n", "f:2: missing column 1 (t)"),
            (
                b"t,value\nabc,1\n",
                "f:2: column 1 (t): time `abc` is not a number",
            ),
            (
                b"0.1,1.0\n",
                "f:1: expected a header line such as `t,value`, found data `0.1,1.0`",
            ),
            (
                b"",
                "f: empty file: expected a header line such as `t,value`",
            ),
        ];
        for (input, want) in cases {
            assert_eq!(
                parse_signature_csv(input, "f").unwrap_err().to_string(),
                want
            );
        }
        // columns named the other way round are refused, not read swapped; other
        // names are fine (the columns are positional)
        for header in ["value,t", "\"Value\",T", "flow,t", "value,time"] {
            let text = format!("{header}\n0.1,1.0\n");
            let e = parse_signature_csv(text.as_bytes(), "f").unwrap_err();
            assert_eq!(e.line, Some(1), "{header}: {e}");
            assert!(e.message.contains("another order"), "{header}: {e}");
        }
        assert!(parse_signature_csv(b"time_s,flow\n0.1,1.0\n", "f").is_ok());
        let e = parse_truth_csv(b"offset,t\n0.1,0.2\n", "f").unwrap_err();
        assert!(
            e.to_string().contains("`t` (seconds) first, then `offset`"),
            "{e}"
        );
        let e = parse_signature_csv(b"t,value\n1,2\n\xff,1\n", "f").unwrap_err();
        assert_eq!(e.line, Some(3));
        let e = parse_signature_csv(b"t,value\ninf,1\n", "f").unwrap_err();
        assert!(e.message.contains("not finite"), "{e}");
    }

    #[test]
    fn lenient_parts_are_counted() {
        // two blank lines: an empty one (CRLF) and one of spaces; the newline ending
        // the file starts none (it was counted as a third)
        let text =
            b"\xEF\xBB\xBFt,value,extra\r\n0.1,1.5,foo\r\n\r\n  \n0.2, NaN\n0.3,-inf\n0.4,nan\n";
        let (s, st) = parse_signature_csv(text, "f").unwrap();
        assert_eq!(s.len(), 4);
        assert_eq!(s[0], Sample::new(100_000_000, 1.5));
        assert_eq!(
            st,
            CsvStats {
                rows: 4,
                blank_lines: 2,
                non_finite_values: 3,
                extra_column_rows: 1
            }
        );
        assert!(s[3].value.is_nan());
        // a normal file has none, with or without its last newline; one more newline is one
        for (text, blank) in [
            (&b"t,value\n0.1,1\n"[..], 0),
            (b"t,value\r\n0.1,1\r\n", 0),
            (b"t,value\n0.1,1", 0),
            (b"t,value\n0.1,1\n\n", 1),
            (b"t,value\n", 0),
        ] {
            let (_, st) = parse_signature_csv(text, "f").unwrap();
            assert_eq!(st.blank_lines, blank, "{:?}", String::from_utf8_lossy(text));
        }
    }

    #[test]
    fn exact_time_parsing() {
        assert_eq!(parse_secs("0.0000000015"), Ok(2));
        assert_eq!(parse_secs("-0.0000000015"), Ok(-2));
        assert_eq!(parse_secs(".5"), Ok(500_000_000));
        assert_eq!(parse_secs("5."), Ok(5_000_000_000));
        assert!(parse_secs("99999999999999").is_err());
        assert!(parse_secs("1e30").is_err());
        assert!(parse_secs("-").is_err());
        assert!(parse_secs(".").is_err());
        for bad in ["1e", "e5", "1e+", "1e5.5", "1.5e-x", "--1", "+-1", "1 e5"] {
            assert!(
                parse_secs(bad).unwrap_err().contains("not a number"),
                "{bad}"
            );
        }
        for bad in ["inf", "-infinity", "NaN"] {
            assert!(parse_secs(bad).unwrap_err().contains("not finite"), "{bad}");
        }
        assert_eq!(format_secs(0), "0.000000000");
        assert_eq!(parse_secs(&format_secs(i64::MIN)), Ok(i64::MIN));
        assert_eq!(parse_secs(&format_secs(i64::MAX)), Ok(i64::MAX));
    }

    /// A time in exponent form is read as exactly as the same time written out, over
    /// the same range: exponents went through `f64` and refused |t| ≥ 9.2e18 ns, which
    /// the plain form accepts up to `i64::MAX`.
    #[test]
    fn exponent_and_plain_forms_agree() {
        let pairs = [
            ("9.2e9", "9200000000"),
            ("-9.2e9", "-9200000000"),
            ("9.223372036854775807e9", "9223372036.854775807"),
            ("-9223372036854775808E-9", "-9223372036.854775808"),
            ("1.7000000001234567e9", "1700000000.1234567"),
            ("25e-10", "0.0000000025"),
            ("-25e-10", "-0.0000000025"),
            ("2.4999e-9", "0.0000000024999"),
            ("0.5e1", "5"),
            ("5.E-1", ".5"),
            ("+.5e+1", "5."),
            ("00012.5e-3", "0.0125"),
            ("0e999999999999", "0"),
            ("1e-999999999999", "0"),
        ];
        for (exp, plain) in pairs {
            assert_eq!(parse_secs(exp), parse_secs(plain), "{exp} against {plain}");
            assert!(parse_secs(exp).is_ok(), "{exp}");
        }
        assert_eq!(parse_secs("9.2e9"), Ok(9_200_000_000_000_000_000));
        assert_eq!(parse_secs("25e-10"), Ok(3));
        assert_eq!(
            parse_secs("1.7000000001234567e9"),
            Ok(1_700_000_000_123_456_700)
        );
        for out in [
            "9.223372036854775808e9",
            "9223372036.854775808",
            "-9.223372036854775809e9",
            "1e10",
            "1e999999999999",
            "0.00000000000000000001e30",
        ] {
            let e = parse_secs(out).unwrap_err();
            assert!(e.contains("out of the nanosecond range"), "{out}: {e}");
        }
        // exactness and the range, for any time written both ways
        for ns in [
            i64::MIN,
            i64::MIN + 1,
            -1,
            0,
            1,
            123_456_789,
            i64::MAX - 1,
            i64::MAX,
        ] {
            let plain = format_secs(ns);
            let digits: String = plain.chars().filter(|c| c.is_ascii_digit()).collect();
            let sign = if ns < 0 { "-" } else { "" };
            assert_eq!(parse_secs(&format!("{sign}{digits}e-9")), Ok(ns), "{plain}");
            assert_eq!(parse_secs(&plain), Ok(ns));
        }
    }

    #[test]
    fn file_roundtrip_and_unwritable_path() {
        let dir = std::env::temp_dir().join(format!("vlsync-sim-io-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("sig.csv");
        let samples = vec![Sample::new(-3, 1e-300), Sample::new(5, f64::INFINITY)];
        write_signature_csv(&p, &samples).unwrap();
        let (back, _) = read_signature_csv(&p).unwrap();
        assert_eq!(back, samples);
        let bad = dir.join("no-such-dir").join("x.csv");
        let e = write_signature_csv(&bad, &samples).unwrap_err();
        assert!(e.to_string().contains("no-such-dir"), "{e}");
        let e = read_signature_csv(&bad).unwrap_err();
        assert!(e.to_string().contains("cannot read"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn truth_values_order_and_emptiness_are_checked() {
        let ok = parse_truth_csv(b"t,offset\n0,0.02\n\n40,0.025,x\n", "t.csv").unwrap();
        assert_eq!(ok, vec![(0, 0.02), (40_000_000_000, 0.025)]);
        let cases: [(&[u8], &str); 7] = [
            (
                b"t,offset\n0,nan\n40,nan\n",
                "t.csv:2: column 2 (offset): NaN is not a finite number",
            ),
            (
                b"t,offset\n0,0.02\n40,-inf\n",
                "t.csv:3: column 2 (offset): -inf is not a finite number",
            ),
            (
                b"t,offset\n0,0.02\n80,0.02\n40,0.03\n",
                "t.csv:4: column 1 (t): time 40.000000000 s is not after the previous row's \
                 80.000000000 s (truth rows must be in increasing time)",
            ),
            (
                b"t,offset\n1,0.02\n1,0.02\n",
                "t.csv:3: column 1 (t): time 1.000000000 s is not after the previous row's \
                 1.000000000 s (truth rows must be in increasing time)",
            ),
            (
                b"t,offset\n",
                "t.csv: no data rows: expected `t,offset` rows after the header",
            ),
            (
                b"t,offset\n\n \n",
                "t.csv: no data rows: expected `t,offset` rows after the header",
            ),
            (b"t,offset\n0\n", "t.csv:2: missing column 2 (offset)"),
        ];
        for (input, want) in cases {
            assert_eq!(
                parse_truth_csv(input, "t.csv").unwrap_err().to_string(),
                want
            );
        }
        let e = parse_truth_csv(b"t,offset\ninf,0.1\n", "t.csv").unwrap_err();
        assert!(e.to_string().starts_with("t.csv:2: column 1 (t)"), "{e}");
        assert!(e.message.contains("not finite"), "{e}");
        // the file reader applies the same rules and names the file
        let dir = std::env::temp_dir().join(format!("vlsync-sim-truth-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("truth.csv");
        std::fs::write(&p, "t,offset\n0,nan\n").unwrap();
        let e = read_truth_csv(&p).unwrap_err();
        assert_eq!(e.path, p);
        assert_eq!(e.line, Some(2));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn only_regular_files_are_read() {
        let dir = std::env::temp_dir().join(format!("vlsync-sim-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let e = read_signature_csv(&dir).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        // a named pipe without a writer would block the open forever
        let fifo = dir.join("cam.csv");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        for e in [
            read_signature_csv(&fifo).unwrap_err(),
            read_truth_csv(&fifo).unwrap_err(),
        ] {
            assert_eq!(e.path, fifo);
            assert!(e.to_string().contains("not a regular file"), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    proptest! {
        #[test]
        fn truth_reader_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = parse_truth_csv(&bytes, "fuzz");
        }

        #[test]
        fn reader_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = parse_signature_csv(&bytes, "fuzz");
        }

        #[test]
        fn reader_never_panics_on_csvish_text(text in "[t,value0-9.eE+\\-naif \r\n]{0,200}") {
            let _ = parse_signature_csv(text.as_bytes(), "fuzz");
        }

        /// A file the signature reader accepts gives one publish time per sample, or
        /// an error naming its line, never a panic.
        #[test]
        fn publish_column_has_one_time_per_sample_or_names_the_line(
            rows in proptest::collection::vec(
                (-1_000_000_000_000i64..1_000_000_000_000, "[0-9.\\-]{0,6}", any::<bool>()),
                0..30,
            )
        ) {
            let mut text = String::from("t,value,seq,publish,flags\n");
            for (k, (t, publish, blank)) in rows.iter().enumerate() {
                if *blank {
                    text.push_str(" \r\n");
                }
                text.push_str(&format!("{},0.5,{k},{publish},0\n", format_secs(*t)));
            }
            let (samples, _) = parse_signature_csv(text.as_bytes(), "rec.csv").unwrap();
            match parse_publish_column(text.as_bytes(), "rec.csv") {
                Ok(Some(p)) => prop_assert_eq!(p.len(), samples.len()),
                Ok(None) => prop_assert!(false, "the header names the column"),
                Err(e) => prop_assert!(e.to_string().starts_with("rec.csv:") && e.line.is_some()),
            }
        }

        #[test]
        fn written_text_roundtrips(rows in proptest::collection::vec((any::<i64>(), any::<f64>()), 0..50)) {
            let samples: Vec<Sample> = rows.iter().map(|&(t, v)| Sample::new(t, v)).collect();
            let (back, st) = parse_signature_csv(signature_csv_string(&samples).as_bytes(), "rt").unwrap();
            prop_assert_eq!(back.len(), samples.len());
            prop_assert_eq!(st.rows, samples.len());
            for (a, b) in back.iter().zip(&samples) {
                prop_assert_eq!(a.t_ns, b.t_ns);
                prop_assert!(a.value == b.value || (a.value.is_nan() && b.value.is_nan()));
            }
        }
    }
}
