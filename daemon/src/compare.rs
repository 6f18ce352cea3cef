//! Estimates files read back, and two runs' estimates compared: `vlsyncd replay
//! --compare` against the live estimates `vlsyncd record` wrote, or against an earlier
//! replay with another configuration.
//!
//! The reader takes what [`crate::replay::write_estimates`] writes. The six columns
//! issue 2 names (`t,offset,drift,offset_std,drift_std,state`) are required, in that
//! order; the five after them (`polarity,peak_score,peak_ratio,measured_offset,seq`)
//! are read when present. A malformed row is an error naming the file and line.
//!
//! ```
//! use vlsyncd::compare::{compare, parse_estimates_csv};
//! let text = "t,offset,drift,offset_std,drift_std,state\n\
//!             10.000000000,0.012,0,0.001,0,tracking\n\
//!             10.500000000,0.013,0,0.001,0,holding\n";
//! let ests = parse_estimates_csv(text.as_bytes(), "est.csv").unwrap();
//! assert_eq!(ests[1].t_ref_ns, 10_500_000_000);
//! let c = compare(&ests, &ests);
//! assert_eq!((c.same_times, c.identical, c.max_abs_diff_s), (2, 2, 0.0));
//! let err = parse_estimates_csv(b"t,offset,drift,offset_std,drift_std,state\n1.0,0.1,0,0,0,fine\n", "est.csv");
//! assert_eq!(err.unwrap_err().to_string(), "est.csv:2: column 6 (state): `fine` is not one of acquiring, tracking, holding, lost");
//! ```

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use vlsync_common::text::clip;
use vlsync_common::{Estimate, EstimatorState, Polarity};
use vlsync_sim::io::{parse_secs, CsvError};

/// The columns an estimates file must start with.
pub const REQUIRED: [&str; 6] = ["t", "offset", "drift", "offset_std", "drift_std", "state"];
/// The columns read when present, after the required ones.
pub const OPTIONAL: [&str; 5] = [
    "polarity",
    "peak_score",
    "peak_ratio",
    "measured_offset",
    "seq",
];

/// Parses an estimates CSV; `source` names it in errors.
pub fn parse_estimates_csv(bytes: &[u8], source: &str) -> Result<Vec<Estimate>, CsvError> {
    let err = |line: Option<usize>, message: String| CsvError {
        path: PathBuf::from(source),
        line,
        message,
    };
    let body = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let text = std::str::from_utf8(body).map_err(|e| {
        // named by its line, as the signature and truth readers do
        let before = &body[..e.valid_up_to()];
        let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
        let column = before.len()
            - before
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |i| i + 1);
        err(Some(line), format!("invalid UTF-8 at byte {column}"))
    })?;
    let mut lines = text.split('\n').enumerate();
    let header = lines.next().map_or("", |(_, l)| l.trim_end_matches('\r'));
    // a file with CR-only line ends is one line here: said so, not read as a header
    // and no rows
    if header.contains('\r') {
        return Err(err(Some(1), vlsync_common::text::CR_INSIDE_LINE.into()));
    }
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    if names.len() < REQUIRED.len() || names[..REQUIRED.len()] != REQUIRED {
        return Err(err(
            Some(1),
            format!(
                "expected the header of an estimates file, `{}` (then optionally `{}`), found `{}`",
                REQUIRED.join(","),
                OPTIONAL.join(","),
                clip(header)
            ),
        ));
    }
    // how many of the optional columns the header names, in order
    let optional = OPTIONAL
        .iter()
        .zip(&names[REQUIRED.len()..])
        .take_while(|(a, b)| a == b)
        .count();
    let mut out = Vec::new();
    for (idx, raw) in lines {
        let line = raw.strip_suffix('\r').unwrap_or(raw);
        let lineno = idx + 1;
        if line.contains('\r') {
            return Err(err(
                Some(lineno),
                vlsync_common::text::CR_INSIDE_LINE.into(),
            ));
        }
        if line.trim().is_empty() {
            continue;
        }
        let cols: Vec<&str> = line.split(',').map(str::trim).collect();
        let want = REQUIRED.len() + optional;
        if cols.len() < want {
            return Err(err(
                Some(lineno),
                format!("{} columns, the header names {want}", cols.len()),
            ));
        }
        let num = |i: usize| -> Result<f64, CsvError> {
            cols[i].parse::<f64>().map_err(|_| {
                let name = REQUIRED.iter().chain(&OPTIONAL).nth(i).unwrap_or(&"?");
                err(
                    Some(lineno),
                    format!(
                        "column {} ({name}): `{}` is not a number",
                        i + 1,
                        clip(cols[i])
                    ),
                )
            })
        };
        // the required numbers are finite (the daemon and replay write no other), the
        // deviations not negative: a NaN would pass as "not identical" without a word
        let finite = |i: usize| -> Result<f64, CsvError> {
            let v = num(i)?;
            let ok = v.is_finite() && (i < 3 || v >= 0.0);
            if ok {
                Ok(v)
            } else {
                Err(err(
                    Some(lineno),
                    format!(
                        "column {} ({}): {v} is not a {}number",
                        i + 1,
                        REQUIRED[i],
                        if i < 3 {
                            "finite "
                        } else {
                            "finite, non-negative "
                        }
                    ),
                ))
            }
        };
        let t_ref_ns =
            parse_secs(cols[0]).map_err(|m| err(Some(lineno), format!("column 1 (t): {m}")))?;
        let state = EstimatorState::from_name(cols[5]).ok_or_else(|| {
            err(
                Some(lineno),
                format!(
                    "column 6 (state): `{}` is not one of acquiring, tracking, holding, lost",
                    clip(cols[5])
                ),
            )
        })?;
        let polarity = if optional > 0 {
            [Polarity::Unknown, Polarity::Positive, Polarity::Negative]
                .into_iter()
                .find(|p| p.name() == cols[6])
                .ok_or_else(|| {
                    err(
                        Some(lineno),
                        format!(
                            "column 7 (polarity): `{}` is not one of unknown, positive, negative",
                            clip(cols[6])
                        ),
                    )
                })?
        } else {
            Polarity::Unknown
        };
        let opt = |k: usize| -> Result<f64, CsvError> {
            if optional > k {
                num(REQUIRED.len() + k)
            } else {
                Ok(f64::NAN)
            }
        };
        let seq = if optional > 4 {
            cols[10].parse::<u64>().map_err(|_| {
                err(
                    Some(lineno),
                    format!(
                        "column 11 (seq): `{}` is not a whole number >= 0",
                        clip(cols[10])
                    ),
                )
            })?
        } else {
            out.len() as u64
        };
        out.push(Estimate {
            seq,
            t_ref_ns,
            offset_s: finite(1)?,
            drift: finite(2)?,
            offset_std_s: finite(3)?,
            drift_std: finite(4)?,
            state,
            polarity,
            peak_score: opt(1)?,
            peak_ratio: opt(2)?,
            measured_offset_s: opt(3)?,
        });
    }
    Ok(out)
}

/// Reads an estimates CSV file (a regular file only).
pub fn read_estimates_csv(path: &Path) -> Result<Vec<Estimate>, CsvError> {
    let bytes = vlsync_common::file::read_regular(path).map_err(|e| CsvError {
        path: path.to_path_buf(),
        line: None,
        message: format!("cannot read: {e}"),
    })?;
    parse_estimates_csv(&bytes, &path.display().to_string())
}

/// Two runs' estimates compared at the reference times both have.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Comparison {
    /// Estimates of the first run.
    pub rows: usize,
    /// Estimates of the other run.
    pub other_rows: usize,
    /// Reference times both runs have an estimate at.
    pub same_times: usize,
    /// Of those, estimates whose rows (as the estimates file writes them) are identical.
    pub identical: usize,
    /// Of those, the ones in a different state.
    pub state_differs: usize,
    /// Of those, the ones locked (tracking or holding) in both.
    pub locked_both: usize,
    /// Mean |offset difference| over `locked_both`, seconds (NaN when none).
    pub mean_abs_diff_s: f64,
    /// Largest |offset difference| over `locked_both`, seconds (0 when none).
    pub max_abs_diff_s: f64,
}

fn locked(e: &Estimate) -> bool {
    matches!(e.state, EstimatorState::Tracking | EstimatorState::Holding)
}

/// How far apart two reference times may be and still be the same estimate's, ns.
/// Files written before `t` was exact (through an f64: an epoch-sized stamp came back
/// up to ~240 ns off) still match; estimates are a hop apart (0.05 s at least).
pub const SAME_TIME_NS: i64 = 1_000;

/// The row of `sorted` (by time, one per time) nearest to `t`, if within
/// [`SAME_TIME_NS`].
fn nearest<'a>(sorted: &[(i64, &'a Estimate)], t: i64) -> Option<&'a Estimate> {
    let i = sorted.partition_point(|&(u, _)| u < t.saturating_sub(SAME_TIME_NS));
    sorted[i..]
        .iter()
        .take_while(|&&(u, _)| u <= t.saturating_add(SAME_TIME_NS))
        .min_by_key(|&&(u, _)| u.abs_diff(t))
        .map(|&(_, e)| e)
}

/// Compares `ests` with `other` at the reference times both have, to within
/// [`SAME_TIME_NS`] (the latest row of `other` for a time it repeats).
pub fn compare(ests: &[Estimate], other: &[Estimate]) -> Comparison {
    let by_time: HashMap<i64, &Estimate> = other.iter().map(|e| (e.t_ref_ns, e)).collect();
    let mut sorted: Vec<(i64, &Estimate)> = by_time.into_iter().collect();
    sorted.sort_unstable_by_key(|&(t, _)| t);
    let (mut a, mut b) = (String::new(), String::new());
    let mut c = Comparison {
        rows: ests.len(),
        other_rows: other.len(),
        same_times: 0,
        identical: 0,
        state_differs: 0,
        locked_both: 0,
        mean_abs_diff_s: f64::NAN,
        max_abs_diff_s: 0.0,
    };
    let mut sum = 0.0;
    for e in ests {
        let Some(o) = nearest(&sorted, e.t_ref_ns) else {
            continue;
        };
        c.same_times += 1;
        crate::replay::estimate_row(e, &mut a);
        // the same estimate, whatever rounding its time went through
        crate::replay::estimate_row(
            &Estimate {
                t_ref_ns: e.t_ref_ns,
                ..*o
            },
            &mut b,
        );
        c.identical += usize::from(a == b);
        c.state_differs += usize::from(e.state != o.state);
        if locked(e) && locked(o) {
            let d = (e.offset_s - o.offset_s).abs();
            if d.is_finite() {
                c.locked_both += 1;
                sum += d;
                c.max_abs_diff_s = c.max_abs_diff_s.max(d);
            }
        }
    }
    if c.locked_both > 0 {
        c.mean_abs_diff_s = sum / c.locked_both as f64;
    }
    c
}

impl Comparison {
    /// One readable line: `name` is the other run's file.
    pub fn describe(&self, name: &str) -> String {
        if self.same_times == 0 {
            return format!(
                "against {name}: no estimate at a reference time its {} rows have (another hop_s or grid, or another recording?); a --plot shows both",
                self.other_rows
            );
        }
        let mut s = format!(
            "against {name}: {} of {} estimates at reference times it has ({} rows); {} identical, {} in another state",
            self.same_times, self.rows, self.other_rows, self.identical, self.state_differs
        );
        if self.locked_both > 0 {
            s.push_str(&format!(
                "; locked in both {}: |offset difference| mean {:.3} ms, max {:.3} ms",
                self.locked_both,
                self.mean_abs_diff_s * 1e3,
                self.max_abs_diff_s * 1e3
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn est(seq: u64, t_ns: i64, offset_s: f64, state: EstimatorState) -> Estimate {
        Estimate {
            seq,
            t_ref_ns: t_ns,
            offset_s,
            drift: 1e-5,
            offset_std_s: 0.001,
            drift_std: 2e-5,
            state,
            polarity: Polarity::Negative,
            peak_score: 0.8,
            peak_ratio: f64::INFINITY,
            measured_offset_s: f64::NAN,
        }
    }

    #[test]
    fn invalid_utf8_is_named_by_its_line() {
        let mut bytes = format!("{}\n", crate::replay::ESTIMATE_HEADER).into_bytes();
        bytes.extend_from_slice(b"1.0,0,0,0,0,lost\n2.0,\xff\n");
        let e = parse_estimates_csv(&bytes, "e.csv").unwrap_err();
        assert_eq!(e.line, Some(3), "{e}");
        assert!(
            e.to_string()
                .starts_with("e.csv:3: invalid UTF-8 at byte 4"),
            "{e}"
        );
    }

    fn file(ests: &[Estimate]) -> String {
        let mut s = format!("{}\n", crate::replay::ESTIMATE_HEADER);
        let mut row = String::new();
        for e in ests {
            crate::replay::estimate_row(e, &mut row);
            s.push_str(&row);
            s.push('\n');
        }
        s
    }

    proptest! {
        /// What the estimates file writes reads back to the same rows.
        #[test]
        fn written_rows_read_back_to_the_same_rows(
            t in any::<i64>(),
            offset in -2.0f64..2.0,
            drift in -1e-3f64..1e-3,
            std in 0.0f64..1.0,
            state in 0u8..4,
            seq in any::<u64>(),
            measured in prop::option::of(-2.0f64..2.0),
        ) {
            let mut e = est(seq, t, offset, EstimatorState::from_code(state).unwrap());
            e.drift = drift;
            e.offset_std_s = std;
            e.measured_offset_s = measured.unwrap_or(f64::NAN);
            let text = file(&[e]);
            let back = parse_estimates_csv(text.as_bytes(), "p.csv").unwrap();
            prop_assert_eq!(back.len(), 1);
            prop_assert_eq!(file(&back), text);
            prop_assert_eq!(back[0].t_ref_ns, t);
            prop_assert_eq!(back[0].seq, seq);
        }

        /// Arbitrary text gives estimates or an error naming the file, never a panic.
        #[test]
        fn any_text_is_read_or_refused_with_the_file_named(body in "[-0-9a-z.,\\r\\n ]{0,200}") {
            let text = format!("{}\n{body}", crate::replay::ESTIMATE_HEADER);
            if let Err(e) = parse_estimates_csv(text.as_bytes(), "x.csv") {
                prop_assert!(e.to_string().starts_with("x.csv:"));
            }
        }
    }

    #[test]
    fn only_the_required_columns_are_needed_and_errors_name_the_line() {
        let ests = parse_estimates_csv(
            b"t,offset,drift,offset_std,drift_std,state,note\n\n1.5,0.01,0,0.001,0,lost,x\n",
            "e.csv",
        )
        .unwrap();
        assert_eq!(ests.len(), 1);
        assert_eq!(ests[0].state, EstimatorState::Lost);
        assert!(ests[0].peak_score.is_nan() && ests[0].polarity == Polarity::Unknown);
        let cases: [(&[u8], &str); 9] = [
            (
                b"t,offset,drift,offset_std,drift_std,state\r1.0,0,0,0,0,lost\r",
                "e.csv:1: a carriage return inside the line",
            ),
            (
                b"t,offset,drift,offset_std,drift_std,state\r\n1.0,0,0,0,0,lost\r2.0,0,0,0,0,lost\r\n",
                "e.csv:2: a carriage return inside the line",
            ),
            (
                b"t,offset,drift,offset_std,drift_std,state\n1.0,NaN,0,0,0,lost\n",
                "e.csv:2: column 2 (offset): NaN is not a finite number",
            ),
            (
                b"t,offset,drift,offset_std,drift_std,state\n1.0,0,0,-0.1,0,lost\n",
                "e.csv:2: column 4 (offset_std): -0.1 is not a finite, non-negative number",
            ),
            (b"", "e.csv:1: expected the header of an estimates file"),
            (b"t,value\n1,2\n", "e.csv:1: expected the header"),
            (
                b"t,offset,drift,offset_std,drift_std,state\n1.0,0.1,0,0\n",
                "e.csv:2: 4 columns, the header names 6",
            ),
            (
                b"t,offset,drift,offset_std,drift_std,state\n1.0,abc,0,0,0,lost\n",
                "e.csv:2: column 2 (offset): `abc` is not a number",
            ),
            (
                b"t,offset,drift,offset_std,drift_std,state,polarity\n\n1.0,0,0,0,0,lost,up\n",
                "e.csv:3: column 7 (polarity): `up` is not one of",
            ),
        ];
        for (text, want) in cases {
            let e = parse_estimates_csv(text, "e.csv").unwrap_err().to_string();
            assert!(e.starts_with(want), "{e} / {want}");
        }
    }

    #[test]
    fn epoch_sized_reference_times_read_back_exactly() {
        // 1.7e18 ns has no exact f64: written through one, it came back 72 ns off,
        // and `--compare` matched no estimate of a recording stamped on the epoch
        let t = 1_700_000_000_123_456_789;
        let e = est(7, t, 0.01, EstimatorState::Tracking);
        let text = file(&[e]);
        assert!(text.contains("\n1700000000.123456789,"), "{text}");
        let back = parse_estimates_csv(text.as_bytes(), "e.csv").unwrap();
        assert_eq!(back[0].t_ref_ns, t);
        assert_eq!(compare(&[e], &back).identical, 1);
    }

    #[test]
    fn times_written_through_an_f64_still_match() {
        // what files written before `t` was exact hold: 1700000000.1234567 s
        let t = 1_700_000_000_123_456_789;
        let e = est(7, t, 0.01, EstimatorState::Tracking);
        let text = file(&[e]).replace("1700000000.123456789,", "1700000000.1234567,");
        let old = parse_estimates_csv(text.as_bytes(), "old.csv").unwrap();
        assert_eq!(old[0].t_ref_ns, 1_700_000_000_123_456_700);
        let c = compare(&[e], &old);
        assert_eq!((c.same_times, c.identical, c.locked_both), (1, 1, 1));
        // a neighbour a hop away is another estimate, never matched
        let next = est(8, t + 500_000_000, 0.02, EstimatorState::Tracking);
        let c = compare(&[next], &old);
        assert_eq!((c.same_times, c.identical), (0, 0));
        // of two rows near a time, the nearer
        let near = est(9, t + 2, 0.05, EstimatorState::Tracking);
        let far = est(10, t - 900, 0.01, EstimatorState::Tracking);
        let c = compare(&[e], &[far, near]);
        assert_eq!(c.same_times, 1);
        assert!(
            (c.max_abs_diff_s - 0.04).abs() < 1e-12,
            "{}",
            c.max_abs_diff_s
        );
    }

    #[test]
    fn comparison_counts_identical_rows_states_and_offset_differences() {
        let s = 1_000_000_000;
        let a = [
            est(0, 0, 0.0, EstimatorState::Acquiring),
            est(1, s, 0.010, EstimatorState::Tracking),
            est(2, 2 * s, 0.011, EstimatorState::Tracking),
            est(3, 3 * s, 0.012, EstimatorState::Holding),
        ];
        let mut b = a;
        b[2].offset_s = 0.0115;
        b[3].state = EstimatorState::Tracking;
        let c = compare(&a, &b[1..]);
        assert_eq!((c.rows, c.other_rows, c.same_times), (4, 3, 3));
        assert_eq!((c.identical, c.state_differs, c.locked_both), (1, 1, 3));
        assert!((c.max_abs_diff_s - 0.0005).abs() < 1e-12);
        assert!((c.mean_abs_diff_s - 0.0005 / 3.0).abs() < 1e-12);
        let line = c.describe("est.csv");
        assert_eq!(
            line,
            "against est.csv: 3 of 4 estimates at reference times it has (3 rows); 1 identical, 1 in another state; locked in both 3: |offset difference| mean 0.167 ms, max 0.500 ms"
        );
        let shifted = |by: i64| -> Vec<Estimate> {
            a.iter()
                .map(|e| Estimate {
                    t_ref_ns: e.t_ref_ns + by,
                    ..*e
                })
                .collect()
        };
        assert!(compare(&a, &shifted(SAME_TIME_NS + 1))
            .describe("o.csv")
            .starts_with("against o.csv: no estimate at a reference time its 4 rows have"));
        let c = compare(&a, &shifted(SAME_TIME_NS));
        assert_eq!((c.same_times, c.identical), (4, 4));
    }
}
