//! CPU-pressure change points: hints to the estimator that the offset may have
//! stepped (`daemon.load_hints`).
//!
//! A sensor stamped in software after its processing (a cheap camera) is late by
//! its processing time, which grows when the CPU is contended: a load change is
//! an offset step. The estimator finds such steps from the data alone, but at the
//! signatures' signal-to-noise ratio that takes 5-8 s; told when the step happened
//! ([`vlsync_estimator::Estimator::hint_change`], a change that may not have
//! happened) it restarts its segment there once two seconds of data follow and
//! weighs a step against none until the new segment alone is as precise.
//!
//! The kernel's pressure-stall information measures that contention directly:
//! `/proc/pressure/cpu`'s `some ... total=` is the time (µs) during which at
//! least one runnable task waited for a CPU (a cgroup's `cpu.pressure` has the
//! same format; `daemon.load_hint_source` names the file). [`LoadWatch`] turns its rate into
//! change points: the mean over the newest [`NEW_S`] against the [`OLD_S`] before
//! it; a difference beyond the threshold is a change, dated at the first interval
//! of the new window past the midpoint of the two levels. After a hint the
//! history restarts (each level is measured afresh) and no hint follows for
//! `min_interval`. A wrong hint costs only history: the segment restarts, its σ
//! is larger for a while, the estimate stays unbiased.
//!
//! Runs on the service thread (it reads a file); the hint crosses to the
//! real-time thread over a bounded channel.
#![forbid(unsafe_code)]

use std::collections::VecDeque;
use vlsync_common::Nanos;

/// The newest window, seconds.
pub const NEW_S: f64 = 2.0;
/// The window before it, seconds.
pub const OLD_S: f64 = 4.0;

/// A detected change of CPU pressure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hint {
    /// When the new level began, `CLOCK_MONOTONIC` ns.
    pub at_ns: Nanos,
    /// Share of time some task waited for a CPU, before (0-1).
    pub before: f64,
    /// The same, after.
    pub after: f64,
}

/// Change-point detector on the CPU-pressure counter.
#[derive(Debug, Clone)]
pub struct LoadWatch {
    threshold: f64,
    min_interval_ns: Nanos,
    last: Option<(Nanos, u64)>,
    /// (interval start, interval end, pressure share), oldest first.
    hist: VecDeque<(Nanos, Nanos, f64)>,
    last_hint: Option<Nanos>,
}

impl LoadWatch {
    /// A detector for changes of at least `threshold` (share of time, 0-1), at
    /// most one per `min_interval_s`.
    pub fn new(threshold: f64, min_interval_s: f64) -> Self {
        Self {
            threshold,
            min_interval_ns: (min_interval_s * 1e9) as Nanos,
            last: None,
            hist: VecDeque::new(),
            last_hint: None,
        }
    }

    /// Takes a reading of the `some` total (µs) at `now_ns`; returns a change if
    /// one is now evident. A counter that goes backwards or a clock that does not
    /// advance restarts the history.
    pub fn observe(&mut self, now_ns: Nanos, total_us: u64) -> Option<Hint> {
        let (t0, u0) = self.last.replace((now_ns, total_us))?;
        let dt = now_ns.saturating_sub(t0);
        if dt <= 0 || total_us < u0 {
            self.hist.clear();
            return None;
        }
        let share = ((total_us - u0) as f64 * 1e3 / dt as f64).clamp(0.0, 1.0);
        self.hist.push_back((t0, now_ns, share));
        let span_ns = ((NEW_S + OLD_S) * 1e9) as Nanos;
        while self
            .hist
            .front()
            .is_some_and(|&(a, _, _)| a < now_ns.saturating_sub(span_ns))
        {
            self.hist.pop_front();
        }
        let split = now_ns.saturating_sub((NEW_S * 1e9) as Nanos);
        let (mut old, mut new) = ((0.0, 0i64), (0.0, 0i64));
        for &(a, b, s) in &self.hist {
            let w = b - a;
            let acc = if a >= split { &mut new } else { &mut old };
            acc.0 += s * w as f64;
            acc.1 += w;
        }
        // both levels need most of their window
        if (new.1 as f64) < 0.75 * NEW_S * 1e9 || (old.1 as f64) < 0.75 * OLD_S * 1e9 {
            return None;
        }
        let (before, after) = (old.0 / old.1 as f64, new.0 / new.1 as f64);
        if (after - before).abs() < self.threshold {
            return None;
        }
        if self
            .last_hint
            .is_some_and(|h| now_ns.saturating_sub(h) < self.min_interval_ns)
        {
            return None;
        }
        let mid = 0.5 * (before + after);
        let up = after > before;
        let at_ns = self
            .hist
            .iter()
            .find(|&&(a, _, s)| a >= split && (s > mid) == up)
            .map_or(split, |&(a, _, _)| a);
        self.last_hint = Some(now_ns);
        self.hist.clear();
        Some(Hint {
            at_ns,
            before,
            after,
        })
    }
}

/// The `some` line's `total=` (µs) of a `/proc/pressure/*` file's text.
pub fn parse_some_total(text: &str) -> Result<u64, String> {
    let line = text
        .lines()
        .find(|l| l.starts_with("some "))
        .ok_or_else(|| "no `some` line".to_string())?;
    let v = line
        .split_whitespace()
        .find_map(|f| f.strip_prefix("total="))
        .ok_or_else(|| format!("no `total=` in `{}`", vlsync_common::text::clip(line)))?;
    v.parse::<u64>().map_err(|e| {
        format!(
            "`total={}` in `{}`: {e}",
            vlsync_common::text::clip(v),
            vlsync_common::text::clip(line)
        )
    })
}

/// The most of a pressure file read (the kernel's is about 100 bytes).
const MAX_PRESSURE_BYTES: u64 = 4096;

/// Reads the `some` total (µs) of the pressure file `path`
/// (`daemon.load_hint_source`); the error names the file. A regular file only (a
/// named pipe would block the daemon's start for good), and its first
/// `MAX_PRESSURE_BYTES`.
pub fn read_pressure(path: &str) -> Result<u64, String> {
    use std::io::Read as _;
    let mut text = String::new();
    vlsync_common::file::open_regular(std::path::Path::new(path))
        .and_then(|f| f.take(MAX_PRESSURE_BYTES).read_to_string(&mut text))
        .map_err(|e| format!("{path}: {e}"))?;
    parse_some_total(&text).map_err(|e| format!("{path}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const MS: Nanos = 1_000_000;

    #[test]
    fn the_pressure_file_is_read_and_a_named_pipe_is_refused() {
        let dir = std::env::temp_dir().join(format!("vlsync-pressure-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("cpu");
        std::fs::write(&f, "some avg10=1.00 avg60=0.50 avg300=0.10 total=12345\n").unwrap();
        assert_eq!(read_pressure(f.to_str().unwrap()), Ok(12345));
        let e = read_pressure(dir.to_str().unwrap()).unwrap_err();
        assert!(e.contains("not a regular file (a directory)"), "{e}");
        // a named pipe without a writer would block the daemon's start forever
        let fifo = dir.join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        // read on another thread: a regression would block, and must fail, not hang
        let path = fifo.to_str().unwrap().to_string();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(read_pressure(&path));
        });
        let got = rx.recv_timeout(std::time::Duration::from_secs(5));
        let e = got.expect("reading a named pipe blocked").unwrap_err();
        assert!(e.ends_with("not a regular file (a named pipe)"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Feeds `levels` (share, seconds) in 250 ms readings from t = 0; returns the hints.
    fn feed(w: &mut LoadWatch, levels: &[(f64, f64)]) -> Vec<(Nanos, Hint)> {
        let (mut t, mut total, mut out) = (0i64, 0u64, Vec::new());
        w.observe(t, total);
        for &(share, secs) in levels {
            for _ in 0..(secs * 4.0).round() as usize {
                t += 250 * MS;
                total += (share * 250_000.0) as u64;
                if let Some(h) = w.observe(t, total) {
                    out.push((t, h));
                }
            }
        }
        out
    }

    #[test]
    fn a_load_step_is_dated_where_it_happened() {
        let mut w = LoadWatch::new(0.15, 10.0);
        let hints = feed(&mut w, &[(0.05, 20.0), (0.40, 20.0)]);
        assert_eq!(hints.len(), 1, "{hints:?}");
        let (seen, h) = hints[0];
        assert_eq!(h.at_ns, 20_000 * MS);
        // the new window's mean when it first differs enough
        assert!(
            (h.before - 0.05).abs() < 1e-3 && h.after >= 0.05 + 0.15,
            "{h:?}"
        );
        // noticed within the new window's length
        assert!(seen - h.at_ns <= (NEW_S * 1e9) as Nanos, "{seen}");
        // and back down
        let hints = feed(&mut LoadWatch::new(0.15, 10.0), &[(0.4, 10.0), (0.0, 10.0)]);
        assert_eq!(hints.len(), 1);
        assert_eq!(hints[0].1.at_ns, 10_000 * MS);
    }

    #[test]
    fn steady_or_small_changes_give_no_hint() {
        let mut w = LoadWatch::new(0.15, 10.0);
        assert!(feed(&mut w, &[(0.3, 60.0)]).is_empty());
        assert!(feed(&mut w, &[(0.3, 10.0), (0.4, 20.0)]).is_empty());
    }

    #[test]
    fn bursts_give_at_most_one_hint_per_interval() {
        let mut w = LoadWatch::new(0.15, 10.0);
        let mut levels = vec![(0.0, 10.0)];
        for _ in 0..12 {
            levels.push((0.6, 2.0));
            levels.push((0.0, 3.0));
        }
        let hints = feed(&mut w, &levels);
        assert!(!hints.is_empty());
        for p in hints.windows(2) {
            assert!(p[1].0 - p[0].0 >= 10_000 * MS, "{hints:?}");
        }
    }

    #[test]
    fn counter_reset_or_stalled_clock_restarts_quietly() {
        let mut w = LoadWatch::new(0.15, 10.0);
        feed(&mut w, &[(0.0, 10.0)]);
        assert_eq!(w.observe(10_000 * MS, 0), None);
        assert_eq!(w.observe(10_000 * MS, 5), None);
        assert!(w.hist.is_empty());
    }

    #[test]
    fn parses_the_kernel_format_and_names_what_is_wrong() {
        let text = "some avg10=0.04 avg60=0.66 avg300=1.67 total=9952753945\n\
                    full avg10=0.00 avg60=0.00 avg300=0.00 total=0\n";
        assert_eq!(parse_some_total(text), Ok(9_952_753_945));
        assert!(parse_some_total("full total=3")
            .unwrap_err()
            .contains("some"));
        let e = parse_some_total("some avg10=0.04").unwrap_err();
        assert!(e.contains("total="), "{e}");
        let e = parse_some_total("some total=-4").unwrap_err();
        assert!(e.contains("-4"), "{e}");
    }

    proptest! {
        #[test]
        fn parser_never_panics(s in "\\PC{0,200}") {
            let _ = parse_some_total(&s);
        }

        /// Any readings: no panic, shares stay in 0-1, hints respect the interval.
        #[test]
        fn any_readings_are_harmless(
            steps in proptest::collection::vec((-(10 * MS)..(2_000 * MS), 0u64..5_000_000), 0..300)
        ) {
            let mut w = LoadWatch::new(0.1, 5.0);
            let (mut t, mut total) = (0i64, 0u64);
            let mut last: Option<Nanos> = None;
            for (dt, du) in steps {
                t = t.saturating_add(dt);
                total = total.saturating_add(du);
                if let Some(h) = w.observe(t, total) {
                    prop_assert!((0.0..=1.0).contains(&h.before) && (0.0..=1.0).contains(&h.after));
                    if let Some(l) = last { prop_assert!(t - l >= 5_000 * MS); }
                    last = Some(t);
                }
            }
        }
    }
}
