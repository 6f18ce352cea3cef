//! Text quoted in error messages.

/// Most characters of an input value quoted in an error.
pub const CLIP_CHARS: usize = 40;

/// `s` as an error quotes it: cut at [`CLIP_CHARS`] characters with an ellipsis, so
/// a megabyte of garbage in one field does not become a megabyte of error.
///
/// ```
/// use vlsync_common::text::clip;
/// assert_eq!(clip("1.5x"), "1.5x");
/// assert_eq!(clip(&"9".repeat(100)), format!("{}…", "9".repeat(40)));
/// ```
pub fn clip(s: &str) -> String {
    if s.chars().count() > CLIP_CHARS {
        let mut c: String = s.chars().take(CLIP_CHARS).collect();
        c.push('…');
        c
    } else {
        s.to_string()
    }
}

/// The error for a line that still holds a carriage return once its line ending
/// is taken off: a file with CR-only line endings reads as one line, and every
/// CSV reader says so instead of reading it as a header and no rows.
pub const CR_INSIDE_LINE: &str =
    "a carriage return inside the line: CR-only line endings? (lines must end in LF or CRLF)";

/// A number as an error quotes it: plain for everyday magnitudes (`0.01`, `3600`),
/// in exponent form below 1e-3 and from 1e6 on, so an input such as 1e300 is not
/// printed with 301 digits.
///
/// ```
/// use vlsync_common::text::number;
/// assert_eq!(number(0.01), "0.01");
/// assert_eq!(number(3600.0), "3600");
/// assert_eq!(number(1e300), "1e300");
/// assert_eq!(number(-2.5e-9), "-2.5e-9");
/// assert_eq!(number(0.0), "0");
/// assert_eq!(number(f64::NAN), "NaN");
/// ```
pub fn number(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-3..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}
