//! The truth an estimate is scored against.
//!
//! * [`TruthModel::Known`]: the simulator's offset model (`vlsync_sim::Truth`,
//!   also what the rendering simulator reports for its sensor clocks).
//! * [`TruthModel::Measured`]: what the drivers measured while they ran
//!   (`--truth-out`), for runs whose stamps depend on the machine (software
//!   stamping under load).
//!
//! # Measured truth
//!
//! Each driver writes, per published sample, its true event time `e` and the
//! stamp `s` it published, both on `CLOCK_MONOTONIC` (`--stamp mono|software`).
//! A sample spans two frames (two passes for the LiDAR): its event is the
//! midpoint of the two true instants and its stamp the midpoint of the two
//! stamps, so `d = s - e` is the mean stamping error of the two frames. The
//! instantaneous true offset of an event at `e` is
//!
//! ```text
//! o(e) = d_L(e) - d_C(e)
//! ```
//!
//! (`t_L - t_C` for one event), each `d` interpolated linearly between that
//! stream's samples. The estimator cannot see faster than its correlation
//! window `W` (`estimator.window_s`): an estimate with reference time `t_ref`
//! (LiDAR clock) measures the offset over the window centred there. The
//! measured truth of that estimate is therefore the mean of `o` at the camera
//! sample events within `±W/2` of `e_ref = t_ref - d_L(t_ref)`; it is undefined
//! (`None`) when camera samples cover less than [`MIN_COVERAGE`] of the window
//! (start and end of the run, long stalls).

use std::path::Path;
use vlsync_common::Nanos;

/// Share of a window that camera samples must cover for a measured truth.
pub const MIN_COVERAGE: f64 = 0.8;

/// One row of a driver's truth file (`vlsync_driver::TRUTH_HEADER`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TruthRow {
    /// Sequence number the sample was published with.
    pub seq: u64,
    /// When it was published, `CLOCK_MONOTONIC` ns.
    pub publish_ns: Nanos,
    /// True event time, ns.
    pub event_ns: Nanos,
    /// Stamp published, ns.
    pub stamp_ns: Nanos,
    /// Camera: end of exposure to front-end, ns.
    pub late_ns: Nanos,
    /// Camera: front-end processing time, ns.
    pub process_ns: Nanos,
    /// Camera: render lateness, ns.
    pub render_late_ns: Nanos,
}

impl TruthRow {
    /// Stamping error `stamp - event`, ns.
    pub fn delay_ns(&self) -> Nanos {
        self.stamp_ns.saturating_sub(self.event_ns)
    }
}

/// Reads a truth file; errors name the file and line.
pub fn read_truth_csv(path: &Path) -> Result<Vec<TruthRow>, String> {
    // a regular file only: a named pipe would block the read
    let text = vlsync_common::file::read_regular_to_string(path)
        .map_err(|e| format!("truth file {}: {e}", path.display()))?;
    parse_truth_csv(&text, &path.display().to_string())
}

/// Parses truth-file text (`what` names it in errors). A last line without its
/// newline is ignored when incomplete (a driver stopped while writing it).
pub fn parse_truth_csv(text: &str, what: &str) -> Result<Vec<TruthRow>, String> {
    let mut lines = text.split_inclusive('\n').enumerate();
    match lines.next() {
        Some((_, h)) if h.trim_end() == vlsync_driver::TRUTH_HEADER => {}
        Some((_, h)) => {
            return Err(format!(
                "{what}:1: header {:?} is not {:?}",
                h.trim_end(),
                vlsync_driver::TRUTH_HEADER
            ))
        }
        None => return Err(format!("{what}: empty file (no header)")),
    }
    let mut rows = vec![];
    for (i, line) in lines {
        let complete = line.ends_with('\n');
        let l = line.trim_end();
        if l.is_empty() {
            continue;
        }
        let f: Vec<&str> = l.split(',').collect();
        let parsed: Option<Vec<i64>> = if f.len() == 7 {
            f.iter().map(|v| v.parse().ok()).collect()
        } else {
            None
        };
        match parsed {
            Some(v) if v[0] >= 0 => rows.push(TruthRow {
                seq: v[0] as u64,
                publish_ns: v[1],
                event_ns: v[2],
                stamp_ns: v[3],
                late_ns: v[4],
                process_ns: v[5],
                render_late_ns: v[6],
            }),
            _ if !complete => break,
            _ => {
                return Err(format!(
                    "{what}:{}: expected 7 integers (seq,publish_ns,event_ns,stamp_ns,late_ns,process_ns,render_late_ns), got {:?}",
                    i + 1,
                    vlsync_common::text::clip(l)
                ))
            }
        }
    }
    Ok(rows)
}

/// `(event, delay)` pairs of one stream, sorted by event time.
#[derive(Debug, Clone, Default)]
struct Delays {
    e: Vec<Nanos>,
    d: Vec<f64>,
}

impl Delays {
    fn new(rows: &[TruthRow]) -> Self {
        let mut v: Vec<(Nanos, f64)> = rows
            .iter()
            .map(|r| (r.event_ns, r.delay_ns() as f64 * 1e-9))
            .collect();
        v.sort_by_key(|p| p.0);
        v.dedup_by_key(|p| p.0);
        Self {
            e: v.iter().map(|p| p.0).collect(),
            d: v.iter().map(|p| p.1).collect(),
        }
    }

    /// Linear interpolation at `e`; the end values outside (within `reach`); `None` beyond.
    fn at(&self, e: Nanos, reach: Nanos) -> Option<f64> {
        let n = self.e.len();
        if n == 0 || e < self.e[0].saturating_sub(reach) || e > self.e[n - 1].saturating_add(reach)
        {
            return None;
        }
        let i = self.e.partition_point(|&x| x <= e);
        if i == 0 {
            return Some(self.d[0]);
        }
        if i == n {
            return Some(self.d[n - 1]);
        }
        let (e0, e1) = (self.e[i - 1], self.e[i]);
        if e1.saturating_sub(e0) > reach {
            // a gap: the nearer side
            return Some(if e.saturating_sub(e0) <= e1.saturating_sub(e) {
                self.d[i - 1]
            } else {
                self.d[i]
            });
        }
        let u = (e - e0) as f64 / (e1 - e0) as f64;
        Some(self.d[i - 1] + u * (self.d[i] - self.d[i - 1]))
    }
}

/// The true offset measured by the drivers; see the module documentation.
#[derive(Debug, Clone)]
pub struct MeasuredTruth {
    cam: Delays,
    lidar: Delays,
    /// Event times of the camera samples and `o` there, with prefix sums.
    o_e: Vec<Nanos>,
    o: Vec<f64>,
    o_sum: Vec<f64>,
    window_ns: Nanos,
    cam_period_ns: Nanos,
}

/// How far a stream's delay is extrapolated past its ends or across a gap.
const REACH_NS: Nanos = 300_000_000;

impl MeasuredTruth {
    /// From the two drivers' rows and the estimator's window (seconds).
    pub fn new(cam: &[TruthRow], lidar: &[TruthRow], window_s: f64) -> Result<Self, String> {
        if cam.len() < 2 || lidar.len() < 2 {
            return Err(format!(
                "measured truth needs rows from both drivers (camera {}, LiDAR {})",
                cam.len(),
                lidar.len()
            ));
        }
        if !(window_s.is_finite() && window_s > 0.0) {
            return Err(format!("window {window_s} s must be a positive number"));
        }
        let cam = Delays::new(cam);
        let lidar = Delays::new(lidar);
        let mut o_e = vec![];
        let mut o = vec![];
        for (&e, &dc) in cam.e.iter().zip(&cam.d) {
            if let Some(dl) = lidar.at(e, REACH_NS) {
                o_e.push(e);
                o.push(dl - dc);
            }
        }
        let mut o_sum = Vec::with_capacity(o.len() + 1);
        o_sum.push(0.0);
        for v in &o {
            o_sum.push(o_sum[o_sum.len() - 1] + v);
        }
        // the median camera sample spacing (the nominal frame period)
        let mut gaps: Vec<Nanos> = cam
            .e
            .windows(2)
            .map(|w| w[1].saturating_sub(w[0]))
            .collect();
        gaps.sort_unstable();
        let cam_period_ns = gaps.get(gaps.len() / 2).copied().unwrap_or(1).max(1);
        Ok(Self {
            cam,
            lidar,
            o_e,
            o,
            o_sum,
            window_ns: (window_s * 1e9) as Nanos,
            cam_period_ns,
        })
    }

    /// Event time (`CLOCK_MONOTONIC`) of LiDAR time `t_l`.
    pub fn event_of_lidar(&self, t_l: Nanos) -> Option<Nanos> {
        // d_L is small and slow: one fixed-point step is exact to well below a ns
        let d0 = self.lidar.at(t_l, REACH_NS)?;
        let e = t_l.saturating_sub((d0 * 1e9) as Nanos);
        let d = self.lidar.at(e, REACH_NS)?;
        Some(t_l.saturating_sub((d * 1e9) as Nanos))
    }

    /// Instantaneous true offset at event time `e`, seconds.
    pub fn instant_at_event(&self, e: Nanos) -> Option<f64> {
        Some(self.lidar.at(e, REACH_NS)? - self.cam.at(e, REACH_NS)?)
    }

    /// Mean of the instantaneous offset over the window centred on event `e`.
    pub fn smoothed_at_event(&self, e: Nanos) -> Option<f64> {
        let (a, b) = (
            e.saturating_sub(self.window_ns / 2),
            e.saturating_add(self.window_ns / 2),
        );
        let i0 = self.o_e.partition_point(|&x| x < a);
        let i1 = self.o_e.partition_point(|&x| x <= b);
        let n = i1.saturating_sub(i0);
        let expected = self.window_ns as f64 / self.cam_period_ns as f64;
        if n == 0 || (n as f64) < MIN_COVERAGE * expected {
            return None;
        }
        Some((self.o_sum[i1] - self.o_sum[i0]) / n as f64)
    }

    /// The measured truth of an estimate with reference time `t_ref` (LiDAR clock), seconds.
    pub fn offset_at(&self, t_ref: Nanos) -> Option<f64> {
        self.smoothed_at_event(self.event_of_lidar(t_ref)?)
    }

    /// The instantaneous offset at every camera sample: `(event, o)`.
    pub fn instant_series(&self) -> impl Iterator<Item = (Nanos, f64)> + '_ {
        self.o_e.iter().copied().zip(self.o.iter().copied())
    }

    /// Mean instantaneous offset over the events in `[a, b)`, and how many samples.
    pub fn mean_between(&self, a: Nanos, b: Nanos) -> Option<(f64, usize)> {
        let i0 = self.o_e.partition_point(|&x| x < a);
        let i1 = self.o_e.partition_point(|&x| x < b);
        let n = i1.checked_sub(i0).filter(|&n| n > 0)?;
        Some(((self.o_sum[i1] - self.o_sum[i0]) / n as f64, n))
    }
}

/// What an estimate is scored against.
#[derive(Debug, Clone)]
pub enum TruthModel {
    /// A known offset model.
    Known(vlsync_sim::Truth),
    /// Measured by the drivers.
    Measured(MeasuredTruth),
}

impl TruthModel {
    /// The true offset for an estimate with reference time `t_ref` (LiDAR clock), seconds.
    pub fn offset_at(&self, t_ref: Nanos) -> Option<f64> {
        match self {
            TruthModel::Known(t) => Some(t.offset_at(t_ref)),
            TruthModel::Measured(m) => m.offset_at(t_ref),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(seq: u64, event: Nanos, stamp: Nanos) -> TruthRow {
        TruthRow {
            seq,
            publish_ns: stamp,
            event_ns: event,
            stamp_ns: stamp,
            late_ns: 0,
            process_ns: 0,
            render_late_ns: 0,
        }
    }

    const MS: Nanos = 1_000_000;

    /// Camera 30 Hz with a delay that steps from 5 to 9 ms at 20 s; LiDAR 10 Hz
    /// stamped 0.2 ms late; 40 s.
    fn stepped() -> (Vec<TruthRow>, Vec<TruthRow>) {
        let base = 1_000_000 * MS;
        let cam = (0..1200)
            .map(|k| {
                let e = base + k * 33_333_333;
                let d = if e < base + 20_000 * MS {
                    5 * MS
                } else {
                    9 * MS
                };
                row(k as u64, e, e + d)
            })
            .collect();
        let lidar = (0..400)
            .map(|k| {
                let e = base + 7 * MS + k * 100 * MS;
                row(k as u64, e, e + MS / 5)
            })
            .collect();
        (cam, lidar)
    }

    #[test]
    fn offset_is_lidar_delay_minus_camera_delay_smoothed_over_the_window() {
        let (cam, lidar) = stepped();
        let m = MeasuredTruth::new(&cam, &lidar, 6.0).unwrap();
        let base = 1_000_000 * MS;
        // far from the step: exactly 0.2 - 5 ms, then 0.2 - 9 ms
        let before = m.offset_at(base + 10_000 * MS + MS / 5).unwrap();
        assert!((before - (0.0002 - 0.005)).abs() < 1e-9, "{before}");
        let after = m.offset_at(base + 30_000 * MS).unwrap();
        assert!((after - (0.0002 - 0.009)).abs() < 1e-9, "{after}");
        // at the step the window holds half of each
        let at = m.offset_at(base + 20_000 * MS).unwrap();
        assert!((at - (0.0002 - 0.007)).abs() < 2e-4, "{at}");
        // instantaneous: the step itself
        assert!((m.instant_at_event(base + 19_000 * MS).unwrap() + 0.0048).abs() < 1e-9);
        assert!((m.instant_at_event(base + 21_000 * MS).unwrap() + 0.0088).abs() < 1e-9);
        // too close to the start for a full window, and outside the run
        assert!(m.offset_at(base + 1_000 * MS).is_none());
        assert!(m.offset_at(base - 10_000 * MS).is_none());
        let (mean, n) = m
            .mean_between(base + 25_000 * MS, base + 35_000 * MS)
            .unwrap();
        assert!((mean + 0.0088).abs() < 1e-9 && n == 300, "{mean} {n}");
        assert!(m.mean_between(base, base).is_none());
        // the event of a LiDAR time undoes the LiDAR delay
        assert_eq!(
            m.event_of_lidar(base + 10_000 * MS + MS / 5),
            Some(base + 10_000 * MS)
        );
    }

    #[test]
    fn a_gap_in_the_camera_leaves_the_truth_undefined_there() {
        let (mut cam, lidar) = stepped();
        let base = 1_000_000 * MS;
        // a 4 s hole: the 6 s window around its centre holds only a third of its samples
        cam.retain(|r| r.event_ns < base + 8_000 * MS || r.event_ns > base + 12_000 * MS);
        let m = MeasuredTruth::new(&cam, &lidar, 6.0).unwrap();
        assert!(m.offset_at(base + 10_000 * MS).is_none());
        assert!(m.offset_at(base + 16_000 * MS).is_some());
    }

    #[test]
    fn truth_files_parse_and_errors_name_file_and_line() {
        let h = vlsync_driver::TRUTH_HEADER;
        let rows =
            parse_truth_csv(&format!("{h}\n0,10,1,3,0,0,0\n1,20,11,13,4,5,6\n"), "f").unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].delay_ns(), 2);
        assert_eq!(
            (rows[1].late_ns, rows[1].process_ns, rows[1].render_late_ns),
            (4, 5, 6)
        );
        // a torn last line (driver stopped mid-write) is ignored
        let rows = parse_truth_csv(&format!("{h}\n0,10,1,3,0,0,0\n1,20,1"), "f").unwrap();
        assert_eq!(rows.len(), 1);
        let e = parse_truth_csv(&format!("{h}\n0,10,1,3,0,0,0\nx,1,2,3,4,5,6\n"), "cam.csv")
            .unwrap_err();
        assert!(e.starts_with("cam.csv:3:"), "{e}");
        let e = parse_truth_csv("t,value\n", "cam.csv").unwrap_err();
        assert!(e.contains("cam.csv:1") && e.contains("header"), "{e}");
        assert!(parse_truth_csv("", "x").unwrap_err().contains("empty"));
        let e = read_truth_csv(Path::new("/nonexistent/vlsync/t.csv")).unwrap_err();
        assert!(e.contains("/nonexistent/vlsync/t.csv"), "{e}");
        assert!(MeasuredTruth::new(&[], &[], 6.0).is_err());
        // hostile values: extreme stamps score as nothing, never overflow
        let e =
            parse_truth_csv(&format!("{h}\n0,1,2,3,4,{}\n", "9".repeat(5000)), "f").unwrap_err();
        assert!(e.len() < 300, "{} bytes", e.len());
        let (lo, hi) = (i64::MIN, i64::MAX);
        let text = format!("{h}\n0,0,{lo},{hi},0,0,0\n1,0,{hi},{lo},0,0,0\n2,0,0,0,0,0,0\n");
        let rows = parse_truth_csv(&text, "f").unwrap();
        assert_eq!(rows[0].delay_ns(), hi);
        let m = MeasuredTruth::new(&rows, &rows, 6.0).unwrap();
        for t in [lo, -1, 0, 1, hi] {
            let _ = m.offset_at(t);
            let _ = m.instant_at_event(t);
        }
    }
}
